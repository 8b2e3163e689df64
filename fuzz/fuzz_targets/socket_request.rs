//! Fuzzes the daemon's request parser: any bytes give a request or a
//! refusal, never a panic, and a refusal always serializes to one JSON line.
#![no_main]

use libfuzzer_sys::fuzz_target;
use micropos::daemon::protocol::{error_reply, parse_request};

fuzz_target!(|data: &[u8]| {
    if let Err(r) = parse_request(data) {
        let line = error_reply(&r.id, &r.error);
        assert!(line.ends_with('\n'));
        assert_eq!(line.matches('\n').count(), 1);
        let v: serde_json::Value = serde_json::from_str(&line).expect("reply is JSON");
        assert_eq!(v["ok"], false);
    }
});
