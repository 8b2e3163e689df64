//! The sweep characterization's static anchors, pure: where the job stops
//! after the passes of a cycle, how it reaches each stop, and the
//! correction of the sweep's records the stops give. `daemon::jobs::sweep_job`
//! moves and measures; [`super`] has the passes and the camera delay.
//!
//! # Why
//! A pass is one constant-velocity move across the range, so whatever the
//! stage's error owes to the path since the move began is loaded in a
//! sweep as far as the pass has travelled: lost motion that winds up with
//! the length of the move (the paper-faithful stage's
//! `−dir·A·(1 − e^(−L/λ))`, A = 5 µm, λ = 1 mm), a hysteresis that closes
//! with the travel since the reversal. A step characterization stops every
//! `step_um` and measures the stage after a move of `step_um`; lookup tables
//! built from it describe that state, and their compensation assumes it. A
//! sweep record carries the pass's state instead, and differs from the
//! step plan's by an offset that varies along the axis with where the pass
//! began.
//!
//! The anchors measure the step plan's state at a few grid points per axis
//! and direction, in every cycle. The difference anchor − sweep (same
//! point, direction and cycle, on `e = cmd − measured` of both components;
//! the median over the cycles) is an offset curve per axis and direction,
//! and every record of the sweep is corrected by it: linear between
//! anchors, the end anchor's value beyond the first and the last. Nothing
//! here knows the stage's model: an anchor is a measurement, the curve is
//! what the data show.
//!
//! # Route
//! The anchors of one direction are visited as the step plan visits its
//! points, in the pass's direction ([`anchor_route`]): the axis turns at the
//! pass's first grid point (it arrives there against the pass direction from
//! [`PARK_APPROACH_UM`] beyond, as the step plan arrives at its turn), then
//! for each anchor moves to one step before it and arrives by a final move
//! of `step_um`. At every anchor the last move is therefore a step (what a
//! length-dependent lost motion sees), the travel since the last reversal is
//! the step plan's (what a play or a hysteresis sees) and the direction is
//! the pass's. The job settles and averages frames as the step job does.
//!
//! # Spacing
//! Linear interpolation between anchors `h` apart is off by at most
//! `h²/8 · max|c″|` of the offset curve `c`: the correction follows what
//! varies slower than the spacing. For lost motion of amplitude A that builds
//! up over λ, `|c″| ≤ A/λ²`, so the error is at most `A·(h/λ)²/8`: on the
//! faithful stage 0.039 µm at the default [`DEFAULT_ANCHOR_SPACING_UM`]
//! (250 µm), about one anchor's own scatter (the settling σ of 0.035 µm per
//! stop), 0.16 µm at 500 µm. An effect that closes within a few steps of the
//! turn (a play taken up over 10 µm) is seen by the first anchor only and
//! spread over the first interval: the spacing bounds what the correction
//! can resolve, in both directions.
//!
//! # Noise
//! An anchor carries the settling scatter of one stop per cycle (σ 0.035 µm
//! on the simulated M-111), which an interpolated curve passes on to every
//! record between its anchors. Where a curve does not vary beyond that noise
//! the anchors' weighted mean is as good and much quieter: per axis,
//! direction and component (along, across), the medians' χ² about their
//! weighted mean, each weighted by its variance (the cycles' pooled scatter
//! about their anchor's mean, π/2 of it per cycle for a median), is tested
//! against its upper 99 % point; below it the curve is flat at the mean
//! (a constant offset per direction, as a play that differs on the fly),
//! above it the anchors are interpolated. A stage without path dependence
//! thus gets a constant of noise σ/√(anchors · cycles); a wind-up of a few
//! µm over a millimetre is thousands of σ above the point.
//!
//! # Robustness
//! The cycles' differences at an anchor are reduced to their median. A stop
//! on a rough stretch of the travel (stick-slip: the faithful stage's
//! settling σ is 1 µm there) scatters from cycle to cycle far more than the
//! others: an anchor whose largest deviation from its median exceeds
//! [`REJECT_FACTOR`] × the median of that figure over the axis's anchors (and
//! [`SPREAD_FLOOR_UM`]) is left out, and the curve interpolates across it.
//! The sweep's own value at an anchor is its frames' linear interpolation at
//! the anchor's position ([`value_at`]), not a cell mean: frames fall
//! anywhere in a cell, and the leadscrew's slope over half a step (≈ 0.06 µm
//! on the simulated stage) would enter the difference.

use super::{frames_at, FrameAt, PassData, SweepPlan};
use crate::charact::scan::PARK_APPROACH_UM;
use crate::model::XyUm;

/// Spacing of the anchors when the request names none, µm (see the module
/// docs, "Spacing": A·(h/λ)²/8 = 0.039 µm for the faithful stage's 5 µm
/// over 1 mm).
pub const DEFAULT_ANCHOR_SPACING_UM: f64 = 250.0;

/// An anchor whose cycles deviate from their median by more than this many
/// times the axis's typical deviation is left out (a rough stretch).
pub const REJECT_FACTOR: f64 = 5.0;

/// Deviations up to this are never a rough stretch, µm: a settling scatter
/// of 0.035 µm per stop gives deviations of that size, and a test without
/// noise must not reject anchors for rounding.
pub const SPREAD_FLOOR_UM: f64 = 0.05;

/// The sweep's value at an anchor interpolates the frames on either side
/// only when both lie within this many steps of it.
pub const MAX_GAP_STEPS: f64 = 2.0;

/// One stop of an anchor route on the swept axis (the held axis stays at
/// the pass's hold).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RouteStop {
    /// Position of the swept axis, µm.
    pub pos_um: f64,
    /// Settle and measure here (an anchor), or only pass through.
    pub measure: bool,
}

/// Signed direction: +1 forward, −1 backward.
fn sign(forward: bool) -> f64 {
    if forward {
        1.0
    } else {
        -1.0
    }
}

/// The anchor positions of one axis and direction, in the order the route
/// measures them (the pass's). Every `anchor_every()`-th grid point and the
/// range's far end; the pass's first grid point is its turn (the step plan
/// logs it as a repeat of the previous pass's last point, which `tables
/// build` drops), so the anchor there moves one step in. Empty without
/// anchors.
pub fn anchor_positions(plan: &SweepPlan, x_axis: bool, forward: bool) -> Vec<f64> {
    let grid = plan.grid(x_axis);
    let Some(every) = plan.anchor_every() else {
        return Vec::new();
    };
    let Some(last) = grid.len().checked_sub(1).filter(|&l| l > 0) else {
        return Vec::new();
    };
    let mut idx: Vec<usize> = (0..=last).step_by(every).collect();
    if idx.last() != Some(&last) {
        idx.push(last);
    }
    let (turn, inward) = if forward { (0, 1) } else { (last, last - 1) };
    for i in &mut idx {
        if *i == turn {
            *i = inward;
        }
    }
    idx.sort_unstable();
    idx.dedup();
    if !forward {
        idx.reverse();
    }
    idx.into_iter().map(|i| grid[i]).collect()
}

/// The route of one axis and direction's anchors (see the module docs,
/// "Route"): the turn at the pass's first grid point, reached from
/// [`PARK_APPROACH_UM`] into the range, then per anchor a stop one step
/// before it (unless the route is there already) and the anchor, measured.
pub fn anchor_route(plan: &SweepPlan, x_axis: bool, forward: bool) -> Vec<RouteStop> {
    let anchors = anchor_positions(plan, x_axis, forward);
    let grid = plan.grid(x_axis);
    let (Some(&first), Some(&last)) = (grid.first(), grid.last()) else {
        return Vec::new();
    };
    if anchors.is_empty() {
        return Vec::new();
    }
    let dir = sign(forward);
    let turn = if forward { first } else { last };
    let mut route = vec![
        RouteStop {
            pos_um: turn + dir * PARK_APPROACH_UM,
            measure: false,
        },
        RouteStop {
            pos_um: turn,
            measure: false,
        },
    ];
    for p in anchors {
        let before = p - dir * plan.step_um;
        if route
            .last()
            .is_none_or(|s| (s.pos_um - before).abs() > 1e-6)
        {
            route.push(RouteStop {
                pos_um: before,
                measure: false,
            });
        }
        route.push(RouteStop {
            pos_um: p,
            measure: true,
        });
    }
    route
}

/// One anchor as measured.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AnchorMeas {
    /// On the X axis (else Y).
    pub x_axis: bool,
    /// In the forward direction.
    pub forward: bool,
    /// Cycle of the passes it follows.
    pub cycle: u32,
    /// Position of the swept axis (the command), µm.
    pub pos_um: f64,
    /// Position of the held axis (the command), µm.
    pub hold_um: f64,
    /// Measured position, stage frame, µm.
    pub meas: XyUm,
    /// The frames' mean camera stamp, rig s.
    pub t_s: f64,
    /// Mean decoder quality.
    pub quality: f64,
}

impl AnchorMeas {
    /// `cmd − measured` of the swept and of the held axis, µm.
    pub fn errors_um(&self) -> (f64, f64) {
        let (scan, held) = if self.x_axis {
            (self.meas.x_um, self.meas.y_um)
        } else {
            (self.meas.y_um, self.meas.x_um)
        };
        (self.pos_um - scan, self.hold_um - held)
    }
}

/// The sweep's `(e_scan, e_held)` at `pos_um`: the frames (sorted by
/// position) on either side joined by a straight line, both within
/// `max_gap_um`; a frame exactly there is taken as it is. `None` where the
/// frames do not bracket the position closely enough.
pub fn value_at(frames: &[FrameAt], pos_um: f64, max_gap_um: f64) -> Option<(f64, f64)> {
    let k = frames.partition_point(|f| f.cmd_um < pos_um);
    let b = frames.get(k)?;
    if b.cmd_um == pos_um {
        return Some((b.e_scan_um, b.e_held_um));
    }
    let a = frames.get(k.checked_sub(1)?)?;
    let span = b.cmd_um - a.cmd_um;
    if pos_um - a.cmd_um > max_gap_um
        || b.cmd_um - pos_um > max_gap_um
        || span.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater)
    {
        return None;
    }
    let w = (pos_um - a.cmd_um) / span;
    Some((
        a.e_scan_um + w * (b.e_scan_um - a.e_scan_um),
        a.e_held_um + w * (b.e_held_um - a.e_held_um),
    ))
}

/// One cycle's difference at an anchor: anchor − sweep, µm.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AnchorDiff {
    /// The cycle.
    pub cycle: u32,
    /// Of `e` along the swept axis.
    pub scan_um: f64,
    /// Of `e` across it (the held axis).
    pub held_um: f64,
}

/// One anchor position of one axis and direction, over the cycles.
#[derive(Debug, Clone, PartialEq)]
pub struct AnchorPoint {
    /// On the X axis (else Y).
    pub x_axis: bool,
    /// In the forward direction.
    pub forward: bool,
    /// Position of the swept axis, µm.
    pub pos_um: f64,
    /// Per cycle, where the sweep has a value there.
    pub diffs: Vec<AnchorDiff>,
    /// Median over the cycles, along the swept axis, µm.
    pub scan_um: f64,
    /// Median over the cycles, across it, µm.
    pub held_um: f64,
    /// Largest deviation of a cycle from the medians (either component), µm.
    pub spread_um: f64,
    /// Whether the correction uses it (it has a difference and its cycles
    /// agree; see the module docs, "Robustness").
    pub used: bool,
}

impl AnchorPoint {
    /// `x_fwd@1234.5`: how the log's metadata names a point.
    pub fn label(&self) -> String {
        format!(
            "{}_{}@{}",
            if self.x_axis { "x" } else { "y" },
            if self.forward { "fwd" } else { "bwd" },
            self.pos_um
        )
    }
}

/// Whether one axis and direction's curve varies beyond its noise (see the
/// module docs, "Noise").
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GroupFit {
    /// On the X axis (else Y).
    pub x_axis: bool,
    /// In the forward direction.
    pub forward: bool,
    /// Along and across the axis: χ² of the used anchors' medians about
    /// their weighted mean, per degree of freedom (NaN: not tested).
    pub chi2_per_dof: [f64; 2],
    /// Along and across: the curve is flat (every anchor takes the weighted
    /// mean).
    pub flat: [bool; 2],
}

impl GroupFit {
    /// `x_fwd`: how the log's metadata names a group.
    pub fn label(&self) -> String {
        format!(
            "{}_{}",
            if self.x_axis { "x" } else { "y" },
            if self.forward { "fwd" } else { "bwd" }
        )
    }
}

/// The offset curves the anchors give, per axis and direction.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct AnchorCorrection {
    /// Every anchor position, grouped by axis and direction, ascending.
    pub points: Vec<AnchorPoint>,
    /// Per axis (x, y), the median spread the rejection compares with, µm.
    pub typical_spread_um: [f64; 2],
    /// Per axis (x, y) and component (along, across), the pooled variance
    /// of one cycle's difference about its anchor's mean, µm².
    pub cycle_variance_um2: [[f64; 2]; 2],
    /// Per axis and direction with anchors, the flatness test.
    pub groups: Vec<GroupFit>,
}

/// Variance of the median of `n` samples over that of one sample, times
/// `n`: 1 for one or two (the median is the mean), π/2 beyond (the large-`n`
/// value, above the exact 1.35 of three: the test errs towards a curve).
fn median_variance_factor(n: usize) -> f64 {
    if n <= 2 {
        1.0
    } else {
        std::f64::consts::FRAC_PI_2
    }
}

/// Upper 99 % point of χ² with `dof` degrees of freedom (Wilson–Hilferty).
fn chi2_upper_99(dof: f64) -> f64 {
    let a = 2.0 / (9.0 * dof);
    dof * (1.0 - a + 2.326 * a.sqrt()).powi(3)
}

/// The flatness test of one group and component (see the module docs,
/// "Noise"): `(χ²/dof, flat, weighted mean)`, or `None` when it cannot be
/// made (fewer than two used anchors, no cycle scatter to weigh them by).
fn flatness(values: &[(f64, usize)], cycle_var: f64) -> Option<(f64, bool, f64)> {
    if values.len() < 2 || cycle_var.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
        return None;
    }
    let var = |n: usize| median_variance_factor(n) * cycle_var / n.max(1) as f64;
    let (sw, swc) = values.iter().fold((0.0, 0.0), |(a, b), &(c, n)| {
        (a + 1.0 / var(n), b + c / var(n))
    });
    let mean = swc / sw;
    let q: f64 = values
        .iter()
        .map(|&(c, n)| (c - mean).powi(2) / var(n))
        .sum();
    let dof = (values.len() - 1) as f64;
    let chi = q / dof;
    chi.is_finite()
        .then_some((chi, q <= chi2_upper_99(dof), mean))
}

/// Median of `v` (mean of the middle two for an even count); `None` if
/// empty.
fn median(mut v: Vec<f64>) -> Option<f64> {
    v.retain(|x| x.is_finite());
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    Some(if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    })
}

/// The anchors' correction: per measured anchor, the sweep's value at its
/// position in the pass of the same axis, direction and cycle (frames placed
/// at `stamp − delay_s`), the difference, the median over cycles and the
/// rejection of scattering anchors (see the module docs).
pub fn anchor_correction(
    passes: &[PassData],
    anchors: &[AnchorMeas],
    delay_s: f64,
    step_um: f64,
) -> AnchorCorrection {
    let placed: Vec<Vec<FrameAt>> = passes.iter().map(|p| frames_at(p, delay_s)).collect();
    let mut points: Vec<AnchorPoint> = Vec::new();
    for m in anchors {
        let k = points.iter().position(|p| {
            p.x_axis == m.x_axis && p.forward == m.forward && (p.pos_um - m.pos_um).abs() < 1e-6
        });
        let k = k.unwrap_or_else(|| {
            points.push(AnchorPoint {
                x_axis: m.x_axis,
                forward: m.forward,
                pos_um: m.pos_um,
                diffs: Vec::new(),
                scan_um: 0.0,
                held_um: 0.0,
                spread_um: 0.0,
                used: false,
            });
            points.len() - 1
        });
        let pass = passes.iter().position(|p| {
            p.spec.x_axis == m.x_axis && p.spec.forward == m.forward && p.spec.cycle == m.cycle
        });
        let Some(frames) = pass.and_then(|i| placed.get(i)) else {
            continue;
        };
        let Some((es, eh)) = value_at(frames, m.pos_um, MAX_GAP_STEPS * step_um) else {
            continue;
        };
        let (as_, ah) = m.errors_um();
        let d = AnchorDiff {
            cycle: m.cycle,
            scan_um: as_ - es,
            held_um: ah - eh,
        };
        if d.scan_um.is_finite() && d.held_um.is_finite() {
            points[k].diffs.push(d);
        }
    }
    for p in &mut points {
        let (Some(s), Some(h)) = (
            median(p.diffs.iter().map(|d| d.scan_um).collect()),
            median(p.diffs.iter().map(|d| d.held_um).collect()),
        ) else {
            continue;
        };
        p.scan_um = s;
        p.held_um = h;
        p.spread_um = p
            .diffs
            .iter()
            .map(|d| (d.scan_um - s).abs().max((d.held_um - h).abs()))
            .fold(0.0, f64::max);
        p.used = true;
    }
    let mut typical = [0.0; 2];
    for (a, t) in typical.iter_mut().enumerate() {
        let spreads = points
            .iter()
            .filter(|p| usize::from(!p.x_axis) == a && p.diffs.len() >= 2)
            .map(|p| p.spread_um)
            .collect();
        *t = median(spreads).unwrap_or(0.0);
    }
    for p in &mut points {
        let limit = (REJECT_FACTOR * typical[usize::from(!p.x_axis)]).max(SPREAD_FLOOR_UM);
        if p.diffs.len() >= 2 && p.spread_um > limit {
            p.used = false;
        }
    }
    // The cycles' scatter about their anchor's mean, pooled per axis and
    // component over the used anchors.
    let mut cycle_var = [[0.0; 2]; 2];
    for (a, v) in cycle_var.iter_mut().enumerate() {
        let mut ss = [0.0; 2];
        let mut dof = 0usize;
        for p in points
            .iter()
            .filter(|p| p.used && usize::from(!p.x_axis) == a && p.diffs.len() >= 2)
        {
            let n = p.diffs.len() as f64;
            let m = [
                p.diffs.iter().map(|d| d.scan_um).sum::<f64>() / n,
                p.diffs.iter().map(|d| d.held_um).sum::<f64>() / n,
            ];
            for d in &p.diffs {
                ss[0] += (d.scan_um - m[0]).powi(2);
                ss[1] += (d.held_um - m[1]).powi(2);
            }
            dof += p.diffs.len() - 1;
        }
        if dof > 0 {
            *v = ss.map(|x| x / dof as f64);
        }
    }
    let mut groups = Vec::new();
    for x_axis in [true, false] {
        for forward in [true, false] {
            let in_group = |p: &AnchorPoint| p.x_axis == x_axis && p.forward == forward;
            if !points.iter().any(in_group) {
                continue;
            }
            let mut g = GroupFit {
                x_axis,
                forward,
                chi2_per_dof: [f64::NAN; 2],
                flat: [false; 2],
            };
            for (c, &var) in cycle_var[usize::from(!x_axis)].iter().enumerate() {
                let values: Vec<(f64, usize)> = points
                    .iter()
                    .filter(|p| p.used && in_group(p))
                    .map(|p| (if c == 0 { p.scan_um } else { p.held_um }, p.diffs.len()))
                    .collect();
                let Some((chi, flat, mean)) = flatness(&values, var) else {
                    continue;
                };
                g.chi2_per_dof[c] = chi;
                g.flat[c] = flat;
                if flat {
                    for p in points.iter_mut().filter(|p| p.used && in_group(p)) {
                        if c == 0 {
                            p.scan_um = mean;
                        } else {
                            p.held_um = mean;
                        }
                    }
                }
            }
            groups.push(g);
        }
    }
    points.sort_by(|a, b| {
        (!a.x_axis, a.forward)
            .cmp(&(!b.x_axis, b.forward))
            .then(a.pos_um.total_cmp(&b.pos_um))
    });
    AnchorCorrection {
        points,
        typical_spread_um: typical,
        cycle_variance_um2: cycle_var,
        groups,
    }
}

impl AnchorCorrection {
    /// The used points of one axis and direction, ascending.
    fn group(&self, x_axis: bool, forward: bool) -> impl Iterator<Item = &AnchorPoint> {
        self.points
            .iter()
            .filter(move |p| p.used && p.x_axis == x_axis && p.forward == forward)
    }

    /// The correction `(scan, held)` to add to a record's `e` (µm) at
    /// `pos_um` of that axis and direction: linear between the used anchors,
    /// the first's (last's) value before (after) them, zero where the axis
    /// and direction have none.
    pub fn at(&self, x_axis: bool, forward: bool, pos_um: f64) -> (f64, f64) {
        let mut prev: Option<&AnchorPoint> = None;
        for p in self.group(x_axis, forward) {
            if pos_um <= p.pos_um {
                return match prev {
                    None => (p.scan_um, p.held_um),
                    Some(a) => {
                        let w = (pos_um - a.pos_um) / (p.pos_um - a.pos_um);
                        (
                            a.scan_um + w * (p.scan_um - a.scan_um),
                            a.held_um + w * (p.held_um - a.held_um),
                        )
                    }
                };
            }
            prev = Some(p);
        }
        prev.map_or((0.0, 0.0), |p| (p.scan_um, p.held_um))
    }

    /// The difference logged with one anchor measurement, if the sweep had
    /// a value there.
    pub fn diff_of(&self, m: &AnchorMeas) -> Option<AnchorDiff> {
        self.points
            .iter()
            .find(|p| {
                p.x_axis == m.x_axis && p.forward == m.forward && (p.pos_um - m.pos_um).abs() < 1e-6
            })?
            .diffs
            .iter()
            .find(|d| d.cycle == m.cycle)
            .copied()
    }

    /// The anchor positions left out because their cycles scatter (see
    /// the module docs, "Robustness").
    pub fn rejected(&self) -> impl Iterator<Item = &AnchorPoint> {
        self.points
            .iter()
            .filter(|p| !p.used && !p.diffs.is_empty())
    }

    /// The anchor positions the sweep has no value at in any cycle (an end
    /// of the travel where the passes decelerate: no frame at the pass's
    /// velocity there).
    pub fn unmatched(&self) -> impl Iterator<Item = &AnchorPoint> {
        self.points.iter().filter(|p| p.diffs.is_empty())
    }

    /// Largest |correction| over the used anchors of an axis, `(scan,
    /// held)`, µm.
    pub fn max_abs_um(&self, x_axis: bool) -> (f64, f64) {
        self.points
            .iter()
            .filter(|p| p.used && p.x_axis == x_axis)
            .fold((0.0, 0.0), |(s, h), p| {
                (s.max(p.scan_um.abs()), h.max(p.held_um.abs()))
            })
    }
}

#[cfg(test)]
mod tests;
