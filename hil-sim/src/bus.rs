//! Several controllers behind one serial line (a daisy chain), sans-IO.
//!
//! Every controller on a real chain sees every byte; each acts only on the
//! commands addressed to it (no prefix = address 1). One shared
//! [`RequestDecoder`] therefore stands for all of them: they all frame the
//! same bytes the same way.

use crate::controller::Controller;
use micropos::gcs::frame::{Request, RequestDecoder};
use micropos::gcs::Address;
use std::time::Duration;

/// An answer and which controller (index on the bus) sent it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Reply {
    /// Index of the sender in [`Bus::controllers`].
    pub from: usize,
    /// The bytes it writes.
    pub bytes: Vec<u8>,
}

/// Why a bus cannot be built.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum BusError {
    /// Two controllers were given the same DIP-switch address.
    #[error("two controllers share daisy-chain address {0}")]
    DuplicateAddress(Address),
}

/// The controllers on one line.
#[derive(Debug)]
pub struct Bus {
    decoder: RequestDecoder,
    controllers: Vec<Controller>,
}

impl Bus {
    /// A line with these controllers (addresses must differ).
    pub fn new(controllers: Vec<Controller>) -> Result<Self, BusError> {
        for (i, c) in controllers.iter().enumerate() {
            if controllers[..i].iter().any(|o| o.address() == c.address()) {
                return Err(BusError::DuplicateAddress(c.address()));
            }
        }
        Ok(Self {
            decoder: RequestDecoder::new(),
            controllers,
        })
    }

    /// The controllers, in the order given.
    pub fn controllers(&self) -> &[Controller] {
        &self.controllers
    }

    /// Mutable access to one controller (power cycle, platform model).
    pub fn controller_mut(&mut self, index: usize) -> Option<&mut Controller> {
        self.controllers.get_mut(index)
    }

    /// Feeds bytes received from the host at simulated time `now`; returns
    /// the replies in the order they are due.
    pub fn receive(&mut self, now: Duration, bytes: &[u8]) -> Vec<Reply> {
        let mut out = Vec::new();
        for req in self.decoder.push(bytes) {
            out.extend(self.handle(now, &req));
        }
        out
    }

    /// Handles one decoded request.
    pub fn handle(&mut self, now: Duration, req: &Request) -> Vec<Reply> {
        self.controllers
            .iter_mut()
            .enumerate()
            .filter_map(|(from, c)| c.handle(now, req).map(|bytes| Reply { from, bytes }))
            .collect()
    }

    /// Drops a partial command line (the line was cut: whatever the host had
    /// half-sent is gone, as on a real UART after a break).
    pub fn reset_line(&mut self) {
        self.decoder = RequestDecoder::new();
    }
}
