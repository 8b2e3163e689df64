//! Step 4's refinement of a periodic candidate: the period searched on a
//! fine grid and then by golden section, over the whole data, over one
//! fold's training rows, or localized (place and width of an error that
//! lives in part of the travel). Why a file of its own: it is the one
//! nonlinear search the families share, with its own guards against
//! aliases; [`super::search`] says which families use it.

use super::data::{median, Data};
use super::search::{columns, Spec};
use crate::model::StageModel;

/// A periodic spec's period refined against the joint fit of `base` and the
/// spec's own columns on every row (variable projection: the period whose
/// least-squares fit, all linear parameters free, leaves the smallest
/// residual). Other specs come back unchanged.
///
/// Why: the search reads its period off the base fit's residual, and base
/// parameters that share variance with the periodic error (a thermal
/// coefficient while the room temperature wanders on the same time scale, a
/// cyclic term near the same period) have already taken part of it, which
/// biases the period. A period wrong by 2 % puts the extrapolated phase a
/// quarter-cycle off a few periods after the log ends; the joint fit's
/// minimum is where the term predicts beyond the log.
pub(super) fn refine_period(spec: Spec, d: &Data, base: &[Vec<f64>], model: &StageModel) -> Spec {
    let (p0, span) = match &spec {
        Spec::PosPeriodic {
            axis, period_um, ..
        } => (*period_um, super::data::span_of(d, *axis)),
        Spec::TimePeriodic { period_s, .. } => {
            let (lo, hi) = d
                .states
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), s| {
                    (a.min(s.time_s), b.max(s.time_s))
                });
            (*period_s, hi - lo)
        }
        _ => return spec,
    };
    if !(p0.is_finite() && p0 > 0.0 && span.is_finite() && span > 0.0) {
        return spec;
    }
    let with = |period: f64| -> Spec {
        match &spec {
            Spec::PosPeriodic { axis, comp, .. } => Spec::PosPeriodic {
                axis: *axis,
                comp: *comp,
                period_um: period,
            },
            Spec::TimePeriodic { comp, .. } => Spec::TimePeriodic {
                comp: *comp,
                period_s: period,
            },
            other => other.clone(),
        }
    };
    let all = vec![true; d.n];
    let sse = |f: f64| -> f64 {
        let mut cols = base.to_vec();
        cols.extend(columns(&with(1.0 / f), d, model));
        let fb = super::fit::fold_base(d, &cols, all.clone());
        (0..d.n)
            .map(|i| {
                (0..2)
                    .filter(|&c| d.measured[c])
                    .map(|c| fb.resid[2 * i + c].powi(2))
                    .sum::<f64>()
            })
            .sum()
    };
    let f0 = 1.0 / p0;
    let f = if matches!(spec, Spec::TimePeriodic { .. }) {
        // A time search reads its peak off the base residual, where the
        // base's own terms (a scale, a play, the constant of a held axis
        // per pass) have taken part of the oscillation, differently at
        // each frequency: on the rig's 301 s oscillation of y the peak
        // came out at 408 s, 1.3 resolutions away. The joint fit is
        // scanned over the alias window as on a fold.
        let half = ALIAS_WINDOW / span;
        let (flo, fhi) = ((f0 - half).max(0.5 * f0), (f0 + half).min(2.0 * f0));
        grid_then_golden(flo, fhi, 1.0 / (ALIAS_GRID * span), &sse).0
    } else {
        // One periodogram resolution (1 / span) either side of the found
        // frequency: the search's own peak lies within it.
        let half = 1.0 / span;
        golden_max((f0 - half).max(0.5 * f0), f0 + half, 40, |f| -sse(f)).0
    };
    // Keep the search's period unless the refined one fits better.
    if sse(f) < sse(f0) {
        with(1.0 / f)
    } else {
        spec
    }
}

/// A time-periodic spec's period refined on one fold's training rows
/// against the joint fit of the fold's base (`fb`, fitted on those rows)
/// and the spec's own columns: the period whose fit, every linear
/// parameter free, leaves the smallest training residual. Other specs
/// come back unchanged.
///
/// Why: with whole-cycle folds, the training rows of a middle fold are
/// the cycles before and after a gap (cycles 0 and 2 around cycle 1). A
/// sinusoid fitted on two blocks apart is ambiguous in the number of
/// periods that pass during the gap: its training periodogram has peaks
/// of nearly equal height at the true frequency and at aliases
/// `±k / (gap between the blocks' centres)`. The search reads the peak off
/// the base residual, where base terms fitted without the periodic error
/// (thermal coefficients while the room temperature wanders on the same
/// time scale) have taken part of it differently in each block, which is
/// enough to tip the choice to an alias; the alias predicts the held-out
/// gap a quarter to half a period off. The joint fit undoes that bias as
/// [`refine_period`] does on all rows. The window covers the nearest
/// aliases (`±ALIAS_WINDOW / span`, a grid of `span / 8`-resolution, then
/// golden section around its best point), and only training rows are
/// used, so the held-out fold still judges a period it did not choose.
pub(super) fn refine_period_on_fold(
    spec: Spec,
    d: &Data,
    base: &[Vec<f64>],
    fb: &super::fit::FoldBase,
    model: &StageModel,
) -> Spec {
    let Spec::TimePeriodic { comp, period_s } = spec else {
        return spec;
    };
    let (lo, hi) =
        (0..d.n)
            .filter(|&i| fb.train[i])
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), i| {
                let t = d.states[i].time_s;
                (a.min(t), b.max(t))
            });
    let span = hi - lo;
    if !(period_s.is_finite() && period_s > 0.0 && span.is_finite() && span > 0.0) {
        return spec;
    }
    let with = |f: f64| Spec::TimePeriodic {
        comp,
        period_s: 1.0 / f,
    };
    let sse = |f: f64| -> f64 {
        let (resid, _) = super::fit::fit_with(d, base, fb, &columns(&with(f), d, model));
        (0..d.n)
            .filter(|&i| fb.train[i])
            .map(|i| resid[2 * i + comp.index()].powi(2))
            .sum()
    };
    let f0 = 1.0 / period_s;
    let half = ALIAS_WINDOW / span;
    let (flo, fhi) = ((f0 - half).max(0.5 * f0), (f0 + half).min(2.0 * f0));
    let s0 = sse(f0);
    let (f, s) = grid_then_golden(flo, fhi, 1.0 / (ALIAS_GRID * span), &sse);
    if s < s0 {
        with(f)
    } else {
        spec
    }
}

/// The frequency in `[flo, fhi]` with the smallest `sse`, and that sse: a
/// grid of `step` (an alias peak is a few steps wide), then golden section
/// within one grid step of the grid's best point.
pub(super) fn grid_then_golden(
    flo: f64,
    fhi: f64,
    step: f64,
    sse: &dyn Fn(f64) -> f64,
) -> (f64, f64) {
    let k = ((fhi - flo) / step).ceil().max(1.0) as usize;
    let (mut fb_best, mut s_best) = (flo, f64::INFINITY);
    for j in 0..=k {
        let f = flo + (fhi - flo) * j as f64 / k as f64;
        let v = sse(f);
        if v < s_best {
            (fb_best, s_best) = (f, v);
        }
    }
    let g = (fhi - flo) / k as f64;
    let (f, neg) = golden_max(fb_best - g, fb_best + g, 20, |f| -sse(f));
    if -neg < s_best {
        (f, -neg)
    } else {
        (fb_best, s_best)
    }
}

/// Half-width of [`refine_period_on_fold`]'s window in periodogram
/// resolutions (`1 / span` of the training rows): with three cycles and
/// the middle one held out, the blocks' centres are ⅔ of the span apart,
/// so the nearest aliases lie `1.5 / span` from the true frequency.
pub(super) const ALIAS_WINDOW: f64 = 2.0;

/// Grid points per periodogram resolution in [`refine_period_on_fold`]
/// (an alias peak is about `1 / span` wide: 8 points resolve it).
pub(super) const ALIAS_GRID: f64 = 8.0;

/// A localized spec's place and width refined against the joint fit of
/// `base` and the spec's own (centred) column on every row: the place and
/// width whose least-squares fit, every linear parameter free, leaves the
/// smallest residual (a pattern search from the search's values). Other
/// specs come back unchanged.
///
/// Why: the search scores an uncentred Gaussian against the base fit's
/// residual. Two things bias it that only the joint fit undoes: base
/// parameters that share variance with a broad bump (a guide waviness whose
/// period is near the scan's span, freed by the base) have taken part of it,
/// so the bump left in the residual is smaller and flatter; and a bump of
/// one component along the other axis is seen only on lines where that
/// component's axis stands still, whose block constant is profiled out, so
/// the residual holds the bump minus its mean over the line, which looks
/// narrower. The column the extended model is fitted with is centred the
/// same way, so its joint fit is where the term predicts.
pub(super) fn refine_localized(
    spec: Spec,
    d: &Data,
    base: &[Vec<f64>],
    model: &StageModel,
) -> Spec {
    let Spec::Localized {
        axis,
        comp,
        position_um,
        width_um,
    } = spec
    else {
        return spec;
    };
    let pos = super::data::distinct_positions(d, axis);
    let (Some(&lo), Some(&hi)) = (pos.first(), pos.last()) else {
        return spec;
    };
    let spacing = median(pos.windows(2).map(|w| w[1] - w[0]).collect()).unwrap_or(0.0);
    if !(position_um.is_finite() && width_um.is_finite() && width_um > 0.0 && spacing > 0.0) {
        return spec;
    }
    let with = |p: f64, w: f64| Spec::Localized {
        axis,
        comp,
        position_um: p,
        width_um: w,
    };
    let all = vec![true; d.n];
    let sse = |p: f64, w: f64| -> f64 {
        let mut cols = base.to_vec();
        cols.extend(columns(&with(p, w), d, model));
        let fb = super::fit::fold_base(d, &cols, all.clone());
        (0..d.n)
            .map(|i| {
                (0..2)
                    .filter(|&c| d.measured[c])
                    .map(|c| fb.resid[2 * i + c].powi(2))
                    .sum::<f64>()
            })
            .sum()
    };
    let (mut p, mut w) = (position_um, width_um);
    let mut best = sse(p, w);
    let start = best;
    let (mut dp, mut dw) = (w / 4.0, 0.25);
    let w_max = (hi - lo).max(spacing);
    for _ in 0..REFINE_STEPS {
        let mut improved = false;
        for (np, nw) in [
            (p + dp, w),
            (p - dp, w),
            (p, w * (1.0 + dw)),
            (p, w / (1.0 + dw)),
        ] {
            // Inside the measured travel: a place outside it is not
            // measured (its tail alone is seen, and its amplitude grows
            // without bound as it leaves).
            if nw < spacing || nw > w_max || np < lo || np > hi {
                continue;
            }
            let v = sse(np, nw);
            if v < best {
                (best, p, w) = (v, np, nw);
                improved = true;
            }
        }
        if !improved {
            dp /= 2.0;
            dw /= 2.0;
            if dp < 0.01 * spacing && dw < 1e-3 {
                break;
            }
        }
    }
    if best < start {
        with(p, w)
    } else {
        spec
    }
}

/// Most probes of [`refine_localized`]'s pattern search (four per step).
pub(super) const REFINE_STEPS: usize = 40;

/// Golden-section search for the largest `f` on `[lo, hi]` (unimodal there):
/// `(x, f(x))` of the better of the last two probes.
pub(super) fn golden_max(
    lo: f64,
    hi: f64,
    iterations: usize,
    mut f: impl FnMut(f64) -> f64,
) -> (f64, f64) {
    let g = 0.5 * (5f64.sqrt() - 1.0);
    let (mut l, mut h) = (lo, hi);
    let mut x1 = h - g * (h - l);
    let mut x2 = l + g * (h - l);
    let (mut f1, mut f2) = (f(x1), f(x2));
    for _ in 0..iterations {
        if f1 >= f2 {
            h = x2;
            x2 = x1;
            f2 = f1;
            x1 = h - g * (h - l);
            f1 = f(x1);
        } else {
            l = x1;
            x1 = x2;
            f1 = f2;
            x2 = l + g * (h - l);
            f2 = f(x2);
        }
    }
    if f1 >= f2 {
        (x1, f1)
    } else {
        (x2, f2)
    }
}
