//! The typed requests: what a parsed line means, independent of JSON.
//!
//! Why a file of its own: these types are what the daemon's handlers and
//! jobs consume; the wire format that produces them lives in `parse`.

use serde_json::Value;

use super::ProtoError;

/// Which axes a command applies to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Axes {
    /// X only.
    X,
    /// Y only.
    Y,
    /// Both axes.
    Both,
}

impl Axes {
    /// Whether X is included.
    pub fn x(self) -> bool {
        matches!(self, Axes::X | Axes::Both)
    }
    /// Whether Y is included.
    pub fn y(self) -> bool {
        matches!(self, Axes::Y | Axes::Both)
    }
    /// The axes as sent on the wire (`both` is spelt `xy`).
    pub fn as_str(self) -> &'static str {
        match self {
            Axes::X => "x",
            Axes::Y => "y",
            Axes::Both => "xy",
        }
    }
}

/// How a move reaches its target.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MoveMode {
    /// The controllers' own positioning, uncorrected.
    Raw,
    /// Targets corrected by the active compensation table.
    Compensated,
    /// Move, measure with the camera, correct the residual.
    ClosedLoop,
}

impl MoveMode {
    /// The mode as sent on the wire.
    pub fn as_str(self) -> &'static str {
        match self {
            MoveMode::Raw => "raw",
            MoveMode::Compensated => "compensated",
            MoveMode::ClosedLoop => "closed_loop",
        }
    }
}

/// A `move` request. Positions in µm, stage frame; `relative` moves are
/// offsets from the commanded target.
#[derive(Debug, Clone, PartialEq)]
pub struct MoveRequest {
    /// X target (or offset), µm; `None` leaves X where it is.
    pub x_um: Option<f64>,
    /// Y target (or offset), µm; `None` leaves Y where it is.
    pub y_um: Option<f64>,
    /// Offsets instead of absolute targets.
    pub relative: bool,
    /// How to get there.
    pub mode: MoveMode,
    /// Reply only once on target (otherwise once the controllers accepted).
    pub wait: bool,
    /// Closed loop: acceptable residual, µm.
    pub tolerance_um: Option<f64>,
    /// `x_um`, `y_um` are where this tool (a `[tools]` name) should be,
    /// not the watched point; planned, absolute moves only.
    pub tool: Option<String>,
}

impl MoveRequest {
    /// An absolute, uncompensated move of both axes that replies once on
    /// target: what jobs and drift references use to place the stage
    /// exactly where their plan says.
    pub fn raw_to(x_um: f64, y_um: f64) -> Self {
        MoveRequest {
            x_um: Some(x_um),
            y_um: Some(y_um),
            relative: false,
            mode: MoveMode::Raw,
            wait: true,
            tolerance_um: None,
            tool: None,
        }
    }
}

/// Parameters of a characterization job; `None` = the configured default.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct CharacterizeParams {
    /// Log file name inside the daemon's data directory (no path).
    pub log: Option<String>,
    /// Axes to scan.
    pub axes: Option<Axes>,
    /// Step between points, µm.
    pub step_um: Option<f64>,
    /// Scan range of X, µm.
    pub x_range_um: Option<f64>,
    /// Scan range of Y, µm.
    pub y_range_um: Option<f64>,
    /// Forward + backward cycles per axis.
    pub cycles: Option<u32>,
    /// Frames averaged per point.
    pub frames_per_point: Option<u32>,
    /// Settle time after each move, s.
    pub settle_s: Option<f64>,
    /// Re-measure the drift reference every this many s of rig time; 0 = off.
    pub drift_every_s: Option<f64>,
    /// Drift reference point `[x, y]`, µm; default: the scan's start corner.
    pub drift_reference_um: Option<[f64; 2]>,
    /// Stop-and-measure (default) or on-the-fly sweeps.
    pub mode: Option<CharacterizeMode>,
    /// Sweep: velocity of the odd cycles, µm/s (even cycles sweep at twice
    /// it, so the camera delay separates from the backlash).
    pub velocity_um_per_s: Option<f64>,
    /// Sweep: also write the log resampled without the delay correction
    /// (file name in the data directory), to show what the delay costs.
    pub uncorrected_log: Option<String>,
    /// Sweep: also write the log without the anchor correction (file name
    /// in the data directory), to show what the anchors change.
    pub unanchored_log: Option<String>,
    /// Sweep: spacing of the static anchors, µm (rounded to a multiple of
    /// the step; 0 = none; default
    /// `charact::sweep::anchor::DEFAULT_ANCHOR_SPACING_UM`).
    pub anchor_spacing_um: Option<f64>,
    /// Step mode: moves of varied length per cycle after the scans
    /// (`charact::plan::ScanPlan::moves_per_cycle`); default 0.
    pub moves_per_cycle: Option<u32>,
    /// What is measured: the paper's scan lines (default) or a grid over
    /// the whole area.
    pub plan: Option<CharacterizePlan>,
    /// Grid plan: node spacing along both axes, µm (default `step_um`).
    pub pitch_um: Option<f64>,
    /// Grid plan: how the nodes are reached (default: from below).
    pub approach: Option<GridApproach>,
    /// Grid plan: the order of the nodes (default: raster).
    pub order: Option<GridOrder>,
}

/// The order of a grid plan's nodes.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum GridOrder {
    /// Every row in increasing x, each row's first node by an approach
    /// move from below.
    #[default]
    Raster,
    /// Rows alternately in increasing and decreasing x (no return move per
    /// row); needs `approach = both`, since its returning rows reach x
    /// from above.
    Serpentine,
}

/// How a grid plan reaches its nodes.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum GridApproach {
    /// Every node from below on both axes, once per cycle: one map, for
    /// moves that arrive from below (half the time of `Both`).
    #[default]
    Below,
    /// Every node from below on both axes (segment `grid_fwd`), then every
    /// node from above (`grid_bwd`, rows of decreasing x, in decreasing y),
    /// per cycle: a map per arrival direction, as the paper's forward and
    /// backward tables, for moves that arrive either way.
    Both,
}

/// Which points a step characterization measures.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum CharacterizePlan {
    /// One scan line per axis through the centre of the other's range,
    /// forward and backward (the paper's; builds its lookup tables).
    #[default]
    Lines,
    /// Every node of a lattice over the area, in rows of increasing x,
    /// rows in increasing y, each node reached from below on both axes
    /// (builds a 2-D map, `comp::grid`: error that depends on both axes).
    Grid,
}

/// How a characterization measures.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum CharacterizeMode {
    /// Move, settle, average frames, log; point after point (the paper's).
    #[default]
    Step,
    /// Constant-velocity sweeps, every frame decoded and timestamped,
    /// resampled onto the step grid (`charact::sweep`).
    Sweep,
}

impl CharacterizeMode {
    /// The protocol word.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Step => "step",
            Self::Sweep => "sweep",
        }
    }
}

/// Sub-commands of `characterize`.
#[derive(Debug, Clone, PartialEq)]
pub enum CharacterizeAction {
    /// Start a new job.
    Start(Box<CharacterizeParams>),
    /// Progress of the current or last job.
    Status,
    /// Cancel the running job (the log stays resumable).
    Cancel,
    /// Continue a job from its log.
    Resume {
        /// Log file name inside the data directory.
        log: String,
    },
}

/// Sub-commands of `tables`.
#[derive(Debug, Clone, PartialEq)]
pub enum TablesAction {
    /// List known tables.
    List,
    /// Load a table file by name.
    Load {
        /// File name inside the data directory.
        name: String,
    },
    /// Make a loaded table the active one (`None` deactivates).
    Activate {
        /// Table name.
        name: Option<String>,
    },
    /// Build the paper's tables and a model table from a characterization
    /// log, write them into the data directory and load them.
    Build(TablesBuildParams),
}

/// Sub-commands of `drift` (live drift correction).
#[derive(Debug, Clone, PartialEq)]
pub enum DriftAction {
    /// The live drift state.
    Show,
    /// Change the method and/or the interval (unset fields stay).
    Set {
        /// `off`, `static` or `adaptive`.
        method: Option<crate::daemon::config::DriftMethodName>,
        /// Interval between re-measurements, s.
        every_s: Option<f64>,
        /// Adaptive forgetting time constant, s.
        time_constant_s: Option<f64>,
    },
    /// Forget the re-measurements (the next compensated move measures).
    Reset,
    /// Re-measure the reference now (with the active table).
    Measure,
}

/// Parameters of `tables build`.
#[derive(Debug, Clone, PartialEq)]
pub struct TablesBuildParams {
    /// The characterization log (file name in the data directory).
    pub log: String,
    /// Output name stem: writes `STEM-paper.toml` and `STEM-model.toml`
    /// (default: the log's stem).
    pub name: Option<String>,
    /// Which tables: `paper`, `model`, `grid`. Empty: the log's default,
    /// `grid` for a grid log (targets filling a lattice, no scan
    /// segments), `paper` and `model` otherwise.
    pub kinds: Vec<String>,
    /// Activate the paper table (or the model table if only that is built).
    pub activate: bool,
}

/// How a validation mode moves to a pose.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ValidateMode {
    /// Plain controller moves.
    Raw,
    /// Compensated by the paper's lookup tables.
    Table,
    /// Compensated by a fitted stage model.
    Model,
    /// Compensated, then corrected on the camera.
    ClosedLoop,
}

impl ValidateMode {
    /// Every mode, in report order.
    pub const ALL: [ValidateMode; 4] = [
        ValidateMode::Raw,
        ValidateMode::Table,
        ValidateMode::Model,
        ValidateMode::ClosedLoop,
    ];

    /// The mode as sent on the wire.
    pub fn as_str(self) -> &'static str {
        match self {
            ValidateMode::Raw => "raw",
            ValidateMode::Table => "table",
            ValidateMode::Model => "model",
            ValidateMode::ClosedLoop => "closed_loop",
        }
    }
}

/// Parameters of `validate start`; `None` = the default.
#[derive(Debug, Clone, PartialEq)]
pub struct ValidateParams {
    /// `square`, `random` (in this order when both).
    pub tests: Vec<String>,
    /// Modes, in the order run.
    pub modes: Vec<ValidateMode>,
    /// Cycles per test and mode.
    pub cycles: Option<u32>,
    /// Log file name.
    pub log: Option<String>,
    /// Stage position of the paper's (0, 0), µm.
    pub origin_x_um: Option<f64>,
    /// Stage position of the paper's (0, 0), µm.
    pub origin_y_um: Option<f64>,
    /// Distance between square poses along a side, µm.
    pub square_step_um: Option<f64>,
    /// Lookup table file for mode `table` (loaded or in the data directory).
    pub table: Option<String>,
    /// Model table file for mode `model`.
    pub model_table: Option<String>,
    /// Frames averaged per pose.
    pub frames_per_point: Option<u32>,
    /// Settle time after each move, s.
    pub settle_s: Option<f64>,
}

/// Sub-commands of `validate`.
#[derive(Debug, Clone, PartialEq)]
pub enum ValidateAction {
    /// Start a validation run.
    Start(ValidateParams),
    /// Progress.
    Status,
    /// Cancel.
    Cancel,
}

/// Which job's log `figures` reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FiguresJob {
    /// A characterization (`scan_x` / `scan_y`): the paper's Figs. 4–6.
    Characterize,
    /// A validation (`square` / `random`): Figs. 10–11 with ISO 9283 AP/RP.
    Validate,
}

impl FiguresJob {
    /// The protocol word, also the log's `job` metadata value.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Characterize => "characterize",
            Self::Validate => "validate",
        }
    }
}

/// Parameters of `figures`.
#[derive(Debug, Clone, PartialEq)]
pub struct FiguresParams {
    /// Whose figures.
    pub job: FiguresJob,
    /// The log (file name in the data directory); `None`: the newest log
    /// whose `job` metadata names [`FiguresParams::job`].
    pub log: Option<String>,
}

/// Event topics a client can subscribe to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Topic {
    /// Positions at camera rate (and on each controller poll).
    Position,
    /// Job progress.
    Job,
    /// Faults and state changes.
    Fault,
    /// Live drift re-measurements and their failures.
    Drift,
}

impl Topic {
    /// The topic as sent on the wire.
    pub fn as_str(self) -> &'static str {
        match self {
            Topic::Position => "position",
            Topic::Job => "job",
            Topic::Fault => "fault",
            Topic::Drift => "drift",
        }
    }
}

/// One parsed command.
#[derive(Debug, Clone, PartialEq)]
pub enum Command {
    /// Daemon, rig and job state.
    Status,
    /// Positions from every source.
    Position,
    /// Move the stage.
    Move(MoveRequest),
    /// Halt everything now.
    Stop,
    /// Acknowledge a latched fault so that motion is allowed again.
    Reset,
    /// Reference axes.
    Reference(Axes),
    /// Stream events on this connection.
    Subscribe(Vec<Topic>),
    /// Characterization job control.
    Characterize(CharacterizeAction),
    /// Validation job control.
    Validate(ValidateAction),
    /// Compensation tables.
    Tables(TablesAction),
    /// Live drift correction.
    Drift(DriftAction),
    /// The paper's figures of a characterization or validation log.
    Figures(FiguresParams),
    /// The effective configuration.
    Config,
    /// Daemon and protocol version.
    Version,
}

/// Names of all commands, for `unknown_command` messages and docs.
pub const COMMANDS: &[&str] = &[
    "status",
    "position",
    "move",
    "stop",
    "reset",
    "reference",
    "subscribe",
    "characterize",
    "validate",
    "tables",
    "drift",
    "figures",
    "config",
    "version",
];

/// A parsed request: its `id` (echoed verbatim) and the command.
#[derive(Debug, Clone, PartialEq)]
pub struct Request {
    /// Whatever the client sent as `id` (`null` when absent).
    pub id: Value,
    /// What to do.
    pub command: Command,
}

/// A refused request: the `id` if it could be read (`null` otherwise) and
/// the error to send back.
#[derive(Debug, Clone, PartialEq)]
pub struct Refusal {
    /// The request's `id`, or `null`.
    pub id: Value,
    /// Why it was refused.
    pub error: ProtoError,
}
