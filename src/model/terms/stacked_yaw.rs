//! The lower carriage's yaw acting on the upper axis's travel: the error of
//! a stacked XY stage that depends on both positions at once (no
//! `f(x) + g(y)` holds it, so the paper's tables cannot; a grid map can).
//!
//! Physics: in a stacked stage the upper axis rides on the lower carriage.
//! When the lower carriage yaws as it travels (a guide that is not
//! straight in the horizontal plane turns the carriage by an angle that
//! changes along its travel), the whole upper axis turns with it about the
//! carriage's rotation centre, and the platform, which the upper axis has
//! carried some distance from that centre, moves sideways by the yaw times
//! that distance. The yaw is taken to change linearly along the lower
//! axis's travel (a guide bent to a constant curvature; its constant part
//! is a squareness, its straightness error a separable term, both
//! elsewhere), so the error is bilinear in the two positions:
//!
//! ```text
//! ε   = slope·1e-9·(lower_cmd − lower_center)            (rad; slope in µrad/mm)
//! arm = upper_cmd − upper_center                          (µm)
//! lower = x (Y on top):  dx = −ε·arm,  dy = 0
//! lower = y (X on top):  dx = 0,       dy = +ε·arm
//! ```
//!
//! Sign convention: yaw positive counter-clockwise seen from above (+x
//! towards +y), so a positive yaw moves a point at +y from the centre
//! towards −x, and one at +x towards +y. Linear in `slope_urad_per_mm`.
//! It is the kind seen on a real stacked wafer stage's map, where the y
//! error's slope along x changed from −473 to −18 µrad across y.

use serde::{Deserialize, Serialize};

use super::super::error::ModelError;
use super::super::spec::{param, ParamSpec, SpecTerm, TermSpec};
use super::super::state::{Axis, MotionState};

/// Kind name.
pub const KIND: &str = "stacked_yaw";

/// Model-file table of a stacked-yaw term.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StackedYawConfig {
    /// The lower axis, whose carriage yaws (the other axis rides on it).
    pub lower_axis: Axis,
    /// Change of the lower carriage's yaw per mm of its travel, µrad/mm
    /// (positive: counter-clockwise seen from above, growing with +travel).
    pub slope_urad_per_mm: f64,
    /// Lower-axis position where the yaw is zero, µm.
    #[serde(default)]
    pub lower_center_um: f64,
    /// Upper-axis position of the carriage's rotation centre, µm.
    #[serde(default)]
    pub upper_center_um: f64,
}

/// The stacked-yaw kind: one parameter, `slope_urad_per_mm`, linear.
#[derive(Debug, Clone, PartialEq)]
pub struct StackedYaw;

/// The stacked-yaw term.
pub type StackedYawTerm = SpecTerm<StackedYaw>;

/// The contribution per µrad/mm of slope.
fn unit(cfg: &StackedYawConfig, state: &MotionState) -> [f64; 2] {
    let upper = cfg.lower_axis.other();
    let eps = 1e-9 * (state.cmd_um(cfg.lower_axis) - cfg.lower_center_um);
    let arm = state.cmd_um(upper) - cfg.upper_center_um;
    match cfg.lower_axis {
        Axis::X => [-eps * arm, 0.0],
        Axis::Y => [0.0, eps * arm],
    }
}

impl TermSpec for StackedYaw {
    type Config = StackedYawConfig;
    const KIND: &'static str = KIND;
    const PARAMS: &'static [ParamSpec<StackedYawConfig>] = &[param!(
        slope_urad_per_mm,
        "µrad/mm",
        Finite,
        |c| {
            format!(
                "yaw of the {} carriage per mm of its travel, acting on the {} axis's travel",
                c.lower_axis,
                c.lower_axis.other()
            )
        },
        linear(unit)
    )];

    fn check(name: &str, cfg: &StackedYawConfig) -> Result<(), ModelError> {
        for (key, v) in [
            ("lower_center_um", cfg.lower_center_um),
            ("upper_center_um", cfg.upper_center_um),
        ] {
            if !(v.is_finite() && v.abs() <= 1e9) {
                return Err(ModelError::Invalid {
                    key: format!("{name}.{key}"),
                    reason: "must be finite, |v| ≤ 1e9 µm".to_owned(),
                });
            }
        }
        Ok(())
    }

    fn contribution(cfg: &StackedYawConfig, state: &MotionState) -> [f64; 2] {
        let u = unit(cfg, state);
        [cfg.slope_urad_per_mm * u[0], cfg.slope_urad_per_mm * u[1]]
    }

    /// ε itself: the lower carriage turns the upper axis and the platform
    /// with it.
    fn yaw_rad(cfg: &StackedYawConfig, state: &MotionState) -> f64 {
        cfg.slope_urad_per_mm * 1e-9 * (state.cmd_um(cfg.lower_axis) - cfg.lower_center_um)
    }
}

#[cfg(test)]
mod tests {
    use super::super::super::term::Term;
    use super::*;

    fn term(lower: Axis, slope: f64) -> StackedYawTerm {
        StackedYawTerm::new(
            "yaw",
            StackedYawConfig {
                lower_axis: lower,
                slope_urad_per_mm: slope,
                lower_center_um: 5000.0,
                upper_center_um: 2000.0,
            },
        )
        .unwrap()
    }

    /// X below: 10 µrad/mm, 4 mm from the yaw's zero, 3 mm from the
    /// rotation centre: 40 µrad × 3000 µm = 0.12 µm towards −x. Not
    /// separable: the mixed second difference is the slope itself.
    #[test]
    fn the_error_is_bilinear_and_not_separable() {
        let t = term(Axis::X, 10.0);
        let c = t.contribution(&MotionState::at_rest(9000.0, 5000.0));
        assert!((c[0] + 0.12).abs() < 1e-12 && c[1] == 0.0, "{c:?}");
        // The yaw it reports: 40 µrad, whose turn of the arm (0, 3000 µm)
        // about +z is the −x displacement above.
        let yaw = t.yaw_rad(&MotionState::at_rest(9000.0, 5000.0));
        assert!((yaw - 40e-6).abs() < 1e-15 && (c[0] + yaw * 3000.0).abs() < 1e-12);
        let at = |x: f64, y: f64| t.contribution(&MotionState::at_rest(x, y))[0];
        let mixed =
            at(6000.0, 3000.0) - at(5000.0, 3000.0) - at(6000.0, 2000.0) + at(5000.0, 2000.0);
        assert!(
            (mixed + 10.0 * 1e-9 * 1000.0 * 1000.0).abs() < 1e-12,
            "{mixed}"
        );
        // Y below, X on top: the y error.
        let t = term(Axis::Y, -20.0);
        let c = t.contribution(&MotionState::at_rest(3000.0, 6000.0));
        assert!(
            c[0] == 0.0 && (c[1] + 20e-9 * 1000.0 * 1000.0).abs() < 1e-12,
            "{c:?}"
        );
        assert_eq!(
            t.jacobian(&MotionState::at_rest(3000.0, 6000.0)),
            vec![[0.0, 1e-9 * 1000.0 * 1000.0]]
        );
    }

    #[test]
    fn a_bad_centre_is_refused() {
        let e = StackedYawTerm::new(
            "yaw",
            StackedYawConfig {
                lower_axis: Axis::X,
                slope_urad_per_mm: 1.0,
                lower_center_um: f64::NAN,
                upper_center_um: 0.0,
            },
        )
        .unwrap_err();
        assert!(e.to_string().contains("lower_center_um"), "{e}");
    }
}
