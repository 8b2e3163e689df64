//! `microposd --check-config` judges the `[web]` section's token file as
//! part of the configuration: a group-readable or missing token file is a
//! bad configuration (exit 2, the key and the fix named), a private one
//! passes. Why a process test: systemd's `ExecStartPre=` runs exactly this
//! before the daemon starts.

use std::os::unix::fs::PermissionsExt;
use std::process::Command;

const MIN: &str = "[driver.x]\nport = \"/dev/ttyUSB0\"\n[driver.y]\nport = \"/dev/ttyUSB1\"\n";

fn check(config: &std::path::Path) -> (i32, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_microposd"))
        .arg("--config")
        .arg(config)
        .arg("--check-config")
        .output()
        .unwrap();
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn the_token_file_is_checked_with_the_configuration() {
    let dir = tempfile::tempdir().unwrap();
    let token = dir.path().join("web-token");
    std::fs::write(&token, "c4ca4238a0b923820dcc509a6f75849b\n").unwrap();
    let config = dir.path().join("microposd.toml");
    std::fs::write(
        &config,
        format!(
            "{MIN}[web]\nlisten = \"127.0.0.1:0\"\ncontrol = true\ntoken_file = \"{}\"\n",
            token.display()
        ),
    )
    .unwrap();

    std::fs::set_permissions(&token, std::fs::Permissions::from_mode(0o640)).unwrap();
    let (code, stderr) = check(&config);
    assert_eq!(code, 2, "{stderr}");
    assert!(
        stderr.contains("[web].token_file") && stderr.contains("chmod 600"),
        "{stderr}"
    );

    std::fs::set_permissions(&token, std::fs::Permissions::from_mode(0o600)).unwrap();
    let (code, stderr) = check(&config);
    assert_eq!(code, 0, "{stderr}");

    std::fs::remove_file(&token).unwrap();
    let (code, stderr) = check(&config);
    assert_eq!(code, 2, "{stderr}");
    assert!(stderr.contains("[web].token_file"), "{stderr}");

    // control without any token is refused by the plain validation.
    std::fs::write(&config, format!("{MIN}[web]\ncontrol = true\n")).unwrap();
    let (code, stderr) = check(&config);
    assert_eq!(code, 2, "{stderr}");
    assert!(stderr.contains("[web].control"), "{stderr}");
}
