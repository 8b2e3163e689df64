//! The main job (`hil-sim run`) end to end on a reduced plan: simulated rig
//! on ptys + camera socket + sim clock, microposd in-process on a Unix
//! socket, and only socket commands from there (reference, two
//! characterizations, tables build, validate in all four modes).
//!
//! Checks the JSON shape the README documents and that compensation
//! improves on raw by a stated factor: the grid row's 2-D map (1 mm pitch)
//! by ≥ 3×, the lookup tables and the model by ≥ 5× in AP (typical on this plan: raw ≈ 13 µm, table ≈ 0.2-0.5 µm,
//! model ≈ 1-1.5 µm from 500 µm steps), closed loop to ≤ 0.5 µm
//! (typically ≈ 0.1 µm; its tolerance is 0.1 µm).

use hil_sim::run::{run, RunOptions, RunPlan};

#[test]
fn pipeline_through_the_daemon_improves_on_raw() {
    let dir = tempfile::tempdir().unwrap();
    let plan = RunPlan {
        step_um: 100.0,
        short_step_um: 500.0,
        cycles: 1,
        validate_cycles: 2,
        square_step_um: 2000.0,
        // The drift comparison has its own test (live_drift.rs).
        drift_compare: false,
        // The sweep row has its own test (sweep_charact.rs).
        sweep_velocity_um_per_s: 0.0,
        // The grid row: 11 × 6 nodes over the ranges (the ends included).
        grid_pitch_um: 1000.0,
        // This project's timing for both characterizations (the paper's
        // 2.0 s settle only stretches the simulated hours here).
        paper_settle_s: 0.3,
        ..RunPlan::paper()
    };
    let opts = RunOptions {
        seed: 3,
        out_dir: Some(dir.path().to_owned()),
        plan,
        ..RunOptions::default()
    };
    let mut lines = Vec::new();
    let report = run(opts, &mut |l: &str| lines.push(l.to_owned()))
        .unwrap_or_else(|e| panic!("{e}; progress: {lines:?}"));
    let s = &report.summary;
    for test in ["square", "random"] {
        for mode in ["raw", "table", "model", "closed_loop"] {
            let r = &s[test][mode];
            assert!(r["ap_um"].as_f64().is_some(), "{test} {mode}: {s}");
            assert!(r["rp_um"].as_f64().is_some(), "{test} {mode}: {s}");
        }
        let ap = |m: &str| s[test][m]["ap_um"].as_f64().unwrap();
        assert!(
            ap("raw") > 5.0,
            "{test}: raw AP should show the stage errors: {s}"
        );
        assert!(ap("table") * 5.0 < ap("raw"), "{test} table: {s}");
        assert!(ap("model") * 5.0 < ap("raw"), "{test} model: {s}");
        assert!(ap("closed_loop") <= 0.5, "{test} closed_loop: {s}");
    }
    // The grid row: every node once (the range's end a node too), its map
    // validated in table mode.
    let g = &s["grid"];
    assert_eq!(g["nodes"], 11 * 6, "{g}");
    assert_eq!(g["report"]["nodes"], serde_json::json!([11, 6]), "{g}");
    for test in ["square", "random"] {
        let raw = s[test]["raw"]["ap_um"].as_f64().unwrap();
        let grid = g[test]["ap_um"].as_f64().unwrap();
        assert!(grid * 3.0 < raw, "{test}: grid map {grid} µm, raw {raw} µm");
    }
    assert!(report.files.iter().any(|f| f == "run-grid-grid.toml"));
    let ch = &s["characterization"];
    // 96 + 43 points per pass (100 µm over 9500 and 4200 µm), 2 passes.
    assert_eq!(ch["points"], 2 * 96 + 2 * 43, "{s}");
    assert!(ch["simulated_s"].as_f64().unwrap() > 0.0);
    // Per pose figures and the logs the plots are drawn from.
    let poses = report.validation["square"]["table"]["poses"]
        .as_array()
        .unwrap();
    assert_eq!(poses.len(), 8);
    assert_eq!(poses[0]["pose"], "A");
    let data = report.data_dir.unwrap();
    let log = micropos::charact::log::read_file(data.join("validate.csv")).unwrap();
    let visits = log.records.iter().filter(|r| r.segment != "drift_ref");
    assert_eq!(visits.count(), (8 + 10) * 4 * 2);
    assert!(log.columns.extra.contains(&"pose".to_owned()));
    let ch_log = micropos::charact::log::read_file(data.join("charact-paper.csv")).unwrap();
    assert!(ch_log.metadata.get("vision_frame_rotation_rad").is_some());
}
