//! Sums over the lattice sites that hold a dot, once the code is known:
//! the missing (coded) dots' exact effect on the globally windowed
//! estimates, evaluated from the code instead of measured (O(sites), no
//! pixel pass).
//!
//! Each dot at u_s adds e^{iφ}·B̂·[g(u_s) + i β k̂·∇g(u_s)] to a sum weighted
//! by g (first order in g's variation across the dot; β =
//! [`Grid::blob_slope_px`]). Over a full lattice the ∇g terms cancel; the
//! coded dots are missing asymmetrically about the centre, so they do not.

// `!(x > t)` is deliberate: it also rejects NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use realfft::num_complex::Complex;

use super::fine::{Grid, Moments};

/// One present site: its position (px, image coordinates, not centred) and
/// sin/cos of the window arguments πx/W and πy/H.
struct Site {
    x: f64,
    y: f64,
    sx: f64,
    cx: f64,
    sy: f64,
    cy: f64,
}

/// Calls `f` for every site inside the frame that holds a dot, lattice row
/// by lattice row. `phi` are the dot phases at the centre (π removed for
/// dark dots); `present(m_a, m_b)` says whether site (m_a, m_b) holds a dot.
/// Returns false (and calls nothing) for a degenerate or absurdly large
/// lattice.
fn walk_sites(
    grid: &Grid,
    phi: [f64; 2],
    w: usize,
    h: usize,
    present: impl Fn(i64, i64) -> bool,
    mut f: impl FnMut(&Site),
) -> bool {
    use std::f64::consts::{PI, TAU};
    let k = grid.k;
    let det = k[0][0] * k[1][1] - k[0][1] * k[1][0];
    if !(det.abs() > 1e-12) {
        return false;
    }
    // u − c = K⁻¹ (2π m − φ).
    let inv = [
        [k[1][1] / det, -k[0][1] / det],
        [-k[1][0] / det, k[0][0] / det],
    ];
    let (wf, hf) = (w as f64, h as f64);
    let (cx, cy) = (wf / 2.0, hf / 2.0);
    let mut lo = [f64::MAX; 2];
    let mut hi = [f64::MIN; 2];
    for (x, y) in [(-cx, -cy), (cx, -cy), (-cx, cy), (cx, cy)] {
        for d in 0..2 {
            let m = (k[d][0] * x + k[d][1] * y + phi[d]) / TAU;
            lo[d] = lo[d].min(m);
            hi[d] = hi[d].max(m);
        }
    }
    // A frame spans at most a few thousand periods; bound the loop anyway.
    if !(lo.iter().chain(hi.iter()).all(|v| v.is_finite()))
        || (hi[0] - lo[0]) * (hi[1] - lo[1]) > 4e6
    {
        return false;
    }
    let (ax, ay) = (PI / wf, PI / hf);
    // Along a lattice row x and y step by constants, so sin/cos of the
    // window arguments follow by complex rotation (no per-site trig).
    let (dxa, dya) = (inv[0][0] * TAU, inv[1][0] * TAU);
    let (rx, ry) = (
        Complex::from_polar(1.0, ax * dxa),
        Complex::from_polar(1.0, ay * dya),
    );
    let ma0 = lo[0].floor() as i64;
    for mb in lo[1].floor() as i64..=hi[1].ceil() as i64 {
        let pb = TAU * mb as f64 - phi[1];
        let pa = TAU * ma0 as f64 - phi[0];
        let mut x = inv[0][0] * pa + inv[0][1] * pb + cx;
        let mut y = inv[1][0] * pa + inv[1][1] * pb + cy;
        let mut zx = Complex::from_polar(1.0, ax * x);
        let mut zy = Complex::from_polar(1.0, ay * y);
        for ma in ma0..=hi[0].ceil() as i64 {
            let inside = x > 0.0 && x < wf && y > 0.0 && y < hf;
            let site = Site {
                x,
                y,
                sx: zx.im,
                cx: zx.re,
                sy: zy.im,
                cy: zy.re,
            };
            x += dxa;
            y += dya;
            zx *= rx;
            zy *= ry;
            if inside && present(ma, mb) {
                f(&site);
            }
        }
    }
    true
}

/// Phase error (rad, per lattice direction) that the missing dots cause in
/// the globally windowed demodulation; subtract it from the measured phase.
///
/// With g = w the phase is off by β k̂·Σ_present ∇w / Σ_present w: constant
/// under sub-period motion, ~2e-3 px at some views.
pub(super) fn missing_dot_correction(
    grid: &Grid,
    phi: [f64; 2],
    w: usize,
    h: usize,
    present: impl Fn(i64, i64) -> bool,
) -> [f64; 2] {
    let (ax, ay) = (
        std::f64::consts::PI / w as f64,
        std::f64::consts::PI / h as f64,
    );
    let (mut s0, mut sx, mut sy) = (0.0, 0.0, 0.0);
    let ok = walk_sites(grid, phi, w, h, present, |s| {
        let (wx, wy) = (s.sx * s.sx, s.sy * s.sy);
        s0 += wx * wy;
        // d/dx sin²(πx/W) = (π/W)·2 sin cos.
        sx += 2.0 * ax * s.sx * s.cx * wy;
        sy += 2.0 * ay * s.sy * s.cy * wx;
    });
    if !ok || !(s0 > 0.0) {
        return [0.0; 2];
    }
    let k = grid.k;
    [0, 1].map(|d| {
        let kk = k[d][0].hypot(k[d][1]);
        let c = grid.blob_slope_px[d] * (k[d][0] * sx + k[d][1] * sy) / (kk * s0);
        if c.is_finite() {
            c
        } else {
            0.0
        }
    })
}

/// Window moments over the present sites (coordinates from the image
/// centre, px): Σw, Σxw, Σyw, Σx²w, Σxyw, Σy²w, and of ∇w = (w_x, w_y):
/// Σw_x, Σw_y, Σx·w_x, Σx·w_y, Σy·w_x, Σy·w_y.
#[derive(Default)]
struct SiteSums {
    s0: f64,
    sx: f64,
    sy: f64,
    sxx: f64,
    sxy: f64,
    syy: f64,
    dx: f64,
    dy: f64,
    xdx: f64,
    xdy: f64,
    ydx: f64,
    ydy: f64,
}

/// The wave vectors (rad/px, image frame, as [`Grid::k`]) from the
/// globally windowed moments: the frame's rotation is read from these.
///
/// With k the moments' wave vectors and δ = k_true − k, the ratios
/// R_x = Z_xw/Z_w and R_y = Z_yw/Z_w of the moments are, to first order in
/// δ and in the window's variation across a dot, real plus
/// i·[A_w·B_g − A_g·B_w]/A_w², with A_g = Σ_present g and B_g = β k̂·Σ∇g +
/// δ·Σ g·u. Amplitude variations (missing dots, shading) are real weights:
/// the measured real part of R_g stands for A_g/A_w, and what is left is
/// linear in δ: a 2 × 2 solve per direction. `None` when the sums are degenerate or the
/// correction is not small (the tile fit's k is kept then).
pub(super) fn theta_wave_vectors(
    grid: &Grid,
    m: &Moments,
    phi: [f64; 2],
    w: usize,
    h: usize,
    present: impl Fn(i64, i64) -> bool,
) -> Option<[[f64; 2]; 2]> {
    let (wf, hf) = (w as f64, h as f64);
    let (ax, ay) = (std::f64::consts::PI / wf, std::f64::consts::PI / hf);
    let mut t = SiteSums::default();
    let ok = walk_sites(grid, phi, w, h, present, |s| {
        let (wx, wy) = (s.sx * s.sx, s.sy * s.sy);
        let (x, y) = (s.x - wf / 2.0, s.y - hf / 2.0);
        let g = wx * wy;
        let gx = 2.0 * ax * s.sx * s.cx * wy;
        let gy = 2.0 * ay * s.sy * s.cy * wx;
        t.s0 += g;
        t.sx += x * g;
        t.sy += y * g;
        t.sxx += x * x * g;
        t.sxy += x * y * g;
        t.syy += y * y * g;
        t.dx += gx;
        t.dy += gy;
        t.xdx += x * gx;
        t.xdy += x * gy;
        t.ydx += y * gx;
        t.ydy += y * gy;
    });
    if !ok || !(t.s0 > 0.0) {
        return None;
    }
    let mut out = [[0.0; 2]; 2];
    for d in 0..2 {
        let [z0, zx, zy] = m.z[d];
        if !(z0.norm() > 0.0) {
            return None;
        }
        let (rx, ry) = (zx / z0, zy / z0);
        let kk = m.k[d][0].hypot(m.k[d][1]);
        let (c, s) = (m.k[d][0] / kk, m.k[d][1] / kk);
        let beta = grid.blob_slope_px[d];
        let g0 = c * t.dx + s * t.dy;
        let gx = c * (t.s0 + t.xdx) + s * t.xdy;
        let gy = c * t.ydx + s * (t.s0 + t.ydy);
        // Im R_g·A_w = B_g − Re R_g·B_w: the measured real part stands for
        // A_g/A_w, so shading (which weights the sites unevenly) does not
        // enter through it.
        let a = [
            [t.sxx - rx.re * t.sx, t.sxy - rx.re * t.sy],
            [t.sxy - ry.re * t.sx, t.syy - ry.re * t.sy],
        ];
        let b = [
            rx.im * t.s0 - beta * (gx - rx.re * g0),
            ry.im * t.s0 - beta * (gy - ry.re * g0),
        ];
        let det = a[0][0] * a[1][1] - a[0][1] * a[1][0];
        if !(det.abs() > 0.0) {
            return None;
        }
        let delta = [
            (a[1][1] * b[0] - a[0][1] * b[1]) / det,
            (a[0][0] * b[1] - a[1][0] * b[0]) / det,
        ];
        // After the tile fit the residual is a few µrad of k's direction
        // (a 1e-5 fraction of |k|); anything near 1e-3 of |k| is not that.
        if !(delta[0].hypot(delta[1]) <= 1e-3 * kk) {
            return None;
        }
        out[d] = [m.k[d][0] + delta[0], m.k[d][1] + delta[1]];
    }
    Some(out)
}
