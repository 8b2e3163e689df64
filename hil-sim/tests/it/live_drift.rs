//! Live drift correction on the rig's thermal drift, through the daemon
//! the main job's pipeline (`hil-sim run`) on a reduced
//! plan with a fast temperature ramp, characterizations with reference
//! re-measurements (tables corrected to the rig's state at their start),
//! then the `table` mode validated with live drift `off`, `static` and
//! `adaptive` (`RunPlan::drift_compare`).
//!
//! The ramp (linear, +10 °C per 1000 simulated s, the default stage model's
//! thermal terms: 0.35 / 0.25 µm/°C platform and 0.5 / 0.35 µm/°C optics
//! offsets) makes the drift between the characterization and the
//! validations several µm, and keep growing during each validation, so the
//! three methods separate: off keeps the whole offset, static the growth
//! since its first re-measurement, adaptive only the extrapolation error.

use hil_sim::run::{run, RunOptions, RunPlan};

/// The documented stage model with the temperature history replaced by a
/// linear ramp of `c_per_ks` °C per 1000 s.
fn ramp_model(dir: &std::path::Path, c_per_ks: f64) -> std::path::PathBuf {
    let text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../config/stage-model.toml"
    ))
    .unwrap()
    .replace(
        "temperature_interpolation = \"smooth\"",
        "temperature_interpolation = \"linear\"",
    );
    let start = text.find("temperature = [").unwrap();
    let end = start + text[start..].find("]\n").unwrap() + 2;
    let ramp = format!(
        "temperature = [\n    {{ time_s = 0.0, temp_c = 20.0 }},\n    {{ time_s = 100000.0, temp_c = {} }},\n]\n",
        20.0 + 100.0 * c_per_ks
    );
    let p = dir.join("ramp-model.toml");
    std::fs::write(&p, format!("{}{ramp}{}", &text[..start], &text[end..])).unwrap();
    p
}

#[test]
fn live_drift_correction_removes_the_thermal_offset() {
    let dir = tempfile::tempdir().unwrap();
    // 10 °C per 1000 s: the run takes ≈ 1100 simulated s (virtual clock),
    // so the thermal offset grows by ≈ 8 µm over it and by ≈ 0.13 µm between
    // two live re-measurements 15 s apart, a few times the measurement noise:
    // holding the last reference (static) and extrapolating the ramp
    // (adaptive) then differ by more than the noise.
    let model = ramp_model(dir.path(), 10.0);
    let plan = RunPlan {
        // 100 µm: the lookup tables resolve the 400 µm screw cycle well
        // enough (table AP ≈ 0.2-0.5 µm at constant temperature,
        // run_pipeline.rs) for the drift to dominate.
        step_um: 100.0,
        short_step_um: 2000.0,
        cycles: 1,
        validate_cycles: 2,
        square_step_um: 2000.0,
        drift_every_s: 60.0,
        live_drift: "adaptive".to_owned(),
        // Several re-measurements inside each trajectory, so adaptive has a
        // rate to extrapolate (with one, it can only hold it, as static).
        live_drift_every_s: 15.0,
        drift_compare: true,
        // The sweep row has its own test (sweep_charact.rs), the grid row
        // run_pipeline.rs.
        sweep_velocity_um_per_s: 0.0,
        grid_pitch_um: 0.0,
        // This project's timing for both characterizations (the paper's
        // 2.0 s settle only stretches the simulated hours here).
        paper_settle_s: 0.3,
        ..RunPlan::paper()
    };
    let opts = RunOptions {
        seed: 5,
        model: Some(model),
        out_dir: Some(dir.path().join("run")),
        plan,
        ..RunOptions::default()
    };
    let mut lines = Vec::new();
    let report = run(opts, &mut |l: &str| lines.push(l.to_owned()))
        .unwrap_or_else(|e| panic!("{e}; progress: {lines:?}"));
    let s = &report.summary;
    eprintln!("{}", hil_sim::run::format_table(s));
    let d = &s["drift"];
    assert!(
        d["tables_drift"]["references"].as_u64().unwrap() >= 2,
        "{d}"
    );
    let cmp = &d["compare"];
    let norm = |m: &str, t: &str| {
        let o = &cmp[m][t]["offset_um"];
        o[0].as_f64().unwrap().hypot(o[1].as_f64().unwrap())
    };
    let ap = |m: &str, t: &str| cmp[m][t]["ap_um"].as_f64().unwrap();
    for t in ["square", "random"] {
        assert!(norm("off", t) > 1.0, "{t}: the ramp should show: {cmp}");
        assert!(
            norm("adaptive", t) < 0.3 * norm("off", t),
            "{t}: adaptive should remove most of the offset: {cmp}"
        );
        assert!(ap("adaptive", t) < ap("off", t), "{t}: {cmp}");
        // Static holds the last re-measurement, adaptive extrapolates the
        // ramp: on a ramp adaptive is better, with no slack (the run is
        // the same on every machine: one seed, one result).
        assert!(
            norm("static", t) < 0.3 * norm("off", t),
            "{t}: static should remove most of the offset: {cmp}"
        );
        assert!(
            norm("adaptive", t) < norm("static", t),
            "{t}: adaptive should follow the ramp better than static: {cmp}"
        );
        // Mean AP over the poses: the largest AP is one pose, set by that
        // pose's own residual error as much as by the drift (measured: 1.227
        // vs 1.213 µm on the square while adaptive's offset was the smaller).
        assert!(
            cmp["adaptive"][t]["ap_mean_um"].as_f64().unwrap()
                < cmp["static"][t]["ap_mean_um"].as_f64().unwrap(),
            "{t}: {cmp}"
        );
        assert!(cmp["adaptive"][t]["references"].as_u64().unwrap() >= 1);
    }
    // The re-measurements are in the validation logs with the drift.
    let data = report.data_dir.unwrap();
    let log = micropos::charact::log::read_file(data.join("validate-drift-adaptive.csv")).unwrap();
    let refs: Vec<_> = log
        .records
        .iter()
        .filter(|r| r.segment == "drift_ref")
        .collect();
    assert!(!refs.is_empty());
    let col = log
        .columns
        .extra
        .iter()
        .position(|c| c == "drift_x_um")
        .unwrap();
    for r in &refs {
        let dx: f64 = r.extra[col].parse().unwrap();
        assert!(dx.abs() > 0.1, "drift at the reference: {r:?}");
    }
    let corrected = log
        .records
        .iter()
        .filter(|r| r.segment != "drift_ref" && !r.extra[col].is_empty())
        .count();
    assert_eq!(corrected, (8 + 10) * 2, "every table point corrected");
    assert_eq!(log.metadata.get("live_drift_method"), Some("adaptive"));
}
