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
//!   [`Platform`] maps actuator to platform position: the identity
//!   ([`IdealPlatform`]) for a controller alone; the shared rig installs its
//!   stage error model (`crate::rig::RigAxis`).
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
//!
//! # Layout
//! This file holds the controller's configuration and state; its behaviour
//! is split by concern:
//! * `platform`: the seam between actuator and platform ([`Platform`],
//!   [`ActuatorPath`]) and the switch geometry.
//! * `state`: the observable state evaluated in closed form at any time
//!   (positions, status register, finished activities brought to rest).
//! * `actions`: what starts, re-plans and stops motion and referencing,
//!   with the checks a real C-863 makes first.
//! * `recorder`: the data recorder (`DRC`, `RTR`, `DRT`, `DRR?`, ...),
//!   sampled at the servo rate on the rig clock.
//! * `commands`: request handling: control characters, GCS commands and
//!   their answers, the `HLP?` list.

mod actions;
mod commands;
mod platform;
mod recorder;
mod state;
#[cfg(test)]
mod tests;

pub use platform::{ActuatorPath, IdealPlatform, Platform, StageGeometry};
pub use recorder::{SERVO_CYCLE_S, TABLES as RECORD_TABLES, TABLE_POINTS as RECORD_TABLE_POINTS};

use crate::motion::Profile;
use crate::params::ParamSet;
use micropos::gcs::{Address, GcsErrorCode as E};
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
    /// Servo lag time constant τ, s (`crate::motion`): at velocity `v` the
    /// encoder (`POS?`) and the carriage trail the commanded trajectory by
    /// `v·τ`. 0: they are the command.
    pub following_lag_s: f64,
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
            following_lag_s: 0.0,
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
    /// The carriage is blocked mid-move ([`Controller::stall`]): the
    /// controller still tries (moving, not on target) until a stop, a halt
    /// or a new move.
    stalled: bool,
    /// Servo lag time constant, s ([`ControllerConfig::following_lag_s`]).
    lag_s: f64,
    /// The data recorder (`recorder`).
    recorder: recorder::Recorder,
}
