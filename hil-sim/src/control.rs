//! The JSON-lines control socket: fault injection and ground truth for a
//! simulator running in another process (the `hil-sim serve` binary).
//!
//! One request per line, one reply line per request:
//! - `{"axis":"x","fault":"drop_line"}`, `"restore_line"`, `"power_cycle"`,
//!   `"stall"` (the carriage jams mid-move), `"motion_error"` (servo fault:
//!   error 1024, servo off)
//! - `{"axis":"x","fault":"slip","um":-250}`: the carriage slips by a whole
//!   number of µm against the encoder (the controller does not notice)
//! - `{"axis":"x","fault":"garbage","hex":"ff00"}`
//! - `{"axis":"x","fault":"delay_replies","ms":300}`
//! - `{"axis":"x","fault":"withhold_replies","on":true}`
//! - `{"query":"truth"}` → `{"ok":true,"sim_time_s":..,"x_mm":..,"y_mm":..,
//!   "true_x_um":..,"true_y_um":..,"observed_x_um":..,"observed_y_um":..}`
//!   (`observed_*` = pattern point under the image centre, pattern frame,
//!   as the camera decodes it; `observed_stage_*_um` = the same in the stage
//!   frame; `platform_yaw_urad` = the platform's yaw, right-handed about +z,
//!   so `true_*_um` and it are the platform pose (x, y, θ); `tool_*_um` =
//!   the rig file's `[tool]` point, when it names one; see `crate::rig`)
//! - `{"clock":"now"}` → `{"ok":true,"t_s":..}`;
//!   `{"clock":"advance","s":0.25}` → `{"ok":true,"t_s":..}` (time after)
//! - `{"camera":"stall"|"garbage"|"normal"}`: camera faults
//!
//! Without `"axis"`, a controller fault applies to both controllers and a
//! line fault to every line once. Replies are `{"ok":true}` or
//! `{"ok":false,"error":"<what and why>"}`; a bad request never closes the
//! connection.

use crate::fault::{AxisName, Corruption, Fault, SimError};
use crate::linesock::{LineHandler, LineServer};
use serde_json::{json, Value};
use std::path::Path;
use std::sync::Arc;
use std::time::Duration;

/// Longest request line accepted (a garbage payload of 16 KiB in hex).
const MAX_REQUEST: usize = 64 * 1024;

/// What the control socket acts on (the simulator core).
pub trait Injector: Send + Sync {
    /// Injects a fault on an axis.
    fn inject(&self, axis: AxisName, fault: Fault) -> Result<(), SimError>;
    /// Ground truth of an axis (mm).
    fn true_position_mm(&self, axis: AxisName) -> f64;
    /// Simulated time now.
    fn sim_time(&self) -> Duration;
    /// One axis per distinct serial line.
    fn line_axes(&self) -> Vec<AxisName>;
    /// The rig's ground truth now (stage model and camera view), if a rig
    /// is simulated.
    fn rig_truth(&self) -> Option<crate::rig::RigTruth> {
        None
    }
    /// Advances simulated time by `d`.
    fn advance(&self, d: Duration) -> Result<(), SimError>;
    /// Sets the camera's fault mode.
    fn camera_mode(&self, mode: crate::camera::CameraMode) -> Result<(), SimError>;
}

/// A parsed control request.
#[derive(Debug, Clone, PartialEq)]
pub enum ControlRequest {
    /// Inject `fault` on these axes.
    Fault {
        /// The axis, or `None` for all.
        axis: Option<AxisName>,
        /// The fault.
        fault: Fault,
    },
    /// Report ground truth.
    Truth,
    /// Report simulated time.
    ClockNow,
    /// Advance simulated time.
    ClockAdvance(Duration),
    /// Set the camera's fault mode.
    Camera(crate::camera::CameraMode),
}

fn decode_hex(s: &str) -> Result<Vec<u8>, String> {
    let s = s.trim();
    if s.len() % 2 != 0 {
        return Err(format!(
            "hex string has an odd number of digits ({})",
            s.len()
        ));
    }
    (0..s.len())
        .step_by(2)
        .map(|i| {
            s.get(i..i + 2)
                .and_then(|h| u8::from_str_radix(h, 16).ok())
                .ok_or_else(|| format!("{:?} is not a hex byte", s.get(i..i + 2).unwrap_or("")))
        })
        .collect()
}

/// Parses one request line.
pub fn parse_request(line: &str) -> Result<ControlRequest, String> {
    let v: Value = serde_json::from_str(line).map_err(|e| format!("not JSON: {e}"))?;
    let obj = v.as_object().ok_or("request must be a JSON object")?;
    if let Some(c) = obj.get("clock") {
        return match c.as_str() {
            Some("now") => Ok(ControlRequest::ClockNow),
            Some("advance") => {
                let secs = obj
                    .get("s")
                    .and_then(Value::as_f64)
                    .filter(|s| s.is_finite() && (0.0..=1e7).contains(s))
                    .ok_or("clock advance needs \"s\": seconds, a number in 0..=1e7")?;
                Ok(ControlRequest::ClockAdvance(Duration::from_secs_f64(secs)))
            }
            _ => Err(format!(
                "unknown clock request {c} (known: \"now\", \"advance\")"
            )),
        };
    }
    if let Some(c) = obj.get("camera") {
        use crate::camera::CameraMode;
        return match c.as_str() {
            Some("stall") => Ok(ControlRequest::Camera(CameraMode::Stall)),
            Some("garbage") => Ok(ControlRequest::Camera(CameraMode::Garbage)),
            Some("normal") => Ok(ControlRequest::Camera(CameraMode::Normal)),
            _ => Err(format!(
                "unknown camera mode {c} (known: \"stall\", \"garbage\", \"normal\")"
            )),
        };
    }
    if let Some(q) = obj.get("query") {
        return match q.as_str() {
            Some("truth") => Ok(ControlRequest::Truth),
            _ => Err(format!("unknown query {q} (known: \"truth\")")),
        };
    }
    let axis = match obj.get("axis") {
        None | Some(Value::Null) => None,
        Some(Value::String(s)) => Some(s.parse::<AxisName>().map_err(|e| e.to_string())?),
        Some(other) => return Err(format!("axis must be \"x\" or \"y\", got {other}")),
    };
    let name = obj
        .get("fault")
        .and_then(Value::as_str)
        .ok_or("request needs \"fault\" (a string) or \"query\"")?;
    let fault = match name {
        "drop_line" => Fault::DropLine,
        "restore_line" => Fault::RestoreLine,
        "power_cycle" => Fault::PowerCycle,
        "stall" => Fault::Stall,
        "motion_error" => Fault::MotionError,
        "slip" => {
            let um = obj
                .get("um")
                .and_then(Value::as_i64)
                .and_then(|v| i32::try_from(v).ok())
                .ok_or("slip needs \"um\": an integer number of µm (either sign)")?;
            Fault::Slip { slip_um: um }
        }
        "garbage" => {
            let hex = obj
                .get("hex")
                .and_then(Value::as_str)
                .ok_or("garbage needs \"hex\": the bytes as a hex string")?;
            Fault::Garbage(decode_hex(hex)?)
        }
        "delay_replies" => {
            let ms = obj
                .get("ms")
                .and_then(Value::as_u64)
                .ok_or("delay_replies needs \"ms\": a non-negative integer")?;
            Fault::DelayReplies(Duration::from_millis(ms))
        }
        "withhold_replies" => {
            let on = obj
                .get("on")
                .and_then(Value::as_bool)
                .ok_or("withhold_replies needs \"on\": true or false")?;
            Fault::WithholdReplies(on)
        }
        "corrupt_replies" => {
            let how = match obj.get("how").and_then(Value::as_str) {
                Some("garble") => Corruption::Garble,
                Some("drop") => Corruption::Drop,
                _ => return Err("corrupt_replies needs \"how\": \"garble\" or \"drop\"".into()),
            };
            let count = obj
                .get("count")
                .and_then(Value::as_u64)
                .and_then(|c| u32::try_from(c).ok())
                .ok_or("corrupt_replies needs \"count\": a non-negative integer (≤ 2³²−1)")?;
            Fault::CorruptReplies { how, count }
        }
        other => {
            return Err(format!(
                "unknown fault {other:?} (known: drop_line, restore_line, power_cycle, stall, motion_error, slip, garbage, delay_replies, withhold_replies, corrupt_replies)"
            ))
        }
    };
    Ok(ControlRequest::Fault { axis, fault })
}

fn is_line_fault(f: &Fault) -> bool {
    matches!(f, Fault::DropLine | Fault::RestoreLine | Fault::Garbage(_))
}

/// Executes one request line and returns the reply line (without LF).
pub fn handle_line(inj: &dyn Injector, line: &str) -> String {
    let reply = match parse_request(line) {
        Err(e) => json!({"ok": false, "error": e}),
        Ok(ControlRequest::Truth) => {
            let mut v = json!({
                "ok": true,
                "sim_time_s": inj.sim_time().as_secs_f64(),
                "x_mm": inj.true_position_mm(AxisName::X),
                "y_mm": inj.true_position_mm(AxisName::Y),
            });
            if let (Some(t), Some(o)) = (inj.rig_truth(), v.as_object_mut()) {
                for (k, x) in [
                    ("sim_time_s", t.sim_time_s),
                    ("true_x_um", t.true_um[0]),
                    ("true_y_um", t.true_um[1]),
                    ("observed_x_um", t.observed_pattern_um[0]),
                    ("observed_y_um", t.observed_pattern_um[1]),
                    ("observed_stage_x_um", t.observed_stage_um[0]),
                    ("observed_stage_y_um", t.observed_stage_um[1]),
                    ("platform_yaw_urad", t.platform_yaw_urad),
                ] {
                    o.insert(k.into(), json!(x));
                }
                if let Some([x, y]) = t.tool_um {
                    o.insert("tool_x_um".into(), json!(x));
                    o.insert("tool_y_um".into(), json!(y));
                }
                o.insert("moving".into(), json!(t.moving));
            }
            v
        }
        Ok(ControlRequest::ClockNow) => json!({"ok": true, "t_s": inj.sim_time().as_secs_f64()}),
        Ok(ControlRequest::ClockAdvance(d)) => match inj.advance(d) {
            Ok(()) => json!({"ok": true, "t_s": inj.sim_time().as_secs_f64()}),
            Err(e) => json!({"ok": false, "error": e.to_string()}),
        },
        Ok(ControlRequest::Camera(m)) => match inj.camera_mode(m) {
            Ok(()) => json!({"ok": true}),
            Err(e) => json!({"ok": false, "error": e.to_string()}),
        },
        Ok(ControlRequest::Fault { axis, fault }) => {
            let axes = match axis {
                Some(a) => vec![a],
                None if is_line_fault(&fault) => inj.line_axes(),
                None => AxisName::ALL.to_vec(),
            };
            let r: Result<(), SimError> = axes
                .into_iter()
                .try_for_each(|a| inj.inject(a, fault.clone()));
            match r {
                Ok(()) => json!({"ok": true}),
                Err(e) => json!({"ok": false, "error": e.to_string()}),
            }
        }
    };
    reply.to_string()
}

/// The running control socket server.
pub struct ControlServer {
    server: LineServer,
}

impl ControlServer {
    /// Binds `path` (a stale socket file there is replaced; any other file
    /// is an error) and serves it on its own threads.
    pub fn start(path: &Path, inj: Arc<dyn Injector>) -> Result<ControlServer, SimError> {
        let server = LineServer::start(path, "control", MAX_REQUEST, Arc::new(Requests(inj)))?;
        Ok(ControlServer { server })
    }

    /// Stops the server, joins its threads and removes the socket file.
    pub fn stop(self) {
        self.server.stop();
    }
}

/// The control socket's answer to a line: one JSON reply line; an empty
/// line gets none.
struct Requests(Arc<dyn Injector>);

impl LineHandler for Requests {
    fn reply(&self, line: &str) -> Option<Vec<u8>> {
        let text = line.trim();
        (!text.is_empty()).then(|| format!("{}\n", handle_line(self.0.as_ref(), text)).into_bytes())
    }

    fn too_long(&self, limit: usize) -> Vec<u8> {
        let msg = json!({"ok": false, "error": format!("request longer than {limit} bytes")});
        format!("{msg}\n").into_bytes()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_contract_requests() {
        assert_eq!(
            parse_request(r#"{"axis":"x","fault":"drop_line"}"#),
            Ok(ControlRequest::Fault {
                axis: Some(AxisName::X),
                fault: Fault::DropLine
            })
        );
        assert_eq!(
            parse_request(r#"{"fault":"garbage","hex":"ff00"}"#),
            Ok(ControlRequest::Fault {
                axis: None,
                fault: Fault::Garbage(vec![0xff, 0])
            })
        );
        assert_eq!(
            parse_request(r#"{"axis":"y","fault":"delay_replies","ms":300}"#),
            Ok(ControlRequest::Fault {
                axis: Some(AxisName::Y),
                fault: Fault::DelayReplies(Duration::from_millis(300))
            })
        );
        assert_eq!(
            parse_request(r#"{"axis":"x","fault":"corrupt_replies","how":"drop","count":2}"#),
            Ok(ControlRequest::Fault {
                axis: Some(AxisName::X),
                fault: Fault::CorruptReplies {
                    how: Corruption::Drop,
                    count: 2
                }
            })
        );
        assert_eq!(
            parse_request(r#"{"axis":"y","fault":"withhold_replies","on":true}"#),
            Ok(ControlRequest::Fault {
                axis: Some(AxisName::Y),
                fault: Fault::WithholdReplies(true)
            })
        );
        assert_eq!(
            parse_request(r#"{"axis":"y","fault":"slip","um":-250}"#),
            Ok(ControlRequest::Fault {
                axis: Some(AxisName::Y),
                fault: Fault::Slip { slip_um: -250 }
            })
        );
        assert_eq!(
            parse_request(r#"{"query":"truth"}"#),
            Ok(ControlRequest::Truth)
        );
        assert_eq!(
            parse_request(r#"{"clock":"advance","s":0.25}"#),
            Ok(ControlRequest::ClockAdvance(Duration::from_millis(250)))
        );
        assert_eq!(
            parse_request(r#"{"clock":"now"}"#),
            Ok(ControlRequest::ClockNow)
        );
        assert_eq!(
            parse_request(r#"{"camera":"garbage"}"#),
            Ok(ControlRequest::Camera(crate::camera::CameraMode::Garbage))
        );
        for (bad, why) in [
            ("nope", "not JSON"),
            ("[1]", "object"),
            (r#"{"fault":"melt"}"#, "unknown fault"),
            (r#"{"fault":"corrupt_replies","count":1}"#, "how"),
            (r#"{"fault":"corrupt_replies","how":"garble"}"#, "count"),
            (r#"{"axis":"z","fault":"drop_line"}"#, "unknown axis"),
            (r#"{"fault":"garbage","hex":"f"}"#, "odd"),
            (r#"{"fault":"garbage","hex":"zz"}"#, "hex byte"),
            (r#"{"fault":"delay_replies","ms":-1}"#, "ms"),
            (r#"{"fault":"slip","um":0.5}"#, "um"),
            (r#"{"fault":"slip"}"#, "um"),
            (r#"{"query":"everything"}"#, "unknown query"),
            (r#"{"clock":"later"}"#, "unknown clock"),
            (r#"{"clock":"advance","s":-1}"#, "seconds"),
            (r#"{"clock":"advance"}"#, "seconds"),
            (r#"{"camera":"melt"}"#, "unknown camera"),
        ] {
            let e = parse_request(bad).unwrap_err();
            assert!(e.contains(why), "{bad}: {e}");
        }
    }
}
