//! `diagnose` on logs the simulated rig wrote (`tests/data/rig/`): microposd
//! characterizing the in-process hil-sim rig (servo dynamics, rendered and
//! decoded frames, the daemon's tie), kept with
//! `MICROPOS_RIG_KEEP=DIR cargo test -p hil-sim --test it hidden_rig::` so the
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
//!   folds kept. Written before the daemon logged each point's approach
//!   direction: the first point of the first y pass, reached from below by
//!   an approach move the log does not hold, is replayed as reached from
//!   above (where the x scans held y), on the other side of y's 1.8 µm
//!   play. With the second cycle's first point it forms a target visited
//!   twice whose visits disagree by 1.7 µm: a discordant pair, left out.
//! - `plain-seed3001-approach.csv`: the same run by the daemon that logs
//!   each point's `approach` (how its scanned axis was last moved,
//!   unlogged approach moves included): replayed with it, the first y
//!   point is on the right side of the play and no pair disagrees.
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

/// One pair of visits 1.7 µm apart must not set y's repeatability (it made
/// it 0.14 µm against x's 0.036) nor stay in the fit (its row left 0.09 µm
/// of y held-out rms against 0.022 µm of neighbour noise).
#[test]
fn a_pair_of_visits_that_disagree_is_left_out_and_named() {
    let log = read_file(data("plain-seed3001.csv")).unwrap();
    let d = diagnose(&log, &nominal(), &DiagnoseOptions::default()).unwrap();
    let text = d.to_text();
    let comp = |a: Axis| {
        d.noise
            .components
            .iter()
            .find(|c| c.component == a)
            .unwrap()
    };
    let (x, y) = (comp(Axis::X), comp(Axis::Y));
    assert!(x.discordant_pairs.is_empty(), "{text}");
    assert_eq!(y.discordant_pairs.len(), 1, "{text}");
    assert!(!y.discordant_pairs_kept, "{text}");
    let p = &y.discordant_pairs[0];
    assert!((p.target_um - 500.0).abs() < 1e-6, "{text}");
    assert!(
        (p.difference_um.abs() - 1.7).abs() < 0.2 && p.sigmas > 10.0,
        "{text}"
    );
    assert!(p.first_of_pass.iter().any(|&f| f), "{text}");
    assert!(text.contains("discordant pair"), "{text}");
    let (rx, ry) = (x.repeatability_um.unwrap(), y.repeatability_um.unwrap());
    assert!(ry < 1.5 * rx && ry > rx / 1.5, "{text}");
    let nb = y.neighbour_noise_um.unwrap();
    assert!(y.heldout_rms_um < 1.5 * nb, "{text}");
    assert!(!y.unexplained, "{text}");
}

/// With the `approach` column the replay puts every point on the side of
/// the play it was reached from: the pair above agrees, y repeats like x,
/// and y's held-out residual is its neighbour noise.
#[test]
fn a_log_that_says_how_each_point_was_approached_is_replayed_right() {
    let log = read_file(data("plain-seed3001-approach.csv")).unwrap();
    // The daemon's cells: a pass's first point after an approach move, and
    // the next cycle's first point read again where the last pass ended
    // (no move: it keeps the direction it was reached by).
    let col = log
        .columns
        .extra
        .iter()
        .position(|c| c == diagnose::APPROACH_COLUMN)
        .unwrap();
    let first = |seg: &str, cycle: u32| {
        let r = log
            .records
            .iter()
            .find(|r| r.segment == seg && r.cycle == cycle)
            .unwrap();
        r.extra[col].clone()
    };
    assert_eq!(first("scan_y_fwd", 1), "fwd");
    assert_eq!(first("scan_y_bwd", 1), "fwd");
    assert_eq!(first("scan_y_fwd", 2), "bwd");
    let d = diagnose(&log, &nominal(), &DiagnoseOptions::default()).unwrap();
    let text = d.to_text();
    assert!(d.findings.is_empty(), "{text}");
    for c in &d.noise.components {
        assert!(c.discordant_pairs.is_empty(), "{text}");
        assert!(!c.unexplained, "{text}");
        let nb = c.neighbour_noise_um.unwrap();
        assert!(c.heldout_rms_um < 1.2 * nb, "{text}");
    }
    let r: Vec<f64> = d
        .noise
        .components
        .iter()
        .map(|c| c.repeatability_um.unwrap())
        .collect();
    assert!(r[1] < 1.5 * r[0] && r[1] > r[0] / 1.5, "{text}");
}
