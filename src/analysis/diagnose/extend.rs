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
use super::fit::{determined_variances, fold_base, solve_with_cov, FoldBase};
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

/// [`extended`] plus the standard error of every parameter by full name
/// (linear ones, and the shape parameters of localized and step-size
/// terms, see [`shape_columns`]; a finding's parameter the log does not
/// determine has none).
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
    let (beta, _) = solve_with_cov(&fb.gbb, &fb.rb);
    // Standard errors from the linearization at the reported values, the
    // shape parameters' columns (∂/∂place, ∂/∂width, ∂/∂length) beside
    // the linear ones: every σ, linear or not, from one covariance.
    let shape = shape_columns(d, model, specs, &beta, base_names.len());
    let n_lin = cols.len();
    cols.extend(shape.iter().map(|s| s.col.clone()));
    let (all_se, determined) = standard_errors(d, &cols, shape.is_empty().then_some(fb));
    let se_of = |j: usize| all_se.get(j).copied().unwrap_or(f64::NAN);
    let shape_se = |j: usize| determined.get(j).copied().flatten();
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
        se.insert(name.clone(), se_of(j));
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
        // A finding's coefficient the log does not determine (a column of
        // zeros: a feature between the sampled positions) gets no σ.
        for (m, p) in pn.iter().enumerate() {
            if let Some(e) = shape_se(col + m) {
                se.insert(format!("{name}.{p}"), e);
            }
        }
        col += pn.len();
        term_names.push(name);
    }
    // A shape parameter the log does not determine gets no σ (`withdraw`
    // then withdraws its finding).
    for (j, s) in shape.iter().enumerate() {
        if let (Some(e), Some(term)) = (shape_se(n_lin + j), term_names.get(s.spec)) {
            se.insert(format!("{term}.{}", s.param), e);
        }
    }
    Ok((ext, term_names, se, unmodelled))
}

/// The standard errors of the coefficients of `cols` fitted jointly on
/// all rows (`fit` when it is that fit already): the pseudo-inverse's
/// (`0` along the directions it drops, as the base corrections always
/// had), and the same `None` where the Gram matrix does not determine a
/// coefficient ([`determined_variances`]).
fn standard_errors(
    d: &Data,
    cols: &[Vec<f64>],
    fit: Option<FoldBase>,
) -> (Vec<f64>, Vec<Option<f64>>) {
    let fit = fit.unwrap_or_else(|| fold_base(d, cols, vec![true; d.n]));
    let (_, pdiag) = solve_with_cov(&fit.gbb, &fit.rb);
    let rows = d.n * d.measured.iter().filter(|&&m| m).count();
    let dof = rows.saturating_sub(cols.len()).max(1) as f64;
    let sigma2 = fit.resid.iter().map(|v| v * v).sum::<f64>() / dof;
    let determined = determined_variances(&fit.gbb)
        .into_iter()
        .map(|v| v.map(|v| (sigma2 * v).sqrt()))
        .collect();
    let all = pdiag.iter().map(|v| (sigma2 * v).sqrt()).collect();
    (all, determined)
}

/// The column of one shape parameter of a nonlinear spec: the change of
/// the spec's fitted contribution per unit of the parameter.
struct ShapeColumn {
    /// Index of the spec in the extension's list.
    spec: usize,
    /// The parameter (`position_um`, `width_um`, `length_um`).
    param: &'static str,
    /// `A·∂g/∂θ` (centred like every column), by central difference.
    col: Vec<f64>,
}

/// Relative step of the central differences of [`shape_columns`].
const SHAPE_STEP: f64 = 1e-3;

/// The [`ShapeColumn`]s of `specs` (a localized feature's place and width,
/// a step-size term's length) at the amplitudes `beta` (the linear solve's
/// coefficients, the specs' starting after `n_base` base columns).
///
/// Why: the shape parameters come from the search and its refinement, not
/// from the linear solve; their standard errors are those of the
/// Gauss–Newton linearization at the values reported, in the same centred
/// fit (block constants of static axes profiled out). The model's own
/// Levenberg–Marquardt, used before, iterated to a place of its own
/// (it cannot profile out the block constants) and gave the σ there:
/// 5·10¹³ µm on a step-size length the log determines to 35 %.
fn shape_columns(
    d: &Data,
    model: &StageModel,
    specs: &[Spec],
    beta: &nalgebra::DVector<f64>,
    n_base: usize,
) -> Vec<ShapeColumn> {
    let mut out = Vec::new();
    let mut col = n_base;
    for (k, spec) in specs.iter().enumerate() {
        let amp = beta.get(col).copied().unwrap_or(0.0);
        col += spec_param_names(spec, model).len();
        let params: &[(&'static str, f64)] = match *spec {
            Spec::Localized { width_um, .. } => {
                &[("position_um", width_um), ("width_um", width_um)]
            }
            Spec::StepSize { length_um, .. } => &[("length_um", length_um)],
            _ => continue,
        };
        for &(param, scale) in params {
            let h = SHAPE_STEP * scale;
            let (Some(plus), Some(minus)) = (shifted(spec, param, h), shifted(spec, param, -h))
            else {
                continue;
            };
            let (plus, minus) = (columns(&plus, d, model), columns(&minus, d, model));
            let (Some(p), Some(m)) = (plus.first(), minus.first()) else {
                continue;
            };
            let c = p
                .iter()
                .zip(m)
                .map(|(a, b)| amp * (a - b) / (2.0 * h))
                .collect();
            out.push(ShapeColumn {
                spec: k,
                param,
                col: c,
            });
        }
    }
    out
}

/// `spec` with its shape parameter `param` moved by `delta`, or `None`
/// for a step that is zero or not finite, or a parameter the spec does
/// not have.
fn shifted(spec: &Spec, param: &str, delta: f64) -> Option<Spec> {
    if !(delta.is_finite() && delta != 0.0) {
        return None;
    }
    let mut s = spec.clone();
    match (&mut s, param) {
        (Spec::Localized { position_um, .. }, "position_um") => *position_um += delta,
        (Spec::Localized { width_um, .. }, "width_um") => *width_um += delta,
        (Spec::StepSize { length_um, .. }, "length_um") => *length_um += delta,
        _ => return None,
    }
    Some(s)
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
