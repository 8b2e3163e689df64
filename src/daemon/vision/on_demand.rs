//! On-demand capture ([`Capture::OnDemand`](super::Capture::OnDemand)): one
//! task on the runtime grabs a frame only while a consumer waits, waits out
//! its exposure on the rig clock, and has it decoded by the decode worker.
//!
//! The decode worker is a thread of its own that owns the decoder and
//! decodes frames in the order they are handed to it. Two ways to wait for
//! it, and both keep the rig clock still while they wait:
//!
//! - the loop itself waits (a consumer that wants the measurement now,
//!   [`Vision::want`](super::Vision::want)): the wait runs on tokio's
//!   blocking pool, which holds the paused clock;
//! - a consumer takes the exposed frame with its decode still running
//!   ([`Vision::defer`](super::Vision::defer)) and goes on (a
//!   characterization moves to its next point); it waits later
//!   ([`Vision::finish`](super::Vision::finish)), again on the blocking
//!   pool, and only then is the measurement published.
//!
//! Why a thread and not the blocking pool for the decode itself: a task on
//! the blocking pool holds the virtual clock for as long as it runs, so a
//! decode there would stop the next move's timers until it ended. On the
//! worker the clock runs on while it decodes; nothing on the runtime sees
//! the decode until a consumer waits for it at a point of its own sequence
//! of events, so the rig's history is the same whichever finishes first
//! (only the wall time changes).

use super::{frame_time, publish, set, FrameTap, Measurement, Published, Stamp, VisionStats};
use crate::camera::timebase::CameraTimebase;
use crate::camera::FrameSource;
use crate::clock::RigClock;
use crate::frame::Frame;
use crate::pattern::decode::{DecodeError, Decoded, Decoder};
use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{mpsc, Arc, Mutex};
use tokio::sync::{oneshot, watch};

/// A decode's outcome.
pub(super) type DecodeResult = Result<Decoded, DecodeError>;

/// Consumers waiting for a frame.
#[derive(Debug, Default)]
pub(super) struct Demand {
    pub(super) waiters: AtomicUsize,
    /// Those of `waiters` that take every frame ([`Vision::want_stream`](super::Vision::want_stream)).
    pub(super) streams: AtomicUsize,
    /// Those of `waiters` that take the next exposed frame undecoded
    /// ([`Vision::defer`](super::Vision::defer)), first come first served.
    pub(super) deferred: Mutex<VecDeque<oneshot::Sender<Deferred>>>,
    pub(super) notify: tokio::sync::Notify,
}

impl Demand {
    /// The oldest deferred request whose consumer still waits.
    fn take_deferred(&self) -> Option<oneshot::Sender<Deferred>> {
        let mut q = self.deferred.lock().unwrap_or_else(|p| p.into_inner());
        while let Some(tx) = q.pop_front() {
            if !tx.is_closed() {
                return Some(tx);
            }
        }
        None
    }
}

/// Keeps on-demand capture grabbing while alive (see [`Vision::want`](super::Vision::want)).
#[derive(Debug)]
pub struct Want {
    pub(super) demand: Option<Arc<Demand>>,
    pub(super) stream: bool,
}

impl Drop for Want {
    fn drop(&mut self) {
        if let Some(d) = &self.demand {
            if self.stream {
                d.streams.fetch_sub(1, Ordering::SeqCst);
            }
            d.waiters.fetch_sub(1, Ordering::SeqCst);
        }
    }
}

/// A frame whose exposure has ended and whose decode the decode worker
/// runs while its consumer goes on ([`Vision::defer`](super::Vision::defer)).
/// Nothing is published until [`Vision::finish`](super::Vision::finish)
/// waits for it; a `Deferred` dropped unfinished is decoded and discarded
/// (its frame is counted, its decode is not).
#[derive(Debug)]
pub struct Deferred {
    pub(super) stamp: Stamp,
    reply: mpsc::Receiver<DecodeResult>,
}

impl Deferred {
    /// Rig time at which the frame's grab was requested, s (see
    /// [`Measurement::t_s`]).
    pub fn request_t_s(&self) -> f64 {
        self.stamp.request_t_s
    }

    /// Waits for the decode on the blocking pool (the rig clock stands
    /// still meanwhile); `None` when the worker ended without an answer.
    pub(super) async fn decoded(self) -> Option<DecodeResult> {
        wait(self.reply).await
    }
}

/// One frame for the decode worker and where its outcome goes.
struct Job {
    frame: Frame,
    reply: mpsc::SyncSender<DecodeResult>,
}

/// The decode worker's queue; the worker ends when this is dropped.
#[derive(Debug)]
pub(super) struct Worker {
    jobs: mpsc::Sender<Job>,
}

impl Worker {
    /// Starts the worker thread, owning `decoder`. Each decode is timed
    /// (wall, `decode_seconds`) and offered to the web view's tap; the
    /// outcome is not counted here but where it is published.
    pub(super) fn start(
        mut decoder: Decoder,
        stats: Arc<VisionStats>,
        tap: Arc<FrameTap>,
    ) -> std::io::Result<Worker> {
        let (jobs, rx) = mpsc::channel::<Job>();
        std::thread::Builder::new()
            .name("microposd-decode".into())
            .spawn(move || {
                while let Ok(Job { frame, reply }) = rx.recv() {
                    let t0 = std::time::Instant::now();
                    let frame = Arc::new(frame);
                    let r = decoder.decode_shared(&frame);
                    stats.decode_seconds.observe(t0.elapsed().as_secs_f64());
                    let frame = Arc::try_unwrap(frame).unwrap_or_else(|f| (*f).clone());
                    tap.offer(frame, &r);
                    // A consumer that went away leaves nobody to tell.
                    let _ = reply.send(r);
                }
            })?;
        Ok(Worker { jobs })
    }

    /// Queues `frame`; `None` when the worker has ended.
    fn submit(&self, frame: Frame) -> Option<mpsc::Receiver<DecodeResult>> {
        let (reply, rx) = mpsc::sync_channel(1);
        self.jobs.send(Job { frame, reply }).ok()?;
        Some(rx)
    }

    /// Decodes `frame` and waits for it with the clock held.
    async fn decode(&self, frame: Frame) -> Option<DecodeResult> {
        wait(self.submit(frame)?).await
    }
}

/// Waits for a decode on the blocking pool: tokio's paused clock does not
/// advance while a blocking task runs, so no timer fires during the wait
/// and the rig's history does not depend on how long the decode took.
/// (Awaiting an async channel here instead would let the clock jump to the
/// next timer whenever the runtime idles, at a wall-time-dependent point.)
async fn wait(rx: mpsc::Receiver<DecodeResult>) -> Option<DecodeResult> {
    tokio::task::spawn_blocking(move || rx.recv().ok())
        .await
        .ok()
        .flatten()
}

/// The state of the on-demand capture task.
pub(super) struct OnDemandLoop {
    pub(super) source: Box<dyn FrameSource>,
    pub(super) worker: Worker,
    pub(super) clock: Arc<dyn RigClock>,
    pub(super) tx: watch::Sender<Option<Measurement>>,
    pub(super) stats: Arc<VisionStats>,
    pub(super) last_error: Arc<std::sync::Mutex<Option<String>>>,
    pub(super) stop: Arc<AtomicBool>,
    pub(super) demand: Arc<Demand>,
    pub(super) timebase: CameraTimebase,
}

/// Pause after a failed grab before the next one, rig time: a camera that
/// fails at once must not spin, and a consumer's frame deadline must come.
const RETRY_AFTER_FAILED_GRAB: std::time::Duration = std::time::Duration::from_millis(50);

/// Grab while someone waits, wait out the exposure on the rig clock, then
/// either hand the exposed frame to a consumer that defers its decode, or
/// decode it (waiting with the clock held) and publish. While a consumer
/// takes every frame ([`Vision::want_stream`](super::Vision::want_stream))
/// the next frame is grabbed (rendered) on the blocking pool alongside the
/// current frame's decode: the clock stands still while either runs, the
/// grab is requested at the rig time it would be requested after the
/// publication (neither the decode nor the publication takes rig time), and
/// its exposure is waited out after the publication, so the consumer sees
/// each frame at the rig time it would see it with one task after the other.
pub(super) async fn on_demand_loop(mut l: OnDemandLoop) {
    // A frame whose exposure has ended, not decoded yet.
    let mut exposed: Option<(Frame, Stamp)> = None;
    loop {
        if l.stop.load(Ordering::Relaxed) {
            return;
        }
        let Some((frame, stamp)) = exposed.take() else {
            if l.demand.waiters.load(Ordering::SeqCst) == 0 {
                let notified = l.demand.notify.notified();
                tokio::pin!(notified);
                notified.as_mut().enable();
                if l.demand.waiters.load(Ordering::SeqCst) == 0 {
                    tokio::select! {
                        () = notified => {}
                        () = l.tx.closed() => return,
                    }
                }
                continue;
            }
            // Before the grab: see the module docs of `vision`.
            let t = l.clock.now_s();
            let Some((source, grabbed)) = grab_blocking(l.source).await else {
                set(&l.last_error, "camera: the grab task failed".to_owned());
                return;
            };
            l.source = source;
            let Some(e) = l.expose(grabbed, t).await else {
                return;
            };
            exposed = e;
            continue;
        };
        if let Some(consumer) = l.demand.take_deferred() {
            let Some(reply) = l.worker.submit(frame) else {
                set(&l.last_error, "decode: the decode worker ended".to_owned());
                return;
            };
            // A consumer gone meanwhile drops it: decoded, not published.
            let _ = consumer.send(Deferred { stamp, reply });
            // As after a publication (below): the consumer drops its `Want`
            // before the next round looks at the demand.
            tokio::task::yield_now().await;
            continue;
        }
        let decode = l.worker.decode(frame);
        let t = l.clock.now_s();
        let (decoded, ahead) = if l.demand.streams.load(Ordering::SeqCst) > 0 {
            let (decoded, grabbed) = tokio::join!(decode, grab_blocking(l.source));
            let Some((source, grabbed)) = grabbed else {
                set(&l.last_error, "camera: the grab task failed".to_owned());
                return;
            };
            l.source = source;
            (decoded, Some(grabbed))
        } else {
            (decode.await, None)
        };
        let Some(decoded) = decoded else {
            set(&l.last_error, "decode: the decode worker ended".to_owned());
            return;
        };
        match publish(decoded, stamp, &l.stats, &l.last_error, &l.tx) {
            Published::Closed => return,
            // Let the consumers the frame woke run first: one that had all
            // it needs drops its `Want` before the next round looks at the
            // demand (without this every measurement rendered and decoded a
            // second frame nobody asked for).
            Published::Sent(_) => tokio::task::yield_now().await,
            Published::Failed => {}
        }
        if let Some(grabbed) = ahead {
            let Some(e) = l.expose(grabbed, t).await else {
                return;
            };
            exposed = e;
        }
    }
}

/// What a grab gives the on-demand loop: a frame and how long until its
/// exposure ends on the rig clock (`None`: it has ended).
type Grabbed = Result<(Frame, Option<std::time::Duration>), crate::camera::CameraError>;

/// One grab on the blocking pool; the source comes back with it. `None`
/// when the task failed (a panic in the source).
async fn grab_blocking(
    mut source: Box<dyn FrameSource>,
) -> Option<(Box<dyn FrameSource>, Grabbed)> {
    tokio::task::spawn_blocking(move || {
        let r = source.next_frame();
        let ready = source.frame_ready_after();
        (source, r.map(|f| (f, ready)))
    })
    .await
    .ok()
}

impl OnDemandLoop {
    /// Waits out the exposure of the frame grabbed at rig time
    /// `request_s` (a source on a virtual clock renders at once; the frame
    /// exists only when its exposure has ended) and stamps it: `Some(None)`
    /// after a failed grab (counted, the error kept, the retry pause
    /// waited), `None` when the source ended.
    async fn expose(&mut self, grabbed: Grabbed, request_s: f64) -> Option<Option<(Frame, Stamp)>> {
        let (frame, ready) = match grabbed {
            Ok(g) => g,
            Err(e) => {
                self.stats.camera_errors.fetch_add(1, Ordering::Relaxed);
                set(&self.last_error, format!("camera: {e}"));
                if matches!(e, crate::camera::CameraError::EndOfStream { .. }) {
                    tracing::warn!("camera source ended: {e}");
                    return None;
                }
                self.clock.sleep(RETRY_AFTER_FAILED_GRAB).await;
                return Some(None);
            }
        };
        if let Some(d) = ready {
            self.clock.sleep(d).await;
        }
        self.stats.frames.fetch_add(1, Ordering::Relaxed);
        let frame_t_s = frame_time(
            self.source.frame_clock(),
            &frame,
            request_s,
            self.clock.now_s(),
            &mut self.timebase,
            &self.stats,
        );
        let stamp = Stamp {
            request_t_s: request_s,
            frame_t_s,
            sequence: frame.sequence,
        };
        Some(Some((frame, stamp)))
    }
}

#[cfg(test)]
mod tests {
    use super::super::{Capture, Vision};
    use crate::camera::{CameraError, CameraInfo, FrameSource};
    use crate::clock::{RigClock, WallClock};
    use crate::frame::Frame;
    use crate::pattern::decode::{DecodeOptions, Decoder};
    use crate::pattern::render::{Pose, RenderConfig, Renderer};
    use std::sync::atomic::Ordering;
    use std::sync::Arc;
    use std::time::Duration;

    /// Frame `k` of the scripted camera: the pattern at `pose(k)` with
    /// noise seed `k`, or blank (undecodable) for a `k` in `blank`. Each
    /// frame is ready 10 ms of rig time after its request.
    #[derive(Debug)]
    struct Scripted {
        r: Renderer,
        k: u64,
        blank: Vec<u64>,
    }

    fn pose(k: u64) -> Pose {
        Pose {
            x_um: 20_000.0 + 37.3 * k as f64,
            y_um: 9_000.0 - 11.9 * k as f64,
            theta_rad: 0.3,
            pixel_um: 0.9,
            mirrored: false,
        }
    }

    fn frame(r: &mut Renderer, k: u64) -> Frame {
        r.render(&pose(k), k, 0.0, k).unwrap()
    }

    impl FrameSource for Scripted {
        fn info(&self) -> CameraInfo {
            CameraInfo {
                backend: "files",
                model: "scripted".to_owned(),
                serial: String::new(),
                width: self.r.config().width,
                height: self.r.config().height,
                pixel_format: "Mono8".to_owned(),
                bit_depth: 8,
            }
        }
        fn next_frame(&mut self) -> Result<Frame, CameraError> {
            let k = self.k;
            self.k += 1;
            let f = frame(&mut self.r, k);
            if self.blank.contains(&k) {
                let (w, h) = (f.width(), f.height());
                let px = crate::frame::Pixels::U8(vec![0; w * h]);
                return Ok(Frame::new(w, h, 8, px, 0.0, k).unwrap());
            }
            Ok(f)
        }
        fn set_timeout(&mut self, _timeout: Duration) {}
        fn frame_ready_after(&self) -> Option<Duration> {
            Some(Duration::from_millis(10))
        }
    }

    /// A deferred frame is handed over when its exposure ends, undecoded
    /// and unpublished; the rig clock runs on meanwhile; `finish` gives and
    /// publishes the very measurement a decoder gives for that frame. A
    /// blank frame's `finish` is an error, counted as a failed decode. The
    /// on-demand path that decodes before publishing works as before.
    #[tokio::test(start_paused = true)]
    async fn a_deferred_frame_is_decoded_beside_the_clock_and_published_when_finished() {
        let opts = DecodeOptions::new(9.0, 12);
        let src = Scripted {
            r: Renderer::new(RenderConfig::default()).unwrap(),
            k: 0,
            blank: vec![1],
        };
        let clock: Arc<dyn RigClock> = Arc::new(WallClock::since(tokio::time::Instant::now()));
        let v = Vision::start_with(
            Box::new(src),
            opts.clone(),
            clock.clone(),
            Capture::OnDemand,
        )
        .unwrap();
        let mut r = Renderer::new(RenderConfig::default()).unwrap();
        let mut reference = Decoder::new(opts).unwrap();

        let (want, rx) = v.defer().unwrap();
        let d = rx.await.unwrap();
        drop(want);
        assert_eq!(d.request_t_s(), 0.0);
        assert!((clock.now_s() - 0.010).abs() < 1e-9, "{}", clock.now_s());
        assert_eq!(v.stats.frames.load(Ordering::SeqCst), 1);
        assert_eq!(v.stats.decoded.load(Ordering::SeqCst), 0);
        assert!(v.latest.borrow().is_none(), "published before finish");
        // The job moves on: rig time passes while the frame decodes.
        clock.sleep(Duration::from_secs(2)).await;
        assert!((clock.now_s() - 2.010).abs() < 1e-9);
        let m = v.finish(d).await.unwrap();
        let want0 = reference.decode(&frame(&mut r, 0)).unwrap();
        assert_eq!(
            (m.x_um, m.y_um, m.quality),
            (want0.x_um, want0.y_um, want0.quality)
        );
        assert_eq!(m.t_s, 0.0);
        assert_eq!(v.stats.decoded.load(Ordering::SeqCst), 1);
        assert_eq!(*v.latest.borrow(), Some(m));
        // Finishing took no rig time.
        assert!((clock.now_s() - 2.010).abs() < 1e-9);

        // Frame 1 is blank.
        let (want, rx) = v.defer().unwrap();
        let d = rx.await.unwrap();
        drop(want);
        let e = v.finish(d).await.unwrap_err();
        assert!(e.contains("decode"), "{e}");
        assert_eq!(v.stats.failed.load(Ordering::SeqCst), 1);
        assert_eq!(
            *v.latest.borrow(),
            Some(m),
            "a failed decode publishes nothing"
        );

        // Frame 2 through the path that decodes before it publishes.
        let mut rx = v.latest.clone();
        rx.borrow_and_update();
        let want = v.want();
        rx.changed().await.unwrap();
        drop(want);
        let m2 = rx.borrow().unwrap();
        let want2 = reference.decode(&frame(&mut r, 2)).unwrap();
        assert_eq!((m2.x_um, m2.y_um), (want2.x_um, want2.y_um));
        assert_eq!(m2.sequence, 2);
        assert_eq!(v.stats.decoded.load(Ordering::SeqCst), 2);
    }
}
