//! The code-depth check: whether the code lines a frame reads can only
//! come from the configured sequence, or fit another depth better. A file
//! of its own: it is pure combinatorics on the hard readings (no pixels,
//! no lattice), run once per cold decode after the per-dot stage's search.

use super::super::error::DecodeError;
use crate::pattern::sequence::LineSequence;

/// Whether the code lines read confirm the configured code depth.
///
/// Why: the code margin compares offsets *within* the configured
/// sequence; it cannot tell that the frame comes from a pattern of another
/// depth, whose windows never occur in this sequence. The best offset then
/// still wins (by chance), and the position is confidently wrong. The check
/// asks how many offsets of the sequence a random reading of the same length
/// would match with as few disagreements: when that is large, the match
/// proves nothing.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CodeCheck {
    /// The match is beyond chance (`chance` ≤ [`CODE_CHANCE_MAX`]).
    pub confirmed: bool,
    /// Expected number of offset pairs (both axes) of the configured
    /// sequence that random code readings of the same lengths would match
    /// with at most the disagreements found: ≪ 1 means the reading can only
    /// come from this sequence.
    pub chance: f64,
    /// Hard disagreements of the chosen offsets, per lattice axis.
    pub mismatches: [usize; 2],
    /// Hard-read code lines, per lattice axis.
    pub lines: [usize; 2],
}

/// Largest expected number of chance matches for which a code reading
/// confirms the configured depth.
pub const CODE_CHANCE_MAX: f64 = 1e-3;

/// Hard reading of a soft code-line value: +1 present, −1 absent, 0 unread
/// (the same |t| > 0.2 as the readable-line count).
pub(super) fn hard(t: f32) -> i8 {
    if t > 0.2 {
        1
    } else if t < -0.2 {
        -1
    } else {
        0
    }
}

/// The code-line values (±1) of every code slot of `seq`.
pub(super) fn slot_values(seq: &LineSequence) -> Vec<i8> {
    (0..seq.len() / 3)
        .map(|q| if seq.line(3 * q as i64 + 1) { 1 } else { -1 })
        .collect()
}

/// Disagreements of `read` (hard values, slot order) placed with its first
/// line at slot `q0`; a read line outside the sequence disagrees.
fn mismatches_at(read: &[i8], slots: &[i8], q0: i64) -> usize {
    read.iter()
        .enumerate()
        .filter(|(t, &r)| {
            r != 0
                && usize::try_from(q0 + *t as i64)
                    .ok()
                    .and_then(|q| slots.get(q))
                    .is_none_or(|&c| c != r)
        })
        .count()
}

/// Fewest disagreements of `read` over every offset overlapping `slots`.
fn best_mismatches(read: &[i8], slots: &[i8]) -> usize {
    let kk = read.len() as i64;
    (1 - kk..slots.len() as i64)
        .map(|q0| mismatches_at(read, slots, q0))
        .min()
        .unwrap_or(read.len())
}

/// ln of the expected number of `offsets` at which `n` random code bits
/// disagree with a sequence on at most `e`: offsets · P(Binomial(n, ½) ≤ e),
/// in logs so that long readings do not underflow.
fn ln_chance(n: usize, e: usize, offsets: usize) -> f64 {
    // Running log-sum-exp over the terms ln C(n, k) − n ln 2 (no buffer: a
    // warm decode allocates nothing).
    let mut sum = f64::NEG_INFINITY;
    let mut t = -(n as f64) * std::f64::consts::LN_2;
    for k in 0..=e.min(n) {
        let (hi, lo) = if t > sum { (t, sum) } else { (sum, t) };
        sum = hi + (lo - hi).exp().ln_1p();
        t += ((n - k) as f64 / (k + 1) as f64).ln();
    }
    sum + (offsets.max(1) as f64).ln()
}

/// ln of the joint chance (both axes) of readings `read` against `slots`
/// with `mism` disagreements per axis.
fn ln_joint(read: [&[i8]; 2], mism: [usize; 2], slots: usize) -> f64 {
    (0..2)
        .map(|a| {
            let n = read[a].iter().filter(|&&r| r != 0).count();
            ln_chance(n, mism[a], slots + read[a].len().saturating_sub(1))
        })
        .sum()
}

/// The code-depth check of two axes' readings (`read`, hard values in slot
/// order) placed at slots `q0` of `seq` (see [`CodeCheck`]). When the
/// reading does not confirm `seq`'s depth but confirms another supported
/// depth, that is an error naming the depth that fits: the frame comes from
/// another pattern, and the position is wrong.
pub(crate) fn check_code(
    read: [&[i8]; 2],
    q0: [i64; 2],
    seq: &LineSequence,
    slots: &[i8],
) -> Result<CodeCheck, DecodeError> {
    let mism = [0, 1].map(|a| mismatches_at(read[a], slots, q0[a]));
    let lines = [0, 1].map(|a| read[a].iter().filter(|&&r| r != 0).count());
    let ln_given = ln_joint(read, mism, slots.len());
    let check = CodeCheck {
        confirmed: ln_given <= CODE_CHANCE_MAX.ln(),
        chance: ln_given.exp(),
        mismatches: mism,
        lines,
    };
    if check.confirmed {
        return Ok(check);
    }
    match better_depth(read, seq, ln_given, mism, lines) {
        Some(e) => Err(e),
        None => Ok(check),
    }
}

/// The supported depth other than `seq`'s whose sequence the readings fit
/// beyond chance and better than `ln_given` (ln of the configured depth's
/// joint chance), as the error that names it; `None` when no other depth
/// does. `mism` and `lines` describe the configured depth's fit.
fn better_depth(
    read: [&[i8]; 2],
    seq: &LineSequence,
    ln_given: f64,
    mism: [usize; 2],
    lines: [usize; 2],
) -> Option<DecodeError> {
    use crate::pattern::sequence::{MAX_BITS, MIN_BITS};
    let mut best: Option<(f64, u32, [usize; 2])> = None;
    for bits in MIN_BITS..=MAX_BITS {
        if bits == seq.bits() {
            continue;
        }
        let Ok(other) = LineSequence::new(bits) else {
            continue;
        };
        let s = slot_values(&other);
        let m = [0, 1].map(|a| best_mismatches(read[a], &s));
        let ln = ln_joint(read, m, s.len());
        if best.is_none_or(|(b, ..)| ln < b) {
            best = Some((ln, bits, m));
        }
    }
    match best {
        Some((ln, bits, m)) if ln <= CODE_CHANCE_MAX.ln() && ln < ln_given => {
            Some(DecodeError::CodeDepthMismatch {
                bits: seq.bits(),
                fits_bits: bits,
                lines,
                mismatches: mism,
                fits_mismatches: m,
            })
        }
        _ => None,
    }
}

/// When the code margin fails (`ambiguous`), whether the readings fit
/// another depth: then the configured depth is wrong, and the error says
/// which one fits instead of only "ambiguous". Both axes' readings must be
/// in `read` (an axis not read is empty).
pub(crate) fn ambiguous_or_other_depth(
    ambiguous: DecodeError,
    read: [&[i8]; 2],
    seq: &LineSequence,
) -> DecodeError {
    let slots = slot_values(seq);
    let mism = [0, 1].map(|a| best_mismatches(read[a], &slots));
    let lines = [0, 1].map(|a| read[a].iter().filter(|&&r| r != 0).count());
    let ln_given = ln_joint(read, mism, slots.len());
    better_depth(read, seq, ln_given, mism, lines).unwrap_or(ambiguous)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn window(bits: u32, q0: usize, len: usize) -> Vec<i8> {
        let s = slot_values(&LineSequence::new(bits).unwrap());
        s[q0..q0 + len].to_vec()
    }

    #[test]
    fn chance_is_offsets_times_binomial_tail() {
        let ln = ln_chance(20, 0, 4095);
        assert!((ln - (4095.0f64 / f64::from(1u32 << 20)).ln()).abs() < 1e-9);
        // P(Bin(4, ½) ≤ 1) = 5/16.
        assert!((ln_chance(4, 1, 16).exp() - 5.0).abs() < 1e-9);
        // Long readings do not underflow to "certain".
        assert!(ln_chance(3000, 1400, 4095).is_finite());
        assert!(ln_chance(3000, 1400, 4095) > ln_chance(3000, 10, 4095));
    }

    #[test]
    fn a_window_of_the_sequence_is_confirmed() {
        let seq = LineSequence::new(12).unwrap();
        let (a, b) = (window(12, 500, 20), window(12, 3000, 23));
        let c = check_code([&a, &b], [500, 3000], &seq, &slot_values(&seq)).unwrap();
        assert!(c.confirmed, "{c:?}");
        assert_eq!(c.mismatches, [0, 0]);
        assert_eq!(c.lines, [20, 23]);
    }

    #[test]
    fn a_window_of_another_depth_names_it() {
        let seq = LineSequence::new(12).unwrap();
        let (a, b) = (window(10, 100, 25), window(10, 700, 25));
        // Wherever the decoder placed them in the 12-bit sequence.
        let q0 = [0, 1].map(|i| {
            let s = slot_values(&seq);
            let r = if i == 0 { &a } else { &b };
            (1 - r.len() as i64..s.len() as i64)
                .min_by_key(|&q| mismatches_at(r, &s, q))
                .unwrap()
        });
        match check_code([&a, &b], q0, &seq, &slot_values(&seq)) {
            Err(DecodeError::CodeDepthMismatch {
                bits, fits_bits, ..
            }) => assert_eq!((bits, fits_bits), (12, 10)),
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn a_short_reading_is_unconfirmed_not_an_error() {
        let seq = LineSequence::new(12).unwrap();
        let (a, b) = (window(12, 40, 13), window(12, 900, 13));
        let c = check_code([&a, &b], [40, 900], &seq, &slot_values(&seq)).unwrap();
        assert!(!c.confirmed, "{c:?}");
        assert!(c.chance > CODE_CHANCE_MAX);
    }
}
