//! The discrepancy analysis: what the model (the simulation) gets wrong
//! about a measurement log.
//!
//! # Method
//! 1. **Replay.** The log's commanded positions go through the model's
//!    [`MotionTracker`] (with the model's minimum incremental motion), so
//!    each point gets the state the simulator would have had; the logged
//!    temperature is used when present (else the model's environment).
//! 2. **Base fit.** The parameters of the terms a characterization measures
//!    anyway (by default the cyclic look-up tables: kinds `leadscrew_cyclic`
//!    and `cross_coupling`; all linear) are identified from the log by least
//!    squares; every other parameter of the model is a claim the log can
//!    refute. Residual = measured − model.
//! 3. **Nuisance.** An axis that does not move during a segment-cycle keeps
//!    one settling error for the whole line; that block constant is profiled
//!    out (the residual and every column are centred within the block for
//!    that component), otherwise it would look like structure in time.
//!    Likewise one constant per component over the rows where its axis
//!    moves: a camera log's frame origin is a convention (the daemon's tie
//!    pre-scan puts the mean of command − measured along its X tie line at
//!    zero), not something the model predicts, so an absolute offset is
//!    profiled out rather than reported as structure (measured on the
//!    simulated rig: a 3.5 µm offset was named a 6.7 mm wide "dip").
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
//!    at least `min_gain_pct`. A term that only fits noise predicts held-out
//!    data worse, so it fails.
//! 6. **Greedy.** The most useful significant candidate (largest held-out
//!    reduction) is accepted, added to the base, and the search repeats.
//! 7. **Extension.** Accepted candidates become model terms
//!    ([`crate::model::terms::discovered`], or more play in the model's
//!    backlash term); the extended model is refitted with the model's own
//!    Levenberg–Marquardt ([`StageModel::fit`]), which gives the standard
//!    errors of the nonlinear parameters (a localized feature's place and
//!    width, a step-size term's length).
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

use std::collections::{BTreeMap, HashMap};
use std::fmt::Write as _;

use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};

use crate::charact::log::MeasurementLog;
use crate::model::terms::{
    discovered::step_size_shape, BacklashConfig, BacklashTerm, DiscoveredConfig, DiscoveredTerm,
    LocalizedConfig, PositionPeriodicConfig, PositionSlopeConfig, StepSizeConfig,
    TemperatureConfig, TimeDriftConfig, TimePeriodicConfig,
};
use crate::model::{
    Axis, Direction, Environment, FitOptions, Interpolation, MotionState, MotionTracker, Sample,
    StageModel, TemperaturePoint, Term, Waypoint, DEFAULT_TEMP_C,
};

use super::periodogram::strongest_peak;
use super::{AnalysisError, FindingKind};

/// How to diagnose.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DiagnoseOptions {
    /// A candidate is significant when its held-out reduction of squared
    /// error is at least this many standard errors above zero.
    pub z_threshold: f64,
    /// ... and the held-out RMS of its component drops by at least this, %.
    pub min_gain_pct: f64,
    /// At most this many findings.
    pub max_findings: usize,
    /// At most this many folds (whole cycles) for held-out judging.
    pub max_folds: usize,
    /// Kinds of model terms whose parameters the base fit identifies from
    /// the log (must be linear terms).
    pub base_free_kinds: Vec<String>,
}

impl Default for DiagnoseOptions {
    fn default() -> Self {
        DiagnoseOptions {
            z_threshold: 5.0,
            min_gain_pct: 1.0,
            max_findings: 4,
            max_folds: 4,
            base_free_kinds: vec!["leadscrew_cyclic".into(), "cross_coupling".into()],
        }
    }
}

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

/// One named discrepancy.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Finding {
    /// What kind of effect.
    pub kind: FindingKind,
    /// The variable axis (`x`/`y`); for time and temperature kinds, the
    /// component.
    pub axis: Axis,
    /// The error component it affects.
    pub component: Axis,
    /// Parameters (names carry their unit), model sign.
    pub params: BTreeMap<String, f64>,
    /// 1-σ uncertainty of each parameter (same keys, where known).
    pub uncertainty: BTreeMap<String, f64>,
    /// Shape of a drift (`linear`/`quadratic`); absent otherwise.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub shape: Option<String>,
    /// Held-out z-score: paired mean reduction of squared error over its
    /// standard error.
    pub significance: f64,
    /// Held-out RMS of the component before adding this term, µm.
    pub heldout_rms_before_um: f64,
    /// ... and after, µm.
    pub heldout_rms_after_um: f64,
    /// `100·(1 − after/before)`, %.
    pub gain_pct: f64,
    /// A sentence a person understands.
    pub explanation: String,
    /// Likely physical cause.
    pub cause: String,
    /// Name of the term that models it in the extended model (empty when
    /// the model cannot express it: kind `other`).
    pub term: String,
    /// The log column the error follows (kind `other`); absent otherwise.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub variable: Option<String>,
    /// Whether the extended model includes the effect (false for `other`:
    /// the model has no input for a log's extra column).
    #[serde(default = "yes")]
    pub in_extended_model: bool,
}

fn yes() -> bool {
    true
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
    /// Temperature, °C.
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
    /// Held-out RMS with every finding the extended model includes, µm.
    pub extended_rms_um: RmsXy,
    /// Held-out RMS with the `other` findings (log columns the model cannot
    /// read) as well, µm; absent when there are none.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub with_unmodelled_rms_um: Option<RmsXy>,
    /// In-sample RMS of the refitted extended model, µm (what a replay of
    /// the log through the extended model leaves: the noise floor when
    /// everything is explained).
    pub extended_fit_rms_um: RmsXy,
    /// Parameters the base fit identified.
    pub base_free_params: Vec<String>,
    /// Options used.
    pub options: DiagnoseOptions,
    /// The extended model (base fit + findings, refitted), with the log's
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

/// The log turned into model states and residual rows.
struct Data {
    n: usize,
    states: Vec<MotionState>,
    meas: Vec<[f64; 2]>,
    /// Residual of the model as given, index `2i + c`.
    r0: Vec<f64>,
    fold: Vec<usize>,
    nfolds: usize,
    /// Centring group per row and component (static axis in its block).
    group: Vec<[Option<usize>; 2]>,
    ngroups: usize,
    /// Whether axis `a` moves within the row's block.
    moving: Vec<[bool; 2]>,
    t0: f64,
    temp_varies: bool,
    /// Numeric extra columns searched by the `other` family.
    extra: Vec<ExtraVar>,
}

/// A numeric extra column of the log.
struct ExtraVar {
    name: String,
    /// Value per row (unparsable cells: the column mean).
    values: Vec<f64>,
    /// Mean over the rows: the column is `value − mean` (a model has no
    /// intercept to absorb a column's offset).
    mean: f64,
    min: f64,
    max: f64,
}

impl Data {
    fn center(&self, v: &mut [f64]) {
        if self.ngroups == 0 {
            return;
        }
        let mut sum = vec![0.0; self.ngroups];
        let mut cnt = vec![0usize; self.ngroups];
        for i in 0..self.n {
            for c in 0..2 {
                if let Some(g) = self.group[i][c] {
                    sum[g] += v[2 * i + c];
                    cnt[g] += 1;
                }
            }
        }
        for i in 0..self.n {
            for c in 0..2 {
                if let Some(g) = self.group[i][c] {
                    v[2 * i + c] -= sum[g] / cnt[g] as f64;
                }
            }
        }
    }
}

fn prepare(
    log: &MeasurementLog,
    model: &StageModel,
    max_folds: usize,
) -> Result<Data, AnalysisError> {
    let recs = &log.records;
    if recs.len() < 20 {
        return Err(AnalysisError::Invalid(format!(
            "the log has {} points; the analysis needs at least 20",
            recs.len()
        )));
    }
    let env = model.environment();
    let waypoints: Vec<Waypoint> = recs
        .iter()
        .map(|r| Waypoint {
            x_um: r.x_cmd_um,
            y_um: r.y_cmd_um,
            time_s: r.t_s,
            temp_c: r.temp_c.unwrap_or_else(|| env.temperature_at(r.t_s)),
            cycle: r.cycle,
        })
        .collect();
    let min_move = model.stochastic().min_incremental_motion_um;
    let mut start = MotionState::at_rest(waypoints[0].x_um, waypoints[0].y_um);
    start.time_s = waypoints[0].time_s;
    start.temp_c = waypoints[0].temp_c;
    let states = MotionTracker::new(start)?
        .with_min_move(min_move)?
        .replay(&waypoints)?;
    let n = states.len();
    let meas: Vec<[f64; 2]> = recs.iter().map(|r| [r.x_meas_um, r.y_meas_um]).collect();
    let mut r0 = vec![0.0; 2 * n];
    for i in 0..n {
        let o = model.observed_position(&states[i]);
        r0[2 * i] = meas[i][0] - o.x_um;
        r0[2 * i + 1] = meas[i][1] - o.y_um;
    }
    // Folds: whole cycles, else contiguous chunks.
    let mut cycles: Vec<u32> = recs.iter().map(|r| r.cycle).collect();
    cycles.sort_unstable();
    cycles.dedup();
    let max_folds = max_folds.max(2);
    let (fold, nfolds) = if cycles.len() >= 2 {
        let k = cycles.len().min(max_folds);
        let rank: HashMap<u32, usize> = cycles.iter().enumerate().map(|(i, c)| (*c, i)).collect();
        (
            recs.iter().map(|r| rank[&r.cycle] % k).collect::<Vec<_>>(),
            k,
        )
    } else {
        let k = max_folds.min(5);
        ((0..n).map(|i| i * k / n).collect(), k)
    };
    // Blocks (segment, cycle, fold): static axes and centring groups.
    let mut block_of: HashMap<(&str, u32, usize), usize> = HashMap::new();
    let mut block = vec![0usize; n];
    for i in 0..n {
        let key = (recs[i].segment.as_str(), recs[i].cycle, fold[i]);
        let next = block_of.len();
        block[i] = *block_of.entry(key).or_insert(next);
    }
    let nb = block_of.len();
    let mut lo = vec![[f64::INFINITY; 2]; nb];
    let mut hi = vec![[f64::NEG_INFINITY; 2]; nb];
    for i in 0..n {
        for a in 0..2 {
            let v = states[i].axes[a].cmd_um;
            lo[block[i]][a] = lo[block[i]][a].min(v);
            hi[block[i]][a] = hi[block[i]][a].max(v);
        }
    }
    let tol = min_move.max(1e-6);
    let mut group = vec![[None; 2]; n];
    let mut moving = vec![[false; 2]; n];
    for i in 0..n {
        for a in 0..2 {
            let b = block[i];
            let still = hi[b][a] - lo[b][a] <= tol;
            moving[i][a] = !still;
            group[i][a] = Some(if still {
                2 * b + a
            } else {
                // Frame gauge: one constant per component over the rows
                // where it moves (see the module docs, step 3).
                2 * nb + a
            });
        }
    }
    let temps: Vec<f64> = states.iter().map(|s| s.temp_c).collect();
    let tmean = temps.iter().sum::<f64>() / n as f64;
    let tsd = (temps.iter().map(|t| (t - tmean).powi(2)).sum::<f64>() / n as f64).sqrt();
    let extra = numeric_extra_columns(log, &states);
    let mut d = Data {
        n,
        t0: states[0].time_s,
        states,
        meas,
        r0,
        fold,
        nfolds,
        group,
        ngroups: 2 * nb + 2,
        moving,
        temp_varies: tsd > 0.02,
        extra,
    };
    let mut r = std::mem::take(&mut d.r0);
    d.center(&mut r);
    d.r0 = r;
    Ok(d)
}

/// Share of rows in which an extra column must be a finite number to be
/// searched.
const EXTRA_MIN_NUMERIC: f64 = 0.95;

/// |correlation| with a commanded position, time or temperature from which
/// an extra column counts as a repeat of that variable (not searched).
const EXTRA_MAX_CORRELATION: f64 = 0.98;

fn correlation(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len().min(b.len()) as f64;
    if n < 2.0 {
        return 0.0;
    }
    let ma = a.iter().sum::<f64>() / n;
    let mb = b.iter().sum::<f64>() / n;
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        sab += (x - ma) * (y - mb);
        saa += (x - ma) * (x - ma);
        sbb += (y - mb) * (y - mb);
    }
    if saa > 0.0 && sbb > 0.0 {
        sab / (saa * sbb).sqrt()
    } else {
        0.0
    }
}

/// The log's extra columns worth searching (see the module docs): numeric
/// in ≥ [`EXTRA_MIN_NUMERIC`] of the rows, not constant, not a repeat of a
/// variable the other families already cover.
fn numeric_extra_columns(log: &MeasurementLog, states: &[MotionState]) -> Vec<ExtraVar> {
    let n = log.records.len();
    let known: [Vec<f64>; 4] = [
        states.iter().map(|s| s.cmd_um(Axis::X)).collect(),
        states.iter().map(|s| s.cmd_um(Axis::Y)).collect(),
        states.iter().map(|s| s.time_s).collect(),
        states.iter().map(|s| s.temp_c).collect(),
    ];
    let mut out = Vec::new();
    for (j, name) in log.columns.extra.iter().enumerate() {
        let parsed: Vec<Option<f64>> = log
            .records
            .iter()
            .map(|r| {
                r.extra
                    .get(j)
                    .and_then(|t| t.trim().parse::<f64>().ok())
                    .filter(|v| v.is_finite() && v.abs() < 1e15)
            })
            .collect();
        let ok: Vec<f64> = parsed.iter().flatten().copied().collect();
        if (ok.len() as f64) < EXTRA_MIN_NUMERIC * n as f64 || ok.len() < 20 {
            continue;
        }
        let mean = ok.iter().sum::<f64>() / ok.len() as f64;
        let values: Vec<f64> = parsed.iter().map(|v| v.unwrap_or(mean)).collect();
        let (min, max) = values
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), v| {
                (l.min(*v), h.max(*v))
            });
        if max <= min {
            continue;
        }
        if known
            .iter()
            .any(|k| correlation(k, &values).abs() >= EXTRA_MAX_CORRELATION)
        {
            continue;
        }
        out.push(ExtraVar {
            name: name.clone(),
            values,
            mean,
            min,
            max,
        });
    }
    out
}

/// A concrete candidate term (its nonlinear hyper-parameters chosen).
#[derive(Debug, Clone, PartialEq)]
enum Spec {
    PosPeriodic {
        axis: Axis,
        comp: Axis,
        period_um: f64,
    },
    Localized {
        axis: Axis,
        comp: Axis,
        position_um: f64,
        width_um: f64,
    },
    Slope {
        axis: Axis,
        comp: Axis,
    },
    Drift {
        comp: Axis,
        quadratic: bool,
    },
    TimePeriodic {
        comp: Axis,
        period_s: f64,
    },
    Temperature {
        comp: Axis,
    },
    Reversal {
        axis: Axis,
    },
    StepSize {
        axis: Axis,
        length_um: f64,
    },
    /// Linear in extra column `var` (index into `Data::extra`); no model
    /// term can carry it.
    Other {
        comp: Axis,
        var: usize,
    },
}

/// A search family (what varies, before the search fixes it).
#[derive(Debug, Clone, Copy, PartialEq)]
enum Family {
    PosPeriodic { axis: Axis, comp: Axis },
    Localized { axis: Axis, comp: Axis },
    Slope { axis: Axis, comp: Axis },
    Drift { comp: Axis, quadratic: bool },
    TimePeriodic { comp: Axis },
    Temperature { comp: Axis },
    Reversal { axis: Axis },
    StepSize { axis: Axis },
    Other { comp: Axis, var: usize },
}

impl Family {
    fn comp(&self) -> Axis {
        match *self {
            Family::PosPeriodic { comp, .. }
            | Family::Localized { comp, .. }
            | Family::Slope { comp, .. }
            | Family::Drift { comp, .. }
            | Family::TimePeriodic { comp }
            | Family::Temperature { comp }
            | Family::Other { comp, .. } => comp,
            Family::Reversal { axis } | Family::StepSize { axis } => axis,
        }
    }
}

fn families(d: &Data) -> Vec<Family> {
    let mut out = Vec::new();
    for comp in Axis::ALL {
        for axis in Axis::ALL {
            out.push(Family::PosPeriodic { axis, comp });
            out.push(Family::Localized { axis, comp });
            out.push(Family::Slope { axis, comp });
        }
        out.push(Family::Drift {
            comp,
            quadratic: false,
        });
        out.push(Family::Drift {
            comp,
            quadratic: true,
        });
        out.push(Family::TimePeriodic { comp });
        if d.temp_varies {
            out.push(Family::Temperature { comp });
        }
        for var in 0..d.extra.len() {
            out.push(Family::Other { comp, var });
        }
    }
    for axis in Axis::ALL {
        out.push(Family::Reversal { axis });
        out.push(Family::StepSize { axis });
    }
    out
}

/// Range of the step-size length λ worth searching for `axis`, µm, or
/// `None` when the log cannot tell a step-size effect from extra play: too
/// few moves, or (nearly) all of the same length (a log of constant-step
/// scans), where `1 − exp(−L/λ)` is one number times the direction.
fn step_length_range(d: &Data, axis: Axis) -> Option<(f64, f64)> {
    let mut lens = move_lengths(d, axis);
    if lens.len() < 16 {
        return None;
    }
    lens.sort_by(f64::total_cmp);
    let med = lens[lens.len() / 2];
    let distinct = lens
        .iter()
        .filter(|&&l| l >= 3.0 * med || l <= med / 3.0)
        .count();
    if distinct < STEP_MIN_DISTINCT.max(lens.len() / 50) {
        return None;
    }
    let lo = (0.5 * lens[lens.len() / 20]).max(1e-3);
    let hi = (2.0 * lens[lens.len() - 1]).max(4.0 * lo);
    Some((lo, hi))
}

/// Moves whose length differs at least 3× from the median a log needs
/// before the step-size family is searched (and at least 2 % of its
/// moves: the few repositioning moves between constant-step scans do not
/// make a step-size effect identifiable).
const STEP_MIN_DISTINCT: usize = 8;

/// The step-size length λ whose column best explains `resid` on the
/// training rows (largest squared projection), log grid then golden
/// section.
fn step_size_search(d: &Data, axis: Axis, resid: &[f64], train: &[bool]) -> Option<Spec> {
    let (lo, hi) = step_length_range(d, axis)?;
    let c = axis.index();
    let mut col = vec![0.0; 2 * d.n];
    let mut score = |log_l: f64| -> f64 {
        let l = log_l.exp();
        col.iter_mut().for_each(|v| *v = 0.0);
        for (i, s) in d.states.iter().enumerate() {
            let m = s.axes[c];
            col[2 * i + c] = step_size_shape(m.dir.sign(), m.last_move_um, l);
        }
        d.center(&mut col);
        let (mut br, mut bb) = (0.0, 0.0);
        for i in 0..d.n {
            if train[i] {
                br += col[2 * i + c] * resid[2 * i + c];
                bb += col[2 * i + c] * col[2 * i + c];
            }
        }
        if bb > 0.0 {
            br * br / bb
        } else {
            0.0
        }
    };
    let (a, b) = (lo.ln(), hi.ln());
    let n = 40;
    let grid: Vec<(f64, f64)> = (0..=n)
        .map(|k| {
            let x = a + (b - a) * k as f64 / n as f64;
            (x, score(x))
        })
        .collect();
    let (kbest, _) = grid
        .iter()
        .enumerate()
        .max_by(|p, q| p.1 .1.total_cmp(&q.1 .1))?;
    if grid[kbest].1 <= 0.0 {
        return None;
    }
    // Golden section between the best point's neighbours.
    let mut l = grid[kbest.saturating_sub(1)].0;
    let mut h = grid[(kbest + 1).min(n)].0;
    let g = 0.5 * (5f64.sqrt() - 1.0);
    let mut x1 = h - g * (h - l);
    let mut x2 = l + g * (h - l);
    let (mut f1, mut f2) = (score(x1), score(x2));
    for _ in 0..25 {
        if f1 >= f2 {
            h = x2;
            x2 = x1;
            f2 = f1;
            x1 = h - g * (h - l);
            f1 = score(x1);
        } else {
            l = x1;
            x1 = x2;
            f1 = f2;
            x2 = l + g * (h - l);
            f2 = score(x2);
        }
    }
    let best = if f1.max(f2) >= grid[kbest].1 {
        if f1 >= f2 {
            x1
        } else {
            x2
        }
    } else {
        grid[kbest].0
    };
    Some(Spec::StepSize {
        axis,
        length_um: best.exp(),
    })
}

fn median(mut v: Vec<f64>) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    Some(v[v.len() / 2])
}

/// Position samples of axis `a` (rows where it moves, training rows only),
/// averaged per distinct position: position-dependent structure is common
/// to all passes, and averaging makes the periodogram 5–10× cheaper.
fn position_profile(
    d: &Data,
    a: Axis,
    comp: Axis,
    resid: &[f64],
    train: &[bool],
) -> (Vec<f64>, Vec<f64>) {
    let mut pts: Vec<(f64, f64)> = (0..d.n)
        .filter(|&i| train[i] && d.moving[i][a.index()])
        .map(|i| (d.states[i].cmd_um(a), resid[2 * i + comp.index()]))
        .collect();
    pts.sort_by(|p, q| p.0.total_cmp(&q.0));
    let mut xs = Vec::new();
    let mut ys = Vec::new();
    let mut i = 0;
    while i < pts.len() {
        let mut j = i;
        let mut s = 0.0;
        while j < pts.len() && (pts[j].0 - pts[i].0).abs() < 1e-3 {
            s += pts[j].1;
            j += 1;
        }
        xs.push(pts[i].0);
        ys.push(s / (j - i) as f64);
        i = j;
    }
    (xs, ys)
}

fn search(f: Family, d: &Data, resid: &[f64], train: &[bool]) -> Option<Spec> {
    match f {
        Family::PosPeriodic { axis, comp } => {
            let (x, y) = position_profile(d, axis, comp, resid, train);
            if x.len() < 16 {
                return None;
            }
            let span = x[x.len() - 1] - x[0];
            let spacing = median(x.windows(2).map(|w| w[1] - w[0]).collect())?;
            let p_min = (5.0 * spacing).max(1e-3);
            let p_max = span / 2.0;
            if p_max <= p_min {
                return None;
            }
            let (fr, _) = strongest_peak(&x, &y, 1.0 / p_max, 1.0 / p_min, 3.0)?;
            Some(Spec::PosPeriodic {
                axis,
                comp,
                period_um: 1.0 / fr,
            })
        }
        Family::Localized { axis, comp } => {
            let (x, y) = position_profile(d, axis, comp, resid, train);
            if x.len() < 16 {
                return None;
            }
            let span = x[x.len() - 1] - x[0];
            let spacing = median(x.windows(2).map(|w| w[1] - w[0]).collect())?;
            let score = |p: f64, w: f64| -> f64 {
                let lo = x.partition_point(|&v| v < p - 5.0 * w);
                let hi = x.partition_point(|&v| v <= p + 5.0 * w);
                let (mut gr, mut gg) = (0.0, 0.0);
                for k in lo..hi {
                    let z = (x[k] - p) / w;
                    let g = (-0.5 * z * z).exp();
                    gr += g * y[k];
                    gg += g * g;
                }
                if gg > 0.0 {
                    gr * gr / gg
                } else {
                    0.0
                }
            };
            let mut best = (0.0, 0.0, 0.0);
            let mut w = 1.5 * spacing;
            while w <= span / 8.0 {
                let mut p = x[0];
                while p <= x[x.len() - 1] {
                    let s = score(p, w);
                    if s > best.0 {
                        best = (s, p, w);
                    }
                    p += w / 3.0;
                }
                w *= 1.4;
            }
            if best.0 <= 0.0 {
                return None;
            }
            // Local pattern search around the grid optimum.
            let (mut s, mut p, mut w) = best;
            let (mut dp, mut dw) = (w / 6.0, 0.2);
            for _ in 0..40 {
                let mut improved = false;
                for (np, nw) in [
                    (p + dp, w),
                    (p - dp, w),
                    (p, w * (1.0 + dw)),
                    (p, w / (1.0 + dw)),
                ] {
                    if nw < spacing {
                        continue;
                    }
                    let ns = score(np, nw);
                    if ns > s {
                        (s, p, w) = (ns, np, nw);
                        improved = true;
                    }
                }
                if !improved {
                    dp /= 2.0;
                    dw /= 2.0;
                }
            }
            Some(Spec::Localized {
                axis,
                comp,
                position_um: p,
                width_um: w,
            })
        }
        Family::Slope { axis, comp } => Some(Spec::Slope { axis, comp }),
        Family::Drift { comp, quadratic } => Some(Spec::Drift { comp, quadratic }),
        Family::Temperature { comp } => Some(Spec::Temperature { comp }),
        Family::Reversal { axis } => {
            let has_both = (0..d.n)
                .any(|i| d.states[i].axes[axis.index()].dir == Direction::Forward)
                && (0..d.n).any(|i| d.states[i].axes[axis.index()].dir == Direction::Backward);
            has_both.then_some(Spec::Reversal { axis })
        }
        Family::StepSize { axis } => step_size_search(d, axis, resid, train),
        Family::Other { comp, var } => Some(Spec::Other { comp, var }),
        Family::TimePeriodic { comp } => {
            let idx: Vec<usize> = (0..d.n).filter(|&i| train[i]).collect();
            let x: Vec<f64> = idx.iter().map(|&i| d.states[i].time_s).collect();
            let y: Vec<f64> = idx.iter().map(|&i| resid[2 * i + comp.index()]).collect();
            if x.len() < 16 {
                return None;
            }
            let span = x.iter().cloned().fold(f64::NEG_INFINITY, f64::max)
                - x.iter().cloned().fold(f64::INFINITY, f64::min);
            let dt = median(x.windows(2).map(|w| (w[1] - w[0]).abs()).collect())?;
            let p_min = (20.0 * dt).max(60.0);
            let p_max = span / 2.0;
            if p_max <= p_min {
                return None;
            }
            let (fr, _) = strongest_peak(&x, &y, 1.0 / p_max, 1.0 / p_min, 3.0)?;
            Some(Spec::TimePeriodic {
                comp,
                period_s: 1.0 / fr,
            })
        }
    }
}

fn backlash_term_of(model: &StageModel, axis: Axis) -> Option<&dyn Term> {
    model.terms().iter().map(|t| &**t).find(|t| {
        t.kind() == crate::model::terms::backlash::KIND
            && t.params().len() == 1
            && t.to_config()
                .ok()
                .and_then(|c| c.get("axis").and_then(|v| v.as_str().map(String::from)))
                .as_deref()
                == Some(axis.as_str())
    })
}

/// The candidate's design columns over all rows (index `2i + c`), centred.
fn columns(spec: &Spec, d: &Data, model: &StageModel) -> Vec<Vec<f64>> {
    let n = d.n;
    let mut cols: Vec<Vec<f64>> = Vec::new();
    let mut one = |c: Axis, f: &dyn Fn(&MotionState) -> f64| {
        let mut v = vec![0.0; 2 * n];
        for i in 0..n {
            v[2 * i + c.index()] = f(&d.states[i]);
        }
        cols.push(v);
    };
    let tau = std::f64::consts::TAU;
    match *spec {
        Spec::PosPeriodic {
            axis,
            comp,
            period_um,
        } => {
            one(comp, &|s| {
                (tau * (s.cmd_um(axis) / period_um).fract()).sin()
            });
            one(comp, &|s| {
                (tau * (s.cmd_um(axis) / period_um).fract()).cos()
            });
        }
        Spec::Localized {
            axis,
            comp,
            position_um,
            width_um,
        } => one(comp, &|s| {
            let z = (s.cmd_um(axis) - position_um) / width_um;
            (-0.5 * z * z).exp()
        }),
        Spec::Slope { axis, comp } => one(comp, &|s| 1e-6 * s.cmd_um(axis)),
        Spec::Drift { comp, quadratic } => {
            let t0 = d.t0;
            one(comp, &|s| (s.time_s - t0) / 3600.0);
            if quadratic {
                one(comp, &|s| ((s.time_s - t0) / 3600.0).powi(2));
            }
        }
        Spec::TimePeriodic { comp, period_s } => {
            one(comp, &|s| (tau * (s.time_s / period_s).fract()).sin());
            one(comp, &|s| (tau * (s.time_s / period_s).fract()).cos());
        }
        Spec::Temperature { comp } => one(comp, &|s| s.temp_c - DEFAULT_TEMP_C),
        Spec::Reversal { axis } => match backlash_term_of(model, axis) {
            Some(t) => {
                let mut v = vec![0.0; 2 * n];
                for i in 0..n {
                    let j = t.jacobian(&d.states[i]);
                    v[2 * i] = j[0][0];
                    v[2 * i + 1] = j[0][1];
                }
                cols.push(v);
            }
            None => one(axis, &|s| -0.5 * s.axis(axis).dir.sign()),
        },
        Spec::StepSize { axis, length_um } => one(axis, &|s| {
            let m = s.axis(axis);
            step_size_shape(m.dir.sign(), m.last_move_um, length_um)
        }),
        Spec::Other { comp, var } => {
            let mut v = vec![0.0; 2 * n];
            if let Some(x) = d.extra.get(var) {
                for (i, val) in x.values.iter().enumerate().take(n) {
                    v[2 * i + comp.index()] = *val - x.mean;
                }
            }
            cols.push(v);
        }
    }
    for c in &mut cols {
        d.center(c);
    }
    cols
}

/// Columns of the base fit: the jacobian of the free parameters (linear
/// terms, so exact and independent of the values).
fn base_columns(d: &Data, model: &StageModel, kinds: &[String]) -> (Vec<String>, Vec<Vec<f64>>) {
    let mut names = Vec::new();
    let mut cols = Vec::new();
    for t in model.terms() {
        if !kinds.iter().any(|k| k == t.kind()) || !t.is_linear() {
            continue;
        }
        let p = t.params();
        let mut tc = vec![vec![0.0; 2 * d.n]; p.len()];
        for i in 0..d.n {
            for (k, j) in t.jacobian(&d.states[i]).iter().enumerate().take(p.len()) {
                tc[k][2 * i] = j[0];
                tc[k][2 * i + 1] = j[1];
            }
        }
        for (k, mut c) in tc.into_iter().enumerate() {
            if c.iter().all(|v| v.abs() < 1e-12) {
                continue;
            }
            d.center(&mut c);
            names.push(format!("{}.{}", t.name(), p[k].name));
            cols.push(c);
        }
    }
    (names, cols)
}

fn dot_rows(a: &[f64], b: &[f64], train: &[bool]) -> f64 {
    let mut s = 0.0;
    for (i, &t) in train.iter().enumerate() {
        if t {
            s += a[2 * i] * b[2 * i] + a[2 * i + 1] * b[2 * i + 1];
        }
    }
    s
}

/// Minimum-norm least squares from the normal equations, columns scaled to
/// unit norm and small eigenvalues truncated (unidentifiable combinations
/// get no coefficient instead of a huge one).
fn solve_normal(g: &DMatrix<f64>, r: &DVector<f64>) -> DVector<f64> {
    if g.nrows() == 0 {
        return DVector::zeros(0);
    }
    ScaledEigen::new(g).solve(r)
}

/// The eigendecomposition of a Gram matrix with its columns scaled to unit
/// norm: computed once, it gives both the truncated minimum-norm solution
/// and the parameter variances.
struct ScaledEigen {
    scale: Vec<f64>,
    eig: nalgebra::SymmetricEigen<f64, nalgebra::Dyn>,
    lmax: f64,
}

impl ScaledEigen {
    fn new(g: &DMatrix<f64>) -> Self {
        let p = g.nrows();
        let scale: Vec<f64> = (0..p)
            .map(|i| {
                let v = g[(i, i)];
                if v > 0.0 {
                    1.0 / v.sqrt()
                } else {
                    0.0
                }
            })
            .collect();
        let gs = DMatrix::from_fn(p, p, |i, j| g[(i, j)] * scale[i] * scale[j]);
        let eig = nalgebra::SymmetricEigen::new(gs);
        let lmax = eig.eigenvalues.iter().cloned().fold(0.0, f64::max);
        Self { scale, eig, lmax }
    }

    /// Whether eigenvalue `l` is kept (the rest are unidentifiable).
    fn kept(&self, l: f64) -> bool {
        l > 1e-10 * self.lmax && l > 0.0
    }

    fn solve(&self, r: &DVector<f64>) -> DVector<f64> {
        let p = self.scale.len();
        let rs = DVector::from_fn(p, |i, _| r[i] * self.scale[i]);
        let mut x = DVector::zeros(p);
        for k in 0..p {
            let l = self.eig.eigenvalues[k];
            if self.kept(l) {
                let v = self.eig.eigenvectors.column(k);
                let c = v.dot(&rs) / l;
                x += v * c;
            }
        }
        DVector::from_fn(p, |i, _| x[i] * self.scale[i])
    }

    /// Diagonal of the pseudo-inverse of the unscaled Gram matrix.
    fn inverse_diagonal(&self) -> Vec<f64> {
        let p = self.scale.len();
        let mut diag = vec![0.0; p];
        for k in 0..p {
            let l = self.eig.eigenvalues[k];
            if self.kept(l) {
                for (i, dv) in diag.iter_mut().enumerate() {
                    let v = self.eig.eigenvectors[(i, k)];
                    *dv += v * v / l;
                }
            }
        }
        for (i, dv) in diag.iter_mut().enumerate() {
            *dv *= self.scale[i] * self.scale[i];
        }
        diag
    }
}

/// Per fold: the base Gram matrix and right-hand side on the training rows.
struct FoldBase {
    train: Vec<bool>,
    gbb: DMatrix<f64>,
    rb: DVector<f64>,
    /// Residual of every row after the fold's base fit.
    resid: Vec<f64>,
}

fn fold_base(d: &Data, base: &[Vec<f64>], train: Vec<bool>) -> FoldBase {
    let p = base.len();
    let mut gbb = DMatrix::zeros(p, p);
    for j in 0..p {
        for k in j..p {
            let v = dot_rows(&base[j], &base[k], &train);
            gbb[(j, k)] = v;
            gbb[(k, j)] = v;
        }
    }
    let rb = DVector::from_fn(p, |j, _| dot_rows(&base[j], &d.r0, &train));
    let beta = solve_normal(&gbb, &rb);
    let mut resid = d.r0.clone();
    for (j, col) in base.iter().enumerate() {
        let b = beta[j];
        if b != 0.0 {
            for (r, c) in resid.iter_mut().zip(col) {
                *r -= b * c;
            }
        }
    }
    FoldBase {
        train,
        gbb,
        rb,
        resid,
    }
}

/// Joint fit of base + candidate columns on the fold's training rows;
/// returns the residual of every row and the candidate's coefficients.
fn fit_with(d: &Data, base: &[Vec<f64>], fb: &FoldBase, cand: &[Vec<f64>]) -> (Vec<f64>, Vec<f64>) {
    let p = base.len();
    let k = cand.len();
    let mut g = DMatrix::zeros(p + k, p + k);
    g.view_mut((0, 0), (p, p)).copy_from(&fb.gbb);
    let mut r = DVector::zeros(p + k);
    r.rows_mut(0, p).copy_from(&fb.rb);
    for a in 0..k {
        for j in 0..p {
            let v = dot_rows(&cand[a], &base[j], &fb.train);
            g[(p + a, j)] = v;
            g[(j, p + a)] = v;
        }
        for b in a..k {
            let v = dot_rows(&cand[a], &cand[b], &fb.train);
            g[(p + a, p + b)] = v;
            g[(p + b, p + a)] = v;
        }
        r[p + a] = dot_rows(&cand[a], &d.r0, &fb.train);
    }
    let beta = solve_normal(&g, &r);
    let mut resid = d.r0.clone();
    for (j, col) in base.iter().chain(cand.iter()).enumerate() {
        let b = beta[j];
        if b != 0.0 {
            for (rr, c) in resid.iter_mut().zip(col) {
                *rr -= b * c;
            }
        }
    }
    (resid, beta.iter().skip(p).cloned().collect())
}

/// Held-out verdict on one family.
struct Verdict {
    family: Family,
    /// Pooled held-out residual after, `2i + c`.
    after: Vec<f64>,
    reduction: f64,
    z: f64,
    gain_pct: f64,
    rms_before: f64,
    rms_after: f64,
}

fn paired_z(before: &[f64], after: &[f64], c: usize) -> (f64, f64) {
    let diffs: Vec<f64> = before
        .iter()
        .zip(after)
        .skip(c)
        .step_by(2)
        .map(|(b, a)| b * b - a * a)
        .filter(|v| *v != 0.0)
        .collect();
    let m = diffs.len();
    if m < 3 {
        return (0.0, 0.0);
    }
    let sum: f64 = diffs.iter().sum();
    let mean = sum / m as f64;
    let var = diffs.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (m - 1) as f64;
    let z = if var > 0.0 {
        mean / (var / m as f64).sqrt()
    } else {
        0.0
    };
    (sum, z)
}

fn rms_comp(v: &[f64], c: usize) -> f64 {
    let (s, k) = v
        .iter()
        .skip(c)
        .step_by(2)
        .fold((0.0, 0usize), |(s, k), x| (s + x * x, k + 1));
    (s / k.max(1) as f64).sqrt()
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
    let d = prepare(log, model, opts.max_folds)?;
    let (base_names, mut base) = base_columns(&d, model, &opts.base_free_kinds);
    let n_base = base.len();
    let fams = families(&d);
    let mut accepted: Vec<(Spec, Verdict)> = Vec::new();
    let mut baseline_rms = [0.0; 2];
    let mut last_heldout = [0.0; 2];
    for round in 0..=opts.max_findings {
        // Held-out residuals of the current base, and each family's verdict.
        let mut before = vec![0.0; 2 * d.n];
        let mut after: Vec<Vec<f64>> = vec![vec![0.0; 2 * d.n]; fams.len()];
        for f in 0..d.nfolds {
            let train: Vec<bool> = d.fold.iter().map(|&k| k != f).collect();
            let fb = fold_base(&d, &base, train);
            for i in 0..d.n {
                if !fb.train[i] {
                    before[2 * i] = fb.resid[2 * i];
                    before[2 * i + 1] = fb.resid[2 * i + 1];
                }
            }
            if round == opts.max_findings {
                continue;
            }
            for (fi, fam) in fams.iter().enumerate() {
                let (resid, _) = match search(*fam, &d, &fb.resid, &fb.train) {
                    Some(spec) => fit_with(&d, &base, &fb, &columns(&spec, &d, model)),
                    None => (fb.resid.clone(), Vec::new()),
                };
                for i in 0..d.n {
                    if !fb.train[i] {
                        after[fi][2 * i] = resid[2 * i];
                        after[fi][2 * i + 1] = resid[2 * i + 1];
                    }
                }
            }
        }
        let heldout = [rms_comp(&before, 0), rms_comp(&before, 1)];
        if round == 0 {
            baseline_rms = heldout;
        }
        last_heldout = heldout;
        if round == opts.max_findings {
            break;
        }
        let mut verdicts: Vec<Verdict> = fams
            .iter()
            .zip(after)
            .map(|(fam, after)| {
                let c = fam.comp().index();
                let (reduction, z) = paired_z(&before, &after, c);
                let rb = rms_comp(&before, c);
                let ra = rms_comp(&after, c);
                Verdict {
                    family: *fam,
                    after,
                    reduction,
                    z,
                    gain_pct: if rb > 0.0 {
                        100.0 * (1.0 - ra / rb)
                    } else {
                        0.0
                    },
                    rms_before: rb,
                    rms_after: ra,
                }
            })
            .filter(|v| v.z >= opts.z_threshold && v.gain_pct >= opts.min_gain_pct)
            .collect();
        verdicts.sort_by(|a, b| b.reduction.total_cmp(&a.reduction));
        let Some(mut best) = verdicts.first().map(|v| v.family) else {
            break;
        };
        // A quadratic drift must beat the linear one on held-out data.
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
                let (_, z) = paired_z(&l.after, &q.after, comp.index());
                if z < opts.z_threshold {
                    best = lin;
                }
            }
        }
        let Some(pos) = verdicts.iter().position(|v| v.family == best) else {
            break;
        };
        let verdict = verdicts.swap_remove(pos);
        // The accepted term's hyper-parameters from all the data.
        let all = vec![true; d.n];
        let fb = fold_base(&d, &base, all.clone());
        let Some(spec) = search(best, &d, &fb.resid, &all) else {
            break;
        };
        base.extend(columns(&spec, &d, model));
        accepted.push((spec, verdict));
    }

    // The extended model cannot carry `other` findings (log columns it has
    // no input for): its held-out RMS is that of the other findings only.
    let unmodelled = |s: &Spec| matches!(s, Spec::Other { .. });
    let (extended_heldout, with_unmodelled) = if accepted.iter().any(|(s, _)| unmodelled(s)) {
        let mut cols: Vec<Vec<f64>> = base[..n_base].to_vec();
        for (s, _) in &accepted {
            if !unmodelled(s) {
                cols.extend(columns(s, &d, model));
            }
        }
        let mut ho = vec![0.0; 2 * d.n];
        for f in 0..d.nfolds {
            let train: Vec<bool> = d.fold.iter().map(|&k| k != f).collect();
            let fb = fold_base(&d, &cols, train);
            for i in 0..d.n {
                if !fb.train[i] {
                    ho[2 * i] = fb.resid[2 * i];
                    ho[2 * i + 1] = fb.resid[2 * i + 1];
                }
            }
        }
        (
            [rms_comp(&ho, 0), rms_comp(&ho, 1)],
            Some(RmsXy::from(last_heldout)),
        )
    } else {
        (last_heldout, None)
    };

    let samples: Vec<Sample> = (0..d.n)
        .map(|i| Sample {
            state: d.states[i],
            measured_x_um: d.meas[i][0],
            measured_y_um: d.meas[i][1],
        })
        .collect();
    let specs: Vec<Spec> = accepted.iter().map(|(s, _)| s.clone()).collect();
    let mut std_errs: HashMap<String, f64> = HashMap::new();
    // Localized features: standard errors of place and width from the
    // model's own Levenberg–Marquardt (the only nonlinear candidate). Its
    // values are not taken: it cannot profile out the block constants of
    // static axes, and the centred search already refined place and width.
    let nonlinear = |s: &Spec| matches!(s, Spec::Localized { .. } | Spec::StepSize { .. });
    if specs.iter().any(nonlinear) {
        let (ext, names) = extended(&d, model, &base_names, &specs)?;
        let mut free = base_names.clone();
        for (spec, name) in specs.iter().zip(&names) {
            if nonlinear(spec) {
                free.push(format!("{name}.*"));
            }
        }
        let mut fitted = ext.clone();
        let fo = FitOptions {
            free,
            max_iterations: 30,
            ..FitOptions::default()
        };
        if let Ok(report) = fitted.fit(&samples, &fo) {
            for p in &report.params {
                if p.name.ends_with(".position_um")
                    || p.name.ends_with(".width_um")
                    || p.name.ends_with(".length_um")
                {
                    if let Some(e) = p.std_error {
                        std_errs.insert(p.name.clone(), e);
                    }
                }
            }
        }
    }
    // Every linear coefficient from the centred solve (block constants of
    // static axes profiled out, which the plain model fit cannot do), with
    // standard errors from the same normal equations.
    let (mut fitted, term_names, lin_se, unmodelled_values) =
        extended_with_se(&d, model, &base_names, &specs)?;
    let (mut base_model, _) = extended(&d, model, &base_names, &[])?;
    if let Some(env) = log_environment(log)? {
        fitted.set_environment(env.clone())?;
        base_model.set_environment(env)?;
    }
    std_errs.extend(lin_se);
    let std_err = |name: &str| -> Option<f64> { std_errs.get(name).copied() };
    let accepted: Vec<(Spec, Verdict)> = specs
        .into_iter()
        .zip(accepted)
        .map(|(s, (_, v))| (s, v))
        .collect();
    // Residual series and in-sample RMS of the extended model.
    let mut series = ResidualSeries::default();
    let mut after = vec![0.0; 2 * d.n];
    for i in 0..d.n {
        let o = fitted.observed_position(&d.states[i]);
        after[2 * i] = d.meas[i][0] - o.x_um;
        after[2 * i + 1] = d.meas[i][1] - o.y_um;
    }
    d.center(&mut after);
    let base_only = fold_base(&d, &base[..n_base], vec![true; d.n]);
    for i in 0..d.n {
        let s = &d.states[i];
        series.x_um.push(s.cmd_um(Axis::X));
        series.y_um.push(s.cmd_um(Axis::Y));
        series.t_s.push(s.time_s);
        series.temp_c.push(s.temp_c);
        series.x_dir.push(s.axes[0].dir.sign());
        series.y_dir.push(s.axes[1].dir.sign());
        series.x_last_move_um.push(s.axes[0].last_move_um);
        series.y_last_move_um.push(s.axes[1].last_move_um);
        for c in 0..2 {
            series.before_um[c].push(base_only.resid[2 * i + c]);
            series.after_um[c].push(after[2 * i + c]);
        }
    }
    series.extra = d
        .extra
        .iter()
        .map(|x| (x.name.clone(), x.values.clone()))
        .collect();
    let fit_rms = [rms_comp(&after, 0), rms_comp(&after, 1)];
    let value = |name: &str| -> Option<f64> { unmodelled_values.get(name).copied() };
    let findings = accepted
        .iter()
        .zip(&term_names)
        .map(|((spec, v), name)| describe(spec, v, name, &fitted, model, &std_err, &value, &d))
        .collect::<Result<Vec<_>, _>>()?;
    let mut r0 = vec![0.0; 2 * d.n];
    for i in 0..d.n {
        let o = model.observed_position(&d.states[i]);
        r0[2 * i] = d.meas[i][0] - o.x_um;
        r0[2 * i + 1] = d.meas[i][1] - o.y_um;
    }
    Ok(Diagnosis {
        points: d.n,
        folds: d.nfolds,
        model_rms_um: RmsXy::from([rms_comp(&r0, 0), rms_comp(&r0, 1)]),
        baseline_rms_um: RmsXy::from(baseline_rms),
        findings,
        extended_rms_um: RmsXy::from(extended_heldout),
        with_unmodelled_rms_um: with_unmodelled,
        extended_fit_rms_um: RmsXy::from(fit_rms),
        base_free_params: base_names,
        options: opts.clone(),
        extended_model: fitted,
        base_model,
        series,
    })
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

/// Linear-parameter names of a spec's columns, in column order.
fn spec_param_names(spec: &Spec) -> &'static [&'static str] {
    match spec {
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
    }
}

/// The model extended by `specs`, linear coefficients from the centred
/// full-data solve; also the term names.
fn extended(
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
fn extended_with_se(
    d: &Data,
    model: &StageModel,
    base_names: &[String],
    specs: &[Spec],
) -> Result<Extended, AnalysisError> {
    let (names_check, mut cols) = base_columns(d, model, &base_kinds_of(model, base_names));
    debug_assert_eq!(names_check, base_names);
    for s in specs {
        cols.extend(columns(s, d, model));
    }
    let fb = fold_base(d, &cols, vec![true; d.n]);
    let (beta, pdiag) = solve_with_cov(&fb.gbb, &fb.rb);
    let dof = (2 * d.n).saturating_sub(cols.len()).max(1) as f64;
    let sigma2 = fb.resid.iter().map(|v| v * v).sum::<f64>() / dof;
    let mut se: HashMap<String, f64> = HashMap::new();
    let mut ext = model.clone();
    for (j, name) in base_names.iter().enumerate() {
        let v = ext.param(name)? + beta[j];
        ext.set_param(name, v)?;
        se.insert(name.clone(), (sigma2 * pdiag[j]).sqrt());
    }
    let mut col = base_names.len();
    let mut term_names = Vec::new();
    let mut unmodelled = HashMap::new();
    for (k, spec) in specs.iter().enumerate() {
        let pn = spec_param_names(spec);
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
            add_term(&mut ext, spec, &coef, k + 1, d.t0)?
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

/// [`solve_normal`] plus the diagonal of the pseudo-inverse of `g` (the
/// parameter variances per unit residual variance).
fn solve_with_cov(g: &DMatrix<f64>, r: &DVector<f64>) -> (DVector<f64>, Vec<f64>) {
    if g.nrows() == 0 {
        return (DVector::zeros(0), Vec::new());
    }
    let se = ScaledEigen::new(g);
    (se.solve(r), se.inverse_diagonal())
}

/// Adds the term for an accepted candidate; returns its name.
fn add_term(
    m: &mut StageModel,
    spec: &Spec,
    coef: &[f64],
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

#[allow(clippy::too_many_arguments)]
fn describe(
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

/// Lengths of the moves axis `a` made in the log (rows where it moved),
/// µm.
fn move_lengths(d: &Data, a: Axis) -> Vec<f64> {
    d.states
        .windows(2)
        .filter(|w| w[1].cmd_um(a) != w[0].cmd_um(a))
        .map(|w| w[1].axis(a).last_move_um)
        .filter(|l| l.is_finite() && *l > 0.0)
        .collect()
}

/// Median length of the moves of axis `a` in the log, µm (0 without moves).
fn typical_move_um(d: &Data, a: Axis) -> f64 {
    median(move_lengths(d, a)).unwrap_or(0.0)
}

fn span_of(d: &Data, a: Axis) -> f64 {
    let (lo, hi) = d
        .states
        .iter()
        .map(|s| s.cmd_um(a))
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), v| {
            (l.min(v), h.max(v))
        });
    (hi - lo).max(1e-9)
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

impl Diagnosis {
    /// The human-readable report.
    pub fn to_text(&self) -> String {
        let mut out = String::new();
        let _ = writeln!(
            out,
            "{} points, {} held-out folds (whole cycles); base fit identified {} parameters of the model's cyclic tables",
            self.points,
            self.folds,
            self.base_free_params.len()
        );
        let _ = writeln!(
            out,
            "model as given:           rms x {:.4} µm, y {:.4} µm",
            self.model_rms_um.x, self.model_rms_um.y
        );
        let _ = writeln!(
            out,
            "after base fit, held out: rms x {:.4} µm, y {:.4} µm",
            self.baseline_rms_um.x, self.baseline_rms_um.y
        );
        if self.findings.is_empty() {
            let _ = writeln!(
                out,
                "no significant structure in the residuals (held-out z ≥ {}, gain ≥ {} %): the model explains the log to its noise",
                self.options.z_threshold, self.options.min_gain_pct
            );
        }
        for (i, f) in self.findings.iter().enumerate() {
            let _ = writeln!(
                out,
                "\nfinding {}: {} ({} error, variable {})",
                i + 1,
                f.kind,
                f.component,
                f.variable.as_deref().unwrap_or(f.axis.as_str())
            );
            let _ = writeln!(out, "  {}", f.explanation);
            let _ = writeln!(out, "  likely cause: {}", f.cause);
            for (k, v) in &f.params {
                match f.uncertainty.get(k) {
                    Some(u) => {
                        let _ = writeln!(out, "  {k:<22} {v:>12.4} ± {u:.4}");
                    }
                    None => {
                        let _ = writeln!(out, "  {k:<22} {v:>12.4}");
                    }
                }
            }
            let _ = writeln!(
                out,
                "  held-out rms {}: {:.4} → {:.4} µm ({:.1} % better, z = {:.1}); {}",
                f.component,
                f.heldout_rms_before_um,
                f.heldout_rms_after_um,
                f.gain_pct,
                f.significance,
                if f.in_extended_model {
                    format!("model term `{}`", f.term)
                } else {
                    "NOT in the extended model (no model input for this column)".to_string()
                }
            );
        }
        let gx = pct(self.baseline_rms_um.x, self.extended_rms_um.x);
        let gy = pct(self.baseline_rms_um.y, self.extended_rms_um.y);
        let _ = writeln!(
            out,
            "\nextended model, held out: rms x {:.4} µm ({gx:+.1} %), y {:.4} µm ({gy:+.1} %); in-sample x {:.4}, y {:.4} µm",
            self.extended_rms_um.x,
            self.extended_rms_um.y,
            self.extended_fit_rms_um.x,
            self.extended_fit_rms_um.y
        );
        if let Some(w) = &self.with_unmodelled_rms_um {
            let _ = writeln!(
                out,
                "with the log-column findings the model cannot carry, held out: rms x {:.4} µm, y {:.4} µm",
                w.x, w.y
            );
        }
        out
    }

    /// The JSON report (`--json`).
    pub fn to_json(&self) -> serde_json::Value {
        serde_json::json!({
            "points": self.points,
            "folds": self.folds,
            "model_rms_um": self.model_rms_um,
            "baseline_rms_um": self.baseline_rms_um,
            "findings": self.findings,
            "extended_rms_um": self.extended_rms_um,
            "extended_fit_rms_um": self.extended_fit_rms_um,
            "with_unmodelled_rms_um": self.with_unmodelled_rms_um,
            "gain_pct": {
                "x": pct(self.baseline_rms_um.x, self.extended_rms_um.x),
                "y": pct(self.baseline_rms_um.y, self.extended_rms_um.y),
            },
            "base_free_params": self.base_free_params,
            "options": self.options,
        })
    }
}

fn pct(before: f64, after: f64) -> f64 {
    if before > 0.0 {
        100.0 * (1.0 - after / before)
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::analysis::generate::{add_extra_column, simulate_log, truth_model, SimPlan};
    use crate::charact::log::{parse_bytes, Columns};

    fn small_plan(random_points: usize) -> SimPlan {
        SimPlan {
            x_range_um: [250.0, 1250.0],
            x_scan_y_um: 600.0,
            y_range_um: [250.0, 1050.0],
            y_scan_x_um: 700.0,
            cycles: 2,
            random_points,
            ..SimPlan::default()
        }
    }

    #[test]
    fn only_numeric_varying_new_columns_are_searched() {
        let base = StageModel::paper_default().unwrap();
        // Long enough (3.4 h) for the wandering column to wander: over a
        // few of its 300 s knots it is a straight line in time, which the
        // selection rightly leaves to the time families.
        let plan = SimPlan {
            dwell_s: 30.0,
            ..small_plan(20)
        };
        let truth = truth_model(&base, None, &plan, 3).unwrap();
        let mut log = simulate_log(&truth, &plan, 3).unwrap();
        add_extra_column(&mut log, "humidity_pct", 3, None).unwrap();
        let mut extra = log.columns.extra.clone();
        for name in ["focus", "mostly_text", "constant", "x_reported_um"] {
            extra.push(name.to_string());
        }
        log.columns = Columns::new(true, extra).unwrap();
        let n = log.records.len();
        for (i, r) in log.records.iter_mut().enumerate() {
            r.extra.push("ok".into());
            r.extra
                .push(if i % 2 == 0 { "1.5" } else { "n/a" }.to_string());
            r.extra.push("7".into());
            r.extra.push(format!("{:.4}", r.x_cmd_um + 0.001));
            if i == n / 2 {
                r.extra[0] = "garbage".into();
            }
        }
        let parsed = parse_bytes(&log.to_bytes().unwrap()).unwrap();
        let d = prepare(&parsed, &base, 4).unwrap();
        let names: Vec<&str> = d.extra.iter().map(|x| x.name.as_str()).collect();
        assert_eq!(names, ["humidity_pct"]);
        let h = &d.extra[0];
        // One unparsable cell takes the mean (no effect on the fit).
        assert!((h.values[n / 2] - h.mean).abs() < 1e-12);
        assert!(h.min < h.max);
    }

    #[test]
    fn step_size_is_searched_only_with_moves_of_different_lengths() {
        let base = StageModel::paper_default().unwrap();
        for (random, want) in [(0usize, false), (40, true)] {
            let plan = small_plan(random);
            let truth = truth_model(&base, None, &plan, 5).unwrap();
            let log = simulate_log(&truth, &plan, 5).unwrap();
            let parsed = parse_bytes(&log.to_bytes().unwrap()).unwrap();
            let d = prepare(&parsed, &base, 4).unwrap();
            assert_eq!(
                step_length_range(&d, Axis::X).is_some(),
                want,
                "{random} random points"
            );
        }
    }
}
