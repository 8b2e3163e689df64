//! The lead scan's fixed parts: the log's residual without the screw, the
//! other base columns profiled out once, per fold and on every row, and
//! the criteria evaluated at a candidate lead (the cheap one the scan
//! ranks by, the joint fit, the pooled held-out residual).

use super::super::data::Data;
use super::super::fit::{fit_with, fold_base, keep_heldout, sse_after, unjudged, FoldBase};
use super::super::ident;
use super::super::options::DiagnoseOptions;
use super::super::search::base_columns;
use crate::analysis::AnalysisError;
use crate::model::terms::cyclic::CyclicTerm;
use crate::model::{StageModel, Term};

use super::screw::{columns_of, ScrewTerm};

/// The base columns a lead scan profiles out: every base parameter but
/// the screw's own that the log resolves (`super::aliased_period`,
/// `super::unresolved`) and separates (`ident`). Not the base fit's
/// held-out selection (`fit::select_base`): the model's lead and every
/// candidate are judged against the same columns, so what the selection
/// would drop costs both sides alike, and the selection (run twice per
/// screw) cost as much as the scan itself.
fn other_columns(
    d: &Data,
    model: &StageModel,
    terms: &[ScrewTerm],
    opts: &DiagnoseOptions,
) -> Vec<Vec<f64>> {
    let (names, cols) = base_columns(d, model, &opts.base_free_kinds);
    let own = |n: &str| terms.iter().any(|t| n.starts_with(&format!("{}.", t.name)));
    let (names, cols): (Vec<String>, Vec<Vec<f64>>) = names
        .into_iter()
        .zip(cols)
        .filter(|(n, _)| {
            !own(n)
                && super::super::aliased_period(d, model, n).is_none()
                && super::super::unresolved(d, model, n).is_none()
        })
        .unzip();
    let (separable, _) = ident::identifiable(d, model, &names, &cols);
    separable.into_iter().map(|j| cols[j].clone()).collect()
}

/// Each entry of `active` (`2i + c`) with a compact index of its
/// centring group (`Data::group`; `None`: not centred), and the number
/// of groups.
fn compact_groups(d: &Data, active: &[usize]) -> (Vec<(usize, Option<usize>)>, usize) {
    let mut ids: std::collections::HashMap<usize, usize> = Default::default();
    let out = active
        .iter()
        .map(|&e| {
            let g = d.group[e / 2][e % 2].map(|g| {
                let next = ids.len();
                *ids.entry(g).or_insert(next)
            });
            (e, g)
        })
        .collect();
    (out, ids.len())
}

/// A lead scan's fixed parts: the log with the screw's own contribution
/// put back into its residual, the other base columns, and their fits.
pub(super) struct Scan<'a> {
    pub(super) d: Data,
    /// The screw's terms, the `leadscrew_cyclic` term first (the scan's
    /// criterion uses its columns alone).
    pub(super) terms: &'a [ScrewTerm],
    /// Entries (`2i + c`) its columns can be non-zero at (the axis's own
    /// component, rows fitted, blocks where the axis moves), with the
    /// centring group of each (`Data::group`; compact index).
    pub(super) active: Vec<(usize, Option<usize>)>,
    /// Groups of `active`.
    pub(super) groups: usize,
    /// The others' residual over every row, at `active`.
    pub(super) coarse_resid: Vec<f64>,
    pub(super) others: Vec<Vec<f64>>,
    /// Per fold: the other columns fitted on the training rows.
    pub(super) folds: Vec<FoldBase>,
    /// The other columns fitted on every row.
    pub(super) all: FoldBase,
}

impl<'a> Scan<'a> {
    pub(super) fn new(
        d: &Data,
        model: &StageModel,
        terms: &'a [ScrewTerm],
        opts: &DiagnoseOptions,
    ) -> Result<Self, AnalysisError> {
        let built: Vec<CyclicTerm> = terms.iter().map(ScrewTerm::own).collect::<Result<_, _>>()?;
        // The residual of `model` (the other screws at the leads found
        // so far, not `d`'s model) without this screw's own terms.
        let mut dn = d.clone();
        let mut r = vec![0.0; 2 * d.n];
        for (i, s) in d.states.iter().enumerate() {
            let o = model.observed_position(s);
            r[2 * i] = d.meas[i][0] - o.x_um;
            r[2 * i + 1] = d.meas[i][1] - o.y_um;
            for t in &built {
                let c = t.contribution(s);
                r[2 * i] += c[0];
                r[2 * i + 1] += c[1];
            }
        }
        dn.center(&mut r);
        dn.r0 = r;
        let others = other_columns(&dn, model, terms, opts);
        let folds = (0..dn.nfolds)
            .map(|f| fold_base(&dn, &others, dn.fold.iter().map(|&k| k != f).collect()))
            .collect();
        let all = fold_base(&dn, &others, vec![true; dn.n]);
        let cols0 = columns_of(&dn, &terms[..1], terms[0].cfg.period_um)?;
        let active: Vec<usize> = (0..2 * dn.n)
            .filter(|&e| cols0.iter().any(|c| c[e] != 0.0))
            .collect();
        let coarse_resid = active.iter().map(|&e| all.resid[e]).collect();
        let (active, groups) = compact_groups(&dn, &active);
        Ok(Scan {
            d: dn,
            terms,
            active,
            groups,
            coarse_resid,
            others,
            folds,
            all,
        })
    }

    /// The screw's centred columns at `lead_um` (its term and followers;
    /// zero columns dropped).
    pub(super) fn columns(&self, lead_um: f64) -> Result<Vec<Vec<f64>>, AnalysisError> {
        columns_of(&self.d, self.terms, lead_um)
    }

    /// Squared error left on every row when the screw at `lead_um` is
    /// fitted to the residual of the other columns (the scan's criterion:
    /// cheap, the others profiled out once).
    pub(super) fn coarse_sse(&self, lead_um: f64) -> Result<f64, AnalysisError> {
        Ok(sse_after(
            &self.coarse_resid,
            &self.coarse_columns(lead_um)?,
        ))
    }

    /// The screw term's columns at `lead_um` at the `active` entries
    /// only, centred per group there: what [`columns_of`] gives at those
    /// entries (the others are zero for every lead), at a fraction of the
    /// cost (the scan evaluates hundreds of leads).
    pub(super) fn coarse_columns(&self, lead_um: f64) -> Result<Vec<Vec<f64>>, AnalysisError> {
        let t = self.terms[0].at(lead_um)?;
        let k = t.params().len();
        let mut cols = vec![vec![0.0; self.active.len()]; k];
        for (a, &(e, _)) in self.active.iter().enumerate() {
            for (j, g) in t.jacobian(&self.d.states[e / 2]).iter().enumerate().take(k) {
                cols[j][a] = g[e % 2];
            }
        }
        for c in &mut cols {
            let mut sum = vec![(0.0, 0usize); self.groups];
            for (v, &(_, g)) in c.iter().zip(&self.active) {
                if let Some(g) = g {
                    sum[g].0 += v;
                    sum[g].1 += 1;
                }
            }
            for (v, &(_, g)) in c.iter_mut().zip(&self.active) {
                if let Some(g) = g {
                    *v -= sum[g].0 / sum[g].1 as f64;
                }
            }
        }
        Ok(cols)
    }

    /// Squared error left on every row by the joint fit of the others and
    /// the screw at `lead_um`.
    pub(super) fn joint_sse(&self, lead_um: f64) -> Result<f64, AnalysisError> {
        let cols = self.columns(lead_um)?;
        let (resid, _) = fit_with(&self.d, &self.others, &self.all, &cols);
        Ok(resid.iter().map(|v| v * v).sum())
    }

    /// Pooled held-out residual with the screw at each of `leads_um`
    /// (together: one lead, or the model's and a candidate's).
    pub(super) fn heldout(&self, leads_um: &[f64]) -> Result<Vec<f64>, AnalysisError> {
        let mut cols = Vec::new();
        for &p in leads_um {
            cols.extend(self.columns(p)?);
        }
        let mut out = unjudged(&self.d);
        for fb in &self.folds {
            let (resid, _) = fit_with(&self.d, &self.others, fb, &cols);
            keep_heldout(&self.d, &mut out, &resid, &fb.train);
        }
        Ok(out)
    }
}
