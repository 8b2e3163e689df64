//! One task per serial line: it owns the byte stream and a
//! [`Session`](crate::gcs::Session), runs one exchange at a time, watches the
//! line while idle, and reopens the device after a fault.
//!
//! Invariants:
//! - Exactly one exchange is in flight on a line; answers are matched to
//!   requests only by order (GCS has no request ids).
//! - Bytes received while no exchange runs are never part of an answer: the
//!   session's decoder is cleared before each request is written.
//! - After a silence the line waits until it has been quiet for one full
//!   answer timeout before writing again, so a late answer is dropped instead
//!   of being taken for the answer to the next request.
//! - Every reply carries the connection epoch (incremented on each reopen), so
//!   callers can tell that the device may have changed under them.
//! - An exchange, once started, is completed even if its caller went away
//!   (cancellation-safe: the line never loses track of what is in flight).
//! - An urgent command ([`Line::urgent`]: `#24` stop all;
//!   [`Line::urgent_command`]: `HLT`) does not queue: the task writes it
//!   before any queued exchange, and also while an exchange waits for its
//!   answer or for the line to fall quiet (its request is on the wire by
//!   then, so the urgent bytes cannot split it). It expects no answer.
//! - The task keeps a ledger per controller address of the writes that may
//!   have set its error register (commands without an answer, queries that
//!   stayed silent, urgent stops) and of the answered `ERR?` that read them
//!   ([`Line::error_unread`]). Why: a transaction's `ERR?` is sent by its
//!   caller, and a caller that goes away between its command and its
//!   `ERR?` (a job cancelled mid-move; a halt's confirmation dropped with
//!   its future) leaves the code in the register, where the next command's
//!   own `ERR?` would read it as that command's refusal (seen: a cancelled
//!   job's halt left error 10, and the resumed job's first `MOV` was
//!   reported refused although it ran).

use super::error::DriverError;
use super::transport::Connector;
use super::AxisEvent;
use crate::gcs::frame::Address;
use crate::gcs::{Answer, ControlChar, Outgoing, Session, SessionEvent};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::sync::{broadcast, mpsc, oneshot};
use tokio::time::Instant;

/// Reconnect behaviour of a line.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LineOptions {
    /// First delay between reopen attempts.
    pub reconnect_min: Duration,
    /// Largest delay between reopen attempts (the delay doubles up to it).
    /// It bounds how long a controller that came back runs on unwatched
    /// before [`LineOptions::stop_on_reopen`] stops it.
    pub reconnect_max: Duration,
    /// Write `#24` (stop all) to every controller the line has spoken to,
    /// as the first bytes on each re-opened connection. Why: a controller
    /// keeps running the move it had when its line dropped, and nobody
    /// watched it while the line was down; whatever the caller does next
    /// (a halt, a fault latch, a reconnect check) comes after at least one
    /// exchange, while the carriage runs on. Its error register then reads
    /// 10 (stopped by the command), which the ledger accounts for.
    pub stop_on_reopen: bool,
}

impl Default for LineOptions {
    fn default() -> Self {
        Self {
            reconnect_min: Duration::from_millis(50),
            reconnect_max: Duration::from_millis(100),
            stop_on_reopen: true,
        }
    }
}

/// How an exchange ended.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Outcome {
    /// The answer (daisy-chain header removed).
    Answer(Answer),
    /// The request expects no answer and was written.
    Sent,
    /// No complete answer before the timeout.
    Silence {
        /// Whether part of an answer had arrived.
        partial: bool,
    },
}

/// The result of one exchange with the connection epoch it ran on.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Reply {
    /// What happened.
    pub outcome: Outcome,
    /// Connection epoch: 1 for the first connection, +1 per reopen.
    pub epoch: u64,
}

/// An urgent control byte to write at once.
struct Urgent {
    addr: Option<Address>,
    bytes: Vec<u8>,
    done: oneshot::Sender<Result<(), DriverError>>,
}

/// Per controller address (none: slot 0): writes that may have set the
/// error register, and how many of them an answered `ERR?` has read.
#[derive(Debug, Default)]
struct Ledger {
    slots: [(u64, u64); 17],
}

impl Ledger {
    fn slot(addr: Option<Address>) -> usize {
        addr.map_or(0, |a| usize::from(a.get()).min(16))
    }

    /// A write that may have set the register.
    fn wrote(&mut self, addr: Option<Address>) {
        self.slots[Self::slot(addr)].0 += 1;
    }

    /// The writes so far (what an `ERR?` written now will read).
    fn written(&self, addr: Option<Address>) -> u64 {
        self.slots[Self::slot(addr)].0
    }

    /// An `ERR?` written after `n` writes was answered.
    fn read(&mut self, addr: Option<Address>, n: u64) {
        let s = &mut self.slots[Self::slot(addr)];
        s.1 = s.1.max(n);
    }

    fn unread(&self, addr: Option<Address>) -> bool {
        let s = self.slots[Self::slot(addr)];
        s.0 > s.1
    }
}

fn lock_ledger(l: &std::sync::Mutex<Ledger>) -> std::sync::MutexGuard<'_, Ledger> {
    l.lock().unwrap_or_else(|p| p.into_inner())
}

enum Request {
    Exchange {
        addr: Option<Address>,
        out: Outgoing,
        timeout: Duration,
        reply: oneshot::Sender<Result<Reply, DriverError>>,
    },
    Resync {
        quiet: Duration,
    },
}

/// Handle to a line task. Cheap to clone; the task ends (closing the device)
/// when the last handle is dropped, after finishing the exchange in flight.
/// Closing sends nothing to the controller: motion in progress continues.
#[derive(Debug, Clone)]
pub struct Line {
    tx: mpsc::Sender<Request>,
    urgent: mpsc::Sender<Urgent>,
    name: Arc<str>,
    epoch: Arc<AtomicU64>,
    noise: Arc<AtomicU64>,
    ledger: Arc<std::sync::Mutex<Ledger>>,
}

impl Line {
    /// Opens the line once (an error here is returned as is: a missing device
    /// at start-up is a configuration problem, not a fault to ride out), then
    /// spawns its task, which reopens it after faults.
    pub async fn open<C: Connector>(
        mut connector: C,
        options: LineOptions,
        events: broadcast::Sender<AxisEvent>,
    ) -> Result<Line, DriverError> {
        let io = connector.connect().await?;
        let name: Arc<str> = connector.name().into();
        let epoch = Arc::new(AtomicU64::new(1));
        let noise = Arc::new(AtomicU64::new(0));
        let (tx, rx) = mpsc::channel(32);
        let (urgent, urgent_rx) = mpsc::channel(8);
        let ledger = Arc::new(std::sync::Mutex::new(Ledger::default()));
        let task = Task {
            ledger: ledger.clone(),
            urgent: urgent_rx,
            connector,
            options,
            events,
            name: name.clone(),
            session: Session::new(),
            t0: Instant::now(),
            epoch: epoch.clone(),
            noise: noise.clone(),
            quiet_needed: None,
            down_reason: String::new(),
            known: Vec::new(),
        };
        let _ = task.events.send(AxisEvent::Connected {
            line: name.to_string(),
        });
        tokio::spawn(task.run(io, rx));
        Ok(Line {
            tx,
            urgent,
            name,
            epoch,
            noise,
            ledger,
        })
    }

    /// The device path.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// The current connection epoch (see [`Reply::epoch`]).
    pub fn epoch(&self) -> u64 {
        self.epoch.load(Ordering::SeqCst)
    }

    /// How many times bytes that belong to no request have arrived. A
    /// reading is trusted only if this did not change while it was taken
    /// and confirmed (see `Axis::position_um`): garbage shaped like an answer
    /// can be taken for one, but then the real answer arrives out of turn and
    /// moves this counter.
    pub fn noise_count(&self) -> u64 {
        self.noise.load(Ordering::SeqCst)
    }

    /// Whether the controller at `addr` may hold an error code that no
    /// answered `ERR?` has read since it was written (see the module docs):
    /// a transaction reads it first, so that its own `ERR?` is its own.
    pub fn error_unread(&self, addr: Option<Address>) -> bool {
        lock_ledger(&self.ledger).unread(addr)
    }

    /// Runs one exchange: writes the request and, if it expects an answer,
    /// waits for it at most `timeout` after the last byte received.
    pub async fn exchange(
        &self,
        addr: Option<Address>,
        out: Outgoing,
        timeout: Duration,
    ) -> Result<Reply, DriverError> {
        let (reply, rx) = oneshot::channel();
        self.tx
            .send(Request::Exchange {
                addr,
                out,
                timeout,
                reply,
            })
            .await
            .map_err(|_| self.closed())?;
        rx.await.map_err(|_| self.closed())?
    }

    /// Writes a single-character command that expects no answer (`#24`)
    /// ahead of every queued exchange, even while one waits for its answer;
    /// returns once it is written. Why: a stop must not wait behind the
    /// line's queue (up to 32 exchanges, each up to an answer timeout).
    pub async fn urgent(&self, addr: Option<Address>, c: ControlChar) -> Result<(), DriverError> {
        if c.has_answer() {
            return Err(DriverError::Invalid(format!(
                "#{} has an answer: not an urgent command",
                c.byte()
            )));
        }
        self.write_urgent(addr, crate::gcs::frame::encode_control(addr, c))
            .await
    }

    /// Writes a whole command line that expects no answer (`HLT`) the way
    /// [`Line::urgent`] writes `#24`: ahead of every queued exchange, also
    /// while one waits for its answer or for the line to fall quiet. Why: a
    /// halt after a fault must not wait behind reads that are timing out
    /// (each an answer timeout plus a resynchronisation) on the very line
    /// that failed. The controller runs it after the line in flight (whose
    /// answer, if any, still comes); its error register (10 after `HLT`) is
    /// for the caller to read in turn.
    pub async fn urgent_command(
        &self,
        addr: Option<Address>,
        cmd: &crate::gcs::Command,
    ) -> Result<(), DriverError> {
        if cmd.is_query() {
            return Err(DriverError::Invalid(format!(
                "`{}` has an answer: not an urgent command",
                cmd.to_text()
            )));
        }
        let bytes = crate::gcs::frame::encode_line(addr, &cmd.to_text())
            .map_err(|e| DriverError::Invalid(e.to_string()))?;
        self.write_urgent(addr, bytes).await
    }

    async fn write_urgent(&self, addr: Option<Address>, bytes: Vec<u8>) -> Result<(), DriverError> {
        let (done, rx) = oneshot::channel();
        self.urgent
            .send(Urgent { addr, bytes, done })
            .await
            .map_err(|_| self.closed())?;
        rx.await.map_err(|_| self.closed())?
    }

    /// Asks the line to wait for `quiet` without traffic before its next
    /// write: used when an answer turned out to be unusable, so that whatever
    /// caused it (garbage, a late answer) is drained.
    pub async fn resync(&self, quiet: Duration) {
        let _ = self.tx.send(Request::Resync { quiet }).await;
    }

    fn closed(&self) -> DriverError {
        DriverError::Closed {
            line: self.name.to_string(),
        }
    }
}

struct Task<C: Connector> {
    ledger: Arc<std::sync::Mutex<Ledger>>,
    urgent: mpsc::Receiver<Urgent>,
    connector: C,
    options: LineOptions,
    events: broadcast::Sender<AxisEvent>,
    name: Arc<str>,
    session: Session,
    t0: Instant,
    epoch: Arc<AtomicU64>,
    noise: Arc<AtomicU64>,
    /// Set after a silence: how long the line must be quiet before the next write.
    quiet_needed: Option<Duration>,
    down_reason: String,
    /// The controller addresses written to on this line, in first-use
    /// order (what [`LineOptions::stop_on_reopen`] stops).
    known: Vec<Option<Address>>,
}

enum Step {
    Continue,
    Down(String),
    Exit,
}

impl<C: Connector> Task<C> {
    fn now(&self) -> Duration {
        self.t0.elapsed()
    }

    fn noise(&self, text: String) {
        self.noise.fetch_add(1, Ordering::SeqCst);
        tracing::warn!(line = %self.name, "unexpected bytes: {text}");
        let _ = self.events.send(AxisEvent::Noise {
            line: self.name.to_string(),
            text,
        });
    }

    fn disconnected(&self) -> DriverError {
        DriverError::Disconnected {
            line: self.name.to_string(),
            reason: self.down_reason.clone(),
        }
    }

    async fn run(mut self, io: C::Io, mut rx: mpsc::Receiver<Request>) {
        let mut conn = Some(io);
        let mut buf = [0u8; 1024];
        let mut backoff = self.options.reconnect_min;
        let mut next_try = Instant::now();
        loop {
            let step = match conn.as_mut() {
                Some(io) => {
                    tokio::select! {
                        biased;
                        Some(u) = self.urgent.recv() => self.write_urgent(io, u).await,
                        req = rx.recv() => match req {
                            None => Step::Exit,
                            Some(req) => self.handle(io, req).await,
                        },
                        r = io.read(&mut buf) => match r {
                            Ok(0) => Step::Down("end of file (device closed)".to_owned()),
                            Ok(n) => {
                                // No request is in flight: whatever this is, it is not an answer.
                                self.noise.fetch_add(1, Ordering::SeqCst);
                                let now = self.now();
                                for ev in self.session.on_bytes(now, &buf[..n]) {
                                    if let SessionEvent::Unexpected(t) = ev {
                                        self.noise(t);
                                    }
                                }
                                Step::Continue
                            }
                            Err(e) => Step::Down(format!("read error: {e}")),
                        },
                    }
                }
                None => {
                    tokio::select! {
                        Some(u) = self.urgent.recv() => {
                            let _ = u.done.send(Err(self.disconnected()));
                            Step::Continue
                        }
                        req = rx.recv() => match req {
                            None => Step::Exit,
                            Some(Request::Exchange { reply, .. }) => {
                                let _ = reply.send(Err(self.disconnected()));
                                Step::Continue
                            }
                            Some(Request::Resync { .. }) => Step::Continue,
                        },
                        () = tokio::time::sleep_until(next_try) => {
                            match self.connector.connect().await {
                                Ok(mut io) => {
                                    self.session.reset();
                                    self.quiet_needed = None;
                                    backoff = self.options.reconnect_min;
                                    match self.stop_after_reopen(&mut io).await {
                                        Ok(()) => {
                                            conn = Some(io);
                                            let e = self.epoch.fetch_add(1, Ordering::SeqCst) + 1;
                                            tracing::info!(line = %self.name, epoch = e, "line reconnected");
                                            let _ = self.events.send(AxisEvent::Connected {
                                                line: self.name.to_string(),
                                            });
                                        }
                                        Err(reason) => {
                                            tracing::warn!(line = %self.name, "reopened line fails at once: {reason}");
                                            self.down_reason = reason;
                                            next_try = Instant::now() + backoff;
                                        }
                                    }
                                }
                                Err(e) => {
                                    self.down_reason = format!("reopening fails: {e}");
                                    next_try = Instant::now() + backoff;
                                    backoff = (backoff * 2).min(self.options.reconnect_max);
                                }
                            }
                            Step::Continue
                        }
                    }
                }
            };
            match step {
                Step::Continue => {}
                Step::Exit => return,
                Step::Down(reason) => {
                    tracing::warn!(line = %self.name, "line down: {reason}");
                    conn = None;
                    self.session.reset();
                    self.down_reason = reason.clone();
                    next_try = Instant::now() + self.options.reconnect_min;
                    backoff = self.options.reconnect_min;
                    let _ = self.events.send(AxisEvent::Disconnected {
                        line: self.name.to_string(),
                        reason,
                    });
                }
            }
        }
    }

    /// [`LineOptions::stop_on_reopen`]: `#24` to every known controller,
    /// before anything else is written on the new connection.
    async fn stop_after_reopen(&mut self, io: &mut C::Io) -> Result<(), String> {
        if !self.options.stop_on_reopen || self.known.is_empty() {
            return Ok(());
        }
        let mut bytes = Vec::new();
        for &addr in &self.known {
            bytes.extend(crate::gcs::frame::encode_control(
                addr,
                ControlChar::StopAll,
            ));
            // Counted before the write: part of it may reach the controller
            // even if the write fails.
            lock_ledger(&self.ledger).wrote(addr);
        }
        write_now(io, &bytes)
            .await
            .map_err(|why| format!("{why}, on the re-opened line"))?;
        tracing::warn!(
            line = %self.name,
            controllers = self.known.len(),
            "line re-opened: stop all (#24) sent first"
        );
        Ok(())
    }

    /// A controller address this line writes to.
    fn note_address(&mut self, addr: Option<Address>) {
        if !self.known.contains(&addr) {
            self.known.push(addr);
        }
    }

    /// Writes an urgent byte; a failed or stalled write takes the line down.
    async fn write_urgent(&mut self, io: &mut C::Io, u: Urgent) -> Step {
        // Counted before the write: part of it may reach the controller
        // even if the write fails.
        lock_ledger(&self.ledger).wrote(u.addr);
        self.note_address(u.addr);
        match write_now(io, &u.bytes).await {
            Ok(()) => {
                let _ = u.done.send(Ok(()));
                Step::Continue
            }
            Err(reason) => {
                self.down_reason = reason.clone();
                let _ = u.done.send(Err(self.disconnected()));
                Step::Down(reason)
            }
        }
    }

    async fn handle(&mut self, io: &mut C::Io, req: Request) -> Step {
        match req {
            Request::Resync { quiet } => {
                self.quiet_needed = Some(self.quiet_needed.map_or(quiet, |q| q.max(quiet)));
                Step::Continue
            }
            Request::Exchange {
                addr,
                out,
                timeout,
                reply,
            } => {
                if reply.is_closed() {
                    // The caller gave up before anything was sent.
                    return Step::Continue;
                }
                self.note_address(addr);
                let (step, result) = self.exchange(io, addr, &out, timeout).await;
                let result = result.map(|outcome| Reply {
                    outcome,
                    epoch: self.epoch.load(Ordering::SeqCst),
                });
                let _ = reply.send(result);
                step
            }
        }
    }

    /// Reads whatever arrives within `quiet` (zero: only what is already
    /// there, without touching the timer, whose granularity is 1 ms); true
    /// when the line was quiet.
    async fn drain(&mut self, io: &mut C::Io, quiet: Duration) -> Result<bool, String> {
        let mut buf = [0u8; 1024];
        let read = if quiet.is_zero() {
            poll_once(io.read(&mut buf)).await
        } else {
            tokio::time::timeout(quiet, io.read(&mut buf)).await.ok()
        };
        self.drained(read, &buf)
    }

    /// What [`Task::drain`] read (`None`: nothing within the quiet time):
    /// true when the line was quiet.
    fn drained(
        &mut self,
        read: Option<std::io::Result<usize>>,
        buf: &[u8],
    ) -> Result<bool, String> {
        match read {
            None => Ok(true),
            Some(Ok(0)) => Err("end of file (device closed)".to_owned()),
            Some(Err(e)) => Err(format!("read error: {e}")),
            Some(Ok(n)) => {
                self.noise.fetch_add(1, Ordering::SeqCst);
                let now = self.now();
                for ev in self.session.on_bytes(now, &buf[..n]) {
                    if let SessionEvent::Unexpected(t) = ev {
                        self.noise(t);
                    }
                }
                Ok(false)
            }
        }
    }

    async fn exchange(
        &mut self,
        io: &mut C::Io,
        addr: Option<Address>,
        out: &Outgoing,
        timeout: Duration,
    ) -> (Step, Result<Outcome, DriverError>) {
        // 1. Resynchronise after a silence: let late answers arrive and drop them.
        if let Some(quiet) = self.quiet_needed.take() {
            // A line that never falls quiet (streaming garbage) gets a bounded wait.
            let give_up = Instant::now() + quiet * 10;
            loop {
                // An urgent write does not wait for the quiet: it expects
                // no answer, so a late answer cannot be taken for its own.
                let mut buf = [0u8; 1024];
                let read = tokio::select! {
                    biased;
                    Some(u) = self.urgent.recv() => {
                        if let Step::Down(reason) = self.write_urgent(io, u).await {
                            return (Step::Down(reason), Err(self.disconnected()));
                        }
                        continue;
                    }
                    r = tokio::time::timeout(quiet, io.read(&mut buf)) => r.ok(),
                };
                match self.drained(read, &buf) {
                    Ok(true) => break,
                    Ok(false) if Instant::now() >= give_up => break,
                    Ok(false) => {}
                    Err(reason) => {
                        self.down_reason = reason.clone();
                        return (Step::Down(reason), Err(self.disconnected()));
                    }
                }
            }
        }
        // 2. Take in what is already there, then drop any partial answer.
        loop {
            match self.drain(io, Duration::ZERO).await {
                Ok(true) => break,
                Ok(false) => {}
                Err(reason) => {
                    self.down_reason = reason.clone();
                    return (Step::Down(reason), Err(self.disconnected()));
                }
            }
        }
        self.session.reset();
        // 3. Write the request.
        let bytes = match self.session.start(self.now(), addr, out, timeout) {
            Ok(b) => b,
            Err(e) => return (Step::Continue, Err(DriverError::Invalid(e.to_string()))),
        };
        let written_before = lock_ledger(&self.ledger).written(addr);
        let (step, result) = self.write_and_wait(io, bytes, timeout).await;
        // The error ledger (module docs): an answered `ERR?` read every
        // write before it; anything else without an answer may have set
        // the register.
        let mut ledger = lock_ledger(&self.ledger);
        match (&result, out) {
            (Ok(Outcome::Answer(_)), Outgoing::Command(crate::gcs::Command::Err)) => {
                ledger.read(addr, written_before);
            }
            (Ok(Outcome::Answer(_)), _) => {}
            _ => ledger.wrote(addr),
        }
        drop(ledger);
        (step, result)
    }

    /// Step 3 and 4 of [`Task::exchange`]: writes `bytes`, then waits for
    /// the answer if one is due.
    async fn write_and_wait(
        &mut self,
        io: &mut C::Io,
        bytes: Vec<u8>,
        timeout: Duration,
    ) -> (Step, Result<Outcome, DriverError>) {
        let write = async {
            io.write_all(&bytes).await?;
            io.flush().await
        };
        match tokio::time::timeout(timeout.max(Duration::from_millis(100)), write).await {
            Ok(Ok(())) => {}
            Ok(Err(e)) => {
                let reason = format!("write error: {e}");
                self.down_reason = reason.clone();
                return (Step::Down(reason), Err(self.disconnected()));
            }
            Err(_) => {
                // Half a command may be on the line: only a reopen makes it clean.
                let reason = "write stalled (nobody reads the line)".to_owned();
                self.down_reason = reason.clone();
                return (Step::Down(reason), Err(self.disconnected()));
            }
        }
        if !self.session.is_busy() {
            return (Step::Continue, Ok(Outcome::Sent));
        }
        // 4. Wait for the answer or the deadline.
        let mut buf = [0u8; 1024];
        loop {
            let Some(deadline) = self.session.deadline() else {
                return (Step::Continue, Ok(Outcome::Silence { partial: false }));
            };
            let at = self.t0 + deadline;
            tokio::select! {
                biased;
                Some(u) = self.urgent.recv() => {
                    // The request is on the wire: the byte cannot split it.
                    if let Step::Down(reason) = self.write_urgent(io, u).await {
                        return (Step::Down(reason), Err(self.disconnected()));
                    }
                }
                r = io.read(&mut buf) => match r {
                    Ok(0) | Err(_) => {
                        let reason = match r {
                            Err(e) => format!("read error: {e}"),
                            _ => "end of file (device closed)".to_owned(),
                        };
                        self.down_reason = reason.clone();
                        return (Step::Down(reason), Err(self.disconnected()));
                    }
                    Ok(n) => {
                        let now = self.now();
                        let mut answer = None;
                        for ev in self.session.on_bytes(now, &buf[..n]) {
                            match ev {
                                SessionEvent::Answer(a) if answer.is_none() => answer = Some(a),
                                SessionEvent::Answer(a) => self.noise(a.text()),
                                SessionEvent::Unexpected(t) => {
                                    self.quiet_needed = Some(timeout);
                                    self.noise(t);
                                }
                                SessionEvent::Silence { .. } => {}
                            }
                        }
                        if let Some(a) = answer {
                            return (Step::Continue, Ok(Outcome::Answer(a)));
                        }
                    }
                },
                () = tokio::time::sleep_until(at) => {
                    if let Some(SessionEvent::Silence { partial }) = self.session.on_time(self.now()) {
                        self.quiet_needed = Some(timeout);
                        return (Step::Continue, Ok(Outcome::Silence { partial }));
                    }
                }
            }
        }
    }
}

/// Polls `fut` once: its output if it is ready now, else `None`.
/// How long a write that expects no answer (a stop) may take: a line
/// nobody reads is down.
const URGENT_WRITE_TIMEOUT: Duration = Duration::from_millis(100);

/// Writes and flushes `bytes` within [`URGENT_WRITE_TIMEOUT`]; the reason
/// the line is down otherwise.
async fn write_now<W: tokio::io::AsyncWrite + Unpin>(
    io: &mut W,
    bytes: &[u8],
) -> Result<(), String> {
    let write = async {
        io.write_all(bytes).await?;
        io.flush().await
    };
    match tokio::time::timeout(URGENT_WRITE_TIMEOUT, write).await {
        Ok(Ok(())) => Ok(()),
        Ok(Err(e)) => Err(format!("write error: {e}")),
        Err(_) => Err("write stalled (nobody reads the line)".to_owned()),
    }
}

async fn poll_once<F: std::future::Future>(fut: F) -> Option<F::Output> {
    let mut fut = std::pin::pin!(fut);
    std::future::poll_fn(|cx| match fut.as_mut().poll(cx) {
        std::task::Poll::Ready(v) => std::task::Poll::Ready(Some(v)),
        std::task::Poll::Pending => std::task::Poll::Ready(None),
    })
    .await
}
