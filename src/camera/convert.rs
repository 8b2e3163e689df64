//! Camera buffer → [`Frame`] conversion.
//!
//! Why separate from the backends: the byte layouts (row stride, 16-bit
//! little-endian containers, YUYV interleaving) are the same whether the
//! bytes come from V4L2 or aravis, and pure functions over byte slices can be
//! unit-tested and fuzzed without a camera. Nothing here panics on any input.

use super::{CameraError, PixelFormat};
use crate::frame::{Frame, Pixels};

/// Bytes one pixel occupies in the camera buffer.
pub fn bytes_per_pixel(format: PixelFormat) -> usize {
    match format {
        PixelFormat::Mono8 => 1,
        PixelFormat::Mono10
        | PixelFormat::Mono12
        | PixelFormat::Mono14
        | PixelFormat::Mono16
        | PixelFormat::Yuyv => 2,
    }
}

/// Checks the buffer geometry and returns the effective row stride.
///
/// `stride` is bytes per row; 0 means tightly packed. The last row need not
/// be padded, and trailing bytes after it are ignored (V4L2 and GigE
/// buffers are often larger than the image).
fn row_stride(
    format: PixelFormat,
    width: usize,
    height: usize,
    stride: usize,
    len: usize,
) -> Result<usize, CameraError> {
    if width == 0 || height == 0 {
        return Err(CameraError::BadData(format!(
            "empty image {width}×{height}"
        )));
    }
    if format == PixelFormat::Yuyv && width % 2 != 0 {
        return Err(CameraError::BadData(format!(
            "YUYV needs an even width, got {width}"
        )));
    }
    let row_bytes = width
        .checked_mul(bytes_per_pixel(format))
        .ok_or_else(|| CameraError::BadData(format!("width {width} overflows")))?;
    let stride = if stride == 0 { row_bytes } else { stride };
    if stride < row_bytes {
        return Err(CameraError::BadData(format!(
            "row stride {stride} B is shorter than a {width}-pixel {format} row ({row_bytes} B)"
        )));
    }
    let needed = stride
        .checked_mul(height - 1)
        .and_then(|v| v.checked_add(row_bytes))
        .ok_or_else(|| CameraError::BadData(format!("{width}×{height} overflows")))?;
    if len < needed {
        return Err(CameraError::BadData(format!(
            "{format} {width}×{height} (stride {stride} B) needs {needed} B, buffer holds {len} B"
        )));
    }
    Ok(stride)
}

/// Converts a camera buffer into a grayscale frame.
///
/// Monochrome formats deeper than 8 bits are read as little-endian `u16`
/// right-aligned counts (the GenICam "unpacked" and V4L2 Y10/Y12/Y16
/// layouts); a value above the format's full scale is rejected rather than
/// silently clipped, because it means the format was misdeclared. YUYV keeps
/// the luma bytes only.
pub fn to_frame(
    format: PixelFormat,
    width: usize,
    height: usize,
    stride: usize,
    data: &[u8],
    timestamp_s: f64,
    sequence: u64,
) -> Result<Frame, CameraError> {
    let stride = row_stride(format, width, height, stride, data.len())?;
    let rows = (0..height).filter_map(|r| {
        let start = r * stride;
        data.get(start..start + width * bytes_per_pixel(format))
    });
    let pixels = match format {
        PixelFormat::Mono8 => {
            let mut out = Vec::with_capacity(width * height);
            for row in rows {
                out.extend_from_slice(row);
            }
            Pixels::U8(out)
        }
        PixelFormat::Yuyv => {
            let mut out = Vec::with_capacity(width * height);
            for row in rows {
                out.extend(row.iter().step_by(2));
            }
            Pixels::U8(out)
        }
        PixelFormat::Mono10 | PixelFormat::Mono12 | PixelFormat::Mono14 | PixelFormat::Mono16 => {
            let max = ((1u32 << format.bit_depth()) - 1) as u16;
            let mut out = Vec::with_capacity(width * height);
            for row in rows {
                out.extend(
                    row.chunks_exact(2)
                        .map(|b| u16::from_le_bytes([b[0], b[1]])),
                );
            }
            if let Some(pos) = out.iter().position(|&v| v > max) {
                return Err(CameraError::BadData(format!(
                    "pixel ({}, {}) = {} exceeds {format} full scale {max}",
                    pos % width,
                    pos / width,
                    out[pos]
                )));
            }
            Pixels::U16(out)
        }
    };
    Ok(Frame::new(
        width,
        height,
        format.bit_depth(),
        pixels,
        timestamp_s,
        sequence,
    )?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn mono8_with_stride() {
        // 3×2 image, rows padded to 4 bytes, last row unpadded.
        let data = [1, 2, 3, 99, 4, 5, 6];
        let f = to_frame(PixelFormat::Mono8, 3, 2, 4, &data, 1.0, 5).unwrap();
        assert_eq!(f.pixels(), &Pixels::U8(vec![1, 2, 3, 4, 5, 6]));
        assert_eq!((f.bit_depth(), f.sequence, f.timestamp_s), (8, 5, 1.0));
    }

    #[test]
    fn mono12_little_endian_and_range() {
        let data = [0x01, 0x00, 0xFF, 0x0F];
        let f = to_frame(PixelFormat::Mono12, 2, 1, 0, &data, 0.0, 0).unwrap();
        assert_eq!(f.pixels(), &Pixels::U16(vec![1, 4095]));
        assert_eq!(f.bit_depth(), 12);
        let bad = [0x00, 0x10, 0x00, 0x00];
        let e = to_frame(PixelFormat::Mono12, 2, 1, 0, &bad, 0.0, 0).unwrap_err();
        assert!(e.to_string().contains("4096 exceeds Mono12"), "{e}");
        let f = to_frame(PixelFormat::Mono16, 1, 1, 0, &[0xFF, 0xFF], 0.0, 0).unwrap();
        assert_eq!(f.get(0, 0), Some(65535));
    }

    #[test]
    fn yuyv_keeps_luma() {
        let data = [10, 128, 20, 130, 30, 128, 40, 130];
        let f = to_frame(PixelFormat::Yuyv, 2, 2, 0, &data, 0.0, 0).unwrap();
        assert_eq!(f.pixels(), &Pixels::U8(vec![10, 20, 30, 40]));
        assert!(to_frame(PixelFormat::Yuyv, 3, 1, 0, &[0; 6], 0.0, 0).is_err());
    }

    #[test]
    fn rejects_short_buffers_and_bad_strides() {
        assert!(to_frame(PixelFormat::Mono8, 4, 4, 0, &[0; 15], 0.0, 0).is_err());
        assert!(to_frame(PixelFormat::Mono8, 4, 1, 3, &[0; 16], 0.0, 0).is_err());
        assert!(to_frame(PixelFormat::Mono16, 0, 1, 0, &[], 0.0, 0).is_err());
        assert!(to_frame(PixelFormat::Mono8, usize::MAX, 2, 0, &[0; 4], 0.0, 0).is_err());
    }

    proptest! {
        #[test]
        fn never_panics_and_sizes_match(
            fmt_idx in 0usize..6,
            width in 0usize..20,
            height in 0usize..6,
            stride in 0usize..64,
            data in proptest::collection::vec(any::<u8>(), 0..300),
        ) {
            let format = PixelFormat::ALL[fmt_idx];
            if let Ok(f) = to_frame(format, width, height, stride, &data, 0.0, 0) {
                prop_assert_eq!(f.width(), width);
                prop_assert_eq!(f.height(), height);
                prop_assert_eq!(f.bit_depth(), format.bit_depth());
            }
        }

        #[test]
        fn mono8_round_trips(width in 1usize..16, height in 1usize..8, pad in 0usize..4, seed in any::<u64>()) {
            let stride = width + pad;
            let data: Vec<u8> = (0..stride * height).map(|i| (i as u64).wrapping_mul(seed | 1) as u8).collect();
            let f = to_frame(PixelFormat::Mono8, width, height, stride, &data, 0.0, 0).unwrap();
            for y in 0..height {
                for x in 0..width {
                    prop_assert_eq!(f.get(x, y), Some(u16::from(data[y * stride + x])));
                }
            }
        }
    }
}
