//! A second thread for the decoder's two data-parallel loops (the
//! demodulation's tile sums, the code lattices' bilinear samples).
//!
//! Why a persistent thread with owned buffers rather than a scoped thread
//! per frame: starting a thread allocates, and a warm decoder allocates
//! nothing per frame (`tests/decode_alloc.rs`); the crate forbids `unsafe`,
//! so the helper cannot borrow the caller's frame either. It reads the frame
//! through an `Arc` the caller lends for one decode
//! ([`super::Decoder::decode_shared`]), and each job carries its own tables
//! and output buffers, moved in and out of one slot (a move, not a copy of
//! the heap data; the buffers keep their capacity from frame to frame).
//!
//! Same bits as one thread: a job computes outputs that no other part of the
//! decode writes (whole tile rows, a whole lattice), each in the order the
//! single-threaded loop uses.

use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::thread::JoinHandle;

use crate::frame::Frame;

/// Work the helper thread can run: one of the decoder's data-parallel
/// halves (the demodulation's lower tile rows, one code lattice). A trait
/// so that the helper knows no decode stage and the stages import only
/// the helper.
pub(crate) trait Work: Send + 'static {
    /// Runs the job on `frame`.
    fn run(&mut self, frame: &Frame);
    /// The job as `Any`, so its owner can take its own type back
    /// ([`take_back`]).
    fn into_any(self: Box<Self>) -> Box<dyn std::any::Any + Send>;
}

/// Work for the helper thread, boxed so that it moves as one pointer (the
/// boxes are made once per decoder, not per frame).
pub(crate) type Job = Box<dyn Work>;

/// The owner's job back from the helper as its own type (a pointer cast:
/// no allocation); `None` if it is another stage's.
pub(crate) fn take_back<T: Work>(job: Job) -> Option<Box<T>> {
    job.into_any().downcast::<T>().ok()
}

#[derive(Default)]
struct Slot {
    /// The frame lent for the current decode.
    frame: Option<Arc<Frame>>,
    /// Submitted, not yet taken by the thread.
    pending: Option<Job>,
    /// Whether the submitted job is over (`done` holds it unless it
    /// panicked).
    finished: bool,
    done: Option<Job>,
    quit: bool,
}

struct Shared {
    slot: Mutex<Slot>,
    cv: Condvar,
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, Slot> {
        self.slot.lock().unwrap_or_else(|e| e.into_inner())
    }
}

/// The helper thread and its slot (see the module docs). Dropping it stops
/// and joins the thread.
pub(crate) struct Helper {
    shared: Arc<Shared>,
    thread: Option<JoinHandle<()>>,
}

impl std::fmt::Debug for Helper {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Helper").finish_non_exhaustive()
    }
}

impl Helper {
    /// Starts the thread.
    pub(crate) fn start() -> std::io::Result<Helper> {
        let shared = Arc::new(Shared {
            slot: Mutex::new(Slot::default()),
            cv: Condvar::new(),
        });
        let s = shared.clone();
        let thread = std::thread::Builder::new()
            .name("decode-helper".into())
            .spawn(move || worker(&s))?;
        Ok(Helper {
            shared,
            thread: Some(thread),
        })
    }

    /// Lends `frame` for the jobs of one decode (`None`: takes it back).
    pub(crate) fn share(&self, frame: Option<Arc<Frame>>) {
        let old = std::mem::replace(&mut self.shared.lock().frame, frame);
        drop(old);
    }

    /// Hands `job` on `frame` to the thread, or gives it back when `frame`
    /// is not the lent one (the caller then runs it itself).
    pub(crate) fn submit(&self, frame: &Frame, job: Job) -> Result<(), Job> {
        let mut s = self.shared.lock();
        let lent = s.frame.as_deref().is_some_and(|f| std::ptr::eq(f, frame));
        if !lent || s.pending.is_some() || s.quit {
            return Err(job);
        }
        s.pending = Some(job);
        s.finished = false;
        s.done = None;
        drop(s);
        self.shared.cv.notify_all();
        Ok(())
    }

    /// Waits for the submitted job; `None` if it panicked.
    pub(crate) fn wait(&self) -> Option<Job> {
        let mut s = self.shared.lock();
        while !s.finished {
            s = self.shared.cv.wait(s).unwrap_or_else(|e| e.into_inner());
        }
        s.finished = false;
        s.done.take()
    }
}

impl Drop for Helper {
    fn drop(&mut self) {
        self.shared.lock().quit = true;
        self.shared.cv.notify_all();
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

fn worker(s: &Shared) {
    loop {
        let (mut job, frame) = {
            let mut slot = s.lock();
            loop {
                if slot.quit {
                    return;
                }
                if let Some(j) = slot.pending.take() {
                    break (j, slot.frame.clone());
                }
                slot = s.cv.wait(slot).unwrap_or_else(|e| e.into_inner());
            }
        };
        let done = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            if let Some(f) = &frame {
                job.run(f);
            }
            job
        }))
        .ok();
        // The frame goes back to its owner before the job is reported done.
        drop(frame);
        let mut slot = s.lock();
        slot.done = done;
        slot.finished = true;
        drop(slot);
        s.cv.notify_all();
    }
}
