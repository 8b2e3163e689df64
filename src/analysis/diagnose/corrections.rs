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
    if unit == "µrad" {
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
        let sentence = format!(
            "this stage's {} is {f:+.4} ± {s:.4} {u}, the model says {m:+.4}{}",
            what(&p.kind, &p.term, &p.info.name),
            if significant {
                ""
            } else {
                " (the log agrees within 3 σ)"
            }
        );
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
        });
    }
    out
}
