//! Time as the rig sees it.
//!
//! Why a trait: on hardware, waiting for a settle time means sleeping; on the
//! simulated rig the same wait can advance simulated time at once, so a
//! 9.5-hour characterization runs in minutes while every move, settle and
//! exposure still takes its physical time on the rig's clock. Jobs and the
//! motion coordinator wait only through a [`RigClock`], never through
//! `tokio::time` directly, and timestamp measurements with [`RigClock::now_s`].

use std::fmt::Debug;
use std::future::Future;
use std::pin::Pin;
use std::time::Duration;

/// A boxed future, so [`RigClock`] stays object-safe.
pub type ClockFuture<'a> = Pin<Box<dyn Future<Output = ()> + Send + 'a>>;

/// The rig's clock.
pub trait RigClock: Send + Sync + Debug {
    /// Seconds on the rig's clock: monotonic since the clock was made for
    /// hardware, simulated time for the simulator.
    fn now_s(&self) -> f64;

    /// Waits `d` of rig time. Hardware sleeps; a simulated rig may advance
    /// its clock at once.
    fn sleep(&self, d: Duration) -> ClockFuture<'_>;
}

/// The tokio runtime's clock: monotonic wall time on hardware.
///
/// Why the runtime's clock and not `std::time::Instant`: the daemon's
/// timers (poll periods, timeouts, back-offs, the frame deadline) run on
/// `tokio::time`, and timestamps must be on the same clock as those timers.
/// On real hardware the two are the same monotonic time. Under a *paused*
/// current-thread runtime (the simulator's in-process rig, `hil-sim run`),
/// tokio's clock is virtual: it stands still while any task is runnable or
/// any blocking task runs, and jumps to the next timer when everything
/// waits. Then this clock reads that virtual time and `sleep` costs no wall
/// time, so one seed gives one result whatever the machine's load.
#[derive(Debug, Clone)]
pub struct WallClock {
    start: tokio::time::Instant,
}

impl WallClock {
    /// A clock reading 0 now. Call it inside the runtime whose clock it
    /// should read (outside any runtime it reads wall time).
    pub fn new() -> Self {
        Self {
            start: tokio::time::Instant::now(),
        }
    }
}

impl WallClock {
    /// A clock that read 0 at `start`: the simulator's in-process rig makes
    /// the daemon's clock read the simulator's time, so that the simulated
    /// camera's frame stamps are rig times.
    pub fn since(start: tokio::time::Instant) -> Self {
        Self { start }
    }
}

impl Default for WallClock {
    fn default() -> Self {
        Self::new()
    }
}

impl RigClock for WallClock {
    fn now_s(&self) -> f64 {
        tokio::time::Instant::now()
            .saturating_duration_since(self.start)
            .as_secs_f64()
    }

    fn sleep(&self, d: Duration) -> ClockFuture<'_> {
        Box::pin(tokio::time::sleep(d))
    }
}

/// The simulated rig's clock, read and advanced through `hil-sim`'s control
/// socket (`{"clock":"now"}`, `{"clock":"advance","s":…}`).
///
/// Why: on the simulator a settle time or an exposure should cost simulated
/// time, not wall time, so `sleep(d)` advances the rig's clock by `d` at once
/// and a 9.5-hour job runs in minutes. `now_s` is a synchronous trait method,
/// so it does one bounded exchange on a local Unix socket (answered by a
/// dedicated thread in microseconds; read/write timeouts 1 s); `sleep` runs
/// its exchange on the blocking pool. On a failed exchange `now_s` returns
/// the last time it knew (never going back) and logs the error: a clock must
/// not panic, and the next job step reports the dead simulator anyway.
#[derive(Debug)]
pub struct SimClock {
    path: std::path::PathBuf,
    conn: std::sync::Arc<std::sync::Mutex<SimClockConn>>,
}

#[derive(Debug, Default)]
struct SimClockConn {
    stream: Option<std::io::BufReader<std::os::unix::net::UnixStream>>,
    last_s: f64,
}

/// Why the simulated clock could not be read or advanced.
#[derive(Debug, thiserror::Error)]
pub enum SimClockError {
    /// The control socket could not be reached or broke.
    #[error("simulator control socket {path}: {source}")]
    Io {
        /// The socket path.
        path: String,
        /// The OS error.
        source: std::io::Error,
    },
    /// The simulator answered something that is not a clock reply.
    #[error("simulator control socket {path}: bad clock reply {reply:?}")]
    BadReply {
        /// The socket path.
        path: String,
        /// The reply line.
        reply: String,
    },
}

/// Longest control reply line read by [`SimClock`].
const SIM_CLOCK_MAX_REPLY: u64 = 64 * 1024;

impl SimClockConn {
    fn exchange(&mut self, path: &std::path::Path, request: &str) -> Result<f64, SimClockError> {
        use std::io::{BufRead, Read, Write};
        let io = |source| SimClockError::Io {
            path: path.display().to_string(),
            source,
        };
        if self.stream.is_none() {
            let s = std::os::unix::net::UnixStream::connect(path).map_err(io)?;
            let t = Some(Duration::from_secs(1));
            s.set_read_timeout(t).map_err(io)?;
            s.set_write_timeout(t).map_err(io)?;
            self.stream = Some(std::io::BufReader::new(s));
        }
        let r = (|| {
            let Some(stream) = self.stream.as_mut() else {
                return Err(io(std::io::Error::other("not connected")));
            };
            stream
                .get_mut()
                .write_all(format!("{request}\n").as_bytes())
                .map_err(io)?;
            let mut line = String::new();
            stream
                .by_ref()
                .take(SIM_CLOCK_MAX_REPLY)
                .read_line(&mut line)
                .map_err(io)?;
            let bad = || SimClockError::BadReply {
                path: path.display().to_string(),
                reply: line.trim_end().to_owned(),
            };
            let v: serde_json::Value = serde_json::from_str(&line).map_err(|_| bad())?;
            if v.get("ok").and_then(serde_json::Value::as_bool) != Some(true) {
                return Err(bad());
            }
            v.get("t_s")
                .and_then(serde_json::Value::as_f64)
                .filter(|t| t.is_finite())
                .ok_or_else(bad)
        })();
        match r {
            Ok(t) => {
                self.last_s = self.last_s.max(t);
                Ok(self.last_s)
            }
            Err(e) => {
                self.stream = None;
                Err(e)
            }
        }
    }
}

impl SimClock {
    /// Connects to the control socket of `hil-sim serve` and reads the time
    /// once, so a wrong path fails here.
    pub fn connect(path: &std::path::Path) -> Result<Self, SimClockError> {
        let c = Self {
            path: path.to_owned(),
            conn: Default::default(),
        };
        c.try_now_s()?;
        Ok(c)
    }

    /// Like [`SimClock::connect`], but waits up to `wait` for the simulator
    /// to come up: a daemon and `hil-sim serve` started together (a script,
    /// the README's lines pasted at once) must not race. Only a missing or
    /// refusing socket is waited for; any other failure returns at once.
    pub fn connect_waiting(path: &std::path::Path, wait: Duration) -> Result<Self, SimClockError> {
        let deadline = std::time::Instant::now() + wait;
        let mut logged = false;
        loop {
            match Self::connect(path) {
                Err(SimClockError::Io { ref source, .. })
                    if matches!(
                        source.kind(),
                        std::io::ErrorKind::NotFound | std::io::ErrorKind::ConnectionRefused
                    ) && std::time::Instant::now() < deadline =>
                {
                    if !logged {
                        tracing::info!(
                            "waiting up to {:.0} s for the simulator's control socket {}",
                            wait.as_secs_f64(),
                            path.display()
                        );
                        logged = true;
                    }
                    std::thread::sleep(Duration::from_millis(100));
                }
                r => return r,
            }
        }
    }

    /// Simulated time now, or why it could not be read.
    pub fn try_now_s(&self) -> Result<f64, SimClockError> {
        let mut g = self.conn.lock().unwrap_or_else(|e| e.into_inner());
        g.exchange(&self.path, r#"{"clock":"now"}"#)
    }

    /// Advances simulated time by `d` (blocking exchange); returns the new time.
    pub fn advance_blocking(&self, d: Duration) -> Result<f64, SimClockError> {
        let mut g = self.conn.lock().unwrap_or_else(|e| e.into_inner());
        let req = serde_json::json!({"clock": "advance", "s": d.as_secs_f64()}).to_string();
        g.exchange(&self.path, &req)
    }
}

impl RigClock for SimClock {
    fn now_s(&self) -> f64 {
        match self.try_now_s() {
            Ok(t) => t,
            Err(e) => {
                tracing::warn!("{e}");
                self.conn.lock().unwrap_or_else(|e| e.into_inner()).last_s
            }
        }
    }

    fn sleep(&self, d: Duration) -> ClockFuture<'_> {
        let conn = self.conn.clone();
        let path = self.path.clone();
        Box::pin(async move {
            let req = serde_json::json!({"clock": "advance", "s": d.as_secs_f64()}).to_string();
            let r = tokio::task::spawn_blocking(move || {
                let mut g = conn.lock().unwrap_or_else(|e| e.into_inner());
                g.exchange(&path, &req)
            })
            .await;
            match r {
                Ok(Ok(_)) => {}
                Ok(Err(e)) => {
                    // Time must still pass for the caller: fall back to
                    // waiting on the wall clock.
                    tracing::warn!("{e}; sleeping on the wall clock instead");
                    tokio::time::sleep(d).await;
                }
                Err(e) => {
                    tracing::warn!("clock advance task failed: {e}");
                    tokio::time::sleep(d).await;
                }
            }
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test(start_paused = true)]
    async fn wall_clock_follows_a_paused_runtime() {
        let c = WallClock::new();
        let wall = std::time::Instant::now();
        c.sleep(Duration::from_secs(3600)).await;
        assert!((c.now_s() - 3600.0).abs() < 2e-3, "{}", c.now_s());
        assert!(wall.elapsed() < Duration::from_secs(60));
    }

    /// A daemon started beside `hil-sim serve` waits for its control
    /// socket instead of exiting; without a wait a missing socket fails.
    #[test]
    fn sim_clock_waits_for_a_simulator_that_is_starting() {
        use std::io::{BufRead, Write};
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("control.sock");
        assert!(matches!(
            SimClock::connect_waiting(&path, Duration::ZERO),
            Err(SimClockError::Io { .. })
        ));
        let p = path.clone();
        let server = std::thread::spawn(move || {
            std::thread::sleep(Duration::from_millis(300));
            let l = std::os::unix::net::UnixListener::bind(&p).unwrap();
            let (s, _) = l.accept().unwrap();
            let mut r = std::io::BufReader::new(s.try_clone().unwrap());
            let mut w = s;
            let mut line = String::new();
            while r.read_line(&mut line).unwrap_or(0) > 0 {
                writeln!(w, r#"{{"ok":true,"t_s":12.5}}"#).unwrap();
                line.clear();
            }
        });
        let c = SimClock::connect_waiting(&path, Duration::from_secs(60)).unwrap();
        assert_eq!(c.try_now_s().unwrap(), 12.5);
        drop(c);
        server.join().unwrap();
    }

    #[tokio::test]
    async fn wall_clock_advances_by_sleeping() {
        let c = WallClock::new();
        let t0 = c.now_s();
        c.sleep(Duration::from_millis(5)).await;
        assert!(c.now_s() - t0 >= 0.005);
        let dynamic: &dyn RigClock = &c;
        assert!(dynamic.now_s() >= 0.005);
    }
}

/// A UTC calendar time (proleptic Gregorian), for the few timestamps micropos
/// writes into files (compensation tables, GDSII headers). Why here and not a
/// date crate: one conversion, civil-from-days, is all that is needed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct UtcTime {
    /// Year.
    pub year: i64,
    /// 1..=12.
    pub month: u32,
    /// 1..=31.
    pub day: u32,
    /// 0..=23.
    pub hour: u32,
    /// 0..=59.
    pub minute: u32,
    /// 0..=59.
    pub second: u32,
}

impl UtcTime {
    /// The UTC time of `unix_s` seconds since 1970-01-01T00:00:00Z.
    pub fn from_unix(unix_s: u64) -> Self {
        let days = (unix_s / 86_400) as i64;
        let rem = unix_s % 86_400;
        // Civil-from-days, era-based (400-year eras of 146 097 days).
        let z = days + 719_468;
        let era = z.div_euclid(146_097);
        let doe = z - era * 146_097;
        let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
        let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
        let mp = (5 * doy + 2) / 153;
        let day = doy - (153 * mp + 2) / 5 + 1;
        let month = if mp < 10 { mp + 3 } else { mp - 9 };
        UtcTime {
            year: yoe + era * 400 + i64::from(month <= 2),
            month: month as u32,
            day: day as u32,
            hour: (rem / 3600) as u32,
            minute: (rem % 3600 / 60) as u32,
            second: (rem % 60) as u32,
        }
    }

    /// RFC 3339 text, e.g. `2026-11-18T11:06:40Z`.
    pub fn rfc3339(&self) -> String {
        format!(
            "{:04}-{:02}-{:02}T{:02}:{:02}:{:02}Z",
            self.year, self.month, self.day, self.hour, self.minute, self.second
        )
    }
}
