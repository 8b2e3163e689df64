//! Placing the dots: the stamp tables (one pixel-integrated, blurred dot
//! image per sub-pixel phase) and the loop that adds the stamps of every
//! visible dot to a band of image rows. A file of its own: the renderer's
//! innermost loop, inlined into each instruction set's band pass, with
//! the exact floor and round it needs.

use super::{FastRenderer, Q};

impl FastRenderer {
    /// Adds the stamps of `table` of the dots seen with `(x_um, y_um)` at
    /// the image centre to the image rows `row0..` that `band` (whole rows
    /// of the accumulator) holds.
    #[inline(always)]
    pub(super) fn stamp_rows(
        &self,
        band: &mut [f32],
        row0: usize,
        x_um: f64,
        y_um: f64,
        table: &StampTable,
    ) {
        let (w, h) = (self.cfg.width as i64, self.cfg.height as i64);
        let band_lo = row0 as i64;
        let band_hi = band_lo + (band.len() / self.cfg.width) as i64;
        let p = self.cfg.period_um;
        let s = self.cfg.pixel_um;
        let (sn, cs) = self.view_sin_cos;
        let (e1, e2) = ((cs, sn), (-sn, cs));
        let (cxi, cyi) = (w as f64 / 2.0, h as f64 / 2.0);
        // Pattern bounding box of the band's rows plus the stamp margin:
        // every dot whose stamp reaches the band, in the frame's dot order.
        let m = table.geom.reach_px() as f64 + 1.0;
        let (v_lo, v_hi) = (band_lo as f64 - m, band_hi as f64 + m);
        let mut cmin = f64::MAX;
        let mut cmax = f64::MIN;
        let mut rmin = f64::MAX;
        let mut rmax = f64::MIN;
        for (u, v) in [
            (-m, v_lo),
            (w as f64 + m, v_lo),
            (-m, v_hi),
            (w as f64 + m, v_hi),
        ] {
            let du = u - cxi;
            let dv = v - cyi;
            let x = x_um + s * (cs * du + sn * dv);
            let y = y_um + s * (-sn * du + cs * dv);
            cmin = cmin.min(x / p);
            cmax = cmax.max(x / p);
            rmin = rmin.min(y / p);
            rmax = rmax.max(y / p);
        }
        let len = self.seq.len() as f64;
        let c0 = (cmin - 1.0).floor().max(0.0) as i64;
        let c1 = (cmax + 1.0).ceil().min(len) as i64;
        let r0 = (rmin - 1.0).floor().max(0.0) as i64;
        let r1 = (rmax + 1.0).ceil().min(len) as i64;
        let StampTable {
            stamps,
            geom:
                StampGeom {
                    rows,
                    cols,
                    stride,
                    row_off,
                    col_off,
                },
            weight,
        } = *table;
        let wu = w as usize;
        for r in r0..r1 {
            if !self.seq.line(r) {
                continue;
            }
            let dy = (r as f64 * p - y_um) / s;
            for c in c0..c1 {
                if !self.seq.dot(c, r) {
                    continue;
                }
                let dx = (c as f64 * p - x_um) / s;
                let uc = cxi + e1.0 * dx + e2.0 * dy;
                let vc = cyi + e1.1 * dx + e2.1 * dy;
                let mut j0 = floor(uc);
                let mut a = round_non_negative((uc - j0) * Q as f64) as usize;
                if a >= Q {
                    a = 0;
                    j0 += 1.0;
                }
                let mut i0 = floor(vc);
                let mut b = round_non_negative((vc - i0) * Q as f64) as usize;
                if b >= Q {
                    b = 0;
                    i0 += 1.0;
                }
                let (j0, i0) = (j0 as i64 + col_off, i0 as i64 + row_off);
                if j0 >= w || i0 >= band_hi || j0 + cols as i64 <= 0 || i0 + rows as i64 <= band_lo
                {
                    continue;
                }
                let ph = (b * Q + a) * rows * stride;
                let stamp = &stamps[ph..ph + rows * stride];
                let kx0 = (-j0).max(0) as usize;
                let kx1 = ((w - j0).min(cols as i64)) as usize;
                let ky0 = (band_lo - i0).max(0);
                let ky1 = (band_hi - i0).min(rows as i64);
                // A stamp whose padded rows fit in the image adds whole
                // vectors: the padding adds +0.0 · weight = +0.0, which
                // leaves every sum as it was (the accumulator starts at
                // +0.0 and is never −0.0), so the bits are those of the
                // unpadded row.
                let whole = j0 >= 0 && j0 + stride as i64 <= w;
                for ky in ky0..ky1 {
                    let row = (i0 + ky - band_lo) as usize * wu;
                    let ky = ky as usize;
                    if whole {
                        let at = row + j0 as usize;
                        let dst = &mut band[at..at + stride];
                        let src = &stamp[ky * stride..(ky + 1) * stride];
                        for (d, s) in dst.chunks_exact_mut(8).zip(src.chunks_exact(8)) {
                            add8(d, s, weight);
                        }
                        continue;
                    }
                    let dst = &mut band
                        [row + (j0 + kx0 as i64) as usize..row + (j0 + kx1 as i64) as usize];
                    let src = &stamp[ky * stride + kx0..ky * stride + kx1];
                    for (d, s) in dst.iter_mut().zip(src) {
                        *d += s * weight;
                    }
                }
            }
        }
    }
}

/// A table of dot stamps, one per sub-pixel phase (Q × Q) of a dot's
/// position, and where a stamp lies relative to the dot's pixel.
#[derive(Debug, Clone, Copy)]
pub(super) struct StampTable<'a> {
    pub(super) stamps: &'a [f32],
    pub(super) geom: StampGeom,
    /// Factor on every stamp value.
    pub(super) weight: f32,
}

/// The shape of the stamps of a [`StampTable`] (the sharp ones, or the
/// blurred ones of `FastRenderer::blur`).
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct StampGeom {
    /// Rows and columns of a stamp, and the length of its rows in the
    /// table (whole vectors of 8, padded with +0.0).
    pub(super) rows: usize,
    pub(super) cols: usize,
    pub(super) stride: usize,
    /// The stamp's first row and column relative to the dot's pixel.
    pub(super) row_off: i64,
    pub(super) col_off: i64,
}

impl StampGeom {
    /// How far from a dot's pixel its stamp's farthest pixel lies, px: `k`
    /// for the sharp stamps, so a still frame visits the dots it always
    /// did.
    pub(super) fn reach_px(&self) -> i64 {
        (-self.row_off)
            .max(-self.col_off)
            .max(self.rows as i64 - 1 + self.row_off)
            .max(self.cols as i64 - 1 + self.col_off)
    }
}

/// `d += s · weight` over eight lanes: both read into registers before
/// the store, so the compiler need not prove that `d` and `s` do not
/// overlap and emits one vector multiply and add (a plain loop over the
/// two slices stayed scalar).
#[inline(always)]
pub(super) fn add8(d: &mut [f32], s: &[f32], weight: f32) {
    let (Ok(dv), Ok(sv)) = (<[f32; 8]>::try_from(&*d), <[f32; 8]>::try_from(s)) else {
        return;
    };
    let mut out = [0f32; 8];
    for ((o, a), b) in out.iter_mut().zip(dv).zip(sv) {
        *o = a + b * weight;
    }
    d.copy_from_slice(&out);
}

/// `x.floor()`, exactly, for |x| < 2⁶³ (a dot's image position). Why not
/// `f64::floor`: the baseline x86-64 target has no rounding instruction,
/// so that is a libm call, two per dot and instant of every frame.
#[inline(always)]
pub(super) fn floor(x: f64) -> f64 {
    let t = x as i64 as f64;
    if t > x {
        t - 1.0
    } else {
        t
    }
}

/// `x.round()` (half away from zero), exactly, for 0 ≤ x < 2⁶³: the
/// fractional part `x − trunc(x)` of a float is exact. Same reason as
/// [`floor`].
#[inline(always)]
pub(super) fn round_non_negative(x: f64) -> f64 {
    let t = x as i64 as f64;
    if x - t >= 0.5 {
        t + 1.0
    } else {
        t
    }
}
