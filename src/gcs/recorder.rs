//! The controller's data recorder (GCS 2.0): record tables that sample a
//! source (an axis) with a record option (what of it: commanded or actual
//! position, ...) every `RTR` servo cycles, started by a trigger (`DRT`),
//! read back with `DRR?` as *GCS array data*:
//!
//! ```text
//! # TYPE = 1 ⏎
//! # SEPARATOR = 32 ⏎
//! # DIM = 1 ⏎
//! # SAMPLE_TIME = 0.001000 ⏎
//! # NDATA = 3 ⏎
//! # NAME0 = Actual Position of 1 ⏎
//! # END_HEADER ⏎
//! 7.5001230 ⏎
//! 7.5002430 ⏎
//! 7.5003630
//! ```
//!
//! (every line but the last ends with the GCS continuation space; `DIM` is
//! the number of columns, one per table read, `SAMPLE_TIME` the time
//! between records in seconds, `NDATA` the number of rows.) This is the
//! format PIPython's `qDRR` reads (`getgcsheader` for the header, one float
//! per column per line after `# END_HEADER`).
//!
//! Why here: the simulated C-863 writes these answers and the driver reads
//! them; both use [`encode_records`] and [`parse_records`], so the format
//! is defined once. The parser reads outside data and never panics
//! (`fuzz/fuzz_targets/gcs_data_record.rs`, proptests below).

use thiserror::Error;

/// Record option 1: the commanded position of the source axis.
pub const RECORD_COMMANDED_POSITION: u32 = 1;
/// Record option 2: the actual (encoder) position of the source axis, what
/// `POS?` reports.
pub const RECORD_ACTUAL_POSITION: u32 = 2;
/// Record option 3: the position error (commanded − actual).
pub const RECORD_POSITION_ERROR: u32 = 3;

/// Trigger source 0: the controller's default (on a C-863, as 1).
pub const TRIGGER_DEFAULT: u32 = 0;
/// Trigger source 1: the next position-changing command (`MOV`, `MVR`, ...).
pub const TRIGGER_POSITION_CHANGING_COMMAND: u32 = 1;
/// Trigger source 4: immediately, when `DRT` is received.
pub const TRIGGER_IMMEDIATELY: u32 = 4;

/// Most columns or rows a reply may declare or hold: far above what a
/// controller sends (a C-863 holds 1024 points per table), low enough that
/// nothing a line says can make the reader allocate without bound.
pub const MAX_RECORDS: usize = 1 << 20;

/// Why a `DRR?` reply is not the data it should be.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum RecordError {
    /// No `# END_HEADER` line.
    #[error("no `# END_HEADER` line in the data recorder reply")]
    NoHeaderEnd,
    /// A header line is not `# KEY = value`.
    #[error("header line {0:?} is not of the form `# KEY = value`")]
    BadHeaderLine(String),
    /// A header value that must be a number is not (or is out of range).
    #[error("header {key} = {value:?} is not a valid number")]
    BadHeaderValue {
        /// The key.
        key: String,
        /// Its text.
        value: String,
    },
    /// `SAMPLE_TIME` is missing.
    #[error("the header has no SAMPLE_TIME")]
    NoSampleTime,
    /// A data line has a field that is not a finite number.
    #[error("data line {line}: {text:?} is not a number")]
    BadValue {
        /// 0-based data line.
        line: usize,
        /// The field.
        text: String,
    },
    /// A data line has a different number of fields than the first (or
    /// than `DIM`).
    #[error("data line {line} has {got} values, expected {expected}")]
    ColumnCount {
        /// 0-based data line.
        line: usize,
        /// Values found.
        got: usize,
        /// Values expected.
        expected: usize,
    },
    /// `NDATA` does not match the rows received.
    #[error("the header announces {announced} rows, the reply has {got}")]
    RowCount {
        /// `NDATA`.
        announced: usize,
        /// Rows received.
        got: usize,
    },
    /// More than [`MAX_RECORDS`] rows or columns.
    #[error("more than {MAX_RECORDS} values")]
    TooLarge,
}

/// A `DRR?` reply: its header in order, the sample time and the columns
/// (one per table read; every column has the same length).
#[derive(Debug, Clone, PartialEq)]
pub struct DataRecords {
    /// Header entries `(KEY, value)` in reply order, text as sent.
    pub header: Vec<(String, String)>,
    /// Time between two rows, s (`SAMPLE_TIME`).
    pub sample_time_s: f64,
    /// The values, column by column (controller units: mm for positions).
    pub columns: Vec<Vec<f64>>,
}

impl DataRecords {
    /// Rows in the reply.
    pub fn rows(&self) -> usize {
        self.columns.first().map_or(0, Vec::len)
    }

    /// The header value of `key` (case-insensitive), if any.
    pub fn get(&self, key: &str) -> Option<&str> {
        self.header
            .iter()
            .find(|(k, _)| k.eq_ignore_ascii_case(key))
            .map(|(_, v)| v.as_str())
    }
}

fn header_count(key: &str, value: &str) -> Result<usize, RecordError> {
    let bad = || RecordError::BadHeaderValue {
        key: key.to_owned(),
        value: value.to_owned(),
    };
    let n: usize = value.trim().parse().map_err(|_| bad())?;
    if n > MAX_RECORDS {
        return Err(RecordError::TooLarge);
    }
    Ok(n)
}

/// Reads the lines of a `DRR?` answer (continuation spaces and LFs already
/// removed, as [`super::Answer::lines`] gives them). Strict: every header
/// line must be `# KEY = value` (a `#` line without `=` is accepted as a
/// comment only if it is empty after the `#`), `SAMPLE_TIME` must be a
/// positive finite number, every data line must have the same number of
/// finite values (`DIM` if the header has it), and `NDATA`, if present,
/// must match the rows. Blank data lines are skipped.
pub fn parse_records(lines: &[String]) -> Result<DataRecords, RecordError> {
    let mut header = Vec::new();
    let mut body = None;
    for (i, l) in lines.iter().enumerate() {
        let t = l.trim();
        let Some(rest) = t.strip_prefix('#') else {
            return Err(RecordError::BadHeaderLine(l.clone()));
        };
        let rest = rest.trim();
        if rest.eq_ignore_ascii_case("END_HEADER") {
            body = Some(i + 1);
            break;
        }
        if rest.is_empty() {
            continue;
        }
        let (k, v) = rest
            .split_once('=')
            .ok_or_else(|| RecordError::BadHeaderLine(l.clone()))?;
        let k = k.trim();
        if k.is_empty() {
            return Err(RecordError::BadHeaderLine(l.clone()));
        }
        header.push((k.to_owned(), v.trim().to_owned()));
    }
    let body = body.ok_or(RecordError::NoHeaderEnd)?;
    let find = |key: &str| {
        header
            .iter()
            .find(|(k, _): &&(String, String)| k.eq_ignore_ascii_case(key))
            .map(|(_, v)| v.as_str())
    };
    let sample_time_s = match find("SAMPLE_TIME") {
        None => return Err(RecordError::NoSampleTime),
        Some(v) => match v.parse::<f64>() {
            Ok(x) if x.is_finite() && x > 0.0 => x,
            _ => {
                return Err(RecordError::BadHeaderValue {
                    key: "SAMPLE_TIME".into(),
                    value: v.to_owned(),
                })
            }
        },
    };
    let dim = find("DIM").map(|v| header_count("DIM", v)).transpose()?;
    let ndata = find("NDATA")
        .map(|v| header_count("NDATA", v))
        .transpose()?;
    let mut columns: Vec<Vec<f64>> = Vec::new();
    let mut expected = dim;
    let mut rows = 0usize;
    for (line, l) in lines.get(body..).unwrap_or_default().iter().enumerate() {
        let t = l.trim();
        if t.is_empty() {
            continue;
        }
        let mut values = Vec::new();
        for f in t.split_whitespace() {
            match f.parse::<f64>() {
                Ok(v) if v.is_finite() => values.push(v),
                _ => {
                    return Err(RecordError::BadValue {
                        line,
                        text: f.to_owned(),
                    })
                }
            }
            if values.len() > MAX_RECORDS {
                return Err(RecordError::TooLarge);
            }
        }
        let want = *expected.get_or_insert(values.len());
        if values.len() != want {
            return Err(RecordError::ColumnCount {
                line,
                got: values.len(),
                expected: want,
            });
        }
        if columns.is_empty() {
            columns = vec![Vec::new(); want];
        }
        for (c, v) in columns.iter_mut().zip(values) {
            c.push(v);
        }
        rows += 1;
        if rows > MAX_RECORDS {
            return Err(RecordError::TooLarge);
        }
    }
    if columns.is_empty() {
        columns = vec![Vec::new(); expected.unwrap_or(0)];
    }
    if let Some(n) = ndata {
        if n != rows {
            return Err(RecordError::RowCount {
                announced: n,
                got: rows,
            });
        }
    }
    Ok(DataRecords {
        header,
        sample_time_s,
        columns,
    })
}

/// The answer lines of `DRR?` for `columns` (each named, all of one length)
/// sampled every `sample_time_s`: the header (`TYPE`, `SEPARATOR`, `DIM`,
/// `SAMPLE_TIME`, `NDATA`, `NAMEn`), `# END_HEADER`, then one line per row,
/// values with 7 decimals separated by a space. Columns shorter than the
/// first are cut to the shortest.
pub fn encode_records(sample_time_s: f64, columns: &[(String, Vec<f64>)]) -> Vec<String> {
    let rows = columns.iter().map(|(_, c)| c.len()).min().unwrap_or(0);
    let mut out = vec![
        "# TYPE = 1".to_owned(),
        "# SEPARATOR = 32".to_owned(),
        format!("# DIM = {}", columns.len()),
        format!("# SAMPLE_TIME = {sample_time_s:.9}"),
        format!("# NDATA = {rows}"),
    ];
    for (i, (name, _)) in columns.iter().enumerate() {
        out.push(format!("# NAME{i} = {name}"));
    }
    out.push("# END_HEADER".to_owned());
    for r in 0..rows {
        let row: Vec<String> = columns
            .iter()
            .map(|(_, c)| format!("{:.7}", c.get(r).copied().unwrap_or(0.0)))
            .collect();
        out.push(row.join(" "));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lines(s: &str) -> Vec<String> {
        s.lines().map(str::to_owned).collect()
    }

    #[test]
    fn reads_what_the_encoder_writes() {
        let cols = vec![
            (
                "Actual Position of 1".to_owned(),
                vec![7.5, 7.5001, 7.50025],
            ),
            ("Commanded Position of 1".to_owned(), vec![7.5, 7.5, 7.5003]),
        ];
        let enc = encode_records(0.001, &cols);
        let r = parse_records(&enc).unwrap();
        assert_eq!(r.sample_time_s, 0.001);
        assert_eq!(r.rows(), 3);
        assert_eq!(r.columns[0], cols[0].1);
        assert_eq!(r.columns[1], cols[1].1);
        assert_eq!(r.get("name1"), Some("Commanded Position of 1"));
    }

    #[test]
    fn reads_a_controller_style_reply() {
        let r = parse_records(&lines(
            "# TYPE = 1\n# SEPARATOR = 32\n# DIM = 1\n# SAMPLE_TIME = 0.000050\n# NDATA = 2\n# NAME0 = Actual Position of 1\n# END_HEADER\n1.0000000\n-2.5",
        ))
        .unwrap();
        assert_eq!(r.sample_time_s, 5e-5);
        assert_eq!(r.columns, vec![vec![1.0, -2.5]]);
        // No rows at all is a valid (empty) reply.
        let r = parse_records(&lines("# SAMPLE_TIME = 0.001\n# DIM = 2\n# END_HEADER")).unwrap();
        assert_eq!(r.columns, vec![Vec::<f64>::new(), Vec::new()]);
    }

    #[test]
    fn refuses_what_does_not_fit() {
        let bad = [
            ("1.0\n2.0", "header"),
            ("# SAMPLE_TIME = 0.001\n1.0", "header line"),
            ("# SAMPLE_TIME = 0.001", "no end"),
            ("# DIM = 1\n# END_HEADER\n1.0", "no sample time"),
            ("# SAMPLE_TIME = -1\n# END_HEADER\n1.0", "negative"),
            ("# SAMPLE_TIME = nan\n# END_HEADER\n1.0", "nan"),
            (
                "# SAMPLE_TIME = 0.001\n# END_HEADER\n1.0 2.0\n3.0",
                "ragged",
            ),
            ("# SAMPLE_TIME = 0.001\n# DIM = 2\n# END_HEADER\n1.0", "dim"),
            ("# SAMPLE_TIME = 0.001\n# END_HEADER\n1.0\ninf", "inf"),
            ("# SAMPLE_TIME = 0.001\n# END_HEADER\n1.0\n1=2", "text"),
            (
                "# SAMPLE_TIME = 0.001\n# NDATA = 3\n# END_HEADER\n1.0",
                "ndata",
            ),
            (
                "# SAMPLE_TIME = 0.001\n# NDATA = 99999999999\n# END_HEADER",
                "huge",
            ),
            ("# SAMPLE_TIME = 0.001\n# no equals\n# END_HEADER", "key"),
        ];
        for (text, why) in bad {
            assert!(parse_records(&lines(text)).is_err(), "{why}: {text:?}");
        }
    }

    proptest::proptest! {
        /// Whatever the lines, the reader returns, never panics, and what
        /// it returns is consistent (columns of one length, a positive
        /// sample time).
        #[test]
        fn never_panics_on_arbitrary_lines(
            ls in proptest::collection::vec(".{0,40}", 0..12),
        ) {
            if let Ok(r) = parse_records(&ls) {
                proptest::prop_assert!(r.sample_time_s > 0.0);
                let n = r.rows();
                proptest::prop_assert!(r.columns.iter().all(|c| c.len() == n));
            }
        }

        /// Header-shaped noise mixed into a valid reply: still no panic.
        #[test]
        fn never_panics_on_mangled_replies(
            vals in proptest::collection::vec(-20.0f64..20.0, 0..30),
            cut in 0usize..40,
            junk in "[#= 0-9a-zA-Z.\\-]{0,20}",
        ) {
            let mut enc = encode_records(0.002, &[("p".to_owned(), vals.clone())]);
            let r = parse_records(&enc).unwrap();
            proptest::prop_assert_eq!(r.rows(), vals.len());
            for (a, b) in r.columns[0].iter().zip(&vals) {
                proptest::prop_assert!((a - b).abs() < 1e-7);
            }
            let at = cut.min(enc.len());
            enc.insert(at, junk);
            let _ = parse_records(&enc);
        }
    }
}
