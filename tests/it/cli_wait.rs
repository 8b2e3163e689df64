//! `micropos --wait-s S`: a script that has just started microposd waits
//! for its socket and for its controllers to connect, instead of failing
//! with "daemon unreachable" (exit 3) or `not_connected` (exit 1).
//!
//! The daemon here is a stand-in on a Unix socket that appears only after
//! the client has started and refuses the first request with
//! `not_connected`, as a daemon still connecting its controllers does.

use std::io::{BufRead, BufReader, Write};
use std::os::unix::net::UnixListener;
use std::process::{Command, Stdio};

fn micropos(socket: &std::path::Path, wait: &str) -> std::process::Child {
    Command::new(env!("CARGO_BIN_EXE_micropos"))
        .arg("--socket")
        .arg(socket)
        .args(["--wait-s", wait, "reference"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

/// Answers `refusals` requests with `not_connected`, then one with ok;
/// returns the requests seen.
fn serve(listener: UnixListener, refusals: usize) -> Vec<String> {
    let (stream, _) = listener.accept().unwrap();
    let mut reader = BufReader::new(stream.try_clone().unwrap());
    let mut w = stream;
    let mut seen = Vec::new();
    for i in 0..=refusals {
        let mut line = String::new();
        if reader.read_line(&mut line).unwrap() == 0 {
            break;
        }
        let req: serde_json::Value = serde_json::from_str(&line).unwrap();
        seen.push(req["cmd"].as_str().unwrap_or("?").to_owned());
        let reply = if i < refusals {
            serde_json::json!({"id": req["id"], "ok": false, "error": {"code": "not_connected",
                "message": "the controllers are not connected yet (connecting); see status"}})
        } else {
            serde_json::json!({"id": req["id"], "ok": true, "result": {"referenced": "xy"}})
        };
        writeln!(w, "{reply}").unwrap();
    }
    seen
}

#[test]
fn waits_for_a_starting_daemon_and_its_controllers() {
    let dir = tempfile::tempdir().unwrap();
    let socket = dir.path().join("micropos.sock");
    let child = micropos(&socket, "30");
    // The client is already retrying: the socket does not exist yet.
    std::thread::sleep(std::time::Duration::from_millis(300));
    let listener = UnixListener::bind(&socket).unwrap();
    let seen = serve(listener, 2);
    let out = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{:?}: {stderr}", out.status);
    assert_eq!(seen, ["reference", "reference", "reference"]);
}

#[test]
fn without_a_wait_a_missing_daemon_fails_at_once_and_says_how_to_wait() {
    let dir = tempfile::tempdir().unwrap();
    let out = micropos(&dir.path().join("none.sock"), "0")
        .wait_with_output()
        .unwrap();
    assert_eq!(out.status.code(), Some(3));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("--wait-s"), "{stderr}");
}

#[test]
fn a_bad_wait_is_a_usage_error() {
    let dir = tempfile::tempdir().unwrap();
    for bad in ["-1", "nan", "inf", "soon"] {
        let out = micropos(&dir.path().join("none.sock"), bad)
            .wait_with_output()
            .unwrap();
        assert_eq!(out.status.code(), Some(2), "--wait-s {bad}");
    }
}
