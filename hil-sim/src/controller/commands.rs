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

    /// Runs one command: its reply lines (`None` for a command without a
    /// reply) or the GCS error it sets.
    fn execute(&mut self, now: Duration, cmd: &Command) -> Result<Option<Vec<String>>, E> {
        use Command as C;
        match cmd {
            C::Idn | C::Csv | C::Err | C::Hlp | C::Hpa | C::Ver | C::SaiQuery { .. } => {
                Ok(Some(self.identify(cmd)))
            }
            C::CstQuery(a)
            | C::TmnQuery(a)
            | C::TmxQuery(a)
            | C::PosQuery(a)
            | C::MovQuery(a)
            | C::OntQuery(a)
            | C::FrfQuery(a)
            | C::SvoQuery(a)
            | C::RonQuery(a)
            | C::VelQuery(a)
            | C::AccQuery(a)
            | C::DecQuery(a) => self.query_axes(now, cmd, a),
            C::SpaQuery(items) => self.query_parameters(items).map(Some),
            C::Svo(items) => self.set_servo(now, items).map(|()| None),
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
            C::Mov(items) => self.move_to(now, items, false).map(|()| None),
            C::Mvr(items) => self.move_to(now, items, true).map(|()| None),
            C::Vel(items) => self.set_velocity(now, items).map(|()| None),
            C::Acc(items) => {
                let ids = (params::ACCELERATION, params::MAX_ACCELERATION);
                self.set_ramp(now, items, ids).map(|()| None)
            }
            C::Dec(items) => {
                let ids = (params::DECELERATION, params::MAX_DECELERATION);
                self.set_ramp(now, items, ids).map(|()| None)
            }
            C::Spa(items) => self.set_parameters(now, items).map(|()| None),
            C::Hlt(a) => self.halt(now, a).map(|()| None),
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

    /// The controller's identity, help and error queries (`ERR?` also
    /// clears the error, as on the controller).
    fn identify(&mut self, cmd: &Command) -> Vec<String> {
        use Command as C;
        match cmd {
            C::Idn => vec![format!("{VENDOR}, {MODEL}, {}, {FIRMWARE}", self.serial)],
            C::Csv => vec!["2.0".to_owned()],
            C::Err => {
                let e = self.error;
                self.error = E::NO_ERROR;
                vec![e.0.to_string()]
            }
            C::Hlp => {
                let mut lines = vec!["The following commands are valid:".to_owned()];
                lines.extend(HELP.iter().map(|(c, d)| format!("{c} {d}")));
                lines.push("end of help".to_owned());
                lines
            }
            C::Hpa => params::hpa_lines(),
            C::Ver => vec![
                format!("FW_ARM: V{FIRMWARE}"),
                format!(
                    "hil-sim: V{} (simulated controller)",
                    env!("CARGO_PKG_VERSION")
                ),
            ],
            // SAI?
            _ => vec![AXIS.to_owned()],
        }
    }

    /// The queries answered per axis (`AXIS=value` lines).
    fn query_axes(
        &self,
        now: Duration,
        cmd: &Command,
        a: &[AxisId],
    ) -> Result<Option<Vec<String>>, E> {
        use Command as C;
        let number = |id, default| num7(self.params.number(id, default));
        let value = match cmd {
            C::CstQuery(_) => self
                .params
                .get(params::STAGE_NAME)
                .map(ParamValue::to_text)
                .unwrap_or_default(),
            C::TmnQuery(_) => number(params::MAX_TRAVEL_NEG, 0.0),
            C::TmxQuery(_) => number(params::MAX_TRAVEL_POS, 15.0),
            C::PosQuery(_) => num7(self.encoder_mm(now)),
            C::MovQuery(_) => num7(self.target_mm),
            C::OntQuery(_) => bool01(self.on_target(now)),
            C::FrfQuery(_) => bool01(self.is_referenced(now)),
            C::SvoQuery(_) => bool01(self.servo),
            C::RonQuery(_) => bool01(self.reference_mode),
            C::VelQuery(_) => number(params::VELOCITY, 1.0),
            C::AccQuery(_) => number(params::ACCELERATION, 10.0),
            // DEC?
            _ => number(params::DECELERATION, 10.0),
        };
        Self::per_axis(a, || value.clone())
    }

    /// `SPA?`: the parameters asked for, or every one without arguments.
    fn query_parameters(&self, items: &[(AxisId, u32)]) -> Result<Vec<String>, E> {
        if items.is_empty() {
            return Ok(self
                .params
                .iter()
                .map(|(id, v)| format!("{AXIS} 0x{id:X}={}", v.to_text()))
                .collect());
        }
        let mut out = Vec::new();
        for (a, id) in items {
            Self::check_axis(a)?;
            let v = self.params.get(*id).ok_or(E::UNKNOWN_PARAMETER)?;
            out.push(format!("{a} 0x{id:X}={}", v.to_text()));
        }
        Ok(out)
    }

    /// `SVO`: closing the loop holds the current position; opening it
    /// leaves the motor undriven (and ends a reference move unreferenced).
    fn set_servo(&mut self, now: Duration, items: &[(AxisId, bool)]) -> Result<(), E> {
        for (a, _) in items {
            Self::check_axis(a)?;
        }
        for (_, on) in items {
            if *on && !self.servo {
                self.encoder_mm = self.encoder_mm(now);
                self.target_mm = self.encoder_mm;
                self.settled_at = now;
            } else if !*on && self.servo {
                let (p, _) = self.state_at(now);
                if matches!(self.activity, Activity::Referencing { .. }) {
                    self.referenced = false;
                }
                self.encoder_mm = p;
                self.activity = Activity::Idle;
            }
            self.servo = *on;
        }
        Ok(())
    }

    /// `MOV` (`relative`: `MVR`): every target is checked before anything
    /// moves.
    fn move_to(&mut self, now: Duration, items: &[(AxisId, f64)], relative: bool) -> Result<(), E> {
        for (a, _) in items {
            Self::check_axis(a)?;
        }
        self.check_move_allowed(now)?;
        let mut target = self.target_mm;
        for (_, v) in items {
            target = if relative { target + v } else { *v };
            self.check_limits(target)?;
        }
        self.start_move(now, target);
        self.recorder.on_move(now);
        Ok(())
    }

    /// `VEL`: within (0, the maximum velocity]; a move under way is
    /// replanned.
    fn set_velocity(&mut self, now: Duration, items: &[(AxisId, f64)]) -> Result<(), E> {
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
        Ok(())
    }

    /// `ACC` or `DEC` (`ids`: the parameter and its maximum's).
    fn set_ramp(
        &mut self,
        now: Duration,
        items: &[(AxisId, f64)],
        ids: (u32, u32),
    ) -> Result<(), E> {
        let (id, max_id) = ids;
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
        Ok(())
    }

    /// `SPA`: every value parsed before any is set.
    fn set_parameters(&mut self, now: Duration, items: &[(AxisId, u32, String)]) -> Result<(), E> {
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
        Ok(())
    }

    /// `HLT`: a move or a reference move brakes at the deceleration (a
    /// reference move ends unreferenced); the error becomes "stopped".
    fn halt(&mut self, now: Duration, a: &[AxisId]) -> Result<(), E> {
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
        Ok(())
    }

    /// The commands `HLP?` lists (without descriptions).
    pub fn help_commands() -> impl Iterator<Item = &'static str> {
        HELP.iter().map(|(c, _)| *c)
    }
}
