//! Peak search: the cold-start estimate of the two grid wave vectors from
//! the strongest peaks of a Hann-windowed 2-D FFT of a central block, and
//! the alternative lattice readings of the strongest peak.

// `!(x >= t)` is deliberate: it also rejects NaN. Index loops mirror the maths.
#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::needless_range_loop)]

use realfft::num_complex::Complex;

use super::super::error::DecodeError;
use super::{FineStage, MAX_ALTS};
use crate::frame::{Frame, Pixels};

/// Alternative lattice readings of the strongest spectral peak f kept by the
/// peak search, as z with f = z·k_a/3 (k_a as a complex number, k_b = i·k_a):
/// the pattern's spectral peaks are (m·k_a + l·k_b)/3, so f is one of these
/// Gaussian integers over 3 (up to a unit, which only relabels the axes):
/// the fundamental, the 3-period structure's k/3 and 2k/3, the empty-crossing
/// diagonals (k_a ± k_b)/3, (2k_a ± k_b)/3, 2(k_a ± k_b)/3, and the harmonics
/// 2k and k_a + k_b.
const LATTICE_READINGS: [(f64, f64); MAX_ALTS] = [
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

/// Side of the FFT block for the peak search.
const MAX_FFT: usize = 256;

impl FineStage {
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

    /// Cold peak search: approximate wave vectors (rad/px) of the two grid
    /// directions, with k_a × k_b > 0. The steps: the block's power
    /// spectrum ([`FineStage::power_spectrum`]), the strongest peak in the
    /// admissible annulus ([`FineStage::strongest_peak`]), the fundamental
    /// it implies ([`FineStage::fundamental`]), and its perpendicular
    /// partner ([`FineStage::perpendicular_peak`], or the diagonal reading,
    /// [`FineStage::diagonal_reading`]).
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
        self.power_spectrum(frame, n)?;
        let fmin = (n as f64 / max_period_px).max(2.0);
        let fmax = (n as f64 / min_period_px).min(n as f64 / 2.0 - 1.0);
        if fmin >= fmax {
            return Err(DecodeError::NoGrid(format!(
                "no admissible period range: {min_period_px:.2}..{max_period_px:.2} px in a {n} px block"
            )));
        }
        let (best, mean_p) = self.strongest_peak(n, fmin, fmax);
        if best.0 <= 0.0 || f64::from(best.0) < 20.0 * mean_p {
            return Err(DecodeError::NoGrid(format!(
                "no spectral peak stands out (peak/mean power {:.1}, need 20)",
                f64::from(best.0) / mean_p.max(f64::MIN_POSITIVE)
            )));
        }
        let ka0 = self.refine_peak(best.1, best.2, n);
        let fmax_abs = n as f64 / 2.0 - 1.0;
        self.lattice_hypotheses(ka0, fmin, fmax.min(fmax_abs), mean_p, n);
        let ka = self.fundamental(ka0, best.0, fmax, n);
        let best2 = self.perpendicular_peak(ka, n);
        let one_direction = f64::from(best2.0) < 10.0 * mean_p || best2.0 < 0.05 * best.0;
        let [ka, kb] = if !one_direction {
            [ka, self.refine_peak(best2.1, best2.2, n)]
        } else {
            self.diagonal_reading(ka0, fmin, fmax, mean_p, n)?
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

    /// The power spectrum of the frame's central `n` × `n` block into
    /// `self.power` (row-major, `n / 2 + 1` columns): cropped (only the
    /// block's pixels are converted), the mean removed, Hann-windowed, a
    /// 2-D real FFT.
    fn power_spectrum(&mut self, frame: &Frame, n: usize) -> Result<(), DecodeError> {
        let w = frame.width();
        let h = frame.height();
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
        Ok(())
    }

    /// The strongest peak (power, fy, fx) in the annulus `fmin..=fmax`
    /// (cycles per block; squared radii, and per row only the columns the
    /// annulus can reach), and the annulus's mean power.
    fn strongest_peak(&self, n: usize, fmin: f64, fmax: f64) -> ((f32, usize, usize), f64) {
        let nc = n / 2 + 1;
        let mut best = (0.0f32, 0usize, 0usize);
        let mut acc = 0.0f64;
        let mut cnt = 0usize;
        let (r2min, r2max) = (fmin * fmin, fmax * fmax);
        for fy in 0..n {
            let y = signed_freq(fy, n);
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
        (best, acc / cnt.max(1) as f64)
    }

    /// The fundamental k the strongest peak `ka0` (power `pbest`) implies.
    ///
    /// The pattern's 3-period structure (empty crossings, code lines)
    /// puts peaks at k/3 and 2k/3 too; under heavy blur at short periods
    /// one of them can outshine the fundamental k. If the strongest peak f
    /// is k/3, then 3f (= k) and 2f (= 2k/3) are strong peaks; if f is k,
    /// they are its 3rd and 2nd harmonics, which the dot shape, pixel
    /// integration and blur keep below ~9 % and ~5 % of its power (a
    /// 50 %-fill square dot, unblurred, is the worst case). Likewise for
    /// f = 2k/3: 1.5f (= k) and 0.5f (= k/3) are peaks, while 1.5k and
    /// k/2 are not peaks of the pattern at all.
    fn fundamental(&self, ka0: (f64, f64), pbest: f32, fmax: f64, n: usize) -> (f64, f64) {
        let fmax_abs = n as f64 / 2.0 - 1.0;
        let pbest = f64::from(pbest);
        let rel = |m: f64| f64::from(self.local_peak((ka0.0 * m, ka0.1 * m), n).0) / pbest;
        let mut ka = ka0;
        for (m, companion) in [(3.0, 2.0), (1.5, 0.5)] {
            let c = (ka0.0 * m, ka0.1 * m);
            if c.0.hypot(c.1) > fmax_abs.min(fmax * 1.05) {
                continue;
            }
            if rel(m) >= 0.15 && rel(companion) >= 0.05 {
                let (_, fy, fx) = self.local_peak(c, n);
                ka = self.refine_peak(fy, fx, n);
                break;
            }
        }
        ka
    }

    /// The second peak (power, fy, fx): near perpendicular to `ka`
    /// (|cos| ≤ 0.3), of similar modulus (0.8–1.25 ×).
    fn perpendicular_peak(&self, ka: (f64, f64), n: usize) -> (f32, usize, usize) {
        let nc = n / 2 + 1;
        let ra = (ka.0 * ka.0 + ka.1 * ka.1).sqrt();
        let mut best2 = (0.0f32, 0usize, 0usize);
        let (q2min, q2max) = ((0.8 * ra).powi(2), (1.25 * ra).powi(2));
        for fy in 0..n {
            let y = signed_freq(fy, n);
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
        best2
    }

    /// The lattice when the strongest peak `f` has no perpendicular
    /// partner: read as the empty-crossing diagonal (k_a + k_b)/3.
    ///
    /// Under heavy blur the empty-crossing sublattice's diagonal
    /// component (k_a + k_b)/3 (modulus 0.47 |k|, so barely blurred)
    /// can outshine everything else, while its partner (k_a − k_b)/3
    /// is weak: then the strongest peak has no perpendicular partner.
    /// Test that reading: k_a, k_b = 3/2 (f ± f⊥) must both be peaks
    /// standing out of the annulus's mean power, of similar power.
    /// Only reached where the plain reading already failed; a wrong
    /// lattice is still caught by the coherence, orientation and code
    /// checks downstream.
    fn diagonal_reading(
        &self,
        f: (f64, f64),
        fmin: f64,
        fmax: f64,
        mean_p: f64,
        n: usize,
    ) -> Result<[(f64, f64); 2], DecodeError> {
        let fmax_abs = n as f64 / 2.0 - 1.0;
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
        Ok([self.refine_peak(ya, xa, n), self.refine_peak(yb, xb, n)])
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
}

/// The signed frequency (cycles per block) of FFT row `fy` of an `n`-point
/// transform: rows past `n / 2` are the negative frequencies.
fn signed_freq(fy: usize, n: usize) -> f64 {
    if fy > n / 2 {
        fy as f64 - n as f64
    } else {
        fy as f64
    }
}
