use micropos::analysis::generate::{draw_effect, simulate_log, truth_model, SimPlan};
use micropos::analysis::{diagnose, DiagnoseOptions, FindingKind};
use micropos::charact::log::parse_bytes;
use micropos::model::StageModel;

#[test]
#[ignore]
fn explore() {
    let base = StageModel::paper_default().unwrap();
    let plan = SimPlan::default();
    let kinds: Vec<Option<FindingKind>> = match std::env::var("KIND") {
        Ok(k) if k == "none" => vec![None],
        Ok(k) => vec![FindingKind::parse(&k)],
        Err(_) => vec![None],
    };
    let n: u64 = std::env::var("SEEDS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(2);
    for k in kinds {
        for seed in 0..n {
            let eff = k.map(|k| draw_effect(seed, Some(k), &plan).unwrap());
            let truth = truth_model(&base, eff.as_ref(), &plan, seed).unwrap();
            let log = simulate_log(&truth, &plan, seed).unwrap();
            let bytes = log.to_bytes().unwrap();
            let parsed = parse_bytes(&bytes).unwrap();
            let t = std::time::Instant::now();
            let d = diagnose(&parsed, &base, &DiagnoseOptions::default()).unwrap();
            println!(
                "seed {seed} truth {:?} {:?}/{:?} {:?}",
                eff.as_ref().map(|e| e.kind),
                eff.as_ref().map(|e| e.axis),
                eff.as_ref().map(|e| e.component),
                eff.as_ref().map(|e| &e.params)
            );
            println!("{}", d.to_text());
            println!("elapsed {:?}", t.elapsed());
        }
    }
}
