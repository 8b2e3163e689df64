//! `--source` and `--pixel-format` strings must parse or fail cleanly, and
//! a parsed source spec prints back to a string that parses to the same spec.
#![no_main]

use libfuzzer_sys::fuzz_target;
use micropos::camera::{PixelFormat, SourceSpec};

fuzz_target!(|data: &[u8]| {
    let Ok(s) = std::str::from_utf8(data) else {
        return;
    };
    let _ = s.parse::<PixelFormat>();
    if let Ok(spec) = s.parse::<SourceSpec>() {
        let again: SourceSpec = spec.to_string().parse().expect("printed spec parses");
        assert_eq!(again, spec);
    }
});
