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

use super::config::DaemonConfig;
use super::deviation::DeviationJudge;
use super::protocol::{Axes, ErrorCode, MoveMode, MoveRequest, ProtoError, Topic};
use super::state::{Action, Activity, AxisId, Input, Refusal, SafetyState};
use super::supervisor::{Bounds, ReadFailure, Supervisor};
use super::vision::{Measurement, Vision};
use crate::clock::RigClock;
use crate::driver::{Axis, AxisEvent, DriverError, Stage};
use serde_json::{json, Map, Value};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tokio::sync::broadcast;

/// An event for subscribers, serialized once for all of them.
#[derive(Debug, Clone)]
pub struct Pushed {
    /// Its topic (subscribers filter on it).
    pub topic: Topic,
    /// The complete line, newline included.
    pub line: Arc<str>,
}

/// Positions last read from the controllers.
#[derive(Debug, Clone, Copy, Default)]
struct Reported {
    t_s: f64,
    x_um: Option<f64>,
    y_um: Option<f64>,
}

/// The rig. Shared by every task through an `Arc`.
#[derive(Debug)]
pub struct Rig {
    /// The validated configuration.
    pub cfg: DaemonConfig,
    /// The rig's clock: every wait and timestamp goes through it.
    pub clock: Arc<dyn RigClock>,
    stage: Mutex<Option<Stage>>,
    state: Mutex<SafetyState>,
    commanded: Mutex<[Option<f64>; 2]>,
    reported: Mutex<Reported>,
    motion: tokio::sync::Mutex<()>,
    stop_gen: AtomicU64,
    supervisor: Mutex<Supervisor>,
    /// Vision against controller (`daemon::deviation`).
    deviation: Mutex<DeviationJudge>,
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
    pub metrics: super::web::metrics::Metrics,
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
        lock(&self.rig.state).apply(Input::End(self.activity), t);
    }
}

/// Maps a driver error to a protocol error with a stable code.
pub fn driver_error(e: DriverError) -> ProtoError {
    let code = match &e {
        DriverError::OutOfTravel { .. } => ErrorCode::OutOfTravel,
        DriverError::NotReferenced { .. } => ErrorCode::NotReferenced,
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

fn refusal(r: Refusal) -> ProtoError {
    match r {
        Refusal::NotConnected(m) => ProtoError::new(ErrorCode::NotConnected, m),
        Refusal::NotReferenced(a) => ProtoError::new(
            ErrorCode::NotReferenced,
            format!("axis {} is not referenced; send reference first", a.name()),
        ),
        Refusal::Busy(a) => ProtoError::new(
            ErrorCode::Busy,
            format!("the axes are busy ({a:?}); stop it or wait"),
        ),
        Refusal::FaultLatched(m) => ProtoError::new(
            ErrorCode::FaultLatched,
            format!("a fault is latched ({m}); find its cause, then send reset"),
        ),
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
        let metrics = super::web::metrics::Metrics::new(vision.as_ref().map(|v| &*v.stats));
        let supervisor = Supervisor::new(Bounds {
            following_error_um: cfg.safety.following_error_um,
            read_fail_s: cfg.safety.read_fail_s,
            motion_timeout_s: [cfg.driver.x.motion_timeout_s, cfg.driver.y.motion_timeout_s],
        });
        Rig {
            supervisor: Mutex::new(supervisor),
            deviation: Mutex::new(DeviationJudge::new(cfg.safety.deviation_um)),
            sampling: tokio::sync::Mutex::new(()),
            drift,
            live: super::reload::Live::new(&cfg),
            cfg,
            clock,
            stage: Mutex::new(None),
            state: Mutex::new(SafetyState::new()),
            commanded: Mutex::new([None, None]),
            reported: Mutex::new(Reported::default()),
            motion: tokio::sync::Mutex::new(()),
            stop_gen: AtomicU64::new(0),
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

    /// The motion supervisor's judge (`daemon::supervisor`).
    pub(super) fn supervisor(&self) -> std::sync::MutexGuard<'_, Supervisor> {
        lock(&self.supervisor)
    }

    /// The stage, once connected.
    pub(super) fn connected_stage(&self) -> Option<Stage> {
        lock(&self.stage).clone()
    }

    /// Whether a reference run owns the axes.
    pub(super) fn referencing(&self) -> bool {
        lock(&self.state).activity() == Activity::Referencing
    }

    /// The vision → stage orientation for the deviation check: the active
    /// table's frame, else with `safety.deviation_frame = "camera"` the
    /// configured camera rotation, else none (no check).
    fn deviation_frame(&self) -> Option<crate::comp::VisionFrame> {
        self.vision.as_ref()?;
        if let Some(f) = self.comp.active().and_then(|a| a.frame) {
            return Some(f);
        }
        (self.cfg.safety.deviation_frame == super::config::DeviationFrame::Camera).then_some(
            crate::comp::VisionFrame {
                rotation_rad: self.cfg.camera.rotation_rad,
                mirrored: false,
                translation_um: [0.0, 0.0],
            },
        )
    }

    /// A controller position read of `axis` between `t0_s` and `t1_s`
    /// (poller or supervisor): input of the deviation check.
    pub(super) fn deviation_read(self: &Arc<Self>, axis: AxisId, t0_s: f64, t1_s: f64, um: f64) {
        lock(&self.deviation).controller(axis, t0_s, t1_s, um);
        self.judge_deviation();
    }

    /// Judges the frames that can be judged; a breach is a fault.
    fn judge_deviation(self: &Arc<Self>) {
        let frame = self.deviation_frame();
        // A tie needs both axes at rest: no move watched and no reference
        // run (the judge also wants the reads around the frame to agree).
        let quiet = self.supervisor().watching() == [false, false] && !self.referencing();
        let r = {
            let mut j = lock(&self.deviation);
            j.set_frame(frame);
            j.judge(quiet)
        };
        if let Some(tie) = r.tied_um {
            tracing::info!(
                "vision deviation check tied at rest: translation x {:.1} µm, y {:.1} µm",
                tie[0],
                tie[1]
            );
        }
        if let Some(reason) = r.fault {
            self.supervisor_fault(reason);
        }
    }

    /// The deviation check's state (for `status`).
    pub fn deviation_json(&self) -> Value {
        lock(&self.deviation).to_json()
    }

    /// Feeds the watchdog heartbeat: the rig is supervised.
    pub(super) fn beat(&self) {
        self.heartbeat.fetch_add(1, Ordering::Relaxed);
    }

    /// A breach found by the motion supervisor: halts both axes, latches.
    pub(super) fn supervisor_fault(self: &Arc<Self>, reason: String) {
        tracing::error!("motion supervisor: {reason}");
        self.apply(Input::Fault(reason));
    }

    pub(crate) fn stage(&self) -> Result<Stage, ProtoError> {
        lock(&self.stage).clone().ok_or_else(|| {
            ProtoError::new(
                ErrorCode::NotConnected,
                "the controllers are not connected (yet); see status",
            )
        })
    }

    /// Feeds the state machine and carries out what it asks.
    pub fn apply(self: &Arc<Self>, input: Input) {
        let t = self.clock.now_s();
        let actions = lock(&self.state).apply(input, t);
        for a in actions {
            match a {
                Action::HaltAll { reason } => {
                    tracing::warn!("halting both axes: {reason}");
                    self.metrics.record_fault();
                    self.stop_gen.fetch_add(1, Ordering::SeqCst);
                    self.supervisor().clear();
                    self.push(
                        Topic::Fault,
                        "fault",
                        json!({"t_s": t, "reason": reason, "latched": true}),
                    );
                    let rig = self.clone();
                    tokio::spawn(async move {
                        let r = rig.wait_at_rest(rig.halt_all().await).await;
                        tracing::warn!("after the fault: {r}");
                    });
                }
            }
        }
    }

    /// Halts both axes at once (`HLT` ahead of each line's queue:
    /// [`Axis::halt_now`]); errors (a dead line) are logged, not fatal.
    async fn halt_all(&self) -> Vec<(AxisId, Result<(), DriverError>)> {
        let Ok(stage) = self.stage() else {
            return vec![];
        };
        self.supervisor().clear();
        let (x, y) = tokio::join!(stage.x.halt_now(), stage.y.halt_now());
        let mut out = vec![(AxisId::X, x), (AxisId::Y, y)];
        for (a, r) in &mut out {
            if let Err(e) = r {
                tracing::warn!("halt of axis {} failed: {e}", a.name());
            }
        }
        *lock(&self.commanded) = [None, None];
        out
    }

    /// Halts both axes (`HLT`, after overtaking queued moves and stopping
    /// the supervisor's watches) and waits until both report no motion
    /// (`#5`) or `safety.halt_wait_s` passed. Why wait: a shutdown or a
    /// job cancel must not return while the stage still moves; a smooth
    /// halt decelerates, it does not stop at once. `why` goes to the log
    /// and to `fault` subscribers (`halted` event).
    pub async fn halt_and_wait(&self, why: &str) -> Value {
        self.stop_gen.fetch_add(1, Ordering::SeqCst);
        tracing::warn!("halting both axes: {why}");
        let t = self.clock.now_s();
        let halts = self.halt_all().await;
        let mut r = self.wait_at_rest(halts).await;
        r["reason"] = json!(why);
        self.push(
            Topic::Fault,
            "halted",
            json!({"t_s": t, "reason": why, "at_rest": r["at_rest"], "wait_s": r["wait_s"]}),
        );
        tracing::info!("halt ({why}): {r}");
        r
    }

    /// Polls `#5` on both axes until neither moves, at most
    /// `safety.halt_wait_s` (tokio's timer: the wait must not advance a
    /// simulated rig's clock). `halts`: what the halts returned.
    async fn wait_at_rest(&self, halts: Vec<(AxisId, Result<(), DriverError>)>) -> Value {
        let errors: Vec<String> = halts
            .iter()
            .filter_map(|(a, r)| r.as_ref().err().map(|e| format!("axis {}: {e}", a.name())))
            .collect();
        let Ok(stage) = self.stage() else {
            return json!({"at_rest": false, "wait_s": 0.0, "errors": ["not connected"]});
        };
        let t0 = tokio::time::Instant::now();
        let bound = Duration::try_from_secs_f64(self.cfg.safety.halt_wait_s).unwrap_or_default();
        let step = Duration::from_millis(self.cfg.driver.x.poll_interval_ms.max(5));
        let moving = loop {
            let (x, y) = tokio::join!(stage.x.is_moving(), stage.y.is_moving());
            // An axis that does not answer is not known to be at rest.
            let moving = [x.unwrap_or(true), y.unwrap_or(true)];
            if moving == [false, false] || t0.elapsed() >= bound {
                break moving;
            }
            tokio::time::sleep(step).await;
        };
        json!({"at_rest": moving == [false, false],
               "moving": {"x": moving[0], "y": moving[1]},
               "wait_s": t0.elapsed().as_secs_f64(), "errors": errors})
    }

    /// `reset`: acknowledges the latched fault. Motion is allowed again
    /// (an axis whose reference was lost stays unreferenced: reference it).
    pub fn reset(&self) -> Value {
        let t = self.clock.now_s();
        let mut s = lock(&self.state);
        let cleared = s
            .latched()
            .map(|f| json!({"t_s": f.t_s, "reason": f.reason}));
        s.apply(Input::Reset, t);
        let state = s.to_json();
        drop(s);
        lock(&self.deviation).retie();
        if let Some(c) = &cleared {
            tracing::info!("fault reset by a client: {}", c["reason"]);
            self.push(Topic::Fault, "reset", json!({"t_s": t, "cleared": c}));
        }
        json!({"cleared": cleared, "rig": state})
    }

    /// A line came back: its axis is halted (the controller kept running
    /// while nobody could reach it) and read back (`status`) before
    /// anything else; the line loss stays latched until `reset`.
    async fn recover_axis(self: Arc<Self>, a: AxisId) {
        let Ok(stage) = self.stage() else { return };
        let axis = match a {
            AxisId::X => stage.x.clone(),
            AxisId::Y => stage.y.clone(),
        };
        let t = self.clock.now_s();
        let halt = axis.halt().await;
        let status = axis.status().await;
        let fields = match (&halt, &status) {
            (Ok(()), Ok(s)) => json!({"t_s": t, "axis": a.name(), "halted": true,
                "referenced": s.referenced, "servo_on": s.servo_on, "on_target": s.on_target,
                "position_um": s.position_um, "target_um": s.target_um}),
            _ => json!({"t_s": t, "axis": a.name(), "halted": halt.is_ok(),
                "error": halt.err().or(status.err()).map(|e| e.to_string())}),
        };
        tracing::warn!(
            "axis {} reconnected, halted and read back: {fields}",
            a.name()
        );
        self.push(Topic::Fault, "axis_recovered", fields);
    }

    /// Connects the stage, retrying with backoff until it answers (the
    /// daemon runs, and says why nothing moves, while the controllers are
    /// off). Then watches driver events.
    pub async fn connect_loop(self: Arc<Self>, mut shutdown: broadcast::Receiver<()>) {
        let (tx, mut rx) = broadcast::channel(256);
        let mut delay = Duration::from_millis(200);
        let mut reported = false;
        let stage = loop {
            tokio::select! {
                r = Stage::connect_via(&self.cfg.driver, tx.clone(), self.links.as_ref()) => match r {
                    Ok(s) => break s,
                    Err(e) => {
                        if !reported {
                            tracing::warn!("controllers not available: {e}; retrying");
                            self.push(Topic::Fault, "fault", json!({"t_s": self.clock.now_s(), "reason": format!("controllers not available: {e}")}));
                            reported = true;
                        }
                    }
                },
                _ = shutdown.recv() => return,
            }
            tokio::select! {
                _ = tokio::time::sleep(delay) => {},
                _ = shutdown.recv() => return,
            }
            delay = (delay * 2).min(Duration::from_secs(5));
        };
        let rx_x = stage.x.is_referenced().await.unwrap_or(false);
        let rx_y = stage.y.is_referenced().await.unwrap_or(false);
        tracing::info!(
            "controllers connected (referenced: x {rx_x}, y {rx_y}; travel x {:?} µm, y {:?} µm)",
            stage.x.travel_um(),
            stage.y.travel_um()
        );
        *lock(&self.stage) = Some(stage);
        lock(&self.deviation).retie();
        self.apply(Input::StageUp {
            referenced: [rx_x, rx_y],
        });
        self.push(
            Topic::Fault,
            "state",
            json!({"t_s": self.clock.now_s(), "state": lock(&self.state).to_json()}),
        );
        loop {
            let ev = tokio::select! {
                ev = rx.recv() => ev,
                _ = shutdown.recv() => return,
            };
            let ev = match ev {
                Ok(ev) => ev,
                Err(broadcast::error::RecvError::Lagged(n)) => {
                    self.apply(Input::Fault(format!("{n} driver events were missed")));
                    continue;
                }
                Err(broadcast::error::RecvError::Closed) => return,
            };
            self.on_driver_event(ev);
        }
    }

    fn axis_of_line(&self, line: &str) -> Vec<AxisId> {
        let mut v = Vec::new();
        if self.cfg.driver.x.port.to_string_lossy() == line {
            v.push(AxisId::X);
        }
        if self.cfg.driver.y.port.to_string_lossy() == line {
            v.push(AxisId::Y);
        }
        v
    }

    fn on_driver_event(self: &Arc<Self>, ev: AxisEvent) {
        tracing::debug!("driver event {ev:?}");
        match ev {
            AxisEvent::Connected { line } => {
                for a in self.axis_of_line(&line) {
                    self.apply(Input::LinkUp(a));
                    if lock(&self.stage).is_some() {
                        tokio::spawn(self.clone().recover_axis(a));
                    }
                }
                self.metrics.record_link_up(&line);
                self.push(Topic::Fault, "link_up", json!({"line": line}));
            }
            AxisEvent::Disconnected { line, reason } => {
                for a in self.axis_of_line(&line) {
                    self.apply(Input::LinkDown(a, reason.clone()));
                }
            }
            AxisEvent::Noise { line, text } => {
                tracing::debug!("noise on {line}: {text:?}");
            }
            AxisEvent::Garbled { source, error } => {
                // The call that got it fails and decides; the controller
                // is alive, so nothing is halted (see `AxisEvent::Garbled`).
                tracing::warn!("garbled answer from {source}: {error}");
                self.push(
                    Topic::Fault,
                    "garbled",
                    json!({"t_s": self.clock.now_s(), "source": source, "error": error}),
                );
            }
            AxisEvent::Fault { source, error } => {
                self.apply(Input::Fault(format!("{source}: {error}")));
            }
            AxisEvent::ReferenceLost { axis } => {
                if let Some(a) = AxisId::from_name(&axis) {
                    self.apply(Input::ReferenceLost(a));
                }
            }
            AxisEvent::Referenced { axis } => {
                if let Some(a) = AxisId::from_name(&axis) {
                    self.apply(Input::Referenced(a));
                }
            }
        }
    }

    /// Streams every new vision measurement to position subscribers as it
    /// is decoded, so the stream runs at the camera's decode rate. (It used
    /// to ride on the controller poll tick and carried at most one vision
    /// position per `poll_interval_ms`: measured 3.5 events/s against 56
    /// frames/s.) A subscriber slower than the camera sees the newest
    /// measurement, never a queue of stale ones.
    pub async fn vision_stream_loop(self: Arc<Self>, mut shutdown: broadcast::Receiver<()>) {
        let Some(v) = &self.vision else { return };
        let mut latest = v.latest.clone();
        let mut last_seq = None;
        loop {
            tokio::select! {
                r = latest.changed() => if r.is_err() { return },
                _ = shutdown.recv() => return,
            }
            let m = *latest.borrow_and_update();
            let Some(m) = m else { continue };
            if Some(m.sequence) == last_seq {
                continue;
            }
            last_seq = Some(m.sequence);
            if m.quality >= self.cfg.camera.min_quality {
                lock(&self.deviation).vision(m.t_s, m.frame_t_s, m.x_um, m.y_um);
                self.judge_deviation();
            }
            let (sx, sy) = self.vision_to_stage(&m);
            let mut f = m.to_json();
            f["source"] = json!("vision");
            f["stage_x_um"] = json!(sx);
            f["stage_y_um"] = json!(sy);
            self.push(Topic::Position, "position", f);
        }
    }

    /// Polls controller positions while idle or moving (not during a
    /// reference run) and streams them; each round whose reads answered
    /// feeds the watchdog heartbeat, and failing reads go to the motion
    /// supervisor's judge (`safety.read_fail_s`).
    pub async fn poll_loop(self: Arc<Self>, mut shutdown: broadcast::Receiver<()>) {
        let period = Duration::from_millis(self.cfg.daemon.poll_interval_ms);
        let window = Duration::from_millis(self.cfg.camera.timeout_ms);
        let mut health = self
            .vision
            .as_ref()
            .map(|v| super::vision::HealthWatch::new(v, tokio::time::Instant::now()));
        loop {
            tokio::select! {
                _ = tokio::time::sleep(period) => {},
                _ = shutdown.recv() => return,
            }
            let t = self.clock.now_s();
            if let (Some(v), Some(h)) = (&self.vision, health.as_mut()) {
                let s = &v.stats;
                let (frames, decoded) = (
                    s.frames.load(Ordering::Relaxed),
                    s.decoded.load(Ordering::Relaxed),
                );
                let now = tokio::time::Instant::now();
                if v.is_idle() {
                    h.rest(frames, decoded, now);
                } else if let Some(state) = h.update(frames, decoded, window, now) {
                    let reason = match state {
                        super::vision::Health::Ok => "frames decode again".to_owned(),
                        _ => lock(&v.last_error)
                            .clone()
                            .unwrap_or_else(|| "no frame".to_owned()),
                    };
                    tracing::warn!("camera {}: {reason}", state.as_str());
                    self.push(
                        Topic::Fault,
                        "camera",
                        json!({"t_s": t, "state": state.as_str(), "reason": reason}),
                    );
                }
            }
            let Ok(stage) = self.stage() else {
                // Not connected yet: the connect loop is alive, so are we.
                self.heartbeat.fetch_add(1, Ordering::Relaxed);
                continue;
            };
            // Under the sampling lock, checked after taking it: a reference
            // run that began meanwhile is seen here, and one that begins
            // now waits for these reads (see `Rig::sampling`).
            let sampling = self.sampling.lock().await;
            if lock(&self.state).activity() == Activity::Referencing {
                self.heartbeat.fetch_add(1, Ordering::Relaxed);
                continue;
            }
            let t0 = self.clock.now_s();
            let (x, y) = tokio::join!(stage.x.position_um(), stage.y.position_um());
            let t1 = self.clock.now_s();
            drop(sampling);
            for (a, r) in [(AxisId::X, &x), (AxisId::Y, &y)] {
                if let Ok(um) = r {
                    self.deviation_read(a, t0, t1, *um);
                }
            }
            // The watchdog is fed only when the rig is supervised: every
            // read answered, or its line is known down (a latched fault
            // the line task is riding out).
            let mut supervised = true;
            for (a, r) in [(AxisId::X, &x), (AxisId::Y, &y)] {
                let r = r.as_ref().map(|v| *v).map_err(ReadFailure::of);
                supervised &= !matches!(r, Err(ReadFailure::Failed(_)));
                let verdict = self.supervisor().read_result(a, t, &r);
                if let Some(reason) = verdict {
                    self.supervisor_fault(reason);
                }
            }
            let x = x.ok();
            let y = y.ok();
            *lock(&self.reported) = Reported {
                t_s: t,
                x_um: x,
                y_um: y,
            };
            if supervised {
                self.beat();
            }
            self.push(
                Topic::Position,
                "position",
                json!({"source": "controller", "t_s": t, "x_um": x, "y_um": y}),
            );
        }
    }

    /// Vision (pattern frame) to stage frame with the configured rotation;
    /// the offset is not known here (jobs establish it), so these are
    /// pattern coordinates rotated into the stage axes.
    pub fn vision_to_stage(&self, m: &Measurement) -> (f64, f64) {
        let (s, c) = self.cfg.camera.rotation_rad.sin_cos();
        (c * m.x_um - s * m.y_um, s * m.x_um + c * m.y_um)
    }

    /// Soft limits ∩ controller travel for an axis, µm.
    pub fn limits_um(&self, axis: &Axis, a: AxisId) -> (f64, f64) {
        let (tmin, tmax) = axis.travel_um();
        let l = &self.live.limits();
        let (lo, hi) = match a {
            AxisId::X => (l.x_min_um, l.x_max_um),
            AxisId::Y => (l.y_min_um, l.y_max_um),
        };
        (
            lo.map_or(tmin, |v| v.max(tmin)),
            hi.map_or(tmax, |v| v.min(tmax)),
        )
    }

    /// A client or job move. Refused before any byte is sent if the state
    /// forbids it or a target is outside the limits.
    pub async fn move_to(
        self: &Arc<Self>,
        req: &MoveRequest,
        from_job: bool,
    ) -> Result<Value, ProtoError> {
        self.move_with(req, from_job, None).await
    }

    /// [`Rig::move_to`] with the compensator (and the vision frame for
    /// closed loop) named by the caller instead of the active table: the
    /// validation job compares several tables without changing which one
    /// client moves use.
    pub async fn move_with(
        self: &Arc<Self>,
        req: &MoveRequest,
        from_job: bool,
        comp: Option<super::comp::Active>,
    ) -> Result<Value, ProtoError> {
        let r = match req.mode {
            MoveMode::Raw => self.raw_move(req, from_job, true).await,
            MoveMode::Compensated | MoveMode::ClosedLoop => {
                self.planned_move(req, from_job, comp).await
            }
        };
        self.metrics
            .record_move(r.as_ref().map(|_| ()).map_err(|e| e.code));
        r
    }

    /// The commanded position of both axes (cached, else queried).
    async fn current_cmd(&self) -> Result<[f64; 2], ProtoError> {
        let stage = self.stage()?;
        let cached = *lock(&self.commanded);
        let x = match cached[0] {
            Some(v) => v,
            None => stage.x.target_um().await.map_err(driver_error)?,
        };
        let y = match cached[1] {
            Some(v) => v,
            None => stage.y.target_um().await.map_err(driver_error)?,
        };
        Ok([x, y])
    }

    /// A `compensated` or `closed_loop` move: plan with the active
    /// compensator (closed loop without a table plans uncompensated), send
    /// the waypoints waiting for each, commit the plan to the history, then
    /// for closed loop correct from fresh frames.
    async fn planned_move(
        self: &Arc<Self>,
        req: &MoveRequest,
        from_job: bool,
        named: Option<super::comp::Active>,
    ) -> Result<Value, ProtoError> {
        use super::comp as c;
        let active = named.or_else(|| self.comp.active());
        let comp = match &active {
            Some(a) => a.comp.clone(),
            None => c::compensator_for(self, req.mode == MoveMode::Compensated)?,
        };
        let frame = if req.mode == MoveMode::ClosedLoop {
            if self.vision.is_none() {
                return Err(ProtoError::new(
                    ErrorCode::CameraUnavailable,
                    "closed_loop needs a camera (camera.source)",
                ));
            }
            let f = active.as_ref().and_then(|a| a.frame).ok_or_else(|| {
                ProtoError::new(
                    ErrorCode::NoActiveTable,
                    "closed_loop needs the vision → stage transform: activate a table built from a characterization (it records the frame)",
                )
            })?;
            Some(f)
        } else {
            None
        };
        let start = self.current_cmd().await?;
        let base = self
            .comp
            .last_user_target()
            .map_or(start, |t| [t.x_um, t.y_um]);
        let pick = |v: Option<f64>, b: f64| match v {
            Some(v) if req.relative => b + v,
            Some(v) => v,
            None => b,
        };
        let target = crate::model::XyUm {
            x_um: pick(req.x_um, base[0]),
            y_um: pick(req.y_um, base[1]),
        };
        // Live drift: the table's command for `target − drift` lands on
        // `target` in today's state of the rig (see `daemon::drift`).
        let drift = if req.mode == MoveMode::Compensated {
            self.drift_correction(active.as_ref(), !from_job).await?
        } else {
            super::drift::Correction::default()
        };
        let offset = drift.offset_um.unwrap_or([0.0, 0.0]);
        let planned_target = crate::model::XyUm {
            x_um: target.x_um - offset[0],
            y_um: target.y_um - offset[1],
        };
        // A re-measurement moved the stage: plan from where it is now.
        let start = if drift.info.get("measured").is_some() {
            self.current_cmd().await?
        } else {
            start
        };
        let mut opts = self.live.compensation().plan_options();
        if frame.is_some() {
            // The first arrival ends with the loop's re-approach, as every
            // correction does (`ClosedLoopConfig::plan_options`).
            opts = c::loop_config(self, req.tolerance_um).plan_options(opts);
        }
        let plan = self.comp.plan(&*comp, planned_target, start, &opts)?;
        for w in &plan.waypoints {
            let r = MoveRequest::raw_to(w.x_um, w.y_um);
            self.raw_move(&r, from_job, false).await?;
        }
        self.comp.commit_plan(&plan, self.clock.now_s());
        self.comp.set_target_offset(offset);
        let mut out = json!({
            "mode": req.mode.as_str(),
            "compensator": comp.kind(),
            "target": {"x_um": target.x_um, "y_um": target.y_um},
            "commanded": {"x_um": plan.cmd.x_um, "y_um": plan.cmd.y_um},
            "waypoints": plan.waypoints.len(),
            "predicted_offset_um": plan.predicted_offset_um,
            "on_target": true,
        });
        if self.drift.enabled() && req.mode == MoveMode::Compensated {
            out["drift"] = drift.info;
        }
        if let Some(frame) = frame {
            let cl = crate::comp::closed_loop::ClosedLoop::new(
                target,
                plan.cmd,
                plan.arrival,
                c::loop_config(self, req.tolerance_um),
            )
            .map_err(|e| ProtoError::new(ErrorCode::BadValue, format!("closed loop: {e}")))?;
            let me = self.clone();
            let res = c::run_loop(self, cl, frame, move |wps| {
                let me = me.clone();
                Box::pin(async move {
                    for w in wps {
                        let r = MoveRequest::raw_to(w.x_um, w.y_um);
                        me.raw_move(&r, from_job, true).await?;
                    }
                    Ok(())
                })
            })
            .await;
            // Done or not, the move was for the user's target.
            self.comp.restore_target(plan.target, offset);
            out["closed_loop"] = res?;
        }
        Ok(out)
    }

    /// A raw move (also each waypoint of a planned move). `commit` records
    /// it in the motion history (planned moves commit their whole plan).
    pub(super) async fn raw_move(
        self: &Arc<Self>,
        req: &MoveRequest,
        from_job: bool,
        commit: bool,
    ) -> Result<Value, ProtoError> {
        let stage = self.stage()?;
        let gen = self.stop_gen.load(Ordering::SeqCst);
        let _queue = self.motion.lock().await;
        if self.stop_gen.load(Ordering::SeqCst) != gen {
            return Err(ProtoError::new(
                ErrorCode::Halted,
                "a stop or fault came before this move started; it was not sent",
            ));
        }
        let want = [req.x_um.is_some(), req.y_um.is_some()];
        lock(&self.state)
            .may_move(want, from_job)
            .map_err(refusal)?;
        let mut targets = [None, None];
        for (i, (a, axis, v)) in [
            (AxisId::X, &stage.x, req.x_um),
            (AxisId::Y, &stage.y, req.y_um),
        ]
        .into_iter()
        .enumerate()
        {
            let Some(v) = v else { continue };
            let t = if req.relative {
                let cached = lock(&self.commanded)[i];
                let base = match cached {
                    Some(c) => c,
                    None => axis.target_um().await.map_err(driver_error)?,
                };
                base + v
            } else {
                v
            };
            let (lo, hi) = self.limits_um(axis, a);
            if !(lo..=hi).contains(&t) {
                return Err(ProtoError::new(
                    ErrorCode::OutOfTravel,
                    format!(
                        "axis {} target {t} µm is outside the allowed range {lo}..{hi} µm (soft limits ∩ controller travel); nothing was sent",
                        a.name()
                    ),
                ));
            }
            targets[i] = Some(t);
        }
        self.apply(Input::Begin(Activity::Moving));
        let _guard = ActivityGuard {
            rig: self,
            activity: Activity::Moving,
        };
        let send = |axis: &Axis, t: Option<f64>| {
            let axis = axis.clone();
            async move {
                match t {
                    Some(t) => axis.move_abs_um(t).await.map(Some),
                    None => Ok(None),
                }
            }
        };
        let (rx, ry) = tokio::join!(send(&stage.x, targets[0]), send(&stage.y, targets[1]));
        {
            let mut c = lock(&self.commanded);
            if rx.is_ok() && targets[0].is_some() {
                c[0] = targets[0];
            }
            if ry.is_ok() && targets[1].is_some() {
                c[1] = targets[1];
            }
        }
        if let Err(e) = rx.and(ry) {
            // One axis may have started: a half-accepted move is halted.
            self.halt_all().await;
            return Err(driver_error(e));
        }
        if self.stop_gen.load(Ordering::SeqCst) != gen {
            // A stop or a fault came while the move was being sent: its
            // halt (written ahead of the queue) may have reached the
            // controller before this `MOV`, which would then run on.
            self.halt_all().await;
            return Err(ProtoError::new(
                ErrorCode::Halted,
                "a stop or fault came while this move was being sent; both axes were halted again",
            ));
        }
        {
            let t = self.clock.now_s();
            let mut sup = self.supervisor();
            for (a, tg) in [(AxisId::X, targets[0]), (AxisId::Y, targets[1])] {
                if let Some(tg) = tg {
                    sup.watch(a, tg, t);
                }
            }
        }
        if commit {
            self.comp.commit_raw(targets, self.clock.now_s());
        }
        let mut out = json!({"commanded": {"x_um": targets[0], "y_um": targets[1]}});
        if req.wait {
            let wait = |axis: &Axis, t: Option<f64>| {
                let axis = axis.clone();
                async move {
                    match t {
                        Some(_) => axis.wait_on_target(None).await.map(Some),
                        None => Ok(None),
                    }
                }
            };
            let (wx, wy) = tokio::join!(wait(&stage.x, targets[0]), wait(&stage.y, targets[1]));
            // A controller error or a motion timeout while waiting is a
            // fault (halt both, latch), not only this client's failure.
            for r in [&wx, &wy] {
                if let Err(e @ (DriverError::MotionTimeout { .. } | DriverError::Gcs { .. })) = r {
                    self.apply(Input::Fault(format!("while waiting for a move: {e}")));
                }
            }
            let (wx, wy) = (wx.map_err(driver_error)?, wy.map_err(driver_error)?);
            out["reported"] = json!({"x_um": wx, "y_um": wy});
            out["on_target"] = json!(true);
        }
        Ok(out)
    }

    /// Halts everything now: overtakes queued moves (they are refused when
    /// their turn comes), stops a job, sends `#24` to both controllers.
    pub async fn stop(self: &Arc<Self>) -> Result<Value, ProtoError> {
        self.stop_gen.fetch_add(1, Ordering::SeqCst);
        let t = self.clock.now_s();
        lock(&self.state).apply(Input::Stop, t);
        self.push(
            Topic::Fault,
            "stopped",
            json!({"t_s": t, "reason": "stop requested by a client"}),
        );
        self.supervisor().clear();
        let stage = self.stage()?;
        let (x, y) = tokio::join!(stage.x.stop(), stage.y.stop());
        *lock(&self.commanded) = [None, None];
        let mut errors = Vec::new();
        for (n, r) in [("x", x), ("y", y)] {
            if let Err(e) = r {
                errors.push(format!("axis {n}: {e}"));
            }
        }
        if errors.is_empty() {
            Ok(json!({"stopped": true}))
        } else {
            Err(ProtoError::new(
                ErrorCode::DriverError,
                format!("stop sent, but: {}", errors.join("; ")),
            ))
        }
    }

    /// A stop generation: jobs compare it to notice a stop or a fault.
    pub fn stop_generation(&self) -> u64 {
        self.stop_gen.load(Ordering::SeqCst)
    }

    /// Marks a job as owning the axes (refused unless idle and connected).
    pub fn begin_job(self: &Arc<Self>) -> Result<(), ProtoError> {
        let t = self.clock.now_s();
        let mut s = lock(&self.state);
        s.may_take_axes().map_err(refusal)?;
        s.apply(Input::Begin(Activity::Job), t);
        self.job_retries.store(0, Ordering::SeqCst);
        Ok(())
    }

    /// Runs one job operation (a move, a measurement), retrying it after a
    /// transient fault ([`ProtoError::transient`]) up to `daemon.job_retries`
    /// times, with a back-off of `daemon.job_retry_backoff_s` on the rig's
    /// clock, doubled per retry. Each retry is counted in
    /// [`Rig::job_retries`] and pushed as a `job_retry` event on the `job`
    /// topic. A permanent fault returns at once; so does a stop or fault of
    /// the rig during the back-off (`halted`: the job must notice it, not
    /// carry on). `op` must be idempotent: jobs retry absolute moves (the
    /// commanded position is re-queried after a failed move, see
    /// `raw_move`) and measurements, never relative moves.
    pub async fn retry_transient<T, F, Fut>(
        &self,
        operation: &str,
        mut op: F,
    ) -> Result<T, ProtoError>
    where
        F: FnMut() -> Fut,
        Fut: std::future::Future<Output = Result<T, ProtoError>>,
    {
        let max = self.cfg.daemon.job_retries;
        let mut backoff_s = self.cfg.daemon.job_retry_backoff_s;
        let gen = self.stop_generation();
        let mut attempt = 0u32;
        loop {
            let e = match op().await {
                Ok(v) => return Ok(v),
                Err(e) => e,
            };
            if !e.transient {
                return Err(e);
            }
            if attempt >= max {
                return Err(ProtoError::new(
                    e.code,
                    format!(
                        "{operation}: {} (a transient fault, but it persisted through {attempt} {}; daemon.job_retries = {max})",
                        e.message,
                        if attempt == 1 { "retry" } else { "retries" }
                    ),
                ));
            }
            attempt += 1;
            let total = self.job_retries.fetch_add(1, Ordering::SeqCst) + 1;
            tracing::warn!(
                "{operation}: transient fault ({}: {}); retry {attempt} of {max} in {backoff_s} s",
                e.code,
                e.message
            );
            self.push(
                Topic::Job,
                "job_retry",
                json!({"t_s": self.clock.now_s(), "operation": operation, "attempt": attempt,
                       "max": max, "code": e.code.as_str(), "error": e.message,
                       "backoff_s": backoff_s, "retries": total}),
            );
            self.clock
                .sleep(Duration::try_from_secs_f64(backoff_s).unwrap_or_default())
                .await;
            backoff_s *= 2.0;
            if self.stop_generation() != gen {
                return Err(ProtoError::new(
                    ErrorCode::Halted,
                    format!(
                        "{operation}: a stop or fault came while waiting to retry after: {}",
                        e.message
                    ),
                ));
            }
        }
    }

    /// Ends a job's ownership of the axes.
    pub fn end_job(&self) {
        let t = self.clock.now_s();
        lock(&self.state).apply(Input::End(Activity::Job), t);
    }

    /// References the selected axes (the stage moves to its reference).
    pub async fn reference(self: &Arc<Self>, axes: Axes) -> Result<Value, ProtoError> {
        let stage = self.stage()?;
        let gen = self.stop_gen.load(Ordering::SeqCst);
        let _queue = self.motion.lock().await;
        // The play is unknown again after a reference run.
        self.comp.reset_history();
        {
            let t = self.clock.now_s();
            let mut s = lock(&self.state);
            s.may_take_axes().map_err(refusal)?;
            s.apply(Input::Begin(Activity::Referencing), t);
        }
        // A reference run supersedes the moves watched so far; a sample in
        // flight finishes before the run starts.
        self.supervisor().clear();
        let _guard = ActivityGuard {
            rig: self,
            activity: Activity::Referencing,
        };
        drop(self.sampling.lock().await);
        if self.stop_gen.load(Ordering::SeqCst) != gen {
            return Err(ProtoError::new(
                ErrorCode::Halted,
                "a stop or fault came before the reference run started; it was not sent",
            ));
        }
        let run = |axis: &Axis, on: bool| {
            let axis = axis.clone();
            async move {
                if on {
                    axis.reference().await.map(Some)
                } else {
                    Ok(None)
                }
            }
        };
        // A stop or fault during the run halts it (its `HLT` or `#24`); one
        // that came while `SVO`/`FRF` were being sent may have been
        // overtaken by them (the halt goes ahead of the line's queue), so
        // once the generation moved the axes are halted again every
        // supervisor period until the run gives up.
        // The watch runs beside the run (not between its polls: a run
        // suspended inside an exchange holds its controller's lock, which
        // the halt's confirmation needs) and ends with it.
        let period = Duration::from_millis(self.cfg.safety.supervise_interval_ms);
        let (done_tx, mut done_rx) = tokio::sync::oneshot::channel::<()>();
        let runs = async {
            let r = tokio::join!(run(&stage.x, axes.x()), run(&stage.y, axes.y()));
            let _ = done_tx.send(());
            r
        };
        let watch = async {
            loop {
                tokio::select! {
                    _ = &mut done_rx => return,
                    () = tokio::time::sleep(period) => {}
                }
                if self.stop_gen.load(Ordering::SeqCst) != gen {
                    self.halt_all().await;
                }
            }
        };
        let ((x, y), ()) = tokio::join!(runs, watch);
        // The counts changed meaning: the deviation check ties afresh.
        lock(&self.deviation).retie();
        if self.stop_gen.load(Ordering::SeqCst) != gen {
            // Halted once more: an `FRF` written after the stop's `#24` or
            // `HLT` runs while its `ERR?` reports the stop (10), so the run
            // can end in an error with the axis still referencing.
            self.halt_all().await;
            return Err(ProtoError::new(
                ErrorCode::Halted,
                "a stop or fault came during the reference run; it was halted",
            ));
        }
        let x = x.map_err(driver_error)?;
        let y = y.map_err(driver_error)?;
        {
            let mut c = lock(&self.commanded);
            if x.is_some() {
                c[0] = x;
            }
            if y.is_some() {
                c[1] = y;
            }
        }
        for (a, v) in [(AxisId::X, x), (AxisId::Y, y)] {
            if v.is_some() {
                self.apply(Input::Referenced(a));
            }
        }
        Ok(json!({"reported": {"x_um": x, "y_um": y}}))
    }

    /// Positions from every source, each named, with its time.
    pub async fn position(&self) -> Value {
        let commanded = *lock(&self.commanded);
        let mut controller = json!(null);
        if let Ok(stage) = self.stage() {
            let t = self.clock.now_s();
            let (x, y) = tokio::join!(stage.x.position_um(), stage.y.position_um());
            let err = |r: &Result<f64, DriverError>| r.as_ref().err().map(|e| e.to_string());
            controller = json!({"t_s": t, "x_um": x.as_ref().ok(), "y_um": y.as_ref().ok(),
                                "x_error": err(&x), "y_error": err(&y)});
        } else {
            let r = *lock(&self.reported);
            if r.x_um.is_some() || r.y_um.is_some() {
                controller = json!({"t_s": r.t_s, "x_um": r.x_um, "y_um": r.y_um});
            }
        }
        let vision = self.vision.as_ref().and_then(|v| {
            let m = (*v.latest.borrow())?;
            let (sx, sy) = self.vision_to_stage(&m);
            let mut j = m.to_json();
            j["age_s"] = json!(self.clock.now_s() - m.t_s);
            j["stage_x_um"] = json!(sx);
            j["stage_y_um"] = json!(sy);
            Some(j)
        });
        json!({
            "commanded": {"x_um": commanded[0], "y_um": commanded[1]},
            "controller": controller,
            "vision": vision,
        })
    }

    /// The commanded position `[x, y]` µm (what the last move asked).
    pub fn commanded_um(&self) -> [Option<f64>; 2] {
        *lock(&self.commanded)
    }

    /// The controllers' positions as last polled: `(t_s, x_um, y_um)`.
    pub fn reported_um(&self) -> (f64, Option<f64>, Option<f64>) {
        let r = *lock(&self.reported);
        (r.t_s, r.x_um, r.y_um)
    }

    /// The state part of `status`.
    pub fn status(&self) -> Value {
        let stage = lock(&self.stage).clone();
        let travel = stage.map(|s| {
            let (xl, xh) = self.limits_um(&s.x, AxisId::X);
            let (yl, yh) = self.limits_um(&s.y, AxisId::Y);
            json!({"x_um": [xl, xh], "y_um": [yl, yh]})
        });
        json!({
            "t_s": self.clock.now_s(),
            "rig": lock(&self.state).to_json(),
            "limits": travel,
            "camera": self.vision.as_ref().map(|v| v.to_json()),
            "drift": self.drift.to_json(self.clock.now_s()),
            "deviation": self.deviation_json(),
        })
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
