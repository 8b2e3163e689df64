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

use super::super::spec::{param, ParamSpec, SpecTerm, TermSpec};
use super::super::state::MotionState;

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

/// The origin-offset kind: `x_um` and `y_um`, linear.
#[derive(Debug, Clone, PartialEq)]
pub struct OriginOffset;

/// The origin-offset term.
pub type OriginOffsetTerm = SpecTerm<OriginOffset>;

impl TermSpec for OriginOffset {
    type Config = OriginOffsetConfig;
    const KIND: &'static str = KIND;
    const PARAMS: &'static [ParamSpec<OriginOffsetConfig>] = &[
        param!(
            x_um,
            "µm",
            Finite,
            "constant x offset of the measuring frame's origin (platform further in +x)",
            linear(|_, _| [1.0, 0.0])
        ),
        param!(
            y_um,
            "µm",
            Finite,
            "constant y offset of the measuring frame's origin (platform further in +y)",
            linear(|_, _| [0.0, 1.0])
        ),
    ];

    fn contribution(cfg: &OriginOffsetConfig, _state: &MotionState) -> [f64; 2] {
        [cfg.x_um, cfg.y_um]
    }
}

#[cfg(test)]
mod tests {
    use super::super::super::term::Term;
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
