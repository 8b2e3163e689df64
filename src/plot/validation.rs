//! The validation figures of Tan et al.: accuracy on the square (Fig. 10)
//! and on the ten random points (Fig. 11), for every compensation mode.
//!
//! Input: measurement logs with segment `square` or `random` and the extra
//! columns `mode` (`raw`, `table`, `model`, `closed_loop`, or any other
//! name) and `pose` (the pose's index along the trajectory). A log without
//! a `mode` column is taken as one mode named after the file; the returned
//! notes say so. Without a `pose` column, poses are told apart by their
//! target.
//!
//! One series per log and mode: records of one mode from different logs
//! (several runs, e.g. `table` in a validation and in its drift
//! comparison) are never pooled, since their AP and RP would describe no
//! run. A figure of one log labels its series by mode, one that compares
//! logs by mode and log (`table (validate.csv)`); which logs share a figure
//! is the caller's choice (`plot::report`: one log per figure unless a
//! comparison is asked for).
//!
//! What is drawn, per segment:
//! * a plan view: the targets and the measured positions of every visit,
//!   with the deviations (measured − target) magnified by a stated factor —
//!   at true scale a 22 µm error on a 4 mm square is invisible;
//! * the deviations at true scale, measured − target in x against y (µm);
//! * AP per pose (ISO 9283, paper eq. 6: distance of the barycentre of the
//!   visits to the target) along the trajectory, per mode, on a log scale
//!   when the modes differ by orders of magnitude (raw ≈ 22 µm next to
//!   closed loop ≈ 0.1 µm);
//! * bars per mode: AP of the worst pose (micropos' headline figure), mean
//!   AP over poses, worst RP (where every pose was visited at least twice).

use std::collections::HashMap;

use super::figure::{BarGroup, BarPanel, Figure, NamedFigure, Panel, Scale, Style, Trace, XyPanel};
use crate::charact::log::MeasurementLog;
use crate::charact::scan::{SEGMENT_RANDOM, SEGMENT_SQUARE};
use crate::metrology::{pose_stats, summarize_poses, PoseStats, PoseSummary, Xy};

/// Extra column naming the compensation mode of a validation record.
pub const MODE_COLUMN: &str = "mode";
/// Extra column naming the pose (index along the trajectory).
pub const POSE_COLUMN: &str = "pose";
/// The validation segments, with the paper's figure number.
pub const SEGMENTS: [(&str, u32); 2] = [(SEGMENT_SQUARE, 10), (SEGMENT_RANDOM, 11)];
/// Modes in the order they are shown (others follow in order of
/// appearance; one mode of several logs in the logs' order).
pub const KNOWN_MODES: [&str; 4] = ["raw", "table", "model", "closed_loop"];

/// Targets closer than this are the same pose (µm).
const SAME_TARGET_UM: f64 = 1e-3;
/// Palette index of the targets (grey).
const TARGET_COLOR: usize = 5;
/// Resolution of the AP/RP bar labels, µm. A validation's figures come from
/// camera measurements of poses the stage re-approaches with a settling
/// scatter of σ ≈ 0.035 µm (docs/design/conventions.md): a digit below
/// 10 nm is noise and only lengthens the label.
pub const VALUE_RESOLUTION_UM: f64 = 0.01;

/// Palette index of series `k` of a figure (the targets' grey skipped).
fn series_color(k: usize) -> usize {
    if k >= TARGET_COLOR {
        k + 1
    } else {
        k
    }
}

/// One target pose of a validation trajectory.
#[derive(Debug, Clone, PartialEq)]
pub struct Pose {
    /// Target, stage frame, µm.
    pub target: Xy,
    /// The `pose` column's value, if the log has one.
    pub label: Option<String>,
}

/// The visits of one mode in one log.
#[derive(Debug, Clone, PartialEq)]
pub struct ModeVisits {
    /// Mode name.
    pub name: String,
    /// The log the visits come from (its name; its stem, or its name and
    /// place in the list, when another log given has the same name).
    pub source: String,
    /// How figures name the series: the mode, or `mode (log)` when the
    /// validation gathers several logs.
    pub label: String,
    /// Measured positions, µm, per pose (index into [`Validation::poses`]).
    pub visits: Vec<Vec<Xy>>,
}

impl ModeVisits {
    /// ISO 9283 figures of every visited pose, with its pose index.
    pub fn stats(&self, poses: &[Pose]) -> Vec<(usize, PoseStats)> {
        self.visits
            .iter()
            .enumerate()
            .filter(|(_, v)| !v.is_empty())
            .filter_map(|(i, v)| pose_stats(poses[i].target, v).ok().map(|s| (i, s)))
            .collect()
    }

    /// AP/RP over all poses (`None` without any visit).
    pub fn summary(&self, poses: &[Pose]) -> Option<PoseSummary> {
        let s: Vec<PoseStats> = self.stats(poses).into_iter().map(|(_, s)| s).collect();
        summarize_poses(&s).ok()
    }
}

/// One validation segment gathered over one or more logs.
#[derive(Debug, Clone, PartialEq)]
pub struct Validation {
    /// Segment name (`square` or `random`).
    pub segment: String,
    /// Poses in trajectory order.
    pub poses: Vec<Pose>,
    /// One entry per log and mode, in display order.
    pub modes: Vec<ModeVisits>,
    /// Names of the logs it comes from.
    pub sources: Vec<String>,
}

/// Whether a log holds validation records.
pub fn has_validation(log: &MeasurementLog) -> bool {
    log.records
        .iter()
        .any(|r| SEGMENTS.iter().any(|(s, _)| r.segment == *s))
}

struct Builder {
    segment: String,
    poses: Vec<Pose>,
    by_target: HashMap<(i64, i64), Vec<usize>>,
    modes: Vec<ModeVisits>,
    /// Index into the logs given of each entry of `modes`: a series is
    /// one log's, whatever the logs are called.
    mode_logs: Vec<usize>,
    sources: Vec<String>,
}

impl Builder {
    fn pose_index(&mut self, target: Xy, label: Option<&str>) -> usize {
        let key = (
            (target.x_um / SAME_TARGET_UM).round() as i64,
            (target.y_um / SAME_TARGET_UM).round() as i64,
        );
        let candidates = self.by_target.entry(key).or_default();
        for &i in candidates.iter() {
            let l = self.poses[i].label.as_deref();
            if l.is_none() || label.is_none() || l == label {
                if l.is_none() {
                    if let Some(label) = label {
                        self.poses[i].label = Some(label.to_string());
                    }
                }
                return i;
            }
        }
        let i = self.poses.len();
        self.poses.push(Pose {
            target,
            label: label.map(str::to_string),
        });
        candidates.push(i);
        i
    }

    fn mode_index(&mut self, log: usize, source: &str, name: &str) -> usize {
        if let Some(i) = self
            .modes
            .iter()
            .zip(&self.mode_logs)
            .position(|(m, &l)| m.name == name && l == log)
        {
            return i;
        }
        self.mode_logs.push(log);
        self.modes.push(ModeVisits {
            name: name.to_string(),
            source: source.to_string(),
            label: name.to_string(),
            visits: Vec::new(),
        });
        self.modes.len() - 1
    }

    /// Orders poses by their numeric label when every pose has one, and
    /// modes with the known ones first; names each series after its log
    /// too when there are several logs.
    fn finish(mut self) -> Validation {
        let numeric: Option<Vec<f64>> = self
            .poses
            .iter()
            .map(|p| {
                p.label
                    .as_deref()
                    .and_then(|l| l.trim().parse::<f64>().ok())
            })
            .collect();
        if let Some(keys) = numeric {
            let mut order: Vec<usize> = (0..self.poses.len()).collect();
            order.sort_by(|&a, &b| keys[a].total_cmp(&keys[b]).then(a.cmp(&b)));
            self.poses = order.iter().map(|&i| self.poses[i].clone()).collect();
            for m in &mut self.modes {
                m.visits.resize(order.len(), Vec::new());
                m.visits = order
                    .iter()
                    .map(|&i| std::mem::take(&mut m.visits[i]))
                    .collect();
            }
        }
        let n = self.poses.len();
        for m in &mut self.modes {
            m.visits.resize(n, Vec::new());
        }
        let rank = |name: &str| {
            KNOWN_MODES
                .iter()
                .position(|k| *k == name)
                .unwrap_or(KNOWN_MODES.len())
        };
        // Stable: unknown modes keep their order of appearance, one mode's
        // logs their order.
        self.modes.sort_by_key(|m| rank(&m.name));
        self.mode_logs.clear();
        if self.sources.len() > 1 {
            for m in &mut self.modes {
                m.label = format!("{} ({})", m.name, m.source);
            }
        }
        Validation {
            segment: self.segment,
            poses: self.poses,
            modes: self.modes,
            sources: self.sources,
        }
    }
}

/// How series and titles name log `k` of `logs`: its name, or its stem when
/// another log has the same name (two runs' `validate.csv`), or its name
/// and place in the list when the stems agree too.
fn source_name(logs: &[(&str, &str, &MeasurementLog)], k: usize) -> String {
    let (name, stem, _) = logs[k];
    if logs.iter().filter(|l| l.0 == name).count() == 1 {
        name.to_string()
    } else if logs.iter().filter(|l| l.1 == stem).count() == 1 {
        stem.to_string()
    } else {
        format!("{name} #{}", k + 1)
    }
}

/// Gathers the validation segments of `logs` (`(name, stem, log)`; the stem
/// names the mode of a log without a `mode` column), one series per log
/// and mode. Returns the segments found (in the order of [`SEGMENTS`]) and
/// notes for the user.
pub fn gather(logs: &[(&str, &str, &MeasurementLog)]) -> (Vec<Validation>, Vec<String>) {
    let mut notes = Vec::new();
    let mut out = Vec::new();
    for (segment, _) in SEGMENTS {
        let mut b = Builder {
            segment: segment.to_string(),
            poses: Vec::new(),
            by_target: HashMap::new(),
            modes: Vec::new(),
            mode_logs: Vec::new(),
            sources: Vec::new(),
        };
        for (k, (name, stem, log)) in logs.iter().enumerate() {
            if !log.records.iter().any(|r| r.segment == segment) {
                continue;
            }
            let source = source_name(logs, k);
            b.sources.push(source.clone());
            let col = |c: &str| log.columns.extra.iter().position(|e| e == c);
            let (mode_col, pose_col) = (col(MODE_COLUMN), col(POSE_COLUMN));
            if mode_col.is_none() {
                notes.push(format!(
                    "{name}: no `{MODE_COLUMN}` column: its `{segment}` records are taken as one mode named `{stem}`"
                ));
            }
            let mut blank_mode = 0usize;
            for r in log.records.iter().filter(|r| r.segment == segment) {
                let mode = match mode_col.and_then(|i| r.extra.get(i)) {
                    Some(m) if !m.trim().is_empty() => m.trim(),
                    Some(_) => {
                        blank_mode += 1;
                        stem
                    }
                    None => stem,
                };
                let label = pose_col
                    .and_then(|i| r.extra.get(i))
                    .map(|s| s.trim())
                    .filter(|s| !s.is_empty());
                let p = b.pose_index(Xy::new(r.x_target_um, r.y_target_um), label);
                let m = b.mode_index(k, &source, mode);
                let v = &mut b.modes[m].visits;
                if v.len() <= p {
                    v.resize(p + 1, Vec::new());
                }
                v[p].push(Xy::new(r.x_meas_um, r.y_meas_um));
            }
            if blank_mode > 0 {
                notes.push(format!(
                    "{name}: {blank_mode} `{segment}` record(s) with an empty `{MODE_COLUMN}` taken as mode `{stem}`"
                ));
            }
        }
        if !b.sources.is_empty() {
            out.push(b.finish());
        }
    }
    (out, notes)
}

/// Largest of 1, 2, 5 × 10^k not above `v` (at least 1).
fn nice_floor(v: f64) -> f64 {
    if !(v.is_finite() && v > 1.0) {
        return 1.0;
    }
    let mag = 10f64.powf(v.log10().floor());
    [5.0, 2.0, 1.0]
        .iter()
        .map(|m| m * mag)
        .find(|c| *c <= v)
        .unwrap_or(mag)
}

fn fmt_opt(v: Option<f64>) -> String {
    v.map_or("n/a".into(), |v| format!("{v:.3}"))
}

/// The figure of one validation segment (Fig. 10 for the square, 11 for the
/// random points).
pub fn validation_figure(v: &Validation) -> Figure {
    let fig_no = SEGMENTS
        .iter()
        .find(|(s, _)| *s == v.segment)
        .map_or(0, |(_, n)| *n);
    let what = if v.segment == SEGMENT_SQUARE {
        "square trajectory"
    } else if v.segment == SEGMENT_RANDOM {
        "random points"
    } else {
        v.segment.as_str()
    };
    let is_square = v.segment == SEGMENT_SQUARE;
    let mag = magnification(v);
    let targets: Vec<(f64, f64)> = v
        .poses
        .iter()
        .map(|p| (p.target.x_um, p.target.y_um))
        .collect();
    let mut plan = vec![Trace {
        label: Some("targets".into()),
        color: TARGET_COLOR,
        points: if is_square && !targets.is_empty() {
            let mut t = targets.clone();
            t.push(targets[0]);
            t
        } else {
            targets.clone()
        },
        style: if is_square {
            Style::Line
        } else {
            Style::Crosses
        },
    }];
    let mut scatter = Vec::new();
    let mut ap_traces = Vec::new();
    let stats: Vec<Vec<(usize, PoseStats)>> = v.modes.iter().map(|m| m.stats(&v.poses)).collect();
    let summaries: Vec<Option<PoseSummary>> = v.modes.iter().map(|m| m.summary(&v.poses)).collect();
    for (k, m) in v.modes.iter().enumerate() {
        let mut pts = Vec::new();
        let mut dev = Vec::new();
        for (i, vs) in m.visits.iter().enumerate() {
            let t = v.poses[i].target;
            for q in vs {
                let (dx, dy) = (q.x_um - t.x_um, q.y_um - t.y_um);
                pts.push((t.x_um + mag * dx, t.y_um + mag * dy));
                dev.push((dx, dy));
            }
        }
        plan.push(Trace {
            label: Some(m.label.clone()),
            color: series_color(k),
            points: pts,
            style: Style::Dots,
        });
        scatter.push(Trace {
            label: Some(m.label.clone()),
            color: series_color(k),
            points: dev,
            style: Style::Dots,
        });
        let ap = summaries[k]
            .as_ref()
            .map_or("n/a".into(), |s| format!("{:.3}", s.ap_max_um));
        ap_traces.push(Trace {
            label: Some(format!("{} (AP max {ap} µm)", m.label)),
            color: series_color(k),
            points: stats[k].iter().map(|(i, s)| (*i as f64, s.ap_um)).collect(),
            style: Style::LineDots,
        });
    }
    let aps: Vec<f64> = stats
        .iter()
        .flatten()
        .map(|(_, s)| s.ap_um)
        .filter(|a| a.is_finite() && *a > 0.0)
        .collect();
    let (amin, amax) = aps
        .iter()
        .fold((f64::INFINITY, 0.0f64), |(a, b), &x| (a.min(x), b.max(x)));
    let log_scale = aps.len() == stats.iter().map(Vec::len).sum::<usize>()
        && !aps.is_empty()
        && amax / amin > 30.0;
    let cycles = v
        .modes
        .iter()
        .flat_map(|m| m.visits.iter().map(Vec::len))
        .max()
        .unwrap_or(0);
    let rows = vec![
        vec![
            Panel::Xy(XyPanel {
                title: format!("plan view: measured positions, deviations drawn ×{mag}"),
                x_label: "x (µm)".into(),
                y_label: "y (µm)".into(),
                traces: plan,
                y_scale: Scale::Linear,
                equal_aspect: true,
            }),
            Panel::Xy(XyPanel {
                title: "deviations at true scale (every visit)".into(),
                x_label: "x_meas − x_target (µm)".into(),
                y_label: "y_meas − y_target (µm)".into(),
                traces: scatter,
                y_scale: Scale::Linear,
                equal_aspect: true,
            }),
        ],
        vec![Panel::Xy(XyPanel {
            title: format!(
                "accuracy AP per pose (ISO 9283, eq. 6){}",
                if log_scale { ", log scale" } else { "" }
            ),
            x_label: if is_square {
                "pose index along the square A→B→C→D→A".into()
            } else {
                "pose index (order visited)".into()
            },
            y_label: "AP (µm)".into(),
            traces: ap_traces,
            y_scale: if log_scale { Scale::Log } else { Scale::Linear },
            equal_aspect: false,
        })],
        vec![summary_panel(v, &summaries)],
    ];
    let headline: Vec<String> = v
        .modes
        .iter()
        .zip(&summaries)
        .map(|(m, s)| format!("{} {}", m.label, fmt_opt(s.as_ref().map(|s| s.ap_max_um))))
        .collect();
    Figure {
        title: format!(
            "Fig. {fig_no}: accuracy on the {what}, {} poses, up to {cycles} visits each — {}{}; AP max (µm): {}",
            v.poses.len(),
            if v.sources.len() > 1 { "compared: " } else { "" },
            v.sources.join(", "),
            headline.join(", "),
        ),
        rows,
        size: (1400, 1500),
    }
}

/// Magnification of the plan view: the deviations drawn at about 5 % of
/// the poses' span, so that they show beside microns of travel.
fn magnification(v: &Validation) -> f64 {
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for p in &v.poses {
        for (k, c) in [p.target.x_um, p.target.y_um].into_iter().enumerate() {
            lo[k] = lo[k].min(c);
            hi[k] = hi[k].max(c);
        }
    }
    let span = (hi[0] - lo[0]).max(hi[1] - lo[1]);
    let dmax = v
        .modes
        .iter()
        .flat_map(|m| {
            m.visits.iter().enumerate().flat_map(move |(i, vs)| {
                vs.iter().map(move |q| {
                    let t = v.poses[i].target;
                    (q.x_um - t.x_um).hypot(q.y_um - t.y_um)
                })
            })
        })
        .filter(|d| d.is_finite())
        .fold(0.0, f64::max);
    if dmax > 0.0 && span > 0.0 {
        nice_floor(0.05 * span / dmax)
    } else {
        1.0
    }
}

/// The summary bars per mode (and log): AP worst and mean, RP worst.
fn summary_panel(v: &Validation, summaries: &[Option<PoseSummary>]) -> Panel {
    Panel::Bars(BarPanel {
        title: format!(
            "summary per {} (ISO 9283, µm)",
            if v.sources.len() > 1 {
                "mode and log"
            } else {
                "mode"
            }
        ),
        categories: v.modes.iter().map(|m| m.label.clone()).collect(),
        x_label: if v.sources.len() > 1 {
            "mode (log)".into()
        } else {
            "mode".into()
        },
        y_label: "AP, RP (µm)".into(),
        groups: vec![
            BarGroup::labelled(
                BAR_AP_MAX,
                0,
                summaries
                    .iter()
                    .map(|s| s.as_ref().map(|s| s.ap_max_um))
                    .collect(),
                VALUE_RESOLUTION_UM,
                "µm",
            ),
            BarGroup::labelled(
                BAR_AP_MEAN,
                2,
                summaries
                    .iter()
                    .map(|s| s.as_ref().map(|s| s.ap_mean_um))
                    .collect(),
                VALUE_RESOLUTION_UM,
                "µm",
            ),
            BarGroup::labelled(
                BAR_RP_MAX,
                3,
                summaries
                    .iter()
                    .map(|s| s.as_ref().and_then(|s| s.rp_max_um))
                    .collect(),
                VALUE_RESOLUTION_UM,
                "µm",
            ),
        ],
    })
}

/// Legend of the bars of the worst pose's AP.
pub const BAR_AP_MAX: &str = "AP, worst pose";
/// Legend of the bars of the mean AP over poses.
pub const BAR_AP_MEAN: &str = "AP, mean over poses";
/// Legend of the bars of the worst pose's RP.
pub const BAR_RP_MAX: &str = "RP, worst pose";

/// The figure of every validation segment in `logs`, named
/// `<prefix>_fig10_square` / `<prefix>_fig11_random`, and notes. All of
/// `logs` share each figure (one series per log and mode): pass one log
/// for a figure of one run.
pub fn validation_figures(
    logs: &[(&str, &str, &MeasurementLog)],
    prefix: &str,
) -> (Vec<NamedFigure>, Vec<String>) {
    let (sets, notes) = gather(logs);
    let figures = sets
        .iter()
        .map(|v| {
            let fig_no = SEGMENTS
                .iter()
                .find(|(s, _)| *s == v.segment)
                .map_or(0, |(_, n)| *n);
            NamedFigure {
                stem: format!("{prefix}_fig{fig_no}_{}", v.segment),
                figure: validation_figure(v),
            }
        })
        .collect();
    (figures, notes)
}
