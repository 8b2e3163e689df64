//! Terms the discrepancy analysis (`micropos diagnose`, `crate::analysis`)
//! adds to a model when the log shows an effect the model lacks.
//!
//! Why they are built-in kinds and not registered by the analysis at run
//! time: an extended model file written by `diagnose --out` must load
//! everywhere a model loads (`hil-sim --model`, `StageModel::from_toml`),
//! without the loader knowing about the analysis.
//!
//! Every term puts its error on one `component` (x or y) and, where it
//! depends on position, on the commanded position of one `axis` (the same
//! axis for a scale-like error, the other one for a cross-axis dependence).
//! Contributions follow the model's sign (added to the commanded position:
//! the paper's error `target − measured` is their negative).
//!
//! ```text
//! position_periodic:  d = s·sin(2π·p/P) + c·cos(2π·p/P)            p = cmd of `axis`
//! localized:          d = A·exp(−(p − p0)²/(2w²))                  (Gaussian bump, w = σ)
//! position_slope:     d = ppm·1e-6·p                               (zero at p = 0)
//! time_drift:         d = r·h + q·h²,  h = (t − t0)/3600 s          (zero at t0)
//! time_periodic:      d = s·sin(2π·t/T) + c·cos(2π·t/T)
//! temperature_linear: d = k·(temp − reference)
//! step_size:          d = −dir·A·(1 − exp(−L/λ))                   L = last move of `axis`
//! position_table:     d = T(p)            (lost_motion: d = −½·dir·T(p))
//!                     T = linear interpolation of `values_um` between `positions_um`,
//!                     constant beyond the first and last knot
//! ```
//! All are linear in their parameters except `localized` (position and
//! width) and `step_size` (length λ).
//!
//! `position_table` is what a metrologist reads from a test with few
//! targets (an ISO 230-2 plan): a per-target table, not a formula. With
//! `lost_motion = false` it is a non-linearity of the drive (the
//! bidirectional mean deviation between targets); with `lost_motion = true`
//! it is a reversal table, lost motion that changes along the travel (a
//! constant play cannot follow it). Between knots the error is interpolated
//! linearly: nothing is claimed about structure shorter than the knot
//! spacing.
//!
//! `step_size` is lost motion that depends on the length `L` of the axis's
//! last single commanded move ([`crate::model::AxisMotion::last_move_um`]):
//! a short move leaves the platform short by little, a move much longer than
//! λ by the full `A` (µm, > 0 = lost motion: the platform trails the command
//! in the direction it moved, `dir` = +1 forward, −1 backward, 0 before any
//! motion). Physically: elastic wind-up of screw, coupling or nut, or guide
//! friction, that is only fully loaded after a long move. It differs from
//! the `backlash` play, which depends on the direction and on the travel
//! since the last reversal (and is fully taken up after a few µm), not on
//! the length of one move: ten 20 µm steps in one direction have a 200 µm
//! run but a 20 µm last move. The error sits on the axis's own component.

use serde::{Deserialize, Serialize};

use super::super::state::{Axis, MotionState, DEFAULT_TEMP_C};
use super::super::term::{
    check_param_values, config_table, parse_term_config, require_finite, require_positive,
    ParamInfo, Term,
};
use super::super::ModelError;

/// Kind name: periodic error in position at any period.
pub const POSITION_PERIODIC_KIND: &str = "position_periodic";
/// Kind name: localized (Gaussian) error feature along an axis.
pub const LOCALIZED_KIND: &str = "localized";
/// Kind name: error proportional to an axis position (scale or cross-axis slope).
pub const POSITION_SLOPE_KIND: &str = "position_slope";
/// Kind name: slow drift with time.
pub const TIME_DRIFT_KIND: &str = "time_drift";
/// Kind name: periodic error in time.
pub const TIME_PERIODIC_KIND: &str = "time_periodic";
/// Kind name: error proportional to the temperature difference.
pub const TEMPERATURE_KIND: &str = "temperature_linear";
/// Kind name: lost motion that saturates with the length of the last move.
pub const STEP_SIZE_KIND: &str = "step_size";
/// Kind name: error (or lost motion) tabulated at knots along an axis.
pub const POSITION_TABLE_KIND: &str = "position_table";

fn default_reference_temp_c() -> f64 {
    DEFAULT_TEMP_C
}

/// `position_periodic` table.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PositionPeriodicConfig {
    /// Axis whose commanded position sets the phase.
    pub axis: Axis,
    /// Error component the term moves.
    pub component: Axis,
    /// Period, µm of `axis` travel (> 0).
    pub period_um: f64,
    /// Sine amplitude, µm.
    pub sin_um: f64,
    /// Cosine amplitude, µm.
    pub cos_um: f64,
}

/// `localized` table.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LocalizedConfig {
    /// Axis along which the feature sits.
    pub axis: Axis,
    /// Error component the term moves.
    pub component: Axis,
    /// Centre, µm of commanded `axis` position.
    pub position_um: f64,
    /// Gaussian σ, µm (> 0).
    pub width_um: f64,
    /// Peak error, µm (signed).
    pub amplitude_um: f64,
}

/// `position_slope` table.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PositionSlopeConfig {
    /// Axis whose position the error is proportional to.
    pub axis: Axis,
    /// Error component the term moves.
    pub component: Axis,
    /// Slope, ppm (µm of error per m of `axis` position; µrad when the
    /// component is the other axis).
    pub ppm: f64,
}

/// `time_drift` table.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TimeDriftConfig {
    /// Error component the term moves.
    pub component: Axis,
    /// Time at which the drift is zero, s.
    #[serde(default)]
    pub start_time_s: f64,
    /// Linear rate, µm per hour.
    pub rate_um_per_h: f64,
    /// Quadratic coefficient, µm per hour².
    #[serde(default)]
    pub curvature_um_per_h2: f64,
}

/// `time_periodic` table.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TimePeriodicConfig {
    /// Error component the term moves.
    pub component: Axis,
    /// Period, s (> 0).
    pub period_s: f64,
    /// Sine amplitude, µm.
    pub sin_um: f64,
    /// Cosine amplitude, µm.
    pub cos_um: f64,
}

/// `temperature_linear` table.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TemperatureConfig {
    /// Error component the term moves.
    pub component: Axis,
    /// Temperature at which the term is zero, °C.
    #[serde(default = "default_reference_temp_c")]
    pub reference_temp_c: f64,
    /// Sensitivity, µm per °C.
    pub um_per_c: f64,
}

/// `step_size` table: lost motion `A·(1 − exp(−L/λ))` against the direction
/// of the last move, `L` its length (see the module docs).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StepSizeConfig {
    /// Axis whose last move sets the error; the error is on this axis's own
    /// component.
    pub axis: Axis,
    /// Lost motion after a move much longer than `length_um`, µm (> 0: the
    /// platform trails the command; < 0: it overshoots).
    pub amplitude_um: f64,
    /// Move length λ over which the lost motion builds up, µm (> 0): after a
    /// move of λ it is 63 % of `amplitude_um`.
    pub length_um: f64,
}

/// `position_table` table: an error tabulated at knots along `axis`,
/// interpolated linearly between them (see the module docs).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PositionTableConfig {
    /// Axis whose commanded position indexes the table.
    pub axis: Axis,
    /// Error component the term moves (for a lost-motion table, `axis`).
    pub component: Axis,
    /// Knots, µm of commanded `axis` position, strictly increasing (≥ 2).
    pub positions_um: Vec<f64>,
    /// Value at each knot, µm (same length as `positions_um`): the error,
    /// or with `lost_motion` the lost motion (> 0: the platform trails the
    /// command in the direction it moved, as a play does).
    pub values_um: Vec<f64>,
    /// Whether the table is lost motion: the contribution is `−½·dir·T(p)`
    /// (`dir` of `axis`: +1 forward, −1 backward, 0 unknown).
    #[serde(default)]
    pub lost_motion: bool,
}

impl PositionTableConfig {
    /// `T(p)`: linear between knots, the end values beyond them.
    pub fn table_um(&self, p_um: f64) -> f64 {
        table_weights(&self.positions_um, p_um)
            .map(|(k, w)| {
                let a = self.values_um.get(k).copied().unwrap_or(0.0);
                let b = self.values_um.get(k + 1).copied().unwrap_or(a);
                a + w * (b - a)
            })
            .unwrap_or(0.0)
    }
}

/// `(k, w)`: `p` lies between knot `k` and `k + 1` at fraction `w` (0 at or
/// below the first knot, 1 at or beyond the last: `k` is then the second
/// last); `None` without two knots or for a non-finite `p`.
pub fn table_weights(knots_um: &[f64], p_um: f64) -> Option<(usize, f64)> {
    if knots_um.len() < 2 || !p_um.is_finite() {
        return None;
    }
    let last = knots_um.len() - 2;
    let k = knots_um
        .partition_point(|&q| q <= p_um)
        .saturating_sub(1)
        .min(last);
    let (a, b) = (knots_um[k], knots_um[k + 1]);
    let w = if b > a {
        ((p_um - a) / (b - a)).clamp(0.0, 1.0)
    } else {
        0.0
    };
    Some((k, w))
}

/// Hat-function values of the knots at `p` (each knot's weight in the
/// linear interpolation; they sum to 1): the table's basis, one entry per
/// knot.
pub fn table_basis(knots_um: &[f64], p_um: f64) -> Vec<f64> {
    let mut out = vec![0.0; knots_um.len()];
    if let Some((k, w)) = table_weights(knots_um, p_um) {
        out[k] += 1.0 - w;
        out[k + 1] += w;
    }
    out
}

/// The configuration of a discovered term, one variant per kind.
#[derive(Debug, Clone, PartialEq)]
pub enum DiscoveredConfig {
    /// See [`PositionPeriodicConfig`].
    PositionPeriodic(PositionPeriodicConfig),
    /// See [`LocalizedConfig`].
    Localized(LocalizedConfig),
    /// See [`PositionSlopeConfig`].
    PositionSlope(PositionSlopeConfig),
    /// See [`TimeDriftConfig`].
    TimeDrift(TimeDriftConfig),
    /// See [`TimePeriodicConfig`].
    TimePeriodic(TimePeriodicConfig),
    /// See [`TemperatureConfig`].
    Temperature(TemperatureConfig),
    /// See [`StepSizeConfig`].
    StepSize(StepSizeConfig),
    /// See [`PositionTableConfig`].
    PositionTable(PositionTableConfig),
}

impl DiscoveredConfig {
    fn kind(&self) -> &'static str {
        match self {
            DiscoveredConfig::PositionPeriodic(_) => POSITION_PERIODIC_KIND,
            DiscoveredConfig::Localized(_) => LOCALIZED_KIND,
            DiscoveredConfig::PositionSlope(_) => POSITION_SLOPE_KIND,
            DiscoveredConfig::TimeDrift(_) => TIME_DRIFT_KIND,
            DiscoveredConfig::TimePeriodic(_) => TIME_PERIODIC_KIND,
            DiscoveredConfig::Temperature(_) => TEMPERATURE_KIND,
            DiscoveredConfig::StepSize(_) => STEP_SIZE_KIND,
            DiscoveredConfig::PositionTable(_) => POSITION_TABLE_KIND,
        }
    }

    fn component(&self) -> Axis {
        match self {
            DiscoveredConfig::PositionPeriodic(c) => c.component,
            DiscoveredConfig::Localized(c) => c.component,
            DiscoveredConfig::PositionSlope(c) => c.component,
            DiscoveredConfig::TimeDrift(c) => c.component,
            DiscoveredConfig::TimePeriodic(c) => c.component,
            DiscoveredConfig::Temperature(c) => c.component,
            DiscoveredConfig::StepSize(c) => c.axis,
            DiscoveredConfig::PositionTable(c) => c.component,
        }
    }

    fn validate(&self, name: &str) -> Result<(), ModelError> {
        match self {
            DiscoveredConfig::PositionPeriodic(c) => {
                require_positive(name, "period_um", c.period_um)?;
                require_finite(name, "sin_um", c.sin_um)?;
                require_finite(name, "cos_um", c.cos_um)?;
            }
            DiscoveredConfig::Localized(c) => {
                require_finite(name, "position_um", c.position_um)?;
                require_positive(name, "width_um", c.width_um)?;
                require_finite(name, "amplitude_um", c.amplitude_um)?;
            }
            DiscoveredConfig::PositionSlope(c) => {
                require_finite(name, "ppm", c.ppm)?;
            }
            DiscoveredConfig::TimeDrift(c) => {
                require_finite(name, "start_time_s", c.start_time_s)?;
                require_finite(name, "rate_um_per_h", c.rate_um_per_h)?;
                require_finite(name, "curvature_um_per_h2", c.curvature_um_per_h2)?;
            }
            DiscoveredConfig::TimePeriodic(c) => {
                require_positive(name, "period_s", c.period_s)?;
                require_finite(name, "sin_um", c.sin_um)?;
                require_finite(name, "cos_um", c.cos_um)?;
            }
            DiscoveredConfig::Temperature(c) => {
                require_finite(name, "reference_temp_c", c.reference_temp_c)?;
                require_finite(name, "um_per_c", c.um_per_c)?;
            }
            DiscoveredConfig::StepSize(c) => {
                require_finite(name, "amplitude_um", c.amplitude_um)?;
                require_positive(name, "length_um", c.length_um)?;
            }
            DiscoveredConfig::PositionTable(c) => {
                let bad = |why: &str| ModelError::Invalid {
                    key: format!("term `{name}`: positions_um"),
                    reason: why.to_string(),
                };
                if c.positions_um.len() < 2 {
                    return Err(bad("needs at least two knots"));
                }
                if c.values_um.len() != c.positions_um.len() {
                    return Err(ModelError::Invalid {
                        key: format!("term `{name}`: values_um"),
                        reason: "needs one value per knot of positions_um".into(),
                    });
                }
                for (k, (&p, &v)) in c.positions_um.iter().zip(&c.values_um).enumerate() {
                    require_finite(name, &format!("positions_um[{k}]"), p)?;
                    require_finite(name, &format!("values_um[{k}]"), v)?;
                }
                if c.positions_um.windows(2).any(|w| w[1] <= w[0]) {
                    return Err(bad("must be strictly increasing"));
                }
            }
        }
        Ok(())
    }
}

/// A term found by the discrepancy analysis; see the module docs.
#[derive(Debug, Clone, PartialEq)]
pub struct DiscoveredTerm {
    name: String,
    cfg: DiscoveredConfig,
}

impl DiscoveredTerm {
    /// Builds and validates.
    pub fn new(name: &str, cfg: DiscoveredConfig) -> Result<Self, ModelError> {
        cfg.validate(name)?;
        Ok(DiscoveredTerm {
            name: name.to_string(),
            cfg,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &DiscoveredConfig {
        &self.cfg
    }
}

/// `(sin, cos)` of `2π·v/period`, with `v` reduced modulo the period first
/// so large positions or times stay exact.
fn phase(v: f64, period: f64) -> (f64, f64) {
    let frac = v.rem_euclid(period) / period;
    (std::f64::consts::TAU * frac).sin_cos()
}

/// Basis value(s) of a linear term at `state` (one per parameter).
fn linear_basis(cfg: &DiscoveredConfig, state: &MotionState) -> Vec<f64> {
    match cfg {
        DiscoveredConfig::PositionPeriodic(c) => {
            let (s, co) = phase(state.cmd_um(c.axis), c.period_um);
            vec![s, co]
        }
        DiscoveredConfig::PositionSlope(c) => vec![1e-6 * state.cmd_um(c.axis)],
        DiscoveredConfig::TimeDrift(c) => {
            let h = (state.time_s - c.start_time_s) / 3600.0;
            vec![h, h * h]
        }
        DiscoveredConfig::TimePeriodic(c) => {
            let (s, co) = phase(state.time_s, c.period_s);
            vec![s, co]
        }
        DiscoveredConfig::Temperature(c) => vec![state.temp_c - c.reference_temp_c],
        DiscoveredConfig::Localized(c) => {
            let z = (state.cmd_um(c.axis) - c.position_um) / c.width_um.abs().max(1e-9);
            // Beyond 40σ the bump is below 1e-300: exactly zero, no underflow games.
            vec![if z.abs() > 40.0 {
                0.0
            } else {
                (-0.5 * z * z).exp()
            }]
        }
        DiscoveredConfig::StepSize(c) => vec![step_size_shape(
            state.axis(c.axis).dir.sign(),
            state.axis(c.axis).last_move_um,
            c.length_um,
        )],
        DiscoveredConfig::PositionTable(c) => {
            let f = if c.lost_motion {
                -0.5 * state.axis(c.axis).dir.sign()
            } else {
                1.0
            };
            table_basis(&c.positions_um, state.cmd_um(c.axis))
                .into_iter()
                .map(|b| f * b)
                .collect()
        }
    }
}

/// `−dir·(1 − exp(−L/λ))`: the `step_size` term per µm of amplitude. A
/// non-positive λ (possible mid-fit) is read as |λ| floored at 1e-9 µm, so
/// the value stays finite; an infinite `L` gives the saturated value.
pub fn step_size_shape(dir_sign: f64, last_move_um: f64, length_um: f64) -> f64 {
    let lambda = length_um.abs().max(1e-9);
    let x = (last_move_um / lambda).max(0.0);
    // 1 − e^(−x) = −expm1(−x), exact for small x.
    dir_sign * (-x).exp_m1()
}

impl Term for DiscoveredTerm {
    fn name(&self) -> &str {
        &self.name
    }

    fn kind(&self) -> &'static str {
        self.cfg.kind()
    }

    fn params(&self) -> Vec<ParamInfo> {
        let comp = self.cfg.component();
        match &self.cfg {
            DiscoveredConfig::PositionPeriodic(c) => vec![
                ParamInfo::new(
                    "sin_um",
                    "µm",
                    c.sin_um,
                    format!("{comp} error ∝ sin(2π·{}/{} µm)", c.axis, c.period_um),
                ),
                ParamInfo::new(
                    "cos_um",
                    "µm",
                    c.cos_um,
                    format!("{comp} error ∝ cos(2π·{}/{} µm)", c.axis, c.period_um),
                ),
            ],
            DiscoveredConfig::Localized(c) => vec![
                ParamInfo::new(
                    "amplitude_um",
                    "µm",
                    c.amplitude_um,
                    format!("peak {comp} error of the feature"),
                ),
                ParamInfo::new(
                    "position_um",
                    "µm",
                    c.position_um,
                    format!("centre of the feature along {}", c.axis),
                ),
                ParamInfo::new(
                    "width_um",
                    "µm",
                    c.width_um,
                    "Gaussian σ of the feature".to_string(),
                ),
            ],
            DiscoveredConfig::PositionSlope(c) => vec![ParamInfo::new(
                "ppm",
                "ppm",
                c.ppm,
                format!("{comp} error per unit of {} position", c.axis),
            )],
            DiscoveredConfig::TimeDrift(c) => vec![
                ParamInfo::new(
                    "rate_um_per_h",
                    "µm/h",
                    c.rate_um_per_h,
                    format!("linear {comp} drift"),
                ),
                ParamInfo::new(
                    "curvature_um_per_h2",
                    "µm/h²",
                    c.curvature_um_per_h2,
                    format!("quadratic {comp} drift"),
                ),
            ],
            DiscoveredConfig::TimePeriodic(c) => vec![
                ParamInfo::new(
                    "sin_um",
                    "µm",
                    c.sin_um,
                    format!("{comp} error ∝ sin(2π·t/{} s)", c.period_s),
                ),
                ParamInfo::new(
                    "cos_um",
                    "µm",
                    c.cos_um,
                    format!("{comp} error ∝ cos(2π·t/{} s)", c.period_s),
                ),
            ],
            DiscoveredConfig::Temperature(c) => vec![ParamInfo::new(
                "um_per_c",
                "µm/°C",
                c.um_per_c,
                format!("{comp} error per °C from the reference"),
            )],
            DiscoveredConfig::StepSize(c) => vec![
                ParamInfo::new(
                    "amplitude_um",
                    "µm",
                    c.amplitude_um,
                    format!("{comp} lost motion after a move much longer than length_um"),
                ),
                ParamInfo::new(
                    "length_um",
                    "µm",
                    c.length_um,
                    format!(
                        "{} move length over which the lost motion builds up",
                        c.axis
                    ),
                ),
            ],
            DiscoveredConfig::PositionTable(c) => c
                .positions_um
                .iter()
                .zip(&c.values_um)
                .enumerate()
                .map(|(k, (p, v))| {
                    let what = if c.lost_motion {
                        format!("{} lost motion", c.axis)
                    } else {
                        format!("{comp} error")
                    };
                    ParamInfo::new(
                        format!("value{k}_um"),
                        "µm",
                        *v,
                        format!("{what} at {} = {p} µm", c.axis),
                    )
                })
                .collect(),
        }
    }

    fn set_params(&mut self, values: &[f64]) -> Result<(), ModelError> {
        let n = self.params().len();
        check_param_values(&self.name, n, values)?;
        let mut next = self.cfg.clone();
        match &mut next {
            DiscoveredConfig::PositionPeriodic(c) => {
                c.sin_um = values[0];
                c.cos_um = values[1];
            }
            DiscoveredConfig::Localized(c) => {
                c.amplitude_um = values[0];
                c.position_um = values[1];
                c.width_um = values[2];
            }
            DiscoveredConfig::PositionSlope(c) => c.ppm = values[0],
            DiscoveredConfig::TimeDrift(c) => {
                c.rate_um_per_h = values[0];
                c.curvature_um_per_h2 = values[1];
            }
            DiscoveredConfig::TimePeriodic(c) => {
                c.sin_um = values[0];
                c.cos_um = values[1];
            }
            DiscoveredConfig::Temperature(c) => c.um_per_c = values[0],
            DiscoveredConfig::StepSize(c) => {
                c.amplitude_um = values[0];
                c.length_um = values[1];
            }
            DiscoveredConfig::PositionTable(c) => c.values_um = values.to_vec(),
        }
        // Values from a fit may be anything finite (checked above); a
        // negative or zero width or length is read as |w| (floored) by the evaluation,
        // so every contribution stays finite.
        self.cfg = next;
        Ok(())
    }

    fn contribution(&self, state: &MotionState) -> [f64; 2] {
        let basis = linear_basis(&self.cfg, state);
        let v = match &self.cfg {
            DiscoveredConfig::Localized(c) => c.amplitude_um * basis[0],
            DiscoveredConfig::StepSize(c) => c.amplitude_um * basis[0],
            _ => self
                .params()
                .iter()
                .zip(&basis)
                .map(|(p, b)| p.value * b)
                .sum(),
        };
        let mut out = [0.0; 2];
        out[self.cfg.component().index()] = v;
        out
    }

    fn is_linear(&self) -> bool {
        !matches!(
            self.cfg,
            DiscoveredConfig::Localized(_) | DiscoveredConfig::StepSize(_)
        )
    }

    fn jacobian(&self, state: &MotionState) -> Vec<[f64; 2]> {
        if !self.is_linear() {
            return super::super::term::numeric_jacobian(self, state);
        }
        let i = self.cfg.component().index();
        linear_basis(&self.cfg, state)
            .into_iter()
            .map(|b| {
                let mut d = [0.0; 2];
                d[i] = b;
                d
            })
            .collect()
    }

    fn to_config(&self) -> Result<toml::Table, ModelError> {
        match &self.cfg {
            DiscoveredConfig::PositionPeriodic(c) => config_table(&self.name, c),
            DiscoveredConfig::Localized(c) => config_table(&self.name, c),
            DiscoveredConfig::PositionSlope(c) => config_table(&self.name, c),
            DiscoveredConfig::TimeDrift(c) => config_table(&self.name, c),
            DiscoveredConfig::TimePeriodic(c) => config_table(&self.name, c),
            DiscoveredConfig::Temperature(c) => config_table(&self.name, c),
            DiscoveredConfig::StepSize(c) => config_table(&self.name, c),
            DiscoveredConfig::PositionTable(c) => config_table(&self.name, c),
        }
    }

    fn clone_box(&self) -> Box<dyn Term> {
        Box::new(self.clone())
    }
}

fn boxed(name: &str, cfg: DiscoveredConfig) -> Result<Box<dyn Term>, ModelError> {
    Ok(Box::new(DiscoveredTerm::new(name, cfg)?))
}

pub(crate) fn build_position_periodic(
    name: &str,
    table: toml::Table,
) -> Result<Box<dyn Term>, ModelError> {
    let c = parse_term_config(name, POSITION_PERIODIC_KIND, table)?;
    boxed(name, DiscoveredConfig::PositionPeriodic(c))
}

pub(crate) fn build_localized(name: &str, table: toml::Table) -> Result<Box<dyn Term>, ModelError> {
    let c = parse_term_config(name, LOCALIZED_KIND, table)?;
    boxed(name, DiscoveredConfig::Localized(c))
}

pub(crate) fn build_position_slope(
    name: &str,
    table: toml::Table,
) -> Result<Box<dyn Term>, ModelError> {
    let c = parse_term_config(name, POSITION_SLOPE_KIND, table)?;
    boxed(name, DiscoveredConfig::PositionSlope(c))
}

pub(crate) fn build_time_drift(
    name: &str,
    table: toml::Table,
) -> Result<Box<dyn Term>, ModelError> {
    let c = parse_term_config(name, TIME_DRIFT_KIND, table)?;
    boxed(name, DiscoveredConfig::TimeDrift(c))
}

pub(crate) fn build_time_periodic(
    name: &str,
    table: toml::Table,
) -> Result<Box<dyn Term>, ModelError> {
    let c = parse_term_config(name, TIME_PERIODIC_KIND, table)?;
    boxed(name, DiscoveredConfig::TimePeriodic(c))
}

pub(crate) fn build_temperature(
    name: &str,
    table: toml::Table,
) -> Result<Box<dyn Term>, ModelError> {
    let c = parse_term_config(name, TEMPERATURE_KIND, table)?;
    boxed(name, DiscoveredConfig::Temperature(c))
}

pub(crate) fn build_step_size(name: &str, table: toml::Table) -> Result<Box<dyn Term>, ModelError> {
    let c = parse_term_config(name, STEP_SIZE_KIND, table)?;
    boxed(name, DiscoveredConfig::StepSize(c))
}

pub(crate) fn build_position_table(
    name: &str,
    table: toml::Table,
) -> Result<Box<dyn Term>, ModelError> {
    let c = parse_term_config(name, POSITION_TABLE_KIND, table)?;
    boxed(name, DiscoveredConfig::PositionTable(c))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::{Direction, StageModel};

    #[test]
    fn values_and_round_trip() {
        let t = DiscoveredTerm::new(
            "p",
            DiscoveredConfig::PositionPeriodic(PositionPeriodicConfig {
                axis: Axis::X,
                component: Axis::Y,
                period_um: 1600.0,
                sin_um: 0.8,
                cos_um: 0.0,
            }),
        )
        .unwrap();
        let c = t.contribution(&MotionState::at_rest(400.0, 0.0));
        assert!((c[1] - 0.8).abs() < 1e-12 && c[0] == 0.0, "{c:?}");
        let b = DiscoveredTerm::new(
            "b",
            DiscoveredConfig::Localized(LocalizedConfig {
                axis: Axis::Y,
                component: Axis::Y,
                position_um: 1000.0,
                width_um: 50.0,
                amplitude_um: -0.5,
            }),
        )
        .unwrap();
        let c = b.contribution(&MotionState::at_rest(0.0, 1050.0));
        assert!((c[1] + 0.5 * (-0.5f64).exp()).abs() < 1e-12);
        let mut m = StageModel::ideal();
        m.push_term(Box::new(t)).unwrap();
        m.push_term(Box::new(b)).unwrap();
        let text = m.to_toml().unwrap();
        let back = StageModel::from_toml(&text).unwrap();
        assert_eq!(back.parameter_vector(), m.parameter_vector());
        let mut odd = back.clone();
        odd.set_param("b.width_um", -50.0).unwrap();
        let c2 = odd.observed_error_um(&MotionState::at_rest(0.0, 1050.0));
        assert!((c2[1] + 0.5 * (-0.5f64).exp()).abs() < 1e-12);
        odd.set_param("b.width_um", 0.0).unwrap();
        assert!(odd.observed_error_um(&MotionState::at_rest(0.0, 1000.0))[1].is_finite());
        assert!(StageModel::from_toml(&text.replace("width_um = 50.0", "width_um = 0.0")).is_err());
    }

    #[test]
    fn drift_temperature_and_slope() {
        let mut s = MotionState::at_rest(2000.0, 0.0);
        s.time_s = 7200.0;
        s.temp_c = 21.0;
        let d = DiscoveredTerm::new(
            "d",
            DiscoveredConfig::TimeDrift(TimeDriftConfig {
                component: Axis::X,
                start_time_s: 0.0,
                rate_um_per_h: 0.5,
                curvature_um_per_h2: 0.1,
            }),
        )
        .unwrap();
        assert!((d.contribution(&s)[0] - 1.4).abs() < 1e-12);
        let k = DiscoveredTerm::new(
            "k",
            DiscoveredConfig::Temperature(TemperatureConfig {
                component: Axis::Y,
                reference_temp_c: 20.0,
                um_per_c: 0.3,
            }),
        )
        .unwrap();
        assert!((k.contribution(&s)[1] - 0.3).abs() < 1e-12);
        let p = DiscoveredTerm::new(
            "p",
            DiscoveredConfig::PositionSlope(PositionSlopeConfig {
                axis: Axis::X,
                component: Axis::Y,
                ppm: 50.0,
            }),
        )
        .unwrap();
        assert!((p.contribution(&s)[1] - 0.1).abs() < 1e-12);
        assert_eq!(p.jacobian(&s)[0], [0.0, 2000.0e-6]);
    }

    #[test]
    fn step_size_saturates_with_the_last_move_and_opposes_it() {
        let t = DiscoveredTerm::new(
            "s",
            DiscoveredConfig::StepSize(StepSizeConfig {
                axis: Axis::Y,
                amplitude_um: 0.4,
                length_um: 100.0,
            }),
        )
        .unwrap();
        let mut s = MotionState::at_rest(0.0, 500.0);
        // Not moved yet: no lost motion.
        assert_eq!(t.contribution(&s), [0.0, 0.0]);
        // A forward move of λ: 63 % of A, behind the command (negative).
        s.axes[1].dir = Direction::Forward;
        s.axes[1].run_um = 1000.0;
        s.axes[1].last_move_um = 100.0;
        let c = t.contribution(&s);
        let want = -0.4 * (1.0 - (-1.0f64).exp());
        assert!(c[0] == 0.0 && (c[1] - want).abs() < 1e-12, "{c:?}");
        // Same run, shorter last move: less lost motion (the play term
        // would not tell these apart).
        s.axes[1].last_move_um = 20.0;
        let want20 = -0.4 * (1.0 - (-0.2f64).exp());
        assert!((t.contribution(&s)[1] - want20).abs() < 1e-12);
        // Backward, very long (and infinite) move: +A.
        s.axes[1].dir = Direction::Backward;
        s.axes[1].last_move_um = 1e6;
        assert!((t.contribution(&s)[1] - 0.4).abs() < 1e-12);
        let arrived = MotionState::arrived(0.0, Direction::Forward, 0.0, Direction::Backward);
        assert!((t.contribution(&arrived)[1] - 0.4).abs() < 1e-12);
        // Jacobian: amplitude column is the shape, length column numeric.
        s.axes[1].last_move_um = 50.0;
        let j = t.jacobian(&s);
        let shape = 1.0 - (-0.5f64).exp();
        assert!((j[0][1] - shape).abs() < 1e-6, "{j:?}");
        // d/dλ of A(1 − e^(−L/λ)) = −A·L/λ²·e^(−L/λ), times −dir = +1.
        let dl = -0.4 * 50.0 / 1e4 * (-0.5f64).exp();
        assert!((j[1][1] - dl).abs() < 1e-6, "{j:?} vs {dl}");
        // Round trip through a model file; a zero length is refused.
        let mut m = StageModel::ideal();
        m.push_term(Box::new(t)).unwrap();
        let text = m.to_toml().unwrap();
        assert!(text.contains("kind = \"step_size\""), "{text}");
        let back = StageModel::from_toml(&text).unwrap();
        assert_eq!(back.parameter_vector(), m.parameter_vector());
        assert!(
            StageModel::from_toml(&text.replace("length_um = 100.0", "length_um = 0.0")).is_err()
        );
        let mut odd = back.clone();
        odd.set_param("s.length_um", 0.0).unwrap();
        assert!(odd.observed_error_um(&s)[1].is_finite());
    }

    #[test]
    fn position_table_interpolates_and_carries_lost_motion() {
        let cfg = PositionTableConfig {
            axis: Axis::X,
            component: Axis::X,
            positions_um: vec![0.0, 1000.0, 3000.0],
            values_um: vec![1.0, -1.0, 3.0],
            lost_motion: false,
        };
        let t = DiscoveredTerm::new("t", DiscoveredConfig::PositionTable(cfg.clone())).unwrap();
        let at = |x: f64| t.contribution(&MotionState::at_rest(x, 0.0))[0];
        // At the knots, between them, and constant beyond the ends.
        assert!((at(1000.0) + 1.0).abs() < 1e-12);
        assert!((at(500.0) - 0.0).abs() < 1e-12);
        assert!((at(2000.0) - 1.0).abs() < 1e-12);
        assert!((at(-50.0) - 1.0).abs() < 1e-12 && (at(9e9) - 3.0).abs() < 1e-12);
        assert_eq!(
            t.contribution(&MotionState::at_rest(f64::NAN, 0.0)),
            [0.0, 0.0]
        );
        // Linear in its values: the Jacobian is the hat functions.
        let j = t.jacobian(&MotionState::at_rest(2500.0, 0.0));
        assert_eq!(j.len(), 3);
        assert!((j[1][0] - 0.25).abs() < 1e-12 && (j[2][0] - 0.75).abs() < 1e-12);
        // Lost motion: −½·dir·T, the play's sign (forward: short of target).
        let lm = DiscoveredTerm::new(
            "r",
            DiscoveredConfig::PositionTable(PositionTableConfig {
                lost_motion: true,
                ..cfg
            }),
        )
        .unwrap();
        let fwd = MotionState::arrived(3000.0, Direction::Forward, 0.0, Direction::Unknown);
        let bwd = MotionState::arrived(3000.0, Direction::Backward, 0.0, Direction::Unknown);
        assert!((lm.contribution(&fwd)[0] + 1.5).abs() < 1e-12);
        assert!((lm.contribution(&bwd)[0] - 1.5).abs() < 1e-12);
        // Round trip; malformed tables are refused with the key named.
        let mut m = StageModel::ideal();
        m.push_term(Box::new(lm)).unwrap();
        let text = m.to_toml().unwrap();
        let back = StageModel::from_toml(&text).unwrap();
        assert_eq!(back.parameter_vector(), m.parameter_vector());
        for bad in [
            text.replace(
                "positions_um = [0.0, 1000.0, 3000.0]",
                "positions_um = [0.0, 3000.0, 1000.0]",
            ),
            text.replace(
                "positions_um = [0.0, 1000.0, 3000.0]",
                "positions_um = [0.0, 1000.0]",
            ),
            text.replace(
                "positions_um = [0.0, 1000.0, 3000.0]",
                "positions_um = [0.0]",
            ),
        ] {
            assert_ne!(bad, text, "the replacement must apply: {text}");
            let e = StageModel::from_toml(&bad).unwrap_err().to_string();
            assert!(e.contains("_um"), "{e}");
        }
    }
}
