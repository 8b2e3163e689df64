//! The characterization figures of Tan et al. from the `scan_x` / `scan_y`
//! segments of a measurement log: errors along each axis forward and
//! backward (Fig. 4), coupling errors across the moving axis (Fig. 5) and
//! the repeatability at each point (Fig. 6).
//!
//! Conventions (the paper's, and the measurement log's):
//! * error = target − measured, per axis, µm (`Record::error_x_um`);
//! * the direction of a point is the sign of the change of the moving
//!   axis' *target* from the previous record of the segment, or at the turn
//!   of a pass (equal targets) towards the next one — the rule the lookup
//!   tables are built with (`crate::comp::table::infer_directions`), so the
//!   plots show exactly what the tables will hold; points whose direction
//!   cannot be told are left out and counted in the notes;
//! * a *pass* is a run of consecutive records of one cycle and one
//!   direction; every pass of every cycle is drawn, forward and backward in
//!   two colours;
//! * repeatability is ISO 9283 RP (paper eqs. 1–3): at each target and
//!   direction, the measured (x, y) of the cycles around their barycentre.

use std::collections::BTreeMap;

use super::figure::{Figure, NamedFigure, Panel, Scale, Style, Trace, XyPanel};
use crate::charact::log::{MeasurementLog, Record};
use crate::charact::scan::{SEGMENT_SCAN_X, SEGMENT_SCAN_Y};
use crate::comp::table::infer_directions;
use crate::metrology::{pose_stats, Xy};
use crate::model::{Axis, Direction};

/// Targets closer than this are the same point (µm); the log writes
/// 0.1 nm, so this only merges a target written twice.
const SAME_TARGET_UM: f64 = 1e-3;

/// Palette index of forward passes.
const FWD: usize = 0;
/// Palette index of backward passes.
const BWD: usize = 1;

/// One logged point of a scan with what the figures need.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScanPoint {
    /// Cycle from the log.
    pub cycle: u32,
    /// Arrival direction along the moving axis.
    pub direction: Direction,
    /// Target of the moving axis, µm.
    pub target_um: f64,
    /// Error along the moving axis, target − measured, µm.
    pub along_um: f64,
    /// Error across the moving axis (the held axis), target − measured, µm.
    pub across_um: f64,
    /// Measured position, stage frame, µm.
    pub meas: Xy,
}

/// The points of one scan segment, in log order.
#[derive(Debug, Clone, PartialEq)]
pub struct Scan {
    /// Which axis moved.
    pub axis: Axis,
    /// Points with a known direction.
    pub points: Vec<ScanPoint>,
    /// Records of the segment whose direction could not be told.
    pub undetermined: usize,
}

fn scan_of(records: &[Record], axis: Axis) -> Option<Scan> {
    let segment = match axis {
        Axis::X => SEGMENT_SCAN_X,
        Axis::Y => SEGMENT_SCAN_Y,
    };
    // The daemon logs its passes as `scan_x_fwd` / `scan_x_bwd`; other
    // programs write one `scan_x` segment. Both are one scan here (direction
    // comes from the command order either way).
    let recs: Vec<&Record> = records
        .iter()
        .filter(|r| {
            r.segment == segment
                || r.segment
                    .strip_prefix(segment)
                    .is_some_and(|rest| rest == "_fwd" || rest == "_bwd")
        })
        .collect();
    if recs.is_empty() {
        return None;
    }
    let moving: Vec<f64> = recs
        .iter()
        .map(|r| match axis {
            Axis::X => r.x_target_um,
            Axis::Y => r.y_target_um,
        })
        .collect();
    let dirs = infer_directions(&moving, SAME_TARGET_UM);
    let mut points = Vec::with_capacity(recs.len());
    let mut undetermined = 0;
    for ((r, d), &t) in recs.iter().zip(dirs).zip(&moving) {
        let Some(direction) = d else {
            undetermined += 1;
            continue;
        };
        let (along_um, across_um) = match axis {
            Axis::X => (r.error_x_um(), r.error_y_um()),
            Axis::Y => (r.error_y_um(), r.error_x_um()),
        };
        points.push(ScanPoint {
            cycle: r.cycle,
            direction,
            target_um: t,
            along_um,
            across_um,
            meas: Xy::new(r.x_meas_um, r.y_meas_um),
        });
    }
    Some(Scan {
        axis,
        points,
        undetermined,
    })
}

/// The `scan_x` and `scan_y` segments of a log (or the daemon's
/// `scan_x_fwd`/`scan_x_bwd` passes; absent ones are `None`).
pub fn scans(log: &MeasurementLog) -> [Option<Scan>; 2] {
    [
        scan_of(&log.records, Axis::X),
        scan_of(&log.records, Axis::Y),
    ]
}

/// `(target, value)` pairs of one pass.
type PassPoints = Vec<(f64, f64)>;

/// Consecutive runs of one cycle and one direction, each as `(target, value)`
/// pairs in target order.
fn passes(scan: &Scan, value: impl Fn(&ScanPoint) -> f64) -> Vec<(Direction, PassPoints)> {
    let mut out: Vec<(Direction, u32, PassPoints)> = Vec::new();
    for p in &scan.points {
        match out.last_mut() {
            Some((d, c, v)) if *d == p.direction && *c == p.cycle => {
                v.push((p.target_um, value(p)))
            }
            _ => out.push((p.direction, p.cycle, vec![(p.target_um, value(p))])),
        }
    }
    out.into_iter()
        .map(|(d, _, mut v)| {
            v.sort_by(|a, b| a.0.total_cmp(&b.0));
            (d, v)
        })
        .collect()
}

/// Number of distinct cycles among the points of a scan.
pub fn cycles(scan: &Scan) -> usize {
    let mut c: Vec<u32> = scan.points.iter().map(|p| p.cycle).collect();
    c.sort_unstable();
    c.dedup();
    c.len()
}

fn pass_traces(scan: &Scan, value: impl Fn(&ScanPoint) -> f64) -> Vec<Trace> {
    let n = cycles(scan);
    let mut seen = [false, false];
    passes(scan, value)
        .into_iter()
        .map(|(d, points)| {
            let k = usize::from(d == Direction::Backward);
            let label = (!seen[k]).then(|| {
                format!(
                    "{} ({} cycle{})",
                    if k == 0 { "forward" } else { "backward" },
                    n,
                    if n == 1 { "" } else { "s" }
                )
            });
            seen[k] = true;
            Trace {
                label,
                color: if k == 0 { FWD } else { BWD },
                points,
                style: Style::Line,
            }
        })
        .collect()
}

fn axis_name(a: Axis) -> &'static str {
    match a {
        Axis::X => "x",
        Axis::Y => "y",
    }
}

/// Fig. 4: error along the moving axis against its target, one panel per
/// scanned axis.
pub fn fig4_errors(name: &str, scans: &[Scan]) -> Figure {
    let panels = scans
        .iter()
        .map(|s| {
            let a = axis_name(s.axis);
            Panel::Xy(XyPanel {
                title: format!("scan_{a}: error along {a} ({a}_T − {a}_m)"),
                x_label: format!("{a} target (µm)"),
                y_label: format!("{a} error, target − measured (µm)"),
                traces: pass_traces(s, |p| p.along_um),
                y_scale: Scale::Linear,
                equal_aspect: false,
            })
        })
        .collect::<Vec<_>>();
    Figure {
        title: format!("Errors along each axis, forward and backward, all cycles — {name}"),
        size: (1200, 420 * panels.len().max(1) as u32 + 40),
        rows: panels.into_iter().map(|p| vec![p]).collect(),
    }
}

/// Fig. 5: error across the moving axis (the held axis' error) against the
/// moving axis' target: y error during `scan_x`, x error during `scan_y`.
pub fn fig5_coupling(name: &str, scans: &[Scan]) -> Figure {
    let panels = scans
        .iter()
        .map(|s| {
            let (a, o) = (axis_name(s.axis), axis_name(s.axis.other()));
            Panel::Xy(XyPanel {
                title: format!("scan_{a}: coupling error in {o} while {a} moves ({o}_T − {o}_m)"),
                x_label: format!("{a} target (µm)"),
                y_label: format!("{o} error, target − measured (µm)"),
                traces: pass_traces(s, |p| p.across_um),
                y_scale: Scale::Linear,
                equal_aspect: false,
            })
        })
        .collect::<Vec<_>>();
    Figure {
        title: format!("Coupling errors across the moving axis, forward and backward — {name}"),
        size: (1200, 420 * panels.len().max(1) as u32 + 40),
        rows: panels.into_iter().map(|p| vec![p]).collect(),
    }
}

/// Per direction (`[forward, backward]`), the points of a scan grouped by
/// target: `target key → (target, values)`, in target order.
type ByTarget<T> = [BTreeMap<i64, (f64, Vec<T>)>; 2];

fn by_target<T>(scan: &Scan, value: impl Fn(&ScanPoint) -> T) -> ByTarget<T> {
    let mut groups: ByTarget<T> = [BTreeMap::new(), BTreeMap::new()];
    for p in &scan.points {
        let k = usize::from(p.direction == Direction::Backward);
        let key = (p.target_um / SAME_TARGET_UM).round() as i64;
        groups[k]
            .entry(key)
            .or_insert((p.target_um, Vec::new()))
            .1
            .push(value(p));
    }
    groups
}

/// RP (µm, ISO 9283) at each target of a scan, per direction:
/// `[forward, backward]`, each `(target, RP)` in target order. Targets
/// visited fewer than twice in a direction have no RP and are left out.
pub fn repeatability(scan: &Scan) -> [Vec<(f64, f64)>; 2] {
    by_target(scan, |p| p.meas).map(|g| {
        g.into_values()
            .filter(|(_, v)| v.len() >= 2)
            .filter_map(|(t, v)| {
                // The target's own coordinates do not enter RP (spread about
                // the barycentre), so the moving coordinate alone suffices.
                pose_stats(Xy::new(t, 0.0), &v)
                    .ok()
                    .and_then(|s| s.rp_um)
                    .map(|rp| (t, rp))
            })
            .collect()
    })
}

/// Mean error along the moving axis at each target over the cycles, per
/// direction: `[forward, backward]`, each `(target, mean µm)` in target
/// order. What the paper's lookup tables hold at their points (Fig. 4's
/// passes averaged); the gap between the two is the backlash.
pub fn mean_errors(scan: &Scan) -> [Vec<(f64, f64)>; 2] {
    by_target(scan, |p| p.along_um).map(|g| {
        g.into_values()
            .map(|(t, v)| (t, v.iter().sum::<f64>() / v.len() as f64))
            .collect()
    })
}

/// Backlash of a scan, µm: the mean over the targets reached from both
/// directions of (forward − backward) mean error along the moving axis.
/// Positive when each direction stops short of its target (lost motion:
/// error = target − measured is positive forward, negative backward);
/// `None` when no target was reached both ways.
pub fn backlash_um(scan: &Scan) -> Option<f64> {
    let [f, b] = mean_errors(scan);
    let key = |t: f64| (t / SAME_TARGET_UM).round() as i64;
    let back: BTreeMap<i64, f64> = b.into_iter().map(|(t, e)| (key(t), e)).collect();
    let gaps: Vec<f64> = f
        .into_iter()
        .filter_map(|(t, e)| back.get(&key(t)).map(|eb| e - eb))
        .collect();
    (!gaps.is_empty()).then(|| gaps.iter().sum::<f64>() / gaps.len() as f64)
}

/// Fig. 6: ISO 9283 repeatability RP at every target, forward and backward,
/// one panel per scanned axis. `None` when no target was visited twice in
/// the same direction (a single-cycle log has no repeatability).
pub fn fig6_repeatability(name: &str, scans: &[Scan]) -> Option<Figure> {
    let mut panels = Vec::new();
    for s in scans {
        let a = axis_name(s.axis);
        let [f, b] = repeatability(s);
        if f.is_empty() && b.is_empty() {
            continue;
        }
        let n = cycles(s);
        let worst = f.iter().chain(&b).map(|p| p.1).fold(0.0, f64::max);
        let traces = [(f, "forward", FWD), (b, "backward", BWD)]
            .into_iter()
            .filter(|(v, _, _)| !v.is_empty())
            .map(|(points, d, color)| Trace {
                label: Some(format!("{d} ({n} cycles)")),
                color,
                points,
                style: Style::LineDots,
            })
            .collect();
        panels.push(Panel::Xy(XyPanel {
            title: format!("scan_{a}: repeatability RP per point (max {worst:.3} µm)"),
            x_label: format!("{a} target (µm)"),
            y_label: "RP = l̄ + 3·S (µm)".into(),
            traces,
            y_scale: Scale::Linear,
            equal_aspect: false,
        }));
    }
    if panels.is_empty() {
        return None;
    }
    Some(Figure {
        title: format!("Positioning repeatability per point (ISO 9283 RP over cycles) — {name}"),
        size: (1200, 420 * panels.len() as u32 + 40),
        rows: panels.into_iter().map(|p| vec![p]).collect(),
    })
}

/// Figs. 4, 5 and 6 of the scans of `log`, named `<stem>_fig4_errors`,
/// `_fig5_coupling`, `_fig6_repeatability`, and notes for the user (points
/// left out, figures skipped and why). No figure when the log has no scan
/// segment; no Fig. 6 when no target was visited twice in one direction.
pub fn charact_figures(
    name: &str,
    stem: &str,
    log: &MeasurementLog,
) -> (Vec<NamedFigure>, Vec<String>) {
    let scans: Vec<Scan> = scans(log)
        .into_iter()
        .flatten()
        .filter(|s| !s.points.is_empty())
        .collect();
    let mut notes = Vec::new();
    let mut figures = Vec::new();
    if scans.is_empty() {
        return (figures, notes);
    }
    for s in &scans {
        if s.undetermined > 0 {
            notes.push(format!(
                "{name}: scan_{}: {} point(s) without a direction (no target change on either side) left out",
                axis_name(s.axis),
                s.undetermined
            ));
        }
    }
    let named = |suffix: &str, figure: Figure| NamedFigure {
        stem: format!("{stem}_{suffix}"),
        figure,
    };
    figures.push(named("fig4_errors", fig4_errors(name, &scans)));
    figures.push(named("fig5_coupling", fig5_coupling(name, &scans)));
    match fig6_repeatability(name, &scans) {
        Some(f) => figures.push(named("fig6_repeatability", f)),
        None => notes.push(format!(
            "{name}: no target visited twice in one direction: no repeatability figure (needs ≥ 2 cycles)"
        )),
    }
    (figures, notes)
}
