//! What a log's columns say beyond the positions: which axes it measured
//! (from the data, or declared in its metadata), the side each record
//! was approached from (declared, or from the moves before it) and which
//! records are judged, and the numeric extra columns worth searching
//! (kind `other`). Why a file of its own: these are read once per log,
//! before any row is built ([`super::data::prepare`]), and each is a rule
//! about the log's format rather than about the model.

use super::data::{median, ExtraVar, MeasuredSource};
use crate::analysis::AnalysisError;
use crate::charact::log::MeasurementLog;
use crate::charact::scan::{grid_direction, SEGMENT_GRID};
use crate::model::{Axis, MotionState, Waypoint};
use std::collections::HashMap;

/// Metadata key a log declares its measured axes with (`x`, `y`, `x,y`):
/// written by `micropos import`; other writers may use it.
pub const MEASURED_AXES_KEY: &str = "measured_axes";

/// Spread below which a `*_meas_um` column counts as a constant placeholder,
/// µm (a real sensor's readings differ at least in their last digit).
pub(super) const PLACEHOLDER_SPREAD_UM: f64 = 1e-9;

/// Which error components the log measured (see [`Data::measured`]).
pub(super) fn measured_axes(
    log: &MeasurementLog,
) -> Result<([bool; 2], MeasuredSource), AnalysisError> {
    if let Some(v) = log.metadata.get(MEASURED_AXES_KEY) {
        let mut m = [false; 2];
        for part in v.split([',', ' ', ';']).filter(|p| !p.trim().is_empty()) {
            match part.trim().to_ascii_lowercase().as_str() {
                "x" => m[0] = true,
                "y" => m[1] = true,
                other => {
                    return Err(AnalysisError::Invalid(format!(
                        "metadata {MEASURED_AXES_KEY}: {other:?} is not an axis (x, y)"
                    )))
                }
            }
        }
        if m == [false; 2] {
            return Err(AnalysisError::Invalid(format!(
                "metadata {MEASURED_AXES_KEY} names no axis"
            )));
        }
        return Ok((m, MeasuredSource::Metadata));
    }
    let mut m = [true; 2];
    for (c, mc) in m.iter_mut().enumerate() {
        let (lo, hi) = log
            .records
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), r| {
                let v = if c == 0 { r.x_meas_um } else { r.y_meas_um };
                (l.min(v), h.max(v))
            });
        *mc = hi - lo > PLACEHOLDER_SPREAD_UM;
    }
    if m == [false; 2] {
        return Err(AnalysisError::Invalid(
            "neither x_meas_um nor y_meas_um varies: the log measured nothing".into(),
        ));
    }
    Ok((m, MeasuredSource::Data))
}

/// Name of the extra column holding the true approach direction.
pub const APPROACH_COLUMN: &str = "approach";

/// Parses an approach cell: `+1` forward (towards larger positions), `−1`
/// backward, `None` for anything else (`rest`, empty).
pub fn parse_approach(s: &str) -> Option<f64> {
    match s.trim().to_ascii_lowercase().as_str() {
        "fwd" | "forward" | "+" | "+1" | "1" | "up" | "pos" | "positive" | "↑" => Some(1.0),
        "bwd" | "backward" | "-" | "-1" | "down" | "neg" | "negative" | "↓" => Some(-1.0),
        _ => None,
    }
}

/// The approach direction the log's `approach` column declares per row
/// and axis (`None` where it says nothing): only for an axis that moves
/// alone in its segment (a 1-D scan; with both axes moving the column
/// cannot say which it means).
pub(super) fn declared_approach(log: &MeasurementLog) -> Vec<[Option<f64>; 2]> {
    // A grid measured both ways names each node's arrival on both axes in
    // its segment, and microposd's one-way grid plan reaches every node
    // from below; their approach moves (a row's first node reached from
    // its pass's side) are not logged.
    let one_way_plan = log.metadata.get("plan") == Some("grid")
        && log
            .metadata
            .get("grid_approach")
            .is_none_or(|v| v == "below");
    let mut out: Vec<[Option<f64>; 2]> = log
        .records
        .iter()
        .map(|r| match grid_direction(&r.segment) {
            Some(d) => [Some(d[0].sign()), Some(d[1].sign())],
            None if one_way_plan && r.segment == SEGMENT_GRID => [Some(1.0), Some(1.0)],
            None => [None; 2],
        })
        .collect();
    let Some(j) = log.columns.extra.iter().position(|c| c == APPROACH_COLUMN) else {
        return out;
    };
    // Axes whose command varies, per segment.
    let mut varies: HashMap<&str, [(f64, f64); 2]> = HashMap::new();
    for r in &log.records {
        let e = varies
            .entry(r.segment.as_str())
            .or_insert([(f64::INFINITY, f64::NEG_INFINITY); 2]);
        for (a, v) in [r.x_cmd_um, r.y_cmd_um].into_iter().enumerate() {
            e[a] = (e[a].0.min(v), e[a].1.max(v));
        }
    }
    for (i, r) in log.records.iter().enumerate() {
        let Some(sign) = r.extra.get(j).and_then(|t| parse_approach(t)) else {
            continue;
        };
        let Some(v) = varies.get(r.segment.as_str()) else {
            continue;
        };
        match [v[0].1 > v[0].0, v[1].1 > v[1].0] {
            [true, false] => out[i][0] = Some(sign),
            [false, true] => out[i][1] = Some(sign),
            _ => {}
        }
    }
    out
}

/// Shortest virtual approach move, µm: long enough to take up any play a
/// micropositioning stage has.
pub(super) const MIN_APPROACH_MOVE_UM: f64 = 100.0;

/// The log's waypoints with a virtual approach move inserted before each
/// row whose declared approach the previous command does not give (an ISO
/// 230-2 test approaches each pass's first target from beyond it, unlogged):
/// a waypoint one typical step (at least [`MIN_APPROACH_MOVE_UM`]) on the
/// far side. Returns the waypoints and the index of each log row in them.
pub(super) fn with_approach_moves(
    wps: &[Waypoint],
    declared: &[[Option<f64>; 2]],
    min_move_um: f64,
) -> (Vec<Waypoint>, Vec<usize>) {
    if declared.iter().all(|d| d == &[None, None]) {
        return (wps.to_vec(), (0..wps.len()).collect());
    }
    let step = |a: usize| -> f64 {
        let moves: Vec<f64> = wps
            .windows(2)
            .map(|w| {
                if a == 0 {
                    (w[1].x_um - w[0].x_um).abs()
                } else {
                    (w[1].y_um - w[0].y_um).abs()
                }
            })
            .filter(|d| *d > min_move_um && d.is_finite())
            .collect();
        median(moves).unwrap_or(0.0).max(MIN_APPROACH_MOVE_UM)
    };
    let steps = [step(0), step(1)];
    let mut out: Vec<Waypoint> = Vec::with_capacity(wps.len() + wps.len() / 4);
    let mut real = Vec::with_capacity(wps.len());
    // Direction of each axis's last motion over the waypoints so far.
    let mut last_dir = [0.0f64; 2];
    let at = |p: &Waypoint, a: usize| if a == 0 { p.x_um } else { p.y_um };
    let push = |out: &mut Vec<Waypoint>, w: Waypoint, last_dir: &mut [f64; 2]| {
        if let Some(p) = out.last() {
            for (a, d) in last_dir.iter_mut().enumerate() {
                let dp = at(&w, a) - at(p, a);
                if dp.abs() > min_move_um {
                    *d = dp.signum();
                }
            }
        }
        out.push(w);
    };
    for (i, wp) in wps.iter().enumerate() {
        let mut virt = *wp;
        let mut needed = false;
        for (a, dir) in declared[i].iter().enumerate() {
            let Some(dir) = *dir else { continue };
            let here = at(wp, a);
            let prev = out.last().map(|p| at(p, a));
            // Approached the declared way when the previous command is
            // on the far side by more than the minimum motion, or the
            // axis has not moved since it last moved that way (a grid
            // row's held y).
            let ok = prev.is_some_and(|p| {
                dir * (here - p) > min_move_um
                    || ((here - p).abs() <= min_move_um && last_dir[a] == dir)
            });
            if !ok {
                let from = here - dir * steps[a];
                if a == 0 {
                    virt.x_um = from;
                } else {
                    virt.y_um = from;
                }
                needed = true;
            }
        }
        if needed {
            push(&mut out, virt, &mut last_dir);
        }
        real.push(out.len());
        push(&mut out, *wp, &mut last_dir);
    }
    (out, real)
}

/// Approach sign per row and axis: the replayed direction, replaced by the
/// declared one where the log has an `approach` column (see
/// [`declared_approach`]).
pub(super) fn approach_signs(log: &MeasurementLog, states: &[MotionState]) -> Vec<[f64; 2]> {
    let declared = declared_approach(log);
    states
        .iter()
        .zip(declared)
        .map(|(s, d)| {
            [
                d[0].unwrap_or_else(|| s.axes[0].dir.sign()),
                d[1].unwrap_or_else(|| s.axes[1].dir.sign()),
            ]
        })
        .collect()
}

/// Rows whose held-out prediction is an interpolation (see
/// [`Data::judged`]): for each axis moving in the row, the row's position
/// lies within the range the other folds sampled with the same approach.
pub(super) fn judged_rows(
    states: &[MotionState],
    approach: &[[f64; 2]],
    moving: &[[bool; 2]],
    fold: &[usize],
    nfolds: usize,
) -> Vec<bool> {
    let n = states.len();
    // range[fold][axis][dir] over rows NOT in the fold.
    let key = |s: f64| usize::from(s > 0.0) + 2 * usize::from(s < 0.0);
    let mut range = vec![[[(f64::INFINITY, f64::NEG_INFINITY); 3]; 2]; nfolds];
    for (f, rf) in range.iter_mut().enumerate() {
        for i in (0..n).filter(|&i| fold[i] != f) {
            for a in 0..2 {
                if moving[i][a] {
                    let v = states[i].axes[a].cmd_um;
                    let r = &mut rf[a][key(approach[i][a])];
                    *r = (r.0.min(v), r.1.max(v));
                }
            }
        }
    }
    (0..n)
        .map(|i| {
            (0..2).all(|a| {
                if !moving[i][a] {
                    return true;
                }
                let v = states[i].axes[a].cmd_um;
                let (lo, hi) = range[fold[i]][a][key(approach[i][a])];
                v >= lo - 1e-6 && v <= hi + 1e-6
            })
        })
        .collect()
}

/// Share of rows in which an extra column must be a finite number to be
/// searched.
pub(super) const EXTRA_MIN_NUMERIC: f64 = 0.95;

/// |correlation| with a commanded position, time or temperature from which
/// an extra column counts as a repeat of that variable (not searched).
pub(super) const EXTRA_MAX_CORRELATION: f64 = 0.98;

fn correlation(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len().min(b.len()) as f64;
    if n < 2.0 {
        return 0.0;
    }
    let ma = a.iter().sum::<f64>() / n;
    let mb = b.iter().sum::<f64>() / n;
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        sab += (x - ma) * (y - mb);
        saa += (x - ma) * (x - ma);
        sbb += (y - mb) * (y - mb);
    }
    if saa > 0.0 && sbb > 0.0 {
        sab / (saa * sbb).sqrt()
    } else {
        0.0
    }
}

/// The log's extra columns worth searching (see the module docs): numeric
/// in ≥ [`EXTRA_MIN_NUMERIC`] of the rows, not constant, not a repeat of a
/// variable the other families already cover, not [`APPROACH_COLUMN`].
pub(super) fn numeric_extra_columns(log: &MeasurementLog, states: &[MotionState]) -> Vec<ExtraVar> {
    let n = log.records.len();
    let known: [Vec<f64>; 4] = [
        states.iter().map(|s| s.cmd_um(Axis::X)).collect(),
        states.iter().map(|s| s.cmd_um(Axis::Y)).collect(),
        states.iter().map(|s| s.time_s).collect(),
        states.iter().map(|s| s.temp_c).collect(),
    ];
    let mut out = Vec::new();
    for (j, name) in log.columns.extra.iter().enumerate() {
        // The approach direction is the replay's input (the play's side),
        // not a variable of its own.
        if name == APPROACH_COLUMN {
            continue;
        }
        let parsed: Vec<Option<f64>> = log
            .records
            .iter()
            .map(|r| {
                r.extra
                    .get(j)
                    .and_then(|t| t.trim().parse::<f64>().ok())
                    .filter(|v| v.is_finite() && v.abs() < 1e15)
            })
            .collect();
        let ok: Vec<f64> = parsed.iter().flatten().copied().collect();
        if (ok.len() as f64) < EXTRA_MIN_NUMERIC * n as f64 || ok.len() < 20 {
            continue;
        }
        let mean = ok.iter().sum::<f64>() / ok.len() as f64;
        let values: Vec<f64> = parsed.iter().map(|v| v.unwrap_or(mean)).collect();
        let (min, max) = values
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), v| {
                (l.min(*v), h.max(*v))
            });
        if max <= min {
            continue;
        }
        if known
            .iter()
            .any(|k| correlation(k, &values).abs() >= EXTRA_MAX_CORRELATION)
        {
            continue;
        }
        out.push(ExtraVar {
            name: name.clone(),
            values,
            mean,
            min,
            max,
        });
    }
    out
}
