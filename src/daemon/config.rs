//! The daemon configuration (`microposd.toml`), validated at start so a bad
//! file stops the daemon with a message naming the key and the problem
//! instead of failing hours later in a job.

use crate::camera::SourceSpec;
use crate::driver::DriverConfig;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// A configuration problem: which key, what is wrong.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("config key {key}: {problem}")]
pub struct ConfigError {
    /// Dotted key, e.g. `characterize.step_um`.
    pub key: String,
    /// What is wrong and what would be right.
    pub problem: String,
}

fn bad(key: &str, problem: impl Into<String>) -> ConfigError {
    ConfigError {
        key: key.to_owned(),
        problem: problem.into(),
    }
}

/// The whole file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub struct DaemonConfig {
    /// Process and socket settings.
    pub daemon: DaemonSection,
    /// The two controllers (see `config/driver.example.toml`).
    pub driver: DriverConfig,
    /// Soft limits, tighter than the controllers' travel.
    pub limits: Limits,
    /// The motion supervisor's bounds.
    pub safety: SafetySection,
    /// The camera and the decoder.
    pub camera: CameraSection,
    /// Defaults of the characterization job.
    pub characterize: CharacterizeDefaults,
    /// Closed-loop moves.
    pub closed_loop: ClosedLoop,
    /// How compensated and closed-loop moves approach their target.
    pub compensation: CompensationSection,
    /// The rig's clock.
    pub rig: RigSection,
    /// Live drift correction of compensated moves.
    pub drift: DriftSection,
    /// Roles of the socket's clients; `None` (no `[access]` section): the
    /// socket's file permissions are the only gate and every client that
    /// can connect is `admin` (see [`AccessSection`]).
    pub access: Option<AccessSection>,
    /// The web view and `/metrics` (`docs/design/web.md`); `None` (no
    /// `[web]` section): no network listener at all.
    pub web: Option<WebSection>,
}

/// `[web]`: the live web view and the Prometheus `/metrics` endpoint on one
/// TCP listener. Read-only unless `control = true`; then every command
/// needs `Authorization: Bearer <token>` and runs with `role`.
///
/// Why off by default and loopback by default: the socket's gate is the
/// kernel's (file mode, `SO_PEERCRED`); a TCP port has none, so it exists
/// only when the operator asks for it, and reaches other machines only when
/// the operator names a non-loopback address (the daemon warns then).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct WebSection {
    /// Address and port, e.g. `"127.0.0.1:8080"` (port 0: any free port).
    pub listen: String,
    /// Whether HTTP clients may send commands (with the token).
    pub control: bool,
    /// The role of an HTTP client holding the token: `"read"`,
    /// `"operate"` (default) or `"admin"`.
    pub role: String,
    /// The bearer token, inline. Prefer `token_file`: the configuration is
    /// often world-readable. Never shown by the `config` command.
    #[serde(skip_serializing)]
    pub token: Option<String>,
    /// A file holding the token (surrounding whitespace ignored); it must
    /// not be readable by group or others (like ssh's keys).
    pub token_file: Option<PathBuf>,
    /// Camera view: frames per second at most (> 0, ≤ 10).
    pub camera_max_hz: f64,
    /// Camera view: the longer side of the downscaled image, pixels
    /// (16..=2048).
    pub camera_max_px: u32,
}

impl Default for WebSection {
    fn default() -> Self {
        WebSection {
            listen: "127.0.0.1:8080".to_owned(),
            control: false,
            role: "operate".to_owned(),
            token: None,
            token_file: None,
            camera_max_hz: 2.0,
            camera_max_px: 480,
        }
    }
}

/// The shortest token accepted: a guessable token on a network port is
/// no gate.
pub const MIN_WEB_TOKEN_CHARS: usize = 16;

impl WebSection {
    /// The parsed `listen` address.
    pub fn listen_addr(&self) -> Result<std::net::SocketAddr, ConfigError> {
        self.listen.trim().parse().map_err(|_| {
            bad(
                "web.listen",
                format!(
                    "{:?} is not an address and port like \"127.0.0.1:8080\" or \"[::1]:8080\"",
                    self.listen
                ),
            )
        })
    }

    /// The parsed `role`.
    pub fn role(&self) -> Result<crate::daemon::protocol::Role, ConfigError> {
        use crate::daemon::protocol::Role;
        match self.role.trim() {
            "read" => Ok(Role::Read),
            "operate" => Ok(Role::Operate),
            "admin" => Ok(Role::Admin),
            r => Err(bad(
                "web.role",
                format!("{r:?}: expected \"read\", \"operate\" or \"admin\""),
            )),
        }
    }

    /// Checks what can be checked without reading files.
    pub fn validate(&self) -> Result<(), ConfigError> {
        self.listen_addr()?;
        self.role()?;
        if !(self.camera_max_hz.is_finite()
            && self.camera_max_hz > 0.0
            && self.camera_max_hz <= 10.0)
        {
            return Err(bad("web.camera_max_hz", "must be within (0, 10] Hz"));
        }
        if !(16..=2048).contains(&self.camera_max_px) {
            return Err(bad("web.camera_max_px", "must be within 16..=2048 pixels"));
        }
        match (&self.token, &self.token_file) {
            (Some(_), Some(_)) => Err(bad("web.token", "set token or token_file, not both")),
            (None, None) if self.control => Err(bad(
                "web.control",
                "control = true needs token_file (or token): every HTTP command must carry it",
            )),
            (Some(t), None) => check_token("web.token", t).map(|_| ()),
            _ => Ok(()),
        }
    }

    /// The token HTTP commands must carry, read from `token_file` when
    /// set; `None` when `control` is off (then no command is accepted).
    pub fn resolve_token(&self) -> Result<Option<String>, ConfigError> {
        if !self.control {
            return Ok(None);
        }
        if let Some(t) = &self.token {
            return check_token("web.token", t).map(Some);
        }
        let Some(path) = &self.token_file else {
            return Err(bad(
                "web.control",
                "control = true needs token_file (or token)",
            ));
        };
        use std::os::unix::fs::PermissionsExt;
        let key = "web.token_file";
        let meta =
            std::fs::metadata(path).map_err(|e| bad(key, format!("{}: {e}", path.display())))?;
        let mode = meta.permissions().mode();
        if mode & 0o077 != 0 {
            return Err(bad(
                key,
                format!(
                    "{} has mode {:04o}: group or others can read the token; chmod 600 (owner: the daemon's user)",
                    path.display(),
                    mode & 0o7777
                ),
            ));
        }
        let text = std::fs::read_to_string(path)
            .map_err(|e| bad(key, format!("{}: {e}", path.display())))?;
        check_token(key, text.trim()).map(Some)
    }
}

fn check_token(key: &str, t: &str) -> Result<String, ConfigError> {
    let t = t.trim();
    if t.chars().count() < MIN_WEB_TOKEN_CHARS {
        return Err(bad(
            key,
            format!("the token must have at least {MIN_WEB_TOKEN_CHARS} characters (e.g. `openssl rand -hex 32`)"),
        ));
    }
    if !t.bytes().all(|b| b.is_ascii_graphic()) {
        return Err(bad(key, "the token must be printable ASCII without spaces"));
    }
    Ok(t.to_owned())
}

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

/// `[drift]`: live drift correction of compensated moves (see
/// `docs/design/daemon.md`, "Live drift correction"). Why: over hours the
/// room's temperature moves the platform and the optics by more than the
/// tables' accuracy; re-measuring one reference point at intervals
/// measures that drift, and compensated targets are shifted by it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DriftSection {
    /// `"off"` (default), `"static"` (the offset of the first
    /// re-measurement, held) or `"adaptive"` (local line with forgetting
    /// `time_constant_s`, extrapolated to each move).
    pub method: DriftMethodName,
    /// Re-measure the reference every this many s of rig time (checked
    /// before compensated moves and between validation points), > 0.
    pub every_s: f64,
    /// Forgetting time constant of the adaptive model, s (> 0).
    pub time_constant_s: f64,
    /// Reference point `[x, y]` µm for tables that record none (built from
    /// logs without `drift_every_s`); unset = `characterize.drift_reference_um`,
    /// else the characterization's start corner. A table's own reference
    /// always wins: drift is only meaningful against its baseline.
    pub reference_um: Option<[f64; 2]>,
}

/// `[drift] method`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum DriftMethodName {
    /// No live correction.
    #[default]
    Off,
    /// First offset, held.
    Static,
    /// Local line with forgetting.
    Adaptive,
}

impl DriftMethodName {
    /// As written in the config and the protocol.
    pub fn as_str(self) -> &'static str {
        match self {
            DriftMethodName::Off => "off",
            DriftMethodName::Static => "static",
            DriftMethodName::Adaptive => "adaptive",
        }
    }
}

impl Default for DriftSection {
    fn default() -> Self {
        Self {
            method: DriftMethodName::Off,
            every_s: 300.0,
            time_constant_s: crate::analysis::drift::LIVE_TIME_CONSTANT_S,
            reference_um: None,
        }
    }
}

impl DriftSection {
    /// The live method this section stands for.
    pub fn live_method(&self) -> crate::analysis::drift::LiveMethod {
        use crate::analysis::drift::LiveMethod;
        match self.method {
            DriftMethodName::Off => LiveMethod::Off,
            DriftMethodName::Static => LiveMethod::Static,
            DriftMethodName::Adaptive => LiveMethod::Adaptive {
                time_constant_s: self.time_constant_s,
            },
        }
    }
}

/// `[rig]`: where the rig's time comes from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RigSection {
    /// `"wall"` (hardware: monotonic wall time) or `"sim:PATH"` (the
    /// simulator's control socket: settle times advance simulated time, so
    /// a 9.5-hour characterization runs in minutes). Every wait and
    /// timestamp of the daemon goes through this clock.
    pub clock: String,
}

impl Default for RigSection {
    fn default() -> Self {
        Self {
            clock: "wall".to_owned(),
        }
    }
}

/// The parsed `[rig] clock` key.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ClockSpec {
    /// Monotonic wall time (hardware).
    Wall,
    /// hil-sim's control socket.
    Sim(PathBuf),
}

/// `[daemon]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DaemonSection {
    /// Unix socket path (overridden by `--socket`; ignored under socket
    /// activation).
    pub socket: PathBuf,
    /// Socket file mode, octal string (default `"0660"`: owner and group).
    pub socket_mode: String,
    /// Where measurement logs and tables live; client-given file names are
    /// resolved inside it and nowhere else.
    pub data_dir: PathBuf,
    /// Period of the controller position poll that feeds the position
    /// stream and the health check, ms.
    pub poll_interval_ms: u64,
    /// Most clients served at once. A client beyond it gets one of the
    /// `stop_slots` (which accept only `stop`), or a `busy` line and is
    /// closed: it never waits in the accept queue.
    pub max_clients: usize,
    /// Connections kept beyond `max_clients` that accept only `stop`. Why:
    /// a daemon whose slots are all held by idle or stuck clients must
    /// still let someone halt the stage, on the same socket path (no second
    /// socket to configure, activate and protect).
    pub stop_slots: usize,
    /// A client that sends nothing for this long while it has no request
    /// running and no subscription is disconnected, s (0 = never). A
    /// subscriber is never idle: it is receiving events, and a subscriber
    /// that stops reading them is caught by `write_timeout_s` instead.
    pub idle_timeout_s: f64,
    /// Longest time from the first byte of a request line to its newline,
    /// s. A client that starts a line and stalls holds a slot for nothing.
    /// Stop-only connections also use it as their idle timeout.
    pub read_timeout_s: f64,
    /// Longest time one reply or event line may take to be written, s: a
    /// client that does not read its socket is disconnected instead of
    /// holding a slot (its events are already dropped, never queued).
    pub write_timeout_s: f64,
    /// How often a job retries one operation (a move, a measurement) after
    /// a *transient* fault: a lost or late controller reply, a garbled
    /// reply, a camera that delivered no decodable frame in time. Why: a
    /// characterization runs for hours, and one glitch on the serial line
    /// must not throw the rest away. Permanent faults (controller error
    /// codes, limits, servo off, lost reference, a dropped line) are never
    /// retried. 0 = fail at the first fault, as before.
    pub job_retries: u32,
    /// Back-off before the first retry, rig seconds (simulated seconds
    /// under a `sim:` clock); doubled for each further retry of the same
    /// operation, so a line that needs a moment to fall quiet gets it.
    pub job_retry_backoff_s: f64,
    /// `sync_data` of the characterization and validation logs after every
    /// this many records: a power cut loses at most this many − 1 records
    /// (plus the torn last line, which reading repairs). 0 = never sync,
    /// only hand each record to the operating system at once (a crash of
    /// the process still loses nothing). Why configurable: a sync costs
    /// milliseconds, nothing against a real point's seconds but most of the
    /// wall time of a simulated rig whose points cost microseconds
    /// (`hil-sim run` sets 0).
    pub log_sync_every: u32,
}

impl Default for DaemonSection {
    fn default() -> Self {
        Self {
            socket: PathBuf::from("/run/micropos/micropos.sock"),
            socket_mode: "0660".to_owned(),
            data_dir: PathBuf::from("/var/lib/micropos"),
            poll_interval_ms: 200,
            max_clients: 256,
            stop_slots: 4,
            idle_timeout_s: 3600.0,
            read_timeout_s: 10.0,
            write_timeout_s: 10.0,
            job_retries: 3,
            job_retry_backoff_s: 0.5,
            log_sync_every: 1,
        }
    }
}

/// `[safety]`: the bounds of the motion supervisor (`daemon::supervisor`;
/// `docs/design/daemon.md`, "Motion safety"). Why configurable: how far a
/// healthy stage may lag its commanded trajectory depends on its speed and
/// acceleration (a reversal at speed v and deceleration a lags by about
/// v²/a), and how long a line may stay silent before nobody is watching
/// the stage is a lab's decision.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SafetySection {
    /// How often a move in flight is checked (ERR?, POS?, ONT?), ms.
    pub supervise_interval_ms: u64,
    /// Largest distance between an axis's controller position and its
    /// commanded trajectory (start → target at the axis velocity), µm;
    /// 0 turns the check off.
    pub following_error_um: f64,
    /// Position reads of an axis may fail (no answer, garbled) for this
    /// long before a fault is latched, s. A line that is down is a fault of
    /// its own at once.
    pub read_fail_s: f64,
    /// How long a halt waits for both axes to come to rest (shutdown,
    /// `microposd --halt`, job cancel), s.
    pub halt_wait_s: f64,
    /// Largest distance between where the camera sees the platform and
    /// where the controller counts it, per axis, µm (`daemon::deviation`:
    /// vision − controller in the stage frame, translation tied at rest);
    /// 0 turns the check off. Above the stage's static error and drift.
    pub deviation_um: f64,
    /// Where the vision → stage orientation of that check comes from.
    pub deviation_frame: DeviationFrame,
}

/// Where the deviation check takes the vision → stage rotation from. Why
/// a choice: a wrong orientation makes every move look like a deviation of
/// up to twice its length, so the check only runs where the orientation is
/// known.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum DeviationFrame {
    /// The active compensation table's vision frame (fitted by the
    /// characterization that built it); no active table with a frame, no
    /// check.
    #[default]
    Table,
    /// `camera.rotation_rad` (for a rig without a table whose camera
    /// orientation is set by hand); an active table's frame still wins.
    Camera,
}

impl Default for SafetySection {
    fn default() -> Self {
        Self {
            supervise_interval_ms: 100,
            following_error_um: 500.0,
            read_fail_s: 2.0,
            halt_wait_s: 5.0,
            deviation_um: 100.0,
            deviation_frame: DeviationFrame::Table,
        }
    }
}

/// `[limits]`: soft limits in µm, controller coordinates. Unset = the
/// controller's travel (`TMN?`/`TMX?`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub struct Limits {
    /// Lowest X target, µm.
    pub x_min_um: Option<f64>,
    /// Highest X target, µm.
    pub x_max_um: Option<f64>,
    /// Lowest Y target, µm.
    pub y_min_um: Option<f64>,
    /// Highest Y target, µm.
    pub y_max_um: Option<f64>,
}

/// `[camera]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CameraSection {
    /// Frame source (`v4l2:/dev/video0`, `genicam[:ID]`, `files:GLOB`,
    /// `sim:PATH` for hil-sim's camera socket); empty = no camera (vision features
    /// answer `camera_unavailable`).
    pub source: String,
    /// Longest wait for a frame, ms.
    pub timeout_ms: u64,
    /// Replay sources: start again after the last file.
    pub looping: bool,
    /// Pattern period, µm.
    pub period_um: f64,
    /// Pattern code depth (4..=12).
    pub bits: u32,
    /// The optics mirror the image.
    pub mirrored: bool,
    /// Oldest measurement a closed-loop move or a job point may use, s.
    pub max_age_s: f64,
    /// Lowest decode quality accepted: the code evidence in bits (log₂
    /// likelihood ratio of the best code position over the runner-up). The
    /// decoder itself refuses less than 16 bits; clean frames score hundreds,
    /// so a lab can raise this to reject marginal frames (dust, defocus).
    pub min_quality: f64,
    /// Angle from the pattern frame to the stage frame, rad
    /// (counter-clockwise positive): stage = R(angle)·vision + offset.
    pub rotation_rad: f64,
}

impl Default for CameraSection {
    fn default() -> Self {
        Self {
            source: String::new(),
            timeout_ms: 2000,
            looping: false,
            period_um: 9.0,
            bits: 12,
            mirrored: false,
            max_age_s: 1.0,
            min_quality: 16.0,
            rotation_rad: 0.0,
        }
    }
}

/// `[characterize]`: job defaults (a `characterize start` may override each).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CharacterizeDefaults {
    /// Step between points, µm.
    pub step_um: f64,
    /// X scan range, µm (centred in the travel unless `x_start_um`).
    pub x_range_um: f64,
    /// Y scan range, µm.
    pub y_range_um: f64,
    /// First X point, µm; unset = centred.
    pub x_start_um: Option<f64>,
    /// First Y point, µm; unset = centred.
    pub y_start_um: Option<f64>,
    /// Forward + backward cycles.
    pub cycles: u32,
    /// Frames averaged per point.
    pub frames_per_point: u32,
    /// Wait after on-target before measuring, s.
    pub settle_s: f64,
    /// Re-measure the drift reference every this many s of rig time during
    /// a characterization; 0 = off (see `docs/measurement-log.md`).
    pub drift_every_s: f64,
    /// Drift reference point `[x, y]`, µm; unset = the scan's start corner.
    pub drift_reference_um: Option<[f64; 2]>,
}

impl Default for CharacterizeDefaults {
    fn default() -> Self {
        Self {
            step_um: 5.0,
            x_range_um: 9500.0,
            y_range_um: 4200.0,
            x_start_um: None,
            y_start_um: None,
            cycles: 3,
            frames_per_point: 4,
            settle_s: 0.5,
            drift_every_s: 0.0,
            drift_reference_um: None,
        }
    }
}

/// `[closed_loop]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ClosedLoop {
    /// Residual accepted, µm.
    pub tolerance_um: f64,
    /// Corrections tried before giving up. Many are cheap: a stage that
    /// is deterministic at the target converges in one or two; where it
    /// scatters at arrival (stick-slip, σ ≈ 10× the tolerance) each try
    /// lands with ≈ 7–8 % chance, so 30 give ≈ 90 % and 60 ≈ 99 %; a
    /// validation visits such a target three times per trajectory, and
    /// one failed loop sets its AP at the stretch's σ.
    pub max_iterations: u32,
    /// Farthest the loop may move the command from the compensated one, µm
    /// (larger than the stage's whole raw error: beyond it the loop is
    /// chasing a wrong transform or a slipping platform, and stops).
    pub max_correction_um: f64,
    /// Every correction re-approaches from behind, so each ends with a move
    /// of the same length (`comp::closed_loop`); false: only corrections
    /// against the arrival direction do.
    pub always_reapproach: bool,
}

impl Default for ClosedLoop {
    fn default() -> Self {
        Self {
            tolerance_um: 0.1,
            max_iterations: 60,
            max_correction_um: 25.0,
            always_reapproach: true,
        }
    }
}

/// `[compensation]`: the backlash strategy of compensated and closed-loop
/// moves. Why a choice: direction-aware tables (the paper) correct the lost
/// motion of either arrival direction, but a unidirectional final approach
/// makes the backlash the same at every target, which is what a lab wants
/// when repeatability matters more than the extra move.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CompensationSection {
    /// `"direction_aware"` (each axis arrives in the direction from its
    /// previous target, corrected by the table of that direction) or
    /// `"unidirectional"` (each axis always arrives moving forward, +µm,
    /// from `overshoot_um` below the target when it comes from above).
    pub approach: Approach,
    /// Distance below the target from which a wrong-side arrival is
    /// re-approached, µm (≥ 10, well beyond the ≈ 2 µm backlash).
    pub overshoot_um: f64,
}

/// The backlash strategy (`[compensation] approach`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum Approach {
    /// Arrive in the direction of travel (the paper).
    #[default]
    DirectionAware,
    /// Always arrive moving forward.
    Unidirectional,
}

impl Default for CompensationSection {
    fn default() -> Self {
        Self {
            approach: Approach::DirectionAware,
            overshoot_um: 20.0,
        }
    }
}

impl CompensationSection {
    /// The planner options this section stands for.
    pub fn plan_options(&self) -> crate::comp::PlanOptions {
        use crate::comp::ApproachPolicy;
        use crate::model::Direction;
        crate::comp::PlanOptions {
            policy: match self.approach {
                Approach::DirectionAware => ApproachPolicy::DirectionAware,
                Approach::Unidirectional => {
                    ApproachPolicy::Unidirectional([Direction::Forward, Direction::Forward])
                }
            },
            overshoot_um: self.overshoot_um,
            ..crate::comp::PlanOptions::default()
        }
    }
}

impl DaemonConfig {
    /// Parses and validates a TOML text.
    pub fn from_toml(text: &str) -> Result<Self, ConfigError> {
        let cfg: DaemonConfig = toml::from_str(text).map_err(|e| ConfigError {
            key: e
                .span()
                .map(|s| format!("at byte {}", s.start))
                .unwrap_or_else(|| "(file)".to_owned()),
            problem: e.message().to_owned(),
        })?;
        cfg.validate()?;
        Ok(cfg)
    }

    /// Reads, parses and validates a file.
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| bad("(file)", format!("cannot read {}: {e}", path.display())))?;
        Self::from_toml(&text)
    }

    /// How the daemon's jobs sync their logs (`daemon.log_sync_every`).
    pub fn log_sync(&self) -> crate::charact::log::SyncPolicy {
        use crate::charact::log::SyncPolicy;
        std::num::NonZeroU32::new(self.daemon.log_sync_every)
            .map_or(SyncPolicy::FlushOnly, SyncPolicy::Every)
    }

    /// The socket mode as a number.
    pub fn socket_mode(&self) -> Result<u32, ConfigError> {
        let s = self.daemon.socket_mode.trim_start_matches("0o");
        u32::from_str_radix(s, 8)
            .ok()
            .filter(|m| *m <= 0o777)
            .ok_or_else(|| {
                bad(
                    "daemon.socket_mode",
                    format!(
                        "{:?} is not an octal mode like \"0660\"",
                        self.daemon.socket_mode
                    ),
                )
            })
    }

    /// The camera source, if one is configured.
    pub fn camera_source(&self) -> Result<Option<SourceSpec>, ConfigError> {
        if self.camera.source.trim().is_empty() {
            return Ok(None);
        }
        self.camera
            .source
            .parse()
            .map(Some)
            .map_err(|e| bad("camera.source", format!("{e}")))
    }

    /// The parsed `[rig] clock`.
    pub fn clock_spec(&self) -> Result<ClockSpec, ConfigError> {
        let c = self.rig.clock.trim();
        if c == "wall" {
            return Ok(ClockSpec::Wall);
        }
        match c.strip_prefix("sim:") {
            Some(p) if !p.is_empty() => Ok(ClockSpec::Sim(PathBuf::from(p))),
            _ => Err(bad(
                "rig.clock",
                format!("{c:?}: expected \"wall\" or \"sim:PATH\" (hil-sim's control socket)"),
            )),
        }
    }

    /// Checks every value that can be checked without hardware.
    pub fn validate(&self) -> Result<(), ConfigError> {
        self.clock_spec()?;
        if self.daemon.socket.as_os_str().is_empty() {
            return Err(bad("daemon.socket", "must be a path"));
        }
        self.socket_mode()?;
        if self.daemon.data_dir.as_os_str().is_empty() {
            return Err(bad("daemon.data_dir", "must be a directory path"));
        }
        if !(10..=60_000).contains(&self.daemon.poll_interval_ms) {
            return Err(bad("daemon.poll_interval_ms", "must be within 10..=60000"));
        }
        let sf = &self.safety;
        if !(10..=60_000).contains(&sf.supervise_interval_ms) {
            return Err(bad(
                "safety.supervise_interval_ms",
                "must be within 10..=60000",
            ));
        }
        if !(sf.following_error_um.is_finite() && sf.following_error_um >= 0.0) {
            return Err(bad(
                "safety.following_error_um",
                "must be a finite number of µm ≥ 0 (0 = off)",
            ));
        }
        if !(sf.read_fail_s.is_finite() && sf.read_fail_s > 0.0 && sf.read_fail_s <= 600.0) {
            return Err(bad("safety.read_fail_s", "must be within (0, 600] s"));
        }
        if !(sf.halt_wait_s.is_finite() && sf.halt_wait_s > 0.0 && sf.halt_wait_s <= 60.0) {
            return Err(bad("safety.halt_wait_s", "must be within (0, 60] s"));
        }
        if !(sf.deviation_um.is_finite() && sf.deviation_um >= 0.0) {
            return Err(bad(
                "safety.deviation_um",
                "must be a finite number of µm ≥ 0 (0 = off)",
            ));
        }
        if self.daemon.max_clients == 0 {
            return Err(bad("daemon.max_clients", "must be at least 1"));
        }
        if !(1..=64).contains(&self.daemon.stop_slots) {
            return Err(bad(
                "daemon.stop_slots",
                "must be within 1..=64 (a full daemon must still accept stop)",
            ));
        }
        let d = &self.daemon;
        if !(d.idle_timeout_s.is_finite() && (0.0..=864_000.0).contains(&d.idle_timeout_s)) {
            return Err(bad(
                "daemon.idle_timeout_s",
                "must be within 0..=864000 s (0 = never)",
            ));
        }
        for (key, v) in [
            ("daemon.read_timeout_s", d.read_timeout_s),
            ("daemon.write_timeout_s", d.write_timeout_s),
        ] {
            if !(v.is_finite() && (0.01..=3600.0).contains(&v)) {
                return Err(bad(key, "must be within 0.01..=3600 s"));
            }
        }
        if let Some(w) = &self.web {
            w.validate()?;
        }
        if let Some(a) = &self.access {
            a.validate()?;
        }
        if self.daemon.job_retries > 100 {
            return Err(bad(
                "daemon.job_retries",
                "must be within 0..=100 (a fault that persists over 100 retries is not transient)",
            ));
        }
        if !(0.0..=60.0).contains(&self.daemon.job_retry_backoff_s) {
            return Err(bad(
                "daemon.job_retry_backoff_s",
                "must be within 0..=60 s (finite)",
            ));
        }
        self.driver
            .validate()
            .map_err(|e| bad("driver", e.to_string()))?;
        for (axis, lo, hi) in [
            ("x", self.limits.x_min_um, self.limits.x_max_um),
            ("y", self.limits.y_min_um, self.limits.y_max_um),
        ] {
            for (k, v) in [("min", lo), ("max", hi)] {
                if let Some(v) = v {
                    if !v.is_finite() {
                        return Err(bad(&format!("limits.{axis}_{k}_um"), "must be finite"));
                    }
                }
            }
            if let (Some(lo), Some(hi)) = (lo, hi) {
                if lo >= hi {
                    return Err(bad(
                        &format!("limits.{axis}_min_um"),
                        format!("{lo} must be below {axis}_max_um = {hi}"),
                    ));
                }
            }
        }
        self.camera_source()?;
        let c = &self.camera;
        if c.timeout_ms == 0 {
            return Err(bad("camera.timeout_ms", "must be positive"));
        }
        if !(c.period_um.is_finite() && c.period_um > 0.0) {
            return Err(bad("camera.period_um", "must be a positive number of µm"));
        }
        if !(4..=12).contains(&c.bits) {
            return Err(bad("camera.bits", "must be within 4..=12"));
        }
        if !(c.max_age_s.is_finite() && c.max_age_s > 0.0) {
            return Err(bad("camera.max_age_s", "must be a positive number of s"));
        }
        if !c.min_quality.is_finite() {
            return Err(bad("camera.min_quality", "must be a number"));
        }
        if !c.rotation_rad.is_finite() {
            return Err(bad("camera.rotation_rad", "must be a number"));
        }
        let k = &self.characterize;
        for (key, v) in [
            ("characterize.step_um", k.step_um),
            ("characterize.x_range_um", k.x_range_um),
            ("characterize.y_range_um", k.y_range_um),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(bad(
                    key,
                    format!("must be a positive number of µm, got {v}"),
                ));
            }
        }
        if k.step_um > k.x_range_um.min(k.y_range_um) {
            return Err(bad(
                "characterize.step_um",
                "must not exceed the scan ranges",
            ));
        }
        if !(1..=1000).contains(&k.cycles) {
            return Err(bad("characterize.cycles", "must be within 1..=1000"));
        }
        if !(1..=1000).contains(&k.frames_per_point) {
            return Err(bad(
                "characterize.frames_per_point",
                "must be within 1..=1000",
            ));
        }
        if !(k.settle_s.is_finite() && (0.0..=3600.0).contains(&k.settle_s)) {
            return Err(bad("characterize.settle_s", "must be within 0..=3600 s"));
        }
        if !(k.drift_every_s.is_finite() && (0.0..=86_400.0).contains(&k.drift_every_s)) {
            return Err(bad(
                "characterize.drift_every_s",
                "must be within 0..=86400 s (0 = off)",
            ));
        }
        if k.drift_reference_um
            .is_some_and(|r| !r.iter().all(|v| v.is_finite()))
        {
            return Err(bad(
                "characterize.drift_reference_um",
                "must be two finite numbers [x, y] µm",
            ));
        }
        let d = &self.drift;
        if !(d.every_s.is_finite() && (0.001..=86_400.0).contains(&d.every_s)) {
            return Err(bad("drift.every_s", "must be within 0.001..=86400 s"));
        }
        if !(d.time_constant_s.is_finite() && d.time_constant_s > 0.0) {
            return Err(bad(
                "drift.time_constant_s",
                "must be a positive number of s",
            ));
        }
        if d.reference_um
            .is_some_and(|r| !r.iter().all(|v| v.is_finite()))
        {
            return Err(bad(
                "drift.reference_um",
                "must be two finite numbers [x, y] µm",
            ));
        }
        let cl = &self.closed_loop;
        if !(cl.tolerance_um.is_finite() && cl.tolerance_um > 0.0) {
            return Err(bad(
                "closed_loop.tolerance_um",
                "must be a positive number of µm",
            ));
        }
        if !(1..=100).contains(&cl.max_iterations) {
            return Err(bad("closed_loop.max_iterations", "must be within 1..=100"));
        }
        if !(cl.max_correction_um.is_finite() && cl.max_correction_um > 0.0) {
            return Err(bad(
                "closed_loop.max_correction_um",
                "must be a positive number of µm",
            ));
        }
        let o = self.compensation.overshoot_um;
        if !(o.is_finite() && (10.0..=1000.0).contains(&o)) {
            return Err(bad(
                "compensation.overshoot_um",
                format!("must be within 10..=1000 µm (beyond the backlash), got {o}"),
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MIN: &str = "[driver.x]\nport = \"/dev/ttyUSB0\"\n[driver.y]\nport = \"/dev/ttyUSB1\"\n";

    #[test]
    fn minimal_file_gets_defaults() {
        let c = DaemonConfig::from_toml(MIN).unwrap();
        assert_eq!(
            c.daemon.socket,
            PathBuf::from("/run/micropos/micropos.sock")
        );
        assert_eq!(c.socket_mode().unwrap(), 0o660);
        assert_eq!(c.characterize.step_um, 5.0);
        assert_eq!(c.characterize.cycles, 3);
        assert!(c.camera_source().unwrap().is_none());
    }

    #[test]
    fn errors_name_the_key() {
        let e =
            DaemonConfig::from_toml(&format!("{MIN}[characterize]\nstep_um = -1\n")).unwrap_err();
        assert_eq!(e.key, "characterize.step_um");
        let e = DaemonConfig::from_toml(&format!("{MIN}[daemon]\nsocket_mode = \"999\"\n"))
            .unwrap_err();
        assert_eq!(e.key, "daemon.socket_mode");
        let e = DaemonConfig::from_toml(&format!("{MIN}[limits]\nx_min_um = 5\nx_max_um = 1\n"))
            .unwrap_err();
        assert_eq!(e.key, "limits.x_min_um");
        let e =
            DaemonConfig::from_toml(&format!("{MIN}[camera]\nsource = \"webcam\"\n")).unwrap_err();
        assert_eq!(e.key, "camera.source");
        let e = DaemonConfig::from_toml("[driver.x]\nport = \"/dev/a\"\n").unwrap_err();
        assert_eq!(e.key, "driver");
        let e = DaemonConfig::from_toml(&format!("{MIN}[daemon]\nsokcet = \"/x\"\n")).unwrap_err();
        assert!(e.problem.contains("sokcet"), "{e}");
    }

    #[test]
    fn compensation_approach_selects_the_backlash_strategy() {
        use crate::comp::ApproachPolicy;
        use crate::model::Direction;
        let c = DaemonConfig::from_toml(MIN).unwrap();
        assert_eq!(
            c.compensation.plan_options().policy,
            ApproachPolicy::DirectionAware
        );
        let c = DaemonConfig::from_toml(&format!(
            "{MIN}[compensation]\napproach = \"unidirectional\"\novershoot_um = 30\n"
        ))
        .unwrap();
        let o = c.compensation.plan_options();
        assert_eq!(
            o.policy,
            ApproachPolicy::Unidirectional([Direction::Forward, Direction::Forward])
        );
        assert_eq!(o.overshoot_um, 30.0);
        o.validate().unwrap();
        let e = DaemonConfig::from_toml(&format!("{MIN}[compensation]\napproach = \"sideways\"\n"))
            .unwrap_err();
        assert!(e.problem.contains("sideways"), "{e}");
        let e = DaemonConfig::from_toml(&format!("{MIN}[compensation]\novershoot_um = 1\n"))
            .unwrap_err();
        assert_eq!(e.key, "compensation.overshoot_um");
    }

    #[test]
    fn drift_section_defaults_off_and_is_checked() {
        use crate::analysis::drift::LiveMethod;
        let c = DaemonConfig::from_toml(MIN).unwrap();
        assert_eq!(c.drift.live_method(), LiveMethod::Off);
        let c = DaemonConfig::from_toml(&format!(
            "{MIN}[drift]\nmethod = \"adaptive\"\nevery_s = 60\ntime_constant_s = 600\n"
        ))
        .unwrap();
        assert_eq!(
            c.drift.live_method(),
            LiveMethod::Adaptive {
                time_constant_s: 600.0
            }
        );
        assert_eq!(c.drift.every_s, 60.0);
        for (text, key) in [
            ("every_s = 0", "drift.every_s"),
            ("time_constant_s = -1", "drift.time_constant_s"),
        ] {
            let e = DaemonConfig::from_toml(&format!("{MIN}[drift]\n{text}\n")).unwrap_err();
            assert_eq!(e.key, key);
        }
        let e =
            DaemonConfig::from_toml(&format!("{MIN}[drift]\nmethod = \"kalman\"\n")).unwrap_err();
        assert!(e.problem.contains("kalman"), "{e}");
    }

    #[test]
    fn web_section_is_checked() {
        let c = DaemonConfig::from_toml(MIN).unwrap();
        assert_eq!(c.web, None);
        let c = DaemonConfig::from_toml(&format!("{MIN}[web]\n")).unwrap();
        let w = c.web.unwrap();
        assert_eq!(w.listen_addr().unwrap().to_string(), "127.0.0.1:8080");
        assert!(!w.control);
        assert_eq!(w.resolve_token().unwrap(), None);
        for (extra, key) in [
            ("listen = \"localhost\"", "web.listen"),
            ("role = \"root\"", "web.role"),
            ("control = true", "web.control"),
            ("control = true\ntoken = \"short\"", "web.token"),
            (
                "token = \"0123456789abcdef\"\ntoken_file = \"/x\"",
                "web.token",
            ),
            ("camera_max_hz = 0", "web.camera_max_hz"),
            ("camera_max_px = 4", "web.camera_max_px"),
        ] {
            let e = DaemonConfig::from_toml(&format!("{MIN}[web]\n{extra}\n")).unwrap_err();
            assert_eq!(e.key, key, "{extra}: {e}");
        }
        let c = DaemonConfig::from_toml(&format!(
            "{MIN}[web]\ncontrol = true\ntoken = \"0123456789abcdef\"\nrole = \"read\"\n"
        ))
        .unwrap();
        let w = c.web.clone().unwrap();
        assert_eq!(
            w.resolve_token().unwrap().as_deref(),
            Some("0123456789abcdef")
        );
        assert_eq!(w.role().unwrap(), crate::daemon::protocol::Role::Read);
        // The token never leaves through `config`.
        let shown = serde_json::to_string(&c).unwrap();
        assert!(!shown.contains("0123456789abcdef"), "{shown}");
    }

    #[test]
    fn web_token_file_must_be_private() {
        use std::os::unix::fs::PermissionsExt;
        let dir = tempfile::tempdir().unwrap();
        let f = dir.path().join("token");
        std::fs::write(&f, "0123456789abcdef0123\n").unwrap();
        let w = WebSection {
            control: true,
            token_file: Some(f.clone()),
            ..WebSection::default()
        };
        std::fs::set_permissions(&f, std::fs::Permissions::from_mode(0o644)).unwrap();
        let e = w.resolve_token().unwrap_err();
        assert_eq!(e.key, "web.token_file");
        assert!(e.problem.contains("chmod 600"), "{e}");
        std::fs::set_permissions(&f, std::fs::Permissions::from_mode(0o600)).unwrap();
        assert_eq!(
            w.resolve_token().unwrap().as_deref(),
            Some("0123456789abcdef0123")
        );
        let missing = WebSection {
            token_file: Some(dir.path().join("none")),
            ..w
        };
        assert_eq!(missing.resolve_token().unwrap_err().key, "web.token_file");
    }

    #[test]
    fn access_and_client_limits_are_checked() {
        let c = DaemonConfig::from_toml(MIN).unwrap();
        assert_eq!(c.access, None);
        assert_eq!(c.daemon.stop_slots, 4);
        let c = DaemonConfig::from_toml(&format!(
            "{MIN}[access]\nread = [\"users\", \"1000\"]\noperate = [\"lab-ops\"]\n"
        ))
        .unwrap();
        let a = c.access.unwrap();
        assert_eq!(a.read, ["users", "1000"]);
        assert!(a.admin.is_empty());
        for (text, key) in [
            ("[access]\nread = [\"a b\"]", "access.read"),
            ("[access]\nadmin = [\"\"]", "access.admin"),
            ("[daemon]\nstop_slots = 0", "daemon.stop_slots"),
            ("[daemon]\nidle_timeout_s = -1", "daemon.idle_timeout_s"),
            ("[daemon]\nread_timeout_s = 0", "daemon.read_timeout_s"),
            ("[daemon]\nwrite_timeout_s = inf", "daemon.write_timeout_s"),
        ] {
            let e = DaemonConfig::from_toml(&format!("{MIN}{text}\n")).unwrap_err();
            assert_eq!(e.key, key, "{text}");
        }
        let e = DaemonConfig::from_toml(&format!("{MIN}[access]\nwrite = [\"x\"]\n")).unwrap_err();
        assert!(e.problem.contains("write"), "{e}");
    }

    #[test]
    fn shipped_configs_are_valid() {
        for f in ["config/microposd.toml", "config/microposd-sim.toml"] {
            let p = Path::new(env!("CARGO_MANIFEST_DIR")).join(f);
            DaemonConfig::load(&p).unwrap_or_else(|e| panic!("{f}: {e}"));
        }
    }
}
