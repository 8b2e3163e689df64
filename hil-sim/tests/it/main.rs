//! The integration tests of `hil-sim` as one test crate (`--test it`):
//! each module was a test binary of its own (`hil-sim/tests/<name>.rs`).
//! One crate compiles micropos's and hil-sim's generics at the test
//! profile's opt-level 3 and links once instead of 22 times. One module's
//! tests: `cargo test -p hil-sim --test it <module>::`.
//!
//! Tests of different modules run in parallel threads of one process, so
//! none may assume a process of its own: every simulator, daemon and web
//! listener gets its own temporary directory (ptys, Unix sockets, logs) and
//! port 0, no test sets an environment variable, changes directory or
//! installs a global subscriber or signal handler, and the simulator's
//! pty masters are close-on-exec (a process another test spawns must not
//! hold a line open that a test drops). The one fixed port, GigE Vision's
//! GVCP port 3956, is used by `genicam_gige` alone.

#![allow(
    clippy::too_many_lines,
    reason = "a test reads as one story: set-up, act, check"
)]

mod common;

mod camera_blur;
mod camera_scale;
mod charact_lost_motion;
mod comp_range;
mod daemon_access;
mod daemon_sim;
mod determinism;
mod driver_process;
mod driver_sim;
#[cfg(feature = "genicam")]
mod genicam_gige;
mod grid_charact;
mod hidden_rig;
mod job_retries;
mod live_drift;
mod model_replay;
mod motion_safety;
mod rig_camera;
mod rig_paper;
mod run_pipeline;
mod run_plots;
mod serve;
mod sweep_anchors;
mod sweep_charact;
mod tie_drift;
mod tool_move;
mod validate_origin;
mod web_browser;
mod web_metrics;
