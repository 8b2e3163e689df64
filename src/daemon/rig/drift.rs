//! Live drift correction as the rig runs it: re-measuring the drift
//! reference (approached as the characterization does) and the correction
//! a compensated move plans with. The state itself is
//! [`DriftControl`](crate::daemon::drift::DriftControl), a component the
//! rig owns.

use super::measure::{clamp_to_travel, measure, PARK_APPROACH_UM};
use super::Rig;
use crate::comp::VisionFrame;
use crate::daemon::comp::Active;
use crate::daemon::drift::{is_measurement_error, Correction, Remeasured};
use crate::daemon::protocol::{to_value, ErrorCode, MoveRequest, ProtoError, Topic};
use crate::model::XyUm;
use serde_json::json;
use std::sync::{Arc, Mutex};
use std::time::Duration;

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
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
        let approach = PARK_APPROACH_UM;
        let mut moved = None;
        let below = clamp_to_travel(self, rx - approach, ry - approach);
        for (x, y) in [below, (rx, ry)] {
            let req = MoveRequest::raw_to(x, y);
            moved = Some(self.raw_move(&req, from_job, true).await?);
        }
        self.clock
            .sleep(Duration::try_from_secs_f64(settle_s).unwrap_or_default())
            .await;
        let now = self.clock.now_s();
        let measured = measure(self, frames, now).await;
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
            reported: to_value(&moved.and_then(|m| m.reported)),
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
