//! The replicates of the noise estimate: which records are visits of the
//! same target from the same side (arriving at rest), their deviations,
//! the wild visits among them (outliers) and the visit pairs that
//! disagree beyond the noise. Why a file of its own: the grouping is
//! what every replicate figure of [`super::noise`] stands on, and the
//! fit leaves the outliers it finds out ([`outlier_rows`]).

use super::data::Data;
use super::noise::{
    outliers_in, DISCORDANT_SIGMAS, MAX_DISCORDANT_SHARE, MIN_SCATTER_GROUPS, OUTLIER_SIGMAS,
};
use crate::charact::log::MeasurementLog;
use crate::model::Axis;
use std::collections::BTreeMap;

pub(super) fn key_of(v: f64) -> i64 {
    (v * 1e3).round() as i64
}

/// Replicate-group key: (segment, target x, target y, approach x, approach y).
type Key<'a> = (&'a str, i64, i64, i64, i64);

/// The replicated targets of component `c` (groups of ≥ 2 visits), each
/// group's median deviation, whether the group repositions `c`'s own axis
/// ([`positions_axis`]), and the robust σ.
pub(super) struct Replicates<'a> {
    pub(super) reps: Vec<(Key<'a>, Vec<usize>)>,
    pub(super) medians: Vec<f64>,
    /// Per group: whether its visits reposition the component's axis.
    pub(super) positioning: Vec<bool>,
    pub(super) robust: Option<f64>,
    /// Per group: its scatter in robust σ when it is a discordant pair
    /// ([`DiscordantPair`]) of the class that sets the repeatability.
    pub(super) discordant: Vec<Option<f64>>,
    /// Whether those pairs are too many to leave out
    /// ([`MAX_DISCORDANT_SHARE`]).
    pub(super) discordant_kept: bool,
}

/// Whether row `i` arrives by moving axis `a`: its command differs from
/// the previous row's, or its approach direction does (a reversal at one
/// target is a move through an overtravel the log did not record); the
/// first row counts as arrived.
pub(super) fn arrives_moving(log: &MeasurementLog, d: &Data, i: usize, a: Axis) -> bool {
    let cmd = |r: &crate::charact::log::Record| match a {
        Axis::X => r.x_cmd_um,
        Axis::Y => r.y_cmd_um,
    };
    i == 0
        || (cmd(&log.records[i]) - cmd(&log.records[i - 1])).abs() > 1e-6
        || d.approach[i][a.index()] != d.approach[i - 1][a.index()]
}

/// Whether a replicate group repositions axis `a` (at least half its
/// visits arrive by moving it).
///
/// Why: the repeatability is the scatter of repeated *positioning* of an
/// axis (ISO 230-2's `s_i`). The reading of an axis held still while the
/// other one scans (y during an x scan) sees neither the drive nor its
/// settling: on the simulated rig it repeats to 0.0001 µm, 300× below the
/// y axis's positioning scatter, and pooled with the rest it set the
/// repeatability, called every positioned visit an outlier and every
/// 0.01 µm of systematic error "85× the repeatability".
pub(super) fn positions_axis(log: &MeasurementLog, d: &Data, rows: &[usize], a: Axis) -> bool {
    2 * rows
        .iter()
        .filter(|&&i| arrives_moving(log, d, i, a))
        .count()
        >= rows.len()
}

/// The finest step the log writes its readings of component `c` with, µm
/// (`10⁻ᵏ` for the smallest `k ≤ 9` at which every reading is a whole
/// number of steps): no scatter smaller than it can be measured from the
/// log, so the repeatability is not taken below it.
pub(super) fn resolution_um(log: &MeasurementLog, c: Axis) -> Option<f64> {
    let vals: Vec<f64> = log
        .records
        .iter()
        .map(|r| match c {
            Axis::X => r.x_meas_um,
            Axis::Y => r.y_meas_um,
        })
        .filter(|v| v.is_finite())
        .collect();
    if vals.is_empty() {
        return None;
    }
    (0..=9).find_map(|k| {
        let scale = 10f64.powi(k);
        vals.iter()
            .all(|v| {
                let x = v * scale;
                (x - x.round()).abs() <= 1e-3 + 1e-15 * x.abs()
            })
            .then(|| 1.0 / scale)
    })
}

/// Deviation `meas − target` of row `i` on component `ci`.
pub(super) fn deviation(log: &MeasurementLog, i: usize, ci: usize) -> f64 {
    let r = &log.records[i];
    if ci == 0 {
        r.x_meas_um - r.x_target_um
    } else {
        r.y_meas_um - r.y_target_um
    }
}

pub(super) fn replicates<'a>(log: &'a MeasurementLog, d: &Data, c: Axis) -> Replicates<'a> {
    let ci = c.index();
    let mut groups: BTreeMap<Key, Vec<usize>> = BTreeMap::new();
    for (i, r) in log.records.iter().enumerate().take(d.n) {
        let ap = d.approach[i];
        let k = (
            r.segment.as_str(),
            key_of(r.x_target_um),
            key_of(r.y_target_um),
            ap[0] as i64,
            ap[1] as i64,
        );
        groups.entry(k).or_default().push(i);
    }
    let dev = |i: usize| deviation(log, i, ci);
    // Robust σ: the median over targets of the variance between visits
    // (one wild visit inflates its own target's variance, not the median),
    // and each target's median as its centre.
    let reps: Vec<(Key, Vec<usize>)> = groups.into_iter().filter(|(_, r)| r.len() >= 2).collect();
    let medians: Vec<f64> = reps
        .iter()
        .map(|(_, rows)| super::data::median(rows.iter().map(|&i| dev(i)).collect()).unwrap_or(0.0))
        .collect();
    let positioning: Vec<bool> = reps
        .iter()
        .map(|(_, rows)| positions_axis(log, d, rows, c))
        .collect();
    // The robust σ from the groups that reposition the axis, when there
    // are any (a held axis's reading is not a positioning repeat).
    let any_positioning = positioning.iter().any(|&p| p);
    let in_class: Vec<bool> = positioning.iter().map(|&p| p || !any_positioning).collect();
    let vars: Vec<f64> = reps
        .iter()
        .map(|(_, rows)| {
            let n = rows.len() as f64;
            let m = rows.iter().map(|&i| dev(i)).sum::<f64>() / n;
            rows.iter().map(|&i| (dev(i) - m).powi(2)).sum::<f64>() / (n - 1.0)
        })
        .collect();
    let class_vars = || {
        vars.iter()
            .zip(&in_class)
            .filter(|(_, &c)| c)
            .map(|(v, _)| *v)
    };
    let median_var = super::data::median(class_vars().collect());
    let robust = median_var.map(f64::sqrt);
    let (discordant, discordant_kept) = discordant_pairs(&reps, &in_class, &vars, median_var);
    Replicates {
        reps,
        medians,
        positioning,
        robust,
        discordant,
        discordant_kept,
    }
}

/// The discordant pairs among `reps` (see [`DiscordantPair`]): per group,
/// its `s` in robust σ when it has two visits, belongs to the class that
/// sets the repeatability (`in_class`) and exceeds [`DISCORDANT_SIGMAS`];
/// and whether they are too many to leave out. `vars` are the groups'
/// `s_i²`, `median_var` their median over the class (χ²-median corrected
/// here). Needs [`MIN_SCATTER_GROUPS`] groups in the
/// class.
fn discordant_pairs(
    reps: &[(Key, Vec<usize>)],
    in_class: &[bool],
    vars: &[f64],
    median_var: Option<f64>,
) -> (Vec<Option<f64>>, bool) {
    let none = (vec![None; reps.len()], false);
    let dof: Vec<f64> = reps
        .iter()
        .zip(in_class)
        .filter(|(_, &c)| c)
        .map(|((_, rows), _)| (rows.len() - 1) as f64)
        .collect();
    if dof.len() < MIN_SCATTER_GROUPS {
        return none;
    }
    let (Some(k), Some(med)) = (super::data::median(dof), median_var) else {
        return none;
    };
    let factor = (1.0 - 2.0 / (9.0 * k)).powi(3);
    if factor <= 0.0 || med <= 0.0 {
        return none;
    }
    let sigma = (med / factor).sqrt();
    let mut pairs = 0usize;
    let out: Vec<Option<f64>> = reps
        .iter()
        .zip(in_class.iter().zip(vars))
        .map(|((_, rows), (&c, &v))| {
            if !c || rows.len() != 2 {
                return None;
            }
            pairs += 1;
            let z = v.sqrt() / sigma;
            (z > DISCORDANT_SIGMAS).then_some(z)
        })
        .collect();
    let found = out.iter().flatten().count();
    let kept = found as f64 > MAX_DISCORDANT_SHARE * pairs as f64;
    (out, kept)
}

/// Whether row `i` is the first of its pass (its segment or cycle differs
/// from the previous row's).
pub(super) fn first_of_pass(log: &MeasurementLog, i: usize) -> bool {
    i == 0 || {
        let (r, q) = (&log.records[i], &log.records[i - 1]);
        r.segment != q.segment || r.cycle != q.cycle
    }
}

/// Whether a visit `excess_um` from its target's median, in a group of
/// `visits`, is an outlier: a target needs three visits before one of them
/// can be called the odd one out.
pub(super) fn is_outlier(visits: usize, robust: Option<f64>, excess_um: f64) -> bool {
    matches!(robust, Some(r) if visits >= 3 && r > 0.0 && excess_um.abs() > OUTLIER_SIGMAS * r)
}

/// Rows of component `c` that are outliers among the visits of their
/// target (see [`Data::excluded`]).
pub(super) fn outlier_rows(log: &MeasurementLog, d: &Data, c: Axis) -> Vec<usize> {
    let rep = replicates(log, d, c);
    let mut rows = outliers_in(&rep, log, c.index());
    if !rep.discordant_kept {
        for ((_, g), z) in rep.reps.iter().zip(&rep.discordant) {
            if z.is_some() {
                rows.extend(g);
            }
        }
    }
    rows
}
