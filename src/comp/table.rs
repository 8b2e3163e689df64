//! The paper's lookup tables (eqs. 4 and 5) and how they are built from the
//! `scan_x` / `scan_y` segments of a measurement log.
//!
//! ```text
//! ex(x, y) = [f_xx(x) or b_xx(x)] + δx(y) + [f_yx(y) or b_yx(y)]
//! ey(x, y) = [f_xy(x) or b_xy(x)]         + [f_yy(y) or b_yy(y)]
//! ```
//! `e = cmd − measured` (the paper's sign, target = cmd during the scan),
//! `f`/`b` chosen by the arrival direction of the axis.
//!
//! # How the tables are built
//! 1. Per scan record the pass direction is inferred from the log order:
//!    the sign of the change of the moving axis' target from the previous
//!    record of the segment, or if that is zero (the turn of a pass), to the
//!    next one. Records are grouped by commanded position (within
//!    `grid_tolerance_um`) and direction; each table value is the mean over
//!    the visits (cycles) of `cmd − meas`.
//! 2. The X scan is taken at `y = y_hold` (Y parked by a forward approach):
//!    its tables are used as measured: `f_xx`, `b_xx`, `f_xy`, `b_xy` include
//!    the Y stage's error at `(y_hold, forward)`.
//! 3. So that this is not counted twice, the Y-scan tables are referenced to
//!    that point: `f_y·(y) = Y_fwd(y) − Y_fwd(y_hold)`, `b_y·(y) = Y_bwd(y) −
//!    Y_fwd(y_hold)` (linear interpolation at `y_hold`). For an error that is
//!    a sum of an x-dependent and a y-dependent part this is exact: the
//!    X-stage error at the Y scan's `x_hold` cancels too.
//! 4. `δx(y)` and `f_yx` split (as the paper: a linear bias for the
//!    out-of-squareness): `δx(y) = k·(y − y_hold)` with `k` the least-squares
//!    slope of the Y scan's x error (both directions, every table point)
//!    against y; `f_yx`/`b_yx` are what is left:
//!    `f_yx(y) = Y_fwd,x(y) − Y_fwd,x(y_hold) − δx(y)`. The sum `δx + f_yx`
//!    is the measured Y-scan x error either way; the split matters outside
//!    the scanned range, where `δx` extrapolates linearly and the tables
//!    are held at their end values. `k = −squareness angle` (model sign:
//!    +Y leaning towards +X moves the platform to +x, `e` negative).
//!
//! Rotation vs squareness: the Y scan's x error includes the squareness
//! only because the vision→stage rotation was fixed by the X scan direction
//! (`crate::comp::frame`); see `docs/compensation-tables.md`.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use super::{invalid, CompError, Compensator};
use crate::charact::log::Record;
use crate::charact::scan::{SEGMENT_SCAN_X, SEGMENT_SCAN_Y};
use crate::model::{Axis, Direction, MotionState};

/// Interpolation between table points.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum Interpolation {
    /// Piecewise linear (the paper's `interp1`).
    #[default]
    Linear,
    /// Piecewise cubic Hermite with centred-difference slopes
    /// (Catmull–Rom on a non-uniform grid): smoother, same values at the
    /// points, no overshoot beyond one segment.
    Cubic,
}

/// One direction of one scan: error components at the commanded positions
/// of the moving axis. Paper sign (`cmd − measured`), µm.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DirTable {
    /// Commanded positions of the moving axis, strictly increasing, µm.
    pub positions_um: Vec<f64>,
    /// x error at each position, µm.
    pub ex_um: Vec<f64>,
    /// y error at each position, µm.
    pub ey_um: Vec<f64>,
    /// Number of visits averaged at each position.
    pub visits: Vec<u32>,
}

impl DirTable {
    /// Checks lengths, order and finiteness; `what` names the table in
    /// errors.
    pub fn validate(&self, what: &str) -> Result<(), CompError> {
        let n = self.positions_um.len();
        if n < 2 {
            return Err(invalid(what, format!("needs ≥ 2 points, has {n}")));
        }
        for (name, len) in [
            ("ex_um", self.ex_um.len()),
            ("ey_um", self.ey_um.len()),
            ("visits", self.visits.len()),
        ] {
            if len != n {
                return Err(invalid(
                    format!("{what}.{name}"),
                    format!("has {len} values for {n} positions"),
                ));
            }
        }
        for (name, v) in [
            ("positions_um", &self.positions_um),
            ("ex_um", &self.ex_um),
            ("ey_um", &self.ey_um),
        ] {
            if let Some(i) = v.iter().position(|x| !x.is_finite() || x.abs() > 1e9) {
                return Err(invalid(
                    format!("{what}.{name}[{i}]"),
                    "is not a finite number within ±1e9",
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

    /// `[ex, ey]` at `pos_um`, held at the end values outside the table.
    pub fn lookup(&self, pos_um: f64, interp: Interpolation) -> [f64; 2] {
        [
            interpolate(&self.positions_um, &self.ex_um, pos_um, interp),
            interpolate(&self.positions_um, &self.ey_um, pos_um, interp),
        ]
    }
}

pub(super) fn interpolate(xs: &[f64], ys: &[f64], x: f64, interp: Interpolation) -> f64 {
    let n = xs.len();
    if n == 0 {
        return 0.0;
    }
    if n == 1 || x <= xs[0] || x.is_nan() {
        return ys[0];
    }
    if x >= xs[n - 1] {
        return ys[n - 1];
    }
    // xs[i] ≤ x < xs[i+1]
    let i = xs.partition_point(|&v| v <= x).saturating_sub(1).min(n - 2);
    let h = xs[i + 1] - xs[i];
    let t = (x - xs[i]) / h;
    match interp {
        Interpolation::Linear => ys[i] + t * (ys[i + 1] - ys[i]),
        Interpolation::Cubic => {
            let slope = |k: usize| -> f64 {
                if k == 0 {
                    (ys[1] - ys[0]) / (xs[1] - xs[0])
                } else if k == n - 1 {
                    (ys[n - 1] - ys[n - 2]) / (xs[n - 1] - xs[n - 2])
                } else {
                    (ys[k + 1] - ys[k - 1]) / (xs[k + 1] - xs[k - 1])
                }
            };
            let (m0, m1) = (slope(i) * h, slope(i + 1) * h);
            let (t2, t3) = (t * t, t * t * t);
            (2.0 * t3 - 3.0 * t2 + 1.0) * ys[i]
                + (t3 - 2.0 * t2 + t) * m0
                + (-2.0 * t3 + 3.0 * t2) * ys[i + 1]
                + (t3 - t2) * m1
        }
    }
}

/// Forward and backward tables of one scan.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AxisTables {
    /// Where the other axis was held during the scan, µm.
    pub hold_um: f64,
    /// After forward motion (`f_··`).
    pub forward: DirTable,
    /// After backward motion (`b_··`).
    pub backward: DirTable,
}

/// The complete table set of eqs. 4 and 5.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CompTable {
    /// Interpolation between points.
    pub interpolation: Interpolation,
    /// `f_xx, f_xy` (forward.ex/ey) and `b_xx, b_xy`: X scan as measured at
    /// `y = x_scan.hold_um`.
    pub x_scan: AxisTables,
    /// `f_yx, f_yy` (forward.ex/ey) and `b_yx, b_yy`: Y scan referenced to
    /// `(y = x_scan.hold_um, forward)` with `δx` removed from `ex`.
    pub y_scan: AxisTables,
    /// Slope `k` of `δx(y) = k·(y − x_scan.hold_um)`, µm per µm
    /// (= −squareness angle in rad).
    pub delta_x_slope: f64,
}

impl CompTable {
    /// Checks every table.
    pub fn validate(&self) -> Result<(), CompError> {
        self.x_scan.forward.validate("x_scan.forward")?;
        self.x_scan.backward.validate("x_scan.backward")?;
        self.y_scan.forward.validate("y_scan.forward")?;
        self.y_scan.backward.validate("y_scan.backward")?;
        for (k, v) in [
            ("x_scan.hold_um", self.x_scan.hold_um),
            ("y_scan.hold_um", self.y_scan.hold_um),
        ] {
            if !(v.is_finite() && v.abs() <= 1e9) {
                return Err(invalid(k, "is not a finite number within ±1e9"));
            }
        }
        if !(self.delta_x_slope.is_finite() && self.delta_x_slope.abs() < 0.1) {
            return Err(invalid(
                "delta_x_slope",
                "must be finite and |k| < 0.1 (a 100 mrad squareness is not a stage)",
            ));
        }
        Ok(())
    }

    /// The area the tables were measured over: the x scan's positions
    /// (both directions) by the y scan's (see [`super::Area`]).
    pub fn area(&self) -> super::Area {
        let span = |t: &AxisTables| {
            let (f, b) = (&t.forward.positions_um, &t.backward.positions_um);
            let lo = f.first().copied().unwrap_or(f64::NAN);
            let hi = f.last().copied().unwrap_or(f64::NAN);
            let blo = b.first().copied().unwrap_or(lo);
            let bhi = b.last().copied().unwrap_or(hi);
            [lo.min(blo), hi.max(bhi)]
        };
        super::Area {
            x_um: span(&self.x_scan),
            y_um: span(&self.y_scan),
        }
    }

    /// `δx(y)`, µm.
    pub fn delta_x_um(&self, y_um: f64) -> f64 {
        self.delta_x_slope * (y_um - self.x_scan.hold_um)
    }

    /// The paper's error `e = cmd − measured` `[ex, ey]` for commanded
    /// `(x, y)` reached with directions `[dx, dy]` (eqs. 4, 5). `Unknown` uses
    /// the mean of the forward and backward tables.
    pub fn error_um(&self, x_um: f64, y_um: f64, dir: [Direction; 2]) -> [f64; 2] {
        let pick = |t: &AxisTables, p: f64, d: Direction| -> [f64; 2] {
            let i = self.interpolation;
            match d {
                Direction::Forward => t.forward.lookup(p, i),
                Direction::Backward => t.backward.lookup(p, i),
                Direction::Unknown => {
                    let (a, b) = (t.forward.lookup(p, i), t.backward.lookup(p, i));
                    [(a[0] + b[0]) / 2.0, (a[1] + b[1]) / 2.0]
                }
            }
        };
        let ex = pick(&self.x_scan, x_um, dir[0]);
        let ey = pick(&self.y_scan, y_um, dir[1]);
        [ex[0] + self.delta_x_um(y_um) + ey[0], ex[1] + ey[1]]
    }

    /// Squareness angle implied by `δx`, µrad (model sign: +Y leaning
    /// towards +X).
    pub fn squareness_urad(&self) -> f64 {
        -self.delta_x_slope * 1e6
    }

    /// Builds the tables from a log's records (see the module docs).
    pub fn from_records(
        records: &[Record],
        options: &TableBuildOptions,
    ) -> Result<(CompTable, BuildReport), CompError> {
        options.validate()?;
        let x = scan_tables(records, &options.x_segment, Axis::X, options)?;
        let y = scan_tables(records, &options.y_segment, Axis::Y, options)?;
        let y_hold = x.tables.hold_um;
        let i = options.interpolation;
        let r = y.tables.forward.lookup(y_hold, i);
        // δx: least-squares line of the Y scan's x error against y.
        let (mut sy, mut se, mut syy, mut sye, mut n) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for t in [&y.tables.forward, &y.tables.backward] {
            for (p, e) in t.positions_um.iter().zip(&t.ex_um) {
                let p = p - y_hold;
                sy += p;
                se += e;
                syy += p * p;
                sye += p * e;
                n += 1.0;
            }
        }
        let den = n * syy - sy * sy;
        if den.is_nan() || den <= 0.0 {
            return Err(CompError::NoData {
                what: "the Y scan spans a single position: cannot fit δx(y)".into(),
            });
        }
        let k = (n * sye - sy * se) / den;
        let reference = |t: &DirTable| DirTable {
            positions_um: t.positions_um.clone(),
            ex_um: t
                .positions_um
                .iter()
                .zip(&t.ex_um)
                .map(|(p, e)| e - r[0] - k * (p - y_hold))
                .collect(),
            ey_um: t.ey_um.iter().map(|e| e - r[1]).collect(),
            visits: t.visits.clone(),
        };
        let y_scan = AxisTables {
            hold_um: y.tables.hold_um,
            forward: reference(&y.tables.forward),
            backward: reference(&y.tables.backward),
        };
        let table = CompTable {
            interpolation: i,
            x_scan: x.tables,
            y_scan,
            delta_x_slope: k,
        };
        table.validate()?;
        let report = BuildReport {
            x_records: x.used,
            y_records: y.used,
            skipped_records: x.skipped + y.skipped,
            x_points: [
                table.x_scan.forward.positions_um.len(),
                table.x_scan.backward.positions_um.len(),
            ],
            y_points: [
                table.y_scan.forward.positions_um.len(),
                table.y_scan.backward.positions_um.len(),
            ],
            squareness_urad: table.squareness_urad(),
            y_reference_um: r,
            max_spread_um: x.max_spread_um.max(y.max_spread_um),
        };
        Ok((table, report))
    }
}

/// How to build tables from a log.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TableBuildOptions {
    /// Segment of the X scan.
    pub x_segment: String,
    /// Segment of the Y scan.
    pub y_segment: String,
    /// Commands closer than this are the same table point, µm.
    pub grid_tolerance_um: f64,
    /// Interpolation stored in the table.
    pub interpolation: Interpolation,
}

impl Default for TableBuildOptions {
    fn default() -> Self {
        TableBuildOptions {
            x_segment: SEGMENT_SCAN_X.into(),
            y_segment: SEGMENT_SCAN_Y.into(),
            grid_tolerance_um: 1e-3,
            interpolation: Interpolation::Linear,
        }
    }
}

impl TableBuildOptions {
    fn validate(&self) -> Result<(), CompError> {
        if !(self.grid_tolerance_um.is_finite() && self.grid_tolerance_um > 0.0) {
            return Err(invalid("grid_tolerance_um", "must be a finite number > 0"));
        }
        Ok(())
    }
}

/// What building found.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BuildReport {
    /// Records of the X scan used.
    pub x_records: usize,
    /// Records of the Y scan used.
    pub y_records: usize,
    /// Scan records whose direction could not be told (isolated repeats).
    pub skipped_records: usize,
    /// Points of the X tables `[forward, backward]`.
    pub x_points: [usize; 2],
    /// Points of the Y tables `[forward, backward]`.
    pub y_points: [usize; 2],
    /// Squareness from `δx`, µrad.
    pub squareness_urad: f64,
    /// Y-scan error at `(y_hold, forward)` removed from the Y tables, µm.
    pub y_reference_um: [f64; 2],
    /// Largest distance of a visit from its point's mean (repeatability
    /// indicator), µm.
    pub max_spread_um: f64,
}

struct ScanResult {
    tables: AxisTables,
    used: usize,
    skipped: usize,
    max_spread_um: f64,
}

/// One direction's bins of a 1-DoF scan: per commanded position rounded
/// to the grid tolerance, the sum of the positions and the binned values in
/// record order.
pub(crate) type Bins<T> = BTreeMap<i64, (f64, Vec<T>)>;

/// Bins a scan's records by arrival direction (`[forward, backward]`) and
/// commanded position (`mov`, rounded to `tol`), taking `value(i)` of
/// record `i`; a `None` value is left out. Returns the bins and how many
/// records with a value had no direction (not binned). The position
/// tables and the yaw tables group the same way through this.
pub(crate) fn bin_by_direction<T>(
    mov: &[f64],
    dirs: &[Option<Direction>],
    tol: f64,
    mut value: impl FnMut(usize) -> Option<T>,
) -> ([Bins<T>; 2], usize) {
    let mut acc: [Bins<T>; 2] = [BTreeMap::new(), BTreeMap::new()];
    let mut skipped = 0;
    for (i, (d, p)) in dirs.iter().zip(mov).enumerate() {
        let Some(v) = value(i) else {
            continue;
        };
        let k = match d {
            Some(Direction::Forward) => 0,
            Some(Direction::Backward) => 1,
            _ => {
                skipped += 1;
                continue;
            }
        };
        let a = acc[k]
            .entry((p / tol).round() as i64)
            .or_insert((0.0, Vec::new()));
        a.0 += p;
        a.1.push(v);
    }
    (acc, skipped)
}

/// Direction of each record of a 1-DoF scan from the log order (see the
/// module docs); `None` where it cannot be told.
pub fn infer_directions(moving_um: &[f64], tolerance_um: f64) -> Vec<Option<Direction>> {
    let sign = |d: f64| {
        if d > tolerance_um {
            Some(Direction::Forward)
        } else if d < -tolerance_um {
            Some(Direction::Backward)
        } else {
            None
        }
    };
    (0..moving_um.len())
        .map(|i| {
            let back = if i > 0 {
                sign(moving_um[i] - moving_um[i - 1])
            } else {
                None
            };
            back.or_else(|| moving_um.get(i + 1).and_then(|n| sign(n - moving_um[i])))
        })
        .collect()
}

fn scan_tables(
    records: &[Record],
    segment: &str,
    axis: Axis,
    options: &TableBuildOptions,
) -> Result<ScanResult, CompError> {
    let recs: Vec<&Record> = records
        .iter()
        .filter(|r| r.segment == segment)
        .filter(|r| {
            [r.x_cmd_um, r.y_cmd_um, r.x_meas_um, r.y_meas_um]
                .iter()
                .all(|v| v.is_finite())
        })
        .collect();
    if recs.len() < 4 {
        return Err(CompError::NoData {
            what: format!(
                "segment `{segment}` has {} usable records (need ≥ 4: two points each way)",
                recs.len()
            ),
        });
    }
    let (mov, held): (Vec<f64>, Vec<f64>) = recs
        .iter()
        .map(|r| match axis {
            Axis::X => (r.x_cmd_um, r.y_cmd_um),
            Axis::Y => (r.y_cmd_um, r.x_cmd_um),
        })
        .unzip();
    let hold = held[0];
    let tol = options.grid_tolerance_um;
    if let Some(i) = held.iter().position(|h| (h - hold).abs() > tol) {
        return Err(invalid(
            format!("segment `{segment}`"),
            format!(
                "the {} command varies ({:.3} then {:.3} µm at record {i} of the segment): a 1-DoF scan holds the other axis",
                axis.other(),
                hold,
                held[i]
            ),
        ));
    }
    let dirs = infer_directions(&mov, tol);
    let (acc, skipped) = bin_by_direction(&mov, &dirs, tol, |i| {
        let r = recs[i];
        Some([r.x_cmd_um - r.x_meas_um, r.y_cmd_um - r.y_meas_um])
    });
    let mut max_spread: f64 = 0.0;
    let mut build = |a: &Bins<[f64; 2]>, name: &str| -> Result<DirTable, CompError> {
        let mut t = DirTable {
            positions_um: Vec::new(),
            ex_um: Vec::new(),
            ey_um: Vec::new(),
            visits: Vec::new(),
        };
        for (sp, vals) in a.values() {
            let n = u32::try_from(vals.len()).unwrap_or(u32::MAX);
            let nf = f64::from(n);
            let sx = vals.iter().fold(0.0, |s, v| s + v[0]);
            let sy = vals.iter().fold(0.0, |s, v| s + v[1]);
            let (mx, my) = (sx / nf, sy / nf);
            for v in vals {
                max_spread = max_spread.max((v[0] - mx).hypot(v[1] - my));
            }
            t.positions_um.push(sp / nf);
            t.ex_um.push(mx);
            t.ey_um.push(my);
            t.visits.push(n);
        }
        if t.positions_um.len() < 2 {
            return Err(CompError::NoData {
                what: format!(
                    "segment `{segment}` has {} {name} point(s) (need ≥ 2)",
                    t.positions_um.len()
                ),
            });
        }
        Ok(t)
    };
    let forward = build(&acc[0], "forward")?;
    let backward = build(&acc[1], "backward")?;
    Ok(ScanResult {
        tables: AxisTables {
            hold_um: hold,
            forward,
            backward,
        },
        used: recs.len() - skipped,
        skipped,
        max_spread_um: max_spread,
    })
}

/// The paper's compensator: eqs. 4 and 5 through the inverse.
#[derive(Debug, Clone, PartialEq)]
pub struct LookupCompensator {
    table: CompTable,
}

impl LookupCompensator {
    /// Wraps validated tables.
    pub fn new(table: CompTable) -> Result<Self, CompError> {
        table.validate()?;
        Ok(LookupCompensator { table })
    }

    /// The tables.
    pub fn table(&self) -> &CompTable {
        &self.table
    }
}

impl Compensator for LookupCompensator {
    fn kind(&self) -> &'static str {
        "lookup"
    }

    fn predicted_offset_um(&self, state: &MotionState) -> Result<[f64; 2], CompError> {
        let c = state.cmd_xy_um();
        let e = self
            .table
            .error_um(c[0], c[1], [state.axes[0].dir, state.axes[1].dir]);
        Ok([-e[0], -e[1]])
    }

    fn characterized_area(&self) -> Option<super::Area> {
        Some(self.table.area())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn interpolation_hits_points_and_holds_ends() {
        let xs = [0.0, 1.0, 3.0, 4.0];
        let ys = [0.0, 2.0, 2.0, 5.0];
        for interp in [Interpolation::Linear, Interpolation::Cubic] {
            for (x, y) in xs.iter().zip(&ys) {
                assert!((interpolate(&xs, &ys, *x, interp) - y).abs() < 1e-12);
            }
            assert_eq!(interpolate(&xs, &ys, -5.0, interp), 0.0);
            assert_eq!(interpolate(&xs, &ys, 9.0, interp), 5.0);
        }
        assert!((interpolate(&xs, &ys, 0.5, Interpolation::Linear) - 1.0).abs() < 1e-12);
        assert!((interpolate(&xs, &ys, 3.5, Interpolation::Linear) - 3.5).abs() < 1e-12);
        // Cubic reproduces a straight line exactly.
        let ls = [1.0, 3.0, 7.0, 9.0];
        assert!((interpolate(&xs, &ls, 2.2, Interpolation::Cubic) - 5.4).abs() < 1e-12);
    }

    #[test]
    fn directions_come_from_the_log_order() {
        let d = infer_directions(&[0.0, 5.0, 10.0, 10.0, 5.0, 0.0, 0.0, 5.0], 1e-3);
        use Direction::*;
        assert_eq!(
            d,
            vec![
                Some(Forward),
                Some(Forward),
                Some(Forward),
                Some(Backward),
                Some(Backward),
                Some(Backward),
                Some(Forward),
                Some(Forward)
            ]
        );
        assert_eq!(infer_directions(&[1.0, 1.0], 1e-3), vec![None, None]);
    }
}

#[cfg(test)]
mod area_tests {
    use super::*;
    use crate::comp::{Area, CompFile, Compensator, SourceInfo};
    use crate::model::XyUm;

    fn dir(positions: &[f64]) -> DirTable {
        DirTable {
            positions_um: positions.to_vec(),
            ex_um: vec![-22.65; positions.len()],
            ey_um: vec![0.0; positions.len()],
            visits: vec![1; positions.len()],
        }
    }

    /// A 1000 × 500 µm table whose backward x pass reaches further than the
    /// forward one.
    fn table() -> CompTable {
        CompTable {
            interpolation: Interpolation::Linear,
            x_scan: AxisTables {
                hold_um: 0.0,
                forward: dir(&[0.0, 500.0, 900.0]),
                backward: dir(&[100.0, 500.0, 1000.0]),
            },
            y_scan: AxisTables {
                hold_um: 0.0,
                forward: dir(&[0.0, 500.0]),
                backward: dir(&[0.0, 500.0]),
            },
            delta_x_slope: 0.0,
        }
    }

    #[test]
    fn lookup_area_is_the_scans_extent_and_the_check_measures_outside() {
        let c = LookupCompensator::new(table()).unwrap();
        let a = c.characterized_area().unwrap();
        assert_eq!(
            a,
            Area {
                x_um: [0.0, 1000.0],
                y_um: [0.0, 500.0]
            }
        );
        assert!(!c.extrapolates_by_model());
        let at = |x_um, y_um| XyUm { x_um, y_um };
        // The issue's move: far outside, by 1500 and 1800 µm.
        assert_eq!(a.outside_by_um(at(2500.0, 2300.0), 0.0), [1500.0, 1800.0]);
        assert!(!a.contains(at(2500.0, 2300.0), 0.0));
        assert!(a.contains(at(1000.0, 0.0), 0.0));
        assert!(!a.contains(at(1005.0, 0.0), 0.0));
        assert!(a.contains(at(1005.0, -5.0), 10.0));
        assert_eq!(a.outside_by_um(at(-30.0, 250.0), 10.0), [20.0, 0.0]);
        assert!(!a.contains(at(f64::NAN, 0.0), 10.0));
        assert_eq!(a.to_string(), "x 0.0 … 1000.0 µm, y 0.0 … 500.0 µm");
    }

    #[test]
    fn a_model_file_carries_its_area() {
        let m = crate::model::StageModel::paper_default().unwrap();
        let mut f = CompFile::model(&m, "t", SourceInfo::default()).unwrap();
        assert_eq!(f.compensator().unwrap().characterized_area(), None);
        let a = Area {
            x_um: [10.0, 20.0],
            y_um: [30.0, 40.0],
        };
        f.area = Some(a);
        let back = CompFile::from_toml(&f.to_toml().unwrap()).unwrap();
        let c = back.compensator().unwrap();
        assert_eq!(c.characterized_area(), Some(a));
        assert!(c.extrapolates_by_model());
        f.area = Some(Area {
            x_um: [20.0, 10.0],
            y_um: [30.0, 40.0],
        });
        assert!(f.validate().is_err(), "low > high is refused");
    }
}
