//! microposd under systemd's tools, as a process:
//!
//! - `systemd-analyze verify` accepts the shipped units (`systemd/`) and
//!   the GigE drop-in without a single complaint. The units are copied
//!   with `ExecStart=` pointing at the built binary (verify insists the
//!   command exists); nothing else is changed.
//! - `systemd-socket-activate` holds the listening socket and starts the
//!   real `microposd` with the simulated-rig config
//!   (`config/microposd-sim.toml` against `hil-sim serve`) on the first
//!   connection; that client gets its `status` through the passed socket.
//! - SIGHUP reloads what can change live (soft limits, drift, compensation,
//!   access roles), refuses the rest with a log line naming the keys, and
//!   never stops the daemon.
//!
//! A missing tool skips its test with a printed reason (CI installs the
//! `systemd` package, see `.ci/run`). The binaries: `microposd` from cargo
//! (`CARGO_BIN_EXE_microposd`), `hil-sim` from the same target directory
//! (`cargo test --workspace` builds it; `HIL_SIM_BIN` overrides), as in
//! `tests/it/daemon_process.rs`.

use crate::bins::{hil_sim_bin, microposd_bin};
use serde_json::{json, Value};
use std::io::{BufRead, BufReader, Write};
use std::os::unix::net::UnixStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// Generous: builds may run in parallel on 2 cores.
const DEADLINE: Duration = Duration::from_secs(90);

/// `Some(path)` of a tool on PATH, else prints why the test is skipped.
fn tool(name: &str) -> Option<PathBuf> {
    let found = std::env::var_os("PATH").and_then(|paths| {
        std::env::split_paths(&paths)
            .map(|d| d.join(name))
            .find(|p| p.is_file())
    });
    if found.is_none() {
        eprintln!("SKIPPED: {name} is not installed (Debian package `systemd`; CI installs it)");
    }
    found
}

/// A child process killed (SIGKILL) and reaped on drop.
struct Proc(Child);

impl Drop for Proc {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// `hil-sim serve` in `dir` (ptys, control and camera sockets).
fn start_sim(dir: &Path) -> Proc {
    let mut child = Command::new(hil_sim_bin())
        .args(["serve", "--link-dir"])
        .arg(dir)
        .args(["--seed", "3", "--time-scale", "20"])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    assert!(line.starts_with("hil-sim ready"), "{line}");
    Proc(child)
}

/// The shipped simulated-rig config moved into `dir`, plus `extra` TOML.
fn sim_config(dir: &Path, extra: &str) -> PathBuf {
    let text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/config/microposd-sim.toml"
    ))
    .unwrap()
    .replace("/tmp/rig", dir.to_str().unwrap());
    let p = dir.join("microposd.toml");
    std::fs::write(&p, format!("{text}\n{extra}")).unwrap();
    p
}

/// One request on a new connection and its reply.
fn request(socket: &Path, req: Value) -> Value {
    let s = UnixStream::connect(socket).unwrap();
    s.set_read_timeout(Some(DEADLINE)).unwrap();
    let mut w = s.try_clone().unwrap();
    writeln!(w, "{req}").unwrap();
    let mut line = String::new();
    BufReader::new(s).read_line(&mut line).unwrap();
    serde_json::from_str(&line).unwrap_or_else(|e| panic!("{line:?}: {e}"))
}

fn wait_for(what: &str, mut cond: impl FnMut() -> bool) {
    let t = Instant::now();
    while !cond() {
        assert!(t.elapsed() < DEADLINE, "timed out waiting for {what}");
        std::thread::sleep(Duration::from_millis(20));
    }
}

#[test]
fn shipped_units_pass_systemd_analyze_verify() {
    let Some(analyze) = tool("systemd-analyze") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let units = Path::new(env!("CARGO_MANIFEST_DIR")).join("systemd");
    let bin = microposd_bin();
    let service = std::fs::read_to_string(units.join("microposd.service"))
        .unwrap()
        .replace("/usr/bin/microposd", bin.to_str().unwrap());
    std::fs::write(dir.path().join("microposd.service"), service).unwrap();
    std::fs::copy(
        units.join("microposd.socket"),
        dir.path().join("microposd.socket"),
    )
    .unwrap();
    let dropin = dir.path().join("microposd.service.d");
    std::fs::create_dir(&dropin).unwrap();
    for conf in ["gige-camera.conf", "web-view.conf"] {
        std::fs::copy(units.join(conf), dropin.join(conf)).unwrap();
    }
    let out = Command::new(analyze)
        .args(["verify", "--man=no"])
        .arg(dir.path().join("microposd.service"))
        .arg(dir.path().join("microposd.socket"))
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    // verify exits 0 on unknown keys and bad values: any line is a finding.
    assert!(stderr.trim().is_empty(), "systemd-analyze verify: {stderr}");
    // The unit keeps what socket activation and the hardening need.
    let text = std::fs::read_to_string(units.join("microposd.service")).unwrap();
    for key in [
        "RuntimeDirectoryPreserve=yes",
        "DeviceAllow=char-ttyS rw",
        "SystemCallFilter=@system-service",
        "UMask=0027",
        "MemoryMax=",
        "TasksMax=",
        "After=microposd.socket",
    ] {
        assert!(text.contains(key), "microposd.service lacks {key}");
    }
}

#[test]
fn socket_activation_serves_status_through_the_passed_socket() {
    let Some(activate) = tool("systemd-socket-activate") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let _sim = start_sim(dir.path());
    let cfg = sim_config(dir.path(), "");
    // The daemon must use the passed socket, not bind daemon.socket.
    let socket = dir.path().join("activated.sock");
    let log = std::fs::File::create(dir.path().join("microposd.log")).unwrap();
    let _act = Proc(
        Command::new(activate)
            .arg("--listen")
            .arg(&socket)
            .args(["-E", "RUST_LOG=info"])
            .arg(microposd_bin())
            .arg("-c")
            .arg(&cfg)
            .stdout(Stdio::null())
            .stderr(log)
            .spawn()
            .unwrap(),
    );
    wait_for("the activation socket", || socket.exists());
    // The first connection starts microposd; its reply comes through.
    let v = request(&socket, json!({"id": 1, "cmd": "status"}));
    assert_eq!(v["ok"], true, "{v}");
    assert_eq!(v["id"], 1);
    assert!(v["rig"].is_object(), "{v}");
    let logged = std::fs::read_to_string(dir.path().join("microposd.log")).unwrap();
    assert!(
        logged.contains("using the socket passed by systemd"),
        "{logged}"
    );
    assert!(
        !dir.path().join("micropos.sock").exists(),
        "microposd bound daemon.socket instead of using the passed socket"
    );
    // Controllers come up behind the activated socket too.
    wait_for("both controllers", || {
        request(&socket, json!({"cmd": "status"}))["rig"]["connected"]
            == json!({"x": true, "y": true})
    });
}

#[test]
fn sighup_reloads_limits_and_names_what_it_cannot_change() {
    let dir = tempfile::tempdir().unwrap();
    let _sim = start_sim(dir.path());
    let cfg = sim_config(dir.path(), "[limits]\nx_max_um = 14000.0\n");
    let log_path = dir.path().join("microposd.log");
    let log = std::fs::File::create(&log_path).unwrap();
    let mut daemon = Proc(
        Command::new(microposd_bin())
            .arg("-c")
            .arg(&cfg)
            .stdout(Stdio::null())
            .stderr(log)
            .spawn()
            .unwrap(),
    );
    let socket = dir.path().join("micropos.sock");
    wait_for("the daemon's socket", || {
        UnixStream::connect(&socket).is_ok()
    });
    wait_for("both controllers", || {
        request(&socket, json!({"cmd": "status"}))["rig"]["connected"]
            == json!({"x": true, "y": true})
    });
    let v = request(&socket, json!({"cmd": "reference"}));
    assert_eq!(v["ok"], true, "{v}");
    let code = |v: &Value| v["error"]["code"].as_str().unwrap_or("").to_owned();
    let v = request(&socket, json!({"cmd": "move", "x_um": 14500.0}));
    assert_eq!(code(&v), "out_of_travel", "{v}");
    let v = request(
        &socket,
        json!({"cmd": "move", "x_um": 13000.0, "wait": true}),
    );
    assert_eq!(v["ok"], true, "{v}");
    let hup = |pid: u32| {
        let st = Command::new("kill")
            .args(["-HUP", &pid.to_string()])
            .status()
            .unwrap();
        assert!(st.success());
    };
    let pid = daemon.0.id();
    // Tighter limits (live) and a new poll interval (not live).
    let text = std::fs::read_to_string(&cfg)
        .unwrap()
        .replace("x_max_um = 14000.0", "x_max_um = 12000.0")
        .replace("poll_interval_ms = 200", "poll_interval_ms = 300");
    std::fs::write(&cfg, text).unwrap();
    hup(pid);
    wait_for("the new limit", || {
        code(&request(&socket, json!({"cmd": "move", "x_um": 12500.0}))) == "out_of_travel"
    });
    let logged = || std::fs::read_to_string(&log_path).unwrap();
    wait_for("the reload's log lines", || {
        let l = logged();
        l.contains("SIGHUP: reloaded limits.x_max_um")
            && l.contains(
                "not reloadable, restart to apply (running values kept): daemon.poll_interval_ms",
            )
    });
    let c = request(&socket, json!({"cmd": "config"}));
    assert_eq!(c["config"]["limits"]["x_max_um"], 12000.0, "{c}");
    assert_eq!(c["config"]["daemon"]["poll_interval_ms"], 200, "{c}");
    // A broken file changes nothing and stops nothing.
    std::fs::write(&cfg, "[daemon\n").unwrap();
    hup(pid);
    wait_for("the refusal", || {
        logged().contains("the running configuration stays")
    });
    let v = request(&socket, json!({"cmd": "move", "x_um": 12500.0}));
    assert_eq!(code(&v), "out_of_travel", "{v}");
    let v = request(
        &socket,
        json!({"cmd": "move", "x_um": 11000.0, "wait": true}),
    );
    assert_eq!(v["ok"], true, "{v}");
    assert!(
        daemon.0.try_wait().unwrap().is_none(),
        "SIGHUP ended the daemon"
    );
}

/// The exposure score `systemd-analyze security --offline=true` gives the
/// unit in `dir` (with the drop-ins in its `.d` directory).
fn exposure(analyze: &Path, unit: &Path) -> f64 {
    let out = Command::new(analyze)
        .args(["security", "--offline=true", "--no-pager"])
        .arg(unit)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    let line = text
        .lines()
        .find(|l| l.contains("Overall exposure level"))
        .unwrap_or_else(|| {
            panic!(
                "no score in: {text}{}",
                String::from_utf8_lossy(&out.stderr)
            )
        });
    line.split(':')
        .nth(1)
        .and_then(|v| v.split_whitespace().next())
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("score unreadable: {line}"))
}

#[test]
fn the_unit_scores_at_most_2_5_with_and_without_each_drop_in() {
    let Some(analyze) = tool("systemd-analyze") else {
        return;
    };
    let units = Path::new(env!("CARGO_MANIFEST_DIR")).join("systemd");
    let service = std::fs::read_to_string(units.join("microposd.service"))
        .unwrap()
        .replace("/usr/bin/microposd", microposd_bin().to_str().unwrap());
    for dropin in [None, Some("web-view.conf"), Some("gige-camera.conf")] {
        let dir = tempfile::tempdir().unwrap();
        let unit = dir.path().join("microposd.service");
        std::fs::write(&unit, &service).unwrap();
        if let Some(conf) = dropin {
            let d = dir.path().join("microposd.service.d");
            std::fs::create_dir(&d).unwrap();
            std::fs::copy(units.join(conf), d.join(conf)).unwrap();
        }
        let score = exposure(&analyze, &unit);
        eprintln!("exposure with {dropin:?}: {score}");
        // 3.7 (4.1 with the web drop-in) before the capability bounding
        // set, /proc, hostname, IPC and @privileged/@resources limits.
        assert!(score <= 2.5, "exposure {score} with {dropin:?}");
    }
}

#[test]
fn no_drop_in_lifts_the_ip_deny_list() {
    // An empty IPAddressDeny= resets the unit's `any`: with no deny entry
    // systemd lets every address through, whatever IPAddressAllow= says.
    let units = Path::new(env!("CARGO_MANIFEST_DIR")).join("systemd");
    let service = std::fs::read_to_string(units.join("microposd.service")).unwrap();
    assert!(service.lines().any(|l| l.trim() == "IPAddressDeny=any"));
    for conf in ["web-view.conf", "gige-camera.conf"] {
        let text = std::fs::read_to_string(units.join(conf)).unwrap();
        for l in text.lines().map(str::trim).filter(|l| !l.starts_with('#')) {
            if let Some(v) = l.strip_prefix("IPAddressDeny=") {
                assert!(!v.trim().is_empty(), "{conf} resets IPAddressDeny: {l}");
            }
        }
        assert!(
            text.lines()
                .any(|l| l.trim_start().starts_with("IPAddressAllow=")),
            "{conf} allows nothing"
        );
    }
}
