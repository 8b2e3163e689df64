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
//! This file holds the public types, [`diagnose`] (its steps in order)
//! and the log's temperature record; each step's machinery has its own
//! file:
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
//! * `base`: step 2, which base parameters are fitted and why the others
//!   stay at the model's value.
//! * `ident`: step 2, which base parameters the log can separate, and the
//!   combinations it cannot.
//! * `greedy`: steps 4–6, the greedy loop that accepts findings.
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

mod base;
mod corrections;
mod data;
mod describe;
mod extend;
mod family;
mod finding;
mod fit;
mod greedy;
mod ident;
mod iso_figures;
mod judge;
mod lead;
mod log_columns;
mod map_term;
mod noise;
mod options;
mod readings;
mod refine;
mod replicates;
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
use base::{aliased_period, unresolved, LONGEST_PERIOD_SPANS};
use base::{select_base_params, Base};
pub use corrections::{ParamCorrection, SIGNIFICANT_SIGMAS};
use data::{FoldScheme, MeasuredSource};
use extend::extended;
pub use finding::{Finding, Withdrawn};
use fit::{fold_base, rms_comp, Verdict};
use greedy::Greedy;
pub use ident::Unidentifiable;
use judge::Accepted;
pub use lead::{LeadCheck, LeadTest, LeadVerdict};
pub use log_columns::{parse_approach, APPROACH_COLUMN, MEASURED_AXES_KEY};
pub use map_term::{MapComponent, MapFold, MapTermReport};
pub use noise::{ComponentNoise, IsoFigures, NoiseReport, Outlier, Sampling, TargetRepeat};
pub use options::DiagnoseOptions;
pub use readings::{Reading, ReadingKind, ReadingTerm, READING_Z};
pub use search::ALL_KINDS;
use search::{families, search, Spec};
#[cfg(test)]
use {family::Family, judge::rejudge, search::columns};

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
    let (measured, _) = log_columns::measured_axes(log)?;
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

/// Steps 1 and 3: the log replayed into [`data::Data`] ([`data::prepare`]),
/// the replicates' outliers ([`replicates::outlier_rows`]) left out of the fit
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
        for i in replicates::outlier_rows(log, &d, c) {
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
