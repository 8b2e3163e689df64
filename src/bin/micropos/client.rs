//! The daemon client: one subcommand per socket command. Human-readable
//! output by default, the daemon's JSON reply with `--json`.
//!
//! Exit codes (scripts rely on them): 0 success; 1 the daemon refused or
//! failed the command (its error code is printed, e.g. `out_of_travel`),
//! or a job followed with `--follow` ended other than done; 2 usage error;
//! 3 the daemon is not reachable (socket missing, refused, closed
//! mid-reply or while following a job).

use anyhow::Context;
use clap::{Args, Subcommand};
use micropos::daemon::protocol::{
    build_needs_log, error_reply_value, from_reply, load_needs_name, resume_needs_log,
    unknown_action, Axes, CharacterizeAction, CharacterizeParams, Command, ErrorBody, ErrorCode,
    JobObject, JobReply, JobState, MoveMode, MoveReply, MoveRequest, ProtoError, Request,
    TablesAction, TablesBuildParams, Topic, ValidateAction, ValidateMode, ValidateParams,
    ValidateTest, ValidationStatusReply, Word,
};
use serde::de::DeserializeOwned;
use serde_json::{json, Value};
use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;
use tokio::io::{AsyncBufReadExt, AsyncWriteExt, BufReader};
use tokio::net::UnixStream;

mod follow;
mod status;

use crate::fmt::{human, rms_um};

/// Options of every daemon command.
#[derive(Debug, Args)]
pub struct GlobalOpts {
    /// The daemon's socket.
    #[arg(long, global = true, default_value = "/run/micropos/micropos.sock")]
    pub socket: PathBuf,
    /// Print the daemon's JSON replies instead of text.
    #[arg(long, global = true)]
    pub json: bool,
    /// Wait up to this many seconds for the daemon to accept and its
    /// controllers to connect (a script that has just started microposd);
    /// 0 fails at once.
    #[arg(long, global = true, default_value_t = 0.0, value_name = "S",
          value_parser = parse_wait_s)]
    pub wait_s: f64,
}

/// A wait in seconds: finite and not negative.
fn parse_wait_s(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() && (0.0..=86_400.0).contains(&v) => Ok(v),
        _ => Err(format!("{s:?} is not a wait in seconds (0 to 86400)")),
    }
}

/// Commands sent to microposd.
#[derive(Debug, Subcommand)]
pub enum ClientCommand {
    /// Daemon, rig and job state.
    Status,
    /// Positions: commanded, controller-reported, vision-measured.
    Position,
    /// Move the stage (µm). A compensated target outside the active
    /// table's characterized area is refused (error outside_table) or
    /// warned about, per `[compensation] outside_table` in the daemon's
    /// config.
    Move {
        /// X target (or offset with --relative), µm.
        #[arg(long, allow_hyphen_values = true)]
        x: Option<f64>,
        /// Y target (or offset), µm.
        #[arg(long, allow_hyphen_values = true)]
        y: Option<f64>,
        /// Offsets from the commanded position.
        #[arg(long)]
        relative: bool,
        /// raw, compensated or closed_loop.
        #[arg(long, default_value = "raw")]
        mode: String,
        /// Return only once on target.
        #[arg(long)]
        wait: bool,
        /// Bring this tool point (a `[tools]` name of the daemon's
        /// config) to (--x, --y) instead of the watched point; planned
        /// modes, absolute, both axes.
        #[arg(long)]
        tool: Option<String>,
    },
    /// Halt everything now.
    Stop,
    /// Acknowledge a latched fault (after finding its cause): motion is
    /// allowed again; an axis that lost its reference still needs one.
    Reset,
    /// Reference axes (x, y or xy).
    Reference {
        /// Axes.
        #[arg(default_value = "xy")]
        axes: String,
    },
    /// Print events (positions, job progress, faults) until interrupted.
    Subscribe {
        /// Topics: position, job, fault (default all).
        topics: Vec<String>,
    },
    /// Characterization job: start, status, cancel, resume.
    Characterize {
        /// start | status | cancel | resume
        #[arg(default_value = "status")]
        action: String,
        /// Log file name (in the daemon's data directory).
        #[arg(long)]
        log: Option<String>,
        /// Step, µm.
        #[arg(long)]
        step_um: Option<f64>,
        /// Length of the X scan from the start corner, µm (default: the
        /// daemon's `[characterize]` range).
        #[arg(long)]
        x_range_um: Option<f64>,
        /// Length of the Y scan from the start corner, µm.
        #[arg(long)]
        y_range_um: Option<f64>,
        /// Cycles.
        #[arg(long)]
        cycles: Option<u32>,
        /// step (stop and measure, default) or sweep (on the fly at
        /// constant velocity; the camera delay is estimated from the data).
        #[arg(long)]
        mode: Option<String>,
        /// Sweep: velocity of the odd cycles, µm/s (even cycles: twice it).
        #[arg(long)]
        velocity_um_per_s: Option<f64>,
        /// Sweep: also write the log without the delay correction.
        #[arg(long)]
        uncorrected_log: Option<String>,
        /// Sweep: spacing of the static anchors, µm (0 = none; default
        /// 250). The records are corrected to the step plan's motion state
        /// by the anchors' offset curves.
        #[arg(long)]
        anchor_spacing_um: Option<f64>,
        /// Sweep: also write the log without the anchor correction.
        #[arg(long)]
        unanchored_log: Option<String>,
        /// lines (the paper's scan lines, default) or grid (every node of a
        /// lattice over both ranges, reached from below on both axes: for
        /// a 2-D map, `tables build` kind grid).
        #[arg(long)]
        plan: Option<String>,
        /// Grid: node spacing along both axes, µm (default --step-um).
        #[arg(long)]
        pitch_um: Option<f64>,
        /// Grid: below (every node from below on both axes, default) or
        /// both (then every node from above too: a map per arrival
        /// direction, for moves that arrive either way; twice the time).
        #[arg(long)]
        approach: Option<String>,
        /// Grid: raster (every row in increasing x, default) or serpentine
        /// (rows alternately in increasing and decreasing x, no return
        /// move per row; needs --approach both).
        #[arg(long)]
        order: Option<String>,
        /// Wait for the job to end (a progress bar on a terminal, a progress
        /// line every 10 s on stderr otherwise), then print its final state,
        /// what it measured and the next step. Exit 0 only if it ended done;
        /// 1 if it failed, was cancelled or stopped; 3 if the daemon went away.
        #[arg(long)]
        follow: bool,
    },
    /// Validation job (the paper's square and Table II): start, status, cancel.
    /// A start whose table or model poses leave their table's characterized
    /// area is refused before anything moves (error outside_table; move the
    /// poses with --origin-x-um/--origin-y-um), or warned, per the daemon's
    /// `[compensation] outside_table`.
    Validate {
        /// start | status | cancel
        #[arg(default_value = "status")]
        action: String,
        /// square, random or both (default both).
        #[arg(long)]
        test: Option<String>,
        /// Modes, comma-separated: raw,table,model,closed_loop (default all).
        #[arg(long, value_delimiter = ',')]
        modes: Vec<String>,
        /// Cycles per test and mode (default 3).
        #[arg(long)]
        cycles: Option<u32>,
        /// Log file name (in the daemon's data directory).
        #[arg(long)]
        log: Option<String>,
        /// Stage x of the paper's (0, 0), µm (default: the characterization
        /// start, or the travel's start where the poses would leave the
        /// travel from there; a refusal names the range that fits).
        #[arg(long, allow_hyphen_values = true)]
        origin_x_um: Option<f64>,
        /// Stage y of the paper's (0, 0), µm (default as --origin-x-um).
        #[arg(long, allow_hyphen_values = true)]
        origin_y_um: Option<f64>,
        /// Distance between square poses, µm (default 500).
        #[arg(long)]
        square_step_um: Option<f64>,
        /// Lookup table for mode table (default: the latest loaded).
        #[arg(long)]
        table: Option<String>,
        /// Model table for mode model (default: the latest loaded).
        #[arg(long)]
        model_table: Option<String>,
        /// Wait for the job to end (a progress bar on a terminal, a progress
        /// line every 10 s on stderr otherwise), then print its final state,
        /// what it measured and the next step. Exit 0 only if it ended done;
        /// 1 if it failed, was cancelled or stopped; 3 if the daemon went away.
        #[arg(long)]
        follow: bool,
    },
    /// Compensation tables: list, load NAME, activate [NAME], build LOG.
    Tables {
        /// list | load | activate | build
        #[arg(default_value = "list")]
        action: String,
        /// Table name (load, activate) or characterization log (build).
        name: Option<String>,
        /// build: output stem (writes STEM-paper.toml, STEM-model.toml, STEM-grid.toml).
        #[arg(long)]
        out: Option<String>,
        /// build: which tables, comma-separated: paper,model,grid (default:
        /// grid for a grid log without scan segments, else paper,model).
        #[arg(long, value_delimiter = ',')]
        kinds: Vec<String>,
        /// build: activate the (first) table built.
        #[arg(long)]
        activate: bool,
    },
    /// The daemon's effective configuration.
    Config,
    /// Daemon and protocol version.
    Version,
}

/// A connection to the daemon.
struct Conn {
    reader: BufReader<tokio::net::unix::OwnedReadHalf>,
    writer: tokio::net::unix::OwnedWriteHalf,
}

/// Failure to reach the daemon (exit 3) vs. a refused command (exit 1).
struct Unreachable(anyhow::Error);

impl Conn {
    /// Connects, retrying a missing or refusing socket for `wait_s` seconds
    /// (a daemon still starting binds its socket within milliseconds).
    async fn open(path: &PathBuf, wait_s: f64) -> Result<Conn, Unreachable> {
        let deadline = tokio::time::Instant::now() + std::time::Duration::from_secs_f64(wait_s);
        let s = loop {
            match UnixStream::connect(path).await {
                Err(e)
                    if matches!(
                        e.kind(),
                        std::io::ErrorKind::NotFound | std::io::ErrorKind::ConnectionRefused
                    ) && tokio::time::Instant::now() < deadline =>
                {
                    tokio::time::sleep(std::time::Duration::from_millis(100)).await;
                }
                r => break r,
            }
        };
        let s = s
            .with_context(|| {
                format!(
                    "cannot reach microposd at {} (is it running? --socket names its socket; --wait-s S waits for one that is starting)",
                    path.display()
                )
            })
            .map_err(Unreachable)?;
        let (r, w) = s.into_split();
        Ok(Conn {
            reader: BufReader::new(r),
            writer: w,
        })
    }

    async fn line(&mut self) -> Result<Value, Unreachable> {
        let mut l = String::new();
        let n = self
            .reader
            .read_line(&mut l)
            .await
            .map_err(|e| Unreachable(e.into()))?;
        if n == 0 {
            return Err(Unreachable(anyhow::anyhow!(
                "the daemon closed the connection"
            )));
        }
        serde_json::from_str(&l)
            .map_err(|e| Unreachable(anyhow::anyhow!("unreadable reply {l:?}: {e}")))
    }

    /// Sends `command` (`id` 1) and returns its reply, skipping events.
    async fn request(&mut self, command: Command) -> Result<Value, Unreachable> {
        let req = Request {
            id: Value::from(1),
            command,
        };
        let mut s = req.to_json().to_string();
        s.push('\n');
        self.writer
            .write_all(s.as_bytes())
            .await
            .map_err(|e| Unreachable(e.into()))?;
        loop {
            let v = self.line().await?;
            if v.get("event").is_none() {
                return Ok(v);
            }
        }
    }
}

/// An ok reply read as its typed struct. A reply this client cannot read
/// (a field missing or of another type: a daemon of another version) is
/// an error naming the field, reported like an unreadable line (exit 3),
/// never a panic.
fn typed<T: DeserializeOwned>(reply: &Value, what: &str) -> Result<T, Unreachable> {
    from_reply(reply).map_err(|e| {
        Unreachable(anyhow::anyhow!(
            "unreadable {what} reply from the daemon ({e}; a daemon of another version?): {reply}"
        ))
    })
}

/// The typed request a client command sends. A word the protocol does not
/// know (a mode, an action) or a missing required name is refused here
/// with the code and message the daemon would send; numbers and file names
/// are the daemon's to judge.
fn build(cmd: &ClientCommand) -> Result<Command, ProtoError> {
    Ok(match cmd {
        ClientCommand::Status => Command::Status,
        ClientCommand::Position => Command::Position,
        ClientCommand::Move {
            x,
            y,
            relative,
            mode,
            wait,
            tool,
        } => Command::Move(MoveRequest {
            x_um: *x,
            y_um: *y,
            relative: *relative,
            mode: MoveMode::from_word(mode)?,
            wait: *wait,
            tolerance_um: None,
            tool: tool.clone(),
        }),
        ClientCommand::Stop => Command::Stop,
        ClientCommand::Reset => Command::Reset,
        ClientCommand::Reference { axes } => Command::Reference(Axes::from_word(axes)?),
        ClientCommand::Subscribe { topics } => {
            // None named: every topic, as the daemon's default.
            let mut typed = Vec::new();
            for t in topics {
                let t = Topic::from_word(t)?;
                if !typed.contains(&t) {
                    typed.push(t);
                }
            }
            Command::Subscribe(if topics.is_empty() {
                Topic::ALL.to_vec()
            } else {
                typed
            })
        }
        ClientCommand::Characterize { .. } => Command::Characterize(characterize(cmd)?),
        ClientCommand::Validate { .. } => Command::Validate(validate(cmd)?),
        ClientCommand::Tables {
            action,
            name,
            out,
            kinds,
            activate,
        } => Command::Tables(match action.as_str() {
            "list" => TablesAction::List,
            "load" => TablesAction::Load {
                name: name.clone().ok_or_else(load_needs_name)?,
            },
            "activate" => TablesAction::Activate { name: name.clone() },
            "build" => TablesAction::Build(TablesBuildParams {
                log: name.clone().ok_or_else(build_needs_log)?,
                name: out.clone(),
                kinds: kinds.clone(),
                activate: *activate,
            }),
            other => return Err(unknown_action("tables", other)),
        }),
        ClientCommand::Config => Command::Config,
        ClientCommand::Version => Command::Version,
    })
}

/// `characterize ACTION`'s typed action (see [`build`]).
fn characterize(cmd: &ClientCommand) -> Result<CharacterizeAction, ProtoError> {
    let ClientCommand::Characterize {
        action,
        log,
        step_um,
        x_range_um,
        y_range_um,
        cycles,
        mode,
        velocity_um_per_s,
        uncorrected_log,
        anchor_spacing_um,
        unanchored_log,
        plan,
        pitch_um,
        approach,
        order,
        ..
    } = cmd
    else {
        return Err(unknown_action("characterize", ""));
    };
    fn word<W: Word>(w: &Option<String>) -> Result<Option<W>, ProtoError> {
        w.as_deref().map(W::from_word).transpose()
    }
    Ok(match action.as_str() {
        "start" => CharacterizeAction::Start(Box::new(CharacterizeParams {
            log: log.clone(),
            step_um: *step_um,
            x_range_um: *x_range_um,
            y_range_um: *y_range_um,
            cycles: *cycles,
            mode: word(mode)?,
            velocity_um_per_s: *velocity_um_per_s,
            uncorrected_log: uncorrected_log.clone(),
            unanchored_log: unanchored_log.clone(),
            anchor_spacing_um: *anchor_spacing_um,
            plan: word(plan)?,
            pitch_um: *pitch_um,
            approach: word(approach)?,
            order: word(order)?,
            ..CharacterizeParams::default()
        })),
        "status" => CharacterizeAction::Status,
        "cancel" => CharacterizeAction::Cancel,
        "resume" => CharacterizeAction::Resume {
            log: log.clone().ok_or_else(resume_needs_log)?,
        },
        other => return Err(unknown_action("characterize", other)),
    })
}

/// `validate ACTION`'s typed action (see [`build`]).
fn validate(cmd: &ClientCommand) -> Result<ValidateAction, ProtoError> {
    let ClientCommand::Validate {
        action,
        test,
        modes,
        cycles,
        log,
        origin_x_um,
        origin_y_um,
        square_step_um,
        table,
        model_table,
        ..
    } = cmd
    else {
        return Err(unknown_action("validate", ""));
    };
    Ok(match action.as_str() {
        "start" => {
            let tests = match test {
                Some(t) => ValidateTest::from_word(t)?,
                None => ValidateTest::Both,
            };
            // None named: every mode, as the daemon's default.
            let mut typed = Vec::new();
            for m in modes {
                let m = ValidateMode::from_word(m)?;
                if !typed.contains(&m) {
                    typed.push(m);
                }
            }
            ValidateAction::Start(ValidateParams {
                tests: tests.tests(),
                modes: if modes.is_empty() {
                    ValidateMode::ALL.to_vec()
                } else {
                    typed
                },
                cycles: *cycles,
                log: log.clone(),
                origin_x_um: *origin_x_um,
                origin_y_um: *origin_y_um,
                square_step_um: *square_step_um,
                table: table.clone(),
                model_table: model_table.clone(),
                frames_per_point: None,
                settle_s: None,
            })
        }
        "status" => ValidateAction::Status,
        "cancel" => ValidateAction::Cancel,
        other => return Err(unknown_action("validate", other)),
    })
}

/// Runs a client command.
pub async fn run(opts: GlobalOpts, cmd: ClientCommand) -> anyhow::Result<ExitCode> {
    match run_inner(&opts, &cmd).await {
        Ok(code) => Ok(code),
        Err(Unreachable(e)) => {
            eprintln!("error: {}", micropos::error_text(e.as_ref()));
            Ok(ExitCode::from(3))
        }
    }
}

async fn run_inner(opts: &GlobalOpts, cmd: &ClientCommand) -> Result<ExitCode, Unreachable> {
    let deadline = tokio::time::Instant::now() + std::time::Duration::from_secs_f64(opts.wait_s);
    let mut conn = Conn::open(&opts.socket, opts.wait_s).await?;
    // A daemon just started connects its controllers within moments:
    // `not_connected` refuses a command without doing anything, so with
    // --wait-s the command is sent again until they are (or time is up).
    let command = match build(cmd) {
        Ok(c) => c,
        // Refused before sending: shown as the daemon's refusal would be.
        Err(e) => {
            return Ok(print_reply_or_error(
                opts,
                &error_reply_value(&Value::from(1), &e),
            ))
        }
    };
    let reply = loop {
        let reply = conn.request(command.clone()).await?;
        let not_connected =
            ErrorBody::of_reply(&reply).is_some_and(|e| e.code == ErrorCode::NotConnected.as_str());
        if not_connected && tokio::time::Instant::now() < deadline {
            tokio::time::sleep(std::time::Duration::from_millis(200)).await;
            continue;
        }
        break reply;
    };
    let out = std::io::stdout();
    if opts.json || reply["ok"] != true {
        let code = print_reply_or_error(opts, &reply);
        if reply["ok"] != true {
            return Ok(code);
        }
    }
    if !opts.json {
        let text = text_of(cmd, &reply, &mut conn).await?;
        let _ = write!(out.lock(), "{text}");
        for w in reply_warnings(cmd, &reply)? {
            eprintln!("warning: {w}");
        }
    }
    match cmd {
        ClientCommand::Subscribe { .. } => loop {
            let ev = conn.line().await?;
            if opts.json {
                let _ = writeln!(out.lock(), "{ev}");
            } else {
                let name = ev["event"].as_str().unwrap_or("?").to_owned();
                let _ = writeln!(
                    out.lock(),
                    "[{name}] {}",
                    human(&ev).replace('\n', "  ").trim_end()
                );
            }
        },
        ClientCommand::Characterize {
            follow: true,
            action,
            ..
        } if action == "start" || action == "resume" => {
            let started: JobReply = typed(&reply, "characterize start")?;
            let job = follow::follow(&mut conn, &started).await?;
            let summary = follow::characterize_summary(&job);
            Ok(follow::report_end(&job, summary, opts.json, None))
        }
        ClientCommand::Validate {
            follow: true,
            action,
            ..
        } if action == "start" => {
            let started: JobReply = typed(&reply, "validate start")?;
            let job = follow::follow(&mut conn, &started).await?;
            if job.known().map(|p| p.state) != Some(JobState::Done) {
                return Ok(follow::report_end(&job, None, opts.json, None));
            }
            // The results come with the job-done state: shown like a reply.
            let s = conn
                .request(Command::Validate(ValidateAction::Status))
                .await?;
            let status: ValidationStatusReply = typed(&s, "validate status")?;
            let table = validation_table(&status.validation);
            Ok(follow::report_end(&job, Some(table), opts.json, Some(&s)))
        }
        _ => Ok(ExitCode::SUCCESS),
    }
}

/// With `--json` the reply line; without, a refusal's code and message on
/// stderr. The exit code: 0 for an ok reply, 1 for a refusal.
fn print_reply_or_error(opts: &GlobalOpts, reply: &Value) -> ExitCode {
    if opts.json {
        let _ = writeln!(std::io::stdout().lock(), "{reply}");
    }
    if reply["ok"] == true {
        return ExitCode::SUCCESS;
    }
    if !opts.json {
        let e = ErrorBody::of_reply(reply);
        eprintln!(
            "error [{}]: {}",
            e.as_ref().map_or("?", |e| e.code.as_str()),
            e.as_ref().map_or("?", |e| e.message.as_str())
        );
    }
    ExitCode::from(1)
}

/// A command's reply for a person. Most replies print as indented
/// `key: value` lines with rounded numbers and units ([`human`]); the
/// ones a person reads most have their own form: `status` (the state that
/// matters first, with positions, table and settings asked for on the same
/// connection), `move` (target and command first), `validate status` (the
/// AP/RP table), `characterize status` (the job in a line), `tables build`
/// (the unidentifiable parameters grouped, with advice).
async fn text_of(
    cmd: &ClientCommand,
    reply: &Value,
    conn: &mut Conn,
) -> Result<String, Unreachable> {
    Ok(match cmd {
        ClientCommand::Status => {
            let extra = status::Extra {
                position: optional(conn, Command::Position, "position").await?,
                tables: optional(conn, Command::Tables(TablesAction::List), "tables list").await?,
                config: optional(conn, Command::Config, "config").await?,
            };
            status::text(&typed(reply, "status")?, &extra)
        }
        ClientCommand::Move { .. } => {
            format!("{}{}", move_summary(&typed(reply, "move")?), human(reply))
        }
        ClientCommand::Validate { action, .. } if action == "status" => {
            validate_status_text(&typed(reply, "validate status")?)
        }
        ClientCommand::Characterize { action, .. } if action == "status" => {
            let job: JobReply = typed(reply, "characterize status")?;
            let job = job.job.as_ref();
            let mut s = format!("job: {}\n", status::job_line(job));
            if let Some(sweep) = job
                .and_then(JobObject::known)
                .and_then(|p| sweep_summary(&p.result))
            {
                s.push_str(&sweep);
                s.push('\n');
            }
            s
        }
        ClientCommand::Tables { action, .. } if action == "build" => tables_build_text(reply),
        // start, resume, cancel: the job in a line, then the rest.
        ClientCommand::Characterize { .. } | ClientCommand::Validate { .. }
            if reply["job"].is_object() =>
        {
            let job: JobReply = typed(reply, "job")?;
            let mut rest = reply.clone();
            if let Some(m) = rest.as_object_mut() {
                m.remove("job");
            }
            format!(
                "job: {}\n{}",
                status::job_line(job.job.as_ref()),
                human(&rest)
            )
        }
        _ => human(reply),
    })
}

/// A reply the view can do without: `None` when the daemon refused it
/// (a role that may not read it).
async fn optional<T: DeserializeOwned>(
    conn: &mut Conn,
    command: Command,
    what: &str,
) -> Result<Option<T>, Unreachable> {
    let r = conn.request(command).await?;
    if r["ok"] != true {
        return Ok(None);
    }
    typed(&r, what).map(Some)
}

/// `validate status`: the job, the AP/RP table (modes in the order raw,
/// table, model, closed_loop), the logs; the per-pose figures are in
/// `--json`.
fn validate_status_text(reply: &ValidationStatusReply) -> String {
    let mut s = format!("job: {}\n", status::job_line(reply.job.as_ref()));
    // The results are the validation job's own JSON (per test and mode).
    let v = &reply.validation;
    if v["results"].as_object().is_some_and(|r| !r.is_empty()) {
        s.push_str(&validation_table(v));
        if let Some(logs) = v["logs"].as_array() {
            let names: Vec<&str> = logs.iter().filter_map(Value::as_str).collect();
            if !names.is_empty() {
                s.push_str(&format!(
                    "logs (daemon data_dir): {}; per-pose figures: `micropos validate status --json`\n",
                    names.join(", ")
                ));
            }
        }
    } else {
        s.push_str("no validation results yet\n");
    }
    s
}

/// `tables build`: the reply as usual, but the model's unidentifiable
/// parameters as groups with their cause and remedy, not a list of names.
fn tables_build_text(reply: &Value) -> String {
    let mut shown = reply.clone();
    let model = &reply["model"];
    let groups = model["unidentifiable_groups"].as_array().cloned();
    let n = model["unidentifiable"].as_array().map_or(0, Vec::len);
    if let Some(m) = shown["model"].as_object_mut() {
        m.remove("unidentifiable_groups");
        if n > 0 {
            m.insert(
                "unidentifiable".to_owned(),
                json!(format!(
                    "{n} parameters, kept at the template's values (below)"
                )),
            );
        }
    }
    let mut s = human(&shown);
    match groups {
        Some(groups) if !groups.is_empty() => {
            s.push_str(&format!(
                "{n} parameters of {} the log cannot identify, by cause:\n",
                model["name"].as_str().unwrap_or("the model table")
            ));
            for g in groups {
                let k = g["params"].as_array().map_or(0, Vec::len);
                s.push_str(&format!(
                    "  - {} ({k} parameter{})\n",
                    g["advice"].as_str().unwrap_or("?"),
                    if k == 1 { "" } else { "s" }
                ));
            }
        }
        // An older daemon: the names, on one line.
        _ if n > 0 => {
            let names: Vec<&str> = model["unidentifiable"]
                .as_array()
                .map(|a| a.iter().filter_map(Value::as_str).collect())
                .unwrap_or_default();
            s.push_str(&format!("unidentifiable: {}\n", names.join(", ")));
        }
        _ => {}
    }
    s
}

/// The first line of a move's reply: the target the user asked for, then
/// the command the daemon sent to reach it (they differ by the
/// compensation).
fn move_summary(v: &MoveReply) -> String {
    let c = match (v.commanded.x_um, v.commanded.y_um) {
        (Some(x), Some(y)) => Some(format!("({x:.3}, {y:.3}) µm")),
        _ => None,
    };
    match (
        v.target
            .map(|t| format!("({:.3}, {:.3}) µm", t.x_um, t.y_um)),
        c,
    ) {
        (Some(t), Some(c)) => format!("target {t}, commanded {c}\n"),
        (Some(t), None) => format!("target {t}\n"),
        _ => String::new(),
    }
}

/// Warnings a reply carries: a compensated move's `outside_table.warning`,
/// `validate start`'s `warnings`.
fn reply_warnings(cmd: &ClientCommand, v: &Value) -> Result<Vec<String>, Unreachable> {
    Ok(match cmd {
        ClientCommand::Move { .. } => typed::<MoveReply>(v, "move")?
            .outside_table
            .and_then(|o| o.warning)
            .into_iter()
            .collect(),
        ClientCommand::Validate { action, .. } if action == "start" => {
            typed::<JobReply>(v, "validate start")?
                .warnings
                .unwrap_or_default()
        }
        _ => Vec::new(),
    })
}

/// The order a person reads the modes in: uncompensated first, then by
/// what each adds (the paper's tables, the model, the closed loop); modes
/// this client does not know follow, by name.
fn mode_rank(mode: &str) -> (usize, &str) {
    let known = ["raw", "table", "model", "closed_loop"];
    (
        known.iter().position(|m| *m == mode).unwrap_or(known.len()),
        mode,
    )
}

/// AP and RP per trajectory and mode from `validate status`'s results.
fn validation_table(v: &Value) -> String {
    let mut s =
        String::from("trajectory  mode         AP max µm  AP mean µm  RP max µm  RP mean µm\n");
    let f = |v: &Value| v.as_f64().map_or("-".to_owned(), |x| format!("{x:.3}"));
    let mut rp_missing = false;
    if let Some(tests) = v["results"].as_object() {
        let mut tests: Vec<(&String, &Value)> = tests.iter().collect();
        // The paper's order: the square, then Table II's random targets.
        tests.sort_by_key(|(t, _)| match t.as_str() {
            "square" => 0,
            "random" => 1,
            _ => 2,
        });
        for (test, modes) in tests {
            if let Some(modes) = modes.as_object() {
                let mut modes: Vec<(&String, &Value)> = modes.iter().collect();
                modes.sort_by(|a, b| mode_rank(a.0).cmp(&mode_rank(b.0)));
                for (mode, r) in modes {
                    rp_missing |= r["rp_um"].is_null();
                    s.push_str(&format!(
                        "{test:<11} {mode:<12} {:>9}  {:>10}  {:>9}  {:>10}\n",
                        f(&r["ap_um"]),
                        f(&r["ap_mean_um"]),
                        f(&r["rp_um"]),
                        f(&r["rp_mean_um"])
                    ));
                }
            }
        }
    }
    if rp_missing {
        s.push_str("RP -: a pose visited once has no spread (RP needs --cycles 2 or more)\n");
    }
    s
}

/// What a finished sweep measured (its camera delay, frames, records and
/// static anchors), for a person; `None` for a step job's result.
fn sweep_summary(r: &Value) -> Option<String> {
    let d = r["camera_delay_s"].as_f64()?;
    let mut s = format!(
        "sweep: camera delay {:.3} ms (residual {}), {} frames, {} records, {:.0} s",
        d * 1e3,
        rms_um(r["camera_delay_residual_um"].as_f64().unwrap_or(f64::NAN)),
        r["frames"],
        r["records"],
        r["duration_s"].as_f64().unwrap_or(f64::NAN)
    );
    let a = &r["anchors"];
    if let Some(n) = a["measured"].as_u64() {
        let list = |v: &Value| {
            v.as_array().filter(|l| !l.is_empty()).map(|l| {
                l.iter()
                    .filter_map(Value::as_str)
                    .collect::<Vec<_>>()
                    .join(" ")
            })
        };
        s.push_str(&format!(
            "\nanchors: {n} visits at {} positions every {:.0} µm ({:.0} s); correction up to x {:.3} µm, y {:.3} µm",
            a["positions"],
            a["spacing_um"].as_f64().unwrap_or(f64::NAN),
            a["duration_s"].as_f64().unwrap_or(f64::NAN),
            a["x"]["max_along_um"].as_f64().unwrap_or(f64::NAN),
            a["y"]["max_along_um"].as_f64().unwrap_or(f64::NAN),
        ));
        if let Some(l) = list(&a["rejected"]) {
            s.push_str(&format!("; left out for their scatter: {l}"));
        }
        if let Some(l) = list(&a["unmatched"]) {
            s.push_str(&format!("; without a sweep value: {l}"));
        }
    }
    Some(s)
}

#[cfg(test)]
mod tests {
    use super::*;
    use micropos::daemon::protocol::parse_request;

    /// The CLI's typed requests read back as sent, and a word the protocol
    /// does not know is refused with the daemon's own code and message.
    #[test]
    fn requests_are_typed_and_bad_words_refused_as_the_daemon_would() {
        let mv = |mode: &str| ClientCommand::Move {
            x: Some(1.5),
            y: None,
            relative: true,
            mode: mode.to_owned(),
            wait: false,
            tool: None,
        };
        let Ok(c) = build(&mv("compensated")) else {
            panic!("a known mode is typed");
        };
        let line = c.to_json().to_string();
        assert_eq!(parse_request(line.as_bytes()).map(|r| r.command), Ok(c));
        let local = build(&mv("fast")).unwrap_err();
        let daemon = parse_request(br#"{"cmd":"move","x_um":1.5,"mode":"fast"}"#)
            .unwrap_err()
            .error;
        assert_eq!(local, daemon);
        let t = ClientCommand::Tables {
            action: "load".to_owned(),
            name: None,
            out: None,
            kinds: vec![],
            activate: false,
        };
        let daemon = parse_request(br#"{"cmd":"tables","action":"load"}"#)
            .unwrap_err()
            .error;
        assert_eq!(build(&t).unwrap_err(), daemon);
    }

    #[test]
    fn the_validation_table_lists_modes_raw_first_then_what_each_adds() {
        let v = json!({"results": {"square": {
            "table": {"ap_um": 3.0}, "closed_loop": {"ap_um": 0.1},
            "raw": {"ap_um": 22.0}, "model": {"ap_um": 1.0}, "extra": {"ap_um": 5.0}
        }}});
        let t = validation_table(&v);
        let modes: Vec<&str> = t
            .lines()
            .filter(|l| l.starts_with("square "))
            .filter_map(|l| l.split_whitespace().nth(1))
            .collect();
        assert_eq!(
            modes,
            ["raw", "table", "model", "closed_loop", "extra"],
            "{t}"
        );
        assert!(t.starts_with("trajectory  mode"), "{t}");
    }

    /// Issue 33: `validate status` printed the reply as a dump (modes by
    /// name, no header); now the job, then the table with its header and
    /// units, the square before the random targets, raw first.
    #[test]
    fn validate_status_is_the_job_and_the_table() {
        let r = |ap: f64| {
            json!({"ap_um": ap, "ap_mean_um": ap / 2.0, "rp_um": 0.123456, "rp_mean_um": 0.05,
                                 "poses": [{"pose": "A", "ap_um": ap}]})
        };
        let reply = json!({"ok": true,
            "job": {"kind": "validate", "log": "v.csv", "state": "done", "done": 84, "total": 84,
                    "retries": 0, "error": null, "eta_s": null},
            "validation": {"results": {"random": {"raw": r(19.55), "closed_loop": r(0.048)},
                                       "square": {"closed_loop": r(0.075), "raw": r(28.66123456)}},
                           "logs": ["v.csv"]}});
        let t = validate_status_text(&from_reply(&reply).unwrap());
        let lines: Vec<&str> = t.lines().collect();
        assert_eq!(lines[0], "job: validate v.csv: done, 84/84 points", "{t}");
        assert_eq!(
            lines[1], "trajectory  mode         AP max µm  AP mean µm  RP max µm  RP mean µm",
            "{t}"
        );
        let rows: Vec<(&str, &str)> = lines[2..6]
            .iter()
            .map(|l| {
                let mut w = l.split_whitespace();
                (w.next().unwrap_or(""), w.next().unwrap_or(""))
            })
            .collect();
        assert_eq!(
            rows,
            [
                ("square", "raw"),
                ("square", "closed_loop"),
                ("random", "raw"),
                ("random", "closed_loop")
            ],
            "{t}"
        );
        assert!(
            lines[2].contains("28.661") && lines[2].contains("0.123"),
            "{t}"
        );
        assert!(lines[6].starts_with("logs (daemon data_dir): v.csv"), "{t}");
        // Every RP measured: no note about single visits.
        assert!(!t.contains("RP -"), "{t}");
        assert!(!t.contains("poses"), "{t}");
    }

    /// Issue 33: a model table's unidentifiable parameters were a list of
    /// names; now one line per cause, with the advice, and the rest of the
    /// reply rounded.
    #[test]
    fn tables_build_groups_the_unidentifiable_parameters() {
        let reply = json!({"ok": true, "log": "c.csv",
            "model": {"name": "c-model.toml", "rms_residual_um": [0.020993187246186144, 0.022473125779433657],
                      "unidentifiable": ["x_cyclic.forward_sin_2_um", "x_cyclic.forward_sin_3_um", "origin.y_um"],
                      "unidentifiable_groups": [
                          {"term": "x_cyclic", "params": ["x_cyclic.forward_sin_2_um", "x_cyclic.forward_sin_3_um"],
                           "advice": "x_cyclic: a step of 100 µm along x cannot resolve …"},
                          {"term": null, "params": ["origin.y_um"], "advice": "origin.y_um: …"}],
                      "extended_by": []},
            "written": ["c-model.toml"]});
        let t = tables_build_text(&reply);
        for want in [
            "  rms_residual: [0.0210, 0.0225] µm\n",
            "  unidentifiable: 3 parameters, kept at the template's values (below)\n",
            "3 parameters of c-model.toml the log cannot identify, by cause:\n",
            "  - x_cyclic: a step of 100 µm along x cannot resolve … (2 parameters)\n",
            "  - origin.y_um: … (1 parameter)\n",
        ] {
            assert!(t.contains(want), "want {want:?} in\n{t}");
        }
        assert!(!t.contains("forward_sin_2_um"), "{t}");
    }
}
