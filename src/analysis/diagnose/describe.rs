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
    let cx = Cx {
        v,
        term,
        fitted,
        std_err,
        d,
    };
    let w = match *spec {
        Spec::PosPeriodic {
            axis: a,
            comp: c,
            period_um,
        } => position_periodic(&cx, a, c, period_um)?,
        Spec::Localized {
            axis: a, comp: c, ..
        } => localized(&cx, a, c)?,
        Spec::Slope { axis: a, comp: c } => slope(&cx, a, c)?,
        Spec::Drift { comp: c, quadratic } => drift(&cx, c, quadratic)?,
        Spec::TimePeriodic { comp: c, period_s } => time_periodic(&cx, c, period_s)?,
        Spec::Temperature { comp: c } => temperature(&cx, c)?,
        Spec::Reversal { axis: a } => reversal(&cx, original, a)?,
        Spec::StepSize { axis: a, .. } => step_size(&cx, a)?,
        Spec::Table {
            axis: a,
            ref knots,
            lost_motion,
        } => table(&cx, a, knots, lost_motion)?,
        Spec::Tables { .. } => {
            return Err(AnalysisError::Invalid(
                "two tables judged jointly are described one by one".into(),
            ))
        }
        Spec::Other { comp: c, var } => other(&cx, unmodelled_value, c, var)?,
    };
    let Words {
        kind,
        axis,
        comp,
        params,
        unc,
        explanation,
        cause,
        shape,
        variable,
        in_model,
    } = w;
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

/// What every kind of finding is described from, so that each kind's
/// wording is a function of its own.
struct Cx<'a> {
    v: &'a Verdict,
    term: &'a str,
    fitted: &'a StageModel,
    std_err: &'a dyn Fn(&str) -> Option<f64>,
    d: &'a Data,
}

impl Cx<'_> {
    /// The fitted value of the finding's parameter `k`.
    fn p(&self, k: &str) -> Result<f64, AnalysisError> {
        Ok(self.fitted.param(&format!("{}.{k}", self.term))?)
    }

    /// The standard error of the finding's parameter `k`, where known.
    fn se(&self, k: &str) -> Option<f64> {
        (self.std_err)(&format!("{}.{k}", self.term))
    }
}

/// One kind's part of a [`Finding`]; the verdict's numbers are common to
/// all kinds and added by [`describe`].
struct Words {
    kind: FindingKind,
    axis: Axis,
    comp: Axis,
    params: BTreeMap<String, f64>,
    unc: BTreeMap<String, f64>,
    explanation: String,
    cause: String,
    shape: Option<String>,
    variable: Option<String>,
    in_model: bool,
}

impl Words {
    /// A finding of `kind` the extended model carries, its numbers and
    /// sentences to be filled in.
    fn new(kind: FindingKind, axis: Axis, comp: Axis) -> Self {
        Words {
            kind,
            axis,
            comp,
            params: BTreeMap::new(),
            unc: BTreeMap::new(),
            explanation: String::new(),
            cause: String::new(),
            shape: None,
            variable: None,
            in_model: true,
        }
    }

    /// Records the standard error of parameter `k` (under the name
    /// `key`) when the fit has one.
    fn unc_of(&mut self, cx: &Cx, k: &str, key: &str) {
        if let Some(e) = cx.se(k) {
            self.unc.insert(key.into(), e);
        }
    }
}

fn position_periodic(cx: &Cx, a: Axis, c: Axis, period_um: f64) -> Result<Words, AnalysisError> {
    let (s, co) = (cx.p("sin_um")?, cx.p("cos_um")?);
    let mut w = Words::new(FindingKind::PositionPeriodic, a, c);
    let amp = s.hypot(co);
    w.params.insert("period_um".into(), period_um);
    w.params.insert("amplitude_um".into(), amp);
    w.params
        .insert("phase_deg".into(), co.atan2(s).to_degrees());
    if let (Some(es), Some(ec)) = (cx.se("sin_um"), cx.se("cos_um")) {
        let ea = ((s * es).powi(2) + (co * ec).powi(2)).sqrt() / amp.max(1e-12);
        w.unc.insert("amplitude_um".into(), ea);
        // Period precision of a sinusoid fit: √6·σ/(π·A·span·√N)·P².
        let span = span_of(cx.d, a);
        let noise = cx.v.rms_after;
        let nn = cx.d.n as f64;
        w.unc.insert(
            "period_um".into(),
            6f64.sqrt() * noise / (std::f64::consts::PI * amp.max(1e-12) * span * nn.sqrt())
                * period_um
                * period_um,
        );
    }
    let screw = nearest_screw_multiple(cx.fitted, a, period_um);
    w.explanation = format!(
        "{c} error repeats every {:.3} mm of {a} travel, amplitude {amp:.3} µm{}",
        period_um / 1000.0,
        screw
    );
    w.cause = if a == c {
        "a periodic error at a period the model lacks: a bearing, gear or motor-step period, or a periodic error of the pattern".into()
    } else {
        "guideway waviness or a periodic wobble of the carriage seen across the axis".into()
    };
    Ok(w)
}

fn localized(cx: &Cx, a: Axis, c: Axis) -> Result<Words, AnalysisError> {
    let mut w = Words::new(FindingKind::Localized, a, c);
    for k in ["position_um", "width_um", "amplitude_um"] {
        w.params.insert(k.into(), cx.p(k)?);
        w.unc_of(cx, k, k);
    }
    let params = &w.params;
    w.explanation = format!(
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
    w.cause = "a local defect: damaged screw thread, dent or debris on the guideway, or a defect of the pattern at that place".into();
    Ok(w)
}

fn slope(cx: &Cx, a: Axis, c: Axis) -> Result<Words, AnalysisError> {
    let ppm = cx.p("ppm")?;
    if a == c {
        let mut w = Words::new(FindingKind::Scale, a, c);
        w.params.insert("ppm".into(), ppm);
        w.unc_of(cx, "ppm", "ppm");
        w.explanation = format!(
            "{c} error grows linearly with {a}: {ppm:+.1} ppm beyond the model's scale ({:+.3} µm over 10 mm)",
            ppm * 1e-2
        );
        w.cause = "lead error of the screw differs from the model, a wrong counts-per-unit setting, or the pattern's scale (its thermal expansion)".into();
        Ok(w)
    } else {
        let mut w = Words::new(FindingKind::CrossAxis, a, c);
        w.params.insert("slope_urad".into(), ppm);
        w.unc_of(cx, "ppm", "slope_urad");
        w.explanation = format!(
            "{c} error changes with the position of {a}: {ppm:+.1} µrad ({:+.3} µm per 10 mm of {a}) the model does not have",
            ppm * 1e-2
        );
        w.cause = "out-of-squareness of the axes (or rotation of the camera/pattern against the stage) different from the model".into();
        Ok(w)
    }
}

fn drift(cx: &Cx, c: Axis, quadratic: bool) -> Result<Words, AnalysisError> {
    let mut w = Words::new(FindingKind::TimeDrift, c, c);
    let r = cx.p("rate_um_per_h")?;
    w.params.insert("rate_um_per_h".into(), r);
    w.unc_of(cx, "rate_um_per_h", "rate_um_per_h");
    if quadratic {
        w.params
            .insert("curvature_um_per_h2".into(), cx.p("curvature_um_per_h2")?);
        w.unc_of(cx, "curvature_um_per_h2", "curvature_um_per_h2");
    }
    w.shape = Some(if quadratic { "quadratic" } else { "linear" }.to_string());
    w.explanation = format!(
        "{c} error drifts with time at {r:+.3} µm/h{} independently of position and temperature",
        if quadratic { " (curving)" } else { "" }
    );
    w.cause = "slow thermal drift of stage or microscope not explained by the logged temperature, creep, or a drifting camera mount".into();
    Ok(w)
}

fn time_periodic(cx: &Cx, c: Axis, period_s: f64) -> Result<Words, AnalysisError> {
    let (s, co) = (cx.p("sin_um")?, cx.p("cos_um")?);
    let mut w = Words::new(FindingKind::TimePeriodic, c, c);
    let amp = s.hypot(co);
    w.params.insert("period_s".into(), period_s);
    w.params.insert("amplitude_um".into(), amp);
    if let (Some(es), Some(ec)) = (cx.se("sin_um"), cx.se("cos_um")) {
        w.unc.insert(
            "amplitude_um".into(),
            ((s * es).powi(2) + (co * ec).powi(2)).sqrt() / amp.max(1e-12),
        );
    }
    w.explanation = format!(
        "{c} error oscillates in time every {:.1} min, amplitude {amp:.3} µm",
        period_s / 60.0
    );
    w.cause =
        "an air-conditioning or heater cycle, or another periodic disturbance of the room".into();
    Ok(w)
}

fn temperature(cx: &Cx, c: Axis) -> Result<Words, AnalysisError> {
    let mut w = Words::new(FindingKind::Temperature, c, c);
    let k = cx.p("um_per_c")?;
    w.params.insert("um_per_c".into(), k);
    w.unc_of(cx, "um_per_c", "um_per_c");
    w.explanation = format!(
        "{c} error follows the logged temperature: {k:+.3} µm/°C beyond the model's thermal terms"
    );
    w.cause = "thermal expansion or drift of stage, mount or microscope larger than the model says"
        .into();
    Ok(w)
}

fn reversal(cx: &Cx, original: &StageModel, a: Axis) -> Result<Words, AnalysisError> {
    let v0 = reversal_value(original, cx.fitted, cx.term)?;
    let mut w = Words::new(FindingKind::Reversal, a, a);
    w.params.insert("value_um".into(), v0);
    w.unc_of(cx, "backlash_um", "value_um");
    w.explanation = format!(
        "{a} lands differently depending on the direction it came from: {:+.3} µm of lost motion on reversal beyond the model's play",
        v0
    );
    w.cause = "more (or less) play between screw and nut than the model: wear, preload lost, or friction in the guide".into();
    Ok(w)
}

fn step_size(cx: &Cx, a: Axis) -> Result<Words, AnalysisError> {
    let amp = cx.p("amplitude_um")?;
    let len = cx.p("length_um")?;
    let mut w = Words::new(FindingKind::StepSize, a, a);
    w.params.insert("amplitude_um".into(), amp);
    w.params.insert("length_um".into(), len);
    for k in ["amplitude_um", "length_um"] {
        w.unc_of(cx, k, k);
    }
    let typical = typical_move_um(cx.d, a);
    let at_typical = amp * -(-typical / len.max(1e-9)).exp_m1();
    w.explanation = format!(
        "{a} {} by an amount that depends on the length of the preceding move: {:.3} µm after long moves, building up over about {len:.0} µm of move ({:.3} µm after the log's typical {typical:.0} µm move)",
        if amp >= 0.0 {
            "falls short of its target (lost motion)"
        } else {
            "overshoots its target"
        },
        amp.abs(),
        at_typical.abs()
    );
    w.cause = "elastic wind-up of screw, coupling or nut, or guide friction, that is only fully loaded after a long move (the play of the model depends on the direction only); a nut preload that yields over a travel of about the build-up length".into();
    Ok(w)
}

fn table(cx: &Cx, a: Axis, knots: &[f64], lost_motion: bool) -> Result<Words, AnalysisError> {
    let kind = if lost_motion {
        FindingKind::ReversalVaries
    } else {
        FindingKind::Nonlinearity
    };
    let mut w = Words::new(kind, a, a);
    // The lost motion a table describes is the play plus the
    // table (the play carries its first knot); a non-linearity is
    // the table alone (zero at both ends).
    let play_name = if lost_motion {
        super::search::backlash_term_of(cx.fitted, a).map(|t| format!("{}.backlash_um", t.name()))
    } else {
        None
    };
    let play = play_name
        .as_ref()
        .and_then(|n| cx.fitted.param(n).ok())
        .unwrap_or(0.0);
    let vals = table_values(cx, &mut w, knots, play, play_name.as_deref())?;
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
    if lost_motion {
        w.explanation = format!(
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
        w.cause = "nut preload or wear that varies along the screw, a bent screw or misaligned coupling whose wind-up changes with position, or guide friction that varies; one constant play cannot follow it".into();
    } else {
        let k = (0..vals.len())
            .max_by(|&i, &j| vals[i].1.abs().total_cmp(&vals[j].1.abs()))
            .unwrap_or(0);
        w.explanation = format!(
            "{a}'s error departs from the straight line through the table's end knots by up to {:+.3} µm (at {}; a table at {} knots, linear between them, zero at both ends: the offset and the slope are the base fit's; model sign, measured − command): {}",
            vals[k].1,
            at(vals[k].0),
            knots.len(),
            vals.iter()
                .map(|(x, v)| format!("{v:+.3} µm at {}", at(*x)))
                .collect::<Vec<_>>()
                .join(", ")
        );
        w.cause = "progressive pitch error of the screw, a worn or bent section, or guide straightness seen through an Abbe offset".into();
    }
    Ok(w)
}

/// A table's value at each knot (`play` added: the lost motion a
/// reversal table states includes the play `play_name`), recorded in
/// `w` with its uncertainty; `(knot, value)` pairs for the sentence.
fn table_values(
    cx: &Cx,
    w: &mut Words,
    knots: &[f64],
    play: f64,
    play_name: Option<&str>,
) -> Result<Vec<(f64, f64)>, AnalysisError> {
    let mut vals = Vec::with_capacity(knots.len());
    for (k, &pos) in knots.iter().enumerate() {
        let v = cx.p(&format!("value{k}_um"))? + play;
        w.params.insert(format!("knot{k}_um"), pos);
        w.params.insert(format!("value{k}_um"), v);
        // A knot the table holds at zero is the play there (its
        // uncertainty the play's, when the log measured it).
        let e = cx
            .se(&format!("value{k}_um"))
            .or_else(|| play_name.and_then(|n| (cx.std_err)(n)));
        if let Some(e) = e {
            w.unc.insert(format!("value{k}_um"), e);
        }
        vals.push((pos, v));
    }
    Ok(vals)
}

fn other(
    cx: &Cx,
    unmodelled_value: &dyn Fn(&str) -> Option<f64>,
    c: Axis,
    var: usize,
) -> Result<Words, AnalysisError> {
    let x =
        cx.d.extra
            .get(var)
            .ok_or_else(|| AnalysisError::Invalid(format!("extra column {var} vanished")))?;
    let k = unmodelled_value(&format!("{}.um_per_unit", cx.term))
        .ok_or_else(|| AnalysisError::Invalid(format!("no coefficient for `{}`", x.name)))?;
    let mut w = Words::new(FindingKind::Other, c, c);
    w.params.insert("um_per_unit".into(), k);
    w.unc_of(cx, "um_per_unit", "um_per_unit");
    w.params.insert("variable_min".into(), x.min);
    w.params.insert("variable_max".into(), x.max);
    w.explanation = format!(
        "{c} error follows the log column `{}`: {k:+.4} µm per unit ({:.3} µm over its logged range {} … {}); the model has no input for this column, so the extended model does not include it (its simulation and compensation still miss this error)",
        x.name,
        (k * (x.max - x.min)).abs(),
        x.min,
        x.max
    );
    w.cause = format!(
        "whatever `{}` measures (or something that varies with it) moves the platform or the camera: humidity, motor current or load, air pressure; log and control that quantity, or model it outside the stage model",
        x.name
    );
    w.variable = Some(x.name.clone());
    w.in_model = false;
    Ok(w)
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
