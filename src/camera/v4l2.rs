//! V4L2 cameras (Linux video devices) through the `v4l` crate.
//!
//! Why: many industrial USB cameras and every UVC webcam show up as
//! /dev/videoN; the `v4l` crate wraps the ioctls and memory-mapped
//! streaming without any C library beyond the kernel headers.
//!
//! Formats: GREY (8-bit), Y10/Y12/Y16 (little-endian 16-bit containers)
//! and YUYV (luma kept). If the device is set to something else at open,
//! the source switches it to GREY, then Y16, then YUYV, whichever the
//! driver accepts.
//!
//! Controls: exposure through V4L2_CID_EXPOSURE_ABSOLUTE (units of 100 µs,
//! after switching V4L2_CID_EXPOSURE_AUTO to manual); frame rate through the
//! capture time-per-frame. V4L2 gain has no defined unit, so gain in dB is
//! refused with an explanation rather than guessed.

use std::path::{Path, PathBuf};
use std::time::Duration;

use v4l::buffer::Type;
use v4l::control::{Control, Value};
use v4l::io::mmap::Stream as MmapStream;
use v4l::io::traits::CaptureStream;
use v4l::video::Capture;
use v4l::{Device, FourCC};

use super::convert::to_frame;
use super::{
    unwrap_counter, CameraError, CameraInfo, CameraListing, FrameClock, FrameSource, PixelFormat,
    TimeAnchor,
};
use crate::frame::Frame;

/// V4L2_CID_EXPOSURE_AUTO (camera class base + 1).
const CID_EXPOSURE_AUTO: u32 = 0x009a_0901;
/// V4L2_CID_EXPOSURE_ABSOLUTE, in units of 100 µs.
const CID_EXPOSURE_ABSOLUTE: u32 = 0x009a_0902;
/// V4L2_EXPOSURE_MANUAL.
const EXPOSURE_MANUAL: i64 = 1;
/// Memory-mapped buffers queued on the device.
const N_BUFFERS: u32 = 4;

fn fourcc_of(format: PixelFormat) -> Option<FourCC> {
    Some(FourCC::new(match format {
        PixelFormat::Mono8 => b"GREY",
        PixelFormat::Mono10 => b"Y10 ",
        PixelFormat::Mono12 => b"Y12 ",
        PixelFormat::Mono16 => b"Y16 ",
        PixelFormat::Yuyv => b"YUYV",
        PixelFormat::Mono14 => return None,
    }))
}

fn format_of(fourcc: FourCC) -> Option<PixelFormat> {
    PixelFormat::ALL
        .into_iter()
        .find(|&f| fourcc_of(f) == Some(fourcc))
}

fn io_err(path: &Path, context: &str, e: std::io::Error) -> CameraError {
    CameraError::Backend {
        backend: "v4l2",
        message: format!("{}: {context}: {e}", path.display()),
    }
}

/// A V4L2 capture device streaming through mmap buffers.
pub struct V4l2Source {
    path: PathBuf,
    device: Device,
    stream: Option<MmapStream<'static>>,
    format: PixelFormat,
    stride: usize,
    info: CameraInfo,
    timeout: Duration,
    clock: TimeAnchor,
    last_seq: Option<(u64, u64)>,
    /// Whether the last frame carried the driver's timestamp.
    camera_stamped: bool,
}

impl std::fmt::Debug for V4l2Source {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("V4l2Source")
            .field("path", &self.path)
            .field("info", &self.info)
            .finish_non_exhaustive()
    }
}

impl V4l2Source {
    /// Opens a device node. A missing node gives [`CameraError::NoDevice`].
    pub fn open(path: &Path) -> Result<Self, CameraError> {
        if !path.exists() {
            return Err(CameraError::NoDevice {
                path: path.display().to_string(),
                hint: "no such device node; is the camera plugged in and its driver loaded? \
                       (`micropos camera list` shows the V4L2 devices found)"
                    .into(),
            });
        }
        let device = Device::with_path(path).map_err(|e| io_err(path, "opening", e))?;
        let caps = device
            .query_caps()
            .map_err(|e| io_err(path, "querying capabilities", e))?;
        if !caps
            .capabilities
            .contains(v4l::capability::Flags::VIDEO_CAPTURE)
        {
            return Err(CameraError::NotSupported {
                source_kind: "v4l2",
                what: format!("{} ({})", path.display(), caps.card),
                why: "the device cannot capture single-planar video".into(),
            });
        }
        let mut source = Self {
            path: path.to_path_buf(),
            device,
            stream: None,
            format: PixelFormat::Mono8,
            stride: 0,
            info: CameraInfo {
                backend: "v4l2",
                model: format!("{} ({})", caps.card, caps.driver),
                serial: caps.bus.clone(),
                width: 0,
                height: 0,
                pixel_format: String::new(),
                bit_depth: 8,
            },
            timeout: Duration::from_secs(2),
            clock: TimeAnchor::new(),
            camera_stamped: false,
            last_seq: None,
        };
        let current = source
            .device
            .format()
            .map_err(|e| io_err(path, "reading format", e))?;
        if format_of(current.fourcc).is_none() {
            let mut switched = false;
            for f in [PixelFormat::Mono8, PixelFormat::Mono16, PixelFormat::Yuyv] {
                if source.apply_format(f).is_ok() {
                    switched = true;
                    break;
                }
            }
            if !switched {
                return Err(CameraError::NotSupported {
                    source_kind: "v4l2",
                    what: format!("pixel format {}", current.fourcc),
                    why: "the device accepts none of GREY, Y16, YUYV".into(),
                });
            }
        } else {
            source.read_format()?;
        }
        Ok(source)
    }

    /// Reads the device's current format into `info`, `format`, `stride`.
    fn read_format(&mut self) -> Result<(), CameraError> {
        let f = self
            .device
            .format()
            .map_err(|e| io_err(&self.path, "reading format", e))?;
        let format = format_of(f.fourcc).ok_or_else(|| CameraError::NotSupported {
            source_kind: "v4l2",
            what: format!("pixel format {}", f.fourcc),
            why: "use GREY, Y10, Y12, Y16 or YUYV".into(),
        })?;
        self.format = format;
        self.stride = f.stride as usize;
        self.info.width = f.width as usize;
        self.info.height = f.height as usize;
        self.info.pixel_format = f.fourcc.to_string();
        self.info.bit_depth = format.bit_depth();
        Ok(())
    }

    fn apply_format(&mut self, format: PixelFormat) -> Result<(), CameraError> {
        let fourcc = fourcc_of(format).ok_or_else(|| CameraError::NotSupported {
            source_kind: "v4l2",
            what: format!("pixel format {format}"),
            why: "V4L2 has no 14-bit luma format".into(),
        })?;
        self.stream = None;
        let mut f = self
            .device
            .format()
            .map_err(|e| io_err(&self.path, "reading format", e))?;
        f.fourcc = fourcc;
        let got = self
            .device
            .set_format(&f)
            .map_err(|e| io_err(&self.path, "setting format", e))?;
        if got.fourcc != fourcc {
            return Err(CameraError::NotSupported {
                source_kind: "v4l2",
                what: format!("pixel format {format}"),
                why: format!("the driver answered with {}", got.fourcc),
            });
        }
        self.last_seq = None;
        self.read_format()
    }

    fn stream(&mut self) -> Result<&mut MmapStream<'static>, CameraError> {
        if self.stream.is_none() {
            let mut s = MmapStream::with_buffers(&self.device, Type::VideoCapture, N_BUFFERS)
                .map_err(|e| io_err(&self.path, "starting stream", e))?;
            // v4l converts to i32 milliseconds; stay inside that.
            s.set_timeout(self.timeout.min(Duration::from_secs(3600)));
            self.stream = Some(s);
        }
        self.stream.as_mut().ok_or_else(|| CameraError::Backend {
            backend: "v4l2",
            message: "stream vanished".into(),
        })
    }
}

impl FrameSource for V4l2Source {
    fn info(&self) -> CameraInfo {
        self.info.clone()
    }

    fn next_frame(&mut self) -> Result<Frame, CameraError> {
        let (format, width, height, stride) =
            (self.format, self.info.width, self.info.height, self.stride);
        let timeout = self.timeout;
        let path = self.path.clone();
        let stream = self.stream()?;
        let (data, meta) = match CaptureStream::next(stream) {
            Ok((d, m)) => {
                let used = (m.bytesused as usize).min(d.len());
                (d[..used].to_vec(), *m)
            }
            Err(e) => {
                // The v4l stream cannot resume after a failed dequeue:
                // restart it on the next call.
                self.stream = None;
                return Err(if e.kind() == std::io::ErrorKind::TimedOut {
                    CameraError::Timeout {
                        timeout_s: timeout.as_secs_f64(),
                    }
                } else {
                    io_err(&path, "capturing", e)
                });
            }
        };
        let cam_s = meta.timestamp.sec as f64 + meta.timestamp.usec as f64 * 1e-6;
        self.camera_stamped = cam_s > 0.0;
        let ts = self.clock.stamp(Some(cam_s));
        let raw = u64::from(meta.sequence);
        let seq = match self.last_seq {
            None => 0,
            Some((last, seq)) => unwrap_counter(last, raw, seq, 1 << 32),
        };
        self.last_seq = Some((raw, seq));
        to_frame(format, width, height, stride, &data, ts, seq)
    }

    /// The driver's timestamp (the kernel's monotonic clock at the frame,
    /// for most drivers), when the last frame carried one.
    fn frame_clock(&self) -> FrameClock {
        if self.camera_stamped {
            FrameClock::Camera
        } else {
            FrameClock::None
        }
    }

    fn set_timeout(&mut self, timeout: Duration) {
        self.timeout = timeout;
        if let Some(s) = self.stream.as_mut() {
            s.set_timeout(timeout.min(Duration::from_secs(3600)));
        }
    }

    fn set_exposure_us(&mut self, exposure_us: f64) -> Result<f64, CameraError> {
        let controls = self
            .device
            .query_controls()
            .map_err(|e| io_err(&self.path, "listing controls", e))?;
        let desc = controls
            .iter()
            .find(|c| c.id == CID_EXPOSURE_ABSOLUTE)
            .ok_or_else(|| CameraError::NotSupported {
                source_kind: "v4l2",
                what: "exposure control".into(),
                why: "the device has no exposure_time_absolute control".into(),
            })?;
        let units = (exposure_us / 100.0).round();
        let (min, max) = (desc.minimum as f64 * 100.0, desc.maximum as f64 * 100.0);
        if !(units >= desc.minimum as f64 && units <= desc.maximum as f64) {
            return Err(CameraError::OutOfRange {
                what: "exposure_us",
                value: exposure_us,
                min,
                max,
            });
        }
        if controls.iter().any(|c| c.id == CID_EXPOSURE_AUTO) {
            self.device
                .set_control(Control {
                    id: CID_EXPOSURE_AUTO,
                    value: Value::Integer(EXPOSURE_MANUAL),
                })
                .map_err(|e| io_err(&self.path, "switching exposure to manual", e))?;
        }
        self.device
            .set_control(Control {
                id: CID_EXPOSURE_ABSOLUTE,
                value: Value::Integer(units as i64),
            })
            .map_err(|e| io_err(&self.path, "setting exposure", e))?;
        self.exposure_us()
    }

    fn exposure_us(&self) -> Result<f64, CameraError> {
        let c = self
            .device
            .control(CID_EXPOSURE_ABSOLUTE)
            .map_err(|e| io_err(&self.path, "reading exposure", e))?;
        match c.value {
            Value::Integer(v) => Ok(v as f64 * 100.0),
            other => Err(CameraError::BadData(format!(
                "exposure control holds {other:?}"
            ))),
        }
    }

    fn set_gain_db(&mut self, _gain_db: f64) -> Result<f64, CameraError> {
        Err(CameraError::NotSupported {
            source_kind: "v4l2",
            what: "gain in dB".into(),
            why: "V4L2 gain controls have no defined unit; set the raw gain with v4l2-ctl".into(),
        })
    }

    fn pixel_formats(&self) -> Result<Vec<PixelFormat>, CameraError> {
        let formats = self
            .device
            .enum_formats()
            .map_err(|e| io_err(&self.path, "listing formats", e))?;
        Ok(formats.iter().filter_map(|d| format_of(d.fourcc)).collect())
    }

    fn set_pixel_format(&mut self, format: PixelFormat) -> Result<(), CameraError> {
        self.apply_format(format)
    }

    fn set_frame_rate_hz(&mut self, rate_hz: f64) -> Result<f64, CameraError> {
        if !(rate_hz.is_finite() && rate_hz > 0.0 && rate_hz < 1e6) {
            return Err(CameraError::OutOfRange {
                what: "frame_rate_hz",
                value: rate_hz,
                min: 0.0,
                max: 1e6,
            });
        }
        self.stream = None;
        let params = v4l::video::capture::Parameters::new(v4l::Fraction::new(
            1000,
            (rate_hz * 1000.0).round() as u32,
        ));
        let got = self
            .device
            .set_params(&params)
            .map_err(|e| io_err(&self.path, "setting frame rate", e))?;
        let (n, d) = (got.interval.numerator, got.interval.denominator);
        if n == 0 {
            return Err(CameraError::BadData(
                "driver reports a zero frame interval".into(),
            ));
        }
        Ok(f64::from(d) / f64::from(n))
    }
}

/// V4L2 capture devices under /dev.
pub fn list() -> Result<Vec<CameraListing>, CameraError> {
    let dev = Path::new("/dev");
    let entries = std::fs::read_dir(dev).map_err(|source| CameraError::Io {
        path: dev.to_path_buf(),
        source,
    })?;
    let mut paths: Vec<PathBuf> = entries
        .filter_map(Result::ok)
        .map(|e| e.path())
        .filter(|p| {
            p.file_name()
                .and_then(|n| n.to_str())
                .is_some_and(|n| n.starts_with("video"))
        })
        .collect();
    paths.sort();
    let mut out = Vec::new();
    for p in paths {
        let description = match Device::with_path(&p).and_then(|d| d.query_caps()) {
            Ok(c)
                if c.capabilities
                    .contains(v4l::capability::Flags::VIDEO_CAPTURE) =>
            {
                format!("{} ({}, {})", c.card, c.driver, c.bus)
            }
            Ok(_) => continue, // metadata or output node
            Err(e) => format!("cannot query: {e}"),
        };
        out.push(CameraListing {
            backend: "v4l2",
            source: format!("v4l2:{}", p.display()),
            description,
        });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fourcc_mapping() {
        assert_eq!(format_of(FourCC::new(b"GREY")), Some(PixelFormat::Mono8));
        assert_eq!(format_of(FourCC::new(b"Y16 ")), Some(PixelFormat::Mono16));
        assert_eq!(format_of(FourCC::new(b"YUYV")), Some(PixelFormat::Yuyv));
        assert_eq!(format_of(FourCC::new(b"MJPG")), None);
        assert_eq!(fourcc_of(PixelFormat::Mono14), None);
    }
}
