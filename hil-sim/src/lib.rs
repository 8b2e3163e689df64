//! hil-sim: hardware-in-the-loop simulator for micropos.
//!
//! Simulated PI Mercury C-863.11 controllers (GCS 2.0, built on the
//! protocol core in [`micropos::gcs`]) driving simulated M-111.1DG stages,
//! served on real pseudo-terminals with fault injection, so the driver and
//! PI's own Python client can be tested without hardware.
//!
//! Layers, from the inside out:
//! - [`motion`]: trapezoidal profiles evaluated lazily in time;
//! - [`controller`]: one C-863 as a sans-IO state machine (requests + time
//!   in, answer bytes out), with the [`controller::Platform`] seam for the
//!   stage error model;
//! - [`bus`]: controllers sharing one line (daisy chain);
//! - [`clock`]: scaled wall time, manual time, or the runtime's (virtual)
//!   clock;
//! - [`fault`]: axis names, faults, errors (shared by the servers);
//! - [`serve`]: ptys, threads, faults; [`vline`]: the same lines served in
//!   process on a tokio runtime; [`control`]: the JSON control socket.

// No unsafe code, except the aravis fill callback of the GigE Vision camera
// (feature `genicam`, `camera::gige::ffi`, which allows it for itself).
#![cfg_attr(not(feature = "genicam"), forbid(unsafe_code))]
#![cfg_attr(feature = "genicam", deny(unsafe_code))]
#![warn(missing_docs)]
// Unit tests read as one story (set-up, act, check), however long.
#![cfg_attr(test, allow(clippy::too_many_lines))]

pub mod bus;
pub mod camera;
pub mod clock;
pub mod control;
pub mod controller;
pub mod experiment;
pub mod fault;
pub mod linesock;
pub mod motion;
pub mod params;
pub mod rig;
pub mod run;
pub mod serve;
pub mod vline;

pub use fault::{AxisName, Corruption, Fault, SimError};
pub use serve::{ServeConfig, SimHandle};
