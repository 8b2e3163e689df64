//! Accepts clients on the Unix socket and serves each on its own task:
//! requests are answered in order; `stop` is executed the moment it is read,
//! even while an earlier request of the same client still runs, and pushed
//! events interleave with replies (whole lines, never mixed).

use super::connection::{write_line, Incoming, LineReader};
use super::protocol::{self, Command, ErrorCode, ProtoError, Topic};
use super::Daemon;
use std::sync::Arc;
use tokio::net::{UnixListener, UnixStream};
use tokio::sync::{broadcast, mpsc, Semaphore};

/// Accepts until shutdown.
pub async fn serve(
    daemon: Arc<Daemon>,
    listener: UnixListener,
    mut shutdown: broadcast::Receiver<()>,
) {
    let limit = Arc::new(Semaphore::new(daemon.rig.cfg.daemon.max_clients));
    loop {
        let permit = tokio::select! {
            p = limit.clone().acquire_owned() => match p { Ok(p) => p, Err(_) => return },
            _ = shutdown.recv() => return,
        };
        let stream = tokio::select! {
            r = listener.accept() => match r {
                Ok((s, _)) => s,
                Err(e) => {
                    tracing::warn!("accept failed: {e}");
                    tokio::time::sleep(std::time::Duration::from_millis(50)).await;
                    continue;
                }
            },
            _ = shutdown.recv() => return,
        };
        let d = daemon.clone();
        let sd = d.shutdown.subscribe();
        tokio::spawn(async move {
            if let Err(e) = client(d, stream, sd).await {
                tracing::debug!("client ended: {e}");
            }
            drop(permit);
        });
    }
}

async fn client(
    daemon: Arc<Daemon>,
    stream: UnixStream,
    mut shutdown: broadcast::Receiver<()>,
) -> std::io::Result<()> {
    let (r, mut w) = stream.into_split();
    let mut reader = LineReader::new(r);
    // Replies and events go through one writer task so lines never mix.
    let (out_tx, mut out_rx) = mpsc::channel::<Arc<str>>(256);
    let writer = tokio::spawn(async move {
        while let Some(line) = out_rx.recv().await {
            if write_line(&mut w, &line).await.is_err() {
                break;
            }
        }
    });
    // Requests run in order on a worker; stop bypasses it.
    let (req_tx, mut req_rx) = mpsc::channel::<protocol::Request>(64);
    let worker = {
        let daemon = daemon.clone();
        let out = out_tx.clone();
        tokio::spawn(async move {
            let mut subscription: Option<tokio::task::JoinHandle<()>> = None;
            while let Some(req) = req_rx.recv().await {
                let line = match req.command {
                    Command::Subscribe(topics) => {
                        if let Some(s) = subscription.take() {
                            s.abort();
                        }
                        subscription = Some(spawn_forwarder(&daemon, topics.clone(), out.clone()));
                        let names: Vec<&str> = topics.iter().map(|t| t.as_str()).collect();
                        protocol::ok_reply(&req.id, obj(serde_json::json!({"subscribed": names})))
                    }
                    cmd => match daemon.execute(cmd).await {
                        Ok(v) => protocol::ok_reply(&req.id, obj(v)),
                        Err(e) => protocol::error_reply(&req.id, &e),
                    },
                };
                if out.send(line.into()).await.is_err() {
                    break;
                }
            }
            if let Some(s) = subscription {
                s.abort();
            }
        })
    };
    loop {
        let incoming = tokio::select! {
            r = reader.next() => r?,
            _ = shutdown.recv() => {
                let _ = out_tx.send(protocol::error_reply(&serde_json::Value::Null, &ProtoError::new(ErrorCode::ShuttingDown, "the daemon is shutting down")).into()).await;
                break;
            }
        };
        let line = match incoming {
            Incoming::Closed => break,
            Incoming::TooLarge(n) => {
                protocol::error_reply(&serde_json::Value::Null, &protocol::too_large(n))
            }
            Incoming::Line(l) if l.iter().all(u8::is_ascii_whitespace) => continue,
            Incoming::Line(l) => match protocol::parse_request(&l) {
                Err(r) => protocol::error_reply(&r.id, &r.error),
                Ok(req) if req.command == Command::Stop => {
                    // Overtakes anything queued on this connection too.
                    match daemon.execute(Command::Stop).await {
                        Ok(v) => protocol::ok_reply(&req.id, obj(v)),
                        Err(e) => protocol::error_reply(&req.id, &e),
                    }
                }
                Ok(req) => {
                    let id = req.id.clone();
                    match req_tx.try_send(req) {
                        Ok(()) => continue,
                        Err(_) => protocol::error_reply(&id, &ProtoError::new(ErrorCode::Busy, "more than 64 requests pending on this connection; wait for replies")),
                    }
                }
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
                    let line =
                        protocol::event_line("lagged", obj(serde_json::json!({"missed": n})));
                    let _ = out.try_send(line.into());
                }
                Err(broadcast::error::RecvError::Closed) => return,
            }
        }
    })
}

fn obj(v: serde_json::Value) -> serde_json::Map<String, serde_json::Value> {
    match v {
        serde_json::Value::Object(m) => m,
        other => {
            let mut m = serde_json::Map::new();
            m.insert("result".to_owned(), other);
            m
        }
    }
}
