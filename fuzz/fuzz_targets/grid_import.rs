//! Fuzzes the 2-D grid import (`micropos import --format grid`) and the
//! grid analysis behind `diagnose` with arbitrary bytes: neither may
//! panic, and what the import accepts must be a measurement log the reader
//! accepts, which the map reader then reads without panicking.
#![no_main]

use libfuzzer_sys::fuzz_target;
use micropos::analysis::grid::{analyse, GridMap};
use micropos::charact::import::Unit;
use micropos::charact::import_grid::{import_grid_bytes, is_grid_export, ErrorSign, GridImportOptions};
use micropos::charact::log::parse_bytes;

fuzz_target!(|data: &[u8]| {
    let Some((&sel, body)) = data.split_first() else {
        return;
    };
    let _ = is_grid_export(body);
    let opts = GridImportOptions {
        units: [None, Some(Unit::Mm), Some(Unit::Um), Some(Unit::Nm), Some(Unit::M)]
            [usize::from(sel % 5)],
        error_sign: if sel & 8 == 0 {
            ErrorSign::MeasuredMinusTarget
        } else {
            ErrorSign::TargetMinusMeasured
        },
        source: None,
    };
    let Ok(bytes) = import_grid_bytes(body, &opts) else {
        return;
    };
    let log = match parse_bytes(&bytes) {
        Ok(l) => l,
        Err(e) => panic!("import wrote a log the reader refuses: {e}"),
    };
    assert!(log.is_complete());
    if let Some(map) = GridMap::from_log(&log, [true, true]) {
        let _ = analyse(&map, 5.0, 1.0);
    }
});
