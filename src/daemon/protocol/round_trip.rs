//! The typed requests and their wire form agree: every request kind, with
//! every optional field set or not, written by [`Request::to_json`] and read
//! back by [`parse_request`] is the same request, and writes only fields the
//! schema lists with the types it gives them; the schema file is current.
//!
//! Why this makes the field lists live in one place: a field added to a
//! parameter struct must be given a value here (the struct literals below
//! do not compile otherwise), is then lost unless `wire` writes it, and
//! refused unless `schema` lists it and the parser reads it.

use std::collections::BTreeSet;

use proptest::prelude::*;
use proptest::strategy::ValueTree;
use proptest::test_runner::TestRunner;
use serde_json::Value;

use super::*;
use crate::daemon::config::DriftMethodName;

/// A number of `lo..=hi` with at most three decimals (nm, ms): the values
/// a person types. Why not any f64: serde_json's default float parsing
/// (without its `float_roundtrip` feature) may miss the last bit of a
/// 17-digit number, which is a property of the JSON library, not of the
/// protocol's field lists.
fn num(lo: f64, hi: f64) -> impl Strategy<Value = f64> {
    ((lo * 1000.0) as i64..=(hi * 1000.0) as i64).prop_map(|n| n as f64 / 1000.0)
}

fn opt_num(lo: f64, hi: f64) -> impl Strategy<Value = Option<f64>> {
    proptest::option::of(num(lo, hi))
}

fn um() -> impl Strategy<Value = f64> {
    num(-1e9, 1e9)
}

fn file_name() -> impl Strategy<Value = String> {
    "[A-Za-z0-9_-][A-Za-z0-9_.-]{0,15}"
}

fn opt_file() -> impl Strategy<Value = Option<String>> {
    proptest::option::of(file_name())
}

fn word<T: Word + std::fmt::Debug>() -> impl Strategy<Value = T> {
    proptest::sample::select(T::ALL)
}

/// A non-empty list of distinct words in any order (the parser drops
/// repeats and refuses an empty `modes`).
fn some_words<T: Word + std::fmt::Debug>() -> impl Strategy<Value = Vec<T>> {
    proptest::sample::subsequence(T::ALL.to_vec(), 1..=T::ALL.len()).prop_shuffle()
}

fn count(lo: u32, hi: u32) -> impl Strategy<Value = Option<u32>> {
    proptest::option::of(lo..=hi)
}

fn move_request() -> impl Strategy<Value = MoveRequest> {
    (
        proptest::option::of(um()),
        proptest::option::of(um()),
        any::<bool>(),
        word::<MoveMode>(),
        any::<bool>(),
        opt_num(0.001, 1e9),
        proptest::option::of("[A-Za-z0-9_-]{1,64}"),
    )
        .prop_filter("move needs x_um or y_um", |m| {
            m.0.is_some() || m.1.is_some()
        })
        .prop_map(
            |(x_um, y_um, relative, mode, wait, tolerance_um, tool)| MoveRequest {
                x_um,
                y_um,
                relative,
                mode,
                wait,
                tolerance_um,
                // A tool move is absolute, planned, of both axes.
                tool: tool.filter(|_| {
                    x_um.is_some() && y_um.is_some() && !relative && mode != MoveMode::Raw
                }),
            },
        )
}

fn characterize_params() -> impl Strategy<Value = CharacterizeParams> {
    let scan = (
        opt_file(),
        proptest::option::of(word::<Axes>()),
        opt_num(0.001, 1e9),
        opt_num(0.001, 1e9),
        opt_num(0.001, 1e9),
        count(1, 1000),
        count(1, 1000),
        opt_num(0.0, 3600.0),
        opt_num(0.0, 86_400.0),
        proptest::option::of((um(), um()).prop_map(|(x, y)| [x, y])),
    );
    let sweep_and_grid = (
        proptest::option::of(word::<CharacterizeMode>()),
        opt_num(1.0, 5000.0),
        opt_file(),
        opt_file(),
        opt_num(0.0, 1e6),
        count(0, 100_000),
        proptest::option::of(word::<CharacterizePlan>()),
        opt_num(0.001, 1e9),
        proptest::option::of(word::<GridApproach>()),
        proptest::option::of(word::<GridOrder>()),
    );
    (scan, sweep_and_grid).prop_map(|(a, b)| CharacterizeParams {
        log: a.0,
        axes: a.1,
        step_um: a.2,
        x_range_um: a.3,
        y_range_um: a.4,
        cycles: a.5,
        frames_per_point: a.6,
        settle_s: a.7,
        drift_every_s: a.8,
        drift_reference_um: a.9,
        mode: b.0,
        velocity_um_per_s: b.1,
        uncorrected_log: b.2,
        unanchored_log: b.3,
        anchor_spacing_um: b.4,
        moves_per_cycle: b.5,
        plan: b.6,
        pitch_um: b.7,
        approach: b.8,
        order: b.9,
    })
}

fn validate_params() -> impl Strategy<Value = ValidateParams> {
    (
        word::<ValidateTest>(),
        some_words::<ValidateMode>(),
        count(1, 1000),
        opt_file(),
        proptest::option::of(um()),
        proptest::option::of(um()),
        opt_num(1.0, 4000.0),
        opt_file(),
        opt_file(),
        count(1, 1000),
        opt_num(0.0, 3600.0),
    )
        .prop_map(|v| ValidateParams {
            tests: v.0.tests(),
            modes: v.1,
            cycles: v.2,
            log: v.3,
            origin_x_um: v.4,
            origin_y_um: v.5,
            square_step_um: v.6,
            table: v.7,
            model_table: v.8,
            frames_per_point: v.9,
            settle_s: v.10,
        })
}

fn tables_action() -> impl Strategy<Value = TablesAction> {
    let kinds = proptest::sample::subsequence(TABLE_KINDS.to_vec(), 0..=TABLE_KINDS.len())
        .prop_shuffle()
        .prop_map(|k| k.into_iter().map(str::to_owned).collect::<Vec<_>>());
    prop_oneof![
        Just(TablesAction::List),
        file_name().prop_map(|name| TablesAction::Load { name }),
        opt_file().prop_map(|name| TablesAction::Activate { name }),
        (file_name(), opt_file(), kinds, any::<bool>()).prop_map(|(log, name, kinds, activate)| {
            TablesAction::Build(TablesBuildParams {
                log,
                name,
                kinds,
                activate,
            })
        }),
    ]
}

fn drift_action() -> impl Strategy<Value = DriftAction> {
    prop_oneof![
        Just(DriftAction::Show),
        Just(DriftAction::Reset),
        Just(DriftAction::Measure),
        (
            proptest::option::of(word::<DriftMethodName>()),
            opt_num(0.001, 86_400.0),
            opt_num(1.0, 1e7),
        )
            .prop_map(|(method, every_s, time_constant_s)| DriftAction::Set {
                method,
                every_s,
                time_constant_s,
            }),
    ]
}

fn command() -> impl Strategy<Value = Command> {
    let characterize = prop_oneof![
        characterize_params().prop_map(|p| CharacterizeAction::Start(Box::new(p))),
        Just(CharacterizeAction::Status),
        Just(CharacterizeAction::Cancel),
        file_name().prop_map(|log| CharacterizeAction::Resume { log }),
    ];
    let validate = prop_oneof![
        validate_params().prop_map(ValidateAction::Start),
        Just(ValidateAction::Status),
        Just(ValidateAction::Cancel),
    ];
    let topics =
        proptest::sample::subsequence(Topic::ALL.to_vec(), 0..=Topic::ALL.len()).prop_shuffle();
    prop_oneof![
        Just(Command::Status),
        Just(Command::Position),
        Just(Command::Stop),
        Just(Command::Reset),
        Just(Command::Config),
        Just(Command::Version),
        move_request().prop_map(Command::Move),
        word::<Axes>().prop_map(Command::Reference),
        topics.prop_map(Command::Subscribe),
        characterize.prop_map(Command::Characterize),
        validate.prop_map(Command::Validate),
        tables_action().prop_map(Command::Tables),
        drift_action().prop_map(Command::Drift),
        (word::<FiguresJob>(), opt_file())
            .prop_map(|(job, log)| Command::Figures(FiguresParams { job, log })),
    ]
}

fn request() -> impl Strategy<Value = Request> {
    let id = prop_oneof![
        Just(Value::Null),
        any::<i64>().prop_map(Value::from),
        "[a-z0-9]{0,8}".prop_map(Value::from),
    ];
    (id, command()).prop_map(|(id, command)| Request { id, command })
}

/// The fields a written request carries besides `id`, `cmd` and `action`,
/// each checked against the schema: `(cmd, action, field)`.
fn schema_fields_of(v: &Value) -> Result<Vec<(String, String, String)>, String> {
    let obj = v.as_object().ok_or("not an object")?;
    let cmd = obj["cmd"].as_str().ok_or("cmd is not a string")?;
    let schema = command_schema(cmd).ok_or(format!("{cmd} not in the schema"))?;
    let action = obj.get("action").and_then(Value::as_str);
    let mut seen = Vec::new();
    for (k, x) in obj {
        if matches!(k.as_str(), "id" | "cmd" | "action") {
            continue;
        }
        let field = schema
            .field(action, k)
            .ok_or(format!("{cmd} {action:?} writes {k}, not in the schema"))?;
        if !field.ty.admits(x) {
            return Err(format!("{cmd} {k} = {x} is not {:?}", field.ty));
        }
        seen.push((cmd.to_owned(), action.unwrap_or("").to_owned(), k.clone()));
    }
    Ok(seen)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]

    #[test]
    fn every_request_reads_back_as_written(req in request()) {
        let v = req.to_json();
        let mut line = v.to_string();
        prop_assert_eq!(parse_request(line.as_bytes()), Ok(req.clone()), "{}", line);
        line.push('\n');
        prop_assert_eq!(line.matches('\n').count(), 1);
        let checked = schema_fields_of(&v);
        prop_assert!(checked.is_ok(), "{:?}", checked);
    }
}

/// Every field of every action in the schema is written by some request:
/// a field listed but never sent (a parameter the types lost) fails here.
#[test]
fn every_schema_field_is_written_by_some_request() {
    let mut runner = TestRunner::deterministic();
    let strategy = request();
    let mut seen = BTreeSet::new();
    let mut actions = BTreeSet::new();
    for _ in 0..4000 {
        let Ok(tree) = strategy.new_tree(&mut runner) else {
            continue;
        };
        let v = tree.current().to_json();
        actions.insert((
            v["cmd"].as_str().unwrap_or("").to_owned(),
            v["action"].as_str().unwrap_or("").to_owned(),
        ));
        seen.extend(schema_fields_of(&v).unwrap_or_default());
    }
    for c in SCHEMA {
        let per_action: Vec<(&str, &[Field])> = if c.actions.is_empty() {
            vec![("", c.fields)]
        } else {
            c.actions.iter().map(|a| (a.name, a.fields)).collect()
        };
        for (action, fields) in per_action {
            assert!(
                actions.contains(&(c.cmd.to_owned(), action.to_owned())),
                "no request {} {action}",
                c.cmd
            );
            for f in fields {
                let key = (c.cmd.to_owned(), action.to_owned(), f.name.to_owned());
                assert!(seen.contains(&key), "never written: {key:?}");
            }
        }
    }
}

/// The parser knows exactly the schema's commands, and refuses an unknown
/// field naming the schema's list.
#[test]
fn the_parser_reads_the_schema_lists() {
    let names: Vec<&str> = SCHEMA.iter().map(|c| c.cmd).collect();
    assert_eq!(names, COMMANDS);
    let e = parse_request(br#"{"cmd":"tables","colour":1}"#).unwrap_err();
    assert_eq!(e.error.code, ErrorCode::BadValue);
    assert_eq!(
        e.error.message,
        "command tables has no field \"colour\" (fields: action, name, log, kinds, activate)"
    );
    let e = parse_request(br#"{"cmd":"characterize","action":"pause"}"#).unwrap_err();
    assert_eq!(
        e.error.message,
        "characterize action \"pause\" unknown; use start, status, cancel, resume"
    );
}

/// `docs/socket-schema.json` is what [`schema_json`] writes: the file other
/// clients' tests read cannot fall behind the types. `UPDATE_SCHEMA=1`
/// rewrites it.
#[test]
fn the_schema_file_is_current() {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/docs/socket-schema.json");
    let want = format!(
        "{}\n",
        serde_json::to_string_pretty(&schema_json()).expect("a Value serializes")
    );
    if std::env::var_os("UPDATE_SCHEMA").is_some() {
        std::fs::write(path, &want).expect("docs/ is writable");
    }
    let have = std::fs::read_to_string(path).unwrap_or_default();
    assert!(
        have == want,
        "docs/socket-schema.json is stale; rewrite it with \
         UPDATE_SCHEMA=1 cargo test -p micropos --lib protocol::round_trip"
    );
}

/// Every error code the reference lists is one of [`ErrorCode::ALL`] and
/// the reverse, so the schema's list of codes is the documented one.
#[test]
fn the_error_codes_are_the_documented_ones() {
    let doc = include_str!("../../../docs/socket-protocol.md");
    let start = doc.find("### Error codes").expect("the section exists");
    let end = start + doc[start..].find("\n## ").expect("a next section");
    let documented: BTreeSet<&str> = doc[start..end]
        .split('`')
        .skip(1)
        .step_by(2)
        .filter(|w| !w.is_empty() && w.chars().all(|c| c.is_ascii_lowercase() || c == '_'))
        .collect();
    let codes: BTreeSet<&str> = ErrorCode::ALL.iter().map(|c| c.as_str()).collect();
    assert_eq!(documented, codes);
}
