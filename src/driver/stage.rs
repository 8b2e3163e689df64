//! The two axes of an XY stage, from configuration: each on its own port, or
//! both daisy-chained on one port (one line task serves both addresses).

use super::axis::{Axis, AxisParams, ReferenceMode};
use super::controller::Controller;
use super::error::DriverError;
use super::line::{Line, LineOptions};
use super::transport::{Framing, LinkOpener, OpenerConnector, SerialConnector, SerialSettings};
use super::AxisEvent;
use crate::gcs::frame::Address;
use crate::gcs::AxisId;
use serde::{Deserialize, Serialize};
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;
use tokio::sync::broadcast;

/// Configuration of one axis (the `[driver.x]` / `[driver.y]` tables).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AxisConfig {
    /// Serial device (a stable `/dev/serial/by-id/...` path or a symlink).
    pub port: PathBuf,
    /// Baud rate (C-863 default 115200).
    pub baud: u32,
    /// Character framing, e.g. `"8N1"`.
    pub framing: Framing,
    /// Daisy-chain address 1..=16; leave unset for a controller alone on its
    /// line (no address prefix is sent).
    pub address: Option<u8>,
    /// Axis identifier on the controller (`"1"` on a C-863).
    pub axis: String,
    /// Referencing method: `"frf"` (reference switch), `"fnl"`, `"fpl"`.
    pub reference: ReferenceMode,
    /// Answer timeout in ms, counted from the last byte received.
    pub timeout_ms: u64,
    /// Longest referencing time in s.
    pub reference_timeout_s: f64,
    /// Default longest wait for on-target in s.
    pub motion_timeout_s: f64,
    /// Polling period while waiting, in ms.
    pub poll_interval_ms: u64,
}

impl Default for AxisConfig {
    fn default() -> Self {
        Self {
            port: PathBuf::new(),
            baud: 115_200,
            framing: Framing::default(),
            address: None,
            axis: "1".to_owned(),
            reference: ReferenceMode::Frf,
            timeout_ms: 1000,
            reference_timeout_s: 60.0,
            motion_timeout_s: 60.0,
            poll_interval_ms: 20,
        }
    }
}

impl AxisConfig {
    /// The serial settings of its line.
    pub fn serial(&self) -> SerialSettings {
        SerialSettings {
            baud: self.baud,
            framing: self.framing,
        }
    }

    /// The daisy-chain address, if any.
    pub fn address(&self) -> Result<Option<Address>, DriverError> {
        self.address
            .map(|a| Address::new(a).map_err(|e| DriverError::Invalid(e.to_string())))
            .transpose()
    }

    fn params(&self, name: &str) -> Result<AxisParams, DriverError> {
        let secs = |v: f64, what: &str| {
            Duration::try_from_secs_f64(v).map_err(|_| {
                DriverError::Invalid(format!(
                    "axis {name}: {what} {v} s is not a non-negative duration"
                ))
            })
        };
        if self.timeout_ms == 0 {
            return Err(DriverError::Invalid(format!(
                "axis {name}: timeout_ms must be positive"
            )));
        }
        Ok(AxisParams {
            name: name.to_owned(),
            axis: AxisId::new(&self.axis).map_err(|e| DriverError::Invalid(e.to_string()))?,
            reference: self.reference,
            reference_timeout: secs(self.reference_timeout_s, "reference_timeout_s")?,
            motion_timeout: secs(self.motion_timeout_s, "motion_timeout_s")?,
            poll_interval: Duration::from_millis(self.poll_interval_ms.max(1)),
        })
    }
}

/// Configuration of the stage driver (the `[driver]` table).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DriverConfig {
    /// The X axis.
    pub x: AxisConfig,
    /// The Y axis.
    pub y: AxisConfig,
    /// First delay between reopen attempts after a fault, ms.
    pub reconnect_min_ms: u64,
    /// Largest delay between reopen attempts, ms: also the longest a
    /// controller whose line came back runs on before the `#24` that every
    /// re-opened line starts with (a reopen attempt is one `open(2)`).
    pub reconnect_max_ms: u64,
}

impl Default for DriverConfig {
    fn default() -> Self {
        Self {
            x: AxisConfig::default(),
            y: AxisConfig::default(),
            reconnect_min_ms: 50,
            reconnect_max_ms: 100,
        }
    }
}

impl DriverConfig {
    /// Checks what can be checked without hardware: a shared port must have
    /// the same serial settings and two distinct explicit addresses.
    pub fn validate(&self) -> Result<(), DriverError> {
        for (n, a) in [("x", &self.x), ("y", &self.y)] {
            if a.port.as_os_str().is_empty() {
                return Err(DriverError::Invalid(format!(
                    "axis {n}: no port configured"
                )));
            }
            a.address()?;
            a.params(n)?;
        }
        if self.x.port == self.y.port {
            if self.x.serial() != self.y.serial() {
                return Err(DriverError::Invalid(format!(
                    "x and y share {} but have different serial settings",
                    self.x.port.display()
                )));
            }
            match (self.x.address, self.y.address) {
                (Some(a), Some(b)) if a != b => {}
                _ => {
                    return Err(DriverError::Invalid(format!(
                        "x and y share {} (daisy chain) and need two different addresses",
                        self.x.port.display()
                    )))
                }
            }
        }
        Ok(())
    }

    pub(crate) fn line_options(&self) -> LineOptions {
        LineOptions {
            reconnect_min: Duration::from_millis(self.reconnect_min_ms.max(1)),
            reconnect_max: Duration::from_millis(self.reconnect_max_ms.max(self.reconnect_min_ms)),
            stop_on_reopen: true,
        }
    }
}

/// An XY stage: two brought-up axes.
#[derive(Debug, Clone)]
pub struct Stage {
    /// The X axis.
    pub x: Axis,
    /// The Y axis.
    pub y: Axis,
    events: broadcast::Sender<AxisEvent>,
}

impl Stage {
    /// Opens the line(s) and brings both axes up (see [`Axis::bring_up`]).
    /// Events go to `events` (create one with `broadcast::channel` and
    /// subscribe before calling, to see the bring-up too).
    pub async fn connect(
        cfg: &DriverConfig,
        events: broadcast::Sender<AxisEvent>,
    ) -> Result<Stage, DriverError> {
        Self::connect_via(cfg, events, None).await
    }

    /// Like [`Stage::connect`], but with `opener` (when given) opening the
    /// configured ports instead of serial devices: the simulator's
    /// in-process rig. Everything above the byte stream is the same code.
    pub async fn connect_via(
        cfg: &DriverConfig,
        events: broadcast::Sender<AxisEvent>,
        opener: Option<&Arc<dyn LinkOpener>>,
    ) -> Result<Stage, DriverError> {
        cfg.validate()?;
        let opts = cfg.line_options();
        let open = |a: &AxisConfig| {
            let events = events.clone();
            let opener = opener.cloned();
            let (port, serial) = (a.port.clone(), a.serial());
            async move {
                match opener {
                    Some(o) => Line::open(OpenerConnector::new(o, port), opts, events).await,
                    None => Line::open(SerialConnector::new(port, serial), opts, events).await,
                }
            }
        };
        let x_line = open(&cfg.x).await?;
        let y_line = if cfg.y.port == cfg.x.port {
            x_line.clone()
        } else {
            open(&cfg.y).await?
        };
        let x = bring_up_axis(x_line, &cfg.x, "x", &events).await?;
        let y = bring_up_axis(y_line, &cfg.y, "y", &events).await?;
        Ok(Stage { x, y, events })
    }

    /// Two brought-up axes as a stage (tests build them on one line).
    #[cfg(test)]
    pub(crate) fn from_axes(x: Axis, y: Axis, events: broadcast::Sender<AxisEvent>) -> Stage {
        Stage { x, y, events }
    }

    /// A new receiver of the stage's events.
    pub fn subscribe(&self) -> broadcast::Receiver<AxisEvent> {
        self.events.subscribe()
    }

    /// Starts an absolute move of both axes (µm, controller coordinates),
    /// all or nothing: both targets inside the travel and both axes
    /// referenced (asked of the controllers) before anything is sent; if
    /// one controller still refuses its `MOV`, the other axis, which may
    /// have started, is halted, and the refusal is returned. Why: an XY
    /// target reached in one axis only is a different point, and a tool
    /// sent there can hit what the full move would have avoided.
    pub async fn move_abs_both_um(&self, x_um: f64, y_um: f64) -> Result<(), DriverError> {
        self.x.check_target_um(x_um)?;
        self.y.check_target_um(y_um)?;
        let (rx, ry) = tokio::join!(self.x.is_referenced(), self.y.is_referenced());
        for (axis, referenced) in [(&self.x, rx), (&self.y, ry)] {
            if !referenced? {
                return Err(DriverError::NotReferenced {
                    axis: axis.name().to_owned(),
                });
            }
        }
        let (mx, my) = tokio::join!(self.x.move_abs_um(x_um), self.y.move_abs_um(y_um));
        let (refused, other) = match (mx, my) {
            (Ok(()), Ok(())) => return Ok(()),
            (Err(e), Ok(())) => (e, &self.y),
            (Ok(()), Err(e)) => (e, &self.x),
            (Err(e), Err(_)) => return Err(e),
        };
        if let Err(h) = other.halt().await {
            tracing::error!(
                axis = other.name(),
                "halting after the other axis refused its move: {h}"
            );
        }
        Err(DriverError::OtherAxisHalted {
            refused: Box::new(refused),
            halted: other.name().to_owned(),
        })
    }
}

/// Brings up one axis on an open line.
pub async fn bring_up_axis(
    line: Line,
    cfg: &AxisConfig,
    name: &str,
    events: &broadcast::Sender<AxisEvent>,
) -> Result<Axis, DriverError> {
    let ctl = Controller::new(
        line,
        cfg.address()?,
        Duration::from_millis(cfg.timeout_ms),
        events.clone(),
    );
    Axis::bring_up(ctl, cfg.params(name)?, events.clone()).await
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn config_from_toml_and_validation() {
        let cfg: DriverConfig = toml::from_str(
            r#"
            [x]
            port = "/dev/ttyUSB0"
            [y]
            port = "/dev/ttyUSB0"
            address = 2
            framing = "8N1"
            "#,
        )
        .unwrap();
        assert_eq!(cfg.y.baud, 115_200);
        // Shared port without two addresses is refused.
        assert!(matches!(cfg.validate(), Err(DriverError::Invalid(m)) if m.contains("addresses")));
        let mut ok = cfg.clone();
        ok.x.address = Some(1);
        ok.validate().unwrap();
        let mut bad = ok.clone();
        bad.y.address = Some(17);
        assert!(bad.validate().is_err());
        let mut bad = ok.clone();
        bad.y.baud = 9600;
        assert!(bad.validate().is_err());
        assert!(toml::from_str::<DriverConfig>("[x]\nbogus = 1\n").is_err());
        assert!(toml::from_str::<DriverConfig>("[x]\nframing = \"9Q1\"\n").is_err());
        assert!(DriverConfig::default().validate().is_err());
    }
}

#[cfg(test)]
mod example_config {
    use super::*;

    /// The shipped example must stay loadable.
    #[test]
    fn example_config_parses() {
        let text = include_str!("../../config/driver.example.toml");
        let table: toml::Table = toml::from_str(text).unwrap();
        let cfg: DriverConfig = table["driver"].clone().try_into().unwrap();
        assert_eq!(cfg.x.port, PathBuf::from("/dev/ttyUSB0"));
        assert_eq!(cfg.y.timeout_ms, 1000);
        cfg.validate().unwrap();
    }
}
