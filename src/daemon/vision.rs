//! Camera capture and decoding, off the async runtime: one thread blocks in
//! [`FrameSource::next_frame`], one thread decodes (keeping only the newest
//! frame, so a slow decoder drops frames instead of building a backlog) and
//! publishes [`Measurement`]s on a `watch` channel.
//!
//! Each measurement carries the rig time at which its frame arrived, so a
//! consumer can refuse stale data, and the decoder's quality, so it can
//! refuse doubtful data. A failed decode publishes nothing new: the last
//! measurement simply ages.

use crate::camera::FrameSource;
use crate::clock::RigClock;
use crate::frame::Frame;
use crate::pattern::decode::{DecodeOptions, Decoder};
use serde_json::{json, Value};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{mpsc, Arc};
use std::thread;
use tokio::sync::watch;

/// One vision measurement of the pattern point under the image centre.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Measurement {
    /// Rig time the frame arrived, s.
    pub t_s: f64,
    /// Camera frame sequence number.
    pub sequence: u64,
    /// Pattern x, µm (pattern frame, not yet the stage frame).
    pub x_um: f64,
    /// Pattern y, µm.
    pub y_um: f64,
    /// Pattern angle, rad.
    pub theta_rad: f64,
    /// Decoder quality (smaller code margin, bits).
    pub quality: f64,
}

impl Measurement {
    /// As JSON for replies and events.
    pub fn to_json(&self) -> Value {
        json!({"t_s": self.t_s, "sequence": self.sequence, "x_um": self.x_um, "y_um": self.y_um,
               "theta_rad": self.theta_rad, "quality": self.quality})
    }
}

/// Counters of the pipeline, for `status`.
#[derive(Debug, Default)]
pub struct VisionStats {
    /// Frames received.
    pub frames: AtomicU64,
    /// Frames decoded.
    pub decoded: AtomicU64,
    /// Decodes that failed.
    pub failed: AtomicU64,
    /// Frames the camera did not deliver (timeouts, errors).
    pub camera_errors: AtomicU64,
    /// Frames dropped because the decoder was busy.
    pub dropped: AtomicU64,
}

/// The running pipeline.
#[derive(Debug)]
pub struct Vision {
    /// The newest measurement.
    pub latest: watch::Receiver<Option<Measurement>>,
    /// Counters.
    pub stats: Arc<VisionStats>,
    /// The last camera or decode error, readable.
    pub last_error: Arc<std::sync::Mutex<Option<String>>>,
    stop: Arc<AtomicBool>,
}

impl Vision {
    /// Starts capture and decode threads.
    pub fn start(
        mut source: Box<dyn FrameSource>,
        opts: DecodeOptions,
        clock: Arc<dyn RigClock>,
    ) -> Result<Vision, crate::pattern::decode::DecodeError> {
        let mut decoder = Decoder::new(opts)?;
        let (tx, rx) = watch::channel(None);
        let stats = Arc::new(VisionStats::default());
        let last_error = Arc::new(std::sync::Mutex::new(None::<String>));
        let stop = Arc::new(AtomicBool::new(false));
        let (ftx, frx) = mpsc::sync_channel::<(f64, Frame)>(1);
        {
            let stats = stats.clone();
            let stop = stop.clone();
            let last_error = last_error.clone();
            thread::Builder::new()
                .name("microposd-capture".into())
                .spawn(move || {
                    while !stop.load(Ordering::Relaxed) {
                        // The rig time *before* the request: the frame was
                        // exposed no earlier (request-driven sources such as
                        // the simulator's socket), so "fresh after t" checks
                        // never accept a frame exposed before a settle ended.
                        // Stamping on arrival did: a 1.5 MB frame requested
                        // before a move arrived after the settle advance and
                        // passed as fresh (measured: one point in three of a
                        // sim characterization showed the previous point).
                        let t_request = clock.now_s();
                        match source.next_frame() {
                            Ok(frame) => {
                                stats.frames.fetch_add(1, Ordering::Relaxed);
                                let t = t_request;
                                if let Err(mpsc::TrySendError::Full(_)) = ftx.try_send((t, frame)) {
                                    stats.dropped.fetch_add(1, Ordering::Relaxed);
                                }
                            }
                            Err(e) => {
                                stats.camera_errors.fetch_add(1, Ordering::Relaxed);
                                set(&last_error, format!("camera: {e}"));
                                if matches!(e, crate::camera::CameraError::EndOfStream { .. }) {
                                    tracing::warn!("camera source ended: {e}");
                                    break;
                                }
                                // Do not spin on a camera that fails at once.
                                thread::sleep(std::time::Duration::from_millis(50));
                            }
                        }
                    }
                })
                .map_err(|e| {
                    crate::pattern::decode::DecodeError::Options(format!(
                        "cannot start the capture thread: {e}"
                    ))
                })?;
        }
        {
            let stats = stats.clone();
            let last_error = last_error.clone();
            thread::Builder::new()
                .name("microposd-decode".into())
                .spawn(move || {
                    // Ends when the capture thread ends (sender dropped).
                    while let Ok((t_s, frame)) = frx.recv() {
                        // Cold decode of every frame: tracking assumes
                        // less than half a period of motion between frames,
                        // which a job's steps (5-500 µm between frames on a
                        // simulated clock that jumps) break; measured on the
                        // sim rig, tracked frames after a step slipped by
                        // whole periods (12 × 4 µm) without failing the
                        // code check.
                        match decoder.decode(&frame) {
                            Ok(d) => {
                                stats.decoded.fetch_add(1, Ordering::Relaxed);
                                let m = Measurement {
                                    t_s,
                                    sequence: frame.sequence,
                                    x_um: d.x_um,
                                    y_um: d.y_um,
                                    theta_rad: d.theta_rad,
                                    quality: d.quality,
                                };
                                if tx.send(Some(m)).is_err() {
                                    break;
                                }
                            }
                            Err(e) => {
                                stats.failed.fetch_add(1, Ordering::Relaxed);
                                set(&last_error, format!("decode: {e}"));
                            }
                        }
                    }
                })
                .map_err(|e| {
                    crate::pattern::decode::DecodeError::Options(format!(
                        "cannot start the decode thread: {e}"
                    ))
                })?;
        }
        Ok(Vision {
            latest: rx,
            stats,
            last_error,
            stop,
        })
    }

    /// Status as JSON.
    pub fn to_json(&self) -> Value {
        let s = &self.stats;
        json!({
            "frames": s.frames.load(Ordering::Relaxed),
            "decoded": s.decoded.load(Ordering::Relaxed),
            "failed": s.failed.load(Ordering::Relaxed),
            "camera_errors": s.camera_errors.load(Ordering::Relaxed),
            "dropped": s.dropped.load(Ordering::Relaxed),
            "last_error": self.last_error.lock().map(|g| g.clone()).unwrap_or(None),
            "latest": (*self.latest.borrow()).map(|m| m.to_json()),
        })
    }
}

impl Drop for Vision {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
    }
}

fn set(slot: &std::sync::Mutex<Option<String>>, msg: String) {
    if let Ok(mut g) = slot.lock() {
        *g = Some(msg);
    }
}
