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
//!
//! Following error: the profile is the *command*; the axis's actual
//! position trails it through a first-order servo lag of time constant τ
//! ([`Profile::with_lag`]): `e' = v_cmd − e/τ`, `actual = command − e`. At
//! constant velocity `e = v·τ` (the `v/Kv` of a velocity-gain servo, Kv =
//! 1/τ). Per constant-acceleration phase the lag is closed-form too:
//! `e(t) = τ(v₀ + a·t) − τ²a + (e₀ − τv₀ + τ²a)·exp(−t/τ)`. After the
//! command ends, `e` decays as `exp(−t/τ)`; the motion ends (the actual
//! position is snapped onto the target) [`LAG_TAIL_TIME_CONSTANTS`] τ
//! later, when the rest is below a picometre.

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

/// Time constants of following-error decay after the command ends before
/// the motion counts as over: the error left is `exp(−12)` ≈ 6e-6 of what
/// it was when the command stopped (≤ τ·v, a few µm at most).
pub const LAG_TAIL_TIME_CONSTANTS: f64 = 12.0;

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
    /// Servo lag time constant τ, s (0: the axis is where the command is).
    lag_s: f64,
    /// Following error (command − actual) at the start, mm.
    lag0_mm: f64,
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
            lag_s: 0.0,
            lag0_mm: 0.0,
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
            lag_s: 0.0,
            lag0_mm: 0.0,
        }
    }

    /// The same command followed by an axis with servo lag `lag_s` (τ, s;
    /// non-finite or negative: none) that trails it by `lag0_mm` at the
    /// start (the following error of the motion this one replaces). See
    /// the module docs.
    pub fn with_lag(mut self, lag_s: f64, lag0_mm: f64) -> Profile {
        if lag_s.is_finite() && lag_s > 0.0 && lag0_mm.is_finite() {
            self.lag_s = lag_s;
            self.lag0_mm = lag0_mm;
        }
        self
    }

    /// Duration of the command.
    pub fn duration(&self) -> Duration {
        Duration::from_secs_f64(self.phases.iter().map(|p| p.duration_s).sum::<f64>())
    }

    /// When the command ends (the trajectory generator is at the target).
    pub fn command_end_time(&self) -> Duration {
        self.start + self.duration()
    }

    /// When the motion ends (the axis is at rest at [`Profile::end_mm`]):
    /// the command's end plus the following error's decay.
    pub fn end_time(&self) -> Duration {
        let tail = if self.lag_s > 0.0 {
            Duration::from_secs_f64(LAG_TAIL_TIME_CONSTANTS * self.lag_s)
        } else {
            Duration::ZERO
        };
        self.command_end_time() + tail
    }

    /// Where the motion comes to rest.
    pub fn end_mm(&self) -> f64 {
        self.end_mm
    }

    /// Actual position (mm) and velocity (mm/s) at time `now`: the
    /// command less the following error. Before the start it is the start
    /// state; after the end it is at rest at the end position.
    pub fn state_at(&self, now: Duration) -> (f64, f64) {
        if now >= self.end_time() {
            return (self.end_mm, 0.0);
        }
        let (p, v) = self.command_at(now);
        if self.lag_s <= 0.0 {
            return (p, v);
        }
        let e = self.following_error_at(now);
        // e' = v − e/τ, so the actual velocity v − e' is e/τ.
        (p - e, e / self.lag_s)
    }

    /// Following error (command − actual position) at `now`, mm.
    pub fn following_error_at(&self, now: Duration) -> f64 {
        let tau = self.lag_s;
        if tau <= 0.0 || now >= self.end_time() {
            return 0.0;
        }
        let Some(mut t) = now.checked_sub(self.start).map(|d| d.as_secs_f64()) else {
            return self.lag0_mm;
        };
        let mut e = self.lag0_mm;
        let mut v = self.start_vel;
        for ph in &self.phases {
            let dt = t.min(ph.duration_s);
            let a = ph.accel;
            e = tau * (v + a * dt) - tau * tau * a
                + (e - tau * v + tau * tau * a) * (-dt / tau).exp();
            if t <= ph.duration_s {
                return e;
            }
            v += a * ph.duration_s;
            t -= ph.duration_s;
        }
        e * (-t / tau).exp()
    }

    /// Commanded position (mm) and velocity (mm/s) at time `now` (the
    /// trajectory generator's, without the following error).
    pub fn command_at(&self, now: Duration) -> (f64, f64) {
        if now >= self.command_end_time() {
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

    /// At constant velocity the axis trails the command by v·τ; the lag is
    /// continuous across a re-plan and decays after the command ends.
    #[test]
    fn following_error_is_v_tau_at_cruise_and_decays() {
        let tau = 0.002;
        let p = Profile::plan(s(1.0), 0.0, 0.0, 2.0, L).with_lag(tau, 0.0);
        // Cruise from 1.1 s to ≈ 2.95 s at 1 mm/s: e = τ·v after the
        // acceleration's transient (≫ τ).
        let e = p.following_error_at(s(2.0));
        assert!((e - tau * 1.0).abs() < 1e-12, "{e}");
        let (x, v) = p.state_at(s(2.0));
        let (xc, vc) = p.command_at(s(2.0));
        assert!((xc - x - tau).abs() < 1e-12 && (v - vc).abs() < 1e-9);
        // The command has ended, the axis has not yet.
        let ce = p.command_end_time();
        assert!(p.end_time() > ce && p.is_done(p.end_time()) && !p.is_done(ce));
        // Braking at 5 mm/s² it trailed by τ²·dec when the command
        // stopped; one τ later by e⁻¹ of that.
        let (x, _) = p.state_at(ce + s(tau));
        let left = tau * tau * 5.0 * (-1.0f64).exp();
        assert!((2.0 - x - left).abs() < 1e-3 * left, "{x}");
        assert_eq!(p.state_at(p.end_time()), (2.0, 0.0));
        // A re-plan from the command state carrying the error is continuous.
        let t = s(2.0);
        let (c, vc) = p.command_at(t);
        let q = Profile::plan(t, c, vc, 1.0, L).with_lag(tau, p.following_error_at(t));
        assert!((q.state_at(t).0 - p.state_at(t).0).abs() < 1e-12);
        assert!((q.state_at(t).1 - p.state_at(t).1).abs() < 1e-9);
        // Without lag the actual is the command.
        let r = Profile::plan(s(1.0), 0.0, 0.0, 2.0, L);
        assert_eq!(r.state_at(s(2.0)), r.command_at(s(2.0)));
        assert_eq!(r.end_time(), r.command_end_time());
    }

    proptest! {
        /// With a lag the axis stays continuous, never overshoots the
        /// command's span by more than the lag allows, and its velocity is
        /// the position's derivative.
        #[test]
        fn lagged_profiles_are_continuous_and_end_on_target(
            p0 in -5.0f64..5.0, target in -5.0f64..5.0, vel in 0.01f64..2.0,
            acc in 0.5f64..50.0, tau in 0.0001f64..0.02, e0 in -0.01f64..0.01,
        ) {
            let lim = Limits { velocity: vel, acceleration: acc, deceleration: acc };
            let p = Profile::plan(s(1.0), p0, 0.0, target, lim).with_lag(tau, e0);
            prop_assert_eq!(p.state_at(p.end_time()), (target, 0.0));
            let total = (p.end_time() - s(1.0)).as_secs_f64();
            let n = 400;
            let dt = total / f64::from(n);
            let mut prev = p.state_at(s(1.0));
            for i in 1..=n {
                let (x, v) = p.state_at(s(1.0 + dt * f64::from(i)));
                // |v_actual| ≤ vmax + |e0|/τ-ish: bounded steps.
                prop_assert!((x - prev.0).abs() <= (vel + e0.abs() / tau) * dt + 1e-6);
                prop_assert!(v.is_finite());
                prev = (x, v);
            }
            // The snap at the end is below a nanometre.
            let before = p.state_at(p.end_time() - s(1e-6)).0;
            prop_assert!((before - target).abs() < 1e-6, "{} vs {}", before, target);
        }

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

        /// The driver's earliest on-target instant (`micropos::driver::
        /// profile`, from VEL?, ACC?, DEC? and the distance from rest) is
        /// never after this simulator's command end, over its whole range
        /// of limits, both directions, short triangles and long cruises:
        /// the polls the driver skips cannot see the axis on target.
        #[test]
        fn the_drivers_earliest_on_target_is_never_late(
            p0 in -20.0f64..20.0, target in -20.0f64..20.0, vel in 0.001f64..20.0,
            acc in 0.1f64..500.0, dec in 0.1f64..500.0,
        ) {
            let lim = Limits { velocity: vel, acceleration: acc, deceleration: dec };
            let p = Profile::plan(s(3.0), p0, 0.0, target, lim);
            let driver = micropos::driver::profile::MotionLimits {
                velocity_mm_s: vel,
                acceleration_mm_s2: acc,
                deceleration_mm_s2: dec,
            };
            let t = driver.min_move_s(target - p0).unwrap();
            let lead = micropos::driver::profile::lead_s(t);
            let command = (p.command_end_time() - s(3.0)).as_secs_f64();
            prop_assert!(lead <= command, "lead {} s after the command end {} s", lead, command);
            // And it is close: the skip is worth it.
            prop_assert!(t <= command * (1.0 + 1e-9) + 1e-9, "{} vs {}", t, command);
            prop_assert!(t >= command * (1.0 - 1e-6) - 1e-9, "{} vs {}", t, command);
        }
    }
}
