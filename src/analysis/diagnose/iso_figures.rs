//! ISO 230-2 figures of a log that is a complete bidirectional test of an
//! axis, as the standard defines them and a test report computes them (on
//! every visit), and without the visits the noise section left out.
//!
//! Why a file of its own: the figures are the standard's arithmetic
//! (`metrology::iso230_2`) applied to the replayed rows; the noise section
//! (`noise.rs`) only reports them beside its own, model-free statistics.

use serde::Serialize;

use crate::charact::log::MeasurementLog;
use crate::metrology::iso230_2::{self, Approach, Observation, TargetFigures};
use crate::model::Axis;

use super::data::Data;

/// ISO 230-2 figures of a complete bidirectional test in the log.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct IsoFigures {
    /// Cycles.
    pub cycles: usize,
    /// Visits the figures are computed from.
    pub visits: usize,
    /// When a target's forward and backward arrivals stopped at different
    /// positions (a test program's offset): the largest such distance,
    /// µm. They are paired as one target (as the test's own report pairs
    /// them by index); the log is then not an ISO 230-2 test in the
    /// standard's sense, whose reversal is read at one position.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub paired_within_um: Option<f64>,
    /// `R`, bidirectional repeatability, µm.
    pub r_um: f64,
    /// `R↑ = max 4 s↑_i`, unidirectional repeatability (forward), µm.
    pub r_up_um: f64,
    /// `R↓ = max 4 s↓_i`, unidirectional repeatability (backward), µm.
    pub r_down_um: f64,
    /// `B = max |B_i|`, reversal value, µm (≥ 0).
    pub b_um: f64,
    /// `B̄ = mean B_i`, mean reversal value, µm, signed: `B_i = x̄↑ − x̄↓`
    /// (measured − target), negative when the platform trails the command.
    pub mean_b_um: f64,
    /// `E`, bidirectional systematic positional deviation, µm.
    pub e_um: f64,
    /// `M`, range of the mean bidirectional positional deviation, µm.
    pub m_um: f64,
    /// `A`, accuracy, µm.
    pub a_um: f64,
    /// Per target (increasing): the mean deviations `x̄↑_i`, `x̄↓_i` and
    /// their `s↑_i`, `s↓_i` (measured − target), what ISO 230-2's
    /// deviation chart draws (`plot::diagnosis`). Not in the JSON report,
    /// which gives the axis figures.
    #[serde(skip)]
    pub per_target: Vec<TargetFigures>,
}

/// ISO 230-2 figures of axis `c` when the log is a complete bidirectional
/// test of it (only `c` moves, every target approached both ways in every
/// cycle); `None` otherwise. `without_excluded`: the excluded visits
/// (outliers) left out, each target's figures from the visits it keeps.
pub(super) fn iso_figures(
    log: &MeasurementLog,
    d: &Data,
    c: Axis,
    without_excluded: bool,
) -> Option<IsoFigures> {
    let ci = c.index();
    let other = 1 - ci;
    let targets = super::data::targets_of(&super::data::distinct_positions(d, c));
    let mut obs = Vec::new();
    for (i, r) in log.records.iter().enumerate().take(d.n) {
        if d.moving[i][other] || !d.moving[i][ci] {
            return None;
        }
        if without_excluded && d.excluded.get(i).copied().unwrap_or(false) {
            continue;
        }
        let approach = match d.approach[i][ci] {
            s if s > 0.0 => Approach::Positive,
            s if s < 0.0 => Approach::Negative,
            _ => continue,
        };
        let (target_um, measured_um) = if ci == 0 {
            (r.x_target_um, r.x_meas_um)
        } else {
            (r.y_target_um, r.y_meas_um)
        };
        // A target whose approaches stop at slightly different positions
        // is one target (paired by `data::targets_of`), its deviation
        // from the position it stopped at.
        let dev = measured_um - target_um;
        let t = targets
            .index_of(target_um)
            .map_or(target_um, |k| targets.centre(k));
        obs.push(Observation {
            target_um: t,
            cycle: r.cycle,
            approach,
            measured_um: t + dev,
        });
    }
    let f = if without_excluded {
        // The complete test must exist before its gaps are ours to leave.
        iso_figures(log, d, c, false)?;
        iso230_2::evaluate_allowing_gaps(&obs).ok()?
    } else {
        iso230_2::evaluate(&obs).ok()?
    };
    Some(IsoFigures {
        cycles: f.cycles,
        visits: obs.len(),
        paired_within_um: (targets.widest_um() > 1e-3).then(|| targets.widest_um()),
        r_um: f.r_um,
        r_up_um: f.r_up_um,
        r_down_um: f.r_down_um,
        b_um: f.reversal_um,
        mean_b_um: f.mean_reversal_um,
        e_um: f.e_um,
        m_um: f.m_um,
        a_um: f.a_um,
        per_target: f.targets,
    })
}
