//! What the simulation gets wrong: fitting the stage model to a measurement
//! log, searching the residuals for structure, naming it, and extending the
//! model with it.
//!
//! * [`diagnose`]: the discrepancy analysis behind `micropos diagnose`
//!   ([`diagnose::diagnose`]): base fit, residual search against every
//!   variable of the log, held-out judging, findings, extended model.
//! * [`periodogram`]: generalized Lomb–Scargle periodogram of unevenly
//!   sampled data (positions and times of a log are not a regular grid).
//! * [`generate`]: synthetic characterization logs with one hidden effect,
//!   the analysis's test bench (`micropos simlog`).
//! * [`physical`]: the same logs from a stage built from its physical
//!   description (screw, nut with play, guideway angles, squareness), in
//!   code apart from the model, so a test does not share its assumptions.
//! * [`comp_gain`]: closing the loop: compensation from the extended model
//!   against compensation from the original one, ISO 9283 AP on a simulated
//!   stage that has the effect.
//! * [`paper`]: the paper's measurements as data: the paper's procedure run
//!   on a model, every quantitative statement measured against it.
//! * [`drift`]: drift estimation from re-measurements of a reference point
//!   (static vs adaptive), for long runs.
//!
//! Sign convention of every reported value: the model's (a contribution is
//! added to the commanded position: positive = the platform is further in
//! + than commanded). The paper's error `target − measured` is its negative.

use serde::{Deserialize, Serialize};
use thiserror::Error;

pub mod comp_gain;
pub mod diagnose;
pub mod drift;
pub mod generate;
pub mod grid;
pub mod paper;
pub mod periodogram;
pub mod physical;

pub use diagnose::{
    diagnose, DiagnoseOptions, Diagnosis, Finding, LeadCheck, LeadTest, LeadVerdict, Reading,
    ReadingKind, ReadingTerm,
};

/// Why an analysis could not run.
#[derive(Debug, Error)]
pub enum AnalysisError {
    /// The model refused something (bad state, bad parameter).
    #[error(transparent)]
    Model(#[from] crate::model::ModelError),
    /// Compensation refused something (plan, inverse).
    #[error(transparent)]
    Comp(#[from] crate::comp::CompError),
    /// The log could not be read or written.
    #[error(transparent)]
    Log(#[from] crate::charact::log::LogError),
    /// The input cannot support the analysis (too few points, ...).
    #[error("{0}")]
    Invalid(String),
}

/// The kinds of discrepancy the analysis names (the `kind` of a finding).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FindingKind {
    /// Periodic in an axis position at a period the model lacks.
    PositionPeriodic,
    /// Error proportional to the position along the same axis.
    Scale,
    /// Localized feature (bump) along an axis.
    Localized,
    /// Drift with time.
    TimeDrift,
    /// Periodic in time.
    TimePeriodic,
    /// Lost motion on reversal beyond the model's play.
    Reversal,
    /// Dependence on the length of the preceding move (`step_size`).
    StepSize,
    /// Dependence on the other axis's position.
    CrossAxis,
    /// Proportional to temperature.
    Temperature,
    /// Lost motion that changes along the travel (a reversal table).
    ReversalVaries,
    /// Departure of the mean deviation from a straight line between
    /// targets (a non-linearity table).
    Nonlinearity,
    /// Anything else (named by its variable).
    Other,
}

impl FindingKind {
    /// The JSON / command-line name.
    pub const fn as_str(self) -> &'static str {
        match self {
            FindingKind::PositionPeriodic => "position_periodic",
            FindingKind::Scale => "scale",
            FindingKind::Localized => "localized",
            FindingKind::TimeDrift => "time_drift",
            FindingKind::TimePeriodic => "time_periodic",
            FindingKind::Reversal => "reversal",
            FindingKind::StepSize => "step_size",
            FindingKind::CrossAxis => "cross_axis",
            FindingKind::Temperature => "temperature",
            FindingKind::ReversalVaries => "reversal_varies",
            FindingKind::Nonlinearity => "nonlinearity",
            FindingKind::Other => "other",
        }
    }

    /// Parses the name written by [`FindingKind::as_str`].
    pub fn parse(s: &str) -> Option<Self> {
        [
            FindingKind::PositionPeriodic,
            FindingKind::Scale,
            FindingKind::Localized,
            FindingKind::TimeDrift,
            FindingKind::TimePeriodic,
            FindingKind::Reversal,
            FindingKind::StepSize,
            FindingKind::CrossAxis,
            FindingKind::Temperature,
            FindingKind::ReversalVaries,
            FindingKind::Nonlinearity,
            FindingKind::Other,
        ]
        .into_iter()
        .find(|k| k.as_str() == s)
    }
}

impl std::fmt::Display for FindingKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}
