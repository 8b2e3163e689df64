//! The supervisor's task: samples the watched axes on tokio's timer and
//! hands the samples to the sans-IO judge ([`Supervisor`](crate::daemon::supervisor::Supervisor));
//! a breach becomes a fault of the rig.

use super::Rig;
use crate::daemon::state::AxisId;
use crate::daemon::supervisor::{AxisSample, ReadFailure, UncheckedMove};
use crate::driver::Axis;
use std::sync::Arc;
use std::time::Duration;
use tokio::sync::broadcast;

/// Samples one watched axis: `VEL?` once per move, then `ERR?`, the
/// position and `ONT?`.
async fn sample(rig: &Arc<Rig>, a: AxisId, axis: &Axis) -> (f64, f64, AxisSample) {
    let needs_velocity = rig.core().needs_velocity(a);
    if needs_velocity {
        if let Ok(v) = axis.velocity_um_per_s().await {
            rig.core().set_velocity(a, v);
        }
    }
    let t0 = rig.clock.now_s();
    let error = axis.controller().error().await.ok();
    let tp = rig.clock.now_s();
    let position_um = axis.position_um().await.map_err(|e| ReadFailure::of(&e));
    if let Ok(um) = position_um {
        rig.deviation_read(a, tp, rig.clock.now_s(), um);
    }
    let on_target = match position_um {
        Ok(_) => axis.on_target().await.ok(),
        Err(_) => None,
    };
    let t1 = rig.clock.now_s();
    (
        t0,
        t1,
        AxisSample {
            error,
            position_um,
            on_target,
        },
    )
}

/// The supervisor task: samples the watched axes every
/// `safety.supervise_interval_ms` (tokio's timer; judged on the rig's
/// clock) and turns a breach into a fault. Each clean round of a watched
/// move feeds the watchdog heartbeat: the rig is supervised.
pub async fn run(rig: Arc<Rig>, mut shutdown: broadcast::Receiver<()>) {
    let period = Duration::from_millis(rig.cfg.safety.supervise_interval_ms);
    let mut unchecked = UncheckedMove::default();
    loop {
        tokio::select! {
            _ = tokio::time::sleep(period) => {},
            _ = shutdown.recv() => return,
        }
        let _sampling = rig.sampling.lock().await;
        let watching = rig.core().watching();
        if let Some(v) = &rig.vision {
            let counts = (
                v.stats.frames.load(std::sync::atomic::Ordering::Relaxed),
                v.stats.decoded.load(std::sync::atomic::Ordering::Relaxed),
            );
            if let Some((frames, rounds)) = unchecked.update(watching != [false, false], counts) {
                let t = rig.clock.now_s();
                tracing::warn!(
                    "{frames} camera frames during a move, none decoded: the vision deviation check is not running"
                );
                rig.push(
                    crate::daemon::protocol::Topic::Fault,
                    "vision_unchecked",
                    serde_json::json!({"t_s": t, "frames": frames, "rounds": rounds,
                        "reason": "frames arrive during the move but none decode: vision is not compared with the controllers"}),
                );
            }
        }
        if watching == [false, false] || rig.referencing() {
            continue;
        }
        let Some(stage) = rig.connected_stage() else {
            continue;
        };
        let one = |a: AxisId, axis: &Axis, on: bool| {
            let axis = axis.clone();
            let rig = &rig;
            async move {
                if on {
                    Some(sample(rig, a, &axis).await)
                } else {
                    None
                }
            }
        };
        let (sx, sy) = tokio::join!(
            one(AxisId::X, &stage.x, watching[0]),
            one(AxisId::Y, &stage.y, watching[1])
        );
        let mut faults = Vec::new();
        let mut clean = true;
        for (a, s) in [(AxisId::X, sx), (AxisId::Y, sy)] {
            let Some((t0, t1, s)) = s else { continue };
            clean &= s.position_um.is_ok();
            let verdict = rig.core().observe(a, t0, t1, &s);
            if let Err(reason) = verdict {
                faults.push(reason);
            }
        }
        if clean {
            rig.beat();
        }
        if !faults.is_empty() {
            rig.supervisor_fault(faults.join("; "));
        }
    }
}
