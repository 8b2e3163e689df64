//! microposd, the service: owns the two controllers and the camera, serves
//! commands over a local Unix socket (newline-delimited JSON, see
//! `docs/socket-protocol.md`), runs long jobs.
//!
//! Files, one job each:
//! - [`protocol`]: requests and replies, sans-IO (fuzzed);
//! - [`connection`]: splits a byte stream into bounded lines;
//! - [`server`]: accepts clients, one task per client (timeouts, stop
//!   slots, the role check);
//! - [`access`]: the peer's credentials and role (`[access]`);
//! - [`audit`]: who ran which state-changing command (journal + file);
//! - [`state`]: the safe-state machine (pure; faults latch until `reset`);
//! - [`supervisor`]: watches every move to completion (controller errors,
//!   following error, motion timeout, failing reads);
//! - [`rig`]: motion coordinator, soft limits, positions, event bus;
//! - [`vision`]: capture and decoding, never blocking the runtime;
//! - [`jobs`]: characterization with resume (and its own camera tie),
//!   validation, `tables build`;
//! - [`drift`]: live drift correction of compensated moves;
//! - [`figures`]: the paper's figures of the newest logs, read-only;
//! - [`config`]: the validated configuration;
//! - [`reload`]: what SIGHUP may change live, and its running values;
//! - [`notify`]: systemd readiness, status and a health-fed watchdog;
//! - [`web`]: the optional web view and `/metrics` (`[web]`).
//!
//! Shutdown: a running job is cancelled, both axes are halted and waited
//! for (bounded by `safety.halt_wait_s`), then one `broadcast` tells every
//! task; clients get a `shutting_down` error line (the job's log stays
//! resumable).

pub mod access;
pub mod audit;
pub mod comp;
pub mod config;
pub mod connection;
pub mod deviation;
pub mod drift;
pub mod figures;
pub mod jobs;
pub mod notify;
pub mod protocol;
pub mod reload;
pub mod rig;
pub mod server;
pub mod state;
pub mod supervisor;
pub mod vision;
pub mod web;

use crate::camera::FrameSource;
use crate::clock::RigClock;
use crate::pattern::decode::DecodeOptions;
use config::DaemonConfig;
use protocol::{
    CharacterizeAction, Command, DriftAction, ErrorCode, ProtoError, TablesAction, ValidateAction,
};
use serde_json::{json, Value};
use std::sync::Arc;
use tokio::net::UnixListener;
use tokio::sync::broadcast;

/// The running daemon's shared parts.
#[derive(Debug)]
pub struct Daemon {
    /// The rig.
    pub rig: Arc<rig::Rig>,
    /// Jobs.
    pub jobs: jobs::Jobs,
    /// Sends shutdown to every task.
    pub shutdown: broadcast::Sender<()>,
    /// Client roles (`[access]`, reloadable).
    pub access: access::Access,
    /// The audit trail of state-changing commands.
    pub audit: audit::Audit,
}

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
        let audit = audit::Audit::start(&cfg.daemon.data_dir);
        let rig = Arc::new(rig::Rig::new(cfg, clock, vision, links));
        let daemon = Arc::new(Daemon {
            rig: rig.clone(),
            jobs: jobs::Jobs::default(),
            shutdown: shutdown.clone(),
            access,
            audit,
        });
        let mut tasks = vec![
            tokio::spawn(rig.clone().connect_loop(shutdown.subscribe())),
            tokio::spawn(rig.clone().poll_loop(shutdown.subscribe())),
            tokio::spawn(supervisor::run(rig.clone(), shutdown.subscribe())),
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

    /// Executes one command (everything but `subscribe`, which the server
    /// handles per connection).
    pub async fn execute(&self, cmd: Command) -> Result<Value, ProtoError> {
        let rig = &self.rig;
        match cmd {
            Command::Version => Ok(json!({
                "daemon": env!("CARGO_PKG_VERSION"),
                "protocol": protocol::PROTOCOL_VERSION,
                "commands": protocol::COMMANDS,
            })),
            Command::Status => {
                let mut s = rig.status();
                s["job"] = self.jobs.status();
                Ok(s)
            }
            Command::Drift(a) => self.drift(a).await,
            Command::Position => Ok(rig.position().await),
            Command::Move(m) => rig.move_to(&m, false).await,
            Command::Stop => {
                self.jobs.signal_cancel();
                rig.stop().await
            }
            Command::Reset => Ok(rig.reset()),
            Command::Reference(axes) => rig.reference(axes).await,
            Command::Config => serde_json::to_value(self.effective_config())
                .map(|c| json!({"config": c}))
                .map_err(|e| ProtoError::new(ErrorCode::Internal, e.to_string())),
            Command::Characterize(a) => match a {
                CharacterizeAction::Start(p) => self.jobs.start(rig, p).await,
                CharacterizeAction::Resume { log } => self.jobs.resume(rig, &log).await,
                CharacterizeAction::Status => Ok(json!({"job": self.jobs.status()})),
                CharacterizeAction::Cancel => self.cancel_job().await,
            },
            Command::Validate(v) => match v {
                ValidateAction::Status => Ok(self.jobs.validation_status()),
                ValidateAction::Start(p) => self.jobs.start_validation(rig, p).await,
                ValidateAction::Cancel => self.cancel_job().await,
            },
            Command::Tables(t) => match t {
                TablesAction::List => rig.comp.list(&rig.cfg.daemon.data_dir).await,
                TablesAction::Load { name } => rig.comp.load(&rig.cfg.daemon.data_dir, &name).await,
                TablesAction::Activate { name } => rig.comp.activate(name.as_deref()),
                TablesAction::Build(p) => jobs::tables::build(rig, p).await,
            },
            Command::Figures(p) => figures::figures(&rig.cfg.daemon.data_dir, p).await,
            Command::Subscribe(_) => Err(ProtoError::new(
                ErrorCode::Internal,
                "subscribe is handled by the connection",
            )),
        }
    }

    /// The configuration in force: the file read at start with the
    /// running values of the reloadable sections.
    pub fn effective_config(&self) -> DaemonConfig {
        let mut c = self.rig.live.effective(&self.rig.cfg);
        c.access = self.access.current();
        c
    }

    /// Applies a reloaded configuration (SIGHUP): the changed keys of the
    /// reloadable sections take effect (limits and compensation from the
    /// next move, drift settings now, roles for new connections); other
    /// changed keys keep their running values and are reported as refused.
    /// A client's `drift set` survives a reload that leaves `[drift]`
    /// unchanged in the file.
    pub fn reload(&self, new: &DaemonConfig) -> reload::ReloadReport {
        let running = self.effective_config();
        let (applied, refused): (Vec<String>, Vec<String>) = reload::diff_keys(&running, new)
            .into_iter()
            .partition(|k| reload::is_reloadable(k));
        let changed = |section: &str| {
            applied
                .iter()
                .any(|k| k == section || k.starts_with(&format!("{section}.")))
        };
        let mut merged = running;
        merged.limits = new.limits;
        merged.compensation = new.compensation.clone();
        merged.drift = new.drift.clone();
        self.rig.live.set(&merged);
        if changed("drift") {
            let d = &new.drift;
            if let Err(e) = self.rig.drift.set(
                &merged,
                Some(d.method),
                Some(d.every_s),
                Some(d.time_constant_s),
            ) {
                tracing::warn!("reload: [drift] not applied: {e}");
            }
        }
        if changed("access") {
            self.access.set(new.access.clone());
        }
        reload::ReloadReport { applied, refused }
    }

    /// `characterize|validate cancel`: ends the job and halts both axes
    /// (waiting until they are at rest): the job's move in flight is
    /// dropped with its future, and the stage must not finish it alone.
    async fn cancel_job(&self) -> Result<Value, ProtoError> {
        self.jobs.signal_cancel();
        let halt = self.rig.halt_and_wait("job cancelled").await;
        let job = self.jobs.cancel().await?;
        Ok(json!({"job": job, "halt": halt}))
    }

    /// `drift show|set|reset|measure`.
    async fn drift(&self, a: DriftAction) -> Result<Value, ProtoError> {
        let rig = &self.rig;
        let mut out = json!({});
        match a {
            DriftAction::Show => {}
            DriftAction::Set {
                method,
                every_s,
                time_constant_s,
            } => rig.drift.set(&rig.cfg, method, every_s, time_constant_s)?,
            DriftAction::Reset => rig.drift.reset(),
            DriftAction::Measure => {
                if self.jobs.is_running() {
                    return Err(ProtoError::new(
                        ErrorCode::Busy,
                        "a job is running; it re-measures the reference itself",
                    ));
                }
                let active = rig.comp.active().ok_or_else(|| {
                    ProtoError::new(
                        ErrorCode::NoActiveTable,
                        "drift is measured against the active table's baseline: tables activate NAME",
                    )
                })?;
                let k = &rig.cfg.characterize;
                let r = rig
                    .drift_measure(&active, k.frames_per_point, k.settle_s, false)
                    .await?;
                out["measured"] = json!(r.sample);
            }
        }
        out["drift"] = rig.drift.to_json(rig.clock.now_s());
        Ok(out)
    }
}
