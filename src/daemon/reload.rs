//! What a configuration reload (SIGHUP) may change while the daemon runs,
//! and the running values of those settings.
//!
//! Reloadable: `[limits]` (checked before every move), `[compensation]`
//! (read when a move is planned), `[drift]` (method, interval, time
//! constant, reference) and `[access]` (roles of new connections). Why
//! only these: everything else is bound at start to something that lives
//! on (the open serial lines and camera, the socket, the clock, a running
//! job's plan), and changing it under a running rig would be a restart in
//! disguise. Those keys are named in a log line and keep their running
//! values; the file's other changes still apply.
//!
//! [`diff_keys`] is the sans-IO core: the dotted keys in which two
//! configurations differ.

use super::config::{CompensationSection, DaemonConfig, DriftSection, Limits};
use serde_json::Value;
use std::sync::RwLock;

/// Sections a reload applies (as dotted-key prefixes).
pub const RELOADABLE: &[&str] = &["limits", "compensation", "drift", "access"];

/// The running values of the reloadable sections.
#[derive(Debug)]
pub struct Live {
    inner: RwLock<LiveValues>,
}

#[derive(Debug, Clone)]
struct LiveValues {
    limits: Limits,
    compensation: CompensationSection,
    drift: DriftSection,
}

impl Live {
    /// The values of `cfg`.
    pub fn new(cfg: &DaemonConfig) -> Live {
        Live {
            inner: RwLock::new(LiveValues {
                limits: cfg.limits,
                compensation: cfg.compensation.clone(),
                drift: cfg.drift.clone(),
            }),
        }
    }

    fn read(&self) -> LiveValues {
        match self.inner.read() {
            Ok(g) => g.clone(),
            Err(p) => p.into_inner().clone(),
        }
    }

    /// The soft limits in force.
    pub fn limits(&self) -> Limits {
        self.read().limits
    }

    /// The `[compensation]` settings in force.
    pub fn compensation(&self) -> CompensationSection {
        self.read().compensation
    }

    /// The `[drift]` settings in force.
    pub fn drift(&self) -> DriftSection {
        self.read().drift
    }

    /// Takes the reloadable sections of `cfg`.
    pub fn set(&self, cfg: &DaemonConfig) {
        let v = LiveValues {
            limits: cfg.limits,
            compensation: cfg.compensation.clone(),
            drift: cfg.drift.clone(),
        };
        match self.inner.write() {
            Ok(mut g) => *g = v,
            Err(p) => *p.into_inner() = v,
        }
    }

    /// `cfg` with the running values of the reloadable sections (what
    /// `config` reports).
    pub fn effective(&self, cfg: &DaemonConfig) -> DaemonConfig {
        let v = self.read();
        let mut c = cfg.clone();
        c.limits = v.limits;
        c.compensation = v.compensation;
        c.drift = v.drift;
        c
    }
}

/// What a reload did.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct ReloadReport {
    /// Keys whose new values are in force.
    pub applied: Vec<String>,
    /// Keys that changed in the file but keep their running values.
    pub refused: Vec<String>,
}

/// The dotted keys (`limits.x_max_um`, `access`) whose values differ
/// between `a` and `b`. Tables are compared key by key; arrays and an
/// absent-vs-present section count as one key.
pub fn diff_keys(a: &DaemonConfig, b: &DaemonConfig) -> Vec<String> {
    let (va, vb) = match (serde_json::to_value(a), serde_json::to_value(b)) {
        (Ok(va), Ok(vb)) => (va, vb),
        // Serializing a validated config cannot fail (finite floats,
        // string keys); if it did, call everything changed.
        _ => return vec!["(file)".to_owned()],
    };
    let mut out = Vec::new();
    diff(&va, &vb, "", &mut out);
    out
}

fn diff(a: &Value, b: &Value, prefix: &str, out: &mut Vec<String>) {
    match (a, b) {
        (Value::Object(ma), Value::Object(mb)) => {
            let mut keys: Vec<&String> = ma.keys().chain(mb.keys()).collect();
            keys.sort();
            keys.dedup();
            for k in keys {
                let p = if prefix.is_empty() {
                    k.clone()
                } else {
                    format!("{prefix}.{k}")
                };
                diff(
                    ma.get(k).unwrap_or(&Value::Null),
                    mb.get(k).unwrap_or(&Value::Null),
                    &p,
                    out,
                );
            }
        }
        _ if a != b => out.push(prefix.to_owned()),
        _ => {}
    }
}

/// Whether a changed key may be applied live.
pub fn is_reloadable(key: &str) -> bool {
    RELOADABLE
        .iter()
        .any(|p| key == *p || key.strip_prefix(p).is_some_and(|r| r.starts_with('.')))
}

#[cfg(test)]
mod tests {
    use super::*;

    const MIN: &str = "[driver.x]\nport = \"/dev/ttyUSB0\"\n[driver.y]\nport = \"/dev/ttyUSB1\"\n";

    fn cfg(extra: &str) -> DaemonConfig {
        DaemonConfig::from_toml(&format!("{MIN}{extra}")).unwrap()
    }

    #[test]
    fn changed_keys_are_named_and_split_by_reloadability() {
        let a = cfg("");
        assert!(diff_keys(&a, &a).is_empty());
        let b = cfg(
            "[limits]\nx_max_um = 100\n[daemon]\npoll_interval_ms = 500\n\
             [drift]\nmethod = \"static\"\n[access]\nread = [\"users\"]\n",
        );
        let keys = diff_keys(&a, &b);
        assert_eq!(
            keys,
            [
                "access",
                "daemon.poll_interval_ms",
                "drift.method",
                "limits.x_max_um"
            ]
        );
        let refused: Vec<&String> = keys.iter().filter(|k| !is_reloadable(k)).collect();
        assert_eq!(refused, ["daemon.poll_interval_ms"]);
        assert!(!is_reloadable("limitsx"));
    }

    #[test]
    fn live_values_replace_the_sections_in_the_effective_config() {
        let a = cfg("");
        let live = Live::new(&a);
        let b = cfg("[limits]\ny_min_um = 5\n[compensation]\novershoot_um = 30\n");
        live.set(&b);
        assert_eq!(live.limits().y_min_um, Some(5.0));
        assert_eq!(live.compensation().overshoot_um, 30.0);
        let e = live.effective(&a);
        assert!(diff_keys(&e, &b).is_empty());
    }
}
