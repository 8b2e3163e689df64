//! The pushed events (`{"event": name, …fields}`), each a struct naming
//! its event word and topic ([`Event`]), so the daemon sends one by type
//! and a client reads its fields by the same type.

use serde::{Deserialize, Serialize};
use serde_json::Value;

use super::motion::VisionPosition;
use super::status::RigStatus;
use super::{to_value, JobProgress, TimedReason};
use crate::daemon::protocol::Topic;
use crate::daemon::protocol::{event_line, reply_fields};

/// An event's word (`event`) and the topic it is sent on.
pub trait Event: Serialize {
    /// The `event` word.
    const NAME: &'static str;
    /// Who gets it: subscribers of this topic.
    const TOPIC: Topic;
}

/// `fault`: a fault (latched) or the controllers not reachable at start.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FaultEvent {
    /// Rig time, s.
    #[serde(deserialize_with = "super::null_as_nan")]
    pub t_s: f64,
    /// What happened.
    pub reason: String,
    /// `true` for a fault that latched (absent for one that did not).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub latched: Option<bool>,
}

impl Event for FaultEvent {
    const NAME: &'static str = "fault";
    const TOPIC: Topic = Topic::Fault;
}

/// `stopped`: a client's stop.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StoppedEvent(pub TimedReason);

impl Event for StoppedEvent {
    const NAME: &'static str = "stopped";
    const TOPIC: Topic = Topic::Fault;
}

/// `reset`: a client acknowledged the latched fault `cleared`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ClearedEvent {
    /// Rig time, s.
    #[serde(deserialize_with = "super::null_as_nan")]
    pub t_s: f64,
    /// The fault acknowledged.
    pub cleared: TimedReason,
}

impl Event for ClearedEvent {
    const NAME: &'static str = "reset";
    const TOPIC: Topic = Topic::Fault;
}

/// `state`: the rig's state once the controllers connected.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StateEvent {
    /// Rig time, s.
    #[serde(deserialize_with = "super::null_as_nan")]
    pub t_s: f64,
    /// The state.
    pub state: RigStatus,
}

impl Event for StateEvent {
    const NAME: &'static str = "state";
    const TOPIC: Topic = Topic::Fault;
}

/// `link_up`: a serial line (re)connected.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LinkUpEvent {
    /// The line (device path).
    pub line: String,
}

impl Event for LinkUpEvent {
    const NAME: &'static str = "link_up";
    const TOPIC: Topic = Topic::Fault;
}

/// `garbled`: an answer that did not parse (the controller is alive).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GarbledEvent {
    /// Rig time, s.
    #[serde(deserialize_with = "super::null_as_nan")]
    pub t_s: f64,
    /// Which controller.
    pub source: String,
    /// What was wrong with it.
    pub error: String,
}

impl Event for GarbledEvent {
    const NAME: &'static str = "garbled";
    const TOPIC: Topic = Topic::Fault;
}

/// `camera`: the camera's health changed (frames stall, stop decoding, or
/// decode again).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CameraEvent {
    /// Rig time, s.
    #[serde(deserialize_with = "super::null_as_nan")]
    pub t_s: f64,
    /// The health word (`ok`, `stalled`, `low_quality`).
    pub state: String,
    /// Why, in words.
    pub reason: String,
}

impl Event for CameraEvent {
    const NAME: &'static str = "camera";
    const TOPIC: Topic = Topic::Fault;
}

/// `position`: a new decode (`source` `vision`) or a controller poll
/// (`source` `controller`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "source", rename_all = "lowercase")]
pub enum PositionEvent {
    /// A decoded frame, with its stage position when tied.
    Vision(VisionPosition),
    /// The controllers' positions as polled.
    Controller(PolledPosition),
}

impl Event for PositionEvent {
    const NAME: &'static str = "position";
    const TOPIC: Topic = Topic::Position;
}

/// The controllers' positions of one poll (`null`: that read failed).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PolledPosition {
    /// Rig time, s.
    #[serde(deserialize_with = "super::null_as_nan")]
    pub t_s: f64,
    /// X, µm.
    pub x_um: Option<f64>,
    /// Y, µm.
    pub y_um: Option<f64>,
}

/// `job`: a job's progress, and when a validation ends its results.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct JobEvent {
    /// The progress.
    #[serde(flatten)]
    pub progress: JobProgress,
    /// A validation's test under way (`square`, `random`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub test: Option<String>,
    /// A validation's mode under way.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mode: Option<String>,
    /// An ended validation's results (as `validate status` has them).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub results: Option<Value>,
    /// An ended validation's logs.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub logs: Option<Value>,
}

impl JobEvent {
    /// The progress alone.
    pub fn of(progress: JobProgress) -> Self {
        Self {
            progress,
            test: None,
            mode: None,
            results: None,
            logs: None,
        }
    }
}

impl Event for JobEvent {
    const NAME: &'static str = "job";
    const TOPIC: Topic = Topic::Job;
}

/// `lagged`: events dropped for a slow reader (sent to it alone, on no
/// topic of its own).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct LaggedEvent {
    /// How many.
    pub missed: u64,
}

impl LaggedEvent {
    /// The `event` word.
    pub const NAME: &'static str = "lagged";

    /// The event's line (sent outside the topics' bus).
    pub fn line(&self) -> String {
        event_line(Self::NAME, reply_fields(to_value(self)))
    }
}

/// `halted`: a halt asked for (a job cancel, a shutdown) and whether it
/// brought both axes to rest.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct HaltedEvent {
    /// Rig time of the halt, s.
    #[serde(deserialize_with = "super::null_as_nan")]
    pub t_s: f64,
    /// Why.
    pub reason: String,
    /// Whether both axes came to rest.
    pub at_rest: bool,
    /// How long it waited, s.
    #[serde(deserialize_with = "super::null_as_nan")]
    pub wait_s: f64,
}

impl Event for HaltedEvent {
    const NAME: &'static str = "halted";
    const TOPIC: Topic = Topic::Fault;
}

/// `axis_recovered`: a line came back; its axis was halted and read back
/// (or why that failed).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AxisRecoveredEvent {
    /// Rig time, s.
    #[serde(deserialize_with = "super::null_as_nan")]
    pub t_s: f64,
    /// Which axis (`x`, `y`).
    pub axis: String,
    /// Whether the halt was answered.
    pub halted: bool,
    /// The state read back, when halt and read succeeded.
    #[serde(flatten)]
    pub read_back: Option<AxisReadBack>,
    /// Why halt or read-back failed; absent when both succeeded.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
}

impl Event for AxisRecoveredEvent {
    const NAME: &'static str = "axis_recovered";
    const TOPIC: Topic = Topic::Fault;
}

/// An axis' state read back after its line came back.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct AxisReadBack {
    /// Whether it is referenced.
    pub referenced: bool,
    /// Whether its servo is on.
    pub servo_on: bool,
    /// Whether it is on target.
    pub on_target: bool,
    /// Its position, µm (`null`: not referenced).
    pub position_um: Option<f64>,
    /// Its target, µm (`null`: not referenced).
    pub target_um: Option<f64>,
}
