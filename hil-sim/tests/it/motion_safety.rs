//! Motion safety against the in-process simulated rig (tokio's paused
//! clock: simulated time, one result per seed): for each way a move can go
//! wrong, both axes' true positions (the rig's ground truth, not what the
//! controllers say) must come to rest within a stated bound of simulated
//! time, and the next `move` must be refused (`fault_latched`) until a
//! client sends `reset`.
//!
//! Faults: a controller error mid-move (servo fault, `ERR?` = 1024), a
//! motion timeout, a jammed axis (following error), position reads
//! failing, a line dropped mid-move (both axes), a carriage slipping
//! against its encoder (vision deviation), plus the ways out that
//! are not faults: shutdown (what SIGTERM runs), job cancel, and the
//! daemon gone without a word (SIGKILL) followed by the stop hook
//! (`microposd --halt`'s `driver::halt::halt_all`).
//!
//! Each test prints one `HALT` line (time to rest after the fault, distance
//! travelled after it, per axis): `cargo test -p hil-sim --test it
//! motion_safety:: -- --nocapture | grep HALT` gives the table of
//! `docs/design/daemon.md`.

use crate::common::{self, Client, DaemonRig};
use hil_sim::run::{daemon_config, RunPlan};
use hil_sim::{AxisName, Corruption, Fault, SimHandle};
use micropos::daemon::config::{DaemonConfig, DeviationFrame};
use serde_json::{json, Value};
use std::time::Duration;

/// Longest a fault may take to bring both axes to rest (simulated s),
/// unless a test states its own: detection (a supervisor period or a read
/// timeout) plus the deceleration from 1 mm/s.
const HALT_BOUND_S: f64 = 1.0;

/// The in-process rig with the daemon on it, both axes referenced (at the
/// reference switch, 7500 µm). `tweak` adjusts the daemon's configuration.
async fn rig(tweak: impl FnOnce(&mut DaemonConfig)) -> DaemonRig {
    DaemonRig::in_process(3, 1.0, |c| {
        c.daemon.poll_interval_ms = 100;
        for a in [&mut c.driver.x, &mut c.driver.y] {
            a.timeout_ms = 200;
            a.poll_interval_ms = 20;
            a.motion_timeout_s = 30.0;
        }
        c.safety.supervise_interval_ms = 50;
        c.safety.following_error_um = 200.0;
        c.safety.read_fail_s = 0.5;
        tweak(c);
    })
    .await
}

fn code(v: &Value) -> &str {
    v["error"]["code"].as_str().unwrap_or("")
}

fn truth_um(sim: &SimHandle) -> [f64; 2] {
    [
        sim.true_position_mm(AxisName::X) * 1000.0,
        sim.true_position_mm(AxisName::Y) * 1000.0,
    ]
}

fn now_s(sim: &SimHandle) -> f64 {
    sim.sim_time().as_secs_f64()
}

/// What the ground truth did after a fault.
#[derive(Debug)]
struct Halt {
    /// Time from the fault to the last motion, per axis, s.
    rest_after_s: [f64; 2],
    /// Distance from the position at the fault to the rest position, µm.
    travel_um: [f64; 2],
}

/// Samples the true positions every 10 ms from the fault (at `t_fault`,
/// positions `p_fault`) until neither axis moved (> 0.5 µm per sample; a
/// moving axis covers ≥ 5 µm) for a full second. Panics if that takes
/// longer than `bound_s` + 1 s.
async fn rest_after(sim: &SimHandle, t_fault: f64, p_fault: [f64; 2], bound_s: f64) -> Halt {
    rest_while(sim, t_fault, p_fault, bound_s, async {}).await.0
}

/// [`rest_after`] while `action` (what halts the stage: a shutdown, a
/// cancel, the stop hook) runs: the sampling covers its whole duration.
async fn rest_while<T>(
    sim: &SimHandle,
    t_fault: f64,
    p_fault: [f64; 2],
    bound_s: f64,
    action: impl std::future::Future<Output = T>,
) -> (Halt, T) {
    let (h, out) = tokio::join!(sample_rest(sim, t_fault, p_fault, bound_s), action);
    (h, out)
}

async fn sample_rest(sim: &SimHandle, t_fault: f64, p_fault: [f64; 2], bound_s: f64) -> Halt {
    let mut prev = truth_um(sim);
    let mut last_change = [t_fault; 2];
    loop {
        tokio::time::sleep(Duration::from_millis(10)).await;
        let t = now_s(sim);
        let p = truth_um(sim);
        for i in 0..2 {
            if (p[i] - prev[i]).abs() > 0.5 {
                last_change[i] = t;
            }
        }
        prev = p;
        if t - last_change[0].max(last_change[1]) >= 1.0 {
            break;
        }
        assert!(
            t - t_fault < bound_s + 1.0,
            "still moving {:.2} s after the fault: {p:?}",
            t - t_fault
        );
    }
    let h = Halt {
        rest_after_s: [last_change[0] - t_fault, last_change[1] - t_fault],
        travel_um: [(prev[0] - p_fault[0]).abs(), (prev[1] - p_fault[1]).abs()],
    };
    for i in 0..2 {
        assert!(
            h.rest_after_s[i] <= bound_s,
            "axis {i} came to rest {:.3} s after the fault (bound {bound_s} s): {h:?}",
            h.rest_after_s[i]
        );
    }
    h
}

fn report(name: &str, h: &Halt) {
    println!(
        "HALT | {name} | x {:.3} s, {:.1} µm | y {:.3} s, {:.1} µm |",
        h.rest_after_s[0], h.travel_um[0], h.rest_after_s[1], h.travel_um[1]
    );
}

/// Starts a long move of both axes (not waited on: the supervisor alone
/// watches it) and lets it run for `run_s` simulated s.
async fn long_move(cl: &mut Client, sim: &SimHandle, run_s: f64) {
    cl.call_ok(json!({"cmd":"move","x_um":13500.0,"y_um":1500.0}))
        .await;
    tokio::time::sleep(Duration::from_secs_f64(run_s)).await;
    let p = truth_um(sim);
    assert!(
        p[0] > 7600.0 && p[1] < 7400.0,
        "both axes should be under way: {p:?}"
    );
}

/// The next move is refused naming the fault; `reset` clears the latch
/// (and reports what it cleared); `then` may re-reference; a move works.
async fn refused_until_reset(cl: &mut Client, fault_words: &str, re_reference: bool) {
    let m = cl
        .call(json!({"cmd":"move","x_um":7000.0,"wait":true}))
        .await;
    assert_eq!(code(&m), "fault_latched", "{m}");
    let msg = m["error"]["message"].as_str().unwrap();
    assert!(msg.contains(fault_words), "{msg}");
    let st = cl.call_ok(json!({"cmd":"status"})).await;
    assert_eq!(st["rig"]["mode"], "fault", "{st}");
    assert!(
        st["rig"]["fault_latched"]["reason"]
            .as_str()
            .unwrap()
            .contains(fault_words),
        "{st}"
    );
    let r = cl.call_ok(json!({"cmd":"reset"})).await;
    assert!(
        r["cleared"]["reason"]
            .as_str()
            .unwrap()
            .contains(fault_words),
        "{r}"
    );
    if re_reference {
        cl.call_ok(json!({"cmd":"reference"})).await;
    }
    // A short move from where the stage stands (within any motion timeout).
    let p = controller_um(cl).await;
    let (x, y) = (p[0] + 100.0, p[1] - 100.0);
    let m = cl
        .call(json!({"cmd":"move","x_um":x,"y_um":y,"wait":true}))
        .await;
    assert_eq!(m["ok"], true, "{m}");
    let q = controller_um(cl).await;
    assert!((q[0] - x).abs() < 1.0 && (q[1] - y).abs() < 1.0, "{q:?}");
}

async fn controller_um(cl: &mut Client) -> [f64; 2] {
    let p = cl.call_ok(json!({"cmd":"position"})).await;
    [
        p["controller"]["x_um"].as_f64().unwrap(),
        p["controller"]["y_um"].as_f64().unwrap(),
    ]
}

#[tokio::test(start_paused = true)]
async fn controller_error_mid_move_halts_both_and_latches() {
    let r = rig(|_| {}).await;
    let sim = r.sim();
    let mut cl = Client::connect(&r.socket).await;
    long_move(&mut cl, sim, 1.0).await;
    let (t, p) = (now_s(sim), truth_um(sim));
    sim.inject(AxisName::X, Fault::MotionError).unwrap();
    let h = rest_after(sim, t, p, HALT_BOUND_S).await;
    report("controller error (ERR? 1024) on x mid-move", &h);
    // The servo fault switched X's servo off: a reference run turns it on.
    refused_until_reset(&mut cl, "1024", true).await;
    r.shutdown().await;
}

#[tokio::test(start_paused = true)]
async fn motion_timeout_halts_both_and_latches() {
    // The long move needs ≈ 6 s; the timeout allows 2.
    let r = rig(|c| {
        c.driver.x.motion_timeout_s = 2.0;
        c.driver.y.motion_timeout_s = 2.0;
    })
    .await;
    let sim = r.sim();
    let mut cl = Client::connect(&r.socket).await;
    let t0 = now_s(sim);
    long_move(&mut cl, sim, 1.0).await;
    // The fault is the timeout expiring, 2 s after the move was sent.
    tokio::time::sleep(Duration::from_secs_f64(t0 + 2.0 - now_s(sim))).await;
    let (t, p) = (now_s(sim), truth_um(sim));
    let h = rest_after(sim, t, p, HALT_BOUND_S).await;
    report("motion timeout (2 s)", &h);
    refused_until_reset(&mut cl, "motion timeout", false).await;
    r.shutdown().await;
}

#[tokio::test(start_paused = true)]
async fn a_jammed_axis_is_a_following_error() {
    let r = rig(|_| {}).await;
    let sim = r.sim();
    let mut cl = Client::connect(&r.socket).await;
    long_move(&mut cl, sim, 1.0).await;
    let (t, p) = (now_s(sim), truth_um(sim));
    sim.inject(AxisName::Y, Fault::Stall).unwrap();
    let h = rest_after(sim, t, p, HALT_BOUND_S).await;
    // Y jammed at once (the stage model's creep moves it by µm); X is the
    // axis the daemon had to halt.
    assert!(h.travel_um[1] < 5.0, "{h:?}");
    report("following error (y jammed)", &h);
    refused_until_reset(&mut cl, "following error", false).await;
    r.shutdown().await;
}

#[tokio::test(start_paused = true)]
async fn failing_position_reads_halt_both_and_latch() {
    let r = rig(|_| {}).await;
    let sim = r.sim();
    let mut cl = Client::connect(&r.socket).await;
    let mut sub = Client::connect(&r.socket).await;
    sub.call_ok(json!({"cmd":"subscribe","topics":["fault"]}))
        .await;
    long_move(&mut cl, sim, 1.0).await;
    let (t, p) = (now_s(sim), truth_um(sim));
    // Every value answer of X is lost from now on (ERR?, #5 and the halt's
    // confirmation still pass): the daemon cannot see where X is.
    sim.inject(
        AxisName::X,
        Fault::CorruptReplies {
            how: Corruption::Drop,
            count: u32::MAX,
        },
    )
    .unwrap();
    // read_fail_s 0.5 + one read timeout (0.2 s) + the halt.
    let h = rest_after(sim, t, p, 1.5).await;
    let ev = loop {
        let ev = sub.line().await;
        if ev["event"] == "fault" {
            break ev;
        }
    };
    let detect_s = ev["t_s"].as_f64().unwrap() - t;
    // From the fault latched to both axes at rest: the `HLT` goes ahead of
    // the reads queued on x's line (each running into its answer timeout),
    // so this is the deceleration (0.1 s from 1 mm/s) and a little more.
    let halt_s = h.rest_after_s[0].max(h.rest_after_s[1]) - detect_s;
    assert!(
        (0.3..=1.2).contains(&detect_s) && halt_s < 0.25,
        "detected {detect_s:.3} s after the reads began failing, at rest {halt_s:.3} s later: {h:?}"
    );
    println!(
        "HALT | position reads of x failing (bound 0.5 s; latched after {detect_s:.3} s, both at rest {halt_s:.3} s after that) | x {:.3} s, {:.1} µm | y {:.3} s, {:.1} µm |",
        h.rest_after_s[0], h.travel_um[0], h.rest_after_s[1], h.travel_um[1]
    );
    sim.inject(
        AxisName::X,
        Fault::CorruptReplies {
            how: Corruption::Drop,
            count: 0,
        },
    )
    .unwrap();
    refused_until_reset(&mut cl, "position reads failing", false).await;
    r.shutdown().await;
}

#[tokio::test(start_paused = true)]
async fn a_dropped_line_halts_the_other_axis_and_the_lost_one_on_reconnect() {
    let r = rig(|_| {}).await;
    let sim = r.sim();
    let mut cl = Client::connect(&r.socket).await;
    let mut sub = Client::connect(&r.socket).await;
    sub.call_ok(json!({"cmd":"subscribe","topics":["fault"]}))
        .await;
    long_move(&mut cl, sim, 1.0).await;
    let (t, p) = (now_s(sim), truth_um(sim));
    sim.inject(AxisName::X, Fault::DropLine).unwrap();
    // Y is halted at once; X runs on while nobody can reach it; the line
    // comes back after 0.5 s.
    let away = async {
        tokio::time::sleep(Duration::from_millis(500)).await;
        let px = truth_um(sim)[0];
        assert!(
            px > p[0] + 300.0,
            "x runs on without its line: {px} vs {}",
            p[0]
        );
        let m = cl.call(json!({"cmd":"move","y_um":7000.0})).await;
        assert_eq!(code(&m), "not_connected", "{m}");
        let t_back = now_s(sim);
        sim.inject(AxisName::X, Fault::RestoreLine).unwrap();
        t_back
    };
    // Y: rest within the bound of the drop; X: within the bound of the
    // line's return (reconnect back-off 20 ms).
    let (h, t_back) = rest_while(sim, t, p, 0.5 + HALT_BOUND_S, away).await;
    assert!(h.rest_after_s[1] < HALT_BOUND_S, "{h:?}");
    assert!(h.rest_after_s[0] - (t_back - t) < HALT_BOUND_S, "{h:?}");
    println!(
        "HALT | line of x dropped (y) / restored after {:.2} s (x) | x {:.3} s after restore, {:.1} µm after the drop | y {:.3} s, {:.1} µm |",
        t_back - t,
        h.rest_after_s[0] - (t_back - t),
        h.travel_um[0],
        h.rest_after_s[1],
        h.travel_um[1]
    );
    // The daemon said it halted and read back the reconnected axis.
    let ev = loop {
        let ev = sub.line().await;
        if ev["event"] == "axis_recovered" {
            break ev;
        }
    };
    assert_eq!(ev["axis"], "x", "{ev}");
    assert_eq!(ev["halted"], true, "{ev}");
    assert!(ev["position_um"].as_f64().is_some(), "{ev}");
    refused_until_reset(&mut cl, "axis x line down", false).await;
    r.shutdown().await;
}

#[tokio::test(start_paused = true)]
async fn shutdown_mid_move_halts_both_axes() {
    let mut r = rig(|_| {}).await;
    let mut cl = Client::connect(&r.socket).await;
    long_move(&mut cl, r.sim(), 1.0).await;
    let sim = r.sim.take().unwrap();
    let (t, p) = (now_s(&sim), truth_um(&sim));
    // What microposd does on SIGTERM / SIGINT.
    let daemon = r.daemon.take().unwrap();
    let (h, ()) = rest_while(&sim, t, p, HALT_BOUND_S, daemon.shutdown()).await;
    report("shutdown (SIGTERM) mid-move", &h);
    tokio::task::spawn_blocking(move || sim.shutdown())
        .await
        .unwrap();
}

#[tokio::test(start_paused = true)]
async fn job_cancel_mid_move_halts_both_axes() {
    let r = rig(|_| {}).await;
    let sim = r.sim();
    let mut cl = Client::connect(&r.socket).await;
    // A characterization whose first move (to its start corner, far from
    // the reference position) is long.
    let st = cl
        .call(
            json!({"cmd": "characterize", "action": "start", "log": "c.csv", "axes": "xy",
                     "step_um": 500.0, "x_range_um": 1000.0, "y_range_um": 1000.0, "cycles": 1,
                     "frames_per_point": 1, "settle_s": 0.05, "drift_every_s": 0.0}),
        )
        .await;
    assert_eq!(st["ok"], true, "{st}");
    // Wait until the stage is under way.
    let p0 = truth_um(sim);
    let t_start = now_s(sim);
    loop {
        tokio::time::sleep(Duration::from_millis(10)).await;
        let p = truth_um(sim);
        if (p[0] - p0[0]).abs() > 500.0 || (p[1] - p0[1]).abs() > 500.0 {
            break;
        }
        assert!(now_s(sim) - t_start < 30.0, "the job never moved");
    }
    let (t, p) = (now_s(sim), truth_um(sim));
    let (h, c) = rest_while(
        sim,
        t,
        p,
        HALT_BOUND_S,
        cl.call_ok(json!({"cmd":"characterize","action":"cancel"})),
    )
    .await;
    assert_eq!(c["job"]["state"], "cancelled", "{c}");
    assert_eq!(c["halt"]["at_rest"], true, "{c}");
    report("job cancel mid-move", &h);
    // A cancel is not a fault: the next move is served.
    let m = cl
        .call(json!({"cmd":"move","x_um":7000.0,"wait":true}))
        .await;
    assert_eq!(m["ok"], true, "{m}");
    r.shutdown().await;
}

#[tokio::test(start_paused = true)]
async fn stop_hook_halts_a_stage_left_moving_by_a_killed_daemon() {
    // No daemon: the driver alone, as a daemon that dies by SIGKILL leaves
    // it (lines closed, nothing sent, the move runs on).
    let dir = tempfile::tempdir().unwrap();
    let rig_dir = dir.path().join("rig");
    std::fs::create_dir_all(&rig_dir).unwrap();
    let cfg = common::serve_config(&rig_dir, 1.0, 3);
    let rig_cfg = cfg.rig.clone();
    let sim = common::serve_in_process(cfg);
    let c = daemon_config(
        &rig_dir,
        &dir.path().join("data"),
        &dir.path().join("d.sock"),
        &rig_cfg,
        &RunPlan::reduced(),
    )
    .unwrap();
    let opener = sim.link_opener().unwrap();
    let (tx, _) = tokio::sync::broadcast::channel(64);
    let stage = micropos::driver::Stage::connect_via(&c.driver, tx, Some(&opener))
        .await
        .unwrap();
    let (x, y) = tokio::join!(stage.x.reference(), stage.y.reference());
    x.unwrap();
    y.unwrap();
    stage.x.move_abs_um(13500.0).await.unwrap();
    stage.y.move_abs_um(1500.0).await.unwrap();
    drop(stage);
    tokio::time::sleep(Duration::from_secs(1)).await;
    let (t, p) = (now_s(&sim), truth_um(&sim));
    assert!(p[0] > 7600.0 && p[1] < 7400.0, "{p:?}");
    // The stop hook: microposd --halt (ExecStopPost=).
    let hook = micropos::driver::halt::halt_all(&c.driver, Some(&opener), Duration::from_secs(5));
    let (h, report_) = rest_while(&sim, t, p, HALT_BOUND_S, hook).await;
    assert!(report_.iter().all(|a| a.ok()), "{report_:?}");
    report("SIGKILL, then the stop hook (microposd --halt, #24)", &h);
    tokio::task::spawn_blocking(move || sim.shutdown())
        .await
        .unwrap();
}

/// A seed for the drawn parameters: `MICROPOS_TEST_SEED` or a fresh one,
/// printed so a failure can be repeated.
fn test_rng(name: &str) -> rand_chacha::ChaCha8Rng {
    use rand::SeedableRng;
    let seed = std::env::var("MICROPOS_TEST_SEED")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(rand::random::<u64>);
    println!("{name}: MICROPOS_TEST_SEED={seed}");
    rand_chacha::ChaCha8Rng::seed_from_u64(seed)
}

/// Waits (simulated time, at most `within_s`) until `status` says
/// `pred`; returns the last status.
async fn status_until(cl: &mut Client, within_s: f64, pred: impl Fn(&Value) -> bool) -> Value {
    let t0 = tokio::time::Instant::now();
    loop {
        let st = cl.call_ok(json!({"cmd":"status"})).await;
        if pred(&st) {
            return st;
        }
        assert!(
            t0.elapsed().as_secs_f64() < within_s,
            "not within {within_s} s: {st}"
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

#[tokio::test(start_paused = true)]
async fn a_carriage_slipping_against_its_encoder_is_a_vision_deviation() {
    use rand::Rng;
    let mut rng = test_rng("vision deviation");
    let theta_deg = hil_sim::rig::Mounting::default().theta_deg;
    let bound_um = 50.0;
    let r = rig(|c| {
        c.safety.deviation_um = bound_um;
        // No table here: the camera's orientation by hand. The simulated
        // camera sees P = offset − R(θ)·platform (config/sim-rig.toml), so
        // vision → stage is a rotation by θ + π.
        c.safety.deviation_frame = DeviationFrame::Camera;
        c.camera.rotation_rad = theta_deg.to_radians() - std::f64::consts::PI;
    })
    .await;
    let sim = r.sim();
    assert_eq!(sim.rig().mounting().theta_deg, theta_deg);
    // On the in-process rig frames are grabbed on demand; a camera on a
    // real rig streams. This keeps it streaming for the test.
    let daemon = &r.daemon.as_ref().unwrap().daemon;
    let _frames = daemon.rig.vision.as_ref().unwrap().want();
    let mut cl = Client::connect(&r.socket).await;
    let mut sub = Client::connect(&r.socket).await;
    sub.call_ok(json!({"cmd":"subscribe","topics":["fault"]}))
        .await;
    // Tied at rest after the reference run.
    status_until(&mut cl, 5.0, |s| s["deviation"]["tied"] == true).await;
    // A healthy move across the pattern (random, both signs) passes the
    // check, and the check ran on it.
    let (x1, y1) = (
        rng.gen_range(1000.0..11000.0),
        rng.gen_range(1000.0..11000.0),
    );
    cl.call_ok(json!({"cmd":"move","x_um":x1,"y_um":y1,"wait":true}))
        .await;
    let st = status_until(&mut cl, 5.0, |s| s["deviation"]["last_um"].is_object()).await;
    for a in ["x", "y"] {
        let d = st["deviation"]["last_um"][a].as_f64().unwrap();
        assert!(
            d.abs() < bound_um,
            "healthy move: deviation {a} {d} µm: {st}"
        );
    }
    assert_eq!(st["rig"]["mode"], "idle", "{st}");
    // A long move of both axes, not waited on, still on the pattern.
    let (x2, y2) = (
        if x1 > 6000.0 { 500.0 } else { 11400.0 },
        if y1 > 6000.0 { 500.0 } else { 11400.0 },
    );
    cl.call_ok(json!({"cmd":"move","x_um":x2,"y_um":y2})).await;
    tokio::time::sleep(Duration::from_secs_f64(rng.gen_range(0.5..2.0))).await;
    let axis = if rng.gen_bool(0.5) {
        AxisName::X
    } else {
        AxisName::Y
    };
    let slip_um: i32 = rng.gen_range(3 * bound_um as i32..8 * bound_um as i32)
        * if rng.gen_bool(0.5) { 1 } else { -1 };
    let (t, p) = (now_s(sim), truth_um(sim));
    sim.inject(axis, Fault::Slip { slip_um }).unwrap();
    let p_slipped = truth_um(sim);
    let h = rest_after(sim, t, p_slipped, HALT_BOUND_S).await;
    let ev = loop {
        let ev = sub.line().await;
        if ev["event"] == "fault" {
            break ev;
        }
    };
    let reason = ev["reason"].as_str().unwrap();
    assert!(
        reason.contains(&format!("axis {axis}: vision deviation")),
        "{ev}"
    );
    // The sign convention: vision − controller, so the sign of the slip.
    let sign = if slip_um > 0 { "+" } else { "-" };
    assert!(reason.contains(&format!("deviation {sign}")), "{ev}");
    let detect_s = ev["t_s"].as_f64().unwrap() - t;
    assert!(
        (0.0..0.5).contains(&detect_s),
        "detected after {detect_s} s"
    );
    assert!(
        (p_slipped[0] - p[0]).abs() + (p_slipped[1] - p[1]).abs() > 100.0,
        "the slip moved the platform: {p:?} → {p_slipped:?}"
    );
    println!(
        "HALT | vision deviation (slip {slip_um:+} µm on {axis}, bound {bound_um} µm; detected after {detect_s:.3} s) | x {:.3} s, {:.1} µm | y {:.3} s, {:.1} µm |",
        h.rest_after_s[0], h.travel_um[0], h.rest_after_s[1], h.travel_um[1]
    );
    refused_until_reset(&mut cl, "vision deviation", false).await;
    // Reset ties afresh where the stage now stands: a move afterwards is
    // checked against the new tie, without a fault.
    status_until(&mut cl, 5.0, |s| s["deviation"]["tied"] == true).await;
    let m = cl
        .call(json!({"cmd":"move","x_um":x1,"y_um":y1,"wait":true}))
        .await;
    assert_eq!(m["ok"], true, "{m}");
    let st = cl.call_ok(json!({"cmd":"status"})).await;
    assert_eq!(st["rig"]["mode"], "idle", "{st}");
    r.shutdown().await;
}

#[tokio::test(start_paused = true)]
async fn without_decodes_there_is_no_deviation_check_and_no_fault() {
    // The same rig and check; the camera's frames stop decoding (garbage):
    // no check, no fault, the move is reported as unchecked by vision. A
    // slip meanwhile is found once frames decode again.
    use hil_sim::camera::CameraMode;
    use rand::Rng;
    let mut rng = test_rng("no decodes");
    let theta_deg = hil_sim::rig::Mounting::default().theta_deg;
    let r = rig(|c| {
        c.safety.deviation_um = 50.0;
        c.safety.deviation_frame = DeviationFrame::Camera;
        c.camera.rotation_rad = theta_deg.to_radians() - std::f64::consts::PI;
    })
    .await;
    let sim = r.sim();
    let daemon = &r.daemon.as_ref().unwrap().daemon;
    let _frames = daemon.rig.vision.as_ref().unwrap().want();
    let mut cl = Client::connect(&r.socket).await;
    let mut sub = Client::connect(&r.socket).await;
    sub.call_ok(json!({"cmd":"subscribe","topics":["fault"]}))
        .await;
    status_until(&mut cl, 5.0, |s| s["deviation"]["tied"] == true).await;
    sim.camera().set_mode(CameraMode::Garbage);
    let (x, y) = (
        rng.gen_range(1000.0..5000.0),
        rng.gen_range(10000.0..11000.0),
    );
    cl.call_ok(json!({"cmd":"move","x_um":x,"y_um":y})).await;
    tokio::time::sleep(Duration::from_millis(300)).await;
    let slip_um = rng.gen_range(200..400) * if rng.gen_bool(0.5) { 1 } else { -1 };
    sim.inject(AxisName::X, Fault::Slip { slip_um }).unwrap();
    let ev = loop {
        let ev = sub.line().await;
        if ev["event"] == "vision_unchecked" || ev["event"] == "fault" {
            break ev;
        }
    };
    assert_eq!(ev["event"], "vision_unchecked", "{ev}");
    // The move ends (at most ≈ 7 s at 1 mm/s), unjudged and without a fault.
    tokio::time::sleep(Duration::from_secs(8)).await;
    let st = cl.call_ok(json!({"cmd":"status"})).await;
    assert!(st["rig"]["fault_latched"].is_null(), "{st}");
    let p = controller_um(&mut cl).await;
    assert!((p[0] - x).abs() < 1.0 && (p[1] - y).abs() < 1.0, "{p:?}");
    // Frames decode again: the stage stands slipped against the tie.
    let t = now_s(sim);
    sim.camera().set_mode(CameraMode::Normal);
    let ev = loop {
        let ev = sub.line().await;
        if ev["event"] == "fault" {
            break ev;
        }
    };
    let reason = ev["reason"].as_str().unwrap();
    assert!(reason.contains("axis x: vision deviation"), "{ev}");
    assert!(ev["t_s"].as_f64().unwrap() - t < 1.0, "{ev}");
    r.shutdown().await;
}

#[tokio::test(start_paused = true)]
async fn a_stop_racing_a_reference_run_is_never_lost() {
    use rand::Rng;
    let mut rng = test_rng("stop racing a reference run");
    let r = rig(|_| {}).await;
    let sim = r.sim();
    let mut cl = Client::connect(&r.socket).await;
    let mut stopper = Client::connect(&r.socket).await;
    for round in 0..8 {
        // A stopped run leaves the axes unreferenced (a latched reference
        // loss): reset and reference first.
        if round > 0 {
            cl.call_ok(json!({"cmd":"reset"})).await;
            cl.call_ok(json!({"cmd":"reference","axes":"xy"})).await;
        }
        // Away from the reference switch, so the run moves the stage.
        let x = rng.gen_range(1000.0..5000.0);
        let y = rng.gen_range(10000.0..14000.0);
        cl.call_ok(json!({"cmd":"move","x_um":x,"y_um":y,"wait":true}))
            .await;
        // The stop lands anywhere from before the run's first command to
        // well into the run (µs steps: the exchanges that start it take
        // a few ms of simulated time).
        let delay_us = match round {
            0 => 0,
            1..=5 => rng.gen_range(0..2000),
            _ => rng.gen_range(2000..300_000),
        };
        cl.next += 1;
        let id = cl.next;
        cl.send_raw(format!("{}\n", json!({"cmd":"reference","axes":"xy","id":id})).as_bytes())
            .await;
        tokio::time::sleep(Duration::from_micros(delay_us)).await;
        let (t, p) = (now_s(sim), truth_um(sim));
        stopper.call_ok(json!({"cmd":"stop"})).await;
        let reply = loop {
            let v = cl.line().await;
            if v.get("event").is_none() {
                break v;
            }
        };
        let h = rest_after(sim, t, p, HALT_BOUND_S).await;
        println!("round {round}: stop {delay_us} µs after the request: {reply}");
        // The run may have finished before the stop only if it was short;
        // here it needs seconds, so it must have been stopped.
        assert_eq!(
            reply["ok"], false,
            "round {round}, stop after {delay_us} µs: {reply}"
        );
        let q = truth_um(sim);
        assert!(
            (q[0] - 7500.0).abs() > 100.0 && (q[1] - 7500.0).abs() > 100.0,
            "round {round}: the run went on to the switch after the stop: {q:?} ({h:?})"
        );
    }
    r.shutdown().await;
}
