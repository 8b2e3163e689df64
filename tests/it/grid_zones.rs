//! Overlapping grid zones combined (`analysis::grid::zones`,
//! `micropos combine`): the real map of `../shared/reference/real-2d-grids/`
//! cut into three overlapping zones, each read through a known set-up
//! with fresh noise, must give back the set-ups and the map; two
//! synthetic zone logs through the binary must give one log `diagnose`
//! reads as a grid.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use micropos::analysis::grid::zones::combined_log;
use micropos::analysis::grid::{combine_zones, GridMap, Zone, ZoneOptions};
use micropos::charact::log::{parse_bytes, read_file, Metadata, Record};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

fn real_path() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/reference/real-2d-grids/aerotech_planarhd_cz1.csv")
}

/// A set-up: offsets at a pivot and the cross slopes (µrad).
#[derive(Debug, Clone, Copy)]
struct SetUp {
    pivot_um: [f64; 2],
    offset_um: [f64; 2],
    a_urad: f64,
    b_urad: f64,
}

impl SetUp {
    fn at(&self, x: f64, y: f64) -> [f64; 2] {
        [
            self.offset_um[0] + 1e-6 * self.a_urad * (y - self.pivot_um[1]),
            self.offset_um[1] + 1e-6 * self.b_urad * (x - self.pivot_um[0]),
        ]
    }
}

/// The records of columns `ix` and rows `iy` of the lattice, read through
/// `s` with fresh noise of `noise_um` (a re-set-up instrument reads the
/// same stage with its own zero, mirrors and noise).
fn sub_zone(
    records: &[Record],
    map: &GridMap,
    ix: std::ops::RangeInclusive<usize>,
    iy: std::ops::RangeInclusive<usize>,
    s: &SetUp,
    noise_um: f64,
    rng: &mut ChaCha8Rng,
) -> GridMap {
    let noise = Normal::new(0.0, noise_um).unwrap();
    let inside = |v: f64, xs: &[f64], r: &std::ops::RangeInclusive<usize>| {
        v >= xs[*r.start()] - 1.0 && v <= xs[*r.end()] + 1.0
    };
    let recs: Vec<Record> = records
        .iter()
        .filter(|r| {
            inside(r.x_target_um, &map.xs_um, &ix) && inside(r.y_target_um, &map.ys_um, &iy)
        })
        .map(|r| {
            let mut r = r.clone();
            let u = s.at(r.x_target_um, r.y_target_um);
            r.x_meas_um += u[0] + noise.sample(rng);
            r.y_meas_um += u[1] + noise.sample(rng);
            r
        })
        .collect();
    GridMap::from_records(&recs, [true, true]).expect("a sub-zone is a grid")
}

#[test]
fn the_real_map_cut_into_zones_gives_back_their_setups_and_itself() {
    let p = real_path();
    if !p.exists() {
        eprintln!("skipped: {} not found", p.display());
        return;
    }
    let log = read_file(&p).unwrap();
    let whole = GridMap::from_log(&log, [true, true]).unwrap();
    assert_eq!((whole.nx(), whole.ny()), (36, 36));
    let mut rng = ChaCha8Rng::seed_from_u64(2025);
    let noise_um = 0.02;
    let centre = |m: &GridMap| {
        [
            0.5 * (m.xs_um[0] + m.xs_um[m.nx() - 1]),
            0.5 * (m.ys_um[0] + m.ys_um[m.ny() - 1]),
        ]
    };
    // Set-ups of a few µm and tens to hundreds of µrad, pivots anywhere.
    let setups = [
        SetUp {
            pivot_um: [-2e5, -1e5],
            offset_um: [0.3, -0.4],
            a_urad: 30.0,
            b_urad: -20.0,
        },
        SetUp {
            pivot_um: [5e4, -2.4e5],
            offset_um: [1.5, -0.8],
            a_urad: 120.0,
            b_urad: -75.0,
        },
        SetUp {
            pivot_um: [0.0, 0.0],
            offset_um: [-2.2, 0.6],
            a_urad: -40.0,
            b_urad: 210.0,
        },
    ];
    let places = [(0..=19, 0..=19), (15..=35, 0..=21), (6..=29, 17..=35)];
    let zones: Vec<Zone> = places
        .iter()
        .zip(&setups)
        .enumerate()
        .map(|(k, ((ix, iy), s))| Zone {
            name: format!("zone {}", k + 1),
            map: sub_zone(
                &log.records,
                &whole,
                ix.clone(),
                iy.clone(),
                s,
                noise_um,
                &mut rng,
            ),
        })
        .collect();
    let comb = combine_zones(&zones, &ZoneOptions::default()).unwrap();
    let mut text = String::new();
    micropos::analysis::grid::zones::write_text(&mut text, &comb);
    eprintln!("{text}");
    // The set-ups, relative to zone 1's, at each zone's centre.
    let r = setups[0];
    for k in 1..3 {
        let s = &comb.setups[k];
        let c = centre(&zones[k].map);
        assert_eq!(s.centre_um, c);
        let (sk, sr) = (setups[k].at(c[0], c[1]), r.at(c[0], c[1]));
        let truth = [
            sk[0] - sr[0],
            sk[1] - sr[1],
            setups[k].a_urad - r.a_urad,
            setups[k].b_urad - r.b_urad,
        ];
        let fitted = [s.offset_x_um, s.offset_y_um, s.dex_dy_urad, s.dey_dx_urad];
        for (name, (f, t)) in ["ox", "oy", "a", "b"].iter().zip(fitted.iter().zip(truth)) {
            let z = (f.value - t) / f.sigma;
            eprintln!(
                "zone {}: {name} fitted {:+.4} ± {:.4}, true {t:+.4}, z {z:+.2}",
                k + 1,
                f.value,
                f.sigma
            );
            assert!(z.abs() < 3.0, "zone {}: {name}: {f:?} vs {t}", k + 1);
        }
    }
    // The noise the overlaps see is the one added (the stage's own
    // readings cancel where zones share a node).
    for c in 0..2 {
        assert!(
            (comb.noise_um[c] / noise_um - 1.0).abs() < 0.15,
            "{:?}",
            comb.noise_um
        );
    }
    // The map: the original cells as zone 1's set-up reads them, to the
    // noise (each node σ); the corner no zone covered is empty.
    assert_eq!((comb.map.nx(), comb.map.ny()), (36, 36));
    let (mut z2, mut err2, mut n) = (0.0, 0.0, 0.0);
    for iy in 0..36 {
        for ix in 0..36 {
            let covered = places
                .iter()
                .any(|(px, py)| px.contains(&ix) && py.contains(&iy));
            let Some(cell) = comb.map.cell(ix, iy) else {
                assert!(!covered, "({ix}, {iy})");
                continue;
            };
            assert!(covered);
            let (x, y) = (whole.xs_um[ix], whole.ys_um[iy]);
            let orig = whole.cell(ix, iy).unwrap().e_um;
            let sigma = comb.node_sigma_um[iy * 36 + ix].unwrap();
            for c in 0..2 {
                let err = cell.e_um[c] - orig[c] - r.at(x, y)[c];
                z2 += (err / sigma[c]).powi(2);
                err2 += err * err;
                n += 1.0;
            }
        }
    }
    let (z_rms, rms) = ((z2 / n).sqrt(), (err2 / n).sqrt());
    eprintln!(
        "combined − original: rms {rms:.4} µm ({:.2} × the noise), rms / node σ {z_rms:.3}",
        rms / noise_um
    );
    assert!((0.75..1.25).contains(&z_rms), "{z_rms}");
    assert!(rms < 1.5 * noise_um, "{rms}");
    // Its log reads back as the same lattice, a grid the diagnosis takes.
    let bytes = combined_log(&comb, &Metadata::new()).unwrap();
    let back = GridMap::from_log(&parse_bytes(&bytes).unwrap(), [true, true]).unwrap();
    assert_eq!(back.xs_um, comb.map.xs_um);
    assert_eq!(back.filled(), comb.map.filled());
}

fn micropos() -> Command {
    Command::new(env!("CARGO_BIN_EXE_micropos"))
}

/// A zone log: columns `i`, rows `j` of a 5 mm lattice, a stage with a
/// joint x–y error read through `s`, noise 0.01 µm.
fn zone_log(path: &Path, i: std::ops::Range<i32>, j: std::ops::Range<i32>, s: &SetUp, seed: u64) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let noise = Normal::new(0.0, 0.01).unwrap();
    let mut t = String::from("# format: micropos-measurement-log/1\n# measured_axes: x,y\n");
    let _ = writeln!(t, "# source: zone {seed}");
    t.push_str("t_s,segment,cycle,x_target_um,y_target_um,x_cmd_um,y_cmd_um,x_meas_um,y_meas_um\n");
    let mut k = 0;
    for jy in j {
        for ix in i.clone() {
            let (x, y) = (5000.0 * f64::from(ix), 5000.0 * f64::from(jy));
            let e = [
                2e-6 * x + 0.2 * (x / 9000.0).sin() * (y / 7000.0).cos(),
                -1e-6 * y + 5e-6 * x + 0.1 * (y / 11000.0).sin(),
            ];
            let u = s.at(x, y);
            let mx = x + e[0] + u[0] + noise.sample(&mut rng);
            let my = y + e[1] + u[1] + noise.sample(&mut rng);
            let _ = writeln!(t, "{k},grid,1,{x},{y},{x},{y},{mx:.5},{my:.5}");
            k += 1;
        }
    }
    std::fs::write(path, t).unwrap();
}

fn combine(dir: &Path, zones: &[&str], out: &str, extra: &[&str]) -> Output {
    micropos()
        .arg("combine")
        .args(zones.iter().map(|z| dir.join(z)))
        .arg("--out")
        .arg(dir.join(out))
        .args(extra)
        .output()
        .unwrap()
}

#[test]
fn combine_writes_one_log_that_diagnoses_as_a_grid() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let flat = SetUp {
        pivot_um: [0.0, 0.0],
        offset_um: [0.0, 0.0],
        a_urad: 0.0,
        b_urad: 0.0,
    };
    let turned = SetUp {
        pivot_um: [4e4, 2e4],
        offset_um: [2.5, -1.0],
        a_urad: -300.0,
        b_urad: 250.0,
    };
    zone_log(&d.join("a.csv"), 0..10, 0..8, &flat, 1);
    zone_log(&d.join("b.csv"), 6..16, 0..8, &turned, 2);
    zone_log(&d.join("far.csv"), 30..36, 0..8, &flat, 3);
    let o = combine(d, &["a.csv", "b.csv"], "ab.csv", &[]);
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "{}{stdout}",
        String::from_utf8_lossy(&o.stderr)
    );
    eprintln!("{stdout}");
    assert!(stdout.contains("a.csv (reference)"), "{stdout}");
    assert!(
        stdout.contains("combined map: 16 × 8 nodes, 128 measured (32 by more than one zone)"),
        "{stdout}"
    );
    // b's set-up as logged, recovered (its centre (52.5 mm, 17.5 mm)).
    let log = read_file(d.join("ab.csv")).unwrap();
    assert_eq!(log.records.len(), 128);
    assert_eq!(log.metadata.get("zones"), Some("a.csv ; b.csv"));
    assert_eq!(log.metadata.get("zone_2_source"), Some("zone 2"));
    let b = log.metadata.get("zone_2").unwrap();
    assert!(
        b.starts_with("name=b.csv; centre_um=(52500.000, 17500.000)"),
        "{b}"
    );
    let want_ox = 2.5 - 300e-6 * (17_500.0 - 2e4);
    let ox: f64 = b
        .split("offset_x=")
        .nth(1)
        .and_then(|v| v.split('±').next())
        .unwrap()
        .parse()
        .unwrap();
    assert!((ox - want_ox).abs() < 0.01, "{b}");
    // The daemon's `tables build` path: its lattice, a 2-D table.
    let map = GridMap::from_records(&log.records, [true, true]).unwrap();
    let offsets: Vec<Option<[f64; 2]>> = map.cells.iter().map(|c| c.map(|c| c.e_um)).collect();
    let (_, report) =
        micropos::comp::GridTable::from_lattice(&map.xs_um, &map.ys_um, &offsets).unwrap();
    assert_eq!(report.measured, 128);
    // diagnose reads it as a 16 × 8 map.
    let o = micropos()
        .args(["diagnose", d.join("ab.csv").to_str().unwrap(), "--json"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let j: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(j["grid"]["columns"], 16, "{}", j["grid"]);
    assert_eq!(j["grid"]["rows"], 8);
    assert_eq!(j["measured_axes"], serde_json::json!(["x", "y"]));
    // Not overwritten; a zone that overlaps nothing is named; a wrong
    // reference is refused.
    let o = combine(d, &["a.csv", "b.csv"], "ab.csv", &[]);
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("exists"));
    let o = combine(
        d,
        &["a.csv", "b.csv", "far.csv"],
        "abf.csv",
        &["--reference", "2"],
    );
    assert_eq!(o.status.code(), Some(1));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("zone far.csv does not overlap the reference zone b.csv"),
        "{err}"
    );
    assert!(!d.join("abf.csv").exists());
    let o = combine(d, &["a.csv", "b.csv"], "x.csv", &["--reference", "3"]);
    assert_eq!(o.status.code(), Some(1));
}

/// Zones of the real map whose nodes interleave (one takes the even
/// columns, the other the odd ones; then rows, too): no node is shared, so
/// every difference interpolates the other zone, and the real stage's
/// curvature between its nodes (20 mm apart) enters the residuals. The
/// noise estimated from them grows with it, and the set-up is still found
/// within its σ.
#[test]
fn interleaved_zones_of_the_real_map_are_fitted_through_the_interpolation() {
    let p = real_path();
    if !p.exists() {
        eprintln!("skipped: {} not found", p.display());
        return;
    }
    let log = read_file(&p).unwrap();
    let whole = GridMap::from_log(&log, [true, true]).unwrap();
    let s = SetUp {
        pivot_um: [-5e4, -5e4],
        offset_um: [1.0, -2.0],
        a_urad: 80.0,
        b_urad: -60.0,
    };
    for rows_too in [false, true] {
        let pick = |r: &Record, cols: std::ops::RangeInclusive<usize>, odd: bool| {
            let (ix, iy) = whole.index_of(r.x_target_um, r.y_target_um);
            let parity = usize::from(odd);
            cols.contains(&ix) && ix % 2 == parity && (!rows_too || iy % 2 == parity)
        };
        let a: Vec<Record> = log
            .records
            .iter()
            .filter(|r| pick(r, 0..=23, false))
            .cloned()
            .collect();
        let b: Vec<Record> = log
            .records
            .iter()
            .filter(|r| pick(r, 12..=35, true))
            .map(|r| {
                let mut r = r.clone();
                let u = s.at(r.x_target_um, r.y_target_um);
                r.x_meas_um += u[0];
                r.y_meas_um += u[1];
                r
            })
            .collect();
        let zones = [
            Zone {
                name: "even".into(),
                map: GridMap::from_records(&a, [true, true]).unwrap(),
            },
            Zone {
                name: "odd".into(),
                map: GridMap::from_records(&b, [true, true]).unwrap(),
            },
        ];
        let comb = combine_zones(&zones, &ZoneOptions::default()).unwrap();
        let st = &comb.setups[1];
        let u = s.at(st.centre_um[0], st.centre_um[1]);
        let truth = [u[0], u[1], s.a_urad, s.b_urad];
        let fitted = [
            st.offset_x_um,
            st.offset_y_um,
            st.dex_dy_urad,
            st.dey_dx_urad,
        ];
        for (name, (f, t)) in ["ox", "oy", "a", "b"].iter().zip(fitted.iter().zip(truth)) {
            let z = (f.value - t) / f.sigma;
            eprintln!(
                "interleaved (rows too: {rows_too}): {name} fitted {:+.4} ± {:.4}, true {t:+.4}, z {z:+.2}",
                f.value, f.sigma
            );
            assert!(z.abs() < 3.0, "{name}: {f:?} vs {t}");
        }
        eprintln!(
            "  noise from the overlaps: x {:.4} µm, y {:.4} µm",
            comb.noise_um[0], comb.noise_um[1]
        );
    }
}
