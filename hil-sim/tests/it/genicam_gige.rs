//! The simulated camera served as a GigE Vision camera on loopback (aravis's
//! GvFakeCamera filled by hil-sim's renderer), opened by micropos's GenICam
//! source through aravis's GigE Vision discovery, GVCP and GVSP, and its
//! frames decoded by micropos's decoder: the decoded position must be the
//! simulator's ground truth (pattern point under the image centre, and the
//! platform position after undoing the mounting), frame after frame, across
//! a platform move, in Mono16 and Mono8; camera faults must give errors,
//! never positions.
//!
//! Cannot hang: every grab has a timeout, and a watchdog ends the process
//! after `WATCHDOG` with a message (the whole `it` test binary: a hang
//! fails every test of it still running rather than blocking CI). Skips
//! (saying so) only when no UDP socket can be opened on 127.0.0.1 at all.
//! One test function: the GVCP port (3956) admits one GigE Vision camera
//! per address; no other test of this binary serves one. Feature `genicam`
//! (on this module's line in `main.rs`).

use hil_sim::camera::gige::{GigeCamera, GigeConfig};
use hil_sim::camera::{CameraConfig, CameraMode, SimCamera};
use hil_sim::clock::{Clock, ManualClock};
use hil_sim::controller::ActuatorPath;
use hil_sim::rig::{Rig, RigConfig, RigTruth};
use micropos::camera::{open_source, OpenOptions, PixelFormat, SourceSpec};
use micropos::frame::{Frame, Pixels};
use micropos::model::{Axis, StageModel};
use micropos::pattern::decode::{DecodeOptions, Decoded, Decoder};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Whole-test limit (the test takes a few seconds).
const WATCHDOG: Duration = Duration::from_secs(150);
/// Agreement required between decoded and true position, µm (0.05 px at
/// 0.4 µm/px; a stale or wrong frame is hundreds of µm off).
const TOL_UM: f64 = 0.02;
/// Frames from before a move that may still be queued after it (aravis
/// stream buffers + frames in flight).
const MAX_STALE: usize = 12;

struct Watchdog(Arc<AtomicBool>);

impl Watchdog {
    fn arm(limit: Duration) -> Watchdog {
        let done = Arc::new(AtomicBool::new(false));
        let d = done.clone();
        std::thread::spawn(move || {
            let start = Instant::now();
            while !d.load(Ordering::SeqCst) {
                if start.elapsed() > limit {
                    eprintln!("genicam_gige: watchdog: no result after {limit:?}, aborting");
                    std::process::abort();
                }
                std::thread::sleep(Duration::from_millis(100));
            }
        });
        Watchdog(done)
    }
}

impl Drop for Watchdog {
    fn drop(&mut self) {
        self.0.store(true, Ordering::SeqCst);
    }
}

fn rest(mm: f64) -> ActuatorPath {
    ActuatorPath {
        offset_mm: 0.0,
        profile: None,
        rest_encoder_mm: mm,
    }
}

/// Decoded minus true, in the pattern frame and (after the mounting) in the
/// stage frame, µm.
fn errors(rig: &Rig, d: &Decoded, t: &RigTruth) -> ([f64; 2], [f64; 2]) {
    let p = [
        d.x_um - t.observed_pattern_um[0],
        d.y_um - t.observed_pattern_um[1],
    ];
    let s = rig.mounting().stage_point([d.x_um, d.y_um]);
    (
        p,
        [s[0] - t.observed_stage_um[0], s[1] - t.observed_stage_um[1]],
    )
}

fn within(e: [f64; 2]) -> bool {
    e[0].abs() < TOL_UM && e[1].abs() < TOL_UM
}

struct Checker {
    rig: Arc<Rig>,
    decoder: Decoder,
    theta_rad: f64,
    worst_um: f64,
    checked: usize,
}

impl Checker {
    fn decode(&mut self, f: &Frame) -> Decoded {
        match self.decoder.decode(f) {
            Ok(d) => d,
            Err(e) => panic!("frame {} did not decode: {e}", f.sequence),
        }
    }

    /// Asserts that `d` is the truth `t` (pattern point, stage point, θ).
    fn assert_matches(&mut self, d: &Decoded, t: &RigTruth, what: &str) {
        let (p, s) = errors(&self.rig, d, t);
        assert!(
            within(p) && within(s),
            "{what}: decoded ({:.4}, {:.4}) µm, truth ({:.4}, {:.4}) µm: pattern error {p:?}, stage error {s:?}",
            d.x_um,
            d.y_um,
            t.observed_pattern_um[0],
            t.observed_pattern_um[1]
        );
        assert!(
            (d.theta_rad - self.theta_rad).abs() < 1e-4,
            "{what}: θ {} rad, mounting {} rad",
            d.theta_rad,
            self.theta_rad
        );
        self.worst_um = self.worst_um.max(p[0].abs().max(p[1].abs()));
        self.checked += 1;
    }
}

/// Mean grey level of a frame.
fn mean_grey(f: &Frame) -> f64 {
    let (sum, n) = match f.pixels() {
        Pixels::U8(v) => (v.iter().map(|&p| f64::from(p)).sum::<f64>(), v.len()),
        Pixels::U16(v) => (v.iter().map(|&p| f64::from(p)).sum::<f64>(), v.len()),
    };
    sum / n.max(1) as f64
}

/// The mean grey level once a setting change has reached the frames: the
/// frames already queued are skipped, the next three must agree and decode
/// to `truth`.
fn settled_mean(
    cam: &mut Box<dyn micropos::camera::FrameSource>,
    check: &mut Checker,
    truth: &RigTruth,
    what: &str,
) -> f64 {
    for _ in 0..MAX_STALE {
        cam.next_frame().unwrap();
    }
    let means: Vec<f64> = (0..3)
        .map(|i| {
            let f = cam.next_frame().unwrap();
            let d = check.decode(&f);
            check.assert_matches(&d, truth, &format!("{what}, frame {i}"));
            mean_grey(&f)
        })
        .collect();
    let m = means.iter().sum::<f64>() / 3.0;
    assert!(
        means.iter().all(|v| (v / m - 1.0).abs() < 0.01),
        "{what}: frames disagree {means:?}"
    );
    m
}

/// The next frame, or `None` for a frame lost on the way (UDP packets
/// dropped on a loaded loopback: aravis reports an incomplete buffer); a
/// timeout (no frames at all) is a failure.
fn next_unless_lost(cam: &mut Box<dyn micropos::camera::FrameSource>) -> Option<Frame> {
    match cam.next_frame() {
        Ok(f) => Some(f),
        Err(e) => {
            assert!(
                !matches!(e, micropos::camera::CameraError::Timeout { .. }),
                "{e}"
            );
            println!("a frame was lost on the way ({e})");
            None
        }
    }
}

#[test]
fn the_daemons_genicam_source_decodes_the_served_simulator_to_its_ground_truth() {
    let _watchdog = Watchdog::arm(WATCHDOG);
    if let Err(e) = std::net::UdpSocket::bind(("127.0.0.1", 0)) {
        eprintln!(
            "SKIPPED genicam_gige: the loopback interface cannot be used here (UDP bind on 127.0.0.1 failed: {e}); the GigE Vision path was NOT tested"
        );
        return;
    }

    // The rig: the paper's stage model and mounting, on a clock that only
    // moves when the test moves it (the truth is fixed between moves).
    let rig_cfg = RigConfig::default();
    let rig = Arc::new(
        Rig::new(
            StageModel::paper_default().unwrap(),
            3,
            [6.0, 5.0],
            rig_cfg.mounting,
        )
        .unwrap(),
    );
    let clock = Arc::new(ManualClock::new());
    clock.set(Duration::from_secs(10));
    let cam_cfg = CameraConfig::default();
    let camera = Arc::new(SimCamera::new(&cam_cfg, rig.clone(), clock.clone(), 11).unwrap());

    let started = Instant::now();
    let served = GigeCamera::start(camera.clone(), &GigeConfig::default())
        .unwrap_or_else(|e| panic!("serving the GigE Vision camera on loopback: {e}"));
    println!(
        "served as {} on {} ({:.2} s to start and be discovered)",
        served.device_id(),
        served.interface(),
        started.elapsed().as_secs_f64()
    );

    // micropos's GenICam source, exactly as `--source genicam:127.0.0.1`
    // opens it (by address: see `hil-sim serve`'s ready line).
    let spec: SourceSpec = format!("genicam:{}", served.interface()).parse().unwrap();
    let options = OpenOptions {
        timeout: Duration::from_secs(5),
        ..OpenOptions::default()
    };
    let mut cam = open_source(&spec, &options).unwrap();
    let info = cam.info();
    println!("opened: {info:?}");
    assert_eq!(info.backend, "genicam");
    assert_eq!((info.width, info.height), (cam_cfg.width, cam_cfg.height));
    assert_eq!(info.bit_depth, 16, "a 10-bit sensor is served as Mono16");

    let mut check = Checker {
        rig: rig.clone(),
        decoder: Decoder::new(DecodeOptions::new(cam_cfg.period_um, cam_cfg.bits)).unwrap(),
        theta_rad: rig_cfg.mounting.theta_deg.to_radians(),
        worst_um: 0.0,
        checked: 0,
    };

    // 1. At rest: every frame shows the truth.
    let truth_a = rig.truth(clock.now());
    let grab_start = Instant::now();
    let mut last_seq = None;
    for i in 0..6 {
        let f = cam.next_frame().unwrap();
        assert_eq!(f.bit_depth(), 16);
        if let Some(s) = last_seq {
            assert!(f.sequence > s, "sequence {} after {s}", f.sequence);
        }
        last_seq = Some(f.sequence);
        let d = check.decode(&f);
        check.assert_matches(&d, &truth_a, &format!("pose A, frame {i}"));
    }
    let client_rate = 5.0 / grab_start.elapsed().as_secs_f64();

    // 2. A move of the platform: frames queued before it still show pose A,
    // then every frame shows pose B; none shows anything else.
    rig.set_path(Axis::X, &rest(6.75), clock.now());
    rig.set_path(Axis::Y, &rest(4.6), clock.now());
    clock.advance(Duration::from_secs(2));
    let truth_b = rig.truth(clock.now());
    let moved = (truth_b.observed_pattern_um[0] - truth_a.observed_pattern_um[0])
        .hypot(truth_b.observed_pattern_um[1] - truth_a.observed_pattern_um[1]);
    assert!(moved > 500.0, "the move is visible ({moved} µm)");
    let mut stale = 0;
    let mut fresh = 0;
    while fresh < 5 {
        let f = cam.next_frame().unwrap();
        let d = check.decode(&f);
        let (pb, _) = errors(&rig, &d, &truth_b);
        if fresh == 0 && !within(pb) {
            check.assert_matches(&d, &truth_a, "a frame queued before the move");
            stale += 1;
            assert!(
                stale <= MAX_STALE,
                "{stale} frames after the move still show pose A"
            );
        } else {
            check.assert_matches(&d, &truth_b, &format!("pose B, frame {fresh}"));
            fresh += 1;
        }
    }

    // 3. Mono8, as a client would switch it (stop, reformat, restart).
    cam.set_pixel_format(PixelFormat::Mono8).unwrap();
    assert_eq!(cam.info().bit_depth, 8);
    for i in 0..3 {
        let f = cam.next_frame().unwrap();
        assert_eq!(f.bit_depth(), 8);
        let d = check.decode(&f);
        check.assert_matches(&d, &truth_b, &format!("Mono8, frame {i}"));
    }

    // 3b. Exposure and gain change the image as on a sensor: half the
    // exposure halves the grey levels, +6 dB of gain doubles them back; the
    // pattern decodes to the same pose throughout.
    let base_exposure_us = cam.exposure_us().unwrap();
    let base = settled_mean(&mut cam, &mut check, &truth_b, "nominal exposure");
    let half = cam.set_exposure_us(base_exposure_us / 2.0).unwrap();
    assert!(
        (half - base_exposure_us / 2.0).abs() <= 1.0,
        "applied {half} µs"
    );
    let dim = settled_mean(&mut cam, &mut check, &truth_b, "half exposure");
    let gain_db = cam.set_gain_db(6.0).unwrap();
    assert!((gain_db - 6.0).abs() < 1e-9, "applied gain {gain_db} dB");
    let bright = settled_mean(&mut cam, &mut check, &truth_b, "half exposure, +6 dB");
    let served_sensor = served.stats().last.map(|l| l.sensor);
    println!(
        "mean grey: nominal {base:.1}, half exposure {dim:.1} ({:.3}×), +6 dB {bright:.1} ({:.3}×); camera reports {served_sensor:?}",
        dim / base,
        bright / base
    );
    assert!(
        (dim / base - 0.5).abs() < 0.03,
        "half exposure: {dim} vs {base}"
    );
    let want = 0.5 * 10f64.powf(6.0 / 20.0);
    assert!(
        (bright / base - want).abs() < 0.03,
        "+6 dB: {bright} vs {base}"
    );
    cam.set_gain_db(0.0).unwrap();
    cam.set_exposure_us(base_exposure_us).unwrap();

    // 4. Faults: garbage frames are errors, never positions.
    camera.set_mode(CameraMode::Garbage);
    let mut garbage_errors = 0;
    for _ in 0..(MAX_STALE + 4) {
        let f = cam.next_frame().unwrap();
        match check.decoder.decode(&f) {
            Ok(d) => check.assert_matches(&d, &truth_b, "a frame queued before the fault"),
            Err(_) => garbage_errors += 1,
        }
    }
    assert!(
        garbage_errors >= 3,
        "only {garbage_errors} garbage frames seen"
    );
    camera.set_mode(CameraMode::Normal);

    // 5. Timestamps: with the rig's clock following wall time, every
    // frame's timestamp is the camera's own clock (its origin and rate are
    // the rig file's `clock_offset_s`, `clock_rate_ppm`), carried through
    // the GVSP leader to micropos's frame: the intervals between a client's
    // frames are exactly those between the served stamps on the camera's
    // clock, never the host's arrival times.
    let running = Arc::new(AtomicBool::new(true));
    let driver = {
        let (clock, running) = (clock.clone(), running.clone());
        let (base, wall0) = (clock.now(), Instant::now());
        std::thread::spawn(move || {
            while running.load(Ordering::SeqCst) {
                clock.set(base + wall0.elapsed());
                std::thread::sleep(Duration::from_micros(500));
            }
        })
    };
    for _ in 0..MAX_STALE {
        next_unless_lost(&mut cam);
    }
    let stamps: Vec<f64> = (0..60)
        .filter_map(|_| next_unless_lost(&mut cam).map(|f| f.timestamp_s))
        .take(40)
        .collect();
    running.store(false, Ordering::SeqCst);
    driver.join().unwrap();
    let recent = served.stats().recent;
    let matched = recent.iter().find_map(|first| {
        let c0 = first.camera_ns as f64 * 1e-9;
        let frames: Vec<&hil_sim::camera::gige::ServedFrame> = stamps
            .iter()
            .map(|ts| {
                let want = c0 + (ts - stamps[0]);
                recent
                    .iter()
                    .find(|s| (s.camera_ns as f64 * 1e-9 - want).abs() < 1e-6)
            })
            .collect::<Option<_>>()?;
        Some(frames)
    });
    let Some(matched) = matched else {
        panic!("the client's frame intervals {stamps:?} are not those of the camera's clock");
    };
    let (first, last) = (matched[0], matched[matched.len() - 1]);
    let camera_s = (last.camera_ns - first.camera_ns) as f64 * 1e-9;
    let rig_s = last.stamp_s - first.stamp_s;
    let rate_ppm = (camera_s / rig_s - 1.0) * 1e6;
    println!(
        "timestamps: {} frames over {rig_s:.3} rig s, {camera_s:.6} camera s: camera clock {rate_ppm:.1} ppm fast (configured {}), offset {:.3} s",
        matched.len(),
        cam_cfg.clock_rate_ppm,
        first.camera_ns as f64 * 1e-9 - first.stamp_s
    );
    assert!(rig_s > 0.5, "the frames span {rig_s} s");
    assert!(
        (rate_ppm - cam_cfg.clock_rate_ppm).abs() < 1.0,
        "the camera clock runs {rate_ppm} ppm fast"
    );

    // 6. A stalled camera (no frames, no control answers) is a timeout
    // error, never an old frame passed off as new; frames showing the truth
    // resume when it recovers.
    for _ in 0..MAX_STALE {
        next_unless_lost(&mut cam);
    }
    camera.set_mode(CameraMode::Stall);
    let stall_start = Instant::now();
    let mut before_stall = 0;
    let stall_err = loop {
        match cam.next_frame() {
            Ok(f) => {
                // Frames already in flight when the stall began.
                before_stall += 1;
                assert!(
                    before_stall <= MAX_STALE,
                    "frames keep coming from a stalled camera"
                );
                let d = check.decode(&f);
                check.assert_matches(&d, &truth_b, "a frame sent before the stall");
            }
            Err(e) => break e,
        }
    };
    println!(
        "stall: {before_stall} frames in flight, then after {:.1} s: {stall_err}",
        stall_start.elapsed().as_secs_f64()
    );
    assert!(
        matches!(stall_err, micropos::camera::CameraError::Timeout { .. }),
        "a stall is a timeout: {stall_err:?}"
    );
    camera.set_mode(CameraMode::Normal);
    let mut resumed = None;
    for attempt in 0..5 {
        match cam.next_frame() {
            Ok(f) => {
                let d = check.decode(&f);
                check.assert_matches(&d, &truth_b, "after the stall");
                resumed = Some(attempt);
                break;
            }
            Err(e) => println!("after the stall, attempt {attempt}: {e}"),
        }
    }
    assert!(resumed.is_some(), "no frames after the stall ended");

    let stats = served.stats();
    drop(cam);
    served.stop();
    println!(
        "served {} frames at {:.1} frames/s ({} black); client decoded {:.1} frames/s; {} frames checked, worst |decoded − truth| {:.1} nm; {stale} stale frames after the move; {garbage_errors} garbage frames refused",
        stats.frames,
        stats.frame_rate_hz(),
        stats.failures,
        client_rate,
        check.checked,
        check.worst_um * 1000.0
    );
    assert_eq!(stats.failures, 0, "{:?}", stats.last_error);
}
