//! Loading image files (PNG 8/16-bit, TIFF, JPEG) into [`Frame`]s.
//!
//! Why here and not in a camera module: the CLI decoder, the file-replay
//! frame source and the tests all read the same files, and they must agree on
//! how colour and bit depth are reduced to one grayscale frame. Colour images
//! are converted to luma (Rec. 601 weights, as the `image` crate does); 16-bit
//! images keep all 16 bits (`bit_depth` 16), everything else becomes 8-bit.

use std::io::Cursor;
use std::path::Path;

use image::{DynamicImage, ImageReader};
use thiserror::Error;

use crate::frame::{Frame, FrameError, Pixels};

/// Why an image file could not be turned into a frame.
#[derive(Debug, Error)]
pub enum ImageIoError {
    /// The file could not be read.
    #[error("cannot read {path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// The OS error.
        #[source]
        source: std::io::Error,
    },
    /// The bytes are not an image in a supported format (PNG, TIFF, JPEG).
    #[error("cannot decode image: {0}")]
    Decode(#[from] image::ImageError),
    /// The decoded image does not make a valid frame (e.g. zero size).
    #[error("image does not make a frame: {0}")]
    Frame(#[from] FrameError),
}

/// Decodes an in-memory image (format guessed from its content) into a
/// grayscale frame with timestamp 0 and sequence 0.
pub fn frame_from_bytes(bytes: &[u8]) -> Result<Frame, ImageIoError> {
    let img = ImageReader::new(Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|source| ImageIoError::Io {
            path: "<memory>".into(),
            source,
        })?
        .decode()?;
    frame_from_image(img)
}

/// Reads an image file into a grayscale frame.
pub fn load_frame(path: &Path) -> Result<Frame, ImageIoError> {
    let bytes = std::fs::read(path).map_err(|source| ImageIoError::Io {
        path: path.display().to_string(),
        source,
    })?;
    frame_from_bytes(&bytes)
}

/// Converts a decoded image: 16-bit (or deeper) sources stay 16-bit, the rest
/// become 8-bit luma.
pub fn frame_from_image(img: DynamicImage) -> Result<Frame, ImageIoError> {
    let (w, h) = (img.width() as usize, img.height() as usize);
    let deep = matches!(
        img,
        DynamicImage::ImageLuma16(_)
            | DynamicImage::ImageLumaA16(_)
            | DynamicImage::ImageRgb16(_)
            | DynamicImage::ImageRgba16(_)
            | DynamicImage::ImageRgb32F(_)
            | DynamicImage::ImageRgba32F(_)
    );
    if deep {
        let g = img.into_luma16();
        Ok(Frame::new(w, h, 16, Pixels::U16(g.into_raw()), 0.0, 0)?)
    } else {
        let g = img.into_luma8();
        Ok(Frame::new(w, h, 8, Pixels::U8(g.into_raw()), 0.0, 0)?)
    }
}

/// Encodes a frame as PNG (8- or 16-bit grayscale; deeper-than-8 frames are
/// scaled to the full 16-bit range so viewers show them correctly).
///
/// Why: test fixtures and the simulator's frame dumps must be readable by
/// [`load_frame`] and by ordinary tools.
pub fn frame_to_png(frame: &Frame) -> Result<Vec<u8>, ImageIoError> {
    let (w, h) = (frame.width() as u32, frame.height() as u32);
    let img = match frame.pixels() {
        Pixels::U8(p) => image::GrayImage::from_raw(w, h, p.clone()).map(DynamicImage::ImageLuma8),
        Pixels::U16(p) => {
            let shift = 16 - u32::from(frame.bit_depth());
            let scaled: Vec<u16> = p.iter().map(|&v| v << shift).collect();
            image::ImageBuffer::<image::Luma<u16>, _>::from_raw(w, h, scaled)
                .map(DynamicImage::ImageLuma16)
        }
    };
    let img = img.ok_or(ImageIoError::Frame(FrameError::SizeMismatch {
        width: w as usize,
        height: h as usize,
        expected: (w as usize) * (h as usize),
        got: 0,
    }))?;
    let mut out = Vec::new();
    img.write_to(&mut Cursor::new(&mut out), image::ImageFormat::Png)?;
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn png_round_trip_8_and_16_bit() {
        let f8 = Frame::new(3, 2, 8, Pixels::U8(vec![0, 1, 2, 3, 254, 255]), 0.0, 0).unwrap();
        let back = frame_from_bytes(&frame_to_png(&f8).unwrap()).unwrap();
        assert_eq!(back, f8);
        let f16 = Frame::new(2, 1, 16, Pixels::U16(vec![7, 65535]), 0.0, 0).unwrap();
        let back = frame_from_bytes(&frame_to_png(&f16).unwrap()).unwrap();
        assert_eq!(back, f16);
        // 12-bit frames come back as 16-bit with the values scaled up.
        let f12 = Frame::new(1, 1, 12, Pixels::U16(vec![4095]), 0.0, 0).unwrap();
        let back = frame_from_bytes(&frame_to_png(&f12).unwrap()).unwrap();
        assert_eq!(back.get(0, 0), Some(4095 << 4));
    }

    #[test]
    fn garbage_is_an_error() {
        assert!(frame_from_bytes(b"not an image").is_err());
        assert!(frame_from_bytes(&[]).is_err());
        assert!(load_frame(Path::new("/nonexistent/file.png")).is_err());
    }
}
