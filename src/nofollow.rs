//! File access in the data directory that never follows a symbolic link.
//!
//! Why: the data directory is writable by the service and may be by its
//! group; a link planted there (`STEM-paper.toml.tmp` → `/etc/…`, a log
//! named like a table → a secret file) would make the daemon write through
//! it or quote the target's content in an error to a client. Reads open
//! with `O_NOFOLLOW` (a link as the last component fails with `ELOOP`);
//! writes go to a fresh temporary file (`create_new`, a random name the
//! planter cannot predict, `O_NOFOLLOW`), synced, then renamed over the
//! path (rename replaces a link itself, never its target).

use rand::Rng;
use std::fs::{File, OpenOptions};
use std::io::{self, Read, Write};
use std::os::unix::fs::OpenOptionsExt;
use std::path::{Path, PathBuf};

/// A link refused: the error names it instead of `ELOOP`'s "too many
/// levels of symbolic links".
fn refused(e: io::Error) -> io::Error {
    if e.raw_os_error() == Some(libc::ELOOP) {
        io::Error::new(
            io::ErrorKind::InvalidInput,
            "is a symbolic link (not followed)",
        )
    } else {
        e
    }
}

/// Opens `path` for reading; a symbolic link is refused.
pub fn open(path: &Path) -> io::Result<File> {
    OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_NOFOLLOW)
        .open(path)
        .map_err(refused)
}

/// The whole content of `path`; a symbolic link is refused.
pub fn read(path: &Path) -> io::Result<Vec<u8>> {
    let mut out = Vec::new();
    open(path)?.read_to_end(&mut out)?;
    Ok(out)
}

/// A temporary name next to `path` no one can guess in advance:
/// `.NAME.RANDOM.tmp`.
fn temp_path(path: &Path) -> PathBuf {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let suffix: u64 = rand::thread_rng().gen();
    path.with_file_name(format!(".{name}.{suffix:016x}.tmp"))
}

/// Writes `bytes` to `path` atomically: a new temporary file in the same
/// directory (never an existing file or link), synced, renamed over
/// `path`. Readers see the old or the new content, never half a file.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> io::Result<()> {
    let tmp = temp_path(path);
    let result = (|| {
        let mut f = OpenOptions::new()
            .write(true)
            .create_new(true)
            .custom_flags(libc::O_NOFOLLOW)
            .open(&tmp)
            .map_err(refused)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_refuse_a_link_and_name_it() {
        let d = tempfile::tempdir().unwrap();
        let secret = d.path().join("secret");
        std::fs::write(&secret, "first line of a secret\n").unwrap();
        let link = d.path().join("t.csv");
        std::os::unix::fs::symlink(&secret, &link).unwrap();
        let e = read(&link).unwrap_err();
        assert!(e.to_string().contains("symbolic link"), "{e}");
        assert!(!e.to_string().contains("secret"), "{e}");
        assert_eq!(read(&secret).unwrap(), b"first line of a secret\n");
    }

    #[test]
    fn writes_never_go_through_a_planted_link() {
        let d = tempfile::tempdir().unwrap();
        let victim = d.path().join("victim");
        std::fs::write(&victim, "keep").unwrap();
        let path = d.path().join("t-paper.toml");
        // The old fixed temporary name and the path itself as links.
        std::os::unix::fs::symlink(&victim, d.path().join("t-paper.toml.tmp")).unwrap();
        std::os::unix::fs::symlink(&victim, &path).unwrap();
        write_atomic(&path, b"new").unwrap();
        assert_eq!(std::fs::read(&victim).unwrap(), b"keep");
        assert!(!std::fs::symlink_metadata(&path).unwrap().is_symlink());
        assert_eq!(std::fs::read(&path).unwrap(), b"new");
    }
}
