//! microposd, the service: owns the two controllers and the camera, serves
//! commands over a local Unix socket (newline-delimited JSON, see
//! `docs/socket-protocol.md`), runs long jobs.
//!
//! Files, one job each:
//! - [`protocol`]: requests and replies, sans-IO (fuzzed);
//! - [`connection`]: splits a byte stream into bounded lines;
//! - [`server`]: accepts clients, one task per client (timeouts, stop
//!   slots, the role check);
//! - [`service`]: the shared parts ([`Daemon`]) and what a command does;
//! - [`access`]: the peer's credentials and role (`[access]`);
//! - [`audit`]: who ran which state-changing command (journal + file);
//! - [`state`]: the safe-state machine (pure; faults latch until `reset`);
//! - [`motion_core`]: the move policy, sans-IO (safe state, stop
//!   generation, commanded targets, soft limits, supervisor and deviation
//!   verdicts), held by the rig under one lock;
//! - [`supervisor`]: judges every move to completion (controller errors,
//!   following error, motion timeout, failing reads; sampled by
//!   `rig::supervise`);
//! - [`rig`]: motion coordinator, soft limits, positions, event bus (one
//!   file per duty; compensation and drift state are its components);
//! - [`vision`]: capture and decoding, never blocking the runtime;
//! - [`vision_tie`]: vision → stage measured after a reference run, kept
//!   across restarts;
//! - [`jobs`]: characterization with resume (and its own camera tie),
//!   validation, `tables build`;
//! - [`comp`]: loaded tables, the active compensator, the motion history;
//! - [`drift`]: the live drift estimate of compensated moves;
//! - [`figures`]: the paper's figures of the newest logs, read-only;
//! - [`config`]: the validated configuration;
//! - [`reload`]: what SIGHUP may change live, and its running values;
//! - [`metrics`]: the rig's counters for `/metrics` (rendered by `web`);
//! - [`notify`]: systemd readiness, status and a health-fed watchdog;
//! - [`web`]: the optional web view and `/metrics` (`[web]`).
//!
//! Shutdown: a running job is cancelled, both axes are halted and waited
//! for (bounded by `safety.halt_wait_s`), then one `broadcast` tells every
//! task; clients get a `shutting_down` error line (the job's log stays
//! resumable).

pub mod access;
pub(crate) mod admission;
pub mod audit;
pub mod comp;
pub mod config;
pub mod connection;
pub mod deviation;
pub mod drift;
pub mod figures;
pub mod jobs;
pub mod metrics;
pub(crate) mod motion_core;
pub mod notify;
pub mod protocol;
pub mod reload;
pub mod rig;
pub mod server;
pub mod service;
pub mod state;
pub mod supervisor;
pub mod vision;
pub mod vision_tie;
pub mod web;

use crate::camera::FrameSource;
use crate::clock::RigClock;
use crate::pattern::decode::DecodeOptions;
pub use service::Daemon;

use config::DaemonConfig;
use protocol::{ErrorCode, ProtoError};
use std::sync::Arc;
use tokio::net::UnixListener;
use tokio::sync::broadcast;

/// Handle to a started daemon.
#[derive(Debug)]
pub struct Running {
    /// The shared parts.
    pub daemon: Arc<Daemon>,
    /// The web listener's bound address (`[web]`), if any.
    pub web_addr: Option<std::net::SocketAddr>,
    tasks: Vec<tokio::task::JoinHandle<()>>,
}

impl Running {
    /// Cancels a job, halts both axes and waits until they are at rest
    /// (bounded: `safety.halt_wait_s`), then asks every task to stop and
    /// waits for them. Why halt: nobody watches the stage once the daemon
    /// is gone, so it must not leave a move running.
    pub async fn shutdown(self) {
        self.daemon.jobs.signal_cancel();
        self.daemon
            .rig
            .halt_and_wait("the daemon is shutting down")
            .await;
        let _ = self.daemon.shutdown.send(());
        for t in self.tasks {
            let _ = t.await;
        }
    }
}

/// What the daemon runs on besides its configuration: the rig's clock, the
/// opened camera, how it captures, and (for the simulator's in-process rig)
/// who opens the controller lines.
///
/// Why a struct the caller fills: the binary passes the hardware's (a wall
/// clock, the configured camera, free-running capture, serial ports); the
/// simulator's in-process rig passes its own (the paused runtime's virtual
/// clock, its camera on demand, in-memory lines), and everything above is
/// the same code.
#[derive(Debug)]
pub struct Environment {
    /// Every wait of jobs and every timestamp.
    pub clock: Arc<dyn RigClock>,
    /// The opened frame source, if any.
    pub camera: Option<Box<dyn FrameSource>>,
    /// How frames are captured.
    pub capture: vision::Capture,
    /// Opens the configured controller ports; `None`: serial devices.
    pub links: Option<Arc<dyn crate::driver::LinkOpener>>,
}

impl Environment {
    /// Hardware: `clock`, `camera`, free-running capture, serial ports.
    pub fn hardware(clock: Arc<dyn RigClock>, camera: Option<Box<dyn FrameSource>>) -> Self {
        Environment {
            clock,
            camera,
            capture: vision::Capture::FreeRunning,
            links: None,
        }
    }
}

impl Daemon {
    /// Starts the rig tasks and the server on `listener`. `camera` is the
    /// opened frame source, if any (the caller opens it so tests can pass
    /// their own).
    pub fn start(
        cfg: DaemonConfig,
        clock: Arc<dyn RigClock>,
        camera: Option<Box<dyn FrameSource>>,
        listener: UnixListener,
    ) -> Result<Running, ProtoError> {
        Self::start_in(cfg, Environment::hardware(clock, camera), listener)
    }

    /// Starts the daemon in `env` (see [`Environment`]).
    pub fn start_in(
        cfg: DaemonConfig,
        env: Environment,
        listener: UnixListener,
    ) -> Result<Running, ProtoError> {
        let Environment {
            clock,
            camera,
            capture,
            links,
        } = env;
        // Bound before anything starts: a bad address or token file stops
        // the daemon with a message instead of leaving it half up.
        let web = cfg.web.as_ref().map(web::bind).transpose()?;
        let web_addr = web.as_ref().map(|w| w.addr);
        let vision = match camera {
            Some(src) => {
                let mut opts = DecodeOptions::new(cfg.camera.period_um, cfg.camera.bits);
                opts.mirrored = cfg.camera.mirrored;
                opts.pixel_um = cfg.camera.pixel_um;
                Some(
                    vision::Vision::start_with(src, opts, clock.clone(), capture).map_err(|e| {
                        ProtoError::new(ErrorCode::CameraUnavailable, e.to_string())
                    })?,
                )
            }
            None => None,
        };
        let (shutdown, _) = broadcast::channel(4);
        let access = access::Access::new(cfg.access.clone());
        let audit = audit::Audit::start_limited(
            &cfg.daemon.data_dir,
            audit::journal_socket(),
            cfg.audit.clone(),
        );
        let rig = Arc::new(rig::Rig::new(cfg, clock, vision, links));
        let daemon = Arc::new(Daemon {
            rig: rig.clone(),
            jobs: jobs::Jobs::default(),
            shutdown: shutdown.clone(),
            access,
            audit,
        });
        let mut tasks = vec![
            tokio::spawn(rig.clone().restore_tie()),
            tokio::spawn(rig.clone().connect_loop(shutdown.subscribe())),
            tokio::spawn(rig.clone().poll_loop(shutdown.subscribe())),
            tokio::spawn(rig::supervise::run(rig.clone(), shutdown.subscribe())),
            tokio::spawn(rig.clone().vision_stream_loop(shutdown.subscribe())),
            tokio::spawn(server::serve(
                daemon.clone(),
                listener,
                shutdown.subscribe(),
            )),
        ];
        if let Some(w) = web {
            tasks.push(tokio::spawn(web::serve(daemon.clone(), w)));
        }
        Ok(Running {
            daemon,
            web_addr,
            tasks,
        })
    }
}
