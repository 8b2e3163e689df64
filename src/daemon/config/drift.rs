//! `[drift]`: live drift correction of compensated moves.

use serde::{Deserialize, Serialize};

/// `[drift]`: live drift correction of compensated moves (see
/// `docs/design/daemon.md`, "Live drift correction"). Why: over hours the
/// room's temperature moves the platform and the optics by more than the
/// tables' accuracy; re-measuring one reference point at intervals
/// measures that drift, and compensated targets are shifted by it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DriftSection {
    /// `"off"` (default), `"static"` (the offset of the first
    /// re-measurement, held) or `"adaptive"` (local line with forgetting
    /// `time_constant_s`, extrapolated to each move).
    pub method: DriftMethodName,
    /// Re-measure the reference every this many s of rig time (checked
    /// before compensated moves and between validation points), > 0.
    pub every_s: f64,
    /// Forgetting time constant of the adaptive model, s (> 0).
    pub time_constant_s: f64,
    /// Reference point `[x, y]` µm for tables that record none (built from
    /// logs without `drift_every_s`); unset = `characterize.drift_reference_um`,
    /// else the characterization's start corner. A table's own reference
    /// always wins: drift is only meaningful against its baseline.
    pub reference_um: Option<[f64; 2]>,
}

/// `[drift] method`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum DriftMethodName {
    /// No live correction.
    #[default]
    Off,
    /// First offset, held.
    Static,
    /// Local line with forgetting.
    Adaptive,
}

impl DriftMethodName {
    /// As written in the config and the protocol.
    pub fn as_str(self) -> &'static str {
        match self {
            DriftMethodName::Off => "off",
            DriftMethodName::Static => "static",
            DriftMethodName::Adaptive => "adaptive",
        }
    }
}

impl Default for DriftSection {
    fn default() -> Self {
        Self {
            method: DriftMethodName::Off,
            every_s: 300.0,
            time_constant_s: crate::analysis::drift::LIVE_TIME_CONSTANT_S,
            reference_um: None,
        }
    }
}

impl DriftSection {
    /// The live method this section stands for.
    pub fn live_method(&self) -> crate::analysis::drift::LiveMethod {
        use crate::analysis::drift::LiveMethod;
        match self.method {
            DriftMethodName::Off => LiveMethod::Off,
            DriftMethodName::Static => LiveMethod::Static,
            DriftMethodName::Adaptive => LiveMethod::Adaptive {
                time_constant_s: self.time_constant_s,
            },
        }
    }
}
