//! Model-based compensation: fit the parametric stage model (harmonics of
//! the screw lead, backlash, cross coupling, squareness, lead error,
//! angular errors × Abbe arms) to the scans and predict the error anywhere.
//!
//! Why: a table needs points closer than the ripple it interpolates (the
//! paper: 5 µm on a 400 µm screw, 9.5 h of measurement); a model with the
//! right structure needs a few points per harmonic (50 µm steps: 10× fewer
//! points), averages the settling noise over all of them, and behaves
//! sensibly between and beyond the points (periodic terms stay periodic,
//! squareness and lead stay linear). The price: errors the model has no
//! term for stay uncompensated (the fit report's residual says how much).
//!
//! The log only holds the measured points, not the unlogged approach moves
//! of the scan plan; the replay re-creates them (`approach_um` before each
//! point whose inferred direction differs from the tracked one) so that the
//! fitted states carry the right direction and play.

use serde::{Deserialize, Serialize};

use super::table::infer_directions;
use super::{invalid, CompError, Compensator};
use crate::charact::log::Record;
use crate::charact::scan::{SEGMENT_MOVES, SEGMENT_SCAN_X, SEGMENT_SCAN_Y};
use crate::model::terms::offset::{OriginOffsetConfig, OriginOffsetTerm, KIND as OFFSET_KIND};
use crate::model::{
    Axis, Direction, Effect, FitOptions, FitReport, MotionState, MotionTracker, Sample, StageModel,
    Waypoint, DEFAULT_TEMP_C,
};

/// Compensation by a fitted [`StageModel`]: the predicted offset is
/// `observed_error_um` (platform and observation terms: the camera is the
/// reference).
#[derive(Debug, Clone)]
pub struct ModelCompensator {
    model: StageModel,
    area: Option<super::Area>,
}

impl ModelCompensator {
    /// Wraps a model (e.g. loaded from a compensation file).
    pub fn new(model: StageModel) -> Self {
        ModelCompensator { model, area: None }
    }

    /// The same, knowing the area its scans covered (a compensation file's
    /// `[area]`).
    pub fn with_area(mut self, area: Option<super::Area>) -> Self {
        self.area = area;
        self
    }

    /// The model.
    pub fn model(&self) -> &StageModel {
        &self.model
    }

    /// Fits `template` (see [`compensation_template`]) to the scan records
    /// of a log and returns the compensator with the fit report.
    pub fn fit_records(
        template: StageModel,
        records: &[Record],
        options: &ModelBuildOptions,
    ) -> Result<(ModelCompensator, FitReport), CompError> {
        let samples = scan_samples(records, options)?;
        let mut model = template;
        // Magnitudes only: geometry (arms, where and how wide a feature
        // is, periods) comes from the model or the diagnosis. Freed, the
        // geometry of a term whose magnitude is zero is unidentifiable and
        // wanders off to invalid values (measured: the default model's
        // zero-amplitude `extra_localized` fitted to a width of −4134 µm on a
        // 500 µm-step log of the paper-faithful stage).
        let free: Vec<String> = model
            .params()
            .into_iter()
            .filter(|p| !is_geometry(&p.info.name))
            .map(|p| p.full_name)
            .collect();
        if free.is_empty() {
            return Err(invalid("template", "has no parameter to fit"));
        }
        let fit = FitOptions {
            free,
            max_iterations: options.max_iterations,
            ..FitOptions::default()
        };
        let report = model.fit(&samples, &fit)?;
        Ok((ModelCompensator::new(model), report))
    }
}

impl Compensator for ModelCompensator {
    fn kind(&self) -> &'static str {
        "model"
    }

    fn predicted_offset_um(&self, state: &MotionState) -> Result<[f64; 2], CompError> {
        state.validate()?;
        let e = self.model.observed_error_um(state);
        if e.iter().all(|v| v.is_finite()) {
            Ok(e)
        } else {
            Err(invalid("model", "predicted a non-finite error"))
        }
    }

    fn characterized_area(&self) -> Option<super::Area> {
        self.area
    }

    fn extrapolates_by_model(&self) -> bool {
        true
    }
}

/// The template a characterization fits: the structure of `model` (its
/// terms, periods, harmonic counts, and the parameters that say *where* an
/// effect is rather than how large it is — Abbe arms, the centre and width
/// of a localized feature; see [`is_geometry`]) with every other parameter
/// reset to zero (backlash starts at 1 µm), and without the thermal,
/// observation, time and temperature terms (they need a temperature or time
/// history the scans do not resolve, and cannot predict a later move; see
/// `docs/compensation-tables.md`) and without the angular terms (on 1-DoF
/// scan lines they are indistinguishable from squareness, lead and cyclic
/// error, so a fit splits the effect between them arbitrarily).
pub fn compensation_template(model: &StageModel) -> Result<StageModel, CompError> {
    compensation_template_for(model, false)
}

/// [`compensation_template`], keeping the `step_size` terms of `model` whose
/// amplitude is not zero (their length λ as geometry) when `moves` is true:
/// the log to be fitted has moves of varied length
/// ([`crate::charact::scan::SEGMENT_MOVES`]), which separate the lost
/// motion of a move from the play; the compensator then predicts it for
/// the length and direction of the move actually planned.
pub fn compensation_template_for(model: &StageModel, moves: bool) -> Result<StageModel, CompError> {
    let mut m = model.clone();
    let step_size = crate::model::terms::discovered::STEP_SIZE_KIND;
    let identified = |t: &dyn crate::model::Term| {
        moves
            && t.kind() == step_size
            && t.params()
                .iter()
                .any(|p| p.name == "amplitude_um" && p.value != 0.0)
    };
    let drop: Vec<String> = m
        .terms()
        .iter()
        .filter(|t| {
            t.effect() == Effect::Observation
                || t.kind() == "thermal_expansion"
                || t.kind() == "optics_drift"
                // Functions of time or temperature cannot predict a future
                // move; fitted to scans they absorb whatever else is left
                // and extrapolate without bound (measured: a time drift fitted
                // at −1005 µm/h predicted 360 µm of error 2000 s later).
                || t.kind() == crate::model::terms::discovered::TIME_DRIFT_KIND
                || t.kind() == crate::model::terms::discovered::TIME_PERIODIC_KIND
                || t.kind() == crate::model::terms::discovered::TEMPERATURE_KIND
                // On constant-step scans a step-size term's amplitude is one
                // number times the direction: the same column as the play.
                || (t.kind() == step_size && !identified(t.as_ref()))
                // A zero table is a documented placeholder; its knots are no
                // claim about the stage (a fitted two-knot table is a line,
                // the same columns as the origin and the lead).
                || (t.kind() == crate::model::terms::discovered::POSITION_TABLE_KIND
                    && t.params().iter().all(|p| p.value == 0.0))
                // Angular errors act through Abbe arms: on a 1-DoF scan line
                // a yaw slope × arm is the same straight line as squareness
                // or lead, and its periodic part the same as the cyclic and
                // coupling terms. The fit then splits one effect between
                // them at random (minimum norm), right on the line and wrong
                // everywhere else (measured: 5.3 mrad of squareness shared
                // with y_yaw, model-compensated AP 10 µm on the square). The
                // identifiable terms absorb the angular errors' effect on
                // the scanned lines instead.
                || t.kind() == "angular"
                // A 2-D map has a parameter per node: the scans' two lines
                // cannot fit it (freed, its nodes on the lines would take
                // the scans' errors as their own, the rest are reported
                // unidentifiable). A map comes from a grid log, whose
                // compensation is the grid table.
                || t.kind() == crate::model::terms::position_map::KIND
        })
        .map(|t| t.name().to_string())
        .collect();
    for name in drop {
        m.remove_term(&name);
    }
    // A camera log's origin is the tie's, not the controllers' zero: the fit
    // needs a constant to take it (see `terms::offset`).
    if !m.terms().iter().any(|t| t.kind() == OFFSET_KIND) {
        let name = (0..)
            .map(|i| {
                if i == 0 {
                    "origin".to_string()
                } else {
                    format!("origin_{i}")
                }
            })
            .find(|n| m.terms().iter().all(|t| t.name() != n))
            .unwrap_or_else(|| "origin".to_string());
        m.push_term(Box::new(OriginOffsetTerm::new(
            &name,
            OriginOffsetConfig {
                x_um: 0.0,
                y_um: 0.0,
            },
        )?))?;
    }
    let values: Vec<f64> = m
        .params()
        .iter()
        .map(|p| {
            if is_geometry(&p.info.name) {
                p.info.value
            } else if p.info.name == "backlash_um" {
                1.0
            } else {
                0.0
            }
        })
        .collect();
    m.set_parameter_vector(&values)?;
    Ok(m)
}

/// Whether a parameter is geometry (kept from the model in a template)
/// rather than a magnitude (fitted from zero). Zeroing a geometry parameter
/// would make the term meaningless or invalid (a localized feature of zero
/// width), and the scans of a characterization cannot re-discover it.
pub fn is_geometry(param_name: &str) -> bool {
    param_name.starts_with("arm_")
        || param_name == "position_um"
        || param_name == "width_um"
        || param_name == "length_um"
        || param_name.contains("period")
}

/// How to fit a model to a log.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelBuildOptions {
    /// Segment of the X scan.
    pub x_segment: String,
    /// Segment of the Y scan.
    pub y_segment: String,
    /// Commands closer than this count as no move, µm.
    pub grid_tolerance_um: f64,
    /// Approach distance of the scan plan (re-created moves), µm.
    pub approach_um: f64,
    /// Minimum incremental motion of the stage, µm (as the model's).
    pub min_move_um: f64,
    /// Fit iteration limit.
    pub max_iterations: usize,
    /// Segment of the moves of varied length (see [`scan_samples`]).
    #[serde(default = "default_moves_segment")]
    pub moves_segment: String,
}

fn default_moves_segment() -> String {
    SEGMENT_MOVES.into()
}

impl Default for ModelBuildOptions {
    fn default() -> Self {
        ModelBuildOptions {
            x_segment: SEGMENT_SCAN_X.into(),
            y_segment: SEGMENT_SCAN_Y.into(),
            grid_tolerance_um: 1e-3,
            approach_um: 20.0,
            min_move_um: 0.0,
            max_iterations: 50,
            moves_segment: SEGMENT_MOVES.into(),
        }
    }
}

/// Fit samples from the scan segments of a log: states re-created by
/// replaying the commands (with the scan plan's approach moves), measured
/// positions from the log, temperature from `temp_c` (or
/// [`DEFAULT_TEMP_C`]). Then the records of the moves segment, if any: a
/// chain of records adjacent in the log is replayed as direct moves, each
/// from the one before; the first two of a chain only start the replay
/// (the history before them, hence the play, is not known), and any other
/// record in between (a scan, a drift reference detour) starts a new chain.
pub fn scan_samples(
    records: &[Record],
    options: &ModelBuildOptions,
) -> Result<Vec<Sample>, CompError> {
    if !(options.approach_um.is_finite() && options.approach_um > 0.0) {
        return Err(invalid("approach_um", "must be a finite number > 0"));
    }
    if !(options.grid_tolerance_um.is_finite() && options.grid_tolerance_um > 0.0) {
        return Err(invalid("grid_tolerance_um", "must be a finite number > 0"));
    }
    let mut out = Vec::new();
    for (segment, axis) in [(&options.x_segment, Axis::X), (&options.y_segment, Axis::Y)] {
        let recs: Vec<&Record> = records
            .iter()
            .filter(|r| &r.segment == segment)
            .filter(|r| {
                [r.t_s, r.x_cmd_um, r.y_cmd_um, r.x_meas_um, r.y_meas_um]
                    .iter()
                    .all(|v| v.is_finite())
            })
            .collect();
        if recs.len() < 4 {
            return Err(CompError::NoData {
                what: format!("segment `{segment}` has {} usable records", recs.len()),
            });
        }
        let i = axis.index();
        let mov: Vec<f64> = recs.iter().map(|r| [r.x_cmd_um, r.y_cmd_um][i]).collect();
        let dirs = infer_directions(&mov, options.grid_tolerance_um);
        let first = recs[0];
        let mut tracker = MotionTracker::new(MotionState::at_rest(first.x_cmd_um, first.y_cmd_um))?
            .with_min_move(options.min_move_um)?;
        for (r, d) in recs.iter().zip(dirs) {
            let Some(d) = d else { continue };
            let temp_c = r.temp_c.filter(|t| t.is_finite()).unwrap_or(DEFAULT_TEMP_C);
            let cmd = [r.x_cmd_um, r.y_cmd_um];
            let st = *tracker.state();
            // Re-create the plan's approach moves: the held axis parked
            // forward, the moving axis arriving in its pass direction.
            let mut need = [Direction::Forward; 2];
            need[i] = d;
            let mut approach = cmd;
            let mut any = false;
            for k in 0..2 {
                if st.axes[k].dir != need[k] {
                    approach[k] = cmd[k] - need[k].sign() * options.approach_um;
                    any = true;
                }
            }
            let wp = |p: [f64; 2]| Waypoint {
                x_um: p[0],
                y_um: p[1],
                time_s: r.t_s,
                temp_c,
                cycle: r.cycle,
            };
            if any {
                tracker.step(wp(approach))?;
            }
            let state = tracker.step(wp(cmd))?;
            out.push(Sample {
                state,
                measured_x_um: r.x_meas_um,
                measured_y_um: r.y_meas_um,
            });
        }
    }
    let mut chain: Option<(usize, usize, MotionTracker)> = None;
    for (k, r) in records.iter().enumerate() {
        if r.segment != options.moves_segment
            || ![r.t_s, r.x_cmd_um, r.y_cmd_um, r.x_meas_um, r.y_meas_um]
                .iter()
                .all(|v| v.is_finite())
        {
            continue;
        }
        let temp_c = r.temp_c.filter(|t| t.is_finite()).unwrap_or(DEFAULT_TEMP_C);
        let wp = Waypoint {
            x_um: r.x_cmd_um,
            y_um: r.y_cmd_um,
            time_s: r.t_s,
            temp_c,
            cycle: r.cycle,
        };
        match chain.as_mut() {
            Some((last, n, tracker)) if *last + 1 == k => {
                let state = tracker.step(wp)?;
                *last = k;
                *n += 1;
                if *n >= 3 {
                    out.push(Sample {
                        state,
                        measured_x_um: r.x_meas_um,
                        measured_y_um: r.y_meas_um,
                    });
                }
            }
            _ => {
                let tracker = MotionTracker::new(MotionState::at_rest(r.x_cmd_um, r.y_cmd_um))?
                    .with_min_move(options.min_move_um)?;
                chain = Some((k, 1, tracker));
            }
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn template_keeps_geometry_and_zeroes_magnitudes() {
        let model = StageModel::paper_default().unwrap();
        let tmpl = compensation_template(&model).unwrap();
        for p in tmpl.params() {
            let original = model.param(&p.full_name).unwrap();
            if is_geometry(&p.info.name) {
                assert_eq!(p.info.value, original, "{}", p.full_name);
            } else if p.info.name == "backlash_um" {
                assert_eq!(p.info.value, 1.0);
            } else {
                assert_eq!(p.info.value, 0.0, "{}", p.full_name);
            }
        }
        // Not identifiable from 1-DoF scans: left out.
        assert!(tmpl.terms().iter().all(|t| t.kind() != "angular"));
        assert!(model.terms().iter().any(|t| t.kind() == "angular"));
        // Nor a 2-D map (the shipped models carry a zero one).
        let map = crate::model::terms::position_map::KIND;
        assert!(model.terms().iter().any(|t| t.kind() == map));
        assert!(tmpl.terms().iter().all(|t| t.kind() != map));
        // The template is a valid model file (a zero width would not be).
        let text = tmpl.to_toml().unwrap();
        StageModel::from_toml(&text).unwrap();
        assert!(is_geometry("width_um") && is_geometry("arm_y_um") && !is_geometry("sin_um"));
    }
}
