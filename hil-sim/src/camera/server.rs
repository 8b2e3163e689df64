//! Serves the simulated camera on a Unix socket (`DIR/camera.sock`), with
//! the protocol of `micropos::camera::simsocket` (shared definition).
//!
//! The socket handling is `crate::linesock`'s; this file answers the lines:
//! a request line that is not `{"grab":true}` gets an error reply; a
//! stalled camera never answers (the client times out, as with a hung
//! camera).

use super::{GrabError, SimCamera};
use crate::fault::SimError;
use crate::linesock::{LineHandler, LineServer};
use micropos::camera::simsocket::{encode_payload, error_line, FrameHeader};
use std::path::Path;
use std::sync::Arc;

/// Longest request line accepted.
const MAX_REQUEST: usize = 4096;

/// What one request line asks for.
fn is_grab(line: &str) -> Result<(), String> {
    let v: serde_json::Value =
        serde_json::from_str(line.trim()).map_err(|e| format!("request is not JSON: {e}"))?;
    if v.get("grab").and_then(serde_json::Value::as_bool) == Some(true) {
        Ok(())
    } else {
        Err("unknown request (expected {\"grab\":true})".into())
    }
}

/// The running camera socket server.
#[derive(Debug)]
pub struct CameraServer {
    server: LineServer,
}

impl CameraServer {
    /// Binds `path` (a stale socket there is replaced, any other file is an
    /// error) and serves `camera`.
    pub fn start(path: &Path, camera: Arc<SimCamera>) -> Result<CameraServer, SimError> {
        let server = LineServer::start(path, "camera", MAX_REQUEST, Arc::new(Grabs(camera)))?;
        Ok(CameraServer { server })
    }

    /// The socket path.
    pub fn path(&self) -> &Path {
        self.server.path()
    }

    /// Stops serving and removes the socket.
    pub fn stop(self) {
        self.server.stop();
    }
}

/// The camera's answer to a request line: a frame, an error line, or
/// nothing while the camera is stalled.
struct Grabs(Arc<SimCamera>);

impl LineHandler for Grabs {
    fn reply(&self, line: &str) -> Option<Vec<u8>> {
        if let Err(e) = is_grab(line) {
            return Some(error_line(&e).into_bytes());
        }
        match self.0.grab() {
            Ok(g) => {
                let f = &g.frame;
                let payload = encode_payload(f);
                let h = FrameHeader {
                    width: f.width(),
                    height: f.height(),
                    bit_depth: f.bit_depth(),
                    t_s: f.timestamp_s,
                    sequence: f.sequence,
                    bytes: payload.len(),
                };
                let mut out = h.to_line().into_bytes();
                out.extend_from_slice(&payload);
                Some(out)
            }
            Err(GrabError::Stalled) => None,
            Err(e) => Some(error_line(&e.to_string()).into_bytes()),
        }
    }

    fn too_long(&self, _limit: usize) -> Vec<u8> {
        error_line("request line too long").into_bytes()
    }
}
