//! The stage error model itself: an ordered list of named terms plus the
//! stochastic part and the environment the simulator needs; its parameters
//! as one vector (what fitting moves) and the error it predicts.

use super::env::{Environment, Interpolation, Stochastic};
use super::error::ModelError;
use super::state::MotionState;
use super::term::{Effect, ParamInfo, Term};
use super::xy::XyUm;
use serde::Serialize;

/// A parameter of a model, with its term.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ModelParam {
    /// `term.param`, the name fitting and reports use.
    pub full_name: String,
    /// Term name.
    pub term: String,
    /// Term kind.
    pub kind: String,
    /// The parameter itself.
    pub info: ParamInfo,
}

/// The stage error model: an ordered list of named terms plus what the
/// simulator needs beyond them. See the module docs.
#[derive(Debug, Clone)]
pub struct StageModel {
    description: String,
    terms: Vec<Box<dyn Term>>,
    stochastic: Stochastic,
    environment: Environment,
}

impl StageModel {
    /// Assembles and validates a model (unique, well-formed term names; valid
    /// stochastic and environment sections).
    pub fn new(
        description: String,
        terms: Vec<Box<dyn Term>>,
        stochastic: Stochastic,
        environment: Environment,
    ) -> Result<Self, ModelError> {
        stochastic.validate()?;
        environment.validate()?;
        let mut model = StageModel {
            description,
            terms: Vec::with_capacity(terms.len()),
            stochastic,
            environment,
        };
        for t in terms {
            model.push_term(t)?;
        }
        Ok(model)
    }

    /// The ideal stage: no term, no noise, constant temperature.
    pub fn ideal() -> Self {
        StageModel {
            description: "ideal stage".into(),
            terms: Vec::new(),
            stochastic: Stochastic::default(),
            environment: Environment::default(),
        }
    }

    /// Free-text description from the file.
    pub fn description(&self) -> &str {
        &self.description
    }

    /// The stochastic section.
    pub fn stochastic(&self) -> &Stochastic {
        &self.stochastic
    }

    /// Replaces the stochastic section (validated).
    pub fn set_stochastic(&mut self, s: Stochastic) -> Result<(), ModelError> {
        s.validate()?;
        self.stochastic = s;
        Ok(())
    }

    /// The environment section.
    pub fn environment(&self) -> &Environment {
        &self.environment
    }

    /// Replaces the environment section (validated).
    pub fn set_environment(&mut self, e: Environment) -> Result<(), ModelError> {
        e.validate()?;
        self.environment = e;
        Ok(())
    }

    /// The terms, in evaluation and parameter order.
    pub fn terms(&self) -> &[Box<dyn Term>] {
        &self.terms
    }

    /// A term by name.
    pub fn term(&self, name: &str) -> Option<&dyn Term> {
        self.terms.iter().find(|t| t.name() == name).map(|t| &**t)
    }

    /// Appends a term (how the analysis extends a model). Its name must be
    /// new and made of letters, digits, `_` and `-`.
    pub fn push_term(&mut self, term: Box<dyn Term>) -> Result<(), ModelError> {
        let name = term.name();
        if name.is_empty()
            || !name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-')
        {
            return Err(ModelError::Invalid {
                key: format!("term name `{name}`"),
                reason: "must be non-empty ASCII letters, digits, `_` or `-`".into(),
            });
        }
        if self.term(name).is_some() {
            return Err(ModelError::DuplicateTerm {
                name: name.to_string(),
            });
        }
        self.terms.push(term);
        Ok(())
    }

    /// Puts `term` in the place of the term of the same name. Why in
    /// place: the terms' order is the parameter vector's and the model
    /// file's, so a term rebuilt with other geometry (a screw lead the
    /// analysis corrected) keeps every other parameter where it was.
    pub fn replace_term(&mut self, term: Box<dyn Term>) -> Result<(), ModelError> {
        let slot = self
            .terms
            .iter_mut()
            .find(|t| t.name() == term.name())
            .ok_or_else(|| ModelError::Invalid {
                key: format!("term `{}`", term.name()),
                reason: "no term of that name to replace".into(),
            })?;
        *slot = term;
        Ok(())
    }

    /// Removes a term by name.
    pub fn remove_term(&mut self, name: &str) -> Option<Box<dyn Term>> {
        let i = self.terms.iter().position(|t| t.name() == name)?;
        Some(self.terms.remove(i))
    }

    /// All parameters in vector order.
    pub fn params(&self) -> Vec<ModelParam> {
        let mut out = Vec::new();
        for t in &self.terms {
            for info in t.params() {
                out.push(ModelParam {
                    full_name: format!("{}.{}", t.name(), info.name),
                    term: t.name().to_string(),
                    kind: t.kind().to_string(),
                    info,
                });
            }
        }
        out
    }

    /// A human-readable listing: every term with its kind and effect, every
    /// parameter with value, unit and meaning. For `micropos model show`
    /// and reports, so a user can see every number the model uses.
    pub fn describe(&self) -> String {
        use std::fmt::Write;
        let mut out = String::new();
        let _ = writeln!(out, "stage model: {}", self.description);
        let s = &self.stochastic;
        let _ = writeln!(
            out,
            "  settling σ [x, y] = [{}, {}] µm; minimum incremental motion {} µm; position quantum {} µm",
            s.repeatability_sigma_um[0],
            s.repeatability_sigma_um[1],
            s.min_incremental_motion_um,
            s.position_quantum_um
        );
        let temps: Vec<String> = self
            .environment
            .temperature
            .iter()
            .map(|p| format!("{} s: {} °C", p.time_s, p.temp_c))
            .collect();
        let _ = writeln!(
            out,
            "  temperature ({}): {}",
            match self.environment.temperature_interpolation {
                Interpolation::Linear => "linear",
                Interpolation::Smooth => "smooth",
            },
            temps.join(", ")
        );
        for t in &self.terms {
            let _ = writeln!(out, "{} ({}, {:?})", t.name(), t.kind(), t.effect());
            for p in t.params() {
                let _ = writeln!(
                    out,
                    "  {:<28} {:>14} {:<9} {}",
                    p.name,
                    format!("{}", p.value),
                    p.unit,
                    p.doc
                );
            }
        }
        out
    }

    /// Number of parameters.
    pub fn param_count(&self) -> usize {
        self.terms.iter().map(|t| t.params().len()).sum()
    }

    /// All parameter values, term after term in [`Term::params`] order.
    pub fn parameter_vector(&self) -> Vec<f64> {
        self.terms
            .iter()
            .flat_map(|t| t.params().into_iter().map(|p| p.value))
            .collect()
    }

    /// Sets all parameters. All-or-nothing: on error the model is unchanged.
    pub fn set_parameter_vector(&mut self, values: &[f64]) -> Result<(), ModelError> {
        let expected = self.param_count();
        if values.len() != expected {
            return Err(ModelError::ParamCount {
                term: "model".into(),
                expected,
                got: values.len(),
            });
        }
        let mut next = self.terms.clone();
        let mut i = 0;
        for t in &mut next {
            let n = t.params().len();
            t.set_params(&values[i..i + n])?;
            i += n;
        }
        self.terms = next;
        Ok(())
    }

    /// One parameter by full name (`term.param`).
    pub fn param(&self, full_name: &str) -> Result<f64, ModelError> {
        self.params()
            .into_iter()
            .find(|p| p.full_name == full_name)
            .map(|p| p.info.value)
            .ok_or_else(|| ModelError::UnknownParam {
                name: full_name.to_string(),
            })
    }

    /// Sets one parameter by full name.
    pub fn set_param(&mut self, full_name: &str, value: f64) -> Result<(), ModelError> {
        let i = self
            .params()
            .iter()
            .position(|p| p.full_name == full_name)
            .ok_or_else(|| ModelError::UnknownParam {
                name: full_name.to_string(),
            })?;
        let mut v = self.parameter_vector();
        v[i] = value;
        self.set_parameter_vector(&v)
    }

    /// Each term's contribution at `state`: `(name, effect, [dx_um, dy_um])`.
    pub fn contributions(&self, state: &MotionState) -> Vec<(&str, Effect, [f64; 2])> {
        self.terms
            .iter()
            .map(|t| (t.name(), t.effect(), t.contribution(state)))
            .collect()
    }

    fn sum(&self, state: &MotionState, include_observation: bool) -> [f64; 2] {
        let mut out = [0.0; 2];
        for t in &self.terms {
            if include_observation || t.effect() == Effect::Platform {
                let c = t.contribution(state);
                out[0] += c[0];
                out[1] += c[1];
            }
        }
        out
    }

    /// The platform's yaw at `state`, rad: the sum of every platform term's
    /// [`Term::yaw_rad`] (the yaw of both carriages; small angles add),
    /// right-handed about +z in the stage frame (+x towards +y). Why: the
    /// simulated camera renders the pattern turned by it, so the decoded θ
    /// is the mounting angle plus this; observation terms shift the view,
    /// never turn the platform.
    pub fn platform_yaw_rad(&self, state: &MotionState) -> f64 {
        self.terms
            .iter()
            .filter(|t| t.effect() == Effect::Platform)
            .map(|t| t.yaw_rad(state))
            .sum()
    }

    /// Σ Platform contributions `[dx_um, dy_um]`: true − commanded.
    pub fn platform_error_um(&self, state: &MotionState) -> [f64; 2] {
        self.sum(state, false)
    }

    /// Σ all contributions `[dx_um, dy_um]`: observed − commanded.
    pub fn observed_error_um(&self, state: &MotionState) -> [f64; 2] {
        self.sum(state, true)
    }

    /// The paper's error `e = target − measured` for a stage commanded to
    /// the target: `−observed_error_um`.
    pub fn paper_error_um(&self, state: &MotionState) -> [f64; 2] {
        let e = self.observed_error_um(state);
        [-e[0], -e[1]]
    }

    /// Where the platform really is (no settling noise: that is the
    /// simulator's). Finite for every state that passes
    /// [`MotionState::validate`].
    pub fn true_position(&self, state: &MotionState) -> XyUm {
        let e = self.platform_error_um(state);
        let c = state.cmd_xy_um();
        XyUm::from([c[0] + e[0], c[1] + e[1]])
    }

    /// Where the camera sees the platform (true position plus observation
    /// terms such as optics drift).
    pub fn observed_position(&self, state: &MotionState) -> XyUm {
        let e = self.observed_error_um(state);
        let c = state.cmd_xy_um();
        XyUm::from([c[0] + e[0], c[1] + e[1]])
    }

    /// ∂observed/∂parameter for every parameter, in vector order.
    pub fn jacobian(&self, state: &MotionState) -> Vec<[f64; 2]> {
        self.terms.iter().flat_map(|t| t.jacobian(state)).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::state::Direction;

    #[test]
    fn default_model_loads_and_round_trips() {
        let m = StageModel::paper_default().unwrap();
        assert!(m.terms().len() >= 10);
        let text = m.to_toml().unwrap();
        let back = StageModel::from_toml(&text).unwrap();
        assert_eq!(back.parameter_vector(), m.parameter_vector());
        assert_eq!(back.params(), m.params());
        assert_eq!(back.stochastic(), m.stochastic());
        assert_eq!(back.environment(), m.environment());
        assert_eq!(back.to_toml().unwrap(), text);
    }

    /// The paper stage's yaw is the sum of its two carriages' yaw terms,
    /// within the datasheet's ±150 µrad over the travel, and zero at the
    /// origin (each term is zero at commanded 0).
    #[test]
    fn the_platform_yaw_sums_both_carriages() {
        let m = StageModel::paper_default().unwrap();
        let s = MotionState::at_rest(3300.0, 7100.0);
        let sum: f64 = ["x_yaw", "y_yaw"]
            .iter()
            .map(|n| m.term(n).unwrap().yaw_rad(&s))
            .sum();
        let yaw = m.platform_yaw_rad(&s);
        assert!(yaw.abs() > 1e-6 && (yaw - sum).abs() < 1e-18, "{yaw} {sum}");
        assert!(m.term("x_pitch").unwrap().yaw_rad(&s) == 0.0);
        assert_eq!(m.platform_yaw_rad(&MotionState::at_rest(0.0, 0.0)), 0.0);
        for i in 0..=24 {
            let p = 500.0 * i as f64;
            let y = m.platform_yaw_rad(&MotionState::at_rest(p, p));
            assert!(y.abs() < 150e-6, "{p}: {y}");
        }
    }

    #[test]
    fn describe_lists_every_parameter() {
        let m = StageModel::paper_default().unwrap();
        let d = m.describe();
        for p in m.params() {
            assert!(d.contains(&p.info.name), "{}", p.full_name);
        }
        assert!(d.contains("x_backlash (backlash, Platform)"));
        assert!(d.contains("optics_thermal (optics_drift, Observation)"));
    }

    #[test]
    fn set_parameter_vector_is_all_or_nothing() {
        let mut m = StageModel::paper_default().unwrap();
        let p = m.parameter_vector();
        let mut bad = p.clone();
        let last = bad.len() - 1;
        bad[last] = f64::NAN;
        assert!(m.set_parameter_vector(&bad).is_err());
        assert_eq!(m.parameter_vector(), p);
        assert!(m.set_parameter_vector(&p[1..]).is_err());
        m.set_param("x_backlash.backlash_um", 3.0).unwrap();
        assert_eq!(m.param("x_backlash.backlash_um").unwrap(), 3.0);
        assert!(m.param("nope.nothing").is_err());
    }

    #[test]
    fn signs_follow_the_documented_convention() {
        let m = StageModel::paper_default().unwrap();
        let mut s = MotionState::arrived(1234.0, Direction::Forward, 2345.0, Direction::Backward);
        s.temp_c = 20.3;
        let t = m.true_position(&s);
        let o = m.observed_position(&s);
        let pe = m.platform_error_um(&s);
        let oe = m.observed_error_um(&s);
        assert!((t.x_um - (1234.0 + pe[0])).abs() < 1e-9);
        assert!((o.y_um - (2345.0 + oe[1])).abs() < 1e-9);
        let e = m.paper_error_um(&s);
        assert!((e[0] - (1234.0 - o.x_um)).abs() < 1e-9);
        assert!((e[1] - (2345.0 - o.y_um)).abs() < 1e-9);
        // Optics drift makes observed differ from true.
        assert!((o.x_um - t.x_um).abs() > 1e-3);
    }
}
