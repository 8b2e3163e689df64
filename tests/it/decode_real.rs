//! The real 12-bit, 9 µm Megarena image (tests/data/megarena-12bit-9um.jpg):
//! agreement with the reference decoder, shifted crops, rotations.

use micropos::frame::{Frame, Pixels};
use micropos::imageio::load_frame;
use micropos::pattern::decode::{DecodeOptions, Decoded, Decoder};

fn real() -> Frame {
    load_frame(std::path::Path::new(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/data/megarena-12bit-9um.jpg"
    )))
    .unwrap()
}

fn bytes(f: &Frame) -> &[u8] {
    match f.pixels() {
        Pixels::U8(p) => p,
        Pixels::U16(_) => panic!("8-bit JPEG expected"),
    }
}

fn crop(f: &Frame, x0: usize, y0: usize, w: usize, h: usize) -> Frame {
    let p = bytes(f);
    let mut out = Vec::with_capacity(w * h);
    for i in y0..y0 + h {
        out.extend_from_slice(&p[i * f.width() + x0..i * f.width() + x0 + w]);
    }
    Frame::new(w, h, 8, Pixels::U8(out), 0.0, 0).unwrap()
}

/// Rotates by 90° clockwise on screen (image x → image y), `times` times.
fn rot90(f: &Frame, times: usize) -> Frame {
    let mut cur = f.clone();
    for _ in 0..times {
        let (w, h) = (cur.width(), cur.height());
        let p = bytes(&cur);
        let mut out = vec![0u8; w * h];
        // New image (width h, height w): new(u', v') = old(v', h - 1 - u').
        for v2 in 0..w {
            for u2 in 0..h {
                out[v2 * h + u2] = p[(h - 1 - u2) * w + v2];
            }
        }
        cur = Frame::new(h, w, 8, Pixels::U8(out), 0.0, 0).unwrap();
    }
    cur
}

fn decode(f: &Frame) -> Decoded {
    decode_with(f, false)
}

fn decode_with(f: &Frame, distortion: bool) -> Decoded {
    let mut o = DecodeOptions::new(9.0, 12);
    o.distortion = distortion;
    Decoder::new(o).unwrap().decode(f).unwrap()
}

#[test]
fn matches_reference_decoder() {
    let d = decode(&real());
    eprintln!(
        "real: x {:.4} y {:.4} θ {:.5} pixel {:.5} quality {:.2} ({:?})",
        d.x_um, d.y_um, d.theta_rad, d.pixel_um, d.quality, d.details
    );
    assert!((d.x_um - 34827.52).abs() < 0.1, "x {}", d.x_um);
    assert!((d.y_um - 26759.97).abs() < 0.1, "y {}", d.y_um);
    assert!((d.theta_rad - 2.99895).abs() < 2e-3, "θ {}", d.theta_rad);
    assert!((d.pixel_um - 0.61185).abs() < 1e-3, "pixel {}", d.pixel_um);
    assert!(!d.details.dark_dots);
}

#[test]
fn shifted_crops_move_by_the_offset() {
    let f = real();
    let (w, h) = (896, 728);
    for distortion in [false, true] {
        let base = decode_with(&crop(&f, 0, 0, w, h), distortion);
        let mut worst = 0.0f64;
        for (ox, oy) in [(128i64, 0i64), (0, 128), (128, 128)] {
            let d = decode_with(&crop(&f, ox as usize, oy as usize, w, h), distortion);
            // Expected pattern displacement of the centre: s·R·(ox, oy).
            let (s, t) = (base.pixel_um, base.theta_rad);
            let ex = s * (t.cos() * ox as f64 + t.sin() * oy as f64);
            let ey = s * (-t.sin() * ox as f64 + t.cos() * oy as f64);
            let rx = (d.x_um - base.x_um - ex) / s;
            let ry = (d.y_um - base.y_um - ey) / s;
            eprintln!(
                "distortion model {distortion}: offset ({ox},{oy}) px: residual ({rx:.3}, {ry:.3}) px, distortion {:.3} px",
                d.grid.distortion_px
            );
            worst = worst.max(rx.abs()).max(ry.abs());
        }
        // Lens distortion leaves a few tenths of a pixel; a period slip would be 14.7 px.
        assert!(worst < 1.0, "worst residual {worst} px");
    }
}

#[test]
fn rotations_decode_to_the_same_point() {
    let f = real();
    let base = decode(&f);
    for k in 1..4 {
        let d = decode(&rot90(&f, k));
        let dt = (d.theta_rad - base.theta_rad + std::f64::consts::PI)
            .rem_euclid(std::f64::consts::TAU)
            - std::f64::consts::PI;
        eprintln!(
            "rot {}°: dx {:.4} dy {:.4} µm, dθ {:.5} rad",
            90 * k,
            d.x_um - base.x_um,
            d.y_um - base.y_um,
            dt
        );
        assert!((d.x_um - base.x_um).abs() < 0.05 && (d.y_um - base.y_um).abs() < 0.05);
        // Rotating the image so that old +x becomes new +y turns θ by +90°.
        let want = (k as f64) * std::f64::consts::FRAC_PI_2;
        let e = (dt - want + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU)
            - std::f64::consts::PI;
        assert!(e.abs() < 1e-3, "rot {k}: dθ {dt}");
    }
}

/// 768×640 crops (about 16 × 13 code lines, 1–4 beyond the code depth):
/// the confidence-weighted code correlation must place every one of them,
/// consistently with the whole image, without a period slip; a crop it
/// cannot place must fail as an error, never as a wrong position.
#[test]
fn small_crops_decode_consistently() {
    let f = real();
    let base = decode(&f);
    let (w, h) = (768usize, 640usize);
    let (s, t) = (base.pixel_um, base.theta_rad);
    let (mut ok, mut worst) = (0, 0.0f64);
    let mut fails = Vec::new();
    for y0 in [0usize, 108, 216] {
        for x0 in [0usize, 128, 256] {
            let c = crop(&f, x0, y0, w, h);
            // Crop centre relative to the whole image's centre, px.
            let du = (x0 + w / 2) as f64 - f.width() as f64 / 2.0;
            let dv = (y0 + h / 2) as f64 - f.height() as f64 / 2.0;
            let ex = s * (t.cos() * du + t.sin() * dv);
            let ey = s * (-t.sin() * du + t.cos() * dv);
            match Decoder::new(DecodeOptions::new(9.0, 12))
                .unwrap()
                .decode(&c)
            {
                Ok(d) => {
                    let rx = (d.x_um - base.x_um - ex) / s;
                    let ry = (d.y_um - base.y_um - ey) / s;
                    eprintln!(
                        "crop 768×640 at ({x0},{y0}): residual ({rx:.3}, {ry:.3}) px, code margins {:?} bits, readable lines {:?}",
                        d.details.code_margin_bits, d.details.code_bits
                    );
                    // A slip would be a whole period, 14.7 px.
                    assert!(rx.abs() < 2.0 && ry.abs() < 2.0, "crop ({x0},{y0}) slipped");
                    worst = worst.max(rx.abs()).max(ry.abs());
                    ok += 1;
                }
                Err(e) => {
                    eprintln!("crop 768×640 at ({x0},{y0}): {e}");
                    fails.push((x0, y0));
                }
            }
        }
    }
    eprintln!("768×640 crops: {ok}/9 decode, worst residual {worst:.3} px");
    assert!(fails.is_empty(), "crops that did not decode: {fails:?}");
}
