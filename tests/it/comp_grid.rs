//! The 2-D compensation map (`comp::grid`) on the real grid map in
//! `../shared/reference/real-2d-grids/` (skipped with a message when the
//! directory is absent), judged on nodes it was not built from: the map is
//! built from one fold of the lattice (checkerboard, alternate rows,
//! alternate columns), and its prediction at the other nodes is compared
//! with what the laser measured there. Beside it, the separable f(x) + g(y)
//! a paper-style table holds, fitted to the same fold, and the measured
//! noise floor: the map must do clearly better than the raw error and no
//! worse than the separable fit (the map holds the joint x–y structure the
//! separable fit cannot).
//!
//! Also: a grid file's round trip through TOML, and compensated commands
//! through the inverse that put the stage model's prediction on target.

use std::path::PathBuf;

use micropos::analysis::grid::GridMap;
use micropos::charact::log::read_file;
use micropos::comp::{CompFile, GridTable, MotionHistory, PlanOptions, SourceInfo};
use micropos::model::{MotionState, XyUm};

fn map() -> Option<GridMap> {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/reference/real-2d-grids/aerotech_planarhd_cz1.csv");
    if !p.exists() {
        eprintln!("skipped: {} not found", p.display());
        return None;
    }
    let log = read_file(&p).unwrap();
    Some(GridMap::from_log(&log, [true, true]).expect("a grid map"))
}

/// Rms over `v`.
fn rms(v: &[f64]) -> f64 {
    (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt()
}

/// f(x) + g(y) fitted by alternating means to the training nodes of one
/// component (`e[iy·nx + ix]`, `None` where held out), evaluated at
/// every node.
fn separable(e: &[Option<f64>], nx: usize, ny: usize) -> Vec<f64> {
    let mut f = vec![0.0; nx];
    let mut g = vec![0.0; ny];
    for _ in 0..200 {
        for (ix, fx) in f.iter_mut().enumerate() {
            let v: Vec<f64> = (0..ny)
                .filter_map(|iy| e[iy * nx + ix].map(|v| v - g[iy]))
                .collect();
            *fx = v.iter().sum::<f64>() / v.len().max(1) as f64;
        }
        for (iy, gy) in g.iter_mut().enumerate() {
            let v: Vec<f64> = (0..nx)
                .filter_map(|ix| e[iy * nx + ix].map(|v| v - f[ix]))
                .collect();
            *gy = v.iter().sum::<f64>() / v.len().max(1) as f64;
        }
    }
    // A column or row with no training node (alternate-line folds): the
    // mean of its neighbours, as the map's fill does.
    let has_x: Vec<bool> = (0..nx)
        .map(|ix| (0..ny).any(|iy| e[iy * nx + ix].is_some()))
        .collect();
    let has_y: Vec<bool> = (0..ny)
        .map(|iy| (0..nx).any(|ix| e[iy * nx + ix].is_some()))
        .collect();
    fill_line(&mut f, &has_x);
    fill_line(&mut g, &has_y);
    (0..nx * ny).map(|k| f[k % nx] + g[k / nx]).collect()
}

/// Replaces each entry without data by the mean of its neighbours that
/// have data.
fn fill_line(v: &mut [f64], known: &[bool]) {
    for i in 0..v.len() {
        if known[i] {
            continue;
        }
        let n: Vec<f64> = [i.wrapping_sub(1), i + 1]
            .into_iter()
            .filter(|&j| j < v.len() && known[j])
            .map(|j| v[j])
            .collect();
        v[i] = n.iter().sum::<f64>() / n.len().max(1) as f64;
    }
}

#[test]
fn the_map_predicts_held_out_nodes_of_the_shared_grid() {
    let Some(map) = map() else { return };
    let (nx, ny) = (map.nx(), map.ny());
    type Fold = fn(usize, usize) -> bool;
    let folds: [(&str, Fold); 3] = [
        ("checkerboard", |ix, iy| (ix + iy) % 2 == 1),
        ("alternate rows", |_, iy| iy % 2 == 1),
        ("alternate columns", |ix, _| ix % 2 == 1),
    ];
    for (name, held_out) in folds {
        let mut train: Vec<Option<[f64; 2]>> = Vec::new();
        for iy in 0..ny {
            for ix in 0..nx {
                let inner = ix > 0 && iy > 0 && ix + 1 < nx && iy + 1 < ny;
                // Held-out nodes on the rim would test extrapolation, not the map.
                let out = inner && held_out(ix, iy);
                train.push(if out {
                    None
                } else {
                    map.cell(ix, iy).map(|c| c.e_um)
                });
            }
        }
        let (table, report) = GridTable::from_lattice(&map.xs_um, &map.ys_um, &train).unwrap();
        assert_eq!(report.nodes, [nx, ny]);
        for c in 0..2 {
            let field: Vec<Option<f64>> = train.iter().map(|t| t.map(|t| t[c])).collect();
            let sep = separable(&field, nx, ny);
            let (mut raw, mut by_map, mut by_sep) = (Vec::new(), Vec::new(), Vec::new());
            for iy in 0..ny {
                for ix in 0..nx {
                    let k = iy * nx + ix;
                    if train[k].is_some() {
                        continue;
                    }
                    let Some(cell) = map.cell(ix, iy) else {
                        continue;
                    };
                    let truth = cell.e_um[c];
                    // The table holds e = target − measured: −(measured − target).
                    let predicted = -table.error_at_um(map.xs_um[ix], map.ys_um[iy])[c];
                    raw.push(truth);
                    by_map.push(truth - predicted);
                    by_sep.push(truth - sep[k]);
                }
            }
            let (r, m, s) = (rms(&raw), rms(&by_map), rms(&by_sep));
            eprintln!(
                "GRID-TABLE | {name} | {} | held out {} | raw {r:.3} µm | map {m:.3} µm | separable {s:.3} µm |",
                ["x", "y"][c],
                raw.len()
            );
            assert!(m < 0.25 * r, "{name} {c}: the map leaves {m} of {r} µm");
            assert!(
                m <= 1.05 * s,
                "{name} {c}: the map {m} µm, separable {s} µm"
            );
        }
    }
}

/// A table built from a smooth non-separable field: the file reads back
/// identical, the compensator's prediction at a node is −e there, and the
/// inverse finds commands whose predicted position is the target.
#[test]
fn a_grid_file_round_trips_and_its_inverse_lands_on_target() {
    let xs: Vec<f64> = (0..9).map(|i| 1000.0 + 500.0 * i as f64).collect();
    let ys: Vec<f64> = (0..7).map(|i| 2000.0 + 400.0 * i as f64).collect();
    let f = |x: f64, y: f64| {
        [
            0.8 * ((x - 1000.0) / 900.0).sin() + 3e-7 * (x - 3000.0) * (y - 3000.0),
            -0.5 + 2e-4 * (x - 1000.0) - 4e-7 * (x - 3000.0) * (y - 3200.0),
        ]
    };
    let mut offsets = Vec::new();
    for y in &ys {
        for x in &xs {
            offsets.push(Some(f(*x, *y)));
        }
    }
    offsets[10] = None;
    let (table, report) = GridTable::from_lattice(&xs, &ys, &offsets).unwrap();
    assert_eq!((report.measured, report.filled), (62, 1));
    let file = CompFile::grid(table, "2026-11-28T00:00:00Z", SourceInfo::default());
    let text = file.to_toml().unwrap();
    let back = CompFile::from_toml(&text).unwrap();
    assert_eq!(back, file);
    let comp = back.compensator().unwrap();
    assert_eq!(comp.kind(), "grid");
    let area = comp.characterized_area().unwrap();
    assert_eq!((area.x_um, area.y_um), ([1000.0, 5000.0], [2000.0, 4400.0]));
    let at = |x: f64, y: f64| MotionState::at_rest(x, y);
    let p = comp.predicted_offset_um(&at(xs[3], ys[2])).unwrap();
    let want = f(xs[3], ys[2]);
    assert!((p[0] - want[0]).abs() < 1e-12 && (p[1] - want[1]).abs() < 1e-12);

    let history = MotionHistory::new(at(3000.0, 3000.0), 0.0).unwrap();
    for target in [(1250.0, 2100.0), (4321.0, 3999.0), (3000.0, 3000.0)] {
        let target = XyUm {
            x_um: target.0,
            y_um: target.1,
        };
        let plan = comp
            .command_for(target, &history, &PlanOptions::default())
            .unwrap();
        let o = comp
            .predicted_offset_um(&at(plan.cmd.x_um, plan.cmd.y_um))
            .unwrap();
        let landed = [plan.cmd.x_um + o[0], plan.cmd.y_um + o[1]];
        assert!(
            (landed[0] - target.x_um).abs() < 1e-5 && (landed[1] - target.y_um).abs() < 1e-5,
            "{target:?} → {landed:?}"
        );
    }
}
