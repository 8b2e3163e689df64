//! Property tests of `micropos import` (`charact::import`): an ISO 230-2
//! test written as a CSV or a `.dat` imports to a log whose records carry
//! the same targets, readings (µm, to the log's 0.1 nm), directions and
//! cycles; arbitrary bytes never panic.

use micropos::charact::import::{import_bytes, ImportFormat, ImportOptions, Unit};
use micropos::charact::log::parse_bytes;
use micropos::model::Axis;
use proptest::prelude::*;

fn config(cases: u32) -> ProptestConfig {
    ProptestConfig {
        cases,
        failure_persistence: None,
        rng_algorithm: proptest::test_runner::RngAlgorithm::ChaCha,
        rng_seed: proptest::test_runner::RngSeed::Fixed(0x6973_6f5f_696d_7072),
        ..ProptestConfig::default()
    }
}

/// An ISO 230-2 test: distinct targets (mm), cycles, and one deviation
/// (mm) per target, cycle and direction.
fn test_plan() -> impl Strategy<Value = (Vec<f64>, u32, Vec<f64>)> {
    (
        prop::collection::btree_set(-50_000i32..50_000, 2..7),
        1u32..6,
    )
        .prop_flat_map(|(targets, cycles)| {
            let t: Vec<f64> = targets.into_iter().map(|v| f64::from(v) * 1e-3).collect();
            let n = t.len() * cycles as usize * 2;
            (
                Just(t),
                Just(cycles),
                prop::collection::vec(-0.5f64..0.5, n..=n),
            )
        })
}

/// `(cycle, direction, target_mm, reading_mm)` in the standard's order.
fn arrivals(targets: &[f64], cycles: u32, dev: &[f64]) -> Vec<(u32, f64, f64, f64)> {
    let mut out = Vec::new();
    let mut k = 0;
    for c in 1..=cycles {
        for dir in [1.0, -1.0] {
            let order: Vec<&f64> = if dir > 0.0 {
                targets.iter().collect()
            } else {
                targets.iter().rev().collect()
            };
            for &t in order {
                out.push((c, dir, t, t + dev[k]));
                k += 1;
            }
        }
    }
    out
}

fn check(bytes: &[u8], want: &[(u32, f64, f64, f64)], axis: Axis) {
    let log = parse_bytes(bytes).unwrap();
    assert_eq!(log.records.len(), want.len());
    assert_eq!(log.metadata.get("measured_axes"), Some(axis.as_str()));
    for (r, &(c, dir, t, m)) in log.records.iter().zip(want) {
        let (rt, rm, ot, om) = match axis {
            Axis::X => (r.x_target_um, r.x_meas_um, r.y_target_um, r.y_meas_um),
            Axis::Y => (r.y_target_um, r.y_meas_um, r.x_target_um, r.x_meas_um),
        };
        assert_eq!(r.cycle, c);
        assert_eq!(r.extra[0], if dir > 0.0 { "fwd" } else { "bwd" });
        assert!((rt - t * 1e3).abs() < 1e-4, "{rt} vs {t} mm");
        assert!((rm - m * 1e3).abs() < 1e-4, "{rm} vs {m} mm");
        assert_eq!((ot, om), (0.0, 0.0));
    }
}

proptest! {
    #![proptest_config(config(64))]

    #[test]
    fn csv_round_trips((targets, cycles, dev) in test_plan(), y in any::<bool>()) {
        let want = arrivals(&targets, cycles, &dev);
        let mut csv = String::from("cycle,direction,target_mm,measured_mm\n");
        for &(c, dir, t, m) in &want {
            csv += &format!("{c},{},{t},{m}\n", if dir > 0.0 { "forward" } else { "backward" });
        }
        let axis = if y { Axis::Y } else { Axis::X };
        let opts = ImportOptions { axis, ..ImportOptions::default() };
        check(&import_bytes(csv.as_bytes(), &opts).unwrap(), &want, axis);
    }

    #[test]
    fn dat_round_trips((targets, cycles, dev) in test_plan()) {
        let want = arrivals(&targets, cycles, &dev);
        let mut dat = String::from("UNIT=mm\n");
        // Target indices in reverse position order: the order is by position.
        let n = targets.len();
        for (i, t) in targets.iter().enumerate() {
            dat += &format!("TGT_DATA[{}]={t}\n", n - i);
        }
        for &(c, dir, t, m) in &want {
            let i = n - targets.iter().position(|&v| v == t).unwrap();
            let key = if dir > 0.0 { "REF_DATA_FWD" } else { "REF_DATA_BWD" };
            dat += &format!("{key}[{i},{c}]={m}\n");
        }
        let opts = ImportOptions { format: ImportFormat::Dat, ..ImportOptions::default() };
        check(&import_bytes(dat.as_bytes(), &opts).unwrap(), &want, Axis::X);
    }

    #[test]
    fn any_bytes_never_panic(data in prop::collection::vec(any::<u8>(), 0..400), fmt in 0u8..4) {
        let opts = ImportOptions {
            format: [ImportFormat::Auto, ImportFormat::Csv, ImportFormat::Dat, ImportFormat::Report]
                [usize::from(fmt)],
            units: Some(Unit::Mm),
            ..ImportOptions::default()
        };
        if let Ok(bytes) = import_bytes(&data, &opts) {
            prop_assert!(parse_bytes(&bytes).is_ok());
        }
    }

    #[test]
    fn csv_like_text_never_panics(lines in prop::collection::vec("[a-z0-9_,;.+ -]{0,30}", 0..8)) {
        let text = format!("cycle,direction,target_mm,measured_mm\n{}", lines.join("\n"));
        if let Ok(bytes) = import_bytes(text.as_bytes(), &ImportOptions::default()) {
            prop_assert!(parse_bytes(&bytes).is_ok());
        }
    }

    #[test]
    fn report_like_text_never_panics(
        heading in "(# (Forward|Backward|positive|x) [a-z ]{0,8})?",
        header in "[a-zA-Z_ ()\\[\\],0-9|]{0,60}",
        rows in prop::collection::vec("[0-9.| -]{0,40}", 0..6),
        wide in any::<bool>(),
    ) {
        let header = if wide {
            format!("i |tgt_pos(i) [mm]|ref_pos(i,1) [mm]|{header}")
        } else {
            format!("i (pos id)| j (cycle)| Tgt_pos(i,j) [mm] | Reference(i,j) [mm] |{header}")
        };
        let text = format!("{heading}\n{header}\n--- | --- | --- |\n{}\n", rows.join("\n"));
        if let Ok(bytes) = import_bytes(text.as_bytes(), &ImportOptions::default()) {
            prop_assert!(parse_bytes(&bytes).is_ok());
        }
    }
}
