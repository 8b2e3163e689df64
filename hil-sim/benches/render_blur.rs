//! The simulated camera's render of one frame (`FastRenderer`), the paper
//! camera at the rig's mounting angle: a still frame, and a sweep frame at
//! 240 µm/s over the 2 ms exposure (0.48 µm = 1.2 px of motion blur, five
//! instants: what `SimCamera::grab` renders during the main job's sweep
//! row) placed instant by instant (`render_path_per_instant`) and with the
//! frame's blurred stamps (`render_path`), the blurred stamps reused from
//! the previous frame (a sweep at constant velocity: the same
//! displacements frame after frame) or rebuilt for every frame (the
//! velocity changes between frames).
//!
//! `cargo bench -p hil-sim --bench render_blur` (the medians are in
//! `target/criterion/render_1024x768/*/new/estimates.json`).

use criterion::{black_box, criterion_group, criterion_main, Criterion};
use hil_sim::camera::fast::FastRenderer;
use hil_sim::rig::RigConfig;

/// Exposure, s, and the sweep's velocity, µm/s (pattern frame).
const EXPOSURE_S: f64 = 2e-3;
const SWEEP_UM_S: f64 = 240.0;

/// `n` equally spaced instants of the exposure at velocity `v_um_s` along
/// pattern x, mid-point at `x_um` (as `SimCamera::grab` takes them).
fn sweep(x_um: f64, v_um_s: f64, n: usize) -> Vec<[f64; 2]> {
    (0..n)
        .map(|k| {
            let f = ((k as f64 + 0.5) / n as f64 - 0.5) * EXPOSURE_S;
            [x_um + v_um_s * f, 4000.0]
        })
        .collect()
}

fn bench(c: &mut Criterion) {
    let rig = RigConfig::default();
    let cam = &rig.camera;
    let mut r = FastRenderer::new(cam, rig.mounting.theta_deg.to_radians()).expect("renderer");
    // As `SimCamera::grab` counts them: odd, at most a quarter pixel apart.
    let travel_um = SWEEP_UM_S * EXPOSURE_S;
    let n = ((travel_um / (cam.pixel_um / 4.0)).ceil() as usize) | 1;
    assert_eq!(n, 5, "instants of the paper camera's sweep frame");
    // Frame i of a sweep at 30 fps: 8 µm further along.
    let x = |i: u64| 2000.0 + 8.0 * (i % 500) as f64;
    let mut grp = c.benchmark_group("render_1024x768");
    grp.sample_size(40);
    let mut i = 0u64;
    grp.bench_function("still", |b| {
        b.iter(|| {
            i += 1;
            let f = r.render_path(&[[x(i), 4000.0]], 1.0, 1.0, i, 0.0, i);
            black_box(f.expect("render"))
        })
    });
    grp.bench_function("sweep_per_instant", |b| {
        b.iter(|| {
            i += 1;
            let f = r.render_path_per_instant(&sweep(x(i), SWEEP_UM_S, n), 1.0, 1.0, i, 0.0, i);
            black_box(f.expect("render"))
        })
    });
    grp.bench_function("sweep_blurred", |b| {
        b.iter(|| {
            i += 1;
            let f = r.render_path(&sweep(x(i), SWEEP_UM_S, n), 1.0, 1.0, i, 0.0, i);
            black_box(f.expect("render"))
        })
    });
    // 240 and 200 µm/s in turn: both five instants, other displacements.
    grp.bench_function("sweep_blurred_rebuilt", |b| {
        b.iter(|| {
            i += 1;
            let v = if i % 2 == 0 { SWEEP_UM_S } else { 200.0 };
            let f = r.render_path(&sweep(x(i), v, n), 1.0, 1.0, i, 0.0, i);
            black_box(f.expect("render"))
        })
    });
    grp.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
