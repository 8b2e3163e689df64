//! Maps a camera's own frame clock onto the rig clock: the one job of this
//! file. Sans-IO: it takes (camera stamp, arrival time) pairs and returns
//! rig times; the vision pipeline feeds it.
//!
//! Why: a GigE Vision or V4L2 camera stamps each frame on its own clock
//! (the camera's tick counter, or the kernel's at start of frame), which
//! is free of the host's scheduling jitter but has its own origin and its
//! own rate (a camera's crystal is off by tens of ppm: 30 ppm is 54 ms over
//! a 30-minute sweep, 270 times the 0.2 ms a sweep's delay estimate must
//! resolve). The host's arrival time is on the rig clock but carries the
//! transfer and scheduling delay, which varies frame to frame by
//! milliseconds and is never negative. So the rig time of a stamp is read
//! from the pairs as a line `arrival = offset + rate · stamp + delay`:
//! - the rate by least squares through the earliest arrival of each
//!   [`RATE_BLOCK_S`] block of stamps since the anchor: a block's earliest
//!   arrival carries a fraction of the jitter (the least-delayed of its
//!   frames) and no hiccup, and the rate is stable over hours, so a long
//!   span pins it;
//! - the offset from the *lower envelope*: the smallest `arrival − rate ·
//!   stamp` over the recent pairs, i.e. the frames that arrived with the
//!   least delay. Delays only ever add, so the envelope is immune to
//!   hiccups and the remaining constant (the camera's shortest
//!   stamp-to-arrival time) is a fixed delay that the sweep
//!   characterization estimates with the rest of the camera's latency.
//!
//! A stamp that goes backwards or disagrees with the line by more than
//! [`RESET_S`] (camera restarted, clock reset) re-anchors the map.
//!
//! Sign convention: the returned time is on the rig clock, in seconds, and
//! is never later than the frame's arrival.

use std::collections::VecDeque;

/// A disagreement with the current line beyond which the map starts over, s.
pub const RESET_S: f64 = 1.0;
/// The block of stamps whose earliest arrival is one point of the rate
/// fit, s.
pub const RATE_BLOCK_S: f64 = 2.0;
/// The span of stamps below which the rate is taken as exactly 1, s: over
/// a short span the arrival jitter would set it, not the clocks.
pub const MIN_RATE_SPAN_S: f64 = 5.0;
/// The largest rate error believed, relative (1000 ppm: any crystal
/// oscillator is within 100 ppm; more means the pairs are not one clock).
pub const MAX_RATE_ERROR: f64 = 1e-3;
/// The span of recent stamps over which the lower envelope is taken, s:
/// short enough that a rate error of a few ppm moves the line by
/// microseconds across it, long enough to hold hundreds of frames.
pub const ENVELOPE_SPAN_S: f64 = 10.0;
/// The most pairs the envelope holds (bounded memory at any frame rate).
pub const ENVELOPE_PAIRS: usize = 1024;

/// The map from a camera's clock to the rig clock (module docs).
#[derive(Debug, Clone, Default)]
pub struct CameraTimebase {
    /// (stamp, arrival) of the anchor pair: sums are kept relative to it
    /// so that large clock values keep their precision.
    origin: Option<(f64, f64)>,
    last_stamp_s: f64,
    /// The open block: (x at its start, x and y of its earliest arrival).
    block: Option<(f64, f64, f64)>,
    /// Least-squares sums over the closed blocks' earliest arrivals.
    n: f64,
    sx: f64,
    sy: f64,
    sxx: f64,
    sxy: f64,
    x_max: f64,
    recent: VecDeque<(f64, f64)>,
    resets: u64,
}

impl CameraTimebase {
    /// An empty map (the first pair anchors it).
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds the pair (`stamp_s` on the camera's clock, `arrival_s` on the
    /// rig clock) and returns the rig time of `stamp_s`. `None` when either
    /// is not finite (the caller falls back to its own time).
    pub fn observe(&mut self, stamp_s: f64, arrival_s: f64) -> Option<f64> {
        if !stamp_s.is_finite() || !arrival_s.is_finite() {
            return None;
        }
        let fresh = match self.origin {
            None => true,
            Some(_) if stamp_s <= self.last_stamp_s => true,
            Some(_) => (arrival_s - self.rig_time_unchecked(stamp_s)).abs() > RESET_S,
        };
        if fresh {
            if self.origin.is_some() {
                self.resets += 1;
            }
            *self = Self {
                resets: self.resets,
                ..Self::default()
            };
            self.origin = Some((stamp_s, arrival_s));
        }
        self.last_stamp_s = stamp_s;
        let (s0, a0) = self.origin.unwrap_or((stamp_s, arrival_s));
        let x = stamp_s - s0;
        let y = arrival_s - a0;
        self.block = match self.block {
            Some((start, bx, by)) if x - start < RATE_BLOCK_S => Some(if y - x < by - bx {
                (start, x, y)
            } else {
                (start, bx, by)
            }),
            closed => {
                if let Some((_, bx, by)) = closed {
                    self.n += 1.0;
                    self.sx += bx;
                    self.sy += by;
                    self.sxx += bx * bx;
                    self.sxy += bx * by;
                    self.x_max = self.x_max.max(bx);
                }
                Some((x, x, y))
            }
        };
        while self.recent.len() >= ENVELOPE_PAIRS
            || self
                .recent
                .front()
                .is_some_and(|&(x0, _)| x - x0 > ENVELOPE_SPAN_S)
        {
            self.recent.pop_front();
        }
        self.recent.push_back((x, y));
        Some(self.rig_time_unchecked(stamp_s).min(arrival_s))
    }

    /// The rig time of `stamp_s` by the current map, without adding a
    /// pair. `None` before the first pair.
    pub fn rig_time(&self, stamp_s: f64) -> Option<f64> {
        self.origin.map(|_| self.rig_time_unchecked(stamp_s))
    }

    /// The current rate of the rig clock per camera second (1 + error).
    pub fn rate(&self) -> f64 {
        if self.n < 3.0 || self.x_max < MIN_RATE_SPAN_S {
            return 1.0;
        }
        let var = self.sxx - self.sx * self.sx / self.n;
        if var <= 0.0 {
            return 1.0;
        }
        let b = (self.sxy - self.sx * self.sy / self.n) / var;
        if b.is_finite() && (b - 1.0).abs() <= MAX_RATE_ERROR {
            b
        } else {
            1.0
        }
    }

    /// How often the map started over (camera clock went backwards or
    /// jumped): a camera restart shows here.
    pub fn resets(&self) -> u64 {
        self.resets
    }

    /// `y` (arrival relative to the anchor) of the lower envelope at `x`.
    fn line_y(&self, x: f64) -> f64 {
        let b = self.rate();
        let a = self
            .recent
            .iter()
            .map(|&(xi, yi)| yi - b * xi)
            .fold(f64::INFINITY, f64::min);
        if a.is_finite() {
            a + b * x
        } else {
            x
        }
    }

    fn rig_time_unchecked(&self, stamp_s: f64) -> f64 {
        let (s0, a0) = self.origin.unwrap_or((stamp_s, 0.0));
        a0 + self.line_y(stamp_s - s0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// A camera whose clock reads `(t + offset) · (1 + ppm·1e-6)` at rig
    /// time `t`, exposing at `fps`; each frame arrives `min_delay` plus an
    /// exponential delay of mean `mean_jitter` after its stamp, and one
    /// frame in `1/p_hiccup` another 10–100 ms later. Returns per frame
    /// (stamp on the camera clock, arrival, true rig time of the stamp).
    #[allow(clippy::too_many_arguments)]
    fn camera(
        seed: u64,
        offset_s: f64,
        ppm: f64,
        fps: f64,
        min_delay_s: f64,
        mean_jitter_s: f64,
        p_hiccup: f64,
        duration_s: f64,
    ) -> Vec<(f64, f64, f64)> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let n = (duration_s * fps) as usize;
        (0..n)
            .map(|k| {
                let t = 10.0 + k as f64 / fps;
                let stamp = (t + offset_s) * (1.0 + ppm * 1e-6);
                let u: f64 = rng.gen_range(1e-12..1.0);
                let mut delay = min_delay_s - mean_jitter_s * u.ln();
                if rng.gen_bool(p_hiccup) {
                    delay += rng.gen_range(0.01..0.1);
                }
                (stamp, t + delay, t)
            })
            .collect()
    }

    /// Spread (max − min) of the mapped time's error against the true rig
    /// time of each stamp, over the frames after `warm_s`.
    fn spread(frames: &[(f64, f64, f64)], warm_s: f64) -> (f64, f64) {
        let mut tb = CameraTimebase::new();
        let t0 = frames.first().map_or(0.0, |f| f.2);
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for &(stamp, arrival, t) in frames {
            let Some(m) = tb.observe(stamp, arrival) else {
                continue;
            };
            assert!(m <= arrival, "mapped {m} after arrival {arrival}");
            if t - t0 >= warm_s {
                lo = lo.min(m - t);
                hi = hi.max(m - t);
            }
        }
        (lo, hi)
    }

    #[test]
    fn a_fast_clock_with_jittery_arrivals_maps_to_a_constant_delay() {
        // 50 ppm fast, powered up a day ago, 1 ms mean jitter, 1 % hiccups.
        let frames = camera(7, 86_400.0, 50.0, 30.0, 0.004, 0.001, 0.01, 1800.0);
        let (lo, hi) = spread(&frames, 60.0);
        assert!(hi - lo < 50e-6, "mapped error spread {} s", hi - lo);
        // What is left is the shortest stamp-to-arrival delay.
        assert!((lo - 0.004).abs() < 50e-6, "constant part {lo} s");
        // Arrival times alone spread by the jitter and the hiccups.
        let (alo, ahi) = frames
            .iter()
            .skip(1800)
            .map(|f| f.1 - f.2)
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), d| {
                (l.min(d), h.max(d))
            });
        assert!(ahi - alo > 0.01, "arrival spread {} s", ahi - alo);
        // A map without the rate (the camera's seconds taken as rig
        // seconds) drifts by 50 ppm × 30 min = 90 ms.
        let (s0, a0, _) = frames[0];
        let last = frames[frames.len() - 1];
        let no_rate = a0 + (last.0 - s0) - last.2;
        assert!(no_rate - (a0 - frames[0].2) > 0.08);
    }

    #[test]
    fn a_camera_restart_re_anchors() {
        let mut frames = camera(3, 500.0, -20.0, 25.0, 0.002, 0.0005, 0.0, 120.0);
        let restart = camera(4, 0.0, -20.0, 25.0, 0.002, 0.0005, 0.0, 120.0);
        frames.extend(
            restart
                .into_iter()
                .map(|(s, a, t)| (s, a + 130.0, t + 130.0)),
        );
        let mut tb = CameraTimebase::new();
        let mut last_err = f64::NAN;
        for &(s, a, t) in &frames {
            last_err = tb.observe(s, a).map_or(f64::NAN, |m| m - t);
        }
        assert_eq!(tb.resets(), 1);
        assert!(
            (last_err - 0.002).abs() < 1e-4,
            "error after restart {last_err}"
        );
    }

    #[test]
    fn bad_pairs_give_none_and_change_nothing() {
        let mut tb = CameraTimebase::new();
        assert_eq!(tb.observe(f64::NAN, 1.0), None);
        assert_eq!(tb.observe(1.0, f64::INFINITY), None);
        assert_eq!(tb.rig_time(1.0), None);
        assert_eq!(tb.observe(100.0, 5.0), Some(5.0));
        assert_eq!(tb.resets(), 0);
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(24))]
        /// Any clock origin and rate error a camera has, any arrival
        /// jitter: after a minute the mapped stamps carry a constant delay,
        /// never after arrival. Two things move it, both bounded from the
        /// drawn camera:
        /// - the envelope is the least of `n` delays (exponential of mean
        ///   `mean_jitter / n` for exponential jitter), so over a run it
        ///   wanders by a few `mean_jitter / n`;
        /// - the rate is a least-squares slope through one block minimum
        ///   per [`RATE_BLOCK_S`] (σ `mean_jitter / m` for `m` frames a
        ///   block), so after `warm` seconds its σ is
        ///   `σ_block · √(12 / blocks) / warm`, and a rate error `δ` tilts
        ///   the envelope line by up to `δ · ENVELOPE_SPAN_S` between its
        ///   oldest pair and now.
        ///
        /// The bound is ten of the first plus five σ of the second plus
        /// 20 µs; the constant part stays above the shortest delay by the
        /// same rate term.
        #[test]
        fn any_camera_clock_maps_to_a_constant_delay(
            seed in any::<u64>(),
            offset_s in -1e5f64..1e6,
            ppm in -200.0f64..200.0,
            fps in 10.0f64..200.0,
            min_delay_s in 0.0f64..0.03,
            mean_jitter_s in 1e-5f64..0.005,
            p_hiccup in 0.0f64..0.05,
        ) {
            let warm_s = 60.0;
            let frames = camera(seed, offset_s, ppm, fps, min_delay_s, mean_jitter_s, p_hiccup, 300.0);
            let (lo, hi) = spread(&frames, warm_s);
            let n = (fps * ENVELOPE_SPAN_S).min(ENVELOPE_PAIRS as f64);
            let sigma_block = mean_jitter_s / (fps * RATE_BLOCK_S);
            let sigma_rate = sigma_block * (12.0 / (warm_s / RATE_BLOCK_S)).sqrt() / warm_s;
            let rate_term = 5.0 * sigma_rate * ENVELOPE_SPAN_S;
            prop_assert!(hi - lo <= 10.0 * mean_jitter_s / n + 2.0 * rate_term + 20e-6,
                "spread {} s for mean jitter {} s", hi - lo, mean_jitter_s);
            prop_assert!(lo >= min_delay_s - rate_term - 20e-6,
                "constant part {} below the shortest delay {} by more than the rate term {}",
                lo, min_delay_s, rate_term);
        }
    }
}
