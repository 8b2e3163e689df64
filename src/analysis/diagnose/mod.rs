//! The discrepancy analysis: what the model (the simulation) gets wrong
//! about a measurement log.
//!
//! # Method
//! 1. **Replay.** The log's commanded positions go through the model's
//!    [`MotionTracker`] (with the model's minimum incremental motion), so
//!    each point gets the state the simulator would have had; the logged
//!    temperature is used when present (else the model's environment).
//!
//!    **Screw leads.** The period of each `leadscrew_cyclic` term on a
//!    measured axis (the screw's lead) is checked next, where the log can
//!    tell it (two leads spanned, four points per lead): candidate leads
//!    are scanned and one is adopted only when it predicts held-out data
//!    better by the findings' test; the rest of the diagnosis runs on the
//!    model with that lead, reported as a parameter correction
//!    ([`LeadCheck`]). Where the log cannot tell it, the check says why
//!    and what scan would (`lead`).
//! 2. **Base fit.** Every parameter of the model the log can identify is
//!    fitted (`base_free_kinds = ["*"]`: linear terms, backlash through its
//!    Jacobian, the angles of angular terms at their Abbe arms), with
//!    standard errors, and reported as a **parameter correction**
//!    ([`ParamCorrection`]: model value, fitted value ± σ, a sentence), not
//!    as a finding: a stage that is merely another stage differs from the
//!    model in its values, not its structure. A parameter stays at the
//!    model's value, with its reason ([`FixedParam`]), when its period is
//!    aliased by the log's spacing or longer than twice the span it covers
//!    (a screw's cyclic terms: when the log spans fewer than two leads),
//!    when it is a temperature coefficient and the log's temperature does
//!    not change, when the log cannot separate it from parameters taken
//!    before it (`ident`: the rank of the Jacobian, column by column in a
//!    physical order; the combination is named, [`Unidentifiable`]), or
//!    when freeing its term does not predict held-out data better
//!    (`fit::select_base`). Residual = measured − model.
//! 3. **Nuisance.** An axis that does not move during a segment-cycle keeps
//!    one settling error for the whole line; that block constant is profiled
//!    out (the residual and every column are centred within the block for
//!    that component), otherwise it would look like structure in time.
//!    Likewise one constant per component over the rows where its axis
//!    moves: a camera log's frame origin is a convention (the daemon's tie
//!    pre-scan puts the mean of command − measured along its X tie line at
//!    zero), not something the model predicts, so an absolute offset is
//!    profiled out rather than reported as structure (otherwise, on the
//!    simulated rig, a 3.5 µm offset is named a 6.7 mm wide "dip").
//! 4. **Search.** For each error component, candidate families against every
//!    variable of the log: each axis position (periodic at any period by a
//!    generalized Lomb–Scargle periodogram; slope; a localized Gaussian
//!    feature at any place and width), time (linear and quadratic drift,
//!    periodic), direction of motion (extra play on reversal, through the
//!    model's own play operator), the length of the preceding move (lost
//!    motion `A·(1 − exp(−L/λ))` against the move's direction, λ on a log
//!    grid refined by golden section, `A` linear; searched only when the
//!    log has moves of clearly different lengths, else it is the same column
//!    as extra play), temperature, and every extra column of the log that
//!    is numeric in (nearly) all rows (linear dependence; kind `other`).
//! 5. **Held-out judging.** Folds are whole cycles (contiguous time chunks
//!    when the log has one cycle). For each fold the base is fitted and the
//!    candidate's period/place is searched **on the other folds only**, then
//!    the joint fit predicts the held-out fold. Pooled over folds this gives
//!    every point's held-out error before and after; a family is significant
//!    when the paired mean reduction of squared error is at least
//!    `z_threshold` standard errors above zero and the held-out RMS drops by
//!    at least `min_gain_pct`. The standard error counts, besides the rows'
//!    own scatter, the base's estimation error that a fold's held-out rows
//!    share (`fit::base_share`). A table with a knot per target may pass
//!    instead by the χ² of its held-out per-target means against the
//!    replicates' σ (`tables::heldout_chi_z`). A term that only fits noise
//!    predicts held-out data worse, so it fails.
//! 6. **Greedy.** The most useful significant candidate (largest held-out
//!    reduction) is accepted, added to the base, and the search repeats.
//! 7. **Extension.** Accepted candidates become model terms
//!    ([`crate::model::terms::discovered`], or more play in the model's
//!    backlash term); every linear coefficient comes from the centred
//!    solve on all rows, and every standard error from the same solve with
//!    the columns of the nonlinear parameters (a localized feature's place
//!    and width, a step-size term's length: their derivatives at the
//!    values the search refined) beside the linear ones: the Gauss–Newton
//!    covariance at the values reported. A nonlinear parameter the log
//!    does not determine gets no standard error.
//! 8. **Withdrawal.** A finding that states a number the log does not
//!    determine (a place outside the measured travel of its axis; a place,
//!    width, length or amplitude without a finite standard error, or with
//!    one larger than the travel, resp. the log's peak-to-peak error; any
//!    non-finite number) is withdrawn ([`Withdrawn`], with the reason),
//!    the last accepted first, and the extension refitted without it
//!    until every finding left is usable (`withdraw`). The extended
//!    model, its held-out and in-sample RMS, the parameter corrections and
//!    the noise report's residual are those without the withdrawn ones;
//!    the report lists them apart and credits them with no gain. The
//!    greedy search does not search again in their place: what they
//!    carried stays in the residual (and in the noise report's
//!    unexplained error).
//!
//! # Extra columns (`other`)
//! A log may carry columns the model has no input for (humidity, motor
//! current, a quality figure, ...). Each one that parses as a finite number
//! in at least 95 % of the rows (the rest take its mean) and is not constant
//! is searched like any family: the error component linear in the column,
//! judged on the held-out folds. Columns that nearly repeat a variable the
//! analysis already has (|correlation| ≥ 0.98 with a commanded position,
//! time or temperature, e.g. a reported position) are left out: a
//! dependence on them is named by that variable's own family. A finding of
//! kind `other` names its column (`variable`) and slope (`um_per_unit`).
//! **The extended model does not include it**: a model is evaluated on a
//! [`MotionState`] (commanded position, history, time, temperature) and
//! cannot read an arbitrary column, so no model term could reproduce the
//! effect in a simulation or compensate it. The finding says so
//! (`in_extended_model = false`), its column is still fitted jointly (so
//! the other findings are not biased by it), and the report's extended
//! held-out RMS and in-sample RMS are those of the model-expressible
//! findings only; the held-out RMS with the `other` findings as well is
//! reported separately (`with_unmodelled_rms_um`).
//!
//! # Layout
//! This file holds the public types, [`diagnose`] (the greedy loop of
//! steps 4–6) and the log's temperature record; each step's machinery has
//! its own file:
//! * `options`: [`DiagnoseOptions`], how to diagnose.
//! * `finding`: [`Finding`], one named discrepancy.
//! * `data`: step 1 and 3, the log replayed into model states, residual
//!   rows, folds, centring groups, and the extra columns worth searching.
//! * `family`: the candidate families (what a discrepancy may vary with),
//!   shared by the search and the held-out verdicts.
//! * `search`: step 4, the families a log offers and the search that fixes a
//!   family's period, place, width or length; a candidate's design columns.
//! * `fit`: step 5, the centred least squares per fold and the held-out
//!   verdict (paired z, RMS); the base fit's held-out selection.
//! * `lead`: step 1b, the screw leads the log can correct, and what it
//!   cannot check.
//! * `ident`: step 2, which base parameters the log can separate, and the
//!   combinations it cannot.
//! * `corrections`: step 2's parameter corrections (model vs fitted value).
//! * `extend`: step 7, accepted candidates turned into model terms, with
//!   the standard errors of their parameters.
//! * `withdraw`: step 8, findings whose numbers the log does not determine
//!   withdrawn, the extension refitted without them.
//! * `describe`: a finding's parameters, uncertainty, sentence and likely
//!   cause.
//! * `tables`: the readings of the replicates as table families, their
//!   held-out tests, and the term attached to each reading.
//! * `report`: the text and JSON reports of a [`Diagnosis`].

mod corrections;
mod data;
mod describe;
mod extend;
mod family;
mod finding;
mod fit;
mod ident;
mod iso_figures;
mod judge;
mod lead;
mod map_term;
mod noise;
mod options;
mod readings;
mod report;
mod search;
mod tables;
#[cfg(test)]
mod tests;
mod withdraw;

use serde::{Deserialize, Serialize};

use crate::charact::log::MeasurementLog;
use crate::charact::scan::is_sweep_anchor;
use crate::model::{Axis, Environment, Interpolation, StageModel, TemperaturePoint, XyUm};

use super::grid::{self, GridReport};
use super::AnalysisError;
pub use corrections::{ParamCorrection, SIGNIFICANT_SIGMAS};
pub use data::{parse_approach, APPROACH_COLUMN, MEASURED_AXES_KEY};
use data::{FoldScheme, MeasuredSource};
use extend::extended;
use family::Family;
pub use finding::{Finding, Withdrawn};
use fit::{fold_base, paired_z, rms_comp, select_base, Verdict};
pub use ident::Unidentifiable;
use judge::{judge, passes_test, rejudge, with_findings, Accepted};
pub use lead::{LeadCheck, LeadTest, LeadVerdict};
pub use map_term::{MapComponent, MapFold, MapTermReport};
pub use noise::{ComponentNoise, IsoFigures, NoiseReport, Outlier, Sampling, TargetRepeat};
pub use options::DiagnoseOptions;
pub use readings::{Reading, ReadingKind, ReadingTerm, READING_Z};
pub use search::ALL_KINDS;
use search::{base_columns, columns, families, refine_localized, refine_period, search, Spec};

/// RMS per error component, µm.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RmsXy {
    /// x component, µm.
    pub x: f64,
    /// y component, µm.
    pub y: f64,
}

impl RmsXy {
    fn from(v: [f64; 2]) -> Self {
        RmsXy { x: v[0], y: v[1] }
    }

    /// The component's value.
    pub fn get(&self, c: Axis) -> f64 {
        match c {
            Axis::X => self.x,
            Axis::Y => self.y,
        }
    }
}

/// Residual series for plots: one entry per log point.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct ResidualSeries {
    /// Commanded x, µm.
    pub x_um: Vec<f64>,
    /// Commanded y, µm.
    pub y_um: Vec<f64>,
    /// Time, s.
    pub t_s: Vec<f64>,
    /// The log's temperature, °C; NaN where the log has none (no `temp_c`
    /// column, or an empty cell). Not the model's assumed temperature
    /// history the replay uses there: a plot against it would show the
    /// model's assumption as if it were a measurement.
    pub temp_c: Vec<f64>,
    /// Direction sign of the x axis (+1, −1, 0).
    pub x_dir: Vec<f64>,
    /// Direction sign of the y axis.
    pub y_dir: Vec<f64>,
    /// Length of the last move of the x axis, µm.
    pub x_last_move_um: Vec<f64>,
    /// Length of the last move of the y axis, µm.
    pub y_last_move_um: Vec<f64>,
    /// The log's numeric extra columns that were searched: name and value
    /// per point (unparsable cells hold the column mean).
    pub extra: Vec<(String, Vec<f64>)>,
    /// Residual (measured − model) after the base fit, `[x, y]` µm, block
    /// constants of static axes removed.
    pub before_um: [Vec<f64>; 2],
    /// Residual after the extended fit, µm.
    pub after_um: [Vec<f64>; 2],
    /// Rows left out as outliers (`Data::excluded`): their residuals above
    /// are not fitted values (zero after the centring) and are not drawn.
    pub excluded: Vec<bool>,
}

/// A base-fit parameter kept at the model's value, and why.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FixedParam {
    /// Full parameter name (`term.param`).
    pub name: String,
    /// Why the log cannot support it.
    pub reason: String,
    /// Whether the reason is an aliased period (else: a period longer than
    /// the log spans, no temperature change, not separable from other
    /// parameters, or freeing it predicted held-out data worse).
    pub aliased: bool,
}

/// `(period, shortest resolvable period)` when parameter `name` belongs to
/// a periodic term (`period_um` in its configuration) along an axis whose
/// sampling cannot resolve that period; `None` otherwise.
fn aliased_period(d: &data::Data, model: &StageModel, name: &str) -> Option<(f64, f64)> {
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
const CONSTANT_TEMPERATURE: &str = "the log's temperature does not change";

/// Why the log cannot identify parameter `name` beyond aliasing, or
/// `None`: a periodic term whose period is more than
/// [`LONGEST_PERIOD_SPANS`] times the log's span of its variable (less
/// than half a period is seen: its sine and cosine are a smooth curve that
/// trades off against every slope, a fitted amplitude means nothing), or a temperature coefficient (unit `…/°C…`) when the
/// log's temperature does not change (the column is then the model's own
/// assumed temperature history, not a measurement).
fn unresolved(d: &data::Data, model: &StageModel, name: &str) -> Option<String> {
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
const LONGEST_PERIOD_SPANS: f64 = 2.0;

/// Everything `diagnose` found.
#[derive(Debug, Clone, Serialize)]
pub struct Diagnosis {
    /// Points analysed.
    pub points: usize,
    /// Folds used for held-out judging.
    pub folds: usize,
    /// RMS of measured − model as given (nothing fitted), µm.
    pub model_rms_um: RmsXy,
    /// Held-out RMS after the base fit, µm.
    pub baseline_rms_um: RmsXy,
    /// Findings in order of acceptance.
    pub findings: Vec<Finding>,
    /// Candidates that passed the held-out test but state a number the log
    /// does not determine (a place outside the measured travel, a missing
    /// or absurd standard error), with the reason (step 8, `withdraw`):
    /// not findings, and not in the extended model.
    pub withdrawn: Vec<Withdrawn>,
    /// Held-out RMS with every finding the extended model includes, µm
    /// (the reported findings only: not the `other` ones, nor the
    /// withdrawn ones, each fold fitted without them).
    pub extended_rms_um: RmsXy,
    /// Held-out RMS with the `other` findings (log columns the model cannot
    /// read) as well, µm; absent when there are none.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub with_unmodelled_rms_um: Option<RmsXy>,
    /// In-sample RMS of the refitted extended model, µm (what a replay of
    /// the log through the extended model leaves: the noise floor when
    /// everything is explained).
    pub extended_fit_rms_um: RmsXy,
    /// The model's own parameters as the log measured them (base fit,
    /// jointly with the findings): parameter corrections, not findings.
    pub parameters: Vec<ParamCorrection>,
    /// The screw leads of the model's `leadscrew_cyclic` terms on the
    /// measured axes as the log measured them: corrected (also a
    /// parameter correction, and the extended model's period), kept, or
    /// not checked with what scan would check them (`lead`).
    pub leads: Vec<LeadCheck>,
    /// Parameters the log cannot separate from others (kept at the
    /// model's value), with the combination it measures instead.
    pub unidentifiable: Vec<Unidentifiable>,
    /// Parameters the base fit identified.
    pub base_free_params: Vec<String>,
    /// Parameters of the base kinds the log cannot support, kept at the
    /// model's value, with the reason (aliased period, or freeing them made
    /// the held-out prediction worse).
    pub base_fixed_params: Vec<FixedParam>,
    /// The error components the log measured (an unmeasured one, e.g. the
    /// placeholder `y_*` columns of a 1-D log, is neither fitted nor
    /// reported).
    pub measured_axes: Vec<Axis>,
    /// How the measured axes were decided: `metadata` (the log's
    /// `measured_axes` entry) or `data` (a constant `*_meas_um` column is a
    /// placeholder).
    pub measured_from: String,
    /// Whether the log's times are synthetic (its `time_source` metadata
    /// says so, as `micropos import` writes for exports without times):
    /// rates per hour are then per 3600 records and say nothing about
    /// time.
    pub synthetic_time: bool,
    /// The axis whose position follows time over the whole log, and the
    /// correlation (a one-way scan at a steady rate): nothing is fitted or
    /// searched as a function of time.
    pub time_with: Option<(Axis, f64)>,
    /// Why the log's time explains nothing (a grid visited once per
    /// cell, or with synthetic times), when it cannot.
    pub time_unusable: Option<String>,
    /// The 2-D grid map's own reading (stage-frame geometry, noise,
    /// separable or not), when the log is one (`analysis::grid`).
    pub grid: Option<GridReport>,
    /// The 2-D map term judged on the grid's held-out cells, per
    /// component (`map_term`), when the log is a map: a `position_map`
    /// term in the extended model where it passed.
    pub map_term: Option<MapTermReport>,
    /// The angle a grid map's readings were turned by before the model
    /// fit (the measuring frame's rotation, µrad), when they were.
    pub frame_turn_urad: Option<f64>,
    /// Whether the held-out folds are whole cycles (else contiguous
    /// chunks of the log's one cycle, or interleaved in time).
    pub whole_cycle_folds: bool,
    /// Why the folds are blocks interleaved in time
    /// (`data::FoldScheme::InterleavedInTime`), when they are: a component
    /// whose replicates changed between visits under whole-cycle folds.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub folds_interleaved: Option<String>,
    /// RMS over the log's rows of what the aliased base parameters (held
    /// at the model's value because the sampling cannot resolve their
    /// period) contribute to the model's prediction, µm: the part of the
    /// residual that is the model's own unverifiable claim.
    pub aliased_contribution_rms_um: RmsXy,
    /// Held-out rows judged (interpolations within the range the other
    /// folds sampled) out of `points`.
    pub judged_points: usize,
    /// Noise from the data (replicates, neighbours), the systematic error
    /// the findings leave against it, and what the sampling resolves.
    pub noise: NoiseReport,
    /// Options used.
    pub options: DiagnoseOptions,
    /// The extended model (base fit + the reported findings, refitted
    /// without the withdrawn ones), with the log's
    /// temperature record as its environment (so a simulator running it
    /// replays the log under the same conditions).
    #[serde(skip)]
    pub extended_model: StageModel,
    /// The model as given with only the base fit applied (no findings), same
    /// environment: what compensation from the original model uses, the
    /// reference the extended model is compared against.
    #[serde(skip)]
    pub base_model: StageModel,
    /// Residual series for plots.
    #[serde(skip)]
    pub series: ResidualSeries,
}

/// Runs the analysis of `log` against `model`. See the module docs.
pub fn diagnose(
    log: &MeasurementLog,
    model: &StageModel,
    opts: &DiagnoseOptions,
) -> Result<Diagnosis, AnalysisError> {
    if !(opts.z_threshold.is_finite() && opts.min_gain_pct.is_finite()) {
        return Err(AnalysisError::Invalid(
            "z_threshold and min_gain_pct must be finite".into(),
        ));
    }
    // A sweep log's anchors: their approach (a move of the anchor spacing,
    // then one step) is not in the log, and a replay would give them the
    // spacing as their last move. The scan records the anchors corrected
    // describe the step plan's motion, which the replay gives them.
    let without_anchors;
    let log = if log.records.iter().any(|r| is_sweep_anchor(&r.segment)) {
        let mut l = log.clone();
        l.records.retain(|r| !is_sweep_anchor(&r.segment));
        without_anchors = l;
        &without_anchors
    } else {
        log
    };
    let (measured, _) = data::measured_axes(log)?;
    let grid = grid::report_of(&log.records, measured, opts.z_threshold, opts.min_gain_pct);
    let turned;
    let log = match &grid {
        Some(g) if !camera_tied(log) && g.geometry.frame_rotation_urad.value.is_finite() => {
            turned = turn_frame(log, g);
            &turned
        }
        _ => log,
    };
    let mut out = diagnose_cross_folds(log, model, opts)?;
    out.frame_turn_urad = log
        .metadata
        .get(FRAME_TURN_KEY)
        .and_then(|v| v.parse().ok());
    if let Some(g) = &grid {
        out.map_term = Some(map_term::fit(&mut out, g)?);
    }
    out.grid = grid;
    Ok(out)
}

/// Metadata key [`diagnose`] writes into the log it fits when it turned
/// the measuring frame of a grid map (µrad).
const FRAME_TURN_KEY: &str = "micropos_frame_turn_urad";

/// Whether the log's frame is a microposd camera tie (its
/// `vision_frame_*` metadata): the tie already fixes the frame by the
/// stage's x axis, the same convention [`turn_frame`] applies.
fn camera_tied(log: &MeasurementLog) -> bool {
    log.metadata
        .iter()
        .any(|(k, _)| k.starts_with("vision_frame_"))
}

/// Whether [`turn_frame`] turned this log.
fn frame_turned(log: &MeasurementLog) -> bool {
    log.metadata.get(FRAME_TURN_KEY).is_some()
}

/// The log with its readings turned so that the stage's x axis is the
/// frame's x (the map's `d(ey)/dx` becomes zero, `d(ex)/dy` the
/// out-of-squareness): the model's squareness is then the stage's, not
/// the instrument's alignment. Small-angle, about the map's centre.
fn turn_frame(log: &MeasurementLog, g: &grid::GridReport) -> MeasurementLog {
    let th = 1e-6 * g.geometry.frame_rotation_urad.value;
    let p = g.geometry.planes[0];
    let mut l = log.clone();
    for r in &mut l.records {
        let (x, y) = (r.x_meas_um - p.xc_um, r.y_meas_um - p.yc_um);
        r.x_meas_um += th * y;
        r.y_meas_um -= th * x;
    }
    l.metadata.insert(
        FRAME_TURN_KEY,
        format!("{:.6}", g.geometry.frame_rotation_urad.value),
    );
    l
}

/// The measuring frame's rotation as a base column (µrad; `e_x = −θ·y`,
/// `e_y = +θ·x` about the log's mean command).
fn rotation_column(d: &data::Data) -> Vec<f64> {
    let n = d.n as f64;
    let xc = d.states.iter().map(|s| s.cmd_um(Axis::X)).sum::<f64>() / n;
    let yc = d.states.iter().map(|s| s.cmd_um(Axis::Y)).sum::<f64>() / n;
    let mut col = vec![0.0; 2 * d.n];
    for (i, s) in d.states.iter().enumerate() {
        col[2 * i] = -1e-6 * (s.cmd_um(Axis::Y) - yc);
        col[2 * i + 1] = 1e-6 * (s.cmd_um(Axis::X) - xc);
    }
    col
}

/// [`diagnose`] on whole-cycle folds, and again on folds interleaved in
/// time when the replicates show the error changing between visits.
fn diagnose_cross_folds(
    log: &MeasurementLog,
    model: &StageModel,
    opts: &DiagnoseOptions,
) -> Result<Diagnosis, AnalysisError> {
    let first = diagnose_with(log, model, opts, FoldScheme::Cycles)?;
    // An error that changes between visits of a target is a time (or
    // path) effect that whole-cycle folds judge by extrapolation in time
    // (see `data::FoldScheme`): the log is judged again on interleaved
    // folds. Not when time follows a position (no time family is searched
    // then).
    let changing: Vec<String> = first
        .noise
        .components
        .iter()
        .filter(|c| c.changes_between_visits)
        .filter_map(|c| {
            let (s, nb) = (c.residual_replicate_scatter_um?, c.replicate_neighbour_noise_um?);
            Some(format!(
                "{}'s visits of one target scatter {s:.4} µm in the residual of whole-cycle folds, {:.1}× its neighbour noise ({nb:.4} µm)",
                c.component,
                s / nb
            ))
        })
        .collect();
    if changing.is_empty() || first.time_with.is_some() || first.time_unusable.is_some() {
        return Ok(first);
    }
    let mut second = diagnose_with(log, model, opts, FoldScheme::InterleavedInTime)?;
    second.folds_interleaved = Some(format!(
        "{}: the error changes between visits, and a fold that holds out a whole cycle would judge a time effect by extrapolating it into that cycle",
        changing.join("; ")
    ));
    Ok(second)
}

/// [`diagnose`] with the rows assigned to folds by `scheme`. The screw
/// leads are checked first (`lead`): the rest runs on `given` with the
/// leads the log supports; "model as given" is `given`.
fn diagnose_with(
    log: &MeasurementLog,
    given: &StageModel,
    opts: &DiagnoseOptions,
    scheme: FoldScheme,
) -> Result<Diagnosis, AnalysisError> {
    let d = prepare_with(log, given, opts.max_folds, scheme)?;
    let leads = lead::check_leads(&d, given, opts)?;
    let d = if leads.corrections.is_empty() {
        d
    } else {
        prepare_with(log, &leads.model, opts.max_folds, scheme)?
    };
    let model = &leads.model;
    let (mut base, unidentifiable) = select_base_params(log, &d, model, opts);
    // Readings of the replicates that the base leaves (a reversal that
    // varies along the travel, a non-linearity between targets) become
    // candidate terms, tables judged on held-out data like every family.
    let mut fams = families(&d);
    fams.extend(tables::wanted(log, &d, &base.cols));
    fams.extend(lead::shape_tables(&leads.checks, &d, &fams));
    let Greedy {
        acc,
        table_tests,
        baseline_rms,
        final_heldout,
        ..
    } = Greedy::run(&d, model, opts, &fams, &mut base);
    let Outcome {
        findings,
        withdrawn,
        mut fitted,
        std_errs,
        final_heldout,
        extended_heldout,
        with_unmodelled,
    } = settle_findings(&d, model, &base, &acc, final_heldout)?;
    let base_model = base_model_with_environment(log, &d, model, &base.names, &mut fitted)?;
    let synthetic_time = log
        .metadata
        .get(TIME_SOURCE_KEY)
        .is_some_and(|v| v.trim_start().starts_with("synthetic"));
    let mut parameters = leads.corrections.clone();
    parameters.extend(corrections::corrections(
        model,
        &fitted,
        &base.names,
        &std_errs,
        synthetic_time,
    ));
    corrections::with_joint_totals(&mut parameters, model, &unidentifiable);
    // Residual series and in-sample RMS of the extended model.
    let observed: Vec<_> = d
        .states
        .iter()
        .map(|s| fitted.observed_position(s))
        .collect();
    let after = extended_residual(&d, &observed);
    let series = residual_series(log, &d, &base.cols, &after);
    let fit_rms = [rms_comp(&after, 0), rms_comp(&after, 1)];
    corrections::note_tables(&mut parameters, &findings, model);
    corrections::note_model_scale(&mut parameters, &fitted, &d.states, &observed, d.measured);
    note_short_periods(&mut parameters, &d, model);
    let r0 = given_model_residual(&d, given);
    let mut noise = noise::noise_report(log, &d, &final_heldout);
    tables::reading_terms(&mut noise, &findings, &table_tests, &d, opts);
    let aliased_rms = aliased_contribution(&d, model, &base.fixed)?;
    let mut findings = findings;
    note_aliased_in_tables(&mut findings, aliased_rms);
    lead::note_held(&mut findings, &leads.checks);
    Ok(Diagnosis {
        points: d.n,
        folds: d.nfolds,
        model_rms_um: RmsXy::from([rms_comp(&r0, 0), rms_comp(&r0, 1)]),
        baseline_rms_um: RmsXy::from(baseline_rms),
        findings,
        withdrawn,
        extended_rms_um: RmsXy::from(extended_heldout),
        with_unmodelled_rms_um: with_unmodelled,
        extended_fit_rms_um: RmsXy::from(fit_rms),
        parameters,
        leads: leads.checks,
        unidentifiable,
        base_free_params: base.names,
        base_fixed_params: base.fixed,
        measured_axes: Axis::ALL
            .into_iter()
            .filter(|a| d.measured[a.index()])
            .collect(),
        measured_from: match d.measured_source {
            MeasuredSource::Metadata => "metadata".into(),
            MeasuredSource::Data => "data".into(),
        },
        synthetic_time,
        time_with: d.time_with,
        time_unusable: d.time_unusable.clone(),
        grid: None,
        map_term: None,
        frame_turn_urad: None,
        whole_cycle_folds: d.whole_cycle_folds,
        folds_interleaved: None,
        aliased_contribution_rms_um: RmsXy::from(aliased_rms),
        judged_points: d.judged.iter().filter(|&&j| j).count(),
        noise,
        options: opts.clone(),
        extended_model: fitted,
        base_model,
        series,
    })
}

/// The base fit's parameters. The greedy search changes them: a finding
/// may free a candidate the selection left at the model's value, or make
/// a kept one inseparable from its table.
struct Base {
    /// Free parameters, in the order of `cols`.
    names: Vec<String>,
    /// Their design columns.
    cols: Vec<Vec<f64>>,
    /// Parameters at the model's value, each with the reason the report
    /// gives.
    fixed: Vec<FixedParam>,
    /// The held-out selection's candidates, kept so that a later finding
    /// can free one of them.
    cand_names: Vec<String>,
    cand_cols: Vec<Vec<f64>>,
    /// Candidates the selection left at the model's value: a later finding
    /// that one of them can carry frees it instead.
    dropped: Vec<usize>,
}

impl Base {
    /// Frees candidate `j`: a finding showed the log measures it after all.
    fn free(&mut self, j: usize) {
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
    fn fix_spanned_by(&mut self, d: &data::Data, model: &StageModel, acc: &[Accepted]) {
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
fn select_base_params(
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

/// Steps 4–6, the greedy search: its inputs, and what it has found so
/// far.
struct Greedy<'a> {
    d: &'a data::Data,
    model: &'a StageModel,
    opts: &'a DiagnoseOptions,
    fams: &'a [Family],
    acc: Vec<Accepted>,
    /// The last held-out test of each table family (against the final
    /// model when it was not accepted).
    table_tests: Vec<tables::TableTest>,
    /// The held-out RMS before any finding: the report's baseline.
    baseline_rms: [f64; 2],
    /// The held-out residual of the last pass.
    final_heldout: Vec<f64>,
}

impl<'a> Greedy<'a> {
    /// Each pass accepts a finding (re-judging the others, which may drop
    /// one), frees a carrier or stops. A dropped family can come back with
    /// hyper-parameters searched afresh; the bound on the passes guards
    /// against a finding and its replacement taking turns.
    fn run(
        d: &'a data::Data,
        model: &'a StageModel,
        opts: &'a DiagnoseOptions,
        fams: &'a [Family],
        base: &mut Base,
    ) -> Self {
        let mut g = Greedy {
            d,
            model,
            opts,
            fams,
            acc: Vec::new(),
            table_tests: Vec::new(),
            baseline_rms: [0.0; 2],
            final_heldout: Vec::new(),
        };
        let mut passes = 0usize;
        loop {
            passes += 1;
            if !g.pass(base, passes) {
                break;
            }
        }
        g
    }

    /// One pass; `false` when the search stops.
    fn pass(&mut self, base: &mut Base, passes: usize) -> bool {
        let (d, model, opts) = (self.d, self.model, self.opts);
        let round: usize = self.acc.iter().map(|a| a.findings()).sum();
        let cols = with_findings(&base.cols, &self.acc, None);
        let judged_fams: &[Family] = if round >= opts.max_findings
            || passes > MAX_PASSES_PER_FINDING * opts.max_findings + 2
        {
            &[]
        } else {
            self.fams
        };
        let cands: Vec<(Family, Option<&[Vec<f64>]>)> =
            judged_fams.iter().map(|f| (*f, None)).collect();
        let (before, all_verdicts) = judge(d, &cols, &cands, model);
        let heldout = [rms_comp(&before, 0), rms_comp(&before, 1)];
        if self.acc.is_empty() {
            self.baseline_rms = heldout;
        }
        self.final_heldout = before;
        if judged_fams.is_empty() {
            return false;
        }
        trace_verdicts(&all_verdicts);
        let taken: Vec<Family> = self.acc.iter().map(|a| a.family).collect();
        tables::record(&mut self.table_tests, &all_verdicts, &taken);
        let mut verdicts = significant(all_verdicts, opts, round);
        let Some(best) = verdicts.first().map(|v| v.family) else {
            return false;
        };
        let best = prefer_linear_drift(best, &verdicts, opts);
        let Some(pos) = verdicts.iter().position(|v| v.family == best) else {
            return false;
        };
        let verdict = verdicts.swap_remove(pos);
        let Some(spec) = refined_spec(d, model, best, &cols) else {
            return false;
        };
        let spec_cols = columns(&spec, d, model);
        // A finding the model's own parameters can carry is a parameter
        // correction: a candidate the base selection left at the model's
        // value (its effect was hidden under a larger unmodelled one) whose
        // columns span the finding's is freed instead, and the search goes
        // on without spending a finding.
        let carriers = ident::carriers(d, &spec_cols, &base.dropped, &base.cand_cols);
        if !carriers.is_empty() {
            for j in carriers {
                base.free(j);
            }
        } else {
            self.accept(
                base,
                Accepted {
                    family: best,
                    spec,
                    verdict,
                    cols: spec_cols,
                },
            );
        }
        // The findings so far, against what the base and each other now
        // carry (a freed carrier can take over an earlier finding's error).
        rejudge(d, &base.cols, &mut self.acc, model, opts);
        true
    }

    /// Takes `finding`, with what it implies for the base.
    fn accept(&mut self, base: &mut Base, finding: Accepted) {
        // A reversal table is the lost motion relative to the axis's
        // play (zero at its first knot, `search::table_free_knots`):
        // with the play left at the model's value by the base
        // selection, the table's first knot would be the model's
        // play, a value nothing in the log measured. The play is
        // freed with it.
        for j in table_plays(&finding.spec, self.model, &base.cand_names, &base.dropped) {
            base.free(j);
        }
        let table = matches!(finding.spec, Spec::Table { .. } | Spec::Tables { .. });
        self.acc.push(finding);
        if table {
            base.fix_spanned_by(self.d, self.model, &self.acc);
        }
    }
}

/// Every held-out verdict of a pass, for `RUST_LOG=debug`: why a family
/// was or was not taken.
fn trace_verdicts(all_verdicts: &[Verdict]) {
    for v in all_verdicts {
        tracing::debug!(
            family = ?v.family,
            gain_pct = v.gain_pct,
            z = v.z,
            rms_before_um = v.rms_before,
            rms_after_um = v.rms_after,
            "diagnose: held-out verdict"
        );
    }
}

/// The verdicts that pass the findings' test, the most useful (largest
/// held-out reduction) first. `round` findings are taken already.
fn significant(all_verdicts: Vec<Verdict>, opts: &DiagnoseOptions, round: usize) -> Vec<Verdict> {
    let mut verdicts: Vec<Verdict> = all_verdicts
        .into_iter()
        .filter(|v| passes_test(v, opts))
        // Two tables at once are two findings: only within the cap.
        .filter(|v| !matches!(v.family, Family::Tables { .. }) || round + 2 <= opts.max_findings)
        .collect();
    verdicts.sort_by(|a, b| b.reduction.total_cmp(&a.reduction));
    verdicts
}

/// A quadratic drift must beat the linear one on held-out data: `best`,
/// or the linear drift when it does not.
fn prefer_linear_drift(best: Family, verdicts: &[Verdict], opts: &DiagnoseOptions) -> Family {
    if let Family::Drift {
        comp,
        quadratic: true,
    } = best
    {
        let lin = Family::Drift {
            comp,
            quadratic: false,
        };
        if let (Some(q), Some(l)) = (
            verdicts.iter().find(|v| v.family == best),
            verdicts.iter().find(|v| v.family == lin),
        ) {
            let (_, z) = paired_z(&l.after, &q.after, comp.index(), 0.0);
            if z < opts.z_threshold {
                return lin;
            }
        }
    }
    best
}

/// The accepted family's hyper-parameters, from all the data (`cols`:
/// the base with the findings so far).
fn refined_spec(
    d: &data::Data,
    model: &StageModel,
    best: Family,
    cols: &[Vec<f64>],
) -> Option<Spec> {
    let all = vec![true; d.n];
    let fb = fold_base(d, cols, all.clone());
    let spec = search(best, d, &fb.resid, &all)?;
    Some(refine_localized(
        refine_period(spec, d, cols, model),
        d,
        cols,
        model,
    ))
}

/// The findings left after withdrawal, and the held-out residuals of the
/// extended model they make.
struct Outcome {
    findings: Vec<Finding>,
    withdrawn: Vec<Withdrawn>,
    fitted: StageModel,
    std_errs: std::collections::HashMap<String, f64>,
    /// The held-out residual with every finding left.
    final_heldout: Vec<f64>,
    /// The held-out RMS of the extended model (without `other` findings).
    extended_heldout: [f64; 2],
    /// The held-out RMS with the `other` findings too, when there are any.
    with_unmodelled: Option<RmsXy>,
}

/// Step 8 on the greedy search's findings `acc`, whose last held-out
/// residual is `final_heldout`.
fn settle_findings(
    d: &data::Data,
    model: &StageModel,
    base: &Base,
    acc: &[Accepted],
    mut final_heldout: Vec<f64>,
) -> Result<Outcome, AnalysisError> {
    let accepted: Vec<(Spec, Verdict)> = acc
        .iter()
        .flat_map(|a| {
            a.spec
                .clone()
                .split()
                .into_iter()
                .map(|s| (s, a.verdict.clone()))
        })
        .collect();
    // Step 8: findings whose numbers the log does not determine are
    // withdrawn, the extended model refitted without them (`withdraw`).
    let settled = withdraw::settle(d, model, &base.names, accepted)?;
    let kept = &settled.accepted;
    if !settled.withdrawn.is_empty() {
        final_heldout = withdraw::heldout_of(d, model, &base.cols, kept.iter().map(|(s, _)| s));
    }
    let all_heldout = [rms_comp(&final_heldout, 0), rms_comp(&final_heldout, 1)];
    // The extended model cannot carry `other` findings (log columns it has
    // no input for): its held-out RMS is that of the other findings only.
    let unmodelled = |s: &Spec| matches!(s, Spec::Other { .. });
    let (extended_heldout, with_unmodelled) = if kept.iter().any(|(s, _)| unmodelled(s)) {
        let modelled = kept.iter().map(|(s, _)| s).filter(|s| !unmodelled(s));
        let ho = withdraw::heldout_of(d, model, &base.cols, modelled);
        (
            [rms_comp(&ho, 0), rms_comp(&ho, 1)],
            Some(RmsXy::from(all_heldout)),
        )
    } else {
        (all_heldout, None)
    };
    let withdraw::Settled {
        findings,
        withdrawn,
        fitted,
        std_errs,
        ..
    } = settled;
    Ok(Outcome {
        findings,
        withdrawn,
        fitted,
        std_errs,
        final_heldout,
        extended_heldout,
        with_unmodelled,
    })
}

/// The model with the base fit alone (no findings), and the log's
/// temperature record given to it and to `fitted`: both are written
/// out and simulated under the log's conditions.
fn base_model_with_environment(
    log: &MeasurementLog,
    d: &data::Data,
    model: &StageModel,
    base_names: &[String],
    fitted: &mut StageModel,
) -> Result<StageModel, AnalysisError> {
    let (mut base_model, _) = extended(d, model, base_names, &[])?;
    if let Some(env) = log_environment(log)? {
        fitted.set_environment(env.clone())?;
        base_model.set_environment(env)?;
    }
    Ok(base_model)
}

/// Measured − extended model at every row (`observed`: the extended
/// model's positions), centred like the fit's residuals.
fn extended_residual(d: &data::Data, observed: &[XyUm]) -> Vec<f64> {
    let mut after = vec![0.0; 2 * d.n];
    for (i, o) in observed.iter().enumerate() {
        after[2 * i] = d.meas[i][0] - o.x_um;
        after[2 * i + 1] = d.meas[i][1] - o.y_um;
    }
    d.center(&mut after);
    after
}

/// The residuals before (base fit `base0`) and after (`after`) the
/// findings at every row, beside the variables the plots draw them
/// against.
fn residual_series(
    log: &MeasurementLog,
    d: &data::Data,
    base0: &[Vec<f64>],
    after: &[f64],
) -> ResidualSeries {
    let mut series = ResidualSeries::default();
    let base_only = fold_base(d, base0, vec![true; d.n]);
    for i in 0..d.n {
        let s = &d.states[i];
        series.x_um.push(s.cmd_um(Axis::X));
        series.y_um.push(s.cmd_um(Axis::Y));
        series.t_s.push(s.time_s);
        series.temp_c.push(
            log.records
                .get(i)
                .and_then(|r| r.temp_c)
                .filter(|t| t.is_finite())
                .unwrap_or(f64::NAN),
        );
        series.x_dir.push(s.axes[0].dir.sign());
        series.y_dir.push(s.axes[1].dir.sign());
        series.x_last_move_um.push(s.axes[0].last_move_um);
        series.y_last_move_um.push(s.axes[1].last_move_um);
        for c in 0..2 {
            series.before_um[c].push(base_only.resid[2 * i + c]);
            series.after_um[c].push(after[2 * i + c]);
        }
        series.excluded.push(d.excluded[i]);
    }
    series.extra = d
        .extra
        .iter()
        .map(|x| (x.name.clone(), x.values.clone()))
        .collect();
    series
}

/// Measured − the model as given, on the measured components: the
/// report's "model as given" RMS.
fn given_model_residual(d: &data::Data, given: &StageModel) -> Vec<f64> {
    let mut r0 = vec![0.0; 2 * d.n];
    for i in 0..d.n {
        let o = given.observed_position(&d.states[i]);
        for c in 0..2 {
            if d.measured[c] {
                r0[2 * i + c] = d.meas[i][c] - if c == 0 { o.x_um } else { o.y_um };
            }
        }
    }
    r0
}

/// What the aliased parameters (`base_fixed`'s) contribute at the log's
/// points, RMS per component: a table finding takes it too.
fn aliased_contribution(
    d: &data::Data,
    model: &StageModel,
    base_fixed: &[FixedParam],
) -> Result<[f64; 2], AnalysisError> {
    let mut aliased_rms = [0.0; 2];
    if base_fixed.iter().any(|p| p.aliased) {
        let mut zeroed = model.clone();
        for p in base_fixed.iter().filter(|p| p.aliased) {
            zeroed.set_param(&p.name, 0.0)?;
        }
        let mut diff = vec![0.0; 2 * d.n];
        for i in 0..d.n {
            let a = model.observed_position(&d.states[i]);
            let b = zeroed.observed_position(&d.states[i]);
            for c in 0..2 {
                if d.measured[c] {
                    diff[2 * i + c] = if c == 0 {
                        a.x_um - b.x_um
                    } else {
                        a.y_um - b.y_um
                    };
                }
            }
        }
        aliased_rms = [rms_comp(&diff, 0), rms_comp(&diff, 1)];
    }
    Ok(aliased_rms)
}

/// A table with a knot per target also takes what the model's aliased
/// terms (unverifiable, at the model's values) claim at the targets: on
/// an axis whose real error is linear to 0.01 µm, a table can read
/// 2.6 µm, all of it the model's own screw and guide claims. The table
/// findings say so.
fn note_aliased_in_tables(findings: &mut [Finding], aliased_rms: [f64; 2]) {
    for f in findings.iter_mut().filter(|f| {
        matches!(
            f.kind,
            crate::analysis::FindingKind::Nonlinearity
                | crate::analysis::FindingKind::ReversalVaries
        )
    }) {
        let a = aliased_rms[f.component.index()];
        if a > 0.0 {
            f.explanation.push_str(&format!(
                "; these values also correct the model's own aliased terms, which stay at the model's values and contribute {a:.3} µm rms at the log's points: where the model's claim is wrong there, the table holds the difference, and the stage's own departure is the replicates' reading (no model)"
            ));
        }
    }
}

/// Relative spread (standard deviation over the training rows of a fold
/// against that over all rows) below which a base column cannot be
/// fitted from the training rows, see [`testable_in_every_fold`].
const TRAINING_SPREAD: f64 = 1e-3;

/// Whether base column `col` varies over the training rows of every fold
/// (measured components, rows not excluded): a parameter that does not is
/// fitted on the full data from the held-out part alone, where no
/// held-out test can judge it.
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

/// Periods a log must span before a fitted periodic parameter reads as
/// a periodic error rather than a bow of the travel.
const PERIODS_FOR_A_PERIOD: f64 = 2.0;

/// Says, in the sentence of a periodic parameter (`sin`/`cos`) that the
/// log spans fewer than [`PERIODS_FOR_A_PERIOD`] periods of, that its
/// value is as much a bow of the travel as a periodic error.
///
/// Why: over fewer than two periods a fitted sinusoid is a smooth curve
/// as much as a periodic error (a guideway's 5 mm waviness on a 4.2 mm
/// scan); a reader must not take it for the error at that period. A
/// screw's cyclic terms never get here: over fewer than two leads they
/// are not fitted at all (`lead::held_screw_reason`).
fn note_short_periods(parameters: &mut [ParamCorrection], d: &data::Data, model: &StageModel) {
    for p in parameters.iter_mut() {
        if !(p.parameter.contains("sin") || p.parameter.contains("cos")) {
            continue;
        }
        let Some(cfg) = model
            .terms()
            .iter()
            .find(|t| t.name() == p.term)
            .and_then(|t| t.to_config().ok())
        else {
            continue;
        };
        let Some(period_um) = cfg.get("period_um").and_then(|v| v.as_float()) else {
            continue;
        };
        let axis = match cfg.get("axis").and_then(|v| v.as_str()) {
            Some("x") => Axis::X,
            Some("y") => Axis::Y,
            _ => continue,
        };
        // Harmonic k of the term's fundamental (`forward_sin_3_um`: k = 3).
        let k: f64 = p
            .parameter
            .split('_')
            .skip_while(|w| *w != "sin" && *w != "cos")
            .nth(1)
            .and_then(|w| w.parse().ok())
            .unwrap_or(1.0);
        let period_um = period_um / k.max(1.0);
        let span = data::span_of(d, axis);
        let periods = span / period_um;
        if periods < PERIODS_FOR_A_PERIOD {
            p.sentence.push_str(&format!(
                "; the log spans only {periods:.1} periods of it ({period_um:.0} µm over {span:.0} µm of {axis}): as much a bow of the travel as a periodic error at that period"
            ));
        }
    }
}

/// Indices in `cand_names` of the plays (`backlash_um`) a reversal table
/// in `spec` is relative to, among the `dropped` candidates (left at the
/// model's value by the base selection).
fn table_plays(
    spec: &Spec,
    model: &StageModel,
    cand_names: &[String],
    dropped: &[usize],
) -> Vec<usize> {
    let mut out = Vec::new();
    for s in spec.clone().split() {
        let Spec::Table {
            axis,
            lost_motion: true,
            ..
        } = s
        else {
            continue;
        };
        let Some(t) = search::backlash_term_of(model, axis) else {
            continue;
        };
        let play = format!("{}.backlash_um", t.name());
        out.extend(dropped.iter().copied().filter(|&j| cand_names[j] == play));
    }
    out.sort_unstable();
    out.dedup();
    out
}

/// Passes of the greedy loop per allowed finding (each pass accepts a
/// finding, frees a carrier, or stops): a guard against a finding and its
/// replacement taking turns, above what a log uses (one per finding, one
/// per freed carrier, one per dropped finding).
const MAX_PASSES_PER_FINDING: usize = 3;

/// Steps 1 and 3: the log replayed into [`data::Data`] ([`data::prepare`]),
/// the replicates' outliers ([`noise::outlier_rows`]) left out of the fit
/// and of the judging, and the residual centred. Why here: the outliers are
/// read from the replicates, on the rows `data` builds.
#[cfg(test)]
fn prepare(
    log: &MeasurementLog,
    model: &StageModel,
    max_folds: usize,
) -> Result<data::Data, AnalysisError> {
    prepare_with(log, model, max_folds, FoldScheme::Cycles)
}

/// [`prepare`] with the rows assigned to folds by `scheme`.
fn prepare_with(
    log: &MeasurementLog,
    model: &StageModel,
    max_folds: usize,
    scheme: FoldScheme,
) -> Result<data::Data, AnalysisError> {
    let mut d = data::prepare(log, model, max_folds, scheme)?;
    let measured = d.measured;
    for c in Axis::ALL.into_iter().filter(|c| measured[c.index()]) {
        for i in noise::outlier_rows(log, &d, c) {
            d.excluded[i] = true;
            d.judged[i] = false;
        }
    }
    let mut r = std::mem::take(&mut d.r0);
    d.center(&mut r);
    d.r0 = r;
    Ok(d)
}

/// The log's temperature record as a model environment (linear between
/// points at least [`ENV_STEP_S`] apart), or `None` when the log holds no
/// usable temperature. Why: the extended model's thermal and temperature
/// terms need the temperature the log was taken at; with it, a simulator
/// running the extended model (`hil-sim --model`) sees the same room.
fn log_environment(log: &MeasurementLog) -> Result<Option<Environment>, AnalysisError> {
    let mut pts: Vec<TemperaturePoint> = Vec::new();
    for r in &log.records {
        let Some(temp_c) = r.temp_c.filter(|t| t.is_finite()) else {
            continue;
        };
        if !r.t_s.is_finite() {
            continue;
        }
        match pts.last() {
            Some(l) if r.t_s < l.time_s + ENV_STEP_S => {}
            _ => pts.push(TemperaturePoint {
                time_s: r.t_s,
                temp_c,
            }),
        }
    }
    if pts.is_empty() {
        return Ok(None);
    }
    let env = Environment {
        temperature_interpolation: Interpolation::Linear,
        temperature: pts,
    };
    env.validate()?;
    Ok(Some(env))
}

/// Spacing of the temperature points taken from a log, s (room temperature
/// changes over minutes; 30 s keeps a 9.5 h log to ~1000 points).
const ENV_STEP_S: f64 = 30.0;

/// Metadata key of a log's time source (`micropos import` writes
/// `synthetic: …` for exports without times).
pub const TIME_SOURCE_KEY: &str = "time_source";
