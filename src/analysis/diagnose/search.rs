//! Step 4 of the analysis: the candidate families (what a discrepancy may
//! depend on), the search that fixes a family's nonlinear hyper-parameters
//! (period, place and width, step length) on the training rows, and a
//! candidate's design columns.
//!
//! Why a file of its own: the families are where a new kind of finding is
//! added; the held-out judging ([`super::fit`]) is the same for all.

use super::data::{median, move_lengths, Data};
use super::family::Family;
use super::refine::golden_max;
use crate::analysis::periodogram::strongest_peak;
use crate::model::terms::discovered::{step_size_shape, table_basis};
use crate::model::{Axis, Direction, MotionState, StageModel, Term, DEFAULT_TEMP_C};

/// A concrete candidate term (its nonlinear hyper-parameters chosen).
#[derive(Debug, Clone, PartialEq)]
pub(super) enum Spec {
    PosPeriodic {
        axis: Axis,
        comp: Axis,
        period_um: f64,
    },
    Localized {
        axis: Axis,
        comp: Axis,
        position_um: f64,
        width_um: f64,
    },
    Slope {
        axis: Axis,
        comp: Axis,
    },
    Drift {
        comp: Axis,
        quadratic: bool,
    },
    TimePeriodic {
        comp: Axis,
        period_s: f64,
    },
    Temperature {
        comp: Axis,
    },
    Reversal {
        axis: Axis,
    },
    StepSize {
        axis: Axis,
        length_um: f64,
    },
    /// Linear in extra column `var` (index into `Data::extra`); no model
    /// term can carry it.
    Other {
        comp: Axis,
        var: usize,
    },
    /// A table of `axis`'s own error at `knots`, linear between them: lost
    /// motion (`lost_motion`, a reversal table) or a non-linearity.
    Table {
        axis: Axis,
        knots: Vec<f64>,
        lost_motion: bool,
    },
    /// Both tables of `axis` at once (a bidirectional table, as ISO 230-2
    /// compensation tables are): judged jointly, then carried as its two
    /// [`Spec::Table`]s ([`Spec::split`]).
    Tables {
        axis: Axis,
        knots: Vec<f64>,
    },
}

impl Spec {
    /// The specs that become model terms: [`Spec::Tables`] is its two
    /// tables, every other spec itself.
    pub(super) fn split(self) -> Vec<Spec> {
        match self {
            Spec::Tables { axis, knots } => vec![
                Spec::Table {
                    axis,
                    knots: knots.clone(),
                    lost_motion: false,
                },
                Spec::Table {
                    axis,
                    knots,
                    lost_motion: true,
                },
            ],
            other => vec![other],
        }
    }
}

pub(super) fn families(d: &Data) -> Vec<Family> {
    let mut out = Vec::new();
    // Nothing is searched on a component the log did not measure.
    let measured = |a: Axis| d.measured[a.index()];
    for comp in Axis::ALL.into_iter().filter(|&c| measured(c)) {
        for axis in Axis::ALL {
            out.push(Family::PosPeriodic { axis, comp });
            out.push(Family::Localized { axis, comp });
            out.push(Family::Slope { axis, comp });
        }
        // Time families only when time is a variable of its own (see
        // `data::Data::time_with`).
        if d.time_with.is_none() && d.time_unusable.is_none() {
            out.push(Family::Drift {
                comp,
                quadratic: false,
            });
            out.push(Family::Drift {
                comp,
                quadratic: true,
            });
            out.push(Family::TimePeriodic { comp });
        }
        if d.temp_varies {
            out.push(Family::Temperature { comp });
        }
        for var in 0..d.extra.len() {
            out.push(Family::Other { comp, var });
        }
    }
    for axis in Axis::ALL.into_iter().filter(|&a| measured(a)) {
        out.push(Family::Reversal { axis });
        out.push(Family::StepSize { axis });
    }
    out
}

/// Range of the step-size length λ worth searching for `axis`, µm, or
/// `None` when the log cannot tell a step-size effect from extra play: too
/// few moves, or (nearly) all of the same length (a log of constant-step
/// scans), where `1 − exp(−L/λ)` is one number times the direction.
pub(super) fn step_length_range(d: &Data, axis: Axis) -> Option<(f64, f64)> {
    let mut lens = move_lengths(d, axis);
    if lens.len() < 16 {
        return None;
    }
    lens.sort_by(f64::total_cmp);
    let med = lens[lens.len() / 2];
    let distinct = lens
        .iter()
        .filter(|&&l| l >= 3.0 * med || l <= med / 3.0)
        .count();
    if distinct < STEP_MIN_DISTINCT.max(lens.len() / 50) {
        return None;
    }
    let lo = (0.5 * lens[lens.len() / 20]).max(1e-3);
    let hi = (2.0 * lens[lens.len() - 1]).max(4.0 * lo);
    Some((lo, hi))
}

/// Moves whose length differs at least 3× from the median a log needs
/// before the step-size family is searched (and at least 2 % of its
/// moves: the few repositioning moves between constant-step scans do not
/// make a step-size effect identifiable).
const STEP_MIN_DISTINCT: usize = 8;

/// The step-size length λ whose column best explains `resid` on the
/// training rows (largest squared projection), log grid then golden
/// section.
fn step_size_search(d: &Data, axis: Axis, resid: &[f64], train: &[bool]) -> Option<Spec> {
    let (lo, hi) = step_length_range(d, axis)?;
    let c = axis.index();
    // λ is scored on the part of the column a constant play (`±B/2` by
    // direction, which the base fit frees with the model's backlash) does
    // not explain: otherwise the play absorbs the long moves' plateau and
    // the score drifts to a longer λ.
    let mut play = vec![0.0; 2 * d.n];
    for (i, s) in d.states.iter().enumerate() {
        play[2 * i + c] = s.axes[c].dir.sign();
    }
    d.center(&mut play);
    let (mut pp, mut pr) = (0.0, 0.0);
    for i in 0..d.n {
        if train[i] {
            pp += play[2 * i + c] * play[2 * i + c];
            pr += play[2 * i + c] * resid[2 * i + c];
        }
    }
    let mut col = vec![0.0; 2 * d.n];
    let mut score = |log_l: f64| -> f64 {
        let l = log_l.exp();
        col.iter_mut().for_each(|v| *v = 0.0);
        for (i, s) in d.states.iter().enumerate() {
            let m = s.axes[c];
            col[2 * i + c] = step_size_shape(m.dir.sign(), m.last_move_um, l);
        }
        d.center(&mut col);
        let (mut br, mut bb, mut cp) = (0.0, 0.0, 0.0);
        for i in 0..d.n {
            if train[i] {
                br += col[2 * i + c] * resid[2 * i + c];
                bb += col[2 * i + c] * col[2 * i + c];
                cp += col[2 * i + c] * play[2 * i + c];
            }
        }
        if pp > 0.0 {
            br -= cp / pp * pr;
            bb -= cp * cp / pp;
        }
        if bb > 1e-12 * (1.0 + pp) {
            br * br / bb
        } else {
            0.0
        }
    };
    let (a, b) = (lo.ln(), hi.ln());
    let n = 40;
    let grid: Vec<(f64, f64)> = (0..=n)
        .map(|k| {
            let x = a + (b - a) * k as f64 / n as f64;
            (x, score(x))
        })
        .collect();
    let (kbest, _) = grid
        .iter()
        .enumerate()
        .max_by(|p, q| p.1 .1.total_cmp(&q.1 .1))?;
    if grid[kbest].1 <= 0.0 {
        return None;
    }
    // Golden section between the best point's neighbours.
    let (x, fx) = golden_max(
        grid[kbest.saturating_sub(1)].0,
        grid[(kbest + 1).min(n)].0,
        25,
        score,
    );
    let best = if fx >= grid[kbest].1 {
        x
    } else {
        grid[kbest].0
    };
    Some(Spec::StepSize {
        axis,
        length_um: best.exp(),
    })
}

/// Knots of a table along `axis`: its targets (distinct positions, those
/// of one target merged, `data::targets_of`) when there are at
/// most [`MAX_TABLE_TARGETS`] (a test with few targets: one value per
/// target, nothing claimed between them), else [`DENSE_TABLE_KNOTS`]
/// evenly spaced over its span (a dense scan: a smooth curve, the finer
/// structure is the periodic and localized families' business); `None`
/// with fewer than three positions (two knots are a constant and a slope,
/// which the base already has).
pub(super) fn table_knots(d: &Data, axis: Axis) -> Option<Vec<f64>> {
    let pos = super::data::distinct_positions(d, axis);
    // A target whose approaches stop at slightly different positions is
    // one knot (see `data::targets_of`).
    let targets = super::data::targets_of(&pos).centres();
    if targets.len() < 3 {
        return None;
    }
    if targets.len() <= MAX_TABLE_TARGETS {
        return Some(targets);
    }
    let (lo, hi) = (pos[0], pos[pos.len() - 1]);
    let k = DENSE_TABLE_KNOTS - 1;
    Some(
        (0..=k)
            .map(|j| lo + (hi - lo) * j as f64 / k as f64)
            .collect(),
    )
}

/// Distinct positions up to which a table has one knot per target.
pub(super) const MAX_TABLE_TARGETS: usize = 12;

/// Knots of a table along a densely sampled axis.
pub(super) const DENSE_TABLE_KNOTS: usize = 6;

/// Indices of a table's knots the fit frees. A non-linearity table is zero
/// at both ends: a constant and a slope are the origin and the scale, which
/// the base already carries. A lost-motion table is zero at its first knot
/// when the model has a play for the axis (the play carries the constant
/// lost motion, the table how it changes along the travel), else free at
/// every knot.
pub(super) fn table_free_knots(
    k: usize,
    lost_motion: bool,
    model: &StageModel,
    axis: Axis,
) -> std::ops::Range<usize> {
    match (lost_motion, backlash_term_of(model, axis).is_some()) {
        (false, _) => 1..k.saturating_sub(1).max(1),
        (true, true) => 1..k,
        (true, false) => 0..k,
    }
}

/// Distinct positions an axis needs before its periodic and localized
/// families are searched (fewer cannot place a period or a bump).
pub(super) const MIN_PROFILE_POSITIONS: usize = 16;

/// Position samples of axis `a` (rows where it moves, training rows only),
/// averaged per distinct position: position-dependent structure is common
/// to all passes, and averaging makes the periodogram 5–10× cheaper.
fn position_profile(
    d: &Data,
    a: Axis,
    comp: Axis,
    resid: &[f64],
    train: &[bool],
) -> (Vec<f64>, Vec<f64>) {
    let mut pts: Vec<(f64, f64)> = (0..d.n)
        .filter(|&i| train[i] && !d.excluded[i] && d.moving[i][a.index()])
        .map(|i| (d.states[i].cmd_um(a), resid[2 * i + comp.index()]))
        .collect();
    pts.sort_by(|p, q| p.0.total_cmp(&q.0));
    let mut xs = Vec::new();
    let mut ys = Vec::new();
    let mut i = 0;
    while i < pts.len() {
        let mut j = i;
        let mut s = 0.0;
        while j < pts.len() && (pts[j].0 - pts[i].0).abs() < 1e-3 {
            s += pts[j].1;
            j += 1;
        }
        xs.push(pts[i].0);
        ys.push(s / (j - i) as f64);
        i = j;
    }
    (xs, ys)
}

pub(super) fn search(f: Family, d: &Data, resid: &[f64], train: &[bool]) -> Option<Spec> {
    match f {
        Family::PosPeriodic { axis, comp } => {
            let (x, y) = position_profile(d, axis, comp, resid, train);
            if x.len() < MIN_PROFILE_POSITIONS {
                return None;
            }
            let span = x[x.len() - 1] - x[0];
            let spacing = median(x.windows(2).map(|w| w[1] - w[0]).collect())?;
            let p_min = (5.0 * spacing).max(1e-3);
            let p_max = span / 2.0;
            if p_max <= p_min {
                return None;
            }
            let (fr, _) = strongest_peak(&x, &y, 1.0 / p_max, 1.0 / p_min, 3.0)?;
            Some(Spec::PosPeriodic {
                axis,
                comp,
                period_um: 1.0 / fr,
            })
        }
        Family::Localized { axis, comp } => {
            let (x, y) = position_profile(d, axis, comp, resid, train);
            if x.len() < MIN_PROFILE_POSITIONS {
                return None;
            }
            let span = x[x.len() - 1] - x[0];
            let spacing = median(x.windows(2).map(|w| w[1] - w[0]).collect())?;
            let score = |p: f64, w: f64| -> f64 {
                let lo = x.partition_point(|&v| v < p - 5.0 * w);
                let hi = x.partition_point(|&v| v <= p + 5.0 * w);
                let (mut gr, mut gg) = (0.0, 0.0);
                for k in lo..hi {
                    let z = (x[k] - p) / w;
                    let g = (-0.5 * z * z).exp();
                    gr += g * y[k];
                    gg += g * g;
                }
                if gg > 0.0 {
                    gr * gr / gg
                } else {
                    0.0
                }
            };
            let mut best = (0.0, 0.0, 0.0);
            let mut w = 1.5 * spacing;
            while w <= span / 8.0 {
                let mut p = x[0];
                while p <= x[x.len() - 1] {
                    let s = score(p, w);
                    if s > best.0 {
                        best = (s, p, w);
                    }
                    p += w / 3.0;
                }
                w *= 1.4;
            }
            if best.0 <= 0.0 {
                return None;
            }
            // Local pattern search around the grid optimum.
            let (mut s, mut p, mut w) = best;
            let (mut dp, mut dw) = (w / 6.0, 0.2);
            for _ in 0..40 {
                let mut improved = false;
                for (np, nw) in [
                    (p + dp, w),
                    (p - dp, w),
                    (p, w * (1.0 + dw)),
                    (p, w / (1.0 + dw)),
                ] {
                    // A feature is located inside the measured travel, and
                    // no wider than an eighth of it (wider is a slope or
                    // a bow, which other families carry).
                    if nw < spacing || nw > span / 8.0 || np < x[0] || np > x[x.len() - 1] {
                        continue;
                    }
                    let ns = score(np, nw);
                    if ns > s {
                        (s, p, w) = (ns, np, nw);
                        improved = true;
                    }
                }
                if !improved {
                    dp /= 2.0;
                    dw /= 2.0;
                }
            }
            Some(Spec::Localized {
                axis,
                comp,
                position_um: p,
                width_um: w,
            })
        }
        Family::Slope { axis, comp } => Some(Spec::Slope { axis, comp }),
        Family::Drift { comp, quadratic } => Some(Spec::Drift { comp, quadratic }),
        Family::Temperature { comp } => Some(Spec::Temperature { comp }),
        Family::Reversal { axis } => {
            let has_both = (0..d.n)
                .any(|i| d.states[i].axes[axis.index()].dir == Direction::Forward)
                && (0..d.n).any(|i| d.states[i].axes[axis.index()].dir == Direction::Backward);
            has_both.then_some(Spec::Reversal { axis })
        }
        Family::StepSize { axis } => step_size_search(d, axis, resid, train),
        Family::Other { comp, var } => Some(Spec::Other { comp, var }),
        Family::Table { axis, lost_motion } => Some(Spec::Table {
            axis,
            knots: table_knots(d, axis)?,
            lost_motion,
        }),
        Family::Tables { axis } => Some(Spec::Tables {
            axis,
            knots: table_knots(d, axis)?,
        }),
        Family::TimePeriodic { comp } => {
            let idx: Vec<usize> = (0..d.n).filter(|&i| train[i] && !d.excluded[i]).collect();
            let x: Vec<f64> = idx.iter().map(|&i| d.states[i].time_s).collect();
            let y: Vec<f64> = idx.iter().map(|&i| resid[2 * i + comp.index()]).collect();
            if x.len() < 16 {
                return None;
            }
            let span = x.iter().cloned().fold(f64::NEG_INFINITY, f64::max)
                - x.iter().cloned().fold(f64::INFINITY, f64::min);
            let dt = median(x.windows(2).map(|w| (w[1] - w[0]).abs()).collect())?;
            let p_min = (20.0 * dt).max(60.0);
            let p_max = span / 2.0;
            if p_max <= p_min {
                return None;
            }
            let (fr, _) = strongest_peak(&x, &y, 1.0 / p_max, 1.0 / p_min, 3.0)?;
            Some(Spec::TimePeriodic {
                comp,
                period_s: 1.0 / fr,
            })
        }
    }
}

pub(super) fn backlash_term_of(model: &StageModel, axis: Axis) -> Option<&dyn Term> {
    model.terms().iter().map(|t| &**t).find(|t| {
        t.kind() == crate::model::terms::backlash::KIND
            && t.params().len() == 1
            && t.to_config()
                .ok()
                .and_then(|c| c.get("axis").and_then(|v| v.as_str().map(String::from)))
                .as_deref()
                == Some(axis.as_str())
    })
}

/// The candidate's design columns over all rows (index `2i + c`), centred.
pub(super) fn columns(spec: &Spec, d: &Data, model: &StageModel) -> Vec<Vec<f64>> {
    let n = d.n;
    let mut cols: Vec<Vec<f64>> = Vec::new();
    let mut one = |c: Axis, f: &dyn Fn(&MotionState) -> f64| {
        let mut v = vec![0.0; 2 * n];
        for i in 0..n {
            v[2 * i + c.index()] = f(&d.states[i]);
        }
        cols.push(v);
    };
    let tau = std::f64::consts::TAU;
    match *spec {
        Spec::PosPeriodic {
            axis,
            comp,
            period_um,
        } => {
            one(comp, &|s| {
                (tau * (s.cmd_um(axis) / period_um).fract()).sin()
            });
            one(comp, &|s| {
                (tau * (s.cmd_um(axis) / period_um).fract()).cos()
            });
        }
        Spec::Localized {
            axis,
            comp,
            position_um,
            width_um,
        } => one(comp, &|s| {
            let z = (s.cmd_um(axis) - position_um) / width_um;
            (-0.5 * z * z).exp()
        }),
        Spec::Slope { axis, comp } => one(comp, &|s| 1e-6 * s.cmd_um(axis)),
        Spec::Drift { comp, quadratic } => {
            let t0 = d.t0;
            one(comp, &|s| (s.time_s - t0) / 3600.0);
            if quadratic {
                one(comp, &|s| ((s.time_s - t0) / 3600.0).powi(2));
            }
        }
        Spec::TimePeriodic { comp, period_s } => {
            one(comp, &|s| (tau * (s.time_s / period_s).fract()).sin());
            one(comp, &|s| (tau * (s.time_s / period_s).fract()).cos());
        }
        Spec::Temperature { comp } => one(comp, &|s| s.temp_c - DEFAULT_TEMP_C),
        Spec::Reversal { axis } => match backlash_term_of(model, axis) {
            Some(t) => {
                let mut v = vec![0.0; 2 * n];
                for i in 0..n {
                    let j = t.jacobian(&d.states[i]);
                    v[2 * i] = j[0][0];
                    v[2 * i + 1] = j[0][1];
                }
                cols.push(v);
            }
            None => one(axis, &|s| -0.5 * s.axis(axis).dir.sign()),
        },
        Spec::StepSize { axis, length_um } => one(axis, &|s| {
            let m = s.axis(axis);
            step_size_shape(m.dir.sign(), m.last_move_um, length_um)
        }),
        Spec::Tables { .. } => {
            return spec
                .clone()
                .split()
                .iter()
                .flat_map(|s| columns(s, d, model))
                .collect()
        }
        Spec::Table {
            axis,
            ref knots,
            lost_motion,
        } => {
            for k in table_free_knots(knots.len(), lost_motion, model, axis) {
                one(axis, &|s| {
                    let f = if lost_motion {
                        -0.5 * s.axis(axis).dir.sign()
                    } else {
                        1.0
                    };
                    f * table_basis(knots, s.cmd_um(axis))[k]
                });
            }
        }
        Spec::Other { comp, var } => {
            let mut v = vec![0.0; 2 * n];
            if let Some(x) = d.extra.get(var) {
                for (i, val) in x.values.iter().enumerate().take(n) {
                    v[2 * i + comp.index()] = *val - x.mean;
                }
            }
            cols.push(v);
        }
    }
    for c in &mut cols {
        d.center(c);
    }
    cols
}

/// Whether `kind` is among the base fit's kinds: named in `kinds`, or
/// `kinds` holds [`ALL_KINDS`].
pub(super) fn base_kind_selected(kinds: &[String], kind: &str) -> bool {
    kinds.iter().any(|k| k == kind || k == ALL_KINDS)
}

/// Whether `t` is a zero-amplitude periodic term of a discovered kind
/// (`position_periodic`, `time_periodic`): its period is a placeholder of
/// the model file (the documented default's 1600 µm and 1800 s), not a
/// claim about the stage, so the base fit does not fit an amplitude at a
/// period nobody measured (it would take part of a real periodic error at
/// a nearby period and extrapolate it in time). A periodic error is the
/// search's job; once found, its term has an amplitude and is freed. The
/// same holds for a zero `position_table`: its knots are the file's, not
/// the stage's targets.
fn placeholder(t: &dyn Term) -> bool {
    use crate::model::terms::discovered::{
        POSITION_PERIODIC_KIND, POSITION_TABLE_KIND, TIME_PERIODIC_KIND,
    };
    (t.kind() == POSITION_PERIODIC_KIND
        || t.kind() == TIME_PERIODIC_KIND
        || t.kind() == POSITION_TABLE_KIND)
        && t.params().iter().all(|p| p.value == 0.0)
}

/// The `base_free_kinds` entry that selects every kind of the model.
pub const ALL_KINDS: &str = "*";

/// Whether the base fit can free a term's parameters by one linear solve:
/// linear terms; backlash, whose play enters the contribution as `±B/2`
/// on a steady approach (its Jacobian, taken at the model's play, is that
/// sign; the solve is the first Gauss–Newton step); and angular error
/// motions, which are linear in their angles at a given Abbe arm (the arm
/// itself is geometry, see [`base_param_fittable`]); never a position map.
/// Other nonlinear terms
/// (a localized feature's place and width, a step-size length) stay at the
/// model's values.
pub(super) fn base_fittable(t: &dyn Term) -> bool {
    // A position map has a parameter per node: freed in the base it would
    // take every target's error as its own. On a grid log `diagnose`
    // fits a map itself, judged on held-out cells (`map_term`).
    if t.kind() == crate::model::terms::position_map::KIND {
        return false;
    }
    t.is_linear()
        || t.kind() == crate::model::terms::backlash::KIND
        || t.kind() == crate::model::terms::angular::KIND
}

/// Whether parameter `param` of a base-fittable term is freed: not an
/// angular term's Abbe arm (`arm_*`), which multiplies the angles (a
/// fit of both is bilinear, and the log sees only their product).
pub(super) fn base_param_fittable(kind: &str, param: &str) -> bool {
    !(kind == crate::model::terms::angular::KIND && param.starts_with("arm_"))
}

/// Columns of the base fit: the jacobian of the free parameters (linear
/// terms, so exact and independent of the values).
pub(super) fn base_columns(
    d: &Data,
    model: &StageModel,
    kinds: &[String],
) -> (Vec<String>, Vec<Vec<f64>>) {
    let mut names = Vec::new();
    let mut cols = Vec::new();
    for t in model.terms() {
        if !base_kind_selected(kinds, t.kind()) || !base_fittable(&**t) || placeholder(&**t) {
            continue;
        }
        let p = t.params();
        let mut tc = vec![vec![0.0; 2 * d.n]; p.len()];
        for i in 0..d.n {
            for (k, j) in t.jacobian(&d.states[i]).iter().enumerate().take(p.len()) {
                tc[k][2 * i] = j[0];
                tc[k][2 * i + 1] = j[1];
            }
        }
        for (k, mut c) in tc.into_iter().enumerate() {
            if !base_param_fittable(t.kind(), &p[k].name) {
                continue;
            }
            // A drift's curvature at zero is no claim either: fitted in the
            // base it extrapolates quadratically beyond the log (a
            // compensation an hour later is off by µm); a quadratic drift
            // must earn its place as a finding (held out against linear).
            if p[k].name == "curvature_um_per_h2" && p[k].value == 0.0 {
                continue;
            }
            // Centred first: a column that is constant within every
            // centring group, or lives only on an unmeasured component,
            // carries nothing the log can identify.
            d.center(&mut c);
            if c.iter().all(|v| v.abs() < 1e-12) {
                continue;
            }
            names.push(format!("{}.{}", t.name(), p[k].name));
            cols.push(c);
        }
    }
    (names, cols)
}
