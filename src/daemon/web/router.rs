//! The routes of the web listener and its lifetime: bound at start (a bad
//! address stops the daemon with a message), served until the daemon's
//! shutdown, which also ends every event stream.
//!
//! Why an accept loop of its own instead of `axum::serve`: the listener may
//! face a network, so it caps the connections it holds open
//! ([`MAX_CONNECTIONS`]) and closes those that idle or never finish a
//! request header ([`IDLE_TIMEOUT`]); `axum::serve` does neither.

use super::shared::{Web, MAX_STREAMS};
use super::{camera, command, host, live, page};
use crate::daemon::config::WebSection;
use crate::daemon::protocol::{ErrorCode, ProtoError, Role};
use crate::daemon::Daemon;
use axum::extract::{ConnectInfo, Query, State};
use axum::http::{header, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::{Extension, Router};
use hyper_util::rt::{TokioIo, TokioTimer};
use hyper_util::service::TowerToHyperService;
use serde::Deserialize;
use serde_json::json;
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;
use tokio::sync::Semaphore;

/// A bound web listener and what its clients may do.
#[derive(Debug)]
pub struct WebListener {
    listener: tokio::net::TcpListener,
    /// The bound address (the real port when `listen` asked for port 0).
    pub addr: SocketAddr,
    token: Option<String>,
    role: Role,
    camera_max_hz: f64,
    camera_max_px: u32,
    /// `[web] hosts`: `Host` names allowed besides the loopback ones.
    hosts: Vec<String>,
}

/// Binds `[web] listen` and reads the token (`token_file`); must be called
/// inside a tokio runtime. Warns when the address is not loopback: the
/// view and `/metrics` then reach every machine that can route to it.
pub fn bind(cfg: &WebSection) -> Result<WebListener, ProtoError> {
    let bad =
        |e: crate::daemon::config::ConfigError| ProtoError::new(ErrorCode::BadValue, e.to_string());
    let addr = cfg.listen_addr().map_err(bad)?;
    let role = cfg.role().map_err(bad)?;
    let token = cfg.resolve_token().map_err(bad)?;
    let std_listener = std::net::TcpListener::bind(addr).map_err(|e| {
        ProtoError::new(
            ErrorCode::Internal,
            format!("web.listen {addr}: cannot bind: {e}"),
        )
    })?;
    std_listener
        .set_nonblocking(true)
        .map_err(|e| ProtoError::new(ErrorCode::Internal, format!("web.listen {addr}: {e}")))?;
    let listener = tokio::net::TcpListener::from_std(std_listener)
        .map_err(|e| ProtoError::new(ErrorCode::Internal, format!("web.listen {addr}: {e}")))?;
    let addr = listener.local_addr().unwrap_or(addr);
    if !addr.ip().is_loopback() {
        tracing::warn!(
            "web view on {addr}, a non-loopback address: the rig's state, camera image and metrics are visible to every host that can reach it{}",
            if token.is_some() { "; commands need the token" } else { "" }
        );
    } else {
        tracing::info!("web view on http://{addr}/");
    }
    Ok(WebListener {
        listener,
        addr,
        token,
        role,
        camera_max_hz: cfg.camera_max_hz,
        camera_max_px: cfg.camera_max_px,
        hosts: cfg.hosts.clone(),
    })
}

/// The routes, every one behind the `Host` allow-list
/// ([`host::check`]).
pub fn router(web: Arc<Web>, hosts: Arc<Vec<String>>) -> Router {
    let routes = Router::new()
        .route("/", get(page::index))
        .route("/app.js", get(page::app_js))
        .route("/figures.js", get(page::figures_js))
        .route("/style.css", get(page::style_css))
        .route("/api/events", get(live::events))
        .route("/api/command", post(command::command))
        .route("/api/camera", get(camera_overlay))
        .route("/api/camera.png", get(camera_png))
        .route("/metrics", get(metrics_text))
        .with_state(web);
    behind_host_check(routes, hosts)
}

/// `routes` behind the `Host` allow-list ([`host::check`]).
fn behind_host_check(routes: Router, hosts: Arc<Vec<String>>) -> Router {
    routes.layer(axum::middleware::from_fn(move |req, next| {
        host::check(hosts.clone(), req, next)
    }))
}

/// HTTP connections open at once at most (event streams included, which
/// have their own cap, [`MAX_STREAMS`]); a connection beyond it is closed
/// as soon as it is accepted, so a flood of clients costs a socket each and
/// nothing more.
pub const MAX_CONNECTIONS: usize = 64;

/// Ordinary connections one source address may hold at once: one
/// address (a script gone wrong, a flood) cannot take all
/// [`MAX_CONNECTIONS`].
pub const MAX_PER_SOURCE: usize = 16;

/// Connections beyond the ordinary ones that serve only the web STOP
/// (`POST /api/command` with `stop`; everything else 503), one per source
/// address, each closed after [`STOP_SLOT_TIMEOUT`]: when a flood holds
/// every ordinary connection, an operator's STOP still gets through.
pub const STOP_SLOTS: usize = 8;

/// How long a stop slot's connection may take to send its request and
/// receive the answer.
pub const STOP_SLOT_TIMEOUT: Duration = Duration::from_secs(5);

/// A connection that has not sent a complete request header this long
/// after it opened, or after its last response, is closed (hyper's header
/// read timeout, which also runs while a keep-alive connection idles).
pub const IDLE_TIMEOUT: Duration = Duration::from_secs(30);

/// How long the shutdown waits for open connections to finish their
/// responses (event streams end at once on shutdown).
const DRAIN_TIMEOUT: Duration = Duration::from_secs(5);

/// Serves until the daemon's shutdown: accepts at most
/// [`MAX_CONNECTIONS`] connections at once, each an HTTP/1.1 connection
/// with the [`IDLE_TIMEOUT`]; at shutdown stops accepting, lets open
/// connections finish their current response and waits for them
/// (bounded).
pub async fn serve(daemon: Arc<Daemon>, l: WebListener) {
    let camera = daemon
        .rig
        .vision
        .as_ref()
        .map(|v| camera::CameraView::new(v.tap.clone(), l.camera_max_hz, l.camera_max_px));
    let mut shutdown = daemon.shutdown.subscribe();
    let web = Arc::new(Web {
        daemon: daemon.clone(),
        token: l.token,
        role: l.role,
        camera,
        streams: Arc::new(Semaphore::new(MAX_STREAMS)),
        shutdown: daemon.shutdown.clone(),
    });
    let hosts = Arc::new(l.hosts);
    let stop_app = stop_router(web.clone(), hosts.clone());
    let app = router(web, hosts);
    let open = Arc::new(Semaphore::new(MAX_CONNECTIONS));
    let stop_slots = Arc::new(Semaphore::new(STOP_SLOTS));
    let per_source = Sources::default();
    let stop_sources = Sources::default();
    loop {
        // Subscribed before the accept: a shutdown sent after it reaches
        // the connection accepted now.
        let stop = daemon.shutdown.subscribe();
        let (stream, remote) = tokio::select! {
            _ = shutdown.recv() => break,
            r = l.listener.accept() => match r {
                Ok(c) => c,
                Err(e) => {
                    // Out of file descriptors and the like: wait instead of
                    // spinning on the same error.
                    tracing::warn!("web listener: accept failed: {e}");
                    tokio::time::sleep(Duration::from_millis(100)).await;
                    continue;
                }
            },
        };
        let ip = remote.ip();
        if let Some(slot) = per_source.take(ip, MAX_PER_SOURCE) {
            if let Ok(permit) = open.clone().try_acquire_owned() {
                let svc =
                    TowerToHyperService::new(app.clone().layer(Extension(ConnectInfo(remote))));
                tokio::spawn(async move {
                    let _held = (permit, slot);
                    serve_connection(stream, svc, remote, stop, None).await;
                });
                continue;
            }
        }
        let (Some(slot), Ok(permit)) = (
            stop_sources.take(ip, 1),
            stop_slots.clone().try_acquire_owned(),
        ) else {
            tracing::debug!("web listener: {remote} refused, its connections or all are taken");
            drop(stream);
            continue;
        };
        tracing::debug!("web listener: {remote} on a stop slot");
        let svc = TowerToHyperService::new(
            stop_app
                .clone()
                .layer(Extension(ConnectInfo(remote)))
                .layer(Extension(command::StopOnly)),
        );
        tokio::spawn(async move {
            let _held = (permit, slot);
            serve_connection(stream, svc, remote, stop, Some(STOP_SLOT_TIMEOUT)).await;
        });
    }
    let _ = tokio::time::timeout(
        DRAIN_TIMEOUT,
        open.acquire_many(u32::try_from(MAX_CONNECTIONS).unwrap_or(u32::MAX)),
    )
    .await;
}

/// One HTTP/1.1 connection until it ends, the daemon shuts down, or
/// `limit` (stop slots) passes.
async fn serve_connection<S>(
    stream: tokio::net::TcpStream,
    svc: S,
    remote: SocketAddr,
    mut stop: tokio::sync::broadcast::Receiver<()>,
    limit: Option<Duration>,
) where
    S: hyper::service::Service<
            hyper::Request<hyper::body::Incoming>,
            Response = hyper::Response<axum::body::Body>,
        > + 'static,
    S::Error: Into<Box<dyn std::error::Error + Send + Sync>>,
    S::Future: 'static,
{
    let conn = hyper::server::conn::http1::Builder::new()
        .timer(TokioTimer::new())
        .header_read_timeout(limit.unwrap_or(IDLE_TIMEOUT).min(IDLE_TIMEOUT))
        .serve_connection(TokioIo::new(stream), svc);
    tokio::pin!(conn);
    let deadline = async {
        match limit {
            Some(l) => tokio::time::sleep(l).await,
            None => std::future::pending().await,
        }
    };
    let r = tokio::select! {
        r = conn.as_mut() => r,
        _ = stop.recv() => {
            conn.as_mut().graceful_shutdown();
            conn.await
        }
        () = deadline => {
            tracing::debug!("web connection {remote}: stop slot closed after {limit:?}");
            return;
        }
    };
    if let Err(e) = r {
        tracing::debug!("web connection {remote}: {e}");
    }
}

/// Connections held per source address; a [`SourceSlot`] gives its one
/// back when dropped.
#[derive(Debug, Clone, Default)]
struct Sources(Arc<std::sync::Mutex<std::collections::HashMap<std::net::IpAddr, usize>>>);

impl Sources {
    /// One more connection of `ip`, if it holds fewer than `max`.
    fn take(&self, ip: std::net::IpAddr, max: usize) -> Option<SourceSlot> {
        let mut m = self.0.lock().unwrap_or_else(|p| p.into_inner());
        let n = m.entry(ip).or_insert(0);
        if *n >= max {
            return None;
        }
        *n += 1;
        Some(SourceSlot {
            sources: self.clone(),
            ip,
        })
    }
}

/// One connection of a source address, counted in [`Sources`].
#[derive(Debug)]
struct SourceSlot {
    sources: Sources,
    ip: std::net::IpAddr,
}

impl Drop for SourceSlot {
    fn drop(&mut self) {
        let mut m = self.sources.0.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(n) = m.get_mut(&self.ip) {
            *n = n.saturating_sub(1);
            if *n == 0 {
                m.remove(&self.ip);
            }
        }
    }
}

/// The routes of a stop slot: `POST /api/command` (which serves only
/// `stop` there), everything else 503; behind the same `Host` allow-list.
fn stop_router(web: Arc<Web>, hosts: Arc<Vec<String>>) -> Router {
    let routes = Router::new()
        .route("/api/command", post(command::command))
        .fallback(|| async {
            (
                StatusCode::SERVICE_UNAVAILABLE,
                [(header::RETRY_AFTER, "1")],
                "the web listener's connections are all taken; this connection serves only POST /api/command {\"cmd\":\"stop\"}\n",
            )
        })
        .with_state(web);
    behind_host_check(routes, hosts)
}

fn json_response(status: StatusCode, v: serde_json::Value) -> Response {
    (status, [(header::CACHE_CONTROL, "no-store")], axum::Json(v)).into_response()
}

/// `GET /api/camera`: the overlay of the newest render (`sequence` null
/// while the camera has delivered no frame yet; `camera: false` without a
/// camera).
async fn camera_overlay(State(web): State<Arc<Web>>) -> Response {
    let Some(view) = &web.camera else {
        return json_response(StatusCode::OK, json!({"camera": false, "sequence": null}));
    };
    match view.current().await {
        Some(r) => json_response(StatusCode::OK, r.overlay),
        None => json_response(StatusCode::OK, json!({"sequence": null})),
    }
}

/// `?seq=N` of `GET /api/camera.png`.
#[derive(Debug, Deserialize)]
struct SeqQuery {
    seq: Option<u64>,
}

/// `GET /api/camera.png[?seq=N]`: the render of frame `N` if still kept,
/// else the newest.
async fn camera_png(State(web): State<Arc<Web>>, Query(q): Query<SeqQuery>) -> Response {
    let Some(view) = &web.camera else {
        return StatusCode::NOT_FOUND.into_response();
    };
    let r = match q.seq {
        Some(n) => match view.by_sequence(n).await {
            Some(r) => Some(r),
            None => view.current().await,
        },
        None => view.current().await,
    };
    match r {
        Some(r) => (
            [
                (header::CONTENT_TYPE, "image/png".to_owned()),
                (header::CACHE_CONTROL, "no-store".to_owned()),
                (
                    header::HeaderName::from_static("x-micropos-sequence"),
                    r.sequence.to_string(),
                ),
            ],
            r.png.as_ref().clone(),
        )
            .into_response(),
        None => StatusCode::SERVICE_UNAVAILABLE.into_response(),
    }
}

/// `GET /metrics`.
async fn metrics_text(State(web): State<Arc<Web>>) -> Response {
    match web.daemon.rig.metrics.render(&web.daemon) {
        Ok(text) => (
            [(
                header::CONTENT_TYPE,
                "application/openmetrics-text; version=1.0.0; charset=utf-8",
            )],
            text,
        )
            .into_response(),
        Err(_) => StatusCode::INTERNAL_SERVER_ERROR.into_response(),
    }
}
