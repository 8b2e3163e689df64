//! Steps 4–6, the greedy search: each pass judges every candidate family
//! on held-out data, accepts the most useful significant one (or frees a
//! base parameter that carries it) and re-judges the findings so far.
//!
//! Why a file of its own: the loop's state (the findings, the table
//! tests, the baseline) and its rules (the pass bound, the drift and
//! table preferences) are apart from what is done with its findings.

use crate::model::StageModel;

use super::base::Base;
use super::data;
use super::family::Family;
use super::fit::{fold_base, paired_z, rms_comp, Verdict};
use super::ident;
use super::judge::{judge, passes_test, rejudge, with_findings, Accepted};
use super::refine::{refine_localized, refine_period};
use super::search::{self, columns, search, Spec};
use super::tables;
use super::DiagnoseOptions;

/// Steps 4–6, the greedy search: its inputs, and what it has found so
/// far.
pub(super) struct Greedy<'a> {
    d: &'a data::Data,
    model: &'a StageModel,
    opts: &'a DiagnoseOptions,
    fams: &'a [Family],
    pub(super) acc: Vec<Accepted>,
    /// The last held-out test of each table family (against the final
    /// model when it was not accepted).
    pub(super) table_tests: Vec<tables::TableTest>,
    /// The held-out RMS before any finding: the report's baseline.
    pub(super) baseline_rms: [f64; 2],
    /// The held-out residual of the last pass.
    pub(super) final_heldout: Vec<f64>,
}

impl<'a> Greedy<'a> {
    /// Each pass accepts a finding (re-judging the others, which may drop
    /// one), frees a carrier or stops. A dropped family can come back with
    /// hyper-parameters searched afresh; the bound on the passes guards
    /// against a finding and its replacement taking turns.
    pub(super) fn run(
        d: &'a data::Data,
        model: &'a StageModel,
        opts: &'a DiagnoseOptions,
        fams: &'a [Family],
        base: &mut Base,
    ) -> Self {
        let mut g = Greedy {
            d,
            model,
            opts,
            fams,
            acc: Vec::new(),
            table_tests: Vec::new(),
            baseline_rms: [0.0; 2],
            final_heldout: Vec::new(),
        };
        let mut passes = 0usize;
        loop {
            passes += 1;
            if !g.pass(base, passes) {
                break;
            }
        }
        g
    }

    /// One pass; `false` when the search stops.
    fn pass(&mut self, base: &mut Base, passes: usize) -> bool {
        let (d, model, opts) = (self.d, self.model, self.opts);
        let round: usize = self.acc.iter().map(|a| a.findings()).sum();
        let cols = with_findings(&base.cols, &self.acc, None);
        let judged_fams: &[Family] = if round >= opts.max_findings
            || passes > MAX_PASSES_PER_FINDING * opts.max_findings + 2
        {
            &[]
        } else {
            self.fams
        };
        let cands: Vec<(Family, Option<&[Vec<f64>]>)> =
            judged_fams.iter().map(|f| (*f, None)).collect();
        let (before, all_verdicts) = judge(d, &cols, &cands, model);
        let heldout = [rms_comp(&before, 0), rms_comp(&before, 1)];
        if self.acc.is_empty() {
            self.baseline_rms = heldout;
        }
        self.final_heldout = before;
        if judged_fams.is_empty() {
            return false;
        }
        trace_verdicts(&all_verdicts);
        let taken: Vec<Family> = self.acc.iter().map(|a| a.family).collect();
        tables::record(&mut self.table_tests, &all_verdicts, &taken);
        let mut verdicts = significant(all_verdicts, opts, round);
        let Some(best) = verdicts.first().map(|v| v.family) else {
            return false;
        };
        let best = prefer_linear_drift(best, &verdicts, opts);
        let Some(pos) = verdicts.iter().position(|v| v.family == best) else {
            return false;
        };
        let verdict = verdicts.swap_remove(pos);
        let Some(spec) = refined_spec(d, model, best, &cols) else {
            return false;
        };
        let spec_cols = columns(&spec, d, model);
        // A finding the model's own parameters can carry is a parameter
        // correction: a candidate the base selection left at the model's
        // value (its effect was hidden under a larger unmodelled one) whose
        // columns span the finding's is freed instead, and the search goes
        // on without spending a finding.
        let carriers = ident::carriers(d, &spec_cols, &base.dropped, &base.cand_cols);
        if !carriers.is_empty() {
            for j in carriers {
                base.free(j);
            }
        } else {
            self.accept(
                base,
                Accepted {
                    family: best,
                    spec,
                    verdict,
                    cols: spec_cols,
                },
            );
        }
        // The findings so far, against what the base and each other now
        // carry (a freed carrier can take over an earlier finding's error).
        rejudge(d, &base.cols, &mut self.acc, model, opts);
        true
    }

    /// Takes `finding`, with what it implies for the base.
    fn accept(&mut self, base: &mut Base, finding: Accepted) {
        // A reversal table is the lost motion relative to the axis's
        // play (zero at its first knot, `search::table_free_knots`):
        // with the play left at the model's value by the base
        // selection, the table's first knot would be the model's
        // play, a value nothing in the log measured. The play is
        // freed with it.
        for j in table_plays(&finding.spec, self.model, &base.cand_names, &base.dropped) {
            base.free(j);
        }
        let table = matches!(finding.spec, Spec::Table { .. } | Spec::Tables { .. });
        self.acc.push(finding);
        if table {
            base.fix_spanned_by(self.d, self.model, &self.acc);
        }
    }
}

/// Every held-out verdict of a pass, for `RUST_LOG=debug`: why a family
/// was or was not taken.
fn trace_verdicts(all_verdicts: &[Verdict]) {
    for v in all_verdicts {
        tracing::debug!(
            family = ?v.family,
            gain_pct = v.gain_pct,
            z = v.z,
            rms_before_um = v.rms_before,
            rms_after_um = v.rms_after,
            "diagnose: held-out verdict"
        );
    }
}

/// The verdicts that pass the findings' test, the most useful (largest
/// held-out reduction) first. `round` findings are taken already.
fn significant(all_verdicts: Vec<Verdict>, opts: &DiagnoseOptions, round: usize) -> Vec<Verdict> {
    let mut verdicts: Vec<Verdict> = all_verdicts
        .into_iter()
        .filter(|v| passes_test(v, opts))
        // Two tables at once are two findings: only within the cap.
        .filter(|v| !matches!(v.family, Family::Tables { .. }) || round + 2 <= opts.max_findings)
        .collect();
    verdicts.sort_by(|a, b| b.reduction.total_cmp(&a.reduction));
    verdicts
}

/// A quadratic drift must beat the linear one on held-out data: `best`,
/// or the linear drift when it does not.
fn prefer_linear_drift(best: Family, verdicts: &[Verdict], opts: &DiagnoseOptions) -> Family {
    if let Family::Drift {
        comp,
        quadratic: true,
    } = best
    {
        let lin = Family::Drift {
            comp,
            quadratic: false,
        };
        if let (Some(q), Some(l)) = (
            verdicts.iter().find(|v| v.family == best),
            verdicts.iter().find(|v| v.family == lin),
        ) {
            let (_, z) = paired_z(&l.after, &q.after, comp.index(), 0.0);
            if z < opts.z_threshold {
                return lin;
            }
        }
    }
    best
}

/// The accepted family's hyper-parameters, from all the data (`cols`:
/// the base with the findings so far).
fn refined_spec(
    d: &data::Data,
    model: &StageModel,
    best: Family,
    cols: &[Vec<f64>],
) -> Option<Spec> {
    let all = vec![true; d.n];
    let fb = fold_base(d, cols, all.clone());
    let spec = search(best, d, &fb.resid, &all)?;
    Some(refine_localized(
        refine_period(spec, d, cols, model),
        d,
        cols,
        model,
    ))
}

/// Indices in `cand_names` of the plays (`backlash_um`) a reversal table
/// in `spec` is relative to, among the `dropped` candidates (left at the
/// model's value by the base selection).
fn table_plays(
    spec: &Spec,
    model: &StageModel,
    cand_names: &[String],
    dropped: &[usize],
) -> Vec<usize> {
    let mut out = Vec::new();
    for s in spec.clone().split() {
        let Spec::Table {
            axis,
            lost_motion: true,
            ..
        } = s
        else {
            continue;
        };
        let Some(t) = search::backlash_term_of(model, axis) else {
            continue;
        };
        let play = format!("{}.backlash_um", t.name());
        out.extend(dropped.iter().copied().filter(|&j| cand_names[j] == play));
    }
    out.sort_unstable();
    out.dedup();
    out
}

/// Passes of the greedy loop per allowed finding (each pass accepts a
/// finding, frees a carrier, or stops): a guard against a finding and its
/// replacement taking turns, above what a log uses (one per finding, one
/// per freed carrier, one per dropped finding).
const MAX_PASSES_PER_FINDING: usize = 3;
