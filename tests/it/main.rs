//! The integration tests of `micropos` as one test crate (`--test it`):
//! each module was a test binary of its own (`tests/<name>.rs`). One crate
//! compiles the library's generics at the test profile's opt-level 3 and
//! links once instead of 39 times. One module's tests:
//! `cargo test -p micropos --test it <module>::`.
//!
//! Tests of different modules run in parallel threads of one process, so
//! none may assume a process of its own: ports are bound as port 0, files
//! and sockets live in temporary directories, no test sets an environment
//! variable, changes directory, installs a global subscriber or a signal
//! handler, or counts the process's threads, allocations or CPU time.
//! What is process-wide is locked: [`ARAVIS`].
//!
//! Kept apart, a binary of its own: `tests/decode_alloc.rs` (a counting
//! `#[global_allocator]`: it counts every allocation of its process, so it
//! must be alone in it).

#![allow(
    clippy::too_many_lines,
    reason = "a test reads as one story: set-up, act, check"
)]

/// aravis's interfaces (GigE Vision, USB3 Vision, Fake) are process-wide
/// singletons, not safe to update from two threads: the tests that reach
/// them in this process (`camera_genicam` opening its fake camera,
/// `camera_v4l2` listing every backend's cameras) hold this lock.
#[cfg(feature = "genicam")]
pub static ARAVIS: std::sync::Mutex<()> = std::sync::Mutex::new(());

mod bins;
mod camera_cli;
mod camera_files;
#[cfg(feature = "genicam")]
mod camera_genicam;
#[cfg(feature = "v4l2")]
mod camera_v4l2;
mod cli_pipe;
mod cli_wait;
mod closed_loop_paper;
mod comp_file;
mod comp_frame;
mod comp_grid;
mod comp_paper;
mod daemon_check_config;
mod daemon_process;
mod daemon_socket;
mod daemon_systemd;
mod daemon_web_config;
mod decode_code_check;
mod decode_real;
mod decode_render;
mod decode_robust;
mod diagnose_drift;
mod diagnose_hidden;
mod diagnose_lead;
mod diagnose_loop;
mod diagnose_random;
mod diagnose_real;
mod diagnose_real_extra;
mod diagnose_real_grid;
mod diagnose_rig_logs;
mod diagnose_robust_logs;
mod diagnose_sane;
mod diagnose_tables;
mod drift_correction_gain;
mod driver_cli;
mod grid_random_model;
mod grid_zones;
mod import_cli;
mod import_props;
mod log_colour;
mod log_format;
mod log_props;
mod log_resume;
mod metrology_iso230_2;
mod metrology_props;
mod model_fit;
mod model_paper;
mod model_props;
mod model_toml;
mod paper_statements;
mod pattern_export;
mod simlog_cli;
