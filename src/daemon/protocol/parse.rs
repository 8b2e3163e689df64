//! One request line into a typed [`Request`] or a [`Refusal`] that keeps the
//! `id` when it was readable; command by command, unknown fields refused.
//!
//! Why a file of its own: this is the only code that reads client bytes
//! (fuzzed by `fuzz/fuzz_targets/socket_request.rs`).

use serde_json::{Map, Value};

use super::command::{
    Axes, CharacterizeAction, CharacterizeParams, Command, DriftAction, FiguresJob, FiguresParams,
    MoveMode, MoveRequest, Refusal, Request, TablesAction, TablesBuildParams, Topic,
    ValidateAction, ValidateMode, ValidateParams, COMMANDS,
};
use super::fields::{
    check_file_name, opt_bool, opt_count, opt_f64, opt_f64_within, opt_str, opt_xy, req_str,
    truncate, type_name, unknown_word, wrong_type,
};
use super::schema::{command_schema, unknown_action, CommandSchema};
use super::strict::{parse_strict, StrictError};
use super::words::{
    build_needs_log, load_needs_name, resume_needs_log, ValidateTest, Word, TABLE_KINDS,
};
use super::{ErrorCode, ProtoError, MAX_REQUEST_BYTES};

/// Parses one request line (without its newline).
pub fn parse_request(line: &[u8]) -> Result<Request, Refusal> {
    let refuse = |id: Value, error| Refusal { id, error };
    if line.len() > MAX_REQUEST_BYTES {
        return Err(refuse(Value::Null, too_large(line.len())));
    }
    let text = std::str::from_utf8(line).map_err(|e| {
        refuse(
            Value::Null,
            ProtoError::new(
                ErrorCode::BadJson,
                format!("request is not UTF-8 (byte {})", e.valid_up_to()),
            ),
        )
    })?;
    let value = parse_strict(text).map_err(|e| {
        refuse(
            Value::Null,
            match e {
                StrictError::Json(e) => {
                    ProtoError::new(ErrorCode::BadJson, format!("request is not JSON: {e}"))
                }
                StrictError::DuplicateKey(key) => ProtoError::new(
                    ErrorCode::BadRequest,
                    format!(
                        "key {:?} appears twice in one object; a request has each key once",
                        truncate(&key, 64)
                    ),
                ),
            },
        )
    })?;
    let Value::Object(obj) = value else {
        return Err(refuse(
            Value::Null,
            ProtoError::new(
                ErrorCode::NotAnObject,
                format!(
                    "a request is a JSON object like {{\"id\":1,\"cmd\":\"status\"}}, got {}",
                    type_name(&value)
                ),
            ),
        ));
    };
    let id = obj.get("id").cloned().unwrap_or(Value::Null);
    let command = parse_command(&obj).map_err(|e| refuse(id.clone(), e))?;
    Ok(Request { id, command })
}

/// The error for a line of `len` bytes over the limit.
pub fn too_large(len: usize) -> ProtoError {
    ProtoError::new(
        ErrorCode::RequestTooLarge,
        format!("request of {len} bytes exceeds the limit of {MAX_REQUEST_BYTES} bytes"),
    )
}

fn parse_command(obj: &Map<String, Value>) -> Result<Command, ProtoError> {
    let cmd = req_str(obj, "cmd")?;
    let Some(schema) = command_schema(cmd) else {
        return Err(ProtoError::new(
            ErrorCode::UnknownCommand,
            format!(
                "unknown command {:?}; known: {}",
                truncate(cmd, 64),
                COMMANDS.join(", ")
            ),
        ));
    };
    let known = schema.known_fields();
    for key in obj.keys() {
        if key != "id" && key != "cmd" && !known.contains(&key.as_str()) {
            return Err(ProtoError::new(
                ErrorCode::BadValue,
                format!(
                    "command {cmd} has no field {:?} (fields: {})",
                    truncate(key, 64),
                    if known.is_empty() {
                        "none".to_owned()
                    } else {
                        known.join(", ")
                    }
                ),
            ));
        }
    }
    Ok(match cmd {
        "status" => Command::Status,
        "position" => Command::Position,
        "stop" => Command::Stop,
        "reset" => Command::Reset,
        "config" => Command::Config,
        "version" => Command::Version,
        "move" => Command::Move(parse_move(obj)?),
        "reference" => Command::Reference(opt_word(obj, "axes")?.unwrap_or(Axes::Both)),
        "subscribe" => Command::Subscribe(parse_topics(obj)?),
        "characterize" => Command::Characterize(parse_characterize(obj, schema)?),
        "validate" => Command::Validate(parse_validate(obj, schema)?),
        "drift" => Command::Drift(parse_drift(obj, schema)?),
        "figures" => Command::Figures(parse_figures(obj)?),
        _ => Command::Tables(parse_tables(obj, schema)?),
    })
}
fn parse_move(obj: &Map<String, Value>) -> Result<MoveRequest, ProtoError> {
    let x_um = opt_f64(obj, "x_um")?;
    let y_um = opt_f64(obj, "y_um")?;
    if x_um.is_none() && y_um.is_none() {
        return Err(ProtoError::new(
            ErrorCode::MissingField,
            "move needs x_um, y_um or both",
        ));
    }
    let mode = opt_word(obj, "mode")?.unwrap_or(MoveMode::Raw);
    let tolerance_um = opt_f64(obj, "tolerance_um")?;
    if let Some(t) = tolerance_um {
        if t <= 0.0 {
            return Err(ProtoError::new(
                ErrorCode::BadValue,
                format!("tolerance_um must be positive, got {t}"),
            ));
        }
    }
    let relative = opt_bool(obj, "relative")?.unwrap_or(false);
    let tool = opt_str(obj, "tool")?.map(str::to_owned);
    if let Some(t) = &tool {
        check_tool_move(t, x_um.is_some() && y_um.is_some(), relative, mode)?;
    }
    Ok(MoveRequest {
        x_um,
        y_um,
        relative,
        mode,
        wait: opt_bool(obj, "wait")?.unwrap_or(false),
        tolerance_um,
        tool,
    })
}

/// A tool move names a tool point (1 to 64 of `A-Z a-z 0-9 _ -`, as
/// `[tools]` names them) and where it should be: both axes, absolute,
/// planned (its target goes through the tables' yaw).
fn check_tool_move(
    tool: &str,
    both_axes: bool,
    relative: bool,
    mode: MoveMode,
) -> Result<(), ProtoError> {
    let bad = |m: &str| Err(ProtoError::new(ErrorCode::BadValue, m.to_owned()));
    if tool.is_empty()
        || tool.len() > 64
        || !tool
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-')
    {
        return bad("tool must be a [tools] name: 1 to 64 of A-Z a-z 0-9 _ -");
    }
    if !both_axes {
        return bad("a tool move needs x_um and y_um: the tool's target is a point");
    }
    if relative {
        return bad("a tool move is absolute (relative is false)");
    }
    if mode == MoveMode::Raw {
        return bad("a tool move is planned: mode compensated or closed_loop");
    }
    Ok(())
}

fn parse_topics(obj: &Map<String, Value>) -> Result<Vec<Topic>, ProtoError> {
    let Some(v) = obj.get("topics") else {
        return Ok(Topic::ALL.to_vec());
    };
    let Value::Array(items) = v else {
        return Err(wrong_type("topics", "an array of strings", v));
    };
    let mut topics = Vec::new();
    for item in items {
        let Value::String(s) = item else {
            return Err(wrong_type("topics[]", "a string", item));
        };
        let t = Topic::from_word(s)?;
        if !topics.contains(&t) {
            topics.push(t);
        }
    }
    Ok(topics)
}

fn parse_characterize(
    obj: &Map<String, Value>,
    schema: &CommandSchema,
) -> Result<CharacterizeAction, ProtoError> {
    let action = action_word(obj, schema)?;
    let log = opt_str(obj, "log")?.map(str::to_owned);
    if let Some(l) = &log {
        check_file_name("log", l)?;
    }
    match action {
        "start" => {
            let positive = |k: &str| -> Result<Option<f64>, ProtoError> {
                match opt_f64(obj, k)? {
                    Some(v) if v <= 0.0 => Err(ProtoError::new(
                        ErrorCode::BadValue,
                        format!("{k} must be positive, got {v}"),
                    )),
                    v => Ok(v),
                }
            };
            let settle_s = opt_f64_within(obj, "settle_s", 0.0, 3600.0, "0..3600")?;
            let drift_every_s =
                opt_f64_within(obj, "drift_every_s", 0.0, 86_400.0, "0..86400 (0 = off)")?;
            Ok(CharacterizeAction::Start(Box::new(CharacterizeParams {
                log,
                axes: opt_word(obj, "axes")?,
                step_um: positive("step_um")?,
                x_range_um: positive("x_range_um")?,
                y_range_um: positive("y_range_um")?,
                cycles: opt_count(obj, "cycles", 1, 1000)?,
                frames_per_point: opt_count(obj, "frames_per_point", 1, 1000)?,
                settle_s,
                drift_every_s,
                drift_reference_um: opt_xy(obj, "drift_reference_um")?,
                mode: opt_word(obj, "mode")?,
                velocity_um_per_s: opt_f64_within(
                    obj,
                    "velocity_um_per_s",
                    1.0,
                    5000.0,
                    "1..5000",
                )?,
                uncorrected_log: match opt_str(obj, "uncorrected_log")? {
                    Some(l) => {
                        check_file_name("uncorrected_log", l)?;
                        Some(l.to_owned())
                    }
                    None => None,
                },
                unanchored_log: match opt_str(obj, "unanchored_log")? {
                    Some(l) => {
                        check_file_name("unanchored_log", l)?;
                        Some(l.to_owned())
                    }
                    None => None,
                },
                anchor_spacing_um: opt_f64_within(
                    obj,
                    "anchor_spacing_um",
                    0.0,
                    1e6,
                    "0..1000000 (0 = no anchors)",
                )?,
                moves_per_cycle: opt_count(obj, "moves_per_cycle", 0, 100_000)?,
                plan: opt_word(obj, "plan")?,
                pitch_um: positive("pitch_um")?,
                approach: opt_word(obj, "approach")?,
                order: opt_word(obj, "order")?,
            })))
        }
        "status" => Ok(CharacterizeAction::Status),
        "cancel" => Ok(CharacterizeAction::Cancel),
        "resume" => match log {
            Some(log) => Ok(CharacterizeAction::Resume { log }),
            None => Err(resume_needs_log()),
        },
        other => Err(unknown_action(schema.cmd, other)),
    }
}

fn parse_figures(obj: &Map<String, Value>) -> Result<FiguresParams, ProtoError> {
    let job = opt_word(obj, "job")?.unwrap_or(FiguresJob::Characterize);
    let log = match opt_str(obj, "log")? {
        Some(l) => {
            check_file_name("log", l)?;
            Some(l.to_owned())
        }
        None => None,
    };
    Ok(FiguresParams { job, log })
}

fn parse_drift(
    obj: &Map<String, Value>,
    schema: &CommandSchema,
) -> Result<DriftAction, ProtoError> {
    match action_word(obj, schema)? {
        "show" => Ok(DriftAction::Show),
        "reset" => Ok(DriftAction::Reset),
        "measure" => Ok(DriftAction::Measure),
        "set" => Ok(DriftAction::Set {
            method: opt_word(obj, "method")?,
            every_s: opt_f64_within(obj, "every_s", 0.001, 86_400.0, "0.001..86400")?,
            time_constant_s: opt_f64_within(obj, "time_constant_s", 1.0, 1e7, "1..10000000")?,
        }),
        other => Err(unknown_action(schema.cmd, other)),
    }
}

fn parse_validate(
    obj: &Map<String, Value>,
    schema: &CommandSchema,
) -> Result<ValidateAction, ProtoError> {
    match action_word(obj, schema)? {
        "start" => {
            let tests = opt_word(obj, "test")?.unwrap_or(ValidateTest::Both).tests();
            let modes = match obj.get("modes") {
                None | Some(Value::Null) => ValidateMode::ALL.to_vec(),
                Some(Value::Array(items)) => {
                    let mut modes = Vec::new();
                    for item in items {
                        let Value::String(m) = item else {
                            return Err(wrong_type("modes[]", "a string", item));
                        };
                        let m = ValidateMode::from_word(m)?;
                        if !modes.contains(&m) {
                            modes.push(m);
                        }
                    }
                    if modes.is_empty() {
                        return Err(ProtoError::new(
                            ErrorCode::BadValue,
                            "modes is empty; give at least one of raw, table, model, closed_loop",
                        ));
                    }
                    modes
                }
                Some(v) => return Err(wrong_type("modes", "an array of strings", v)),
            };
            let mut names = [None, None, None];
            for (slot, key) in names.iter_mut().zip(["log", "table", "model_table"]) {
                if let Some(n) = opt_str(obj, key)? {
                    check_file_name(key, n)?;
                    *slot = Some(n.to_owned());
                }
            }
            let [log, table, model_table] = names;
            let square_step_um = opt_f64_within(obj, "square_step_um", 1.0, 4000.0, "1..4000")?;
            let settle_s = opt_f64_within(obj, "settle_s", 0.0, 3600.0, "0..3600")?;
            Ok(ValidateAction::Start(ValidateParams {
                tests,
                modes,
                cycles: opt_count(obj, "cycles", 1, 1000)?,
                log,
                origin_x_um: opt_f64(obj, "origin_x_um")?,
                origin_y_um: opt_f64(obj, "origin_y_um")?,
                square_step_um,
                table,
                model_table,
                frames_per_point: opt_count(obj, "frames_per_point", 1, 1000)?,
                settle_s,
            }))
        }
        "status" => Ok(ValidateAction::Status),
        "cancel" => Ok(ValidateAction::Cancel),
        other => Err(unknown_action(schema.cmd, other)),
    }
}

fn parse_tables(
    obj: &Map<String, Value>,
    schema: &CommandSchema,
) -> Result<TablesAction, ProtoError> {
    let name = opt_str(obj, "name")?;
    match action_word(obj, schema)? {
        "list" => Ok(TablesAction::List),
        "load" => {
            let Some(name) = name else {
                return Err(load_needs_name());
            };
            check_file_name("name", name)?;
            Ok(TablesAction::Load {
                name: name.to_owned(),
            })
        }
        "activate" => Ok(TablesAction::Activate {
            name: name.map(str::to_owned),
        }),
        "build" => {
            let Some(log) = opt_str(obj, "log")? else {
                return Err(build_needs_log());
            };
            check_file_name("log", log)?;
            if let Some(n) = name {
                check_file_name("name", n)?;
            }
            let kinds = match obj.get("kinds") {
                // Empty: the log's own default (see TablesBuildParams::kinds).
                None | Some(Value::Null) => Vec::new(),
                Some(Value::Array(items)) => {
                    let mut kinds: Vec<String> = Vec::new();
                    for item in items {
                        match item {
                            Value::String(k) if TABLE_KINDS.contains(&k.as_str()) => {
                                if !kinds.contains(k) {
                                    kinds.push(k.clone());
                                }
                            }
                            Value::String(k) => {
                                return Err(unknown_word("table kind", k, &TABLE_KINDS.join(", ")))
                            }
                            other => return Err(wrong_type("kinds[]", "a string", other)),
                        }
                    }
                    if kinds.is_empty() {
                        return Err(ProtoError::new(ErrorCode::BadValue, "kinds is empty"));
                    }
                    kinds
                }
                Some(v) => return Err(wrong_type("kinds", "an array of strings", v)),
            };
            Ok(TablesAction::Build(TablesBuildParams {
                log: log.to_owned(),
                name: name.map(str::to_owned),
                kinds,
                activate: opt_bool(obj, "activate")?.unwrap_or(false),
            }))
        }
        other => Err(unknown_action(schema.cmd, other)),
    }
}

/// An optional keyword field: `None` when absent or null, else its word
/// read by [`Word::from_word`] (a wrong word refused with the type's
/// wording, a non-string as `wrong_type`).
fn opt_word<T: Word>(obj: &Map<String, Value>, key: &str) -> Result<Option<T>, ProtoError> {
    opt_str(obj, key)?.map(T::from_word).transpose()
}

/// The `action` word, or the command's default action when absent.
fn action_word<'a>(
    obj: &'a Map<String, Value>,
    schema: &CommandSchema,
) -> Result<&'a str, ProtoError> {
    Ok(opt_str(obj, "action")?
        .or(schema.default_action)
        .unwrap_or_default())
}
