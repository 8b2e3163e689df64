//! Scan plans: the trajectories a characterization and its validation run.
//!
//! * Characterization (Tan et al., section IV): one axis at a time moves in a
//!   straight line in steps (1-DoF scan) while the other is held still; each
//!   cycle is one forward pass (increasing target) and one backward pass. The
//!   paper: 5 µm steps over 9500 µm of X and 4200 µm of Y, 3 cycles.
//! * Validation (section V): the 4000 × 4000 µm square from 10 to 4010 µm
//!   (segments AB, BC, CD, DA) and the ten random targets of Table II.
//!
//! Why approach points: a leadscrew stage lands in a different place when it
//! arrives from the other side (backlash), so every pass starts with an
//! unlogged move to `approach_um` *before* its first point, and the held axis
//! is parked by a forward approach. Every logged point is then reached in the
//! pass's direction with the play taken up, which is what the compensation
//! tables (`crate::comp`) assume. Consequence for the daemon: a plan reaches
//! `start − approach_um` and `end + approach_um`; check [`AxisScan::extent_um`]
//! against the stage's travel before running it.
//!
//! Pure data: the daemon walks the points, moves, waits, measures and logs
//! `logged` points under [`ScanPoint::segment`] with [`ScanPoint::cycle`].

use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::model::{Axis, Direction, XyUm};

/// Distance below the first point from which the held axis is parked, µm
/// (10× the M-111's 2 µm backlash, as [`AxisScan::approach_um`]'s
/// default): the daemon's jobs, the scan plan and the sweep's anchors all
/// park from here, so it lives with the plans' geometry.
pub const PARK_APPROACH_UM: f64 = 20.0;

/// Segment name of the X scan in the measurement log.
pub const SEGMENT_SCAN_X: &str = "scan_x";
/// Segment name of the Y scan in the measurement log.
pub const SEGMENT_SCAN_Y: &str = "scan_y";
/// Segment name of the square validation in the measurement log.
pub const SEGMENT_SQUARE: &str = "square";
/// Segment name of the random-target validation in the measurement log.
pub const SEGMENT_RANDOM: &str = "random";
/// Log segment of a characterization's moves of varied length: each point
/// reached by one direct move (both axes) from the point logged before it
/// in the same segment, as an application moves. Why: a lost motion that
/// grows with the length of the move (`step_size`) is invisible on
/// constant-step scans; these moves make it identifiable
/// (`crate::comp::model_comp::scan_samples`).
pub const SEGMENT_MOVES: &str = "moves";
/// Log segments of a sweep characterization's static anchors (x forward,
/// x backward, y forward, y backward): stops measured as the step plan
/// measures its points, each reached by a move of the anchor spacing and a
/// final move of one step, neither of which the log holds
/// (`crate::charact::sweep::anchor`). Readers that replay the logged
/// commands as the motion (`crate::analysis::diagnose`) leave them out.
pub const SEGMENTS_SWEEP_ANCHOR: [&str; 4] = [
    "anchor_x_fwd",
    "anchor_x_bwd",
    "anchor_y_fwd",
    "anchor_y_bwd",
];

/// Log segment of a grid's nodes measured one way: microposd's grid plan
/// (`plan: grid` in the log's metadata, without `grid_approach: both`)
/// reaches each of them from below on both axes; an import does not say.
pub const SEGMENT_GRID: &str = "grid";
/// Log segment of a grid's nodes reached from below on both axes, in a
/// grid measured both ways (microposd's grid plan with `approach = both`,
/// or an import with a direction column). A grid measured one way only
/// logs its nodes as `grid`.
pub const SEGMENT_GRID_FWD: &str = "grid_fwd";
/// Log segment of a grid's nodes reached from above on both axes.
pub const SEGMENT_GRID_BWD: &str = "grid_bwd";
/// Log segment of a grid's nodes reached from above on x, from below on y
/// (the returning rows of a serpentine).
pub const SEGMENT_GRID_XBWD: &str = "grid_xbwd";
/// Log segment of a grid's nodes reached from below on x, from above on y.
pub const SEGMENT_GRID_YBWD: &str = "grid_ybwd";

/// The direction a grid record's node was reached on each axis (`[x, y]`),
/// by its segment ([`SEGMENT_GRID_FWD`], [`SEGMENT_GRID_BWD`],
/// [`SEGMENT_GRID_XBWD`], [`SEGMENT_GRID_YBWD`]); `None` for any other
/// segment (a one-way grid does not say).
pub fn grid_direction(segment: &str) -> Option<[Direction; 2]> {
    use Direction::{Backward as B, Forward as F};
    match segment {
        SEGMENT_GRID_FWD => Some([F, F]),
        SEGMENT_GRID_BWD => Some([B, B]),
        SEGMENT_GRID_XBWD => Some([B, F]),
        SEGMENT_GRID_YBWD => Some([F, B]),
        _ => None,
    }
}

/// The segment of a grid node reached in `dirs` (`[x, y]`; an unknown
/// direction counts as forward): the inverse of [`grid_direction`].
pub fn grid_segment(dirs: [Direction; 2]) -> &'static str {
    let up = |d: Direction| d != Direction::Backward;
    match (up(dirs[0]), up(dirs[1])) {
        (true, true) => SEGMENT_GRID_FWD,
        (false, false) => SEGMENT_GRID_BWD,
        (false, true) => SEGMENT_GRID_XBWD,
        (true, false) => SEGMENT_GRID_YBWD,
    }
}

/// Whether `segment` is one of [`SEGMENTS_SWEEP_ANCHOR`].
pub fn is_sweep_anchor(segment: &str) -> bool {
    SEGMENTS_SWEEP_ANCHOR.contains(&segment)
}

/// Largest number of points a plan may generate (a typo such as a 1 nm step
/// over 10 mm must not allocate gigabytes).
pub const MAX_PLAN_POINTS: usize = 10_000_000;

/// A scan plan that cannot be run.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum ScanError {
    /// A parameter is out of range.
    #[error("scan plan: {key}: {reason}")]
    Invalid {
        /// Which parameter.
        key: String,
        /// Why.
        reason: String,
    },
}

fn invalid(key: &str, reason: impl Into<String>) -> ScanError {
    ScanError::Invalid {
        key: key.into(),
        reason: reason.into(),
    }
}

/// A 1-DoF scan of one axis.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AxisScan {
    /// The moving axis.
    pub axis: Axis,
    /// First target of a forward pass, µm (stage frame).
    pub start_um: f64,
    /// Last target of a forward pass, µm (> `start_um`).
    pub end_um: f64,
    /// Distance between targets, µm (> 0). The last point is `end_um` even
    /// when the stroke is not a multiple of the step.
    pub step_um: f64,
    /// Cycles; each is one forward and one backward pass.
    pub cycles: u32,
    /// Where the other axis is held, µm (reached by a forward approach).
    pub hold_um: f64,
    /// Distance beyond the first point of each pass from which it is
    /// approached, µm (> the backlash; default 20 µm = 10× the M-111's 2 µm).
    pub approach_um: f64,
}

/// One move of a plan.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ScanPoint {
    /// Log segment name.
    pub segment: String,
    /// Cycle (0-based).
    pub cycle: u32,
    /// Direction of the pass along the moving axis (`Forward` = increasing
    /// target); for validation points, the direction of the move along the
    /// segment.
    pub direction: Direction,
    /// Target, µm, stage frame.
    pub target: XyUm,
    /// False for approach moves: move there, do not measure or log.
    pub logged: bool,
}

impl AxisScan {
    /// The paper's X scan: 0 → 9500 µm in 5 µm steps, 3 cycles, Y held at 0.
    pub fn paper_x() -> Self {
        AxisScan {
            axis: Axis::X,
            start_um: 0.0,
            end_um: 9500.0,
            step_um: 5.0,
            cycles: 3,
            hold_um: 0.0,
            approach_um: 20.0,
        }
    }

    /// The paper's Y scan: 0 → 4200 µm in 5 µm steps, 3 cycles, X held at 0.
    pub fn paper_y() -> Self {
        AxisScan {
            axis: Axis::Y,
            end_um: 4200.0,
            ..Self::paper_x()
        }
    }

    /// Checks the numbers (finite, ordered, positive step, bounded count).
    pub fn validate(&self) -> Result<(), ScanError> {
        for (k, v) in [
            ("start_um", self.start_um),
            ("end_um", self.end_um),
            ("step_um", self.step_um),
            ("hold_um", self.hold_um),
            ("approach_um", self.approach_um),
        ] {
            if !v.is_finite() {
                return Err(invalid(k, format!("{v} is not a finite number")));
            }
        }
        if self.end_um <= self.start_um {
            return Err(invalid(
                "end_um",
                format!(
                    "must be greater than start_um ({} ≤ {})",
                    self.end_um, self.start_um
                ),
            ));
        }
        if self.step_um <= 0.0 {
            return Err(invalid("step_um", "must be > 0"));
        }
        if self.approach_um <= 0.0 {
            return Err(invalid(
                "approach_um",
                "must be > 0 (the first point of a pass must be approached in the pass direction)",
            ));
        }
        if self.cycles == 0 {
            return Err(invalid("cycles", "must be ≥ 1"));
        }
        let n = self.points_per_pass_f();
        let total = n * 2.0 * f64::from(self.cycles);
        if total.is_nan() || total > MAX_PLAN_POINTS as f64 {
            return Err(invalid(
                "step_um",
                format!("{total} points exceed the limit of {MAX_PLAN_POINTS}"),
            ));
        }
        Ok(())
    }

    fn points_per_pass_f(&self) -> f64 {
        ((self.end_um - self.start_um) / self.step_um).ceil() + 1.0
    }

    /// The targets of one forward pass (increasing), µm.
    pub fn targets_um(&self) -> Result<Vec<f64>, ScanError> {
        self.validate()?;
        let n = self.points_per_pass_f() as usize;
        let mut out: Vec<f64> = (0..n)
            .map(|i| (self.start_um + self.step_um * i as f64).min(self.end_um))
            .collect();
        out.dedup();
        Ok(out)
    }

    /// Lowest and highest commanded position of the moving axis, approach
    /// moves included, µm.
    pub fn extent_um(&self) -> (f64, f64) {
        (
            self.start_um - self.approach_um,
            self.end_um + self.approach_um,
        )
    }

    /// Log segment name.
    pub fn segment(&self) -> &'static str {
        match self.axis {
            Axis::X => SEGMENT_SCAN_X,
            Axis::Y => SEGMENT_SCAN_Y,
        }
    }

    fn xy(&self, moving_um: f64, held_um: f64) -> XyUm {
        match self.axis {
            Axis::X => XyUm {
                x_um: moving_um,
                y_um: held_um,
            },
            Axis::Y => XyUm {
                x_um: held_um,
                y_um: moving_um,
            },
        }
    }

    /// Every move in order: park the held axis (forward approach), then per
    /// cycle an approach and a forward pass, an approach and a backward pass.
    pub fn points(&self) -> Result<Vec<ScanPoint>, ScanError> {
        let targets = self.targets_um()?;
        let seg = self.segment().to_string();
        let mut out = Vec::with_capacity(targets.len() * 2 * self.cycles as usize + 8);
        let first = self.start_um - self.approach_um;
        let point = |cycle, direction, target, logged| ScanPoint {
            segment: seg.clone(),
            cycle,
            direction,
            target,
            logged,
        };
        // Park the held axis by a forward approach.
        out.push(point(
            0,
            Direction::Forward,
            self.xy(first, self.hold_um - self.approach_um),
            false,
        ));
        for cycle in 0..self.cycles {
            out.push(point(
                cycle,
                Direction::Forward,
                self.xy(first, self.hold_um),
                false,
            ));
            for &t in &targets {
                out.push(point(
                    cycle,
                    Direction::Forward,
                    self.xy(t, self.hold_um),
                    true,
                ));
            }
            out.push(point(
                cycle,
                Direction::Backward,
                self.xy(self.end_um + self.approach_um, self.hold_um),
                false,
            ));
            for &t in targets.iter().rev() {
                out.push(point(
                    cycle,
                    Direction::Backward,
                    self.xy(t, self.hold_um),
                    true,
                ));
            }
        }
        Ok(out)
    }
}

/// The two scans of a characterization.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CharacterizationPlan {
    /// X scan (Y held).
    pub x: AxisScan,
    /// Y scan (X held).
    pub y: AxisScan,
}

impl CharacterizationPlan {
    /// The paper's characterization (5 µm steps, 3 cycles, 11 406 + 5 046
    /// logged points; 9.5 h on the paper's rig).
    pub fn paper() -> Self {
        CharacterizationPlan {
            x: AxisScan::paper_x(),
            y: AxisScan::paper_y(),
        }
    }

    /// Ten times fewer points (50 µm steps, 8 per screw period): enough for
    /// the model-based compensation (`crate::comp::ModelCompensator`),
    /// which fits harmonics of the screw lead instead of interpolating.
    pub fn short() -> Self {
        let mut p = Self::paper();
        p.x.step_um = 50.0;
        p.y.step_um = 50.0;
        p
    }

    /// X scan then Y scan.
    pub fn points(&self) -> Result<Vec<ScanPoint>, ScanError> {
        let mut v = self.x.points()?;
        v.extend(self.y.points()?);
        Ok(v)
    }
}

/// The paper's square: 4000 × 4000 µm from (10, 10) to (4010, 4010) µm,
/// traversed A(10,10) → B(4010,10) → C(4010,4010) → D(10,4010) → A, one pose
/// every `step_um` (the corner ending a segment starts the next one). Each
/// point is labelled [`SEGMENT_SQUARE`] and carries its segment's direction
/// along the moving axis; use [`square_segment_name`] for AB/BC/CD/DA.
pub fn square_poses(step_um: f64) -> Result<Vec<ScanPoint>, ScanError> {
    if !(step_um.is_finite() && step_um > 0.0) {
        return Err(invalid("step_um", "must be a finite number > 0"));
    }
    let (lo, hi) = (10.0, 4010.0);
    let n = ((hi - lo) / step_um).ceil();
    if n * 4.0 > MAX_PLAN_POINTS as f64 {
        return Err(invalid("step_um", "too many points"));
    }
    let n = n as usize;
    let s = |i: usize| (lo + step_um * i as f64).min(hi);
    let r = |i: usize| (hi - step_um * i as f64).max(lo);
    let mut out = Vec::with_capacity(4 * n);
    let mut push = |x, y, d| {
        out.push(ScanPoint {
            segment: SEGMENT_SQUARE.into(),
            cycle: 0,
            direction: d,
            target: XyUm { x_um: x, y_um: y },
            logged: true,
        })
    };
    for i in 0..n {
        push(s(i), lo, Direction::Forward); // AB
    }
    for i in 0..n {
        push(hi, s(i), Direction::Forward); // BC
    }
    for i in 0..n {
        push(r(i), hi, Direction::Backward); // CD
    }
    for i in 0..n {
        push(lo, r(i), Direction::Backward); // DA
    }
    Ok(out)
}

/// Which side of the square a pose index of [`square_poses`] is on
/// (`"AB"`, `"BC"`, `"CD"`, `"DA"`), given the number of poses.
pub fn square_segment_name(index: usize, total: usize) -> &'static str {
    let per = (total / 4).max(1);
    match index / per {
        0 => "AB",
        1 => "BC",
        2 => "CD",
        _ => "DA",
    }
}

/// The label of pose `index` of [`square_poses`] with `per_side` poses per
/// side: the corners are `A` (10, 10), `B` (4010, 10), `C` (4010, 4010),
/// `D` (10, 4010); the poses between are the side's name and their
/// 1-based place on it (`AB1`, `AB2`, …, `DA7`). Validation logs use it in
/// their `pose` column.
pub fn square_pose_label(index: usize, per_side: usize) -> String {
    let per = per_side.max(1);
    let side = (index / per).min(3);
    let k = index - side * per;
    if k == 0 {
        ["A", "B", "C", "D"][side].to_owned()
    } else {
        format!("{}{k}", ["AB", "BC", "CD", "DA"][side])
    }
}

/// Table II of the paper: the ten random targets, µm, visited in this order.
pub const RANDOM_TARGETS_UM: [(f64, f64); 10] = [
    (3471.0, 2311.0),
    (6044.0, 3991.0),
    (3673.0, 39.0),
    (5118.0, 2738.0),
    (3643.0, 2071.0),
    (8196.0, 186.0),
    (1702.0, 756.0),
    (3776.0, 3815.0),
    (3903.0, 1390.0),
    (1035.0, 35.0),
];

/// [`RANDOM_TARGETS_UM`] as positions.
pub fn random_targets() -> Vec<XyUm> {
    RANDOM_TARGETS_UM
        .iter()
        .map(|&(x_um, y_um)| XyUm { x_um, y_um })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paper_plan_has_the_papers_point_counts() {
        let p = CharacterizationPlan::paper();
        let x = p.x.points().unwrap();
        let y = p.y.points().unwrap();
        let lx = x.iter().filter(|p| p.logged).count();
        let ly = y.iter().filter(|p| p.logged).count();
        // Paper: 11 403 and 5 043 (it does not say how the ends were counted).
        assert_eq!(lx, 1901 * 6);
        assert_eq!(ly, 841 * 6);
        assert_eq!(p.x.extent_um(), (-20.0, 9520.0));
        let short = CharacterizationPlan::short();
        assert_eq!(
            short
                .x
                .points()
                .unwrap()
                .iter()
                .filter(|p| p.logged)
                .count(),
            191 * 6
        );
    }

    #[test]
    fn every_logged_point_is_reached_in_its_pass_direction() {
        let pts = AxisScan::paper_y().points().unwrap();
        let mut prev = pts[0].target;
        for p in &pts[1..] {
            let d = p.target.y_um - prev.y_um;
            if p.logged {
                match p.direction {
                    Direction::Forward => assert!(d > 0.0, "{p:?}"),
                    Direction::Backward => assert!(d < 0.0, "{p:?}"),
                    Direction::Unknown => panic!(),
                }
                assert_eq!(p.target.x_um, 0.0);
            }
            prev = p.target;
        }
        // The held axis was parked by a forward move.
        assert!(pts[0].target.x_um < pts[1].target.x_um);
    }

    #[test]
    fn last_point_is_the_end_even_off_grid() {
        let s = AxisScan {
            end_um: 12.0,
            step_um: 5.0,
            ..AxisScan::paper_x()
        };
        assert_eq!(s.targets_um().unwrap(), vec![0.0, 5.0, 10.0, 12.0]);
    }

    #[test]
    fn bad_plans_are_refused() {
        let mut s = AxisScan::paper_x();
        s.step_um = 0.0;
        assert!(s.points().is_err());
        s.step_um = 1e-9;
        assert!(s.points().is_err());
        s.step_um = f64::NAN;
        assert!(s.validate().is_err());
        let mut s = AxisScan::paper_x();
        s.end_um = -1.0;
        assert!(s.validate().is_err());
        assert!(square_poses(0.0).is_err());
        assert!(square_poses(f64::INFINITY).is_err());
    }

    #[test]
    fn square_goes_round() {
        let p = square_poses(200.0).unwrap();
        assert_eq!(p.len(), 80);
        assert_eq!((p[0].target.x_um, p[0].target.y_um), (10.0, 10.0));
        assert_eq!((p[20].target.x_um, p[20].target.y_um), (4010.0, 10.0));
        assert_eq!((p[40].target.x_um, p[40].target.y_um), (4010.0, 4010.0));
        assert_eq!((p[60].target.x_um, p[60].target.y_um), (10.0, 4010.0));
        assert_eq!(square_segment_name(25, 80), "BC");
        assert_eq!(square_pose_label(0, 20), "A");
        assert_eq!(square_pose_label(20, 20), "B");
        assert_eq!(square_pose_label(41, 20), "CD1");
        assert_eq!(square_pose_label(79, 20), "DA19");
        assert_eq!(square_pose_label(60, 20), "D");
        assert_eq!(random_targets().len(), 10);
    }
}
