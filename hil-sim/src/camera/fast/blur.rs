//! Motion blur: the frame's table of blurred stamps (each phase's sharp
//! stamps at every instant's displacement, averaged), built once per
//! frame and reused while the path does not change. A file of its own:
//! the one step a moving frame adds to a still one.

use super::stamp::{add8, StampGeom, StampTable};
use super::{FastRenderer, MAX_BLUR_SPREAD_PX, Q};

impl FastRenderer {
    /// The sharp stamps, times `weight`.
    pub(super) fn sharp_table(&self, weight: f32) -> StampTable<'_> {
        let k = self.k as i64;
        StampTable {
            stamps: &self.stamps,
            geom: StampGeom {
                rows: self.side,
                cols: self.side,
                stride: self.stride,
                row_off: -k,
                col_off: -k,
            },
            weight,
        }
    }

    /// The blurred stamps [`FastRenderer::build_blur`] built last.
    pub(super) fn blur_table(&self) -> StampTable<'_> {
        StampTable {
            stamps: &self.blur,
            geom: self.blur_geom,
            weight: 1.0,
        }
    }

    /// Builds this frame's blurred stamps for the instants `path_um` (at
    /// least two), unless the last frame's are the same: for each sub-pixel
    /// phase of a dot's position at the reference instant (the middle one,
    /// the exposure's mid-point), the mean of the sharp stamps of the dot at
    /// every instant, summed in time order. Why one stamp per frame: the
    /// pattern moves rigidly, so every dot moves by the same displacement
    /// from the reference instant, and the blurred image of a dot depends
    /// only on its phase there; placing each dot once costs about one
    /// instant's pass where placing it per instant costs one pass per
    /// instant, and building the table costs Q² = 1024 stamp additions per
    /// instant, fewer than a frame's 4000–4500 dots. An instant's displacement
    /// is rounded to the stamps' 1/Q px (a shift common to all dots; for
    /// motion that is uniform over the exposure the displacements, and so
    /// their rounding, are symmetric about the reference, which keeps the
    /// blur centred on it), and the dot's position at the reference to
    /// 1/Q px as for a still frame. The table is a function of the rounded
    /// displacements alone, and a sweep at constant velocity gives the
    /// same ones frame after frame: then the last table is used again
    /// (same bits as rebuilding it). False, and nothing built, when the
    /// path spreads over more than [`MAX_BLUR_SPREAD_PX`] from the
    /// reference (the caller then places the sharp stamps instant by
    /// instant): that bounds the table, (side + 32)² floats per phase at
    /// most, ≈ 11 MB for the paper's camera.
    pub(super) fn build_blur(&mut self, path_um: &[[f64; 2]]) -> bool {
        let Some(shifts) = self.blur_shifts(path_um) else {
            return false;
        };
        if shifts == self.blur_key {
            return true;
        }
        // Set again only once the table is complete.
        self.blur_key.clear();
        let q = Q as i64;
        let lo_hi = |f: fn(&(i64, i64)) -> i64| {
            let lo = shifts.iter().map(f).min().unwrap_or(0);
            let hi = shifts.iter().map(f).max().unwrap_or(0);
            (lo.div_euclid(q), (hi + q - 1).div_euclid(q))
        };
        let (col_lo, col_hi) = lo_hi(|s| s.0);
        let (row_lo, row_hi) = lo_hi(|s| s.1);
        let cols = self.side + (col_hi - col_lo) as usize;
        let rows = self.side + (row_hi - row_lo) as usize;
        let stride = cols.div_ceil(8) * 8;
        let k = self.k as i64;
        self.blur_geom = StampGeom {
            rows,
            cols,
            stride,
            row_off: row_lo - k,
            col_off: col_lo - k,
        };
        let mut blur = std::mem::take(&mut self.blur);
        // Each stamp is zeroed before it is filled (`BlurFill`).
        blur.resize(Q * Q * rows * stride, 0.0);
        let weight = 1.0 / shifts.len() as f32;
        // Two threads, each filling whole stamps (its own phase rows).
        let (top, bottom) = blur.split_at_mut(Q / 2 * Q * rows * stride);
        let this = &*self;
        let fill = |tables: &mut [f32], b0: usize| {
            this.arch.dispatch(BlurFill {
                r: this,
                shifts: &shifts,
                origin: (col_lo, row_lo),
                rows,
                stride,
                weight,
                tables,
                b0,
            });
        };
        std::thread::scope(|sc| {
            sc.spawn(|| fill(bottom, Q / 2));
            fill(top, 0);
        });
        self.blur = blur;
        self.blur_key = shifts;
        true
    }

    /// Each instant's displacement of the dots' images from the reference
    /// instant (the middle one) in whole 1/Q px, (columns, rows): the
    /// derivative of the dot position of [`FastRenderer::stamp_rows`] with
    /// respect to the pattern point, times the point's move, rounded.
    /// `None` when one is beyond [`MAX_BLUR_SPREAD_PX`] (or not finite).
    pub(super) fn blur_shifts(&self, path_um: &[[f64; 2]]) -> Option<Vec<(i64, i64)>> {
        let [xr, yr] = *path_um.get(path_um.len() / 2)?;
        let s = self.cfg.pixel_um;
        let (sn, cs) = self.view_sin_cos;
        let limit = (MAX_BLUR_SPREAD_PX * Q) as f64;
        let mut shifts = Vec::with_capacity(path_um.len());
        for &[x, y] in path_um {
            let (dx, dy) = (x - xr, y - yr);
            let du = (-cs * dx + sn * dy) / s * Q as f64;
            let dv = (-sn * dx - cs * dy) / s * Q as f64;
            if !(du.abs() <= limit && dv.abs() <= limit) {
                return None;
            }
            shifts.push((du.round() as i64, dv.round() as i64));
        }
        Some(shifts)
    }
}

/// Fills the blurred stamps of the phases with rows `b0..` (whole phase
/// rows of Q stamps) in `tables`, as a `pulp` operation (see [`Half`]):
/// for each phase (a, b) at the reference instant and each instant in
/// time order, the sharp stamp of the phase the instant's shift leads to,
/// times the instant's weight, added at the whole pixels it leads to.
pub(super) struct BlurFill<'a> {
    pub(super) r: &'a FastRenderer,
    /// Each instant's shift from the reference instant, 1/Q px.
    pub(super) shifts: &'a [(i64, i64)],
    /// The blurred stamp's first column and row, whole px from the sharp
    /// stamp's at the reference instant.
    pub(super) origin: (i64, i64),
    /// Rows of a blurred stamp and the length of its rows.
    pub(super) rows: usize,
    pub(super) stride: usize,
    pub(super) weight: f32,
    pub(super) tables: &'a mut [f32],
    pub(super) b0: usize,
}

impl pulp::WithSimd for BlurFill<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _: S) {
        let q = Q as i64;
        let (side, src_stride) = (self.r.side, self.r.stride);
        for (i, table) in self
            .tables
            .chunks_exact_mut(self.rows * self.stride)
            .enumerate()
        {
            // Zeroed here, in cache, rather than the whole table up front.
            table.fill(0.0);
            let (a, b) = ((i % Q) as i64, (self.b0 + i / Q) as i64);
            for &(sx, sy) in self.shifts {
                let (ta, tb) = (a + sx, b + sy);
                let col = (ta.div_euclid(q) - self.origin.0) as usize;
                let row = (tb.div_euclid(q) - self.origin.1) as usize;
                let ph =
                    (tb.rem_euclid(q) as usize * Q + ta.rem_euclid(q) as usize) * side * src_stride;
                let src = &self.r.stamps[ph..ph + side * src_stride];
                for ky in 0..side {
                    let at = (row + ky) * self.stride + col;
                    let d = &mut table[at..at + side];
                    let s = &src[ky * src_stride..ky * src_stride + side];
                    let mut d8 = d.chunks_exact_mut(8);
                    let mut s8 = s.chunks_exact(8);
                    for (d, s) in (&mut d8).zip(&mut s8) {
                        add8(d, s, self.weight);
                    }
                    for (d, s) in d8.into_remainder().iter_mut().zip(s8.remainder()) {
                        *d += s * self.weight;
                    }
                }
            }
        }
    }
}
