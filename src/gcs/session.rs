//! The host side of one serial line as a deterministic state machine.
//!
//! quinn-proto style: the caller feeds it the time and the bytes it read and
//! sends the bytes it returns; the session decides what an exchange is, when
//! it has timed out and what arrived out of turn. The tokio driver is a thin
//! shell around it, and every timing rule is testable without a clock.
//!
//! One exchange at a time: GCS over RS-232 has no request ids, so answers are
//! matched to requests only by order. A second request before the first is
//! answered (or timed out) would make that matching a guess, so it is refused.

use super::command::Command;
use super::frame::{
    encode_control, encode_line, Address, Answer, AnswerDecoder, AnswerItem, ControlChar,
    FrameError,
};
use std::time::Duration;
use thiserror::Error;

/// What to send.
#[derive(Debug, Clone, PartialEq)]
pub enum Outgoing {
    /// A typed command.
    Command(Command),
    /// A single-character command.
    Control(ControlChar),
    /// A raw line typed by a person (the `micropos gcs` console). It expects
    /// an answer when its first word ends in `?`.
    Raw(String),
}

impl Outgoing {
    /// Whether the controller answers it.
    pub fn expects_answer(&self) -> bool {
        match self {
            Self::Command(c) => c.is_query(),
            Self::Control(c) => c.has_answer(),
            Self::Raw(t) => t
                .split(' ')
                .find(|w| !w.is_empty())
                .is_some_and(|w| w.ends_with('?')),
        }
    }

    fn encode(&self, addr: Option<Address>) -> Result<Vec<u8>, FrameError> {
        match self {
            Self::Command(c) => encode_line(addr, &c.to_text()),
            Self::Control(c) => Ok(encode_control(addr, *c)),
            Self::Raw(t) => encode_line(addr, t),
        }
    }
}

/// Why a request could not be started.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum SessionError {
    /// An exchange is still waiting for its answer.
    #[error("an exchange is still waiting for its answer")]
    Busy,
    /// The request cannot be framed.
    #[error(transparent)]
    Frame(#[from] FrameError),
}

/// What the session has to report.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum SessionEvent {
    /// The answer to the pending request (daisy-chain header removed).
    Answer(Answer),
    /// No complete answer before the deadline. A C-863 stays silent on an
    /// unknown command (and sets error 2), so silence alone does not say
    /// whether the command was unknown or the controller is gone: the caller
    /// asks `ERR?` to tell them apart.
    Silence {
        /// Whether part of an answer had arrived (a cut-off answer points to a
        /// line fault rather than an unknown command).
        partial: bool,
    },
    /// Bytes that belong to no request: garbage on the line, a late answer
    /// after a timeout, an answer from the wrong daisy-chain address, or an
    /// answer too long to keep.
    Unexpected(String),
}

#[derive(Debug, Clone)]
struct Pending {
    addr: Option<Address>,
    timeout: Duration,
    deadline: Duration,
}

/// Host side of one serial line (one controller, or a daisy chain).
#[derive(Debug, Default)]
pub struct Session {
    decoder: AnswerDecoder,
    pending: Option<Pending>,
}

impl Session {
    /// An idle session.
    pub fn new() -> Self {
        Self::default()
    }

    /// Starts an exchange at time `now`; returns the bytes to write.
    ///
    /// `addr` is the daisy-chain address, or `None` for a controller alone on
    /// its line. Requests without an answer (set commands, `#24`) leave the
    /// session idle at once. `timeout` counts from the last byte received, as
    /// PI's own clients do, so a long answer at a slow baud rate is not cut.
    pub fn start(
        &mut self,
        now: Duration,
        addr: Option<Address>,
        out: &Outgoing,
        timeout: Duration,
    ) -> Result<Vec<u8>, SessionError> {
        if self.pending.is_some() {
            return Err(SessionError::Busy);
        }
        let bytes = out.encode(addr)?;
        if out.expects_answer() {
            self.pending = Some(Pending {
                addr,
                timeout,
                deadline: now + timeout,
            });
        }
        Ok(bytes)
    }

    /// Whether an answer is awaited.
    pub fn is_busy(&self) -> bool {
        self.pending.is_some()
    }

    /// When [`Session::on_time`] must next be called, if an answer is awaited.
    pub fn deadline(&self) -> Option<Duration> {
        self.pending.as_ref().map(|p| p.deadline)
    }

    /// Feeds bytes read from the line at time `now`.
    pub fn on_bytes(&mut self, now: Duration, bytes: &[u8]) -> Vec<SessionEvent> {
        if let Some(p) = self.pending.as_mut() {
            if !bytes.is_empty() {
                p.deadline = now + p.timeout;
            }
        }
        let mut out = Vec::new();
        for item in self.decoder.push(bytes) {
            match item {
                AnswerItem::Overlong => out.push(SessionEvent::Unexpected(
                    "answer too long; dropped".to_owned(),
                )),
                AnswerItem::Answer(a) => match self.pending.take() {
                    None => out.push(SessionEvent::Unexpected(format!(
                        "unrequested bytes on the line: {:?}",
                        truncate(&a.text())
                    ))),
                    Some(Pending { addr: None, .. }) => out.push(SessionEvent::Answer(a)),
                    Some(
                        p @ Pending {
                            addr: Some(expected),
                            ..
                        },
                    ) => match a.strip_header(expected) {
                        Ok(a) => out.push(SessionEvent::Answer(a)),
                        Err(e) => {
                            // Not ours: keep waiting for the real answer.
                            self.pending = Some(p);
                            out.push(SessionEvent::Unexpected(e.to_string()));
                        }
                    },
                },
            }
        }
        out
    }

    /// Checks the deadline at time `now`.
    pub fn on_time(&mut self, now: Duration) -> Option<SessionEvent> {
        let p = self.pending.as_ref()?;
        if now < p.deadline {
            return None;
        }
        self.pending = None;
        let partial = self.decoder.is_mid_answer();
        self.decoder.reset();
        Some(SessionEvent::Silence { partial })
    }

    /// Forgets everything in flight (after a reconnect): stale bytes of the
    /// old connection must never complete a new answer.
    pub fn reset(&mut self) {
        self.pending = None;
        self.decoder.reset();
    }
}

fn truncate(s: &str) -> String {
    s.chars().take(60).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gcs::command::AxisId;

    const T: Duration = Duration::from_millis(100);

    fn ms(v: u64) -> Duration {
        Duration::from_millis(v)
    }

    fn pos_query() -> Outgoing {
        Outgoing::Command(Command::PosQuery(vec![AxisId::new("1").unwrap()]))
    }

    #[test]
    fn query_answer_cycle() {
        let mut s = Session::new();
        let bytes = s.start(ms(0), None, &pos_query(), T).unwrap();
        assert_eq!(bytes, b"POS? 1\n");
        assert!(s.is_busy());
        assert_eq!(
            s.start(ms(1), None, &pos_query(), T),
            Err(SessionError::Busy)
        );
        assert_eq!(s.on_bytes(ms(5), b"1=1.5"), vec![]);
        let ev = s.on_bytes(ms(6), b"\n");
        assert_eq!(
            ev,
            vec![SessionEvent::Answer(Answer::from_lines(vec![
                b"1=1.5".to_vec()
            ]))]
        );
        assert!(!s.is_busy());
    }

    #[test]
    fn set_commands_leave_session_idle() {
        let mut s = Session::new();
        let out = Outgoing::Command(Command::Mov(vec![(AxisId::new("1").unwrap(), 2.0)]));
        assert_eq!(s.start(ms(0), None, &out, T).unwrap(), b"MOV 1 2\n");
        assert!(!s.is_busy());
        assert_eq!(
            s.start(ms(0), None, &Outgoing::Control(ControlChar::StopAll), T)
                .unwrap(),
            vec![24]
        );
        assert!(!s.is_busy());
        assert!(Outgoing::Raw("POS? 1".into()).expects_answer());
        assert!(!Outgoing::Raw("MOV 1 1".into()).expects_answer());
    }

    #[test]
    fn silence_and_deadline_extension() {
        let mut s = Session::new();
        s.start(ms(0), None, &pos_query(), T).unwrap();
        assert_eq!(s.deadline(), Some(ms(100)));
        assert_eq!(s.on_time(ms(99)), None);
        s.on_bytes(ms(90), b"1=");
        assert_eq!(s.deadline(), Some(ms(190)));
        assert_eq!(s.on_time(ms(150)), None);
        assert_eq!(
            s.on_time(ms(190)),
            Some(SessionEvent::Silence { partial: true })
        );
        assert!(!s.is_busy());
        // The cut-off bytes must not glue onto the next answer.
        s.start(ms(200), None, &pos_query(), T).unwrap();
        assert_eq!(
            s.on_bytes(ms(201), b"1=2\n"),
            vec![SessionEvent::Answer(Answer::from_lines(vec![
                b"1=2".to_vec()
            ]))]
        );
        s.start(ms(300), None, &pos_query(), T).unwrap();
        assert_eq!(
            s.on_time(ms(400)),
            Some(SessionEvent::Silence { partial: false })
        );
    }

    #[test]
    fn unexpected_bytes_and_daisy_chain() {
        let mut s = Session::new();
        assert!(matches!(
            s.on_bytes(ms(0), b"junk\n")[0],
            SessionEvent::Unexpected(_)
        ));
        let a2 = Address::new(2).unwrap();
        assert_eq!(
            s.start(ms(0), Some(a2), &pos_query(), T).unwrap(),
            b"2 POS? 1\n"
        );
        let ev = s.on_bytes(ms(1), b"0 3 1=9\n0 2 1=4\n");
        assert!(matches!(ev[0], SessionEvent::Unexpected(_)));
        assert_eq!(
            ev[1],
            SessionEvent::Answer(Answer::from_lines(vec![b"1=4".to_vec()]))
        );
        s.start(ms(10), None, &pos_query(), T).unwrap();
        s.on_bytes(ms(11), b"1=");
        s.reset();
        assert!(!s.is_busy());
    }
}
