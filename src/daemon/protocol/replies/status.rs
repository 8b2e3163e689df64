//! `status` and its parts (the rig's state, travel, camera, deviation
//! check, vision tie), and `reset`, which answers with the rig's state.

use serde::{Deserialize, Serialize};
use serde_json::Value;

use super::{JobObject, PerAxis, TimedReason};

/// The `status` reply: the rig, its travel, camera, drift, checks and job.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StatusReply {
    /// Rig time, s.
    #[serde(deserialize_with = "super::null_as_nan")]
    pub t_s: f64,
    /// Connection, reference and fault state.
    pub rig: RigStatus,
    /// The allowed range (soft limits ∩ travel); `null` while not
    /// connected.
    pub limits: Option<Limits>,
    /// The vision pipeline's counters; `null` without a camera.
    pub camera: Option<CameraStatus>,
    /// Live drift correction, as `analysis::drift::LiveDrift` writes it
    /// (not typed here: the library module below the daemon owns it).
    pub drift: Value,
    /// The vision-vs-controller deviation check.
    pub deviation: DeviationStatus,
    /// Whether vision is tied to the stage.
    pub vision_tie: VisionTieStatus,
    /// The current or last job; `null` before the first.
    pub job: Option<JobObject>,
    /// The configured tool points (`[tools]`); absent when none is.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tools: Option<ToolsStatus>,
}

/// The tool points a `move --tool` can bring to a target
/// (`status.tools`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ToolsStatus {
    /// The tool used when a move names none; `null`: a tool move must
    /// name one.
    pub active: Option<String>,
    /// Each tool's offset from the watched point `[x, y]`, µm, platform
    /// frame at the tie.
    pub offsets_um: std::collections::BTreeMap<String, [f64; 2]>,
}

/// The rig's state (`status.rig`, `reset.rig`, the `state` event).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RigStatus {
    /// The overall state in a word: `disconnected`, `fault`,
    /// `unreferenced`, `idle`, `moving`, `referencing`, `job`.
    pub mode: String,
    /// What the axes are doing: `idle`, `moving`, `referencing`, `job`.
    pub activity: String,
    /// Whether each axis' controller is connected.
    pub connected: PerAxis<bool>,
    /// Whether each axis is referenced.
    pub referenced: PerAxis<bool>,
    /// Faults since start.
    pub faults: u64,
    /// The last fault, latched or reset.
    pub last_fault: Option<TimedReason>,
    /// The fault latched now (motion refused until `reset`).
    pub fault_latched: Option<TimedReason>,
    /// Per axis why it is not connected (`null` for a connected one);
    /// absent while both are.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub not_connected: Option<PerAxis<Option<String>>>,
}

/// The allowed range of each axis, `[low, high]` µm.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Limits {
    /// X range, µm.
    pub x_um: [f64; 2],
    /// Y range, µm.
    pub y_um: [f64; 2],
}

/// The vision pipeline's counters and newest measurement
/// (`status.camera`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CameraStatus {
    /// Frames grabbed.
    pub frames: u64,
    /// Frames decoded.
    pub decoded: u64,
    /// Frames that did not decode.
    pub failed: u64,
    /// Errors of the camera itself.
    pub camera_errors: u64,
    /// Frames dropped (the decoder was busy; a newer one took their place).
    pub dropped: u64,
    /// The last error, in words.
    pub last_error: Option<String>,
    /// The newest decode.
    pub latest: Option<VisionMeasurement>,
    /// The camera clock against the rig clock, once estimated.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera_clock: Option<CameraClock>,
}

/// The camera clock's rate against the rig clock.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CameraClock {
    /// Rate difference, ppm.
    #[serde(deserialize_with = "super::null_as_nan")]
    pub rate_ppm: f64,
    /// Times the camera's clock restarted.
    pub resets: u64,
}

/// One decoded frame in pattern coordinates (`camera.latest`, and the
/// core of `position.vision` and the position events).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct VisionMeasurement {
    /// Rig time of the grab request, s.
    #[serde(deserialize_with = "super::null_as_nan")]
    pub t_s: f64,
    /// Rig time of the exposure, s.
    #[serde(deserialize_with = "super::null_as_nan")]
    pub frame_t_s: f64,
    /// The frame's sequence number.
    pub sequence: u64,
    /// Pattern x, µm.
    #[serde(deserialize_with = "super::null_as_nan")]
    pub x_um: f64,
    /// Pattern y, µm.
    #[serde(deserialize_with = "super::null_as_nan")]
    pub y_um: f64,
    /// Pattern angle, rad.
    #[serde(deserialize_with = "super::null_as_nan")]
    pub theta_rad: f64,
    /// Decoder quality (smaller code margin, bits).
    #[serde(deserialize_with = "super::null_as_nan")]
    pub quality: f64,
}

/// The deviation check's state (`status.deviation`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DeviationStatus {
    /// Whether the check runs now.
    pub armed: bool,
    /// What it does or why it does not, in words.
    pub state: String,
    /// The bound, µm (0: off).
    #[serde(deserialize_with = "super::null_as_nan")]
    pub bound_um: f64,
    /// Where its orientation comes from; `null` without one.
    pub frame: Option<String>,
    /// Whether it has an orientation.
    pub frame_known: bool,
    /// Whether its translation is tied.
    pub tied: bool,
    /// The last deviation, µm per axis.
    pub last_um: Option<PerAxis<f64>>,
}

/// Whether vision is tied to the stage (`status.vision_tie`): `tied`, and
/// either the tie (its frame, when, what it saw) or `why` not and what that
/// switches off. Every field but `tied` is written only in some states.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct VisionTieStatus {
    /// Whether a tie is stored.
    pub tied: bool,
    /// Why not tied, or why the stored tie is not in force.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub why: Option<String>,
    /// What an untied camera cannot do.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub switched_off: Option<String>,
    /// `false` when tied but not usable now (an axis lost its reference).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub in_force: Option<bool>,
    /// The frame vision positions are given in now.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frame_in_force: Option<String>,
    /// What the tie followed (`reference`, a job).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub after: Option<String>,
    /// When it was taken, UTC.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub taken_utc: Option<String>,
    /// Whether it was restored from the data directory, in words (`no`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub restored: Option<String>,
    /// Camera rotation, rad.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rotation_rad: Option<f64>,
    /// Whether the camera image is mirrored.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mirrored: Option<bool>,
    /// Pattern-to-stage translation, µm.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub translation_um: Option<PerAxis<f64>>,
    /// Where the tie was anchored, µm.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub anchor_um: Option<PerAxis<f64>>,
    /// Axis squareness, µrad.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub squareness_urad: Option<f64>,
    /// Scale per axis, ppm.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scale_ppm: Option<PerAxis<f64>>,
    /// The tie fit's rms error, µm per axis.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rms_error_um: Option<PerAxis<f64>>,
}

/// The `reset` reply: the fault it cleared (`null`: none was latched) and
/// the rig's state after.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ResetReply {
    /// The fault acknowledged.
    pub cleared: Option<TimedReason>,
    /// The state after.
    pub rig: RigStatus,
}
