//! Step 2: the plane of each component, read in the stage's frame.
//!
//! Slopes are in µm/m, i.e. ppm for a scale and µrad for an angle, of
//! `e = measured − target`. The measuring instrument's frame is rotated by
//! an arbitrary small angle φ against the stage's axes (a laser's mirror
//! pair, a camera's tie): it adds `−φ·y` to `ex` and `+φ·x` to `ey`, so
//! neither cross slope alone is a property of the stage. Their sum is:
//! the out-of-squareness `d(ex)/dy + d(ey)/dx` (ISO 230-1's squareness of
//! the y axis's path to the x axis's, on the sign convention of the stage
//! model's `squareness` term: positive when +Y leans towards +X, i.e. the
//! angle between the positive axes is less than 90° by that much). The
//! reference is taken square (a mirror pair's own out-of-squareness adds
//! to the figure).
//!
//! Uncertainties: a plane's residual on a real map is structure, not
//! white noise, and neighbouring cells share it, so the least-squares σ
//! is too small. Each slope's σ is the largest of the least-squares σ and
//! the jackknife σ over whole columns and over whole rows (a line left out
//! at a time), which sees what a line's worth of structure does to it.

use serde::Serialize;

use super::GridMap;

/// A slope with its standard uncertainty.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Slope {
    /// Value, µm/m (ppm or µrad).
    pub value: f64,
    /// Standard uncertainty, µm/m; infinite when the map cannot tell.
    pub sigma: f64,
}

/// One component's plane: `e = offset + dx·(x − xc) + dy·(y − yc)`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Plane {
    /// Offset at the lattice centre, µm.
    pub offset_um: f64,
    /// Slope along x, µm/m.
    pub dx: f64,
    /// Slope along y, µm/m.
    pub dy: f64,
    /// Centre x, µm.
    pub xc_um: f64,
    /// Centre y, µm.
    pub yc_um: f64,
}

impl Plane {
    /// The plane at `(x, y)`, µm.
    pub fn at(&self, x_um: f64, y_um: f64) -> f64 {
        self.offset_um + 1e-6 * (self.dx * (x_um - self.xc_um) + self.dy * (y_um - self.yc_um))
    }
}

/// The map's geometry in the stage's frame.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Geometry {
    /// Scale error of x, `d(ex)/dx`, ppm.
    pub scale_x_ppm: Slope,
    /// Scale error of y, `d(ey)/dy`, ppm.
    pub scale_y_ppm: Slope,
    /// Out-of-squareness `d(ex)/dy + d(ey)/dx`, µrad: invariant to the
    /// measuring frame's rotation (see the module docs for the sign).
    pub out_of_squareness_urad: Slope,
    /// The stage's x axis as the instrument sees it, µrad counter-
    /// clockwise from the instrument's x (`d(ey)/dx`): the measuring
    /// frame's rotation, a nuisance of the set-up, not of the stage.
    pub frame_rotation_urad: Slope,
    /// `d(ex)/dy` as measured, in the instrument's frame, µrad.
    pub dex_dy_instrument_urad: Slope,
    /// The planes of `ex` and `ey` (instrument frame).
    pub planes: [Plane; 2],
}

impl Geometry {
    /// Component `c`'s plane.
    pub fn plane(&self, c: usize) -> Plane {
        self.planes[c]
    }
}

/// Least-squares plane of component `c` over the cells `keep` admits:
/// `[offset, dx, dy]`, the normal matrix's inverse and the residual
/// variance; `None` when the cells do not span a plane.
fn plane_fit(
    map: &GridMap,
    c: usize,
    centre: (f64, f64),
    keep: &dyn Fn(usize, usize) -> bool,
) -> Option<([f64; 3], [[f64; 3]; 3], f64)> {
    let mut ata = [[0.0f64; 3]; 3];
    let mut atb = [0.0f64; 3];
    let mut rows = Vec::new();
    for iy in 0..map.ny() {
        for ix in 0..map.nx() {
            let Some(cell) = map.cell(ix, iy) else {
                continue;
            };
            if !keep(ix, iy) {
                continue;
            }
            let a = [
                1.0,
                1e-6 * (map.xs_um[ix] - centre.0),
                1e-6 * (map.ys_um[iy] - centre.1),
            ];
            for i in 0..3 {
                for j in 0..3 {
                    ata[i][j] += a[i] * a[j];
                }
                atb[i] += a[i] * cell.e_um[c];
            }
            rows.push((a, cell.e_um[c]));
        }
    }
    let inv = invert3(&ata)?;
    let p: [f64; 3] = std::array::from_fn(|i| (0..3).map(|j| inv[i][j] * atb[j]).sum());
    let dof = rows.len().checked_sub(3).filter(|&d| d > 0)?;
    let ss: f64 = rows
        .iter()
        .map(|(a, e)| {
            let r = e - (p[0] * a[0] + p[1] * a[1] + p[2] * a[2]);
            r * r
        })
        .sum();
    Some((p, inv, ss / dof as f64))
}

/// Inverse of a 3 × 3 matrix, `None` when (nearly) singular.
fn invert3(m: &[[f64; 3]; 3]) -> Option<[[f64; 3]; 3]> {
    let c = |i: usize, j: usize| {
        let (r0, r1) = ((i + 1) % 3, (i + 2) % 3);
        let (c0, c1) = ((j + 1) % 3, (j + 2) % 3);
        m[r0][c0] * m[r1][c1] - m[r0][c1] * m[r1][c0]
    };
    let det: f64 = (0..3).map(|j| m[0][j] * c(0, j)).sum();
    // Singular when the determinant of the matrix scaled to a unit
    // diagonal is (nearly) zero: independent of the columns' units, so a
    // lattice of a few hundred µm (slopes' columns of 1e-4) is not taken
    // for a degenerate one, as a test against the largest entry did.
    let diag: f64 = (0..3).map(|i| m[i][i]).product();
    if !det.is_finite() || diag.is_nan() || diag <= 0.0 || det.abs() <= 1e-12 * diag {
        return None;
    }
    // Inverse = adjugate / det; the cofactor of (j, i) gives entry (i, j).
    Some(std::array::from_fn(|i| {
        std::array::from_fn(|j| c(j, i) / det)
    }))
}

/// The five slopes of interest from the two planes' parameters.
fn slopes(px: &[f64; 3], py: &[f64; 3]) -> [f64; 5] {
    // scale x, scale y, squareness, rotation, d(ex)/dy
    [px[1], py[2], px[2] + py[1], py[1], px[2]]
}

/// Jackknife σ of the five slopes with whole lines left out in turn
/// (`lines` lines, `drop(line, ix, iy)` true for the cells of `line`).
fn jackknife(
    map: &GridMap,
    centre: (f64, f64),
    lines: usize,
    drop: &dyn Fn(usize, usize, usize) -> bool,
) -> [f64; 5] {
    let mut est: Vec<[f64; 5]> = Vec::new();
    for l in 0..lines {
        let keep = |ix: usize, iy: usize| !drop(l, ix, iy);
        if let (Some((px, _, _)), Some((py, _, _))) = (
            plane_fit(map, 0, centre, &keep),
            plane_fit(map, 1, centre, &keep),
        ) {
            est.push(slopes(&px, &py));
        }
    }
    let m = est.len();
    if m < 3 {
        return [f64::INFINITY; 5];
    }
    std::array::from_fn(|k| {
        let mean = est.iter().map(|e| e[k]).sum::<f64>() / m as f64;
        let ss: f64 = est.iter().map(|e| (e[k] - mean).powi(2)).sum();
        ((m - 1) as f64 / m as f64 * ss).sqrt()
    })
}

/// Fits the geometry of `map` (see the module docs).
pub(super) fn fit(map: &GridMap) -> Geometry {
    let centre = (
        map.xs_um.iter().sum::<f64>() / map.nx() as f64,
        map.ys_um.iter().sum::<f64>() / map.ny() as f64,
    );
    let all = |_: usize, _: usize| true;
    let (fx, fy) = (
        plane_fit(map, 0, centre, &all),
        plane_fit(map, 1, centre, &all),
    );
    let (Some((px, ix, vx)), Some((py, iy, vy))) = (fx, fy) else {
        let none = Slope {
            value: f64::NAN,
            sigma: f64::INFINITY,
        };
        let flat = Plane {
            offset_um: 0.0,
            dx: 0.0,
            dy: 0.0,
            xc_um: centre.0,
            yc_um: centre.1,
        };
        return Geometry {
            scale_x_ppm: none,
            scale_y_ppm: none,
            out_of_squareness_urad: none,
            frame_rotation_urad: none,
            dex_dy_instrument_urad: none,
            planes: [flat, flat],
        };
    };
    let value = slopes(&px, &py);
    // Least-squares σ of each slope (the two components independent).
    let ls = [
        (vx * ix[1][1]).sqrt(),
        (vy * iy[2][2]).sqrt(),
        (vx * ix[2][2] + vy * iy[1][1]).sqrt(),
        (vy * iy[1][1]).sqrt(),
        (vx * ix[2][2]).sqrt(),
    ];
    let by_col = jackknife(map, centre, map.nx(), &|l, ix, _| ix == l);
    let by_row = jackknife(map, centre, map.ny(), &|l, _, iy| iy == l);
    let s = |k: usize| Slope {
        value: value[k],
        sigma: ls[k].max(by_col[k]).max(by_row[k]),
    };
    let plane = |p: &[f64; 3]| Plane {
        offset_um: p[0],
        dx: p[1],
        dy: p[2],
        xc_um: centre.0,
        yc_um: centre.1,
    };
    Geometry {
        scale_x_ppm: s(0),
        scale_y_ppm: s(1),
        out_of_squareness_urad: s(2),
        frame_rotation_urad: s(3),
        dex_dy_instrument_urad: s(4),
        planes: [plane(&px), plane(&py)],
    }
}
