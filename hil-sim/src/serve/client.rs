//! Blocking client helpers: one request/answer exchange through a serial
//! device path.

use nix::poll::{poll, PollFd, PollFlags, PollTimeout};
use std::fs::File;
use std::io::{self, Read, Write};
use std::os::fd::AsFd;
use std::path::Path;
use std::time::{Duration, Instant};

/// One blocking request/answer exchange through a serial device path: writes
/// `request`, reads until an answer's final LF (a LF not preceded by a
/// space) or `timeout`. A small helper for probes and tests; the real driver
/// lives in `micropos`.
pub fn exchange(path: &Path, request: &[u8], timeout: Duration) -> io::Result<Vec<u8>> {
    let mut f = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .open(path)?;
    f.write_all(request)?;
    read_answer(&mut f, timeout)
}

/// Reads one complete GCS answer from `f` (see [`exchange`]).
pub fn read_answer(f: &mut File, timeout: Duration) -> io::Result<Vec<u8>> {
    let deadline = Instant::now() + timeout;
    let mut out = Vec::new();
    let mut buf = [0u8; 1024];
    loop {
        let left = deadline.saturating_duration_since(Instant::now());
        if left.is_zero() {
            return Err(io::Error::new(
                io::ErrorKind::TimedOut,
                format!("no complete answer within {timeout:?} (got {out:?})"),
            ));
        }
        let ms = u16::try_from(left.as_millis().max(1)).unwrap_or(u16::MAX);
        let mut fds = [PollFd::new(f.as_fd(), PollFlags::POLLIN)];
        let n = poll(&mut fds, PollTimeout::from(ms)).map_err(io::Error::from)?;
        if n == 0 {
            continue;
        }
        let got = f.read(&mut buf)?;
        if got == 0 {
            return Err(io::Error::new(io::ErrorKind::UnexpectedEof, "line closed"));
        }
        out.extend_from_slice(&buf[..got]);
        if out.ends_with(b"\n") && (out.len() < 2 || out[out.len() - 2] != b' ') {
            return Ok(out);
        }
    }
}
