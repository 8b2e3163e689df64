//! Log lines on a redirected stderr carry no ANSI colour codes, from any of
//! the three binaries (`micropos`, `microposd`, `hil-sim`): a log kept in a
//! file or piped into `grep` must read as plain text. Each binary is made
//! to log at once (`RUST_LOG=trace`: the async runtime's first events)
//! with stderr a pipe, as in a script or under a CI runner. The rule itself
//! (terminal and `NO_COLOR`) is `micropos::colour_wanted`'s unit test.
//!
//! `hil-sim` comes from the target directory (see `bins.rs`): `cargo build
//! -p hil-sim` before running this file alone.

use crate::bins::{hil_sim_bin, microposd_bin};
use std::io::{BufRead, BufReader, Read};
use std::process::{Command, Stdio};

/// Fails if `stderr` holds an escape character, else checks it holds a
/// log line at all (a test that saw no log would prove nothing).
fn plain(what: &str, stderr: &str) {
    assert!(
        !stderr.contains('\u{1b}'),
        "{what}: ANSI codes in a redirected stderr:\n{stderr}"
    );
    assert!(
        stderr.contains("TRACE") || stderr.contains("ERROR"),
        "{what}: logged nothing:\n{stderr}"
    );
}

#[test]
fn micropos_logs_plain_text_into_a_pipe() {
    let dir = tempfile::tempdir().unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_micropos"))
        .arg("--socket")
        .arg(dir.path().join("none.sock"))
        .arg("status")
        .env("RUST_LOG", "trace")
        .env_remove("NO_COLOR")
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(3));
    plain("micropos", &String::from_utf8_lossy(&out.stderr));
}

#[test]
fn microposd_logs_plain_text_into_a_pipe() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("microposd.toml");
    // A socket it cannot create: it starts its runtime, logs, and exits.
    std::fs::write(
        &cfg,
        format!(
            "[daemon]\nsocket = \"/dev/null/sub/m.sock\"\ndata_dir = \"{}\"\n\
             [driver.x]\nport = \"/nonexistent/x\"\n[driver.y]\nport = \"/nonexistent/y\"\n",
            dir.path().join("data").display()
        ),
    )
    .unwrap();
    let out = Command::new(microposd_bin())
        .arg("-c")
        .arg(&cfg)
        .env("RUST_LOG", "trace")
        .env_remove("NO_COLOR")
        .env_remove("JOURNAL_STREAM")
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    plain("microposd", &String::from_utf8_lossy(&out.stderr));
}

#[test]
fn hil_sim_logs_plain_text_into_a_pipe() {
    let dir = tempfile::tempdir().unwrap();
    let mut child = Command::new(hil_sim_bin())
        .args(["serve", "--link-dir"])
        .arg(dir.path())
        .env("RUST_LOG", "trace")
        .env_remove("NO_COLOR")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut ready = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut ready)
        .unwrap();
    assert!(ready.starts_with("hil-sim ready"), "{ready}");
    let _ = child.kill();
    let mut stderr = String::new();
    child
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut stderr)
        .unwrap();
    let _ = child.wait();
    plain("hil-sim", &stderr);
}
