//! Every printed number is sane (issue 31, item 6): a finding's place lies
//! inside the travel the log measured and every number it states has a
//! finite standard error (no larger than the travel for places and widths,
//! than the log's peak-to-peak error for amplitudes), or the finding is
//! withdrawn and the report says why; and no sentence contradicts the
//! number beside it.
//!
//! Checked in the text a person reads (the numbers parsed back out of each
//! `finding N:` block) as well as in the JSON, against bounds taken from
//! the log itself (not from the analysis), on
//! * random stages with random hidden effects drawn through the
//!   generators of `diagnose_random` (model-generated and physical
//!   stages), half of the dents placed at an end of the travel, where a
//!   feature is seen by its flank alone;
//! * the real logs (`../shared/reference/real-axis-logs/`,
//!   `tests/data/real-extra/`, the 2-D grid of
//!   `../shared/reference/real-2d-grids/`) when present.
//!
//! [`problems`] is also called by `diagnose_random`, `diagnose_real_extra`
//! and `diagnose_real_grid` on every report they make.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use micropos::analysis::generate::{simulate_log, truth_model};
use micropos::analysis::physical::{simulate_physical_log, PhysicalEffect, PhysicalStage};
use micropos::analysis::{diagnose, DiagnoseOptions, Diagnosis};
use micropos::charact::log::{read_file, MeasurementLog};
use micropos::model::{Axis, StageModel};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::diagnose_random as random;

/// What the log itself measured: the commanded range of each axis and the
/// peak-to-peak of measured − commanded of each component, over all its
/// records (the analysis leaves some out: these bounds are the wider).
struct LogBounds {
    range: [(f64, f64); 2],
    p2p: [f64; 2],
}

fn log_bounds(log: &MeasurementLog) -> LogBounds {
    let mut range = [(f64::INFINITY, f64::NEG_INFINITY); 2];
    let mut err = [(f64::INFINITY, f64::NEG_INFINITY); 2];
    for r in &log.records {
        for (c, (x, m)) in [(r.x_cmd_um, r.x_meas_um), (r.y_cmd_um, r.y_meas_um)]
            .into_iter()
            .enumerate()
        {
            range[c] = (range[c].0.min(x), range[c].1.max(x));
            err[c] = (err[c].0.min(m - x), err[c].1.max(m - x));
        }
    }
    LogBounds {
        range,
        p2p: err.map(|(lo, hi)| hi - lo),
    }
}

fn axis_named(s: &str) -> Option<Axis> {
    match s {
        "x" => Some(Axis::X),
        "y" => Some(Axis::Y),
        _ => None,
    }
}

/// One `finding N:` block of the text report, parsed back.
#[derive(Debug, Default)]
struct TextFinding {
    header: String,
    kind: String,
    component: String,
    variable: String,
    explanation: String,
    /// The model term its held-out line names.
    term: String,
    /// Parameter lines: value and the σ when printed.
    params: BTreeMap<String, (f64, Option<f64>)>,
}

/// The `finding N:` blocks of a text report.
fn text_findings(text: &str) -> Vec<TextFinding> {
    let mut out: Vec<TextFinding> = Vec::new();
    let mut inside = false;
    for line in text.lines() {
        if let Some(rest) = line.strip_prefix("finding ") {
            // "finding 1: localized (x error, variable x)"
            let (_, what) = rest.split_once(": ").unwrap_or(("", rest));
            let (kind, paren) = what.split_once(" (").unwrap_or((what, ""));
            let component = paren.split(' ').next().unwrap_or("").to_string();
            let variable = paren
                .rsplit_once("variable ")
                .map_or("", |(_, v)| v.trim_end_matches(')'))
                .to_string();
            out.push(TextFinding {
                header: line.to_string(),
                kind: kind.to_string(),
                component,
                variable,
                ..TextFinding::default()
            });
            inside = true;
            continue;
        }
        let Some(f) = out.last_mut().filter(|_| inside) else {
            continue;
        };
        let Some(body) = line.strip_prefix("  ") else {
            inside = false;
            continue;
        };
        if f.explanation.is_empty() {
            f.explanation = body.to_string();
            continue;
        }
        if let Some(term) = body
            .split("model term `")
            .nth(1)
            .and_then(|s| s.split('`').next())
        {
            f.term = term.to_string();
        }
        let t: Vec<&str> = body.split_whitespace().collect();
        let value = t.get(1).and_then(|v| v.parse::<f64>().ok());
        match (t.len(), value) {
            (2, Some(v)) => {
                f.params.insert(t[0].to_string(), (v, None));
            }
            (4, Some(v)) if t[2] == "±" => {
                let e = t[3].parse::<f64>().unwrap_or(f64::NAN);
                f.params.insert(t[0].to_string(), (v, Some(e)));
            }
            _ => {}
        }
    }
    out
}

/// The number in `s` right after `prefix`, e.g. the play in "T is the
/// play `x_backlash` (+0.123 µm)".
fn number_after(s: &str, prefix: &str) -> Option<f64> {
    let rest = &s[s.find(prefix)? + prefix.len()..];
    let end = rest
        .find(|c: char| !(c.is_ascii_digit() || c == '.' || c == '+' || c == '-' || c == 'e'))
        .unwrap_or(rest.len());
    rest[..end].parse().ok()
}

/// Everything insane in the report of `d` on `log`: numbers outside the
/// measured travel or without a usable σ (text and JSON), withdrawn
/// findings printed as findings or without a reason, and sentences that
/// contradict the numbers beside them.
pub(crate) fn problems(log: &MeasurementLog, d: &Diagnosis) -> Vec<String> {
    let mut out = Vec::new();
    let b = log_bounds(log);
    let text = d.to_text();
    let json = d.to_json();
    let tf = text_findings(&text);
    if tf.len() != d.findings.len() {
        out.push(format!(
            "the text prints {} finding blocks, the report has {} findings ({} withdrawn)",
            tf.len(),
            d.findings.len(),
            d.withdrawn.len()
        ));
    }
    for f in &tf {
        out.extend(text_finding_problems(f, &b));
    }
    out.extend(json_problems(&json, &b));
    out.extend(withdrawn_problems(d, &text, &json));
    out.extend(first_knot_problems(&text, &tf));
    out
}

/// A text finding's numbers against the log's bounds.
fn text_finding_problems(f: &TextFinding, b: &LogBounds) -> Vec<String> {
    let mut out = Vec::new();
    let axis = axis_named(&f.variable);
    let comp = axis_named(&f.component);
    if f.params.is_empty() {
        out.push(format!("{}: no parameter lines parsed", f.header));
    }
    for (k, &(v, e)) in &f.params {
        if !v.is_finite() || e.is_some_and(|e| !e.is_finite()) {
            out.push(format!("{}: {k} {v} ± {e:?} in the text", f.header));
            continue;
        }
        let Some(a) = axis else { continue };
        let (lo, hi) = b.range[a.index()];
        let span = hi - lo;
        // Printed to 4 decimals.
        let place = k == "position_um" || (k.starts_with("knot") && k.ends_with("_um"));
        if place && (v < lo - 1e-4 || v > hi + 1e-4) {
            out.push(format!(
                "{}: {k} {v} µm outside the measured {a} travel {lo} … {hi} µm",
                f.header
            ));
        }
        let width = matches!(k.as_str(), "position_um" | "width_um" | "length_um");
        if width && e.is_none_or(|e| e > span) {
            out.push(format!("{}: {k} {v} ± {e:?} (travel {span} µm)", f.header));
        }
        if k == "amplitude_um" {
            let p2p = comp.map_or(f64::INFINITY, |c| b.p2p[c.index()]);
            if e.is_none_or(|e| e > p2p) {
                out.push(format!(
                    "{}: {k} {v} ± {e:?} (the log's error spans {p2p} µm)",
                    f.header
                ));
            }
        }
    }
    out
}

/// The JSON findings: every number a finite number (NaN is `null`), the
/// places inside the travel.
fn json_problems(json: &serde_json::Value, b: &LogBounds) -> Vec<String> {
    let mut out = Vec::new();
    let empty = Vec::new();
    for f in json["findings"].as_array().unwrap_or(&empty) {
        let axis = f["axis"].as_str().and_then(axis_named);
        for key in ["params", "uncertainty"] {
            let Some(m) = f[key].as_object() else {
                out.push(format!("JSON finding without {key}: {f}"));
                continue;
            };
            for (k, v) in m {
                let Some(v) = v.as_f64().filter(|v| v.is_finite()) else {
                    out.push(format!("JSON {} {key}.{k} = {v}", f["kind"]));
                    continue;
                };
                let place = k == "position_um" || (k.starts_with("knot") && k.ends_with("_um"));
                if let (true, "params", Some(a)) = (place, key, axis) {
                    let (lo, hi) = b.range[a.index()];
                    if v < lo - 1e-6 || v > hi + 1e-6 {
                        out.push(format!("JSON {} {k} {v} outside {lo} … {hi}", f["kind"]));
                    }
                }
            }
        }
    }
    out
}

/// Withdrawn findings: each with a reason, in the JSON, in their own text
/// section and never as a finding.
fn withdrawn_problems(d: &Diagnosis, text: &str, json: &serde_json::Value) -> Vec<String> {
    let mut out = Vec::new();
    let n_json = json["withdrawn"].as_array().map_or(0, |a| a.len());
    if n_json != d.withdrawn.len() {
        out.push(format!(
            "{n_json} withdrawn in the JSON, {}",
            d.withdrawn.len()
        ));
    }
    if d.withdrawn.is_empty() {
        if text.contains("withdrawn (not determined") {
            out.push("a withdrawn section without withdrawn findings".into());
        }
        return out;
    }
    let Some(at) = text.find("\nwithdrawn (not determined by this log") else {
        out.push("withdrawn findings but no withdrawn section in the text".into());
        return out;
    };
    let section: String = text[at + 1..]
        .lines()
        .take_while(|l| !l.is_empty())
        .collect::<Vec<_>>()
        .join("\n");
    for w in &d.withdrawn {
        if w.reason.trim().is_empty() || !section.contains(&w.reason) {
            out.push(format!("withdrawn without its reason in the text: {w:?}"));
        }
        if w.finding.in_extended_model || !w.finding.term.is_empty() {
            out.push(format!("withdrawn but in the extended model: {w:?}"));
        }
        if d.findings.iter().any(|f| f == &w.finding) {
            out.push(format!("withdrawn and reported: {w:?}"));
        }
    }
    if section.to_lowercase().contains("finding") || section.contains("% better") {
        out.push(format!(
            "the withdrawn section reads as findings: {section}"
        ));
    }
    out
}

/// A reversal table's sentences against its numbers: "the table is zero
/// and T is the play `…` (p)" beside a first value that is not p; a play's
/// correction saying its table "is zero at its first knot" while the
/// table's own sentence says otherwise (the issue's −20.2 µm).
fn first_knot_problems(text: &str, tf: &[TextFinding]) -> Vec<String> {
    let mut out = Vec::new();
    for f in tf.iter().filter(|f| f.kind == "reversal_varies") {
        let Some(rest) = f
            .explanation
            .split("the table is zero and T is the play `")
            .nth(1)
        else {
            continue;
        };
        let v0 = f.params.get("value0_um").map(|p| p.0);
        match (v0, number_after(rest, "` (")) {
            (Some(v0), Some(p)) if (v0 - p).abs() <= 1e-3 => {}
            (v0, p) => out.push(format!(
                "{}: says the table is zero at its first knot (T = the play {p:?}) beside value0_um {v0:?}",
                f.header
            )),
        }
    }
    for line in text.lines().filter(|l| l.contains("at its first knot (")) {
        let Some(term) = line
            .split("reversal table `")
            .nth(1)
            .and_then(|s| s.split('`').next())
        else {
            continue;
        };
        let Some(table) = tf.iter().find(|f| f.term == term) else {
            out.push(format!(
                "a play's sentence names table `{term}`, which is no finding: {line}"
            ));
            continue;
        };
        let says_zero = line.contains("which is zero at its first knot");
        let is_zero = table.explanation.contains("the table is zero");
        if says_zero != is_zero {
            out.push(format!(
                "the play's sentence (zero: {says_zero}) and the table's (zero: {is_zero}) disagree on the first knot: {line}"
            ));
        }
    }
    out
}

/// Prints a report's withdrawn findings (the sweep's tally) and returns
/// them as `(kind, reason)`.
fn withdrawn_of(name: &str, d: &Diagnosis) -> Vec<(String, String)> {
    d.withdrawn
        .iter()
        .map(|w| {
            eprintln!(
                "{name}: withdrawn {} because {}; params {:?} ± {:?}",
                w.finding.kind, w.reason, w.finding.params, w.finding.uncertainty
            );
            (w.finding.kind.to_string(), w.reason.clone())
        })
        .collect()
}

fn real_logs() -> Vec<PathBuf> {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let mut out = Vec::new();
    for dir in [
        root.join("../shared/reference/real-axis-logs"),
        root.join("tests/data/real-extra"),
    ] {
        let Ok(rd) = std::fs::read_dir(&dir) else {
            eprintln!("skipped: {} not found", dir.display());
            continue;
        };
        let mut v: Vec<PathBuf> = rd
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|x| x == "csv"))
            .collect();
        v.sort();
        out.extend(v);
    }
    let grid = root.join("../shared/reference/real-2d-grids/aerotech_planarhd_cz1.csv");
    if grid.exists() {
        out.push(grid);
    }
    out
}

fn name(p: &Path) -> String {
    p.file_name()
        .map_or_else(String::new, |n| n.to_string_lossy().into())
}

#[test]
fn real_logs_print_only_sane_numbers() {
    let logs = real_logs();
    // tests/data/real-extra/ alone holds 12.
    assert!(logs.len() >= 12, "{} real logs", logs.len());
    let model = StageModel::paper_default().unwrap();
    let results = random::par_map(&logs, |p| {
        let log = read_file(p).unwrap();
        let d = diagnose(&log, &model, &DiagnoseOptions::default()).unwrap();
        let n = name(p);
        eprintln!(
            "{n}: {} finding(s), {} withdrawn",
            d.findings.len(),
            d.withdrawn.len()
        );
        let w = withdrawn_of(&n, &d);
        let bad: Vec<String> = problems(&log, &d)
            .into_iter()
            .map(|s| format!("{n}: {s}"))
            .collect();
        if !bad.is_empty() {
            eprintln!("{}", d.to_text());
        }
        (bad, w.len())
    });
    let withdrawn: usize = results.iter().map(|r| r.1).sum();
    let bad: Vec<String> = results.into_iter().flat_map(|r| r.0).collect();
    eprintln!("{} real logs, {withdrawn} finding(s) withdrawn", logs.len());
    assert!(bad.is_empty(), "{bad:#?}");
}

/// Random stages in the sweep (each a log of the reduced characterization
/// plan, ≈ 2 s to diagnose): a third each of edge dents, model-generated
/// and physical stages.
const RANDOM_STAGES: u64 = 36;

/// A random stage with a random hidden effect of size 3–12× the noise
/// from `seed`: by `seed % 3`, a physical dent at an end of the travel
/// (its centre within half its width of the end, inside or out, on the
/// full or a short scan), a model-generated stage with an effect of a
/// random kind, or a physical stage with an effect of a random kind.
fn random_case(seed: u64) -> (String, MeasurementLog) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x5a4e_0000_0000_0031);
    let size = random::NOISE_UM * rng.gen_range(3.0..12.0);
    let mut plan = random::plan();
    let (name, sim) = match seed % 3 {
        1 => {
            let kind = random::MODEL_KINDS[rng.gen_range(0..random::MODEL_KINDS.len())];
            let (e, _) = random::model_effect(kind, size, seed);
            let truth = truth_model(&random::random_model(seed), Some(&e), &plan, seed).unwrap();
            let sim = simulate_log(&truth, &plan, seed).unwrap();
            (format!("model {kind} seed {seed}"), sim)
        }
        k => {
            let (kind, edge) = if k == 0 {
                (0, true)
            } else {
                (rng.gen_range(0..random::PHYSICAL_KINDS.len()), false)
            };
            let (mut effect, _) = random::physical_effect(kind, size, seed);
            let short = edge && rng.gen::<bool>();
            if short {
                // A quarter of the travel on each axis.
                plan.x_range_um = [250.0, 2650.0];
                plan.y_range_um = [250.0, 1300.0];
                plan.x_scan_y_um = 800.0;
                plan.y_scan_x_um = 1400.0;
            }
            if let (
                true,
                PhysicalEffect::Dent {
                    axis,
                    position_um,
                    half_width_um,
                    ..
                },
            ) = (edge, &mut effect)
            {
                let [lo, hi] = match axis {
                    Axis::X => plan.x_range_um,
                    Axis::Y => plan.y_range_um,
                };
                let end = if rng.gen::<bool>() { lo } else { hi };
                *position_um = end + rng.gen_range(-0.5..0.5) * *half_width_um;
            }
            let mut stage = PhysicalStage::random(seed);
            stage.effects.push(effect);
            let sim = simulate_physical_log(&stage, &plan, seed).unwrap();
            let what = random::PHYSICAL_KINDS[kind];
            let at = match (edge, short) {
                (true, true) => " at an end of a short scan",
                (true, false) => " at an end",
                _ => "",
            };
            (format!("physical {what}{at} seed {seed}"), sim)
        }
    };
    (name, random::parsed(&sim))
}

#[test]
fn random_stages_print_only_sane_numbers() {
    let mut seeds: Vec<u64> = (0..RANDOM_STAGES).map(|s| 31_000 + s).collect();
    if let Ok(v) = std::env::var("MICROPOS_SEEDS") {
        seeds = v.split(',').filter_map(|s| s.trim().parse().ok()).collect();
    }
    let results = random::par_map(&seeds, |&seed| {
        let (name, log) = random_case(seed);
        let d = random::run_parsed(&log);
        eprintln!(
            "{name}: {} finding(s) {:?}, {} withdrawn",
            d.findings.len(),
            d.findings
                .iter()
                .map(|f| f.kind.to_string())
                .collect::<Vec<_>>(),
            d.withdrawn.len()
        );
        let w = withdrawn_of(&name, &d);
        let bad: Vec<String> = problems(&log, &d)
            .into_iter()
            .map(|s| format!("{name}: {s}"))
            .collect();
        if !bad.is_empty() || std::env::var("MICROPOS_SEEDS").is_ok() {
            eprintln!("{}", d.to_text());
        }
        (bad, w, d.findings.len())
    });
    let findings: usize = results.iter().map(|r| r.2).sum();
    let withdrawn: Vec<&(String, String)> = results.iter().flat_map(|r| &r.1).collect();
    eprintln!(
        "{} random stages: {findings} finding(s) reported, {} withdrawn: {withdrawn:?}",
        seeds.len(),
        withdrawn.len()
    );
    let bad: Vec<&String> = results.iter().flat_map(|r| &r.0).collect();
    assert!(bad.is_empty(), "{bad:#?}");
    // The sweep is not empty: most hidden effects are found (and so
    // checked).
    assert!(findings >= seeds.len() / 2, "{findings} findings");
}

#[test]
fn the_checks_catch_what_they_are_for() {
    // The parser and the checks on hand-written reports: each must fail
    // where the reports failed.
    let b = LogBounds {
        range: [(0.0, 1000.0), (0.0, 500.0)],
        p2p: [5.0, 5.0],
    };
    let block = |lines: &str| {
        text_findings(&format!(
            "header\n\nfinding 1: localized (x error, variable x)\n  x error has a local dip\n  likely cause: a dent\n{lines}  held-out rms x: 0.2 → 0.1 µm (50.0 % better, z = 9.0); model term `found1`\n\nextended model\n"
        ))
    };
    let sane = block("  amplitude_um                 -0.3000 ± 0.0100\n  position_um                500.0000 ± 2.0000\n  width_um                    40.0000 ± 3.0000\n");
    assert_eq!(sane.len(), 1);
    assert_eq!(sane[0].params.len(), 3, "{sane:?}");
    assert!(text_finding_problems(&sane[0], &b).is_empty());
    for bad in [
        "  position_um                500.0000 ± 30000000000000000.0000\n",
        "  position_um                -40.0000\n",
        "  position_um                500.0000 ± NaN\n",
        "  amplitude_um                 -0.3000 ± 7.0000\n",
    ] {
        let f = block(bad);
        assert!(
            !text_finding_problems(&f[0], &b).is_empty(),
            "passed: {bad}"
        );
    }
    // The contradiction: "zero at its first knot" beside −20.2.
    let table = |v0: &str| {
        format!("finding 1: reversal_varies (x error, variable x)\n  x's lost motion …: {v0} µm at 0.0 µm; at 0.0 µm the table is zero and T is the play `x_backlash` (+0.000 µm)\n  likely cause: wear\n  knot0_um                     0.0000\n  value0_um                  {v0} ± 0.5000\n  held-out rms x: 2.0 → 1.0 µm (50.0 % better, z = 9.0); model term `found1_x_reversal_table`\n")
    };
    let bad = table("-20.2000");
    assert_eq!(first_knot_problems(&bad, &text_findings(&bad)).len(), 1);
    let good = table("0.0000");
    assert!(first_knot_problems(&good, &text_findings(&good)).is_empty());
    // The play's correction against the table's own sentence.
    let play = "  x_backlash: fitted jointly with the reversal table `found1_x_reversal_table`, which is zero at its first knot (0.0 µm): this is the lost motion there\n";
    let both = format!("{play}\n{good}");
    assert!(first_knot_problems(&both, &text_findings(&both)).is_empty());
    let no_zero = good.replace("the table is zero and T is the play", "T is the play");
    let both = format!("{play}\n{no_zero}");
    assert_eq!(first_knot_problems(&both, &text_findings(&both)).len(), 1);
}
