//! `version`, `tables list|load|activate`, the job replies
//! (`characterize`/`validate` start, status, cancel) and `subscribe`.

use serde::{Deserialize, Serialize};
use serde_json::Value;

use super::JobObject;
use crate::comp::file::CompKind;

/// The `version` reply.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct VersionReply {
    /// The daemon's package version.
    pub daemon: String,
    /// The protocol version ([`PROTOCOL_VERSION`](super::super::PROTOCOL_VERSION)).
    pub protocol: u32,
    /// The command words it knows.
    pub commands: Vec<String>,
}

/// The `tables list` reply.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TablesListReply {
    /// The `.toml` files of the data directory, sorted.
    pub files: Vec<String>,
    /// The tables loaded, in name order.
    pub loaded: Vec<LoadedTable>,
    /// The active table; `null` for none.
    pub active: Option<String>,
}

/// One loaded table.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LoadedTable {
    /// Its file name.
    pub name: String,
    /// What it holds.
    pub kind: CompKind,
    /// When it was built (RFC 3339).
    pub created: String,
    /// Records of the log it was built from.
    pub records: u64,
    /// Whether it carries its measuring frame.
    pub has_frame: bool,
}

/// The `tables load` reply.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TableLoadReply {
    /// The file loaded.
    pub loaded: String,
    /// What it holds.
    pub kind: CompKind,
    /// Records of its log.
    pub records: u64,
}

/// The `tables activate` reply: the table now active (`null`: none, and
/// then no `kind`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TableActivateReply {
    /// The active table.
    pub active: Option<String>,
    /// What it holds.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub kind: Option<CompKind>,
}

/// The reply of `characterize status`, `characterize start|resume` and
/// `validate start`: the job (`null`: none yet) and, for `validate
/// start`, the origin and warnings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct JobReply {
    /// The current or last job.
    pub job: Option<JobObject>,
    /// `validate start`: the stage position of the paper's (0, 0).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub origin: Option<super::PairUm<f64>>,
    /// `validate start`: what the daemon warns about (poses outside a
    /// table's area under policy warn).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub warnings: Option<Vec<String>>,
}

impl JobReply {
    /// `{"job": …}` alone.
    pub fn job(job: Option<JobObject>) -> Self {
        Self {
            job,
            origin: None,
            warnings: None,
        }
    }
}

/// The `validate status` reply: the job (`null` unless the current or
/// last job is a validation) and its results.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ValidationStatusReply {
    /// The current or last validation.
    pub job: Option<JobObject>,
    /// Its results per test and mode, and its logs (`null` before any):
    /// as the validation job writes them.
    pub validation: Value,
}

/// The `characterize|validate cancel` reply: the job as it ended and the
/// halt that followed.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct JobCancelReply {
    /// The job.
    pub job: Option<JobObject>,
    /// The halt: at rest or not, how long it waited, errors.
    pub halt: super::HaltReport,
}

/// The `subscribe` reply.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SubscribeReply {
    /// The topics subscribed to.
    pub subscribed: Vec<String>,
}

/// The `drift show|set|reset|measure` reply: the live drift state after
/// the action, and what `measure` measured.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DriftReply {
    /// The state, as `analysis::drift::LiveDrift` writes it.
    pub drift: Value,
    /// `measure`: the reference sample taken.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub measured: Option<Value>,
}

/// The `config` reply: the configuration in force, as `DaemonConfig`
/// serializes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ConfigReply {
    /// The configuration.
    pub config: Value,
}
