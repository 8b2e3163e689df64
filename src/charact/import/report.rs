//! Markdown reports (see the parent module's docs): pipe tables under
//! headings that name the direction, read by their column names.
//!
//! Why a file of its own: a report's layouts (a row per arrival, a column
//! per cycle), its headings and its swapped direction labels are rules of
//! their own, apart from the CSV and `.dat` readers.

use std::collections::BTreeMap;

use super::{
    cycle_of, is_table_rule, number, to_um, Arrival, DirectionLabels, ImportError, Parsed, Unit,
};

/// The direction a report heading names: `+1` forward, `−1` backward,
/// `None` when it names neither (or both).
fn heading_direction(h: &str) -> Option<f64> {
    let h = h.to_ascii_lowercase();
    let fwd = ["forward", "positive", "fwd"].iter().any(|w| h.contains(w));
    let bwd = ["backward", "negative", "bwd"]
        .iter()
        .any(|w| h.contains(w));
    match (fwd, bwd) {
        (true, false) => Some(1.0),
        (false, true) => Some(-1.0),
        _ => None,
    }
}

/// Cells of a markdown table row (a leading and a trailing `|` delimit,
/// they do not add cells).
fn table_cells(l: &str) -> Vec<&str> {
    let t = l.trim();
    let t = t.strip_prefix('|').unwrap_or(t);
    let t = t.strip_suffix('|').unwrap_or(t);
    t.split('|').map(str::trim).collect()
}

/// A report table's header cell: its role name (lower case, units and
/// parenthesized indices removed, spaces as `_`), its unit (`[mm]`) and
/// the cycle it holds when it is a per-cycle column (`ref_pos(i,3)`).
fn report_cell(c: &str) -> (String, Option<Unit>, Option<u32>) {
    let lower = c.trim().trim_matches('*').to_ascii_lowercase();
    let mut name = String::new();
    let mut unit = None;
    let mut cycle = None;
    let mut rest = lower.as_str();
    while let Some(pos) = rest.find(['(', '[']) {
        name.push_str(&rest[..pos]);
        let close = if rest[pos..].starts_with('(') {
            ')'
        } else {
            ']'
        };
        let Some(end) = rest[pos..].find(close) else {
            name.push_str(&rest[pos..]);
            rest = "";
            break;
        };
        let inner = rest[pos + 1..pos + end].trim();
        if let Some(u) = Unit::parse(inner) {
            unit = Some(u);
        } else if let Some((i, j)) = inner.split_once(',') {
            if i.trim() == "i" {
                cycle = j.trim().parse().ok();
            }
        }
        rest = &rest[pos + end + 1..];
    }
    name.push_str(rest);
    let name = name
        .trim()
        .trim_matches(|c: char| c == ',' || c == ':' || c == '_')
        .trim()
        .replace(' ', "_");
    (name, unit, cycle)
}

const REPORT_CYCLE_NAMES: &[&str] = &["j", "cycle", "cycle_id", "cycle_no", "run"];
const REPORT_TARGET_NAMES: &[&str] = &[
    "tgt_pos",
    "tgt",
    "target",
    "target_position",
    "setpoint",
    "set_point",
    "nominal",
];
const REPORT_READING_NAMES: &[&str] = &[
    "reference",
    "ref_pos",
    "ref",
    "reference_position",
    "measured",
    "reading",
    "ild2300",
];

/// Whether a reading cell says the arrival was not measured.
fn not_measured(cell: &str) -> bool {
    matches!(
        cell.trim().to_ascii_lowercase().as_str(),
        "" | "-" | "nan" | "n/a" | "na" | "out of range"
    )
}

/// One table of readings found in a report.
struct ReportTable {
    /// Per-target rows with a column per cycle (`ref_pos(i,j)`).
    per_cycle_columns: bool,
}

/// Parses a markdown report (see the module docs).
pub(super) fn parse_report(
    text: &str,
    units: Option<Unit>,
    directions: DirectionLabels,
) -> Result<Parsed, ImportError> {
    let lines: Vec<&str> = text.lines().collect();
    let mut heading = String::new();
    let mut arrivals: Vec<(Arrival, usize)> = Vec::new();
    let mut seen: BTreeMap<(u32, i8, i64), usize> = BTreeMap::new();
    let mut tables: Vec<ReportTable> = Vec::new();
    let mut skipped = 0usize;
    let mut unit_seen: Option<Unit> = None;
    let mut k = 0;
    while k < lines.len() {
        let l = lines[k];
        if l.trim_start().starts_with('#') {
            heading = l.trim_start().trim_start_matches('#').trim().to_string();
            k += 1;
            continue;
        }
        let is_header = l.contains('|') && k + 1 < lines.len() && is_table_rule(lines[k + 1]);
        if !is_header {
            k += 1;
            continue;
        }
        let header: Vec<(String, Option<Unit>, Option<u32>)> =
            table_cells(l).into_iter().map(report_cell).collect();
        let raw: Vec<String> = table_cells(l).iter().map(|c| c.to_string()).collect();
        // The table's rows: up to the first line that is not a row.
        let mut end = k + 2;
        while end < lines.len() && lines[end].contains('|') && !is_table_rule(lines[end]) {
            end += 1;
        }
        let rows = (k + 2)..end;
        k = end;
        let Some(dir) = heading_direction(&heading) else {
            continue;
        };
        let find = |names: &[&str]| {
            header
                .iter()
                .position(|(n, _, c)| c.is_none() && names.contains(&n.as_str()))
        };
        let target = find(REPORT_TARGET_NAMES);
        let per_cycle: Vec<(usize, u32)> = header
            .iter()
            .enumerate()
            .filter_map(|(i, (n, _, c))| {
                c.filter(|_| REPORT_READING_NAMES.contains(&n.as_str()))
                    .map(|c| (i, c))
            })
            .collect();
        let reading = find(REPORT_READING_NAMES);
        let cycle = find(REPORT_CYCLE_NAMES);
        let Some(target) = target else {
            continue;
        };
        // Long layout: one row per arrival; wide: a column per cycle.
        let columns: Vec<(usize, Option<u32>)> = match (cycle, reading) {
            (Some(_), Some(r)) => vec![(r, None)],
            _ if !per_cycle.is_empty() => per_cycle.iter().map(|&(i, c)| (i, Some(c))).collect(),
            _ => continue,
        };
        let unit_of = |col: usize| -> Result<Unit, ImportError> {
            units
                .or(header[col].1)
                .ok_or_else(|| ImportError::UnknownUnits {
                    column: raw[col].clone(),
                })
        };
        let target_unit = unit_of(target)?;
        let wide = cycle.is_none() || reading.is_none();
        tables.push(ReportTable {
            per_cycle_columns: wide,
        });
        // The layout printed swapped (module docs) is the wide one.
        let swap = match directions {
            DirectionLabels::Auto => wide,
            DirectionLabels::AsLabelled => false,
            DirectionLabels::Swapped => true,
        };
        let approach = if swap { -dir } else { dir };
        for row in rows {
            let line = row + 1;
            let cells = table_cells(lines[row]);
            let cell = |i: usize| cells.get(i).copied().unwrap_or("");
            let name = |i: usize| raw.get(i).cloned().unwrap_or_default();
            if not_measured(cell(target)) {
                skipped += columns.len();
                continue;
            }
            let t = to_um(
                number(cell(target), line, &name(target))?,
                target_unit,
                line,
                &name(target),
            )?;
            for &(col, cyc) in &columns {
                let c = match (cyc, cycle) {
                    (Some(c), _) => c,
                    (None, Some(cc)) => cycle_of(cell(cc), line, &name(cc))?,
                    (None, None) => continue,
                };
                if not_measured(cell(col)) {
                    skipped += 1;
                    continue;
                }
                let u = unit_of(col)?;
                unit_seen.get_or_insert(u);
                let v = to_um(number(cell(col), line, &name(col))?, u, line, &name(col))?;
                let key = (c, approach as i8, (t * 1e3).round() as i64);
                if let Some(first) = seen.insert(key, line) {
                    return Err(ImportError::Line {
                        line,
                        column: Some(name(col)),
                        message: format!(
                            "target {} {}, cycle {c}, {} approach is read twice (first on line {first})",
                            number(cell(target), line, &name(target))?,
                            match target_unit {
                                Unit::M => "m",
                                Unit::Mm => "mm",
                                Unit::Um => "µm",
                                Unit::Nm => "nm",
                            },
                            if approach > 0.0 { "forward" } else { "backward" }
                        ),
                    });
                }
                arrivals.push((
                    Arrival {
                        target_um: t,
                        measured_um: v,
                        approach,
                        cycle: c,
                        t_s: None,
                    },
                    line,
                ));
            }
        }
    }
    if tables.is_empty() {
        return Err(ImportError::NoReadingTable);
    }
    in_standard_order(&mut arrivals);
    let wide = tables.iter().any(|t| t.per_cycle_columns);
    let notes = report_notes(wide, directions, skipped);
    Ok(Parsed {
        arrivals: arrivals.into_iter().map(|(a, _)| a).collect(),
        unit: units.or(unit_seen).unwrap_or(Unit::Mm),
        notes,
    })
}

/// The standard's order (per cycle: forward over increasing targets,
/// then backward over decreasing ones), as the test ran it.
fn in_standard_order(arrivals: &mut [(Arrival, usize)]) {
    arrivals.sort_by(|(a, _), (b, _)| {
        a.cycle
            .cmp(&b.cycle)
            .then(b.approach.total_cmp(&a.approach))
            .then(if a.approach > 0.0 {
                a.target_um.total_cmp(&b.target_um)
            } else {
                b.target_um.total_cmp(&a.target_um)
            })
    });
}

/// The notes a report's log carries: its layout (`wide`: a column per
/// cycle), how its direction headings were read and what was skipped,
/// so that the log says how it was imported.
fn report_notes(wide: bool, directions: DirectionLabels, skipped: usize) -> Vec<(String, String)> {
    let mut notes = vec![(
        "report_layout".to_string(),
        if wide {
            "markdown tables, a row per target and a reading column per cycle (ecmc ecmcISO230_2.py)"
        } else {
            "markdown tables, a row per arrival (position index, cycle, target, reference reading)"
        }
        .to_string(),
    )];
    let swapped = match directions {
        DirectionLabels::Auto => wide,
        DirectionLabels::AsLabelled => false,
        DirectionLabels::Swapped => true,
    };
    notes.push((
        "direction_labels".to_string(),
        match (swapped, directions) {
            (true, DirectionLabels::Auto) => "swapped: this layout prints its input's REF_DATA_BWD readings (approached from above) under 'forward' and vice versa; imported by the true approach (--directions as-labelled keeps the headings)",
            (true, _) => "swapped on request (--directions swapped): 'forward' tables imported as approached from above",
            (false, _) => "as the headings say",
        }
        .to_string(),
    ));
    if skipped > 0 {
        notes.push((
            "unmeasured_cells".to_string(),
            format!("{skipped} arrivals without a reading (empty or 'out of range' cells) skipped"),
        ));
    }
    notes
}
