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
//! Direction: a node's value is the mean of its visits, whatever their
//! approach. A grid measured with one approach direction per axis (a
//! raster) holds that direction's errors, and moves compensated with it
//! should arrive the same way (a unidirectional approach policy); a grid
//! measured from both sides holds the mean of the two, half the play off
//! either way.
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
    /// Rms of `e` over the measured nodes, per component, µm.
    pub rms_error_um: [f64; 2],
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
        let (nx, ny) = (xs_um.len(), ys_um.len());
        if offsets_um.len() != nx.saturating_mul(ny) {
            return Err(invalid(
                "grid",
                format!("{} node values for {nx} × {ny} nodes", offsets_um.len()),
            ));
        }
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
        let t = GridTable {
            xs_um: xs_um.to_vec(),
            ys_um: ys_um.to_vec(),
            ex_um: fill_holes(&ex, &measured, nx, ny),
            ey_um: fill_holes(&ey, &measured, nx, ny),
            measured,
            arrival: GridArrival::Unknown,
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
        GridBuildReport {
            nodes: [nx, ny],
            measured: n,
            filled: nx * ny - n,
            pitch_um: [pitch(&self.xs_um), pitch(&self.ys_um)],
            rms_error_um: [rms(&self.ex_um), rms(&self.ey_um)],
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
        for (k, len) in [
            ("grid.ex_um", self.ex_um.len()),
            ("grid.ey_um", self.ey_um.len()),
            ("grid.measured", self.measured.len()),
        ] {
            if len != nx * ny {
                return Err(invalid(
                    k,
                    format!("has {len} values; {nx} × {ny} nodes need {}", nx * ny),
                ));
            }
        }
        for (k, v) in [("grid.ex_um", &self.ex_um), ("grid.ey_um", &self.ey_um)] {
            if !v.iter().all(|e| e.is_finite() && e.abs() <= 1e6) {
                return Err(invalid(k, "every value must be finite, |e| ≤ 1e6 µm"));
            }
        }
        if !self.measured.iter().any(|m| *m) {
            return Err(invalid("grid.measured", "no node was measured"));
        }
        Ok(())
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
    /// nodes, the edge values outside. Call on a validated table.
    pub fn error_at_um(&self, x_um: f64, y_um: f64) -> [f64; 2] {
        let (ix, fx) = cell_of(&self.xs_um, x_um);
        let (iy, fy) = cell_of(&self.ys_um, y_um);
        let nx = self.xs_um.len();
        let at = |v: &[f64]| {
            let k = iy * nx + ix;
            let (a, b) = (v[k], v[k + 1]);
            let (c, d) = (v[k + nx], v[k + nx + 1]);
            (1.0 - fy) * ((1.0 - fx) * a + fx * b) + fy * ((1.0 - fx) * c + fx * d)
        };
        [at(&self.ex_um), at(&self.ey_um)]
    }
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
        let e = self.table.error_at_um(cx, cy);
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
            GridArrival::Unknown => super::solve(self, target, history, options),
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
