//! Converts common ISO 230-2 exports into the measurement-log format
//! (`micropos import`), so a measurement from another instrument or lab
//! reaches `diagnose`, `plot` and `tables build` without a hand-edited
//! file.
//!
//! Two inputs are understood (format: `docs/measurement-log.md`,
//! "Importing ISO 230-2 exports"):
//! * **CSV**: one row per arrival, a header naming the columns (any order,
//!   case-insensitive, separator `,` `;` or tab): target (`target`,
//!   `setpoint`, `nominal`, `position`, …), reading (`measured`, `reading`,
//!   `actual`, …) or deviation (`deviation`, `error`: ISO 230-2's
//!   `x_ij = measured − target`), direction (`direction`, `approach`,
//!   `dir`: forward/backward, fwd/bwd, up/down, +/−), cycle (`cycle`,
//!   `run`); optionally a time (`t_s`, `time_s`). A unit suffix on a name
//!   (`target_mm`) sets its unit; [`ImportOptions::units`] overrides.
//! * **`.dat`** (`KEY=VALUE` lines, as written by the ecmc ISO 230-2
//!   tools): `TGT_DATA[i]` targets, `REF_DATA_FWD[i,j]` / `REF_DATA_BWD[i,j]`
//!   readings of target `i` in cycle `j`, optional `UNIT` (default mm).
//! * **Markdown reports** (pipe tables under headings, as the ecmc test
//!   tools print them): a table under a heading that names the direction
//!   (`forward`/`backward`, `positive`/`negative`) with either one row per
//!   arrival (position index, cycle, target, reference reading; the drive's
//!   own motor/resolver columns are ignored) or one row per target with a
//!   reading column per cycle (`ref_pos(i,j)`). Empty cells are arrivals
//!   that were not measured; they are skipped and counted in the metadata.
//!   The second layout (written by ecmc's `ecmcISO230_2.py`) prints its
//!   input's `REF_DATA_BWD` readings, the approaches from above, under
//!   "forward" and vice versa in every version published (2021–2023), so
//!   [`DirectionLabels::Auto`] swaps its labels and says so in the metadata.
//!
//! The log written is a 1-D log: the measured axis ([`ImportOptions::axis`])
//! gets target = command = the target, meas = the reading; the other axis's
//! columns are 0 placeholders, and the metadata says so
//! (`measured_axes`). An `approach` column carries the true approach
//! direction (the approach moves of an ISO test are usually not logged, so
//! a replay of the commands alone cannot see it). Rows of a `.dat` follow
//! the standard's order (per cycle: forward over increasing targets, then
//! backward over decreasing ones); rows of a CSV keep the file's order.
//! Times are the CSV's when it has them, else synthetic (1 s per row, said
//! in the metadata).
//!
//! Parsing is sans-IO ([`import_bytes`]), never panics, and names the line
//! and column of anything it refuses.

use std::collections::BTreeMap;

use thiserror::Error;

use super::log::{Columns, LogError, LogWriter, Metadata, Record, SyncPolicy, MAX_ABS_VALUE};
use crate::model::Axis;

mod report;
use report::parse_report;

/// Length units of an export.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Unit {
    /// Metres.
    M,
    /// Millimetres (the usual ISO 230-2 export unit).
    Mm,
    /// Micrometres.
    Um,
    /// Nanometres.
    Nm,
}

impl Unit {
    /// µm per unit.
    pub fn um(self) -> f64 {
        match self {
            Unit::M => 1e6,
            Unit::Mm => 1e3,
            Unit::Um => 1.0,
            Unit::Nm => 1e-3,
        }
    }

    /// Parses `m`, `mm`, `um`/`µm`/`micron`, `nm` (case-insensitive).
    pub fn parse(s: &str) -> Option<Unit> {
        match s.trim().to_ascii_lowercase().as_str() {
            "m" => Some(Unit::M),
            "mm" => Some(Unit::Mm),
            "um" | "µm" | "μm" | "micron" | "microns" => Some(Unit::Um),
            "nm" => Some(Unit::Nm),
            _ => None,
        }
    }
}

/// Which export format the input is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ImportFormat {
    /// Decide from the content: `KEY=VALUE` lines with `TGT_DATA` → dat,
    /// else CSV.
    Auto,
    /// One row per arrival with a header.
    Csv,
    /// `KEY=VALUE` lines (`TGT_DATA[i]`, `REF_DATA_FWD[i,j]`, …).
    Dat,
    /// A markdown test report: pipe tables of readings under headings that
    /// name the approach direction.
    Report,
}

/// How to read the direction labels of a markdown report.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum DirectionLabels {
    /// As labelled, except the one layout known to print them swapped
    /// (ecmc's per-target `ref_pos(i,j)` tables, see the module docs).
    #[default]
    Auto,
    /// As the headings say.
    AsLabelled,
    /// Forward tables are the approaches from above and vice versa.
    Swapped,
}

/// How to import.
#[derive(Debug, Clone, PartialEq)]
pub struct ImportOptions {
    /// Input format.
    pub format: ImportFormat,
    /// The axis the measurement is of (the other is logged as unmeasured).
    pub axis: Axis,
    /// Units of every length in the input; `None`: from the header's name
    /// suffixes (CSV) or `UNIT` (dat, default mm).
    pub units: Option<Unit>,
    /// Free text for the log's `source` metadata (e.g. the file name).
    pub source: Option<String>,
    /// How a markdown report's direction labels are read (other formats
    /// name the direction per row or per key and ignore it).
    pub directions: DirectionLabels,
}

impl Default for ImportOptions {
    fn default() -> Self {
        ImportOptions {
            format: ImportFormat::Auto,
            axis: Axis::X,
            units: None,
            source: None,
            directions: DirectionLabels::Auto,
        }
    }
}

/// Why an export could not be imported.
#[derive(Debug, Error, PartialEq)]
pub enum ImportError {
    /// A line (1-based) is malformed; `column` names the field when one is
    /// to blame.
    #[error("line {line}{}: {message}", column.as_ref().map(|c| format!(", column {c}")).unwrap_or_default())]
    Line {
        /// 1-based line number.
        line: usize,
        /// The column at fault, if any.
        column: Option<String>,
        /// What is wrong.
        message: String,
    },
    /// The CSV header lacks a column the import needs.
    #[error("line {line}: no {what} column in the header (accepted names: {accepted})")]
    MissingColumn {
        /// 1-based line of the header.
        line: usize,
        /// What is missing (`target`, `reading or deviation`, …).
        what: &'static str,
        /// Names that would have been recognized.
        accepted: String,
    },
    /// The units of a column cannot be told.
    #[error("units unknown for column {column}: add a suffix (_mm, _um, _nm, _m) to its name or give --units")]
    UnknownUnits {
        /// The column.
        column: String,
    },
    /// The input holds no data.
    #[error("no measurement in the input")]
    Empty,
    /// A `.dat` reading refers to a target that has no `TGT_DATA`.
    #[error("line {line}: {key} refers to target {index}, which has no TGT_DATA[{index}]")]
    UnknownTarget {
        /// 1-based line.
        line: usize,
        /// The key.
        key: String,
        /// The target index.
        index: u32,
    },
    /// A report holds no table of readings the import can read.
    #[error("no table of readings: a report needs a table under a heading naming the direction (forward/backward) with a target column and either a cycle and a reading (reference) column or a reading column per cycle (ref_pos(i,1), …)")]
    NoReadingTable,
    /// The log writer refused the converted content.
    #[error("cannot write the log: {0}")]
    Log(String),
}

impl From<LogError> for ImportError {
    fn from(e: LogError) -> Self {
        ImportError::Log(e.to_string())
    }
}

/// One arrival at a target.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Arrival {
    /// Target, µm.
    pub target_um: f64,
    /// Reading of the reference, µm.
    pub measured_um: f64,
    /// `+1` forward (towards larger positions), `−1` backward.
    pub approach: f64,
    /// Cycle.
    pub cycle: u32,
    /// Time, s, when the input has one.
    pub t_s: Option<f64>,
}

/// An export parsed: its arrivals, the unit it was written in and what the
/// log's metadata must say about how it was read.
#[derive(Debug, Clone, PartialEq)]
pub struct Parsed {
    /// The arrivals, in the order the log gets them.
    pub arrivals: Vec<Arrival>,
    /// The unit of the input's lengths.
    pub unit: Unit,
    /// Metadata entries (key, value) describing the reading of the input
    /// (layout, direction labels, skipped cells).
    pub notes: Vec<(String, String)>,
}

/// Converts an export into measurement-log bytes (see the module docs).
pub fn import_bytes(data: &[u8], opts: &ImportOptions) -> Result<Vec<u8>, ImportError> {
    let p = parse_export(data, opts)?;
    write_log_with_notes(&p.arrivals, opts, p.unit, &p.notes)
}

/// Parses an export into arrivals (µm) and the unit the input was in.
pub fn parse_arrivals(
    data: &[u8],
    opts: &ImportOptions,
) -> Result<(Vec<Arrival>, Unit), ImportError> {
    let p = parse_export(data, opts)?;
    Ok((p.arrivals, p.unit))
}

/// Whether `l` is the separator row under a markdown table's header
/// (`--- | --- |`, `|:--|--:|`).
fn is_table_rule(l: &str) -> bool {
    let t = l.trim();
    t.contains('-')
        && t.contains('|')
        && t.chars().all(|c| matches!(c, '-' | '|' | ':' | ' ' | '\t'))
}

/// Parses an export (see the module docs).
pub fn parse_export(data: &[u8], opts: &ImportOptions) -> Result<Parsed, ImportError> {
    let text = match std::str::from_utf8(data) {
        Ok(t) => t,
        Err(e) => {
            let line = 1 + data[..e.valid_up_to()]
                .iter()
                .filter(|&&b| b == b'\n')
                .count();
            return Err(ImportError::Line {
                line,
                column: None,
                message: "not valid UTF-8".into(),
            });
        }
    };
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let format = match opts.format {
        ImportFormat::Auto => {
            if text.lines().any(|l| {
                let l = l.trim_start();
                l.starts_with("TGT_DATA[") || l.starts_with("REF_DATA_")
            }) {
                ImportFormat::Dat
            } else if text.lines().any(is_table_rule) {
                ImportFormat::Report
            } else {
                ImportFormat::Csv
            }
        }
        f => f,
    };
    let out = match format {
        ImportFormat::Dat => {
            let (arrivals, unit) = parse_dat(text, opts.units)?;
            Parsed {
                arrivals,
                unit,
                notes: Vec::new(),
            }
        }
        ImportFormat::Report => parse_report(text, opts.units, opts.directions)?,
        _ => {
            let (arrivals, unit) = parse_csv(text, opts.units)?;
            Parsed {
                arrivals,
                unit,
                notes: Vec::new(),
            }
        }
    };
    if out.arrivals.is_empty() {
        return Err(ImportError::Empty);
    }
    Ok(out)
}

/// Parses a finite number, naming line and column when it is not one.
pub(super) fn number(s: &str, line: usize, column: &str) -> Result<f64, ImportError> {
    let t = s.trim();
    let v: f64 = t.parse().map_err(|_| ImportError::Line {
        line,
        column: Some(column.to_string()),
        message: format!("{t:?} is not a number"),
    })?;
    if !v.is_finite() {
        return Err(ImportError::Line {
            line,
            column: Some(column.to_string()),
            message: format!("{t:?} is not finite"),
        });
    }
    Ok(v)
}

/// Converts `v` in `unit` to µm, refusing what a log cannot hold.
pub(super) fn to_um(v: f64, unit: Unit, line: usize, column: &str) -> Result<f64, ImportError> {
    let um = v * unit.um();
    if !um.is_finite() || um.abs() > MAX_ABS_VALUE {
        return Err(ImportError::Line {
            line,
            column: Some(column.to_string()),
            message: format!("{v} is beyond ±1e9 µm"),
        });
    }
    Ok(um)
}

fn cycle_of(s: &str, line: usize, column: &str) -> Result<u32, ImportError> {
    let t = s.trim();
    // Integers, also written as `3.0` by spreadsheets.
    let v = number(t, line, column)?;
    if v < 0.0 || v.fract() != 0.0 || v > f64::from(u32::MAX) {
        return Err(ImportError::Line {
            line,
            column: Some(column.to_string()),
            message: format!("{t:?} is not a non-negative integer"),
        });
    }
    Ok(v as u32)
}

pub(super) fn direction_of(s: &str, line: usize, column: &str) -> Result<f64, ImportError> {
    let t = s.trim().trim_matches('"');
    match t.to_ascii_lowercase().as_str() {
        "forward" | "fwd" | "f" | "up" | "+" | "pos" | "positive" | "1" | "+1" | "↑" => Ok(1.0),
        "backward" | "bwd" | "b" | "down" | "-" | "−" | "neg" | "negative" | "-1" | "↓" => {
            Ok(-1.0)
        }
        _ => Err(ImportError::Line {
            line,
            column: Some(column.to_string()),
            message: format!("{t:?} is not a direction (forward/backward, fwd/bwd, up/down, +/-)"),
        }),
    }
}

/// Accepted header names per role (without unit suffix).
const TARGET_NAMES: &[&str] = &[
    "target",
    "setpoint",
    "set_point",
    "nominal",
    "position",
    "target_position",
    "tgt",
    "p_i",
    "pi",
];
const READING_NAMES: &[&str] = &[
    "measured",
    "reading",
    "actual",
    "meas",
    "measured_position",
    "reference",
    "ref",
    "value",
];
const DEVIATION_NAMES: &[&str] = &["deviation", "error", "dev", "x_ij", "xij"];
const DIRECTION_NAMES: &[&str] = &["direction", "approach", "dir"];
const CYCLE_NAMES: &[&str] = &["cycle", "run", "cycle_no", "j"];
const TIME_NAMES: &[&str] = &["t_s", "time_s", "time"];

/// A header name split into its role name and unit suffix.
fn split_unit(name: &str) -> (String, Option<Unit>) {
    let n = name.trim().trim_matches('"').trim().to_ascii_lowercase();
    // `target [mm]`, `target (mm)`, `target_mm`.
    for (open, close) in [("[", "]"), ("(", ")")] {
        if let (Some(a), true) = (n.rfind(open), n.ends_with(close)) {
            if let Some(u) = Unit::parse(&n[a + 1..n.len() - 1]) {
                return (n[..a].trim().replace(' ', "_"), Some(u));
            }
        }
    }
    if let Some((base, suffix)) = n.rsplit_once('_') {
        if let Some(u) = Unit::parse(suffix) {
            if !base.is_empty() {
                return (base.to_string(), Some(u));
            }
        }
    }
    (n.replace(' ', "_"), None)
}

fn split_fields(line: &str, sep: char) -> Vec<&str> {
    line.split(sep)
        .map(|f| f.trim().trim_matches('"').trim())
        .collect()
}

fn parse_csv(text: &str, units: Option<Unit>) -> Result<(Vec<Arrival>, Unit), ImportError> {
    let mut lines = text
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l))
        .filter(|(_, l)| !l.trim().is_empty() && !l.trim_start().starts_with('#'));
    let Some((hline, header)) = lines.next() else {
        return Err(ImportError::Empty);
    };
    let sep = [',', ';', '\t']
        .into_iter()
        .max_by_key(|c| header.matches(*c).count())
        .unwrap_or(',');
    let names: Vec<(String, Option<Unit>)> = split_fields(header, sep)
        .into_iter()
        .map(split_unit)
        .collect();
    let raw: Vec<&str> = split_fields(header, sep);
    let find = |accepted: &[&str]| {
        names
            .iter()
            .position(|(n, _)| accepted.contains(&n.as_str()))
    };
    let missing = |what: &'static str, accepted: &[&str]| ImportError::MissingColumn {
        line: hline,
        what,
        accepted: accepted.join(", "),
    };
    let target = find(TARGET_NAMES).ok_or_else(|| missing("target", TARGET_NAMES))?;
    let reading = find(READING_NAMES);
    let deviation = find(DEVIATION_NAMES);
    let value = reading.or(deviation).ok_or_else(|| {
        missing(
            "reading or deviation",
            &[READING_NAMES, DEVIATION_NAMES].concat(),
        )
    })?;
    let is_deviation = reading.is_none();
    let direction = find(DIRECTION_NAMES).ok_or_else(|| missing("direction", DIRECTION_NAMES))?;
    let cycle = find(CYCLE_NAMES).ok_or_else(|| missing("cycle", CYCLE_NAMES))?;
    let time = find(TIME_NAMES);
    let unit_of = |col: usize| -> Result<Unit, ImportError> {
        units
            .or(names[col].1)
            .ok_or_else(|| ImportError::UnknownUnits {
                column: raw[col].to_string(),
            })
    };
    let target_unit = unit_of(target)?;
    let value_unit = unit_of(value)?;
    let mut out = Vec::new();
    for (line, l) in lines {
        let f = split_fields(l, sep);
        if f.len() != names.len() {
            return Err(ImportError::Line {
                line,
                column: None,
                message: format!(
                    "{} fields, the header has {} (separator {sep:?})",
                    f.len(),
                    names.len()
                ),
            });
        }
        let t = to_um(
            number(f[target], line, raw[target])?,
            target_unit,
            line,
            raw[target],
        )?;
        let v = to_um(
            number(f[value], line, raw[value])?,
            value_unit,
            line,
            raw[value],
        )?;
        let measured_um = if is_deviation { t + v } else { v };
        if measured_um.abs() > MAX_ABS_VALUE {
            return Err(ImportError::Line {
                line,
                column: Some(raw[value].to_string()),
                message: "target + deviation is beyond ±1e9 µm".into(),
            });
        }
        let t_s = match time {
            Some(c) => {
                let v = number(f[c], line, raw[c])?;
                if v.abs() > MAX_ABS_VALUE {
                    return Err(ImportError::Line {
                        line,
                        column: Some(raw[c].to_string()),
                        message: format!("{v} is beyond ±1e9 s"),
                    });
                }
                Some(v)
            }
            None => None,
        };
        out.push(Arrival {
            target_um: t,
            measured_um,
            approach: direction_of(f[direction], line, raw[direction])?,
            cycle: cycle_of(f[cycle], line, raw[cycle])?,
            t_s,
        });
    }
    Ok((out, target_unit))
}

/// `NAME[a]` or `NAME[a,b]` → (NAME, [a, b?]).
fn indexed_key(key: &str) -> Option<(&str, Vec<u32>)> {
    let open = key.find('[')?;
    let inner = key[open + 1..].strip_suffix(']')?;
    let idx: Option<Vec<u32>> = inner.split(',').map(|s| s.trim().parse().ok()).collect();
    Some((key[..open].trim(), idx?))
}

fn parse_dat(text: &str, units: Option<Unit>) -> Result<(Vec<Arrival>, Unit), ImportError> {
    let mut unit = Unit::Mm;
    let mut targets: BTreeMap<u32, (f64, usize)> = BTreeMap::new();
    // (target index, cycle, approach sign as i8) → (raw value, line)
    let mut readings: BTreeMap<(u32, u32, i8), (f64, usize)> = BTreeMap::new();
    for (i, l) in text.lines().enumerate() {
        let line = i + 1;
        let l = l.trim();
        if l.is_empty() || l.starts_with('#') {
            continue;
        }
        let Some((key, value)) = l.split_once('=') else {
            return Err(ImportError::Line {
                line,
                column: None,
                message: "expected KEY=VALUE".into(),
            });
        };
        let key = key.trim();
        let value = value.trim();
        if key.eq_ignore_ascii_case("UNIT") {
            unit = Unit::parse(value).ok_or_else(|| ImportError::Line {
                line,
                column: Some("UNIT".into()),
                message: format!("{value:?} is not a unit (m, mm, um, nm)"),
            })?;
            continue;
        }
        let Some((name, idx)) = indexed_key(key) else {
            // Other settings (CYCLES, POSITIONS, REF_PV, …) carry no data.
            continue;
        };
        let bad_index = || ImportError::Line {
            line,
            column: Some(key.to_string()),
            message: "wrong number of indices".into(),
        };
        match name {
            "TGT_DATA" => {
                let [p] = idx[..] else {
                    return Err(bad_index());
                };
                let v = number(value, line, key)?;
                if targets.insert(p, (v, line)).is_some() {
                    return Err(ImportError::Line {
                        line,
                        column: Some(key.to_string()),
                        message: "target defined twice".into(),
                    });
                }
            }
            "REF_DATA_FWD" | "REF_DATA_BWD" => {
                let [p, c] = idx[..] else {
                    return Err(bad_index());
                };
                let dir = if name == "REF_DATA_FWD" { 1 } else { -1 };
                let v = number(value, line, key)?;
                if readings.insert((p, c, dir), (v, line)).is_some() {
                    return Err(ImportError::Line {
                        line,
                        column: Some(key.to_string()),
                        message: "reading defined twice".into(),
                    });
                }
            }
            _ => {}
        }
    }
    let unit = units.unwrap_or(unit);
    let mut cycles: Vec<u32> = readings.keys().map(|k| k.1).collect();
    cycles.sort_unstable();
    cycles.dedup();
    // Targets in increasing position (the index order need not be).
    let mut order: Vec<(u32, f64)> = targets.iter().map(|(&p, &(v, _))| (p, v)).collect();
    order.sort_by(|a, b| a.1.total_cmp(&b.1));
    for (&(p, _, _), &(_, line)) in &readings {
        if !targets.contains_key(&p) {
            let key = format!("REF_DATA[{p}]");
            return Err(ImportError::UnknownTarget {
                line,
                key,
                index: p,
            });
        }
    }
    let mut out = Vec::new();
    for &c in &cycles {
        let pass = |dir: i8, out: &mut Vec<Arrival>| -> Result<(), ImportError> {
            let it: Box<dyn Iterator<Item = &(u32, f64)>> = if dir > 0 {
                Box::new(order.iter())
            } else {
                Box::new(order.iter().rev())
            };
            for &(p, t) in it {
                if let Some(&(v, line)) = readings.get(&(p, c, dir)) {
                    let tline = targets.get(&p).map_or(line, |x| x.1);
                    out.push(Arrival {
                        target_um: to_um(t, unit, tline, "TGT_DATA")?,
                        measured_um: to_um(v, unit, line, "REF_DATA")?,
                        approach: f64::from(dir),
                        cycle: c,
                        t_s: None,
                    });
                }
            }
            Ok(())
        };
        pass(1, &mut out)?;
        pass(-1, &mut out)?;
    }
    Ok((out, unit))
}

/// Writes arrivals as a 1-D measurement log (see the module docs).
pub fn write_log(
    arrivals: &[Arrival],
    opts: &ImportOptions,
    source_unit: Unit,
) -> Result<Vec<u8>, ImportError> {
    write_log_with_notes(arrivals, opts, source_unit, &[])
}

/// [`write_log`] with extra metadata entries describing how the input was
/// read ([`Parsed::notes`]).
pub fn write_log_with_notes(
    arrivals: &[Arrival],
    opts: &ImportOptions,
    source_unit: Unit,
    notes: &[(String, String)],
) -> Result<Vec<u8>, ImportError> {
    if arrivals.is_empty() {
        return Err(ImportError::Empty);
    }
    let other = match opts.axis {
        Axis::X => Axis::Y,
        Axis::Y => Axis::X,
    };
    let mut md = Metadata::new();
    md.insert(super::log::FORMAT_KEY, super::log::FORMAT_ID);
    md.insert("imported_by", "micropos import");
    if let Some(s) = &opts.source {
        // Metadata values are one line.
        let clean: String = s.chars().filter(|c| !c.is_control()).collect();
        md.insert("source", clean);
    }
    md.insert(
        "source_unit",
        match source_unit {
            Unit::M => "m",
            Unit::Mm => "mm",
            Unit::Um => "um",
            Unit::Nm => "nm",
        },
    );
    md.insert(
        crate::analysis::diagnose::MEASURED_AXES_KEY,
        opts.axis.as_str(),
    );
    md.insert(
        "axis_mapping",
        format!(
            "single linear axis -> {}; {} not measured ({} target/cmd/meas = 0 placeholders)",
            opts.axis, other, other
        ),
    );
    let synthetic = arrivals.iter().any(|a| a.t_s.is_none());
    md.insert(
        "time_source",
        if synthetic {
            "synthetic: record order, 1 s per point (the input has no times)"
        } else {
            "the input's time column"
        },
    );
    md.insert("error_sign", "target - meas (micropos)");
    for (k, v) in notes {
        let clean: String = v.chars().filter(|c| !c.is_control()).collect();
        md.insert(k.as_str(), clean);
    }
    let columns = Columns::new(
        false,
        vec![crate::analysis::diagnose::APPROACH_COLUMN.into()],
    )?;
    let mut w = LogWriter::create(Vec::new(), &md, columns, SyncPolicy::FlushOnly)?;
    let segment = match opts.axis {
        Axis::X => "scan_x",
        Axis::Y => "scan_y",
    };
    for (k, a) in arrivals.iter().enumerate() {
        let t_s = if synthetic {
            k as f64
        } else {
            a.t_s.unwrap_or(k as f64)
        };
        let (x, y, xm, ym) = match opts.axis {
            Axis::X => (a.target_um, 0.0, a.measured_um, 0.0),
            Axis::Y => (0.0, a.target_um, 0.0, a.measured_um),
        };
        w.append(&Record {
            t_s,
            segment: segment.into(),
            cycle: a.cycle,
            x_target_um: x,
            y_target_um: y,
            x_cmd_um: x,
            y_cmd_um: y,
            x_meas_um: xm,
            y_meas_um: ym,
            temp_c: None,
            theta_urad: None,
            extra: vec![if a.approach > 0.0 { "fwd" } else { "bwd" }.into()],
        })?;
    }
    Ok(w.into_inner())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::charact::log::parse_bytes;

    const CSV: &str = "cycle,direction,target_mm,measured_mm\n\
        1,forward,-10,-10.0000990190\n\
        1,forward,0.24,0.2399139810\n\
        1,backward,0.24,0.2399279810\n\
        1,backward,-10,-10.0000810190\n\
        2,forward,-10,-10.0000940190\n\
        2,forward,0.24,0.2398979810\n\
        2,backward,0.24,0.2399099810\n\
        2,backward,-10,-10.0001020190\n";

    #[test]
    fn csv_with_unit_suffixes_becomes_a_1d_log() {
        let bytes = import_bytes(CSV.as_bytes(), &ImportOptions::default()).unwrap();
        let log = parse_bytes(&bytes).unwrap();
        assert_eq!(log.records.len(), 8);
        assert_eq!(log.metadata.get("measured_axes"), Some("x"));
        let r = &log.records[0];
        assert_eq!(r.x_target_um, -10_000.0);
        assert!((r.x_meas_um - (-10_000.099_019)).abs() < 1e-3);
        assert_eq!((r.y_target_um, r.y_meas_um), (0.0, 0.0));
        assert_eq!(log.records[2].extra, vec!["bwd".to_string()]);
        assert_eq!(log.records[7].cycle, 2);
    }

    #[test]
    fn csv_with_deviation_semicolons_and_units_option() {
        let text = "Run;Dir;Setpoint;Deviation\n1;+;10;0.5\n1;-;10;-0.5\n";
        let opts = ImportOptions {
            units: Some(Unit::Um),
            axis: Axis::Y,
            ..ImportOptions::default()
        };
        let log = parse_bytes(&import_bytes(text.as_bytes(), &opts).unwrap()).unwrap();
        assert_eq!(log.records[0].y_meas_um, 10.5);
        assert_eq!(log.records[1].y_meas_um, 9.5);
        assert_eq!(log.records[0].segment, "scan_y");
        assert_eq!(log.metadata.get("measured_axes"), Some("y"));
    }

    #[test]
    fn csv_errors_name_line_and_column() {
        let text = "cycle,direction,target_mm,measured_mm\n1,forward,abc,1\n";
        let e = import_bytes(text.as_bytes(), &ImportOptions::default()).unwrap_err();
        assert_eq!(
            e.to_string(),
            "line 2, column target_mm: \"abc\" is not a number"
        );
        let text = "cycle,direction,target,measured\n1,forward,1,1\n";
        let e = import_bytes(text.as_bytes(), &ImportOptions::default()).unwrap_err();
        assert!(matches!(e, ImportError::UnknownUnits { .. }), "{e}");
        let text = "cycle,target_mm,measured_mm\n1,1,1\n";
        let e = import_bytes(text.as_bytes(), &ImportOptions::default()).unwrap_err();
        assert!(e.to_string().contains("no direction column"), "{e}");
        let text = "cycle,direction,target_mm,measured_mm\n1,sideways,1,1\n";
        let e = import_bytes(text.as_bytes(), &ImportOptions::default()).unwrap_err();
        assert!(e.to_string().starts_with("line 2, column direction"), "{e}");
        let text = "cycle,direction,target_mm,measured_mm\n1,fwd,1\n";
        let e = import_bytes(text.as_bytes(), &ImportOptions::default()).unwrap_err();
        assert!(e.to_string().starts_with("line 2:"), "{e}");
    }

    const DAT: &str = "TEST_DATA=# comment\nUNIT=mm\nCYCLES=2\nTGT_DATA[1]=15\nTGT_DATA[2]=25.2\n\
        REF_DATA_FWD[1,1]=15.1\nREF_DATA_FWD[2,1]=25.3\nREF_DATA_BWD[1,1]=15.0\nREF_DATA_BWD[2,1]=25.2\n\
        REF_DATA_FWD[1,2]=14.9\nREF_DATA_FWD[2,2]=25.2\nREF_DATA_BWD[1,2]=15.0\nREF_DATA_BWD[2,2]=25.1\n";

    #[test]
    fn dat_follows_the_standard_order() {
        let log =
            parse_bytes(&import_bytes(DAT.as_bytes(), &ImportOptions::default()).unwrap()).unwrap();
        let seq: Vec<(u32, f64, &str)> = log
            .records
            .iter()
            .map(|r| (r.cycle, r.x_target_um, r.extra[0].as_str()))
            .collect();
        assert_eq!(
            seq,
            vec![
                (1, 15000.0, "fwd"),
                (1, 25200.0, "fwd"),
                (1, 25200.0, "bwd"),
                (1, 15000.0, "bwd"),
                (2, 15000.0, "fwd"),
                (2, 25200.0, "fwd"),
                (2, 25200.0, "bwd"),
                (2, 15000.0, "bwd"),
            ]
        );
        assert!((log.records[0].x_meas_um - 15100.0).abs() < 1e-6);
    }

    #[test]
    fn dat_errors_name_the_line() {
        let e = import_bytes(
            b"TGT_DATA[1]=15\nREF_DATA_FWD[2,1]=1\n",
            &ImportOptions::default(),
        )
        .unwrap_err();
        assert!(e.to_string().starts_with("line 2:"), "{e}");
        let e = import_bytes(
            b"TGT_DATA[1]=15\nREF_DATA_FWD[1,1]=x\n",
            &ImportOptions::default(),
        )
        .unwrap_err();
        assert_eq!(
            e.to_string(),
            "line 2, column REF_DATA_FWD[1,1]: \"x\" is not a number"
        );
        let e =
            import_bytes(b"TGT_DATA[1]=15\nUNIT=furlong\n", &ImportOptions::default()).unwrap_err();
        assert!(e.to_string().starts_with("line 2, column UNIT"), "{e}");
    }

    const REPORT_LONG: &str = "# Report\n\n# Forward test sequence\n\n\
        i (pos id)| j (cycle)| Tgt_pos(i,j) [mm] | Motor(i,j) [mm] | Reference(i,j) [mm] | x(i,j) [mm]\n\
        --- | --- | --- | --- | --- |--- |\n\
        1 | 1 | 15.00000 | 15.00070 | 15.00161 | .00161 |\n\
        2 | 1 | 25.00000 | 25.00078 | 25.02160 | .02160 |\n\
        1 | 2 | 15.00000 | 15.00070 | 15.00141 | .00141 |\n\
        2 | 2 | 25.00000 | 25.00078 | | |\n\
        \n# Backward test sequence\n\
        i (pos id)| j (cycle)| Tgt_pos(i,j) [mm] | Motor(i,j) [mm] | Reference(i,j) [mm] | x(i,j) [mm]\n\
        --- | --- | --- | --- | --- |--- |\n\
        1 | 1 | 15.20000 | 15.19945 | 15.19889 | -.00111 |\n\
        2 | 1 | 25.20000 | 25.19929 | 25.22130 | .02130 |\n\
        \n# Mean Position Deviation\n\
        i (pos id) | Tgt_pos(i) [mm] | X_fwd(i) [mm]\n--- | --- | --- |\n1 | 15.0 | .001\n";

    #[test]
    fn a_report_with_a_row_per_arrival_is_read_by_its_headings() {
        let p = parse_export(REPORT_LONG.as_bytes(), &ImportOptions::default()).unwrap();
        let seq: Vec<(u32, f64, f64, f64)> = p
            .arrivals
            .iter()
            .map(|a| (a.cycle, a.approach, a.target_um, a.measured_um))
            .collect();
        // Standard order; the empty cell is skipped and counted; targets
        // as the rows give them (the backward ones 0.2 mm apart).
        assert_eq!(seq.len(), 5);
        assert_eq!(seq[0].0, 1);
        assert_eq!((seq[0].1, seq[0].2), (1.0, 15_000.0));
        assert!((seq[0].3 - 15_001.61).abs() < 1e-6);
        assert_eq!((seq[2].1, seq[2].2), (-1.0, 25_200.0));
        assert_eq!((seq[3].1, seq[3].2), (-1.0, 15_200.0));
        assert_eq!(seq[4].0, 2);
        let note = |k: &str| p.notes.iter().find(|n| n.0 == k).map(|n| n.1.clone());
        assert_eq!(
            note("direction_labels").as_deref(),
            Some("as the headings say")
        );
        assert!(note("unmeasured_cells").is_some_and(|v| v.starts_with("1 ")));
        let log =
            parse_bytes(&import_bytes(REPORT_LONG.as_bytes(), &ImportOptions::default()).unwrap())
                .unwrap();
        assert_eq!(log.records.len(), 5);
    }

    const REPORT_WIDE: &str = "### Data forward direction\n\n\
        i |tgt_pos(i) [mm]|ref_pos(i,1) [mm]|ref_pos(i,2) [mm]|\n--- |--- |--- |--- |\n\
        1|15.0|15.00335|15.00233|\n2|25.2|25.19974|25.20015|\n\n\
        ### Data backward direction\n\n\
        i |tgt_pos(i) [mm]|ref_pos(i,1) [mm]|ref_pos(i,2) [mm]|\n--- |--- |--- |--- |\n\
        1|15.0|15.00518|15.00518|\n2|25.2|25.19628|25.19607|\n";

    #[test]
    fn a_report_with_a_column_per_cycle_swaps_its_labels_unless_told() {
        let p = parse_export(REPORT_WIDE.as_bytes(), &ImportOptions::default()).unwrap();
        assert_eq!(p.arrivals.len(), 8);
        // "forward" 15.00335 (cycle 1) is the approach from above.
        let a = p
            .arrivals
            .iter()
            .find(|a| a.cycle == 1 && a.target_um == 15_000.0 && a.approach < 0.0)
            .unwrap();
        assert!((a.measured_um - 15_003.35).abs() < 1e-6);
        assert!(p
            .notes
            .iter()
            .any(|n| n.0 == "direction_labels" && n.1.starts_with("swapped")));
        let opts = ImportOptions {
            directions: DirectionLabels::AsLabelled,
            ..ImportOptions::default()
        };
        let p = parse_export(REPORT_WIDE.as_bytes(), &opts).unwrap();
        let a = p
            .arrivals
            .iter()
            .find(|a| a.cycle == 1 && a.target_um == 15_000.0 && a.approach > 0.0)
            .unwrap();
        assert!((a.measured_um - 15_003.35).abs() < 1e-6);
    }

    #[test]
    fn report_errors_name_line_and_column() {
        let e = import_bytes(
            b"# x\n\nA | B\n--- | ---\n1 | 2\n",
            &ImportOptions::default(),
        )
        .unwrap_err();
        assert_eq!(e, ImportError::NoReadingTable);
        let bad = REPORT_LONG.replace("15.00161", "1x.5");
        let e = import_bytes(bad.as_bytes(), &ImportOptions::default()).unwrap_err();
        assert!(
            e.to_string()
                .starts_with("line 7, column Reference(i,j) [mm]"),
            "{e}"
        );
        let twice = format!("{REPORT_WIDE}\n### Data forward direction again\n\ni |tgt_pos(i) [mm]|ref_pos(i,1) [mm]|\n--- |--- |--- |\n1|15.0|15.1|\n");
        let e = import_bytes(twice.as_bytes(), &ImportOptions::default()).unwrap_err();
        assert!(e.to_string().contains("read twice"), "{e}");
        let nounit = "# Forward\nj | tgt | reference\n--- | --- | ---\n1 | 1 | 1\n";
        let e = import_bytes(nounit.as_bytes(), &ImportOptions::default()).unwrap_err();
        assert!(matches!(e, ImportError::UnknownUnits { .. }), "{e}");
    }
}
