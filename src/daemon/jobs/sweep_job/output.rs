//! What a sweep writes from what it measured: the records of its log (the
//! passes resampled onto the step plan's grid, the references and anchors
//! between them), the log's metadata and the job's result. No I/O.

use super::*;

/// The sweep log's metadata: the plan, drift references, the tie, what
/// was measured (`counts`: frames, position samples) and found.
pub(super) fn sweep_metadata(
    a: &SweepArgs,
    tied: &tie::Tie,
    m: &Measured,
    est: &DelayEstimate,
    corr: &AnchorCorrection,
    counts: [usize; 2],
    duration_s: f64,
) -> Metadata {
    let plan = &a.plan;
    let [frames, samples] = counts;
    let mut md = Metadata::new();
    plan.to_metadata(&mut md);
    if let Some(d) = &a.drift {
        d.to_metadata(&mut md);
    }
    tie::to_metadata(&mut md, tied);
    md.insert("daemon_version", env!("CARGO_PKG_VERSION"));
    md.insert("sweep_frames", frames.to_string());
    md.insert("sweep_pos_samples", samples.to_string());
    for (key, used, swept) in [
        ("sweep_position_source_x", m.recorder[0], plan.scan_x),
        ("sweep_position_source_y", m.recorder[1], plan.scan_y),
    ] {
        if swept {
            md.insert(key, if used { "data_recorder" } else { "pos_polling" });
        }
    }
    if m.recorded.records > 0 {
        md.insert("sweep_recorder_records", m.recorded.records.to_string());
        md.insert(
            "sweep_recorder_sample_time_s",
            format!("{:.6}", m.recorded.sample_time_s),
        );
    }
    md.insert("sweep_duration_s", format!("{duration_s:.3}"));
    md.insert("camera_delay_s", format!("{:.7}", est.delay_s));
    md.insert(
        "camera_delay_residual_um",
        format!("{:.5}", est.residual_um),
    );
    anchor_metadata(&mut md, corr, m.anchors.len(), m.anchor_s);
    md
}

pub(super) fn result_json(
    est: &DelayEstimate,
    frames: usize,
    samples: usize,
    records: usize,
    duration_s: f64,
) -> Value {
    json!({
        "mode": "sweep",
        "camera_delay_s": est.delay_s,
        "camera_delay_residual_um": est.residual_um,
        "camera_delay_passes": est.passes,
        "frames": frames,
        "pos_samples": samples,
        "records": records,
        "duration_s": duration_s,
    })
}

/// How [`records`] builds one log.
pub(super) struct RecordContext<'a> {
    pub(super) plan: &'a SweepPlan,
    /// Frames are placed at `stamp − delay_s`.
    pub(super) delay_s: f64,
    /// Rig time of the log's zero.
    pub(super) origin: f64,
    /// The anchors' correction (its differences are logged in the anchor
    /// rows in every variant).
    pub(super) corr: &'a AnchorCorrection,
    /// Whether the scan records are corrected by it.
    pub(super) apply: bool,
}

/// `v` µm with 4 decimals.
pub(super) fn um(v: f64) -> String {
    format!("{v:.4}")
}

/// The resampled records of every pass, in plan order (forward passes
/// ascending, backward descending, as the step plan), frames placed at
/// `stamp − delay_s`, corrected by the anchors when `apply`; times relative
/// to `origin`. What was measured between passes goes before the pass it
/// preceded.
pub(super) fn records(
    passes: &[PassData],
    between: &[(usize, Between)],
    ctx: &RecordContext,
) -> Vec<Record> {
    let plan = ctx.plan;
    let mut out = Vec::new();
    for k in 0..=passes.len() {
        for (_, b) in between.iter().filter(|(before, _)| *before == k) {
            out.push(match b {
                Between::Ref(r) => r.clone(),
                Between::Anchor(row) => anchor_record(row, ctx),
            });
        }
        let Some(p) = passes.get(k) else { break };
        let s = p.spec;
        let grid = plan.grid(s.x_axis);
        let mut vals: Vec<_> = resample(&frames_at(p, ctx.delay_s), &grid, plan.step_um)
            .into_iter()
            .flatten()
            .collect();
        if !s.forward {
            vals.reverse();
        }
        for v in vals {
            let (c_scan, c_held) = if ctx.apply {
                ctx.corr.at(s.x_axis, s.forward, v.pos_um)
            } else {
                (0.0, 0.0)
            };
            let scan_meas = v.pos_um - (v.e_scan_um + c_scan);
            let held_meas = s.hold_um - (v.e_held_um + c_held);
            let (x, y, xm, ym) = if s.x_axis {
                (v.pos_um, s.hold_um, scan_meas, held_meas)
            } else {
                (s.hold_um, v.pos_um, held_meas, scan_meas)
            };
            let (cx, cy) = if s.x_axis {
                (c_scan, c_held)
            } else {
                (c_held, c_scan)
            };
            let applied = |c: f64| if ctx.apply { um(c) } else { String::new() };
            out.push(Record {
                t_s: v.t_s - ctx.origin,
                segment: s.segment().to_owned(),
                cycle: s.cycle,
                x_target_um: x,
                y_target_um: y,
                x_cmd_um: x,
                y_cmd_um: y,
                x_meas_um: xm,
                y_meas_um: ym,
                temp_c: None,
                theta_urad: Some(v.theta_urad),
                extra: vec![
                    um(x),
                    um(y),
                    format!("{:.3}", v.quality),
                    format!("{}", s.sign() * s.velocity_um_per_s),
                    format!("{:.6}", v.t_s + ctx.delay_s - ctx.origin),
                    v.frames.to_string(),
                    applied(cx),
                    applied(cy),
                ],
            });
        }
    }
    out
}

/// An anchor's record: target = command = the anchor, the measured
/// position, velocity 0, and that cycle's anchor − sweep difference in the
/// correction columns (empty where the sweep had no value there).
pub(super) fn anchor_record(row: &AnchorRow, ctx: &RecordContext) -> Record {
    let m = &row.m;
    let (x, y) = if m.x_axis {
        (m.pos_um, m.hold_um)
    } else {
        (m.hold_um, m.pos_um)
    };
    let diff = ctx.corr.diff_of(m).map(|d| {
        if m.x_axis {
            (d.scan_um, d.held_um)
        } else {
            (d.held_um, d.scan_um)
        }
    });
    let t = m.t_s - ctx.origin;
    Record {
        t_s: t,
        segment: anchor_segment(m.x_axis, m.forward).to_owned(),
        cycle: m.cycle,
        x_target_um: x,
        y_target_um: y,
        x_cmd_um: x,
        y_cmd_um: y,
        x_meas_um: m.meas.x_um,
        y_meas_um: m.meas.y_um,
        temp_c: None,
        theta_urad: row.theta_urad,
        extra: vec![
            row.reported[0].map_or(String::new(), um),
            row.reported[1].map_or(String::new(), um),
            format!("{:.3}", m.quality),
            "0".to_owned(),
            format!("{t:.6}"),
            row.frames.to_string(),
            diff.map_or(String::new(), |d| um(d.0)),
            diff.map_or(String::new(), |d| um(d.1)),
        ],
    }
}

/// The anchors' summary in the log's metadata (docs/measurement-log.md,
/// "Sweep logs").
pub(super) fn anchor_metadata(
    md: &mut Metadata,
    corr: &AnchorCorrection,
    measured: usize,
    duration_s: f64,
) {
    md.insert("sweep_anchors", measured.to_string());
    md.insert("sweep_anchor_positions", corr.points.len().to_string());
    let labels = |v: Vec<String>| {
        if v.is_empty() {
            "none".to_owned()
        } else {
            v.join(" ")
        }
    };
    md.insert(
        "sweep_anchor_rejected",
        labels(corr.rejected().map(|p| p.label()).collect()),
    );
    md.insert(
        "sweep_anchor_unmatched",
        labels(corr.unmatched().map(|p| p.label()).collect()),
    );
    let flat: Vec<String> = corr
        .groups
        .iter()
        .flat_map(|g| {
            ["along", "across"]
                .into_iter()
                .zip(g.flat)
                .filter(|(_, f)| *f)
                .map(move |(c, _)| format!("{}/{c}", g.label()))
        })
        .collect();
    md.insert("sweep_anchor_flat", labels(flat));
    for (axis, x_axis) in [("x", true), ("y", false)] {
        let (scan, held) = corr.max_abs_um(x_axis);
        md.insert(format!("sweep_anchor_max_along_{axis}_um"), um(scan));
        md.insert(format!("sweep_anchor_max_across_{axis}_um"), um(held));
        md.insert(
            format!("sweep_anchor_typical_spread_{axis}_um"),
            um(corr.typical_spread_um[usize::from(!x_axis)]),
        );
    }
    md.insert("sweep_anchor_duration_s", format!("{duration_s:.3}"));
}

/// The anchors' summary in the job's result.
pub(super) fn anchor_json(
    plan: &SweepPlan,
    corr: &AnchorCorrection,
    measured: usize,
    duration_s: f64,
) -> Value {
    let axis = |x_axis: bool| {
        let (scan, held) = corr.max_abs_um(x_axis);
        json!({"max_along_um": scan, "max_across_um": held,
               "typical_spread_um": corr.typical_spread_um[usize::from(!x_axis)]})
    };
    json!({
        "spacing_um": plan.anchor_spacing_used_um(),
        "measured": measured,
        "positions": corr.points.len(),
        "rejected": corr.rejected().map(|p| p.label()).collect::<Vec<_>>(),
        "unmatched": corr.unmatched().map(|p| p.label()).collect::<Vec<_>>(),
        "duration_s": duration_s,
        "x": axis(true),
        "y": axis(false),
        "groups": corr.groups.iter().map(|g| json!({
            "group": g.label(),
            "chi2_per_dof": g.chi2_per_dof.map(|c| c.is_finite().then_some(c)),
            "flat": g.flat,
        })).collect::<Vec<_>>(),
    })
}
