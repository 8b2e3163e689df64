//! Camera capture and decoding, off the async runtime: one thread blocks in
//! [`FrameSource::next_frame`], one thread decodes (keeping only the newest
//! frame, so a slow decoder drops frames instead of building a backlog) and
//! publishes [`Measurement`]s on a `watch` channel.
//!
//! Each measurement carries the rig time at which its grab was requested,
//! so a consumer can refuse stale data, and the decoder's quality, so it can
//! refuse doubtful data. A failed decode publishes nothing new: the last
//! measurement simply ages.
//!
//! Why the request time and not the arrival time: a grab that was already
//! in flight when a move settled (exposed before or during the move) arrives
//! *after* the settle, because rendering/transfer and decoding take time. A
//! consumer that wants a frame exposed after time `T` must ask for
//! `t_s >= T`; stamping arrival times let such frames through (a
//! characterization logged the previous point's position).

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
    /// Rig time at which the frame's grab was requested, s. On a triggered
    /// camera (the simulator, a software-triggered grab) the exposure
    /// began no earlier, so `t_s >= T` means "exposed after `T`".
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
                        // Before the grab: see the module docs.
                        let t = clock.now_s();
                        match source.next_frame() {
                            Ok(frame) => {
                                stats.frames.fetch_add(1, Ordering::Relaxed);
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

/// What the camera pipeline delivers, judged over a window of wall time
/// (`camera` events: a lab wants to hear that the camera stopped, not find
/// out when a job or a closed-loop move fails).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Health {
    /// Frames decode.
    Ok,
    /// No frame arrived during the window.
    Stalled,
    /// Frames arrived during the window but none decoded.
    Undecodable,
}

impl Health {
    /// The name sent in `camera` events.
    pub fn as_str(self) -> &'static str {
        match self {
            Health::Ok => "ok",
            Health::Stalled => "stalled",
            Health::Undecodable => "undecodable",
        }
    }
}

/// Turns the pipeline's counters into [`Health`] transitions. Pure: the
/// caller passes the counters and the time.
#[derive(Debug, Clone)]
pub struct HealthWatch {
    frames: u64,
    decoded: u64,
    since: std::time::Instant,
    state: Health,
}

impl HealthWatch {
    /// Starts watching at `now` with the counters as they are (healthy
    /// until a window passes without a decoded frame).
    pub fn new(v: &Vision, now: std::time::Instant) -> Self {
        HealthWatch {
            frames: v.stats.frames.load(Ordering::Relaxed),
            decoded: v.stats.decoded.load(Ordering::Relaxed),
            since: now,
            state: Health::Ok,
        }
    }

    /// The new state if it changed: `Ok` as soon as a frame decodes;
    /// `Stalled` / `Undecodable` once `window` passed without one.
    pub fn update(
        &mut self,
        frames: u64,
        decoded: u64,
        window: std::time::Duration,
        now: std::time::Instant,
    ) -> Option<Health> {
        let new = if decoded != self.decoded {
            Health::Ok
        } else if now.duration_since(self.since) >= window {
            if frames != self.frames {
                Health::Undecodable
            } else {
                Health::Stalled
            }
        } else {
            return None;
        };
        // Each window is judged on its own counters.
        self.frames = frames;
        self.decoded = decoded;
        self.since = now;
        if new == self.state {
            return None;
        }
        self.state = new;
        Some(new)
    }
}

fn set(slot: &std::sync::Mutex<Option<String>>, msg: String) {
    if let Ok(mut g) = slot.lock() {
        *g = Some(msg);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::{Duration, Instant};

    #[test]
    fn health_transitions() {
        let t0 = Instant::now();
        let w = Duration::from_secs(2);
        let mut h = HealthWatch {
            frames: 0,
            decoded: 0,
            since: t0,
            state: Health::Ok,
        };
        assert_eq!(h.update(3, 3, w, t0 + Duration::from_secs(1)), None);
        // Frames keep coming, none decode: undecodable after the window.
        assert_eq!(h.update(6, 3, w, t0 + Duration::from_secs(2)), None);
        assert_eq!(
            h.update(9, 3, w, t0 + Duration::from_secs(4)),
            Some(Health::Undecodable)
        );
        // Then nothing arrives at all: stalled.
        assert_eq!(
            h.update(9, 3, w, t0 + Duration::from_secs(6)),
            Some(Health::Stalled)
        );
        assert_eq!(h.update(9, 3, w, t0 + Duration::from_secs(9)), None);
        // One decoded frame: ok at once.
        assert_eq!(
            h.update(10, 4, w, t0 + Duration::from_millis(9100)),
            Some(Health::Ok)
        );
    }
}
