//! `micropos status` for a person: what matters first — is a fault latched,
//! may the stage move — then the axes, vision, compensation, the job, and
//! last the counters (issue 33: the reply printed as an alphabetical dump,
//! `dropped: 30` and `quality 784.8` before the fault state).
//!
//! Besides the `status` reply it shows the positions (`position`), the
//! active table (`tables list`) and the compensation settings (`config`),
//! each asked for on the same connection; one the daemon refuses (a client
//! with the `read` role may not read `config`) is left out, not an error.
//! `--json` prints the `status` reply alone, as before.

use crate::fmt::{margin_short, rms_um, um};
use micropos::daemon::protocol::{
    JobObject, JobState, PerAxis, PositionReply, RigStatus, StatusReply, TablesListReply,
};
use serde_json::Value;
use std::fmt::Write;

/// The other replies the view draws on, when the daemon gave them.
#[derive(Debug, Default)]
pub(super) struct Extra {
    /// `position`.
    pub position: Option<PositionReply>,
    /// `tables list`.
    pub tables: Option<TablesListReply>,
    /// `config` (the daemon's `DaemonConfig` as JSON).
    pub config: Option<Value>,
}

/// Seconds, for a rig time stamp (to 1 ms).
fn t(t: f64) -> String {
    format!("{t:.3} s")
}

/// An axis' value by its name.
fn axis<T: Copy>(p: &PerAxis<T>, a: &str) -> T {
    if a == "x" {
        p.x
    } else {
        p.y
    }
}

/// The axes that are not referenced: `["x", "y"]`.
fn unreferenced(rig: &RigStatus) -> Vec<&'static str> {
    ["x", "y"]
        .into_iter()
        .filter(|a| !axis(&rig.referenced, a))
        .collect()
}

/// The whole view.
pub(super) fn text(s: &StatusReply, extra: &Extra) -> String {
    let mut out = String::new();
    safety(s, &mut out);
    axes(s, extra.position.as_ref(), &mut out);
    vision(s, extra.position.as_ref(), &mut out);
    compensation(s, extra, &mut out);
    job(s.job.as_ref(), &mut out);
    details(s, &mut out);
    out
}

/// Fault state and whether motion is allowed, and why not.
fn safety(s: &StatusReply, out: &mut String) {
    let rig = &s.rig;
    let connected = rig.connected.x && rig.connected.y;
    if let Some(latched) = &rig.fault_latched {
        let _ = writeln!(
            out,
            "safety: FAULT LATCHED at t {}: {}",
            t(latched.t_s),
            latched.reason
        );
        let _ = writeln!(
            out,
            "  motion refused until its cause is found and `micropos reset` acknowledges it"
        );
    } else {
        let allowed = match rig.activity.as_str() {
            _ if !connected => {
                "motion refused: the controllers are not connected (see axes)".to_owned()
            }
            "job" => {
                let kind = s
                    .job
                    .as_ref()
                    .and_then(JobObject::known)
                    .map_or("characterize", |j| j.kind.as_str());
                format!(
                    "a {kind} job moves the axes: client moves refused until it ends (`micropos {kind} cancel` ends it)"
                )
            }
            "referencing" => {
                "a reference run moves the axes: moves refused until it ends".to_owned()
            }
            activity => {
                let missing = unreferenced(rig);
                let moving = if activity == "moving" {
                    " (a client move is under way)"
                } else {
                    ""
                };
                if missing.is_empty() {
                    format!("motion allowed{moving}")
                } else {
                    format!(
                        "moves of {} refused until referenced (`micropos reference`){moving}",
                        missing.join(" and ")
                    )
                }
            }
        };
        let _ = writeln!(out, "safety: no fault latched; {allowed}");
    }
    let faults = rig.faults;
    match &rig.last_fault {
        Some(last) if faults > 0 && rig.fault_latched.is_none() => {
            let _ = writeln!(
                out,
                "  {faults} fault{} since start, the last at t {} (reset): {}",
                if faults == 1 { "" } else { "s" },
                t(last.t_s),
                last.reason
            );
        }
        _ if faults > 1 => {
            let _ = writeln!(out, "  {faults} faults since start");
        }
        _ => {}
    }
}

/// Per axis: connected (or why not), referenced, position; the activity
/// and the travel.
fn axes(s: &StatusReply, position: Option<&PositionReply>, out: &mut String) {
    let rig = &s.rig;
    let _ = writeln!(
        out,
        "axes: {}",
        match rig.activity.as_str() {
            "idle" => "idle",
            "moving" => "moving (a client move)",
            "referencing" => "referencing",
            "job" => "moving for a job",
            _ => "?",
        }
    );
    for a in ["x", "y"] {
        let mut parts = Vec::new();
        let connected = axis(&rig.connected, a);
        if !connected {
            let why = rig
                .not_connected
                .as_ref()
                .and_then(|n| {
                    if a == "x" {
                        n.x.as_deref()
                    } else {
                        n.y.as_deref()
                    }
                })
                .unwrap_or("no reason given");
            parts.push(format!("not connected: {why}"));
        } else {
            parts.push("connected".to_owned());
        }
        if axis(&rig.referenced, a) {
            parts.push("referenced".to_owned());
        } else {
            parts.push("NOT referenced".to_owned());
        }
        if let Some(p) = position {
            let of = |xy: (Option<f64>, Option<f64>)| if a == "x" { xy.0 } else { xy.1 };
            let c = p.controller.as_ref().map(|c| (c.x_um, c.y_um));
            match c.and_then(of) {
                Some(v) => parts.push(format!("at {} (controller)", um(v))),
                None if connected => parts.push("position unknown".to_owned()),
                None => {}
            }
            if let Some(v) = of((p.commanded.x_um, p.commanded.y_um)) {
                parts.push(format!("commanded {}", um(v)));
            }
        }
        let _ = writeln!(out, "  {a}: {}", parts.join(", "));
    }
    if let Some(l) = &s.limits {
        let range = |[lo, hi]: [f64; 2]| format!("{lo:.3} .. {hi:.3} µm");
        let _ = writeln!(
            out,
            "  allowed range (soft limits ∩ travel): x {}, y {}",
            range(l.x_um),
            range(l.y_um)
        );
    }
}

/// Tied or not and what being untied switches off, the vision position,
/// the deviation check.
fn vision(s: &StatusReply, position: Option<&PositionReply>, out: &mut String) {
    if s.camera.is_none() {
        let _ = writeln!(out, "vision: no camera configured (camera.source)");
        return;
    }
    let tie = &s.vision_tie;
    if tie.tied && tie.in_force != Some(false) {
        let mut how = Vec::new();
        if let Some(a) = &tie.after {
            how.push(format!("after {a}"));
        }
        if let Some(u) = &tie.taken_utc {
            how.push(format!("taken {u}"));
        }
        if let Some(r) = tie.restored.as_ref().filter(|r| *r != "no") {
            how.push(format!("restored {r}"));
        }
        if let Some(e) = &tie.rms_error_um {
            how.push(format!("fit rms x {}, y {}", rms_um(e.x), rms_um(e.y)));
        }
        let _ = writeln!(out, "vision: tied to the stage ({})", how.join("; "));
    } else {
        let _ = writeln!(
            out,
            "vision: NOT tied to the stage: {}",
            tie.why.as_deref().unwrap_or("no reason given")
        );
        if let Some(off) = &tie.switched_off {
            let _ = writeln!(out, "  switched off: {off}");
        }
    }
    if let Some(v) = position.and_then(|p| p.vision.as_ref()) {
        let age = v.age_s.map_or(String::new(), |a| {
            format!(", {} s old", crate::fmt::sig(a, 2))
        });
        match (v.stage_x_um, v.stage_y_um) {
            (Some(x), Some(y)) => {
                let _ = writeln!(
                    out,
                    "  position: x {}, y {} (stage frame{age})",
                    um(x),
                    um(y)
                );
            }
            _ => {
                let _ = writeln!(
                    out,
                    "  position: x {}, y {} (pattern coordinates, not stage{age})",
                    um(v.measurement.x_um),
                    um(v.measurement.y_um)
                );
            }
        }
    }
    let d = &s.deviation;
    let armed = if d.armed { "armed" } else { "not armed" };
    let mut line = format!("  deviation check: {armed}: {}", d.state);
    if let Some(l) = &d.last_um {
        let _ = write!(line, "; last x {}, y {}", um(l.x), um(l.y));
    }
    let _ = writeln!(out, "{line}");
}

/// The active table and its kind, the approach and outside-table policy,
/// live drift.
fn compensation(s: &StatusReply, extra: &Extra, out: &mut String) {
    match &extra.tables {
        Some(t) => match &t.active {
            Some(name) => {
                let kind = t
                    .loaded
                    .iter()
                    .find(|e| &e.name == name)
                    .map_or("?".to_owned(), |e| kind_word(e.kind));
                let loaded = t.loaded.len();
                let _ = writeln!(
                    out,
                    "compensation: active table {name} ({kind}); {loaded} loaded (`micropos tables`)"
                );
            }
            None => {
                let _ = writeln!(
                    out,
                    "compensation: no active table: compensated and closed-loop moves need one (`micropos tables activate NAME`)"
                );
            }
        },
        None => {
            let _ = writeln!(out, "compensation: (tables not readable)");
        }
    }
    // The configuration is the daemon's `DaemonConfig`, shown as sent.
    if let Some(c) = extra.config.as_ref().map(|c| &c["config"]["compensation"]) {
        let mut line = format!(
            "  approach {}, a target outside the table: {}",
            c["approach"].as_str().unwrap_or("?"),
            c["outside_table"].as_str().unwrap_or("?")
        );
        if let Some(m) = c["outside_margin_um"].as_f64() {
            let _ = write!(line, " (margin {})", um(m));
        }
        let _ = writeln!(out, "{line}");
    }
    // Live drift is `analysis::drift`'s own JSON (not a protocol type).
    let d = &s.drift;
    if d.is_object() {
        let method = d["method"].as_str().unwrap_or("?");
        let mut line = format!("  live drift correction: {method}");
        if method != "off" {
            if let Some((x, y)) = d["correction_um"]
                .as_array()
                .and_then(|c| Some((c.first()?.as_f64()?, c.get(1)?.as_f64()?)))
            {
                let _ = write!(line, ", now x {}, y {}", um(x), um(y));
            }
            let _ = write!(
                line,
                ", {} references, {} failed",
                d["references"].as_u64().unwrap_or(0),
                d["failures"].as_u64().unwrap_or(0)
            );
        }
        if let Some(e) = d["last_error"].as_str() {
            let _ = write!(line, " (last error: {e})");
        }
        let _ = writeln!(out, "{line}");
    }
}

/// A table kind's word (`lookup`), as the daemon writes it.
fn kind_word(k: micropos::comp::file::CompKind) -> String {
    micropos::daemon::protocol::to_value(&k)
        .as_str()
        .unwrap_or("?")
        .to_owned()
}

/// The job's one line: `job: characterize c.csv: done, 80/80 points`.
pub(super) fn job(j: Option<&JobObject>, out: &mut String) {
    let _ = writeln!(out, "job: {}", job_line(j));
}

/// `characterize c.csv: running, 5/80 points, ETA 30 s` (or `none`; a job
/// object this client cannot read, a newer daemon's state, as `unreadable`).
pub(super) fn job_line(j: Option<&JobObject>) -> String {
    let p = match j {
        None => return "none".to_owned(),
        Some(JobObject::Unknown(v)) => return format!("unreadable ({v})"),
        Some(JobObject::Known(p)) => p,
    };
    let mut s = format!(
        "{} {}: {}, {}/{} points",
        p.kind, p.log, p.state, p.done, p.total
    );
    if let Some(eta) = p.eta_s.filter(|_| p.state == JobState::Running) {
        let _ = write!(s, ", ETA {eta:.0} s");
    }
    match p.retries {
        0 => {}
        1 => s.push_str(" (1 retry)"),
        n => {
            let _ = write!(s, " ({n} retries)");
        }
    }
    if let Some(e) = p.error.as_ref().filter(|e| !e.is_empty()) {
        let _ = write!(s, ": {e}");
    }
    s
}

/// The counters, for who looks closer.
fn details(s: &StatusReply, out: &mut String) {
    let _ = writeln!(out, "details:");
    if let Some(c) = &s.camera {
        let _ = writeln!(
            out,
            "  camera: {} frames, {} decoded, {} failed to decode, {} dropped (the decoder was busy; a newer frame took their place), {} camera errors{}",
            c.frames,
            c.decoded,
            c.failed,
            c.dropped,
            c.camera_errors,
            c.last_error
                .as_ref()
                .map_or(String::new(), |e| format!(" (last: {e})"))
        );
        if let Some(l) = &c.latest {
            let _ = writeln!(out, "  decode quality: {}", margin_short(l.quality));
            let _ = writeln!(
                out,
                "  latest decode: pattern x {}, y {}, θ {:.6} rad, frame at t {}",
                um(l.x_um),
                um(l.y_um),
                l.theta_rad,
                t(l.frame_t_s)
            );
        }
        if let Some(k) = &c.camera_clock {
            let _ = writeln!(
                out,
                "  camera clock: {:.1} ppm against the rig clock, {} restarts",
                k.rate_ppm, k.resets
            );
        }
    }
    let _ = writeln!(out, "  rig time: {}", t(s.t_s));
}

#[cfg(test)]
mod tests {
    use super::*;
    use micropos::daemon::protocol::from_reply;
    use serde_json::json;

    fn status(latched: bool, referenced: bool) -> StatusReply {
        let fault = json!({"t_s": 2146.868066595, "reason": "/dev/y: no answer"});
        from_reply(&json!({"ok": true, "t_s": 2291.989211655,
            "camera": {"camera_errors": 1, "decoded": 1297, "dropped": 74, "failed": 0,
                       "frames": 1372, "last_error": null,
                       "latest": {"frame_t_s": 2287.425264875, "quality": 784.8261022435961,
                                  "sequence": 1372, "t_s": 2287.425264875,
                                  "theta_rad": 0.005241216334754882,
                                  "x_um": 4528.956800949039, "y_um": 5042.137353581423}},
            "deviation": {"armed": true, "bound_um": 100.0, "frame": "table c100-paper.toml", "frame_known": true, "last_um": {"x": -2.068593962115301, "y": 1.9797587091225068},
                          "state": "checking: vision − controller within ±100 µm per axis (stage frame)", "tied": true},
            "drift": {"method": "off", "references": 0, "failures": 0, "last_error": null},
            "job": {"done": 80, "error": null, "eta_s": null, "kind": "characterize",
                    "log": "c100.csv", "result": null, "retries": 2, "state": "done", "total": 80},
            "limits": {"x_um": [0.0, 15000.0], "y_um": [0.0, 15000.0]},
            "rig": {"activity": "idle", "connected": {"x": true, "y": true},
                    "fault_latched": if latched { fault.clone() } else { Value::Null },
                    "faults": 1, "last_fault": fault, "mode": if latched { "fault" } else { "idle" },
                    "referenced": {"x": referenced, "y": true}},
            "vision_tie": {"after": "reference", "tied": true, "taken_utc": "2026-11-29T08:27:16Z",
                           "restored": "no",
                           "rms_error_um": {"x": 4.6007803683465065, "y": 0.19937879175275167}}}))
        .unwrap()
    }

    fn extra() -> Extra {
        Extra {
            position: Some(
                from_reply(&json!({"commanded": {"x_um": null, "y_um": null},
                "controller": {"t_s": 2291.9, "x_um": 7500.0, "y_um": 7100.000000000001,
                               "x_error": null, "y_error": null},
                "vision": {"age_s": 4.61482822500011, "stage_x_um": 7498.025602046547,
                           "stage_y_um": 7101.978995896246, "frame": "table c100-paper.toml",
                           "t_s": 2287.4, "frame_t_s": 2287.4, "sequence": 1372,
                           "x_um": 4528.9, "y_um": 5042.1, "theta_rad": 0.005, "quality": 784.8}}))
                .unwrap(),
            ),
            tables: Some(
                from_reply(&json!({"active": "c100-paper.toml", "files": [],
                "loaded": [{"name": "c100-model.toml", "kind": "model", "created": "2026-11-29T08:27:16Z",
                            "records": 80, "has_frame": true},
                           {"name": "c100-paper.toml", "kind": "lookup", "created": "2026-11-29T08:27:16Z",
                            "records": 80, "has_frame": true}]}))
                .unwrap(),
            ),
            config: Some(
                json!({"config": {"compensation": {"approach": "direction_aware",
                "outside_table": "refuse", "outside_margin_um": 10.0}}}),
            ),
        }
    }

    /// Issue 33: the state that matters first, grouped; counters last;
    /// numbers rounded with units.
    #[test]
    fn status_reads_safety_axes_vision_compensation_job_details_in_that_order() {
        let text = text(&status(false, true), &extra());
        let heads: Vec<&str> = text
            .lines()
            .filter(|l| !l.starts_with(' '))
            .map(|l| l.split(':').next().unwrap_or(""))
            .collect();
        assert_eq!(
            heads,
            ["safety", "axes", "vision", "compensation", "job", "details"],
            "{text}"
        );
        for want in [
            "safety: no fault latched; motion allowed\n",
            "  x: connected, referenced, at 7500.000 µm (controller)\n",
            "  y: connected, referenced, at 7100.000 µm (controller)\n",
            "vision: tied to the stage (after reference; taken 2026-11-29T08:27:16Z; fit rms x 4.60 µm, y 0.199 µm)\n",
            "  position: x 7498.026 µm, y 7101.979 µm (stage frame, 4.6 s old)\n",
            "  deviation check: armed: checking",
            "compensation: active table c100-paper.toml (lookup); 2 loaded",
            "  approach direction_aware, a target outside the table: refuse (margin 10.000 µm)\n",
            "job: characterize c100.csv: done, 80/80 points (2 retries)\n",
            "74 dropped (the decoder was busy",
            "  decode quality: 785 bits of code margin (safe;",
        ] {
            assert!(text.contains(want), "want {want:?} in\n{text}");
        }
        assert!(!text.contains("0000000"), "{text}");
    }

    #[test]
    fn a_latched_fault_and_a_missing_reference_come_first() {
        let text = text(&status(true, true), &Extra::default());
        assert!(
            text.starts_with(
                "safety: FAULT LATCHED at t 2146.868 s: /dev/y: no answer\n  motion refused until its cause is found and `micropos reset` acknowledges it\n"
            ),
            "{text}"
        );
        let text = text_of(&status(false, false));
        assert!(
            text.starts_with("safety: no fault latched; moves of x refused until referenced (`micropos reference`)\n"),
            "{text}"
        );
        assert!(text.contains("  x: connected, NOT referenced\n"), "{text}");
        assert!(
            text.contains("compensation: (tables not readable)"),
            "{text}"
        );
    }

    fn text_of(s: &StatusReply) -> String {
        text(s, &Extra::default())
    }
}
