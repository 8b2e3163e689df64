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
use micropos::daemon::protocol::{JobProgress, JobState};
use serde_json::Value;
use std::fmt::Write;

/// The other replies the view draws on, when the daemon gave them.
#[derive(Debug, Default)]
pub(super) struct Extra {
    /// `position`.
    pub position: Option<Value>,
    /// `tables list`.
    pub tables: Option<Value>,
    /// `config`.
    pub config: Option<Value>,
}

/// `x` and `y` of an object as numbers.
fn xy(v: &Value) -> Option<(f64, f64)> {
    Some((v["x"].as_f64()?, v["y"].as_f64()?))
}

/// Seconds, for a rig time stamp (to 1 ms).
fn t(v: &Value) -> String {
    v.as_f64().map_or("?".to_owned(), |t| format!("{t:.3} s"))
}

/// The axes that are not referenced: `["x", "y"]`.
fn unreferenced(rig: &Value) -> Vec<&'static str> {
    ["x", "y"]
        .into_iter()
        .filter(|a| rig["referenced"][*a] != true)
        .collect()
}

/// The whole view.
pub(super) fn text(s: &Value, extra: &Extra) -> String {
    let mut out = String::new();
    safety(s, &mut out);
    axes(s, extra.position.as_ref(), &mut out);
    vision(s, extra.position.as_ref(), &mut out);
    compensation(s, extra, &mut out);
    job(&s["job"], &mut out);
    details(s, &mut out);
    out
}

/// Fault state and whether motion is allowed, and why not.
fn safety(s: &Value, out: &mut String) {
    let rig = &s["rig"];
    let connected = rig["connected"]["x"] == true && rig["connected"]["y"] == true;
    let latched = &rig["fault_latched"];
    if latched.is_object() {
        let _ = writeln!(
            out,
            "safety: FAULT LATCHED at t {}: {}",
            t(&latched["t_s"]),
            latched["reason"].as_str().unwrap_or("?")
        );
        let _ = writeln!(
            out,
            "  motion refused until its cause is found and `micropos reset` acknowledges it"
        );
    } else {
        let allowed = match rig["activity"].as_str() {
            _ if !connected => {
                "motion refused: the controllers are not connected (see axes)".to_owned()
            }
            Some("job") => {
                let kind = s["job"]["kind"].as_str().unwrap_or("characterize");
                format!(
                    "a {kind} job moves the axes: client moves refused until it ends (`micropos {kind} cancel` ends it)"
                )
            }
            Some("referencing") => {
                "a reference run moves the axes: moves refused until it ends".to_owned()
            }
            activity => {
                let missing = unreferenced(rig);
                let moving = if activity == Some("moving") {
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
    let faults = rig["faults"].as_u64().unwrap_or(0);
    let last = &rig["last_fault"];
    if faults > 0 && !latched.is_object() && last.is_object() {
        let _ = writeln!(
            out,
            "  {faults} fault{} since start, the last at t {} (reset): {}",
            if faults == 1 { "" } else { "s" },
            t(&last["t_s"]),
            last["reason"].as_str().unwrap_or("?")
        );
    } else if faults > 1 {
        let _ = writeln!(out, "  {faults} faults since start");
    }
}

/// Per axis: connected (or why not), referenced, position; the activity
/// and the travel.
fn axes(s: &Value, position: Option<&Value>, out: &mut String) {
    let rig = &s["rig"];
    let _ = writeln!(
        out,
        "axes: {}",
        match rig["activity"].as_str() {
            Some("idle") => "idle",
            Some("moving") => "moving (a client move)",
            Some("referencing") => "referencing",
            Some("job") => "moving for a job",
            _ => "?",
        }
    );
    for a in ["x", "y"] {
        let mut parts = Vec::new();
        if rig["connected"][a] != true {
            let why = rig["not_connected"][a]
                .as_str()
                .unwrap_or("no reason given");
            parts.push(format!("not connected: {why}"));
        } else {
            parts.push("connected".to_owned());
        }
        if rig["referenced"][a] == true {
            parts.push("referenced".to_owned());
        } else {
            parts.push("NOT referenced".to_owned());
        }
        if let Some(p) = position {
            let c = &p["controller"];
            match c[format!("{a}_um")].as_f64() {
                Some(v) => parts.push(format!("at {} (controller)", um(v))),
                None if rig["connected"][a] == true => parts.push("position unknown".to_owned()),
                None => {}
            }
            if let Some(v) = p["commanded"][format!("{a}_um")].as_f64() {
                parts.push(format!("commanded {}", um(v)));
            }
        }
        let _ = writeln!(out, "  {a}: {}", parts.join(", "));
    }
    if let (Some(x), Some(y)) = (
        s["limits"]["x_um"].as_array(),
        s["limits"]["y_um"].as_array(),
    ) {
        let range = |r: &Vec<Value>| match (
            r.first().and_then(Value::as_f64),
            r.get(1).and_then(Value::as_f64),
        ) {
            (Some(lo), Some(hi)) => format!("{lo:.3} .. {hi:.3} µm"),
            _ => "?".to_owned(),
        };
        let _ = writeln!(
            out,
            "  allowed range (soft limits ∩ travel): x {}, y {}",
            range(x),
            range(y)
        );
    }
}

/// Tied or not and what being untied switches off, the vision position,
/// the deviation check.
fn vision(s: &Value, position: Option<&Value>, out: &mut String) {
    if s["camera"].is_null() {
        let _ = writeln!(out, "vision: no camera configured (camera.source)");
        return;
    }
    let tie = &s["vision_tie"];
    if tie["tied"] == true && tie["in_force"] != false {
        let mut how = Vec::new();
        if let Some(a) = tie["after"].as_str() {
            how.push(format!("after {a}"));
        }
        if let Some(u) = tie["taken_utc"].as_str() {
            how.push(format!("taken {u}"));
        }
        if let Some(r) = tie["restored"].as_str().filter(|r| *r != "no") {
            how.push(format!("restored {r}"));
        }
        if let Some((x, y)) = xy(&tie["rms_error_um"]) {
            how.push(format!("fit rms x {}, y {}", rms_um(x), rms_um(y)));
        }
        let _ = writeln!(out, "vision: tied to the stage ({})", how.join("; "));
    } else {
        let _ = writeln!(
            out,
            "vision: NOT tied to the stage: {}",
            tie["why"].as_str().unwrap_or("no reason given")
        );
        if let Some(off) = tie["switched_off"].as_str() {
            let _ = writeln!(out, "  switched off: {off}");
        }
    }
    if let Some(v) = position.map(|p| &p["vision"]).filter(|v| v.is_object()) {
        let age = v["age_s"].as_f64().map_or(String::new(), |a| {
            format!(", {} s old", crate::fmt::sig(a, 2))
        });
        match (v["stage_x_um"].as_f64(), v["stage_y_um"].as_f64()) {
            (Some(x), Some(y)) => {
                let _ = writeln!(
                    out,
                    "  position: x {}, y {} (stage frame{age})",
                    um(x),
                    um(y)
                );
            }
            _ => {
                if let (Some(x), Some(y)) = (v["x_um"].as_f64(), v["y_um"].as_f64()) {
                    let _ = writeln!(
                        out,
                        "  position: x {}, y {} (pattern coordinates, not stage{age})",
                        um(x),
                        um(y)
                    );
                }
            }
        }
    }
    let d = &s["deviation"];
    if d.is_object() {
        let armed = if d["armed"] == true {
            "armed"
        } else {
            "not armed"
        };
        let mut line = format!(
            "  deviation check: {armed}: {}",
            d["state"].as_str().unwrap_or("?")
        );
        if let Some((x, y)) = xy(&d["last_um"]) {
            let _ = write!(line, "; last x {}, y {}", um(x), um(y));
        }
        let _ = writeln!(out, "{line}");
    }
}

/// The active table and its kind, the approach and outside-table policy,
/// live drift.
fn compensation(s: &Value, extra: &Extra, out: &mut String) {
    match &extra.tables {
        Some(t) => match t["active"].as_str() {
            Some(name) => {
                let kind = t["loaded"]
                    .as_array()
                    .and_then(|l| l.iter().find(|e| e["name"] == name))
                    .and_then(|e| e["kind"].as_str())
                    .unwrap_or("?");
                let loaded = t["loaded"].as_array().map_or(0, Vec::len);
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
    let d = &s["drift"];
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

/// The job's one line: `job: characterize c.csv: done, 80/80 points`.
pub(super) fn job(j: &Value, out: &mut String) {
    let _ = writeln!(out, "job: {}", job_line(j));
}

/// `characterize c.csv: running, 5/80 points, ETA 30 s` (or `none`; a job
/// object this client cannot read, a newer daemon's state, as `unreadable`).
pub(super) fn job_line(j: &Value) -> String {
    if !j.is_object() {
        return "none".to_owned();
    }
    let Some(p) = JobProgress::from_json(j) else {
        return format!("unreadable ({j})");
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
    if let Some(e) = p.error.filter(|e| !e.is_empty()) {
        let _ = write!(s, ": {e}");
    }
    s
}

/// The counters, for who looks closer.
fn details(s: &Value, out: &mut String) {
    let _ = writeln!(out, "details:");
    let c = &s["camera"];
    if c.is_object() {
        let n = |k: &str| c[k].as_u64().unwrap_or(0);
        let _ = writeln!(
            out,
            "  camera: {} frames, {} decoded, {} failed to decode, {} dropped (the decoder was busy; a newer frame took their place), {} camera errors{}",
            n("frames"),
            n("decoded"),
            n("failed"),
            n("dropped"),
            n("camera_errors"),
            c["last_error"]
                .as_str()
                .map_or(String::new(), |e| format!(" (last: {e})"))
        );
        let l = &c["latest"];
        if l.is_object() {
            if let Some(q) = l["quality"].as_f64() {
                let _ = writeln!(out, "  decode quality: {}", margin_short(q));
            }
            if let (Some(x), Some(y)) = (l["x_um"].as_f64(), l["y_um"].as_f64()) {
                let _ = writeln!(
                    out,
                    "  latest decode: pattern x {}, y {}, θ {:.6} rad, frame at t {}",
                    um(x),
                    um(y),
                    l["theta_rad"].as_f64().unwrap_or(f64::NAN),
                    t(&l["frame_t_s"])
                );
            }
        }
        if let Some(r) = c["camera_clock"]["rate_ppm"].as_f64() {
            let _ = writeln!(
                out,
                "  camera clock: {r:.1} ppm against the rig clock, {} restarts",
                c["camera_clock"]["resets"].as_u64().unwrap_or(0)
            );
        }
    }
    let _ = writeln!(out, "  rig time: {}", t(&s["t_s"]));
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    fn status(latched: bool, referenced: bool) -> Value {
        let fault = json!({"t_s": 2146.868066595, "reason": "/dev/y: no answer"});
        json!({"ok": true, "t_s": 2291.989211655,
            "camera": {"camera_errors": 1, "decoded": 1297, "dropped": 74, "failed": 0,
                       "frames": 1372, "last_error": null,
                       "latest": {"frame_t_s": 2287.425264875, "quality": 784.8261022435961,
                                  "sequence": 1372, "t_s": 2287.425264875,
                                  "theta_rad": 0.005241216334754882,
                                  "x_um": 4528.956800949039, "y_um": 5042.137353581423}},
            "deviation": {"armed": true, "bound_um": 100.0, "last_um": {"x": -2.068593962115301, "y": 1.9797587091225068},
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
                           "rms_error_um": {"x": 4.6007803683465065, "y": 0.19937879175275167}}})
    }

    fn extra() -> Extra {
        Extra {
            position: Some(json!({"commanded": {"x_um": null, "y_um": null},
                "controller": {"x_um": 7500.0, "y_um": 7100.000000000001},
                "vision": {"age_s": 4.61482822500011, "stage_x_um": 7498.025602046547,
                           "stage_y_um": 7101.978995896246}})),
            tables: Some(json!({"active": "c100-paper.toml",
                "loaded": [{"name": "c100-model.toml", "kind": "model"},
                           {"name": "c100-paper.toml", "kind": "lookup"}]})),
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

    fn text_of(s: &Value) -> String {
        text(s, &Extra::default())
    }
}
