//! Compensation of position-dependent errors (Tan et al., section V), done
//! properly: the inverse is solved, backlash is planned around, and a closed
//! loop on the camera removes what the tables cannot.
//!
//! # Pieces
//! * [`table`]: the paper's lookup tables `f_xx, b_xx, f_xy, b_xy, f_yx,
//!   b_yx, f_yy, b_yy` and `δx(y)` (eqs. 4 and 5), built from the `scan_x`
//!   and `scan_y` segments of a measurement log; [`LookupCompensator`].
//! * [`model_comp`]: the stage model (`crate::model`) fitted to the scans;
//!   [`ModelCompensator`]. Equal accuracy from ten times fewer points.
//! * [`grid`]: a 2-D error map measured on a lattice of (x, y) targets,
//!   bilinear between its nodes; [`GridCompensator`]. Holds error that
//!   depends on both axes at once, which the tables cannot.
//! * [`yaw`]: the platform's yaw against each axis's position from the
//!   decoded θ of the same scans ([`YawTables`]), and the tool point's
//!   transform through it.
//! * [`file`]: compensation files (TOML, `format_version = 1`) carrying the
//!   characterization they came from; [`CompFile`].
//! * [`frame`]: the vision→stage transform estimated from the scans.
//! * [`closed_loop`]: sans-IO [`ClosedLoop`] state machine.
//!
//! # Sign conventions
//! Stage frame, µm. The paper's error `e = target − measured` (the sign of
//! the measurement log) is what the tables hold. A [`Compensator`] predicts
//! the *offset* `observed − commanded = −e` (the sign of
//! `crate::model::StageModel::observed_error_um`) for a motion state.
//!
//! # The inverse
//! The error is a function of where the stage is commanded, not of the
//! target: subtracting `e(target)` once leaves `e(cmd) − e(target)`, up to
//! 0.1 µm on a 1.6 µm leadscrew ripple. [`Compensator::command_for`] solves
//! `cmd + offset(state(cmd)) = target` by fixed-point iteration
//! `cmd ← target − offset(state(cmd))` (a contraction: the slope of the
//! error is ≤ a few %), with a convergence check, where `state(cmd)` is the
//! motion state reached by the planned moves (direction, play).
//!
//! # Backlash
//! Tables hold errors of moves that arrived in a known direction with the
//! play taken up. The planner ([`PlanOptions`]) guarantees that: each axis
//! arrives in its *arrival direction* (direction-aware: from the previous
//! target, as the paper; unidirectional: always the same), and when an axis
//! would arrive from the wrong side, or by a reversal shorter than
//! `min_reversal_run_um` (which would be lost in the play), the plan first
//! goes `overshoot_um` beyond and approaches from there.

use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::model::{Direction, ModelError, MotionState, MotionTracker, Waypoint, XyUm};

pub mod closed_loop;
pub mod file;
pub mod frame;
pub mod grid;
pub mod model_comp;
pub mod table;
pub mod yaw;

pub use closed_loop::{
    Action, ClosedLoop, ClosedLoopConfig, FailReason, FrameMeasurement, RejectReason,
};
pub use file::{fnv1a64_hex, CompFile, CompKind, SourceInfo, COMP_FORMAT_VERSION};
pub use frame::{estimate_vision_frame, FrameReport, FrameSample, VisionFrame};
pub use grid::{GridArrival, GridBuildReport, GridCompensator, GridLayer, GridTable};
pub use model_comp::{
    compensation_template, compensation_template_for, ModelBuildOptions, ModelCompensator,
};
pub use table::{
    AxisTables, BuildReport, CompTable, DirTable, Interpolation, LookupCompensator,
    TableBuildOptions,
};
pub use yaw::{pattern_for_tool_um, tool_from_pattern_um, YawBuildReport, YawTables};

/// Everything that can go wrong building, loading or using compensation.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum CompError {
    /// A value or option is out of range; names the key and says why.
    #[error("compensation: {key}: {reason}")]
    Invalid {
        /// What is wrong (dotted key or option name).
        key: String,
        /// Why.
        reason: String,
    },
    /// The log lacks data a table needs.
    #[error("compensation: not enough data: {what}")]
    NoData {
        /// What is missing.
        what: String,
    },
    /// The inverse did not converge.
    #[error("compensation: inverse did not converge for target ({x_um}, {y_um}) µm after {iterations} iterations (last step {step_um:e} µm)")]
    NotConverged {
        /// Target x.
        x_um: f64,
        /// Target y.
        y_um: f64,
        /// Iterations run.
        iterations: usize,
        /// Size of the last update, µm.
        step_um: f64,
    },
    /// The stage model refused something.
    #[error("compensation: stage model: {0}")]
    Model(#[from] ModelError),
    /// A compensation file is malformed.
    #[error("compensation file: {0}")]
    File(String),
    /// Reading or writing a file failed.
    #[error("compensation file {path}: {message}")]
    Io {
        /// The path.
        path: String,
        /// The OS message.
        message: String,
    },
}

pub(crate) fn invalid(key: impl Into<String>, reason: impl Into<String>) -> CompError {
    CompError::Invalid {
        key: key.into(),
        reason: reason.into(),
    }
}

/// The area a compensation was characterized over: per axis, the span of
/// the commanded positions its scans measured (stage frame, µm).
///
/// Why it is kept: outside it a lookup table only holds its end values and
/// a model extrapolates its terms; neither was measured there, so the
/// daemon refuses or warns before compensating a target outside it
/// (`[compensation] outside_table`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Area {
    /// Lowest and highest x measured, µm.
    pub x_um: [f64; 2],
    /// Lowest and highest y measured, µm.
    pub y_um: [f64; 2],
}

impl Area {
    /// Checks that both spans are finite and ordered; `what` names the key.
    pub fn validate(&self, what: &str) -> Result<(), CompError> {
        for (k, v) in [("x_um", self.x_um), ("y_um", self.y_um)] {
            if !(v.iter().all(|x| x.is_finite() && x.abs() <= 1e9) && v[0] <= v[1]) {
                return Err(invalid(
                    format!("{what}.{k}"),
                    "must be [low, high], finite, low ≤ high",
                ));
            }
        }
        Ok(())
    }

    /// How far `p` lies outside the area grown by `margin_um` on every
    /// side, per axis (µm, 0 inside; NaN counts as outside).
    pub fn outside_by_um(&self, p: XyUm, margin_um: f64) -> [f64; 2] {
        let by = |v: f64, r: [f64; 2]| {
            if v.is_nan() {
                f64::INFINITY
            } else {
                (r[0] - margin_um - v).max(v - r[1] - margin_um).max(0.0)
            }
        };
        [by(p.x_um, self.x_um), by(p.y_um, self.y_um)]
    }

    /// Whether `p` lies within the area grown by `margin_um`.
    pub fn contains(&self, p: XyUm, margin_um: f64) -> bool {
        self.outside_by_um(p, margin_um) == [0.0, 0.0]
    }

    /// The span of the positions of the x scan and the y scan records
    /// (segments `scan_x`, `scan_y`; commanded targets), if both exist.
    pub fn of_scans(records: &[crate::charact::log::Record]) -> Option<Area> {
        use crate::charact::scan::{SEGMENT_SCAN_X, SEGMENT_SCAN_Y};
        let span = |seg: &str, f: fn(&crate::charact::log::Record) -> f64| {
            records
                .iter()
                .filter(|r| r.segment == seg)
                .map(f)
                .filter(|v| v.is_finite())
                .fold(None, |acc: Option<[f64; 2]>, v| {
                    Some(acc.map_or([v, v], |a| [a[0].min(v), a[1].max(v)]))
                })
        };
        Some(Area {
            x_um: span(SEGMENT_SCAN_X, |r| r.x_target_um)?,
            y_um: span(SEGMENT_SCAN_Y, |r| r.y_target_um)?,
        })
    }
}

impl std::fmt::Display for Area {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "x {:.1} … {:.1} µm, y {:.1} … {:.1} µm",
            self.x_um[0], self.x_um[1], self.y_um[0], self.y_um[1]
        )
    }
}

/// How moves are planned around backlash.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum ApproachPolicy {
    /// Each axis arrives in the direction from its previous target to this
    /// one (the paper); an unchanged target keeps the last direction.
    #[default]
    DirectionAware,
    /// Each axis always arrives in the given direction (`[x, y]`; `Unknown`
    /// means forward): the backlash is the same at every target, at the
    /// price of an extra move whenever an axis goes the other way.
    Unidirectional([Direction; 2]),
}

/// Options of the planner and the inverse.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlanOptions {
    /// Backlash strategy.
    pub policy: ApproachPolicy,
    /// Distance beyond the command from which a wrong-side arrival is
    /// re-approached, µm (≥ `min_reversal_run_um`).
    pub overshoot_um: f64,
    /// A reversal shorter than this may be lost in the play and is replaced
    /// by an approach from `overshoot_um` away, µm (> the backlash; default
    /// 10 µm for the M-111's 2 µm).
    pub min_reversal_run_um: f64,
    /// Iteration limit of the inverse.
    pub max_iterations: usize,
    /// The inverse has converged when an update is smaller than this, µm.
    pub tolerance_um: f64,
    /// Every axis whose command changes arrives by an approach from
    /// `overshoot_um` behind, also when a direct move would keep its
    /// direction. Why: a closed loop's corrections each end with such an
    /// approach ([`closed_loop`]); when the first arrival ends with the
    /// same move, a lost motion that depends on the length of the last move
    /// is the same in the first frame as after every correction, so the
    /// first correction does not jump by the difference (see
    /// [`ClosedLoopConfig::plan_options`]).
    #[serde(default)]
    pub approach_always: bool,
}

impl Default for PlanOptions {
    fn default() -> Self {
        PlanOptions {
            policy: ApproachPolicy::DirectionAware,
            overshoot_um: 20.0,
            min_reversal_run_um: 10.0,
            max_iterations: 50,
            tolerance_um: 1e-6,
            approach_always: false,
        }
    }
}

impl PlanOptions {
    /// Checks the numbers.
    pub fn validate(&self) -> Result<(), CompError> {
        if !(self.min_reversal_run_um.is_finite() && self.min_reversal_run_um >= 0.0) {
            return Err(invalid(
                "min_reversal_run_um",
                "must be a finite number ≥ 0",
            ));
        }
        if !(self.overshoot_um.is_finite()
            && self.overshoot_um > 0.0
            && self.overshoot_um >= self.min_reversal_run_um)
        {
            return Err(invalid(
                "overshoot_um",
                "must be finite, > 0 and ≥ min_reversal_run_um",
            ));
        }
        if !(self.tolerance_um.is_finite() && self.tolerance_um > 0.0) {
            return Err(invalid("tolerance_um", "must be a finite number > 0"));
        }
        if self.max_iterations == 0 {
            return Err(invalid("max_iterations", "must be ≥ 1"));
        }
        Ok(())
    }
}

/// What the stage has done so far, in commanded terms: where each axis is
/// commanded, which way it last moved, how far (for the play), and the last
/// target. The daemon keeps one per stage and [`MotionHistory::commit`]s
/// every executed plan (or [`MotionHistory::commit_move`]s any other move).
#[derive(Debug, Clone, PartialEq)]
pub struct MotionHistory {
    tracker: MotionTracker,
    last_target: XyUm,
}

impl MotionHistory {
    /// Starts at `start` (e.g. `MotionState::at_rest` after the reference
    /// move). `min_move_um` is the stage's minimum incremental motion (moves
    /// shorter than it do not happen and do not change the direction).
    pub fn new(start: MotionState, min_move_um: f64) -> Result<Self, CompError> {
        let tracker = MotionTracker::new(start)?.with_min_move(min_move_um)?;
        let c = start.cmd_xy_um();
        Ok(MotionHistory {
            tracker,
            last_target: XyUm::from(c),
        })
    }

    /// The current motion state.
    pub fn state(&self) -> &MotionState {
        self.tracker.state()
    }

    /// The last target (the paper's "previous target").
    pub fn last_target(&self) -> XyUm {
        self.last_target
    }

    /// Sets the target the last move was for, leaving the motion state (the
    /// commands the axes got) as it is.
    ///
    /// Why: a closed loop's corrections are recorded as raw moves, each its
    /// own target; the move was for the user's target, and a following
    /// relative move, or an axis the next move leaves out, continues from
    /// that target, not from the last correction's command (up to tens of
    /// µm away).
    pub fn set_last_target(&mut self, target: XyUm) {
        self.last_target = target;
    }

    /// Records an executed plan (all its waypoints), settled at `time_s`
    /// with ambient `temp_c`.
    pub fn commit(&mut self, plan: &MovePlan, time_s: f64, temp_c: f64) -> Result<(), CompError> {
        let mut t = self.tracker.clone();
        for w in &plan.waypoints {
            t.step(Waypoint {
                x_um: w.x_um,
                y_um: w.y_um,
                time_s,
                temp_c,
                cycle: t.state().cycle,
            })?;
        }
        self.tracker = t;
        self.last_target = plan.target;
        Ok(())
    }

    /// Records a move made without a plan (e.g. a scan step): commanded
    /// position `cmd`, aiming at `target`.
    pub fn commit_move(
        &mut self,
        cmd: XyUm,
        target: XyUm,
        time_s: f64,
        temp_c: f64,
    ) -> Result<(), CompError> {
        let cycle = self.tracker.state().cycle;
        self.tracker.step(Waypoint {
            x_um: cmd.x_um,
            y_um: cmd.y_um,
            time_s,
            temp_c,
            cycle,
        })?;
        self.last_target = target;
        Ok(())
    }
}

/// The moves that bring the stage to a target.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MovePlan {
    /// Where the stage should end up (stage frame, as the camera measures).
    pub target: XyUm,
    /// Commands to send in order, µm; the last one is `cmd`. The earlier
    /// one (if any) is the approach point beyond `cmd`.
    pub waypoints: Vec<XyUm>,
    /// The final command.
    pub cmd: XyUm,
    /// Direction in which each axis arrives at `cmd`.
    pub arrival: [Direction; 2],
    /// Predicted `observed − cmd` at the end, µm.
    pub predicted_offset_um: [f64; 2],
    /// Iterations the inverse took.
    pub iterations: usize,
}

/// A way of predicting the stage's error, and so of compensating it.
///
/// Implemented by [`LookupCompensator`] (the paper's tables),
/// [`ModelCompensator`] (fitted stage model), [`GridCompensator`] (a 2-D
/// map) and [`Uncompensated`]. The
/// daemon holds a `Box<dyn Compensator>` loaded from a [`CompFile`] and
/// swaps it without restart.
pub trait Compensator: std::fmt::Debug + Send + Sync {
    /// `"lookup"`, `"model"`, `"grid"`, `"none"`.
    fn kind(&self) -> &'static str;

    /// Predicted `observed − commanded` (µm, `[x, y]`) when the stage is in
    /// `state` (commanded position, arrival direction, play, temperature).
    fn predicted_offset_um(&self, state: &MotionState) -> Result<[f64; 2], CompError>;

    /// The area the compensation was characterized over, if known (see
    /// [`Area`]). Outside it the prediction was never measured.
    fn characterized_area(&self) -> Option<Area> {
        None
    }

    /// Whether the prediction outside [`Compensator::characterized_area`]
    /// follows from physics (a model's periodic and linear terms) rather
    /// than from holding the last measured value (a table). The daemon
    /// refuses a table outside its area by default but only warns for a
    /// model.
    fn extrapolates_by_model(&self) -> bool {
        false
    }

    /// The moves that put the stage at `target`, from `history`: arrival
    /// directions from `options.policy`, command from the inverse (see the
    /// module docs), approach point where backlash requires one.
    fn command_for(
        &self,
        target: XyUm,
        history: &MotionHistory,
        options: &PlanOptions,
    ) -> Result<MovePlan, CompError> {
        solve(self, target, history, options)
    }
}

/// No compensation: `cmd = target` (still planned around backlash).
#[derive(Debug, Clone, Copy, Default)]
pub struct Uncompensated;

impl Compensator for Uncompensated {
    fn kind(&self) -> &'static str {
        "none"
    }
    fn predicted_offset_um(&self, _state: &MotionState) -> Result<[f64; 2], CompError> {
        Ok([0.0; 2])
    }
}

/// Arrival direction of each axis for `target`.
pub fn arrival_directions(
    target: XyUm,
    history: &MotionHistory,
    policy: ApproachPolicy,
) -> [Direction; 2] {
    let known = |d: Direction| match d {
        Direction::Unknown => Direction::Forward,
        d => d,
    };
    match policy {
        ApproachPolicy::Unidirectional(d) => [known(d[0]), known(d[1])],
        ApproachPolicy::DirectionAware => {
            let last = history.last_target();
            let st = history.state();
            let dir = |t: f64, l: f64, i: usize| {
                if t > l {
                    Direction::Forward
                } else if t < l {
                    Direction::Backward
                } else {
                    known(st.axes[i].dir)
                }
            };
            [
                dir(target.x_um, last.x_um, 0),
                dir(target.y_um, last.y_um, 1),
            ]
        }
    }
}

/// The waypoints that bring the axes from `state` to `cmd`, each arriving in
/// `arrival` with the play taken up (see the module docs).
pub fn plan_waypoints(
    state: &MotionState,
    cmd: [f64; 2],
    arrival: [Direction; 2],
    options: &PlanOptions,
) -> Vec<XyUm> {
    let mut approach = cmd;
    let mut needs = false;
    for i in 0..2 {
        let p = state.axes[i].cmd_um;
        let last = state.axes[i].dir;
        let s = arrival[i].sign();
        let run = (cmd[i] - p) * s;
        let direct = if cmd[i] == p {
            last == arrival[i]
        } else if options.approach_always {
            false
        } else if last == arrival[i] {
            run > 0.0
        } else {
            run >= options.min_reversal_run_um
        };
        if !direct && s != 0.0 {
            approach[i] = cmd[i] - s * options.overshoot_um;
            needs = true;
        }
    }
    let mut w = Vec::with_capacity(2);
    if needs {
        w.push(XyUm::from(approach));
    }
    w.push(XyUm::from(cmd));
    w
}

fn state_after(history: &MotionHistory, waypoints: &[XyUm]) -> Result<MotionState, CompError> {
    let mut t = history.tracker.clone();
    let st = *t.state();
    for w in waypoints {
        t.step(Waypoint {
            x_um: w.x_um,
            y_um: w.y_um,
            time_s: st.time_s,
            temp_c: st.temp_c,
            cycle: st.cycle,
        })?;
    }
    Ok(*t.state())
}

fn solve<C: Compensator + ?Sized>(
    comp: &C,
    target: XyUm,
    history: &MotionHistory,
    options: &PlanOptions,
) -> Result<MovePlan, CompError> {
    options.validate()?;
    if !(target.x_um.is_finite() && target.y_um.is_finite()) {
        return Err(invalid("target", "is not finite"));
    }
    let arrival = arrival_directions(target, history, options.policy);
    let t = [target.x_um, target.y_um];
    let mut cmd = t;
    let mut last_step = f64::INFINITY;
    for it in 1..=options.max_iterations {
        let w = plan_waypoints(history.state(), cmd, arrival, options);
        let st = state_after(history, &w)?;
        let off = comp.predicted_offset_um(&st)?;
        let next = [t[0] - off[0], t[1] - off[1]];
        if !(next[0].is_finite() && next[1].is_finite()) {
            return Err(invalid("predicted offset", "is not finite"));
        }
        last_step = (next[0] - cmd[0]).hypot(next[1] - cmd[1]);
        cmd = next;
        if last_step <= options.tolerance_um {
            let waypoints = plan_waypoints(history.state(), cmd, arrival, options);
            let st = state_after(history, &waypoints)?;
            let predicted_offset_um = comp.predicted_offset_um(&st)?;
            return Ok(MovePlan {
                target,
                waypoints,
                cmd: XyUm::from(cmd),
                arrival,
                predicted_offset_um,
                iterations: it,
            });
        }
    }
    Err(CompError::NotConverged {
        x_um: target.x_um,
        y_um: target.y_um,
        iterations: options.max_iterations,
        step_um: last_step,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug)]
    struct Ripple;
    impl Compensator for Ripple {
        fn kind(&self) -> &'static str {
            "test"
        }
        fn predicted_offset_um(&self, s: &MotionState) -> Result<[f64; 2], CompError> {
            let x = s.axes[0].cmd_um;
            Ok([
                1.6 * (std::f64::consts::TAU * x / 400.0).sin() + s.axes[0].dir.sign(),
                0.005 * x,
            ])
        }
    }

    #[test]
    fn inverse_solves_cmd_plus_offset_equals_target() {
        let h = MotionHistory::new(MotionState::at_rest(0.0, 0.0), 0.0).unwrap();
        let target = XyUm {
            x_um: 1234.5,
            y_um: 10.0,
        };
        let p = Ripple
            .command_for(target, &h, &PlanOptions::default())
            .unwrap();
        let st = state_after(&h, &p.waypoints).unwrap();
        let off = Ripple.predicted_offset_um(&st).unwrap();
        assert!((p.cmd.x_um + off[0] - target.x_um).abs() < 1e-5);
        assert!((p.cmd.y_um + off[1] - target.y_um).abs() < 1e-5);
        assert_eq!(p.arrival, [Direction::Forward, Direction::Forward]);
        // Subtracting once would be off by the ripple's change.
        assert!(p.iterations > 2);
    }

    #[test]
    fn short_reversal_goes_through_an_approach_point() {
        let mut h = MotionHistory::new(MotionState::at_rest(0.0, 0.0), 0.0).unwrap();
        let o = PlanOptions::default();
        let p = Uncompensated
            .command_for(XyUm::from([100.0, 50.0]), &h, &o)
            .unwrap();
        // From unknown direction: approached from below on both axes.
        assert_eq!(p.waypoints.len(), 1, "{p:?}");
        h.commit(&p, 1.0, 20.0).unwrap();
        let q = Uncompensated
            .command_for(XyUm::from([99.0, 60.0]), &h, &o)
            .unwrap();
        assert_eq!(
            q.waypoints,
            vec![XyUm::from([119.0, 60.0]), XyUm::from([99.0, 60.0])]
        );
        h.commit(&q, 2.0, 20.0).unwrap();
        // 1 µm back after a forward arrival: re-approached from above, so
        // it arrives backward with the play taken up.
        assert_eq!(h.state().axes[0].dir, Direction::Backward);
        assert_eq!(q.arrival[0], Direction::Backward);
        let u = PlanOptions {
            policy: ApproachPolicy::Unidirectional([Direction::Forward; 2]),
            ..o
        };
        let r = Uncompensated
            .command_for(XyUm::from([50.0, 70.0]), &h, &u)
            .unwrap();
        // Unidirectional: x goes back to 50 but still arrives forward.
        assert_eq!(r.waypoints[0].x_um, 30.0);
        assert_eq!(r.arrival, [Direction::Forward; 2]);
        assert!(Uncompensated
            .command_for(XyUm::from([f64::NAN, 0.0]), &h, &o)
            .is_err());
        let bad = PlanOptions {
            overshoot_um: 1.0,
            ..o
        };
        assert!(Uncompensated
            .command_for(XyUm::from([0.0, 0.0]), &h, &bad)
            .is_err());
    }
}
