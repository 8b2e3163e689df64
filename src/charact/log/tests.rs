//! Unit tests of the log reader and writer.

use super::fields::*;
use super::read::*;
use super::write::*;
use super::*;

#[test]
fn split_fields_handles_spaces_and_quotes() {
    let f = split_fields(" a , b,\"c, d\" ,\"e\"\"f\",,").unwrap();
    assert_eq!(f, vec!["a", "b", "c, d", "e\"f", "", ""]);
    assert_eq!(split_fields("").unwrap(), vec![""]);
    assert_eq!(
        split_fields("a,\"b"),
        Err(LineError::BadQuoting("quoted field is not closed"))
    );
    assert!(matches!(
        split_fields("\"a\"b,c"),
        Err(LineError::BadQuoting(_))
    ));
}

#[test]
fn push_field_quotes_only_what_the_reader_would_change() {
    for v in [
        "plain",
        "a,b",
        "say \"hi\"",
        " lead",
        "trail\t",
        "#x",
        "",
        "é ü",
    ] {
        let mut s = String::new();
        push_field(&mut s, v);
        assert_eq!(split_fields(&s).unwrap(), vec![v], "{s:?}");
    }
    let mut s = String::new();
    push_field(&mut s, "plain");
    assert_eq!(s, "plain");
}

#[test]
fn metadata_lines() {
    assert_eq!(
        parse_metadata_line("stage: M-111"),
        Some(("stage", "M-111"))
    );
    assert_eq!(parse_metadata_line("rate = 2 Hz"), Some(("rate", "2 Hz")));
    assert_eq!(
        parse_metadata_line("start:12:30:00"),
        Some(("start", "12:30:00"))
    );
    assert_eq!(parse_metadata_line("k=a:b"), Some(("k", "a:b")));
    assert_eq!(parse_metadata_line("Created at 12:30"), None);
    assert_eq!(parse_metadata_line("just words"), None);
    assert_eq!(parse_metadata_line(": empty key"), None);
}

#[test]
fn metadata_keeps_order_and_replaces_in_place() {
    let mut m = Metadata::new();
    assert_eq!(m.insert("b", "1"), None);
    assert_eq!(m.insert("a", "2"), None);
    assert_eq!(m.insert("b", "3"), Some("1".into()));
    assert_eq!(m.iter().collect::<Vec<_>>(), vec![("b", "3"), ("a", "2")]);
    assert_eq!(m.get("a"), Some("2"));
    assert_eq!(m.get("c"), None);
    assert_eq!(m.len(), 2);
}

#[test]
fn header_rules() {
    let h = |s: &str| parse_header(&split_fields(s).unwrap());
    let base = MANDATORY_COLUMNS.join(",");
    assert_eq!(h(&base).unwrap(), Columns::default());
    assert_eq!(
        h(&format!("{base},temp_c,focus,\"note, free\"")).unwrap(),
        Columns {
            temp_c: true,
            theta_urad: false,
            extra: vec!["focus".into(), "note, free".into()]
        }
    );
    assert_eq!(
        h(&format!("{base},focus,temp_c")),
        Err(LineError::MisplacedTemp { position: 11 })
    );
    assert!(matches!(
        h(&format!("{base},a,a")),
        Err(LineError::BadExtraColumn { position: 11, .. })
    ));
    assert!(matches!(
        h(&format!("{base},,a")),
        Err(LineError::BadExtraColumn { position: 10, .. })
    ));
    assert!(matches!(
        h(&format!("{base},t_s")),
        Err(LineError::BadExtraColumn { .. })
    ));
    assert_eq!(
        h("t_s,segment,cycle,y_target_um"),
        Err(LineError::BadHeader {
            position: 4,
            expected: "x_target_um",
            found: "y_target_um".into()
        })
    );
    assert!(matches!(
        h("t_s,segment"),
        Err(LineError::BadHeader { position: 3, .. })
    ));
}

#[test]
fn writer_refuses_what_it_could_not_read_back() {
    let rec = Record {
        t_s: 0.0,
        segment: "scan_x".into(),
        cycle: 1,
        x_target_um: 0.0,
        y_target_um: 0.0,
        x_cmd_um: 0.0,
        y_cmd_um: 0.0,
        x_meas_um: 0.0,
        y_meas_um: 0.0,
        temp_c: None,
        theta_urad: None,
        extra: vec![],
    };
    let mut w = LogWriter::create(
        Vec::new(),
        &Metadata::new(),
        Columns::default(),
        SyncPolicy::default(),
    )
    .unwrap();
    w.append(&rec).unwrap();
    for bad in [
        Record {
            x_meas_um: f64::NAN,
            ..rec.clone()
        },
        Record {
            t_s: 2e9,
            ..rec.clone()
        },
        Record {
            segment: " ".into(),
            ..rec.clone()
        },
        Record {
            segment: "a\nb".into(),
            ..rec.clone()
        },
        Record {
            temp_c: Some(20.0),
            ..rec.clone()
        },
        Record {
            extra: vec!["x".into()],
            ..rec.clone()
        },
    ] {
        assert!(
            matches!(w.append(&bad), Err(LogError::InvalidRecord { .. })),
            "{bad:?}"
        );
    }
    assert_eq!(w.records(), 1);

    for (k, v) in [
        ("a b", "x"),
        ("", "x"),
        ("k:", "x"),
        ("k", " x"),
        ("k", "x\ny"),
        ("format", "other/2"),
    ] {
        let mut m = Metadata::new();
        m.insert(k, v);
        assert!(
            matches!(
                LogWriter::create(Vec::new(), &m, Columns::default(), SyncPolicy::default()),
                Err(LogError::InvalidMetadata { .. })
            ),
            "{k:?}: {v:?}"
        );
    }
    assert!(Columns::new(false, vec!["temp_c".into()]).is_err());
    assert!(Columns::new(false, vec!["a".into(), "a".into()]).is_err());
    assert!(Columns::new(false, vec!["a\tb".into()]).is_err());
}

/// A sink that fails after `budget` bytes, like a full disk.
struct FullDisk {
    written: Vec<u8>,
    budget: usize,
}
impl Write for FullDisk {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        if self.budget == 0 {
            return Err(io::Error::new(io::ErrorKind::StorageFull, "disk full"));
        }
        let n = buf.len().min(self.budget);
        self.written.extend_from_slice(&buf[..n]);
        self.budget -= n;
        Ok(n)
    }
    fn flush(&mut self) -> io::Result<()> {
        Ok(())
    }
}
impl LogSink for FullDisk {
    fn sync_data(&mut self) -> io::Result<()> {
        Ok(())
    }
}

#[test]
fn a_failed_write_poisons_the_writer() {
    let header_len = format!(
        "# {FORMAT_KEY}: {FORMAT_ID}\n{}\n",
        Columns::default().header_line()
    )
    .len();
    let sink = FullDisk {
        written: Vec::new(),
        budget: header_len + 10,
    };
    let mut w = LogWriter::create(
        sink,
        &Metadata::new(),
        Columns::default(),
        SyncPolicy::FlushOnly,
    )
    .unwrap();
    let rec = Record {
        t_s: 1.0,
        segment: "s".into(),
        cycle: 0,
        x_target_um: 1.0,
        y_target_um: 2.0,
        x_cmd_um: 3.0,
        y_cmd_um: 4.0,
        x_meas_um: 5.0,
        y_meas_um: 6.0,
        temp_c: None,
        theta_urad: None,
        extra: vec![],
    };
    assert!(matches!(w.append(&rec), Err(LogError::Io(_))));
    assert!(matches!(w.append(&rec), Err(LogError::Poisoned)));
    assert!(matches!(w.sync(), Err(LogError::Poisoned)));
    // What reached the "disk" is a header and a torn line, which the
    // reader reports as such.
    let bytes = w.into_inner().written;
    let log = parse_bytes(&bytes).unwrap();
    assert!(log.records.is_empty());
    assert_eq!(log.torn_tail.unwrap().line, 3);
}

/// The optional `theta_urad` column: after `temp_c`, before the extras; an
/// empty cell is `None`; it round-trips at 0.01 µrad; a log without it
/// (every log before it existed) reads with `None`; misplaced or repeated
/// as an extra it is an error, and a writer without it refuses a θ rather
/// than drop it.
#[test]
fn the_theta_column_is_optional_and_round_trips() {
    let h = |s: &str| parse_header(&split_fields(s).unwrap());
    let base = MANDATORY_COLUMNS.join(",");
    let both = Columns::new(true, vec!["q".into()])
        .unwrap()
        .with_theta(true);
    assert_eq!(h(&format!("{base},temp_c,theta_urad,q")).unwrap(), both);
    assert_eq!(
        h(&format!("{base},theta_urad")).unwrap(),
        Columns::default().with_theta(true)
    );
    assert_eq!(
        h(&format!("{base},theta_urad,temp_c")),
        Err(LineError::MisplacedTemp { position: 11 })
    );
    assert_eq!(
        h(&format!("{base},q,theta_urad")),
        Err(LineError::MisplacedTheta { position: 11 })
    );
    assert!(Columns::new(false, vec![THETA_COLUMN.into()]).is_err());

    let rec = |theta_urad: Option<f64>| Record {
        t_s: 1.5,
        segment: "scan_x".into(),
        cycle: 1,
        x_target_um: 10.0,
        y_target_um: 0.0,
        x_cmd_um: 10.0,
        y_cmd_um: 0.0,
        x_meas_um: 10.1,
        y_meas_um: -0.2,
        temp_c: Some(21.5),
        theta_urad,
        extra: vec!["7".into()],
    };
    let mut w = LogWriter::create(
        Vec::new(),
        &Metadata::new(),
        both.clone(),
        SyncPolicy::default(),
    )
    .unwrap();
    w.append(&rec(Some(-123.456_789))).unwrap();
    w.append(&rec(None)).unwrap();
    let bytes = w.into_inner();
    let text = String::from_utf8(bytes.clone()).unwrap();
    assert!(
        text.contains(",21.500,-123.46,7\n") && text.contains(",21.500,,7\n"),
        "{text}"
    );
    let log = parse_bytes(&bytes).unwrap();
    assert_eq!(log.columns, both);
    assert_eq!(log.records[0].theta_urad, Some(-123.46));
    assert_eq!(log.records[1].theta_urad, None);
    assert_eq!(log.records[0].extra, vec!["7".to_owned()]);

    // An old log: no column, no value.
    let old = format!("{base},temp_c\n0,s,1,0,0,0,0,0,0,20\n");
    let log = parse_bytes(old.as_bytes()).unwrap();
    assert!(!log.columns.theta_urad && log.records[0].theta_urad.is_none());
    // A value that is no number is an error naming the column.
    let bad = format!("{base},theta_urad\n0,s,1,0,0,0,0,0,0,x\n");
    let e = parse_bytes(bad.as_bytes()).unwrap_err().to_string();
    assert!(e.contains("theta_urad"), "{e}");

    let plain = Columns::new(true, vec!["q".into()]).unwrap();
    let mut w =
        LogWriter::create(Vec::new(), &Metadata::new(), plain, SyncPolicy::default()).unwrap();
    let e = w.append(&rec(Some(1.0))).unwrap_err().to_string();
    assert!(e.contains("theta_urad"), "{e}");
    w.append(&rec(None)).unwrap();
}
