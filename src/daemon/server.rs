//! Accepts clients on the Unix socket and serves each on its own task:
//! requests are answered in order; `stop` is executed the moment it is read,
//! even while an earlier request of the same client still runs, and pushed
//! events interleave with replies (whole lines, never mixed).
//!
//! `stop` always gets through: up to `daemon.max_clients` full clients,
//! then up to `daemon.stop_slots` connections that accept only `stop`
//! (everything else is `busy`), then a `busy` line and close; one uid
//! holds at most `max_clients_per_uid` and `stop_slots_per_uid` of them,
//! and a peer without a role is refused at connect
//! ([`admission`](super::admission)). Clients are
//! disconnected when idle (`idle_timeout_s`: nothing sent, no request
//! running, no subscription), when a started line stalls
//! (`read_timeout_s`), or when they stop reading (`write_timeout_s`), so
//! stuck clients give their slots back.
//!
//! Every request is checked against the client's role (`[access]`,
//! resolved once per connection from `SO_PEERCRED`); state-changing and
//! refused commands go to the audit trail before they run.

use super::access::Peer;
use super::admission::{Admission, Admit, Limits, Slot};
use super::audit::Origin;
use super::connection::{write_line, Incoming, LineReader};
use super::protocol::{self, Command, ErrorCode, ProtoError, Role, Topic};
use super::Daemon;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tokio::net::{UnixListener, UnixStream};
use tokio::sync::{broadcast, mpsc};

/// A slot held by a connection, given back when dropped.
struct Held {
    admission: Arc<Mutex<Admission>>,
    uid: u32,
    slot: Slot,
}

impl Drop for Held {
    fn drop(&mut self) {
        // A poisoned lock still holds the counts (no panic leaves them
        // half-updated: admit and release are plain arithmetic).
        let mut a = self
            .admission
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        a.release(self.uid, self.slot);
    }
}

/// The kernel's word on who connected; a socket without credentials
/// (never on Linux) is nobody.
fn peer_of(stream: &UnixStream) -> Peer {
    match stream.peer_cred() {
        Ok(c) => Peer {
            uid: c.uid(),
            gid: c.gid(),
            pid: c.pid(),
        },
        Err(e) => {
            tracing::warn!("no peer credentials: {e}");
            Peer {
                uid: u32::MAX,
                gid: u32::MAX,
                pid: None,
            }
        }
    }
}

/// Refuses a connection with one error line, best effort, never waiting.
fn refuse(stream: &UnixStream, code: ErrorCode, message: String) {
    let line = protocol::error_reply(&serde_json::Value::Null, &ProtoError::new(code, message));
    let _ = stream.try_write(line.as_bytes());
}

/// Accepts until shutdown.
pub async fn serve(
    daemon: Arc<Daemon>,
    listener: UnixListener,
    mut shutdown: broadcast::Receiver<()>,
) {
    let d = &daemon.rig.cfg.daemon;
    let admission = Arc::new(Mutex::new(Admission::new(Limits {
        max_clients: d.max_clients,
        max_clients_per_uid: d.max_clients_per_uid,
        stop_slots: d.stop_slots,
        stop_slots_per_uid: d.stop_slots_per_uid,
    })));
    loop {
        let stream = tokio::select! {
            r = listener.accept() => match r {
                Ok((s, _)) => s,
                Err(e) => {
                    tracing::warn!("accept failed: {e}");
                    tokio::time::sleep(Duration::from_millis(50)).await;
                    continue;
                }
            },
            _ = shutdown.recv() => return,
        };
        let d = daemon.clone();
        let admission = admission.clone();
        tokio::spawn(async move {
            let peer = peer_of(&stream);
            let role = d.access.role_of(peer).await;
            let admitted = admission
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner)
                .admit(peer.uid, role.is_some());
            let held = match admitted {
                Admit::Slot(slot) => Held {
                    admission,
                    uid: peer.uid,
                    slot,
                },
                Admit::NoRole => {
                    tracing::info!(uid = peer.uid, "client without a role refused at connect");
                    refuse(
                        &stream,
                        ErrorCode::PermissionDenied,
                        format!(
                            "uid {} has no role on this daemon ([access]): not even stop",
                            peer.uid
                        ),
                    );
                    return;
                }
                Admit::Busy => {
                    refuse(
                        &stream,
                        ErrorCode::Busy,
                        format!(
                            "every client slot and stop slot this user (uid {}) may hold, or every slot, is taken; try again",
                            peer.uid
                        ),
                    );
                    return;
                }
            };
            let sd = d.shutdown.subscribe();
            if let Err(e) = client(d, stream, peer, role, held.slot, sd).await {
                tracing::debug!("client ended: {e}");
            }
            drop(held);
        });
    }
}

fn secs(s: f64) -> Duration {
    Duration::try_from_secs_f64(s).unwrap_or(Duration::MAX)
}

/// Serves one connection until it closes, idles, stalls, stops reading or
/// the daemon shuts down; then lets its queued requests finish and their
/// replies go out.
async fn client(
    daemon: Arc<Daemon>,
    stream: UnixStream,
    peer: Peer,
    role: Option<Role>,
    slot: Slot,
    mut shutdown: broadcast::Receiver<()>,
) -> std::io::Result<()> {
    let cfg = &daemon.rig.cfg.daemon;
    let read_timeout = secs(cfg.read_timeout_s);
    let idle_timeout = match slot {
        Slot::StopOnly => Some(read_timeout),
        Slot::Full if cfg.idle_timeout_s > 0.0 => Some(secs(cfg.idle_timeout_s)),
        Slot::Full => None,
    };
    tracing::debug!(
        uid = peer.uid,
        gid = peer.gid,
        pid = peer.pid.unwrap_or(-1),
        role = role.map_or("none", Role::as_str),
        stop_only = slot == Slot::StopOnly,
        "client connected"
    );
    let (r, w) = stream.into_split();
    let mut reader = LineReader::new(r);
    let (out_tx, mut gone_rx, writer) = spawn_writer(w, secs(cfg.write_timeout_s));
    let busy = Busy::default();
    let (req_tx, worker) = spawn_worker(&daemon, &out_tx, &busy);
    let conn = Conn {
        daemon: &daemon,
        peer,
        role,
        slot,
        busy: &busy,
        req_tx: &req_tx,
    };
    let null = serde_json::Value::Null;
    let timed_out =
        |why: String| protocol::error_reply(&null, &ProtoError::new(ErrorCode::TimedOut, why));
    loop {
        let incoming = tokio::select! {
            r = reader.next_within(idle_timeout, Some(read_timeout)) => r?,
            _ = shutdown.recv() => {
                let _ = out_tx.send(protocol::error_reply(&null, &ProtoError::new(ErrorCode::ShuttingDown, "the daemon is shutting down")).into()).await;
                break;
            }
            _ = &mut gone_rx => break,
        };
        let line = match incoming {
            Incoming::Closed => break,
            Incoming::Idle if slot == Slot::Full && busy.any() => continue,
            Incoming::Idle => {
                let idle = idle_timeout.unwrap_or_default();
                let _ = out_tx
                    .send(timed_out(format!("idle for {idle:?}: disconnected")).into())
                    .await;
                break;
            }
            Incoming::Stalled => {
                let why =
                    format!("request line not finished within {read_timeout:?}: disconnected");
                let _ = out_tx.send(timed_out(why).into()).await;
                break;
            }
            Incoming::TooLarge(n) => protocol::error_reply(&null, &protocol::too_large(n)),
            Incoming::Line(l) if l.iter().all(u8::is_ascii_whitespace) => continue,
            Incoming::Line(l) => match conn.answer(&l).await {
                Some(reply) => reply,
                None => continue,
            },
        };
        if out_tx.send(line.into()).await.is_err() {
            break;
        }
    }
    // Let queued requests finish and their replies go out, then close.
    drop(req_tx);
    let _ = worker.await;
    drop(out_tx);
    let _ = writer.await;
    Ok(())
}

/// Replies and events go through one writer task so lines never mix. A
/// client that does not take a line within `write_timeout` is gone: the
/// returned receiver then resolves.
fn spawn_writer(
    mut w: tokio::net::unix::OwnedWriteHalf,
    write_timeout: Duration,
) -> (
    mpsc::Sender<Arc<str>>,
    tokio::sync::oneshot::Receiver<()>,
    tokio::task::JoinHandle<()>,
) {
    let (out_tx, mut out_rx) = mpsc::channel::<Arc<str>>(256);
    let (gone_tx, gone_rx) = tokio::sync::oneshot::channel::<()>();
    let writer = tokio::spawn(async move {
        while let Some(line) = out_rx.recv().await {
            match tokio::time::timeout(write_timeout, write_line(&mut w, &line)).await {
                Ok(Ok(())) => {}
                Ok(Err(_)) => break,
                Err(_) => {
                    tracing::info!("client not reading for {write_timeout:?}: disconnected");
                    break;
                }
            }
        }
        drop(gone_tx);
    });
    (out_tx, gone_rx, writer)
}

/// Whether a connection has work in flight: then it is not idle.
#[derive(Default)]
struct Busy {
    /// Requests queued or running.
    pending: Arc<AtomicUsize>,
    /// Whether it subscribed to events.
    subscribed: Arc<AtomicBool>,
}

impl Busy {
    fn any(&self) -> bool {
        self.pending.load(Ordering::Relaxed) > 0 || self.subscribed.load(Ordering::Relaxed)
    }
}

/// The worker that runs a connection's requests in order (`stop`
/// bypasses it) and sends their replies; a `subscribe` starts the event
/// forwarder, replacing the one before.
fn spawn_worker(
    daemon: &Arc<Daemon>,
    out: &mpsc::Sender<Arc<str>>,
    busy: &Busy,
) -> (mpsc::Sender<protocol::Request>, tokio::task::JoinHandle<()>) {
    let (req_tx, mut req_rx) = mpsc::channel::<protocol::Request>(MAX_PENDING);
    let daemon = daemon.clone();
    let out = out.clone();
    let pending = busy.pending.clone();
    let subscribed = busy.subscribed.clone();
    let worker = tokio::spawn(async move {
        let mut subscription: Option<tokio::task::JoinHandle<()>> = None;
        while let Some(req) = req_rx.recv().await {
            let line = match req.command {
                Command::Subscribe(topics) => {
                    if let Some(s) = subscription.take() {
                        s.abort();
                    }
                    subscription = Some(spawn_forwarder(&daemon, topics.clone(), out.clone()));
                    subscribed.store(true, Ordering::Relaxed);
                    let subscribed = topics.iter().map(|t| t.as_str().to_owned()).collect();
                    protocol::ok_reply(
                        &req.id,
                        protocol::reply_fields(protocol::to_value(&protocol::SubscribeReply {
                            subscribed,
                        })),
                    )
                }
                cmd => protocol::reply(&req.id, daemon.execute(cmd).await),
            };
            let sent = out.send(line.into()).await;
            pending.fetch_sub(1, Ordering::Relaxed);
            if sent.is_err() {
                break;
            }
        }
        if let Some(s) = subscription {
            s.abort();
        }
    });
    (req_tx, worker)
}

/// Most requests a connection may have queued behind the one running.
const MAX_PENDING: usize = 64;

/// A connection as its request lines are answered.
struct Conn<'a> {
    daemon: &'a Arc<Daemon>,
    peer: Peer,
    role: Option<Role>,
    slot: Slot,
    busy: &'a Busy,
    req_tx: &'a mpsc::Sender<protocol::Request>,
}

impl Conn<'_> {
    /// The reply to one request line now, or `None` when the request was
    /// queued for the worker (its reply comes from there). A stop-only
    /// connection takes nothing but `stop`; every request passes the role
    /// check and the audit ([`Audit::admit`](super::audit::Audit::admit));
    /// `stop` runs at once, overtaking anything queued.
    async fn answer(&self, l: &[u8]) -> Option<String> {
        let req = match protocol::parse_request(l) {
            Err(r) => return Some(protocol::error_reply(&r.id, &r.error)),
            Ok(req) => req,
        };
        if self.slot == Slot::StopOnly && req.command != Command::Stop {
            let why = format!(
                "all {} client slots are taken; this connection accepts only stop",
                self.daemon.rig.cfg.daemon.max_clients
            );
            return Some(protocol::error_reply(
                &req.id,
                &ProtoError::new(ErrorCode::Busy, why),
            ));
        }
        let permitted = self.role >= Some(req.command.role());
        let origin = Origin::Socket(self.peer);
        if !self
            .daemon
            .audit
            .admit(origin, self.role, &req.command, l, permitted)
        {
            let why = format!(
                "{} needs role {}; uid {} has {}",
                req.command.name(),
                req.command.role().as_str(),
                self.peer.uid,
                self.role.map_or("none", Role::as_str)
            );
            return Some(protocol::error_reply(
                &req.id,
                &ProtoError::new(ErrorCode::PermissionDenied, why),
            ));
        }
        if req.command == Command::Stop {
            return Some(protocol::reply(
                &req.id,
                self.daemon.execute(Command::Stop).await,
            ));
        }
        let id = req.id.clone();
        self.busy.pending.fetch_add(1, Ordering::Relaxed);
        match self.req_tx.try_send(req) {
            Ok(()) => None,
            Err(_) => {
                self.busy.pending.fetch_sub(1, Ordering::Relaxed);
                Some(protocol::error_reply(
                    &id,
                    &ProtoError::new(
                        ErrorCode::Busy,
                        "more than 64 requests pending on this connection; wait for replies",
                    ),
                ))
            }
        }
    }
}

fn spawn_forwarder(
    daemon: &Arc<Daemon>,
    topics: Vec<Topic>,
    out: mpsc::Sender<Arc<str>>,
) -> tokio::task::JoinHandle<()> {
    let mut rx = daemon.rig.subscribe();
    tokio::spawn(async move {
        loop {
            match rx.recv().await {
                Ok(ev) => {
                    if topics.contains(&ev.topic) {
                        // A slow client loses events rather than slowing the daemon.
                        if let Err(mpsc::error::TrySendError::Closed(_)) =
                            out.try_send(ev.line.clone())
                        {
                            return;
                        }
                    }
                }
                Err(broadcast::error::RecvError::Lagged(n)) => {
                    let line = protocol::LaggedEvent { missed: n }.line();
                    let _ = out.try_send(line.into());
                }
                Err(broadcast::error::RecvError::Closed) => return,
            }
        }
    })
}
