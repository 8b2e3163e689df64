//! A long job's kind and state as the protocol carries them (`job` in
//! replies and events): one type for the daemon that writes them and the
//! clients that read them, so a state the daemon adds cannot go unread by
//! a `match` in the CLI.

use std::fmt;

use super::command::{CharacterizeAction, Command, ValidateAction};

/// Which long job a progress describes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum JobKind {
    /// `characterize`: a step, grid or sweep characterization.
    Characterize,
    /// `validate`: the ISO 9283 validation.
    Validate,
}

impl JobKind {
    /// The protocol word, which is also the command that starts the job.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Characterize => "characterize",
            Self::Validate => "validate",
        }
    }

    /// The kind a protocol word names; `None` for a word this client does
    /// not know.
    pub fn parse(word: &str) -> Option<Self> {
        [Self::Characterize, Self::Validate]
            .into_iter()
            .find(|k| k.as_str() == word)
    }

    /// The request for this kind's progress (`characterize status`,
    /// `validate status`): what a client following a job asks.
    pub fn status_command(self) -> Command {
        match self {
            Self::Characterize => Command::Characterize(CharacterizeAction::Status),
            Self::Validate => Command::Validate(ValidateAction::Status),
        }
    }
}

impl fmt::Display for JobKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// Where a job is: `Running` until it ends, then how it ended (kept until
/// the next job starts). Its log stays resumable in every ended state but
/// `Done`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum JobState {
    /// Moving and measuring.
    Running,
    /// Every point of its plan measured.
    Done,
    /// A client's `cancel` ended it.
    Cancelled,
    /// A stop or a fault halted the rig under it.
    Stopped,
    /// An error ended it (the progress's `error` says which).
    Failed,
}

impl JobState {
    /// Every state, in the order a job can pass through them.
    pub const ALL: [Self; 5] = [
        Self::Running,
        Self::Done,
        Self::Cancelled,
        Self::Stopped,
        Self::Failed,
    ];

    /// The protocol word.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Running => "running",
            Self::Done => "done",
            Self::Cancelled => "cancelled",
            Self::Stopped => "stopped",
            Self::Failed => "failed",
        }
    }

    /// The state a protocol word names; `None` for a word this client does
    /// not know (a newer daemon's), which a reader treats as ended.
    pub fn parse(word: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|s| s.as_str() == word)
    }

    /// The state of a `job` object (a reply's or an event's), for a
    /// client; `None` when it has none or one this client does not know.
    pub fn of(job: &serde_json::Value) -> Option<Self> {
        job["state"].as_str().and_then(Self::parse)
    }

    /// Whether the job has ended (every state but `Running`).
    pub fn ended(self) -> bool {
        self != Self::Running
    }
}

impl fmt::Display for JobState {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// serde's spelling (the typed replies) is the protocol word.
    #[test]
    fn serde_writes_the_protocol_words() {
        for s in JobState::ALL {
            assert_eq!(serde_json::json!(s), serde_json::json!(s.as_str()));
        }
        for k in [JobKind::Characterize, JobKind::Validate] {
            assert_eq!(serde_json::json!(k), serde_json::json!(k.as_str()));
            assert_eq!(JobKind::parse(k.as_str()), Some(k));
        }
    }

    #[test]
    fn every_state_reads_back_from_its_word() {
        for s in JobState::ALL {
            assert_eq!(JobState::parse(s.as_str()), Some(s));
        }
        assert_eq!(JobState::parse("paused"), None);
        assert_eq!(
            JobState::of(&serde_json::json!({"state": "stopped"})),
            Some(JobState::Stopped)
        );
        assert_eq!(JobState::of(&serde_json::json!({})), None);
        assert_eq!(
            JobState::ALL.iter().filter(|s| !s.ended()).count(),
            1,
            "only running has not ended"
        );
    }
}
