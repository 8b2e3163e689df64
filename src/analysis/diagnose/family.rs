//! The search families: what a candidate discrepancy may vary with,
//! before the search fixes its nonlinear hyper-parameters.
//!
//! Why a file of its own: the search ([`super::search`]) enumerates and
//! searches them and the held-out judging ([`super::fit`]) records which
//! one a verdict is for; a leaf both import keeps the two apart.

use crate::model::Axis;

/// A search family (what varies, before the search fixes it).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) enum Family {
    PosPeriodic {
        axis: Axis,
        comp: Axis,
    },
    Localized {
        axis: Axis,
        comp: Axis,
    },
    Slope {
        axis: Axis,
        comp: Axis,
    },
    Drift {
        comp: Axis,
        quadratic: bool,
    },
    TimePeriodic {
        comp: Axis,
    },
    Temperature {
        comp: Axis,
    },
    Reversal {
        axis: Axis,
    },
    StepSize {
        axis: Axis,
    },
    Other {
        comp: Axis,
        var: usize,
    },
    /// Searched only where a reading of the replicates says the model
    /// lacks it (see `tables_wanted`).
    Table {
        axis: Axis,
        lost_motion: bool,
    },
    /// Both tables jointly, where both readings say the model lacks them.
    Tables {
        axis: Axis,
    },
}

impl Family {
    pub(super) fn comp(&self) -> Axis {
        match *self {
            Family::PosPeriodic { comp, .. }
            | Family::Localized { comp, .. }
            | Family::Slope { comp, .. }
            | Family::Drift { comp, .. }
            | Family::TimePeriodic { comp }
            | Family::Temperature { comp }
            | Family::Other { comp, .. } => comp,
            Family::Reversal { axis }
            | Family::StepSize { axis }
            | Family::Table { axis, .. }
            | Family::Tables { axis } => axis,
        }
    }
}
