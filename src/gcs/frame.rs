//! GCS 2.0 framing: how bytes on the RS-232 line become requests and answers.
//!
//! Facts this module encodes (PI GCS 2.0):
//! - A command line ends in LF (never CRLF).
//! - An answer of several lines ends every line but the last with a space
//!   before the LF (`" \n"`); the last line ends in a bare LF.
//! - The single-character commands #4, #5, #7 and #24 (bytes 4, 5, 7, 24) are
//!   sent alone, with no LF, and answered with a line. #7 answers the raw byte
//!   0xB1 (ready) or 0xB0 (busy).
//! - Daisy chain: up to 16 controllers on one line. A command may be prefixed
//!   with the target address (`"2 POS? 1\n"`); without a prefix it goes to
//!   address 1. The reply of an addressed command starts its first line with
//!   `"0 <addr> "` (target 0 = the host, then the sender).
//!
//! Both directions are plain push-bytes/pop-items state machines with bounded
//! buffers: they never block, never panic and never grow without limit, so a
//! stream of garbage costs at most one bounded buffer and an error item.

use std::fmt;
use thiserror::Error;

/// Largest request line the server side keeps (PI controllers have a command
/// buffer of a few hundred bytes; longer lines are errors, not memory).
pub const MAX_LINE_LEN: usize = 1024;
/// Largest answer the client side keeps (`HLP?` and `HPA?` are the longest
/// answers, a few KiB).
pub const MAX_ANSWER_LEN: usize = 64 * 1024;

/// A daisy-chain address, 1..=16. Address 1 is also the unaddressed default.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Address(u8);

impl Address {
    /// The default address of a controller that is alone on its line.
    pub const DEFAULT: Address = Address(1);

    /// Checks the range 1..=16 that the C-863 DIP switches allow.
    pub fn new(a: u8) -> Result<Self, FrameError> {
        if (1..=16).contains(&a) {
            Ok(Self(a))
        } else {
            Err(FrameError::BadAddress(u32::from(a)))
        }
    }

    /// The address as a number.
    pub fn get(self) -> u8 {
        self.0
    }
}

impl fmt::Display for Address {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.0)
    }
}

/// The single-character commands. They bypass the command parser on the
/// controller, which is why they work while a long command is executing.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ControlChar {
    /// `#4`: status register (hex word).
    Status = 4,
    /// `#5`: motion status bitmask (hex; bit 0 = axis 1 moving).
    MotionStatus = 5,
    /// `#7`: controller ready (raw byte 0xB1 ready, 0xB0 busy).
    Ready = 7,
    /// `#24`: stop all axes at once (sets error 10).
    StopAll = 24,
}

impl ControlChar {
    /// The control character for a byte, if it is one of the four.
    pub fn from_byte(b: u8) -> Option<Self> {
        match b {
            4 => Some(Self::Status),
            5 => Some(Self::MotionStatus),
            7 => Some(Self::Ready),
            24 => Some(Self::StopAll),
            _ => None,
        }
    }

    /// The byte on the wire.
    pub fn byte(self) -> u8 {
        self as u8
    }

    /// Whether the controller answers it (#24 has no answer).
    pub fn has_answer(self) -> bool {
        !matches!(self, Self::StopAll)
    }
}

/// Framing errors.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum FrameError {
    /// Daisy-chain addresses are 1..=16.
    #[error("address {0} is outside the daisy-chain range 1..=16")]
    BadAddress(u32),
    /// A command line may not contain LF or the control bytes.
    #[error("command line contains a line feed or a control byte: {0:?}")]
    BadCommandText(String),
    /// A request line grew past [`MAX_LINE_LEN`] before its LF.
    #[error("request line longer than {MAX_LINE_LEN} bytes")]
    LineTooLong,
    /// An answer grew past [`MAX_ANSWER_LEN`] before its final line.
    #[error("answer longer than {MAX_ANSWER_LEN} bytes")]
    AnswerTooLong,
    /// The reply did not start with the expected `0 <addr> ` header.
    #[error("reply header {got:?} does not match address {expected}")]
    BadReplyHeader {
        /// Address the command was sent to.
        expected: Address,
        /// The start of the first line as received.
        got: String,
    },
}

/// Bytes of a command line to send, with the optional daisy-chain prefix.
///
/// `addr = None` sends no prefix (the controller at address 1 answers, with no
/// reply header). The text must not contain LF, CR or control bytes.
pub fn encode_line(addr: Option<Address>, text: &str) -> Result<Vec<u8>, FrameError> {
    if text
        .bytes()
        .any(|b| b == b'\n' || b == b'\r' || ControlChar::from_byte(b).is_some())
    {
        return Err(FrameError::BadCommandText(text.to_owned()));
    }
    let mut out = Vec::with_capacity(text.len() + 4);
    if let Some(a) = addr {
        out.extend_from_slice(format!("{a} ").as_bytes());
    }
    out.extend_from_slice(text.as_bytes());
    out.push(b'\n');
    Ok(out)
}

/// Bytes of a single-character command, with the optional daisy-chain prefix
/// (`"2 "` then the byte, no LF).
pub fn encode_control(addr: Option<Address>, c: ControlChar) -> Vec<u8> {
    let mut out = Vec::with_capacity(4);
    if let Some(a) = addr {
        out.extend_from_slice(format!("{a} ").as_bytes());
    }
    out.push(c.byte());
    out
}

/// Text of a byte string as the controller means it: PI controllers speak
/// 8-bit code page text, so each byte maps to one char and nothing fails.
pub fn bytes_to_text(b: &[u8]) -> String {
    b.iter().map(|&c| char::from(c)).collect()
}

// ---------------------------------------------------------------- server side

/// What the controller side of the line received.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Request {
    /// A command line, LF stripped, daisy-chain prefix split off.
    Line {
        /// The address prefix, if the line had one.
        addr: Option<Address>,
        /// The command text (8-bit text, see [`bytes_to_text`]).
        text: String,
    },
    /// A single-character command.
    Control {
        /// The address prefix, if one stood just before it.
        addr: Option<Address>,
        /// Which command.
        command: ControlChar,
    },
    /// A line longer than [`MAX_LINE_LEN`] was discarded up to its LF. A
    /// controller sets error 3 for it.
    Overlong,
}

/// Splits a received line into its daisy-chain prefix and command text.
///
/// A prefix is 1–2 digits and a space at the start of the line; a number
/// outside 1..=16 is not a prefix (the line is then taken as it is, and the
/// command parser rejects it).
fn split_address(line: &[u8]) -> (Option<Address>, &[u8]) {
    let digits = line.iter().take_while(|b| b.is_ascii_digit()).count();
    if (1..=2).contains(&digits) && line.get(digits) == Some(&b' ') {
        let n = line[..digits]
            .iter()
            .fold(0u32, |acc, &d| acc * 10 + u32::from(d - b'0'));
        if let Ok(a) = u8::try_from(n)
            .map_err(|_| ())
            .and_then(|n| Address::new(n).map_err(|_| ()))
        {
            return (Some(a), &line[digits + 1..]);
        }
    }
    (None, line)
}

/// Turns the byte stream a controller receives into [`Request`]s.
///
/// Control bytes are handled the moment they arrive, like a real controller
/// does (so `#24` stops motion even in the middle of a line). If the bytes
/// before one are exactly an address prefix, the control command is addressed.
#[derive(Debug, Default)]
pub struct RequestDecoder {
    line: Vec<u8>,
    discarding: bool,
}

impl RequestDecoder {
    /// A decoder with an empty buffer.
    pub fn new() -> Self {
        Self::default()
    }

    /// Feeds received bytes; returns the requests they complete, in order.
    pub fn push(&mut self, bytes: &[u8]) -> Vec<Request> {
        let mut out = Vec::new();
        for &b in bytes {
            if let Some(c) = ControlChar::from_byte(b) {
                let (addr, rest) = split_address(&self.line);
                if addr.is_some() && rest.is_empty() {
                    self.line.clear();
                    out.push(Request::Control { addr, command: c });
                } else {
                    out.push(Request::Control {
                        addr: None,
                        command: c,
                    });
                }
                continue;
            }
            if b == b'\n' {
                if self.discarding {
                    self.discarding = false;
                    out.push(Request::Overlong);
                } else {
                    let (addr, text) = split_address(&self.line);
                    out.push(Request::Line {
                        addr,
                        text: bytes_to_text(text),
                    });
                }
                self.line.clear();
                continue;
            }
            if self.discarding {
                continue;
            }
            if self.line.len() >= MAX_LINE_LEN {
                self.line.clear();
                self.discarding = true;
                continue;
            }
            self.line.push(b);
        }
        out
    }

    /// Bytes held for an unfinished line.
    pub fn pending(&self) -> usize {
        self.line.len()
    }
}

/// Builds the bytes of an answer: lines joined by `" \n"`, a final `"\n"`,
/// and the `"0 <addr> "` header when the request was addressed.
pub fn encode_answer(addr: Option<Address>, lines: &[String]) -> Vec<u8> {
    let mut out = Vec::new();
    if let Some(a) = addr {
        out.extend_from_slice(format!("0 {a} ").as_bytes());
    }
    for (i, l) in lines.iter().enumerate() {
        out.extend(
            l.chars()
                .map(|c| u8::try_from(u32::from(c)).unwrap_or(b'?')),
        );
        if i + 1 < lines.len() {
            out.push(b' ');
        }
        out.push(b'\n');
    }
    if lines.is_empty() {
        out.push(b'\n');
    }
    out
}

// ---------------------------------------------------------------- client side

/// One complete answer: its lines, without the continuation spaces and LFs.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Answer {
    lines: Vec<Vec<u8>>,
}

impl Answer {
    /// Builds an answer from raw lines (for tests and the simulator).
    pub fn from_lines(lines: Vec<Vec<u8>>) -> Self {
        Self { lines }
    }

    /// The raw lines (8-bit bytes).
    pub fn raw_lines(&self) -> &[Vec<u8>] {
        &self.lines
    }

    /// The lines as text (see [`bytes_to_text`]).
    pub fn lines(&self) -> Vec<String> {
        self.lines.iter().map(|l| bytes_to_text(l)).collect()
    }

    /// The whole answer as text, lines joined by `\n`.
    pub fn text(&self) -> String {
        self.lines().join("\n")
    }

    /// Removes the `"0 <addr> "` header of a daisy-chain reply, checking that
    /// it comes from the controller the command was sent to.
    pub fn strip_header(mut self, expected: Address) -> Result<Self, FrameError> {
        let header = format!("0 {expected} ");
        let first = self.lines.first().map(Vec::as_slice).unwrap_or(&[]);
        if first.starts_with(header.as_bytes()) {
            if let Some(l) = self.lines.first_mut() {
                l.drain(..header.len());
            }
            Ok(self)
        } else {
            Err(FrameError::BadReplyHeader {
                expected,
                got: bytes_to_text(&first[..first.len().min(16)]),
            })
        }
    }
}

/// What the host side of the line decoded.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum AnswerItem {
    /// A complete answer.
    Answer(Answer),
    /// An answer exceeded [`MAX_ANSWER_LEN`]; its bytes up to the next
    /// terminating LF were dropped.
    Overlong,
}

/// Turns the byte stream the host receives into answers.
#[derive(Debug, Default)]
pub struct AnswerDecoder {
    lines: Vec<Vec<u8>>,
    current: Vec<u8>,
    size: usize,
    discarding: bool,
}

impl AnswerDecoder {
    /// A decoder with an empty buffer.
    pub fn new() -> Self {
        Self::default()
    }

    /// Feeds received bytes; returns the answers they complete, in order.
    pub fn push(&mut self, bytes: &[u8]) -> Vec<AnswerItem> {
        let mut out = Vec::new();
        for &b in bytes {
            if b == b'\n' {
                let continued = self.current.last() == Some(&b' ');
                if continued {
                    self.current.pop();
                }
                if !self.discarding {
                    self.lines.push(std::mem::take(&mut self.current));
                }
                self.current.clear();
                if !continued {
                    if self.discarding {
                        out.push(AnswerItem::Overlong);
                    } else {
                        out.push(AnswerItem::Answer(Answer {
                            lines: std::mem::take(&mut self.lines),
                        }));
                    }
                    self.reset();
                }
                continue;
            }
            if self.discarding {
                // Remember only whether the last byte was a space.
                self.current.clear();
                self.current.push(b);
                continue;
            }
            self.size += 1;
            if self.size > MAX_ANSWER_LEN {
                self.lines.clear();
                self.current.clear();
                self.current.push(b);
                self.discarding = true;
                continue;
            }
            self.current.push(b);
        }
        out
    }

    /// Whether part of an answer is buffered.
    pub fn is_mid_answer(&self) -> bool {
        !self.lines.is_empty() || !self.current.is_empty() || self.discarding
    }

    /// Drops any partial answer (after a timeout or a reconnect, so stale bytes
    /// never complete a later answer).
    pub fn reset(&mut self) {
        self.lines.clear();
        self.current.clear();
        self.size = 0;
        self.discarding = false;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn line(addr: Option<u8>, text: &str) -> Request {
        Request::Line {
            addr: addr.map(|a| Address::new(a).unwrap()),
            text: text.into(),
        }
    }

    #[test]
    fn request_lines_and_addresses() {
        let mut d = RequestDecoder::new();
        assert_eq!(
            d.push(b"POS? 1\n2 MOV 1 3.5\n17 X\n"),
            vec![
                line(None, "POS? 1"),
                line(Some(2), "MOV 1 3.5"),
                line(None, "17 X"),
            ]
        );
        assert_eq!(d.push(b"*ID"), vec![]);
        assert_eq!(d.pending(), 3);
        assert_eq!(d.push(b"N?\n"), vec![line(None, "*IDN?")]);
    }

    #[test]
    fn control_chars_are_immediate() {
        let mut d = RequestDecoder::new();
        assert_eq!(
            d.push(&[5]),
            vec![Request::Control {
                addr: None,
                command: ControlChar::MotionStatus
            }]
        );
        assert_eq!(
            d.push(b"2 \x07"),
            vec![Request::Control {
                addr: Some(Address::new(2).unwrap()),
                command: ControlChar::Ready
            }]
        );
        // #24 in the middle of a line stops at once; the line goes on.
        assert_eq!(
            d.push(b"MO\x18V 1 2\n"),
            vec![
                Request::Control {
                    addr: None,
                    command: ControlChar::StopAll
                },
                line(None, "MOV 1 2"),
            ]
        );
    }

    #[test]
    fn overlong_lines_are_dropped_whole() {
        let mut d = RequestDecoder::new();
        let mut long = vec![b'A'; MAX_LINE_LEN + 10];
        long.push(b'\n');
        long.extend_from_slice(b"ERR?\n");
        assert_eq!(d.push(&long), vec![Request::Overlong, line(None, "ERR?")]);
    }

    #[test]
    fn encoding() {
        let a2 = Address::new(2).unwrap();
        assert_eq!(encode_line(None, "POS? 1").unwrap(), b"POS? 1\n");
        assert_eq!(encode_line(Some(a2), "POS? 1").unwrap(), b"2 POS? 1\n");
        assert!(encode_line(None, "A\nB").is_err());
        assert!(encode_line(None, "A\x18").is_err());
        assert_eq!(encode_control(None, ControlChar::Ready), vec![7]);
        assert_eq!(encode_control(Some(a2), ControlChar::StopAll), b"2 \x18");
        assert_eq!(encode_answer(None, &["1=2.5".into()]), b"1=2.5\n");
        assert_eq!(
            encode_answer(Some(a2), &["a".into(), "b".into()]),
            b"0 2 a \nb\n"
        );
        assert!(Address::new(0).is_err());
        assert!(Address::new(17).is_err());
    }

    #[test]
    fn answers_multiline_and_headers() {
        let mut d = AnswerDecoder::new();
        let items = d.push(b"1=1.0 \n2=2.0\n0 2 1=5\n");
        assert_eq!(items.len(), 2);
        let AnswerItem::Answer(a) = &items[0] else {
            panic!()
        };
        assert_eq!(a.lines(), vec!["1=1.0", "2=2.0"]);
        let AnswerItem::Answer(b) = items[1].clone() else {
            panic!()
        };
        let b = b.strip_header(Address::new(2).unwrap()).unwrap();
        assert_eq!(b.lines(), vec!["1=5"]);
        let c = Answer::from_lines(vec![b"0 3 x".to_vec()]);
        assert!(c.strip_header(Address::new(2).unwrap()).is_err());
        // #7 answer: raw byte 0xB1.
        let items = d.push(&[0xB1, b'\n']);
        let AnswerItem::Answer(r) = &items[0] else {
            panic!()
        };
        assert_eq!(r.raw_lines(), &[vec![0xB1]]);
        assert!(!d.is_mid_answer());
        d.push(b"partial");
        assert!(d.is_mid_answer());
        d.reset();
        assert!(!d.is_mid_answer());
    }

    #[test]
    fn overlong_answers_resynchronise() {
        let mut d = AnswerDecoder::new();
        let mut bytes = Vec::new();
        for _ in 0..(MAX_ANSWER_LEN / 10 + 10) {
            bytes.extend_from_slice(b"123456789 \n");
        }
        bytes.extend_from_slice(b"end\nok\n");
        let items = d.push(&bytes);
        assert_eq!(items.len(), 2);
        assert_eq!(items[0], AnswerItem::Overlong);
        assert_eq!(
            items[1],
            AnswerItem::Answer(Answer::from_lines(vec![b"ok".to_vec()]))
        );
    }

    proptest! {
        #[test]
        fn decoders_never_panic_and_stay_bounded(chunks in proptest::collection::vec(proptest::collection::vec(any::<u8>(), 0..300), 0..40)) {
            let mut r = RequestDecoder::new();
            let mut a = AnswerDecoder::new();
            for c in &chunks {
                r.push(c);
                a.push(c);
                prop_assert!(r.pending() <= MAX_LINE_LEN);
                prop_assert!(a.size <= MAX_ANSWER_LEN);
            }
        }

        #[test]
        fn chunking_does_not_matter(data in proptest::collection::vec(any::<u8>(), 0..600), split in 0usize..600) {
            let split = split.min(data.len());
            let mut whole = RequestDecoder::new();
            let mut parts = RequestDecoder::new();
            let w = whole.push(&data);
            let mut p = parts.push(&data[..split]);
            p.extend(parts.push(&data[split..]));
            prop_assert_eq!(w, p);
            let mut whole = AnswerDecoder::new();
            let mut parts = AnswerDecoder::new();
            let w = whole.push(&data);
            let mut p = parts.push(&data[..split]);
            p.extend(parts.push(&data[split..]));
            prop_assert_eq!(w, p);
        }

        #[test]
        fn answers_round_trip(lines in proptest::collection::vec("[ -~&&[^ ]][ -~]{0,20}[!-~]", 1..6), addr in proptest::option::of(1u8..=16)) {
            let addr = addr.map(|a| Address::new(a).unwrap());
            let bytes = encode_answer(addr, &lines);
            let mut d = AnswerDecoder::new();
            let items = d.push(&bytes);
            prop_assert_eq!(items.len(), 1);
            let AnswerItem::Answer(ans) = items[0].clone() else { panic!() };
            let ans = match addr { Some(a) => ans.strip_header(a).unwrap(), None => ans };
            prop_assert_eq!(ans.lines(), lines);
        }

        #[test]
        fn requests_round_trip(text in "[A-Z*]{1,4}\\??( [0-9A-Za-z.+-]{1,10}){0,4}", addr in proptest::option::of(1u8..=16)) {
            let addr = addr.map(|a| Address::new(a).unwrap());
            let bytes = encode_line(addr, &text).unwrap();
            let mut d = RequestDecoder::new();
            prop_assert_eq!(d.push(&bytes), vec![Request::Line { addr, text: text.clone() }]);
        }
    }
}
