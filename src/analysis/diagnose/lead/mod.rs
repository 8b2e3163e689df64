//! The screw lead as a parameter the log can correct (before step 2).
//!
//! A `leadscrew_cyclic` term's harmonics repeat every `period_um`, the
//! screw's lead. The base fit frees the harmonics' amplitudes but not the
//! period (it is not linear), so a stage whose screw has another lead (a
//! 0.5 mm micrometer against the model's 0.4 mm PI screw) gets amplitudes
//! at the wrong period, and its own cyclic error is left to the search as
//! a single-harmonic "periodic error". The lead is one number the log can
//! measure when it spans enough of it, so it is checked here, before the
//! base fit, and the rest of the diagnosis runs on the model with the lead
//! the log supports.
//!
//! **When the log can tell the lead** (`Sampling::range`): it spans at
//! least two of the model's leads along the axis and its spacing gives at
//! least four points per lead. Then candidate leads from a quarter to
//! eight times the model's, clipped to the shortest period with four
//! points and the longest the log spans twice, are scanned evenly in
//! frequency (two candidates per periodogram resolution `1/span`): each
//! candidate's columns (every harmonic, both directions, of the term and
//! of the cross-coupling terms of the same screw) are fitted to the
//! residual of the model without them, the other base parameters profiled
//! out. The best local minima are refined and **judged on the held-out
//! folds diagnose uses** (the base and the candidate fitted on the other
//! folds). A different lead is adopted only when (a) it predicts held-out
//! data better than the model's lead by the findings' own test (paired
//! `z ≥ z_threshold`, gain ≥ `min_gain_pct`) and (b) the model's lead
//! added to it does not predict better by the same test: otherwise the
//! stage has a periodic error besides its screw's, and that is the
//! search's to find (a physical stage's 800 µm bearing error next to its
//! 400 µm screw reads as an "800 µm lead" that drops the screw's second
//! harmonic). A lead whose divisor (half, a third) predicts held-out data
//! as well is replaced by it: a sinusoid at 500 µm is equally the second
//! harmonic of a 1000 µm lead, and the shortest lead that carries the
//! error is the one the data show. The adopted lead is refined on all
//! rows (golden section against the joint fit) with a standard error from
//! the curvature of that fit's squared error.
//!
//! **When it cannot**, the check says so with the numbers, and what scan
//! would resolve it (`LeadCheck::sentence`). Over fewer than two leads
//! the screw's harmonics are not fitted at all ([`held_screw_reason`],
//! used by `super::unresolved`): a sinusoid over 1.1 periods is a bow of
//! the travel as much as a periodic error, and on a stage whose lead is
//! unknown a fitted 400 µm harmonic would be presented as a correction of
//! a screw the stage may not have. Over two leads or more, sampled too
//! coarsely to check the lead, the harmonics are fitted at the model's
//! lead, taken as given (the sentence says so): the log still measures
//! them there, and a claim held at the model's values that the log
//! contradicts would stay in every residual (a grid at 200 µm pitch whose
//! stage has no cyclic error kept the model's 1.3 µm of it, and no map
//! could be told from it).
//!
//! * `screw`: a screw's terms (the `leadscrew_cyclic` term and its cross
//!   coupling) rebuilt at any lead, and their columns;
//! * `scan`: the scan's fixed parts (the other base columns profiled out
//!   per fold) and its criteria at a candidate lead;
//! * `judge`: the held-out verdict, the refinement and the standard error;
//! * `sentence`: the statement for a metrologist.

mod judge;
mod scan;
mod screw;
mod sentence;
#[cfg(test)]
mod tests;

use serde::Serialize;

use super::corrections::ParamCorrection;
use super::data::{self, Data};
use super::family::Family;
use super::options::DiagnoseOptions;
use super::search::{base_kind_selected, table_knots};
use crate::analysis::AnalysisError;
use crate::model::terms::cyclic::{CyclicConfig, COUPLING_KIND, LEADSCREW_KIND};
use crate::model::{Axis, StageModel, Term};

use scan::Scan;
use screw::{cyclic_config, held_rms_um, screw_terms, with_lead};
use sentence::sentence;

/// What the log says about a screw's lead.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum LeadVerdict {
    /// Another lead predicts held-out data better: the extended model
    /// carries it.
    Corrected,
    /// Scanned; no other lead predicts held-out data better.
    Kept,
    /// The log cannot tell the lead (too short a span or too coarse a
    /// spacing); the sentence says what would.
    NotChecked,
}

/// The held-out test of a candidate lead against the model's.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct LeadTest {
    /// The candidate lead, µm.
    pub lead_um: f64,
    /// Held-out RMS of the axis's component with the model's lead, µm.
    pub heldout_rms_model_um: f64,
    /// Held-out RMS with the candidate lead, µm.
    pub heldout_rms_um: f64,
    /// Paired z of the candidate over the model's lead.
    pub z: f64,
    /// Held-out RMS gain of the candidate, %.
    pub gain_pct: f64,
    /// Paired z of the model's lead added to the candidate over the
    /// candidate alone (not computed when the candidate does not predict
    /// held-out data better than the model's lead at all).
    pub both_z: Option<f64>,
    /// Whether the candidate passes the findings' held-out test over the
    /// model's lead.
    pub beats_model: bool,
    /// Whether the model's lead added to the candidate passes it over the
    /// candidate alone: two periodic errors, not another lead.
    pub model_adds: bool,
}

/// One `leadscrew_cyclic` term's lead as the log measured it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LeadCheck {
    /// The term (e.g. `x_cyclic`).
    pub term: String,
    /// Its axis.
    pub axis: Axis,
    /// Cross-coupling terms of the same screw (same axis and period),
    /// whose period follows the lead.
    pub followers: Vec<String>,
    /// The model's lead, µm.
    pub model_lead_um: f64,
    /// What the log says.
    pub verdict: LeadVerdict,
    /// The lead the diagnosis (and the extended model) uses, µm.
    pub lead_um: f64,
    /// 1-σ standard error of a corrected lead, µm.
    pub std_error_um: Option<f64>,
    /// The span of the axis's positions, µm.
    pub span_um: f64,
    /// The axis's sampling spacing (`data::sampling_spacing_um`), µm.
    pub spacing_um: Option<f64>,
    /// Shortest and longest candidate lead scanned, µm.
    pub scanned_um: Option<[f64; 2]>,
    /// The best candidate other than the model's lead, judged held out.
    pub candidate: Option<LeadTest>,
    /// RMS at the log's points of what the screw's harmonics, held at the
    /// model's values because the log spans fewer than two leads,
    /// contribute to the prediction of the axis's component, µm: a claim
    /// of the model the log can neither confirm nor correct.
    pub held_contribution_rms_um: Option<f64>,
    /// The span a scan needs to tell the model's lead (two leads), µm.
    pub needs_span_um: f64,
    /// The spacing it needs (four points per lead), µm.
    pub needs_step_um: f64,
    /// The statement for a metrologist.
    pub sentence: String,
}

/// The leads checked, the model with the leads the log supports, and a
/// parameter correction per corrected lead.
pub(super) struct Leads {
    pub(super) model: StageModel,
    pub(super) checks: Vec<LeadCheck>,
    pub(super) corrections: Vec<ParamCorrection>,
}

/// The name a corrected lead has among the parameter corrections
/// (`x_cyclic.period_um`): the term's own key for it.
pub(super) const LEAD_PARAM: &str = "period_um";

/// Leads a log must span to tell a screw's lead (and its harmonics from
/// a bow of the travel).
pub(super) const LEADS_SPANNED: f64 = 2.0;
/// Points per lead a log needs to scan leads around it.
const POINTS_PER_LEAD: f64 = 4.0;
/// Candidates range from the model's lead divided by this ...
const SHORTEST_FACTOR: f64 = 4.0;
/// ... to the model's lead times this.
const LONGEST_FACTOR: f64 = 8.0;
/// Candidates per periodogram resolution (`1/span`): a peak is a
/// resolution wide, and each of the best minima is refined within a step.
const OVERSAMPLE: f64 = 2.0;
/// Local minima of the scan judged on held-out folds.
const JUDGED_MINIMA: usize = 3;
/// Golden-section steps of the refinement of the lead reported (the
/// interval of two scan steps to 1e-3 of it).
const REFINE_STEPS: usize = 16;
/// Golden-section steps of the refinement of a scan's minimum before it is
/// judged held out (to 2 % of two scan steps: enough to rank them).
const RANK_STEPS: usize = 8;

/// Checks the lead of every `leadscrew_cyclic` term on a measured axis
/// (see the module docs); `model` comes back with the corrected leads.
pub(super) fn check_leads(
    d: &Data,
    model: &StageModel,
    opts: &DiagnoseOptions,
) -> Result<Leads, AnalysisError> {
    if !base_kind_selected(&opts.base_free_kinds, LEADSCREW_KIND) {
        return Ok(Leads {
            model: model.clone(),
            checks: Vec::new(),
            corrections: Vec::new(),
        });
    }
    let screws = measured_screws(d, model)?;
    let mut checks = check_in_turn(d, model, &screws, opts)?;
    if screws.len() > 1 && checks.iter().any(LeadCheck::corrected) {
        checks = check_against_the_others(d, model, &screws, &checks, opts)?;
    }
    let mut corrected = model.clone();
    for c in &checks {
        corrected = applied(&corrected, c)?;
    }
    Ok(Leads {
        model: corrected,
        corrections: checks
            .iter()
            .filter(|c| c.corrected())
            .map(correction)
            .collect(),
        checks,
    })
}

/// The `leadscrew_cyclic` terms of `model` on an axis the log measures
/// (a screw whose axis is not measured has nothing to be checked by).
fn measured_screws(
    d: &Data,
    model: &StageModel,
) -> Result<Vec<(String, CyclicConfig)>, AnalysisError> {
    let mut out = Vec::new();
    for t in model.terms().iter().filter(|t| t.kind() == LEADSCREW_KIND) {
        let cfg = cyclic_config(&**t)?;
        if d.measured[cfg.axis.index()] {
            out.push((t.name().to_string(), cfg));
        }
    }
    Ok(out)
}

/// One screw after the other, each against the leads found before it.
fn check_in_turn(
    d: &Data,
    model: &StageModel,
    screws: &[(String, CyclicConfig)],
    opts: &DiagnoseOptions,
) -> Result<Vec<LeadCheck>, AnalysisError> {
    let mut m = model.clone();
    let mut checks = Vec::new();
    for (name, cfg) in screws {
        let check = check_one(d, &m, name, cfg, opts)?;
        m = applied(&m, &check)?;
        checks.push(check);
    }
    Ok(checks)
}

/// Each screw again, against every other at the lead `first` found. Why:
/// a 2-D log's y screw couples into x, so x's held-out figures with y
/// still at the model's lead carry y's coupling at the wrong period.
fn check_against_the_others(
    d: &Data,
    model: &StageModel,
    screws: &[(String, CyclicConfig)],
    first: &[LeadCheck],
    opts: &DiagnoseOptions,
) -> Result<Vec<LeadCheck>, AnalysisError> {
    let mut all = model.clone();
    for c in first {
        all = applied(&all, c)?;
    }
    let mut checks = Vec::new();
    for (name, cfg) in screws {
        // This screw back at the model's lead, the others as found.
        let mut m = all.clone();
        for t in screw_terms(model, name, cfg)? {
            m.replace_term(Box::new(t.own()?))?;
        }
        checks.push(check_one(d, &m, name, cfg, opts)?);
    }
    Ok(checks)
}

impl LeadCheck {
    /// Whether the log corrected the lead.
    fn corrected(&self) -> bool {
        self.verdict == LeadVerdict::Corrected
    }
}

/// `model` with the lead `check` found, when it corrected one.
fn applied(model: &StageModel, check: &LeadCheck) -> Result<StageModel, AnalysisError> {
    if check.verdict == LeadVerdict::Corrected {
        with_lead(model, check, check.lead_um)
    } else {
        Ok(model.clone())
    }
}

/// The sampling of one axis, as the lead check reads it.
#[derive(Debug, Clone, Copy)]
struct Sampling {
    span_um: f64,
    spacing_um: Option<f64>,
}

impl Sampling {
    fn of(d: &Data, axis: Axis) -> Self {
        let pos = data::distinct_positions(d, axis);
        Sampling {
            span_um: data::span_um(&pos),
            spacing_um: data::sampling_spacing_um(&pos),
        }
    }

    /// The candidate leads `[shortest, longest]` the log can tell around
    /// `lead_um`, or `None` when it cannot tell `lead_um` itself.
    fn range(&self, lead_um: f64) -> Option<[f64; 2]> {
        let spacing = self.spacing_um?;
        let tells = self.span_um >= LEADS_SPANNED * lead_um && spacing <= lead_um / POINTS_PER_LEAD;
        tells.then(|| {
            [
                (lead_um / SHORTEST_FACTOR).max(POINTS_PER_LEAD * spacing),
                (lead_um * LONGEST_FACTOR).min(self.span_um / LEADS_SPANNED),
            ]
        })
    }

    /// Whether a screw's harmonics at `lead_um` are held at the model's
    /// values for the lead check's reason (the log spans fewer than
    /// [`LEADS_SPANNED`] leads) and not for aliasing, whose contribution
    /// the base fit states on its own
    /// (`Diagnosis::aliased_contribution_rms_um`). A log long enough but
    /// too coarse to check the lead has them fitted at the model's lead.
    fn holds(&self, lead_um: f64) -> bool {
        let aliased = self.spacing_um.is_some_and(|s| lead_um < 2.0 * s);
        self.span_um < LEADS_SPANNED * lead_um && !aliased
    }
}

/// Why a screw's cyclic term (`leadscrew_cyclic` or `cross_coupling`) is
/// held at the model's values, or `None`: the log spans fewer than
/// [`LEADS_SPANNED`] of the screw's leads along its axis. (A longer log
/// sampled too coarsely to check the lead has the harmonics fitted at the
/// model's lead: see the module's notes.)
///
/// Why the whole term, every harmonic: over 1.1 periods a fitted
/// sinusoid is a bow of the travel as much as a periodic error, and it
/// predicts held-out cycles better for that reason alone. On a flexure
/// pushed by a 500 µm micrometer over 450 µm, the model's 400 µm
/// harmonics came out at 10σ and were listed as "corrections" of a screw
/// the stage does not have; its bow is the search's (a table, a localized
/// feature) and the scale's. The higher harmonics belong to the same lead,
/// which the log cannot check either, so they are held with it, however
/// finely the log samples them.
pub(super) fn held_screw_reason(d: &Data, term: &dyn Term) -> Option<String> {
    if term.kind() != LEADSCREW_KIND && term.kind() != COUPLING_KIND {
        return None;
    }
    let cfg = cyclic_config(term).ok()?;
    let (lead_um, axis) = (cfg.period_um, cfg.axis);
    let s = Sampling::of(d, axis);
    if s.range(lead_um).is_some() {
        return None;
    }
    (s.span_um < LEADS_SPANNED * lead_um).then(|| {
        format!(
            "the log spans {} µm of {axis}, less than two screw leads ({} µm): the screw's harmonics cannot be told from a bow of the travel, nor its lead checked",
            sentence::um(s.span_um),
            sentence::um(LEADS_SPANNED * lead_um)
        )
    })
}

/// The check of one screw.
fn check_one(
    d: &Data,
    model: &StageModel,
    name: &str,
    cfg: &CyclicConfig,
    opts: &DiagnoseOptions,
) -> Result<LeadCheck, AnalysisError> {
    let terms = screw_terms(model, name, cfg)?;
    let sampling = Sampling::of(d, cfg.axis);
    let mut check = LeadCheck {
        term: name.to_string(),
        axis: cfg.axis,
        followers: terms.iter().skip(1).map(|t| t.name.clone()).collect(),
        model_lead_um: cfg.period_um,
        verdict: LeadVerdict::NotChecked,
        lead_um: cfg.period_um,
        std_error_um: None,
        span_um: sampling.span_um,
        spacing_um: sampling.spacing_um,
        scanned_um: sampling.range(cfg.period_um),
        candidate: None,
        held_contribution_rms_um: sampling
            .holds(cfg.period_um)
            .then(|| held_rms_um(d, &terms, cfg.axis))
            .transpose()?,
        needs_span_um: LEADS_SPANNED * cfg.period_um,
        needs_step_um: cfg.period_um / POINTS_PER_LEAD,
        sentence: String::new(),
    };
    if let Some(range) = check.scanned_um {
        let scan = Scan::new(d, model, &terms, opts)?;
        scan.judge(&mut check, range, opts)?;
    }
    check.sentence = sentence(&check);
    Ok(check)
}

/// Appends to each table finding (a non-linearity or reversal table) on
/// an axis whose screw harmonics are held (the log cannot check the
/// lead) what they contribute: the table holds the difference between
/// the stage and the model's claim.
pub(super) fn note_held(findings: &mut [super::Finding], checks: &[LeadCheck]) {
    use crate::analysis::FindingKind;
    for f in findings.iter_mut().filter(|f| {
        matches!(
            f.kind,
            FindingKind::Nonlinearity | FindingKind::ReversalVaries
        )
    }) {
        for c in checks.iter().filter(|c| c.axis == f.component) {
            if let Some(h) = c.held_contribution_rms_um {
                f.explanation.push_str(&format!(
                    "; these values also correct the model's own screw harmonics ({}, held at the model's values: the log cannot check the lead), which contribute {h:.3} µm rms at the log's points: the table holds the stage's shape less that claim",
                    c.term
                ));
            }
        }
    }
}

/// A non-linearity table family for each axis whose screw harmonics are
/// held because the log spans fewer than two leads, where the base would
/// otherwise have fitted them as a curve over the travel (a span of at
/// least half a lead, `super::LONGEST_PERIOD_SPANS`), not yet among
/// `fams`. Why: over 1.1 leads the freed harmonics carried the travel's
/// shape (the 40-step flexure log: 2.91 → 0.51 µm held out), and that
/// shape needs a carrier that says what it is, a departure from the line
/// along the travel judged held out like every finding, not the
/// harmonics of a screw the log cannot check. Over a shorter span the
/// harmonics were never fitted and the search's own families read the
/// shape as before.
pub(super) fn shape_tables(checks: &[LeadCheck], d: &Data, fams: &[Family]) -> Vec<Family> {
    let mut out = Vec::new();
    let replaces_a_curve = |c: &&LeadCheck| {
        c.span_um < c.needs_span_um && c.span_um * super::LONGEST_PERIOD_SPANS >= c.model_lead_um
    };
    for c in checks.iter().filter(replaces_a_curve) {
        let f = Family::Table {
            axis: c.axis,
            lost_motion: false,
        };
        if !fams.contains(&f) && !out.contains(&f) && table_knots(d, c.axis).is_some() {
            out.push(f);
        }
    }
    out
}

/// The parameter correction of a corrected lead.
fn correction(check: &LeadCheck) -> ParamCorrection {
    let se = check.std_error_um.unwrap_or(f64::NAN);
    ParamCorrection {
        term: check.term.clone(),
        kind: LEADSCREW_KIND.into(),
        parameter: LEAD_PARAM.into(),
        unit: "µm".into(),
        model_value: check.model_lead_um,
        fitted_value: check.lead_um,
        std_error: se,
        significant: !se.is_finite()
            || (check.lead_um - check.model_lead_um).abs()
                >= super::corrections::SIGNIFICANT_SIGMAS * se,
        sentence: check.sentence.clone(),
        total_value: None,
    }
}
