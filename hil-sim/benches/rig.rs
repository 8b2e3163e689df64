//! Simulated rig benchmark (prints medians; `cargo bench -p hil-sim --bench rig`).
//!
//! 1. Cost per simulated frame: fast render, decode, and micropos's exact
//!    renderer for comparison (1024 × 768, 10-bit, 4 µm, 0.4 µm/px).
//! 2. Simulated-to-wall time ratio of the paper's characterization
//!    (5 µm steps over 9500 µm in X and 4200 µm in Y, 3 forward-and-back
//!    cycles: 11403 + 5043 points, ≈ 9.5 simulated hours): a fraction of it
//!    is run through the real path (driver over ptys, camera socket,
//!    decoder) with a dwell per point so that the simulated time per point
//!    is the paper's (34 200 s / 16 446 points), then extrapolated.

use hil_sim::camera::fast::FastRenderer;
use hil_sim::camera::CameraConfig;
use hil_sim::experiment::{Session, SessionOptions};
use micropos::pattern::decode::{DecodeOptions, Decoder};
use micropos::pattern::render::{Pose, Renderer};
use std::time::{Duration, Instant};

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    let cfg = CameraConfig::default();
    let theta = 0.3f64.to_radians();
    let t = Instant::now();
    let mut fast = FastRenderer::new(&cfg, theta).expect("renderer");
    println!(
        "fast renderer setup (stamps): {:.1} ms",
        t.elapsed().as_secs_f64() * 1e3
    );
    let mut dec = Decoder::new(DecodeOptions::new(cfg.period_um, cfg.bits)).expect("decoder");
    let (mut tr, mut td) = (Vec::new(), Vec::new());
    let mut frame = None;
    for i in 0..40 {
        let x = 3000.0 + 0.37 * i as f64;
        let t = Instant::now();
        let f = fast.render(x, 4000.0, 1.0, i, 0.0, i).expect("render");
        tr.push(t.elapsed().as_secs_f64());
        let t = Instant::now();
        let _ = dec.decode(&f);
        td.push(t.elapsed().as_secs_f64());
        frame = Some(f);
    }
    drop(frame);
    let mut exact = Renderer::new(cfg.exact_render_config()).expect("exact renderer");
    let mut te = Vec::new();
    for i in 0..5 {
        let pose = Pose {
            x_um: 3000.0 + i as f64,
            y_um: 4000.0,
            theta_rad: theta,
            pixel_um: cfg.pixel_um,
            mirrored: false,
        };
        let t = Instant::now();
        let _ = exact.render(&pose, 1, 0.0, 1);
        te.push(t.elapsed().as_secs_f64());
    }
    let (r, d, e) = (median(tr) * 1e3, median(td) * 1e3, median(te) * 1e3);
    println!("per frame (median): fast render {r:.2} ms, decode {d:.2} ms, render+decode {:.2} ms; exact render {e:.1} ms ({:.0}× slower)", r + d, e / r);

    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .expect("runtime");
    rt.block_on(async {
        let mut s = Session::start(SessionOptions::default()).await.expect("session");
        let total_points = 11403.0 + 5043.0;
        let dwell_s: f64 = 34_200.0 / total_points;
        // Approach from beyond the first point, then 5 µm steps along X.
        s.visit([0.0, 2000.0]).await.expect("visit");
        let n = 300;
        let sim0 = s.sim().expect("sim").sim_time().as_secs_f64();
        let wall = Instant::now();
        let mut per_point = Vec::new();
        for i in 0..n {
            let t = Instant::now();
            let before = s.sim().expect("sim").sim_time().as_secs_f64();
            s.visit([10.0 + 5.0 * i as f64, 2000.0]).await.expect("visit");
            let used = s.sim().expect("sim").sim_time().as_secs_f64() - before;
            // The job dwells (settling, averaging) for the rest of the
            // paper's time per point, on the simulated clock.
            if dwell_s > used {
                s.sim()
                    .expect("sim")
                    .advance(Duration::from_secs_f64(dwell_s - used));
            }
            per_point.push(t.elapsed().as_secs_f64());
        }
        let wall_s = wall.elapsed().as_secs_f64();
        let sim_s = s.sim().expect("sim").sim_time().as_secs_f64() - sim0;
        let ratio = sim_s / wall_s;
        println!(
            "characterization fraction: {n} points, {sim_s:.0} simulated s in {wall_s:.2} wall s: sim/wall ratio {ratio:.0}; median wall per point {:.2} ms",
            median(per_point) * 1e3
        );
        println!(
            "extrapolated full characterization ({total_points} points, {:.1} simulated h): {:.0} wall s ({:.1} min)",
            34_200.0 / 3600.0,
            total_points * wall_s / n as f64,
            total_points * wall_s / n as f64 / 60.0
        );
        s.shutdown().await;
    });
}
