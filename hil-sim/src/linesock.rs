//! A Unix-socket server of request lines: the one job of this file. It binds
//! (replacing a stale socket, refusing any other file), accepts on one
//! thread, serves each client on its own thread with short read timeouts so
//! that every thread notices a stop, bounds a request line's length, and
//! removes the socket when stopped or dropped.
//!
//! Why shared: the camera socket and the control socket differ only in what
//! they answer to a line ([`LineHandler`]); the socket handling, which must
//! never let a client hold a thread past a stop or grow a buffer without
//! bound, is written once.

use crate::fault::SimError;
use std::io::{BufRead, BufReader, Read, Write};
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Duration;

/// How a client's read waits before it checks the stop flag again.
const READ_POLL: Duration = Duration::from_millis(50);
/// How long the accepting thread sleeps when no client is waiting.
const ACCEPT_POLL: Duration = Duration::from_millis(5);

/// What a line server answers.
pub trait LineHandler: Send + Sync + 'static {
    /// The reply to one request line (its bytes up to and without the
    /// newline, decoded lossily); `None` sends nothing (a stalled device).
    fn reply(&self, line: &str) -> Option<Vec<u8>>;
    /// The reply to a line longer than the server's limit (the line is
    /// dropped and the connection stays open).
    fn too_long(&self, limit: usize) -> Vec<u8>;
}

/// A running line server.
#[derive(Debug)]
pub struct LineServer {
    path: PathBuf,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl LineServer {
    /// Binds `path` and serves `handler` there; `what` names the socket in
    /// errors and thread names (`"camera"`, `"control"`), `max_line` bounds
    /// a request line in bytes.
    pub fn start(
        path: &Path,
        what: &'static str,
        max_line: usize,
        handler: Arc<dyn LineHandler>,
    ) -> Result<LineServer, SimError> {
        use std::os::unix::fs::FileTypeExt;
        if let Ok(meta) = std::fs::symlink_metadata(path) {
            if meta.file_type().is_socket() {
                let _ = std::fs::remove_file(path);
            } else {
                return Err(SimError::Config(format!(
                    "{what} socket path {} exists and is not a socket",
                    path.display()
                )));
            }
        }
        let io = |context: String| move |source| SimError::Io { context, source };
        let listener = UnixListener::bind(path)
            .map_err(io(format!("bind {what} socket {}", path.display())))?;
        listener
            .set_nonblocking(true)
            .map_err(io(format!("{what} socket non-blocking")))?;
        let stop = Arc::new(AtomicBool::new(false));
        let stop2 = stop.clone();
        let thread = std::thread::Builder::new()
            .name(format!("hil-sim-{what}"))
            .spawn(move || accept_loop(listener, what, max_line, handler, stop2))
            .map_err(io(format!("spawn {what} thread")))?;
        Ok(LineServer {
            path: path.to_owned(),
            stop,
            thread: Some(thread),
        })
    }

    /// The socket path.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Stops serving, joins the threads and removes the socket.
    pub fn stop(mut self) {
        self.shutdown();
    }

    fn shutdown(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
            let _ = std::fs::remove_file(&self.path);
        }
    }
}

impl Drop for LineServer {
    fn drop(&mut self) {
        self.shutdown();
    }
}

fn accept_loop(
    listener: UnixListener,
    what: &'static str,
    max_line: usize,
    handler: Arc<dyn LineHandler>,
    stop: Arc<AtomicBool>,
) {
    let mut clients: Vec<JoinHandle<()>> = Vec::new();
    while !stop.load(Ordering::SeqCst) {
        match listener.accept() {
            Ok((stream, _)) => {
                let handler = handler.clone();
                let stop = stop.clone();
                match std::thread::Builder::new()
                    .name(format!("hil-sim-{what}-conn"))
                    .spawn(move || serve_client(stream, max_line, handler.as_ref(), &stop))
                {
                    Ok(t) => clients.push(t),
                    Err(e) => tracing::warn!("{what} connection thread: {e}"),
                }
                clients.retain(|t| !t.is_finished());
            }
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {
                std::thread::sleep(ACCEPT_POLL);
            }
            Err(e) => {
                tracing::warn!("{what} socket accept: {e}");
                std::thread::sleep(4 * ACCEPT_POLL);
            }
        }
    }
    for t in clients {
        let _ = t.join();
    }
}

fn serve_client(stream: UnixStream, max_line: usize, handler: &dyn LineHandler, stop: &AtomicBool) {
    if stream.set_nonblocking(false).is_err() || stream.set_read_timeout(Some(READ_POLL)).is_err() {
        return;
    }
    let Ok(mut writer) = stream.try_clone() else {
        return;
    };
    let mut reader = BufReader::new(stream);
    let mut line = Vec::new();
    // Whether the bytes being read belong to a line already refused as too
    // long (they are dropped up to its newline).
    let mut discarding = false;
    while !stop.load(Ordering::SeqCst) {
        // At most one byte past the limit: enough to tell a line of exactly
        // `max_line` bytes and its newline from a longer one.
        let room = (max_line + 1).saturating_sub(line.len()) as u64;
        match reader.by_ref().take(room).read_until(b'\n', &mut line) {
            Ok(0) => return,
            Ok(_) => {}
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock
                        | std::io::ErrorKind::TimedOut
                        | std::io::ErrorKind::Interrupted
                ) =>
            {
                // Partial data stays in `line`; keep reading.
                continue;
            }
            Err(_) => return,
        }
        let complete = line.ends_with(b"\n");
        let reply = if discarding {
            discarding = !complete;
            None
        } else if complete {
            Some(handler.reply(&String::from_utf8_lossy(&line[..line.len() - 1])))
        } else if line.len() > max_line {
            discarding = true;
            Some(Some(handler.too_long(max_line)))
        } else {
            continue;
        };
        line.clear();
        if let Some(Some(bytes)) = reply {
            if writer.write_all(&bytes).is_err() {
                return;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::{BufRead, BufReader, Write};

    struct Echo;
    impl LineHandler for Echo {
        fn reply(&self, line: &str) -> Option<Vec<u8>> {
            (line != "quiet").then(|| format!("got {line}\n").into_bytes())
        }
        fn too_long(&self, limit: usize) -> Vec<u8> {
            format!("longer than {limit}\n").into_bytes()
        }
    }

    #[test]
    fn lines_are_answered_bounded_and_the_socket_goes_with_the_server() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("s.sock");
        let server = LineServer::start(&path, "test", 16, Arc::new(Echo)).unwrap();
        let mut c = UnixStream::connect(&path).unwrap();
        c.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
        let mut r = BufReader::new(c.try_clone().unwrap());
        let mut read = || {
            let mut s = String::new();
            r.read_line(&mut s).unwrap();
            s
        };
        c.write_all(b"hello\n").unwrap();
        assert_eq!(read(), "got hello\n");
        // Nothing for a quiet line; the next line is answered.
        c.write_all(b"quiet\nabc").unwrap();
        c.write_all(b"def\n").unwrap();
        assert_eq!(read(), "got abcdef\n");
        // A line of exactly the limit is served; a longer one gets one
        // refusal, however long, and the connection stays open.
        c.write_all(b"0123456789abcdef\n").unwrap();
        assert_eq!(read(), "got 0123456789abcdef\n");
        c.write_all(&[b'x'; 100]).unwrap();
        c.write_all(b"\nafter\n").unwrap();
        assert_eq!(read(), "longer than 16\n");
        assert_eq!(read(), "got after\n");
        server.stop();
        assert!(!path.exists());
    }

    #[test]
    fn another_file_at_the_path_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("f");
        std::fs::write(&path, b"data").unwrap();
        let err = LineServer::start(&path, "test", 16, Arc::new(Echo)).unwrap_err();
        assert!(err.to_string().contains("not a socket"), "{err}");
        assert_eq!(std::fs::read(&path).unwrap(), b"data");
    }
}
