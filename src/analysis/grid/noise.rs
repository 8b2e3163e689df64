//! Step 3: the noise floor of a map's cells.
//!
//! With several visits per cell, the visits' scatter (pooled) is the
//! noise of one visit, and a cell's mean has that over √visits. A one-pass
//! map has no replicates; its floor comes from the neighbours along each
//! line: the second difference `e[i−1] − 2e[i] + e[i+1]` of three evenly
//! spaced cells removes any error that is straight over two pitches and
//! leaves `√6` times the noise of white noise. It is taken robustly (1.4826
//! times the median absolute deviation) along the rows and along the
//! columns, and the smaller is the floor: structure that curves over two
//! pitches only adds to a second difference, so the smaller direction is
//! the tighter upper bound of the noise. (A raster's fast axis usually
//! gives it: its neighbours were measured seconds apart.)

use serde::Serialize;

use super::GridMap;

/// Spacing mismatch up to which three cells count as evenly spaced.
const EVEN: f64 = 0.1;

/// Noise of one component of a map.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct NoiseFloor {
    /// Noise of one cell's mean value, µm: the floor every other figure
    /// is compared against.
    pub cell_sigma_um: f64,
    /// Where it comes from: `replicates` or `neighbours along x` / `y`.
    pub source: String,
    /// From second differences along the rows (x), µm; `None` with fewer
    /// than 5 triples.
    pub along_x_um: Option<f64>,
    /// From second differences along the columns (y), µm.
    pub along_y_um: Option<f64>,
    /// Pooled scatter of one visit about its cell's mean, µm (cells
    /// visited more than once).
    pub replicate_um: Option<f64>,
}

/// Robust σ of `v` about its median.
fn robust_sigma(mut v: Vec<f64>) -> Option<f64> {
    if v.len() < 5 {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let med = v[v.len() / 2];
    let mut dev: Vec<f64> = v.iter().map(|x| (x - med).abs()).collect();
    dev.sort_by(f64::total_cmp);
    Some(1.4826 * dev[dev.len() / 2])
}

/// Second differences of component `c` along x (`along_x`) or y.
fn second_differences(map: &GridMap, c: usize, along_x: bool) -> Vec<f64> {
    let (n_line, n_along) = if along_x {
        (map.ny(), map.nx())
    } else {
        (map.nx(), map.ny())
    };
    let pos = if along_x { &map.xs_um } else { &map.ys_um };
    let mut out = Vec::new();
    for l in 0..n_line {
        let get = |i: usize| {
            if along_x {
                map.cell(i, l)
            } else {
                map.cell(l, i)
            }
        };
        for i in 1..n_along.saturating_sub(1) {
            let (a, b) = (pos[i] - pos[i - 1], pos[i + 1] - pos[i]);
            if (a - b).abs() > EVEN * a.max(b) {
                continue;
            }
            if let (Some(p), Some(q), Some(r)) = (get(i - 1), get(i), get(i + 1)) {
                out.push(p.e_um[c] - 2.0 * q.e_um[c] + r.e_um[c]);
            }
        }
    }
    out
}

/// The noise floor of component `c` (see the module docs).
pub(super) fn floor(map: &GridMap, c: usize) -> NoiseFloor {
    let along_x = robust_sigma(second_differences(map, c, true)).map(|s| s / 6f64.sqrt());
    let along_y = robust_sigma(second_differences(map, c, false)).map(|s| s / 6f64.sqrt());
    let (mut ss, mut dof, mut inv_visits, mut cells) = (0.0, 0usize, 0.0, 0usize);
    for cell in map.cells.iter().flatten() {
        if cell.visits > 1 {
            ss += cell.ss_um2[c];
            dof += cell.visits - 1;
        }
        inv_visits += 1.0 / cell.visits as f64;
        cells += 1;
    }
    let replicate = (dof >= 5).then(|| (ss / dof as f64).sqrt());
    let mean_inv = if cells > 0 {
        inv_visits / cells as f64
    } else {
        1.0
    };
    let (cell_sigma_um, source) = match (replicate, along_x, along_y) {
        (Some(r), _, _) => (r * mean_inv.sqrt(), "replicates"),
        (None, Some(a), Some(b)) if b < a => (b, "neighbours along y"),
        (None, Some(a), _) => (a, "neighbours along x"),
        (None, None, Some(b)) => (b, "neighbours along y"),
        (None, None, None) => (f64::NAN, "none: too few cells"),
    };
    NoiseFloor {
        cell_sigma_um,
        source: source.into(),
        along_x_um: along_x,
        along_y_um: along_y,
        replicate_um: replicate,
    }
}
