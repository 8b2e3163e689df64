//! The async PI C-863 driver: a thin tokio shell around the sans-IO GCS core
//! ([`crate::gcs`]).
//!
//! Layers, bottom up:
//! - [`transport`]: opens (and reopens) a line's byte stream; real serial
//!   devices through `tokio-serial`, or any `AsyncRead + AsyncWrite` in tests.
//! - [`line`]: one task per serial line (a daisy chain is one line serving
//!   several controllers), one exchange at a time, timeouts, resync after
//!   silence, reconnect with backoff.
//! - [`controller`]: GCS transactions with one address: queries, set commands
//!   followed by `ERR?`, silence read as "unknown command" or "not answering".
//! - [`axis`]: one C-863 axis in micrometres, with bring-up, referencing and
//!   the rule that positions are only reported while referenced.
//! - [`stage`]: the two axes of an XY stage from configuration, sharing a line
//!   when daisy-chained.
//!
//! Faults are reported twice: as errors on the calls they affect, and as
//! [`AxisEvent`]s on a broadcast channel for whoever watches the rig.
//!
//! Shutdown: dropping every handle ends the line tasks (after the exchange in
//! flight) and closes the devices. Nothing is sent on close: an axis that is
//! moving keeps moving to its target and the servo stays on. Call
//! [`Axis::halt`] first if the stage must stop; [`halt::halt_all`] stops
//! both axes from the configuration alone (`microposd --halt`).

pub mod axis;
pub mod controller;
pub mod error;
pub mod halt;
pub mod line;
pub mod profile;
pub mod stage;
pub mod transport;
pub mod units;

#[cfg(test)]
mod fake;
#[cfg(test)]
mod tests;

pub use axis::{Axis, AxisParams, AxisStatus, ReferenceMode};
pub use controller::{ConsoleReply, Controller};
pub use error::DriverError;
pub use line::{Line, LineOptions};
pub use stage::{AxisConfig, DriverConfig, Stage};
pub use transport::{
    Connector, Framing, LinkIo, LinkOpener, OpenFuture, OpenerConnector, SerialConnector,
    SerialSettings,
};

/// Something the watcher of the rig should know about, as it happens.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum AxisEvent {
    /// A line was opened or reopened.
    Connected {
        /// The device path.
        line: String,
    },
    /// A line went down (device gone, read/write error, end of file). The
    /// driver keeps reopening it.
    Disconnected {
        /// The device path.
        line: String,
        /// What happened.
        reason: String,
    },
    /// Bytes that belong to no request (garbage, a late answer). They were
    /// dropped, never attributed to a request.
    Noise {
        /// The device path.
        line: String,
        /// The bytes as text (truncated).
        text: String,
    },
    /// One answer could not be parsed (line noise inside an answer, a late
    /// answer to an earlier command). The call that got it failed with
    /// [`DriverError::BadAnswer`] and the line was drained; the controller
    /// is alive, so this is not a [`AxisEvent::Fault`]: the caller decides
    /// (a daemon job retries, an interactive move fails).
    Garbled {
        /// Line and address.
        source: String,
        /// The error, readable.
        error: String,
    },
    /// A controller stopped answering, or changed.
    Fault {
        /// Axis name or line and address.
        source: String,
        /// The error, readable.
        error: String,
    },
    /// A referenced axis is no longer referenced (power cycle): positions are
    /// refused until it is referenced again.
    ReferenceLost {
        /// The axis name.
        axis: String,
    },
    /// The axis is referenced (at bring-up or after referencing).
    Referenced {
        /// The axis name.
        axis: String,
    },
}
