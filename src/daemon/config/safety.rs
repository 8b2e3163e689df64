//! `[safety]` and `[limits]`: the motion supervisor's bounds and the soft limits.

use serde::{Deserialize, Serialize};

/// `[safety]`: the bounds of the motion supervisor (`daemon::supervisor`;
/// `docs/design/daemon.md`, "Motion safety"). Why configurable: how far a
/// healthy stage may lag its commanded trajectory depends on its speed and
/// acceleration (a reversal at speed v and deceleration a lags by about
/// v²/a), and how long a line may stay silent before nobody is watching
/// the stage is a lab's decision.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SafetySection {
    /// How often a move in flight is checked (ERR?, POS?, ONT?), ms.
    pub supervise_interval_ms: u64,
    /// Largest distance between an axis's controller position and its
    /// commanded trajectory (start → target at the axis velocity), µm;
    /// 0 turns the check off.
    pub following_error_um: f64,
    /// Position reads of an axis may fail (no answer, garbled) for this
    /// long before a fault is latched, s. A line that is down is a fault of
    /// its own at once.
    pub read_fail_s: f64,
    /// How long a halt waits for both axes to come to rest (shutdown,
    /// `microposd --halt`, job cancel), s.
    pub halt_wait_s: f64,
    /// Largest distance between where the camera sees the platform and
    /// where the controller counts it, per axis, µm (`daemon::deviation`:
    /// vision − controller in the stage frame, translation tied at rest);
    /// 0 turns the check off. Above the stage's static error and drift.
    pub deviation_um: f64,
    /// Where the vision → stage orientation of that check comes from.
    pub deviation_frame: DeviationFrame,
}

/// Where the deviation check takes the vision → stage rotation from. Why
/// a choice: a wrong orientation makes every move look like a deviation of
/// up to twice its length, so the check only runs where the orientation is
/// known.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum DeviationFrame {
    /// A fitted vision frame: the rig's vision tie (`daemon::vision_tie`,
    /// taken after `reference`), else the active compensation table's
    /// (fitted by the characterization that built it); neither, no check.
    #[default]
    Table,
    /// `camera.rotation_rad` (for a rig without a tie or table whose
    /// camera orientation is set by hand); a tie or an active table's frame
    /// still wins.
    Camera,
}

impl Default for SafetySection {
    fn default() -> Self {
        Self {
            supervise_interval_ms: 100,
            following_error_um: 500.0,
            read_fail_s: 2.0,
            halt_wait_s: 5.0,
            deviation_um: 100.0,
            deviation_frame: DeviationFrame::Table,
        }
    }
}

/// `[limits]`: soft limits in µm, controller coordinates. Unset = the
/// controller's travel (`TMN?`/`TMX?`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub struct Limits {
    /// Lowest X target, µm.
    pub x_min_um: Option<f64>,
    /// Highest X target, µm.
    pub x_max_um: Option<f64>,
    /// Lowest Y target, µm.
    pub y_min_um: Option<f64>,
    /// Highest Y target, µm.
    pub y_max_um: Option<f64>,
}
