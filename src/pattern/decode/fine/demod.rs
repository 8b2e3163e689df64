//! Demodulation: the frame, under a separable Hann window, multiplied by
//! e^{−i k·(u − c)} and summed per tile into the tile phasors the fit reads.

// Index loops mirror the maths.
#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::needless_range_loop)]

use realfft::num_complex::Complex;

use super::super::simd;
use super::{FineStage, TILE};
use crate::frame::{Frame, Pixels};

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
}
