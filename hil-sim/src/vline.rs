//! In-process serial lines: the simulated controllers served over in-memory
//! byte streams on the caller's tokio runtime.
//!
//! Why next to the pty lines: a pty is served by its own thread and its
//! bytes cross the kernel's line discipline asynchronously, so a virtual
//! clock that advances "when every task waits" cannot know a reply is on
//! its way and jumps past it. Here the host's end of the line
//! ([`HostEnd`]) hands what the host writes to the controllers at once, at
//! the current rig time, and queues their replies for the host to read, so
//! no byte is ever in flight while the runtime is idle and the paused clock
//! stands still until the exchange is over (`hil-sim run`, the in-process
//! rig).
//!
//! Why inside the write rather than in tasks of their own: the controllers
//! answer at the instant the request arrives either way (the clock cannot
//! move while a task is runnable), and a reply then waits in the host's
//! queue before the host looks for it, so an exchange costs no task hop
//! and no answer timer. Replies the reply faults delay (rig time) go
//! through one task per connection, in order, and every later reply
//! queues behind them, as on a wire.
//!
//! The controllers, the bus and the reply faults are the same as on a pty
//! ([`crate::fault::ReplyFaults`]); a dropped line refuses to open until it
//! is restored, as an unplugged cable.

use crate::bus::Bus;
use crate::clock::Clock;
use crate::fault::{AxisName, LineCmd, ReplyFaults, SimError};
use micropos::driver::{DriverError, LinkIo, LinkOpener, OpenFuture};
use std::path::{Path, PathBuf};
use std::pin::Pin;
use std::sync::{Arc, Mutex, MutexGuard};
use std::task::{Context, Poll, Waker};
use std::time::Duration;
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::sync::mpsc;
use tokio::task::JoinHandle;

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

/// The current host connection: the bytes on their way to the host and
/// the task that delivers delayed replies.
struct Conn {
    wire: Arc<Mutex<Wire>>,
    delayed: mpsc::UnboundedSender<(Duration, Vec<u8>)>,
    task: JoinHandle<()>,
}

impl Conn {
    /// Cuts the connection: the host reads what was delivered, then the end
    /// of the stream; its writes fail.
    fn close(self) {
        self.task.abort();
        let mut w = lock(&self.wire);
        w.closed = true;
        w.wake();
    }

    /// Queues `bytes` for the host after `delay` (rig time), behind every
    /// reply queued before them.
    fn deliver(&self, delay: Duration, bytes: Vec<u8>) {
        deliver(&self.wire, &self.delayed, delay, bytes);
    }
}

/// The simulator-to-host direction of one connection.
#[derive(Default)]
struct Wire {
    /// Delivered bytes the host has not read yet, from `start`.
    bytes: Vec<u8>,
    start: usize,
    /// Replies handed to the delay task and not delivered yet.
    queued: usize,
    /// The host waiting for bytes.
    reader: Option<Waker>,
    /// The connection was cut (line dropped, reopened, closed) or the host
    /// shut its side down.
    closed: bool,
}

impl Wire {
    fn push(&mut self, bytes: &[u8]) {
        self.bytes.extend_from_slice(bytes);
        self.wake();
    }

    fn wake(&mut self) {
        if let Some(w) = self.reader.take() {
            w.wake();
        }
    }
}

fn deliver(
    wire: &Mutex<Wire>,
    delayed: &mpsc::UnboundedSender<(Duration, Vec<u8>)>,
    delay: Duration,
    bytes: Vec<u8>,
) {
    let mut w = lock(wire);
    if w.closed {
        return;
    }
    if delay.is_zero() && w.queued == 0 {
        w.push(&bytes);
    } else if delayed.send((delay, bytes)).is_ok() {
        w.queued += 1;
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
                    c.deliver(Duration::ZERO, bytes);
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
        let wire = Arc::new(Mutex::new(Wire::default()));
        let (tx, rx) = mpsc::unbounded_channel();
        let task = tokio::spawn(delay_loop(wire.clone(), rx));
        st.conn = Some(Conn {
            wire: wire.clone(),
            delayed: tx.clone(),
            task,
        });
        Ok(Box::new(HostEnd {
            line: self.clone(),
            wire,
            delayed: tx,
        }))
    }

    /// What the host wrote reaches the controllers at the current rig
    /// time; what reaches the host of their replies is queued for it.
    fn receive(
        &self,
        bytes: &[u8],
        wire: &Mutex<Wire>,
        delayed: &mpsc::UnboundedSender<(Duration, Vec<u8>)>,
    ) {
        let now = self.clock.now();
        let replies = lock(&self.bus).receive(now, bytes);
        if replies.is_empty() {
            return;
        }
        let out = lock(&self.state).faults.apply(replies);
        for (delay, bytes) in out {
            deliver(wire, delayed, delay, bytes);
        }
    }
}

/// Delivers delayed replies in order, each after its delay (rig time).
async fn delay_loop(wire: Arc<Mutex<Wire>>, mut rx: mpsc::UnboundedReceiver<(Duration, Vec<u8>)>) {
    while let Some((delay, bytes)) = rx.recv().await {
        if !delay.is_zero() {
            tokio::time::sleep(delay).await;
        }
        let mut w = lock(&wire);
        if w.closed {
            return;
        }
        w.queued = w.queued.saturating_sub(1);
        w.push(&bytes);
    }
}

/// The host's end of an in-process line: what the driver reads and writes.
struct HostEnd {
    line: Arc<InProcessLine>,
    wire: Arc<Mutex<Wire>>,
    delayed: mpsc::UnboundedSender<(Duration, Vec<u8>)>,
}

impl HostEnd {
    /// The host closed its side: what it sent still reached the controllers;
    /// their line state is cleared for the next client, unless the
    /// connection was cut already (a reopen cleared it then).
    fn hang_up(&self) {
        let was_open = {
            let mut w = lock(&self.wire);
            !std::mem::replace(&mut w.closed, true)
        };
        if was_open {
            lock(&self.line.bus).reset_line();
        }
    }
}

impl AsyncRead for HostEnd {
    fn poll_read(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<std::io::Result<()>> {
        let mut w = lock(&self.wire);
        let pending = &w.bytes[w.start..];
        if !pending.is_empty() {
            let n = pending.len().min(buf.remaining());
            buf.put_slice(&pending[..n]);
            w.start += n;
            if w.start == w.bytes.len() {
                w.bytes.clear();
                w.start = 0;
            }
            return Poll::Ready(Ok(()));
        }
        if w.closed {
            // End of stream.
            return Poll::Ready(Ok(()));
        }
        if !w.reader.as_ref().is_some_and(|r| r.will_wake(cx.waker())) {
            w.reader = Some(cx.waker().clone());
        }
        Poll::Pending
    }
}

impl AsyncWrite for HostEnd {
    fn poll_write(
        self: Pin<&mut Self>,
        _cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<std::io::Result<usize>> {
        if lock(&self.wire).closed {
            return Poll::Ready(Err(std::io::ErrorKind::BrokenPipe.into()));
        }
        self.line.receive(buf, &self.wire, &self.delayed);
        Poll::Ready(Ok(buf.len()))
    }

    fn poll_flush(self: Pin<&mut Self>, _cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Poll::Ready(Ok(()))
    }

    fn poll_shutdown(self: Pin<&mut Self>, _cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        self.hang_up();
        Poll::Ready(Ok(()))
    }
}

impl Drop for HostEnd {
    fn drop(&mut self) {
        self.hang_up();
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
