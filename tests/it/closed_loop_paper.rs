//! The closed loop and the open-loop bound on the paper-faithful stage
//! (`config/stage-model-paper.toml`), at model level: the paper's lookup
//! tables built from a simulated paper characterization (5 µm steps, 9.5 h,
//! as `micropos paper`), then the square (poses every 500 µm) and Table II's
//! targets visited three times each the way microposd drives a
//! `closed_loop` move: a planned first move, then corrections from camera
//! frames (observed position + 10 nm noise), every correction committed to
//! the motion history as a raw move.
//!
//! Why at model level: the full rig (`hil-sim run --model …`) needs the
//! 9.5 h characterization to build the same tables (minutes of release
//! build per run); the loop's behaviour depends only on the stage physics
//! and the planner, which are the same code here.
//!
//! Run with `--nocapture` to see the figures.

use micropos::charact::log::Record;
use micropos::charact::scan::{random_targets, square_poses, CharacterizationPlan, SEGMENT_MOVES};
use micropos::comp::closed_loop::{
    Action, ClosedLoop, ClosedLoopConfig, FailReason, FrameMeasurement,
};
use micropos::comp::table::{CompTable, LookupCompensator, TableBuildOptions};
use micropos::comp::{
    compensation_template_for, Compensator, ModelBuildOptions, ModelCompensator, MotionHistory,
    PlanOptions,
};
use micropos::metrology::{pose_stats, summarize_poses, Xy};
use micropos::model::{MotionState, StageModel, StageSimulator, XyUm};
use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};

/// Time per move, s (the paper's 2.08 s per characterization point).
const MOVE_S: f64 = 2.08;
/// Camera noise, µm (the paper's reproducibility).
const CAMERA_SIGMA_UM: f64 = 0.01;

fn faithful() -> StageModel {
    let text = std::fs::read_to_string("config/stage-model-paper.toml").unwrap();
    StageModel::from_toml(&text).unwrap()
}

/// The paper's characterization on `model` (as `analysis::paper`), its
/// lookup tables, and the time of its last point.
fn paper_table(model: &StageModel, seed: u64) -> (LookupCompensator, f64) {
    let (records, t) = characterize(model, CharacterizationPlan::paper(), 0, seed);
    let (table, _) = CompTable::from_records(&records, &TableBuildOptions::default()).unwrap();
    (LookupCompensator::new(table).unwrap(), t)
}

/// The log of `plan` on `model` followed, per cycle, by `moves` points of
/// the moves segment (seeded uniform over the scanned area, each reached
/// directly from the one before), and the time of its last point.
fn characterize(
    model: &StageModel,
    plan: CharacterizationPlan,
    moves: usize,
    seed: u64,
) -> (Vec<Record>, f64) {
    use rand::Rng;
    let mut points = plan.points().unwrap();
    let mut pick = rand_chacha::ChaCha8Rng::seed_from_u64(seed ^ 0x30fe);
    for cycle in 1..=3 {
        for _ in 0..moves {
            let x = 9500.0 * pick.gen::<f64>();
            let y = 4200.0 * pick.gen::<f64>();
            let mut p = points[0].clone();
            p.segment = SEGMENT_MOVES.to_owned();
            p.cycle = cycle;
            p.target = XyUm { x_um: x, y_um: y };
            p.logged = true;
            points.push(p);
        }
    }
    let first = points[0].target;
    let mut start = MotionState::at_rest(first.x_um, first.y_um);
    start.temp_c = model.environment().temperature_at(0.0);
    let mut sim = StageSimulator::new(model.clone(), start, seed).unwrap();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed ^ 0x5eed);
    let mut records = Vec::new();
    let mut t = 0.0;
    for p in &points {
        t += MOVE_S;
        let step = sim
            .move_to(p.target.x_um, p.target.y_um, t, p.cycle)
            .unwrap();
        if !p.logged {
            continue;
        }
        let nx: f64 = StandardNormal.sample(&mut rng);
        let ny: f64 = StandardNormal.sample(&mut rng);
        records.push(Record {
            t_s: t,
            segment: p.segment.clone(),
            cycle: p.cycle,
            x_target_um: p.target.x_um,
            y_target_um: p.target.y_um,
            x_cmd_um: p.target.x_um,
            y_cmd_um: p.target.y_um,
            x_meas_um: step.observed_um.x_um + CAMERA_SIGMA_UM * nx,
            y_meas_um: step.observed_um.y_um + CAMERA_SIGMA_UM * ny,
            temp_c: Some(step.state.temp_c),
            theta_urad: None,
            extra: Vec::new(),
        });
    }
    (records, t)
}

/// What a validation measured.
#[derive(Debug)]
struct Outcome {
    /// ISO 9283 AP max over the poses, µm (camera view).
    ap_max_um: f64,
    /// Loops that failed: (pose index, why).
    failures: Vec<(usize, FailReason)>,
}

/// `targets` visited `cycles` times in order from rest at the first one,
/// starting at `t0`. `closed`: the loop's configuration (and `first` the
/// planner options of its first move); `None`: open loop (one planned
/// move per visit).
fn validate(
    model: &StageModel,
    comp: &dyn Compensator,
    targets: &[XyUm],
    t0: f64,
    seed: u64,
    first: &PlanOptions,
    closed: Option<ClosedLoopConfig>,
) -> Outcome {
    let mut start = MotionState::at_rest(targets[0].x_um, targets[0].y_um);
    start.time_s = t0;
    start.temp_c = model.environment().temperature_at(t0);
    let mut sim = StageSimulator::new(model.clone(), start, seed).unwrap();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed ^ 0xca3e);
    let min_move = model.stochastic().min_incremental_motion_um;
    let mut hist = MotionHistory::new(*sim.state(), min_move).unwrap();
    let mut t = t0;
    let mut seq = 0;
    let mut seen: Vec<Vec<Xy>> = vec![Vec::new(); targets.len()];
    let mut failures = Vec::new();
    for cycle in 0..3 {
        for (i, target) in targets.iter().enumerate() {
            let plan = comp.command_for(*target, &hist, first).unwrap();
            let mut step = None;
            for w in &plan.waypoints {
                t += MOVE_S;
                step = Some(sim.move_to(w.x_um, w.y_um, t, cycle).unwrap());
            }
            hist.commit(&plan, t, model.environment().temperature_at(t))
                .unwrap();
            let mut step = step.unwrap();
            if let Some(cfg) = closed {
                let mut cl = ClosedLoop::new(*target, plan.cmd, plan.arrival, cfg).unwrap();
                loop {
                    cl.settled(t);
                    seq += 1;
                    let nx: f64 = StandardNormal.sample(&mut rng);
                    let ny: f64 = StandardNormal.sample(&mut rng);
                    let m = FrameMeasurement {
                        position: XyUm {
                            x_um: step.observed_um.x_um + CAMERA_SIGMA_UM * nx,
                            y_um: step.observed_um.y_um + CAMERA_SIGMA_UM * ny,
                        },
                        timestamp_s: t + 0.1,
                        quality: 100.0,
                        frame_seq: seq,
                    };
                    match cl.on_frame(&m) {
                        Action::Move { waypoints } => {
                            for w in waypoints {
                                t += MOVE_S;
                                step = sim.move_to(w.x_um, w.y_um, t, cycle).unwrap();
                                // The daemon commits a correction as a raw move.
                                hist.commit_move(w, w, t, model.environment().temperature_at(t))
                                    .unwrap();
                            }
                        }
                        Action::AwaitFrame { .. } => unreachable!("every frame is fresh"),
                        Action::Done { .. } => break,
                        Action::Failed { reason, .. } => {
                            failures.push((i, reason));
                            break;
                        }
                    }
                }
            }
            seen[i].push(Xy::new(step.observed_um.x_um, step.observed_um.y_um));
        }
    }
    let stats: Vec<_> = targets
        .iter()
        .zip(&seen)
        .map(|(t, v)| pose_stats(Xy::new(t.x_um, t.y_um), v).unwrap())
        .collect();
    Outcome {
        ap_max_um: summarize_poses(&stats).unwrap().ap_max_um,
        failures,
    }
}

/// The main job's validation origin: the paper's poses + 100 µm on both
/// axes (`hil-sim run`'s `validate_origin_um`), so the poses are the rig's.
const ORIGIN_UM: f64 = 100.0;

fn shifted(p: XyUm) -> XyUm {
    XyUm {
        x_um: p.x_um + ORIGIN_UM,
        y_um: p.y_um + ORIGIN_UM,
    }
}

fn square() -> Vec<XyUm> {
    square_poses(500.0)
        .unwrap()
        .into_iter()
        .map(|p| shifted(p.target))
        .collect()
}

fn random() -> Vec<XyUm> {
    random_targets().into_iter().map(shifted).collect()
}

/// The daemon's closed-loop configuration (`[closed_loop]` defaults:
/// 5 corrections, tolerance 0.1 µm, every correction re-approached).
fn daemon_loop() -> ClosedLoopConfig {
    ClosedLoopConfig {
        max_corrections: 5,
        ..ClosedLoopConfig::default()
    }
}

#[test]
fn closed_loop_converges_on_every_square_pose_of_the_faithful_stage() {
    let model = faithful();
    let (table, t_end) = paper_table(&model, 1);
    let cfg = daemon_loop();
    let direct = PlanOptions::default();
    // The first move planned as before: a direct long move. Its lost motion
    // (≈ 2 µm after 500 µm) is released by the first correction's 20 µm
    // approach; where the table's other errors cancel part of it, the
    // jump is more than twice the first residual and the loop stops as
    // diverging (the faithful rig: the backward-x poses, side CD and D).
    let before = validate(&model, &table, &square(), t_end, 11, &direct, Some(cfg));
    // As microposd plans it: the first arrival ends with the loop's own
    // approach (`ClosedLoopConfig::plan_options`).
    let after = validate(
        &model,
        &table,
        &square(),
        t_end,
        11,
        &cfg.plan_options(direct),
        Some(cfg),
    );
    println!(
        "square, closed loop: direct first move AP {:.3} µm, {} failed loops {:?}; loop's approach AP {:.3} µm, {} failed",
        before.ap_max_um,
        before.failures.len(),
        before.failures,
        after.ap_max_um,
        after.failures.len()
    );
    assert!(after.failures.is_empty(), "{after:?}");
    assert!(after.ap_max_um <= 0.1, "{after:?}");
}

#[test]
fn random_targets_fail_only_on_the_rough_stretch() {
    let model = faithful();
    let (table, t_end) = paper_table(&model, 2);
    let cfg = daemon_loop();
    let opts = cfg.plan_options(PlanOptions::default());
    let targets = random();
    let closed = validate(&model, &table, &targets, t_end, 12, &opts, Some(cfg));
    println!(
        "random targets, closed loop: AP {:.3} µm, failed loops {:?}",
        closed.ap_max_um, closed.failures
    );
    // Only target 9 (4003, 1490) µm fails, if any: it sits on the y rough
    // stretch (y = 1500 µm, σ 1.0 µm), where every correction draws a new
    // settling error of ≈ 1 µm, so a 0.1 µm tolerance is met only by luck.
    let rough = targets
        .iter()
        .position(|t| (t.y_um - 1500.0).abs() < 30.0)
        .unwrap();
    assert!(
        closed.failures.iter().all(|(i, _)| *i == rough),
        "{closed:?}"
    );
}

/// Median, min, max.
fn spread(v: &mut [f64]) -> (f64, f64, f64) {
    v.sort_by(f64::total_cmp);
    (v[v.len() / 2], v[0], v[v.len() - 1])
}

#[test]
fn open_loop_bound_is_below_1_um_only_with_the_move_length_lost_motion() {
    // Compensated by the very model the stage runs (every systematic error
    // known, only the settling draws unknown), the AP left is the stage's
    // repeatability seen through three visits: the bound of any open-loop
    // compensation. The same model without its `step_size` terms is the
    // best a compensator blind to the move-length lost motion can do.
    let model = faithful();
    let mut blind = model.clone();
    blind.remove_term("x_step_size");
    blind.remove_term("y_step_size");
    let open = PlanOptions::default();
    let (mut bound_sq, mut bound_rn, mut blind_sq, mut blind_rn) = (vec![], vec![], vec![], vec![]);
    for seed in 1..=5u64 {
        // The validation starts after the paper's 9.5 h characterization.
        let t0 = 34_200.0;
        let truth = ModelCompensator::new(model.clone());
        let no_ss = ModelCompensator::new(blind.clone());
        bound_sq.push(validate(&model, &truth, &square(), t0, seed, &open, None).ap_max_um);
        bound_rn.push(validate(&model, &truth, &random(), t0, seed, &open, None).ap_max_um);
        blind_sq.push(validate(&model, &no_ss, &square(), t0, seed, &open, None).ap_max_um);
        blind_rn.push(validate(&model, &no_ss, &random(), t0, seed, &open, None).ap_max_um);
    }
    let f = |v: &mut Vec<f64>| {
        let (m, lo, hi) = spread(v);
        format!("{m:.3} [{lo:.3}, {hi:.3}]")
    };
    println!(
        "open loop, seeds 1-5, AP max µm median [min, max]: true model square {} random {}; without step_size square {} random {}",
        f(&mut bound_sq),
        f(&mut bound_rn),
        f(&mut blind_sq),
        f(&mut blind_rn)
    );
    assert!(spread(&mut bound_sq).0 < 0.3, "{bound_sq:?}");
    assert!(spread(&mut bound_rn).0 < 1.0, "{bound_rn:?}");
    assert!(spread(&mut blind_rn).0 > 1.0, "{blind_rn:?}");
}

#[test]
fn a_model_table_fitted_with_moves_of_varied_length_corrects_the_lost_motion() {
    // The model table's characterization (50 µm scans) plus 40 moves of
    // varied length per cycle; the template keeps the `step_size` terms
    // (their λ from the structure, as the diagnosis gives it), so the fit
    // separates the lost motion of a long move from the play, and the
    // compensator predicts it for each planned move.
    let model = faithful();
    let open = PlanOptions::default();
    let (mut with_sq, mut with_rn, mut without_sq, mut without_rn) =
        (vec![], vec![], vec![], vec![]);
    for seed in 1..=5u64 {
        let (records, t_end) = characterize(&model, CharacterizationPlan::short(), 40, seed);
        let fit = |moves: bool| {
            let template = compensation_template_for(&model, moves).unwrap();
            let (comp, _) =
                ModelCompensator::fit_records(template, &records, &ModelBuildOptions::default())
                    .unwrap();
            comp
        };
        let (with, without) = (fit(true), fit(false));
        assert!(with.model().terms().iter().any(|t| t.kind() == "step_size"));
        assert!(without
            .model()
            .terms()
            .iter()
            .all(|t| t.kind() != "step_size"));
        with_sq.push(validate(&model, &with, &square(), t_end, seed, &open, None).ap_max_um);
        with_rn.push(validate(&model, &with, &random(), t_end, seed, &open, None).ap_max_um);
        without_sq.push(validate(&model, &without, &square(), t_end, seed, &open, None).ap_max_um);
        without_rn.push(validate(&model, &without, &random(), t_end, seed, &open, None).ap_max_um);
    }
    let f = |v: &mut Vec<f64>| {
        let (m, lo, hi) = spread(v);
        format!("{m:.3} [{lo:.3}, {hi:.3}]")
    };
    println!(
        "model table, seeds 1-5, AP max µm median [min, max]: with step_size square {} random {}; without square {} random {}",
        f(&mut with_sq),
        f(&mut with_rn),
        f(&mut without_sq),
        f(&mut without_rn)
    );
    assert!(spread(&mut with_rn).0 < spread(&mut without_rn).0 / 3.0);
    assert!(spread(&mut with_sq).0 < spread(&mut without_sq).0);
}
