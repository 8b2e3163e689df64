//! Who asked for what: every state-changing command (and every refused
//! one) as a tracing event with the peer's uid, gid, pid, role and the
//! command as fields, and as one JSON line appended to `audit.jsonl` in the
//! data directory. Under systemd (`JOURNAL_STREAM` set) the record also
//! goes to journald's native socket as fields of their own
//! (`journalctl MICROPOS_UID=1001`), and the text line drops to debug so
//! the journal does not hold it twice.
//!
//! Why a thread of its own behind a bounded queue: the file write may be
//! slow (a full disk, a stalled NFS mount) and must never delay a reply,
//! least of all `stop`'s. [`Audit::record`] only `try_send`s; when the
//! queue is full the record is counted as dropped (and said so in the
//! journal and in the next record written) rather than waited for.
//!
//! Why the record is bounded, rate-limited and rotated: the trail is written
//! for requests anyone who can reach a listener sends, refused ones
//! included, so it must not be a way to fill the disk. A record holds a
//! summary of the request (a few top-level scalar fields, truncated, and
//! the request's size in bytes), never the request itself; each source (a
//! uid, or an HTTP client's address) has a token bucket
//! ([`AuditLimits::rate_per_s`], [`AuditLimits::burst`]), records beyond it
//! are counted and the next record let through says how many
//! (`rate_dropped`); the file is rotated at [`AuditLimits::max_bytes`]
//! (`audit.jsonl` → `audit.jsonl.1` … `.N`). The file is opened with
//! `O_NOFOLLOW`: a symlink planted at its path is refused (logged, naming
//! the file), not written through. An audit failure never blocks or
//! refuses a command: motion safety outranks the trail, and the failure is
//! logged.

use super::access::Peer;
use super::protocol::{Command, Role};
use crate::clock::UtcTime;
use serde_json::{json, Value};
use std::collections::HashMap;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{sync_channel, Receiver, SyncSender, TrySendError};
use std::sync::{Arc, Mutex};
use std::time::Instant;

/// Records queued for the file at most; beyond, records are dropped.
const QUEUE: usize = 4096;

/// Top-level fields a record's request summary keeps at most.
const SUMMARY_FIELDS: usize = 8;
/// Characters a summarized key or string value keeps at most.
const SUMMARY_CHARS: usize = 64;
/// Sources whose buckets are remembered at most; beyond, refilled buckets
/// are forgotten (a forgotten source starts with a full bucket).
const MAX_SOURCES: usize = 4096;

/// `[audit]`: the bounds of the audit file.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AuditLimits {
    /// Records per second each source (uid, or HTTP client address) may
    /// add in the long run.
    pub rate_per_s: f64,
    /// Records a source may add at once before the rate applies.
    pub burst: f64,
    /// Size at which `audit.jsonl` is rotated, bytes.
    pub max_bytes: u64,
    /// Rotated files kept (`audit.jsonl.1` … `.N`); the oldest is deleted.
    pub files: u32,
}

impl Default for AuditLimits {
    fn default() -> Self {
        Self {
            rate_per_s: 5.0,
            burst: 50.0,
            max_bytes: 16 * 1024 * 1024,
            files: 4,
        }
    }
}

/// One source's token bucket.
#[derive(Debug, Clone, Copy)]
struct Bucket {
    tokens: f64,
    last: Instant,
    dropped: u64,
}

/// Per-source token buckets, sans-IO: the caller gives the time.
#[derive(Debug)]
struct RateLimiter {
    rate_per_s: f64,
    burst: f64,
    buckets: HashMap<String, Bucket>,
}

impl RateLimiter {
    fn new(limits: &AuditLimits) -> Self {
        Self {
            rate_per_s: limits.rate_per_s.max(0.0),
            burst: limits.burst.max(1.0),
            buckets: HashMap::new(),
        }
    }

    /// `Some(n)`: write the record, after `n` dropped from this source;
    /// `None`: drop it (counted).
    fn admit(&mut self, source: &str, now: Instant) -> Option<u64> {
        if self.buckets.len() >= MAX_SOURCES && !self.buckets.contains_key(source) {
            let (rate, burst) = (self.rate_per_s, self.burst);
            self.buckets.retain(|_, b| {
                b.dropped > 0
                    || b.tokens + now.saturating_duration_since(b.last).as_secs_f64() * rate < burst
            });
            if self.buckets.len() >= MAX_SOURCES {
                return Some(0);
            }
        }
        let b = self.buckets.entry(source.to_owned()).or_insert(Bucket {
            tokens: self.burst,
            last: now,
            dropped: 0,
        });
        let dt = now.saturating_duration_since(b.last).as_secs_f64();
        b.tokens = (b.tokens + dt * self.rate_per_s).min(self.burst);
        b.last = now;
        if b.tokens >= 1.0 {
            b.tokens -= 1.0;
            Some(std::mem::take(&mut b.dropped))
        } else {
            b.dropped += 1;
            None
        }
    }
}

/// The request as a record keeps it: its top-level scalar fields (at most
/// [`SUMMARY_FIELDS`], keys and strings cut to [`SUMMARY_CHARS`]
/// characters, arrays and objects by type only). `Null` when the request
/// is not a JSON object or is over the protocol's size limit.
fn summarize(request: &[u8]) -> Value {
    if request.len() > super::protocol::MAX_REQUEST_BYTES {
        return Value::Null;
    }
    let Ok(Value::Object(obj)) = serde_json::from_slice::<Value>(request) else {
        return Value::Null;
    };
    let cut = |s: &str| s.chars().take(SUMMARY_CHARS).collect::<String>();
    let mut out = serde_json::Map::new();
    for (k, v) in obj.iter().take(SUMMARY_FIELDS) {
        let v = match v {
            Value::String(s) => Value::String(cut(s)),
            Value::Array(_) => Value::String("[array]".to_owned()),
            Value::Object(_) => Value::String("{object}".to_owned()),
            other => other.clone(),
        };
        out.insert(cut(k), v);
    }
    Value::Object(out)
}

/// Name of the audit file inside the data directory.
pub const AUDIT_FILE: &str = "audit.jsonl";

/// journald's native protocol socket.
pub const JOURNAL_SOCKET: &str = "/run/systemd/journal/socket";

/// journald's socket when running under systemd (`JOURNAL_STREAM` set).
pub fn journal_socket() -> Option<PathBuf> {
    std::env::var_os("JOURNAL_STREAM").map(|_| PathBuf::from(JOURNAL_SOCKET))
}

/// One record for the writer thread.
#[derive(Debug)]
struct Record {
    line: String,
    journal: Vec<u8>,
}

/// A journald native-protocol datagram: `KEY=value` lines (newlines in
/// values become spaces; the values here are numbers and fixed names).
pub fn journal_entry(fields: &[(&str, String)]) -> Vec<u8> {
    let mut out = Vec::new();
    for (k, v) in fields {
        out.extend_from_slice(k.as_bytes());
        out.push(b'=');
        out.extend(v.bytes().map(|b| if b == b'\n' { b' ' } else { b }));
        out.push(b'\n');
    }
    out
}

/// Whether the command ran or was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Outcome {
    /// Passed the role check and was executed.
    Allowed,
    /// Refused with `permission_denied`.
    Denied,
}

impl Outcome {
    fn as_str(self) -> &'static str {
        match self {
            Outcome::Allowed => "allowed",
            Outcome::Denied => "denied",
        }
    }
}

/// Where a command came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Origin {
    /// A client of the Unix socket, as the kernel named it.
    Socket(Peer),
    /// An HTTP client of the web listener (`[web] control`), by address:
    /// it proved the token, the kernel knows no more about it.
    Http(std::net::SocketAddr),
}

impl std::fmt::Display for Origin {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Origin::Socket(p) => {
                write!(f, "uid {} gid {} pid {}", p.uid, p.gid, p.pid.unwrap_or(-1))
            }
            Origin::Http(a) => write!(f, "http {a}"),
        }
    }
}

impl Origin {
    /// "uid U (pid P" or "http ADDR (": the start of the journal message,
    /// whose parenthesis the role closes.
    fn describe(self) -> String {
        match self {
            Origin::Socket(p) => format!("uid {} (pid {}", p.uid, p.pid.unwrap_or(-1)),
            Origin::Http(a) => format!("http {a} ("),
        }
    }
}

/// The audit trail's writer side.
#[derive(Debug)]
pub struct Audit {
    tx: SyncSender<Record>,
    dropped: Arc<AtomicU64>,
    path: PathBuf,
    journal: Option<PathBuf>,
    limiter: Mutex<RateLimiter>,
}

impl Audit {
    /// Starts the writer thread for `data_dir/audit.jsonl` (the file, and
    /// the directory if missing, are created at the first record; the file
    /// with mode 0640 before the umask).
    pub fn start(data_dir: &Path) -> Audit {
        Self::start_limited(data_dir, journal_socket(), AuditLimits::default())
    }

    /// [`Audit::start`] with an explicit journald socket (`None`: none).
    pub fn start_with(data_dir: &Path, journal: Option<PathBuf>) -> Audit {
        Self::start_limited(data_dir, journal, AuditLimits::default())
    }

    /// [`Audit::start_with`] with explicit bounds (`[audit]`).
    pub fn start_limited(data_dir: &Path, journal: Option<PathBuf>, limits: AuditLimits) -> Audit {
        let path = data_dir.join(AUDIT_FILE);
        let (tx, rx) = sync_channel(QUEUE);
        let p = path.clone();
        let j = journal.clone();
        let limiter = Mutex::new(RateLimiter::new(&limits));
        let spawned = std::thread::Builder::new()
            .name("microposd-audit".to_owned())
            .spawn(move || writer(&p, j.as_deref(), rx, &limits));
        if let Err(e) = spawned {
            tracing::error!(
                "audit: cannot start the writer thread ({e}); only the journal records commands"
            );
        }
        Audit {
            tx,
            dropped: Arc::new(AtomicU64::new(0)),
            path,
            journal,
            limiter,
        }
    }

    /// The audit file's path.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Records one command of `peer` (holding `role`); `request` is the
    /// request line as received (summarized in the record, see
    /// [`summarize`]).
    /// Never blocks.
    pub fn record(
        &self,
        peer: &Peer,
        role: Option<Role>,
        cmd: &Command,
        outcome: Outcome,
        request: &[u8],
    ) {
        self.record_from(Origin::Socket(*peer), role, cmd, outcome, request);
    }

    /// The gate both front doors pass a parsed request through, after
    /// their own role rule decided `permitted`: a refusal is recorded, and
    /// so is an admitted command that changes state, before it runs.
    /// Returns `permitted`.
    pub fn admit(
        &self,
        origin: Origin,
        role: Option<Role>,
        cmd: &Command,
        request: &[u8],
        permitted: bool,
    ) -> bool {
        if !permitted {
            self.record_from(origin, role, cmd, Outcome::Denied, request);
        } else if cmd.changes_state() {
            self.record_from(origin, role, cmd, Outcome::Allowed, request);
        }
        permitted
    }

    /// [`Audit::record`] for a client on either listener.
    pub fn record_from(
        &self,
        origin: Origin,
        role: Option<Role>,
        cmd: &Command,
        outcome: Outcome,
        request: &[u8],
    ) {
        let source = match origin {
            Origin::Socket(p) => format!("uid {}", p.uid),
            Origin::Http(a) => format!("http {}", a.ip()),
        };
        let admitted = match self.limiter.lock() {
            Ok(mut l) => l.admit(&source, Instant::now()),
            Err(_) => Some(0),
        };
        let Some(rate_dropped) = admitted else {
            return;
        };
        let role_s = role.map_or("none", Role::as_str);
        let who = origin.describe();
        if self.journal.is_none() {
            tracing::info!(target: "micropos::audit", client = %origin,
                role = role_s, cmd = cmd.name(), outcome = outcome.as_str(), "client command");
        } else {
            tracing::debug!(target: "micropos::audit", client = %origin,
                role = role_s, cmd = cmd.name(), outcome = outcome.as_str(), "client command");
        }
        let journal = match self.journal {
            Some(_) => {
                let mut fields = vec![
                    (
                        "MESSAGE",
                        format!(
                            "{} {} by {who}{}role {role_s})",
                            cmd.name(),
                            outcome.as_str(),
                            if matches!(origin, Origin::Socket(_)) {
                                ", "
                            } else {
                                ""
                            }
                        ),
                    ),
                    ("PRIORITY", "6".to_owned()),
                    ("SYSLOG_IDENTIFIER", "microposd".to_owned()),
                    ("MICROPOS_AUDIT", "1".to_owned()),
                    ("MICROPOS_ROLE", role_s.to_owned()),
                    ("MICROPOS_CMD", cmd.name().to_owned()),
                    ("MICROPOS_OUTCOME", outcome.as_str().to_owned()),
                ];
                match origin {
                    Origin::Socket(peer) => {
                        fields.push(("MICROPOS_UID", peer.uid.to_string()));
                        fields.push(("MICROPOS_GID", peer.gid.to_string()));
                        fields.push(("MICROPOS_PID", peer.pid.unwrap_or(-1).to_string()));
                    }
                    Origin::Http(addr) => fields.push(("MICROPOS_REMOTE", addr.to_string())),
                }
                journal_entry(&fields)
            }
            None => Vec::new(),
        };
        let unix = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_secs_f64())
            .unwrap_or(0.0);
        let request_bytes = request.len();
        let request = summarize(request);
        let mut rec = json!({
            "time": UtcTime::from_unix(unix as u64).rfc3339(),
            "unix_s": unix,
            "role": role_s,
            "cmd": cmd.name(),
            "outcome": outcome.as_str(),
            "request": request,
            "request_bytes": request_bytes,
        });
        if rate_dropped > 0 {
            rec["rate_dropped"] = json!(rate_dropped);
        }
        match origin {
            Origin::Socket(peer) => {
                rec["uid"] = json!(peer.uid);
                rec["gid"] = json!(peer.gid);
                rec["pid"] = json!(peer.pid);
            }
            Origin::Http(addr) => {
                rec["via"] = json!("http");
                rec["remote"] = json!(addr.to_string());
            }
        }
        let lost = self.dropped.swap(0, Ordering::Relaxed);
        if lost > 0 {
            rec["dropped_before"] = json!(lost);
        }
        let mut line = rec.to_string();
        line.push('\n');
        match self.tx.try_send(Record { line, journal }) {
            Ok(()) => {}
            Err(TrySendError::Full(_)) => {
                self.dropped.fetch_add(lost + 1, Ordering::Relaxed);
                tracing::warn!("audit: queue full, a record was dropped (journal only)");
            }
            Err(TrySendError::Disconnected(_)) => {
                self.dropped.fetch_add(lost + 1, Ordering::Relaxed);
            }
        }
    }
}

/// Opens (creating) the audit file for appending, mode 0640, refusing a
/// symlink at its path (`O_NOFOLLOW`); logs a failure unless `failing`.
fn open_audit(path: &Path, failing: bool) -> Option<std::fs::File> {
    use std::os::unix::fs::OpenOptionsExt;
    if let Some(dir) = path.parent() {
        let _ = std::fs::create_dir_all(dir);
    }
    std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .mode(0o640)
        .custom_flags(libc::O_NOFOLLOW)
        .open(path)
        .map_err(|e| {
            if !failing {
                tracing::error!(
                    "audit: cannot open {} (a symlink there is refused): {e}",
                    path.display()
                );
            }
        })
        .ok()
}

/// `audit.jsonl.N` for `n` > 0, `audit.jsonl` for 0.
fn rotated(path: &Path, n: u32) -> PathBuf {
    if n == 0 {
        return path.to_path_buf();
    }
    let mut s = path.as_os_str().to_owned();
    s.push(format!(".{n}"));
    PathBuf::from(s)
}

/// Shifts `audit.jsonl.K` to `.K+1` (the last is overwritten) and
/// `audit.jsonl` to `.1`; with `files` = 0 the file is only removed.
fn rotate(path: &Path, files: u32) {
    if files == 0 {
        let _ = std::fs::remove_file(path);
        return;
    }
    for k in (0..files).rev() {
        let _ = std::fs::rename(rotated(path, k), rotated(path, k + 1));
    }
}

/// Appends each line; reopens after an error so a transient failure (disk
/// full, directory recreated) costs only the records written meanwhile.
/// Rotates before a line would take the file past `limits.max_bytes`.
fn writer(path: &Path, journal: Option<&Path>, rx: Receiver<Record>, limits: &AuditLimits) {
    let mut file: Option<std::fs::File> = None;
    let mut size: u64 = 0;
    let mut failing = false;
    let socket = journal.and_then(|_| std::os::unix::net::UnixDatagram::unbound().ok());
    let mut journal_failing = false;
    for Record {
        line,
        journal: entry,
    } in rx
    {
        if let (Some(s), Some(j)) = (&socket, journal) {
            let sent = s.send_to(&entry, j);
            if let Err(e) = &sent {
                if !journal_failing {
                    tracing::warn!("audit: journald ({}): {e}", j.display());
                }
            }
            journal_failing = sent.is_err();
        }
        let len = line.len() as u64;
        if file.is_some() && size > 0 && size + len > limits.max_bytes {
            file = None;
            rotate(path, limits.files);
        }
        if file.is_none() {
            file = open_audit(path, failing);
            size = file
                .as_ref()
                .and_then(|f| f.metadata().ok())
                .map_or(0, |m| m.len());
            if file.is_some() && size > 0 && size + len > limits.max_bytes {
                rotate(path, limits.files);
                file = open_audit(path, failing);
                size = 0;
            }
        }
        let written = match file.as_mut() {
            Some(f) => f.write_all(line.as_bytes()).map_err(|e| {
                if !failing {
                    tracing::error!("audit: cannot write {}: {e}", path.display());
                }
            }),
            None => Err(()),
        };
        failing = written.is_err();
        if failing {
            file = None;
        } else {
            size += len;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::{Duration, Instant};

    #[test]
    fn records_are_appended_as_json_lines() {
        let dir = tempfile::tempdir().unwrap();
        let a = Audit::start(dir.path());
        let peer = Peer {
            uid: 1001,
            gid: 1002,
            pid: Some(77),
        };
        let req = br#"{"id":1,"cmd":"move","x_um":5}"#;
        let cmd = crate::daemon::protocol::parse_request(req).unwrap().command;
        a.record(&peer, Some(Role::Operate), &cmd, Outcome::Allowed, req);
        a.record(&peer, Some(Role::Read), &cmd, Outcome::Denied, b"not json");
        let t = Instant::now();
        let lines: Vec<Value> = loop {
            let text = std::fs::read_to_string(a.path()).unwrap_or_default();
            if text.lines().count() == 2 {
                break text
                    .lines()
                    .map(|l| serde_json::from_str(l).unwrap())
                    .collect();
            }
            assert!(t.elapsed() < Duration::from_secs(20), "{text:?}");
            std::thread::sleep(Duration::from_millis(5));
        };
        assert_eq!(lines[0]["uid"], 1001);
        assert_eq!(lines[0]["gid"], 1002);
        assert_eq!(lines[0]["pid"], 77);
        assert_eq!(lines[0]["cmd"], "move");
        assert_eq!(lines[0]["role"], "operate");
        assert_eq!(lines[0]["outcome"], "allowed");
        assert_eq!(lines[0]["request"]["x_um"], 5);
        assert!(lines[0]["time"].as_str().unwrap().ends_with('Z'));
        assert_eq!(lines[1]["outcome"], "denied");
        assert_eq!(lines[1]["request"], Value::Null);
    }

    #[test]
    fn http_clients_are_recorded_by_address() {
        let dir = tempfile::tempdir().unwrap();
        let sock = dir.path().join("journal.sock");
        let journal = std::os::unix::net::UnixDatagram::bind(&sock).unwrap();
        journal
            .set_read_timeout(Some(Duration::from_secs(20)))
            .unwrap();
        let a = Audit::start_with(dir.path(), Some(sock));
        let req = br#"{"cmd":"move","x_um":5}"#;
        let cmd = crate::daemon::protocol::parse_request(req).unwrap().command;
        let remote: std::net::SocketAddr = "127.0.0.1:40001".parse().unwrap();
        a.record_from(Origin::Http(remote), None, &cmd, Outcome::Denied, req);
        let mut buf = vec![0u8; 4096];
        let n = journal.recv(&mut buf).unwrap();
        let text = String::from_utf8(buf[..n].to_vec()).unwrap();
        assert!(text.contains("MICROPOS_REMOTE=127.0.0.1:40001\n"), "{text}");
        assert!(
            text.contains("MESSAGE=move denied by http 127.0.0.1:40001 (role none)\n"),
            "{text}"
        );
        assert!(!text.contains("MICROPOS_UID"), "{text}");
        let t = Instant::now();
        let line: Value = loop {
            let text = std::fs::read_to_string(a.path()).unwrap_or_default();
            if let Some(l) = text.lines().next() {
                break serde_json::from_str(l).unwrap();
            }
            assert!(t.elapsed() < Duration::from_secs(20));
            std::thread::sleep(Duration::from_millis(5));
        };
        assert_eq!(line["via"], "http");
        assert_eq!(line["remote"], "127.0.0.1:40001");
        assert_eq!(line["role"], "none");
        assert_eq!(line["outcome"], "denied");
        assert_eq!(line.get("uid"), None);
    }

    #[test]
    fn under_systemd_the_fields_reach_the_journal_socket() {
        let dir = tempfile::tempdir().unwrap();
        let sock = dir.path().join("journal.sock");
        let journal = std::os::unix::net::UnixDatagram::bind(&sock).unwrap();
        journal
            .set_read_timeout(Some(Duration::from_secs(20)))
            .unwrap();
        let a = Audit::start_with(dir.path(), Some(sock));
        let peer = Peer {
            uid: 1001,
            gid: 1002,
            pid: Some(77),
        };
        let req = br#"{"cmd":"stop"}"#;
        let cmd = crate::daemon::protocol::parse_request(req).unwrap().command;
        a.record(&peer, Some(Role::Read), &cmd, Outcome::Allowed, req);
        let mut buf = vec![0u8; 4096];
        let n = journal.recv(&mut buf).unwrap();
        let text = String::from_utf8(buf[..n].to_vec()).unwrap();
        for field in [
            "MICROPOS_UID=1001\n",
            "MICROPOS_GID=1002\n",
            "MICROPOS_PID=77\n",
            "MICROPOS_CMD=stop\n",
            "MICROPOS_ROLE=read\n",
            "MICROPOS_OUTCOME=allowed\n",
            "MESSAGE=stop allowed by uid 1001 (pid 77, role read)\n",
        ] {
            assert!(text.contains(field), "{field:?} not in {text:?}");
        }
        assert_eq!(journal_entry(&[("A", "x\ny".into())]), b"A=x y\n");
    }

    fn peer() -> Peer {
        Peer {
            uid: 1001,
            gid: 1002,
            pid: Some(77),
        }
    }

    /// Waits until the writer has written `n` lines in total (all files).
    fn wait_lines(dir: &Path, n: usize) -> u64 {
        let t = Instant::now();
        loop {
            let mut lines = 0;
            let mut bytes = 0;
            for e in std::fs::read_dir(dir).unwrap() {
                let p = e.unwrap().path();
                if p.file_name()
                    .unwrap()
                    .to_string_lossy()
                    .starts_with(AUDIT_FILE)
                {
                    let text = std::fs::read_to_string(&p).unwrap_or_default();
                    lines += text.lines().count();
                    bytes += text.len() as u64;
                }
            }
            if lines >= n {
                return bytes;
            }
            assert!(
                t.elapsed() < Duration::from_secs(20),
                "{lines} of {n} lines"
            );
            std::thread::sleep(Duration::from_millis(5));
        }
    }

    #[test]
    fn a_huge_request_adds_a_bounded_record() {
        let dir = tempfile::tempdir().unwrap();
        let a = Audit::start(dir.path());
        let stop = crate::daemon::protocol::parse_request(br#"{"cmd":"stop"}"#)
            .unwrap()
            .command;
        let mut req = br#"{"cmd":"stop","x":""#.to_vec();
        req.resize(10_000_000, b'a');
        req.extend_from_slice(br#""}"#);
        a.record(&peer(), None, &stop, Outcome::Denied, &req);
        let small = format!(r#"{{"cmd":"stop","x":"{}"}}"#, "a".repeat(60_000));
        a.record(&peer(), None, &stop, Outcome::Denied, small.as_bytes());
        let bytes = wait_lines(dir.path(), 2);
        assert!(bytes < 2048, "{bytes} bytes for two records");
        let text = std::fs::read_to_string(a.path()).unwrap();
        let lines: Vec<Value> = text
            .lines()
            .map(|l| serde_json::from_str(l).unwrap())
            .collect();
        assert_eq!(lines[0]["request_bytes"], 10_000_002);
        assert_eq!(
            lines[1]["request"]["x"].as_str().unwrap().len(),
            SUMMARY_CHARS
        );
    }

    #[test]
    fn refused_requests_from_one_source_add_bounded_bytes() {
        let dir = tempfile::tempdir().unwrap();
        let limits = AuditLimits {
            rate_per_s: 0.001,
            burst: 10.0,
            ..AuditLimits::default()
        };
        let a = Audit::start_limited(dir.path(), None, limits);
        let req = format!(
            r#"{{"cmd":"move","x_um":5,"tolerance_um":{}}}"#,
            "1".repeat(30)
        );
        let cmd = crate::daemon::protocol::parse_request(br#"{"cmd":"move","x_um":5}"#)
            .unwrap()
            .command;
        for _ in 0..200 {
            a.record(
                &peer(),
                Some(Role::Read),
                &cmd,
                Outcome::Denied,
                req.as_bytes(),
            );
        }
        // Another source still gets its own records.
        let other = Peer { uid: 7, ..peer() };
        a.record(
            &other,
            Some(Role::Read),
            &cmd,
            Outcome::Denied,
            req.as_bytes(),
        );
        let bytes = wait_lines(dir.path(), 11);
        std::thread::sleep(Duration::from_millis(100));
        let text = std::fs::read_to_string(a.path()).unwrap();
        assert_eq!(text.lines().count(), 11, "{text}");
        assert!(bytes < 11 * 512, "{bytes}");
        // The limiter reports the drops when the rate allows again.
        let mut l = RateLimiter::new(&AuditLimits {
            rate_per_s: 1.0,
            burst: 1.0,
            ..AuditLimits::default()
        });
        let t0 = Instant::now();
        assert_eq!(l.admit("uid 1", t0), Some(0));
        assert_eq!(l.admit("uid 1", t0), None);
        assert_eq!(l.admit("uid 1", t0), None);
        assert_eq!(l.admit("uid 1", t0 + Duration::from_secs(1)), Some(2));
    }

    #[test]
    fn a_symlink_at_the_audit_file_is_not_followed() {
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("victim");
        std::fs::write(&target, "precious\n").unwrap();
        let data = dir.path().join("data");
        std::fs::create_dir(&data).unwrap();
        std::os::unix::fs::symlink(&target, data.join(AUDIT_FILE)).unwrap();
        // The writer run on this thread: when it returns, the record was
        // either written or refused.
        let (tx, rx) = sync_channel(1);
        tx.send(Record {
            line: "{}\n".to_owned(),
            journal: Vec::new(),
        })
        .unwrap();
        drop(tx);
        writer(&data.join(AUDIT_FILE), None, rx, &AuditLimits::default());
        assert_eq!(std::fs::read_to_string(&target).unwrap(), "precious\n");
        let err = open_audit(&data.join(AUDIT_FILE), true);
        assert!(err.is_none());
    }

    #[test]
    fn rotation_keeps_the_cap() {
        let dir = tempfile::tempdir().unwrap();
        let limits = AuditLimits {
            rate_per_s: 1e9,
            burst: 1e9,
            max_bytes: 4096,
            files: 2,
        };
        let a = Audit::start_limited(dir.path(), None, limits);
        let req = br#"{"cmd":"stop"}"#;
        let cmd = crate::daemon::protocol::parse_request(req).unwrap().command;
        for _ in 0..300 {
            a.record(&peer(), None, &cmd, Outcome::Allowed, req);
        }
        // Wait until the writer has drained the queue: the last line lands
        // in audit.jsonl, and then nothing changes any more.
        let t = Instant::now();
        let mut last = 0;
        loop {
            std::thread::sleep(Duration::from_millis(200));
            let n = std::fs::metadata(a.path()).map_or(0, |m| m.len());
            if n == last && n > 0 {
                break;
            }
            last = n;
            assert!(t.elapsed() < Duration::from_secs(20));
        }
        let mut total = 0;
        for k in 0..=2 {
            let len = std::fs::metadata(rotated(a.path(), k)).unwrap().len();
            assert!(len <= 4096, "file {k}: {len} bytes");
            total += len;
        }
        assert!(total <= 3 * 4096);
        assert!(!rotated(a.path(), 3).exists());
    }
}
