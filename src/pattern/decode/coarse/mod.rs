//! Per-dot stage: which dots are missing, the orientation, and where the view
//! sits in the code.
//!
//! The fine grid gives every dot site's image position. The stage samples each
//! site and each background point (the lattice shifted by half a period along
//! both axes), and measures presence as the site's contrast against its four
//! background neighbours, normalised by the best contrast in its 5 × 5
//! neighbourhood (vignetting- and gradient-proof). Sites whose neighbourhood
//! has no contrast at all are void (dust, off-pattern) and are not read.
//!
//! Orientation comes from the 3 × 3 table of mean presence by (line index mod
//! 3) of both axes: the pattern's empty crossings (both indices ≡ 0) give the
//! one empty cell, and the code lines (≡ 1, half of them missing) sit one line
//! after the crossing line in the forward direction and one line before it
//! in the reversed direction. Matching the table against the template for
//! all 36 (offset, direction) hypotheses and both dot polarities tells the
//! lattice phase, the direction of each axis, and bright vs dark dots.
//!
//! The code lines' soft presence values (−1 … 1) are then correlated against
//! the whole sequence; the best offset must beat the runner-up by a margin
//! (in bit units) or the decoder refuses to answer.

// `!(x >= t)` is deliberate: it also rejects NaN. Index loops mirror the maths.
#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::needless_range_loop)]
use std::sync::Arc;

use super::error::DecodeError;
use super::fine::{Grid, HELPER_MIN_PIXELS};
use super::helper::{take_back, Helper};
use lattice::{sample_lattice, LatticeJob};

mod lattice;
use crate::frame::{Frame, Pixels};
use crate::pattern::sequence::LineSequence;

/// Expected mean presence by line class (0 = crossing line, 1 = code line,
/// 2 = plain full line) of the column and row lines.
const TEMPLATE: [[f64; 3]; 3] = [[0.0, 0.5, 1.0], [0.5, 0.25, 0.5], [1.0, 0.5, 1.0]];

/// What the per-dot stage found.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct CodeFix {
    /// True when the dots are at the fundamental's phase π (dark dots).
    pub dark_dots: bool,
    /// Line-index direction along lattice axis a and b (+1/−1).
    pub sigma: [i64; 2],
    /// Global line index of lattice line 0 of axis a and b.
    pub origin: [i64; 2],
    /// Orientation template correlation of the chosen hypothesis.
    pub orientation_score: f64,
    /// Best minus second-best template correlation.
    pub orientation_margin: f64,
    /// Code correlation margin, bits, per lattice axis.
    pub code_margin_bits: [f64; 2],
    /// Code lines read (non-void) per lattice axis.
    pub code_bits: [usize; 2],
    /// Estimated disagreeing code bits of the chosen offset, per axis.
    pub code_errors: [f64; 2],
    /// How the code read fits the configured code depth.
    pub code_check: CodeCheck,
}

/// Whether the code lines read confirm the configured code depth.
///
/// Why: the code margin compares offsets *within* the configured
/// sequence; it cannot tell that the frame comes from a pattern of another
/// depth, whose windows never occur in this sequence. The best offset then
/// still wins (by chance), and the position is confidently wrong. The check
/// asks how many offsets of the sequence a random reading of the same length
/// would match with as few disagreements: when that is large, the match
/// proves nothing.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CodeCheck {
    /// The match is beyond chance (`chance` ≤ [`CODE_CHANCE_MAX`]).
    pub confirmed: bool,
    /// Expected number of offset pairs (both axes) of the configured
    /// sequence that random code readings of the same lengths would match
    /// with at most the disagreements found: ≪ 1 means the reading can only
    /// come from this sequence.
    pub chance: f64,
    /// Hard disagreements of the chosen offsets, per lattice axis.
    pub mismatches: [usize; 2],
    /// Hard-read code lines, per lattice axis.
    pub lines: [usize; 2],
}

/// Largest expected number of chance matches for which a code reading
/// confirms the configured depth.
pub const CODE_CHANCE_MAX: f64 = 1e-3;

/// Hard reading of a soft code-line value: +1 present, −1 absent, 0 unread
/// (the same |t| > 0.2 as the readable-line count).
fn hard(t: f32) -> i8 {
    if t > 0.2 {
        1
    } else if t < -0.2 {
        -1
    } else {
        0
    }
}

/// The code-line values (±1) of every code slot of `seq`.
fn slot_values(seq: &LineSequence) -> Vec<i8> {
    (0..seq.len() / 3)
        .map(|q| if seq.line(3 * q as i64 + 1) { 1 } else { -1 })
        .collect()
}

/// Disagreements of `read` (hard values, slot order) placed with its first
/// line at slot `q0`; a read line outside the sequence disagrees.
fn mismatches_at(read: &[i8], slots: &[i8], q0: i64) -> usize {
    read.iter()
        .enumerate()
        .filter(|(t, &r)| {
            r != 0
                && usize::try_from(q0 + *t as i64)
                    .ok()
                    .and_then(|q| slots.get(q))
                    .is_none_or(|&c| c != r)
        })
        .count()
}

/// Fewest disagreements of `read` over every offset overlapping `slots`.
fn best_mismatches(read: &[i8], slots: &[i8]) -> usize {
    let kk = read.len() as i64;
    (1 - kk..slots.len() as i64)
        .map(|q0| mismatches_at(read, slots, q0))
        .min()
        .unwrap_or(read.len())
}

/// ln of the expected number of `offsets` at which `n` random code bits
/// disagree with a sequence on at most `e`: offsets · P(Binomial(n, ½) ≤ e),
/// in logs so that long readings do not underflow.
fn ln_chance(n: usize, e: usize, offsets: usize) -> f64 {
    // Running log-sum-exp over the terms ln C(n, k) − n ln 2 (no buffer: a
    // warm decode allocates nothing).
    let mut sum = f64::NEG_INFINITY;
    let mut t = -(n as f64) * std::f64::consts::LN_2;
    for k in 0..=e.min(n) {
        let (hi, lo) = if t > sum { (t, sum) } else { (sum, t) };
        sum = hi + (lo - hi).exp().ln_1p();
        t += ((n - k) as f64 / (k + 1) as f64).ln();
    }
    sum + (offsets.max(1) as f64).ln()
}

/// ln of the joint chance (both axes) of readings `read` against `slots`
/// with `mism` disagreements per axis.
fn ln_joint(read: [&[i8]; 2], mism: [usize; 2], slots: usize) -> f64 {
    (0..2)
        .map(|a| {
            let n = read[a].iter().filter(|&&r| r != 0).count();
            ln_chance(n, mism[a], slots + read[a].len().saturating_sub(1))
        })
        .sum()
}

/// The code-depth check of two axes' readings (`read`, hard values in slot
/// order) placed at slots `q0` of `seq` (see [`CodeCheck`]). When the
/// reading does not confirm `seq`'s depth but confirms another supported
/// depth, that is an error naming the depth that fits: the frame comes from
/// another pattern, and the position is wrong.
pub(crate) fn check_code(
    read: [&[i8]; 2],
    q0: [i64; 2],
    seq: &LineSequence,
    slots: &[i8],
) -> Result<CodeCheck, DecodeError> {
    let mism = [0, 1].map(|a| mismatches_at(read[a], slots, q0[a]));
    let lines = [0, 1].map(|a| read[a].iter().filter(|&&r| r != 0).count());
    let ln_given = ln_joint(read, mism, slots.len());
    let check = CodeCheck {
        confirmed: ln_given <= CODE_CHANCE_MAX.ln(),
        chance: ln_given.exp(),
        mismatches: mism,
        lines,
    };
    if check.confirmed {
        return Ok(check);
    }
    match better_depth(read, seq, ln_given, mism, lines) {
        Some(e) => Err(e),
        None => Ok(check),
    }
}

/// The supported depth other than `seq`'s whose sequence the readings fit
/// beyond chance and better than `ln_given` (ln of the configured depth's
/// joint chance), as the error that names it; `None` when no other depth
/// does. `mism` and `lines` describe the configured depth's fit.
fn better_depth(
    read: [&[i8]; 2],
    seq: &LineSequence,
    ln_given: f64,
    mism: [usize; 2],
    lines: [usize; 2],
) -> Option<DecodeError> {
    use crate::pattern::sequence::{MAX_BITS, MIN_BITS};
    let mut best: Option<(f64, u32, [usize; 2])> = None;
    for bits in MIN_BITS..=MAX_BITS {
        if bits == seq.bits() {
            continue;
        }
        let Ok(other) = LineSequence::new(bits) else {
            continue;
        };
        let s = slot_values(&other);
        let m = [0, 1].map(|a| best_mismatches(read[a], &s));
        let ln = ln_joint(read, m, s.len());
        if best.is_none_or(|(b, ..)| ln < b) {
            best = Some((ln, bits, m));
        }
    }
    match best {
        Some((ln, bits, m)) if ln <= CODE_CHANCE_MAX.ln() && ln < ln_given => {
            Some(DecodeError::CodeDepthMismatch {
                bits: seq.bits(),
                fits_bits: bits,
                lines,
                mismatches: mism,
                fits_mismatches: m,
            })
        }
        _ => None,
    }
}

/// When the code margin fails (`ambiguous`), whether the readings fit
/// another depth: then the configured depth is wrong, and the error says
/// which one fits instead of only "ambiguous". Both axes' readings must be
/// in `read` (an axis not read is empty).
pub(crate) fn ambiguous_or_other_depth(
    ambiguous: DecodeError,
    read: [&[i8]; 2],
    seq: &LineSequence,
) -> DecodeError {
    let slots = slot_values(seq);
    let mism = [0, 1].map(|a| best_mismatches(read[a], &slots));
    let lines = [0, 1].map(|a| read[a].iter().filter(|&&r| r != 0).count());
    let ln_given = ln_joint(read, mism, slots.len());
    better_depth(read, seq, ln_given, mism, lines).unwrap_or(ambiguous)
}

/// Code slots (3 lines each) either side of a tracked prediction that the
/// tracking check scores against: motions of up to ±24 periods between
/// frames that the continuity prediction missed show up as a better
/// neighbour; larger ones as a prediction that disagrees on about half the
/// bits.
const TRACK_SLOTS: i64 = 8;

/// Largest evidence one dot contributes to its code line, nats.
const DOT_LLR_CAP_NATS: f32 = 2.0;

/// Decision thresholds of the per-dot stage.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CoarseThresholds {
    /// Minimum correlation of the 3 × 3 class table with its template.
    pub min_orientation_score: f64,
    /// Minimum lead of the best orientation hypothesis over the runner-up.
    pub min_orientation_margin: f64,
    /// Minimum lead of the best code offset over the runner-up, in bits of
    /// evidence: log₂ of the likelihood ratio of the two offsets given the
    /// per-dot presence values (each dot contributes at most
    /// 2 nats ≈ 2.9 bits, so the default asks for about six clearly read
    /// dots net on the code lines that tell the two offsets apart).
    pub min_code_margin_bits: f64,
}

impl Default for CoarseThresholds {
    fn default() -> Self {
        Self {
            min_orientation_score: 0.7,
            min_orientation_margin: 0.1,
            min_code_margin_bits: 16.0,
        }
    }
}

/// Reused buffers of the per-dot stage.
#[derive(Debug, Default)]
pub(crate) struct CoarseStage {
    /// Samples on the integer lattice (α, β integers), [nb][na].
    g0: Vec<f32>,
    /// Samples on the half lattice (α+½, β+½), [nb+1][na+1].
    g1: Vec<f32>,
    pres: Vec<f32>,
    /// Presence of the best hypothesis so far (swapped with `pres`).
    best_pres: Vec<f32>,
    tmp: Vec<f32>,
    lmax: Vec<f32>,
    sel: Vec<f32>,
    lines: Vec<f32>,
    /// Per-site log-likelihood ratio present vs absent, nats (0 = unread).
    llr: Vec<f32>,
    /// Per code line: summed dot log-likelihood ratios (bit 1 vs 0), nats.
    line_llr: Vec<f32>,
    counts: Vec<f32>,
    /// Code-correlation score of every candidate offset.
    scores: Vec<f32>,
    epad: Vec<f32>,
    epad_bits: u32,
    /// Code-line values (±1) of every slot of the configured sequence.
    slots: Vec<i8>,
    /// Hard code readings of the two lattice axes (slot order).
    read: [Vec<i8>; 2],
    /// One sample per site instead of five (faster, less robust).
    pub(crate) single_sample: bool,
    /// The decoder's helper thread, once started
    /// ([`super::Decoder::decode_shared`]).
    pub(crate) helper: Option<Arc<Helper>>,
    /// The helper's lattice buffer while it has no job.
    lattice_job: Option<Box<LatticeJob>>,
}

impl CoarseStage {
    /// The soft evidence of code line `li` of `axis`: its value in −1..=1
    /// (2·mean presence − 1, weighted down below 8 readable dots; 0 with
    /// fewer than 3) and its summed per-dot log-likelihood, over the dots
    /// whose cross line is not a code line itself (`skip(oi)`).
    fn line_evidence(
        &self,
        axis: usize,
        li: usize,
        sna: usize,
        n_other: usize,
        skip: impl Fn(usize) -> bool,
    ) -> (f32, f32) {
        let (mut sum, mut cnt, mut ll) = (0.0f32, 0.0f32, 0.0f32);
        for oi in 0..n_other {
            if skip(oi) {
                continue;
            }
            let idx = if axis == 0 {
                oi * sna + li
            } else {
                li * sna + oi
            };
            let v = self.pres[idx];
            if v.is_finite() {
                sum += v;
                cnt += 1.0;
                ll += self.llr[idx];
            }
        }
        let t = if cnt >= 3.0 {
            (2.0 * (sum / cnt) - 1.0).clamp(-1.0, 1.0) * (cnt / 8.0).min(1.0)
        } else {
            0.0
        };
        (t, ll)
    }

    fn prepare_code(&mut self, seq: &LineSequence, pad: usize) {
        let q = seq.len() / 3;
        if self.epad_bits == seq.bits() && self.epad.len() == q + 2 * pad {
            return;
        }
        self.epad_bits = seq.bits();
        self.epad.clear();
        self.epad.resize(pad, 0.0);
        for i in 0..q {
            self.epad.push(if seq.line(3 * i as i64 + 1) {
                1.0
            } else {
                -1.0
            });
        }
        self.epad.resize(q + 2 * pad, 0.0);
    }

    /// Samples every dot site and background point of the view into `g0`
    /// and `g1`; returns (na, nb, a0, b0): the integer lattice's size and
    /// first lattice coordinates.
    fn sample(
        &mut self,
        frame: &Frame,
        grid: &Grid,
        seq: &LineSequence,
    ) -> Result<(usize, usize, i64, i64), DecodeError> {
        let (w, h) = (frame.width(), frame.height());
        let tau = std::f64::consts::TAU;
        let k = grid.k;
        let det = k[0][0] * k[1][1] - k[0][1] * k[1][0];
        if det.abs() < 1e-12 {
            return Err(DecodeError::NoGrid("degenerate grid".into()));
        }
        // K⁻¹: image offset of a lattice-coordinate step.
        let inv = [
            [k[1][1] / det, -k[0][1] / det],
            [-k[1][0] / det, k[0][0] / det],
        ];
        let da = [inv[0][0] * tau, inv[1][0] * tau];
        let db = [inv[0][1] * tau, inv[1][1] * tau];
        let (cx, cy) = (w as f64 / 2.0, h as f64 / 2.0);
        let u00 = [
            cx - (inv[0][0] * grid.phi[0] + inv[0][1] * grid.phi[1]),
            cy - (inv[1][0] * grid.phi[0] + inv[1][1] * grid.phi[1]),
        ];
        // Lattice coordinate range over the frame.
        let lat = |u: f64, v: f64| {
            let x = u - cx;
            let y = v - cy;
            (
                (k[0][0] * x + k[0][1] * y + grid.phi[0]) / tau,
                (k[1][0] * x + k[1][1] * y + grid.phi[1]) / tau,
            )
        };
        let mut amin = f64::MAX;
        let mut amax = f64::MIN;
        let mut bmin = f64::MAX;
        let mut bmax = f64::MIN;
        for (u, v) in [
            (0.0, 0.0),
            (w as f64, 0.0),
            (0.0, h as f64),
            (w as f64, h as f64),
        ] {
            let (a, b) = lat(u, v);
            amin = amin.min(a);
            amax = amax.max(a);
            bmin = bmin.min(b);
            bmax = bmax.max(b);
        }
        let a0 = amin.ceil() as i64;
        let b0 = bmin.ceil() as i64;
        let na = (amax.floor() as i64 - a0 + 1).max(0) as usize;
        let nb = (bmax.floor() as i64 - b0 + 1).max(0) as usize;
        if na * nb > 4_000_000 || na < 9 || nb < 9 {
            return Err(DecodeError::TooFewPeriods {
                got: na.min(nb),
                need: seq.min_periods_in_view(),
            });
        }
        // One bilinear sample per dot site (integer lattice) and per
        // background point (half lattice); both polarity hypotheses below
        // read the same samples. The dots are ≥ 3 px and blurred, so the
        // centre sample carries the site's contrast.
        let g1_origin = [
            u00[0] + (a0 as f64 - 0.5) * da[0] + (b0 as f64 - 0.5) * db[0],
            u00[1] + (a0 as f64 - 0.5) * da[1] + (b0 as f64 - 0.5) * db[1],
        ];
        let g0_origin = [
            u00[0] + a0 as f64 * da[0] + b0 as f64 * db[0],
            u00[1] + a0 as f64 * da[1] + b0 as f64 * db[1],
        ];
        // Centre plus four points at ±1/6 period along the lattice axes: the
        // mean over the dot's core is robust to blur, noise and the few
        // tenths of a pixel that lens distortion moves a site.
        let mut offs = [[0.0; 2]; 5];
        for (t, &(fa, fb)) in [(0.0, 0.0), (1.0, 0.0), (-1.0, 0.0), (0.0, 1.0), (0.0, -1.0)]
            .iter()
            .enumerate()
        {
            offs[t] = [
                (fa * da[0] + fb * db[0]) / 6.0,
                (fa * da[1] + fb * db[1]) / 6.0,
            ];
        }
        let offs: &[[f64; 2]] = if self.single_sample {
            &offs[..1]
        } else {
            &offs
        };
        // The half lattice on the helper thread when the decode lent it
        // this frame (see `decode::helper`), the integer one here.
        let mut lent = false;
        if let Some(helper) = &self.helper {
            let mut job = self.lattice_job.take().unwrap_or_default();
            if w * h >= HELPER_MIN_PIXELS {
                job.w = w;
                job.h = h;
                job.origin = g1_origin;
                job.da = da;
                job.db = db;
                job.ni = na + 1;
                job.nj = nb + 1;
                job.offs[..offs.len()].copy_from_slice(offs);
                job.n_offs = offs.len();
                match helper.submit(frame, job) {
                    Ok(()) => lent = true,
                    Err(j) => self.lattice_job = take_back(j),
                }
            } else {
                self.lattice_job = Some(job);
            }
        }
        match frame.pixels() {
            Pixels::U8(p) => {
                sample_lattice(p, w, h, g0_origin, da, db, na, nb, offs, &mut self.g0);
            }
            Pixels::U16(p) => {
                sample_lattice(p, w, h, g0_origin, da, db, na, nb, offs, &mut self.g0);
            }
        }
        let done = if lent {
            self.helper.as_ref().and_then(|h| h.wait())
        } else {
            None
        };
        if let Some(mut job) = done.and_then(take_back::<LatticeJob>) {
            std::mem::swap(&mut self.g1, &mut job.out);
            self.lattice_job = Some(job);
        } else {
            // Not lent, or the helper failed (a panic): on this thread.
            match frame.pixels() {
                Pixels::U8(p) => sample_lattice(
                    p,
                    w,
                    h,
                    g1_origin,
                    da,
                    db,
                    na + 1,
                    nb + 1,
                    offs,
                    &mut self.g1,
                ),
                Pixels::U16(p) => sample_lattice(
                    p,
                    w,
                    h,
                    g1_origin,
                    da,
                    db,
                    na + 1,
                    nb + 1,
                    offs,
                    &mut self.g1,
                ),
            }
        }
        Ok((na, nb, a0, b0))
    }

    /// Runs the stage on `frame` with the fine `grid`.
    #[expect(
        clippy::too_many_lines,
        reason = "the coarse decode's stages share many locals; to be split with a state struct"
    )]
    pub(crate) fn run(
        &mut self,
        frame: &Frame,
        grid: &Grid,
        seq: &LineSequence,
        polarity: Option<bool>,
        th: &CoarseThresholds,
    ) -> Result<CodeFix, DecodeError> {
        let (na, nb, a0, b0) = self.sample(frame, grid, seq)?;
        // Both polarity hypotheses, unless fixed.
        let hyps: &[bool] = match polarity {
            Some(false) => &[false],
            Some(true) => &[true],
            None => &[false, true],
        };
        let mut best: Option<(f64, bool, [usize; 2], [i64; 2])> = None;
        let mut second = f64::MIN;
        let mut chosen_pres = std::mem::take(&mut self.best_pres);
        let mut dims = (0, 0, 0i64, 0i64);
        for &dark in hyps {
            let (sa0, sb0, sna, snb) = self.presence(dark, na, nb, a0, b0);
            let table = self.class_table(sna, snb, sa0, sb0);
            for i0 in 0..3usize {
                for j0 in 0..3usize {
                    for sa in [1i64, -1] {
                        for sb in [1i64, -1] {
                            let score = template_corr(&table, i0, sa, j0, sb);
                            match best {
                                Some((bs, ..)) if score <= bs => second = second.max(score),
                                _ => {
                                    if let Some((bs, ..)) = best {
                                        second = second.max(bs);
                                    }
                                    best = Some((score, dark, [i0, j0], [sa, sb]));
                                    chosen_pres.clone_from(&self.pres);
                                    dims = (sna, snb, sa0, sb0);
                                }
                            }
                        }
                    }
                }
            }
        }
        let Some((oscore, dark, res0, sigma)) = best else {
            return Err(DecodeError::NoGrid("no orientation hypothesis".into()));
        };
        let omargin = oscore - second;
        if !(oscore >= th.min_orientation_score) {
            return Err(DecodeError::Orientation(format!(
                "dot layout does not match the pattern's line structure (template correlation {oscore:.3} < {:.3})",
                th.min_orientation_score
            )));
        }
        if !(omargin >= th.min_orientation_margin) {
            return Err(DecodeError::Orientation(format!(
                "orientation ambiguous (margin {omargin:.3} < {:.3})",
                th.min_orientation_margin
            )));
        }
        std::mem::swap(&mut self.pres, &mut chosen_pres);
        self.best_pres = chosen_pres;
        let (sna, snb, sa0, sb0) = dims;
        self.fill_llr(
            sna,
            snb,
            sa0,
            sb0,
            |l| (sigma[0] * (l - res0[0] as i64)).rem_euclid(3),
            |l| (sigma[1] * (l - res0[1] as i64)).rem_euclid(3),
        );
        // Code lines of each axis.
        let need = seq.min_periods_in_view();
        let mut origin = [0i64; 2];
        let mut margins = [0.0; 2];
        let mut nbits = [0usize; 2];
        let mut errs = [0.0; 2];
        let mut slot0 = [0i64; 2];
        let mut ambiguous: Option<DecodeError> = None;
        self.read[0].clear();
        self.read[1].clear();
        for axis in 0..2 {
            let (n_this, n_other, l0) = if axis == 0 {
                (sna, snb, sa0)
            } else {
                (snb, sna, sb0)
            };
            if n_this < need {
                return Err(ambiguous.unwrap_or(DecodeError::TooFewPeriods { got: n_this, need }));
            }
            let s_this = sigma[axis];
            let s_other = sigma[1 - axis];
            let r_this = res0[axis] as i64;
            let r_other = res0[1 - axis] as i64;
            let class = |l: i64, r0: i64, s: i64| (s * (l - r0)).rem_euclid(3);
            // Soft line values of this axis's code lines.
            self.lines.clear();
            self.line_llr.clear();
            self.counts.clear();
            let mut first_code: Option<i64> = None;
            let o0 = if axis == 0 { sb0 } else { sa0 };
            for li in 0..n_this {
                let l = l0 + li as i64;
                if class(l, r_this, s_this) != 1 {
                    continue;
                }
                if first_code.is_none() {
                    first_code = Some(l);
                }
                let (t, ll) = self.line_evidence(axis, li, sna, n_other, |oi| {
                    class(o0 + oi as i64, r_other, s_other) == 1
                });
                self.line_llr.push(ll);
                self.lines.push(t);
            }
            let Some(first) = first_code else {
                return Err(ambiguous.unwrap_or(DecodeError::TooFewPeriods { got: n_this, need }));
            };
            let kk = self.lines.len();
            nbits[axis] = self.lines.iter().filter(|t| t.abs() > 0.2).count();
            if nbits[axis] < seq.bits() as usize + 1 {
                return Err(ambiguous.unwrap_or(DecodeError::CodeAmbiguous {
                    axis,
                    readable_bits: nbits[axis],
                    code_bits: seq.bits(),
                    reason: format!("need at least {} readable code lines", seq.bits() + 1),
                }));
            }
            if s_this < 0 {
                self.lines.reverse();
                self.line_llr.reverse();
            }
            self.prepare_code(seq, kk);
            let qn = seq.len() / 3;
            // Candidate q0 (code slot of the lowest-slot visible code line)
            // from −(kk−1) to qn−1, scored by log-likelihood: code bits c = ±1
            // at that offset give ln P(dots | c) = const + Σ c·L/2 with L the
            // lines' summed dot log-likelihood ratios.
            // All offsets at once, one line at a time: the same sum in the
            // same order per offset as a per-offset dot product (so the same
            // scores), but a vectorisable multiply-add along the offsets.
            let n_off = qn + kk - 1;
            self.scores.clear();
            self.scores.resize(n_off, 0.0);
            for (t, &l) in self.line_llr.iter().enumerate() {
                let e = &self.epad[t + 1..t + 1 + n_off];
                for (sc, &e) in self.scores.iter_mut().zip(e) {
                    *sc += e * l;
                }
            }
            let mut b1 = (f32::MIN, 0i64);
            let mut b2 = f32::MIN;
            for (q, &sc) in self.scores.iter().enumerate() {
                let q0 = q as i64 - (kk as i64 - 1);
                if sc > b1.0 {
                    b2 = b2.max(b1.0);
                    b1 = (sc, q0);
                } else if sc > b2 {
                    b2 = sc;
                }
            }
            let margin = f64::from(b1.0 - b2) / (2.0 * std::f64::consts::LN_2);
            margins[axis] = margin;
            let st = (b1.1 + kk as i64) as usize;
            let agree: f32 = self.epad[st..st + kk]
                .iter()
                .zip(&self.lines)
                .map(|(a, b)| a * b)
                .sum();
            let total: f32 = self.lines.iter().map(|t| t.abs()).sum();
            errs[axis] = f64::from(total - agree) / 2.0;
            self.read[axis].clear();
            self.read[axis].extend(self.lines.iter().map(|&t| hard(t)));
            slot0[axis] = b1.1;
            if !(margin >= th.min_code_margin_bits) {
                // Read the other axis too before refusing: a reading that
                // fits another code depth says what is wrong.
                ambiguous.get_or_insert(DecodeError::CodeAmbiguous {
                    axis,
                    readable_bits: nbits[axis],
                    code_bits: seq.bits(),
                    reason: format!(
                        "best offset leads the runner-up by {margin:.1} bits of evidence, need {:.1}",
                        th.min_code_margin_bits
                    ),
                });
                continue;
            }
            // Global line of the visible code line with the lowest slot.
            let q0 = b1.1;
            let last_code = first + 3 * (kk as i64 - 1);
            let (l_low, g_low) = if s_this > 0 {
                (first, 3 * q0 + 1)
            } else {
                (last_code, 3 * q0 + 1)
            };
            origin[axis] = g_low - s_this * l_low;
        }
        if let Some(e) = ambiguous {
            return Err(ambiguous_or_other_depth(
                e,
                [&self.read[0], &self.read[1]],
                seq,
            ));
        }
        if self.slots.len() != seq.len() / 3 {
            self.slots = slot_values(seq);
        }
        let code_check = check_code([&self.read[0], &self.read[1]], slot0, seq, &self.slots)?;
        Ok(CodeFix {
            dark_dots: dark,
            sigma,
            origin,
            orientation_score: oscore,
            orientation_margin: omargin,
            code_margin_bits: margins,
            code_bits: nbits,
            code_errors: errs,
            code_check,
        })
    }

    /// Tracking check of a predicted code fix (polarity, axis directions and
    /// line origins carried over from the previous frame, the origins moved by
    /// the whole periods the new fine phase implies): samples the sites as
    /// [`CoarseStage::run`] does, but builds presence for the predicted
    /// polarity only and, instead of correlating the code lines with the
    /// whole sequence, scores the predicted code offset against its
    /// neighbours ±`TRACK_SLOTS` code slots. Accepts only when the predicted
    /// orientation hypothesis is the best of all 36 by the usual margin, the
    /// predicted offset beats every neighbour by the usual code margin and at
    /// most a fifth of the readable code bits disagree (a wrong offset of an
    /// m-sequence disagrees on about half). Any failure means "do the full
    /// search", never a guess.
    pub(crate) fn verify(
        &mut self,
        frame: &Frame,
        grid: &Grid,
        seq: &LineSequence,
        pred: &CodeFix,
        th: &CoarseThresholds,
    ) -> Result<CodeFix, DecodeError> {
        let (na, nb, a0, b0) = self.sample(frame, grid, seq)?;
        let dark = pred.dark_dots;
        let sigma = pred.sigma;
        let origin = pred.origin;
        let (sa0, sb0, sna, snb) = self.presence(dark, na, nb, a0, b0);
        self.fill_llr(
            sna,
            snb,
            sa0,
            sb0,
            |l| (origin[0] + sigma[0] * l).rem_euclid(3),
            |l| (origin[1] + sigma[1] * l).rem_euclid(3),
        );
        let table = self.class_table(sna, snb, sa0, sb0);
        // Global line g = origin + σ·l is a crossing line when g ≡ 0 (mod 3),
        // i.e. l ≡ −σ·origin: the crossing residue of the class table.
        let res0 = [
            (-sigma[0] * origin[0]).rem_euclid(3) as usize,
            (-sigma[1] * origin[1]).rem_euclid(3) as usize,
        ];
        let oscore = template_corr(&table, res0[0], sigma[0], res0[1], sigma[1]);
        let mut second = f64::MIN;
        for i0 in 0..3usize {
            for j0 in 0..3usize {
                for sa in [1i64, -1] {
                    for sb in [1i64, -1] {
                        if [i0, j0] == res0 && [sa, sb] == sigma {
                            continue;
                        }
                        second = second.max(template_corr(&table, i0, sa, j0, sb));
                    }
                }
            }
        }
        let omargin = oscore - second;
        if !(oscore >= th.min_orientation_score && omargin >= th.min_orientation_margin) {
            return Err(DecodeError::Orientation(format!(
                "tracking: predicted orientation scores {oscore:.3} (margin {omargin:.3})"
            )));
        }
        let need = seq.min_periods_in_view();
        let len = seq.len() as i64;
        let code = |g: i64| -> f32 {
            if g < 0 || g >= len {
                0.0
            } else if seq.line(g) {
                1.0
            } else {
                -1.0
            }
        };
        let mut margins = [0.0; 2];
        let mut nbits = [0usize; 2];
        let mut errs = [0.0; 2];
        for axis in 0..2 {
            let (n_this, n_other, l0, o0) = if axis == 0 {
                (sna, snb, sa0, sb0)
            } else {
                (snb, sna, sb0, sa0)
            };
            if n_this < need {
                return Err(DecodeError::TooFewPeriods { got: n_this, need });
            }
            let (s_this, s_other) = (sigma[axis], sigma[1 - axis]);
            let (g_this, g_other) = (origin[axis], origin[1 - axis]);
            self.lines.clear();
            self.line_llr.clear();
            let mut first: Option<i64> = None;
            for li in 0..n_this {
                let g = g_this + s_this * (l0 + li as i64);
                if g.rem_euclid(3) != 1 {
                    continue;
                }
                first.get_or_insert(g);
                let (t, ll) = self.line_evidence(axis, li, sna, n_other, |oi| {
                    (g_other + s_other * (o0 + oi as i64)).rem_euclid(3) == 1
                });
                self.line_llr.push(ll);
                self.lines.push(t);
            }
            let Some(g_first) = first else {
                return Err(DecodeError::TooFewPeriods { got: n_this, need });
            };
            nbits[axis] = self.lines.iter().filter(|t| t.abs() > 0.2).count();
            if nbits[axis] < seq.bits() as usize + 1 {
                return Err(DecodeError::CodeAmbiguous {
                    axis,
                    readable_bits: nbits[axis],
                    code_bits: seq.bits(),
                    reason: "tracking: too few readable code lines".into(),
                });
            }
            let step = 3 * s_this;
            let score = |v: &[f32], shift: i64| -> f32 {
                v.iter()
                    .enumerate()
                    .map(|(i, t)| t * code(g_first + step * i as i64 + 3 * shift))
                    .sum()
            };
            let s0 = score(&self.line_llr, 0);
            let mut s2 = f32::MIN;
            for shift in -TRACK_SLOTS..=TRACK_SLOTS {
                if shift != 0 {
                    s2 = s2.max(score(&self.line_llr, shift));
                }
            }
            let total: f32 = self.lines.iter().map(|t| t.abs()).sum();
            margins[axis] = f64::from(s0 - s2) / (2.0 * std::f64::consts::LN_2);
            errs[axis] = f64::from(total - score(&self.lines, 0)) / 2.0;
            if !(margins[axis] >= th.min_code_margin_bits && errs[axis] <= 0.2 * nbits[axis] as f64)
            {
                return Err(DecodeError::CodeAmbiguous {
                    axis,
                    readable_bits: nbits[axis],
                    code_bits: seq.bits(),
                    reason: format!(
                        "tracking: predicted code offset leads by {:.2} bits with {:.2} disagreeing",
                        margins[axis], errs[axis]
                    ),
                });
            }
        }
        Ok(CodeFix {
            dark_dots: dark,
            sigma,
            origin,
            orientation_score: oscore,
            orientation_margin: omargin,
            code_margin_bits: margins,
            code_bits: nbits,
            code_errors: errs,
            // The prediction was confirmed when it was first found; the
            // tracking check above held it to the same margins since.
            code_check: pred.code_check,
        })
    }

    /// Presence of every site for a polarity hypothesis, into `self.pres`
    /// ([nb][na] of the site lattice, NaN = unreadable). Returns the site
    /// lattice's first indices and size.
    fn presence(
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
    fn fill_llr(
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
    fn class_table(&self, sna: usize, snb: usize, sa0: i64, sb0: i64) -> [[f64; 3]; 3] {
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
fn template_corr(t: &[[f64; 3]; 3], i0: usize, sa: i64, j0: usize, sb: i64) -> f64 {
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

#[cfg(test)]
mod code_check_tests {
    use super::*;

    fn window(bits: u32, q0: usize, len: usize) -> Vec<i8> {
        let s = slot_values(&LineSequence::new(bits).unwrap());
        s[q0..q0 + len].to_vec()
    }

    #[test]
    fn chance_is_offsets_times_binomial_tail() {
        let ln = ln_chance(20, 0, 4095);
        assert!((ln - (4095.0f64 / f64::from(1u32 << 20)).ln()).abs() < 1e-9);
        // P(Bin(4, ½) ≤ 1) = 5/16.
        assert!((ln_chance(4, 1, 16).exp() - 5.0).abs() < 1e-9);
        // Long readings do not underflow to "certain".
        assert!(ln_chance(3000, 1400, 4095).is_finite());
        assert!(ln_chance(3000, 1400, 4095) > ln_chance(3000, 10, 4095));
    }

    #[test]
    fn a_window_of_the_sequence_is_confirmed() {
        let seq = LineSequence::new(12).unwrap();
        let (a, b) = (window(12, 500, 20), window(12, 3000, 23));
        let c = check_code([&a, &b], [500, 3000], &seq, &slot_values(&seq)).unwrap();
        assert!(c.confirmed, "{c:?}");
        assert_eq!(c.mismatches, [0, 0]);
        assert_eq!(c.lines, [20, 23]);
    }

    #[test]
    fn a_window_of_another_depth_names_it() {
        let seq = LineSequence::new(12).unwrap();
        let (a, b) = (window(10, 100, 25), window(10, 700, 25));
        // Wherever the decoder placed them in the 12-bit sequence.
        let q0 = [0, 1].map(|i| {
            let s = slot_values(&seq);
            let r = if i == 0 { &a } else { &b };
            (1 - r.len() as i64..s.len() as i64)
                .min_by_key(|&q| mismatches_at(r, &s, q))
                .unwrap()
        });
        match check_code([&a, &b], q0, &seq, &slot_values(&seq)) {
            Err(DecodeError::CodeDepthMismatch {
                bits, fits_bits, ..
            }) => assert_eq!((bits, fits_bits), (12, 10)),
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn a_short_reading_is_unconfirmed_not_an_error() {
        let seq = LineSequence::new(12).unwrap();
        let (a, b) = (window(12, 40, 13), window(12, 900, 13));
        let c = check_code([&a, &b], [40, 900], &seq, &slot_values(&seq)).unwrap();
        assert!(!c.confirmed, "{c:?}");
        assert!(c.chance > CODE_CHANCE_MAX);
    }
}
