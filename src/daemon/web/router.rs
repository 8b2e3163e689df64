//! The routes of the web listener and its lifetime: bound at start (a bad
//! address stops the daemon with a message), served until the daemon's
//! shutdown, which also ends every event stream.

use super::{camera, command, live, page};
use crate::daemon::config::WebSection;
use crate::daemon::protocol::{ErrorCode, ProtoError, Role};
use crate::daemon::Daemon;
use axum::extract::{Query, State};
use axum::http::{header, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::Router;
use serde::Deserialize;
use serde_json::json;
use std::net::SocketAddr;
use std::sync::Arc;
use tokio::sync::{broadcast, Semaphore};

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
    })
}

/// What every handler shares.
#[derive(Debug)]
pub struct Web {
    /// The daemon.
    pub daemon: Arc<Daemon>,
    /// The bearer token; `None`: no command beyond anonymous reads.
    pub token: Option<String>,
    /// The role of a client holding the token.
    pub role: Role,
    /// The camera view, if a camera is configured.
    pub camera: Option<camera::CameraView>,
    /// Event streams open at most at once.
    pub streams: Arc<Semaphore>,
    /// Ends event streams at shutdown.
    pub shutdown: broadcast::Sender<()>,
}

/// Event streams served at once at most (each holds a bus receiver).
pub const MAX_STREAMS: usize = 32;

/// The routes.
pub fn router(web: Arc<Web>) -> Router {
    Router::new()
        .route("/", get(page::index))
        .route("/app.js", get(page::app_js))
        .route("/style.css", get(page::style_css))
        .route("/api/events", get(live::events))
        .route("/api/command", post(command::command))
        .route("/api/camera", get(camera_overlay))
        .route("/api/camera.png", get(camera_png))
        .route("/metrics", get(metrics_text))
        .with_state(web)
}

/// Serves until the daemon's shutdown.
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
    let app = router(web).into_make_service_with_connect_info::<SocketAddr>();
    let r = axum::serve(l.listener, app)
        .with_graceful_shutdown(async move {
            let _ = shutdown.recv().await;
        })
        .await;
    if let Err(e) = r {
        tracing::error!("web listener failed: {e}");
    }
}

fn json_response(status: StatusCode, v: serde_json::Value) -> Response {
    (status, [(header::CACHE_CONTROL, "no-store")], axum::Json(v)).into_response()
}

/// `GET /api/camera`: the overlay of the newest render (`sequence` null
/// while no frame was kept yet; the first request starts the tap;
/// `camera: false` without a camera).
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
