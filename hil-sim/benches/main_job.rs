//! Wall time of the main job (`hil-sim run`) on the in-process rig, whose
//! virtual clock makes it bounded by CPU, not by simulated time.
//!
//! Default: the reduced plan (`--short`), three runs of seed 1; the median
//! wall time, the simulated and the wall time per phase and the frames rendered and
//! decoded. `MICROPOS_BENCH_FULL=1`: the paper's plan, once (minutes).
//!
//! Baseline, measured in the same run: rendering and decoding one frame of
//! the rig's camera back to back (the work the job cannot avoid; decoded
//! on two threads as the daemon does, `Decoder::decode_shared`), as a
//! median over 60 frames at poses spread over the pattern; the job's wall
//! time is then reported against `frames × that median` (the ratio is the
//! cost of everything else: motion, serial exchanges, the daemon, logs,
//! tables, the fits).
//!
//! `cargo bench -p hil-sim --bench main_job`

use hil_sim::camera::fast::FastRenderer;
use hil_sim::rig::RigConfig;
use hil_sim::run::{run, RunOptions, RunPlan};
use micropos::pattern::decode::{DecodeOptions, Decoder};
use std::sync::Arc;
use std::time::{Duration, Instant};

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Median seconds to render and decode one frame of the default rig.
fn frame_baseline_s() -> f64 {
    let rig = RigConfig::default();
    let cam = &rig.camera;
    let mut r = FastRenderer::new(cam, rig.mounting.theta_deg.to_radians()).unwrap();
    let mut d = Decoder::new(DecodeOptions::new(cam.period_um, cam.bits)).unwrap();
    let mut t = Vec::new();
    for i in 0..60 {
        let (x, y) = (2000.0 + 137.3 * i as f64, 1500.0 + 91.7 * i as f64);
        let t0 = Instant::now();
        let f = Arc::new(
            r.render_exposed(x, y, 1.0, 1.0, i as u64, 0.0, i as u64)
                .unwrap(),
        );
        let _ = std::hint::black_box(d.decode_shared(&f));
        t.push(t0.elapsed().as_secs_f64());
    }
    median(&mut t)
}

fn main() {
    let full = std::env::var("MICROPOS_BENCH_FULL").is_ok_and(|v| v == "1");
    let (plan, runs) = if full {
        (RunPlan::paper(), 1)
    } else {
        (RunPlan::reduced(), 3)
    };
    let per_frame = frame_baseline_s();
    let mut walls = Vec::new();
    let mut phase_walls: Vec<Vec<(String, f64)>> = Vec::new();
    let mut summary = serde_json::Value::Null;
    for _ in 0..runs {
        let t0 = Instant::now();
        let opts = RunOptions {
            seed: 1,
            plan: plan.clone(),
            ..RunOptions::default()
        };
        let r = run(opts, &mut |_| {}).expect("main job");
        walls.push(t0.elapsed().as_secs_f64());
        phase_walls.push(r.phases_wall_s);
        summary = r.summary;
    }
    let wall = median(&mut walls);
    let frames = summary["frames"]["grabbed"].as_f64().unwrap_or(f64::NAN);
    let base = frames * per_frame;
    println!(
        "main job ({} plan, seed 1, {runs} run(s)): median wall {wall:.1} s (runs {:?})",
        if full { "paper" } else { "reduced" },
        walls.iter().map(|w| format!("{w:.1}")).collect::<Vec<_>>()
    );
    println!(
        "baseline: render + decode {:.2} ms/frame (median of 60) × {frames} frames = {base:.1} s; job / baseline = {:.2}",
        per_frame * 1e3,
        wall / base
    );
    let total: f64 = summary["phases_s"]
        .as_object()
        .map(|p| p.values().filter_map(|v| v.as_f64()).sum())
        .unwrap_or(f64::NAN);
    println!("simulated time: {total:.0} s in all; per phase, simulated s and median wall s:");
    if let Some(p) = summary["phases_s"].as_object() {
        for (k, v) in p {
            let mut w: Vec<f64> = phase_walls
                .iter()
                .filter_map(|run| run.iter().find(|(n, _)| n == k).map(|(_, w)| *w))
                .collect();
            let w = if w.is_empty() {
                f64::NAN
            } else {
                median(&mut w)
            };
            println!(
                "  {k:<28} {:>9.1} s  {w:>7.2} s wall",
                v.as_f64().unwrap_or(f64::NAN)
            );
        }
    }
    println!(
        "simulated / wall = {:.0}",
        total / Duration::from_secs_f64(wall).as_secs_f64()
    );
}
