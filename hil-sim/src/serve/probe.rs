//! The receive-side latency probe of a simulated line.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Mutex, MutexGuard};
use std::time::Instant;

/// When host bytes reached a simulated line: the far end of a
/// command-to-first-serial-byte latency measurement (`benches/daemon.rs`).
///
/// Why in the simulator: only the line thread sees the instant a byte
/// leaves the pty; timing it from the host side would measure the host's
/// own write call. Arm it with [`RxProbe::arm`] just before sending a
/// command to the system under test; the line thread stamps the wall-clock
/// [`Instant`] of the first chunk read after that, and of the chunk that
/// completes `needle` (e.g. `b"MOV"`), so unrelated traffic (status polls)
/// can be told apart. Costs one relaxed atomic load per chunk when unarmed.
#[derive(Debug, Default)]
pub struct RxProbe {
    armed: AtomicBool,
    state: Mutex<ProbeState>,
}

#[derive(Debug, Default)]
struct ProbeState {
    needle: Vec<u8>,
    seen: Vec<u8>,
    first: Option<Instant>,
    matched: Option<Instant>,
}

/// Bytes kept after arming to find a needle split across chunks.
const PROBE_WINDOW: usize = 4096;

impl RxProbe {
    fn state(&self) -> MutexGuard<'_, ProbeState> {
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Clears previous stamps and starts watching for `needle` (an empty
    /// needle matches the first chunk).
    pub fn arm(&self, needle: &[u8]) {
        let mut st = self.state();
        *st = ProbeState {
            needle: needle.to_vec(),
            ..ProbeState::default()
        };
        self.armed.store(true, Ordering::SeqCst);
    }

    /// When the first byte after [`RxProbe::arm`] was read, if any.
    pub fn first_byte(&self) -> Option<Instant> {
        self.state().first
    }

    /// When the bytes read since [`RxProbe::arm`] first contained the
    /// needle, if they have.
    pub fn matched(&self) -> Option<Instant> {
        self.state().matched
    }

    pub(super) fn observe(&self, bytes: &[u8], at: Instant) {
        if !self.armed.load(Ordering::Relaxed) || bytes.is_empty() {
            return;
        }
        let mut st = self.state();
        st.first.get_or_insert(at);
        if st.matched.is_none() {
            let room = PROBE_WINDOW.saturating_sub(st.seen.len());
            st.seen.extend_from_slice(&bytes[..bytes.len().min(room)]);
            let n = st.needle.len();
            if n == 0 || st.seen.windows(n).any(|w| w == st.needle.as_slice()) {
                st.matched = Some(at);
            }
        }
        if st.matched.is_some() {
            self.armed.store(false, Ordering::Relaxed);
        }
    }
}

#[cfg(test)]
mod probe_tests {
    use super::*;
    use std::time::Duration;

    #[test]
    fn probe_stamps_first_byte_and_needle_across_chunks() {
        let p = RxProbe::default();
        let t0 = Instant::now();
        let (t1, t2, t3) = (
            t0 + Duration::from_micros(1),
            t0 + Duration::from_micros(2),
            t0 + Duration::from_micros(3),
        );
        // Unarmed: nothing recorded.
        p.observe(b"MOV 1 2\n", t0);
        assert_eq!((p.first_byte(), p.matched()), (None, None));
        p.arm(b"MOV");
        p.observe(b"POS?\nM", t1);
        assert_eq!((p.first_byte(), p.matched()), (Some(t1), None));
        p.observe(b"O", t2);
        p.observe(b"V 1 2\n", t3);
        assert_eq!((p.first_byte(), p.matched()), (Some(t1), Some(t3)));
        // Disarmed after the match; re-arming clears the stamps.
        p.observe(b"MOV", t3 + Duration::from_micros(1));
        assert_eq!(p.matched(), Some(t3));
        p.arm(b"");
        assert_eq!(p.first_byte(), None);
        p.observe(b"x", t2);
        assert_eq!((p.first_byte(), p.matched()), (Some(t2), Some(t2)));
    }
}
