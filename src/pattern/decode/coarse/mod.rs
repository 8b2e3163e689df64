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
//!
//! The files: this one holds the stage's state and the search (orientation,
//! then each axis's code read against the whole sequence); `sample` the
//! pixel pass, `presence` the per-site contrast and orientation evidence,
//! `check` the code-depth check, `track` the tracking check of a predicted
//! fix, `lattice` the bilinear sampling loop.

// `!(x >= t)` is deliberate: it also rejects NaN. Index loops mirror the maths.
#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::needless_range_loop)]
use std::sync::Arc;

use super::error::DecodeError;
use super::fine::Grid;
use super::helper::Helper;
use check::{ambiguous_or_other_depth, check_code, hard, slot_values};
use lattice::LatticeJob;
use presence::template_corr;

mod check;
mod lattice;
mod presence;
mod sample;
mod track;
use crate::frame::Frame;
use crate::pattern::sequence::LineSequence;

pub use check::{CodeCheck, CODE_CHANCE_MAX};

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

/// The orientation hypothesis [`CoarseStage::orient`] chose.
#[derive(Debug, Clone, Copy)]
struct Orientation {
    /// Template correlation of the hypothesis.
    score: f64,
    /// Its lead over the runner-up.
    margin: f64,
    /// Dark dots (the fundamental's phase π).
    dark: bool,
    /// Crossing-line residue (mod 3) of each lattice axis.
    res0: [usize; 2],
    /// Line-index direction of each lattice axis (+1/−1).
    sigma: [i64; 2],
    /// The site lattice of the chosen polarity: (sna, snb, sa0, sb0).
    dims: (usize, usize, i64, i64),
}

/// One lattice axis's code read by [`CoarseStage::read_axis`].
#[derive(Debug, Clone, Copy)]
struct AxisCode {
    /// Lead of the best offset over the runner-up, bits.
    margin_bits: f64,
    /// Readable code lines.
    bits: usize,
    /// Estimated disagreeing code bits of the best offset.
    errors: f64,
    /// Code slot of the lowest-slot visible code line (the best offset).
    slot0: i64,
    /// Global line index of lattice line 0 at that offset.
    origin: i64,
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

    /// Runs the stage on `frame` with the fine `grid`: the sites sampled,
    /// the orientation chosen ([`CoarseStage::orient`]), the dots' evidence
    /// calibrated, each axis's code lines read against the whole sequence
    /// ([`CoarseStage::read_axis`]), and the reading checked against the
    /// configured depth (`check`).
    pub(crate) fn run(
        &mut self,
        frame: &Frame,
        grid: &Grid,
        seq: &LineSequence,
        polarity: Option<bool>,
        th: &CoarseThresholds,
    ) -> Result<CodeFix, DecodeError> {
        let (na, nb, a0, b0) = self.sample(frame, grid, seq)?;
        let o = self.orient(na, nb, a0, b0, polarity, th)?;
        let (sigma, res0) = (o.sigma, o.res0);
        let (sna, snb, sa0, sb0) = o.dims;
        self.fill_llr(
            sna,
            snb,
            sa0,
            sb0,
            |l| (sigma[0] * (l - res0[0] as i64)).rem_euclid(3),
            |l| (sigma[1] * (l - res0[1] as i64)).rem_euclid(3),
        );
        // Code lines of each axis.
        let mut origin = [0i64; 2];
        let mut margins = [0.0; 2];
        let mut nbits = [0usize; 2];
        let mut errs = [0.0; 2];
        let mut slot0 = [0i64; 2];
        let mut ambiguous: Option<DecodeError> = None;
        self.read[0].clear();
        self.read[1].clear();
        for axis in 0..2 {
            let code = match self.read_axis(axis, &o, seq) {
                Ok(code) => code,
                Err(e) => return Err(ambiguous.unwrap_or(e)),
            };
            margins[axis] = code.margin_bits;
            nbits[axis] = code.bits;
            errs[axis] = code.errors;
            slot0[axis] = code.slot0;
            let margin = code.margin_bits;
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
            origin[axis] = code.origin;
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
            dark_dots: o.dark,
            sigma,
            origin,
            orientation_score: o.score,
            orientation_margin: o.margin,
            code_margin_bits: margins,
            code_bits: nbits,
            code_errors: errs,
            code_check,
        })
    }

    /// The orientation: every (polarity, crossing residues, directions)
    /// hypothesis's class table matched against the template; the best must
    /// score and lead the runner-up by the thresholds. Leaves the chosen
    /// hypothesis's presence in `self.pres`.
    fn orient(
        &mut self,
        na: usize,
        nb: usize,
        a0: i64,
        b0: i64,
        polarity: Option<bool>,
        th: &CoarseThresholds,
    ) -> Result<Orientation, DecodeError> {
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
        Ok(Orientation {
            score: oscore,
            margin: omargin,
            dark,
            res0,
            sigma,
            dims,
        })
    }

    /// Reads the code lines of lattice `axis` under orientation `o` and
    /// places them in the sequence: the soft line values into
    /// `self.lines` (and their hard reading into `self.read[axis]`), every
    /// offset scored ([`CoarseStage::score_offsets`]), the best one's
    /// margin, disagreements and line origin. The margin is the caller's to
    /// judge; too few lines or readable bits are errors.
    fn read_axis(
        &mut self,
        axis: usize,
        o: &Orientation,
        seq: &LineSequence,
    ) -> Result<AxisCode, DecodeError> {
        let (sigma, res0) = (o.sigma, o.res0);
        let (sna, snb, sa0, sb0) = o.dims;
        let need = seq.min_periods_in_view();
        let (n_this, n_other, l0) = if axis == 0 {
            (sna, snb, sa0)
        } else {
            (snb, sna, sb0)
        };
        if n_this < need {
            return Err(DecodeError::TooFewPeriods { got: n_this, need });
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
            return Err(DecodeError::TooFewPeriods { got: n_this, need });
        };
        let kk = self.lines.len();
        let bits = self.lines.iter().filter(|t| t.abs() > 0.2).count();
        if bits < seq.bits() as usize + 1 {
            return Err(DecodeError::CodeAmbiguous {
                axis,
                readable_bits: bits,
                code_bits: seq.bits(),
                reason: format!("need at least {} readable code lines", seq.bits() + 1),
            });
        }
        if s_this < 0 {
            self.lines.reverse();
            self.line_llr.reverse();
        }
        self.prepare_code(seq, kk);
        let (b1, b2) = self.score_offsets(seq.len() / 3, kk);
        let margin = f64::from(b1.0 - b2) / (2.0 * std::f64::consts::LN_2);
        let st = (b1.1 + kk as i64) as usize;
        let agree: f32 = self.epad[st..st + kk]
            .iter()
            .zip(&self.lines)
            .map(|(a, b)| a * b)
            .sum();
        let total: f32 = self.lines.iter().map(|t| t.abs()).sum();
        let errors = f64::from(total - agree) / 2.0;
        self.read[axis].clear();
        self.read[axis].extend(self.lines.iter().map(|&t| hard(t)));
        // Global line of the visible code line with the lowest slot.
        let q0 = b1.1;
        let last_code = first + 3 * (kk as i64 - 1);
        let (l_low, g_low) = if s_this > 0 {
            (first, 3 * q0 + 1)
        } else {
            (last_code, 3 * q0 + 1)
        };
        Ok(AxisCode {
            margin_bits: margin,
            bits,
            errors,
            slot0: b1.1,
            origin: g_low - s_this * l_low,
        })
    }

    /// Scores every offset of the `kk` code lines read against the `qn`
    /// code slots of the sequence, into `self.scores`; returns the best
    /// (score, q0) and the runner-up's score.
    ///
    /// Candidate q0 (code slot of the lowest-slot visible code line)
    /// from −(kk−1) to qn−1, scored by log-likelihood: code bits c = ±1
    /// at that offset give ln P(dots | c) = const + Σ c·L/2 with L the
    /// lines' summed dot log-likelihood ratios.
    /// All offsets at once, one line at a time: the same sum in the
    /// same order per offset as a per-offset dot product (so the same
    /// scores), but a vectorisable multiply-add along the offsets.
    fn score_offsets(&mut self, qn: usize, kk: usize) -> ((f32, i64), f32) {
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
        (b1, b2)
    }
}
