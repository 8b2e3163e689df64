//! Fuzzes the measurement log reader with arbitrary bytes: it must never
//! panic, and a log it accepts must re-write (when the writer accepts its
//! content) to bytes that read back to the same number of records and
//! re-write identically.
#![no_main]

use libfuzzer_sys::fuzz_target;
use micropos::charact::log::{parse_bytes, LogWriter, MeasurementLog, SyncPolicy};

fn rewrite(log: &MeasurementLog) -> Option<Vec<u8>> {
    let mut w = LogWriter::create(
        Vec::new(),
        &log.metadata,
        log.columns.clone(),
        SyncPolicy::FlushOnly,
    )
    .ok()?;
    for r in &log.records {
        w.append(r).ok()?;
    }
    Some(w.into_inner())
}

fuzz_target!(|data: &[u8]| {
    let Ok(log) = parse_bytes(data) else {
        return;
    };
    let Some(first) = rewrite(&log) else {
        return;
    };
    let again = match parse_bytes(&first) {
        Ok(l) => l,
        Err(e) => panic!("the writer produced a log the reader refuses: {e}"),
    };
    assert_eq!(again.records.len(), log.records.len());
    assert!(again.is_complete());
    let second = rewrite(&again).expect("a written log re-writes");
    assert_eq!(first, second, "re-writing is not stable");
});
