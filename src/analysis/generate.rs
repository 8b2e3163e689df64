//! Synthetic characterization logs with one hidden effect: the test bench of
//! the discrepancy analysis, and a way for users to try `micropos diagnose`.
//!
//! The "truth" is a model file: the given base model plus at most one extra
//! term ([`InjectedEffect::term`]) and a seeded temperature history. The log
//! is what the simulated rig ([`StageSimulator`]) produces when it runs a
//! characterization-like plan (per cycle: an x scan forward and back, a y
//! scan forward and back, a few random points), plus camera noise. Because
//! the truth is just a model, `hil-sim --model truth.toml` can replay the
//! same hidden effect through the full served rig.
//!
//! The effect's kind, axis, component and size are drawn from a seed the
//! analysis never sees; sizes go from clearly visible down to about twice
//! the measurement noise (settling σ ⊕ camera σ ≈ 0.046 µm with the
//! defaults).
//!
//! [`add_extra_column`] adds a logged quantity the model has no input for
//! (a humidity-like series wandering in time) as an extra column, with or
//! without an error proportional to it: the test bench of the `other`
//! finding. That effect lives only in the log (no model can carry it), so a
//! truth model replayed by `hil-sim` does not have it.

use std::collections::BTreeMap;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use serde::Serialize;

use crate::charact::log::{Columns, Metadata, Record};
use crate::model::terms::{
    BacklashConfig, BacklashTerm, DiscoveredConfig, DiscoveredTerm, LocalizedConfig,
    PositionPeriodicConfig, PositionSlopeConfig, StepSizeConfig, TemperatureConfig,
    TimeDriftConfig, TimePeriodicConfig,
};
use crate::model::{
    Axis, Environment, Interpolation, MotionState, StageModel, StageSimulator, TemperaturePoint,
    Term, DEFAULT_TEMP_C,
};

use super::{AnalysisError, FindingKind};

/// The scan plan of a synthetic characterization run.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SimPlan {
    /// x scan range `[start, end]`, µm (y held at `x_scan_y_um`).
    pub x_range_um: [f64; 2],
    /// y during the x scan, µm.
    pub x_scan_y_um: f64,
    /// y scan range `[start, end]`, µm (x held at `y_scan_x_um`).
    pub y_range_um: [f64; 2],
    /// x during the y scan, µm.
    pub y_scan_x_um: f64,
    /// Step between scan points, µm (the paper: 5 µm; 20 µm keeps tests fast).
    pub step_um: f64,
    /// Cycles (each: x forward+back, y forward+back, random points).
    pub cycles: u32,
    /// Random points per cycle (both axes move), inside the scan ranges.
    pub random_points: usize,
    /// Time per point (move, settle, image), s.
    pub dwell_s: f64,
    /// Camera measurement noise σ per axis, µm (added to the observed position).
    pub camera_sigma_um: f64,
    /// σ of the temperature random walk per 10 min, °C (0 = constant 20 °C).
    pub temp_walk_c: f64,
}

impl Default for SimPlan {
    fn default() -> Self {
        SimPlan {
            x_range_um: [250.0, 9750.0],
            x_scan_y_um: 2000.0,
            y_range_um: [250.0, 4450.0],
            y_scan_x_um: 5000.0,
            step_um: 20.0,
            cycles: 3,
            random_points: 40,
            dwell_s: 1.5,
            camera_sigma_um: 0.03,
            temp_walk_c: 0.3,
        }
    }
}

impl SimPlan {
    /// Number of points the plan produces (for sizing effects against the
    /// run's duration).
    pub fn points(&self) -> usize {
        let nx = ((self.x_range_um[1] - self.x_range_um[0]) / self.step_um).round() as usize + 1;
        let ny = ((self.y_range_um[1] - self.y_range_um[0]) / self.step_um).round() as usize + 1;
        1 + self.cycles as usize * (2 * nx + 2 * ny + self.random_points)
    }

    /// Duration of the run, s.
    pub fn duration_s(&self) -> f64 {
        self.points() as f64 * self.dwell_s
    }

    pub(crate) fn validate(&self) -> Result<(), AnalysisError> {
        let ok = self.step_um > 0.0
            && self.x_range_um[1] > self.x_range_um[0] + self.step_um
            && self.y_range_um[1] > self.y_range_um[0] + self.step_um
            && self.cycles >= 1
            && self.dwell_s > 0.0
            && self.camera_sigma_um >= 0.0
            && self.temp_walk_c >= 0.0
            && self.points() <= 2_000_000;
        if ok {
            Ok(())
        } else {
            Err(AnalysisError::Invalid(
                "simulation plan: ranges must hold at least two steps, step, dwell and cycles must be positive, noise ≥ 0, at most 2e6 points".into(),
            ))
        }
    }
}

/// The hidden effect of a synthetic log, with its ground-truth parameters.
#[derive(Debug, Clone, Serialize)]
pub struct InjectedEffect {
    /// What the analysis should name.
    pub kind: FindingKind,
    /// Variable axis (for position-dependent kinds) or the component itself.
    pub axis: Axis,
    /// Error component.
    pub component: Axis,
    /// Parameters under the names the analysis reports (`period_um`,
    /// `amplitude_um`, `ppm`, `slope_urad`, `position_um`, `width_um`,
    /// `rate_um_per_h`, `period_s`, `value_um`, `um_per_c`, `length_um`),
    /// model sign.
    pub params: BTreeMap<String, f64>,
    /// The extra model term.
    #[serde(skip)]
    pub term: Box<dyn Term>,
}

/// Kinds the generator can hide.
pub const GENERATED_KINDS: [FindingKind; 9] = [
    FindingKind::PositionPeriodic,
    FindingKind::Scale,
    FindingKind::Localized,
    FindingKind::TimeDrift,
    FindingKind::TimePeriodic,
    FindingKind::Reversal,
    FindingKind::CrossAxis,
    FindingKind::Temperature,
    FindingKind::StepSize,
];

fn log_uniform(rng: &mut ChaCha8Rng, lo: f64, hi: f64) -> f64 {
    (lo.ln() + rng.gen::<f64>() * (hi.ln() - lo.ln())).exp()
}

fn sign(rng: &mut ChaCha8Rng) -> f64 {
    if rng.gen::<bool>() {
        1.0
    } else {
        -1.0
    }
}

fn axis_of(rng: &mut ChaCha8Rng) -> Axis {
    if rng.gen::<bool>() {
        Axis::X
    } else {
        Axis::Y
    }
}

/// Draws a hidden effect from `seed`: the kind (or the given one), axis,
/// component and parameters. Sizes: the effect's peak error is
/// log-uniform in 0.1–1.5 µm (≈ 2–30× the default noise).
pub fn draw_effect(
    seed: u64,
    kind: Option<FindingKind>,
    plan: &SimPlan,
) -> Result<InjectedEffect, AnalysisError> {
    plan.validate()?;
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x5eed_effe_c700_0000);
    let kind = match kind {
        Some(k) => k,
        None => GENERATED_KINDS[rng.gen_range(0..GENERATED_KINDS.len())],
    };
    let size = log_uniform(&mut rng, 0.1, 1.5);
    draw_with(rng, kind, size, plan)
}

/// [`draw_effect`] with the effect's peak error fixed at `size_um` (the
/// other parameters still drawn from `seed`): for tests that need an effect
/// large enough to matter, e.g. the compensation comparison.
pub fn draw_effect_sized(
    seed: u64,
    kind: FindingKind,
    size_um: f64,
    plan: &SimPlan,
) -> Result<InjectedEffect, AnalysisError> {
    plan.validate()?;
    if !(size_um.is_finite() && size_um > 0.0) {
        return Err(AnalysisError::Invalid(format!(
            "effect size must be a finite number > 0 µm, got {size_um}"
        )));
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x5eed_effe_c700_0000);
    // The same draws as `draw_effect` with a given kind (the size), so the
    // other parameters agree for a seed.
    let _ = log_uniform(&mut rng, 0.1, 1.5);
    draw_with(rng, kind, size_um, plan)
}

fn draw_with(
    mut rng: ChaCha8Rng,
    kind: FindingKind,
    size: f64,
    plan: &SimPlan,
) -> Result<InjectedEffect, AnalysisError> {
    let mut params = BTreeMap::new();
    let name = "injected";
    let (axis, component, cfg): (Axis, Axis, DiscoveredConfig) = match kind {
        FindingKind::PositionPeriodic => position_periodic(&mut rng, size, plan, &mut params),
        FindingKind::Scale | FindingKind::CrossAxis => {
            position_slope(&mut rng, kind, size, plan, &mut params)
        }
        FindingKind::Localized => localized(&mut rng, size, plan, &mut params),
        FindingKind::TimeDrift => {
            let component = axis_of(&mut rng);
            let rate = sign(&mut rng) * size / (plan.duration_s() / 3600.0);
            params.insert("rate_um_per_h".into(), rate);
            (
                component,
                component,
                DiscoveredConfig::TimeDrift(TimeDriftConfig {
                    component,
                    start_time_s: 0.0,
                    rate_um_per_h: rate,
                    curvature_um_per_h2: 0.0,
                }),
            )
        }
        FindingKind::TimePeriodic => {
            let component = axis_of(&mut rng);
            let period = log_uniform(&mut rng, 300.0, plan.duration_s() / 4.0);
            let phi = rng.gen::<f64>() * std::f64::consts::TAU;
            params.insert("period_s".into(), period);
            params.insert("amplitude_um".into(), size);
            (
                component,
                component,
                DiscoveredConfig::TimePeriodic(TimePeriodicConfig {
                    component,
                    period_s: period,
                    sin_um: size * phi.cos(),
                    cos_um: size * phi.sin(),
                }),
            )
        }
        FindingKind::Temperature => {
            let component = axis_of(&mut rng);
            // Peak error over a ±1 °C excursion.
            let k = sign(&mut rng) * size;
            params.insert("um_per_c".into(), k);
            (
                component,
                component,
                DiscoveredConfig::Temperature(TemperatureConfig {
                    component,
                    reference_temp_c: DEFAULT_TEMP_C,
                    um_per_c: k,
                }),
            )
        }
        FindingKind::Reversal => {
            let axis = axis_of(&mut rng);
            // Extra play B: ±B/2 after each direction, so B = 2·size.
            let b = 2.0 * size;
            params.insert("value_um".into(), b);
            let term = BacklashTerm::new(
                name,
                BacklashConfig {
                    axis,
                    backlash_um: b,
                },
            )?;
            return Ok(InjectedEffect {
                kind,
                axis,
                component: axis,
                params,
                term: Box::new(term),
            });
        }
        FindingKind::StepSize => {
            let axis = axis_of(&mut rng);
            // Lost motion (> 0) reached after moves ≫ λ; λ from 50 µm (a
            // 20 µm scan step already loses a third of it) to 1.5 mm (scan
            // steps lose ~1 %, the random moves of the plan, 0–9.5 mm,
            // span the build-up).
            let length = log_uniform(&mut rng, 50.0, 1500.0);
            params.insert("amplitude_um".into(), size);
            params.insert("length_um".into(), length);
            (
                axis,
                axis,
                DiscoveredConfig::StepSize(StepSizeConfig {
                    axis,
                    amplitude_um: size,
                    length_um: length,
                }),
            )
        }
        FindingKind::Other | FindingKind::ReversalVaries | FindingKind::Nonlinearity => {
            return Err(AnalysisError::Invalid(format!(
                "the generator cannot hide a `{}` effect (it can: {})",
                kind.as_str(),
                GENERATED_KINDS.map(|k| k.as_str()).join(", ")
            )))
        }
    };
    Ok(InjectedEffect {
        kind,
        axis,
        component,
        params,
        term: Box::new(DiscoveredTerm::new(name, cfg)?),
    })
}

/// The travel of axis `a` in `plan`, µm.
fn range_of(plan: &SimPlan, a: Axis) -> [f64; 2] {
    match a {
        Axis::X => plan.x_range_um,
        Axis::Y => plan.y_range_um,
    }
}

/// A periodic error along an axis, its period drawn within the travel.
fn position_periodic(
    rng: &mut ChaCha8Rng,
    size: f64,
    plan: &SimPlan,
    params: &mut BTreeMap<String, f64>,
) -> (Axis, Axis, DiscoveredConfig) {
    let axis = axis_of(rng);
    let component = axis_of(rng);
    let [lo, hi] = range_of(plan, axis);
    let period = log_uniform(rng, 600.0, (3000.0f64).min((hi - lo) / 2.5));
    let phi = rng.gen::<f64>() * std::f64::consts::TAU;
    params.insert("period_um".into(), period);
    params.insert("amplitude_um".into(), size);
    (
        axis,
        component,
        DiscoveredConfig::PositionPeriodic(PositionPeriodicConfig {
            axis,
            component,
            period_um: period,
            sin_um: size * phi.cos(),
            cos_um: size * phi.sin(),
        }),
    )
}

/// A scale error (`kind` `Scale`) or a cross-axis slope, reaching `size`
/// at the end of the travel.
fn position_slope(
    rng: &mut ChaCha8Rng,
    kind: FindingKind,
    size: f64,
    plan: &SimPlan,
    params: &mut BTreeMap<String, f64>,
) -> (Axis, Axis, DiscoveredConfig) {
    let axis = axis_of(rng);
    let component = if kind == FindingKind::Scale {
        axis
    } else {
        axis.other()
    };
    let ppm = sign(rng) * size / (range_of(plan, axis)[1] * 1e-6);
    params.insert(
        if kind == FindingKind::Scale {
            "ppm"
        } else {
            "slope_urad"
        }
        .into(),
        ppm,
    );
    (
        axis,
        component,
        DiscoveredConfig::PositionSlope(PositionSlopeConfig {
            axis,
            component,
            ppm,
        }),
    )
}

/// A local bump or dip, away from the ends of the travel.
fn localized(
    rng: &mut ChaCha8Rng,
    size: f64,
    plan: &SimPlan,
    params: &mut BTreeMap<String, f64>,
) -> (Axis, Axis, DiscoveredConfig) {
    let axis = axis_of(rng);
    let component = axis_of(rng);
    let [lo, hi] = range_of(plan, axis);
    let position = lo + (hi - lo) * (0.1 + 0.8 * rng.gen::<f64>());
    let width = log_uniform(rng, 60.0, 300.0);
    let amp = sign(rng) * size;
    params.insert("position_um".into(), position);
    params.insert("width_um".into(), width);
    params.insert("amplitude_um".into(), amp);
    (
        axis,
        component,
        DiscoveredConfig::Localized(LocalizedConfig {
            axis,
            component,
            position_um: position,
            width_um: width,
            amplitude_um: amp,
        }),
    )
}

/// The truth model: `base` plus the effect's term, with a seeded random-walk
/// temperature history (knots every 600 s, smooth) over the plan's duration.
pub fn truth_model(
    base: &StageModel,
    effect: Option<&InjectedEffect>,
    plan: &SimPlan,
    seed: u64,
) -> Result<StageModel, AnalysisError> {
    plan.validate()?;
    let mut m = base.clone();
    if let Some(e) = effect {
        m.push_term(e.term.clone())?;
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x7e3b_0000_0000_0001);
    let mut temperature = Vec::new();
    let mut t = 0.0;
    let mut temp = DEFAULT_TEMP_C;
    let end = plan.duration_s() + 600.0;
    while t <= end {
        temperature.push(TemperaturePoint {
            time_s: t,
            temp_c: temp,
        });
        let z: f64 = StandardNormal.sample(&mut rng);
        // Mean-reverting walk keeps the excursion near ±1 °C on long runs.
        temp += plan.temp_walk_c * z - 0.1 * (temp - DEFAULT_TEMP_C);
        t += 600.0;
    }
    m.set_environment(Environment {
        temperature_interpolation: Interpolation::Smooth,
        temperature,
    })?;
    Ok(m)
}

fn ramp(a: f64, b: f64, step: f64) -> Vec<f64> {
    let n = ((b - a).abs() / step).round() as usize;
    let s = if b >= a { step } else { -step };
    (0..=n).map(|i| a + s * i as f64).collect()
}

/// A synthetic log: records, columns (with `temp_c`) and metadata naming
/// the generator (not the hidden effect).
#[derive(Debug, Clone)]
pub struct SimLog {
    /// Measured points, in time order.
    pub records: Vec<Record>,
    /// Column set (`temp_c` present).
    pub columns: Columns,
    /// Metadata for the log header.
    pub metadata: Metadata,
}

/// Runs `truth` through the plan with the simulator (settling noise seeded
/// by `seed`) and adds camera noise.
pub fn simulate_log(
    truth: &StageModel,
    plan: &SimPlan,
    seed: u64,
) -> Result<SimLog, AnalysisError> {
    plan.validate()?;
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0xca3e_0000_0000_0002);
    let start = [plan.x_range_um[0] - 50.0, plan.x_scan_y_um];
    let mut sim = StageSimulator::new(
        truth.clone(),
        MotionState::at_rest(start[0], start[1]),
        seed,
    )?;
    let mut records = Vec::with_capacity(plan.points());
    let mut t = 0.0;
    let mut push = |sim: &mut StageSimulator,
                    rng: &mut ChaCha8Rng,
                    x: f64,
                    y: f64,
                    t: f64,
                    segment: &str,
                    cycle: u32|
     -> Result<(), AnalysisError> {
        let step = sim.move_to(x, y, t, cycle)?;
        let nx: f64 = StandardNormal.sample(rng);
        let ny: f64 = StandardNormal.sample(rng);
        records.push(Record {
            t_s: t,
            segment: segment.to_string(),
            cycle,
            x_target_um: x,
            y_target_um: y,
            x_cmd_um: x,
            y_cmd_um: y,
            x_meas_um: step.observed_um.x_um + plan.camera_sigma_um * nx,
            y_meas_um: step.observed_um.y_um + plan.camera_sigma_um * ny,
            temp_c: Some(step.state.temp_c),
            theta_urad: None,
            extra: Vec::new(),
        });
        Ok(())
    };
    push(&mut sim, &mut rng, start[0], start[1], t, "start", 0)?;
    for cycle in 0..plan.cycles {
        let [x0, x1] = plan.x_range_um;
        let xs: Vec<f64> = ramp(x0, x1, plan.step_um)
            .into_iter()
            .chain(ramp(x1, x0, plan.step_um))
            .collect();
        for x in xs {
            t += plan.dwell_s;
            push(&mut sim, &mut rng, x, plan.x_scan_y_um, t, "scan_x", cycle)?;
        }
        let [y0, y1] = plan.y_range_um;
        // Approach the first y point from below so its direction is known.
        let ys: Vec<f64> = ramp(y0, y1, plan.step_um)
            .into_iter()
            .chain(ramp(y1, y0, plan.step_um))
            .collect();
        for y in ys {
            t += plan.dwell_s;
            push(&mut sim, &mut rng, plan.y_scan_x_um, y, t, "scan_y", cycle)?;
        }
        for _ in 0..plan.random_points {
            t += plan.dwell_s;
            let x = x0 + (x1 - x0) * rng.gen::<f64>();
            let y = y0 + (y1 - y0) * rng.gen::<f64>();
            push(&mut sim, &mut rng, x, y, t, "random", cycle)?;
        }
    }
    let mut metadata = Metadata::new();
    metadata.insert("source", "micropos simlog (synthetic)");
    metadata.insert("seed", seed.to_string());
    metadata.insert("step_um", plan.step_um.to_string());
    Ok(SimLog {
        records,
        columns: Columns::new(true, Vec::new())?,
        metadata,
    })
}

/// A wandering logged quantity (e.g. relative humidity, %), seeded: mean
/// 45, knots every 300 s with σ 1.5 steps and mean reversion, linear in
/// between. Independent of the temperature walk (other seed stream).
fn wandering_series(times_s: &[f64], seed: u64) -> Vec<f64> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x0e47_a000_0000_0003);
    let t0 = times_s.first().copied().unwrap_or(0.0);
    let t1 = times_s.last().copied().unwrap_or(0.0);
    let mut knots = Vec::new();
    let mut v = 0.0;
    let mut t = t0;
    loop {
        knots.push((t, v));
        if t > t1 {
            break;
        }
        let z: f64 = StandardNormal.sample(&mut rng);
        v += 1.5 * z - 0.15 * v;
        t += 300.0;
    }
    times_s
        .iter()
        .map(|&t| {
            let k = knots.partition_point(|(kt, _)| *kt <= t).max(1) - 1;
            let (ta, va) = knots[k];
            let (tb, vb) = knots.get(k + 1).copied().unwrap_or((ta + 300.0, va));
            let w = ((t - ta) / (tb - ta)).clamp(0.0, 1.0);
            45.0 + va + w * (vb - va)
        })
        .collect()
}

/// Adds an extra numeric column `name` to `log`: a wandering quantity
/// (humidity-like, see the module docs) drawn from `seed`, written with 3
/// decimals. With `effect = Some((component, um_per_unit))` the measured
/// position of that component also moves by `um_per_unit·(value − mean)`
/// (model sign: added to the platform position). Returns the values as
/// written. Errors: a name the log format refuses (empty, repeated, a
/// standard column) or a non-finite slope.
pub fn add_extra_column(
    log: &mut SimLog,
    name: &str,
    seed: u64,
    effect: Option<(Axis, f64)>,
) -> Result<Vec<f64>, AnalysisError> {
    if let Some((_, k)) = effect {
        if !k.is_finite() {
            return Err(AnalysisError::Invalid(format!(
                "extra column effect must be finite, got {k} µm per unit"
            )));
        }
    }
    let mut extra = log.columns.extra.clone();
    extra.push(name.to_string());
    let columns = Columns::new(log.columns.temp_c, extra)?;
    let times: Vec<f64> = log.records.iter().map(|r| r.t_s).collect();
    // Rounded as written, so the effect follows the logged value exactly.
    let values: Vec<f64> = wandering_series(&times, seed)
        .into_iter()
        .map(|v| (v * 1000.0).round() / 1000.0)
        .collect();
    let mean = values.iter().sum::<f64>() / values.len().max(1) as f64;
    for (r, v) in log.records.iter_mut().zip(&values) {
        r.extra.push(format!("{v:.3}"));
        if let Some((c, k)) = effect {
            match c {
                Axis::X => r.x_meas_um += k * (v - mean),
                Axis::Y => r.y_meas_um += k * (v - mean),
            }
        }
    }
    log.columns = columns;
    Ok(values)
}

impl SimLog {
    /// The log as file bytes in the measurement log format.
    pub fn to_bytes(&self) -> Result<Vec<u8>, AnalysisError> {
        let mut w = crate::charact::log::LogWriter::create(
            Vec::new(),
            &self.metadata,
            self.columns.clone(),
            crate::charact::log::SyncPolicy::FlushOnly,
        )?;
        for r in &self.records {
            w.append(r)?;
        }
        Ok(w.into_inner())
    }
}
