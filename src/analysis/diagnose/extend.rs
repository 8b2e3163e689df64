//! Step 7 of the analysis: the accepted candidates turned into model terms
//! (discovered terms, or more play in the model's backlash term), with
//! their linear coefficients and standard errors from the centred
//! full-data solve.
//!
//! Why a file of its own: this is the one place that knows how a candidate
//! maps to a term configuration and parameter names.

use std::collections::HashMap;

use crate::model::terms::{
    BacklashConfig, BacklashTerm, DiscoveredConfig, DiscoveredTerm, LocalizedConfig,
    PositionPeriodicConfig, PositionSlopeConfig, PositionTableConfig, StepSizeConfig,
    TemperatureConfig, TimeDriftConfig, TimePeriodicConfig,
};
use crate::model::{StageModel, DEFAULT_TEMP_C};

use super::data::Data;
use super::fit::{fold_base, solve_with_cov};
use super::search::{backlash_term_of, base_columns, columns, table_free_knots, Spec};
use crate::analysis::AnalysisError;

/// Linear-parameter names of a spec's columns, in column order.
fn spec_param_names(spec: &Spec, model: &StageModel) -> Vec<String> {
    let fixed: &[&str] = match spec {
        Spec::PosPeriodic { .. } | Spec::TimePeriodic { .. } => &["sin_um", "cos_um"],
        Spec::Localized { .. } => &["amplitude_um"],
        Spec::Slope { .. } => &["ppm"],
        Spec::Drift {
            quadratic: true, ..
        } => &["rate_um_per_h", "curvature_um_per_h2"],
        Spec::Drift { .. } => &["rate_um_per_h"],
        Spec::Temperature { .. } => &["um_per_c"],
        Spec::Reversal { .. } => &["backlash_um"],
        Spec::StepSize { .. } => &["amplitude_um"],
        Spec::Other { .. } => &["um_per_unit"],
        Spec::Table {
            axis,
            knots,
            lost_motion,
        } => {
            return table_free_knots(knots.len(), *lost_motion, model, *axis)
                .map(|k| format!("value{k}_um"))
                .collect()
        }
        Spec::Tables { .. } => {
            return spec
                .clone()
                .split()
                .iter()
                .flat_map(|s| spec_param_names(s, model))
                .collect()
        }
    };
    fixed.iter().map(|s| s.to_string()).collect()
}

/// The model extended by `specs`, linear coefficients from the centred
/// full-data solve; also the term names.
pub(super) fn extended(
    d: &Data,
    model: &StageModel,
    base_names: &[String],
    specs: &[Spec],
) -> Result<(StageModel, Vec<String>), AnalysisError> {
    extended_with_se(d, model, base_names, specs).map(|(m, n, _, _)| (m, n))
}

/// Extended model, its new term names, standard errors by full name, and
/// the coefficients of the findings no model term can carry (`other`), by
/// `name.parameter`.
type Extended = (
    StageModel,
    Vec<String>,
    HashMap<String, f64>,
    HashMap<String, f64>,
);

/// [`extended`] plus the standard error of every linear parameter, by full
/// name.
pub(super) fn extended_with_se(
    d: &Data,
    model: &StageModel,
    base_names: &[String],
    specs: &[Spec],
) -> Result<Extended, AnalysisError> {
    let (all_names, all_cols) = base_columns(d, model, &base_kinds_of(model, base_names));
    // The selected base parameters only (the base fit's model selection
    // may have kept some at the model's value).
    let mut cols: Vec<Vec<f64>> = Vec::with_capacity(base_names.len());
    for name in base_names {
        let Some(j) = all_names.iter().position(|n| n == name) else {
            return Err(AnalysisError::Invalid(format!(
                "base parameter {name} has no column"
            )));
        };
        cols.push(all_cols[j].clone());
    }
    for s in specs {
        cols.extend(columns(s, d, model));
    }
    let fb = fold_base(d, &cols, vec![true; d.n]);
    let (beta, pdiag) = solve_with_cov(&fb.gbb, &fb.rb);
    let rows = d.n * d.measured.iter().filter(|&&m| m).count();
    let dof = rows.saturating_sub(cols.len()).max(1) as f64;
    let sigma2 = fb.resid.iter().map(|v| v * v).sum::<f64>() / dof;
    let mut se: HashMap<String, f64> = HashMap::new();
    let mut ext = model.clone();
    // A play the fit wants below zero, by backlash term: a lost-motion
    // table on the same axis takes it over (its values are relative to the
    // play, see `search::table_free_knots`).
    let mut play_deficit: HashMap<String, f64> = HashMap::new();
    for (j, name) in base_names.iter().enumerate() {
        let mut v = ext.param(name)? + beta[j];
        // Play cannot be negative (the fit's linear step can overshoot).
        if let Some(term) = name.strip_suffix(".backlash_um") {
            if v < 0.0 {
                play_deficit.insert(term.to_string(), v);
            }
            v = v.max(0.0);
        }
        ext.set_param(name, v)?;
        se.insert(name.clone(), (sigma2 * pdiag[j]).sqrt());
    }
    let mut col = base_names.len();
    let mut term_names = Vec::new();
    let mut unmodelled = HashMap::new();
    for (k, spec) in specs.iter().enumerate() {
        let pn = spec_param_names(spec, model);
        let coef: Vec<f64> = (col..col + pn.len()).map(|j| beta[j]).collect();
        let name = if let Spec::Other { comp, var } = *spec {
            // Fitted jointly, but no model term: the model has no input for
            // a log column (see the module docs).
            let vname = d.extra.get(var).map_or("?", |x| x.name.as_str());
            let name = format!("unmodelled{}_{comp}_vs_{vname}", k + 1);
            for (m, p) in pn.iter().enumerate() {
                unmodelled.insert(format!("{name}.{p}"), coef[m]);
            }
            name
        } else {
            let shift = match spec {
                Spec::Table {
                    axis,
                    lost_motion: true,
                    ..
                } => backlash_term_of(model, *axis)
                    .and_then(|t| play_deficit.get(t.name()).copied())
                    .unwrap_or(0.0),
                _ => 0.0,
            };
            add_term(&mut ext, model, spec, &coef, shift, k + 1, d.t0)?
        };
        for (m, p) in pn.iter().enumerate() {
            se.insert(format!("{name}.{p}"), (sigma2 * pdiag[col + m]).sqrt());
        }
        col += pn.len();
        term_names.push(name);
    }
    Ok((ext, term_names, se, unmodelled))
}

/// The term kinds owning `names` (to rebuild the same base columns).
fn base_kinds_of(model: &StageModel, names: &[String]) -> Vec<String> {
    let mut kinds: Vec<String> = model
        .params()
        .into_iter()
        .filter(|p| names.contains(&p.full_name))
        .map(|p| p.kind)
        .collect();
    kinds.sort();
    kinds.dedup();
    kinds
}

/// Adds the term for an accepted candidate; returns its name.
/// `shift_um` is added to every value of a lost-motion table: the part of
/// the lost motion a play (which cannot be negative) could not take.
fn add_term(
    m: &mut StageModel,
    original: &StageModel,
    spec: &Spec,
    coef: &[f64],
    shift_um: f64,
    k: usize,
    t0: f64,
) -> Result<String, AnalysisError> {
    let c0 = coef.first().copied().unwrap_or(0.0);
    let c1 = coef.get(1).copied().unwrap_or(0.0);
    let (name, cfg) = match *spec {
        Spec::PosPeriodic {
            axis,
            comp,
            period_um,
        } => (
            format!("found{k}_{comp}_periodic_in_{axis}"),
            DiscoveredConfig::PositionPeriodic(PositionPeriodicConfig {
                axis,
                component: comp,
                period_um,
                sin_um: c0,
                cos_um: c1,
            }),
        ),
        Spec::Localized {
            axis,
            comp,
            position_um,
            width_um,
        } => (
            format!("found{k}_{comp}_localized_in_{axis}"),
            DiscoveredConfig::Localized(LocalizedConfig {
                axis,
                component: comp,
                position_um,
                width_um,
                amplitude_um: c0,
            }),
        ),
        Spec::Slope { axis, comp } => (
            format!("found{k}_{comp}_slope_in_{axis}"),
            DiscoveredConfig::PositionSlope(PositionSlopeConfig {
                axis,
                component: comp,
                ppm: c0,
            }),
        ),
        Spec::Drift { comp, .. } => (
            format!("found{k}_{comp}_time_drift"),
            DiscoveredConfig::TimeDrift(TimeDriftConfig {
                component: comp,
                start_time_s: t0,
                rate_um_per_h: c0,
                curvature_um_per_h2: c1,
            }),
        ),
        Spec::TimePeriodic { comp, period_s } => (
            format!("found{k}_{comp}_time_periodic"),
            DiscoveredConfig::TimePeriodic(TimePeriodicConfig {
                component: comp,
                period_s,
                sin_um: c0,
                cos_um: c1,
            }),
        ),
        Spec::Temperature { comp } => (
            format!("found{k}_{comp}_temperature"),
            DiscoveredConfig::Temperature(TemperatureConfig {
                component: comp,
                reference_temp_c: DEFAULT_TEMP_C,
                um_per_c: c0,
            }),
        ),
        Spec::StepSize { axis, length_um } => (
            format!("found{k}_{axis}_step_size"),
            DiscoveredConfig::StepSize(StepSizeConfig {
                axis,
                amplitude_um: c0,
                length_um,
            }),
        ),
        Spec::Table {
            axis,
            ref knots,
            lost_motion,
        } => {
            let mut values_um = vec![if lost_motion { shift_um } else { 0.0 }; knots.len()];
            for (j, k) in table_free_knots(knots.len(), lost_motion, original, axis).enumerate() {
                values_um[k] += coef.get(j).copied().unwrap_or(0.0);
            }
            (
                format!(
                    "found{k}_{axis}_{}_table",
                    if lost_motion {
                        "reversal"
                    } else {
                        "nonlinearity"
                    }
                ),
                DiscoveredConfig::PositionTable(PositionTableConfig {
                    axis,
                    component: axis,
                    positions_um: knots.clone(),
                    values_um,
                    lost_motion,
                }),
            )
        }
        Spec::Tables { .. } => {
            return Err(AnalysisError::Invalid(
                "two tables judged jointly become two terms (split them first)".into(),
            ))
        }
        Spec::Other { comp, .. } => {
            return Err(AnalysisError::Invalid(format!(
                "a dependence of the {comp} error on a log column cannot become a model term (the model has no input for it)"
            )))
        }
        Spec::Reversal { axis } => {
            if let Some(t) = backlash_term_of(m, axis) {
                let name = t.name().to_string();
                let full = format!("{name}.backlash_um");
                let v = (m.param(&full)? + c0).max(0.0);
                m.set_param(&full, v)?;
                return Ok(name);
            }
            let name = format!("found{k}_{axis}_backlash");
            m.push_term(Box::new(BacklashTerm::new(
                &name,
                BacklashConfig {
                    axis,
                    backlash_um: c0.max(0.0),
                },
            )?))?;
            return Ok(name);
        }
    };
    m.push_term(Box::new(DiscoveredTerm::new(&name, cfg)?))?;
    Ok(name)
}
