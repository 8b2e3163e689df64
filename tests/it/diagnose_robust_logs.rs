//! Real logs are not tidy: targets are missed, cycles are uneven, a
//! visit is wild, exports come in m, mm, µm or nm, as readings or as
//! deviations, with the approach spelled in many ways, sometimes with
//! times and sometimes without, and some are short. Whatever such a log
//! holds, `import` then `diagnose` must give a report or a clear error,
//! never a panic; and a log of at least 20 points gives a report.
//!
//! The logs are drawn by proptest (shrinkable dimensions, fixed seed) and
//! go through the user's path: an ISO 230-2 export (CSV or ecmc `.dat`) →
//! `import_bytes` → `parse_bytes` → `diagnose` against the paper's model
//! and against a one-axis model.

use micropos::analysis::{diagnose, DiagnoseOptions};
use micropos::charact::import::{import_bytes, ImportOptions};
use micropos::charact::log::parse_bytes;
use micropos::model::{Axis, StageModel};
use proptest::prelude::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const AXIS_MODEL: &str = r#"
format_version = 1
description = "one leadscrew axis: play and lead error"

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

fn config(cases: u32) -> ProptestConfig {
    ProptestConfig {
        cases,
        failure_persistence: None,
        rng_algorithm: proptest::test_runner::RngAlgorithm::ChaCha,
        rng_seed: proptest::test_runner::RngSeed::Fixed(0x726f_6275_7374_6c67),
        ..ProptestConfig::default()
    }
}

/// The shape of one messy test.
#[derive(Debug, Clone)]
struct Messy {
    targets: usize,
    cycles: u32,
    /// Fraction of arrivals left out (missed targets, aborted cycles).
    drop: f64,
    /// Wild visits (µm-to-mm spikes).
    outliers: usize,
    /// 0 m, 1 mm, 2 µm, 3 nm.
    unit: usize,
    /// Deviation column instead of a reading.
    deviation: bool,
    /// Spelling of the approach (index into `LABELS`).
    labels: usize,
    /// Only forward approaches.
    one_way: bool,
    /// A time column (else synthetic times).
    times: bool,
    /// An ecmc `.dat` instead of a CSV.
    dat: bool,
    seed: u64,
}

const LABELS: [(&str, &str); 5] = [
    ("fwd", "bwd"),
    ("forward", "backward"),
    ("up", "down"),
    ("+", "-"),
    ("1", "-1"),
];

fn messy() -> impl Strategy<Value = Messy> {
    (
        (1usize..12, 1u32..8, 0.0f64..0.4, 0usize..4, 0usize..4),
        (
            any::<bool>(),
            0usize..LABELS.len(),
            prop::bool::weighted(0.15),
            any::<bool>(),
            prop::bool::weighted(0.25),
            any::<u64>(),
        ),
    )
        .prop_map(
            |(
                (targets, cycles, drop, outliers, unit),
                (deviation, labels, one_way, times, dat, seed),
            )| {
                Messy {
                    targets,
                    cycles,
                    drop,
                    outliers,
                    unit,
                    deviation,
                    labels,
                    one_way,
                    times,
                    dat,
                    seed,
                }
            },
        )
}

/// `(bytes of the export, arrivals written)`.
fn export(m: &Messy) -> (Vec<u8>, usize) {
    let mut rng = ChaCha8Rng::seed_from_u64(m.seed);
    let (unit, um_per) = [("m", 1e6), ("mm", 1e3), ("um", 1.0), ("nm", 1e-3)][m.unit];
    let spacing_um = rng.gen_range(50.0..20_000.0);
    let first_um = rng.gen_range(-100_000.0..100_000.0);
    let targets: Vec<f64> = (0..m.targets)
        .map(|k| first_um + k as f64 * spacing_um * rng.gen_range(0.8..1.2))
        .collect();
    let sigma = rng.gen_range(0.01..5.0);
    let scale = rng.gen_range(-500.0..500.0) * 1e-6;
    let play = rng.gen_range(0.0..20.0);
    let mut rows: Vec<(u32, f64, f64, f64)> = Vec::new(); // (cycle, dir, target, dev)
                                                          // Cycle numbers as labs write them: not always 1, 2, 3 (a restarted
                                                          // test keeps counting).
    let cycle_step = rng.gen_range(1..4u32);
    for c in (1..=m.cycles).map(|c| 1 + (c - 1) * cycle_step) {
        for dir in if m.one_way {
            vec![1.0]
        } else {
            vec![1.0, -1.0]
        } {
            let order: Vec<f64> = if dir > 0.0 {
                targets.clone()
            } else {
                targets.iter().rev().copied().collect()
            };
            for t in order {
                if rng.gen::<f64>() < m.drop {
                    continue;
                }
                let e: f64 = (0..6).map(|_| rng.gen::<f64>() - 0.5).sum();
                rows.push((c, dir, t, scale * t - dir * play / 2.0 + sigma * e));
            }
        }
    }
    for _ in 0..m.outliers {
        if rows.is_empty() {
            break;
        }
        let k = rng.gen_range(0..rows.len());
        let sign = if rng.gen::<bool>() { 1.0 } else { -1.0 };
        rows[k].3 += sign * 10f64.powf(rng.gen_range(1.0..5.0));
    }
    let n = rows.len();
    if m.dat {
        // ecmc layout: readings per target index and cycle; a missing
        // arrival is simply not written.
        let mut s = format!("UNIT={unit}\nCYCLES={}\n", 1 + (m.cycles - 1) * cycle_step);
        for (k, t) in targets.iter().enumerate() {
            s.push_str(&format!("TGT_DATA[{}]={}\n", k + 1, t / um_per));
        }
        for (c, dir, t, dev) in &rows {
            let k = targets.iter().position(|q| q == t).unwrap_or(0) + 1;
            let key = if *dir > 0.0 {
                "REF_DATA_FWD"
            } else {
                "REF_DATA_BWD"
            };
            s.push_str(&format!("{key}[{k},{c}]={}\n", (t + dev) / um_per));
        }
        return (s.into_bytes(), n);
    }
    let value = if m.deviation { "deviation" } else { "measured" };
    let mut s = format!("target_{unit},{value}_{unit},direction,cycle");
    if m.times {
        s.push_str(",t_s");
    }
    s.push('\n');
    let (fwd, bwd) = LABELS[m.labels];
    let mut t_s = 0.0;
    for (c, dir, t, dev) in &rows {
        let v = if m.deviation { *dev } else { t + dev };
        s.push_str(&format!(
            "{},{},{},{c}",
            t / um_per,
            v / um_per,
            if *dir > 0.0 { fwd } else { bwd }
        ));
        if m.times {
            t_s += rng.gen_range(0.5..30.0);
            s.push_str(&format!(",{t_s:.3}"));
        }
        s.push('\n');
    }
    (s.into_bytes(), n)
}

proptest! {
    #![proptest_config(config(200))]

    #[test]
    fn messy_iso_exports_give_a_report_or_a_clear_error(m in messy()) {
        let (bytes, n) = export(&m);
        let axis = if m.seed % 3 == 0 { Axis::Y } else { Axis::X };
        let opts = ImportOptions { axis, ..ImportOptions::default() };
        let imported = match import_bytes(&bytes, &opts) {
            Ok(b) => b,
            Err(e) => {
                // Only an empty export may be refused; the message says why.
                prop_assert!(n == 0, "{e} for {m:?}");
                prop_assert!(!e.to_string().is_empty());
                return Ok(());
            }
        };
        let log = parse_bytes(&imported).map_err(|e| TestCaseError::fail(format!("{e}")))?;
        for model in [
            StageModel::paper_default().unwrap(),
            StageModel::from_toml(&AXIS_MODEL.replace("\"x\"", &format!("\"{axis}\""))).unwrap(),
        ] {
            match diagnose(&log, &model, &DiagnoseOptions::default()) {
                Ok(d) => {
                    let text = d.to_text();
                    prop_assert!(text.contains("not measured"), "{text}");
                    let json = d.to_json();
                    prop_assert!(json["findings"].is_array() && json["parameters"].is_array());
                    prop_assert_eq!(d.measured_axes.clone(), vec![axis]);
                    for f in &d.findings {
                        prop_assert_eq!(f.component, axis);
                        prop_assert!(f.heldout_rms_after_um.is_finite(), "{f:?}");
                    }
                }
                Err(e) => {
                    prop_assert!(log.records.len() < 20, "{e} on {} points: {m:?}", log.records.len());
                    prop_assert!(e.to_string().contains("20"), "{e}");
                }
            }
        }
    }
}
