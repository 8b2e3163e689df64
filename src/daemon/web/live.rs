//! `GET /api/events`: the rig's event bus (the one `subscribe` forwards on
//! the socket) as server-sent events, every topic. Each SSE event is named
//! by its topic (`position`, `job`, `fault`, `drift`) and carries the very
//! line a socket subscriber gets; a stream opens with a `status` and a
//! `position` event (the replies of those commands) so a page has
//! something to show at once.
//!
//! A slow browser loses events (`lagged` says how many) rather than
//! slowing the daemon, as on the socket. Streams end at the daemon's
//! shutdown, and at most [`MAX_STREAMS`](super::shared::MAX_STREAMS) run
//! at once.

use super::shared::Web;
use crate::daemon::protocol::{self, Command};
use axum::extract::State;
use axum::http::StatusCode;
use axum::response::sse::{Event, KeepAlive, Sse};
use axum::response::{IntoResponse, Response};
use futures_util::stream::{self, Stream, StreamExt};
use std::convert::Infallible;
use std::sync::Arc;
use tokio::sync::broadcast;

/// `GET /api/events`.
pub async fn events(State(web): State<Arc<Web>>) -> Response {
    let Ok(permit) = web.streams.clone().try_acquire_owned() else {
        return (
            StatusCode::SERVICE_UNAVAILABLE,
            "too many event streams are open; close one",
        )
            .into_response();
    };
    // Subscribe before reading the state: nothing falls between the two.
    let rx = web.daemon.rig.subscribe();
    let shutdown = web.shutdown.subscribe();
    let mut first = Vec::new();
    for (name, cmd) in [("status", Command::Status), ("position", Command::Position)] {
        if let Ok(v) = web.daemon.execute(cmd).await {
            let fields = match v {
                serde_json::Value::Object(m) => m,
                _ => serde_json::Map::new(),
            };
            first.push(
                Event::default()
                    .event(name)
                    .data(protocol::event_line(name, fields).trim_end()),
            );
        }
    }
    let head = stream::iter(first.into_iter().map(Ok::<Event, Infallible>));
    let tail = bus_stream(rx, shutdown, permit);
    Sse::new(head.chain(tail))
        .keep_alive(KeepAlive::default())
        .into_response()
}

/// The bus as SSE events until shutdown; holds `permit` while it runs.
fn bus_stream(
    rx: broadcast::Receiver<crate::daemon::rig::Pushed>,
    shutdown: broadcast::Receiver<()>,
    permit: tokio::sync::OwnedSemaphorePermit,
) -> impl Stream<Item = Result<Event, Infallible>> {
    stream::unfold(
        (rx, shutdown, permit),
        |(mut rx, mut shutdown, permit)| async move {
            let ev = tokio::select! {
                r = rx.recv() => match r {
                    Ok(p) => Event::default()
                        .event(p.topic.as_str())
                        .data(p.line.trim_end()),
                    Err(broadcast::error::RecvError::Lagged(n)) => {
                        Event::default()
                            .event(protocol::LaggedEvent::NAME)
                            .data(protocol::LaggedEvent { missed: n }.line().trim_end())
                    }
                    Err(broadcast::error::RecvError::Closed) => return None,
                },
                _ = shutdown.recv() => return None,
            };
            Some((Ok(ev), (rx, shutdown, permit)))
        },
    )
}
