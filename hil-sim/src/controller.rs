//! One simulated Mercury C-863.11 with an M-111.1DG stage, as a sans-IO
//! state machine.
//!
//! Inputs are decoded [`Request`]s plus the simulated time; outputs are the
//! answer bytes (or nothing). There is no tick: motion and referencing are
//! planned when a command starts them and evaluated in closed form whenever a
//! later request (or the test harness) asks, so simulated time can run at any
//! speed.
//!
//! # Frames of reference
//! - *actuator position* (mm): where the motor/leadscrew has physically put
//!   the carriage, measured from the stage's negative hard limit. The stage's
//!   switches sit at fixed actuator positions ([`StageGeometry`]).
//! - *encoder position* (mm): what the controller counts and reports (`POS?`).
//!   `actuator = encoder + offset`. At power-up the encoder reads 0 wherever
//!   the carriage is; referencing sets the offset so that the encoder reads
//!   parameter 0x16 (7.5 mm) at the reference switch.
//! - *true platform position* (mm): where the platform really is. A
//!   [`Platform`] maps actuator to platform position; today it is the
//!   identity ([`IdealPlatform`]), later issues put a stage error model there.
//!
//! # Status register (`#4`), bit layout used here (C-863 `SRG?` layout)
//! | bit | meaning |
//! |-----|---------|
//! | 0   | negative limit switch active |
//! | 1   | reference switch signal (high on the positive side of the switch) |
//! | 2   | positive limit switch active |
//! | 8   | error flag (an error code is pending for `ERR?`) |
//! | 12  | servo on |
//! | 13  | in motion (a move or a referencing move is running) |
//! | 14  | referencing in progress |
//! | 15  | on target |

use crate::motion::{Limits, Profile};
use crate::params::{self, ParamSet, ParamValue, ValueError};
use micropos::gcs::frame::{encode_answer, Request};
use micropos::gcs::{Address, AxisId, Command, ControlChar, GcsErrorCode as E};
use std::fmt;
use std::time::Duration;

/// The firmware version a C-863.11 of the simulated vintage reports.
pub const FIRMWARE: &str = "01.110";
/// Manufacturer field of `*IDN?`.
pub const VENDOR: &str = "(c)2015 Physik Instrumente (PI) GmbH & Co. KG";
/// Model field of `*IDN?`.
pub const MODEL: &str = "C-863.11";
/// Time from the end of a motion profile until `ONT?` reports on target: the
/// servo loop settling inside its on-target window.
pub const SETTLE_TIME: Duration = Duration::from_millis(50);
/// Time a referencing move spends at the switch finding its edge (slow
/// approach, reverse, slow approach) after the fast move to it.
pub const EDGE_SEARCH_TIME: Duration = Duration::from_millis(1500);

/// The one axis identifier of a C-863 (single-axis controller).
const AXIS: &str = "1";

/// Physical switch positions of the stage, in actuator coordinates (mm).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StageGeometry {
    /// Negative limit switch.
    pub negative_limit_mm: f64,
    /// Reference switch (direction-sensing: high on its positive side).
    pub reference_mm: f64,
    /// Positive limit switch.
    pub positive_limit_mm: f64,
}

impl Default for StageGeometry {
    /// An M-111.1DG: 15 mm travel, reference switch at mid travel.
    fn default() -> Self {
        Self {
            negative_limit_mm: 0.0,
            reference_mm: 7.5,
            positive_limit_mm: 15.0,
        }
    }
}

/// Where the platform really is, given where the actuator put it.
///
/// This is the seam for the stage error model: the controller only ever
/// knows its encoder; tests and the simulated camera ask the platform.
pub trait Platform: Send + fmt::Debug {
    /// True platform position (mm) for actuator position `actuator_mm` at
    /// simulated time `now`.
    fn platform_position_mm(&self, actuator_mm: f64, now: Duration) -> f64;
}

/// A perfect stage: the platform is exactly where the actuator is.
#[derive(Debug, Clone, Copy, Default)]
pub struct IdealPlatform;

impl Platform for IdealPlatform {
    fn platform_position_mm(&self, actuator_mm: f64, _now: Duration) -> f64 {
        actuator_mm
    }
}

/// How a controller is built.
#[derive(Debug)]
pub struct ControllerConfig {
    /// Daisy-chain address (DIP switches), 1 when alone on a line.
    pub address: Address,
    /// Serial number reported by `*IDN?`.
    pub serial: String,
    /// Actuator position at the first power-up (mm): the carriage is
    /// wherever it was left, the controller does not know where.
    pub initial_actuator_mm: f64,
    /// Switch positions.
    pub stage: StageGeometry,
    /// Actuator → platform mapping.
    pub platform: Box<dyn Platform>,
}

impl ControllerConfig {
    /// A controller at `address` with an ideal M-111.1DG whose carriage
    /// starts at `initial_actuator_mm`.
    pub fn new(address: Address, serial: &str, initial_actuator_mm: f64) -> Self {
        Self {
            address,
            serial: serial.to_owned(),
            initial_actuator_mm,
            stage: StageGeometry::default(),
            platform: Box::new(IdealPlatform),
        }
    }
}

/// Which switch a referencing move goes to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RefKind {
    /// `FRF`: the reference switch.
    Reference,
    /// `FNL`: the negative limit switch.
    NegativeLimit,
    /// `FPL`: the positive limit switch.
    PositiveLimit,
}

#[derive(Debug, Clone, PartialEq)]
enum Activity {
    Idle,
    Moving(Profile),
    Referencing {
        profile: Profile,
        done_at: Duration,
        kind: RefKind,
    },
}

/// The simulated controller.
#[derive(Debug)]
pub struct Controller {
    address: Address,
    serial: String,
    stage: StageGeometry,
    platform: Box<dyn Platform>,
    /// actuator = encoder + offset.
    offset_mm: f64,
    /// Encoder position when idle (mm).
    encoder_mm: f64,
    activity: Activity,
    target_mm: f64,
    servo: bool,
    referenced: bool,
    reference_mode: bool,
    error: E,
    settled_at: Duration,
    params: ParamSet,
    last_now: Duration,
}

/// Formats a number the way the C-863 answers positions: 7 decimals, no
/// negative zero.
fn num7(v: f64) -> String {
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
    ("ERR?", "Get Error Number"),
    ("FNL", "[{<AxisID>}] Fast Reference Move To Negative Limit"),
    ("FPL", "[{<AxisID>}] Fast Reference Move To Positive Limit"),
    (
        "FRF",
        "[{<AxisID>}] Fast Reference Move To Reference Switch",
    ),
    ("FRF?", "[{<AxisID>}] Get Referencing Result"),
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
    ("TMX?", "[{<AxisID>}] Get Maximum Commandable Position"),
    ("VEL", "{<AxisID> <Velocity>} Set Closed-Loop Velocity"),
    ("VEL?", "[{<AxisID>}] Get Closed-Loop Velocity"),
    ("VER?", "Get Versions Of Firmware And Drivers"),
];

impl Controller {
    /// A controller just powered up (servo off, unreferenced, encoder 0).
    pub fn new(cfg: ControllerConfig) -> Self {
        Self {
            address: cfg.address,
            serial: cfg.serial,
            stage: cfg.stage,
            platform: cfg.platform,
            offset_mm: cfg.initial_actuator_mm,
            encoder_mm: 0.0,
            activity: Activity::Idle,
            target_mm: 0.0,
            servo: false,
            referenced: false,
            reference_mode: true,
            error: E::NO_ERROR,
            settled_at: Duration::ZERO,
            params: ParamSet::default(),
            last_now: Duration::ZERO,
        }
    }

    /// Daisy-chain address.
    pub fn address(&self) -> Address {
        self.address
    }

    /// Serial number.
    pub fn serial(&self) -> &str {
        &self.serial
    }

    /// Replaces the platform model (the stage error model of later issues).
    pub fn set_platform(&mut self, platform: Box<dyn Platform>) {
        self.platform = platform;
    }

    /// Whether this controller takes a request with this address prefix
    /// (no prefix = address 1).
    pub fn accepts(&self, addr: Option<Address>) -> bool {
        addr.unwrap_or(Address::DEFAULT) == self.address
    }

    /// Power cycle: everything the controller knows is reset (servo off,
    /// unreferenced, encoder 0, no error, default parameters, motion cut);
    /// the carriage stays physically where it is.
    pub fn power_cycle(&mut self, now: Duration) {
        let now = self.tick(now);
        let actuator = self.actuator_mm(now);
        self.offset_mm = actuator;
        self.encoder_mm = 0.0;
        self.activity = Activity::Idle;
        self.target_mm = 0.0;
        self.servo = false;
        self.referenced = false;
        self.reference_mode = true;
        self.error = E::NO_ERROR;
        self.settled_at = now;
        self.params = ParamSet::default();
    }

    /// Encoder position (what `POS?` says) at `now`, in mm.
    pub fn encoder_mm(&self, now: Duration) -> f64 {
        self.state_at(now).0
    }

    /// Actuator position at `now` (mm from the negative hard limit).
    pub fn actuator_mm(&self, now: Duration) -> f64 {
        self.encoder_mm(now) + self.offset_mm
    }

    /// Ground truth: the true platform position at `now` (mm).
    pub fn true_position_mm(&self, now: Duration) -> f64 {
        let now = now.max(self.last_now);
        self.platform
            .platform_position_mm(self.actuator_mm(now), now)
    }

    /// The pending error code, without clearing it (for tests and logs).
    pub fn peek_error(&self) -> E {
        self.error
    }

    /// Whether a referencing move is running at `now`.
    pub fn is_referencing(&self, now: Duration) -> bool {
        matches!(&self.activity, Activity::Referencing { done_at, .. } if now < *done_at)
    }

    /// Whether the axis is moving at `now` (a move or referencing move).
    pub fn is_moving(&self, now: Duration) -> bool {
        match &self.activity {
            Activity::Idle => false,
            Activity::Moving(p) => !p.is_done(now),
            Activity::Referencing { done_at, .. } => now < *done_at,
        }
    }

    /// Whether `ONT?` reports on target at `now`.
    pub fn on_target(&self, now: Duration) -> bool {
        if !self.servo {
            return false;
        }
        match &self.activity {
            Activity::Idle => now >= self.settled_at,
            Activity::Moving(p) => now >= p.end_time() + SETTLE_TIME,
            Activity::Referencing { .. } => false,
        }
    }

    /// Whether the axis is referenced at `now`.
    pub fn is_referenced(&self, now: Duration) -> bool {
        match &self.activity {
            Activity::Referencing { done_at, .. } if now >= *done_at => true,
            _ => self.referenced,
        }
    }

    /// The `#4` status word at `now` (bit layout in the module docs).
    pub fn status_register(&self, now: Duration) -> u16 {
        let act = self.actuator_mm(now);
        let eps = 1e-9;
        let mut s = 0u16;
        if act <= self.stage.negative_limit_mm + eps {
            s |= 1;
        }
        if act > self.stage.reference_mm {
            s |= 1 << 1;
        }
        if act >= self.stage.positive_limit_mm - eps {
            s |= 1 << 2;
        }
        if !self.error.is_ok() {
            s |= 1 << 8;
        }
        if self.servo {
            s |= 1 << 12;
        }
        if self.is_moving(now) {
            s |= 1 << 13;
        }
        if self.is_referencing(now) {
            s |= 1 << 14;
        }
        if self.on_target(now) {
            s |= 1 << 15;
        }
        s
    }

    /// (encoder position, velocity) at `now`.
    fn state_at(&self, now: Duration) -> (f64, f64) {
        match &self.activity {
            Activity::Idle => (self.encoder_mm, 0.0),
            Activity::Moving(p) => p.state_at(now),
            Activity::Referencing {
                profile,
                done_at,
                kind,
            } => {
                if now >= *done_at {
                    (self.reference_value(*kind), 0.0)
                } else {
                    profile.state_at(now)
                }
            }
        }
    }

    /// Encoder value assigned at the switch a referencing move finds.
    fn reference_value(&self, kind: RefKind) -> f64 {
        let at_ref = self.params.number(params::VALUE_AT_REFERENCE, 7.5);
        match kind {
            RefKind::Reference => at_ref,
            RefKind::NegativeLimit => {
                at_ref - self.params.number(params::DIST_NEG_LIMIT_TO_REF, 7.5)
            }
            RefKind::PositiveLimit => {
                at_ref + self.params.number(params::DIST_REF_TO_POS_LIMIT, 7.5)
            }
        }
    }

    /// Brings finished activities to rest. Returns the (monotonic) time.
    fn tick(&mut self, now: Duration) -> Duration {
        let now = now.max(self.last_now);
        self.last_now = now;
        match &self.activity {
            Activity::Idle => {}
            Activity::Moving(p) => {
                if p.is_done(now) {
                    self.encoder_mm = p.end_mm();
                    self.settled_at = p.end_time() + SETTLE_TIME;
                    self.activity = Activity::Idle;
                }
            }
            Activity::Referencing {
                profile,
                done_at,
                kind,
            } => {
                if now >= *done_at {
                    let value = self.reference_value(*kind);
                    // The carriage stands at the switch; from now on the
                    // encoder reads `value` there.
                    let actuator = profile.end_mm() + self.offset_mm;
                    self.offset_mm = actuator - value;
                    self.encoder_mm = value;
                    self.target_mm = value;
                    self.referenced = true;
                    self.settled_at = *done_at + SETTLE_TIME;
                    self.activity = Activity::Idle;
                }
            }
        }
        now
    }

    fn set_error(&mut self, e: E) {
        // A C-863 keeps the first error until ERR? reads it.
        if self.error.is_ok() {
            self.error = e;
        }
    }

    fn limits(&self) -> Limits {
        Limits {
            velocity: self.params.number(params::VELOCITY, 1.0),
            acceleration: self.params.number(params::ACCELERATION, 10.0),
            deceleration: self.params.number(params::DECELERATION, 10.0),
        }
    }

    /// Handles one request at `now`; returns the answer bytes if this
    /// controller answers it. Requests for other addresses are ignored.
    pub fn handle(&mut self, now: Duration, req: &Request) -> Option<Vec<u8>> {
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
    fn axes(axes: &[AxisId]) -> Result<Vec<AxisId>, E> {
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

    /// STP / #24: stop at once (the motor is braked hard; the profile is cut).
    fn stop_now(&mut self, now: Duration) {
        let (p, _) = self.state_at(now);
        self.encoder_mm = p;
        if matches!(self.activity, Activity::Moving(_)) {
            self.target_mm = p;
        }
        if matches!(self.activity, Activity::Referencing { .. }) {
            self.referenced = false;
        }
        self.activity = Activity::Idle;
        self.settled_at = now + SETTLE_TIME;
        self.set_error(E::STOPPED);
    }

    /// Starts (or re-plans) a move to `target` from the current state.
    fn start_move(&mut self, now: Duration, target: f64) {
        let (p, v) = self.state_at(now);
        self.target_mm = target;
        self.activity = Activity::Moving(Profile::plan(now, p, v, target, self.limits()));
    }

    /// After VEL/ACC/DEC change while moving: continue to the same target
    /// with the new limits.
    fn replan(&mut self, now: Duration) {
        if let Activity::Moving(p) = &self.activity {
            if !p.is_done(now) {
                let t = self.target_mm;
                self.start_move(now, t);
            }
        }
    }

    fn check_move_allowed(&self, now: Duration) -> Result<(), E> {
        if !self.servo {
            return Err(E::UNREFERENCED_OR_SERVO_OFF);
        }
        if self.is_referencing(now) {
            return Err(E::UNREFERENCED_OR_SERVO_OFF);
        }
        if self.reference_mode && !self.referenced {
            return Err(E::UNREFERENCED_OR_SERVO_OFF);
        }
        Ok(())
    }

    fn check_limits(&self, target: f64) -> Result<(), E> {
        let lo = self.params.number(params::MAX_TRAVEL_NEG, 0.0);
        let hi = self.params.number(params::MAX_TRAVEL_POS, 15.0);
        // Targets are compared at the 0.1 nm resolution they are written in.
        let t = (target * 1e7).round() / 1e7;
        if t < lo || t > hi {
            Err(E::POS_OUT_OF_LIMITS)
        } else {
            Ok(())
        }
    }

    fn start_referencing(
        &mut self,
        now: Duration,
        axes: &[AxisId],
        kind: RefKind,
    ) -> Result<(), E> {
        Self::axes(axes)?;
        if !self.servo {
            return Err(E::UNREFERENCED_OR_SERVO_OFF);
        }
        if self.is_moving(now) {
            return Err(E::NOT_ALLOWED_WHILE_MOVING);
        }
        let switch_actuator = match kind {
            RefKind::Reference => self.stage.reference_mm,
            RefKind::NegativeLimit => self.stage.negative_limit_mm,
            RefKind::PositiveLimit => self.stage.positive_limit_mm,
        };
        let (p, v) = self.state_at(now);
        let limits = Limits {
            velocity: self.params.number(params::REFERENCE_VELOCITY, 0.5),
            ..self.limits()
        };
        let profile = Profile::plan(now, p, v, switch_actuator - self.offset_mm, limits);
        let done_at = profile.end_time() + EDGE_SEARCH_TIME;
        self.referenced = false;
        self.activity = Activity::Referencing {
            profile,
            done_at,
            kind,
        };
        Ok(())
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
                let (p, v) = self.state_at(now);
                match &self.activity {
                    Activity::Idle => {}
                    Activity::Moving(_) | Activity::Referencing { .. } => {
                        if matches!(self.activity, Activity::Referencing { .. }) {
                            self.referenced = false;
                        }
                        let dec = self.limits().deceleration;
                        let profile = Profile::brake(now, p, v, dec);
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
        }
    }

    /// The commands `HLP?` lists (without descriptions).
    pub fn help_commands() -> impl Iterator<Item = &'static str> {
        HELP.iter().map(|(c, _)| *c)
    }
}
