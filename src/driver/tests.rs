//! Driver logic against the fake controller over in-memory streams, with a
//! paused tokio clock (deterministic, no real waiting).

use super::fake::{duplex_connector, Fake};
use super::*;
use crate::gcs::frame::Address;
use crate::gcs::{AxisId, Command, GcsErrorCode};
use std::time::Duration;
use tokio::io::DuplexStream;
use tokio::sync::{broadcast, mpsc};

const T: Duration = Duration::from_millis(200);

struct FakeLine {
    fake: Fake,
    feed: mpsc::UnboundedSender<DuplexStream>,
    line: Line,
    events: broadcast::Sender<AxisEvent>,
    rx: broadcast::Receiver<AxisEvent>,
    garbage: mpsc::UnboundedSender<Vec<u8>>,
}

impl FakeLine {
    async fn new(addresses: &[u8]) -> FakeLine {
        let fake = Fake::new(addresses);
        let (conn, feed) = duplex_connector();
        let (host, dev) = tokio::io::duplex(4096);
        let garbage = fake.serve(dev);
        feed.send(host).unwrap();
        let (events, rx) = broadcast::channel(256);
        let line = Line::open(conn, LineOptions::default(), events.clone())
            .await
            .unwrap();
        FakeLine {
            fake,
            feed,
            line,
            events,
            rx,
            garbage,
        }
    }

    fn controller(&self, addr: Option<u8>) -> Controller {
        Controller::new(
            self.line.clone(),
            addr.map(|a| Address::new(a).unwrap()),
            T,
            self.events.clone(),
        )
    }

    async fn axis(&self, name: &str, addr: Option<u8>) -> Result<Axis, DriverError> {
        Axis::bring_up(self.controller(addr), params(name), self.events.clone()).await
    }

    /// Pulls the cable: the fake side closes.
    fn pull(&self) {
        self.garbage.send(Vec::new()).unwrap();
    }

    /// Plugs a new cable to the same controller(s).
    fn plug(&mut self) {
        let (host, dev) = tokio::io::duplex(4096);
        self.garbage = self.fake.serve(dev);
        self.feed.send(host).unwrap();
    }

    fn drain_events(&mut self) -> Vec<AxisEvent> {
        let mut v = Vec::new();
        while let Ok(e) = self.rx.try_recv() {
            v.push(e);
        }
        v
    }
}

fn params(name: &str) -> AxisParams {
    AxisParams {
        name: name.to_owned(),
        axis: AxisId::new("1").unwrap(),
        reference: ReferenceMode::Frf,
        reference_timeout: Duration::from_secs(10),
        motion_timeout: Duration::from_secs(60),
        poll_interval: Duration::from_millis(20),
    }
}

async fn referenced_axis(rig: &FakeLine) -> Axis {
    let ax = rig.axis("x", None).await.unwrap();
    assert_eq!(ax.reference().await.unwrap(), 7500.0);
    ax
}

#[tokio::test(start_paused = true)]
async fn bring_up_reference_and_moves_in_micrometres() {
    let mut rig = FakeLine::new(&[1]).await;
    let ax = rig.axis("x", None).await.unwrap();
    assert_eq!(ax.identity().model, "C-863.11");
    assert_eq!(ax.travel_um(), (0.0, 15_000.0));
    // Power-up state: no position until referenced.
    assert!(matches!(
        ax.position_um().await,
        Err(DriverError::NotReferenced { .. })
    ));
    assert!(matches!(
        ax.move_abs_um(1000.0).await,
        Err(DriverError::NotReferenced { .. })
    ));
    assert_eq!(ax.reference().await.unwrap(), 7500.0);
    assert!(rig
        .drain_events()
        .contains(&AxisEvent::Referenced { axis: "x".into() }));
    ax.set_velocity_um_per_s(500.0).await.unwrap();
    assert_eq!(ax.velocity_um_per_s().await.unwrap(), 500.0);
    ax.move_abs_um(10_000.0).await.unwrap();
    assert!(ax.is_moving().await.unwrap());
    assert_eq!(ax.wait_on_target(None).await.unwrap(), 10_000.0);
    assert!(!ax.is_moving().await.unwrap());
    ax.move_rel_um(-2_500.5).await.unwrap();
    assert_eq!(ax.wait_on_target(None).await.unwrap(), 7_499.5);
    assert!((rig.fake.axis(1, |a| a.target_mm) - 7.4995).abs() < 1e-12);
    let st = ax.status().await.unwrap();
    assert!(st.referenced && st.servo_on && st.on_target);
    assert_eq!(st.position_um, Some(7_499.5));
    // Out of travel: refused before sending anything.
    match ax.move_abs_um(15_000.1).await {
        Err(DriverError::OutOfTravel {
            target_um,
            min_um,
            max_um,
            ..
        }) => assert_eq!((target_um, min_um, max_um), (15_000.1, 0.0, 15_000.0)),
        other => panic!("{other:?}"),
    }
    assert!(matches!(
        ax.move_rel_um(-8_000.0).await,
        Err(DriverError::OutOfTravel { .. })
    ));
    assert!(matches!(
        ax.move_abs_um(f64::NAN).await,
        Err(DriverError::Invalid(_))
    ));
    assert!(ax.set_velocity_um_per_s(-1.0).await.is_err());
    assert!((rig.fake.axis(1, |a| a.target_mm) - 7.4995).abs() < 1e-12);
    // The controller's own refusal comes back with PI's name.
    match ax.set_velocity_um_per_s(5_000.0).await {
        Err(DriverError::Gcs { code, command }) => {
            assert_eq!(code, GcsErrorCode::VEL_OUT_OF_LIMITS);
            assert_eq!(command, "VEL 1 5");
        }
        other => panic!("{other:?}"),
    }
}

#[tokio::test(start_paused = true)]
async fn silence_is_unknown_command_or_not_answering() {
    let rig = FakeLine::new(&[1]).await;
    let ctl = rig.controller(None);
    // The fake does not know HPA?: silence, then ERR? = 2.
    match ctl.query(&Command::Hpa).await {
        Err(DriverError::Gcs { code, command }) => {
            assert_eq!(code, GcsErrorCode::UNKNOWN_COMMAND);
            assert_eq!(command, "HPA?");
        }
        other => panic!("{other:?}"),
    }
    let r = ctl.console("XYZ? 1").await.unwrap();
    assert!(r.silent && r.answer.is_none());
    assert_eq!(r.error, GcsErrorCode::UNKNOWN_COMMAND);
    let r = ctl.console("POS? 1").await.unwrap();
    assert_eq!(r.answer.unwrap().text(), "1=0.0000000");
    assert_eq!(r.error, GcsErrorCode::NO_ERROR);
    let r = ctl.console("#7").await.unwrap();
    assert_eq!(r.answer.unwrap().raw_lines(), &[vec![0xB1]]);
    // Nothing answers at all.
    rig.fake.with(|b| b.silent = true);
    assert!(matches!(
        ctl.query(&Command::Idn).await,
        Err(DriverError::NotAnswering { .. })
    ));
    assert!(matches!(
        rig.axis("x", None).await,
        Err(DriverError::NotAnswering { .. })
    ));
    rig.fake.with(|b| b.silent = false);
    assert!(rig.axis("x", None).await.is_ok());
}

#[tokio::test(start_paused = true)]
async fn non_pi_and_non_c863_are_refused() {
    let rig = FakeLine::new(&[1]).await;
    rig.fake.axis(1, |a| a.idn = "Arduino Uno".into());
    match rig.axis("x", None).await {
        Err(DriverError::NotPi { idn, .. }) => assert_eq!(idn, "Arduino Uno"),
        other => panic!("{other:?}"),
    }
    rig.fake.axis(1, |a| {
        a.idn = "(c)2019 Physik Instrumente (PI) GmbH & Co. KG, E-709.CHG, 1, 1".into()
    });
    assert!(matches!(
        rig.axis("x", None).await,
        Err(DriverError::NotC863 { model, .. }) if model == "E-709.CHG"
    ));
}

#[tokio::test(start_paused = true)]
async fn halt_stops_the_move_and_the_waiter() {
    let rig = FakeLine::new(&[1]).await;
    let ax = referenced_axis(&rig).await;
    ax.move_abs_um(14_000.0).await.unwrap();
    let waiter = {
        let ax = ax.clone();
        tokio::spawn(async move { ax.wait_on_target(None).await })
    };
    tokio::time::sleep(Duration::from_secs(2)).await;
    ax.halt().await.unwrap();
    assert!(matches!(
        waiter.await.unwrap(),
        Err(DriverError::Halted { .. })
    ));
    let p = ax.position_um().await.unwrap();
    assert!(p > 7_500.0 && p < 14_000.0, "{p}");
    // Error 10 was consumed by halt(): the next command is clean.
    assert_eq!(
        ax.controller().error().await.unwrap(),
        GcsErrorCode::NO_ERROR
    );
    // Raw access reports error 10 as the controller does.
    let r = ax.controller().console("HLT 1").await.unwrap();
    assert_eq!(r.error, GcsErrorCode::STOPPED);
    ax.move_abs_um(8_000.0).await.unwrap();
    ax.stop().await.unwrap();
    assert!(matches!(
        ax.wait_on_target(None).await,
        Err(DriverError::Halted { .. })
    ));
}

/// A halt whose `ERR?` never came (its caller went away after the urgent
/// `HLT`, as a cancelled job's does) leaves error 10 in the register; the
/// next command reads it first, so it is not reported refused by it.
#[tokio::test(start_paused = true)]
async fn an_abandoned_halt_does_not_refuse_the_next_move() {
    let rig = FakeLine::new(&[1]).await;
    let ax = referenced_axis(&rig).await;
    ax.move_abs_um(9_000.0).await.unwrap();
    assert!(!rig.line.error_unread(None));
    rig.line
        .urgent_command(None, &Command::Hlt(vec![AxisId::new("1").unwrap()]))
        .await
        .unwrap();
    assert!(rig.line.error_unread(None));
    ax.move_abs_um(8_000.0).await.unwrap();
    assert!(!rig.line.error_unread(None));
    assert_eq!(ax.wait_on_target(None).await.unwrap(), 8_000.0);
    assert_eq!(
        ax.controller().error().await.unwrap(),
        GcsErrorCode::NO_ERROR
    );
}

/// A command sent without its `ERR?` (a caller that went away) whose
/// controller refused it leaves a code other than 10: the next command is
/// not sent and says which code was waiting; nothing is lost.
#[tokio::test(start_paused = true)]
async fn a_waiting_refusal_is_reported_and_the_next_command_not_sent() {
    let rig = FakeLine::new(&[1]).await;
    let ax = referenced_axis(&rig).await;
    let ctl = ax.controller().clone();
    let vel = |v: f64| Command::Vel(vec![(AxisId::new("1").unwrap(), v)]);
    rig.line
        .exchange(None, crate::gcs::Outgoing::Command(vel(99.0)), T)
        .await
        .unwrap();
    match ctl.set(&vel(0.5)).await {
        Err(DriverError::PendingError { code, command, .. }) => {
            assert_eq!(code, GcsErrorCode::VEL_OUT_OF_LIMITS);
            assert_eq!(command, "VEL 1 0.5");
        }
        other => panic!("{other:?}"),
    }
    // Not sent: the velocity is the one before.
    assert_ne!(ax.velocity_um_per_s().await.unwrap(), 500.0);
    ctl.set(&vel(0.5)).await.unwrap();
    assert_eq!(ax.velocity_um_per_s().await.unwrap(), 500.0);
}

/// A halt during the reference move leaves the controller ready and
/// unreferenced with its error 10 consumed by the halt: the reference
/// says it was halted, not that the controller gave up.
#[tokio::test(start_paused = true)]
async fn a_halt_during_referencing_reads_as_halted() {
    let rig = FakeLine::new(&[1]).await;
    let ax = rig.axis("x", None).await.unwrap();
    let referencing = {
        let ax = ax.clone();
        tokio::spawn(async move { ax.reference().await })
    };
    tokio::time::sleep(Duration::from_millis(300)).await;
    ax.halt().await.unwrap();
    match referencing.await.unwrap() {
        Err(DriverError::Halted { axis }) => assert_eq!(axis, "x"),
        other => panic!("{other:?}"),
    }
    assert!(!ax.is_referenced().await.unwrap());
    // A reference after it is not disturbed by the old halt.
    assert_eq!(ax.reference().await.unwrap(), 7500.0);
}

#[tokio::test(start_paused = true)]
async fn pulled_cable_gives_clear_errors_then_recovers() {
    let mut rig = FakeLine::new(&[1]).await;
    let ax = referenced_axis(&rig).await;
    rig.drain_events();
    rig.pull();
    tokio::time::sleep(Duration::from_millis(10)).await;
    match ax.position_um().await {
        Err(DriverError::Disconnected { line, .. }) => assert_eq!(line, "fake"),
        other => panic!("{other:?}"),
    }
    // Still down: reopening fails and says so.
    tokio::time::sleep(Duration::from_millis(500)).await;
    match ax.position_um().await {
        Err(DriverError::Disconnected { reason, .. }) => {
            assert!(reason.contains("reopening fails"), "{reason}")
        }
        other => panic!("{other:?}"),
    }
    rig.plug();
    tokio::time::sleep(Duration::from_secs(2)).await;
    assert_eq!(ax.position_um().await.unwrap(), 7500.0);
    let ev = rig.drain_events();
    assert!(ev
        .iter()
        .any(|e| matches!(e, AxisEvent::Disconnected { .. })));
    assert!(ev.contains(&AxisEvent::Connected {
        line: "fake".into()
    }));
}

#[tokio::test(start_paused = true)]
async fn power_cycle_refuses_positions_until_referenced() {
    let mut rig = FakeLine::new(&[1]).await;
    let ax = referenced_axis(&rig).await;
    ax.set_velocity_um_per_s(700.0).await.unwrap();
    ax.move_abs_um(9_000.0).await.unwrap();
    ax.wait_on_target(None).await.unwrap();
    rig.drain_events();
    rig.fake.axis(1, |a| a.power_cycle());
    assert!(matches!(
        ax.position_um().await,
        Err(DriverError::NotReferenced { .. })
    ));
    assert_eq!(
        rig.drain_events(),
        vec![AxisEvent::ReferenceLost { axis: "x".into() }]
    );
    assert!(matches!(
        ax.move_abs_um(5_000.0).await,
        Err(DriverError::NotReferenced { .. })
    ));
    assert!(matches!(
        ax.target_um().await,
        Err(DriverError::NotReferenced { .. })
    ));
    assert_eq!(ax.status().await.unwrap().position_um, None);
    assert_eq!(ax.reference().await.unwrap(), 7500.0);
    // The velocity set before the power cycle is back.
    assert_eq!(ax.velocity_um_per_s().await.unwrap(), 700.0);
}

#[tokio::test(start_paused = true)]
async fn garbage_is_never_taken_for_an_answer() {
    let mut rig = FakeLine::new(&[1]).await;
    let ax = referenced_axis(&rig).await;
    // While idle, with and without a line feed: dropped, reported, harmless.
    rig.garbage.send(b"\xff\x00noise".to_vec()).unwrap();
    tokio::time::sleep(Duration::from_millis(5)).await;
    assert_eq!(ax.position_um().await.unwrap(), 7500.0);
    rig.garbage.send(b"1=3.0000000\n".to_vec()).unwrap();
    tokio::time::sleep(Duration::from_millis(5)).await;
    assert_eq!(ax.position_um().await.unwrap(), 7500.0);
    assert!(rig
        .drain_events()
        .iter()
        .any(|e| matches!(e, AxisEvent::Noise { .. })));
    // Garbage that lands in the middle of an exchange: a clear error, never a number.
    rig.fake.with(|b| b.delay = Duration::from_millis(50));
    let garbage = rig.garbage.clone();
    let inject = tokio::spawn(async move {
        tokio::time::sleep(Duration::from_millis(10)).await;
        garbage.send(b"\x13\xfe".to_vec()).unwrap();
    });
    let r = ax.position_um().await;
    inject.await.unwrap();
    assert!(matches!(r, Err(DriverError::BadAnswer { .. })), "{r:?}");
    rig.fake.with(|b| b.delay = Duration::ZERO);
    assert_eq!(ax.position_um().await.unwrap(), 7500.0);
    assert_eq!(ax.position_um().await.unwrap(), 7500.0);
}

#[tokio::test(start_paused = true)]
async fn late_replies_are_dropped_not_misattributed() {
    let rig = FakeLine::new(&[1]).await;
    let ax = referenced_axis(&rig).await;
    ax.move_abs_um(9_000.0).await.unwrap();
    ax.wait_on_target(None).await.unwrap();
    rig.fake.with(|b| b.delay = T + T / 2);
    let r = ax.position_um().await;
    assert!(
        matches!(
            r,
            Err(DriverError::NotAnswering { .. } | DriverError::Timeout { .. })
        ),
        "{r:?}"
    );
    rig.fake.with(|b| b.delay = Duration::ZERO);
    for _ in 0..3 {
        assert_eq!(ax.position_um().await.unwrap(), 9_000.0);
        assert!(ax.is_referenced().await.unwrap());
    }
}

#[tokio::test(start_paused = true)]
async fn withheld_replies_then_recovery() {
    let rig = FakeLine::new(&[1]).await;
    let ax = referenced_axis(&rig).await;
    rig.fake.with(|b| b.silent = true);
    assert!(matches!(
        ax.position_um().await,
        Err(DriverError::NotAnswering { .. })
    ));
    rig.fake.with(|b| b.silent = false);
    assert_eq!(ax.position_um().await.unwrap(), 7500.0);
}

#[tokio::test(start_paused = true)]
async fn daisy_chain_serves_two_addresses() {
    let rig = FakeLine::new(&[1, 2]).await;
    let x = rig.axis("x", Some(1)).await.unwrap();
    let y = rig.axis("y", Some(2)).await.unwrap();
    let (a, b) = tokio::join!(x.reference(), y.reference());
    assert_eq!((a.unwrap(), b.unwrap()), (7500.0, 7500.0));
    let (a, b) = tokio::join!(x.move_abs_um(1_000.0), y.move_abs_um(12_000.0));
    a.unwrap();
    b.unwrap();
    let (a, b) = tokio::join!(x.wait_on_target(None), y.wait_on_target(None));
    assert_eq!((a.unwrap(), b.unwrap()), (1_000.0, 12_000.0));
    assert_eq!(rig.fake.axis(1, |a| a.target_mm), 1.0);
    assert_eq!(rig.fake.axis(2, |a| a.target_mm), 12.0);
    // A power cycle of one controller does not touch the other.
    rig.fake.axis(2, |a| a.power_cycle());
    assert_eq!(x.position_um().await.unwrap(), 1_000.0);
    assert!(matches!(
        y.position_um().await,
        Err(DriverError::NotReferenced { .. })
    ));
    // Nobody at address 3.
    assert!(matches!(
        rig.axis("z", Some(3)).await,
        Err(DriverError::NotAnswering { .. })
    ));
}

#[tokio::test(start_paused = true)]
async fn a_different_controller_after_reconnect_is_refused() {
    let mut rig = FakeLine::new(&[1]).await;
    let ax = referenced_axis(&rig).await;
    rig.pull();
    rig.fake.axis(1, |a| {
        a.idn = "(c)2015 Physik Instrumente (PI) GmbH & Co. KG, C-863.11, 999, 01.110".into()
    });
    rig.plug();
    tokio::time::sleep(Duration::from_secs(2)).await;
    assert!(matches!(
        ax.position_um().await,
        Err(DriverError::ControllerChanged { .. })
    ));
}

/// A two-axis move is all or nothing: an unreferenced axis refuses it
/// before anything is sent; a controller that still refuses its `MOV`
/// (servo off) has the other axis, which had started, halted.
#[tokio::test(start_paused = true)]
async fn a_two_axis_move_is_all_or_nothing() {
    let rig = FakeLine::new(&[1, 2]).await;
    let x = rig.axis("x", Some(1)).await.unwrap();
    let y = rig.axis("y", Some(2)).await.unwrap();
    assert_eq!(x.reference().await.unwrap(), 7500.0);
    let stage = Stage::from_axes(x.clone(), y.clone(), rig.events.clone());
    let e = stage.move_abs_both_um(12_000.0, 9_000.0).await.unwrap_err();
    assert!(
        matches!(&e, DriverError::NotReferenced { axis } if axis == "y"),
        "{e}"
    );
    assert_eq!(rig.fake.axis(1, |a| a.target_mm), 7.5, "x was sent a move");

    assert_eq!(y.reference().await.unwrap(), 7500.0);
    rig.fake.axis(2, |a| a.servo = false);
    let e = stage.move_abs_both_um(12_000.0, 9_000.0).await.unwrap_err();
    assert!(
        matches!(&e, DriverError::OtherAxisHalted { refused, halted }
            if halted == "x" && matches!(**refused, DriverError::ServoOff { .. })),
        "{e}"
    );
    tokio::time::sleep(Duration::from_secs(1)).await;
    let now = tokio::time::Instant::now();
    let (pos, target) = rig.fake.axis(1, |a| (a.pos_mm(now), a.target_mm));
    assert_eq!(pos, target, "x still moving");
    assert!(pos < 8.0, "x ran to {pos} mm");

    rig.fake.axis(2, |a| a.servo = true);
    stage.move_abs_both_um(8_000.0, 9_000.0).await.unwrap();
    let (a, b) = tokio::join!(x.wait_on_target(None), y.wait_on_target(None));
    assert_eq!((a.unwrap(), b.unwrap()), (8_000.0, 9_000.0));
}

/// A controller keeps the move it had when its line dropped; the first
/// bytes on the re-opened line stop it (`#24`), within one reopen delay of
/// the line's return, before anyone asks anything. Its error 10 is then
/// not taken for the refusal of the next command.
#[tokio::test(start_paused = true)]
async fn a_reopened_line_stops_the_controller_first() {
    let mut rig = FakeLine::new(&[1]).await;
    let ax = referenced_axis(&rig).await;
    ax.move_abs_um(14_000.0).await.unwrap(); // 6.5 mm at 1 mm/s
    tokio::time::sleep(Duration::from_secs(1)).await;
    rig.pull();
    // Down for 1 s: the move runs on, unwatched.
    tokio::time::sleep(Duration::from_secs(1)).await;
    rig.plug();
    let bound = LineOptions::default().reconnect_max + Duration::from_millis(20);
    tokio::time::sleep(bound).await;
    let (pos_mm, target_mm, error) = rig.fake.axis(1, |a| {
        (a.pos_mm(tokio::time::Instant::now()), a.target_mm, a.error)
    });
    assert_eq!(
        pos_mm, target_mm,
        "still moving {bound:?} after the line came back"
    );
    // At 1 mm/s from 7.5 mm, 2 s (and a few exchanges) before the line came
    // back: it ran on at most `bound` after that.
    let ran_on_mm = pos_mm - 9.5;
    assert!(
        ran_on_mm <= bound.as_secs_f64() + 0.05,
        "ran on {ran_on_mm} mm after the line came back"
    );
    assert_eq!(error, 10, "the stop is what set the register");
    // The next move is not refused by the stop's error 10.
    ax.move_abs_um(9_000.0).await.unwrap();
    assert_eq!(ax.wait_on_target(None).await.unwrap(), 9_000.0);
}

#[tokio::test(start_paused = true)]
async fn dropping_handles_ends_the_line_task_without_sending() {
    let rig = FakeLine::new(&[1]).await;
    let ax = referenced_axis(&rig).await;
    ax.move_abs_um(14_000.0).await.unwrap();
    let fake = rig.fake.clone();
    drop(ax);
    drop(rig);
    tokio::time::sleep(Duration::from_secs(10)).await;
    // Nothing halted the move: the controller finished it on its own.
    assert_eq!(
        fake.axis(1, |a| a.pos_mm(tokio::time::Instant::now())),
        14.0
    );
}

/// The real serial path: `tokio-serial` on a pty, the fake on the master.
#[tokio::test]
async fn serial_connector_on_a_pty_and_hangup() {
    use tokio_serial::SerialPort;
    let (master, slave) = tokio_serial::SerialStream::pair().unwrap();
    let path = slave.name().unwrap();
    drop(slave);
    let fake = Fake::new(&[1]);
    let kill = fake.serve(master);
    let (events, _rx) = broadcast::channel(64);
    let line = Line::open(
        SerialConnector::new(&path, SerialSettings::default()),
        LineOptions::default(),
        events.clone(),
    )
    .await
    .unwrap();
    let ctl = Controller::new(line, None, Duration::from_millis(500), events.clone());
    let ax = Axis::bring_up(ctl, params("x"), events).await.unwrap();
    assert!(matches!(
        ax.position_um().await,
        Err(DriverError::NotReferenced { .. })
    ));
    // Close the master: the host side sees a hangup.
    kill.send(Vec::new()).unwrap();
    tokio::time::sleep(Duration::from_millis(100)).await;
    let r = ax.position_um().await;
    assert!(matches!(r, Err(DriverError::Disconnected { .. })), "{r:?}");
}

#[tokio::test(start_paused = true)]
async fn garbage_shaped_like_an_answer_is_not_trusted() {
    let rig = FakeLine::new(&[1]).await;
    let ax = referenced_axis(&rig).await;
    rig.fake.with(|b| b.delay = Duration::from_millis(50));
    let garbage = rig.garbage.clone();
    let inject = tokio::spawn(async move {
        tokio::time::sleep(Duration::from_millis(10)).await;
        garbage.send(b"1=9.9000000\n".to_vec()).unwrap();
    });
    let r = ax.position_um().await;
    inject.await.unwrap();
    assert!(matches!(r, Err(DriverError::BadAnswer { .. })), "{r:?}");
    rig.fake.with(|b| b.delay = Duration::ZERO);
    assert_eq!(ax.position_um().await.unwrap(), 7500.0);
}

#[tokio::test(start_paused = true)]
async fn urgent_stop_overtakes_a_busy_line() {
    let rig = FakeLine::new(&[1]).await;
    let ax = referenced_axis(&rig).await;
    ax.move_abs_um(14_000.0).await.unwrap();
    // The controller stops answering: every query waits its timeout, then
    // its ERR? waits another; five of them queue on the line.
    rig.fake.with(|b| b.silent = true);
    let queued: Vec<_> = (0..5)
        .map(|_| {
            let ax = ax.clone();
            tokio::spawn(async move { ax.position_um().await })
        })
        .collect();
    tokio::time::sleep(Duration::from_millis(1)).await;
    let t = tokio::time::Instant::now();
    let ctl = ax.controller();
    ctl.line()
        .urgent(ctl.address(), crate::gcs::ControlChar::StopAll)
        .await
        .unwrap();
    // Written at once, not after the queue (≥ 5 × 2 × 200 ms).
    assert!(t.elapsed() < Duration::from_millis(5), "{:?}", t.elapsed());
    tokio::time::sleep(Duration::from_millis(1)).await;
    let target = rig.fake.axis(1, |a| a.target_mm);
    assert!(
        target > 7.5 && target < 14.0,
        "the controller did not stop: {target}"
    );
    for q in queued {
        assert!(q.await.unwrap().is_err());
    }
    // A command with an answer is not urgent.
    assert!(matches!(
        ctl.line()
            .urgent(None, crate::gcs::ControlChar::MotionStatus)
            .await,
        Err(DriverError::Invalid(_))
    ));
}

#[tokio::test(start_paused = true)]
async fn urgent_halt_overtakes_reads_that_time_out_and_their_resync() {
    let rig = FakeLine::new(&[1]).await;
    let ax = referenced_axis(&rig).await;
    ax.move_abs_um(14_000.0).await.unwrap();
    rig.fake.with(|b| b.silent = true);
    let queued: Vec<_> = (0..5)
        .map(|_| {
            let ax = ax.clone();
            tokio::spawn(async move { ax.position_um().await })
        })
        .collect();
    // The first read has timed out: the line now waits for a quiet answer
    // timeout before the next read, with four more queued behind it.
    tokio::time::sleep(T + Duration::from_millis(20)).await;
    let t = tokio::time::Instant::now();
    let ctl = ax.controller();
    ctl.line()
        .urgent_command(
            ctl.address(),
            &Command::Hlt(vec![AxisId::new("1").unwrap()]),
        )
        .await
        .unwrap();
    // Written at once, not after the resynchronisation and the queue.
    assert!(t.elapsed() < Duration::from_millis(5), "{:?}", t.elapsed());
    tokio::time::sleep(Duration::from_millis(1)).await;
    let target = rig.fake.axis(1, |a| a.target_mm);
    assert!(
        target > 7.5 && target < 14.0,
        "the controller did not halt: {target}"
    );
    for q in queued {
        assert!(q.await.unwrap().is_err());
    }
    // A query is not urgent.
    assert!(matches!(
        ctl.line()
            .urgent_command(None, &Command::PosQuery(vec![]))
            .await,
        Err(DriverError::Invalid(_))
    ));
    // `Axis::halt_now` on a line that answers again: HLT, then ERR? = 10.
    rig.fake.with(|b| b.silent = false);
    ax.move_abs_um(14_000.0).await.unwrap();
    ax.halt_now().await.unwrap();
    assert!(rig.fake.axis(1, |a| a.target_mm) < 14.0);
}

/// A controller without a data recorder (the fake knows no `TNR?`, `DRC`)
/// reads as having none, not as a fault: the sweep then polls `POS?`.
#[tokio::test(start_paused = true)]
async fn a_controller_without_a_data_recorder_reads_as_none() {
    let rig = FakeLine::new(&[1]).await;
    let ax = referenced_axis(&rig).await;
    assert_eq!(ax.recorder_tables().await.unwrap(), None);
    let e = ax.record_actual_position(1, 20).await.unwrap_err();
    assert_eq!(e.gcs_code(), Some(GcsErrorCode::UNKNOWN_COMMAND), "{e}");
    assert_eq!(ax.position_um().await.unwrap(), 7500.0);
}

/// A move from a known rest waits out the shortest profile the
/// controller's own `VEL?`/`ACC?`/`DEC?` allow, polling `ONT?` only every
/// 50 ms meanwhile (a halt is still seen), then every poll interval: it
/// is seen on target at the same instant as a move polled throughout (the
/// first move, whose start is not known), with far fewer polls.
#[tokio::test(start_paused = true)]
async fn a_move_from_rest_is_polled_sparsely_until_it_can_have_ended() {
    let rig = FakeLine::new(&[1]).await;
    let ax = referenced_axis(&rig).await;
    ax.set_velocity_um_per_s(500.0).await.unwrap();
    let polls = || rig.fake.axis(1, |a| a.ont_queries);
    // From the reference position: where the axis rests is not known yet.
    let n0 = polls();
    ax.move_abs_um(10_000.0).await.unwrap();
    let t0 = tokio::time::Instant::now();
    assert_eq!(ax.wait_on_target(None).await.unwrap(), 10_000.0);
    let (dense_s, dense) = (t0.elapsed(), polls() - n0);
    // 2.5 mm at 0.5 mm/s: 5 s, seen by a poll every 20 ms.
    assert!((dense_s.as_secs_f64() - 5.0).abs() <= 0.021, "{dense_s:?}");
    assert!(dense >= 250, "{dense} polls");
    // Back by the same distance from rest.
    let n1 = polls();
    ax.move_abs_um(7_500.0).await.unwrap();
    let t1 = tokio::time::Instant::now();
    assert_eq!(ax.wait_on_target(None).await.unwrap(), 7_500.0);
    let (sparse_s, sparse) = (t1.elapsed(), polls() - n1);
    assert_eq!(sparse_s, dense_s, "seen on target at another instant");
    assert!(sparse * 10 < dense * 6, "{sparse} polls against {dense}");
    // A halt during the sparse stretch is seen within 50 ms.
    ax.move_abs_um(10_000.0).await.unwrap();
    let ax2 = ax.clone();
    let wait = tokio::spawn(async move { ax2.wait_on_target(None).await });
    tokio::time::sleep(Duration::from_secs(1)).await;
    ax.halt().await.unwrap();
    let t2 = tokio::time::Instant::now();
    assert!(matches!(
        wait.await.unwrap(),
        Err(DriverError::Halted { .. })
    ));
    assert!(
        t2.elapsed() <= Duration::from_millis(50),
        "{:?}",
        t2.elapsed()
    );
    // Stopped short: the next move's start is unknown, every poll is made.
    let n3 = polls();
    ax.move_abs_um(7_500.0).await.unwrap();
    let t3 = tokio::time::Instant::now();
    ax.wait_on_target(None).await.unwrap();
    let every = t3.elapsed().as_millis() / 20;
    assert!(every >= 40, "{:?}", t3.elapsed());
    assert!(
        u128::from(polls() - n3) > every,
        "{} polls in {:?}",
        polls() - n3,
        t3.elapsed()
    );
}
