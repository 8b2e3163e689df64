//! The web listener (`[web]`, off by default): a live view of the rig for
//! browsers and `GET /metrics` for Prometheus, served by axum on the
//! daemon's runtime.
//!
//! The socket protocol stays the one source of truth: reads and commands
//! go through [`protocol::parse_request`](super::protocol::parse_request),
//! the role table ([`Command::role`](super::protocol::Command::role)),
//! the audit trail and [`Daemon::execute`](super::Daemon::execute); live data is the rig's own
//! event bus, the one `subscribe` forwards. Nothing is possible over HTTP
//! that the socket does not allow, and less without the token: an HTTP
//! client without it may only run read commands that change nothing (not
//! even `stop`).
//!
//! Files, one job each:
//! - [`router`]: the routes and the listener's lifetime;
//! - [`host`]: the `Host` allow-list (DNS rebinding);
//! - [`command`]: `POST /api/command` (token, role, audit, dispatch);
//! - [`live`]: `GET /api/events`, the event bus as server-sent events;
//! - [`camera`]: the downscaled camera frame and its overlay;
//! - [`metrics`]: `GET /metrics`, the scrape of `daemon::metrics` (OpenMetrics text);
//! - [`page`]: the embedded page (HTML, JS, CSS; no build step);
//! - [`shared`]: what every handler shares.

pub mod camera;
pub mod command;
pub mod host;
pub mod live;
pub mod metrics;
pub mod page;
pub mod router;
pub mod shared;

pub use router::{bind, serve, WebListener};
