//! The held-out verdict on a scan's candidates: which minimum predicts
//! held-out data best, whether it beats the model's lead by the findings'
//! test and the model's lead does not add to it, the shortest equivalent
//! lead, its refinement on all rows and its standard error.

use super::super::fit::{paired_z, rms_comp};
use super::super::options::DiagnoseOptions;
use super::super::refine::golden_max;
use crate::analysis::AnalysisError;

use super::scan::Scan;
use super::{
    LeadCheck, LeadTest, LeadVerdict, JUDGED_MINIMA, OVERSAMPLE, RANK_STEPS, REFINE_STEPS,
};

/// Sum of squares of the finite entries (a pooled held-out vector holds
/// NaN where a row is not judged).
fn sse(v: &[f64]) -> f64 {
    v.iter().filter(|x| x.is_finite()).map(|x| x * x).sum()
}

/// Whether a held-out comparison passes the findings' test.
fn passes(z: f64, gain_pct: f64, opts: &DiagnoseOptions) -> bool {
    z >= opts.z_threshold && gain_pct >= opts.min_gain_pct
}

/// Held-out RMS gain of `after` over `before` on component `c`, %.
fn gain_pct(before: &[f64], after: &[f64], c: usize) -> f64 {
    let (b, a) = (rms_comp(before, c), rms_comp(after, c));
    if b > 0.0 {
        100.0 * (1.0 - a / b)
    } else {
        0.0
    }
}

/// The held-out test of `cand` against the model's lead (`model`: its
/// pooled held-out residual) on component `c`, and of the model's lead
/// added to it (`both`, when computed).
fn lead_test(
    model: &[f64],
    cand: &Judged,
    both: Option<&[f64]>,
    c: usize,
    opts: &DiagnoseOptions,
) -> LeadTest {
    let z = paired_z(model, &cand.heldout, c, 0.0).1;
    let gain = gain_pct(model, &cand.heldout, c);
    let both_z = both.map(|b| paired_z(&cand.heldout, b, c, 0.0).1);
    LeadTest {
        lead_um: cand.lead_um,
        heldout_rms_model_um: rms_comp(model, c),
        heldout_rms_um: rms_comp(&cand.heldout, c),
        z,
        gain_pct: gain,
        both_z,
        beats_model: passes(z, gain, opts),
        model_adds: both
            .zip(both_z)
            .is_some_and(|(b, bz)| passes(bz, gain_pct(&cand.heldout, b, c), opts)),
    }
}

/// A candidate lead and its pooled held-out residual.
struct Judged {
    lead_um: f64,
    heldout: Vec<f64>,
}

impl Scan<'_> {
    /// The scan, the held-out verdict and the refinement (module docs);
    /// fills `check`'s verdict, lead and candidate.
    pub(super) fn judge(
        &self,
        check: &mut LeadCheck,
        range: [f64; 2],
        opts: &DiagnoseOptions,
    ) -> Result<(), AnalysisError> {
        check.verdict = LeadVerdict::Kept;
        let step = 1.0 / (OVERSAMPLE * check.span_um);
        let c = check.axis.index();
        let model = self.heldout(&[check.model_lead_um])?;
        let Some(best) = self.best_minimum(range, step)? else {
            return Ok(());
        };
        // A lead must pass the test as scanned and again once refined:
        // one that does not as scanned (a stage with the model's lead) is
        // not refined into passing.
        let scanned = lead_test(&model, &best, None, c, opts);
        if !scanned.beats_model {
            check.candidate = Some(scanned);
            return Ok(());
        }
        let best = self.shortest_equivalent(best, range, step, c, opts)?;
        let lead_um = self.refine(best.lead_um, step, REFINE_STEPS, |p| self.joint_sse(p))?;
        let cand = Judged {
            lead_um,
            heldout: self.heldout(&[lead_um])?,
        };
        let both = self.heldout(&[check.model_lead_um, lead_um])?;
        let test = lead_test(&model, &cand, Some(&both), c, opts);
        if test.beats_model && !test.model_adds {
            check.verdict = LeadVerdict::Corrected;
            check.lead_um = lead_um;
            check.std_error_um = self.std_error_um(lead_um, step)?;
        }
        check.candidate = Some(test);
        Ok(())
    }

    /// Of the best local minima of the scan, the one that predicts
    /// held-out data best.
    fn best_minimum(&self, range: [f64; 2], step: f64) -> Result<Option<Judged>, AnalysisError> {
        let mut best: Option<Judged> = None;
        for lead_um in self.minima(range, step)? {
            let heldout = self.heldout(&[lead_um])?;
            if best
                .as_ref()
                .is_none_or(|b| sse(&heldout) < sse(&b.heldout))
            {
                best = Some(Judged { lead_um, heldout });
            }
        }
        Ok(best)
    }

    /// The best local minima of the coarse criterion over the candidate
    /// leads (evenly spaced in frequency by `step`), each refined within
    /// one step.
    fn minima(&self, range: [f64; 2], step: f64) -> Result<Vec<f64>, AnalysisError> {
        let (flo, fhi) = (1.0 / range[1], 1.0 / range[0]);
        let k = ((fhi - flo) / step).ceil().max(1.0) as usize;
        let freqs: Vec<f64> = (0..=k)
            .map(|j| flo + (fhi - flo) * j as f64 / k as f64)
            .collect();
        let s: Vec<f64> = freqs
            .iter()
            .map(|f| self.coarse_sse(1.0 / f))
            .collect::<Result<_, _>>()?;
        let mut idx: Vec<usize> = (0..s.len())
            .filter(|&j| (j == 0 || s[j] <= s[j - 1]) && (j + 1 == s.len() || s[j] <= s[j + 1]))
            .collect();
        idx.sort_by(|&a, &b| s[a].total_cmp(&s[b]));
        idx.truncate(JUDGED_MINIMA);
        idx.iter()
            .map(|&j| self.refine(1.0 / freqs[j], step, RANK_STEPS, |p| self.coarse_sse(p)))
            .collect()
    }

    /// The lead within one frequency `step` of `lead_um` with the
    /// smallest `sse` (golden section in frequency, `steps` of it);
    /// `lead_um` itself unless that is better.
    fn refine(
        &self,
        lead_um: f64,
        step: f64,
        steps: usize,
        sse: impl Fn(f64) -> Result<f64, AnalysisError>,
    ) -> Result<f64, AnalysisError> {
        let f0 = 1.0 / lead_um;
        let mut failed = None;
        let (f, neg) = golden_max((f0 - step).max(0.5 * f0), f0 + step, steps, |f| {
            -sse(1.0 / f).unwrap_or_else(|e| {
                failed = Some(e);
                f64::INFINITY
            })
        });
        if let Some(e) = failed {
            return Err(e);
        }
        Ok(if -neg < sse(lead_um)? {
            1.0 / f
        } else {
            lead_um
        })
    }

    /// `best`, or the shortest of its divisors (a half, a third) that
    /// predicts held-out data as well: the same error with fewer leads.
    fn shortest_equivalent(
        &self,
        best: Judged,
        range: [f64; 2],
        step: f64,
        c: usize,
        opts: &DiagnoseOptions,
    ) -> Result<Judged, AnalysisError> {
        for k in [3.0, 2.0] {
            let q = best.lead_um / k;
            if q < range[0] {
                continue;
            }
            let q = self.refine(q, step, RANK_STEPS, |p| self.coarse_sse(p))?;
            let heldout = self.heldout(&[q])?;
            let (_, z) = paired_z(&heldout, &best.heldout, c, 0.0);
            if !passes(z, gain_pct(&heldout, &best.heldout, c), opts) {
                return Ok(Judged {
                    lead_um: q,
                    heldout,
                });
            }
        }
        Ok(best)
    }

    /// 1-σ of a lead from the curvature of the joint fit's squared error
    /// in frequency: `var(f) = 2σ² / S''(f)` (the profile of the linear
    /// parameters), `σ² = S / (entries − columns)`.
    fn std_error_um(&self, lead_um: f64, step: f64) -> Result<Option<f64>, AnalysisError> {
        let f = 1.0 / lead_um;
        let h = 0.1 * step;
        let s0 = self.joint_sse(lead_um)?;
        let sp = self.joint_sse(1.0 / (f + h))?;
        let sm = self.joint_sse(1.0 / (f - h))?;
        let curvature = (sp - 2.0 * s0 + sm) / (h * h);
        let entries = self.d.r0.iter().filter(|v| **v != 0.0).count();
        let cols = self.others.len() + self.columns(lead_um)?.len();
        let dof = entries.saturating_sub(cols).max(1) as f64;
        let var_f = 2.0 * (s0 / dof) / curvature;
        Ok((curvature > 0.0 && var_f.is_finite()).then(|| var_f.sqrt() / (f * f)))
    }
}
