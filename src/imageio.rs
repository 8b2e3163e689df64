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

/// Largest accepted image side, px: a hostile header cannot make the decoder
/// allocate gigabytes.
pub const MAX_SIDE_PX: u32 = 32_768;
/// Largest total allocation the image decoder may make, bytes.
pub const MAX_DECODE_BYTES: u64 = 2 << 30;

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
    /// The bytes are not in a supported format (PNG, TIFF, JPEG).
    #[error("not a PNG, TIFF or JPEG image")]
    UnknownFormat,
    /// The bytes are not a valid image, or exceed the size limits.
    #[error("cannot decode image: {0}")]
    Decode(#[from] image::ImageError),
    /// The declared bit depth is impossible or contradicted by the pixels.
    #[error("bit depth: {0}")]
    BitDepth(String),
    /// The decoded image does not make a valid frame (e.g. zero size).
    #[error("image does not make a frame: {0}")]
    Frame(#[from] FrameError),
}

/// Decodes an in-memory image (format guessed from its content) into a
/// grayscale frame with timestamp 0 and sequence 0; see
/// [`frame_from_bytes_with_depth`].
pub fn frame_from_bytes(bytes: &[u8]) -> Result<Frame, ImageIoError> {
    frame_from_bytes_with_depth(bytes, None)
}

/// Decodes an in-memory image into a grayscale frame — the one image parser
/// of micropos (the CLI, the file-replay camera and the tests all use it, so
/// they agree on colour and bit-depth handling).
///
/// * Colour becomes luma (Rec. 601, as the `image` crate does).
/// * 8-bit sources give 8-bit frames. 16-bit (or float) sources give 16-bit
///   frames, unless a PNG `sBIT` chunk declares fewer significant bits (then
///   the values are shifted down and the frame has that depth, so a 12-bit
///   camera frame saved as PNG round-trips exactly), or `bit_depth` declares
///   the depth of unscaled data (then every pixel must fit it).
/// * Sides above [`MAX_SIDE_PX`] and allocations above [`MAX_DECODE_BYTES`]
///   are refused before decoding, so hostile headers cannot exhaust memory.
///
/// This parses outside input; it is fuzzed
/// (`fuzz/fuzz_targets/camera_image_file.rs`) and never panics.
pub fn frame_from_bytes_with_depth(
    bytes: &[u8],
    bit_depth: Option<u8>,
) -> Result<Frame, ImageIoError> {
    let mut reader = ImageReader::new(Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|source| ImageIoError::Io {
            path: "<memory>".into(),
            source,
        })?;
    if reader.format().is_none() {
        return Err(ImageIoError::UnknownFormat);
    }
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(MAX_SIDE_PX);
    limits.max_image_height = Some(MAX_SIDE_PX);
    limits.max_alloc = Some(MAX_DECODE_BYTES);
    reader.limits(limits);
    let img = reader.decode()?;
    let (w, h) = (img.width() as usize, img.height() as usize);
    if !is_deep(&img) {
        let g = img.into_luma8();
        return Ok(Frame::new(w, h, 8, Pixels::U8(g.into_raw()), 0.0, 0)?);
    }
    let mut px = img.into_luma16().into_raw();
    let depth = match png_sbit(bytes) {
        Some(s) => {
            let shift = 16 - u32::from(s);
            px.iter_mut().for_each(|v| *v >>= shift);
            s
        }
        None => match bit_depth {
            Some(d) if (1..=16).contains(&d) => {
                let max = ((1u32 << d) - 1) as u16;
                if let Some(pos) = px.iter().position(|&v| v > max) {
                    return Err(ImageIoError::BitDepth(format!(
                        "pixel ({}, {}) = {} exceeds the declared {d}-bit full scale {max}",
                        pos % w.max(1),
                        pos / w.max(1),
                        px[pos]
                    )));
                }
                d
            }
            Some(d) => {
                return Err(ImageIoError::BitDepth(format!(
                    "bit depth {d} is outside 1..=16"
                )))
            }
            None => 16,
        },
    };
    Ok(Frame::new(w, h, depth, Pixels::U16(px), 0.0, 0)?)
}

/// Significant bits declared by a 16-bit grayscale PNG's `sBIT` chunk.
fn png_sbit(bytes: &[u8]) -> Option<u8> {
    let decoder = png::Decoder::new(Cursor::new(bytes));
    let reader = decoder.read_info().ok()?;
    let info = reader.info();
    if info.bit_depth != png::BitDepth::Sixteen {
        return None;
    }
    let s = *info.sbit.as_ref()?.first()?;
    (1..16).contains(&s).then_some(s)
}

fn is_deep(img: &DynamicImage) -> bool {
    matches!(
        img,
        DynamicImage::ImageLuma16(_)
            | DynamicImage::ImageLumaA16(_)
            | DynamicImage::ImageRgb16(_)
            | DynamicImage::ImageRgba16(_)
            | DynamicImage::ImageRgb32F(_)
            | DynamicImage::ImageRgba32F(_)
    )
}

/// Reads an image file into a grayscale frame ([`frame_from_bytes`]).
pub fn load_frame(path: &Path) -> Result<Frame, ImageIoError> {
    let bytes = std::fs::read(path).map_err(|source| ImageIoError::Io {
        path: path.display().to_string(),
        source,
    })?;
    frame_from_bytes(&bytes)
}

/// Converts an already decoded image: 16-bit (or deeper) sources stay
/// 16-bit, the rest become 8-bit luma (no sBIT information at this level).
pub fn frame_from_image(img: DynamicImage) -> Result<Frame, ImageIoError> {
    let (w, h) = (img.width() as usize, img.height() as usize);
    if is_deep(&img) {
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
