//! A warm decoder allocates nothing per frame: a counting global allocator
//! watches `decode` and `track` on frames of a size the decoder has seen.
//!
//! A test binary of its own, not a module of `tests/it/` (the other
//! integration tests' one binary): a `#[global_allocator]` is the whole
//! process's, and its counter must see this file's decoding only, not the
//! allocations of other tests running in parallel threads.

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};

use micropos::pattern::decode::{DecodeOptions, Decoder};
use micropos::pattern::render::{Pose, RenderConfig, Renderer};

struct Counting;

static ALLOCS: AtomicUsize = AtomicUsize::new(0);

// SAFETY: forwards to the system allocator unchanged; only counts calls.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        ALLOCS.fetch_add(1, Ordering::SeqCst);
        // SAFETY: same contract as the caller's.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: same contract as the caller's.
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        ALLOCS.fetch_add(1, Ordering::SeqCst);
        // SAFETY: same contract as the caller's.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

/// The counter is process-wide: the tests take turns (the test harness
/// runs them on parallel threads).
static ONE_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn one_at_a_time() -> std::sync::MutexGuard<'static, ()> {
    ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner())
}

#[test]
fn warm_decoder_does_not_allocate() {
    let _turn = one_at_a_time();
    let mut r = Renderer::new(RenderConfig::default()).unwrap();
    let pose = |i: u64| Pose {
        x_um: 20_000.0 + 0.4 * i as f64,
        y_um: 9_000.0 - 0.3 * i as f64,
        theta_rad: 0.3,
        pixel_um: 0.9,
        mirrored: false,
    };
    let frames: Vec<_> = (0..6)
        .map(|i| r.render(&pose(i), i, 0.0, i).unwrap())
        .collect();
    let mut d = Decoder::new(DecodeOptions::new(9.0, 12)).unwrap();
    // Warm up: cold decode and a few tracked frames size every buffer.
    d.decode(&frames[0]).unwrap();
    d.track(&frames[1]).unwrap();
    d.track(&frames[2]).unwrap();
    let before = ALLOCS.load(Ordering::SeqCst);
    let t = d.track(&frames[3]).unwrap();
    let after_track = ALLOCS.load(Ordering::SeqCst);
    let c = d.decode(&frames[4]).unwrap();
    let after_cold = ALLOCS.load(Ordering::SeqCst);
    assert!(t.tracked && t.code_predicted && !c.tracked);
    assert_eq!(after_track - before, 0, "allocations in a warm track()");
    assert_eq!(
        after_cold - after_track,
        0,
        "allocations in a warm decode()"
    );
}

/// The two-thread decode (`decode_shared`, `track_shared`): warm, it
/// allocates nothing either, it leaves the frame unshared when it returns,
/// and its results are those of the one-thread decoder, bit for bit.
#[test]
fn warm_shared_decoder_does_not_allocate_and_matches_one_thread() {
    let _turn = one_at_a_time();
    use std::sync::Arc;
    let mut r = Renderer::new(RenderConfig::default()).unwrap();
    let pose = |i: u64| Pose {
        x_um: 21_000.0 + 3.7 * i as f64,
        y_um: 8_000.0 - 2.9 * i as f64,
        theta_rad: -0.2 + 0.01 * i as f64,
        pixel_um: 0.9,
        mirrored: false,
    };
    let frames: Vec<Arc<_>> = (0..6)
        .map(|i| Arc::new(r.render(&pose(i), 100 + i, 0.0, i).unwrap()))
        .collect();
    let mut one = Decoder::new(DecodeOptions::new(9.0, 12)).unwrap();
    let mut two = Decoder::new(DecodeOptions::new(9.0, 12)).unwrap();
    for f in &frames[..3] {
        assert_eq!(two.decode_shared(f), one.decode(f));
        assert_eq!(two.track_shared(f), one.track(f));
    }
    let before = ALLOCS.load(Ordering::SeqCst);
    let c = two.decode_shared(&frames[3]);
    let t = two.track_shared(&frames[4]);
    let after = ALLOCS.load(Ordering::SeqCst);
    assert_eq!(after - before, 0, "allocations in a warm decode_shared()");
    assert_eq!(c, one.decode(&frames[3]));
    assert_eq!(t, one.track(&frames[4]));
    assert!(c.is_ok() && t.is_ok());
    for f in &frames {
        assert_eq!(Arc::strong_count(f), 1, "the frame is unshared again");
    }
}
