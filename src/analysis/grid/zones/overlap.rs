//! The overlap equations: every node of a zone that another zone's lattice
//! covers, against that zone's bilinear interpolation there.

use super::super::{nearest, GridMap};

/// One overlap difference: zone `node`'s reading at one of its nodes minus
/// zone `other`'s interpolated there.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Equation {
    /// The zone whose node this is.
    pub node: usize,
    /// The zone interpolated at it.
    pub other: usize,
    /// The node's position, µm.
    pub x_um: f64,
    /// The node's position, µm.
    pub y_um: f64,
    /// `e_node − e_other` per component, µm.
    pub d_um: [f64; 2],
    /// Least-squares weight: `1/(2m)` for a node `m` zones measured.
    pub weight: f64,
}

/// The equations and, per zone, its nodes that took part.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct Equations {
    /// All equations, zone by zone, node by node.
    pub list: Vec<Equation>,
    /// Per zone, its nodes another zone covered.
    pub overlap_nodes: Vec<usize>,
}

/// Where `v` falls on sorted positions: the bracketing indices and the
/// weight of the upper one; a position within `tol` of a node is that
/// node (so zones whose nodes coincide compare them directly, and a node
/// on the rim needs no cell beyond it). `None` outside.
fn bracket(sorted: &[f64], v: f64, tol: f64) -> Option<(usize, usize, f64)> {
    let i = nearest(sorted, v);
    let at = *sorted.get(i)?;
    if (at - v).abs() <= tol {
        return Some((i, i, 0.0));
    }
    let hi = sorted.partition_point(|&s| s < v);
    let lo = hi.checked_sub(1)?;
    let (a, b) = (*sorted.get(lo)?, *sorted.get(hi)?);
    Some((lo, hi, (v - a) / (b - a)))
}

/// The map's bilinear interpolation at `(x, y)`, `[ex, ey]` µm; `None`
/// outside its lattice or where a cell it needs was not measured.
pub(super) fn interpolate(map: &GridMap, x_um: f64, y_um: f64, tol: f64) -> Option<[f64; 2]> {
    let (x0, x1, wx) = bracket(&map.xs_um, x_um, tol)?;
    let (y0, y1, wy) = bracket(&map.ys_um, y_um, tol)?;
    let corners = [
        (x0, y0, (1.0 - wx) * (1.0 - wy)),
        (x1, y0, wx * (1.0 - wy)),
        (x0, y1, (1.0 - wx) * wy),
        (x1, y1, wx * wy),
    ];
    let mut v = [0.0; 2];
    for (ix, iy, w) in corners {
        if w == 0.0 {
            continue;
        }
        let cell = map.cell(ix, iy)?;
        v[0] += w * cell.e_um[0];
        v[1] += w * cell.e_um[1];
    }
    Some(v)
}

/// Every zone's filled nodes against every other zone covering them.
pub(super) fn equations(maps: &[&GridMap], tol: f64) -> Equations {
    let mut list = Vec::new();
    let mut overlap_nodes = vec![0; maps.len()];
    for (j, map) in maps.iter().enumerate() {
        for (iy, &y) in map.ys_um.iter().enumerate() {
            for (ix, &x) in map.xs_um.iter().enumerate() {
                let Some(cell) = map.cell(ix, iy) else {
                    continue;
                };
                let hits: Vec<(usize, [f64; 2])> = maps
                    .iter()
                    .enumerate()
                    .filter(|&(k, _)| k != j)
                    .filter_map(|(k, m)| interpolate(m, x, y, tol).map(|v| (k, v)))
                    .collect();
                if hits.is_empty() {
                    continue;
                }
                overlap_nodes[j] += 1;
                let weight = 1.0 / (2.0 * (hits.len() + 1) as f64);
                list.extend(hits.into_iter().map(|(k, v)| Equation {
                    node: j,
                    other: k,
                    x_um: x,
                    y_um: y,
                    d_um: [cell.e_um[0] - v[0], cell.e_um[1] - v[1]],
                    weight,
                }));
            }
        }
    }
    Equations {
        list,
        overlap_nodes,
    }
}
