//! Camera capture and decoding, off the async runtime, in one of two modes
//! ([`Capture`]). Free-running (hardware): one thread blocks in
//! [`FrameSource::next_frame`], one thread decodes (keeping only the newest
//! frame, so a slow decoder drops frames instead of building a backlog).
//! On demand (the simulator's in-process rig on a virtual clock): one task
//! grabs and decodes on the blocking pool only while a consumer waits
//! ([`Vision::want`]); for a consumer that takes every frame
//! ([`Vision::want_stream`]) it grabs the next frame alongside the current
//! decode. Both publish [`Measurement`]s on a `watch` channel.
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

use crate::camera::timebase::CameraTimebase;
use crate::camera::{FrameClock, FrameSource};
use crate::clock::RigClock;
use crate::daemon::protocol::{CameraClock, CameraStatus, VisionMeasurement};
use crate::frame::Frame;
use crate::pattern::decode::{DecodeOptions, Decoder};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{mpsc, Arc};
use std::thread;
use tokio::sync::watch;

mod on_demand;
pub use on_demand::{Deferred, Want};
use on_demand::{Demand, OnDemandLoop, Worker};

/// One vision measurement of the pattern point under the image centre.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Measurement {
    /// Rig time at which the frame's grab was requested, s. On a triggered
    /// camera (the simulator, a software-triggered grab) the exposure
    /// began no earlier, so `t_s >= T` means "exposed after `T`".
    pub t_s: f64,
    /// The frame's own timestamp on the rig clock, s, by the source's
    /// [`FrameSource::frame_clock`]: the camera's stamp as it is when the
    /// camera's clock is the rig's (the simulator's camera: the exposure
    /// mid-point plus the camera's latency and jitter); a camera's own
    /// clock mapped onto the rig clock ([`CameraTimebase`]: its origin and
    /// rate removed, the shortest stamp-to-arrival delay left as a
    /// constant); else `t_s`. The sweep characterization times frames by
    /// it and estimates the constant delay.
    pub frame_t_s: f64,
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

/// `x` wrapped into (−π, π], rad: the difference of two decoded angles as
/// a turn. Why: the decoder's θ is in (−π, π], so a pattern mounted near
/// ±π gives angles on both ends for one orientation.
pub fn wrap_angle_rad(x: f64) -> f64 {
    let pi = std::f64::consts::PI;
    let w = (x + pi).rem_euclid(std::f64::consts::TAU) - pi;
    if w == -pi {
        pi
    } else {
        w
    }
}

impl Measurement {
    /// As replies and events carry it.
    pub fn to_reply(&self) -> VisionMeasurement {
        VisionMeasurement {
            t_s: self.t_s,
            frame_t_s: self.frame_t_s,
            sequence: self.sequence,
            x_um: self.x_um,
            y_um: self.y_um,
            theta_rad: self.theta_rad,
            quality: self.quality,
        }
    }
}

/// Counters of the pipeline, for `status` and `/metrics`.
#[derive(Debug)]
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
    /// Wall time of each decode, s (`micropos_vision_decode_seconds`).
    /// Why wall time even on a virtual rig clock: decoding is CPU work,
    /// and its cost is what a lab watches.
    pub decode_seconds: prometheus_client::metrics::histogram::Histogram,
    /// The camera clock's map onto the rig clock, for a source with a clock
    /// of its own ([`FrameClock::Camera`]): rate error (ppm, rig seconds
    /// per camera second − 1) and how often the map started over.
    pub camera_clock: std::sync::Mutex<Option<(f64, u64)>>,
}

impl Default for VisionStats {
    fn default() -> Self {
        VisionStats {
            frames: AtomicU64::new(0),
            decoded: AtomicU64::new(0),
            failed: AtomicU64::new(0),
            camera_errors: AtomicU64::new(0),
            dropped: AtomicU64::new(0),
            // 0.5 ms … 4 s: a warm decode of a VGA frame is a few ms, a
            // cold 5 MP one a few hundred.
            decode_seconds: prometheus_client::metrics::histogram::Histogram::new(
                prometheus_client::metrics::histogram::exponential_buckets(0.0005, 2.0, 14),
            ),
            camera_clock: std::sync::Mutex::new(None),
        }
    }
}

/// The newest frame and what its decode found, kept for the web view's
/// camera image ([`FrameTap`]).
#[derive(Debug, Clone)]
pub struct Snapshot {
    /// The frame as grabbed.
    pub frame: Arc<Frame>,
    /// Its decode, if it decoded: position, angle, quality, the fine grid.
    pub decoded: Option<SnapshotDecode>,
}

/// The parts of a decode the camera view overlays.
#[derive(Debug, Clone, Copy)]
pub struct SnapshotDecode {
    /// Pattern x, µm.
    pub x_um: f64,
    /// Pattern y, µm.
    pub y_um: f64,
    /// Angle, rad.
    pub theta_rad: f64,
    /// Pixel size on the pattern, µm.
    pub pixel_um: f64,
    /// Quality, bits.
    pub quality: f64,
    /// The fine grid (wave vectors and phases at the image centre).
    pub grid: crate::pattern::decode::Grid,
}

/// Hands the decode path's newest frame to the web view without ever
/// making decode wait: the decode thread only `try_lock`s and keeps the
/// newest frame (the frame it already owns, moved into an `Arc`: no copy
/// of the pixels).
///
/// Why always, not only while a page watches: a page's first camera
/// request must find a frame to show (else the image stays black until a
/// later poll), and on the in-process rig (on-demand capture) frames exist
/// only while something measures, so the view shows the last measured one.
/// The cost is one frame's memory; the decode path drops the frame it
/// replaces instead of the one it just decoded.
#[derive(Debug, Default)]
pub struct FrameTap {
    latest: std::sync::Mutex<Option<Snapshot>>,
}

impl FrameTap {
    /// The newest kept snapshot.
    pub fn latest(&self) -> Option<Snapshot> {
        self.latest.lock().ok().and_then(|g| g.clone())
    }

    /// Keeps `frame` and its decode; skips when the web view holds the
    /// lock (the decode path never waits).
    fn offer(
        &self,
        frame: Frame,
        decoded: &Result<crate::pattern::decode::Decoded, crate::pattern::decode::DecodeError>,
    ) {
        if let Ok(mut g) = self.latest.try_lock() {
            *g = Some(Snapshot {
                frame: Arc::new(frame),
                decoded: decoded.as_ref().ok().map(|d| SnapshotDecode {
                    x_um: d.x_um,
                    y_um: d.y_um,
                    theta_rad: d.theta_rad,
                    pixel_um: d.pixel_um,
                    quality: d.quality,
                    grid: d.grid,
                }),
            });
        }
    }
}

/// The running pipeline.
#[derive(Debug)]
pub struct Vision {
    /// The newest measurement.
    pub latest: watch::Receiver<Option<Measurement>>,
    /// Counters.
    pub stats: Arc<VisionStats>,
    /// The newest frame for the web view (always the newest decoded).
    pub tap: Arc<FrameTap>,
    /// The last camera or decode error, readable.
    pub last_error: Arc<std::sync::Mutex<Option<String>>>,
    stop: Arc<AtomicBool>,
    /// Present when frames are grabbed on demand ([`Capture::OnDemand`]).
    demand: Option<Arc<Demand>>,
    /// Where [`Vision::finish`] publishes a deferred frame's decode
    /// (on-demand capture only).
    publisher: Option<watch::Sender<Option<Measurement>>>,
}

/// How frames are captured.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Capture {
    /// A capture thread grabs frame after frame and a decode thread decodes
    /// the newest: a real camera free-runs, and the position stream shows
    /// vision between jobs.
    #[default]
    FreeRunning,
    /// One task on the runtime grabs a frame only while a consumer waits for
    /// one ([`Vision::want`]), waits on the rig clock until the source says
    /// the frame's exposure ended, and decodes it on the blocking pool.
    ///
    /// Why: on the simulator's in-process rig the clock is virtual (it
    /// advances only when every task waits on a timer), so a free-running
    /// capture thread would render frames at whatever simulated instant the
    /// OS scheduled it, and draw camera noise in that order: the same seed
    /// would give different figures. Grabbing only on demand, from the
    /// runtime, makes every frame's time and noise a function of the job's
    /// own sequence of events. It also spends simulated time on exposures
    /// only when someone measures (a 9.5-hour run does not render 30 frames
    /// a simulated second).
    OnDemand,
}

impl Vision {
    /// Says that the caller waits for fresh frames until the returned guard
    /// is dropped. A free-running pipeline grabs anyway; an on-demand one
    /// grabs only while some guard lives. Every consumer that waits for a
    /// frame exposed after some time holds one.
    pub fn want(&self) -> Want {
        self.want_inner(false)
    }

    /// [`Vision::want`] for a consumer that takes every frame while the
    /// guard lives (a sweep films its whole pass). Why it is told apart:
    /// an on-demand pipeline then grabs (renders) the next frame while it
    /// decodes the current one, on the two cores at once, since that frame
    /// is wanted anyway. For a consumer that wants one fresh frame (a
    /// measurement at a settled point) that grab would be a frame nobody
    /// asked for, so [`Vision::want`] never starts it.
    pub fn want_stream(&self) -> Want {
        self.want_inner(true)
    }

    fn want_inner(&self, stream: bool) -> Want {
        if let Some(d) = &self.demand {
            if stream {
                d.streams.fetch_add(1, Ordering::SeqCst);
            }
            d.waiters.fetch_add(1, Ordering::SeqCst);
            d.notify.notify_one();
        }
        Want {
            demand: self.demand.clone(),
            stream,
        }
    }

    /// Asks for the next frame exposed from now on, handed over as soon as
    /// its exposure has ended with its decode still running on the decode
    /// worker; [`Vision::finish`] waits for it and publishes it. `None` for
    /// a free-running pipeline, which decodes the newest frame anyway.
    ///
    /// Why: a step characterization needs the decode of one point only for
    /// its log record, not to move on. On the simulator's virtual clock the
    /// move to the next point (the controllers' poll, the settle) and the
    /// next frame's render then run beside the decode on the machine's
    /// cores, while the rig's history (every time, every noise draw) stays
    /// what it is with one after the other (see `on_demand`). The consumer
    /// holds the returned [`Want`] until the frame arrives.
    pub fn defer(&self) -> Option<(Want, tokio::sync::oneshot::Receiver<Deferred>)> {
        let d = self.demand.as_ref()?;
        let (tx, rx) = tokio::sync::oneshot::channel();
        d.deferred
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .push_back(tx);
        Some((self.want(), rx))
    }

    /// Waits for a deferred frame's decode (the rig clock stands still
    /// meanwhile) and publishes it as the on-demand loop publishes its own
    /// frames: counted, streamed, judged. `Err` says why there is no
    /// measurement (the decode failed, the worker ended); a frame below
    /// `camera.min_quality` is the caller's to judge.
    pub async fn finish(&self, d: Deferred) -> Result<Measurement, String> {
        let stamp = d.stamp;
        let Some(decoded) = d.decoded().await else {
            let why = "decode: the decode worker ended".to_owned();
            set(&self.last_error, why.clone());
            return Err(why);
        };
        let Some(tx) = &self.publisher else {
            return Err("a free-running pipeline defers nothing".to_owned());
        };
        match publish(decoded, stamp, &self.stats, &self.last_error, tx) {
            Published::Sent(m) => Ok(m),
            Published::Failed => Err(self
                .last_error_text()
                .unwrap_or_else(|| "decode failed".to_owned())),
            Published::Closed => Err("the camera pipeline ended".to_owned()),
        }
    }

    /// The last camera or decode error, if any.
    pub fn last_error_text(&self) -> Option<String> {
        self.last_error
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .clone()
    }

    /// True when frames are grabbed on demand and nobody waits for one: no
    /// frame arriving then says nothing about the camera's health.
    pub fn is_idle(&self) -> bool {
        self.demand
            .as_ref()
            .is_some_and(|d| d.waiters.load(Ordering::SeqCst) == 0)
    }

    /// Starts the pipeline in `capture` mode. [`Capture::OnDemand`] must be
    /// called inside a tokio runtime (it spawns its task there).
    pub fn start_with(
        source: Box<dyn FrameSource>,
        opts: DecodeOptions,
        clock: Arc<dyn RigClock>,
        capture: Capture,
    ) -> Result<Vision, crate::pattern::decode::DecodeError> {
        match capture {
            Capture::FreeRunning => Self::start(source, opts, clock),
            Capture::OnDemand => Self::start_on_demand(source, opts, clock),
        }
    }

    fn start_on_demand(
        source: Box<dyn FrameSource>,
        opts: DecodeOptions,
        clock: Arc<dyn RigClock>,
    ) -> Result<Vision, crate::pattern::decode::DecodeError> {
        let decoder = Decoder::new(opts)?;
        let (tx, rx) = watch::channel(None);
        let stats = Arc::new(VisionStats::default());
        let last_error = Arc::new(std::sync::Mutex::new(None::<String>));
        let stop = Arc::new(AtomicBool::new(false));
        let demand = Arc::new(Demand::default());
        let tap = Arc::new(FrameTap::default());
        let worker = Worker::start(decoder, stats.clone(), tap.clone()).map_err(|e| {
            crate::pattern::decode::DecodeError::Options(format!(
                "cannot start the decode thread: {e}"
            ))
        })?;
        tokio::spawn(on_demand::on_demand_loop(OnDemandLoop {
            source,
            worker,
            clock,
            tx: tx.clone(),
            stats: stats.clone(),
            last_error: last_error.clone(),
            stop: stop.clone(),
            demand: demand.clone(),
            timebase: CameraTimebase::new(),
        }));
        Ok(Vision {
            latest: rx,
            stats,
            tap,
            last_error,
            stop,
            demand: Some(demand),
            publisher: Some(tx),
        })
    }

    /// Starts capture and decode threads ([`Capture::FreeRunning`]).
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
        let (ftx, frx) = mpsc::sync_channel::<(f64, f64, Frame)>(1);
        let tap = Arc::new(FrameTap::default());
        {
            let stats = stats.clone();
            let stop = stop.clone();
            let last_error = last_error.clone();
            thread::Builder::new()
                .name("microposd-capture".into())
                .spawn(move || {
                    let mut timebase = CameraTimebase::new();
                    while !stop.load(Ordering::Relaxed) {
                        // Before the grab: see the module docs.
                        let t = clock.now_s();
                        match source.next_frame() {
                            Ok(frame) => {
                                stats.frames.fetch_add(1, Ordering::Relaxed);
                                // Every frame teaches the camera clock's
                                // map, dropped or not.
                                let frame_t = frame_time(
                                    source.frame_clock(),
                                    &frame,
                                    t,
                                    clock.now_s(),
                                    &mut timebase,
                                    &stats,
                                );
                                if let Err(mpsc::TrySendError::Full(_)) =
                                    ftx.try_send((t, frame_t, frame))
                                {
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
            let tap = tap.clone();
            thread::Builder::new()
                .name("microposd-decode".into())
                .spawn(move || {
                    // Ends when the capture thread ends (sender dropped).
                    while let Ok((t_s, frame_t_s, frame)) = frx.recv() {
                        // Cold decode of every frame: tracking assumes
                        // less than half a period of motion between frames,
                        // which a job's steps (5-500 µm between frames on a
                        // simulated clock that jumps) break; measured on the
                        // sim rig, tracked frames after a step slipped by
                        // whole periods (12 × 4 µm) without failing the
                        // code check.
                        let t0 = std::time::Instant::now();
                        let decoded = decoder.decode(&frame);
                        stats.decode_seconds.observe(t0.elapsed().as_secs_f64());
                        let stamp = Stamp {
                            request_t_s: t_s,
                            frame_t_s,
                            sequence: frame.sequence,
                        };
                        tap.offer(frame, &decoded);
                        let out = publish(decoded, stamp, &stats, &last_error, &tx);
                        if out == Published::Closed {
                            break;
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
            tap,
            last_error,
            stop,
            demand: None,
            publisher: None,
        })
    }

    /// Status (`status.camera`).
    pub fn to_reply(&self) -> CameraStatus {
        let s = &self.stats;
        CameraStatus {
            frames: s.frames.load(Ordering::Relaxed),
            decoded: s.decoded.load(Ordering::Relaxed),
            failed: s.failed.load(Ordering::Relaxed),
            camera_errors: s.camera_errors.load(Ordering::Relaxed),
            dropped: s.dropped.load(Ordering::Relaxed),
            last_error: self.last_error.lock().map(|g| g.clone()).unwrap_or(None),
            latest: (*self.latest.borrow()).map(|m| m.to_reply()),
            camera_clock: s
                .camera_clock
                .lock()
                .ok()
                .and_then(|g| *g)
                .map(|(rate_ppm, resets)| CameraClock { rate_ppm, resets }),
        }
    }
}

/// The rig time of a frame (see [`Measurement::frame_t_s`]): its own stamp
/// when that is on the rig clock, the camera's stamp mapped onto the rig
/// clock by `timebase` (which learns from this frame's `arrival_s`), else
/// the grab's request time.
fn frame_time(
    clock: FrameClock,
    frame: &Frame,
    request_s: f64,
    arrival_s: f64,
    timebase: &mut CameraTimebase,
    stats: &VisionStats,
) -> f64 {
    match clock {
        FrameClock::Rig => frame.timestamp_s,
        FrameClock::None => request_s,
        FrameClock::Camera => {
            let t = timebase
                .observe(frame.timestamp_s, arrival_s)
                .unwrap_or(request_s);
            if let Ok(mut g) = stats.camera_clock.lock() {
                *g = Some(((timebase.rate() - 1.0) * 1e6, timebase.resets()));
            }
            t
        }
    }
}

impl Drop for Vision {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(d) = &self.demand {
            d.notify.notify_one();
        }
    }
}

/// What became of one decoded frame.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Published {
    /// A measurement went out.
    Sent(Measurement),
    /// The decode failed (counted, the error kept).
    Failed,
    /// Nobody listens any more: the pipeline ends.
    Closed,
}

/// When a frame was grabbed and exposed (see [`Measurement`]).
#[derive(Debug, Clone, Copy)]
struct Stamp {
    request_t_s: f64,
    frame_t_s: f64,
    sequence: u64,
}

/// Counts a decode's outcome and publishes its measurement, stamped with
/// the rig time its grab was requested and the frame's own time: the one
/// place both capture modes turn a decode into a [`Measurement`].
fn publish(
    decoded: Result<crate::pattern::decode::Decoded, crate::pattern::decode::DecodeError>,
    stamp: Stamp,
    stats: &VisionStats,
    last_error: &std::sync::Mutex<Option<String>>,
    tx: &watch::Sender<Option<Measurement>>,
) -> Published {
    match decoded {
        Ok(d) => {
            stats.decoded.fetch_add(1, Ordering::Relaxed);
            let m = Measurement {
                t_s: stamp.request_t_s,
                frame_t_s: stamp.frame_t_s,
                sequence: stamp.sequence,
                x_um: d.x_um,
                y_um: d.y_um,
                theta_rad: d.theta_rad,
                quality: d.quality,
            };
            if tx.send(Some(m)).is_err() {
                Published::Closed
            } else {
                Published::Sent(m)
            }
        }
        Err(e) => {
            stats.failed.fetch_add(1, Ordering::Relaxed);
            set(last_error, format!("decode: {e}"));
            Published::Failed
        }
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

/// The pipeline's counters [`HealthWatch`] judges (from [`VisionStats`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct HealthCounts {
    /// Frames that arrived from the camera.
    pub frames: u64,
    /// Frames decoded.
    pub decoded: u64,
    /// Decodes that ended in an error.
    pub failed: u64,
}

impl HealthCounts {
    /// The counters now.
    pub fn of(stats: &VisionStats) -> Self {
        HealthCounts {
            frames: stats.frames.load(Ordering::Relaxed),
            decoded: stats.decoded.load(Ordering::Relaxed),
            failed: stats.failed.load(Ordering::Relaxed),
        }
    }
}

/// Turns the pipeline's counters into [`Health`] transitions. Pure: the
/// caller passes the counters and the time.
///
/// A frame is judged by its decode's outcome, not by its arrival: a frame
/// that arrived just before a window ends is still being decoded (on a
/// loaded machine, for a good part of a second), and counting it as
/// undecodable reported a camera that had just come back from a stall as
/// `undecodable` before `ok`.
#[derive(Debug, Clone)]
pub struct HealthWatch {
    at: HealthCounts,
    since: tokio::time::Instant,
    state: Health,
}

impl HealthWatch {
    /// Starts watching at `now` with the counters as they are (healthy
    /// until a window passes without a decoded frame).
    pub fn new(v: &Vision, now: tokio::time::Instant) -> Self {
        HealthWatch {
            at: HealthCounts::of(&v.stats),
            since: now,
            state: Health::Ok,
        }
    }

    /// Starts a new window at `now` without judging the one that ends: an
    /// on-demand pipeline nobody asked for frames delivers none, which says
    /// nothing about the camera.
    pub fn rest(&mut self, c: HealthCounts, now: tokio::time::Instant) {
        self.at = c;
        self.since = now;
    }

    /// The new state if it changed: `Ok` as soon as a frame decodes;
    /// `Stalled` once `window` passed without a frame; `Undecodable` once
    /// it passed with decodes that all failed, or (a decoder that finishes
    /// nothing) two windows passed with frames arriving and no decode
    /// ending either way.
    pub fn update(
        &mut self,
        c: HealthCounts,
        window: std::time::Duration,
        now: tokio::time::Instant,
    ) -> Option<Health> {
        let waited = now.duration_since(self.since);
        let new = if c.decoded != self.at.decoded {
            Health::Ok
        } else if waited < window {
            return None;
        } else if c.frames == self.at.frames {
            Health::Stalled
        } else if c.failed != self.at.failed || waited >= 2 * window {
            Health::Undecodable
        } else {
            // Frames arrived, none decoded yet: their decodes are under way.
            return None;
        };
        // Each window is judged on its own counters.
        self.rest(c, now);
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
    use std::time::Duration;
    use tokio::time::Instant;

    fn c(frames: u64, decoded: u64, failed: u64) -> HealthCounts {
        HealthCounts {
            frames,
            decoded,
            failed,
        }
    }

    /// A watch healthy at `t0` with counters `start`, a 2 s window, and
    /// the time `ms` milliseconds after `t0`.
    fn watch(start: HealthCounts) -> (HealthWatch, Duration, impl Fn(u64) -> Instant) {
        let t0 = Instant::now();
        let h = HealthWatch {
            at: start,
            since: t0,
            state: Health::Ok,
        };
        (h, Duration::from_secs(2), move |ms| {
            t0 + Duration::from_millis(ms)
        })
    }

    #[test]
    fn health_transitions() {
        let (mut h, w, at) = watch(c(0, 0, 0));
        assert_eq!(h.update(c(3, 3, 0), w, at(1000)), None);
        // Frames keep coming, none decode: undecodable after the window.
        assert_eq!(h.update(c(6, 3, 3), w, at(2000)), None);
        assert_eq!(h.update(c(9, 3, 6), w, at(4000)), Some(Health::Undecodable));
        // Then nothing arrives at all: stalled.
        assert_eq!(h.update(c(9, 3, 6), w, at(6000)), Some(Health::Stalled));
        assert_eq!(h.update(c(9, 3, 6), w, at(9000)), None);
        // One decoded frame: ok at once.
        assert_eq!(h.update(c(10, 4, 6), w, at(9100)), Some(Health::Ok));
    }

    /// A camera back from a stall whose first frame is still being decoded
    /// when the window ends is not undecodable: it is ok once the decode
    /// ends. A decoder that never finishes is undecodable after two windows.
    #[test]
    fn a_frame_still_being_decoded_is_not_undecodable() {
        let (mut h, w, at) = watch(c(5, 5, 0));
        assert_eq!(h.update(c(5, 5, 0), w, at(2000)), Some(Health::Stalled));
        // Back: a frame arrived just before the window's end, in decode.
        assert_eq!(h.update(c(6, 5, 0), w, at(4000)), None);
        assert_eq!(h.update(c(7, 6, 0), w, at(4300)), Some(Health::Ok));
        // Frames arrive, no decode ever ends (a stuck decoder).
        assert_eq!(h.update(c(9, 6, 0), w, at(6300)), None);
        assert_eq!(h.update(c(20, 6, 0), w, at(8299)), None);
        assert_eq!(
            h.update(c(21, 6, 0), w, at(8300)),
            Some(Health::Undecodable)
        );
    }

    /// Each kind of source clock gives the frame time its docs promise: the
    /// rig's stamp as it is, the request time for a source without a
    /// clock, and a camera's own clock (any origin, 300 ppm fast, arrivals
    /// 2–5 ms late) mapped onto the rig clock with a constant delay, the
    /// rate reported in the status.
    #[test]
    fn frame_times_follow_the_source_clock() {
        let frame =
            |t: f64| Frame::new(2, 2, 8, crate::frame::Pixels::U8(vec![0; 4]), t, 0).unwrap();
        let stats = VisionStats::default();
        let mut tb = CameraTimebase::new();
        let f = frame(123.5);
        assert_eq!(
            frame_time(FrameClock::Rig, &f, 1.0, 2.0, &mut tb, &stats),
            123.5
        );
        assert_eq!(
            frame_time(FrameClock::None, &f, 1.0, 2.0, &mut tb, &stats),
            1.0
        );
        assert!(stats.camera_clock.lock().unwrap().is_none());
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for k in 0..3000 {
            let t = 20.0 + k as f64 / 50.0;
            let stamp = (t + 86_400.0) * (1.0 + 300e-6);
            let arrival = t + 0.002 + 0.003 * ((k * 7919) % 101) as f64 / 100.0;
            let m = frame_time(
                FrameClock::Camera,
                &frame(stamp),
                t - 0.04,
                arrival,
                &mut tb,
                &stats,
            );
            if k >= 1000 {
                lo = lo.min(m - t);
                hi = hi.max(m - t);
            }
        }
        assert!(hi - lo < 5e-5, "mapped delay spread {} s", hi - lo);
        assert!((lo - 0.002).abs() < 1e-4, "constant delay {lo} s");
        let (rate_ppm, resets) = stats.camera_clock.lock().unwrap().unwrap();
        assert!((rate_ppm + 300.0).abs() < 5.0, "rate {rate_ppm} ppm");
        assert_eq!(resets, 0);
    }
}
