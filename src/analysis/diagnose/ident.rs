//! Which of the model's parameters a log can identify, and which
//! combinations it cannot separate.
//!
//! Why a file of its own: the base fit frees every parameter of the model,
//! but a log of a given geometry sees some of them only in fixed
//! combinations. On an XY scan, the slope of a carriage's yaw through its
//! Abbe arm moves the tool point exactly as the axis's lead error does; a
//! pitch and a yaw of the same carriage with the same waviness period move
//! it along the same component; a platform's thermal offset and the
//! microscope's thermal drift are both `k·ΔT` on the same component.
//! Fitting all of them gives an arbitrary split (or, with truncation, a
//! minimum-norm split no physical stage has). Instead, the parameters are
//! taken in a physical order of priority (squareness, scale, play, cyclic
//! tables, thermal and drift terms, observation terms, angular terms, the
//! rest) and each is kept only when its (centred) design column is not a
//! combination of the columns kept before it: the rank of the Jacobian,
//! decided column by column (Gram–Schmidt with a relative threshold). A
//! dropped parameter stays at the model's value, and the combination it is
//! not separable from is named, with its coefficients, in the report.

use nalgebra::{DMatrix, DVector};
use serde::Serialize;

use crate::model::StageModel;

use super::data::Data;

/// Relative norm of a column's part outside the span of the columns kept
/// before it below which the log cannot separate the parameter from them
/// (`sin` of the angle to that span; 1e-3 means the column is 99.99995 %
/// a combination of them: a split would be set by 1/1e-3 times the noise).
const SEPARABLE_TOL: f64 = 1e-3;

/// Smallest coefficient (relative to the largest) named in a combination.
const NAME_TOL: f64 = 0.02;

/// A parameter the log cannot separate from others.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Unidentifiable {
    /// Full parameter name (`term.param`), kept at the model's value.
    pub name: String,
    /// The kept parameters whose combination moves the log's points the
    /// same way, with coefficients: a change `δ` of this parameter is
    /// indistinguishable from `coef·δ` of each named one (units: theirs
    /// per this one's).
    pub combination: Vec<(String, f64)>,
    /// A sentence naming the combination.
    pub sentence: String,
}

/// Priority of a term kind: lower is kept first when parameters are not
/// separable. Physical reading: the large, well-known error sources of a
/// stage first; the angular motions seen through Abbe arms last (their
/// slopes are the same column as a scale or squareness).
fn priority(kind: &str) -> u32 {
    match kind {
        "squareness" => 0,
        "lead_error" => 1,
        "backlash" => 2,
        "leadscrew_cyclic" => 3,
        "cross_coupling" => 4,
        "thermal_expansion" => 5,
        "time_drift" => 6,
        "optics_drift" => 7,
        "angular" => 8,
        _ => 9,
    }
}

/// Splits the candidate base parameters into the ones the log identifies
/// (indices into `names`, in their original order) and the ones it cannot
/// separate from those, named with their combination.
pub(super) fn identifiable(
    d: &Data,
    model: &StageModel,
    names: &[String],
    cols: &[Vec<f64>],
) -> (Vec<usize>, Vec<Unidentifiable>) {
    identifiable_given(d, model, names, cols, &[])
}

/// [`identifiable`] with the columns `given` (accepted findings' terms)
/// in the span before any parameter: a parameter whose column they and the
/// parameters kept before it span is not separable from them.
pub(super) fn identifiable_given(
    d: &Data,
    model: &StageModel,
    names: &[String],
    cols: &[Vec<f64>],
    given: &[Vec<f64>],
) -> (Vec<usize>, Vec<Unidentifiable>) {
    let kinds: Vec<String> = names
        .iter()
        .map(|n| {
            let term = n.split('.').next().unwrap_or(n);
            model
                .terms()
                .iter()
                .find(|t| t.name() == term)
                .map_or_else(String::new, |t| t.kind().to_string())
        })
        .collect();
    let mut order: Vec<usize> = (0..names.len()).collect();
    // Stable: within a kind, the model's term and parameter order.
    order.sort_by_key(|&j| priority(&kinds[j]));
    let rows = |v: &[f64]| measured_rows(d, v);
    let mut basis: Vec<Vec<f64>> = Vec::new();
    let mut kept: Vec<usize> = Vec::new();
    let mut dropped: Vec<usize> = Vec::new();
    let orthogonal = |basis: &[Vec<f64>], col: &[f64]| -> Option<Vec<f64>> {
        let norm = dot(col, col).sqrt();
        if norm <= 0.0 || !norm.is_finite() {
            return None;
        }
        let mut r: Vec<f64> = col.iter().map(|v| v / norm).collect();
        for _ in 0..2 {
            for q in basis {
                let c = dot(&r, q);
                for (a, b) in r.iter_mut().zip(q) {
                    *a -= c * b;
                }
            }
        }
        let rn = dot(&r, &r).sqrt();
        (rn >= SEPARABLE_TOL).then(|| r.iter().map(|v| v / rn).collect())
    };
    for g in given {
        if let Some(q) = orthogonal(&basis, &rows(g)) {
            basis.push(q);
        }
    }
    for &j in &order {
        let col = rows(&cols[j]);
        let norm = dot(&col, &col).sqrt();
        if norm <= 0.0 || !norm.is_finite() {
            dropped.push(j);
            continue;
        }
        let mut r: Vec<f64> = col.iter().map(|v| v / norm).collect();
        // Two passes of modified Gram–Schmidt keep the basis orthogonal.
        for _ in 0..2 {
            for q in &basis {
                let c = dot(&r, q);
                for (a, b) in r.iter_mut().zip(q) {
                    *a -= c * b;
                }
            }
        }
        let rn = dot(&r, &r).sqrt();
        if rn < SEPARABLE_TOL {
            dropped.push(j);
        } else {
            basis.push(r.iter().map(|v| v / rn).collect());
            kept.push(j);
        }
    }
    // The kept columns and their normal equations, once for every dropped
    // parameter (each is a least-squares fit on the same columns).
    let span = (!dropped.is_empty()).then(|| Span::new(kept.iter().map(|&k| rows(&cols[k]))));
    let unident = dropped
        .iter()
        .map(|&j| {
            let combination = span
                .as_ref()
                .map_or_else(Vec::new, |sp| combination_of(&rows(&cols[j]), &kept, sp, names));
            let sentence = if combination.is_empty() {
                format!(
                    "{} does not change what this log measured (its effect is constant within every block the analysis centres)",
                    names[j]
                )
            } else {
                format!(
                    "{} moves the measured points as {} does: this log measures only their combination; it stays at the model's value",
                    names[j],
                    combination
                        .iter()
                        .map(|(n, c)| format!("{c:+.4}·{n}"))
                        .collect::<Vec<_>>()
                        .join(" ")
                )
            };
            Unidentifiable {
                name: names[j].clone(),
                combination,
                sentence,
            }
        })
        .collect();
    kept.sort_unstable();
    (kept, unident)
}

/// The held parameters (`held_names`, `held_cols`: kept at the model's
/// value for a reason of their own, `why`) whose column at the log's
/// points is a combination of the kept parameters' (`kept_names`,
/// `kept_cols`), named with it.
///
/// Why: a temperature coefficient held because the log's temperature does
/// not change still acts, at the model's value, through that constant
/// temperature's difference from the model's reference: a scale, exactly
/// the lead's column. The lead is then fitted to the data minus that
/// scale, and reporting the lead (with its Abbe partners) as what "the log
/// measures in all" left it out: −15 ppm stated where the map measures
/// +1.6 ppm (the shared real grid, 1.3 °C above the reference). Named as
/// a combination, it enters that total (`corrections::with_joint_totals`).
pub(super) fn held_along(
    d: &Data,
    held: &[(String, Vec<f64>)],
    kept_names: &[String],
    kept_cols: &[Vec<f64>],
    why: &str,
) -> Vec<Unidentifiable> {
    let rows = |v: &[f64]| measured_rows(d, v);
    let span = Span::new(kept_cols.iter().map(|c| rows(c)));
    let Some(chol) = span.chol.as_ref() else {
        return Vec::new();
    };
    let kept: Vec<usize> = (0..kept_names.len()).collect();
    held.iter()
        .filter_map(|(name, col)| {
            let target = rows(col);
            let tt = dot(&target, &target);
            if !(tt.is_finite() && tt > 0.0) {
                return None;
            }
            let r = DVector::from_fn(span.cols.len(), |a, _| dot(&span.cols[a], &target));
            let beta = chol.solve(&r);
            let outside: f64 = (0..target.len())
                .map(|k| {
                    let fit: f64 = (0..span.cols.len()).map(|a| beta[a] * span.cols[a][k]).sum();
                    (target[k] - fit).powi(2)
                })
                .sum();
            if (outside / tt).sqrt() >= SEPARABLE_TOL {
                return None;
            }
            let combination = combination_of(&target, &kept, &span, kept_names);
            (!combination.is_empty()).then(|| Unidentifiable {
                name: name.clone(),
                sentence: format!(
                    "{name} ({why}) still moves the measured points, at the model's value, as {} does: it is counted in that parameter's total",
                    combination
                        .iter()
                        .map(|(n, c)| format!("{c:+.4}·{n}"))
                        .collect::<Vec<_>>()
                        .join(" ")
                ),
                combination,
            })
        })
        .collect()
}

/// The rows of a column (`2·i + c` per point) of the measured components
/// only: the others carry no information.
fn measured_rows(d: &Data, v: &[f64]) -> Vec<f64> {
    (0..d.n)
        .flat_map(|i| (0..2).map(move |c| (i, c)))
        .filter(|&(_, c)| d.measured[c])
        .map(|(i, c)| v[2 * i + c])
        .collect()
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// The kept columns (rows of the measured components) and the Cholesky
/// factor of their normal equations (`None` when singular or empty).
struct Span {
    cols: Vec<Vec<f64>>,
    chol: Option<nalgebra::Cholesky<f64, nalgebra::Dyn>>,
}

impl Span {
    fn new(cols: impl Iterator<Item = Vec<f64>>) -> Self {
        let cols: Vec<Vec<f64>> = cols.collect();
        let p = cols.len();
        let chol = (p > 0)
            .then(|| DMatrix::from_fn(p, p, |a, b| dot(&cols[a], &cols[b])).cholesky())
            .flatten();
        Self { cols, chol }
    }
}

/// Least-squares coefficients of `target` on the kept columns (`span`,
/// one per index of `kept`), the non-negligible ones with their names.
fn combination_of(
    target: &[f64],
    kept: &[usize],
    span: &Span,
    names: &[String],
) -> Vec<(String, f64)> {
    if kept.is_empty() || target.iter().all(|v| *v == 0.0) {
        return Vec::new();
    }
    let cols = &span.cols;
    let p = cols.len();
    let r = DVector::from_fn(p, |a, _| dot(&cols[a], target));
    let Some(beta) = span.chol.as_ref().map(|c| c.solve(&r)) else {
        return Vec::new();
    };
    // Weigh by each column's size so the threshold compares contributions.
    let tnorm = dot(target, target).sqrt();
    let contrib: Vec<f64> = (0..p)
        .map(|a| (beta[a] * dot(&cols[a], &cols[a]).sqrt() / tnorm).abs())
        .collect();
    let big = contrib.iter().cloned().fold(0.0, f64::max);
    let mut out: Vec<(String, f64, f64)> = (0..p)
        .filter(|&a| contrib[a] >= NAME_TOL * big && contrib[a] > 0.0)
        .map(|a| (names[kept[a]].clone(), beta[a], contrib[a]))
        .collect();
    out.sort_by(|a, b| b.2.total_cmp(&a.2));
    out.into_iter().map(|(n, c, _)| (n, c)).collect()
}

/// |cosine| between a finding's column and a model parameter's column at or
/// above which the parameter carries the finding (the two move the measured
/// points the same way to 1 %).
const CARRY_COS: f64 = 0.99;

/// The candidates among `dropped` (indices into `cand_cols`) that carry the
/// finding whose columns are `spec_cols`: each of its columns is collinear
/// (|cos| ≥ [`CARRY_COS`] over the measured components) with one of them.
/// Empty unless every column has a carrier.
///
/// Why: a model parameter left at its value by the base selection (its
/// effect hidden under a larger unmodelled one, e.g. a thermal coefficient
/// under 5 µm of lost motion) shows up later as a finding of the same
/// shape. It is the model's own structure with this stage's value — a
/// parameter correction, not a missing term.
pub(super) fn carriers(
    d: &Data,
    spec_cols: &[Vec<f64>],
    dropped: &[usize],
    cand_cols: &[Vec<f64>],
) -> Vec<usize> {
    let measured = |v: &[f64]| -> Vec<f64> {
        v.iter()
            .enumerate()
            .map(|(k, &x)| if d.measured[k % 2] { x } else { 0.0 })
            .collect()
    };
    let mut out: Vec<usize> = Vec::new();
    for s in spec_cols {
        let s = measured(s);
        let ss = dot(&s, &s);
        if ss <= 0.0 {
            return Vec::new();
        }
        let best = dropped
            .iter()
            .map(|&j| {
                let c = measured(&cand_cols[j]);
                let cc = dot(&c, &c);
                let cos = if cc > 0.0 {
                    (dot(&s, &c) / (ss * cc).sqrt()).abs()
                } else {
                    0.0
                };
                (j, cos)
            })
            .max_by(|a, b| a.1.total_cmp(&b.1));
        match best {
            Some((j, cos)) if cos >= CARRY_COS => {
                if !out.contains(&j) {
                    out.push(j);
                }
            }
            _ => return Vec::new(),
        }
    }
    out
}
