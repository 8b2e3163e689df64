//! `micropos simlog --extra-column`: the column lands in the log (with the
//! effect when asked), bad specifications fail with a message that names
//! the flag and says what is wrong, and nothing is written then.

use micropos::charact::log::read_file;
use std::path::Path;
use std::process::{Command, Output};

fn simlog(out: &Path, extra: &[&str]) -> Output {
    let mut c = Command::new(env!("CARGO_BIN_EXE_micropos"));
    c.args(["simlog", "--seed", "4", "--effect", "none", "--step", "200"])
        .arg("--out")
        .arg(out);
    for e in extra {
        c.args(["--extra-column", e]);
    }
    c.output().unwrap()
}

fn column(log: &micropos::charact::log::MeasurementLog, name: &str) -> Vec<f64> {
    let i = log
        .columns
        .extra
        .iter()
        .position(|c| c == name)
        .unwrap_or_else(|| panic!("no column {name}: {:?}", log.columns.extra));
    log.records
        .iter()
        .map(|r| r.extra[i].parse().unwrap())
        .collect()
}

#[test]
fn extra_columns_are_logged_and_can_carry_an_effect() {
    let dir = tempfile::tempdir().unwrap();
    let plain = dir.path().join("plain.csv");
    let o = simlog(&plain, &[]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let with = dir.path().join("with.csv");
    let o = simlog(&with, &["humidity_pct:x:0.5", "pressure_hpa"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let plain = read_file(&plain).unwrap();
    let with = read_file(&with).unwrap();
    assert_eq!(plain.records.len(), with.records.len());
    let h = column(&with, "humidity_pct");
    let p = column(&with, "pressure_hpa");
    assert_ne!(h, p, "each column has its own series");
    let mean = h.iter().sum::<f64>() / h.len() as f64;
    let spread = h.iter().fold(0.0f64, |m, v| m.max((v - mean).abs()));
    assert!(spread > 0.5, "the series wanders: {spread}");
    // x moves by 0.5 µm per unit of (value − mean); y and the rest do not.
    for ((a, b), v) in plain.records.iter().zip(&with.records).zip(&h) {
        let want = 0.5 * (v - mean);
        assert!(
            (b.x_meas_um - a.x_meas_um - want).abs() < 1e-3,
            "x {} → {}, want +{want}",
            a.x_meas_um,
            b.x_meas_um
        );
        assert!((b.y_meas_um - a.y_meas_um).abs() < 1e-9);
        assert_eq!(a.t_s, b.t_s);
    }
}

#[test]
fn bad_extra_columns_fail_clearly_and_write_nothing() {
    let dir = tempfile::tempdir().unwrap();
    for (i, (spec, why)) in [
        ("humidity_pct:z:0.5", "axis must be x or y"),
        ("humidity_pct:x:lots", "is not a number"),
        ("humidity_pct:x:NaN", "must be finite"),
        ("humidity_pct:x", "expected NAME or NAME:AXIS:UM_PER_UNIT"),
        ("", "the column name is empty"),
        // A standard column: the log format refuses it.
        ("x_meas_um", "--extra-column \"x_meas_um\""),
    ]
    .into_iter()
    .enumerate()
    {
        let out = dir.path().join(format!("bad{i}.csv"));
        let o = simlog(&out, &[spec]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{spec:?} was accepted");
        assert!(err.contains(why), "{spec:?}: {err}");
        assert!(!err.contains("panicked"), "{err}");
        assert!(!out.exists(), "{spec:?}: a log was written");
    }
    // The same name twice.
    let out = dir.path().join("twice.csv");
    let o = simlog(&out, &["h", "h"]);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("--extra-column \"h\""), "{err}");
    assert!(!out.exists());
}
