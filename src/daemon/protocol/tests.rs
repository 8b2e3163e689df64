//! Parser and reply tests: every command parses, refusals keep their code
//! and the `id`, replies are single lines; property tests over arbitrary
//! bytes and move numbers.

use super::*;
use proptest::prelude::*;
use serde_json::{json, Map, Value};

fn parse(s: &str) -> Result<Request, Refusal> {
    parse_request(s.as_bytes())
}

fn code(s: &str) -> ErrorCode {
    parse(s).unwrap_err().error.code
}

#[test]
fn drift_command_and_topic() {
    use crate::daemon::config::DriftMethodName;
    assert_eq!(
        parse(r#"{"cmd":"drift"}"#).unwrap().command,
        Command::Drift(DriftAction::Show)
    );
    assert_eq!(
        parse(r#"{"cmd":"drift","action":"set","method":"adaptive","every_s":60}"#)
            .unwrap()
            .command,
        Command::Drift(DriftAction::Set {
            method: Some(DriftMethodName::Adaptive),
            every_s: Some(60.0),
            time_constant_s: None,
        })
    );
    for (a, want) in [
        ("reset", DriftAction::Reset),
        ("measure", DriftAction::Measure),
    ] {
        assert_eq!(
            parse(&format!(r#"{{"cmd":"drift","action":"{a}"}}"#))
                .unwrap()
                .command,
            Command::Drift(want)
        );
    }
    for bad in [
        r#"{"cmd":"drift","action":"set","method":"kalman"}"#,
        r#"{"cmd":"drift","action":"set","every_s":0}"#,
        r#"{"cmd":"drift","action":"set","time_constant_s":-5}"#,
        r#"{"cmd":"drift","action":"undo"}"#,
        r#"{"cmd":"drift","every":5}"#,
    ] {
        assert_eq!(code(bad), ErrorCode::BadValue, "{bad}");
    }
    assert_eq!(
        parse(r#"{"cmd":"subscribe","topics":["drift"]}"#)
            .unwrap()
            .command,
        Command::Subscribe(vec![Topic::Drift])
    );
}

#[test]
fn figures_command() {
    assert_eq!(
        parse(r#"{"cmd":"figures"}"#).unwrap().command,
        Command::Figures(FiguresParams {
            job: FiguresJob::Characterize,
            log: None
        })
    );
    let r = parse(r#"{"id":9,"cmd":"figures","job":"validate","log":"v-1.csv"}"#).unwrap();
    assert_eq!(r.id, json!(9));
    assert_eq!(
        r.command,
        Command::Figures(FiguresParams {
            job: FiguresJob::Validate,
            log: Some("v-1.csv".to_owned())
        })
    );
    for (bad, want) in [
        (r#"{"cmd":"figures","job":"diagnose"}"#, ErrorCode::BadValue),
        (
            r#"{"cmd":"figures","log":"../etc/passwd"}"#,
            ErrorCode::BadValue,
        ),
        (r#"{"cmd":"figures","log":".hidden"}"#, ErrorCode::BadValue),
        (r#"{"cmd":"figures","log":""}"#, ErrorCode::BadValue),
        (r#"{"cmd":"figures","log":7}"#, ErrorCode::WrongType),
        (r#"{"cmd":"figures","job":true}"#, ErrorCode::WrongType),
        (r#"{"cmd":"figures","action":"list"}"#, ErrorCode::BadValue),
    ] {
        let refusal = parse(bad).unwrap_err();
        assert_eq!(refusal.error.code, want, "{bad}: {:?}", refusal.error);
    }
    // The refusal of an unknown job names the choices.
    let e = parse(r#"{"cmd":"figures","job":"diagnose"}"#).unwrap_err();
    assert!(
        e.error.message.contains("characterize, validate"),
        "{}",
        e.error.message
    );
    assert!(COMMANDS.contains(&"figures"));
}

#[test]
fn parses_every_command() {
    assert_eq!(
        parse(r#"{"id":1,"cmd":"status"}"#).unwrap().command,
        Command::Status
    );
    let m = parse(r#"{"id":"a","cmd":"move","x_um":10.5,"wait":true}"#).unwrap();
    assert_eq!(m.id, json!("a"));
    assert_eq!(
        m.command,
        Command::Move(MoveRequest {
            x_um: Some(10.5),
            y_um: None,
            relative: false,
            mode: MoveMode::Raw,
            wait: true,
            tolerance_um: None,
            tool: None,
        })
    );
    assert_eq!(
        parse(r#"{"cmd":"reference","axes":"x"}"#).unwrap().command,
        Command::Reference(Axes::X)
    );
    assert_eq!(
        parse(r#"{"cmd":"subscribe","topics":["fault","fault"]}"#)
            .unwrap()
            .command,
        Command::Subscribe(vec![Topic::Fault])
    );
    assert!(matches!(
        start_params(parse(r#"{"cmd":"characterize","action":"start","step_um":5,"cycles":2,"log":"run1.csv"}"#).unwrap().command),
        CharacterizeParams {
            step_um: Some(s),
            cycles: Some(2),
            ..
        } if s == 5.0
    ));
    assert!(matches!(
        start_params(parse(r#"{"cmd":"characterize","action":"start","drift_every_s":600,"drift_reference_um":[100,200.5]}"#).unwrap().command),
        CharacterizeParams {
            drift_every_s: Some(e),
            drift_reference_um: Some([x, y]),
            ..
        } if e == 600.0 && x == 100.0 && y == 200.5
    ));
    assert!(matches!(
        start_params(parse(r#"{"cmd":"characterize","action":"start","mode":"sweep","velocity_um_per_s":120,"uncorrected_log":"u.csv"}"#).unwrap().command),
        CharacterizeParams {
            mode: Some(CharacterizeMode::Sweep),
            velocity_um_per_s: Some(v),
            uncorrected_log: Some(u),
            ..
        } if v == 120.0 && u == "u.csv"
    ));
    assert!(matches!(
        start_params(parse(r#"{"cmd":"characterize","action":"start","mode":"sweep","anchor_spacing_um":500,"unanchored_log":"n.csv"}"#).unwrap().command),
        CharacterizeParams {
            anchor_spacing_um: Some(h),
            unanchored_log: Some(n),
            ..
        } if h == 500.0 && n == "n.csv"
    ));
    assert!(matches!(
        start_params(
            parse(r#"{"cmd":"characterize","action":"start","moves_per_cycle":40}"#)
                .unwrap()
                .command
        ),
        CharacterizeParams {
            moves_per_cycle: Some(40),
            ..
        }
    ));
    assert!(matches!(
        start_params(
            parse(r#"{"cmd":"characterize","action":"start","plan":"grid","pitch_um":250}"#)
                .unwrap()
                .command
        ),
        CharacterizeParams {
            plan: Some(CharacterizePlan::Grid),
            pitch_um: Some(p),
            ..
        } if p == 250.0
    ));
    for bad in [
        r#"{"cmd":"characterize","action":"start","plan":"spiral"}"#,
        r#"{"cmd":"characterize","action":"start","pitch_um":0}"#,
        r#"{"cmd":"characterize","action":"start","moves_per_cycle":-1}"#,
        r#"{"cmd":"characterize","action":"start","mode":"fly"}"#,
        r#"{"cmd":"characterize","action":"start","velocity_um_per_s":0}"#,
        r#"{"cmd":"characterize","action":"start","uncorrected_log":"../x.csv"}"#,
        r#"{"cmd":"characterize","action":"start","unanchored_log":"a/x.csv"}"#,
        r#"{"cmd":"characterize","action":"start","anchor_spacing_um":-5}"#,
        r#"{"cmd":"characterize","action":"start","drift_every_s":-1}"#,
        r#"{"cmd":"characterize","action":"start","drift_reference_um":[1]}"#,
        r#"{"cmd":"characterize","action":"start","drift_reference_um":[1,"a"]}"#,
        r#"{"cmd":"characterize","action":"start","drift_reference_um":5}"#,
    ] {
        assert!(parse(bad).is_err(), "{bad}");
    }
    assert_eq!(
        parse(r#"{"cmd":"characterize","action":"resume","log":"run1.csv"}"#)
            .unwrap()
            .command,
        Command::Characterize(CharacterizeAction::Resume {
            log: "run1.csv".into()
        })
    );
    assert_eq!(
        parse(r#"{"cmd":"tables"}"#).unwrap().command,
        Command::Tables(TablesAction::List)
    );
    for c in ["position", "stop", "config", "version", "validate"] {
        assert!(parse(&format!(r#"{{"cmd":"{c}"}}"#)).is_ok(), "{c}");
    }
    assert_eq!(parse(r#"{"cmd":"reset"}"#).unwrap().command, Command::Reset);
    assert_eq!(code(r#"{"cmd":"reset","axes":"x"}"#), ErrorCode::BadValue);
}

#[test]
fn refusals_have_stable_codes_and_keep_the_id() {
    assert_eq!(code("{"), ErrorCode::BadJson);
    assert_eq!(code("[1]"), ErrorCode::NotAnObject);
    assert_eq!(code(r#"{"id":1}"#), ErrorCode::MissingField);
    assert_eq!(code(r#"{"cmd":3}"#), ErrorCode::WrongType);
    assert_eq!(code(r#"{"cmd":"fly"}"#), ErrorCode::UnknownCommand);
    assert_eq!(code(r#"{"cmd":"move"}"#), ErrorCode::MissingField);
    assert_eq!(code(r#"{"cmd":"move","x_um":"1"}"#), ErrorCode::WrongType);
    assert_eq!(code(r#"{"cmd":"move","x_um":1e300}"#), ErrorCode::BadValue);
    assert_eq!(
        code(r#"{"cmd":"move","x_um":1,"speed":2}"#),
        ErrorCode::BadValue
    );
    assert_eq!(
        code(r#"{"cmd":"characterize","action":"resume","log":"../etc/passwd"}"#),
        ErrorCode::BadValue
    );
    assert_eq!(
        code(r#"{"cmd":"characterize","action":"start","cycles":0}"#),
        ErrorCode::BadValue
    );
    let r = parse(r#"{"id":{"k":[1]},"cmd":"nope"}"#).unwrap_err();
    assert_eq!(r.id, json!({"k":[1]}));
    assert!(r.error.message.contains("known: status"));
    let big = vec![b' '; MAX_REQUEST_BYTES + 1];
    assert_eq!(
        parse_request(&big).unwrap_err().error.code,
        ErrorCode::RequestTooLarge
    );
    assert_eq!(
        parse_request(&[0xff, b'{']).unwrap_err().error.code,
        ErrorCode::BadJson
    );
}

#[test]
fn replies_are_single_lines_that_echo_the_id() {
    let mut f = Map::new();
    f.insert("x".into(), json!(1.5));
    f.insert("ok".into(), json!("spoof"));
    let r = ok_reply(&json!(7), f);
    assert!(r.ends_with('\n') && !r[..r.len() - 1].contains('\n'));
    let v: Value = serde_json::from_str(&r).unwrap();
    assert_eq!(v, json!({"id":7,"ok":true,"x":1.5}));
    let e = error_reply(
        &json!("q"),
        &ProtoError::new(ErrorCode::OutOfTravel, "line\nbreak"),
    );
    assert_eq!(e.matches('\n').count(), 1);
    let v: Value = serde_json::from_str(&e).unwrap();
    assert_eq!(v["error"]["code"], "out_of_travel");
    assert_eq!(v["ok"], false);
    let ev: Value = serde_json::from_str(&event_line("fault", Map::new())).unwrap();
    assert_eq!(ev, json!({"event":"fault"}));
}

proptest! {
    #[test]
    fn any_bytes_give_a_request_or_a_refusal(bytes in proptest::collection::vec(any::<u8>(), 0..300)) {
        match parse_request(&bytes) {
            Ok(_) => {}
            Err(r) => {
                let line = error_reply(&r.id, &r.error);
                let v: Value = serde_json::from_str(&line).unwrap();
                prop_assert_eq!(&v["ok"], &Value::Bool(false));
            }
        }
    }

    #[test]
    fn move_numbers_round_trip(x in -1e6f64..1e6, rel: bool, wait: bool) {
        let s = json!({"id":1,"cmd":"move","x_um":x,"relative":rel,"wait":wait}).to_string();
        match parse(&s).unwrap().command {
            Command::Move(m) => {
                // serde_json's default float parser may be off by one
                // ULP (no float_roundtrip feature): 1e-10 µm here.
                let got = m.x_um.unwrap();
                prop_assert!((got - x).abs() <= 4.0 * f64::EPSILON * x.abs().max(1.0));
                prop_assert_eq!(m.relative, rel);
                prop_assert_eq!(m.wait, wait);
            }
            other => prop_assert!(false, "{other:?}"),
        }
    }
}

/// The parameters of a `characterize start` command (boxed in the command).
fn start_params(c: Command) -> CharacterizeParams {
    match c {
        Command::Characterize(CharacterizeAction::Start(p)) => *p,
        other => panic!("not a characterize start: {other:?}"),
    }
}

#[test]
fn repeated_keys_are_refused_naming_the_key() {
    for (line, key) in [
        (r#"{"cmd":"status","cmd":"move","x_um":1}"#, "cmd"),
        (r#"{"id":1,"cmd":"move","x_um":1,"x_um":2}"#, "x_um"),
        (r#"{"id":1,"id":2,"cmd":"status"}"#, "id"),
        (
            r#"{"cmd":"subscribe","topics":["drift"],"x":{"a":1,"a":1}}"#,
            "a",
        ),
    ] {
        let e = parse(line).unwrap_err().error;
        assert_eq!(e.code, ErrorCode::BadRequest, "{line}");
        assert!(
            e.message.contains(&format!("{key:?}")),
            "{line}: {}",
            e.message
        );
        let reply: Value = serde_json::from_str(&error_reply(&Value::Null, &e)).unwrap();
        assert_eq!(reply["error"]["code"], "bad_request");
    }
}

/// `tool`: a name, with an absolute planned target of both axes; each
/// misuse is refused with the reason.
#[test]
fn a_tool_move_is_absolute_planned_and_of_both_axes() {
    let m =
        parse(r#"{"cmd":"move","x_um":1,"y_um":2,"mode":"compensated","tool":"tip-2"}"#).unwrap();
    let Command::Move(mv) = &m.command else {
        panic!("a move: {m:?}");
    };
    assert_eq!(mv.tool.as_deref(), Some("tip-2"));
    for (line, says) in [
        (
            r#"{"cmd":"move","x_um":1,"mode":"compensated","tool":"t"}"#,
            "x_um and y_um",
        ),
        (r#"{"cmd":"move","x_um":1,"y_um":2,"tool":"t"}"#, "planned"),
        (
            r#"{"cmd":"move","x_um":1,"y_um":2,"mode":"closed_loop","relative":true,"tool":"t"}"#,
            "absolute",
        ),
        (
            r#"{"cmd":"move","x_um":1,"y_um":2,"mode":"compensated","tool":"a b"}"#,
            "[tools] name",
        ),
        (
            r#"{"cmd":"move","x_um":1,"y_um":2,"mode":"compensated","tool":3}"#,
            "string",
        ),
    ] {
        let e = parse(line).unwrap_err().error;
        assert!(e.message.contains(says), "{line}: {e:?}");
    }
}
