//! Full-frame stage: the two grid wave vectors and their phases at the image
//! centre.
//!
//! 1. Peak search (cold start only): a Hann-windowed 2-D real FFT of a
//!    central block of at most 256 × 256 pixels; the strongest peak in the
//!    admissible frequency annulus is one grid direction, the strongest peak
//!    near its perpendicular with a similar modulus is the other.
//! 2. Demodulation: the frame, weighted by a separable Hann window over the
//!    whole frame, is multiplied by e^{−i k·(u − c)} (separable: a per-column
//!    and a per-row phasor table) and summed per tile, O(N) in pixels. The
//!    tile phasors' phases are fitted by a weighted least-squares plane (after
//!    a wrap-free gradient estimate from neighbour products), which refines k.
//!    A second pass at the refined k gives the final phase at the centre as the
//!    argument of the sum of all tiles — the globally Hann-windowed estimate,
//!    unbiased to first order in any residual k error because the window is
//!    symmetric about the centre.
//!
//! Why this shape: every present dot contributes the same phasor at the exact
//! grid frequency, so the missing (coded) dots cost amplitude but not phase;
//! the smooth window keeps leakage from the code's other spectral content and
//! from dots cut by the frame edge far below 1e-3 px.

// `!(x >= t)` is deliberate: it also rejects NaN. Index loops mirror the maths.
#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::needless_range_loop)]
use std::sync::Arc;

use realfft::num_complex::Complex;
use realfft::{RealFftPlanner, RealToComplex};
use rustfft::{Fft, FftPlanner};

use super::{simd, DecodeError};
use crate::frame::{Frame, Pixels};

/// The grid found by the full-frame stage, in image coordinates relative to
/// the image centre point c = (W/2, H/2).
///
/// Intensity ≈ mean + Σ_d A_d cos(k_d·(u − c) + φ_d) for the two lattice
/// directions d = a, b; k_b is oriented so that k_a × k_b > 0 (k_b is k_a
/// turned by about +90°, image x towards image y). Which direction is the
/// pattern x axis, and the signs, are settled by the per-dot stage.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Grid {
    /// Wave vectors, rad/px, `k[d] = [kx, ky]`.
    pub k: [[f64; 2]; 2],
    /// Phases at the image centre, rad, in (−π, π].
    pub phi: [f64; 2],
    /// Amplitude of each fundamental, fraction of full scale.
    pub amplitude: [f64; 2],
    /// Phase coherence |Σ tiles| / Σ |tile| after the plane fit, worst of the
    /// two directions (1 = a perfect plane wave; below ~0.5 no grid).
    pub coherence: f64,
    /// RMS of the tile phase residuals about the fitted plane, rad, worst of
    /// the two directions (lens distortion and noise show here).
    pub phase_rms_rad: f64,
    /// β_d = d ln B̂/d|k| of one dot's spectrum B̂ at the fundamental of
    /// direction d, px (negative: blur and the dot size make B̂ fall with
    /// |k|). Estimated from the 3rd/1st harmonic ratio of the peak search
    /// (square dots of side p/2 convolved with a Gaussian), kept while
    /// tracking. The missing-dot correction of the centre phase scales with it.
    pub blob_slope_px: [f64; 2],
    /// Largest non-affine phase displacement over the tile centres, px,
    /// worst direction: a cubic polynomial fitted to the tile phases minus its
    /// affine part (lens distortion; 0 when the frame has fewer than 4 × 4
    /// tiles).
    pub distortion_px: f64,
}

/// Alternative lattice readings of the strongest spectral peak f kept by the
/// peak search, as z with f = z·k_a/3 (k_a as a complex number, k_b = i·k_a):
/// the pattern's spectral peaks are (m·k_a + l·k_b)/3, so f is one of these
/// Gaussian integers over 3 (up to a unit, which only relabels the axes):
/// the fundamental, the 3-period structure's k/3 and 2k/3, the empty-crossing
/// diagonals (k_a ± k_b)/3, (2k_a ± k_b)/3, 2(k_a ± k_b)/3, and the harmonics
/// 2k and k_a + k_b.
const LATTICE_READINGS: [(f64, f64); 9] = [
    (3.0, 0.0),
    (1.0, 0.0),
    (2.0, 0.0),
    (1.0, 1.0),
    (2.0, 1.0),
    (2.0, -1.0),
    (2.0, 2.0),
    (6.0, 0.0),
    (3.0, 3.0),
];

/// Most alternative lattices kept per peak search.
pub(crate) const MAX_ALTS: usize = LATTICE_READINGS.len();

/// Side of the FFT block for the peak search.
const MAX_FFT: usize = 256;
/// Nominal demodulation tile side, px.
const TILE: usize = 64;

/// Buffers and plans of the full-frame stage, reused across frames.
pub(crate) struct FineStage {
    n: usize,
    r2c: Option<Arc<dyn RealToComplex<f32>>>,
    c2c: Option<Arc<dyn Fft<f32>>>,
    planner_r: RealFftPlanner<f32>,
    planner_c: FftPlanner<f32>,
    crop: Vec<f32>,
    spec: Vec<Complex<f32>>,
    /// The half spectrum transposed: column `fx` at `fx * n..`.
    cols: Vec<Complex<f32>>,
    scratch: Vec<Complex<f32>>,
    rscratch: Vec<Complex<f32>>,
    power: Vec<f32>,
    /// `power` column-major, as the column FFTs leave it.
    power_t: Vec<f32>,
    hann: Vec<f32>,
    row: Vec<f32>,
    wx: Vec<f32>,
    wy: Vec<f64>,
    tab: [Vec<f32>; 4],
    /// `tab` and `tab_dc` without the 1/full-scale factor, quantised to
    /// i16 (scaled by [`Q16`]): the 8-bit path's integer dot products.
    tab16: [Vec<i16>; 5],
    /// Per tile of the current row: the 8-bit path's five dot products.
    dots: Vec<[i32; simd::TABLES]>,
    /// SIMD kernels of this CPU.
    kernels: simd::Kernels,
    /// `wx / full_scale`: the per-tile windowed intensity sum (local mean).
    tab_dc: Vec<f32>,
    /// Per tile: windowed intensity sum, window sum, and per direction the
    /// window's own transform at k (what a constant intensity leaks into
    /// the tile phasor).
    tile_dc: Vec<f64>,
    tile_wsum: Vec<f64>,
    wx_tile: Vec<f64>,
    /// Per tile and direction: the subtracted leakage (added back for the
    /// globally windowed centre phase, which has no box edges).
    leak: [Vec<Complex<f64>>; 2],
    leak_x: [Vec<Complex<f64>>; 2],
    leak_y: [Vec<Complex<f64>>; 2],
    tiles: [Vec<Complex<f64>>; 2],
    tile_x: Vec<usize>,
    tile_y: Vec<usize>,
    /// Window-weighted centroid of each tile column / row, relative to the
    /// image centre, px: the point whose phase a tile phasor measures.
    cen_x: Vec<f64>,
    cen_y: Vec<f64>,
    win_w: usize,
    win_h: usize,
    /// Last estimate of [`Grid::blob_slope_px`] as s² (effective Gaussian
    /// variance, px²) per direction; NaN until a peak search ran.
    blob_var: [f64; 2],
    /// Alternative lattice hypotheses of the last peak search (wave vectors,
    /// rad/px, and blob variances), strongest fundamental first; see
    /// [`FineStage::alternative`].
    alts: [([[f64; 2]; 2], [f64; 2]); MAX_ALTS],
    n_alts: usize,
    /// Take the centre phase and wave vector from the cubic tile-phase model
    /// (see `DecodeOptions::distortion`).
    pub(crate) model_distortion: bool,
}

impl std::fmt::Debug for FineStage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FineStage")
            .field("n", &self.n)
            .finish_non_exhaustive()
    }
}

/// Writes row `i` of `frame` as raw pixel values (no scaling: the
/// demodulation tables carry the 1/full-scale factor).
fn row_raw(frame: &Frame, i: usize, out: &mut Vec<f32>) {
    let w = frame.width();
    out.clear();
    match frame.pixels() {
        Pixels::U8(p) => out.extend(p[i * w..(i + 1) * w].iter().map(|&v| f32::from(v))),
        Pixels::U16(p) => out.extend(p[i * w..(i + 1) * w].iter().map(|&v| f32::from(v))),
    }
}

/// Dot product in eight independent lanes over `chunks_exact`, the shape
/// the compiler turns into packed multiply-adds without bounds checks.
#[inline]
fn dot(x: &[f32], a: &[f32]) -> f32 {
    const L: usize = 8;
    let n = x.len().min(a.len());
    let (x, a) = (&x[..n], &a[..n]);
    let mut s = [0f32; L];
    for (xs, bs) in x.chunks_exact(L).zip(a.chunks_exact(L)) {
        for l in 0..L {
            s[l] += xs[l] * bs[l];
        }
    }
    let mut out = s.iter().sum::<f32>();
    for t in (n / L) * L..n {
        out += x[t] * a[t];
    }
    out
}

/// Four dot products of `x` with `a0..a3`; `x` is a tile row that stays in
/// L1, so four simple passes cost no more memory traffic than one fused
/// pass and vectorise reliably.
#[inline]
fn dot4(x: &[f32], a0: &[f32], a1: &[f32], a2: &[f32], a3: &[f32]) -> [f32; 4] {
    [dot(x, a0), dot(x, a1), dot(x, a2), dot(x, a3)]
}

/// Full scale of the quantised demodulation tables: the window times a
/// unit phasor is at most 1 in magnitude. Quantisation error ≤ 1.5e-5 per
/// entry, the same for every row, moves a tile phase by ~1e-6 rad.
const Q16: f64 = 32767.0;

fn wrap(a: f64) -> f64 {
    let t = std::f64::consts::TAU;
    let r = a.rem_euclid(t);
    if r > std::f64::consts::PI {
        r - t
    } else {
        r
    }
}

impl FineStage {
    pub(crate) fn new() -> Self {
        Self {
            n: 0,
            r2c: None,
            c2c: None,
            planner_r: RealFftPlanner::new(),
            planner_c: FftPlanner::new(),
            crop: Vec::new(),
            spec: Vec::new(),
            cols: Vec::new(),
            scratch: Vec::new(),
            rscratch: Vec::new(),
            power: Vec::new(),
            power_t: Vec::new(),
            hann: Vec::new(),
            row: Vec::new(),
            wx: Vec::new(),
            wy: Vec::new(),
            tab: [Vec::new(), Vec::new(), Vec::new(), Vec::new()],
            tab16: [Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new()],
            dots: Vec::new(),
            kernels: simd::Kernels::detect(),
            tab_dc: Vec::new(),
            tile_dc: Vec::new(),
            tile_wsum: Vec::new(),
            wx_tile: Vec::new(),
            leak: [Vec::new(), Vec::new()],
            leak_x: [Vec::new(), Vec::new()],
            leak_y: [Vec::new(), Vec::new()],
            tiles: [Vec::new(), Vec::new()],
            tile_x: Vec::new(),
            tile_y: Vec::new(),
            cen_x: Vec::new(),
            cen_y: Vec::new(),
            win_w: 0,
            win_h: 0,
            blob_var: [f64::NAN; 2],
            alts: [([[0.0; 2]; 2], [f64::NAN; 2]); MAX_ALTS],
            n_alts: 0,
            model_distortion: false,
        }
    }

    /// Name of the SIMD kernel set in use.
    pub(crate) fn kernels_name(&self) -> &'static str {
        self.kernels.name()
    }

    fn prepare_fft(&mut self, n: usize) {
        if self.n == n && self.r2c.is_some() {
            return;
        }
        self.n = n;
        let r2c = self.planner_r.plan_fft_forward(n);
        let c2c = self.planner_c.plan_fft_forward(n);
        self.rscratch = r2c.make_scratch_vec();
        self.scratch = vec![Complex::new(0.0, 0.0); c2c.get_inplace_scratch_len()];
        self.crop = vec![0.0; n * n];
        self.spec = vec![Complex::new(0.0, 0.0); n * (n / 2 + 1)];
        self.cols = vec![Complex::new(0.0, 0.0); n * (n / 2 + 1)];
        self.power = vec![0.0; n * (n / 2 + 1)];
        self.power_t = vec![0.0; n * (n / 2 + 1)];
        self.hann = (0..n)
            .map(|i| {
                let s = (std::f64::consts::PI * (i as f64 + 0.5) / n as f64).sin();
                (s * s) as f32
            })
            .collect();
        self.r2c = Some(r2c);
        self.c2c = Some(c2c);
    }

    fn prepare_windows(&mut self, w: usize, h: usize) {
        if self.win_w == w && self.win_h == h {
            return;
        }
        self.win_w = w;
        self.win_h = h;
        let hann = |i: usize, n: usize| {
            let s = (std::f64::consts::PI * (i as f64 + 0.5) / n as f64).sin();
            s * s
        };
        self.wx = (0..w).map(|j| hann(j, w) as f32).collect();
        self.wy = (0..h).map(|i| hann(i, h)).collect();
        let ntx = (w as f64 / TILE as f64).round().max(1.0) as usize;
        let nty = (h as f64 / TILE as f64).round().max(1.0) as usize;
        self.tile_x = (0..=ntx).map(|t| t * w / ntx).collect();
        self.tile_y = (0..=nty).map(|t| t * h / nty).collect();
        let centroid = |a: usize, b: usize, n: usize| {
            let (mut sw, mut sx) = (0.0, 0.0);
            for j in a..b {
                let wt = hann(j, n);
                sw += wt;
                sx += wt * (j as f64 + 0.5 - n as f64 / 2.0);
            }
            if sw > 0.0 {
                sx / sw
            } else {
                0.5 * (a + b) as f64 - n as f64 / 2.0
            }
        };
        self.cen_x = (0..ntx)
            .map(|t| centroid(self.tile_x[t], self.tile_x[t + 1], w))
            .collect();
        self.cen_y = (0..nty)
            .map(|t| centroid(self.tile_y[t], self.tile_y[t + 1], h))
            .collect();
    }

    /// Cold peak search: approximate wave vectors (rad/px) of the two grid
    /// directions, with k_a × k_b > 0.
    pub(crate) fn peak_search(
        &mut self,
        frame: &Frame,
        min_period_px: f64,
        max_period_px: f64,
    ) -> Result<[[f64; 2]; 2], DecodeError> {
        self.n_alts = 0;
        let (w, h) = (frame.width(), frame.height());
        let m = w.min(h).min(MAX_FFT);
        if m < 16 {
            return Err(DecodeError::TooSmall {
                width: w,
                height: h,
            });
        }
        let n = 1usize << (usize::BITS - 1 - m.leading_zeros());
        self.prepare_fft(n);
        let (Some(r2c), Some(c2c)) = (self.r2c.clone(), self.c2c.clone()) else {
            return Err(DecodeError::NoGrid("FFT plan unavailable".into()));
        };
        let x0 = (w - n) / 2;
        let y0 = (h - n) / 2;
        // Crop (only the block's pixels are converted), mean from the exact
        // integer pixel sum, window.
        let scale = 1.0 / frame.full_scale() as f32;
        let mut sum = 0u64;
        for i in 0..n {
            let dst = &mut self.crop[i * n..(i + 1) * n];
            let at = (y0 + i) * w + x0;
            match frame.pixels() {
                Pixels::U8(p) => {
                    let src = &p[at..at + n];
                    sum += src.iter().map(|&v| u64::from(v)).sum::<u64>();
                    for (d, &v) in dst.iter_mut().zip(src) {
                        *d = f32::from(v) * scale;
                    }
                }
                Pixels::U16(p) => {
                    let src = &p[at..at + n];
                    sum += src.iter().map(|&v| u64::from(v)).sum::<u64>();
                    for (d, &v) in dst.iter_mut().zip(src) {
                        *d = f32::from(v) * scale;
                    }
                }
            }
        }
        let mean = (sum as f64 / (n * n) as f64) as f32 * scale;
        for i in 0..n {
            let wy = self.hann[i];
            for (v, &wx) in self.crop[i * n..(i + 1) * n].iter_mut().zip(&self.hann) {
                *v = (*v - mean) * wx * wy;
            }
        }
        let nc = n / 2 + 1;
        for i in 0..n {
            let (input, output) = (
                &mut self.crop[i * n..(i + 1) * n],
                &mut self.spec[i * nc..(i + 1) * nc],
            );
            r2c.process_with_scratch(input, output, &mut self.rscratch)
                .map_err(|e| DecodeError::NoGrid(format!("FFT failed: {e}")))?;
        }
        // Columns: a cache-blocked transpose, one batched column FFT call
        // over all of them, the power transposed back to row-major.
        transpose::transpose(&self.spec, &mut self.cols, nc, n);
        c2c.process_with_scratch(&mut self.cols, &mut self.scratch);
        for (p, v) in self.power_t.iter_mut().zip(&self.cols) {
            *p = v.norm_sqr();
        }
        transpose::transpose(&self.power_t, &mut self.power, n, nc);
        let fmin = (n as f64 / max_period_px).max(2.0);
        let fmax = (n as f64 / min_period_px).min(n as f64 / 2.0 - 1.0);
        if fmin >= fmax {
            return Err(DecodeError::NoGrid(format!(
                "no admissible period range: {min_period_px:.2}..{max_period_px:.2} px in a {n} px block"
            )));
        }
        let freq = |fy: usize, fx: usize| -> (f64, f64) {
            let y = if fy > n / 2 {
                fy as f64 - n as f64
            } else {
                fy as f64
            };
            (fx as f64, y)
        };
        // Strongest peak in the annulus (squared radii, and per row only the
        // columns the annulus can reach).
        let mut best = (0.0f32, 0usize, 0usize);
        let mut acc = 0.0f64;
        let mut cnt = 0usize;
        let (r2min, r2max) = (fmin * fmin, fmax * fmax);
        for fy in 0..n {
            let (_, y) = freq(fy, 0);
            if y.abs() > fmax {
                continue;
            }
            let xmax = ((r2max - y * y).max(0.0).sqrt() as usize).min(nc - 1);
            let row = &self.power[fy * nc..fy * nc + xmax + 1];
            for (fx, &p) in row.iter().enumerate() {
                let x = fx as f64;
                let r2 = x * x + y * y;
                if r2 < r2min || r2 > r2max {
                    continue;
                }
                acc += f64::from(p);
                cnt += 1;
                if p > best.0 {
                    best = (p, fy, fx);
                }
            }
        }
        let mean_p = acc / cnt.max(1) as f64;
        if best.0 <= 0.0 || f64::from(best.0) < 20.0 * mean_p {
            return Err(DecodeError::NoGrid(format!(
                "no spectral peak stands out (peak/mean power {:.1}, need 20)",
                f64::from(best.0) / mean_p.max(f64::MIN_POSITIVE)
            )));
        }
        // The pattern's 3-period structure (empty crossings, code lines)
        // puts peaks at k/3 and 2k/3 too; under heavy blur at short periods
        // one of them can outshine the fundamental k. If the strongest peak f
        // is k/3, then 3f (= k) and 2f (= 2k/3) are strong peaks; if f is k,
        // they are its 3rd and 2nd harmonics, which the dot shape, pixel
        // integration and blur keep below ~9 % and ~5 % of its power (a
        // 50 %-fill square dot, unblurred, is the worst case). Likewise for
        // f = 2k/3: 1.5f (= k) and 0.5f (= k/3) are peaks, while 1.5k and
        // k/2 are not peaks of the pattern at all.
        let ka0 = self.refine_peak(best.1, best.2, n);
        let fmax_abs = n as f64 / 2.0 - 1.0;
        self.lattice_hypotheses(ka0, fmin, fmax.min(fmax_abs), mean_p, n);
        let pbest = f64::from(best.0);
        let rel = |st: &Self, m: f64| f64::from(st.local_peak((ka0.0 * m, ka0.1 * m), n).0) / pbest;
        let mut ka = ka0;
        for (m, companion) in [(3.0, 2.0), (1.5, 0.5)] {
            let c = (ka0.0 * m, ka0.1 * m);
            if c.0.hypot(c.1) > fmax_abs.min(fmax * 1.05) {
                continue;
            }
            if rel(self, m) >= 0.15 && rel(self, companion) >= 0.05 {
                let (_, fy, fx) = self.local_peak(c, n);
                ka = self.refine_peak(fy, fx, n);
                break;
            }
        }
        let ra = (ka.0 * ka.0 + ka.1 * ka.1).sqrt();
        // Second peak: near perpendicular, similar modulus.
        let mut best2 = (0.0f32, 0usize, 0usize);
        let (q2min, q2max) = ((0.8 * ra).powi(2), (1.25 * ra).powi(2));
        for fy in 0..n {
            let (_, y) = freq(fy, 0);
            if y.abs() > 1.25 * ra {
                continue;
            }
            let xmax = ((q2max - y * y).max(0.0).sqrt() as usize).min(nc - 1);
            let row = &self.power[fy * nc..fy * nc + xmax + 1];
            for (fx, &p) in row.iter().enumerate() {
                let x = fx as f64;
                let r2 = x * x + y * y;
                if r2 < q2min || r2 > q2max || !(p > best2.0) {
                    continue;
                }
                // |cos| ≤ 0.3 between the two directions.
                let dotp = x * ka.0 + y * ka.1;
                if dotp * dotp > 0.09 * r2 * ra * ra {
                    continue;
                }
                best2 = (p, fy, fx);
            }
        }
        let one_direction = f64::from(best2.0) < 10.0 * mean_p || best2.0 < 0.05 * best.0;
        let (ka, kb) = if !one_direction {
            (ka, self.refine_peak(best2.1, best2.2, n))
        } else {
            // Under heavy blur the empty-crossing sublattice's diagonal
            // component (k_a + k_b)/3 (modulus 0.47 |k|, so barely blurred)
            // can outshine everything else, while its partner (k_a − k_b)/3
            // is weak: then the strongest peak has no perpendicular partner.
            // Test that reading: k_a, k_b = 3/2 (f ± f⊥) must both be peaks
            // standing out of the annulus's mean power, of similar power.
            // Only reached where the plain reading already failed; a wrong
            // lattice is still caught by the coherence, orientation and code
            // checks downstream.
            let f = ka0;
            let fr = (f.1, -f.0);
            let ca = (1.5 * (f.0 + fr.0), 1.5 * (f.1 + fr.1));
            let cb = (1.5 * (f.0 - fr.0), 1.5 * (f.1 - fr.1));
            let rmax = fmax_abs.min(fmax * 1.05);
            let r = ca.0.hypot(ca.1);
            let (pa, ya, xa) = self.local_peak(ca, n);
            let (pb, yb, xb) = self.local_peak(cb, n);
            let (pa, pb) = (f64::from(pa), f64::from(pb));
            let stands_out = pa.min(pb) >= 10.0 * mean_p && pa.min(pb) >= 0.25 * pa.max(pb);
            if !(r <= rmax && r >= fmin && stands_out) {
                return Err(DecodeError::NoGrid(
                    "only one grid direction found (no peak near the perpendicular)".into(),
                ));
            }
            (self.refine_peak(ya, xa, n), self.refine_peak(yb, xb, n))
        };
        for (d, kd) in [ka, kb].into_iter().enumerate() {
            self.blob_var[d] = self.blob_variance(kd, n);
        }
        let s = std::f64::consts::TAU / n as f64;
        let a = [ka.0 * s, ka.1 * s];
        let mut b = [kb.0 * s, kb.1 * s];
        if a[0] * b[1] - a[1] * b[0] < 0.0 {
            b = [-b[0], -b[1]];
        }
        Ok([a, b])
    }

    /// Fills `alts` with the lattices in which the strongest peak `f`
    /// (cycles per block) is another of the pattern's spectral components
    /// (see [`LATTICE_READINGS`]): for each reading, the fundamental k_a
    /// must fall in the admissible band `fmin..=fmax`, the strongest bins
    /// near k_a and k_b = i·k_a (within 1 + 3/|z| bins) must both stand out of the annulus mean power
    /// (≥ 4×), and their interpolated peaks must still form a square lattice
    /// (moduli within 15 %, |cos| of the angle < 0.15: a reading whose
    /// predicted fundamentals fall on noise or on another component's
    /// sidelobes fails this). They keep the order of [`LATTICE_READINGS`]
    /// (a prior, not a power ranking: under the blur that causes lock-ons the
    /// true fundamental is the most attenuated component). O(readings), no
    /// pixel pass: the peak search runs it every cold frame, the decoder
    /// evaluates the alternatives only when the first reading fails.
    fn lattice_hypotheses(&mut self, f: (f64, f64), fmin: f64, fmax: f64, mean_p: f64, n: usize) {
        let s = std::f64::consts::TAU / n as f64;
        self.n_alts = 0;
        for &(zr, zi) in &LATTICE_READINGS {
            // k_a = 3 f / z (complex division).
            let d = zr * zr + zi * zi;
            let ka = (
                3.0 * (f.0 * zr + f.1 * zi) / d,
                3.0 * (f.1 * zr - f.0 * zi) / d,
            );
            let kb = (-ka.1, ka.0);
            let r = ka.0.hypot(ka.1);
            if !(r >= fmin && r <= fmax) {
                continue;
            }
            // The strongest peak's position is known to about a bin (its
            // neighbours on the 3-period structure's components pull the
            // interpolation); the reading scales that by 3/|z|.
            let rad = 1 + (3.0 / d.sqrt()).round() as i64;
            let (pa, ya, xa) = self.local_peak_r(ka, n, rad);
            let (pb, yb, xb) = self.local_peak_r(kb, n, rad);
            let p = f64::from(pa.min(pb));
            if !(p >= 4.0 * mean_p) {
                continue;
            }
            let (ka, kb) = (self.refine_peak(ya, xa, n), self.refine_peak(yb, xb, n));
            let (ma, mb) = (ka.0.hypot(ka.1), kb.0.hypot(kb.1));
            let cos = (ka.0 * kb.0 + ka.1 * kb.1) / (ma * mb);
            if !(ma <= 1.15 * mb && mb <= 1.15 * ma && cos.abs() < 0.15) {
                continue;
            }
            if self.n_alts == MAX_ALTS {
                break;
            }
            let bv = [self.blob_variance(ka, n), self.blob_variance(kb, n)];
            let a = [ka.0 * s, ka.1 * s];
            let mut b = [kb.0 * s, kb.1 * s];
            if a[0] * b[1] - a[1] * b[0] < 0.0 {
                b = [-b[0], -b[1]];
            }
            self.alts[self.n_alts] = ([a, b], bv);
            self.n_alts += 1;
        }
    }

    /// Number of alternative lattice hypotheses of the last peak search.
    pub(crate) fn alternatives(&self) -> usize {
        self.n_alts
    }

    /// Alternative lattice `i` of the last peak search (wave vectors, rad/px,
    /// k_a × k_b > 0), and makes its blob variance current for the next
    /// [`FineStage::refine`]. `None` past the last one.
    pub(crate) fn alternative(&mut self, i: usize) -> Option<[[f64; 2]; 2]> {
        if i >= self.n_alts {
            return None;
        }
        let (k, bv) = self.alts[i];
        self.blob_var = bv;
        Some(k)
    }

    /// Effective Gaussian variance s² (px²) of one dot's blur from the ratio
    /// r of the 3rd harmonic to the fundamental at peak `f` (cycles per
    /// block): a square dot of side p/2 has |B̂(3k)/B̂(k)| = 1/3 unblurred and
    /// a Gaussian of variance s² multiplies that by exp(−4 s² k²). Summed
    /// 3 × 3 bin powers make the ratio independent of the sub-bin offset.
    /// NaN when the 3rd harmonic lies beyond the usable band.
    fn blob_variance(&self, f: (f64, f64), n: usize) -> f64 {
        let f3 = (3.0 * f.0, 3.0 * f.1);
        if f3.0.hypot(f3.1) > n as f64 / 2.0 - 2.0 {
            return f64::NAN;
        }
        let e1 = self.bin_energy(f, n);
        let e3 = self.bin_energy(f3, n);
        if !(e1 > 0.0) {
            return f64::NAN;
        }
        let r = (e3 / e1).sqrt();
        let k = std::f64::consts::TAU * f.0.hypot(f.1) / n as f64;
        // Pixel aperture alone gives s² ≈ 1/12 px²; ratios at the noise floor
        // are capped at a blur of 4 px.
        (-(3.0 * r).max(1e-12).ln() / (4.0 * k * k)).clamp(1.0 / 12.0, 16.0)
    }

    /// Sum of the powers in the 3 × 3 bins around frequency `f`.
    fn bin_energy(&self, f: (f64, f64), n: usize) -> f64 {
        let nc = n / 2 + 1;
        let (x, y) = if f.0 < 0.0 { (-f.0, -f.1) } else { f };
        let (cx, cy) = (x.round() as i64, y.round() as i64);
        let mut e = 0.0;
        for dy in -1..=1i64 {
            for dx in -1..=1i64 {
                let (mut bx, mut by) = (cx + dx, cy + dy);
                if bx < 0 {
                    bx = -bx;
                    by = -by;
                }
                if bx >= nc as i64 {
                    continue;
                }
                let fy = by.rem_euclid(n as i64) as usize;
                e += f64::from(self.power[fy * nc + bx as usize]);
            }
        }
        e
    }

    /// Largest power in the 3 × 3 bins around frequency `f` (cycles per
    /// block, x ≥ 0 after Hermitian folding), with its bin (fy, fx).
    fn local_peak(&self, f: (f64, f64), n: usize) -> (f32, usize, usize) {
        self.local_peak_r(f, n, 1)
    }

    /// [`FineStage::local_peak`] over the (2r + 1)² bins around `f`.
    fn local_peak_r(&self, f: (f64, f64), n: usize, r: i64) -> (f32, usize, usize) {
        let nc = n / 2 + 1;
        let (x, y) = if f.0 < 0.0 { (-f.0, -f.1) } else { f };
        let (cx, cy) = (x.round() as i64, y.round() as i64);
        let mut best = (0.0f32, 0usize, 0usize);
        for dy in -r..=r {
            for dx in -r..=r {
                let (mut bx, mut by) = (cx + dx, cy + dy);
                if bx < 0 {
                    bx = -bx;
                    by = -by;
                }
                if bx >= nc as i64 {
                    continue;
                }
                let fy = by.rem_euclid(n as i64) as usize;
                let p = self.power[fy * nc + bx as usize];
                if p > best.0 {
                    best = (p, fy, bx as usize);
                }
            }
        }
        best
    }

    /// Sub-bin peak position (cycles per block) by parabolic interpolation of
    /// the log power along each axis.
    fn refine_peak(&self, fy: usize, fx: usize, n: usize) -> (f64, f64) {
        let nc = n / 2 + 1;
        let p = |fy: isize, fx: isize| -> f64 {
            // Hermitian symmetry for fx outside 0..nc.
            let (fy, fx) = if fx < 0 { (-fy, -fx) } else { (fy, fx) };
            let fy = fy.rem_euclid(n as isize) as usize;
            let fx = (fx as usize).min(nc - 1);
            f64::from(self.power[fy * nc + fx]).max(1e-30).ln()
        };
        let (y, x) = (fy as isize, fx as isize);
        let c = p(y, x);
        let off = |m: f64, z: f64, q: f64| {
            let d = m - 2.0 * z + q;
            if d < 0.0 {
                (0.5 * (m - q) / d).clamp(-0.5, 0.5)
            } else {
                0.0
            }
        };
        let dx = off(p(y, x - 1), c, p(y, x + 1));
        let dy = off(p(y - 1, x), c, p(y + 1, x));
        let yy = if fy > n / 2 {
            fy as f64 - n as f64
        } else {
            fy as f64
        };
        (fx as f64 + dx, yy + dy)
    }

    /// One demodulation pass at wave vectors `k`: fills the tile phasors.
    ///
    /// A tile is a box slice of the global window, so a constant intensity
    /// leaks into its phasor through the box's sidelobes: about
    /// 1/(π·cycles per tile) of the local mean, the same order as the
    /// fundamental itself on a bright background with blurred dark dots
    /// (that made the tile phases incoherent under heavy blur). Each tile's
    /// windowed mean is measured alongside (one more dot product per tile
    /// row) and its exact leakage — the mean times the window's own
    /// transform over the tile at k, separable — is subtracted.
    fn demod(&mut self, frame: &Frame, k: &[[f64; 2]; 2]) {
        let (w, h) = (frame.width(), frame.height());
        self.prepare_windows(w, h);
        let cx = w as f64 / 2.0;
        let cy = h as f64 / 2.0;
        for t in &mut self.tab {
            t.clear();
        }
        for t in &mut self.tab16 {
            t.clear();
        }
        self.tab_dc.clear();
        let ntx = self.tile_x.len() - 1;
        let nty = self.tile_y.len() - 1;
        // e^{−i kx·x} by a complex recurrence (no per-column trig); in f64
        // the accumulated rounding over a few thousand steps is ~1e-13 rad.
        let scale = 1.0 / frame.full_scale() as f64;
        for d in 0..2 {
            let x0 = 0.5 - cx;
            let mut z = Complex::from_polar(1.0, -k[d][0] * x0);
            let step = Complex::from_polar(1.0, -k[d][0]);
            let lx = &mut self.leak_x[d];
            lx.clear();
            lx.resize(ntx, Complex::new(0.0, 0.0));
            let mut tx = 0;
            for j in 0..w {
                while tx + 1 < ntx && j >= self.tile_x[tx + 1] {
                    tx += 1;
                }
                let wx = f64::from(self.wx[j]);
                lx[tx] += z * wx;
                self.tab[2 * d].push((wx * scale * z.re) as f32);
                self.tab[2 * d + 1].push((wx * scale * z.im) as f32);
                self.tab16[2 * d].push((wx * z.re * Q16).round() as i16);
                self.tab16[2 * d + 1].push((wx * z.im * Q16).round() as i16);
                z *= step;
            }
        }
        self.tab_dc
            .extend(self.wx.iter().map(|&v| (f64::from(v) * scale) as f32));
        self.tab16[4].extend(self.wx.iter().map(|&v| (f64::from(v) * Q16).round() as i16));
        let scale16 = scale / Q16;
        self.wx_tile.clear();
        for tx in 0..ntx {
            let s: f64 = self.wx[self.tile_x[tx]..self.tile_x[tx + 1]]
                .iter()
                .map(|&v| f64::from(v))
                .sum();
            self.wx_tile.push(s);
        }
        for t in self.tiles.iter_mut().chain(self.leak.iter_mut()) {
            t.clear();
            t.resize(ntx * nty, Complex::new(0.0, 0.0));
        }
        for ly in &mut self.leak_y {
            ly.clear();
            ly.resize(nty, Complex::new(0.0, 0.0));
        }
        self.tile_dc.clear();
        self.tile_dc.resize(ntx * nty, 0.0);
        self.tile_wsum.clear();
        self.tile_wsum.resize(ntx * nty, 0.0);
        // e^{−i ky·y} of each row by the same recurrence as the columns.
        let y0 = 0.5 - cy;
        let mut rz = [0, 1].map(|d| Complex::from_polar(1.0, -k[d][1] * y0));
        let rstep = [0, 1].map(|d| Complex::from_polar(1.0, -k[d][1]));
        let mut ty = 0;
        self.dots.clear();
        self.dots.resize(ntx, [0; simd::TABLES]);
        for i in 0..h {
            while ty + 1 < nty && i >= self.tile_y[ty + 1] {
                ty += 1;
            }
            // 8-bit frames: exact integer products on the raw row, all
            // tiles in one kernel call; deeper frames: f32 on a converted
            // row.
            let row8 = match frame.pixels() {
                Pixels::U8(p) => {
                    let t = &self.tab16;
                    self.kernels.tile_dots_u8(
                        &p[i * w..(i + 1) * w],
                        [&t[0], &t[1], &t[2], &t[3], &t[4]],
                        &self.tile_x,
                        &mut self.dots,
                    );
                    true
                }
                Pixels::U16(_) => {
                    row_raw(frame, i, &mut self.row);
                    false
                }
            };
            let wy = self.wy[i];
            let ph = [rz[0] * wy, rz[1] * wy];
            rz[0] *= rstep[0];
            rz[1] *= rstep[1];
            self.leak_y[0][ty] += ph[0];
            self.leak_y[1][ty] += ph[1];
            for tx in 0..ntx {
                let (j0, j1) = (self.tile_x[tx], self.tile_x[tx + 1]);
                let (s, dc) = if row8 {
                    let d = self.dots[tx].map(|v| f64::from(v) * scale16);
                    ([d[0], d[1], d[2], d[3]], d[4])
                } else {
                    let x = &self.row[j0..j1];
                    let s = dot4(
                        x,
                        &self.tab[0][j0..j1],
                        &self.tab[1][j0..j1],
                        &self.tab[2][j0..j1],
                        &self.tab[3][j0..j1],
                    );
                    let dc = dot(x, &self.tab_dc[j0..j1]);
                    (s.map(f64::from), f64::from(dc))
                };
                let za = Complex::new(s[0], s[1]);
                let zb = Complex::new(s[2], s[3]);
                let t = ty * ntx + tx;
                self.tiles[0][t] += za * ph[0];
                self.tiles[1][t] += zb * ph[1];
                self.tile_dc[t] += dc * wy;
                self.tile_wsum[t] += self.wx_tile[tx] * wy;
            }
        }
        for ty in 0..nty {
            for tx in 0..ntx {
                let t = ty * ntx + tx;
                if !(self.tile_wsum[t] > 0.0) {
                    continue;
                }
                let mean = self.tile_dc[t] / self.tile_wsum[t];
                for d in 0..2 {
                    let g = self.leak_x[d][tx] * self.leak_y[d][ty] * mean;
                    self.leak[d][t] = g;
                    self.tiles[d][t] -= g;
                }
            }
        }
    }

    /// Plane fit of the tile phases of direction `d`: returns (δk, phase at
    /// the centre from the tile sum — or from the cubic model when
    /// distortion modelling is on —, coherence, residual rms, |Σ|,
    /// largest non-affine phase, rad).
    fn fit(&self, d: usize) -> ([f64; 2], f64, f64, f64, f64, f64) {
        let ntx = self.tile_x.len() - 1;
        let nty = self.tile_y.len() - 1;
        let z = &self.tiles[d];
        let centre = |tx: usize, ty: usize| (self.cen_x[tx], self.cen_y[ty]);
        // Wrap-free gradient from neighbour products.
        let mut gx = Complex::new(0.0, 0.0);
        let mut gy = Complex::new(0.0, 0.0);
        for ty in 0..nty {
            for tx in 0..ntx {
                if tx + 1 < ntx {
                    gx += z[ty * ntx + tx + 1] * z[ty * ntx + tx].conj();
                }
                if ty + 1 < nty {
                    gy += z[(ty + 1) * ntx + tx] * z[ty * ntx + tx].conj();
                }
            }
        }
        let dxt = self.win_w as f64 / ntx as f64;
        let dyt = self.win_h as f64 / nty as f64;
        let g = [
            if ntx > 1 { gx.arg() / dxt } else { 0.0 },
            if nty > 1 { gy.arg() / dyt } else { 0.0 },
        ];
        // Reference phase after removing the gradient.
        let mut zs = Complex::new(0.0, 0.0);
        let mut mag = 0.0;
        for ty in 0..nty {
            for tx in 0..ntx {
                let (x, y) = centre(tx, ty);
                let v = z[ty * ntx + tx];
                zs += v * Complex::from_polar(1.0, -(g[0] * x + g[1] * y));
                mag += v.norm();
            }
        }
        let r0 = zs.arg();
        // Weighted LS plane on small residual phases.
        let (mut sw, mut sx, mut sy, mut sxx, mut syy, mut sxy, mut sp, mut sxp, mut syp) =
            (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
        for ty in 0..nty {
            for tx in 0..ntx {
                let (x, y) = centre(tx, ty);
                let v = z[ty * ntx + tx];
                let wt = v.norm_sqr();
                let p = wrap(v.arg() - (g[0] * x + g[1] * y) - r0);
                sw += wt;
                sx += wt * x;
                sy += wt * y;
                sxx += wt * x * x;
                syy += wt * y * y;
                sxy += wt * x * y;
                sp += wt * p;
                sxp += wt * x * p;
                syp += wt * y * p;
            }
        }
        let mut h_ = [0.0, 0.0];
        let mut p0 = 0.0;
        if sw > 0.0 {
            // Solve the 3×3 normal equations (p0, hx, hy), dropping a
            // dimension with a single tile.
            let m = [[sw, sx, sy], [sx, sxx, sxy], [sy, sxy, syy]];
            let rhs = [sp, sxp, syp];
            let use_x = ntx > 1;
            let use_y = nty > 1;
            let sol = solve3(m, rhs, use_x, use_y);
            p0 = sol[0];
            h_ = [sol[1], sol[2]];
        }
        let mut res = 0.0;
        for ty in 0..nty {
            for tx in 0..ntx {
                let (x, y) = centre(tx, ty);
                let v = z[ty * ntx + tx];
                let p = wrap(v.arg() - (g[0] * x + g[1] * y) - r0);
                let e = p - (p0 + h_[0] * x + h_[1] * y);
                res += v.norm_sqr() * e * e;
            }
        }
        let rms = if sw > 0.0 {
            (res / sw).sqrt()
        } else {
            f64::INFINITY
        };
        let coherence = if mag > 0.0 { zs.norm() / mag } else { 0.0 };
        let (cub, distortion_px) = self.cubic_fit(d, g, r0);
        if let (true, Some(c)) = (self.model_distortion, cub) {
            // Phase and local wave vector of the centre point from the cubic
            // model (the polynomial is in units of half the frame width).
            let sc = 2.0 / self.win_w as f64;
            return (
                [g[0] + c[1] * sc, g[1] + c[2] * sc],
                wrap(r0 + c[0]),
                coherence,
                rms,
                zs.norm(),
                distortion_px,
            );
        }
        // Centre phase: the tile phasors brought to the centre with the
        // refined k correction, summed (weights ∝ the symmetric window, so a
        // residual error in the correction cancels to first order). The
        // per-tile leakage correction is undone here: the sum is the
        // globally windowed estimate, which has no box edges to leak
        // through, while the tile means carry the dots cut by the tile edges
        // and would add a sub-period-periodic error (~1e-3 px).
        let dk = [g[0] + h_[0], g[1] + h_[1]];
        let mut zc = Complex::new(0.0, 0.0);
        let leak = &self.leak[d];
        for ty in 0..nty {
            for tx in 0..ntx {
                let (x, y) = centre(tx, ty);
                let t = ty * ntx + tx;
                let raw = z[t] + leak.get(t).copied().unwrap_or_default();
                zc += raw * Complex::from_polar(1.0, -(dk[0] * x + dk[1] * y));
            }
        }
        (dk, zc.arg(), coherence, rms, zc.norm(), distortion_px)
    }

    /// Weighted LS fit of a cubic polynomial (10 terms, coordinates in units
    /// of half the frame width) to the tile phases of direction `d` after
    /// removing the gradient `g` and reference `r0`. Returns the coefficients
    /// (constant, x, y, x², xy, y², x³, x²y, xy², y³) and the largest
    /// non-affine phase over the tiles in rad; `None` with fewer than
    /// 4 × 4 tiles.
    fn cubic_fit(&self, d: usize, g: [f64; 2], r0: f64) -> (Option<[f64; 10]>, f64) {
        let ntx = self.tile_x.len() - 1;
        let nty = self.tile_y.len() - 1;
        if ntx < 4 || nty < 4 {
            return (None, 0.0);
        }
        let z = &self.tiles[d];
        let sc = 2.0 / self.win_w as f64;
        let basis = |x: f64, y: f64| {
            [
                1.0,
                x,
                y,
                x * x,
                x * y,
                y * y,
                x * x * x,
                x * x * y,
                x * y * y,
                y * y * y,
            ]
        };
        let mut a = [[0.0f64; 11]; 10];
        for ty in 0..nty {
            for tx in 0..ntx {
                let (x, y) = (self.cen_x[tx], self.cen_y[ty]);
                let v = z[ty * ntx + tx];
                let wt = v.norm_sqr();
                let p = wrap(v.arg() - (g[0] * x + g[1] * y) - r0);
                let b = basis(x * sc, y * sc);
                for i in 0..10 {
                    for j in 0..10 {
                        a[i][j] += wt * b[i] * b[j];
                    }
                    a[i][10] += wt * b[i] * p;
                }
            }
        }
        // Gaussian elimination with partial pivoting.
        for c in 0..10 {
            let mut piv = c;
            for r in c + 1..10 {
                if a[r][c].abs() > a[piv][c].abs() {
                    piv = r;
                }
            }
            a.swap(c, piv);
            if !(a[c][c].abs() > 1e-300) {
                return (None, 0.0);
            }
            for r in 0..10 {
                if r != c {
                    let f = a[r][c] / a[c][c];
                    for cc in c..11 {
                        a[r][cc] -= f * a[c][cc];
                    }
                }
            }
        }
        let mut coef = [0.0; 10];
        for i in 0..10 {
            coef[i] = a[i][10] / a[i][i];
        }
        let mut worst = 0.0f64;
        for ty in 0..nty {
            for tx in 0..ntx {
                let b = basis(self.cen_x[tx] * sc, self.cen_y[ty] * sc);
                let q: f64 = (3..10).map(|i| coef[i] * b[i]).sum();
                worst = worst.max(q.abs());
            }
        }
        if !coef.iter().all(|c| c.is_finite()) {
            return (None, 0.0);
        }
        (Some(coef), worst)
    }

    /// Demodulates at `k0`, refines k, and (if the refinement was not
    /// negligible, or `passes` asks for it) demodulates again.
    pub(crate) fn refine(
        &mut self,
        frame: &Frame,
        k0: [[f64; 2]; 2],
        max_passes: usize,
    ) -> Result<Grid, DecodeError> {
        let mut k = k0;
        let mut out = None;
        for _ in 0..max_passes.max(1) {
            self.demod(frame, &k);
            let fa = self.fit(0);
            let fb = self.fit(1);
            let wsum: f64 =
                self.wx.iter().map(|&v| f64::from(v)).sum::<f64>() * self.wy.iter().sum::<f64>();
            let amp = [2.0 * fa.4 / wsum.max(1e-30), 2.0 * fb.4 / wsum.max(1e-30)];
            let grid = Grid {
                k: [
                    [k[0][0] + fa.0[0], k[0][1] + fa.0[1]],
                    [k[1][0] + fb.0[0], k[1][1] + fb.0[1]],
                ],
                phi: [fa.1, fb.1],
                amplitude: amp,
                coherence: fa.2.min(fb.2),
                phase_rms_rad: fa.3.max(fb.3),
                distortion_px: (fa.5 / k[0][0].hypot(k[0][1])).max(fb.5 / k[1][0].hypot(k[1][1])),
                blob_slope_px: [0, 1].map(|d| {
                    let kk = k[d][0].hypot(k[d][1]);
                    // Without an estimate assume σ ≈ 0.8 px blur plus the
                    // pixel aperture.
                    let var = if self.blob_var[d].is_finite() {
                        self.blob_var[d]
                    } else {
                        0.72
                    };
                    -1.0 / kk - var * kk
                }),
            };
            let step = (fa.0[0].hypot(fa.0[1])).max(fb.0[0].hypot(fb.0[1])) * TILE as f64;
            out = Some(grid);
            k = grid.k;
            // The tile phasors are referenced to their centroids, so one pass
            // suffices unless the starting k was so far off that the phase
            // ran by more than ~0.3 rad across a tile (amplitude loss, and the
            // centroid approximation's second-order terms).
            if step < 0.3 {
                break;
            }
        }
        let g = out.ok_or_else(|| DecodeError::NoGrid("no demodulation pass".into()))?;
        if !(g
            .k
            .iter()
            .flatten()
            .chain(g.phi.iter())
            .all(|v| v.is_finite()))
        {
            return Err(DecodeError::NoGrid("non-finite grid estimate".into()));
        }
        Ok(g)
    }
}

/// Solves the symmetric 3×3 system for (p0, hx, hy), fixing hx or hy to 0
/// when that dimension has a single tile.
fn solve3(m: [[f64; 3]; 3], r: [f64; 3], use_x: bool, use_y: bool) -> [f64; 3] {
    // Fixed-size index list: this runs per frame and must not allocate.
    let mut idx = [0usize; 3];
    let mut k = 1;
    for (on, i) in [(use_x, 1), (use_y, 2)] {
        if on {
            idx[k] = i;
            k += 1;
        }
    }
    let idx = &idx[..k];
    let mut a = [[0.0; 4]; 3];
    for (ii, &i) in idx.iter().enumerate() {
        for (jj, &j) in idx.iter().enumerate() {
            a[ii][jj] = m[i][j];
        }
        a[ii][3] = r[i];
    }
    // Gaussian elimination with partial pivoting.
    for c in 0..k {
        let piv = (c..k)
            .max_by(|&x, &y| a[x][c].abs().total_cmp(&a[y][c].abs()))
            .unwrap_or(c);
        a.swap(c, piv);
        if a[c][c].abs() < 1e-300 {
            return [0.0; 3];
        }
        for rr in 0..k {
            if rr != c {
                let f = a[rr][c] / a[c][c];
                for cc in c..4 {
                    a[rr][cc] -= f * a[c][cc];
                }
            }
        }
    }
    let mut out = [0.0; 3];
    for (ii, &i) in idx.iter().enumerate() {
        out[i] = a[ii][3] / a[ii][ii];
    }
    out
}
