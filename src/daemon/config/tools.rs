//! `[tools]`: tool points on the platform, at an arm from the point the
//! camera watches.

use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

use super::error::{bad, ConfigError};

/// Largest tool arm accepted per component, µm (1 m: no tool on a
/// micropositioning stage reaches further; a larger value is a typo).
pub const MAX_TOOL_OFFSET_UM: f64 = 1e6;

/// `[tools]`: the tools fastened to the platform. Why: what a lab positions
/// is a gripper's jaws or a probe's tip at an arm from the watched point;
/// the platform's yaw turns that arm (`move --tool NAME`, see
/// `docs/design/daemon.md`). Written as
///
/// ```toml
/// [tools]
/// active = "gripper"
/// [tools.points.gripper]
/// offset_um = [0.0, 20000.0]
/// ```
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub struct ToolsSection {
    /// The tool `move --tool` uses when the request names none; `None`:
    /// a tool move must name its tool.
    pub active: Option<String>,
    /// The tools by name.
    pub points: BTreeMap<String, ToolPoint>,
}

/// One tool point.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ToolPoint {
    /// The tool's offset from the watched point `[x, y]`, µm, in the
    /// platform frame as it was at the characterization's tie (the stage
    /// axes when the platform is not turned); the yaw since turns it.
    pub offset_um: [f64; 2],
}

impl ToolsSection {
    /// Checks names, offsets and that `active` names a tool.
    pub fn validate(&self) -> Result<(), ConfigError> {
        for (name, p) in &self.points {
            let ok_name = !name.is_empty()
                && name.len() <= 64
                && name
                    .chars()
                    .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-');
            if !ok_name {
                return Err(bad(
                    "tools.points",
                    "tool names are 1 to 64 of A-Z a-z 0-9 _ -",
                ));
            }
            if !p
                .offset_um
                .iter()
                .all(|v| v.is_finite() && v.abs() <= MAX_TOOL_OFFSET_UM)
            {
                return Err(bad(
                    &format!("tools.points.{name}.offset_um"),
                    format!("must be two finite numbers [x, y] µm within ±{MAX_TOOL_OFFSET_UM:e}"),
                ));
            }
        }
        if let Some(a) = &self.active {
            if !self.points.contains_key(a) {
                return Err(bad(
                    "tools.active",
                    format!(
                        "names no tool of [tools.points] (configured: {})",
                        self.names()
                    ),
                ));
            }
        }
        Ok(())
    }

    /// The tool `name`, or the active one for `None`; the error says what
    /// is configured.
    pub fn resolve(&self, name: Option<&str>) -> Result<(&str, ToolPoint), String> {
        let Some(n) = name.or(self.active.as_deref()) else {
            return Err(format!(
                "no tool named and no [tools] active (configured: {})",
                self.names()
            ));
        };
        self.points
            .get_key_value(n)
            .map(|(k, p)| (k.as_str(), *p))
            .ok_or_else(|| {
                format!(
                    "no tool {n:?} in [tools.points] (configured: {})",
                    self.names()
                )
            })
    }

    fn names(&self) -> String {
        if self.points.is_empty() {
            "none".to_owned()
        } else {
            self.points.keys().cloned().collect::<Vec<_>>().join(", ")
        }
    }
}
