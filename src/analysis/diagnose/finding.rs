//! A named discrepancy ([`Finding`]): the record a diagnosis reports for
//! each accepted candidate.
//!
//! Why a file of its own: the description step ([`super::describe`]) fills
//! it and the table readings ([`super::tables`]) attach terms to it; a leaf
//! keeps the steps from importing the file that drives them.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::analysis::FindingKind;
use crate::model::Axis;

/// One named discrepancy.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Finding {
    /// What kind of effect.
    pub kind: FindingKind,
    /// The variable axis (`x`/`y`); for time and temperature kinds, the
    /// component.
    pub axis: Axis,
    /// The error component it affects.
    pub component: Axis,
    /// Parameters (names carry their unit), model sign.
    pub params: BTreeMap<String, f64>,
    /// 1-σ uncertainty of each parameter (same keys, where known).
    pub uncertainty: BTreeMap<String, f64>,
    /// Shape of a drift (`linear`/`quadratic`); absent otherwise.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub shape: Option<String>,
    /// Held-out z-score: paired mean reduction of squared error over its
    /// standard error.
    pub significance: f64,
    /// Held-out RMS of the component before adding this term, µm.
    pub heldout_rms_before_um: f64,
    /// ... and after, µm.
    pub heldout_rms_after_um: f64,
    /// `100·(1 − after/before)`, %.
    pub gain_pct: f64,
    /// A sentence a person understands.
    pub explanation: String,
    /// Likely physical cause.
    pub cause: String,
    /// Name of the term that models it in the extended model (empty when
    /// the model cannot express it: kind `other`).
    pub term: String,
    /// The log column the error follows (kind `other`); absent otherwise.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub variable: Option<String>,
    /// Whether the extended model includes the effect (false for `other`:
    /// the model has no input for a log's extra column).
    #[serde(default = "yes")]
    pub in_extended_model: bool,
}

fn yes() -> bool {
    true
}

/// A finding that passed the held-out test but states a number the log
/// does not determine (a place outside the measured travel, a standard
/// error missing, not finite or wider than the travel or the log's error),
/// and why. It is not a finding: the report lists it apart, credits it with
/// no gain, and the extended model does not include it.
///
/// Why kept at all: a reader who sees structure in the residual plots (or
/// an `UNEXPLAINED` line) learns that a term was tried there and why it
/// was not reported, instead of nothing.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Withdrawn {
    /// The finding as it was described before it was withdrawn (its
    /// held-out figures are those it was accepted on; `term` is empty and
    /// `in_extended_model` false: the extended model was refitted without
    /// it).
    pub finding: Finding,
    /// Why the log does not determine it (the offending parameter and
    /// number).
    pub reason: String,
}
