//! Step 9, grid logs only: a 2-D map term (`position_map`) fitted into the
//! extended model where it predicts held-out cells better than the model.
//!
//! Why after everything else: the findings are named causes (a period, a
//! slope, a table along one axis), each judged on held-out data. What they
//! and the base leave on a map can still hold joint x–y structure no named
//! cause carries (the grid report's non-separable finding) or separable
//! structure outside the model's vocabulary. A map of the extended model's
//! residual at the lattice's nodes carries both, so the extended model (and
//! the simulator that runs it) reproduces the measured map. It earns its
//! place like a finding: on held-out cells.
//!
//! 1. The residual of the extended model (measured − model, its nuisance
//!    constants removed), averaged per lattice cell; one layer, or one per
//!    arrival direction of the component's axis where the log holds both
//!    ways over most of the lattice.
//! 2. Held out: interleaved folds of cells (diagonal thirds judged;
//!    alternate rows and columns reported). A held-out node
//!    gets the mean of its visited training 4-neighbours (what the term
//!    does for a node the log never visited); the model alone predicts
//!    zero residual there.
//! 3. A map term for the component when the paired reduction of the
//!    held-out squared errors is `z_threshold` standard errors above zero
//!    and the held-out RMS drops by `min_gain_pct`: then its node values
//!    are the cells' residuals from all the data.

use serde::Serialize;

use super::{Diagnosis, ResidualSeries};
use crate::analysis::grid::{nearest, paired_reduction_z, GridReport};
use crate::model::terms::position_map::{PositionMapConfig, PositionMapTerm};
use crate::model::{Axis, ModelError};

/// The judged fold scheme's name (see [`SCHEMES`]).
pub const JUDGED_SCHEME: &str = "diagonal thirds";

/// Fold schemes: name, folds, fold of cell `(ix, iy)`. The first is judged.
/// No checkerboard: its held-out cells keep the same four training
/// neighbours as the diagonal thirds', so with this predictor it scores
/// the same; alternate rows and columns ask more (a held-out node's
/// neighbours along one axis are held out too: the map at half its
/// density).
/// The fold of cell `(ix, iy)`.
type FoldOf = fn(usize, usize) -> usize;

const SCHEMES: [(&str, usize, FoldOf); 3] = [
    (JUDGED_SCHEME, 3, |ix, iy| (ix + iy) % 3),
    ("alternate rows", 2, |_, iy| iy % 2),
    ("alternate columns", 2, |ix, _| ix % 2),
];

/// Fraction of the lattice each direction's layer must fill for the map
/// to get a layer per direction (else the directions are pooled).
const MIN_LAYER_FILL: f64 = 0.5;

/// Held-out scores of the map under one fold scheme.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MapFold {
    /// Fold scheme (`diagonal thirds`, `alternate rows`, `alternate
    /// columns`).
    pub scheme: String,
    /// Held-out cells judged (a cell without a visited training neighbour
    /// is not).
    pub cells: usize,
    /// Held-out RMS of the extended model alone, µm.
    pub model_um: f64,
    /// Held-out RMS of the extended model with the map, µm.
    pub with_map_um: f64,
}

/// The map term's verdict for one error component.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MapComponent {
    /// `x` or `y`.
    pub component: String,
    /// Name of the `position_map` term added to the extended model, when
    /// the map passed.
    pub term: Option<String>,
    /// The layers: `one way` (a single layer for every arrival), or
    /// `from below` and `from above` (the component's axis's arrival).
    pub layers: Vec<String>,
    /// Nodes `[columns, rows]` (the grid's lattice).
    pub nodes: [usize; 2],
    /// Held-out scores per fold scheme; the first is judged.
    pub folds: Vec<MapFold>,
    /// Drop of the judged held-out RMS with the map, %.
    pub gain_pct: f64,
    /// Paired z of the judged held-out squared errors.
    pub z: f64,
    /// The grid's noise floor for one cell, µm (what a map of a perfect
    /// model would still show).
    pub cell_noise_um: f64,
    /// In words: why the term was or was not added.
    pub verdict: String,
}

/// The map term of each measured component of a grid log.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MapTermReport {
    /// Per component.
    pub components: Vec<MapComponent>,
}

/// A layer: the residual's mean per cell and its visits, row-major.
struct Layer {
    mean_um: Vec<Option<f64>>,
}

/// Cell index of each row of the series on the grid's lattice, `None` for
/// an excluded row or one off the lattice's nodes.
fn cells_of_rows(s: &ResidualSeries, g: &GridReport) -> Vec<Option<usize>> {
    let nx = g.xs_um.len();
    // A row off every node by a quarter pitch is no visit of one.
    let (tx, ty) = (0.25 * g.pitch_um[0], 0.25 * g.pitch_um[1]);
    (0..s.x_um.len())
        .map(|i| {
            if s.excluded.get(i).copied().unwrap_or(true) {
                return None;
            }
            let ix = nearest(&g.xs_um, s.x_um[i]);
            let iy = nearest(&g.ys_um, s.y_um[i]);
            ((g.xs_um[ix] - s.x_um[i]).abs() <= tx && (g.ys_um[iy] - s.y_um[i]).abs() <= ty)
                .then_some(iy * nx + ix)
        })
        .collect()
}

/// The layers of component `c`: one per arrival direction of `c`'s axis
/// when each fills [`MIN_LAYER_FILL`] of the lattice, else one.
fn layers(s: &ResidualSeries, c: usize, cell: &[Option<usize>], n: usize) -> Vec<(String, Layer)> {
    let dirs = if c == 0 { &s.x_dir } else { &s.y_dir };
    let layer = |take: &dyn Fn(f64) -> bool| {
        let mut sum = vec![0.0; n];
        let mut cnt = vec![0usize; n];
        for (i, k) in cell.iter().enumerate() {
            if let Some(k) = *k {
                if take(dirs.get(i).copied().unwrap_or(0.0)) {
                    sum[k] += s.after_um[c][i];
                    cnt[k] += 1;
                }
            }
        }
        Layer {
            mean_um: (0..n)
                .map(|k| (cnt[k] > 0).then(|| sum[k] / cnt[k] as f64))
                .collect(),
        }
    };
    let filled = |l: &Layer| l.mean_um.iter().filter(|v| v.is_some()).count() as f64;
    let below = layer(&|d| d > 0.0);
    let above = layer(&|d| d < 0.0);
    if filled(&below) >= MIN_LAYER_FILL * n as f64 && filled(&above) >= MIN_LAYER_FILL * n as f64 {
        vec![("from below".into(), below), ("from above".into(), above)]
    } else {
        vec![("one way".into(), layer(&|_| true))]
    }
}

/// Mean of the visited 4-neighbours of `(ix, iy)` that `keep` accepts.
fn neighbour_mean(
    v: &[Option<f64>],
    nx: usize,
    ny: usize,
    ix: usize,
    iy: usize,
    keep: &dyn Fn(usize, usize) -> bool,
) -> Option<f64> {
    let mut sum = 0.0;
    let mut k = 0usize;
    let cand = [
        (ix.wrapping_sub(1), iy),
        (ix + 1, iy),
        (ix, iy.wrapping_sub(1)),
        (ix, iy + 1),
    ];
    for (jx, jy) in cand {
        if jx < nx && jy < ny && keep(jx, jy) {
            if let Some(x) = v[jy * nx + jx] {
                sum += x;
                k += 1;
            }
        }
    }
    (k > 0).then(|| sum / k as f64)
}

/// Held-out `(model, with map)` squared errors of every judged cell of
/// every layer under one scheme.
fn heldout(
    layers: &[(String, Layer)],
    nx: usize,
    ny: usize,
    folds: usize,
    fold: FoldOf,
) -> (Vec<f64>, Vec<f64>) {
    let (mut model, mut map) = (Vec::new(), Vec::new());
    for (_, l) in layers {
        for f in 0..folds {
            let train = |jx: usize, jy: usize| fold(jx, jy) != f;
            for iy in 0..ny {
                for ix in (0..nx).filter(|&ix| fold(ix, iy) == f) {
                    let Some(r) = l.mean_um[iy * nx + ix] else {
                        continue;
                    };
                    if let Some(p) = neighbour_mean(&l.mean_um, nx, ny, ix, iy, &train) {
                        model.push(r * r);
                        map.push((r - p).powi(2));
                    }
                }
            }
        }
    }
    (model, map)
}

fn rms(sq: &[f64]) -> f64 {
    if sq.is_empty() {
        0.0
    } else {
        (sq.iter().sum::<f64>() / sq.len() as f64).sqrt()
    }
}

/// Node values of a layer: the cell means, a node the log did not visit
/// filled from its visited neighbours (repeatedly, outwards), zero where
/// nothing reaches.
fn node_values(l: &Layer, nx: usize, ny: usize) -> Vec<f64> {
    let mut v = l.mean_um.clone();
    for _ in 0..nx + ny {
        let missing: Vec<usize> = (0..v.len()).filter(|&k| v[k].is_none()).collect();
        if missing.is_empty() {
            break;
        }
        let fill: Vec<(usize, Option<f64>)> = missing
            .iter()
            .map(|&k| (k, neighbour_mean(&v, nx, ny, k % nx, k / nx, &|_, _| true)))
            .collect();
        for (k, x) in fill {
            v[k] = x;
        }
    }
    v.into_iter().map(|x| x.unwrap_or(0.0)).collect()
}

/// A name for the term that no term of the model has yet.
fn free_name(d: &Diagnosis, base: &str) -> String {
    let taken = |n: &str| d.extended_model.terms().iter().any(|t| t.name() == n);
    if !taken(base) {
        return base.to_string();
    }
    (2..)
        .map(|i| format!("{base}_{i}"))
        .find(|n| !taken(n))
        .unwrap_or_else(|| base.to_string())
}

/// Judges a map term per measured component of the grid log `d` was
/// diagnosed on, and adds those that pass to `d.extended_model`.
pub(super) fn fit(d: &mut Diagnosis, g: &GridReport) -> Result<MapTermReport, ModelError> {
    let (nx, ny) = (g.xs_um.len(), g.ys_um.len());
    let n = nx * ny;
    let cell = cells_of_rows(&d.series, g);
    let mut components = Vec::new();
    for axis in Axis::ALL {
        if !d.measured_axes.contains(&axis) {
            continue;
        }
        let c = axis.index();
        let layers = layers(&d.series, c, &cell, n);
        let folds: Vec<(MapFold, Vec<f64>, Vec<f64>)> = SCHEMES
            .iter()
            .map(|&(scheme, k, fold)| {
                let (model, map) = heldout(&layers, nx, ny, k, fold);
                let f = MapFold {
                    scheme: scheme.to_string(),
                    cells: model.len(),
                    model_um: rms(&model),
                    with_map_um: rms(&map),
                };
                (f, model, map)
            })
            .collect();
        let (judged, model_sq, map_sq) = &folds[0];
        let gain_pct = if judged.model_um > 0.0 {
            100.0 * (1.0 - judged.with_map_um / judged.model_um)
        } else {
            0.0
        };
        let reductions: Vec<f64> = model_sq.iter().zip(map_sq).map(|(a, b)| a - b).collect();
        let z = paired_reduction_z(&reductions);
        let (zt, gt) = (d.options.z_threshold, d.options.min_gain_pct);
        let passes = judged.cells >= 3 && z >= zt && gain_pct >= gt;
        let mut comp = MapComponent {
            component: axis.as_str().to_string(),
            term: None,
            layers: layers.iter().map(|(n, _)| n.clone()).collect(),
            nodes: [nx, ny],
            folds: folds.iter().map(|f| f.0.clone()).collect(),
            gain_pct,
            z,
            cell_noise_um: g.noise[c].cell_sigma_um,
            verdict: String::new(),
        };
        if passes {
            let name = free_name(d, &format!("{}_map", axis.as_str()));
            let mut vals = layers.iter().map(|(_, l)| node_values(l, nx, ny));
            let values_um = vals.next().unwrap_or_else(|| vec![0.0; n]);
            let from_above_um = vals.next();
            let term = PositionMapTerm::new(
                &name,
                PositionMapConfig {
                    component: axis,
                    xs_um: g.xs_um.clone(),
                    ys_um: g.ys_um.clone(),
                    values_um,
                    from_above_um,
                },
            )?;
            d.extended_model.push_term(Box::new(term))?;
            comp.verdict = format!(
                "fitted into the extended model as `{name}`: held-out ({JUDGED_SCHEME}) {:.4} → {:.4} µm ({gain_pct:+.0} %, z = {z:.1} ≥ {zt}, gain ≥ {gt} %)",
                judged.model_um, judged.with_map_um
            );
            comp.term = Some(name);
        } else {
            comp.verdict = format!(
                "not added: held-out ({JUDGED_SCHEME}) {:.4} → {:.4} µm ({gain_pct:+.0} %, z = {z:.1}; needs z ≥ {zt} and gain ≥ {gt} %): what the model leaves between neighbouring cells is not a map the neighbours predict",
                judged.model_um, judged.with_map_um
            );
        }
        components.push(comp);
    }
    Ok(MapTermReport { components })
}
