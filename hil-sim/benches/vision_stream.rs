//! Wall time per frame of the daemon's on-demand vision pipeline on the
//! in-process rig (virtual clock), for a consumer that takes every frame:
//! held with `Vision::want_stream` (a sweep: the next frame is grabbed,
//! i.e. rendered, alongside the current decode) against `Vision::want`
//! (the baseline, measured in the same run: grab, expose, decode, publish,
//! one after the other). Both give the same frames at the same rig times
//! (`rig_camera::a_stream_sees_the_frames_one_grab_at_a_time_would_give`).
//!
//! Prints the median over five alternating runs of 150 frames each, and
//! the ratio. `cargo bench -p hil-sim --bench vision_stream`
use hil_sim::{ServeConfig, SimHandle};
use micropos::daemon::vision::{Capture, Vision};
use micropos::pattern::decode::DecodeOptions;
use std::time::Instant;

const FRAMES: usize = 150;
const RUNS: usize = 5;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Wall seconds per frame for `FRAMES` frames taken by one consumer.
fn per_frame_s(stream: bool) -> f64 {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .start_paused(true)
        .build()
        .expect("runtime");
    let dir = tempfile::tempdir().expect("temporary directory");
    rt.block_on(async {
        let sim = SimHandle::start_in_process(ServeConfig {
            link_dir: dir.path().to_path_buf(),
            seed: 3,
            ..ServeConfig::default()
        })
        .expect("rig");
        let env = hil_sim::run::in_process_environment(&sim);
        let cam = sim.camera().config();
        let v = Vision::start_with(
            env.camera.expect("camera"),
            DecodeOptions::new(cam.period_um, cam.bits),
            env.clock.clone(),
            Capture::OnDemand,
        )
        .expect("vision");
        let mut rx = v.latest.clone();
        let want = if stream { v.want_stream() } else { v.want() };
        let t0 = Instant::now();
        let mut n = 0;
        while n < FRAMES {
            rx.changed().await.expect("pipeline");
            if rx.borrow_and_update().is_some() {
                n += 1;
            }
        }
        let s = t0.elapsed().as_secs_f64() / FRAMES as f64;
        drop(want);
        s
    })
}

fn main() {
    let (mut one, mut stream) = (Vec::new(), Vec::new());
    for _ in 0..RUNS {
        one.push(per_frame_s(false));
        stream.push(per_frame_s(true));
    }
    let (a, b) = (median(one), median(stream));
    println!(
        "on-demand vision, {FRAMES} frames, median of {RUNS}: one grab at a time {:.2} ms/frame, grab ahead (stream) {:.2} ms/frame, ratio {:.2}",
        a * 1e3,
        b * 1e3,
        b / a
    );
}
