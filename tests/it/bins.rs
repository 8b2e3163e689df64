//! The binaries the process tests start: `microposd` (this package's) and
//! `hil-sim` (built beside it by `cargo test --workspace`), one lookup for
//! every module.

use std::path::{Path, PathBuf};
use std::time::SystemTime;

fn newest_mtime(dir: &Path) -> SystemTime {
    let mut newest = SystemTime::UNIX_EPOCH;
    let Ok(rd) = std::fs::read_dir(dir) else {
        return newest;
    };
    for e in rd.flatten() {
        let p = e.path();
        let t = if p.is_dir() {
            newest_mtime(&p)
        } else {
            e.metadata()
                .and_then(|m| m.modified())
                .unwrap_or(SystemTime::UNIX_EPOCH)
        };
        newest = newest.max(t);
    }
    newest
}

/// `MICROPOSD_BIN` overrides the path (a target directory shared by
/// several checkouts may hold another checkout's build).
pub fn microposd_bin() -> PathBuf {
    std::env::var_os("MICROPOSD_BIN")
        .map_or_else(|| env!("CARGO_BIN_EXE_microposd").into(), PathBuf::from)
}

/// `HIL_SIM_BIN` overrides the path; otherwise the binary beside
/// `microposd`, refused when older than hil-sim's sources (a stale
/// simulator fails tests for reasons that are not theirs).
pub fn hil_sim_bin() -> PathBuf {
    if let Some(p) = std::env::var_os("HIL_SIM_BIN") {
        return p.into();
    }
    let bin = Path::new(env!("CARGO_BIN_EXE_microposd"))
        .parent()
        .unwrap()
        .join("hil-sim");
    let advice = "run `cargo test --workspace`, or `cargo build -p hil-sim` before this test alone (or set HIL_SIM_BIN)";
    let built = std::fs::metadata(&bin)
        .and_then(|m| m.modified())
        .unwrap_or_else(|e| panic!("no hil-sim binary at {}: {e}; {advice}", bin.display()));
    let sources = newest_mtime(Path::new(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/hil-sim/src"
    )));
    assert!(
        built >= sources,
        "{} is older than hil-sim's sources; {advice}",
        bin.display()
    );
    bin
}
