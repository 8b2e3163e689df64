//! Replay decoding of arbitrary image file bytes must never panic.
#![no_main]

use libfuzzer_sys::fuzz_target;
use micropos::camera::files::decode_image_bytes;

fuzz_target!(|data: &[u8]| {
    let depth = data.first().map(|b| b % 18);
    let _ = decode_image_bytes(data, None);
    let _ = decode_image_bytes(data, depth);
});
