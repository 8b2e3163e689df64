//! Who gets a connection slot on the socket: sans-IO, so the rule that
//! `stop` always gets through is a property of a plain struct, tested
//! without sockets.
//!
//! Why per uid: slots were first come, first served, so one local client
//! (even one with no role) could hold every client slot and every stop
//! slot, re-opening them as they timed out, and an operator's `stop` got
//! `busy`. Now:
//! * a peer with no role is refused at connect and holds nothing (it could
//!   not even send `stop`, which needs `read`);
//! * one uid holds at most `max_clients_per_uid` full slots and
//!   `stop_slots_per_uid` stop-only slots;
//! * so as long as the caps leave room (`max_clients_per_uid <
//!   max_clients`, `stop_slots_per_uid < stop_slots`, checked with the
//!   configuration), a connection from any other uid with a role is
//!   admitted, with a slot that accepts `stop`, whatever one uid does.
//!
//! Clients that share the operator's uid are the operator's own programs:
//! no rule on the socket can tell them apart from the operator.

use std::collections::HashMap;

/// What a connection may do.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Slot {
    /// Every command its role allows.
    Full,
    /// Only `stop`: the overflow that keeps `stop` reachable.
    StopOnly,
}

/// The answer to a connection.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Admit {
    /// Served in this slot (release it with [`Admission::release`]).
    Slot(Slot),
    /// The peer has no role: refused, holds nothing.
    NoRole,
    /// Every slot this uid may hold, or every slot, is taken.
    Busy,
}

/// The slot limits (`[daemon]`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Limits {
    /// Full slots in all.
    pub(crate) max_clients: usize,
    /// Full slots one uid may hold.
    pub(crate) max_clients_per_uid: usize,
    /// Stop-only slots in all.
    pub(crate) stop_slots: usize,
    /// Stop-only slots one uid may hold.
    pub(crate) stop_slots_per_uid: usize,
}

/// The slots held, per uid.
#[derive(Debug)]
pub(crate) struct Admission {
    limits: Limits,
    held: HashMap<u32, [usize; 2]>,
    total: [usize; 2],
}

fn index(s: Slot) -> usize {
    match s {
        Slot::Full => 0,
        Slot::StopOnly => 1,
    }
}

impl Admission {
    /// No slot held.
    pub(crate) fn new(limits: Limits) -> Self {
        Admission {
            limits,
            held: HashMap::new(),
            total: [0, 0],
        }
    }

    /// A connection from `uid`, whose role is known (`has_role`): a full
    /// slot if this uid and the total allow, else a stop-only one, else
    /// busy.
    pub(crate) fn admit(&mut self, uid: u32, has_role: bool) -> Admit {
        if !has_role {
            return Admit::NoRole;
        }
        let l = self.limits;
        let mine = self.held.get(&uid).copied().unwrap_or([0, 0]);
        let slot = if mine[0] < l.max_clients_per_uid && self.total[0] < l.max_clients {
            Slot::Full
        } else if mine[1] < l.stop_slots_per_uid && self.total[1] < l.stop_slots {
            Slot::StopOnly
        } else {
            return Admit::Busy;
        };
        let k = index(slot);
        self.held.entry(uid).or_insert([0, 0])[k] += 1;
        self.total[k] += 1;
        Admit::Slot(slot)
    }

    /// A connection admitted with `slot` for `uid` has closed.
    pub(crate) fn release(&mut self, uid: u32, slot: Slot) {
        let k = index(slot);
        if let Some(h) = self.held.get_mut(&uid) {
            if h[k] > 0 {
                h[k] -= 1;
                self.total[k] = self.total[k].saturating_sub(1);
            }
            if *h == [0, 0] {
                self.held.remove(&uid);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    const L: Limits = Limits {
        max_clients: 4,
        max_clients_per_uid: 2,
        stop_slots: 2,
        stop_slots_per_uid: 1,
    };

    #[test]
    fn one_uid_cannot_take_every_slot() {
        let mut a = Admission::new(L);
        let got: Vec<Admit> = (0..10).map(|_| a.admit(1000, true)).collect();
        assert_eq!(
            got[..3],
            [
                Admit::Slot(Slot::Full),
                Admit::Slot(Slot::Full),
                Admit::Slot(Slot::StopOnly)
            ]
        );
        assert!(got[3..].iter().all(|g| *g == Admit::Busy));
        // Another uid still gets a full slot, then a stop slot.
        assert_eq!(a.admit(1001, true), Admit::Slot(Slot::Full));
        assert_eq!(a.admit(1001, true), Admit::Slot(Slot::Full));
        assert_eq!(a.admit(1001, true), Admit::Slot(Slot::StopOnly));
        assert_eq!(a.admit(1002, true), Admit::Busy);
        // A closed connection gives its slot back.
        a.release(1000, Slot::Full);
        assert_eq!(a.admit(1002, true), Admit::Slot(Slot::Full));
    }

    #[test]
    fn a_peer_without_a_role_holds_nothing() {
        let mut a = Admission::new(L);
        for _ in 0..100 {
            assert_eq!(a.admit(65534, false), Admit::NoRole);
        }
        assert_eq!(a.admit(1000, true), Admit::Slot(Slot::Full));
    }

    proptest! {
        /// Whatever one uid does (opens and closes in any order, with or
        /// without a role), another uid with a role gets a slot, and so a
        /// connection that accepts `stop`.
        #[test]
        fn stop_gets_through_whatever_one_uid_does(
            ops in proptest::collection::vec((any::<bool>(), any::<bool>()), 0..200),
            max in 2usize..20, stop in 2usize..6,
        ) {
            let limits = Limits {
                max_clients: max,
                max_clients_per_uid: max - 1,
                stop_slots: stop,
                stop_slots_per_uid: 1,
            };
            let mut a = Admission::new(limits);
            let mut open: Vec<Slot> = Vec::new();
            for (opens, role) in ops {
                if opens || open.is_empty() {
                    if let Admit::Slot(s) = a.admit(7, role) {
                        open.push(s);
                    }
                } else if let Some(s) = open.pop() {
                    a.release(7, s);
                }
            }
            let other = a.admit(8, true);
            prop_assert!(matches!(other, Admit::Slot(_)), "{other:?} after {open:?}");
        }
    }
}
