//! The motion coordinator's I/O: one move at a time per stage, raw and
//! planned (`compensated`, `closed_loop`) moves, `stop`. What a move may
//! do (admission, soft limits, the stop generation, what a failure is) is
//! decided by the motion core (`daemon::motion_core`); this file sends
//! what it decides and feeds back what the controllers answered.

use super::{driver_error, ActivityGuard, Rig};
use crate::daemon::motion_core as core;
use crate::daemon::protocol::{
    ErrorCode, MoveMode, MoveReply, MoveRequest, PairUm, ProtoError, StopReply, StoppedEvent,
    TimedReason,
};
use crate::daemon::state::{Activity, AxisId, Input};
use crate::driver::Axis;
use std::sync::Arc;

impl Rig {
    /// Soft limits ∩ controller travel for an axis, µm.
    pub fn limits_um(&self, axis: &Axis, a: AxisId) -> (f64, f64) {
        let l = &self.live.limits();
        let (lo, hi) = match a {
            AxisId::X => (l.x_min_um, l.x_max_um),
            AxisId::Y => (l.y_min_um, l.y_max_um),
        };
        core::allowed_range_um(axis.travel_um(), lo, hi)
    }

    /// A client or job move. Refused before any byte is sent if the state
    /// forbids it or a target is outside the limits.
    pub async fn move_to(
        self: &Arc<Self>,
        req: &MoveRequest,
        from_job: bool,
    ) -> Result<MoveReply, ProtoError> {
        self.move_with(req, from_job, None).await
    }

    /// [`Rig::move_to`] with the compensator (and the vision frame for
    /// closed loop) named by the caller instead of the active table: the
    /// validation job compares several tables without changing which one
    /// client moves use.
    pub async fn move_with(
        self: &Arc<Self>,
        req: &MoveRequest,
        from_job: bool,
        comp: Option<crate::daemon::comp::Active>,
    ) -> Result<MoveReply, ProtoError> {
        let r = match req.mode {
            MoveMode::Raw => self.raw_move(req, from_job, true).await,
            MoveMode::Compensated | MoveMode::ClosedLoop => {
                self.planned_move(req, from_job, comp).await
            }
        };
        self.metrics
            .record_move(r.as_ref().map(|_| ()).map_err(|e| e.code));
        r
    }

    /// The commanded position of both axes (cached, else queried).
    pub(super) async fn current_cmd(&self) -> Result<[f64; 2], ProtoError> {
        let stage = self.stage()?;
        let cached = self.commanded_um();
        let x = match cached[0] {
            Some(v) => v,
            None => stage.x.target_um().await.map_err(driver_error)?,
        };
        let y = match cached[1] {
            Some(v) => v,
            None => stage.y.target_um().await.map_err(driver_error)?,
        };
        Ok([x, y])
    }

    /// A `compensated` or `closed_loop` move: plan with the active
    /// compensator (closed loop without a table plans uncompensated), send
    /// the waypoints waiting for each, commit the plan to the history, then
    /// for closed loop correct from fresh frames.
    pub(super) async fn planned_move(
        self: &Arc<Self>,
        req: &MoveRequest,
        from_job: bool,
        named: Option<crate::daemon::comp::Active>,
    ) -> Result<MoveReply, ProtoError> {
        use super::closed_loop as c;
        let active = named.or_else(|| self.comp.active());
        let comp = match &active {
            Some(a) => a.comp.clone(),
            None => c::compensator_for(self, req.mode == MoveMode::Compensated)?,
        };
        let frame = if req.mode == MoveMode::ClosedLoop {
            if self.vision.is_none() {
                return Err(ProtoError::new(
                    ErrorCode::CameraUnavailable,
                    "closed_loop needs a camera (camera.source)",
                ));
            }
            let f = active.as_ref().and_then(|a| a.frame).ok_or_else(|| {
                ProtoError::new(
                    ErrorCode::NoActiveTable,
                    "closed_loop needs the vision → stage transform: activate a table built from a characterization (it records the frame)",
                )
            })?;
            Some(f)
        } else {
            None
        };
        let start = self.current_cmd().await?;
        let base = self
            .comp
            .last_user_target()
            .map_or(start, |t| [t.x_um, t.y_um]);
        let pick = |v: Option<f64>, b: f64| match v {
            Some(v) if req.relative => b + v,
            Some(v) => v,
            None => b,
        };
        let mut tool = super::tool::ToolTarget::of_request(self, req, active.as_ref())?;
        // A tool move: the watched point's target (first estimate; the
        // plan refines it with the yaw at its command).
        let target = match tool.as_mut() {
            Some(t) => t.first_target(),
            None => crate::model::XyUm {
                x_um: pick(req.x_um, base[0]),
                y_um: pick(req.y_um, base[1]),
            },
        };
        // Outside the table's characterized area: refused or warned before
        // anything moves (`[compensation] outside_table`). A closed loop
        // measures its arrival, so only compensated moves are checked.
        let outside = match &active {
            Some(a) if req.mode == MoveMode::Compensated => crate::daemon::comp::check_area(
                &*a.comp,
                &a.name,
                target,
                &self.live.compensation(),
                "target",
            )?,
            _ => None,
        };
        // Live drift: the table's command for `target − drift` lands on
        // `target` in today's state of the rig (see `daemon::drift`).
        let drift = if req.mode == MoveMode::Compensated {
            self.drift_correction(active.as_ref(), !from_job).await?
        } else {
            crate::daemon::drift::Correction::default()
        };
        let offset = drift.offset_um.unwrap_or([0.0, 0.0]);
        // A re-measurement moved the stage: plan from where it is now.
        let start = if drift.info.get("measured").is_some() {
            self.current_cmd().await?
        } else {
            start
        };
        let mut opts = self.live.compensation().plan_options();
        if frame.is_some() {
            // The first arrival ends with the loop's re-approach, as every
            // correction does (`ClosedLoopConfig::plan_options`).
            opts = c::loop_config(self, req.tolerance_um).plan_options(opts);
        }
        let (plan, target) =
            self.plan_target(&*comp, tool.as_mut(), target, offset, start, &opts)?;
        for w in &plan.waypoints {
            let r = MoveRequest::raw_to(w.x_um, w.y_um);
            self.raw_move(&r, from_job, false).await?;
        }
        self.comp.commit_plan(&plan, self.clock.now_s());
        self.comp.set_target_offset(offset);
        let mut out = MoveReply {
            mode: Some(req.mode.as_str().to_owned()),
            compensator: Some(comp.kind().to_owned()),
            target: Some(PairUm::of([target.x_um, target.y_um])),
            waypoints: Some(plan.waypoints.len() as u64),
            predicted_offset_um: Some(plan.predicted_offset_um),
            on_target: Some(true),
            drift: (self.drift.enabled() && req.mode == MoveMode::Compensated)
                .then_some(drift.info),
            outside_table: outside,
            tool: tool.as_ref().map(|t| t.reply(req.mode)),
            ..MoveReply::commanded([Some(plan.cmd.x_um), Some(plan.cmd.y_um)])
        };
        if let Some(frame) = frame {
            let cl = crate::comp::closed_loop::ClosedLoop::new(
                target,
                plan.cmd,
                plan.arrival,
                c::loop_config(self, req.tolerance_um),
            )
            .map_err(|e| ProtoError::new(ErrorCode::BadValue, format!("closed loop: {e}")))?;
            let me = self.clone();
            let res = c::run_loop(self, cl, frame, move |wps| {
                let me = me.clone();
                Box::pin(async move {
                    for w in wps {
                        let r = MoveRequest::raw_to(w.x_um, w.y_um);
                        me.raw_move(&r, from_job, true).await?;
                    }
                    Ok(())
                })
            })
            .await;
            // Done or not, the move was for the user's target.
            self.comp.restore_target(plan.target, offset);
            out.closed_loop = Some(res?);
        }
        Ok(out)
    }

    /// A raw move (also each waypoint of a planned move). `commit` records
    /// it in the motion history (planned moves commit their whole plan).
    pub(crate) async fn raw_move(
        self: &Arc<Self>,
        req: &MoveRequest,
        from_job: bool,
        commit: bool,
    ) -> Result<MoveReply, ProtoError> {
        let stage = self.stage()?;
        let gen = self.stop_generation();
        let _queue = self.motion.lock().await;
        let want = [req.x_um.is_some(), req.y_um.is_some()];
        self.core().admit_move(gen, want, from_job)?;
        let mut targets = [None, None];
        for (i, (a, axis, v)) in [
            (AxisId::X, &stage.x, req.x_um),
            (AxisId::Y, &stage.y, req.y_um),
        ]
        .into_iter()
        .enumerate()
        {
            let Some(v) = v else { continue };
            let base = if req.relative {
                let cached = self.commanded_um()[i];
                match cached {
                    Some(c) => Some(c),
                    None => Some(axis.target_um().await.map_err(driver_error)?),
                }
            } else {
                None
            };
            targets[i] = Some(core::target_within(a, v, base, self.limits_um(axis, a))?);
        }
        let t = self.clock.now_s();
        self.core().begin_move(t);
        let _guard = ActivityGuard {
            rig: self,
            activity: Activity::Moving,
        };
        let send = |axis: &Axis, t: Option<f64>| {
            let axis = axis.clone();
            async move {
                match t {
                    Some(t) => axis.move_abs_um(t).await.map(Some),
                    None => Ok(None),
                }
            }
        };
        let sent_t0 = self.clock.now_s();
        let (rx, ry) = tokio::join!(send(&stage.x, targets[0]), send(&stage.y, targets[1]));
        // When the move was sent (the supervisor's watch and the motion
        // history take it too: one clock read, which on a served simulator
        // is an exchange with it).
        let sent_t1 = self.clock.now_s();
        self.core()
            .move_sent(targets, [rx.is_ok(), ry.is_ok()], sent_t0, sent_t1);
        if let Err(e) = rx.and(ry) {
            // One axis may have started: a half-accepted move is halted.
            self.halt_all().await;
            if let Some(fault) = core::fault_of_send(&e) {
                self.apply(Input::Fault(fault));
            }
            return Err(driver_error(e));
        }
        if !self.core().watch_sent(gen, targets, sent_t1) {
            // A stop or a fault came while the move was being sent: its
            // halt (written ahead of the queue) may have reached the
            // controller before this `MOV`, which would then run on.
            self.halt_all().await;
            return Err(self.halted_because(
                ProtoError::new(
                    ErrorCode::Halted,
                    "a stop or fault came while this move was being sent; both axes were halted again",
                ),
                gen,
            ));
        }
        if commit {
            self.comp.commit_raw(targets, sent_t1);
        }
        let mut out = MoveReply::commanded(targets);
        if req.wait {
            let wait = |axis: &Axis, t: Option<f64>| {
                let axis = axis.clone();
                async move {
                    match t {
                        Some(_) => axis.wait_on_target(None).await.map(Some),
                        None => Ok(None),
                    }
                }
            };
            let (wx, wy) = tokio::join!(wait(&stage.x, targets[0]), wait(&stage.y, targets[1]));
            // A controller error or a motion timeout while waiting is a
            // fault (halt both, latch), not only this client's failure.
            for r in [&wx, &wy] {
                if let Some(fault) = r.as_ref().err().and_then(core::fault_of_wait) {
                    self.apply(Input::Fault(fault));
                }
            }
            let why = |e| self.halted_because(driver_error(e), gen);
            let (wx, wy) = (wx.map_err(why)?, wy.map_err(why)?);
            out.reported = Some(PairUm::of([wx, wy]));
            out.on_target = Some(true);
        }
        Ok(out)
    }

    /// Halts everything now: overtakes queued moves (they are refused when
    /// their turn comes), stops a job, sends `#24` to both controllers.
    pub async fn stop(self: &Arc<Self>) -> Result<StopReply, ProtoError> {
        const WHY: &str = "stop requested by a client";
        let t = self.clock.now_s();
        self.core().stop(WHY, t);
        self.emit(&StoppedEvent(TimedReason {
            t_s: t,
            reason: WHY.to_owned(),
        }));
        let stage = self.stage()?;
        let (x, y) = tokio::join!(stage.x.stop(), stage.y.stop());
        self.core().halted();
        let mut errors = Vec::new();
        for (n, r) in [("x", x), ("y", y)] {
            if let Err(e) = r {
                errors.push(format!("axis {n}: {e}"));
            }
        }
        if errors.is_empty() {
            Ok(StopReply { stopped: true })
        } else {
            Err(ProtoError::new(
                ErrorCode::DriverError,
                format!("stop sent, but: {}", errors.join("; ")),
            ))
        }
    }

    /// A stop generation: jobs compare it to notice a stop or a fault.
    pub fn stop_generation(&self) -> u64 {
        self.core().stop_generation()
    }

    /// A move's `halted` error with the reason of the stop, halt or fault
    /// that came since generation `gen` (`MotionCore::halted_because`).
    fn halted_because(&self, e: ProtoError, gen: u64) -> ProtoError {
        self.core().halted_because(e, gen)
    }
}
