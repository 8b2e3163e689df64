//! The typed replies both ends use: the daemon builds them, the CLI reads
//! them, one struct each, so a field renamed on one side cannot go unread on
//! the other (mini-redis' "one frame type for client and server").
//!
//! Why serde structs here while requests are parsed by hand: a reply has no
//! refusal to word; the daemon writes it and a client either reads it or
//! says which field it lacks (`serde`'s "missing field `t_s`").
//!
//! # Bytes on the wire
//! Every reply is serialized through `serde_json::Value`, whose maps keep
//! their keys sorted (serde_json without `preserve_order`), so a reply's
//! bytes do not depend on the field order here and are the bytes the
//! `json!` builders these replaced wrote (the tests in `pinned` keep the
//! old builders as the oracle). A field the daemon writes only sometimes
//! is `skip_serializing_if`; one it writes as `null` is an `Option`
//! without it. A number that is not finite (a NaN decode quality, an
//! unset fit rms) goes out as `null`, as `serde_json` writes it; every
//! plain `f64` field reads `null` back as NaN ([`null_as_nan`]), so one
//! such number never makes a whole reply unreadable.
//!
//! # Layout
//! * this file: the job progress ([`JobProgress`]), the `error` object
//!   ([`ErrorBody`]) and the small shapes the others share.
//! * `status`: `status` and its parts, `reset`.
//! * `motion`: `position`, `move` (every mode), `stop`, `reference`.
//! * `misc`: `version`, `tables`, the job replies, `subscribe`.
//! * `events`: the pushed events.

use serde::{Deserialize, Serialize};
use serde_json::Value;

use super::{JobKind, JobState, ProtoError};

mod events;
mod misc;
mod motion;
#[cfg(test)]
mod pinned;
#[cfg(test)]
mod round_trip;
mod status;

pub use events::{
    AxisReadBack, AxisRecoveredEvent, CameraEvent, ClearedEvent, Event, FaultEvent, GarbledEvent,
    HaltedEvent, JobEvent, LaggedEvent, LinkUpEvent, PolledPosition, PositionEvent, StateEvent,
    StoppedEvent,
};
pub use misc::{
    ConfigReply, DriftReply, JobCancelReply, JobReply, LoadedTable, SubscribeReply,
    TableActivateReply, TableLoadReply, TablesListReply, ValidationStatusReply, VersionReply,
};
pub use motion::{
    ClosedLoopOutcome, ControllerPosition, HaltReport, LoopMeasurement, MoveReply, OutsideTable,
    PositionReply, ReadErrors, ReferenceReply, StopReply, ToolMove, VisionPosition,
};
pub use status::{
    CameraClock, CameraStatus, DeviationStatus, Limits, ResetReply, RigStatus, StatusReply,
    ToolsStatus, VisionMeasurement, VisionTieStatus,
};

/// Reads a number or `null` (what `serde_json` writes for NaN and the
/// infinities) as an `f64`, `null` as NaN: the reader shows "not a
/// number" where the daemon had none, instead of refusing the reply.
pub(crate) fn null_as_nan<'de, D>(d: D) -> Result<f64, D::Error>
where
    D: serde::Deserializer<'de>,
{
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
}

/// A long job's progress, as the `job` object of replies and events
/// carries it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct JobProgress {
    /// Which job.
    pub kind: JobKind,
    /// Its log file name (identifies the job).
    pub log: String,
    /// Running, or how it ended.
    pub state: JobState,
    /// Points (poses) measured so far.
    pub done: u64,
    /// Points (poses) in the plan.
    pub total: u64,
    /// Estimated remaining rig time, s (`null` until known and once ended).
    pub eta_s: Option<f64>,
    /// Why it failed or stopped.
    pub error: Option<String>,
    /// Operations retried after transient faults in this run of the job
    /// (0 from a daemon that does not report it).
    #[serde(default)]
    pub retries: u64,
    /// A finished sweep's findings; `null` for other jobs.
    #[serde(default)]
    pub result: Value,
}

impl JobProgress {
    /// The progress as its JSON object.
    pub fn to_json(&self) -> Value {
        to_value(self)
    }

    /// The progress a `job` object holds; `None` for `null` (no job yet)
    /// or an object this client cannot read (a state a newer daemon added).
    pub fn from_json(v: &Value) -> Option<Self> {
        Self::deserialize(v).ok()
    }
}

/// The `error` object of a refusal: its stable code and a message for a
/// person.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ErrorBody {
    /// The stable code (`out_of_travel`); a string, since a newer daemon may
    /// send one this client does not know.
    pub code: String,
    /// What went wrong, for a person.
    pub message: String,
}

impl ErrorBody {
    /// The wire form of a refusal's error.
    pub fn of(e: &ProtoError) -> Self {
        Self {
            code: e.code.as_str().to_owned(),
            message: e.message.clone(),
        }
    }

    /// The `error` of a reply; `None` for an ok reply or an unreadable one.
    pub fn of_reply(reply: &Value) -> Option<Self> {
        Self::deserialize(&reply["error"]).ok()
    }
}

/// A job object as a reply carries it: one this side can read, or the
/// object as sent. Why not [`JobProgress`] alone: a newer daemon's job
/// state must not make the whole `status` unreadable; the client shows
/// that job as unreadable and the rest as usual.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum JobObject {
    /// A progress this side knows every word of.
    Known(JobProgress),
    /// Anything else, kept as sent.
    Unknown(Value),
}

impl JobObject {
    /// The progress, if this side could read it.
    pub fn known(&self) -> Option<&JobProgress> {
        match self {
            Self::Known(p) => Some(p),
            Self::Unknown(_) => None,
        }
    }

    /// The object as JSON (what the daemon sent).
    pub fn to_json(&self) -> Value {
        to_value(self)
    }
}

impl From<JobProgress> for JobObject {
    fn from(p: JobProgress) -> Self {
        Self::Known(p)
    }
}

/// A position pair keyed `x_um`/`y_um` (`target`, `commanded`,
/// `reported`): `T` is `f64`, or `Option<f64>` where an axis may have no
/// value (`null`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PairUm<T> {
    /// X, µm.
    pub x_um: T,
    /// Y, µm.
    pub y_um: T,
}

impl<T: Copy> PairUm<T> {
    /// From `[x, y]`.
    pub fn of(xy: [T; 2]) -> Self {
        Self {
            x_um: xy[0],
            y_um: xy[1],
        }
    }
}

/// One value per axis keyed `x`/`y` (`connected`, `rms_error_um`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct PerAxis<T> {
    /// The X axis'.
    pub x: T,
    /// The Y axis'.
    pub y: T,
}

impl<T: Clone> PerAxis<T> {
    /// From `[x, y]`.
    pub fn of(xy: [T; 2]) -> Self {
        let [x, y] = xy;
        Self { x, y }
    }
}

/// A time and why (`last_fault`, `fault_latched`, `cleared`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TimedReason {
    /// Rig time, s.
    #[serde(deserialize_with = "null_as_nan")]
    pub t_s: f64,
    /// What happened, in words.
    pub reason: String,
}

/// A reply struct as a JSON value: the daemon's one way to turn a reply
/// into what `reply` writes. Serializing these cannot fail (string keys,
/// no maps of other keys; a non-finite number becomes `null`, as `json!`
/// writes it), so the `null` fallback is never taken.
pub fn to_value<T: Serialize>(t: &T) -> Value {
    serde_json::to_value(t).unwrap_or(Value::Null)
}

/// A reply read from its JSON: `Err` says which field is missing or of the
/// wrong type (`missing field `t_s``), for a client to report instead of
/// guessing. The reply's `id` and `ok`, and fields a newer daemon added,
/// are ignored.
pub fn from_reply<T: serde::de::DeserializeOwned>(v: &Value) -> Result<T, serde_json::Error> {
    T::deserialize(v)
}

pub(super) fn error_body_value(e: &ProtoError) -> Value {
    to_value(&ErrorBody::of(e))
}
