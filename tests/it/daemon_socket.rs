//! The daemon's socket, as `microposd` creates it (no systemd): it is never
//! reachable with a mode wider than `daemon.socket_mode`, whatever the
//! umask (it is bound in a private directory and renamed into place), no
//! staging directory is left behind, and a socket open to every local user
//! without `[access]` is warned about at start.
//!
//! A process test: the window it closes is between two system calls of the
//! real binary.

use std::os::unix::fs::{FileTypeExt, PermissionsExt};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

fn config(dir: &Path, mode: &str, access: bool) -> (PathBuf, PathBuf) {
    let sock_dir = dir.join("run");
    let socket = sock_dir.join("micropos.sock");
    let mut text = format!(
        "[daemon]\nsocket = \"{}\"\nsocket_mode = \"{mode}\"\ndata_dir = \"{}\"\n\
         [driver.x]\nport = \"{}\"\n[driver.y]\nport = \"{}\"\n",
        socket.display(),
        dir.join("data").display(),
        dir.join("no-such-tty-x").display(),
        dir.join("no-such-tty-y").display(),
    );
    if access {
        text.push_str("[access]\nadmin = [\"root\"]\n");
    }
    let path = dir.join("microposd.toml");
    std::fs::write(&path, text).unwrap();
    (path, socket)
}

/// microposd under umask 000 (so a socket bound in place would be 0777
/// until its chmod), stderr to a file.
fn start(config: &Path, stderr: &Path) -> Child {
    Command::new("sh")
        .arg("-c")
        .arg("umask 000; exec \"$0\" --config \"$1\"")
        .arg(env!("CARGO_BIN_EXE_microposd"))
        .arg(config)
        .env("RUST_LOG", "info")
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(stderr).unwrap())
        .spawn()
        .unwrap()
}

/// Every mode the socket path shows from its first appearance on, polled
/// as fast as `lstat` allows, until it has been seen `n` times.
fn modes_seen(path: &Path, n: usize) -> Vec<u32> {
    let deadline = Instant::now() + Duration::from_secs(60);
    let mut seen = Vec::new();
    while seen.len() < n {
        assert!(
            Instant::now() < deadline,
            "{} never appeared",
            path.display()
        );
        if let Ok(m) = std::fs::symlink_metadata(path) {
            assert!(m.file_type().is_socket(), "{m:?}");
            seen.push(m.permissions().mode() & 0o777);
        }
    }
    seen
}

fn stop(mut child: Child) {
    let _ = child.kill();
    let _ = child.wait();
}

#[test]
fn the_socket_appears_with_its_final_mode_and_nothing_is_left_behind() {
    let dir = tempfile::tempdir().unwrap();
    let (cfg, socket) = config(dir.path(), "0600", false);
    let err = dir.path().join("stderr");
    let child = start(&cfg, &err);
    let seen = modes_seen(&socket, 200);
    let mut clients = std::os::unix::net::UnixStream::connect(&socket);
    // The private bind directory goes once the socket is renamed into
    // place: wait for it (a kill between the rename and its removal would
    // leave it, which is not what this test is about).
    let names = || -> Vec<String> {
        std::fs::read_dir(socket.parent().unwrap())
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect()
    };
    let t0 = std::time::Instant::now();
    while names() != ["micropos.sock"] && t0.elapsed() < std::time::Duration::from_secs(10) {
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    stop(child);
    let octal: Vec<String> = seen.iter().map(|m| format!("{m:o}")).collect();
    assert!(seen.iter().all(|m| *m == 0o600), "modes seen: {octal:?}");
    assert!(clients.as_mut().is_ok(), "{clients:?}");
    assert_eq!(names(), ["micropos.sock"], "left in the socket's directory");
    let stderr = std::fs::read_to_string(&err).unwrap();
    assert!(!stderr.contains("every local user"), "{stderr}");
}

#[test]
fn a_socket_open_to_everyone_without_access_is_warned_about() {
    for (access, warned) in [(false, true), (true, false)] {
        let dir = tempfile::tempdir().unwrap();
        let (cfg, socket) = config(dir.path(), "0666", access);
        let err = dir.path().join("stderr");
        let child = start(&cfg, &err);
        let seen = modes_seen(&socket, 1);
        stop(child);
        assert_eq!(seen, [0o666]);
        let stderr = std::fs::read_to_string(&err).unwrap();
        assert_eq!(
            stderr.contains("every local user connect"),
            warned,
            "access: {access}; stderr: {stderr}"
        );
    }
}

/// A wrong serial port, seen as a user sees it: `micropos status` names
/// the port and why it failed for both axes (not only the daemon's log),
/// and a move is refused with the same reason.
#[test]
fn a_wrong_serial_port_is_named_in_status_and_in_a_refused_move() {
    let dir = tempfile::tempdir().unwrap();
    let (cfg, socket) = config(dir.path(), "0600", false);
    let err = dir.path().join("stderr");
    let child = start(&cfg, &err);
    let _ = modes_seen(&socket, 1);
    let cli = |args: &[&str]| {
        let out = Command::new(env!("CARGO_BIN_EXE_micropos"))
            .arg("--socket")
            .arg(&socket)
            .args(args)
            .output()
            .unwrap();
        (
            out.status.success(),
            String::from_utf8_lossy(&out.stdout).into_owned()
                + &String::from_utf8_lossy(&out.stderr),
        )
    };
    // The first attempt's failure is recorded once it has been made.
    let t0 = Instant::now();
    let mut status = String::new();
    while t0.elapsed() < Duration::from_secs(20) {
        status = cli(&["status"]).1;
        if status.contains("no-such-tty") {
            break;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    let (moved, refusal) = cli(&["move", "--x", "100", "--y", "100"]);
    stop(child);
    assert!(
        status.contains("motion refused: the controllers are not connected"),
        "{status}"
    );
    let why: Vec<&str> = status
        .lines()
        .filter(|l| l.contains("no-such-tty"))
        .collect();
    assert_eq!(why.len(), 2, "both axes with the reason: {status}");
    assert!(why.iter().all(|l| l.contains("[driver] port")), "{status}");
    assert!(!moved, "{refusal}");
    assert!(refusal.contains("no-such-tty"), "{refusal}");
}

/// A daemon killed between the socket's rename and its private
/// directory's removal leaves that directory, empty: the next start
/// removes it, and leaves alone one with something in it.
#[test]
fn an_empty_bind_directory_left_by_a_killed_daemon_is_removed_at_start() {
    let dir = tempfile::tempdir().unwrap();
    let (cfg, socket) = config(dir.path(), "0600", false);
    let run = socket.parent().unwrap();
    let stale = run.join(".microposd-bind-AbC123");
    let kept = run.join(".microposd-bind-XyZ789");
    std::fs::create_dir_all(&stale).unwrap();
    std::fs::create_dir_all(&kept).unwrap();
    std::fs::write(kept.join("note"), "not a daemon's").unwrap();
    let err = dir.path().join("stderr");
    let child = start(&cfg, &err);
    let _ = modes_seen(&socket, 1);
    let t0 = Instant::now();
    while stale.exists() && t0.elapsed() < Duration::from_secs(10) {
        std::thread::sleep(Duration::from_millis(20));
    }
    stop(child);
    assert!(!stale.exists(), "the empty bind directory is still there");
    assert!(kept.join("note").exists(), "a non-empty one was touched");
}
