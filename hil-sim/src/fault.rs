//! The simulator's shared vocabulary: axis names, the faults a test can
//! inject, the errors of serving, and the reply faults of a line. Why a
//! module of its own: the pty lines (`serve`), the in-process lines
//! (`vline`), the control socket (`control`) and the camera server all use
//! these, and none of them should have to import another server to get them.

use crate::bus::BusError;
use std::fmt;
use std::io;
use std::path::PathBuf;
use std::time::Duration;

/// One of the two stage axes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum AxisName {
    /// The X axis (first controller; address 1 on a daisy chain).
    X,
    /// The Y axis (second controller; address 2 on a daisy chain).
    Y,
}

impl AxisName {
    /// Both axes, X first.
    pub const ALL: [AxisName; 2] = [AxisName::X, AxisName::Y];

    pub(crate) fn index(self) -> usize {
        match self {
            Self::X => 0,
            Self::Y => 1,
        }
    }
}

impl fmt::Display for AxisName {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::X => "x",
            Self::Y => "y",
        })
    }
}

impl std::str::FromStr for AxisName {
    type Err = SimError;
    fn from_str(s: &str) -> Result<Self, SimError> {
        match s {
            "x" | "X" => Ok(Self::X),
            "y" | "Y" => Ok(Self::Y),
            other => Err(SimError::Config(format!(
                "unknown axis {other:?} (expected \"x\" or \"y\")"
            ))),
        }
    }
}

/// A fault to inject on an axis's line or controller.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Fault {
    /// Pulled cable: pty closed, symlink removed; controller state kept
    /// (motion in progress goes on).
    DropLine,
    /// Cable back: new pty, symlink re-pointed to it.
    RestoreLine,
    /// Controller reset: unreferenced, servo off, position 0, error 0,
    /// motion stopped, parameters back to defaults; line stays up.
    PowerCycle,
    /// The carriage jams mid-move (`Controller::stall`): it stops where it
    /// is while the controller keeps trying (a following error); a stop, a
    /// halt or a new move ends it.
    Stall,
    /// A servo fault (`Controller::motion_error`): motion cut, servo off,
    /// error 1024 pending for the next `ERR?`.
    MotionError,
    /// The carriage slips against the encoder (`Controller::slip`): the
    /// platform jumps by `slip_um` along +axis while the controller's count
    /// does not change, moving or at rest. The controller sees nothing; only
    /// an outside measurement (the camera) does. Whole µm: a fault size,
    /// not a measurement.
    Slip {
        /// Jump of the platform against the encoder, µm (either sign).
        slip_um: i32,
    },
    /// These bytes are written to the host at once.
    Garbage(Vec<u8>),
    /// Every reply is delayed by this much wall time (`Duration::ZERO` to
    /// undo).
    DelayReplies(Duration),
    /// true: the controller reads and executes but never answers.
    WithholdReplies(bool),
    /// The next `count` value answers (replies with an `=`, as to `POS?`,
    /// `ONT?`) of the controller are corrupted as `how` says; other replies
    /// (`ERR?`, `*IDN?`) pass. Why value answers only: a transient glitch
    /// that hits one query is what a host must ride through (the
    /// daemon's job retries), and targeting them makes the glitch land on
    /// a known exchange so tests are deterministic.
    CorruptReplies {
        /// What happens to each of them.
        how: Corruption,
        /// How many value answers are hit (0 clears a pending fault).
        count: u32,
    },
}

/// How [`Fault::CorruptReplies`] corrupts a reply.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Corruption {
    /// The value is replaced by unparsable bytes (line noise inside an
    /// answer); the terminating newline stays, so the answer ends on time.
    Garble,
    /// The reply is lost (the host's query times out; `ERR?` still answers).
    Drop,
}

/// What can go wrong while serving.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    /// The configuration or a request is invalid.
    #[error("invalid configuration: {0}")]
    Config(String),
    /// A system call on a file, pty or socket failed.
    #[error("{context}: {source}")]
    Io {
        /// What was being done.
        context: String,
        /// The OS error.
        source: io::Error,
    },
    /// The line of this axis is down (after [`Fault::DropLine`]).
    #[error("the line of axis {0} is down")]
    LineDown(AxisName),
    /// A controller did not answer its readiness probe.
    #[error("controller of axis {axis} did not answer at {link}: {why}")]
    NotReady {
        /// Which axis.
        axis: AxisName,
        /// The link probed.
        link: PathBuf,
        /// What happened.
        why: String,
    },
    /// The serving thread of a line is gone.
    #[error("the serving thread of axis {0} has stopped")]
    ThreadGone(AxisName),
    /// Controllers could not be put on a bus.
    #[error(transparent)]
    Bus(#[from] BusError),
}

/// `answer` with everything after each `=` replaced by bytes no GCS value
/// parses as (the line structure, `=` and newlines, kept).
fn garble(answer: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(answer.len() + 4);
    let mut in_value = false;
    for &b in answer {
        match b {
            b'=' => {
                in_value = true;
                out.extend_from_slice(b"=#?\x7f");
            }
            b'\n' | b' ' => {
                in_value = false;
                out.push(b);
            }
            _ if in_value => {}
            _ => out.push(b),
        }
    }
    out
}

/// Commands to a line thread.
pub(crate) enum LineCmd {
    /// Pull the cable.
    Drop,
    /// Plug it back.
    Restore,
    /// Write these bytes to the host.
    Garbage(Vec<u8>),
    /// Delay replies of controller `.0` by `.1`.
    Delay(usize, Duration),
    /// Withhold replies of controller `.0`.
    Withhold(usize, bool),
    /// Corrupt the next `.2` value answers of controller `.0`.
    Corrupt(usize, Corruption, u32),
}

/// The reply faults of one line, per controller on its bus
/// ([`Fault::DelayReplies`], [`Fault::WithholdReplies`],
/// [`Fault::CorruptReplies`]): one definition for the pty lines and the
/// in-process ones.
#[derive(Debug, Clone)]
pub(crate) struct ReplyFaults {
    delay: Vec<Duration>,
    withhold: Vec<bool>,
    /// Pending [`Fault::CorruptReplies`] per controller.
    corrupt: Vec<(Corruption, u32)>,
}

impl ReplyFaults {
    /// No fault on any of `n` controllers.
    pub(crate) fn new(n: usize) -> Self {
        ReplyFaults {
            delay: vec![Duration::ZERO; n],
            withhold: vec![false; n],
            corrupt: vec![(Corruption::Garble, 0); n],
        }
    }

    /// Applies a reply-fault command; other commands are not for it.
    pub(crate) fn set(&mut self, cmd: &LineCmd) {
        match *cmd {
            LineCmd::Delay(i, d) => {
                if let Some(slot) = self.delay.get_mut(i) {
                    *slot = d;
                }
            }
            LineCmd::Withhold(i, on) => {
                if let Some(slot) = self.withhold.get_mut(i) {
                    *slot = on;
                }
            }
            LineCmd::Corrupt(i, how, n) => {
                if let Some(slot) = self.corrupt.get_mut(i) {
                    *slot = (how, n);
                }
            }
            LineCmd::Drop | LineCmd::Restore | LineCmd::Garbage(_) => {}
        }
    }

    /// What reaches the host of `replies`, each with its delay.
    pub(crate) fn apply(&mut self, replies: Vec<crate::bus::Reply>) -> Vec<(Duration, Vec<u8>)> {
        let mut out = Vec::with_capacity(replies.len());
        for r in replies {
            if self.withhold.get(r.from).copied().unwrap_or(false) {
                continue;
            }
            let mut bytes = r.bytes;
            if let Some((how, n)) = self.corrupt.get_mut(r.from) {
                if *n > 0 && bytes.contains(&b'=') {
                    *n -= 1;
                    match how {
                        Corruption::Drop => continue,
                        Corruption::Garble => bytes = garble(&bytes),
                    }
                }
            }
            out.push((self.delay.get(r.from).copied().unwrap_or_default(), bytes));
        }
        out
    }
}
