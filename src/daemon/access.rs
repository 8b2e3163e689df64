//! Who is on the other end of a connection and which role they hold.
//!
//! The peer comes from the kernel (`SO_PEERCRED`: uid, primary gid, pid at
//! `connect`), never from anything the client says. Its groups are that
//! gid plus its user's supplementary groups from the group database
//! (`getgrouplist`, NSS-aware); the `[access]` section's group names are
//! resolved to gids the same way. Both lookups may block (LDAP, sssd), so
//! they run on the blocking pool, once per connection.
//!
//! [`Policy`] is the sans-IO core: gids per role in, the highest role a
//! set of groups holds out. [`Access`] holds the reloadable section (SIGHUP
//! swaps it; connections made after the swap see the new roles).

use super::config::AccessSection;
use super::protocol::Role;
use std::sync::RwLock;

/// The kernel's credentials of a connected client.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Peer {
    /// User id.
    pub uid: u32,
    /// Primary group id at `connect`.
    pub gid: u32,
    /// Process id at `connect` (`None` where the kernel gives none).
    pub pid: Option<i32>,
}

/// Gids per role, resolved from an [`AccessSection`].
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Policy {
    /// Gids holding `read`.
    pub read: Vec<u32>,
    /// Gids holding `operate`.
    pub operate: Vec<u32>,
    /// Gids holding `admin`.
    pub admin: Vec<u32>,
}

impl Policy {
    /// The highest role any of `groups` holds; `None`: no role at all.
    pub fn role_of(&self, groups: &[u32]) -> Option<Role> {
        let holds = |list: &[u32]| groups.iter().any(|g| list.contains(g));
        if holds(&self.admin) {
            Some(Role::Admin)
        } else if holds(&self.operate) {
            Some(Role::Operate)
        } else if holds(&self.read) {
            Some(Role::Read)
        } else {
            None
        }
    }
}

/// The daemon's access control: the current `[access]` section.
#[derive(Debug, Default)]
pub struct Access {
    section: RwLock<Option<AccessSection>>,
}

impl Access {
    /// Access under `section` (`None`: everyone who connects is admin).
    pub fn new(section: Option<AccessSection>) -> Self {
        Access {
            section: RwLock::new(section),
        }
    }

    /// Replaces the section (SIGHUP reload); new connections use it.
    pub fn set(&self, section: Option<AccessSection>) {
        match self.section.write() {
            Ok(mut s) => *s = section,
            Err(poisoned) => *poisoned.into_inner() = section,
        }
    }

    /// The section in force.
    pub fn current(&self) -> Option<AccessSection> {
        match self.section.read() {
            Ok(s) => s.clone(),
            Err(poisoned) => poisoned.into_inner().clone(),
        }
    }

    /// The role of `peer` (`None`: no role). Without an `[access]` section
    /// this is `admin` and looks nothing up; with one, the group lookups
    /// run on the blocking pool.
    pub async fn role_of(&self, peer: Peer) -> Option<Role> {
        let Some(section) = self.current() else {
            return Some(Role::Admin);
        };
        let r = tokio::task::spawn_blocking(move || {
            let policy = resolve(&section);
            let groups = peer_groups(peer);
            policy.role_of(&groups)
        })
        .await;
        match r {
            Ok(role) => role,
            Err(e) => {
                tracing::warn!("group lookup for uid {} failed: {e}", peer.uid);
                None
            }
        }
    }

    /// Whether an `[access]` section is in force.
    pub fn is_configured(&self) -> bool {
        self.current().is_some()
    }
}

/// Resolves group names to gids (blocking: NSS). A name that does not
/// resolve grants nothing and is logged.
fn resolve(section: &AccessSection) -> Policy {
    let gids = |role: &str, list: &[String]| -> Vec<u32> {
        list.iter()
            .filter_map(|g| match gid_of(g) {
                Some(gid) => Some(gid),
                None => {
                    tracing::warn!("access.{role}: no group {g:?}; it grants nothing");
                    None
                }
            })
            .collect()
    };
    Policy {
        read: gids("read", &section.read),
        operate: gids("operate", &section.operate),
        admin: gids("admin", &section.admin),
    }
}

/// A numeric gid as is, a name through the group database.
fn gid_of(entry: &str) -> Option<u32> {
    if let Ok(n) = entry.parse::<u32>() {
        return Some(n);
    }
    match nix::unistd::Group::from_name(entry) {
        Ok(Some(g)) => Some(g.gid.as_raw()),
        _ => None,
    }
}

/// The peer's primary gid and its user's supplementary groups (blocking:
/// NSS). A uid without a user entry has only its primary gid.
fn peer_groups(peer: Peer) -> Vec<u32> {
    let mut groups = vec![peer.gid];
    let user = nix::unistd::User::from_uid(nix::unistd::Uid::from_raw(peer.uid));
    if let Ok(Some(u)) = user {
        if let Ok(name) = std::ffi::CString::new(u.name.as_bytes()) {
            if let Ok(list) = nix::unistd::getgrouplist(&name, nix::unistd::Gid::from_raw(peer.gid))
            {
                groups.extend(list.into_iter().map(|g| g.as_raw()));
            }
        }
    }
    groups.sort_unstable();
    groups.dedup();
    groups
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_highest_role_wins_and_no_group_is_no_role() {
        let p = Policy {
            read: vec![10, 11],
            operate: vec![20],
            admin: vec![30],
        };
        assert_eq!(p.role_of(&[]), None);
        assert_eq!(p.role_of(&[5]), None);
        assert_eq!(p.role_of(&[11]), Some(Role::Read));
        assert_eq!(p.role_of(&[11, 20]), Some(Role::Operate));
        assert_eq!(p.role_of(&[30, 10]), Some(Role::Admin));
    }

    #[test]
    fn numeric_entries_are_gids_and_unknown_names_grant_nothing() {
        let s = AccessSection {
            read: vec!["4242".into(), "no-such-group-micropos".into()],
            operate: vec![],
            admin: vec!["0".into()],
        };
        let p = resolve(&s);
        assert_eq!(p.read, vec![4242]);
        assert_eq!(p.admin, vec![0]);
    }

    #[tokio::test]
    async fn without_a_section_everyone_is_admin() {
        let a = Access::new(None);
        let peer = Peer {
            uid: 12345,
            gid: 12345,
            pid: None,
        };
        assert_eq!(a.role_of(peer).await, Some(Role::Admin));
        assert!(!a.is_configured());
        a.set(Some(AccessSection {
            read: vec!["12345".into()],
            ..AccessSection::default()
        }));
        assert_eq!(a.role_of(peer).await, Some(Role::Read));
        a.set(Some(AccessSection::default()));
        assert_eq!(a.role_of(peer).await, None);
    }
}
