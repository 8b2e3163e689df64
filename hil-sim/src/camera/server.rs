//! Serves the simulated camera on a Unix socket (`DIR/camera.sock`), with
//! the protocol of `micropos::camera::simsocket` (shared definition).
//!
//! One thread accepts; each client gets its own thread. A request line that
//! is not `{"grab":true}` gets an error reply; a stalled camera never
//! answers (the client times out, as with a hung camera).

use super::{GrabError, SimCamera};
use crate::fault::SimError;
use micropos::camera::simsocket::{encode_payload, error_line, FrameHeader};
use std::io::{BufRead, BufReader, Read, Write};
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Duration;

/// Longest request line accepted.
const MAX_REQUEST: u64 = 4096;

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
    path: PathBuf,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl CameraServer {
    /// Binds `path` (a stale socket there is replaced, any other file is an
    /// error) and serves `camera`.
    pub fn start(path: &Path, camera: Arc<SimCamera>) -> Result<CameraServer, SimError> {
        use std::os::unix::fs::FileTypeExt;
        if let Ok(meta) = std::fs::symlink_metadata(path) {
            if meta.file_type().is_socket() {
                let _ = std::fs::remove_file(path);
            } else {
                return Err(SimError::Config(format!(
                    "camera socket path {} exists and is not a socket",
                    path.display()
                )));
            }
        }
        let io = |context: String| move |source| SimError::Io { context, source };
        let listener = UnixListener::bind(path)
            .map_err(io(format!("bind camera socket {}", path.display())))?;
        listener
            .set_nonblocking(true)
            .map_err(io("camera socket non-blocking".into()))?;
        let stop = Arc::new(AtomicBool::new(false));
        let stop2 = stop.clone();
        let thread = std::thread::Builder::new()
            .name("hil-sim-camera".into())
            .spawn(move || accept_loop(listener, camera, stop2))
            .map_err(io("spawn camera thread".into()))?;
        Ok(CameraServer {
            path: path.to_owned(),
            stop,
            thread: Some(thread),
        })
    }

    /// The socket path.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Stops serving and removes the socket.
    pub fn stop(mut self) {
        self.shutdown();
    }

    fn shutdown(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
        let _ = std::fs::remove_file(&self.path);
    }
}

impl Drop for CameraServer {
    fn drop(&mut self) {
        self.shutdown();
    }
}

fn accept_loop(listener: UnixListener, camera: Arc<SimCamera>, stop: Arc<AtomicBool>) {
    let mut clients: Vec<JoinHandle<()>> = Vec::new();
    while !stop.load(Ordering::SeqCst) {
        match listener.accept() {
            Ok((stream, _)) => {
                let cam = camera.clone();
                let stop2 = stop.clone();
                if let Ok(t) = std::thread::Builder::new()
                    .name("hil-sim-camera-client".into())
                    .spawn(move || serve_client(stream, cam, stop2))
                {
                    clients.push(t);
                }
                clients.retain(|t| !t.is_finished());
            }
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {
                std::thread::sleep(Duration::from_millis(5));
            }
            Err(e) => {
                tracing::warn!("camera socket accept: {e}");
                std::thread::sleep(Duration::from_millis(20));
            }
        }
    }
    for t in clients {
        let _ = t.join();
    }
}

fn serve_client(stream: UnixStream, camera: Arc<SimCamera>, stop: Arc<AtomicBool>) {
    // Short read timeouts so the thread notices shutdown.
    if stream.set_nonblocking(false).is_err()
        || stream
            .set_read_timeout(Some(Duration::from_millis(50)))
            .is_err()
    {
        return;
    }
    let Ok(mut writer) = stream.try_clone() else {
        return;
    };
    let mut reader = BufReader::new(stream);
    let mut line = Vec::new();
    while !stop.load(Ordering::SeqCst) {
        let r = reader
            .by_ref()
            .take(MAX_REQUEST + 1 - line.len() as u64)
            .read_until(b'\n', &mut line);
        match r {
            Ok(0) => return,
            Ok(_) if !line.ends_with(b"\n") && line.len() as u64 <= MAX_REQUEST => continue,
            Ok(_) => {}
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) =>
            {
                continue
            }
            Err(_) => return,
        }
        let text = String::from_utf8_lossy(&line).into_owned();
        line.clear();
        if text.len() as u64 > MAX_REQUEST {
            if writer
                .write_all(error_line("request line too long").as_bytes())
                .is_err()
            {
                return;
            }
            continue;
        }
        let reply: Option<Vec<u8>> = match is_grab(&text) {
            Err(e) => Some(error_line(&e).into_bytes()),
            Ok(()) => match camera.grab() {
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
            },
        };
        if let Some(bytes) = reply {
            if writer.write_all(&bytes).is_err() {
                return;
            }
        }
    }
}
