//! The tracking check: a code fix predicted from the previous frame,
//! confirmed or refused against its neighbouring offsets instead of
//! searched for. A file of its own: the warm path of a tracked decode,
//! with its own acceptance rules (any failure falls back to the search in
//! `mod.rs`).

use super::super::error::DecodeError;
use super::super::fine::Grid;
use super::presence::template_corr;
use super::{CoarseStage, CoarseThresholds, CodeFix};
use crate::frame::Frame;
use crate::pattern::sequence::LineSequence;

/// Code slots (3 lines each) either side of a tracked prediction that the
/// tracking check scores against: motions of up to ±24 periods between
/// frames that the continuity prediction missed show up as a better
/// neighbour; larger ones as a prediction that disagrees on about half the
/// bits.
const TRACK_SLOTS: i64 = 8;

impl CoarseStage {
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
}
