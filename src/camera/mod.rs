//! Frame sources: everything that hands the decoder a [`Frame`].
//!
//! Why one trait: the daemon, the CLI and the characterization runs must not
//! care whether frames come from a GigE Vision camera, a V4L2 device, a
//! directory of recorded images or the simulator. They all implement
//! [`FrameSource`]; the rest of micropos only sees frames with a timestamp,
//! a sequence number and a bit depth.
//!
//! Threading model: [`FrameSource::next_frame`] blocks (bounded by the
//! source's timeout), so the daemon calls it from a blocking thread
//! (`tokio::task::spawn_blocking` or a dedicated capture thread), never from
//! an async task. Sources are `Send` so they can move to that thread.
//!
//! Backends:
//! - [`files`]: replay of recorded runs (always compiled in);
//! - `v4l2` (cargo feature `v4l2`): Linux video devices through the `v4l` crate;
//! - `genicam` (cargo feature `genicam`): GigE Vision / USB3 Vision cameras
//!   through aravis.
//!
//! A simulated camera fits the same trait: its `next_frame` renders the
//! pattern at the current simulated time and stamps the frame with it.

pub mod convert;
pub mod files;
#[cfg(feature = "genicam")]
pub mod genicam;
pub mod simsocket;
pub mod source;
pub mod timebase;
#[cfg(feature = "v4l2")]
pub mod v4l2;

use std::fmt;
use std::path::PathBuf;
use std::str::FromStr;
use std::time::Duration;

use crate::frame::Frame;

pub use source::{
    unwrap_counter, CameraError, CameraInfo, CameraListing, FrameClock, FrameSource, PixelFormat,
    TimeAnchor,
};

/// Which source to open, parsed from the CLI/config string.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum SourceSpec {
    /// `v4l2[:/dev/videoN]`; default /dev/video0.
    V4l2 {
        /// Device node.
        path: PathBuf,
    },
    /// `genicam[:ID]`; without an id the first camera aravis finds.
    Genicam {
        /// Aravis device id ("Vendor-Model-Serial"), serial, or IP address.
        id: Option<String>,
    },
    /// `files:DIR_OR_GLOB_OR_FILE`: replay of recorded images.
    Files {
        /// Directory, single file or glob pattern (`*`, `?`, `[..]`).
        pattern: String,
    },
    /// `sim:PATH`: the simulated rig's camera socket (`hil-sim serve`).
    Sim {
        /// The Unix socket, e.g. `/tmp/rig/camera.sock`.
        path: PathBuf,
    },
}

impl FromStr for SourceSpec {
    type Err = CameraError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let bad = |reason: &str| CameraError::BadSpec {
            spec: s.to_string(),
            reason: reason.to_string(),
        };
        let (kind, rest) = match s.split_once(':') {
            Some((k, r)) => (k, Some(r)),
            None => (s, None),
        };
        match kind.trim().to_ascii_lowercase().as_str() {
            "v4l2" => {
                let path = rest
                    .map(str::trim)
                    .filter(|r| !r.is_empty())
                    .unwrap_or("/dev/video0");
                Ok(SourceSpec::V4l2 {
                    path: PathBuf::from(path),
                })
            }
            "genicam" | "aravis" => Ok(SourceSpec::Genicam {
                id: rest
                    .map(str::trim)
                    .filter(|r| !r.is_empty())
                    .map(str::to_string),
            }),
            "files" | "file" => match rest.filter(|r| !r.is_empty()) {
                Some(p) => Ok(SourceSpec::Files {
                    pattern: p.to_string(),
                }),
                None => Err(bad(
                    "files: needs a directory, file or glob, e.g. files:run1/*.png",
                )),
            },
            "sim" => match rest.map(str::trim).filter(|r| !r.is_empty()) {
                Some(p) => Ok(SourceSpec::Sim {
                    path: PathBuf::from(p),
                }),
                None => Err(bad(
                    "sim: needs the camera socket of hil-sim, e.g. sim:/tmp/rig/camera.sock",
                )),
            },
            _ => Err(bad(
                "expected v4l2:/dev/videoN, genicam[:ID], files:DIR_OR_GLOB or sim:SOCKET",
            )),
        }
    }
}

impl fmt::Display for SourceSpec {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SourceSpec::V4l2 { path } => write!(f, "v4l2:{}", path.display()),
            SourceSpec::Genicam { id: None } => f.write_str("genicam"),
            SourceSpec::Genicam { id: Some(id) } => write!(f, "genicam:{id}"),
            SourceSpec::Files { pattern } => write!(f, "files:{pattern}"),
            SourceSpec::Sim { path } => write!(f, "sim:{}", path.display()),
        }
    }
}

/// Options that apply when opening any source.
#[derive(Debug, Clone, PartialEq)]
pub struct OpenOptions {
    /// How long `next_frame` waits for a live camera.
    pub timeout: Duration,
    /// Replay options (ignored by live cameras).
    pub files: files::FileOptions,
}

impl Default for OpenOptions {
    fn default() -> Self {
        Self {
            timeout: Duration::from_secs(2),
            files: files::FileOptions::default(),
        }
    }
}

/// Opens the source `spec` names.
pub fn open_source(
    spec: &SourceSpec,
    options: &OpenOptions,
) -> Result<Box<dyn FrameSource>, CameraError> {
    let mut source: Box<dyn FrameSource> = match spec {
        SourceSpec::Files { pattern } => {
            Box::new(files::FileSource::open(pattern, options.files.clone())?)
        }
        SourceSpec::Sim { path } => Box::new(simsocket::SimSocketSource::open(path)?),
        #[cfg(feature = "v4l2")]
        SourceSpec::V4l2 { path } => Box::new(v4l2::V4l2Source::open(path)?),
        #[cfg(not(feature = "v4l2"))]
        SourceSpec::V4l2 { .. } => {
            return Err(CameraError::NotCompiled {
                backend: "v4l2",
                feature: "v4l2",
            })
        }
        #[cfg(feature = "genicam")]
        SourceSpec::Genicam { id } => Box::new(genicam::GenicamSource::open(id.as_deref())?),
        #[cfg(not(feature = "genicam"))]
        SourceSpec::Genicam { .. } => {
            return Err(CameraError::NotCompiled {
                backend: "genicam",
                feature: "genicam",
            })
        }
    };
    source.set_timeout(options.timeout);
    Ok(source)
}

/// Backends compiled into this build, and those that are not.
pub fn backends() -> (Vec<&'static str>, Vec<&'static str>) {
    let mut have = vec!["files"];
    let mut missing = Vec::new();
    if cfg!(feature = "v4l2") {
        have.push("v4l2");
    } else {
        missing.push("v4l2");
    }
    if cfg!(feature = "genicam") {
        have.push("genicam");
    } else {
        missing.push("genicam");
    }
    (have, missing)
}

/// Cameras of every compiled-in live backend. A backend that fails to
/// enumerate reports its error in place of its cameras, so one broken
/// backend does not hide the others.
pub fn list_cameras() -> Vec<(&'static str, Result<Vec<CameraListing>, CameraError>)> {
    type Lister = fn() -> Result<Vec<CameraListing>, CameraError>;
    let listers: &[(&'static str, Lister)] = &[
        #[cfg(feature = "v4l2")]
        ("v4l2", v4l2::list),
        #[cfg(feature = "genicam")]
        ("genicam", genicam::list),
    ];
    listers.iter().map(|(name, list)| (*name, list())).collect()
}

/// Mean pixel value of a frame in counts; a cheap exposure check for
/// `micropos camera stream`.
pub fn frame_mean(frame: &Frame) -> f64 {
    let n = (frame.width() * frame.height()) as f64;
    let sum: u64 = match frame.pixels() {
        crate::frame::Pixels::U8(p) => p.iter().map(|&v| u64::from(v)).sum(),
        crate::frame::Pixels::U16(p) => p.iter().map(|&v| u64::from(v)).sum(),
    };
    sum as f64 / n
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_source_specs() {
        assert_eq!(
            "sim:/tmp/rig/camera.sock".parse::<SourceSpec>().unwrap(),
            SourceSpec::Sim {
                path: "/tmp/rig/camera.sock".into()
            }
        );
        assert!("sim:".parse::<SourceSpec>().is_err());
        assert_eq!(
            SourceSpec::Sim {
                path: "/a/b".into()
            }
            .to_string(),
            "sim:/a/b"
        );
        assert_eq!(
            "v4l2:/dev/video3".parse::<SourceSpec>().unwrap(),
            SourceSpec::V4l2 {
                path: "/dev/video3".into()
            }
        );
        assert_eq!(
            "v4l2".parse::<SourceSpec>().unwrap(),
            SourceSpec::V4l2 {
                path: "/dev/video0".into()
            }
        );
        assert_eq!(
            "genicam".parse::<SourceSpec>().unwrap(),
            SourceSpec::Genicam { id: None }
        );
        assert_eq!(
            "genicam:Aravis-Fake-GV01".parse::<SourceSpec>().unwrap(),
            SourceSpec::Genicam {
                id: Some("Aravis-Fake-GV01".into())
            }
        );
        assert_eq!(
            "files:/data/run1/*.png".parse::<SourceSpec>().unwrap(),
            SourceSpec::Files {
                pattern: "/data/run1/*.png".into()
            }
        );
        // Colons after the first belong to the argument (IPv6, Windows-ish paths).
        assert_eq!(
            "files:a:b".parse::<SourceSpec>().unwrap(),
            SourceSpec::Files {
                pattern: "a:b".into()
            }
        );
        assert!(matches!(
            "files:".parse::<SourceSpec>(),
            Err(CameraError::BadSpec { .. })
        ));
        assert!(matches!(
            "usb:0".parse::<SourceSpec>(),
            Err(CameraError::BadSpec { .. })
        ));
        for s in ["v4l2:/dev/video1", "genicam", "genicam:x", "files:d"] {
            assert_eq!(s.parse::<SourceSpec>().unwrap().to_string(), s);
        }
    }

    #[test]
    fn parses_pixel_formats() {
        assert_eq!(
            "mono16".parse::<PixelFormat>().unwrap(),
            PixelFormat::Mono16
        );
        assert_eq!("GREY".parse::<PixelFormat>().unwrap(), PixelFormat::Mono8);
        assert_eq!("Y12".parse::<PixelFormat>().unwrap(), PixelFormat::Mono12);
        assert_eq!("YUYV".parse::<PixelFormat>().unwrap(), PixelFormat::Yuyv);
        assert!("RGB8".parse::<PixelFormat>().is_err());
        for f in PixelFormat::ALL {
            assert_eq!(f.genicam_name().parse::<PixelFormat>().unwrap(), f);
        }
        assert_eq!(PixelFormat::Mono12.bit_depth(), 12);
        assert_eq!(PixelFormat::Yuyv.bit_depth(), 8);
    }

    #[test]
    fn unwraps_counters() {
        // 64-bit counter with a gap of 2 dropped frames.
        assert_eq!(unwrap_counter(10, 13, 100, 0), 103);
        // 16-bit GigE block id wrapping from 65535 to 1 (0 is skipped).
        assert_eq!(unwrap_counter(0xFFFF, 1, 100, 0xFFFF), 101);
        assert_eq!(unwrap_counter(0xFFFE, 2, 100, 0xFFFF), 103);
        // Restart: counter jumps back a little, counts as one frame.
        assert_eq!(unwrap_counter(500, 3, 100, 0), 101);
        assert_eq!(unwrap_counter(u64::MAX, 3, u64::MAX, 0), u64::MAX);
    }

    #[test]
    fn time_anchor_follows_camera_clock() {
        let mut a = TimeAnchor::new();
        assert_eq!(a.stamp_at(Some(100.0), 0.5), 0.5);
        // Host jitter is ignored once anchored.
        assert_eq!(a.stamp_at(Some(100.25), 0.9), 0.75);
        // No camera stamp: host time.
        assert_eq!(a.stamp_at(None, 1.0), 1.0);
        // Camera clock reset: re-anchor.
        assert_eq!(a.stamp_at(Some(1.0), 2.0), 2.0);
        assert_eq!(a.stamp_at(Some(1.5), 2.1), 2.5);
    }

    #[test]
    fn frame_mean_counts() {
        let f = Frame::new(
            2,
            2,
            12,
            crate::frame::Pixels::U16(vec![0, 4095, 1, 4]),
            0.0,
            0,
        )
        .unwrap();
        assert_eq!(frame_mean(&f), 1025.0);
    }
}
