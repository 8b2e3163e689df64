//! Fuzzes the ISO 230-2 import (`micropos import`) with arbitrary bytes in
//! every format and unit: it must never panic, and what it accepts must be
//! a measurement log the reader accepts, with as many records as arrivals.
#![no_main]

use libfuzzer_sys::fuzz_target;
use micropos::charact::import::{
    import_bytes, parse_arrivals, DirectionLabels, ImportFormat, ImportOptions, Unit,
};
use micropos::charact::log::parse_bytes;
use micropos::model::Axis;

fuzz_target!(|data: &[u8]| {
    let Some((&sel, body)) = data.split_first() else {
        return;
    };
    let opts = ImportOptions {
        format: [
            ImportFormat::Auto,
            ImportFormat::Csv,
            ImportFormat::Dat,
            ImportFormat::Report,
        ][usize::from(sel % 4)],
        axis: if sel & 4 == 0 { Axis::X } else { Axis::Y },
        units: [None, Some(Unit::Mm), Some(Unit::Um), Some(Unit::Nm), Some(Unit::M)]
            [usize::from((sel >> 3) % 5)],
        source: None,
        directions: [
            DirectionLabels::Auto,
            DirectionLabels::AsLabelled,
            DirectionLabels::Swapped,
        ][usize::from((sel >> 6) % 3)],
    };
    let Ok(bytes) = import_bytes(body, &opts) else {
        return;
    };
    let log = match parse_bytes(&bytes) {
        Ok(l) => l,
        Err(e) => panic!("import wrote a log the reader refuses: {e}"),
    };
    let (arrivals, _) = parse_arrivals(body, &opts).expect("import accepted it once");
    assert_eq!(log.records.len(), arrivals.len());
    assert!(log.is_complete());
});
