//! systemd integration: `READY=1` once the socket listens, `STATUS=` with
//! the rig's mode, and `WATCHDOG=1` only while the position poller makes
//! progress (a hung runtime or a stuck poller lets systemd restart us).
//! Outside systemd (`NOTIFY_SOCKET` unset) every call is a no-op.

use super::protocol::JobState;
use super::Daemon;
use sd_notify::NotifyState;
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::Duration;
use tokio::sync::broadcast;

/// Tells systemd the daemon is ready.
pub fn ready() {
    if let Err(e) = sd_notify::notify(&[NotifyState::Ready]) {
        tracing::warn!("sd_notify READY failed: {e}");
    }
}

/// Tells systemd a reload is under way (`READY` ends it).
pub fn reloading() {
    let _ = sd_notify::notify(&[NotifyState::Reloading]);
}

/// Tells systemd the daemon is stopping.
pub fn stopping() {
    let _ = sd_notify::notify(&[NotifyState::Stopping]);
}

/// Feeds the watchdog (if systemd asked for one) and updates STATUS.
pub async fn watchdog_loop(daemon: Arc<Daemon>, mut shutdown: broadcast::Receiver<()>) {
    let interval = sd_notify::watchdog_enabled()
        .map(|d| d / 2)
        .unwrap_or(Duration::from_secs(5));
    let mut last_beat = daemon.rig.heartbeat.load(Ordering::Relaxed);
    let mut last_status = String::new();
    loop {
        tokio::select! {
            _ = tokio::time::sleep(interval) => {},
            _ = shutdown.recv() => return,
        }
        let beat = daemon.rig.heartbeat.load(Ordering::Relaxed);
        let status = daemon.rig.status();
        let mode = status.rig.mode;
        let text = match daemon.jobs.status() {
            Some(j) if j.state == JobState::Running => {
                format!("{mode}; job {}/{}", j.done, j.total)
            }
            _ => mode,
        };
        if text != last_status {
            let _ = sd_notify::notify(&[NotifyState::Status(&text)]);
            last_status = text;
        }
        if beat != last_beat {
            let _ = sd_notify::notify(&[NotifyState::Watchdog]);
            last_beat = beat;
        } else {
            tracing::warn!(
                "position poller made no progress for {interval:?}; not feeding the watchdog"
            );
        }
    }
}
