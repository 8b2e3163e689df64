//! The simulated camera's sweep effects: motion blur (the decoder on
//! blurred frames: bias and noise against blur length) and frame
//! timestamps (exposure mid-point + hidden latency + jitter).
//!
//! The figures printed by `decoder_on_blurred_frames` are the ones in
//! `docs/design/vision.md` ("Motion blur"):
//! `cargo test -p hil-sim --test it camera_blur:: -- --nocapture`.

use hil_sim::camera::fast::FastRenderer;
use hil_sim::camera::{CameraConfig, SimCamera};
use hil_sim::clock::ManualClock;
use hil_sim::controller::ActuatorPath;
use hil_sim::motion::{Limits, Profile};
use hil_sim::rig::{Mounting, Rig};
use micropos::model::{Axis, StageModel};
use micropos::pattern::decode::{DecodeOptions, Decoder};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::sync::Arc;
use std::time::Duration;

/// Mean and standard deviation.
fn stats(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    let m = v.iter().sum::<f64>() / n;
    let s = (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
    (m, s)
}

/// Blur along pattern x of length L: the frame averages the pattern at
/// instants spread evenly over L (as `SimCamera::grab` does), and the
/// decoder should return the mid-point. Bias and σ of decoded − mid, per L.
#[test]
fn decoder_on_blurred_frames() {
    let cfg = CameraConfig::default();
    let theta = Mounting::default().theta_deg.to_radians();
    let mut r = FastRenderer::new(&cfg, theta).unwrap();
    let mut dec = Decoder::new(DecodeOptions::new(cfg.period_um, cfg.bits)).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(17);
    let frames = 16;
    println!("blur_um\tsamples\tbias_x_um\tsigma_x_um\tbias_y_um\tsigma_y_um");
    let mut rows = Vec::new();
    for blur_um in [0.0, 0.4, 1.0, 2.0, 3.0] {
        let n = ((blur_um / (cfg.pixel_um / 4.0)).ceil().max(1.0) as usize) | 1;
        let (mut ex, mut ey) = (Vec::new(), Vec::new());
        for k in 0..frames {
            let x0 = rng.gen_range(3000.0..9000.0);
            let y0 = rng.gen_range(3000.0..9000.0);
            let path: Vec<[f64; 2]> = (0..n)
                .map(|i| {
                    let f = if n == 1 {
                        0.0
                    } else {
                        (i as f64 + 0.5) / n as f64 - 0.5
                    };
                    [x0 + f * blur_um, y0]
                })
                .collect();
            let f = r.render_path(&path, 1.0, 1.0, 1000 + k, 0.0, k).unwrap();
            let d = dec.decode(&f).unwrap();
            ex.push(d.x_um - x0);
            ey.push(d.y_um - y0);
        }
        let ((bx, sx), (by, sy)) = (stats(&ex), stats(&ey));
        println!("{blur_um}\t{n}\t{bx:.4}\t{sx:.4}\t{by:.4}\t{sy:.4}");
        rows.push((blur_um, bx, sx, by, sy));
    }
    for (blur_um, bx, sx, by, sy) in rows {
        // Symmetric blur leaves the mid-point: no bias beyond the still
        // frame's, noise of the same order up to a blur of a period.
        if blur_um <= 2.0 {
            assert!(bx.abs() < 0.02 && by.abs() < 0.02, "blur {blur_um}: bias");
            assert!(sx < 0.02 && sy < 0.02, "blur {blur_um}: sigma");
        } else {
            assert!(bx.abs() < 0.1 && sx < 0.1, "blur {blur_um}");
        }
    }
    // A blur of one whole period erases the grid along the motion: the
    // decoder refuses the frame rather than guess.
    let path: Vec<[f64; 2]> = (0..41)
        .map(|i| [5000.0 + (f64::from(i) + 0.5) / 41.0 * cfg.period_um, 5000.0])
        .collect();
    let f = r.render_path(&path, 1.0, 1.0, 7, 0.0, 99).unwrap();
    assert!(dec.decode(&f).is_err());
}

/// A grab during constant-velocity travel: decoded = the truth at the
/// exposure mid-point; the stamp = mid-point + latency + jitter.
#[test]
fn grab_in_motion_is_blurred_about_the_midpoint_and_stamped_late() {
    let cfg = CameraConfig {
        exposure_us: 5000.0,
        latency_us: 2500.0,
        timestamp_jitter_us: 30.0,
        ..CameraConfig::default()
    };
    let rig = Arc::new(Rig::new(StageModel::ideal(), 3, [5.0, 5.0], Mounting::default()).unwrap());
    let clock = Arc::new(ManualClock::new());
    let cam = SimCamera::new(&cfg, rig.clone(), clock.clone(), 9).unwrap();
    // 0.4 mm/s: 2 µm of travel per 5 ms exposure (5 px of blur).
    let lim = Limits {
        velocity: 0.4,
        acceleration: 10.0,
        deceleration: 10.0,
    };
    let p = Profile::plan(Duration::ZERO, 5.0, 0.0, 6.0, lim);
    rig.set_path(
        Axis::X,
        &ActuatorPath {
            offset_mm: 0.0,
            profile: Some(p),
            rest_encoder_mm: 5.0,
        },
        Duration::ZERO,
    );
    clock.set(Duration::from_millis(200));
    let mut dec = Decoder::new(DecodeOptions::new(cfg.period_um, cfg.bits)).unwrap();
    let (mut lag, mut err) = (Vec::new(), Vec::new());
    for _ in 0..12 {
        let g = cam.grab().unwrap();
        assert!(g.truth.moving);
        lag.push(g.frame.timestamp_s - g.truth.sim_time_s);
        let d = dec.decode(&g.frame).unwrap();
        err.push(d.x_um - g.truth.observed_pattern_um[0]);
        clock.advance(Duration::from_millis(40));
    }
    let (lag_m, lag_s) = stats(&lag);
    assert!((lag_m - 2.5e-3).abs() < 30e-6, "latency {lag_m}");
    assert!(lag_s > 10e-6 && lag_s < 60e-6, "jitter {lag_s}");
    let (b, s) = stats(&err);
    assert!(b.abs() < 0.03 && s < 0.03, "blurred decode {b} ± {s}");
}
