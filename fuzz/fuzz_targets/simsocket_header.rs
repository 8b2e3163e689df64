#![no_main]
//! The simulated camera's header line is outside input to micropos (it comes
//! from another process): parsing must never panic, and an accepted header
//! must describe a frame whose payload can be decoded.
use libfuzzer_sys::fuzz_target;
use micropos::camera::simsocket::{decode_payload, parse_header, Reply};

fuzz_target!(|data: &[u8]| {
    if let Ok(Reply::Frame(h)) = parse_header(data) {
        if h.bytes <= 1 << 16 {
            let payload = vec![0u8; h.bytes];
            let _ = decode_payload(&h, &payload);
        }
    }
});
