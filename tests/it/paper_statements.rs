//! The paper's measurements as the data the simulation must reproduce
//! (`micropos::analysis::paper`, docs/design/paper-faithful.md).
//!
//! - The default model is kinder than the paper's real stage: the paper's
//!   own lookup-table procedure gives it well under 1 µm where the paper
//!   measured 3.5 / 7 µm — the discrepancy the faithful model explains.
//! - The paper-faithful model (`config/stage-model-paper.toml`) meets every
//!   statement, as the median over five seeds.
//! - Each effect the faithful model adds is needed: without it some
//!   statement fails (leave one out). And the hypotheses that were
//!   rejected fail on their own (docs give the numbers).

use micropos::analysis::generate::{simulate_log, truth_model, SimPlan};
use micropos::analysis::paper::{compare, reproduce, PaperFigures, PaperOptions, STATEMENTS};
use micropos::analysis::{diagnose, DiagnoseOptions, FindingKind};
use micropos::charact::log::parse_bytes;
use micropos::model::{Axis, StageModel, PAPER_DEFAULT_TOML as PAPER_DEFAULT};

const FAITHFUL: &str = include_str!("../../config/stage-model-paper.toml");

fn runs(model: &StageModel, seeds: u64) -> Vec<PaperFigures> {
    let opts = PaperOptions::default();
    (1..=seeds)
        .map(|s| reproduce(model, &opts, s).unwrap())
        .collect()
}

fn failing(model: &StageModel) -> Vec<&'static str> {
    compare(&runs(model, 5))
        .into_iter()
        .filter(|c| !c.holds)
        .map(|c| c.statement.id)
        .collect()
}

fn edited(replace: &[(&str, &str)]) -> StageModel {
    let mut text = FAITHFUL.to_owned();
    for (a, b) in replace {
        assert!(text.contains(a), "the faithful model has no `{a}`");
        text = text.replacen(a, b, 1);
    }
    StageModel::from_toml(&text).unwrap()
}

#[test]
fn the_faithful_model_meets_every_statement_over_five_seeds() {
    let model = StageModel::from_toml(FAITHFUL).unwrap();
    let r = runs(&model, 5);
    let checks = compare(&r);
    assert_eq!(checks.len(), STATEMENTS.len());
    for c in &checks {
        assert!(
            c.holds,
            "{}: median {} not in {:?} (spread {:?})",
            c.statement.id, c.median, c.statement.accept, c.spread
        );
    }
    // The paper's plan and time: 9.5 h, +0.5 °C.
    assert!((r[0].characterization_s / 3600.0 - 9.5).abs() < 0.1);
    assert!((r[0].temperature_change_c - 0.5).abs() < 0.01);
    // Seeds differ (noise is drawn) but the same seed gives the same run.
    assert_ne!(r[0], r[1]);
    assert_eq!(runs(&model, 1)[0], r[0]);
}

#[test]
fn the_default_model_is_kinder_than_the_paper_s_stage() {
    let model = StageModel::paper_default().unwrap();
    let checks = compare(&runs(&model, 5));
    let get = |id: &str| checks.iter().find(|c| c.statement.id == id).unwrap();
    // Raw accuracy and the scans' shape are right …
    for id in [
        "raw_square_ap_um",
        "raw_random_ap_um",
        "backlash_x_um",
        "x_period_um",
        "coupling_period_um",
    ] {
        assert!(get(id).holds, "{id}: {}", get(id).median);
    }
    // … but the paper's procedure leaves far less than it did on the real
    // stage, random targets no worse than the square, and no RP peaks.
    assert!(get("table_square_ap_um").median < 1.0);
    assert!(get("table_random_ap_um").median < 1.0);
    assert!(get("random_over_square").median < 1.5);
    assert!(!get("rp_peaks_above_1um").holds);
}

#[test]
fn every_added_effect_is_needed() {
    // Without the move-length lost motion the compensated figures collapse.
    let no_lost_motion = edited(&[
        ("amplitude_um = 5.0", "amplitude_um = 0.0"),
        ("amplitude_um = 5.0", "amplitude_um = 0.0"),
    ]);
    let f = failing(&no_lost_motion);
    for id in [
        "table_square_ap_um",
        "table_random_ap_um",
        "random_over_square",
    ] {
        assert!(f.contains(&id), "{id} should fail without it: {f:?}");
    }
    // Without the rough stretches the RP profile has no isolated peaks.
    let no_spots = edited(&[
        ("sigma_um = 1.2", "sigma_um = 0.0"),
        ("sigma_um = 1.2", "sigma_um = 0.0"),
        ("sigma_um = 1.0", "sigma_um = 0.0"),
    ]);
    assert!(failing(&no_spots).contains(&"rp_peaks_above_1um"));
}

#[test]
fn the_rejected_hypotheses_fail_on_their_own() {
    let default = PAPER_DEFAULT;
    let with = |replace: &[(&str, &str)]| {
        let mut text = default.to_owned();
        for (a, b) in replace {
            assert!(text.contains(a), "the default model has no `{a}`");
            text = text.replacen(a, b, 1);
        }
        failing(&StageModel::from_toml(&text).unwrap())
    };
    // More thermal drift (the paper's reading of its RP): the compensated
    // figures stay far below the paper's, random no worse than the square.
    let thermal = with(&[
        ("x_offset_um_per_c = 0.35", "x_offset_um_per_c = 0.8"),
        ("y_offset_um_per_c = 0.25", "y_offset_um_per_c = 0.6"),
    ]);
    assert!(thermal.contains(&"table_square_ap_um") && thermal.contains(&"random_over_square"));
    // Larger repeatability: same.
    let sigma = with(&[(
        "repeatability_sigma_um = [0.035, 0.035]",
        "repeatability_sigma_um = [0.1, 0.1]",
    )]);
    assert!(sigma.contains(&"table_random_ap_um") && sigma.contains(&"random_over_square"));
    // A non-separable error: the lower (Y) carriage's yaw seen through the
    // x travel, at five times the datasheet's ±150 µrad: the square can
    // reach 3.5 µm, but random targets do not get twice as bad.
    let yaw = with(&[
        (
            "slope_urad_per_mm = -5.0\nperiod_um = 5000.0\nsin_urad = [15.0]",
            "slope_urad_per_mm = 0.0\nperiod_um = 5000.0\nsin_urad = [750.0]",
        ),
        (
            "arm_x_um = 8000.0                  # µm, tool point beside the y drive line\narm_y_um = 0.0\n",
            "arm_x_um = 8000.0\narm_y_um = 0.0\ncarries_other_axis = true\n",
        ),
    ]);
    assert!(yaw.contains(&"random_over_square"), "{yaw:?}");
}

/// The loop closed on the paper's data: `diagnose`, starting from the old
/// default model, names what the faithful model added — on a log whose moves
/// vary in length (scans plus random points, `micropos simlog`'s plan). The
/// paper's own plan moves 5 µm at a time: its log cannot show a lost motion
/// that needs long moves (docs/design/paper-faithful.md).
#[test]
fn diagnose_names_the_added_effects_from_the_default_model() {
    let faithful = StageModel::from_toml(FAITHFUL).unwrap();
    let default = StageModel::paper_default().unwrap();
    let plan = SimPlan::default();
    for seed in [3, 11] {
        let truth = truth_model(&faithful, None, &plan, seed).unwrap();
        let log = simulate_log(&truth, &plan, seed).unwrap();
        let parsed = parse_bytes(&log.to_bytes().unwrap()).unwrap();
        let d = diagnose(&parsed, &default, &DiagnoseOptions::default()).unwrap();
        for axis in [Axis::X, Axis::Y] {
            let f = d
                .findings
                .iter()
                .find(|f| f.kind == FindingKind::StepSize && f.component == axis)
                .unwrap_or_else(|| {
                    panic!("seed {seed}: no step_size on {axis:?}: {:#?}", d.findings)
                });
            let a = f.params["amplitude_um"];
            assert!(
                (a - 5.0).abs() < 0.75,
                "seed {seed} {axis:?}: amplitude {a}"
            );
        }
        // The larger thermal offset: +0.45 / +0.35 µm/°C beyond the default.
        // The default model has the term (`stage_thermal`'s offset
        // coefficient), so the base fit reports it as a parameter correction
        // of that size, not as a finding.
        for (axis, param, extra) in [
            (Axis::X, "x_offset_um_per_c", 0.45),
            (Axis::Y, "y_offset_um_per_c", 0.35),
        ] {
            assert!(
                !d.findings
                    .iter()
                    .any(|f| f.kind == FindingKind::Temperature && f.component == axis),
                "seed {seed}: the thermal offset on {axis:?} is the model's own term, not a finding: {:#?}",
                d.findings
            );
            let p = d
                .parameters
                .iter()
                .find(|p| p.kind == "thermal_expansion" && p.parameter == param)
                .unwrap_or_else(|| {
                    panic!("seed {seed}: no correction of {param}: {:#?}", d.parameters)
                });
            let k = p.fitted_value - p.model_value;
            assert!(
                p.significant && (k - extra).abs() < 0.15,
                "seed {seed} {axis:?}: correction {k:+.3} µm/°C (truth {extra:+.2}): {p:#?}"
            );
        }
    }
}
