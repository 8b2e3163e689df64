//! `[rig]` and `[daemon]`: the rig's clock, the socket, the data directory, polling.

use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// `[rig]`: where the rig's time comes from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RigSection {
    /// `"wall"` (hardware: monotonic wall time) or `"sim:PATH"` (the
    /// simulator's control socket: settle times advance simulated time, so
    /// a 9.5-hour characterization runs in minutes). Every wait and
    /// timestamp of the daemon goes through this clock.
    pub clock: String,
}

impl Default for RigSection {
    fn default() -> Self {
        Self {
            clock: "wall".to_owned(),
        }
    }
}

/// The parsed `[rig] clock` key.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ClockSpec {
    /// Monotonic wall time (hardware).
    Wall,
    /// hil-sim's control socket.
    Sim(PathBuf),
}

/// `[daemon]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DaemonSection {
    /// Unix socket path (overridden by `--socket`; ignored under socket
    /// activation).
    pub socket: PathBuf,
    /// Socket file mode, octal string (default `"0660"`: owner and group).
    pub socket_mode: String,
    /// Where measurement logs and tables live; client-given file names are
    /// resolved inside it and nowhere else.
    pub data_dir: PathBuf,
    /// Period of the controller position poll that feeds the position
    /// stream and the health check, ms.
    pub poll_interval_ms: u64,
    /// Most clients served at once. A client beyond it gets one of the
    /// `stop_slots` (which accept only `stop`), or a `busy` line and is
    /// closed: it never waits in the accept queue.
    pub max_clients: usize,
    /// Connections kept beyond `max_clients` that accept only `stop`. Why:
    /// a daemon whose slots are all held by idle or stuck clients must
    /// still let someone halt the stage, on the same socket path (no second
    /// socket to configure, activate and protect).
    pub stop_slots: usize,
    /// Full slots one uid may hold (values above `max_clients` mean no
    /// cap). Why: so that no single local user (a runaway script, a
    /// hostile client) can hold every slot; the other users' `stop` still
    /// gets through (`daemon::admission`).
    pub max_clients_per_uid: usize,
    /// Stop-only slots one uid may hold (default 1): below `stop_slots`,
    /// no single uid can take them all.
    pub stop_slots_per_uid: usize,
    /// A client that sends nothing for this long while it has no request
    /// running and no subscription is disconnected, s (0 = never). A
    /// subscriber is never idle: it is receiving events, and a subscriber
    /// that stops reading them is caught by `write_timeout_s` instead.
    pub idle_timeout_s: f64,
    /// Longest time from the first byte of a request line to its newline,
    /// s. A client that starts a line and stalls holds a slot for nothing.
    /// Stop-only connections also use it as their idle timeout.
    pub read_timeout_s: f64,
    /// Longest time one reply or event line may take to be written, s: a
    /// client that does not read its socket is disconnected instead of
    /// holding a slot (its events are already dropped, never queued).
    pub write_timeout_s: f64,
    /// How often a job retries one operation (a move, a measurement) after
    /// a *transient* fault: a lost or late controller reply, a garbled
    /// reply, a camera that delivered no decodable frame in time. Why: a
    /// characterization runs for hours, and one glitch on the serial line
    /// must not throw the rest away. Permanent faults (controller error
    /// codes, limits, servo off, lost reference, a dropped line) are never
    /// retried. 0 = fail at the first fault, as before.
    pub job_retries: u32,
    /// Back-off before the first retry, rig seconds (simulated seconds
    /// under a `sim:` clock); doubled for each further retry of the same
    /// operation, so a line that needs a moment to fall quiet gets it.
    pub job_retry_backoff_s: f64,
    /// `sync_data` of the characterization and validation logs after every
    /// this many records: a power cut loses at most this many − 1 records
    /// (plus the torn last line, which reading repairs). 0 = never sync,
    /// only hand each record to the operating system at once (a crash of
    /// the process still loses nothing). Why configurable: a sync costs
    /// milliseconds, nothing against a real point's seconds but most of the
    /// wall time of a simulated rig whose points cost microseconds
    /// (`hil-sim run` sets 0).
    pub log_sync_every: u32,
}

impl Default for DaemonSection {
    fn default() -> Self {
        Self {
            socket: PathBuf::from("/run/micropos/micropos.sock"),
            socket_mode: "0660".to_owned(),
            data_dir: PathBuf::from("/var/lib/micropos"),
            poll_interval_ms: 200,
            max_clients: 256,
            stop_slots: 4,
            max_clients_per_uid: 128,
            stop_slots_per_uid: 1,
            idle_timeout_s: 3600.0,
            read_timeout_s: 10.0,
            write_timeout_s: 10.0,
            job_retries: 3,
            job_retry_backoff_s: 0.5,
            log_sync_every: 1,
        }
    }
}
