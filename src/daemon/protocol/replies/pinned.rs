//! The typed replies write the bytes the `json!` builders they replaced
//! wrote. Each test keeps the old builder, copied from the daemon as it
//! was, as the oracle, fed the same values (floats that print awkwardly,
//! a non-finite one, `None` and `Some`), and compares the reply lines.
//!
//! Why the old builders and not only literal strings: they are what the
//! daemon sent; a literal pins one case, the builder every branch.

use serde::Serialize;
use serde_json::{json, Value};

use super::*;
use crate::comp::file::CompKind;

/// What `reply` writes for a typed reply.
fn bytes<T: Serialize>(t: &T) -> String {
    crate::daemon::protocol::reply(&json!(1), Ok(to_value(t)))
}

/// What `reply` wrote for the old builder's value.
fn old(v: Value) -> String {
    crate::daemon::protocol::reply(&json!(1), Ok(v))
}

const AWKWARD: f64 = 0.1 + 0.2;

fn fault() -> TimedReason {
    TimedReason {
        t_s: 2146.868066595,
        reason: "/dev/y: no answer".to_owned(),
    }
}

fn rig(latched: bool, why: Option<[Option<String>; 2]>) -> RigStatus {
    RigStatus {
        mode: "idle".to_owned(),
        activity: "idle".to_owned(),
        connected: PerAxis::of([true, false]),
        referenced: PerAxis::of([true, true]),
        faults: 3,
        last_fault: Some(fault()),
        fault_latched: latched.then(fault),
        not_connected: why.map(PerAxis::of),
    }
}

/// The old `SafetyState::to_json`.
fn old_rig(latched: bool, why: Option<[Option<String>; 2]>) -> Value {
    let f = fault();
    let mut v = json!({
        "mode": "idle",
        "activity": "idle",
        "connected": {"x": true, "y": false},
        "referenced": {"x": true, "y": true},
        "faults": 3_u64,
        "last_fault": Some(&f).map(|f| json!({"t_s": f.t_s, "reason": f.reason})),
        "fault_latched": latched.then_some(&f).map(|f| json!({"t_s": f.t_s, "reason": f.reason})),
    });
    if let Some(why) = why {
        v["not_connected"] = json!({"x": why[0], "y": why[1]});
    }
    v
}

#[test]
fn rig_state() {
    for latched in [false, true] {
        for why in [
            None,
            Some([None, Some("no serial device at /dev/y".to_owned())]),
        ] {
            assert_eq!(
                bytes(&rig(latched, why.clone())),
                old(old_rig(latched, why))
            );
        }
    }
    assert_eq!(
        to_value(&rig(false, None)).to_string(),
        r#"{"activity":"idle","connected":{"x":true,"y":false},"fault_latched":null,"faults":3,"last_fault":{"reason":"/dev/y: no answer","t_s":2146.868066595},"mode":"idle","referenced":{"x":true,"y":true}}"#
    );
}

fn measurement() -> VisionMeasurement {
    VisionMeasurement {
        t_s: 2287.425264875,
        frame_t_s: AWKWARD,
        sequence: 1372,
        x_um: 7500.0,
        y_um: -0.0,
        theta_rad: 0.005241216334754882,
        quality: f64::NAN,
    }
}

/// The old `Measurement::to_json`.
fn old_measurement(m: &VisionMeasurement) -> Value {
    json!({"t_s": m.t_s, "frame_t_s": m.frame_t_s, "sequence": m.sequence, "x_um": m.x_um, "y_um": m.y_um,
           "theta_rad": m.theta_rad, "quality": m.quality})
}

fn camera(clock: bool) -> CameraStatus {
    CameraStatus {
        frames: 1372,
        decoded: 1297,
        failed: 0,
        camera_errors: 1,
        dropped: 74,
        last_error: Some("timeout".to_owned()),
        latest: Some(measurement()),
        camera_clock: clock.then_some(CameraClock {
            rate_ppm: 12.5,
            resets: 2,
        }),
    }
}

/// The old `Vision::to_json`.
fn old_camera(clock: bool) -> Value {
    let mut v = json!({
        "frames": 1372_u64, "decoded": 1297_u64, "failed": 0_u64, "camera_errors": 1_u64,
        "dropped": 74_u64, "last_error": Some("timeout"),
        "latest": Some(measurement()).map(|m| old_measurement(&m)),
    });
    if clock {
        v["camera_clock"] = json!({"rate_ppm": 12.5, "resets": 2_u64});
    }
    v
}

#[test]
fn camera_status() {
    for clock in [false, true] {
        assert_eq!(bytes(&camera(clock)), old(old_camera(clock)));
    }
}

fn deviation(last: bool) -> DeviationStatus {
    DeviationStatus {
        armed: true,
        state: "checking: vision − controller within ±5 µm per axis (stage frame)".to_owned(),
        bound_um: 5.0,
        frame: Some("table t.toml".to_owned()),
        frame_known: true,
        tied: false,
        last_um: last.then_some(PerAxis::of([AWKWARD, -1e-7])),
    }
}

fn old_deviation(last: bool) -> Value {
    let last_um = last.then_some([AWKWARD, -1e-7]);
    json!({
        "armed": true,
        "state": "checking: vision − controller within ±5 µm per axis (stage frame)",
        "bound_um": 5.0,
        "frame": Some("table t.toml"),
        "frame_known": true,
        "tied": false,
        "last_um": last_um.map(|d| json!({"x": d[0], "y": d[1]})),
    })
}

#[test]
fn deviation_status() {
    for last in [false, true] {
        assert_eq!(bytes(&deviation(last)), old(old_deviation(last)));
    }
}

fn tie_tied() -> VisionTieStatus {
    VisionTieStatus {
        tied: true,
        after: Some("reference".to_owned()),
        taken_utc: Some("2026-11-29T08:27:16Z".to_owned()),
        restored: Some("no".to_owned()),
        rotation_rad: Some(AWKWARD),
        mirrored: Some(false),
        translation_um: Some(PerAxis::of([10_000.0, 14_000.0])),
        anchor_um: Some(PerAxis::of([7500.0, 7100.000000000001])),
        squareness_urad: Some(-12.5),
        scale_ppm: Some(PerAxis::of([1.0, -3.25])),
        rms_error_um: Some(PerAxis::of([4.6007803683465065, 0.19937879175275167])),
        ..VisionTieStatus::default()
    }
}

/// The old `VisionTie::to_json` for a tie, with `Rig::tie_json`'s
/// additions.
fn old_tie_tied(in_force: Option<&str>) -> Value {
    let mut j = json!({
        "tied": true,
        "after": "reference",
        "taken_utc": "2026-11-29T08:27:16Z",
        "restored": "no",
        "rotation_rad": AWKWARD,
        "mirrored": false,
        "translation_um": {"x": 10_000.0, "y": 14_000.0},
        "anchor_um": {"x": 7500.0, "y": 7100.000000000001},
        "squareness_urad": -12.5,
        "scale_ppm": {"x": 1.0, "y": -3.25},
        "rms_error_um": {"x": 4.6007803683465065, "y": 0.19937879175275167},
    });
    match in_force {
        Some(f) => j["frame_in_force"] = json!(f),
        None => {
            j["in_force"] = json!(false);
            j["why"] = json!("axis y lost its reference");
            j["switched_off"] = json!("vision positions are pattern coordinates");
        }
    }
    j
}

#[test]
fn vision_tie() {
    let mut t = tie_tied();
    t.frame_in_force = Some("table t.toml".to_owned());
    assert_eq!(bytes(&t), old(old_tie_tied(Some("table t.toml"))));
    let mut t = tie_tied();
    t.in_force = Some(false);
    t.why = Some("axis y lost its reference".to_owned());
    t.switched_off = Some("vision positions are pattern coordinates".to_owned());
    assert_eq!(bytes(&t), old(old_tie_tied(None)));
    let untied = VisionTieStatus {
        tied: false,
        why: Some("no tie yet".to_owned()),
        switched_off: Some("vision positions are pattern coordinates".to_owned()),
        ..VisionTieStatus::default()
    };
    assert_eq!(
        bytes(&untied),
        old(json!({"tied": false, "why": "no tie yet",
                   "switched_off": "vision positions are pattern coordinates"}))
    );
    let no_camera = VisionTieStatus {
        tied: false,
        why: Some("no camera is configured (camera.source)".to_owned()),
        ..VisionTieStatus::default()
    };
    assert_eq!(
        bytes(&no_camera),
        old(json!({"tied": false, "why": "no camera is configured (camera.source)"}))
    );
}

#[test]
fn status() {
    let drift = json!({"method": "off", "references": 0});
    let job = JobProgress {
        kind: JobKind::Characterize,
        log: "c.csv".to_owned(),
        state: JobState::Running,
        done: 5,
        total: 80,
        eta_s: Some(AWKWARD),
        error: None,
        retries: 2,
        result: Value::Null,
    };
    for (limits, cam, with_job) in [(true, true, true), (false, false, false)] {
        let s = StatusReply {
            t_s: 2291.989211655,
            rig: rig(false, None),
            limits: limits.then_some(Limits {
                x_um: [0.0, 15000.0],
                y_um: [-0.5, AWKWARD],
            }),
            camera: cam.then(|| camera(true)),
            drift: drift.clone(),
            deviation: deviation(true),
            vision_tie: tie_tied(),
            job: with_job.then(|| JobObject::from(job.clone())),
            tools: None,
        };
        // The old `Rig::status`, with `job` set by `Daemon::execute`.
        let travel = limits.then(|| json!({"x_um": [0.0, 15000.0], "y_um": [-0.5, AWKWARD]}));
        let mut v = json!({
            "t_s": 2291.989211655,
            "rig": old_rig(false, None),
            "limits": travel,
            "camera": cam.then(|| old_camera(true)),
            "drift": drift,
            "deviation": old_deviation(true),
            "vision_tie": to_value(&tie_tied()),
        });
        v["job"] = if with_job { job.to_json() } else { Value::Null };
        assert_eq!(bytes(&s), old(v));
    }
}

#[test]
fn reset() {
    for cleared in [None, Some(fault())] {
        let r = ResetReply {
            cleared: cleared.clone(),
            rig: rig(false, None),
        };
        let c = cleared.map(|f| json!({"t_s": f.t_s, "reason": f.reason}));
        assert_eq!(
            bytes(&r),
            old(json!({"cleared": c, "rig": old_rig(false, None)}))
        );
    }
}

fn vision_position(tied: bool, age: bool) -> VisionPosition {
    VisionPosition {
        measurement: measurement(),
        stage_x_um: tied.then_some(7498.025602046547),
        stage_y_um: tied.then_some(AWKWARD),
        frame: tied.then(|| "table t.toml".to_owned()),
        untied: (!tied).then(|| "vision is not tied to the stage: why; off".to_owned()),
        age_s: age.then_some(4.61482822500011),
    }
}

/// The old `Rig::vision_json` (and `age_s` as `position` added it).
fn old_vision_position(tied: bool, age: bool) -> Value {
    let mut j = old_measurement(&measurement());
    if tied {
        j["stage_x_um"] = json!(7498.025602046547);
        j["stage_y_um"] = json!(AWKWARD);
        j["frame"] = json!("table t.toml");
    } else {
        j["untied"] = json!(format!(
            "vision is not tied to the stage: {}; {}",
            "why", "off"
        ));
    }
    if age {
        j["age_s"] = json!(4.61482822500011);
    }
    j
}

#[test]
fn position() {
    let x: Result<f64, String> = Ok(7500.0);
    let y: Result<f64, String> = Err("axis y: timeout".to_owned());
    let err = |r: &Result<f64, String>| r.as_ref().err().cloned();
    let live = ControllerPosition {
        t_s: 12.5,
        x_um: x.as_ref().ok().copied(),
        y_um: y.as_ref().ok().copied(),
        errors: Some(ReadErrors {
            x_error: err(&x),
            y_error: err(&y),
        }),
    };
    let old_live = json!({"t_s": 12.5, "x_um": x.as_ref().ok(), "y_um": y.as_ref().ok(),
                          "x_error": err(&x), "y_error": err(&y)});
    let polled = ControllerPosition {
        t_s: 3.0,
        x_um: Some(AWKWARD),
        y_um: None,
        errors: None,
    };
    let old_polled = json!({"t_s": 3.0, "x_um": Some(AWKWARD), "y_um": None::<f64>});
    for (c, oc) in [
        (Some(live), old_live),
        (Some(polled), old_polled),
        (None, json!(null)),
    ] {
        for tied in [false, true] {
            let p = PositionReply {
                commanded: PairUm::of([Some(100.0), None]),
                controller: c.clone(),
                vision: Some(vision_position(tied, true)),
            };
            let v = json!({
                "commanded": {"x_um": Some(100.0), "y_um": None::<f64>},
                "controller": oc,
                "vision": Some(old_vision_position(tied, true)),
            });
            assert_eq!(bytes(&p), old(v));
        }
    }
}

#[test]
fn moves() {
    // Raw, without and with wait.
    let targets = [Some(AWKWARD), None];
    let mut m = MoveReply::commanded(targets);
    let mut v = json!({"commanded": {"x_um": targets[0], "y_um": targets[1]}});
    assert_eq!(bytes(&m), old(v.clone()));
    m.reported = Some(PairUm::of([Some(0.30000000000000004), None]));
    m.on_target = Some(true);
    v["reported"] = json!({"x_um": Some(0.30000000000000004), "y_um": None::<f64>});
    v["on_target"] = json!(true);
    assert_eq!(bytes(&m), old(v));
    // Planned, with every optional part and without.
    let outside = OutsideTable {
        policy: "warn".to_owned(),
        area: Limits {
            x_um: [0.0, 1000.0],
            y_um: [0.0, 500.0],
        },
        margin_um: 10.0,
        outside_by_um: [1490.0, 0.0],
        warning: Some("target outside".to_owned()),
    };
    let cl = ClosedLoopOutcome {
        residual_um: PairUm::of([0.01, -0.02]),
        corrections: 2,
        measured: LoopMeasurement {
            x_um: 99.99,
            y_um: 200.02,
            t_s: 17.25,
            quality: 700.5,
        },
        commanded: PairUm::of([100.5, 199.5]),
    };
    let drift = json!({"correction_um": [0.1, 0.2], "method": "static", "failures": 0});
    for full in [false, true] {
        let m = MoveReply {
            mode: Some("closed_loop".to_owned()),
            compensator: Some("lookup".to_owned()),
            target: Some(PairUm::of([100.0, 200.0])),
            waypoints: Some(2),
            predicted_offset_um: Some([AWKWARD, -1.5]),
            on_target: Some(true),
            drift: full.then(|| drift.clone()),
            outside_table: full.then(|| outside.clone()),
            closed_loop: full.then(|| cl.clone()),
            ..MoveReply::commanded([Some(100.5), Some(199.5)])
        };
        // The old `Rig::planned_move`.
        let mut v = json!({
            "mode": "closed_loop",
            "compensator": "lookup",
            "target": {"x_um": 100.0, "y_um": 200.0},
            "commanded": {"x_um": 100.5, "y_um": 199.5},
            "waypoints": 2_usize,
            "predicted_offset_um": [AWKWARD, -1.5],
            "on_target": true,
        });
        if full {
            v["drift"] = drift.clone();
            // The old `comp::check_area`.
            let mut o = json!({"policy": "warn", "area": {"x_um": [0.0, 1000.0], "y_um": [0.0, 500.0]},
                               "margin_um": 10.0, "outside_by_um": [1490.0, 0.0]});
            o["warning"] = json!("target outside");
            v["outside_table"] = o;
            // The old `closed_loop::run_loop`.
            v["closed_loop"] = json!({
                "residual_um": {"x_um": 0.01, "y_um": -0.02},
                "corrections": 2_u32,
                "measured": {"x_um": 99.99, "y_um": 200.02, "t_s": 17.25, "quality": 700.5},
                "commanded": {"x_um": 100.5, "y_um": 199.5},
            });
        }
        assert_eq!(bytes(&m), old(v));
    }
}

#[test]
fn stop_reference_halt() {
    assert_eq!(
        bytes(&StopReply { stopped: true }),
        old(json!({"stopped": true}))
    );
    assert_eq!(
        bytes(&StopReply { stopped: true }),
        "{\"id\":1,\"ok\":true,\"stopped\":true}\n"
    );
    let tie = json!({"tied": false, "why": "camera.tie_after_reference = false"});
    let r = ReferenceReply {
        reported: PairUm::of([Some(0.0), None]),
        vision_tie: tie.clone(),
    };
    let mut v = json!({"reported": {"x_um": Some(0.0), "y_um": None::<f64>}});
    v["vision_tie"] = tie;
    assert_eq!(bytes(&r), old(v));
    // The old `Rig::wait_at_rest` (both forms) and `halt_and_wait`'s reason.
    let not_connected = HaltReport {
        at_rest: false,
        moving: None,
        wait_s: 0.0,
        errors: vec!["not connected".to_owned()],
        reason: None,
    };
    assert_eq!(
        bytes(&not_connected),
        old(json!({"at_rest": false, "wait_s": 0.0, "errors": ["not connected"]}))
    );
    let waited = HaltReport {
        at_rest: true,
        moving: Some(PerAxis::of([false, false])),
        wait_s: AWKWARD,
        errors: vec![],
        reason: Some("job cancelled".to_owned()),
    };
    let errors: Vec<String> = vec![];
    let mut v = json!({"at_rest": true, "moving": {"x": false, "y": false},
                       "wait_s": AWKWARD, "errors": errors});
    v["reason"] = json!("job cancelled");
    assert_eq!(bytes(&waited), old(v.clone()));
    let job = JobProgress {
        kind: JobKind::Validate,
        log: "v.csv".to_owned(),
        state: JobState::Cancelled,
        done: 3,
        total: 84,
        eta_s: None,
        error: Some("a client cancelled it".to_owned()),
        retries: 0,
        result: Value::Null,
    };
    let c = JobCancelReply {
        job: Some(job.clone().into()),
        halt: waited,
    };
    assert_eq!(bytes(&c), old(json!({"job": job.to_json(), "halt": v})));
}

#[test]
fn version_tables_subscribe() {
    let commands = ["status", "position", "move"];
    let v = VersionReply {
        daemon: "0.1.0".to_owned(),
        protocol: 1,
        commands: commands.iter().map(|&c| c.to_owned()).collect(),
    };
    assert_eq!(
        bytes(&v),
        old(json!({"daemon": "0.1.0", "protocol": 1_u32, "commands": commands}))
    );
    let list = TablesListReply {
        files: vec!["a.toml".to_owned(), "b.toml".to_owned()],
        loaded: vec![LoadedTable {
            name: "a.toml".to_owned(),
            kind: CompKind::Lookup,
            created: "2026-11-29T08:27:16Z".to_owned(),
            records: 80,
            has_frame: true,
        }],
        active: None,
    };
    let loaded = vec![
        json!({"name": "a.toml", "kind": CompKind::Lookup, "created": "2026-11-29T08:27:16Z",
                       "records": 80_u64, "has_frame": true}),
    ];
    let active: Option<String> = None;
    assert_eq!(
        bytes(&list),
        old(json!({"files": ["a.toml", "b.toml"], "loaded": loaded, "active": active}))
    );
    let load = TableLoadReply {
        loaded: "m.toml".to_owned(),
        kind: CompKind::Model,
        records: 12,
    };
    assert_eq!(
        bytes(&load),
        old(json!({"loaded": "m.toml", "kind": CompKind::Model, "records": 12_u64}))
    );
    let none = TableActivateReply {
        active: None,
        kind: None,
    };
    assert_eq!(bytes(&none), old(json!({"active": null})));
    let some = TableActivateReply {
        active: Some("g.toml".to_owned()),
        kind: Some(CompKind::Grid),
    };
    assert_eq!(
        bytes(&some),
        old(json!({"active": "g.toml", "kind": CompKind::Grid}))
    );
    let names = vec!["position", "job"];
    let s = SubscribeReply {
        subscribed: names.iter().map(|&n| n.to_owned()).collect(),
    };
    assert_eq!(bytes(&s), old(json!({"subscribed": names})));
}

#[test]
fn jobs() {
    let p = JobProgress {
        kind: JobKind::Characterize,
        log: "c.csv".to_owned(),
        state: JobState::Done,
        done: 80,
        total: 80,
        eta_s: None,
        error: None,
        retries: 1,
        result: json!({"camera_delay_s": AWKWARD}),
    };
    assert_eq!(bytes(&JobReply::job(None)), old(json!({"job": null})));
    let started = JobReply::job(Some(p.clone().into()));
    assert_eq!(bytes(&started), old(json!({"job": p.to_json()})));
    // `validate start`: origin, warnings only when there are some.
    for warnings in [vec![], vec!["pose A outside".to_owned()]] {
        let mut r = JobReply::job(Some(p.clone().into()));
        r.origin = Some(PairUm::of([7500.0, AWKWARD]));
        r.warnings = (!warnings.is_empty()).then(|| warnings.clone());
        let mut v = json!({"job": p.to_json()});
        v["origin"] = json!({"x_um": 7500.0, "y_um": AWKWARD});
        if !warnings.is_empty() {
            v["warnings"] = json!(warnings);
        }
        assert_eq!(bytes(&r), old(v));
    }
    let results = json!({"results": {"square": {"raw": {"ap_um": 22.0}}}, "logs": ["v.csv"]});
    for (job, validation) in [(None, Value::Null), (Some(p.clone()), results)] {
        let s = ValidationStatusReply {
            job: job.clone().map(JobObject::from),
            validation: validation.clone(),
        };
        let j = job.map_or(Value::Null, |p| p.to_json());
        assert_eq!(bytes(&s), old(json!({"job": j, "validation": validation})));
    }
    let drift = json!({"method": "static"});
    for measured in [None, Some(json!({"t_s": 1.0}))] {
        let d = DriftReply {
            drift: drift.clone(),
            measured: measured.clone(),
        };
        let mut v = json!({});
        if let Some(m) = measured {
            v["measured"] = m;
        }
        v["drift"] = drift.clone();
        assert_eq!(bytes(&d), old(v));
    }
}

/// What `Rig::push` writes for a typed event.
fn event<E: Event>(e: &E) -> String {
    crate::daemon::protocol::event_line(E::NAME, reply_fields(to_value(e)))
}

fn old_event(name: &str, v: Value) -> String {
    crate::daemon::protocol::event_line(name, reply_fields(v))
}

use crate::daemon::protocol::reply_fields;

#[test]
fn events() {
    let t = AWKWARD;
    let f = FaultEvent {
        t_s: t,
        reason: "x: error 1".to_owned(),
        latched: Some(true),
    };
    assert_eq!(
        event(&f),
        old_event(
            "fault",
            json!({"t_s": t, "reason": "x: error 1", "latched": true})
        )
    );
    let f = FaultEvent { latched: None, ..f };
    assert_eq!(
        event(&f),
        old_event("fault", json!({"t_s": t, "reason": "x: error 1"}))
    );
    let s = StoppedEvent(TimedReason {
        t_s: t,
        reason: "stop requested by a client".to_owned(),
    });
    assert_eq!(
        event(&s),
        old_event(
            "stopped",
            json!({"t_s": t, "reason": "stop requested by a client"})
        )
    );
    let c = ClearedEvent {
        t_s: t,
        cleared: fault(),
    };
    let fc = fault();
    assert_eq!(
        event(&c),
        old_event(
            "reset",
            json!({"t_s": t, "cleared": json!({"t_s": fc.t_s, "reason": fc.reason})})
        )
    );
    let st = StateEvent {
        t_s: t,
        state: rig(true, None),
    };
    assert_eq!(
        event(&st),
        old_event("state", json!({"t_s": t, "state": old_rig(true, None)}))
    );
    let l = LinkUpEvent {
        line: "/dev/ttyUSB0".to_owned(),
    };
    assert_eq!(
        event(&l),
        old_event("link_up", json!({"line": "/dev/ttyUSB0"}))
    );
    let g = GarbledEvent {
        t_s: t,
        source: "x".to_owned(),
        error: "bad".to_owned(),
    };
    assert_eq!(
        event(&g),
        old_event("garbled", json!({"t_s": t, "source": "x", "error": "bad"}))
    );
    let cam = CameraEvent {
        t_s: t,
        state: "stalled".to_owned(),
        reason: "no frame".to_owned(),
    };
    assert_eq!(
        event(&cam),
        old_event(
            "camera",
            json!({"t_s": t, "state": "stalled", "reason": "no frame"})
        )
    );
    for tied in [false, true] {
        let p = PositionEvent::Vision(vision_position(tied, false));
        let mut v = old_vision_position(tied, false);
        v["source"] = json!("vision");
        assert_eq!(event(&p), old_event("position", v));
    }
    let (x, y) = (Some(AWKWARD), None::<f64>);
    let p = PositionEvent::Controller(PolledPosition {
        t_s: t,
        x_um: x,
        y_um: y,
    });
    assert_eq!(
        event(&p),
        old_event(
            "position",
            json!({"source": "controller", "t_s": t, "x_um": x, "y_um": y})
        )
    );
    let h = HaltedEvent {
        t_s: t,
        reason: "job cancelled".to_owned(),
        at_rest: true,
        wait_s: 0.25,
    };
    assert_eq!(
        event(&h),
        old_event(
            "halted",
            json!({"t_s": t, "reason": "job cancelled", "at_rest": true, "wait_s": 0.25})
        )
    );
    let read = AxisRecoveredEvent {
        t_s: t,
        axis: "y".to_owned(),
        halted: true,
        read_back: Some(AxisReadBack {
            referenced: true,
            servo_on: true,
            on_target: false,
            position_um: Some(AWKWARD),
            target_um: None,
        }),
        error: None,
    };
    assert_eq!(
        event(&read),
        old_event(
            "axis_recovered",
            json!({"t_s": t, "axis": "y", "halted": true,
                "referenced": true, "servo_on": true, "on_target": false,
                "position_um": Some(AWKWARD), "target_um": None::<f64>})
        )
    );
    let failed = AxisRecoveredEvent {
        halted: false,
        read_back: None,
        error: Some("timeout".to_owned()),
        ..read
    };
    assert_eq!(
        event(&failed),
        old_event(
            "axis_recovered",
            json!({"t_s": t, "axis": "y", "halted": false, "error": Some("timeout")})
        )
    );
    let p = JobProgress {
        kind: JobKind::Validate,
        log: "v.csv".to_owned(),
        state: JobState::Running,
        done: 1,
        total: 84,
        eta_s: Some(AWKWARD),
        error: None,
        retries: 0,
        result: Value::Null,
    };
    assert_eq!(
        event(&JobEvent::of(p.clone())),
        old_event("job", p.to_json())
    );
    let mut ended = JobEvent::of(p.clone());
    ended.results = Some(json!({"square": {}}));
    ended.logs = Some(json!(["v.csv"]));
    let mut v = p.to_json();
    v["results"] = json!({"square": {}});
    v["logs"] = json!(["v.csv"]);
    assert_eq!(event(&ended), old_event("job", v));
    assert_eq!(
        LaggedEvent { missed: 7 }.line(),
        old_event("lagged", json!({"missed": 7_u64}))
    );
    assert_eq!(
        LaggedEvent { missed: 7 }.line(),
        "{\"event\":\"lagged\",\"missed\":7}\n"
    );
}

/// With tools configured `status` carries them; without, the key is
/// absent (the bytes above).
#[test]
fn status_tools_are_reported_when_configured() {
    let t = ToolsStatus {
        active: Some("tip".into()),
        offsets_um: [("tip".to_owned(), [0.0, 20000.0])].into_iter().collect(),
    };
    assert_eq!(
        to_value(&t),
        json!({"active": "tip", "offsets_um": {"tip": [0.0, 20000.0]}})
    );
    let back: ToolsStatus = serde_json::from_value(to_value(&t)).unwrap();
    assert_eq!(back, t);
}

/// A tool move's part of the `move` reply, as `Rig::planned_move` writes
/// it; absent from other moves (the bytes above).
#[test]
fn move_tool_part_is_pinned() {
    let t = ToolMove {
        name: "tip".into(),
        offset_um: [0.0, 20000.0],
        tool_target_um: [1000.0, 22000.0],
        yaw_urad: -12.5,
        yaw_source: "table".into(),
        closed_on: None,
    };
    assert_eq!(
        to_value(&t),
        json!({"name": "tip", "offset_um": [0.0, 20000.0], "tool_target_um": [1000.0, 22000.0],
               "yaw_urad": -12.5, "yaw_source": "table"})
    );
    let back: ToolMove = serde_json::from_value(to_value(&t)).unwrap();
    assert_eq!(back, t);
}
