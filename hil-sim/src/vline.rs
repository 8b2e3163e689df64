//! In-process serial lines: the simulated controllers served over in-memory
//! byte streams, as tasks on the caller's tokio runtime.
//!
//! Why next to the pty lines: a pty is served by its own thread and its
//! bytes cross the kernel's line discipline asynchronously, so a virtual
//! clock that advances "when every task waits" cannot know a reply is on
//! its way and jumps past it. Here a request is read, answered and written
//! by tasks of the same runtime as the driver that sent it, so the runtime
//! is never idle while bytes are in flight and the paused clock stands
//! still until the exchange is over (`hil-sim run`, the in-process rig).
//!
//! The controllers, the bus and the reply faults are the same as on a pty
//! ([`crate::fault::ReplyFaults`]); a dropped line refuses to open until it
//! is restored, as an unplugged cable; reply delays are rig time.

use crate::bus::Bus;
use crate::clock::Clock;
use crate::fault::{AxisName, LineCmd, ReplyFaults, SimError};
use micropos::driver::{DriverError, LinkIo, LinkOpener, OpenFuture};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::sync::mpsc;
use tokio::task::JoinHandle;

/// Bytes buffered in each direction of an in-process line.
const LINE_BUFFER: usize = 64 * 1024;

/// One in-process line (one bus: one controller, or two on a daisy chain).
pub(crate) struct InProcessLine {
    axis: AxisName,
    link: PathBuf,
    bus: Arc<Mutex<Bus>>,
    clock: Arc<dyn Clock>,
    state: Mutex<LineState>,
}

impl std::fmt::Debug for InProcessLine {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("InProcessLine")
            .field("axis", &self.axis)
            .field("link", &self.link)
            .finish()
    }
}

struct LineState {
    faults: ReplyFaults,
    down: bool,
    conn: Option<Conn>,
}

/// The current host connection: the queue of replies to write and the two
/// tasks serving it.
struct Conn {
    replies: mpsc::UnboundedSender<(Duration, Vec<u8>)>,
    tasks: [JoinHandle<()>; 2],
}

impl Conn {
    fn close(self) {
        for t in self.tasks {
            t.abort();
        }
    }
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

impl InProcessLine {
    pub(crate) fn new(
        axis: AxisName,
        link: PathBuf,
        bus: Arc<Mutex<Bus>>,
        clock: Arc<dyn Clock>,
        controllers: usize,
    ) -> Self {
        InProcessLine {
            axis,
            link,
            bus,
            clock,
            state: Mutex::new(LineState {
                faults: ReplyFaults::new(controllers),
                down: false,
                conn: None,
            }),
        }
    }

    /// The name the host opens it by (`DIR/x`, `DIR/y` or `DIR/bus`).
    pub(crate) fn link(&self) -> &Path {
        &self.link
    }

    /// Applies a line fault; in effect when this returns.
    pub(crate) fn apply(&self, cmd: LineCmd) -> Result<(), SimError> {
        let mut st = lock(&self.state);
        match cmd {
            LineCmd::Drop => {
                st.down = true;
                if let Some(c) = st.conn.take() {
                    c.close();
                }
                lock(&self.bus).reset_line();
                Ok(())
            }
            LineCmd::Restore => {
                st.down = false;
                Ok(())
            }
            LineCmd::Garbage(bytes) => match &st.conn {
                _ if st.down => Err(SimError::LineDown(self.axis)),
                Some(c) => {
                    let _ = c.replies.send((Duration::ZERO, bytes));
                    Ok(())
                }
                // Nobody listens: the bytes are lost, as on a real line.
                None => Ok(()),
            },
            other => {
                st.faults.set(&other);
                Ok(())
            }
        }
    }

    /// Closes the host connection (shutdown).
    pub(crate) fn close(&self) {
        if let Some(c) = lock(&self.state).conn.take() {
            c.close();
        }
    }

    /// A new host connection; the previous one, if any, is cut and the
    /// controllers' line state cleared (a client opening the port never
    /// reads stale answers). Must run inside a tokio runtime.
    fn open(self: &Arc<Self>) -> Result<Box<dyn LinkIo>, DriverError> {
        let mut st = lock(&self.state);
        if st.down {
            return Err(DriverError::NoDevice {
                path: self.link.clone(),
                reason: "the simulated line is unplugged (fault injected)".into(),
            });
        }
        if let Some(c) = st.conn.take() {
            c.close();
        }
        lock(&self.bus).reset_line();
        let (host, sim) = tokio::io::duplex(LINE_BUFFER);
        let (rd, wr) = tokio::io::split(sim);
        let (tx, rx) = mpsc::unbounded_channel();
        let reader = tokio::spawn(read_loop(self.clone(), rd, tx.clone()));
        let writer = tokio::spawn(write_loop(wr, rx));
        st.conn = Some(Conn {
            replies: tx,
            tasks: [reader, writer],
        });
        Ok(Box::new(host))
    }
}

/// Feeds what the host sends to the controllers at the current rig time and
/// queues what reaches the host of their replies.
async fn read_loop(
    line: Arc<InProcessLine>,
    mut rd: tokio::io::ReadHalf<tokio::io::DuplexStream>,
    tx: mpsc::UnboundedSender<(Duration, Vec<u8>)>,
) {
    let mut buf = vec![0u8; 4096];
    loop {
        let n = match rd.read(&mut buf).await {
            Ok(0) | Err(_) => break,
            Ok(n) => n,
        };
        let now = line.clock.now();
        let replies = lock(&line.bus).receive(now, &buf[..n]);
        let out = lock(&line.state).faults.apply(replies);
        for o in out {
            if tx.send(o).is_err() {
                return;
            }
        }
    }
    // The host closed the port: what it sent still reached the controllers;
    // their line state is cleared for the next client.
    lock(&line.bus).reset_line();
}

/// Writes replies in order, each after its delay (rig time).
async fn write_loop(
    mut wr: tokio::io::WriteHalf<tokio::io::DuplexStream>,
    mut rx: mpsc::UnboundedReceiver<(Duration, Vec<u8>)>,
) {
    while let Some((delay, bytes)) = rx.recv().await {
        if !delay.is_zero() {
            tokio::time::sleep(delay).await;
        }
        if wr.write_all(&bytes).await.is_err() {
            return;
        }
    }
}

/// Opens the in-process lines by name for the micropos driver (the daemon's
/// `links`, `Stage::connect_via`).
#[derive(Debug, Clone)]
pub struct InProcessLinks {
    lines: Vec<Arc<InProcessLine>>,
}

impl InProcessLinks {
    pub(crate) fn new(lines: Vec<Arc<InProcessLine>>) -> Self {
        InProcessLinks { lines }
    }
}

impl LinkOpener for InProcessLinks {
    fn open(&self, port: &Path) -> OpenFuture {
        let line = self.lines.iter().find(|l| l.link() == port).cloned();
        let port = port.to_owned();
        Box::pin(async move {
            match line {
                Some(l) => l.open(),
                None => Err(DriverError::NoDevice {
                    path: port,
                    reason: "no simulated line has this name".into(),
                }),
            }
        })
    }
}
