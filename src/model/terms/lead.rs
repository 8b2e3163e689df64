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

use super::super::spec::{param, ParamSpec, SpecTerm, TermSpec};
use super::super::state::{Axis, MotionState};

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

/// The lead error kind: one parameter, `ppm`, linear.
#[derive(Debug, Clone, PartialEq)]
pub struct Lead;

/// The lead error term.
pub type LeadTerm = SpecTerm<Lead>;

impl TermSpec for Lead {
    type Config = LeadConfig;
    const KIND: &'static str = KIND;
    const PARAMS: &'static [ParamSpec<LeadConfig>] = &[param!(
        ppm,
        "ppm",
        Finite,
        |c| {
            format!(
                "scale error of {}: positive goes further than commanded",
                c.axis
            )
        },
        linear(|c, state| {
            let mut d = [0.0; 2];
            d[c.axis.index()] = 1e-6 * state.cmd_um(c.axis);
            d
        })
    )];

    fn contribution(cfg: &LeadConfig, state: &MotionState) -> [f64; 2] {
        let mut out = [0.0; 2];
        out[cfg.axis.index()] = cfg.ppm * 1e-6 * state.cmd_um(cfg.axis);
        out
    }
}

#[cfg(test)]
mod tests {
    use super::super::super::term::Term;
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
