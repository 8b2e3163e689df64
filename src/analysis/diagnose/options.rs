//! The options of a diagnosis ([`DiagnoseOptions`]) and their defaults.
//!
//! Why a file of its own: the greedy loop ([`super::diagnose`]) and the
//! table tests ([`super::tables`]) both read them; a leaf keeps the steps
//! from importing the file that drives them.

use serde::{Deserialize, Serialize};

use super::search::ALL_KINDS;

/// How to diagnose.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DiagnoseOptions {
    /// A candidate is significant when its held-out reduction of squared
    /// error is at least this many standard errors above zero.
    pub z_threshold: f64,
    /// ... and the held-out RMS of its component drops by at least this, %.
    pub min_gain_pct: f64,
    /// At most this many findings.
    pub max_findings: usize,
    /// At most this many folds (whole cycles) for held-out judging.
    pub max_folds: usize,
    /// Kinds of model terms whose parameters the base fit identifies from
    /// the log ([`ALL_KINDS`], `"*"`: every kind). Linear terms and
    /// backlash qualify; other nonlinear parameters stay at the model's
    /// values.
    pub base_free_kinds: Vec<String>,
}

impl Default for DiagnoseOptions {
    fn default() -> Self {
        DiagnoseOptions {
            z_threshold: 5.0,
            min_gain_pct: 1.0,
            max_findings: 4,
            max_folds: 4,
            base_free_kinds: vec![ALL_KINDS.into()],
        }
    }
}
