//! The built-in error terms. Each file holds one physical effect: its config
//! struct (the model-file table), the term, its builder and unit tests with
//! hand-computed values.

use super::term::{TermBuilder, TermRegistry};

pub mod angular;
pub mod backlash;
mod basis;
pub mod cyclic;
pub mod discovered;
pub mod lead;
pub mod offset;
pub mod position_map;
pub mod squareness;
pub mod stacked_yaw;
pub mod thermal;

pub(crate) use basis::{direction_weights, harmonics};

pub use angular::{AngularConfig, AngularTerm, Rotation};
pub use backlash::{play_offset_um, Backlash, BacklashConfig, BacklashTerm, PlayOperator};
pub use cyclic::{CyclicConfig, CyclicTerm};
pub use discovered::{
    DiscoveredConfig, DiscoveredTerm, LocalizedConfig, PositionPeriodicConfig, PositionSlopeConfig,
    PositionTableConfig, StepSizeConfig, TemperatureConfig, TimeDriftConfig, TimePeriodicConfig,
};
pub use lead::{Lead, LeadConfig, LeadTerm};
pub use offset::{OriginOffset, OriginOffsetConfig, OriginOffsetTerm};
pub use position_map::{PositionMapConfig, PositionMapTerm};
pub use squareness::{Squareness, SquarenessConfig, SquarenessTerm};
pub use stacked_yaw::{StackedYaw, StackedYawConfig, StackedYawTerm};
pub use thermal::{
    OpticsDrift, OpticsDriftConfig, OpticsDriftTerm, ThermalExpansion, ThermalExpansionConfig,
    ThermalExpansionTerm,
};

/// `(kind, one-line doc, builder)` of every built-in term.
pub(crate) const BUILTIN: &[(&str, &str, TermBuilder)] = &[
    (
        cyclic::LEADSCREW_KIND,
        "cyclic error along an axis at the leadscrew pitch and its harmonics, per direction",
        cyclic::build_leadscrew,
    ),
    (
        cyclic::COUPLING_KIND,
        "cyclic error across an axis while it moves (same period), per direction",
        cyclic::build_coupling,
    ),
    (
        backlash::KIND,
        "play between screw and nut: lost motion on reversal",
        backlash::BacklashTerm::build,
    ),
    (
        squareness::KIND,
        "out-of-squareness of the Y axis: x error proportional to y",
        squareness::SquarenessTerm::build,
    ),
    (
        stacked_yaw::KIND,
        "yaw of the lower carriage growing along its travel, times the upper axis's travel: error in both positions at once",
        stacked_yaw::StackedYawTerm::build,
    ),
    (
        lead::KIND,
        "cumulative lead (scale) error of an axis, ppm",
        lead::LeadTerm::build,
    ),
    (
        offset::KIND,
        "constant offset between the commanded frame and the measuring frame (the camera tie's origin)",
        offset::OriginOffsetTerm::build,
    ),
    (
        angular::KIND,
        "yaw/pitch/roll of a moving carriage times the Abbe offset of the tool point",
        angular::build,
    ),
    (
        thermal::EXPANSION_KIND,
        "thermal expansion and drift of the stage with ambient temperature",
        thermal::ThermalExpansionTerm::build,
    ),
    (
        thermal::OPTICS_KIND,
        "apparent shift of the camera's view with ambient temperature",
        thermal::OpticsDriftTerm::build,
    ),
    (
        discovered::POSITION_PERIODIC_KIND,
        "periodic error along a position at any period (found by `micropos diagnose`)",
        discovered::build_position_periodic,
    ),
    (
        discovered::LOCALIZED_KIND,
        "localized (Gaussian) error feature along an axis (found by `micropos diagnose`)",
        discovered::build_localized,
    ),
    (
        discovered::POSITION_SLOPE_KIND,
        "error proportional to an axis position: scale or cross-axis slope, ppm",
        discovered::build_position_slope,
    ),
    (
        discovered::TIME_DRIFT_KIND,
        "linear/quadratic drift of an error component with time",
        discovered::build_time_drift,
    ),
    (
        discovered::TIME_PERIODIC_KIND,
        "periodic error in time (e.g. an HVAC cycle)",
        discovered::build_time_periodic,
    ),
    (
        discovered::TEMPERATURE_KIND,
        "error proportional to the temperature difference from a reference",
        discovered::build_temperature,
    ),
    (
        discovered::STEP_SIZE_KIND,
        "lost motion that grows with the length of the last move (found by `micropos diagnose`)",
        discovered::build_step_size,
    ),
    (
        discovered::POSITION_TABLE_KIND,
        "error or lost motion tabulated at knots along an axis, linear between them (found by `micropos diagnose`)",
        discovered::build_position_table,
    ),
    (
        position_map::KIND,
        "error over x and y tabulated at the nodes of a lattice, bilinear between them, per arrival direction (fitted by `micropos diagnose` on grid maps)",
        position_map::PositionMapTerm::build,
    ),
];

impl TermRegistry {
    /// The built-in terms.
    pub fn builtin() -> Self {
        let mut r = TermRegistry::empty();
        for (kind, doc, builder) in BUILTIN {
            r.kinds.insert((*kind).to_string(), (*builder, *doc));
        }
        r
    }
}
