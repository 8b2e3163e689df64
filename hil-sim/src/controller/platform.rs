//! Where the stage's switches are and where the platform really is: the
//! seam between the controller (which only knows its encoder) and the
//! stage error model of the shared rig.
//!
//! Why a file of its own: the rig and the simulated camera implement and
//! read these types without touching the controller's state machine.

use crate::motion::Profile;
use std::fmt;
use std::time::Duration;

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
