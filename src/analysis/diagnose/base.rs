//! Step 2's choice of the base fit: which parameters of the model the
//! log measures (fitted, reported as parameter corrections) and which stay
//! at the model's value, each with the reason the report gives.
//!
//! Why a file of its own: the reasons a parameter is not measured
//! (aliasing, a span too short, a constant temperature, a geometry that
//! cannot separate it, an effect on a handful of points, no held-out
//! test) are many, and grow apart from the greedy search that uses the
//! result.

use crate::charact::log::MeasurementLog;
use crate::model::{Axis, StageModel};

use super::data;
use super::fit::select_base;
use super::ident::{self, Unidentifiable};
use super::judge::Accepted;
use super::lead;
use super::search::base_columns;
use super::{frame_turned, rotation_column, DiagnoseOptions, FixedParam};

/// `(period, shortest resolvable period)` when parameter `name` belongs to
/// a periodic term (`period_um` in its configuration) along an axis whose
/// sampling cannot resolve that period; `None` otherwise.
pub(super) fn aliased_period(d: &data::Data, model: &StageModel, name: &str) -> Option<(f64, f64)> {
    let (term_name, param) = name.split_once('.')?;
    // Only the periodic parameters (a term's slope is not aliased).
    if !(param.contains("sin") || param.contains("cos")) {
        return None;
    }
    let term = model.terms().iter().find(|t| t.name() == term_name)?;
    let cfg = term.to_config().ok()?;
    let period_um = cfg.get("period_um")?.as_float()?;
    let axis = match cfg.get("axis")?.as_str()? {
        "x" => Axis::X,
        "y" => Axis::Y,
        _ => return None,
    };
    let shortest_um = data::shortest_period_um(d, axis)?;
    (period_um < shortest_um).then_some((period_um, shortest_um))
}

/// The reason a temperature coefficient is held (the start of it).
pub(super) const CONSTANT_TEMPERATURE: &str = "the log's temperature does not change";

/// Why the log cannot identify parameter `name` beyond aliasing, or
/// `None`: a periodic term whose period is more than
/// [`LONGEST_PERIOD_SPANS`] times the log's span of its variable (less
/// than half a period is seen: its sine and cosine are a smooth curve that
/// trades off against every slope, a fitted amplitude means nothing), or a temperature coefficient (unit `…/°C…`) when the
/// log's temperature does not change (the column is then the model's own
/// assumed temperature history, not a measurement).
pub(super) fn unresolved(d: &data::Data, model: &StageModel, name: &str) -> Option<String> {
    let (term_name, param) = name.split_once('.')?;
    let mp = model.params();
    let unit = mp.iter().find(|p| p.full_name == name)?.info.unit;
    if unit.contains("°C") && !d.temp_varies {
        return Some(format!(
            "{CONSTANT_TEMPERATURE}: temperature coefficients cannot be identified"
        ));
    }
    let time_reason = match (d.time_with, &d.time_unusable) {
        (Some((axis, r)), _) => Some(format!(
            "time and {axis} position move together over this log (r = {r:+.3}): a drift cannot be told from an error along {axis}"
        )),
        (None, Some(why)) => Some(why.clone()),
        (None, None) => None,
    };
    if let Some(reason) = time_reason {
        let per_time = unit.contains("/h") || unit.contains("/s");
        let timed = model
            .terms()
            .iter()
            .find(|t| t.name() == term_name)
            .and_then(|t| t.to_config().ok())
            .is_some_and(|c| c.get("period_s").is_some());
        if per_time || timed {
            return Some(reason);
        }
    }
    if !(param.contains("sin") || param.contains("cos")) {
        return None;
    }
    let term = model.terms().iter().find(|t| t.name() == term_name)?;
    if let Some(reason) = lead::held_screw_reason(d, &**term) {
        return Some(reason);
    }
    let cfg = term.to_config().ok()?;
    if let Some(period_s) = cfg.get("period_s").and_then(|v| v.as_float()) {
        let (lo, hi) = d
            .states
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), s| {
                (l.min(s.time_s), h.max(s.time_s))
            });
        let span_s = hi - lo;
        return (period_s > LONGEST_PERIOD_SPANS * span_s).then(|| {
            format!("the log cannot resolve them: period {period_s:.0} s is more than {LONGEST_PERIOD_SPANS}× the {span_s:.0} s it lasts")
        });
    }
    let period_um = cfg.get("period_um")?.as_float()?;
    let axis = match cfg.get("axis")?.as_str()? {
        "x" => Axis::X,
        "y" => Axis::Y,
        _ => return None,
    };
    let span_um = data::span_um(&data::distinct_positions(d, axis));
    (period_um > LONGEST_PERIOD_SPANS * span_um).then(|| {
        format!("the log cannot resolve them: period {period_um:.1} µm is more than {LONGEST_PERIOD_SPANS}× the {span_um:.1} µm of {axis} it spans")
    })
}

/// A periodic base term is fitted up to a period of this many times the
/// log's span of its variable: over half a period its sine and cosine are
/// still a distinct curve (a 5 mm guideway waviness on a 4.2 mm y scan),
/// over less they trade off against every slope.
pub(super) const LONGEST_PERIOD_SPANS: f64 = 2.0;

/// The base fit's parameters. The greedy search changes them: a finding
/// may free a candidate the selection left at the model's value, or make
/// a kept one inseparable from its table.
pub(super) struct Base {
    /// Free parameters, in the order of `cols`.
    pub(super) names: Vec<String>,
    /// Their design columns.
    pub(super) cols: Vec<Vec<f64>>,
    /// Parameters at the model's value, each with the reason the report
    /// gives.
    pub(super) fixed: Vec<FixedParam>,
    /// The held-out selection's candidates, kept so that a later finding
    /// can free one of them.
    pub(super) cand_names: Vec<String>,
    pub(super) cand_cols: Vec<Vec<f64>>,
    /// Candidates the selection left at the model's value: a later finding
    /// that one of them can carry frees it instead.
    pub(super) dropped: Vec<usize>,
}

impl Base {
    /// Frees candidate `j`: a finding showed the log measures it after all.
    pub(super) fn free(&mut self, j: usize) {
        self.cols.push(self.cand_cols[j].clone());
        self.names.push(self.cand_names[j].clone());
        let name = &self.cand_names[j];
        self.fixed.retain(|f| f.name != *name);
        self.dropped.retain(|&k| k != j);
    }

    /// A table with a knot at every target takes any error of its
    /// axis at those targets: a base parameter whose effect it (with
    /// the other base parameters) spans is no longer separable and
    /// stays at the model's value (see `ident`). Fitted as well, the
    /// split between it and the table is arbitrary, and so is its σ.
    pub(super) fn fix_spanned_by(&mut self, d: &data::Data, model: &StageModel, acc: &[Accepted]) {
        let given: Vec<Vec<f64>> = acc.iter().flat_map(|a| a.cols.clone()).collect();
        let (kept, unid) = ident::identifiable_given(d, model, &self.names, &self.cols, &given);
        if kept.len() < self.names.len() {
            for u in unid {
                self.fixed.push(FixedParam {
                    name: u.name.clone(),
                    reason: "the per-target table of a finding spans its effect at the log's targets: not separable from it".into(),
                    aliased: false,
                });
            }
            self.cols = kept.iter().map(|&j| self.cols[j].clone()).collect();
            self.names = kept.iter().map(|&j| self.names[j].clone()).collect();
        }
    }
}

/// Step 2's choice of the base parameters: each parameter of the model
/// is free unless the log cannot measure it or freeing it does not
/// predict held-out data better; the ones left at the model's value say
/// why.
pub(super) fn select_base_params(
    log: &MeasurementLog,
    d: &data::Data,
    model: &StageModel,
    opts: &DiagnoseOptions,
) -> (Base, Vec<Unidentifiable>) {
    let (all_names, all_base) = base_columns(d, model, &opts.base_free_kinds);
    let (mut base_fixed, resolvable) = split_resolvable(d, model, &all_names);
    // Parameters the log's geometry cannot separate from others stay at
    // the model's value; their combination is named (see `ident`).
    let res_names: Vec<String> = resolvable.iter().map(|&j| all_names[j].clone()).collect();
    let res_cols: Vec<Vec<f64>> = resolvable.iter().map(|&j| all_base[j].clone()).collect();
    let held = held_temperature_columns(&base_fixed, &all_names, &all_base);
    drop(all_base);
    let (mut separable, mut unidentifiable) = ident::identifiable(d, model, &res_names, &res_cols);
    if d.grid && frame_turned(log) {
        let res = (&res_names[..], &res_cols[..]);
        fix_frame_rotation(d, model, res, &mut separable, &mut base_fixed);
    }
    for u in &unidentifiable {
        base_fixed.push(FixedParam {
            name: u.name.clone(),
            reason: "the log cannot separate them from other parameters (see `unidentifiable`)"
                .into(),
            aliased: false,
        });
    }
    {
        let kept_names: Vec<String> = separable.iter().map(|&j| res_names[j].clone()).collect();
        let kept_cols: Vec<Vec<f64>> = separable.iter().map(|&j| res_cols[j].clone()).collect();
        unidentifiable.extend(ident::held_along(
            d,
            &held,
            &kept_names,
            &kept_cols,
            "held: the log's temperature does not change",
        ));
    }
    fix_undetermined(
        d,
        model,
        (&res_names, &res_cols),
        &mut separable,
        &mut base_fixed,
    );
    let (testable, untestable): (Vec<usize>, Vec<usize>) = separable
        .iter()
        .partition(|&&j| testable_in_every_fold(d, &res_cols[j]));
    for &j in &untestable {
        base_fixed.push(FixedParam {
            name: res_names[j].clone(),
            reason: "no held-out test can judge them: on the training rows of a fold their effect does not vary (it lies in the held-out part alone)".into(),
            aliased: false,
        });
    }
    let cand_names: Vec<String> = testable.iter().map(|&j| res_names[j].clone()).collect();
    let cand_cols: Vec<Vec<f64>> = testable.iter().map(|&j| res_cols[j].clone()).collect();
    drop(res_cols);
    let base = select_candidates(d, cand_names, cand_cols, base_fixed);
    (base, unidentifiable)
}

/// Splits the base parameters into those the log's sampling resolves
/// (their indices) and those it does not (at the model's value). A
/// periodic base term whose period the log's sampling cannot resolve is
/// aliased: fitting it would turn it into an arbitrary per-target
/// correction.
fn split_resolvable(
    d: &data::Data,
    model: &StageModel,
    all_names: &[String],
) -> (Vec<FixedParam>, Vec<usize>) {
    let mut base_fixed: Vec<FixedParam> = Vec::new();
    let mut resolvable: Vec<usize> = Vec::new();
    for (j, name) in all_names.iter().enumerate() {
        if let Some((period_um, shortest_um)) = aliased_period(d, model, name) {
            base_fixed.push(FixedParam {
                name: name.clone(),
                reason: format!(
                    "the log cannot resolve them: period {period_um:.1} µm is shorter than the {shortest_um:.1} µm its spacing resolves (aliased); sampling at ≤ {:.1} µm, or a dense segment at that step, resolves it",
                    crate::model::sampling::resolving_step_um(period_um)
                ),
                aliased: true,
            });
        } else if let Some(reason) = unresolved(d, model, name) {
            base_fixed.push(FixedParam {
                name: name.clone(),
                reason,
                aliased: false,
            });
        } else {
            resolvable.push(j);
        }
    }
    (base_fixed, resolvable)
}

/// Temperature coefficients held at a constant temperature, with their
/// columns: some may still act along a kept parameter, and the report
/// names those (`ident::held_along`).
fn held_temperature_columns(
    base_fixed: &[FixedParam],
    all_names: &[String],
    all_base: &[Vec<f64>],
) -> Vec<(String, Vec<f64>)> {
    base_fixed
        .iter()
        .filter(|f| f.reason.starts_with(CONSTANT_TEMPERATURE))
        .filter_map(|f| {
            let j = all_names.iter().position(|n| *n == f.name)?;
            Some((f.name.clone(), all_base[j].clone()))
        })
        .collect()
}

/// On a map from an outside instrument, a slope of the y error along x
/// is the measuring frame's rotation as much as the stage's (the frame
/// was turned to make it zero, see `diagnose`): a parameter whose
/// column the rotation and the parameters before it span is not
/// measured by the log. `res` holds the names and columns `separable`
/// indexes.
fn fix_frame_rotation(
    d: &data::Data,
    model: &StageModel,
    (res_names, res_cols): (&[String], &[Vec<f64>]),
    separable: &mut Vec<usize>,
    base_fixed: &mut Vec<FixedParam>,
) {
    let rot = rotation_column(d);
    let (with_rot, _) =
        ident::identifiable_given(d, model, res_names, res_cols, std::slice::from_ref(&rot));
    separable.retain(|j| {
        let kept = with_rot.contains(j);
        if !kept {
            base_fixed.push(FixedParam {
                name: res_names[*j].clone(),
                reason: "not determined by this log: in-plane readings cannot tell it from a rotation of the measuring frame (the frame is fixed by taking the stage's x axis as the reference)".into(),
                aliased: false,
            });
        }
        kept
    });
}

/// A parameter the training rows of some fold do not vary (its effect
/// lies in the held-out cycle or chunk alone, e.g. the forward screw
/// harmonics of a log with four forward points in its first chunk)
/// is fitted from a handful of points no held-out row ever tests.
/// Likewise a parameter whose effect lies on a handful of points (the
/// play of an axis that only ever moves forward, seen at the log's
/// first point alone): a fit to those points, not a measurement. Both
/// leave `separable` for `base_fixed`; `res` holds the names and
/// columns `separable` indexes.
fn fix_undetermined(
    d: &data::Data,
    model: &StageModel,
    (res_names, res_cols): (&[String], &[Vec<f64>]),
    separable: &mut Vec<usize>,
    base_fixed: &mut Vec<FixedParam>,
) {
    separable.retain(|&j| {
        if let Some(axis) = one_way_play(d, model, &res_names[j]) {
            base_fixed.push(FixedParam {
                name: res_names[j].clone(),
                reason: format!(
                    "not determined by this log: the {axis} axis reaches its points from one side only (fewer than {MIN_EFFECTIVE_POINTS:.0} approaches from the other), so its play is never taken up and let go"
                ),
                aliased: false,
            });
            return false;
        }
        let pts = effective_points(d, &res_cols[j]);
        let enough = pts >= MIN_EFFECTIVE_POINTS;
        if !enough {
            base_fixed.push(FixedParam {
                name: res_names[j].clone(),
                reason: format!(
                    "not determined by this log: its effect lies on about {pts:.0} of the log's points (fewer than {MIN_EFFECTIVE_POINTS:.0})"
                ),
                aliased: false,
            });
        }
        enough
    });
}

/// Model selection on the base fit too: only the candidates whose
/// freeing predicts held-out data better are free (see
/// `fit::select_base`); the others stay at the model's value until a
/// finding frees them.
fn select_candidates(
    d: &data::Data,
    cand_names: Vec<String>,
    cand_cols: Vec<Vec<f64>>,
    mut base_fixed: Vec<FixedParam>,
) -> Base {
    let keep = select_base(d, &cand_names, &cand_cols);
    let base_names: Vec<String> = keep.iter().map(|&j| cand_names[j].clone()).collect();
    base_fixed.extend(
        cand_names
            .iter()
            .enumerate()
            .filter(|(j, _)| !keep.contains(j))
            .map(|(_, n)| FixedParam {
                name: n.clone(),
                reason: "freeing them did not predict held-out data better than the model's values"
                    .into(),
                aliased: false,
            }),
    );
    // The base: the selected parameters, then (in the greedy search)
    // every carrier a finding frees.
    let base0: Vec<Vec<f64>> = keep.iter().map(|&j| cand_cols[j].clone()).collect();
    let dropped: Vec<usize> = (0..cand_names.len())
        .filter(|j| !keep.contains(j))
        .collect();
    Base {
        names: base_names,
        cols: base0,
        fixed: base_fixed,
        cand_names,
        cand_cols,
        dropped,
    }
}

/// Relative spread (standard deviation over the training rows of a fold
/// against that over all rows) below which a base column cannot be
/// fitted from the training rows, see [`testable_in_every_fold`].
const TRAINING_SPREAD: f64 = 1e-3;

/// The axis of a play (`backlash`) parameter whose axis the log
/// approaches from one side only, or `None`.
fn one_way_play(d: &data::Data, model: &StageModel, name: &str) -> Option<Axis> {
    let term = name.split('.').next()?;
    let t = model.terms().iter().find(|t| t.name() == term)?;
    if t.kind() != "backlash" {
        return None;
    }
    let axis = match t.to_config().ok()?.get("axis")?.as_str()? {
        "x" => Axis::X,
        "y" => Axis::Y,
        _ => return None,
    };
    let count = |sign: f64| {
        (0..d.n)
            .filter(|&i| !d.excluded[i] && d.approach[i][axis.index()] == sign)
            .count() as f64
    };
    (count(1.0).min(count(-1.0)) < MIN_EFFECTIVE_POINTS).then_some(axis)
}

/// Points a parameter's effect must spread over to be measured by a log.
const MIN_EFFECTIVE_POINTS: f64 = 8.0;

/// How many of the log's points a base column's effect lies on: the
/// participation ratio `(Σ v²)² / Σ v⁴` of the column centred over the
/// measured components (1 for a single point, the number of points for
/// an even spread).
fn effective_points(d: &data::Data, col: &[f64]) -> f64 {
    let vals: Vec<f64> = (0..d.n)
        .filter(|&i| !d.excluded[i])
        .flat_map(|i| {
            (0..2)
                .filter(|&c| d.measured[c])
                .map(move |c| col[2 * i + c])
        })
        .collect();
    if vals.is_empty() {
        return 0.0;
    }
    let m = vals.iter().sum::<f64>() / vals.len() as f64;
    let (s2, s4) = vals.iter().fold((0.0, 0.0), |(a, b), v| {
        let q = (v - m) * (v - m);
        (a + q, b + q * q)
    });
    if s4 > 0.0 {
        s2 * s2 / s4
    } else {
        0.0
    }
}

/// Whether base column `col` varies over the training rows of every fold
/// (measured components, rows not excluded): a parameter that does not is
/// fitted on the full data from the held-out part alone, where no
/// held-out test can judge it.
fn testable_in_every_fold(d: &data::Data, col: &[f64]) -> bool {
    let spread = |use_row: &dyn Fn(usize) -> bool| -> f64 {
        let vals: Vec<f64> = (0..d.n)
            .filter(|&i| use_row(i) && !d.excluded[i])
            .flat_map(|i| {
                (0..2)
                    .filter(|&c| d.measured[c])
                    .map(move |c| col[2 * i + c])
            })
            .collect();
        if vals.len() < 2 {
            return 0.0;
        }
        let m = vals.iter().sum::<f64>() / vals.len() as f64;
        (vals.iter().map(|v| (v - m).powi(2)).sum::<f64>() / vals.len() as f64).sqrt()
    };
    let all = spread(&|_| true);
    if all <= 0.0 {
        return true;
    }
    (0..d.nfolds).all(|f| spread(&|i| d.fold[i] != f) >= TRAINING_SPREAD * all)
}
