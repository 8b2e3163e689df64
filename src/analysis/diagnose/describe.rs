//! A finding in words: its parameters (in the finding's own units, model
//! sign), their uncertainty, the sentence a person understands and the
//! likely physical cause.
//!
//! Why a file of its own: the wording is long and changes for reasons of
//! its own (what a lab needs to read), apart from the numerics.

use std::collections::BTreeMap;

use crate::model::{Axis, StageModel};

use super::data::{span_of, typical_move_um, Data};
use super::finding::Finding;
use super::fit::Verdict;
use super::search::Spec;
use crate::analysis::{AnalysisError, FindingKind};

#[allow(clippy::too_many_arguments)]
pub(super) fn describe(
    spec: &Spec,
    v: &Verdict,
    term: &str,
    fitted: &StageModel,
    original: &StageModel,
    std_err: &dyn Fn(&str) -> Option<f64>,
    unmodelled_value: &dyn Fn(&str) -> Option<f64>,
    d: &Data,
) -> Result<Finding, AnalysisError> {
    let p = |k: &str| fitted.param(&format!("{term}.{k}"));
    let se = |k: &str| std_err(&format!("{term}.{k}"));
    let mut params = BTreeMap::new();
    let mut unc = BTreeMap::new();
    let mut shape = None;
    let mut variable = None;
    let mut in_model = true;
    let (kind, axis, comp, explanation, cause);
    match *spec {
        Spec::PosPeriodic {
            axis: a,
            comp: c,
            period_um,
        } => {
            let (s, co) = (p("sin_um")?, p("cos_um")?);
            let amp = s.hypot(co);
            params.insert("period_um".into(), period_um);
            params.insert("amplitude_um".into(), amp);
            params.insert("phase_deg".into(), co.atan2(s).to_degrees());
            if let (Some(es), Some(ec)) = (se("sin_um"), se("cos_um")) {
                let ea = ((s * es).powi(2) + (co * ec).powi(2)).sqrt() / amp.max(1e-12);
                unc.insert("amplitude_um".into(), ea);
                // Period precision of a sinusoid fit: √6·σ/(π·A·span·√N)·P².
                let span = span_of(d, a);
                let noise = v.rms_after;
                let nn = d.n as f64;
                unc.insert(
                    "period_um".into(),
                    6f64.sqrt() * noise
                        / (std::f64::consts::PI * amp.max(1e-12) * span * nn.sqrt())
                        * period_um
                        * period_um,
                );
            }
            let screw = nearest_screw_multiple(fitted, a, period_um);
            kind = FindingKind::PositionPeriodic;
            axis = a;
            comp = c;
            explanation = format!(
                "{c} error repeats every {:.3} mm of {a} travel, amplitude {amp:.3} µm{}",
                period_um / 1000.0,
                screw
            );
            cause = if a == c {
                "a periodic error at a period the model lacks: a bearing, gear or motor-step period, or a periodic error of the pattern".into()
            } else {
                "guideway waviness or a periodic wobble of the carriage seen across the axis".into()
            };
        }
        Spec::Localized {
            axis: a, comp: c, ..
        } => {
            for k in ["position_um", "width_um", "amplitude_um"] {
                params.insert(k.into(), p(k)?);
                if let Some(e) = se(k) {
                    unc.insert(k.into(), e);
                }
            }
            kind = FindingKind::Localized;
            axis = a;
            comp = c;
            explanation = format!(
                "{c} error has a local {} of {:.3} µm around {a} = {:.1} µm (σ {:.0} µm)",
                if params["amplitude_um"] >= 0.0 {
                    "bump"
                } else {
                    "dip"
                },
                params["amplitude_um"].abs(),
                params["position_um"],
                params["width_um"]
            );
            cause = "a local defect: damaged screw thread, dent or debris on the guideway, or a defect of the pattern at that place".into();
        }
        Spec::Slope { axis: a, comp: c } => {
            let ppm = p("ppm")?;
            if a == c {
                params.insert("ppm".into(), ppm);
                if let Some(e) = se("ppm") {
                    unc.insert("ppm".into(), e);
                }
                kind = FindingKind::Scale;
                explanation = format!(
                    "{c} error grows linearly with {a}: {ppm:+.1} ppm beyond the model's scale ({:+.3} µm over 10 mm)",
                    ppm * 1e-2
                );
                cause = "lead error of the screw differs from the model, a wrong counts-per-unit setting, or the pattern's scale (its thermal expansion)".into();
            } else {
                params.insert("slope_urad".into(), ppm);
                if let Some(e) = se("ppm") {
                    unc.insert("slope_urad".into(), e);
                }
                kind = FindingKind::CrossAxis;
                explanation = format!(
                    "{c} error changes with the position of {a}: {ppm:+.1} µrad ({:+.3} µm per 10 mm of {a}) the model does not have",
                    ppm * 1e-2
                );
                cause = "out-of-squareness of the axes (or rotation of the camera/pattern against the stage) different from the model".into();
            }
            axis = a;
            comp = c;
        }
        Spec::Drift { comp: c, quadratic } => {
            let r = p("rate_um_per_h")?;
            params.insert("rate_um_per_h".into(), r);
            if let Some(e) = se("rate_um_per_h") {
                unc.insert("rate_um_per_h".into(), e);
            }
            if quadratic {
                params.insert("curvature_um_per_h2".into(), p("curvature_um_per_h2")?);
                if let Some(e) = se("curvature_um_per_h2") {
                    unc.insert("curvature_um_per_h2".into(), e);
                }
            }
            shape = Some(if quadratic { "quadratic" } else { "linear" }.to_string());
            kind = FindingKind::TimeDrift;
            axis = c;
            comp = c;
            explanation = format!(
                "{c} error drifts with time at {r:+.3} µm/h{} independently of position and temperature",
                if quadratic { " (curving)" } else { "" }
            );
            cause = "slow thermal drift of stage or microscope not explained by the logged temperature, creep, or a drifting camera mount".into();
        }
        Spec::TimePeriodic { comp: c, period_s } => {
            let (s, co) = (p("sin_um")?, p("cos_um")?);
            let amp = s.hypot(co);
            params.insert("period_s".into(), period_s);
            params.insert("amplitude_um".into(), amp);
            if let (Some(es), Some(ec)) = (se("sin_um"), se("cos_um")) {
                unc.insert(
                    "amplitude_um".into(),
                    ((s * es).powi(2) + (co * ec).powi(2)).sqrt() / amp.max(1e-12),
                );
            }
            kind = FindingKind::TimePeriodic;
            axis = c;
            comp = c;
            explanation = format!(
                "{c} error oscillates in time every {:.1} min, amplitude {amp:.3} µm",
                period_s / 60.0
            );
            cause =
                "an air-conditioning or heater cycle, or another periodic disturbance of the room"
                    .into();
        }
        Spec::Temperature { comp: c } => {
            let k = p("um_per_c")?;
            params.insert("um_per_c".into(), k);
            if let Some(e) = se("um_per_c") {
                unc.insert("um_per_c".into(), e);
            }
            kind = FindingKind::Temperature;
            axis = c;
            comp = c;
            explanation = format!(
                "{c} error follows the logged temperature: {k:+.3} µm/°C beyond the model's thermal terms"
            );
            cause = "thermal expansion or drift of stage, mount or microscope larger than the model says".into();
        }
        Spec::Reversal { axis: a } => {
            let v0 = reversal_value(original, fitted, term)?;
            params.insert("value_um".into(), v0);
            if let Some(e) = se("backlash_um") {
                unc.insert("value_um".into(), e);
            }
            kind = FindingKind::Reversal;
            axis = a;
            comp = a;
            explanation = format!(
                "{a} lands differently depending on the direction it came from: {:+.3} µm of lost motion on reversal beyond the model's play",
                v0
            );
            cause = "more (or less) play between screw and nut than the model: wear, preload lost, or friction in the guide".into();
        }
        Spec::StepSize { axis: a, .. } => {
            let amp = p("amplitude_um")?;
            let len = p("length_um")?;
            params.insert("amplitude_um".into(), amp);
            params.insert("length_um".into(), len);
            for k in ["amplitude_um", "length_um"] {
                if let Some(e) = se(k) {
                    unc.insert(k.into(), e);
                }
            }
            let typical = typical_move_um(d, a);
            let at_typical = amp * -(-typical / len.max(1e-9)).exp_m1();
            kind = FindingKind::StepSize;
            axis = a;
            comp = a;
            explanation = format!(
                "{a} {} by an amount that depends on the length of the preceding move: {:.3} µm after long moves, building up over about {len:.0} µm of move ({:.3} µm after the log's typical {typical:.0} µm move)",
                if amp >= 0.0 {
                    "falls short of its target (lost motion)"
                } else {
                    "overshoots its target"
                },
                amp.abs(),
                at_typical.abs()
            );
            cause = "elastic wind-up of screw, coupling or nut, or guide friction, that is only fully loaded after a long move (the play of the model depends on the direction only); a nut preload that yields over a travel of about the build-up length".into();
        }
        Spec::Table {
            axis: a,
            ref knots,
            lost_motion,
        } => {
            // The lost motion a table describes is the play plus the
            // table (the play carries its first knot); a non-linearity is
            // the table alone (zero at both ends).
            let play_name = if lost_motion {
                super::search::backlash_term_of(fitted, a)
                    .map(|t| format!("{}.backlash_um", t.name()))
            } else {
                None
            };
            let play = play_name
                .as_ref()
                .and_then(|n| fitted.param(n).ok())
                .unwrap_or(0.0);
            let mut vals = Vec::with_capacity(knots.len());
            for (k, &pos) in knots.iter().enumerate() {
                let v = p(&format!("value{k}_um"))? + play;
                params.insert(format!("knot{k}_um"), pos);
                params.insert(format!("value{k}_um"), v);
                // A knot the table holds at zero is the play there (its
                // uncertainty the play's, when the log measured it).
                let e = se(&format!("value{k}_um"))
                    .or_else(|| play_name.as_ref().and_then(|n| std_err(n)));
                if let Some(e) = e {
                    unc.insert(format!("value{k}_um"), e);
                }
                vals.push((pos, v));
            }
            let span = knots.last().copied().unwrap_or(0.0) - knots.first().copied().unwrap_or(0.0);
            let at = |x: f64| -> String {
                if span >= 10_000.0 {
                    format!("{:.1} mm", x / 1e3)
                } else {
                    format!("{x:.1} µm")
                }
            };
            let first = *vals
                .first()
                .ok_or_else(|| AnalysisError::Invalid("a table without knots".into()))?;
            let (lo, hi) = vals.iter().fold((first, first), |(lo, hi), v| {
                (
                    if v.1 < lo.1 { *v } else { lo },
                    if v.1 > hi.1 { *v } else { hi },
                )
            });
            axis = a;
            comp = a;
            if lost_motion {
                kind = FindingKind::ReversalVaries;
                explanation = format!(
                    "{a}'s lost motion on reversal changes along the travel, from {:+.3} µm at {} to {:+.3} µm at {} (a reversal table at {} knots, linear between them). Lost motion T = the model's play + the table, > 0 when the platform trails the command in both directions (the model's error is −½·T when arriving forward, +½·T backward), so T = −B in ISO 230-2's sign (B = x̄↑ − x̄↓, measured − target): {}{}",
                    lo.1,
                    at(lo.0),
                    hi.1,
                    at(hi.0),
                    knots.len(),
                    vals.iter()
                        .map(|(x, v)| format!("{v:+.3} µm at {}", at(*x)))
                        .collect::<Vec<_>>()
                        .join(", "),
                    first_knot(&at(first.0), first.1, first.1 - play, play, play_name.as_deref())
                );
                cause = "nut preload or wear that varies along the screw, a bent screw or misaligned coupling whose wind-up changes with position, or guide friction that varies; one constant play cannot follow it".into();
            } else {
                kind = FindingKind::Nonlinearity;
                let k = (0..vals.len())
                    .max_by(|&i, &j| vals[i].1.abs().total_cmp(&vals[j].1.abs()))
                    .unwrap_or(0);
                explanation = format!(
                    "{a}'s error departs from the straight line through the table's end knots by up to {:+.3} µm (at {}; a table at {} knots, linear between them, zero at both ends: the offset and the slope are the base fit's; model sign, measured − command): {}",
                    vals[k].1,
                    at(vals[k].0),
                    knots.len(),
                    vals.iter()
                        .map(|(x, v)| format!("{v:+.3} µm at {}", at(*x)))
                        .collect::<Vec<_>>()
                        .join(", ")
                );
                cause = "progressive pitch error of the screw, a worn or bent section, or guide straightness seen through an Abbe offset".into();
            }
        }
        Spec::Tables { .. } => {
            return Err(AnalysisError::Invalid(
                "two tables judged jointly are described one by one".into(),
            ))
        }
        Spec::Other { comp: c, var } => {
            let x = d
                .extra
                .get(var)
                .ok_or_else(|| AnalysisError::Invalid(format!("extra column {var} vanished")))?;
            let k = unmodelled_value(&format!("{term}.um_per_unit")).ok_or_else(|| {
                AnalysisError::Invalid(format!("no coefficient for `{}`", x.name))
            })?;
            params.insert("um_per_unit".into(), k);
            if let Some(e) = se("um_per_unit") {
                unc.insert("um_per_unit".into(), e);
            }
            params.insert("variable_min".into(), x.min);
            params.insert("variable_max".into(), x.max);
            kind = FindingKind::Other;
            axis = c;
            comp = c;
            explanation = format!(
                "{c} error follows the log column `{}`: {k:+.4} µm per unit ({:.3} µm over its logged range {} … {}); the model has no input for this column, so the extended model does not include it (its simulation and compensation still miss this error)",
                x.name,
                (k * (x.max - x.min)).abs(),
                x.min,
                x.max
            );
            cause = format!(
                "whatever `{}` measures (or something that varies with it) moves the platform or the camera: humidity, motor current or load, air pressure; log and control that quantity, or model it outside the stage model",
                x.name
            );
            variable = Some(x.name.clone());
            in_model = false;
        }
    }
    Ok(Finding {
        kind,
        axis,
        component: comp,
        params,
        uncertainty: unc,
        shape,
        significance: v.z,
        heldout_rms_before_um: v.rms_before,
        heldout_rms_after_um: v.rms_after,
        gain_pct: v.gain_pct,
        explanation,
        cause,
        term: if in_model {
            term.to_string()
        } else {
            String::new()
        },
        variable,
        in_extended_model: in_model,
    })
}

/// Below this (µm) a reversal table's own value at its first knot reads
/// as zero: half the last digit the report prints values with.
pub(super) const TABLE_ZERO_UM: f64 = 5e-5;

/// The end of a reversal table's sentence: what the lost motion `t_um` at
/// its first knot (at `at`) is made of, `t = play + table`, worded after
/// the numbers (the table's own value there is `table_um`).
///
/// Why from the numbers: the table is held at zero at its first knot only
/// when the model has a play for the axis and the fit leaves that play
/// non-negative; a play the fit wants below zero is moved into the table
/// (`extend`), and without a play term the table is free at every knot.
/// A fixed "the table is zero there" sat beside a first value of
/// −20.2 µm.
fn first_knot(at: &str, t_um: f64, table_um: f64, play: f64, play_name: Option<&str>) -> String {
    match play_name {
        None => format!(
            "; the model has no play term for this axis: T is the table alone ({t_um:+.3} µm at {at})"
        ),
        Some(n) if table_um.abs() < TABLE_ZERO_UM => {
            format!("; at {at} the table is zero and T is the play `{n}` ({play:+.3} µm)")
        }
        Some(n) => format!(
            "; at {at} T ({t_um:+.3} µm) is the play `{n}` ({play:+.3} µm) plus the table's {table_um:+.3} µm{}",
            if table_um < 0.0 && play <= 0.0 {
                " (the fit wants the play below zero, which a play cannot be: the table holds the rest)"
            } else {
                ""
            }
        ),
    }
}

/// Extra play found for a reversal: the fitted play minus the play of the
/// model as given (zero when the model had no play term for the axis).
fn reversal_value(
    original: &StageModel,
    fitted: &StageModel,
    term: &str,
) -> Result<f64, AnalysisError> {
    let full = format!("{term}.backlash_um");
    let before = original.param(&full).unwrap_or(0.0);
    Ok(fitted.param(&full)? - before)
}

/// " (not the 0.4 mm screw pitch)" or " (3× the 0.4 mm screw pitch)".
fn nearest_screw_multiple(m: &StageModel, a: Axis, period_um: f64) -> String {
    let pitch = m
        .terms()
        .iter()
        .filter(|t| t.kind() == crate::model::terms::cyclic::LEADSCREW_KIND)
        .filter_map(|t| t.to_config().ok())
        .find(|c| c.get("axis").and_then(|v| v.as_str()) == Some(a.as_str()))
        .and_then(|c| c.get("period_um").and_then(|v| v.as_float()));
    match pitch {
        Some(p) if p > 0.0 => {
            let ratio = period_um / p;
            if (ratio - ratio.round()).abs() < 0.03 && ratio.round() >= 2.0 {
                format!(
                    ": {}× the {:.3} mm screw pitch (a once-per-{}-turns error: gear or coupling)",
                    ratio.round(),
                    p / 1000.0,
                    ratio.round()
                )
            } else {
                format!(": not the {:.3} mm screw pitch", p / 1000.0)
            }
        }
        _ => String::new(),
    }
}
