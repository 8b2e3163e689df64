//! The configuration's error (which key, what is wrong, where in the
//! file): a leaf every section imports.

use std::path::PathBuf;

/// A configuration problem: which key, what is wrong, and where.
///
/// Shown as `FILE:LINE:COLUMN: config key [camera].pixl_um: PROBLEM` (the
/// parts known): the place an editor jumps to, and the key as the file
/// writes it, section and name.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub struct ConfigError {
    /// Dotted key, e.g. `characterize.step_um`; `(file)` and `(syntax)`
    /// for a file that cannot be read or parsed at all.
    pub key: String,
    /// What is wrong and what would be right.
    pub problem: String,
    /// 1-based line and column (characters) in the file, when known.
    pub line_column: Option<(usize, usize)>,
    /// The file, when the error came from reading one.
    pub file: Option<PathBuf>,
}

impl std::fmt::Display for ConfigError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match (&self.file, self.line_column) {
            (Some(p), Some((l, c))) => write!(f, "{}:{l}:{c}: ", p.display())?,
            (Some(p), None) => write!(f, "{}: ", p.display())?,
            (None, Some((l, c))) => write!(f, "line {l}, column {c}: ")?,
            (None, None) => {}
        }
        if self.key.starts_with('(') {
            write!(f, "{}", self.problem)
        } else {
            write!(f, "config key {}: {}", written_key(&self.key), self.problem)
        }
    }
}

/// A dotted key as the file writes it: `[section].key` (`[driver.x].port`,
/// `[web].token_file`); a key without a section is its section, `[key]`.
pub fn written_key(key: &str) -> String {
    match key.rsplit_once('.') {
        Some((section, name)) => format!("[{section}].{name}"),
        None => format!("[{key}]"),
    }
}

/// A [`ConfigError`] for `key`.
pub(super) fn bad(key: &str, problem: impl Into<String>) -> ConfigError {
    ConfigError {
        key: key.to_owned(),
        problem: problem.into(),
        line_column: None,
        file: None,
    }
}
