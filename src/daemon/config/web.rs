//! `[web]`: the web view's listener, token and role.

use super::error::{bad, ConfigError};
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

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
    /// Names (without port) the `Host` header may carry besides the
    /// loopback names `localhost`, `127.0.0.1` and `[::1]`, e.g. this
    /// host's lab name or address when `listen` is not loopback. Any
    /// other `Host` is refused (421): DNS rebinding.
    pub hosts: Vec<String>,
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
            hosts: Vec::new(),
        }
    }
}

/// The shortest token accepted: a guessable token on a network port is
/// no gate (32 characters: `openssl rand -hex 16` and longer).
pub const MIN_WEB_TOKEN_CHARS: usize = 32;

/// The fewest distinct characters a token may have: a long token made of
/// few characters (`aaaa…`, `abab…`, a word repeated) is low-entropy and
/// guessable. A random hex token of 32 characters has ≈ 15 distinct ones;
/// below 10 happens for a random one with odds under 1 in 10^9.
pub const MIN_WEB_TOKEN_DISTINCT_CHARS: usize = 10;

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
    if let Some(why) = weak_token(t.as_bytes()) {
        return Err(bad(
            key,
            format!(
                "the token is guessable: {why}; use a random one (e.g. `openssl rand -hex 32`)"
            ),
        ));
    }
    Ok(t.to_owned())
}

/// Why a printable token of sufficient length is still guessable, or
/// `None`. The rule (documented in docs/design/web.md): at least
/// [`MIN_WEB_TOKEN_DISTINCT_CHARS`] distinct characters, no character making up
/// more than half of it, and not a shorter string repeated.
fn weak_token(t: &[u8]) -> Option<String> {
    let mut count = [0usize; 256];
    for &b in t {
        count[usize::from(b)] += 1;
    }
    let distinct = count.iter().filter(|&&n| n > 0).count();
    if distinct < MIN_WEB_TOKEN_DISTINCT_CHARS {
        return Some(format!(
            "it uses {distinct} distinct characters (at least {MIN_WEB_TOKEN_DISTINCT_CHARS} needed)"
        ));
    }
    let most = count.iter().copied().max().unwrap_or(0);
    if 2 * most > t.len() {
        return Some(format!(
            "one character makes up {most} of its {} characters",
            t.len()
        ));
    }
    let period = (1..=t.len() / 2).find(|&p| (p..t.len()).all(|i| t[i] == t[i - p]));
    period.map(|p| format!("it repeats a {p}-character string"))
}

/// Refuses an inline `token` in a configuration file that its group or
/// others can read (`mode`): anyone who reads the file holds the web's
/// role, past the socket's group and `[access]`.
pub(super) fn check_inline_token_file_mode(
    web: &WebSection,
    path: &std::path::Path,
    mode: u32,
) -> Result<(), ConfigError> {
    if web.token.is_some() && mode & 0o077 != 0 {
        return Err(bad(
            "web.token",
            format!(
                "the token is inline in {} (mode {:04o}), which group or others can read: move it to token_file (chmod 600) or chmod 600 the configuration",
                path.display(),
                mode & 0o7777
            ),
        ));
    }
    Ok(())
}
