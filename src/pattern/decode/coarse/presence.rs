//! Presence of the dot sites, and the orientation evidence drawn from it:
//! each site's contrast against its background neighbours, normalised by
//! its neighbourhood's best ([`CoarseStage::presence`]), the per-site
//! likelihood ratios calibrated on the sites the layout fixes
//! ([`CoarseStage::fill_llr`]), and the 3 × 3 class table matched against
//! the template ([`template_corr`]). A file of its own: the per-site
//! arithmetic both the search and the tracking check run on the sampled
//! lattices.

use super::CoarseStage;

/// Expected mean presence by line class (0 = crossing line, 1 = code line,
/// 2 = plain full line) of the column and row lines.
const TEMPLATE: [[f64; 3]; 3] = [[0.0, 0.5, 1.0], [0.5, 0.25, 0.5], [1.0, 0.5, 1.0]];

/// Largest evidence one dot contributes to its code line, nats.
const DOT_LLR_CAP_NATS: f32 = 2.0;

impl CoarseStage {
    /// Presence of every site for a polarity hypothesis, into `self.pres`
    /// ([nb][na] of the site lattice, NaN = unreadable). Returns the site
    /// lattice's first indices and size.
    pub(super) fn presence(
        &mut self,
        dark: bool,
        na: usize,
        nb: usize,
        a0: i64,
        b0: i64,
    ) -> (i64, i64, usize, usize) {
        // Bright dots: sites on g0 (integer lattice), background on g1.
        // Dark dots: sites on g1 (half lattice), background on g0; the half
        // lattice point (a0 + i − ½) has g0 neighbours i−1 and i.
        let (sa0, sb0, sna, snb) = if dark {
            (a0, b0, na.saturating_sub(1), nb.saturating_sub(1))
        } else {
            (a0, b0, na, nb)
        };
        self.pres.clear();
        self.tmp.clear();
        // Whole rows as slices (one bounds check per row, not per site).
        for j in 0..snb {
            let (site, bg0, bg1) = if dark {
                // site g1[j+1][i+1] is at (a0+i+½, b0+j+½); neighbours g0[j..=j+1][i..=i+1].
                (
                    &self.g1[(j + 1) * (na + 1) + 1..][..sna],
                    &self.g0[j * na..][..sna + 1],
                    &self.g0[(j + 1) * na..][..sna + 1],
                )
            } else {
                (
                    &self.g0[j * na..][..sna],
                    &self.g1[j * (na + 1)..][..sna + 1],
                    &self.g1[(j + 1) * (na + 1)..][..sna + 1],
                )
            };
            for (i, &s) in site.iter().enumerate() {
                let bm = 0.25 * (bg0[i] + bg0[i + 1] + bg1[i] + bg1[i + 1]);
                self.pres.push(if dark { bm - s } else { s - bm });
            }
        }
        // Site (i, j) of the dark lattice sits at lattice coordinate a0+i+½,
        // which is a0+i in the lattice whose phases are shifted by π (dots at
        // phase π): the caller uses φ − π for dark dots, so lines are indexed
        // by the integer a0+i for both polarities.
        // Local contrast: 5×5 max of r (NaN-aware: f32::max ignores NaN, and
        // a window with no readable site stays −∞), separable, as
        // element-wise maxima of shifted rows (vectorisable).
        let n = sna * snb;
        self.lmax.clear();
        self.lmax.resize(n, f32::NEG_INFINITY);
        self.tmp.clear();
        self.tmp.resize(n, f32::NEG_INFINITY);
        if sna > 0 {
            for (row, out) in self
                .pres
                .chunks_exact(sna)
                .zip(self.tmp.chunks_exact_mut(sna))
            {
                for d in 0..5usize {
                    // out[i] = max over row[i + d − 2].
                    let (o0, r0) = if d < 2 { (2 - d, 0) } else { (0, d - 2) };
                    if o0.max(r0) >= sna {
                        continue;
                    }
                    let len = sna - o0.max(r0);
                    for (m, &v) in out[o0..o0 + len].iter_mut().zip(&row[r0..r0 + len]) {
                        *m = m.max(v);
                    }
                }
            }
            for j in 0..snb {
                let out = &mut self.lmax[j * sna..(j + 1) * sna];
                for jj in j.saturating_sub(2)..(j + 3).min(snb) {
                    for (m, &v) in out.iter_mut().zip(&self.tmp[jj * sna..(jj + 1) * sna]) {
                        *m = m.max(v);
                    }
                }
            }
        }
        // Global contrast: 90th percentile of the local maxima.
        self.sel.clear();
        self.sel.extend(
            self.lmax
                .iter()
                .copied()
                .filter(|v| v.is_finite() && *v > 0.0),
        );
        let cglob = if self.sel.is_empty() {
            0.0
        } else {
            let k = (self.sel.len() * 9) / 10;
            let k = k.min(self.sel.len() - 1);
            let (_, v, _) = self.sel.select_nth_unstable_by(k, |a, b| a.total_cmp(b));
            *v
        };
        for (p, &m) in self.pres.iter_mut().zip(&self.lmax) {
            if !(p.is_finite() && m.is_finite() && cglob > 0.0 && m > 0.35 * cglob) {
                *p = f32::NAN;
            } else {
                *p /= m;
            }
        }
        (sa0, sb0, sna, snb)
    }

    /// Per-site log-likelihood ratio "dot present" vs "dot absent" into
    /// `self.llr` (0 for unread sites), given the line classes of the chosen
    /// orientation (`ca`, `cb`: lattice line → 0 crossing, 1 code, 2 plain).
    ///
    /// The sites whose state the layout fixes calibrate the model: sites on
    /// two non-code lines are present unless both are crossing lines, where
    /// they are absent. Presence is modelled as Gaussian about the median of
    /// each group with the pooled robust spread (MAD); the ratio is linear in
    /// the presence value and capped at ±[`DOT_LLR_CAP_NATS`] so that no
    /// single dot (dust edge, defect) can carry a code line alone.
    pub(super) fn fill_llr(
        &mut self,
        sna: usize,
        snb: usize,
        sa0: i64,
        sb0: i64,
        ca: impl Fn(i64) -> i64,
        cb: impl Fn(i64) -> i64,
    ) {
        self.sel.clear();
        self.tmp.clear();
        for j in 0..snb {
            let cj = cb(sb0 + j as i64);
            if cj == 1 {
                continue;
            }
            for i in 0..sna {
                let ci = ca(sa0 + i as i64);
                let v = self.pres[j * sna + i];
                if ci == 1 || !v.is_finite() {
                    continue;
                }
                if ci == 0 && cj == 0 {
                    self.tmp.push(v);
                } else {
                    self.sel.push(v);
                }
            }
        }
        self.llr.clear();
        let stats = median_mad(&mut self.sel).zip(median_mad(&mut self.tmp));
        let Some(((m1, s1), (m0, s0))) = stats else {
            self.llr.resize(sna * snb, 0.0);
            return;
        };
        let gap = m1 - m0;
        // Floor the spread: a frame rendered without noise has MAD ≈ 0.
        let sd = (1.4826 * 0.5 * (s1 + s0)).max(0.05);
        let slope = if gap > 0.0 { gap / (sd * sd) } else { 0.0 };
        let mid = 0.5 * (m0 + m1);
        self.llr.extend(self.pres.iter().map(|&v| {
            if v.is_finite() {
                (slope * (v - mid)).clamp(-DOT_LLR_CAP_NATS, DOT_LLR_CAP_NATS)
            } else {
                0.0
            }
        }));
    }

    /// Mean presence by (a mod 3, b mod 3), rows = a residue.
    pub(super) fn class_table(&self, sna: usize, snb: usize, sa0: i64, sb0: i64) -> [[f64; 3]; 3] {
        let mut s = [[0.0f64; 3]; 3];
        let mut c = [[0.0f64; 3]; 3];
        for j in 0..snb {
            let rb = (sb0 + j as i64).rem_euclid(3) as usize;
            for i in 0..sna {
                let v = self.pres[j * sna + i];
                if v.is_finite() {
                    let ra = (sa0 + i as i64).rem_euclid(3) as usize;
                    s[ra][rb] += f64::from(v);
                    c[ra][rb] += 1.0;
                }
            }
        }
        let mut t = [[f64::NAN; 3]; 3];
        for ra in 0..3 {
            for rb in 0..3 {
                if c[ra][rb] > 0.0 {
                    t[ra][rb] = s[ra][rb] / c[ra][rb];
                }
            }
        }
        t
    }
}

/// Median and median absolute deviation of `v` (reordered); `None` when
/// fewer than 4 values.
fn median_mad(v: &mut [f32]) -> Option<(f32, f32)> {
    if v.len() < 4 {
        return None;
    }
    let k = v.len() / 2;
    let (_, m, _) = v.select_nth_unstable_by(k, |a, b| a.total_cmp(b));
    let m = *m;
    for x in v.iter_mut() {
        *x = (*x - m).abs();
    }
    let (_, d, _) = v.select_nth_unstable_by(k, |a, b| a.total_cmp(b));
    Some((m, *d))
}

/// Pearson correlation of the class table with the template under the
/// hypothesis (crossing residues i0, j0; directions sa, sb).
pub(super) fn template_corr(t: &[[f64; 3]; 3], i0: usize, sa: i64, j0: usize, sb: i64) -> f64 {
    let mut xs = [0.0; 9];
    let mut ys = [0.0; 9];
    let mut n = 0;
    for ra in 0..3i64 {
        for rb in 0..3i64 {
            let v = t[ra as usize][rb as usize];
            if !v.is_finite() {
                continue;
            }
            let ca = (sa * (ra - i0 as i64)).rem_euclid(3) as usize;
            let cb = (sb * (rb - j0 as i64)).rem_euclid(3) as usize;
            xs[n] = v;
            ys[n] = TEMPLATE[ca][cb];
            n += 1;
        }
    }
    if n < 9 {
        return f64::MIN;
    }
    let mx = xs.iter().sum::<f64>() / 9.0;
    let my = ys.iter().sum::<f64>() / 9.0;
    let (mut sxy, mut sxx, mut syy) = (0.0, 0.0, 0.0);
    for i in 0..9 {
        sxy += (xs[i] - mx) * (ys[i] - my);
        sxx += (xs[i] - mx).powi(2);
        syy += (ys[i] - my).powi(2);
    }
    if sxx <= 0.0 || syy <= 0.0 {
        return f64::MIN;
    }
    sxy / (sxx * syy).sqrt()
}
