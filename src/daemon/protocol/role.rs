//! Which role each command needs, in one table ([`Command::role`]), and
//! which commands change state (those are audited).
//!
//! Why here, sans-IO: the mapping is part of the protocol (clients and
//! `docs/socket-protocol.md` depend on it), and keeping it next to the
//! command types makes a new command fail to compile until it has a role.

use super::{CharacterizeAction, Command, DriftAction, TablesAction, ValidateAction};

/// A client's role. Roles nest: `Admin` ⊃ `Operate` ⊃ `Read` (the derived
/// order says so: a client may run a command when its role is at least the
/// command's).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Role {
    /// Look: status, positions, events, job and table listings; `stop`.
    Read,
    /// Move: moves, references, jobs, tables.
    Operate,
    /// Configure: the configuration, drift settings, fault reset.
    Admin,
}

impl Role {
    /// The role as written in the config and the audit log.
    pub fn as_str(self) -> &'static str {
        match self {
            Role::Read => "read",
            Role::Operate => "operate",
            Role::Admin => "admin",
        }
    }
}

impl Command {
    /// The least role allowed to run this command.
    ///
    /// `stop` needs only `read`: an emergency stop is for everyone at the
    /// instrument, as the red button on a rack is. `drift measure` moves
    /// the stage (to the reference point), so it is `operate`; changing the
    /// drift method or forgetting its samples changes how every later move
    /// is corrected, so those are `admin`. `config` is `admin` because it
    /// reveals the whole installation (ports, paths, roles).
    pub fn role(&self) -> Role {
        match self {
            Command::Status
            | Command::Position
            | Command::Version
            | Command::Subscribe(_)
            | Command::Figures(_)
            | Command::Stop => Role::Read,
            Command::Characterize(CharacterizeAction::Status)
            | Command::Validate(ValidateAction::Status)
            | Command::Tables(TablesAction::List)
            | Command::Drift(DriftAction::Show) => Role::Read,
            Command::Move(_)
            | Command::Reference(_)
            | Command::Characterize(_)
            | Command::Validate(_)
            | Command::Tables(_)
            | Command::Drift(DriftAction::Measure) => Role::Operate,
            // Clearing a latched fault declares the rig safe to move again.
            Command::Drift(DriftAction::Set { .. } | DriftAction::Reset)
            | Command::Config
            | Command::Reset => Role::Admin,
        }
    }

    /// Whether the command changes the rig's or the daemon's state (and is
    /// therefore audited): everything beyond `read`, plus `stop`.
    pub fn changes_state(&self) -> bool {
        matches!(self, Command::Stop) || (self.role() > Role::Read && *self != Command::Config)
    }

    /// A short name for logs: the command and its action, e.g.
    /// `tables build`.
    pub fn name(&self) -> &'static str {
        match self {
            Command::Status => "status",
            Command::Position => "position",
            Command::Move(_) => "move",
            Command::Stop => "stop",
            Command::Reset => "reset",
            Command::Reference(_) => "reference",
            Command::Subscribe(_) => "subscribe",
            Command::Characterize(a) => match a {
                CharacterizeAction::Start(_) => "characterize start",
                CharacterizeAction::Status => "characterize status",
                CharacterizeAction::Cancel => "characterize cancel",
                CharacterizeAction::Resume { .. } => "characterize resume",
            },
            Command::Validate(a) => match a {
                ValidateAction::Start(_) => "validate start",
                ValidateAction::Status => "validate status",
                ValidateAction::Cancel => "validate cancel",
            },
            Command::Tables(a) => match a {
                TablesAction::List => "tables list",
                TablesAction::Load { .. } => "tables load",
                TablesAction::Activate { .. } => "tables activate",
                TablesAction::Build(_) => "tables build",
            },
            Command::Drift(a) => match a {
                DriftAction::Show => "drift show",
                DriftAction::Set { .. } => "drift set",
                DriftAction::Reset => "drift reset",
                DriftAction::Measure => "drift measure",
            },
            Command::Figures(_) => "figures",
            Command::Config => "config",
            Command::Version => "version",
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::daemon::protocol::parse_request;

    fn cmd(line: &str) -> Command {
        parse_request(line.as_bytes())
            .unwrap_or_else(|r| panic!("{line}: {:?}", r.error))
            .command
    }

    #[test]
    fn every_command_has_the_documented_role() {
        let table = [
            (r#"{"cmd":"status"}"#, Role::Read, false),
            (r#"{"cmd":"position"}"#, Role::Read, false),
            (r#"{"cmd":"version"}"#, Role::Read, false),
            (r#"{"cmd":"subscribe"}"#, Role::Read, false),
            (r#"{"cmd":"stop"}"#, Role::Read, true),
            (r#"{"cmd":"reset"}"#, Role::Admin, true),
            (r#"{"cmd":"characterize"}"#, Role::Read, false),
            (r#"{"cmd":"validate"}"#, Role::Read, false),
            (r#"{"cmd":"tables"}"#, Role::Read, false),
            (r#"{"cmd":"drift"}"#, Role::Read, false),
            (r#"{"cmd":"figures"}"#, Role::Read, false),
            (
                r#"{"cmd":"figures","job":"validate","log":"v.csv"}"#,
                Role::Read,
                false,
            ),
            (r#"{"cmd":"move","x_um":1}"#, Role::Operate, true),
            (r#"{"cmd":"reference"}"#, Role::Operate, true),
            (
                r#"{"cmd":"characterize","action":"start"}"#,
                Role::Operate,
                true,
            ),
            (
                r#"{"cmd":"characterize","action":"cancel"}"#,
                Role::Operate,
                true,
            ),
            (
                r#"{"cmd":"characterize","action":"resume","log":"a.csv"}"#,
                Role::Operate,
                true,
            ),
            (
                r#"{"cmd":"validate","action":"start"}"#,
                Role::Operate,
                true,
            ),
            (
                r#"{"cmd":"validate","action":"cancel"}"#,
                Role::Operate,
                true,
            ),
            (
                r#"{"cmd":"tables","action":"load","name":"t.toml"}"#,
                Role::Operate,
                true,
            ),
            (
                r#"{"cmd":"tables","action":"activate","name":null}"#,
                Role::Operate,
                true,
            ),
            (
                r#"{"cmd":"tables","action":"build","log":"c.csv"}"#,
                Role::Operate,
                true,
            ),
            (r#"{"cmd":"drift","action":"measure"}"#, Role::Operate, true),
            (
                r#"{"cmd":"drift","action":"set","method":"off"}"#,
                Role::Admin,
                true,
            ),
            (r#"{"cmd":"drift","action":"reset"}"#, Role::Admin, true),
            (r#"{"cmd":"config"}"#, Role::Admin, false),
        ];
        for (line, role, audited) in table {
            let c = cmd(line);
            assert_eq!(c.role(), role, "{line}");
            assert_eq!(c.changes_state(), audited, "{line}");
            assert!(
                super::super::COMMANDS.contains(&c.name().split(' ').next().unwrap_or("")),
                "{line}"
            );
        }
        assert!(Role::Admin > Role::Operate && Role::Operate > Role::Read);
    }
}
