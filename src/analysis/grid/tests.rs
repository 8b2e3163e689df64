//! Random 2-D stages (every parameter drawn, both signs, the measuring
//! frame rotated at random) mapped on random lattices, against what the
//! grid analysis reads from them.

use std::fmt::Write as _;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

use super::*;
use crate::charact::log::parse_bytes;

/// One drawn stage and its lattice.
struct Stage {
    xs: Vec<f64>,
    ys: Vec<f64>,
    scale_ppm: [f64; 2],
    squareness_urad: f64,
    rotation_urad: f64,
    /// Smooth separable waves: (component, along x?, amplitude µm,
    /// period µm, phase).
    waves: Vec<(usize, bool, f64, f64, f64)>,
    /// A Gaussian bump: (component, x0, y0, width, amplitude µm).
    bump: Option<(usize, f64, f64, f64, f64)>,
    noise_um: f64,
}

impl Stage {
    fn draw(rng: &mut ChaCha8Rng) -> Stage {
        let nx = rng.gen_range(10..=36);
        let ny = rng.gen_range(10..=36);
        let pitch = [rng.gen_range(20.0..10_000.0), rng.gen_range(20.0..10_000.0)];
        let x0 = rng.gen_range(-2e5..2e5);
        let y0 = rng.gen_range(-2e5..2e5);
        let xs: Vec<f64> = (0..nx).map(|i| x0 + i as f64 * pitch[0]).collect();
        let ys: Vec<f64> = (0..ny).map(|i| y0 + i as f64 * pitch[1]).collect();
        let noise_um = 10f64.powf(rng.gen_range(-2.5..-0.5));
        let mut waves = Vec::new();
        for c in 0..2 {
            for along_x in [true, false] {
                if rng.gen_bool(0.7) {
                    let span = if along_x {
                        pitch[0] * nx as f64
                    } else {
                        pitch[1] * ny as f64
                    };
                    waves.push((
                        c,
                        along_x,
                        rng.gen_range(-30.0..30.0) * noise_um,
                        span * rng.gen_range(0.3..3.0),
                        rng.gen_range(0.0..std::f64::consts::TAU),
                    ));
                }
            }
        }
        Stage {
            xs,
            ys,
            scale_ppm: [rng.gen_range(-50.0..50.0), rng.gen_range(-50.0..50.0)],
            squareness_urad: rng.gen_range(-300.0..300.0),
            rotation_urad: rng.gen_range(-2000.0..2000.0),
            waves,
            bump: None,
            noise_um,
        }
    }

    /// The stage's error (true − target) at a target, µm, in its frame.
    fn error(&self, x: f64, y: f64) -> [f64; 2] {
        let (xc, yc) = (self.xs[0], self.ys[0]);
        let mut e = [
            1e-6 * (self.scale_ppm[0] * (x - xc) + self.squareness_urad * (y - yc)),
            1e-6 * self.scale_ppm[1] * (y - yc),
        ];
        for &(c, along_x, a, p, ph) in &self.waves {
            let v = if along_x { x } else { y };
            e[c] += a * (std::f64::consts::TAU * v / p + ph).sin();
        }
        if let Some((c, bx, by, w, a)) = self.bump {
            e[c] += a * (-((x - bx).powi(2) + (y - by).powi(2)) / (2.0 * w * w)).exp();
        }
        e
    }

    /// Adds a bump in component `c` whose joint x–y part has `k` times
    /// the noise as RMS over the lattice.
    fn with_bump(mut self, rng: &mut ChaCha8Rng, c: usize, k: f64) -> Stage {
        let (nx, ny) = (self.xs.len(), self.ys.len());
        let pitch = (self.xs[1] - self.xs[0]).min(self.ys[1] - self.ys[0]);
        let w = pitch * rng.gen_range(1.5..4.0);
        let bx = self.xs[rng.gen_range(2..nx - 2)];
        let by = self.ys[rng.gen_range(2..ny - 2)];
        // The bump's own joint part at unit amplitude.
        let mut unit = GridMap {
            xs_um: self.xs.clone(),
            ys_um: self.ys.clone(),
            cells: Vec::new(),
        };
        for &y in &self.ys {
            for &x in &self.xs {
                let v = (-((x - bx).powi(2) + (y - by).powi(2)) / (2.0 * w * w)).exp();
                unit.cells.push(Some(Cell {
                    e_um: [v, v],
                    visits: 1,
                    ss_um2: [0.0; 2],
                }));
            }
        }
        let g = geometry::fit(&unit);
        let none = NoiseFloor {
            cell_sigma_um: 0.0,
            source: String::new(),
            along_x_um: None,
            along_y_um: None,
            replicate_um: None,
        };
        let joint = maps::judge(&unit, 0, &g.plane(0), &none, 3.0, 5.0).separable_rms_um;
        let sign = if rng.gen_bool(0.5) { 1.0 } else { -1.0 };
        self.bump = Some((c, bx, by, w, sign * k * self.noise_um / joint));
        self
    }

    /// The stage mapped once per cell through a frame rotated by the
    /// drawn angle, in the given record order, as a measurement log.
    fn log(&self, rng: &mut ChaCha8Rng, order: Order) -> MeasurementLog {
        let noise = Normal::new(0.0, self.noise_um).unwrap();
        let phi = 1e-6 * self.rotation_urad;
        let (ox, oy) = (rng.gen_range(-5.0..5.0), rng.gen_range(-5.0..5.0));
        // The noise of each position is drawn in lattice order, so one
        // grid logged in another order reads the same at every position.
        let nx = self.xs.len();
        let draws: Vec<[f64; 2]> = (0..nx * self.ys.len())
            .map(|_| [noise.sample(rng), noise.sample(rng)])
            .collect();
        let mut pts: Vec<(usize, usize)> = Vec::new();
        for iy in 0..self.ys.len() {
            let row: Vec<usize> = (0..self.xs.len()).collect();
            let row: Vec<usize> = if order == Order::Serpentine && iy % 2 == 1 {
                row.into_iter().rev().collect()
            } else {
                row
            };
            pts.extend(row.into_iter().map(|ix| (ix, iy)));
        }
        if order == Order::Shuffled {
            for i in (1..pts.len()).rev() {
                let j = rng.gen_range(0..=i);
                pts.swap(i, j);
            }
        }
        let mut s = String::from("# format: micropos-measurement-log/1\n# measured_axes: x,y\n");
        s.push_str(
            "t_s,segment,cycle,x_target_um,y_target_um,x_cmd_um,y_cmd_um,x_meas_um,y_meas_um\n",
        );
        for (i, &(ix, iy)) in pts.iter().enumerate() {
            let (x, y) = (self.xs[ix], self.ys[iy]);
            let e = self.error(x, y);
            let (tx, ty) = (x + e[0], y + e[1]);
            // The instrument reads the true position in its own frame.
            let n = draws[iy * nx + ix];
            let mx = tx * phi.cos() + ty * phi.sin() + ox + n[0];
            let my = -tx * phi.sin() + ty * phi.cos() + oy + n[1];
            let seg = match order {
                Order::Lines | Order::Serpentine => format!("line_{iy}"),
                _ => "grid".into(),
            };
            let _ = writeln!(s, "{i},{seg},1,{x:.6},{y:.6},{x:.6},{y:.6},{mx:.6},{my:.6}");
        }
        parse_bytes(s.as_bytes()).unwrap()
    }
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Order {
    OneSegment,
    Lines,
    Serpentine,
    Shuffled,
}

fn report(log: &MeasurementLog) -> GridReport {
    let map = GridMap::from_log(log, [true, true]).expect("a grid");
    analyse(&map, 5.0, 1.0)
}

/// The squareness the stage has in its own frame: the plane of its
/// noise-free error field (what a least-squares reference line gives).
fn true_geometry(s: &Stage) -> Geometry {
    let mut map = GridMap {
        xs_um: s.xs.clone(),
        ys_um: s.ys.clone(),
        cells: Vec::new(),
    };
    for &y in &s.ys {
        for &x in &s.xs {
            map.cells.push(Some(Cell {
                e_um: s.error(x, y),
                visits: 1,
                ss_um2: [0.0; 2],
            }));
        }
    }
    geometry::fit(&map)
}

#[test]
fn squareness_is_read_in_the_stages_frame_within_its_sigma() {
    let mut rng = ChaCha8Rng::seed_from_u64(31);
    let mut outside = Vec::new();
    for case in 0..60 {
        let s = Stage::draw(&mut rng);
        let r = report(&s.log(&mut rng, Order::OneSegment));
        let g = &r.geometry;
        let truth_g = true_geometry(&s);
        let truth = truth_g.out_of_squareness_urad.value;
        let z = (g.out_of_squareness_urad.value - truth) / g.out_of_squareness_urad.sigma;
        assert!(z.is_finite(), "case {case}: {g:?}");
        if z.abs() > 3.0 {
            outside.push((case, z));
        }
        // The frame's rotation goes into the nuisance, not the squareness:
        // the instrument sees the stage's own x axis turned by −φ.
        let seen = g.frame_rotation_urad.value;
        let expect = truth_g.frame_rotation_urad.value - s.rotation_urad;
        assert!(
            (seen - expect).abs() < 5.0 * g.frame_rotation_urad.sigma + 1e-3 * expect.abs(),
            "case {case}: rotation {seen}, expected {expect}"
        );
    }
    // 3σ holds for 99.7 % of normal errors: at most 2 of 60 outside.
    assert!(outside.len() <= 2, "outside 3σ: {outside:?}");
}

#[test]
fn the_frames_rotation_does_not_change_the_squareness() {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    for _ in 0..10 {
        let mut s = Stage::draw(&mut rng);
        s.noise_um = 1e-9;
        let a = report(&s.log(&mut ChaCha8Rng::seed_from_u64(1), Order::OneSegment));
        s.rotation_urad += 3000.0;
        let b = report(&s.log(&mut ChaCha8Rng::seed_from_u64(1), Order::OneSegment));
        let (qa, qb) = (
            a.geometry.out_of_squareness_urad.value,
            b.geometry.out_of_squareness_urad.value,
        );
        // Invariant to first order: what is left is the turn times the
        // slopes themselves (3 mrad × tens of ppm).
        let g = &a.geometry;
        let slopes = g.scale_x_ppm.value.abs()
            + g.scale_y_ppm.value.abs()
            + g.out_of_squareness_urad.value.abs()
            + g.frame_rotation_urad.value.abs();
        let tol = 1e-2 * slopes + 1e-3;
        assert!((qa - qb).abs() < tol, "{qa} vs {qb} (tol {tol})");
        assert!(
            (a.geometry.frame_rotation_urad.value - b.geometry.frame_rotation_urad.value - 3000.0)
                .abs()
                < tol + 10.0,
            "{} vs {}",
            a.geometry.frame_rotation_urad.value,
            b.geometry.frame_rotation_urad.value
        );
    }
}

#[test]
fn separable_stages_get_no_non_separable_finding() {
    let mut rng = ChaCha8Rng::seed_from_u64(2026);
    let mut false_findings = Vec::new();
    for case in 0..50 {
        let s = Stage::draw(&mut rng);
        let r = report(&s.log(&mut rng, Order::OneSegment));
        for m in &r.components {
            if let Some(ns) = &m.non_separable {
                false_findings.push((case, m.component.clone(), ns.z, ns.gain_pct));
            }
            // White noise on a separable stage is explained to its noise.
            assert!(
                m.unexplained.is_none(),
                "case {case}: {:?} (noise {} µm)",
                m.unexplained,
                s.noise_um
            );
        }
    }
    assert!(false_findings.is_empty(), "{false_findings:?}");
}

#[test]
fn a_joint_error_is_found_at_six_times_the_noise_and_mostly_at_three() {
    let mut rng = ChaCha8Rng::seed_from_u64(99);
    for (k, min_rate) in [(6.0, 0.8), (3.0, 0.7)] {
        let mut found = 0;
        let mut misses = Vec::new();
        let cases = 30;
        for case in 0..cases {
            let c = rng.gen_range(0..2);
            let s = Stage::draw(&mut rng).with_bump(&mut rng, c, k);
            let r = report(&s.log(&mut rng, Order::OneSegment));
            match &r.components[c].non_separable {
                Some(ns) => {
                    found += 1;
                    // The separable part takes the bump's profile along its
                    // row and its column, so what it misses most lies on
                    // the bump's row or column (at the centre, or at the
                    // far ends of a line the bump covers much of).
                    let (_, bx, by, w, _) = s.bump.unwrap();
                    let (dx, dy) = ((ns.peak_at_um[0] - bx).abs(), (ns.peak_at_um[1] - by).abs());
                    assert!(
                        dx <= 2.5 * w || dy <= 2.5 * w,
                        "case {case}: peak {dx}, {dy} µm from the bump (w {w})"
                    );
                }
                None => {
                    let pitch = (s.xs[1] - s.xs[0]).min(s.ys[1] - s.ys[0]);
                    let cells = s.xs.len() * s.ys.len();
                    misses.push(format!(
                        "case {case}: z {:.1}, width {:.1} pitches on {cells} cells",
                        r.components[c].z,
                        s.bump.map_or(0.0, |b| b.3) / pitch
                    ));
                }
            }
            assert!(
                r.components[1 - c].non_separable.is_none(),
                "case {case}: a finding on the component without the bump"
            );
        }
        let rate = found as f64 / cases as f64;
        eprintln!("joint error at {k}× the noise: found {found}/{cases}; misses: {misses:#?}");
        assert!(rate >= min_rate, "{k}×: {rate}");
    }
}

#[test]
fn the_same_grid_in_any_encoding_gives_the_same_report() {
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    for _ in 0..5 {
        let s = Stage::draw(&mut rng).with_bump(&mut rng, 1, 8.0);
        let reports: Vec<GridReport> = [
            Order::OneSegment,
            Order::Lines,
            Order::Serpentine,
            Order::Shuffled,
        ]
        .iter()
        .map(|&o| report(&s.log(&mut ChaCha8Rng::seed_from_u64(11), o)))
        .collect();
        // Every position reads the same in every order: the figures agree
        // to rounding.
        let json = |r: &GridReport| serde_json::to_value(r).unwrap();
        let first = json(&reports[0]);
        for r in &reports[1..] {
            assert!(close_json(&first, &json(r)), "{first}\n{}", json(r));
        }
    }
}

/// A grid measured both ways (random stages, a play of random size and
/// sign per axis that varies over the plane): the maps are of the arrivals
/// from below, so the play is not read as noise nor as a joint error, and
/// the reversal reads it back.
#[test]
fn a_grid_measured_both_ways_reads_the_play_apart() {
    use crate::charact::scan::{SEGMENT_GRID_BWD, SEGMENT_GRID_FWD};
    let mut rng = ChaCha8Rng::seed_from_u64(314);
    for case in 0..10 {
        let s = Stage::draw(&mut rng);
        let one_way = s.log(&mut rng, Order::OneSegment);
        let play = [
            rng.gen_range(-3.0..3.0) * 20.0 * s.noise_um,
            rng.gen_range(-3.0..3.0) * 20.0 * s.noise_um,
        ];
        // The play grows by up to 20 % across x (a worn screw end).
        let (x0, x1) = (s.xs[0], s.xs[s.xs.len() - 1]);
        let noise = Normal::new(0.0, s.noise_um).unwrap();
        let mut both = one_way.clone();
        both.records.clear();
        for r in &one_way.records {
            let mut f = r.clone();
            f.segment = SEGMENT_GRID_FWD.into();
            both.records.push(f);
        }
        for r in one_way.records.iter().rev() {
            let mut b = r.clone();
            b.segment = SEGMENT_GRID_BWD.into();
            let grow = 1.0 + 0.2 * (r.x_target_um - x0) / (x1 - x0);
            b.x_meas_um += play[0] * grow + noise.sample(&mut rng);
            b.y_meas_um += play[1] * grow + noise.sample(&mut rng);
            both.records.push(b);
        }
        let a = report(&one_way);
        let b = report_of(&both.records, [true, true], 5.0, 1.0).unwrap();
        let rv = b.reversal.as_ref().expect("a reversal");
        assert_eq!(rv.cells, s.xs.len() * s.ys.len());
        for (c, p) in play.iter().enumerate() {
            let want = p * 1.1;
            let sigma = s.noise_um * (2.0 / rv.cells as f64).sqrt();
            assert!(
                (rv.mean_um[c] - want).abs() < 5.0 * sigma + 1e-9,
                "case {case} {c}: {} vs {want}",
                rv.mean_um[c]
            );
            assert!(rv.max_abs_um[c] >= rv.mean_um[c].abs());
            // The maps are the one-way grid's.
            assert_eq!(
                a.components[c].non_separable.is_some(),
                b.components[c].non_separable.is_some()
            );
            assert!((a.noise[c].cell_sigma_um - b.noise[c].cell_sigma_um).abs() < 1e-12);
        }
        let mut text = String::new();
        write_text(&mut text, &b);
        assert!(text.contains("measured both ways: reversal"), "{text}");
    }
}

#[test]
fn a_cross_of_two_scan_lines_is_not_a_grid() {
    let mut s = String::from(
        "t_s,segment,cycle,x_target_um,y_target_um,x_cmd_um,y_cmd_um,x_meas_um,y_meas_um\n",
    );
    for i in 0..20 {
        let v = i as f64 * 5.0;
        let _ = writeln!(s, "{i},scan_x,1,{v},0,{v},0,{v},0.1");
        let _ = writeln!(s, "{i},scan_y,1,0,{v},0,{v},0.1,{v}");
    }
    let log = parse_bytes(s.as_bytes()).unwrap();
    assert!(GridMap::from_log(&log, [true, true]).is_none());
}

/// Whether two JSON values agree, numbers to a relative 1e-6.
fn close_json(a: &serde_json::Value, b: &serde_json::Value) -> bool {
    use serde_json::Value;
    match (a, b) {
        (Value::Number(x), Value::Number(y)) => {
            let (x, y) = (
                x.as_f64().unwrap_or(f64::NAN),
                y.as_f64().unwrap_or(f64::NAN),
            );
            (x - y).abs() <= 1e-6 * (1.0 + x.abs())
        }
        (Value::Array(x), Value::Array(y)) => {
            x.len() == y.len() && x.iter().zip(y).all(|(p, q)| close_json(p, q))
        }
        (Value::Object(x), Value::Object(y)) => {
            x.len() == y.len()
                && x.iter()
                    .all(|(k, v)| y.get(k).is_some_and(|w| close_json(v, w)))
        }
        _ => a == b,
    }
}
