//! Step 8 of the analysis: a finding whose stated numbers the log does not
//! determine is withdrawn ([`Withdrawn`]) rather than reported, and the
//! extended model is refitted without it ([`settle`]).
//!
//! A finding is withdrawn when
//! * a parameter or a standard error is not finite;
//! * a place it states (a localized feature's `position_um`, a table's
//!   `knot*_um`) lies outside the commanded range of its axis over the
//!   rows the fit uses ([`Bounds`]);
//! * a width or length (`width_um`, `length_um`) is not positive, or a
//!   width is wider than that range;
//! * a place, width, length or amplitude (`amplitude_um`) estimated from
//!   the log has no standard error;
//! * the standard error of a place, width or length is larger than the
//!   measured range of its axis, or that of a µm value (an amplitude, a
//!   table value, extra play) larger than the peak-to-peak of the log's
//!   error in its component.
//!
//! Why: each of these prints a number no metrologist can use ("a local dip
//! at x = 3e16 ± 3e16 µm", "around x = −40 µm" on a 0…25 mm scan): the
//! held-out test said a column helps, but the log cannot say what the
//! column's parameters are. A held-out gain is no licence to state them.
//!
//! Why a file of its own: this is the one place that decides whether a
//! described finding is reported; `describe` words it, `extend` builds it.

use std::collections::HashMap;

use crate::model::{Axis, StageModel};

use super::data::Data;
use super::describe::describe;
use super::extend::extended_with_se;
use super::finding::{Finding, Withdrawn};
use super::fit::{fold_base, keep_heldout, unjudged, Verdict};
use super::search::{columns, Spec};
use crate::analysis::AnalysisError;

/// What the log measured, against which a finding's numbers are judged.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Bounds {
    /// Lowest and highest commanded position of each axis over the rows
    /// the fit uses (not excluded), µm: the measured travel.
    pub(super) range: [(f64, f64); 2],
    /// Peak-to-peak of measured − commanded of each component over the
    /// same rows, µm: the largest error the log can speak of.
    pub(super) p2p: [f64; 2],
}

/// The [`Bounds`] of the prepared log `d`.
pub(super) fn bounds(d: &Data) -> Bounds {
    let mut range = [(f64::INFINITY, f64::NEG_INFINITY); 2];
    let mut err = [(f64::INFINITY, f64::NEG_INFINITY); 2];
    for i in (0..d.n).filter(|&i| !d.excluded[i]) {
        for a in Axis::ALL {
            let c = a.index();
            let x = d.states[i].cmd_um(a);
            let e = d.meas[i][c] - x;
            if x.is_finite() {
                range[c] = (range[c].0.min(x), range[c].1.max(x));
            }
            if e.is_finite() {
                err[c] = (err[c].0.min(e), err[c].1.max(e));
            }
        }
    }
    Bounds {
        range,
        p2p: err.map(|(lo, hi)| if hi >= lo { hi - lo } else { 0.0 }),
    }
}

/// What a parameter of a finding is, by its name (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Role {
    /// A place along the finding's axis estimated from the log.
    Place,
    /// A place the analysis chose (a table's knot at a target): it has no
    /// standard error, and must still lie inside the travel.
    Knot,
    /// A width along the axis, or a build-up length of moves.
    Width,
    /// An amplitude in µm that must have a standard error.
    Amplitude,
    /// Another µm value (a table value, extra play): its standard error,
    /// when it has one, must be below the log's peak-to-peak error.
    Micrometres,
    /// Anything else (slopes, rates, periods, phases): finite.
    Other,
}

fn role(name: &str) -> Role {
    match name {
        "position_um" => Role::Place,
        "width_um" | "length_um" => Role::Width,
        "amplitude_um" => Role::Amplitude,
        n if n.starts_with("knot") && n.ends_with("_um") => Role::Knot,
        n if n.starts_with("value") && n.ends_with("_um") => Role::Micrometres,
        _ => Role::Other,
    }
}

/// Numbers in a reason: four significant figures, in exponent form when
/// absurdly large or small (the reason quotes the number that is absurd).
fn num(v: f64) -> String {
    if v != 0.0 && v.is_finite() && !(1e-3..1e6).contains(&v.abs()) {
        format!("{v:.3e}")
    } else {
        format!("{v:.4}")
    }
}

/// Allowance on the travel's ends, µm, for rounding only: a knot placed at
/// the end target is that target (no slack beyond it, see [`why_withdrawn`]).
const ROUNDING_UM: f64 = 1e-6;

/// Why finding `f` is not determined by a log with bounds `b`, or `None`
/// when every number it states is usable (see the module docs).
///
/// No slack is allowed beyond the travel's ends (not even half a width):
/// the search and its refinement keep a feature's centre inside the
/// travel, so a centre outside comes from nowhere the log measured; and a
/// Gaussian centred outside is seen by its tail alone, where its place,
/// width and amplitude trade off without bound (its amplitude is an
/// extrapolation). A feature whose centre is inside but whose flank runs
/// beyond the end is kept: its peak was measured.
pub(super) fn why_withdrawn(f: &Finding, b: &Bounds) -> Option<String> {
    // The most direct reason first: a number that is none, then a place
    // the log did not measure, then a σ that says it cannot tell.
    not_finite(f)
        .or_else(|| misplaced(f, b))
        .or_else(|| undetermined(f, b))
}

/// A parameter or a standard error of `f` that is not a finite number.
fn not_finite(f: &Finding) -> Option<String> {
    for (k, &v) in &f.params {
        if !v.is_finite() {
            return Some(format!("its {k} is not finite ({v})"));
        }
        if let Some(e) = f.uncertainty.get(k).filter(|e| !e.is_finite() || **e < 0.0) {
            return Some(format!(
                "the standard error of its {k} is not a number ({e})"
            ));
        }
    }
    None
}

/// A place of `f` outside the measured travel of its axis, or a width
/// that is not positive or wider than that travel.
fn misplaced(f: &Finding, b: &Bounds) -> Option<String> {
    let a = f.axis;
    let (lo, hi) = b.range[a.index()];
    let span = hi - lo;
    for (k, &v) in &f.params {
        let r = role(k);
        let outside = v < lo - ROUNDING_UM || v > hi + ROUNDING_UM || span.is_nan() || span < 0.0;
        if matches!(r, Role::Place | Role::Knot) && outside {
            return Some(format!(
                "its {k} {} µm lies outside the measured {a} travel ({} … {} µm)",
                num(v),
                num(lo),
                num(hi)
            ));
        }
        if r == Role::Width && v <= 0.0 {
            return Some(format!("its {k} {} µm is not positive", num(v)));
        }
        if k == "width_um" && v > span {
            return Some(format!(
                "its width {} µm is wider than the measured {a} travel ({} µm): a bow, not a local feature",
                num(v),
                num(span)
            ));
        }
    }
    None
}

/// A place, width, length or amplitude of `f` without a standard error,
/// or one with a σ larger than the travel (places, widths) or the log's
/// peak-to-peak error (µm values).
fn undetermined(f: &Finding, b: &Bounds) -> Option<String> {
    let a = f.axis;
    let (lo, hi) = b.range[a.index()];
    let p2p = b.p2p[f.component.index()];
    for (k, &v) in &f.params {
        let r = role(k);
        let (limit, of) = match r {
            Role::Place | Role::Width => (hi - lo, format!("the measured {a} travel")),
            Role::Amplitude | Role::Micrometres => (
                p2p,
                format!("the peak-to-peak {} error of the log", f.component),
            ),
            Role::Knot | Role::Other => continue,
        };
        match f.uncertainty.get(k) {
            None if r != Role::Micrometres => {
                return Some(format!(
                    "its {k} ({} µm) has no standard error: the log does not determine it (its effect is nil, or what the other terms already carry)",
                    num(v)
                ))
            }
            Some(&e) if e > limit => {
                return Some(format!(
                    "the standard error of its {k} ({} ± {} µm) is larger than {of} ({} µm)",
                    num(v),
                    num(e),
                    num(limit)
                ))
            }
            _ => {}
        }
    }
    None
}

/// The accepted findings after withdrawal: the kept ones (spec and
/// verdict, in order of acceptance) and their descriptions, the withdrawn
/// ones, and the extended model refitted with the kept ones only (with
/// the standard errors of its parameters by full name).
pub(super) struct Settled {
    pub(super) accepted: Vec<(Spec, Verdict)>,
    pub(super) findings: Vec<Finding>,
    pub(super) withdrawn: Vec<Withdrawn>,
    pub(super) fitted: StageModel,
    pub(super) std_errs: HashMap<String, f64>,
}

/// Builds the extended model from `accepted` (step 7: the centred solve,
/// standard errors of the shape parameters included), describes
/// each finding and withdraws the last-accepted one that [`why_withdrawn`]
/// rejects; repeats until every finding left is usable.
///
/// Why one at a time, the latest first: two findings that share the same
/// error (two bumps at one place) both come out with a huge σ in the joint
/// fit; without the later one the earlier is determined again. The greedy
/// loop accepted the later one as the lesser gain.
pub(super) fn settle(
    d: &Data,
    model: &StageModel,
    base_names: &[String],
    mut accepted: Vec<(Spec, Verdict)>,
) -> Result<Settled, AnalysisError> {
    let b = bounds(d);
    let mut withdrawn = Vec::new();
    loop {
        let specs: Vec<Spec> = accepted.iter().map(|(s, _)| s.clone()).collect();
        let (fitted, term_names, std_errs, unmodelled) =
            extended_with_se(d, model, base_names, &specs)?;
        let se = |n: &str| std_errs.get(n).copied();
        let value = |n: &str| unmodelled.get(n).copied();
        let mut findings = accepted
            .iter()
            .zip(&term_names)
            .map(|((s, v), name)| describe(s, v, name, &fitted, model, &se, &value, d))
            .collect::<Result<Vec<_>, _>>()?;
        let bad = findings
            .iter()
            .enumerate()
            .rev()
            .find_map(|(i, f)| why_withdrawn(f, &b).map(|r| (i, r)));
        let Some((i, reason)) = bad else {
            return Ok(Settled {
                accepted,
                findings,
                withdrawn,
                fitted,
                std_errs,
            });
        };
        accepted.remove(i);
        let mut finding = findings.swap_remove(i);
        finding.term = String::new();
        finding.in_extended_model = false;
        withdrawn.push(Withdrawn { finding, reason });
    }
}

/// Pooled held-out residual (`2i + c`, NaN where not judged) of the
/// base columns `base0` and the columns of `specs`, each fold fitted on
/// the others: what the greedy loop's last judging gives for the same
/// findings (their hyper-parameters from all the data).
pub(super) fn heldout_of<'a>(
    d: &Data,
    model: &StageModel,
    base0: &[Vec<f64>],
    specs: impl IntoIterator<Item = &'a Spec>,
) -> Vec<f64> {
    let mut cols = base0.to_vec();
    for s in specs {
        cols.extend(columns(s, d, model));
    }
    let mut ho = unjudged(d);
    for f in 0..d.nfolds {
        let train: Vec<bool> = d.fold.iter().map(|&k| k != f).collect();
        let fb = fold_base(d, &cols, train);
        keep_heldout(d, &mut ho, &fb.resid, &fb.train);
    }
    ho
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::analysis::FindingKind;
    use std::collections::BTreeMap;

    fn bounds_0_1000() -> Bounds {
        Bounds {
            range: [(0.0, 1000.0), (-50.0, 50.0)],
            p2p: [4.0, 2.0],
        }
    }

    fn localized(position: f64, width: f64, amp: f64, se: [Option<f64>; 3]) -> Finding {
        let keys = ["position_um", "width_um", "amplitude_um"];
        let mut params = BTreeMap::new();
        let mut uncertainty = BTreeMap::new();
        for ((k, v), e) in keys.iter().zip([position, width, amp]).zip(se) {
            params.insert(k.to_string(), v);
            if let Some(e) = e {
                uncertainty.insert(k.to_string(), e);
            }
        }
        Finding {
            kind: FindingKind::Localized,
            axis: Axis::X,
            component: Axis::X,
            params,
            uncertainty,
            shape: None,
            significance: 9.0,
            heldout_rms_before_um: 0.2,
            heldout_rms_after_um: 0.1,
            gain_pct: 50.0,
            explanation: String::new(),
            cause: String::new(),
            term: "found1_x_localized_in_x".into(),
            variable: None,
            in_extended_model: true,
        }
    }

    #[test]
    fn a_determined_feature_inside_the_travel_stays() {
        let f = localized(500.0, 40.0, 0.3, [Some(2.0), Some(3.0), Some(0.02)]);
        assert_eq!(why_withdrawn(&f, &bounds_0_1000()), None);
        // At the very end of the travel (its peak measured) it stays too.
        let f = localized(1000.0, 40.0, 0.3, [Some(2.0), Some(3.0), Some(0.02)]);
        assert_eq!(why_withdrawn(&f, &bounds_0_1000()), None);
    }

    #[test]
    fn each_unusable_number_withdraws_with_its_reason() {
        let b = bounds_0_1000();
        let ok = [Some(2.0), Some(3.0), Some(0.02)];
        let cases: Vec<(Finding, &str)> = vec![
            // The σ of 3e16 µm on the place.
            (
                localized(500.0, 40.0, 0.3, [Some(3e16), Some(3.0), Some(0.02)]),
                "position_um (500.0000 ± 3.000e16 µm) is larger than the measured x travel",
            ),
            // Centred outside the travel, with no σ.
            (
                localized(-40.0, 40.0, 0.3, [None, Some(3.0), Some(0.02)]),
                "position_um -40.0000 µm lies outside the measured x travel",
            ),
            (
                localized(1000.5, 40.0, 0.3, ok),
                "lies outside the measured x travel (0.0000 … 1000.0000 µm)",
            ),
            (
                localized(500.0, 40.0, 0.3, [None, Some(3.0), Some(0.02)]),
                "position_um (500.0000 µm) has no standard error",
            ),
            (
                localized(500.0, 40.0, 0.3, [Some(2.0), None, Some(0.02)]),
                "width_um (40.0000 µm) has no standard error",
            ),
            (
                localized(500.0, 40.0, 0.3, [Some(2.0), Some(f64::NAN), Some(0.02)]),
                "standard error of its width_um is not a number",
            ),
            (
                localized(500.0, 40.0, 0.3, [Some(2.0), Some(3.0), Some(5.0)]),
                "larger than the peak-to-peak x error of the log (4.0000 µm)",
            ),
            (
                localized(500.0, 2000.0, 0.3, ok),
                "wider than the measured x travel",
            ),
            (
                localized(500.0, 40.0, f64::INFINITY, ok),
                "amplitude_um is not finite",
            ),
        ];
        for (f, want) in cases {
            let why = why_withdrawn(&f, &b);
            assert!(
                why.as_deref().is_some_and(|w| w.contains(want)),
                "{:?}: {why:?}, want …{want}…",
                f.params
            );
        }
    }

    #[test]
    fn a_table_knot_outside_the_travel_withdraws_a_missing_value_sigma_does_not() {
        let b = bounds_0_1000();
        let mut f = localized(0.0, 1.0, 0.0, [None; 3]);
        f.kind = FindingKind::ReversalVaries;
        f.params.clear();
        for (k, x) in [0.0, 500.0, 1000.0].into_iter().enumerate() {
            f.params.insert(format!("knot{k}_um"), x);
            f.params.insert(format!("value{k}_um"), 1.0);
        }
        f.uncertainty.insert("value1_um".into(), 0.1);
        assert_eq!(why_withdrawn(&f, &b), None);
        f.uncertainty.insert("value2_um".into(), 4.5);
        assert!(why_withdrawn(&f, &b).is_some_and(|w| w.contains("value2_um")));
        f.uncertainty.remove("value2_um");
        f.params.insert("knot2_um".into(), 1200.0);
        assert!(why_withdrawn(&f, &b).is_some_and(|w| w.contains("knot2_um 1200.0000 µm")));
    }
}
