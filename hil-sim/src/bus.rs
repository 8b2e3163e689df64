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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::controller::ControllerConfig;

    fn c(addr: u8) -> Controller {
        Controller::new(ControllerConfig::new(
            Address::new(addr).unwrap(),
            &format!("{addr}"),
            5.0,
        ))
    }

    #[test]
    fn addresses_must_differ() {
        assert_eq!(
            Bus::new(vec![c(1), c(1)]).unwrap_err(),
            BusError::DuplicateAddress(Address::new(1).unwrap())
        );
    }

    #[test]
    fn each_request_reaches_its_controller() {
        let mut bus = Bus::new(vec![c(1), c(2)]).unwrap();
        let t = Duration::ZERO;
        let r = bus.receive(t, b"*IDN?\n2 CSV?\n3 CSV?\n2 SVO 1 1\n2 SVO? 1\n1 SVO? 1\n");
        assert_eq!(r.len(), 4);
        assert_eq!(r[0].from, 0);
        assert!(r[0].bytes.starts_with(b"(c)2015"));
        assert_eq!(
            r[1],
            Reply {
                from: 1,
                bytes: b"0 2 2.0\n".to_vec()
            }
        );
        assert_eq!(
            r[2],
            Reply {
                from: 1,
                bytes: b"0 2 1=1\n".to_vec()
            }
        );
        assert_eq!(
            r[3],
            Reply {
                from: 0,
                bytes: b"0 1 1=0\n".to_vec()
            }
        );
        // A line cut mid-command is forgotten.
        assert!(bus.receive(t, b"2 CS").is_empty());
        bus.reset_line();
        assert_eq!(bus.receive(t, b"V?\n").len(), 0);
        assert_eq!(bus.receive(t, b"2 ERR?\n")[0].bytes, b"0 2 0\n");
        assert_eq!(bus.receive(t, b"ERR?\n")[0].bytes, b"2\n");
        // An overlong line is an error on every controller of the line.
        let mut long = vec![b'A'; 2000];
        long.push(b'\n');
        assert!(bus.receive(t, &long).is_empty());
        assert_eq!(bus.receive(t, b"1 ERR?\n")[0].bytes, b"0 1 3\n");
        assert_eq!(bus.receive(t, b"2 ERR?\n")[0].bytes, b"0 2 3\n");
    }
}
