//! `[characterize]`: the job defaults.

use serde::{Deserialize, Serialize};

/// `[characterize]`: job defaults (a `characterize start` may override each).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CharacterizeDefaults {
    /// Step between points, µm.
    pub step_um: f64,
    /// X scan range, µm (centred in the travel unless `x_start_um`).
    pub x_range_um: f64,
    /// Y scan range, µm.
    pub y_range_um: f64,
    /// First X point, µm; unset = centred.
    pub x_start_um: Option<f64>,
    /// First Y point, µm; unset = centred.
    pub y_start_um: Option<f64>,
    /// Forward + backward cycles.
    pub cycles: u32,
    /// Frames averaged per point.
    pub frames_per_point: u32,
    /// Wait after on-target before measuring, s.
    pub settle_s: f64,
    /// Re-measure the drift reference every this many s of rig time during
    /// a characterization; 0 = off (see `docs/measurement-log.md`).
    pub drift_every_s: f64,
    /// Drift reference point `[x, y]`, µm; unset = the scan's start corner.
    pub drift_reference_um: Option<[f64; 2]>,
    /// On a camera grabbed on demand (the simulator's in-process rig), go
    /// on to the next point while a point's frames decode (`Vision::defer`):
    /// the same records in less wall time. `false`: each point is decoded
    /// before the stage moves on (to rule the overlap out when looking for
    /// a cause). No effect on a free-running camera, which decodes as it
    /// grabs.
    pub overlap_decode: bool,
}

impl Default for CharacterizeDefaults {
    fn default() -> Self {
        Self {
            step_um: 5.0,
            x_range_um: 9500.0,
            y_range_um: 4200.0,
            x_start_um: None,
            y_start_um: None,
            cycles: 3,
            frames_per_point: 4,
            settle_s: 0.5,
            drift_every_s: 0.0,
            drift_reference_um: None,
            overlap_decode: true,
        }
    }
}
