//! Does the extended model pay off? Closing the loop of the diagnosis: the
//! model `diagnose` extended must compensate the stage that has the effect
//! better than the model it started from.
//!
//! [`compare_compensation`] runs the paper's two validations (the square of
//! [`square_poses`] and the ten [`random_targets`], each visited several
//! times) on a simulated stage running the *rig* model (the one with the
//! effect), three times: uncompensated, compensated by the original model
//! (the base fit of the diagnosis, [`super::Diagnosis::base_model`]) and by
//! the extended model ([`super::Diagnosis::extended_model`]), both as
//! [`ModelCompensator`]s planned by [`Compensator::command_for`] (inverse
//! and backlash planning, as the daemon's `compensated` moves). It reports
//! ISO 9283 AP and RP on what the camera sees (the paper's measure), and how
//! far the original model is from the rig where the validation goes (the
//! size of the missing effect *there*: an effect away from the validation
//! poses cannot change their AP).
//!
//! Why a simulation and not the log: AP needs the stage to go to targets
//! with the compensation applied; the log only shows where it went without.
//! On a real rig the same comparison is the daemon's validation job.
//!
//! Sans-IO and deterministic (seeded settling noise).

use serde::Serialize;

use crate::charact::scan::{random_targets, square_poses};
use crate::comp::{Compensator, ModelCompensator, MotionHistory, PlanOptions, Uncompensated};
use crate::metrology::{pose_stats, summarize_poses, Xy};
use crate::model::{MotionState, StageModel, StageSimulator, XyUm};

use super::AnalysisError;

/// How to run the validations.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CompGainOptions {
    /// Step of the square's poses along its sides, µm (the paper: 200).
    pub square_step_um: f64,
    /// Visits of the whole square.
    pub square_cycles: u32,
    /// Visits of the ten random targets.
    pub random_cycles: u32,
    /// Time per move (move, settle, image), s (the paper: ≈ 2.08).
    pub move_s: f64,
    /// Time at which the validations start, s on the rig model's clock
    /// (after the characterization: time and temperature terms go on).
    pub start_time_s: f64,
    /// Seed of the simulated settling noise (the same for every run).
    pub seed: u64,
}

impl Default for CompGainOptions {
    fn default() -> Self {
        CompGainOptions {
            square_step_um: 200.0,
            square_cycles: 5,
            random_cycles: 10,
            move_s: 2.08,
            start_time_s: 0.0,
            seed: 7,
        }
    }
}

/// ISO 9283 figures of one compensation on both validations, µm.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ValidationFigures {
    /// Square: AP, max over poses.
    pub square_ap_um: f64,
    /// Square: RP, max over poses.
    pub square_rp_um: f64,
    /// Random targets: AP, max over poses.
    pub random_ap_um: f64,
    /// Random targets: RP, max over poses.
    pub random_rp_um: f64,
}

impl ValidationFigures {
    /// The larger of the two APs (the headline number).
    pub fn worst_ap_um(&self) -> f64 {
        self.square_ap_um.max(self.random_ap_um)
    }
}

/// The three runs side by side.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CompGain {
    /// No compensation (still planned around backlash).
    pub uncompensated: ValidationFigures,
    /// Compensation by the original (base-fitted) model.
    pub original: ValidationFigures,
    /// Compensation by the extended model.
    pub extended: ValidationFigures,
    /// Largest |rig − original model| observed error over the states the
    /// original-model validation visited, µm: how large the missing effect
    /// is where the validation goes.
    pub original_mismatch_um: f64,
    /// The same for the extended model, µm.
    pub extended_mismatch_um: f64,
    /// Options used.
    pub options: CompGainOptions,
}

impl CompGain {
    /// `100·(1 − extended/original)` of the worst AP, %.
    pub fn ap_gain_pct(&self) -> f64 {
        let a = self.original.worst_ap_um();
        if a > 0.0 {
            100.0 * (1.0 - self.extended.worst_ap_um() / a)
        } else {
            0.0
        }
    }

    /// A few lines for people.
    pub fn to_text(&self) -> String {
        let row = |name: &str, f: &ValidationFigures| {
            format!(
                "{name:<26} square AP {:>7.3} µm RP {:>6.3} µm   random AP {:>7.3} µm RP {:>6.3} µm\n",
                f.square_ap_um, f.square_rp_um, f.random_ap_um, f.random_rp_um
            )
        };
        let mut s = String::from(
            "compensation on the simulated rig (ISO 9283, what the camera sees, max over poses):\n",
        );
        s += &row("uncompensated", &self.uncompensated);
        s += &row("original model", &self.original);
        s += &row("extended model", &self.extended);
        s += &format!(
            "worst AP {:.3} → {:.3} µm ({:+.1} %); model vs rig where the validation goes: original {:.3} µm, extended {:.3} µm\n",
            self.original.worst_ap_um(),
            self.extended.worst_ap_um(),
            self.ap_gain_pct(),
            self.original_mismatch_um,
            self.extended_mismatch_um
        );
        s
    }
}

/// One validation: `targets` visited `cycles` times in order, compensated
/// by `comp`; returns (AP max, RP max, max |rig − model| over visited
/// states when `model` is given). Also the paper-reproduction's validation
/// ([`super::paper`]).
pub(crate) fn run_validation(
    rig: &StageModel,
    comp: &dyn Compensator,
    model: Option<&StageModel>,
    targets: &[XyUm],
    cycles: u32,
    t0: f64,
    opts: &CompGainOptions,
) -> Result<(f64, f64, f64), AnalysisError> {
    let first = targets
        .first()
        .ok_or_else(|| AnalysisError::Invalid("validation without targets".into()))?;
    // The stage starts at rest at the first target, at the validation's
    // time and room temperature (the compensator reads both from the
    // history: a 20 °C default would miscompensate the first visit).
    let mut start = MotionState::at_rest(first.x_um, first.y_um);
    start.time_s = t0;
    start.temp_c = rig.environment().temperature_at(t0);
    let mut sim = StageSimulator::new(rig.clone(), start, opts.seed)?;
    let min_move = rig.stochastic().min_incremental_motion_um;
    let mut hist = MotionHistory::new(*sim.state(), min_move)?;
    let plan_opts = PlanOptions::default();
    let mut t = t0;
    let mut seen: Vec<Vec<Xy>> = vec![Vec::with_capacity(cycles as usize); targets.len()];
    let mut mismatch: f64 = 0.0;
    for cycle in 0..cycles {
        for (i, target) in targets.iter().enumerate() {
            let plan = comp.command_for(*target, &hist, &plan_opts)?;
            let mut last = None;
            for w in &plan.waypoints {
                t += opts.move_s;
                last = Some(sim.move_to(w.x_um, w.y_um, t, cycle)?);
            }
            let step = last.ok_or_else(|| AnalysisError::Invalid("empty move plan".into()))?;
            hist.commit(&plan, t, step.state.temp_c)?;
            if let Some(m) = model {
                let a = rig.observed_error_um(&step.state);
                let b = m.observed_error_um(&step.state);
                mismatch = mismatch.max((a[0] - b[0]).hypot(a[1] - b[1]));
            }
            seen[i].push(Xy::new(step.observed_um.x_um, step.observed_um.y_um));
        }
    }
    let stats = targets
        .iter()
        .zip(&seen)
        .map(|(t, v)| pose_stats(Xy::new(t.x_um, t.y_um), v))
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| AnalysisError::Invalid(format!("ISO 9283: {e}")))?;
    let s =
        summarize_poses(&stats).map_err(|e| AnalysisError::Invalid(format!("ISO 9283: {e}")))?;
    Ok((s.ap_max_um, s.rp_max_um.unwrap_or(f64::NAN), mismatch))
}

fn figures(
    rig: &StageModel,
    comp: &dyn Compensator,
    model: Option<&StageModel>,
    opts: &CompGainOptions,
) -> Result<(ValidationFigures, f64), AnalysisError> {
    let square: Vec<XyUm> = square_poses(opts.square_step_um)
        .map_err(|e| AnalysisError::Invalid(e.to_string()))?
        .into_iter()
        .map(|p| p.target)
        .collect();
    let t_square = opts.start_time_s;
    // The random targets follow the square on the same clock.
    let t_random =
        t_square + opts.move_s * 2.0 * (square.len() as f64) * f64::from(opts.square_cycles.max(1));
    let (sq_ap, sq_rp, m1) = run_validation(
        rig,
        comp,
        model,
        &square,
        opts.square_cycles,
        t_square,
        opts,
    )?;
    let (rn_ap, rn_rp, m2) = run_validation(
        rig,
        comp,
        model,
        &random_targets(),
        opts.random_cycles,
        t_random,
        opts,
    )?;
    Ok((
        ValidationFigures {
            square_ap_um: sq_ap,
            square_rp_um: sq_rp,
            random_ap_um: rn_ap,
            random_rp_um: rn_rp,
        },
        m1.max(m2),
    ))
}

/// Runs the square and random-target validations on a simulated stage
/// running `rig`, uncompensated and compensated by `original` and by
/// `extended`. See the module docs.
pub fn compare_compensation(
    rig: &StageModel,
    original: &StageModel,
    extended: &StageModel,
    opts: &CompGainOptions,
) -> Result<CompGain, AnalysisError> {
    let ok = opts.square_step_um.is_finite()
        && opts.square_step_um > 0.0
        && opts.square_cycles >= 2
        && opts.random_cycles >= 2
        && opts.move_s.is_finite()
        && opts.move_s > 0.0
        && opts.start_time_s.is_finite();
    if !ok {
        return Err(AnalysisError::Invalid(
            "validation: square step and move time must be finite and > 0, at least 2 cycles each (RP needs repeats), start time finite".into(),
        ));
    }
    let (uncompensated, _) = figures(rig, &Uncompensated, None, opts)?;
    let (orig, m_orig) = figures(
        rig,
        &ModelCompensator::new(original.clone()),
        Some(original),
        opts,
    )?;
    let (ext, m_ext) = figures(
        rig,
        &ModelCompensator::new(extended.clone()),
        Some(extended),
        opts,
    )?;
    Ok(CompGain {
        uncompensated,
        original: orig,
        extended: ext,
        original_mismatch_um: m_orig,
        extended_mismatch_um: m_ext,
        options: opts.clone(),
    })
}
