//! Crash safety of the measurement log: resuming a job with `open_append`
//! after a clean stop, after a torn last line, and after a crash at every
//! possible byte.

use std::fs;
use std::io::Write;

use micropos::charact::log::{
    create_file, open_append, read_file, Columns, LineError, LogError, Metadata, Record, SyncPolicy,
};

fn columns() -> Columns {
    Columns::new(true, vec!["focus".into()]).unwrap()
}

/// Records whose values are exact at the written precision, so that reading
/// back compares with `==`.
fn records(n: usize) -> Vec<Record> {
    (0..n)
        .map(|i| {
            let x = i as f64 * 12.5 - 100.0;
            Record {
                t_s: i as f64 * 0.25,
                segment: if i < n / 2 { "scan_x" } else { "scan_y" }.into(),
                cycle: (i % 3) as u32,
                x_target_um: x,
                y_target_um: -x,
                x_cmd_um: x + 0.0625,
                y_cmd_um: -x - 0.0625,
                x_meas_um: x + 1.5,
                y_meas_um: -x - 0.75,
                temp_c: (i % 2 == 0).then_some(21.125),
                theta_urad: None,
                extra: vec![format!("{i}")],
            }
        })
        .collect()
}

fn metadata() -> Metadata {
    let mut m = Metadata::new();
    m.insert("job", "characterize-x");
    m
}

fn write_log(path: &std::path::Path, recs: &[Record]) {
    let mut w = create_file(path, &metadata(), columns(), SyncPolicy::default()).unwrap();
    for r in recs {
        w.append(r).unwrap();
    }
}

#[test]
fn clean_resume_continues_after_the_last_record() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("job.csv");
    let all = records(6);
    write_log(&path, &all[..4]);

    let (mut w, resume) = open_append(&path, &columns(), SyncPolicy::default()).unwrap();
    assert_eq!(resume.records, 4);
    assert_eq!(resume.last_record.as_ref(), Some(&all[3]));
    assert_eq!(resume.repaired, None);
    assert_eq!(resume.metadata.get("job"), Some("characterize-x"));
    assert_eq!(w.records(), 4);
    for r in &all[4..] {
        w.append(r).unwrap();
    }
    w.sync().unwrap();
    drop(w);

    let log = read_file(&path).unwrap();
    assert_eq!(log.records, all);
    assert!(log.is_complete() && log.warnings.is_empty());
}

#[test]
fn create_refuses_to_overwrite_a_previous_log() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("job.csv");
    write_log(&path, &records(2));
    let e = create_file(&path, &metadata(), columns(), SyncPolicy::default())
        .err()
        .unwrap();
    assert!(
        matches!(&e, LogError::Io(io) if io.kind() == std::io::ErrorKind::AlreadyExists),
        "{e}"
    );
    assert_eq!(read_file(&path).unwrap().records.len(), 2);
}

#[test]
fn torn_line_is_cut_and_the_point_written_once() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("job.csv");
    let all = records(5);
    write_log(&path, &all[..3]);
    let before = fs::metadata(&path).unwrap().len();
    // A crash in the middle of writing record 3.
    fs::OpenOptions::new()
        .append(true)
        .open(&path)
        .unwrap()
        .write_all(b"0.750000,scan_y,0,-62.50")
        .unwrap();

    let log = read_file(&path).unwrap();
    assert_eq!(log.records, all[..3]);
    assert_eq!(log.torn_tail.as_ref().unwrap().line, 7);

    let (mut w, resume) = open_append(&path, &columns(), SyncPolicy::default()).unwrap();
    let repaired = resume.repaired.unwrap();
    assert_eq!(repaired.line, 7);
    assert_eq!(repaired.offset, before);
    assert_eq!(repaired.len, 24);
    assert!(matches!(
        repaired.error,
        Some(LineError::WrongColumnCount { .. })
    ));
    assert_eq!(resume.records, 3);
    assert_eq!(resume.last_record.as_ref(), Some(&all[2]));
    assert_eq!(fs::metadata(&path).unwrap().len(), before);
    for r in &all[3..] {
        w.append(r).unwrap();
    }
    drop(w);
    let log = read_file(&path).unwrap();
    assert_eq!(log.records, all);
    assert!(log.is_complete() && log.warnings.is_empty());
}

#[test]
fn an_unterminated_record_is_dropped_and_measured_again() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("job.csv");
    let all = records(4);
    write_log(&path, &all);
    // The record's bytes reached the disk, its newline did not. Its last
    // number might be cut short, so it is not trusted.
    let len = fs::metadata(&path).unwrap().len();
    fs::OpenOptions::new()
        .write(true)
        .open(&path)
        .unwrap()
        .set_len(len - 1)
        .unwrap();

    let (mut w, resume) = open_append(&path, &columns(), SyncPolicy::default()).unwrap();
    let repaired = resume.repaired.unwrap();
    assert_eq!(repaired.error, None);
    assert_eq!(repaired.line, 7);
    assert_eq!(resume.records, 3);
    assert_eq!(resume.last_record.as_ref(), Some(&all[2]));
    assert!(resume.warnings.is_empty(), "{:?}", resume.warnings);
    w.append(&all[3]).unwrap();
    drop(w);
    assert_eq!(read_file(&path).unwrap().records, all);
}

#[test]
fn unterminated_blanks_are_cut_without_losing_a_record() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("job.csv");
    let all = records(3);
    write_log(&path, &all);
    fs::OpenOptions::new()
        .append(true)
        .open(&path)
        .unwrap()
        .write_all(b"  ")
        .unwrap();
    let (_, resume) = open_append(&path, &columns(), SyncPolicy::default()).unwrap();
    assert_eq!(resume.records, 3);
    assert_eq!(resume.last_record.as_ref(), Some(&all[2]));
    assert_eq!(resume.repaired.unwrap().len, 2);
}

#[test]
fn wrong_columns_or_a_corrupt_middle_refuse_to_resume() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("job.csv");
    write_log(&path, &records(3));
    let other = Columns::new(false, vec![]).unwrap();
    let e = open_append(&path, &other, SyncPolicy::default())
        .err()
        .unwrap();
    assert!(matches!(e, LogError::ColumnsMismatch { .. }), "{e}");

    let text = fs::read_to_string(&path).unwrap();
    let broken = text.replacen("scan_y,1,", "scan_y,one,", 1);
    assert_ne!(broken, text);
    fs::write(&path, broken).unwrap();
    let e = open_append(&path, &columns(), SyncPolicy::default())
        .err()
        .unwrap();
    assert_eq!(
        e.to_string(),
        "line 5: column cycle: \"one\" is not a non-negative integer"
    );
}

/// Simulates a crash after every byte of the file: whatever prefix survives,
/// either `open_append` refuses it (the header itself is incomplete: nothing
/// was measured yet) or the job resumes and the finished log holds every
/// record exactly once.
#[test]
fn resume_after_a_crash_at_any_byte_keeps_every_point_once() {
    let dir = tempfile::tempdir().unwrap();
    let full_path = dir.path().join("full.csv");
    let all = records(5);
    write_log(&full_path, &all);
    let full = fs::read(&full_path).unwrap();
    let header_end = full.windows(10).position(|w| w == b"focus\n0.00").unwrap() + "focus\n".len();

    let path = dir.path().join("crashed.csv");
    for cut in 0..=full.len() {
        fs::write(&path, &full[..cut]).unwrap();
        match open_append(&path, &columns(), SyncPolicy::FlushOnly) {
            Err(e) => {
                // Only a log without its complete header line may be refused.
                assert!(cut < header_end - 1, "cut at {cut}: {e}");
            }
            Ok((mut w, resume)) => {
                assert!(cut >= header_end - 1, "cut at {cut} accepted");
                let done = resume.records as usize;
                assert_eq!(
                    resume.last_record.as_ref(),
                    done.checked_sub(1).map(|i| &all[i])
                );
                for r in &all[done..] {
                    w.append(r).unwrap();
                }
                drop(w);
                let log = read_file(&path).unwrap();
                assert_eq!(log.records, all, "cut at {cut}");
                assert!(log.is_complete() && log.warnings.is_empty(), "cut at {cut}");
                assert_eq!(fs::read(&path).unwrap(), full, "cut at {cut}");
            }
        }
    }
}
