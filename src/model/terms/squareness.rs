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

use super::super::spec::{param, ParamSpec, SpecTerm, TermSpec};
use super::super::state::{Axis, MotionState};

/// Kind name.
pub const KIND: &str = "squareness";

/// Model-file table of a squareness term.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SquarenessConfig {
    /// Angle by which +Y leans towards +X, µrad (x error per y travel).
    pub angle_urad: f64,
}

/// The squareness kind: one parameter, `angle_urad`, linear.
#[derive(Debug, Clone, PartialEq)]
pub struct Squareness;

/// The squareness term.
pub type SquarenessTerm = SpecTerm<Squareness>;

impl TermSpec for Squareness {
    type Config = SquarenessConfig;
    const KIND: &'static str = KIND;
    const PARAMS: &'static [ParamSpec<SquarenessConfig>] = &[param!(
        angle_urad,
        "µrad",
        Finite,
        "out-of-squareness: +Y leans towards +X by this angle; x error = angle·y",
        linear(|_, state| [1e-6 * state.cmd_um(Axis::Y), 0.0])
    )];

    fn contribution(cfg: &SquarenessConfig, state: &MotionState) -> [f64; 2] {
        [cfg.angle_urad * 1e-6 * state.cmd_um(Axis::Y), 0.0]
    }
}

#[cfg(test)]
mod tests {
    use super::super::super::term::Term;
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
