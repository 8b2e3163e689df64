//! Moves bytes: splits a stream into request lines with a size limit and
//! time limits, and writes reply lines. No parsing beyond finding newlines.
//!
//! Why the time limits live here: a line's deadline starts at its first
//! byte, which only the reader sees; cutting a read from outside would
//! lose the bytes already taken from the buffer.

use super::protocol::MAX_REQUEST_BYTES;
use std::time::Duration;
use tokio::io::{AsyncBufReadExt, AsyncWrite, AsyncWriteExt, BufReader};
use tokio::time::Instant;

/// One line read from a client.
#[derive(Debug, PartialEq)]
pub enum Incoming {
    /// A complete line (newline removed, `\r` too).
    Line(Vec<u8>),
    /// A line longer than the limit; its bytes were discarded up to the
    /// next newline. Carries the length seen.
    TooLarge(usize),
    /// End of stream.
    Closed,
    /// No byte arrived within the idle limit (nothing was consumed; the
    /// caller may wait again).
    Idle,
    /// A line started but its newline did not arrive within the line
    /// limit; the partial line is discarded.
    Stalled,
}

/// Reads request lines.
#[derive(Debug)]
pub struct LineReader<R> {
    inner: BufReader<R>,
}

impl<R: tokio::io::AsyncRead + Unpin> LineReader<R> {
    /// Wraps a read half.
    pub fn new(r: R) -> Self {
        Self {
            inner: BufReader::with_capacity(16 * 1024, r),
        }
    }

    /// The next line, never buffering more than the limit: an oversized
    /// line is skipped to its newline without being kept in memory.
    pub async fn next(&mut self) -> std::io::Result<Incoming> {
        self.next_within(None, None).await
    }

    /// [`LineReader::next`] with time limits: `Idle` if no byte arrives
    /// within `idle`, `Stalled` if a started line does not end within
    /// `line` of its first byte (`None`: no limit).
    pub async fn next_within(
        &mut self,
        idle: Option<Duration>,
        line_limit: Option<Duration>,
    ) -> std::io::Result<Incoming> {
        let mut line = Vec::new();
        let mut seen = 0usize;
        let idle_deadline = idle.map(|d| Instant::now() + d);
        let mut line_deadline: Option<Option<Instant>> =
            (!self.inner.buffer().is_empty()).then(|| line_limit.map(|d| Instant::now() + d));
        loop {
            let deadline = match line_deadline {
                Some(d) => d,
                None => idle_deadline,
            };
            let buf = match deadline {
                None => self.inner.fill_buf().await?,
                // Cancelling fill_buf loses nothing: bytes read stay in
                // the buffer.
                Some(d) => match tokio::time::timeout_at(d, self.inner.fill_buf()).await {
                    Ok(r) => r?,
                    Err(_) => {
                        return Ok(if line_deadline.is_some() {
                            Incoming::Stalled
                        } else {
                            Incoming::Idle
                        })
                    }
                },
            };
            if line_deadline.is_none() && !buf.is_empty() {
                line_deadline = Some(line_limit.map(|d| Instant::now() + d));
            }
            if buf.is_empty() {
                // EOF: a last line without newline is still a request.
                return Ok(if seen == 0 {
                    Incoming::Closed
                } else if seen > MAX_REQUEST_BYTES {
                    Incoming::TooLarge(seen)
                } else {
                    Incoming::Line(trim_cr(line))
                });
            }
            let (chunk, found) = match buf.iter().position(|&b| b == b'\n') {
                Some(i) => (&buf[..i], Some(i + 1)),
                None => (buf, None),
            };
            seen = seen.saturating_add(chunk.len());
            if seen <= MAX_REQUEST_BYTES + 1 {
                line.extend_from_slice(chunk);
            } else if !line.is_empty() {
                line = Vec::new();
            }
            let used = found.unwrap_or(chunk.len());
            self.inner.consume(used);
            if found.is_some() {
                let l = trim_cr(line);
                return Ok(
                    if seen > MAX_REQUEST_BYTES + 1 || l.len() > MAX_REQUEST_BYTES {
                        Incoming::TooLarge(seen)
                    } else {
                        Incoming::Line(l)
                    },
                );
            }
        }
    }
}

fn trim_cr(mut l: Vec<u8>) -> Vec<u8> {
    if l.last() == Some(&b'\r') {
        l.pop();
    }
    l
}

/// Writes one complete line.
pub async fn write_line<W: AsyncWrite + Unpin>(w: &mut W, line: &str) -> std::io::Result<()> {
    w.write_all(line.as_bytes()).await?;
    w.flush().await
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn splits_lines_and_skips_oversized_ones() {
        let mut data = b"{\"a\":1}\r\nsecond\n".to_vec();
        data.extend(vec![b'x'; MAX_REQUEST_BYTES + 10]);
        data.extend(b"\nlast");
        let mut r = LineReader::new(&data[..]);
        assert_eq!(
            r.next().await.unwrap(),
            Incoming::Line(b"{\"a\":1}".to_vec())
        );
        assert_eq!(r.next().await.unwrap(), Incoming::Line(b"second".to_vec()));
        assert_eq!(
            r.next().await.unwrap(),
            Incoming::TooLarge(MAX_REQUEST_BYTES + 10)
        );
        assert_eq!(r.next().await.unwrap(), Incoming::Line(b"last".to_vec()));
        assert_eq!(r.next().await.unwrap(), Incoming::Closed);
    }

    #[tokio::test(start_paused = true)]
    async fn idle_and_stalled_lines_are_told_apart() {
        let (mut client, server) = tokio::io::duplex(1024);
        let mut r = LineReader::new(server);
        let s = Duration::from_secs(1);
        // Nothing sent: idle, and waiting again is fine.
        assert_eq!(
            r.next_within(Some(s), Some(s)).await.unwrap(),
            Incoming::Idle
        );
        // A started line keeps its own deadline, not the idle one.
        client.write_all(b"{\"cmd\"").await.unwrap();
        assert_eq!(
            r.next_within(Some(10 * s), Some(s)).await.unwrap(),
            Incoming::Stalled
        );
        // A line that completes in time is read whole.
        let mut r = LineReader::new(&b"ok\n"[..]);
        assert_eq!(
            r.next_within(Some(s), Some(s)).await.unwrap(),
            Incoming::Line(b"ok".to_vec())
        );
    }

    #[tokio::test]
    async fn a_line_at_the_limit_is_accepted() {
        let mut data = vec![b'y'; MAX_REQUEST_BYTES];
        data.push(b'\n');
        let mut r = LineReader::new(&data[..]);
        assert!(
            matches!(r.next().await.unwrap(), Incoming::Line(l) if l.len() == MAX_REQUEST_BYTES)
        );
    }
}
