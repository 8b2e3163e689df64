//! What the characterization's reference re-measurements (`drift_every_s`)
//! gain on the rig's thermal drift, measured through the same function
//! `tables build` applies to a log (`analysis::drift::correct_log_drift`).
//!
//! The log is made on the model simulator's default stage model: a 9.5 h
//! run (the paper's length) scanning X back and forth over 9.5 mm at 5 µm
//! steps, one point every 10 s, under a room temperature wandering by a
//! random walk (σ = 0.25 °C per 10 min, smooth), with a `drift_ref`
//! re-measurement of the start corner every 10 min (noise σ = 46 nm, the
//! rig's measurement noise). The scan points are noise-free so that the
//! residual isolates drift: residual = measured − what the same rig at the
//! starting temperature would have measured at that point. Prints, per
//! seed and on average: residual drift without correction, with the static
//! correction (line fitted on the first hour) and with the adaptive one
//! the daemon uses (τ = 20 min).

use micropos::analysis::drift::{
    correct_log_drift, DriftMethod, DRIFT_REF_SEGMENT, LOG_DRIFT_METHOD,
};
use micropos::charact::log::Record;
use micropos::model::{Environment, Interpolation, MotionState, StageModel, TemperaturePoint};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

const RUN_S: f64 = 9.5 * 3600.0;
const POINT_EVERY_S: f64 = 10.0;
const REF_EVERY_S: f64 = 600.0;
const X_START_UM: f64 = 2750.0;
const X_RANGE_UM: f64 = 9500.0;
const STEP_UM: f64 = 5.0;
const Y_HOLD_UM: f64 = 7500.0;
const REF_UM: [f64; 2] = [2750.0, 5400.0];

fn record(seg: &str, t_s: f64, target: [f64; 2], meas: [f64; 2]) -> Record {
    Record {
        t_s,
        segment: seg.to_owned(),
        cycle: 1,
        x_target_um: target[0],
        y_target_um: target[1],
        x_cmd_um: target[0],
        y_cmd_um: target[1],
        x_meas_um: meas[0],
        y_meas_um: meas[1],
        temp_c: None,
        theta_urad: None,
        extra: Vec::new(),
    }
}

/// RMS over both components of (measured − drift-free measured), µm.
fn residual_um(records: &[Record], drift_free: &[[f64; 2]]) -> f64 {
    let scans: Vec<&Record> = records
        .iter()
        .filter(|r| r.segment != DRIFT_REF_SEGMENT)
        .collect();
    assert_eq!(scans.len(), drift_free.len());
    let s: f64 = scans
        .iter()
        .zip(drift_free)
        .map(|(r, f)| (r.x_meas_um - f[0]).powi(2) + (r.y_meas_um - f[1]).powi(2))
        .sum();
    (s / (2 * scans.len()) as f64).sqrt()
}

#[test]
fn reference_re_measurements_remove_most_thermal_drift() {
    let model = StageModel::paper_default().unwrap();
    let seeds = 8;
    let (mut sum_none, mut sum_static, mut sum_adaptive) = (0.0, 0.0, 0.0);
    let mut adaptive_not_best = 0;
    for seed in 0..seeds {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let walk = Normal::new(0.0, 0.25).unwrap();
        let noise = Normal::new(0.0, 0.046).unwrap();
        let mut temp = 20.0;
        let mut pts = Vec::new();
        for k in 0..=60 {
            pts.push(TemperaturePoint {
                time_s: 600.0 * k as f64,
                temp_c: temp,
            });
            temp += walk.sample(&mut rng);
        }
        let env = Environment {
            temperature_interpolation: Interpolation::Smooth,
            temperature: pts,
        };
        // Measured position at `p` and time `t` (observed error added).
        let measure = |p: [f64; 2], t: f64| {
            let mut s = MotionState::at_rest(p[0], p[1]);
            s.time_s = t;
            s.temp_c = env.temperature_at(t);
            let e = model.observed_error_um(&s);
            [p[0] + e[0], p[1] + e[1]]
        };
        let n_steps = (X_RANGE_UM / STEP_UM) as i64;
        let mut log = Vec::new();
        let mut drift_free = Vec::new();
        let mut next_ref = 0.0;
        let mut k: i64 = 0;
        let mut t = 0.0;
        while t < RUN_S {
            if t >= next_ref {
                let m = measure(REF_UM, t);
                let m = [m[0] + noise.sample(&mut rng), m[1] + noise.sample(&mut rng)];
                log.push(record(DRIFT_REF_SEGMENT, t, REF_UM, m));
                next_ref += REF_EVERY_S;
                t += 30.0; // the detour to the reference and back
            }
            // Back and forth over the range.
            let phase = k.rem_euclid(2 * n_steps);
            let i = if phase <= n_steps {
                phase
            } else {
                2 * n_steps - phase
            };
            let p = [X_START_UM + STEP_UM * i as f64, Y_HOLD_UM];
            log.push(record("scan_x_fwd", t, p, measure(p, t)));
            drift_free.push(measure(p, 0.0));
            k += 1;
            t += POINT_EVERY_S;
        }
        let none = residual_um(&log, &drift_free);
        let (st, rep) = correct_log_drift(
            &log,
            DriftMethod::Static {
                calibration_s: 3600.0,
            },
        )
        .unwrap();
        let rep = rep.unwrap();
        assert_eq!(rep.references, (RUN_S / REF_EVERY_S).ceil() as usize);
        assert_eq!(rep.corrected, drift_free.len());
        let stat = residual_um(&st, &drift_free);
        let (ad, _) = correct_log_drift(&log, LOG_DRIFT_METHOD).unwrap();
        let adap = residual_um(&ad, &drift_free);
        println!(
            "seed {seed}: residual drift none {none:.3} µm, static {stat:.3} µm, \
             adaptive {adap:.3} µm (max drift at the reference {:.2}/{:.2} µm)",
            rep.max_drift_um[0], rep.max_drift_um[1]
        );
        sum_none += none;
        sum_static += stat;
        sum_adaptive += adap;
        if adap >= stat.min(none) {
            adaptive_not_best += 1;
        }
    }
    let n = seeds as f64;
    let (mn, ms, ma) = (sum_none / n, sum_static / n, sum_adaptive / n);
    println!(
        "mean residual drift over {seeds} seeds: none {mn:.3} µm, static {ms:.3} µm, \
         adaptive {ma:.3} µm ({:.0} % lower than none, {:.0} % lower than static)",
        100.0 * (1.0 - ma / mn),
        100.0 * (1.0 - ma / ms)
    );
    assert!(
        adaptive_not_best <= 1,
        "adaptive not best in {adaptive_not_best} runs"
    );
    assert!(ma < 0.5 * mn, "adaptive {ma} µm vs uncorrected {mn} µm");
    assert!(ma < 0.5 * ms, "adaptive {ma} µm vs static {ms} µm");
}

/// A log without `drift_ref` records comes back unchanged.
#[test]
fn logs_without_references_are_unchanged() {
    let log = vec![record("scan_x_fwd", 0.0, [1.0, 2.0], [1.1, 2.2])];
    let (out, rep) = correct_log_drift(&log, LOG_DRIFT_METHOD).unwrap();
    assert_eq!(out, log);
    assert!(rep.is_none());
}
