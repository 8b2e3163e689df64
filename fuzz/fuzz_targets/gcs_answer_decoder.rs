//! The host-side framing of controller answers, and the typed readings of
//! them: never panic, stay bounded, independent of read boundaries.
#![no_main]

use libfuzzer_sys::fuzz_target;
use micropos::gcs::answer;
use micropos::gcs::frame::{Address, AnswerDecoder, AnswerItem};
use micropos::gcs::AxisId;

fuzz_target!(|data: &[u8]| {
    let Some((&split, bytes)) = data.split_first() else {
        return;
    };
    let split = usize::from(split).min(bytes.len());
    let mut whole = AnswerDecoder::new();
    let all = whole.push(bytes);
    let mut parts = AnswerDecoder::new();
    let mut got = parts.push(&bytes[..split]);
    got.extend(parts.push(&bytes[split..]));
    assert_eq!(all, got);
    let one = AxisId::new("1").ok();
    for item in all {
        let AnswerItem::Answer(a) = item else {
            continue;
        };
        let _ = answer::axis_values(&a);
        let _ = answer::hex_word(&a);
        let _ = answer::ready(&a);
        let _ = answer::error_code(&a);
        let _ = answer::identification(&a);
        let _ = answer::single_number(&a);
        let _ = answer::word_list(&a);
        let _ = answer::parameters(&a);
        if let Some(axis) = &one {
            let _ = answer::value_for(&a, axis, answer::number);
            let _ = answer::value_for(&a, axis, answer::boolean);
        }
        if let Ok(addr) = Address::new(split as u8 % 16 + 1) {
            let _ = a.strip_header(addr);
        }
    }
});
