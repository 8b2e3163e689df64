//! `position`, `move` (every mode), `stop` and `reference`.

use serde::{Deserialize, Serialize};
use serde_json::Value;

use super::status::VisionMeasurement;
use super::PairUm;

/// The `position` reply: every source, each with its time.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PositionReply {
    /// What the last move asked (`null` for an axis never moved).
    pub commanded: PairUm<Option<f64>>,
    /// The controllers' positions; `null` when none is known.
    pub controller: Option<ControllerPosition>,
    /// The newest decode; `null` without a camera or before the first.
    pub vision: Option<VisionPosition>,
}

/// The controllers' positions: read now (with each axis' read error), or,
/// while not connected, as last polled (without them).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ControllerPosition {
    /// Rig time of the read, s.
    #[serde(deserialize_with = "super::null_as_nan")]
    pub t_s: f64,
    /// X, µm (`null`: the read failed or was never made).
    pub x_um: Option<f64>,
    /// Y, µm.
    pub y_um: Option<f64>,
    /// The read errors of a read made now; absent for a polled value.
    #[serde(flatten)]
    pub errors: Option<ReadErrors>,
}

/// Why an axis' position read failed (`null`: it did not).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ReadErrors {
    /// X's read error.
    #[serde(deserialize_with = "Option::deserialize")]
    pub x_error: Option<String>,
    /// Y's read error.
    #[serde(deserialize_with = "Option::deserialize")]
    pub y_error: Option<String>,
}

/// A decoded measurement with, through the frame in force, the stage
/// position (`position.vision`, the vision position events): either the
/// stage coordinates and the `frame`, or `untied` saying why there are
/// none.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct VisionPosition {
    /// The decode in pattern coordinates.
    #[serde(flatten)]
    pub measurement: VisionMeasurement,
    /// Stage x, µm (the controllers' axes and signs).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stage_x_um: Option<f64>,
    /// Stage y, µm.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stage_y_um: Option<f64>,
    /// The frame the stage coordinates are in.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frame: Option<String>,
    /// Why there are no stage coordinates, and what that switches off.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub untied: Option<String>,
    /// How old the measurement is, s (`position` only).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub age_s: Option<f64>,
}

/// The `move` reply. A raw move writes `commanded` (and with `wait`
/// `reported` and `on_target`); a compensated or closed-loop one the
/// target, the compensator, the plan, and what drift, the table's area
/// and the closed loop did.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MoveReply {
    /// The command sent (`null` for an axis not moved by a raw move).
    pub commanded: PairUm<Option<f64>>,
    /// The positions reported once on target (raw with `wait`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reported: Option<PairUm<Option<f64>>>,
    /// Whether the move ended on target (raw with `wait`, planned moves).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub on_target: Option<bool>,
    /// The mode of a planned move.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mode: Option<String>,
    /// The compensator's kind (`lookup`, `model`, `grid`, `none`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub compensator: Option<String>,
    /// The target the user asked for.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub target: Option<PairUm<f64>>,
    /// Moves the plan took.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub waypoints: Option<u64>,
    /// The predicted `observed − commanded`, µm `[x, y]`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub predicted_offset_um: Option<[f64; 2]>,
    /// Live drift's part (compensated, with drift on).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub drift: Option<Value>,
    /// The target lies outside the table's area (policy warn or
    /// extrapolate).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub outside_table: Option<OutsideTable>,
    /// How the closed loop ended (mode `closed_loop`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub closed_loop: Option<ClosedLoopOutcome>,
    /// A tool move (`tool`): the tool, the yaw predicted for it and the
    /// watched point's target it became (`target` above).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tool: Option<ToolMove>,
}

/// What a tool move planned: the tool's target less its arm turned by the
/// predicted yaw is the watched point's target.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ToolMove {
    /// The tool's `[tools]` name.
    pub name: String,
    /// Its offset from the watched point, platform frame at the tie, µm.
    pub offset_um: [f64; 2],
    /// Where the tool should be, µm.
    pub tool_target_um: [f64; 2],
    /// The yaw predicted at the arrival, µrad (positive: +x towards +y).
    pub yaw_urad: f64,
    /// `table`: from the active table's `[yaw]`; `none`: the table has
    /// no yaw tables (built from a log without θ) or no table is active,
    /// so θ = 0 was used and the tool is off by the yaw times its arm.
    pub yaw_source: String,
    /// What the closed loop closes on (mode `closed_loop`): `pattern`, the
    /// watched point's target; absent otherwise.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub closed_on: Option<String>,
}

impl MoveReply {
    /// A raw move's reply before its wait: the command alone.
    pub fn commanded(targets: [Option<f64>; 2]) -> Self {
        Self {
            commanded: PairUm::of(targets),
            reported: None,
            on_target: None,
            mode: None,
            compensator: None,
            target: None,
            waypoints: None,
            predicted_offset_um: None,
            drift: None,
            outside_table: None,
            closed_loop: None,
            tool: None,
        }
    }
}

/// A converged closed loop: where it ended and how many corrections it
/// took.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ClosedLoopOutcome {
    /// `target − measured` at the end, µm.
    pub residual_um: PairUm<f64>,
    /// Correction moves made.
    pub corrections: u32,
    /// The last measurement.
    pub measured: LoopMeasurement,
    /// The last command.
    pub commanded: PairUm<f64>,
}

/// The closed loop's last measurement (stage frame).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LoopMeasurement {
    /// X, µm.
    #[serde(deserialize_with = "super::null_as_nan")]
    pub x_um: f64,
    /// Y, µm.
    #[serde(deserialize_with = "super::null_as_nan")]
    pub y_um: f64,
    /// Rig time, s.
    #[serde(deserialize_with = "super::null_as_nan")]
    pub t_s: f64,
    /// Decode quality.
    #[serde(deserialize_with = "super::null_as_nan")]
    pub quality: f64,
}

/// The `stop` reply (a stop that failed on an axis is an error).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct StopReply {
    /// Always `true`.
    pub stopped: bool,
}

/// The `reference` reply: where the run left the axes, and the vision tie
/// that followed it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ReferenceReply {
    /// The positions reported after the run (`null`: axis not referenced).
    pub reported: PairUm<Option<f64>>,
    /// The tie's outcome (`tied` and the frame, or `tied: false` and
    /// `why`), as `jobs::tie` writes it.
    pub vision_tie: Value,
}

/// A halt and the wait for rest that followed it (`halt` of a job
/// cancel's reply).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct HaltReport {
    /// Whether both axes reported no motion within `safety.halt_wait_s`.
    pub at_rest: bool,
    /// Per axis whether it still moved (absent when not connected).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub moving: Option<super::PerAxis<bool>>,
    /// How long it waited, s.
    #[serde(deserialize_with = "super::null_as_nan")]
    pub wait_s: f64,
    /// The halts that failed, per axis.
    pub errors: Vec<String>,
    /// Why it halted (a halt asked for: a cancel, a shutdown).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reason: Option<String>,
}

/// A target outside the area the active table was characterized over,
/// under policy `warn` or `extrapolate` (`outside_table` of a compensated
/// move; its `warning` also in `validate start`'s `warnings`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct OutsideTable {
    /// `warn` or `extrapolate`.
    pub policy: String,
    /// The characterized area.
    pub area: super::status::Limits,
    /// `[compensation] outside_margin_um`.
    #[serde(deserialize_with = "super::null_as_nan")]
    pub margin_um: f64,
    /// How far outside per axis, µm `[x, y]`.
    pub outside_by_um: [f64; 2],
    /// The warning, in words (policy `warn`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub warning: Option<String>,
}
