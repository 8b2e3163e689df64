//! The rig's background tasks: connecting (and reconnecting) the
//! controller lines, driver events, the camera's frames to subscribers and
//! the position poller.

use super::{lock, Rig};
use crate::daemon::motion_core::Reported;
use crate::daemon::protocol::{
    CameraEvent, FaultEvent, GarbledEvent, LinkUpEvent, PolledPosition, PositionEvent, StateEvent,
};
use crate::daemon::state::{AxisId, Input};
use crate::daemon::supervisor::ReadFailure;
use crate::driver::{AxisEvent, Stage};
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::Duration;
use tokio::sync::broadcast;

impl Rig {
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
                        self.apply(Input::ConnectFailed(e.to_string()));
                        if !reported {
                            tracing::warn!("controllers not available: {e}; retrying");
                            self.emit(&FaultEvent {
                                t_s: self.clock.now_s(),
                                reason: format!("controllers not available: {e}"),
                                latched: None,
                            });
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
        // The events of the connect itself (each line's first open is a
        // `Connected`) are no reconnection: nothing was commanded yet, so
        // there is nothing to halt. They are applied before the stage is
        // handed out, which is what keeps them from recovering (handled
        // as reconnections, they spawned a halt that raced the first
        // client command: a `reference` sent at once was aborted, "not
        // referenced", seen on a loaded machine).
        let mut during_connect = Vec::new();
        while let Ok(ev) = rx.try_recv() {
            during_connect.push(ev);
        }
        self.apply(Input::StageUp {
            referenced: [rx_x, rx_y],
        });
        for ev in during_connect {
            self.on_driver_event(ev);
        }
        *lock(&self.stage) = Some(stage);
        self.core().retie();
        let t = self.clock.now_s();
        let state = self.core().state().to_reply();
        self.emit(&StateEvent { t_s: t, state });
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

    pub(super) fn axis_of_line(&self, line: &str) -> Vec<AxisId> {
        let mut v = Vec::new();
        if self.cfg.driver.x.port.to_string_lossy() == line {
            v.push(AxisId::X);
        }
        if self.cfg.driver.y.port.to_string_lossy() == line {
            v.push(AxisId::Y);
        }
        v
    }

    /// Applies a driver event to the fault state. A line that comes back
    /// once the stage is up is halted and read back.
    pub(super) fn on_driver_event(self: &Arc<Self>, ev: AxisEvent) {
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
                self.emit(&LinkUpEvent { line });
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
                self.emit(&GarbledEvent {
                    t_s: self.clock.now_s(),
                    source,
                    error,
                });
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
                self.core().vision(m.t_s, m.frame_t_s, m.x_um, m.y_um);
                self.judge_deviation();
            }
            self.emit(&PositionEvent::Vision(self.vision_position(&m)));
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
            .map(|v| crate::daemon::vision::HealthWatch::new(v, tokio::time::Instant::now()));
        loop {
            tokio::select! {
                _ = tokio::time::sleep(period) => {},
                _ = shutdown.recv() => return,
            }
            let t = self.clock.now_s();
            if let (Some(v), Some(h)) = (&self.vision, health.as_mut()) {
                let counts = crate::daemon::vision::HealthCounts::of(&v.stats);
                let now = tokio::time::Instant::now();
                if v.is_idle() {
                    h.rest(counts, now);
                } else if let Some(state) = h.update(counts, window, now) {
                    let reason = match state {
                        crate::daemon::vision::Health::Ok => "frames decode again".to_owned(),
                        _ => lock(&v.last_error)
                            .clone()
                            .unwrap_or_else(|| "no frame".to_owned()),
                    };
                    tracing::warn!("camera {}: {reason}", state.as_str());
                    self.emit(&CameraEvent {
                        t_s: t,
                        state: state.as_str().to_owned(),
                        reason,
                    });
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
            if self.referencing() {
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
                let verdict = self.core().read_result(a, t, &r);
                if let Some(reason) = verdict {
                    self.supervisor_fault(reason);
                }
            }
            let x = x.ok();
            let y = y.ok();
            self.core().set_reported(Reported {
                t_s: t,
                x_um: x,
                y_um: y,
            });
            if supervised {
                self.beat();
            }
            self.emit(&PositionEvent::Controller(PolledPosition {
                t_s: t,
                x_um: x,
                y_um: y,
            }));
        }
    }
}
