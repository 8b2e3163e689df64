//! The sweep characterization (`characterize start` with `mode = sweep`)
//! through microposd on the in-process rig (paused test runtime: virtual
//! clock). The camera's hidden latency is drawn from the seed; checked:
//! the job estimates it within 0.2 ms from the data, the log (and the
//! delay-ignored one) is accepted by `tables build`, it has the step plan's
//! grid, and the sweep took the simulated time its motion needs (no
//! settles). A second test checks the delay goal on random draws of the
//! rig's timing (camera delay of both signs, jitter, exposure, the servo's
//! following lag).
//!
//! `cargo test -p hil-sim --test it sweep_charact:: -- --nocapture` prints the
//! figures.

use crate::common::{self, Client};
use hil_sim::camera::CameraConfig;
use hil_sim::rig::{RigConfig, ServoConfig};
use hil_sim::run::{daemon_config, RunPlan};
use hil_sim::ServeConfig;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde_json::json;
use std::time::{Duration, Instant};

const SEED: u64 = 23;

/// What one sweep through the daemon gave.
struct Swept {
    /// The job's result (`characterize status` → `job.result`).
    result: serde_json::Value,
    /// The corrected log.
    log: micropos::charact::log::MeasurementLog,
    /// The delay-ignored log's `tables build` reply and the corrected one's.
    built: [serde_json::Value; 2],
    /// `characterize resume` of the sweep log (refused).
    resume: serde_json::Value,
}

/// Ranges, grid and velocity of the reduced sweep plan (a grid of
/// 400 × 250 µm at 10 µm, 2 cycles at 120 / 240 µm/s) from (3000, 3000).
const X_RANGE: f64 = 400.0;
const Y_RANGE: f64 = 250.0;
const STEP: f64 = 10.0;
const V: f64 = 120.0;
const START: f64 = 3000.0;

/// Starts the in-process rig `rig_cfg` with `seed` and microposd on it,
/// references, runs the reduced sweep plan and builds tables from both
/// logs.
/// `anchor_spacing_um`: `None` for the daemon's default, `Some(0.0)` for
/// none (the delay estimate does not use them; the random-rig test leaves
/// them out to halve its frames).
async fn sweep_on(
    rig_cfg: RigConfig,
    seed: u64,
    cycles: u32,
    drift_every_s: f64,
    anchor_spacing_um: Option<f64>,
) -> Swept {
    let wall = Instant::now();
    let dir = tempfile::tempdir().unwrap();
    let rig_dir = dir.path().join("rig");
    let data_dir = dir.path().join("data");
    std::fs::create_dir_all(&rig_dir).unwrap();
    std::fs::create_dir_all(&data_dir).unwrap();
    let sim = common::serve_in_process(ServeConfig {
        rig: rig_cfg.clone(),
        ..common::serve_config(&rig_dir, 1.0, seed)
    });
    let socket = dir.path().join("micropos.sock");
    let plan = RunPlan {
        step_um: STEP,
        x_range_um: X_RANGE,
        y_range_um: Y_RANGE,
        cycles,
        frames_per_point: 1,
        settle_s: 0.5,
        ..RunPlan::reduced()
    };
    let mut c = daemon_config(&rig_dir, &data_dir, &socket, &rig_cfg, &plan).unwrap();
    c.characterize.x_start_um = Some(START);
    c.characterize.y_start_um = Some(START);
    c.validate().unwrap();
    let daemon = common::start_daemon_in_process(c, &sim, &socket);
    let mut cl = Client::connect(&socket).await;
    common::connect_and_reference(&mut cl).await;
    let r = cl
        .call_ok(
            json!({"cmd": "characterize", "action": "start", "log": "sweep.csv",
            "mode": "sweep", "velocity_um_per_s": V, "step_um": STEP,
            "x_range_um": X_RANGE, "y_range_um": Y_RANGE, "cycles": cycles,
            "uncorrected_log": "sweep-nodelay.csv", "drift_every_s": drift_every_s,
            "anchor_spacing_um": anchor_spacing_um}),
        )
        .await;
    assert_eq!(r["job"]["state"], "running", "{r}");
    let status = loop {
        let s = cl
            .call_ok(json!({"cmd": "characterize", "action": "status"}))
            .await;
        if s["job"]["state"] != "running" {
            break s;
        }
        assert!(wall.elapsed() < Duration::from_secs(900), "{s}");
        tokio::time::sleep(Duration::from_secs(1)).await;
    };
    assert_eq!(status["job"]["state"], "done", "{status}");
    let log = micropos::charact::log::read_file(data_dir.join("sweep.csv")).unwrap();
    let mut built = [json!(null), json!(null)];
    for (k, name) in ["sweep.csv", "sweep-nodelay.csv"].iter().enumerate() {
        built[k] = cl
            .call_ok(json!({"cmd": "tables", "action": "build", "log": name}))
            .await;
    }
    let resume = cl
        .call(json!({"cmd": "characterize", "action": "resume", "log": "sweep.csv"}))
        .await;
    drop(cl);
    daemon.shutdown().await;
    let _ = tokio::task::spawn_blocking(move || sim.shutdown()).await;
    Swept {
        result: status["job"]["result"].clone(),
        log,
        built,
        resume,
    }
}

#[tokio::test(start_paused = true)]
async fn sweep_estimates_the_hidden_delay_and_logs_the_step_grid() {
    let wall = Instant::now();
    let latency_us = ChaCha8Rng::seed_from_u64(SEED).gen_range(1000.0..9000.0);
    let rig_cfg = RigConfig {
        camera: CameraConfig {
            latency_us,
            ..CameraConfig::default()
        },
        ..RigConfig::default()
    };
    let (x_range, y_range, step, v) = (X_RANGE, Y_RANGE, STEP, V);
    // Drift references every 15 s: before the first pass and between
    // passes.
    let sw = sweep_on(rig_cfg, SEED, 2, 15.0, None).await;
    let res = &sw.result;
    let est_s = res["camera_delay_s"].as_f64().unwrap();
    let err_ms = (est_s - latency_us * 1e-6) * 1e3;
    let duration_s = res["duration_s"].as_f64().unwrap();
    println!(
        "hidden latency {:.3} ms, estimated {:.3} ms (error {err_ms:+.4} ms, residual {:.4} µm); \
         {} frames, {} position samples ({} records of the data recorder), {} records, {} drift references; sweep {duration_s:.1} s simulated; wall {:.1} s",
        latency_us * 1e-3,
        est_s * 1e3,
        res["camera_delay_residual_um"],
        res["frames"],
        res["pos_samples"],
        res["recorder_records"],
        res["records"],
        res["drift_references"],
        wall.elapsed().as_secs_f64()
    );
    assert!(err_ms.abs() < 0.2, "delay off by {err_ms} ms");

    // The log has the step plan's grid and segments; tables build takes it.
    let log = &sw.log;
    assert_eq!(log.metadata.get("mode"), Some("sweep"));
    let grid = |r: f64| (r / step) as usize + 1;
    let per_axis = [(grid(x_range), "scan_x"), (grid(y_range), "scan_y")];
    for (n, seg) in per_axis {
        let k = log
            .records
            .iter()
            .filter(|r| r.segment.starts_with(seg))
            .count();
        // Four passes per axis; at most the first and last cells may miss.
        // (`starts_with`: drift references are not scan records.)
        assert!(k <= 4 * n && k + 8 >= 4 * n, "{seg}: {k} of {}", 4 * n);
    }
    for r in &log.records {
        let on_grid = |p: f64, s: f64| ((p - s) / step - ((p - s) / step).round()).abs() < 1e-9;
        assert!(on_grid(r.x_cmd_um, START) || on_grid(r.y_cmd_um, START));
    }
    // The drift references stand between the passes; tables build removes
    // the drift they measure from both logs.
    let refs = res["drift_references"].as_u64().unwrap();
    let logged = log
        .records
        .iter()
        .filter(|r| r.segment == "drift_ref")
        .count();
    assert!(
        refs >= 2 && logged as u64 == refs,
        "{refs} references, {logged} logged"
    );
    assert_eq!(log.records[0].segment, "drift_ref");
    for b in &sw.built {
        assert!(b["paper"]["name"].is_string(), "{b}");
        assert_eq!(b["drift"]["references"].as_u64(), Some(refs), "{b}");
        assert!(b["drift"]["corrected"].as_u64().unwrap() > 0, "{b}");
    }
    // Simulated time: the motion (ranges plus run-ups at v, 2v), the tie
    // and the reference detours (a few s each), no settles per point.
    let motion_s: f64 = [x_range, y_range]
        .iter()
        .map(|r| {
            // One run-up for every pass: 20 µm + 0.3 s at 2v.
            2.0 * (r + 2.0 * (20.0 + 0.6 * v)) / v + 2.0 * (r + 2.0 * (20.0 + 0.6 * v)) / (2.0 * v)
        })
        .sum();
    let tie_s: f64 = log.metadata.get("tie_duration_s").unwrap().parse().unwrap();
    // The anchors: every 250 µm (the default), both directions, after each
    // cycle; each a move, a step, the settle and a frame.
    let anchors = &res["anchors"];
    let anchor_s = anchors["duration_s"].as_f64().unwrap();
    let measured = anchors["measured"].as_u64().unwrap();
    assert_eq!(anchors["spacing_um"], 250.0, "{anchors}");
    // x: 10, 250, 400 µm forward, 390, 250, 0 backward; y: 10, 250 and
    // 240, 0; two cycles.
    assert_eq!(measured, 2 * (6 + 4), "{anchors}");
    assert!(
        anchor_s < measured as f64 * (0.5 + 1.5),
        "{anchor_s} s for {measured} anchors"
    );
    assert!(
        duration_s < motion_s + tie_s + anchor_s + 5.0 * refs as f64 + 30.0,
        "{duration_s} s vs motion {motion_s} s + tie {tie_s} s + anchors {anchor_s} s + {refs} references"
    );
    // The log holds the anchors (rows of their own segments, each with its
    // cycle's anchor − sweep difference) and the correction applied to
    // every scan record; on this stage (no path dependence) it is noise.
    let cols = &log.columns.extra;
    let cx = cols.iter().position(|c| c == "x_anchor_corr_um").unwrap();
    let anchor_rows: Vec<_> = log
        .records
        .iter()
        .filter(|r| r.segment.starts_with("anchor_"))
        .collect();
    assert_eq!(anchor_rows.len() as u64, measured);
    assert!(anchor_rows.iter().all(|r| !r.extra[cx].is_empty()));
    for r in log
        .records
        .iter()
        .filter(|r| r.segment.starts_with("scan_"))
    {
        let c: f64 = r.extra[cx].parse().unwrap();
        assert!(c.abs() < 0.2, "correction {c} µm on {r:?}");
    }
    assert_eq!(
        log.metadata.get("sweep_anchor_correction_applied"),
        Some("true")
    );
    assert_eq!(
        log.metadata.get("sweep_anchors"),
        Some(measured.to_string().as_str())
    );
    // A sweep log is not resumable.
    assert_eq!(sw.resume["ok"], false, "{}", sw.resume);
    // The simulated C-863s have a data recorder: the positions came from
    // it, a record per millisecond of every pass, and the log says so.
    for key in ["sweep_position_source_x", "sweep_position_source_y"] {
        assert_eq!(log.metadata.get(key), Some("data_recorder"), "{key}");
    }
    assert_eq!(
        log.metadata.get("sweep_recorder_sample_time_s"),
        Some("0.001000")
    );
    let records = res["recorder_records"].as_u64().unwrap() as f64;
    assert!(
        records > 0.9 * (motion_s * 1000.0) && records <= (duration_s + 1.0) * 1000.0,
        "{records} records for {motion_s} s of passes"
    );
}

/// Seeds of [`the_delay_goal_holds_on_random_rigs`]: kept apart from the
/// seeds the method was developed on (23 here, 1–5 in the main job).
const DRAW_SEEDS: std::ops::RangeInclusive<u64> = 9101..=9106;

/// The delay goal (within 0.2 ms of the simulator's delay) on the named rig
/// (`config/sim-rig.toml`: the documented stage, `config/stage-model.toml`)
/// with its timing parameters drawn per seed: camera delay of either sign
/// (−4…9 ms: a camera stamping the exposure's start is early), timestamp
/// jitter σ 0–100 µs, exposure 1–3 ms, servo following lag 0–5 ms (up to
/// 0.6 µm at 120 µm/s and 1.2 µm at 240: frames placed on the commanded
/// trajectory would be off by the whole lag). Three cycles (v, 2v, v), as
/// the paper plan. `-- --nocapture` prints each draw.
#[tokio::test(start_paused = true)]
async fn the_delay_goal_holds_on_random_rigs() {
    let mut worst: f64 = 0.0;
    let mut signs = [false; 2];
    for seed in DRAW_SEEDS {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let latency_us = rng.gen_range(-4000.0..9000.0);
        let jitter_us = rng.gen_range(0.0..100.0);
        let exposure_us = rng.gen_range(1000.0..3000.0);
        let lag_ms = rng.gen_range(0.0..5.0);
        let rig_cfg = RigConfig {
            camera: CameraConfig {
                latency_us,
                timestamp_jitter_us: jitter_us,
                exposure_us,
                ..CameraConfig::default()
            },
            servo: ServoConfig {
                following_lag_ms: lag_ms,
            },
            ..RigConfig::default()
        };
        let sw = sweep_on(rig_cfg, seed, 3, 0.0, Some(0.0)).await;
        let est_s = sw.result["camera_delay_s"].as_f64().unwrap();
        let err_ms = (est_s - latency_us * 1e-6) * 1e3;
        println!(
            "seed {seed}: delay {:+.3} ms, jitter {jitter_us:.0} µs, exposure {exposure_us:.0} µs, \
             following lag {lag_ms:.2} ms → estimated {:+.3} ms (error {err_ms:+.4} ms, residual {:.4} µm)",
            latency_us * 1e-3,
            est_s * 1e3,
            sw.result["camera_delay_residual_um"]
        );
        signs[usize::from(latency_us > 0.0)] = true;
        worst = worst.max(err_ms.abs());
        assert!(err_ms.abs() < 0.2, "seed {seed}: delay off by {err_ms} ms");
    }
    assert_eq!(signs, [true, true], "both signs of the delay were drawn");
    println!("worst error {worst:.4} ms");
}

/// The main job's sweep row (`hil_sim::run`, `summary.sweep`) on the
/// paper's ranges and cycles, with step-mode and sweep tables on a grid of
/// `MICROPOS_SWEEP_STEP_UM` (default 25 µm; the paper's 5 µm with
/// `MICROPOS_SWEEP_STEP_UM=5`), on the main job's default stage, the
/// paper-faithful one (`MICROPOS_SWEEP_MODEL=FILE` for another, e.g.
/// `config/stage-model.toml`): the sweep's simulated duration, anchors
/// included (goal ≤ 30 min), the delay estimate against the simulator's
/// (goal 0.2 ms) and the sweep tables' AP against the step tables' on the
/// same rig and seed, live drift off (goal: within 10 %, plus
/// [`STEP_AP_SPREAD_UM`], the validation's own spread at these figures),
/// and the AP with the delay ignored. Slow (the whole main job, 20 000+
/// frames): `cargo test -p hil-sim --test it sweep_charact:: -- --ignored
/// --nocapture`.
#[test]
#[ignore = "the whole main job on the paper's ranges: minutes of wall time"]
fn main_job_sweep_row_on_the_paper_ranges() {
    let step_um = std::env::var("MICROPOS_SWEEP_STEP_UM")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(25.0);
    let plan = hil_sim::run::RunPlan {
        step_um,
        short_step_um: 500.0,
        grid_pitch_um: 0.0,
        ..hil_sim::run::RunPlan::paper()
    };
    let model = std::env::var_os("MICROPOS_SWEEP_MODEL").map(std::path::PathBuf::from);
    let stage_model = match model {
        Some(_) => None,
        None => Some(
            micropos::model::StageModel::from_toml(micropos::model::PAPER_FAITHFUL_TOML).unwrap(),
        ),
    };
    let opts = hil_sim::run::RunOptions {
        plan,
        model,
        stage_model,
        ..hil_sim::run::RunOptions::default()
    };
    let report = hil_sim::run::run(opts, &mut |l| eprintln!("main job: {l}")).unwrap();
    let s = &report.summary;
    println!("{}", hil_sim::run::format_table(s));
    println!("{}", serde_json::to_string_pretty(&s["sweep"]).unwrap());
    let sw = &s["sweep"];
    let sim_s = sw["simulated_s"].as_f64().unwrap();
    assert!(sim_s <= 1800.0, "sweep took {sim_s} simulated s");
    let est = sw["result"]["camera_delay_s"].as_f64().unwrap();
    let truth = sw["true_delay_s"].as_f64().unwrap();
    assert!((est - truth).abs() < 2e-4, "delay {est} vs {truth}");
    let mut unanchored_misses = false;
    for t in ["square", "random"] {
        let step = sw["step_table_ap_um"][t]["ap_um"].as_f64().unwrap();
        let sweep = sw["run-sweep"][t]["ap_um"].as_f64().unwrap();
        let ignored = sw["run-sweep-nodelay"][t]["ap_um"].as_f64().unwrap();
        let unanchored = sw["run-sweep-noanchor"][t]["ap_um"].as_f64().unwrap();
        let goal = 1.1 * step + STEP_AP_SPREAD_UM;
        assert!(
            sweep <= goal,
            "{t}: sweep table AP {sweep} µm vs step {step} µm"
        );
        unanchored_misses |= unanchored > goal;
        // Ignoring the delay shifts each direction's records by ±v·delay
        // (0.44 / 0.89 µm at 120 / 240 µm/s): it shows where the tables
        // themselves are well below that. (On the faithful stage the
        // tables leave the long moves' lost motion, and a shift in the
        // direction of travel cancels part of it.)
        if step < 0.3 {
            assert!(ignored > 5.0 * sweep, "{t}: delay ignored {ignored} µm");
        }
    }
    // Where the stage's error depends on the path (the faithful stage),
    // the anchors are what meets the goal.
    let faithful = std::env::var_os("MICROPOS_SWEEP_MODEL").is_none();
    assert!(
        unanchored_misses || !faithful,
        "the unanchored sweep tables meet the goal too: {}",
        sw["run-sweep-noanchor"]
    );
}

/// The spread of the step tables' own AP max between validations of the
/// same tables on the same run (the main job's drift comparison: random
/// targets 0.063 / 0.107 / 0.079 µm with live drift off / static /
/// adaptive at a 25 µm grid, seed 1): below it, AP differences are the
/// validation's noise (its RP max is ≈ 0.13 µm), not table quality.
const STEP_AP_SPREAD_UM: f64 = 0.05;
