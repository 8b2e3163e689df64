//! The served simulator, talked to through its pty links with plain blocking
//! files, as any serial client would.

use hil_sim::clock::ManualClock;
use hil_sim::serve::read_answer;
use hil_sim::{AxisName, Fault, ServeConfig, SimHandle};
use nix::poll::{poll, PollFd, PollFlags, PollTimeout};
use std::fs::File;
use std::io::{Read, Write};
use std::os::fd::AsFd;
use std::path::Path;
use std::sync::Arc;
use std::time::{Duration, Instant};

const T: Duration = Duration::from_secs(3);

fn open(p: &Path) -> File {
    std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .open(p)
        .unwrap()
}

fn ask(f: &mut File, line: &str) -> String {
    f.write_all(line.as_bytes()).unwrap();
    String::from_utf8_lossy(&read_answer(f, T).unwrap()).into_owned()
}

fn tell(f: &mut File, line: &str) {
    f.write_all(line.as_bytes()).unwrap();
}

/// Reads whatever arrives within `d`.
fn drain(f: &mut File, d: Duration) -> Vec<u8> {
    let deadline = Instant::now() + d;
    let mut out = Vec::new();
    let mut buf = [0u8; 256];
    loop {
        let left = deadline.saturating_duration_since(Instant::now());
        if left.is_zero() {
            return out;
        }
        let mut fds = [PollFd::new(f.as_fd(), PollFlags::POLLIN)];
        let ms = u16::try_from(left.as_millis().max(1)).unwrap();
        if poll(&mut fds, PollTimeout::from(ms)).unwrap() == 0 {
            continue;
        }
        match f.read(&mut buf) {
            Ok(0) | Err(_) => return out,
            Ok(n) => out.extend_from_slice(&buf[..n]),
        }
    }
}

fn manual(dir: &Path, daisy: bool, control: bool) -> (SimHandle, ManualClock) {
    let clock = ManualClock::new();
    let cfg = ServeConfig {
        stage_model: Some(micropos::model::StageModel::ideal()),
        link_dir: dir.to_owned(),
        daisy_chain: daisy,
        control_socket: control.then(|| dir.join("ctl")),
        seed: 7,
        ..ServeConfig::default()
    };
    let sim = SimHandle::start_with_clock(cfg, Arc::new(clock.clone())).unwrap();
    (sim, clock)
}

/// Servo on and referenced, in manual time.
fn reference(f: &mut File, clock: &ManualClock, prefix: &str) {
    tell(f, &format!("{prefix}SVO 1 1\n{prefix}FRF 1\n"));
    // Wait until the FRF line was processed (an answered query after it).
    assert!(ask(f, &format!("{prefix}FRF? 1\n")).ends_with("1=0\n"));
    clock.advance(Duration::from_secs(60));
    assert!(ask(f, &format!("{prefix}FRF? 1\n")).ends_with("1=1\n"));
}

#[test]
fn two_lines_two_controllers() {
    let dir = tempfile::tempdir().unwrap();
    let (sim, clock) = manual(dir.path(), false, false);
    assert_eq!(sim.link(AxisName::X), dir.path().join("x"));
    assert_eq!(sim.link(AxisName::Y), dir.path().join("y"));
    let mut x = open(&sim.link(AxisName::X));
    let mut y = open(&sim.link(AxisName::Y));
    let idx = ask(&mut x, "*IDN?\n");
    let idy = ask(&mut y, "*IDN?\n");
    assert!(idx.starts_with("(c)2015 Physik Instrumente (PI) GmbH & Co. KG, C-863.11, "));
    assert!(idx.ends_with(", 01.110\n"));
    assert_ne!(idx, idy, "serial numbers differ");
    assert_eq!(ask(&mut x, "CSV?\n"), "2.0\n");
    assert_eq!(ask(&mut x, "TMX? 1\n"), "1=15.0000000\n");
    reference(&mut x, &clock, "");
    tell(&mut x, "MOV 1 3.25\n");
    assert_eq!(ask(&mut x, "MOV? 1\n"), "1=3.2500000\n");
    clock.advance(Duration::from_secs(30));
    assert_eq!(ask(&mut x, "POS? 1\n"), "1=3.2500000\n");
    assert_eq!(ask(&mut x, "ONT? 1\n"), "1=1\n");
    assert_eq!(sim.true_position_mm(AxisName::X), 3.25);
    // Y was never referenced: its carriage is still where it powered up.
    assert_eq!(ask(&mut y, "FRF? 1\n"), "1=0\n");
    let ty = sim.true_position_mm(AxisName::Y);
    assert!((1.0..14.0).contains(&ty), "{ty}");
    sim.shutdown();
    assert!(!dir.path().join("x").exists());
    assert!(std::fs::symlink_metadata(dir.path().join("y")).is_err());
}

#[test]
fn pty_is_raw() {
    let dir = tempfile::tempdir().unwrap();
    let (sim, _clock) = manual(dir.path(), false, false);
    let mut x = open(&sim.link(AxisName::X));
    // Control characters reach the controller (no ISIG/ICANON/IXON eating
    // them), nothing is echoed, LF is not turned into CRLF.
    tell(&mut x, "\x07");
    assert_eq!(read_answer(&mut x, T).unwrap(), vec![0xB1, b'\n']);
    tell(&mut x, "\x05");
    assert_eq!(read_answer(&mut x, T).unwrap(), b"0\n");
    tell(&mut x, "\x04");
    assert_eq!(read_answer(&mut x, T).unwrap(), b"0x0\n");
    // CR is not turned into LF on input: "ERR?\r" is an unknown command.
    tell(&mut x, "ERR?\r");
    assert_eq!(drain(&mut x, Duration::from_millis(200)), b"");
    tell(&mut x, "\n");
    assert_eq!(drain(&mut x, Duration::from_millis(200)), b"");
    assert_eq!(ask(&mut x, "ERR?\n"), "2\n");
    let hlp = ask(&mut x, "HLP?\n");
    assert!(!hlp.contains('\r'));
    assert!(hlp.contains(" \n#24 Stop All Axes \n"));
    // Bytes above 0x7F pass unchanged (#7 busy/ready bytes rely on it).
    tell(&mut x, "\u{7f}\n");
    assert_eq!(ask(&mut x, "ERR?\n"), "2\n");
    // A client that leaves without reading its answer: the next one does
    // not get it.
    tell(&mut x, "HLP?\n");
    std::thread::sleep(Duration::from_millis(50));
    drop(x);
    std::thread::sleep(Duration::from_millis(50));
    let mut x = open(&sim.link(AxisName::X));
    assert_eq!(drain(&mut x, Duration::from_millis(100)), b"");
    assert_eq!(ask(&mut x, "CSV?\n"), "2.0\n");
    // Commands sent just before closing are still executed, their answers
    // still lost, and a half line does not glue onto the next client's.
    tell(&mut x, "SVO 1 1\nHLP?\nPOS");
    drop(x);
    std::thread::sleep(Duration::from_millis(50));
    let mut x = open(&sim.link(AxisName::X));
    assert_eq!(drain(&mut x, Duration::from_millis(100)), b"");
    assert_eq!(ask(&mut x, "SVO? 1\n"), "1=1\n");
    assert_eq!(ask(&mut x, "ERR?\n"), "0\n");
}

#[test]
fn daisy_chain_on_one_bus() {
    let dir = tempfile::tempdir().unwrap();
    let (sim, clock) = manual(dir.path(), true, false);
    let bus = dir.path().join("bus");
    assert_eq!(sim.link(AxisName::X), bus);
    assert_eq!(sim.link(AxisName::Y), bus);
    assert!(!dir.path().join("x").exists());
    let mut f = open(&bus);
    let a1 = ask(&mut f, "1 *IDN?\n");
    let a2 = ask(&mut f, "2 *IDN?\n");
    assert!(a1.starts_with("0 1 (c)2015"), "{a1}");
    assert!(a2.starts_with("0 2 (c)2015"), "{a2}");
    // Unaddressed goes to address 1, without a header.
    assert!(ask(&mut f, "*IDN?\n").starts_with("(c)2015"));
    // Nobody at address 3: silence.
    tell(&mut f, "3 *IDN?\n");
    assert_eq!(drain(&mut f, Duration::from_millis(200)), b"");
    reference(&mut f, &clock, "2 ");
    tell(&mut f, "2 MOV 1 4\n");
    assert_eq!(ask(&mut f, "1 FRF? 1\n"), "0 1 1=0\n");
    clock.advance(Duration::from_secs(30));
    assert_eq!(ask(&mut f, "2 POS? 1\n"), "0 2 1=4.0000000\n");
    assert_eq!(sim.true_position_mm(AxisName::Y), 4.0);
    tell(&mut f, "2 \x07");
    assert_eq!(read_answer(&mut f, T).unwrap(), b"0 2 \xb1\n");
    // An error on 2 is not seen by 1.
    tell(&mut f, "2 FOO\n");
    assert_eq!(ask(&mut f, "1 ERR?\n"), "0 1 0\n");
    assert_eq!(ask(&mut f, "2 ERR?\n"), "0 2 2\n");
    // Faults address the right controller on the shared line.
    sim.inject(AxisName::Y, Fault::WithholdReplies(true))
        .unwrap();
    tell(&mut f, "2 CSV?\n");
    assert_eq!(drain(&mut f, Duration::from_millis(200)), b"");
    assert_eq!(ask(&mut f, "1 CSV?\n"), "0 1 2.0\n");
    sim.inject(AxisName::Y, Fault::WithholdReplies(false))
        .unwrap();
    sim.inject(AxisName::Y, Fault::PowerCycle).unwrap();
    assert_eq!(ask(&mut f, "2 POS? 1\n"), "0 2 1=0.0000000\n");
    assert_eq!(ask(&mut f, "1 SVO? 1\n"), "0 1 1=0\n");
    // Pulling the shared cable takes both controllers off the line.
    sim.inject(AxisName::Y, Fault::DropLine).unwrap();
    assert!(std::fs::symlink_metadata(&bus).is_err());
    let e = sim
        .inject(AxisName::Y, Fault::Garbage(vec![1]))
        .unwrap_err();
    assert_eq!(e.to_string(), "the line of axis y is down");
    sim.inject(AxisName::X, Fault::RestoreLine).unwrap();
    let mut f = open(&bus);
    assert_eq!(ask(&mut f, "2 POS? 1\n"), "0 2 1=0.0000000\n");
}

#[test]
fn drop_and_restore_line() {
    let dir = tempfile::tempdir().unwrap();
    let (sim, clock) = manual(dir.path(), false, false);
    let link = sim.link(AxisName::X);
    let mut x = open(&link);
    reference(&mut x, &clock, "");
    tell(&mut x, "MOV 1 12\n");
    assert_eq!(ask(&mut x, "MOV? 1\n"), "1=12.0000000\n");
    sim.inject(AxisName::X, Fault::DropLine).unwrap();
    assert!(std::fs::symlink_metadata(&link).is_err(), "link removed");
    // The open port is dead: reads end (EOF or EIO), writes fail or vanish.
    let mut buf = [0u8; 16];
    let r = x.read(&mut buf);
    assert!(matches!(r, Ok(0) | Err(_)), "{r:?}");
    // Line faults on a dead line are refused; the other line is unaffected.
    assert!(sim
        .inject(AxisName::X, Fault::Garbage(b"x".to_vec()))
        .is_err());
    let mut y = open(&sim.link(AxisName::Y));
    assert_eq!(ask(&mut y, "CSV?\n"), "2.0\n");
    // The controller kept running without its cable.
    clock.advance(Duration::from_secs(30));
    assert_eq!(sim.true_position_mm(AxisName::X), 12.0);
    sim.inject(AxisName::X, Fault::DropLine).unwrap();
    sim.inject(AxisName::X, Fault::RestoreLine).unwrap();
    let mut x = open(&link);
    assert_eq!(ask(&mut x, "POS? 1\n"), "1=12.0000000\n");
    assert_eq!(ask(&mut x, "FRF? 1\n"), "1=1\n");
    // Restoring a line that is up is harmless.
    sim.inject(AxisName::X, Fault::RestoreLine).unwrap();
    assert_eq!(ask(&mut x, "CSV?\n"), "2.0\n");
}

#[test]
fn power_cycle_garbage_delay_withhold() {
    let dir = tempfile::tempdir().unwrap();
    let (sim, clock) = manual(dir.path(), false, false);
    let mut x = open(&sim.link(AxisName::X));
    reference(&mut x, &clock, "");
    tell(&mut x, "MOV 1 10\nVEL 1 0.5\n");
    // Time moves only after the simulator has read the commands.
    assert_eq!(ask(&mut x, "MOV? 1\n"), "1=10.0000000\n");
    clock.advance(Duration::from_secs(60));
    assert_eq!(ask(&mut x, "POS? 1\n"), "1=10.0000000\n");

    sim.inject(AxisName::X, Fault::PowerCycle).unwrap();
    assert_eq!(ask(&mut x, "POS? 1\n"), "1=0.0000000\n");
    assert_eq!(ask(&mut x, "SVO? 1\n"), "1=0\n");
    assert_eq!(ask(&mut x, "FRF? 1\n"), "1=0\n");
    assert_eq!(ask(&mut x, "VEL? 1\n"), "1=1.0000000\n");
    assert_eq!(ask(&mut x, "ERR?\n"), "0\n");
    assert_eq!(sim.true_position_mm(AxisName::X), 10.0);

    sim.inject(AxisName::X, Fault::Garbage(vec![0xff, 0x00, b'z', b'\n']))
        .unwrap();
    assert_eq!(
        read_answer(&mut x, T).unwrap(),
        vec![0xff, 0x00, b'z', b'\n']
    );

    sim.inject(AxisName::X, Fault::DelayReplies(Duration::from_millis(300)))
        .unwrap();
    let t0 = Instant::now();
    tell(&mut x, "CSV?\n");
    assert_eq!(drain(&mut x, Duration::from_millis(150)), b"");
    assert_eq!(read_answer(&mut x, T).unwrap(), b"2.0\n");
    assert!(t0.elapsed() >= Duration::from_millis(300));
    sim.inject(AxisName::X, Fault::DelayReplies(Duration::ZERO))
        .unwrap();
    assert_eq!(ask(&mut x, "CSV?\n"), "2.0\n");

    sim.inject(AxisName::X, Fault::WithholdReplies(true))
        .unwrap();
    tell(&mut x, "SVO 1 1\nSVO? 1\n");
    assert_eq!(drain(&mut x, Duration::from_millis(300)), b"");
    sim.inject(AxisName::X, Fault::WithholdReplies(false))
        .unwrap();
    // The command ran although nothing was answered.
    assert_eq!(ask(&mut x, "SVO? 1\n"), "1=1\n");
}

#[test]
fn control_socket_json_lines() {
    use std::io::{BufRead, BufReader};
    use std::os::unix::net::UnixStream;
    let dir = tempfile::tempdir().unwrap();
    let (sim, clock) = manual(dir.path(), false, true);
    let ctl = dir.path().join("ctl");
    let s = UnixStream::connect(&ctl).unwrap();
    let mut w = s.try_clone().unwrap();
    let mut r = BufReader::new(s);
    let mut call = |req: &str| -> serde_json::Value {
        w.write_all(format!("{req}\n").as_bytes()).unwrap();
        let mut line = String::new();
        r.read_line(&mut line).unwrap();
        serde_json::from_str(&line).unwrap()
    };
    let mut x = open(&sim.link(AxisName::X));
    reference(&mut x, &clock, "");
    let truth = call(r#"{"query":"truth"}"#);
    assert_eq!(truth["ok"], true);
    assert_eq!(truth["x_mm"], 7.5);
    assert_eq!(truth["sim_time_s"], 60.0);
    assert!(truth["y_mm"].as_f64().unwrap() > 0.0);

    assert_eq!(
        call(r#"{"axis":"x","fault":"garbage","hex":"41420a"}"#)["ok"],
        true
    );
    assert_eq!(read_answer(&mut x, T).unwrap(), b"AB\n");
    assert_eq!(
        call(r#"{"axis":"x","fault":"withhold_replies","on":true}"#)["ok"],
        true
    );
    tell(&mut x, "CSV?\n");
    assert_eq!(drain(&mut x, Duration::from_millis(200)), b"");
    assert_eq!(
        call(r#"{"axis":"x","fault":"withhold_replies","on":false}"#)["ok"],
        true
    );
    assert_eq!(
        call(r#"{"axis":"x","fault":"delay_replies","ms":0}"#)["ok"],
        true
    );
    assert_eq!(ask(&mut x, "CSV?\n"), "2.0\n");
    assert_eq!(call(r#"{"axis":"x","fault":"power_cycle"}"#)["ok"], true);
    assert_eq!(ask(&mut x, "FRF? 1\n"), "1=0\n");
    assert_eq!(call(r#"{"axis":"x","fault":"drop_line"}"#)["ok"], true);
    assert!(!dir.path().join("x").exists());
    let bad = call(r#"{"axis":"x","fault":"garbage","hex":"00"}"#);
    assert_eq!(bad["ok"], false);
    assert!(bad["error"].as_str().unwrap().contains("down"), "{bad}");
    assert_eq!(call(r#"{"axis":"x","fault":"restore_line"}"#)["ok"], true);
    let mut x = open(&sim.link(AxisName::X));
    assert_eq!(ask(&mut x, "CSV?\n"), "2.0\n");
    // No axis: every line.
    assert_eq!(call(r#"{"fault":"garbage","hex":"5a0a"}"#)["ok"], true);
    assert_eq!(read_answer(&mut x, T).unwrap(), b"Z\n");
    // Y had no client: its garbage was lost, as on a cable nobody listens to.
    let mut y = open(&sim.link(AxisName::Y));
    assert_eq!(drain(&mut y, Duration::from_millis(100)), b"");
    tell(&mut y, "FOO\n");
    assert_eq!(ask(&mut y, "CSV?\n"), "2.0\n");
    assert_eq!(call(r#"{"fault":"power_cycle"}"#)["ok"], true);
    assert_eq!(ask(&mut y, "ERR?\n"), "0\n");
    // Bad requests get a reason and the connection stays usable.
    let bad = call("{nope");
    assert_eq!(bad["ok"], false);
    assert!(bad["error"].as_str().unwrap().contains("JSON"));
    assert_eq!(call(r#"{"query":"truth"}"#)["ok"], true);
    sim.shutdown();
    assert!(!ctl.exists(), "socket removed");
}

#[test]
fn scaled_time_and_start_errors() {
    let dir = tempfile::tempdir().unwrap();
    let sim = SimHandle::start(ServeConfig {
        stage_model: Some(micropos::model::StageModel::ideal()),
        link_dir: dir.path().to_owned(),
        time_scale: 1000.0,
        ..ServeConfig::default()
    })
    .unwrap();
    let mut x = open(&sim.link(AxisName::X));
    tell(&mut x, "SVO 1 1\nFRF 1\n");
    let t0 = Instant::now();
    while ask(&mut x, "FRF? 1\n") != "1=1\n" {
        assert!(t0.elapsed() < Duration::from_secs(10));
        std::thread::sleep(Duration::from_millis(5));
    }
    assert!(sim.sim_time() > Duration::from_secs(1));
    drop(sim);
    assert!(!dir.path().join("x").exists());

    for bad in [0.0, -1.0, f64::NAN, f64::INFINITY] {
        let e = SimHandle::start(ServeConfig {
            stage_model: Some(micropos::model::StageModel::ideal()),
            link_dir: dir.path().to_owned(),
            time_scale: bad,
            ..ServeConfig::default()
        })
        .unwrap_err();
        assert!(e.to_string().contains("time_scale"), "{e}");
    }
    std::fs::write(dir.path().join("x"), b"precious").unwrap();
    let e = SimHandle::start(ServeConfig {
        stage_model: Some(micropos::model::StageModel::ideal()),
        link_dir: dir.path().to_owned(),
        ..ServeConfig::default()
    })
    .unwrap_err();
    assert!(e.to_string().contains("not a symlink"), "{e}");
    assert_eq!(std::fs::read(dir.path().join("x")).unwrap(), b"precious");
    let e = SimHandle::start(ServeConfig::default()).unwrap_err();
    assert!(e.to_string().contains("link_dir"), "{e}");
    let e = SimHandle::start(ServeConfig {
        stage_model: Some(micropos::model::StageModel::ideal()),
        link_dir: dir.path().join("missing"),
        ..ServeConfig::default()
    })
    .unwrap_err();
    assert!(e.to_string().contains("not a directory"), "{e}");
}

#[test]
fn starts_inside_a_tokio_runtime() {
    let dir = tempfile::tempdir().unwrap();
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    let path = dir.path().to_owned();
    let sim = rt.block_on(async move {
        SimHandle::start(ServeConfig {
            stage_model: Some(micropos::model::StageModel::ideal()),
            link_dir: path,
            ..ServeConfig::default()
        })
    });
    let sim = sim.unwrap();
    let mut x = open(&sim.link(AxisName::X));
    assert_eq!(ask(&mut x, "CSV?\n"), "2.0\n");
}

#[test]
fn binary_serves_until_sigterm() {
    use std::io::BufRead;
    use std::process::{Command, Stdio};
    let dir = tempfile::tempdir().unwrap();
    let mut child = Command::new(env!("CARGO_BIN_EXE_hil-sim"))
        .args(["serve", "--link-dir"])
        .arg(dir.path())
        .args(["--time-scale", "100", "--seed", "3", "--control"])
        .arg(dir.path().join("ctl"))
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    let mut out = std::io::BufReader::new(child.stdout.take().unwrap());
    let mut line = String::new();
    out.read_line(&mut line).unwrap();
    let x = dir.path().join("x");
    let y = dir.path().join("y");
    assert_eq!(
        line.trim_end(),
        format!(
            "hil-sim ready x={} y={} camera={} control={}",
            x.display(),
            y.display(),
            dir.path().join("camera.sock").display(),
            dir.path().join("ctl").display()
        )
    );
    assert!(dir.path().join("camera.sock").exists());
    let mut fx = open(&x);
    assert!(ask(&mut fx, "*IDN?\n").contains("C-863.11"));
    assert!(dir.path().join("ctl").exists());
    let pid = nix::unistd::Pid::from_raw(i32::try_from(child.id()).unwrap());
    nix::sys::signal::kill(pid, nix::sys::signal::Signal::SIGTERM).unwrap();
    let status = child.wait().unwrap();
    assert!(status.success(), "{status}");
    assert!(std::fs::symlink_metadata(&x).is_err());
    assert!(std::fs::symlink_metadata(&y).is_err());
    assert!(!dir.path().join("ctl").exists());
    assert!(!dir.path().join("camera.sock").exists());

    // Daisy chain and a bad argument.
    let mut child = Command::new(env!("CARGO_BIN_EXE_hil-sim"))
        .args(["serve", "--daisy-chain", "--link-dir"])
        .arg(dir.path())
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    let mut out = std::io::BufReader::new(child.stdout.take().unwrap());
    let mut line = String::new();
    out.read_line(&mut line).unwrap();
    assert_eq!(
        line.trim_end(),
        format!(
            "hil-sim ready bus={} camera={} control={}",
            dir.path().join("bus").display(),
            dir.path().join("camera.sock").display(),
            dir.path().join("control.sock").display()
        )
    );
    let pid = nix::unistd::Pid::from_raw(i32::try_from(child.id()).unwrap());
    nix::sys::signal::kill(pid, nix::sys::signal::Signal::SIGINT).unwrap();
    assert!(child.wait().unwrap().success());
    assert!(std::fs::symlink_metadata(dir.path().join("bus")).is_err());

    let o = Command::new(env!("CARGO_BIN_EXE_hil-sim"))
        .args(["serve", "--time-scale", "0", "--link-dir"])
        .arg(dir.path())
        .output()
        .unwrap();
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("time_scale"));
}

/// One scripted session against `hil-sim serve --manual-clock --seed N`,
/// as a separate process: the transcript of every answer (serial, control,
/// camera: a frame's header and a hash of its pixels).
fn manual_clock_session(seed: u64) -> Vec<String> {
    use micropos::camera::simsocket::{parse_header, Reply, GRAB_REQUEST};
    use std::collections::hash_map::DefaultHasher;
    use std::hash::{Hash, Hasher};
    use std::io::BufRead;
    use std::os::unix::net::UnixStream;
    use std::process::{Command, Stdio};
    let dir = tempfile::tempdir().unwrap();
    let mut child = Command::new(env!("CARGO_BIN_EXE_hil-sim"))
        .args([
            "serve",
            "--manual-clock",
            "--seed",
            &seed.to_string(),
            "--link-dir",
        ])
        .arg(dir.path())
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    let mut out = std::io::BufReader::new(child.stdout.take().unwrap());
    let mut ready = String::new();
    out.read_line(&mut ready).unwrap();
    assert!(ready.trim_end().ends_with(" clock=manual"), "{ready}");
    let control = UnixStream::connect(dir.path().join("control.sock")).unwrap();
    control.set_read_timeout(Some(T)).unwrap();
    let mut control_in = std::io::BufReader::new(control.try_clone().unwrap());
    let mut control_out = control;
    let mut ctl = |req: &str| {
        control_out
            .write_all(format!("{req}\n").as_bytes())
            .unwrap();
        let mut reply = String::new();
        control_in.read_line(&mut reply).unwrap();
        reply
    };
    let camera = UnixStream::connect(dir.path().join("camera.sock")).unwrap();
    camera.set_read_timeout(Some(T)).unwrap();
    let mut camera_in = std::io::BufReader::new(camera.try_clone().unwrap());
    let mut camera_out = camera;
    let mut grab = || {
        camera_out.write_all(GRAB_REQUEST).unwrap();
        let mut header = String::new();
        camera_in.read_line(&mut header).unwrap();
        let Ok(Reply::Frame(h)) = parse_header(header.as_bytes()) else {
            panic!("no frame: {header}");
        };
        let mut payload = vec![0u8; h.bytes];
        camera_in.read_exact(&mut payload).unwrap();
        let mut hasher = DefaultHasher::new();
        payload.hash(&mut hasher);
        format!("{} pixels {:016x}", header.trim_end(), hasher.finish())
    };
    let mut x = open(&dir.path().join("x"));
    let mut t = Vec::new();
    // Time stands still while nobody advances it, whatever the wall clock.
    let before = ctl(r#"{"clock":"now"}"#);
    std::thread::sleep(Duration::from_millis(300));
    assert_eq!(ctl(r#"{"clock":"now"}"#), before);
    t.push(before);
    for line in ["SVO 1 1\n", "FRF 1\n"] {
        tell(&mut x, line);
    }
    t.push(ask(&mut x, "FRF? 1\n"));
    t.push(ctl(r#"{"clock":"advance","s":20}"#));
    t.push(ask(&mut x, "FRF? 1\n"));
    let start = ask(&mut x, "POS? 1\n");
    tell(&mut x, "MOV 1 4.5\n");
    t.push(ask(&mut x, "ONT? 1\n"));
    t.push(ctl(r#"{"clock":"advance","s":1.0}"#));
    t.push(ask(&mut x, "POS? 1\n"));
    t.push(ctl(r#"{"clock":"advance","s":10}"#));
    t.push(ask(&mut x, "ONT? 1\n"));
    t.push(ask(&mut x, "POS? 1\n"));
    t.push(ctl(r#"{"query":"truth"}"#));
    t.push(grab());
    t.push(grab());
    t.push(ctl(r#"{"clock":"now"}"#));
    t.push(start);
    let pid = nix::unistd::Pid::from_raw(i32::try_from(child.id()).unwrap());
    nix::sys::signal::kill(pid, nix::sys::signal::Signal::SIGTERM).unwrap();
    assert!(child.wait().unwrap().success());
    t
}

#[test]
fn a_manual_clock_gives_one_transcript_per_seed() {
    let a = manual_clock_session(11);
    let b = manual_clock_session(11);
    assert_eq!(a, b);
    // The session did something: referenced, moved, took frames.
    assert_eq!(a[1], "1=0\n");
    assert_eq!(a[3], "1=1\n");
    assert_eq!(a[8], "1=1\n", "on target after the advance");
    assert_eq!(a[4], "1=0\n", "moving before it");
    let pos = |s: &str| -> f64 { s.trim_end().trim_start_matches("1=").parse().unwrap() };
    let (from, mid) = (pos(&a[14]), pos(&a[6]));
    assert!(
        (from - 4.5).abs() > 1.0,
        "a move of over a millimetre from {from}"
    );
    assert!(
        (mid - 4.5) * (from - 4.5) > 0.0 && (mid - 4.5).abs() < (from - 4.5).abs(),
        "mid-move {mid} between {from} and 4.5"
    );
    assert!((pos(&a[9]) - 4.5).abs() < 1e-3, "at the target {}", a[9]);
    assert!(a[11] != a[12], "two grabs, two frames");
    let c = manual_clock_session(12);
    assert_ne!(a, c, "another seed, another rig");
    // A manual clock and a time scale are exclusive.
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_hil-sim"))
        .args([
            "serve",
            "--manual-clock",
            "--time-scale",
            "2",
            "--link-dir",
            "/tmp",
        ])
        .output()
        .unwrap();
    assert!(!o.status.success());
}

/// Long answers (six readouts of 1024 data-recorder records, ≈ 90 KB) reach
/// a host that reads them slowly in small pieces, whole: the simulator
/// writes at once what a real controller's baud rate paces, so the pty
/// buffer fills, and the rest must wait for the host rather than be
/// dropped.
#[test]
fn a_long_answer_reaches_a_slow_reader_whole() {
    let dir = tempfile::tempdir().unwrap();
    let (sim, clock) = manual(dir.path(), false, false);
    let mut x = open(&sim.link(AxisName::X));
    reference(&mut x, &clock, "");
    tell(&mut x, "DRC 1 1 2\nRTR 20\nVEL 1 0.5\nDRT 1 1 0\nMOV 1 8\n");
    assert_eq!(ask(&mut x, "MOV? 1\n"), "1=8.0000000\n");
    clock.advance(Duration::from_secs(5));
    assert!(ask(&mut x, "DRL? 1\n").ends_with("=1024\n"));
    tell(&mut x, &"DRR? 1 1024 1\n".repeat(6));
    // A slow host: it starts late and reads 256 bytes every 2 ms.
    std::thread::sleep(Duration::from_millis(200));
    let mut got = Vec::new();
    let mut buf = [0u8; 256];
    let deadline = Instant::now() + Duration::from_secs(20);
    let answers = |got: &[u8]| {
        got.windows(2)
            .filter(|w| w[1] == b'\n' && w[0] != b' ')
            .count()
    };
    while answers(&got) < 6 {
        assert!(Instant::now() < deadline, "{} bytes", got.len());
        let mut fds = [PollFd::new(x.as_fd(), PollFlags::POLLIN)];
        if poll(&mut fds, PollTimeout::from(100u16)).unwrap() == 0 {
            continue;
        }
        let n = x.read(&mut buf).unwrap();
        got.extend_from_slice(&buf[..n]);
        std::thread::sleep(Duration::from_millis(2));
    }
    let text = String::from_utf8_lossy(&got);
    let data_lines = text
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .count();
    assert!(got.len() > 65536, "{} bytes", got.len());
    assert_eq!(data_lines, 6 * 1024, "{} bytes", got.len());
}
