//! Cumulative lead (scale) error of an axis.
//!
//! Physics: the screw's real lead differs from nominal by a few hundred ppm
//! (manufacturing, and the controller's counts-per-unit rounding), so the
//! error grows linearly with commanded position from the origin of the stage
//! frame:
//!
//! ```text
//! d_axis = ppm·1e-6·cmd_axis
//! ```
//! Linear.

use serde::{Deserialize, Serialize};

use super::super::state::{Axis, MotionState};
use super::super::term::{
    check_param_values, config_table, parse_term_config, require_finite, ParamInfo, Term,
};
use super::super::ModelError;

/// Kind name.
pub const KIND: &str = "lead_error";

/// Model-file table of a lead error term.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LeadConfig {
    /// The axis.
    pub axis: Axis,
    /// Scale error, ppm (µm of error per m of commanded travel); positive
    /// means the platform goes further than commanded.
    pub ppm: f64,
}

/// The lead error term.
#[derive(Debug, Clone, PartialEq)]
pub struct LeadTerm {
    name: String,
    cfg: LeadConfig,
}

impl LeadTerm {
    /// Builds and validates.
    pub fn new(name: &str, cfg: LeadConfig) -> Result<Self, ModelError> {
        require_finite(name, "ppm", cfg.ppm)?;
        Ok(LeadTerm {
            name: name.to_string(),
            cfg,
        })
    }
}

impl Term for LeadTerm {
    fn name(&self) -> &str {
        &self.name
    }

    fn kind(&self) -> &'static str {
        KIND
    }

    fn params(&self) -> Vec<ParamInfo> {
        vec![ParamInfo::new(
            "ppm",
            "ppm",
            self.cfg.ppm,
            format!(
                "scale error of {}: positive goes further than commanded",
                self.cfg.axis
            ),
        )]
    }

    fn set_params(&mut self, values: &[f64]) -> Result<(), ModelError> {
        check_param_values(&self.name, 1, values)?;
        self.cfg.ppm = values[0];
        Ok(())
    }

    fn contribution(&self, state: &MotionState) -> [f64; 2] {
        let mut out = [0.0; 2];
        out[self.cfg.axis.index()] = self.cfg.ppm * 1e-6 * state.cmd_um(self.cfg.axis);
        out
    }

    fn is_linear(&self) -> bool {
        true
    }

    fn jacobian(&self, state: &MotionState) -> Vec<[f64; 2]> {
        let mut d = [0.0; 2];
        d[self.cfg.axis.index()] = 1e-6 * state.cmd_um(self.cfg.axis);
        vec![d]
    }

    fn to_config(&self) -> Result<toml::Table, ModelError> {
        config_table(&self.name, &self.cfg)
    }

    fn clone_box(&self) -> Box<dyn Term> {
        Box::new(self.clone())
    }
}

pub(crate) fn build(name: &str, table: toml::Table) -> Result<Box<dyn Term>, ModelError> {
    let cfg = parse_term_config(name, KIND, table)?;
    Ok(Box::new(LeadTerm::new(name, cfg)?))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grows_with_position() {
        let t = LeadTerm::new(
            "yl",
            LeadConfig {
                axis: Axis::Y,
                ppm: -100.0,
            },
        )
        .unwrap();
        let c = t.contribution(&MotionState::at_rest(5000.0, 10_000.0));
        assert!((c[1] + 1.0).abs() < 1e-12 && c[0] == 0.0, "{c:?}");
    }
}
