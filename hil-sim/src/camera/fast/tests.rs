use super::sensor::quantize;
use super::stamp::{floor, round_non_negative};
use super::*;

#[test]
fn quantize_rounds_to_nearest_even() {
    for (x, want) in [
        (0.0, 0u16),
        (0.49, 0),
        (0.5, 0),
        (0.51, 1),
        (1.5, 2),
        (2.5, 2),
        (1023.4, 1023),
        (65534.5, 65534),
        (65535.0, 65535),
    ] {
        assert_eq!(quantize(x), want, "{x}");
    }
    for i in 0..=65535u16 {
        assert_eq!(quantize(f32::from(i)), i);
    }
}

#[test]
fn inline_floor_and_round_are_the_std_ones() {
    let mut xs = vec![
        0.0,
        -0.0,
        0.5,
        1.5,
        2.5,
        0.499_999_999_999_999_94,
        -0.5,
        -1.0,
        -1.000_000_000_000_000_2,
        31.999_999_999_999_996,
        1e9,
        -1e9 + 0.5,
        4_503_599_627_370_497.0,
    ];
    let mut z = 0.123_456_789f64;
    for _ in 0..10_000 {
        z = (z * 3.9 * (1.0 - z)).clamp(1e-9, 1.0 - 1e-9);
        xs.push((z - 0.5) * 2e4);
        xs.push(z * 32.0);
    }
    for x in xs {
        assert_eq!(floor(x), x.floor(), "floor({x})");
        if x >= 0.0 {
            assert_eq!(round_non_negative(x), x.round(), "round({x})");
        }
    }
}

#[test]
fn erfc_is_accurate() {
    for (x, want) in [
        (0.0, 1.0),
        (0.5, 0.479_500_122_186_953_5),
        (1.0, 0.157_299_207_050_285_1),
        (-1.0, 1.842_700_792_949_715),
        (2.5, 4.069_520_174_449_59e-4),
    ] {
        assert!((erfc(x) - want).abs() < 2e-7, "erfc({x})");
    }
}

#[test]
fn banded_render_gives_the_two_pass_frame_bit_for_bit() {
    // Odd heights: the halves differ in size and end in partial bands
    // (71 rows: one band and a bit per half; 171: several). A still
    // frame and a blank one, rendered both ways on the same renderer.
    for height in [71, 171] {
        let cfg = CameraConfig {
            width: 96,
            height,
            ..CameraConfig::default()
        };
        let mut r = FastRenderer::new(&cfg, 0.3f64.to_radians()).unwrap();
        let path = [[1234.5, 987.25]];
        let banded = r.render_path(&path, 0.9, 1.3, 17, 1.0, 5).unwrap();
        let two_pass = r.two_pass(&path, 0.9, 1.3, 17);
        assert_eq!(banded.pixels(), &Pixels::U16(two_pass), "height {height}");
        assert_ne!(
            r.render_path(&path, 0.9, 1.3, 18, 1.0, 5).unwrap().pixels(),
            banded.pixels(),
            "another noise seed gives another frame"
        );
        let blank = r.garbage(false, 3, 0.0, 1).unwrap();
        assert_eq!(blank.pixels(), &Pixels::U16(r.two_pass(&[], 1.0, 1.0, 3)));
    }
}

/// The instants of a sweep as `SimCamera::grab` takes them: `n`
/// equally spaced instants of an exposure of `exposure_s` at constant
/// velocity `v_um_s` (pattern frame) whose mid-point is at `mid_um`.
fn sweep(mid_um: [f64; 2], v_um_s: [f64; 2], exposure_s: f64, n: usize) -> Vec<[f64; 2]> {
    (0..n)
        .map(|k| {
            let f = ((k as f64 + 0.5) / n as f64 - 0.5) * exposure_s;
            [mid_um[0] + v_um_s[0] * f, mid_um[1] + v_um_s[1] * f]
        })
        .collect()
}

fn pixels16(f: &Frame) -> &[u16] {
    match f.pixels() {
        Pixels::U16(p) => p,
        Pixels::U8(_) => panic!("a 10-bit frame"),
    }
}

#[test]
fn a_blurred_stamp_is_the_mean_of_the_sharp_stamps_at_the_rounded_shifts() {
    // An accelerating path at a mounting angle of 7°: its displacements
    // are not symmetric about the middle instant and move the dots'
    // images along both image axes, across whole pixels both ways, so
    // the sign, the axes and the rounding of the shifts all show in the
    // table (a symmetric path would hide a sign error).
    let cfg = CameraConfig {
        width: 64,
        height: 64,
        ..CameraConfig::default()
    };
    let theta = 7f64.to_radians();
    let mut r = FastRenderer::new(&cfg, theta).unwrap();
    let path: Vec<[f64; 2]> = [0.0, 0.07, 0.2, 0.42, 0.75]
        .iter()
        .map(|t| [3000.0 + t, 2000.0 - 0.5 * t])
        .collect();
    assert!(r.build_blur(&path));
    // Where a fixed pattern point's image lies, px from the image
    // centre, with `c` at the centre: the inverse of the rotation of
    // `stamp_rows` (pattern = c + s·R·(u, v), R = [[cos, sin],
    // [−sin, cos]]).
    let (sn, cs) = theta.sin_cos();
    let image = |c: [f64; 2]| {
        let (dx, dy) = (-c[0] / cfg.pixel_um, -c[1] / cfg.pixel_um);
        [cs * dx - sn * dy, sn * dx + cs * dy]
    };
    let q = Q as i64;
    let [ur, vr] = image(path[2]);
    let shifts: Vec<(i64, i64)> = path
        .iter()
        .map(|&c| {
            let [u, v] = image(c);
            let d = |x: f64| (x * Q as f64).round() as i64;
            (d(u - ur), d(v - vr))
        })
        .collect();
    assert!(shifts.iter().any(|s| s.0 < -q) && shifts.iter().any(|s| s.0 > 0));
    assert!(shifts.iter().any(|s| s.1 > q / 4) && shifts.iter().any(|s| s.1 < 0));
    // Every phase's blurred stamp and the mean of the sharp stamps,
    // each laid on a canvas of offsets from the dot's pixel (origin at
    // `o`): equal up to float rounding (five f32 products and sums of
    // values ≤ 1: ≲ 3e-7), and nothing beyond the blurred stamp.
    let (n, o) = (64usize, 32i64);
    let (k, side, sstride) = (r.k as i64, r.side, r.stride);
    let g = r.blur_geom;
    assert!(g.cols <= g.stride && g.stride % 8 == 0);
    let mut worst = 0f64;
    for b in 0..q {
        for a in 0..q {
            let mut want = vec![0f64; n * n];
            for &(sx, sy) in &shifts {
                let (ta, tb) = (a + sx, b + sy);
                let ph = (tb.rem_euclid(q) * q + ta.rem_euclid(q)) as usize;
                let (col, row) = (o + ta.div_euclid(q) - k, o + tb.div_euclid(q) - k);
                for ky in 0..side {
                    for kx in 0..side {
                        let v = r.stamps[(ph * side + ky) * sstride + kx];
                        let at = (row as usize + ky) * n + col as usize + kx;
                        want[at] += f64::from(v) / shifts.len() as f64;
                    }
                }
            }
            let mut got = vec![0f64; n * n];
            let ph = (b * q + a) as usize;
            let table = &r.blur[ph * g.rows * g.stride..(ph + 1) * g.rows * g.stride];
            for ky in 0..g.rows {
                for kx in 0..g.stride {
                    let v = table[ky * g.stride + kx];
                    if kx >= g.cols {
                        assert_eq!(v.to_bits(), 0, "padding is +0.0");
                        continue;
                    }
                    let row = (o + g.row_off) as usize + ky;
                    got[row * n + (o + g.col_off) as usize + kx] = f64::from(v);
                }
            }
            for (i, (w, g)) in want.iter().zip(&got).enumerate() {
                let d = (w - g).abs();
                assert!(d < 1e-6, "phase ({a}, {b}), offset {i}: {g} vs {w}");
                worst = worst.max(d);
            }
        }
    }
    println!("largest difference from the mean of the sharp stamps: {worst:.2e}");
}

/// The most a pixel of a frame rendered with `light` and `analog_gain`
/// changes when one dot moves by one phase step (1/Q px) along each
/// image axis, codes: the stamps' largest difference between
/// neighbouring phases along x plus along y, times the dot's contrast
/// at the brightest shading, times the growth of the shot noise term
/// with the signal (at most 1 + max|noise| · (1/full well) / (2 · read
/// noise)).
fn phase_step_codes(r: &FastRenderer, light: f64, analog_gain: f64) -> f64 {
    let (side, stride) = (r.side, r.stride);
    let stamp = |a: usize, b: usize| &r.stamps[(b * Q + a) * side * stride..][..side * stride];
    let (mut dx, mut dy) = (0f32, 0f32);
    for b in 0..Q - 1 {
        for a in 0..Q - 1 {
            for ((s, sx), sy) in stamp(a, b).iter().zip(stamp(a + 1, b)).zip(stamp(a, b + 1)) {
                dx = dx.max((sx - s).abs());
                dy = dy.max((sy - s).abs());
            }
        }
    }
    let c = &r.cfg;
    let shade = r.shade.iter().fold(0f32, |m, &s| m.max(s));
    let noise = r.noise.iter().fold(0f32, |m, &n| m.max(n.abs()));
    let shot = 1.0 + f64::from(noise) / c.full_well_e / (2.0 * c.read_noise);
    let full_scale = f64::from((1u32 << c.bit_depth) - 1);
    f64::from(dx + dy)
        * (c.foreground - c.background).abs()
        * f64::from(shade)
        * light
        * analog_gain
        * full_scale
        * shot
}

#[test]
fn a_blurred_frame_is_the_per_instant_frame_up_to_the_rounding() {
    // The paper camera's sweep (240 µm/s, 2 ms: 1.2 px of blur, five
    // instants) along x, y and the diagonals, both ways, and blurs five
    // times as long, at the rig's mounting angle; each blurred frame
    // against the same path placed instant by instant, same noise.
    let cfg = CameraConfig {
        width: 256,
        height: 192,
        ..CameraConfig::default()
    };
    let theta = 0.3f64.to_radians();
    let (sn, cs) = theta.sin_cos();
    let mut r = FastRenderer::new(&cfg, theta).unwrap();
    let (light, gain) = (0.9, 1.3);
    // How much the rounding may move a pixel: every instant of a dot
    // one phase step off along each axis (the displacement rounded
    // apart from the position, where placing instant by instant
    // rounds their sum), plus one code of quantisation.
    let tolerance = phase_step_codes(&r, light, gain).ceil() as u16 + 1;
    println!("tolerance {tolerance} codes");
    let d = 240.0 / 2f64.sqrt();
    let mut all = (0u16, 0i64, 0usize, 0usize);
    for (v, n) in [
        ([240.0, 0.0], 5),
        ([-240.0, 0.0], 5),
        ([0.0, 240.0], 5),
        ([0.0, -240.0], 5),
        ([d, d], 5),
        ([-d, -d], 5),
        ([d, -d], 5),
        ([1200.0, 0.0], 25),
        ([-d * 5.0, d * 5.0], 25),
    ] {
        let (mut max, mut sum, mut sq, mut len) = (0u16, 0i64, 0i64, 0usize);
        for (i, mid) in [[2000.0, 1500.0], [5321.7, 8765.43], [1234.56, 3000.01]]
            .into_iter()
            .enumerate()
        {
            let path = sweep(mid, v, 2e-3, n);
            let seed = 40 + i as u64;
            let blurred = r.render_path(&path, light, gain, seed, 1.0, 5).unwrap();
            let blurred = pixels16(&blurred);
            let per_instant = r
                .render_path_per_instant(&path, light, gain, seed, 1.0, 5)
                .unwrap();
            let per_instant = pixels16(&per_instant);
            assert_eq!(per_instant, r.two_pass(&path, light, gain, seed));
            // The path moved to the rounded displacements: placing it
            // instant by instant gives every dot the blurred stamp's
            // phases, so only the order of the float sums differs (a
            // code where a sum falls on a rounding boundary).
            let shifts = r.blur_shifts(&path).unwrap();
            let [xr, yr] = path[n / 2];
            let snapped: Vec<[f64; 2]> = shifts
                .iter()
                .map(|&(su, sv)| {
                    let (du, dv) = (su as f64 / Q as f64, sv as f64 / Q as f64);
                    let s = cfg.pixel_um;
                    [xr - s * (cs * du + sn * dv), yr - s * (-sn * du + cs * dv)]
                })
                .collect();
            let snapped = r
                .render_path_per_instant(&snapped, light, gain, seed, 1.0, 5)
                .unwrap();
            let mut equal = 0;
            for (a, b) in blurred.iter().zip(pixels16(&snapped)) {
                assert!(a.abs_diff(*b) <= 1, "{v:?}: {a} vs {b}, snapped");
                equal += usize::from(a == b);
            }
            assert!(equal * 1000 >= 999 * blurred.len(), "{v:?}: {equal} equal");
            for (a, b) in blurred.iter().zip(per_instant) {
                assert!(a.abs_diff(*b) <= tolerance, "{v:?}: {a} vs {b}");
                max = max.max(a.abs_diff(*b));
                let d = i64::from(*a) - i64::from(*b);
                sum += d;
                sq += d * d;
            }
            len += blurred.len();
            let sharp = r.render_path(&path[n / 2..][..1], light, gain, seed, 1.0, 5);
            assert_ne!(pixels16(&sharp.unwrap()), blurred, "{v:?}: the blur shows");
        }
        let mean = sum as f64 / len as f64;
        println!(
            "v {v:?} µm/s, {n} instants: max |Δ| {max}, mean Δ {mean:+.4}, rms {:.3}",
            (sq as f64 / len as f64).sqrt()
        );
        // The rounding moves a dot either way alike: no bias.
        assert!(mean.abs() < 0.01, "{v:?}: mean difference {mean}");
        all = (
            all.0.max(max),
            all.1 + sum,
            all.2 + sq as usize,
            all.3 + len,
        );
    }
    println!(
        "all: max |Δ| {}, mean Δ {:+.4}, rms {:.3}",
        all.0,
        all.1 as f64 / all.3 as f64,
        (all.2 as f64 / all.3 as f64).sqrt()
    );
}

#[test]
fn a_path_beyond_the_blur_spread_is_placed_instant_by_instant() {
    // 41 instants over 8 µm (20 px: 9.8 px either side of the middle
    // one) fit a blurred stamp; over 14 µm (17.1 px either side, more
    // than MAX_BLUR_SPREAD_PX) they do not, and the frame is the
    // per-instant render, bit for bit.
    let cfg = CameraConfig {
        width: 96,
        height: 171,
        ..CameraConfig::default()
    };
    let mut r = FastRenderer::new(&cfg, 0.3f64.to_radians()).unwrap();
    assert_eq!(MAX_BLUR_SPREAD_PX, 16);
    for (len_um, blurred) in [(8.0, true), (14.0, false)] {
        let path = sweep([2000.0, 1500.0], [len_um / 2e-3, 0.0], 2e-3, 41);
        assert_eq!(r.blur_shifts(&path).is_some(), blurred, "{len_um} µm");
        let f = r.render_path(&path, 0.9, 1.3, 3, 1.0, 5).unwrap();
        let per_instant = r.render_path_per_instant(&path, 0.9, 1.3, 3, 1.0, 5);
        assert_eq!(
            f.pixels() == per_instant.unwrap().pixels(),
            !blurred,
            "{len_um} µm"
        );
        let sharp = r.render_path(&path[20..21], 0.9, 1.3, 3, 1.0, 5).unwrap();
        assert_ne!(f.pixels(), sharp.pixels(), "{len_um} µm: the blur shows");
    }
    // Any spread at all, even and odd counts, beyond the pattern and
    // across the largest accepted coordinates: a frame, no panic.
    for path in [
        vec![[2000.0, 1500.0], [2000.3, 1500.1]],
        vec![[-5e8, 3.0], [0.0, 0.0], [9.9e8, -9.9e8]],
        vec![[1e3, 1e3]; 7],
        sweep([12_384.0, -50.0], [-3e4, 2e4], 2e-3, 63),
    ] {
        let f = r.render_path(&path, 1.0, 1.0, 1, 0.0, 1).unwrap();
        assert_eq!(pixels16(&f).len(), 96 * 171);
    }
    assert!(r
        .render_path(&[[f64::NAN, 0.0]], 1.0, 1.0, 1, 0.0, 1)
        .is_err());
    assert!(r
        .render_path(&[[0.0, 0.0], [f64::INFINITY, 0.0]], 1.0, 1.0, 1, 0.0, 1)
        .is_err());
    assert!(r.render_path(&[], 1.0, 1.0, 1, 0.0, 1).is_err());
}

#[test]
fn blurred_frames_are_deterministic_and_reuse_the_last_table() {
    // The next frame of a sweep (8 µm further at 30 fps) has the same
    // rounded displacements and reuses the table; another velocity
    // rebuilds it; a fresh renderer gives the same bits either way.
    let cfg = CameraConfig {
        width: 96,
        height: 171,
        ..CameraConfig::default()
    };
    let theta = 0.3f64.to_radians();
    let mut r = FastRenderer::new(&cfg, theta).unwrap();
    let a = sweep([2000.0, 1500.0], [240.0, 1.3], 2e-3, 5);
    let b = sweep([2008.0, 1500.04], [240.0, 1.3], 2e-3, 5);
    let c = sweep([2016.0, 1500.0], [-180.0, 90.0], 2e-3, 5);
    assert_eq!(r.blur_shifts(&a), r.blur_shifts(&b));
    assert_ne!(r.blur_shifts(&a), r.blur_shifts(&c));
    let render = |r: &mut FastRenderer, path: &[[f64; 2]], seed| {
        r.render_path(path, 0.9, 1.3, seed, 1.0, 5).unwrap()
    };
    let fa = render(&mut r, &a, 3);
    let table = r.blur.clone();
    let fb = render(&mut r, &b, 4);
    assert_eq!(r.blur, table, "reused");
    let fc = render(&mut r, &c, 5);
    assert_ne!(r.blur, table, "rebuilt");
    let fb2 = render(&mut r, &b, 4);
    assert_eq!(fb.pixels(), fb2.pixels());
    let mut fresh = FastRenderer::new(&cfg, theta).unwrap();
    assert_eq!(render(&mut fresh, &b, 4).pixels(), fb.pixels());
    assert_eq!(render(&mut fresh, &c, 5).pixels(), fc.pixels());
    assert_eq!(render(&mut fresh, &a, 3).pixels(), fa.pixels());
}

#[test]
#[cfg(all(target_arch = "x86_64", target_os = "linux", target_env = "gnu"))]
fn still_frames_are_the_ones_rendered_before_blurred_stamps() {
    // FNV-1a over the pixels of still frames at several poses and
    // angles, and of a blank frame, as rendered by commit d1fbb28 (each
    // dot placed per instant): blurred stamps must leave a one-point
    // path bit for bit as it was. The value holds where the stamps,
    // shading and noise tables come out the same (x86-64 Linux, glibc's
    // libm: where it was computed).
    let mut h = 0xcbf2_9ce4_8422_2325u64;
    let mut eat = |f: &Frame| {
        let Pixels::U16(p) = f.pixels() else {
            panic!("a 10-bit frame")
        };
        for v in p {
            for b in v.to_le_bytes() {
                h = (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3);
            }
        }
    };
    let cfg = CameraConfig {
        width: 320,
        height: 241,
        ..CameraConfig::default()
    };
    for (theta_deg, pose) in [
        (0.3, [2000.0, 1500.0]),
        (0.3, [5321.77, 8765.432]),
        (-7.0, [1234.5, 987.25]),
        (0.0, [12_300.0, 40.0]),
    ] {
        let mut r = FastRenderer::new(&cfg, f64::to_radians(theta_deg)).unwrap();
        eat(&r.render_path(&[pose], 0.9, 1.3, 17, 1.0, 5).unwrap());
        eat(&r.render(pose[0], pose[1], 1.0, 18, 1.0, 6).unwrap());
        eat(&r.garbage(false, 3, 0.0, 1).unwrap());
    }
    println!("still frames: fnv1a64 {h:#018x}");
    assert_eq!(h, 0xad72_2a21_2437_41a7);
}

#[test]
fn a_stamp_integrates_to_the_dot_area() {
    let cfg = CameraConfig {
        width: 64,
        height: 64,
        ..CameraConfig::default()
    };
    let r = FastRenderer::new(&cfg, 0.3f64.to_radians()).unwrap();
    let (side, stride) = (r.side, r.stride);
    let area_px = (cfg.period_um / 2.0 / cfg.pixel_um).powi(2);
    for ph in [0, 5, Q * Q - 1] {
        let s: f32 = r.stamps[ph * side * stride..(ph + 1) * side * stride]
            .iter()
            .sum();
        assert!(
            (f64::from(s) - area_px).abs() < 1e-3 * area_px,
            "{s} vs {area_px}"
        );
    }
}
