//! GCS 2.0 protocol core (sans-IO): framing, typed commands and answers, PI's
//! error codes, and the host-side session state machine.
//!
//! Nothing here touches a file descriptor, a clock or tokio: inputs are bytes
//! and times, outputs are bytes and events. The async driver
//! (`crate::driver`) and the simulated controller (`hil-sim`) are both built
//! on this module, which is what keeps them speaking the same protocol.

pub mod answer;
pub mod command;
pub mod error;
pub mod frame;
pub mod recorder;
pub mod session;

pub use command::{AxisId, Command, CommandError};
pub use error::GcsErrorCode;
pub use frame::{Address, Answer, AnswerDecoder, ControlChar, FrameError, Request, RequestDecoder};
pub use session::{Outgoing, Session, SessionError, SessionEvent};
