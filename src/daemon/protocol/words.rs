//! The protocol's keywords (`"mode": "raw"`, `"axes": "xy"`, …): each
//! keyword type's words, its refusal of an unknown word, and the refusals of
//! a missing required field, shared by the parser and by clients that build
//! typed requests.
//!
//! Why a file of its own: the CLI reads the same words from its command
//! line; with [`Word::from_word`] it refuses a typo with the daemon's code
//! and message, and the schema (`schema`) lists the words from here, so a
//! word added to a type reaches parser, client and schema at once.

use super::command::{
    Axes, CharacterizeMode, CharacterizePlan, FiguresJob, GridApproach, GridOrder, MoveMode, Topic,
    ValidateMode,
};
use super::fields::unknown_word;
use super::{ErrorCode, ProtoError};
use crate::daemon::config::DriftMethodName;

/// A keyword type of the protocol: a closed set of words on the wire.
pub trait Word: Copy + PartialEq + Sized + 'static {
    /// Every value, in the order refusals and the schema list them.
    const ALL: &'static [Self];
    /// What a refusal calls the field (`"mode"`, `"grid order"`).
    const WHAT: &'static str;
    /// The words as a refusal lists them (`"raw, compensated or closed_loop"`).
    const CHOICES: &'static str;

    /// The word sent on the wire.
    fn as_str(self) -> &'static str;

    /// The value a word names, or the `bad_value` refusal the daemon sends
    /// for it (the word cut to 64 characters).
    fn from_word(word: &str) -> Result<Self, ProtoError> {
        Self::ALL
            .iter()
            .copied()
            .find(|w| w.as_str() == word)
            .ok_or_else(|| unknown_word(Self::WHAT, word, Self::CHOICES))
    }
}

/// The words of a keyword type, for the schema.
pub(super) fn words<T: Word>() -> Vec<&'static str> {
    T::ALL.iter().map(|w| w.as_str()).collect()
}

impl Word for MoveMode {
    const ALL: &'static [Self] = &[Self::Raw, Self::Compensated, Self::ClosedLoop];
    const WHAT: &'static str = "mode";
    const CHOICES: &'static str = "raw, compensated or closed_loop";
    fn as_str(self) -> &'static str {
        MoveMode::as_str(self)
    }
}

impl Word for Axes {
    const ALL: &'static [Self] = &[Self::X, Self::Y, Self::Both];
    const WHAT: &'static str = "axes";
    const CHOICES: &'static str = "x, y or xy";
    fn as_str(self) -> &'static str {
        Axes::as_str(self)
    }
    /// `both` is read as `xy` too (older clients send it).
    fn from_word(word: &str) -> Result<Self, ProtoError> {
        match word {
            "both" => Ok(Axes::Both),
            _ => Self::ALL
                .iter()
                .copied()
                .find(|w| w.as_str() == word)
                .ok_or_else(|| unknown_word(Self::WHAT, word, Self::CHOICES)),
        }
    }
}

impl Word for Topic {
    const ALL: &'static [Self] = &[Self::Position, Self::Job, Self::Fault, Self::Drift];
    const WHAT: &'static str = "topic";
    const CHOICES: &'static str = "position, job, fault, drift";
    fn as_str(self) -> &'static str {
        Topic::as_str(self)
    }
}

impl Word for CharacterizeMode {
    const ALL: &'static [Self] = &[Self::Step, Self::Sweep];
    const WHAT: &'static str = "characterize mode";
    const CHOICES: &'static str = "step, sweep";
    fn as_str(self) -> &'static str {
        CharacterizeMode::as_str(self)
    }
}

impl Word for CharacterizePlan {
    const ALL: &'static [Self] = &[Self::Lines, Self::Grid];
    const WHAT: &'static str = "characterize plan";
    const CHOICES: &'static str = "lines, grid";
    fn as_str(self) -> &'static str {
        match self {
            Self::Lines => "lines",
            Self::Grid => "grid",
        }
    }
}

impl Word for GridApproach {
    const ALL: &'static [Self] = &[Self::Below, Self::Both];
    const WHAT: &'static str = "grid approach";
    const CHOICES: &'static str = "below, both";
    fn as_str(self) -> &'static str {
        match self {
            Self::Below => "below",
            Self::Both => "both",
        }
    }
}

impl Word for GridOrder {
    const ALL: &'static [Self] = &[Self::Raster, Self::Serpentine];
    const WHAT: &'static str = "grid order";
    const CHOICES: &'static str = "raster, serpentine";
    fn as_str(self) -> &'static str {
        match self {
            Self::Raster => "raster",
            Self::Serpentine => "serpentine",
        }
    }
}

impl Word for ValidateMode {
    const ALL: &'static [Self] = &ValidateMode::ALL;
    const WHAT: &'static str = "mode";
    const CHOICES: &'static str = "raw, table, model, closed_loop";
    fn as_str(self) -> &'static str {
        ValidateMode::as_str(self)
    }
}

impl Word for FiguresJob {
    const ALL: &'static [Self] = &[Self::Characterize, Self::Validate];
    const WHAT: &'static str = "figures job";
    const CHOICES: &'static str = "characterize, validate";
    fn as_str(self) -> &'static str {
        FiguresJob::as_str(self)
    }
}

impl Word for DriftMethodName {
    const ALL: &'static [Self] = &[Self::Off, Self::Static, Self::Adaptive];
    const WHAT: &'static str = "drift method";
    const CHOICES: &'static str = "off, static or adaptive";
    fn as_str(self) -> &'static str {
        DriftMethodName::as_str(self)
    }
}

/// The trajectories of `validate start` (`test`), as one word for a
/// choice of [`ValidateParams::tests`](super::ValidateParams::tests).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ValidateTest {
    /// The paper's square.
    Square,
    /// Table II's random targets.
    Random,
    /// The square, then the random targets.
    Both,
}

impl ValidateTest {
    /// The trajectories the word names, in the order run.
    pub fn tests(self) -> Vec<String> {
        match self {
            Self::Square => vec!["square".to_owned()],
            Self::Random => vec!["random".to_owned()],
            Self::Both => vec!["square".to_owned(), "random".to_owned()],
        }
    }

    /// The word for a list of trajectories: `both` for anything but one
    /// of them alone (the parser produces no other list).
    pub fn of(tests: &[String]) -> Self {
        match tests {
            [t] if t == "square" => Self::Square,
            [t] if t == "random" => Self::Random,
            _ => Self::Both,
        }
    }
}

impl Word for ValidateTest {
    const ALL: &'static [Self] = &[Self::Square, Self::Random, Self::Both];
    const WHAT: &'static str = "test";
    const CHOICES: &'static str = "square, random or both";
    fn as_str(self) -> &'static str {
        match self {
            Self::Square => "square",
            Self::Random => "random",
            Self::Both => "both",
        }
    }
}

/// The table kinds of `tables build` (`kinds`); kept as words in
/// [`TablesBuildParams::kinds`](super::TablesBuildParams::kinds).
pub const TABLE_KINDS: &[&str] = &["paper", "model", "grid"];

/// The refusal of `characterize resume` without `log`.
pub fn resume_needs_log() -> ProtoError {
    ProtoError::new(
        ErrorCode::MissingField,
        "characterize resume needs log (the file name of the job to continue)",
    )
}

/// The refusal of `tables load` without `name`.
pub fn load_needs_name() -> ProtoError {
    ProtoError::new(
        ErrorCode::MissingField,
        "tables load needs name (a table file in the data directory)",
    )
}

/// The refusal of `tables build` without `log`.
pub fn build_needs_log() -> ProtoError {
    ProtoError::new(
        ErrorCode::MissingField,
        "tables build needs log (a characterization log in the data directory)",
    )
}
