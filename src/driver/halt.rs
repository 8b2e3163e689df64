//! The last-resort halt: opens the controllers' lines itself, sends `#24`
//! (stop all) to both axes, waits (bounded) until neither moves, and says
//! what it found. `microposd --halt` runs it from systemd's `ExecStopPost=`
//! so a daemon that died by SIGKILL, a crash or the watchdog does not leave
//! a move running with nobody watching.
//!
//! Why `#24` and not `HLT`: the daemon may have died in the middle of an
//! exchange, leaving half a command in the controller's input buffer; a
//! text command appended to it would be garbage, while the single byte 24
//! is acted on at once whatever precedes it. Why no bring-up (`*IDN?`,
//! `FRF?`): nothing here depends on which controller answers; a stop must
//! not wait for checks. `#24` stops abruptly (no deceleration ramp); that
//! is the price of needing no daemon.

use super::controller::Controller;
use super::error::DriverError;
use super::line::Line;
use super::stage::{AxisConfig, DriverConfig};
use super::transport::{LinkOpener, OpenerConnector, SerialConnector};
use super::AxisEvent;
use crate::gcs::{answer, ControlChar, GcsErrorCode};
use std::sync::Arc;
use std::time::Duration;
use tokio::sync::broadcast;
use tokio::time::Instant;

/// What the halt found on one axis.
#[derive(Debug, Clone, PartialEq)]
pub struct AxisHalt {
    /// `"x"` or `"y"`.
    pub axis: &'static str,
    /// Whether `#24` was written to the line.
    pub sent: bool,
    /// Whether `#5` reported the axis at rest before the bound.
    pub at_rest: bool,
    /// `ERR?` after the stop (10 = stopped by the command).
    pub error: Option<GcsErrorCode>,
    /// What went wrong, if anything.
    pub problem: Option<String>,
}

impl AxisHalt {
    /// Nothing sent yet, nothing known.
    fn new(axis: &'static str) -> Self {
        AxisHalt {
            axis,
            sent: false,
            at_rest: false,
            error: None,
            problem: None,
        }
    }

    /// Nothing could be sent, for `problem`.
    fn failed(axis: &'static str, problem: String) -> Self {
        AxisHalt {
            problem: Some(problem),
            ..AxisHalt::new(axis)
        }
    }

    /// Sent and at rest.
    pub fn ok(&self) -> bool {
        self.sent && self.at_rest
    }
}

async fn open_line(
    a: &AxisConfig,
    cfg: &DriverConfig,
    opener: Option<&Arc<dyn LinkOpener>>,
    events: &broadcast::Sender<AxisEvent>,
) -> Result<Line, DriverError> {
    let opts = cfg.line_options();
    match opener {
        Some(o) => {
            Line::open(
                OpenerConnector::new(o.clone(), a.port.clone()),
                opts,
                events.clone(),
            )
            .await
        }
        None => {
            Line::open(
                SerialConnector::new(a.port.clone(), a.serial()),
                opts,
                events.clone(),
            )
            .await
        }
    }
}

/// How long an axis may still report motion after a `#24` before the stop
/// is written again (a stop lost in a garbled or reopened line).
const RESTOP_AFTER: Duration = Duration::from_millis(200);

/// How often a line that cannot be opened is tried again.
const REOPEN_EVERY: Duration = Duration::from_millis(50);

/// Opens the line, trying again until `deadline`: a port can be briefly
/// unavailable (the dead daemon's descriptor not yet released, a USB
/// adapter re-enumerating), and the stop tool must not give up on the
/// first refusal.
async fn open_line_until(
    a: &AxisConfig,
    cfg: &DriverConfig,
    opener: Option<&Arc<dyn LinkOpener>>,
    events: &broadcast::Sender<AxisEvent>,
    deadline: Instant,
) -> Result<Line, DriverError> {
    loop {
        match open_line(a, cfg, opener, events).await {
            Ok(l) => return Ok(l),
            Err(e) if Instant::now() + REOPEN_EVERY >= deadline => return Err(e),
            Err(e) => {
                tracing::warn!(port = %a.port.display(), "halt: opening the line: {e}; trying again");
                tokio::time::sleep(REOPEN_EVERY).await;
            }
        }
    }
}

/// `#24`, then `#5` until the axis reports rest, until `deadline`. A `#24`
/// that could not be written is written again at the next poll; one after
/// which the axis still moves [`RESTOP_AFTER`] later is written again too.
/// Why retries: this is the last line of defence, run when the daemon died,
/// possibly on a loaded machine where one answer can time out.
async fn halt_one(
    ctl: Controller,
    name: &'static str,
    deadline: Instant,
    poll: Duration,
) -> AxisHalt {
    let mut out = AxisHalt::new(name);
    let mut last_stop: Option<Instant> = None;
    loop {
        let now = Instant::now();
        if last_stop.is_none_or(|t| now.duration_since(t) >= RESTOP_AFTER) {
            match ctl.control(ControlChar::StopAll).await {
                Ok(_) => {
                    if !out.sent {
                        out.sent = true;
                        out.error = ctl.error().await.ok();
                    }
                    last_stop = Some(Instant::now());
                }
                Err(e) => out.problem = Some(format!("#24: {e}")),
            }
        }
        if out.sent {
            match ctl.control(ControlChar::MotionStatus).await {
                Ok((Some(a), _)) => match answer::hex_word(&a) {
                    Ok(w) if w & 1 == 0 => {
                        out.at_rest = true;
                        out.problem = None;
                        return out;
                    }
                    Ok(_) => {}
                    Err(e) => out.problem = Some(format!("#5: {e}")),
                },
                Ok((None, _)) => out.problem = Some("#5 returned no answer".to_owned()),
                Err(e) => out.problem = Some(format!("#5: {e}")),
            }
        }
        if Instant::now() >= deadline {
            out.problem
                .get_or_insert_with(|| "still moving at the deadline".to_owned());
            return out;
        }
        tokio::time::sleep(poll).await;
    }
}

/// Stops both axes of `cfg` with `#24` and waits up to `wait` for them to
/// report rest (`#5`). `opener` opens the ports instead of serial devices
/// (the simulator's in-process rig). Both axes are handled at once; a line
/// that cannot be opened is tried again until `wait` has passed, and the
/// other axis is stopped meanwhile. `wait` bounds the whole run.
pub async fn halt_all(
    cfg: &DriverConfig,
    opener: Option<&Arc<dyn LinkOpener>>,
    wait: Duration,
) -> Vec<AxisHalt> {
    let (events, _) = broadcast::channel(64);
    let deadline = Instant::now() + wait;
    let poll = Duration::from_millis(cfg.x.poll_interval_ms.clamp(5, 100));
    let shared = cfg.y.port == cfg.x.port;
    let one = |a: &AxisConfig, name: &'static str, line: Option<Line>| {
        let a = a.clone();
        let events = events.clone();
        async move {
            let addr = match a.address() {
                Ok(addr) => addr,
                Err(e) => return AxisHalt::failed(name, e.to_string()),
            };
            let line = match line {
                Some(l) => l,
                None => match open_line_until(&a, cfg, opener, &events, deadline).await {
                    Ok(l) => l,
                    Err(e) => return AxisHalt::failed(name, format!("opening the line: {e}")),
                },
            };
            let timeout = Duration::from_millis(a.timeout_ms);
            let ctl = Controller::new(line, addr, timeout, events);
            halt_one(ctl, name, deadline, poll).await
        }
    };
    if shared {
        // One line for both controllers: opened once, both stops at once.
        let line = match open_line_until(&cfg.x, cfg, opener, &events, deadline).await {
            Ok(l) => l,
            Err(e) => {
                return ["x", "y"]
                    .map(|axis| AxisHalt::failed(axis, format!("opening the line: {e}")))
                    .to_vec()
            }
        };
        let (x, y) = tokio::join!(
            one(&cfg.x, "x", Some(line.clone())),
            one(&cfg.y, "y", Some(line))
        );
        return vec![x, y];
    }
    let (x, y) = tokio::join!(one(&cfg.x, "x", None), one(&cfg.y, "y", None));
    vec![x, y]
}
