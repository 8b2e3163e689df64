//! What every frame source is and says: the [`FrameSource`] trait, its
//! errors, pixel formats, descriptions, and the timestamp and frame-counter
//! helpers the camera backends share. Its own file so the backends import
//! it without importing the module that opens them (`camera/mod.rs`).

use std::fmt;
use std::path::PathBuf;
use std::str::FromStr;
use std::time::Duration;

use serde::Serialize;
use thiserror::Error;

use crate::frame::{Frame, FrameError};

/// Why a frame source could not open, deliver a frame or change a setting.
#[derive(Debug, Error)]
pub enum CameraError {
    /// The source cannot do what was asked (e.g. set exposure on a replay).
    #[error("{what} is not supported by the {source_kind} source: {why}")]
    NotSupported {
        /// Which source kind ("files", "v4l2", "genicam").
        source_kind: &'static str,
        /// What was asked for ("exposure control", "pixel format Mono12", …).
        what: String,
        /// Why not, so the user knows what to do instead.
        why: String,
    },
    /// The named device does not exist.
    #[error("no device {path}: {hint}")]
    NoDevice {
        /// The device path or camera id that was asked for.
        path: String,
        /// What to check.
        hint: String,
    },
    /// No frame arrived within the source's timeout.
    #[error("no frame within {timeout_s:.3} s")]
    Timeout {
        /// The timeout that expired, in seconds.
        timeout_s: f64,
    },
    /// A finite source (replay without loop) has delivered all its frames.
    #[error("end of stream: all {frames} frames delivered")]
    EndOfStream {
        /// How many frames the source delivered in total.
        frames: u64,
    },
    /// Reading a file or a directory failed.
    #[error("{path}: {source}")]
    Io {
        /// The file or directory involved.
        path: PathBuf,
        /// The underlying error.
        #[source]
        source: std::io::Error,
    },
    /// An image file could not be decoded or does not fit the stream.
    #[error("{path}: {reason}")]
    Decode {
        /// The offending file.
        path: PathBuf,
        /// What is wrong with it.
        reason: String,
    },
    /// A camera buffer does not match its declared format.
    #[error("bad frame data: {0}")]
    BadData(String),
    /// The camera backend reported an error.
    #[error("{backend}: {message}")]
    Backend {
        /// "v4l2" or "genicam".
        backend: &'static str,
        /// The backend's message, with context.
        message: String,
    },
    /// The source string asks for a backend this binary was built without.
    #[error("the {backend} backend is not compiled in (rebuild with `--features {feature}`)")]
    NotCompiled {
        /// Backend name.
        backend: &'static str,
        /// Cargo feature that enables it.
        feature: &'static str,
    },
    /// A source specification string could not be understood.
    #[error("bad source {spec:?}: {reason}")]
    BadSpec {
        /// The string as given.
        spec: String,
        /// Why it was rejected.
        reason: String,
    },
    /// A requested setting is outside what the camera accepts.
    #[error("{what} = {value} is outside the camera's range [{min}, {max}]")]
    OutOfRange {
        /// The setting.
        what: &'static str,
        /// Requested value.
        value: f64,
        /// Smallest accepted value.
        min: f64,
        /// Largest accepted value.
        max: f64,
    },
    /// The assembled pixels do not make a valid frame.
    #[error(transparent)]
    Frame(#[from] FrameError),
}

/// Pixel formats micropos can take from a camera. All are converted to a
/// grayscale [`Frame`]; colour cameras are not useful for phase decoding.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize)]
pub enum PixelFormat {
    /// 8-bit luma (GenICam Mono8, V4L2 GREY).
    Mono8,
    /// 10-bit luma in 16-bit little-endian containers (GenICam Mono10, V4L2 Y10).
    Mono10,
    /// 12-bit luma in 16-bit little-endian containers (GenICam Mono12, V4L2 Y12).
    Mono12,
    /// 14-bit luma in 16-bit little-endian containers (GenICam Mono14).
    Mono14,
    /// 16-bit little-endian luma (GenICam Mono16, V4L2 Y16).
    Mono16,
    /// Packed 4:2:2 Y0 U Y1 V (V4L2 YUYV, GenICam YUV422_8); only luma is kept.
    Yuyv,
}

impl PixelFormat {
    /// Every supported format, in order of preference for decoding (deepest
    /// monochrome first is not always best: more bits cost bandwidth, so the
    /// daemon keeps whatever the camera is set to unless told otherwise).
    pub const ALL: [PixelFormat; 6] = [
        PixelFormat::Mono8,
        PixelFormat::Mono10,
        PixelFormat::Mono12,
        PixelFormat::Mono14,
        PixelFormat::Mono16,
        PixelFormat::Yuyv,
    ];

    /// Significant bits per pixel of the luma the frame will carry.
    pub fn bit_depth(self) -> u8 {
        match self {
            PixelFormat::Mono8 | PixelFormat::Yuyv => 8,
            PixelFormat::Mono10 => 10,
            PixelFormat::Mono12 => 12,
            PixelFormat::Mono14 => 14,
            PixelFormat::Mono16 => 16,
        }
    }

    /// The GenICam (PFNC) name, as cameras spell it.
    pub fn genicam_name(self) -> &'static str {
        match self {
            PixelFormat::Mono8 => "Mono8",
            PixelFormat::Mono10 => "Mono10",
            PixelFormat::Mono12 => "Mono12",
            PixelFormat::Mono14 => "Mono14",
            PixelFormat::Mono16 => "Mono16",
            PixelFormat::Yuyv => "YUV422_8",
        }
    }
}

impl fmt::Display for PixelFormat {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.genicam_name())
    }
}

impl FromStr for PixelFormat {
    type Err = CameraError;

    /// Accepts GenICam names (Mono8, Mono16, YUV422_8, …) and V4L2 fourccs
    /// (GREY, Y10, Y12, Y16, YUYV), case-insensitively.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let t = s.trim().to_ascii_lowercase();
        Ok(match t.as_str() {
            "mono8" | "grey" | "gray" | "y8" | "y800" => PixelFormat::Mono8,
            "mono10" | "y10" => PixelFormat::Mono10,
            "mono12" | "y12" => PixelFormat::Mono12,
            "mono14" | "y14" => PixelFormat::Mono14,
            "mono16" | "y16" => PixelFormat::Mono16,
            "yuyv" | "yuv422_8" | "yuv422_yuyv_packed" | "yuy2" => PixelFormat::Yuyv,
            _ => {
                return Err(CameraError::BadSpec {
                    spec: s.to_string(),
                    reason:
                        "unknown pixel format; use Mono8, Mono10, Mono12, Mono14, Mono16 or YUYV"
                            .into(),
                })
            }
        })
    }
}

/// What a source is and what it delivers.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CameraInfo {
    /// Backend kind: "files", "v4l2" or "genicam".
    pub backend: &'static str,
    /// Vendor and model as the camera reports them (a path for replays).
    pub model: String,
    /// Serial number or device path; empty when unknown.
    pub serial: String,
    /// Frame width in pixels.
    pub width: usize,
    /// Frame height in pixels.
    pub height: usize,
    /// Pixel format the camera delivers (before conversion to luma).
    pub pixel_format: String,
    /// Significant bits per pixel of the frames this source produces.
    pub bit_depth: u8,
}

/// A camera found by [`list_cameras`].
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct CameraListing {
    /// Backend kind.
    pub backend: &'static str,
    /// The `--source` string that opens this camera.
    pub source: String,
    /// Human description (vendor, model, serial, address).
    pub description: String,
}

/// A source of frames. Implementations block in [`FrameSource::next_frame`]
/// for at most their timeout.
///
/// Controls have default implementations that return
/// [`CameraError::NotSupported`], so a source only implements what it
/// really has and callers get a clear message for the rest.
pub trait FrameSource: Send + fmt::Debug {
    /// What this source is and what it delivers.
    fn info(&self) -> CameraInfo;

    /// The next frame. Blocks until one is available, the timeout expires
    /// ([`CameraError::Timeout`]) or a finite source runs out
    /// ([`CameraError::EndOfStream`]). A failed frame does not end the
    /// stream: callers may call again.
    fn next_frame(&mut self) -> Result<Frame, CameraError>;

    /// How long [`FrameSource::next_frame`] waits before giving up.
    fn set_timeout(&mut self, timeout: Duration);

    /// For a source on a virtual clock: how long after the request the frame
    /// last returned by [`FrameSource::next_frame`] became available (the
    /// wait for its frame slot plus its exposure), which the caller must
    /// spend on the rig clock before using it. `None` (every real camera):
    /// `next_frame` itself waited for the frame in real time.
    ///
    /// Why: the simulator's in-process camera renders a frame at once, at
    /// the simulated instant its exposure will have reached; under a virtual
    /// clock only the caller can let that time pass, by sleeping on the same
    /// clock as everything else.
    fn frame_ready_after(&self) -> Option<Duration> {
        None
    }

    /// What clock the last frame's [`Frame::timestamp_s`] is on (see
    /// [`FrameClock`]); the vision pipeline turns it into a rig time.
    fn frame_clock(&self) -> FrameClock {
        FrameClock::None
    }

    /// Sets the exposure time and returns the value the camera applied
    /// (cameras round to their own increments).
    fn set_exposure_us(&mut self, exposure_us: f64) -> Result<f64, CameraError> {
        let _ = exposure_us;
        Err(self.not_supported("exposure control", "this source has no exposure setting"))
    }

    /// Current exposure time.
    fn exposure_us(&self) -> Result<f64, CameraError> {
        Err(self.not_supported("exposure control", "this source has no exposure setting"))
    }

    /// Sets the analog gain in dB and returns the applied value.
    fn set_gain_db(&mut self, gain_db: f64) -> Result<f64, CameraError> {
        let _ = gain_db;
        Err(self.not_supported("gain control", "this source has no gain setting"))
    }

    /// Current gain in dB.
    fn gain_db(&self) -> Result<f64, CameraError> {
        Err(self.not_supported("gain control", "this source has no gain setting"))
    }

    /// Switches the camera's pixel format. Frames after the call use it.
    fn set_pixel_format(&mut self, format: PixelFormat) -> Result<(), CameraError> {
        Err(self.not_supported(
            &format!("pixel format {format}"),
            "this source's pixel format is fixed",
        ))
    }

    /// Pixel formats this source can be switched to.
    fn pixel_formats(&self) -> Result<Vec<PixelFormat>, CameraError> {
        Err(self.not_supported(
            "pixel format listing",
            "this source's pixel format is fixed",
        ))
    }

    /// Sets the acquisition frame rate and returns the applied rate.
    fn set_frame_rate_hz(&mut self, rate_hz: f64) -> Result<f64, CameraError> {
        let _ = rate_hz;
        Err(self.not_supported(
            "frame rate control",
            "this source has no frame rate setting",
        ))
    }

    /// Builds the [`CameraError::NotSupported`] error for this source.
    fn not_supported(&self, what: &str, why: &str) -> CameraError {
        CameraError::NotSupported {
            source_kind: self.info().backend,
            what: what.to_string(),
            why: why.to_string(),
        }
    }
}

/// What clock a source's frame timestamps are on: it decides how the vision
/// pipeline times a frame on the rig clock
/// (`daemon::vision::Measurement::frame_t_s`), which the sweep
/// characterization places frames by.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum FrameClock {
    /// No clock of its own (files, the socket camera): the grab's request
    /// time stands in, and a sweep's delay estimate absorbs the
    /// difference along with the transfer's jitter.
    #[default]
    None,
    /// The camera's own clock (a GigE Vision camera's tick counter, the
    /// kernel's V4L2 stamp), seconds since the source opened
    /// ([`TimeAnchor`]): free of host jitter, but with its own origin and
    /// rate, which [`timebase::CameraTimebase`] maps onto the rig clock.
    Camera,
    /// The rig's clock itself: the simulator's in-process camera, whose
    /// clock is the rig's. Passed on as it is.
    Rig,
}

/// Turns camera frame timestamps into source timestamps: seconds since the
/// source was opened, taken from the host's monotonic clock at the first
/// frame and advanced by the camera's own clock after that, so host
/// scheduling jitter does not enter the frame intervals. A camera clock that
/// goes backwards (camera restarted) re-anchors on the host clock.
#[derive(Debug, Clone)]
pub struct TimeAnchor {
    opened: std::time::Instant,
    origin: Option<(f64, f64)>,
}

impl TimeAnchor {
    /// Starts the source clock now.
    pub fn new() -> Self {
        Self {
            opened: std::time::Instant::now(),
            origin: None,
        }
    }

    /// Source timestamp for a frame stamped `camera_s` by the camera (None
    /// when the camera gives no timestamp).
    pub fn stamp(&mut self, camera_s: Option<f64>) -> f64 {
        let host_s = self.opened.elapsed().as_secs_f64();
        self.stamp_at(camera_s, host_s)
    }

    /// [`TimeAnchor::stamp`] with the host time given, for tests.
    pub fn stamp_at(&mut self, camera_s: Option<f64>, host_s: f64) -> f64 {
        let Some(cam) = camera_s.filter(|c| c.is_finite() && *c > 0.0) else {
            return host_s;
        };
        match self.origin {
            Some((cam0, host0)) if cam >= cam0 => host0 + (cam - cam0),
            _ => {
                self.origin = Some((cam, host_s));
                host_s
            }
        }
    }
}

impl Default for TimeAnchor {
    fn default() -> Self {
        Self::new()
    }
}

/// Unwraps a camera frame counter that wraps at `modulus` (0 = 64-bit, no
/// wrap) into a monotonically increasing sequence number, so gaps (dropped
/// frames) stay visible across wraps. Returns the new sequence number.
///
/// `last` is the previous raw counter, `seq` the previous sequence number. A
/// counter that goes backwards without wrapping (camera restarted) counts as
/// one step.
pub fn unwrap_counter(last: u64, raw: u64, seq: u64, modulus: u64) -> u64 {
    let delta = if raw > last {
        raw - last
    } else if modulus != 0 && last < modulus && raw < modulus && last - raw > modulus / 2 {
        // Wrapped: counters like the GigE Vision 16-bit block id skip 0,
        // which the caller encodes by passing modulus = 0xFFFF and ids 1..=0xFFFF.
        modulus - last + raw
    } else {
        1
    };
    seq.saturating_add(delta)
}
