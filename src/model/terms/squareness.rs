//! Out-of-squareness between the two axes: the paper's `δx(y)`.
//!
//! Physics: the Y stage is bolted on the X stage at an angle `90° − α` instead
//! of 90°, so a y motion also moves the platform along x by `α·y`. Positive
//! `α` leans +Y towards +X:
//!
//! ```text
//! dx = α·1e-6·y_cmd    (α in µrad, y in µm)
//! ```
//!
//! The y component (`y·(cos α − 1)`, 0.01 µm for 5 mrad over 4 mm) is
//! neglected. The paper's square test (≈ 22 µm uncompensated, mostly on the
//! y-moving segments) is dominated by this term. Linear.

use serde::{Deserialize, Serialize};

use super::super::state::{Axis, MotionState};
use super::super::term::{
    check_param_values, config_table, parse_term_config, require_finite, ParamInfo, Term,
};
use super::super::ModelError;

/// Kind name.
pub const KIND: &str = "squareness";

/// Model-file table of a squareness term.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SquarenessConfig {
    /// Angle by which +Y leans towards +X, µrad (x error per y travel).
    pub angle_urad: f64,
}

/// The squareness term.
#[derive(Debug, Clone, PartialEq)]
pub struct SquarenessTerm {
    name: String,
    cfg: SquarenessConfig,
}

impl SquarenessTerm {
    /// Builds and validates.
    pub fn new(name: &str, cfg: SquarenessConfig) -> Result<Self, ModelError> {
        require_finite(name, "angle_urad", cfg.angle_urad)?;
        Ok(SquarenessTerm {
            name: name.to_string(),
            cfg,
        })
    }
}

impl Term for SquarenessTerm {
    fn name(&self) -> &str {
        &self.name
    }

    fn kind(&self) -> &'static str {
        KIND
    }

    fn params(&self) -> Vec<ParamInfo> {
        vec![ParamInfo::new(
            "angle_urad",
            "µrad",
            self.cfg.angle_urad,
            "out-of-squareness: +Y leans towards +X by this angle; x error = angle·y",
        )]
    }

    fn set_params(&mut self, values: &[f64]) -> Result<(), ModelError> {
        check_param_values(&self.name, 1, values)?;
        self.cfg.angle_urad = values[0];
        Ok(())
    }

    fn contribution(&self, state: &MotionState) -> [f64; 2] {
        [self.cfg.angle_urad * 1e-6 * state.cmd_um(Axis::Y), 0.0]
    }

    fn is_linear(&self) -> bool {
        true
    }

    fn jacobian(&self, state: &MotionState) -> Vec<[f64; 2]> {
        vec![[1e-6 * state.cmd_um(Axis::Y), 0.0]]
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
    Ok(Box::new(SquarenessTerm::new(name, cfg)?))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn x_error_proportional_to_y() {
        let t = SquarenessTerm::new("sq", SquarenessConfig { angle_urad: 5000.0 }).unwrap();
        // 5 mrad over 4000 µm of y: 20 µm along x.
        let c = t.contribution(&MotionState::at_rest(1234.0, 4000.0));
        assert!((c[0] - 20.0).abs() < 1e-12 && c[1] == 0.0, "{c:?}");
        assert_eq!(
            t.jacobian(&MotionState::at_rest(0.0, 2000.0)),
            vec![[2e-3, 0.0]]
        );
    }
}
