//! The globally windowed phasor sums and their first moments in x and y, at
//! the wave vectors of the last demodulation pass: what the wave-vector
//! (and so θ) estimate of [`super::super::theta`] reads.
//!
//! Why a pass of its own: the tile phasors that refine k are box slices of
//! the window, and every box edge cuts dots. Which dots it cuts depends on
//! the code, so each tile phase carries a code-dependent error that the
//! plane fit turns into a wave-vector error of a few µrad. The moments use
//! the smooth weights w, x·w and y·w (all zero with zero slope at the frame
//! edge), so nothing is cut; the missing dots' effect on them is computed
//! exactly from the code, like the centre phase's.

use realfft::num_complex::Complex;

use super::super::simd;
use super::demod::{dot, row_raw, Q16};
use super::FineStage;
use crate::frame::{Frame, Pixels};

/// Longest block of an 8-bit row per integer dot product: 255 · 32767 ·
/// 256 < 2³¹.
const MAX_BLOCK: usize = 256;

/// Per lattice direction: Σ g·I·e^{−i k·(u − c)} / full scale for the
/// weights g = w, (x − cx)·w and (y − cy)·w (w the separable Hann window,
/// coordinates in px from the image centre), at the wave vectors `k`
/// (rad/px) of the demodulation pass they were summed at.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Moments {
    pub(crate) k: [[f64; 2]; 2],
    pub(crate) z: [[Complex<f64>; 3]; 2],
}

impl FineStage {
    /// The moments of `frame` at wave vectors `k` (rad/px; the grid the
    /// tile fit found, so that what is left to estimate is small); `None`
    /// for a frame whose windows were not prepared (no demodulation pass of
    /// its size ran) or non-finite sums.
    pub(crate) fn moments(&mut self, frame: &Frame, k: [[f64; 2]; 2]) -> Option<Moments> {
        let (w, h) = (frame.width(), frame.height());
        if self.wx.len() != w || self.wy.len() != h {
            return None;
        }
        let cx = w as f64 / 2.0;
        let cy = h as f64 / 2.0;
        let scale = 1.0 / frame.full_scale() as f64;
        // Per direction: w·e^{−i kx·x} (re, im) and x times it, by the same
        // complex recurrence as the demodulation's tables.
        for d in 0..2 {
            let mut z = Complex::from_polar(1.0, -k[d][0] * (0.5 - cx));
            let step = Complex::from_polar(1.0, -k[d][0]);
            let [re, im, xre, xim] = &mut self.mtab[4 * d..4 * d + 4] else {
                return None;
            };
            let [qre, qim, qxre, qxim] = &mut self.mtab16[4 * d..4 * d + 4] else {
                return None;
            };
            for t in [&mut *re, &mut *im, &mut *xre, &mut *xim] {
                t.clear();
            }
            for t in [&mut *qre, &mut *qim, &mut *qxre, &mut *qxim] {
                t.clear();
            }
            for (j, &wx) in self.wx.iter().enumerate() {
                let v = z * f64::from(wx);
                let x = j as f64 + 0.5 - cx;
                re.push((v.re * scale) as f32);
                im.push((v.im * scale) as f32);
                xre.push((x * v.re * scale) as f32);
                xim.push((x * v.im * scale) as f32);
                // |x| ≤ W/2: the x tables are stored divided by it.
                qre.push((v.re * Q16).round() as i16);
                qim.push((v.im * Q16).round() as i16);
                qxre.push((x / cx * v.re * Q16).round() as i16);
                qxim.push((x / cx * v.im * Q16).round() as i16);
                z *= step;
            }
        }
        self.mtab16[8].clear();
        self.mtab16[8].resize(w, 0);
        // 8-bit rows go through the integer kernel in blocks short enough
        // that its i32 sums cannot overflow.
        self.mbounds.clear();
        self.mbounds.extend((0..w).step_by(MAX_BLOCK));
        self.mbounds.push(w);
        let q = scale / Q16;
        let mut rz = [0, 1].map(|d| Complex::from_polar(1.0, -k[d][1] * (0.5 - cy)));
        let rstep = [0, 1].map(|d| Complex::from_polar(1.0, -k[d][1]));
        let zero = Complex::new(0.0, 0.0);
        let mut z = [[zero; 3]; 2];
        for i in 0..h {
            let y = i as f64 + 0.5 - cy;
            // Per direction: Σ w·e^{−i kx·x}·I and Σ x·w·e^{−i kx·x}·I of row i.
            let sums = match frame.pixels() {
                Pixels::U8(p) => self.row_sums_u8(&p[i * w..(i + 1) * w], q, cx),
                Pixels::U16(_) => {
                    row_raw(frame, i, &mut self.row);
                    let row = &self.row;
                    let dotc = |a: &[f32], b: &[f32]| {
                        Complex::new(f64::from(dot(row, a)), f64::from(dot(row, b)))
                    };
                    let t = &self.mtab;
                    [0, 1].map(|d| {
                        [
                            dotc(&t[4 * d], &t[4 * d + 1]),
                            dotc(&t[4 * d + 2], &t[4 * d + 3]),
                        ]
                    })
                }
            };
            for d in 0..2 {
                let ph = rz[d] * self.wy[i];
                rz[d] *= rstep[d];
                let a = sums[d][0] * ph;
                z[d][0] += a;
                z[d][1] += sums[d][1] * ph;
                z[d][2] += a * y;
            }
        }
        z.iter()
            .flatten()
            .all(|v| v.re.is_finite() && v.im.is_finite())
            .then_some(Moments { k, z })
    }

    /// One 8-bit row's sums (see [`FineStage::moments`]): two calls of the
    /// integer kernel (eight tables and two zero ones), exact per block.
    fn row_sums_u8(&mut self, px: &[u8], q: f64, half_w: f64) -> [[Complex<f64>; 2]; 2] {
        let t = &self.mtab16;
        let zero = &t[8];
        let n = self.mbounds.len().saturating_sub(1);
        self.mdots.clear();
        self.mdots.resize(2 * n, [0; simd::TABLES]);
        let (first, second) = self.mdots.split_at_mut(n);
        self.kernels.tile_dots_u8(
            px,
            [&t[0], &t[1], &t[4], &t[5], &t[2]],
            &self.mbounds,
            first,
        );
        self.kernels
            .tile_dots_u8(px, [&t[3], &t[6], &t[7], zero, zero], &self.mbounds, second);
        let mut s = [0i64; 8];
        for (a, b) in first.iter().zip(second.iter()) {
            for (k, v) in [a[0], a[1], a[4], b[0], a[2], a[3], b[1], b[2]]
                .into_iter()
                .enumerate()
            {
                s[k] += i64::from(v);
            }
        }
        let f = |v: i64| v as f64 * q;
        let fx = |v: i64| v as f64 * q * half_w;
        [
            [
                Complex::new(f(s[0]), f(s[1])),
                Complex::new(fx(s[2]), fx(s[3])),
            ],
            [
                Complex::new(f(s[4]), f(s[5])),
                Complex::new(fx(s[6]), fx(s[7])),
            ],
        ]
    }
}
