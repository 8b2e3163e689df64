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
    /// skips waits, and the camera spends frame time.
    fn advance(&self, d: Duration);
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
