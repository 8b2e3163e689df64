//! `micropos camera grab` against the simulated camera (`hil-sim serve`'s
//! camera socket), as a person brings a camera up: the line it prints
//! says what the grabbed frame is, size and depth, the same as the PNG it
//! wrote (issue 33: a 1024 × 768 10-bit frame was announced as "0×0
//! Mono8 (0 bit)", from the source's info before its first frame).
//!
//! `hil-sim` comes from the target directory (see `bins.rs`).

use crate::bins::hil_sim_bin;
use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};

/// Kills and reaps the simulator however the test ends.
struct Sim(std::process::Child);

impl Drop for Sim {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

#[test]
fn camera_grab_describes_the_frame_it_grabbed() {
    let dir = tempfile::tempdir().unwrap();
    let mut sim = Sim(Command::new(hil_sim_bin())
        .args(["serve", "--link-dir"])
        .arg(dir.path())
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap());
    let mut ready = String::new();
    BufReader::new(sim.0.stdout.take().unwrap())
        .read_line(&mut ready)
        .unwrap();
    let camera = ready
        .split_whitespace()
        .find_map(|w| w.strip_prefix("camera="))
        .unwrap_or_else(|| panic!("no camera in {ready}"))
        .to_owned();
    let png = dir.path().join("grab.png");
    let out = Command::new(env!("CARGO_BIN_EXE_micropos"))
        .args([
            "camera",
            "grab",
            "--source",
            &format!("sim:{camera}"),
            "--out",
        ])
        .arg(&png)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    let frame = micropos::imageio::load_frame(&png).unwrap();
    let (w, h, bits) = (frame.width(), frame.height(), frame.bit_depth());
    assert!(w > 0 && h > 0 && bits > 8, "{w}×{h} {bits} bit");
    let expected = format!(": {w}×{h} Mono{bits} ({bits} bit)");
    assert!(
        stderr
            .lines()
            .any(|l| l.starts_with("sim ") && l.ends_with(&expected)),
        "want a line ending {expected:?}:\n{stderr}"
    );
    assert!(!stderr.contains("0×0"), "{stderr}");
}
