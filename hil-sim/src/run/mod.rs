//! `hil-sim run`: the README's main job. The whole micropos pipeline on the
//! simulated rig, through the daemon, as a user runs it:
//!
//! 1. the simulated rig is served as `hil-sim serve` serves it (controllers
//!    on ptys, camera socket, control socket with the simulated clock);
//! 2. microposd is started in-process on a real Unix socket, configured for
//!    that rig (as `config/microposd-sim.toml`: clock `sim:`, camera `sim:`);
//! 3. from then on this module is only a socket client: reference, the
//!    paper's characterization, a characterization ten times shorter (for
//!    the model table), `tables build` (paper tables from the first, model
//!    table from the second), `validate` (square and Table II in the modes
//!    raw, table, model, closed_loop), and it reports AP and RP per
//!    trajectory and mode next to the paper's figures;
//! 4. drift: the characterizations re-measure a reference point
//!    every `drift_every_s` (tables are built drift-corrected, with their
//!    baseline), the validation runs with live drift correction
//!    (`drift set`), and `table` mode is validated again with live drift
//!    off, static and adaptive to report what each gains.
//!
//! Time: by default the rig runs in process on a virtual clock (see
//! [`run`]): every move, settle, exposure, poll period and timeout takes its
//! simulated time and no wall time, so a paper-size run (≈ 17 500 points,
//! ≈ 9 simulated hours) costs only the CPU of rendering and decoding its
//! frames, and one seed gives byte-identical JSON. `time_scale` serves the
//! rig on ptys in real time instead (not reproducible).
//!
//! The files: this one sets up the rig and the daemon and runs the job;
//! `pipeline` holds its phases, `client` the socket client they talk
//! through, `report` the table and figures made of the summary.

use crate::camera::SimCameraSource;
use crate::rig::RigConfig;
use crate::serve::{AxisName, ServeConfig, SimHandle};
use micropos::camera::{open_source, OpenOptions};
use micropos::clock::{SimClock, WallClock};
use micropos::daemon::config::DaemonConfig;
use micropos::daemon::vision::Capture;
use micropos::daemon::{Daemon, Environment, Running};
use pipeline::pipeline;
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};

mod client;
mod pipeline;
mod report;

pub use pipeline::DRIFT_METHODS;
pub use report::{format_table, plot_run, table_offset};

/// Why the main job failed.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    /// Setting up the rig, the daemon or the directories failed.
    #[error("setup: {0}")]
    Setup(String),
    /// The daemon refused or failed a command.
    #[error("microposd refused {cmd}: {code}: {message}")]
    Refused {
        /// The command.
        cmd: String,
        /// Its stable error code.
        code: String,
        /// The daemon's message.
        message: String,
    },
    /// A job ended other than `done`.
    #[error("{kind} job ended {state}: {error}")]
    Job {
        /// `characterize` or `validate`.
        kind: String,
        /// Its final state.
        state: String,
        /// Why.
        error: String,
    },
    /// The socket connection failed.
    #[error("socket: {0}")]
    Io(#[from] std::io::Error),
}

/// The experiment plan: the paper's (default) or a reduced one.
#[derive(Debug, Clone, PartialEq)]
pub struct RunPlan {
    /// Characterization step, µm (paper 5).
    pub step_um: f64,
    /// X scan range, µm (paper 9500).
    pub x_range_um: f64,
    /// Y scan range, µm (paper 4200).
    pub y_range_um: f64,
    /// Characterization cycles (paper 3).
    pub cycles: u32,
    /// Step of the short characterization for the model table, µm
    /// (ten times the paper's).
    pub short_step_um: f64,
    /// Moves of varied length per cycle of the short characterization
    /// (`characterize … moves_per_cycle`): they make a lost motion that
    /// grows with the move length identifiable for the model table (the
    /// paper-faithful stage's: without them its model table cannot learn
    /// it). 40 in the paper plan, 0 in the reduced one. On a stage without
    /// such lost motion they cost a little: the moves' positions show its
    /// non-separable errors, which the model table's template cannot hold
    /// (docs/design/daemon.md#main-job).
    pub short_moves_per_cycle: u32,
    /// Validation cycles per test and mode.
    pub validate_cycles: u32,
    /// Distance between square poses, µm.
    pub square_step_um: f64,
    /// Frames averaged per point.
    pub frames_per_point: u32,
    /// Settle time after each move of the short characterization, the
    /// validations and the sweep row, s: this project's own timing.
    pub settle_s: f64,
    /// Settle time per point of the paper characterization, s. The paper
    /// spends 9.5 h on 16 446 points, 2.08 s per point; 2.0 s of settle plus
    /// the 5 µm move and the exposure reproduces that, and with it the
    /// thermal drift its lookup tables carry (docs/design/paper-faithful.md).
    pub paper_settle_s: f64,
    /// Stage position of the paper's validation (0, 0), µm, both axes. The
    /// scans start at 0 (the travel's end); the stage frame's origin is the
    /// tie's mean, so near the scan start a compensated command can fall
    /// below 0 (measured: ≈ 12 µm of squareness-driven x error at y = 0).
    /// 100 µm keeps every compensated command inside the travel and every
    /// target inside the characterized area (random up to 8296 × 4091 µm).
    pub validate_origin_um: f64,
    /// Reference re-measurements during both characterizations, every this
    /// many s of rig time (0 = off): `tables build` then corrects the logs
    /// to the rig's state at their start and records that baseline with
    /// the tables.
    pub drift_every_s: f64,
    /// The drift reference point, `[x, y]` µm. Not the scans' start corner
    /// (0, 0): the reference is approached from 20 µm below on both axes,
    /// outside the travel there.
    pub drift_reference_um: [f64; 2],
    /// Live drift correction of the validation's `table` and `model` modes
    /// (`drift set method`): `off`, `static` or `adaptive`.
    pub live_drift: String,
    /// Interval of the live re-measurements, s of rig time.
    pub live_drift_every_s: f64,
    /// After the validation, validate `table` mode again with live drift
    /// off, static and adaptive (the `drift` block of the summary).
    pub drift_compare: bool,
    /// The sweep row (`sweep` block): a sweep characterization of the same
    /// ranges and cycles at this velocity (odd cycles; even at twice it),
    /// its tables validated in `table` mode with live drift off, with and
    /// without the camera delay correction. At least 2 cycles (two
    /// velocities). 0 = no sweep row.
    pub sweep_velocity_um_per_s: f64,
    /// Spacing of the sweep's static anchors, µm (`characterize …
    /// anchor_spacing_um`; 0 = none): the sweep's records are corrected to
    /// the step plan's motion state by them, and the row validates the
    /// tables without that correction too.
    pub sweep_anchor_spacing_um: f64,
    /// The grid row (`grid` block): a grid characterization of the same
    /// ranges at this node pitch (one cycle, every node from below), its
    /// 2-D map (`tables build` kind grid) validated in `table` mode with
    /// live drift off (compare with the drift comparison's `off` row of the
    /// step tables). 0 = no grid row.
    pub grid_pitch_um: f64,
}

impl RunPlan {
    /// The paper's plan: 5 µm steps over 9500 × 4200 µm, 3 cycles; the
    /// short characterization at 50 µm; validation 3 cycles, square poses
    /// every 500 µm.
    pub fn paper() -> Self {
        RunPlan {
            step_um: 5.0,
            x_range_um: 9500.0,
            y_range_um: 4200.0,
            cycles: 3,
            short_step_um: 50.0,
            short_moves_per_cycle: 40,
            validate_cycles: 3,
            square_step_um: 500.0,
            frames_per_point: 1,
            settle_s: 0.3,
            paper_settle_s: 2.0,
            validate_origin_um: 100.0,
            drift_every_s: 600.0,
            drift_reference_um: [100.0, 100.0],
            live_drift: "adaptive".to_owned(),
            live_drift_every_s: 120.0,
            drift_compare: true,
            sweep_velocity_um_per_s: 120.0,
            sweep_anchor_spacing_um: micropos::charact::sweep::anchor::DEFAULT_ANCHOR_SPACING_UM,
            grid_pitch_um: 100.0,
        }
    }

    /// A reduced plan for tests and a quick look (`--short`): 50 µm steps
    /// (500 µm for the short characterization), one cycle, square poses
    /// every 1000 µm, two validation cycles (RP needs two visits), every
    /// characterization at 0.3 s settle.
    pub fn reduced() -> Self {
        RunPlan {
            step_um: 50.0,
            cycles: 1,
            short_step_um: 500.0,
            short_moves_per_cycle: 0,
            validate_cycles: 2,
            square_step_um: 1000.0,
            sweep_velocity_um_per_s: 0.0,
            paper_settle_s: 0.3,
            grid_pitch_um: 1000.0,
            ..Self::paper()
        }
    }
}

/// How to run.
#[derive(Debug, Clone)]
pub struct RunOptions {
    /// Seed of the simulation.
    pub seed: u64,
    /// The rig.
    pub rig: RigConfig,
    /// Stage model file overriding the rig's.
    pub model: Option<PathBuf>,
    /// Stage model overriding the rig's and `model` (the main job's
    /// compiled-in paper-faithful stage).
    pub stage_model: Option<micropos::model::StageModel>,
    /// Where the rig sockets, the daemon's data (logs, tables) and
    /// `run.json` go; `None`: a temporary directory, removed afterwards.
    pub out_dir: Option<PathBuf>,
    /// `None` (the default): the rig runs in process on a virtual clock
    /// (tokio's paused clock): simulated time advances only by the rig's
    /// own events, so the same seed gives byte-identical results.
    /// `Some(k)`: the rig is served on ptys with its camera and control
    /// sockets, its clock running `k` simulated seconds per wall second
    /// besides the daemon's explicit advances (real-time mode: results
    /// depend on the machine's load).
    pub time_scale: Option<f64>,
    /// The plan.
    pub plan: RunPlan,
}

impl Default for RunOptions {
    fn default() -> Self {
        RunOptions {
            seed: 1,
            rig: RigConfig::default(),
            model: None,
            stage_model: None,
            out_dir: None,
            time_scale: None,
            plan: RunPlan::paper(),
        }
    }
}

/// What the run produced.
#[derive(Debug, Clone)]
pub struct RunReport {
    /// The one JSON object of `--json` (see the README).
    pub summary: Value,
    /// Full validation results (per pose) as the daemon reported them.
    pub validation: Value,
    /// The daemon's data directory (logs and tables), if kept.
    pub data_dir: Option<PathBuf>,
    /// Log and table file names in `data_dir`.
    pub files: Vec<String>,
    /// Wall time, s.
    pub wall_s: f64,
    /// Wall time per phase of `summary.phases_s`, s, in the same order.
    /// Not in `summary`: wall time depends on the machine and its load, the
    /// summary only on the seed.
    pub phases_wall_s: Vec<(String, f64)>,
}

/// The daemon's configuration for the rig served in `rig_dir`.
pub fn daemon_config(
    rig_dir: &Path,
    data_dir: &Path,
    socket: &Path,
    rig: &RigConfig,
    plan: &RunPlan,
) -> Result<DaemonConfig, RunError> {
    let mut c = DaemonConfig::default();
    c.daemon.socket = socket.to_owned();
    c.daemon.data_dir = data_dir.to_owned();
    c.daemon.poll_interval_ms = 200;
    c.rig.clock = format!("sim:{}", rig_dir.join("control.sock").display());
    c.driver.x.port = rig_dir.join("x");
    c.driver.y.port = rig_dir.join("y");
    for a in [&mut c.driver.x, &mut c.driver.y] {
        // Generous: the rig shares the machine with the daemon and the
        // decoder (and, in CI, with builds); a late answer is a fault.
        a.timeout_ms = 3000;
        a.poll_interval_ms = 1;
        a.reference_timeout_s = 120.0;
        a.motion_timeout_s = 120.0;
    }
    c.driver.reconnect_min_ms = 20;
    c.driver.reconnect_max_ms = 500;
    // On the virtual clock an idle limit counts simulated seconds: a client
    // that waits out a simulated hour of a job would be closed for it.
    c.daemon.idle_timeout_s = 0.0;
    // No power cut can hit a simulated rig: a sync per record would cost
    // more wall time than the point (a process crash loses nothing either
    // way: every record reaches the OS at once).
    c.daemon.log_sync_every = 0;
    c.camera.source = format!("sim:{}", rig_dir.join("camera.sock").display());
    c.camera.period_um = rig.camera.period_um;
    c.camera.bits = rig.camera.bits;
    c.camera.pixel_um = Some(rig.camera.pixel_um);
    c.camera.timeout_ms = 5000;
    // Every job of the main job ties vision itself before it logs (the
    // characterization's pre-scan tie, the paper's procedure); a tie after
    // the reference would only add moves and simulated time before them
    // (and new random draws under every figure the run prints).
    c.camera.tie_after_reference = false;
    // The paper's frame: scans from (0, 0), where the pattern is in view
    // (config/sim-rig.toml keeps stage x, y in about [−80, 11890] µm on it).
    c.characterize.x_start_um = Some(0.0);
    c.characterize.y_start_um = Some(0.0);
    c.characterize.x_range_um = plan.x_range_um;
    c.characterize.y_range_um = plan.y_range_um;
    c.characterize.step_um = plan.step_um;
    c.characterize.cycles = plan.cycles;
    c.characterize.frames_per_point = plan.frames_per_point;
    c.characterize.settle_s = plan.settle_s;
    c.validate()
        .map_err(|e| RunError::Setup(format!("daemon config: {e}")))?;
    Ok(c)
}

struct Started {
    sim: SimHandle,
    daemon: Running,
    socket: PathBuf,
    data_dir: PathBuf,
}

async fn start(opts: &RunOptions, dir: &Path) -> Result<Started, RunError> {
    let setup = |what: &str, e: &dyn std::fmt::Display| RunError::Setup(format!("{what}: {e}"));
    let rig_dir = dir.join("rig");
    let data_dir = dir.join("data");
    for d in [&rig_dir, &data_dir] {
        std::fs::create_dir_all(d).map_err(|e| setup(&d.display().to_string(), &e))?;
    }
    let served = opts.time_scale.is_some();
    let cfg = ServeConfig {
        link_dir: rig_dir.clone(),
        time_scale: opts.time_scale.unwrap_or(1.0),
        control_socket: served.then(|| rig_dir.join("control.sock")),
        camera_socket: served.then(|| rig_dir.join("camera.sock")),
        seed: opts.seed,
        rig: opts.rig.clone(),
        model: opts.model.clone(),
        stage_model: opts.stage_model.clone(),
        ..ServeConfig::default()
    };
    let sim = if served {
        tokio::task::spawn_blocking(move || SimHandle::start(cfg))
            .await
            .map_err(|e| setup("simulator start task", &e))?
            .map_err(|e| setup("simulator", &e))?
    } else {
        SimHandle::start_in_process(cfg).map_err(|e| setup("simulator", &e))?
    };
    debug_assert_eq!(sim.link(AxisName::X), rig_dir.join("x"));
    let socket = dir.join("micropos.sock");
    let c = daemon_config(&rig_dir, &data_dir, &socket, &opts.rig, &opts.plan)?;
    let env = if served {
        let control = rig_dir.join("control.sock");
        let clock = tokio::task::spawn_blocking(move || SimClock::connect(&control))
            .await
            .map_err(|e| setup("clock task", &e))?
            .map_err(|e| setup("sim clock", &e))?;
        let spec = c
            .camera_source()
            .map_err(|e| setup("camera.source", &e))?
            .ok_or_else(|| RunError::Setup("no camera source".into()))?;
        let oo = OpenOptions {
            timeout: Duration::from_millis(c.camera.timeout_ms),
            ..OpenOptions::default()
        };
        let camera = tokio::task::spawn_blocking(move || open_source(&spec, &oo))
            .await
            .map_err(|e| setup("camera task", &e))?
            .map_err(|e| setup("camera", &e))?;
        Environment::hardware(Arc::new(clock), Some(camera))
    } else {
        in_process_environment(&sim)
    };
    let _ = std::fs::remove_file(&socket);
    let listener = tokio::net::UnixListener::bind(&socket).map_err(|e| setup("socket", &e))?;
    let daemon = Daemon::start_in(c, env, listener).map_err(|e| setup("daemon", &e))?;
    Ok(Started {
        sim,
        daemon,
        socket,
        data_dir,
    })
}

/// The daemon's environment on an in-process rig
/// ([`SimHandle::start_in_process`]): everything on the current runtime's
/// clock (the daemon's timers and timestamps, the controllers' motion, the
/// camera's exposures), the rig's camera grabbed on demand, its lines
/// opened in process. Call it inside the runtime the rig was started on.
pub fn in_process_environment(sim: &SimHandle) -> Environment {
    Environment {
        // The rig's clock reads the simulator's time: the camera's frame
        // stamps are then rig times (`FrameSource::frame_clock`).
        clock: Arc::new(WallClock::since(
            tokio::time::Instant::now()
                .checked_sub(sim.sim_time())
                .unwrap_or_else(tokio::time::Instant::now),
        )),
        camera: Some(Box::new(SimCameraSource::new(sim.camera().clone()))),
        capture: Capture::OnDemand,
        links: sim.link_opener(),
    }
}

/// How often a failed characterization is resumed before the run gives up.
pub const MAX_RESUMES: u32 = 3;

/// The paper's figures next to which results are printed (AP, µm).
pub fn paper_ap_um(test: &str, mode: &str) -> Option<f64> {
    match (test, mode) {
        (_, "raw") => Some(22.0),
        ("square", "table") => Some(3.5),
        ("random", "table") => Some(7.0),
        _ => None,
    }
}

/// Runs the main job on a runtime of its own, and returns when it is over.
/// `progress` receives one line per step (stderr in the binary).
///
/// With `opts.time_scale` `None` the runtime is a *paused* current-thread
/// runtime (tokio's virtual clock with auto-advance): the rig, the daemon
/// and this client are tasks on it, decoding and file I/O run on its
/// blocking pool (which holds the clock still), and simulated time jumps
/// from one timer to the next only when every task waits. Nothing that
/// happens on the machine moves it, so a seed gives one result. Must not be
/// called from inside a tokio runtime.
pub fn run(opts: RunOptions, progress: &mut dyn FnMut(&str)) -> Result<RunReport, RunError> {
    let rt = if opts.time_scale.is_some() {
        tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .enable_all()
            .build()
    } else {
        virtual_runtime()
    }
    .map_err(|e| RunError::Setup(format!("tokio runtime: {e}")))?;
    rt.block_on(run_on_this_runtime(opts, progress))
}

/// The runtime of the in-process rig: current-thread with its clock paused,
/// so simulated time jumps from timer to timer only when every task waits
/// (see [`run`]). `hil-sim run` and `hil-sim demo` run on one.
pub fn virtual_runtime() -> std::io::Result<tokio::runtime::Runtime> {
    tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .start_paused(true)
        .build()
}

/// [`run`] on the caller's runtime (see there for the clock).
pub async fn run_on_this_runtime(
    opts: RunOptions,
    progress: &mut dyn FnMut(&str),
) -> Result<RunReport, RunError> {
    let wall = Instant::now();
    let (dir, keep) = match &opts.out_dir {
        Some(d) => (d.clone(), true),
        None => (
            std::env::temp_dir().join(format!("hil-sim-run-{}", std::process::id())),
            false,
        ),
    };
    std::fs::create_dir_all(&dir)
        .map_err(|e| RunError::Setup(format!("{}: {e}", dir.display())))?;
    progress(&format!(
        "starting the simulated rig (seed {}) and microposd in {}",
        opts.seed,
        dir.display()
    ));
    let st = start(&opts, &dir).await?;
    let r = pipeline(&opts, &st, progress).await;
    st.daemon.shutdown().await;
    let sim = st.sim;
    let _ = tokio::task::spawn_blocking(move || sim.shutdown()).await;
    let (summary, validation, files, phases_wall_s) = r?;
    if !keep {
        let _ = std::fs::remove_dir_all(&dir);
    }
    Ok(RunReport {
        summary,
        validation,
        data_dir: keep.then_some(st.data_dir),
        files,
        wall_s: wall.elapsed().as_secs_f64(),
        phases_wall_s,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn plans_and_paper_figures() {
        let p = RunPlan::paper();
        assert_eq!(
            (p.step_um, p.x_range_um, p.y_range_um, p.cycles),
            (5.0, 9500.0, 4200.0, 3)
        );
        assert_eq!(p.short_step_um, 10.0 * p.step_um);
        assert_eq!(paper_ap_um("square", "table"), Some(3.5));
        assert_eq!(paper_ap_um("random", "table"), Some(7.0));
        assert_eq!(paper_ap_um("random", "raw"), Some(22.0));
        let t = format_table(&json!({}));
        assert!(t.contains("closed_loop"));
    }
}
