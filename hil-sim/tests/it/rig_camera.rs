//! The simulated camera: the fast renderer against micropos's exact renderer,
//! the pattern edge, and the served protocol (camera socket, clock advances,
//! ground truth, camera faults) through micropos's own clients
//! (`SimSocketSource`, `SimClock`).

use hil_sim::camera::fast::FastRenderer;
use hil_sim::camera::CameraConfig;
use hil_sim::rig::Mounting;
use hil_sim::{ServeConfig, SimHandle};
use micropos::camera::simsocket::SimSocketSource;
use micropos::camera::{CameraError, SourceSpec};
use micropos::clock::{RigClock, SimClock};
use micropos::frame::Pixels;
use micropos::pattern::decode::{DecodeOptions, Decoder};
use micropos::pattern::render::{Pose, Renderer};
use std::io::{BufRead, BufReader, Write};
use std::os::unix::net::UnixStream;
use std::time::Duration;

fn noiseless() -> CameraConfig {
    CameraConfig {
        full_well_e: 0.0,
        read_noise: 0.0,
        illumination_drift: 0.0,
        ..CameraConfig::default()
    }
}

#[test]
fn fast_frames_match_the_exact_renderer_and_decode_to_the_same_position() {
    let cfg = noiseless();
    let theta = Mounting::default().theta_deg.to_radians();
    let mut fast = FastRenderer::new(&cfg, theta).unwrap();
    let mut exact = Renderer::new(cfg.exact_render_config()).unwrap();
    let mut dec = Decoder::new(DecodeOptions::new(cfg.period_um, cfg.bits)).unwrap();
    let fs = f64::from((1u32 << cfg.bit_depth) - 1);
    for (x, y) in [(6123.4567, 2345.6789), (1500.013, 9000.987)] {
        let a = fast.render(x, y, 1.0, 1, 0.0, 1).unwrap();
        let pose = Pose {
            x_um: x,
            y_um: y,
            theta_rad: theta,
            pixel_um: cfg.pixel_um,
            mirrored: false,
        };
        let b = exact.render(&pose, 1, 0.0, 1).unwrap();
        let (Pixels::U16(pa), Pixels::U16(pb)) = (a.pixels(), b.pixels()) else {
            panic!("10-bit frames are u16");
        };
        let rms = (pa
            .iter()
            .zip(pb)
            .map(|(&u, &v)| (f64::from(u) - f64::from(v)).powi(2))
            .sum::<f64>()
            / pa.len() as f64)
            .sqrt()
            / fs;
        let da = dec.decode(&a).unwrap();
        let db = dec.decode(&b).unwrap();
        println!(
            "({x}, {y}): pixel RMS {rms:.2e} of full scale; fast − exact decoded: ({:.2e}, {:.2e}) µm; fast − truth ({:.2e}, {:.2e}) µm",
            da.x_um - db.x_um,
            da.y_um - db.y_um,
            da.x_um - x,
            da.y_um - y
        );
        assert!(rms < 2e-3, "pixel RMS {rms}");
        assert!((da.x_um - db.x_um).abs() < 2e-3 && (da.y_um - db.y_um).abs() < 2e-3);
        assert!((da.x_um - x).abs() < 5e-3 && (da.y_um - y).abs() < 5e-3);
        assert!((da.theta_rad - theta).abs() < 1e-4);
    }
}

#[test]
fn beyond_the_pattern_frames_do_not_decode() {
    let cfg = CameraConfig::default();
    let m = Mounting::default();
    let mut fast = FastRenderer::new(&cfg, m.theta_deg.to_radians()).unwrap();
    let mut dec = Decoder::new(DecodeOptions::new(cfg.period_um, cfg.bits)).unwrap();
    // Stage x = 14 000 µm is 1.6 mm off the pattern's end.
    let p = m.pattern_point([14_000.0, 5000.0]);
    let f = fast.render(p[0], p[1], 1.0, 3, 0.0, 1).unwrap();
    assert!(dec.decode(&f).is_err());
    // Inside, with noise, it decodes to within a few nm.
    let p = m.pattern_point([11_800.0, 100.0]);
    let f = fast.render(p[0], p[1], 1.0, 4, 0.0, 2).unwrap();
    let d = dec.decode(&f).unwrap();
    assert!(
        (d.x_um - p[0]).abs() < 0.01 && (d.y_um - p[1]).abs() < 0.01,
        "{d:?}"
    );
}

fn control(path: &std::path::Path, req: &str) -> serde_json::Value {
    let mut s = UnixStream::connect(path).unwrap();
    s.write_all(format!("{req}\n").as_bytes()).unwrap();
    let mut line = String::new();
    BufReader::new(s).read_line(&mut line).unwrap();
    serde_json::from_str(&line).unwrap()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn served_camera_clock_truth_and_faults() {
    let dir = tempfile::tempdir().unwrap();
    let ctl = dir.path().join("control.sock");
    let cam = dir.path().join("camera.sock");
    let cfg = ServeConfig {
        link_dir: dir.path().to_owned(),
        time_scale: 1.0,
        control_socket: Some(ctl.clone()),
        camera_socket: Some(cam.clone()),
        seed: 5,
        ..Default::default()
    };
    let sim = crate::common::serve(cfg).await;

    // The clock: advances through micropos's SimClock.
    let clock = {
        let ctl = ctl.clone();
        tokio::task::spawn_blocking(move || SimClock::connect(&ctl))
            .await
            .unwrap()
            .unwrap()
    };
    let t0 = clock.now_s();
    clock.sleep(Duration::from_secs(3600)).await;
    let t1 = clock.now_s();
    assert!((3600.0..3610.0).contains(&(t1 - t0)), "{t0} → {t1}");

    // Truth, with the contract's keys; at power-up the platform sits at the
    // seed's carriage positions.
    let truth = control(&ctl, r#"{"query":"truth"}"#);
    for k in [
        "true_x_um",
        "true_y_um",
        "observed_x_um",
        "observed_y_um",
        "sim_time_s",
    ] {
        assert!(
            truth[k].as_f64().is_some_and(f64::is_finite),
            "{k}: {truth}"
        );
    }
    let ox = truth["observed_x_um"].as_f64().unwrap();
    let oy = truth["observed_y_um"].as_f64().unwrap();

    // Frames through the socket, as the daemon takes them (`sim:PATH`).
    let spec: SourceSpec = format!("sim:{}", cam.display()).parse().unwrap();
    let mut src = tokio::task::spawn_blocking(move || {
        micropos::camera::open_source(&spec, &Default::default())
    })
    .await
    .unwrap()
    .unwrap();
    let (src_back, frames) = tokio::task::spawn_blocking(move || {
        let a = src.next_frame();
        let b = src.next_frame();
        (src, (a, b))
    })
    .await
    .unwrap();
    let mut src = src_back;
    let (a, b) = (frames.0.unwrap(), frames.1.unwrap());
    assert_eq!((a.width(), a.height(), a.bit_depth()), (1024, 768, 10));
    assert!(b.sequence == a.sequence + 1);
    // Frames are at least one frame period apart in simulated time (up to
    // the stamps' jitter, σ 20 µs).
    assert!(b.timestamp_s - a.timestamp_s >= 1.0 / 30.0 - 120e-6);
    let mut dec = Decoder::new(DecodeOptions::new(4.0, 10)).unwrap();
    let d = dec.decode(&a).unwrap();
    assert!(
        (d.x_um - ox).abs() < 0.05 && (d.y_um - oy).abs() < 0.05,
        "decoded ({}, {}) vs truth ({ox}, {oy})",
        d.x_um,
        d.y_um
    );

    // Faults: garbage frames do not decode; a stall times out; normal again.
    assert_eq!(control(&ctl, r#"{"camera":"garbage"}"#)["ok"], true);
    let (s2, g) = tokio::task::spawn_blocking(move || {
        let g = [src.next_frame(), src.next_frame()];
        (src, g)
    })
    .await
    .unwrap();
    src = s2;
    for f in g {
        assert!(dec.decode(&f.unwrap()).is_err());
    }
    assert_eq!(control(&ctl, r#"{"camera":"stall"}"#)["ok"], true);
    let (s3, r) = tokio::task::spawn_blocking(move || {
        src.set_timeout(Duration::from_millis(200));
        let r = src.next_frame();
        (src, r)
    })
    .await
    .unwrap();
    src = s3;
    assert!(matches!(r, Err(CameraError::Timeout { .. })), "{r:?}");
    assert_eq!(control(&ctl, r#"{"camera":"normal"}"#)["ok"], true);
    let r = tokio::task::spawn_blocking(move || src.next_frame())
        .await
        .unwrap();
    assert!(dec.decode(&r.unwrap()).is_ok());

    // A bad request gets an error line, not a hang.
    let mut s = UnixStream::connect(&cam).unwrap();
    s.write_all(b"{\"grab\":false}\n").unwrap();
    let mut line = String::new();
    BufReader::new(s).read_line(&mut line).unwrap();
    assert!(line.contains("\"ok\":false"), "{line}");
    assert!(SimSocketSource::open(&dir.path().join("nope.sock")).is_err());
    tokio::task::spawn_blocking(move || sim.shutdown())
        .await
        .unwrap();
}

/// The first `n` measurements of an on-demand pipeline on the in-process
/// rig (seed 7, platform at rest) taken by one consumer that holds
/// [`Vision::want_stream`] (`stream`) or [`Vision::want`] (each with the
/// rig time it reached the consumer), then the frames
/// grabbed and decoded once it let go and a simulated second passed.
fn first_measurements(stream: bool, n: usize) -> (Vec<[f64; 6]>, u64, u64) {
    use micropos::daemon::vision::{Capture, Vision};
    use std::sync::atomic::Ordering;
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .start_paused(true)
        .build()
        .unwrap();
    let dir = tempfile::tempdir().unwrap();
    rt.block_on(async {
        let sim = SimHandle::start_in_process(ServeConfig {
            link_dir: dir.path().to_path_buf(),
            seed: 7,
            ..ServeConfig::default()
        })
        .unwrap();
        let env = hil_sim::run::in_process_environment(&sim);
        let cam = sim.camera().config();
        let v = Vision::start_with(
            env.camera.unwrap(),
            DecodeOptions::new(cam.period_um, cam.bits),
            env.clock.clone(),
            Capture::OnDemand,
        )
        .unwrap();
        let mut rx = v.latest.clone();
        let mut got = Vec::new();
        {
            let _want = if stream { v.want_stream() } else { v.want() };
            while got.len() < n {
                rx.changed().await.unwrap();
                if let Some(m) = *rx.borrow_and_update() {
                    let seen_s = env.clock.now_s();
                    got.push([
                        m.t_s,
                        m.frame_t_s,
                        m.sequence as f64,
                        m.x_um,
                        m.y_um,
                        seen_s,
                    ]);
                }
            }
        }
        env.clock.sleep(Duration::from_secs(1)).await;
        let frames = v.stats.frames.load(Ordering::Relaxed);
        let decoded = v.stats.decoded.load(Ordering::Relaxed);
        (got, frames, decoded)
    })
}

/// A consumer that takes every frame (a sweep: `Vision::want_stream`) gets
/// the frames, rig times and positions of one that asks frame after frame
/// (`Vision::want`), bit for bit and at the same rig times: the next grab runs alongside the current
/// decode, but is requested at the rig time it would be requested after
/// the publication, and its exposure is waited out after it. The one
/// difference is at the end: the stream leaves one frame grabbed ahead
/// (rendered, then decoded with nobody waiting), where the frame-by-frame
/// consumer leaves none.
#[test]
fn a_stream_sees_the_frames_one_grab_at_a_time_would_give() {
    let n = 8;
    let (one_by_one, frames_a, decoded_a) = first_measurements(false, n);
    let (streamed, frames_b, decoded_b) = first_measurements(true, n);
    assert_eq!(one_by_one.len(), n);
    for (a, b) in one_by_one.iter().zip(&streamed) {
        assert_eq!(a.map(f64::to_bits), b.map(f64::to_bits), "{a:?} vs {b:?}");
    }
    // Consecutive exposures one frame slot apart (30 fps; the stamps carry
    // 20 µs of jitter), so the stream did not wait a slot more for its
    // grab ahead.
    for w in streamed.windows(2) {
        let dt = w[1][1] - w[0][1];
        assert!((dt - 1.0 / 30.0).abs() < 2e-3, "frames {dt} s apart");
    }
    assert_eq!((frames_a, decoded_a), (n as u64, n as u64));
    assert_eq!((frames_b, decoded_b), (n as u64 + 1, n as u64 + 1));
}
