//! GCS transactions with one controller (one address on a line): queries,
//! set commands followed by `ERR?` as PI's own clients do, and the reading of
//! silence.
//!
//! A C-863 stays silent on a command it does not know and sets error 2, so a
//! silent query is followed by `ERR?`: a non-zero code is the controller's
//! refusal ([`DriverError::Gcs`], e.g. PI_CNTR_UNKNOWN_COMMAND); 0 means the
//! answer was lost or late ([`DriverError::Timeout`]); a silent `ERR?` means
//! nothing answers ([`DriverError::NotAnswering`]).
//!
//! Transactions on one controller are serialised (a lock per controller), so
//! the `ERR?` that follows a command always reports on that command. Commands
//! to other controllers on the same daisy chain may run in between; the error
//! register is per controller, so that is harmless.

use super::error::DriverError;
use super::line::{Line, Outcome};
use super::AxisEvent;
use crate::gcs::answer::{self, Identification};
use crate::gcs::frame::Address;
use crate::gcs::{Answer, Command, ControlChar, GcsErrorCode, Outgoing};
use std::sync::Arc;
use std::time::Duration;
use tokio::sync::{broadcast, Mutex};

/// Handle to one controller on a line. Cheap to clone; clones share the
/// transaction lock.
#[derive(Debug, Clone)]
pub struct Controller {
    line: Line,
    addr: Option<Address>,
    timeout: Duration,
    label: Arc<str>,
    lock: Arc<Mutex<()>>,
    events: broadcast::Sender<AxisEvent>,
}

/// What the raw console got back for one line typed by a person.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ConsoleReply {
    /// The answer, if the command has one and it arrived.
    pub answer: Option<Answer>,
    /// Whether a query stayed silent (the controller refused it; see `error`).
    pub silent: bool,
    /// The `ERR?` that followed.
    pub error: GcsErrorCode,
}

impl Controller {
    /// A controller at `addr` on `line` (`None`: alone on its line, no
    /// address prefix). `timeout` is the answer timeout, counted from the
    /// last byte received.
    pub fn new(
        line: Line,
        addr: Option<Address>,
        timeout: Duration,
        events: broadcast::Sender<AxisEvent>,
    ) -> Self {
        let label = match addr {
            Some(a) => format!("{} address {a}", line.name()),
            None => line.name().to_owned(),
        };
        Self {
            line,
            addr,
            timeout,
            label: label.into(),
            lock: Arc::new(Mutex::new(())),
            events,
        }
    }

    /// Line and address, for messages.
    pub fn label(&self) -> &str {
        &self.label
    }

    /// The line this controller is on.
    pub fn line(&self) -> &Line {
        &self.line
    }

    /// The daisy-chain address (`None`: alone on its line).
    pub fn address(&self) -> Option<Address> {
        self.addr
    }

    /// The answer timeout.
    pub fn timeout(&self) -> Duration {
        self.timeout
    }

    fn not_answering(&self) -> DriverError {
        let e = DriverError::NotAnswering {
            target: self.label.to_string(),
        };
        let _ = self.events.send(AxisEvent::Fault {
            source: self.label.to_string(),
            error: e.to_string(),
        });
        e
    }

    /// Reads and clears the error register. Caller holds the lock.
    async fn read_error(&self) -> Result<(GcsErrorCode, u64), DriverError> {
        let r = self
            .line
            .exchange(self.addr, Outgoing::Command(Command::Err), self.timeout)
            .await?;
        match r.outcome {
            Outcome::Answer(a) => match answer::error_code(&a) {
                Ok(code) => Ok((code, r.epoch)),
                Err(e) => {
                    self.line.resync(self.timeout).await;
                    Err(DriverError::BadAnswer {
                        command: "ERR?".to_owned(),
                        detail: e.to_string(),
                        text: short(&a.text()),
                    })
                }
            },
            Outcome::Silence { .. } | Outcome::Sent => Err(self.not_answering()),
        }
    }

    /// Asks `*IDN?` and checks that a PI controller answered (any model).
    /// A device that stays silent but answers `ERR?` is not a PI controller
    /// either; one that answers nothing is [`DriverError::NotAnswering`].
    pub async fn identify(&self) -> Result<(Identification, u64), DriverError> {
        let (a, epoch) = match self.query(&Command::Idn).await {
            Ok(v) => v,
            Err(DriverError::Gcs { .. } | DriverError::Timeout { .. }) => {
                return Err(DriverError::NotPi {
                    target: self.label.to_string(),
                    idn: "(no answer to *IDN?)".to_owned(),
                })
            }
            Err(e) => return Err(e),
        };
        let text = a.text();
        let not_pi = || DriverError::NotPi {
            target: self.label.to_string(),
            idn: text.chars().take(120).collect(),
        };
        let idn = match answer::identification(&a) {
            Ok(idn) => idn,
            Err(_) => {
                // Garbage or a late answer may be behind it: drain before the next request.
                self.line.resync(self.timeout).await;
                return Err(not_pi());
            }
        };
        let vendor = idn.vendor.to_ascii_uppercase();
        if !(vendor.contains("(PI)") || vendor.contains("PHYSIK INSTRUMENTE")) {
            return Err(not_pi());
        }
        Ok((idn, epoch))
    }

    /// Sends a query and returns its answer with the connection epoch.
    pub async fn query(&self, cmd: &Command) -> Result<(Answer, u64), DriverError> {
        let _g = self.lock.lock().await;
        self.query_locked(Outgoing::Command(cmd.clone()), cmd.to_text())
            .await
    }

    async fn query_locked(
        &self,
        out: Outgoing,
        text: String,
    ) -> Result<(Answer, u64), DriverError> {
        let r = self.line.exchange(self.addr, out, self.timeout).await?;
        match r.outcome {
            Outcome::Answer(a) => Ok((a, r.epoch)),
            Outcome::Silence { partial } => {
                let (code, epoch) = self.read_error().await?;
                if epoch != r.epoch {
                    return Err(self.interrupted(&text));
                }
                if code.is_ok() {
                    Err(DriverError::Timeout {
                        command: text,
                        timeout: self.timeout,
                        partial,
                    })
                } else {
                    Err(DriverError::Gcs {
                        command: text,
                        code,
                    })
                }
            }
            Outcome::Sent => Err(DriverError::Invalid(format!(
                "`{text}` is not a query, nothing to read"
            ))),
        }
    }

    /// Sends a set command, then `ERR?`; `Ok(epoch)` when the code is 0.
    pub async fn set(&self, cmd: &Command) -> Result<u64, DriverError> {
        let (code, epoch) = self.set_with_code(cmd).await?;
        if code.is_ok() {
            Ok(epoch)
        } else {
            Err(DriverError::Gcs {
                command: cmd.to_text(),
                code,
            })
        }
    }

    /// Sends a set command, then `ERR?`, and returns the code whatever it is
    /// (for commands like `HLT` whose success sets error 10).
    pub async fn set_with_code(&self, cmd: &Command) -> Result<(GcsErrorCode, u64), DriverError> {
        let _g = self.lock.lock().await;
        self.set_locked(Outgoing::Command(cmd.clone()), &cmd.to_text())
            .await
    }

    async fn set_locked(
        &self,
        out: Outgoing,
        text: &str,
    ) -> Result<(GcsErrorCode, u64), DriverError> {
        if self.line.error_unread(self.addr) {
            // Someone else's code may wait in the register (`Line`'s error
            // ledger): read it first, so the `ERR?` below is this command's.
            let (code, _) = self.read_error().await?;
            if !(code.is_ok() || code == GcsErrorCode::STOPPED) {
                return Err(DriverError::PendingError {
                    target: self.label.to_string(),
                    code,
                    command: text.to_owned(),
                });
            }
        }
        let r = self.line.exchange(self.addr, out, self.timeout).await?;
        if r.outcome != Outcome::Sent {
            return Err(DriverError::Invalid(format!("`{text}` is a query")));
        }
        let (code, epoch) = self.read_error().await?;
        if epoch != r.epoch {
            return Err(self.interrupted(text));
        }
        Ok((code, epoch))
    }

    /// Sends a single-character command. `#24` has no answer and returns
    /// `None` (follow it with [`Controller::error`]).
    pub async fn control(&self, c: ControlChar) -> Result<(Option<Answer>, u64), DriverError> {
        let _g = self.lock.lock().await;
        if c.has_answer() {
            let (a, e) = self
                .query_locked(Outgoing::Control(c), format!("#{}", c.byte()))
                .await?;
            Ok((Some(a), e))
        } else {
            let r = self
                .line
                .exchange(self.addr, Outgoing::Control(c), self.timeout)
                .await?;
            Ok((None, r.epoch))
        }
    }

    /// Reads and clears the error register (`ERR?`).
    pub async fn error(&self) -> Result<GcsErrorCode, DriverError> {
        let _g = self.lock.lock().await;
        Ok(self.read_error().await?.0)
    }

    /// Sends a line typed by a person (`#4`, `#5`, `#7`, `#24` are the
    /// single-character commands) and then `ERR?`, whatever the line was.
    pub async fn console(&self, text: &str) -> Result<ConsoleReply, DriverError> {
        let out = match text.trim() {
            "#4" => Outgoing::Control(ControlChar::Status),
            "#5" => Outgoing::Control(ControlChar::MotionStatus),
            "#7" => Outgoing::Control(ControlChar::Ready),
            "#24" => Outgoing::Control(ControlChar::StopAll),
            t => Outgoing::Raw(t.to_owned()),
        };
        let _g = self.lock.lock().await;
        let r = self.line.exchange(self.addr, out, self.timeout).await?;
        let (answer, silent) = match r.outcome {
            Outcome::Answer(a) => (Some(a), false),
            Outcome::Sent => (None, false),
            Outcome::Silence { .. } => (None, true),
        };
        let (error, epoch) = self.read_error().await?;
        if epoch != r.epoch {
            return Err(self.interrupted(text));
        }
        Ok(ConsoleReply {
            answer,
            silent,
            error,
        })
    }

    fn interrupted(&self, command: &str) -> DriverError {
        DriverError::Interrupted {
            target: self.label.to_string(),
            command: command.to_owned(),
        }
    }

    /// Turns an unparsable answer into [`DriverError::BadAnswer`] and drains
    /// the line, so whatever caused it cannot spill into the next answer.
    pub(crate) async fn bad_answer(
        &self,
        command: &Command,
        a: &Answer,
        e: impl std::fmt::Display,
    ) -> DriverError {
        self.line.resync(self.timeout).await;
        let err = DriverError::BadAnswer {
            command: command.to_text(),
            detail: e.to_string(),
            text: short(&a.text()),
        };
        let _ = self.events.send(AxisEvent::Garbled {
            source: self.label.to_string(),
            error: err.to_string(),
        });
        err
    }
}

fn short(s: &str) -> String {
    s.chars().take(80).collect()
}
