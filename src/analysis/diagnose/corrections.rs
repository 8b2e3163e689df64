//! Parameter corrections: what the base fit says about the parameters the
//! model already has (this stage's squareness, scale, play, cyclic tables,
//! thermal terms), apart from the findings (structure the model lacks).
//!
//! Why a file of its own: a stage that is merely *another* stage of the
//! same design differs from the model in its values, not its structure.
//! Reporting those differences as findings would use up the findings cap
//! with the model's own defaults coming back; here they are stated as
//! corrections with a standard error and a sentence, and only the search
//! for missing structure produces findings.

use std::collections::HashMap;

use serde::Serialize;

use crate::model::StageModel;

/// A correction is called significant when the fitted value differs from
/// the model's by at least this many standard errors.
pub const SIGNIFICANT_SIGMAS: f64 = 3.0;

/// One parameter of the model as the log measured it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ParamCorrection {
    /// Term name (e.g. `squareness`).
    pub term: String,
    /// Term kind (e.g. `squareness`, `lead_error`).
    pub kind: String,
    /// Parameter name within the term (e.g. `angle_urad`).
    pub parameter: String,
    /// Unit of the values (the parameter's own, e.g. `µrad`, `ppm`, `µm`).
    pub unit: String,
    /// The model's value.
    pub model_value: f64,
    /// The value the log gives (base fit jointly with the findings).
    pub fitted_value: f64,
    /// 1-σ standard error of `fitted_value` (from the residual scatter).
    pub std_error: f64,
    /// `|fitted − model| ≥ SIGNIFICANT_SIGMAS·σ`: the log refutes the
    /// model's value.
    pub significant: bool,
    /// A sentence a person understands.
    pub sentence: String,
    /// What the log measures in all, in `unit`: the fitted value plus what
    /// the parameters it cannot be told from contribute at the model's
    /// values (`None`: the fitted value is what the log measures).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub total_value: Option<f64>,
}

/// What a term kind's parameter is, for the sentence.
fn what(kind: &str, term: &str, parameter: &str) -> String {
    let label = match kind {
        "squareness" => "squareness".to_string(),
        "lead_error" => "scale (lead error)".to_string(),
        "backlash" => "play (backlash)".to_string(),
        "leadscrew_cyclic" => "screw cyclic error".to_string(),
        "cross_coupling" => "cross-axis cyclic coupling".to_string(),
        "thermal_expansion" => "thermal expansion".to_string(),
        "optics_drift" => "optics thermal drift".to_string(),
        "angular" => "angular error motion".to_string(),
        "time_drift" => "drift with time".to_string(),
        other => other.replace('_', " "),
    };
    format!("{label} `{term}.{parameter}`")
}

/// Value and unit for people: µrad beyond ±1000 as mrad.
fn shown(v: f64, unit: &str) -> (f64, String) {
    if unit == "µrad" && v.abs() >= 1000.0 {
        (v / 1000.0, "mrad".to_string())
    } else {
        (v, unit.to_string())
    }
}

/// The corrections of the freed base parameters: model values from
/// `model`, fitted values from `fitted`, standard errors by full name.
pub(super) fn corrections(
    model: &StageModel,
    fitted: &StageModel,
    free: &[String],
    std_errs: &HashMap<String, f64>,
    synthetic_time: bool,
) -> Vec<ParamCorrection> {
    let params = model.params();
    let mut out = Vec::new();
    for name in free {
        let Some(p) = params.iter().find(|p| &p.full_name == name) else {
            continue;
        };
        let Ok(fv) = fitted.param(name) else {
            continue;
        };
        let mv = p.info.value;
        let se = std_errs.get(name).copied().unwrap_or(f64::NAN);
        let significant = se.is_finite() && (fv - mv).abs() >= SIGNIFICANT_SIGMAS * se;
        let unit = p.info.unit;
        let big = unit == "µrad" && (fv.abs().max(mv.abs()) >= 1000.0);
        let (f, u) = if big {
            shown(fv, unit)
        } else {
            (fv, unit.into())
        };
        let (m, _) = if big {
            shown(mv, unit)
        } else {
            (mv, unit.into())
        };
        let s = if big { se / 1000.0 } else { se };
        let mut sentence = format!(
            "this stage's {} is {f:+.4} ± {s:.4} {u}, the model says {m:+.4}{}",
            what(&p.kind, &p.term, &p.info.name),
            if significant {
                ""
            } else {
                " (the log agrees within 3 σ)"
            }
        );
        // A rate against synthetic times is a rate per record.
        if synthetic_time && unit.ends_with("/h") {
            let per = unit.trim_end_matches("/h");
            sentence.push_str(&format!(
                "; the log's times are synthetic (one record per second), so this is {:+.4} ± {:.4} {per} per record, in the order the records were measured, not per hour",
                fv / 3600.0,
                se / 3600.0
            ));
        }
        out.push(ParamCorrection {
            term: p.term.clone(),
            kind: p.kind.clone(),
            parameter: p.info.name.clone(),
            unit: unit.to_string(),
            model_value: mv,
            fitted_value: fv,
            std_error: se,
            significant,
            sentence,
            total_value: None,
        });
    }
    out
}

/// Says, in the sentence of a play fitted jointly with a reversal table on
/// its axis, what that play is: the lost motion at the table's first knot
/// (where the table is zero, unless the fit wanted the play below zero and
/// the table holds the rest: the sentence follows the table's value
/// there), not the axis's lost motion in general, which the table gives
/// along the travel.
///
/// Why: a reader compares the play with the replicates' mean reversal;
/// on a stage whose lost motion changes sign along the travel the two
/// differ by tens of µm and agree only once this is said.
pub(super) fn note_tables(
    parameters: &mut [ParamCorrection],
    findings: &[super::Finding],
    model: &StageModel,
) {
    for f in findings {
        if f.kind == crate::analysis::FindingKind::Nonlinearity {
            note_chord(parameters, f, model);
            continue;
        }
        if f.kind != crate::analysis::FindingKind::ReversalVaries {
            continue;
        }
        let Some(t) = super::search::backlash_term_of(model, f.axis) else {
            continue;
        };
        let Some(p) = parameters
            .iter_mut()
            .find(|p| p.term == t.name() && p.parameter == "backlash_um")
        else {
            continue;
        };
        let knots: Vec<(f64, f64)> = (0..)
            .map_while(|k| {
                Some((
                    *f.params.get(&format!("knot{k}_um"))?,
                    *f.params.get(&format!("value{k}_um"))?,
                ))
            })
            .collect();
        let Some(&(x0, v0)) = knots.first() else {
            continue;
        };
        let mean = knots.iter().map(|k| k.1).sum::<f64>() / knots.len() as f64;
        // The table's own value at its first knot: zero unless the fit
        // wanted the play below zero (see `describe::first_knot`).
        let table0 = v0 - p.fitted_value;
        let there = if table0.abs() < super::describe::TABLE_ZERO_UM {
            format!("which is zero at its first knot ({x0:.1} µm): this is the lost motion there")
        } else {
            format!(
                "which holds {table0:+.3} µm at its first knot ({x0:.1} µm): the lost motion there is {v0:+.3} µm, this play plus the table{}",
                if table0 < 0.0 && p.fitted_value <= 0.0 {
                    " (a play cannot be negative: the table holds what lies below zero)"
                } else {
                    ""
                }
            )
        };
        p.sentence.push_str(&format!(
            "; fitted jointly with the reversal table `{}`, {there}; the table gives it along the travel (from {:+.3} to {:+.3} µm, mean {mean:+.3} µm over its {} knots)",
            f.term,
            knots.iter().map(|k| k.1).fold(f64::INFINITY, f64::min),
            knots.iter().map(|k| k.1).fold(f64::NEG_INFINITY, f64::max),
            knots.len()
        ));
    }
}

/// Says, in the sentence of an axis's scale fitted jointly with a
/// nonlinearity table along it, what that scale is.
///
/// Why: the table is zero at its end knots, so the scale is the chord
/// through the errors at the two ends, not the least-squares slope of the
/// log: on a real ISO 230-2 log (5 targets) the chord said +711 ppm where
/// the targets' least-squares slope is +315 ppm, a figure a metrologist
/// would take for the stage's scale (the least-squares scale follows, see
/// [`note_model_scale`]).
fn note_chord(parameters: &mut [ParamCorrection], f: &super::Finding, model: &StageModel) {
    if f.axis != f.component {
        return;
    }
    let axis = f.axis.to_string();
    let Some(p) = parameters
        .iter_mut()
        .find(|p| p.kind == "lead_error" && axis_of(model, &p.term).as_deref() == Some(&axis))
    else {
        return;
    };
    p.sentence.push_str(&format!(
        "; with the nonlinearity table `{}` on this axis (zero at its end knots) this is the chord through the errors at its two ends",
        f.term
    ));
}

/// The `axis` of term `term` in `model`'s configuration.
fn axis_of(model: &StageModel, term: &str) -> Option<String> {
    model
        .terms()
        .iter()
        .find(|t| t.name() == term)
        .and_then(|t| t.to_config().ok())
        .and_then(|c| c.get("axis").and_then(|a| a.as_str().map(str::to_owned)))
}

/// Adds to each measured axis's scale sentence the least-squares scale of
/// the fitted model's error (`observed`, the fitted model's position at
/// each of `states`) along that axis at the log's points: all its
/// terms together (the lead, Abbe slopes and thermal scale held at the
/// model's values, cyclic harmonics over a span of about one period,
/// tables), so the figure does not depend on how the model splits it.
///
/// Why: a split the log cannot make still printed a "scale in all" that
/// was not the log's: +7576 ± 574 ppm on a flexure scan whose own slope is
/// +21 600 ppm (the rest in 400 µm screw harmonics over a 450 µm span),
/// +711 ppm beside a nonlinearity table on a log whose slope is +315 ppm.
pub(super) fn note_model_scale(
    parameters: &mut [ParamCorrection],
    fitted: &StageModel,
    states: &[crate::model::MotionState],
    observed: &[crate::model::XyUm],
    measured: [bool; 2],
) {
    for p in parameters.iter_mut().filter(|p| p.kind == "lead_error") {
        let axis = match axis_of(fitted, &p.term).as_deref() {
            Some("x") => crate::model::Axis::X,
            Some("y") => crate::model::Axis::Y,
            _ => continue,
        };
        let c = axis.index();
        if !measured[c] || states.len() < 3 {
            continue;
        }
        let pts: Vec<(f64, f64)> = states
            .iter()
            .zip(observed)
            .map(|(s, o)| {
                let cmd = s.cmd_um(axis);
                (cmd, if c == 0 { o.x_um } else { o.y_um } - cmd)
            })
            .collect();
        let Some(ppm) = slope_ppm(&pts) else {
            continue;
        };
        p.sentence.push_str(&format!(
            "; the fitted model, all its terms together, puts a least-squares scale of {ppm:+.1} ppm on {axis}'s error along {axis} at the log's points: the scale this log measures"
        ));
    }
}

/// Least-squares slope of `(position µm, error µm)` pairs, ppm.
fn slope_ppm(pts: &[(f64, f64)]) -> Option<f64> {
    let n = pts.len() as f64;
    let (mx, my) = (
        pts.iter().map(|p| p.0).sum::<f64>() / n,
        pts.iter().map(|p| p.1).sum::<f64>() / n,
    );
    let sxx: f64 = pts.iter().map(|p| (p.0 - mx).powi(2)).sum();
    let v = 1e6 * pts.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum::<f64>() / sxx;
    v.is_finite().then_some(v)
}

/// Restates a correction that the log measures only together with
/// parameters it cannot separate from it (held at the model's values):
/// the fitted value is then the model's split, not the stage's, and what
/// the log measures is the total `fitted + Σ coef·value` of the held
/// ones, in the kept parameter's unit.
///
/// Why: on an XY map the slope of a carriage's pitch or yaw through its
/// Abbe arm moves the points as the scale does; with the angles held at
/// the model's values the scale absorbs the rest, and "this stage's scale
/// is +215 ppm ± 0.04" would be the model's default restated, where the
/// data measure +1.6 ppm in all.
pub(super) fn with_joint_totals(
    params: &mut [ParamCorrection],
    model: &StageModel,
    unidentifiable: &[super::Unidentifiable],
) {
    let values: HashMap<String, f64> = model
        .params()
        .into_iter()
        .map(|p| (p.full_name, p.info.value))
        .collect();
    for p in params.iter_mut() {
        let full = format!("{}.{}", p.term, p.parameter);
        let mut held = Vec::new();
        let mut total = p.fitted_value;
        for u in unidentifiable {
            if let Some((_, coef)) = u.combination.iter().find(|(n, _)| *n == full) {
                if let Some(v) = values.get(&u.name) {
                    // δ of the held one moves the points as coef·δ of
                    // this one: its model value is coef·value of this.
                    total += coef * v;
                    if v.abs() > 0.0 {
                        held.push(u.name.clone());
                    }
                }
            }
        }
        if held.is_empty() {
            continue;
        }
        p.total_value = Some(total);
        let (t, unit) = shown(total, &p.unit);
        let (f, _) = shown(p.fitted_value, &p.unit);
        let (se, _) = shown(p.std_error, &p.unit);
        p.sentence = format!(
            "{} together with {} (held at the model's values; this log cannot tell them apart) measures {t:+.4} ± {se:.4} {unit} in all; the fitted {f:+.4} {unit} is only the model's split of it",
            what(&p.kind, &p.term, &p.parameter),
            held.join(", ")
        );
    }
}
