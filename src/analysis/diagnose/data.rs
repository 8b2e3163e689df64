//! Steps 1 and 3 of the analysis: the log replayed through the model's
//! motion tracker into states and residual rows, with the folds and the
//! centring groups the nuisance constants are profiled out by, and the
//! log's extra columns worth searching (kind `other`).
//!
//! Why a file of its own: every later step reads the log only through
//! [`Data`], so what counts as a row, a fold or a searchable column is
//! decided here once.

use std::collections::HashMap;

use crate::charact::log::MeasurementLog;
use crate::model::{Axis, MotionState, MotionTracker, StageModel, Waypoint};

use super::AnalysisError;

/// The log turned into model states and residual rows.
pub(super) struct Data {
    pub(super) n: usize,
    pub(super) states: Vec<MotionState>,
    pub(super) meas: Vec<[f64; 2]>,
    /// Residual of the model as given, index `2i + c`.
    pub(super) r0: Vec<f64>,
    pub(super) fold: Vec<usize>,
    pub(super) nfolds: usize,
    /// Centring group per row and component (static axis in its block).
    pub(super) group: Vec<[Option<usize>; 2]>,
    pub(super) ngroups: usize,
    /// Whether axis `a` moves within the row's block.
    pub(super) moving: Vec<[bool; 2]>,
    pub(super) t0: f64,
    pub(super) temp_varies: bool,
    /// Numeric extra columns searched by the `other` family.
    pub(super) extra: Vec<ExtraVar>,
}

/// A numeric extra column of the log.
pub(super) struct ExtraVar {
    pub(super) name: String,
    /// Value per row (unparsable cells: the column mean).
    pub(super) values: Vec<f64>,
    /// Mean over the rows: the column is `value − mean` (a model has no
    /// intercept to absorb a column's offset).
    pub(super) mean: f64,
    pub(super) min: f64,
    pub(super) max: f64,
}

impl Data {
    pub(super) fn center(&self, v: &mut [f64]) {
        if self.ngroups == 0 {
            return;
        }
        let mut sum = vec![0.0; self.ngroups];
        let mut cnt = vec![0usize; self.ngroups];
        for i in 0..self.n {
            for c in 0..2 {
                if let Some(g) = self.group[i][c] {
                    sum[g] += v[2 * i + c];
                    cnt[g] += 1;
                }
            }
        }
        for i in 0..self.n {
            for c in 0..2 {
                if let Some(g) = self.group[i][c] {
                    v[2 * i + c] -= sum[g] / cnt[g] as f64;
                }
            }
        }
    }
}

pub(super) fn prepare(
    log: &MeasurementLog,
    model: &StageModel,
    max_folds: usize,
) -> Result<Data, AnalysisError> {
    let recs = &log.records;
    if recs.len() < 20 {
        return Err(AnalysisError::Invalid(format!(
            "the log has {} points; the analysis needs at least 20",
            recs.len()
        )));
    }
    let env = model.environment();
    let waypoints: Vec<Waypoint> = recs
        .iter()
        .map(|r| Waypoint {
            x_um: r.x_cmd_um,
            y_um: r.y_cmd_um,
            time_s: r.t_s,
            temp_c: r.temp_c.unwrap_or_else(|| env.temperature_at(r.t_s)),
            cycle: r.cycle,
        })
        .collect();
    let min_move = model.stochastic().min_incremental_motion_um;
    let mut start = MotionState::at_rest(waypoints[0].x_um, waypoints[0].y_um);
    start.time_s = waypoints[0].time_s;
    start.temp_c = waypoints[0].temp_c;
    let states = MotionTracker::new(start)?
        .with_min_move(min_move)?
        .replay(&waypoints)?;
    let n = states.len();
    let meas: Vec<[f64; 2]> = recs.iter().map(|r| [r.x_meas_um, r.y_meas_um]).collect();
    let mut r0 = vec![0.0; 2 * n];
    for i in 0..n {
        let o = model.observed_position(&states[i]);
        r0[2 * i] = meas[i][0] - o.x_um;
        r0[2 * i + 1] = meas[i][1] - o.y_um;
    }
    // Folds: whole cycles, else contiguous chunks.
    let mut cycles: Vec<u32> = recs.iter().map(|r| r.cycle).collect();
    cycles.sort_unstable();
    cycles.dedup();
    let max_folds = max_folds.max(2);
    let (fold, nfolds) = if cycles.len() >= 2 {
        let k = cycles.len().min(max_folds);
        let rank: HashMap<u32, usize> = cycles.iter().enumerate().map(|(i, c)| (*c, i)).collect();
        (
            recs.iter().map(|r| rank[&r.cycle] % k).collect::<Vec<_>>(),
            k,
        )
    } else {
        let k = max_folds.min(5);
        ((0..n).map(|i| i * k / n).collect(), k)
    };
    // Blocks (segment, cycle, fold): static axes and centring groups.
    let mut block_of: HashMap<(&str, u32, usize), usize> = HashMap::new();
    let mut block = vec![0usize; n];
    for i in 0..n {
        let key = (recs[i].segment.as_str(), recs[i].cycle, fold[i]);
        let next = block_of.len();
        block[i] = *block_of.entry(key).or_insert(next);
    }
    let nb = block_of.len();
    let mut lo = vec![[f64::INFINITY; 2]; nb];
    let mut hi = vec![[f64::NEG_INFINITY; 2]; nb];
    for i in 0..n {
        for a in 0..2 {
            let v = states[i].axes[a].cmd_um;
            lo[block[i]][a] = lo[block[i]][a].min(v);
            hi[block[i]][a] = hi[block[i]][a].max(v);
        }
    }
    let tol = min_move.max(1e-6);
    let mut group = vec![[None; 2]; n];
    let mut moving = vec![[false; 2]; n];
    for i in 0..n {
        for a in 0..2 {
            let b = block[i];
            let still = hi[b][a] - lo[b][a] <= tol;
            moving[i][a] = !still;
            group[i][a] = Some(if still {
                2 * b + a
            } else {
                // Frame gauge: one constant per component over the rows
                // where it moves (see the module docs, step 3).
                2 * nb + a
            });
        }
    }
    let temps: Vec<f64> = states.iter().map(|s| s.temp_c).collect();
    let tmean = temps.iter().sum::<f64>() / n as f64;
    let tsd = (temps.iter().map(|t| (t - tmean).powi(2)).sum::<f64>() / n as f64).sqrt();
    let extra = numeric_extra_columns(log, &states);
    let mut d = Data {
        n,
        t0: states[0].time_s,
        states,
        meas,
        r0,
        fold,
        nfolds,
        group,
        ngroups: 2 * nb + 2,
        moving,
        temp_varies: tsd > 0.02,
        extra,
    };
    let mut r = std::mem::take(&mut d.r0);
    d.center(&mut r);
    d.r0 = r;
    Ok(d)
}

/// Share of rows in which an extra column must be a finite number to be
/// searched.
const EXTRA_MIN_NUMERIC: f64 = 0.95;

/// |correlation| with a commanded position, time or temperature from which
/// an extra column counts as a repeat of that variable (not searched).
const EXTRA_MAX_CORRELATION: f64 = 0.98;

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
/// variable the other families already cover.
fn numeric_extra_columns(log: &MeasurementLog, states: &[MotionState]) -> Vec<ExtraVar> {
    let n = log.records.len();
    let known: [Vec<f64>; 4] = [
        states.iter().map(|s| s.cmd_um(Axis::X)).collect(),
        states.iter().map(|s| s.cmd_um(Axis::Y)).collect(),
        states.iter().map(|s| s.time_s).collect(),
        states.iter().map(|s| s.temp_c).collect(),
    ];
    let mut out = Vec::new();
    for (j, name) in log.columns.extra.iter().enumerate() {
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

pub(super) fn median(mut v: Vec<f64>) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    Some(v[v.len() / 2])
}

/// Lengths of the moves axis `a` made in the log (rows where it moved),
/// µm.
pub(super) fn move_lengths(d: &Data, a: Axis) -> Vec<f64> {
    d.states
        .windows(2)
        .filter(|w| w[1].cmd_um(a) != w[0].cmd_um(a))
        .map(|w| w[1].axis(a).last_move_um)
        .filter(|l| l.is_finite() && *l > 0.0)
        .collect()
}

/// Median length of the moves of axis `a` in the log, µm (0 without moves).
pub(super) fn typical_move_um(d: &Data, a: Axis) -> f64 {
    median(move_lengths(d, a)).unwrap_or(0.0)
}

pub(super) fn span_of(d: &Data, a: Axis) -> f64 {
    let (lo, hi) = d
        .states
        .iter()
        .map(|s| s.cmd_um(a))
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), v| {
            (l.min(v), h.max(v))
        });
    (hi - lo).max(1e-9)
}
