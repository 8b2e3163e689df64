//! Tests of the log handling and the search's preconditions on simulated
//! logs (the whole analysis is exercised by `tests/diagnose_*`).

use super::search::step_length_range;
use super::*;
use crate::analysis::generate::{add_extra_column, simulate_log, truth_model, SimPlan};
use crate::charact::log::{parse_bytes, Columns};

fn small_plan(random_points: usize) -> SimPlan {
    SimPlan {
        x_range_um: [250.0, 1250.0],
        x_scan_y_um: 600.0,
        y_range_um: [250.0, 1050.0],
        y_scan_x_um: 700.0,
        cycles: 2,
        random_points,
        ..SimPlan::default()
    }
}

#[test]
fn only_numeric_varying_new_columns_are_searched() {
    let base = StageModel::paper_default().unwrap();
    // Long enough (3.4 h) for the wandering column to wander: over a
    // few of its 300 s knots it is a straight line in time, which the
    // selection rightly leaves to the time families.
    let plan = SimPlan {
        dwell_s: 30.0,
        ..small_plan(20)
    };
    let truth = truth_model(&base, None, &plan, 3).unwrap();
    let mut log = simulate_log(&truth, &plan, 3).unwrap();
    add_extra_column(&mut log, "humidity_pct", 3, None).unwrap();
    let mut extra = log.columns.extra.clone();
    for name in ["focus", "mostly_text", "constant", "x_reported_um"] {
        extra.push(name.to_string());
    }
    log.columns = Columns::new(true, extra).unwrap();
    let n = log.records.len();
    for (i, r) in log.records.iter_mut().enumerate() {
        r.extra.push("ok".into());
        r.extra
            .push(if i % 2 == 0 { "1.5" } else { "n/a" }.to_string());
        r.extra.push("7".into());
        r.extra.push(format!("{:.4}", r.x_cmd_um + 0.001));
        if i == n / 2 {
            r.extra[0] = "garbage".into();
        }
    }
    let parsed = parse_bytes(&log.to_bytes().unwrap()).unwrap();
    let d = prepare(&parsed, &base, 4).unwrap();
    let names: Vec<&str> = d.extra.iter().map(|x| x.name.as_str()).collect();
    assert_eq!(names, ["humidity_pct"]);
    let h = &d.extra[0];
    // One unparsable cell takes the mean (no effect on the fit).
    assert!((h.values[n / 2] - h.mean).abs() < 1e-12);
    assert!(h.min < h.max);
}

#[test]
fn step_size_is_searched_only_with_moves_of_different_lengths() {
    let base = StageModel::paper_default().unwrap();
    for (random, want) in [(0usize, false), (40, true)] {
        let plan = small_plan(random);
        let truth = truth_model(&base, None, &plan, 5).unwrap();
        let log = simulate_log(&truth, &plan, 5).unwrap();
        let parsed = parse_bytes(&log.to_bytes().unwrap()).unwrap();
        let d = prepare(&parsed, &base, 4).unwrap();
        assert_eq!(
            step_length_range(&d, Axis::X).is_some(),
            want,
            "{random} random points"
        );
    }
}
