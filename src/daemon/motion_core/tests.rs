//! The move policy, rule by rule, and its invariants under random input
//! sequences (proptest). `try_move` drives the core as `Rig::raw_move`
//! does, without the driver: admission, targets within the range, the
//! move begun, sent and watched.

use super::*;
use crate::gcs::GcsErrorCode;
use proptest::prelude::*;

const RANGE: (f64, f64) = (0.0, 25_000.0);

fn bounds() -> Bounds {
    Bounds {
        following_error_um: 50.0,
        read_fail_s: 2.0,
        motion_timeout_s: [10.0, 20.0],
    }
}

/// Connected, both axes referenced, idle.
fn ready() -> MotionCore {
    let mut c = MotionCore::new(bounds(), 50.0);
    assert!(c
        .apply(
            Input::StageUp {
                referenced: [true, true],
            },
            0.0,
        )
        .is_empty());
    c
}

/// A raw move as `Rig::raw_move` makes it, queued at generation `gen`;
/// `bases`: what the controllers would answer for their targets.
fn try_move(
    c: &mut MotionCore,
    gen: u64,
    want: [Option<f64>; 2],
    relative: bool,
    bases: [f64; 2],
    t_s: f64,
) -> Result<[Option<f64>; 2], ProtoError> {
    c.admit_move(gen, [want[0].is_some(), want[1].is_some()], false)?;
    let mut targets = [None, None];
    for (i, a) in [AxisId::X, AxisId::Y].into_iter().enumerate() {
        let Some(v) = want[i] else { continue };
        let base = relative.then(|| c.commanded()[i].unwrap_or(bases[i]));
        targets[i] = Some(target_within(a, v, base, RANGE)?);
    }
    c.begin_move(t_s);
    c.move_sent(targets, [true, true], t_s, t_s + 0.001);
    assert!(c.watch_sent(gen, targets, t_s + 0.001));
    c.end(Activity::Moving, t_s + 0.002);
    Ok(targets)
}

fn halted() -> ProtoError {
    ProtoError::new(ErrorCode::Halted, "the move was halted")
}

#[test]
fn before_the_stage_connects_nothing_moves() {
    let c = MotionCore::new(bounds(), 50.0);
    let e = c.admit_move(0, [true, false], false).unwrap_err();
    assert_eq!(e.code, ErrorCode::NotConnected);
    assert!(e.message.contains("not connected yet"), "{}", e.message);
}

#[test]
fn an_unreferenced_axis_is_refused_the_other_moves() {
    let mut c = MotionCore::new(bounds(), 50.0);
    c.apply(
        Input::StageUp {
            referenced: [true, false],
        },
        0.0,
    );
    let e = c.admit_move(0, [false, true], false).unwrap_err();
    assert_eq!(e.code, ErrorCode::NotReferenced);
    assert_eq!(
        e.message,
        "axis y is not referenced; send reference first (CLI: `micropos reference y`)"
    );
    assert!(c.admit_move(0, [true, false], false).is_ok());
}

#[test]
fn a_reference_run_or_a_job_owns_the_axes() {
    let mut c = ready();
    c.begin_reference(1.0).unwrap();
    let e = c.admit_move(0, [true, false], true).unwrap_err();
    assert_eq!(e.code, ErrorCode::Busy);
    assert_eq!(
        e.message,
        "the axes are busy (Referencing); stop it or wait"
    );
    assert_eq!(c.begin_job(1.1).unwrap_err().code, ErrorCode::Busy);
    c.end(Activity::Referencing, 2.0);
    c.begin_job(3.0).unwrap();
    // The job's own moves go, a client's are refused.
    assert!(c.admit_move(0, [true, true], true).is_ok());
    assert_eq!(
        c.admit_move(0, [true, true], false).unwrap_err().code,
        ErrorCode::Busy
    );
    c.end(Activity::Job, 4.0);
    assert!(c.admit_move(0, [true, true], false).is_ok());
}

#[test]
fn a_fault_latches_halts_and_only_reset_clears_it() {
    let mut c = ready();
    try_move(&mut c, 0, [Some(100.0), Some(200.0)], false, [0.0; 2], 1.0).unwrap();
    assert_eq!(c.watching(), [true, true]);
    let d = c.apply(Input::Fault("servo".to_owned()), 2.0);
    assert_eq!(
        d,
        vec![Decision::HaltAndLatch {
            reason: "servo".to_owned()
        }]
    );
    // Overtaken and unwatched before the shell halts.
    assert_eq!(c.stop_generation(), 1);
    assert_eq!(c.watching(), [false, false]);
    for input in [
        Input::Stop,
        Input::LinkUp(AxisId::X),
        Input::Referenced(AxisId::X),
        Input::End(Activity::Moving),
    ] {
        c.apply(input, 3.0);
        let e = c
            .admit_move(c.stop_generation(), [true, false], false)
            .unwrap_err();
        assert_eq!(e.code, ErrorCode::FaultLatched);
        assert_eq!(
            e.message,
            "a fault is latched (servo); find its cause, then send reset"
        );
    }
    assert_eq!(c.begin_job(4.0).unwrap_err().code, ErrorCode::FaultLatched);
    assert_eq!(
        c.begin_reference(4.0).unwrap_err().code,
        ErrorCode::FaultLatched
    );
    let cleared = c.reset(5.0).unwrap();
    assert_eq!((cleared.t_s, cleared.reason.as_str()), (2.0, "servo"));
    assert!(c
        .admit_move(c.stop_generation(), [true, true], false)
        .is_ok());
    // Nothing latched: a second reset clears nothing.
    assert!(c.reset(6.0).is_none());
}

#[test]
fn a_lost_reference_stays_lost_after_reset() {
    let mut c = ready();
    let d = c.apply(Input::ReferenceLost(AxisId::X), 1.0);
    assert_eq!(d.len(), 1);
    c.reset(2.0);
    let gen = c.stop_generation();
    assert_eq!(
        c.admit_move(gen, [true, false], false).unwrap_err().code,
        ErrorCode::NotReferenced
    );
    assert!(c.admit_move(gen, [false, true], false).is_ok());
}

#[test]
fn a_line_down_refuses_with_its_reason() {
    let mut c = ready();
    c.apply(Input::LinkDown(AxisId::Y, "unplugged".to_owned()), 1.0);
    c.reset(2.0);
    let e = c
        .admit_move(c.stop_generation(), [true, false], false)
        .unwrap_err();
    assert_eq!(e.code, ErrorCode::NotConnected);
    assert_eq!(e.message, "axis y line is down: unplugged");
}

#[test]
fn soft_limits_are_the_configured_ones_within_the_travel() {
    assert_eq!(
        allowed_range_um((0.0, 25_000.0), None, None),
        (0.0, 25_000.0)
    );
    assert_eq!(
        allowed_range_um((0.0, 25_000.0), Some(1000.0), Some(9000.0)),
        (1000.0, 9000.0)
    );
    // A soft limit beyond the travel does not widen it.
    assert_eq!(
        allowed_range_um((0.0, 25_000.0), Some(-5.0), Some(30_000.0)),
        (0.0, 25_000.0)
    );
    let r = allowed_range_um((0.0, 25_000.0), Some(1000.0), Some(9000.0));
    assert_eq!(target_within(AxisId::X, 1000.0, None, r).unwrap(), 1000.0);
    assert_eq!(target_within(AxisId::X, 9000.0, None, r).unwrap(), 9000.0);
    let e = target_within(AxisId::Y, 9000.5, None, r).unwrap_err();
    assert_eq!(e.code, ErrorCode::OutOfTravel);
    assert_eq!(
        e.message,
        "axis y target 9000.500 µm is outside the allowed range 1000.000..9000.000 µm (soft limits ∩ controller travel); nothing was sent"
    );
    // Relative: from the base.
    assert_eq!(
        target_within(AxisId::X, -500.0, Some(1600.0), r).unwrap(),
        1100.0
    );
    assert!(target_within(AxisId::X, -700.0, Some(1600.0), r).is_err());
    assert!(target_within(AxisId::X, f64::NAN, None, r).is_err());
}

#[test]
fn a_relative_move_starts_from_the_commanded_target() {
    let mut c = ready();
    // Nothing commanded yet: from the controller's target.
    let t = try_move(&mut c, 0, [Some(10.0), None], true, [500.0, 0.0], 1.0).unwrap();
    assert_eq!(t, [Some(510.0), None]);
    let t = try_move(&mut c, 0, [Some(10.0), None], true, [500.0, 0.0], 2.0).unwrap();
    assert_eq!(t, [Some(520.0), None]);
    assert_eq!(c.commanded(), [Some(520.0), None]);
    // A halt forgets the commanded targets.
    c.halting();
    c.halted();
    assert_eq!(c.commanded(), [None, None]);
}

#[test]
fn a_send_that_failed_is_not_commanded_but_widens_the_deviation_span() {
    let mut c = ready();
    c.move_sent([Some(100.0), Some(200.0)], [true, false], 1.0, 1.1);
    assert_eq!(c.commanded(), [Some(100.0), None]);
}

#[test]
fn a_move_overtaken_while_it_was_sent_is_not_watched() {
    let mut c = ready();
    let gen = c.stop_generation();
    c.admit_move(gen, [true, false], false).unwrap();
    c.begin_move(1.0);
    c.move_sent([Some(10.0), None], [true, true], 1.0, 1.1);
    c.apply(Input::Fault("line x".to_owned()), 1.05);
    assert!(!c.watch_sent(gen, [Some(10.0), None], 1.1));
    assert_eq!(c.watching(), [false, false]);
}

#[test]
fn a_stop_overtakes_queued_moves_and_names_why() {
    let mut c = ready();
    let queued = c.stop_generation();
    c.begin_move(1.0);
    c.stop("stop requested by a client", 1.5);
    assert_eq!(c.state().activity(), Activity::Idle);
    assert!(c.state().latched().is_none(), "a stop is no fault");
    let e = c.admit_move(queued, [true, false], false).unwrap_err();
    assert_eq!(e.code, ErrorCode::Halted);
    assert_eq!(
        e.message,
        "a stop or fault came before this move started; it was not sent (halted by the daemon: stop requested by a client)"
    );
    // A move queued after the stop goes.
    assert!(c
        .admit_move(c.stop_generation(), [true, false], false)
        .is_ok());
}

#[test]
fn a_halted_error_names_the_latest_stop_only_if_one_came() {
    let mut c = ready();
    let gen = c.stop_generation();
    assert_eq!(
        c.halted_because(halted(), gen).message,
        "the move was halted"
    );
    c.begin_stop("job cancelled");
    c.apply(Input::Fault("ERR 1024".to_owned()), 1.0);
    assert_eq!(
        c.halted_because(halted(), gen).message,
        "the move was halted (halted by the daemon: fault: ERR 1024)"
    );
    // Only a `halted` error is explained.
    let other = ProtoError::new(ErrorCode::DriverError, "x");
    assert_eq!(c.halted_because(other, gen).message, "x");
}

#[test]
fn what_a_failed_send_or_wait_is() {
    let pending = DriverError::PendingError {
        target: "x".to_owned(),
        code: GcsErrorCode(1024),
        command: "MOV 1 5".to_owned(),
    };
    let f = fault_of_send(&pending).unwrap();
    assert!(f.starts_with("before a move: "), "{f}");
    let timeout = DriverError::MotionTimeout {
        axis: "x".to_owned(),
        timeout: std::time::Duration::from_secs(3),
    };
    assert!(fault_of_send(&timeout).is_none());
    let f = fault_of_wait(&timeout).unwrap();
    assert!(f.starts_with("while waiting for a move: "), "{f}");
    let gcs = DriverError::Gcs {
        command: "MOV".to_owned(),
        code: GcsErrorCode(7),
    };
    assert!(fault_of_wait(&gcs).is_some());
    let halted = DriverError::Halted {
        axis: "x".to_owned(),
    };
    assert!(fault_of_wait(&halted).is_none());
    assert!(fault_of_send(&halted).is_none());
}

#[test]
fn the_supervisor_watches_what_was_sent_until_on_target() {
    let mut c = ready();
    try_move(&mut c, 0, [Some(1000.0), None], false, [0.0; 2], 1.0).unwrap();
    assert_eq!(c.watching(), [true, false]);
    assert!(c.needs_velocity(AxisId::X));
    c.set_velocity(AxisId::X, 1000.0);
    assert!(!c.needs_velocity(AxisId::X));
    let moving = AxisSample {
        error: Some(GcsErrorCode(0)),
        position_um: Ok(0.0),
        on_target: Some(false),
    };
    assert!(c.observe(AxisId::X, 1.1, 1.2, &moving).is_ok());
    let arrived = AxisSample {
        error: Some(GcsErrorCode(0)),
        position_um: Ok(1000.0),
        on_target: Some(true),
    };
    assert!(c.observe(AxisId::X, 2.1, 2.2, &arrived).is_ok());
    assert_eq!(c.watching(), [false, false]);
}

#[test]
fn the_supervisor_judges_a_controller_error_and_a_motion_timeout() {
    let mut c = ready();
    try_move(
        &mut c,
        0,
        [Some(1000.0), Some(1000.0)],
        false,
        [0.0; 2],
        1.0,
    )
    .unwrap();
    let servo = AxisSample {
        error: Some(GcsErrorCode(1024)),
        position_um: Ok(10.0),
        on_target: Some(false),
    };
    let e = c.observe(AxisId::X, 1.5, 1.6, &servo).unwrap_err();
    assert!(
        e.starts_with("axis x: the controller reports error 1024"),
        "{e}"
    );
    let stalled = AxisSample {
        error: Some(GcsErrorCode(0)),
        position_um: Ok(10.0),
        on_target: Some(false),
    };
    // Y's timeout is 20 s from the send at 1.001 s.
    assert!(c.observe(AxisId::Y, 20.0, 20.5, &stalled).is_ok());
    let e = c.observe(AxisId::Y, 21.0, 21.5, &stalled).unwrap_err();
    assert!(e.contains("motion timeout 20 s"), "{e}");
    // Failing reads, moving or not, for longer than read_fail_s.
    let failed = Err(ReadFailure::Failed("garbled".to_owned()));
    assert!(c.read_result(AxisId::X, 30.0, &failed).is_none());
    assert!(c.read_result(AxisId::X, 32.5, &failed).is_some());
}

#[test]
fn a_reference_run_drops_the_watches_and_sets_the_commanded_position() {
    let mut c = ready();
    try_move(
        &mut c,
        0,
        [Some(1000.0), Some(1000.0)],
        false,
        [0.0; 2],
        1.0,
    )
    .unwrap();
    c.begin_reference(2.0).unwrap();
    assert_eq!(c.watching(), [false, false]);
    c.reference_done([Some(12_500.0), None]);
    assert_eq!(c.commanded(), [Some(12_500.0), Some(1000.0)]);
}

fn identity() -> Result<(VisionFrame, String), String> {
    Ok((
        VisionFrame {
            rotation_rad: 0.0,
            mirrored: false,
            translation_um: [0.0, 0.0],
        },
        "test".to_owned(),
    ))
}

fn read_both(c: &mut MotionCore, t: f64, p: [f64; 2]) {
    c.controller_read(AxisId::X, t, t + 0.001, p[0]);
    c.controller_read(AxisId::Y, t, t + 0.001, p[1]);
}

#[test]
fn a_deviation_beyond_the_bound_is_a_fault_to_apply() {
    let mut c = ready();
    // The frame is known first (the rig judges after every read): a
    // change of frame drops what was seen under the old one.
    assert_eq!(c.judge_deviation(identity()), Judged::default());
    read_both(&mut c, 0.0, [100.0, 100.0]);
    c.vision(0.01, 0.01, 5.0, -5.0);
    read_both(&mut c, 0.1, [100.0, 100.0]);
    let r = c.judge_deviation(identity());
    assert_eq!(r.tied_um, Some([95.0, 105.0]));
    assert!(r.fault.is_none());
    // Within the bound (50 µm): no fault.
    c.vision(0.2, 0.2, 45.0, -5.0);
    read_both(&mut c, 0.3, [100.0, 100.0]);
    assert!(c.judge_deviation(identity()).fault.is_none());
    // 200 µm beyond at rest: a fault.
    c.vision(0.4, 0.4, 205.0, -5.0);
    read_both(&mut c, 0.5, [100.0, 100.0]);
    let fault = c.judge_deviation(identity()).fault.unwrap();
    assert!(
        fault.contains("axis x") && fault.contains("vision deviation"),
        "{fault}"
    );
    let d = c.apply(Input::Fault(fault.clone()), 0.6);
    assert_eq!(d, vec![Decision::HaltAndLatch { reason: fault }]);
    assert_eq!(
        c.admit_move(c.stop_generation(), [true, false], false)
            .unwrap_err()
            .code,
        ErrorCode::FaultLatched
    );
}

#[test]
fn no_tie_while_a_move_is_watched_or_without_a_frame() {
    let mut c = ready();
    c.judge_deviation(identity());
    try_move(&mut c, 0, [Some(100.0), Some(100.0)], false, [0.0; 2], 0.0).unwrap();
    read_both(&mut c, 0.0, [100.0, 100.0]);
    c.vision(0.01, 0.01, 5.0, -5.0);
    read_both(&mut c, 0.1, [100.0, 100.0]);
    assert!(c.judge_deviation(identity()).tied_um.is_none());
    let j = c.deviation_status(Err("no camera".to_owned()));
    assert!(!j.armed, "{j:?}");
    assert_eq!(j.state, "off: no camera", "{j:?}");
}

/// One input of the property tests.
#[derive(Debug, Clone)]
enum Op {
    StageUp([bool; 2]),
    LinkDown(bool),
    LinkUp(bool),
    Referenced(bool),
    ReferenceLost(bool),
    Fault,
    Reset,
    Stop,
    Halt,
    BeginJob,
    EndJob,
    /// A move of (x, y), relative or not, queued before the last stop or not.
    Move([Option<f64>; 2], bool, bool),
}

fn axis(x: bool) -> AxisId {
    if x {
        AxisId::X
    } else {
        AxisId::Y
    }
}

fn op() -> impl Strategy<Value = Op> {
    let v = prop::option::of(-30_000.0..60_000.0f64);
    prop_oneof![
        any::<[bool; 2]>().prop_map(Op::StageUp),
        any::<bool>().prop_map(Op::LinkDown),
        any::<bool>().prop_map(Op::LinkUp),
        any::<bool>().prop_map(Op::Referenced),
        any::<bool>().prop_map(Op::ReferenceLost),
        Just(Op::Fault),
        Just(Op::Reset),
        Just(Op::Stop),
        Just(Op::Halt),
        Just(Op::BeginJob),
        Just(Op::EndJob),
        (v.clone(), v, any::<bool>(), any::<bool>()).prop_map(|(x, y, rel, stale)| Op::Move(
            [x, y],
            rel,
            stale
        )),
    ]
}

proptest! {
    /// No input sequence yields a move while a fault is latched; every
    /// move sent is within the range; the stop generation never goes
    /// back and moves on with every halt; a latch is cleared by `reset`
    /// alone; after a fault nothing is watched.
    #[test]
    fn the_move_policy_invariants_hold(ops in prop::collection::vec(op(), 1..80)) {
        let mut c = MotionCore::new(bounds(), 50.0);
        let mut stale = 0;
        for (k, o) in ops.into_iter().enumerate() {
            let t = k as f64;
            let gen0 = c.stop_generation();
            let latched0 = c.state().latched().is_some();
            let mut decisions = Vec::new();
            let mut reset = false;
            match o {
                Op::StageUp(r) => decisions = c.apply(Input::StageUp { referenced: r }, t),
                Op::LinkDown(x) => decisions = c.apply(Input::LinkDown(axis(x), "gone".into()), t),
                Op::LinkUp(x) => decisions = c.apply(Input::LinkUp(axis(x)), t),
                Op::Referenced(x) => decisions = c.apply(Input::Referenced(axis(x)), t),
                Op::ReferenceLost(x) => decisions = c.apply(Input::ReferenceLost(axis(x)), t),
                Op::Fault => decisions = c.apply(Input::Fault("f".into()), t),
                Op::Reset => {
                    reset = true;
                    c.reset(t);
                }
                Op::Stop => {
                    stale = c.stop_generation();
                    c.stop("stop", t);
                    prop_assert!(c.stop_generation() > gen0);
                }
                Op::Halt => {
                    stale = c.stop_generation();
                    c.begin_stop("halt");
                    c.halting();
                    c.halted();
                    prop_assert!(c.stop_generation() > gen0);
                    prop_assert_eq!(c.commanded(), [None, None]);
                }
                Op::BeginJob => {
                    let _ = c.begin_job(t);
                }
                Op::EndJob => c.end(Activity::Job, t),
                Op::Move(want, rel, old) => {
                    let gen = if old { stale } else { c.stop_generation() };
                    match try_move(&mut c, gen, want, rel, [12_000.0, 12_000.0], t) {
                        Ok(targets) => {
                            prop_assert!(!latched0, "a move while latched");
                            prop_assert_eq!(gen, gen0, "an overtaken move went");
                            for tg in targets.into_iter().flatten() {
                                prop_assert!((RANGE.0..=RANGE.1).contains(&tg));
                            }
                        }
                        Err(e) if latched0 && gen == gen0 => {
                            // Connected first, then the latch.
                            prop_assert!(matches!(
                                e.code,
                                ErrorCode::FaultLatched | ErrorCode::NotConnected
                            ), "{:?}", e);
                        }
                        Err(_) => {}
                    }
                }
            }
            prop_assert!(c.stop_generation() >= gen0);
            if !decisions.is_empty() {
                prop_assert!(c.stop_generation() > gen0);
                prop_assert_eq!(c.watching(), [false, false]);
                prop_assert!(c.state().latched().is_some());
            }
            if latched0 && !reset {
                prop_assert!(c.state().latched().is_some(), "a latch cleared without reset");
            }
            for v in c.commanded().into_iter().flatten() {
                prop_assert!((RANGE.0..=RANGE.1).contains(&v));
            }
        }
    }
}
