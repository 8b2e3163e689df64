//! Every command's actions and fields with their JSON types: the one list
//! of the request fields. The parser refuses a field not listed here, the
//! round-trip test (`round_trip`) fails for a field [`Command::to_json`]
//! writes and this list lacks (or the parser does not read back), and
//! [`schema_json`] writes the list as `docs/socket-schema.json`, against
//! which the Python client's requests are checked
//! (`clients/python/tests/test_schema.py`).
//!
//! Why a table and not serde: the parser's refusals name the field and the
//! problem in words serde cannot produce; a table gives the parser, the
//! schema and the tests one list to read.
//!
//! [`Command::to_json`]: super::Command::to_json

use serde_json::{json, Map, Value};

use super::command::{
    Axes, CharacterizeMode, CharacterizePlan, FiguresJob, GridApproach, GridOrder, MoveMode, Topic,
    ValidateMode,
};
use super::fields::unknown_word;
use super::words::{words, ValidateTest, TABLE_KINDS};
use super::{ErrorCode, ProtoError, PROTOCOL_VERSION};
use crate::daemon::config::DriftMethodName;

/// The JSON type of a request field.
#[derive(Debug, Clone, Copy)]
pub enum FieldType {
    /// A finite number.
    Number,
    /// A non-negative integer.
    Integer,
    /// `true` or `false`.
    Boolean,
    /// A plain file name in the daemon's data directory.
    FileName,
    /// One of a keyword type's words.
    Word(fn() -> Vec<&'static str>),
    /// An array of a keyword type's words.
    Words(fn() -> Vec<&'static str>),
    /// Two numbers `[x, y]`.
    Pair,
    /// A configured name (`[tools]`): 1 to 64 of `A-Z a-z 0-9 _ -`.
    Name,
}

impl FieldType {
    /// The type as the schema file spells it.
    fn to_json(self) -> Value {
        match self {
            Self::Number => json!("number"),
            Self::Integer => json!("integer"),
            Self::Boolean => json!("boolean"),
            Self::FileName => json!("file_name"),
            Self::Word(w) => json!({"word": w()}),
            Self::Words(w) => json!({"words": w()}),
            Self::Pair => json!("number_pair"),
            Self::Name => json!("name"),
        }
    }

    /// Whether a JSON value has this type (the words unchecked: the parser
    /// names a wrong word). Why: the round-trip test checks that what
    /// [`Command::to_json`](super::Command::to_json) writes is what the
    /// schema says.
    pub fn admits(self, v: &Value) -> bool {
        match self {
            Self::Number => v.is_number(),
            Self::Integer => v.is_u64(),
            Self::Boolean => v.is_boolean(),
            Self::FileName | Self::Word(_) | Self::Name => v.is_string(),
            Self::Words(_) => v.as_array().is_some_and(|a| a.iter().all(Value::is_string)),
            Self::Pair => v
                .as_array()
                .is_some_and(|a| a.len() == 2 && a.iter().all(Value::is_number)),
        }
    }
}

/// One request field: its key and type.
#[derive(Debug, Clone, Copy)]
pub struct Field {
    /// The key.
    pub name: &'static str,
    /// Its type.
    pub ty: FieldType,
}

/// One action of a command with actions (`characterize start`).
#[derive(Debug, Clone, Copy)]
pub struct Action {
    /// The `action` word.
    pub name: &'static str,
    /// The fields it reads.
    pub fields: &'static [Field],
}

/// One command: its fields, or its actions and theirs.
#[derive(Debug, Clone, Copy)]
pub struct CommandSchema {
    /// The `cmd` word.
    pub cmd: &'static str,
    /// The fields of a command without actions.
    pub fields: &'static [Field],
    /// The actions (empty: the command has none), the default first.
    pub actions: &'static [Action],
    /// The action without `action`.
    pub default_action: Option<&'static str>,
}

impl CommandSchema {
    /// Every field the command accepts, `action` first when it has
    /// actions, each once in the order of first appearance: the list a
    /// refusal of an unknown field names.
    pub fn known_fields(&self) -> Vec<&'static str> {
        let mut known: Vec<&'static str> = Vec::new();
        if !self.actions.is_empty() {
            known.push("action");
        }
        let per_action = self.actions.iter().flat_map(|a| a.fields.iter());
        for f in self.fields.iter().chain(per_action) {
            if !known.contains(&f.name) {
                known.push(f.name);
            }
        }
        known
    }

    /// The fields an action reads (`None`: the command has no action or
    /// no field by that name); for commands without actions, `action` is
    /// ignored.
    pub fn field(&self, action: Option<&str>, name: &str) -> Option<Field> {
        let fields = if self.actions.is_empty() {
            self.fields
        } else {
            self.actions.iter().find(|a| Some(a.name) == action)?.fields
        };
        fields.iter().copied().find(|f| f.name == name)
    }

    /// The action names, joined as a refusal lists them.
    pub fn action_choices(&self) -> String {
        let names: Vec<&str> = self.actions.iter().map(|a| a.name).collect();
        names.join(", ")
    }
}

const fn f(name: &'static str, ty: FieldType) -> Field {
    Field { name, ty }
}

const fn act(name: &'static str, fields: &'static [Field]) -> Action {
    Action { name, fields }
}

const fn plain(cmd: &'static str, fields: &'static [Field]) -> CommandSchema {
    CommandSchema {
        cmd,
        fields,
        actions: &[],
        default_action: None,
    }
}

const fn with_actions(
    cmd: &'static str,
    default_action: &'static str,
    actions: &'static [Action],
) -> CommandSchema {
    CommandSchema {
        cmd,
        fields: &[],
        actions,
        default_action: Some(default_action),
    }
}

use FieldType::{Boolean, FileName, Integer, Number, Pair};

fn table_kinds() -> Vec<&'static str> {
    TABLE_KINDS.to_vec()
}

const CHARACTERIZE_START: &[Field] = &[
    f("log", FileName),
    f("axes", FieldType::Word(words::<Axes>)),
    f("step_um", Number),
    f("x_range_um", Number),
    f("y_range_um", Number),
    f("cycles", Integer),
    f("frames_per_point", Integer),
    f("settle_s", Number),
    f("drift_every_s", Number),
    f("drift_reference_um", Pair),
    f("mode", FieldType::Word(words::<CharacterizeMode>)),
    f("velocity_um_per_s", Number),
    f("uncorrected_log", FileName),
    f("unanchored_log", FileName),
    f("anchor_spacing_um", Number),
    f("moves_per_cycle", Integer),
    f("plan", FieldType::Word(words::<CharacterizePlan>)),
    f("pitch_um", Number),
    f("approach", FieldType::Word(words::<GridApproach>)),
    f("order", FieldType::Word(words::<GridOrder>)),
];

const VALIDATE_START: &[Field] = &[
    f("test", FieldType::Word(words::<ValidateTest>)),
    f("modes", FieldType::Words(words::<ValidateMode>)),
    f("cycles", Integer),
    f("log", FileName),
    f("origin_x_um", Number),
    f("origin_y_um", Number),
    f("square_step_um", Number),
    f("table", FileName),
    f("model_table", FileName),
    f("frames_per_point", Integer),
    f("settle_s", Number),
];

/// Every command, in the order of [`COMMANDS`](super::COMMANDS).
pub const SCHEMA: &[CommandSchema] = &[
    plain("status", &[]),
    plain("position", &[]),
    plain(
        "move",
        &[
            f("x_um", Number),
            f("y_um", Number),
            f("relative", Boolean),
            f("mode", FieldType::Word(words::<MoveMode>)),
            f("wait", Boolean),
            f("tolerance_um", Number),
            f("tool", FieldType::Name),
        ],
    ),
    plain("stop", &[]),
    plain("reset", &[]),
    plain("reference", &[f("axes", FieldType::Word(words::<Axes>))]),
    plain(
        "subscribe",
        &[f("topics", FieldType::Words(words::<Topic>))],
    ),
    with_actions(
        "characterize",
        "status",
        &[
            act("start", CHARACTERIZE_START),
            act("status", &[]),
            act("cancel", &[]),
            act("resume", &[f("log", FileName)]),
        ],
    ),
    with_actions(
        "validate",
        "status",
        &[
            act("start", VALIDATE_START),
            act("status", &[]),
            act("cancel", &[]),
        ],
    ),
    with_actions(
        "tables",
        "list",
        &[
            act("list", &[]),
            act("load", &[f("name", FileName)]),
            act("activate", &[f("name", FileName)]),
            act(
                "build",
                &[
                    f("log", FileName),
                    f("name", FileName),
                    f("kinds", FieldType::Words(table_kinds)),
                    f("activate", Boolean),
                ],
            ),
        ],
    ),
    with_actions(
        "drift",
        "show",
        &[
            act("show", &[]),
            act(
                "set",
                &[
                    f("method", FieldType::Word(words::<DriftMethodName>)),
                    f("every_s", Number),
                    f("time_constant_s", Number),
                ],
            ),
            act("reset", &[]),
            act("measure", &[]),
        ],
    ),
    plain(
        "figures",
        &[
            f("job", FieldType::Word(words::<FiguresJob>)),
            f("log", FileName),
        ],
    ),
    plain("config", &[]),
    plain("version", &[]),
];

/// The refusal of an `action` word `cmd` does not know, listing its
/// actions (`characterize action "x" unknown; use start, …`): the parser's
/// and a client's that reads the action from its own command line.
pub fn unknown_action(cmd: &str, got: &str) -> ProtoError {
    let choices = command_schema(cmd).map_or_else(String::new, CommandSchema::action_choices);
    unknown_word(&format!("{cmd} action"), got, &choices)
}

/// The schema of a command word.
pub fn command_schema(cmd: &str) -> Option<&'static CommandSchema> {
    SCHEMA.iter().find(|c| c.cmd == cmd)
}

fn fields_json(fields: &[Field]) -> Value {
    let m: Map<String, Value> = fields
        .iter()
        .map(|f| (f.name.to_owned(), f.ty.to_json()))
        .collect();
    Value::Object(m)
}

/// The machine-readable schema of the requests (every command, action and
/// field with its type, and the error codes), as `docs/socket-schema.json`
/// holds it: what clients in other languages check their requests against.
pub fn schema_json() -> Value {
    let commands: Map<String, Value> = SCHEMA
        .iter()
        .map(|c| {
            let v = if c.actions.is_empty() {
                json!({"fields": fields_json(c.fields)})
            } else {
                let actions: Map<String, Value> = c
                    .actions
                    .iter()
                    .map(|a| (a.name.to_owned(), json!({"fields": fields_json(a.fields)})))
                    .collect();
                json!({"default_action": c.default_action, "actions": actions})
            };
            (c.cmd.to_owned(), v)
        })
        .collect();
    let codes: Vec<&str> = ErrorCode::ALL.iter().map(|c| c.as_str()).collect();
    json!({
        "protocol": PROTOCOL_VERSION,
        "about": "Generated from src/daemon/protocol/schema.rs by `cargo test -p micropos --lib protocol` (UPDATE_SCHEMA=1 rewrites it); do not edit.",
        "request": {"id": "any JSON value, echoed", "cmd": "the command word"},
        "commands": commands,
        "error_codes": codes,
    })
}
