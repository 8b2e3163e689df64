//! Test-only fake C-863 (one or several on a daisy chain) on an in-memory
//! duplex stream, built from the gcs core's server side, plus a connector
//! that hands out duplex streams. Time is tokio time, so tests run with a
//! paused clock.

use super::error::DriverError;
use super::transport::Connector;
use crate::gcs::answer::Identification;
use crate::gcs::frame::{encode_answer, Address, Request, RequestDecoder};
use crate::gcs::{Command, ControlChar};
use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tokio::io::{AsyncReadExt, AsyncWriteExt, DuplexStream};
use tokio::sync::mpsc;
use tokio::time::Instant;

pub const IDN: &str = "(c)2015 Physik Instrumente (PI) GmbH & Co. KG, C-863.11, 0115500123, 01.110";

#[derive(Debug, Clone)]
pub struct FakeAxis {
    pub idn: String,
    pub referenced: bool,
    pub servo: bool,
    pub error: i32,
    start_mm: f64,
    start_at: Instant,
    pub target_mm: f64,
    pub vel_mm_s: f64,
    ref_done_at: Option<Instant>,
    pub min_mm: f64,
    pub max_mm: f64,
    /// `ONT?` queries answered.
    pub ont_queries: u64,
}

impl FakeAxis {
    pub fn new() -> Self {
        Self {
            idn: IDN.to_owned(),
            referenced: false,
            servo: false,
            error: 0,
            start_mm: 0.0,
            start_at: Instant::now(),
            target_mm: 0.0,
            vel_mm_s: 1.0,
            ref_done_at: None,
            min_mm: 0.0,
            max_mm: 15.0,
            ont_queries: 0,
        }
    }

    pub fn power_cycle(&mut self) {
        let idn = self.idn.clone();
        *self = Self::new();
        self.idn = idn;
    }

    fn tick(&mut self, now: Instant) {
        if let Some(t) = self.ref_done_at {
            if now >= t {
                self.ref_done_at = None;
                self.referenced = true;
                self.start_mm = 7.5;
                self.target_mm = 7.5;
                self.start_at = now;
            }
        }
    }

    pub fn pos_mm(&self, now: Instant) -> f64 {
        let d = self.target_mm - self.start_mm;
        let travelled = self.vel_mm_s * now.saturating_duration_since(self.start_at).as_secs_f64();
        if travelled >= d.abs() {
            self.target_mm
        } else {
            self.start_mm + d.signum() * travelled
        }
    }

    fn start_move(&mut self, now: Instant, target: f64) {
        self.start_mm = self.pos_mm(now);
        self.start_at = now;
        self.target_mm = target;
    }

    fn stop(&mut self, now: Instant) {
        let p = self.pos_mm(now);
        self.start_mm = p;
        self.target_mm = p;
        self.ref_done_at = None;
        self.error = 10;
    }

    /// Answer lines, or None for silence (errors set `self.error`).
    fn execute(&mut self, now: Instant, text: &str) -> Option<Vec<String>> {
        self.tick(now);
        let cmd = match Command::parse(text) {
            Ok(c) => c,
            Err(e) => {
                self.error = e.gcs_code().0;
                return None;
            }
        };
        let one = |v: String| Some(vec![format!("1={v}")]);
        let num = |v: f64| one(format!("{v:.7}"));
        let b = |v: bool| one(if v { "1".into() } else { "0".into() });
        let moving_ok = |s: &mut Self, t: f64| -> bool {
            if !s.referenced || !s.servo {
                s.error = 5;
                false
            } else if t < s.min_mm || t > s.max_mm {
                s.error = 7;
                false
            } else {
                true
            }
        };
        match cmd {
            Command::Idn => Some(vec![self.idn.clone()]),
            Command::Csv => Some(vec!["2.0".into()]),
            Command::Err => {
                let e = self.error;
                self.error = 0;
                Some(vec![e.to_string()])
            }
            Command::SaiQuery { .. } => Some(vec!["1".into()]),
            Command::TmnQuery(_) => num(self.min_mm),
            Command::TmxQuery(_) => num(self.max_mm),
            Command::PosQuery(_) => num(self.pos_mm(now)),
            Command::MovQuery(_) => num(self.target_mm),
            Command::OntQuery(_) => {
                self.ont_queries += 1;
                b(self.pos_mm(now) == self.target_mm && self.ref_done_at.is_none())
            }
            Command::FrfQuery(_) => b(self.referenced),
            Command::SvoQuery(_) => b(self.servo),
            Command::VelQuery(_) => num(self.vel_mm_s),
            // It moves at its velocity from the first instant.
            Command::AccQuery(_) | Command::DecQuery(_) => num(1e6),
            Command::Svo(p) => {
                self.servo = p.first().is_some_and(|x| x.1);
                None
            }
            Command::Frf(_) | Command::Fnl(_) | Command::Fpl(_) => {
                if self.servo {
                    self.referenced = false;
                    self.ref_done_at = Some(now + Duration::from_secs(1));
                } else {
                    self.error = 5;
                }
                None
            }
            Command::Mov(p) => {
                let t = p.first().map_or(0.0, |x| x.1);
                if moving_ok(self, t) {
                    self.start_move(now, t);
                }
                None
            }
            Command::Mvr(p) => {
                let t = self.target_mm + p.first().map_or(0.0, |x| x.1);
                if moving_ok(self, t) {
                    self.start_move(now, t);
                }
                None
            }
            Command::Vel(p) => {
                let v = p.first().map_or(0.0, |x| x.1);
                if v > 0.0 && v <= 1.5 {
                    self.start_move(now, self.target_mm);
                    self.vel_mm_s = v;
                } else {
                    self.error = 8;
                }
                None
            }
            Command::Hlt(_) | Command::Stp => {
                self.stop(now);
                None
            }
            _ => {
                self.error = 2;
                None
            }
        }
    }

    fn control(&mut self, now: Instant, c: ControlChar) -> Option<Vec<u8>> {
        self.tick(now);
        match c {
            ControlChar::Ready => Some(vec![if self.ref_done_at.is_some() {
                0xB0
            } else {
                0xB1
            }]),
            ControlChar::MotionStatus => {
                let moving = self.pos_mm(now) != self.target_mm || self.ref_done_at.is_some();
                Some(if moving { b"1".to_vec() } else { b"0".to_vec() })
            }
            ControlChar::Status => Some(b"0x9005".to_vec()),
            ControlChar::StopAll => {
                self.stop(now);
                None
            }
        }
    }
}

#[derive(Debug, Default)]
pub struct Bus {
    pub axes: BTreeMap<u8, FakeAxis>,
    pub silent: bool,
    pub delay: Duration,
}

#[derive(Clone)]
pub struct Fake {
    pub bus: Arc<Mutex<Bus>>,
}

impl Fake {
    pub fn new(addresses: &[u8]) -> Self {
        let mut bus = Bus::default();
        for &a in addresses {
            bus.axes.insert(a, FakeAxis::new());
        }
        Self {
            bus: Arc::new(Mutex::new(bus)),
        }
    }

    pub fn with<R>(&self, f: impl FnOnce(&mut Bus) -> R) -> R {
        f(&mut self.bus.lock().unwrap())
    }

    pub fn axis<R>(&self, addr: u8, f: impl FnOnce(&mut FakeAxis) -> R) -> R {
        self.with(|b| f(b.axes.get_mut(&addr).unwrap()))
    }

    /// Serves the controller side of `io` until it closes or `garbage`
    /// says so; `garbage` bytes are written to the host at once.
    pub fn serve<S>(&self, io: S) -> mpsc::UnboundedSender<Vec<u8>>
    where
        S: tokio::io::AsyncRead + tokio::io::AsyncWrite + Send + 'static,
    {
        let (tx, mut rx) = mpsc::unbounded_channel::<Vec<u8>>();
        let (mut rd, wr) = tokio::io::split(io);
        let wr = Arc::new(tokio::sync::Mutex::new(wr));
        let gw = wr.clone();
        let (pulled_tx, mut pulled) = tokio::sync::watch::channel(false);
        // Garbage (and the pulled cable) go out independently of answers.
        tokio::spawn(async move {
            while let Some(g) = rx.recv().await {
                let mut w = gw.lock().await;
                if g.is_empty() {
                    let _ = w.shutdown().await;
                    let _ = pulled_tx.send(true);
                    return;
                }
                let _ = w.write_all(&g).await;
            }
        });
        let bus = self.bus.clone();
        tokio::spawn(async move {
            let mut dec = RequestDecoder::new();
            let mut buf = [0u8; 256];
            loop {
                let r = tokio::select! {
                    r = rd.read(&mut buf) => r,
                    _ = pulled.changed() => return,
                };
                let n = match r {
                    Ok(0) => return,
                    Ok(n) => n,
                    // A pty master reads EIO while no slave is open yet.
                    Err(_) => {
                        tokio::time::sleep(Duration::from_millis(5)).await;
                        continue;
                    }
                };
                for req in dec.push(&buf[..n]) {
                    let now = Instant::now();
                    let (reply, delay) = {
                        let mut bus = bus.lock().unwrap();
                        let silent = bus.silent;
                        let delay = bus.delay;
                        let out = match req {
                            Request::Line { addr, text } => {
                                let a = addr.map_or(1, Address::get);
                                let Some(ax) = bus.axes.get_mut(&a) else {
                                    continue;
                                };
                                ax.execute(now, &text).map(|l| encode_answer(addr, &l))
                            }
                            Request::Control { addr, command } => {
                                let a = addr.map_or(1, Address::get);
                                let Some(ax) = bus.axes.get_mut(&a) else {
                                    continue;
                                };
                                ax.control(now, command).map(|raw| {
                                    let mut v = Vec::new();
                                    if let Some(a) = addr {
                                        v.extend_from_slice(format!("0 {a} ").as_bytes());
                                    }
                                    v.extend_from_slice(&raw);
                                    v.push(b'\n');
                                    v
                                })
                            }
                            Request::Overlong => continue,
                        };
                        (if silent { None } else { out }, delay)
                    };
                    if let Some(r) = reply {
                        let wr = wr.clone();
                        // Equal delays keep the answers in order.
                        tokio::spawn(async move {
                            tokio::time::sleep(delay).await;
                            let _ = wr.lock().await.write_all(&r).await;
                        });
                    }
                }
            }
        });
        tx
    }
}

/// Hands out duplex streams to the line; no stream queued = no device.
pub struct DuplexConnector {
    rx: mpsc::UnboundedReceiver<DuplexStream>,
}

pub fn duplex_connector() -> (DuplexConnector, mpsc::UnboundedSender<DuplexStream>) {
    let (tx, rx) = mpsc::unbounded_channel();
    (DuplexConnector { rx }, tx)
}

impl Connector for DuplexConnector {
    type Io = DuplexStream;

    async fn connect(&mut self) -> Result<DuplexStream, DriverError> {
        self.rx.try_recv().map_err(|_| DriverError::NoDevice {
            path: "fake".into(),
            reason: "no stream queued".into(),
        })
    }

    fn name(&self) -> String {
        "fake".to_owned()
    }
}

#[allow(dead_code)]
pub fn identity() -> Identification {
    crate::gcs::answer::identification(&crate::gcs::Answer::from_lines(vec![IDN
        .as_bytes()
        .to_vec()]))
    .unwrap()
}
