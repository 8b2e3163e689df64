//! The micropos driver against the simulated C-863s over real ptys (in-process
//! `SimHandle`): bring-up, moves, velocity, halt, travel limits, unknown
//! commands, daisy chain, and every fault the simulator can inject. After
//! each fault: a clear error, no false position, recovery when the device
//! comes back.

use hil_sim::{AxisName, Fault, ServeConfig, SimHandle};
use micropos::driver::{Axis, AxisEvent, DriverConfig, DriverError, Stage};
use micropos::gcs::GcsErrorCode;
use std::time::{Duration, Instant};
use tokio::sync::broadcast;

/// Simulated seconds per wall second: referencing takes a few simulated
/// seconds, so tests run it fast.
const TIME_SCALE: f64 = 20.0;
const TIMEOUT_MS: u64 = 200;

struct DriverRig {
    sim: Option<SimHandle>,
    stage: Stage,
    rx: broadcast::Receiver<AxisEvent>,
    _dir: tempfile::TempDir,
}

impl DriverRig {
    fn sim(&self) -> &SimHandle {
        self.sim.as_ref().unwrap()
    }

    fn truth_um(&self, axis: AxisName) -> f64 {
        self.sim().true_position_mm(axis) * 1000.0
    }

    fn inject(&self, axis: AxisName, f: Fault) {
        self.sim().inject(axis, f).unwrap();
    }

    fn events(&mut self) -> Vec<AxisEvent> {
        let mut v = Vec::new();
        while let Ok(e) = self.rx.try_recv() {
            v.push(e);
        }
        v
    }
}

impl Drop for DriverRig {
    fn drop(&mut self) {
        if let Some(sim) = self.sim.take() {
            sim.shutdown();
        }
    }
}

fn driver_config(sim: &SimHandle, daisy: bool) -> DriverConfig {
    let mut cfg = DriverConfig::default();
    cfg.x.port = sim.link(AxisName::X);
    cfg.y.port = sim.link(AxisName::Y);
    if daisy {
        cfg.x.address = Some(1);
        cfg.y.address = Some(2);
    }
    for a in [&mut cfg.x, &mut cfg.y] {
        a.timeout_ms = TIMEOUT_MS;
        a.reference_timeout_s = 20.0;
        a.motion_timeout_s = 20.0;
    }
    cfg.reconnect_min_ms = 20;
    cfg.reconnect_max_ms = 200;
    cfg
}

async fn rig(daisy: bool) -> DriverRig {
    let dir = tempfile::tempdir().unwrap();
    let cfg = ServeConfig {
        stage_model: Some(micropos::model::StageModel::ideal()),
        link_dir: dir.path().to_owned(),
        daisy_chain: daisy,
        time_scale: TIME_SCALE,
        control_socket: None,
        seed: 7,
        ..Default::default()
    };
    let sim = crate::common::serve(cfg).await;
    let (tx, rx) = broadcast::channel(1024);
    let stage = Stage::connect(&driver_config(&sim, daisy), tx)
        .await
        .unwrap();
    DriverRig {
        sim: Some(sim),
        stage,
        rx,
        _dir: dir,
    }
}

async fn reference_both(r: &DriverRig) {
    let (x, y) = tokio::join!(r.stage.x.reference(), r.stage.y.reference());
    assert!((x.unwrap() - 7500.0).abs() < 0.1);
    assert!((y.unwrap() - 7500.0).abs() < 0.1);
}

/// Retries `f` until it succeeds (recovery), failing after `limit`.
async fn eventually<T, F, Fut>(limit: Duration, mut f: F) -> T
where
    F: FnMut() -> Fut,
    Fut: std::future::Future<Output = Result<T, DriverError>>,
{
    let start = Instant::now();
    loop {
        match f().await {
            Ok(v) => return v,
            Err(e) if start.elapsed() < limit => {
                let _ = e;
                tokio::time::sleep(Duration::from_millis(50)).await;
            }
            Err(e) => panic!("no recovery within {limit:?}: {e}"),
        }
    }
}

fn assert_close(a: f64, b: f64, tol: f64) {
    assert!((a - b).abs() <= tol, "{a} vs {b}");
}

async fn move_and_check(ax: &Axis, r: &DriverRig, name: AxisName, target_um: f64) {
    ax.move_abs_um(target_um).await.unwrap();
    let p = ax.wait_on_target(None).await.unwrap();
    assert_close(p, target_um, 0.5);
    assert_close(r.truth_um(name), p, 0.5);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bring_up_moves_velocity_halt_limits_unknown_command() {
    let mut r = rig(false).await;
    let (x, y) = (r.stage.x.clone(), r.stage.y.clone());
    assert!(x.identity().is_c863());
    assert_eq!(x.travel_um(), (0.0, 15_000.0));
    // Power-up: no position, no move.
    assert!(matches!(
        x.position_um().await,
        Err(DriverError::NotReferenced { .. })
    ));
    assert!(matches!(
        x.move_abs_um(1000.0).await,
        Err(DriverError::NotReferenced { .. })
    ));
    reference_both(&r).await;
    assert!(r
        .events()
        .contains(&AxisEvent::Referenced { axis: "y".into() }));
    move_and_check(&x, &r, AxisName::X, 2_000.0).await;
    move_and_check(&y, &r, AxisName::Y, 12_345.678_9).await;
    // Relative move.
    x.move_rel_um(1_500.25).await.unwrap();
    assert_close(x.wait_on_target(None).await.unwrap(), 3_500.25, 0.5);
    // Velocity in µm/s round trip.
    x.set_velocity_um_per_s(1_500.0).await.unwrap();
    assert_close(x.velocity_um_per_s().await.unwrap(), 1_500.0, 1e-6);
    // Out of travel: refused with the limits, nothing moves.
    match x.move_abs_um(15_000.5).await {
        Err(DriverError::OutOfTravel { max_um, .. }) => assert_eq!(max_um, 15_000.0),
        other => panic!("{other:?}"),
    }
    assert!(matches!(
        x.move_rel_um(-4_000.0).await,
        Err(DriverError::OutOfTravel { .. })
    ));
    assert_close(x.position_um().await.unwrap(), 3_500.25, 0.5);
    // Halt in the middle of a long move.
    x.set_velocity_um_per_s(500.0).await.unwrap();
    x.move_abs_um(14_000.0).await.unwrap();
    let waiter = {
        let x = x.clone();
        tokio::spawn(async move { x.wait_on_target(None).await })
    };
    tokio::time::sleep(Duration::from_millis(200)).await;
    assert!(x.is_moving().await.unwrap());
    x.halt().await.unwrap();
    assert!(matches!(
        waiter.await.unwrap(),
        Err(DriverError::Halted { .. })
    ));
    tokio::time::sleep(Duration::from_millis(300)).await;
    let p = x.position_um().await.unwrap();
    assert!(p > 3_600.0 && p < 13_900.0, "{p}");
    assert!(!x.is_moving().await.unwrap());
    // The raw path shows the controller's own error 10 after HLT.
    let reply = x.controller().console("HLT 1").await.unwrap();
    assert_eq!(reply.error, GcsErrorCode::STOPPED);
    // #24 stops too.
    x.move_abs_um(4_000.0).await.unwrap();
    x.stop().await.unwrap();
    assert!(matches!(
        x.wait_on_target(None).await,
        Err(DriverError::Halted { .. })
    ));
    // Unknown command: silence, then ERR? = 2.
    let reply = y.controller().console("XYZ? 1").await.unwrap();
    assert!(reply.silent);
    assert_eq!(reply.error, GcsErrorCode::UNKNOWN_COMMAND);
    let reply = y.controller().console("POS? 1").await.unwrap();
    assert!(reply.answer.unwrap().text().starts_with("1=12.345"));
    let st = y.status().await.unwrap();
    assert!(st.referenced && st.servo_on && st.on_target);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn daisy_chain_two_controllers_on_one_line() {
    let r = rig(true).await;
    assert_eq!(r.sim().link(AxisName::X), r.sim().link(AxisName::Y));
    assert_ne!(
        r.stage.x.identity().serial,
        r.stage.y.identity().serial,
        "two controllers"
    );
    reference_both(&r).await;
    let (a, b) = tokio::join!(
        r.stage.x.move_abs_um(1_000.0),
        r.stage.y.move_abs_um(9_000.0)
    );
    a.unwrap();
    b.unwrap();
    let (a, b) = tokio::join!(
        r.stage.x.wait_on_target(None),
        r.stage.y.wait_on_target(None)
    );
    assert_close(a.unwrap(), 1_000.0, 0.5);
    assert_close(b.unwrap(), 9_000.0, 0.5);
    assert_close(r.truth_um(AxisName::X), 1_000.0, 0.5);
    assert_close(r.truth_um(AxisName::Y), 9_000.0, 0.5);
    // Power-cycling Y leaves X alone.
    r.inject(AxisName::Y, Fault::PowerCycle);
    assert_close(r.stage.x.position_um().await.unwrap(), 1_000.0, 0.5);
    assert!(matches!(
        r.stage.y.position_um().await,
        Err(DriverError::NotReferenced { .. })
    ));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn pulled_cable_clear_error_no_position_then_recovery() {
    let mut r = rig(false).await;
    reference_both(&r).await;
    move_and_check(&r.stage.x, &r, AxisName::X, 5_000.0).await;
    r.events();
    r.inject(AxisName::X, Fault::DropLine);
    tokio::time::sleep(Duration::from_millis(100)).await;
    for _ in 0..3 {
        match r.stage.x.position_um().await {
            Err(DriverError::Disconnected { line, .. }) => {
                assert_eq!(line, r.sim().link(AxisName::X).display().to_string())
            }
            other => panic!("expected Disconnected, got {other:?}"),
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    // The other axis is not affected.
    assert_close(r.stage.y.position_um().await.unwrap(), 7_500.0, 0.5);
    assert!(r
        .events()
        .iter()
        .any(|e| matches!(e, AxisEvent::Disconnected { .. })));
    r.inject(AxisName::X, Fault::RestoreLine);
    let p = eventually(Duration::from_secs(5), || r.stage.x.position_um()).await;
    assert_close(p, 5_000.0, 0.5);
    assert!(r
        .events()
        .iter()
        .any(|e| matches!(e, AxisEvent::Connected { .. })));
    move_and_check(&r.stage.x, &r, AxisName::X, 6_000.0).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn power_cycle_loses_reference_until_referenced_again() {
    let mut r = rig(false).await;
    reference_both(&r).await;
    move_and_check(&r.stage.x, &r, AxisName::X, 3_000.0).await;
    r.events();
    r.inject(AxisName::X, Fault::PowerCycle);
    assert!(matches!(
        r.stage.x.position_um().await,
        Err(DriverError::NotReferenced { .. })
    ));
    assert!(r
        .events()
        .contains(&AxisEvent::ReferenceLost { axis: "x".into() }));
    assert!(matches!(
        r.stage.x.move_abs_um(4_000.0).await,
        Err(DriverError::NotReferenced { .. })
    ));
    assert_eq!(r.stage.x.status().await.unwrap().position_um, None);
    // Still refused later: no false position ever.
    tokio::time::sleep(Duration::from_millis(200)).await;
    assert!(r.stage.x.position_um().await.is_err());
    let p = r.stage.x.reference().await.unwrap();
    assert_close(p, 7_500.0, 0.5);
    move_and_check(&r.stage.x, &r, AxisName::X, 4_000.0).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn pulled_cable_and_power_cycle_together() {
    let r = rig(false).await;
    reference_both(&r).await;
    r.inject(AxisName::Y, Fault::DropLine);
    r.inject(AxisName::Y, Fault::PowerCycle);
    r.inject(AxisName::Y, Fault::RestoreLine);
    let e = eventually(Duration::from_secs(5), || async {
        match r.stage.y.position_um().await {
            Err(e @ DriverError::NotReferenced { .. }) => Ok(e),
            Ok(p) => panic!("false position {p} after a power cycle"),
            Err(e) => Err(e),
        }
    })
    .await;
    assert!(e.to_string().contains("not referenced"));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn garbage_on_the_line_is_dropped_or_refused_never_attributed() {
    let mut r = rig(false).await;
    reference_both(&r).await;
    move_and_check(&r.stage.x, &r, AxisName::X, 8_000.0).await;
    r.events();
    let garbage: [&[u8]; 4] = [
        b"\xff\x00\x13noise",
        b"1=3.0000000\n",
        b"0 1 1=2.5\n",
        b"\xb1\n",
    ];
    for g in garbage {
        r.inject(AxisName::X, Fault::Garbage(g.to_vec()));
        for _ in 0..3 {
            match r.stage.x.position_um().await {
                Ok(p) => assert_close(p, 8_000.0, 0.5),
                Err(e) => assert!(e.is_link_fault(), "{e}"),
            }
        }
    }
    assert!(r
        .events()
        .iter()
        .any(|e| matches!(e, AxisEvent::Noise { .. })));
    // A burst while a query is in flight.
    let x = r.stage.x.clone();
    let q = tokio::spawn(async move {
        let mut v = Vec::new();
        for _ in 0..20 {
            v.push(x.position_um().await);
        }
        v
    });
    for _ in 0..5 {
        r.inject(AxisName::X, Fault::Garbage(b"1=9.9\n\xfe".to_vec()));
        tokio::time::sleep(Duration::from_millis(3)).await;
    }
    for res in q.await.unwrap() {
        match res {
            Ok(p) => assert_close(p, 8_000.0, 0.5),
            Err(e) => assert!(e.is_link_fault(), "{e}"),
        }
    }
    let p = eventually(Duration::from_secs(2), || r.stage.x.position_um()).await;
    assert_close(p, 8_000.0, 0.5);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn withheld_replies_not_answering_then_recovery() {
    let mut r = rig(false).await;
    reference_both(&r).await;
    r.events();
    r.inject(AxisName::Y, Fault::WithholdReplies(true));
    match r.stage.y.position_um().await {
        Err(e @ DriverError::NotAnswering { .. }) => {
            assert!(e.to_string().contains("baud rate"))
        }
        other => panic!("{other:?}"),
    }
    assert!(r
        .events()
        .iter()
        .any(|e| matches!(e, AxisEvent::Fault { .. })));
    assert!(r.stage.y.move_abs_um(8_000.0).await.is_err());
    r.inject(AxisName::Y, Fault::WithholdReplies(false));
    let p = eventually(Duration::from_secs(3), || r.stage.y.position_um()).await;
    // The MOV sent while replies were withheld was executed by the
    // controller: whatever the position, it is the controller's real one.
    assert_close(p, r.truth_um(AxisName::Y), 0.5);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn replies_later_than_the_timeout() {
    let r = rig(false).await;
    reference_both(&r).await;
    move_and_check(&r.stage.x, &r, AxisName::X, 6_000.0).await;
    r.inject(
        AxisName::X,
        Fault::DelayReplies(Duration::from_millis(TIMEOUT_MS * 3 / 2)),
    );
    for _ in 0..3 {
        match r.stage.x.position_um().await {
            Ok(p) => panic!("answer attributed despite the timeout: {p}"),
            Err(e) => assert!(
                matches!(
                    e,
                    DriverError::NotAnswering { .. }
                        | DriverError::Timeout { .. }
                        | DriverError::BadAnswer { .. }
                ),
                "{e}"
            ),
        }
    }
    // Delays within the timeout are fine.
    r.inject(
        AxisName::X,
        Fault::DelayReplies(Duration::from_millis(TIMEOUT_MS / 4)),
    );
    let p = eventually(Duration::from_secs(3), || r.stage.x.position_um()).await;
    assert_close(p, 6_000.0, 0.5);
    r.inject(AxisName::X, Fault::DelayReplies(Duration::ZERO));
    for _ in 0..5 {
        assert_close(r.stage.x.position_um().await.unwrap(), 6_000.0, 0.5);
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn missing_device_is_a_clear_error() {
    let mut cfg = DriverConfig::default();
    cfg.x.port = "/nonexistent/x".into();
    cfg.y.port = "/nonexistent/y".into();
    let (tx, _rx) = broadcast::channel(8);
    match Stage::connect(&cfg, tx).await {
        Err(e @ DriverError::NoDevice { .. }) => assert!(e.to_string().contains("/nonexistent/x")),
        other => panic!("{other:?}"),
    }
}

/// The driver's data recorder calls over the pty: `TNR?`, `DRC`/`RTR`,
/// `DRT` (immediately), `DRL?`, `DRR?` parsed into µm. The records are
/// 1 ms apart, climb through the move and agree with `POS?` where the
/// axis rests (before the move and after it).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn data_recorder_over_the_pty() {
    let r = rig(false).await;
    let x = r.stage.x.clone();
    reference_both(&r).await;
    assert_eq!(x.recorder_tables().await.unwrap(), Some(2));
    x.record_actual_position(1, 20).await.unwrap();
    x.set_velocity_um_per_s(1000.0).await.unwrap();
    x.trigger_recorder(1).await.unwrap();
    x.move_abs_um(7_800.0).await.unwrap();
    assert_close(x.wait_on_target(None).await.unwrap(), 7_800.0, 1e-3);
    // The move takes 0.3 s of 1.024 s of table at time scale 20: the
    // table is full (or nearly) by now.
    tokio::time::sleep(Duration::from_millis(100)).await;
    let (n, _) = x.recorded_points(1).await.unwrap();
    assert!(n > 300 && n <= 1024, "{n} records");
    let rec = x.read_records(1, 1, n).await.unwrap();
    assert_close(rec.sample_time_s, 0.001, 1e-12);
    assert_eq!(rec.positions_um.len(), n as usize);
    let p = &rec.positions_um;
    assert!(p.windows(2).all(|w| w[1] >= w[0] - 1e-6), "monotone");
    assert_close(p[0], 7_500.0, 1e-3);
    assert_close(*p.last().unwrap(), 7_800.0, 1e-3);
    // Part of the table, and nothing beyond it.
    let part = x.read_records(1, 11, 5).await.unwrap();
    assert_eq!(part.positions_um, p[10..15].to_vec());
    let none = x.read_records(1, 2000, 5).await.unwrap();
    assert!(none.positions_um.is_empty());
}
