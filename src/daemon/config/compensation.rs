//! `[closed_loop]` and `[compensation]`: how moves reach their target.

use serde::{Deserialize, Serialize};

/// `[closed_loop]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ClosedLoop {
    /// Residual accepted, µm.
    pub tolerance_um: f64,
    /// Corrections tried before giving up. Many are cheap: a stage that
    /// is deterministic at the target converges in one or two; where it
    /// scatters at arrival (stick-slip, σ ≈ 10× the tolerance) each try
    /// lands with ≈ 7–8 % chance, so 30 give ≈ 90 % and 60 ≈ 99 %; a
    /// validation visits such a target three times per trajectory, and
    /// one failed loop sets its AP at the stretch's σ.
    pub max_iterations: u32,
    /// Farthest the loop may move the command from the compensated one, µm
    /// (larger than the stage's whole raw error: beyond it the loop is
    /// chasing a wrong transform or a slipping platform, and stops).
    pub max_correction_um: f64,
    /// Every correction re-approaches from behind, so each ends with a move
    /// of the same length (`comp::closed_loop`); false: only corrections
    /// against the arrival direction do.
    pub always_reapproach: bool,
}

impl Default for ClosedLoop {
    fn default() -> Self {
        Self {
            tolerance_um: 0.1,
            max_iterations: 60,
            max_correction_um: 25.0,
            always_reapproach: true,
        }
    }
}

/// `[compensation]`: the backlash strategy of compensated and closed-loop
/// moves. Why a choice: direction-aware tables (the paper) correct the lost
/// motion of either arrival direction, but a unidirectional final approach
/// makes the backlash the same at every target, which is what a lab wants
/// when repeatability matters more than the extra move.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CompensationSection {
    /// `"direction_aware"` (each axis arrives in the direction from its
    /// previous target, corrected by the table of that direction) or
    /// `"unidirectional"` (each axis always arrives moving forward, +µm,
    /// from `overshoot_um` below the target when it comes from above).
    pub approach: Approach,
    /// Distance below the target from which a wrong-side arrival is
    /// re-approached, µm (≥ 10, well beyond the ≈ 2 µm backlash).
    pub overshoot_um: f64,
    /// What a compensated target outside the table's characterized area
    /// (beyond `outside_margin_um`) gets: `"refuse"` (the default: error
    /// `outside_table`, nothing moves), `"warn"` (moves, the reply and the
    /// log say so) or `"extrapolate"` (moves; the reply still reports it).
    /// A model table, whose terms extrapolate by physics, is warned about
    /// under `"refuse"` too.
    pub outside_table: OutsideTable,
    /// How far beyond its characterized area a target still counts as
    /// inside, µm. Why not 0: tables of separate characterizations differ by
    /// their tie's drift (≈ 0.5 µm), so a pose on the scan's last point can
    /// land a fraction of a µm outside; 10 µm is 2.5 % of a 400 µm screw
    /// pitch, over which the held end value stays close.
    pub outside_margin_um: f64,
}

/// `[compensation] outside_table`: a compensated target outside the
/// table's characterized area.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum OutsideTable {
    /// Refuse the move or the validation (error `outside_table`); a model
    /// table is only warned about.
    #[default]
    Refuse,
    /// Move, with a warning in the reply and the daemon's log.
    Warn,
    /// Move; the reply carries the distance outside as information.
    Extrapolate,
}

/// The backlash strategy (`[compensation] approach`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum Approach {
    /// Arrive in the direction of travel (the paper).
    #[default]
    DirectionAware,
    /// Always arrive moving forward.
    Unidirectional,
}

impl Default for CompensationSection {
    fn default() -> Self {
        Self {
            approach: Approach::DirectionAware,
            overshoot_um: 20.0,
            outside_table: OutsideTable::Refuse,
            outside_margin_um: 10.0,
        }
    }
}

impl CompensationSection {
    /// The planner options this section stands for.
    pub fn plan_options(&self) -> crate::comp::PlanOptions {
        use crate::comp::ApproachPolicy;
        use crate::model::Direction;
        crate::comp::PlanOptions {
            policy: match self.approach {
                Approach::DirectionAware => ApproachPolicy::DirectionAware,
                Approach::Unidirectional => {
                    ApproachPolicy::Unidirectional([Direction::Forward, Direction::Forward])
                }
            },
            overshoot_um: self.overshoot_um,
            ..crate::comp::PlanOptions::default()
        }
    }
}
