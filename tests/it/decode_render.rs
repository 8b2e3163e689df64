//! Decoder accuracy on rendered frames (seeded): precision, bias, angle, and
//! absolute correctness over whole patterns.
//!
//! `MICROPOS_FULL=1` runs the full 1000-pose absolute test per pattern; the
//! default run uses fewer poses to keep the suite fast.

use micropos::pattern::decode::{DecodeError, DecodeOptions, Decoder};
use micropos::pattern::render::{Pose, RenderConfig, Renderer};
use micropos::pattern::sequence::LineSequence;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const P: f64 = 9.0;
const PX: f64 = 0.9; // 10 px per period

fn cfg_1024() -> RenderConfig {
    RenderConfig {
        period_um: P,
        bits: 12,
        read_noise: 0.01,
        blur_sigma_px: 1.0,
        ..RenderConfig::default()
    }
}

fn std_dev(v: &[f64]) -> f64 {
    let m = v.iter().sum::<f64>() / v.len() as f64;
    (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (v.len() - 1) as f64).sqrt()
}

#[test]
fn precision_static_pose_8bit_1pct_noise() {
    let mut r = Renderer::new(cfg_1024()).unwrap();
    let mut d = Decoder::new(DecodeOptions::new(P, 12)).unwrap();
    let pose = Pose {
        x_um: 15_000.3,
        y_um: 20_000.7,
        theta_rad: 0.25,
        pixel_um: PX,
        mirrored: false,
    };
    let (mut xs, mut ys, mut ts) = (vec![], vec![], vec![]);
    for seed in 0..10 {
        let f = r.render(&pose, 100 + seed, 0.0, seed).unwrap();
        let o = d.decode(&f).unwrap();
        xs.push(o.x_um / PX);
        ys.push(o.y_um / PX);
        ts.push(o.theta_rad - pose.theta_rad);
        assert!((o.x_um - pose.x_um).abs() < 0.01 && (o.y_um - pose.y_um).abs() < 0.01);
    }
    let (sx, sy) = (std_dev(&xs), std_dev(&ys));
    eprintln!(
        "precision: std x {sx:.2e} px, y {sy:.2e} px; max |dθ| {:.2e} rad",
        ts.iter().fold(0.0f64, |a, b| a.max(b.abs()))
    );
    assert!(sx <= 1e-3 && sy <= 1e-3, "std {sx} {sy}");
    assert!(ts.iter().all(|t| t.abs() < 1e-4));
}

#[test]
fn bias_sub_period_sweep_and_angle() {
    let mut r = Renderer::new(RenderConfig {
        read_noise: 0.0,
        bit_depth: 16,
        ..cfg_1024()
    })
    .unwrap();
    let mut worst: f64 = 0.0;
    let mut worst_t: f64 = 0.0;
    for (i, theta) in [0.02, -0.7, 2.0].iter().enumerate() {
        for step in 0..8 {
            // Sweep one period diagonally in sub-pixel steps.
            let f = step as f64 / 8.0;
            let pose = Pose {
                x_um: 30_000.0 + 1000.0 * i as f64 + f * P,
                y_um: 12_000.0 + f * P * 0.6,
                theta_rad: *theta,
                pixel_um: PX,
                mirrored: i == 1,
            };
            let mut opts = DecodeOptions::new(P, 12);
            opts.mirrored = pose.mirrored;
            let mut d = Decoder::new(opts).unwrap();
            let o = d.decode(&r.render(&pose, 0, 0.0, 0).unwrap()).unwrap();
            let ex = (o.x_um - pose.x_um) / PX;
            let ey = (o.y_um - pose.y_um) / PX;
            eprintln!("θ {theta} step {step}: ex {ex:.2e} ey {ey:.2e}");
            worst = worst.max(ex.abs()).max(ey.abs());
            worst_t = worst_t.max((o.theta_rad - pose.theta_rad).abs());
        }
    }
    eprintln!("bias: worst |error| {worst:.2e} px, worst |dθ| {worst_t:.2e} rad");
    // Without the missing-dot correction the worst is 2.3e-3 px (θ = 2.0
    // rad, a constant offset over the sweep); with it ≈ 5e-4 px.
    assert!(worst <= 1e-3, "bias {worst} px");
    assert!(worst_t <= 1e-4, "theta error {worst_t} rad");
}

#[test]
fn tracking_matches_cold_decode() {
    let mut r = Renderer::new(cfg_1024()).unwrap();
    let mut d = Decoder::new(DecodeOptions::new(P, 12)).unwrap();
    for i in 0..4 {
        let pose = Pose {
            x_um: 5_000.0 + 0.37 * i as f64,
            y_um: 7_000.0 - 0.21 * i as f64,
            theta_rad: 1.0 + 1e-4 * i as f64,
            pixel_um: PX,
            mirrored: false,
        };
        let f = r.render(&pose, i, 0.0, i).unwrap();
        let t = d.track(&f).unwrap();
        assert_eq!(t.tracked, i > 0);
        assert_eq!(t.code_predicted, i > 0, "tracking fast path not taken");
        assert!(
            (t.x_um - pose.x_um).abs() < 2e-3 && (t.y_um - pose.y_um).abs() < 2e-3,
            "{t:?}"
        );
    }
}

#[test]
fn tracking_survives_jumps_and_rotation() {
    // A move of many periods between frames defeats the continuity
    // prediction; the check must notice and fall back to the full search.
    let mut r = Renderer::new(cfg_1024()).unwrap();
    let mut d = Decoder::new(DecodeOptions::new(P, 12)).unwrap();
    let poses = [
        (5_000.0, 7_000.0, 1.0),
        (5_000.4, 7_000.2, 1.0),
        (5_000.4 + 3.0 * P, 7_000.2, 1.0),
        (5_000.4 + 3.0 * P, 7_000.2 - 40.0 * P, 1.0),
        (9_100.0, 3_000.0, 1.0),
        (9_100.0, 3_000.0, 1.0 + std::f64::consts::FRAC_PI_2),
    ];
    for (i, &(x, y, t)) in poses.iter().enumerate() {
        let pose = Pose {
            x_um: x,
            y_um: y,
            theta_rad: t,
            pixel_um: PX,
            mirrored: false,
        };
        let f = r.render(&pose, i as u64, 0.0, i as u64).unwrap();
        let o = d.track(&f).unwrap();
        assert!(
            (o.x_um - x).abs() < 2e-3 && (o.y_um - y).abs() < 2e-3,
            "frame {i}: {o:?}"
        );
        if i == 1 {
            assert!(o.code_predicted);
        }
        if i >= 2 {
            assert!(!o.code_predicted, "frame {i} accepted a wrong prediction");
        }
    }
}

/// The next random view of the pose tests: render settings and pose over a
/// pattern of extent `extent` µm.
fn random_view(
    rng: &mut ChaCha8Rng,
    bits: u32,
    extent: f64,
    w: usize,
    h: usize,
) -> (RenderConfig, Pose) {
    let mirrored = rng.gen_bool(0.3);
    let dark = rng.gen_bool(0.3);
    let pixel = P / rng.gen_range(7.0..11.0);
    let cfg = RenderConfig {
        width: w,
        height: h,
        period_um: P,
        bits,
        dark_dots: dark,
        blur_sigma_px: rng.gen_range(0.5..1.8),
        gradient: [rng.gen_range(-0.3..0.3), rng.gen_range(-0.3..0.3)],
        vignetting: rng.gen_range(0.0..0.4),
        read_noise: rng.gen_range(0.005..0.02),
        dust_fraction: rng.gen_range(0.0..0.15),
        dust_seed: rng.gen(),
        oversample: oversample(),
        ..RenderConfig::default()
    };
    let pose = Pose {
        x_um: rng.gen_range(0.0..extent),
        y_um: rng.gen_range(0.0..extent),
        theta_rad: rng.gen_range(-std::f64::consts::PI..std::f64::consts::PI),
        pixel_um: pixel,
        mirrored,
    };
    (cfg, pose)
}

/// Views of the 10-bit pose test (#207, #772; σ·k 1.5 and 1.2) where the
/// peak search locked onto the 3-period structure's k/3 (22.3 px) and its
/// diagonal (k_a ± k_b)/3 (16.7 px) instead of the ~7.5 px grid: the other
/// lattice readings of the spectrum must find the grid and decode right.
#[test]
fn lattice_lock_on_views_decode() {
    let bits = 10;
    let seq = LineSequence::new(bits).unwrap();
    let extent = (seq.len() - 1) as f64 * P;
    let mut rng = ChaCha8Rng::seed_from_u64(10);
    for i in 0..=772u64 {
        let (cfg, pose) = random_view(&mut rng, bits, extent, 1024, 768);
        if i != 207 && i != 772 {
            continue;
        }
        let f = Renderer::new(cfg)
            .unwrap()
            .render(&pose, i, 0.0, 0)
            .unwrap();
        let mut opts = DecodeOptions::new(P, bits);
        opts.mirrored = pose.mirrored;
        let o = Decoder::new(opts).unwrap().decode(&f);
        eprintln!("view #{i}: {o:?}");
        let o = o.unwrap();
        assert!(
            (o.x_um - pose.x_um).hypot(o.y_um - pose.y_um) < 0.1,
            "view #{i}: {o:?} for {pose:?}"
        );
    }
}

/// Random poses over a whole pattern: no wrong absolute position, ever;
/// failures only as errors and only where the view is not fully on the
/// pattern (or is badly occluded).
fn absolute(bits: u32, n: usize, seed: u64) {
    let seq = LineSequence::new(bits).unwrap();
    let extent = (seq.len() - 1) as f64 * P;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let (w, h) = (1024usize, 768usize);
    let (mut ok, mut wrong, mut err_inside, mut err_edge) = (0, 0, 0, 0);
    let mut unexplained = 0;
    let mut worst = 0.0f64;
    // Errors per condition: (label, poses, errors) by blur σ·k, dust
    // fraction and dot polarity (on-pattern views only).
    let mut by_blur = [
        ("σ·k < 0.6", 0, 0),
        ("σ·k 0.6–1.0", 0, 0),
        ("σ·k ≥ 1.0", 0, 0),
    ];
    let mut by_dust = [
        ("dust < 5 %", 0, 0),
        ("dust 5–10 %", 0, 0),
        ("dust ≥ 10 %", 0, 0),
    ];
    let mut by_pol = [("bright dots", 0, 0), ("dark dots", 0, 0)];
    for i in 0..n {
        let (cfg, pose) = random_view(&mut rng, bits, extent, w, h);
        let mirrored = pose.mirrored;
        let dark = cfg.dark_dots;
        let pixel = pose.pixel_um;
        let cfg_dbg = (
            cfg.blur_sigma_px,
            cfg.dust_fraction,
            cfg.vignetting,
            cfg.gradient,
        );
        let mut r = Renderer::new(cfg).unwrap();
        let f = r.render(&pose, i as u64, 0.0, 0).unwrap();
        let mut opts = DecodeOptions::new(P, bits);
        opts.mirrored = mirrored;
        let mut d = Decoder::new(opts).unwrap();
        let inside = [
            (0.0, 0.0),
            (w as f64, 0.0),
            (0.0, h as f64),
            (w as f64, h as f64),
        ]
        .iter()
        .all(|&(u, v)| {
            let (x, y) = pose.pattern_point(w, h, u, v);
            (-P..extent + P).contains(&x) && (-P..extent + P).contains(&y)
        });
        let sigma_k = cfg_dbg.0 * std::f64::consts::TAU * pixel / P;
        let bins = [
            (sigma_k >= 0.6) as usize + (sigma_k >= 1.0) as usize,
            (cfg_dbg.1 >= 0.05) as usize + (cfg_dbg.1 >= 0.10) as usize,
            dark as usize,
        ];
        let result = d.decode(&f);
        if inside {
            let failed = result.is_err() as usize;
            by_blur[bins[0]].1 += 1;
            by_blur[bins[0]].2 += failed;
            by_dust[bins[1]].1 += 1;
            by_dust[bins[1]].2 += failed;
            by_pol[bins[2]].1 += 1;
            by_pol[bins[2]].2 += failed;
        }
        match result {
            Ok(o) => {
                let e = (o.x_um - pose.x_um).hypot(o.y_um - pose.y_um);
                let dt = (o.theta_rad - pose.theta_rad + std::f64::consts::PI)
                    .rem_euclid(std::f64::consts::TAU)
                    - std::f64::consts::PI;
                if e > P / 4.0 || dt.abs() > 0.01 {
                    wrong += 1;
                    eprintln!("WRONG pose {pose:?} -> {o:?}");
                } else {
                    ok += 1;
                    worst = worst.max(e);
                }
            }
            Err(e) => {
                if inside {
                    err_inside += 1;
                    // Failures must have a stated reason: too few readable
                    // code lines (< n + 4), or a grid or orientation stage
                    // failure under heavy blur (σ·k ≥ 1.0: the fundamental
                    // is attenuated to ≤ 61 %, the 3-period structure's
                    // components much less, and with dust and noise the dot
                    // contrast left is a few % of full scale).
                    let explained = match &e {
                        DecodeError::CodeAmbiguous { readable_bits, .. } => {
                            *readable_bits < bits as usize + 4
                        }
                        DecodeError::NoGrid(_) | DecodeError::Orientation(_) => sigma_k >= 1.0,
                        _ => false,
                    };
                    if !explained {
                        unexplained += 1;
                    }
                    eprintln!(
                        "error inside pattern: #{i} {pose:?} blur {:.2} dust {:.3} vign {:.2} grad {:?}: {e}",
                        cfg_dbg.0, cfg_dbg.1, cfg_dbg.2, cfg_dbg.3
                    );
                } else {
                    err_edge += 1;
                }
            }
        }
    }
    eprintln!(
        "absolute {bits}-bit: {n} poses, ok {ok}, wrong {wrong}, errors inside {err_inside}, errors at pattern edge {err_edge}, worst ok error {worst:.4} µm"
    );
    for (label, poses, errors) in by_blur.iter().chain(&by_dust).chain(&by_pol) {
        eprintln!("  {bits}-bit {label}: {errors} errors / {poses} on-pattern poses");
    }
    assert_eq!(wrong, 0);
    // 1024×768 (the target camera) at 7–11 px/period. They must fail as
    // errors, rarely, and only for a stated reason (measured counts in
    // docs/design/vision.md).
    assert_eq!(
        unexplained, 0,
        "on-pattern failures without a stated reason"
    );
    assert!(
        err_inside * 50 <= n.max(100),
        "too many failures on on-pattern views: {err_inside}/{n}"
    );
}

/// Renderer oversampling of the pose test: 1 (fast, default) or
/// `MICROPOS_OVERSAMPLE`.
fn oversample() -> usize {
    std::env::var("MICROPOS_OVERSAMPLE")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(1)
}

fn pose_count() -> usize {
    if std::env::var("MICROPOS_FULL").is_ok_and(|v| v == "1") {
        1000
    } else {
        60
    }
}

#[test]
fn absolute_random_poses_10bit() {
    absolute(10, pose_count(), 10);
}

#[test]
fn absolute_random_poses_12bit() {
    absolute(12, pose_count(), 12);
}

/// The decoded θ against a known rotation across the platform's yaw range:
/// each view is a random mounting angle turned by a yaw, half of them
/// within the M-111's ±150 µrad, half within ±1 mrad, at random positions
/// fully on the pattern, under the pose tests' random render conditions,
/// for both pattern depths. Prints rms and bias of decoded θ − true θ
/// (µrad) per depth and yaw band, and the slope of the error against the
/// yaw (a θ scale error would show there):
/// `cargo test --release --test it decode_render::theta -- --nocapture`
/// (`MICROPOS_FULL=1`: 400 views per depth instead of 48).
///
/// Measured (`MICROPOS_FULL=1`, 400 views per depth, seeds 34 and 35):
/// 10-bit bias +1.1 µrad, rms 17.2 µrad, worst 117 µrad; 12-bit bias
/// +2.4 µrad, rms 19.1 µrad, worst 138 µrad; slope against the yaw within
/// ±0.005; the same within ±150 µrad and out to ±1 mrad. The default 48
/// views: rms 23.6 and 15.7 µrad. Bounds, with margin over those: rms ≤
/// 30 µrad, |bias| ≤ 4·rms/√n (no bias beyond the sample's own scatter),
/// |slope| ≤ 0.05 (the yaw read at 95 % or more of its size), worst ≤
/// 250 µrad. The dust (up to 15 % of the frame here) is most of it:
/// `theta_per_render_condition` takes the effects one at a time. The error
/// is a property of the view, not noise, so averaging frames of one pose
/// does not reduce it.
#[test]
fn theta_follows_the_yaw_across_its_range() {
    let n = if std::env::var("MICROPOS_FULL").is_ok_and(|v| v == "1") {
        400
    } else {
        48
    };
    for (bits, seed) in [(10, 34), (12, 35)] {
        theta_accuracy(bits, n, seed);
    }
}

fn theta_accuracy(bits: u32, n: usize, seed: u64) {
    let seq = LineSequence::new(bits).unwrap();
    let extent = (seq.len() - 1) as f64 * P;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let (w, h) = (1024usize, 768usize);
    // (yaw_urad, dθ_urad) per decoded view.
    let mut got: Vec<(f64, f64)> = Vec::new();
    let mut failed = 0;
    for i in 0..n {
        let (cfg, mut pose) = random_view(&mut rng, bits, extent, w, h);
        let band_urad = if i % 2 == 0 { 150.0 } else { 1000.0 };
        let yaw_urad = rng.gen_range(-band_urad..band_urad);
        // Fully on the pattern: half the diagonal of the widest view
        // (1280 px × P/7) is 823 µm.
        let margin = 900.0;
        pose.x_um = rng.gen_range(margin..extent - margin);
        pose.y_um = rng.gen_range(margin..extent - margin);
        pose.theta_rad += yaw_urad * 1e-6;
        let f = Renderer::new(cfg)
            .unwrap()
            .render(&pose, 500 + i as u64, 0.0, 0)
            .unwrap();
        let mut opts = DecodeOptions::new(P, bits);
        opts.mirrored = pose.mirrored;
        match Decoder::new(opts).unwrap().decode(&f) {
            Ok(o) => {
                let dt = (o.theta_rad - pose.theta_rad + std::f64::consts::PI)
                    .rem_euclid(std::f64::consts::TAU)
                    - std::f64::consts::PI;
                assert!(
                    (o.x_um - pose.x_um).hypot(o.y_um - pose.y_um) < P / 4.0,
                    "view #{i}: {o:?} for {pose:?}"
                );
                got.push((yaw_urad, dt * 1e6));
            }
            // The pose tests bound how often a view fails and why.
            Err(_) => failed += 1,
        }
    }
    let summary = |v: &[f64]| {
        let k = v.len().max(1) as f64;
        let bias = v.iter().sum::<f64>() / k;
        let rms = (v.iter().map(|e| e * e).sum::<f64>() / k).sqrt();
        let worst = v.iter().fold(0.0f64, |a, e| a.max(e.abs()));
        (bias, rms, worst)
    };
    for (label, lo, hi) in [
        ("|yaw| < 150 µrad", 0.0, 150.0),
        ("150 µrad ≤ |yaw| < 1 mrad", 150.0, 1000.0),
    ] {
        let e: Vec<f64> = got
            .iter()
            .filter(|(y, _)| (lo..hi).contains(&y.abs()))
            .map(|g| g.1)
            .collect();
        let (bias, rms, worst) = summary(&e);
        eprintln!(
            "θ {bits}-bit {label}: {} views, bias {bias:+.1} µrad, rms {rms:.1} µrad, worst {worst:.1} µrad",
            e.len()
        );
    }
    let all: Vec<f64> = got.iter().map(|g| g.1).collect();
    let (bias, rms, worst) = summary(&all);
    // Least-squares slope of dθ against the yaw.
    let k = got.len() as f64;
    let my = got.iter().map(|g| g.0).sum::<f64>() / k;
    let sxy: f64 = got.iter().map(|g| (g.0 - my) * (g.1 - bias)).sum();
    let sxx: f64 = got.iter().map(|g| (g.0 - my).powi(2)).sum();
    let slope = sxy / sxx;
    eprintln!(
        "θ {bits}-bit all: {} views ({failed} failed to decode), bias {bias:+.1} µrad, rms {rms:.1} µrad, worst {worst:.1} µrad, slope against the yaw {slope:+.4}",
        got.len()
    );
    assert!(got.len() * 10 >= n * 9, "{failed} of {n} views failed");
    assert!(rms <= 30.0, "θ rms {rms:.1} µrad");
    assert!(
        bias.abs() <= 4.0 * rms / k.sqrt(),
        "θ bias {bias:+.1} µrad against rms {rms:.1} over {k} views"
    );
    assert!(
        slope.abs() <= 0.05,
        "θ error grows with the yaw: {slope:+.4}"
    );
    assert!(worst <= 250.0, "worst θ error {worst:.1} µrad");
}

/// θ per render condition, one effect at a time on a clean 10-bit view
/// (1024 × 768, blur σ 0.8 px, 0.5 % read noise, 7–11 px per period, random
/// mounting angle and position), and the simulated rig's camera: what each
/// effect costs in θ, and so in tool error (arm × θ). The rotation is read
/// from the globally windowed moments with the missing dots' effect taken
/// from the code (`pattern::decode::sites`); the tile-phase plane fit that
/// refines k gave 4.0 µrad rms on the clean views.
///
/// Measured (30 views per condition, `MICROPOS_FULL=1`; µrad rms): clean
/// 0.43, no read noise 0.08, shading (gradient 0.25/−0.2, vignetting 0.3)
/// 0.49, read noise 2 % 1.55, blur σ 1.6 px 0.66, dust over 10 % 10.8,
/// the simulated rig's camera 0.27 (0.005 µm on a 20 mm arm). Bounds:
/// about 2.5× those (12 views by default); the tile fit's 4.0 on the
/// clean views fails them.
#[test]
fn theta_per_render_condition() {
    let bits = 10;
    let seq = LineSequence::new(bits).unwrap();
    let extent = (seq.len() - 1) as f64 * P;
    let n = if std::env::var("MICROPOS_FULL").is_ok_and(|v| v == "1") {
        30
    } else {
        12
    };
    type Tweak = fn(&mut RenderConfig);
    let cases: [(&str, Tweak, f64); 7] = [
        ("clean", |_| {}, 1.2),
        ("no read noise", |c| c.read_noise = 0.0, 0.25),
        (
            "shading",
            |c| {
                c.gradient = [0.25, -0.2];
                c.vignetting = 0.3;
            },
            1.2,
        ),
        ("read noise 2 %", |c| c.read_noise = 0.02, 4.0),
        ("blur σ 1.6 px", |c| c.blur_sigma_px = 1.6, 1.6),
        ("dust 10 %", |c| c.dust_fraction = 0.1, 28.0),
        (
            "simulated rig",
            |c| {
                c.blur_sigma_px = 0.9;
                c.gradient = [0.03, -0.02];
                c.vignetting = 0.08;
                c.read_noise = 0.003;
            },
            1.0,
        ),
    ];
    for (label, tweak, bound_urad) in cases {
        let mut rng = ChaCha8Rng::seed_from_u64(77);
        let mut e = Vec::new();
        for i in 0..n {
            let mut cfg = RenderConfig {
                bits,
                period_um: P,
                dust_seed: rng.gen(),
                ..RenderConfig::default()
            };
            tweak(&mut cfg);
            let pose = Pose {
                x_um: rng.gen_range(900.0..extent - 900.0),
                y_um: rng.gen_range(900.0..extent - 900.0),
                theta_rad: rng.gen_range(-std::f64::consts::PI..std::f64::consts::PI),
                pixel_um: P / rng.gen_range(7.0..11.0),
                mirrored: false,
            };
            let f = Renderer::new(cfg)
                .unwrap()
                .render(&pose, 900 + i as u64, 0.0, 0)
                .unwrap();
            let o = Decoder::new(DecodeOptions::new(P, bits))
                .unwrap()
                .decode(&f)
                .unwrap_or_else(|err| panic!("{label} view #{i}: {err}"));
            let dt = (o.theta_rad - pose.theta_rad + std::f64::consts::PI)
                .rem_euclid(std::f64::consts::TAU)
                - std::f64::consts::PI;
            e.push(dt * 1e6);
        }
        let rms = (e.iter().map(|x| x * x).sum::<f64>() / e.len() as f64).sqrt();
        eprintln!("θ {label}: {n} views, rms {rms:.2} µrad");
        assert!(
            rms <= bound_urad,
            "θ {label}: rms {rms:.2} µrad > {bound_urad}"
        );
    }
}
