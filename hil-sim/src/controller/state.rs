//! The controller's observable state, evaluated in closed form at any
//! simulated time: positions in the three frames, the status register,
//! on-target and referencing state, and finished activities brought to
//! rest (`tick`).
//!
//! Why a file of its own: there is no periodic tick; every query and every
//! command evaluates the planned profile here, so this is the one place
//! that defines what the controller reports at a given time.

use super::{
    Activity, ActuatorPath, Controller, ControllerConfig, Platform, RefKind, E, SETTLE_TIME,
};
use crate::motion::{Limits, Profile};
use crate::params::{self, ParamSet};
use micropos::gcs::Address;
use std::time::Duration;

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
            stalled: false,
            lag_s: cfg.following_lag_s,
            recorder: super::recorder::Recorder::default(),
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
    pub(super) fn sync_platform(&mut self, now: Duration) {
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

    /// Replaces the platform model (e.g. the rig's stage error model).
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
        self.stalled = false;
        self.sync_platform(now);
    }

    /// A blocked carriage (a jammed leadscrew, a collision): motion stops
    /// where it is while the controller keeps trying, so `#5` says moving
    /// and `ONT?` stays false; the encoder no longer follows the commanded
    /// trajectory (a following error). A stop, a halt or a new move ends
    /// it. No effect at rest.
    pub fn stall(&mut self, now: Duration) {
        let now = self.tick(now);
        if let Activity::Moving(_) = self.activity {
            let (p, _) = self.state_at(now);
            self.encoder_mm = p;
            self.activity = Activity::Idle;
            self.stalled = true;
            self.sync_platform(now);
        }
    }

    /// A servo fault as a C-863 reports it: the position error grew too
    /// large, so the controller cuts the motion where it is, switches its
    /// servo off and sets error 1024 (PI_CNTR_MOTION_ERROR) for the next
    /// `ERR?`. The host must notice it by asking.
    pub fn motion_error(&mut self, now: Duration) {
        let now = self.tick(now);
        let (p, _) = self.state_at(now);
        self.encoder_mm = p;
        self.target_mm = p;
        self.activity = Activity::Idle;
        self.stalled = false;
        self.servo = false;
        self.settled_at = now;
        self.error = E::MOTION_ERROR;
        self.sync_platform(now);
    }

    /// The carriage slips by `slip_mm` against the encoder (a coupling or
    /// a friction drive giving way, a knock against the platform): the
    /// actuator, and with it the platform, jumps while the encoder count
    /// stays, so `POS?`, `ONT?` and the motion in progress carry on as if
    /// nothing happened. Only an outside measurement sees it.
    pub fn slip(&mut self, now: Duration, slip_mm: f64) {
        let now = self.tick(now);
        if slip_mm.is_finite() {
            self.offset_mm += slip_mm;
            self.sync_platform(now);
        }
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
        if self.stalled {
            return true;
        }
        match &self.activity {
            Activity::Idle => false,
            Activity::Moving(p) => !p.is_done(now),
            Activity::Referencing { done_at, .. } => now < *done_at,
        }
    }

    /// Whether `ONT?` reports on target at `now`.
    pub fn on_target(&self, now: Duration) -> bool {
        if !self.servo || self.stalled {
            return false;
        }
        match &self.activity {
            Activity::Idle => now >= self.settled_at,
            Activity::Moving(p) => now >= settles_at(p),
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

    /// The motion profile in force at `now`, or the position the axis rests
    /// at (idle, or a reference move that has ended).
    fn profile_at(&self, now: Duration) -> Result<&Profile, f64> {
        match &self.activity {
            Activity::Idle => Err(self.encoder_mm),
            Activity::Moving(p) => Ok(p),
            Activity::Referencing {
                profile,
                done_at,
                kind,
            } => {
                if now >= *done_at {
                    Err(self.reference_value(*kind))
                } else {
                    Ok(profile)
                }
            }
        }
    }

    /// (encoder position, velocity) at `now`.
    pub(super) fn state_at(&self, now: Duration) -> (f64, f64) {
        match self.profile_at(now) {
            Ok(p) => p.state_at(now),
            Err(rest) => (rest, 0.0),
        }
    }

    /// Commanded position, velocity and following error at `now`: where a
    /// new command continues from (the command is continuous and the
    /// following error carries over, as in a servo whose trajectory
    /// generator is re-planned).
    pub(super) fn command_state_at(&self, now: Duration) -> (f64, f64, f64) {
        let p = match self.profile_at(now) {
            Ok(p) => p,
            Err(rest) => return (rest, 0.0, 0.0),
        };
        let (c, v) = p.command_at(now);
        (c, v, p.following_error_at(now))
    }

    /// A new command from the current state to `target` at `limits`,
    /// followed with the controller's servo lag.
    pub(super) fn plan_from_here(&self, now: Duration, target: f64, limits: Limits) -> Profile {
        let (c, v, e) = self.command_state_at(now);
        Profile::plan(now, c, v, target, limits).with_lag(self.lag_s, e)
    }

    /// Encoder value assigned at the switch a referencing move finds.
    pub(super) fn reference_value(&self, kind: RefKind) -> f64 {
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
    pub(super) fn tick(&mut self, now: Duration) -> Duration {
        let now = now.max(self.last_now);
        self.last_now = now;
        // The recorder's samples due until now, from the trajectory in
        // force since the last request.
        let mut rec = std::mem::take(&mut self.recorder);
        rec.fill(now, &|t| (self.state_at(t).0, self.command_state_at(t).0));
        self.recorder = rec;
        match &self.activity {
            Activity::Idle => {}
            Activity::Moving(p) => {
                if p.is_done(now) {
                    self.encoder_mm = p.end_mm();
                    self.settled_at = settles_at(p);
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

    pub(super) fn set_error(&mut self, e: E) {
        // A C-863 keeps the first error until ERR? reads it.
        if self.error.is_ok() {
            self.error = e;
        }
    }

    pub(super) fn limits(&self) -> Limits {
        Limits {
            velocity: self.params.number(params::VELOCITY, 1.0),
            acceleration: self.params.number(params::ACCELERATION, 10.0),
            deceleration: self.params.number(params::DECELERATION, 10.0),
        }
    }
}

/// When a move's axis is on target: the servo's settle after the command
/// ends, and not before the following error has decayed.
pub(super) fn settles_at(p: &Profile) -> Duration {
    (p.command_end_time() + SETTLE_TIME).max(p.end_time())
}
