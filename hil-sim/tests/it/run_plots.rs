//! The figures of `hil-sim run --short --plots DIR` ([`plot_run`] on the
//! reduced plan's run, the paper-faithful stage as the binary runs it):
//! its validation, the drift comparison's three and the grid row's all
//! carry mode `table`, and each is a figure of its own; Figs. 10–11 of
//! `validate.csv` show exactly the AP and RP the run printed (the same
//! records, ISO 9283 per pose, max and mean over poses); the figures
//! written are the ones the README says `--short` writes.

use std::collections::BTreeSet;

use hil_sim::run::{plot_run, run, RunOptions, RunPlan};
use micropos::plot::figure::Panel;
use micropos::plot::validation::{BAR_AP_MAX, BAR_AP_MEAN, BAR_RP_MAX};
use micropos::plot::Format;

/// The bars of a validation figure: category → (AP max, AP mean, RP max).
fn bars(f: &micropos::plot::figure::Figure) -> Vec<(String, [Option<f64>; 3])> {
    let Some(Panel::Bars(b)) = f.rows.last().and_then(|r| r.first()) else {
        panic!("a bar panel last: {}", f.title)
    };
    let col = |label: &str| b.groups.iter().find(|g| g.label == label).unwrap();
    let (a, m, r) = (col(BAR_AP_MAX), col(BAR_AP_MEAN), col(BAR_RP_MAX));
    b.categories
        .iter()
        .enumerate()
        .map(|(i, c)| (c.clone(), [a.values[i], m.values[i], r.values[i]]))
        .collect()
}

#[test]
fn short_run_figures_show_one_run_each_with_the_printed_numbers() {
    let dir = tempfile::tempdir().unwrap();
    let opts = RunOptions {
        seed: 1,
        out_dir: Some(dir.path().join("run")),
        stage_model: Some(
            micropos::model::StageModel::from_toml(micropos::model::PAPER_FAITHFUL_TOML).unwrap(),
        ),
        plan: RunPlan::reduced(),
        ..RunOptions::default()
    };
    let mut lines = Vec::new();
    let report = run(opts, &mut |l: &str| lines.push(l.to_owned()))
        .unwrap_or_else(|e| panic!("{e}; progress: {lines:?}"));
    let data = report.data_dir.clone().unwrap();
    let out = dir.path().join("plots");
    let p = plot_run(&data, &report.files, &out, Format::Svg)
        .unwrap_or_else(|e| panic!("{e}: files {:?}", report.files));
    let stems: Vec<&str> = p.figures.iter().map(|f| f.stem.as_str()).collect();
    for vlog in [
        "validate",
        "validate-drift-off",
        "validate-drift-static",
        "validate-drift-adaptive",
        "validate-grid",
    ] {
        for fig in ["fig10_square", "fig11_random"] {
            assert!(
                stems.contains(&format!("{vlog}_{fig}").as_str()),
                "{vlog}_{fig} in {stems:?}"
            );
        }
    }
    assert!(
        p.notes.iter().any(|n| n.starts_with("charact-grid.csv")),
        "{:?}",
        p.notes
    );
    // One log per figure: no series of another log, no pooled mode.
    for f in &p.figures {
        let logs = report
            .files
            .iter()
            .filter(|l| l.ends_with(".csv") && f.figure.title.contains(l.as_str()))
            .count();
        assert_eq!(logs, 1, "{}: {}", f.stem, f.figure.title);
    }
    // Figs. 10 and 11 of the validation: the numbers the run printed.
    let s = &report.summary;
    for (test, fig) in [("square", "fig10_square"), ("random", "fig11_random")] {
        let f = p
            .figures
            .iter()
            .find(|f| f.stem == format!("validate_{fig}"))
            .unwrap();
        let b = bars(&f.figure);
        let modes: Vec<&str> = b.iter().map(|(m, _)| m.as_str()).collect();
        assert_eq!(modes, ["raw", "table", "model", "closed_loop"], "{test}");
        for (mode, [ap, ap_mean, rp]) in &b {
            let r = &s[test][mode.as_str()];
            for (what, drawn, printed) in [
                ("AP max", ap, &r["ap_um"]),
                ("AP mean", ap_mean, &r["ap_mean_um"]),
                ("RP max", rp, &r["rp_um"]),
            ] {
                let (d, want) = (drawn.unwrap(), printed.as_f64().unwrap());
                // The log keeps 0.1 nm; the run computes before rounding.
                assert!(
                    (d - want).abs() < 2e-4,
                    "{test} {mode} {what}: figure {d} µm, run {want} µm"
                );
            }
        }
    }
    // `--short`'s characterizations run one cycle: no Fig. 6, and the
    // README says which figures it writes.
    let numbers: BTreeSet<u32> = stems
        .iter()
        .filter_map(|s| s.split("_fig").nth(1))
        .filter_map(|s| s.split('_').next())
        .filter_map(|n| n.parse().ok())
        .collect();
    assert_eq!(numbers, BTreeSet::from([4, 5, 10, 11]), "{stems:?}");
    let readme =
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/../README.md")).unwrap();
    assert!(
        readme.contains("`--short` writes Figs. 4, 5, 10 and 11"),
        "README.md must say which figures `--short` writes"
    );
}
