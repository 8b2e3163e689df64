//! The serving thread of one line: reads host bytes from its pty, passes
//! them to the controllers on the bus, writes (possibly faulted, delayed)
//! replies, and applies line faults sent over its command channel.

use crate::bus::Bus;
use crate::clock::Clock;
use crate::fault::{AxisName, SimError};
use crate::fault::{LineCmd, ReplyFaults};
use std::io::{self, Read, Write};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use super::probe::RxProbe;
use super::pty::{io_err, Pty};

/// Longest a serving thread sleeps before looking at its command channel and
/// the stop flag: bounds fault-injection and shutdown latency.
const POLL_INTERVAL: Duration = Duration::from_millis(5);
/// How long a full pty may refuse reply bytes before they are dropped: a
/// host that reads nothing for this long is not reading at all.
const OUTBOX_PATIENCE: Duration = Duration::from_secs(2);

pub(super) type Ack = mpsc::Sender<Result<(), SimError>>;

/// State owned by one line thread.
pub(super) struct Line {
    pub(super) axis: AxisName,
    pub(super) link: PathBuf,
    pub(super) pty: Option<Pty>,
    pub(super) bus: Arc<Mutex<Bus>>,
    pub(super) clock: Arc<dyn Clock>,
    pub(super) faults: ReplyFaults,
    /// Delayed replies: (due, bytes), sorted by due time.
    pub(super) pending: Vec<(Instant, Vec<u8>)>,
    /// Reply bytes the pty has not taken yet, in order. Why: the simulator
    /// writes a reply at once where a real controller's baud rate paces it,
    /// so a long one (a 1024-record `DRR?` answer, ≈ 15 KB) overfills the
    /// pty buffer of a host that reads as it parses; the rest goes out as
    /// the host reads.
    pub(super) outbox: Vec<u8>,
    /// Since when the pty has taken none of `outbox`.
    pub(super) outbox_since: Option<Instant>,
    /// Arrival times for latency measurements.
    pub(super) probe: Arc<RxProbe>,
}

pub(super) fn lock(bus: &Mutex<Bus>) -> MutexGuard<'_, Bus> {
    // A panic while holding the lock would be a simulator bug; the state is
    // still usable for serving, so do not cascade it.
    bus.lock().unwrap_or_else(|e| e.into_inner())
}

impl Line {
    fn apply(&mut self, cmd: LineCmd) -> Result<(), SimError> {
        match cmd {
            LineCmd::Drop => {
                self.pty = None;
                self.pending.clear();
                self.outbox.clear();
                lock(&self.bus).reset_line();
                match std::fs::remove_file(&self.link) {
                    Ok(()) => Ok(()),
                    Err(e) if e.kind() == io::ErrorKind::NotFound => Ok(()),
                    Err(e) => Err(io_err(format!("remove link {}", self.link.display()))(e)),
                }
            }
            LineCmd::Restore => {
                if self.pty.is_none() {
                    self.pty = Some(Pty::open(&self.link)?);
                }
                Ok(())
            }
            LineCmd::Garbage(bytes) => {
                if self.pty.is_none() {
                    return Err(SimError::LineDown(self.axis));
                }
                self.write(&bytes);
                Ok(())
            }
            other => {
                self.faults.set(&other);
                Ok(())
            }
        }
    }

    /// Writes to the host after what is still queued for it. Bytes the pty
    /// does not take wait in the outbox ([`Line::send_outbox`]).
    fn write(&mut self, bytes: &[u8]) {
        let Some(pty) = self.pty.as_mut() else {
            return;
        };
        let (_, connected) = pty.wait(Duration::ZERO);
        if !connected {
            return;
        }
        self.outbox.extend_from_slice(bytes);
        self.send_outbox();
    }

    /// Hands the pty as much of the outbox as it takes. A host that takes
    /// nothing for [`OUTBOX_PATIENCE`] loses the rest, as on a real line
    /// whose host does not read.
    fn send_outbox(&mut self) {
        let Some(pty) = self.pty.as_mut() else {
            self.outbox.clear();
            return;
        };
        let mut sent = 0;
        while sent < self.outbox.len() {
            match pty.master.write(&self.outbox[sent..]) {
                Ok(0) => break,
                Ok(n) => sent += n,
                Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => break,
                Err(e) => {
                    tracing::warn!(axis = %self.axis, "dropping {} reply bytes: {e}", self.outbox.len() - sent);
                    sent = self.outbox.len();
                }
            }
        }
        self.outbox.drain(..sent);
        let now = Instant::now();
        if self.outbox.is_empty() || sent > 0 {
            self.outbox_since = (!self.outbox.is_empty()).then_some(now);
        } else if let Some(since) = self.outbox_since {
            if now.duration_since(since) >= OUTBOX_PATIENCE {
                tracing::warn!(axis = %self.axis, "the host reads nothing: dropping {} reply bytes", self.outbox.len());
                self.outbox.clear();
                self.outbox_since = None;
            }
        } else {
            self.outbox_since = Some(now);
        }
    }

    fn flush_due(&mut self) {
        let now = Instant::now();
        while self.pending.first().is_some_and(|(due, _)| *due <= now) {
            let (_, bytes) = self.pending.remove(0);
            self.write(&bytes);
        }
    }

    fn on_bytes(&mut self, bytes: &[u8]) {
        let now = self.clock.now();
        let replies = lock(&self.bus).receive(now, bytes);
        for (delay, bytes) in self.faults.apply(replies) {
            if delay.is_zero() && self.pending.is_empty() {
                self.write(&bytes);
            } else {
                let due = Instant::now() + delay;
                let at = self.pending.partition_point(|(d, _)| *d <= due);
                self.pending.insert(at, (due, bytes));
            }
        }
    }

    /// Reads and handles everything the host has sent so far.
    fn drain_input(&mut self) {
        let mut buf = [0u8; 4096];
        loop {
            let Some(pty) = self.pty.as_mut() else {
                return;
            };
            match pty.master.read(&mut buf) {
                Ok(0) => return,
                Ok(n) => {
                    self.probe.observe(&buf[..n], Instant::now());
                    let bytes = buf[..n].to_vec();
                    self.on_bytes(&bytes);
                }
                Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                // WouldBlock: all read. EIO: no client and nothing queued.
                Err(_) => return,
            }
        }
    }

    pub(super) fn run(mut self, rx: mpsc::Receiver<(LineCmd, Ack)>, stop: Arc<AtomicBool>) {
        loop {
            loop {
                match rx.try_recv() {
                    Ok((cmd, ack)) => {
                        let r = self.apply(cmd);
                        let _ = ack.send(r);
                    }
                    Err(mpsc::TryRecvError::Empty) => break,
                    Err(mpsc::TryRecvError::Disconnected) => {
                        stop.store(true, Ordering::SeqCst);
                        break;
                    }
                }
            }
            if stop.load(Ordering::SeqCst) {
                break;
            }
            if !self.outbox.is_empty() {
                self.send_outbox();
            }
            self.flush_due();
            let mut wait = self
                .pending
                .first()
                .map(|(due, _)| due.saturating_duration_since(Instant::now()))
                .unwrap_or(POLL_INTERVAL)
                .min(POLL_INTERVAL);
            if !self.outbox.is_empty() {
                // The host is reading a long reply: offer the rest soon.
                wait = wait.min(Duration::from_millis(1));
            }
            let Some(pty) = self.pty.as_mut() else {
                std::thread::sleep(wait);
                continue;
            };
            let (readable, connected) = pty.wait(wait.max(Duration::from_millis(1)));
            if !connected {
                // What the client sent before it left still reaches the
                // controllers (they execute it; the answers are lost, see
                // `write`). Then its leftovers are cleared so the next client
                // starts clean.
                self.drain_input();
                if let Some(pty) = self.pty.as_mut() {
                    if pty.connected {
                        pty.connected = false;
                        // A client that opened the port after the hang-up
                        // was seen may have had its first request answered
                        // by the drain above: that answer is its own, and a
                        // flush now would leave it waiting for nothing.
                        let (_, reopened) = pty.wait(Duration::ZERO);
                        if !reopened {
                            pty.flush();
                            self.pending.clear();
                            self.outbox.clear();
                            lock(&self.bus).reset_line();
                        }
                    }
                }
                // Hang-up is reported at once; do not spin on it.
                std::thread::sleep(wait);
                continue;
            }
            pty.connected = true;
            if readable {
                self.drain_input();
            }
        }
        self.pty = None;
        let _ = std::fs::remove_file(&self.link);
    }
}
