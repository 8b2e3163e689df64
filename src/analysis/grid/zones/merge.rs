//! The combined map: the union lattice of the zones' nodes, each node the
//! mean of the zones' corrected readings there.

use super::super::{distinct, nearest, Cell, GridMap};
use super::fit::ComponentFit;
use super::ZoneSetup;

/// The union lattice of the maps' node positions and, on it, the mean of
/// every zone's reading minus its fitted set-up; also the zones averaged
/// per node. A node counts as one visit: the combined map is logged as one
/// record per node, and reads back the same.
pub(super) fn combine(maps: &[&GridMap], setups: &[ZoneSetup], tol: f64) -> (GridMap, Vec<usize>) {
    let xs = distinct(maps.iter().flat_map(|m| m.xs_um.clone()).collect(), tol);
    let ys = distinct(maps.iter().flat_map(|m| m.ys_um.clone()).collect(), tol);
    let nx = xs.len();
    let mut sum = vec![[0.0f64; 2]; nx * ys.len()];
    let mut count = vec![0usize; nx * ys.len()];
    for (map, s) in maps.iter().zip(setups) {
        for (iy, &y) in map.ys_um.iter().enumerate() {
            for (ix, &x) in map.xs_um.iter().enumerate() {
                let Some(cell) = map.cell(ix, iy) else {
                    continue;
                };
                let k = nearest(&ys, y) * nx + nearest(&xs, x);
                let set_up = s.at(x, y);
                sum[k][0] += cell.e_um[0] - set_up[0];
                sum[k][1] += cell.e_um[1] - set_up[1];
                count[k] += 1;
            }
        }
    }
    let cells = sum
        .iter()
        .zip(&count)
        .map(|(s, &n)| {
            (n > 0).then(|| Cell {
                e_um: [s[0] / n as f64, s[1] / n as f64],
                visits: 1,
                ss_um2: [0.0; 2],
            })
        })
        .collect();
    let map = GridMap {
        xs_um: xs,
        ys_um: ys,
        cells,
    };
    (map, count)
}

/// Standard uncertainty of each node of the combined map `[x, y]`, µm
/// (`None` where no zone measured): the reading noise over the zones
/// averaged, and the fitted set-ups' uncertainty carried to the node
/// (large far from the overlaps, where a slope's error is multiplied by
/// the distance). The two are taken as independent: at a node two zones
/// share, the fit sees their readings' difference and the map their sum,
/// which are uncorrelated for equal noise.
pub(super) fn sigmas(
    map: &GridMap,
    maps: &[&GridMap],
    centres: &[[f64; 2]],
    fits: &[ComponentFit; 2],
    tol: f64,
) -> Vec<Option<[f64; 2]>> {
    let mut out = Vec::with_capacity(map.cells.len());
    for &y in &map.ys_um {
        for &x in &map.xs_um {
            let zones: Vec<usize> = (0..maps.len())
                .filter(|&k| measured_at(maps[k], x, y, tol))
                .collect();
            if zones.is_empty() {
                out.push(None);
                continue;
            }
            let m = zones.len() as f64;
            out.push(Some(std::array::from_fn(|c| {
                let terms: Vec<(usize, f64)> = zones
                    .iter()
                    .map(|&k| {
                        (
                            k,
                            if c == 0 {
                                y - centres[k][1]
                            } else {
                                x - centres[k][0]
                            },
                        )
                    })
                    .collect();
                let noise = fits[c].noise_um;
                (noise * noise / m + fits[c].sum_variance(&terms) / (m * m)).sqrt()
            })));
        }
    }
    out
}

/// Whether `map` has a measured node within `tol` of `(x, y)`.
fn measured_at(map: &GridMap, x: f64, y: f64, tol: f64) -> bool {
    let (ix, iy) = map.index_of(x, y);
    let near = |v: Option<&f64>, p: f64| v.is_some_and(|v| (v - p).abs() <= tol);
    near(map.xs_um.get(ix), x) && near(map.ys_um.get(iy), y) && map.cell(ix, iy).is_some()
}
