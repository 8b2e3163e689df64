//! Why a frame could not be decoded: the one error type of every decoding
//! stage, in its own file so the stages import it without importing the
//! decoder.

use thiserror::Error;

use crate::pattern::sequence::SequenceError;

/// Why a frame could not be decoded. The decoder returns one of these rather
/// than a position it is not sure of.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum DecodeError {
    /// Bad decoder options.
    #[error("invalid decoder option: {0}")]
    Options(String),
    /// The code depth is not supported.
    #[error(transparent)]
    Sequence(#[from] SequenceError),
    /// The frame is too small for any grid search.
    #[error("frame {width}×{height} is too small (need at least 16×16)")]
    TooSmall {
        /// Frame width.
        width: usize,
        /// Frame height.
        height: usize,
    },
    /// No periodic dot grid with the expected structure was found.
    #[error("no dot grid found: {0}")]
    NoGrid(String),
    /// The view spans too few periods to read enough code bits.
    #[error("view spans {got} periods along a pattern axis, need {need}")]
    TooFewPeriods {
        /// Periods (lines) seen.
        got: usize,
        /// Periods required, 3(n + 1).
        need: usize,
    },
    /// The line structure does not give a unique orientation.
    #[error("orientation: {0}")]
    Orientation(String),
    /// The code does not give a unique position. Carries how many code lines
    /// were readable along the failing lattice axis, so a caller (or a test)
    /// can tell a view short of code bits (fewer than n + a few) from a
    /// decoder weakness.
    #[error("code ambiguous along lattice axis {axis} ({readable_bits} readable code lines, code depth {code_bits}): {reason}")]
    CodeAmbiguous {
        /// Lattice axis (0 = a, 1 = b) that failed.
        axis: usize,
        /// Code lines read with confidence along that axis.
        readable_bits: usize,
        /// Code depth n of the pattern.
        code_bits: u32,
        /// What went wrong.
        reason: String,
    },
}
