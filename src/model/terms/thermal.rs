//! Thermal drift: of the stage (expansion and drift of the platform) and of
//! the optics (apparent shift of the camera's view).
//!
//! Physics: the paper saw ≈ 0.5 °C of ambient drift over its 9.5 h run and
//! blames its ≤ 1 µm repeatability (worse than the 0.1 µm datasheet value)
//! on it. With `ΔT = temp_c − reference_temp_c`:
//!
//! ```text
//! thermal_expansion:  d_x = ΔT·(k_x·x_cmd/1000 + o_x),  d_y = ΔT·(k_y·y_cmd/1000 + o_y)
//! optics_drift:       d_x = ΔT·m_x,  d_y = ΔT·m_y       (observation only)
//! ```
//! `k` is the differential expansion between screw/stage and pattern in µm
//! per °C per mm of position, `o` a position-independent drift of the platform
//! (µm/°C), `m` the drift of the microscope relative to the stage base. `o`
//! and `m` are indistinguishable from camera data alone (the fit reports the
//! pair as unidentifiable if both are free); the simulator needs both to
//! place the platform and the view correctly. Both terms are linear.

use serde::{Deserialize, Serialize};

use super::super::state::{MotionState, DEFAULT_TEMP_C};
use super::super::term::{
    check_param_values, config_table, parse_term_config, require_finite, Effect, ParamInfo, Term,
};
use super::super::ModelError;

/// Kind name of the stage term.
pub const EXPANSION_KIND: &str = "thermal_expansion";
/// Kind name of the optics term.
pub const OPTICS_KIND: &str = "optics_drift";

fn default_reference_temp_c() -> f64 {
    DEFAULT_TEMP_C
}

/// Model-file table of the stage thermal term.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ThermalExpansionConfig {
    /// Temperature at which the term is zero, °C.
    #[serde(default = "default_reference_temp_c")]
    pub reference_temp_c: f64,
    /// Differential expansion along x, µm per °C per mm of x.
    pub x_um_per_c_per_mm: f64,
    /// Differential expansion along y, µm per °C per mm of y.
    pub y_um_per_c_per_mm: f64,
    /// Position-independent platform drift along x, µm per °C.
    pub x_offset_um_per_c: f64,
    /// Position-independent platform drift along y, µm per °C.
    pub y_offset_um_per_c: f64,
}

/// Model-file table of the optics thermal term.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OpticsDriftConfig {
    /// Temperature at which the term is zero, °C.
    #[serde(default = "default_reference_temp_c")]
    pub reference_temp_c: f64,
    /// Apparent shift of the view along x, µm per °C.
    pub x_um_per_c: f64,
    /// Apparent shift of the view along y, µm per °C.
    pub y_um_per_c: f64,
}

/// The stage thermal term.
#[derive(Debug, Clone, PartialEq)]
pub struct ThermalExpansionTerm {
    name: String,
    cfg: ThermalExpansionConfig,
}

impl ThermalExpansionTerm {
    /// Builds and validates.
    pub fn new(name: &str, cfg: ThermalExpansionConfig) -> Result<Self, ModelError> {
        require_finite(name, "reference_temp_c", cfg.reference_temp_c)?;
        require_finite(name, "x_um_per_c_per_mm", cfg.x_um_per_c_per_mm)?;
        require_finite(name, "y_um_per_c_per_mm", cfg.y_um_per_c_per_mm)?;
        require_finite(name, "x_offset_um_per_c", cfg.x_offset_um_per_c)?;
        require_finite(name, "y_offset_um_per_c", cfg.y_offset_um_per_c)?;
        Ok(ThermalExpansionTerm {
            name: name.to_string(),
            cfg,
        })
    }

    fn basis(&self, s: &MotionState) -> [[f64; 2]; 4] {
        let dt = s.temp_c - self.cfg.reference_temp_c;
        [
            [dt * s.axes[0].cmd_um / 1000.0, 0.0],
            [0.0, dt * s.axes[1].cmd_um / 1000.0],
            [dt, 0.0],
            [0.0, dt],
        ]
    }

    fn values(&self) -> [f64; 4] {
        [
            self.cfg.x_um_per_c_per_mm,
            self.cfg.y_um_per_c_per_mm,
            self.cfg.x_offset_um_per_c,
            self.cfg.y_offset_um_per_c,
        ]
    }
}

impl Term for ThermalExpansionTerm {
    fn name(&self) -> &str {
        &self.name
    }

    fn kind(&self) -> &'static str {
        EXPANSION_KIND
    }

    fn params(&self) -> Vec<ParamInfo> {
        let v = self.values();
        vec![
            ParamInfo::new(
                "x_um_per_c_per_mm",
                "µm/°C/mm",
                v[0],
                "differential thermal expansion along x (stage vs pattern), per mm of x",
            ),
            ParamInfo::new(
                "y_um_per_c_per_mm",
                "µm/°C/mm",
                v[1],
                "differential thermal expansion along y (stage vs pattern), per mm of y",
            ),
            ParamInfo::new(
                "x_offset_um_per_c",
                "µm/°C",
                v[2],
                "position-independent thermal drift of the platform along x",
            ),
            ParamInfo::new(
                "y_offset_um_per_c",
                "µm/°C",
                v[3],
                "position-independent thermal drift of the platform along y",
            ),
        ]
    }

    fn set_params(&mut self, values: &[f64]) -> Result<(), ModelError> {
        check_param_values(&self.name, 4, values)?;
        self.cfg.x_um_per_c_per_mm = values[0];
        self.cfg.y_um_per_c_per_mm = values[1];
        self.cfg.x_offset_um_per_c = values[2];
        self.cfg.y_offset_um_per_c = values[3];
        Ok(())
    }

    fn contribution(&self, state: &MotionState) -> [f64; 2] {
        let b = self.basis(state);
        let v = self.values();
        let mut out = [0.0; 2];
        for (bi, vi) in b.iter().zip(v) {
            out[0] += bi[0] * vi;
            out[1] += bi[1] * vi;
        }
        out
    }

    fn is_linear(&self) -> bool {
        true
    }

    fn jacobian(&self, state: &MotionState) -> Vec<[f64; 2]> {
        self.basis(state).to_vec()
    }

    fn to_config(&self) -> Result<toml::Table, ModelError> {
        config_table(&self.name, &self.cfg)
    }

    fn clone_box(&self) -> Box<dyn Term> {
        Box::new(self.clone())
    }
}

/// The optics thermal term (an [`Effect::Observation`] term).
#[derive(Debug, Clone, PartialEq)]
pub struct OpticsDriftTerm {
    name: String,
    cfg: OpticsDriftConfig,
}

impl OpticsDriftTerm {
    /// Builds and validates.
    pub fn new(name: &str, cfg: OpticsDriftConfig) -> Result<Self, ModelError> {
        require_finite(name, "reference_temp_c", cfg.reference_temp_c)?;
        require_finite(name, "x_um_per_c", cfg.x_um_per_c)?;
        require_finite(name, "y_um_per_c", cfg.y_um_per_c)?;
        Ok(OpticsDriftTerm {
            name: name.to_string(),
            cfg,
        })
    }
}

impl Term for OpticsDriftTerm {
    fn name(&self) -> &str {
        &self.name
    }

    fn kind(&self) -> &'static str {
        OPTICS_KIND
    }

    fn effect(&self) -> Effect {
        Effect::Observation
    }

    fn params(&self) -> Vec<ParamInfo> {
        vec![
            ParamInfo::new(
                "x_um_per_c",
                "µm/°C",
                self.cfg.x_um_per_c,
                "apparent shift of the camera's view along x (microscope drift)",
            ),
            ParamInfo::new(
                "y_um_per_c",
                "µm/°C",
                self.cfg.y_um_per_c,
                "apparent shift of the camera's view along y (microscope drift)",
            ),
        ]
    }

    fn set_params(&mut self, values: &[f64]) -> Result<(), ModelError> {
        check_param_values(&self.name, 2, values)?;
        self.cfg.x_um_per_c = values[0];
        self.cfg.y_um_per_c = values[1];
        Ok(())
    }

    fn contribution(&self, state: &MotionState) -> [f64; 2] {
        let dt = state.temp_c - self.cfg.reference_temp_c;
        [dt * self.cfg.x_um_per_c, dt * self.cfg.y_um_per_c]
    }

    fn is_linear(&self) -> bool {
        true
    }

    fn jacobian(&self, state: &MotionState) -> Vec<[f64; 2]> {
        let dt = state.temp_c - self.cfg.reference_temp_c;
        vec![[dt, 0.0], [0.0, dt]]
    }

    fn to_config(&self) -> Result<toml::Table, ModelError> {
        config_table(&self.name, &self.cfg)
    }

    fn clone_box(&self) -> Box<dyn Term> {
        Box::new(self.clone())
    }
}

pub(crate) fn build_expansion(name: &str, table: toml::Table) -> Result<Box<dyn Term>, ModelError> {
    let cfg = parse_term_config(name, EXPANSION_KIND, table)?;
    Ok(Box::new(ThermalExpansionTerm::new(name, cfg)?))
}

pub(crate) fn build_optics(name: &str, table: toml::Table) -> Result<Box<dyn Term>, ModelError> {
    let cfg = parse_term_config(name, OPTICS_KIND, table)?;
    Ok(Box::new(OpticsDriftTerm::new(name, cfg)?))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn expansion_hand_values() {
        let t = ThermalExpansionTerm::new(
            "th",
            ThermalExpansionConfig {
                reference_temp_c: 20.0,
                x_um_per_c_per_mm: 0.01,
                y_um_per_c_per_mm: 0.02,
                x_offset_um_per_c: 0.3,
                y_offset_um_per_c: -0.2,
            },
        )
        .unwrap();
        let mut s = MotionState::at_rest(5000.0, 2000.0);
        s.temp_c = 20.5;
        // x: 0.5·(0.01·5 + 0.3) = 0.175; y: 0.5·(0.02·2 − 0.2) = −0.08.
        let d = t.contribution(&s);
        assert!(
            (d[0] - 0.175).abs() < 1e-12 && (d[1] + 0.08).abs() < 1e-12,
            "{d:?}"
        );
        s.temp_c = 20.0;
        assert_eq!(t.contribution(&s), [0.0, 0.0]);
    }

    #[test]
    fn optics_is_an_observation() {
        let t = OpticsDriftTerm::new(
            "op",
            OpticsDriftConfig {
                reference_temp_c: 21.0,
                x_um_per_c: 1.0,
                y_um_per_c: -2.0,
            },
        )
        .unwrap();
        let mut s = MotionState::at_rest(0.0, 0.0);
        s.temp_c = 20.0;
        assert_eq!(t.contribution(&s), [-1.0, 2.0]);
        assert_eq!(t.effect(), Effect::Observation);
    }
}
