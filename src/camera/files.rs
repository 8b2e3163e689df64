//! Replay of recorded runs: a directory, a glob or a single image file as a
//! [`FrameSource`], and the PNG writer `micropos camera grab` records with.
//!
//! Why: a characterization run is only trustworthy if it can be re-decoded
//! later, bit for bit, with a newer decoder. Replaying the recorded images
//! through the same trait the cameras use makes that a one-flag change.
//!
//! Order: files are sorted by their full path, byte-wise (so recorders must
//! zero-pad frame numbers: `f000123.png`). A directory contributes every
//! file ending in .png, .tif, .tiff, .jpg or .jpeg (any case); a glob
//! contributes every regular file it matches.
//!
//! Bit depth: 8-bit files give 8-bit frames. 16-bit PNG files carrying an
//! `sBIT` chunk of s bits give s-bit frames, read by shifting the samples
//! right by 16 − s (the PNG specification stores s-bit data scaled up to the
//! full 16 bits, which is what [`write_png`] does). Other 16-bit files give
//! 16-bit frames unless [`FileOptions::bit_depth`] says the counts are
//! right-aligned at a smaller depth. Colour images are reduced to luma.
//!
//! Merge note: `src/imageio.rs` (vision branch) also turns image files into
//! frames; the two should become one module.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use super::{CameraError, CameraInfo, FrameSource};
use crate::frame::{Frame, Pixels};

/// Size limits of the image parser (defined once, in [`crate::imageio`]).
pub use crate::imageio::{MAX_DECODE_BYTES, MAX_SIDE_PX};

/// How replay frames are stamped.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum FileTiming {
    /// Frame k (counted over loops) has timestamp k / rate_hz.
    Rate {
        /// Frames per second.
        rate_hz: f64,
    },
    /// Frame k has timestamp k seconds: only the order is known.
    FileOrder,
}

/// Replay options.
#[derive(Debug, Clone, PartialEq)]
pub struct FileOptions {
    /// Start again at the first file after the last one.
    pub looping: bool,
    /// How timestamps are assigned.
    pub timing: FileTiming,
    /// With [`FileTiming::Rate`], deliver frames no faster than the rate (so
    /// a replay into the daemon behaves like the live camera).
    pub pace: bool,
    /// Treat 16-bit samples without `sBIT` as right-aligned counts of this
    /// depth (a file whose values exceed it is rejected).
    pub bit_depth: Option<u8>,
}

impl Default for FileOptions {
    fn default() -> Self {
        Self {
            looping: false,
            timing: FileTiming::FileOrder,
            pace: false,
            bit_depth: None,
        }
    }
}

/// Frames from recorded image files.
#[derive(Debug)]
pub struct FileSource {
    files: Vec<PathBuf>,
    options: FileOptions,
    info: CameraInfo,
    /// Index into the stream counted over loops (= sequence number).
    k: u64,
    /// The first file, decoded at open for [`CameraInfo`], served once.
    first: Option<Frame>,
    started: Option<Instant>,
}

fn has_glob_chars(s: &str) -> bool {
    s.contains(['*', '?', '['])
}

fn is_image_name(p: &Path) -> bool {
    p.extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase())
        .is_some_and(|e| matches!(e.as_str(), "png" | "tif" | "tiff" | "jpg" | "jpeg"))
}

/// The files a replay pattern names, sorted.
pub fn list_files(pattern: &str) -> Result<Vec<PathBuf>, CameraError> {
    let path = Path::new(pattern);
    let mut files = if path.is_dir() {
        let rd = std::fs::read_dir(path).map_err(|source| CameraError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        let mut v = Vec::new();
        for entry in rd {
            let entry = entry.map_err(|source| CameraError::Io {
                path: path.to_path_buf(),
                source,
            })?;
            let p = entry.path();
            if p.is_file() && is_image_name(&p) {
                v.push(p);
            }
        }
        v
    } else if path.is_file() {
        vec![path.to_path_buf()]
    } else if has_glob_chars(pattern) {
        let paths = glob::glob(pattern).map_err(|e| CameraError::BadSpec {
            spec: pattern.to_string(),
            reason: format!("bad glob pattern: {e}"),
        })?;
        let mut v = Vec::new();
        for p in paths {
            let p = p.map_err(|e| CameraError::Io {
                path: e.path().to_path_buf(),
                source: std::io::Error::new(e.error().kind(), e.error().to_string()),
            })?;
            if p.is_file() {
                v.push(p);
            }
        }
        v
    } else {
        return Err(CameraError::Io {
            path: path.to_path_buf(),
            source: std::io::Error::new(std::io::ErrorKind::NotFound, "no such file or directory"),
        });
    };
    files.sort();
    if files.is_empty() {
        return Err(CameraError::BadSpec {
            spec: pattern.to_string(),
            reason: "matches no image files (.png, .tif, .tiff, .jpg, .jpeg)".into(),
        });
    }
    Ok(files)
}

/// Decodes an encoded image (PNG, TIFF, JPEG) into a frame with timestamp 0
/// and sequence 0. `bit_depth` is [`FileOptions::bit_depth`].
///
/// Delegates to [`crate::imageio::frame_from_bytes_with_depth`], the one
/// image parser (size limits, sBIT, declared depth); this wrapper only turns
/// its error into the reason string of [`CameraError::Decode`].
pub fn decode_image_bytes(bytes: &[u8], bit_depth: Option<u8>) -> Result<Frame, String> {
    crate::imageio::frame_from_bytes_with_depth(bytes, bit_depth).map_err(|e| e.to_string())
}

/// Reads and decodes one image file; see [`decode_image_bytes`].
pub fn decode_image_file(path: &Path, bit_depth: Option<u8>) -> Result<Frame, CameraError> {
    let bytes = std::fs::read(path).map_err(|source| CameraError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    decode_image_bytes(&bytes, bit_depth).map_err(|reason| CameraError::Decode {
        path: path.to_path_buf(),
        reason,
    })
}

/// Why a frame could not be written.
#[derive(Debug, thiserror::Error)]
pub enum WriteError {
    /// The file could not be created or written.
    #[error("{path}: {source}")]
    Io {
        /// The output file.
        path: PathBuf,
        /// The underlying error.
        #[source]
        source: std::io::Error,
    },
    /// The PNG encoder refused the frame.
    #[error("{path}: PNG encoding failed: {message}")]
    Encode {
        /// The output file.
        path: PathBuf,
        /// The encoder's message.
        message: String,
    },
}

/// Encodes a frame as a grayscale PNG into `out`.
///
/// 8-bit frames become 8-bit PNGs. Deeper frames become 16-bit PNGs with
/// the samples scaled up to 16 bits (shifted left by 16 − depth) and an
/// `sBIT` chunk recording the depth, as the PNG specification asks: viewers
/// show the right brightness and [`decode_image_bytes`] recovers the exact
/// counts. Frames of fewer than 8 bits are handled the same way in 8 bits.
pub fn encode_png<W: Write>(frame: &Frame, out: W) -> Result<(), String> {
    let w = u32::try_from(frame.width()).map_err(|_| "frame too wide for PNG".to_string())?;
    let h = u32::try_from(frame.height()).map_err(|_| "frame too tall for PNG".to_string())?;
    let mut enc = png::Encoder::new(out, w, h);
    enc.set_color(png::ColorType::Grayscale);
    let depth = frame.bit_depth();
    let (storage, data): (u8, Vec<u8>) = match frame.pixels() {
        Pixels::U8(p) => {
            let shift = 8 - depth;
            (8, p.iter().map(|&v| v << shift).collect())
        }
        Pixels::U16(p) => {
            let shift = 16 - depth;
            (
                16,
                p.iter().flat_map(|&v| (v << shift).to_be_bytes()).collect(),
            )
        }
    };
    enc.set_depth(if storage == 8 {
        png::BitDepth::Eight
    } else {
        png::BitDepth::Sixteen
    });
    let mut writer = enc.write_header().map_err(|e| e.to_string())?;
    if depth < storage {
        writer
            .write_chunk(png::chunk::sBIT, &[depth])
            .map_err(|e| e.to_string())?;
    }
    writer.write_image_data(&data).map_err(|e| e.to_string())?;
    writer.finish().map_err(|e| e.to_string())
}

/// Writes a frame to a PNG file; see [`encode_png`].
pub fn write_png(frame: &Frame, path: &Path) -> Result<(), WriteError> {
    let file = File::create(path).map_err(|source| WriteError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let mut out = BufWriter::new(file);
    encode_png(frame, &mut out).map_err(|message| WriteError::Encode {
        path: path.to_path_buf(),
        message,
    })?;
    out.flush().map_err(|source| WriteError::Io {
        path: path.to_path_buf(),
        source,
    })
}

impl FileSource {
    /// Opens a replay of the files `pattern` names (directory, file or glob).
    /// The first file is decoded now so [`FrameSource::info`] is exact and a
    /// bad recording fails at open, not mid-run.
    pub fn open(pattern: &str, options: FileOptions) -> Result<Self, CameraError> {
        if let FileTiming::Rate { rate_hz } = options.timing {
            if !(rate_hz.is_finite() && rate_hz > 0.0) {
                return Err(CameraError::BadSpec {
                    spec: pattern.to_string(),
                    reason: format!("replay rate must be a positive number of Hz, got {rate_hz}"),
                });
            }
        }
        let files = list_files(pattern)?;
        let first = decode_image_file(&files[0], options.bit_depth)?;
        let info = CameraInfo {
            backend: "files",
            model: format!("replay of {pattern}"),
            serial: String::new(),
            width: first.width(),
            height: first.height(),
            pixel_format: if first.bit_depth() <= 8 {
                "Mono8".into()
            } else {
                format!("Mono{}", first.bit_depth())
            },
            bit_depth: first.bit_depth(),
        };
        Ok(Self {
            files,
            options,
            info,
            k: 0,
            first: Some(first),
            started: None,
        })
    }

    /// The files of the replay, in delivery order.
    pub fn files(&self) -> &[PathBuf] {
        &self.files
    }

    fn timestamp_s(&self, k: u64) -> f64 {
        match self.options.timing {
            FileTiming::Rate { rate_hz } => k as f64 / rate_hz,
            FileTiming::FileOrder => k as f64,
        }
    }
}

impl FrameSource for FileSource {
    fn info(&self) -> CameraInfo {
        self.info.clone()
    }

    fn next_frame(&mut self) -> Result<Frame, CameraError> {
        let n = self.files.len() as u64;
        if !self.options.looping && self.k >= n {
            return Err(CameraError::EndOfStream { frames: n });
        }
        let k = self.k;
        self.k += 1;
        let path = &self.files[(k % n) as usize];
        let mut frame = match self.first.take() {
            Some(f) if k == 0 => f,
            _ => decode_image_file(path, self.options.bit_depth)?,
        };
        if frame.width() != self.info.width
            || frame.height() != self.info.height
            || frame.bit_depth() != self.info.bit_depth
        {
            return Err(CameraError::Decode {
                path: path.clone(),
                reason: format!(
                    "is {}×{} at {} bits, the replay is {}×{} at {} bits",
                    frame.width(),
                    frame.height(),
                    frame.bit_depth(),
                    self.info.width,
                    self.info.height,
                    self.info.bit_depth
                ),
            });
        }
        frame.timestamp_s = self.timestamp_s(k);
        frame.sequence = k;
        if let (true, FileTiming::Rate { .. }) = (self.options.pace, self.options.timing) {
            let start = *self.started.get_or_insert_with(Instant::now);
            let due = Duration::from_secs_f64(frame.timestamp_s);
            if let Some(wait) = due.checked_sub(start.elapsed()) {
                std::thread::sleep(wait);
            }
        }
        Ok(frame)
    }

    /// Replays never wait for a frame, so the timeout has no effect.
    fn set_timeout(&mut self, _timeout: Duration) {}
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame16(depth: u8) -> Frame {
        let max = (1u32 << depth) - 1;
        let px: Vec<u16> = (0..12u32).map(|i| (i * max / 11) as u16).collect();
        Frame::new(4, 3, depth, Pixels::U16(px), 0.0, 0).unwrap()
    }

    #[test]
    fn png_round_trip_keeps_counts_and_depth() {
        for depth in [10u8, 12, 14, 16] {
            let f = frame16(depth);
            let mut buf = Vec::new();
            encode_png(&f, &mut buf).unwrap();
            let g = decode_image_bytes(&buf, None).unwrap();
            assert_eq!(g.bit_depth(), depth);
            assert_eq!(g.pixels(), f.pixels(), "depth {depth}");
        }
        let f = Frame::new(3, 1, 8, Pixels::U8(vec![0, 7, 255]), 0.0, 0).unwrap();
        let mut buf = Vec::new();
        encode_png(&f, &mut buf).unwrap();
        assert_eq!(decode_image_bytes(&buf, None).unwrap().pixels(), f.pixels());
    }

    #[test]
    fn twelve_bit_png_is_scaled_up_on_disk() {
        let f = frame16(12);
        let mut buf = Vec::new();
        encode_png(&f, &mut buf).unwrap();
        let img = image::load_from_memory(&buf).unwrap().into_luma16();
        // 4095 << 4 = 65520: a viewer shows full white.
        assert_eq!(img.get_pixel(3, 2).0[0], 65520);
    }

    #[test]
    fn declared_depth_for_plain_16_bit_files() {
        let img =
            image::ImageBuffer::<image::Luma<u16>, _>::from_raw(2, 1, vec![100u16, 4095]).unwrap();
        let mut buf = Vec::new();
        img.write_to(&mut std::io::Cursor::new(&mut buf), image::ImageFormat::Png)
            .unwrap();
        assert_eq!(decode_image_bytes(&buf, None).unwrap().bit_depth(), 16);
        let f = decode_image_bytes(&buf, Some(12)).unwrap();
        assert_eq!((f.bit_depth(), f.get(1, 0)), (12, Some(4095)));
        let e = decode_image_bytes(&buf, Some(10)).unwrap_err();
        assert!(e.contains("exceeds the declared 10-bit"), "{e}");
    }

    #[test]
    fn garbage_is_an_error() {
        assert!(decode_image_bytes(b"", None).is_err());
        assert!(decode_image_bytes(b"\x89PNG\r\n\x1a\nxx", None).is_err());
        assert!(decode_image_bytes(&[0u8; 100], None).is_err());
    }
}
