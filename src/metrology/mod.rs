//! Metrology: the standard figures a lab reports for a stage, computed from
//! measured positions.
//!
//! * [`iso9283`]: pose accuracy AP and pose repeatability RP (ISO 9283, the
//!   figures of Tan et al., eqs. 1–3 and 6), per target pose and summarised
//!   over several poses.
//! * [`iso230_2`]: bidirectional positioning accuracy and repeatability of one
//!   numerically controlled axis (ISO 230-2:2014): A, R, B, E, M and their
//!   per-target constituents.
//!
//! Everything here is a pure function of numbers in micrometres: no I/O, no
//! clock, no state. Inputs are validated (non-finite values, too few
//! repetitions, inconsistent targets) and rejected with an error that says
//! what is wrong, because a figure computed from bad input is worse than no
//! figure for a lab that certifies a stage with it.

pub mod iso230_2;
pub mod iso9283;

pub use iso230_2::{
    evaluate as evaluate_iso230_2, Approach, AxisFigures, Iso230Error, Observation, TargetFigures,
};
pub use iso9283::{pose_stats, summarize_poses, Iso9283Error, PoseStats, PoseSummary, Xy};
