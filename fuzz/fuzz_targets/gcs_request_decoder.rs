//! The controller-side framing of bytes from the host: never panics, stays
//! bounded, and does not depend on how the bytes are split into reads.
#![no_main]

use libfuzzer_sys::fuzz_target;
use micropos::gcs::frame::{Request, RequestDecoder, MAX_LINE_LEN};

fuzz_target!(|data: &[u8]| {
    let Some((&split, bytes)) = data.split_first() else {
        return;
    };
    let split = usize::from(split).min(bytes.len());
    let mut whole = RequestDecoder::new();
    let all = whole.push(bytes);
    assert!(whole.pending() <= MAX_LINE_LEN);
    let mut parts = RequestDecoder::new();
    let mut got = parts.push(&bytes[..split]);
    assert!(parts.pending() <= MAX_LINE_LEN);
    got.extend(parts.push(&bytes[split..]));
    assert_eq!(all, got);
    for r in &all {
        if let Request::Line { text, .. } = r {
            assert!(!text.contains('\n'));
            // One char per received byte (8-bit text).
            assert!(text.chars().count() <= MAX_LINE_LEN);
        }
    }
});
