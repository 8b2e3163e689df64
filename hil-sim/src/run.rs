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

use crate::camera::SimCameraSource;
use crate::rig::RigConfig;
use crate::serve::{AxisName, ServeConfig, SimHandle};
use micropos::camera::{open_source, OpenOptions};
use micropos::clock::{SimClock, WallClock};
use micropos::daemon::config::DaemonConfig;
use micropos::daemon::protocol::JobState;
use micropos::daemon::vision::Capture;
use micropos::daemon::{Daemon, Environment, Running};
use serde_json::{json, Value};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio::io::{AsyncBufReadExt, AsyncWriteExt, BufReader};
use tokio::net::UnixStream;

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
            sweep_anchor_spacing_um:
                micropos::charact::sweep::anchor::DEFAULT_ANCHOR_SPACING_UM,
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

/// A JSON-lines client of the daemon's socket.
struct Client {
    r: BufReader<tokio::net::unix::OwnedReadHalf>,
    w: tokio::net::unix::OwnedWriteHalf,
    next: u64,
}

impl Client {
    async fn connect(p: &Path) -> Result<Client, RunError> {
        let (r, w) = UnixStream::connect(p).await?.into_split();
        Ok(Client {
            r: BufReader::new(r),
            w,
            next: 0,
        })
    }

    /// Sends a request; its reply's fields, or the refusal as an error.
    async fn call(&mut self, mut req: Value) -> Result<Value, RunError> {
        self.next += 1;
        req["id"] = json!(self.next);
        self.w.write_all(format!("{req}\n").as_bytes()).await?;
        loop {
            let mut l = String::new();
            if self.r.read_line(&mut l).await? == 0 {
                return Err(RunError::Setup("the daemon closed the connection".into()));
            }
            let v: Value = serde_json::from_str(&l)
                .map_err(|e| RunError::Setup(format!("unreadable reply {l:?}: {e}")))?;
            if v.get("event").is_some() || v["id"] != json!(self.next) {
                continue;
            }
            if v["ok"] == json!(true) {
                return Ok(v);
            }
            return Err(RunError::Refused {
                cmd: req["cmd"].as_str().unwrap_or("?").to_owned(),
                code: v["error"]["code"].as_str().unwrap_or("?").to_owned(),
                message: v["error"]["message"].as_str().unwrap_or("?").to_owned(),
            });
        }
    }

    /// The daemon's rig time, s.
    async fn now_s(&mut self) -> Result<f64, RunError> {
        Ok(self.call(json!({"cmd": "status"})).await?["t_s"]
            .as_f64()
            .unwrap_or(f64::NAN))
    }

    /// Polls a job's status until it leaves `running`; reports progress.
    /// Starts the validation job `req` and follows it to its end; returns
    /// its final status.
    async fn validate(
        &mut self,
        req: Value,
        progress: &mut dyn FnMut(&str),
    ) -> Result<Value, RunError> {
        self.call(req).await?;
        self.follow(
            json!({"cmd": "validate", "action": "status"}),
            "validate",
            progress,
        )
        .await
    }

    async fn follow(
        &mut self,
        status_req: Value,
        what: &str,
        progress: &mut dyn FnMut(&str),
    ) -> Result<Value, RunError> {
        let mut last_print = Instant::now();
        loop {
            let s = self.call(status_req.clone()).await?;
            let job = &s["job"];
            let state = JobState::of(job);
            if state != Some(JobState::Running) {
                if state != Some(JobState::Done) {
                    return Err(RunError::Job {
                        kind: what.to_owned(),
                        state: job["state"].as_str().unwrap_or("?").to_owned(),
                        error: job["error"].as_str().unwrap_or("").to_owned(),
                    });
                }
                progress(&format!(
                    "{what}: done ({} points)",
                    job["done"].as_u64().unwrap_or(0)
                ));
                return Ok(s);
            }
            if last_print.elapsed() >= Duration::from_secs(5) {
                last_print = Instant::now();
                // No estimate before the job's first points.
                let eta = job["eta_s"].as_f64().filter(|e| e.is_finite()).map_or_else(
                    || "ETA not yet known".to_owned(),
                    |e| format!("ETA {e:.0} simulated s"),
                );
                progress(&format!(
                    "{what}: {}/{} points, {eta}",
                    job["done"].as_u64().unwrap_or(0),
                    job["total"].as_u64().unwrap_or(0),
                ));
            }
            // Rig time (virtual on the in-process rig): the job's end is
            // seen within a second, without thousands of status calls per
            // simulated hour.
            tokio::time::sleep(STATUS_POLL).await;
        }
    }
}

/// How often the start-up asks whether the daemon's controllers are
/// connected (rig time).
const CONNECT_POLL: Duration = Duration::from_millis(50);

/// How often a followed job's status is read.
const STATUS_POLL: Duration = Duration::from_secs(1);

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

/// The validation request every run makes (both tests, the plan's cycles,
/// poses, frames and settling, the paper table); callers add modes and the
/// model table.
fn validate_request(p: &RunPlan, log: &str) -> Value {
    json!({"cmd": "validate", "action": "start", "test": "both",
           "log": log, "cycles": p.validate_cycles,
           "square_step_um": p.square_step_um, "origin_x_um": p.validate_origin_um,
           "origin_y_um": p.validate_origin_um, "table": "run-paper.toml",
           "frames_per_point": p.frames_per_point, "settle_s": p.settle_s})
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

#[expect(
    clippy::too_many_lines,
    reason = "the main job's pipeline, phase after phase; to be split into its phases"
)]
async fn pipeline(
    opts: &RunOptions,
    st: &Started,
    progress: &mut dyn FnMut(&str),
) -> Result<(Value, Value, Vec<String>, Vec<(String, f64)>), RunError> {
    let p = &opts.plan;
    let mut c = Client::connect(&st.socket).await?;
    let t0 = Instant::now();
    loop {
        // Wait first, then ask. Why: the daemon connects its controllers
        // at the rig's first instant, and whether a status call at that
        // same instant already sees them depends only on how many task
        // polls the daemon's start-up takes; asking one poll period later
        // puts the rig's time origin for the run (every later instant, so
        // every result) out of reach of that.
        tokio::time::sleep(CONNECT_POLL).await;
        let s = c.call(json!({"cmd": "status"})).await?;
        if s["rig"]["connected"]["x"] == true && s["rig"]["connected"]["y"] == true {
            break;
        }
        if t0.elapsed() > Duration::from_secs(30) {
            return Err(RunError::Setup(format!(
                "controllers not connected after 30 s: {s}"
            )));
        }
    }
    progress("referencing both axes");
    // Simulated seconds per phase, in order (the `phases_s` block).
    let mut phases = serde_json::Map::new();
    let mut mark = c.now_s().await?;
    // Wall seconds per phase, beside the simulated ones (not in the JSON).
    let mut walls = Vec::new();
    let mut wall_mark = Instant::now();
    c.call(json!({"cmd": "reference", "axes": "xy"})).await?;
    let mut lap = |c_now: f64, name: &str, phases: &mut serde_json::Map<String, Value>| {
        phases.insert(name.to_owned(), json!(c_now - mark));
        mark = c_now;
        walls.push((name.to_owned(), wall_mark.elapsed().as_secs_f64()));
        wall_mark = Instant::now();
    };
    lap(c.now_s().await?, "reference", &mut phases);
    let mut chars = Vec::new();
    for (log, step, moves, settle_s) in [
        ("charact-paper.csv", p.step_um, 0, p.paper_settle_s),
        (
            "charact-short.csv",
            p.short_step_um,
            p.short_moves_per_cycle,
            p.settle_s,
        ),
    ] {
        progress(&format!(
            "characterize {log}: {step} µm steps over {} × {} µm, {} cycles, {settle_s} s settle",
            p.x_range_um, p.y_range_um, p.cycles
        ));
        let t_start = c.now_s().await?;
        c.call(json!({"cmd": "characterize", "action": "start", "log": log,
                      "step_um": step, "x_range_um": p.x_range_um, "y_range_um": p.y_range_um,
                      "cycles": p.cycles, "frames_per_point": p.frames_per_point,
                      "settle_s": settle_s, "drift_every_s": p.drift_every_s,
                      "drift_reference_um": p.drift_reference_um,
                      "moves_per_cycle": moves}))
            .await?;
        // A job that fails on a transient fault (a late serial answer on a
        // loaded machine) is resumed from its log, as a user would: every
        // point is logged once (see the daemon's resume).
        let mut attempts = 0;
        let s = loop {
            match c
                .follow(
                    json!({"cmd": "characterize", "action": "status"}),
                    "characterize",
                    progress,
                )
                .await
            {
                Err(RunError::Job { state, error, .. }) if attempts < MAX_RESUMES => {
                    attempts += 1;
                    progress(&format!(
                        "characterize {log} {state} ({error}); resuming it from its log ({attempts}/{MAX_RESUMES})"
                    ));
                    tokio::time::sleep(Duration::from_millis(500)).await;
                    c.call(json!({"cmd": "characterize", "action": "resume", "log": log}))
                        .await?;
                }
                other => break other?,
            }
        };
        let t_end = c.now_s().await?;
        chars.push((s["job"]["done"].as_u64().unwrap_or(0), t_end - t_start));
        lap(t_end, log.trim_end_matches(".csv"), &mut phases);
    }
    progress(
        "tables build: paper tables from charact-paper.csv, model table from charact-short.csv",
    );
    let paper = c
        .call(
            json!({"cmd": "tables", "action": "build", "log": "charact-paper.csv",
                     "name": "run", "kinds": ["paper"], "activate": true}),
        )
        .await?;
    let model = c
        .call(
            json!({"cmd": "tables", "action": "build", "log": "charact-short.csv",
                     "name": "run-short", "kinds": ["model"]}),
        )
        .await?;
    lap(c.now_s().await?, "tables", &mut phases);
    let rms = |i: usize| {
        model["model"]["rms_residual_um"][i]
            .as_f64()
            .unwrap_or(f64::NAN)
    };
    progress(&format!(
        "  paper tables: squareness {:.1} µrad; model fit residual rms x {:.3} µm, y {:.3} µm",
        paper["paper"]["report"]["squareness_urad"]
            .as_f64()
            .unwrap_or(f64::NAN),
        rms(0),
        rms(1)
    ));
    c.call(
        json!({"cmd": "drift", "action": "set", "method": p.live_drift,
                  "every_s": p.live_drift_every_s}),
    )
    .await?;
    progress(&format!(
        "validate: square and Table II in raw, table, model, closed_loop (live drift {})",
        p.live_drift
    ));
    let mut req = validate_request(p, "validate.csv");
    req["model_table"] = json!("run-short-model.toml");
    let v = c.validate(req, progress).await?;
    lap(c.now_s().await?, "validate", &mut phases);
    let results = v["validation"]["results"].clone();
    let mut summary = json!({});
    for test in ["square", "random"] {
        let mut t = json!({});
        for mode in ["raw", "table", "model", "closed_loop"] {
            let r = &results[test][mode];
            t[mode] = json!({"ap_um": r["ap_um"], "rp_um": r["rp_um"],
                             "ap_mean_um": r["ap_mean_um"], "rp_mean_um": r["rp_mean_um"]});
        }
        summary[test] = t;
    }
    summary["characterization"] = json!({
        "points": chars[0].0, "simulated_s": chars[0].1, "settle_s": p.paper_settle_s,
        "short_points": chars[1].0, "short_simulated_s": chars[1].1,
        "short_settle_s": p.settle_s, "short_step_um": p.short_step_um,
        "short_moves_per_cycle": p.short_moves_per_cycle,
        "lead_periods_um": st.sim.rig().lead_periods_um(),
    });
    let mut files = [
        "charact-paper.csv",
        "charact-short.csv",
        "validate.csv",
        "run-paper.toml",
        "run-short-model.toml",
    ]
    .map(str::to_owned)
    .to_vec();
    let mut drift = json!({
        "characterization_every_s": p.drift_every_s,
        "tables_drift": paper["drift"],
        "live": p.live_drift, "live_every_s": p.live_drift_every_s,
        "validation": {"square": table_offset(&results["square"]["table"]),
                       "random": table_offset(&results["random"]["table"])},
    });
    if p.drift_compare {
        let mut cmp = json!({});
        for method in DRIFT_METHODS {
            progress(&format!(
                "validate: table mode with live drift {method} (the drift comparison)"
            ));
            c.call(json!({"cmd": "drift", "action": "set", "method": method,
                          "every_s": p.live_drift_every_s}))
                .await?;
            c.call(json!({"cmd": "drift", "action": "reset"})).await?;
            let log = format!("validate-drift-{method}.csv");
            let mut req = validate_request(p, &log);
            req["modes"] = json!(["table"]);
            let v = c.validate(req, progress).await?;
            lap(
                c.now_s().await?,
                &format!("validate_drift_{method}"),
                &mut phases,
            );
            let r = &v["validation"]["results"];
            cmp[method] = json!({"square": table_offset(&r["square"]["table"]),
                                 "random": table_offset(&r["random"]["table"])});
            files.push(log);
        }
        drift["compare"] = cmp;
    }
    summary["drift"] = drift;
    if p.sweep_velocity_um_per_s > 0.0 {
        let mut sw = sweep_phase(opts, &mut c, progress, &mut files).await?;
        sw["step_simulated_s"] = json!(chars[0].1);
        sw["step_table_ap_um"] = summary["drift"]["compare"]["off"].clone();
        summary["sweep"] = sw;
        lap(c.now_s().await?, "sweep", &mut phases);
    }
    if p.grid_pitch_um > 0.0 {
        let mut g = grid_phase(opts, &mut c, progress, &mut files).await?;
        g["step_table_ap_um"] = summary["drift"]["compare"]["off"].clone();
        summary["grid"] = g;
        lap(c.now_s().await?, "grid", &mut phases);
    }
    summary["phases_s"] = Value::Object(phases);
    // Frames the camera delivered and the decoder read: the work the run
    // cannot avoid (the main-job benchmark's baseline is their cost).
    let cam = &c.call(json!({"cmd": "status"})).await?["camera"];
    summary["frames"] = json!({"grabbed": cam["frames"], "decoded": cam["decoded"]});
    Ok((summary, results, files, walls))
}

/// The sweep row: `characterize start mode=sweep` over the plan's ranges
/// with the step characterization's drift references and the plan's
/// anchors, tables from the corrected log, the delay-ignored one and (with
/// anchors) the unanchored one, each validated in `table` mode with live
/// drift off (compare with the drift comparison's `off` row of the step
/// tables).
async fn sweep_phase(
    opts: &RunOptions,
    c: &mut Client,
    progress: &mut dyn FnMut(&str),
    files: &mut Vec<String>,
) -> Result<Value, RunError> {
    let p = &opts.plan;
    progress(&format!(
        "characterize charact-sweep.csv: sweeps at {} and {} µm/s over {} × {} µm, {} cycles",
        p.sweep_velocity_um_per_s,
        2.0 * p.sweep_velocity_um_per_s,
        p.x_range_um,
        p.y_range_um,
        p.cycles.max(2)
    ));
    let t0 = c.now_s().await?;
    let anchored = p.sweep_anchor_spacing_um > 0.0;
    let mut req = json!({"cmd": "characterize", "action": "start", "log": "charact-sweep.csv",
                  "mode": "sweep", "velocity_um_per_s": p.sweep_velocity_um_per_s,
                  "uncorrected_log": "charact-sweep-nodelay.csv", "step_um": p.step_um,
                  "x_range_um": p.x_range_um, "y_range_um": p.y_range_um,
                  "cycles": p.cycles.max(2), "frames_per_point": p.frames_per_point,
                  "settle_s": p.settle_s, "drift_every_s": p.drift_every_s,
                  "drift_reference_um": p.drift_reference_um,
                  "anchor_spacing_um": p.sweep_anchor_spacing_um});
    if anchored {
        req["unanchored_log"] = json!("charact-sweep-noanchor.csv");
    }
    c.call(req).await?;
    let s = c
        .follow(
            json!({"cmd": "characterize", "action": "status"}),
            "sweep",
            progress,
        )
        .await?;
    let simulated_s = c.now_s().await? - t0;
    let res = &s["job"]["result"];
    c.call(json!({"cmd": "drift", "action": "set", "method": "off"}))
        .await?;
    let mut out = json!({"simulated_s": simulated_s, "result": res,
                         "true_delay_s": opts.rig.camera.latency_us * 1e-6});
    let mut logs = vec![
        ("charact-sweep.csv", "run-sweep"),
        ("charact-sweep-nodelay.csv", "run-sweep-nodelay"),
    ];
    if anchored {
        logs.push(("charact-sweep-noanchor.csv", "run-sweep-noanchor"));
    }
    for (log, stem) in logs {
        c.call(
            json!({"cmd": "tables", "action": "build", "log": log, "name": stem,
                      "kinds": ["paper"]}),
        )
        .await?;
        let vlog = format!("validate-{stem}.csv");
        let mut req = validate_request(p, &vlog);
        req["modes"] = json!(["table"]);
        req["table"] = json!(format!("{stem}-paper.toml"));
        progress(&format!("validate: table mode with {stem}-paper.toml"));
        let v = c.validate(req, progress).await?;
        let r = &v["validation"]["results"];
        out[stem] = json!({"square": table_offset(&r["square"]["table"]),
                           "random": table_offset(&r["random"]["table"])});
        files.extend([log.to_owned(), format!("{stem}-paper.toml"), vlog]);
    }
    Ok(out)
}

/// The grid row: `characterize start plan=grid` over the plan's ranges at
/// `grid_pitch_um` (one cycle, the plan's drift references), its 2-D map
/// (`tables build` kind grid), validated in `table` mode with live drift
/// off.
async fn grid_phase(
    opts: &RunOptions,
    c: &mut Client,
    progress: &mut dyn FnMut(&str),
    files: &mut Vec<String>,
) -> Result<Value, RunError> {
    let p = &opts.plan;
    progress(&format!(
        "characterize charact-grid.csv: a grid at {} µm pitch over {} × {} µm",
        p.grid_pitch_um, p.x_range_um, p.y_range_um
    ));
    let t0 = c.now_s().await?;
    c.call(
        json!({"cmd": "characterize", "action": "start", "log": "charact-grid.csv",
                  "plan": "grid", "pitch_um": p.grid_pitch_um,
                  "x_range_um": p.x_range_um, "y_range_um": p.y_range_um, "cycles": 1,
                  "frames_per_point": p.frames_per_point, "settle_s": p.settle_s,
                  "drift_every_s": p.drift_every_s,
                  "drift_reference_um": p.drift_reference_um}),
    )
    .await?;
    let s = c
        .follow(
            json!({"cmd": "characterize", "action": "status"}),
            "grid",
            progress,
        )
        .await?;
    let simulated_s = c.now_s().await? - t0;
    let built = c
        .call(
            json!({"cmd": "tables", "action": "build", "log": "charact-grid.csv",
                     "name": "run-grid", "kinds": ["grid"]}),
        )
        .await?;
    c.call(json!({"cmd": "drift", "action": "set", "method": "off"}))
        .await?;
    let mut req = validate_request(p, "validate-grid.csv");
    req["modes"] = json!(["table"]);
    req["table"] = json!("run-grid-grid.toml");
    progress("validate: table mode with the grid map run-grid-grid.toml");
    let v = c.validate(req, progress).await?;
    let r = &v["validation"]["results"];
    files.extend(
        [
            "charact-grid.csv",
            "run-grid-grid.toml",
            "validate-grid.csv",
        ]
        .map(str::to_owned),
    );
    Ok(
        json!({"pitch_um": p.grid_pitch_um, "nodes": s["job"]["done"],
              "simulated_s": simulated_s, "report": built["grid"]["report"],
              "square": table_offset(&r["square"]["table"]),
              "random": table_offset(&r["random"]["table"])}),
    )
}

/// The live drift methods the comparison runs, in this order.
pub const DRIFT_METHODS: [&str; 3] = ["off", "static", "adaptive"];

/// AP of one validation result and its constant part: the mean over poses
/// of the signed APx, APy (measured − target, µm), i.e. the offset common
/// to every pose that drift between the characterization and the
/// validation leaves.
pub fn table_offset(r: &Value) -> Value {
    let poses = r["poses"].as_array().map_or(&[][..], |v| v.as_slice());
    let mean = |k: &str| -> Option<f64> {
        let v: Vec<f64> = poses.iter().filter_map(|p| p[k].as_f64()).collect();
        (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
    };
    json!({"ap_um": r["ap_um"], "ap_mean_um": r["ap_mean_um"],
           "offset_um": [mean("apx_um"), mean("apy_um")],
           "references": r["drift"]["references_logged"]})
}

/// Why the model table stays behind the lookup tables, when it does: it is
/// fitted to the short characterization, and a plan that samples it
/// coarser than half the screw's lead, or without moves of varied length,
/// withholds the two things the model needs (the screw's cycle, the lost
/// motion that grows with the move length). Said from the plan's own
/// numbers, so a reader of `--short` is not left with figures that
/// contradict the README's.
fn model_note(summary: &Value) -> Option<String> {
    let worse: Vec<&str> = ["square", "random"]
        .into_iter()
        .filter(|t| {
            let ap = |m: &str| summary[*t][m]["ap_um"].as_f64();
            matches!((ap("model"), ap("table")), (Some(m), Some(t)) if m > t)
        })
        .collect();
    if worse.is_empty() {
        return None;
    }
    let ch = &summary["characterization"];
    let step = ch["short_step_um"].as_f64()?;
    let moves = ch["short_moves_per_cycle"].as_u64()?;
    let leads: Vec<f64> = ch["lead_periods_um"]
        .as_array()
        .map(|v| v.iter().filter_map(Value::as_f64).collect())
        .unwrap_or_default();
    let mut why = Vec::new();
    if let Some(lead) = leads
        .iter()
        .copied()
        .filter(|l| step > l / 2.0)
        .reduce(f64::min)
    {
        why.push(format!(
            "its {step:.0} µm steps cannot resolve the screw's {lead:.0} µm cycle (a step of at most {:.0} µm can)",
            lead / 2.0
        ));
    }
    if moves == 0 {
        why.push(
            "it has no moves of varied length, so it cannot learn the lost motion that grows with the move length"
                .to_owned(),
        );
    }
    let because = if why.is_empty() {
        "on this plan the model's terms do not hold this stage's error better than the tables"
            .to_owned()
    } else {
        why.join("; ")
    };
    let full = RunPlan::paper();
    Some(format!(
        "note: the model table ({}) is behind the lookup tables: it is fitted to the short characterization, and {because}. \
         The default plan ({:.0} µm steps, {} moves of varied length per cycle) gives the model the figures the README reports.\n",
        worse.join(" and "),
        full.short_step_um,
        full.short_moves_per_cycle
    ))
}

/// The figures of a run (`hil-sim run --plots DIR`): from the run's logs in
/// `data_dir` (`files` as [`RunReport::files`] lists them), each log's own
/// figures, no comparison: Figs. 4–5 (and 6 with at least two cycles) of
/// every characterization log that has scans, Figs. 10–11 of every
/// validation log. So `validate_fig11_random` shows the AP and RP the run
/// printed, and the drift comparison's and the sweep's and grid's
/// validations are figures of their own (`validate-drift-off_fig11_random`,
/// …), never pooled into one mode. Logs with no paper figure (the grid's
/// map, sweeps' raw passes without scans) are named in the notes.
pub fn plot_run(
    data_dir: &Path,
    files: &[String],
    out_dir: &Path,
    format: micropos::plot::Format,
) -> Result<micropos::plot::Plotted, micropos::plot::PlotError> {
    use micropos::plot::{plot_logs, read_logs};
    let paths: Vec<PathBuf> = files
        .iter()
        .filter(|f| f.ends_with(".csv"))
        .map(|f| data_dir.join(f))
        .collect();
    let (plottable, other): (Vec<_>, Vec<_>) = read_logs(&paths)?.into_iter().partition(|l| {
        let c = micropos::plot::report::contents(&l.log);
        c.characterization || c.validation
    });
    let mut p = plot_logs(&plottable, out_dir, format, false)?;
    for l in other {
        p.notes.push(format!(
            "{}: no scan or validation records: none of the paper's figures",
            l.name
        ));
    }
    Ok(p)
}

/// The human-readable table of AP and RP per trajectory and mode.
pub fn format_table(summary: &Value) -> String {
    let mut s =
        String::from("trajectory  mode         AP max µm  AP mean µm  RP max µm   paper AP µm\n");
    let f = |v: &Value| v.as_f64().map_or("-".to_owned(), |x| format!("{x:.3}"));
    for test in ["square", "random"] {
        for mode in ["raw", "table", "model", "closed_loop"] {
            let r = &summary[test][mode];
            s.push_str(&format!(
                "{test:<11} {mode:<12} {:>9}  {:>10}  {:>9}   {:>11}\n",
                f(&r["ap_um"]),
                f(&r["ap_mean_um"]),
                f(&r["rp_um"]),
                paper_ap_um(test, mode).map_or("-".to_owned(), |x| format!("≈{x}"))
            ));
        }
    }
    if let Some(note) = model_note(summary) {
        s.push_str(&note);
    }
    let d = &summary["drift"];
    if !d.is_null() {
        s.push_str(&format!(
            "drift: references every {} s in the characterizations; live {} every {} s\n",
            d["characterization_every_s"], d["live"], d["live_every_s"]
        ));
        let cmp = &d["compare"];
        if cmp.is_object() {
            s.push_str("table mode by live drift  AP max µm (square / random)  offset x, y µm (square / random)\n");
            for m in DRIFT_METHODS {
                let off = |t: &str| {
                    let o = &cmp[m][t]["offset_um"];
                    format!("{}, {}", f(&o[0]), f(&o[1]))
                };
                s.push_str(&format!(
                    "  {m:<9}               {:>7} / {:<7}            {} / {}\n",
                    f(&cmp[m]["square"]["ap_um"]),
                    f(&cmp[m]["random"]["ap_um"]),
                    off("square"),
                    off("random")
                ));
            }
        }
    }
    if let Some(p) = summary["phases_s"].as_object() {
        let list: Vec<String> = p
            .iter()
            .map(|(k, v)| format!("{k} {:.0}", v.as_f64().unwrap_or(f64::NAN)))
            .collect();
        s.push_str(&format!("simulated s per phase: {}\n", list.join(", ")));
    }
    let sw = &summary["sweep"];
    if sw.is_object() {
        let ap = |k: &str, t: &str| f(&sw[k][t]["ap_um"]);
        s.push_str(&format!(
            "sweep: {:.0} simulated s (step plan {:.0} s); camera delay {:.3} ms estimated, {:.3} ms true\n\
             table AP max µm (square / random), live drift off: step {} / {}, sweep {} / {}, sweep delay ignored {} / {}, sweep without anchors {} / {}\n",
            sw["simulated_s"].as_f64().unwrap_or(f64::NAN),
            sw["step_simulated_s"].as_f64().unwrap_or(f64::NAN),
            sw["result"]["camera_delay_s"].as_f64().unwrap_or(f64::NAN) * 1e3,
            sw["true_delay_s"].as_f64().unwrap_or(f64::NAN) * 1e3,
            ap("step_table_ap_um", "square"),
            ap("step_table_ap_um", "random"),
            ap("run-sweep", "square"),
            ap("run-sweep", "random"),
            ap("run-sweep-nodelay", "square"),
            ap("run-sweep-nodelay", "random"),
            ap("run-sweep-noanchor", "square"),
            ap("run-sweep-noanchor", "random"),
        ));
    }
    let g = &summary["grid"];
    if g.is_object() {
        let ap = |k: &str, t: &str| f(&g[k][t]["ap_um"]);
        s.push_str(&format!(
            "grid: {} nodes at {} µm pitch, {:.0} simulated s; 2-D map table AP max µm (square / random), live drift off: {} / {} (step tables {} / {})\n",
            g["nodes"],
            g["pitch_um"],
            g["simulated_s"].as_f64().unwrap_or(f64::NAN),
            f(&g["square"]["ap_um"]),
            f(&g["random"]["ap_um"]),
            ap("step_table_ap_um", "square"),
            ap("step_table_ap_um", "random"),
        ));
    }
    let ch = &summary["characterization"];
    s.push_str(&format!(
        "characterization: {} points, {:.0} simulated s; short: {} points, {:.0} simulated s\n",
        ch["points"],
        ch["simulated_s"].as_f64().unwrap_or(f64::NAN),
        ch["short_points"],
        ch["short_simulated_s"].as_f64().unwrap_or(f64::NAN)
    ));
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_model_table_behind_the_tables_is_explained_from_the_plan() {
        let summary = |model: f64, step: f64, moves: u32| {
            json!({
                "square": {"table": {"ap_um": 3.22}, "model": {"ap_um": model}},
                "random": {"table": {"ap_um": 6.41}, "model": {"ap_um": 1.0}},
                "characterization": {"short_step_um": step, "short_moves_per_cycle": moves,
                                     "lead_periods_um": [400.0, 400.0]},
            })
        };
        let n = model_note(&summary(5.06, 500.0, 0)).unwrap();
        assert!(n.contains("model table (square)"), "{n}");
        assert!(
            n.contains("500 µm steps cannot resolve the screw's 400 µm cycle"),
            "{n}"
        );
        assert!(n.contains("at most 200 µm"), "{n}");
        assert!(n.contains("no moves of varied length"), "{n}");
        // Fine steps, moves of varied length: no plan reason, a plain one.
        let n = model_note(&summary(5.06, 50.0, 40)).unwrap();
        assert!(
            !n.contains("cannot resolve") && !n.contains("no moves"),
            "{n}"
        );
        // The model ahead: nothing to explain.
        assert_eq!(model_note(&summary(0.4, 500.0, 0)), None);
        // The note is part of the table.
        assert!(format_table(&summary(5.06, 500.0, 0)).contains("note: the model table"));
    }

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
