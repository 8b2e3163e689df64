//! Every typed reply and event reads back as written: serialized as the
//! daemon sends it (one reply line), parsed as the CLI reads it, the same
//! value. Why: a field written under one name and read under another, or
//! written only sometimes and required on reading, would fail here before
//! a client meets it.
//!
//! The values are what the daemon can send: finite numbers (a non-finite
//! one is written `null`, read back as none), and never `Some(null)` in a
//! field that is left out when absent (it reads back as absent).

use proptest::prelude::*;
use serde::de::DeserializeOwned;
use serde::Serialize;
use serde_json::{json, Value};

use super::*;
use crate::comp::file::CompKind;

/// A number with at most three decimals (see `protocol::round_trip` on
/// serde_json's float parsing).
fn num() -> impl Strategy<Value = f64> {
    (-1_000_000_000_i64..=1_000_000_000).prop_map(|n| n as f64 / 1000.0)
}

fn opt_num() -> impl Strategy<Value = Option<f64>> {
    proptest::option::of(num())
}

fn text() -> impl Strategy<Value = String> {
    "[a-z0-9 ./:µ-]{0,12}"
}

fn opt_text() -> impl Strategy<Value = Option<String>> {
    proptest::option::of(text())
}

/// A JSON object as the untyped parts hold them (never `null`).
fn object() -> impl Strategy<Value = Value> {
    (text(), num()).prop_map(|(k, v)| json!({"method": k, "correction_um": [v, v]}))
}

fn per_axis<T: std::fmt::Debug + Clone, S: Strategy<Value = T>>(
    s: impl Fn() -> S,
) -> impl Strategy<Value = PerAxis<T>> {
    (s(), s()).prop_map(|(x, y)| PerAxis { x, y })
}

fn pair<T: std::fmt::Debug + Clone + Copy, S: Strategy<Value = T>>(
    s: impl Fn() -> S,
) -> impl Strategy<Value = PairUm<T>> {
    (s(), s()).prop_map(|(x_um, y_um)| PairUm { x_um, y_um })
}

fn timed() -> impl Strategy<Value = TimedReason> {
    (num(), text()).prop_map(|(t_s, reason)| TimedReason { t_s, reason })
}

fn rig() -> impl Strategy<Value = RigStatus> {
    (
        (text(), text()),
        (per_axis(any::<bool>), per_axis(any::<bool>)),
        any::<u64>(),
        (proptest::option::of(timed()), proptest::option::of(timed())),
        proptest::option::of(per_axis(opt_text)),
    )
        .prop_map(
            |((mode, activity), (connected, referenced), faults, (last, latched), nc)| RigStatus {
                mode,
                activity,
                connected,
                referenced,
                faults,
                last_fault: last,
                fault_latched: latched,
                not_connected: nc,
            },
        )
}

fn measurement() -> impl Strategy<Value = VisionMeasurement> {
    ((num(), num(), any::<u64>()), (num(), num(), num(), num())).prop_map(
        |((t_s, frame_t_s, sequence), (x_um, y_um, theta_rad, quality))| VisionMeasurement {
            t_s,
            frame_t_s,
            sequence,
            x_um,
            y_um,
            theta_rad,
            quality,
        },
    )
}

fn camera() -> impl Strategy<Value = CameraStatus> {
    (
        proptest::array::uniform5(any::<u64>()),
        opt_text(),
        proptest::option::of(measurement()),
        proptest::option::of((num(), any::<u64>())),
    )
        .prop_map(|(n, last_error, latest, clock)| CameraStatus {
            frames: n[0],
            decoded: n[1],
            failed: n[2],
            camera_errors: n[3],
            dropped: n[4],
            last_error,
            latest,
            camera_clock: clock.map(|(rate_ppm, resets)| CameraClock { rate_ppm, resets }),
        })
}

fn deviation() -> impl Strategy<Value = DeviationStatus> {
    (
        proptest::array::uniform3(any::<bool>()),
        text(),
        num(),
        opt_text(),
        proptest::option::of(per_axis(num)),
    )
        .prop_map(|(b, state, bound_um, frame, last_um)| DeviationStatus {
            armed: b[0],
            state,
            bound_um,
            frame,
            frame_known: b[1],
            tied: b[2],
            last_um,
        })
}

fn tie() -> impl Strategy<Value = VisionTieStatus> {
    (
        (
            any::<bool>(),
            opt_text(),
            opt_text(),
            proptest::option::of(any::<bool>()),
        ),
        (opt_text(), opt_text(), opt_text(), opt_text()),
        (opt_num(), proptest::option::of(any::<bool>()), opt_num()),
        proptest::array::uniform4(proptest::option::of(per_axis(num))),
    )
        .prop_map(
            |(
                (tied, why, switched_off, in_force),
                (fif, after, taken, restored),
                (rot, mir, sq),
                pa,
            )| {
                let [translation_um, anchor_um, scale_ppm, rms_error_um] = pa;
                VisionTieStatus {
                    tied,
                    why,
                    switched_off,
                    in_force,
                    frame_in_force: fif,
                    after,
                    taken_utc: taken,
                    restored,
                    rotation_rad: rot,
                    mirrored: mir,
                    translation_um,
                    anchor_um,
                    squareness_urad: sq,
                    scale_ppm,
                    rms_error_um,
                }
            },
        )
}

fn job() -> impl Strategy<Value = JobProgress> {
    (
        prop_oneof![Just(JobKind::Characterize), Just(JobKind::Validate)],
        text(),
        proptest::sample::select(JobState::ALL.to_vec()),
        (any::<u64>(), any::<u64>(), any::<u64>()),
        opt_num(),
        opt_text(),
        prop_oneof![Just(Value::Null), object()],
    )
        .prop_map(
            |(kind, log, state, (done, total, retries), eta_s, error, result)| JobProgress {
                kind,
                log,
                state,
                done,
                total,
                eta_s,
                error,
                retries,
                result,
            },
        )
}

fn status() -> impl Strategy<Value = StatusReply> {
    (
        num(),
        rig(),
        proptest::option::of((num(), num(), num(), num())),
        proptest::option::of(camera()),
        object(),
        deviation(),
        tie(),
        proptest::option::of(job()),
        proptest::option::of(("[a-z]{1,8}", num(), num())),
    )
        .prop_map(
            |(t_s, rig, l, camera, drift, deviation, vision_tie, job, tool)| StatusReply {
                t_s,
                rig,
                limits: l.map(|(a, b, c, d)| Limits {
                    x_um: [a, b],
                    y_um: [c, d],
                }),
                camera,
                drift,
                deviation,
                vision_tie,
                job: job.map(JobObject::from),
                tools: tool.map(|(n, x, y)| ToolsStatus {
                    active: Some(n.clone()),
                    offsets_um: [(n, [x, y])].into_iter().collect(),
                }),
            },
        )
}

fn vision_position() -> impl Strategy<Value = VisionPosition> {
    (
        measurement(),
        opt_num(),
        opt_num(),
        opt_text(),
        opt_text(),
        opt_num(),
    )
        .prop_map(
            |(measurement, stage_x_um, stage_y_um, frame, untied, age_s)| VisionPosition {
                measurement,
                stage_x_um,
                stage_y_um,
                frame,
                untied,
                age_s,
            },
        )
}

fn position() -> impl Strategy<Value = PositionReply> {
    (
        pair(opt_num),
        proptest::option::of((
            num(),
            opt_num(),
            opt_num(),
            proptest::option::of((opt_text(), opt_text())),
        )),
        proptest::option::of(vision_position()),
    )
        .prop_map(|(commanded, c, vision)| PositionReply {
            commanded,
            controller: c.map(|(t_s, x_um, y_um, e)| ControllerPosition {
                t_s,
                x_um,
                y_um,
                errors: e.map(|(x_error, y_error)| ReadErrors { x_error, y_error }),
            }),
            vision,
        })
}

fn outside() -> impl Strategy<Value = OutsideTable> {
    (
        text(),
        proptest::array::uniform4(num()),
        num(),
        (num(), num()),
        opt_text(),
    )
        .prop_map(|(policy, a, margin_um, (bx, by), warning)| OutsideTable {
            policy,
            area: Limits {
                x_um: [a[0], a[1]],
                y_um: [a[2], a[3]],
            },
            margin_um,
            outside_by_um: [bx, by],
            warning,
        })
}

fn closed_loop() -> impl Strategy<Value = ClosedLoopOutcome> {
    (
        pair(num),
        any::<u32>(),
        proptest::array::uniform4(num()),
        pair(num),
    )
        .prop_map(
            |(residual_um, corrections, m, commanded)| ClosedLoopOutcome {
                residual_um,
                corrections,
                measured: LoopMeasurement {
                    x_um: m[0],
                    y_um: m[1],
                    t_s: m[2],
                    quality: m[3],
                },
                commanded,
            },
        )
}

fn moved() -> impl Strategy<Value = MoveReply> {
    (
        (
            pair(opt_num),
            proptest::option::of(pair(opt_num)),
            proptest::option::of(any::<bool>()),
        ),
        (opt_text(), opt_text(), proptest::option::of(pair(num))),
        (
            proptest::option::of(any::<u64>()),
            proptest::option::of((num(), num())),
        ),
        (
            proptest::option::of(object()),
            proptest::option::of(outside()),
            proptest::option::of(closed_loop()),
        ),
    )
        .prop_map(
            |(
                (commanded, reported, on_target),
                (mode, compensator, target),
                (w, p),
                (d, o, cl),
            )| {
                MoveReply {
                    commanded,
                    reported,
                    on_target,
                    mode,
                    compensator,
                    target,
                    waypoints: w,
                    predicted_offset_um: p.map(|(x, y)| [x, y]),
                    drift: d,
                    outside_table: o,
                    closed_loop: cl,
                    tool: None,
                }
            },
        )
}

fn halt() -> impl Strategy<Value = HaltReport> {
    (
        any::<bool>(),
        proptest::option::of(per_axis(any::<bool>)),
        num(),
        proptest::collection::vec(text(), 0..3),
        opt_text(),
    )
        .prop_map(|(at_rest, moving, wait_s, errors, reason)| HaltReport {
            at_rest,
            moving,
            wait_s,
            errors,
            reason,
        })
}

fn kind() -> impl Strategy<Value = CompKind> {
    prop_oneof![
        Just(CompKind::Lookup),
        Just(CompKind::Model),
        Just(CompKind::Grid)
    ]
}

fn tables() -> impl Strategy<Value = TablesListReply> {
    (
        proptest::collection::vec(text(), 0..3),
        proptest::collection::vec((text(), kind(), text(), any::<u64>(), any::<bool>()), 0..3),
        opt_text(),
    )
        .prop_map(|(files, loaded, active)| TablesListReply {
            files,
            loaded: loaded
                .into_iter()
                .map(|(name, kind, created, records, has_frame)| LoadedTable {
                    name,
                    kind,
                    created,
                    records,
                    has_frame,
                })
                .collect(),
            active,
        })
}

fn job_reply() -> impl Strategy<Value = JobReply> {
    (
        proptest::option::of(job()),
        proptest::option::of(pair(num)),
        proptest::option::of(proptest::collection::vec(text(), 0..3)),
    )
        .prop_map(|(job, origin, warnings)| JobReply {
            job: job.map(JobObject::from),
            origin,
            warnings,
        })
}

fn job_event() -> impl Strategy<Value = JobEvent> {
    (
        job(),
        opt_text(),
        opt_text(),
        proptest::option::of(object()),
        proptest::option::of(object()),
    )
        .prop_map(|(progress, test, mode, results, logs)| JobEvent {
            progress,
            test,
            mode,
            results,
            logs,
        })
}

fn recovered() -> impl Strategy<Value = AxisRecoveredEvent> {
    (
        num(),
        text(),
        any::<bool>(),
        proptest::option::of((
            proptest::array::uniform3(any::<bool>()),
            opt_num(),
            opt_num(),
        )),
        opt_text(),
    )
        .prop_map(|(t_s, axis, halted, r, error)| AxisRecoveredEvent {
            t_s,
            axis,
            halted,
            read_back: r.map(|(b, position_um, target_um)| AxisReadBack {
                referenced: b[0],
                servo_on: b[1],
                on_target: b[2],
                position_um,
                target_um,
            }),
            error,
        })
}

fn position_event() -> impl Strategy<Value = PositionEvent> {
    prop_oneof![
        vision_position().prop_map(PositionEvent::Vision),
        (num(), opt_num(), opt_num()).prop_map(|(t_s, x_um, y_um)| PositionEvent::Controller(
            PolledPosition { t_s, x_um, y_um }
        )),
    ]
}

/// Written as a reply line, read back by the client's path.
fn back<T: Serialize + DeserializeOwned>(t: &T) -> Result<T, String> {
    let line = crate::daemon::protocol::reply(&json!("id"), Ok(to_value(t)));
    let v: Value = serde_json::from_str(&line).map_err(|e| e.to_string())?;
    from_reply(&v).map_err(|e| format!("{e} in {line}"))
}

macro_rules! round_trips {
    ($($name:ident: $strategy:expr;)*) => {
        proptest! {
            #![proptest_config(ProptestConfig::with_cases(64))]
            $(
                #[test]
                fn $name(r in $strategy) {
                    prop_assert_eq!(back(&r), Ok(r));
                }
            )*
        }
    };
}

round_trips! {
    status_reply: status();
    reset_reply: (proptest::option::of(timed()), rig())
        .prop_map(|(cleared, rig)| ResetReply { cleared, rig });
    position_reply: position();
    move_reply: moved();
    stop_reply: any::<bool>().prop_map(|stopped| StopReply { stopped });
    reference_reply: (pair(opt_num), object())
        .prop_map(|(reported, vision_tie)| ReferenceReply { reported, vision_tie });
    halt_report: halt();
    version_reply: (text(), any::<u32>(), proptest::collection::vec(text(), 0..4))
        .prop_map(|(daemon, protocol, commands)| VersionReply { daemon, protocol, commands });
    tables_list_reply: tables();
    table_load_reply: (text(), kind(), any::<u64>())
        .prop_map(|(loaded, kind, records)| TableLoadReply { loaded, kind, records });
    table_activate_reply: proptest::option::of((text(), proptest::option::of(kind())))
        .prop_map(|a| TableActivateReply {
            active: a.as_ref().map(|(n, _)| n.clone()),
            kind: a.and_then(|(_, k)| k),
        });
    job_reply_: job_reply();
    validation_status_reply: (proptest::option::of(job()), prop_oneof![Just(Value::Null), object()])
        .prop_map(|(job, validation)| ValidationStatusReply {
            job: job.map(JobObject::from),
            validation,
        });
    job_cancel_reply: (proptest::option::of(job()), halt())
        .prop_map(|(job, halt)| JobCancelReply { job: job.map(JobObject::from), halt });
    drift_reply: (object(), proptest::option::of(object()))
        .prop_map(|(drift, measured)| DriftReply { drift, measured });
    config_reply: object().prop_map(|config| ConfigReply { config });
    subscribe_reply: proptest::collection::vec(text(), 0..4)
        .prop_map(|subscribed| SubscribeReply { subscribed });
    fault_event: (num(), text(), proptest::option::of(any::<bool>()))
        .prop_map(|(t_s, reason, latched)| FaultEvent { t_s, reason, latched });
    stopped_event: timed().prop_map(StoppedEvent);
    cleared_event: (num(), timed()).prop_map(|(t_s, cleared)| ClearedEvent { t_s, cleared });
    state_event: (num(), rig()).prop_map(|(t_s, state)| StateEvent { t_s, state });
    link_up_event: text().prop_map(|line| LinkUpEvent { line });
    garbled_event: (num(), text(), text())
        .prop_map(|(t_s, source, error)| GarbledEvent { t_s, source, error });
    camera_event: (num(), text(), text())
        .prop_map(|(t_s, state, reason)| CameraEvent { t_s, state, reason });
    position_event_: position_event();
    job_event_: job_event();
    halted_event: (num(), text(), any::<bool>(), num())
        .prop_map(|(t_s, reason, at_rest, wait_s)| HaltedEvent { t_s, reason, at_rest, wait_s });
    axis_recovered_event: recovered();
    lagged_event: any::<u64>().prop_map(|missed| LaggedEvent { missed });
}

/// A reply without a field the type needs is an error naming it, never a
/// panic or a default: what the CLI reports.
#[test]
fn a_missing_field_is_named() {
    let e = from_reply::<StatusReply>(&json!({"id": 1, "ok": true, "rig": {}})).unwrap_err();
    assert!(e.to_string().contains("missing field"), "{e}");
    let e = from_reply::<MoveReply>(&json!({"ok": true})).unwrap_err();
    assert!(e.to_string().contains("`commanded`"), "{e}");
    // A newer daemon's job state: the status still reads, the job as sent.
    let j = json!({"kind": "characterize", "log": "c.csv", "state": "paused", "done": 1,
                   "total": 2, "eta_s": null, "error": null});
    let Ok(JobReply { job: Some(o), .. }) = from_reply::<JobReply>(&json!({"job": j})) else {
        panic!("a job reply with an unknown state reads");
    };
    assert!(o.known().is_none());
    assert_eq!(o.to_json(), j);
}

#[test]
fn a_number_sent_as_null_reads_as_nan_and_a_missing_one_is_still_named() {
    // What the daemon writes for a NaN quality (serde_json has no NaN).
    let m = VisionMeasurement {
        t_s: 1.0,
        frame_t_s: 0.9,
        sequence: 3,
        x_um: 10.0,
        y_um: 20.0,
        theta_rad: 0.001,
        quality: f64::NAN,
    };
    let v = serde_json::to_value(m).unwrap();
    assert_eq!(v["quality"], Value::Null);
    let back: VisionMeasurement = serde_json::from_value(v.clone()).unwrap();
    assert!(back.quality.is_nan());
    assert_eq!(back.x_um, 10.0);
    let mut lacking = v;
    lacking.as_object_mut().unwrap().remove("quality");
    let e = serde_json::from_value::<VisionMeasurement>(lacking).unwrap_err();
    assert!(e.to_string().contains("`quality`"), "{e}");
}
