//! Fuzzes the daemon's request parser: any bytes give a request or a
//! refusal, never a panic, and a refusal always serializes to one JSON line.
//! The same bytes also build a request with a key repeated in one object
//! (at a nesting depth and with a key taken from the bytes): it must be
//! refused with `bad_request`.
#![no_main]

use libfuzzer_sys::fuzz_target;
use micropos::daemon::protocol::{error_reply, parse_request, ErrorCode, MAX_REQUEST_BYTES};

fuzz_target!(|data: &[u8]| {
    if let Err(r) = parse_request(data) {
        let line = error_reply(&r.id, &r.error);
        assert!(line.ends_with('\n'));
        assert_eq!(line.matches('\n').count(), 1);
        let v: serde_json::Value = serde_json::from_str(&line).expect("reply is JSON");
        assert_eq!(v["ok"], false);
    }
    repeated_key_is_refused(data);
});

/// `{"cmd":"status","n":{"n":{… {K:1,"o":[V],K:2}}}}`: key `K` from the
/// bytes, depth and the value `V` between the repeats from the bytes.
fn repeated_key_is_refused(data: &[u8]) {
    let Some((&first, rest)) = data.split_first() else {
        return;
    };
    let depth = usize::from(first % 8);
    let split = rest.len() / 2;
    let key = serde_json::to_string(&String::from_utf8_lossy(&rest[..split])).expect("a string");
    let between = serde_json::to_string(&String::from_utf8_lossy(&rest[split..])).expect("a string");
    let mut obj = format!("{{{key}:1,\"o\":[{between}],{key}:2}}");
    for _ in 0..depth {
        obj = format!("{{\"n\":{obj}}}");
    }
    let line = if first & 0x80 == 0 {
        format!("{{\"cmd\":\"status\",\"n\":{obj}}}")
    } else {
        // The repeat at the top level, next to `cmd`.
        format!("{{\"cmd\":\"status\",{key}:1,\"o\":[{between}],{key}:2}}")
    };
    if line.len() > MAX_REQUEST_BYTES {
        return;
    }
    let refusal = parse_request(line.as_bytes()).expect_err("a repeated key is refused");
    assert_eq!(refusal.error.code, ErrorCode::BadRequest, "{line}");
}
