//! The driver's error type: every variant says what went wrong in terms a
//! person at the rig can act on (check the cable, the baud rate, reference the
//! axis, ...), and carries PI's own name for controller errors.

use crate::gcs::GcsErrorCode;
use std::path::PathBuf;
use std::time::Duration;
use thiserror::Error;

/// Why a driver call failed.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum DriverError {
    /// The serial device does not exist (cable pulled, USB adapter gone, wrong path).
    #[error(
        "no serial device at {path}: {reason} (is the controller plugged in and the path right?)"
    )]
    NoDevice {
        /// The path that was opened.
        path: PathBuf,
        /// What the operating system said.
        reason: String,
    },
    /// The device exists but could not be opened (permissions, in use by another program).
    #[error("cannot open serial device {path}: {reason}")]
    Open {
        /// The path that was opened.
        path: PathBuf,
        /// What the operating system said.
        reason: String,
    },
    /// Not even `ERR?` got an answer: nothing on the other end speaks GCS at these settings.
    #[error("no answer from {target} (not even to ERR?): wrong baud rate, wrong daisy-chain address, controller switched off or cable fault")]
    NotAnswering {
        /// Line and address, e.g. `/dev/ttyUSB0 address 2`.
        target: String,
    },
    /// The device answered `*IDN?` with something that is not a PI identification.
    #[error("the device on {target} is not a PI controller: it answered *IDN? with {idn:?}")]
    NotPi {
        /// Line and address.
        target: String,
        /// The answer as received.
        idn: String,
    },
    /// A PI controller, but not a C-863 (the driver relies on C-863 behaviour).
    #[error("the controller on {target} is a {model}, not a C-863 Mercury: refusing to drive it ({idn:?})")]
    NotC863 {
        /// Line and address.
        target: String,
        /// The model field of the identification.
        model: String,
        /// The whole identification.
        idn: String,
    },
    /// `CSV?` did not answer 2.0.
    #[error("the controller on {target} speaks GCS syntax {version}, micropos needs GCS 2.0")]
    UnsupportedSyntax {
        /// Line and address.
        target: String,
        /// The `CSV?` answer.
        version: String,
    },
    /// The configured axis identifier is not one the controller has (`SAI?`).
    #[error("axis {axis:?} does not exist on {target}; the controller has {available:?}")]
    NoSuchAxis {
        /// Line and address.
        target: String,
        /// The configured identifier.
        axis: String,
        /// What `SAI?` listed.
        available: Vec<String>,
    },
    /// The controller refused a command: `ERR?` returned a non-zero code.
    #[error("controller refused `{command}`: {code}")]
    Gcs {
        /// The command line as sent.
        command: String,
        /// PI's error code (its Display carries PI's name and meaning).
        code: GcsErrorCode,
    },
    /// A query got no answer in time, yet the controller answered the `ERR?`
    /// that followed with 0: the reply was lost or came too late.
    #[error("`{command}`: no answer within {timeout:?} although the controller is alive (reply lost or late{})", if *.partial { "; part of an answer arrived" } else { "" })]
    Timeout {
        /// The command line as sent.
        command: String,
        /// The answer timeout in force.
        timeout: Duration,
        /// Whether part of an answer had arrived.
        partial: bool,
    },
    /// The serial line is down (cable pulled, device gone, read error); the
    /// driver keeps reopening the path in the background.
    #[error("serial line {line} is down ({reason}); reconnecting in the background")]
    Disconnected {
        /// The device path.
        line: String,
        /// Why it went down, or why reopening fails.
        reason: String,
    },
    /// One axis refused its part of a two-axis move after the other had
    /// started; that one was halted (a two-axis move is all or nothing).
    #[error(
        "{refused}; axis {halted} had started and was halted (a two-axis move is all or nothing)"
    )]
    OtherAxisHalted {
        /// Why the refusing axis refused.
        refused: Box<DriverError>,
        /// The axis that was halted.
        halted: String,
    },
    /// The axis has no valid reference, so its position is not known.
    #[error("axis {axis} is not referenced (power cycle or never referenced): its position is unknown; reference it first (`micropos axes reference`)")]
    NotReferenced {
        /// The axis name.
        axis: String,
    },
    /// The servo is off (e.g. switched off by a motion error), so the axis
    /// cannot move.
    #[error("axis {axis}: servo is off (motion error or switched off); reference the axis again to switch it on")]
    ServoOff {
        /// The axis name.
        axis: String,
    },
    /// A target outside the travel range reported by `TMN?`/`TMX?`.
    #[error(
        "axis {axis}: target {target_um} µm is outside the travel range [{min_um}, {max_um}] µm"
    )]
    OutOfTravel {
        /// The axis name.
        axis: String,
        /// The requested absolute target.
        target_um: f64,
        /// Lower travel limit.
        min_um: f64,
        /// Upper travel limit.
        max_um: f64,
    },
    /// An answer that does not have the form the command calls for (garbage
    /// on the line, a late answer to an earlier command).
    #[error("unusable answer to `{command}`: {detail}: {text:?}")]
    BadAnswer {
        /// The command line as sent.
        command: String,
        /// What is wrong with it.
        detail: String,
        /// The answer as received (truncated).
        text: String,
    },
    /// A request that cannot be sent (not finite, bad characters, bad config).
    #[error("invalid request: {0}")]
    Invalid(String),
    /// Referencing did not finish in time (the axis was halted).
    #[error("axis {axis}: referencing did not finish within {timeout:?}; the axis was halted")]
    ReferenceTimeout {
        /// The axis name.
        axis: String,
        /// The timeout in force.
        timeout: Duration,
    },
    /// The axis did not report on-target in time.
    #[error("axis {axis}: not on target within {timeout:?}")]
    MotionTimeout {
        /// The axis name.
        axis: String,
        /// The timeout in force.
        timeout: Duration,
    },
    /// The move was stopped by `halt`/`stop` before it reached its target.
    #[error(
        "axis {axis}: the move was halted before reaching its target (PI_CNTR_STOP, error 10)"
    )]
    Halted {
        /// The axis name.
        axis: String,
    },
    /// After a reconnect the line leads to a different controller.
    #[error("{target}: a different controller answers after the reconnect (serial {found}, expected {expected}); refusing to drive it")]
    ControllerChanged {
        /// Line and address.
        target: String,
        /// Serial number seen at bring-up.
        expected: String,
        /// Serial number seen now.
        found: String,
    },
    /// The line reconnected in the middle of a multi-step operation, so its
    /// outcome is not known.
    #[error(
        "{target}: the line reconnected during `{command}`; its outcome is unknown, try again"
    )]
    Interrupted {
        /// Line and address.
        target: String,
        /// The command whose outcome is unknown.
        command: String,
    },
    /// Before a command, the controller's error register held a code that
    /// no caller had read (a command whose caller went away before its
    /// `ERR?`): other than 0 and 10 (a halt's own), it is reported here and
    /// the command is not sent, so that it is neither lost nor taken for
    /// the new command's refusal.
    #[error("{target}: the controller held error {code} from an earlier command whose caller went away; `{command}` was not sent")]
    PendingError {
        /// Line and address.
        target: String,
        /// The code that was waiting.
        code: GcsErrorCode,
        /// The command that was not sent.
        command: String,
    },
    /// The driver task has ended (all handles to the line were closed).
    #[error("the driver for {line} has shut down")]
    Closed {
        /// The device path.
        line: String,
    },
}

impl DriverError {
    /// The GCS error code, if the controller refused the command.
    pub fn gcs_code(&self) -> Option<GcsErrorCode> {
        match self {
            Self::Gcs { code, .. } => Some(*code),
            _ => None,
        }
    }

    /// Whether the same call may well succeed if simply sent again: the
    /// controller is alive and nothing it reported says the rig is wrong,
    /// but one reply was lost, late or garbled, or the line reconnected in
    /// the middle of the exchange. Why separate from
    /// [`DriverError::is_link_fault`]: a line that is down or a controller
    /// that answers nothing at all is not a glitch a retry rides through.
    pub fn is_transient(&self) -> bool {
        matches!(
            self,
            Self::Timeout { .. } | Self::BadAnswer { .. } | Self::Interrupted { .. }
        )
    }

    /// Whether the failure is a property of the line or the controller's
    /// liveness (so a retry after recovery may succeed) rather than of the
    /// request itself.
    pub fn is_link_fault(&self) -> bool {
        matches!(
            self,
            Self::NoDevice { .. }
                | Self::NotAnswering { .. }
                | Self::Timeout { .. }
                | Self::Disconnected { .. }
                | Self::BadAnswer { .. }
                | Self::Interrupted { .. }
        )
    }
}
