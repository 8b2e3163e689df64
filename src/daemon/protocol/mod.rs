//! The socket protocol, sans-IO: one request line in, one typed request or a
//! typed error out; replies and events serialized to one line each.
//!
//! Why hand-written parsing over `serde(deserialize)`: every refusal must
//! name the field and the problem with a stable error code, and a request
//! whose `id` is readable must get that `id` back even when the rest is
//! wrong. Nothing here does I/O; `fuzz/fuzz_targets/socket_request.rs`
//! drives [`parse_request`] with arbitrary bytes. Format: docs/socket-protocol.md.
//!
//! # Layout
//! * `error`: the stable error codes and [`ProtoError`], shared by every
//!   other part of the daemon that refuses a request.
//! * `command`: the typed requests ([`Request`], [`Command`] and each
//!   command's parameters): what the rest of the daemon consumes.
//! * `parse`: one request line into a [`Request`] or a [`Refusal`], command
//!   by command; the only code that reads client JSON.
//! * `strict`: JSON into a `serde_json::Value` refusing a key repeated in
//!   one object (serde_json would keep the last silently).
//! * `fields`: the field readers `parse` is built from (type, range and
//!   file-name checks with their error messages).
//! * `job`: a long job's kind and state ([`JobKind`], [`JobState`]), as
//!   replies and events carry them and clients read them.
//! * `reply`: replies and events serialized to one line each.
//! * `replies`: the typed replies and events both ends use, one struct
//!   per reply kind ([`StatusReply`], [`MoveReply`], [`JobProgress`],
//!   [`ErrorBody`], …): the daemon builds and serializes them, the CLI
//!   reads them.
//! * `role`: the role each command needs ([`Role`], [`Command::role`]) and
//!   which commands are audited.
//! * `schema`: every command's actions and fields with their types: the one
//!   list of request fields, the parser's and `docs/socket-schema.json`'s.
//! * `words`: the keyword types' words ([`Word`]) and the refusals a client
//!   building typed requests shares with the parser.
//! * `wire`: typed requests back into their wire form ([`Request::to_json`]),
//!   what the CLI sends.

mod command;
mod error;
mod fields;
mod job;
mod parse;
mod replies;
mod reply;
mod role;
#[cfg(test)]
mod round_trip;
mod schema;
mod strict;
#[cfg(test)]
mod tests;
mod wire;
mod words;

pub use command::{
    Axes, CharacterizeAction, CharacterizeMode, CharacterizeParams, CharacterizePlan, Command,
    DriftAction, FiguresJob, FiguresParams, GridApproach, GridOrder, MoveMode, MoveRequest,
    Refusal, Request, TablesAction, TablesBuildParams, Topic, ValidateAction, ValidateMode,
    ValidateParams, COMMANDS,
};
pub use error::{ErrorCode, ProtoError};
pub use job::{JobKind, JobState};
pub use parse::{parse_request, too_large};
pub use replies::*;
pub use reply::{error_reply, error_reply_value, event_line, ok_reply, reply, reply_fields};
pub use role::Role;
pub use schema::{
    command_schema, schema_json, unknown_action, CommandSchema, Field, FieldType, SCHEMA,
};
pub use words::{
    build_needs_log, load_needs_name, resume_needs_log, ValidateTest, Word, TABLE_KINDS,
};

/// Version of the protocol this daemon speaks (the `version` command reports
/// it; a client refuses a major version it does not know).
pub const PROTOCOL_VERSION: u32 = 1;

/// Longest request line accepted, bytes (without the newline). Larger
/// requests are answered with `request_too_large` and skipped.
pub const MAX_REQUEST_BYTES: usize = 64 * 1024;
