//! Steps 1 and 3 of the analysis: the log replayed through the model's
//! motion tracker into states and residual rows, with the folds and the
//! centring groups the nuisance constants are profiled out by, and the
//! log's extra columns worth searching (kind `other`).
//!
//! Why a file of its own: every later step reads the log only through
//! [`Data`], so what counts as a row, a fold or a searchable column is
//! decided here once.

use super::log_columns::{
    approach_signs, declared_approach, judged_rows, measured_axes, numeric_extra_columns,
    with_approach_moves,
};
use crate::analysis::grid::GridMap;
use crate::analysis::AnalysisError;
use crate::charact::log::{MeasurementLog, Record};
use crate::model::{Axis, MotionState, MotionTracker, StageModel, Waypoint};
use std::collections::HashMap;

/// The log turned into model states and residual rows.
#[derive(Clone)]
pub(super) struct Data {
    pub(super) n: usize,
    pub(super) states: Vec<MotionState>,
    pub(super) meas: Vec<[f64; 2]>,
    /// Residual of the model as given, index `2i + c`.
    pub(super) r0: Vec<f64>,
    pub(super) fold: Vec<usize>,
    pub(super) nfolds: usize,
    /// Centring group per row and component (static axis in its block).
    pub(super) group: Vec<[Option<usize>; 2]>,
    pub(super) ngroups: usize,
    /// Whether axis `a` moves within the row's block.
    pub(super) moving: Vec<[bool; 2]>,
    pub(super) t0: f64,
    pub(super) temp_varies: bool,
    /// Numeric extra columns searched by the `other` family.
    pub(super) extra: Vec<ExtraVar>,
    /// Whether the log measured each error component (`[x, y]`): from the
    /// `measured_axes` metadata when present, else an axis whose
    /// `*_meas_um` column is constant (a placeholder) is unmeasured.
    /// Unmeasured components are zeroed in every residual and column
    /// ([`Data::center`]), so nothing is fitted or reported on them.
    pub(super) measured: [bool; 2],
    /// How each axis's measured status was decided (for the report).
    pub(super) measured_source: MeasuredSource,
    /// Whether a row's held-out prediction is judged: with whole-cycle
    /// folds, a row whose position (per moving axis and approach
    /// direction) lies outside the range the other folds sampled is an
    /// extrapolation the fold was never trained on, and is not scored.
    pub(super) judged: Vec<bool>,
    /// Rows left out of every fit and every held-out score: visits the
    /// replicates show to be wild (more than `noise::OUTLIER_SIGMAS`
    /// robust σ from the other visits of their target, e.g. a first
    /// approach after rest). A single such visit of +128 µm among visits
    /// that agree within 3 µm would otherwise set both the fit of every
    /// per-target term and the held-out score of every candidate. They are
    /// reported (noise section, `first_approach` readings), not fitted.
    pub(super) excluded: Vec<bool>,
    /// Approach direction per row of the moving axis (`+1`, `−1`, `0`):
    /// the log's `approach` column when it has one (the true approach of
    /// ISO 230-2 exports, which a replay of logged commands cannot see
    /// when the approach moves were not logged), else the replayed one.
    pub(super) approach: Vec<[f64; 2]>,
    /// Whether the folds are whole cycles (else contiguous chunks of the
    /// log's one cycle, or blocks interleaved in time).
    pub(super) whole_cycle_folds: bool,
    /// The axis whose commanded position moves with time over the whole
    /// log (|r| ≥ [`TIME_POSITION_R`] over the rows where it moves: a
    /// one-way scan at a steady rate), and that correlation.
    pub(super) time_with: Option<(Axis, f64)>,
    /// Why the log's time explains nothing, when it cannot (a 2-D grid
    /// visited once per cell, or with synthetic times: time only follows
    /// the plan, so a drift cannot be told from an error over the grid).
    pub(super) time_unusable: Option<String>,
    /// Whether the log is a 2-D grid map (`analysis::grid`): then a
    /// segment is not a pass with a held axis (a raster's lines and one
    /// segment read the same), and a one-cycle map's folds are interleaved
    /// over the lattice, not chunks of the record order.
    pub(super) grid: bool,
}

/// How rows are assigned to held-out folds.
///
/// Why two schemes: a fold that holds out a whole cycle (or a contiguous
/// chunk) asks every term to extrapolate in time into a stretch of the log
/// it was not trained on. That is the right test of position structure
/// (the held-out cycle revisits the same positions) and the wrong one of a
/// time effect that is really there: a 301 s oscillation fitted on one
/// 600 s cycle does not predict the next (its phase is lost over the gap),
/// so it is judged worse than nothing and the log is called noise. Short
/// blocks of consecutive rows dealt round the folds hold out stretches
/// that lie between trained ones, in time and along every pass: what is
/// judged is interpolation. The diagnosis uses them only when the
/// replicates show that the error changes between visits of a target
/// (`noise::ComponentNoise::changes_between_visits`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum FoldScheme {
    /// Whole cycles, else contiguous chunks of a one-cycle log.
    Cycles,
    /// Blocks of [`INTERLEAVE_ROWS`] consecutive rows (in time) dealt
    /// round the folds.
    InterleavedInTime,
}

/// Rows per block of [`FoldScheme::InterleavedInTime`]: short against the
/// shortest period the time search looks for (20 row intervals, see
/// `search::search`), so a held-out block lies within a fraction of a
/// period of trained rows on both sides.
pub(super) const INTERLEAVE_ROWS: usize = 4;

/// Correlation of time with an axis's position from which a log cannot
/// tell a drift from an error that depends on that position.
pub(super) const TIME_POSITION_R: f64 = 0.98;

/// The axis (and the correlation) whose commanded position follows time
/// over the rows where it moves, or `None`.
///
/// Why: on a one-way scan at a steady rate (a flexure's return leg
/// recorded alone) position and time are one variable; a bow of the
/// travel fits as a curving drift of 1000 µm/h, and a drift as a scale.
/// Neither can be told from the other, so the log's time is not used to
/// explain anything.
fn time_position(states: &[MotionState], moving: &[[bool; 2]]) -> Option<(Axis, f64)> {
    Axis::ALL.into_iter().find_map(|a| {
        let pts: Vec<(f64, f64)> = states
            .iter()
            .zip(moving)
            .filter(|(_, m)| m[a.index()])
            .map(|(s, _)| (s.time_s, s.cmd_um(a)))
            .collect();
        if pts.len() < 10 || pts.len() * 10 < states.len() * 9 {
            return None;
        }
        let n = pts.len() as f64;
        let (mt, mx) = pts
            .iter()
            .fold((0.0, 0.0), |(t, x), p| (t + p.0 / n, x + p.1 / n));
        let (mut stt, mut sxx, mut stx) = (0.0, 0.0, 0.0);
        for &(t, x) in &pts {
            stt += (t - mt) * (t - mt);
            sxx += (x - mx) * (x - mx);
            stx += (t - mt) * (x - mx);
        }
        if stt <= 0.0 || sxx <= 0.0 {
            return None;
        }
        let r = stx / (stt * sxx).sqrt();
        (r.abs() >= TIME_POSITION_R).then_some((a, r))
    })
}

/// Where the measured/unmeasured decision came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum MeasuredSource {
    /// The log's `measured_axes` metadata entry.
    Metadata,
    /// The data: a constant `*_meas_um` column is a placeholder.
    Data,
}

/// A numeric extra column of the log.
#[derive(Clone)]
pub(super) struct ExtraVar {
    pub(super) name: String,
    /// Value per row (unparsable cells: the column mean).
    pub(super) values: Vec<f64>,
    /// Mean over the rows: the column is `value − mean` (a model has no
    /// intercept to absorb a column's offset).
    pub(super) mean: f64,
    pub(super) min: f64,
    pub(super) max: f64,
}

impl Data {
    /// Removes the nuisance constants (centring groups) from a residual or
    /// design column (index `2i + c`) and zeroes the components the log
    /// did not measure.
    /// Excluded rows ([`Data::excluded`]) are zero afterwards (a zero row
    /// adds nothing to a least-squares fit) and take no part in the means.
    pub(super) fn center(&self, v: &mut [f64]) {
        let rows = self.n.min(v.len() / 2);
        for c in 0..2 {
            if !self.measured[c] {
                for i in 0..rows {
                    v[2 * i + c] = 0.0;
                }
            }
        }
        let out = |i: usize| self.excluded.get(i).copied().unwrap_or(false);
        if self.ngroups > 0 {
            let mut sum = vec![0.0; self.ngroups];
            let mut cnt = vec![0usize; self.ngroups];
            for i in (0..rows).filter(|&i| !out(i)) {
                for c in 0..2 {
                    if let Some(g) = self.group[i][c] {
                        sum[g] += v[2 * i + c];
                        cnt[g] += 1;
                    }
                }
            }
            for i in 0..rows {
                for c in 0..2 {
                    if let Some(g) = self.group[i][c] {
                        if cnt[g] > 0 {
                            v[2 * i + c] -= sum[g] / cnt[g] as f64;
                        }
                    }
                }
            }
        }
        for i in (0..rows).filter(|&i| out(i)) {
            v[2 * i] = 0.0;
            v[2 * i + 1] = 0.0;
        }
    }
}

/// The log as [`Data`], its residual not yet centred: the caller
/// (`super::prepare`) leaves out the replicates' outliers, then centres.
pub(super) fn prepare(
    log: &MeasurementLog,
    model: &StageModel,
    max_folds: usize,
    scheme: FoldScheme,
) -> Result<Data, AnalysisError> {
    let recs = &log.records;
    if recs.len() < 20 {
        return Err(AnalysisError::Invalid(format!(
            "the log has {} points; the analysis needs at least 20",
            recs.len()
        )));
    }
    let env = model.environment();
    let waypoints: Vec<Waypoint> = recs
        .iter()
        .map(|r| Waypoint {
            x_um: r.x_cmd_um,
            y_um: r.y_cmd_um,
            time_s: r.t_s,
            temp_c: r.temp_c.unwrap_or_else(|| env.temperature_at(r.t_s)),
            cycle: r.cycle,
        })
        .collect();
    let min_move = model.stochastic().min_incremental_motion_um;
    // The approach moves a log declares (`approach` column) but did not
    // log become virtual waypoints, so the replayed direction and play
    // are the ones the stage really had.
    let declared = declared_approach(log);
    let (waypoints, real) = with_approach_moves(&waypoints, &declared, min_move);
    let mut start = MotionState::at_rest(waypoints[0].x_um, waypoints[0].y_um);
    start.time_s = waypoints[0].time_s;
    start.temp_c = waypoints[0].temp_c;
    let all_states = MotionTracker::new(start)?
        .with_min_move(min_move)?
        .replay(&waypoints)?;
    let states: Vec<MotionState> = real.iter().map(|&k| all_states[k]).collect();
    let n = states.len();
    let meas: Vec<[f64; 2]> = recs.iter().map(|r| [r.x_meas_um, r.y_meas_um]).collect();
    let mut r0 = vec![0.0; 2 * n];
    for i in 0..n {
        let o = model.observed_position(&states[i]);
        r0[2 * i] = meas[i][0] - o.x_um;
        r0[2 * i + 1] = meas[i][1] - o.y_um;
    }
    let (measured, measured_source) = measured_axes(log)?;
    let grid = GridMap::from_log(log, measured);
    // Folds: whole cycles, else contiguous chunks (a grid: interleaved
    // over its lattice).
    let mut cycles: Vec<u32> = recs.iter().map(|r| r.cycle).collect();
    cycles.sort_unstable();
    cycles.dedup();
    let (fold, nfolds) = folds(recs, &states, &cycles, grid.as_ref(), max_folds, scheme);
    let Centring { group, moving, nb } =
        centring_groups(recs, &states, &fold, grid.is_some(), scheme, min_move);
    let temps: Vec<f64> = states.iter().map(|s| s.temp_c).collect();
    let tmean = temps.iter().sum::<f64>() / n as f64;
    let tsd = (temps.iter().map(|t| (t - tmean).powi(2)).sum::<f64>() / n as f64).sqrt();
    let extra = numeric_extra_columns(log, &states);
    let synthetic = log
        .metadata
        .get(super::TIME_SOURCE_KEY)
        .is_some_and(|v| v.trim_start().starts_with("synthetic"));
    let time_unusable = grid.as_ref().and_then(|g| {
        if synthetic {
            Some("the log's times are synthetic (they only number the records of a grid): nothing is fitted or searched as a function of time".to_string())
        } else if g.cells.iter().flatten().all(|c| c.visits == 1) {
            Some("each point of the grid is visited once, so time only follows the plan: a drift cannot be told from an error over the grid, and nothing is fitted or searched as a function of time".to_string())
        } else {
            None
        }
    });
    let approach = approach_signs(log, &states);
    let judged = if cycles.len() >= 2 || scheme == FoldScheme::InterleavedInTime {
        judged_rows(&states, &approach, &moving, &fold, nfolds)
    } else {
        // Time-chunk folds partition the range by construction: masking
        // would leave nothing to judge (a known limit, see the docs).
        vec![true; n]
    };
    let d = Data {
        n,
        t0: states[0].time_s,
        states,
        meas,
        r0,
        fold,
        nfolds,
        group,
        ngroups: 2 * nb + 2,
        moving,
        temp_varies: tsd > 0.02,
        extra,
        measured,
        measured_source,
        judged,
        excluded: vec![false; n],
        approach,
        whole_cycle_folds: cycles.len() >= 2 && scheme == FoldScheme::Cycles,
        time_with: None,
        time_unusable,
        grid: grid.is_some(),
    };
    let mut d = d;
    d.time_with = time_position(&d.states, &d.moving);
    Ok(d)
}

/// Folds: whole cycles, else contiguous chunks (a grid: interleaved
/// over its lattice); interleaved in time under
/// [`FoldScheme::InterleavedInTime`]. Each row's fold, and how many.
fn folds(
    recs: &[Record],
    states: &[MotionState],
    cycles: &[u32],
    grid: Option<&GridMap>,
    max_folds: usize,
    scheme: FoldScheme,
) -> (Vec<usize>, usize) {
    let n = states.len();
    let max_folds = max_folds.max(2);
    if scheme == FoldScheme::InterleavedInTime {
        let k = if cycles.len() >= 2 {
            cycles.len().min(max_folds)
        } else {
            max_folds.min(5)
        };
        let mut order: Vec<usize> = (0..n).collect();
        order.sort_by(|&a, &b| states[a].time_s.total_cmp(&states[b].time_s));
        let mut fold = vec![0usize; n];
        for (rank, &i) in order.iter().enumerate() {
            fold[i] = (rank / INTERLEAVE_ROWS) % k;
        }
        (fold, k)
    } else if cycles.len() >= 2 {
        let k = cycles.len().min(max_folds);
        let rank: HashMap<u32, usize> = cycles.iter().enumerate().map(|(i, c)| (*c, i)).collect();
        (
            recs.iter().map(|r| rank[&r.cycle] % k).collect::<Vec<_>>(),
            k,
        )
    } else if let Some(g) = grid {
        // A diagonal pattern: every held-out cell has trained neighbours
        // on its row and its column, whatever order the log has.
        let k = max_folds.min(5);
        let fold = recs
            .iter()
            .map(|r| {
                let (ix, iy) = g.index_of(r.x_target_um, r.y_target_um);
                (ix + 2 * iy) % k
            })
            .collect();
        (fold, k)
    } else {
        let k = max_folds.min(5);
        ((0..n).map(|i| i * k / n).collect(), k)
    }
}

/// The centring groups of the rows (see [`Data::group`]).
struct Centring {
    /// Each row's centring group, per component.
    group: Vec<[Option<usize>; 2]>,
    /// Whether each row's axes move within its block.
    moving: Vec<[bool; 2]>,
    /// The number of blocks.
    nb: usize,
}

/// Blocks (segment, cycle, fold): static axes and centring groups.
fn centring_groups(
    recs: &[Record],
    states: &[MotionState],
    fold: &[usize],
    grid: bool,
    scheme: FoldScheme,
    min_move: f64,
) -> Centring {
    let n = states.len();
    let mut block_of: HashMap<(&str, u32, usize), usize> = HashMap::new();
    let mut block = vec![0usize; n];
    for i in 0..n {
        // Interleaved folds share their blocks: a pass's static axis has
        // one constant, not one per fold.
        let f = if scheme == FoldScheme::InterleavedInTime {
            0
        } else {
            fold[i]
        };
        let seg = if grid { "" } else { recs[i].segment.as_str() };
        let key = (seg, recs[i].cycle, f);
        let next = block_of.len();
        block[i] = *block_of.entry(key).or_insert(next);
    }
    let nb = block_of.len();
    let mut lo = vec![[f64::INFINITY; 2]; nb];
    let mut hi = vec![[f64::NEG_INFINITY; 2]; nb];
    for i in 0..n {
        for a in 0..2 {
            let v = states[i].axes[a].cmd_um;
            lo[block[i]][a] = lo[block[i]][a].min(v);
            hi[block[i]][a] = hi[block[i]][a].max(v);
        }
    }
    let tol = min_move.max(1e-6);
    let mut group = vec![[None; 2]; n];
    let mut moving = vec![[false; 2]; n];
    for i in 0..n {
        for a in 0..2 {
            let b = block[i];
            let still = hi[b][a] - lo[b][a] <= tol;
            moving[i][a] = !still;
            group[i][a] = Some(if still {
                2 * b + a
            } else {
                // Frame gauge: one constant per component over the rows
                // where it moves (see the module docs, step 3).
                2 * nb + a
            });
        }
    }
    Centring { group, moving, nb }
}

pub(super) fn median(mut v: Vec<f64>) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    Some(v[v.len() / 2])
}

/// Lengths of the moves axis `a` made in the log (rows where it moved),
/// µm.
pub(super) fn move_lengths(d: &Data, a: Axis) -> Vec<f64> {
    d.states
        .windows(2)
        .filter(|w| w[1].cmd_um(a) != w[0].cmd_um(a))
        .map(|w| w[1].axis(a).last_move_um)
        .filter(|l| l.is_finite() && *l > 0.0)
        .collect()
}

/// Median length of the moves of axis `a` in the log, µm (0 without moves).
pub(super) fn typical_move_um(d: &Data, a: Axis) -> f64 {
    median(move_lengths(d, a)).unwrap_or(0.0)
}

pub(super) fn span_of(d: &Data, a: Axis) -> f64 {
    let (lo, hi) = d
        .states
        .iter()
        .map(|s| s.cmd_um(a))
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), v| {
            (l.min(v), h.max(v))
        });
    (hi - lo).max(1e-9)
}

/// Distinct commanded positions of axis `a` over the rows where it moves
/// (within 1 nm), sorted.
pub(super) fn distinct_positions(d: &Data, a: Axis) -> Vec<f64> {
    let ai = a.index();
    let mut pos: Vec<f64> = (0..d.n)
        .filter(|&i| d.moving[i][ai])
        .map(|i| d.states[i].cmd_um(a))
        .collect();
    pos.sort_by(f64::total_cmp);
    pos.dedup_by(|p, q| (*p - *q).abs() < 1e-3);
    pos
}

/// The span of sorted positions `pos`, µm (0 without any).
pub(super) fn span_um(pos: &[f64]) -> f64 {
    match (pos.first(), pos.last()) {
        (Some(a), Some(b)) => b - a,
        _ => 0.0,
    }
}

/// Shortest period the log resolves along axis `a`, µm: two positions per
/// period at the [`sampling_spacing_um`] of its distinct positions (`None`
/// with fewer than two positions). A periodic error of a shorter period is
/// aliased: the log cannot identify it.
pub(super) fn shortest_period_um(d: &Data, a: Axis) -> Option<f64> {
    sampling_spacing_um(&distinct_positions(d, a)).map(|s| 2.0 * s)
}

/// The spacing at which sorted positions sample their span (the step of
/// an even grid): one definition with the model table's advice on what a
/// step resolves.
pub(super) use crate::model::sampling::sampling_spacing_um;

/// Fraction of the sampling spacing within which distinct positions count
/// as one target (see [`targets_of`]).
const CLUSTER_FRACTION: f64 = 0.05;

/// Targets up to which nearby positions are merged into one target.
const MAX_CLUSTERED_TARGETS: usize = 12;

/// The targets a test's positions stand for: each a cluster of distinct
/// positions closer than [`CLUSTER_FRACTION`] of the sampling spacing.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct Targets {
    /// Per target: its lowest and highest position, µm.
    pub bounds: Vec<(f64, f64)>,
}

impl Targets {
    /// Index of the target `x` belongs to (within 1 nm of its bounds).
    /// The bounds are in increasing order (built from sorted positions), so
    /// this is a binary search: the readings ask it for every pair of
    /// groups of a dense log.
    pub fn index_of(&self, x: f64) -> Option<usize> {
        // The first target whose upper bound reaches x, as a linear scan
        // for the first match would find it.
        let k = self.bounds.partition_point(|&(_, hi)| hi + 1e-3 < x);
        let &(lo, hi) = self.bounds.get(k)?;
        (x >= lo - 1e-3 && x <= hi + 1e-3).then_some(k)
    }

    /// Centre of target `k`, µm.
    pub fn centre(&self, k: usize) -> f64 {
        let (lo, hi) = self.bounds[k];
        0.5 * (lo + hi)
    }

    /// Centres of all targets, µm.
    pub fn centres(&self) -> Vec<f64> {
        (0..self.bounds.len()).map(|k| self.centre(k)).collect()
    }

    /// Widest target (its highest less its lowest position), µm: 0 when
    /// every target is one position.
    pub fn widest_um(&self) -> f64 {
        self.bounds
            .iter()
            .map(|(lo, hi)| hi - lo)
            .fold(0.0, f64::max)
    }
}

/// Groups sorted distinct positions `pos` into the targets of a test with
/// few targets: positions closer than [`CLUSTER_FRACTION`] of the
/// [`sampling_spacing_um`] are one target, when that leaves at most
/// [`MAX_CLUSTERED_TARGETS`]; otherwise every position is its own target.
///
/// Why: a test program whose backward pass stops 0.2 mm from its forward
/// targets (10 mm apart) measured 5 targets, not 10. Read as 10, a table
/// with a knot at each position takes the reversal as a non-linearity
/// (the forward and the backward positions get knots of their own), and
/// the play, pinned only by the table's end knots, gets a σ of 0.1 µm for
/// a value nothing measured. Read as 5, each target's reversal is the
/// difference of its two approaches, as the test's own report pairs them;
/// the report says how far apart they were.
pub(super) fn targets_of(pos: &[f64]) -> Targets {
    let single = Targets {
        bounds: pos.iter().map(|&p| (p, p)).collect(),
    };
    let Some(spacing) = sampling_spacing_um(pos) else {
        return single;
    };
    let tol = CLUSTER_FRACTION * spacing;
    let mut bounds: Vec<(f64, f64)> = Vec::new();
    for &p in pos {
        match bounds.last_mut() {
            Some(b) if p - b.1 < tol => b.1 = p,
            _ => bounds.push((p, p)),
        }
    }
    if bounds.len() == pos.len() || bounds.len() > MAX_CLUSTERED_TARGETS {
        single
    } else {
        Targets { bounds }
    }
}

#[cfg(test)]
mod tests {
    use super::targets_of;
    use proptest::prelude::*;

    proptest! {
        /// The binary search finds the target a scan for the first match
        /// finds, on clustered and plain positions, at and between them.
        #[test]
        fn index_of_finds_what_a_linear_scan_finds(
            steps in proptest::collection::vec(
                prop_oneof![0.0005f64..0.003, 0.1f64..2.0, 5.0f64..50.0], 1..40),
            probes in proptest::collection::vec(-10.0f64..500.0, 1..30),
        ) {
            let mut pos = vec![0.0];
            for s in steps {
                let p = pos[pos.len() - 1] + s;
                pos.push(p);
            }
            pos.dedup_by(|p, q| (*p - *q).abs() < 1e-3);
            let t = targets_of(&pos);
            let linear = |x: f64| {
                t.bounds
                    .iter()
                    .position(|&(lo, hi)| x >= lo - 1e-3 && x <= hi + 1e-3)
            };
            for x in pos.iter().copied().chain(probes) {
                prop_assert_eq!(t.index_of(x), linear(x), "x = {}", x);
            }
        }
    }
}
