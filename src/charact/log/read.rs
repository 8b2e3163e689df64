//! Reading a log: [`LogReader`] over any `BufRead`, strict about content,
//! tolerant of what other programs write (see the module docs of
//! [`super`]).

use super::fields::split_fields;
use super::*;

pub(super) fn parse_header(fields: &[Cow<'_, str>]) -> Result<Columns, LineError> {
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
    let theta_urad = rest.first().is_some_and(|f| f == THETA_COLUMN);
    if theta_urad {
        rest = &rest[1..];
    }
    let first_extra = MANDATORY_COLUMNS.len() + usize::from(temp_c) + usize::from(theta_urad) + 1;
    let mut extra: Vec<String> = Vec::with_capacity(rest.len());
    for (i, name) in rest.iter().enumerate() {
        let position = first_extra + i;
        if name == TEMP_COLUMN {
            return Err(LineError::MisplacedTemp { position });
        }
        if name == THETA_COLUMN {
            return Err(LineError::MisplacedTheta { position });
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
    Ok(Columns {
        temp_c,
        theta_urad,
        extra,
    })
}

pub(super) fn parse_number(column: &str, value: &str) -> Result<f64, LineError> {
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

pub(super) fn parse_record(columns: &Columns, line: &str) -> Result<Record, LineError> {
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
    // An optional number column at `at`: an empty cell is `None`.
    let optional = |on: bool, at: usize, name: &str| -> Result<Option<f64>, LineError> {
        match f.get(at) {
            Some(v) if on && !v.is_empty() => parse_number(name, v).map(Some),
            _ => Ok(None),
        }
    };
    let temp_c = optional(columns.temp_c, MANDATORY_COLUMNS.len(), TEMP_COLUMN)?;
    let theta_at = MANDATORY_COLUMNS.len() + usize::from(columns.temp_c);
    let theta_urad = optional(columns.theta_urad, theta_at, THETA_COLUMN)?;
    let first_extra = theta_at + usize::from(columns.theta_urad);
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
        theta_urad,
        extra: f[first_extra..].iter().map(|s| s.to_string()).collect(),
    })
}

/// Parses a `#` line above the header: `Some((key, value))` for metadata,
/// `None` for a free comment.
pub(super) fn parse_metadata_line(text: &str) -> Option<(&str, &str)> {
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
/// (Fields are visible to `write`, whose resume takes a reader apart.)
pub struct LogReader<R> {
    pub(super) inner: R,
    pub(super) buf: Vec<u8>,
    pub(super) line_no: usize,
    pub(super) offset: u64,
    pub(super) complete_len: u64,
    pub(super) metadata: Metadata,
    pub(super) comments: Vec<String>,
    pub(super) columns: Columns,
    pub(super) header_terminated: bool,
    pub(super) warnings: Vec<Warning>,
    pub(super) warnings_dropped: usize,
    pub(super) torn_tail: Option<TornTail>,
    pub(super) last_t_s: Option<f64>,
    pub(super) last_record_terminated: bool,
    pub(super) finished: bool,
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
    read_from(crate::nofollow::open(path.as_ref())?)
}
