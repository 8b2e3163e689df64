//! Demodulation: the frame, under a separable Hann window, multiplied by
//! e^{−i k·(u − c)} and summed per tile into the tile phasors the fit reads.

// Index loops mirror the maths.
#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::needless_range_loop)]

use realfft::num_complex::Complex;

use super::super::helper::{take_back, Work};
use super::super::simd;
use super::{FineStage, TILE};
use crate::frame::{Frame, Pixels};

/// Frames from this many pixels up split their demodulation with the
/// helper thread (below, waking it costs more than it saves).
pub(crate) const HELPER_MIN_PIXELS: usize = 1 << 16;

/// What the rows of one demodulation pass read: the column tables, the
/// tiles, and the row phasors times the row window.
#[derive(Clone, Copy)]
struct RowCtx<'a> {
    tab: [&'a [f32]; 4],
    tab16: [&'a [i16]; 5],
    tab_dc: &'a [f32],
    tile_x: &'a [usize],
    tile_y: &'a [usize],
    wx_tile: &'a [f64],
    wy: &'a [f64],
    ph: &'a [[Complex<f64>; 2]],
    scale16: f64,
    kernels: simd::Kernels,
}

/// Sums the tile phasors, windowed means and window sums of the tile rows
/// `ty0..ty1` into `tiles`, `dc` and `wsum` (indexed from tile row `ty0`),
/// row by row in image order: per tile the same additions in the same
/// order whichever thread runs which band.
#[allow(clippy::too_many_arguments)]
fn demod_rows(
    frame: &Frame,
    c: &RowCtx<'_>,
    ty0: usize,
    ty1: usize,
    row: &mut Vec<f32>,
    dots: &mut Vec<[i32; simd::TABLES]>,
    tiles: [&mut [Complex<f64>]; 2],
    dc_out: &mut [f64],
    wsum: &mut [f64],
) {
    let w = frame.width();
    let ntx = c.tile_x.len() - 1;
    dots.clear();
    dots.resize(ntx, [0; simd::TABLES]);
    let [tiles_a, tiles_b] = tiles;
    for ty in ty0..ty1 {
        for i in c.tile_y[ty]..c.tile_y[ty + 1] {
            // 8-bit frames: exact integer products on the raw row, all
            // tiles in one kernel call; deeper frames: f32 on a converted
            // row.
            let row8 = match frame.pixels() {
                Pixels::U8(p) => {
                    let t = &c.tab16;
                    c.kernels.tile_dots_u8(
                        &p[i * w..(i + 1) * w],
                        [t[0], t[1], t[2], t[3], t[4]],
                        c.tile_x,
                        dots,
                    );
                    true
                }
                Pixels::U16(_) => {
                    row_raw(frame, i, row);
                    false
                }
            };
            let wy = c.wy[i];
            let ph = c.ph[i];
            for tx in 0..ntx {
                let (j0, j1) = (c.tile_x[tx], c.tile_x[tx + 1]);
                let (s, dc) = if row8 {
                    let d = dots[tx].map(|v| f64::from(v) * c.scale16);
                    ([d[0], d[1], d[2], d[3]], d[4])
                } else {
                    let x = &row[j0..j1];
                    let s = dot4(
                        x,
                        &c.tab[0][j0..j1],
                        &c.tab[1][j0..j1],
                        &c.tab[2][j0..j1],
                        &c.tab[3][j0..j1],
                    );
                    let dc = dot(x, &c.tab_dc[j0..j1]);
                    (s.map(f64::from), f64::from(dc))
                };
                let za = Complex::new(s[0], s[1]);
                let zb = Complex::new(s[2], s[3]);
                let t = (ty - ty0) * ntx + tx;
                tiles_a[t] += za * ph[0];
                tiles_b[t] += zb * ph[1];
                dc_out[t] += dc * wy;
                wsum[t] += c.wx_tile[tx] * wy;
            }
        }
    }
}

/// The helper thread's band of a demodulation pass: copies of the pass's
/// tables (refilled in place each pass) and its own sums and scratch.
#[derive(Default)]
pub(crate) struct DemodJob {
    tab: [Vec<f32>; 4],
    tab16: [Vec<i16>; 5],
    tab_dc: Vec<f32>,
    tile_x: Vec<usize>,
    tile_y: Vec<usize>,
    wx_tile: Vec<f64>,
    wy: Vec<f64>,
    ph: Vec<[Complex<f64>; 2]>,
    scale16: f64,
    kernels: Option<simd::Kernels>,
    ty0: usize,
    ty1: usize,
    pub(super) tiles: [Vec<Complex<f64>>; 2],
    pub(super) dc: Vec<f64>,
    pub(super) wsum: Vec<f64>,
    row: Vec<f32>,
    dots: Vec<[i32; simd::TABLES]>,
}

impl Work for DemodJob {
    fn run(&mut self, frame: &Frame) {
        self.sum_band(frame);
    }

    fn into_any(self: Box<Self>) -> Box<dyn std::any::Any + Send> {
        self
    }
}

impl DemodJob {
    /// Copies the pass's tables from `f` (no allocation once the buffers
    /// have grown to the frame's size) for tile rows `ty0..ty1`.
    fn load(&mut self, f: &FineStage, scale16: f64, ty0: usize, ty1: usize) {
        fn fill<T: Copy>(dst: &mut Vec<T>, src: &[T]) {
            dst.clear();
            dst.extend_from_slice(src);
        }
        for (d, s) in self.tab.iter_mut().zip(&f.tab) {
            fill(d, s);
        }
        for (d, s) in self.tab16.iter_mut().zip(&f.tab16) {
            fill(d, s);
        }
        fill(&mut self.tab_dc, &f.tab_dc);
        fill(&mut self.tile_x, &f.tile_x);
        fill(&mut self.tile_y, &f.tile_y);
        fill(&mut self.wx_tile, &f.wx_tile);
        fill(&mut self.wy, &f.wy);
        fill(&mut self.ph, &f.row_ph);
        self.scale16 = scale16;
        self.kernels = Some(f.kernels);
        self.ty0 = ty0;
        self.ty1 = ty1;
        let n = (ty1 - ty0) * (f.tile_x.len() - 1);
        for t in &mut self.tiles {
            t.clear();
            t.resize(n, Complex::new(0.0, 0.0));
        }
        self.dc.clear();
        self.dc.resize(n, 0.0);
        self.wsum.clear();
        self.wsum.resize(n, 0.0);
    }

    /// Sums the band (on the helper thread).
    fn sum_band(&mut self, frame: &Frame) {
        let Some(kernels) = self.kernels else {
            return;
        };
        let c = RowCtx {
            tab: [&self.tab[0], &self.tab[1], &self.tab[2], &self.tab[3]],
            tab16: [
                &self.tab16[0],
                &self.tab16[1],
                &self.tab16[2],
                &self.tab16[3],
                &self.tab16[4],
            ],
            tab_dc: &self.tab_dc,
            tile_x: &self.tile_x,
            tile_y: &self.tile_y,
            wx_tile: &self.wx_tile,
            wy: &self.wy,
            ph: &self.ph,
            scale16: self.scale16,
            kernels,
        };
        let [t0, t1] = &mut self.tiles;
        demod_rows(
            frame,
            &c,
            self.ty0,
            self.ty1,
            &mut self.row,
            &mut self.dots,
            [t0, t1],
            &mut self.dc,
            &mut self.wsum,
        );
    }
}

/// Writes row `i` of `frame` as raw pixel values (no scaling: the
/// demodulation tables carry the 1/full-scale factor).
pub(super) fn row_raw(frame: &Frame, i: usize, out: &mut Vec<f32>) {
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
pub(super) fn dot(x: &[f32], a: &[f32]) -> f32 {
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
pub(super) const Q16: f64 = 32767.0;

impl FineStage {
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
    pub(super) fn demod(&mut self, frame: &Frame, k: &[[f64; 2]; 2]) {
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
        // e^{−i ky·y} of each row by the same recurrence as the columns,
        // times the row's window: one table for both bands of tile rows.
        let y0 = 0.5 - cy;
        let mut rz = [0, 1].map(|d| Complex::from_polar(1.0, -k[d][1] * y0));
        let rstep = [0, 1].map(|d| Complex::from_polar(1.0, -k[d][1]));
        let mut ty = 0;
        self.row_ph.clear();
        for i in 0..h {
            while ty + 1 < nty && i >= self.tile_y[ty + 1] {
                ty += 1;
            }
            let wy = self.wy[i];
            let ph = [rz[0] * wy, rz[1] * wy];
            rz[0] *= rstep[0];
            rz[1] *= rstep[1];
            self.leak_y[0][ty] += ph[0];
            self.leak_y[1][ty] += ph[1];
            self.row_ph.push(ph);
        }
        // The lower half of the tile rows on the helper thread when the
        // decode lent it this frame (see `decode::helper`).
        let split = nty / 2;
        let mut lent = false;
        if let (Some(helper), Some(mut job)) = (&self.helper, self.demod_job.take()) {
            if split > 0 && w * h >= HELPER_MIN_PIXELS {
                job.load(self, scale16, split, nty);
                match helper.submit(frame, job) {
                    Ok(()) => lent = true,
                    Err(j) => self.demod_job = take_back(j),
                }
            } else {
                self.demod_job = Some(job);
            }
        }
        let ctx = RowCtx {
            tab: [&self.tab[0], &self.tab[1], &self.tab[2], &self.tab[3]],
            tab16: [
                &self.tab16[0],
                &self.tab16[1],
                &self.tab16[2],
                &self.tab16[3],
                &self.tab16[4],
            ],
            tab_dc: &self.tab_dc,
            tile_x: &self.tile_x,
            tile_y: &self.tile_y,
            wx_tile: &self.wx_tile,
            wy: &self.wy,
            ph: &self.row_ph,
            scale16,
            kernels: self.kernels,
        };
        let ty1 = if lent { split } else { nty };
        let [t0, t1] = &mut self.tiles;
        demod_rows(
            frame,
            &ctx,
            0,
            ty1,
            &mut self.row,
            &mut self.dots,
            [&mut t0[..ty1 * ntx], &mut t1[..ty1 * ntx]],
            &mut self.tile_dc[..ty1 * ntx],
            &mut self.tile_wsum[..ty1 * ntx],
        );
        if lent {
            let done = self.helper.as_ref().and_then(|h| h.wait());
            let Some(job) = done.and_then(take_back::<DemodJob>) else {
                // The helper failed (a panic): this band on this thread.
                let [t0, t1] = &mut self.tiles;
                demod_rows(
                    frame,
                    &ctx,
                    split,
                    nty,
                    &mut self.row,
                    &mut self.dots,
                    [&mut t0[split * ntx..], &mut t1[split * ntx..]],
                    &mut self.tile_dc[split * ntx..],
                    &mut self.tile_wsum[split * ntx..],
                );
                self.demod_job = Some(Box::default());
                return self.subtract_leakage(ntx, nty);
            };
            let a = split * ntx;
            self.tiles[0][a..].copy_from_slice(&job.tiles[0]);
            self.tiles[1][a..].copy_from_slice(&job.tiles[1]);
            self.tile_dc[a..].copy_from_slice(&job.dc);
            self.tile_wsum[a..].copy_from_slice(&job.wsum);
            self.demod_job = Some(job);
        }
        self.subtract_leakage(ntx, nty);
    }

    /// Subtracts each tile's leakage of its windowed mean (see
    /// [`FineStage::demod`]).
    fn subtract_leakage(&mut self, ntx: usize, nty: usize) {
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
}
