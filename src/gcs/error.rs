//! GCS error codes as PI documents them.
//!
//! Why a table: the controller only ever says a number (`ERR?` → `7`); a user
//! reading a log or an error reply needs PI's meaning next to it.

use std::fmt;

/// A GCS error code as returned by `ERR?`. 0 means "no error".
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct GcsErrorCode(pub i32);

impl GcsErrorCode {
    /// No error.
    pub const NO_ERROR: Self = Self(0);
    /// Parameter syntax error.
    pub const PARAM_SYNTAX: Self = Self(1);
    /// Unknown command.
    pub const UNKNOWN_COMMAND: Self = Self(2);
    /// Command length out of limits or command buffer overrun.
    pub const COMMAND_TOO_LONG: Self = Self(3);
    /// Unallowable move attempted on unreferenced axis, or move while servo off.
    pub const UNREFERENCED_OR_SERVO_OFF: Self = Self(5);
    /// Position out of limits.
    pub const POS_OUT_OF_LIMITS: Self = Self(7);
    /// Velocity out of limits.
    pub const VEL_OUT_OF_LIMITS: Self = Self(8);
    /// Controller was stopped by command (HLT, STP, #24).
    pub const STOPPED: Self = Self(10);
    /// Invalid axis identifier.
    pub const INVALID_AXIS: Self = Self(15);
    /// Parameter out of range.
    pub const PARAM_OUT_OF_RANGE: Self = Self(17);
    /// Illegal axis.
    pub const ILLEGAL_AXIS: Self = Self(23);
    /// Incorrect number of parameters.
    pub const WRONG_PARAM_COUNT: Self = Self(24);
    /// Command not allowed for selected stage(s).
    pub const NOT_ALLOWED_FOR_STAGE: Self = Self(34);
    /// Unknown parameter.
    pub const UNKNOWN_PARAMETER: Self = Self(54);
    /// Password invalid.
    pub const PASSWORD_INVALID: Self = Self(56);
    /// Protected parameter: current command level (CCL) too low.
    pub const PROTECTED_PARAMETER: Self = Self(60);
    /// Unknown stage name / not allowed in current motion mode. On C-863:
    /// "Not allowed while referencing (FRF) or in motion".
    pub const NOT_ALLOWED_WHILE_MOVING: Self = Self(307);
    /// Motion error: position error too large, servo switched off automatically.
    pub const MOTION_ERROR: Self = Self(1024);

    /// PI's short name for the code, when it is one micropos knows.
    pub fn name(self) -> Option<&'static str> {
        Some(match self.0 {
            0 => "PI_CNTR_NO_ERROR",
            1 => "PI_CNTR_PARAM_SYNTAX",
            2 => "PI_CNTR_UNKNOWN_COMMAND",
            3 => "PI_CNTR_COMMAND_TOO_LONG",
            5 => "PI_CNTR_UNALLOWED_MOVE_ON_UNREF_AXIS",
            7 => "PI_CNTR_POS_OUT_OF_LIMITS",
            8 => "PI_CNTR_VEL_OUT_OF_LIMITS",
            10 => "PI_CNTR_STOP",
            15 => "PI_CNTR_INVALID_AXIS_IDENTIFIER",
            17 => "PI_CNTR_PARAM_OUT_OF_RANGE",
            23 => "PI_CNTR_ILLEGAL_AXIS",
            24 => "PI_CNTR_INCORRECT_NUMBER_OF_PARAMETERS",
            34 => "PI_CNTR_COMMAND_NOT_ALLOWED_FOR_STAGE",
            54 => "PI_CNTR_UNKNOWN_PARAMETER",
            56 => "PI_CNTR_PASSWORD_INVALID",
            60 => "PI_CNTR_PROTECTED_PARAM_CURRENT_CCL",
            307 => "PI_CNTR_NOT_ALLOWED_IN_CURRENT_MOTION_MODE",
            1024 => "PI_CNTR_MOTION_ERROR",
            _ => return None,
        })
    }

    /// PI's description of the code, for people.
    pub fn description(self) -> &'static str {
        match self.0 {
            0 => "No error",
            1 => "Parameter syntax error",
            2 => "Unknown command",
            3 => "Command length out of limits or command buffer overrun",
            5 => {
                "Unallowable move attempted on unreferenced axis, or move attempted with servo off"
            }
            7 => "Position out of limits",
            8 => "Velocity out of limits",
            10 => "Controller was stopped by command",
            15 => "Invalid axis identifier",
            17 => "Parameter out of range",
            23 => "Illegal axis",
            24 => "Incorrect number of parameters",
            34 => "Command not allowed for selected stage(s)",
            54 => "Unknown parameter",
            56 => "Password invalid",
            60 => "Protected Param: current Command Level (CCL) too low",
            307 => "Not allowed while referencing or in current motion mode",
            1024 => "Motion error: position error too large, servo is switched off automatically",
            _ => "Error code not known to micropos (see the controller manual)",
        }
    }

    /// Whether this is the "no error" code.
    pub fn is_ok(self) -> bool {
        self.0 == 0
    }
}

impl fmt::Display for GcsErrorCode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.name() {
            Some(name) => write!(f, "GCS error {} ({name}): {}", self.0, self.description()),
            None => write!(f, "GCS error {}: {}", self.0, self.description()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn required_codes_are_named() {
        for code in [
            0, 1, 2, 3, 5, 7, 8, 10, 15, 17, 23, 24, 34, 54, 56, 60, 307, 1024,
        ] {
            let c = GcsErrorCode(code);
            assert!(c.name().is_some(), "{code}");
            assert!(!c.description().contains("not known"), "{code}");
        }
        assert_eq!(GcsErrorCode(99999).name(), None);
        assert!(GcsErrorCode(7)
            .to_string()
            .contains("Position out of limits"));
        assert!(GcsErrorCode(0).is_ok());
    }
}
