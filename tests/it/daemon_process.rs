//! Reliability of microposd with the daemon and the simulator as separate
//! processes: the `microposd` binary against the `hil-sim serve`
//! binary, through the ptys, the camera socket, the simulated clock and the
//! control socket, exactly as in a deployment against the simulated rig.
//!
//! - SIGKILL in the middle of a characterization (right after a logged
//!   point, during a move, while measuring), restart, `characterize resume`:
//!   the log holds every planned point exactly once, its header intact.
//! - Camera faults (stall, undecodable frames) during a job and during
//!   closed-loop moves: clear error codes, nothing logged or corrected on
//!   stale data, `camera` events to subscribers, recovery.
//! - A controller line dropped mid-move: the other axis halts, the fault
//!   reaches subscribers, the daemon reconnects.
//!
//! Where the binaries come from: this test lives in the root package, so
//! cargo builds `microposd` for it (`CARGO_BIN_EXE_microposd`, always
//! current). `hil-sim` is another workspace package; cargo offers no
//! artifact dependency on stable, so the test takes `hil-sim` from the same
//! target directory as `microposd` — `cargo test --workspace` (the project's
//! test command, `scripts/test.sh`) builds every package's binaries before
//! running any test. Running this file alone (`cargo test -p micropos
//! --test it daemon_process::`) needs `cargo build -p hil-sim` first; the test
//! refuses a missing or older-than-its-sources hil-sim binary with that
//! advice rather than testing a stale simulator. `HIL_SIM_BIN` and
//! `MICROPOSD_BIN` override the paths.
//!
//! Timing: the machine may be loaded (2 cores, parallel builds), so every
//! wait is on a condition with a generous deadline, never a bare sleep.

use crate::bins::{hil_sim_bin, microposd_bin};
use micropos::charact::log;
use micropos::charact::plan::ScanPlan;
use serde_json::{json, Value};
use std::io::{BufRead, BufReader, Write};
use std::os::unix::net::UnixStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// Generous: builds may run in parallel on 2 cores.
const DEADLINE: Duration = Duration::from_secs(90);

/// The test's directory (sockets, logs, the daemon's stderr): removed
/// afterwards unless `MICROPOS_KEEP_TMP` is set, to read a failure's
/// daemon log (`microposd-N.log`) afterwards; its path is printed.
fn test_dir() -> tempfile::TempDir {
    let keep = std::env::var_os("MICROPOS_KEEP_TMP").is_some();
    let dir = tempfile::Builder::new()
        .prefix("daemon_process")
        .disable_cleanup(keep)
        .tempdir()
        .unwrap();
    if keep {
        eprintln!("test directory kept: {}", dir.path().display());
    }
    dir
}

/// A child process killed (SIGKILL) and reaped on drop.
struct Proc(Child);

impl Drop for Proc {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

struct Sim {
    _p: Proc,
    control: PathBuf,
}

impl Sim {
    fn start(dir: &Path, time_scale: f64) -> Sim {
        let mut child = Command::new(hil_sim_bin())
            .args(["serve", "--link-dir"])
            .arg(dir)
            .args(["--seed", "3", "--time-scale", &time_scale.to_string()])
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        let mut line = String::new();
        BufReader::new(child.stdout.take().unwrap())
            .read_line(&mut line)
            .unwrap();
        assert!(line.starts_with("hil-sim ready"), "{line}");
        let control = line
            .split_whitespace()
            .find_map(|w| w.strip_prefix("control="))
            .unwrap()
            .into();
        Sim {
            _p: Proc(child),
            control,
        }
    }

    fn control(&self, req: Value) -> Value {
        let mut s = UnixStream::connect(&self.control).unwrap();
        s.set_read_timeout(Some(DEADLINE)).unwrap();
        writeln!(s, "{req}").unwrap();
        let mut reply = String::new();
        BufReader::new(s).read_line(&mut reply).unwrap();
        let v: Value = serde_json::from_str(&reply).unwrap();
        assert_eq!(v["ok"], true, "{req} -> {v}");
        v
    }

    fn camera(&self, mode: &str) {
        self.control(json!({ "camera": mode }));
    }
}

fn set(t: &mut toml::Table, section: &str, key: &str, v: i64) {
    t[section]
        .as_table_mut()
        .unwrap()
        .insert(key.into(), toml::Value::Integer(v));
}

/// The shipped simulated-rig config (config/microposd-sim.toml) moved into
/// `dir`, with test timings: generous timeouts for a loaded machine.
fn daemon_config(dir: &Path) -> PathBuf {
    let text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/config/microposd-sim.toml"
    ))
    .unwrap()
    .replace("/tmp/rig", dir.to_str().unwrap());
    let mut t: toml::Table = toml::from_str(&text).unwrap();
    set(&mut t, "daemon", "poll_interval_ms", 50);
    for a in ["x", "y"] {
        let d = t["driver"].as_table_mut().unwrap();
        set(d, a, "timeout_ms", 2000);
    }
    // A frame may take long on a loaded machine; a stall is detected
    // after this much wall time.
    set(&mut t, "camera", "timeout_ms", 6000);
    // One retry of a failed job operation (each camera retry waits the
    // timeout above again).
    set(&mut t, "daemon", "job_retries", 1);
    let p = dir.join("microposd.toml");
    std::fs::write(&p, toml::to_string(&t).unwrap()).unwrap();
    p
}

struct Daemon {
    p: Proc,
    socket: PathBuf,
    log: PathBuf,
}

impl Daemon {
    fn start(dir: &Path, n: u32) -> Daemon {
        let cfg = daemon_config(dir);
        let log = dir.join(format!("microposd-{n}.log"));
        let err = std::fs::File::create(&log).unwrap();
        let child = Command::new(microposd_bin())
            .arg("-c")
            .arg(&cfg)
            .stdout(Stdio::null())
            .stderr(err)
            .spawn()
            .unwrap();
        let d = Daemon {
            p: Proc(child),
            socket: dir.join("micropos.sock"),
            log,
        };
        let t = Instant::now();
        let mut c = loop {
            if let Ok(s) = UnixStream::connect(&d.socket) {
                break Client::from(s);
            }
            assert!(t.elapsed() < DEADLINE, "microposd did not listen");
            std::thread::sleep(Duration::from_millis(20));
        };
        c.wait_for(|s| s["rig"]["connected"] == json!({"x": true, "y": true}));
        d
    }

    /// What the daemon wrote to stderr so far (its tracing log).
    fn log_text(&self) -> String {
        std::fs::read_to_string(&self.log).unwrap_or_default()
    }

    fn client(&self) -> Client {
        let mut c = Client::from(UnixStream::connect(&self.socket).unwrap());
        c.log = Some(self.log.clone());
        c
    }

    fn sigkill(mut self) {
        self.p.0.kill().unwrap();
        let st = self.p.0.wait().unwrap();
        assert!(!st.success());
    }
}

struct Client {
    /// The daemon's log, shown when an answer does not come.
    log: Option<PathBuf>,
    r: BufReader<UnixStream>,
    w: UnixStream,
    next: u64,
    /// Events read but not yet asked for (replies and events interleave).
    events: std::collections::VecDeque<Value>,
}

impl From<UnixStream> for Client {
    fn from(s: UnixStream) -> Client {
        s.set_read_timeout(Some(DEADLINE)).unwrap();
        Client {
            log: None,
            w: s.try_clone().unwrap(),
            r: BufReader::new(s),
            next: 0,
            events: Default::default(),
        }
    }
}

impl Client {
    fn line(&mut self) -> Value {
        let mut l = String::new();
        let n = match self.r.read_line(&mut l) {
            Ok(n) => n,
            Err(e) => {
                panic!(
                    "no line within the deadline ({e}); events read but not asked for: {:?}\nthe daemon's log ends:\n{}",
                    self.events,
                    self.log_tail()
                );
            }
        };
        assert!(n > 0, "connection closed");
        serde_json::from_str(&l).unwrap()
    }

    /// A request and its reply (events in between are skipped).
    fn call(&mut self, mut req: Value) -> Value {
        self.next += 1;
        req["id"] = json!(self.next);
        writeln!(self.w, "{req}").unwrap();
        loop {
            let v = self.line();
            if v.get("event").is_none() {
                assert_eq!(v["id"], json!(self.next), "{v}");
                return v;
            }
            self.events.push_back(v);
        }
    }

    /// A request that must succeed; a refusal shows the daemon's log tail
    /// (a fault's reason is there, not in the reply).
    fn ok(&mut self, req: Value) -> Value {
        let v = self.call(req.clone());
        if v["ok"] != true {
            panic!("{req} -> {v}\nthe daemon's log ends:\n{}", self.log_tail());
        }
        v
    }

    /// The last 40 lines of the daemon's log (empty without one).
    fn log_tail(&self) -> String {
        let log = self
            .log
            .as_ref()
            .and_then(|p| std::fs::read_to_string(p).ok())
            .unwrap_or_default();
        let lines: Vec<&str> = log.lines().collect();
        lines[lines.len().saturating_sub(40)..].join("\n")
    }

    /// Polls `status` until `f` holds.
    fn wait_for(&mut self, f: impl Fn(&Value) -> bool) -> Value {
        let t = Instant::now();
        loop {
            let s = self.ok(json!({"cmd": "status"}));
            if f(&s) {
                return s;
            }
            assert!(t.elapsed() < DEADLINE, "condition not reached: {s}");
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// The oldest event satisfying `f` (earlier events that do not are
    /// kept for later questions).
    fn event(&mut self, f: impl Fn(&Value) -> bool) -> Value {
        if let Some(i) = self.events.iter().position(&f) {
            return self.events.remove(i).unwrap();
        }
        loop {
            let v = self.line();
            if v.get("event").is_some() {
                if f(&v) {
                    return v;
                }
                self.events.push_back(v);
            }
        }
    }

    /// Forgets the events read so far (a later question must be answered
    /// by a later event).
    fn forget_events(&mut self) {
        self.events.clear();
    }
}

fn code(v: &Value) -> &str {
    v["error"]["code"].as_str().unwrap_or("")
}

fn job_start(c: &mut Client, log: &str) -> Value {
    c.ok(json!({"cmd": "characterize", "action": "start", "log": log,
                "step_um": 500.0, "x_range_um": 1000.0, "y_range_um": 1000.0,
                "cycles": 1, "frames_per_point": 1, "settle_s": 0.1}))
}

/// Every planned point exactly once, in plan order, measured (a stale or
/// made-up measurement is a step away from its target), times increasing.
fn check_log(path: &Path, metadata: Option<&log::Metadata>) -> log::MeasurementLog {
    let l = log::read_file(path).unwrap();
    assert!(l.is_complete(), "torn tail: {:?}", l.torn_tail);
    assert!(l.warnings.is_empty(), "{:?}", l.warnings);
    if let Some(md) = metadata {
        assert_eq!(&l.metadata, md, "the header changed");
    }
    let plan = ScanPlan::from_metadata(&l.metadata).unwrap();
    let points = plan.points();
    assert_eq!(l.records.len(), points.len(), "points lost or duplicated");
    let mut last_t = f64::NEG_INFINITY;
    for (i, (r, p)) in l.records.iter().zip(&points).enumerate() {
        assert_eq!(
            (r.segment.as_str(), r.cycle, r.x_target_um, r.y_target_um),
            (p.segment, p.cycle, p.x_um, p.y_um),
            "record {i}"
        );
        assert!(
            (r.x_meas_um - r.x_target_um).abs() < 20.0
                && (r.y_meas_um - r.y_target_um).abs() < 20.0,
            "record {i} measured far from its target (stale frame?): {r:?}"
        );
        assert!(r.t_s >= last_t, "record {i}: time went back");
        last_t = r.t_s;
    }
    l
}

/// Subscribes to job events and waits until the job reports `done >= n`
/// (or ends).
fn wait_done(sub: &mut Client, n: u64) -> Value {
    sub.event(|e| e["event"] == "job" && (e["done"].as_u64() >= Some(n) || e["state"] != "running"))
}

#[test]
fn sigkill_mid_characterization_resumes_every_point_once() {
    let dir = test_dir();
    // Slow enough simulated time that a move lasts a few wall milliseconds
    // (the kill during a move must find one), fast enough to reference.
    let sim = Sim::start(dir.path(), 5.0);
    let mut d = Daemon::start(dir.path(), 0);
    let mut c = d.client();
    c.ok(json!({"cmd": "reference"}));
    let mut sub = d.client();
    sub.ok(json!({"cmd": "subscribe", "topics": ["job"]}));
    let j = job_start(&mut c, "kill.csv");
    let total = j["job"]["total"].as_u64().unwrap();
    assert_eq!(total, 12);
    let path = dir.path().join("data/kill.csv");
    let mut metadata = None;
    // (when to kill, description)
    let kills = ["after a logged point", "during a move", "while measuring"];
    for (k, how) in kills.iter().enumerate() {
        let after = 2 + 3 * k as u64;
        let ev = wait_done(&mut sub, after);
        assert_eq!(ev["state"], "running", "job ended early: {ev}");
        match k {
            0 => {}
            1 => {
                // Poll the ground truth until the stage moves.
                let t = Instant::now();
                while sim.control(json!({"query": "truth"}))["moving"] != true {
                    assert!(t.elapsed() < DEADLINE, "no move seen");
                }
            }
            _ => {
                // A move starts and ends: now the job settles and measures.
                let t = Instant::now();
                while sim.control(json!({"query": "truth"}))["moving"] != true {
                    assert!(t.elapsed() < DEADLINE, "no move seen");
                }
                while sim.control(json!({"query": "truth"}))["moving"] == true {
                    assert!(t.elapsed() < DEADLINE, "move did not end");
                }
            }
        }
        d.sigkill();
        eprintln!("killed {how}");
        let l = log::read_file(&path).unwrap();
        assert!(
            l.records.len() as u64 >= after,
            "{how}: {}",
            l.records.len()
        );
        match &metadata {
            None => metadata = Some(l.metadata.clone()),
            Some(md) => assert_eq!(&l.metadata, md),
        }
        d = Daemon::start(dir.path(), k as u32 + 1);
        c = d.client();
        sub = d.client();
        sub.ok(json!({"cmd": "subscribe", "topics": ["job"]}));
        // The controllers kept their reference: no new reference run.
        let st = c.ok(json!({"cmd": "status"}));
        assert_eq!(st["rig"]["referenced"], json!({"x": true, "y": true}));
        let r = c.ok(json!({"cmd": "characterize", "action": "resume", "log": "kill.csv"}));
        assert_eq!(r["job"]["done"].as_u64(), Some(l.records.len() as u64));
    }
    let ev = wait_done(&mut sub, total);
    let ev = if ev["state"] == "running" {
        sub.event(|e| e["event"] == "job" && e["state"] != "running")
    } else {
        ev
    };
    assert_eq!(ev["state"], "done", "{ev}");
    check_log(&path, metadata.as_ref());
    // A complete log cannot be resumed again.
    let r = c.call(json!({"cmd": "characterize", "action": "resume", "log": "kill.csv"}));
    assert_eq!(code(&r), "job_state", "{r}");
}

/// A closed-loop move to `(x, y)`.
fn closed_loop(c: &mut Client, x: f64, y: f64) -> Value {
    c.call(json!({"cmd": "move", "x_um": x, "y_um": y, "mode": "closed_loop", "wait": true}))
}

#[test]
fn camera_faults_fail_clearly_and_never_use_stale_data() {
    let dir = test_dir();
    let sim = Sim::start(dir.path(), 20.0);
    let d = Daemon::start(dir.path(), 0);
    let mut c = d.client();
    c.ok(json!({"cmd": "reference"}));
    let mut sub = d.client();
    sub.ok(json!({"cmd": "subscribe", "topics": ["job", "fault"]}));

    // A job point with no valid frame: the job fails with the reason, logs
    // nothing made up, and resumes once the camera is back.
    job_start(&mut c, "cam.csv");
    let path = dir.path().join("data/cam.csv");
    for (fault, want_code, want_state) in [
        ("stall", "camera_stalled", "stalled"),
        ("garbage", "low_quality", "undecodable"),
    ] {
        sub.forget_events();
        let ev = wait_done(
            &mut sub,
            2 + log::read_file(&path).map_or(0, |l| l.records.len() as u64),
        );
        assert_eq!(ev["state"], "running", "{ev}");
        sim.camera(fault);
        let ev = sub.event(|e| e["event"] == "job" && e["state"] != "running");
        assert_eq!(ev["state"], "failed", "{ev}");
        let err = ev["error"].as_str().unwrap();
        assert!(err.starts_with(want_code), "{fault}: {err}");
        assert!(err.contains("not logged"), "{err}");
        assert!(err.contains("persisted through 1 retry;"), "{err}");
        let cam = sub.event(|e| e["event"] == "camera");
        assert_eq!(cam["state"], want_state, "{cam}");
        let l = log::read_file(&path).unwrap();
        assert_eq!(Some(l.records.len() as u64), ev["done"].as_u64(), "{ev}");
        sub.forget_events();
        sim.camera("normal");
        let ok = sub.event(|e| e["event"] == "camera");
        assert_eq!(ok["state"], "ok", "{ok}");
        c.ok(json!({"cmd": "characterize", "action": "resume", "log": "cam.csv"}));
    }
    let ev = sub.event(|e| e["event"] == "job" && e["state"] != "running");
    assert_eq!(ev["state"], "done", "{ev}");
    let l = check_log(&path, None);

    // Closed loop needs a table and the vision → stage transform the job
    // established itself (its tie pre-scan, in the log's metadata).
    let md = |k: &str| -> f64 { l.metadata.get(k).unwrap().parse().unwrap() };
    let frame = micropos::comp::VisionFrame {
        rotation_rad: md("vision_frame_rotation_rad"),
        mirrored: l.metadata.get("vision_frame_mirrored").unwrap() == "true",
        translation_um: [
            md("vision_frame_translation_x_um"),
            md("vision_frame_translation_y_um"),
        ],
    };
    let model =
        micropos::model::StageModel::from_toml(micropos::model::PAPER_DEFAULT_TOML).unwrap();
    let tmpl = micropos::comp::compensation_template(&model).unwrap();
    let mut file =
        micropos::comp::CompFile::model(&tmpl, "test", micropos::comp::SourceInfo::default())
            .unwrap();
    file.frame = Some(frame);
    file.write_path(dir.path().join("data/cl.toml")).unwrap();
    c.ok(json!({"cmd": "tables", "action": "load", "name": "cl.toml"}));
    c.ok(json!({"cmd": "tables", "action": "activate", "name": "cl.toml"}));
    let m = closed_loop(&mut c, 7700.0, 7600.0);
    assert_eq!(m["ok"], true, "{m}");
    let true_um = |sim: &Sim| {
        let t = sim.control(json!({"query": "truth"}));
        [
            t["true_x_um"].as_f64().unwrap(),
            t["true_y_um"].as_f64().unwrap(),
        ]
    };
    let before = true_um(&sim);

    for (fault, want_code, want_state, target) in [
        ("stall", "camera_stalled", "stalled", [7300.0, 7400.0]),
        ("garbage", "low_quality", "undecodable", [7700.0, 7600.0]),
    ] {
        sub.forget_events();
        sim.camera(fault);
        let cam = sub.event(|e| e["event"] == "camera");
        assert_eq!(cam["state"], want_state, "{cam}");
        let m = closed_loop(&mut c, target[0], target[1]);
        assert_eq!(code(&m), want_code, "{fault}: {m}");
        // Not corrected on stale data: the last frame saw the previous
        // target, 400 µm away; a correction from it would command far off.
        let p = c.ok(json!({"cmd": "position"}));
        for (i, a) in ["x_um", "y_um"].into_iter().enumerate() {
            let cmd = p["commanded"][a].as_f64().unwrap();
            assert!((cmd - target[i]).abs() < 20.0, "{fault}: {p}");
        }
        // Raw moves do not need the camera.
        let r = c.ok(json!({"cmd": "move", "x_um": target[0] + 10.0, "wait": true}));
        assert_eq!(r["on_target"], true, "{r}");
        sub.forget_events();
        sim.camera("normal");
        let ok = sub.event(|e| e["event"] == "camera");
        assert_eq!(ok["state"], "ok", "{ok}");
        // Closed loop works again.
        let m = closed_loop(&mut c, target[0], target[1]);
        assert_eq!(m["ok"], true, "{fault}, after: {m}");
        let res = &m["closed_loop"]["residual_um"];
        assert!(res["x_um"].as_f64().unwrap().abs() < 0.2, "{m}");
    }
    // The last recovery went to the first target again: the stage is
    // where the closed loop put it before the faults (its frame is the
    // job's, offset by the stage's error at the first point, so compare
    // with itself rather than with the commanded numbers).
    let after = true_um(&sim);
    for i in 0..2 {
        assert!((after[i] - before[i]).abs() < 0.5, "{before:?} {after:?}");
    }
    // A relative move after a closed loop continues from the target the
    // user asked for, not from the loop's last corrected command, and an
    // axis it leaves out keeps that target.
    let corrected = &m["closed_loop"]["commanded"];
    assert!(
        (corrected["x_um"].as_f64().unwrap() - 7700.0).abs() > 1e-3,
        "the loop corrected the command: {m}"
    );
    let r = c.ok(json!({"cmd": "move", "x_um": 100.0, "relative": true,
                        "mode": "compensated", "wait": true}));
    assert_eq!(r["target"]["x_um"].as_f64(), Some(7800.0), "{r}");
    assert_eq!(r["target"]["y_um"].as_f64(), Some(7600.0), "{r}");
}

#[test]
fn line_drop_mid_move_halts_the_other_axis_reconnects_and_power_cycle_needs_reference() {
    let dir = test_dir();
    // Slow simulated time: the moves last wall seconds.
    let sim = Sim::start(dir.path(), 2.0);
    let d = Daemon::start(dir.path(), 0);
    let mut c = d.client();
    c.ok(json!({"cmd": "reference"}));
    let mut sub = d.client();
    sub.ok(json!({"cmd": "subscribe", "topics": ["fault"]}));
    c.ok(json!({"cmd": "move", "x_um": 9000.0, "y_um": 14000.0}));
    let t = Instant::now();
    while sim.control(json!({"query": "truth"}))["moving"] != true {
        assert!(t.elapsed() < DEADLINE, "no move seen");
    }
    sim.control(json!({"axis": "x", "fault": "drop_line"}));
    let ev = sub.event(|e| e["event"] == "fault");
    assert!(ev["reason"].as_str().unwrap().contains("axis x"), "{ev}");
    // Y halts well before its target.
    let t = Instant::now();
    while sim.control(json!({"query": "truth"}))["moving"] == true {
        assert!(t.elapsed() < DEADLINE, "y never halted");
    }
    let y = sim.control(json!({"query": "truth"}))["true_y_um"]
        .as_f64()
        .unwrap();
    assert!(y < 13_900.0, "y reached its target: {y}");
    let m = c.call(json!({"cmd": "move", "y_um": 8000.0}));
    assert_eq!(code(&m), "not_connected", "{m}");
    sim.control(json!({"axis": "x", "fault": "restore_line"}));
    c.wait_for(|s| s["rig"]["connected"]["x"] == true);
    // The line loss stays latched until a client resets it.
    let m = c.call(json!({"cmd": "move", "x_um": 8000.0}));
    assert_eq!(code(&m), "fault_latched", "{m}");
    c.ok(json!({"cmd": "reset"}));
    c.ok(json!({"cmd": "move", "x_um": 8000.0, "y_um": 8000.0, "wait": true}));
    // A power cycle loses the reference: a latched fault, and after the
    // reset moves are still refused (before any byte reaches the
    // controller) until the axis is referenced again.
    sim.control(json!({"axis": "y", "fault": "power_cycle"}));
    let t = Instant::now();
    loop {
        let m = c.call(json!({"cmd": "move", "y_um": 7000.0}));
        if code(&m) == "fault_latched" {
            break;
        }
        assert!(t.elapsed() < DEADLINE, "power cycle unnoticed: {m}");
        std::thread::sleep(Duration::from_millis(100));
    }
    c.ok(json!({"cmd": "reset"}));
    let m = c.call(json!({"cmd": "move", "y_um": 7000.0}));
    assert_eq!(code(&m), "not_referenced", "{m}");
    // A two-axis move with one axis unreferenced is refused as a whole:
    // the referenced axis does not move either.
    let (before, _) = truth(&sim);
    let m = c.call(json!({"cmd": "move", "x_um": 12_000.0, "y_um": 7000.0}));
    assert_eq!(code(&m), "not_referenced", "{m}");
    std::thread::sleep(Duration::from_millis(300));
    let (after, moving) = truth(&sim);
    assert!(
        !moving && (after[0] - before[0]).abs() < 5.0,
        "x moved: {before:?} → {after:?}"
    );
    c.ok(json!({"cmd": "reference", "axes": "y"}));
    c.ok(json!({"cmd": "move", "y_um": 7000.0, "wait": true}));
}

/// A line that comes back mid-move: its controller ran on, unwatched,
/// while the line was down; the re-opened line's first bytes stop it
/// (`#24`), before the daemon's own checks. Measured from the line's
/// return to rest through the simulator's truth (`--nocapture | grep
/// HALT`); it ran on 1.0 mm when the daemon's halt came after the bring-up
/// exchanges.
#[test]
fn a_line_back_mid_move_stops_its_axis_first() {
    let dir = test_dir();
    let sim = Sim::start(dir.path(), 2.0);
    let d = Daemon::start(dir.path(), 0);
    let mut c = d.client();
    c.ok(json!({"cmd": "reference"}));
    long_move(&mut c, &sim, 14_500.0, 12_500.0);
    sim.control(json!({"axis": "x", "fault": "drop_line"}));
    // Down for a while: x runs on (nobody can stop it), y is halted.
    std::thread::sleep(Duration::from_millis(400));
    let (p, moving) = truth(&sim);
    assert!(moving && p[0] < 13_000.0, "x is not running on: {p:?}");
    let h = halt_figures(&sim, || {
        sim.control(json!({"axis": "x", "fault": "restore_line"}));
    });
    println!(
        "HALT | x's line back mid-move (microposd process, hil-sim serve ×2) | at rest {:.3} s simulated ({:.3} s wall) after the line's return | x ran on {:.1} µm |",
        h.sim_s, h.wall_s, h.travel_um[0]
    );
    assert!(h.travel_um[0] < 500.0, "{h:?}");
    c.wait_for(|s| s["rig"]["connected"]["x"] == true);
    at_rest_short_of(&sim, [14_500.0, 12_500.0]);
    let log = d.log_text();
    assert!(log.contains("stop all (#24) sent first"), "{log}");
}

/// `drift_every_s`: reference re-measurements are logged as `drift_ref`
/// records at the reference (default: the start corner), are not plan
/// points, and a cancelled job resumes at the right plan point with the
/// drift plan read back from the log.
#[test]
fn drift_references_are_logged_and_resume_keeps_the_plan() {
    let dir = test_dir();
    let sim = Sim::start(dir.path(), 20.0);
    let d = Daemon::start(dir.path(), 0);
    let mut c = d.client();
    c.ok(json!({"cmd": "reference"}));
    let mut sub = d.client();
    sub.ok(json!({"cmd": "subscribe", "topics": ["job"]}));
    // A tiny interval: a re-measurement before every point.
    let j = c.ok(
        json!({"cmd": "characterize", "action": "start", "log": "drift.csv",
                        "step_um": 500.0, "x_range_um": 1000.0, "y_range_um": 1000.0,
                        "cycles": 1, "frames_per_point": 1, "settle_s": 0.1,
                        "drift_every_s": 0.001}),
    );
    assert_eq!(j["job"]["total"].as_u64(), Some(12));
    wait_done(&mut sub, 4);
    c.ok(json!({"cmd": "characterize", "action": "cancel"}));
    let path = dir.path().join("data/drift.csv");
    let l = log::read_file(&path).unwrap();
    let logged = l
        .records
        .iter()
        .filter(|r| r.segment != "drift_ref")
        .count();
    assert!((4..12).contains(&logged), "{logged}");
    let ev = sub.event(|e| e["event"] == "job" && e["state"] == "cancelled");
    assert_eq!(ev["log"], "drift.csv");
    sub.forget_events();
    let r = c.ok(json!({"cmd": "characterize", "action": "resume", "log": "drift.csv"}));
    assert_eq!(r["job"]["done"].as_u64(), Some(logged as u64));
    let ev = sub.event(|e| e["event"] == "job" && e["state"] != "running");
    assert_eq!(ev["state"], "done", "{ev}");
    let l = log::read_file(&path).unwrap();
    assert!(l.is_complete() && l.warnings.is_empty(), "{:?}", l.warnings);
    let plan = ScanPlan::from_metadata(&l.metadata).unwrap();
    let corner = [plan.x_start_um, plan.y_start_um];
    let (refs, scans): (Vec<_>, Vec<_>) = l.records.iter().partition(|r| r.segment == "drift_ref");
    let points = plan.points();
    assert_eq!(scans.len(), points.len(), "points lost or duplicated");
    for (i, (r, p)) in scans.iter().zip(&points).enumerate() {
        assert_eq!(
            (r.segment.as_str(), r.x_target_um, r.y_target_um),
            (p.segment, p.x_um, p.y_um),
            "record {i}"
        );
    }
    // After each detour the job re-approached the next point from the
    // side of its pass, unlogged; the `approach` column says so (empty on
    // the references, which scan no axis).
    let col = l
        .columns
        .extra
        .iter()
        .position(|c| c == "approach")
        .unwrap();
    for r in &l.records {
        let want = match r.segment.as_str() {
            "drift_ref" => "",
            s if s.ends_with("_bwd") => "bwd",
            _ => "fwd",
        };
        assert_eq!(r.extra[col], want, "{r:?}");
    }
    assert!(refs.len() >= points.len(), "{} references", refs.len());
    for r in &refs {
        assert_eq!([r.x_target_um, r.y_target_um], corner);
        assert!(
            (r.x_meas_um - corner[0]).abs() < 20.0 && (r.y_meas_um - corner[1]).abs() < 20.0,
            "reference measured far from the corner: {r:?}"
        );
    }
    assert_eq!(l.metadata.get("drift_every_s"), Some("0.001"));
    // `tables build` uses the references and says so.
    let b = c.ok(
        json!({"cmd": "tables", "action": "build", "log": "drift.csv",
                        "kinds": ["paper"]}),
    );
    assert_eq!(
        b["drift"]["references"].as_u64(),
        Some(refs.len() as u64),
        "{b}"
    );
    assert_eq!(
        b["drift"]["corrected"].as_u64(),
        Some(points.len() as u64),
        "{b}"
    );

    // Live drift correction against the table's baseline: the
    // table records where the reference was at the start of the run.
    let name = b["paper"]["name"].as_str().unwrap().to_owned();
    c.ok(json!({"cmd": "tables", "action": "activate", "name": name}));
    let mut dsub = d.client();
    dsub.ok(json!({"cmd": "subscribe", "topics": ["drift"]}));
    // Off by default: compensated moves say nothing about drift.
    let target = [corner[0] + 500.0, corner[1] + 500.0];
    let m = c.ok(json!({"cmd": "move", "x_um": target[0], "y_um": target[1],
                        "mode": "compensated", "wait": true}));
    assert!(m.get("drift").is_none(), "{m}");
    let r = c.ok(
        json!({"cmd": "drift", "action": "set", "method": "adaptive",
                        "every_s": 0.001}),
    );
    assert_eq!(r["drift"]["method"], "adaptive", "{r}");
    // Due before the move: re-measured, then corrected.
    let m = c.ok(json!({"cmd": "move", "x_um": target[0], "y_um": target[1],
                        "mode": "compensated", "wait": true}));
    let corr = &m["drift"]["correction_um"];
    assert!(m["drift"]["measured"].is_object(), "{m}");
    assert!(corr[0].is_f64() && corr[1].is_f64(), "{m}");
    // The command is the table's for the target shifted by the drift: the
    // target itself is reported as asked.
    assert_eq!(m["target"]["x_um"].as_f64(), Some(target[0]), "{m}");
    let ev = dsub.event(|e| e["event"] == "drift" && e["state"] == "measured");
    assert_eq!(ev["drift"]["baseline"], "table", "{ev}");
    assert_eq!(ev["drift"]["reference_um"], json!(corner), "{ev}");
    // A relative move continues from the user's target, not the shifted one
    // (and not from the reference point the re-measurement visited).
    let m = c.ok(json!({"cmd": "move", "x_um": 100.0, "relative": true,
                        "mode": "compensated", "wait": true}));
    assert_eq!(m["target"]["x_um"].as_f64(), Some(target[0] + 100.0), "{m}");
    assert_eq!(m["target"]["y_um"].as_f64(), Some(target[1]), "{m}");
    let before = c.ok(json!({"cmd": "status"}))["drift"].clone();
    assert_eq!(before["references"], 2, "{before}");
    // A failing re-measurement (undecodable frames) leaves the estimate:
    // the move goes on with the last good one and says why.
    dsub.forget_events();
    sim.camera("garbage");
    let m = c.ok(json!({"cmd": "move", "x_um": target[0], "y_um": target[1],
                        "mode": "compensated", "wait": true}));
    let err = m["drift"]["error"].as_str().unwrap_or("");
    assert!(err.starts_with("low_quality"), "{m}");
    assert!(m["drift"]["correction_um"][0].is_f64(), "{m}");
    // (Earlier `measured` events may still be in flight: ask for the failure.)
    let ev = dsub.event(|e| e["event"] == "drift" && e["state"] == "failed");
    assert!(
        ev["error"]
            .as_str()
            .unwrap_or("")
            .starts_with("low_quality"),
        "{ev}"
    );
    let after = c.ok(json!({"cmd": "status"}))["drift"].clone();
    assert_eq!(after["references"], 2, "{after}");
    assert_eq!(after["last"], before["last"], "estimate unchanged");
    assert_eq!(after["failures"], 1, "{after}");
    sim.camera("normal");
    let r = c.ok(json!({"cmd": "drift", "action": "measure"}));
    assert_eq!(r["drift"]["references"], 3, "{r}");
    assert_eq!(r["drift"]["failures"], 0, "{r}");
    let r = c.ok(json!({"cmd": "drift", "action": "reset"}));
    assert_eq!(r["drift"]["references"], 0, "{r}");
    // No line dropped in this test: the lines' first opens at start-up are
    // not reconnections (each was halted, racing the first `reference`).
    let log = d.log_text();
    assert!(!log.contains("reconnected"), "{log}");
}

/// Truth positions (µm) and whether anything moves.
fn truth(sim: &Sim) -> ([f64; 2], bool) {
    let t = sim.control(json!({"query": "truth"}));
    (
        [
            t["true_x_um"].as_f64().unwrap(),
            t["true_y_um"].as_f64().unwrap(),
        ],
        t["moving"] == true,
    )
}

/// Starts a long move of both axes and waits until the rig moves.
fn long_move(c: &mut Client, sim: &Sim, x_um: f64, y_um: f64) {
    c.ok(json!({"cmd": "move", "x_um": x_um, "y_um": y_um}));
    let t = Instant::now();
    while !truth(sim).1 {
        assert!(t.elapsed() < DEADLINE, "no move seen");
    }
    std::thread::sleep(Duration::from_millis(300));
}

/// The rig is at rest now and stays there (the stage model's creep moves
/// the true position by µm at most), far from the move's target.
fn at_rest_short_of(sim: &Sim, target: [f64; 2]) {
    let (p, moving) = truth(sim);
    assert!(!moving, "still moving at {p:?}");
    std::thread::sleep(Duration::from_millis(300));
    let (q, moving) = truth(sim);
    assert!(!moving, "moving again at {q:?}");
    for i in 0..2 {
        assert!((p[i] - q[i]).abs() < 5.0, "{p:?} → {q:?}");
        assert!(
            (q[i] - target[i]).abs() > 1000.0,
            "reached its target: {q:?}"
        );
    }
}

/// What the rig did from an action (a signal, the stop hook) until it
/// stood still, sampled through the control socket as fast as it answers.
#[derive(Debug)]
struct HaltFigures {
    /// Simulated time from the action to the first sample at rest, s.
    sim_s: f64,
    /// The same in wall time, s.
    wall_s: f64,
    /// Distance from the position at the action to the rest position, µm.
    travel_um: [f64; 2],
}

/// Runs `action` (on a thread of its own) and samples the truth until
/// neither axis moves.
fn halt_figures(sim: &Sim, action: impl FnOnce() + Send) -> HaltFigures {
    let t0 = sim.control(json!({"query": "truth"}));
    let p0 = [
        t0["true_x_um"].as_f64().unwrap(),
        t0["true_y_um"].as_f64().unwrap(),
    ];
    let s0 = t0["sim_time_s"].as_f64().unwrap();
    let w0 = Instant::now();
    std::thread::scope(|s| {
        let h = s.spawn(action);
        let out = loop {
            let t = sim.control(json!({"query": "truth"}));
            if t["moving"] == false {
                let p = [
                    t["true_x_um"].as_f64().unwrap(),
                    t["true_y_um"].as_f64().unwrap(),
                ];
                break HaltFigures {
                    sim_s: t["sim_time_s"].as_f64().unwrap() - s0,
                    wall_s: w0.elapsed().as_secs_f64(),
                    travel_um: [(p[0] - p0[0]).abs(), (p[1] - p0[1]).abs()],
                };
            }
            assert!(w0.elapsed() < DEADLINE, "still moving: {t}");
        };
        h.join().unwrap();
        out
    })
}

/// The unit's stop hook, `microposd -c CFG --halt`: must exit 0 (`what`
/// names the case in the failure).
fn stop_hook(cfg: &Path, what: &str) {
    let out = Command::new(microposd_bin())
        .arg("-c")
        .arg(cfg)
        .arg("--halt")
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{what}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// Longest a halt by SIGTERM or by the stop hook may take, simulated s
/// (the deceleration from 1 mm/s takes 0.1 s; the rest is the daemon's or
/// the hook's start-up on a loaded machine at time scale 2).
const PROCESS_HALT_BOUND_S: f64 = 2.0;

/// The real binaries: SIGTERM mid-move makes microposd halt both axes and
/// wait for rest before it exits (0); after a SIGKILL mid-move the stage
/// runs on until the unit's stop hook, `microposd --halt`, stops it. Prints
/// the figures of the fault table (`--nocapture | grep HALT`).
#[test]
fn sigterm_halts_before_exit_and_the_stop_hook_halts_after_sigkill() {
    let dir = test_dir();
    let sim = Sim::start(dir.path(), 2.0);
    let mut d = Daemon::start(dir.path(), 0);
    let mut c = d.client();
    c.ok(json!({"cmd": "reference"}));
    long_move(&mut c, &sim, 13_500.0, 1_500.0);
    let pid = d.p.0.id().to_string();
    let h = halt_figures(&sim, || {
        let st = Command::new("kill").args(["-TERM", &pid]).status().unwrap();
        assert!(st.success());
    });
    println!(
        "HALT | SIGTERM mid-move (microposd process, hil-sim serve ×2) | x, y at rest {:.3} s simulated ({:.3} s wall) | x {:.1} µm, y {:.1} µm |",
        h.sim_s, h.wall_s, h.travel_um[0], h.travel_um[1]
    );
    assert!(h.sim_s < PROCESS_HALT_BOUND_S, "{h:?}");
    let st = d.p.0.wait().unwrap();
    assert!(st.success(), "microposd exited with {st}");
    at_rest_short_of(&sim, [13_500.0, 1_500.0]);
    let log = std::fs::read_to_string(dir.path().join("microposd-0.log")).unwrap();
    assert!(log.contains("halting both axes"), "{log}");
    assert_requested_halts_do_not_warn(&log);

    d = Daemon::start(dir.path(), 1);
    let mut c = d.client();
    long_move(&mut c, &sim, 1_500.0, 13_500.0);
    let (p_kill, _) = truth(&sim);
    d.sigkill();
    // Nobody halted it: the move runs on.
    std::thread::sleep(Duration::from_millis(200));
    assert!(truth(&sim).1, "the stage stopped by itself");
    let cfg = daemon_config(dir.path());
    let h = halt_figures(&sim, || stop_hook(&cfg, "after SIGKILL"));
    let (p_rest, _) = truth(&sim);
    println!(
        "HALT | SIGKILL mid-move, then microposd --halt 0.2 s (wall) later | at rest {:.3} s simulated ({:.3} s wall) after the hook started | x {:.1} µm, y {:.1} µm after the hook started; {:.1} µm, {:.1} µm after the kill |",
        h.sim_s,
        h.wall_s,
        h.travel_um[0],
        h.travel_um[1],
        (p_rest[0] - p_kill[0]).abs(),
        (p_rest[1] - p_kill[1]).abs()
    );
    assert!(h.sim_s < PROCESS_HALT_BOUND_S, "{h:?}");
    at_rest_short_of(&sim, [1_500.0, 13_500.0]);
}

/// `microposd --halt`, the stop hook, on a loaded machine (four spinning
/// threads per core beside the simulator and the daemon): SIGKILL
/// mid-move, then the hook, three times; each time it exits 0 within its
/// bound with both axes at rest. It runs alone (`.config/nextest.toml`):
/// the load it makes must not slow other tests.
#[test]
fn the_stop_hook_halts_under_cpu_load() {
    let dir = test_dir();
    let sim = Sim::start(dir.path(), 2.0);
    let cfg = daemon_config(dir.path());
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let cores = std::thread::available_parallelism().map_or(2, |n| n.get());
    let hogs: Vec<_> = (0..4 * cores)
        .map(|_| {
            let stop = stop.clone();
            std::thread::spawn(move || {
                let mut x = 0u64;
                while !stop.load(std::sync::atomic::Ordering::Relaxed) {
                    x = std::hint::black_box(x.wrapping_mul(6364136223846793005).wrapping_add(1));
                }
            })
        })
        .collect();
    let mut figures = Vec::new();
    for round in 0..3u32 {
        let d = Daemon::start(dir.path(), round);
        let mut c = d.client();
        if round == 0 {
            c.ok(json!({"cmd": "reference"}));
        }
        let target = if round % 2 == 0 {
            [13_500.0, 1_500.0]
        } else {
            [1_500.0, 13_500.0]
        };
        long_move(&mut c, &sim, target[0], target[1]);
        d.sigkill();
        let h = halt_figures(&sim, || stop_hook(&cfg, &format!("round {round}")));
        assert!(h.sim_s < PROCESS_HALT_BOUND_S, "round {round}: {h:?}");
        at_rest_short_of(&sim, target);
        figures.push(h);
    }
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    for h in hogs {
        h.join().unwrap();
    }
    println!(
        "HALT | stop hook under CPU load ({} spinning threads), 3 rounds | {figures:?} |",
        4 * cores
    );
}

/// The sweep characterization as a person runs it: `micropos characterize
/// start --mode sweep … --follow` against microposd and `hil-sim serve` in
/// real time. The CLI follows the job to its end, exits 0 and prints the
/// camera delay it measured and the static anchors; the log is a sweep log
/// on the step grid.
///
/// Ignored by default: in real time the sweep gets the frames the daemon
/// decodes while the axis passes, and a debug build decodes too few to
/// cover the grid at two velocities (the job then fails with
/// `low_quality`, as it should). Run it on release binaries:
/// `cargo build --release --bins -p micropos -p hil-sim && MICROPOS_BIN=target/release/micropos
/// MICROPOSD_BIN=target/release/microposd HIL_SIM_BIN=target/release/hil-sim
/// cargo test --test it daemon_process::cli_sweep -- --ignored`.
#[test]
#[ignore = "needs release binaries (see its doc comment)"]
fn cli_sweep_characterization_follows_to_its_delay_and_anchors() {
    let dir = test_dir();
    let _sim = Sim::start(dir.path(), 1.0);
    let d = Daemon::start(dir.path(), 0);
    d.client().ok(json!({"cmd": "reference"}));
    let cli = std::env::var_os("MICROPOS_BIN")
        .map_or_else(|| env!("CARGO_BIN_EXE_micropos").into(), PathBuf::from);
    let out = Command::new(cli)
        .arg("--socket")
        .arg(&d.socket)
        .args([
            "characterize",
            "start",
            "--mode",
            "sweep",
            "--log",
            "cli-sweep.csv",
            "--step-um",
            "20",
            "--x-range-um",
            "100",
            "--y-range-um",
            "60",
            "--cycles",
            "2",
            "--velocity-um-per-s",
            "20",
            "--anchor-spacing-um",
            "40",
            "--follow",
        ])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success(),
        "{:?}\n{stdout}\n{stderr}\n{}",
        out.status,
        std::fs::read_to_string(dir.path().join("microposd-0.log")).unwrap_or_default()
    );
    let delay_line = stdout
        .lines()
        .find(|l| l.starts_with("sweep: camera delay "))
        .unwrap_or_else(|| panic!("no delay line in {stdout}"));
    let delay_ms: f64 = delay_line["sweep: camera delay ".len()..]
        .split_whitespace()
        .next()
        .unwrap()
        .parse()
        .unwrap();
    assert!(delay_ms.is_finite(), "{delay_line}");
    assert!(
        stdout.lines().any(|l| l.starts_with("anchors: ")),
        "no anchors line in {stdout}"
    );
    // What the CLI printed is what the daemon reports.
    let s = d
        .client()
        .ok(json!({"cmd": "characterize", "action": "status"}));
    assert_eq!(s["job"]["state"], "done", "{s}");
    let r = &s["job"]["result"];
    assert_eq!(
        format!("{:.3}", r["camera_delay_s"].as_f64().unwrap() * 1e3),
        format!("{delay_ms:.3}")
    );
    assert!(r["anchors"]["measured"].as_u64().unwrap() > 0, "{r}");
    let l = log::read_file(dir.path().join("data/cli-sweep.csv")).unwrap();
    assert!(l.is_complete() && l.warnings.is_empty(), "{:?}", l.warnings);
    assert_eq!(l.metadata.get("mode"), Some("sweep"));
    for (segment, x_axis) in [("scan_x", true), ("scan_y", false)] {
        let targets: Vec<f64> = l
            .records
            .iter()
            .filter(|r| r.segment.starts_with(segment))
            .map(|r| if x_axis { r.x_target_um } else { r.y_target_um })
            .collect();
        assert!(targets.len() >= 6, "{segment}: {} records", targets.len());
        let first = targets.iter().copied().fold(f64::INFINITY, f64::min);
        for t in &targets {
            let k = (t - first) / 20.0;
            assert!(
                (k - k.round()).abs() < 1e-9,
                "{segment}: {t} off the 20 µm grid"
            );
        }
    }
}

/// A log begun before the step log had its `approach` column resumes
/// without it: the job goes on in the log's own columns, losing nothing.
#[test]
fn a_log_without_the_approach_column_resumes_in_its_own_columns() {
    let dir = test_dir();
    let _sim = Sim::start(dir.path(), 20.0);
    let d = Daemon::start(dir.path(), 0);
    let mut c = d.client();
    c.ok(json!({"cmd": "reference"}));
    let mut sub = d.client();
    sub.ok(json!({"cmd": "subscribe", "topics": ["job"]}));
    c.ok(
        json!({"cmd": "characterize", "action": "start", "log": "old.csv",
                        "step_um": 500.0, "x_range_um": 1000.0, "y_range_um": 1000.0,
                        "cycles": 1, "frames_per_point": 1, "settle_s": 0.1}),
    );
    wait_done(&mut sub, 3);
    c.ok(json!({"cmd": "characterize", "action": "cancel"}));
    sub.event(|e| e["event"] == "job" && e["state"] == "cancelled");
    sub.forget_events();
    // Rewrite it as the daemon wrote step logs before: no `approach`.
    let path = dir.path().join("data/old.csv");
    let text = std::fs::read_to_string(&path).unwrap();
    let old: String = text
        .lines()
        .map(|line| {
            if line.starts_with('#') {
                line.to_owned()
            } else {
                let (keep, last) = line.rsplit_once(',').unwrap();
                assert!(matches!(last, "approach" | "fwd" | "bwd" | ""), "{line}");
                keep.to_owned()
            }
        })
        .map(|l| l + "\n")
        .collect();
    std::fs::write(&path, old).unwrap();
    let before = log::read_file(&path).unwrap().records.len();
    assert!(before >= 3, "{before}");
    let r = c.ok(json!({"cmd": "characterize", "action": "resume", "log": "old.csv"}));
    assert_eq!(r["job"]["done"].as_u64(), Some(before as u64));
    let ev = sub.event(|e| e["event"] == "job" && e["state"] != "running");
    assert_eq!(ev["state"], "done", "{ev}");
    let l = log::read_file(&path).unwrap();
    assert!(l.is_complete() && l.warnings.is_empty(), "{:?}", l.warnings);
    assert!(!l.columns.extra.iter().any(|c| c == "approach"));
    let plan = ScanPlan::from_metadata(&l.metadata).unwrap();
    assert_eq!(
        l.records.len(),
        plan.points().len(),
        "points lost or duplicated"
    );
}

/// `micropos characterize start … --follow` with stdout piped, as a script
/// or a CI log runs it, on a tiny characterization (12 points).
fn follow_cli(d: &Daemon, log: &str) -> Child {
    Command::new(env!("CARGO_BIN_EXE_micropos"))
        .arg("--socket")
        .arg(&d.socket)
        .args(["characterize", "start", "--log", log, "--step-um", "500"])
        .args([
            "--x-range-um",
            "1000",
            "--y-range-um",
            "1000",
            "--cycles",
            "1",
        ])
        .arg("--follow")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

/// The CLI's exit status, stdout and stderr once it exits (within the
/// deadline: a CLI that never returns fails the test instead of hanging it).
fn cli_end(mut cli: Child) -> (std::process::ExitStatus, String, String) {
    let t = Instant::now();
    while cli.try_wait().unwrap().is_none() {
        if t.elapsed() > DEADLINE {
            let _ = cli.kill();
            panic!("micropos --follow did not return");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let out = cli.wait_with_output().unwrap();
    let text = |b: &[u8]| String::from_utf8_lossy(b).into_owned();
    (out.status, text(&out.stdout), text(&out.stderr))
}

/// Polls until the job writing `log` has logged a point and still runs.
fn running_with_a_point(c: &mut Client, log: &str) {
    let s = c.wait_for(|s| s["job"]["log"] == log && s["job"]["done"].as_u64() >= Some(1));
    assert_eq!(s["job"]["state"], "running", "the job ended too soon: {s}");
}

/// Issue 33, "a lab's first hour": `--follow` into a pipe returns only
/// once the job ended, prints its final state and the next step, and exits
/// 0 only for done (a cancelled job: 1, saying so); `tables build` refuses
/// the log of the job still writing it and builds once the job is done.
#[test]
fn piped_follow_waits_for_the_job_and_tables_build_refuses_its_running_log() {
    let dir = test_dir();
    let _sim = Sim::start(dir.path(), 20.0);
    let d = Daemon::start(dir.path(), 0);
    let mut c = d.client();
    c.ok(json!({"cmd": "reference"}));
    let build = json!({"cmd": "tables", "action": "build", "log": "f.csv", "kinds": ["paper"]});

    let cli = follow_cli(&d, "f.csv");
    running_with_a_point(&mut c, "f.csv");
    let refused = c.call(build.clone());
    assert_eq!(code(&refused), "job_state", "{refused}");
    let msg = refused["error"]["message"].as_str().unwrap();
    assert!(
        msg.contains("running characterize job f.csv") && msg.contains("cancel"),
        "{msg}"
    );
    assert!(
        !dir.path().join("data/f-paper.toml").exists(),
        "a table was written from the running job's log"
    );
    let (st, out, err) = cli_end(cli);
    assert!(st.success(), "{st:?}\n{out}\n{err}");
    assert!(
        out.contains("characterize f.csv: state done, 12/12 points\n")
            && out.contains("next: micropos tables build f.csv\n"),
        "{out}"
    );
    // It returned after the end: the daemon says done, the log is whole.
    let s = c.ok(json!({"cmd": "characterize", "action": "status"}));
    assert_eq!(s["job"]["state"], "done", "{s}");
    check_log(&dir.path().join("data/f.csv"), None);
    let built = c.ok(build);
    assert_eq!(built["paper"]["name"], "f-paper.toml", "{built}");

    let cli = follow_cli(&d, "g.csv");
    running_with_a_point(&mut c, "g.csv");
    c.ok(json!({"cmd": "characterize", "action": "cancel"}));
    let (st, out, err) = cli_end(cli);
    assert_eq!(st.code(), Some(1), "{out}\n{err}");
    assert!(out.contains("characterize g.csv: state cancelled"), "{out}");
    assert!(err.contains("ended cancelled, not done"), "{err}");
    let log = d.log_text();
    assert!(
        log.lines()
            .any(|l| l.contains("INFO") && l.contains("halting both axes: job cancelled")),
        "{log}"
    );
    assert_requested_halts_do_not_warn(&log);
}

/// A halt someone asked for (a job cancel, a shutdown) is logged at info:
/// a warning at the end of every normal run (issue 33) taught users to
/// ignore warnings. Only a fault's halt, or one that leaves an axis
/// moving, warns.
fn assert_requested_halts_do_not_warn(log: &str) {
    let warned: Vec<&str> = log
        .lines()
        .filter(|l| l.contains("WARN") && l.contains("halt"))
        .collect();
    assert!(warned.is_empty(), "requested halts warned: {warned:#?}");
}

/// What a terminal shows of `raw` (a pty's output): per line, what
/// follows the line's last carriage return, escape sequences removed.
fn visible_lines(raw: &str) -> Vec<String> {
    raw.split('\n')
        .map(|l| {
            let l = l.trim_end_matches('\r');
            let shown = l.rsplit('\r').next().unwrap_or("");
            let mut out = String::new();
            let mut chars = shown.chars();
            while let Some(c) = chars.next() {
                if c == '\u{1b}' {
                    // CSI: ESC [ parameters, then a final letter.
                    for d in chars.by_ref() {
                        if d.is_ascii_alphabetic() {
                            break;
                        }
                    }
                } else {
                    out.push(c);
                }
            }
            out
        })
        .collect()
}

/// Issue 33: `--follow` on a terminal ended at the bar ("12/12 points
/// ETA 0 s") with the final state printed on the bar's own line. Now the
/// bar is taken off at the end, and the final state, the log and the next
/// step are lines of their own. stdout and stderr on a pseudo-terminal, as
/// a person runs it.
#[test]
fn follow_on_a_terminal_ends_with_the_final_state_on_its_own_line() {
    use std::io::Read;
    let dir = test_dir();
    let _sim = Sim::start(dir.path(), 20.0);
    let d = Daemon::start(dir.path(), 0);
    d.client().ok(json!({"cmd": "reference"}));
    let size = nix::pty::Winsize {
        ws_row: 24,
        ws_col: 120,
        ws_xpixel: 0,
        ws_ypixel: 0,
    };
    let pty = nix::pty::openpty(Some(&size), None).unwrap();
    let stderr_fd = pty.slave.try_clone().unwrap();
    let mut cli = Command::new(env!("CARGO_BIN_EXE_micropos"))
        .arg("--socket")
        .arg(&d.socket)
        .args([
            "characterize",
            "start",
            "--log",
            "t.csv",
            "--step-um",
            "500",
        ])
        .args([
            "--x-range-um",
            "1000",
            "--y-range-um",
            "1000",
            "--cycles",
            "1",
        ])
        .arg("--follow")
        .env("TERM", "xterm")
        .env_remove("NO_COLOR")
        .stdin(Stdio::null())
        .stdout(Stdio::from(pty.slave))
        .stderr(Stdio::from(stderr_fd))
        .spawn()
        .unwrap();
    // The master is read on a thread until the CLI's end closes the
    // terminal: a full pty would stall the CLI.
    let mut master = std::fs::File::from(pty.master);
    let reader = std::thread::spawn(move || {
        let mut all = Vec::new();
        let mut chunk = [0u8; 4096];
        while let Ok(n) = master.read(&mut chunk) {
            if n == 0 {
                break;
            }
            all.extend_from_slice(&chunk[..n]);
        }
        all
    });
    let t = Instant::now();
    let status = loop {
        if let Some(st) = cli.try_wait().unwrap() {
            break st;
        }
        if t.elapsed() > DEADLINE {
            let _ = cli.kill();
            panic!("micropos --follow did not return");
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    let raw = String::from_utf8_lossy(&reader.join().unwrap()).into_owned();
    let lines = visible_lines(&raw);
    assert!(status.success(), "{status:?}\n{raw:?}");
    assert!(
        raw.contains("points  ETA"),
        "no progress bar: not the terminal view\n{raw:?}"
    );
    let end = lines
        .iter()
        .position(|l| l.contains("characterize t.csv: state done"))
        .unwrap_or_else(|| panic!("no final state in {lines:#?}"));
    assert!(
        lines[end].starts_with("characterize t.csv: state done, 12/12 points"),
        "the final state shares its line: {:?}",
        lines[end]
    );
    assert_eq!(
        lines[end + 1],
        "log: t.csv in the daemon's data_dir, 12 points"
    );
    assert_eq!(lines[end + 2], "next: micropos tables build t.csv");
}

/// `position` until its vision reading was grabbed after rig time `t_s`.
fn vision_after(c: &mut Client, t_s: f64) -> Value {
    let t = Instant::now();
    loop {
        let p = c.ok(json!({"cmd": "position"}));
        if p["vision"]["t_s"].as_f64().is_some_and(|v| v > t_s) {
            return p;
        }
        assert!(t.elapsed() < DEADLINE, "no fresh frame: {p}");
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// Vision in stage coordinates minus the platform's true position
/// (hil-sim's truth), µm `[x, y]`, at rest: the tie's constant offset
/// (its origin is where vision and controller agree on the tie's X line,
/// the truth's where the stage model has none), the same everywhere when
/// vision measures the platform in the stage's axes.
fn vision_minus_truth(c: &mut Client, sim: &Sim) -> [f64; 2] {
    let now = c.ok(json!({"cmd": "status"}))["t_s"].as_f64().unwrap();
    let p = vision_after(c, now);
    let (truth, moving) = truth(sim);
    assert!(!moving);
    let v = &p["vision"];
    [
        v["stage_x_um"].as_f64().unwrap() - truth[0],
        v["stage_y_um"].as_f64().unwrap() - truth[1],
    ]
}

/// The tie on a served rig (issue 33): `hil-sim serve` and `microposd`
/// with the shipped config/microposd-sim.toml. Before: after `reference`,
/// `position` gave vision x −4498 µm against the controller's 7500, and
/// `status` said the deviation check was armed while it had no frame.
/// Now: untied, both say so and what that switches off; `reference` ties
/// (vision within the stage's few-µm errors of the controller where it
/// tied; after a move to (2000, 12000) vision tracks the platform's true
/// position to 1 µm, the controller differs by the stage's squareness);
/// the check is armed and tied; a restart restores the tie (confirmed at
/// rest); a stored tie the rig contradicts is dropped, saying why.
#[test]
fn reference_ties_vision_to_the_stage_and_a_restart_keeps_it() {
    let dir = test_dir();
    let sim = Sim::start(dir.path(), 20.0);
    let d = Daemon::start(dir.path(), 0);
    let mut c = d.client();
    // Untied: no stage coordinates, and the reasons in words.
    let p = vision_after(&mut c, 0.0);
    let untied = p["vision"]["untied"].as_str().unwrap_or_default();
    for part in [
        "vision is not tied to the stage",
        "reference ties it",
        "pattern coordinates, not stage positions",
        "deviation check",
    ] {
        assert!(untied.contains(part), "{part:?} not in {p}");
    }
    assert!(p["vision"]["stage_x_um"].is_null(), "{p}");
    let st = c.ok(json!({"cmd": "status"}));
    assert_eq!(st["deviation"]["armed"], false, "{st}");
    assert!(
        st["deviation"]["state"]
            .as_str()
            .unwrap()
            .starts_with("off: vision is not tied to the stage"),
        "{st}"
    );
    assert_eq!(st["vision_tie"]["tied"], false, "{st}");

    // The reference run ties, and leaves the stage at its reference.
    let r = c.ok(json!({"cmd": "reference", "axes": "xy"}));
    assert_eq!(r["vision_tie"]["tied"], true, "{r}");
    let t_ref = c.ok(json!({"cmd": "status"}))["t_s"].as_f64().unwrap();
    let p = vision_after(&mut c, t_ref);
    let (v, k) = (&p["vision"], &p["controller"]);
    assert!(v["frame"]
        .as_str()
        .unwrap()
        .starts_with("tie after reference"));
    for a in ["x", "y"] {
        let (vs, ks) = (
            v[format!("stage_{a}_um")].as_f64().unwrap(),
            k[format!("{a}_um")].as_f64().unwrap(),
        );
        assert!((ks - 7500.0).abs() < 0.01, "{p}");
        // The stage's cyclic error and backlash where it tied.
        assert!(
            (vs - ks).abs() < 3.0,
            "axis {a}: vision {vs} controller {ks}"
        );
    }
    let off_ref = vision_minus_truth(&mut c, &sim);
    c.ok(json!({"cmd": "move", "x_um": 2000.0, "y_um": 12000.0, "wait": true}));
    let off_far = vision_minus_truth(&mut c, &sim);
    for i in 0..2 {
        assert!(
            (off_far[i] - off_ref[i]).abs() < 1.0,
            "vision − truth {off_ref:?} at the reference, {off_far:?} at (2000, 12000)"
        );
    }
    // The check runs.
    let st = c.wait_for(|s| s["deviation"]["armed"] == true);
    assert_eq!(st["deviation"]["tied"], true, "{st}");
    assert!(
        st["deviation"]["state"]
            .as_str()
            .unwrap()
            .starts_with("checking:"),
        "{st}"
    );
    assert_eq!(st["vision_tie"]["restored"], "no", "{st}");
    drop(c);

    // A restart keeps the tie: restored, then confirmed at rest; the same
    // stage coordinates.
    d.sigkill();
    let d = Daemon::start(dir.path(), 1);
    let mut c = d.client();
    let st = c.ok(json!({"cmd": "status"}));
    assert_eq!(st["vision_tie"]["tied"], true, "{st}");
    let st = c.wait_for(|s| {
        s["vision_tie"]["restored"] == "from the data directory, confirmed at rest"
            && s["deviation"]["armed"] == true
    });
    assert!(st["vision_tie"]["frame_in_force"]
        .as_str()
        .unwrap()
        .starts_with("tie after reference"));
    let off_again = vision_minus_truth(&mut c, &sim);
    for i in 0..2 {
        assert!(
            (off_again[i] - off_far[i]).abs() < 1.0,
            "{off_again:?} {off_far:?}"
        );
    }
    drop(c);

    // A stored tie 50 µm off (the camera moved while the daemon was down):
    // dropped at the first tie at rest, saying why, and its file removed.
    d.sigkill();
    let file = dir.path().join("data").join("vision-tie.json");
    let mut t: Value = serde_json::from_slice(&std::fs::read(&file).unwrap()).unwrap();
    t["frame"]["translation_um"][1] =
        json!(t["frame"]["translation_um"][1].as_f64().unwrap() + 50.0);
    std::fs::write(&file, t.to_string()).unwrap();
    let d = Daemon::start(dir.path(), 2);
    let mut c = d.client();
    let st = c.wait_for(|s| s["vision_tie"]["tied"] == false);
    let why = st["vision_tie"]["why"].as_str().unwrap();
    for part in [
        "disagrees with the rig by",
        "beyond the stage errors the tie measured",
        "reference ties it again",
    ] {
        assert!(why.contains(part), "{part:?} not in {st}");
    }
    let p = c.ok(json!({"cmd": "position"}));
    assert!(
        p["vision"]["untied"]
            .as_str()
            .unwrap()
            .contains("disagrees with the rig"),
        "{p}"
    );
    let t = Instant::now();
    while file.exists() {
        assert!(t.elapsed() < DEADLINE, "the dropped tie's file stays");
        std::thread::sleep(Duration::from_millis(20));
    }
}
