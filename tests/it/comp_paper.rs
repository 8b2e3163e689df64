//! Compensation on the default stage model (seeded `StageSimulator`), the
//! paper's way: characterize (scan_x, scan_y), build tables / fit the model,
//! then run the square and the ten random targets raw, table-compensated,
//! model-compensated (from a 10× shorter characterization) and closed-loop,
//! and compute ISO 9283 AP (max over poses) and RP.
//!
//! `cargo test --test it comp_paper:: -- --nocapture` prints the table.

use micropos::charact::log::Record;
use micropos::charact::scan::{random_targets, square_poses, CharacterizationPlan};
use micropos::comp::{
    compensation_template, Action, ClosedLoop, ClosedLoopConfig, CompFile, CompTable, Compensator,
    FrameMeasurement, ModelBuildOptions, ModelCompensator, MotionHistory, PlanOptions, SourceInfo,
    TableBuildOptions,
};
use micropos::metrology::{pose_stats, summarize_poses, Xy};
use micropos::model::{MotionState, StageModel, StageSimulator, XyUm};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

const MOVE_S: f64 = 2.08; // the paper: 16 449 points in 9.5 h

fn simulator(seed: u64) -> StageSimulator {
    let m = StageModel::paper_default().unwrap();
    StageSimulator::new(m, MotionState::at_rest(7500.0, 7500.0), seed).unwrap()
}

/// Runs a characterization plan, returns the log records and the end time.
fn characterize(
    sim: &mut StageSimulator,
    plan: &CharacterizationPlan,
    t0: f64,
) -> (Vec<Record>, f64) {
    let mut t = t0;
    let mut out = Vec::new();
    for p in plan.points().unwrap() {
        t += MOVE_S;
        let s = sim
            .move_to(p.target.x_um, p.target.y_um, t, p.cycle)
            .unwrap();
        if p.logged {
            out.push(Record {
                t_s: t,
                segment: p.segment.clone(),
                cycle: p.cycle,
                x_target_um: p.target.x_um,
                y_target_um: p.target.y_um,
                x_cmd_um: p.target.x_um,
                y_cmd_um: p.target.y_um,
                x_meas_um: s.observed_um.x_um,
                y_meas_um: s.observed_um.y_um,
                temp_c: Some(s.state.temp_c),
                theta_urad: None,
                extra: Vec::new(),
            });
        }
    }
    (out, t)
}

#[derive(Clone, Copy)]
enum Mode<'a> {
    Raw,
    Comp(&'a dyn Compensator),
    Closed(&'a dyn Compensator),
}

struct Run {
    ap_obs: f64,
    rp_obs: f64,
    ap_true: f64,
    corrections: f64,
}

/// Visits `targets` `cycles` times in sequence; AP/RP on what the camera
/// sees (observed, as the paper) and on the ground truth.
fn validate(sim: &mut StageSimulator, mode: Mode, targets: &[XyUm], cycles: u32, t0: f64) -> Run {
    let min_move = sim.model().stochastic().min_incremental_motion_um;
    let mut hist = MotionHistory::new(*sim.state(), min_move).unwrap();
    let opts = PlanOptions::default();
    let mut rng = ChaCha8Rng::seed_from_u64(99);
    let decode = Normal::new(0.0, 0.005).unwrap();
    let mut t = t0;
    let mut seq = 0u64;
    let mut obs = vec![Vec::new(); targets.len()];
    let mut tru = vec![Vec::new(); targets.len()];
    let mut corrections = 0u32;
    for cycle in 0..cycles {
        for (i, target) in targets.iter().enumerate() {
            let mut last = None;
            match mode {
                Mode::Raw => {
                    t += MOVE_S;
                    last = Some(sim.move_to(target.x_um, target.y_um, t, cycle).unwrap());
                }
                Mode::Comp(c) | Mode::Closed(c) => {
                    let plan = c.command_for(*target, &hist, &opts).unwrap();
                    for w in &plan.waypoints {
                        t += MOVE_S;
                        last = Some(sim.move_to(w.x_um, w.y_um, t, cycle).unwrap());
                    }
                    let temp = sim.state().temp_c;
                    hist.commit(&plan, t, temp).unwrap();
                    if let Mode::Closed(_) = mode {
                        let mut cl = ClosedLoop::new(
                            *target,
                            plan.cmd,
                            plan.arrival,
                            ClosedLoopConfig::default(),
                        )
                        .unwrap();
                        cl.settled(t);
                        loop {
                            let s = last.unwrap();
                            seq += 1;
                            let m = FrameMeasurement {
                                position: XyUm {
                                    x_um: s.observed_um.x_um + decode.sample(&mut rng),
                                    y_um: s.observed_um.y_um + decode.sample(&mut rng),
                                },
                                timestamp_s: t + 0.05,
                                quality: 100.0,
                                frame_seq: seq,
                            };
                            match cl.on_frame(&m) {
                                Action::Move { waypoints } => {
                                    for w in &waypoints {
                                        t += MOVE_S;
                                        last = Some(sim.move_to(w.x_um, w.y_um, t, cycle).unwrap());
                                        hist.commit_move(*w, *target, t, sim.state().temp_c)
                                            .unwrap();
                                    }
                                    cl.settled(t);
                                }
                                Action::Done { corrections: n, .. } => {
                                    corrections += n;
                                    break;
                                }
                                other => panic!("closed loop: {other:?}"),
                            }
                        }
                    }
                }
            }
            let s = last.unwrap();
            obs[i].push(Xy::new(s.observed_um.x_um, s.observed_um.y_um));
            tru[i].push(Xy::new(s.true_um.x_um, s.true_um.y_um));
        }
    }
    let summary = |m: &[Vec<Xy>]| {
        let st: Vec<_> = targets
            .iter()
            .zip(m)
            .map(|(t, v)| pose_stats(Xy::new(t.x_um, t.y_um), v).unwrap())
            .collect();
        summarize_poses(&st).unwrap()
    };
    let so = summary(&obs);
    let st = summary(&tru);
    Run {
        ap_obs: so.ap_max_um,
        rp_obs: so.rp_max_um.unwrap_or(f64::NAN),
        ap_true: st.ap_max_um,
        corrections: f64::from(corrections) / (targets.len() as f64 * f64::from(cycles)),
    }
}

fn print(name: &str, what: &str, r: &Run) {
    println!(
        "{name:<28} {what:<7} AP max {:>7.3} µm  RP max {:>6.3} µm  AP(true) {:>7.3} µm  corrections/visit {:.2}",
        r.ap_obs, r.rp_obs, r.ap_true, r.corrections
    );
}

fn square() -> Vec<XyUm> {
    square_poses(200.0)
        .unwrap()
        .into_iter()
        .map(|p| p.target)
        .collect()
}

#[test]
fn paper_characterization_tables_reach_one_micrometre() {
    let mut sim = simulator(21);
    let (log, t_end) = characterize(&mut sim, &CharacterizationPlan::paper(), 0.0);
    let (table, report) = CompTable::from_records(&log, &TableBuildOptions::default()).unwrap();
    println!("table build: {report:?}");
    assert!(
        (report.squareness_urad - 5300.0).abs() < 300.0,
        "{report:?}"
    );
    // Through a file, as the daemon loads it.
    let file = CompFile::lookup(table, "2024-01-01T00:00:00Z", SourceInfo::default());
    let text = file.to_toml().unwrap();
    let comp = CompFile::from_toml(&text).unwrap().compensator().unwrap();
    assert_eq!(comp.kind(), "lookup");

    let sq = square();
    let rnd = random_targets();
    let t0 = t_end + 60.0;
    let raw_sq = validate(&mut sim, Mode::Raw, &sq, 5, t0);
    let raw_rnd = validate(&mut sim, Mode::Raw, &rnd, 10, t0 + 2000.0);
    let tab_sq = validate(&mut sim, Mode::Comp(&*comp), &sq, 5, t0 + 4000.0);
    let tab_rnd = validate(&mut sim, Mode::Comp(&*comp), &rnd, 10, t0 + 6000.0);
    let cl_sq = validate(&mut sim, Mode::Closed(&*comp), &sq, 3, t0 + 8000.0);
    let cl_rnd = validate(&mut sim, Mode::Closed(&*comp), &rnd, 5, t0 + 10000.0);
    print("raw", "square", &raw_sq);
    print("raw", "random", &raw_rnd);
    print("table (5 µm, 9.5 h)", "square", &tab_sq);
    print("table (5 µm, 9.5 h)", "random", &tab_rnd);
    print("closed loop (table first)", "square", &cl_sq);
    print("closed loop (table first)", "random", &cl_rnd);
    assert!((19.0..=25.0).contains(&raw_sq.ap_obs));
    assert!((19.0..=25.0).contains(&raw_rnd.ap_obs));
    assert!(tab_sq.ap_obs <= 1.0, "table square AP {}", tab_sq.ap_obs);
    assert!(tab_rnd.ap_obs <= 1.0, "table random AP {}", tab_rnd.ap_obs);
    assert!(
        cl_sq.ap_obs <= 0.1,
        "closed-loop square AP {}",
        cl_sq.ap_obs
    );
    assert!(
        cl_rnd.ap_obs <= 0.1,
        "closed-loop random AP {}",
        cl_rnd.ap_obs
    );
}

#[test]
fn model_from_a_ten_times_shorter_characterization_reaches_one_micrometre() {
    let mut sim = simulator(22);
    let (log, t_end) = characterize(&mut sim, &CharacterizationPlan::short(), 0.0);
    let template = compensation_template(sim.model()).unwrap();
    let opts = ModelBuildOptions {
        min_move_um: sim.model().stochastic().min_incremental_motion_um,
        ..ModelBuildOptions::default()
    };
    let (mc, fit) = ModelCompensator::fit_records(template, &log, &opts).unwrap();
    println!(
        "model fit: {} samples, residual rms {:?} µm (from {:?}), rank {}, unidentifiable {:?}",
        fit.samples, fit.residual_rms_um, fit.initial_residual_rms_um, fit.rank, fit.unidentifiable
    );
    let file = CompFile::model(mc.model(), "2024-01-01T00:00:00Z", SourceInfo::default()).unwrap();
    let comp = CompFile::from_toml(&file.to_toml().unwrap())
        .unwrap()
        .compensator()
        .unwrap();
    assert_eq!(comp.kind(), "model");
    // The same short log as tables, for comparison.
    let (table, _) = CompTable::from_records(&log, &TableBuildOptions::default()).unwrap();
    let short_table = micropos::comp::LookupCompensator::new(table).unwrap();

    let sq = square();
    let rnd = random_targets();
    let t0 = t_end + 60.0;
    let m_sq = validate(&mut sim, Mode::Comp(&*comp), &sq, 5, t0);
    let m_rnd = validate(&mut sim, Mode::Comp(&*comp), &rnd, 10, t0 + 2000.0);
    let s_sq = validate(&mut sim, Mode::Comp(&short_table), &sq, 5, t0 + 4000.0);
    let s_rnd = validate(&mut sim, Mode::Comp(&short_table), &rnd, 10, t0 + 6000.0);
    print("model (50 µm, 57 min)", "square", &m_sq);
    print("model (50 µm, 57 min)", "random", &m_rnd);
    print("table (50 µm, 57 min)", "square", &s_sq);
    print("table (50 µm, 57 min)", "random", &s_rnd);
    assert!(m_sq.ap_obs <= 1.0, "model square AP {}", m_sq.ap_obs);
    assert!(m_rnd.ap_obs <= 1.0, "model random AP {}", m_rnd.ap_obs);
}
