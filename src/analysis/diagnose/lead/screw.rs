//! A screw's cyclic terms as the lead check rebuilds them: the term and
//! its cross coupling at any candidate lead, their columns, and what the
//! model's harmonics contribute where the log cannot check them.

use super::super::data::Data;
use crate::analysis::AnalysisError;
use crate::model::term::parse_term_config;
use crate::model::terms::cyclic::{CyclicConfig, CyclicTerm, COUPLING_KIND};
use crate::model::{Axis, StageModel, Term};

use super::LeadCheck;

/// A cyclic term's configuration.
pub(super) fn cyclic_config(t: &dyn Term) -> Result<CyclicConfig, AnalysisError> {
    Ok(parse_term_config(t.name(), t.kind(), t.to_config()?)?)
}

/// One cyclic term of a screw, its configuration read once (the scan
/// rebuilds it at every candidate lead).
#[derive(Debug, Clone)]
pub(super) struct ScrewTerm {
    pub(super) name: String,
    /// `cross_coupling` (the error across the axis).
    pub(super) across: bool,
    pub(super) cfg: CyclicConfig,
}

impl ScrewTerm {
    /// The term at period `lead_um`.
    pub(super) fn at(&self, lead_um: f64) -> Result<CyclicTerm, AnalysisError> {
        let mut cfg = self.cfg.clone();
        cfg.period_um = lead_um;
        Ok(CyclicTerm::new(&self.name, self.across, cfg)?)
    }

    /// The term as the model has it.
    pub(super) fn own(&self) -> Result<CyclicTerm, AnalysisError> {
        self.at(self.cfg.period_um)
    }
}

/// The terms of one screw: the `leadscrew_cyclic` term `name` first, then
/// the cross-coupling terms of its axis at its period.
pub(super) fn screw_terms(
    model: &StageModel,
    name: &str,
    cfg: &CyclicConfig,
) -> Result<Vec<ScrewTerm>, AnalysisError> {
    let mut out = vec![ScrewTerm {
        name: name.to_string(),
        across: false,
        cfg: cfg.clone(),
    }];
    for t in model.terms().iter().filter(|t| t.kind() == COUPLING_KIND) {
        let c = cyclic_config(&**t)?;
        if c.axis == cfg.axis && (c.period_um - cfg.period_um).abs() < 1e-9 {
            out.push(ScrewTerm {
                name: t.name().to_string(),
                across: true,
                cfg: c,
            });
        }
    }
    Ok(out)
}

/// `model` with the screw of `check` (its term and followers) at
/// `lead_um`.
pub(super) fn with_lead(
    model: &StageModel,
    check: &LeadCheck,
    lead_um: f64,
) -> Result<StageModel, AnalysisError> {
    let mut m = model.clone();
    for name in std::iter::once(&check.term).chain(&check.followers) {
        if let Some(t) = model.term(name) {
            let st = ScrewTerm {
                name: name.clone(),
                across: t.kind() == COUPLING_KIND,
                cfg: cyclic_config(t)?,
            };
            m.replace_term(Box::new(st.at(lead_um)?))?;
        }
    }
    Ok(m)
}

/// RMS over the log's rows of the screw terms' contribution (at the
/// model's values, centred as every residual) to component `axis`.
pub(super) fn held_rms_um(d: &Data, terms: &[ScrewTerm], axis: Axis) -> Result<f64, AnalysisError> {
    let built: Vec<CyclicTerm> = terms.iter().map(ScrewTerm::own).collect::<Result<_, _>>()?;
    let mut v = vec![0.0; 2 * d.n];
    for (i, s) in d.states.iter().enumerate() {
        for t in &built {
            let c = t.contribution(s);
            v[2 * i] += c[0];
            v[2 * i + 1] += c[1];
        }
    }
    d.center(&mut v);
    let c = axis.index();
    let rows = (0..d.n).filter(|&i| !d.excluded[i]).count().max(1);
    Ok(((0..d.n).map(|i| v[2 * i + c].powi(2)).sum::<f64>() / rows as f64).sqrt())
}

/// The centred columns of `terms` rebuilt at `lead_um` (zero columns
/// dropped).
pub(super) fn columns_of(
    d: &Data,
    terms: &[ScrewTerm],
    lead_um: f64,
) -> Result<Vec<Vec<f64>>, AnalysisError> {
    let mut out = Vec::new();
    for t in terms {
        let t = t.at(lead_um)?;
        let k = t.params().len();
        let mut cols = vec![vec![0.0; 2 * d.n]; k];
        for (i, s) in d.states.iter().enumerate() {
            for (j, g) in t.jacobian(s).iter().enumerate().take(k) {
                cols[j][2 * i] = g[0];
                cols[j][2 * i + 1] = g[1];
            }
        }
        for mut c in cols {
            d.center(&mut c);
            if c.iter().any(|v| v.abs() > 1e-12) {
                out.push(c);
            }
        }
    }
    Ok(out)
}
