//! The earliest a point-to-point move can be on target, from the limits
//! the controller itself reports.
//!
//! Why: while it waits for a move, the driver polls `ONT?` every
//! `poll_interval`. A poll before the move's trajectory can have ended
//! cannot answer 1: it only loads the line. On the simulator's virtual clock
//! a 1 ms poll during an 80 s sweep pass is 80 000 exchanges, and on a real
//! RS-232 line each one takes line time from the other axis. Knowing the
//! shortest time a trapezoidal profile over the distance can take,
//! [`Axis::wait_on_target`](super::Axis::wait_on_target) polls sparsely until
//! then, on its own poll grid, so the first poll that can see the axis on
//! target is the one it would be without the skip.
//!
//! Sans-IO: numbers in, numbers out. Units: mm, mm/s, mm/s², s (the
//! controller's own).

/// The controller's motion limits (`VEL?`, `ACC?`, `DEC?`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MotionLimits {
    /// Cruise velocity, mm/s.
    pub velocity_mm_s: f64,
    /// Acceleration, mm/s².
    pub acceleration_mm_s2: f64,
    /// Deceleration, mm/s².
    pub deceleration_mm_s2: f64,
}

impl MotionLimits {
    /// The duration of the rest-to-rest trapezoid (or triangle, when the
    /// cruise velocity is not reached) over `distance_mm`, s: no move over
    /// that distance within these limits ends sooner. `None` when a limit
    /// is not a positive finite number or the distance is not finite.
    pub fn min_move_s(&self, distance_mm: f64) -> Option<f64> {
        let (v, a, d) = (
            self.velocity_mm_s,
            self.acceleration_mm_s2,
            self.deceleration_mm_s2,
        );
        let ok = |x: f64| x.is_finite() && x > 0.0;
        if !(ok(v) && ok(a) && ok(d) && distance_mm.is_finite()) {
            return None;
        }
        let s = distance_mm.abs();
        // Distance to reach v and to stop from it.
        let ramps = v * v / (2.0 * a) + v * v / (2.0 * d);
        let t = if s >= ramps {
            s / v + v / (2.0 * a) + v / (2.0 * d)
        } else {
            // Triangle: the peak velocity vp covers s = vp²/2a + vp²/2d.
            let vp = (2.0 * s * a * d / (a + d)).sqrt();
            vp / a + vp / d
        };
        t.is_finite().then_some(t)
    }
}

/// How far ahead of [`MotionLimits::min_move_s`] the wait starts polling
/// densely: 5 % of the profile plus 1 ms, for the controller's own rounding
/// (counts, servo cycles) and a send that took the command late in its
/// window. A poll early costs one exchange; a poll late would see the axis
/// on target later than it is.
pub fn lead_s(min_move_s: f64) -> f64 {
    (0.95 * min_move_s - 0.001).max(0.0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn lim(v: f64, a: f64, d: f64) -> MotionLimits {
        MotionLimits {
            velocity_mm_s: v,
            acceleration_mm_s2: a,
            deceleration_mm_s2: d,
        }
    }

    #[test]
    fn trapezoid_and_triangle_by_hand() {
        // 1 mm/s, 10 mm/s²: ramps 0.05 mm each way; 1 mm: 1 + 0.05 + 0.05 s.
        let l = lim(1.0, 10.0, 10.0);
        assert!((l.min_move_s(1.0).unwrap() - 1.1).abs() < 1e-12);
        // 5 µm: a triangle, 2·sqrt(s/a) = 2·sqrt(0.0005) s.
        let t = l.min_move_s(0.005).unwrap();
        assert!((t - 2.0 * 0.0005f64.sqrt()).abs() < 1e-12, "{t}");
        assert_eq!(l.min_move_s(0.0), Some(0.0));
        assert_eq!(l.min_move_s(-1.0), l.min_move_s(1.0));
        for bad in [
            lim(0.0, 1.0, 1.0),
            lim(1.0, -1.0, 1.0),
            lim(1.0, 1.0, f64::NAN),
        ] {
            assert_eq!(bad.min_move_s(1.0), None);
        }
        assert_eq!(l.min_move_s(f64::INFINITY), None);
        assert_eq!(lead_s(0.0), 0.0);
        assert!((lead_s(1.0) - 0.949).abs() < 1e-12);
    }

    proptest! {
        /// The closed form against the motion it describes, integrated in
        /// small steps: at each step as fast as the acceleration, the
        /// cruise velocity and the braking curve to the end allow (the
        /// fastest admissible motion). It arrives no sooner than the
        /// closed form (up to the integration's own error), and not much
        /// later.
        #[test]
        fn no_integrated_move_is_shorter(
            v in 0.01f64..20.0, a in 0.5f64..500.0, d in 0.5f64..500.0,
            s in 0.0f64..30.0,
        ) {
            let l = lim(v, a, d);
            let t = l.min_move_s(s).unwrap();
            let dt = (t / 20_000.0).max(1e-7);
            let (mut x, mut u, mut time) = (0.0f64, 0.0f64, 0.0f64);
            while s - x > 1e-9 && time < 10.0 * t + 1.0 {
                let brake = (2.0 * d * (s - x)).sqrt();
                let u1 = (u + a * dt).min(v).min(brake);
                x += 0.5 * (u + u1) * dt;
                u = u1;
                time += dt;
            }
            // Forward steps run a little ahead of the braking curve: 0.1 %
            // (20 steps) covers the discretisation.
            prop_assert!(time >= t * 0.999 - 2.0 * dt - 1e-9, "integrated {time} s < closed form {t} s");
            prop_assert!(time <= t * 1.01 + 0.001, "integrated {time} s ≫ closed form {t} s");
        }
    }
}
