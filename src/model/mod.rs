//! The parametric stage error model: where the platform of the XY leadscrew
//! stack really is, given what was commanded and how it got there.
//!
//! One model serves both sides of micropos: `hil-sim` runs it forward (through
//! [`StageSimulator`], which adds the stochastic part: settling noise, minimum
//! incremental motion, the temperature history), and the analysis fits it to
//! measurement logs ([`StageModel::fit`]) and extends it with new terms
//! ([`TermRegistry::register`]). Both build [`MotionState`]s with the same
//! [`MotionTracker`], so a model fitted on simulated data is the model the
//! simulator ran.
//!
//! # Frames and sign conventions
//!
//! Everything is in the *stage frame*, µm: x along the X stage, y along the Y
//! stage, origin at commanded (0, 0). The rigid transform between the pattern
//! or camera and the stage (mounting angle, offset) belongs to the simulated
//! camera and to the calibration, not to this model.
//!
//! ```text
//! true_um     = cmd_um + Σ contributions of Platform terms
//! observed_um = true_um + Σ contributions of Observation terms   (what the camera reports)
//! paper error e = target − measured = −Σ contributions            (when cmd = target)
//! ```
//!
//! # Terms
//! See [`terms`]: leadscrew cyclic error, cross-axis coupling, backlash (play),
//! squareness, lead error, angular error × Abbe arm, thermal expansion, optics
//! drift. The documented default, reproducing the magnitudes of Tan et al.
//! (cyclic errors of a few µm every 400 µm, ≈ 2 µm backlash, ≈ 22 µm
//! uncompensated accuracy on the square and random-point tests, ≤ 1 µm
//! repeatability over 9.5 h), is `config/stage-model.toml`, built in as
//! [`StageModel::paper_default`].

pub mod env;
pub mod error;
pub mod file;
pub mod fit;
pub mod sampling;
pub mod sim;
pub mod spec;
pub mod stage;
pub mod state;
pub mod term;
pub mod terms;
pub mod xy;

pub use env::{Environment, Interpolation, RoughSpot, Stochastic, TemperaturePoint};
pub use error::ModelError;
pub use file::{FORMAT_VERSION, PAPER_DEFAULT_TOML, PAPER_FAITHFUL_TOML};
pub use fit::{FitOptions, FitReport, FittedParam, Sample};
pub use sim::{SimStep, StageSimulator};
pub use stage::{ModelParam, StageModel};
pub use state::{
    Axis, AxisMotion, Direction, MotionState, MotionTracker, Waypoint, DEFAULT_TEMP_C,
    MAX_POSITION_UM, MAX_TEMP_C,
};
pub use term::{Effect, ParamInfo, Term, TermBuilder, TermRegistry, MAX_PARAM_MAGNITUDE};
pub use xy::XyUm;
