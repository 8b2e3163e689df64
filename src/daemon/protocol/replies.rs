//! The typed replies both ends use: the daemon writes them, the CLI reads
//! them, one struct each, so a field renamed on one side cannot go unread on
//! the other. The job progress (`job` in `status`, `characterize status`,
//! `validate status` and `job` events) and an error reply's `error` object.
//!
//! Why only these: they are what clients parse field by field to decide
//! something (has the job ended, which code); the other replies are shown
//! or passed on whole and stay `serde_json::Value` (docs/socket-protocol.md
//! lists their fields). Serialized through `serde_json::Value`, whose maps
//! keep their keys sorted, so a reply's bytes do not depend on the field
//! order here.

use serde::{Deserialize, Serialize};
use serde_json::Value;

use super::{JobKind, JobState, ProtoError};

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

/// A reply struct as a JSON value. Serializing these cannot fail (string
/// keys, no maps of other keys; a non-finite number becomes `null`, as
/// `json!` writes it), so the `null` fallback is never taken.
fn to_value<T: Serialize>(t: &T) -> Value {
    serde_json::to_value(t).unwrap_or(Value::Null)
}

pub(super) fn error_body_value(e: &ProtoError) -> Value {
    to_value(&ErrorBody::of(e))
}
