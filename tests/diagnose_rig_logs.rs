//! `diagnose` on logs the simulated rig wrote (`tests/data/rig/`): microposd
//! characterizing the in-process hil-sim rig (servo dynamics, rendered and
//! decoded frames, the daemon's tie), kept with
//! `MICROPOS_RIG_KEEP=DIR cargo test -p hil-sim --test hidden_rig` so the
//! cases the rig showed run in CI without the rig (2 × 15 s there).
//!
//! - `time-periodic-y-seed2004.csv`: the rig's nominal model
//!   (`config/stage-model.toml`) plus a y error oscillating in time,
//!   0.933 µm every 301.5 s (`…-truth.toml`), in a log of 1212 s whose
//!   x scans (both cycles) precede its y scans. Whole-cycle folds cannot
//!   judge it (trained on one 600 s cycle, its phase is lost over the gap):
//!   they found nothing and called the log noise. Its visits of one target
//!   disagree ≈ 20× more than neighbouring points, so the diagnosis judges
//!   it again on folds interleaved in time.
//! - `plain-seed3001.csv`: the nominal model alone: no finding, whole-cycle
//!   folds kept.
//!
//! The errors are made by the rig's physics and camera, not by evaluating
//! the analysis's columns; the truth model is read only to compare.

use micropos::analysis::{diagnose, DiagnoseOptions, FindingKind};
use micropos::charact::log::read_file;
use micropos::model::{Axis, StageModel};
use std::path::Path;

fn data(name: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/rig")
        .join(name)
}

/// The rig's nominal model, what the daemon's log is diagnosed against.
fn nominal() -> StageModel {
    StageModel::paper_default().unwrap()
}

#[test]
fn a_time_periodic_error_whole_cycle_folds_miss_is_named_on_interleaved_folds() {
    let log = read_file(data("time-periodic-y-seed2004.csv")).unwrap();
    let d = diagnose(&log, &nominal(), &DiagnoseOptions::default()).unwrap();
    let text = d.to_text();
    println!("{text}");
    let why = d
        .folds_interleaved
        .as_deref()
        .unwrap_or_else(|| panic!("{text}"));
    assert!(why.starts_with("y's visits"), "{why}");
    let f = d.findings.first().unwrap_or_else(|| panic!("{text}"));
    assert_eq!(
        (f.kind, f.component),
        (FindingKind::TimePeriodic, Axis::Y),
        "{text}"
    );
    // The truth, from the model the rig served.
    let truth = std::fs::read_to_string(data("time-periodic-y-seed2004-truth.toml")).unwrap();
    let truth: toml::Value = toml::from_str(&truth).unwrap();
    let term = truth["term"]
        .as_array()
        .unwrap()
        .iter()
        .find(|t| t["name"].as_str() == Some("injected"))
        .unwrap();
    let period_s = term["period_s"].as_float().unwrap();
    let amplitude_um = term["sin_um"]
        .as_float()
        .unwrap()
        .hypot(term["cos_um"].as_float().unwrap());
    // The hidden-rig test's tolerances (5 % + 10 s, 25 % + 0.04 µm).
    let (p, a) = (f.params["period_s"], f.params["amplitude_um"]);
    assert!(
        (p - period_s).abs() <= 0.05 * period_s + 10.0,
        "{p} vs {period_s}"
    );
    assert!(
        (a - amplitude_um).abs() <= 0.25 * amplitude_um + 0.04,
        "{a} vs {amplitude_um}"
    );
    assert!(f.gain_pct > 50.0, "{text}");
    // With the finding in the model the visits agree again.
    let y = d
        .noise
        .components
        .iter()
        .find(|c| c.component == Axis::Y)
        .unwrap();
    assert!(!y.changes_between_visits, "{text}");
}

#[test]
fn the_plain_rig_keeps_whole_cycle_folds_and_finds_nothing() {
    let log = read_file(data("plain-seed3001.csv")).unwrap();
    let d = diagnose(&log, &nominal(), &DiagnoseOptions::default()).unwrap();
    let text = d.to_text();
    assert!(d.folds_interleaved.is_none(), "{text}");
    assert!(d.whole_cycle_folds, "{text}");
    assert!(d.findings.is_empty(), "{text}");
    assert!(
        d.noise.components.iter().all(|c| !c.changes_between_visits),
        "{text}"
    );
}
