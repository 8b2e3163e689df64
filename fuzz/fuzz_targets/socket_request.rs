//! Fuzzes the daemon's request parser: any bytes give a request or a
//! refusal, never a panic, and a refusal always serializes to one JSON line.
//! Also: the fuzz bytes' request with one of its keys repeated (the line
//! re-encoded with the key's value written again) is always refused, so no
//! request runs with a meaning a first-key reader would not see.
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
        return;
    }
    // An accepted request is an object: write one of its keys twice.
    let Ok(serde_json::Value::Object(obj)) = serde_json::from_slice::<serde_json::Value>(data)
    else {
        return;
    };
    let Some((k, v)) = obj.iter().nth(data.len() % obj.len().max(1)) else {
        return;
    };
    let body = serde_json::to_string(&obj).expect("an object serializes");
    let repeat = format!(
        "{{{}:{},{}",
        serde_json::to_string(k).expect("a key serializes"),
        v,
        &body[1..]
    );
    assert!(
        parse_request(repeat.as_bytes()).is_err(),
        "a repeated key was accepted: {repeat}"
    );
});
