//! Unit tests of the lead check: the scan's compact columns, and a lead
//! the log cannot tell.

use super::screw::columns_of;
use super::*;
use crate::analysis::generate::{simulate_log, truth_model, SimPlan};
use crate::charact::log::parse_bytes;

fn data(plan: &SimPlan) -> (Data, StageModel) {
    let model = StageModel::paper_default().unwrap();
    let truth = truth_model(&model, None, plan, 11).unwrap();
    let log = simulate_log(&truth, plan, 11).unwrap();
    let parsed = parse_bytes(&log.to_bytes().unwrap()).unwrap();
    (super::super::prepare(&parsed, &model, 4).unwrap(), model)
}

fn plan() -> SimPlan {
    SimPlan {
        x_range_um: [250.0, 1450.0],
        x_scan_y_um: 600.0,
        y_range_um: [250.0, 850.0],
        y_scan_x_um: 700.0,
        cycles: 2,
        random_points: 10,
        ..SimPlan::default()
    }
}

/// The scan's criterion evaluates the screw's columns at the entries
/// they can be non-zero at, centred there: they must be the full
/// columns' values at those entries, and the full columns zero
/// elsewhere.
#[test]
fn the_scans_compact_columns_are_the_full_ones() {
    let (d, model) = data(&plan());
    let cfg = cyclic_config(model.term("x_cyclic").unwrap()).unwrap();
    let terms = screw_terms(&model, "x_cyclic", &cfg).unwrap();
    let scan = Scan::new(&d, &model, &terms, &DiagnoseOptions::default()).unwrap();
    for lead_um in [137.0, 400.0, 611.5] {
        let full = columns_of(&scan.d, &scan.terms[..1], lead_um).unwrap();
        let compact = scan.coarse_columns(lead_um).unwrap();
        assert_eq!(full.len(), compact.len());
        for (f, c) in full.iter().zip(&compact) {
            let mut at = vec![false; f.len()];
            for (v, &(e, _)) in c.iter().zip(&scan.active) {
                assert!((v - f[e]).abs() < 1e-9, "{lead_um}: {v} vs {}", f[e]);
                at[e] = true;
            }
            assert!(f.iter().zip(&at).all(|(v, a)| *a || *v == 0.0));
        }
    }
}

/// A lead is scanned only where the log spans two of it at four
/// points per lead; otherwise the sentence gives the numbers and the
/// scan that would.
#[test]
fn a_lead_the_log_cannot_tell_is_not_scanned_and_the_report_says_why() {
    let s = Sampling {
        span_um: 450.0,
        spacing_um: Some(11.25),
    };
    assert_eq!(s.range(400.0), None);
    assert_eq!(s.range(200.0), Some([50.0, 225.0]));
    let coarse = Sampling {
        span_um: 40_000.0,
        spacing_um: Some(10_000.0),
    };
    assert_eq!(coarse.range(400.0), None);
    let (d, model) = data(&plan());
    let check = check_one(
        &d,
        &model,
        "y_cyclic",
        &cyclic_config(model.term("y_cyclic").unwrap()).unwrap(),
        &DiagnoseOptions::default(),
    )
    .unwrap();
    assert_eq!(check.verdict, LeadVerdict::NotChecked);
    assert!(
        check.sentence.starts_with(
            "y_cyclic (the screw lead, 400 µm in the model) is not checked: the log spans 600 µm of y, less than two leads (800 µm); its harmonics cannot be told from a bow of the travel and are held at the model's values ("
        ),
        "{}",
        check.sentence
    );
    assert!(
        check
            .sentence
            .ends_with("a scan over ≥ 800 µm at ≤ 100 µm steps resolves them"),
        "{}",
        check.sentence
    );
    let x = check_one(
        &d,
        &model,
        "x_cyclic",
        &cfg_of(&model, "x_cyclic"),
        &DiagnoseOptions::default(),
    )
    .unwrap();
    assert_eq!(x.verdict, LeadVerdict::Kept, "{x:?}");
    assert_eq!(x.scanned_um, Some([100.0, 600.0]));
}

fn cfg_of(model: &StageModel, name: &str) -> CyclicConfig {
    cyclic_config(model.term(name).unwrap()).unwrap()
}

/// A log that spans many leads at more than a quarter lead apart (and
/// less than half: not aliased) cannot tell the lead either: the
/// harmonics are fitted at the model's lead, taken as given, and the
/// sentence gives the spacing and the scan that would check it. A log
/// over fewer than two leads holds them.
#[test]
fn a_coarse_log_fits_the_harmonics_at_the_models_lead_and_says_what_scan_would_check_it() {
    let coarse = Sampling {
        span_um: 4000.0,
        spacing_um: Some(150.0),
    };
    assert_eq!(coarse.range(400.0), None);
    assert!(!coarse.holds(400.0));
    let short = Sampling {
        span_um: 600.0,
        spacing_um: Some(20.0),
    };
    assert_eq!(short.range(400.0), None);
    assert!(short.holds(400.0));
    // Aliased (a period below two spacings): held by the base fit's own
    // rule, with its own figure.
    assert!(!coarse.holds(250.0));
    let fine = Sampling {
        span_um: 4000.0,
        spacing_um: Some(25.0),
    };
    assert!(!fine.holds(400.0));
    let check = LeadCheck {
        term: "x_cyclic".into(),
        axis: Axis::X,
        followers: vec![],
        model_lead_um: 400.0,
        verdict: LeadVerdict::NotChecked,
        lead_um: 400.0,
        std_error_um: None,
        span_um: 4000.0,
        spacing_um: Some(150.0),
        scanned_um: None,
        candidate: None,
        held_contribution_rms_um: None,
        needs_span_um: 800.0,
        needs_step_um: 100.0,
        sentence: String::new(),
    };
    assert_eq!(
        sentence(&check),
        "x_cyclic (the screw lead, 400 µm in the model) is not checked: its x positions are 150 µm apart, more than a quarter lead (100 µm); its harmonics are fitted at the model's lead, taken as given; a scan over ≥ 800 µm at ≤ 100 µm steps resolves them"
    );
}

/// No input makes the sentences panic: a log that does not scan the
/// axis, NaN figures.
#[test]
fn a_check_without_numbers_still_says_what_scan_would() {
    let mut check = LeadCheck {
        term: "y_cyclic".into(),
        axis: Axis::Y,
        followers: vec![],
        model_lead_um: 400.0,
        verdict: LeadVerdict::NotChecked,
        lead_um: 400.0,
        std_error_um: None,
        span_um: 0.0,
        spacing_um: None,
        scanned_um: None,
        candidate: None,
        held_contribution_rms_um: None,
        needs_span_um: 800.0,
        needs_step_um: 100.0,
        sentence: String::new(),
    };
    assert!(sentence(&check).ends_with("a scan over ≥ 800 µm at ≤ 100 µm steps resolves them"));
    check.spacing_um = Some(f64::NAN);
    check.span_um = f64::NAN;
    assert!(sentence(&check).contains("is not checked"));
}
