//! Hidden effects on stages drawn at random: the baseline stage itself is
//! random (every parameter of every family of the default model, both
//! signs, ranges wider than the paper's), the analysis starts from the
//! **default** model (`config/stage-model.toml`), and only structure the
//! default model lacks may come back as a finding; the stage's own values
//! come back as parameter corrections.
//!
//! Two generators make the logs:
//! * the model's simulator running a randomized copy of the default model
//!   (plus the hidden effect as a model term, [`draw_effect_sized`]);
//! * [`micropos::analysis::physical`], a stage built from its physical
//!   description (screw, nut with play as a hysteresis state machine,
//!   guideway angles through Abbe arms, squareness, thermal expansion) in
//!   code apart from the model, with hidden effects of other shapes (a
//!   raised-cosine dent instead of a Gaussian, elastic wind-up, an
//!   air-conditioning cycle).
//!
//! Measured per kind and size (3×, 6×, 12× the noise of 0.046 µm): the
//! fraction of logs whose findings name the hidden effect (kind, component,
//! variable axis); on clean stages, the number of findings (false
//! structural findings). The table is printed (`--nocapture`); the test
//! requires 0 false findings and detection rates the runs hold with a
//! margin (see `docs/design/analysis.md` for the measured rates).

use micropos::analysis::generate::{
    draw_effect_sized, simulate_log, truth_model, InjectedEffect, SimLog, SimPlan,
};
use micropos::analysis::physical::{simulate_physical_log, PhysicalEffect, PhysicalStage};
use micropos::analysis::{diagnose, DiagnoseOptions, Diagnosis, FindingKind, LeadVerdict};
use micropos::charact::log::{parse_bytes, MeasurementLog};
use micropos::model::{Axis, StageModel};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Noise of the plan: settling σ 0.035 ⊕ camera σ 0.03, µm.
pub(crate) const NOISE_UM: f64 = 0.046;

/// Sizes of the hidden effects, multiples of the noise.
const SIZES: [f64; 3] = [3.0, 6.0, 12.0];

/// A reduced characterization plan (40 µm steps, 3 cycles): ≈ 2200
/// points, enough to resolve the 400 µm screw's three harmonics.
pub(crate) fn plan() -> SimPlan {
    SimPlan {
        step_um: 40.0,
        ..SimPlan::default()
    }
}

fn uniform(rng: &mut ChaCha8Rng, lo: f64, hi: f64) -> f64 {
    lo + (hi - lo) * rng.gen::<f64>()
}

fn signed(rng: &mut ChaCha8Rng, lo: f64, hi: f64) -> f64 {
    let v = uniform(rng, lo, hi);
    if rng.gen::<bool>() {
        v
    } else {
        -v
    }
}

/// The default model with every parameter of every family drawn at
/// random: squareness ±10 mrad, scales ±300 ppm, play 0.3–5 µm, cyclic
/// first harmonics 0.3–4 µm (cross coupling 0.1–1.5 µm) at random phases
/// with higher harmonics up to 30 % / 10 % of it and the backward flank
/// within ±25 % and ±0.5 rad of the forward one, angular slopes
/// ±10 µrad/mm and waviness ±30 µrad, thermal terms, x drift 0–0.3 µm/h.
/// Abbe arms, periods and the documented-zero discovered terms (other
/// than the x drift) keep their values.
pub(crate) fn random_model(seed: u64) -> StageModel {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x4a4d_0000_0000_0011);
    let mut m = StageModel::paper_default().unwrap();
    let params = m.params();
    for p in &params {
        let name = p.full_name.as_str();
        let v = match (p.kind.as_str(), p.info.name.as_str()) {
            ("squareness", _) => uniform(&mut rng, -10_000.0, 10_000.0),
            ("lead_error", _) => uniform(&mut rng, -300.0, 300.0),
            ("backlash", _) => uniform(&mut rng, 0.3, 5.0),
            ("angular", n) if n.starts_with("slope") => uniform(&mut rng, -10.0, 10.0),
            ("angular", n) if n.starts_with("sin") || n.starts_with("cos") => {
                uniform(&mut rng, -30.0, 30.0)
            }
            ("thermal_expansion", n) if n.contains("per_mm") => uniform(&mut rng, -0.02, 0.02),
            ("thermal_expansion", n) if n.contains("offset") => uniform(&mut rng, -0.5, 0.5),
            ("optics_drift", _) => uniform(&mut rng, -0.5, 0.5),
            ("time_drift", "rate_um_per_h") => signed(&mut rng, 0.0, 0.3),
            _ => continue,
        };
        m.set_param(name, v).unwrap();
    }
    // Cyclic tables by harmonic: amplitude and phase per flank.
    let terms: Vec<(String, String)> = m
        .terms()
        .iter()
        .map(|t| (t.name().to_string(), t.kind().to_string()))
        .collect();
    for (term, kind) in terms {
        let a1 = match kind.as_str() {
            "leadscrew_cyclic" => uniform(&mut rng, 0.3, 4.0),
            "cross_coupling" => uniform(&mut rng, 0.1, 1.5),
            _ => continue,
        };
        for k in 1..=3 {
            let key = |flank: &str, f: &str| format!("{term}.{flank}_{f}_{k}_um");
            if m.param(&key("forward", "sin")).is_err() {
                continue;
            }
            let a = a1
                * match k {
                    1 => 1.0,
                    2 => uniform(&mut rng, 0.0, 0.3),
                    _ => uniform(&mut rng, 0.0, 0.1),
                };
            let phi = uniform(&mut rng, 0.0, std::f64::consts::TAU);
            let ab = a * uniform(&mut rng, 0.75, 1.25);
            let pb = phi + uniform(&mut rng, -0.5, 0.5);
            m.set_param(&key("forward", "sin"), a * phi.cos()).unwrap();
            m.set_param(&key("forward", "cos"), a * phi.sin()).unwrap();
            m.set_param(&key("backward", "sin"), ab * pb.cos()).unwrap();
            m.set_param(&key("backward", "cos"), ab * pb.sin()).unwrap();
        }
    }
    m
}

/// `f` over `items` on up to four threads (the diagnoses are independent
/// and seeded; the order of the results is the order of `items`).
pub(crate) fn par_map<T: Sync, R: Send>(items: &[T], f: impl Fn(&T) -> R + Sync) -> Vec<R> {
    let workers = std::thread::available_parallelism()
        .map_or(1, |n| n.get())
        .clamp(1, 4);
    let next = std::sync::atomic::AtomicUsize::new(0);
    let out: std::sync::Mutex<Vec<Option<R>>> =
        std::sync::Mutex::new((0..items.len()).map(|_| None).collect());
    std::thread::scope(|s| {
        for _ in 0..workers {
            s.spawn(|| loop {
                let i = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                let Some(item) = items.get(i) else { break };
                let r = f(item);
                out.lock().unwrap()[i] = Some(r);
            });
        }
    });
    out.into_inner()
        .unwrap()
        .into_iter()
        .map(|r| r.unwrap())
        .collect()
}

fn describe(d: &Diagnosis) -> Vec<String> {
    let withdrawn = d.withdrawn.iter().map(|w| {
        let f = &w.finding;
        format!(
            "WITHDRAWN {} {} vs {} because {}",
            f.kind, f.component, f.axis, w.reason
        )
    });
    d.findings
        .iter()
        .map(|f| {
            format!(
                "{} {} vs {}: {}",
                f.kind, f.component, f.axis, f.explanation
            )
        })
        .chain(withdrawn)
        .collect()
}

/// `log` through the file format (what `diagnose` reads).
pub(crate) fn parsed(log: &SimLog) -> MeasurementLog {
    parse_bytes(&log.to_bytes().unwrap()).unwrap()
}

/// Diagnoses a parsed log against the default model.
pub(crate) fn run_parsed(log: &MeasurementLog) -> Diagnosis {
    let model = StageModel::paper_default().unwrap();
    diagnose(log, &model, &DiagnoseOptions::default()).unwrap()
}

/// Diagnoses `log` (through the file format) against the default model,
/// and requires every number its report prints to be sane
/// (`diagnose_sane::problems`).
fn run(log: &SimLog) -> Diagnosis {
    let parsed = parsed(log);
    let d = run_parsed(&parsed);
    let bad = super::diagnose_sane::problems(&parsed, &d);
    assert!(bad.is_empty(), "{bad:#?}\n{}", d.to_text());
    d
}

/// What a finding must name: kind, component, and the variable axis for
/// position-dependent kinds.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Expect {
    kind: FindingKind,
    component: Axis,
    axis: Option<Axis>,
}

fn found(d: &Diagnosis, e: &Expect) -> bool {
    d.findings.iter().any(|f| {
        f.kind == e.kind && f.component == e.component && e.axis.is_none_or(|a| a == f.axis)
    })
}

/// Kinds hidden in model-generated logs (structure the default model
/// lacks; a time drift only on y: the default has an x drift term).
pub(crate) const MODEL_KINDS: [FindingKind; 5] = [
    FindingKind::PositionPeriodic,
    FindingKind::Localized,
    FindingKind::TimePeriodic,
    FindingKind::StepSize,
    FindingKind::TimeDrift,
];

/// A hidden model-term effect of `kind` and peak `size_um` from `seed`,
/// skipping draws the default model can express (a y drift only; an x
/// periodic of x near the default's 1600 µm extra period).
pub(crate) fn model_effect(kind: FindingKind, size_um: f64, seed: u64) -> (InjectedEffect, Expect) {
    let plan = plan();
    for s in seed.. {
        let e = draw_effect_sized(s, kind, size_um, &plan).unwrap();
        if kind == FindingKind::TimeDrift && e.component != Axis::Y {
            continue;
        }
        if kind == FindingKind::PositionPeriodic
            && e.axis == Axis::X
            && e.component == Axis::X
            && (e.params["period_um"] / 1600.0 - 1.0).abs() < 0.25
        {
            continue;
        }
        let axis = match kind {
            FindingKind::PositionPeriodic | FindingKind::Localized => Some(e.axis),
            _ => None,
        };
        let x = Expect {
            kind,
            component: e.component,
            axis,
        };
        return (e, x);
    }
    unreachable!("an unbounded seed range always yields a draw")
}

/// A hidden physical effect of kind index `k` (dent, bearing, wind-up, air
/// cycle, y drift) and peak `size_um` from `seed`.
pub(crate) fn physical_effect(k: usize, size_um: f64, seed: u64) -> (PhysicalEffect, Expect) {
    let plan = plan();
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x0ef1_0000_0000_0013);
    let axis = if rng.gen::<bool>() { Axis::X } else { Axis::Y };
    let component = if rng.gen::<bool>() { Axis::X } else { Axis::Y };
    let [lo, hi] = match axis {
        Axis::X => plan.x_range_um,
        Axis::Y => plan.y_range_um,
    };
    let sign = if rng.gen::<bool>() { 1.0 } else { -1.0 };
    let hours = plan.duration_s() / 3600.0;
    match k {
        0 => (
            PhysicalEffect::Dent {
                axis,
                component,
                position_um: lo + (hi - lo) * uniform(&mut rng, 0.1, 0.9),
                half_width_um: uniform(&mut rng, 150.0, 600.0),
                depth_um: sign * size_um,
            },
            Expect {
                kind: FindingKind::Localized,
                component,
                axis: Some(axis),
            },
        ),
        1 => {
            // Away from the default's 1600 µm x period.
            let mut period = (uniform(&mut rng, 600f64.ln(), 3000f64.ln())).exp();
            if axis == Axis::X && component == Axis::X && (period / 1600.0 - 1.0).abs() < 0.25 {
                period = 800.0;
            }
            (
                PhysicalEffect::Bearing {
                    axis,
                    component,
                    period_um: period.min((hi - lo) / 2.5),
                    amplitude_um: size_um,
                    phase_rad: uniform(&mut rng, 0.0, std::f64::consts::TAU),
                },
                Expect {
                    kind: FindingKind::PositionPeriodic,
                    component,
                    axis: Some(axis),
                },
            )
        }
        2 => (
            PhysicalEffect::WindUp {
                axis,
                amplitude_um: size_um,
                length_um: (uniform(&mut rng, 50f64.ln(), 1500f64.ln())).exp(),
            },
            Expect {
                kind: FindingKind::StepSize,
                component: axis,
                axis: None,
            },
        ),
        3 => (
            PhysicalEffect::AirCycle {
                component,
                period_s: (uniform(&mut rng, 300f64.ln(), (plan.duration_s() / 4.0).ln())).exp(),
                amplitude_um: size_um,
                phase_rad: uniform(&mut rng, 0.0, std::f64::consts::TAU),
            },
            Expect {
                kind: FindingKind::TimePeriodic,
                component,
                axis: None,
            },
        ),
        _ => (
            PhysicalEffect::DriftY {
                rate_um_per_h: sign * size_um / hours,
            },
            Expect {
                kind: FindingKind::TimeDrift,
                component: Axis::Y,
                axis: None,
            },
        ),
    }
}

pub(crate) const PHYSICAL_KINDS: [&str; 5] = ["dent", "bearing", "wind-up", "air cycle", "y drift"];

/// Clean stages: model-generated and physical. Returns the number of
/// stages and of findings on them (all false: the stages have no
/// structure the default model lacks).
fn clean(n_model: u64, n_physical: u64) -> (usize, usize) {
    let plan = plan();
    let seeds: Vec<(bool, u64)> = (0..n_model)
        .map(|s| (false, s))
        .chain((0..n_physical).map(|s| (true, 1000 + s)))
        .collect();
    let results = par_map(&seeds, |&(physical, seed)| {
        let log = if physical {
            simulate_physical_log(&PhysicalStage::random(seed), &plan, seed).unwrap()
        } else {
            let truth = truth_model(&random_model(seed), None, &plan, seed).unwrap();
            simulate_log(&truth, &plan, seed).unwrap()
        };
        let d = run(&log);
        check_corrections(&d);
        check_leads_kept(&d);
        check_findings_hold(&d);
        eprintln!(
            "clean {} stage {seed}: {} finding(s) {:?}; {} significant corrections; fixed: {:?}",
            if physical { "physical" } else { "model" },
            d.findings.len(),
            describe(&d),
            d.parameters.iter().filter(|p| p.significant).count(),
            d.base_fixed_params
                .iter()
                .map(|p| p.name.as_str())
                .collect::<Vec<_>>()
        );
        d.findings.len()
    });
    (results.len(), results.iter().sum())
}

/// Every random stage differs from the default in its squareness by
/// several mrad: the report must say so as a parameter correction (and
/// never as a finding).
fn check_corrections(d: &Diagnosis) {
    let sq = d
        .parameters
        .iter()
        .find(|p| p.term == "squareness")
        .expect("squareness is identified");
    assert!(sq.std_error.is_finite() && sq.std_error < 50.0, "{sq:?}");
    assert!(
        d.findings
            .iter()
            .all(|f| f.kind != FindingKind::CrossAxis && f.kind != FindingKind::Scale),
        "a scale or squareness difference reported as a finding: {:?}",
        d.findings
    );
}

/// Every screw of the clean stages has the default model's 400 µm lead
/// (the physical stages' besides a bearing's periodic error at another
/// period): the lead check must keep it on both axes, never correct it.
fn check_leads_kept(d: &Diagnosis) {
    assert_eq!(d.leads.len(), 2, "{:?}", d.leads);
    for l in &d.leads {
        assert_eq!(l.verdict, LeadVerdict::Kept, "{l:?}");
    }
    assert!(
        d.parameters.iter().all(|p| p.parameter != "period_um"),
        "{:?}",
        d.parameters
    );
}

/// Seeds named in `MICROPOS_SEEDS` (comma-separated), if set: only those
/// hidden-effect cases run, their diagnoses are printed and no rate is
/// asserted (a look at single cases).
fn only_seeds() -> Option<Vec<u64>> {
    let v = std::env::var("MICROPOS_SEEDS").ok()?;
    Some(v.split(',').filter_map(|s| s.trim().parse().ok()).collect())
}

/// A finding is reported only when the final joint fit still gives it an
/// amplitude well above its uncertainty (a finding another one absorbed
/// is dropped, not reported).
fn check_findings_hold(d: &Diagnosis) {
    for f in &d.findings {
        for key in ["amplitude_um", "rate_um_per_h"] {
            if let (Some(v), Some(e)) = (f.params.get(key), f.uncertainty.get(key)) {
                assert!(
                    v.abs() >= 3.0 * e,
                    "{} {} vs {}: {key} {v} ± {e} in the final fit",
                    f.kind,
                    f.component,
                    f.axis
                );
            }
        }
    }
}

#[test]
fn random_stages_parameters_apart_from_hidden_structure() {
    let seeds = only_seeds();
    let (stages, false_findings) = if seeds.is_some() {
        (0, 0)
    } else {
        clean(28, 12)
    };
    // Detection per kind and size: (generator, kind index, size, seed).
    let plan = plan();
    let mut cases: Vec<(bool, usize, f64, u64)> = Vec::new();
    for ki in 0..MODEL_KINDS.len() {
        for &k in &SIZES {
            for rep in 0..2u64 {
                cases.push((false, ki, k, 100 + rep * 7919 + (k as u64) * 31));
            }
        }
    }
    for ki in 0..PHYSICAL_KINDS.len() {
        for &k in &SIZES {
            cases.push((true, ki, k, 2000 + ki as u64 * 101 + k as u64));
        }
    }
    if let Some(seeds) = &seeds {
        cases.retain(|c| seeds.contains(&c.3));
        // `MICROPOS_KIND` (e.g. `time_drift`, `dent`) narrows them further.
        if let Ok(kind) = std::env::var("MICROPOS_KIND") {
            cases.retain(|&(physical, ki, _, _)| {
                if physical {
                    PHYSICAL_KINDS[ki] == kind
                } else {
                    MODEL_KINDS[ki].to_string() == kind
                }
            });
        }
    }
    let hits = par_map(&cases, |&(physical, ki, k, seed)| {
        let (name, log, x) = if physical {
            let mut stage = PhysicalStage::random(seed);
            let (effect, x) = physical_effect(ki, k * NOISE_UM, seed);
            stage.effects.push(effect);
            let log = simulate_physical_log(&stage, &plan, seed).unwrap();
            (format!("physical {}", PHYSICAL_KINDS[ki]), log, x)
        } else {
            let (e, x) = model_effect(MODEL_KINDS[ki], k * NOISE_UM, seed);
            let truth = truth_model(&random_model(seed), Some(&e), &plan, seed).unwrap();
            let log = simulate_log(&truth, &plan, seed).unwrap();
            (format!("model {}", MODEL_KINDS[ki]), log, x)
        };
        let d = run(&log);
        let ok = found(&d, &x);
        eprintln!(
            "{name} {k}× seed {seed}: {} (want {:?}; found {:?})",
            if ok { "found" } else { "MISSED" },
            x,
            describe(&d)
        );
        if seeds.is_some() {
            eprintln!("{}", d.to_text());
        }
        check_findings_hold(&d);
        (name, k, ok)
    });
    let mut rows: Vec<(String, f64, usize, usize)> = Vec::new();
    for (name, k, ok) in hits {
        match rows.iter_mut().find(|r| r.0 == name && r.1 == k) {
            Some(r) => {
                r.2 += usize::from(ok);
                r.3 += 1;
            }
            None => rows.push((name, k, usize::from(ok), 1)),
        }
    }
    eprintln!("\n{:<28} {:>6} {:>8}", "hidden effect", "size", "found");
    for (name, k, hits, n) in &rows {
        eprintln!("{name:<28} {k:>5}× {hits:>4}/{n}");
    }
    eprintln!("clean stages: {stages}, findings on them: {false_findings}");
    let at = |k: f64| -> (usize, usize) {
        rows.iter()
            .filter(|r| r.1 == k)
            .fold((0, 0), |(h, n), r| (h + r.2, n + r.3))
    };
    let (h12, n12) = at(12.0);
    let (h6, n6) = at(6.0);
    eprintln!("detected: 12× {h12}/{n12}, 6× {h6}/{n6}");
    if seeds.is_some() {
        return;
    }
    assert!(stages >= 40);
    assert_eq!(
        false_findings, 0,
        "{false_findings} false findings on {stages} clean random stages"
    );
    assert!(h12 * 100 >= DETECT_12X_PCT * n12, "12×: {h12}/{n12}");
    assert!(h6 * 100 >= DETECT_6X_PCT * n6, "6×: {h6}/{n6}");
}

/// Bounds the detection asserts hold with a margin (measured: 14/15
/// detected at 12×, 15/15 at 6×, and 0 false findings on 40 clean stages,
/// which the test requires; see `docs/design/analysis.md`).
const DETECT_12X_PCT: usize = 75;
const DETECT_6X_PCT: usize = 85;
