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
use std::time::{Duration, Instant};

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

/// The clock of real hardware: monotonic wall time.
#[derive(Debug, Clone)]
pub struct WallClock {
    start: Instant,
}

impl WallClock {
    /// A clock reading 0 now.
    pub fn new() -> Self {
        Self {
            start: Instant::now(),
        }
    }
}

impl Default for WallClock {
    fn default() -> Self {
        Self::new()
    }
}

impl RigClock for WallClock {
    fn now_s(&self) -> f64 {
        self.start.elapsed().as_secs_f64()
    }

    fn sleep(&self, d: Duration) -> ClockFuture<'_> {
        Box::pin(tokio::time::sleep(d))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
