#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else { return };
    if let Ok(model) = micropos::model::StageModel::from_toml(text) {
        let _ = model.to_toml();
        let s = micropos::model::MotionState::at_rest(1000.0, 2000.0);
        let _ = model.observed_position(&s);
    }
});
