//! Drift correction from reference re-measurements on simulated thermal
//! drift (the default model's thermal terms under a wandering room
//! temperature, 9.5 h like the paper's run): the adaptive estimator must
//! beat the static one. Prints both residuals for the report.

use micropos::analysis::drift::{DriftEstimator, DriftMethod, ReferenceSample};
use micropos::model::{Environment, Interpolation, MotionState, StageModel, TemperaturePoint};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

#[test]
fn adaptive_drift_model_beats_the_static_one() {
    let model = StageModel::paper_default().unwrap();
    let mut worse = 0;
    let (mut sum_static, mut sum_adaptive) = (0.0, 0.0);
    let seeds = 8;
    for seed in 0..seeds {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let step = Normal::new(0.0, 0.25).unwrap();
        let noise = Normal::new(0.0, 0.046).unwrap();
        let mut temp = 20.0;
        let mut pts = Vec::new();
        for k in 0..=60 {
            pts.push(TemperaturePoint {
                time_s: 600.0 * k as f64,
                temp_c: temp,
            });
            temp += step.sample(&mut rng);
        }
        let env = Environment {
            temperature_interpolation: Interpolation::Smooth,
            temperature: pts,
        };
        let drift = |t: f64| {
            let mut s = MotionState::at_rest(5000.0, 2000.0);
            s.temp_c = env.temperature_at(t);
            let e = model.observed_error_um(&s);
            let mut s0 = s;
            s0.temp_c = env.temperature_at(0.0);
            let e0 = model.observed_error_um(&s0);
            [e[0] - e0[0], e[1] - e0[1]]
        };
        let mut st = DriftEstimator::new(DriftMethod::Static {
            calibration_s: 3600.0,
        })
        .unwrap();
        let mut ad = DriftEstimator::new(DriftMethod::Adaptive {
            time_constant_s: 1200.0,
        })
        .unwrap();
        let (mut es, mut ea, mut n) = (0.0, 0.0, 0);
        for minute in 0..570 {
            let t = 60.0 * minute as f64;
            if minute % 10 == 0 {
                let d = drift(t);
                let m = ReferenceSample {
                    t_s: t,
                    drift_um: [d[0] + noise.sample(&mut rng), d[1] + noise.sample(&mut rng)],
                };
                st.push(m).unwrap();
                ad.push(m).unwrap();
            }
            let truth = drift(t);
            let (ps, pa) = (st.predict(t).unwrap(), ad.predict(t).unwrap());
            for c in 0..2 {
                es += (truth[c] - ps[c]).powi(2);
                ea += (truth[c] - pa[c]).powi(2);
            }
            n += 2;
        }
        let (rs, ra) = ((es / n as f64).sqrt(), (ea / n as f64).sqrt());
        println!("seed {seed}: residual drift static {rs:.3} µm, adaptive {ra:.3} µm");
        sum_static += rs;
        sum_adaptive += ra;
        if ra >= rs {
            worse += 1;
        }
    }
    let (ms, ma) = (sum_static / seeds as f64, sum_adaptive / seeds as f64);
    println!(
        "mean residual drift: static {ms:.3} µm, adaptive {ma:.3} µm ({:.0} % lower)",
        100.0 * (1.0 - ma / ms)
    );
    assert!(worse <= 1, "adaptive worse than static in {worse} runs");
    assert!(ma < 0.5 * ms, "adaptive {ma} vs static {ms}");
}
