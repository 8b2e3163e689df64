//! The main job's phases after start-up, as a socket client: reference,
//! the characterizations, the tables, the validation, the drift
//! comparison, the sweep and grid rows, each timed in rig time. A file of
//! its own: the experiment itself, apart from the rig's and the daemon's
//! set-up (`mod.rs`) and the report (`report`).

use super::client::Client;
use super::report::table_offset;
use super::{RunError, RunOptions, RunPlan, Started, MAX_RESUMES};
use serde_json::{json, Value};
use std::time::{Duration, Instant};

/// How often the start-up asks whether the daemon's controllers are
/// connected (rig time).
const CONNECT_POLL: Duration = Duration::from_millis(50);

/// The live drift methods the comparison runs, in this order.
pub const DRIFT_METHODS: [&str; 3] = ["off", "static", "adaptive"];

/// The validation request every run makes (both tests, the plan's cycles,
/// poses, frames and settling, the paper table); callers add modes and the
/// model table.
fn validate_request(p: &RunPlan, log: &str) -> Value {
    json!({"cmd": "validate", "action": "start", "test": "both",
           "log": log, "cycles": p.validate_cycles,
           "square_step_um": p.square_step_um, "origin_x_um": p.validate_origin_um,
           "origin_y_um": p.validate_origin_um, "table": "run-paper.toml",
           "frames_per_point": p.frames_per_point, "settle_s": p.settle_s})
}

/// Simulated and wall seconds per phase, in order: the `phases_s` block of
/// the summary and [`super::RunReport::phases_wall_s`] (wall time is not in
/// the JSON).
struct Laps {
    phases: serde_json::Map<String, Value>,
    /// Rig time at the end of the last phase, s.
    mark: f64,
    walls: Vec<(String, f64)>,
    wall_mark: Instant,
}

impl Laps {
    /// The first phase starts at rig time `mark_s`.
    fn start(mark_s: f64) -> Self {
        Laps {
            phases: serde_json::Map::new(),
            mark: mark_s,
            walls: Vec::new(),
            wall_mark: Instant::now(),
        }
    }

    /// Ends phase `name` at rig time `now_s`.
    fn lap(&mut self, now_s: f64, name: &str) {
        self.phases
            .insert(name.to_owned(), json!(now_s - self.mark));
        self.mark = now_s;
        self.walls
            .push((name.to_owned(), self.wall_mark.elapsed().as_secs_f64()));
        self.wall_mark = Instant::now();
    }
}

/// The main job after start-up, phase after phase: reference, the two
/// characterizations, the tables, the validation, the drift comparison,
/// the sweep and grid rows; returns the summary, the validation results,
/// the files written and the wall seconds per phase.
pub(super) async fn pipeline(
    opts: &RunOptions,
    st: &Started,
    progress: &mut dyn FnMut(&str),
) -> Result<(Value, Value, Vec<String>, Vec<(String, f64)>), RunError> {
    let p = &opts.plan;
    let mut c = Client::connect(&st.socket).await?;
    wait_connected(&mut c).await?;
    progress("referencing both axes");
    let mut laps = Laps::start(c.now_s().await?);
    c.call(json!({"cmd": "reference", "axes": "xy"})).await?;
    laps.lap(c.now_s().await?, "reference");
    let chars = characterize(&mut c, p, &mut laps, progress).await?;
    let paper = build_tables(&mut c, &mut laps, progress).await?;
    c.call(
        json!({"cmd": "drift", "action": "set", "method": p.live_drift,
                  "every_s": p.live_drift_every_s}),
    )
    .await?;
    progress(&format!(
        "validate: square and Table II in raw, table, model, closed_loop (live drift {})",
        p.live_drift
    ));
    let mut req = validate_request(p, "validate.csv");
    req["model_table"] = json!("run-short-model.toml");
    let v = c.validate(req, progress).await?;
    laps.lap(c.now_s().await?, "validate");
    let results = v["validation"]["results"].clone();
    let mut summary = json!({});
    for test in ["square", "random"] {
        let mut t = json!({});
        for mode in ["raw", "table", "model", "closed_loop"] {
            let r = &results[test][mode];
            t[mode] = json!({"ap_um": r["ap_um"], "rp_um": r["rp_um"],
                             "ap_mean_um": r["ap_mean_um"], "rp_mean_um": r["rp_mean_um"]});
        }
        summary[test] = t;
    }
    summary["characterization"] = json!({
        "points": chars[0].0, "simulated_s": chars[0].1, "settle_s": p.paper_settle_s,
        "short_points": chars[1].0, "short_simulated_s": chars[1].1,
        "short_settle_s": p.settle_s, "short_step_um": p.short_step_um,
        "short_moves_per_cycle": p.short_moves_per_cycle,
        "lead_periods_um": st.sim.rig().lead_periods_um(),
    });
    let mut files = [
        "charact-paper.csv",
        "charact-short.csv",
        "validate.csv",
        "run-paper.toml",
        "run-short-model.toml",
    ]
    .map(str::to_owned)
    .to_vec();
    let mut drift = json!({
        "characterization_every_s": p.drift_every_s,
        "tables_drift": paper["drift"],
        "live": p.live_drift, "live_every_s": p.live_drift_every_s,
        "validation": {"square": table_offset(&results["square"]["table"]),
                       "random": table_offset(&results["random"]["table"])},
    });
    if p.drift_compare {
        drift["compare"] = drift_compare(&mut c, p, &mut laps, &mut files, progress).await?;
    }
    summary["drift"] = drift;
    if p.sweep_velocity_um_per_s > 0.0 {
        let mut sw = sweep_phase(opts, &mut c, progress, &mut files).await?;
        sw["step_simulated_s"] = json!(chars[0].1);
        sw["step_table_ap_um"] = summary["drift"]["compare"]["off"].clone();
        summary["sweep"] = sw;
        laps.lap(c.now_s().await?, "sweep");
    }
    if p.grid_pitch_um > 0.0 {
        let mut g = grid_phase(opts, &mut c, progress, &mut files).await?;
        g["step_table_ap_um"] = summary["drift"]["compare"]["off"].clone();
        summary["grid"] = g;
        laps.lap(c.now_s().await?, "grid");
    }
    summary["phases_s"] = Value::Object(laps.phases);
    // Frames the camera delivered and the decoder read: the work the run
    // cannot avoid (the main-job benchmark's baseline is their cost).
    let cam = &c.call(json!({"cmd": "status"})).await?["camera"];
    summary["frames"] = json!({"grabbed": cam["frames"], "decoded": cam["decoded"]});
    Ok((summary, results, files, laps.walls))
}

/// Waits until the daemon has connected both controllers (30 s at most).
async fn wait_connected(c: &mut Client) -> Result<(), RunError> {
    let t0 = Instant::now();
    loop {
        // Wait first, then ask. Why: the daemon connects its controllers
        // at the rig's first instant, and whether a status call at that
        // same instant already sees them depends only on how many task
        // polls the daemon's start-up takes; asking one poll period later
        // puts the rig's time origin for the run (every later instant, so
        // every result) out of reach of that.
        tokio::time::sleep(CONNECT_POLL).await;
        let s = c.call(json!({"cmd": "status"})).await?;
        if s["rig"]["connected"]["x"] == true && s["rig"]["connected"]["y"] == true {
            return Ok(());
        }
        if t0.elapsed() > Duration::from_secs(30) {
            return Err(RunError::Setup(format!(
                "controllers not connected after 30 s: {s}"
            )));
        }
    }
}

/// The paper's characterization and the ten times shorter one (for the
/// model table), each followed to its end (resumed from its log after a
/// transient fault); returns (points, simulated s) of each.
async fn characterize(
    c: &mut Client,
    p: &RunPlan,
    laps: &mut Laps,
    progress: &mut dyn FnMut(&str),
) -> Result<Vec<(u64, f64)>, RunError> {
    let mut chars = Vec::new();
    for (log, step, moves, settle_s) in [
        ("charact-paper.csv", p.step_um, 0, p.paper_settle_s),
        (
            "charact-short.csv",
            p.short_step_um,
            p.short_moves_per_cycle,
            p.settle_s,
        ),
    ] {
        progress(&format!(
            "characterize {log}: {step} µm steps over {} × {} µm, {} cycles, {settle_s} s settle",
            p.x_range_um, p.y_range_um, p.cycles
        ));
        let t_start = c.now_s().await?;
        c.call(json!({"cmd": "characterize", "action": "start", "log": log,
                      "step_um": step, "x_range_um": p.x_range_um, "y_range_um": p.y_range_um,
                      "cycles": p.cycles, "frames_per_point": p.frames_per_point,
                      "settle_s": settle_s, "drift_every_s": p.drift_every_s,
                      "drift_reference_um": p.drift_reference_um,
                      "moves_per_cycle": moves}))
            .await?;
        // A job that fails on a transient fault (a late serial answer on a
        // loaded machine) is resumed from its log, as a user would: every
        // point is logged once (see the daemon's resume).
        let mut attempts = 0;
        let s = loop {
            match c
                .follow(
                    json!({"cmd": "characterize", "action": "status"}),
                    "characterize",
                    progress,
                )
                .await
            {
                Err(RunError::Job { state, error, .. }) if attempts < MAX_RESUMES => {
                    attempts += 1;
                    progress(&format!(
                        "characterize {log} {state} ({error}); resuming it from its log ({attempts}/{MAX_RESUMES})"
                    ));
                    tokio::time::sleep(Duration::from_millis(500)).await;
                    c.call(json!({"cmd": "characterize", "action": "resume", "log": log}))
                        .await?;
                }
                other => break other?,
            }
        };
        let t_end = c.now_s().await?;
        chars.push((s["job"]["done"].as_u64().unwrap_or(0), t_end - t_start));
        laps.lap(t_end, log.trim_end_matches(".csv"));
    }
    Ok(chars)
}

/// `tables build`: the paper tables from the paper's characterization
/// (activated), the model table from the short one; returns the paper
/// build's reply.
async fn build_tables(
    c: &mut Client,
    laps: &mut Laps,
    progress: &mut dyn FnMut(&str),
) -> Result<Value, RunError> {
    progress(
        "tables build: paper tables from charact-paper.csv, model table from charact-short.csv",
    );
    let paper = c
        .call(
            json!({"cmd": "tables", "action": "build", "log": "charact-paper.csv",
                     "name": "run", "kinds": ["paper"], "activate": true}),
        )
        .await?;
    let model = c
        .call(
            json!({"cmd": "tables", "action": "build", "log": "charact-short.csv",
                     "name": "run-short", "kinds": ["model"]}),
        )
        .await?;
    laps.lap(c.now_s().await?, "tables");
    let rms = |i: usize| {
        model["model"]["rms_residual_um"][i]
            .as_f64()
            .unwrap_or(f64::NAN)
    };
    progress(&format!(
        "  paper tables: squareness {:.1} µrad; model fit residual rms x {:.3} µm, y {:.3} µm",
        paper["paper"]["report"]["squareness_urad"]
            .as_f64()
            .unwrap_or(f64::NAN),
        rms(0),
        rms(1)
    ));
    Ok(paper)
}

/// The drift comparison: `table` mode validated again with each live
/// drift method ([`DRIFT_METHODS`]); returns the `compare` block.
async fn drift_compare(
    c: &mut Client,
    p: &RunPlan,
    laps: &mut Laps,
    files: &mut Vec<String>,
    progress: &mut dyn FnMut(&str),
) -> Result<Value, RunError> {
    let mut cmp = json!({});
    for method in DRIFT_METHODS {
        progress(&format!(
            "validate: table mode with live drift {method} (the drift comparison)"
        ));
        c.call(json!({"cmd": "drift", "action": "set", "method": method,
                      "every_s": p.live_drift_every_s}))
            .await?;
        c.call(json!({"cmd": "drift", "action": "reset"})).await?;
        let log = format!("validate-drift-{method}.csv");
        let mut req = validate_request(p, &log);
        req["modes"] = json!(["table"]);
        let v = c.validate(req, progress).await?;
        laps.lap(c.now_s().await?, &format!("validate_drift_{method}"));
        let r = &v["validation"]["results"];
        cmp[method] = json!({"square": table_offset(&r["square"]["table"]),
                             "random": table_offset(&r["random"]["table"])});
        files.push(log);
    }
    Ok(cmp)
}

/// The sweep row: `characterize start mode=sweep` over the plan's ranges
/// with the step characterization's drift references and the plan's
/// anchors, tables from the corrected log, the delay-ignored one and (with
/// anchors) the unanchored one, each validated in `table` mode with live
/// drift off (compare with the drift comparison's `off` row of the step
/// tables).
async fn sweep_phase(
    opts: &RunOptions,
    c: &mut Client,
    progress: &mut dyn FnMut(&str),
    files: &mut Vec<String>,
) -> Result<Value, RunError> {
    let p = &opts.plan;
    progress(&format!(
        "characterize charact-sweep.csv: sweeps at {} and {} µm/s over {} × {} µm, {} cycles",
        p.sweep_velocity_um_per_s,
        2.0 * p.sweep_velocity_um_per_s,
        p.x_range_um,
        p.y_range_um,
        p.cycles.max(2)
    ));
    let t0 = c.now_s().await?;
    let anchored = p.sweep_anchor_spacing_um > 0.0;
    let mut req = json!({"cmd": "characterize", "action": "start", "log": "charact-sweep.csv",
                  "mode": "sweep", "velocity_um_per_s": p.sweep_velocity_um_per_s,
                  "uncorrected_log": "charact-sweep-nodelay.csv", "step_um": p.step_um,
                  "x_range_um": p.x_range_um, "y_range_um": p.y_range_um,
                  "cycles": p.cycles.max(2), "frames_per_point": p.frames_per_point,
                  "settle_s": p.settle_s, "drift_every_s": p.drift_every_s,
                  "drift_reference_um": p.drift_reference_um,
                  "anchor_spacing_um": p.sweep_anchor_spacing_um});
    if anchored {
        req["unanchored_log"] = json!("charact-sweep-noanchor.csv");
    }
    c.call(req).await?;
    let s = c
        .follow(
            json!({"cmd": "characterize", "action": "status"}),
            "sweep",
            progress,
        )
        .await?;
    let simulated_s = c.now_s().await? - t0;
    let res = &s["job"]["result"];
    c.call(json!({"cmd": "drift", "action": "set", "method": "off"}))
        .await?;
    let mut out = json!({"simulated_s": simulated_s, "result": res,
                         "true_delay_s": opts.rig.camera.latency_us * 1e-6});
    let mut logs = vec![
        ("charact-sweep.csv", "run-sweep"),
        ("charact-sweep-nodelay.csv", "run-sweep-nodelay"),
    ];
    if anchored {
        logs.push(("charact-sweep-noanchor.csv", "run-sweep-noanchor"));
    }
    for (log, stem) in logs {
        c.call(
            json!({"cmd": "tables", "action": "build", "log": log, "name": stem,
                      "kinds": ["paper"]}),
        )
        .await?;
        let vlog = format!("validate-{stem}.csv");
        let mut req = validate_request(p, &vlog);
        req["modes"] = json!(["table"]);
        req["table"] = json!(format!("{stem}-paper.toml"));
        progress(&format!("validate: table mode with {stem}-paper.toml"));
        let v = c.validate(req, progress).await?;
        let r = &v["validation"]["results"];
        out[stem] = json!({"square": table_offset(&r["square"]["table"]),
                           "random": table_offset(&r["random"]["table"])});
        files.extend([log.to_owned(), format!("{stem}-paper.toml"), vlog]);
    }
    Ok(out)
}

/// The grid row: `characterize start plan=grid` over the plan's ranges at
/// `grid_pitch_um` (one cycle, the plan's drift references), its 2-D map
/// (`tables build` kind grid), validated in `table` mode with live drift
/// off.
async fn grid_phase(
    opts: &RunOptions,
    c: &mut Client,
    progress: &mut dyn FnMut(&str),
    files: &mut Vec<String>,
) -> Result<Value, RunError> {
    let p = &opts.plan;
    progress(&format!(
        "characterize charact-grid.csv: a grid at {} µm pitch over {} × {} µm",
        p.grid_pitch_um, p.x_range_um, p.y_range_um
    ));
    let t0 = c.now_s().await?;
    c.call(
        json!({"cmd": "characterize", "action": "start", "log": "charact-grid.csv",
                  "plan": "grid", "pitch_um": p.grid_pitch_um,
                  "x_range_um": p.x_range_um, "y_range_um": p.y_range_um, "cycles": 1,
                  "frames_per_point": p.frames_per_point, "settle_s": p.settle_s,
                  "drift_every_s": p.drift_every_s,
                  "drift_reference_um": p.drift_reference_um}),
    )
    .await?;
    let s = c
        .follow(
            json!({"cmd": "characterize", "action": "status"}),
            "grid",
            progress,
        )
        .await?;
    let simulated_s = c.now_s().await? - t0;
    let built = c
        .call(
            json!({"cmd": "tables", "action": "build", "log": "charact-grid.csv",
                     "name": "run-grid", "kinds": ["grid"]}),
        )
        .await?;
    c.call(json!({"cmd": "drift", "action": "set", "method": "off"}))
        .await?;
    let mut req = validate_request(p, "validate-grid.csv");
    req["modes"] = json!(["table"]);
    req["table"] = json!("run-grid-grid.toml");
    progress("validate: table mode with the grid map run-grid-grid.toml");
    let v = c.validate(req, progress).await?;
    let r = &v["validation"]["results"];
    files.extend(
        [
            "charact-grid.csv",
            "run-grid-grid.toml",
            "validate-grid.csv",
        ]
        .map(str::to_owned),
    );
    Ok(
        json!({"pitch_um": p.grid_pitch_um, "nodes": s["job"]["done"],
              "simulated_s": simulated_s, "report": built["grid"]["report"],
              "square": table_offset(&r["square"]["table"]),
              "random": table_offset(&r["random"]["table"])}),
    )
}
