//! Random 2-D stages drawn through the one stage model (the model the
//! simulator runs), mapped on random lattices through a measuring frame
//! rotated at random, against what the grid analysis reads from them.
//!
//! Why beside `analysis::grid`'s own random tests: those draw the error
//! field from a generator written for them (waves and a Gaussian bump).
//! Here every parameter of every family of the default stage model is
//! drawn (both signs), the nodes are reached as microposd's grid plan
//! reaches them (rows of increasing x, a row's first node by an approach
//! from below), and the non-separable error is the physical kind a stacked
//! stage has, of random size, sign and place: the lower carriage's yaw
//! growing along its travel (`stacked_yaw`, bilinear), or a yawing lower
//! carriage whose waviness the upper axis carries (`angular` with
//! `carries_other_axis`, θ(x)·y). The grid analysis was developed on the
//! other generator: every case here is held out from it.
//!
//! What must hold: the out-of-squareness in the stage's frame within 3 σ
//! (+ 0.5 µrad) of the noise-free field's; no non-separable finding on
//! ≥ 40 separable stages; the joint error found at 6× and 3× its noise at
//! the rates printed (`--nocapture`), each miss with its z, size and
//! noise (measured: 40 separable stages without a false finding, the
//! squareness within 0.13 σ; 20/20 joint errors found at 6× and at 3×;
//! judged on the checkerboard, as before `analysis::grid::maps` judged on
//! diagonal thirds, 16/20 and 13/20).

use micropos::analysis::grid::{report_of, GridReport};
use micropos::analysis::{diagnose, DiagnoseOptions, Diagnosis};
use micropos::charact::log::{Columns, MeasurementLog, Metadata, Record};
use micropos::model::{
    Direction, MotionState, MotionTracker, StageModel, Waypoint, PAPER_DEFAULT_TOML,
};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

fn uniform(rng: &mut ChaCha8Rng, lo: f64, hi: f64) -> f64 {
    lo + (hi - lo) * rng.gen::<f64>()
}

fn signed(rng: &mut ChaCha8Rng, lo: f64, hi: f64) -> f64 {
    let v = uniform(rng, lo, hi);
    if rng.gen() {
        v
    } else {
        -v
    }
}

/// Which non-separable error a stage gets.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Joint {
    None,
    /// `stacked_yaw` with this lower axis (0: x, 1: y).
    StackedYaw(usize),
    /// The lower carriage's `angular` yaw carried by the other axis.
    CarriedYaw(usize),
}

/// One drawn stage: its model, lattice, noise and measuring frame.
struct Stage {
    model: StageModel,
    xs: Vec<f64>,
    ys: Vec<f64>,
    noise_um: f64,
    rotation_urad: f64,
    offset_um: [f64; 2],
    /// The component the joint error is in (`Joint::None`: none).
    joint: Joint,
}

/// The default model's text with the non-separable term of `joint`.
fn model_text(joint: Joint, rng: &mut ChaCha8Rng, xs: &[f64], ys: &[f64]) -> String {
    let mut text = PAPER_DEFAULT_TOML.to_owned();
    let mid = |v: &[f64], rng: &mut ChaCha8Rng| uniform(rng, v[0], v[v.len() - 1]);
    match joint {
        Joint::None => {}
        Joint::StackedYaw(lower) => {
            let (lo, up) = if lower == 0 { (xs, ys) } else { (ys, xs) };
            text.push_str(&format!(
                "\n[[term]]\nkind = \"stacked_yaw\"\nname = \"carriage_yaw\"\nlower_axis = \"{}\"\nslope_urad_per_mm = 1.0\nlower_center_um = {}\nupper_center_um = {}\n",
                if lower == 0 { "x" } else { "y" },
                mid(lo, rng),
                mid(up, rng)
            ));
        }
        Joint::CarriedYaw(0) => {
            text = text.replace("carries_other_axis = false", "carries_other_axis = true");
        }
        Joint::CarriedYaw(_) => {
            text = text.replace(
                "name = \"y_yaw\"\n",
                "name = \"y_yaw\"\ncarries_other_axis = true\n",
            );
        }
    }
    text
}

/// Every parameter of every family drawn: squareness ±3 mrad, scales
/// ±300 ppm, play 0.3–5 µm, angular slopes ±10 µrad/mm and waviness
/// ±30 µrad, cyclic first harmonics 0.3–4 µm (cross coupling 0.1–1.5 µm)
/// with higher harmonics, thermal, drifts.
fn draw_params(m: &mut StageModel, rng: &mut ChaCha8Rng) {
    for p in m.params() {
        let v = match (p.kind.as_str(), p.info.name.as_str()) {
            ("squareness", _) => signed(rng, 0.0, 3000.0),
            ("lead_error", _) => signed(rng, 0.0, 300.0),
            ("backlash", _) => uniform(rng, 0.3, 5.0),
            ("angular", n) if n.starts_with("slope") => signed(rng, 0.0, 10.0),
            ("angular", n) if n.starts_with("sin") || n.starts_with("cos") => {
                signed(rng, 0.0, 30.0)
            }
            ("thermal_expansion", _) => signed(rng, 0.0, 0.02),
            ("optics_drift", _) => signed(rng, 0.0, 0.5),
            ("time_drift", "rate_um_per_h") => signed(rng, 0.0, 0.3),
            ("leadscrew_cyclic", _) => signed(rng, 0.0, 2.0),
            ("cross_coupling", _) => signed(rng, 0.0, 0.7),
            _ => continue,
        };
        let _ = m.set_param(&p.full_name, v);
    }
}

impl Stage {
    fn draw(rng: &mut ChaCha8Rng, joint: Joint) -> Stage {
        let (nx, ny) = (rng.gen_range(10..=30), rng.gen_range(10..=30));
        let pitch = [uniform(rng, 40.0, 800.0), uniform(rng, 40.0, 800.0)];
        let (x0, y0) = (uniform(rng, 0.0, 1000.0), uniform(rng, 0.0, 1000.0));
        let xs: Vec<f64> = (0..nx).map(|i| x0 + i as f64 * pitch[0]).collect();
        let ys: Vec<f64> = (0..ny).map(|i| y0 + i as f64 * pitch[1]).collect();
        let mut model = StageModel::from_toml(&model_text(joint, rng, &xs, &ys)).unwrap();
        draw_params(&mut model, rng);
        Stage {
            model,
            xs,
            ys,
            noise_um: 10f64.powf(uniform(rng, -2.0, -0.7)),
            rotation_urad: signed(rng, 0.0, 2000.0),
            offset_um: [signed(rng, 0.0, 5.0), signed(rng, 0.0, 5.0)],
            joint,
        }
    }

    /// The component the joint error is in.
    fn joint_component(&self) -> Option<usize> {
        match self.joint {
            Joint::None => None,
            // A yawing lower carriage moves the platform along its own
            // axis by the yaw times the upper axis's reach (dx = −θ·y).
            Joint::StackedYaw(lower) | Joint::CarriedYaw(lower) => Some(lower),
        }
    }

    /// The noise-free error `true − commanded` at every node, reached as
    /// the grid plan reaches it, row-major.
    fn field(&self) -> Vec<[f64; 2]> {
        let mut tracker = MotionTracker::new(MotionState::at_rest(0.0, 0.0)).unwrap();
        let mut out = Vec::new();
        let mut t_s = 0.0;
        for &y in &self.ys {
            tracker
                .step(Waypoint::at(self.xs[0] - 100.0, y - 100.0))
                .unwrap();
            for &x in &self.xs {
                t_s += 2.0;
                let s = tracker
                    .step(Waypoint {
                        time_s: t_s,
                        ..Waypoint::at(x, y)
                    })
                    .unwrap();
                let o = self.model.observed_position(&s);
                out.push([o.x_um - x, o.y_um - y]);
            }
        }
        out
    }

    /// Scales the joint term so that its part no `f(x) + g(y)` holds has
    /// `k` times the noise as rms over the lattice.
    fn scale_joint(&mut self, k: f64) {
        let Some(c) = self.joint_component() else {
            return;
        };
        let names: Vec<String> = match self.joint {
            Joint::StackedYaw(_) => vec!["carriage_yaw.slope_urad_per_mm".into()],
            Joint::CarriedYaw(lower) => {
                let t = if lower == 0 { "x_yaw" } else { "y_yaw" };
                self.model
                    .params()
                    .into_iter()
                    .filter(|p| {
                        p.term == t
                            && (p.info.name.starts_with("slope")
                                || p.info.name.starts_with("sin")
                                || p.info.name.starts_with("cos"))
                    })
                    .map(|p| p.full_name)
                    .collect()
            }
            Joint::None => Vec::new(),
        };
        let unit = joint_rms(&self.field(), self.xs.len(), c);
        let f = k * self.noise_um / unit;
        for n in &names {
            let v = self.model.param(n).unwrap();
            if let Err(e) = self.model.set_param(n, v * f) {
                panic!("{n} = {v} × {f}: {e}");
            }
        }
    }

    /// The map as a measurement log's records: each node once, read
    /// through the rotated, offset frame with noise.
    fn records(&self, rng: &mut ChaCha8Rng) -> Vec<Record> {
        let noise = Normal::new(0.0, self.noise_um).unwrap();
        let phi = 1e-6 * self.rotation_urad;
        let field = self.field();
        let nx = self.xs.len();
        let mut out = Vec::new();
        for (k, e) in field.iter().enumerate() {
            let (x, y) = (self.xs[k % nx], self.ys[k / nx]);
            let (tx, ty) = (x + e[0], y + e[1]);
            out.push(Record {
                t_s: 2.0 * k as f64,
                segment: "grid".into(),
                cycle: 1,
                x_target_um: x,
                y_target_um: y,
                x_cmd_um: x,
                y_cmd_um: y,
                x_meas_um: tx * phi.cos() + ty * phi.sin() + self.offset_um[0] + noise.sample(rng),
                y_meas_um: -tx * phi.sin() + ty * phi.cos() + self.offset_um[1] + noise.sample(rng),
                temp_c: None,
                theta_urad: None,
                extra: Vec::new(),
            });
        }
        out
    }

    /// The out-of-squareness of the noise-free field in the stage's frame:
    /// d(ex)/dy + d(ey)/dx of the least-squares planes, µrad.
    fn true_squareness_urad(&self) -> f64 {
        let field = self.field();
        let nx = self.xs.len();
        let slope = |c: usize, along_y: bool| {
            // Plane fit on a full lattice: the slope along one axis is the
            // regression on that coordinate alone (the lattice is
            // orthogonal).
            let pos = |k: usize| {
                if along_y {
                    self.ys[k / nx]
                } else {
                    self.xs[k % nx]
                }
            };
            let n = field.len() as f64;
            let mp = (0..field.len()).map(pos).sum::<f64>() / n;
            let me = field.iter().map(|e| e[c]).sum::<f64>() / n;
            let (mut sxy, mut sxx) = (0.0, 0.0);
            for (k, e) in field.iter().enumerate() {
                sxy += (pos(k) - mp) * (e[c] - me);
                sxx += (pos(k) - mp).powi(2);
            }
            1e6 * sxy / sxx
        };
        slope(0, true) + slope(1, false)
    }
}

/// Rms of component `c`'s part that no `f(x) + g(y)` holds (the doubly
/// centred field of a full lattice).
fn joint_rms(field: &[[f64; 2]], nx: usize, c: usize) -> f64 {
    let ny = field.len() / nx;
    let v = |ix: usize, iy: usize| field[iy * nx + ix][c];
    let row: Vec<f64> = (0..ny)
        .map(|iy| (0..nx).map(|ix| v(ix, iy)).sum::<f64>() / nx as f64)
        .collect();
    let col: Vec<f64> = (0..nx)
        .map(|ix| (0..ny).map(|iy| v(ix, iy)).sum::<f64>() / ny as f64)
        .collect();
    let all = row.iter().sum::<f64>() / ny as f64;
    let mut s = 0.0;
    for (iy, r) in row.iter().enumerate() {
        for (ix, c) in col.iter().enumerate() {
            s += (v(ix, iy) - r - c + all).powi(2);
        }
    }
    (s / field.len() as f64).sqrt()
}

fn report(s: &Stage, rng: &mut ChaCha8Rng) -> GridReport {
    report_of(&s.records(rng), [true, true], 5.0, 1.0).expect("a grid")
}

/// Separable stages: the squareness in the stage's frame within 3 σ, and
/// no non-separable finding.
#[test]
fn model_stages_get_their_squareness_and_no_false_joint_finding() {
    let mut rng = ChaCha8Rng::seed_from_u64(0x2d_5eed);
    let mut false_findings = Vec::new();
    let mut worst_sigmas = 0.0f64;
    let cases = 40;
    for case in 0..cases {
        let s = Stage::draw(&mut rng, Joint::None);
        let r = report(&s, &mut rng);
        let q = r.geometry.out_of_squareness_urad;
        let truth = s.true_squareness_urad();
        assert!(
            q.sigma.is_finite(),
            "case {case}: {q:?}; field finite: {}, lattice {} × {}, noise {}, report {}",
            s.field()
                .iter()
                .all(|e| e[0].is_finite() && e[1].is_finite()),
            s.xs.len(),
            s.ys.len(),
            s.noise_um,
            serde_json::to_string(&r.geometry).unwrap()
        );
        let dev = (q.value - truth).abs();
        worst_sigmas = worst_sigmas.max(dev / q.sigma);
        assert!(
            dev <= 3.0 * q.sigma + 0.5,
            "case {case}: squareness {} ± {} µrad, true {truth} µrad (frame turned {} µrad)",
            q.value,
            q.sigma,
            s.rotation_urad
        );
        for m in &r.components {
            if let Some(ns) = &m.non_separable {
                false_findings.push(format!(
                    "case {case} {}: z {:.1}, gain {:.0} %, noise {:.3} µm",
                    m.component, ns.z, ns.gain_pct, s.noise_um
                ));
            }
        }
    }
    eprintln!(
        "GRID-MODEL | {cases} separable stages: worst squareness |error|/σ {worst_sigmas:.2}; false joint findings: {}",
        false_findings.len()
    );
    assert!(false_findings.is_empty(), "{false_findings:#?}");
}

/// Stages with a joint error of `k` times the noise: how often it is
/// found in its component, never in the other.
#[test]
fn model_stages_with_a_joint_error_are_found_at_six_and_three_times_the_noise() {
    let mut rng = ChaCha8Rng::seed_from_u64(0x2d_b1a5);
    let cases = 20;
    let mut rates = Vec::new();
    for (k, min_rate) in [(6.0, 0.9), (3.0, 0.8)] {
        let mut found = 0;
        let mut misses = Vec::new();
        for case in 0..cases {
            let lower = rng.gen_range(0..2);
            let joint = if rng.gen() {
                Joint::StackedYaw(lower)
            } else {
                Joint::CarriedYaw(lower)
            };
            let mut s = Stage::draw(&mut rng, joint);
            s.scale_joint(k);
            let c = s.joint_component().unwrap();
            let r = report(&s, &mut rng);
            match &r.components[c].non_separable {
                Some(_) => found += 1,
                None => misses.push(format!(
                    "case {case} {joint:?}: z {:.1} on {} × {} cells (noise {:.3} µm) joint {:.3} sep {:.3} folds {:?}",
                    r.components[c].z,
                    s.xs.len(),
                    s.ys.len(),
                    s.noise_um,
                    joint_rms(&s.field(), s.xs.len(), c),
                    r.components[c].separable_rms_um,
                    r.components[c].folds.iter().map(|f| (f.separable_um, f.map_um)).collect::<Vec<_>>()
                )),
            }
            assert!(
                r.components[1 - c].non_separable.is_none(),
                "case {case} {joint:?}: a finding on the component without the joint error"
            );
        }
        let rate = f64::from(found) / f64::from(cases);
        eprintln!("GRID-MODEL | joint error at {k}× the noise: found {found}/{cases}; misses: {misses:#?}");
        rates.push((k, rate, min_rate));
    }
    for (k, rate, min_rate) in rates {
        assert!(rate >= min_rate, "{k}×: {rate}");
    }
}

/// The stage's map as a measurement log.
fn log_of(records: Vec<Record>) -> MeasurementLog {
    let mut metadata = Metadata::new();
    metadata.insert("measured_axes", "x,y");
    // Reached as microposd's one-way grid plan reaches its nodes.
    metadata.insert("plan", "grid");
    MeasurementLog {
        metadata,
        comments: Vec::new(),
        columns: Columns::new(false, Vec::new()).unwrap(),
        records,
        warnings: Vec::new(),
        warnings_dropped: 0,
        torn_tail: None,
    }
}

/// Rms of component `c` of `d` (per point `[dx, dy]` at `p`) once the
/// best rigid motion (an offset per component and one rotation) is
/// removed: the frames of the truth and of a diagnosis differ by that
/// (the measuring frame's offset and rotation, which `diagnose` turns).
pub(crate) fn rigid_rms(p: &[[f64; 2]], d: &[[f64; 2]], c: usize) -> f64 {
    let n = p.len() as f64;
    let mean = |f: &dyn Fn(usize) -> f64| (0..p.len()).map(f).sum::<f64>() / n;
    let (px, py) = (mean(&|i| p[i][0]), mean(&|i| p[i][1]));
    let (dx, dy) = (mean(&|i| d[i][0]), mean(&|i| d[i][1]));
    let (mut num, mut den) = (0.0, 0.0);
    for i in 0..p.len() {
        let (x, y) = (p[i][0] - px, p[i][1] - py);
        num += -y * (d[i][0] - dx) + x * (d[i][1] - dy);
        den += x * x + y * y;
    }
    let th = if den > 0.0 { num / den } else { 0.0 };
    let s: f64 = (0..p.len())
        .map(|i| {
            let (x, y) = (p[i][0] - px, p[i][1] - py);
            let r = [d[i][0] - dx + th * y, d[i][1] - dy - th * x];
            r[c] * r[c]
        })
        .sum();
    (s / n).sqrt()
}

/// What the extended model with and without its map terms leaves of the
/// stage's noise-free error at the centres of the lattice's cells (points
/// the map never measured, reached as the grid plan reaches a node),
/// component `c`, after a rigid motion: `[without, with]`, µm.
fn between_nodes(s: &Stage, d: &Diagnosis, c: usize) -> [f64; 2] {
    let mut without = d.extended_model.clone();
    for m in d.map_term.iter().flat_map(|m| &m.components) {
        if let Some(t) = &m.term {
            without.remove_term(t);
        }
    }
    let mut pts = Vec::new();
    let mut diff = [Vec::new(), Vec::new()];
    for w in s.xs.windows(2) {
        for v in s.ys.windows(2) {
            let (x, y) = (0.5 * (w[0] + w[1]), 0.5 * (v[0] + v[1]));
            let st = MotionState::arrived(x, Direction::Forward, y, Direction::Forward);
            let t = s.model.observed_position(&st);
            pts.push([x, y]);
            for (k, m) in [&without, &d.extended_model].into_iter().enumerate() {
                let o = m.observed_position(&st);
                diff[k].push([t.x_um - o.x_um, t.y_um - o.y_um]);
            }
        }
    }
    [rigid_rms(&pts, &diff[0], c), rigid_rms(&pts, &diff[1], c)]
}

/// The 2-D map term through the whole diagnosis, on stages whose model is
/// known but for the joint error (the model given to `diagnose` is the
/// stage's own, its `stacked_yaw` removed): a separable stage gets no map
/// (nothing is left between neighbours but noise); a stage with the joint
/// error of 6× the noise gets a map in that component, which brings the
/// extended model closer to the stage's truth at points it never measured
/// (the centres of the cells). Measured (`--nocapture`): see the
/// GRID-MAP-TERM lines.
#[test]
fn the_map_term_joins_the_model_where_a_joint_error_is_and_only_there() {
    let mut rng = ChaCha8Rng::seed_from_u64(0x3a9_7e44);
    let opts = DiagnoseOptions::default();
    let mut false_maps = Vec::new();
    let separable = 12;
    for case in 0..separable {
        let s = Stage::draw(&mut rng, Joint::None);
        let d = diagnose(&log_of(s.records(&mut rng)), &s.model, &opts).unwrap();
        for m in &d.map_term.as_ref().expect("a grid").components {
            if m.term.is_some() {
                false_maps.push(format!("case {case} {}: {}", m.component, m.verdict));
            }
        }
    }
    let joint = 10;
    let mut found = 0;
    let mut gains = Vec::new();
    let mut misses = Vec::new();
    for case in 0..joint {
        let lower = rng.gen_range(0..2);
        let mut s = Stage::draw(&mut rng, Joint::StackedYaw(lower));
        s.scale_joint(6.0);
        let mut given = s.model.clone();
        given.remove_term("carriage_yaw").expect("the joint term");
        let d = diagnose(&log_of(s.records(&mut rng)), &given, &opts).unwrap();
        let m = &d.map_term.as_ref().expect("a grid").components;
        let other = m.iter().find(|m| m.component != ["x", "y"][lower]).unwrap();
        if other.term.is_some() {
            false_maps.push(format!("case {case} other component: {}", other.verdict));
        }
        let mine = m.iter().find(|m| m.component == ["x", "y"][lower]).unwrap();
        if mine.term.is_none() {
            misses.push(format!("case {case}: {}", mine.verdict));
            continue;
        }
        found += 1;
        let [without, with] = between_nodes(&s, &d, lower);
        gains.push((without, with));
        assert!(
            with < without,
            "case {case}: between the nodes the map made it worse: {without:.4} → {with:.4} µm (noise {:.4})",
            s.noise_um
        );
    }
    eprintln!(
        "GRID-MAP-TERM | {separable} separable stages + {joint} with the other component: {} false maps",
        false_maps.len()
    );
    eprintln!(
        "GRID-MAP-TERM | joint error at 6× the noise: map found {found}/{joint}; misses {misses:#?}"
    );
    eprintln!(
        "GRID-MAP-TERM | at the cells' centres, the extended model's error without → with the map (µm): {}",
        gains
            .iter()
            .map(|(a, b)| format!("{a:.4} → {b:.4}"))
            .collect::<Vec<_>>()
            .join(", ")
    );
    assert!(false_maps.is_empty(), "{false_maps:#?}");
    assert!(found >= 9, "{found}/{joint}: {misses:#?}");
}

/// A grid measured both ways whose reversal changes over the plane (a
/// play that grows along x at one end of y only: no `f(x) + g(y)` per
/// direction, no single play): the map term gets a layer per arrival
/// direction, and the extended model reproduces the map of each
/// direction at its nodes, where one pooled layer could not.
#[test]
fn a_map_measured_both_ways_gets_a_layer_per_direction() {
    let mut rng = ChaCha8Rng::seed_from_u64(0xb0_7a);
    let noise = Normal::new(0.0, 0.01).unwrap();
    let (nx, ny) = (14, 11);
    let xs: Vec<f64> = (0..nx).map(|i| 300.0 + 250.0 * i as f64).collect();
    let ys: Vec<f64> = (0..ny).map(|i| 500.0 + 200.0 * i as f64).collect();
    let (sx, sy) = (xs[nx - 1] - xs[0], ys[ny - 1] - ys[0]);
    // Error per direction (from below: 0, from above: 1), component.
    let field = |x: f64, y: f64, up: usize| -> [f64; 2] {
        let (u, v) = ((x - xs[0]) / sx, (y - ys[0]) / sy);
        let below = [
            0.3 * (6.0 * u).sin() + 0.2 * v,
            -0.4 * u * u + 0.1 * (5.0 * v).cos(),
        ];
        let play = [1.5 * u * v, 0.8 * (1.0 - u) * v * v];
        [0, 1].map(|c| below[c] + if up == 1 { play[c] } else { 0.0 })
    };
    let mut records = Vec::new();
    let mut t = 0.0;
    for (up, seg) in [(0usize, "grid_fwd"), (1, "grid_bwd")] {
        let order: Vec<(f64, f64)> = ys
            .iter()
            .flat_map(|&y| xs.iter().map(move |&x| (x, y)))
            .collect();
        let order: Vec<(f64, f64)> = if up == 1 {
            order.into_iter().rev().collect()
        } else {
            order
        };
        for (x, y) in order {
            let e = field(x, y, up);
            t += 2.0;
            records.push(Record {
                t_s: t,
                segment: seg.into(),
                cycle: 1,
                x_target_um: x,
                y_target_um: y,
                x_cmd_um: x,
                y_cmd_um: y,
                x_meas_um: x + e[0] + noise.sample(&mut rng),
                y_meas_um: y + e[1] + noise.sample(&mut rng),
                temp_c: None,
                theta_urad: None,
                extra: Vec::new(),
            });
        }
    }
    let model = StageModel::paper_default().unwrap();
    let d = diagnose(&log_of(records), &model, &DiagnoseOptions::default()).unwrap();
    let m = d.map_term.as_ref().expect("a grid");
    for c in &m.components {
        assert_eq!(c.layers, ["from below", "from above"], "{c:?}");
        assert!(c.term.is_some(), "{c:?}");
    }
    // The written model, each direction's nodes reached that way.
    let back = StageModel::from_toml(&d.extended_model.to_toml().unwrap()).unwrap();
    let mut pooled = back.clone();
    for c in &m.components {
        let name = c.term.as_deref().unwrap();
        let t = pooled.remove_term(name).unwrap();
        let mut cfg: toml::Table = t.to_config().unwrap();
        let below: Vec<f64> = cfg["values_um"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_float().unwrap())
            .collect();
        let above: Vec<f64> = cfg["from_above_um"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_float().unwrap())
            .collect();
        let mean: Vec<toml::Value> = below
            .iter()
            .zip(&above)
            .map(|(a, b)| toml::Value::Float(0.5 * (a + b)))
            .collect();
        cfg.insert("values_um".into(), toml::Value::Array(mean));
        cfg.remove("from_above_um");
        cfg.insert("name".into(), name.into());
        cfg.insert("kind".into(), "position_map".into());
        let text = format!(
            "{}\n[[term]]\n{}",
            pooled.to_toml().unwrap(),
            toml::to_string(&cfg).unwrap()
        );
        pooled = StageModel::from_toml(&text).unwrap();
    }
    let left = |model: &StageModel| -> [f64; 2] {
        let mut pts = Vec::new();
        let mut diff = Vec::new();
        for up in 0..2 {
            let dir = if up == 0 {
                Direction::Forward
            } else {
                Direction::Backward
            };
            for &y in &ys {
                for &x in &xs {
                    let o = model.observed_position(&MotionState::arrived(x, dir, y, dir));
                    let e = field(x, y, up);
                    pts.push([x, y]);
                    diff.push([o.x_um - x - e[0], o.y_um - y - e[1]]);
                }
            }
        }
        [rigid_rms(&pts, &diff, 0), rigid_rms(&pts, &diff, 1)]
    };
    let (layered, one) = (left(&back), left(&pooled));
    eprintln!(
        "GRID-MAP-TERM | both ways, the true map per direction left by the model: a layer per direction x {:.4} / y {:.4} µm, the layers pooled x {:.4} / y {:.4} µm (noise 0.01)",
        layered[0], layered[1], one[0], one[1]
    );
    for c in 0..2 {
        assert!(layered[c] < 0.03, "{layered:?}");
        assert!(one[c] > 5.0 * layered[c], "{one:?} vs {layered:?}");
    }
}
