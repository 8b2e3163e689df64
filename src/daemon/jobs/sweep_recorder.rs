//! Sweep positions from the controller's data recorder, where it has one
//! (`TNR?` answers and `DRC` is accepted): record table 1 samples the swept
//! axis's actual position every [`RECORD_RATE`] servo cycles (1 ms on a
//! C-863, whose servo cycle is 50 µs); the job reads the table every
//! [`CHUNK_S`] of rig time (`DRL?`, `DRR?`) and triggers it again (`DRT`),
//! so a table of 1024 points never fills. `POS?` keeps being polled, more
//! sparsely ([`POLL_WITH_RECORDER`]): it tells when the axis has arrived,
//! covers the short gaps between chunks and ties each chunk's time base to
//! the rig clock.
//!
//! Why the tie: a record's time is `t₀ + i·SAMPLE_TIME` on the controller's
//! servo clock, and `t₀`, the instant the controller read `DRT`, is known
//! on the rig clock only to within the exchange that carried it (on a
//! serial line, milliseconds). [`align_chunk`] fits `t₀` to the `POS?`
//! samples taken during the chunk (least squares on the position, the
//! velocity as the slope), which averages their timing over a few dozen
//! samples; at rest a chunk carries no timing information and keeps the
//! exchange's midpoint, where a time error moves nothing.

use crate::charact::sweep::PosSample;
use std::time::Duration;

/// Servo cycles per record (`RTR`): 1 ms on a C-863 (50 µs cycle).
pub const RECORD_RATE: u32 = 20;

/// The record table the sweep uses.
pub const RECORD_TABLE: u32 = 1;

/// Rig time between two readouts of the table, s: 500 records at 1 ms,
/// half a C-863's table.
pub const CHUNK_S: f64 = 0.5;

/// `POS?` period while the recorder records.
pub const POLL_WITH_RECORDER: Duration = Duration::from_millis(20);

/// One readout of the table.
#[derive(Debug, Clone, PartialEq)]
pub struct Chunk {
    /// Rig time of the trigger's exchange: `(sent, acknowledged)`, s.
    pub trigger_s: (f64, f64),
    /// Time between records, s.
    pub sample_time_s: f64,
    /// Positions of the swept axis, µm.
    pub positions_um: Vec<f64>,
}

/// The chunk's trigger time on the rig clock fitted to the `POS?` samples
/// inside it (see the module docs); the exchange's midpoint when no sample
/// there sees motion.
pub fn align_chunk(chunk: &Chunk, polls: &[PosSample]) -> f64 {
    let guess = 0.5 * (chunk.trigger_s.0 + chunk.trigger_s.1);
    let n = chunk.positions_um.len();
    let dt = chunk.sample_time_s;
    if n < 2 || !(dt > 0.0 && dt.is_finite()) || !guess.is_finite() {
        return guess;
    }
    let span = dt * (n - 1) as f64;
    // Position and slope of the record at chunk time `tau`.
    let at = |tau: f64| -> Option<(f64, f64)> {
        let x = tau / dt;
        if !(x >= 0.0 && x <= (n - 1) as f64) {
            return None;
        }
        let i = (x.floor() as usize).min(n - 2);
        let (a, b) = (chunk.positions_um[i], chunk.positions_um[i + 1]);
        let v = (b - a) / dt;
        Some((a + v * (tau - i as f64 * dt), v))
    };
    let mut t0 = guess;
    for _ in 0..10 {
        let (mut num, mut den) = (0.0, 0.0);
        for p in polls {
            let tau = p.t_s - t0;
            if !(0.0..=span).contains(&tau) {
                continue;
            }
            let Some((pos, v)) = at(tau) else { continue };
            if v.abs() < 1.0 {
                continue;
            }
            num += (p.pos_um - pos) * v;
            den += v * v;
        }
        if den <= 0.0 {
            return t0;
        }
        let step = -num / den;
        if !step.is_finite() {
            return t0;
        }
        t0 += step;
        if step.abs() < 1e-8 {
            break;
        }
    }
    t0
}

/// The pass's position samples: every chunk's records at their aligned
/// times, and the `POS?` samples that fall outside every chunk (before the
/// first trigger, in the gaps between readouts, after the last), in time
/// order.
pub fn merge(chunks: &[Chunk], polls: &[PosSample]) -> Vec<PosSample> {
    let mut spans = Vec::with_capacity(chunks.len());
    let mut out: Vec<PosSample> = Vec::new();
    for c in chunks {
        if c.positions_um.is_empty() {
            continue;
        }
        let t0 = align_chunk(c, polls);
        let end = t0 + c.sample_time_s * (c.positions_um.len() - 1) as f64;
        spans.push((t0, end));
        out.extend(c.positions_um.iter().enumerate().map(|(i, &p)| PosSample {
            t_s: t0 + c.sample_time_s * i as f64,
            pos_um: p,
        }));
    }
    out.extend(
        polls
            .iter()
            .filter(|p| !spans.iter().any(|(a, b)| p.t_s >= *a && p.t_s <= *b))
            .copied(),
    );
    out.sort_by(|a, b| a.t_s.total_cmp(&b.t_s));
    out.dedup_by(|b, a| b.t_s <= a.t_s);
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A pass at 150 µm/s from 0 to 3 s (at rest before 0.2 s); the
    /// recorder triggered at `t0` with an exchange of ±2 ms around it;
    /// `POS?` every 20 ms, each stamped at its exchange's midpoint with an
    /// error of up to ±1 ms.
    #[test]
    fn the_chunk_is_tied_to_the_rig_clock_by_the_polls() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let pos = |t: f64| 100.0 + 150.0 * (t - 0.2).max(0.0);
        for _ in 0..20 {
            let t0 = rng.gen_range(0.0..1.5);
            let dt = 0.001;
            let chunk = Chunk {
                trigger_s: (
                    t0 - rng.gen_range(0.0..0.002),
                    t0 + rng.gen_range(0.0..0.002),
                ),
                sample_time_s: dt,
                positions_um: (0..500).map(|i| pos(t0 + dt * f64::from(i))).collect(),
            };
            let polls: Vec<PosSample> = (0..150)
                .map(|k| {
                    let t = 0.02 * f64::from(k);
                    PosSample {
                        t_s: t + rng.gen_range(-0.001..0.001),
                        pos_um: pos(t),
                    }
                })
                .collect();
            let fitted = align_chunk(&chunk, &polls);
            assert!((fitted - t0).abs() < 5e-4, "{fitted} vs {t0}");
            let merged = merge(std::slice::from_ref(&chunk), &polls);
            assert!(merged.windows(2).all(|w| w[0].t_s < w[1].t_s));
            assert!(merged.len() > 500 && merged.len() < 650);
        }
    }

    #[test]
    fn a_chunk_at_rest_keeps_the_exchange_midpoint() {
        let chunk = Chunk {
            trigger_s: (1.0, 1.004),
            sample_time_s: 0.001,
            positions_um: vec![5.0; 300],
        };
        let polls: Vec<PosSample> = (0..40)
            .map(|k| PosSample {
                t_s: 0.9 + 0.02 * f64::from(k),
                pos_um: 5.0,
            })
            .collect();
        assert_eq!(align_chunk(&chunk, &polls), 1.002);
        // Nothing usable at all: still no panic, no NaN.
        let empty = Chunk {
            trigger_s: (f64::NAN, 1.0),
            sample_time_s: 0.0,
            positions_um: vec![],
        };
        assert!(align_chunk(&empty, &[]).is_nan());
        assert!(merge(&[empty], &polls).len() == polls.len());
    }
}
