//! The daemon configuration (`microposd.toml`), validated at start so a bad
//! file stops the daemon with a message naming the key and the problem
//! instead of failing hours later in a job.

mod access;
mod camera;
mod characterize;
mod compensation;
mod daemon;
mod drift;
mod error;
mod locate;
mod safety;
mod tools;
mod web;

pub use access::AccessSection;
pub use camera::CameraSection;
pub use characterize::CharacterizeDefaults;
pub use compensation::{Approach, ClosedLoop, CompensationSection, OutsideTable};
pub use daemon::{ClockSpec, DaemonSection, RigSection};
pub use drift::{DriftMethodName, DriftSection};
pub use error::{written_key, ConfigError};
pub use safety::{DeviationFrame, Limits, SafetySection};
pub use tools::{ToolPoint, ToolsSection, MAX_TOOL_OFFSET_UM};
pub use web::{WebSection, MIN_WEB_TOKEN_CHARS};

use crate::camera::SourceSpec;
use crate::driver::DriverConfig;
use error::bad;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

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
    /// `[audit]`: the audit file's per-source rate and rotation
    /// (`src/daemon/audit.rs`), so refused requests cannot fill the disk.
    pub audit: crate::daemon::audit::AuditLimits,
    /// Tool points at an arm from the watched point (`move --tool`).
    pub tools: ToolsSection,
}

impl DaemonConfig {
    /// Parses and validates a TOML text. An error names the key as the
    /// file writes it, its line and column, and for a misspelt key or
    /// value the one that was probably meant.
    pub fn from_toml(text: &str) -> Result<Self, ConfigError> {
        let cfg: DaemonConfig = toml::from_str(text).map_err(|e| parse_error(text, &e))?;
        cfg.validate().map_err(|mut e| {
            e.line_column = locate::offset_of(text, &e.key).map(|o| locate::line_column(text, o));
            e
        })?;
        Ok(cfg)
    }

    /// Reads, parses and validates a file; an error names the file.
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let in_file = |mut e: ConfigError| {
            e.file = Some(path.to_owned());
            e
        };
        let text = std::fs::read_to_string(path)
            .map_err(|e| in_file(bad("(file)", format!("cannot read it: {e}"))))?;
        let cfg = Self::from_toml(&text).map_err(in_file)?;
        if let Some(web) = &cfg.web {
            use std::os::unix::fs::PermissionsExt;
            let mode = std::fs::metadata(path)
                .map_err(|e| in_file(bad("(file)", format!("cannot read it: {e}"))))?
                .permissions()
                .mode();
            web::check_inline_token_file_mode(web, path, mode).map_err(|mut e| {
                e.line_column =
                    locate::offset_of(&text, &e.key).map(|o| locate::line_column(&text, o));
                in_file(e)
            })?;
        }
        Ok(cfg)
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
        self.check_daemon_paths()?;
        self.check_safety()?;
        self.check_client_limits()?;
        if let Some(w) = &self.web {
            w.validate()?;
        }
        if let Some(a) = &self.access {
            a.validate()?;
        }
        self.check_audit_and_retries()?;
        self.driver
            .validate()
            .map_err(|e| bad("driver", e.to_string()))?;
        self.check_limits()?;
        self.camera_source()?;
        self.check_camera()?;
        self.check_characterize()?;
        self.check_drift()?;
        self.check_compensation()?;
        self.tools.validate()?;
        Ok(())
    }

    /// The daemon's socket, data directory and polling.
    fn check_daemon_paths(&self) -> Result<(), ConfigError> {
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
        Ok(())
    }

    /// The supervisor's limits: what halts the rig.
    fn check_safety(&self) -> Result<(), ConfigError> {
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
        Ok(())
    }

    /// How many clients, for how long: what keeps a stop admitted.
    fn check_client_limits(&self) -> Result<(), ConfigError> {
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
        if d.max_clients_per_uid == 0 || d.stop_slots_per_uid == 0 {
            return Err(bad(
                if d.max_clients_per_uid == 0 {
                    "daemon.max_clients_per_uid"
                } else {
                    "daemon.stop_slots_per_uid"
                },
                "must be at least 1 (values above max_clients or stop_slots mean no cap per user)",
            ));
        }
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
        Ok(())
    }

    /// The audit log's rate and size, and a job's retries.
    fn check_audit_and_retries(&self) -> Result<(), ConfigError> {
        let au = &self.audit;
        if !(au.rate_per_s.is_finite() && au.rate_per_s > 0.0) {
            return Err(bad(
                "audit.rate_per_s",
                "must be a positive number of records per second",
            ));
        }
        if !(au.burst.is_finite() && au.burst >= 1.0) {
            return Err(bad("audit.burst", "must be at least 1 record"));
        }
        if au.max_bytes < 4096 {
            return Err(bad("audit.max_bytes", "must be at least 4096 bytes"));
        }
        if au.files > 100 {
            return Err(bad("audit.files", "must be within 0..=100"));
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
        Ok(())
    }

    /// The soft travel limits.
    fn check_limits(&self) -> Result<(), ConfigError> {
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
        Ok(())
    }

    /// The camera and the decoder's acceptance.
    fn check_camera(&self) -> Result<(), ConfigError> {
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
        if c.pixel_um.is_some_and(|p| !(p.is_finite() && p > 0.0)) {
            return Err(bad("camera.pixel_um", "must be a positive number of µm"));
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
        Ok(())
    }

    /// A characterization's defaults.
    fn check_characterize(&self) -> Result<(), ConfigError> {
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
        Ok(())
    }

    /// Live drift correction.
    fn check_drift(&self) -> Result<(), ConfigError> {
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
        Ok(())
    }

    /// Closed loop and compensated moves.
    fn check_compensation(&self) -> Result<(), ConfigError> {
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
        let m = self.compensation.outside_margin_um;
        if !(m.is_finite() && m >= 0.0) {
            return Err(bad(
                "compensation.outside_margin_um",
                format!("must be a finite number of µm ≥ 0, got {m}"),
            ));
        }
        Ok(())
    }
}

/// A parse error of `text` (syntax, unknown key, wrong type) as a
/// [`ConfigError`]: the key path and the line and column at its span, a
/// did-you-mean for an unknown key or value, Rust's type names in words.
fn parse_error(text: &str, e: &toml::de::Error) -> ConfigError {
    let at = e.span().map(|s| s.start);
    let message = e.message().trim_end();
    let mut problem = message.to_owned();
    if let Some((word, expected)) = locate::unknown_and_expected(message) {
        if let Some(meant) = locate::did_you_mean(word, &expected) {
            // Right after the unknown word, before the (long) list.
            let head = format!("`{word}`");
            problem = message.replacen(&head, &format!("{head} (did you mean `{meant}`?)"), 1);
        }
    }
    for (rust, words) in [
        ("expected u8", "expected a whole number 0..=255"),
        ("expected u16", "expected a whole number 0..=65535"),
        ("expected u32", "expected a whole number ≥ 0"),
        ("expected u64", "expected a whole number ≥ 0"),
        ("expected usize", "expected a whole number ≥ 0"),
        ("expected i64", "expected a whole number"),
        ("expected f64", "expected a number"),
    ] {
        if let Some(head) = problem.strip_suffix(rust) {
            problem = format!("{head}{words}");
        }
    }
    ConfigError {
        key: at
            .and_then(|a| locate::key_at(text, a))
            .unwrap_or_else(|| "(syntax)".to_owned()),
        problem,
        line_column: at.map(|a| locate::line_column(text, a)),
        file: None,
    }
}

#[cfg(test)]
mod tests;
