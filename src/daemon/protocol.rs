//! The socket protocol, sans-IO: one request line in, one typed request or a
//! typed error out; replies and events serialized to one line each.
//!
//! Why hand-written parsing over `serde(deserialize)`: every refusal must
//! name the field and the problem with a stable error code, and a request
//! whose `id` is readable must get that `id` back even when the rest is
//! wrong. Nothing here does I/O; `fuzz/fuzz_targets/socket_request.rs`
//! drives [`parse_request`] with arbitrary bytes. Format: docs/socket-protocol.md.

use serde_json::{Map, Value};
use std::fmt;

/// Version of the protocol this daemon speaks (the `version` command reports
/// it; a client refuses a major version it does not know).
pub const PROTOCOL_VERSION: u32 = 1;

/// Longest request line accepted, bytes (without the newline). Larger
/// requests are answered with `request_too_large` and skipped.
pub const MAX_REQUEST_BYTES: usize = 64 * 1024;

/// Stable, machine-readable error codes (`"error": {"code": ...}`). Scripts
/// match on these; the message is for people and may change.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ErrorCode {
    /// The line is not valid JSON (or not UTF-8).
    BadJson,
    /// The line exceeds [`MAX_REQUEST_BYTES`].
    RequestTooLarge,
    /// The JSON is not an object.
    NotAnObject,
    /// A required field is missing.
    MissingField,
    /// A field has the wrong JSON type.
    WrongType,
    /// A field has the right type but an unusable value.
    BadValue,
    /// `cmd` names no command.
    UnknownCommand,
    /// A target is outside the soft limits or the controllers' travel.
    OutOfTravel,
    /// An axis is not referenced: positions are unknown, moves refused.
    NotReferenced,
    /// A controller is not connected.
    NotConnected,
    /// The rig is busy (a job or a reference run owns the axes).
    Busy,
    /// The move was halted by `stop` or a fault.
    Halted,
    /// The controller or its line failed during the command.
    DriverError,
    /// The camera gives no usable measurement.
    CameraUnavailable,
    /// The newest measurement is too old or of too low quality.
    StaleMeasurement,
    /// A closed-loop move did not converge within its retries.
    NotConverged,
    /// `compensated` move without an active compensation table.
    NoActiveTable,
    /// Closed loop: no fresh frame arrived after the move settled.
    CameraStalled,
    /// Closed loop: frames arrive but do not decode, or decode below
    /// `camera.min_quality`.
    LowQuality,
    /// Closed loop: the correction limit was reached outside tolerance.
    RetryLimit,
    /// Closed loop: the residual grew; the loop stopped instead of chasing it.
    Diverging,
    /// The feature exists in the protocol but not in this build yet.
    NotAvailable,
    /// No such job, or the job is not in a state that allows the action.
    JobState,
    /// The measurement log could not be created, read or resumed.
    LogError,
    /// The daemon is shutting down.
    ShuttingDown,
    /// A bug or an unexpected internal failure.
    Internal,
}

impl ErrorCode {
    /// The code as sent on the wire.
    pub fn as_str(self) -> &'static str {
        match self {
            ErrorCode::BadJson => "bad_json",
            ErrorCode::RequestTooLarge => "request_too_large",
            ErrorCode::NotAnObject => "not_an_object",
            ErrorCode::MissingField => "missing_field",
            ErrorCode::WrongType => "wrong_type",
            ErrorCode::BadValue => "bad_value",
            ErrorCode::UnknownCommand => "unknown_command",
            ErrorCode::OutOfTravel => "out_of_travel",
            ErrorCode::NotReferenced => "not_referenced",
            ErrorCode::NotConnected => "not_connected",
            ErrorCode::Busy => "busy",
            ErrorCode::Halted => "halted",
            ErrorCode::DriverError => "driver_error",
            ErrorCode::CameraUnavailable => "camera_unavailable",
            ErrorCode::StaleMeasurement => "stale_measurement",
            ErrorCode::NotConverged => "not_converged",
            ErrorCode::NoActiveTable => "no_active_table",
            ErrorCode::CameraStalled => "camera_stalled",
            ErrorCode::LowQuality => "low_quality",
            ErrorCode::RetryLimit => "retry_limit",
            ErrorCode::Diverging => "diverging",
            ErrorCode::NotAvailable => "not_available",
            ErrorCode::JobState => "job_state",
            ErrorCode::LogError => "log_error",
            ErrorCode::ShuttingDown => "shutting_down",
            ErrorCode::Internal => "internal",
        }
    }
}

impl fmt::Display for ErrorCode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// An error reply: a stable code and a message for a person.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{code}: {message}")]
pub struct ProtoError {
    /// Machine-readable code.
    pub code: ErrorCode,
    /// What went wrong and, where possible, what to do.
    pub message: String,
    /// Whether the same request may well succeed if simply tried again (a
    /// lost or garbled controller reply, a camera that delivered no
    /// decodable frame in time). Jobs retry these (`daemon.job_retries`);
    /// everything else is permanent. Not sent on the wire: the code says
    /// what happened, this only steers the daemon's own retries.
    pub transient: bool,
}

impl ProtoError {
    /// A permanent error with this code and message.
    pub fn new(code: ErrorCode, message: impl Into<String>) -> Self {
        Self {
            code,
            message: message.into(),
            transient: false,
        }
    }

    /// The same error marked transient (see [`ProtoError::transient`]).
    pub fn into_transient(mut self) -> Self {
        self.transient = true;
        self
    }
}

/// Which axes a command applies to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Axes {
    /// X only.
    X,
    /// Y only.
    Y,
    /// Both axes.
    Both,
}

impl Axes {
    /// Whether X is included.
    pub fn x(self) -> bool {
        matches!(self, Axes::X | Axes::Both)
    }
    /// Whether Y is included.
    pub fn y(self) -> bool {
        matches!(self, Axes::Y | Axes::Both)
    }
}

/// How a move reaches its target.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MoveMode {
    /// The controllers' own positioning, uncorrected.
    Raw,
    /// Targets corrected by the active compensation table.
    Compensated,
    /// Move, measure with the camera, correct the residual.
    ClosedLoop,
}

impl MoveMode {
    /// The mode as sent on the wire.
    pub fn as_str(self) -> &'static str {
        match self {
            MoveMode::Raw => "raw",
            MoveMode::Compensated => "compensated",
            MoveMode::ClosedLoop => "closed_loop",
        }
    }
}

/// A `move` request. Positions in µm, stage frame; `relative` moves are
/// offsets from the commanded target.
#[derive(Debug, Clone, PartialEq)]
pub struct MoveRequest {
    /// X target (or offset), µm; `None` leaves X where it is.
    pub x_um: Option<f64>,
    /// Y target (or offset), µm; `None` leaves Y where it is.
    pub y_um: Option<f64>,
    /// Offsets instead of absolute targets.
    pub relative: bool,
    /// How to get there.
    pub mode: MoveMode,
    /// Reply only once on target (otherwise once the controllers accepted).
    pub wait: bool,
    /// Closed loop: acceptable residual, µm.
    pub tolerance_um: Option<f64>,
}

impl MoveRequest {
    /// An absolute, uncompensated move of both axes that replies once on
    /// target: what jobs and drift references use to place the stage
    /// exactly where their plan says.
    pub fn raw_to(x_um: f64, y_um: f64) -> Self {
        MoveRequest {
            x_um: Some(x_um),
            y_um: Some(y_um),
            relative: false,
            mode: MoveMode::Raw,
            wait: true,
            tolerance_um: None,
        }
    }
}

/// Parameters of a characterization job; `None` = the configured default.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct CharacterizeParams {
    /// Log file name inside the daemon's data directory (no path).
    pub log: Option<String>,
    /// Axes to scan.
    pub axes: Option<Axes>,
    /// Step between points, µm.
    pub step_um: Option<f64>,
    /// Scan range of X, µm.
    pub x_range_um: Option<f64>,
    /// Scan range of Y, µm.
    pub y_range_um: Option<f64>,
    /// Forward + backward cycles per axis.
    pub cycles: Option<u32>,
    /// Frames averaged per point.
    pub frames_per_point: Option<u32>,
    /// Settle time after each move, s.
    pub settle_s: Option<f64>,
    /// Re-measure the drift reference every this many s of rig time; 0 = off.
    pub drift_every_s: Option<f64>,
    /// Drift reference point `[x, y]`, µm; default: the scan's start corner.
    pub drift_reference_um: Option<[f64; 2]>,
}

/// Sub-commands of `characterize`.
#[derive(Debug, Clone, PartialEq)]
pub enum CharacterizeAction {
    /// Start a new job.
    Start(CharacterizeParams),
    /// Progress of the current or last job.
    Status,
    /// Cancel the running job (the log stays resumable).
    Cancel,
    /// Continue a job from its log.
    Resume {
        /// Log file name inside the data directory.
        log: String,
    },
}

/// Sub-commands of `tables`.
#[derive(Debug, Clone, PartialEq)]
pub enum TablesAction {
    /// List known tables.
    List,
    /// Load a table file by name.
    Load {
        /// File name inside the data directory.
        name: String,
    },
    /// Make a loaded table the active one (`None` deactivates).
    Activate {
        /// Table name.
        name: Option<String>,
    },
    /// Build the paper's tables and a model table from a characterization
    /// log, write them into the data directory and load them.
    Build(TablesBuildParams),
}

/// Sub-commands of `drift` (live drift correction).
#[derive(Debug, Clone, PartialEq)]
pub enum DriftAction {
    /// The live drift state.
    Show,
    /// Change the method and/or the interval (unset fields stay).
    Set {
        /// `off`, `static` or `adaptive`.
        method: Option<crate::daemon::config::DriftMethodName>,
        /// Interval between re-measurements, s.
        every_s: Option<f64>,
        /// Adaptive forgetting time constant, s.
        time_constant_s: Option<f64>,
    },
    /// Forget the re-measurements (the next compensated move measures).
    Reset,
    /// Re-measure the reference now (with the active table).
    Measure,
}

/// Parameters of `tables build`.
#[derive(Debug, Clone, PartialEq)]
pub struct TablesBuildParams {
    /// The characterization log (file name in the data directory).
    pub log: String,
    /// Output name stem: writes `STEM-paper.toml` and `STEM-model.toml`
    /// (default: the log's stem).
    pub name: Option<String>,
    /// Which tables: `paper`, `model` (default both).
    pub kinds: Vec<String>,
    /// Activate the paper table (or the model table if only that is built).
    pub activate: bool,
}

/// How a validation mode moves to a pose.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ValidateMode {
    /// Plain controller moves.
    Raw,
    /// Compensated by the paper's lookup tables.
    Table,
    /// Compensated by a fitted stage model.
    Model,
    /// Compensated, then corrected on the camera.
    ClosedLoop,
}

impl ValidateMode {
    /// Every mode, in report order.
    pub const ALL: [ValidateMode; 4] = [
        ValidateMode::Raw,
        ValidateMode::Table,
        ValidateMode::Model,
        ValidateMode::ClosedLoop,
    ];

    /// The mode as sent on the wire.
    pub fn as_str(self) -> &'static str {
        match self {
            ValidateMode::Raw => "raw",
            ValidateMode::Table => "table",
            ValidateMode::Model => "model",
            ValidateMode::ClosedLoop => "closed_loop",
        }
    }
}

/// Parameters of `validate start`; `None` = the default.
#[derive(Debug, Clone, PartialEq)]
pub struct ValidateParams {
    /// `square`, `random` (in this order when both).
    pub tests: Vec<String>,
    /// Modes, in the order run.
    pub modes: Vec<ValidateMode>,
    /// Cycles per test and mode.
    pub cycles: Option<u32>,
    /// Log file name.
    pub log: Option<String>,
    /// Stage position of the paper's (0, 0), µm.
    pub origin_x_um: Option<f64>,
    /// Stage position of the paper's (0, 0), µm.
    pub origin_y_um: Option<f64>,
    /// Distance between square poses along a side, µm.
    pub square_step_um: Option<f64>,
    /// Lookup table file for mode `table` (loaded or in the data directory).
    pub table: Option<String>,
    /// Model table file for mode `model`.
    pub model_table: Option<String>,
    /// Frames averaged per pose.
    pub frames_per_point: Option<u32>,
    /// Settle time after each move, s.
    pub settle_s: Option<f64>,
}

/// Sub-commands of `validate`.
#[derive(Debug, Clone, PartialEq)]
pub enum ValidateAction {
    /// Start a validation run.
    Start(ValidateParams),
    /// Progress.
    Status,
    /// Cancel.
    Cancel,
}

/// Event topics a client can subscribe to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Topic {
    /// Positions at camera rate (and on each controller poll).
    Position,
    /// Job progress.
    Job,
    /// Faults and state changes.
    Fault,
    /// Live drift re-measurements and their failures.
    Drift,
}

impl Topic {
    /// The topic as sent on the wire.
    pub fn as_str(self) -> &'static str {
        match self {
            Topic::Position => "position",
            Topic::Job => "job",
            Topic::Fault => "fault",
            Topic::Drift => "drift",
        }
    }
}

/// One parsed command.
#[derive(Debug, Clone, PartialEq)]
pub enum Command {
    /// Daemon, rig and job state.
    Status,
    /// Positions from every source.
    Position,
    /// Move the stage.
    Move(MoveRequest),
    /// Halt everything now.
    Stop,
    /// Reference axes.
    Reference(Axes),
    /// Stream events on this connection.
    Subscribe(Vec<Topic>),
    /// Characterization job control.
    Characterize(CharacterizeAction),
    /// Validation job control.
    Validate(ValidateAction),
    /// Compensation tables.
    Tables(TablesAction),
    /// Live drift correction.
    Drift(DriftAction),
    /// The effective configuration.
    Config,
    /// Daemon and protocol version.
    Version,
}

/// Names of all commands, for `unknown_command` messages and docs.
pub const COMMANDS: &[&str] = &[
    "status",
    "position",
    "move",
    "stop",
    "reference",
    "subscribe",
    "characterize",
    "validate",
    "tables",
    "drift",
    "config",
    "version",
];

/// A parsed request: its `id` (echoed verbatim) and the command.
#[derive(Debug, Clone, PartialEq)]
pub struct Request {
    /// Whatever the client sent as `id` (`null` when absent).
    pub id: Value,
    /// What to do.
    pub command: Command,
}

/// A refused request: the `id` if it could be read (`null` otherwise) and
/// the error to send back.
#[derive(Debug, Clone, PartialEq)]
pub struct Refusal {
    /// The request's `id`, or `null`.
    pub id: Value,
    /// Why it was refused.
    pub error: ProtoError,
}

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
    let value: Value = serde_json::from_str(text).map_err(|e| {
        refuse(
            Value::Null,
            ProtoError::new(ErrorCode::BadJson, format!("request is not JSON: {e}")),
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
        "status" | "position" | "stop" | "config" | "version" => &[],
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
        "config" => Command::Config,
        "version" => Command::Version,
        "move" => Command::Move(parse_move(obj)?),
        "reference" => Command::Reference(opt_axes(obj, "axes")?.unwrap_or(Axes::Both)),
        "subscribe" => Command::Subscribe(parse_topics(obj)?),
        "characterize" => Command::Characterize(parse_characterize(obj)?),
        "validate" => Command::Validate(parse_validate(obj)?),
        "drift" => Command::Drift(parse_drift(obj)?),
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
            return Err(ProtoError::new(
                ErrorCode::BadValue,
                format!(
                    "mode {:?} unknown; use raw, compensated or closed_loop",
                    truncate(other, 64)
                ),
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
            other => {
                return Err(ProtoError::new(
                    ErrorCode::BadValue,
                    format!(
                        "topic {:?} unknown; use position, job, fault, drift",
                        truncate(other, 64)
                    ),
                ))
            }
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
            Ok(CharacterizeAction::Start(CharacterizeParams {
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
            }))
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
        other => Err(ProtoError::new(
            ErrorCode::BadValue,
            format!(
                "characterize action {:?} unknown; use start, status, cancel, resume",
                truncate(other, 64)
            ),
        )),
    }
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
                Some(m) => {
                    return Err(ProtoError::new(
                        ErrorCode::BadValue,
                        format!(
                            "drift method {:?} unknown; use off, static or adaptive",
                            truncate(m, 64)
                        ),
                    ))
                }
            };
            Ok(DriftAction::Set {
                method,
                every_s: opt_f64_within(obj, "every_s", 0.001, 86_400.0, "0.001..86400")?,
                time_constant_s: opt_f64_within(obj, "time_constant_s", 1.0, 1e7, "1..10000000")?,
            })
        }
        other => Err(ProtoError::new(
            ErrorCode::BadValue,
            format!(
                "drift action {:?} unknown; use show, set, reset, measure",
                truncate(other, 64)
            ),
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
                test => {
                    return Err(ProtoError::new(
                        ErrorCode::BadValue,
                        format!(
                            "test {:?} unknown; use square, random or both",
                            truncate(test, 64)
                        ),
                    ))
                }
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
                                ProtoError::new(
                                    ErrorCode::BadValue,
                                    format!(
                                        "mode {:?} unknown; use raw, table, model, closed_loop",
                                        truncate(m, 64)
                                    ),
                                )
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
        other => Err(ProtoError::new(
            ErrorCode::BadValue,
            format!(
                "validate action {:?} unknown; use start, status, cancel",
                truncate(other, 64)
            ),
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
                None | Some(Value::Null) => vec!["paper".to_owned(), "model".to_owned()],
                Some(Value::Array(items)) => {
                    let mut kinds: Vec<String> = Vec::new();
                    for item in items {
                        match item {
                            Value::String(k) if k == "paper" || k == "model" => {
                                if !kinds.contains(k) {
                                    kinds.push(k.clone());
                                }
                            }
                            Value::String(k) => {
                                return Err(ProtoError::new(
                                    ErrorCode::BadValue,
                                    format!(
                                        "table kind {:?} unknown; use paper, model",
                                        truncate(k, 64)
                                    ),
                                ))
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
        other => Err(ProtoError::new(
            ErrorCode::BadValue,
            format!(
                "tables action {:?} unknown; use list, load, activate, build",
                truncate(other, 64)
            ),
        )),
    }
}

/// File names from clients stay inside the data directory: no separators,
/// no `..`, no hidden files, printable and short.
fn check_file_name(field: &str, name: &str) -> Result<(), ProtoError> {
    let ok = !name.is_empty()
        && name.len() <= 128
        && !name.starts_with('.')
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.'));
    if ok {
        Ok(())
    } else {
        Err(ProtoError::new(
            ErrorCode::BadValue,
            format!(
                "{field} {:?} must be a plain file name (letters, digits, - _ .; no path, not hidden)",
                truncate(name, 64)
            ),
        ))
    }
}

fn req_str<'a>(obj: &'a Map<String, Value>, key: &str) -> Result<&'a str, ProtoError> {
    match obj.get(key) {
        None => Err(ProtoError::new(
            ErrorCode::MissingField,
            format!("field {key} is missing"),
        )),
        Some(Value::String(s)) => Ok(s),
        Some(v) => Err(wrong_type(key, "a string", v)),
    }
}

fn opt_str<'a>(obj: &'a Map<String, Value>, key: &str) -> Result<Option<&'a str>, ProtoError> {
    match obj.get(key) {
        None | Some(Value::Null) => Ok(None),
        Some(Value::String(s)) => Ok(Some(s)),
        Some(v) => Err(wrong_type(key, "a string", v)),
    }
}

fn opt_bool(obj: &Map<String, Value>, key: &str) -> Result<Option<bool>, ProtoError> {
    match obj.get(key) {
        None | Some(Value::Null) => Ok(None),
        Some(Value::Bool(b)) => Ok(Some(*b)),
        Some(v) => Err(wrong_type(key, "true or false", v)),
    }
}

/// A finite number within ±1e9 (µm or s): anything else is a typo.
fn opt_f64(obj: &Map<String, Value>, key: &str) -> Result<Option<f64>, ProtoError> {
    match obj.get(key) {
        None | Some(Value::Null) => Ok(None),
        Some(Value::Number(n)) => match n.as_f64() {
            Some(v) if v.is_finite() && v.abs() <= 1e9 => Ok(Some(v)),
            _ => Err(ProtoError::new(
                ErrorCode::BadValue,
                format!("{key} = {n} is out of range (|value| ≤ 1e9)"),
            )),
        },
        Some(v) => Err(wrong_type(key, "a number", v)),
    }
}

/// An optional number that must lie in `lo..=hi`; `shown` is the range as
/// the error message states it.
fn opt_f64_within(
    obj: &Map<String, Value>,
    key: &str,
    lo: f64,
    hi: f64,
    shown: &str,
) -> Result<Option<f64>, ProtoError> {
    let v = opt_f64(obj, key)?;
    match v {
        Some(x) if !(lo..=hi).contains(&x) => Err(ProtoError::new(
            ErrorCode::BadValue,
            format!("{key} must be within {shown}, got {x}"),
        )),
        _ => Ok(v),
    }
}

fn opt_count(
    obj: &Map<String, Value>,
    key: &str,
    min: u64,
    max: u64,
) -> Result<Option<u32>, ProtoError> {
    match obj.get(key) {
        None | Some(Value::Null) => Ok(None),
        Some(Value::Number(n)) => match n.as_u64() {
            Some(v) if (min..=max).contains(&v) => Ok(Some(v as u32)),
            _ => Err(ProtoError::new(
                ErrorCode::BadValue,
                format!("{key} = {n} must be an integer within {min}..={max}"),
            )),
        },
        Some(v) => Err(wrong_type(key, "an integer", v)),
    }
}

/// An optional `[x, y]` pair of finite numbers, µm.
fn opt_xy(obj: &Map<String, Value>, key: &str) -> Result<Option<[f64; 2]>, ProtoError> {
    let Some(v) = obj.get(key) else {
        return Ok(None);
    };
    match v
        .as_array()
        .map(|a| a.iter().map(Value::as_f64).collect::<Vec<_>>())
    {
        Some(a) if a.len() == 2 => match (a[0], a[1]) {
            (Some(x), Some(y)) if x.is_finite() && y.is_finite() => Ok(Some([x, y])),
            _ => Err(wrong_type(key, "two finite numbers [x, y]", v)),
        },
        _ => Err(wrong_type(key, "an array [x, y] of two numbers", v)),
    }
}

fn opt_axes(obj: &Map<String, Value>, key: &str) -> Result<Option<Axes>, ProtoError> {
    match opt_str(obj, key)? {
        None => Ok(None),
        Some("x") => Ok(Some(Axes::X)),
        Some("y") => Ok(Some(Axes::Y)),
        Some("xy") | Some("both") => Ok(Some(Axes::Both)),
        Some(other) => Err(ProtoError::new(
            ErrorCode::BadValue,
            format!("{key} {:?} unknown; use x, y or xy", truncate(other, 64)),
        )),
    }
}

fn wrong_type(key: &str, expected: &str, got: &Value) -> ProtoError {
    ProtoError::new(
        ErrorCode::WrongType,
        format!("{key} must be {expected}, got {}", type_name(got)),
    )
}

fn type_name(v: &Value) -> &'static str {
    match v {
        Value::Null => "null",
        Value::Bool(_) => "a boolean",
        Value::Number(_) => "a number",
        Value::String(_) => "a string",
        Value::Array(_) => "an array",
        Value::Object(_) => "an object",
    }
}

fn truncate(s: &str, max_chars: usize) -> String {
    s.chars().take(max_chars).collect()
}

/// A success reply: `{"id":…,"ok":true, …fields}` plus newline.
pub fn ok_reply(id: &Value, fields: Map<String, Value>) -> String {
    let mut obj = Map::new();
    obj.insert("id".to_owned(), id.clone());
    obj.insert("ok".to_owned(), Value::Bool(true));
    for (k, v) in fields {
        if k != "id" && k != "ok" {
            obj.insert(k, v);
        }
    }
    line(Value::Object(obj))
}

/// An error reply: `{"id":…,"ok":false,"error":{"code":…,"message":…}}`.
pub fn error_reply(id: &Value, e: &ProtoError) -> String {
    let mut err = Map::new();
    err.insert("code".to_owned(), Value::from(e.code.as_str()));
    err.insert("message".to_owned(), Value::from(e.message.clone()));
    let mut obj = Map::new();
    obj.insert("id".to_owned(), id.clone());
    obj.insert("ok".to_owned(), Value::Bool(false));
    obj.insert("error".to_owned(), Value::Object(err));
    line(Value::Object(obj))
}

/// A pushed event: `{"event":name, …fields}` plus newline.
pub fn event_line(name: &str, fields: Map<String, Value>) -> String {
    let mut obj = Map::new();
    obj.insert("event".to_owned(), Value::from(name));
    for (k, v) in fields {
        if k != "event" {
            obj.insert(k, v);
        }
    }
    line(Value::Object(obj))
}

fn line(v: Value) -> String {
    // Serializing a Value cannot fail (string keys, no non-finite floats:
    // serde_json turns those into null).
    let mut s = v.to_string();
    s.push('\n');
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use serde_json::json;

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
                tolerance_um: None
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
            parse(r#"{"cmd":"characterize","action":"start","step_um":5,"cycles":2,"log":"run1.csv"}"#)
                .unwrap()
                .command,
            Command::Characterize(CharacterizeAction::Start(CharacterizeParams {
                step_um: Some(s),
                cycles: Some(2),
                ..
            })) if s == 5.0
        ));
        assert!(matches!(
            parse(r#"{"cmd":"characterize","action":"start","drift_every_s":600,"drift_reference_um":[100,200.5]}"#)
                .unwrap()
                .command,
            Command::Characterize(CharacterizeAction::Start(CharacterizeParams {
                drift_every_s: Some(e),
                drift_reference_um: Some([x, y]),
                ..
            })) if e == 600.0 && x == 100.0 && y == 200.5
        ));
        for bad in [
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
}
