//! The configuration's tests: defaults, every checked key, the shipped files.

use super::*;

const MIN: &str = "[driver.x]\nport = \"/dev/ttyUSB0\"\n[driver.y]\nport = \"/dev/ttyUSB1\"\n";

#[test]
fn minimal_file_gets_defaults() {
    let c = DaemonConfig::from_toml(MIN).unwrap();
    assert_eq!(
        c.daemon.socket,
        PathBuf::from("/run/micropos/micropos.sock")
    );
    assert_eq!(c.socket_mode().unwrap(), 0o660);
    assert_eq!(c.characterize.step_um, 5.0);
    assert_eq!(c.characterize.cycles, 3);
    assert!(c.camera_source().unwrap().is_none());
}

#[test]
fn errors_name_the_key() {
    let e = DaemonConfig::from_toml(&format!("{MIN}[characterize]\nstep_um = -1\n")).unwrap_err();
    assert_eq!(e.key, "characterize.step_um");
    let e =
        DaemonConfig::from_toml(&format!("{MIN}[daemon]\nsocket_mode = \"999\"\n")).unwrap_err();
    assert_eq!(e.key, "daemon.socket_mode");
    let e = DaemonConfig::from_toml(&format!("{MIN}[limits]\nx_min_um = 5\nx_max_um = 1\n"))
        .unwrap_err();
    assert_eq!(e.key, "limits.x_min_um");
    let e = DaemonConfig::from_toml(&format!("{MIN}[camera]\nsource = \"webcam\"\n")).unwrap_err();
    assert_eq!(e.key, "camera.source");
    let e = DaemonConfig::from_toml("[driver.x]\nport = \"/dev/a\"\n").unwrap_err();
    assert_eq!(e.key, "driver");
    let e = DaemonConfig::from_toml(&format!("{MIN}[daemon]\nsokcet = \"/x\"\n")).unwrap_err();
    assert!(e.problem.contains("sokcet"), "{e}");
    assert!(e.problem.contains("did you mean `socket`?"), "{e}");
}

/// Issue 33: a typo was reported "at byte 217". Now: the line and column,
/// the key as the file writes it (`[camera].pixl_um`), the key that was
/// probably meant; a wrong type in words; a bad value found by the checks
/// after parsing at its line too.
#[test]
fn errors_give_line_column_key_path_and_did_you_mean() {
    // MIN is lines 1-4.
    let e = DaemonConfig::from_toml(&format!("{MIN}[camera]\nperiod_um = 4.0\npixl_um = 0.4\n"))
        .unwrap_err();
    assert_eq!(e.key, "camera.pixl_um");
    assert_eq!(e.line_column, Some((7, 1)));
    let text = e.to_string();
    assert!(
        text.starts_with(
            "line 7, column 1: config key [camera].pixl_um: unknown field `pixl_um` (did you mean `pixel_um`?), expected one of"
        ),
        "{text}"
    );
    assert!(!text.contains("byte"), "{text}");

    let e = DaemonConfig::from_toml(&format!("{MIN}[daemon]\npoll_interval_ms = \"fast\"\n"))
        .unwrap_err();
    assert_eq!(e.key, "daemon.poll_interval_ms");
    assert_eq!(e.line_column, Some((6, 20)));
    assert!(e.problem.ends_with("expected a whole number ≥ 0"), "{e}");

    // A misspelt section, a misspelt value.
    let e = DaemonConfig::from_toml(&format!("{MIN}[camra]\nbits = 10\n")).unwrap_err();
    assert_eq!((e.key.as_str(), e.line_column), ("camra", Some((5, 2))));
    assert!(
        e.to_string()
            .contains("config key [camra]: unknown field `camra` (did you mean `camera`?)"),
        "{e}"
    );
    let e = DaemonConfig::from_toml(&format!("{MIN}[drift]\nmethod = \"adaptve\"\n")).unwrap_err();
    assert_eq!(e.key, "drift.method");
    assert!(e.problem.contains("(did you mean `adaptive`?)"), "{e}");

    // Found by `validate`, after parsing: located by its key.
    let e = DaemonConfig::from_toml(&format!(
        "{MIN}\n[characterize]\ncycles = 2\nstep_um = -1\n"
    ))
    .unwrap_err();
    assert_eq!(e.key, "characterize.step_um");
    assert_eq!(e.line_column, Some((8, 1)));

    // A syntax error: no key, still a line and column.
    let e = DaemonConfig::from_toml(&format!("{MIN}[camera\n")).unwrap_err();
    assert_eq!(e.key, "(syntax)");
    assert_eq!(e.line_column.map(|l| l.0), Some(5));
}

#[test]
fn compensation_approach_selects_the_backlash_strategy() {
    use crate::comp::ApproachPolicy;
    use crate::model::Direction;
    let c = DaemonConfig::from_toml(MIN).unwrap();
    assert_eq!(
        c.compensation.plan_options().policy,
        ApproachPolicy::DirectionAware
    );
    let c = DaemonConfig::from_toml(&format!(
        "{MIN}[compensation]\napproach = \"unidirectional\"\novershoot_um = 30\n"
    ))
    .unwrap();
    let o = c.compensation.plan_options();
    assert_eq!(
        o.policy,
        ApproachPolicy::Unidirectional([Direction::Forward, Direction::Forward])
    );
    assert_eq!(o.overshoot_um, 30.0);
    o.validate().unwrap();
    let e = DaemonConfig::from_toml(&format!("{MIN}[compensation]\napproach = \"sideways\"\n"))
        .unwrap_err();
    assert!(e.problem.contains("sideways"), "{e}");
    let e =
        DaemonConfig::from_toml(&format!("{MIN}[compensation]\novershoot_um = 1\n")).unwrap_err();
    assert_eq!(e.key, "compensation.overshoot_um");
}

#[test]
fn drift_section_defaults_off_and_is_checked() {
    use crate::analysis::drift::LiveMethod;
    let c = DaemonConfig::from_toml(MIN).unwrap();
    assert_eq!(c.drift.live_method(), LiveMethod::Off);
    let c = DaemonConfig::from_toml(&format!(
        "{MIN}[drift]\nmethod = \"adaptive\"\nevery_s = 60\ntime_constant_s = 600\n"
    ))
    .unwrap();
    assert_eq!(
        c.drift.live_method(),
        LiveMethod::Adaptive {
            time_constant_s: 600.0
        }
    );
    assert_eq!(c.drift.every_s, 60.0);
    for (text, key) in [
        ("every_s = 0", "drift.every_s"),
        ("time_constant_s = -1", "drift.time_constant_s"),
    ] {
        let e = DaemonConfig::from_toml(&format!("{MIN}[drift]\n{text}\n")).unwrap_err();
        assert_eq!(e.key, key);
    }
    let e = DaemonConfig::from_toml(&format!("{MIN}[drift]\nmethod = \"kalman\"\n")).unwrap_err();
    assert!(e.problem.contains("kalman"), "{e}");
}

#[test]
fn web_section_is_checked() {
    let c = DaemonConfig::from_toml(MIN).unwrap();
    assert_eq!(c.web, None);
    let c = DaemonConfig::from_toml(&format!("{MIN}[web]\n")).unwrap();
    let w = c.web.unwrap();
    assert_eq!(w.listen_addr().unwrap().to_string(), "127.0.0.1:8080");
    assert!(!w.control);
    assert_eq!(w.resolve_token().unwrap(), None);
    for (extra, key) in [
        ("listen = \"localhost\"", "web.listen"),
        ("role = \"root\"", "web.role"),
        ("control = true", "web.control"),
        ("control = true\ntoken = \"short\"", "web.token"),
        // 16 characters: too short.
        ("control = true\ntoken = \"0123456789abcdef\"", "web.token"),
        // Long enough, but 2 distinct characters: low-entropy.
        (
            "control = true\ntoken = \"abababababababababababababababab\"",
            "web.token",
        ),
        (
            "token = \"9f86d081884c7d659a2feaa0c55ad015a3bf4f1b2b0b822cd15d6c15b0f00a08\"\ntoken_file = \"/x\"",
            "web.token",
        ),
        ("camera_max_hz = 0", "web.camera_max_hz"),
        ("camera_max_px = 4", "web.camera_max_px"),
    ] {
        let e = DaemonConfig::from_toml(&format!("{MIN}[web]\n{extra}\n")).unwrap_err();
        assert_eq!(e.key, key, "{extra}: {e}");
    }
    let c = DaemonConfig::from_toml(&format!(
        "{MIN}[web]\ncontrol = true\ntoken = \"{STRONG}\"\nrole = \"read\"\n"
    ))
    .unwrap();
    let w = c.web.clone().unwrap();
    assert_eq!(w.resolve_token().unwrap().as_deref(), Some(STRONG));
    assert_eq!(w.role().unwrap(), crate::daemon::protocol::Role::Read);
    // The token never leaves through `config`.
    let shown = serde_json::to_string(&c).unwrap();
    assert!(!shown.contains(STRONG), "{shown}");
}

/// A token as `openssl rand -hex 32` writes one.
const STRONG: &str = "9f86d081884c7d659a2feaa0c55ad015a3bf4f1b2b0b822cd15d6c15b0f00a08";

#[test]
fn a_weak_web_token_is_refused_with_the_reason() {
    for (token, why) in [
        ("aaaaaaaaaaaaaaaa", "at least 32"),
        ("aaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaa", "distinct"),
        ("0123456789abcdef0123456789abcdef", "repeats a 16-character"),
        ("passwordpasswordpasswordpassword", "distinct"),
        ("abcdefghijklmnopaaaaaaaaaaaaaaaaaaaaaaaa", "one character"),
    ] {
        let e = DaemonConfig::from_toml(&format!(
            "{MIN}[web]\ncontrol = true\ntoken = \"{token}\"\n"
        ))
        .unwrap_err();
        assert_eq!(e.key, "web.token", "{token}: {e}");
        assert!(e.to_string().contains(why), "{token}: {e}");
    }
    assert!(DaemonConfig::from_toml(&format!(
        "{MIN}[web]\ncontrol = true\ntoken = \"{STRONG}\"\n"
    ))
    .is_ok());
}

#[test]
fn an_inline_token_in_a_readable_configuration_is_refused() {
    use std::os::unix::fs::PermissionsExt;
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("microposd.toml");
    std::fs::write(
        &path,
        format!("{MIN}[web]\ncontrol = true\ntoken = \"{STRONG}\"\n"),
    )
    .unwrap();
    for mode in [0o644, 0o640, 0o604] {
        std::fs::set_permissions(&path, std::fs::Permissions::from_mode(mode)).unwrap();
        let e = DaemonConfig::load(&path).unwrap_err();
        assert_eq!(e.key, "web.token", "{mode:o}: {e}");
        assert!(e.to_string().contains("token_file"), "{e}");
    }
    std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o600)).unwrap();
    assert!(DaemonConfig::load(&path).is_ok());
}

#[test]
fn web_token_file_must_be_private() {
    use std::os::unix::fs::PermissionsExt;
    let dir = tempfile::tempdir().unwrap();
    let f = dir.path().join("token");
    std::fs::write(&f, format!("{STRONG}\n")).unwrap();
    let w = WebSection {
        control: true,
        token_file: Some(f.clone()),
        ..WebSection::default()
    };
    std::fs::set_permissions(&f, std::fs::Permissions::from_mode(0o644)).unwrap();
    let e = w.resolve_token().unwrap_err();
    assert_eq!(e.key, "web.token_file");
    assert!(e.problem.contains("chmod 600"), "{e}");
    std::fs::set_permissions(&f, std::fs::Permissions::from_mode(0o600)).unwrap();
    assert_eq!(w.resolve_token().unwrap().as_deref(), Some(STRONG));
    let missing = WebSection {
        token_file: Some(dir.path().join("none")),
        ..w
    };
    assert_eq!(missing.resolve_token().unwrap_err().key, "web.token_file");
}

#[test]
fn access_and_client_limits_are_checked() {
    let c = DaemonConfig::from_toml(MIN).unwrap();
    assert_eq!(c.access, None);
    assert_eq!(c.daemon.stop_slots, 4);
    let c = DaemonConfig::from_toml(&format!(
        "{MIN}[access]\nread = [\"users\", \"1000\"]\noperate = [\"lab-ops\"]\n"
    ))
    .unwrap();
    let a = c.access.unwrap();
    assert_eq!(a.read, ["users", "1000"]);
    assert!(a.admin.is_empty());
    for (text, key) in [
        ("[access]\nread = [\"a b\"]", "access.read"),
        ("[access]\nadmin = [\"\"]", "access.admin"),
        ("[daemon]\nstop_slots = 0", "daemon.stop_slots"),
        ("[daemon]\nidle_timeout_s = -1", "daemon.idle_timeout_s"),
        ("[daemon]\nread_timeout_s = 0", "daemon.read_timeout_s"),
        ("[daemon]\nwrite_timeout_s = inf", "daemon.write_timeout_s"),
    ] {
        let e = DaemonConfig::from_toml(&format!("{MIN}{text}\n")).unwrap_err();
        assert_eq!(e.key, key, "{text}");
    }
    let e = DaemonConfig::from_toml(&format!("{MIN}[access]\nwrite = [\"x\"]\n")).unwrap_err();
    assert!(e.problem.contains("write"), "{e}");
}

/// `camera.pixel_um`: unset by default (the period is not checked), a
/// positive number when set; the simulated rig's config sets its camera's.
#[test]
fn camera_pixel_size_is_optional_and_checked() {
    assert_eq!(DaemonConfig::from_toml(MIN).unwrap().camera.pixel_um, None);
    let c = DaemonConfig::from_toml(&format!("{MIN}[camera]\npixel_um = 0.4\n")).unwrap();
    assert_eq!(c.camera.pixel_um, Some(0.4));
    for bad in ["0", "-0.4", "nan"] {
        let e = DaemonConfig::from_toml(&format!("{MIN}[camera]\npixel_um = {bad}\n")).unwrap_err();
        assert_eq!(e.key, "camera.pixel_um", "{bad}");
    }
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/microposd-sim.toml");
    assert_eq!(DaemonConfig::load(&p).unwrap().camera.pixel_um, Some(0.4));
}

#[test]
fn shipped_configs_are_valid() {
    for f in ["config/microposd.toml", "config/microposd-sim.toml"] {
        let p = Path::new(env!("CARGO_MANIFEST_DIR")).join(f);
        DaemonConfig::load(&p).unwrap_or_else(|e| panic!("{f}: {e}"));
    }
}

/// `[tools]`: several named tools, one active; each defect names its key,
/// an unknown key is refused.
#[test]
fn tools_are_named_checked_and_resolved() {
    let c = DaemonConfig::from_toml(MIN).unwrap();
    assert!(c.tools.points.is_empty());
    assert!(c.tools.resolve(None).unwrap_err().contains("none"));
    let text = format!(
        "{MIN}[tools]\nactive = \"tip\"\n[tools.points.tip]\noffset_um = [0.0, 20000.0]\n\
         [tools.points.jaw-2]\noffset_um = [-1500.0, 300.0]\n"
    );
    let c = DaemonConfig::from_toml(&text).unwrap();
    assert_eq!(
        c.tools.resolve(None).unwrap(),
        (
            "tip",
            ToolPoint {
                offset_um: [0.0, 20000.0]
            }
        )
    );
    assert_eq!(
        c.tools.resolve(Some("jaw-2")).unwrap().1.offset_um,
        [-1500.0, 300.0]
    );
    let e = c.tools.resolve(Some("pipette")).unwrap_err();
    assert!(e.contains("jaw-2, tip"), "{e}");
    for (body, key) in [
        (
            "active = \"x\"\n[tools.points.tip]\noffset_um = [0.0, 1.0]\n",
            "tools.active",
        ),
        (
            "[tools.points.tip]\noffset_um = [0.0, 2e6]\n",
            "tools.points.tip.offset_um",
        ),
        (
            "[tools.points.tip]\noffset_um = [0.0, nan]\n",
            "tools.points.tip.offset_um",
        ),
        (
            "[tools.points.\"a b\"]\noffset_um = [0.0, 1.0]\n",
            "tools.points",
        ),
    ] {
        let e = DaemonConfig::from_toml(&format!("{MIN}[tools]\n{body}")).unwrap_err();
        assert_eq!(e.key, key, "{body}: {e}");
    }
    let e = DaemonConfig::from_toml(&format!(
        "{MIN}[tools.points.tip]\noffset_um = [0.0, 1.0]\narm_um = 3\n"
    ))
    .unwrap_err();
    assert!(
        e.key.contains("arm_um") || e.to_string().contains("arm_um"),
        "{e}"
    );
}
