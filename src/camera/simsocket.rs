//! The simulated rig's camera, served on a Unix socket by `hil-sim serve`.
//!
//! Why a socket: the daemon runs in its own process and must take frames from
//! the simulator exactly as it takes them from a camera, through a
//! [`FrameSource`]. The protocol is defined here, sans-IO, so the client
//! ([`SimSocketSource`]) and the server in `hil-sim` share one definition:
//!
//! - client → server: one line `{"grab":true}\n`;
//! - server → client: one JSON header line
//!   `{"ok":true,"width":W,"height":H,"bit_depth":B,"t_s":T,"sequence":N,"bytes":K}\n`
//!   followed by exactly K raw bytes: one byte per pixel if B ≤ 8, else
//!   little-endian `u16`, row-major; or `{"ok":false,"error":"…"}\n`.
//!
//! `t_s` is the simulated time of the exposure mid-point. A grab costs frame
//! time on the simulated clock, like a real camera.

use std::io::{BufRead, BufReader, Read, Write};
use std::os::unix::net::UnixStream;
use std::path::{Path, PathBuf};
use std::time::Duration;

use serde::{Deserialize, Serialize};

use super::{CameraError, CameraInfo, FrameSource};
use crate::frame::{Frame, Pixels};

/// The request line a client sends for one frame (with its LF).
pub const GRAB_REQUEST: &[u8] = b"{\"grab\":true}\n";
/// Longest header line accepted, bytes: a header is < 200 bytes; anything
/// longer is a broken or hostile server.
pub const MAX_HEADER: usize = 4096;
/// Largest frame side accepted, px.
pub const MAX_SIDE: usize = 1 << 15;
/// Largest payload accepted, bytes (256 MiB): bounds the allocation a header
/// can ask for.
pub const MAX_PAYLOAD: usize = 256 << 20;

/// A frame header as sent by the server.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FrameHeader {
    /// Frame width, px.
    pub width: usize,
    /// Frame height, px.
    pub height: usize,
    /// Significant bits per pixel (1..=16).
    pub bit_depth: u8,
    /// Simulated time of the exposure mid-point, s.
    pub t_s: f64,
    /// Frame counter of the server (gaps mean frames the client did not take).
    pub sequence: u64,
    /// Payload length, bytes: width × height × (1 if bit_depth ≤ 8 else 2).
    pub bytes: usize,
}

/// What a header line says.
#[derive(Debug, Clone, PartialEq)]
pub enum Reply {
    /// A frame follows.
    Frame(FrameHeader),
    /// The server could not deliver a frame, and says why.
    Error(String),
}

/// Why a header line or a payload is not acceptable.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SimSocketError {
    /// The header line is not the JSON object the protocol defines.
    #[error("bad frame header: {0}")]
    BadHeader(String),
    /// The header is well formed but describes an impossible frame.
    #[error("inconsistent frame header: {0}")]
    Inconsistent(String),
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawHeader {
    ok: bool,
    width: Option<usize>,
    height: Option<usize>,
    bit_depth: Option<u8>,
    t_s: Option<f64>,
    sequence: Option<u64>,
    bytes: Option<usize>,
    error: Option<String>,
}

/// Bytes per pixel on the wire for a bit depth.
pub fn bytes_per_pixel(bit_depth: u8) -> usize {
    if bit_depth <= 8 {
        1
    } else {
        2
    }
}

impl FrameHeader {
    /// Checks that the header describes a frame this client can hold:
    /// sides in 1..=[`MAX_SIDE`], depth 1..=16, finite time, and a byte count
    /// that matches the size (≤ [`MAX_PAYLOAD`]).
    pub fn validate(&self) -> Result<(), SimSocketError> {
        let bad = |s: String| Err(SimSocketError::Inconsistent(s));
        if !(1..=MAX_SIDE).contains(&self.width) || !(1..=MAX_SIDE).contains(&self.height) {
            return bad(format!(
                "frame size {}×{} outside 1..={MAX_SIDE}",
                self.width, self.height
            ));
        }
        if !(1..=16).contains(&self.bit_depth) {
            return bad(format!("bit_depth {} outside 1..=16", self.bit_depth));
        }
        if !self.t_s.is_finite() {
            return bad(format!("t_s {} is not finite", self.t_s));
        }
        let expected = self.width * self.height * bytes_per_pixel(self.bit_depth);
        if self.bytes != expected {
            return bad(format!(
                "bytes = {} but {}×{} at {} bit needs {expected}",
                self.bytes, self.width, self.height, self.bit_depth
            ));
        }
        if self.bytes > MAX_PAYLOAD {
            return bad(format!("payload {} bytes > {MAX_PAYLOAD}", self.bytes));
        }
        Ok(())
    }

    /// The header line, with its LF.
    pub fn to_line(&self) -> String {
        let mut v = serde_json::json!({
            "ok": true,
            "width": self.width,
            "height": self.height,
            "bit_depth": self.bit_depth,
            "t_s": self.t_s,
            "sequence": self.sequence,
            "bytes": self.bytes,
        })
        .to_string();
        v.push('\n');
        v
    }
}

/// The error reply line for `message`, with its LF.
pub fn error_line(message: &str) -> String {
    let mut v = serde_json::json!({"ok": false, "error": message}).to_string();
    v.push('\n');
    v
}

/// Parses one header line (with or without its LF). Never panics.
pub fn parse_header(line: &[u8]) -> Result<Reply, SimSocketError> {
    if line.len() > MAX_HEADER {
        return Err(SimSocketError::BadHeader(format!(
            "header of {} bytes exceeds {MAX_HEADER}",
            line.len()
        )));
    }
    let text = std::str::from_utf8(line)
        .map_err(|e| SimSocketError::BadHeader(format!("not UTF-8: {e}")))?
        .trim_end_matches(['\n', '\r']);
    let raw: RawHeader =
        serde_json::from_str(text).map_err(|e| SimSocketError::BadHeader(e.to_string()))?;
    if !raw.ok {
        return Ok(Reply::Error(
            raw.error
                .unwrap_or_else(|| "server gave no reason".to_owned()),
        ));
    }
    let missing = |k: &str| SimSocketError::BadHeader(format!("missing \"{k}\""));
    let h = FrameHeader {
        width: raw.width.ok_or_else(|| missing("width"))?,
        height: raw.height.ok_or_else(|| missing("height"))?,
        bit_depth: raw.bit_depth.ok_or_else(|| missing("bit_depth"))?,
        t_s: raw.t_s.ok_or_else(|| missing("t_s"))?,
        sequence: raw.sequence.ok_or_else(|| missing("sequence"))?,
        bytes: raw.bytes.ok_or_else(|| missing("bytes"))?,
    };
    h.validate()?;
    Ok(Reply::Frame(h))
}

/// The payload bytes of a frame (u8, or u16 little-endian), as the server
/// sends them.
pub fn encode_payload(frame: &Frame) -> Vec<u8> {
    match frame.pixels() {
        Pixels::U8(p) => p.clone(),
        Pixels::U16(p) => p.iter().flat_map(|v| v.to_le_bytes()).collect(),
    }
}

/// Builds the frame from a validated header and its payload.
pub fn decode_payload(h: &FrameHeader, payload: &[u8]) -> Result<Frame, CameraError> {
    h.validate()
        .map_err(|e| CameraError::BadData(e.to_string()))?;
    if payload.len() != h.bytes {
        return Err(CameraError::BadData(format!(
            "payload holds {} bytes, header says {}",
            payload.len(),
            h.bytes
        )));
    }
    let pixels = if bytes_per_pixel(h.bit_depth) == 1 {
        Pixels::U8(payload.to_vec())
    } else {
        let full = (1u32 << h.bit_depth) - 1;
        let v: Vec<u16> = payload
            .chunks_exact(2)
            .map(|c| u16::from_le_bytes([c[0], c[1]]))
            .collect();
        if let Some(bad) = v.iter().find(|&&p| u32::from(p) > full) {
            return Err(CameraError::BadData(format!(
                "pixel value {bad} exceeds {}-bit full scale {full}",
                h.bit_depth
            )));
        }
        Pixels::U16(v)
    };
    Ok(Frame::new(
        h.width,
        h.height,
        h.bit_depth,
        pixels,
        h.t_s,
        h.sequence,
    )?)
}

/// Client of the simulated camera socket (`sim:PATH`).
///
/// Blocking I/O bounded by the timeout, like every [`FrameSource`]: call it
/// from a blocking thread. A timed-out or broken exchange drops the
/// connection; the next grab reconnects, so a late answer to an old request
/// is never taken for a new frame.
#[derive(Debug)]
pub struct SimSocketSource {
    path: PathBuf,
    conn: Option<BufReader<UnixStream>>,
    timeout: Duration,
    last: Option<FrameHeader>,
}

impl SimSocketSource {
    /// Connects to the camera socket at `path` (checked now, so a wrong path
    /// fails at open rather than at the first grab).
    pub fn open(path: &Path) -> Result<Self, CameraError> {
        let mut s = Self {
            path: path.to_owned(),
            conn: None,
            timeout: Duration::from_secs(2),
            last: None,
        };
        s.connect()?;
        Ok(s)
    }

    fn connect(&mut self) -> Result<(), CameraError> {
        let stream = UnixStream::connect(&self.path).map_err(|e| CameraError::NoDevice {
            path: self.path.display().to_string(),
            hint: format!(
                "cannot connect to the simulated camera socket ({e}); is `hil-sim serve` running?"
            ),
        })?;
        self.conn = Some(BufReader::new(stream));
        self.apply_timeout()
    }

    fn apply_timeout(&mut self) -> Result<(), CameraError> {
        if let Some(c) = &self.conn {
            let t = Some(self.timeout.max(Duration::from_millis(1)));
            let s = c.get_ref();
            s.set_read_timeout(t)
                .and_then(|()| s.set_write_timeout(t))
                .map_err(|e| self.io_err(e))?;
        }
        Ok(())
    }

    fn io_err(&self, e: std::io::Error) -> CameraError {
        if matches!(
            e.kind(),
            std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
        ) {
            CameraError::Timeout {
                timeout_s: self.timeout.as_secs_f64(),
            }
        } else {
            CameraError::Io {
                path: self.path.clone(),
                source: e,
            }
        }
    }

    fn grab(&mut self) -> Result<Frame, CameraError> {
        if self.conn.is_none() {
            self.connect()?;
        }
        let Some(conn) = self.conn.as_mut() else {
            return Err(CameraError::BadData("no connection".into()));
        };
        conn.get_mut()
            .write_all(GRAB_REQUEST)
            .map_err(|e| self.io_err(e))?;
        let Some(conn) = self.conn.as_mut() else {
            return Err(CameraError::BadData("no connection".into()));
        };
        let mut line = Vec::new();
        let n = conn
            .by_ref()
            .take(MAX_HEADER as u64 + 1)
            .read_until(b'\n', &mut line);
        let n = n.map_err(|e| self.io_err(e))?;
        if n == 0 {
            return Err(CameraError::Io {
                path: self.path.clone(),
                source: std::io::Error::new(
                    std::io::ErrorKind::UnexpectedEof,
                    "camera socket closed by the simulator",
                ),
            });
        }
        let reply = parse_header(&line).map_err(|e| CameraError::BadData(e.to_string()))?;
        let h = match reply {
            Reply::Error(msg) => {
                return Err(CameraError::Backend {
                    backend: "sim",
                    message: msg,
                })
            }
            Reply::Frame(h) => h,
        };
        let mut payload = vec![0u8; h.bytes];
        let Some(conn) = self.conn.as_mut() else {
            return Err(CameraError::BadData("no connection".into()));
        };
        conn.read_exact(&mut payload).map_err(|e| self.io_err(e))?;
        let f = decode_payload(&h, &payload)?;
        self.last = Some(h);
        Ok(f)
    }
}

impl FrameSource for SimSocketSource {
    fn info(&self) -> CameraInfo {
        let (w, h, b) = self
            .last
            .map(|h| (h.width, h.height, h.bit_depth))
            .unwrap_or((0, 0, 0));
        CameraInfo {
            backend: "sim",
            model: "hil-sim simulated microscope camera".into(),
            serial: self.path.display().to_string(),
            width: w,
            height: h,
            pixel_format: if b > 8 {
                format!("Mono{b}")
            } else {
                "Mono8".into()
            },
            bit_depth: b,
        }
    }

    fn next_frame(&mut self) -> Result<Frame, CameraError> {
        let r = self.grab();
        if r.is_err() {
            // Never read a late answer as the next frame: start afresh.
            self.conn = None;
        }
        r
    }

    fn set_timeout(&mut self, timeout: Duration) {
        self.timeout = timeout;
        if self.apply_timeout().is_err() {
            self.conn = None;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn header_round_trips_and_validates() {
        let h = FrameHeader {
            width: 4,
            height: 3,
            bit_depth: 10,
            t_s: 1.5,
            sequence: 7,
            bytes: 24,
        };
        assert_eq!(
            parse_header(h.to_line().as_bytes()).unwrap(),
            Reply::Frame(h)
        );
        let bad = FrameHeader { bytes: 12, ..h };
        assert!(matches!(
            parse_header(bad.to_line().as_bytes()),
            Err(SimSocketError::Inconsistent(_))
        ));
        assert_eq!(
            parse_header(error_line("stalled").as_bytes()).unwrap(),
            Reply::Error("stalled".into())
        );
        assert!(parse_header(b"{\"ok\":true}").is_err());
        assert!(parse_header(b"\xff\xfe").is_err());
        assert!(parse_header(br#"{"ok":true,"width":1e99}"#).is_err());
        let huge = FrameHeader {
            width: 32768,
            height: 32768,
            bit_depth: 16,
            bytes: 32768 * 32768 * 2,
            ..h
        };
        assert!(huge.validate().is_err());
    }

    #[test]
    fn payload_round_trips() {
        let f = Frame::new(3, 2, 10, Pixels::U16(vec![0, 1, 2, 1023, 512, 7]), 2.0, 3).unwrap();
        let h = FrameHeader {
            width: 3,
            height: 2,
            bit_depth: 10,
            t_s: 2.0,
            sequence: 3,
            bytes: 12,
        };
        let p = encode_payload(&f);
        assert_eq!(decode_payload(&h, &p).unwrap(), f);
        let mut over = p.clone();
        over[6] = 0xff;
        over[7] = 0xff;
        assert!(decode_payload(&h, &over).is_err());
        assert!(decode_payload(&h, &p[..10]).is_err());
    }

    proptest::proptest! {
        #[test]
        fn parse_header_never_panics(bytes in proptest::collection::vec(proptest::prelude::any::<u8>(), 0..300)) {
            let _ = parse_header(&bytes);
        }
    }
}
