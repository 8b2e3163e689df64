//! A camera frame: the one image type shared by the renderer, the decoder and
//! every frame source.
//!
//! Why one type: a frame recorded from a real camera, read back from a file or
//! rendered by the simulator must be interchangeable, so replaying a run or
//! swapping a camera for the simulator changes nothing downstream.

use thiserror::Error;

/// Pixel storage. 8-bit sensors keep one byte per pixel; deeper sensors
/// (10/12/14/16-bit) keep their counts right-aligned in a `u16`.
#[derive(Debug, Clone, PartialEq)]
pub enum Pixels {
    /// One byte per pixel, row-major.
    U8(Vec<u8>),
    /// One `u16` per pixel, row-major, values in `0..2^bit_depth`.
    U16(Vec<u16>),
}

/// Why a frame cannot be built from the given parts.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum FrameError {
    /// The pixel buffer does not hold width × height pixels.
    #[error("pixel buffer holds {got} pixels, {width}×{height} needs {expected}")]
    SizeMismatch {
        /// Frame width in pixels.
        width: usize,
        /// Frame height in pixels.
        height: usize,
        /// width × height.
        expected: usize,
        /// What the buffer holds.
        got: usize,
    },
    /// Bit depth outside 1..=16, or above 8 for 8-bit storage.
    #[error("bit depth {bit_depth} does not fit {storage} storage")]
    BadBitDepth {
        /// Declared bit depth.
        bit_depth: u8,
        /// "u8" or "u16".
        storage: &'static str,
    },
    /// A frame needs at least one pixel.
    #[error("empty frame ({width}×{height})")]
    Empty {
        /// Frame width in pixels.
        width: usize,
        /// Frame height in pixels.
        height: usize,
    },
}

/// One grayscale image with its capture metadata.
///
/// Image frame convention: pixel (j, i) is column j, row i and covers
/// [j, j+1) × [i, i+1); the image centre point is (width/2, height/2).
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    width: usize,
    height: usize,
    bit_depth: u8,
    pixels: Pixels,
    /// Capture time in seconds on the source's clock (monotonic for live
    /// cameras, simulated time for the simulator, file time for replays).
    pub timestamp_s: f64,
    /// Sequence number assigned by the source; gaps mean dropped frames.
    pub sequence: u64,
}

impl Frame {
    /// Builds a frame, checking that the buffer matches the size and depth.
    pub fn new(
        width: usize,
        height: usize,
        bit_depth: u8,
        pixels: Pixels,
        timestamp_s: f64,
        sequence: u64,
    ) -> Result<Self, FrameError> {
        if width == 0 || height == 0 {
            return Err(FrameError::Empty { width, height });
        }
        let expected = width.checked_mul(height).ok_or(FrameError::SizeMismatch {
            width,
            height,
            expected: usize::MAX,
            got: 0,
        })?;
        let (got, ok_depth, storage) = match &pixels {
            Pixels::U8(p) => (p.len(), (1..=8).contains(&bit_depth), "u8"),
            Pixels::U16(p) => (p.len(), (1..=16).contains(&bit_depth), "u16"),
        };
        if !ok_depth {
            return Err(FrameError::BadBitDepth { bit_depth, storage });
        }
        if got != expected {
            return Err(FrameError::SizeMismatch {
                width,
                height,
                expected,
                got,
            });
        }
        Ok(Self {
            width,
            height,
            bit_depth,
            pixels,
            timestamp_s,
            sequence,
        })
    }

    /// Width in pixels.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Height in pixels.
    pub fn height(&self) -> usize {
        self.height
    }

    /// Significant bits per pixel (8 for `U8`, 8..=16 for `U16`).
    pub fn bit_depth(&self) -> u8 {
        self.bit_depth
    }

    /// The pixel buffer.
    pub fn pixels(&self) -> &Pixels {
        &self.pixels
    }

    /// Full-scale value, 2^bit_depth − 1.
    pub fn full_scale(&self) -> u32 {
        (1u32 << self.bit_depth) - 1
    }

    /// Pixel value at column `x`, row `y`, or `None` outside the frame.
    pub fn get(&self, x: usize, y: usize) -> Option<u16> {
        if x >= self.width || y >= self.height {
            return None;
        }
        let i = y * self.width + x;
        match &self.pixels {
            Pixels::U8(p) => p.get(i).map(|&v| u16::from(v)),
            Pixels::U16(p) => p.get(i).copied(),
        }
    }

    /// Writes the frame as normalised intensities in [0, 1] into `out`
    /// (resized to width × height), reusing its allocation.
    pub fn to_f32_into(&self, out: &mut Vec<f32>) {
        let scale = 1.0 / self.full_scale() as f32;
        out.clear();
        match &self.pixels {
            Pixels::U8(p) => out.extend(p.iter().map(|&v| f32::from(v) * scale)),
            Pixels::U16(p) => out.extend(p.iter().map(|&v| f32::from(v) * scale)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn checks_size_and_depth() {
        assert!(Frame::new(2, 2, 8, Pixels::U8(vec![0; 4]), 0.0, 0).is_ok());
        assert!(matches!(
            Frame::new(2, 2, 8, Pixels::U8(vec![0; 3]), 0.0, 0),
            Err(FrameError::SizeMismatch { got: 3, .. })
        ));
        assert!(matches!(
            Frame::new(2, 2, 12, Pixels::U8(vec![0; 4]), 0.0, 0),
            Err(FrameError::BadBitDepth { .. })
        ));
        assert!(matches!(
            Frame::new(0, 2, 8, Pixels::U8(vec![]), 0.0, 0),
            Err(FrameError::Empty { .. })
        ));
        let f = Frame::new(2, 1, 12, Pixels::U16(vec![0, 4095]), 1.5, 7).unwrap();
        assert_eq!(f.get(1, 0), Some(4095));
        assert_eq!(f.get(2, 0), None);
        let mut v = Vec::new();
        f.to_f32_into(&mut v);
        assert_eq!(v, vec![0.0, 1.0]);
    }
}
