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
//! [`super::jobs::PARK_APPROACH_UM`] below, so backlash cancels), gives
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

use super::comp::Active;
use super::config::{DaemonConfig, DriftMethodName};
use super::protocol::{ErrorCode, MoveRequest, ProtoError, Topic};
use super::rig::Rig;
use crate::analysis::drift::{LiveDrift, LiveSample};
use crate::comp::VisionFrame;
use crate::model::XyUm;
use serde_json::{json, Value};
use std::sync::{Arc, Mutex};
use std::time::Duration;

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

/// The live drift state of the daemon.
#[derive(Debug)]
pub struct DriftControl {
    live: Mutex<LiveDrift>,
    /// Serializes re-measurements (two clients' moves must not both go).
    measuring: tokio::sync::Mutex<()>,
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

impl Rig {
    /// The reference point and frame live correction uses with `active`,
    /// or why it cannot.
    fn drift_setup(&self, active: &Active) -> Result<([f64; 2], VisionFrame), String> {
        let frame = active.frame.ok_or_else(|| {
            format!(
                "table {} records no vision frame (build it with tables build)",
                active.name
            )
        })?;
        let k = &self.cfg.characterize;
        let reference = active
            .drift_baseline
            .map(|b| b.reference_um)
            .or(self.live.drift().reference_um)
            .or(k.drift_reference_um)
            .or(match (k.x_start_um, k.y_start_um) {
                (Some(x), Some(y)) => Some([x, y]),
                _ => None,
            })
            .ok_or_else(|| {
                "no drift reference point: the table records none; set [drift] reference_um"
                    .to_owned()
            })?;
        Ok((reference, frame))
    }

    /// Arms live drift for `active` and tells whether a re-measurement is
    /// due (`Err`: correction impossible with this table, and why).
    pub fn drift_due(&self, active: &Active) -> Result<bool, String> {
        let (reference, _) = self.drift_setup(active)?;
        let mut g = lock(&self.drift.live);
        g.arm(reference, active.drift_baseline);
        Ok(g.due(self.clock.now_s()))
    }

    /// Re-measures the reference with `active`'s frame (approach as in the
    /// characterization, settle, `frames` frames) and records it. Motion
    /// errors are returned as they are; a measurement failure is recorded
    /// as a failure (estimate untouched), pushed as a `drift` event and
    /// returned.
    pub async fn drift_measure(
        self: &Arc<Self>,
        active: &Active,
        frames: u32,
        settle_s: f64,
        from_job: bool,
    ) -> Result<Remeasured, ProtoError> {
        let (reference, frame) = self
            .drift_setup(active)
            .map_err(|m| ProtoError::new(ErrorCode::NoActiveTable, m))?;
        let _one = self.drift.measuring.lock().await;
        lock(&self.drift.live).arm(reference, active.drift_baseline);
        let [rx, ry] = reference;
        let approach = super::jobs::PARK_APPROACH_UM;
        let mut moved = Value::Null;
        let below = super::jobs::clamp_to_travel(self, rx - approach, ry - approach);
        for (x, y) in [below, (rx, ry)] {
            let req = MoveRequest::raw_to(x, y);
            moved = self.raw_move(&req, from_job, true).await?;
        }
        self.clock
            .sleep(Duration::try_from_secs_f64(settle_s).unwrap_or_default())
            .await;
        let now = self.clock.now_s();
        let measured = super::jobs::measure(self, frames, now).await;
        let (m, quality) = match measured {
            Ok(v) => v,
            Err(e) => {
                let t = self.clock.now_s();
                let why = e.to_string();
                let state = {
                    let mut g = lock(&self.drift.live);
                    g.record_failure(t, why.clone());
                    g.to_json(t)
                };
                tracing::warn!("drift reference re-measurement failed: {why}");
                self.push(
                    Topic::Drift,
                    "drift",
                    json!({"state": "failed", "t_s": t, "error": why, "drift": state}),
                );
                return Err(e);
            }
        };
        let meas = frame.to_stage(XyUm {
            x_um: m.x_um,
            y_um: m.y_um,
        });
        let t = self.clock.now_s();
        let (sample, state) = {
            let mut g = lock(&self.drift.live);
            let s = g
                .record(t, [meas.x_um, meas.y_um])
                .map_err(|e| ProtoError::new(ErrorCode::Internal, format!("drift: {e}")))?;
            (s, g.to_json(t))
        };
        self.push(
            Topic::Drift,
            "drift",
            json!({"state": "measured", "t_s": t, "sample": sample, "drift": state}),
        );
        Ok(Remeasured {
            reference_um: reference,
            sample,
            reported: moved["reported"].clone(),
            quality,
        })
    }

    /// The correction for a compensated move with `active` now; with
    /// `measure_if_due` (a user's move) re-measures first when due. Only
    /// motion errors are returned; everything else is in `info`.
    pub async fn drift_correction(
        self: &Arc<Self>,
        active: Option<&Active>,
        measure_if_due: bool,
    ) -> Result<Correction, ProtoError> {
        if !self.drift.enabled() {
            return Ok(Correction::default());
        }
        let Some(active) = active else {
            return Ok(Correction::default());
        };
        let mut info = json!({});
        match self.drift_due(active) {
            Err(why) => {
                return Ok(Correction {
                    offset_um: None,
                    info: json!({"error": why}),
                })
            }
            Ok(true) if measure_if_due => {
                let k = &self.cfg.characterize;
                match self
                    .drift_measure(active, k.frames_per_point, k.settle_s, false)
                    .await
                {
                    Ok(r) => info["measured"] = json!(r.sample),
                    Err(e) if is_measurement_error(e.code) => {
                        info["error"] = json!(e.to_string());
                    }
                    Err(e) => return Err(e),
                }
            }
            Ok(_) => {}
        }
        let now = self.clock.now_s();
        let g = lock(&self.drift.live);
        let offset = g.correction(now);
        info["correction_um"] = json!(offset);
        info["method"] = json!(g.to_json(now)["method"]);
        info["failures"] = json!(g.failures());
        Ok(Correction {
            offset_um: offset,
            info,
        })
    }
}

/// Errors of the measurement itself (the camera), as opposed to motion.
pub fn is_measurement_error(code: ErrorCode) -> bool {
    matches!(
        code,
        ErrorCode::CameraStalled | ErrorCode::LowQuality | ErrorCode::CameraUnavailable
    )
}
