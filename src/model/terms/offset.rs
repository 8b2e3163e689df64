//! A constant offset between where the stage was commanded and where the
//! measuring frame puts it.
//!
//! Why a term: a camera log's origin is not the controllers' zero. The
//! daemon ties the vision frame to the stage on a pre-scan and chooses the
//! translation so that command − measured averages zero along its X tie
//! line; every other error of the stage at that line (squareness × the
//! line's y, lead × its mean x, the cyclic terms' mean) then shows up as a
//! constant between the model's frame (origin at commanded (0, 0)) and the
//! log's. No other term has a constant mode (lead and squareness are zero
//! at the origin, cyclic terms and play average out), so without this term
//! a model fitted to a camera log absorbs the constant into whatever slope
//! or bump it can, and a model-compensated move lands off by it (measured:
//! ≈ 1 µm on x in the main job).
//!
//! ```text
//! dx = x_um,  dy = y_um     (platform further in + than commanded)
//! ```
//!
//! Linear. The default model's value is zero: the simulator's frame is the
//! model's own.

use serde::{Deserialize, Serialize};

use super::super::state::MotionState;
use super::super::term::{
    check_param_values, config_table, parse_term_config, require_finite, ParamInfo, Term,
};
use super::super::ModelError;

/// Kind name.
pub const KIND: &str = "origin_offset";

/// Model-file table of an origin-offset term.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OriginOffsetConfig {
    /// Constant x offset, µm (positive: the platform is further in +x than
    /// commanded, everywhere).
    pub x_um: f64,
    /// Constant y offset, µm.
    pub y_um: f64,
}

/// The origin-offset term.
#[derive(Debug, Clone, PartialEq)]
pub struct OriginOffsetTerm {
    name: String,
    cfg: OriginOffsetConfig,
}

impl OriginOffsetTerm {
    /// Builds and validates.
    pub fn new(name: &str, cfg: OriginOffsetConfig) -> Result<Self, ModelError> {
        require_finite(name, "x_um", cfg.x_um)?;
        require_finite(name, "y_um", cfg.y_um)?;
        Ok(OriginOffsetTerm {
            name: name.to_string(),
            cfg,
        })
    }
}

impl Term for OriginOffsetTerm {
    fn name(&self) -> &str {
        &self.name
    }

    fn kind(&self) -> &'static str {
        KIND
    }

    fn params(&self) -> Vec<ParamInfo> {
        vec![
            ParamInfo::new(
                "x_um",
                "µm",
                self.cfg.x_um,
                "constant x offset of the measuring frame's origin (platform further in +x)",
            ),
            ParamInfo::new(
                "y_um",
                "µm",
                self.cfg.y_um,
                "constant y offset of the measuring frame's origin (platform further in +y)",
            ),
        ]
    }

    fn set_params(&mut self, values: &[f64]) -> Result<(), ModelError> {
        check_param_values(&self.name, 2, values)?;
        self.cfg.x_um = values[0];
        self.cfg.y_um = values[1];
        Ok(())
    }

    fn contribution(&self, _state: &MotionState) -> [f64; 2] {
        [self.cfg.x_um, self.cfg.y_um]
    }

    fn is_linear(&self) -> bool {
        true
    }

    fn jacobian(&self, _state: &MotionState) -> Vec<[f64; 2]> {
        vec![[1.0, 0.0], [0.0, 1.0]]
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
    Ok(Box::new(OriginOffsetTerm::new(name, cfg)?))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_same_offset_everywhere() {
        let t = OriginOffsetTerm::new(
            "o",
            OriginOffsetConfig {
                x_um: -1.1,
                y_um: 0.25,
            },
        )
        .unwrap();
        for (x, y) in [(0.0, 0.0), (9500.0, 4200.0), (-300.0, 12.5)] {
            assert_eq!(t.contribution(&MotionState::at_rest(x, y)), [-1.1, 0.25]);
        }
        assert!(OriginOffsetTerm::new(
            "o",
            OriginOffsetConfig {
                x_um: f64::NAN,
                y_um: 0.0
            }
        )
        .is_err());
    }
}
