//! Readings of the replicates as model terms: which table families (a
//! reversal table, a non-linearity table) a log's readings ask the search
//! to test, the record of their held-out tests, and the term (or the
//! reason for none) attached to each reading in the report.
//!
//! Why a file of its own: this is the one place where the noise report's
//! readings (`noise`, `readings`) meet the greedy search's verdicts; the
//! search itself treats a table like any other family.

use crate::charact::log::MeasurementLog;
use crate::model::Axis;

use super::data;
use super::family::Family;
use super::finding::Finding;
use super::fit::{fold_base, keep_heldout, unjudged, Verdict};
use super::noise::{self, NoiseReport};
use super::options::DiagnoseOptions;
use super::readings::{ReadingKind, ReadingTerm};
use super::search;
use crate::analysis::FindingKind;

/// The held-out test of a table family (a reading as a model term).
#[derive(Debug, Clone, Copy)]
pub(super) struct TableTest {
    axis: Axis,
    lost_motion: bool,
    /// Both tables of the axis jointly (`lost_motion` is then true).
    joint: bool,
    rms_before_um: f64,
    rms_after_um: f64,
    gain_pct: f64,
    z: f64,
    /// z of the held-out per-target χ² ([`heldout_chi_z`]; −∞ when not
    /// computed).
    chi_z: f64,
}

/// The table families worth searching: a reading of the replicates
/// (`readings::read`, on the base fit's held-out residual, as the report's
/// readings are) of a reversal that varies along the travel or of a
/// non-linearity between targets that the base leaves. Why gated: a table has a parameter per knot; searched on every
/// log it would compete with the periodic and localized families for
/// structure they describe with two or three parameters, and its evidence
/// is the replicates' (same target, same approach, several cycles).
pub(super) fn wanted(log: &MeasurementLog, d: &data::Data, base: &[Vec<f64>]) -> Vec<Family> {
    let mut heldout = unjudged(d);
    for f in 0..d.nfolds {
        let train: Vec<bool> = d.fold.iter().map(|&k| k != f).collect();
        let fb = fold_base(d, base, train);
        keep_heldout(d, &mut heldout, &fb.resid, &fb.train);
    }
    let nr = noise::noise_report(log, d, &heldout);
    let mut out = Vec::new();
    for r in nr.components.iter().flat_map(|c| &c.readings) {
        let lost_motion = match r.kind {
            ReadingKind::ReversalVaries => true,
            ReadingKind::Nonlinearity => false,
            _ => continue,
        };
        if r.model_explains != Some(false) || search::table_knots(d, r.component).is_none() {
            continue;
        }
        let f = Family::Table {
            axis: r.component,
            lost_motion,
        };
        if !out.contains(&f) {
            out.push(f);
        }
    }
    // Both tables of one axis: also jointly (a bidirectional table). A
    // test with few targets gives each table few points; where both are
    // there, neither alone leaves the held-out cycles as close as the two.
    for axis in Axis::ALL {
        let both = [true, false]
            .iter()
            .all(|&lost_motion| out.contains(&Family::Table { axis, lost_motion }));
        if both {
            out.push(Family::Tables { axis });
        }
    }
    out
}

/// Attaches to each reading the model term it became and its held-out
/// gain (or why no term can carry it).
pub(super) fn reading_terms(
    noise: &mut NoiseReport,
    findings: &[Finding],
    tests: &[TableTest],
    d: &data::Data,
    opts: &DiagnoseOptions,
) {
    for c in &mut noise.components {
        for r in &mut c.readings {
            let lost_motion = match r.kind {
                ReadingKind::ReversalVaries => true,
                ReadingKind::Nonlinearity => false,
                ReadingKind::FirstApproach => {
                    r.term = Some(no_term(
                        "",
                        "no model term: it happens once, on the first visit, so no held-out cycle can test a term for it (and a model has no state for \"first visit of the log\"); the visit is left out of every fit and held-out score, the repeatability and the per-target means".into(),
                    ));
                    continue;
                }
                _ => continue,
            };
            let axis = r.component;
            let knots = search::table_knots(d, axis).map_or(0, |k| k.len());
            // What the model's held-out residual no longer shows needs no
            // term (unless it is one: found below).
            let lacks = r.model_explains == Some(false);
            let what = if lost_motion {
                "a reversal table"
            } else {
                "a non-linearity table"
            };
            let want = if lost_motion {
                FindingKind::ReversalVaries
            } else {
                FindingKind::Nonlinearity
            };
            if let Some(f) = findings.iter().find(|f| f.kind == want && f.axis == axis) {
                // Two tables accepted together share one held-out verdict.
                let other = if lost_motion {
                    FindingKind::Nonlinearity
                } else {
                    FindingKind::ReversalVaries
                };
                let joint = findings.iter().any(|g| {
                    g.kind == other
                        && g.axis == axis
                        && g.significance == f.significance
                        && g.gain_pct == f.gain_pct
                });
                let jointly = if joint {
                    " (judged jointly with the other table of the axis)"
                } else {
                    ""
                };
                let chi = tests
                    .iter()
                    .find(|t| {
                        t.axis == axis
                            && t.joint == joint
                            && (joint || t.lost_motion == lost_motion)
                    })
                    .map_or(f64::NEG_INFINITY, |t| t.chi_z);
                r.term = Some(ReadingTerm {
                    kind: crate::model::terms::discovered::POSITION_TABLE_KIND,
                    name: f.term.clone(),
                    knots,
                    heldout_rms_before_um: f.heldout_rms_before_um,
                    heldout_rms_after_um: f.heldout_rms_after_um,
                    gain_pct: f.gain_pct,
                    z: f.significance,
                    in_extended_model: true,
                    sentence: format!(
                        "{what} at {knots} knots{jointly} predicts held-out cycles better: {axis} {:.3} → {:.3} µm ({:+.0} %, z {:.1}{}); the extended model carries it (`{}`)",
                        f.heldout_rms_before_um, f.heldout_rms_after_um, f.gain_pct, f.significance, chi_text(chi), f.term
                    ),
                });
            } else if !lacks {
                continue;
            } else if knots == 0 {
                r.term = Some(untested(
                    what,
                    "the log has fewer than 3 positions along the axis".into(),
                ));
            } else if let Some(t) = tests
                .iter()
                .find(|t| t.axis == axis && t.lost_motion == lost_motion && !t.joint)
            {
                let jointly = tests
                    .iter()
                    .find(|t| t.axis == axis && t.joint)
                    .map(|j| {
                        format!(
                            "; with the {} table jointly: {axis} {:.3} → {:.3} µm ({:+.0} %, z {:.1}{}), not added either",
                            if lost_motion { "non-linearity" } else { "reversal" },
                            j.rms_before_um,
                            j.rms_after_um,
                            j.gain_pct,
                            j.z,
                            chi_text(j.chi_z)
                        )
                    })
                    .unwrap_or_default();
                let verdict = if t.gain_pct <= 0.0 {
                    "it does not generalize: the per-target values of the training cycles do not predict the held-out ones"
                } else if (t.z < opts.z_threshold && t.chi_z < TABLE_CHI_Z)
                    || t.gain_pct < opts.min_gain_pct
                {
                    "the gain is not significant"
                } else {
                    "the finding cap was reached first"
                };
                r.term = Some(ReadingTerm {
                    kind: crate::model::terms::discovered::POSITION_TABLE_KIND,
                    name: String::new(),
                    knots,
                    heldout_rms_before_um: t.rms_before_um,
                    heldout_rms_after_um: t.rms_after_um,
                    gain_pct: t.gain_pct,
                    z: t.z,
                    in_extended_model: false,
                    sentence: format!(
                        "{what} at {knots} knots, held out: {axis} {:.3} → {:.3} µm ({:+.0} %, z {:.1}{}); not added: {verdict}{jointly}",
                        t.rms_before_um, t.rms_after_um, t.gain_pct, t.z, chi_text(t.chi_z)
                    ),
                });
            } else {
                r.term = Some(untested(
                    what,
                    "the base fit's held-out residual did not show it (the final model's does)"
                        .into(),
                ));
            }
        }
    }
}

/// A reading's term that was not tested, and why.
fn untested(what: &str, why: String) -> ReadingTerm {
    no_term(
        crate::model::terms::discovered::POSITION_TABLE_KIND,
        format!("{what} was not tested: {why}"),
    )
}

/// A reading without a tested term of `kind`: no knots, no held-out
/// figures, only the `sentence` saying why.
pub(super) fn no_term(kind: &'static str, sentence: String) -> ReadingTerm {
    ReadingTerm {
        kind,
        name: String::new(),
        knots: 0,
        heldout_rms_before_um: f64::NAN,
        heldout_rms_after_um: f64::NAN,
        gain_pct: f64::NAN,
        z: f64::NAN,
        in_extended_model: false,
        sentence,
    }
}

/// Keeps the latest held-out test of each table family in `tests` (one
/// per axis, table and joint test): a round's verdicts replace the last
/// round's, so what is reported is the test against the final model, or,
/// for a family already `accepted`, the test it was accepted by.
pub(super) fn record(tests: &mut Vec<TableTest>, verdicts: &[Verdict], accepted: &[Family]) {
    for v in verdicts.iter().filter(|v| !accepted.contains(&v.family)) {
        let (axis, lost_motion, joint) = match v.family {
            Family::Table { axis, lost_motion } => (axis, lost_motion, false),
            Family::Tables { axis } => (axis, true, true),
            _ => continue,
        };
        tests.retain(|t| (t.axis, t.lost_motion, t.joint) != (axis, lost_motion, joint));
        tests.push(TableTest {
            axis,
            lost_motion,
            joint,
            rms_before_um: v.rms_before,
            rms_after_um: v.rms_after,
            gain_pct: v.gain_pct,
            z: v.z,
            chi_z: v.table_z,
        });
    }
}

/// `, χ² z …` for a computed held-out χ² z, empty otherwise.
fn chi_text(z: f64) -> String {
    if z.is_finite() {
        format!(", per-target χ² z {z:.1}")
    } else {
        String::new()
    }
}

/// z ([`paulson_z`]) of the held-out per-target χ² at or above which a
/// table family is accepted (with a held-out gain ≥ `min_gain_pct`) even
/// when its paired z is below `z_threshold`: the one-sided normal
/// quantile of a false-acceptance rate of 1e-3 per table tested on an axis
/// whose per-target means hold nothing the base cannot carry.
pub(super) const TABLE_CHI_Z: f64 = 3.09;

/// Paulson's normal approximation of an `F(k, ν)` statistic: a z that is
/// N(0, 1) when `f` is F-distributed (the cube-root transform that
/// Wilson–Hilferty uses for a χ², with the denominator's own scatter).
pub(super) fn paulson_z(f: f64, k: f64, nu: f64) -> f64 {
    if !(f.is_finite() && f >= 0.0 && k > 0.0 && nu > 0.0) {
        return f64::NEG_INFINITY;
    }
    let a = 2.0 / (9.0 * k);
    let b = 2.0 / (9.0 * nu);
    let c = f.cbrt();
    ((1.0 - b) * c - (1.0 - a)) / (a + b * c * c).sqrt()
}

/// Which combination of the per-(target, approach) means a table family
/// carries.
#[derive(Clone, Copy, PartialEq)]
enum Contrast {
    /// Forward minus backward mean per target (a reversal table).
    Reversal,
    /// The mean over the approaches per target (a non-linearity table).
    Mean,
    /// Every (target, approach) mean (both tables jointly).
    All,
}

/// The held-out test of a table family by its per-target means, for axes
/// with a knot per target (at most `search::MAX_TABLE_TARGETS` distinct
/// positions, an ISO 230-2 test): z ([`paulson_z`]) of the χ² of the
/// base's pooled held-out residual (`before`), averaged per target and
/// approach and combined as the table carries them ([`Contrast`]), against
/// its covariance under "the base is right, the rest is noise" with the
/// replicates' σ. `None` when the family is not a table or the axis is not
/// a few replicated targets.
///
/// Why: the paired z (`fit::paired_z`) asks each held-out point to show
/// the gain; a 5-target test has ≤ 50 of them, and a table that takes
/// the held-out RMS from 4.17 to 1.99 µm (the `bifrost` log, σ ≈ 0.5 µm)
/// stays at z 4.4. The per-target means pool the visits the way ISO 230-2
/// does, and the replicates' scatter (`s_i`) says what noise alone would
/// leave in them.
///
/// The covariance is exact for the linear fits: a held-out mean is a
/// linear function of the noise, `v_g·ε` with `v_g` the centred average
/// of its visits less what the base fitted on the other folds predicts
/// there (`x_iᵀ G_f⁺ X_fᵀ`); its covariance is `σ²·V Vᵀ`. The base's
/// error is part of it: a scale fitted on four cycles and extrapolated to
/// the fifth moves every target's held-out mean together, and taking the
/// means as independent with variance `σ²/n` would call that shared
/// error structure on a clean axis. With
/// `σ²` from `ν` replicate degrees of freedom, `χ²/k` is `F(k, ν)`.
pub(super) fn heldout_chi_z(
    d: &data::Data,
    base: &[Vec<f64>],
    before: &[f64],
    family: Family,
) -> Option<f64> {
    use nalgebra::{DMatrix, DVector};
    let (axis, contrast) = match family {
        Family::Table { axis, lost_motion } => (
            axis,
            if lost_motion {
                Contrast::Reversal
            } else {
                Contrast::Mean
            },
        ),
        Family::Tables { axis } => (axis, Contrast::All),
        _ => return None,
    };
    let a = axis.index();
    let c = a;
    if !d.measured[c] {
        return None;
    }
    // Replicate groups: (target, approach) over the rows where the axis
    // moves; the positions of one target (`data::targets_of`) are one.
    let tg = data::targets_of(&data::distinct_positions(d, axis));
    let mut keys: Vec<(i64, i64)> = Vec::new();
    let mut rows_of: Vec<Vec<usize>> = Vec::new();
    for i in (0..d.n).filter(|&i| d.moving[i][a] && !d.excluded[i]) {
        let x = d.states[i].cmd_um(axis);
        let k = (
            tg.index_of(x)
                .map_or_else(|| (x * 1e3).round() as i64, |t| t as i64),
            d.approach[i][a] as i64,
        );
        match keys.iter().position(|x| *x == k) {
            Some(g) => rows_of[g].push(i),
            None => {
                keys.push(k);
                rows_of.push(vec![i]);
            }
        }
    }
    let mut targets: Vec<i64> = keys.iter().map(|k| k.0).collect();
    targets.sort_unstable();
    targets.dedup();
    if targets.len() < 3 || targets.len() > search::MAX_TABLE_TARGETS {
        return None;
    }
    // The replicates' σ²: scatter of the model's residual within a group
    // (the model's prediction is one value per target and approach).
    let (mut ss, mut nu) = (0.0, 0usize);
    for rows in rows_of.iter().filter(|r| r.len() >= 2) {
        let m = rows.iter().map(|&i| d.r0[2 * i + c]).sum::<f64>() / rows.len() as f64;
        ss += rows
            .iter()
            .map(|&i| (d.r0[2 * i + c] - m).powi(2))
            .sum::<f64>();
        nu += rows.len() - 1;
    }
    if nu < 2 || ss <= 0.0 {
        return None;
    }
    let s2 = ss / nu as f64;
    let fbs: Vec<_> = (0..d.nfolds)
        .map(|f| fold_base(d, base, d.fold.iter().map(|&k| k != f).collect()))
        .collect();
    // Held-out mean per group and its noise row `v_g`.
    let mut h: Vec<f64> = Vec::new();
    let mut v: Vec<Vec<f64>> = Vec::new();
    let mut kept: Vec<(i64, i64)> = Vec::new();
    for (g, rows) in rows_of.iter().enumerate() {
        let ho: Vec<usize> = rows
            .iter()
            .copied()
            .filter(|&i| d.judged[i] && before[2 * i + c].is_finite())
            .collect();
        if ho.is_empty() {
            continue;
        }
        let n = ho.len() as f64;
        let mut row = vec![0.0; 2 * d.n];
        for &i in &ho {
            row[2 * i + c] += 1.0 / n;
            let fb = &fbs[d.fold[i]];
            let x = DVector::from_fn(base.len(), |j, _| base[j][2 * i + c]);
            let y = fb.gram_solve(&x);
            if y.is_empty() {
                continue;
            }
            for k in (0..d.n).filter(|&k| fb.train[k]) {
                for cc in 0..2 {
                    let p: f64 = base
                        .iter()
                        .zip(y.iter())
                        .map(|(col, yj)| col[2 * k + cc] * yj)
                        .sum();
                    row[2 * k + cc] -= p / n;
                }
            }
        }
        d.center(&mut row);
        h.push(ho.iter().map(|&i| before[2 * i + c]).sum::<f64>() / n);
        v.push(row);
        kept.push(keys[g]);
    }
    let cm = contrast_weights(&targets, &kept, contrast);
    let q = cm.len();
    if q == 0 {
        return None;
    }
    // Contrasted noise rows and means.
    let rows: Vec<Vec<f64>> = cm
        .iter()
        .map(|w| {
            let mut r = vec![0.0; 2 * d.n];
            for (g, &wg) in w.iter().enumerate() {
                if wg != 0.0 {
                    for (ri, vi) in r.iter_mut().zip(&v[g]) {
                        *ri += wg * vi;
                    }
                }
            }
            r
        })
        .collect();
    let hc = DVector::from_fn(q, |r, _| cm[r].iter().zip(&h).map(|(w, x)| w * x).sum());
    let cov = DMatrix::from_fn(q, q, |r, s| {
        rows[r]
            .iter()
            .zip(&rows[s])
            .map(|(x, y)| x * y)
            .sum::<f64>()
    });
    let eig = nalgebra::SymmetricEigen::new(cov);
    let lmax = eig.eigenvalues.iter().cloned().fold(0.0, f64::max);
    if lmax <= 0.0 {
        return None;
    }
    let (mut chi2, mut k) = (0.0, 0usize);
    for (j, &l) in eig.eigenvalues.iter().enumerate() {
        if l > 1e-9 * lmax {
            let u = eig.eigenvectors.column(j).dot(&hc);
            chi2 += u * u / l;
            k += 1;
        }
    }
    Some(paulson_z(chi2 / s2 / k as f64, k as f64, nu as f64))
}

/// The contrast the table carries: rows of weights over the groups
/// `kept` (target, approach) of `targets`.
fn contrast_weights(targets: &[i64], kept: &[(i64, i64)], contrast: Contrast) -> Vec<Vec<f64>> {
    let mut cm: Vec<Vec<f64>> = Vec::new();
    for &t in targets {
        let here: Vec<usize> = (0..kept.len()).filter(|&g| kept[g].0 == t).collect();
        match contrast {
            Contrast::All => {
                for &g in &here {
                    let mut w = vec![0.0; kept.len()];
                    w[g] = 1.0;
                    cm.push(w);
                }
            }
            Contrast::Mean if !here.is_empty() => {
                let mut w = vec![0.0; kept.len()];
                for &g in &here {
                    w[g] = 1.0 / here.len() as f64;
                }
                cm.push(w);
            }
            Contrast::Reversal => {
                let fwd = here.iter().find(|&&g| kept[g].1 > 0);
                let bwd = here.iter().find(|&&g| kept[g].1 < 0);
                if let (Some(&f), Some(&b)) = (fwd, bwd) {
                    let mut w = vec![0.0; kept.len()];
                    w[f] = 1.0;
                    w[b] = -1.0;
                    cm.push(w);
                }
            }
            Contrast::Mean => {}
        }
    }
    cm
}
