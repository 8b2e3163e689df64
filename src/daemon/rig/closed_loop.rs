//! The closed-loop runner of `closed_loop` moves: after the first planned
//! move settled, waits for fresh frames and corrects until the stage is
//! within tolerance (the decisions are `comp::closed_loop`'s, sans-IO).

use super::Rig;
use crate::comp::closed_loop::{
    Action, ClosedLoop, ClosedLoopConfig, FailReason, FrameMeasurement, RejectReason,
};
use crate::comp::{Compensator, Uncompensated, VisionFrame};
use crate::daemon::protocol::{ClosedLoopOutcome, ErrorCode, LoopMeasurement, PairUm, ProtoError};
use crate::model::XyUm;
use std::sync::{Arc, Mutex};
use std::time::Duration;

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

/// Which compensator a planned move uses.
pub fn compensator_for(rig: &Rig, compensated: bool) -> Result<Arc<dyn Compensator>, ProtoError> {
    match rig.comp.active() {
        Some(a) => Ok(a.comp),
        None if compensated => Err(ProtoError::new(
            ErrorCode::NoActiveTable,
            "no compensation table is active: tables load NAME, tables activate NAME (or use mode raw)",
        )),
        None => Ok(Arc::new(Uncompensated)),
    }
}

/// Maps a closed-loop failure to its error.
pub fn failure(reason: FailReason, residual: Option<[f64; 2]>, corrections: u32) -> ProtoError {
    let (code, what) = match reason {
        FailReason::RetryLimit => (
            ErrorCode::RetryLimit,
            "the correction limit was reached outside tolerance".to_owned(),
        ),
        FailReason::Diverging => (
            ErrorCode::Diverging,
            "the residual grew between corrections; stopped instead of chasing it".to_owned(),
        ),
        FailReason::Frames(RejectReason::LowQuality)
        | FailReason::Frames(RejectReason::NonFinite) => (
            ErrorCode::LowQuality,
            "frames decode below camera.min_quality".to_owned(),
        ),
        FailReason::Frames(r) => (
            ErrorCode::CameraStalled,
            format!("no fresh frame after the move settled ({r:?})"),
        ),
    };
    ProtoError::new(
        code,
        format!("closed loop failed after {corrections} corrections: {what}; last residual {residual:?} µm"),
    )
}

/// Closed-loop parameters from the daemon configuration.
pub fn loop_config(rig: &Rig, tolerance_um: Option<f64>) -> ClosedLoopConfig {
    let d = ClosedLoopConfig::default();
    ClosedLoopConfig {
        tolerance_um: tolerance_um.unwrap_or(rig.cfg.closed_loop.tolerance_um),
        max_corrections: rig.cfg.closed_loop.max_iterations,
        max_correction_um: rig.cfg.closed_loop.max_correction_um,
        min_quality: rig.cfg.camera.min_quality,
        always_reapproach: rig.cfg.closed_loop.always_reapproach,
        // The same approach length as the planned moves, so the first
        // arrival and every correction end with a move of one length
        // (`ClosedLoopConfig::plan_options`).
        overshoot_um: rig.live.compensation().overshoot_um,
        ..d
    }
}

/// Waits for the next vision measurement usable by the loop: exposed after
/// the move settled (its grab was requested at or after `after_s`, the
/// settle time; a frame whose grab was in flight at settle time is also
/// skipped by sequence), converted to the stage frame by `frame`.
///
/// The wait for the camera itself is bounded in wall time
/// (`camera.timeout_ms`): it guards an I/O stall, not a physical duration.
/// A frame that never comes fails as `camera_stalled`; frames that come but
/// do not decode fail as `low_quality`.
pub async fn next_frame(
    rig: &Rig,
    frame: &VisionFrame,
    min_sequence: u64,
    after_s: f64,
) -> Result<FrameMeasurement, ProtoError> {
    let Some(v) = &rig.vision else {
        return Err(ProtoError::new(
            ErrorCode::CameraUnavailable,
            "no camera is configured (camera.source)",
        ));
    };
    let _want = v.want();
    let mut rx = v.latest.clone();
    let failed_before = v.stats.failed.load(std::sync::atomic::Ordering::Relaxed);
    let timeout = Duration::from_millis(rig.cfg.camera.timeout_ms);
    let deadline = tokio::time::Instant::now() + timeout;
    loop {
        if let Some(m) = *rx.borrow_and_update() {
            if m.sequence >= min_sequence && m.t_s >= after_s {
                let p = frame.to_stage(XyUm {
                    x_um: m.x_um,
                    y_um: m.y_um,
                });
                return Ok(FrameMeasurement {
                    position: p,
                    timestamp_s: m.t_s,
                    quality: m.quality,
                    frame_seq: m.sequence,
                });
            }
        }
        match tokio::time::timeout_at(deadline, rx.changed()).await {
            Ok(Ok(())) => continue,
            Ok(Err(_)) | Err(_) => {
                let failed = v.stats.failed.load(std::sync::atomic::Ordering::Relaxed);
                let last = lock(&v.last_error).clone().unwrap_or_default();
                return Err(if failed > failed_before {
                    ProtoError::new(
                        ErrorCode::LowQuality,
                        format!(
                            "frames arrive but do not decode ({} failed in {} ms; last: {last}); the stage was not corrected on old data",
                            failed - failed_before,
                            timeout.as_millis()
                        ),
                    )
                } else {
                    ProtoError::new(
                        ErrorCode::CameraStalled,
                        format!(
                            "no new frame from the camera within {} ms after the move settled (last error: {last}); the stage was not corrected on old data",
                            timeout.as_millis()
                        ),
                    )
                });
            }
        }
    }
}

/// The sequence number a frame must reach to have been grabbed entirely
/// after now: the newest known + 2 (the one in flight may predate now).
pub fn min_sequence_after_now(rig: &Rig) -> u64 {
    rig.vision
        .as_ref()
        .and_then(|v| *v.latest.borrow())
        .map_or(0, |m| m.sequence + 2)
}

/// Runs the closed loop after the first planned move settled.
pub async fn run_loop(
    rig: &Arc<Rig>,
    mut cl: ClosedLoop,
    frame: VisionFrame,
    mut execute: impl FnMut(Vec<XyUm>) -> futures_like::BoxFut<'static>,
) -> Result<ClosedLoopOutcome, ProtoError> {
    let mut settled_s = rig.clock.now_s();
    cl.settled(settled_s);
    let mut min_seq = min_sequence_after_now(rig);
    loop {
        let m = next_frame(rig, &frame, min_seq, settled_s).await?;
        min_seq = m.frame_seq + 1;
        let action = cl.on_frame(&m);
        tracing::debug!(
            "closed loop: frame {} at {:.3} s measured ({:.4}, {:.4}) µm, command ({:.4}, {:.4}) µm: {action:?}",
            m.frame_seq,
            m.timestamp_s,
            m.position.x_um,
            m.position.y_um,
            cl.cmd().x_um,
            cl.cmd().y_um
        );
        match action {
            Action::AwaitFrame { .. } => continue,
            Action::Move { waypoints } => {
                execute(waypoints).await?;
                settled_s = rig.clock.now_s();
                cl.settled(settled_s);
                min_seq = min_sequence_after_now(rig).max(min_seq);
            }
            Action::Done {
                residual_um,
                corrections,
            } => {
                return Ok(ClosedLoopOutcome {
                    residual_um: PairUm::of(residual_um),
                    corrections,
                    measured: LoopMeasurement {
                        x_um: m.position.x_um,
                        y_um: m.position.y_um,
                        t_s: m.timestamp_s,
                        quality: m.quality,
                    },
                    commanded: PairUm::of([cl.cmd().x_um, cl.cmd().y_um]),
                })
            }
            Action::Failed {
                reason,
                residual_um,
                corrections,
            } => return Err(failure(reason, residual_um, corrections)),
        }
    }
}

/// A boxed future alias, so the executor closure can be async.
pub mod futures_like {
    use super::ProtoError;
    /// A boxed, sendable future of a move result.
    pub type BoxFut<'a> =
        std::pin::Pin<Box<dyn std::future::Future<Output = Result<(), ProtoError>> + Send + 'a>>;
}
