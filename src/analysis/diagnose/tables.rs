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
use super::fit::{fold_base, keep_heldout, unjudged, Verdict};
use super::noise::{self, NoiseReport};
use super::readings::{ReadingKind, ReadingTerm};
use super::search::{self, Family};
use super::{DiagnoseOptions, Finding, FindingKind};

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
                let jointly = if findings.iter().any(|g| {
                    g.kind == other
                        && g.axis == axis
                        && g.significance == f.significance
                        && g.gain_pct == f.gain_pct
                }) {
                    " (judged jointly with the other table of the axis)"
                } else {
                    ""
                };
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
                        "{what} at {knots} knots{jointly} predicts held-out cycles better: {axis} {:.3} → {:.3} µm ({:+.0} %, z {:.1}); the extended model carries it (`{}`)",
                        f.heldout_rms_before_um, f.heldout_rms_after_um, f.gain_pct, f.significance, f.term
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
                            "; with the {} table jointly: {axis} {:.3} → {:.3} µm ({:+.0} %, z {:.1}), not added either",
                            if lost_motion { "non-linearity" } else { "reversal" },
                            j.rms_before_um,
                            j.rms_after_um,
                            j.gain_pct,
                            j.z
                        )
                    })
                    .unwrap_or_default();
                let verdict = if t.gain_pct <= 0.0 {
                    "it does not generalize: the per-target values of the training cycles do not predict the held-out ones"
                } else if t.z < opts.z_threshold || t.gain_pct < opts.min_gain_pct {
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
                        "{what} at {knots} knots, held out: {axis} {:.3} → {:.3} µm ({:+.0} %, z {:.1}); not added: {verdict}{jointly}",
                        t.rms_before_um, t.rms_after_um, t.gain_pct, t.z
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
/// round's, so what is reported is the test against the final model.
pub(super) fn record(tests: &mut Vec<TableTest>, verdicts: &[Verdict]) {
    for v in verdicts {
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
        });
    }
}
