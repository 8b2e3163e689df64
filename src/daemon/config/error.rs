//! The configuration's error (which key, what is wrong): a leaf every
//! section imports.

/// A configuration problem: which key, what is wrong.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("config key {key}: {problem}")]
pub struct ConfigError {
    /// Dotted key, e.g. `characterize.step_um`.
    pub key: String,
    /// What is wrong and what would be right.
    pub problem: String,
}

/// A [`ConfigError`] for `key`.
pub(super) fn bad(key: &str, problem: impl Into<String>) -> ConfigError {
    ConfigError {
        key: key.to_owned(),
        problem: problem.into(),
    }
}
