//! The host session state machine under arbitrary interleavings of
//! requests, received bytes, clock ticks and resets: never panics, and its
//! deadline bookkeeping stays consistent.
#![no_main]

use libfuzzer_sys::fuzz_target;
use micropos::gcs::frame::{bytes_to_text, Address, ControlChar};
use micropos::gcs::{AxisId, Command, Outgoing, Session};
use std::time::Duration;

fuzz_target!(|data: &[u8]| {
    let mut s = Session::new();
    let mut now = Duration::ZERO;
    let mut i = 0;
    let axis = AxisId::new("1").ok();
    while i < data.len() {
        let op = data[i];
        i += 1;
        // Time only moves forward, by 0..255 ms per step.
        let dt = data.get(i).copied().unwrap_or(0);
        now += Duration::from_millis(u64::from(dt));
        i += 1;
        match op % 6 {
            0 | 1 => {
                let addr = match op / 6 % 18 {
                    0 => None,
                    a => Address::new(a as u8).ok(),
                };
                let out = match (op / 128, &axis) {
                    (0, Some(a)) => Outgoing::Command(Command::PosQuery(vec![a.clone()])),
                    (_, Some(a)) if dt % 3 == 0 => {
                        Outgoing::Command(Command::Mov(vec![(a.clone(), f64::from(dt) / 7.0)]))
                    }
                    _ if dt % 3 == 1 => Outgoing::Control(match dt % 4 {
                        0 => ControlChar::Status,
                        1 => ControlChar::MotionStatus,
                        2 => ControlChar::Ready,
                        _ => ControlChar::StopAll,
                    }),
                    _ => {
                        let n = usize::from(dt % 16).min(data.len() - i.min(data.len()));
                        let text = bytes_to_text(&data[i.min(data.len())..][..n]);
                        Outgoing::Raw(text)
                    }
                };
                let busy = s.is_busy();
                let r = s.start(now, addr, &out, Duration::from_millis(100));
                if busy {
                    assert!(r.is_err());
                }
            }
            2 | 3 => {
                let n = usize::from(dt).min(data.len() - i.min(data.len()));
                let start = i.min(data.len());
                let _ = s.on_bytes(now, &data[start..start + n]);
                i += n;
            }
            4 => {
                let _ = s.on_time(now);
                if let Some(d) = s.deadline() {
                    assert!(d > now);
                }
            }
            _ => {
                s.reset();
                assert!(!s.is_busy());
            }
        }
        assert_eq!(s.is_busy(), s.deadline().is_some());
    }
});
