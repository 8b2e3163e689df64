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

use super::access::Peer;
use super::protocol::{Command, Role};
use crate::clock::UtcTime;
use serde_json::{json, Value};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{sync_channel, Receiver, SyncSender, TrySendError};
use std::sync::Arc;

/// Records queued for the file at most; beyond, records are dropped.
const QUEUE: usize = 4096;

/// Name of the audit file inside the data directory.
pub const AUDIT_FILE: &str = "audit.jsonl";

/// journald's native protocol socket.
pub const JOURNAL_SOCKET: &str = "/run/systemd/journal/socket";

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
}

impl Audit {
    /// Starts the writer thread for `data_dir/audit.jsonl` (the file, and
    /// the directory if missing, are created at the first record; the file
    /// with mode 0640 before the umask).
    pub fn start(data_dir: &Path) -> Audit {
        let journal = std::env::var_os("JOURNAL_STREAM").map(|_| PathBuf::from(JOURNAL_SOCKET));
        Self::start_with(data_dir, journal)
    }

    /// [`Audit::start`] with an explicit journald socket (`None`: none).
    pub fn start_with(data_dir: &Path, journal: Option<PathBuf>) -> Audit {
        let path = data_dir.join(AUDIT_FILE);
        let (tx, rx) = sync_channel(QUEUE);
        let p = path.clone();
        let j = journal.clone();
        let spawned = std::thread::Builder::new()
            .name("microposd-audit".to_owned())
            .spawn(move || writer(&p, j.as_deref(), rx));
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
        }
    }

    /// The audit file's path.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Records one command of `peer` (holding `role`); `request` is the
    /// request line as received (kept in the record when it is JSON).
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

    /// [`Audit::record`] for a client on either listener.
    pub fn record_from(
        &self,
        origin: Origin,
        role: Option<Role>,
        cmd: &Command,
        outcome: Outcome,
        request: &[u8],
    ) {
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
        let request: Value = serde_json::from_slice(request).unwrap_or(Value::Null);
        let mut rec = json!({
            "time": UtcTime::from_unix(unix as u64).rfc3339(),
            "unix_s": unix,
            "role": role_s,
            "cmd": cmd.name(),
            "outcome": outcome.as_str(),
            "request": request,
        });
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

/// Appends each line; reopens after an error so a transient failure (disk
/// full, directory recreated) costs only the records written meanwhile.
fn writer(path: &Path, journal: Option<&Path>, rx: Receiver<Record>) {
    use std::os::unix::fs::OpenOptionsExt;
    let mut file: Option<std::fs::File> = None;
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
        if file.is_none() {
            if let Some(dir) = path.parent() {
                let _ = std::fs::create_dir_all(dir);
            }
            file = std::fs::OpenOptions::new()
                .create(true)
                .append(true)
                .mode(0o640)
                .open(path)
                .map_err(|e| {
                    if !failing {
                        tracing::error!("audit: cannot open {}: {e}", path.display());
                    }
                })
                .ok();
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
}
