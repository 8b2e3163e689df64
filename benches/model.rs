//! Stage model speed: evaluation (the simulator calls it per move) and a fit
//! of a paper-sized characterization (11 403 samples, 45 free parameters).

use criterion::{black_box, criterion_group, criterion_main, Criterion};
use micropos::model::{Direction, FitOptions, MotionState, Sample, StageModel, StageSimulator};

fn characterization(model: &StageModel) -> Vec<Sample> {
    let mut sim = StageSimulator::new(model.clone(), MotionState::at_rest(7500.0, 7500.0), 1)
        .expect("default model");
    let mut out = Vec::new();
    let mut t = 0.0;
    for cycle in 0..3 {
        for pass in [true, false] {
            for i in 0..=1900 {
                let x = if pass {
                    5.0 * i as f64
                } else {
                    9500.0 - 5.0 * i as f64
                };
                t += 3.0;
                let s = sim.move_to(x, 2000.0, t, cycle).expect("finite");
                out.push(Sample {
                    state: s.state,
                    measured_x_um: s.observed_um.x_um,
                    measured_y_um: s.observed_um.y_um,
                });
            }
        }
    }
    out
}

fn bench(c: &mut Criterion) {
    let model = StageModel::paper_default().expect("default model");
    let state = MotionState::arrived(1234.5, Direction::Forward, 2345.6, Direction::Backward);
    c.bench_function("model/observed_position", |b| {
        b.iter(|| model.observed_position(black_box(&state)))
    });
    c.bench_function("model/jacobian", |b| {
        b.iter(|| model.jacobian(black_box(&state)))
    });
    let samples = characterization(&model);
    let opts = FitOptions::free([
        "x_cyclic.*",
        "x_to_y_coupling.*",
        "x_backlash.*",
        "x_lead.*",
    ]);
    let mut group = c.benchmark_group("model/fit");
    group.sample_size(10);
    group.bench_function("x_characterization_11k", |b| {
        b.iter(|| {
            let mut m = model.clone();
            m.fit(black_box(&samples), &opts).expect("fit")
        })
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
