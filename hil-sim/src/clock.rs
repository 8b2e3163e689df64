//! Simulated time.
//!
//! The controllers never read a clock themselves: every call into them
//! carries the simulated time. This module supplies that time. Served ptys
//! use [`ScaledClock`] (wall time × `time_scale`, so a test can run a
//! referencing move that takes 8 s on hardware in 0.4 s); in-process long
//! jobs use [`ManualClock`] and jump time forward themselves, which makes a
//! 9.5-hour characterization a matter of minutes and fully deterministic.

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// A source of simulated time: the time elapsed since the simulation began.
pub trait Clock: Send + Sync + std::fmt::Debug {
    /// Simulated time now. Never decreases.
    fn now(&self) -> Duration;

    /// Wall-clock time that simulated duration `d` takes, or `None` when
    /// simulated time does not follow the wall clock (manual clocks). Used
    /// to choose how long a serving thread may sleep.
    fn wall_for(&self, d: Duration) -> Option<Duration>;

    /// Jumps simulated time forward by `d` (the contract's
    /// `{"clock":"advance"}`): a client that knows it talks to the simulator
    /// skips waits, and the camera spends frame time. A clock that does not
    /// advance on request ([`Clock::advances_on_request`]) ignores it.
    fn advance(&self, d: Duration);

    /// Whether [`Clock::advance`] moves this clock. False for
    /// [`RuntimeClock`], whose time moves only with the runtime's timers:
    /// there the camera renders a frame at once and reports how long its
    /// exposure takes, and the caller sleeps that long on the same clock.
    fn advances_on_request(&self) -> bool {
        true
    }
}

/// The clock of the tokio runtime it was made in: wall time on an ordinary
/// runtime; on a *paused* current-thread runtime, virtual time, which
/// stands still while any task is runnable or any blocking task runs and
/// jumps to the next timer when every task waits.
///
/// Why: the in-process rig ([`crate::serve::SimHandle::start_in_process`])
/// and the micropos daemon then share one clock that no wall-clock delay
/// can move: a move, a settle, an exposure, a poll period or a timeout
/// each take exactly their simulated time, so one seed gives one result
/// whatever the machine's load (tokio's paused clock with auto-advance; see
/// ARCHITECTURE.md, "Simulated time"). Reads enter the runtime, so threads
/// outside it (the control socket) read the same time.
#[derive(Debug, Clone)]
pub struct RuntimeClock {
    epoch: tokio::time::Instant,
    handle: tokio::runtime::Handle,
}

impl RuntimeClock {
    /// A clock at zero now, on the current runtime; `None` outside one.
    pub fn new() -> Option<Self> {
        let handle = tokio::runtime::Handle::try_current().ok()?;
        Some(RuntimeClock {
            epoch: tokio::time::Instant::now(),
            handle,
        })
    }
}

impl Clock for RuntimeClock {
    fn now(&self) -> Duration {
        let _in_runtime = self.handle.enter();
        tokio::time::Instant::now().saturating_duration_since(self.epoch)
    }

    fn wall_for(&self, _d: Duration) -> Option<Duration> {
        None
    }

    fn advance(&self, _d: Duration) {}

    fn advances_on_request(&self) -> bool {
        false
    }
}

/// Wall time scaled by a constant factor, plus explicit advances:
/// sim_time = scale · wall_elapsed + Σ advances. Clones share the advances.
#[derive(Debug, Clone)]
pub struct ScaledClock {
    start: Instant,
    scale: f64,
    advanced: Arc<Mutex<Duration>>,
}

impl ScaledClock {
    /// A clock starting at zero now, running `scale` simulated seconds per
    /// wall second. `scale` must be finite and > 0 (checked by the caller's
    /// config validation; a bad value here is clamped to 1.0 so time still
    /// moves forward).
    pub fn new(scale: f64) -> Self {
        let scale = if scale.is_finite() && scale > 0.0 {
            scale
        } else {
            1.0
        };
        Self {
            start: Instant::now(),
            scale,
            advanced: Arc::default(),
        }
    }

    /// The scale factor.
    pub fn scale(&self) -> f64 {
        self.scale
    }
}

impl Clock for ScaledClock {
    fn now(&self) -> Duration {
        let wall = self.start.elapsed().as_secs_f64();
        let adv = *self.advanced.lock().unwrap_or_else(|e| e.into_inner());
        Duration::try_from_secs_f64(wall * self.scale)
            .unwrap_or(Duration::MAX)
            .saturating_add(adv)
    }

    fn wall_for(&self, d: Duration) -> Option<Duration> {
        Duration::try_from_secs_f64(d.as_secs_f64() / self.scale).ok()
    }

    fn advance(&self, d: Duration) {
        let mut g = self.advanced.lock().unwrap_or_else(|e| e.into_inner());
        *g = g.saturating_add(d);
    }
}

/// A clock that only moves when told to. Clones share the same time.
#[derive(Debug, Clone, Default)]
pub struct ManualClock {
    now: Arc<Mutex<Duration>>,
}

impl ManualClock {
    /// A clock at time zero.
    pub fn new() -> Self {
        Self::default()
    }

    /// Moves time forward by `d`.
    pub fn advance(&self, d: Duration) {
        let mut g = self.now.lock().unwrap_or_else(|e| e.into_inner());
        *g = g.saturating_add(d);
    }

    /// Sets the time; a time earlier than now is ignored (time never goes
    /// back, the controllers rely on it).
    pub fn set(&self, t: Duration) {
        let mut g = self.now.lock().unwrap_or_else(|e| e.into_inner());
        if t > *g {
            *g = t;
        }
    }
}

impl Clock for ManualClock {
    fn now(&self) -> Duration {
        *self.now.lock().unwrap_or_else(|e| e.into_inner())
    }

    fn advance(&self, d: Duration) {
        ManualClock::advance(self, d);
    }

    fn wall_for(&self, _d: Duration) -> Option<Duration> {
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn runtime_clock_follows_a_paused_runtime() {
        assert!(RuntimeClock::new().is_none());
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_time()
            .start_paused(true)
            .build()
            .unwrap();
        rt.block_on(async {
            let c = RuntimeClock::new().unwrap();
            let wall = Instant::now();
            tokio::time::sleep(Duration::from_secs(7200)).await;
            let t = c.now();
            assert!(
                t >= Duration::from_secs(7200) && t < Duration::from_secs(7201),
                "{t:?}"
            );
            assert!(wall.elapsed() < Duration::from_secs(60));
            // Read from a thread outside the runtime: the same time.
            let c2 = c.clone();
            let t2 = std::thread::spawn(move || c2.now()).join().unwrap();
            assert_eq!(t2, t);
            assert!(!c.advances_on_request());
        });
    }

    #[test]
    fn manual_clock_moves_only_forward() {
        let c = ManualClock::new();
        let c2 = c.clone();
        c.advance(Duration::from_secs(3));
        assert_eq!(c2.now(), Duration::from_secs(3));
        c.set(Duration::from_secs(1));
        assert_eq!(c.now(), Duration::from_secs(3));
        c.set(Duration::from_secs(10));
        assert_eq!(c2.now(), Duration::from_secs(10));
        assert_eq!(c.wall_for(Duration::from_secs(1)), None);
    }

    #[test]
    fn scaled_clock_scales() {
        let c = ScaledClock::new(100.0);
        assert_eq!(
            c.wall_for(Duration::from_secs(10)),
            Some(Duration::from_millis(100))
        );
        let a = c.now();
        let b = c.now();
        assert!(b >= a);
        assert_eq!(ScaledClock::new(f64::NAN).scale(), 1.0);
        assert_eq!(ScaledClock::new(-2.0).scale(), 1.0);
        let before = c.now();
        Clock::advance(&c, Duration::from_secs(100));
        assert!(c.now() >= before + Duration::from_secs(100));
    }
}
