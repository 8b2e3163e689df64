//! Moves bytes: splits a stream into request lines with a size limit, and
//! writes reply lines. No parsing beyond finding newlines.

use super::protocol::MAX_REQUEST_BYTES;
use tokio::io::{AsyncBufReadExt, AsyncWrite, AsyncWriteExt, BufReader};

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
        let mut line = Vec::new();
        let mut seen = 0usize;
        loop {
            let buf = self.inner.fill_buf().await?;
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
