//! Parsing of received command lines: never panics, and whatever parses
//! prints back to a line that parses to the same command.
#![no_main]

use libfuzzer_sys::fuzz_target;
use micropos::gcs::frame::bytes_to_text;
use micropos::gcs::Command;

fuzz_target!(|data: &[u8]| {
    let line = bytes_to_text(data);
    let Ok(cmd) = Command::parse(&line) else {
        return;
    };
    let text = cmd.to_text();
    let again = Command::parse(&text).expect("a parsed command prints to a parsable line");
    assert_eq!(again.mnemonic(), cmd.mnemonic());
    // Printing is a fixed point after one round (numbers are rounded to
    // 7 decimals once).
    assert_eq!(again.to_text(), text);
});
