//! The grid characterization on microposd with the in-process simulated rig
//! (paused clock): `characterize start` with `plan: "grid"` measures every
//! node of a lattice once per cycle, in rows of increasing x, each node
//! reached from below on both axes; `tables build` makes a 2-D map of the
//! log (kind grid, by default for a grid log), which plans its moves to
//! arrive from below as the nodes were; validated on the paper's square in
//! modes raw and table with that map, the map takes out most of the
//! stage's error (scale, squareness, Abbe slopes: the smooth part a 1 mm
//! pitch resolves).

use crate::common::{self, Client};
use hil_sim::run::{daemon_config, RunPlan};
use serde_json::json;
use std::time::{Duration, Instant};

/// Node spacing, µm: five nodes per axis over the paper's square (10 …
/// 4010 µm from the characterization's start corner).
const PITCH_UM: f64 = 1005.0;

/// The in-process served rig (seed `seed`; `model`: a stage model file's
/// text instead of the default one) and microposd on it, axes referenced.
struct Setup {
    _dir: tempfile::TempDir,
    data: std::path::PathBuf,
    sim: hil_sim::SimHandle,
    daemon: micropos::daemon::Running,
    cl: Client,
}

async fn setup(seed: u64, model: Option<&str>) -> Setup {
    let dir = tempfile::tempdir().unwrap();
    let rig_dir = dir.path().join("rig");
    let data = dir.path().join("data");
    std::fs::create_dir_all(&rig_dir).unwrap();
    std::fs::create_dir_all(&data).unwrap();
    let model = model.map(|text| {
        let p = dir.path().join("model.toml");
        std::fs::write(&p, text).unwrap();
        p
    });
    let sim = common::serve_in_process(hil_sim::ServeConfig {
        model,
        ..common::serve_config(&rig_dir, 50.0, seed)
    });
    let socket = dir.path().join("micropos.sock");
    let mut c = daemon_config(
        &rig_dir,
        &data,
        &socket,
        &hil_sim::rig::RigConfig::default(),
        &RunPlan::reduced(),
    )
    .unwrap();
    // Room around the square for the compensated commands (tens of µm
    // beyond the poses); the validation's origin is this start corner.
    c.characterize.x_start_um = Some(1000.0);
    c.characterize.y_start_um = Some(1000.0);
    c.validate().unwrap();
    let daemon = common::start_daemon_in_process(c, &sim, &socket);
    let mut cl = Client::connect(&socket).await;
    common::connect_and_reference(&mut cl).await;
    Setup {
        _dir: dir,
        data,
        sim,
        daemon,
        cl,
    }
}

impl Setup {
    async fn shutdown(self) {
        drop(self.cl);
        self.daemon.shutdown().await;
        let sim = self.sim;
        let _ = tokio::task::spawn_blocking(move || sim.shutdown()).await;
    }
}

#[tokio::test(start_paused = true)]
async fn a_grid_characterization_builds_a_map_that_compensates_the_square() {
    let mut s = setup(31, None).await;
    let (cl, data) = (&mut s.cl, s.data.clone());

    // A pitch without the grid plan is refused with the reason.
    let r = cl
        .call(json!({"cmd": "characterize", "action": "start", "pitch_um": 500.0}))
        .await;
    assert_eq!(r["error"]["code"], "bad_value", "{r}");

    let t0 = Instant::now();
    let started = cl
        .call_ok(
            json!({"cmd": "characterize", "action": "start", "log": "g.csv",
                        "plan": "grid", "pitch_um": PITCH_UM,
                        "x_range_um": 4.0 * PITCH_UM, "y_range_um": 4.0 * PITCH_UM,
                        "cycles": 1, "frames_per_point": 1, "settle_s": 0.5}),
        )
        .await;
    assert_eq!(started["job"]["total"], 25, "{started}");
    loop {
        let s = cl
            .call_ok(json!({"cmd": "characterize", "action": "status"}))
            .await;
        match s["job"]["state"].as_str() {
            Some("done") => break,
            Some("running") => {}
            _ => panic!("{s}"),
        }
        assert!(t0.elapsed() < Duration::from_secs(600), "job too slow: {s}");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    let log = micropos::charact::log::read_file(data.join("g.csv")).unwrap();
    assert_eq!(log.metadata.get("plan"), Some("grid"));
    let grid: Vec<_> = log.records.iter().filter(|r| r.segment == "grid").collect();
    assert_eq!(grid.len(), 25);
    // Rows of increasing x, rows in increasing y.
    assert!(grid.windows(2).all(|w| w[1].y_target_um > w[0].y_target_um
        || (w[1].y_target_um == w[0].y_target_um && w[1].x_target_um > w[0].x_target_um)));

    let built = cl
        .call_ok(json!({"cmd": "tables", "action": "build", "log": "g.csv"}))
        .await;
    assert_eq!(built["written"], json!(["g-grid.toml"]), "{built}");
    assert_eq!(built["grid"]["report"]["measured"], 25, "{built}");
    assert_eq!(built["grid"]["report"]["nodes"], json!([5, 5]), "{built}");
    let file = micropos::comp::CompFile::read_path(data.join("g-grid.toml")).unwrap();
    assert_eq!(
        file.grid.map(|g| g.arrival),
        Some(micropos::comp::GridArrival::FromBelow),
        "the grid plan reached every node from below"
    );

    let started = cl
        .call_ok(
            json!({"cmd": "validate", "action": "start", "test": "square",
                        "modes": ["raw", "table"], "table": "g-grid.toml", "cycles": 1,
                        "square_step_um": 1000.0, "frames_per_point": 1,
                        "settle_s": 0.5, "log": "v.csv"}),
        )
        .await;
    assert!(started["job"]["total"].as_u64().unwrap() > 0, "{started}");
    let results = loop {
        let s = cl.call_ok(json!({"cmd": "validate"})).await;
        match s["job"]["state"].as_str() {
            Some("done") => break s["validation"]["results"]["square"].clone(),
            Some("running") => {}
            _ => panic!("{s}"),
        }
        assert!(
            t0.elapsed() < Duration::from_secs(900),
            "validation too slow: {s}"
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    };
    let ap = |mode: &str| results[mode]["ap_um"].as_f64().unwrap();
    let (raw, table) = (ap("raw"), ap("table"));
    eprintln!("GRID | square AP raw {raw:.2} µm, grid table (pitch {PITCH_UM} µm) {table:.2} µm");
    assert_eq!(results["table"]["table"], "g-grid.toml", "{results}");
    // Measured on seed 31: 25.3 µm raw, 0.89 µm by the map.
    assert!(table < 0.15 * raw, "raw {raw} µm, table {table} µm");
    s.shutdown().await;
}

/// A stage whose only position error besides scale and squareness is the
/// lower carriage's yaw acting on the upper axis (`stacked_yaw`: not
/// separable), with a little repeatability noise.
const STACKED_MODEL: &str = r#"
format_version = 1
description = "scale, squareness and the X carriage's yaw on the Y axis"
[stochastic]
repeatability_sigma_um = [0.02, 0.02]
min_incremental_motion_um = 0.05
position_quantum_um = 0.0
rough_spots = []
[environment]
temperature_interpolation = "smooth"
temperature = [{ time_s = 0.0, temp_c = 20.0 }]
[[term]]
kind = "lead_error"
name = "x_lead"
axis = "x"
ppm = 150.0
[[term]]
kind = "squareness"
name = "sq"
angle_urad = 400.0
[[term]]
kind = "stacked_yaw"
name = "x_carriage_yaw"
lower_axis = "x"
slope_urad_per_mm = 200.0
lower_center_um = 3010.0
upper_center_um = 3010.0
"#;

/// Waits for the current job of `kind` (`characterize`, `validate`) to end.
async fn wait_done(cl: &mut Client, kind: &str) -> serde_json::Value {
    let t0 = Instant::now();
    loop {
        let s = cl.call_ok(json!({"cmd": kind, "action": "status"})).await;
        match s["job"]["state"].as_str() {
            Some("done") => return s,
            Some("running") => {}
            _ => panic!("{s}"),
        }
        assert!(t0.elapsed() < Duration::from_secs(600), "too slow: {s}");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

/// On a stage with non-separable error, the paper's tables (one scan line
/// per axis through the middle, where the yaw's product vanishes) cannot
/// hold it and a grid map can: square AP of the map well below the
/// tables'.
#[tokio::test(start_paused = true)]
async fn on_a_stacked_stage_the_map_holds_what_the_tables_cannot() {
    let mut s = setup(17, Some(STACKED_MODEL)).await;
    let cl = &mut s.cl;
    let range = 4.0 * PITCH_UM;
    for (log, plan) in [("lines.csv", "lines"), ("grid.csv", "grid")] {
        cl.call_ok(json!({"cmd": "characterize", "action": "start", "log": log,
                          "plan": plan, "step_um": if plan == "grid" { PITCH_UM } else { 201.0 },
                          "x_range_um": range, "y_range_um": range, "cycles": 1,
                          "frames_per_point": 1, "settle_s": 0.5}))
            .await;
        wait_done(cl, "characterize").await;
    }
    cl.call_ok(
        json!({"cmd": "tables", "action": "build", "log": "lines.csv",
                      "name": "lines", "kinds": ["paper"]}),
    )
    .await;
    cl.call_ok(json!({"cmd": "tables", "action": "build", "log": "grid.csv", "name": "grid"}))
        .await;
    let mut ap = Vec::new();
    for table in ["lines-paper.toml", "grid-grid.toml"] {
        cl.call_ok(
            json!({"cmd": "validate", "action": "start", "test": "square",
                          "modes": ["table"], "table": table, "cycles": 1,
                          "square_step_um": 1000.0, "frames_per_point": 1, "settle_s": 0.5,
                          "log": format!("v-{table}.csv")}),
        )
        .await;
        let v = wait_done(cl, "validate").await;
        ap.push(
            v["validation"]["results"]["square"]["table"]["ap_um"]
                .as_f64()
                .unwrap(),
        );
    }
    eprintln!(
        "GRID | stacked stage, square AP: paper tables {:.3} µm, grid map {:.3} µm",
        ap[0], ap[1]
    );
    assert!(ap[1] < 0.5 * ap[0], "tables {} µm, map {} µm", ap[0], ap[1]);
    s.shutdown().await;
}

/// A grid measured both ways (`approach: "both"`) gives a map per arrival
/// direction: compensated moves then arrive either way (the daemon's
/// direction-aware policy) and each axis is read from its own direction's
/// layer. On the default stage (lost motion of a few µm) that map
/// compensates the square as the one-way map does; the same log read
/// without its directions (every node the mean of both ways, half the play
/// off either way) does worse.
#[tokio::test(start_paused = true)]
async fn a_grid_measured_both_ways_compensates_either_arrival() {
    both_ways(23, "raster").await;
}

/// The same in serpentine order: the returning rows reach x from above,
/// the pass from above reverses the pass from below, and every node is
/// still measured once each way on each axis.
#[tokio::test(start_paused = true)]
async fn a_serpentine_grid_both_ways_compensates_either_arrival() {
    both_ways(29, "serpentine").await;
}

async fn both_ways(seed: u64, order: &str) {
    let mut s = setup(seed, None).await;
    let (cl, data) = (&mut s.cl, s.data.clone());
    let range = 4.0 * PITCH_UM;
    let started = cl
        .call_ok(
            json!({"cmd": "characterize", "action": "start", "log": "b.csv",
                        "plan": "grid", "approach": "both", "order": order,
                        "pitch_um": PITCH_UM,
                        "x_range_um": range, "y_range_um": range, "cycles": 1,
                        "frames_per_point": 1, "settle_s": 0.5}),
        )
        .await;
    assert_eq!(started["job"]["total"], 50, "{started}");
    wait_done(cl, "characterize").await;
    let log = micropos::charact::log::read_file(data.join("b.csv")).unwrap();
    assert_eq!(log.metadata.get("grid_approach"), Some("both"));
    // Each node once each way on each axis, as the segments say.
    for a in 0..2 {
        let fwd = log
            .records
            .iter()
            .filter_map(|r| micropos::charact::scan::grid_direction(&r.segment))
            .filter(|d| d[a] == micropos::model::Direction::Forward)
            .count();
        assert_eq!(fwd, 25, "axis {a}");
    }
    // The same records without their directions: one pooled map.
    let text = std::fs::read_to_string(data.join("b.csv")).unwrap();
    let pooled = ["grid_fwd", "grid_bwd", "grid_xbwd", "grid_ybwd"]
        .iter()
        .fold(text.clone(), |t, seg| {
            t.replace(&format!(",{seg},"), ",grid,")
        });
    assert_ne!(pooled, text);
    std::fs::write(data.join("p.csv"), pooled).unwrap();
    let built = cl
        .call_ok(json!({"cmd": "tables", "action": "build", "log": "b.csv"}))
        .await;
    let report = &built["grid"]["report"];
    assert_eq!(report["measured_from_above"], 25, "{built}");
    let reversal = report["reversal_rms_um"][0].as_f64().unwrap();
    let file = micropos::comp::CompFile::read_path(data.join("b-grid.toml")).unwrap();
    assert_eq!(
        file.grid.map(|g| g.arrival),
        Some(micropos::comp::GridArrival::Both)
    );
    cl.call_ok(json!({"cmd": "tables", "action": "build", "log": "p.csv", "kinds": ["grid"]}))
        .await;
    let mut ap = Vec::new();
    for table in ["b-grid.toml", "p-grid.toml"] {
        cl.call_ok(
            json!({"cmd": "validate", "action": "start", "test": "square",
                          "modes": ["raw", "table"], "table": table, "cycles": 1,
                          "square_step_um": 1000.0, "frames_per_point": 1, "settle_s": 0.5,
                          "log": format!("v-{table}.csv")}),
        )
        .await;
        let v = wait_done(cl, "validate").await;
        let r = &v["validation"]["results"]["square"];
        ap.push((
            r["raw"]["ap_um"].as_f64().unwrap(),
            r["table"]["ap_um"].as_f64().unwrap(),
        ));
    }
    eprintln!(
        "GRID | both ways, {order}: x reversal rms {reversal:.2} µm; square AP raw {:.2} µm, map per direction {:.3} µm, pooled map {:.3} µm",
        ap[0].0, ap[0].1, ap[1].1
    );
    assert!(reversal > 0.5, "the default stage has lost motion: {built}");
    assert!(ap[0].1 < 0.15 * ap[0].0, "{ap:?}");
    assert!(ap[0].1 < ap[1].1, "{ap:?}");
    s.shutdown().await;
}
