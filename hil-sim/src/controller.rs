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

    /// The controller has a new actuator trajectory (a move, a referencing
    /// move, a stop, a power cycle), planned at `now`. A platform with
    /// history or 2-D coupling (the shared rig of `crate::rig`) needs the
    /// whole path, not just positions at query times: a move must be
    /// committed to the stage model when it settles even if nobody asks
    /// then. Stateless platforms ignore it.
    fn actuator_path(&mut self, path: &ActuatorPath, now: Duration) {
        let _ = (path, now);
    }
}

/// Where the actuator goes from now on: a motion profile (in encoder mm)
/// plus the encoder-to-actuator offset, or rest at an encoder position.
#[derive(Debug, Clone, PartialEq)]
pub struct ActuatorPath {
    /// actuator = encoder + offset_mm along this path.
    pub offset_mm: f64,
    /// The motion, or `None` when the carriage is at rest.
    pub profile: Option<Profile>,
    /// Encoder position at rest (used when `profile` is `None`).
    pub rest_encoder_mm: f64,
}

impl ActuatorPath {
    /// Actuator position (mm) at `now`.
    pub fn actuator_mm(&self, now: Duration) -> f64 {
        match &self.profile {
            Some(p) => p.state_at(now).0 + self.offset_mm,
            None => self.rest_encoder_mm + self.offset_mm,
        }
    }

    /// Where the actuator comes to rest (mm).
    pub fn final_actuator_mm(&self) -> f64 {
        match &self.profile {
            Some(p) => p.end_mm() + self.offset_mm,
            None => self.rest_encoder_mm + self.offset_mm,
        }
    }

    /// When the carriage stops (`None`: it is at rest already).
    pub fn end_time(&self) -> Option<Duration> {
        self.profile.as_ref().map(Profile::end_time)
    }
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
    /// The last path told to the platform.
    reported: Option<ActuatorPath>,
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
            reported: None,
        }
    }

    /// The actuator path of the current activity.
    pub fn actuator_path(&self) -> ActuatorPath {
        let profile = match &self.activity {
            Activity::Idle => None,
            Activity::Moving(p) => Some(p.clone()),
            Activity::Referencing { profile, .. } => Some(profile.clone()),
        };
        ActuatorPath {
            offset_mm: self.offset_mm,
            profile,
            rest_encoder_mm: self.encoder_mm,
        }
    }

    /// Reports the current path to the platform (at power-up, once the
    /// platform is shared).
    pub fn power_up_report(&mut self) {
        self.reported = None;
        let now = self.last_now;
        self.sync_platform(now);
    }

    /// Tells the platform about a changed actuator path.
    fn sync_platform(&mut self, now: Duration) {
        let p = self.actuator_path();
        if self.reported.as_ref() != Some(&p) {
            self.platform.actuator_path(&p, now);
            self.reported = Some(p);
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
        self.reported = None;
        let now = self.last_now;
        self.sync_platform(now);
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
        self.sync_platform(now);
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

#[cfg(test)]
mod tests {
    use super::*;
    use micropos::gcs::frame::RequestDecoder;
    use proptest::prelude::*;

    fn s(v: f64) -> Duration {
        Duration::from_secs_f64(v)
    }

    fn ctl(initial: f64) -> Controller {
        Controller::new(ControllerConfig::new(
            Address::DEFAULT,
            "0115500001",
            initial,
        ))
    }

    /// Sends a line at time `t`; returns the answer text (None = silence).
    fn q(c: &mut Controller, t: f64, line: &str) -> Option<String> {
        let mut d = RequestDecoder::new();
        let reqs = d.push(format!("{line}\n").as_bytes());
        assert_eq!(reqs.len(), 1);
        c.handle(s(t), &reqs[0])
            .map(|b| micropos::gcs::frame::bytes_to_text(&b))
    }

    fn err(c: &mut Controller, t: f64) -> i32 {
        q(c, t, "ERR?").unwrap().trim().parse().unwrap()
    }

    fn pos(c: &mut Controller, t: f64) -> f64 {
        let a = q(c, t, "POS? 1").unwrap();
        a.trim().strip_prefix("1=").unwrap().parse().unwrap()
    }

    fn ctrl(c: &mut Controller, t: f64, b: u8) -> Option<Vec<u8>> {
        let mut d = RequestDecoder::new();
        let reqs = d.push(&[b]);
        c.handle(s(t), &reqs[0])
    }

    /// Servo on, FRF, wait until referenced; returns the time it finished.
    fn referenced(c: &mut Controller) -> f64 {
        assert_eq!(q(c, 0.0, "SVO 1 1"), None);
        assert_eq!(q(c, 0.0, "FRF 1"), None);
        let mut t = 0.0;
        while q(c, t, "FRF? 1").unwrap() != "1=1\n" {
            t += 0.1;
            assert!(t < 60.0);
        }
        assert_eq!(err(c, t), 0);
        t
    }

    #[test]
    fn identification_and_fixed_answers() {
        let mut c = ctl(3.0);
        assert_eq!(
            q(&mut c, 0.0, "*IDN?").unwrap(),
            "(c)2015 Physik Instrumente (PI) GmbH & Co. KG, C-863.11, 0115500001, 01.110\n"
        );
        assert_eq!(q(&mut c, 0.0, "CSV?").unwrap(), "2.0\n");
        assert_eq!(q(&mut c, 0.0, "SAI?").unwrap(), "1\n");
        assert_eq!(q(&mut c, 0.0, "SAI? ALL").unwrap(), "1\n");
        assert_eq!(q(&mut c, 0.0, "TMN? 1").unwrap(), "1=0.0000000\n");
        assert_eq!(q(&mut c, 0.0, "TMX? 1").unwrap(), "1=15.0000000\n");
        assert_eq!(q(&mut c, 0.0, "TMX?").unwrap(), "1=15.0000000\n");
        assert_eq!(q(&mut c, 0.0, "CST? 1").unwrap(), "1=M-111.1DG\n");
        assert_eq!(q(&mut c, 0.0, "VEL? 1").unwrap(), "1=1.0000000\n");
        assert_eq!(q(&mut c, 0.0, "ACC? 1").unwrap(), "1=10.0000000\n");
        assert_eq!(q(&mut c, 0.0, "DEC? 1").unwrap(), "1=10.0000000\n");
        assert_eq!(q(&mut c, 0.0, "RON? 1").unwrap(), "1=1\n");
        let ver = q(&mut c, 0.0, "VER?").unwrap();
        assert!(ver.starts_with("FW_ARM: V01.110 \n"), "{ver:?}");
        assert_eq!(err(&mut c, 0.0), 0);
    }

    #[test]
    fn power_up_state() {
        let mut c = ctl(3.0);
        assert_eq!(q(&mut c, 0.0, "SVO? 1").unwrap(), "1=0\n");
        assert_eq!(q(&mut c, 0.0, "FRF? 1").unwrap(), "1=0\n");
        assert_eq!(q(&mut c, 0.0, "POS? 1").unwrap(), "1=0.0000000\n");
        assert_eq!(q(&mut c, 0.0, "ONT? 1").unwrap(), "1=0\n");
        assert_eq!(c.true_position_mm(s(0.0)), 3.0);
        assert_eq!(ctrl(&mut c, 0.0, 7).unwrap(), vec![0xB1, b'\n']);
        assert_eq!(ctrl(&mut c, 0.0, 5).unwrap(), b"0\n");
        // Carriage at 3.0 < reference switch at 7.5: no switch bits.
        assert_eq!(ctrl(&mut c, 0.0, 4).unwrap(), b"0x0\n");
    }

    #[test]
    fn help_lists_exactly_what_parses() {
        let mut c = ctl(3.0);
        let hlp = q(&mut c, 0.0, "HLP?").unwrap();
        let lines: Vec<&str> = hlp.lines().collect();
        assert!(lines.len() > 30);
        // Multi-line framing: every line but the last ends with a space.
        for l in &lines[..lines.len() - 1] {
            assert!(l.ends_with(' '), "{l:?}");
        }
        assert!(!lines.last().unwrap().ends_with(' '));
        for cmd in Controller::help_commands().filter(|c| !c.starts_with('#')) {
            if let Err(micropos::gcs::CommandError::Unknown(_)) = Command::parse(cmd) {
                panic!("{cmd} listed but unknown");
            }
        }
        let hpa = q(&mut c, 0.0, "HPA?").unwrap();
        assert!(
            hpa.contains("0x3C=\t0\t1\tCHAR\tstage\tStage_Name"),
            "{hpa}"
        );
        assert_eq!(err(&mut c, 0.0), 0);
    }

    #[test]
    fn referencing_takes_time_and_sets_position() {
        let mut c = ctl(3.0);
        // FRF needs the servo.
        assert_eq!(q(&mut c, 0.0, "FRF 1"), None);
        assert_eq!(err(&mut c, 0.0), 5);
        assert_eq!(q(&mut c, 0.0, "SVO 1 1"), None);
        assert_eq!(q(&mut c, 0.0, "FRF 1"), None);
        assert_eq!(err(&mut c, 0.0), 0);
        // 4.5 mm at 0.5 mm/s (plus ramps) and 1.5 s edge search.
        assert_eq!(ctrl(&mut c, 1.0, 7).unwrap(), vec![0xB0, b'\n']);
        assert_eq!(ctrl(&mut c, 1.0, 5).unwrap(), b"1\n");
        let sr = u16::from_str_radix(
            std::str::from_utf8(&ctrl(&mut c, 1.0, 4).unwrap())
                .unwrap()
                .trim()
                .trim_start_matches("0x"),
            16,
        )
        .unwrap();
        assert_eq!(sr & (1 << 14), 1 << 14, "referencing bit");
        assert_eq!(sr & (1 << 13), 1 << 13, "motion bit");
        assert_eq!(sr & (1 << 15), 0, "not on target");
        assert_eq!(q(&mut c, 1.0, "FRF? 1").unwrap(), "1=0\n");
        assert_eq!(q(&mut c, 1.0, "ONT? 1").unwrap(), "1=0\n");
        // Halfway the carriage moves towards the switch.
        assert!(c.true_position_mm(s(5.0)) > 3.0 && c.true_position_mm(s(5.0)) < 7.5);
        let expected = 4.5 / 0.5 + 0.5 / 10.0 + EDGE_SEARCH_TIME.as_secs_f64();
        assert_eq!(q(&mut c, expected - 0.01, "FRF? 1").unwrap(), "1=0\n");
        assert_eq!(q(&mut c, expected + 0.01, "FRF? 1").unwrap(), "1=1\n");
        assert_eq!(ctrl(&mut c, expected + 0.01, 7).unwrap(), vec![0xB1, b'\n']);
        assert_eq!(pos(&mut c, expected + 0.01), 7.5);
        assert_eq!(c.true_position_mm(s(expected + 0.01)), 7.5);
        assert_eq!(q(&mut c, expected + 0.1, "ONT? 1").unwrap(), "1=1\n");
        assert_eq!(
            q(&mut c, expected + 0.1, "MOV? 1").unwrap(),
            "1=7.5000000\n"
        );
    }

    #[test]
    fn limit_referencing() {
        let mut c = ctl(3.0);
        q(&mut c, 0.0, "SVO 1 1");
        q(&mut c, 0.0, "FNL 1");
        assert_eq!(q(&mut c, 100.0, "FRF? 1").unwrap(), "1=1\n");
        assert_eq!(pos(&mut c, 100.0), 0.0);
        assert_eq!(c.true_position_mm(s(100.0)), 0.0);
        assert_eq!(ctrl(&mut c, 100.0, 4).unwrap(), b"0x9001\n");
        q(&mut c, 100.0, "FPL");
        assert_eq!(q(&mut c, 100.5, "FRF? 1").unwrap(), "1=0\n");
        assert_eq!(q(&mut c, 200.0, "FRF? 1").unwrap(), "1=1\n");
        assert_eq!(pos(&mut c, 200.0), 15.0);
        assert_eq!(ctrl(&mut c, 200.0, 4).unwrap(), b"0x9006\n");
        assert_eq!(err(&mut c, 200.0), 0);
    }

    #[test]
    fn reference_value_parameter_shifts_the_encoder() {
        let mut c = ctl(3.0);
        q(&mut c, 0.0, "SPA 1 0x16 10");
        q(&mut c, 0.0, "SVO 1 1");
        q(&mut c, 0.0, "FRF 1");
        assert_eq!(pos(&mut c, 100.0), 10.0);
        assert_eq!(c.true_position_mm(s(100.0)), 7.5);
        q(&mut c, 100.0, "MOV 1 11");
        assert!((c.true_position_mm(s(200.0)) - 8.5).abs() < 1e-12);
    }

    #[test]
    fn trapezoidal_move_timing() {
        let mut c = ctl(3.0);
        let t0 = referenced(&mut c);
        assert_eq!(q(&mut c, t0, "MOV 1 9.5"), None);
        assert_eq!(q(&mut c, t0, "MOV? 1").unwrap(), "1=9.5000000\n");
        // 2 mm at 1 mm/s with 10 mm/s² ramps: 0.1 s + 1.9 s + 0.1 s.
        let mid = pos(&mut c, t0 + 1.0);
        assert!((mid - (7.5 + 0.05 + 0.9)).abs() < 1e-6, "{mid}");
        assert_eq!(ctrl(&mut c, t0 + 1.0, 5).unwrap(), b"1\n");
        assert_eq!(q(&mut c, t0 + 1.0, "ONT? 1").unwrap(), "1=0\n");
        assert_eq!(ctrl(&mut c, t0 + 1.0, 7).unwrap(), vec![0xB1, b'\n']);
        assert_eq!(pos(&mut c, t0 + 2.1), 9.5);
        assert_eq!(ctrl(&mut c, t0 + 2.11, 5).unwrap(), b"0\n");
        // Settling: on target 50 ms after the profile ends.
        assert_eq!(q(&mut c, t0 + 2.12, "ONT? 1").unwrap(), "1=0\n");
        assert_eq!(q(&mut c, t0 + 2.16, "ONT? 1").unwrap(), "1=1\n");
        assert_eq!(c.true_position_mm(s(t0 + 3.0)), 9.5);
    }

    #[test]
    fn relative_moves_add_to_the_target() {
        let mut c = ctl(3.0);
        let t0 = referenced(&mut c);
        q(&mut c, t0, "MVR 1 1.25");
        // A second MVR during the move adds to the commanded target.
        q(&mut c, t0 + 0.2, "MVR 1 -0.5");
        assert_eq!(q(&mut c, t0 + 0.2, "MOV? 1").unwrap(), "1=8.2500000\n");
        assert!((pos(&mut c, t0 + 10.0) - 8.25).abs() < 1e-12);
        q(&mut c, t0 + 10.0, "MVR 1 7");
        assert_eq!(err(&mut c, t0 + 10.0), 7);
        assert_eq!(q(&mut c, t0 + 10.0, "MOV? 1").unwrap(), "1=8.2500000\n");
    }

    #[test]
    fn velocity_and_ramps() {
        let mut c = ctl(3.0);
        let t0 = referenced(&mut c);
        q(&mut c, t0, "VEL 1 0.5");
        assert_eq!(q(&mut c, t0, "VEL? 1").unwrap(), "1=0.5000000\n");
        assert_eq!(q(&mut c, t0, "SPA? 1 0x49").unwrap(), "1 0x49=0.500000\n");
        q(&mut c, t0, "ACC 1 5");
        q(&mut c, t0, "DEC 1 2.5");
        assert_eq!(q(&mut c, t0, "ACC? 1").unwrap(), "1=5.0000000\n");
        assert_eq!(q(&mut c, t0, "DEC?").unwrap(), "1=2.5000000\n");
        q(&mut c, t0, "MOV 1 8.5");
        // 1 mm: accel 0.1 s (0.025 mm), brake 0.2 s (0.05 mm), cruise 1.85 s.
        assert!(pos(&mut c, t0 + 2.1) < 8.5);
        assert_eq!(pos(&mut c, t0 + 2.16), 8.5);
        // Changing VEL mid-move re-plans to the same target.
        q(&mut c, t0 + 3.0, "MOV 1 12.5");
        q(&mut c, t0 + 4.0, "VEL 1 1.5");
        let before = pos(&mut c, t0 + 5.0);
        let after = pos(&mut c, t0 + 6.0);
        assert!((after - before - 1.5).abs() < 1e-9, "{before} {after}");
        assert_eq!(pos(&mut c, t0 + 20.0), 12.5);
        // Out of range values are refused and leave the setting alone.
        for (cmd, code) in [
            ("VEL 1 2", 8),
            ("VEL 1 0", 8),
            ("VEL 1 -1", 8),
            ("ACC 1 0", 17),
            ("DEC 1 100", 17),
        ] {
            q(&mut c, t0 + 20.0, cmd);
            assert_eq!(err(&mut c, t0 + 20.0), code, "{cmd}");
        }
        assert_eq!(q(&mut c, t0 + 20.0, "VEL? 1").unwrap(), "1=1.5000000\n");
    }

    #[test]
    fn soft_limits_refuse_and_nothing_moves() {
        let mut c = ctl(3.0);
        let t0 = referenced(&mut c);
        q(&mut c, t0, "MOV 1 15.0001");
        assert_eq!(err(&mut c, t0), 7);
        q(&mut c, t0, "MOV 1 -0.1");
        assert_eq!(err(&mut c, t0), 7);
        assert_eq!(ctrl(&mut c, t0 + 0.1, 5).unwrap(), b"0\n");
        assert_eq!(pos(&mut c, t0 + 1.0), 7.5);
        assert_eq!(q(&mut c, t0, "MOV? 1").unwrap(), "1=7.5000000\n");
        // Exactly on the limits is fine.
        q(&mut c, t0, "MOV 1 15");
        assert_eq!(err(&mut c, t0), 0);
        assert_eq!(pos(&mut c, t0 + 20.0), 15.0);
        q(&mut c, t0 + 20.0, "MOV 1 0");
        assert_eq!(err(&mut c, t0 + 20.0), 0);
        // Limits follow the parameters.
        q(&mut c, t0 + 40.0, "SPA 1 0x15 10");
        assert_eq!(q(&mut c, t0 + 40.0, "TMX? 1").unwrap(), "1=10.0000000\n");
        q(&mut c, t0 + 40.0, "MOV 1 11");
        assert_eq!(err(&mut c, t0 + 40.0), 7);
    }

    #[test]
    fn moves_need_reference_and_servo() {
        let mut c = ctl(3.0);
        q(&mut c, 0.0, "MOV 1 1");
        assert_eq!(err(&mut c, 0.0), 5);
        q(&mut c, 0.0, "SVO 1 1");
        q(&mut c, 0.0, "MVR 1 1");
        assert_eq!(err(&mut c, 0.0), 5);
        // With reference mode off, an unreferenced axis may move.
        q(&mut c, 0.0, "RON 1 0");
        assert_eq!(q(&mut c, 0.0, "RON? 1").unwrap(), "1=0\n");
        q(&mut c, 0.0, "MOV 1 1");
        assert_eq!(err(&mut c, 0.0), 0);
        assert_eq!(pos(&mut c, 10.0), 1.0);
        assert_eq!(c.true_position_mm(s(10.0)), 4.0);
        q(&mut c, 10.0, "SVO 1 0");
        q(&mut c, 10.0, "MOV 1 2");
        assert_eq!(err(&mut c, 10.0), 5);
    }

    #[test]
    fn servo_off_cuts_motion() {
        let mut c = ctl(3.0);
        let t0 = referenced(&mut c);
        q(&mut c, t0, "MOV 1 12");
        q(&mut c, t0 + 1.0, "SVO 1 0");
        let p = pos(&mut c, t0 + 1.0);
        assert_eq!(pos(&mut c, t0 + 5.0), p);
        assert_eq!(ctrl(&mut c, t0 + 5.0, 5).unwrap(), b"0\n");
        // Reference survives servo off (incremental encoder keeps counting).
        assert_eq!(q(&mut c, t0 + 5.0, "FRF? 1").unwrap(), "1=1\n");
        q(&mut c, t0 + 5.0, "SVO 1 1");
        assert_eq!(
            q(&mut c, t0 + 5.0, "MOV? 1").unwrap(),
            format!("1={}\n", num7(p))
        );
        assert_eq!(q(&mut c, t0 + 5.0, "ONT? 1").unwrap(), "1=1\n");
    }

    #[test]
    fn halt_decelerates_stop_is_immediate() {
        let mut c = ctl(3.0);
        let t0 = referenced(&mut c);
        q(&mut c, t0, "MOV 1 12");
        q(&mut c, t0 + 1.0, "HLT 1");
        let p = pos(&mut c, t0 + 1.0);
        // Braking from 1 mm/s at 10 mm/s²: 0.05 mm further in 0.1 s.
        assert_eq!(ctrl(&mut c, t0 + 1.05, 5).unwrap(), b"1\n");
        assert!((pos(&mut c, t0 + 2.0) - (p + 0.05)).abs() < 1e-9);
        assert_eq!(err(&mut c, t0 + 2.0), 10);
        assert_eq!(
            q(&mut c, t0 + 2.0, "MOV? 1").unwrap(),
            format!("1={}\n", num7(p + 0.05))
        );
        q(&mut c, t0 + 2.0, "MOV 1 12");
        q(&mut c, t0 + 3.0, "STP");
        let p = pos(&mut c, t0 + 3.0);
        assert_eq!(pos(&mut c, t0 + 3.5), p);
        assert_eq!(err(&mut c, t0 + 3.5), 10);
        q(&mut c, t0 + 3.5, "MOV 1 12");
        assert_eq!(ctrl(&mut c, t0 + 4.0, 24), None);
        let p = pos(&mut c, t0 + 4.0);
        assert_eq!(pos(&mut c, t0 + 5.0), p);
        assert_eq!(err(&mut c, t0 + 5.0), 10);
        // Stopping while idle still reports the stop.
        q(&mut c, t0 + 5.0, "HLT");
        assert_eq!(err(&mut c, t0 + 5.0), 10);
    }

    #[test]
    fn stop_during_referencing_leaves_unreferenced() {
        let mut c = ctl(3.0);
        q(&mut c, 0.0, "SVO 1 1");
        q(&mut c, 0.0, "FRF 1");
        ctrl(&mut c, 1.0, 24);
        assert_eq!(q(&mut c, 100.0, "FRF? 1").unwrap(), "1=0\n");
        assert_eq!(ctrl(&mut c, 100.0, 7).unwrap(), vec![0xB1, b'\n']);
        assert_eq!(err(&mut c, 100.0), 10);
        // Referencing again while already moving is refused.
        q(&mut c, 100.0, "FRF 1");
        q(&mut c, 101.0, "FRF 1");
        assert_eq!(err(&mut c, 101.0), 307);
        q(&mut c, 101.0, "HLT 1");
        assert_eq!(q(&mut c, 200.0, "FRF? 1").unwrap(), "1=0\n");
    }

    #[test]
    fn errors_first_sticks_and_read_clears() {
        let mut c = ctl(3.0);
        assert_eq!(q(&mut c, 0.0, "FOO 1"), None);
        assert_eq!(q(&mut c, 0.0, "POS? 2"), None);
        assert_eq!(err(&mut c, 0.0), 2);
        assert_eq!(err(&mut c, 0.0), 0);
        for (line, code) in [
            ("XYZ?", 2),
            ("pos? 1", 2),
            ("POS? 2", 15),
            ("POS? A", 15),
            ("MOV 1", 24),
            ("MOV 1 abc", 1),
            ("SVO 1 2", 1),
            ("*IDN? 1", 24),
            ("SPA? 1 0x999", 54),
            ("SPA 1 0x999 1", 54),
            ("SPA 1 0x49 fast", 1),
            ("SPA 1 0x49 0", 17),
            ("SPA 2 0x49 1", 15),
        ] {
            assert_eq!(q(&mut c, 0.0, line), None, "{line}");
            assert_eq!(err(&mut c, 0.0), code, "{line}");
        }
        assert_eq!(c.handle(s(0.0), &Request::Overlong), None);
        assert_eq!(err(&mut c, 0.0), 3);
        // The error flag shows in the status register.
        q(&mut c, 0.0, "FOO");
        let sr = ctrl(&mut c, 0.0, 4).unwrap();
        assert_eq!(sr, b"0x100\n");
    }

    #[test]
    fn parameters_read_and_write() {
        let mut c = ctl(3.0);
        assert_eq!(
            q(&mut c, 0.0, "SPA? 1 0x3C 1 0x15").unwrap(),
            "1 0x3C=M-111.1DG \n1 0x15=15.000000\n"
        );
        let all = q(&mut c, 0.0, "SPA?").unwrap();
        assert_eq!(all.lines().count(), crate::params::PARAMS.len());
        q(&mut c, 0.0, "SPA 1 0x3C NOSTAGE 1 0x1 120");
        assert_eq!(q(&mut c, 0.0, "CST? 1").unwrap(), "1=NOSTAGE\n");
        assert_eq!(q(&mut c, 0.0, "SPA? 1 1").unwrap(), "1 0x1=120\n");
        // A bad item refuses the whole command.
        q(&mut c, 0.0, "SPA 1 0x1 7 1 0x999 1");
        assert_eq!(err(&mut c, 0.0), 54);
        assert_eq!(q(&mut c, 0.0, "SPA? 1 1").unwrap(), "1 0x1=120\n");
    }

    #[test]
    fn power_cycle_resets_but_carriage_stays() {
        let mut c = ctl(3.0);
        let t0 = referenced(&mut c);
        q(&mut c, t0, "VEL 1 1.5");
        q(&mut c, t0, "MOV 1 12");
        q(&mut c, t0, "FOO");
        c.power_cycle(s(t0 + 1.0));
        let truth = c.true_position_mm(s(t0 + 1.0));
        assert!(truth > 7.5 && truth < 12.0);
        assert_eq!(c.true_position_mm(s(t0 + 10.0)), truth);
        assert_eq!(pos(&mut c, t0 + 10.0), 0.0);
        assert_eq!(q(&mut c, t0 + 10.0, "SVO? 1").unwrap(), "1=0\n");
        assert_eq!(q(&mut c, t0 + 10.0, "FRF? 1").unwrap(), "1=0\n");
        assert_eq!(q(&mut c, t0 + 10.0, "VEL? 1").unwrap(), "1=1.0000000\n");
        assert_eq!(err(&mut c, t0 + 10.0), 0);
        // Referencing again finds the same switch.
        q(&mut c, t0 + 10.0, "SVO 1 1");
        q(&mut c, t0 + 10.0, "FRF 1");
        assert_eq!(pos(&mut c, t0 + 100.0), 7.5);
        assert_eq!(c.true_position_mm(s(t0 + 100.0)), 7.5);
    }

    #[test]
    fn platform_seam_separates_truth_from_encoder() {
        /// A leadscrew 0.1 % long plus a 2 µm offset.
        #[derive(Debug)]
        struct Scaled;
        impl Platform for Scaled {
            fn platform_position_mm(&self, actuator_mm: f64, _now: Duration) -> f64 {
                actuator_mm * 1.001 + 0.002
            }
        }
        let mut c = ctl(3.0);
        c.set_platform(Box::new(Scaled));
        let t0 = referenced(&mut c);
        q(&mut c, t0, "MOV 1 10");
        // The controller reports its encoder; the platform is elsewhere.
        assert_eq!(pos(&mut c, t0 + 10.0), 10.0);
        let truth = c.true_position_mm(s(t0 + 10.0));
        assert!((truth - (10.0 * 1.001 + 0.002)).abs() < 1e-12, "{truth}");
    }

    #[test]
    fn addressing() {
        let mut c = Controller::new(ControllerConfig::new(Address::new(2).unwrap(), "2", 1.0));
        let mut d = RequestDecoder::new();
        let reqs = d.push(b"*IDN?\n1 *IDN?\n2 CSV?\n2 \x07");
        assert_eq!(c.handle(s(0.0), &reqs[0]), None);
        assert_eq!(c.handle(s(0.0), &reqs[1]), None);
        assert_eq!(c.handle(s(0.0), &reqs[2]).unwrap(), b"0 2 2.0\n");
        assert_eq!(c.handle(s(0.0), &reqs[3]).unwrap(), b"0 2 \xb1\n");
        // The addressed controller also answers multi-line with one header.
        let reqs = d.push(b"2 SPA? 1 0x3C 1 0x15\n");
        assert_eq!(
            c.handle(s(0.0), &reqs[0]).unwrap(),
            b"0 2 1 0x3C=M-111.1DG \n1 0x15=15.000000\n"
        );
    }

    #[test]
    fn long_virtual_runs_are_cheap_and_exact() {
        // 10 hours of back-and-forth in virtual time.
        let mut c = ctl(3.0);
        let mut t = referenced(&mut c);
        for i in 0..2000 {
            let target = if i % 2 == 0 { 2.0 } else { 13.0 };
            q(&mut c, t, &format!("MOV 1 {target}"));
            t += 18.0;
            assert_eq!(q(&mut c, t, "ONT? 1").unwrap(), "1=1\n");
            assert_eq!(pos(&mut c, t), target);
        }
        assert!(t > 36_000.0);
    }

    proptest! {
        #[test]
        fn random_bytes_never_panic(chunks in proptest::collection::vec(
            (proptest::collection::vec(any::<u8>(), 0..64), 0u32..5000), 0..40)) {
            let mut bus = crate::bus::Bus::new(vec![
                ctl(3.0),
                Controller::new(ControllerConfig::new(Address::new(2).unwrap(), "2", 9.0)),
            ]).unwrap();
            let mut t = Duration::ZERO;
            for (bytes, dt_ms) in &chunks {
                t += Duration::from_millis(u64::from(*dt_ms));
                for r in bus.receive(t, bytes) {
                    prop_assert!(r.bytes.ends_with(b"\n"));
                }
                for c in bus.controllers() {
                    let p = c.true_position_mm(t);
                    prop_assert!(p.is_finite());
                }
            }
        }

        #[test]
        fn random_commands_never_panic(cmds in proptest::collection::vec(
            (prop_oneof![
                Just("MOV 1 "), Just("MVR 1 "), Just("VEL 1 "), Just("ACC 1 "), Just("DEC 1 "),
                Just("SVO 1 "), Just("FRF "), Just("HLT "), Just("STP "), Just("SPA 1 0x16 "),
                Just("SPA 1 0x15 "), Just("SPA 1 0x30 "), Just("RON 1 "), Just("FNL "), Just("FPL "),
            ], -20.0f64..20.0, 0u32..3000), 0..60)) {
            let mut c = ctl(5.0);
            let mut t = 0.0;
            for (cmd, v, dt) in &cmds {
                t += f64::from(*dt) / 1000.0;
                let arg = if cmd.starts_with("SVO") || cmd.starts_with("RON") {
                    if *v > 0.0 { "1".to_owned() } else { "0".to_owned() }
                } else if cmd.starts_with("FRF") || cmd.starts_with("HLT") || cmd.starts_with("STP") || cmd.starts_with("F") {
                    String::new()
                } else {
                    format!("{v}")
                };
                q(&mut c, t, &format!("{cmd}{arg}"));
                let p = pos(&mut c, t);
                prop_assert!(p.is_finite());
                prop_assert!(c.true_position_mm(s(t)).is_finite());
            }
        }
    }
}
