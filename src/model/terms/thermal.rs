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

use super::super::error::ModelError;
use super::super::spec::{param, ParamSpec, SpecTerm, TermSpec};
use super::super::state::{MotionState, DEFAULT_TEMP_C};
use super::super::term::{require_finite, Effect};

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

/// The stage thermal kind: four parameters, linear.
#[derive(Debug, Clone, PartialEq)]
pub struct ThermalExpansion;

/// The stage thermal term.
pub type ThermalExpansionTerm = SpecTerm<ThermalExpansion>;

/// ∂contribution/∂(the four parameters, in table order), µm per unit.
fn expansion_basis(cfg: &ThermalExpansionConfig, s: &MotionState) -> [[f64; 2]; 4] {
    let dt = s.temp_c - cfg.reference_temp_c;
    [
        [dt * s.axes[0].cmd_um / 1000.0, 0.0],
        [0.0, dt * s.axes[1].cmd_um / 1000.0],
        [dt, 0.0],
        [0.0, dt],
    ]
}

impl TermSpec for ThermalExpansion {
    type Config = ThermalExpansionConfig;
    const KIND: &'static str = EXPANSION_KIND;
    const PARAMS: &'static [ParamSpec<ThermalExpansionConfig>] = &[
        param!(
            x_um_per_c_per_mm,
            "µm/°C/mm",
            Finite,
            "differential thermal expansion along x (stage vs pattern), per mm of x",
            linear(|c, s| expansion_basis(c, s)[0])
        ),
        param!(
            y_um_per_c_per_mm,
            "µm/°C/mm",
            Finite,
            "differential thermal expansion along y (stage vs pattern), per mm of y",
            linear(|c, s| expansion_basis(c, s)[1])
        ),
        param!(
            x_offset_um_per_c,
            "µm/°C",
            Finite,
            "position-independent thermal drift of the platform along x",
            linear(|c, s| expansion_basis(c, s)[2])
        ),
        param!(
            y_offset_um_per_c,
            "µm/°C",
            Finite,
            "position-independent thermal drift of the platform along y",
            linear(|c, s| expansion_basis(c, s)[3])
        ),
    ];

    fn check(name: &str, cfg: &ThermalExpansionConfig) -> Result<(), ModelError> {
        require_finite(name, "reference_temp_c", cfg.reference_temp_c)?;
        Ok(())
    }

    fn contribution(cfg: &ThermalExpansionConfig, state: &MotionState) -> [f64; 2] {
        let b = expansion_basis(cfg, state);
        let v = [
            cfg.x_um_per_c_per_mm,
            cfg.y_um_per_c_per_mm,
            cfg.x_offset_um_per_c,
            cfg.y_offset_um_per_c,
        ];
        let mut out = [0.0; 2];
        for (bi, vi) in b.iter().zip(v) {
            out[0] += bi[0] * vi;
            out[1] += bi[1] * vi;
        }
        out
    }
}

/// The optics thermal kind (an [`Effect::Observation`]): two parameters,
/// linear.
#[derive(Debug, Clone, PartialEq)]
pub struct OpticsDrift;

/// The optics thermal term.
pub type OpticsDriftTerm = SpecTerm<OpticsDrift>;

impl TermSpec for OpticsDrift {
    type Config = OpticsDriftConfig;
    const KIND: &'static str = OPTICS_KIND;
    const EFFECT: Effect = Effect::Observation;
    const PARAMS: &'static [ParamSpec<OpticsDriftConfig>] = &[
        param!(
            x_um_per_c,
            "µm/°C",
            Finite,
            "apparent shift of the camera's view along x (microscope drift)",
            linear(|c, s| [s.temp_c - c.reference_temp_c, 0.0])
        ),
        param!(
            y_um_per_c,
            "µm/°C",
            Finite,
            "apparent shift of the camera's view along y (microscope drift)",
            linear(|c, s| [0.0, s.temp_c - c.reference_temp_c])
        ),
    ];

    fn check(name: &str, cfg: &OpticsDriftConfig) -> Result<(), ModelError> {
        require_finite(name, "reference_temp_c", cfg.reference_temp_c)?;
        Ok(())
    }

    fn contribution(cfg: &OpticsDriftConfig, state: &MotionState) -> [f64; 2] {
        let dt = state.temp_c - cfg.reference_temp_c;
        [dt * cfg.x_um_per_c, dt * cfg.y_um_per_c]
    }
}

#[cfg(test)]
mod tests {
    use super::super::super::term::Term;
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
