//! The motion supervisor: every move, waited on by its client or not, is
//! watched until its axis is on target. Its own task samples each moving
//! axis every `safety.supervise_interval_ms` (`ERR?`, `POS?`/`FRF?`, `ONT?`)
//! and judges the samples on the rig's clock; a breach becomes a fault of
//! the safe-state machine, which halts both axes and latches it until a
//! client sends `reset`.
//!
//! Why a task of its own and not the client's wait: a client that sends a
//! move without `wait` (or disconnects, or is cancelled) leaves nobody to
//! notice a controller error, a stall or a runaway; the lab's stage must
//! not depend on who asked for the move.
//!
//! Split: [`Supervisor`] is the judge, sans-IO (times in rig seconds,
//! samples in, a verdict out; unit-tested below); `rig::supervise::run` is
//! the thin tokio loop that takes the samples. Breaches:
//! - a controller error (`ERR?` ≠ 0, other than 10 = stopped by us) while
//!   a move is watched (a C-863 reports a servo fault as 1024,
//!   PI_CNTR_MOTION_ERROR, and switches its servo off);
//! - a following error: the controller's position farther than
//!   `safety.following_error_um` from the commanded trajectory (from where
//!   the move was first seen to its target at the axis velocity `VEL?`; the
//!   read's latency is allowed for by judging against the whole band of
//!   trajectory positions between the read's start and end);
//! - a motion timeout: not on target `driver.*.motion_timeout_s` after the
//!   move was sent;
//! - position reads failing (no answer, garbled) for longer than
//!   `safety.read_fail_s`, moving or not (the position poller reports its
//!   reads too). A line that is down is not counted here: the line loss is
//!   a fault of its own at once;
//! - a vision deviation (`daemon::deviation`): every position read here
//!   and in the poller is also a controller sample for the camera's frames.
//!   A watched move during which frames arrived but none decoded is
//!   reported (event `vision_unchecked`), not a fault.

use super::state::AxisId;
use crate::driver::DriverError;
use crate::gcs::GcsErrorCode;

/// The supervisor's bounds (from `[safety]` and the driver's motion
/// timeouts).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Bounds {
    /// Largest allowed distance from the commanded trajectory, µm (0: off).
    pub following_error_um: f64,
    /// How long reads may fail before a fault, s.
    pub read_fail_s: f64,
    /// Motion timeout per axis (X, Y), s.
    pub motion_timeout_s: [f64; 2],
}

/// One move being watched.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Watch {
    target_um: f64,
    /// When the move was sent (rig s).
    since_s: f64,
    /// First sample of the move: (time, position).
    start: Option<(f64, f64)>,
    /// The axis velocity, once read.
    velocity_um_s: Option<f64>,
}

/// What one sample found on one axis.
#[derive(Debug, Clone, PartialEq)]
pub struct AxisSample {
    /// `ERR?` (`None`: not read).
    pub error: Option<GcsErrorCode>,
    /// The position, or why it could not be read.
    pub position_um: Result<f64, ReadFailure>,
    /// `ONT?` (`None`: not read).
    pub on_target: Option<bool>,
}

/// Why a position read failed, as far as the supervisor cares.
#[derive(Debug, Clone, PartialEq)]
pub enum ReadFailure {
    /// The line is down: a fault of its own, not counted as a failing read.
    LinkDown,
    /// The controller answered that the axis is not referenced: it is
    /// alive, the reference loss is a fault of its own.
    NotReferenced,
    /// No usable answer (silence, garbage, a controller error).
    Failed(String),
}

impl ReadFailure {
    /// Classifies a driver error of a position read.
    pub fn of(e: &DriverError) -> ReadFailure {
        match e {
            DriverError::NotReferenced { .. } => ReadFailure::NotReferenced,
            DriverError::Disconnected { .. }
            | DriverError::NoDevice { .. }
            | DriverError::Closed { .. } => ReadFailure::LinkDown,
            e => ReadFailure::Failed(e.to_string()),
        }
    }
}

/// The judge. Times are rig seconds.
#[derive(Debug, Clone)]
pub struct Supervisor {
    bounds: Bounds,
    watch: [Option<Watch>; 2],
    failing_since: [Option<f64>; 2],
}

impl Supervisor {
    /// Nothing watched yet.
    pub fn new(bounds: Bounds) -> Self {
        Self {
            bounds,
            watch: [None, None],
            failing_since: [None, None],
        }
    }

    /// The bounds in force.
    pub fn bounds(&self) -> Bounds {
        self.bounds
    }

    /// A move of `axis` to `target_um` was sent at `now_s`: watch it (a move
    /// replacing one in flight replaces its watch).
    pub fn watch(&mut self, axis: AxisId, target_um: f64, now_s: f64) {
        self.watch[idx(axis)] = Some(Watch {
            target_um,
            since_s: now_s,
            start: None,
            velocity_um_s: None,
        });
    }

    /// Forgets every watched move (the axes were halted or stopped).
    pub fn clear(&mut self) {
        self.watch = [None, None];
    }

    /// Which axes have a move in flight.
    pub fn watching(&self) -> [bool; 2] {
        [self.watch[0].is_some(), self.watch[1].is_some()]
    }

    /// Whether the watched move of `axis` still needs the axis velocity.
    pub fn needs_velocity(&self, axis: AxisId) -> bool {
        self.watch[idx(axis)].is_some_and(|w| w.velocity_um_s.is_none())
    }

    /// The axis velocity for the watched move of `axis` (`VEL?`).
    pub fn set_velocity(&mut self, axis: AxisId, v_um_s: f64) {
        if let Some(w) = &mut self.watch[idx(axis)] {
            if v_um_s.is_finite() && v_um_s > 0.0 {
                w.velocity_um_s = Some(v_um_s);
            }
        }
    }

    /// A position read of `axis` at `t_s` that succeeded (`Ok`) or failed:
    /// a fault reason when reads have failed for longer than the bound.
    pub fn read_result(
        &mut self,
        axis: AxisId,
        t_s: f64,
        r: &Result<f64, ReadFailure>,
    ) -> Option<String> {
        let i = idx(axis);
        match r {
            Ok(_) | Err(ReadFailure::NotReferenced) | Err(ReadFailure::LinkDown) => {
                self.failing_since[i] = None;
                None
            }
            Err(ReadFailure::Failed(why)) => {
                let since = *self.failing_since[i].get_or_insert(t_s);
                let for_s = t_s - since;
                if for_s >= self.bounds.read_fail_s {
                    // Reported once per bound: a read that keeps failing
                    // raises the fault again after another full bound.
                    self.failing_since[i] = None;
                    Some(format!(
                        "axis {}: position reads failing for {for_s:.2} s (safety.read_fail_s = {} s): {why}",
                        axis.name(),
                        self.bounds.read_fail_s
                    ))
                } else {
                    None
                }
            }
        }
    }

    /// Judges a sample of `axis` read between `t0_s` and `t1_s`. `Err`:
    /// the fault to latch (the caller halts both axes). A watch ends when
    /// the controller reports on target.
    pub fn observe(
        &mut self,
        axis: AxisId,
        t0_s: f64,
        t1_s: f64,
        s: &AxisSample,
    ) -> Result<(), String> {
        let name = axis.name();
        if let Some(code) = s.error {
            if !code.is_ok() && code != GcsErrorCode::STOPPED && self.watch[idx(axis)].is_some() {
                self.watch[idx(axis)] = None;
                return Err(format!(
                    "axis {name}: the controller reports error {} ({}) during a move",
                    code.0,
                    code.description()
                ));
            }
        }
        if let Some(reason) = self.read_result(axis, t1_s, &s.position_um) {
            return Err(reason);
        }
        let i = idx(axis);
        let Some(mut w) = self.watch[i] else {
            return Ok(());
        };
        if let Ok(p) = s.position_um {
            let start = *w.start.get_or_insert((0.5 * (t0_s + t1_s), p));
            self.watch[i] = Some(w);
            let f = self.bounds.following_error_um;
            if let (Some(v), true) = (w.velocity_um_s, f > 0.0) {
                let off = deviation_um(start, w.target_um, v, t0_s, t1_s, p);
                if off > f {
                    self.watch[i] = None;
                    return Err(format!(
                        "axis {name}: following error {off:.1} µm (position {p:.1} µm on the way from {:.1} to {:.1} µm at {v:.0} µm/s; safety.following_error_um = {f} µm)",
                        start.1, w.target_um
                    ));
                }
            }
        }
        if s.on_target == Some(true) {
            self.watch[i] = None;
            return Ok(());
        }
        let timeout = self.bounds.motion_timeout_s[idx(axis)];
        if t1_s - w.since_s > timeout {
            self.watch[i] = None;
            return Err(format!(
                "axis {name}: not on target {:.2} s after the move to {:.1} µm was sent (motion timeout {timeout} s)",
                t1_s - w.since_s,
                w.target_um
            ));
        }
        Ok(())
    }
}

fn idx(a: AxisId) -> usize {
    match a {
        AxisId::X => 0,
        AxisId::Y => 1,
    }
}

/// The positions the commanded trajectory (from `start` = (t, µm) to
/// `target_um` at `v_um_s`) passes between `t0_s` and `t1_s`, as (low,
/// high).
fn band_um(start: (f64, f64), target_um: f64, v_um_s: f64, t0_s: f64, t1_s: f64) -> (f64, f64) {
    let (ts, ps) = start;
    let dist = target_um - ps;
    let at = |t: f64| ps + dist.signum() * (v_um_s * (t - ts).max(0.0)).min(dist.abs());
    let (a, b) = (at(t0_s), at(t1_s));
    (a.min(b), a.max(b))
}

/// How far position `p` read between `t0_s` and `t1_s` is off the
/// commanded trajectory: behind the band of trajectory positions (a lag:
/// a jam, a slipping drive), or outside the segment from the start to the
/// target (a runaway, an overshoot). Ahead of the trajectory but inside the
/// segment is not counted: harmless, and what a rig clock slower than the
/// controllers' looks like (a time-scaled simulator).
fn deviation_um(
    start: (f64, f64),
    target_um: f64,
    v_um_s: f64,
    t0_s: f64,
    t1_s: f64,
    p: f64,
) -> f64 {
    let dir = (target_um - start.1).signum();
    let (lo, hi) = band_um(start, target_um, v_um_s, t0_s, t1_s);
    // Along the direction of travel: the earliest allowed point.
    let behind = if dir >= 0.0 { lo - p } else { p - hi };
    let (seg_lo, seg_hi) = (start.1.min(target_um), start.1.max(target_um));
    let outside = (seg_lo - p).max(p - seg_hi);
    behind.max(outside).max(0.0)
}

/// Frames that arrive during a watched move without one decoding, after
/// which the move is reported once as unchecked by vision.
const UNCHECKED_FRAMES: u64 = 5;

/// Counts the camera's frames and decodes over one watched move (sans-IO).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub(super) struct UncheckedMove {
    /// (frames, decoded) when the move was first seen, and whether it was
    /// reported.
    start: Option<((u64, u64), bool)>,
    rounds: u64,
}

impl UncheckedMove {
    /// One supervisor round: `moving` (a move is watched) and the camera's
    /// (frames, decoded) counters. `Some((frames, rounds))` the first time
    /// a move has seen [`UNCHECKED_FRAMES`] frames and no decode.
    pub(super) fn update(&mut self, moving: bool, counts: (u64, u64)) -> Option<(u64, u64)> {
        if !moving {
            *self = Self::default();
            return None;
        }
        let ((f0, d0), reported) = *self.start.get_or_insert((counts, false));
        self.rounds += 1;
        let frames = counts.0.saturating_sub(f0);
        if !reported && counts.1 == d0 && frames >= UNCHECKED_FRAMES {
            self.start = Some(((f0, d0), true));
            return Some((frames, self.rounds));
        }
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_move_with_frames_but_no_decode_is_reported_once() {
        let mut u = UncheckedMove::default();
        assert_eq!(u.update(false, (10, 10)), None);
        assert_eq!(u.update(true, (10, 10)), None);
        assert_eq!(u.update(true, (13, 10)), None);
        assert_eq!(u.update(true, (15, 10)), Some((5, 3)));
        assert_eq!(u.update(true, (30, 10)), None);
        // A new move counts afresh; a decode in it keeps it checked.
        assert_eq!(u.update(false, (30, 10)), None);
        assert_eq!(u.update(true, (30, 10)), None);
        assert_eq!(u.update(true, (40, 11)), None);
        assert_eq!(u.update(true, (50, 11)), None);
        // No camera frames at all (a stalled camera): nothing to report
        // here; the camera health events say it.
        let mut s = UncheckedMove::default();
        for _ in 0..10 {
            assert_eq!(s.update(true, (0, 0)), None);
        }
    }

    fn sup() -> Supervisor {
        Supervisor::new(Bounds {
            following_error_um: 100.0,
            read_fail_s: 1.0,
            motion_timeout_s: [10.0, 10.0],
        })
    }

    fn at(p: f64, ont: bool) -> AxisSample {
        AxisSample {
            error: Some(GcsErrorCode::NO_ERROR),
            position_um: Ok(p),
            on_target: Some(ont),
        }
    }

    #[test]
    fn a_move_that_follows_its_trajectory_passes_and_ends_on_target() {
        let mut s = sup();
        s.watch(AxisId::X, 2000.0, 0.0);
        s.set_velocity(AxisId::X, 1000.0);
        // 1 mm/s from 0: within the band (a little lag from acceleration).
        assert!(s.observe(AxisId::X, 0.0, 0.01, &at(0.0, false)).is_ok());
        assert!(s.observe(AxisId::X, 0.5, 0.52, &at(450.0, false)).is_ok());
        assert!(s.observe(AxisId::X, 1.5, 1.51, &at(1480.0, false)).is_ok());
        assert!(s.observe(AxisId::X, 2.1, 2.11, &at(2000.0, true)).is_ok());
        assert_eq!(s.watching(), [false, false]);
    }

    #[test]
    fn a_stalled_axis_is_a_following_error() {
        let mut s = sup();
        s.watch(AxisId::Y, -3000.0, 0.0);
        s.set_velocity(AxisId::Y, 1000.0);
        assert!(s.observe(AxisId::Y, 0.0, 0.0, &at(0.0, false)).is_ok());
        assert!(s.observe(AxisId::Y, 0.05, 0.06, &at(-50.0, false)).is_ok());
        let e = s
            .observe(AxisId::Y, 0.2, 0.21, &at(-50.0, false))
            .unwrap_err();
        assert!(e.contains("axis y: following error"), "{e}");
        assert_eq!(s.watching(), [false, false]);
    }

    #[test]
    fn a_runaway_past_the_target_is_a_following_error() {
        let mut s = sup();
        s.watch(AxisId::X, 100.0, 0.0);
        s.set_velocity(AxisId::X, 1000.0);
        assert!(s.observe(AxisId::X, 0.0, 0.0, &at(0.0, false)).is_ok());
        assert!(s.observe(AxisId::X, 5.0, 5.0, &at(250.0, false)).is_err());
    }

    #[test]
    fn without_a_velocity_only_the_timeout_applies() {
        let mut s = sup();
        s.watch(AxisId::X, 5000.0, 0.0);
        assert!(s.observe(AxisId::X, 0.0, 0.0, &at(0.0, false)).is_ok());
        assert!(s.observe(AxisId::X, 9.0, 9.0, &at(0.0, false)).is_ok());
        let e = s
            .observe(AxisId::X, 10.5, 10.5, &at(0.0, false))
            .unwrap_err();
        assert!(e.contains("motion timeout"), "{e}");
    }

    #[test]
    fn a_controller_error_during_a_move_is_a_fault_but_stopped_is_not() {
        let mut s = sup();
        s.watch(AxisId::X, 5000.0, 0.0);
        let mut smp = at(0.0, false);
        smp.error = Some(GcsErrorCode::STOPPED);
        assert!(s.observe(AxisId::X, 0.0, 0.0, &smp).is_ok());
        smp.error = Some(GcsErrorCode::MOTION_ERROR);
        let e = s.observe(AxisId::X, 0.1, 0.1, &smp).unwrap_err();
        assert!(e.contains("1024"), "{e}");
    }

    #[test]
    fn reads_failing_longer_than_the_bound_are_a_fault_line_loss_is_not_counted() {
        let mut s = sup();
        let fail = Err(ReadFailure::Failed("no answer".into()));
        assert!(s.read_result(AxisId::X, 0.0, &fail).is_none());
        assert!(s.read_result(AxisId::X, 0.9, &fail).is_none());
        // A success in between restarts the count.
        assert!(s.read_result(AxisId::X, 0.95, &Ok(1.0)).is_none());
        assert!(s.read_result(AxisId::X, 1.5, &fail).is_none());
        let e = s.read_result(AxisId::X, 2.6, &fail).unwrap();
        assert!(
            e.contains("axis x: position reads failing for 1.10 s"),
            "{e}"
        );
        for t in 0..50 {
            let r = s.read_result(AxisId::Y, f64::from(t), &Err(ReadFailure::LinkDown));
            assert!(r.is_none());
        }
        let nr = Err(ReadFailure::NotReferenced);
        assert!(s.read_result(AxisId::Y, 99.0, &nr).is_none());
    }

    #[test]
    fn ahead_inside_the_segment_is_no_deviation_behind_or_outside_is() {
        let start = (0.0, 1000.0);
        // Towards 3000 at 1 mm/s; at t = 1 the trajectory is at 2000.
        assert_eq!(deviation_um(start, 3000.0, 1000.0, 1.0, 1.0, 2900.0), 0.0);
        assert!((deviation_um(start, 3000.0, 1000.0, 1.0, 1.0, 1700.0) - 300.0).abs() < 1e-9);
        assert!((deviation_um(start, 3000.0, 1000.0, 1.0, 1.0, 3200.0) - 200.0).abs() < 1e-9);
        assert!((deviation_um(start, 3000.0, 1000.0, 1.0, 1.0, 900.0) - 1100.0).abs() < 1e-9);
        // Towards lower positions.
        assert!((deviation_um(start, -1000.0, 1000.0, 1.0, 1.0, 400.0) - 400.0).abs() < 1e-9);
        assert_eq!(deviation_um(start, -1000.0, 1000.0, 1.0, 1.0, -900.0), 0.0);
    }

    #[test]
    fn the_band_covers_the_read_latency() {
        // Read from t 1.0 to 1.2 at 1 mm/s: anything from 1000 to 1200 µm
        // is on the trajectory.
        assert_eq!(
            band_um((0.0, 0.0), 5000.0, 1000.0, 1.0, 1.2),
            (1000.0, 1200.0)
        );
        // Towards lower positions, clamped at the target.
        assert_eq!(
            band_um((0.0, 0.0), -500.0, 1000.0, 0.4, 1.0),
            (-500.0, -400.0)
        );
    }
}
