//! Model files: the documented default loads, round-trips, names every key
//! it may hold, and bad files are rejected with errors naming the key.

use micropos::model::{StageModel, TermRegistry, PAPER_DEFAULT_TOML};

fn err(text: &str) -> String {
    match StageModel::from_toml(text) {
        Ok(_) => panic!("accepted:\n{text}"),
        Err(e) => {
            println!("{e}");
            e.to_string()
        }
    }
}

/// The default file with `from` replaced by `to` (must occur once).
fn edit(from: &str, to: &str) -> String {
    assert_eq!(PAPER_DEFAULT_TOML.matches(from).count(), 1, "{from}");
    PAPER_DEFAULT_TOML.replace(from, to)
}

#[test]
fn default_file_round_trips_through_to_toml() {
    let m = StageModel::paper_default().unwrap();
    let text = m.to_toml().unwrap();
    let back = StageModel::from_toml(&text).unwrap();
    assert_eq!(back.params(), m.params());
    assert_eq!(back.to_toml().unwrap(), text);
    // Every built-in kind appears in a shipped, documented file: the
    // default, or for the stacked stage's yaw, which the documented stage
    // does not have, config/stage-model-stacked.toml.
    let stacked =
        StageModel::from_toml(include_str!("../../config/stage-model-stacked.toml")).unwrap();
    let kinds: Vec<&str> = m
        .terms()
        .iter()
        .chain(stacked.terms())
        .map(|t| t.kind())
        .collect();
    for (kind, _) in TermRegistry::builtin().kinds() {
        assert!(
            kinds.contains(&kind),
            "no shipped model file has a `{kind}` term"
        );
    }
}

#[test]
fn every_parameter_has_unit_and_doc() {
    let m = StageModel::paper_default().unwrap();
    for p in m.params() {
        assert!(!p.info.unit.is_empty(), "{}", p.full_name);
        assert!(p.info.doc.len() > 10, "{}", p.full_name);
        assert!(p.info.value.is_finite(), "{}", p.full_name);
    }
}

#[test]
fn unknown_keys_are_named() {
    let e = err(&edit(
        "backlash_um = 2.0",
        "backlash_um = 2.0\nbacklash_mm = 0.002",
    ));
    assert!(e.contains("backlash_mm") && e.contains("x_backlash"), "{e}");
    let e = err(&edit("[stochastic]", "[stochastic]\nsigma = 1.0"));
    assert!(e.contains("sigma"), "{e}");
    let e = err(&format!("{PAPER_DEFAULT_TOML}\nextra = 1\n"));
    assert!(e.contains("extra"), "{e}");
    let e = err(&edit(
        "arm_z_um = 25000.0                 # µm, pattern height above the x drive line",
        "arm_z_um = 25000.0\narm_y_um = 3.0",
    ));
    assert!(e.contains("arm_y_um"), "{e}");
}

#[test]
fn bad_values_are_named() {
    let e = err(&edit("backlash_um = 1.8", "backlash_um = -1.8"));
    assert!(e.contains("backlash_um") && e.contains("y_backlash"), "{e}");
    let e = err(&edit("angle_urad = 5300.0", "angle_urad = nan"));
    assert!(e.contains("angle_urad"), "{e}");
    let e = err(&edit("ppm = 150.0", "ppm = inf"));
    assert!(e.contains("ppm"), "{e}");
    let e = err(&edit("ppm = 150.0", "ppm = \"lots\""));
    assert!(e.contains("ppm = \"lots\""), "{e}");
    let e = err(&edit(
        "min_incremental_motion_um = 0.05",
        "min_incremental_motion_um = -0.05",
    ));
    assert!(e.contains("stochastic.min_incremental_motion_um"), "{e}");
    let e = err(&edit(
        "{ time_s = 34200.0, temp_c = 20.5 }",
        "{ time_s = 0.0, temp_c = 20.5 }",
    ));
    assert!(e.contains("environment.temperature[1].time_s"), "{e}");
    let e = err(&edit(
        "forward_sin_um = [1.60, 0.35, 0.0]   # µm, harmonics 1..3, after forward motion",
        "forward_sin_um = [1.60, 0.35]",
    ));
    assert!(
        e.contains("x_cyclic") && e.contains("forward_cos_um"),
        "{e}"
    );
    let e = err(&edit(
        "period_um = 400.0                  # screw lead P, µm",
        "period_um = 0.0",
    ));
    assert!(e.contains("period_um"), "{e}");
    let e = err(&edit(
        "axis = \"x\"                         # moving axis (sets the phase), error along it",
        "axis = \"z\"",
    ));
    assert!(e.contains("x_cyclic"), "{e}");
}

#[test]
fn structural_errors_are_named() {
    let e = err(&edit("kind = \"squareness\"", "kind = \"squarenes\""));
    assert!(e.contains("squarenes") && e.contains("known"), "{e}");
    let e = err(&edit("name = \"y_lead\"", "name = \"x_lead\""));
    assert!(e.contains("x_lead"), "{e}");
    let e = err(&edit("kind = \"squareness\"\n", ""));
    assert!(e.contains("term[6].kind"), "{e}");
    let e = err(&edit("name = \"squareness\"", "name = \"a.b\""));
    assert!(e.contains("a.b"), "{e}");
    let e = err(&edit("format_version = 1", "format_version = 2"));
    assert!(e.contains("format_version"), "{e}");
    let e = err("format_version = 1\n[[term]]\nkind = \"backlash\"\nname = \"b\"\naxis = \"x\"\n");
    assert!(e.contains("backlash_um"), "{e}");
    assert!(StageModel::from_toml("this is not toml").is_err());
}

#[test]
fn minimal_file_defaults_to_an_ideal_stage() {
    let m = StageModel::from_toml("format_version = 1\n").unwrap();
    assert!(m.terms().is_empty());
    assert_eq!(m.stochastic().repeatability_sigma_um, [0.0, 0.0]);
    let text = m.to_toml().unwrap();
    assert!(StageModel::from_toml(&text).is_ok());
}

#[test]
fn written_file_is_readable() {
    let text = StageModel::paper_default().unwrap().to_toml().unwrap();
    println!("{text}");
    assert!(text.contains("[[term]]") && text.contains("kind = \"backlash\""));
}

#[test]
fn describe_default() {
    let d = StageModel::paper_default().unwrap().describe();
    println!("{d}");
    assert!(d.lines().count() > 80);
}

/// The stacked stage is the documented one plus its `stacked_yaw` term,
/// nothing else: the two files cannot drift apart.
#[test]
fn the_stacked_stage_is_the_default_plus_its_yaw() {
    let dir = env!("CARGO_MANIFEST_DIR");
    let read = |f: &str| {
        let text = std::fs::read_to_string(format!("{dir}/config/{f}")).unwrap();
        StageModel::from_toml(&text).unwrap()
    };
    let base = read("stage-model.toml");
    let stacked = read("stage-model-stacked.toml");
    let names = |m: &StageModel| {
        m.terms()
            .iter()
            .map(|t| t.name().to_owned())
            .collect::<Vec<_>>()
    };
    let mut want = names(&base);
    want.push("x_carriage_yaw".to_owned());
    assert_eq!(names(&stacked), want);
    assert_eq!(stacked.terms().last().unwrap().kind(), "stacked_yaw");
    let values = |m: &StageModel| {
        m.params()
            .into_iter()
            .map(|p| (p.full_name, p.info.value))
            .collect::<Vec<_>>()
    };
    let (b, s) = (values(&base), values(&stacked));
    assert_eq!(b, s[..b.len()]);
}
