//! The main job's report: the human-readable table of AP and RP (with the
//! model table's note and the drift comparison), the validation offsets
//! the summary carries, and the run's figures. A file of its own: it reads
//! the summary and the logs, never the rig or the daemon.

use super::pipeline::DRIFT_METHODS;
use super::{paper_ap_um, RunPlan};
use serde_json::{json, Value};
use std::path::{Path, PathBuf};

/// AP of one validation result and its constant part: the mean over poses
/// of the signed APx, APy (measured − target, µm), i.e. the offset common
/// to every pose that drift between the characterization and the
/// validation leaves.
pub fn table_offset(r: &Value) -> Value {
    let poses = r["poses"].as_array().map_or(&[][..], |v| v.as_slice());
    let mean = |k: &str| -> Option<f64> {
        let v: Vec<f64> = poses.iter().filter_map(|p| p[k].as_f64()).collect();
        (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
    };
    json!({"ap_um": r["ap_um"], "ap_mean_um": r["ap_mean_um"],
           "offset_um": [mean("apx_um"), mean("apy_um")],
           "references": r["drift"]["references_logged"]})
}

/// Why the model table stays behind the lookup tables, when it does: it is
/// fitted to the short characterization, and a plan that samples it
/// coarser than half the screw's lead, or without moves of varied length,
/// withholds the two things the model needs (the screw's cycle, the lost
/// motion that grows with the move length). Said from the plan's own
/// numbers, so a reader of `--short` is not left with figures that
/// contradict the README's.
fn model_note(summary: &Value) -> Option<String> {
    let worse: Vec<&str> = ["square", "random"]
        .into_iter()
        .filter(|t| {
            let ap = |m: &str| summary[*t][m]["ap_um"].as_f64();
            matches!((ap("model"), ap("table")), (Some(m), Some(t)) if m > t)
        })
        .collect();
    if worse.is_empty() {
        return None;
    }
    let ch = &summary["characterization"];
    let step = ch["short_step_um"].as_f64()?;
    let moves = ch["short_moves_per_cycle"].as_u64()?;
    let leads: Vec<f64> = ch["lead_periods_um"]
        .as_array()
        .map(|v| v.iter().filter_map(Value::as_f64).collect())
        .unwrap_or_default();
    let mut why = Vec::new();
    if let Some(lead) = leads
        .iter()
        .copied()
        .filter(|l| step > l / 2.0)
        .reduce(f64::min)
    {
        why.push(format!(
            "its {step:.0} µm steps cannot resolve the screw's {lead:.0} µm cycle (a step of at most {:.0} µm can)",
            lead / 2.0
        ));
    }
    if moves == 0 {
        why.push(
            "it has no moves of varied length, so it cannot learn the lost motion that grows with the move length"
                .to_owned(),
        );
    }
    let because = if why.is_empty() {
        "on this plan the model's terms do not hold this stage's error better than the tables"
            .to_owned()
    } else {
        why.join("; ")
    };
    let full = RunPlan::paper();
    Some(format!(
        "note: the model table ({}) is behind the lookup tables: it is fitted to the short characterization, and {because}. \
         The default plan ({:.0} µm steps, {} moves of varied length per cycle) gives the model the figures the README reports.\n",
        worse.join(" and "),
        full.short_step_um,
        full.short_moves_per_cycle
    ))
}

/// The figures of a run (`hil-sim run --plots DIR`): from the run's logs in
/// `data_dir` (`files` as [`RunReport::files`] lists them), each log's own
/// figures, no comparison: Figs. 4–5 (and 6 with at least two cycles) of
/// every characterization log that has scans, Figs. 10–11 of every
/// validation log. So `validate_fig11_random` shows the AP and RP the run
/// printed, and the drift comparison's and the sweep's and grid's
/// validations are figures of their own (`validate-drift-off_fig11_random`,
/// …), never pooled into one mode. Logs with no paper figure (the grid's
/// map, sweeps' raw passes without scans) are named in the notes.
pub fn plot_run(
    data_dir: &Path,
    files: &[String],
    out_dir: &Path,
    format: micropos::plot::Format,
) -> Result<micropos::plot::Plotted, micropos::plot::PlotError> {
    use micropos::plot::{plot_logs, read_logs};
    let paths: Vec<PathBuf> = files
        .iter()
        .filter(|f| f.ends_with(".csv"))
        .map(|f| data_dir.join(f))
        .collect();
    let (plottable, other): (Vec<_>, Vec<_>) = read_logs(&paths)?.into_iter().partition(|l| {
        let c = micropos::plot::report::contents(&l.log);
        c.characterization || c.validation
    });
    let mut p = plot_logs(&plottable, out_dir, format, false)?;
    for l in other {
        p.notes.push(format!(
            "{}: no scan or validation records: none of the paper's figures",
            l.name
        ));
    }
    Ok(p)
}

/// The human-readable table of AP and RP per trajectory and mode.
pub fn format_table(summary: &Value) -> String {
    let mut s =
        String::from("trajectory  mode         AP max µm  AP mean µm  RP max µm   paper AP µm\n");
    let f = |v: &Value| v.as_f64().map_or("-".to_owned(), |x| format!("{x:.3}"));
    for test in ["square", "random"] {
        for mode in ["raw", "table", "model", "closed_loop"] {
            let r = &summary[test][mode];
            s.push_str(&format!(
                "{test:<11} {mode:<12} {:>9}  {:>10}  {:>9}   {:>11}\n",
                f(&r["ap_um"]),
                f(&r["ap_mean_um"]),
                f(&r["rp_um"]),
                paper_ap_um(test, mode).map_or("-".to_owned(), |x| format!("≈{x}"))
            ));
        }
    }
    if let Some(note) = model_note(summary) {
        s.push_str(&note);
    }
    let d = &summary["drift"];
    if !d.is_null() {
        s.push_str(&format!(
            "drift: references every {} s in the characterizations; live {} every {} s\n",
            d["characterization_every_s"], d["live"], d["live_every_s"]
        ));
        let cmp = &d["compare"];
        if cmp.is_object() {
            s.push_str("table mode by live drift  AP max µm (square / random)  offset x, y µm (square / random)\n");
            for m in DRIFT_METHODS {
                let off = |t: &str| {
                    let o = &cmp[m][t]["offset_um"];
                    format!("{}, {}", f(&o[0]), f(&o[1]))
                };
                s.push_str(&format!(
                    "  {m:<9}               {:>7} / {:<7}            {} / {}\n",
                    f(&cmp[m]["square"]["ap_um"]),
                    f(&cmp[m]["random"]["ap_um"]),
                    off("square"),
                    off("random")
                ));
            }
        }
    }
    if let Some(p) = summary["phases_s"].as_object() {
        let list: Vec<String> = p
            .iter()
            .map(|(k, v)| format!("{k} {:.0}", v.as_f64().unwrap_or(f64::NAN)))
            .collect();
        s.push_str(&format!("simulated s per phase: {}\n", list.join(", ")));
    }
    let sw = &summary["sweep"];
    if sw.is_object() {
        let ap = |k: &str, t: &str| f(&sw[k][t]["ap_um"]);
        s.push_str(&format!(
            "sweep: {:.0} simulated s (step plan {:.0} s); camera delay {:.3} ms estimated, {:.3} ms true\n\
             table AP max µm (square / random), live drift off: step {} / {}, sweep {} / {}, sweep delay ignored {} / {}, sweep without anchors {} / {}\n",
            sw["simulated_s"].as_f64().unwrap_or(f64::NAN),
            sw["step_simulated_s"].as_f64().unwrap_or(f64::NAN),
            sw["result"]["camera_delay_s"].as_f64().unwrap_or(f64::NAN) * 1e3,
            sw["true_delay_s"].as_f64().unwrap_or(f64::NAN) * 1e3,
            ap("step_table_ap_um", "square"),
            ap("step_table_ap_um", "random"),
            ap("run-sweep", "square"),
            ap("run-sweep", "random"),
            ap("run-sweep-nodelay", "square"),
            ap("run-sweep-nodelay", "random"),
            ap("run-sweep-noanchor", "square"),
            ap("run-sweep-noanchor", "random"),
        ));
    }
    let g = &summary["grid"];
    if g.is_object() {
        let ap = |k: &str, t: &str| f(&g[k][t]["ap_um"]);
        s.push_str(&format!(
            "grid: {} nodes at {} µm pitch, {:.0} simulated s; 2-D map table AP max µm (square / random), live drift off: {} / {} (step tables {} / {})\n",
            g["nodes"],
            g["pitch_um"],
            g["simulated_s"].as_f64().unwrap_or(f64::NAN),
            f(&g["square"]["ap_um"]),
            f(&g["random"]["ap_um"]),
            ap("step_table_ap_um", "square"),
            ap("step_table_ap_um", "random"),
        ));
    }
    let ch = &summary["characterization"];
    s.push_str(&format!(
        "characterization: {} points, {:.0} simulated s; short: {} points, {:.0} simulated s\n",
        ch["points"],
        ch["simulated_s"].as_f64().unwrap_or(f64::NAN),
        ch["short_points"],
        ch["short_simulated_s"].as_f64().unwrap_or(f64::NAN)
    ));
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_model_table_behind_the_tables_is_explained_from_the_plan() {
        let summary = |model: f64, step: f64, moves: u32| {
            json!({
                "square": {"table": {"ap_um": 3.22}, "model": {"ap_um": model}},
                "random": {"table": {"ap_um": 6.41}, "model": {"ap_um": 1.0}},
                "characterization": {"short_step_um": step, "short_moves_per_cycle": moves,
                                     "lead_periods_um": [400.0, 400.0]},
            })
        };
        let n = model_note(&summary(5.06, 500.0, 0)).unwrap();
        assert!(n.contains("model table (square)"), "{n}");
        assert!(
            n.contains("500 µm steps cannot resolve the screw's 400 µm cycle"),
            "{n}"
        );
        assert!(n.contains("at most 200 µm"), "{n}");
        assert!(n.contains("no moves of varied length"), "{n}");
        // Fine steps, moves of varied length: no plan reason, a plain one.
        let n = model_note(&summary(5.06, 50.0, 40)).unwrap();
        assert!(
            !n.contains("cannot resolve") && !n.contains("no moves"),
            "{n}"
        );
        // The model ahead: nothing to explain.
        assert_eq!(model_note(&summary(0.4, 500.0, 0)), None);
        // The note is part of the table.
        assert!(format_table(&summary(5.06, 500.0, 0)).contains("note: the model table"));
    }
}
