#![no_main]
use libfuzzer_sys::fuzz_target;

// The compensation file is outside input (written by other tools, edited by
// hand): parsing must never panic, and whatever parses must turn into a
// compensator that can be asked for a command without panicking.
fuzz_target!(|data: &[u8]| {
    let Ok(file) = micropos::comp::CompFile::from_bytes(data) else { return };
    let _ = file.to_toml();
    if let Ok(c) = file.compensator() {
        let start = micropos::model::MotionState::at_rest(1000.0, 2000.0);
        if let Ok(h) = micropos::comp::MotionHistory::new(start, 0.0) {
            let target = micropos::model::XyUm { x_um: 1500.0, y_um: 2500.0 };
            let _ = c.command_for(target, &h, &micropos::comp::PlanOptions::default());
        }
    }
});
