//! Random stages mapped zone by zone, each zone through its own random
//! set-up, against the set-ups and the stage the combination recovers;
//! bad input refused with its reason.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

use super::super::{Cell, GridMap};
use super::*;

/// A stage's error field (`e = measured − target`, µm): scales, a
/// squareness, separable waves and a non-separable Gaussian bump, every
/// parameter drawn with both signs.
struct Field {
    origin: [f64; 2],
    scale_ppm: [f64; 2],
    squareness_urad: f64,
    /// (component, along x?, amplitude µm, period µm, phase)
    waves: Vec<(usize, bool, f64, f64, f64)>,
    /// (component, x0, y0, width, amplitude µm)
    bump: (usize, f64, f64, f64, f64),
}

impl Field {
    fn at(&self, x: f64, y: f64) -> [f64; 2] {
        let (dx, dy) = (x - self.origin[0], y - self.origin[1]);
        let mut e = [
            1e-6 * (self.scale_ppm[0] * dx + self.squareness_urad * dy),
            1e-6 * self.scale_ppm[1] * dy,
        ];
        for &(c, along_x, a, p, ph) in &self.waves {
            let v = if along_x { x } else { y };
            e[c] += a * (std::f64::consts::TAU * v / p + ph).sin();
        }
        let (c, bx, by, w, a) = self.bump;
        e[c] += a * (-((x - bx).powi(2) + (y - by).powi(2)) / (2.0 * w * w)).exp();
        e
    }
}

/// A set-up as drawn: offsets at a pivot (the instrument's zero) and the
/// two cross slopes, independent.
#[derive(Debug, Clone, Copy)]
struct SetUp {
    pivot: [f64; 2],
    offset_um: [f64; 2],
    a_urad: f64,
    b_urad: f64,
}

impl SetUp {
    fn at(&self, x: f64, y: f64) -> [f64; 2] {
        [
            self.offset_um[0] + 1e-6 * self.a_urad * (y - self.pivot[1]),
            self.offset_um[1] + 1e-6 * self.b_urad * (x - self.pivot[0]),
        ]
    }
}

/// A zone on the common lattice: first column and row, columns, rows.
#[derive(Debug, Clone, Copy)]
struct Place {
    i0: i64,
    j0: i64,
    nx: i64,
    ny: i64,
}

/// One draw: the stage, the zones' places and set-ups, the noise.
struct Draw {
    field: Field,
    pitch: [f64; 2],
    places: Vec<Place>,
    setups: Vec<SetUp>,
    noise_um: f64,
    reference: usize,
}

fn sign(rng: &mut ChaCha8Rng) -> f64 {
    if rng.gen_bool(0.5) {
        1.0
    } else {
        -1.0
    }
}

impl Draw {
    fn new(rng: &mut ChaCha8Rng) -> Draw {
        let pitch = [rng.gen_range(20.0..10_000.0), rng.gen_range(20.0..10_000.0)];
        let zones = rng.gen_range(2..=4);
        let mut places: Vec<Place> = Vec::new();
        for k in 0..zones {
            let (nx, ny) = (rng.gen_range(6..=20), rng.gen_range(6..=20));
            let place = if k == 0 {
                Place {
                    i0: 0,
                    j0: 0,
                    nx,
                    ny,
                }
            } else {
                // Overlapping a zone drawn before by at least 3 columns and
                // 3 rows, anywhere around it (inside it, too).
                let p = places[rng.gen_range(0..k)];
                Place {
                    i0: p.i0 + rng.gen_range(-(nx - 3)..=p.nx - 3),
                    j0: p.j0 + rng.gen_range(-(ny - 3)..=p.ny - 3),
                    nx,
                    ny,
                }
            };
            places.push(place);
        }
        let noise_um = 10f64.powf(rng.gen_range(-2.5..-0.5));
        let field = Self::field(rng, pitch, &places, noise_um);
        let setups = places
            .iter()
            .map(|p| SetUp {
                pivot: [
                    (p.i0 as f64 + rng.gen_range(-5.0..25.0)) * pitch[0],
                    (p.j0 as f64 + rng.gen_range(-5.0..25.0)) * pitch[1],
                ],
                offset_um: [rng.gen_range(-5.0..5.0), rng.gen_range(-5.0..5.0)],
                a_urad: rng.gen_range(-500.0..500.0),
                b_urad: rng.gen_range(-500.0..500.0),
            })
            .collect();
        Draw {
            field,
            pitch,
            places,
            setups,
            noise_um,
            reference: rng.gen_range(0..zones),
        }
    }

    fn field(rng: &mut ChaCha8Rng, pitch: [f64; 2], places: &[Place], noise: f64) -> Field {
        let span = |a: usize| {
            let (lo, hi) = places.iter().fold((i64::MAX, i64::MIN), |(l, h), p| {
                let (s, n) = if a == 0 { (p.i0, p.nx) } else { (p.j0, p.ny) };
                (l.min(s), h.max(s + n))
            });
            (hi - lo) as f64 * pitch[a]
        };
        let mut waves = Vec::new();
        for c in 0..2 {
            for along_x in [true, false] {
                waves.push((
                    c,
                    along_x,
                    rng.gen_range(-50.0..50.0) * noise,
                    span(usize::from(!along_x)) * rng.gen_range(0.2..2.0),
                    rng.gen_range(0.0..std::f64::consts::TAU),
                ));
            }
        }
        let p = places[0];
        Field {
            origin: [rng.gen_range(-1e5..1e5), rng.gen_range(-1e5..1e5)],
            scale_ppm: [rng.gen_range(-50.0..50.0), rng.gen_range(-50.0..50.0)],
            squareness_urad: rng.gen_range(-300.0..300.0),
            waves,
            bump: (
                rng.gen_range(0..2),
                (p.i0 as f64 + rng.gen_range(0.0..p.nx as f64)) * pitch[0],
                (p.j0 as f64 + rng.gen_range(0.0..p.ny as f64)) * pitch[1],
                rng.gen_range(1.5..4.0) * pitch[0].min(pitch[1]),
                sign(rng) * rng.gen_range(5.0..50.0) * noise,
            ),
        }
    }

    /// The zones' maps: the stage through each set-up, with noise; a few
    /// cells left unmeasured.
    fn zones(&self, rng: &mut ChaCha8Rng) -> Vec<Zone> {
        let noise = Normal::new(0.0, self.noise_um).unwrap();
        self.places
            .iter()
            .zip(&self.setups)
            .enumerate()
            .map(|(k, (p, s))| {
                let xs: Vec<f64> = (0..p.nx)
                    .map(|i| (p.i0 + i) as f64 * self.pitch[0])
                    .collect();
                let ys: Vec<f64> = (0..p.ny)
                    .map(|j| (p.j0 + j) as f64 * self.pitch[1])
                    .collect();
                let mut cells = Vec::new();
                for &y in &ys {
                    for &x in &xs {
                        let (e, u) = (self.field.at(x, y), s.at(x, y));
                        let v = [
                            e[0] + u[0] + noise.sample(rng),
                            e[1] + u[1] + noise.sample(rng),
                        ];
                        cells.push((!rng.gen_bool(0.03)).then_some(Cell {
                            e_um: v,
                            visits: 1,
                            ss_um2: [0.0; 2],
                        }));
                    }
                }
                Zone {
                    name: format!("zone{k}"),
                    map: GridMap {
                        xs_um: xs,
                        ys_um: ys,
                        cells,
                    },
                }
            })
            .collect()
    }

    /// Zone `k`'s set-up minus the reference's at zone `k`'s centre:
    /// `[offset x, offset y, a, b]`, what the fit should give.
    fn relative(&self, k: usize, centre: [f64; 2]) -> [f64; 4] {
        let (s, r) = (self.setups[k], self.setups[self.reference]);
        let (sk, sr) = (s.at(centre[0], centre[1]), r.at(centre[0], centre[1]));
        [
            sk[0] - sr[0],
            sk[1] - sr[1],
            s.a_urad - r.a_urad,
            s.b_urad - r.b_urad,
        ]
    }
}

/// What the random draws measured.
#[derive(Default)]
struct Tally {
    z: Vec<f64>,
    worst: f64,
    noise_ratio2_dof: f64,
    dof: f64,
    /// Σ ((map − truth) / noise)², Σ ((map − truth) / node σ)², values.
    map_err2: f64,
    map_z2: f64,
    map_nodes: usize,
    /// Per draw, the map's rms error over the noise.
    map_rms: Vec<f64>,
    draws: usize,
}

/// Combines one draw and checks it; adds what it measured to `t`.
fn check_draw(case: u64, rng: &mut ChaCha8Rng, t: &mut Tally) {
    let d = Draw::new(rng);
    let zones = d.zones(rng);
    let opts = ZoneOptions {
        reference: d.reference,
        ..ZoneOptions::default()
    };
    let comb = combine_zones(&zones, &opts).unwrap_or_else(|e| panic!("case {case}: {e}"));
    for (k, s) in comb.setups.iter().enumerate() {
        assert_eq!(s.reference, k == d.reference);
        if k == d.reference {
            continue;
        }
        let truth = d.relative(k, s.centre_um);
        let fitted = [s.offset_x_um, s.offset_y_um, s.dex_dy_urad, s.dey_dx_urad];
        for (f, tr) in fitted.iter().zip(truth) {
            let z = (f.value - tr) / (f.sigma + 1e-9 * (1.0 + tr.abs()));
            assert!(z.is_finite(), "case {case}: {s:?}");
            t.worst = t.worst.max(z.abs());
            t.z.push(z);
        }
    }
    for c in 0..2 {
        t.noise_ratio2_dof += comb.dof[c] * (comb.noise_um[c] / d.noise_um).powi(2);
        t.dof += comb.dof[c];
    }
    // The map is the stage as the reference set-up reads it.
    let r = d.setups[d.reference];
    let m = &comb.map;
    let (mut err2, mut nodes) = (0.0, 0);
    for iy in 0..m.ny() {
        for ix in 0..m.nx() {
            if let Some(cell) = m.cell(ix, iy) {
                let (x, y) = (m.xs_um[ix], m.ys_um[iy]);
                let (e, s) = (d.field.at(x, y), r.at(x, y));
                let sigma = comb.node_sigma_um[iy * m.nx() + ix].expect("a σ per node");
                for c in 0..2 {
                    let err = cell.e_um[c] - e[c] - s[c];
                    err2 += (err / d.noise_um).powi(2);
                    t.map_z2 += (err / sigma[c]).powi(2);
                }
                nodes += 2;
            }
        }
    }
    t.map_err2 += err2;
    t.map_nodes += nodes;
    t.map_rms.push((err2 / nodes as f64).sqrt());
    let filled: usize = zones.iter().map(|z| z.map.filled()).sum();
    assert_eq!(comb.zones_per_node.iter().sum::<usize>(), filled);
    // A map the compensation table takes.
    let offsets: Vec<Option<[f64; 2]>> = m.cells.iter().map(|c| c.map(|c| c.e_um)).collect();
    crate::comp::GridTable::from_lattice(&m.xs_um, &m.ys_um, &offsets)
        .unwrap_or_else(|e| panic!("case {case}: {e}"));
    t.draws += 1;
}

fn run_draws(seed: u64, draws: u64) -> Tally {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut t = Tally::default();
    for case in 0..draws {
        check_draw(case, &mut rng, &mut t);
    }
    t
}

/// Checks a tally: the set-ups within 3σ (at most 2 % of the parameters
/// outside, none beyond 5σ), σ of the right size (the z's RMS near 1), the
/// noise estimated to its statistics, the map at the noise.
fn judge(seed: u64, t: &Tally) {
    let n = t.z.len() as f64;
    let outside = t.z.iter().filter(|z| z.abs() > 3.0).count();
    let z_rms = (t.z.iter().map(|z| z * z).sum::<f64>() / n).sqrt();
    let noise_ratio = (t.noise_ratio2_dof / t.dof).sqrt();
    let map_rms = (t.map_err2 / t.map_nodes as f64).sqrt();
    let map_z = (t.map_z2 / t.map_nodes as f64).sqrt();
    let mut per_draw = t.map_rms.clone();
    per_draw.sort_by(f64::total_cmp);
    let median = per_draw[per_draw.len() / 2];
    let worst_draw = per_draw[per_draw.len() - 1];
    eprintln!(
        "seed {seed}: {} draws, {} set-up parameters: worst |fitted − true|/σ {:.2}, \
         {outside} beyond 3σ, rms z {z_rms:.3}; noise estimated / true {noise_ratio:.3}; \
         combined map − truth: rms {map_rms:.3} × the noise (per draw median {median:.3}, \
         worst {worst_draw:.3}), rms of (map − truth) / node σ {map_z:.3}",
        t.draws,
        t.z.len(),
        t.worst
    );
    assert!(t.worst < 5.0, "seed {seed}: worst {}", t.worst);
    assert!(outside as f64 <= 0.02 * n, "seed {seed}: {outside} of {n}");
    assert!((0.8..1.2).contains(&z_rms), "seed {seed}: rms z {z_rms}");
    assert!(
        (0.9..1.1).contains(&noise_ratio),
        "seed {seed}: {noise_ratio}"
    );
    // Each node averages one or more readings, and the set-ups' own
    // errors add where a zone reaches far beyond a narrow overlap: the
    // typical draw's map is at the noise, and every node within its σ.
    assert!(median < 1.25, "seed {seed}: median {median}");
    assert!((0.85..1.15).contains(&map_z), "seed {seed}: {map_z}");
}

#[test]
fn random_stages_give_back_their_setups_within_sigma_and_the_map_at_the_noise() {
    let seed = 31;
    judge(seed, &run_draws(seed, 40));
}

#[test]
fn random_stages_on_seeds_the_code_was_not_developed_on() {
    // These seeds were added after the fit and the bounds above were
    // settled, and run once: not tuned on.
    for seed in [2718, 161_803] {
        judge(seed, &run_draws(seed, 25));
    }
}

/// A zone on columns `i` and rows `j` of a 10 µm lattice, read as `f`.
fn zone(name: &str, i: std::ops::RangeInclusive<i32>, j: std::ops::RangeInclusive<i32>) -> Zone {
    zone_with(name, i, j, |x, y| {
        [1e-3 * x + 0.01 * (x * y).sin(), -2e-3 * y]
    })
}

fn zone_with(
    name: &str,
    i: std::ops::RangeInclusive<i32>,
    j: std::ops::RangeInclusive<i32>,
    f: impl Fn(f64, f64) -> [f64; 2],
) -> Zone {
    let xs: Vec<f64> = i.map(|i| 10.0 * f64::from(i)).collect();
    let ys: Vec<f64> = j.map(|j| 10.0 * f64::from(j)).collect();
    let mut cells = Vec::new();
    for &y in &ys {
        for &x in &xs {
            cells.push(Some(Cell {
                e_um: f(x, y),
                visits: 1,
                ss_um2: [0.0; 2],
            }));
        }
    }
    Zone {
        name: name.into(),
        map: GridMap {
            xs_um: xs,
            ys_um: ys,
            cells,
        },
    }
}

fn combine(zones: &[Zone]) -> Result<ZoneCombination, ZoneError> {
    combine_zones(zones, &ZoneOptions::default())
}

#[test]
fn zones_without_overlap_are_refused_naming_the_zone() {
    let e = combine(&[zone("a", 0..=5, 0..=5), zone("b", 8..=12, 0..=5)]).unwrap_err();
    assert!(
        matches!(&e, ZoneError::NotConnected { zone, .. } if zone == "b"),
        "{e}"
    );
    // Linked through b, c is fine; d overlaps nothing.
    let zs = [
        zone("a", 0..=5, 0..=5),
        zone("b", 3..=9, 2..=8),
        zone("c", 7..=12, 6..=12),
        zone("d", 20..=25, 0..=5),
    ];
    let e = combine(&zs).unwrap_err();
    assert_eq!(
        e.to_string(),
        "zone d does not overlap the reference zone a, directly or through other zones: no \
         node of it lies inside another zone's measured lattice"
    );
    assert!(combine(&zs[..3]).is_ok());
}

#[test]
fn a_single_shared_line_leaves_a_slope_free_and_says_which() {
    // One shared column (x = 50): nothing tells d(ey)/dx.
    let e = combine(&[zone("a", 0..=5, 0..=5), zone("b", 5..=10, 0..=5)]).unwrap_err();
    assert_eq!(
        e,
        ZoneError::Undetermined {
            zone: "b".into(),
            parameter: "d(ey)/dx slope",
            need: "nodes on at least two columns (distinct x)",
        }
    );
    assert!(e.to_string().contains("a single shared line"), "{e}");
    // One shared row: d(ex)/dy; named in a chain, too (c hangs on b).
    let zs = [
        zone("a", 0..=5, 0..=5),
        zone("b", 3..=8, 3..=8),
        zone("c", 3..=8, 8..=12),
    ];
    let e = combine(&zs).unwrap_err();
    assert!(
        matches!(&e, ZoneError::Undetermined { zone, parameter: "d(ex)/dy slope", .. } if zone == "c"),
        "{e}"
    );
    // Two shared lines determine both.
    assert!(combine(&[zone("a", 0..=5, 0..=5), zone("b", 4..=9, 0..=5)]).is_ok());
}

#[test]
fn an_overlap_without_a_spare_difference_is_too_little() {
    // Two diagonal nodes: four parameters, no degree of freedom for the
    // noise.
    let mut b = zone("b", 4..=9, 4..=9);
    for (ix, iy) in [(1, 0), (0, 1)] {
        b.map.cells[iy * 6 + ix] = None;
    }
    let e = combine(&[zone("a", 0..=5, 0..=5), b]).unwrap_err();
    assert!(
        matches!(e, ZoneError::TooLittleOverlap { parameters: 2, .. }),
        "{e}"
    );
}

#[test]
fn non_finite_and_malformed_zones_are_refused() {
    let mut b = zone("b", 3..=8, 0..=5);
    b.map.cells[7] = Some(Cell {
        e_um: [f64::NAN, 0.0],
        visits: 1,
        ss_um2: [0.0; 2],
    });
    let e = combine(&[zone("a", 0..=5, 0..=5), b]).unwrap_err();
    assert_eq!(
        e.to_string(),
        "zone b: a measured node has a non-finite error"
    );
    let mut b = zone("b", 3..=8, 0..=5);
    b.map.xs_um[2] = f64::INFINITY;
    let e = combine(&[zone("a", 0..=5, 0..=5), b]).unwrap_err();
    assert!(
        matches!(&e, ZoneError::Malformed { zone, .. } if zone == "b"),
        "{e}"
    );
    let mut b = zone("b", 3..=8, 0..=5);
    b.map.cells.pop();
    assert!(matches!(
        combine(&[zone("a", 0..=5, 0..=5), b]),
        Err(ZoneError::Malformed { .. })
    ));
    let mut b = zone("b", 3..=8, 0..=5);
    b.map.cells.iter_mut().for_each(|c| *c = None);
    assert!(matches!(
        combine(&[zone("a", 0..=5, 0..=5), b]),
        Err(ZoneError::Malformed { .. })
    ));
    assert_eq!(
        combine(&[zone("a", 0..=5, 0..=5)]),
        Err(ZoneError::TooFewZones { zones: 1 })
    );
    let two = [zone("a", 0..=5, 0..=5), zone("b", 3..=8, 0..=5)];
    let opts = ZoneOptions {
        reference: 2,
        ..ZoneOptions::default()
    };
    assert!(matches!(
        combine_zones(&two, &opts),
        Err(ZoneError::BadReference { .. })
    ));
    let opts = ZoneOptions {
        node_tol_um: Some(f64::NAN),
        ..ZoneOptions::default()
    };
    assert!(matches!(
        combine_zones(&two, &opts),
        Err(ZoneError::BadTolerance { .. })
    ));
}

#[test]
fn noise_free_zones_give_back_their_setups_exactly_and_the_reference_frame() {
    let field = |x: f64, y: f64| {
        [
            0.3 * (x / 37.0).sin() * (y / 23.0).cos(),
            1e-3 * x * y / 50.0,
        ]
    };
    let set_up = |ox: f64, oy: f64, a: f64, b: f64| {
        move |x: f64, y: f64| {
            let e = field(x, y);
            [e[0] + ox + 1e-6 * a * y, e[1] + oy + 1e-6 * b * x]
        }
    };
    let zs = [
        zone_with("a", 0..=8, 0..=8, set_up(1.0, -1.0, 100.0, -50.0)),
        zone_with("b", 5..=14, 2..=9, set_up(-2.0, 3.0, -400.0, 300.0)),
        zone_with("c", 2..=9, 6..=15, set_up(0.5, 0.25, 250.0, 250.0)),
    ];
    let opts = ZoneOptions {
        reference: 1,
        ..ZoneOptions::default()
    };
    let comb = combine_zones(&zs, &opts).unwrap();
    let c = &comb.setups[2];
    // c minus b at c's centre (55, 105).
    let (ox, oy) = (
        0.5 + 250e-6 * 105.0 - (-2.0 - 400e-6 * 105.0),
        0.25 + 250e-6 * 55.0 - (3.0 + 300e-6 * 55.0),
    );
    let close = |a: f64, b: f64| (a - b).abs() < 1e-9;
    assert_eq!(c.centre_um, [55.0, 105.0]);
    assert!(close(c.offset_x_um.value, ox), "{c:?}");
    assert!(close(c.offset_y_um.value, oy), "{c:?}");
    assert!(close(c.dex_dy_urad.value, 650.0), "{c:?}");
    assert!(close(c.dey_dx_urad.value, -50.0), "{c:?}");
    assert!(
        comb.noise_um[0] < 1e-9 && comb.noise_um[1] < 1e-9,
        "{comb:?}"
    );
    assert_eq!((comb.map.nx(), comb.map.ny()), (15, 16));
    // Every measured node is the stage through b's set-up.
    for iy in 0..comb.map.ny() {
        for ix in 0..comb.map.nx() {
            let (x, y) = (comb.map.xs_um[ix], comb.map.ys_um[iy]);
            let want = set_up(-2.0, 3.0, -400.0, 300.0)(x, y);
            match comb.map.cell(ix, iy) {
                Some(cell) => {
                    assert!(close(cell.e_um[0], want[0]) && close(cell.e_um[1], want[1]))
                }
                None => assert!(!zs
                    .iter()
                    .any(|z| z.map.xs_um.contains(&x) && z.map.ys_um.contains(&y))),
            }
        }
    }
}

#[test]
fn interleaved_lattices_are_fitted_through_the_interpolation() {
    // b's nodes lie between a's (half a pitch off in x and y): every
    // difference interpolates; a smooth stage keeps the interpolation's
    // own error under the noise.
    let mut rng = ChaCha8Rng::seed_from_u64(77);
    let noise = Normal::new(0.0, 0.01).unwrap();
    let mut z = Vec::new();
    for _ in 0..40 {
        let truth = [
            rng.gen_range(-3.0..3.0),
            rng.gen_range(-3.0..3.0),
            rng.gen_range(-500.0..500.0),
            rng.gen_range(-500.0..500.0),
        ];
        let field = |x: f64, y: f64| {
            [
                2e-5 * x + 0.05 * (y / 900.0).sin(),
                1e-5 * y + 0.05 * (x / 700.0).cos(),
            ]
        };
        let a = zone_with("a", 0..=12, 0..=12, field);
        let b = zone_with("b", 6..=18, 4..=16, |x, y| {
            let e = field(x + 5.0, y + 5.0);
            let (cx, cy) = (10.0 * 12.0 + 5.0, 10.0 * 10.0 + 5.0);
            [
                e[0] + truth[0] + 1e-6 * truth[2] * (y + 5.0 - cy),
                e[1] + truth[1] + 1e-6 * truth[3] * (x + 5.0 - cx),
            ]
        });
        let mut b = b;
        b.map.xs_um.iter_mut().for_each(|x| *x += 5.0);
        b.map.ys_um.iter_mut().for_each(|y| *y += 5.0);
        let noisy = |mut zn: Zone, rng: &mut ChaCha8Rng| {
            for c in zn.map.cells.iter_mut().flatten() {
                c.e_um[0] += noise.sample(rng);
                c.e_um[1] += noise.sample(rng);
            }
            zn
        };
        let zs = [noisy(a, &mut rng), noisy(b, &mut rng)];
        let comb = combine(&zs).unwrap();
        let s = &comb.setups[1];
        assert_eq!(s.centre_um, [125.0, 105.0]);
        let fitted = [s.offset_x_um, s.offset_y_um, s.dex_dy_urad, s.dey_dx_urad];
        z.extend(
            fitted
                .iter()
                .zip(truth)
                .map(|(f, t)| (f.value - t) / f.sigma),
        );
    }
    let worst = z.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let rms = (z.iter().map(|v| v * v).sum::<f64>() / z.len() as f64).sqrt();
    eprintln!("interleaved: worst |fitted − true|/σ {worst:.2}, rms {rms:.3}");
    assert!(worst < 4.5 && (0.7..1.4).contains(&rms), "{z:?}");
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig::with_cases(200))]
    /// Whatever the maps, an answer or an error, never a panic.
    #[test]
    fn no_input_panics(
        maps in proptest::collection::vec(
            (
                proptest::collection::vec(-3i8..6, 0..5),
                proptest::collection::vec(-3i8..6, 0..5),
                proptest::collection::vec(
                    proptest::option::of(proptest::prelude::any::<(f64, f64)>()), 0..30),
                proptest::prelude::any::<bool>(),
            ),
            0..4,
        ),
        reference in 0usize..4,
        tol in proptest::prelude::any::<Option<f64>>(),
    ) {
        let zones: Vec<Zone> = maps
            .into_iter()
            .enumerate()
            .map(|(k, (xs, ys, cells, sort))| {
                let mut xs: Vec<f64> = xs.into_iter().map(|v| 10.0 * f64::from(v)).collect();
                let mut ys: Vec<f64> = ys.into_iter().map(|v| 10.0 * f64::from(v)).collect();
                if sort {
                    xs.sort_by(f64::total_cmp);
                    xs.dedup();
                    ys.sort_by(f64::total_cmp);
                    ys.dedup();
                }
                let mut cells = cells;
                if sort {
                    cells.resize(xs.len() * ys.len(), Some((0.5, -0.5)));
                }
                let cells = cells
                    .into_iter()
                    .map(|c| c.map(|(a, b)| Cell {
                        e_um: [a, b],
                        visits: 1,
                        ss_um2: [0.0; 2],
                    }))
                    .collect();
                Zone { name: format!("z{k}"), map: GridMap { xs_um: xs, ys_um: ys, cells } }
            })
            .collect();
        let _ = combine_zones(&zones, &ZoneOptions { reference, node_tol_um: tol });
    }
}
