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

use thiserror::Error;

/// The nine mandatory columns, in the order every log must start with.
pub const MANDATORY_COLUMNS: [&str; 9] = [
    "t_s",
    "segment",
    "cycle",
    "x_target_um",
    "y_target_um",
    "x_cmd_um",
    "y_cmd_um",
    "x_meas_um",
    "y_meas_um",
];

/// The optional temperature column; when present it is the tenth column.
pub const TEMP_COLUMN: &str = "temp_c";

/// Metadata key the writer uses to identify the format and its version.
pub const FORMAT_KEY: &str = "format";

/// Value of [`FORMAT_KEY`] written by this version.
pub const FORMAT_ID: &str = "micropos-measurement-log/1";

/// Longest accepted line, terminator included. Guards memory against a
/// binary or corrupt file with no newline; real lines are ~150 bytes.
pub const MAX_LINE_BYTES: usize = 1 << 20;

/// Largest magnitude accepted for any number (µm, s, °C). Bounds the values
/// to physically meaningful ones and keeps the written decimals exact
/// (f64 resolves 1e-6 at this magnitude).
pub const MAX_ABS_VALUE: f64 = 1.0e9;

/// Decimals written for positions in µm: 0.1 nm, below the camera's
/// nanometre-class resolution.
pub const POSITION_DECIMALS: usize = 4;
/// Decimals written for `t_s`: 1 µs, finer than any frame rate.
pub const TIME_DECIMALS: usize = 6;
/// Decimals written for `temp_c`: 1 mK.
pub const TEMP_DECIMALS: usize = 3;

/// At most this many warnings are kept; the rest are only counted.
pub const MAX_WARNINGS: usize = 1000;

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
    /// Names of the extra columns, in order.
    pub extra: Vec<String>,
}

impl Columns {
    /// Columns with an optional `temp_c` and the given extra names, checked:
    /// extra names must be non-empty, unique, distinct from the standard
    /// columns and free of control characters.
    pub fn new(temp_c: bool, extra: Vec<String>) -> Result<Self, LogError> {
        let c = Self { temp_c, extra };
        c.validate()?;
        Ok(c)
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
            if MANDATORY_COLUMNS.contains(&name.as_str()) || name == TEMP_COLUMN {
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
        MANDATORY_COLUMNS.len() + usize::from(self.temp_c) + self.extra.len()
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
    /// A numeric field is beyond ±[`MAX_ABS_VALUE`].
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
    /// Reopen it with [`open_append`], which repairs it.
    #[error("an earlier write to this log failed; reopen it with open_append to repair it")]
    Poisoned,
    /// The operating system refused a read or write.
    #[error("I/O error: {0}")]
    Io(#[from] io::Error),
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

fn is_field_space(c: char) -> bool {
    c == ' ' || c == '\t'
}

/// Splits a line into fields: comma-separated, spaces/tabs around unquoted
/// fields trimmed, RFC 4180 double quotes (with `""` for a quote) honoured.
fn split_fields(line: &str) -> Result<Vec<Cow<'_, str>>, LineError> {
    let mut fields = Vec::new();
    let mut rest = line;
    loop {
        let trimmed = rest.trim_start_matches(is_field_space);
        if let Some(after_quote) = trimmed.strip_prefix('"') {
            let mut value = String::new();
            let mut chars = after_quote.char_indices();
            let end = loop {
                match chars.next() {
                    None => return Err(LineError::BadQuoting("quoted field is not closed")),
                    Some((i, '"')) => {
                        if after_quote[i + 1..].starts_with('"') {
                            value.push('"');
                            chars.next();
                        } else {
                            break i + 1;
                        }
                    }
                    Some((_, c)) => value.push(c),
                }
            };
            fields.push(Cow::Owned(value));
            let after = after_quote[end..].trim_start_matches(is_field_space);
            if after.is_empty() {
                return Ok(fields);
            }
            match after.strip_prefix(',') {
                Some(r) => rest = r,
                None => {
                    return Err(LineError::BadQuoting(
                        "text after the closing quote of a field",
                    ))
                }
            }
        } else {
            match trimmed.find(',') {
                Some(i) => {
                    fields.push(Cow::Borrowed(trimmed[..i].trim_end_matches(is_field_space)));
                    rest = &trimmed[i + 1..];
                }
                None => {
                    fields.push(Cow::Borrowed(trimmed.trim_end_matches(is_field_space)));
                    return Ok(fields);
                }
            }
        }
    }
}

/// Writes a field, quoting it when the reader would otherwise change it.
fn push_field(out: &mut String, value: &str) {
    let needs_quotes = value.contains([',', '"'])
        || value.starts_with(is_field_space)
        || value.ends_with(is_field_space)
        || value.starts_with('#');
    if needs_quotes {
        out.push('"');
        out.push_str(&value.replace('"', "\"\""));
        out.push('"');
    } else {
        out.push_str(value);
    }
}

fn parse_header(fields: &[Cow<'_, str>]) -> Result<Columns, LineError> {
    for (i, expected) in MANDATORY_COLUMNS.iter().enumerate() {
        let found = fields.get(i).map(|f| f.as_ref()).unwrap_or("");
        if found != *expected {
            return Err(LineError::BadHeader {
                position: i + 1,
                expected,
                found: found.to_owned(),
            });
        }
    }
    let mut rest = &fields[MANDATORY_COLUMNS.len()..];
    let temp_c = rest.first().is_some_and(|f| f == TEMP_COLUMN);
    if temp_c {
        rest = &rest[1..];
    }
    let first_extra = MANDATORY_COLUMNS.len() + usize::from(temp_c) + 1;
    let mut extra: Vec<String> = Vec::with_capacity(rest.len());
    for (i, name) in rest.iter().enumerate() {
        let position = first_extra + i;
        if name == TEMP_COLUMN {
            return Err(LineError::MisplacedTemp { position });
        }
        let bad = |reason: &str| LineError::BadExtraColumn {
            position,
            reason: reason.to_owned(),
        };
        if name.is_empty() {
            return Err(bad("has an empty name"));
        }
        if MANDATORY_COLUMNS.contains(&name.as_ref()) || extra.iter().any(|e| e == name) {
            return Err(bad(&format!("repeats the column name {name:?}")));
        }
        if name.chars().any(char::is_control) {
            return Err(bad("has a control character in its name"));
        }
        extra.push(name.to_string());
    }
    Ok(Columns { temp_c, extra })
}

fn parse_number(column: &str, value: &str) -> Result<f64, LineError> {
    let v: f64 = value.parse().map_err(|_| LineError::NotANumber {
        column: column.to_owned(),
        value: value.to_owned(),
    })?;
    if !v.is_finite() {
        return Err(LineError::NonFinite {
            column: column.to_owned(),
            value: value.to_owned(),
        });
    }
    if v.abs() > MAX_ABS_VALUE {
        return Err(LineError::OutOfRange {
            column: column.to_owned(),
            value: value.to_owned(),
        });
    }
    Ok(v)
}

fn parse_record(columns: &Columns, line: &str) -> Result<Record, LineError> {
    let f = split_fields(line)?;
    if f.len() != columns.len() {
        return Err(LineError::WrongColumnCount {
            expected: columns.len(),
            found: f.len(),
        });
    }
    let num = |i: usize| parse_number(MANDATORY_COLUMNS[i], &f[i]);
    let t_s = num(0)?;
    let segment = f[1].to_string();
    if segment.trim().is_empty() {
        return Err(LineError::EmptySegment);
    }
    let cycle: u32 = f[2].parse().map_err(|_| LineError::BadCycle {
        value: f[2].to_string(),
    })?;
    let temp_c = if columns.temp_c {
        let v = &f[MANDATORY_COLUMNS.len()];
        if v.is_empty() {
            None
        } else {
            Some(parse_number(TEMP_COLUMN, v)?)
        }
    } else {
        None
    };
    let first_extra = MANDATORY_COLUMNS.len() + usize::from(columns.temp_c);
    Ok(Record {
        t_s,
        segment,
        cycle,
        x_target_um: num(3)?,
        y_target_um: num(4)?,
        x_cmd_um: num(5)?,
        y_cmd_um: num(6)?,
        x_meas_um: num(7)?,
        y_meas_um: num(8)?,
        temp_c,
        extra: f[first_extra..].iter().map(|s| s.to_string()).collect(),
    })
}

/// Parses a `#` line above the header: `Some((key, value))` for metadata,
/// `None` for a free comment.
fn parse_metadata_line(text: &str) -> Option<(&str, &str)> {
    let sep = text.find([':', '='])?;
    let key = text[..sep].trim();
    if key.is_empty() || key.contains(char::is_whitespace) {
        return None;
    }
    Some((key, text[sep + 1..].trim()))
}

/// A raw line read from the input.
struct RawLine {
    /// 1-based number.
    number: usize,
    /// Offset of its first byte.
    offset: u64,
    /// Whether it ended with `\n`.
    terminated: bool,
}

/// Streaming reader: the header is parsed by [`LogReader::new`], records are
/// pulled one at a time, so a multi-day log needs no more memory than a line.
pub struct LogReader<R> {
    inner: R,
    buf: Vec<u8>,
    line_no: usize,
    offset: u64,
    complete_len: u64,
    metadata: Metadata,
    comments: Vec<String>,
    columns: Columns,
    header_terminated: bool,
    warnings: Vec<Warning>,
    warnings_dropped: usize,
    torn_tail: Option<TornTail>,
    last_t_s: Option<f64>,
    last_record_terminated: bool,
    finished: bool,
}

impl<R: BufRead> LogReader<R> {
    /// Reads the metadata and the header. Errors if the input ends before a
    /// header or if a line before it is malformed.
    pub fn new(inner: R) -> Result<Self, LogError> {
        let mut reader = Self {
            inner,
            buf: Vec::new(),
            line_no: 0,
            offset: 0,
            complete_len: 0,
            metadata: Metadata::new(),
            comments: Vec::new(),
            columns: Columns::default(),
            header_terminated: false,
            warnings: Vec::new(),
            warnings_dropped: 0,
            torn_tail: None,
            last_t_s: None,
            last_record_terminated: true,
            finished: false,
        };
        loop {
            let Some(raw) = reader.read_line()? else {
                return Err(LogError::MissingHeader {
                    lines: reader.line_no,
                });
            };
            let text = reader.line_text(&raw).map_err(|error| LogError::Line {
                line: raw.number,
                error,
            })?;
            let trimmed = text.trim();
            if trimmed.is_empty() {
                continue;
            }
            if let Some(comment) = trimmed.strip_prefix('#') {
                let comment = comment.trim();
                match parse_metadata_line(comment) {
                    Some((key, value)) => {
                        let (key, value) = (key.to_owned(), value.to_owned());
                        if key == FORMAT_KEY && value != FORMAT_ID {
                            reader.warn(
                                raw.number,
                                WarningKind::ForeignFormat {
                                    value: value.clone(),
                                },
                            );
                        }
                        if reader.metadata.insert(key.clone(), value).is_some() {
                            reader.warn(raw.number, WarningKind::DuplicateMetadataKey { key });
                        }
                    }
                    None => reader.comments.push(comment.to_owned()),
                }
                continue;
            }
            let columns = split_fields(&text)
                .and_then(|f| parse_header(&f))
                .map_err(|error| LogError::Line {
                    line: raw.number,
                    error,
                })?;
            reader.columns = columns;
            reader.header_terminated = raw.terminated;
            return Ok(reader);
        }
    }

    /// The next record, `Ok(None)` at the end of the input (including after a
    /// torn last line, see [`LogReader::torn_tail`]).
    pub fn next_record(&mut self) -> Result<Option<Record>, LogError> {
        while !self.finished {
            let Some(raw) = self.read_line()? else {
                self.finished = true;
                break;
            };
            let parsed = self.line_text(&raw).and_then(|text| match text.trim() {
                "" => Ok(None),
                t if t.starts_with('#') => Ok(None),
                _ => parse_record(&self.columns, &text).map(Some),
            });
            match parsed {
                Ok(None) => continue,
                Ok(Some(record)) => {
                    if !raw.terminated {
                        self.warn(raw.number, WarningKind::NoFinalNewline);
                    }
                    if let Some(previous_s) = self.last_t_s {
                        if record.t_s < previous_s {
                            self.warn(
                                raw.number,
                                WarningKind::TimeWentBackwards {
                                    previous_s,
                                    t_s: record.t_s,
                                },
                            );
                        }
                    }
                    self.last_t_s = Some(record.t_s);
                    self.last_record_terminated = raw.terminated;
                    return Ok(Some(record));
                }
                Err(error) if !raw.terminated => {
                    self.torn_tail = Some(TornTail {
                        line: raw.number,
                        offset: raw.offset,
                        len: self.buf.len(),
                        error,
                    });
                    self.finished = true;
                }
                Err(error) => {
                    return Err(LogError::Line {
                        line: raw.number,
                        error,
                    })
                }
            }
        }
        Ok(None)
    }

    /// Metadata from above the header.
    pub fn metadata(&self) -> &Metadata {
        &self.metadata
    }

    /// Free comments from above the header.
    pub fn comments(&self) -> &[String] {
        &self.comments
    }

    /// Columns from the header.
    pub fn columns(&self) -> &Columns {
        &self.columns
    }

    /// Warnings so far.
    pub fn warnings(&self) -> &[Warning] {
        &self.warnings
    }

    /// The torn last line, once the end has been reached.
    pub fn torn_tail(&self) -> Option<&TornTail> {
        self.torn_tail.as_ref()
    }

    /// Bytes up to and including the last `\n` read so far: the length to
    /// truncate a crashed log to.
    pub fn complete_len(&self) -> u64 {
        self.complete_len
    }

    /// Reads all remaining records into a [`MeasurementLog`].
    pub fn read_to_end(mut self) -> Result<MeasurementLog, LogError> {
        let mut records = Vec::new();
        while let Some(r) = self.next_record()? {
            records.push(r);
        }
        Ok(MeasurementLog {
            metadata: self.metadata,
            comments: self.comments,
            columns: self.columns,
            records,
            warnings: self.warnings,
            warnings_dropped: self.warnings_dropped,
            torn_tail: self.torn_tail,
        })
    }

    fn warn(&mut self, line: usize, kind: WarningKind) {
        if self.warnings.len() < MAX_WARNINGS {
            self.warnings.push(Warning { line, kind });
        } else {
            self.warnings_dropped += 1;
        }
    }

    fn read_line(&mut self) -> Result<Option<RawLine>, LogError> {
        self.buf.clear();
        let limit = MAX_LINE_BYTES as u64 + 1;
        let n = (&mut self.inner)
            .take(limit)
            .read_until(b'\n', &mut self.buf)?;
        if n == 0 {
            return Ok(None);
        }
        let terminated = self.buf.last() == Some(&b'\n');
        self.line_no += 1;
        if n > MAX_LINE_BYTES {
            return Err(LogError::Line {
                line: self.line_no,
                error: LineError::TooLong,
            });
        }
        let raw = RawLine {
            number: self.line_no,
            offset: self.offset,
            terminated,
        };
        self.offset += n as u64;
        if terminated {
            self.complete_len = self.offset;
        }
        Ok(Some(raw))
    }

    /// The current line as text, without terminator, CR or (first line) BOM.
    fn line_text(&self, raw: &RawLine) -> Result<String, LineError> {
        let mut bytes = self.buf.as_slice();
        if let Some(b) = bytes.strip_suffix(b"\n") {
            bytes = b;
        }
        if let Some(b) = bytes.strip_suffix(b"\r") {
            bytes = b;
        }
        if raw.number == 1 {
            if let Some(b) = bytes.strip_prefix("\u{feff}".as_bytes()) {
                bytes = b;
            }
        }
        std::str::from_utf8(bytes)
            .map(str::to_owned)
            .map_err(|_| LineError::InvalidUtf8)
    }
}

/// Parses a whole log held in memory. Never panics, whatever the bytes.
pub fn parse_bytes(bytes: &[u8]) -> Result<MeasurementLog, LogError> {
    LogReader::new(bytes)?.read_to_end()
}

/// Reads a whole log from any reader (buffered internally).
pub fn read_from(reader: impl Read) -> Result<MeasurementLog, LogError> {
    LogReader::new(BufReader::new(reader))?.read_to_end()
}

/// Reads a whole log file.
pub fn read_file(path: impl AsRef<Path>) -> Result<MeasurementLog, LogError> {
    read_from(File::open(path)?)
}

/// Where a [`LogWriter`] writes: a `Write` that can also be forced to stable
/// storage.
pub trait LogSink: Write {
    /// Makes written data durable (survive power loss), like
    /// [`File::sync_data`].
    fn sync_data(&mut self) -> io::Result<()>;
}

impl LogSink for File {
    fn sync_data(&mut self) -> io::Result<()> {
        File::sync_data(self)
    }
}

/// Memory sink for tests and in-memory conversion; syncing is a no-op.
impl LogSink for Vec<u8> {
    fn sync_data(&mut self) -> io::Result<()> {
        Ok(())
    }
}

/// How often the writer forces records to stable storage.
///
/// Every record is written with one `write` call and flushed, so it reaches
/// the operating system at once and survives a crash of the process. Only
/// `sync_data` makes it survive a power cut or kernel crash; it costs a few
/// milliseconds on disks, negligible against measurement points that take
/// seconds each, hence the default of syncing every record.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SyncPolicy {
    /// Flush every record, never `sync_data` (except after the header and a
    /// repair). A power cut may lose the records the OS had not written yet.
    FlushOnly,
    /// `sync_data` after every `n` records: a power cut loses at most
    /// `n − 1` records (plus the torn one, which is repaired).
    Every(NonZeroU32),
}

impl Default for SyncPolicy {
    fn default() -> Self {
        SyncPolicy::Every(NonZeroU32::MIN)
    }
}

/// Appends records to a log, one complete line per write.
pub struct LogWriter<W: LogSink> {
    sink: W,
    columns: Columns,
    policy: SyncPolicy,
    unsynced: u32,
    records: u64,
    line: String,
    poisoned: bool,
}

impl<W: LogSink> LogWriter<W> {
    /// Writes the metadata and header to a new sink.
    ///
    /// A `format: micropos-measurement-log/1` entry is always written first;
    /// `metadata` may repeat it but not give another value. Keys must be
    /// non-empty without whitespace, `:`, `=` or control characters; values
    /// single-line without surrounding whitespace, so that they read back
    /// identically.
    pub fn create(
        mut sink: W,
        metadata: &Metadata,
        columns: Columns,
        policy: SyncPolicy,
    ) -> Result<Self, LogError> {
        columns.validate()?;
        let mut text = format!("# {FORMAT_KEY}: {FORMAT_ID}\n");
        for (key, value) in metadata.iter() {
            let bad = |reason| LogError::InvalidMetadata {
                key: key.to_owned(),
                reason,
            };
            if key.is_empty()
                || key
                    .contains(|c: char| c.is_whitespace() || c.is_control() || c == ':' || c == '=')
            {
                return Err(bad(
                    "keys must be non-empty, without whitespace, ':', '=' or control characters",
                ));
            }
            if value.contains(char::is_control) {
                return Err(bad(
                    "values must not contain control characters (line breaks)",
                ));
            }
            if value.trim() != value {
                return Err(bad("values must not start or end with whitespace"));
            }
            if key == FORMAT_KEY {
                if value != FORMAT_ID {
                    return Err(bad("the format key is reserved for the format identifier"));
                }
                continue;
            }
            let _ = writeln!(text, "# {key}: {value}");
        }
        text.push_str(&columns.header_line());
        text.push('\n');
        sink.write_all(text.as_bytes())?;
        sink.flush()?;
        sink.sync_data()?;
        Ok(Self::resume(sink, columns, policy, 0))
    }

    fn resume(sink: W, columns: Columns, policy: SyncPolicy, records: u64) -> Self {
        Self {
            sink,
            columns,
            policy,
            unsynced: 0,
            records,
            line: String::with_capacity(256),
            poisoned: false,
        }
    }

    /// Appends one record: validates it, writes its line in one call, flushes,
    /// and syncs as the policy says. On an I/O error the writer refuses
    /// further records ([`LogError::Poisoned`]) because the file may now end
    /// in a partial line; [`open_append`] repairs it.
    pub fn append(&mut self, record: &Record) -> Result<(), LogError> {
        if self.poisoned {
            return Err(LogError::Poisoned);
        }
        self.line.clear();
        format_record(&self.columns, record, &mut self.line)?;
        let result = self.write_line();
        if result.is_err() {
            self.poisoned = true;
        }
        result
    }

    fn write_line(&mut self) -> Result<(), LogError> {
        self.sink.write_all(self.line.as_bytes())?;
        self.sink.flush()?;
        self.records += 1;
        self.unsynced += 1;
        if let SyncPolicy::Every(n) = self.policy {
            if self.unsynced >= n.get() {
                self.sink.sync_data()?;
                self.unsynced = 0;
            }
        }
        Ok(())
    }

    /// Forces everything written so far to stable storage (call at the end
    /// of a job, or before a planned shutdown, under [`SyncPolicy::FlushOnly`]).
    pub fn sync(&mut self) -> Result<(), LogError> {
        if self.poisoned {
            return Err(LogError::Poisoned);
        }
        self.sink.flush()?;
        self.sink.sync_data()?;
        self.unsynced = 0;
        Ok(())
    }

    /// Columns this writer writes.
    pub fn columns(&self) -> &Columns {
        &self.columns
    }

    /// Records in the log, including those found by [`open_append`].
    pub fn records(&self) -> u64 {
        self.records
    }

    /// The sink, e.g. the bytes of an in-memory log.
    pub fn into_inner(self) -> W {
        self.sink
    }
}

fn check_text(field: &str, value: &str) -> Result<(), LogError> {
    if value.contains(char::is_control) {
        return Err(LogError::InvalidRecord {
            field: field.to_owned(),
            reason: format!("{value:?} contains a control character"),
        });
    }
    Ok(())
}

fn check_number(field: &str, v: f64) -> Result<(), LogError> {
    if !v.is_finite() || v.abs() > MAX_ABS_VALUE {
        return Err(LogError::InvalidRecord {
            field: field.to_owned(),
            reason: format!("{v} is not a finite number within ±1e9"),
        });
    }
    Ok(())
}

/// Formats one record line (with `\n`) after checking it can be read back.
fn format_record(columns: &Columns, r: &Record, out: &mut String) -> Result<(), LogError> {
    for (name, v) in r.numbers() {
        check_number(name, v)?;
    }
    if r.segment.trim().is_empty() {
        return Err(LogError::InvalidRecord {
            field: "segment".into(),
            reason: "segment name is empty".into(),
        });
    }
    check_text("segment", &r.segment)?;
    match (columns.temp_c, r.temp_c) {
        (false, Some(_)) => {
            return Err(LogError::InvalidRecord {
                field: TEMP_COLUMN.into(),
                reason: "the log has no temp_c column; the temperature would be lost".into(),
            })
        }
        (_, Some(t)) => check_number(TEMP_COLUMN, t)?,
        _ => {}
    }
    if r.extra.len() != columns.extra.len() {
        return Err(LogError::InvalidRecord {
            field: "extra".into(),
            reason: format!(
                "{} extra values for {} extra columns",
                r.extra.len(),
                columns.extra.len()
            ),
        });
    }
    for (name, v) in columns.extra.iter().zip(&r.extra) {
        check_text(name, v)?;
    }

    let p = POSITION_DECIMALS;
    let _ = write!(out, "{:.*},", TIME_DECIMALS, r.t_s);
    push_field(out, &r.segment);
    let _ = write!(
        out,
        ",{},{:.p$},{:.p$},{:.p$},{:.p$},{:.p$},{:.p$}",
        r.cycle, r.x_target_um, r.y_target_um, r.x_cmd_um, r.y_cmd_um, r.x_meas_um, r.y_meas_um
    );
    if columns.temp_c {
        out.push(',');
        if let Some(t) = r.temp_c {
            let _ = write!(out, "{:.*}", TEMP_DECIMALS, t);
        }
    }
    for v in &r.extra {
        out.push(',');
        push_field(out, v);
    }
    out.push('\n');
    Ok(())
}

/// Creates a new log file and writes its metadata and header. Refuses to
/// overwrite an existing file (a previous job's data is never clobbered; use
/// [`open_append`] to continue it).
pub fn create_file(
    path: impl AsRef<Path>,
    metadata: &Metadata,
    columns: Columns,
    policy: SyncPolicy,
) -> Result<LogWriter<File>, LogError> {
    let path = path.as_ref();
    let file = OpenOptions::new().write(true).create_new(true).open(path)?;
    let writer = LogWriter::create(file, metadata, columns, policy)?;
    sync_parent_dir(path)?;
    Ok(writer)
}

/// Makes the directory entry of a new file durable (POSIX needs a sync of the
/// directory for that; elsewhere this is a no-op).
fn sync_parent_dir(path: &Path) -> Result<(), LogError> {
    #[cfg(unix)]
    {
        let parent = match path.parent() {
            Some(p) if !p.as_os_str().is_empty() => p,
            _ => Path::new("."),
        };
        File::open(parent)?.sync_all()?;
    }
    #[cfg(not(unix))]
    let _ = path;
    Ok(())
}

/// What [`open_append`] found in the existing log.
#[derive(Debug, Clone, PartialEq)]
pub struct Resume {
    /// Metadata of the existing log.
    pub metadata: Metadata,
    /// Number of complete records kept.
    pub records: u64,
    /// The last complete record kept: the job resumes after it.
    pub last_record: Option<Record>,
    /// The unterminated last line that was cut off, if any. It is either a
    /// torn line (`error` is `Some`) or a line that parsed but lacked its
    /// terminator (`error` is `None`); both are dropped because the writer
    /// always terminates its lines, so the point will simply be measured
    /// again.
    pub repaired: Option<RepairedTail>,
    /// Warnings from reading the existing log.
    pub warnings: Vec<Warning>,
}

/// The bytes [`open_append`] cut off the end of a log.
#[derive(Debug, Clone, PartialEq)]
pub struct RepairedTail {
    /// 1-based line number of the removed line.
    pub line: usize,
    /// Byte offset it started at (the new file length).
    pub offset: u64,
    /// Bytes removed.
    pub len: u64,
    /// Why it did not parse, if it did not.
    pub error: Option<LineError>,
}

/// Opens an existing log to continue a job after a restart or a crash.
///
/// Reads the whole file (streaming), refuses it if any line other than an
/// unterminated last one is malformed or if its columns differ from
/// `expected`, cuts off an unterminated last line (torn by a crash, or a
/// record whose terminator never made it to disk), syncs the repair, and
/// returns a writer positioned at the end together with the last complete
/// record. Records are thus never duplicated nor lost: the caller resumes
/// after `last_record`.
///
/// Only one writer may have a log open at a time; the daemon's job manager
/// guarantees this (no file lock is taken).
pub fn open_append(
    path: impl AsRef<Path>,
    expected: &Columns,
    policy: SyncPolicy,
) -> Result<(LogWriter<File>, Resume), LogError> {
    let mut file = OpenOptions::new()
        .read(true)
        .write(true)
        .open(path.as_ref())?;
    let file_len = file.metadata()?.len();
    let mut reader = LogReader::new(BufReader::new(&file))?;
    if reader.columns != *expected {
        return Err(LogError::ColumnsMismatch {
            expected: expected.header_line(),
            found: reader.columns.header_line(),
        });
    }
    let mut records = 0u64;
    let mut previous = None;
    let mut last_record = None;
    while let Some(r) = reader.next_record()? {
        records += 1;
        previous = last_record.replace(r);
    }
    let LogReader {
        metadata,
        mut warnings,
        torn_tail,
        complete_len,
        header_terminated,
        last_record_terminated,
        line_no,
        ..
    } = reader;

    let mut repaired = None;
    if header_terminated && complete_len < file_len {
        // The file ends in bytes after the last newline: a torn line, an
        // unterminated record, or unterminated blanks. All go.
        let error = torn_tail.map(|t| t.error);
        if error.is_none() && last_record.is_some() && !last_record_terminated {
            records -= 1;
            last_record = previous;
            warnings.retain(|w| !(w.line == line_no && w.kind == WarningKind::NoFinalNewline));
        }
        repaired = Some(RepairedTail {
            line: line_no,
            offset: complete_len,
            len: file_len - complete_len,
            error,
        });
        file.set_len(complete_len)?;
        file.sync_data()?;
    }
    file.seek(SeekFrom::End(0))?;
    if !header_terminated {
        // The header is complete and right (checked above) but its newline
        // never reached the disk.
        file.write_all(b"\n")?;
        file.sync_data()?;
    }
    let writer = LogWriter::resume(file, expected.clone(), policy, records);
    Ok((
        writer,
        Resume {
            metadata,
            records,
            last_record,
            repaired,
            warnings,
        },
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn split_fields_handles_spaces_and_quotes() {
        let f = split_fields(" a , b,\"c, d\" ,\"e\"\"f\",,").unwrap();
        assert_eq!(f, vec!["a", "b", "c, d", "e\"f", "", ""]);
        assert_eq!(split_fields("").unwrap(), vec![""]);
        assert_eq!(
            split_fields("a,\"b"),
            Err(LineError::BadQuoting("quoted field is not closed"))
        );
        assert!(matches!(
            split_fields("\"a\"b,c"),
            Err(LineError::BadQuoting(_))
        ));
    }

    #[test]
    fn push_field_quotes_only_what_the_reader_would_change() {
        for v in [
            "plain",
            "a,b",
            "say \"hi\"",
            " lead",
            "trail\t",
            "#x",
            "",
            "é ü",
        ] {
            let mut s = String::new();
            push_field(&mut s, v);
            assert_eq!(split_fields(&s).unwrap(), vec![v], "{s:?}");
        }
        let mut s = String::new();
        push_field(&mut s, "plain");
        assert_eq!(s, "plain");
    }

    #[test]
    fn metadata_lines() {
        assert_eq!(
            parse_metadata_line("stage: M-111"),
            Some(("stage", "M-111"))
        );
        assert_eq!(parse_metadata_line("rate = 2 Hz"), Some(("rate", "2 Hz")));
        assert_eq!(
            parse_metadata_line("start:12:30:00"),
            Some(("start", "12:30:00"))
        );
        assert_eq!(parse_metadata_line("k=a:b"), Some(("k", "a:b")));
        assert_eq!(parse_metadata_line("Created at 12:30"), None);
        assert_eq!(parse_metadata_line("just words"), None);
        assert_eq!(parse_metadata_line(": empty key"), None);
    }

    #[test]
    fn metadata_keeps_order_and_replaces_in_place() {
        let mut m = Metadata::new();
        assert_eq!(m.insert("b", "1"), None);
        assert_eq!(m.insert("a", "2"), None);
        assert_eq!(m.insert("b", "3"), Some("1".into()));
        assert_eq!(m.iter().collect::<Vec<_>>(), vec![("b", "3"), ("a", "2")]);
        assert_eq!(m.get("a"), Some("2"));
        assert_eq!(m.get("c"), None);
        assert_eq!(m.len(), 2);
    }

    #[test]
    fn header_rules() {
        let h = |s: &str| parse_header(&split_fields(s).unwrap());
        let base = MANDATORY_COLUMNS.join(",");
        assert_eq!(h(&base).unwrap(), Columns::default());
        assert_eq!(
            h(&format!("{base},temp_c,focus,\"note, free\"")).unwrap(),
            Columns {
                temp_c: true,
                extra: vec!["focus".into(), "note, free".into()]
            }
        );
        assert_eq!(
            h(&format!("{base},focus,temp_c")),
            Err(LineError::MisplacedTemp { position: 11 })
        );
        assert!(matches!(
            h(&format!("{base},a,a")),
            Err(LineError::BadExtraColumn { position: 11, .. })
        ));
        assert!(matches!(
            h(&format!("{base},,a")),
            Err(LineError::BadExtraColumn { position: 10, .. })
        ));
        assert!(matches!(
            h(&format!("{base},t_s")),
            Err(LineError::BadExtraColumn { .. })
        ));
        assert_eq!(
            h("t_s,segment,cycle,y_target_um"),
            Err(LineError::BadHeader {
                position: 4,
                expected: "x_target_um",
                found: "y_target_um".into()
            })
        );
        assert!(matches!(
            h("t_s,segment"),
            Err(LineError::BadHeader { position: 3, .. })
        ));
    }

    #[test]
    fn writer_refuses_what_it_could_not_read_back() {
        let rec = Record {
            t_s: 0.0,
            segment: "scan_x".into(),
            cycle: 1,
            x_target_um: 0.0,
            y_target_um: 0.0,
            x_cmd_um: 0.0,
            y_cmd_um: 0.0,
            x_meas_um: 0.0,
            y_meas_um: 0.0,
            temp_c: None,
            extra: vec![],
        };
        let mut w = LogWriter::create(
            Vec::new(),
            &Metadata::new(),
            Columns::default(),
            SyncPolicy::default(),
        )
        .unwrap();
        w.append(&rec).unwrap();
        for bad in [
            Record {
                x_meas_um: f64::NAN,
                ..rec.clone()
            },
            Record {
                t_s: 2e9,
                ..rec.clone()
            },
            Record {
                segment: " ".into(),
                ..rec.clone()
            },
            Record {
                segment: "a\nb".into(),
                ..rec.clone()
            },
            Record {
                temp_c: Some(20.0),
                ..rec.clone()
            },
            Record {
                extra: vec!["x".into()],
                ..rec.clone()
            },
        ] {
            assert!(
                matches!(w.append(&bad), Err(LogError::InvalidRecord { .. })),
                "{bad:?}"
            );
        }
        assert_eq!(w.records(), 1);

        for (k, v) in [
            ("a b", "x"),
            ("", "x"),
            ("k:", "x"),
            ("k", " x"),
            ("k", "x\ny"),
            ("format", "other/2"),
        ] {
            let mut m = Metadata::new();
            m.insert(k, v);
            assert!(
                matches!(
                    LogWriter::create(Vec::new(), &m, Columns::default(), SyncPolicy::default()),
                    Err(LogError::InvalidMetadata { .. })
                ),
                "{k:?}: {v:?}"
            );
        }
        assert!(Columns::new(false, vec!["temp_c".into()]).is_err());
        assert!(Columns::new(false, vec!["a".into(), "a".into()]).is_err());
        assert!(Columns::new(false, vec!["a\tb".into()]).is_err());
    }

    /// A sink that fails after `budget` bytes, like a full disk.
    struct FullDisk {
        written: Vec<u8>,
        budget: usize,
    }
    impl Write for FullDisk {
        fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
            if self.budget == 0 {
                return Err(io::Error::new(io::ErrorKind::StorageFull, "disk full"));
            }
            let n = buf.len().min(self.budget);
            self.written.extend_from_slice(&buf[..n]);
            self.budget -= n;
            Ok(n)
        }
        fn flush(&mut self) -> io::Result<()> {
            Ok(())
        }
    }
    impl LogSink for FullDisk {
        fn sync_data(&mut self) -> io::Result<()> {
            Ok(())
        }
    }

    #[test]
    fn a_failed_write_poisons_the_writer() {
        let header_len = format!(
            "# {FORMAT_KEY}: {FORMAT_ID}\n{}\n",
            Columns::default().header_line()
        )
        .len();
        let sink = FullDisk {
            written: Vec::new(),
            budget: header_len + 10,
        };
        let mut w = LogWriter::create(
            sink,
            &Metadata::new(),
            Columns::default(),
            SyncPolicy::FlushOnly,
        )
        .unwrap();
        let rec = Record {
            t_s: 1.0,
            segment: "s".into(),
            cycle: 0,
            x_target_um: 1.0,
            y_target_um: 2.0,
            x_cmd_um: 3.0,
            y_cmd_um: 4.0,
            x_meas_um: 5.0,
            y_meas_um: 6.0,
            temp_c: None,
            extra: vec![],
        };
        assert!(matches!(w.append(&rec), Err(LogError::Io(_))));
        assert!(matches!(w.append(&rec), Err(LogError::Poisoned)));
        assert!(matches!(w.sync(), Err(LogError::Poisoned)));
        // What reached the "disk" is a header and a torn line, which the
        // reader reports as such.
        let bytes = w.into_inner().written;
        let log = parse_bytes(&bytes).unwrap();
        assert!(log.records.is_empty());
        assert_eq!(log.torn_tail.unwrap().line, 3);
    }
}
