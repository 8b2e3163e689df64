//! Serving simulated controllers on pseudo-terminals, with fault injection.
//!
//! Each serial line is one pty served by one thread; the controllers behind
//! it are a [`Bus`] shared (under a mutex) with the [`SimHandle`] so tests can
//! read ground truth and power-cycle a controller. The thread owns the pty:
//! line faults (pull the cable, plug it back, write garbage) are sent to it
//! over a channel and acknowledged, so a fault is in effect when
//! [`SimHandle::inject`] returns.
//!
//! The pty is switched to raw mode (no echo, no CR/LF translation, no
//! signal or flow-control characters) because the GCS control characters
//! `#4`, `#5`, `#7`, `#24` would otherwise be eaten by the line discipline.
//! The server does not keep the slave side open: while no client has the
//! port open the master reports a hang-up, and what the controllers send
//! then is discarded (and the queues flushed), as bytes sent down a serial
//! cable with nobody listening are lost. A client opening the port later
//! never reads stale answers.
//!
//! This file holds the configuration and the handle; `line.rs` is the
//! serving thread of one pty line, `pty.rs` the pty itself, `probe.rs` the
//! latency probe and `client.rs` the blocking client helpers.

mod client;
mod line;
mod probe;
mod pty;

use crate::bus::Bus;
use crate::clock::{Clock, ScaledClock};
use crate::controller::{Controller, ControllerConfig};
pub use crate::fault::{AxisName, Corruption, Fault, SimError};
use crate::fault::{LineCmd, ReplyFaults};
use micropos::gcs::Address;
use rand::{Rng, SeedableRng};
use std::fmt;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

pub use client::{exchange, read_answer};
use line::{lock, Ack, Line};
pub use probe::RxProbe;
use pty::{io_err, Pty};

/// How long [`SimHandle::start`] waits for each controller to answer.
const READY_TIMEOUT: Duration = Duration::from_secs(5);

/// How to serve the simulated controllers.
#[derive(Debug, Clone)]
pub struct ServeConfig {
    /// Directory for the symlinks `x`, `y` (or `bus` with `daisy_chain`).
    pub link_dir: PathBuf,
    /// Both controllers on one pty: X at address 1, Y at address 2.
    pub daisy_chain: bool,
    /// Simulated seconds per wall second (1.0 = real time).
    pub time_scale: f64,
    /// Unix socket for JSON-lines fault injection, if wanted.
    pub control_socket: Option<PathBuf>,
    /// Seed for everything random (serial numbers, power-up carriage
    /// positions, settling noise, camera noise): the same seed gives the
    /// same simulation.
    pub seed: u64,
    /// The rig: stage model file, pattern mounting, camera.
    pub rig: crate::rig::RigConfig,
    /// Stage model file, overriding `rig.model` (none: the rig's, else the
    /// paper default).
    pub model: Option<PathBuf>,
    /// Unix socket for the simulated camera, if wanted.
    pub camera_socket: Option<PathBuf>,
    /// An in-memory stage model, overriding both model files (tests use
    /// `StageModel::ideal()` to check the controllers alone).
    pub stage_model: Option<micropos::model::StageModel>,
    /// Serve the lines in process ([`crate::vline`]) instead of on ptys:
    /// no links are created; the driver opens them through
    /// [`SimHandle::link_opener`]. Needs a tokio runtime (see
    /// [`SimHandle::start_in_process`]).
    pub in_process: bool,
}

impl Default for ServeConfig {
    fn default() -> Self {
        Self {
            link_dir: PathBuf::new(),
            daisy_chain: false,
            time_scale: 1.0,
            control_socket: None,
            seed: 0,
            rig: crate::rig::RigConfig::default(),
            model: None,
            camera_socket: None,
            stage_model: None,
            in_process: false,
        }
    }
}

/// Where an axis lives: which line, which controller on that line's bus.
#[derive(Debug, Clone, Copy)]
struct Route {
    line: usize,
    controller: usize,
}

struct LineCtl {
    axis: AxisName,
    link: PathBuf,
    probe: Arc<RxProbe>,
    backend: Backend,
}

/// How a line is served.
enum Backend {
    /// A pty owned by a thread, commanded over a channel.
    Pty {
        tx: Mutex<mpsc::Sender<(LineCmd, Ack)>>,
        thread: Option<JoinHandle<()>>,
    },
    /// Tasks on the caller's runtime ([`crate::vline`]).
    InProcess(Arc<crate::vline::InProcessLine>),
}

impl LineCtl {
    /// Waits for a pty line's thread to end (after the stop flag is set).
    fn join(&mut self) {
        if let Backend::Pty { thread, .. } = &mut self.backend {
            if let Some(t) = thread.take() {
                let _ = t.join();
            }
        }
    }
}

/// Shared between the handle and the control socket.
struct Core {
    clock: Arc<dyn Clock>,
    buses: Vec<Arc<Mutex<Bus>>>,
    lines: Vec<LineCtl>,
    routes: [Route; 2],
    stop: Arc<AtomicBool>,
    rig: Arc<crate::rig::Rig>,
    camera: Arc<crate::camera::SimCamera>,
}

impl Core {
    fn send(&self, line: usize, cmd: LineCmd) -> Result<(), SimError> {
        let ctl = &self.lines[line];
        let tx = match &ctl.backend {
            Backend::Pty { tx, .. } => tx,
            Backend::InProcess(l) => return l.apply(cmd),
        };
        let (ack_tx, ack_rx) = mpsc::channel();
        tx.lock()
            .unwrap_or_else(|e| e.into_inner())
            .send((cmd, ack_tx))
            .map_err(|_| SimError::ThreadGone(ctl.axis))?;
        ack_rx
            .recv_timeout(Duration::from_secs(5))
            .map_err(|_| SimError::ThreadGone(ctl.axis))?
    }

    fn inject(&self, axis: AxisName, fault: Fault) -> Result<(), SimError> {
        self.inject_on_route(axis, fault).map_err(|e| match e {
            // A daisy-chain line serves both axes: name the one asked for.
            SimError::LineDown(_) => SimError::LineDown(axis),
            SimError::ThreadGone(_) => SimError::ThreadGone(axis),
            other => other,
        })
    }

    fn inject_on_route(&self, axis: AxisName, fault: Fault) -> Result<(), SimError> {
        let r = self.routes[axis.index()];
        match fault {
            Fault::DropLine => self.send(r.line, LineCmd::Drop),
            Fault::RestoreLine => self.send(r.line, LineCmd::Restore),
            Fault::Garbage(b) => self.send(r.line, LineCmd::Garbage(b)),
            Fault::DelayReplies(d) => self.send(r.line, LineCmd::Delay(r.controller, d)),
            Fault::WithholdReplies(on) => self.send(r.line, LineCmd::Withhold(r.controller, on)),
            Fault::CorruptReplies { how, count } => {
                self.send(r.line, LineCmd::Corrupt(r.controller, how, count))
            }
            Fault::PowerCycle | Fault::Stall | Fault::MotionError | Fault::Slip { .. } => {
                let now = self.clock.now();
                let mut bus = lock(&self.buses[r.line]);
                if let Some(c) = bus.controller_mut(r.controller) {
                    match fault {
                        Fault::Stall => c.stall(now),
                        Fault::MotionError => c.motion_error(now),
                        Fault::Slip { slip_um } => c.slip(now, f64::from(slip_um) / 1000.0),
                        _ => c.power_cycle(now),
                    }
                }
                Ok(())
            }
        }
    }

    fn true_position_mm(&self, axis: AxisName) -> f64 {
        let r = self.routes[axis.index()];
        let now = self.clock.now();
        let bus = lock(&self.buses[r.line]);
        bus.controllers()
            .get(r.controller)
            .map(|c| c.true_position_mm(now))
            .unwrap_or(f64::NAN)
    }

    fn link(&self, axis: AxisName) -> PathBuf {
        self.lines[self.routes[axis.index()].line].link.clone()
    }
}

/// The running simulator. Dropping it shuts everything down and removes the
/// links (and the control socket).
pub struct SimHandle {
    core: Arc<Core>,
    control: Option<crate::control::ControlServer>,
    camera_server: Option<crate::camera::server::CameraServer>,
    down: bool,
}

impl fmt::Debug for SimHandle {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("SimHandle")
            .field(
                "links",
                &self.core.lines.iter().map(|l| &l.link).collect::<Vec<_>>(),
            )
            .finish()
    }
}

/// Serial numbers and power-up carriage positions for both controllers,
/// drawn from the seed; the servo lag from the rig.
fn controller_configs(
    seed: u64,
    daisy: bool,
    servo: &crate::rig::ServoConfig,
) -> Result<[ControllerConfig; 2], SimError> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let mut make = |axis: AxisName| -> Result<ControllerConfig, SimError> {
        let addr = if daisy { axis.index() as u8 + 1 } else { 1 };
        let address = Address::new(addr).map_err(|e| SimError::Config(format!("address: {e}")))?;
        let serial = format!("01155{:05}", rng.gen_range(0..100_000u32));
        // Somewhere inside the travel; the controller does not know where.
        let initial = rng.gen_range(1.0..14.0);
        Ok(ControllerConfig {
            following_lag_s: servo.following_lag_ms * 1e-3,
            ..ControllerConfig::new(address, &serial, initial)
        })
    };
    Ok([make(AxisName::X)?, make(AxisName::Y)?])
}

impl SimHandle {
    /// Starts serving with a clock running `cfg.time_scale` times wall time.
    /// Returns when the links exist and every controller has answered
    /// `*IDN?` through its link. Spawns plain threads (no tokio), so it may
    /// be called from inside or outside a tokio runtime.
    pub fn start(cfg: ServeConfig) -> Result<SimHandle, SimError> {
        if !(cfg.time_scale.is_finite() && cfg.time_scale > 0.0) {
            return Err(SimError::Config(format!(
                "time_scale must be a positive number, got {}",
                cfg.time_scale
            )));
        }
        let clock = Arc::new(ScaledClock::new(cfg.time_scale));
        Self::start_with_clock(cfg, clock)
    }

    /// Starts the rig in process on the current tokio runtime's clock
    /// ([`crate::clock::RuntimeClock`]): lines are served by tasks
    /// ([`crate::vline`]), `cfg.time_scale` is ignored. Under a paused
    /// current-thread runtime simulated time then advances only by the
    /// rig's own events (motion, settling, exposure, the daemon's timers),
    /// never by wall time: one seed, one result.
    pub fn start_in_process(mut cfg: ServeConfig) -> Result<SimHandle, SimError> {
        let clock = crate::clock::RuntimeClock::new().ok_or_else(|| {
            SimError::Config("an in-process rig must be started inside a tokio runtime".into())
        })?;
        cfg.in_process = true;
        Self::start_with_clock(cfg, Arc::new(clock))
    }

    /// Opens the in-process lines by their names (`link(axis)`) for the
    /// micropos driver; `None` when the lines are ptys.
    pub fn link_opener(&self) -> Option<Arc<dyn micropos::driver::LinkOpener>> {
        let lines: Vec<_> = self
            .core
            .lines
            .iter()
            .filter_map(|l| match &l.backend {
                Backend::InProcess(line) => Some(line.clone()),
                Backend::Pty { .. } => None,
            })
            .collect();
        (!lines.is_empty()).then(|| {
            Arc::new(crate::vline::InProcessLinks::new(lines))
                as Arc<dyn micropos::driver::LinkOpener>
        })
    }

    /// Like [`SimHandle::start`] but with a given clock (`cfg.time_scale` is
    /// ignored): a [`crate::clock::ManualClock`] makes served timing
    /// deterministic. The rig and its camera first, then the controllers on
    /// their lines, then each line's link; the sockets last.
    pub fn start_with_clock(
        cfg: ServeConfig,
        clock: Arc<dyn Clock>,
    ) -> Result<SimHandle, SimError> {
        if cfg.link_dir.as_os_str().is_empty() {
            return Err(SimError::Config("link_dir must be set".into()));
        }
        if !cfg.link_dir.is_dir() {
            return Err(SimError::Config(format!(
                "link_dir {} is not a directory",
                cfg.link_dir.display()
            )));
        }
        cfg.rig.validate().map_err(SimError::Config)?;
        let [mut cx, mut cy] = controller_configs(cfg.seed, cfg.daisy_chain, &cfg.rig.servo)?;
        let model_path = cfg.model.clone().or_else(|| cfg.rig.model.clone());
        let model = match &cfg.stage_model {
            Some(m) => m.clone(),
            None => crate::rig::load_model(model_path.as_deref()).map_err(SimError::Config)?,
        };
        let rig = Arc::new(
            crate::rig::Rig::new(
                model,
                cfg.seed,
                [cx.initial_actuator_mm, cy.initial_actuator_mm],
                cfg.rig.mounting,
            )
            .map(|r| r.with_tool(cfg.rig.tool))
            .map_err(|e| SimError::Config(format!("stage model: {e}")))?,
        );
        let camera = Arc::new(
            crate::camera::SimCamera::new(&cfg.rig.camera, rig.clone(), clock.clone(), cfg.seed)
                .map_err(SimError::Config)?,
        );
        cx.platform = rig.platform(micropos::model::Axis::X);
        cy.platform = rig.platform(micropos::model::Axis::Y);
        let stop = Arc::new(AtomicBool::new(false));
        let (buses, routes, names) = wiring(cfg.daisy_chain, cx, cy)?;
        let buses: Vec<Arc<Mutex<Bus>>> =
            buses.into_iter().map(|b| Arc::new(Mutex::new(b))).collect();
        let mut lines = Vec::new();
        for (i, (axis, name)) in names.iter().enumerate() {
            let link = cfg.link_dir.join(name);
            let line = if cfg.in_process {
                Ok(in_process_line(*axis, link, &buses[i], &clock))
            } else {
                pty_line(*axis, name, link, &buses[i], &clock, &stop)
            };
            match line {
                Ok(l) => lines.push(l),
                Err(e) => {
                    // The lines opened so far end with the error.
                    stop.store(true, Ordering::SeqCst);
                    for l in &mut lines {
                        l.join();
                    }
                    return Err(e);
                }
            }
        }
        let core = Arc::new(Core {
            clock,
            buses,
            lines,
            routes,
            stop,
            rig,
            camera,
        });
        // The controllers tell the rig their (rest) paths at once.
        for b in &core.buses {
            let mut bus = lock(b);
            let n = bus.controllers().len();
            for i in 0..n {
                if let Some(c) = bus.controller_mut(i) {
                    c.power_up_report();
                }
            }
        }
        let mut handle = SimHandle {
            core,
            control: None,
            camera_server: None,
            down: false,
        };
        if !cfg.in_process {
            for axis in AxisName::ALL {
                handle.probe(axis, cfg.daisy_chain)?;
            }
        }
        // The control socket last: a daemon that waits for it (the sim
        // clock) then finds the lines and the camera in place.
        if let Some(path) = &cfg.camera_socket {
            handle.camera_server = Some(crate::camera::server::CameraServer::start(
                path,
                handle.core.camera.clone(),
            )?);
        }
        if let Some(path) = &cfg.control_socket {
            let injector: Arc<dyn crate::control::Injector> = handle.core.clone();
            handle.control = Some(crate::control::ControlServer::start(path, injector)?);
        }
        Ok(handle)
    }

    /// Asks the controller of `axis` for `*IDN?` through its link.
    fn probe(&self, axis: AxisName, daisy: bool) -> Result<(), SimError> {
        let link = self.link(axis);
        let not_ready = |why: String| SimError::NotReady {
            axis,
            link: link.clone(),
            why,
        };
        let request = if daisy {
            format!("{} *IDN?\n", axis.index() + 1)
        } else {
            "*IDN?\n".to_owned()
        };
        let answer = exchange(&link, request.as_bytes(), READY_TIMEOUT)
            .map_err(|e| not_ready(e.to_string()))?;
        if answer.windows(8).any(|w| w == b"C-863.11") {
            Ok(())
        } else {
            Err(not_ready(format!(
                "unexpected answer {:?}",
                String::from_utf8_lossy(&answer)
            )))
        }
    }

    /// The link of an axis: `DIR/x`, `DIR/y`, or `DIR/bus` for both.
    pub fn link(&self, axis: AxisName) -> PathBuf {
        self.core.link(axis)
    }

    /// Injects a fault; it is in effect when this returns.
    pub fn inject(&self, axis: AxisName, fault: Fault) -> Result<(), SimError> {
        self.core.inject(axis, fault)
    }

    /// The arrival probe of the line serving `axis` (shared with the other
    /// axis on a daisy chain).
    pub fn rx_probe(&self, axis: AxisName) -> Arc<RxProbe> {
        let r = self.core.routes[axis.index()];
        self.core.lines[r.line].probe.clone()
    }

    /// Ground truth: where the platform of `axis` really is now (mm).
    pub fn true_position_mm(&self, axis: AxisName) -> f64 {
        self.core.true_position_mm(axis)
    }

    /// Simulated time now.
    pub fn sim_time(&self) -> Duration {
        self.core.clock.now()
    }

    /// Jumps simulated time forward by `d`.
    pub fn advance(&self, d: Duration) {
        self.core.clock.advance(d);
    }

    /// The shared rig (stage model, mounting).
    pub fn rig(&self) -> &Arc<crate::rig::Rig> {
        &self.core.rig
    }

    /// Ground truth of the rig now.
    pub fn truth(&self) -> crate::rig::RigTruth {
        self.core.rig.truth(self.core.clock.now())
    }

    /// The simulated camera (for in-process frames:
    /// [`crate::camera::SimCameraSource`]).
    pub fn camera(&self) -> &Arc<crate::camera::SimCamera> {
        &self.core.camera
    }

    /// The camera socket, if served.
    pub fn camera_socket(&self) -> Option<&Path> {
        self.camera_server.as_ref().map(|c| c.path())
    }

    /// Runs `f` on the controller of `axis` (under its bus lock) with the
    /// current simulated time: for tests that need more than the truth, and
    /// for installing a stage error model with
    /// [`Controller::set_platform`].
    pub fn with_controller<T>(
        &self,
        axis: AxisName,
        f: impl FnOnce(&mut Controller, Duration) -> T,
    ) -> Option<T> {
        let r = self.core.routes[axis.index()];
        let now = self.core.clock.now();
        let mut bus = lock(&self.core.buses[r.line]);
        bus.controller_mut(r.controller).map(|c| f(c, now))
    }

    /// Stops serving: threads end, links and control socket are removed.
    pub fn shutdown(mut self) {
        self.stop_all();
    }

    fn stop_all(&mut self) {
        if self.down {
            return;
        }
        self.down = true;
        if let Some(c) = self.control.take() {
            c.stop();
        }
        if let Some(c) = self.camera_server.take() {
            c.stop();
        }
        self.core.stop.store(true, Ordering::SeqCst);
        // The threads are only reachable through the Arc; take them out.
        for l in &self.core.lines {
            if let Backend::InProcess(line) = &l.backend {
                line.close();
            }
        }
        if let Some(core) = Arc::get_mut(&mut self.core) {
            for l in &mut core.lines {
                l.join();
            }
        } else {
            // The control server still holds a reference only if it failed to
            // stop; the threads see the stop flag and remove their links.
            for l in &self.core.lines {
                let _ = std::fs::remove_file(&l.link);
            }
        }
    }
}

impl Drop for SimHandle {
    fn drop(&mut self) {
        self.stop_all();
    }
}

impl crate::control::Injector for Core {
    fn inject(&self, axis: AxisName, fault: Fault) -> Result<(), SimError> {
        Core::inject(self, axis, fault)
    }

    fn true_position_mm(&self, axis: AxisName) -> f64 {
        Core::true_position_mm(self, axis)
    }

    fn sim_time(&self) -> Duration {
        self.clock.now()
    }

    fn rig_truth(&self) -> Option<crate::rig::RigTruth> {
        Some(self.rig.truth(self.clock.now()))
    }

    fn advance(&self, d: Duration) -> Result<(), SimError> {
        if !self.clock.advances_on_request() {
            return Err(SimError::Config(
                "this rig runs on a virtual clock: time advances with the rig's own events, not on request".into(),
            ));
        }
        self.clock.advance(d);
        Ok(())
    }

    fn camera_mode(&self, mode: crate::camera::CameraMode) -> Result<(), SimError> {
        self.camera.set_mode(mode);
        Ok(())
    }

    fn line_axes(&self) -> Vec<AxisName> {
        // One axis per distinct line, so a line fault without an axis hits
        // every line once.
        let mut seen = Vec::new();
        let mut out = Vec::new();
        for axis in AxisName::ALL {
            let l = self.routes[axis.index()].line;
            if !seen.contains(&l) {
                seen.push(l);
                out.push(axis);
            }
        }
        out
    }
}

/// The buses, each axis's route and each line's (axis, link name).
type Wiring = (Vec<Bus>, [Route; 2], Vec<(AxisName, &'static str)>);

/// The buses the two controllers sit on, how each axis is reached, and
/// each line's link name: one daisy-chained line (`bus`), or a line per
/// axis (`x`, `y`).
fn wiring(
    daisy_chain: bool,
    cx: ControllerConfig,
    cy: ControllerConfig,
) -> Result<Wiring, SimError> {
    let route = |line, controller| Route { line, controller };
    Ok(if daisy_chain {
        (
            vec![Bus::new(vec![Controller::new(cx), Controller::new(cy)])?],
            [route(0, 0), route(0, 1)],
            vec![(AxisName::X, "bus")],
        )
    } else {
        (
            vec![
                Bus::new(vec![Controller::new(cx)])?,
                Bus::new(vec![Controller::new(cy)])?,
            ],
            [route(0, 0), route(1, 0)],
            vec![(AxisName::X, "x"), (AxisName::Y, "y")],
        )
    })
}

/// A line served in process (`hil-sim run`, `demo`): no pseudo-terminal.
fn in_process_line(
    axis: AxisName,
    link: PathBuf,
    bus: &Arc<Mutex<Bus>>,
    clock: &Arc<dyn Clock>,
) -> LineCtl {
    let n = lock(bus).controllers().len();
    LineCtl {
        axis,
        link: link.clone(),
        probe: Arc::new(RxProbe::default()),
        backend: Backend::InProcess(Arc::new(crate::vline::InProcessLine::new(
            axis,
            link,
            bus.clone(),
            clock.clone(),
            n,
        ))),
    }
}

/// A line served on a pseudo-terminal whose path is linked at `link`, by
/// a thread of its own. Only our own kind of file is replaced there: a
/// stale symlink.
fn pty_line(
    axis: AxisName,
    name: &str,
    link: PathBuf,
    bus: &Arc<Mutex<Bus>>,
    clock: &Arc<dyn Clock>,
    stop: &Arc<AtomicBool>,
) -> Result<LineCtl, SimError> {
    if let Ok(meta) = std::fs::symlink_metadata(&link) {
        if !meta.file_type().is_symlink() {
            return Err(SimError::Config(format!(
                "{} exists and is not a symlink; refusing to replace it",
                link.display()
            )));
        }
    }
    let pty = Pty::open(&link)?;
    let n = bus
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .controllers()
        .len();
    let probe = Arc::new(RxProbe::default());
    let line = Line {
        axis,
        link: link.clone(),
        pty: Some(pty),
        bus: bus.clone(),
        clock: clock.clone(),
        faults: ReplyFaults::new(n),
        pending: Vec::new(),
        outbox: Vec::new(),
        outbox_since: None,
        probe: probe.clone(),
    };
    let (tx, rx) = mpsc::channel();
    let stop2 = stop.clone();
    let thread = std::thread::Builder::new()
        .name(format!("hil-sim-{name}"))
        .spawn(move || line.run(rx, stop2))
        .map_err(io_err("spawn line thread"))?;
    Ok(LineCtl {
        axis,
        link,
        probe,
        backend: Backend::Pty {
            tx: Mutex::new(tx),
            thread: Some(thread),
        },
    })
}
