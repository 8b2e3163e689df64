//! `diagnose` on the real 2-D grid map in `../shared/reference/real-2d-grids/`
//! (a planar air-bearing XY stage mapped by a plane-mirror laser
//! interferometer, one pass, 36 × 36 points; its README states what a
//! metrologist reads from it). Skipped with a message when the directory
//! is absent.
//!
//! What an honest diagnosis of a map must do, whatever the stage: state
//! the out-of-squareness in the stage's frame (not the mirrors'), the
//! scales the data measure, no play where no axis reverses, no time
//! structure where time only numbers the plan, the joint x–y error that
//! no f(x) + g(y) holds, and the same figures whatever the record order or
//! the segments the grid was logged in.

use std::path::PathBuf;

use micropos::analysis::{diagnose, DiagnoseOptions, Diagnosis};
use micropos::charact::log::{read_file, MeasurementLog};
use micropos::model::{MotionState, StageModel, StageSimulator};

use super::grid_random_model::rigid_rms;

fn path() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/reference/real-2d-grids/aerotech_planarhd_cz1.csv")
}

fn load() -> Option<MeasurementLog> {
    let p = path();
    if !p.exists() {
        eprintln!("skipped: {} not found", p.display());
        return None;
    }
    Some(read_file(&p).unwrap())
}

fn run(log: &MeasurementLog) -> Diagnosis {
    let model = StageModel::paper_default().unwrap();
    diagnose(log, &model, &DiagnoseOptions::default()).unwrap()
}

#[test]
fn the_shared_map_is_read_in_the_stages_frame() {
    let Some(log) = load() else { return };
    let d = run(&log);
    let text = d.to_text();
    eprintln!("{text}");
    let g = d.grid.as_ref().expect("a 2-D grid map");
    assert_eq!((g.columns, g.rows, g.cells), (36, 36, 1296));
    // Squareness: the README's +9.6 µrad (d(ex)/dy −2.85, d(ey)/dx +12.47),
    // within σ + 3 µrad.
    let q = g.geometry.out_of_squareness_urad;
    assert!((q.value - 9.6).abs() <= q.sigma + 3.0, "{q:?}");
    assert!(q.sigma.is_finite() && q.sigma < 3.0, "{q:?}");
    // The mirrors' alignment is the nuisance, apart.
    assert!((g.geometry.frame_rotation_urad.value - 12.47).abs() < 1.0);
    // Scale from the data: x +1.6 ppm, y +0.9 ppm.
    let sx = g.geometry.scale_x_ppm;
    assert!((sx.value - 1.6).abs() <= 3.0 * sx.sigma + 0.3, "{sx:?}");
    let sy = g.geometry.scale_y_ppm;
    assert!((sy.value - 0.9).abs() <= 3.0 * sy.sigma + 0.3, "{sy:?}");
    // Noise from the neighbours along the lines: 0.028 / 0.018 µm in the
    // README (a plain σ of the second differences; ours is robust).
    assert!(
        (0.015..0.035).contains(&g.noise[0].cell_sigma_um),
        "{:?}",
        g.noise[0]
    );
    assert!(
        (0.012..0.025).contains(&g.noise[1].cell_sigma_um),
        "{:?}",
        g.noise[1]
    );
    // The joint x–y structure in y: about 0.16 µm rms, a finding, with a
    // 2-D table's held-out gain (separable 0.157 µm → well under 0.06).
    let y = &g.components[1];
    let ns = y.non_separable.as_ref().expect("joint x–y error in y");
    assert!((0.12..0.20).contains(&ns.rms_um), "{ns:?}");
    assert!(
        ns.heldout_map_um < 0.06 && ns.heldout_separable_um > 0.14,
        "{ns:?}"
    );
    assert!(ns.gain_pct > 50.0);
    // The peak of a finding lies on the lattice, with finite numbers.
    for c in &g.components {
        if let Some(ns) = &c.non_separable {
            assert!(ns.peak_at_um[0] >= g.x_range_um[0] && ns.peak_at_um[0] <= g.x_range_um[1]);
            assert!(ns.peak_at_um[1] >= g.y_range_um[0] && ns.peak_at_um[1] <= g.y_range_um[1]);
        }
    }
    // No play: no axis reverses onto its points from both sides in y, and
    // x's play reads zero; no time structure on a one-pass map.
    for p in &d.parameters {
        if p.kind == "backlash" {
            assert!(p.fitted_value.abs() < 3.0 * p.std_error + 0.1, "{p:?}");
        }
    }
    assert!(d
        .base_fixed_params
        .iter()
        .any(|p| p.name == "y_backlash.backlash_um"));
    assert!(d.time_unusable.is_some());
    for f in &d.findings {
        assert!(
            !matches!(
                f.kind,
                micropos::analysis::FindingKind::TimeDrift
                    | micropos::analysis::FindingKind::TimePeriodic
            ),
            "{f:?}"
        );
    }
    // The model's squareness, read after the frame was turned, is the
    // stage's.
    let sq = d
        .parameters
        .iter()
        .find(|p| p.term == "squareness")
        .expect("squareness fitted");
    assert!((sq.fitted_value - 9.6).abs() < 3.0, "{sq:?}");
    // The text: the map first; never "explained to its noise"; every
    // localized finding located inside the map with a finite σ.
    assert!(text.starts_with("2-D grid map: 36 × 36"), "{text}");
    assert!(
        text.contains("out-of-squareness (d(ex)/dy + d(ey)/dx): +9.6"),
        "{text}"
    );
    assert!(
        text.contains("FINDING: a non-separable error in y"),
        "{text}"
    );
    assert!(!text.contains("explains the log to its noise"), "{text}");
    assert!(
        !text.contains("this stage's scale (lead error) `x_lead.ppm` is +215"),
        "{text}"
    );
    // Every place inside the map, every σ usable, in the text and the
    // JSON (or the finding withdrawn, with its reason).
    let bad = super::diagnose_sane::problems(&log, &d);
    assert!(bad.is_empty(), "{bad:#?}");
    assert!(d.to_json()["grid"]["geometry"]["out_of_squareness_urad"]["value"].is_f64());
}

/// The shared map re-encoded: raster lines as segments, serpentine lines
/// and shuffled records, each with times that number the records.
fn encoded(log: &MeasurementLog, how: &str) -> MeasurementLog {
    let mut l = log.clone();
    match how {
        "lines" => {
            for r in &mut l.records {
                r.segment = format!("line_{:.0}", r.y_target_um);
            }
        }
        "serpentine" => {
            let mut rows: Vec<Vec<micropos::charact::log::Record>> = Vec::new();
            for r in l.records.drain(..) {
                match rows.last_mut() {
                    Some(row) if row[0].y_target_um == r.y_target_um => row.push(r),
                    _ => rows.push(vec![r]),
                }
            }
            for (i, mut row) in rows.into_iter().enumerate() {
                if i % 2 == 1 {
                    row.reverse();
                }
                l.records.extend(row);
            }
        }
        "shuffled" => {
            // A fixed permutation (a multiplicative step coprime with n).
            let n = l.records.len();
            let old = std::mem::take(&mut l.records);
            l.records = (0..n).map(|i| old[(i * 7919) % n].clone()).collect();
        }
        _ => unreachable!(),
    }
    for (i, r) in l.records.iter_mut().enumerate() {
        r.t_s = i as f64;
    }
    l
}

#[test]
fn the_shared_map_in_any_encoding_gives_the_same_conclusions() {
    let Some(log) = load() else { return };
    let base = run(&log);
    let bg = base.grid.as_ref().unwrap();
    for how in ["lines", "serpentine", "shuffled"] {
        let d = run(&encoded(&log, how));
        let g = d.grid.as_ref().expect("a grid in every encoding");
        // The map's own reading depends on the targets alone.
        let (a, b) = (
            bg.geometry.out_of_squareness_urad,
            g.geometry.out_of_squareness_urad,
        );
        assert!((a.value - b.value).abs() < 1e-6, "{how}: {a:?} {b:?}");
        for c in 0..2 {
            assert_eq!(
                bg.components[c].non_separable.is_some(),
                g.components[c].non_separable.is_some(),
                "{how}"
            );
        }
        // The model's reading: the same squareness within 3σ of the
        // map's (the model replays the record order as the stage's path,
        // so a serpentine or shuffled order changes its fit of play and
        // its findings a little), no time finding.
        let sq = |d: &Diagnosis| {
            d.parameters
                .iter()
                .find(|p| p.term == "squareness")
                .map(|p| p.fitted_value)
                .unwrap()
        };
        assert!(
            (sq(&d) - sq(&base)).abs() < 3.0 * b.sigma,
            "{how}: {} vs {}",
            sq(&d),
            sq(&base)
        );
        // The 2-D map term joins the model in the same components.
        let terms = |d: &Diagnosis| -> Vec<bool> {
            d.map_term
                .as_ref()
                .unwrap()
                .components
                .iter()
                .map(|c| c.term.is_some())
                .collect()
        };
        assert_eq!(terms(&d), terms(&base), "{how}");
        assert!(d.time_unusable.is_some(), "{how}");
        assert!(
            d.findings.iter().all(|f| !matches!(
                f.kind,
                micropos::analysis::FindingKind::TimeDrift
                    | micropos::analysis::FindingKind::TimePeriodic
            )),
            "{how}: {:?}",
            d.findings
        );
    }
}

/// The model's reading states the scale the map measures: the lead, its
/// Abbe partners and the thermal scale at the log's constant temperature
/// (held at the model's values) in all, within the σ of both.
#[test]
fn the_models_scale_in_all_is_the_maps() {
    let Some(log) = load() else { return };
    let d = run(&log);
    let g = d.grid.as_ref().expect("a grid");
    let text = d.to_text();
    for (axis, map) in [("x", g.geometry.scale_x_ppm), ("y", g.geometry.scale_y_ppm)] {
        let key = format!("`{axis}_lead.ppm` together with");
        let line = text
            .lines()
            .find(|l| l.contains(&key))
            .unwrap_or_else(|| panic!("no total for {axis}: {text}"));
        assert!(line.contains("stage_thermal"), "{line}");
        let total: Vec<f64> = line
            .split("measures ")
            .nth(1)
            .and_then(|t| t.split(" ppm").next())
            .map(|t| {
                t.split(" ± ")
                    .filter_map(|v| v.trim().parse().ok())
                    .collect()
            })
            .unwrap_or_default();
        assert_eq!(total.len(), 2, "{line}");
        let within = 3.0 * (total[1].powi(2) + map.sigma.powi(2)).sqrt();
        assert!(
            (total[0] - map.value).abs() <= within,
            "{axis}: model total {} ± {} ppm, map {} ± {} ppm",
            total[0],
            total[1],
            map.value,
            map.sigma
        );
    }
}

/// The measured map runs in the simulator: the extended model, written
/// as `micropos diagnose --out` writes it and read back as `hil-sim
/// --model` reads it, driven through the log's targets by the simulator's
/// own stage (`StageSimulator`, settling noise off), reproduces the
/// measured map at its nodes (the node values are the measured cells'
/// residuals, so to rounding); without its map terms it leaves what the
/// named terms cannot carry. Measured (`--nocapture`): see the MAP-IN-SIM line.
#[test]
fn the_shared_map_runs_in_the_simulator() {
    let Some(log) = load() else { return };
    let d = run(&log);
    let m = d.map_term.as_ref().expect("a grid");
    assert!(m.components.iter().all(|c| c.term.is_some()), "{m:?}");
    let text = d.extended_model.to_toml().unwrap();
    assert!(text.contains("kind = \"position_map\""));
    let with = StageModel::from_toml(&text).unwrap();
    let mut without = with.clone();
    for c in &m.components {
        without.remove_term(c.term.as_deref().unwrap()).unwrap();
    }
    let replay = |model: &StageModel| -> [f64; 2] {
        let mut model = model.clone();
        let mut st = model.stochastic().clone();
        st.repeatability_sigma_um = [0.0; 2];
        st.rough_spots.clear();
        model.set_stochastic(st).unwrap();
        let r0 = &log.records[0];
        let start = MotionState::at_rest(r0.x_cmd_um, r0.y_cmd_um);
        let mut sim = StageSimulator::new(model, start, 1).unwrap();
        let mut pts = Vec::new();
        let mut diff = Vec::new();
        for r in &log.records {
            let s = sim.move_to(r.x_cmd_um, r.y_cmd_um, r.t_s, r.cycle).unwrap();
            pts.push([r.x_target_um, r.y_target_um]);
            diff.push([
                (s.observed_um.x_um - r.x_cmd_um) - (r.x_meas_um - r.x_target_um),
                (s.observed_um.y_um - r.y_cmd_um) - (r.y_meas_um - r.y_target_um),
            ]);
        }
        [0, 1].map(|c| rigid_rms(&pts, &diff, c))
    };
    let (a, b) = (replay(&without), replay(&with));
    let g = d.grid.as_ref().unwrap();
    eprintln!(
        "MAP-IN-SIM | simulator vs the measured map, rms x / y: named terms only {:.4} / {:.4} µm, with the map {:.4} / {:.4} µm (cell noise {:.4} / {:.4} µm)",
        a[0], a[1], b[0], b[1], g.noise[0].cell_sigma_um, g.noise[1].cell_sigma_um
    );
    for c in 0..2 {
        assert!(b[c] < 0.5 * a[c], "component {c}: {a:?} → {b:?}");
        assert!(
            b[c] < 0.1 * g.noise[c].cell_sigma_um,
            "component {c}: {b:?}"
        );
    }
}
