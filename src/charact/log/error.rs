//! Why a line, or a whole log, was refused: a leaf the reader, the writer
//! and the field syntax all name.

use super::format::{MANDATORY_COLUMNS, MAX_LINE_BYTES, TEMP_COLUMN, THETA_COLUMN};
use std::io;
use thiserror::Error;

/// Why one line of a log was refused.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum LineError {
    /// The line is not UTF-8.
    #[error("not valid UTF-8")]
    InvalidUtf8,
    /// The line exceeds [`MAX_LINE_BYTES`].
    #[error("line longer than {MAX_LINE_BYTES} bytes")]
    TooLong,
    /// The header's mandatory part is wrong.
    #[error("bad header: column {position} must be {expected:?}, found {found:?} (the header must start with {})", MANDATORY_COLUMNS.join(","))]
    BadHeader {
        /// 1-based column position.
        position: usize,
        /// The name required there.
        expected: &'static str,
        /// What the file has there (empty if the header is too short).
        found: String,
    },
    /// `temp_c` appears elsewhere than right after `y_meas_um`.
    #[error("bad header: {TEMP_COLUMN} must be column 10, right after y_meas_um (found at column {position})")]
    MisplacedTemp {
        /// 1-based position where it was found.
        position: usize,
    },
    /// `theta_urad` appears elsewhere than right after the mandatory
    /// columns and `temp_c`.
    #[error("bad header: {THETA_COLUMN} must follow y_meas_um (and temp_c, when present) directly (found at column {position})")]
    MisplacedTheta {
        /// 1-based position where it was found.
        position: usize,
    },
    /// An extra column has an empty name or repeats another column.
    #[error("bad header: column {position} {reason}")]
    BadExtraColumn {
        /// 1-based column position.
        position: usize,
        /// What is wrong with it.
        reason: String,
    },
    /// A record has the wrong number of fields.
    #[error("wrong column count: the header has {expected} columns, this line has {found}")]
    WrongColumnCount {
        /// Columns in the header.
        expected: usize,
        /// Fields on the line.
        found: usize,
    },
    /// A numeric field does not parse.
    #[error("column {column}: {value:?} is not a number")]
    NotANumber {
        /// Column name.
        column: String,
        /// The text found.
        value: String,
    },
    /// A numeric field is NaN or infinite.
    #[error("column {column}: {value:?} is not finite")]
    NonFinite {
        /// Column name.
        column: String,
        /// The text found.
        value: String,
    },
    /// A numeric field is beyond ±[`MAX_ABS_VALUE`](super::MAX_ABS_VALUE).
    #[error("column {column}: {value:?} is beyond ±1e9")]
    OutOfRange {
        /// Column name.
        column: String,
        /// The text found.
        value: String,
    },
    /// The segment name is empty.
    #[error("column segment is empty")]
    EmptySegment,
    /// The cycle is not a non-negative integer that fits in 32 bits.
    #[error("column cycle: {value:?} is not a non-negative integer")]
    BadCycle {
        /// The text found.
        value: String,
    },
    /// A quoted field is not closed, or text follows its closing quote.
    #[error("bad quoting: {0}")]
    BadQuoting(&'static str),
}

impl LineError {
    /// The error without the file's text (no found values, no extra column
    /// names): what the daemon tells a client about a file in its data
    /// directory, which may hold anything (a planted or misplaced secret's
    /// first line must not come back in an error). Column names of the
    /// mandatory part and positions stay: they are the format's, not the
    /// file's.
    pub fn without_content(&self) -> String {
        match self {
            Self::BadHeader {
                position, expected, ..
            } => format!(
                "bad header: column {position} must be {expected:?} (the header must start with {})",
                MANDATORY_COLUMNS.join(",")
            ),
            Self::BadExtraColumn { position, .. } => {
                format!("bad header: column {position} is not a valid extra column")
            }
            Self::NotANumber { .. } => "a numeric field is not a number".to_owned(),
            Self::NonFinite { .. } => "a numeric field is not finite".to_owned(),
            Self::OutOfRange { .. } => "a numeric field is beyond ±1e9".to_owned(),
            Self::BadCycle { .. } => "column cycle is not a non-negative integer".to_owned(),
            other => other.to_string(),
        }
    }
}

/// Why a log could not be read or written.
#[derive(Debug, Error)]
pub enum LogError {
    /// A line of the file is malformed.
    #[error("line {line}: {error}")]
    Line {
        /// 1-based line number.
        line: usize,
        /// What is wrong with it.
        error: LineError,
    },
    /// The file ends before any header line.
    #[error("no header line (expected one starting with {}) after {lines} line(s)", MANDATORY_COLUMNS.join(","))]
    MissingHeader {
        /// Lines read before the end of the file.
        lines: usize,
    },
    /// Extra column names given to the writer are invalid.
    #[error("invalid columns: {0}")]
    InvalidColumns(String),
    /// A metadata entry given to the writer cannot be written faithfully.
    #[error("invalid metadata entry {key:?}: {reason}")]
    InvalidMetadata {
        /// The key.
        key: String,
        /// Why.
        reason: &'static str,
    },
    /// A record given to the writer cannot be written faithfully.
    #[error("invalid record, field {field}: {reason}")]
    InvalidRecord {
        /// Column name.
        field: String,
        /// Why.
        reason: String,
    },
    /// The file to append to has other columns than the job writes.
    #[error("existing log has columns [{found}], the job writes [{expected}]")]
    ColumnsMismatch {
        /// Header the caller expects.
        expected: String,
        /// Header in the file.
        found: String,
    },
    /// An earlier write failed part-way; the file may end in a partial line.
    /// Reopen it with [`open_append`](super::open_append), which repairs it.
    #[error("an earlier write to this log failed; reopen it with open_append to repair it")]
    Poisoned,
    /// The operating system refused a read or write.
    #[error("I/O error: {0}")]
    Io(#[from] io::Error),
}

impl LogError {
    /// The error without the file's text ([`LineError::without_content`]).
    pub fn without_content(&self) -> String {
        match self {
            Self::Line { line, error } => format!("line {line}: {}", error.without_content()),
            Self::ColumnsMismatch { .. } => {
                "the existing log has other columns than the job writes".to_owned()
            }
            other => other.to_string(),
        }
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn errors_without_content_name_the_line_but_not_the_text() {
        for (text, line) in [
            ("SECRET=hunter2-very-secret\n", 1),
            (
                "t_s,segment,cycle,x_target_um,y_target_um,x_cmd_um,y_cmd_um,x_meas_um,y_meas_um\n\
                 0,a,0,1,2,3,4,hunter2,6\n",
                2,
            ),
        ] {
            let e = super::super::parse_bytes(text.as_bytes()).unwrap_err();
            assert!(
                e.to_string().contains("hunter2"),
                "the full error quotes: {e}"
            );
            let quiet = e.without_content();
            assert!(!quiet.contains("hunter2"), "{quiet}");
            assert!(quiet.starts_with(&format!("line {line}: ")), "{quiet}");
        }
    }
}
