//! Live drift correction of compensated moves (the daemon side of
//! [`crate::analysis::drift::LiveDrift`]).
//!
//! What "drift" means here: a table maps a command to where the stage went
//! in the rig's state when the table's data were taken; `tables build`
//! corrects a log with reference re-measurements to the state of its first
//! re-measurement and records that re-measurement with the table (the
//! *baseline*, [`crate::analysis::drift::DriftBaseline`]). Later the same command lands `d(t)`
//! away. Re-measuring the reference point, approached exactly as the
//! characterization did (raw, forward on both axes from
//! [`super::rig::measure::PARK_APPROACH_UM`] below, so backlash cancels), gives
//! `d(t) = measured(t) − baseline` at the reference; a compensated move to
//! `T` then plans for `T − d̂(t)`, `d̂` the static or adaptive prediction.
//! Tables without a baseline (logs without `drift_every_s`) use the first
//! re-measurement of the session as baseline: only drift since then is
//! corrected.
//!
//! When re-measurements happen (never during a move):
//! * a user's `compensated` move, before the move, when `every_s` of rig
//!   time have passed since the last attempt;
//! * the validation job, between points of its `table` and `model` modes
//!   (logged in the validation log as `drift_ref` rows);
//! * `drift measure`, at once.
//!
//! Raw moves are never corrected (the user asked for the command), nor is
//! `closed_loop` (the camera measures the platform itself).
//!
//! A failed re-measurement (camera stalled, frames undecodable) never
//! touches the estimate: it is reported (`drift` event with
//! `state = "failed"`, `status.drift.last_error`, the move's reply) and the
//! move goes on corrected by the last good estimate, held at most two
//! intervals past its last good re-measurement; the next attempt waits a
//! full interval. Motion errors while approaching the reference (a stop, a
//! fault) fail the move: the user stopped the rig.

use super::config::{DaemonConfig, DriftMethodName};
use super::protocol::{ErrorCode, ProtoError};
use crate::analysis::drift::{LiveDrift, LiveSample};
use serde_json::Value;
use std::sync::Mutex;

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

/// The live drift state of the daemon.
#[derive(Debug)]
pub struct DriftControl {
    /// The estimate (`rig::drift` records re-measurements into it).
    pub(super) live: Mutex<LiveDrift>,
    /// Serializes re-measurements (two clients' moves must not both go).
    pub(super) measuring: tokio::sync::Mutex<()>,
}

impl DriftControl {
    /// From the validated `[drift]` section (an invalid one, impossible
    /// after validation, falls back to off with a warning).
    pub fn new(cfg: &DaemonConfig) -> DriftControl {
        let live = LiveDrift::new(cfg.drift.live_method(), cfg.drift.every_s).unwrap_or_else(|e| {
            tracing::warn!("[drift]: {e}; live drift correction off");
            LiveDrift::off()
        });
        DriftControl {
            live: Mutex::new(live),
            measuring: tokio::sync::Mutex::new(()),
        }
    }

    /// The state as JSON (`status.drift`, `drift show`).
    pub fn to_json(&self, now_s: f64) -> Value {
        lock(&self.live).to_json(now_s)
    }

    /// `drift set`: changes the method and/or interval; re-measurements
    /// are kept.
    pub fn set(
        &self,
        cfg: &DaemonConfig,
        method: Option<DriftMethodName>,
        every_s: Option<f64>,
        time_constant_s: Option<f64>,
    ) -> Result<(), ProtoError> {
        let mut g = lock(&self.live);
        let mut sec = cfg.drift.clone();
        sec.method = method.unwrap_or(match g.method() {
            crate::analysis::drift::LiveMethod::Off => DriftMethodName::Off,
            crate::analysis::drift::LiveMethod::Static => DriftMethodName::Static,
            crate::analysis::drift::LiveMethod::Adaptive { time_constant_s } => {
                sec.time_constant_s = time_constant_s;
                DriftMethodName::Adaptive
            }
        });
        if let Some(t) = time_constant_s {
            sec.time_constant_s = t;
        }
        let every_s = every_s.unwrap_or(g.every_s());
        g.configure(sec.live_method(), every_s)
            .map_err(|e| ProtoError::new(ErrorCode::BadValue, format!("drift: {e}")))
    }

    /// `drift reset`.
    pub fn reset(&self) {
        lock(&self.live).reset();
    }

    /// Whether live correction is on.
    pub fn enabled(&self) -> bool {
        lock(&self.live).method() != crate::analysis::drift::LiveMethod::Off
    }
}

/// A re-measurement of the reference: the sample, the controller-reported
/// position there and the decode quality (what a log row holds).
#[derive(Debug, Clone)]
pub struct Remeasured {
    /// The reference point, µm.
    pub reference_um: [f64; 2],
    /// The sample (time, measured position, drift).
    pub sample: LiveSample,
    /// Controller-reported position after the approach.
    pub reported: Value,
    /// Mean decode quality.
    pub quality: f64,
}

/// The correction a compensated move gets.
#[derive(Debug, Clone, Default)]
pub struct Correction {
    /// Subtract from the target, µm (`None`: uncorrected).
    pub offset_um: Option<[f64; 2]>,
    /// What happened, for the move's reply.
    pub info: Value,
}

/// Errors of the measurement itself (the camera), as opposed to motion.
pub fn is_measurement_error(code: ErrorCode) -> bool {
    matches!(
        code,
        ErrorCode::CameraStalled | ErrorCode::LowQuality | ErrorCode::CameraUnavailable
    )
}
