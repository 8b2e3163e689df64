//! What every web handler shares ([`Web`]) and the cap on event streams:
//! a leaf the router and the handlers all import.

use super::camera;
use crate::daemon::protocol::Role;
use crate::daemon::Daemon;
use std::sync::Arc;
use tokio::sync::{broadcast, Semaphore};

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
