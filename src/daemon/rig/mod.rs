//! The rig as the daemon sees it: the stage (once connected), the safe-state
//! machine, the motion coordinator (one move at a time per stage, `stop`
//! overtakes the queue), soft limits, positions from every source, and the
//! event bus to subscribers.
//!
//! Halting: a fault (from the driver, a failed wait, the motion supervisor
//! of `daemon::supervisor`) halts both axes and latches; `reset` clears the
//! latch; [`Rig::halt_and_wait`] halts and waits (bounded) until both axes
//! are at rest (shutdown, job cancel); a line that comes back has its axis
//! halted and read back before anything else ([`Rig::recover_axis`]).

//!
//! Files, one job each (each adds methods to [`Rig`] or takes it as an
//! argument; this file holds the rig's state and its status):
//! - [`safety`]: the safe state carried out (halts, faults, reset,
//!   recovery) and the vision deviation check;
//! - [`tasks`]: connecting the lines, driver events, the poller, the
//!   camera's frames to subscribers;
//! - [`supervise`]: the motion supervisor's sampling task;
//! - [`motion`]: the motion coordinator (raw and planned moves, `stop`);
//! - [`closed_loop`]: the closed-loop runner of `closed_loop` moves;
//! - [`drift`]: re-measuring the drift reference, a move's correction;
//! - [`measure`]: the park approach, averaged frames, retried moves;
//! - [`job`]: a job's ownership of the axes, retries after transient faults;
//! - [`reference`](mod@reference): the reference run;
//! - [`tie`](mod@tie): the vision → stage frame in force (the rig's tie,
//!   else the active table's) and the tie's file.
//!
//! The move policy itself (the safe state, the stop generation and its
//! reason, the commanded targets, soft limits, the supervisor's and the
//! deviation judge's verdicts) is `daemon::motion_core::MotionCore`,
//! sans-IO and unit-tested; the rig holds it under one lock and carries
//! out its decisions through the driver.
//!
//! Locks, in the order they may be taken (never the other way round):
//! 1. `motion` (tokio): one move or reference run at a time per stage,
//!    held across the driver's I/O of a move;
//! 2. `sampling` (tokio): the supervisor and the poller while they read
//!    positions; a reference run takes (and drops) it after `motion`;
//! 3. `core` (std): the [`MotionCore`]; a leaf: held only for a call
//!    into it, never across an `.await`, and nothing else is locked or
//!    called out to (events, logs, the driver) while it is held — the
//!    inputs it needs from elsewhere (the vision frame in force, the
//!    soft limits) are read before taking it.
//!
//! `stage`, `tie` and the locks inside `comp`, `drift`, `live`, `vision`
//! and `metrics` are leaves too: each held for one read or write, none
//! while another lock is held.

pub mod closed_loop;
pub mod drift;
pub mod job;
pub mod measure;
pub mod motion;
pub mod reference;
pub mod safety;
pub mod supervise;
pub mod tasks;
pub mod tie;
mod tool;

use super::config::DaemonConfig;
use super::motion_core::MotionCore;
use super::protocol::{
    to_value, ControllerPosition, ErrorCode, Event, Limits, PairUm, PerAxis, PositionReply,
    ProtoError, ReadErrors, StatusReply, ToolsStatus, Topic,
};
use super::state::{Activity, AxisId};
use super::supervisor::Bounds;
use super::vision::{Measurement, Vision};
use crate::clock::RigClock;
use crate::driver::{DriverError, Stage};
use serde_json::{Map, Value};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use tokio::sync::broadcast;

/// An event for subscribers, serialized once for all of them.
#[derive(Debug, Clone)]
pub struct Pushed {
    /// Its topic (subscribers filter on it).
    pub topic: Topic,
    /// The complete line, newline included.
    pub line: Arc<str>,
}

/// The rig. Shared by every task through an `Arc`.
#[derive(Debug)]
pub struct Rig {
    /// The validated configuration.
    pub cfg: DaemonConfig,
    /// The rig's clock: every wait and timestamp goes through it.
    pub clock: Arc<dyn RigClock>,
    stage: Mutex<Option<Stage>>,
    /// The move policy (safe state, stop generation, commanded targets,
    /// supervisor, deviation judge, last polled positions): one lock for
    /// all of it, so a decision sees one consistent state.
    core: Mutex<MotionCore>,
    /// One move (or reference run) at a time per stage.
    motion: tokio::sync::Mutex<()>,
    /// Vision → stage, measured after the reference run
    /// (`daemon::vision_tie`).
    tie: Mutex<super::vision_tie::VisionTie>,
    /// Held by the supervisor and the position poller while they read
    /// positions: a reference run takes it after it owns the axes, so no
    /// read begun before the run ends after it began (its `FRF?` would read
    /// the run as a lost reference, its `POS?` a count the run is about to
    /// change, taken for fresh), and none begins during it.
    pub(super) sampling: tokio::sync::Mutex<()>,
    events: broadcast::Sender<Pushed>,
    /// The camera pipeline, if a camera is configured.
    pub vision: Option<Vision>,
    /// Bumped by the position poller on every healthy round: the watchdog
    /// is only fed while it moves.
    pub heartbeat: AtomicU64,
    /// Compensation tables, the active compensator, the motion history.
    pub comp: super::comp::CompState,
    /// Live drift correction (`[drift]`, the `drift` command).
    pub drift: super::drift::DriftControl,
    /// Running values of the settings a reload may change (limits,
    /// compensation, drift); read these, not `cfg`'s.
    pub live: super::reload::Live,
    /// Retries after transient faults in the current (or last) job, reset
    /// when a job begins; the job's progress reads it (`retries`).
    pub job_retries: Arc<AtomicU64>,
    /// Opens the controller lines instead of serial devices (the
    /// simulator's in-process rig); `None` on hardware.
    links: Option<Arc<dyn crate::driver::LinkOpener>>,
    /// Counters for `/metrics` (moves, faults, reconnects, …).
    pub metrics: super::metrics::Metrics,
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

/// Ends an activity in the state machine when dropped (also on error or
/// cancellation of the future).
struct ActivityGuard<'a> {
    rig: &'a Rig,
    activity: Activity,
}

impl Drop for ActivityGuard<'_> {
    fn drop(&mut self) {
        let t = self.rig.clock.now_s();
        self.rig.core().end(self.activity, t);
    }
}

/// Maps a driver error to a protocol error with a stable code.
pub fn driver_error(e: DriverError) -> ProtoError {
    let code = match &e {
        DriverError::OutOfTravel { .. } => ErrorCode::OutOfTravel,
        // The driver's own advice names the direct CLI (`micropos axes`),
        // which would fight microposd for the ports: through the daemon
        // the reference is the daemon's command.
        DriverError::NotReferenced { axis } => {
            return ProtoError::new(
                ErrorCode::NotReferenced,
                format!(
                    "axis {axis} is not referenced (power cycle or never referenced): its position is unknown; send reference first (CLI: `micropos reference {axis}`)"
                ),
            )
        }
        DriverError::Halted { .. } => ErrorCode::Halted,
        e if e.is_link_fault() => ErrorCode::NotConnected,
        _ => ErrorCode::DriverError,
    };
    let p = ProtoError::new(code, e.to_string());
    if e.is_transient() {
        p.into_transient()
    } else {
        p
    }
}

impl Rig {
    /// A rig with no stage yet.
    pub fn new(
        cfg: DaemonConfig,
        clock: Arc<dyn RigClock>,
        vision: Option<Vision>,
        links: Option<Arc<dyn crate::driver::LinkOpener>>,
    ) -> Rig {
        let (events, _) = broadcast::channel(1024);
        let drift = super::drift::DriftControl::new(&cfg);
        let metrics = super::metrics::Metrics::new(vision.as_ref().map(|v| &*v.stats));
        let core = MotionCore::new(
            Bounds {
                following_error_um: cfg.safety.following_error_um,
                read_fail_s: cfg.safety.read_fail_s,
                motion_timeout_s: [cfg.driver.x.motion_timeout_s, cfg.driver.y.motion_timeout_s],
            },
            cfg.safety.deviation_um,
        );
        Rig {
            core: Mutex::new(core),
            tie: Mutex::default(),
            sampling: tokio::sync::Mutex::new(()),
            drift,
            live: super::reload::Live::new(&cfg),
            cfg,
            clock,
            stage: Mutex::new(None),
            motion: tokio::sync::Mutex::new(()),
            events,
            vision,
            heartbeat: AtomicU64::new(0),
            comp: super::comp::CompState::default(),
            job_retries: Arc::default(),
            links,
            metrics,
        }
    }

    /// A receiver of every pushed event.
    pub fn subscribe(&self) -> broadcast::Receiver<Pushed> {
        self.events.subscribe()
    }

    /// Pushes an event to subscribers of `topic`.
    pub fn push(&self, topic: Topic, name: &str, fields: Value) {
        let fields = match fields {
            Value::Object(m) => m,
            _ => Map::new(),
        };
        let line = super::protocol::event_line(name, fields);
        // No subscriber is fine.
        let _ = self.events.send(Pushed {
            topic,
            line: line.into(),
        });
    }

    /// Pushes a typed event on its topic ([`Event`]).
    pub fn emit<E: Event>(&self, event: &E) {
        self.push(E::TOPIC, E::NAME, to_value(event));
    }

    /// The motion core, locked: hold it for one call, never across an
    /// `.await`, and lock nothing else meanwhile.
    pub(super) fn core(&self) -> std::sync::MutexGuard<'_, MotionCore> {
        lock(&self.core)
    }

    /// The stage, once connected.
    pub(super) fn connected_stage(&self) -> Option<Stage> {
        lock(&self.stage).clone()
    }

    /// Whether a reference run owns the axes.
    pub(super) fn referencing(&self) -> bool {
        self.core().state().activity() == Activity::Referencing
    }

    /// Feeds the watchdog heartbeat: the rig is supervised.
    pub(super) fn beat(&self) {
        self.heartbeat.fetch_add(1, Ordering::Relaxed);
    }

    pub(crate) fn stage(&self) -> Result<Stage, ProtoError> {
        let stage = lock(&self.stage).clone();
        stage.ok_or_else(|| {
            // Why, as `status` says it (the last failed attempt), not only
            // in the daemon's log.
            let why = self.core().state().not_connected_because();
            ProtoError::new(ErrorCode::NotConnected, format!("{why}; see status"))
        })
    }

    /// Positions from every source, each named, with its time.
    pub async fn position(&self) -> PositionReply {
        let commanded = self.commanded_um();
        let mut controller = None;
        if let Ok(stage) = self.stage() {
            let t = self.clock.now_s();
            let (x, y) = tokio::join!(stage.x.position_um(), stage.y.position_um());
            let err = |r: &Result<f64, DriverError>| r.as_ref().err().map(|e| e.to_string());
            controller = Some(ControllerPosition {
                t_s: t,
                x_um: x.as_ref().ok().copied(),
                y_um: y.as_ref().ok().copied(),
                errors: Some(ReadErrors {
                    x_error: err(&x),
                    y_error: err(&y),
                }),
            });
        } else {
            let r = self.core().reported();
            if r.x_um.is_some() || r.y_um.is_some() {
                controller = Some(ControllerPosition {
                    t_s: r.t_s,
                    x_um: r.x_um,
                    y_um: r.y_um,
                    errors: None,
                });
            }
        }
        let vision = self.vision.as_ref().and_then(|v| {
            let m = (*v.latest.borrow())?;
            let mut j = self.vision_position(&m);
            j.age_s = Some(self.clock.now_s() - m.t_s);
            Some(j)
        });
        PositionReply {
            commanded: PairUm::of(commanded),
            controller,
            vision,
        }
    }

    /// The commanded position `[x, y]` µm (what the last move asked).
    pub fn commanded_um(&self) -> [Option<f64>; 2] {
        self.core().commanded()
    }

    /// The controllers' positions as last polled: `(t_s, x_um, y_um)`.
    pub fn reported_um(&self) -> (f64, Option<f64>, Option<f64>) {
        let r = self.core().reported();
        (r.t_s, r.x_um, r.y_um)
    }

    /// `status` but its `job`, which the jobs add.
    pub fn status(&self) -> StatusReply {
        // The state first, then the stage: the connect task records the
        // stage up in the state just before it hands the stage out, and a
        // client that reads "connected" must find the stage there for its
        // next command (seen: `reference` refused `not_connected` right
        // after `status` said connected). Until the hand-out, not connected.
        let mut rig = self.core().state().to_reply();
        let stage = lock(&self.stage).clone();
        if stage.is_none() {
            rig.connected = PerAxis::of([false, false]);
        }
        let travel = stage.map(|s| {
            let (xl, xh) = self.limits_um(&s.x, AxisId::X);
            let (yl, yh) = self.limits_um(&s.y, AxisId::Y);
            Limits {
                x_um: [xl, xh],
                y_um: [yl, yh],
            }
        });
        StatusReply {
            t_s: self.clock.now_s(),
            rig,
            limits: travel,
            camera: self.vision.as_ref().map(|v| v.to_reply()),
            drift: self.drift.to_json(self.clock.now_s()),
            deviation: self.deviation_status(),
            vision_tie: self.tie_status(),
            job: None,
            tools: (!self.cfg.tools.points.is_empty()).then(|| ToolsStatus {
                active: self.cfg.tools.active.clone(),
                offsets_um: self
                    .cfg
                    .tools
                    .points
                    .iter()
                    .map(|(n, p)| (n.clone(), p.offset_um))
                    .collect(),
            }),
        }
    }

    /// The newest vision measurement if it is fresh and good enough.
    pub fn fresh_measurement(&self, newer_than_s: f64) -> Result<Option<Measurement>, ProtoError> {
        let Some(v) = &self.vision else {
            return Err(ProtoError::new(
                ErrorCode::CameraUnavailable,
                "no camera is configured (camera.source)",
            ));
        };
        let m = *v.latest.borrow();
        Ok(m.filter(|m| m.t_s > newer_than_s && m.quality >= self.cfg.camera.min_quality))
    }
}
