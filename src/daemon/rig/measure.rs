//! Measuring at a point: the park approach, averaged fresh frames, and the
//! absolute raw move and the measurement retried after transient faults
//! (what jobs and the drift re-measurement share).

use super::Rig;
use crate::daemon::protocol::{ErrorCode, MoveReply, MoveRequest, ProtoError};
use crate::daemon::vision::{Deferred, HealthCounts, Measurement};
use std::sync::Arc;
use std::time::Duration;

/// The park approach, µm (defined with the scan plan's geometry).
pub use crate::charact::scan::PARK_APPROACH_UM;

/// Waits for `n` fresh, good measurements and averages them. Fresh: the
/// grab was requested at or after `after_s` (so the frame was exposed after
/// the settle; see `daemon::vision`) and the frame is newer than any taken
/// before the call. Good: quality ≥ `camera.min_quality`.
///
/// Each accepted frame must come within `camera.timeout_ms` (wall time: it
/// guards an I/O stall, not a physical duration) of the previous one, or of
/// the call; otherwise the point fails with `camera_stalled` (no frame
/// arrived) or `low_quality` (frames arrived but did not decode, or decoded
/// below the minimum quality). Nothing is made up: the caller logs only what
/// this returns.
pub(crate) async fn measure(
    rig: &Rig,
    n: u32,
    after_s: f64,
) -> Result<(Measurement, f64), ProtoError> {
    let Some(v) = &rig.vision else {
        return Err(ProtoError::new(ErrorCode::CameraUnavailable, "no camera"));
    };
    let _want = v.want();
    let mut rx = v.latest.clone();
    let timeout = Duration::from_millis(rig.cfg.camera.timeout_ms);
    let counters = || HealthCounts::of(&v.stats);
    let mut got: Vec<Measurement> = Vec::new();
    let mut last_seq = None;
    let mut below_quality = false;
    let mut deadline = tokio::time::Instant::now() + timeout;
    let mut at_start = counters();
    while got.len() < n as usize {
        let m = *rx.borrow_and_update();
        if let Some(m) = m {
            let fresh = m.t_s >= after_s && Some(m.sequence) != last_seq;
            below_quality |= fresh && m.quality < rig.cfg.camera.min_quality;
            if fresh && m.quality >= rig.cfg.camera.min_quality {
                last_seq = Some(m.sequence);
                got.push(m);
                deadline = tokio::time::Instant::now() + timeout;
                at_start = counters();
                continue;
            }
        }
        match tokio::time::timeout_at(deadline, rx.changed()).await {
            Ok(Ok(())) => {}
            Ok(Err(_)) => {
                return Err(ProtoError::new(
                    ErrorCode::CameraUnavailable,
                    "the camera pipeline ended",
                ))
            }
            Err(_) => {
                let why = v
                    .last_error_text()
                    .unwrap_or_else(|| "no error reported".to_owned());
                // A frame in flight when the camera stalled may still
                // arrive (and be refused as too old): only frames that fail
                // to decode, or fresh ones below the quality, mean that the
                // camera delivers but the data is unusable.
                let failed = counters().failed;
                let (code, what) = if failed > at_start.failed {
                    (
                        ErrorCode::LowQuality,
                        format!(
                            "frames arrive but do not decode ({} failed)",
                            failed - at_start.failed
                        ),
                    )
                } else if below_quality {
                    (
                        ErrorCode::LowQuality,
                        format!(
                            "frames decode below camera.min_quality = {}",
                            rig.cfg.camera.min_quality
                        ),
                    )
                } else {
                    (
                        ErrorCode::CameraStalled,
                        "no frame exposed after the settle arrived from the camera".to_owned(),
                    )
                };
                // Transient: the next frames may well decode (a stalled
                // grab, a blurred or garbled frame); jobs retry it.
                return Err(ProtoError::new(
                    code,
                    format!(
                        "{what} within {} ms (last error: {why}); {} of {n} frames measured, the point was not logged",
                        timeout.as_millis(),
                        got.len()
                    ),
                )
                .into_transient());
            }
        }
    }
    let m = average(&got);
    Ok((m, m.quality))
}

/// The mean of `got` (at least one), the newest frame's sequence number;
/// θ as the first frame's plus the mean turn from it (so angles on both
/// sides of ±π average to the orientation they share).
fn average(got: &[Measurement]) -> Measurement {
    let k = got.len().max(1) as f64;
    let mean = |f: fn(&Measurement) -> f64| got.iter().map(f).sum::<f64>() / k;
    let theta0 = got.first().map_or(0.0, |m| m.theta_rad);
    let turn = got
        .iter()
        .map(|m| crate::daemon::vision::wrap_angle_rad(m.theta_rad - theta0))
        .sum::<f64>()
        / k;
    Measurement {
        t_s: mean(|m| m.t_s),
        frame_t_s: mean(|m| m.frame_t_s),
        sequence: got.last().map_or(0, |m| m.sequence),
        x_um: mean(|m| m.x_um),
        y_um: mean(|m| m.y_um),
        theta_rad: crate::daemon::vision::wrap_angle_rad(theta0 + turn),
        quality: mean(|m| m.quality),
    }
}

/// A point's frames, exposed, their decodes running on the decode worker
/// ([`Vision::defer`](crate::daemon::vision::Vision::defer)).
#[derive(Debug)]
pub(crate) struct Exposed {
    frames: Vec<Deferred>,
}

/// Exposes `n` fresh frames (grab requested at or after `after_s`, as in
/// [`measure`]) and returns as soon as the last exposure has ended, their
/// decodes still running; [`finish`] waits for them. `Ok(None)` when the
/// pipeline decodes as it goes (free-running: use [`measure`]). Each frame
/// must come within `camera.timeout_ms` of the previous one, or of the
/// call; otherwise the point fails with `camera_stalled` (transient).
pub(crate) async fn expose(rig: &Rig, n: u32, after_s: f64) -> Result<Option<Exposed>, ProtoError> {
    let Some(v) = &rig.vision else {
        return Err(ProtoError::new(ErrorCode::CameraUnavailable, "no camera"));
    };
    let timeout = Duration::from_millis(rig.cfg.camera.timeout_ms);
    let mut frames: Vec<Deferred> = Vec::new();
    while frames.len() < n as usize {
        let Some((want, rx)) = v.defer() else {
            return Ok(None);
        };
        let got = tokio::time::timeout(timeout, rx).await;
        drop(want);
        let d = match got {
            Ok(Ok(d)) => d,
            Ok(Err(_)) => {
                finish_all(v, frames).await;
                return Err(ProtoError::new(
                    ErrorCode::CameraUnavailable,
                    "the camera pipeline ended",
                ));
            }
            Err(_) => {
                let why = v
                    .last_error_text()
                    .unwrap_or_else(|| "no error reported".to_owned());
                let measured = frames.len();
                finish_all(v, frames).await;
                return Err(ProtoError::new(
                    ErrorCode::CameraStalled,
                    format!(
                        "no frame exposed after the settle arrived from the camera within {} ms (last error: {why}); {measured} of {n} frames exposed, the point was not logged",
                        timeout.as_millis()
                    ),
                )
                .into_transient());
            }
        };
        if d.request_t_s() >= after_s {
            frames.push(d);
        } else {
            // Exposed before the settle (a grab that was under way): it is
            // published as any frame, and does not count.
            let _ = v.finish(d).await;
        }
    }
    Ok(Some(Exposed { frames }))
}

/// Publishes deferred frames nobody will use (their counts stay whole).
async fn finish_all(v: &crate::daemon::vision::Vision, frames: Vec<Deferred>) {
    for d in frames {
        let _ = v.finish(d).await;
    }
}

/// Waits for the decodes of an exposed point (the rig clock stands still
/// meanwhile), publishes each, and averages them as [`measure`] does.
/// `Err` says why the point has no measurement: a frame did not decode or
/// decoded below `camera.min_quality`; the caller measures it again.
pub(crate) async fn finish(rig: &Rig, e: Exposed) -> Result<(Measurement, f64), String> {
    let Some(v) = &rig.vision else {
        return Err("no camera".to_owned());
    };
    let mut got = Vec::with_capacity(e.frames.len());
    let mut why = None;
    for d in e.frames {
        match v.finish(d).await {
            Ok(m) if m.quality >= rig.cfg.camera.min_quality => got.push(m),
            Ok(m) => {
                why.get_or_insert(format!(
                    "a frame decoded at quality {:.2}, below camera.min_quality = {}",
                    m.quality, rig.cfg.camera.min_quality
                ));
            }
            Err(w) => {
                why.get_or_insert(w);
            }
        }
    }
    match why {
        Some(w) => Err(w),
        None if got.is_empty() => Err("no frame".to_owned()),
        None => {
            let m = average(&got);
            Ok((m, m.quality))
        }
    }
}

/// [`expose`] of `n` frames exposed from now on, retried after transient
/// camera faults as [`measure_retrying`].
pub(crate) async fn expose_retrying(rig: &Rig, n: u32) -> Result<Option<Exposed>, ProtoError> {
    rig.retry_transient("measure", || expose(rig, n, rig.clock.now_s()))
        .await
}

/// An absolute raw move and wait, retried after transient faults.
pub(crate) async fn move_raw_retrying(
    rig: &Arc<Rig>,
    x: f64,
    y: f64,
) -> Result<MoveReply, ProtoError> {
    let req = MoveRequest::raw_to(x, y);
    rig.retry_transient(&format!("move to ({x:.3}, {y:.3}) µm"), || {
        rig.move_to(&req, true)
    })
    .await
}

/// [`measure`] of `n` frames exposed from now on, retried after transient
/// camera faults (each retry waits for frames exposed after it began).
pub(crate) async fn measure_retrying(rig: &Rig, n: u32) -> Result<(Measurement, f64), ProtoError> {
    rig.retry_transient("measure", || measure(rig, n, rig.clock.now_s()))
        .await
}

/// `(x, y)` clamped into the allowed travel (soft limits ∩ controller
/// travel, as `status.limits`); unchanged when the limits are unknown.
pub(crate) fn clamp_to_travel(rig: &Rig, x: f64, y: f64) -> (f64, f64) {
    let Some(l) = rig.status().limits else {
        return (x, y);
    };
    let clamp = |v: f64, [lo, hi]: [f64; 2]| if lo <= hi { v.clamp(lo, hi) } else { v };
    (clamp(x, l.x_um), clamp(y, l.y_um))
}
