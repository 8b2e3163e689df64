//! `hil-sim serve --model EXTENDED.toml` reproduces the log: the model file
//! `micropos diagnose --out` writes loads into the served rig (every term
//! kind the analysis adds), and the log's commanded trajectory run through
//! the stage simulator with that model lands on the log's measured
//! positions to the noise floor (the RMS the truth model itself leaves:
//! settling σ ⊕ camera σ), while the original
//! model (base-fitted, same room temperature, no findings) does not — for
//! an effect the default model lacks. One it has the structure for (scale,
//! squareness, play, x drift, temperature) is a parameter correction, and
//! the base-fitted model itself replays the log to the floor.
//!
//! One log per kind the generator hides (1 µm peak effect).
//! `-- --nocapture` prints the RMS table.

use hil_sim::{ServeConfig, SimHandle};
use micropos::analysis::generate::{
    draw_effect_sized, simulate_log, truth_model, SimPlan, GENERATED_KINDS,
};
use micropos::analysis::{diagnose, DiagnoseOptions};
use micropos::charact::log::{parse_bytes, MeasurementLog};
use micropos::model::{MotionState, StageModel, StageSimulator};

/// Settling σ (0.035 µm) ⊕ camera σ (0.03 µm) of the generated logs.
const NOISE_UM: f64 = 0.046;

/// RMS of measured − simulated (systematic part: the simulator's settling
/// draw removed) over the log, per component, µm.
fn replay_rms(model: &StageModel, log: &MeasurementLog) -> [f64; 2] {
    let r0 = &log.records[0];
    let mut start = MotionState::at_rest(r0.x_cmd_um, r0.y_cmd_um);
    start.time_s = r0.t_s;
    start.temp_c = model.environment().temperature_at(r0.t_s);
    let mut sim = StageSimulator::new(model.clone(), start, 1).unwrap();
    let mut ss = [0.0; 2];
    for r in &log.records {
        let s = sim.move_to(r.x_cmd_um, r.y_cmd_um, r.t_s, r.cycle).unwrap();
        let pred = [
            s.observed_um.x_um - s.settling_um[0],
            s.observed_um.y_um - s.settling_um[1],
        ];
        ss[0] += (r.x_meas_um - pred[0]).powi(2);
        ss[1] += (r.y_meas_um - pred[1]).powi(2);
    }
    let n = log.records.len() as f64;
    [(ss[0] / n).sqrt(), (ss[1] / n).sqrt()]
}

#[test]
fn served_extended_model_reproduces_the_log_to_the_noise_floor() {
    let dir = tempfile::tempdir().unwrap();
    let base = StageModel::paper_default().unwrap();
    let plan = SimPlan::default();
    let mut kinds_loaded = std::collections::BTreeSet::new();
    println!(
        "kind               comp  extended rms    original rms    truth rms (noise floor; σ {NOISE_UM} µm)"
    );
    for (i, kind) in GENERATED_KINDS.iter().enumerate() {
        let seed = 700 + i as u64;
        let e = draw_effect_sized(seed, *kind, 1.0, &plan).unwrap();
        let truth = truth_model(&base, Some(&e), &plan, seed).unwrap();
        let log = parse_bytes(
            &simulate_log(&truth, &plan, seed)
                .unwrap()
                .to_bytes()
                .unwrap(),
        )
        .unwrap();
        let d = diagnose(&log, &base, &DiagnoseOptions::default()).unwrap();
        // An effect the default model has the structure for (scale,
        // squareness, play, x drift, temperature) comes back as a parameter
        // correction of the base fit, not as a finding: then the base model
        // itself must replay the log to the floor.
        let carried = d.findings.is_empty();
        if carried {
            assert!(
                d.parameters.iter().any(|p| p.significant),
                "{kind}: neither a finding nor a parameter correction: {}",
                d.to_text()
            );
        }
        // As `diagnose --out` writes it, and as `serve --model` loads it.
        let path = dir.path().join(format!("extended-{kind}.toml"));
        std::fs::write(&path, d.extended_model.to_toml().unwrap()).unwrap();
        let loaded = hil_sim::rig::load_model(Some(&path)).unwrap();
        assert_eq!(
            loaded.parameter_vector(),
            d.extended_model.parameter_vector()
        );
        for t in loaded.terms() {
            kinds_loaded.insert(t.kind());
        }
        let links = dir.path().join(format!("rig-{kind}"));
        std::fs::create_dir(&links).unwrap();
        let sim = SimHandle::start(ServeConfig {
            link_dir: links,
            model: Some(path.clone()),
            seed,
            ..ServeConfig::default()
        })
        .unwrap();
        sim.shutdown();

        let ext = replay_rms(&loaded, &log);
        let orig = replay_rms(&d.base_model, &log);
        // The realized noise floor of this log: the truth itself replayed
        // (a static axis keeps one settling draw per scan line, so few
        // independent draws make the floor vary around 0.046 µm).
        let floor = replay_rms(&truth, &log);
        let c = e.component.index();
        println!(
            "{:18} {}     {:.4} {:.4}   {:.4} {:.4}   {:.4} {:.4}",
            kind.as_str(),
            e.component,
            ext[0],
            ext[1],
            orig[0],
            orig[1],
            floor[0],
            floor[1]
        );
        for c in 0..2 {
            assert!(
                ext[c] < 1.1 * floor[c] + 0.003 && ext[c] < 1.5 * NOISE_UM,
                "{kind}: extended rms {ext:?}, truth replay {floor:?}"
            );
        }
        if !carried {
            assert!(
                orig[c] > 2.0 * ext[c],
                "{kind}: original rms {orig:?} vs extended {ext:?}"
            );
        }
    }
    for k in [
        "position_periodic",
        "localized",
        "time_drift",
        "time_periodic",
        "step_size",
        "backlash",
    ] {
        assert!(
            kinds_loaded.contains(k),
            "{k} not covered: {kinds_loaded:?}"
        );
    }
}
