//! Property tests of the measurement log: exact round trip at the written
//! precision, and no panic (and a stable re-write) on any input.

use micropos::charact::log::{
    parse_bytes, Columns, LogWriter, MeasurementLog, Metadata, Record, SyncPolicy, WarningKind,
    POSITION_DECIMALS, TEMP_DECIMALS, TIME_DECIMALS,
};
use proptest::prelude::*;

fn config(cases: u32) -> ProptestConfig {
    ProptestConfig {
        cases,
        failure_persistence: None,
        rng_algorithm: proptest::test_runner::RngAlgorithm::ChaCha,
        rng_seed: proptest::test_runner::RngSeed::Fixed(0x6c6f_675f_7072_6f70),
        ..ProptestConfig::default()
    }
}

/// Numbers over the whole accepted range, plus small and exact ones.
fn value(max: f64) -> impl Strategy<Value = f64> {
    prop_oneof![
        -max..max,
        -1.0e4..1.0e4f64,
        (-100_000i32..100_000).prop_map(|i| f64::from(i) * 0.0625),
        Just(0.0),
        Just(-0.0),
    ]
}

/// Free text without control characters (what the writer accepts).
fn text() -> impl Strategy<Value = String> {
    "[a-zA-Z0-9 _,\"#=:.é€-]{0,12}"
}

fn columns() -> impl Strategy<Value = Columns> {
    (
        any::<bool>(),
        prop::collection::btree_set("[a-z][a-z0-9_ ,\"]{0,8}", 0..3),
    )
        .prop_map(|(temp_c, extra)| {
            Columns::new(
                temp_c,
                extra.into_iter().filter(|e| e.trim() != "").collect(),
            )
            .unwrap_or_default()
        })
}

fn record(columns: &Columns) -> impl Strategy<Value = Record> {
    let temp = columns.temp_c;
    (
        value(1.0e9),
        text().prop_filter("segment must not be blank", |s| !s.trim().is_empty()),
        any::<u32>(),
        prop::array::uniform6(value(1.0e9)),
        prop::option::of(value(1.0e3)),
        prop::collection::vec(text(), columns.extra.len()),
    )
        .prop_map(move |(t_s, segment, cycle, p, temp_c, extra)| Record {
            t_s,
            segment,
            cycle,
            x_target_um: p[0],
            y_target_um: p[1],
            x_cmd_um: p[2],
            y_cmd_um: p[3],
            x_meas_um: p[4],
            y_meas_um: p[5],
            temp_c: if temp { temp_c } else { None },
            theta_urad: None,
            extra,
        })
}

fn log_case() -> impl Strategy<Value = (Columns, Vec<Record>)> {
    columns().prop_flat_map(|c| {
        let recs = prop::collection::vec(record(&c), 0..20);
        (Just(c), recs)
    })
}

/// What a value reads back as after being written with `decimals`.
fn at_precision(v: f64, decimals: usize) -> f64 {
    format!("{v:.decimals$}").parse().unwrap()
}

fn write(meta: &Metadata, columns: &Columns, records: &[Record]) -> Vec<u8> {
    let mut w =
        LogWriter::create(Vec::new(), meta, columns.clone(), SyncPolicy::FlushOnly).unwrap();
    for r in records {
        w.append(r).unwrap();
    }
    w.into_inner()
}

/// Re-writes a parsed log if the writer accepts it, and checks that the
/// result parses to a log that re-writes to the same bytes.
fn rewrite_is_stable(log: &MeasurementLog) -> Result<(), TestCaseError> {
    let Ok(mut w) = LogWriter::create(
        Vec::new(),
        &log.metadata,
        log.columns.clone(),
        SyncPolicy::FlushOnly,
    ) else {
        return Ok(());
    };
    for r in &log.records {
        if w.append(r).is_err() {
            return Ok(());
        }
    }
    let first = w.into_inner();
    let again =
        parse_bytes(&first).map_err(|e| TestCaseError::fail(format!("re-read failed: {e}")))?;
    prop_assert_eq!(again.records.len(), log.records.len());
    prop_assert!(again.is_complete());
    let second = write(&again.metadata, &again.columns, &again.records);
    prop_assert_eq!(first, second);
    Ok(())
}

proptest! {
    #![proptest_config(config(200))]

    #[test]
    fn any_records_round_trip_at_the_written_precision(
        (columns, records) in log_case(),
        meta in prop::collection::vec(("[a-z_][a-z0-9_.#-]{0,8}", "[ -~]{0,16}"), 0..4),
    ) {
        let mut metadata = Metadata::new();
        for (k, v) in &meta {
            if k != "format" {
                metadata.insert(k.clone(), v.trim().to_string());
            }
        }
        let bytes = write(&metadata, &columns, &records);
        let log = parse_bytes(&bytes).unwrap();
        prop_assert!(log.is_complete());
        let only_time_warnings = log
            .warnings
            .iter()
            .all(|w| matches!(w.kind, WarningKind::TimeWentBackwards { .. }));
        prop_assert!(only_time_warnings, "{:?}", log.warnings);
        prop_assert_eq!(&log.columns, &columns);
        for (k, v) in metadata.iter() {
            prop_assert_eq!(log.metadata.get(k), Some(v));
        }
        prop_assert_eq!(log.records.len(), records.len());
        let p = POSITION_DECIMALS;
        for (got, want) in log.records.iter().zip(&records) {
            prop_assert_eq!(got.t_s, at_precision(want.t_s, TIME_DECIMALS));
            prop_assert_eq!(&got.segment, &want.segment);
            prop_assert_eq!(got.cycle, want.cycle);
            prop_assert_eq!(got.x_target_um, at_precision(want.x_target_um, p));
            prop_assert_eq!(got.y_target_um, at_precision(want.y_target_um, p));
            prop_assert_eq!(got.x_cmd_um, at_precision(want.x_cmd_um, p));
            prop_assert_eq!(got.y_cmd_um, at_precision(want.y_cmd_um, p));
            prop_assert_eq!(got.x_meas_um, at_precision(want.x_meas_um, p));
            prop_assert_eq!(got.y_meas_um, at_precision(want.y_meas_um, p));
            prop_assert_eq!(got.temp_c, want.temp_c.map(|t| at_precision(t, TEMP_DECIMALS)));
            prop_assert_eq!(&got.extra, &want.extra);
            // Written precision: within half a unit of the last decimal.
            prop_assert!((got.x_meas_um - want.x_meas_um).abs() <= 0.5e-4 * (1.0 + 1e-9) + 1e-7);
        }
        rewrite_is_stable(&log)?;
    }

    #[test]
    fn arbitrary_bytes_never_panic(bytes in prop::collection::vec(any::<u8>(), 0..400)) {
        if let Ok(log) = parse_bytes(&bytes) {
            rewrite_is_stable(&log)?;
        }
    }

    /// Random edits of a valid log reach the record parser far more often
    /// than random bytes do.
    #[test]
    fn edited_logs_never_panic(
        (columns, records) in log_case(),
        edits in prop::collection::vec((any::<prop::sample::Index>(), any::<u8>(), 0u8..3), 1..6),
    ) {
        let mut bytes = write(&Metadata::new(), &columns, &records);
        for (at, byte, op) in edits {
            let i = at.index(bytes.len() + 1);
            match op {
                0 => bytes.insert(i, byte),
                1 if i < bytes.len() => { bytes.remove(i); }
                _ => bytes.truncate(i),
            }
        }
        if let Ok(log) = parse_bytes(&bytes) {
            rewrite_is_stable(&log)?;
        }
    }
}
