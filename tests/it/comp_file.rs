//! Compensation files: round trips through paths and readers, clear errors
//! naming the key, no panic on arbitrary text (proptest; the fuzz target
//! `comp_table` does the same at scale).

use micropos::charact::log::Record;
use micropos::charact::scan::{AxisScan, CharacterizationPlan};
use micropos::comp::{
    compensation_template, fnv1a64_hex, CompFile, CompKind, CompTable, MotionHistory, PlanOptions,
    SourceInfo, TableBuildOptions, VisionFrame,
};
use micropos::model::{MotionState, StageModel, StageSimulator, XyUm};
use proptest::prelude::*;

fn coarse_log() -> Vec<Record> {
    let mut sim = StageSimulator::new(
        StageModel::paper_default().unwrap(),
        MotionState::at_rest(7500.0, 7500.0),
        5,
    )
    .unwrap();
    let plan = CharacterizationPlan {
        x: AxisScan {
            step_um: 250.0,
            cycles: 1,
            ..AxisScan::paper_x()
        },
        y: AxisScan {
            step_um: 250.0,
            cycles: 1,
            ..AxisScan::paper_y()
        },
    };
    let mut out = Vec::new();
    for (i, p) in plan.points().unwrap().into_iter().enumerate() {
        let s = sim
            .move_to(p.target.x_um, p.target.y_um, i as f64, p.cycle)
            .unwrap();
        if p.logged {
            out.push(Record {
                t_s: i as f64,
                segment: p.segment,
                cycle: p.cycle,
                x_target_um: p.target.x_um,
                y_target_um: p.target.y_um,
                x_cmd_um: p.target.x_um,
                y_cmd_um: p.target.y_um,
                x_meas_um: s.observed_um.x_um,
                y_meas_um: s.observed_um.y_um,
                temp_c: None,
                theta_urad: None,
                extra: Vec::new(),
            });
        }
    }
    out
}

fn lookup_file() -> CompFile {
    let (table, _) = CompTable::from_records(&coarse_log(), &TableBuildOptions::default()).unwrap();
    let mut src = SourceInfo {
        log_path: Some("runs/2024-01-01/char.csv".into()),
        log_fnv1a64: Some(fnv1a64_hex(b"the log bytes")),
        records: 123,
        ..SourceInfo::default()
    };
    src.metadata.insert("operator".into(), "tester".into());
    let mut f = CompFile::lookup(table, "2024-01-01T12:00:00Z", src);
    f.description = "coarse test table".into();
    f.frame = Some(VisionFrame {
        rotation_rad: 0.01,
        mirrored: true,
        translation_um: [3.0, -4.0],
    });
    f
}

#[test]
fn lookup_and_model_files_round_trip_through_paths() {
    let dir = tempfile::tempdir().unwrap();
    let f = lookup_file();
    let p = dir.path().join("table.toml");
    f.write_path(&p).unwrap();
    let back = CompFile::read_path(&p).unwrap();
    assert_eq!(back, f);
    assert_eq!(back.kind, CompKind::Lookup);

    let model = compensation_template(&StageModel::paper_default().unwrap()).unwrap();
    let m = CompFile::model(&model, "2024-01-01T12:00:00Z", SourceInfo::default()).unwrap();
    let mut buf = Vec::new();
    m.write_to(&mut buf).unwrap();
    let back = CompFile::read_from(&buf[..]).unwrap();
    assert_eq!(back, m);
    assert_eq!(
        back.stage_model().unwrap().parameter_vector(),
        model.parameter_vector()
    );

    // Both compensators answer.
    let h = MotionHistory::new(MotionState::at_rest(0.0, 0.0), 0.0).unwrap();
    for file in [&f, &m] {
        let c = file.compensator().unwrap();
        let plan = c
            .command_for(XyUm::from([1234.0, 567.0]), &h, &PlanOptions::default())
            .unwrap();
        assert!(plan.cmd.x_um.is_finite());
    }
    let e = CompFile::read_path(dir.path().join("missing.toml")).unwrap_err();
    assert!(e.to_string().contains("missing.toml"), "{e}");
}

#[test]
fn defects_are_errors_that_name_the_key() {
    let text = lookup_file().to_toml().unwrap();
    let cases = [
        (
            text.replacen("positions_um = [0.0, ", "positions_um = [300.0, ", 1),
            "strictly increasing",
        ),
        (
            text.replacen(
                "interpolation = \"linear\"",
                "interpolation = \"quintic\"",
                1,
            ),
            "quintic",
        ),
        (
            text.replacen("kind = \"lookup\"", "kind = \"model\"", 1),
            "[model]",
        ),
        (
            text.replacen("delta_x_slope = ", "delta_x_slope = 1.0 #", 1),
            "delta_x_slope",
        ),
        (
            text.replacen("records = 123", "records = 123\nsurprise = 1", 1),
            "surprise",
        ),
        (
            text.replacen("log_fnv1a64 = \"", "log_fnv1a64 = \"zz", 1),
            "log_fnv1a64",
        ),
    ];
    for (bad, needle) in cases {
        assert_ne!(bad, text, "case {needle} did not change the text");
        let e = CompFile::from_toml(&bad).unwrap_err();
        assert!(e.to_string().contains(needle), "{needle}: {e}");
    }
    let e = CompFile::from_bytes(&[0xff, 0xfe]).unwrap_err();
    assert!(e.to_string().contains("UTF-8"), "{e}");
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]
    #[test]
    fn arbitrary_text_never_panics(s in "\\PC{0,400}") {
        let _ = CompFile::from_toml(&s);
    }

    #[test]
    fn mangled_files_never_panic(cut in 0usize..4000, byte in any::<u8>()) {
        let mut bytes = lookup_file().to_toml().unwrap().into_bytes();
        let i = cut % bytes.len();
        bytes[i] = byte;
        if let Ok(f) = CompFile::from_bytes(&bytes) {
            let _ = f.compensator();
        }
        bytes.truncate(i);
        let _ = CompFile::from_bytes(&bytes);
    }
}
