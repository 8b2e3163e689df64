//! micropos: makes XY micropositioning stages accurate.
//!
//! The library holds everything that is not process plumbing: the GCS 2.0
//! protocol core (sans-IO), the async C-863 driver, the Megarena pattern
//! (layout, rendering, decoding), camera sources, the stage error model,
//! compensation, metrology (ISO 9283, ISO 230-2), discrepancy diagnosis and
//! the daemon's runtime. The binaries `microposd` and `micropos` and the simulator
//! `hil-sim` are thin shells around it. See `ARCHITECTURE.md`.

#![forbid(unsafe_code)]
#![warn(missing_docs)]

pub mod analysis;
pub mod camera;
pub mod charact;
pub mod clock;
pub mod comp;
pub mod daemon;
pub mod driver;
pub mod frame;
pub mod gcs;
pub mod imageio;
pub mod metrology;
pub mod model;
pub mod pattern;
pub mod plot;
