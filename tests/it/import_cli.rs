//! `micropos import` end to end: the real ISO 230-2 example (mm, CSV) and
//! a `.dat`, written as logs `diagnose` reads as 1-D; bad input refused
//! with line and column and exit code 1.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn micropos() -> Command {
    Command::new(env!("CARGO_BIN_EXE_micropos"))
}

/// `micropos import INPUT --out OUT [EXTRA…]`, its output.
fn import(input: &Path, out: &Path, extra: &[&str]) -> Output {
    micropos()
        .arg("import")
        .arg(input)
        .arg("--out")
        .arg(out)
        .args(extra)
        .output()
        .unwrap()
}

#[test]
fn the_iso230_2_example_imports_and_diagnoses_as_one_axis() {
    let src = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/reference/iso230-2-example/encoder-vs-setpoint.csv");
    if !src.exists() {
        eprintln!("skipped: {} not found", src.display());
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("log.csv");
    let o = import(&src, &out, &[]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let o = micropos()
        .args(["diagnose", out.to_str().unwrap(), "--json"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let j: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(j["measured_axes"], serde_json::json!(["x"]));
    assert_eq!(j["measured_from"], "metadata");
    let x = &j["noise"]["components"][0];
    assert_eq!(x["replicated_targets"], 10);
    assert!(x["iso230_2"]["r_um"].as_f64().unwrap() > 0.0);
}

#[test]
fn a_dat_imports_and_bad_input_names_line_and_column() {
    let dir = tempfile::tempdir().unwrap();
    let dat = dir.path().join("t.dat");
    let mut text = String::from("UNIT=mm\n");
    for (i, t) in [10.0, 20.0, 30.0].iter().enumerate() {
        text += &format!("TGT_DATA[{}]={t}\n", i + 1);
        for c in 1..=2 {
            text += &format!("REF_DATA_FWD[{},{c}]={}\n", i + 1, t + 0.001);
            text += &format!("REF_DATA_BWD[{},{c}]={}\n", i + 1, t - 0.001);
        }
    }
    std::fs::write(&dat, text).unwrap();
    let out = dir.path().join("log.csv");
    let o = import(&dat, &out, &["--axis", "y"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let log = micropos::charact::log::read_file(&out).unwrap();
    assert_eq!(log.records.len(), 12);
    assert_eq!(log.records[0].segment, "scan_y");
    // Not overwritten.
    let o = import(&dat, &out, &[]);
    assert_eq!(o.status.code(), Some(1));
    let bad = dir.path().join("bad.csv");
    std::fs::write(
        &bad,
        "cycle;direction;target_mm;measured_mm\n1;fwd;1;1\n1;fwd;2;x\n",
    )
    .unwrap();
    let o = import(&bad, &dir.path().join("b.csv"), &[]);
    assert_eq!(o.status.code(), Some(1));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("line 3, column measured_mm"), "{err}");
}
