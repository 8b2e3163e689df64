//! Converts 2-D grid exports (an XY stage mapped point by point by an
//! outside reference, e.g. a plane-mirror laser interferometer) into the
//! measurement-log format (`micropos import`, `--format grid`), so
//! `diagnose` reads them as maps (`analysis::grid`).
//!
//! Two inputs are understood:
//! * **Header-plus-rows exports** (as written by Aerotech's `Accuracy2D`
//!   test): `Key : value` lines, then a line of column names holding
//!   `Position1`, `LaserData1`, `Position2`, `LaserData2` (commanded
//!   position and reference reading of the two axes; any other columns, e.g.
//!   `AirTemp`, `MatTemp`, `Pressure`, `Humidity`, are carried through),
//!   then `:START` and one whitespace-separated row per point, optionally
//!   closed by `:END`. Lengths in mm unless [`GridImportOptions::units`]
//!   says otherwise. Axis 1 becomes x, axis 2 y. `MatTemp` becomes
//!   `temp_c`. The header's keys are kept as `source_*` metadata.
//! * **CSV** with a header (separator `,`, `;` or tab; names
//!   case-insensitive, a unit suffix `_mm`, `_um`, `_nm`, `_m` sets a
//!   column's unit): the commanded position of each axis (`x_target`,
//!   `x_cmd`, `x_nominal`, `x_setpoint`, `x_position`, `x`; likewise `y_…`)
//!   and, per axis, either the reference reading (`x_meas`, `x_measured`,
//!   `x_reading`, `x_actual`, `x_laser`) or the error (`x_error`,
//!   `x_deviation`, `ex`); optional `cycle`, `t_s` / `time_s`, `temp_c`,
//!   `direction` (how the point was reached on both axes: `forward` /
//!   `fwd` / `+` from below, `backward` / `bwd` / `-` from above) and any
//!   other columns (carried through). An error column's sign is
//!   [`GridImportOptions::error_sign`] (default ISO 230-2's
//!   `measured − target`).
//!
//! The log written has one segment `grid` (a grid with a direction column:
//! `grid_fwd` and `grid_bwd`, which `tables build` makes a map per
//! direction of), target = command = the commanded position, meas = the
//! reading, both axes measured. A point visited again (in the same
//! direction) is the next cycle of its target. Times are the input's,
//! else synthetic (1 s per row, said in the metadata, so `diagnose` draws
//! nothing from them). Parsing is sans-IO, never panics, and names the
//! line and column of anything it refuses.

use super::import::{number, to_um, ImportError, Unit};
use super::log::{Columns, LogWriter, Metadata, Record, SyncPolicy};

/// Which sign an error column has.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ErrorSign {
    /// `measured − target` (ISO 230-2's deviation; most exports).
    #[default]
    MeasuredMinusTarget,
    /// `target − measured` (the measurement log's and the paper's).
    TargetMinusMeasured,
}

/// How to import a grid.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct GridImportOptions {
    /// Units of every length; `None`: CSV name suffixes, else mm.
    pub units: Option<Unit>,
    /// Sign of error columns (CSV).
    pub error_sign: ErrorSign,
    /// Free text for the log's `source` metadata (e.g. the file name).
    pub source: Option<String>,
}

/// One point of a grid: commanded and measured per axis (µm), and the
/// carried columns as text.
#[derive(Debug, Clone, PartialEq)]
struct Point {
    cmd_um: [f64; 2],
    meas_um: [f64; 2],
    t_s: Option<f64>,
    temp_c: Option<f64>,
    cycle: Option<u32>,
    /// `+1` reached from below on both axes, `−1` from above.
    direction: Option<f64>,
    extra: Vec<String>,
}

/// A grid parsed: points, the unit read, extra column names and metadata.
struct Grid {
    points: Vec<Point>,
    unit: Unit,
    extra: Vec<String>,
    notes: Vec<(String, String)>,
}

/// Whether `data` looks like a grid export this module reads (a
/// header-plus-rows export, or a CSV whose header names a target of both
/// axes).
pub fn is_grid_export(data: &[u8]) -> bool {
    let text = String::from_utf8_lossy(data);
    if text.lines().any(|l| l.trim() == ":START") {
        return true;
    }
    let Some(header) = text
        .lines()
        .map(str::trim)
        .find(|l| !l.is_empty() && !l.starts_with('#'))
    else {
        return false;
    };
    let names = header_names(header);
    find(&names, TARGETS[0]).is_some() && find(&names, TARGETS[1]).is_some()
}

/// Converts a grid export into measurement-log bytes (module docs).
pub fn import_grid_bytes(data: &[u8], opts: &GridImportOptions) -> Result<Vec<u8>, ImportError> {
    let text = std::str::from_utf8(data).map_err(|e| ImportError::Line {
        line: 1 + data[..e.valid_up_to()]
            .iter()
            .filter(|&&b| b == b'\n')
            .count(),
        column: None,
        message: "not UTF-8 text".into(),
    })?;
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let grid = if text.lines().any(|l| l.trim() == ":START") {
        parse_rows(text, opts)?
    } else {
        parse_csv(text, opts)?
    };
    write(&grid, opts)
}

/// The header-plus-rows export (module docs).
fn parse_rows(text: &str, opts: &GridImportOptions) -> Result<Grid, ImportError> {
    let lines: Vec<&str> = text.lines().collect();
    let mut notes = Vec::new();
    let start = lines
        .iter()
        .position(|l| l.trim() == ":START")
        .ok_or(ImportError::Empty)?;
    for l in &lines[..start] {
        if let Some((k, v)) = l.split_once(" : ") {
            let key: String = k
                .trim()
                .chars()
                .map(|c| {
                    if c.is_ascii_alphanumeric() {
                        c.to_ascii_lowercase()
                    } else {
                        '_'
                    }
                })
                .collect();
            if !key.is_empty() && !v.trim().is_empty() {
                notes.push((format!("source_{key}"), v.trim().to_string()));
            }
        }
    }
    let (hline, header) = lines[..start]
        .iter()
        .enumerate()
        .rev()
        .find(|(_, l)| !l.trim().is_empty())
        .ok_or(ImportError::MissingColumn {
            line: start + 1,
            what: "column names",
            accepted: "Position1 LaserData1 Position2 LaserData2".into(),
        })?;
    let names: Vec<String> = header.split_whitespace().map(|s| s.to_string()).collect();
    let col = |want: &'static str| -> Result<usize, ImportError> {
        names
            .iter()
            .position(|n| n.eq_ignore_ascii_case(want))
            .ok_or(ImportError::MissingColumn {
                line: hline + 1,
                what: want,
                accepted: want.into(),
            })
    };
    let (p1, l1, p2, l2) = (
        col("Position1")?,
        col("LaserData1")?,
        col("Position2")?,
        col("LaserData2")?,
    );
    let temp = names.iter().position(|n| n.eq_ignore_ascii_case("MatTemp"));
    let extra_idx: Vec<usize> = (0..names.len())
        .filter(|&i| ![p1, l1, p2, l2].contains(&i) && Some(i) != temp)
        .collect();
    let extra: Vec<String> = extra_idx.iter().map(|&i| snake(&names[i])).collect();
    let unit = opts.units.unwrap_or(Unit::Mm);
    let mut points = Vec::new();
    for (k, l) in lines.iter().enumerate().skip(start + 1) {
        let line = k + 1;
        let t = l.trim();
        if t.is_empty() {
            continue;
        }
        if t.starts_with(':') {
            break;
        }
        let f: Vec<&str> = t.split_whitespace().collect();
        if f.len() != names.len() {
            return Err(ImportError::Line {
                line,
                column: None,
                message: format!("{} fields, the header names {}", f.len(), names.len()),
            });
        }
        let get = |i: usize| -> Result<f64, ImportError> {
            to_um(number(f[i], line, &names[i])?, unit, line, &names[i])
        };
        points.push(Point {
            cmd_um: [get(p1)?, get(p2)?],
            meas_um: [get(l1)?, get(l2)?],
            t_s: None,
            temp_c: match temp {
                Some(i) => Some(number(f[i], line, &names[i])?),
                None => None,
            },
            cycle: None,
            direction: None,
            extra: extra_idx.iter().map(|&i| f[i].to_string()).collect(),
        });
    }
    notes.push((
        "axis_mapping".into(),
        "x = the file's axis 1 (Position1/LaserData1); y = axis 2 (Position2/LaserData2)".into(),
    ));
    if temp.is_some() {
        notes.push((
            "temperature".into(),
            "temp_c = the file's MatTemp (material temperature), degC".into(),
        ));
    }
    Ok(Grid {
        points,
        unit,
        extra,
        notes,
    })
}

/// Lower-case name with non-alphanumerics as `_` (`AirTemp` → `air_temp`
/// is not attempted: `airtemp`).
fn snake(s: &str) -> String {
    s.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() {
                c.to_ascii_lowercase()
            } else {
                '_'
            }
        })
        .collect()
}

const TARGETS: [&[&str]; 2] = [
    &[
        "x_target",
        "x_cmd",
        "x_nominal",
        "x_setpoint",
        "x_position",
        "x",
    ],
    &[
        "y_target",
        "y_cmd",
        "y_nominal",
        "y_setpoint",
        "y_position",
        "y",
    ],
];
const READINGS: [&[&str]; 2] = [
    &["x_meas", "x_measured", "x_reading", "x_actual", "x_laser"],
    &["y_meas", "y_measured", "y_reading", "y_actual", "y_laser"],
];
const ERRORS: [&[&str]; 2] = [
    &["x_error", "x_deviation", "ex"],
    &["y_error", "y_deviation", "ey"],
];

fn split(line: &str) -> Vec<&str> {
    let sep = [',', ';', '\t']
        .into_iter()
        .max_by_key(|&c| line.matches(c).count())
        .unwrap_or(',');
    line.split(sep).map(str::trim).collect()
}

/// Header names, lower-cased, split from their unit suffix.
fn header_names(line: &str) -> Vec<(String, Option<Unit>)> {
    split(line)
        .into_iter()
        .map(|n| {
            let n = n.trim().trim_matches('"').to_ascii_lowercase();
            for (suffix, unit) in [
                ("_um", Unit::Um),
                ("_mm", Unit::Mm),
                ("_nm", Unit::Nm),
                ("_m", Unit::M),
            ] {
                if let Some(stem) = n.strip_suffix(suffix) {
                    if !stem.is_empty() {
                        return (stem.to_string(), Some(unit));
                    }
                }
            }
            (n, None)
        })
        .collect()
}

fn find(names: &[(String, Option<Unit>)], accepted: &[&str]) -> Option<usize> {
    accepted
        .iter()
        .find_map(|a| names.iter().position(|(n, _)| n == a))
}

/// The generic CSV (module docs).
fn parse_csv(text: &str, opts: &GridImportOptions) -> Result<Grid, ImportError> {
    let mut lines = text.lines().enumerate().filter(|(_, l)| {
        let t = l.trim();
        !t.is_empty() && !t.starts_with('#')
    });
    let (hline, header) = lines.next().ok_or(ImportError::Empty)?;
    let hline = hline + 1;
    let names = header_names(header);
    let need = |accepted: &[&str], what: &'static str| {
        find(&names, accepted).ok_or_else(|| ImportError::MissingColumn {
            line: hline,
            what,
            accepted: accepted.join(", "),
        })
    };
    let target = [need(TARGETS[0], "x target")?, need(TARGETS[1], "y target")?];
    let mut value = [(0usize, false); 2];
    for a in 0..2 {
        value[a] = match (find(&names, READINGS[a]), find(&names, ERRORS[a])) {
            (Some(i), _) => (i, false),
            (None, Some(i)) => (i, true),
            (None, None) => {
                return Err(ImportError::MissingColumn {
                    line: hline,
                    what: if a == 0 {
                        "x reading or error"
                    } else {
                        "y reading or error"
                    },
                    accepted: [READINGS[a], ERRORS[a]].concat().join(", "),
                })
            }
        };
    }
    let time = find(&names, &["t_s", "time_s", "t", "time"]);
    let temp = find(
        &names,
        &["temp_c", "temperature_c", "temp", "temperature", "mattemp"],
    );
    let cycle = find(&names, &["cycle", "run", "iteration"]);
    let direction = find(&names, &["direction", "dir", "approach"]);
    let used = [target[0], target[1], value[0].0, value[1].0];
    let extra_idx: Vec<usize> = (0..names.len())
        .filter(|i| !used.contains(i) && ![time, temp, cycle, direction].contains(&Some(*i)))
        .collect();
    let extra: Vec<String> = extra_idx.iter().map(|&i| snake(&names[i].0)).collect();
    // Every length column needs a unit: its suffix, or the option.
    let unit_of = |i: usize| -> Result<Unit, ImportError> {
        opts.units
            .or(names[i].1)
            .ok_or_else(|| ImportError::UnknownUnits {
                column: names[i].0.clone(),
            })
    };
    let units = [
        unit_of(target[0])?,
        unit_of(target[1])?,
        unit_of(value[0].0)?,
        unit_of(value[1].0)?,
    ];
    let mut points = Vec::new();
    for (k, l) in lines {
        let line = k + 1;
        let f = split(l);
        if f.len() != names.len() {
            return Err(ImportError::Line {
                line,
                column: None,
                message: format!("{} fields, the header names {}", f.len(), names.len()),
            });
        }
        let len = |i: usize, u: Unit| -> Result<f64, ImportError> {
            to_um(number(f[i], line, &names[i].0)?, u, line, &names[i].0)
        };
        let cmd = [len(target[0], units[0])?, len(target[1], units[1])?];
        let mut meas = [0.0; 2];
        for a in 0..2 {
            let v = len(value[a].0, units[2 + a])?;
            meas[a] = if !value[a].1 {
                v
            } else {
                match opts.error_sign {
                    ErrorSign::MeasuredMinusTarget => cmd[a] + v,
                    ErrorSign::TargetMinusMeasured => cmd[a] - v,
                }
            };
        }
        let opt_num = |i: Option<usize>| -> Result<Option<f64>, ImportError> {
            match i {
                Some(i) if !f[i].is_empty() => Ok(Some(number(f[i], line, &names[i].0)?)),
                _ => Ok(None),
            }
        };
        let cycle = match opt_num(cycle)? {
            Some(c) if c >= 0.0 && c.fract() == 0.0 && c <= f64::from(u32::MAX) => Some(c as u32),
            Some(c) => {
                return Err(ImportError::Line {
                    line,
                    column: Some("cycle".into()),
                    message: format!("{c} is not a cycle number (a whole number ≥ 0)"),
                })
            }
            None => None,
        };
        let direction = match direction {
            Some(i) => Some(super::import::direction_of(f[i], line, &names[i].0)?),
            None => None,
        };
        points.push(Point {
            cmd_um: cmd,
            meas_um: meas,
            t_s: opt_num(time)?,
            temp_c: opt_num(temp)?,
            cycle,
            direction,
            extra: extra_idx.iter().map(|&i| f[i].to_string()).collect(),
        });
    }
    let mut notes = vec![(
        "axis_mapping".to_string(),
        "x and y as the input's columns name them".to_string(),
    )];
    if value.iter().any(|v| v.1) {
        notes.push((
            "source_error_sign".into(),
            match opts.error_sign {
                ErrorSign::MeasuredMinusTarget => {
                    "the input's error columns read as measured - target"
                }
                ErrorSign::TargetMinusMeasured => {
                    "the input's error columns read as target - measured"
                }
            }
            .into(),
        ));
    }
    Ok(Grid {
        points,
        unit: units[0],
        extra,
        notes,
    })
}

/// Writes the grid as a measurement log (module docs).
fn write(grid: &Grid, opts: &GridImportOptions) -> Result<Vec<u8>, ImportError> {
    if grid.points.is_empty() {
        return Err(ImportError::Empty);
    }
    let clean = |s: &str| -> String { s.chars().filter(|c| !c.is_control()).collect() };
    let mut md = Metadata::new();
    md.insert(super::log::FORMAT_KEY, super::log::FORMAT_ID);
    md.insert("imported_by", "micropos import (grid)");
    if let Some(s) = &opts.source {
        md.insert("source", clean(s));
    }
    md.insert(
        "source_unit",
        match grid.unit {
            Unit::M => "m",
            Unit::Mm => "mm",
            Unit::Um => "um",
            Unit::Nm => "nm",
        },
    );
    md.insert(crate::analysis::diagnose::MEASURED_AXES_KEY, "x,y");
    let synthetic = grid.points.iter().any(|p| p.t_s.is_none());
    md.insert(
        crate::analysis::diagnose::TIME_SOURCE_KEY,
        if synthetic {
            "synthetic: record order, 1 s per point (the input has no times)"
        } else {
            "the input's time column"
        },
    );
    md.insert("error_sign", "target - meas (micropos)");
    let directed = grid.points.iter().any(|p| p.direction.is_some());
    md.insert(
        "layout",
        if directed {
            "segments 'grid_fwd' (reached from below) and 'grid_bwd' (from above), from the input's direction column; a point visited again in one direction is the next cycle of its target"
        } else {
            "one segment 'grid'; a point visited again is the next cycle of its target"
        },
    );
    for (k, v) in &grid.notes {
        md.insert(k.as_str(), clean(v));
    }
    let has_temp = grid.points.iter().any(|p| p.temp_c.is_some());
    let columns = Columns::new(has_temp, grid.extra.clone())?;
    let mut w = LogWriter::create(Vec::new(), &md, columns, SyncPolicy::FlushOnly)?;
    let mut seen: std::collections::HashMap<(u64, u64, bool), u32> =
        std::collections::HashMap::new();
    for (i, p) in grid.points.iter().enumerate() {
        let above = p.direction.is_some_and(|d| d < 0.0);
        let key = (p.cmd_um[0].to_bits(), p.cmd_um[1].to_bits(), above);
        let visit = seen.entry(key).or_insert(0);
        *visit += 1;
        let segment = match (directed, above) {
            (false, _) => "grid",
            (true, false) => super::scan::SEGMENT_GRID_FWD,
            (true, true) => super::scan::SEGMENT_GRID_BWD,
        };
        w.append(&Record {
            t_s: p.t_s.unwrap_or(i as f64),
            segment: segment.into(),
            cycle: p.cycle.unwrap_or(*visit),
            x_target_um: p.cmd_um[0],
            y_target_um: p.cmd_um[1],
            x_cmd_um: p.cmd_um[0],
            y_cmd_um: p.cmd_um[1],
            x_meas_um: p.meas_um[0],
            y_meas_um: p.meas_um[1],
            temp_c: p.temp_c,
            theta_urad: None,
            extra: p.extra.clone(),
        })?;
    }
    Ok(w.into_inner())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::charact::log::parse_bytes;

    #[test]
    fn a_header_plus_rows_export_becomes_a_map() {
        let src = "JobName : demo\nTestType : Accuracy2D\n\n   Position1  LaserData1  Position2  LaserData2  AirTemp  MatTemp\n:START\n  -1.0  -0.99999  -1.0  -1.00002  21.2  21.4\n  0.0  0.00001  -1.0  -0.99998  21.2  21.4\n:END\n";
        let bytes = import_grid_bytes(src.as_bytes(), &GridImportOptions::default()).unwrap();
        let log = parse_bytes(&bytes).unwrap();
        assert_eq!(log.records.len(), 2);
        let r = &log.records[0];
        assert_eq!((r.x_target_um, r.y_target_um), (-1000.0, -1000.0));
        assert!((r.x_meas_um + 999.99).abs() < 1e-9);
        assert_eq!(r.temp_c, Some(21.4));
        assert_eq!(log.columns.extra, vec!["airtemp".to_string()]);
        assert_eq!(log.metadata.get("source_jobname"), Some("demo"));
        assert_eq!(log.metadata.get("measured_axes"), Some("x,y"));
        assert!(log
            .metadata
            .get("time_source")
            .unwrap()
            .starts_with("synthetic"));
    }

    #[test]
    fn a_csv_with_errors_takes_their_sign_from_the_options() {
        let src = "x_mm,y_mm,x_error_um,y_error_um,cycle\n1,2,0.5,-0.25,1\n1,2,0.25,0,2\n";
        let iso = import_grid_bytes(src.as_bytes(), &GridImportOptions::default()).unwrap();
        let log = parse_bytes(&iso).unwrap();
        assert!((log.records[0].x_meas_um - 1000.5).abs() < 1e-9);
        assert!((log.records[0].y_meas_um - 1999.75).abs() < 1e-9);
        assert_eq!(log.records[1].cycle, 2);
        let opts = GridImportOptions {
            error_sign: ErrorSign::TargetMinusMeasured,
            ..GridImportOptions::default()
        };
        let log = parse_bytes(&import_grid_bytes(src.as_bytes(), &opts).unwrap()).unwrap();
        assert!((log.records[0].x_meas_um - 999.5).abs() < 1e-9);
    }

    /// A direction column splits the grid into the nodes reached from
    /// below and from above; a row without a direction in such a column is
    /// refused with its line.
    #[test]
    fn a_direction_column_gives_a_grid_per_direction() {
        let mut src = String::from("x_mm,y_mm,x_error_um,y_error_um,direction\n");
        for (d, play) in [("fwd", 0.0), ("bwd", 1.5)] {
            for iy in 0..3 {
                for ix in 0..3 {
                    src.push_str(&format!("{ix},{iy},{play},0,{d}\n"));
                }
            }
        }
        let log =
            parse_bytes(&import_grid_bytes(src.as_bytes(), &GridImportOptions::default()).unwrap())
                .unwrap();
        let segs: Vec<&str> = log.records.iter().map(|r| r.segment.as_str()).collect();
        assert_eq!(segs.iter().filter(|s| **s == "grid_fwd").count(), 9);
        assert_eq!(segs.iter().filter(|s| **s == "grid_bwd").count(), 9);
        assert!(log.records.iter().all(|r| r.cycle == 1));
        let [below, above] =
            crate::analysis::grid::GridMap::directional(&log.records, [true, true]).unwrap();
        let e = |m: &crate::analysis::grid::GridMap| m.cell(1, 1).map(|c| c.e_um[0]);
        assert_eq!((e(&below), e(&above)), (Some(0.0), Some(1.5)));
        let bad = "x_mm,y_mm,x_error_um,y_error_um,direction\n0,0,0,0,sideways\n";
        let err = import_grid_bytes(bad.as_bytes(), &GridImportOptions::default()).unwrap_err();
        assert!(err.to_string().contains("line 2"), "{err}");
    }

    #[test]
    fn bad_input_is_refused_with_line_and_column() {
        let no_unit = "x,y,x_meas,y_meas\n1,2,1,2\n";
        assert!(matches!(
            import_grid_bytes(no_unit.as_bytes(), &GridImportOptions::default()),
            Err(ImportError::UnknownUnits { .. })
        ));
        let bad = "x_um,y_um,x_meas_um,y_meas_um\n1,2,1,nan\n";
        let e = import_grid_bytes(bad.as_bytes(), &GridImportOptions::default()).unwrap_err();
        assert!(e.to_string().contains("line 2"), "{e}");
        let short = ":START\n1 2 3\n";
        assert!(import_grid_bytes(short.as_bytes(), &GridImportOptions::default()).is_err());
        assert!(is_grid_export(b"x_um,y_um,x_meas_um,y_meas_um\n"));
        assert!(!is_grid_export(b"target_mm,measured_mm,direction,cycle\n"));
    }

    proptest::proptest! {
        #[test]
        fn no_input_panics(data in proptest::collection::vec(proptest::prelude::any::<u8>(), 0..400)) {
            let _ = import_grid_bytes(&data, &GridImportOptions::default());
            let _ = is_grid_export(&data);
        }
    }
}
