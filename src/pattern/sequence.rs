//! The Megarena code: a maximal-length LFSR sequence spread over the rows and
//! columns of a dot grid.
//!
//! Why a separate module: the renderer, the exporter and the decoder must agree
//! bit for bit on which dots exist, so the one definition lives here.

use thiserror::Error;

/// Smallest supported code depth.
pub const MIN_BITS: u32 = 4;
/// Largest supported code depth.
pub const MAX_BITS: u32 = 12;

/// Why a code depth cannot be used.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum SequenceError {
    /// Only depths with a published tap set are supported.
    #[error("code depth {0} is outside the supported range {MIN_BITS}..={MAX_BITS}")]
    UnsupportedBits(u32),
}

/// Feedback taps of the Fibonacci LFSR for each code depth (bit indices of the
/// state, bit 0 being the lowest).
fn taps(bits: u32) -> Result<&'static [u32], SequenceError> {
    Ok(match bits {
        4 => &[0, 3],
        5 => &[1, 4],
        6 => &[0, 5],
        7 => &[2, 6],
        8 => &[0, 1, 6, 7],
        9 => &[3, 8],
        10 => &[6, 9],
        11 => &[1, 10],
        12 => &[0, 1, 7, 11],
        other => return Err(SequenceError::UnsupportedBits(other)),
    })
}

/// The maximal-length code b_0 … b_{2^n−2} of depth `bits`.
///
/// The LFSR starts from the all-ones state; each step outputs the state's
/// lowest bit, then shifts left by one and takes the XOR of the tap bits as its
/// new lowest bit. With this convention b_0 = 1 and every window of `bits`
/// consecutive code bits is unique in the cyclic sequence, which is what makes
/// the position absolute.
pub fn lfsr_code(bits: u32) -> Result<Vec<u8>, SequenceError> {
    let taps = taps(bits)?;
    let len = (1usize << bits) - 1;
    let mask = (1u32 << bits) - 1;
    let mut state = mask;
    let mut out = Vec::with_capacity(len);
    for _ in 0..len {
        out.push((state & 1) as u8);
        let fb = taps.iter().fold(0, |acc, &t| acc ^ ((state >> t) & 1));
        state = ((state << 1) | fb) & mask;
    }
    Ok(out)
}

/// The line sequence shared by rows and columns, with its code.
///
/// s has length L = 3·(2^n − 1 + n − 1); it is all ones except
/// s[3(i + n − 1) + 1] = b_i for i = 0 … 2^n − 3. Every third line (index ≡ 0
/// mod 3) is a full line, which lets the decoder find the code phase; code
/// bits sit at index ≡ 1 mod 3.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LineSequence {
    bits: u32,
    code: Vec<u8>,
    lines: Vec<u8>,
}

impl LineSequence {
    /// Builds the sequence of code depth `bits`.
    pub fn new(bits: u32) -> Result<Self, SequenceError> {
        let code = lfsr_code(bits)?;
        let n = bits as usize;
        let len = 3 * (code.len() + n - 1);
        let mut lines = vec![1u8; len];
        for (i, &b) in code.iter().enumerate().take(code.len() - 1) {
            lines[3 * (i + n - 1) + 1] = b;
        }
        Ok(Self { bits, code, lines })
    }

    /// Code depth n.
    pub fn bits(&self) -> u32 {
        self.bits
    }

    /// The LFSR code b_0 … b_{2^n−2}.
    pub fn code(&self) -> &[u8] {
        &self.code
    }

    /// The line sequence s (1 = line present).
    pub fn lines(&self) -> &[u8] {
        &self.lines
    }

    /// Number of lines L (rows or columns) in the pattern.
    pub fn len(&self) -> usize {
        self.lines.len()
    }

    /// Always false: a sequence has at least 3·(15 + 3) lines.
    pub fn is_empty(&self) -> bool {
        self.lines.is_empty()
    }

    /// Whether line `i` is present; lines outside the pattern are absent.
    pub fn line(&self, i: i64) -> bool {
        usize::try_from(i)
            .ok()
            .and_then(|i| self.lines.get(i))
            .is_some_and(|&b| b == 1)
    }

    /// Whether dot (column `c`, row `r`) is present.
    ///
    /// A dot exists where both its row and column lines exist, except where
    /// both indices are multiples of 3: those crossings are left empty so the
    /// two directions' code phases can be told apart from the grid alone.
    pub fn dot(&self, c: i64, r: i64) -> bool {
        self.line(c) && self.line(r) && !(c.rem_euclid(3) == 0 && r.rem_euclid(3) == 0)
    }

    /// Minimum number of periods a view must span in each direction to be
    /// decodable: 3(n + 1).
    pub fn min_periods_in_view(&self) -> usize {
        3 * (self.bits as usize + 1)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn codes_are_maximal_length_and_start_with_one() {
        for bits in MIN_BITS..=MAX_BITS {
            let code = lfsr_code(bits).unwrap();
            assert_eq!(code.len(), (1 << bits) - 1);
            assert_eq!(code[0], 1);
            // A maximal-length sequence has 2^(n-1) ones.
            let ones = code.iter().filter(|&&b| b == 1).count();
            assert_eq!(ones, 1 << (bits - 1), "bits {bits}");
            // Every cyclic window of n bits is unique (and non-zero).
            let n = bits as usize;
            let mut seen = vec![false; 1 << n];
            for i in 0..code.len() {
                let w = (0..n).fold(0usize, |acc, k| {
                    (acc << 1) | code[(i + k) % code.len()] as usize
                });
                assert!(w != 0 && !seen[w], "bits {bits} window {i}");
                seen[w] = true;
            }
        }
    }

    #[test]
    fn four_bit_code_by_hand() {
        // 1111 -> out 1, fb 0 -> 1110 -> out 0, fb 1 -> 1101 -> out 1, fb 0 -> 1010 -> out 0, fb 1 -> 0101 -> out 1
        let code = lfsr_code(4).unwrap();
        assert_eq!(&code[..5], &[1, 0, 1, 0, 1]);
    }

    #[test]
    fn line_sequence_layout() {
        for bits in MIN_BITS..=MAX_BITS {
            let s = LineSequence::new(bits).unwrap();
            let n = bits as usize;
            assert_eq!(s.len(), 3 * ((1 << n) - 1 + n - 1));
            for i in 0..s.len() {
                if i % 3 != 1 {
                    assert!(s.line(i as i64));
                }
            }
            for (i, &b) in s.code().iter().enumerate().take(s.code().len() - 1) {
                assert_eq!(s.lines()[3 * (i + n - 1) + 1], b);
            }
        }
    }

    #[test]
    fn dots_and_errors() {
        let s = LineSequence::new(10).unwrap();
        assert!(!s.dot(0, 0));
        assert!(!s.dot(3, 6));
        assert!(s.dot(2, 0));
        assert!(!s.dot(-1, 2));
        assert!(!s.dot(2, s.len() as i64));
        assert_eq!(s.min_periods_in_view(), 33);
        assert_eq!(LineSequence::new(3), Err(SequenceError::UnsupportedBits(3)));
        assert_eq!(lfsr_code(13), Err(SequenceError::UnsupportedBits(13)));
    }
}
