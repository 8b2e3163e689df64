//! What can go wrong with a model: a leaf every model file names.

use thiserror::Error;

/// Everything that can go wrong loading, evaluating or fitting a model. Every
/// message names the key, term or parameter at fault.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum ModelError {
    /// The file is not valid TOML or does not match the format (the message
    /// from the TOML parser names the key and position).
    #[error("stage model file: {message}")]
    Toml {
        /// Parser message.
        message: String,
    },
    /// A term's table has an unknown key, a missing key or a wrong type.
    #[error("stage model term `{term}` (kind {kind}): {message}")]
    Term {
        /// Term name.
        term: String,
        /// Term kind.
        kind: String,
        /// Deserializer message (names the key).
        message: String,
    },
    /// A value is out of range or not finite.
    #[error("stage model: {key}: {reason}")]
    Invalid {
        /// Dotted key path of the offending value.
        key: String,
        /// What is wrong.
        reason: String,
    },
    /// `kind = "..."` names no registered term.
    #[error("stage model term `{term}`: unknown kind `{kind}` (known: {known})")]
    UnknownKind {
        /// Term name.
        term: String,
        /// The unknown kind.
        kind: String,
        /// Registered kinds.
        known: String,
    },
    /// A kind was registered twice.
    #[error("term kind `{kind}` is already registered")]
    DuplicateKind {
        /// The kind.
        kind: String,
    },
    /// Two terms share a name (parameter names would be ambiguous).
    #[error("stage model: two terms are named `{name}`")]
    DuplicateTerm {
        /// The name.
        name: String,
    },
    /// A parameter vector of the wrong length.
    #[error("term `{term}` has {expected} parameters, got {got}")]
    ParamCount {
        /// Term name (or `model`).
        term: String,
        /// Expected count.
        expected: usize,
        /// Given count.
        got: usize,
    },
    /// A non-finite number where a finite one is required.
    #[error("{what} is not finite")]
    NonFinite {
        /// What it was.
        what: String,
    },
    /// No parameter has this full name (`term.param`).
    #[error("stage model has no parameter `{name}`")]
    UnknownParam {
        /// The name asked for.
        name: String,
    },
    /// Serialization failed.
    #[error("cannot write {what}: {message}")]
    Serialize {
        /// What was written.
        what: String,
        /// Serializer message.
        message: String,
    },
    /// The fit cannot start (no samples, nothing free, ...).
    #[error("fit: {reason}")]
    Fit {
        /// Why.
        reason: String,
    },
}
