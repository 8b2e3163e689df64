//! The measurement log: one CSV file per characterization job, written point
//! by point so that a crash loses nothing, readable by any program.
//!
//! Layout (full specification in `docs/measurement-log.md`):
//!
//! ```text
//! # format: micropos-measurement-log/1
//! # stage: M-111.1DG serial 0123
//! t_s,segment,cycle,x_target_um,y_target_um,x_cmd_um,y_cmd_um,x_meas_um,y_meas_um,temp_c,focus
//! 0.000000,scan_x,1,0.0000,0.0000,0.0000,0.0000,0.0412,-0.0077,21.503,ok
//! ```
//!
//! * `#` lines before the header are metadata (`# key: value` or
//!   `# key = value`; other comments are kept as free text). `#` lines after
//!   the header and blank lines are ignored.
//! * The header starts with the nine mandatory columns in that order,
//!   optionally `temp_c` right after them, then any extra columns, which are
//!   carried through by name as text.
//! * `target` is what was wanted, `cmd` what was sent to the controllers,
//!   `meas` what the camera saw, all in the stage frame, µm. The positioning
//!   error has the paper's sign, `target − meas` ([`Record::error_x_um`]).
//!
//! Reading is tolerant of what other programs write (CRLF, a UTF-8 BOM,
//! blank lines, spaces around fields, RFC 4180 double-quoted fields, no final
//! newline) and strict about content: a malformed line is an error that names
//! the line and the reason. The only exception is the **last** line when it
//! has no line terminator and does not parse: that is what a crash in the
//! middle of a write leaves, so it is reported as a [`TornTail`], not an
//! error, and [`open_append`] cuts it off before resuming.
//!
//! Errors versus warnings. Errors (the file is refused): invalid UTF-8, no
//! header, wrong or misplaced mandatory columns, duplicate column names, a
//! record with the wrong number of fields, a number that does not parse, is
//! NaN/infinite or is beyond ±1e9 (µm, s or °C: no physical log holds such a
//! value, and the bound keeps the written precision exact), an empty segment,
//! a cycle that is not a non-negative integer, bad quoting, a line longer
//! than [`MAX_LINE_BYTES`]. Warnings (the data is usable, the reader says
//! what was odd): time going backwards (logs concatenated by other programs,
//! wall clocks that step), a duplicate metadata key (the last value wins), a
//! final line without terminator that parses, a foreign `format` value.
//!
//! The parsing is sans-IO in spirit: [`LogReader`] works on any `BufRead`
//! and [`parse_bytes`] on a slice; only [`read_file`], [`create_file`] and
//! [`open_append`] touch the file system. They block: call them from
//! `spawn_blocking` in async code.

use std::borrow::Cow;
use std::fmt::Write as _;
use std::fs::{File, OpenOptions};
use std::io::{self, BufRead, BufReader, Read, Seek, SeekFrom, Write};
use std::num::NonZeroU32;
use std::path::Path;

mod error;
mod fields;
mod format;
mod read;
#[cfg(test)]
mod tests;
mod write;

pub use error::{LineError, LogError};
use fields::{is_field_space, push_field};
pub use format::{
    FORMAT_ID, FORMAT_KEY, MANDATORY_COLUMNS, MAX_ABS_VALUE, MAX_LINE_BYTES, MAX_WARNINGS,
    POSITION_DECIMALS, TEMP_COLUMN, TEMP_DECIMALS, THETA_COLUMN, THETA_DECIMALS, TIE_THETA_KEY,
    TIME_DECIMALS,
};
pub use read::{parse_bytes, read_file, read_from, LogReader};
pub use write::{create_file, open_append, LogSink, LogWriter, RepairedTail, Resume, SyncPolicy};

/// One measured point.
#[derive(Clone, Debug, PartialEq)]
pub struct Record {
    /// Time of the measurement, s, from an origin the writer chooses (the
    /// daemon uses the job start).
    pub t_s: f64,
    /// Name of the trajectory the point belongs to (`scan_x`, `scan_y`,
    /// `square`, `random`, …).
    pub segment: String,
    /// Cycle number within the segment.
    pub cycle: u32,
    /// Wanted position x, stage frame, µm.
    pub x_target_um: f64,
    /// Wanted position y, stage frame, µm.
    pub y_target_um: f64,
    /// Position sent to the x controller, µm (differs from the target when
    /// compensation is on).
    pub x_cmd_um: f64,
    /// Position sent to the y controller, µm.
    pub y_cmd_um: f64,
    /// Position the camera measured, x, stage frame, µm.
    pub x_meas_um: f64,
    /// Position the camera measured, y, stage frame, µm.
    pub y_meas_um: f64,
    /// Temperature, °C, if the log has a `temp_c` column and it was measured
    /// for this point (an empty cell reads as `None`).
    pub temp_c: Option<f64>,
    /// Decoded θ relative to the tie's (µrad, [`THETA_COLUMN`]: the
    /// platform's yaw since the tie), if the log has a `theta_urad` column
    /// and the point has one (an empty cell reads as `None`).
    pub theta_urad: Option<f64>,
    /// Values of the extra columns, in header order, as text.
    pub extra: Vec<String>,
}

impl Record {
    /// Positioning error along x with the paper's sign: `x_target − x_meas`
    /// (positive when the stage fell short of a target in +x), µm.
    pub fn error_x_um(&self) -> f64 {
        self.x_target_um - self.x_meas_um
    }

    /// Positioning error along y with the paper's sign: `y_target − y_meas`, µm.
    pub fn error_y_um(&self) -> f64 {
        self.y_target_um - self.y_meas_um
    }

    /// The numeric fields with their column names, for validation.
    fn numbers(&self) -> [(&'static str, f64); 7] {
        [
            ("t_s", self.t_s),
            ("x_target_um", self.x_target_um),
            ("y_target_um", self.y_target_um),
            ("x_cmd_um", self.x_cmd_um),
            ("y_cmd_um", self.y_cmd_um),
            ("x_meas_um", self.x_meas_um),
            ("y_meas_um", self.y_meas_um),
        ]
    }
}

/// Which columns a log has beyond the mandatory nine.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Columns {
    /// Whether the `temp_c` column is present.
    pub temp_c: bool,
    /// Whether the `theta_urad` column is present (after `temp_c`).
    pub theta_urad: bool,
    /// Names of the extra columns, in order.
    pub extra: Vec<String>,
}

impl Columns {
    /// Columns with an optional `temp_c` and the given extra names, checked:
    /// extra names must be non-empty, unique, distinct from the standard
    /// columns and free of control characters.
    pub fn new(temp_c: bool, extra: Vec<String>) -> Result<Self, LogError> {
        let c = Self {
            temp_c,
            theta_urad: false,
            extra,
        };
        c.validate()?;
        Ok(c)
    }

    /// The same columns with or without `theta_urad`.
    pub fn with_theta(mut self, theta_urad: bool) -> Self {
        self.theta_urad = theta_urad;
        self
    }

    fn validate(&self) -> Result<(), LogError> {
        for (i, name) in self.extra.iter().enumerate() {
            let bad =
                |reason: &str| LogError::InvalidColumns(format!("extra column {name:?}: {reason}"));
            if name.trim_matches(is_field_space).is_empty() {
                return Err(bad("name is empty"));
            }
            if name.chars().any(char::is_control) {
                return Err(bad("name contains a control character"));
            }
            if MANDATORY_COLUMNS.contains(&name.as_str())
                || name == TEMP_COLUMN
                || name == THETA_COLUMN
            {
                return Err(bad("name is a standard column"));
            }
            if self.extra[..i].contains(name) {
                return Err(bad("name appears twice"));
            }
        }
        Ok(())
    }

    /// Total number of columns.
    pub fn len(&self) -> usize {
        MANDATORY_COLUMNS.len()
            + usize::from(self.temp_c)
            + usize::from(self.theta_urad)
            + self.extra.len()
    }

    /// Always false: a log has at least the nine mandatory columns. Present
    /// because `len` is.
    pub fn is_empty(&self) -> bool {
        false
    }

    /// The header line (without terminator), as the writer emits it.
    pub fn header_line(&self) -> String {
        let mut s = MANDATORY_COLUMNS.join(",");
        if self.temp_c {
            s.push(',');
            s.push_str(TEMP_COLUMN);
        }
        if self.theta_urad {
            s.push(',');
            s.push_str(THETA_COLUMN);
        }
        for name in &self.extra {
            s.push(',');
            push_field(&mut s, name);
        }
        s
    }
}

/// Ordered `key → value` metadata from the `#` lines above the header.
///
/// Order is kept (it is how a person wrote it); keys are unique, a repeated
/// key replaces the value in place.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Metadata {
    entries: Vec<(String, String)>,
}

impl Metadata {
    /// Empty metadata.
    pub fn new() -> Self {
        Self::default()
    }

    /// Sets `key` to `value`; returns the previous value if the key existed
    /// (its position is kept).
    pub fn insert(&mut self, key: impl Into<String>, value: impl Into<String>) -> Option<String> {
        let key = key.into();
        let value = value.into();
        match self.entries.iter_mut().find(|(k, _)| *k == key) {
            Some((_, v)) => Some(std::mem::replace(v, value)),
            None => {
                self.entries.push((key, value));
                None
            }
        }
    }

    /// The value of `key`, if present.
    pub fn get(&self, key: &str) -> Option<&str> {
        self.entries
            .iter()
            .find(|(k, _)| k == key)
            .map(|(_, v)| v.as_str())
    }

    /// Entries in order.
    pub fn iter(&self) -> impl Iterator<Item = (&str, &str)> {
        self.entries.iter().map(|(k, v)| (k.as_str(), v.as_str()))
    }

    /// Number of entries.
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    /// Whether there is no entry.
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }
}

/// Something odd but harmless the reader noticed.
#[derive(Debug, Clone, PartialEq)]
pub enum WarningKind {
    /// `t_s` is smaller than on the previous record.
    TimeWentBackwards {
        /// Previous record's time, s.
        previous_s: f64,
        /// This record's time, s.
        t_s: f64,
    },
    /// A metadata key appears twice; the later value is kept.
    DuplicateMetadataKey {
        /// The key.
        key: String,
    },
    /// The last line has no terminator but parsed as a complete record. A
    /// program may simply omit the final newline; a crash could also have cut
    /// digits off the last number, which is why [`open_append`] drops it.
    NoFinalNewline,
    /// The `format` metadata names something other than [`FORMAT_ID`].
    ForeignFormat {
        /// The value found.
        value: String,
    },
}

/// A warning with the line it concerns.
#[derive(Debug, Clone, PartialEq)]
pub struct Warning {
    /// 1-based line number.
    pub line: usize,
    /// What was noticed.
    pub kind: WarningKind,
}

/// An unterminated last line that did not parse: the trace of a crash in
/// the middle of a write.
#[derive(Debug, Clone, PartialEq)]
pub struct TornTail {
    /// 1-based line number of the torn line.
    pub line: usize,
    /// Byte offset where it starts (= length of the file once repaired).
    pub offset: u64,
    /// Its length in bytes.
    pub len: usize,
    /// Why it does not parse.
    pub error: LineError,
}

/// A whole log read into memory.
#[derive(Debug, Clone, PartialEq)]
pub struct MeasurementLog {
    /// Metadata entries from the `# key: value` lines.
    pub metadata: Metadata,
    /// Other `#` lines above the header (text after the `#`, trimmed).
    pub comments: Vec<String>,
    /// The columns beyond the mandatory ones.
    pub columns: Columns,
    /// The records, in file order.
    pub records: Vec<Record>,
    /// Warnings (at most [`MAX_WARNINGS`]).
    pub warnings: Vec<Warning>,
    /// Warnings beyond [`MAX_WARNINGS`] that were only counted.
    pub warnings_dropped: usize,
    /// The torn last line, if the file ends in one.
    pub torn_tail: Option<TornTail>,
}

impl MeasurementLog {
    /// Whether the file ended cleanly (no torn last line).
    pub fn is_complete(&self) -> bool {
        self.torn_tail.is_none()
    }
}
