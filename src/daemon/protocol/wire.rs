//! Typed requests back into their wire form: what a client writes, so the
//! CLI builds a [`Command`] and sends [`Request::to_json`] instead of
//! spelling the fields itself.
//!
//! Why hand-written, like the parser: the wire form is the parser's (one
//! `cmd`, an `action` word for the commands that have them, the
//! parameters flat beside it, absent fields meaning "the daemon's
//! default"); `round_trip` checks that [`parse_request`] reads
//! back every request written here, field by field, and `schema` lists
//! the same fields.
//!
//! [`parse_request`]: super::parse_request

use serde_json::{Map, Value};

use super::command::{
    CharacterizeAction, CharacterizeParams, Command, DriftAction, FiguresParams, MoveRequest,
    Request, TablesAction, ValidateAction, ValidateParams,
};
use super::words::{ValidateTest, Word};

impl Request {
    /// The request as the parser reads it: `id`, `cmd` and the command's
    /// fields (one line once serialized).
    pub fn to_json(&self) -> Value {
        let mut obj = self.command.fields();
        obj.insert("id".to_owned(), self.id.clone());
        Value::Object(obj)
    }
}

/// Builds one request object, dropping the fields left at `None`.
struct Obj(Map<String, Value>);

impl Obj {
    fn new(cmd: &str) -> Self {
        let mut m = Map::new();
        m.insert("cmd".to_owned(), Value::from(cmd));
        Obj(m)
    }

    fn with_action(cmd: &str, action: &str) -> Self {
        let mut o = Self::new(cmd);
        o.put("action", action);
        o
    }

    fn put(&mut self, key: &str, v: impl Into<Value>) {
        self.0.insert(key.to_owned(), v.into());
    }

    fn opt(&mut self, key: &str, v: Option<impl Into<Value>>) {
        if let Some(v) = v {
            self.put(key, v);
        }
    }

    fn word<W: Word>(&mut self, key: &str, w: Option<W>) {
        self.opt(key, w.map(W::as_str));
    }

    fn words<W: Word>(&mut self, key: &str, ws: &[W]) {
        let ws: Vec<Value> = ws.iter().map(|w| Value::from(w.as_str())).collect();
        self.put(key, ws);
    }
}

impl Command {
    /// The command as a request object without `id`: `cmd`, `action`
    /// where the command has actions, and every parameter that is set.
    pub fn to_json(&self) -> Value {
        Value::Object(self.fields())
    }

    fn fields(&self) -> Map<String, Value> {
        let o = match self {
            Command::Status => Obj::new("status"),
            Command::Position => Obj::new("position"),
            Command::Stop => Obj::new("stop"),
            Command::Reset => Obj::new("reset"),
            Command::Config => Obj::new("config"),
            Command::Version => Obj::new("version"),
            Command::Move(m) => move_obj(m),
            Command::Reference(axes) => {
                let mut o = Obj::new("reference");
                o.word("axes", Some(*axes));
                o
            }
            Command::Subscribe(topics) => {
                let mut o = Obj::new("subscribe");
                o.words("topics", topics);
                o
            }
            Command::Characterize(a) => characterize_obj(a),
            Command::Validate(a) => validate_obj(a),
            Command::Tables(a) => tables_obj(a),
            Command::Drift(a) => drift_obj(a),
            Command::Figures(p) => figures_obj(p),
        };
        o.0
    }
}

fn move_obj(m: &MoveRequest) -> Obj {
    let mut o = Obj::new("move");
    o.opt("x_um", m.x_um);
    o.opt("y_um", m.y_um);
    o.put("relative", m.relative);
    o.word("mode", Some(m.mode));
    o.put("wait", m.wait);
    o.opt("tolerance_um", m.tolerance_um);
    o.opt("tool", m.tool.clone());
    o
}

fn characterize_obj(a: &CharacterizeAction) -> Obj {
    const CMD: &str = "characterize";
    match a {
        CharacterizeAction::Start(p) => characterize_start(p),
        CharacterizeAction::Status => Obj::with_action(CMD, "status"),
        CharacterizeAction::Cancel => Obj::with_action(CMD, "cancel"),
        CharacterizeAction::Resume { log } => {
            let mut o = Obj::with_action(CMD, "resume");
            o.put("log", log.as_str());
            o
        }
    }
}

fn characterize_start(p: &CharacterizeParams) -> Obj {
    let mut o = Obj::with_action("characterize", "start");
    o.opt("log", p.log.as_deref());
    o.word("axes", p.axes);
    o.opt("step_um", p.step_um);
    o.opt("x_range_um", p.x_range_um);
    o.opt("y_range_um", p.y_range_um);
    o.opt("cycles", p.cycles);
    o.opt("frames_per_point", p.frames_per_point);
    o.opt("settle_s", p.settle_s);
    o.opt("drift_every_s", p.drift_every_s);
    o.opt(
        "drift_reference_um",
        p.drift_reference_um.map(|xy| xy.to_vec()),
    );
    o.word("mode", p.mode);
    o.opt("velocity_um_per_s", p.velocity_um_per_s);
    o.opt("uncorrected_log", p.uncorrected_log.as_deref());
    o.opt("unanchored_log", p.unanchored_log.as_deref());
    o.opt("anchor_spacing_um", p.anchor_spacing_um);
    o.opt("moves_per_cycle", p.moves_per_cycle);
    o.word("plan", p.plan);
    o.opt("pitch_um", p.pitch_um);
    o.word("approach", p.approach);
    o.word("order", p.order);
    o
}

fn validate_obj(a: &ValidateAction) -> Obj {
    match a {
        ValidateAction::Start(p) => validate_start(p),
        ValidateAction::Status => Obj::with_action("validate", "status"),
        ValidateAction::Cancel => Obj::with_action("validate", "cancel"),
    }
}

fn validate_start(p: &ValidateParams) -> Obj {
    let mut o = Obj::with_action("validate", "start");
    o.word("test", Some(ValidateTest::of(&p.tests)));
    o.words("modes", &p.modes);
    o.opt("cycles", p.cycles);
    o.opt("log", p.log.as_deref());
    o.opt("origin_x_um", p.origin_x_um);
    o.opt("origin_y_um", p.origin_y_um);
    o.opt("square_step_um", p.square_step_um);
    o.opt("table", p.table.as_deref());
    o.opt("model_table", p.model_table.as_deref());
    o.opt("frames_per_point", p.frames_per_point);
    o.opt("settle_s", p.settle_s);
    o
}

fn tables_obj(a: &TablesAction) -> Obj {
    const CMD: &str = "tables";
    match a {
        TablesAction::List => Obj::with_action(CMD, "list"),
        TablesAction::Load { name } => {
            let mut o = Obj::with_action(CMD, "load");
            o.put("name", name.as_str());
            o
        }
        TablesAction::Activate { name } => {
            let mut o = Obj::with_action(CMD, "activate");
            o.opt("name", name.as_deref());
            o
        }
        TablesAction::Build(p) => {
            let mut o = Obj::with_action(CMD, "build");
            o.put("log", p.log.as_str());
            o.opt("name", p.name.as_deref());
            if !p.kinds.is_empty() {
                o.put("kinds", p.kinds.clone());
            }
            o.put("activate", p.activate);
            o
        }
    }
}

fn drift_obj(a: &DriftAction) -> Obj {
    const CMD: &str = "drift";
    match a {
        DriftAction::Show => Obj::with_action(CMD, "show"),
        DriftAction::Reset => Obj::with_action(CMD, "reset"),
        DriftAction::Measure => Obj::with_action(CMD, "measure"),
        DriftAction::Set {
            method,
            every_s,
            time_constant_s,
        } => {
            let mut o = Obj::with_action(CMD, "set");
            o.word("method", *method);
            o.opt("every_s", *every_s);
            o.opt("time_constant_s", *time_constant_s);
            o
        }
    }
}

fn figures_obj(p: &FiguresParams) -> Obj {
    let mut o = Obj::new("figures");
    o.word("job", Some(p.job));
    o.opt("log", p.log.as_deref());
    o
}
