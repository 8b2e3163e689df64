//! `microposd --check-config` (systemd's `ExecStartPre=`, and what a
//! person runs after editing the file) on a typo'd key and a wrong-typed
//! value: the file, line and column, the key as the file writes it and,
//! for the typo, the key meant (issue 33: "at byte 217", no line, no
//! suggestion). The daemon's start reads the file the same way.

use std::process::Command;

const MIN: &str = "[driver.x]\nport = \"/dev/ttyUSB0\"\n[driver.y]\nport = \"/dev/ttyUSB1\"\n";

fn check(text: &str) -> (i32, String, std::path::PathBuf, tempfile::TempDir) {
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("microposd.toml");
    std::fs::write(&config, text).unwrap();
    let out = Command::new(crate::bins::microposd_bin())
        .arg("--config")
        .arg(&config)
        .arg("--check-config")
        .output()
        .unwrap();
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stderr).into_owned(),
        config,
        dir,
    )
}

#[test]
fn a_typo_and_a_wrong_type_are_named_with_file_line_column_and_key() {
    let (code, stderr, config, _dir) = check(&format!(
        "{MIN}\n[camera]\nperiod_um = 4.0\npixl_um = 0.4\n"
    ));
    assert_eq!(code, 2, "{stderr}");
    let want = format!(
        "microposd: {}:8:1: config key [camera].pixl_um: unknown field `pixl_um` (did you mean `pixel_um`?)",
        config.display()
    );
    assert!(stderr.starts_with(&want), "want {want:?}\n got {stderr:?}");
    assert!(!stderr.contains("byte"), "{stderr}");

    let (code, stderr, config, _dir) = check(&format!("{MIN}[safety]\nhalt_wait_s = \"5\"\n"));
    assert_eq!(code, 2, "{stderr}");
    let want = format!(
        "microposd: {}:6:15: config key [safety].halt_wait_s: invalid type: string \"5\", expected a number",
        config.display()
    );
    assert!(stderr.starts_with(&want), "want {want:?}\n got {stderr:?}");

    // A value the checks after parsing refuse: located by its key.
    let (code, stderr, config, _dir) = check(&format!("{MIN}[camera]\nbits = 40\n"));
    assert_eq!(code, 2, "{stderr}");
    let want = format!(
        "microposd: {}:6:1: config key [camera].bits: must be within 4..=12",
        config.display()
    );
    assert!(stderr.starts_with(&want), "want {want:?}\n got {stderr:?}");
}
