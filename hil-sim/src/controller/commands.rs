//! Request handling: control characters and GCS command lines in, answer
//! lines out, errors kept for `ERR?` the way a C-863 keeps them; the `HLP?`
//! list of what the simulator implements.
//!
//! Why a file of its own: this is the controller's wire-facing surface,
//! checked against PIPython; the state it reads and the motion it starts
//! live in `state` and `actions`.

use super::{Activity, Controller, RefKind, AXIS, E, FIRMWARE, MODEL, VENDOR};
use crate::motion::Profile;
use crate::params::{self, ParamValue, ValueError};
use micropos::gcs::frame::{encode_answer, Request};
use micropos::gcs::{AxisId, Command, ControlChar};
use std::time::Duration;

/// Formats a number the way the C-863 answers positions: 7 decimals, no
/// negative zero.
pub(super) fn num7(v: f64) -> String {
    let r = (v * 1e7).round() / 1e7;
    let r = if r == 0.0 { 0.0 } else { r };
    format!("{r:.7}")
}

fn bool01(b: bool) -> String {
    if b { "1" } else { "0" }.to_owned()
}

/// Help text of `HLP?`: every command the simulator implements, one per line
/// (PIPython reads the first word of each line to learn what is supported).
const HELP: &[(&str, &str)] = &[
    ("#4", "Request Status Register"),
    ("#5", "Request Motion Status"),
    ("#7", "Request Controller Ready Status"),
    ("#24", "Stop All Axes"),
    ("*IDN?", "Get Device Identification"),
    (
        "ACC",
        "<AxisID> <Acceleration> Set Closed-Loop Acceleration",
    ),
    ("ACC?", "[{<AxisID>}] Get Closed-Loop Acceleration"),
    ("CST?", "[{<AxisID>}] Get Assignment Of Stages To Axes"),
    ("CSV?", "Get Current Syntax Version"),
    (
        "DEC",
        "<AxisID> <Deceleration> Set Closed-Loop Deceleration",
    ),
    ("DEC?", "[{<AxisID>}] Get Closed-Loop Deceleration"),
    (
        "DRC",
        "{<RecTableID> <Source> <RecOption>} Set Data Recorder Configuration",
    ),
    ("DRC?", "[{<RecTableID>}] Get Data Recorder Configuration"),
    ("DRL?", "[{<RecTableID>}] Get Number Of Recorded Points"),
    (
        "DRR?",
        "[<StartPoint> <NumberOfPoints> [{<RecTableID>}]] Get Recorded Data Values",
    ),
    (
        "DRT",
        "{<RecTableID> <TriggerSource> <Value>} Set Data Recorder Trigger Source",
    ),
    ("ERR?", "Get Error Number"),
    ("FNL", "[{<AxisID>}] Fast Reference Move To Negative Limit"),
    ("FPL", "[{<AxisID>}] Fast Reference Move To Positive Limit"),
    (
        "FRF",
        "[{<AxisID>}] Fast Reference Move To Reference Switch",
    ),
    ("FRF?", "[{<AxisID>}] Get Referencing Result"),
    ("HDR?", "Get All Data Recorder Options"),
    ("HLP?", "Get List Of Available Commands"),
    ("HLT", "[{<AxisID>}] Halt Motion Smoothly"),
    ("HPA?", "Get List Of Available Parameters"),
    ("MOV", "{<AxisID> <Position>} Set Target Position"),
    ("MOV?", "[{<AxisID>}] Get Target Position"),
    (
        "MVR",
        "{<AxisID> <Distance>} Set Target Relative To Current Target",
    ),
    ("ONT?", "[{<AxisID>}] Get On-Target State"),
    ("POS?", "[{<AxisID>}] Get Real Position"),
    ("RON", "{<AxisID> <ReferenceOn>} Set Reference Mode"),
    ("RON?", "[{<AxisID>}] Get Reference Mode"),
    ("RTR", "<RecordTableRate> Set Record Table Rate"),
    ("RTR?", "Get Record Table Rate"),
    ("SAI?", "[ALL] Get List Of Current Axis Identifiers"),
    (
        "SPA",
        "{<AxisID> <PamID> <PamValue>} Set Volatile Memory Parameters",
    ),
    (
        "SPA?",
        "[{<AxisID> <PamID>}] Get Volatile Memory Parameters",
    ),
    ("STP", "Stop All Axes"),
    ("SVO", "{<AxisID> <ServoState>} Set Servo Mode"),
    ("SVO?", "[{<AxisID>}] Get Servo Mode"),
    ("TMN?", "[{<AxisID>}] Get Minimum Commandable Position"),
    ("TNR?", "Get Number Of Record Tables"),
    ("TMX?", "[{<AxisID>}] Get Maximum Commandable Position"),
    ("VEL", "{<AxisID> <Velocity>} Set Closed-Loop Velocity"),
    ("VEL?", "[{<AxisID>}] Get Closed-Loop Velocity"),
    ("VER?", "Get Versions Of Firmware And Drivers"),
];

impl Controller {
    /// Handles one request at `now`; returns the answer bytes if this
    /// controller answers it. Requests for other addresses are ignored.
    pub fn handle(&mut self, now: Duration, req: &Request) -> Option<Vec<u8>> {
        let out = self.handle_inner(now, req);
        let now = self.last_now.max(now);
        self.sync_platform(now);
        out
    }

    fn handle_inner(&mut self, now: Duration, req: &Request) -> Option<Vec<u8>> {
        match req {
            Request::Overlong => {
                self.tick(now);
                self.set_error(E::COMMAND_TOO_LONG);
                None
            }
            Request::Control { addr, command } => {
                if !self.accepts(*addr) {
                    return None;
                }
                let now = self.tick(now);
                self.control(now, *command)
                    .map(|line| encode_answer(*addr, &[line]))
            }
            Request::Line { addr, text } => {
                if !self.accepts(*addr) {
                    return None;
                }
                let now = self.tick(now);
                let result = Command::parse(text)
                    .map_err(|e| e.gcs_code())
                    .and_then(|cmd| self.execute(now, &cmd));
                match result {
                    Ok(Some(lines)) => Some(encode_answer(*addr, &lines)),
                    Ok(None) => None,
                    Err(e) => {
                        self.set_error(e);
                        None
                    }
                }
            }
        }
    }

    fn control(&mut self, now: Duration, c: ControlChar) -> Option<String> {
        match c {
            ControlChar::Status => Some(format!("0x{:X}", self.status_register(now))),
            ControlChar::MotionStatus => Some(format!("{:X}", u8::from(self.is_moving(now)))),
            ControlChar::Ready => Some(
                char::from(if self.is_referencing(now) {
                    0xB0u8
                } else {
                    0xB1
                })
                .to_string(),
            ),
            ControlChar::StopAll => {
                self.stop_now(now);
                None
            }
        }
    }

    /// Checks a list of axis ids; empty means all (the one axis).
    pub(super) fn axes(axes: &[AxisId]) -> Result<Vec<AxisId>, E> {
        if axes.is_empty() {
            return Ok(vec![AxisId::new(AXIS).map_err(|_| E::INVALID_AXIS)?]);
        }
        for a in axes {
            if a.as_str() != AXIS {
                return Err(E::INVALID_AXIS);
            }
        }
        Ok(axes.to_vec())
    }

    fn check_axis(a: &AxisId) -> Result<(), E> {
        if a.as_str() == AXIS {
            Ok(())
        } else {
            Err(E::INVALID_AXIS)
        }
    }

    fn per_axis(axes: &[AxisId], f: impl Fn() -> String) -> Result<Option<Vec<String>>, E> {
        Ok(Some(
            Self::axes(axes)?
                .iter()
                .map(|a| format!("{a}={}", f()))
                .collect(),
        ))
    }

    fn execute(&mut self, now: Duration, cmd: &Command) -> Result<Option<Vec<String>>, E> {
        use Command as C;
        match cmd {
            C::Idn => Ok(Some(vec![format!(
                "{VENDOR}, {MODEL}, {}, {FIRMWARE}",
                self.serial
            )])),
            C::Csv => Ok(Some(vec!["2.0".to_owned()])),
            C::Err => {
                let e = self.error;
                self.error = E::NO_ERROR;
                Ok(Some(vec![e.0.to_string()]))
            }
            C::Hlp => {
                let mut lines = vec!["The following commands are valid:".to_owned()];
                lines.extend(HELP.iter().map(|(c, d)| format!("{c} {d}")));
                lines.push("end of help".to_owned());
                Ok(Some(lines))
            }
            C::Hpa => Ok(Some(params::hpa_lines())),
            C::Ver => Ok(Some(vec![
                format!("FW_ARM: V{FIRMWARE}"),
                format!(
                    "hil-sim: V{} (simulated controller)",
                    env!("CARGO_PKG_VERSION")
                ),
            ])),
            C::SaiQuery { .. } => Ok(Some(vec![AXIS.to_owned()])),
            C::CstQuery(a) => {
                let name = self
                    .params
                    .get(params::STAGE_NAME)
                    .map(ParamValue::to_text)
                    .unwrap_or_default();
                Self::per_axis(a, || name.clone())
            }
            C::TmnQuery(a) => {
                let v = self.params.number(params::MAX_TRAVEL_NEG, 0.0);
                Self::per_axis(a, || num7(v))
            }
            C::TmxQuery(a) => {
                let v = self.params.number(params::MAX_TRAVEL_POS, 15.0);
                Self::per_axis(a, || num7(v))
            }
            C::PosQuery(a) => {
                let v = self.encoder_mm(now);
                Self::per_axis(a, || num7(v))
            }
            C::MovQuery(a) => {
                let v = self.target_mm;
                Self::per_axis(a, || num7(v))
            }
            C::OntQuery(a) => {
                let v = self.on_target(now);
                Self::per_axis(a, || bool01(v))
            }
            C::FrfQuery(a) => {
                let v = self.is_referenced(now);
                Self::per_axis(a, || bool01(v))
            }
            C::SvoQuery(a) => Self::per_axis(a, || bool01(self.servo)),
            C::RonQuery(a) => Self::per_axis(a, || bool01(self.reference_mode)),
            C::VelQuery(a) => {
                let v = self.params.number(params::VELOCITY, 1.0);
                Self::per_axis(a, || num7(v))
            }
            C::AccQuery(a) => {
                let v = self.params.number(params::ACCELERATION, 10.0);
                Self::per_axis(a, || num7(v))
            }
            C::DecQuery(a) => {
                let v = self.params.number(params::DECELERATION, 10.0);
                Self::per_axis(a, || num7(v))
            }
            C::SpaQuery(items) => {
                if items.is_empty() {
                    return Ok(Some(
                        self.params
                            .iter()
                            .map(|(id, v)| format!("{AXIS} 0x{id:X}={}", v.to_text()))
                            .collect(),
                    ));
                }
                let mut out = Vec::new();
                for (a, id) in items {
                    Self::check_axis(a)?;
                    let v = self.params.get(*id).ok_or(E::UNKNOWN_PARAMETER)?;
                    out.push(format!("{a} 0x{id:X}={}", v.to_text()));
                }
                Ok(Some(out))
            }
            C::Svo(items) => {
                for (a, _) in items {
                    Self::check_axis(a)?;
                }
                for (_, on) in items {
                    if *on && !self.servo {
                        // Closing the loop holds the current position.
                        self.encoder_mm = self.encoder_mm(now);
                        self.target_mm = self.encoder_mm;
                        self.settled_at = now;
                    } else if !*on && self.servo {
                        // Opening the loop: the motor is no longer driven.
                        let (p, _) = self.state_at(now);
                        if matches!(self.activity, Activity::Referencing { .. }) {
                            self.referenced = false;
                        }
                        self.encoder_mm = p;
                        self.activity = Activity::Idle;
                    }
                    self.servo = *on;
                }
                Ok(None)
            }
            C::Ron(items) => {
                for (a, _) in items {
                    Self::check_axis(a)?;
                }
                for (_, on) in items {
                    self.reference_mode = *on;
                }
                Ok(None)
            }
            C::Frf(a) => self
                .start_referencing(now, a, RefKind::Reference)
                .map(|_| None),
            C::Fnl(a) => self
                .start_referencing(now, a, RefKind::NegativeLimit)
                .map(|_| None),
            C::Fpl(a) => self
                .start_referencing(now, a, RefKind::PositiveLimit)
                .map(|_| None),
            C::Mov(items) | C::Mvr(items) => {
                let relative = matches!(cmd, C::Mvr(_));
                for (a, _) in items {
                    Self::check_axis(a)?;
                }
                self.check_move_allowed(now)?;
                // All targets are checked before anything moves.
                let mut target = self.target_mm;
                for (_, v) in items {
                    target = if relative { target + v } else { *v };
                    self.check_limits(target)?;
                }
                self.start_move(now, target);
                self.recorder.on_move(now);
                Ok(None)
            }
            C::Vel(items) => {
                let max = self.params.number(params::MAX_VELOCITY, 1.5);
                for (a, v) in items {
                    Self::check_axis(a)?;
                    if !(*v > 0.0 && *v <= max) {
                        return Err(E::VEL_OUT_OF_LIMITS);
                    }
                }
                for (_, v) in items {
                    self.params.set(params::VELOCITY, ParamValue::Float(*v));
                }
                self.replan(now);
                Ok(None)
            }
            C::Acc(items) | C::Dec(items) => {
                let (id, max_id) = if matches!(cmd, C::Acc(_)) {
                    (params::ACCELERATION, params::MAX_ACCELERATION)
                } else {
                    (params::DECELERATION, params::MAX_DECELERATION)
                };
                let max = self.params.number(max_id, 20.0);
                for (a, v) in items {
                    Self::check_axis(a)?;
                    if !(*v > 0.0 && *v <= max) {
                        return Err(E::PARAM_OUT_OF_RANGE);
                    }
                }
                for (_, v) in items {
                    self.params.set(id, ParamValue::Float(*v));
                }
                self.replan(now);
                Ok(None)
            }
            C::Spa(items) => {
                let mut parsed = Vec::with_capacity(items.len());
                for (a, id, text) in items {
                    Self::check_axis(a)?;
                    let d = params::lookup(*id).ok_or(E::UNKNOWN_PARAMETER)?;
                    let v = params::parse_value(d, text).map_err(|e| match e {
                        ValueError::Syntax => E::PARAM_SYNTAX,
                        ValueError::OutOfRange => E::PARAM_OUT_OF_RANGE,
                    })?;
                    parsed.push((*id, v));
                }
                for (id, v) in parsed {
                    self.params.set(id, v);
                }
                self.replan(now);
                Ok(None)
            }
            C::Hlt(a) => {
                Self::axes(a)?;
                self.stalled = false;
                let (p, v, e) = self.command_state_at(now);
                match &self.activity {
                    Activity::Idle => {}
                    Activity::Moving(_) | Activity::Referencing { .. } => {
                        if matches!(self.activity, Activity::Referencing { .. }) {
                            self.referenced = false;
                        }
                        let dec = self.limits().deceleration;
                        let profile = Profile::brake(now, p, v, dec).with_lag(self.lag_s, e);
                        self.target_mm = profile.end_mm();
                        self.activity = Activity::Moving(profile);
                    }
                }
                self.set_error(E::STOPPED);
                Ok(None)
            }
            C::Stp => {
                self.stop_now(now);
                Ok(None)
            }
            C::TnrQuery => Ok(Some(vec![super::recorder::TABLES.to_string()])),
            C::HdrQuery => Ok(Some(super::recorder::Recorder::help())),
            C::Drc(items) => self.recorder.configure(items, AXIS).map(|()| None),
            C::DrcQuery(t) => self.recorder.configuration(t, AXIS).map(Some),
            C::Rtr(r) => self.recorder.set_rate(*r).map(|()| None),
            C::RtrQuery => Ok(Some(vec![self.recorder.rate().to_string()])),
            C::Drt(items) => self.recorder.trigger(now, items).map(|()| None),
            C::DrlQuery(t) => self.recorder.lengths(t).map(Some),
            C::DrrQuery {
                start,
                count,
                tables,
            } => self.recorder.read(*start, *count, tables, AXIS).map(Some),
        }
    }

    /// The commands `HLP?` lists (without descriptions).
    pub fn help_commands() -> impl Iterator<Item = &'static str> {
        HELP.iter().map(|(c, _)| *c)
    }
}
