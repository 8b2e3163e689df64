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
    /// The code read fits another code depth than the configured one: the
    /// frame comes from another pattern, and any position would be wrong.
    #[error("the code read ({} and {} lines along the two lattice axes) does not fit a {bits}-bit sequence (best positions disagree on {} and {} lines, as a random reading would) but fits a {fits_bits}-bit one ({} and {} disagreeing): the pattern's code depth is {fits_bits}, not {bits}", lines[0], lines[1], mismatches[0], mismatches[1], fits_mismatches[0], fits_mismatches[1])]
    CodeDepthMismatch {
        /// The configured code depth.
        bits: u32,
        /// The supported depth the reading fits.
        fits_bits: u32,
        /// Hard-read code lines per lattice axis.
        lines: [usize; 2],
        /// Disagreements at the chosen positions of the configured sequence.
        mismatches: [usize; 2],
        /// Fewest disagreements in the sequence of `fits_bits`.
        fits_mismatches: [usize; 2],
    },
    /// The measured dot pitch, the configured period and the camera's known
    /// pixel size disagree: the period (or the pixel size) is wrong, and every
    /// position would be scaled by their ratio.
    #[error("the dots are {period_px:.2} px apart: with a period of {period_um} µm that is {measured_pixel_um:.4} µm per pixel, but the camera's pixel is {expected_pixel_um:.4} µm on the pattern ({ratio:.3}×): the pattern's period is about {fits_period_um:.3} µm (or the pixel size is wrong)", ratio = measured_pixel_um / expected_pixel_um)]
    ScaleMismatch {
        /// The configured period, µm.
        period_um: f64,
        /// The measured dot pitch, px.
        period_px: f64,
        /// Pixel size the configured period implies, µm.
        measured_pixel_um: f64,
        /// The camera's pixel size on the pattern, µm (configured).
        expected_pixel_um: f64,
        /// The period that fits the pitch and the pixel size, µm.
        fits_period_um: f64,
    },
}
