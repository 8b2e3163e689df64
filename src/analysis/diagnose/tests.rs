//! Tests of the log handling and the search's preconditions on simulated
//! logs (the whole analysis is exercised by `tests/it/diagnose_*`).

use super::search::step_length_range;
use super::*;
use crate::analysis::generate::{add_extra_column, simulate_log, truth_model, SimPlan};
use crate::analysis::FindingKind;
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

/// A simulated two-axis log with the y measurement replaced by a constant
/// placeholder (what a 1-D export writes).
fn one_axis_log(seed: u64) -> crate::charact::log::MeasurementLog {
    let base = StageModel::paper_default().unwrap();
    let plan = small_plan(0);
    let truth = truth_model(&base, None, &plan, seed).unwrap();
    let mut log = simulate_log(&truth, &plan, seed).unwrap();
    for r in &mut log.records {
        r.y_meas_um = 0.0;
    }
    parse_bytes(&log.to_bytes().unwrap()).unwrap()
}

#[test]
fn a_constant_meas_column_is_an_unmeasured_axis() {
    let base = StageModel::paper_default().unwrap();
    let log = one_axis_log(11);
    let d = prepare(&log, &base, 4).unwrap();
    assert_eq!(d.measured, [true, false]);
    assert_eq!(d.measured_source, data::MeasuredSource::Data);
    // Every column and residual is zero on the unmeasured component.
    assert!((0..d.n).all(|i| d.r0[2 * i + 1] == 0.0));
    let diag = diagnose(&log, &base, &DiagnoseOptions::default()).unwrap();
    assert_eq!(diag.measured_axes, vec![Axis::X]);
    assert!(diag.findings.iter().all(|f| f.component == Axis::X));
    assert!(diag.base_free_params.iter().all(|p| !p.starts_with("y_")));
    assert!(diag.to_text().contains("y not measured"));
}

#[test]
fn measured_axes_metadata_wins_and_is_checked() {
    let base = StageModel::paper_default().unwrap();
    let plan = small_plan(0);
    let truth = truth_model(&base, None, &plan, 12).unwrap();
    let sim = simulate_log(&truth, &plan, 12).unwrap();
    let mut log = parse_bytes(&sim.to_bytes().unwrap()).unwrap();
    log.metadata.insert(MEASURED_AXES_KEY, "y");
    let d = prepare(&log, &base, 4).unwrap();
    assert_eq!(d.measured, [false, true]);
    assert_eq!(d.measured_source, data::MeasuredSource::Metadata);
    log.metadata.insert(MEASURED_AXES_KEY, "z");
    assert!(prepare(&log, &base, 4).is_err());
    log.metadata.insert(MEASURED_AXES_KEY, "x, y");
    assert_eq!(prepare(&log, &base, 4).unwrap().measured, [true, true]);
}

/// A 1-D log written by hand: `cycles` of (targets, approach) passes.
fn hand_log(passes: &[(u32, Vec<f64>, &str)]) -> crate::charact::log::MeasurementLog {
    let mut s = String::from(
        "t_s,segment,cycle,x_target_um,y_target_um,x_cmd_um,y_cmd_um,x_meas_um,y_meas_um,approach\n",
    );
    let mut t = 0.0;
    for (cycle, targets, approach) in passes {
        for (k, x) in targets.iter().enumerate() {
            // A small deterministic wobble as the reading.
            let m = x + 0.1 * ((k as f64) * 1.7 + f64::from(*cycle)).sin();
            s += &format!("{t},scan_x,{cycle},{x},0,{x},0,{m},0,{approach}\n");
            t += 1.0;
        }
    }
    parse_bytes(s.as_bytes()).unwrap()
}

#[test]
fn a_fold_does_not_judge_extrapolation_into_a_range_it_never_sampled() {
    let base = StageModel::paper_default().unwrap();
    let up1: Vec<f64> = (0..=10).map(|k| 300.0 + 10.0 * f64::from(k)).collect();
    let up2: Vec<f64> = (0..=30).map(|k| 100.0 + 10.0 * f64::from(k)).collect();
    let down: Vec<f64> = (0..=40).rev().map(|k| 10.0 * f64::from(k)).collect();
    let log = hand_log(&[
        (1, up1, "fwd"),
        (1, down.clone(), "bwd"),
        (2, up2, "fwd"),
        (2, down, "bwd"),
    ]);
    let d = prepare(&log, &base, 4).unwrap();
    assert_eq!(d.nfolds, 2);
    for i in 0..d.n {
        let x = d.states[i].cmd_um(Axis::X);
        let fwd = d.approach[i][0] > 0.0;
        let cycle2 = log.records[i].cycle == 2;
        // Cycle 2's forward rows below 300 µm: cycle 1 went forward over
        // 300–400 µm only.
        let want = !(cycle2 && fwd && x < 300.0 - 1e-9);
        assert_eq!(d.judged[i], want, "row {i} at {x} µm");
    }
}

#[test]
fn the_approach_column_sets_the_replicate_direction() {
    assert_eq!(parse_approach("fwd"), Some(1.0));
    assert_eq!(parse_approach(" Backward "), Some(-1.0));
    assert_eq!(parse_approach("rest"), None);
    let base = StageModel::paper_default().unwrap();
    let t: Vec<f64> = (0..=20).map(|k| 20.0 * f64::from(k)).collect();
    let r: Vec<f64> = t.iter().rev().copied().collect();
    // Labelled backward although the commands go up: the column wins.
    let log = hand_log(&[(1, t.clone(), "bwd"), (1, r, "fwd"), (2, t, "bwd")]);
    let d = prepare(&log, &base, 4).unwrap();
    assert_eq!(d.approach[5][0], -1.0);
    assert_eq!(d.approach[30][0], 1.0);
}

#[test]
fn replicates_give_the_repeatability_and_the_unexplained_error() {
    // Five targets, five cycles, both directions; a per-target systematic
    // error of ±20 µm against a 0.5 µm scatter between cycles.
    let targets = [15_000.0, 25_000.0, 35_000.0, 45_000.0, 55_000.0];
    let sys = [20.0, -20.0, 15.0, -15.0, 0.0];
    let mut s = String::from(
        "t_s,segment,cycle,x_target_um,y_target_um,x_cmd_um,y_cmd_um,x_meas_um,y_meas_um,approach\n",
    );
    let mut k = 0;
    for c in 1..=5u32 {
        for (dir, order) in [("fwd", [0, 1, 2, 3, 4]), ("bwd", [4, 3, 2, 1, 0])] {
            for i in order {
                let noise = 0.5 * ((k as f64) * 2.399).sin();
                let m = targets[i] + sys[i] + noise;
                s += &format!("{k},scan_x,{c},{t},0,{t},0,{m},0,{dir}\n", t = targets[i]);
                k += 1;
            }
        }
    }
    let log = parse_bytes(s.as_bytes()).unwrap();
    let base = StageModel::paper_default().unwrap();
    // Without findings, the per-target error is stated against the noise.
    let none = DiagnoseOptions {
        max_findings: 0,
        ..DiagnoseOptions::default()
    };
    let d0 = diagnose(&log, &base, &none).unwrap();
    let x0 = &d0.noise.components[0];
    let rep = x0.repeatability_um.unwrap();
    assert!(rep > 0.1 && rep < 1.0, "{rep}");
    assert!(x0.unexplained);
    assert!(x0.systematic_rms_um.unwrap() > 10.0 * rep);
    assert!(!d0.to_text().contains("explains the log to its noise"));
    // With them, the non-linearity read from the replicates becomes a
    // table the extended model carries, and its held-out residual drops
    // to the scatter's order.
    let d = diagnose(&log, &base, &DiagnoseOptions::default()).unwrap();
    let x = &d.noise.components[0];
    assert_eq!(x.replicated_targets, 10);
    assert!(x.iso230_2.is_some());
    let f = d
        .findings
        .iter()
        .find(|f| f.kind == FindingKind::Nonlinearity)
        .unwrap_or_else(|| panic!("{}", d.to_text()));
    assert!(f.heldout_rms_after_um < 3.0 * rep, "{f:?}");
    assert!(x.systematic_rms_um.unwrap() < 3.0 * rep, "{x:?}");
    let s = &d.noise.sampling[0];
    assert_eq!(s.positions, 5);
    assert!((s.shortest_period_um - 20_000.0).abs() < 1e-6);
    // The model's 400 µm harmonics cannot be resolved on 10 mm targets:
    // no periodic parameter is freed, and the screw table's are aliased.
    assert!(d
        .base_free_params
        .iter()
        .all(|p| !p.contains("sin") && !p.contains("cos")));
    assert!(d
        .base_fixed_params
        .iter()
        .filter(|p| p.name.starts_with("x_cyclic."))
        .all(|p| p.aliased));
    // What is freed is reported as parameter corrections, never findings.
    assert_eq!(d.parameters.len(), d.base_free_params.len());
}

#[test]
fn declared_approach_moves_give_the_replay_the_true_direction() {
    // An ISO-style pass: forward over 0..400 µm, then backward starting at
    // the same 400 µm target (the move beyond it was not logged).
    let base = StageModel::paper_default().unwrap();
    let up: Vec<f64> = (0..=4).map(|k| 100.0 * f64::from(k)).collect();
    let down: Vec<f64> = up.iter().rev().copied().collect();
    let log = hand_log(&[
        (1, up.clone(), "fwd"),
        (1, down.clone(), "bwd"),
        (2, up, "fwd"),
        (2, down, "bwd"),
    ]);
    let d = prepare(&log, &base, 4).unwrap();
    for (i, s) in d.states.iter().enumerate() {
        let want = if log.records[i].extra[0] == "fwd" {
            crate::model::Direction::Forward
        } else {
            crate::model::Direction::Backward
        };
        assert_eq!(s.axes[0].dir, want, "row {i}");
        assert_eq!(s.cmd_um(Axis::X), log.records[i].x_cmd_um);
    }
}

#[test]
fn another_stage_of_the_same_design_gives_corrections_not_findings() {
    // The issue's case: squareness −5.8 mrad instead of +5.3, no lead
    // error, 0.1 µm/h drift on x; no structure the model lacks.
    let mut truth = StageModel::paper_default().unwrap();
    truth.set_param("squareness.angle_urad", -5800.0).unwrap();
    truth.set_param("x_lead.ppm", 0.0).unwrap();
    truth.set_param("y_lead.ppm", 0.0).unwrap();
    truth.set_param("extra_drift.rate_um_per_h", 0.1).unwrap();
    let plan = small_plan(30);
    let truth = truth_model(&truth, None, &plan, 5).unwrap();
    let log = simulate_log(&truth, &plan, 5).unwrap();
    let log = parse_bytes(&log.to_bytes().unwrap()).unwrap();
    let base = StageModel::paper_default().unwrap();
    let d = diagnose(&log, &base, &DiagnoseOptions::default()).unwrap();
    assert!(d.findings.is_empty(), "{}", d.to_text());
    let p = |name: &str| {
        d.parameters
            .iter()
            .find(|p| format!("{}.{}", p.term, p.parameter) == name)
            .unwrap_or_else(|| panic!("{name} not identified: {}", d.to_text()))
    };
    let sq = p("squareness.angle_urad");
    assert!(sq.significant);
    assert!(
        (sq.fitted_value + 5800.0).abs() < 5.0 * sq.std_error + 5.0,
        "{sq:?}"
    );
    assert!(
        sq.sentence.contains("the model says +5.3000"),
        "{}",
        sq.sentence
    );
    assert!(sq.sentence.contains("mrad"), "{}", sq.sentence);
    // The default's yaw slope acts through its Abbe arm as a scale: the
    // fitted x scale is the combination, and the yaw slope is named as
    // not separable.
    assert!(p("x_lead.ppm").significant);
    assert!(d
        .unidentifiable
        .iter()
        .any(|u| u.name == "x_yaw.slope_urad_per_mm"
            && u.combination.iter().any(|(n, _)| n == "x_lead.ppm")));
    let json = d.to_json();
    assert!(json["parameters"].as_array().is_some_and(|a| !a.is_empty()));
    assert!(json["findings"].as_array().is_some_and(|a| a.is_empty()));
    assert!(d.to_text().contains("parameter corrections"));
}

#[test]
fn tables_have_a_knot_per_target_on_sparse_axes_and_free_what_the_base_lacks() {
    use super::search::{table_free_knots, table_knots, DENSE_TABLE_KNOTS};
    let base = StageModel::paper_default().unwrap();
    let targets: Vec<f64> = [1000.0, 3500.0, 5000.0, 9000.0].to_vec();
    let back: Vec<f64> = targets.iter().rev().copied().collect();
    let passes: Vec<(u32, Vec<f64>, &str)> = (1..=5u32)
        .flat_map(|c| [(c, targets.clone(), "fwd"), (c, back.clone(), "bwd")])
        .collect();
    let d = prepare(&hand_log(&passes), &base, 4).unwrap();
    assert_eq!(table_knots(&d, Axis::X), Some(targets.clone()));
    // y never moves: no table along it.
    assert_eq!(table_knots(&d, Axis::Y), None);
    // Non-linearity: zero at both ends; lost motion: zero at the first
    // knot when the model has a play for the axis, free everywhere without.
    assert_eq!(table_free_knots(4, false, &base, Axis::X), 1..3);
    assert_eq!(table_free_knots(4, true, &base, Axis::X), 1..4);
    let mut no_play = base.clone();
    no_play.remove_term("x_backlash");
    assert_eq!(table_free_knots(4, true, &no_play, Axis::X), 0..4);
    // A dense scan: evenly spaced knots over its span.
    let dense: Vec<f64> = (0..=40).map(|k| 10.0 * f64::from(k)).collect();
    let d = prepare(
        &hand_log(&[(1, dense.clone(), "fwd"), (2, dense, "fwd")]),
        &base,
        4,
    )
    .unwrap();
    let k = table_knots(&d, Axis::X).unwrap();
    assert_eq!(k.len(), DENSE_TABLE_KNOTS);
    assert!(
        (k[0] - 0.0).abs() < 1e-9 && (k[k.len() - 1] - 400.0).abs() < 1e-9,
        "{k:?}"
    );
}

/// An ISO 230-2-like test of one leadscrew axis (5–11 targets, 5 cycles,
/// both approaches): a lead error, a play, Gaussian noise, and, when
/// `bow_sigmas > 0`, a bow of that many σ between the targets (a
/// non-linearity the model lacks).
fn iso_log(seed: u64, bow_sigmas: f64) -> crate::charact::log::MeasurementLog {
    use rand::{Rng, SeedableRng};
    use rand_distr::{Distribution, Normal};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed ^ 0x150_2302);
    let n: usize = rng.gen_range(5..=11);
    let spacing = rng.gen_range(2_000.0..15_000.0);
    let targets: Vec<f64> = (0..n)
        .map(|k| {
            let jitter = if k == 0 || k == n - 1 {
                0.0
            } else {
                rng.gen_range(-0.2..0.2) * spacing
            };
            (k as f64 * spacing + jitter).round()
        })
        .collect();
    let sigma = rng.gen_range(0.2..3.0);
    let ppm = rng.gen_range(-300.0..300.0);
    let play = rng.gen_range(0.3..5.0);
    let noise = Normal::new(0.0, sigma).unwrap();
    let span = targets[n - 1];
    let mut s = String::from(
        "t_s,segment,cycle,x_target_um,y_target_um,x_cmd_um,y_cmd_um,x_meas_um,y_meas_um,approach\n",
    );
    let mut t = 0.0;
    for cycle in 1..=5u32 {
        for dir in [1.0, -1.0] {
            let order: Vec<f64> = if dir > 0.0 {
                targets.clone()
            } else {
                targets.iter().rev().copied().collect()
            };
            for x in order {
                let u = x / span;
                let dev = ppm * 1e-6 * x - dir * play / 2.0
                    + bow_sigmas * sigma * 4.0 * u * (1.0 - u)
                    + noise.sample(&mut rng);
                let ap = if dir > 0.0 { "fwd" } else { "bwd" };
                s += &format!("{t},scan_x,{cycle},{x},0,{x},0,{},0,{ap}\n", x + dev);
                t += 10.0;
            }
        }
    }
    parse_bytes(s.as_bytes()).unwrap()
}

/// The model a user writes for such an axis: a play and a lead error.
const AXIS_MODEL: &str = r#"
format_version = 1
[[term]]
kind = "backlash"
name = "x_backlash"
axis = "x"
backlash_um = 2.0

[[term]]
kind = "lead_error"
name = "x_lead"
axis = "x"
ppm = 0.0
"#;

/// The held-out χ² z of every table family of axis x, on the base the
/// analysis selects.
fn table_chi_zs(log: &crate::charact::log::MeasurementLog) -> Vec<f64> {
    use super::family::Family;
    use super::fit::{fold_base, keep_heldout, select_base, unjudged};
    use super::search::base_columns;
    let model = StageModel::from_toml(AXIS_MODEL).unwrap();
    let d = prepare(log, &model, 4).unwrap();
    let (names, cols) = base_columns(&d, &model, &[ALL_KINDS.into()]);
    let keep = select_base(&d, &names, &cols);
    let base: Vec<Vec<f64>> = keep.iter().map(|&j| cols[j].clone()).collect();
    let mut before = unjudged(&d);
    for f in 0..d.nfolds {
        let train: Vec<bool> = d.fold.iter().map(|&k| k != f).collect();
        let fb = fold_base(&d, &base, train);
        keep_heldout(&d, &mut before, &fb.resid, &fb.train);
    }
    [
        Family::Table {
            axis: Axis::X,
            lost_motion: true,
        },
        Family::Table {
            axis: Axis::X,
            lost_motion: false,
        },
        Family::Tables { axis: Axis::X },
    ]
    .into_iter()
    .map(|f| super::tables::heldout_chi_z(&d, &base, &before, f).unwrap())
    .collect()
}

#[test]
fn the_heldout_chi2_of_a_table_holds_its_false_acceptance_rate() {
    use super::tables::TABLE_CHI_Z;
    // Clean axes: the base (play, scale) is right, the rest is noise. The
    // z must be N(0, 1)-like: about 5 % above 1.645, about 0.1 % above
    // the acceptance threshold.
    let (mut n, mut above_5pct, mut accepted) = (0, 0, 0);
    for seed in 0..200u64 {
        for z in table_chi_zs(&iso_log(seed, 0.0)) {
            n += 1;
            above_5pct += usize::from(z >= 1.645);
            accepted += usize::from(z >= TABLE_CHI_Z);
        }
    }
    eprintln!("clean: {above_5pct}/{n} at z ≥ 1.645, {accepted}/{n} at z ≥ {TABLE_CHI_Z}");
    // Binomial bounds: 5 % of 600 is 30 ± 5.3; 0.1 % is 0.6.
    assert!(above_5pct <= 45, "{above_5pct}/{n} above the 5 % point");
    assert!(accepted <= 3, "{accepted}/{n} accepted on clean axes");
    // A bow of 3 σ between the targets (each target's mean has σ/√5
    // of noise): the non-linearity and the joint tables see it.
    let mut seen = 0;
    let cases = 100u64;
    for seed in 0..cases {
        let z = table_chi_zs(&iso_log(1000 + seed, 3.0));
        seen += usize::from(z[1] >= TABLE_CHI_Z && z[2] >= TABLE_CHI_Z);
    }
    eprintln!("3 σ bow: {seen}/{cases} accepted");
    assert!(seen * 100 >= 90 * cases as usize, "{seen}/{cases}");
}

/// An accepted finding with `spec`'s columns on `d` (the verdict is not
/// looked at by the re-judging).
fn accepted_as(family: Family, spec: Spec, d: &data::Data, model: &StageModel) -> Accepted {
    Accepted {
        family,
        cols: columns(&spec, d, model),
        spec,
        verdict: Verdict {
            family,
            after: Vec::new(),
            reduction: 0.0,
            z: 0.0,
            gain_pct: 0.0,
            rms_before: 0.0,
            rms_after: 0.0,
            table_z: f64::NEG_INFINITY,
        },
    }
}

/// The log's time span, s.
fn time_span_s(d: &data::Data) -> f64 {
    let (lo, hi) = d
        .states
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), s| {
            (a.min(s.time_s), b.max(s.time_s))
        });
    hi - lo
}

#[test]
fn a_finding_the_others_carry_is_dropped_when_rejudged() {
    use crate::analysis::generate::draw_effect_sized;
    let model = StageModel::paper_default().unwrap();
    let plan = SimPlan {
        cycles: 3,
        ..small_plan(0)
    };
    let drawn = |kind: FindingKind, comp: Axis| {
        (0u64..)
            .map(|s| draw_effect_sized(s, kind, 0.8, &plan).unwrap())
            .find(|e| e.component == comp)
            .unwrap()
    };
    let opts = DiagnoseOptions::default();
    let kinds = |acc: &[Accepted]| acc.iter().map(|a| a.family).collect::<Vec<_>>();
    // A y drift alone. History: a time-periodic y term (at a third of the
    // log's span, which cannot carry a drift) was accepted before the
    // drift; with the drift in the model it predicts nothing.
    let truth = truth_model(
        &model,
        Some(&drawn(FindingKind::TimeDrift, Axis::Y)),
        &plan,
        11,
    )
    .unwrap();
    let log = simulate_log(&truth, &plan, 11).unwrap();
    let d = prepare(&parse_bytes(&log.to_bytes().unwrap()).unwrap(), &model, 4).unwrap();
    let tp = Family::TimePeriodic { comp: Axis::Y };
    let drift = Family::Drift {
        comp: Axis::Y,
        quadratic: false,
    };
    let tp_spec = Spec::TimePeriodic {
        comp: Axis::Y,
        period_s: time_span_s(&d) / 3.0,
    };
    let drift_spec = Spec::Drift {
        comp: Axis::Y,
        quadratic: false,
    };
    let mut acc = vec![
        accepted_as(tp, tp_spec, &d, &model),
        accepted_as(drift, drift_spec, &d, &model),
    ];
    rejudge(&d, &[], &mut acc, &model, &opts);
    assert_eq!(kinds(&acc), [drift]);

    // Both real (an x drift in the stage, an x time-periodic error): both
    // stay.
    let mut stage = model.clone();
    stage.set_param("extra_drift.rate_um_per_h", 1.5).unwrap();
    let effect = drawn(FindingKind::TimePeriodic, Axis::X);
    let truth = truth_model(&stage, Some(&effect), &plan, 12).unwrap();
    let log = simulate_log(&truth, &plan, 12).unwrap();
    let d = prepare(&parse_bytes(&log.to_bytes().unwrap()).unwrap(), &model, 4).unwrap();
    let tp = Family::TimePeriodic { comp: Axis::X };
    let drift = Family::Drift {
        comp: Axis::X,
        quadratic: false,
    };
    let tp_spec = Spec::TimePeriodic {
        comp: Axis::X,
        period_s: effect.params["period_s"],
    };
    let drift_spec = Spec::Drift {
        comp: Axis::X,
        quadratic: false,
    };
    let mut acc = vec![
        accepted_as(tp, tp_spec, &d, &model),
        accepted_as(drift, drift_spec, &d, &model),
    ];
    rejudge(&d, &[], &mut acc, &model, &opts);
    assert_eq!(kinds(&acc), [tp, drift]);
}

#[test]
fn positions_of_one_target_are_merged_only_on_a_sparse_test() {
    use super::data::{sampling_spacing_um, targets_of};
    // Forward targets 10 mm apart, backward ones 0.2 mm above: five
    // targets, sampled every 10 mm.
    let mut pos: Vec<f64> = (0..5)
        .flat_map(|k| {
            [
                15_000.0 + 10_000.0 * k as f64,
                15_200.0 + 10_000.0 * k as f64,
            ]
        })
        .collect();
    pos.sort_by(f64::total_cmp);
    assert_eq!(sampling_spacing_um(&pos), Some(9_800.0));
    let t = targets_of(&pos);
    assert_eq!(t.bounds.len(), 5);
    assert!((t.widest_um() - 200.0).abs() < 1e-9);
    assert_eq!(t.index_of(15_200.0), Some(0));
    // An even grid (with a hole): every position is its own target.
    let grid: Vec<f64> = (0..40)
        .filter(|&k| k != 17)
        .map(|k| 11.25 * k as f64)
        .collect();
    assert_eq!(sampling_spacing_um(&grid), Some(11.25));
    assert_eq!(targets_of(&grid).bounds.len(), grid.len());
}

/// A sweep log's anchor rows (`anchor_*` segments, their approach not in
/// the log) are left out: the same log with anchor rows inserted between
/// its records, measured 50 µm off, gives the same diagnosis.
#[test]
fn sweep_anchor_rows_are_left_out() {
    let base = StageModel::paper_default().unwrap();
    let plan = small_plan(0);
    let truth = truth_model(&base, None, &plan, 7).unwrap();
    let log = parse_bytes(&simulate_log(&truth, &plan, 7).unwrap().to_bytes().unwrap()).unwrap();
    let mut with = log.clone();
    let mut records = Vec::new();
    for (i, r) in log.records.iter().enumerate() {
        records.push(r.clone());
        if i % 40 == 39 {
            let mut a = r.clone();
            a.segment = crate::charact::scan::SEGMENTS_SWEEP_ANCHOR[i / 40 % 4].to_owned();
            a.x_meas_um += 50.0;
            records.push(a);
        }
    }
    with.records = records;
    assert!(with.records.len() > log.records.len());
    let opts = DiagnoseOptions::default();
    let a = diagnose(&log, &base, &opts).unwrap();
    let b = diagnose(&with, &base, &opts).unwrap();
    assert_eq!(a.to_text(), b.to_text());
}

/// A time-periodic error in a two-cycle log over the rig's ranges
/// (`hil-sim/tests/it/hidden_rig.rs`: 2400 × 2000 µm; here the generator's
/// 20 µm steps and 40 random points per cycle), with a period of a fifth to
/// a third of the log. Whole-cycle folds name
/// it here or, when they do not, the replicates' scatter (visits a cycle
/// apart disagree, neighbours a step apart do not) flags it; folds
/// interleaved in time name it with its parameters in every case. The
/// same plan without the effect keeps whole-cycle folds and finds nothing.
/// (The rig's own case, which whole-cycle folds miss, is
/// `tests/it/diagnose_rig_logs.rs`.)
#[test]
fn an_error_that_changes_between_visits_is_judged_on_interleaved_folds() {
    use crate::analysis::generate::draw_effect_sized;
    let model = StageModel::paper_default().unwrap();
    let plan = SimPlan {
        x_range_um: [500.0, 2900.0],
        x_scan_y_um: 1500.0,
        y_range_um: [500.0, 2500.0],
        y_scan_x_um: 1700.0,
        cycles: 2,
        dwell_s: 3.3,
        ..SimPlan::default()
    };
    let span = plan.duration_s();
    let opts = DiagnoseOptions::default();
    for comp in Axis::ALL {
        let effect = (100u64..)
            .map(|s| draw_effect_sized(s, FindingKind::TimePeriodic, 0.8, &plan).unwrap())
            .find(|e| {
                let p = e.params["period_s"];
                e.component == comp && (0.2 * span..0.34 * span).contains(&p)
            })
            .unwrap();
        let truth = truth_model(&model, Some(&effect), &plan, 21).unwrap();
        let log =
            parse_bytes(&simulate_log(&truth, &plan, 21).unwrap().to_bytes().unwrap()).unwrap();
        let named = |d: &Diagnosis| {
            d.findings
                .iter()
                .find(|f| f.kind == FindingKind::TimePeriodic && f.component == comp)
                .cloned()
        };
        let first = diagnose_with(&log, &model, &opts, FoldScheme::Cycles).unwrap();
        let c = first
            .noise
            .components
            .iter()
            .find(|c| c.component == comp)
            .unwrap();
        assert!(
            named(&first).is_some() || c.changes_between_visits,
            "{comp}: neither named nor flagged: {}",
            first.to_text()
        );
        let (p, a) = (effect.params["period_s"], effect.params["amplitude_um"]);
        for d in [
            diagnose(&log, &model, &opts).unwrap(),
            diagnose_with(&log, &model, &opts, FoldScheme::InterleavedInTime).unwrap(),
        ] {
            let f = named(&d).unwrap_or_else(|| panic!("{comp}: {}", d.to_text()));
            assert!(
                (f.params["period_s"] - p).abs() <= 0.05 * p,
                "{comp}: {f:?} vs {p}"
            );
            assert!(
                (f.params["amplitude_um"] - a).abs() <= 0.25 * a,
                "{comp}: {f:?} vs {a}"
            );
        }
    }
    let truth = truth_model(&model, None, &plan, 22).unwrap();
    let log = parse_bytes(&simulate_log(&truth, &plan, 22).unwrap().to_bytes().unwrap()).unwrap();
    let d = diagnose(&log, &model, &opts).unwrap();
    assert!(d.folds_interleaved.is_none(), "{}", d.to_text());
    assert!(
        d.noise.components.iter().all(|c| !c.changes_between_visits),
        "{}",
        d.to_text()
    );
    assert!(d.findings.is_empty(), "{}", d.to_text());
}

/// A verdict for a finding built by hand (`withdraw::settle` only carries
/// it into the finding).
fn verdict_for(family: Family) -> Verdict {
    Verdict {
        family,
        after: Vec::new(),
        reduction: 1.0,
        z: 9.0,
        gain_pct: 40.0,
        rms_before: 0.2,
        rms_after: 0.12,
        table_z: f64::NEG_INFINITY,
    }
}

#[test]
fn a_feature_the_log_does_not_place_is_withdrawn_and_the_report_says_why() {
    use crate::analysis::generate::draw_effect_sized;
    let model = StageModel::paper_default().unwrap();
    let plan = SimPlan {
        cycles: 3,
        ..small_plan(0)
    };
    // A real 0.8 µm feature of x along x, inside the travel.
    let effect = (0u64..)
        .map(|s| draw_effect_sized(s, FindingKind::Localized, 0.8, &plan).unwrap())
        .find(|e| e.axis == Axis::X && e.component == Axis::X)
        .unwrap();
    let truth = truth_model(&model, Some(&effect), &plan, 21).unwrap();
    let log = parse_bytes(&simulate_log(&truth, &plan, 21).unwrap().to_bytes().unwrap()).unwrap();
    let d = prepare(&log, &model, 4).unwrap();
    let fam = Family::Localized {
        axis: Axis::X,
        comp: Axis::X,
    };
    let at = |position_um: f64, width_um: f64| {
        (
            Spec::Localized {
                axis: Axis::X,
                comp: Axis::X,
                position_um,
                width_um,
            },
            verdict_for(fam),
        )
    };
    let (p, w) = (effect.params["position_um"], effect.params["width_um"]);
    let [lo, _] = plan.x_range_um;
    let accepted = vec![
        at(p, w),
        // Centred outside the travel: seen by its tail alone.
        at(lo - 3.0 * w, w),
        // Narrower than the sampling, between two sampled positions (the
        // plan steps 20 µm from 250 µm): its column is zero, nothing
        // places it.
        at(if p < 750.0 { 1010.0 } else { 510.0 }, 0.5),
    ];
    let s = withdraw::settle(&d, &model, &[], accepted).unwrap();
    assert_eq!(s.findings.len(), 1, "{:?}", s.findings);
    let f = &s.findings[0];
    assert!((f.params["position_um"] - p).abs() < 1e-9);
    for k in ["position_um", "width_um", "amplitude_um"] {
        let e = f.uncertainty[k];
        assert!(e.is_finite() && e > 0.0 && e < 0.2 * w, "{k} ± {e}");
    }
    let reasons: Vec<&str> = s.withdrawn.iter().map(|w| w.reason.as_str()).collect();
    assert_eq!(reasons.len(), 2, "{reasons:?}");
    assert!(
        reasons
            .iter()
            .any(|r| r.contains("lies outside the measured x travel")),
        "{reasons:?}"
    );
    assert!(
        reasons.iter().any(|r| r.contains("standard error")),
        "{reasons:?}"
    );
    assert!(s
        .withdrawn
        .iter()
        .all(|w| w.finding.term.is_empty() && !w.finding.in_extended_model));
    // The extended model carries the kept feature only (beside the
    // model's own localized terms).
    let localized = |m: &StageModel| {
        m.terms()
            .iter()
            .filter(|t| t.kind() == crate::model::terms::discovered::LOCALIZED_KIND)
            .count()
    };
    assert_eq!(localized(&s.fitted), localized(&model) + 1);

    // The report: a section of its own, each reason, no finding block and
    // no gain for them; the JSON lists them.
    let mut diag = diagnose(&log, &model, &DiagnoseOptions::default()).unwrap();
    diag.withdrawn = s.withdrawn.clone();
    let text = diag.to_text();
    let section = text
        .split("\nwithdrawn (not determined by this log")
        .nth(1)
        .expect("a withdrawn section")
        .split("\n\n")
        .next()
        .unwrap_or("");
    for r in &reasons {
        assert!(section.contains(r), "{section}");
    }
    assert!(!section.contains("finding") && !section.contains("% better"));
    assert_eq!(
        text.matches("\nfinding ").count(),
        diag.findings.len(),
        "{text}"
    );
    let json = diag.to_json();
    assert_eq!(json["withdrawn"].as_array().map(|a| a.len()), Some(2));
    assert!(json["withdrawn"][0]["reason"].is_string());
}
