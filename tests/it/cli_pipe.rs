//! `micropos … | head` must end like any Unix filter: killed by SIGPIPE,
//! no panic message, when the reader goes away.

use std::os::unix::process::ExitStatusExt;
use std::process::{Command, Stdio};

#[test]
fn closed_stdout_ends_quietly_by_sigpipe() {
    // The read end is closed before the child starts, so its first write
    // fails: deterministic, no race with the child's output.
    let (reader, writer) = std::io::pipe().unwrap();
    drop(reader);
    let out = Command::new(env!("CARGO_BIN_EXE_micropos"))
        .args(["completions", "bash"])
        .stdout(writer)
        .stderr(Stdio::piped())
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        !stderr.contains("panicked"),
        "panic on a closed pipe: {stderr}"
    );
    assert_eq!(
        out.status.signal(),
        Some(libc::SIGPIPE),
        "status {:?}",
        out.status
    );
}
