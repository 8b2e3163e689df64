//! The 2-D compensation map: the error measured on a lattice of (x, y)
//! targets, interpolated bilinearly between its nodes.
//!
//! Why beside the paper's tables: those are `f(x) + g(y)` per direction
//! plus a squareness (eqs. 4 and 5), and cannot hold error that depends on
//! both axes at once (the y error's slope along x changing across y, as on
//! a stacked stage whose upper guide is not flat). A map holds whatever its
//! grid measured, at the price of one measurement per node: a grid
//! characterization, or an outside instrument's grid map imported with
//! `micropos import --format grid`.
//!
//! Sign conventions: stage frame, µm. Like the lookup tables the file holds
//! the paper's error `e = target − measured` per node; the compensator
//! predicts the offset `observed − commanded = −e` at the commanded
//! position.
//!
//! Direction: a grid measured with one approach direction per axis (a
//! raster, every node from below) holds that direction's errors, and moves
//! compensated with it arrive the same way ([`GridArrival::FromBelow`]: a
//! unidirectional approach). A grid measured from both sides, each visit's
//! direction known (microposd's grid plan with `approach = both`, or an
//! import with a direction column), holds two layers, as the paper's
//! tables hold a forward and a backward table per axis
//! ([`GridArrival::Both`]): the nodes reached from below on both axes, and
//! [`GridTable::from_above`], those reached from above. A compensated move
//! then arrives either way (the caller's approach policy); the x component
//! is read from the layer of x's arrival direction, y from y's. Where a
//! grid's visits' directions are not known the node holds the mean of the
//! visits, half the play off either way.
//!
//! Nodes the grid did not visit are filled from their neighbours (the
//! discrete Laplace equation, so a hole inside the lattice gets the smooth
//! surface around it; one on the rim the mean of its neighbours, nothing
//! extrapolated) and marked as not measured. Outside the lattice the map holds
//! its edge values, which were never measured there: the daemon refuses or
//! warns by its area ([`super::Area`]).

use serde::{Deserialize, Serialize};

use super::{
    invalid, ApproachPolicy, Area, CompError, Compensator, MotionHistory, MovePlan, PlanOptions,
};
use crate::model::{Direction, MotionState, XyUm};

/// Most nodes a map may have (a 1 µm pitch over 1 mm², far beyond any grid
/// a stage is measured on; it bounds the memory a file can ask for).
pub const MAX_NODES: usize = 1 << 20;

/// A 2-D error map. See the module docs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GridTable {
    /// Node x positions (commanded), strictly ascending, µm.
    pub xs_um: Vec<f64>,
    /// Node y positions (commanded), strictly ascending, µm.
    pub ys_um: Vec<f64>,
    /// `e_x = x_target − x_measured` per node, row-major (`[iy·nx + ix]`), µm.
    pub ex_um: Vec<f64>,
    /// `e_y = y_target − y_measured` per node, row-major, µm.
    pub ey_um: Vec<f64>,
    /// Whether each node was measured (`false`: filled from neighbours).
    pub measured: Vec<bool>,
    /// How the nodes were reached (default: not known).
    #[serde(default)]
    pub arrival: GridArrival,
    /// The nodes reached from above on both axes, on the same lattice
    /// (present exactly when `arrival` is [`GridArrival::Both`]; the fields
    /// above then hold the nodes reached from below).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub from_above: Option<GridLayer>,
}

/// One direction's node values of a bidirectional map (same layout and
/// sign as [`GridTable`]'s own fields).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GridLayer {
    /// `e_x = x_target − x_measured` per node, row-major, µm.
    pub ex_um: Vec<f64>,
    /// `e_y = y_target − y_measured` per node, row-major, µm.
    pub ey_um: Vec<f64>,
    /// Whether each node was measured in this direction.
    pub measured: Vec<bool>,
}

/// How a grid's nodes were reached, which decides how compensated moves
/// must arrive for the map to hold.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum GridArrival {
    /// Not known (an imported map): moves are planned with the caller's
    /// approach policy.
    #[default]
    Unknown,
    /// Every node from below on both axes (microposd's grid plan): every
    /// compensated move arrives from below on both axes too (a
    /// unidirectional approach, whatever the caller's policy), so it meets
    /// the play as the map did.
    FromBelow,
    /// Every node from below and from above on both axes (microposd's grid
    /// plan with `approach = both`, or an import with a direction column):
    /// two layers, moves arrive either way (the caller's policy) and each
    /// component is read from its own axis's arrival direction; an axis
    /// whose direction is not known gets the mean of the two layers.
    Both,
}

/// What a map build found.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct GridBuildReport {
    /// Columns and rows.
    pub nodes: [usize; 2],
    /// Nodes measured.
    pub measured: usize,
    /// Nodes filled from their neighbours.
    pub filled: usize,
    /// Mean spacing of the nodes along x and y, µm.
    pub pitch_um: [f64; 2],
    /// Rms of `e` over the measured nodes, per component, µm (the layer
    /// from below when there are two).
    pub rms_error_um: [f64; 2],
    /// A bidirectional map: nodes measured from above.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub measured_from_above: Option<usize>,
    /// A bidirectional map: rms over the nodes measured both ways of the
    /// reversal `e_above − e_below` per component, µm (the play and its
    /// variation over the plane).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reversal_rms_um: Option<[f64; 2]>,
}

/// Sweeps of the Laplace fill (each moves every hole towards the mean of
/// its neighbours; convergence is checked, this only bounds the work).
const FILL_SWEEPS: usize = 10_000;
const FILL_TOLERANCE_UM: f64 = 1e-9;

impl GridTable {
    /// The map of a lattice of nodes `xs_um` × `ys_um` (ascending) whose
    /// row-major `offsets_um` (`[iy·nx + ix]`) hold each visited node's
    /// mean `measured − target` (a grid log's cells, e.g.
    /// `analysis::grid::GridMap`), `None` where the grid did not go.
    pub fn from_lattice(
        xs_um: &[f64],
        ys_um: &[f64],
        offsets_um: &[Option<[f64; 2]>],
    ) -> Result<(GridTable, GridBuildReport), CompError> {
        Self::from_lattices(xs_um, ys_um, offsets_um, None)
    }

    /// A bidirectional map ([`GridArrival::Both`]) when `above_um` holds
    /// the offsets of the nodes reached from above (`below_um` those
    /// reached from below, same layout as [`GridTable::from_lattice`]);
    /// with `None`, [`GridTable::from_lattice`].
    pub fn from_lattices(
        xs_um: &[f64],
        ys_um: &[f64],
        below_um: &[Option<[f64; 2]>],
        above_um: Option<&[Option<[f64; 2]>]>,
    ) -> Result<(GridTable, GridBuildReport), CompError> {
        let (nx, ny) = (xs_um.len(), ys_um.len());
        let layer = |offsets: &[Option<[f64; 2]>], key: &str| {
            if offsets.len() != nx.saturating_mul(ny) {
                return Err(invalid(
                    key,
                    format!("{} node values for {nx} × {ny} nodes", offsets.len()),
                ));
            }
            Ok(layer_of(offsets, nx, ny))
        };
        let below = layer(below_um, "grid")?;
        let from_above = above_um.map(|a| layer(a, "grid.from_above")).transpose()?;
        let t = GridTable {
            xs_um: xs_um.to_vec(),
            ys_um: ys_um.to_vec(),
            ex_um: below.ex_um,
            ey_um: below.ey_um,
            measured: below.measured,
            arrival: if from_above.is_some() {
                GridArrival::Both
            } else {
                GridArrival::Unknown
            },
            from_above,
        };
        t.validate()?;
        let report = t.report();
        Ok((t, report))
    }

    fn report(&self) -> GridBuildReport {
        let (nx, ny) = (self.xs_um.len(), self.ys_um.len());
        let n = self.measured.iter().filter(|m| **m).count();
        let rms = |v: &[f64]| {
            let s: f64 = v
                .iter()
                .zip(&self.measured)
                .filter(|(_, m)| **m)
                .map(|(e, _)| e * e)
                .sum();
            (s / n.max(1) as f64).sqrt()
        };
        let pitch = |v: &[f64]| (v[v.len() - 1] - v[0]) / (v.len() - 1) as f64;
        let reversal = self.from_above.as_ref().map(|a| {
            let both: Vec<usize> = (0..nx * ny)
                .filter(|&k| self.measured[k] && a.measured[k])
                .collect();
            let rms_of = |below: &[f64], above: &[f64]| {
                let s: f64 = both.iter().map(|&k| (above[k] - below[k]).powi(2)).sum();
                (s / both.len().max(1) as f64).sqrt()
            };
            [rms_of(&self.ex_um, &a.ex_um), rms_of(&self.ey_um, &a.ey_um)]
        });
        GridBuildReport {
            nodes: [nx, ny],
            measured: n,
            filled: nx * ny - n,
            pitch_um: [pitch(&self.xs_um), pitch(&self.ys_um)],
            rms_error_um: [rms(&self.ex_um), rms(&self.ey_um)],
            measured_from_above: self
                .from_above
                .as_ref()
                .map(|a| a.measured.iter().filter(|m| **m).count()),
            reversal_rms_um: reversal,
        }
    }

    /// Checks the shape and every number.
    pub fn validate(&self) -> Result<(), CompError> {
        let (nx, ny) = (self.xs_um.len(), self.ys_um.len());
        if nx < 2 || ny < 2 {
            return Err(invalid("grid", "needs at least 2 × 2 nodes"));
        }
        if nx.saturating_mul(ny) > MAX_NODES {
            return Err(invalid("grid", format!("more than {MAX_NODES} nodes")));
        }
        for (k, v) in [("grid.xs_um", &self.xs_um), ("grid.ys_um", &self.ys_um)] {
            if !v.iter().all(|p| p.is_finite() && p.abs() <= 1e9)
                || !v.windows(2).all(|w| w[0] < w[1])
            {
                return Err(invalid(k, "must be finite and strictly ascending"));
            }
        }
        validate_layer(&self.ex_um, &self.ey_um, &self.measured, nx * ny, "grid")?;
        match (&self.from_above, self.arrival) {
            (Some(a), GridArrival::Both) => {
                validate_layer(&a.ex_um, &a.ey_um, &a.measured, nx * ny, "grid.from_above")
            }
            (None, GridArrival::Both) => Err(invalid(
                "grid.from_above",
                "arrival = \"both\" needs the layer of the nodes reached from above",
            )),
            (Some(_), _) => Err(invalid(
                "grid.from_above",
                "a layer from above needs arrival = \"both\"",
            )),
            (None, _) => Ok(()),
        }
    }

    /// The span of the nodes.
    pub fn area(&self) -> Area {
        let span = |v: &[f64]| [v[0], v[v.len() - 1]];
        Area {
            x_um: span(&self.xs_um),
            y_um: span(&self.ys_um),
        }
    }

    /// `e = target − measured` at `(x, y)` (µm), bilinear between the
    /// nodes, the edge values outside; of the layer from below when there
    /// are two. Call on a validated table.
    pub fn error_at_um(&self, x_um: f64, y_um: f64) -> [f64; 2] {
        let at = self.bilinear(x_um, y_um);
        [at(&self.ex_um), at(&self.ey_um)]
    }

    /// `e` at `(x, y)` for an arrival in `dirs` (`[x, y]`): each component
    /// from its own axis's layer when the map has two (the mean of both
    /// for [`Direction::Unknown`]), else [`GridTable::error_at_um`].
    pub fn error_at_dir_um(&self, x_um: f64, y_um: f64, dirs: [Direction; 2]) -> [f64; 2] {
        let Some(above) = &self.from_above else {
            return self.error_at_um(x_um, y_um);
        };
        let at = self.bilinear(x_um, y_um);
        let pick = |below: &[f64], above: &[f64], dir: Direction| match dir {
            Direction::Forward => at(below),
            Direction::Backward => at(above),
            Direction::Unknown => 0.5 * (at(below) + at(above)),
        };
        [
            pick(&self.ex_um, &above.ex_um, dirs[0]),
            pick(&self.ey_um, &above.ey_um, dirs[1]),
        ]
    }

    /// Bilinear interpolation of a node field at `(x, y)`.
    fn bilinear(&self, x_um: f64, y_um: f64) -> impl Fn(&[f64]) -> f64 {
        let (ix, fx) = cell_of(&self.xs_um, x_um);
        let (iy, fy) = cell_of(&self.ys_um, y_um);
        let nx = self.xs_um.len();
        move |v: &[f64]| {
            let k = iy * nx + ix;
            let (a, b) = (v[k], v[k + 1]);
            let (c, d) = (v[k + nx], v[k + nx + 1]);
            (1.0 - fy) * ((1.0 - fx) * a + fx * b) + fy * ((1.0 - fx) * c + fx * d)
        }
    }
}

/// One direction's layer from its visited nodes' offsets (`measured −
/// target`), the holes filled.
fn layer_of(offsets_um: &[Option<[f64; 2]>], nx: usize, ny: usize) -> GridLayer {
    let mut ex = vec![0.0; offsets_um.len()];
    let mut ey = vec![0.0; offsets_um.len()];
    let mut measured = vec![false; offsets_um.len()];
    for (k, o) in offsets_um.iter().enumerate() {
        if let Some(o) = o {
            ex[k] = -o[0];
            ey[k] = -o[1];
            measured[k] = true;
        }
    }
    GridLayer {
        ex_um: fill_holes(&ex, &measured, nx, ny),
        ey_um: fill_holes(&ey, &measured, nx, ny),
        measured,
    }
}

/// Checks one layer's lengths and numbers (`key` names it in errors).
fn validate_layer(
    ex_um: &[f64],
    ey_um: &[f64],
    measured: &[bool],
    nodes: usize,
    key: &str,
) -> Result<(), CompError> {
    for (k, len) in [
        ("ex_um", ex_um.len()),
        ("ey_um", ey_um.len()),
        ("measured", measured.len()),
    ] {
        if len != nodes {
            return Err(invalid(
                format!("{key}.{k}"),
                format!("has {len} values; the lattice has {nodes} nodes"),
            ));
        }
    }
    for (k, v) in [("ex_um", ex_um), ("ey_um", ey_um)] {
        if !v.iter().all(|e| e.is_finite() && e.abs() <= 1e6) {
            return Err(invalid(
                format!("{key}.{k}"),
                "every value must be finite, |e| ≤ 1e6 µm",
            ));
        }
    }
    if !measured.iter().any(|m| *m) {
        return Err(invalid(format!("{key}.measured"), "no node was measured"));
    }
    Ok(())
}

/// The cell `[i, i+1]` of `nodes` (≥ 2, ascending) holding `v`, and the
/// fraction of the way across it; clamped to the ends (NaN: the first).
fn cell_of(nodes: &[f64], v: f64) -> (usize, f64) {
    let last = nodes.len() - 2;
    let i = nodes
        .partition_point(|&p| p <= v)
        .saturating_sub(1)
        .min(last);
    let f = (v - nodes[i]) / (nodes[i + 1] - nodes[i]);
    (i, if f.is_nan() { 0.0 } else { f.clamp(0.0, 1.0) })
}

/// Fills the nodes not `known` with the solution of the discrete Laplace
/// equation whose boundary values are the known nodes (Gauss–Seidel from
/// the mean), so each hole is the mean of its neighbours.
fn fill_holes(v: &[f64], known: &[bool], nx: usize, ny: usize) -> Vec<f64> {
    let mut out = v.to_vec();
    let n_known = known.iter().filter(|k| **k).count();
    if n_known == known.len() || n_known == 0 {
        return out;
    }
    let mean = v
        .iter()
        .zip(known)
        .filter(|(_, k)| **k)
        .map(|(x, _)| x)
        .sum::<f64>()
        / n_known as f64;
    for (o, k) in out.iter_mut().zip(known) {
        if !k {
            *o = mean;
        }
    }
    for _ in 0..FILL_SWEEPS {
        let mut change = 0.0f64;
        for iy in 0..ny {
            for ix in 0..nx {
                let k = iy * nx + ix;
                if known[k] {
                    continue;
                }
                let mut s = 0.0;
                let mut n = 0.0;
                if ix > 0 {
                    s += out[k - 1];
                    n += 1.0;
                }
                if ix + 1 < nx {
                    s += out[k + 1];
                    n += 1.0;
                }
                if iy > 0 {
                    s += out[k - nx];
                    n += 1.0;
                }
                if iy + 1 < ny {
                    s += out[k + nx];
                    n += 1.0;
                }
                let new = s / n;
                change = change.max((new - out[k]).abs());
                out[k] = new;
            }
        }
        if change < FILL_TOLERANCE_UM {
            break;
        }
    }
    out
}

/// The compensator of a [`GridTable`].
#[derive(Debug, Clone)]
pub struct GridCompensator {
    table: GridTable,
}

impl GridCompensator {
    /// Checks the table.
    pub fn new(table: GridTable) -> Result<Self, CompError> {
        table.validate()?;
        Ok(GridCompensator { table })
    }

    /// The table.
    pub fn table(&self) -> &GridTable {
        &self.table
    }
}

impl Compensator for GridCompensator {
    fn kind(&self) -> &'static str {
        "grid"
    }

    fn predicted_offset_um(&self, state: &MotionState) -> Result<[f64; 2], CompError> {
        let [cx, cy] = state.cmd_xy_um();
        let e = self
            .table
            .error_at_dir_um(cx, cy, [state.axes[0].dir, state.axes[1].dir]);
        Ok([-e[0], -e[1]])
    }

    fn characterized_area(&self) -> Option<Area> {
        Some(self.table.area())
    }

    fn command_for(
        &self,
        target: XyUm,
        history: &MotionHistory,
        options: &PlanOptions,
    ) -> Result<MovePlan, CompError> {
        match self.table.arrival {
            GridArrival::Unknown | GridArrival::Both => {
                super::solve(self, target, history, options)
            }
            GridArrival::FromBelow => {
                let below = PlanOptions {
                    policy: ApproachPolicy::Unidirectional([Direction::Forward; 2]),
                    ..*options
                };
                super::solve(self, target, history, &below)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn table(nx: usize, ny: usize, f: impl Fn(f64, f64) -> [f64; 2]) -> GridTable {
        let xs: Vec<f64> = (0..nx).map(|i| 100.0 * i as f64).collect();
        let ys: Vec<f64> = (0..ny).map(|i| 250.0 * i as f64).collect();
        let mut ex = Vec::new();
        let mut ey = Vec::new();
        for y in &ys {
            for x in &xs {
                let e = f(*x, *y);
                ex.push(e[0]);
                ey.push(e[1]);
            }
        }
        GridTable {
            xs_um: xs,
            ys_um: ys,
            ex_um: ex,
            ey_um: ey,
            measured: vec![true; nx * ny],
            arrival: GridArrival::Unknown,
            from_above: None,
        }
    }

    /// Bilinear interpolation reproduces any function of the form
    /// a + b·x + c·y + d·x·y exactly (a non-separable one included).
    #[test]
    fn bilinear_surfaces_are_exact() {
        let f = |x: f64, y: f64| {
            [
                0.3 + 1e-3 * x - 2e-3 * y + 4e-6 * x * y,
                -1.0 + 5e-4 * x * y / 100.0,
            ]
        };
        let t = table(6, 5, f);
        t.validate().unwrap();
        for (x, y) in [(0.0, 0.0), (37.5, 810.0), (499.9, 1000.0), (250.0, 125.0)] {
            let e = t.error_at_um(x, y);
            let want = f(x, y);
            assert!(
                (e[0] - want[0]).abs() < 1e-12 && (e[1] - want[1]).abs() < 1e-12,
                "{x} {y}"
            );
        }
        // Outside: the edge values.
        assert_eq!(t.error_at_um(-50.0, 2000.0), t.error_at_um(0.0, 1000.0));
    }

    /// Holes inside a linear field are filled with the linear field's
    /// value (the Laplace fill is exact for harmonic surfaces); a hole on
    /// the rim gets the mean of its neighbours (no extrapolation).
    #[test]
    fn holes_are_filled_from_their_rim() {
        let f = |x: f64, y: f64| [2e-3 * x + 1e-3 * y, -1e-3 * x];
        let mut t = table(7, 7, f);
        let nx = 7;
        let mut known = vec![true; 49];
        for k in [3 * nx + 3, 3 * nx + 4, 2 * nx + 3, 0] {
            known[k] = false;
            t.ex_um[k] = 99.0;
        }
        let filled = fill_holes(&t.ex_um, &known, 7, 7);
        assert!((filled[0] - (t.ex_um[1] + t.ex_um[nx]) / 2.0).abs() < 1e-6);
        for k in [3 * nx + 3, 3 * nx + 4, 2 * nx + 3] {
            let (x, y) = (t.xs_um[k % nx], t.ys_um[k / nx]);
            assert!(
                (filled[k] - f(x, y)[0]).abs() < 1e-6,
                "node {k}: {}",
                filled[k]
            );
        }
    }

    #[test]
    fn malformed_tables_are_refused_with_the_key() {
        let good = table(3, 3, |_, _| [0.0, 0.0]);
        let mut t = good.clone();
        t.xs_um[1] = t.xs_um[0];
        assert!(t.validate().unwrap_err().to_string().contains("grid.xs_um"));
        let mut t = good.clone();
        t.ey_um.pop();
        assert!(t.validate().unwrap_err().to_string().contains("grid.ey_um"));
        let mut t = good.clone();
        t.ex_um[4] = f64::NAN;
        assert!(t.validate().unwrap_err().to_string().contains("grid.ex_um"));
        let mut t = good;
        t.measured = vec![false; 9];
        assert!(t.validate().unwrap_err().to_string().contains("measured"));
    }

    /// A map measured both ways reads each component from its own axis's
    /// arrival direction, the mean where the direction is unknown; the
    /// report gives the reversal between the layers.
    #[test]
    fn a_bidirectional_map_reads_each_axis_from_its_arrival() {
        use Direction::{Backward, Forward, Unknown};
        let below = table(4, 3, |x, y| [1e-3 * x, -2e-3 * y]);
        let (xs, ys) = (below.xs_um.clone(), below.ys_um.clone());
        let offsets = |play: [f64; 2]| -> Vec<Option<[f64; 2]>> {
            below
                .ex_um
                .iter()
                .zip(&below.ey_um)
                .enumerate()
                .map(|(k, (ex, ey))| (k != 5).then_some([-ex + play[0], -ey + play[1]]))
                .collect()
        };
        let (t, report) =
            GridTable::from_lattices(&xs, &ys, &offsets([0.0; 2]), Some(&offsets([-2.0, 0.5])))
                .unwrap();
        assert_eq!(t.arrival, GridArrival::Both);
        assert_eq!(report.measured_from_above, Some(11));
        let r = report.reversal_rms_um.unwrap();
        assert!(
            (r[0] - 2.0).abs() < 1e-9 && (r[1] - 0.5).abs() < 1e-9,
            "{r:?}"
        );
        let (x, y) = (150.0, 300.0);
        let e0 = t.error_at_um(x, y);
        let e = t.error_at_dir_um(x, y, [Backward, Forward]);
        assert!((e[0] - (e0[0] + 2.0)).abs() < 1e-9 && (e[1] - e0[1]).abs() < 1e-9);
        let e = t.error_at_dir_um(x, y, [Forward, Backward]);
        assert!((e[0] - e0[0]).abs() < 1e-9 && (e[1] - (e0[1] - 0.5)).abs() < 1e-9);
        let e = t.error_at_dir_um(x, y, [Unknown, Unknown]);
        assert!((e[0] - (e0[0] + 1.0)).abs() < 1e-9 && (e[1] - (e0[1] - 0.25)).abs() < 1e-9);
        // Through the file format and back.
        let back: GridTable = toml::from_str(&toml::to_string(&t).unwrap()).unwrap();
        assert_eq!(back, t);
        // A layer without its arrival, or the arrival without its layer.
        let mut bad = t.clone();
        bad.arrival = GridArrival::FromBelow;
        assert!(bad
            .validate()
            .unwrap_err()
            .to_string()
            .contains("from_above"));
        let mut bad = t.clone();
        bad.from_above = None;
        assert!(bad
            .validate()
            .unwrap_err()
            .to_string()
            .contains("from_above"));
        let mut bad = t;
        if let Some(a) = bad.from_above.as_mut() {
            a.ey_um.pop();
        }
        assert!(bad
            .validate()
            .unwrap_err()
            .to_string()
            .contains("grid.from_above.ey_um"));
    }

    proptest! {
        /// The interpolated error lies within the range of the four nodes
        /// around the point (bilinear weights are a convex combination),
        /// for any point, inside or outside.
        #[test]
        fn interpolation_stays_within_its_nodes(
            vals in proptest::collection::vec(-5.0f64..5.0, 12),
            x in -300.0f64..600.0,
            y in -300.0f64..800.0,
        ) {
            let mut t = table(4, 3, |_, _| [0.0, 0.0]);
            t.ex_um = vals.clone();
            t.ey_um = vals.iter().map(|v| -v).collect();
            let e = t.error_at_um(x, y);
            let (lo, hi) = vals.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), v| (l.min(*v), h.max(*v)));
            prop_assert!(e[0] >= lo - 1e-12 && e[0] <= hi + 1e-12);
            prop_assert!((e[0] + e[1]).abs() < 1e-12);
        }
    }
}
