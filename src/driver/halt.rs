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

async fn halt_one(ctl: Controller, name: &'static str, wait: Duration, poll: Duration) -> AxisHalt {
    let mut out = AxisHalt {
        axis: name,
        sent: false,
        at_rest: false,
        error: None,
        problem: None,
    };
    if let Err(e) = ctl.control(ControlChar::StopAll).await {
        out.problem = Some(format!("#24: {e}"));
        return out;
    }
    out.sent = true;
    out.error = ctl.error().await.ok();
    let t0 = tokio::time::Instant::now();
    loop {
        match ctl.control(ControlChar::MotionStatus).await {
            Ok((Some(a), _)) => match answer::hex_word(&a) {
                Ok(w) if w & 1 == 0 => {
                    out.at_rest = true;
                    return out;
                }
                Ok(_) => {}
                Err(e) => out.problem = Some(format!("#5: {e}")),
            },
            Ok((None, _)) => out.problem = Some("#5 returned no answer".to_owned()),
            Err(e) => out.problem = Some(format!("#5: {e}")),
        }
        if t0.elapsed() >= wait {
            out.problem
                .get_or_insert_with(|| format!("still moving after {wait:?}"));
            return out;
        }
        tokio::time::sleep(poll).await;
    }
}

/// Stops both axes of `cfg` with `#24` and waits up to `wait` for them to
/// report rest (`#5`). `opener` opens the ports instead of serial devices
/// (the simulator's in-process rig). Both axes are handled at once; a line
/// that cannot be opened is reported, the other axis is still stopped.
pub async fn halt_all(
    cfg: &DriverConfig,
    opener: Option<&Arc<dyn LinkOpener>>,
    wait: Duration,
) -> Vec<AxisHalt> {
    let (events, _) = broadcast::channel(64);
    let poll = Duration::from_millis(cfg.x.poll_interval_ms.max(5));
    let x_line = open_line(&cfg.x, cfg, opener, &events).await;
    let y_line = if cfg.y.port == cfg.x.port {
        match &x_line {
            Ok(l) => Ok(l.clone()),
            Err(e) => Err(DriverError::Invalid(e.to_string())),
        }
    } else {
        open_line(&cfg.y, cfg, opener, &events).await
    };
    let one = |line: Result<Line, DriverError>, a: &AxisConfig, name: &'static str| {
        let addr = a.address();
        let timeout = Duration::from_millis(a.timeout_ms);
        let events = events.clone();
        async move {
            let fail = |p: String| AxisHalt {
                axis: name,
                sent: false,
                at_rest: false,
                error: None,
                problem: Some(p),
            };
            let line = match line {
                Ok(l) => l,
                Err(e) => return fail(format!("opening the line: {e}")),
            };
            let addr = match addr {
                Ok(a) => a,
                Err(e) => return fail(e.to_string()),
            };
            halt_one(
                Controller::new(line, addr, timeout, events),
                name,
                wait,
                poll,
            )
            .await
        }
    };
    let (x, y) = tokio::join!(one(x_line, &cfg.x, "x"), one(y_line, &cfg.y, "y"));
    vec![x, y]
}
