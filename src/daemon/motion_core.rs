//! The motion core, sans-IO: the move policy of the rig in one plain
//! struct (no async, no locks, no clock reads, no I/O), as quinn-proto's
//! `Connection` or this crate's `gcs::Session`. Inputs are what happened
//! (a move request, a move sent at a time, a stop, a fault, a driver
//! event, a position read, a vision measurement, a supervisor sample);
//! outputs are decisions (refuse with a reason, these axis targets,
//! [`Decision::HaltAndLatch`]). The async rig (`daemon::rig`) holds it
//! under one `std::sync::Mutex`, never across an `.await`, carries the
//! decisions out through the driver and feeds the results back.
//!
//! What it owns (and the rules, each unit-tested in `tests.rs`):
//! - the safe-state machine ([`SafetyState`]): a move is refused while a
//!   fault is latched, while the stage or a line is down, while a reference
//!   run or (for a client) a job owns the axes, and for an axis that is not
//!   referenced; a fault latches and only `reset` clears it;
//! - the stop generation and the reason of the last stop: a stop, halt or
//!   fault moves the generation on, so a move queued before it is refused
//!   when its turn comes and a move cut short names why
//!   ([`MotionCore::halted_because`]); the generation only grows;
//! - the commanded targets `[x, y]` µm (what the last accepted move asked;
//!   forgotten on every halt);
//! - the soft limits: a target outside soft limits ∩ controller travel is
//!   refused before anything is sent ([`allowed_range_um`],
//!   [`target_within`]);
//! - the motion supervisor ([`Supervisor`]): watches what was sent, judges
//!   the samples; a breach is a fault;
//! - the vision deviation judge ([`DeviationJudge`]): commanded targets,
//!   controller reads and vision measurements in, a breach is a fault;
//! - the controllers' positions as last polled (for `position`, `/metrics`
//!   and the tie's confirmation).
//!
//! Invariants (property-tested in `tests.rs`): no input sequence yields
//! accepted move targets while a fault is latched; every accepted target
//! is within the allowed range; the stop generation never decreases.

#[cfg(test)]
mod tests;

use super::protocol::{DeviationStatus, ErrorCode, ProtoError};
use super::state::{Action, Activity, AxisId, FaultRecord, Input, Refusal, SafetyState};
use super::supervisor::{AxisSample, Bounds, ReadFailure, Supervisor};
use crate::comp::VisionFrame;
use crate::daemon::deviation::{DeviationJudge, Judged};
use crate::driver::DriverError;

/// What the shell must carry out.
#[derive(Debug, Clone, PartialEq)]
pub enum Decision {
    /// A fault latched: halt both axes now (ahead of every queue), wait
    /// until they are at rest, tell `fault` subscribers. Every move in
    /// flight was already overtaken (the stop generation moved on) and the
    /// supervisor's watches dropped.
    HaltAndLatch {
        /// Why (the fault's reason).
        reason: String,
    },
}

/// Positions last read from the controllers.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Reported {
    /// Rig time of the read, s.
    pub t_s: f64,
    /// X, µm (`None`: the read failed).
    pub x_um: Option<f64>,
    /// Y, µm.
    pub y_um: Option<f64>,
}

/// The move policy's state; see the module header.
#[derive(Debug, Clone)]
pub struct MotionCore {
    state: SafetyState,
    commanded: [Option<f64>; 2],
    reported: Reported,
    stop_gen: u64,
    /// Why the last stop, halt or fault overtook the moves in flight.
    stop_why: String,
    supervisor: Supervisor,
    deviation: DeviationJudge,
}

/// The range a target of an axis may have, µm: the soft limits (`None`:
/// none on that side) ∩ the controller's travel `(min, max)`. Why both:
/// the soft limits protect what is mounted on the stage, the travel the
/// stage itself, and a reload may widen the soft limits past the travel.
pub fn allowed_range_um(
    travel_um: (f64, f64),
    soft_min_um: Option<f64>,
    soft_max_um: Option<f64>,
) -> (f64, f64) {
    let (tmin, tmax) = travel_um;
    (
        soft_min_um.map_or(tmin, |v| v.max(tmin)),
        soft_max_um.map_or(tmax, |v| v.min(tmax)),
    )
}

/// The target of axis `a` for a requested value `v_um` (relative to
/// `base_um` if given: the commanded position, else the controller's
/// target), checked against `range_um`: outside it the move is refused
/// before any byte is sent (a NaN is outside every range).
pub fn target_within(
    a: AxisId,
    v_um: f64,
    base_um: Option<f64>,
    range_um: (f64, f64),
) -> Result<f64, ProtoError> {
    let t = base_um.map_or(v_um, |b| b + v_um);
    let (lo, hi) = range_um;
    if !(lo..=hi).contains(&t) {
        return Err(ProtoError::new(
            ErrorCode::OutOfTravel,
            format!(
                "axis {} target {t:.3} µm is outside the allowed range {lo:.3}..{hi:.3} µm (soft limits ∩ controller travel); nothing was sent",
                a.name()
            ),
        ));
    }
    Ok(t)
}

/// The fault a failed send of a move is (`None`: only the client's
/// failure). A controller error nobody had read (a servo fault, say) is a
/// fault as the supervisor would meet it.
pub fn fault_of_send(e: &DriverError) -> Option<String> {
    matches!(e, DriverError::PendingError { .. }).then(|| format!("before a move: {e}"))
}

/// The fault a failed wait for a move is (`None`: only the client's
/// failure): a controller error or a motion timeout while waiting halts
/// both axes and latches, whoever waited.
pub fn fault_of_wait(e: &DriverError) -> Option<String> {
    matches!(
        e,
        DriverError::MotionTimeout { .. } | DriverError::Gcs { .. }
    )
    .then(|| format!("while waiting for a move: {e}"))
}

/// A refusal of the state machine as the protocol error a client reads.
pub fn refusal(r: Refusal) -> ProtoError {
    match r {
        Refusal::NotConnected(m) => ProtoError::new(ErrorCode::NotConnected, m),
        Refusal::NotReferenced(a) => ProtoError::new(
            ErrorCode::NotReferenced,
            format!(
                "axis {} is not referenced; send reference first (CLI: `micropos reference {}`)",
                a.name(),
                a.name()
            ),
        ),
        Refusal::Busy(a) => ProtoError::new(
            ErrorCode::Busy,
            format!("the axes are busy ({a:?}); stop it or wait"),
        ),
        Refusal::FaultLatched(m) => ProtoError::new(
            ErrorCode::FaultLatched,
            format!("a fault is latched ({m}); find its cause, then send reset"),
        ),
    }
}

const fn idx(a: AxisId) -> usize {
    match a {
        AxisId::X => 0,
        AxisId::Y => 1,
    }
}

impl MotionCore {
    /// Before the stage connected: nothing may move. `bounds`: the
    /// supervisor's; `deviation_um`: the deviation judge's bound (0: off).
    pub fn new(bounds: Bounds, deviation_um: f64) -> Self {
        Self {
            state: SafetyState::new(),
            commanded: [None, None],
            reported: Reported::default(),
            stop_gen: 0,
            stop_why: String::new(),
            supervisor: Supervisor::new(bounds),
            deviation: DeviationJudge::new(deviation_um),
        }
    }

    /// The safe-state machine (read only: inputs go through
    /// [`MotionCore::apply`] and the named methods).
    pub fn state(&self) -> &SafetyState {
        &self.state
    }

    /// Feeds the state machine at rig time `t_s`. A fault overtakes every
    /// move in flight (`fault: <reason>`) and drops the supervisor's
    /// watches before the shell halts the axes.
    pub fn apply(&mut self, input: Input, t_s: f64) -> Vec<Decision> {
        let actions = self.state.apply(input, t_s);
        actions
            .into_iter()
            .map(|Action::HaltAll { reason }| {
                self.begin_stop(&format!("fault: {reason}"));
                self.supervisor.clear();
                Decision::HaltAndLatch { reason }
            })
            .collect()
    }

    /// An activity ended (a move, a reference run, a job).
    pub fn end(&mut self, activity: Activity, t_s: f64) {
        self.state.apply(Input::End(activity), t_s);
    }

    /// A client's `stop`: overtakes the moves in flight, ends the activity
    /// and drops the watches; no fault latches. The shell halts the axes.
    pub fn stop(&mut self, why: &str, t_s: f64) {
        self.begin_stop(why);
        // The machine's halt is the one the shell sends now: a stop is no
        // fault, nothing else to carry out.
        self.state.apply(Input::Stop, t_s);
        self.supervisor.clear();
    }

    /// A stop, halt or fault overtakes every move in flight: the
    /// generation moves on and `why` is kept for the moves it cuts short.
    pub fn begin_stop(&mut self, why: &str) {
        why.clone_into(&mut self.stop_why);
        self.stop_gen = self.stop_gen.saturating_add(1);
    }

    /// The stop generation: a move or job compares it to notice a stop or
    /// a fault since it began.
    pub fn stop_generation(&self) -> u64 {
        self.stop_gen
    }

    /// A move's `halted` error with the reason of the stop, halt or fault
    /// that came since generation `gen`: "the move was halted" alone leaves
    /// a client (or a job's log) guessing whether a user, a cancel or a
    /// fault did it.
    pub fn halted_because(&self, mut e: ProtoError, gen: u64) -> ProtoError {
        if e.code == ErrorCode::Halted && self.stop_gen != gen && !self.stop_why.is_empty() {
            e.message = format!("{} (halted by the daemon: {})", e.message, self.stop_why);
        }
        e
    }

    /// Whether a move of the axes in `want` queued at generation `gen` may
    /// start now: not if a stop or fault came since (it was overtaken),
    /// nor if the state forbids it.
    pub fn admit_move(&self, gen: u64, want: [bool; 2], from_job: bool) -> Result<(), ProtoError> {
        if self.stop_gen != gen {
            return Err(self.halted_because(
                ProtoError::new(
                    ErrorCode::Halted,
                    "a stop or fault came before this move started; it was not sent",
                ),
                gen,
            ));
        }
        self.state.may_move(want, from_job).map_err(refusal)
    }

    /// The commanded position `[x, y]` µm (what the last accepted move
    /// asked; `None` after a halt, before the first move).
    pub fn commanded(&self) -> [Option<f64>; 2] {
        self.commanded
    }

    /// A move begins (it is sent next).
    pub fn begin_move(&mut self, t_s: f64) {
        self.state.apply(Input::Begin(Activity::Moving), t_s);
    }

    /// A move's targets were sent between `t0_s` and `t1_s`; `accepted`:
    /// per axis, whether its send succeeded. Sent or not (a failed send
    /// may have reached the controller), the deviation check widens its
    /// span by the target; only an accepted target becomes the commanded
    /// position.
    pub fn move_sent(
        &mut self,
        targets: [Option<f64>; 2],
        accepted: [bool; 2],
        t0_s: f64,
        t1_s: f64,
    ) {
        for a in [AxisId::X, AxisId::Y] {
            if let Some(tg) = targets[idx(a)] {
                self.deviation.commanded(a, t0_s, t1_s, tg);
            }
        }
        for ((c, tg), ok) in self.commanded.iter_mut().zip(targets).zip(accepted) {
            if ok && tg.is_some() {
                *c = tg;
            }
        }
    }

    /// The move queued at generation `gen` was sent and is in flight from
    /// `t_s`: the supervisor watches each axis until it is on target. Not
    /// if a stop or fault came since (`false`: the shell halts the axes
    /// again, its halt may have reached the controller before the move):
    /// checked and watched at once, so a halt's dropped watches are never
    /// replaced by the move it halted.
    pub fn watch_sent(&mut self, gen: u64, targets: [Option<f64>; 2], t_s: f64) -> bool {
        if self.stop_gen != gen {
            return false;
        }
        for a in [AxisId::X, AxisId::Y] {
            if let Some(tg) = targets[idx(a)] {
                self.supervisor.watch(a, tg, t_s);
            }
        }
        true
    }

    /// Both axes are about to be halted: no move is watched any more.
    pub fn halting(&mut self) {
        self.supervisor.clear();
    }

    /// Both axes were halted: where they stop is not what was commanded.
    pub fn halted(&mut self) {
        self.commanded = [None, None];
    }

    /// A reference run takes the axes (refused unless idle, connected and
    /// not latched); it supersedes the moves watched so far.
    pub fn begin_reference(&mut self, t_s: f64) -> Result<(), ProtoError> {
        self.state.may_take_axes().map_err(refusal)?;
        self.state.apply(Input::Begin(Activity::Referencing), t_s);
        self.supervisor.clear();
        Ok(())
    }

    /// A reference run ended with the axes at `at_um` (`None`: not run):
    /// that is their commanded position now.
    pub fn reference_done(&mut self, at_um: [Option<f64>; 2]) {
        for (c, at) in self.commanded.iter_mut().zip(at_um) {
            if at.is_some() {
                *c = at;
            }
        }
    }

    /// A job takes the axes (refused unless idle, connected and not
    /// latched).
    pub fn begin_job(&mut self, t_s: f64) -> Result<(), ProtoError> {
        self.state.may_take_axes().map_err(refusal)?;
        self.state.apply(Input::Begin(Activity::Job), t_s);
        Ok(())
    }

    /// `reset`: acknowledges the latched fault (returned, `None` if none
    /// was latched) and lets the deviation check tie afresh.
    pub fn reset(&mut self, t_s: f64) -> Option<FaultRecord> {
        let cleared = self.state.latched().cloned();
        self.state.apply(Input::Reset, t_s);
        self.deviation.retie();
        cleared
    }

    /// The controllers' zero may have changed (connect, reference run):
    /// the deviation check ties afresh.
    pub fn retie(&mut self) {
        self.deviation.retie();
    }

    /// Which axes have a move watched by the supervisor.
    pub fn watching(&self) -> [bool; 2] {
        self.supervisor.watching()
    }

    /// Whether the watched move of `a` still needs the axis velocity.
    pub fn needs_velocity(&self, a: AxisId) -> bool {
        self.supervisor.needs_velocity(a)
    }

    /// The axis velocity (`VEL?`) for the watched move of `a`.
    pub fn set_velocity(&mut self, a: AxisId, v_um_s: f64) {
        self.supervisor.set_velocity(a, v_um_s);
    }

    /// The supervisor's verdict on a sample of `a` taken between `t0_s`
    /// and `t1_s`: `Err` names the breach (the shell makes it a fault).
    pub fn observe(
        &mut self,
        a: AxisId,
        t0_s: f64,
        t1_s: f64,
        s: &AxisSample,
    ) -> Result<(), String> {
        self.supervisor.observe(a, t0_s, t1_s, s)
    }

    /// A position read of `a` at `t_s` (poller): reads failing too long
    /// are a breach (its reason).
    pub fn read_result(
        &mut self,
        a: AxisId,
        t_s: f64,
        r: &Result<f64, ReadFailure>,
    ) -> Option<String> {
        self.supervisor.read_result(a, t_s, r)
    }

    /// A controller read of `a` between `t0_s` and `t1_s`: input of the
    /// deviation check.
    pub fn controller_read(&mut self, a: AxisId, t0_s: f64, t1_s: f64, um: f64) {
        self.deviation.controller(a, t0_s, t1_s, um);
    }

    /// A vision measurement of a frame exposed between `t0_s` and `t1_s`:
    /// input of the deviation check.
    pub fn vision(&mut self, t0_s: f64, t1_s: f64, x_um: f64, y_um: f64) {
        self.deviation.vision(t0_s, t1_s, x_um, y_um);
    }

    /// Judges the frames that can be judged under `frame` (the vision →
    /// stage orientation and its source, or why there is none). A tie
    /// needs both axes at rest: no move watched and no reference run.
    /// `Judged::fault` is a breach the shell must apply as a fault.
    pub fn judge_deviation(&mut self, frame: Result<(VisionFrame, String), String>) -> Judged {
        let quiet = self.supervisor.watching() == [false, false]
            && self.state.activity() != Activity::Referencing;
        self.set_deviation_frame(frame);
        self.deviation.judge(quiet)
    }

    /// The deviation check's state (for `status`) under `frame`.
    pub fn deviation_status(
        &mut self,
        frame: Result<(VisionFrame, String), String>,
    ) -> DeviationStatus {
        self.set_deviation_frame(frame);
        self.deviation.to_reply()
    }

    fn set_deviation_frame(&mut self, frame: Result<(VisionFrame, String), String>) {
        match frame {
            Ok((f, src)) => self.deviation.set_frame(Some(f), src),
            Err(why) => self.deviation.set_frame(None, why),
        }
    }

    /// The controllers' positions as last polled.
    pub fn reported(&self) -> Reported {
        self.reported
    }

    /// A poll of both controllers' positions.
    pub fn set_reported(&mut self, r: Reported) {
        self.reported = r;
    }
}
