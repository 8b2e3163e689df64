//! The rig's safe state: the motion core's decisions carried out (halts,
//! faults, reset), a returning line's axis recovered, and the vision
//! against controller deviation check fed and its verdicts applied.

use super::Rig;
use crate::daemon::motion_core::Decision;
use crate::daemon::protocol::{
    to_value, AxisReadBack, AxisRecoveredEvent, ClearedEvent, DeviationStatus, FaultEvent,
    HaltReport, HaltedEvent, PerAxis, ResetReply, TimedReason,
};
use crate::daemon::state::{AxisId, Input};
use crate::driver::DriverError;
use std::sync::Arc;
use std::time::Duration;

impl Rig {
    /// The vision → stage orientation for the deviation check and where
    /// it comes from: the frame in force ([`Rig::vision_frame`]: the rig's
    /// tie, else the active table's), else with `safety.deviation_frame =
    /// "camera"` the configured camera rotation; `Err`: none, why (no
    /// check).
    pub(super) fn deviation_frame(&self) -> Result<(crate::comp::VisionFrame, String), String> {
        if self.vision.is_none() {
            return Err("no camera is configured (camera.source)".to_owned());
        }
        let why = match self.vision_frame() {
            Ok(f) => return Ok((f.frame, f.source)),
            Err(why) => why,
        };
        if self.cfg.safety.deviation_frame == crate::daemon::config::DeviationFrame::Camera {
            return Ok((
                crate::comp::VisionFrame {
                    rotation_rad: self.cfg.camera.rotation_rad,
                    mirrored: false,
                    translation_um: [0.0, 0.0],
                },
                "camera.rotation_rad (safety.deviation_frame = \"camera\")".to_owned(),
            ));
        }
        Err(format!("vision is not tied to the stage: {why}"))
    }

    /// A controller position read of `axis` between `t0_s` and `t1_s`
    /// (poller or supervisor): input of the deviation check.
    pub(crate) fn deviation_read(self: &Arc<Self>, axis: AxisId, t0_s: f64, t1_s: f64, um: f64) {
        self.core().controller_read(axis, t0_s, t1_s, um);
        self.judge_deviation();
    }

    /// Judges the frames that can be judged; a breach is a fault. The
    /// first tie at rest under the rig's own tie confirms a tie restored at
    /// start ([`Rig::confirm_tie`]).
    pub(super) fn judge_deviation(self: &Arc<Self>) {
        let frame = self.deviation_frame();
        let from_tie = frame.as_ref().is_ok_and(|(_, src)| src.starts_with("tie "));
        let r = self.core().judge_deviation(frame);
        if let Some(tie) = r.tied_um {
            tracing::info!(
                "vision deviation check tied at rest: translation x {:.1} µm, y {:.1} µm",
                tie[0],
                tie[1]
            );
            if from_tie {
                self.confirm_tie(tie);
            }
        }
        if let Some(reason) = r.fault {
            self.supervisor_fault(reason);
        }
    }

    /// The deviation check's state (for `status`), with the frame it
    /// would use now.
    pub fn deviation_status(&self) -> DeviationStatus {
        let frame = self.deviation_frame();
        self.core().deviation_status(frame)
    }

    /// A breach found by the motion supervisor: halts both axes, latches.
    pub(crate) fn supervisor_fault(self: &Arc<Self>, reason: String) {
        tracing::error!("motion supervisor: {reason}");
        self.apply(Input::Fault(reason));
    }

    /// Feeds the motion core's state machine and carries out what it
    /// decides.
    pub fn apply(self: &Arc<Self>, input: Input) {
        let t = self.clock.now_s();
        let decisions = self.core().apply(input, t);
        for d in decisions {
            match d {
                Decision::HaltAndLatch { reason } => {
                    tracing::warn!("halting both axes: {reason}");
                    self.metrics.record_fault();
                    self.emit(&FaultEvent {
                        t_s: t,
                        reason: reason.clone(),
                        latched: Some(true),
                    });
                    let rig = self.clone();
                    tokio::spawn(async move {
                        let r = rig.wait_at_rest(rig.halt_all().await).await;
                        tracing::warn!("after the fault: {}", to_value(&r));
                    });
                }
            }
        }
    }

    /// Halts both axes at once (`HLT` ahead of each line's queue:
    /// [`Axis::halt_now`]); errors (a dead line) are logged, not fatal.
    pub(super) async fn halt_all(&self) -> Vec<(AxisId, Result<(), DriverError>)> {
        let Ok(stage) = self.stage() else {
            return vec![];
        };
        self.core().halting();
        let (x, y) = tokio::join!(stage.x.halt_now(), stage.y.halt_now());
        let mut out = vec![(AxisId::X, x), (AxisId::Y, y)];
        for (a, r) in &mut out {
            if let Err(e) = r {
                tracing::warn!("halt of axis {} failed: {e}", a.name());
            }
        }
        self.core().halted();
        out
    }

    /// Halts both axes (`HLT`, after overtaking queued moves and stopping
    /// the supervisor's watches) and waits until both report no motion
    /// (`#5`) or `safety.halt_wait_s` passed. Why wait: a shutdown or a
    /// job cancel must not return while the stage still moves; a smooth
    /// halt decelerates, it does not stop at once. `why` goes to the log
    /// and to `fault` subscribers (`halted` event).
    ///
    /// Logged at info: it is asked for (a shutdown, a job cancel) and ends
    /// every normal run, so a warning would teach a lab to ignore
    /// warnings. A halt that leaves an axis moving or fails is a warning;
    /// a fault's halt ([`Rig::apply`]) is one too.
    pub async fn halt_and_wait(&self, why: &str) -> HaltReport {
        self.core().begin_stop(why);
        tracing::info!("halting both axes: {why}");
        let t = self.clock.now_s();
        let halts = self.halt_all().await;
        let mut r = self.wait_at_rest(halts).await;
        r.reason = Some(why.to_owned());
        self.emit(&HaltedEvent {
            t_s: t,
            reason: why.to_owned(),
            at_rest: r.at_rest,
            wait_s: r.wait_s,
        });
        let shown = to_value(&r);
        if r.at_rest && r.errors.is_empty() {
            tracing::info!("halt ({why}): both axes at rest: {shown}");
        } else {
            tracing::warn!("halt ({why}) did not bring both axes to rest: {shown}");
        }
        r
    }

    /// Polls `#5` on both axes until neither moves, at most
    /// `safety.halt_wait_s` (tokio's timer: the wait must not advance a
    /// simulated rig's clock). `halts`: what the halts returned.
    pub(super) async fn wait_at_rest(
        &self,
        halts: Vec<(AxisId, Result<(), DriverError>)>,
    ) -> HaltReport {
        let errors: Vec<String> = halts
            .iter()
            .filter_map(|(a, r)| r.as_ref().err().map(|e| format!("axis {}: {e}", a.name())))
            .collect();
        let Ok(stage) = self.stage() else {
            return HaltReport {
                at_rest: false,
                moving: None,
                wait_s: 0.0,
                errors: vec!["not connected".to_owned()],
                reason: None,
            };
        };
        let t0 = tokio::time::Instant::now();
        let bound = Duration::try_from_secs_f64(self.cfg.safety.halt_wait_s).unwrap_or_default();
        let step = Duration::from_millis(self.cfg.driver.x.poll_interval_ms.max(5));
        let moving = loop {
            let (x, y) = tokio::join!(stage.x.is_moving(), stage.y.is_moving());
            // An axis that does not answer is not known to be at rest.
            let moving = [x.unwrap_or(true), y.unwrap_or(true)];
            if moving == [false, false] || t0.elapsed() >= bound {
                break moving;
            }
            tokio::time::sleep(step).await;
        };
        HaltReport {
            at_rest: moving == [false, false],
            moving: Some(PerAxis::of(moving)),
            wait_s: t0.elapsed().as_secs_f64(),
            errors,
            reason: None,
        }
    }

    /// `reset`: acknowledges the latched fault. Motion is allowed again
    /// (an axis whose reference was lost stays unreferenced: reference it).
    pub fn reset(&self) -> ResetReply {
        let t = self.clock.now_s();
        let (cleared, state) = {
            let mut c = self.core();
            let cleared = c.reset(t);
            (cleared, c.state().to_reply())
        };
        let cleared = cleared.map(|f| TimedReason {
            t_s: f.t_s,
            reason: f.reason,
        });
        if let Some(c) = &cleared {
            // As the log showed it: the reason as a JSON string.
            tracing::info!(
                "fault reset by a client: {}",
                serde_json::Value::from(c.reason.as_str())
            );
            self.emit(&ClearedEvent {
                t_s: t,
                cleared: c.clone(),
            });
        }
        ResetReply {
            cleared,
            rig: state,
        }
    }

    /// A line came back: its axis is halted (the controller kept running
    /// while nobody could reach it) and read back (`status`) before
    /// anything else; the line loss stays latched until `reset`.
    pub(super) async fn recover_axis(self: Arc<Self>, a: AxisId) {
        let Ok(stage) = self.stage() else { return };
        let axis = match a {
            AxisId::X => stage.x.clone(),
            AxisId::Y => stage.y.clone(),
        };
        let t = self.clock.now_s();
        let halt = axis.halt().await;
        let status = axis.status().await;
        let event = match (&halt, &status) {
            (Ok(()), Ok(s)) => AxisRecoveredEvent {
                t_s: t,
                axis: a.name().to_owned(),
                halted: true,
                read_back: Some(AxisReadBack {
                    referenced: s.referenced,
                    servo_on: s.servo_on,
                    on_target: s.on_target,
                    position_um: s.position_um,
                    target_um: s.target_um,
                }),
                error: None,
            },
            _ => AxisRecoveredEvent {
                t_s: t,
                axis: a.name().to_owned(),
                halted: halt.is_ok(),
                read_back: None,
                error: halt.err().or(status.err()).map(|e| e.to_string()),
            },
        };
        tracing::warn!(
            "axis {} reconnected, halted and read back: {}",
            a.name(),
            to_value(&event)
        );
        self.emit(&event);
    }
}
