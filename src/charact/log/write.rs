//! Writing a log point by point ([`LogWriter`]), creating one and resuming
//! one after a crash ([`create_file`], [`open_append`]).

use super::fields::push_field;
use super::*;
use std::os::unix::fs::OpenOptionsExt;

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

pub(super) fn check_text(field: &str, value: &str) -> Result<(), LogError> {
    if value.contains(char::is_control) {
        return Err(LogError::InvalidRecord {
            field: field.to_owned(),
            reason: format!("{value:?} contains a control character"),
        });
    }
    Ok(())
}

pub(super) fn check_number(field: &str, v: f64) -> Result<(), LogError> {
    if !v.is_finite() || v.abs() > MAX_ABS_VALUE {
        return Err(LogError::InvalidRecord {
            field: field.to_owned(),
            reason: format!("{v} is not a finite number within ±1e9"),
        });
    }
    Ok(())
}

/// Formats one record line (with `\n`) after checking it can be read back.
pub(super) fn format_record(
    columns: &Columns,
    r: &Record,
    out: &mut String,
) -> Result<(), LogError> {
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
    match (columns.theta_urad, r.theta_urad) {
        (false, Some(_)) => {
            return Err(LogError::InvalidRecord {
                field: THETA_COLUMN.into(),
                reason: "the log has no theta_urad column; the angle would be lost".into(),
            })
        }
        (_, Some(t)) => check_number(THETA_COLUMN, t)?,
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
    if columns.theta_urad {
        out.push(',');
        if let Some(t) = r.theta_urad {
            let _ = write!(out, "{:.*}", THETA_DECIMALS, t);
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
    // create_new (O_EXCL) fails on any existing entry, a link included.
    let file = OpenOptions::new().write(true).create_new(true).open(path)?;
    let writer = LogWriter::create(file, metadata, columns, policy)?;
    sync_parent_dir(path)?;
    Ok(writer)
}

/// Makes the directory entry of a new file durable (POSIX needs a sync of the
/// directory for that; elsewhere this is a no-op).
pub(super) fn sync_parent_dir(path: &Path) -> Result<(), LogError> {
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
    // A link planted where the log was is refused, never appended through.
    let mut file = OpenOptions::new()
        .read(true)
        .write(true)
        .custom_flags(libc::O_NOFOLLOW)
        .open(path.as_ref())?;
    let file_len = file.metadata()?.len();
    let mut reader = LogReader::new(BufReader::new(&file))?;
    if reader.columns() != expected {
        return Err(LogError::ColumnsMismatch {
            expected: expected.header_line(),
            found: reader.columns().header_line(),
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
