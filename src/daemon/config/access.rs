//! `[access]`: which groups hold which role.

use super::error::{bad, ConfigError};
use serde::{Deserialize, Serialize};

/// `[access]`: which groups hold which role. Each entry is a group name or
/// a numeric gid; a client's groups are its primary gid (`SO_PEERCRED`)
/// and its user's supplementary groups. Roles nest: `admin` can do all
/// `operate` can, `operate` all `read` can; a client in no listed group
/// has no role and is refused every command (`permission_denied`).
///
/// Why groups: a lab already manages who may use an instrument by group
/// membership, and the socket's own gate (mode 0660, group `micropos`)
/// is a group too. Why the default without a section is "everyone who can
/// connect is admin": the socket mode already limits who connects, and a
/// rig set up before roles existed keeps working; a lab that wants a
/// read-only group adds the section.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub struct AccessSection {
    /// Groups that may read: status, position, subscribe, job status, and
    /// `stop` (an emergency stop is for anyone at the instrument).
    pub read: Vec<String>,
    /// Groups that may also move: moves, references, jobs, tables.
    pub operate: Vec<String>,
    /// Groups that may also configure: `config`, drift settings, `reset`.
    pub admin: Vec<String>,
}

impl AccessSection {
    /// Every entry must be a plausible group name or a gid.
    pub fn validate(&self) -> Result<(), ConfigError> {
        for (role, list) in [
            ("read", &self.read),
            ("operate", &self.operate),
            ("admin", &self.admin),
        ] {
            for g in list {
                let ok = !g.is_empty()
                    && g.len() <= 64
                    && g.bytes()
                        .all(|b| b.is_ascii_alphanumeric() || b"-_.$".contains(&b));
                if !ok {
                    return Err(bad(
                        &format!("access.{role}"),
                        format!("{g:?} is not a group name or a numeric gid"),
                    ));
                }
            }
        }
        Ok(())
    }
}
