//! Daemon jobs ride through transient faults (a long job must survive a
//! glitch) and still fail cleanly on permanent ones. The simulated rig on
//! ptys + camera socket + sim clock, microposd in-process, a small
//! characterization over the socket.
//!
//! Transient: garbled and lost `ONT?`/`POS?` answers
//! (`Fault::CorruptReplies`, which hits a known exchange, so the test is
//! deterministic) and a camera stall that is lifted when the daemon reports
//! its retry of the measurement. Permanent: a controller power cycle in the
//! middle of the job (reference lost, servo off).

use crate::common::{Client, DaemonRig};
use hil_sim::camera::CameraMode;
use hil_sim::{AxisName, Corruption, Fault};
use serde_json::{json, Value};
use std::time::{Duration, Instant};

async fn rig() -> DaemonRig {
    rig_with(|_| {}).await
}

/// [`rig`] with `tune` applied to the daemon's configuration last.
async fn rig_with(tune: impl FnOnce(&mut micropos::daemon::config::DaemonConfig)) -> DaemonRig {
    DaemonRig::in_process(7, 50.0, |c| {
        // No controller poll during the test: every value answer the rig sends
        // belongs to the job, so a corrupted one lands on the job.
        c.daemon.poll_interval_ms = 60_000;
        // Nor a motion supervisor's sample (`tests/it/motion_safety.rs` covers it).
        c.safety.supervise_interval_ms = 60_000;
        for a in [&mut c.driver.x, &mut c.driver.y] {
            // A lost answer costs this much (rig) time.
            a.timeout_ms = 2000;
            // A power cycle during a wait leaves the axis stopped off target:
            // the driver only notices at the motion timeout. Rig time, so a
            // long one costs no wall time; it must exceed the longest move
            // (7 mm from the reference position at ≈ 1.5 mm/s).
            a.motion_timeout_s = 30.0;
        }
        c.camera.timeout_ms = 1000;
        c.daemon.job_retries = 3;
        c.daemon.job_retry_backoff_s = 0.5;
        tune(c);
    })
    .await
}

/// Subscribes to `job` events, then starts `request` (which must be
/// accepted): the event stream and the client that started it.
async fn start(r: &DaemonRig, request: Value) -> (Client, Client) {
    let mut events = Client::connect(&r.socket).await;
    events
        .call_ok(json!({"cmd":"subscribe","topics":["job"]}))
        .await;
    let mut cl = Client::connect(&r.socket).await;
    let st = cl.call(request).await;
    assert_eq!(st["ok"], true, "{st}");
    (events, cl)
}

/// A small X characterization: tie lines, park, 2 × 3 scan points.
fn characterize(log: &str) -> Value {
    json!({"cmd": "characterize", "action": "start", "log": log, "axes": "x",
           "step_um": 200.0, "x_range_um": 400.0, "y_range_um": 400.0, "cycles": 1,
           "frames_per_point": 1, "settle_s": 0.05, "drift_every_s": 0.0})
}

/// Follows `job` events until the job leaves `running`; `on_event` sees
/// every event first. Returns the final job event and the `job_retry`
/// events.
async fn follow(events: &mut Client, mut on_event: impl FnMut(&Value)) -> (Value, Vec<Value>) {
    let mut retries = Vec::new();
    let t = Instant::now();
    loop {
        assert!(t.elapsed() < Duration::from_secs(60), "job did not end");
        let v = events.line().await;
        on_event(&v);
        match v["event"].as_str() {
            Some("job_retry") => retries.push(v),
            Some("job") if v["state"] != "running" => return (v, retries),
            _ => {}
        }
    }
}

#[tokio::test(start_paused = true)]
async fn transient_faults_are_retried_and_counted() {
    let r = rig().await;
    let mut events = Client::connect(&r.socket).await;
    events
        .call_ok(json!({"cmd":"subscribe","topics":["job"]}))
        .await;
    // The first X value answers come garbled twice, the first Y one is
    // lost: the first move of the job fails twice before it goes through.
    r.sim()
        .inject(
            AxisName::X,
            Fault::CorruptReplies {
                how: Corruption::Garble,
                count: 2,
            },
        )
        .unwrap();
    r.sim()
        .inject(
            AxisName::Y,
            Fault::CorruptReplies {
                how: Corruption::Drop,
                count: 1,
            },
        )
        .unwrap();
    let mut cl = Client::connect(&r.socket).await;
    let st = cl.call(characterize("c.csv")).await;
    assert_eq!(st["ok"], true, "{st}");
    // Once the first scan point is logged, the camera stalls; it comes back
    // when the daemon says it retries the measurement.
    let camera = r.sim().camera().clone();
    let mut stalled = false;
    let (end, retries) = follow(&mut events, |v| {
        if !stalled && v["event"] == "job" && v["done"].as_u64() == Some(1) {
            camera.set_mode(CameraMode::Stall);
            stalled = true;
        }
        if v["event"] == "job_retry" && v["operation"] == "measure" {
            camera.set_mode(CameraMode::Normal);
        }
    })
    .await;
    assert!(stalled, "no point was logged: {end}");
    assert_eq!(end["state"], "done", "{end}; retries: {retries:?}");
    let moves: Vec<_> = retries
        .iter()
        .filter(|e| e["operation"].as_str().unwrap().starts_with("move to"))
        .collect();
    let measures: Vec<_> = retries
        .iter()
        .filter(|e| e["operation"] == "measure")
        .collect();
    // Two failed attempts of the first move (X garbled twice; Y's lost
    // answer falls on the first attempt).
    assert_eq!(moves.len(), 2, "{retries:?}");
    assert_eq!(moves[0]["attempt"], 1);
    assert_eq!(moves[1]["attempt"], 2);
    assert_eq!(moves[0]["operation"], moves[1]["operation"]);
    assert!(
        moves
            .iter()
            .any(|e| e["error"].as_str().unwrap().contains("unusable answer")),
        "{moves:?}"
    );
    // The stalled grab in flight when the camera comes back still has to
    // time out before the next one: one or two measurement retries.
    assert!((1..=2).contains(&measures.len()), "{retries:?}");
    assert!(measures.iter().all(|e| e["code"] == "camera_stalled"));
    assert_eq!(moves.len() + measures.len(), retries.len(), "{retries:?}");
    assert_eq!(end["retries"], json!(retries.len()), "{end}");
    let status = cl
        .call(json!({"cmd":"characterize","action":"status"}))
        .await;
    assert_eq!(status["job"]["retries"], json!(retries.len()), "{status}");
    // Every plan point logged exactly once.
    let log = micropos::charact::log::read_file(r.data.join("c.csv")).unwrap();
    assert_eq!(log.records.len() as u64, end["total"].as_u64().unwrap());
    r.shutdown().await;
}

#[tokio::test(start_paused = true)]
async fn a_permanent_fault_is_not_retried() {
    let r = rig().await;
    let (mut events, _cl) = start(&r, characterize("p.csv")).await;
    let sim = r.sim();
    let mut cycled = false;
    let (end, retries) = follow(&mut events, |v| {
        if !cycled && v["event"] == "job" && v["done"].as_u64() == Some(1) {
            // Reference lost, servo off: nothing a retry fixes.
            sim.inject(AxisName::X, Fault::PowerCycle).unwrap();
            cycled = true;
        }
    })
    .await;
    assert!(cycled, "no point was logged: {end}");
    // The reset may swallow the answer to a query in flight: that one
    // looks like a lost reply and is retried once; the retry meets the
    // permanent fault, which ends the job at once.
    assert!(retries.len() <= 1, "{retries:?}");
    assert_eq!(end["retries"], json!(retries.len()), "{end}");
    for r in &retries {
        let e = r["error"].as_str().unwrap();
        assert!(
            !e.contains("not referenced"),
            "retried a permanent fault: {r}"
        );
    }
    assert_ne!(end["state"], "done", "{end}");
    if end["state"] == "failed" {
        let e = end["error"].as_str().unwrap();
        assert!(
            e.starts_with("not_referenced")
                || e.starts_with("halted")
                || (e.starts_with("driver_error") && e.contains("not on target"))
                // The reset can also swallow the ERR? that follows.
                || (e.starts_with("not_connected") && e.contains("not even to ERR?")),
            "{e}"
        );
        assert!(!e.contains("persisted through"), "{e}");
    } else {
        assert_eq!(end["state"], "stopped", "{end}");
    }
    r.shutdown().await;
}

/// A characterization on the in-process rig goes on to the next point
/// while a point's frame decodes (`Vision::defer`), so a frame that does
/// not decode is found after the stage left its point. The point is then
/// measured again (event `job_remeasure`): the job goes back to it, logs
/// it, approaches the point it had gone on to again, and every plan point
/// ends in the log exactly once, in plan order, measured on the pattern.
#[tokio::test(start_paused = true)]
async fn an_undecodable_frame_is_measured_again_after_the_stage_left_it() {
    let r = rig().await;
    let (mut events, _cl) = start(&r, characterize("g.csv")).await;
    let camera = r.sim().camera().clone();
    let mut garbled = false;
    let mut remeasures = Vec::new();
    let (end, retries) = follow(&mut events, |v| {
        if !garbled && v["event"] == "job" && v["done"].as_u64() == Some(2) {
            camera.set_mode(CameraMode::Garbage);
            garbled = true;
        }
        if v["event"] == "job_remeasure" {
            camera.set_mode(CameraMode::Normal);
            remeasures.push(v.clone());
        }
    })
    .await;
    assert!(garbled, "no second point was logged: {end}");
    assert_eq!(end["state"], "done", "{end}; retries {retries:?}");
    assert_eq!(remeasures.len(), 1, "{remeasures:?}");
    let point = remeasures[0]["point"].as_u64().unwrap() as usize;
    assert!(point >= 2, "{remeasures:?}");
    assert!(
        remeasures[0]["reason"].as_str().unwrap().contains("decode"),
        "{remeasures:?}"
    );
    let log = micropos::charact::log::read_file(r.data.join("g.csv")).unwrap();
    let total = end["total"].as_u64().unwrap() as usize;
    // The stage had gone on unless it was the last point.
    assert_eq!(remeasures[0]["detour"], point + 1 < total, "{remeasures:?}");
    assert_eq!(log.records.len(), total, "every point once");
    // Plan order: forward then backward over 0, 200, 400 µm (relative).
    let x0 = log.records[0].x_target_um;
    let xs: Vec<f64> = log.records.iter().map(|r| r.x_target_um - x0).collect();
    assert_eq!(xs, [0.0, 200.0, 400.0, 400.0, 200.0, 0.0], "{xs:?}");
    // Each point measured where the stage stood: the measured minus the
    // target agrees with the rest of the scan to well under a period, the
    // re-measured point included.
    let err: Vec<f64> = log
        .records
        .iter()
        .map(|r| r.x_meas_um - r.x_target_um)
        .collect();
    let others: Vec<f64> = err
        .iter()
        .enumerate()
        .filter(|&(i, _)| i != point)
        .map(|(_, e)| *e)
        .collect();
    let lo = others.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = others.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    assert!(
        err[point] > lo - 2.0 && err[point] < hi + 2.0,
        "re-measured point {point}: error {} µm, others {lo}..{hi} µm",
        err[point]
    );
    r.shutdown().await;
}

/// Cancelled while a point's frame decodes beside the move to the next
/// point: the point is logged (it was measured), the job's count says so,
/// and a resume measures the rest: every plan point once, in plan order.
#[tokio::test(start_paused = true)]
async fn a_cancel_while_a_point_decodes_logs_it_and_a_resume_completes_the_plan() {
    let r = rig().await;
    let (mut events, mut cl) = start(&r, characterize("k.csv")).await;
    let t = Instant::now();
    loop {
        assert!(t.elapsed() < Duration::from_secs(60), "no third point");
        let v = events.line().await;
        assert_ne!(v["state"], "failed", "{v}");
        if v["event"] == "job" && v["done"].as_u64() == Some(3) {
            break;
        }
    }
    let reply = cl
        .call_ok(json!({"cmd":"characterize","action":"cancel"}))
        .await;
    let cancelled = &reply["job"];
    assert_eq!(cancelled["state"], "cancelled", "{cancelled}");
    let path = r.data.join("k.csv");
    let log = micropos::charact::log::read_file(&path).unwrap();
    let done = cancelled["done"].as_u64().unwrap() as usize;
    assert_eq!(log.records.len(), done, "{cancelled}");
    // Point 3 was exposed when point 2 was logged: it is in the log too
    // (it decoded), unless the cancel came after a further point.
    assert!(done >= 4, "{cancelled}");
    let plan = [0.0, 200.0, 400.0, 400.0, 200.0, 0.0];
    let x0 = log.records[0].x_target_um;
    for (k, rec) in log.records.iter().enumerate() {
        assert_eq!(rec.x_target_um - x0, plan[k], "record {k}");
    }
    let resumed = cl
        .call(json!({"cmd":"characterize","action":"resume","log":"k.csv"}))
        .await;
    assert_eq!(resumed["ok"], true, "{resumed}");
    // The cancelled job's last event may still be on its way.
    let end = loop {
        let (end, _) = follow(&mut events, |_| {}).await;
        if end["state"] != "cancelled" {
            break end;
        }
    };
    assert_eq!(end["state"], "done", "{end}");
    let log = micropos::charact::log::read_file(&path).unwrap();
    let xs: Vec<f64> = log.records.iter().map(|r| r.x_target_um - x0).collect();
    assert_eq!(xs, plan, "every point once, in plan order");
    r.shutdown().await;
}

/// The overlap of a point's decode with the move to the next changes the
/// wall time only: the same rig (seed 7) and plan with
/// `characterize.overlap_decode` on and off write byte-identical logs,
/// with two frames per point and drift reference detours in the scan.
#[tokio::test(start_paused = true)]
async fn overlapping_the_decode_with_the_next_move_changes_no_record() {
    let mut logs = Vec::new();
    for overlap in [true, false] {
        let r = rig_with(|c| c.characterize.overlap_decode = overlap).await;
        let request = json!({"cmd": "characterize", "action": "start", "log": "o.csv", "axes": "xy",
                             "step_um": 100.0, "x_range_um": 400.0, "y_range_um": 300.0, "cycles": 1,
                             "frames_per_point": 2, "settle_s": 0.05, "drift_every_s": 1.0});
        let (mut events, _cl) = start(&r, request).await;
        let (end, retries) = follow(&mut events, |_| {}).await;
        assert_eq!(end["state"], "done", "overlap {overlap}: {end}");
        assert!(retries.is_empty(), "{retries:?}");
        let text = std::fs::read_to_string(r.data.join("o.csv")).unwrap();
        let log = micropos::charact::log::read_file(r.data.join("o.csv")).unwrap();
        let refs = log
            .records
            .iter()
            .filter(|r| r.segment == "drift_ref")
            .count();
        assert!(refs >= 2, "overlap {overlap}: {refs} reference rows");
        logs.push(text);
        r.shutdown().await;
    }
    // The metadata's creation stamps are the wall clock's; the rest, every
    // record included, is the rig's.
    let body = |t: &str| -> Vec<String> {
        t.lines()
            .filter(|l| !l.starts_with('#') || !l.contains("created"))
            .map(str::to_owned)
            .collect()
    };
    let (a, b) = (body(&logs[0]), body(&logs[1]));
    assert!(a.len() > 20, "{}", logs[0]);
    assert_eq!(a, b);
}
