//! The measurement log format: round trip, files written by other programs,
//! malformed files.

use micropos::charact::log::{
    parse_bytes, read_file, Columns, LineError, LogError, LogWriter, Metadata, Record, SyncPolicy,
    WarningKind, FORMAT_ID, MANDATORY_COLUMNS,
};

fn record(t_s: f64, segment: &str, cycle: u32, x: f64, y: f64) -> Record {
    Record {
        t_s,
        segment: segment.into(),
        cycle,
        x_target_um: x,
        y_target_um: y,
        x_cmd_um: x + 0.5,
        y_cmd_um: y - 0.25,
        x_meas_um: x - 1.23456,
        y_meas_um: y + 0.00004,
        temp_c: Some(21.5),
        theta_urad: None,
        extra: vec!["0.93".into(), "a, \"b\"".into()],
    }
}

#[test]
fn round_trip_keeps_everything_at_the_written_precision() {
    let mut meta = Metadata::new();
    meta.insert("stage", "M-111.1DG #0123");
    meta.insert("pattern_period_um", "4");
    let columns = Columns::new(true, vec!["focus".into(), "note".into()]).unwrap();
    let mut w =
        LogWriter::create(Vec::new(), &meta, columns.clone(), SyncPolicy::default()).unwrap();
    let mut records = vec![
        record(0.0, "scan_x", 0, 0.0, 0.0),
        record(1.0000004, "scan_x", 0, 5.0, 0.0),
        record(2.5, "square", 1, -4000.12345, 4010.0),
    ];
    records[1].temp_c = None;
    records[2].extra = vec![String::new(), " spaced ".into()];
    for r in &records {
        w.append(r).unwrap();
    }
    assert_eq!(w.records(), 3);
    let bytes = w.into_inner();
    let text = String::from_utf8(bytes.clone()).unwrap();
    let mut lines = text.lines();
    assert_eq!(
        lines.next(),
        Some(format!("# format: {FORMAT_ID}").as_str())
    );
    assert_eq!(lines.next(), Some("# stage: M-111.1DG #0123"));
    assert_eq!(lines.next(), Some("# pattern_period_um: 4"));
    assert_eq!(
        lines.next(),
        Some(format!("{},temp_c,focus,note", MANDATORY_COLUMNS.join(",")).as_str())
    );
    // Positions with 4 decimals (0.1 nm), time with 6 (1 µs), temperature 3.
    assert_eq!(
        lines.next(),
        Some("0.000000,scan_x,0,0.0000,0.0000,0.5000,-0.2500,-1.2346,0.0000,21.500,0.93,\"a, \"\"b\"\"\"")
    );
    assert_eq!(
        lines.next(),
        Some("1.000000,scan_x,0,5.0000,0.0000,5.5000,-0.2500,3.7654,0.0000,,0.93,\"a, \"\"b\"\"\"")
    );

    let log = parse_bytes(&bytes).unwrap();
    assert!(log.is_complete());
    assert!(log.warnings.is_empty(), "{:?}", log.warnings);
    assert_eq!(log.columns, columns);
    assert_eq!(log.metadata.get("format"), Some(FORMAT_ID));
    assert_eq!(log.metadata.get("stage"), Some("M-111.1DG #0123"));
    assert_eq!(log.records.len(), 3);
    for (got, want) in log.records.iter().zip(&records) {
        assert_eq!(got.segment, want.segment);
        assert_eq!(got.cycle, want.cycle);
        assert_eq!(got.extra, want.extra);
        assert_eq!(got.temp_c, want.temp_c);
        assert!((got.t_s - want.t_s).abs() <= 0.5e-6 + 1e-12);
        for (g, w) in [
            (got.x_target_um, want.x_target_um),
            (got.y_target_um, want.y_target_um),
            (got.x_cmd_um, want.x_cmd_um),
            (got.y_cmd_um, want.y_cmd_um),
            (got.x_meas_um, want.x_meas_um),
            (got.y_meas_um, want.y_meas_um),
        ] {
            assert!((g - w).abs() <= 0.5e-4 + 1e-9, "{g} vs {w}");
        }
    }
    // Writing what was read gives the same bytes: the format is a fixed point.
    let mut w2 = LogWriter::create(
        Vec::new(),
        &log.metadata,
        log.columns.clone(),
        SyncPolicy::FlushOnly,
    )
    .unwrap();
    for r in &log.records {
        w2.append(r).unwrap();
    }
    assert_eq!(w2.into_inner(), bytes);
}

#[test]
fn error_sign_is_target_minus_measured() {
    let r = record(0.0, "s", 0, 100.0, -50.0);
    // x_meas = 100 − 1.23456, so the stage fell short by 1.23456 µm: +1.23456.
    assert!((r.error_x_um() - 1.23456).abs() < 1e-12);
    assert!((r.error_y_um() + 0.00004).abs() < 1e-12);
}

#[test]
fn reads_a_file_written_by_another_program_with_extra_columns() {
    let log = read_file("tests/data/logs/foreign_extra_columns.csv").unwrap();
    assert!(log.is_complete());
    assert_eq!(
        log.metadata.iter().collect::<Vec<_>>(),
        vec![
            ("operator", "A. N. Other"),
            ("stage", "PI M-111.1DG, serial 0123"),
            ("objective", "10x"),
        ]
    );
    assert_eq!(
        log.comments,
        vec![
            "Exported by a lab's own acquisition script (not micropos)",
            "Created at 12:30 on a Tuesday"
        ]
    );
    assert!(log.columns.temp_c);
    assert_eq!(log.columns.extra, vec!["focus_score", "note, free text"]);
    assert_eq!(log.records.len(), 4);
    let r = &log.records;
    assert_eq!(r[0].segment, "scan_x");
    assert_eq!((r[0].x_meas_um, r[0].y_meas_um), (0.5, -0.25));
    assert_eq!(r[0].temp_c, Some(21.5));
    assert_eq!(r[0].extra, vec!["0.93", "start"]);
    assert_eq!(r[1].temp_c, None);
    assert_eq!(r[1].extra, vec!["0.91", ""]);
    assert_eq!(r[2].segment, "scan x (fast)");
    assert_eq!(r[2].t_s, 3.0);
    assert_eq!(r[2].x_target_um, 10.0);
    assert_eq!(r[2].extra[1], "quoted, with comma");
    assert_eq!(r[3].cycle, 12);
    assert_eq!(r[3].error_x_um(), -4000.5 - -3999.875);
    assert_eq!(r[3].extra[1], "she said \"ok\"");
    // The duplicate key (line 6) and the clock going back (line 14) are
    // warnings, not errors.
    assert_eq!(log.warnings.len(), 2, "{:?}", log.warnings);
    assert_eq!(log.warnings[0].line, 6);
    assert_eq!(
        log.warnings[0].kind,
        WarningKind::DuplicateMetadataKey {
            key: "operator".into()
        }
    );
    assert_eq!(log.warnings[1].line, 14);
    assert_eq!(
        log.warnings[1].kind,
        WarningKind::TimeWentBackwards {
            previous_s: 3.0,
            t_s: 2.75
        }
    );
}

#[test]
fn reads_crlf_with_bom_and_no_final_newline() {
    let log = read_file("tests/data/logs/foreign_crlf_bom.csv").unwrap();
    assert_eq!(log.metadata.get("software"), Some("LabVIEW 2019"));
    assert_eq!(log.comments, vec!["written on Windows"]);
    assert_eq!(log.columns, Columns::default());
    assert_eq!(log.records.len(), 2);
    assert_eq!(log.records[0].x_meas_um, 3449.1234);
    assert_eq!(log.records[1].y_meas_um, 3969.9999);
    assert_eq!(log.records[1].segment, "random");
    // The last line parses but has no terminator: kept, with a warning.
    assert!(log.is_complete());
    assert_eq!(log.warnings.len(), 1);
    assert_eq!(log.warnings[0].line, 6);
    assert_eq!(log.warnings[0].kind, WarningKind::NoFinalNewline);
}

const HEADER: &str =
    "t_s,segment,cycle,x_target_um,y_target_um,x_cmd_um,y_cmd_um,x_meas_um,y_meas_um";
const GOOD: &str = "0.1,scan_x,1,0,0,0,0,0,0";

fn line_error(text: &str) -> (usize, LineError, String) {
    match parse_bytes(text.as_bytes()) {
        Err(e @ LogError::Line { .. }) => {
            let msg = e.to_string();
            let LogError::Line { line, error } = e else {
                unreachable!()
            };
            (line, error, msg)
        }
        other => panic!("expected a line error for {text:?}, got {other:?}"),
    }
}

#[test]
fn malformed_files_are_rejected_with_line_and_reason() {
    let h = HEADER;
    let g = GOOD;
    let cases: Vec<(String, usize, &str)> = vec![
        (
            format!("# a: b\n{h},temp_c\n{g}\n"),
            3,
            "wrong column count: the header has 10 columns, this line has 9",
        ),
        (
            format!("{h}\n{g}\n{g},extra\n"),
            3,
            "wrong column count: the header has 9 columns, this line has 10",
        ),
        (
            format!("{h}\n{g}\n0.2,scan_x,1,0,0,abc,0,0,0\n"),
            3,
            "column x_cmd_um: \"abc\" is not a number",
        ),
        (
            format!("{h}\n0.2,scan_x,1,0,0,0,0,NaN,0\n"),
            2,
            "column x_meas_um: \"NaN\" is not finite",
        ),
        (
            format!("{h}\n0.2,scan_x,1,0,0,0,0,0,-inf\n"),
            2,
            "column y_meas_um: \"-inf\" is not finite",
        ),
        (
            format!("{h}\n0.2,scan_x,1,0,1e400,0,0,0,0\n"),
            2,
            "column y_target_um: \"1e400\" is not finite",
        ),
        (
            format!("{h}\n0.2,scan_x,1,0,2e9,0,0,0,0\n"),
            2,
            "column y_target_um: \"2e9\" is beyond ±1e9",
        ),
        (
            format!("{h}\n\n0.2, ,1,0,0,0,0,0,0\n"),
            3,
            "column segment is empty",
        ),
        (
            format!("{h}\n0.2,\"\",1,0,0,0,0,0,0\n"),
            2,
            "column segment is empty",
        ),
        (
            format!("{h}\n0.2,s,1.5,0,0,0,0,0,0\n"),
            2,
            "column cycle: \"1.5\" is not a non-negative integer",
        ),
        (
            format!("{h}\n0.2,s,-1,0,0,0,0,0,0\n"),
            2,
            "column cycle: \"-1\" is not a non-negative integer",
        ),
        (
            format!("{h}\n0.2,s,,0,0,0,0,0,0\n"),
            2,
            "column cycle: \"\" is not a non-negative integer",
        ),
        (
            format!("{h}\n,s,1,0,0,0,0,0,0\n"),
            2,
            "column t_s: \"\" is not a number",
        ),
        (
            format!("{h},temp_c\n0.2,s,1,0,0,0,0,0,0,warm\n"),
            2,
            "column temp_c: \"warm\" is not a number",
        ),
        (
            format!("{h}\n0.2,\"s,1,0,0,0,0,0,0\n{g}\n"),
            2,
            "bad quoting: quoted field is not closed",
        ),
        (
            format!("# c\n\n{}\n", h.replace("x_cmd_um", "x_command_um")),
            3,
            "bad header: column 6 must be \"x_cmd_um\", found \"x_command_um\"",
        ),
        (
            format!("{}\n", h.replace("t_s,", "")),
            1,
            "bad header: column 1 must be \"t_s\", found \"segment\"",
        ),
        (
            "0.1,scan_x,1,0,0,0,0,0,0\n".to_string(),
            1,
            "bad header: column 1 must be \"t_s\", found \"0.1\"",
        ),
        (
            format!("{h},focus,temp_c\n"),
            1,
            "bad header: temp_c must be column 10, right after y_meas_um (found at column 11)",
        ),
        (
            format!("{h},cycle\n"),
            1,
            "bad header: column 10 repeats the column name \"cycle\"",
        ),
        (
            format!("{h},,x\n"),
            1,
            "bad header: column 10 has an empty name",
        ),
    ];
    for (text, line, reason) in &cases {
        let (got_line, _, msg) = line_error(text);
        assert_eq!(got_line, *line, "input {text:?}: {msg}");
        // Header errors append the required header to the reason.
        assert!(
            msg.starts_with(&format!("line {line}: {reason}")),
            "input {text:?}: {msg}"
        );
    }

    // Invalid UTF-8 in the middle of the file.
    let mut bytes = format!("{h}\n{g}\n").into_bytes();
    bytes.extend_from_slice(b"0.2,sc\xffan,1,0,0,0,0,0,0\n");
    bytes.extend_from_slice(format!("{g}\n").as_bytes());
    let e = parse_bytes(&bytes).unwrap_err();
    assert_eq!(e.to_string(), "line 3: not valid UTF-8");

    // No header at all.
    for text in ["", "# only: metadata\n\n", "\u{feff}"] {
        let e = parse_bytes(text.as_bytes()).unwrap_err();
        assert!(matches!(e, LogError::MissingHeader { .. }), "{text:?}: {e}");
    }
    let e = parse_bytes(b"# a: b\n# c: d\n").unwrap_err();
    assert!(
        e.to_string()
            .starts_with("no header line (expected one starting with t_s,segment,cycle,"),
        "{e}"
    );
}

#[test]
fn a_torn_last_line_is_reported_not_fatal() {
    let text = format!("{HEADER}\n{GOOD}\n{GOOD}\n0.3,scan_x,1,0,0,0,0,0");
    let log = parse_bytes(text.as_bytes()).unwrap();
    assert_eq!(log.records.len(), 2);
    let torn = log.torn_tail.as_ref().unwrap();
    assert_eq!(torn.line, 4);
    assert_eq!(
        torn.offset as usize,
        HEADER.len() + 1 + 2 * (GOOD.len() + 1)
    );
    assert_eq!(torn.len, "0.3,scan_x,1,0,0,0,0,0".len());
    assert_eq!(
        torn.error,
        LineError::WrongColumnCount {
            expected: 9,
            found: 8
        }
    );
    assert!(!log.is_complete());

    // The same bytes followed by a newline are a malformed file.
    let e = parse_bytes(format!("{text}\n").as_bytes()).unwrap_err();
    assert_eq!(
        e.to_string(),
        "line 4: wrong column count: the header has 9 columns, this line has 8"
    );

    // A power cut can leave a block of zeros instead of text: also torn.
    let mut bytes = format!("{HEADER}\n{GOOD}\n").into_bytes();
    bytes.extend_from_slice(&[0u8; 4096]);
    let log = parse_bytes(&bytes).unwrap();
    assert_eq!(log.records.len(), 1);
    assert_eq!(log.torn_tail.unwrap().len, 4096);
}

#[test]
fn an_overlong_line_is_refused_without_reading_it_whole() {
    let mut bytes = format!("{HEADER}\n").into_bytes();
    bytes.resize(bytes.len() + (2 << 20), b'1');
    let e = parse_bytes(&bytes).unwrap_err();
    assert!(
        matches!(
            e,
            LogError::Line {
                line: 2,
                error: LineError::TooLong
            }
        ),
        "{e}"
    );
}
