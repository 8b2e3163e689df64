//! One request line into a typed [`Request`] or a [`Refusal`] that keeps the
//! `id` when it was readable; command by command, unknown fields refused.
//!
//! Why a file of its own: this is the only code that reads client bytes
//! (fuzzed by `fuzz/fuzz_targets/socket_request.rs`).

use serde_json::{Map, Value};

use super::command::{
    Axes, CharacterizeAction, CharacterizeMode, CharacterizeParams, CharacterizePlan, Command,
    DriftAction, FiguresJob, FiguresParams, GridApproach, GridOrder, MoveMode, MoveRequest,
    Refusal, Request, TablesAction, TablesBuildParams, Topic, ValidateAction, ValidateMode,
    ValidateParams, COMMANDS,
};
use super::fields::{
    check_file_name, opt_axes, opt_bool, opt_count, opt_f64, opt_f64_within, opt_str, opt_xy,
    req_str, truncate, type_name, unknown_word, wrong_type,
};
use super::strict::{parse_strict, StrictError};
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
    let known: &[&str] = match cmd {
        "status" | "position" | "stop" | "reset" | "config" | "version" => &[],
        "move" => &["x_um", "y_um", "relative", "mode", "wait", "tolerance_um"],
        "reference" => &["axes"],
        "subscribe" => &["topics"],
        "characterize" => &[
            "action",
            "log",
            "axes",
            "step_um",
            "x_range_um",
            "y_range_um",
            "cycles",
            "frames_per_point",
            "settle_s",
            "drift_every_s",
            "drift_reference_um",
            "mode",
            "velocity_um_per_s",
            "uncorrected_log",
            "unanchored_log",
            "anchor_spacing_um",
            "moves_per_cycle",
            "plan",
            "pitch_um",
            "approach",
            "order",
        ],
        "validate" => &[
            "action",
            "test",
            "modes",
            "cycles",
            "log",
            "origin_x_um",
            "origin_y_um",
            "square_step_um",
            "table",
            "model_table",
            "frames_per_point",
            "settle_s",
        ],
        "tables" => &["action", "name", "log", "kinds", "activate"],
        "drift" => &["action", "method", "every_s", "time_constant_s"],
        "figures" => &["job", "log"],
        other => {
            return Err(ProtoError::new(
                ErrorCode::UnknownCommand,
                format!(
                    "unknown command {:?}; known: {}",
                    truncate(other, 64),
                    COMMANDS.join(", ")
                ),
            ))
        }
    };
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
        "reference" => Command::Reference(opt_axes(obj, "axes")?.unwrap_or(Axes::Both)),
        "subscribe" => Command::Subscribe(parse_topics(obj)?),
        "characterize" => Command::Characterize(parse_characterize(obj)?),
        "validate" => Command::Validate(parse_validate(obj)?),
        "drift" => Command::Drift(parse_drift(obj)?),
        "figures" => Command::Figures(parse_figures(obj)?),
        _ => Command::Tables(parse_tables(obj)?),
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
    let mode = match opt_str(obj, "mode")? {
        None | Some("raw") => MoveMode::Raw,
        Some("compensated") => MoveMode::Compensated,
        Some("closed_loop") => MoveMode::ClosedLoop,
        Some(other) => {
            return Err(unknown_word(
                "mode",
                other,
                "raw, compensated or closed_loop",
            ))
        }
    };
    let tolerance_um = opt_f64(obj, "tolerance_um")?;
    if let Some(t) = tolerance_um {
        if t <= 0.0 {
            return Err(ProtoError::new(
                ErrorCode::BadValue,
                format!("tolerance_um must be positive, got {t}"),
            ));
        }
    }
    Ok(MoveRequest {
        x_um,
        y_um,
        relative: opt_bool(obj, "relative")?.unwrap_or(false),
        mode,
        wait: opt_bool(obj, "wait")?.unwrap_or(false),
        tolerance_um,
    })
}

fn parse_topics(obj: &Map<String, Value>) -> Result<Vec<Topic>, ProtoError> {
    let Some(v) = obj.get("topics") else {
        return Ok(vec![
            Topic::Position,
            Topic::Job,
            Topic::Fault,
            Topic::Drift,
        ]);
    };
    let Value::Array(items) = v else {
        return Err(wrong_type("topics", "an array of strings", v));
    };
    let mut topics = Vec::new();
    for item in items {
        let Value::String(s) = item else {
            return Err(wrong_type("topics[]", "a string", item));
        };
        let t = match s.as_str() {
            "position" => Topic::Position,
            "job" => Topic::Job,
            "fault" => Topic::Fault,
            "drift" => Topic::Drift,
            other => return Err(unknown_word("topic", other, "position, job, fault, drift")),
        };
        if !topics.contains(&t) {
            topics.push(t);
        }
    }
    Ok(topics)
}

fn parse_characterize(obj: &Map<String, Value>) -> Result<CharacterizeAction, ProtoError> {
    let action = opt_str(obj, "action")?.unwrap_or("status");
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
                axes: opt_axes(obj, "axes")?,
                step_um: positive("step_um")?,
                x_range_um: positive("x_range_um")?,
                y_range_um: positive("y_range_um")?,
                cycles: opt_count(obj, "cycles", 1, 1000)?,
                frames_per_point: opt_count(obj, "frames_per_point", 1, 1000)?,
                settle_s,
                drift_every_s,
                drift_reference_um: opt_xy(obj, "drift_reference_um")?,
                mode: match opt_str(obj, "mode")? {
                    None => None,
                    Some("step") => Some(CharacterizeMode::Step),
                    Some("sweep") => Some(CharacterizeMode::Sweep),
                    Some(other) => {
                        return Err(unknown_word("characterize mode", other, "step, sweep"))
                    }
                },
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
                plan: match opt_str(obj, "plan")? {
                    None => None,
                    Some("lines") => Some(CharacterizePlan::Lines),
                    Some("grid") => Some(CharacterizePlan::Grid),
                    Some(other) => {
                        return Err(unknown_word("characterize plan", other, "lines, grid"))
                    }
                },
                pitch_um: positive("pitch_um")?,
                approach: match opt_str(obj, "approach")? {
                    None => None,
                    Some("below") => Some(GridApproach::Below),
                    Some("both") => Some(GridApproach::Both),
                    Some(other) => return Err(unknown_word("grid approach", other, "below, both")),
                },
                order: match opt_str(obj, "order")? {
                    None => None,
                    Some("raster") => Some(GridOrder::Raster),
                    Some("serpentine") => Some(GridOrder::Serpentine),
                    Some(other) => {
                        return Err(unknown_word("grid order", other, "raster, serpentine"))
                    }
                },
            })))
        }
        "status" => Ok(CharacterizeAction::Status),
        "cancel" => Ok(CharacterizeAction::Cancel),
        "resume" => match log {
            Some(log) => Ok(CharacterizeAction::Resume { log }),
            None => Err(ProtoError::new(
                ErrorCode::MissingField,
                "characterize resume needs log (the file name of the job to continue)",
            )),
        },
        other => Err(unknown_word(
            "characterize action",
            other,
            "start, status, cancel, resume",
        )),
    }
}

fn parse_figures(obj: &Map<String, Value>) -> Result<FiguresParams, ProtoError> {
    let job = match opt_str(obj, "job")?.unwrap_or("characterize") {
        "characterize" => FiguresJob::Characterize,
        "validate" => FiguresJob::Validate,
        other => return Err(unknown_word("figures job", other, "characterize, validate")),
    };
    let log = match opt_str(obj, "log")? {
        Some(l) => {
            check_file_name("log", l)?;
            Some(l.to_owned())
        }
        None => None,
    };
    Ok(FiguresParams { job, log })
}

fn parse_drift(obj: &Map<String, Value>) -> Result<DriftAction, ProtoError> {
    use crate::daemon::config::DriftMethodName;
    match opt_str(obj, "action")?.unwrap_or("show") {
        "show" => Ok(DriftAction::Show),
        "reset" => Ok(DriftAction::Reset),
        "measure" => Ok(DriftAction::Measure),
        "set" => {
            let method = match opt_str(obj, "method")? {
                None => None,
                Some("off") => Some(DriftMethodName::Off),
                Some("static") => Some(DriftMethodName::Static),
                Some("adaptive") => Some(DriftMethodName::Adaptive),
                Some(m) => return Err(unknown_word("drift method", m, "off, static or adaptive")),
            };
            Ok(DriftAction::Set {
                method,
                every_s: opt_f64_within(obj, "every_s", 0.001, 86_400.0, "0.001..86400")?,
                time_constant_s: opt_f64_within(obj, "time_constant_s", 1.0, 1e7, "1..10000000")?,
            })
        }
        other => Err(unknown_word(
            "drift action",
            other,
            "show, set, reset, measure",
        )),
    }
}

fn parse_validate(obj: &Map<String, Value>) -> Result<ValidateAction, ProtoError> {
    match opt_str(obj, "action")?.unwrap_or("status") {
        "start" => {
            let tests = match opt_str(obj, "test")?.unwrap_or("both") {
                "square" => vec!["square".to_owned()],
                "random" => vec!["random".to_owned()],
                "both" => vec!["square".to_owned(), "random".to_owned()],
                test => return Err(unknown_word("test", test, "square, random or both")),
            };
            let modes = match obj.get("modes") {
                None | Some(Value::Null) => ValidateMode::ALL.to_vec(),
                Some(Value::Array(items)) => {
                    let mut modes = Vec::new();
                    for item in items {
                        let Value::String(m) = item else {
                            return Err(wrong_type("modes[]", "a string", item));
                        };
                        let m = ValidateMode::ALL
                            .into_iter()
                            .find(|k| k.as_str() == m)
                            .ok_or_else(|| {
                                unknown_word("mode", m, "raw, table, model, closed_loop")
                            })?;
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
        other => Err(unknown_word(
            "validate action",
            other,
            "start, status, cancel",
        )),
    }
}

fn parse_tables(obj: &Map<String, Value>) -> Result<TablesAction, ProtoError> {
    let name = opt_str(obj, "name")?;
    match opt_str(obj, "action")?.unwrap_or("list") {
        "list" => Ok(TablesAction::List),
        "load" => {
            let Some(name) = name else {
                return Err(ProtoError::new(
                    ErrorCode::MissingField,
                    "tables load needs name (a table file in the data directory)",
                ));
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
                return Err(ProtoError::new(
                    ErrorCode::MissingField,
                    "tables build needs log (a characterization log in the data directory)",
                ));
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
                            Value::String(k) if k == "paper" || k == "model" || k == "grid" => {
                                if !kinds.contains(k) {
                                    kinds.push(k.clone());
                                }
                            }
                            Value::String(k) => {
                                return Err(unknown_word("table kind", k, "paper, model, grid"))
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
        other => Err(unknown_word(
            "tables action",
            other,
            "list, load, activate, build",
        )),
    }
}
