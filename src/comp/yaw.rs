//! Yaw tables: the platform's rotation about +z against each axis's
//! position, per arrival direction, built from the decoded θ of the same
//! scans the position tables ([`super::table`]) come from; and the tool
//! point's transform through that yaw.
//!
//! Why: a tool (gripper, probe tip) fastened at an arm `o` from the point
//! the camera watches moves by `R_z(θ)·o`; on a 20 mm arm a 150 µrad yaw is
//! 3 µm at the tip, more than the position tables leave at the pattern. The
//! pattern measures θ with every frame, so the yaw can be tabulated like
//! the position errors.
//!
//! ```text
//! θ(x, y) = [fθ_x(x) or bθ_x(x)] + [fθ_y(y) or bθ_y(y)]          (µrad)
//! ```
//! summed as the stage model sums its carriages' yaws
//! (`crate::model::StageModel::platform_yaw_rad`). Sign: positive turns +x
//! towards +y (counter-clockwise seen from above). θ is the log's
//! `theta_urad`: the decoded θ minus the tie's, so the yaw since the tie's
//! anchor, and a tool's offset is in the platform frame as it was there.
//!
//! Built as the position tables are: per scan record the direction from the
//! log order ([`super::table::infer_directions`]), records grouped by
//! commanded position and direction, the mean θ of the visits per point.
//! The X scan's tables are used as measured (they include the Y carriage's
//! yaw at `y_hold`); the Y scan's are referenced to its forward value at
//! `y_hold` (linear interpolation), so that this part is not counted twice:
//! exact for a yaw that is a sum of an x part and a y part.

use serde::{Deserialize, Serialize};

use super::table::{bin_by_direction, infer_directions, Bins, Interpolation, TableBuildOptions};
use super::{invalid, CompError};
use crate::charact::log::Record;
use crate::model::{Axis, Direction};

/// One direction of one scan: the yaw at the commanded positions of the
/// moving axis, µrad (positive: +x towards +y).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct YawDirTable {
    /// Commanded positions of the moving axis, strictly increasing, µm.
    pub positions_um: Vec<f64>,
    /// Yaw at each position, µrad.
    pub yaw_urad: Vec<f64>,
    /// Number of visits averaged at each position.
    pub visits: Vec<u32>,
}

impl YawDirTable {
    fn validate(&self, what: &str) -> Result<(), CompError> {
        let n = self.positions_um.len();
        if n < 2 {
            return Err(invalid(what, format!("needs ≥ 2 points, has {n}")));
        }
        for (name, len) in [
            ("yaw_urad", self.yaw_urad.len()),
            ("visits", self.visits.len()),
        ] {
            if len != n {
                return Err(invalid(
                    format!("{what}.{name}"),
                    format!("has {len} values for {n} positions"),
                ));
            }
        }
        for (name, v, bound) in [
            ("positions_um", &self.positions_um, 1e9),
            // 0.1 rad: no stage yaws that much; a larger value is a defect.
            ("yaw_urad", &self.yaw_urad, 1e5),
        ] {
            if let Some(i) = v.iter().position(|x| !x.is_finite() || x.abs() > bound) {
                return Err(invalid(
                    format!("{what}.{name}[{i}]"),
                    format!("is not a finite number within ±{bound:e}"),
                ));
            }
        }
        if let Some(i) = self.positions_um.windows(2).position(|w| w[1] <= w[0]) {
            return Err(invalid(
                format!("{what}.positions_um[{}]", i + 1),
                "positions must be strictly increasing",
            ));
        }
        Ok(())
    }

    fn lookup(&self, pos_um: f64, interp: Interpolation) -> f64 {
        super::table::interpolate(&self.positions_um, &self.yaw_urad, pos_um, interp)
    }
}

/// Forward and backward yaw tables of one scan.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct YawAxisTables {
    /// After forward motion of the scanned axis.
    pub forward: YawDirTable,
    /// After backward motion.
    pub backward: YawDirTable,
}

impl YawAxisTables {
    fn lookup(&self, pos_um: f64, dir: Direction, interp: Interpolation) -> f64 {
        match dir {
            Direction::Forward => self.forward.lookup(pos_um, interp),
            Direction::Backward => self.backward.lookup(pos_um, interp),
            Direction::Unknown => {
                (self.forward.lookup(pos_um, interp) + self.backward.lookup(pos_um, interp)) / 2.0
            }
        }
    }
}

/// The yaw tables of a characterization (see the module docs).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct YawTables {
    /// Interpolation between points.
    pub interpolation: Interpolation,
    /// Yaw against x, as measured at `y = y_hold_um`.
    pub x_scan: YawAxisTables,
    /// Yaw against y, referenced to its forward value at `y_hold_um`.
    pub y_scan: YawAxisTables,
    /// Where Y was held during the X scan, µm.
    pub y_hold_um: f64,
}

/// What building the yaw tables found.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct YawBuildReport {
    /// Scan records with a θ used.
    pub records: usize,
    /// Points of the X tables `[forward, backward]`.
    pub x_points: [usize; 2],
    /// Points of the Y tables `[forward, backward]`.
    pub y_points: [usize; 2],
    /// Peak-to-peak of each axis's yaw over both directions `[x, y]`, µrad.
    pub span_urad: [f64; 2],
    /// Rms of the visits about their point's mean (the per-record θ
    /// noise, when points are visited more than once), µrad; `None` with a
    /// single visit per point.
    pub repeat_rms_urad: Option<f64>,
}

impl YawTables {
    /// Checks every table.
    pub fn validate(&self) -> Result<(), CompError> {
        self.x_scan.forward.validate("yaw.x_scan.forward")?;
        self.x_scan.backward.validate("yaw.x_scan.backward")?;
        self.y_scan.forward.validate("yaw.y_scan.forward")?;
        self.y_scan.backward.validate("yaw.y_scan.backward")?;
        if !(self.y_hold_um.is_finite() && self.y_hold_um.abs() <= 1e9) {
            return Err(invalid(
                "yaw.y_hold_um",
                "is not a finite number within ±1e9",
            ));
        }
        Ok(())
    }

    /// The predicted yaw at commanded `(x, y)` reached with directions
    /// `[dx, dy]`, µrad (positive: +x towards +y). `Unknown` takes the
    /// mean of both directions; outside the tables held at the end values.
    pub fn yaw_urad(&self, x_um: f64, y_um: f64, dir: [Direction; 2]) -> f64 {
        let i = self.interpolation;
        self.x_scan.lookup(x_um, dir[0], i) + self.y_scan.lookup(y_um, dir[1], i)
    }

    /// Builds the yaw tables from the `scan_x` / `scan_y` records of a log
    /// (segments and grid tolerance from `options`). `Ok(None)` when the
    /// scans carry no θ (a log written without the `theta_urad` column):
    /// such a log builds its position tables exactly as before.
    pub fn from_records(
        records: &[Record],
        options: &TableBuildOptions,
    ) -> Result<Option<(YawTables, YawBuildReport)>, CompError> {
        let in_scans =
            |r: &&Record| r.segment == options.x_segment || r.segment == options.y_segment;
        if !records
            .iter()
            .filter(in_scans)
            .any(|r| r.theta_urad.is_some_and(f64::is_finite))
        {
            return Ok(None);
        }
        let x = scan_yaw(records, &options.x_segment, Axis::X, options)?;
        let y = scan_yaw(records, &options.y_segment, Axis::Y, options)?;
        let r = y.tables.forward.lookup(x.hold_um, options.interpolation);
        let reference = |t: &YawDirTable| YawDirTable {
            positions_um: t.positions_um.clone(),
            yaw_urad: t.yaw_urad.iter().map(|v| v - r).collect(),
            visits: t.visits.clone(),
        };
        let tables = YawTables {
            interpolation: options.interpolation,
            y_scan: YawAxisTables {
                forward: reference(&y.tables.forward),
                backward: reference(&y.tables.backward),
            },
            x_scan: x.tables,
            y_hold_um: x.hold_um,
        };
        tables.validate()?;
        let span = |t: &YawAxisTables| {
            let all = t.forward.yaw_urad.iter().chain(&t.backward.yaw_urad);
            let (lo, hi) = all.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
                (lo.min(*v), hi.max(*v))
            });
            hi - lo
        };
        let (ss, dof) = (x.sum_sq + y.sum_sq, x.dof + y.dof);
        let report = YawBuildReport {
            records: x.used + y.used,
            x_points: [
                tables.x_scan.forward.positions_um.len(),
                tables.x_scan.backward.positions_um.len(),
            ],
            y_points: [
                tables.y_scan.forward.positions_um.len(),
                tables.y_scan.backward.positions_um.len(),
            ],
            span_urad: [span(&tables.x_scan), span(&tables.y_scan)],
            repeat_rms_urad: (dof > 0).then(|| (ss / dof as f64).sqrt()),
        };
        Ok(Some((tables, report)))
    }
}

struct ScanYaw {
    tables: YawAxisTables,
    hold_um: f64,
    used: usize,
    /// Σ (visit − point mean)² and its degrees of freedom.
    sum_sq: f64,
    dof: usize,
}

fn scan_yaw(
    records: &[Record],
    segment: &str,
    axis: Axis,
    options: &TableBuildOptions,
) -> Result<ScanYaw, CompError> {
    let recs: Vec<&Record> = records
        .iter()
        .filter(|r| r.segment == segment)
        .filter(|r| [r.x_cmd_um, r.y_cmd_um].iter().all(|v| v.is_finite()))
        .collect();
    let tol = options.grid_tolerance_um;
    let (mov, held): (Vec<f64>, Vec<f64>) = recs
        .iter()
        .map(|r| match axis {
            Axis::X => (r.x_cmd_um, r.y_cmd_um),
            Axis::Y => (r.y_cmd_um, r.x_cmd_um),
        })
        .unzip();
    let hold_um = held.first().copied().unwrap_or(f64::NAN);
    // Directions from every record's command (a record without θ still
    // tells the next one's direction), then only records with θ.
    let dirs = infer_directions(&mov, tol);
    let (acc, _) = bin_by_direction(&mov, &dirs, tol, |i| {
        recs[i].theta_urad.filter(|t| t.is_finite())
    });
    let used = acc.iter().flat_map(|a| a.values()).map(|b| b.1.len()).sum();
    let (mut sum_sq, mut dof) = (0.0, 0);
    let mut build = |a: &Bins<f64>, name: &str| -> Result<YawDirTable, CompError> {
        let mut t = YawDirTable {
            positions_um: Vec::new(),
            yaw_urad: Vec::new(),
            visits: Vec::new(),
        };
        for (sp, vals) in a.values() {
            let n = vals.len();
            let mean = vals.iter().sum::<f64>() / n as f64;
            sum_sq += vals.iter().map(|v| (v - mean).powi(2)).sum::<f64>();
            dof += n - 1;
            t.positions_um.push(sp / n as f64);
            t.yaw_urad.push(mean);
            t.visits.push(u32::try_from(n).unwrap_or(u32::MAX));
        }
        if t.positions_um.len() < 2 {
            return Err(CompError::NoData {
                what: format!(
                    "segment `{segment}` has {} {name} point(s) with θ (need ≥ 2 for a yaw table)",
                    t.positions_um.len()
                ),
            });
        }
        Ok(t)
    };
    let forward = build(&acc[0], "forward")?;
    let backward = build(&acc[1], "backward")?;
    Ok(ScanYaw {
        tables: YawAxisTables { forward, backward },
        hold_um,
        used,
        sum_sq,
        dof,
    })
}

/// Where a tool at `offset_um` (platform frame, µm) is when the watched
/// point is at `pattern_um` and the platform has turned by `yaw_urad`
/// (positive: +x towards +y): `pattern + R_z(θ)·offset`.
pub fn tool_from_pattern_um(pattern_um: [f64; 2], yaw_urad: f64, offset_um: [f64; 2]) -> [f64; 2] {
    let r = rotate(offset_um, yaw_urad * 1e-6);
    [pattern_um[0] + r[0], pattern_um[1] + r[1]]
}

/// The watched point that puts the tool at `tool_um` under yaw `yaw_urad`:
/// `tool − R_z(θ)·offset`, the inverse of [`tool_from_pattern_um`].
pub fn pattern_for_tool_um(tool_um: [f64; 2], yaw_urad: f64, offset_um: [f64; 2]) -> [f64; 2] {
    let r = rotate(offset_um, yaw_urad * 1e-6);
    [tool_um[0] - r[0], tool_um[1] - r[1]]
}

fn rotate(v: [f64; 2], theta_rad: f64) -> [f64; 2] {
    let (s, c) = theta_rad.sin_cos();
    [c * v[0] - s * v[1], s * v[0] + c * v[1]]
}

#[cfg(test)]
mod tests;
