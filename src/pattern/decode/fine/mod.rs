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
//!
//! This file holds the stage's buffers and the refinement loop that chains
//! the steps; `peak.rs` is step 1, `demod.rs` the demodulation of step 2 and
//! `fit.rs` its phase fits.

// `!(x >= t)` is deliberate: it also rejects NaN. Index loops mirror the maths.
#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::needless_range_loop)]

mod demod;
mod fit;
mod moments;
mod peak;

pub(crate) use demod::DemodJob;
pub(crate) use demod::HELPER_MIN_PIXELS;
pub(crate) use moments::Moments;

use std::sync::Arc;

use realfft::num_complex::Complex;
use realfft::{RealFftPlanner, RealToComplex};
use rustfft::{Fft, FftPlanner};

use super::error::DecodeError;
use super::helper::Helper;
use super::simd;
use crate::frame::Frame;

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

/// Most alternative lattices kept per peak search.
pub(crate) const MAX_ALTS: usize = 9;

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
    /// i16 (scaled by [`demod::Q16`]): the 8-bit path's integer dot products.
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
    /// Per image row: its phasor of each direction times the row window.
    row_ph: Vec<[Complex<f64>; 2]>,
    /// The moments' column tables ([`FineStage::moments`]): per direction
    /// w·e^{−i kx·x} (re, im) and x times it.
    mtab: [Vec<f32>; 8],
    /// `mtab` quantised to i16 (the x tables divided by W/2), and a zero
    /// table: the 8-bit path's integer dot products.
    mtab16: [Vec<i16>; 9],
    /// Block bounds of the moments' 8-bit row products, and their sums.
    mbounds: Vec<usize>,
    mdots: Vec<[i32; simd::TABLES]>,
    /// The decoder's helper thread, once started
    /// ([`super::Decoder::decode_shared`]).
    pub(crate) helper: Option<Arc<Helper>>,
    /// The helper's demodulation buffers while it has no job.
    demod_job: Option<Box<DemodJob>>,
}

impl std::fmt::Debug for FineStage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FineStage")
            .field("n", &self.n)
            .finish_non_exhaustive()
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
            row_ph: Vec::new(),
            mtab: Default::default(),
            mtab16: Default::default(),
            mbounds: Vec::new(),
            mdots: Vec::new(),
            helper: None,
            demod_job: Some(Box::default()),
        }
    }

    /// Name of the SIMD kernel set in use.
    pub(crate) fn kernels_name(&self) -> &'static str {
        self.kernels.name()
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
