//! 2-D grid maps: a log whose targets fill a lattice over x and y (a
//! laser or camera map of an XY stage, point by point) read as a map of
//! the stage's error, in the stage's own frame.
//!
//! Why a module of its own: the model-based diagnosis reads a log as the
//! replay of commanded moves through one stage model, and its 1-D
//! reasoning (a held axis settles once per line, folds in time) does not
//! describe what a grid measures. A grid measures the error over the plane
//! directly, so what a metrologist reads from it is computed from the grid
//! alone, whatever the record order or the segments it was logged in:
//!
//! 1. **Cells** ([`GridMap::from_log`]): records grouped by target into the
//!    lattice of distinct x and y targets; a cell's error is the mean of
//!    its visits. Sign: `e = measured − target` (ISO 230-2 and the stage
//!    model's `true = cmd + Σ`), µm.
//! 2. **Geometry in the stage's frame** ([`geometry`]): a plane per
//!    component. The instrument's frame (a laser's mirror pair, a camera's
//!    tie) is rotated by an arbitrary angle, which puts equal and opposite
//!    slopes on `d(ex)/dy` and `d(ey)/dx`; only their sum, the
//!    out-of-squareness, belongs to the stage. The rotation is a nuisance,
//!    reported apart (fixed by taking the x axis as the reference, the
//!    stage model's convention for squareness).
//! 3. **Noise on one-pass grids** ([`noise`]): from the visits of a cell
//!    when there are several, else from the neighbours along each line
//!    (second differences).
//! 4. **Separable or not** ([`maps`]): the paper's compensation is
//!    `f(x) + g(y)` per component plus a squareness. What that leaves is
//!    measured, and a 2-D term (the separable part plus the interaction
//!    interpolated from the neighbouring cells) is judged on held-out
//!    cells (diagonal thirds; checkerboard and alternate lines reported): a finding only when it
//!    predicts held-out cells better by a paired test.

mod geometry;
mod maps;
mod noise;
mod report;
#[cfg(test)]
mod tests;
pub mod zones;

use serde::Serialize;

use crate::charact::log::{MeasurementLog, Record};
use crate::charact::scan::{grid_direction, is_sweep_anchor};
use crate::model::Direction;

pub use geometry::{Geometry, Slope};
pub(crate) use maps::paired_reduction_z;
pub use maps::{ComponentMaps, FoldScore, NonSeparable};
pub use noise::NoiseFloor;
pub use zones::{combine_zones, Zone, ZoneCombination, ZoneError, ZoneOptions, ZoneSetup};

/// Segments that are not points of a map: drift references and the
/// varied-length moves of a characterization.
fn off_grid(segment: &str) -> bool {
    segment == "drift_ref" || segment == "moves" || is_sweep_anchor(segment)
}

/// Fewest distinct positions per axis, and cells in all, that make a map.
const MIN_LINES: usize = 3;
const MIN_CELLS: usize = 9;
/// Fraction of the lattice's cells a log must fill to be read as a map
/// (a cross of two scan lines fills `(nx + ny − 1) / (nx·ny)`).
const MIN_FILL: f64 = 0.5;

/// One lattice cell: the visits of one (x, y) target.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Cell {
    /// Mean `measured − target` per component over the visits, µm.
    pub e_um: [f64; 2],
    /// Visits.
    pub visits: usize,
    /// Sum of squared deviations of the visits from their mean, µm², per
    /// component (for the replicate noise).
    #[serde(skip)]
    ss_um2: [f64; 2],
}

/// A log's targets as a lattice of cells.
#[derive(Debug, Clone, PartialEq)]
pub struct GridMap {
    /// Distinct x targets, ascending, µm.
    pub xs_um: Vec<f64>,
    /// Distinct y targets, ascending, µm.
    pub ys_um: Vec<f64>,
    /// Cells, row-major: `cells[iy * nx + ix]`, `None` where not visited.
    pub cells: Vec<Option<Cell>>,
}

/// The records that can be cells of a map: on-grid segments, finite
/// targets and readings; `None` unless both components are measured.
fn grid_records(records: &[Record], measured: [bool; 2]) -> Option<Vec<&Record>> {
    if measured != [true, true] {
        return None;
    }
    Some(
        records
            .iter()
            .filter(|r| !off_grid(&r.segment))
            .filter(|r| {
                [r.x_target_um, r.y_target_um, r.x_meas_um, r.y_meas_um]
                    .iter()
                    .all(|v| v.is_finite())
            })
            .collect(),
    )
}

/// The distinct x and y targets of `recs`, or `None` when they are too
/// few lines, or too many positions for the records to fill.
fn lattice(recs: &[&Record]) -> Option<(Vec<f64>, Vec<f64>)> {
    let span = |f: &dyn Fn(&Record) -> f64| {
        let (lo, hi) = recs
            .iter()
            .map(|r| f(r))
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), v| {
                (l.min(v), h.max(v))
            });
        hi - lo
    };
    let tol = |s: f64| (1e-6 * s).max(1e-3);
    let xs = distinct(
        recs.iter().map(|r| r.x_target_um).collect(),
        tol(span(&|r| r.x_target_um)),
    );
    let ys = distinct(
        recs.iter().map(|r| r.y_target_um).collect(),
        tol(span(&|r| r.y_target_um)),
    );
    if xs.len() < MIN_LINES || ys.len() < MIN_LINES {
        return None;
    }
    // At most `records` cells are visited: a lattice that many records
    // cannot fill to MIN_FILL is no map (and is never allocated).
    if (xs.len() as f64) * (ys.len() as f64) * MIN_FILL > recs.len() as f64 {
        return None;
    }
    Some((xs, ys))
}

/// The cells of `recs` on the lattice `xs` × `ys`, component `c` of each
/// from the records `takes(record, c)` (every record for a one-way grid;
/// one arrival direction of that component's axis for a grid measured
/// both ways); a cell needs a visit of each component. `None` when they
/// fill too little of the lattice to be a map.
fn cells_of(
    recs: &[&Record],
    xs: Vec<f64>,
    ys: Vec<f64>,
    takes: impl Fn(&Record, usize) -> bool,
) -> Option<GridMap> {
    let nx = xs.len();
    let n = nx * ys.len();
    if (n as f64) * MIN_FILL > recs.len() as f64 {
        return None;
    }
    let mut sum = vec![[0.0f64; 2]; n];
    let mut sum2 = vec![[0.0f64; 2]; n];
    let mut count = vec![[0usize; 2]; n];
    for r in recs {
        let k = nearest(&ys, r.y_target_um) * nx + nearest(&xs, r.x_target_um);
        let e = [r.x_meas_um - r.x_target_um, r.y_meas_um - r.y_target_um];
        for c in 0..2 {
            if takes(r, c) {
                sum[k][c] += e[c];
                sum2[k][c] += e[c] * e[c];
                count[k][c] += 1;
            }
        }
    }
    let cells: Vec<Option<Cell>> = (0..n)
        .map(|k| {
            let v = count[k];
            (v[0] > 0 && v[1] > 0).then(|| {
                let m = [sum[k][0] / v[0] as f64, sum[k][1] / v[1] as f64];
                Cell {
                    e_um: m,
                    visits: v[0].min(v[1]),
                    ss_um2: [0, 1].map(|c| (sum2[k][c] - v[c] as f64 * m[c] * m[c]).max(0.0)),
                }
            })
        })
        .collect();
    let filled = cells.iter().filter(|c| c.is_some()).count();
    if filled < MIN_CELLS || (filled as f64) < MIN_FILL * n as f64 {
        return None;
    }
    Some(GridMap {
        xs_um: xs,
        ys_um: ys,
        cells,
    })
}

/// Clusters sorted values that lie within `tol` of the previous one;
/// returns the cluster means.
fn distinct(mut v: Vec<f64>, tol: f64) -> Vec<f64> {
    v.sort_by(f64::total_cmp);
    let mut out: Vec<(f64, usize)> = Vec::new();
    let mut last = f64::NEG_INFINITY;
    for x in v {
        match out.last_mut() {
            Some((s, n)) if x - last <= tol => {
                *s += x;
                *n += 1;
            }
            _ => out.push((x, 1)),
        }
        last = x;
    }
    out.into_iter().map(|(s, n)| s / n as f64).collect()
}

/// Index of the value in `sorted` nearest to `x` (0 for a NaN `x`).
pub(crate) fn nearest(sorted: &[f64], x: f64) -> usize {
    let i = sorted.partition_point(|&v| v < x);
    if i == 0 {
        0
    } else if i == sorted.len() || x - sorted[i - 1] <= sorted[i] - x {
        i - 1
    } else {
        i
    }
}

impl GridMap {
    /// The log's map, or `None` when its targets do not fill a lattice of
    /// at least 3 × 3 positions (half of the cells or more) or either
    /// component is unmeasured (`measured`, `[x, y]`). Non-finite readings
    /// are left out.
    pub fn from_log(log: &MeasurementLog, measured: [bool; 2]) -> Option<GridMap> {
        Self::from_records(&log.records, measured)
    }

    /// [`GridMap::from_log`] of a log's records alone (a lattice needs
    /// nothing else of the log). A grid measured both ways, each node's
    /// direction in its segment (`crate::charact::scan::grid_direction`),
    /// is read as its nodes reached from below (one arrival per axis, as a
    /// one-way grid; the other way is [`GridMap::read`]'s), so the play is
    /// not read as noise.
    pub fn from_records(records: &[Record], measured: [bool; 2]) -> Option<GridMap> {
        Self::read(records, measured).map(|(map, _)| map)
    }

    /// A grid measured both ways: the maps of its nodes reached from below
    /// and from above (`[below, above]`) on the lattice of all its nodes,
    /// each component by its own axis's arrival direction (a serpentine's
    /// returning row gives x from above and y from below); `None` when the
    /// log does not hold both directions of both axes as a map each.
    pub fn directional(records: &[Record], measured: [bool; 2]) -> Option<[GridMap; 2]> {
        match Self::read(records, measured)? {
            (below, Some(above)) => Some([below, above]),
            (_, None) => None,
        }
    }

    /// The log's map ([`GridMap::from_records`]) and, for a grid measured
    /// both ways, the map of its arrivals from above: one pass over the
    /// records for callers that want both.
    pub fn read(records: &[Record], measured: [bool; 2]) -> Option<(GridMap, Option<GridMap>)> {
        let recs = grid_records(records, measured)?;
        let (xs, ys) = lattice(&recs)?;
        let dirs: Vec<[Direction; 2]> = recs
            .iter()
            .filter_map(|r| grid_direction(&r.segment))
            .collect();
        let has = |c: usize, d: Direction| dirs.iter().any(|v| v[c] == d);
        if (0..2).all(|c| has(c, Direction::Forward) && has(c, Direction::Backward)) {
            let way = |d: Direction| {
                move |r: &Record, c: usize| grid_direction(&r.segment).is_some_and(|v| v[c] == d)
            };
            let below = cells_of(&recs, xs.clone(), ys.clone(), way(Direction::Forward));
            let above = cells_of(&recs, xs.clone(), ys.clone(), way(Direction::Backward));
            if let (Some(below), Some(above)) = (below, above) {
                return Some((below, Some(above)));
            }
        }
        cells_of(&recs, xs, ys, |_, _| true).map(|map| (map, None))
    }

    /// Column and row of the cell nearest to `(x, y)`.
    pub fn index_of(&self, x_um: f64, y_um: f64) -> (usize, usize) {
        (nearest(&self.xs_um, x_um), nearest(&self.ys_um, y_um))
    }

    /// Columns (distinct x).
    pub fn nx(&self) -> usize {
        self.xs_um.len()
    }

    /// Rows (distinct y).
    pub fn ny(&self) -> usize {
        self.ys_um.len()
    }

    /// The cell at column `ix`, row `iy`.
    pub fn cell(&self, ix: usize, iy: usize) -> Option<&Cell> {
        self.cells.get(iy * self.nx() + ix).and_then(Option::as_ref)
    }

    /// Component `c` of every cell as a row-major field (`None` = empty).
    fn field(&self, c: usize) -> Vec<Option<f64>> {
        self.cells.iter().map(|k| k.map(|k| k.e_um[c])).collect()
    }

    /// Visited cells.
    pub fn filled(&self) -> usize {
        self.cells.iter().filter(|c| c.is_some()).count()
    }
}

/// What a grid map shows: see the module docs.
#[derive(Debug, Clone, Serialize)]
pub struct GridReport {
    /// Distinct x targets (columns) and y targets (rows).
    pub columns: usize,
    /// Rows of the lattice.
    pub rows: usize,
    /// Visited cells.
    pub cells: usize,
    /// Median visits per visited cell.
    pub visits_per_cell: usize,
    /// Pitch of the lattice per axis (median spacing), µm.
    pub pitch_um: [f64; 2],
    /// Extent of the lattice per axis, `[min, max]`, µm.
    pub x_range_um: [f64; 2],
    /// Extent along y, µm.
    pub y_range_um: [f64; 2],
    /// Scales, squareness and the measuring frame's rotation.
    pub geometry: Geometry,
    /// Noise floor per component.
    pub noise: [NoiseFloor; 2],
    /// Separable and 2-D maps per component, with their held-out scores.
    pub components: [ComponentMaps; 2],
    /// The lattice's x positions (columns), µm.
    pub xs_um: Vec<f64>,
    /// The lattice's y positions (rows), µm.
    pub ys_um: Vec<f64>,
    /// A grid measured both ways: the change with the arrival direction
    /// (the maps above are then of the arrivals from below).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reversal: Option<Reversal>,
}

/// What changes with the arrival direction on a grid measured both ways:
/// per component, `e(from above) − e(from below)` over the cells measured
/// both ways (ISO 230-2's reversal value, over the plane), µm. Positive:
/// the stage stops further along the axis when it arrives from above (the
/// play of a leadscrew axis).
#[derive(Debug, Clone, Serialize)]
pub struct Reversal {
    /// Cells measured both ways.
    pub cells: usize,
    /// Mean per component, µm.
    pub mean_um: [f64; 2],
    /// Rms about the mean per component (how much the play varies over
    /// the plane), µm.
    pub spread_um: [f64; 2],
    /// Largest `|reversal|` per component, µm.
    pub max_abs_um: [f64; 2],
}

impl Reversal {
    /// The reversal of two maps on one lattice (`None`: no cell measured
    /// both ways).
    fn between(below: &GridMap, above: &GridMap) -> Option<Reversal> {
        let d: Vec<[f64; 2]> = below
            .cells
            .iter()
            .zip(&above.cells)
            .filter_map(|(b, a)| {
                Some([
                    a.as_ref()?.e_um[0] - b.as_ref()?.e_um[0],
                    a.as_ref()?.e_um[1] - b.as_ref()?.e_um[1],
                ])
            })
            .collect();
        if d.is_empty() {
            return None;
        }
        let n = d.len() as f64;
        let mean_um = [0, 1].map(|c| d.iter().map(|v| v[c]).sum::<f64>() / n);
        Some(Reversal {
            cells: d.len(),
            mean_um,
            spread_um: [0, 1]
                .map(|c| (d.iter().map(|v| (v[c] - mean_um[c]).powi(2)).sum::<f64>() / n).sqrt()),
            max_abs_um: [0, 1].map(|c| d.iter().map(|v| v[c].abs()).fold(0.0, f64::max)),
        })
    }
}

/// The report of a log's grid ([`GridMap::from_records`], [`analyse`]),
/// with the reversal of a grid measured both ways; `None` when the records
/// are not a map.
pub fn report_of(
    records: &[Record],
    measured: [bool; 2],
    z_threshold: f64,
    min_gain_pct: f64,
) -> Option<GridReport> {
    let (map, above) = GridMap::read(records, measured)?;
    let mut report = analyse(&map, z_threshold, min_gain_pct);
    report.reversal = above.and_then(|above| Reversal::between(&map, &above));
    Some(report)
}

/// Pitch of sorted positions: their median spacing.
fn pitch(v: &[f64]) -> f64 {
    let mut d: Vec<f64> = v.windows(2).map(|w| w[1] - w[0]).collect();
    d.sort_by(f64::total_cmp);
    d.get(d.len() / 2).copied().unwrap_or(0.0)
}

/// Analyses a map; `z_threshold` and `min_gain_pct` are the diagnosis's
/// significance rule (a paired z of the held-out squared errors, and a
/// minimum drop of the held-out RMS).
pub fn analyse(map: &GridMap, z_threshold: f64, min_gain_pct: f64) -> GridReport {
    let geometry = geometry::fit(map);
    let noise = [noise::floor(map, 0), noise::floor(map, 1)];
    let components = [0, 1].map(|c| {
        let plane = geometry.plane(c);
        maps::judge(map, c, &plane, &noise[c], z_threshold, min_gain_pct)
    });
    let mut visits: Vec<usize> = map.cells.iter().flatten().map(|c| c.visits).collect();
    visits.sort_unstable();
    GridReport {
        columns: map.nx(),
        rows: map.ny(),
        cells: map.filled(),
        visits_per_cell: visits.get(visits.len() / 2).copied().unwrap_or(0),
        pitch_um: [pitch(&map.xs_um), pitch(&map.ys_um)],
        x_range_um: [map.xs_um[0], map.xs_um[map.nx() - 1]],
        y_range_um: [map.ys_um[0], map.ys_um[map.ny() - 1]],
        geometry,
        noise,
        components,
        xs_um: map.xs_um.clone(),
        ys_um: map.ys_um.clone(),
        reversal: None,
    }
}

pub use report::write_text;
