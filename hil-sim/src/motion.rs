//! Trapezoidal point-to-point motion profiles, evaluated lazily in time.
//!
//! Why lazily: the simulated controller has no tick. A profile is planned
//! once (when a command changes the motion) as a short list of
//! constant-acceleration phases, and position/velocity at any later time are
//! closed-form. A 9.5-hour characterization run in virtual time therefore
//! costs one evaluation per query, not one per servo cycle.
//!
//! Units: positions in mm, velocities in mm/s, accelerations in mm/s², times
//! as [`Duration`] since the simulation started. Sign convention: positive
//! velocity moves towards larger positions.

use std::time::Duration;

/// One constant-acceleration phase.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Phase {
    duration_s: f64,
    accel: f64,
}

/// Kinematic limits of a move.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Limits {
    /// Cruise velocity (mm/s, > 0).
    pub velocity: f64,
    /// Acceleration used when speeding up (mm/s², > 0).
    pub acceleration: f64,
    /// Deceleration used when slowing down (mm/s², > 0).
    pub deceleration: f64,
}

/// A planned motion from a start state to a rest position.
///
/// Invariant: the profile ends at rest exactly at `end_mm` (the last phase is
/// snapped to it, so float round-off never leaves a target missed by 1e-16).
#[derive(Debug, Clone, PartialEq)]
pub struct Profile {
    start: Duration,
    start_mm: f64,
    start_vel: f64,
    phases: Vec<Phase>,
    end_mm: f64,
}

/// Distance covered when braking from `v` to rest with deceleration `dec`.
fn braking_distance(v: f64, dec: f64) -> f64 {
    v * v / (2.0 * dec)
}

impl Profile {
    /// Plans a move from position `p0` with velocity `v0` at time `start` to
    /// rest at `target`, never exceeding `limits.velocity` (except while
    /// braking down from an initial speed above it).
    ///
    /// Handles every start state: at rest, moving towards the target, moving
    /// away from it, or too fast to stop before it (it then overshoots,
    /// stops, and comes back, as a servo with a trapezoidal generator does).
    pub fn plan(start: Duration, p0: f64, v0: f64, target: f64, limits: Limits) -> Profile {
        let Limits {
            velocity: vmax,
            acceleration: acc,
            deceleration: dec,
        } = limits;
        let mut phases = Vec::new();
        let mut p = p0;
        let mut v = v0;
        // Phase A: if moving away from the target, or so fast that braking
        // now would overshoot it, brake to rest first.
        let d = target - p;
        let dir = if d > 0.0 {
            1.0
        } else if d < 0.0 {
            -1.0
        } else {
            -v.signum()
        };
        let v_along = v * dir;
        if v != 0.0 && (v_along < 0.0 || braking_distance(v_along, dec) > d.abs()) {
            let t = v.abs() / dec;
            let a = -v.signum() * dec;
            phases.push(Phase {
                duration_s: t,
                accel: a,
            });
            p += v * t + 0.5 * a * t * t;
            v = 0.0;
        }
        // Phase B: from (p, v) with v either 0 or towards the target and
        // able to stop in time: accelerate (or slow) to a peak, cruise, brake.
        let d = target - p;
        let dist = d.abs();
        if dist > 0.0 {
            let dir = d.signum();
            let u = (v * dir).max(0.0);
            let to_peak = |vp: f64| {
                if vp >= u {
                    (vp * vp - u * u) / (2.0 * acc)
                } else {
                    (u * u - vp * vp) / (2.0 * dec)
                }
            };
            let full = to_peak(vmax) + braking_distance(vmax, dec);
            let vpeak = if full <= dist {
                vmax
            } else if u <= vmax {
                // Triangular: accelerate from u to vp, then brake to 0.
                ((2.0 * acc * dec * dist + dec * u * u) / (acc + dec)).sqrt()
            } else {
                // Faster than vmax but able to stop: brake straight to rest.
                u
            };
            let (t1, a1) = if vpeak >= u {
                ((vpeak - u) / acc, acc * dir)
            } else {
                ((u - vpeak) / dec, -dec * dir)
            };
            let cruise = (dist - to_peak(vpeak) - braking_distance(vpeak, dec)).max(0.0);
            let t2 = if vpeak > 0.0 { cruise / vpeak } else { 0.0 };
            let t3 = vpeak / dec;
            for (t, a) in [(t1, a1), (t2, 0.0), (t3, -dec * dir)] {
                if t > 0.0 {
                    phases.push(Phase {
                        duration_s: t,
                        accel: a,
                    });
                }
            }
        }
        Profile {
            start,
            start_mm: p0,
            start_vel: v0,
            phases,
            end_mm: target,
        }
    }

    /// A profile that brakes from `(p0, v0)` to rest with deceleration
    /// `dec` (what `HLT` does). Its end position is wherever it stops.
    pub fn brake(start: Duration, p0: f64, v0: f64, dec: f64) -> Profile {
        let t = v0.abs() / dec;
        let a = -v0.signum() * dec;
        let end = p0 + v0 * t + 0.5 * a * t * t;
        let phases = if t > 0.0 {
            vec![Phase {
                duration_s: t,
                accel: a,
            }]
        } else {
            Vec::new()
        };
        Profile {
            start,
            start_mm: p0,
            start_vel: v0,
            phases,
            end_mm: end,
        }
    }

    /// Total duration of the motion.
    pub fn duration(&self) -> Duration {
        Duration::from_secs_f64(self.phases.iter().map(|p| p.duration_s).sum::<f64>())
    }

    /// When the motion ends (the axis is at rest at [`Profile::end_mm`]).
    pub fn end_time(&self) -> Duration {
        self.start + self.duration()
    }

    /// Where the motion comes to rest.
    pub fn end_mm(&self) -> f64 {
        self.end_mm
    }

    /// Position (mm) and velocity (mm/s) at time `now`. Before the start it
    /// is the start state; after the end it is at rest at the end position.
    pub fn state_at(&self, now: Duration) -> (f64, f64) {
        if now >= self.end_time() {
            return (self.end_mm, 0.0);
        }
        let Some(mut t) = now.checked_sub(self.start).map(|d| d.as_secs_f64()) else {
            return (self.start_mm, self.start_vel);
        };
        let mut p = self.start_mm;
        let mut v = self.start_vel;
        for ph in &self.phases {
            if t <= ph.duration_s {
                return (p + v * t + 0.5 * ph.accel * t * t, v + ph.accel * t);
            }
            p += v * ph.duration_s + 0.5 * ph.accel * ph.duration_s * ph.duration_s;
            v += ph.accel * ph.duration_s;
            t -= ph.duration_s;
        }
        (self.end_mm, 0.0)
    }

    /// Whether the motion has ended at `now`.
    pub fn is_done(&self, now: Duration) -> bool {
        now >= self.end_time()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    const L: Limits = Limits {
        velocity: 1.0,
        acceleration: 10.0,
        deceleration: 5.0,
    };

    fn s(v: f64) -> Duration {
        Duration::from_secs_f64(v)
    }

    #[test]
    fn trapezoid_from_rest() {
        let p = Profile::plan(s(1.0), 0.0, 0.0, 2.0, L);
        // accel 0.1 s (0.05 mm), brake 0.2 s (0.1 mm), cruise 1.85 mm.
        let expected = 0.1 + 1.85 + 0.2;
        assert!((p.duration().as_secs_f64() - expected).abs() < 1e-9);
        let (x, v) = p.state_at(s(1.05));
        assert!((x - 0.5 * 10.0 * 0.05 * 0.05).abs() < 1e-12);
        assert!((v - 0.5).abs() < 1e-12);
        let (x, v) = p.state_at(s(1.0 + 1.0));
        assert!((v - 1.0).abs() < 1e-12);
        assert!((x - (0.05 + 0.9)).abs() < 1e-9);
        assert_eq!(p.state_at(p.end_time() + s(1.0)), (2.0, 0.0));
        assert_eq!(p.state_at(s(0.5)), (0.0, 0.0));
    }

    #[test]
    fn triangular_short_move() {
        let p = Profile::plan(s(0.0), 1.0, 0.0, 0.99, L);
        let peak = p
            .phases
            .iter()
            .scan(0.0, |v, ph| {
                *v += ph.accel * ph.duration_s;
                Some(v.abs())
            })
            .fold(0.0, f64::max);
        assert!(peak < 1.0);
        assert_eq!(p.state_at(p.end_time()), (0.99, 0.0));
    }

    #[test]
    fn reversal_and_overshoot() {
        // Moving at 1 mm/s towards +, new target just behind: brake, return.
        let p = Profile::plan(s(0.0), 5.0, 1.0, 5.01, L);
        let (x, _) = p.state_at(s(0.2));
        assert!((x - 5.1).abs() < 1e-9, "braked to 5.1, got {x}");
        assert_eq!(p.state_at(p.end_time()), (5.01, 0.0));
        // Moving away from the target.
        let p = Profile::plan(s(0.0), 5.0, -1.0, 6.0, L);
        assert!(p.state_at(s(0.2)).0 < 5.0);
        assert_eq!(p.state_at(p.end_time()), (6.0, 0.0));
    }

    #[test]
    fn brake_profile() {
        let p = Profile::brake(s(0.0), 3.0, -1.0, 5.0);
        assert!((p.end_mm() - 2.9).abs() < 1e-12);
        assert!((p.duration().as_secs_f64() - 0.2).abs() < 1e-12);
        let p = Profile::brake(s(0.0), 3.0, 0.0, 5.0);
        assert_eq!(p.duration(), Duration::ZERO);
        assert_eq!(p.end_mm(), 3.0);
    }

    proptest! {
        #[test]
        fn profiles_respect_limits_and_end_on_target(
            p0 in -20.0f64..20.0, v0 in -3.0f64..3.0, target in -20.0f64..20.0,
            vel in 0.01f64..3.0, acc in 0.5f64..50.0, dec in 0.5f64..50.0,
        ) {
            let lim = Limits { velocity: vel, acceleration: acc, deceleration: dec };
            let p = Profile::plan(s(2.0), p0, v0, target, lim);
            let end = p.end_time();
            prop_assert_eq!(p.state_at(end), (target, 0.0));
            let n = 200;
            let total = p.duration().as_secs_f64();
            let mut prev = p.state_at(s(2.0));
            prop_assert!((prev.0 - p0).abs() < 1e-12);
            for i in 1..=n {
                let t = s(2.0 + total * f64::from(i) / f64::from(n));
                let (x, v) = p.state_at(t);
                // Never faster than the larger of the initial speed and vmax.
                prop_assert!(v.abs() <= vel.max(v0.abs()) + 1e-9);
                // Position is continuous (bounded by the speed).
                let dt = total / f64::from(n);
                // (1e-7: sample times are rounded to whole nanoseconds.)
                prop_assert!((x - prev.0).abs() <= vel.max(v0.abs()) * dt + 1e-7);
                prev = (x, v);
            }
            prop_assert!((prev.0 - target).abs() < 1e-6);
        }
    }
}
