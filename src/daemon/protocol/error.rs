//! Stable error codes and the error a refusal carries.
//!
//! Why a file of its own: scripts match on these codes, so the list and
//! its wire spelling are the protocol's most stable part, used by the
//! parser and by every daemon module that refuses a request.

use std::fmt;

/// Stable, machine-readable error codes (`"error": {"code": ...}`). Scripts
/// match on these; the message is for people and may change.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ErrorCode {
    /// The line is not valid JSON (or not UTF-8).
    BadJson,
    /// The line exceeds [`MAX_REQUEST_BYTES`](super::MAX_REQUEST_BYTES).
    RequestTooLarge,
    /// The request is JSON but ambiguous: a key appears twice in one object
    /// (the message names it).
    BadRequest,
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
    /// A motion fault is latched (the message names it): motion commands
    /// are refused until a client sends `reset`.
    FaultLatched,
    /// The camera gives no usable measurement.
    CameraUnavailable,
    /// The newest measurement is too old or of too low quality.
    StaleMeasurement,
    /// A closed-loop move did not converge within its retries.
    NotConverged,
    /// `compensated` move without an active compensation table.
    NoActiveTable,
    /// A compensated target (a move or a validation pose) lies outside the
    /// area the table was characterized over, and `[compensation]
    /// outside_table = "refuse"`.
    OutsideTable,
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
    /// The client's role does not allow the command (`[access]`).
    PermissionDenied,
    /// The connection was closed for idling, or a request line stalled
    /// (`daemon.idle_timeout_s`, `daemon.read_timeout_s`).
    TimedOut,
    /// The daemon is shutting down.
    ShuttingDown,
    /// A bug or an unexpected internal failure.
    Internal,
}

impl ErrorCode {
    /// Every code, in the order the docs list them (the schema's list).
    pub const ALL: [ErrorCode; 31] = [
        ErrorCode::BadJson,
        ErrorCode::RequestTooLarge,
        ErrorCode::BadRequest,
        ErrorCode::NotAnObject,
        ErrorCode::MissingField,
        ErrorCode::WrongType,
        ErrorCode::BadValue,
        ErrorCode::UnknownCommand,
        ErrorCode::OutOfTravel,
        ErrorCode::NotReferenced,
        ErrorCode::NotConnected,
        ErrorCode::Busy,
        ErrorCode::Halted,
        ErrorCode::DriverError,
        ErrorCode::FaultLatched,
        ErrorCode::CameraUnavailable,
        ErrorCode::StaleMeasurement,
        ErrorCode::NotConverged,
        ErrorCode::NoActiveTable,
        ErrorCode::OutsideTable,
        ErrorCode::CameraStalled,
        ErrorCode::LowQuality,
        ErrorCode::RetryLimit,
        ErrorCode::Diverging,
        ErrorCode::NotAvailable,
        ErrorCode::JobState,
        ErrorCode::LogError,
        ErrorCode::PermissionDenied,
        ErrorCode::TimedOut,
        ErrorCode::ShuttingDown,
        ErrorCode::Internal,
    ];

    /// The code as sent on the wire.
    pub fn as_str(self) -> &'static str {
        match self {
            ErrorCode::BadJson => "bad_json",
            ErrorCode::RequestTooLarge => "request_too_large",
            ErrorCode::BadRequest => "bad_request",
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
            ErrorCode::FaultLatched => "fault_latched",
            ErrorCode::CameraUnavailable => "camera_unavailable",
            ErrorCode::StaleMeasurement => "stale_measurement",
            ErrorCode::NotConverged => "not_converged",
            ErrorCode::NoActiveTable => "no_active_table",
            ErrorCode::OutsideTable => "outside_table",
            ErrorCode::CameraStalled => "camera_stalled",
            ErrorCode::LowQuality => "low_quality",
            ErrorCode::RetryLimit => "retry_limit",
            ErrorCode::Diverging => "diverging",
            ErrorCode::NotAvailable => "not_available",
            ErrorCode::JobState => "job_state",
            ErrorCode::LogError => "log_error",
            ErrorCode::PermissionDenied => "permission_denied",
            ErrorCode::TimedOut => "timed_out",
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
