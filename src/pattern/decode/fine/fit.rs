//! Fits of the tile phases: the weighted least-squares plane that refines
//! the wave vector and gives the centre phase, and the cubic model of the
//! non-affine (lens distortion) part.

// `!(x >= t)` is deliberate: it also rejects NaN. Index loops mirror the maths.
#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::needless_range_loop)]

use realfft::num_complex::Complex;

use super::FineStage;

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
    /// Plane fit of the tile phases of direction `d`: returns (δk, phase at
    /// the centre from the tile sum — or from the cubic model when
    /// distortion modelling is on —, coherence, residual rms, |Σ|,
    /// largest non-affine phase, rad).
    pub(super) fn fit(&self, d: usize) -> ([f64; 2], f64, f64, f64, f64, f64) {
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
