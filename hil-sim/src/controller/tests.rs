//! Behaviour of one simulated C-863 through its request interface:
//! identification, referencing, motion timing, limits, errors, parameters,
//! power cycles, addressing and the platform seam.

use super::commands::num7;
use super::*;
use micropos::gcs::frame::{Request, RequestDecoder};
use micropos::gcs::Command;
use proptest::prelude::*;

fn s(v: f64) -> Duration {
    Duration::from_secs_f64(v)
}

fn ctl(initial: f64) -> Controller {
    Controller::new(ControllerConfig::new(
        Address::DEFAULT,
        "0115500001",
        initial,
    ))
}

/// Sends a line at time `t`; returns the answer text (None = silence).
fn q(c: &mut Controller, t: f64, line: &str) -> Option<String> {
    let mut d = RequestDecoder::new();
    let reqs = d.push(format!("{line}\n").as_bytes());
    assert_eq!(reqs.len(), 1);
    c.handle(s(t), &reqs[0])
        .map(|b| micropos::gcs::frame::bytes_to_text(&b))
}

fn err(c: &mut Controller, t: f64) -> i32 {
    q(c, t, "ERR?").unwrap().trim().parse().unwrap()
}

fn pos(c: &mut Controller, t: f64) -> f64 {
    let a = q(c, t, "POS? 1").unwrap();
    a.trim().strip_prefix("1=").unwrap().parse().unwrap()
}

fn ctrl(c: &mut Controller, t: f64, b: u8) -> Option<Vec<u8>> {
    let mut d = RequestDecoder::new();
    let reqs = d.push(&[b]);
    c.handle(s(t), &reqs[0])
}

/// Servo on, FRF, wait until referenced; returns the time it finished.
fn referenced(c: &mut Controller) -> f64 {
    assert_eq!(q(c, 0.0, "SVO 1 1"), None);
    assert_eq!(q(c, 0.0, "FRF 1"), None);
    let mut t = 0.0;
    while q(c, t, "FRF? 1").unwrap() != "1=1\n" {
        t += 0.1;
        assert!(t < 60.0);
    }
    assert_eq!(err(c, t), 0);
    t
}

#[test]
fn identification_and_fixed_answers() {
    let mut c = ctl(3.0);
    assert_eq!(
        q(&mut c, 0.0, "*IDN?").unwrap(),
        "(c)2015 Physik Instrumente (PI) GmbH & Co. KG, C-863.11, 0115500001, 01.110\n"
    );
    assert_eq!(q(&mut c, 0.0, "CSV?").unwrap(), "2.0\n");
    assert_eq!(q(&mut c, 0.0, "SAI?").unwrap(), "1\n");
    assert_eq!(q(&mut c, 0.0, "SAI? ALL").unwrap(), "1\n");
    assert_eq!(q(&mut c, 0.0, "TMN? 1").unwrap(), "1=0.0000000\n");
    assert_eq!(q(&mut c, 0.0, "TMX? 1").unwrap(), "1=15.0000000\n");
    assert_eq!(q(&mut c, 0.0, "TMX?").unwrap(), "1=15.0000000\n");
    assert_eq!(q(&mut c, 0.0, "CST? 1").unwrap(), "1=M-111.1DG\n");
    assert_eq!(q(&mut c, 0.0, "VEL? 1").unwrap(), "1=1.0000000\n");
    assert_eq!(q(&mut c, 0.0, "ACC? 1").unwrap(), "1=10.0000000\n");
    assert_eq!(q(&mut c, 0.0, "DEC? 1").unwrap(), "1=10.0000000\n");
    assert_eq!(q(&mut c, 0.0, "RON? 1").unwrap(), "1=1\n");
    let ver = q(&mut c, 0.0, "VER?").unwrap();
    assert!(ver.starts_with("FW_ARM: V01.110 \n"), "{ver:?}");
    assert_eq!(err(&mut c, 0.0), 0);
}

#[test]
fn power_up_state() {
    let mut c = ctl(3.0);
    assert_eq!(q(&mut c, 0.0, "SVO? 1").unwrap(), "1=0\n");
    assert_eq!(q(&mut c, 0.0, "FRF? 1").unwrap(), "1=0\n");
    assert_eq!(q(&mut c, 0.0, "POS? 1").unwrap(), "1=0.0000000\n");
    assert_eq!(q(&mut c, 0.0, "ONT? 1").unwrap(), "1=0\n");
    assert_eq!(c.true_position_mm(s(0.0)), 3.0);
    assert_eq!(ctrl(&mut c, 0.0, 7).unwrap(), vec![0xB1, b'\n']);
    assert_eq!(ctrl(&mut c, 0.0, 5).unwrap(), b"0\n");
    // Carriage at 3.0 < reference switch at 7.5: no switch bits.
    assert_eq!(ctrl(&mut c, 0.0, 4).unwrap(), b"0x0\n");
}

#[test]
fn help_lists_exactly_what_parses() {
    let mut c = ctl(3.0);
    let hlp = q(&mut c, 0.0, "HLP?").unwrap();
    let lines: Vec<&str> = hlp.lines().collect();
    assert!(lines.len() > 30);
    // Multi-line framing: every line but the last ends with a space.
    for l in &lines[..lines.len() - 1] {
        assert!(l.ends_with(' '), "{l:?}");
    }
    assert!(!lines.last().unwrap().ends_with(' '));
    for cmd in Controller::help_commands().filter(|c| !c.starts_with('#')) {
        if let Err(micropos::gcs::CommandError::Unknown(_)) = Command::parse(cmd) {
            panic!("{cmd} listed but unknown");
        }
    }
    let hpa = q(&mut c, 0.0, "HPA?").unwrap();
    assert!(
        hpa.contains("0x3C=\t0\t1\tCHAR\tstage\tStage_Name"),
        "{hpa}"
    );
    assert_eq!(err(&mut c, 0.0), 0);
}

#[test]
fn referencing_takes_time_and_sets_position() {
    let mut c = ctl(3.0);
    // FRF needs the servo.
    assert_eq!(q(&mut c, 0.0, "FRF 1"), None);
    assert_eq!(err(&mut c, 0.0), 5);
    assert_eq!(q(&mut c, 0.0, "SVO 1 1"), None);
    assert_eq!(q(&mut c, 0.0, "FRF 1"), None);
    assert_eq!(err(&mut c, 0.0), 0);
    // 4.5 mm at 0.5 mm/s (plus ramps) and 1.5 s edge search.
    assert_eq!(ctrl(&mut c, 1.0, 7).unwrap(), vec![0xB0, b'\n']);
    assert_eq!(ctrl(&mut c, 1.0, 5).unwrap(), b"1\n");
    let sr = u16::from_str_radix(
        std::str::from_utf8(&ctrl(&mut c, 1.0, 4).unwrap())
            .unwrap()
            .trim()
            .trim_start_matches("0x"),
        16,
    )
    .unwrap();
    assert_eq!(sr & (1 << 14), 1 << 14, "referencing bit");
    assert_eq!(sr & (1 << 13), 1 << 13, "motion bit");
    assert_eq!(sr & (1 << 15), 0, "not on target");
    assert_eq!(q(&mut c, 1.0, "FRF? 1").unwrap(), "1=0\n");
    assert_eq!(q(&mut c, 1.0, "ONT? 1").unwrap(), "1=0\n");
    // Halfway the carriage moves towards the switch.
    assert!(c.true_position_mm(s(5.0)) > 3.0 && c.true_position_mm(s(5.0)) < 7.5);
    let expected = 4.5 / 0.5 + 0.5 / 10.0 + EDGE_SEARCH_TIME.as_secs_f64();
    assert_eq!(q(&mut c, expected - 0.01, "FRF? 1").unwrap(), "1=0\n");
    assert_eq!(q(&mut c, expected + 0.01, "FRF? 1").unwrap(), "1=1\n");
    assert_eq!(ctrl(&mut c, expected + 0.01, 7).unwrap(), vec![0xB1, b'\n']);
    assert_eq!(pos(&mut c, expected + 0.01), 7.5);
    assert_eq!(c.true_position_mm(s(expected + 0.01)), 7.5);
    assert_eq!(q(&mut c, expected + 0.1, "ONT? 1").unwrap(), "1=1\n");
    assert_eq!(
        q(&mut c, expected + 0.1, "MOV? 1").unwrap(),
        "1=7.5000000\n"
    );
}

#[test]
fn limit_referencing() {
    let mut c = ctl(3.0);
    q(&mut c, 0.0, "SVO 1 1");
    q(&mut c, 0.0, "FNL 1");
    assert_eq!(q(&mut c, 100.0, "FRF? 1").unwrap(), "1=1\n");
    assert_eq!(pos(&mut c, 100.0), 0.0);
    assert_eq!(c.true_position_mm(s(100.0)), 0.0);
    assert_eq!(ctrl(&mut c, 100.0, 4).unwrap(), b"0x9001\n");
    q(&mut c, 100.0, "FPL");
    assert_eq!(q(&mut c, 100.5, "FRF? 1").unwrap(), "1=0\n");
    assert_eq!(q(&mut c, 200.0, "FRF? 1").unwrap(), "1=1\n");
    assert_eq!(pos(&mut c, 200.0), 15.0);
    assert_eq!(ctrl(&mut c, 200.0, 4).unwrap(), b"0x9006\n");
    assert_eq!(err(&mut c, 200.0), 0);
}

#[test]
fn reference_value_parameter_shifts_the_encoder() {
    let mut c = ctl(3.0);
    q(&mut c, 0.0, "SPA 1 0x16 10");
    q(&mut c, 0.0, "SVO 1 1");
    q(&mut c, 0.0, "FRF 1");
    assert_eq!(pos(&mut c, 100.0), 10.0);
    assert_eq!(c.true_position_mm(s(100.0)), 7.5);
    q(&mut c, 100.0, "MOV 1 11");
    assert!((c.true_position_mm(s(200.0)) - 8.5).abs() < 1e-12);
}

#[test]
fn trapezoidal_move_timing() {
    let mut c = ctl(3.0);
    let t0 = referenced(&mut c);
    assert_eq!(q(&mut c, t0, "MOV 1 9.5"), None);
    assert_eq!(q(&mut c, t0, "MOV? 1").unwrap(), "1=9.5000000\n");
    // 2 mm at 1 mm/s with 10 mm/s² ramps: 0.1 s + 1.9 s + 0.1 s.
    let mid = pos(&mut c, t0 + 1.0);
    assert!((mid - (7.5 + 0.05 + 0.9)).abs() < 1e-6, "{mid}");
    assert_eq!(ctrl(&mut c, t0 + 1.0, 5).unwrap(), b"1\n");
    assert_eq!(q(&mut c, t0 + 1.0, "ONT? 1").unwrap(), "1=0\n");
    assert_eq!(ctrl(&mut c, t0 + 1.0, 7).unwrap(), vec![0xB1, b'\n']);
    assert_eq!(pos(&mut c, t0 + 2.1), 9.5);
    assert_eq!(ctrl(&mut c, t0 + 2.11, 5).unwrap(), b"0\n");
    // Settling: on target 50 ms after the profile ends.
    assert_eq!(q(&mut c, t0 + 2.12, "ONT? 1").unwrap(), "1=0\n");
    assert_eq!(q(&mut c, t0 + 2.16, "ONT? 1").unwrap(), "1=1\n");
    assert_eq!(c.true_position_mm(s(t0 + 3.0)), 9.5);
}

#[test]
fn relative_moves_add_to_the_target() {
    let mut c = ctl(3.0);
    let t0 = referenced(&mut c);
    q(&mut c, t0, "MVR 1 1.25");
    // A second MVR during the move adds to the commanded target.
    q(&mut c, t0 + 0.2, "MVR 1 -0.5");
    assert_eq!(q(&mut c, t0 + 0.2, "MOV? 1").unwrap(), "1=8.2500000\n");
    assert!((pos(&mut c, t0 + 10.0) - 8.25).abs() < 1e-12);
    q(&mut c, t0 + 10.0, "MVR 1 7");
    assert_eq!(err(&mut c, t0 + 10.0), 7);
    assert_eq!(q(&mut c, t0 + 10.0, "MOV? 1").unwrap(), "1=8.2500000\n");
}

#[test]
fn velocity_and_ramps() {
    let mut c = ctl(3.0);
    let t0 = referenced(&mut c);
    q(&mut c, t0, "VEL 1 0.5");
    assert_eq!(q(&mut c, t0, "VEL? 1").unwrap(), "1=0.5000000\n");
    assert_eq!(q(&mut c, t0, "SPA? 1 0x49").unwrap(), "1 0x49=0.500000\n");
    q(&mut c, t0, "ACC 1 5");
    q(&mut c, t0, "DEC 1 2.5");
    assert_eq!(q(&mut c, t0, "ACC? 1").unwrap(), "1=5.0000000\n");
    assert_eq!(q(&mut c, t0, "DEC?").unwrap(), "1=2.5000000\n");
    q(&mut c, t0, "MOV 1 8.5");
    // 1 mm: accel 0.1 s (0.025 mm), brake 0.2 s (0.05 mm), cruise 1.85 s.
    assert!(pos(&mut c, t0 + 2.1) < 8.5);
    assert_eq!(pos(&mut c, t0 + 2.16), 8.5);
    // Changing VEL mid-move re-plans to the same target.
    q(&mut c, t0 + 3.0, "MOV 1 12.5");
    q(&mut c, t0 + 4.0, "VEL 1 1.5");
    let before = pos(&mut c, t0 + 5.0);
    let after = pos(&mut c, t0 + 6.0);
    assert!((after - before - 1.5).abs() < 1e-9, "{before} {after}");
    assert_eq!(pos(&mut c, t0 + 20.0), 12.5);
    // Out of range values are refused and leave the setting alone.
    for (cmd, code) in [
        ("VEL 1 2", 8),
        ("VEL 1 0", 8),
        ("VEL 1 -1", 8),
        ("ACC 1 0", 17),
        ("DEC 1 100", 17),
    ] {
        q(&mut c, t0 + 20.0, cmd);
        assert_eq!(err(&mut c, t0 + 20.0), code, "{cmd}");
    }
    assert_eq!(q(&mut c, t0 + 20.0, "VEL? 1").unwrap(), "1=1.5000000\n");
}

#[test]
fn soft_limits_refuse_and_nothing_moves() {
    let mut c = ctl(3.0);
    let t0 = referenced(&mut c);
    q(&mut c, t0, "MOV 1 15.0001");
    assert_eq!(err(&mut c, t0), 7);
    q(&mut c, t0, "MOV 1 -0.1");
    assert_eq!(err(&mut c, t0), 7);
    assert_eq!(ctrl(&mut c, t0 + 0.1, 5).unwrap(), b"0\n");
    assert_eq!(pos(&mut c, t0 + 1.0), 7.5);
    assert_eq!(q(&mut c, t0, "MOV? 1").unwrap(), "1=7.5000000\n");
    // Exactly on the limits is fine.
    q(&mut c, t0, "MOV 1 15");
    assert_eq!(err(&mut c, t0), 0);
    assert_eq!(pos(&mut c, t0 + 20.0), 15.0);
    q(&mut c, t0 + 20.0, "MOV 1 0");
    assert_eq!(err(&mut c, t0 + 20.0), 0);
    // Limits follow the parameters.
    q(&mut c, t0 + 40.0, "SPA 1 0x15 10");
    assert_eq!(q(&mut c, t0 + 40.0, "TMX? 1").unwrap(), "1=10.0000000\n");
    q(&mut c, t0 + 40.0, "MOV 1 11");
    assert_eq!(err(&mut c, t0 + 40.0), 7);
}

#[test]
fn moves_need_reference_and_servo() {
    let mut c = ctl(3.0);
    q(&mut c, 0.0, "MOV 1 1");
    assert_eq!(err(&mut c, 0.0), 5);
    q(&mut c, 0.0, "SVO 1 1");
    q(&mut c, 0.0, "MVR 1 1");
    assert_eq!(err(&mut c, 0.0), 5);
    // With reference mode off, an unreferenced axis may move.
    q(&mut c, 0.0, "RON 1 0");
    assert_eq!(q(&mut c, 0.0, "RON? 1").unwrap(), "1=0\n");
    q(&mut c, 0.0, "MOV 1 1");
    assert_eq!(err(&mut c, 0.0), 0);
    assert_eq!(pos(&mut c, 10.0), 1.0);
    assert_eq!(c.true_position_mm(s(10.0)), 4.0);
    q(&mut c, 10.0, "SVO 1 0");
    q(&mut c, 10.0, "MOV 1 2");
    assert_eq!(err(&mut c, 10.0), 5);
}

#[test]
fn servo_off_cuts_motion() {
    let mut c = ctl(3.0);
    let t0 = referenced(&mut c);
    q(&mut c, t0, "MOV 1 12");
    q(&mut c, t0 + 1.0, "SVO 1 0");
    let p = pos(&mut c, t0 + 1.0);
    assert_eq!(pos(&mut c, t0 + 5.0), p);
    assert_eq!(ctrl(&mut c, t0 + 5.0, 5).unwrap(), b"0\n");
    // Reference survives servo off (incremental encoder keeps counting).
    assert_eq!(q(&mut c, t0 + 5.0, "FRF? 1").unwrap(), "1=1\n");
    q(&mut c, t0 + 5.0, "SVO 1 1");
    assert_eq!(
        q(&mut c, t0 + 5.0, "MOV? 1").unwrap(),
        format!("1={}\n", num7(p))
    );
    assert_eq!(q(&mut c, t0 + 5.0, "ONT? 1").unwrap(), "1=1\n");
}

#[test]
fn halt_decelerates_stop_is_immediate() {
    let mut c = ctl(3.0);
    let t0 = referenced(&mut c);
    q(&mut c, t0, "MOV 1 12");
    q(&mut c, t0 + 1.0, "HLT 1");
    let p = pos(&mut c, t0 + 1.0);
    // Braking from 1 mm/s at 10 mm/s²: 0.05 mm further in 0.1 s.
    assert_eq!(ctrl(&mut c, t0 + 1.05, 5).unwrap(), b"1\n");
    assert!((pos(&mut c, t0 + 2.0) - (p + 0.05)).abs() < 1e-9);
    assert_eq!(err(&mut c, t0 + 2.0), 10);
    assert_eq!(
        q(&mut c, t0 + 2.0, "MOV? 1").unwrap(),
        format!("1={}\n", num7(p + 0.05))
    );
    q(&mut c, t0 + 2.0, "MOV 1 12");
    q(&mut c, t0 + 3.0, "STP");
    let p = pos(&mut c, t0 + 3.0);
    assert_eq!(pos(&mut c, t0 + 3.5), p);
    assert_eq!(err(&mut c, t0 + 3.5), 10);
    q(&mut c, t0 + 3.5, "MOV 1 12");
    assert_eq!(ctrl(&mut c, t0 + 4.0, 24), None);
    let p = pos(&mut c, t0 + 4.0);
    assert_eq!(pos(&mut c, t0 + 5.0), p);
    assert_eq!(err(&mut c, t0 + 5.0), 10);
    // Stopping while idle still reports the stop.
    q(&mut c, t0 + 5.0, "HLT");
    assert_eq!(err(&mut c, t0 + 5.0), 10);
}

#[test]
fn stop_during_referencing_leaves_unreferenced() {
    let mut c = ctl(3.0);
    q(&mut c, 0.0, "SVO 1 1");
    q(&mut c, 0.0, "FRF 1");
    ctrl(&mut c, 1.0, 24);
    assert_eq!(q(&mut c, 100.0, "FRF? 1").unwrap(), "1=0\n");
    assert_eq!(ctrl(&mut c, 100.0, 7).unwrap(), vec![0xB1, b'\n']);
    assert_eq!(err(&mut c, 100.0), 10);
    // Referencing again while already moving is refused.
    q(&mut c, 100.0, "FRF 1");
    q(&mut c, 101.0, "FRF 1");
    assert_eq!(err(&mut c, 101.0), 307);
    q(&mut c, 101.0, "HLT 1");
    assert_eq!(q(&mut c, 200.0, "FRF? 1").unwrap(), "1=0\n");
}

#[test]
fn errors_first_sticks_and_read_clears() {
    let mut c = ctl(3.0);
    assert_eq!(q(&mut c, 0.0, "FOO 1"), None);
    assert_eq!(q(&mut c, 0.0, "POS? 2"), None);
    assert_eq!(err(&mut c, 0.0), 2);
    assert_eq!(err(&mut c, 0.0), 0);
    for (line, code) in [
        ("XYZ?", 2),
        ("pos? 1", 2),
        ("POS? 2", 15),
        ("POS? A", 15),
        ("MOV 1", 24),
        ("MOV 1 abc", 1),
        ("SVO 1 2", 1),
        ("*IDN? 1", 24),
        ("SPA? 1 0x999", 54),
        ("SPA 1 0x999 1", 54),
        ("SPA 1 0x49 fast", 1),
        ("SPA 1 0x49 0", 17),
        ("SPA 2 0x49 1", 15),
    ] {
        assert_eq!(q(&mut c, 0.0, line), None, "{line}");
        assert_eq!(err(&mut c, 0.0), code, "{line}");
    }
    assert_eq!(c.handle(s(0.0), &Request::Overlong), None);
    assert_eq!(err(&mut c, 0.0), 3);
    // The error flag shows in the status register.
    q(&mut c, 0.0, "FOO");
    let sr = ctrl(&mut c, 0.0, 4).unwrap();
    assert_eq!(sr, b"0x100\n");
}

#[test]
fn parameters_read_and_write() {
    let mut c = ctl(3.0);
    assert_eq!(
        q(&mut c, 0.0, "SPA? 1 0x3C 1 0x15").unwrap(),
        "1 0x3C=M-111.1DG \n1 0x15=15.000000\n"
    );
    let all = q(&mut c, 0.0, "SPA?").unwrap();
    assert_eq!(all.lines().count(), crate::params::PARAMS.len());
    q(&mut c, 0.0, "SPA 1 0x3C NOSTAGE 1 0x1 120");
    assert_eq!(q(&mut c, 0.0, "CST? 1").unwrap(), "1=NOSTAGE\n");
    assert_eq!(q(&mut c, 0.0, "SPA? 1 1").unwrap(), "1 0x1=120\n");
    // A bad item refuses the whole command.
    q(&mut c, 0.0, "SPA 1 0x1 7 1 0x999 1");
    assert_eq!(err(&mut c, 0.0), 54);
    assert_eq!(q(&mut c, 0.0, "SPA? 1 1").unwrap(), "1 0x1=120\n");
}

#[test]
fn power_cycle_resets_but_carriage_stays() {
    let mut c = ctl(3.0);
    let t0 = referenced(&mut c);
    q(&mut c, t0, "VEL 1 1.5");
    q(&mut c, t0, "MOV 1 12");
    q(&mut c, t0, "FOO");
    c.power_cycle(s(t0 + 1.0));
    let truth = c.true_position_mm(s(t0 + 1.0));
    assert!(truth > 7.5 && truth < 12.0);
    assert_eq!(c.true_position_mm(s(t0 + 10.0)), truth);
    assert_eq!(pos(&mut c, t0 + 10.0), 0.0);
    assert_eq!(q(&mut c, t0 + 10.0, "SVO? 1").unwrap(), "1=0\n");
    assert_eq!(q(&mut c, t0 + 10.0, "FRF? 1").unwrap(), "1=0\n");
    assert_eq!(q(&mut c, t0 + 10.0, "VEL? 1").unwrap(), "1=1.0000000\n");
    assert_eq!(err(&mut c, t0 + 10.0), 0);
    // Referencing again finds the same switch.
    q(&mut c, t0 + 10.0, "SVO 1 1");
    q(&mut c, t0 + 10.0, "FRF 1");
    assert_eq!(pos(&mut c, t0 + 100.0), 7.5);
    assert_eq!(c.true_position_mm(s(t0 + 100.0)), 7.5);
}

#[test]
fn a_stall_freezes_the_carriage_until_halted() {
    let mut c = ctl(3.0);
    let t0 = referenced(&mut c);
    q(&mut c, t0, "MOV 1 12");
    c.stall(s(t0 + 1.0));
    let p = pos(&mut c, t0 + 1.0);
    assert!(p > 7.5 && p < 12.0, "{p}");
    // The carriage stays; the controller still tries.
    assert_eq!(pos(&mut c, t0 + 5.0), p);
    assert_eq!(
        c.true_position_mm(s(t0 + 5.0)),
        c.true_position_mm(s(t0 + 1.0))
    );
    assert!(c.is_moving(s(t0 + 5.0)));
    assert_eq!(q(&mut c, t0 + 5.0, "ONT? 1").unwrap(), "1=0\n");
    assert_eq!(err(&mut c, t0 + 5.0), 0);
    q(&mut c, t0 + 5.0, "HLT 1");
    assert!(!c.is_moving(s(t0 + 5.1)));
    assert_eq!(q(&mut c, t0 + 5.2, "ONT? 1").unwrap(), "1=1\n");
    assert_eq!(pos(&mut c, t0 + 6.0), p);
}

#[test]
fn a_slip_moves_the_platform_but_not_the_count() {
    use rand::{Rng, SeedableRng};
    // Random size and sign, mid-move and at rest.
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0x511b);
    for _ in 0..20 {
        let mut c = ctl(rng.gen_range(1.0..14.0));
        let t0 = referenced(&mut c);
        let target = rng.gen_range(2.0..13.0);
        q(&mut c, t0, &format!("MOV 1 {target}"));
        let t_slip = t0 + rng.gen_range(0.0..4.0);
        let before_pos = pos(&mut c, t_slip);
        let before_true = c.true_position_mm(s(t_slip));
        let d = rng.gen_range(-0.5..0.5);
        c.slip(s(t_slip), d);
        assert_eq!(pos(&mut c, t_slip), before_pos);
        assert!((c.true_position_mm(s(t_slip)) - before_true - d).abs() < 1e-9);
        // The move ends on target by the count, off by the slip in truth.
        let end = t0 + 20.0;
        assert_eq!(q(&mut c, end, "ONT? 1").unwrap(), "1=1\n");
        assert!((pos(&mut c, end) - target).abs() < 1e-6);
        assert!((c.true_position_mm(s(end)) - target - d).abs() < 1e-6);
        assert_eq!(err(&mut c, end), 0);
    }
}

#[test]
fn a_motion_error_cuts_motion_servo_off_error_1024() {
    let mut c = ctl(3.0);
    let t0 = referenced(&mut c);
    q(&mut c, t0, "MOV 1 12");
    c.motion_error(s(t0 + 1.0));
    let p = pos(&mut c, t0 + 1.0);
    assert!(p > 7.5 && p < 12.0, "{p}");
    assert_eq!(pos(&mut c, t0 + 5.0), p);
    assert!(!c.is_moving(s(t0 + 5.0)));
    assert_eq!(q(&mut c, t0 + 5.0, "SVO? 1").unwrap(), "1=0\n");
    assert_eq!(err(&mut c, t0 + 5.0), 1024);
    // No move until the servo is back on.
    q(&mut c, t0 + 5.0, "MOV 1 10");
    assert_eq!(err(&mut c, t0 + 5.0), 5);
}

#[test]
fn platform_seam_separates_truth_from_encoder() {
    /// A leadscrew 0.1 % long plus a 2 µm offset.
    #[derive(Debug)]
    struct Scaled;
    impl Platform for Scaled {
        fn platform_position_mm(&self, actuator_mm: f64, _now: Duration) -> f64 {
            actuator_mm * 1.001 + 0.002
        }
    }
    let mut c = ctl(3.0);
    c.set_platform(Box::new(Scaled));
    let t0 = referenced(&mut c);
    q(&mut c, t0, "MOV 1 10");
    // The controller reports its encoder; the platform is elsewhere.
    assert_eq!(pos(&mut c, t0 + 10.0), 10.0);
    let truth = c.true_position_mm(s(t0 + 10.0));
    assert!((truth - (10.0 * 1.001 + 0.002)).abs() < 1e-12, "{truth}");
}

#[test]
fn addressing() {
    let mut c = Controller::new(ControllerConfig::new(Address::new(2).unwrap(), "2", 1.0));
    let mut d = RequestDecoder::new();
    let reqs = d.push(b"*IDN?\n1 *IDN?\n2 CSV?\n2 \x07");
    assert_eq!(c.handle(s(0.0), &reqs[0]), None);
    assert_eq!(c.handle(s(0.0), &reqs[1]), None);
    assert_eq!(c.handle(s(0.0), &reqs[2]).unwrap(), b"0 2 2.0\n");
    assert_eq!(c.handle(s(0.0), &reqs[3]).unwrap(), b"0 2 \xb1\n");
    // The addressed controller also answers multi-line with one header.
    let reqs = d.push(b"2 SPA? 1 0x3C 1 0x15\n");
    assert_eq!(
        c.handle(s(0.0), &reqs[0]).unwrap(),
        b"0 2 1 0x3C=M-111.1DG \n1 0x15=15.000000\n"
    );
}

#[test]
fn long_virtual_runs_are_cheap_and_exact() {
    // 10 hours of back-and-forth in virtual time.
    let mut c = ctl(3.0);
    let mut t = referenced(&mut c);
    for i in 0..2000 {
        let target = if i % 2 == 0 { 2.0 } else { 13.0 };
        q(&mut c, t, &format!("MOV 1 {target}"));
        t += 18.0;
        assert_eq!(q(&mut c, t, "ONT? 1").unwrap(), "1=1\n");
        assert_eq!(pos(&mut c, t), target);
    }
    assert!(t > 36_000.0);
}

proptest! {
    #[test]
    fn random_bytes_never_panic(chunks in proptest::collection::vec(
        (proptest::collection::vec(any::<u8>(), 0..64), 0u32..5000), 0..40)) {
        let mut bus = crate::bus::Bus::new(vec![
            ctl(3.0),
            Controller::new(ControllerConfig::new(Address::new(2).unwrap(), "2", 9.0)),
        ]).unwrap();
        let mut t = Duration::ZERO;
        for (bytes, dt_ms) in &chunks {
            t += Duration::from_millis(u64::from(*dt_ms));
            for r in bus.receive(t, bytes) {
                prop_assert!(r.bytes.ends_with(b"\n"));
            }
            for c in bus.controllers() {
                let p = c.true_position_mm(t);
                prop_assert!(p.is_finite());
            }
        }
    }

    #[test]
    fn random_commands_never_panic(cmds in proptest::collection::vec(
        (prop_oneof![
            Just("MOV 1 "), Just("MVR 1 "), Just("VEL 1 "), Just("ACC 1 "), Just("DEC 1 "),
            Just("SVO 1 "), Just("FRF "), Just("HLT "), Just("STP "), Just("SPA 1 0x16 "),
            Just("SPA 1 0x15 "), Just("SPA 1 0x30 "), Just("RON 1 "), Just("FNL "), Just("FPL "),
        ], -20.0f64..20.0, 0u32..3000), 0..60)) {
        let mut c = ctl(5.0);
        let mut t = 0.0;
        for (cmd, v, dt) in &cmds {
            t += f64::from(*dt) / 1000.0;
            let arg = if cmd.starts_with("SVO") || cmd.starts_with("RON") {
                if *v > 0.0 { "1".to_owned() } else { "0".to_owned() }
            } else if cmd.starts_with("FRF") || cmd.starts_with("HLT") || cmd.starts_with("STP") || cmd.starts_with("F") {
                String::new()
            } else {
                format!("{v}")
            };
            q(&mut c, t, &format!("{cmd}{arg}"));
            let p = pos(&mut c, t);
            prop_assert!(p.is_finite());
            prop_assert!(c.true_position_mm(s(t)).is_finite());
        }
    }
}

/// With a servo lag τ, `POS?` (the encoder) trails the commanded
/// trajectory by v·τ at cruise, the platform is where the encoder is (ideal
/// platform), a re-plan mid-move (`VEL`) keeps position continuous, and the
/// axis still ends exactly on target and reports on target no earlier than
/// without lag.
#[test]
fn following_error_trails_the_command_at_velocity() {
    let tau = 0.004;
    let mut c = Controller::new(ControllerConfig {
        following_lag_s: tau,
        ..ControllerConfig::new(Address::DEFAULT, "0115500001", 3.0)
    });
    let mut free = ctl(3.0);
    let t0 = referenced(&mut c);
    let t0f = referenced(&mut free);
    assert!((t0 - t0f).abs() < 1e-9, "referencing takes as long");
    assert_eq!(pos(&mut c, t0), 7.5);
    assert_eq!(q(&mut c, t0, "VEL 1 0.5"), None);
    assert_eq!(q(&mut c, t0, "MOV 1 9.5"), None);
    // Accelerates in 0.05 s, cruises at 0.5 mm/s: the command is at
    // 7.5 + 0.0125 + 0.5·(t − 0.05).
    let t = t0 + 1.0;
    let cmd = 7.5 + 0.0125 + 0.5 * 0.95;
    let p = pos(&mut c, t);
    assert!((cmd - p - 0.5 * tau).abs() < 2e-7, "lag {} mm", cmd - p);
    assert!((c.true_position_mm(s(t)) - p).abs() < 2e-7);
    // Slower from here: the axis goes on from where it is.
    let before = c.encoder_mm(s(t + 0.01));
    assert_eq!(q(&mut c, t + 0.01, "VEL 1 0.25"), None);
    assert!((c.encoder_mm(s(t + 0.01)) - before).abs() < 1e-12);
    let p2 = c.encoder_mm(s(t + 0.5));
    let p3 = c.encoder_mm(s(t + 0.6));
    assert!(((p3 - p2) / 0.1 - 0.25).abs() < 1e-6);
    let mut te = t + 0.6;
    while q(&mut c, te, "ONT? 1").unwrap() != "1=1\n" {
        te += 0.01;
        assert!(te < t0 + 30.0);
    }
    assert_eq!(pos(&mut c, te), 9.5);
    assert!(!c.is_moving(s(te)));
}

/// The answer lines of a query at `t` (continuations removed).
fn lines(c: &mut Controller, t: f64, line: &str) -> Vec<String> {
    let mut d = RequestDecoder::new();
    let reqs = d.push(format!("{line}\n").as_bytes());
    let bytes = c.handle(s(t), &reqs[0]).expect("an answer");
    let mut a = micropos::gcs::AnswerDecoder::new();
    match a.push(&bytes).pop() {
        Some(micropos::gcs::frame::AnswerItem::Answer(a)) => a.lines(),
        other => panic!("{other:?}"),
    }
}

/// The data recorder records the servo's actual position (what `POS?`
/// says) every `RTR` servo cycles from its trigger, at most
/// `RECORD_TABLE_POINTS` points, read back as GCS array data.
#[test]
fn the_data_recorder_samples_the_actual_position_at_the_servo_rate() {
    use micropos::gcs::recorder::parse_records;
    let mut c = Controller::new(ControllerConfig {
        following_lag_s: 0.003,
        ..ControllerConfig::new(Address::DEFAULT, "0115500001", 3.0)
    });
    let t = referenced(&mut c);
    assert_eq!(q(&mut c, t, "TNR?").unwrap(), "2\n");
    assert_eq!(q(&mut c, t, "DRC 1 1 2"), None);
    assert_eq!(q(&mut c, t, "RTR 20"), None);
    assert_eq!(err(&mut c, t), 0);
    assert_eq!(q(&mut c, t, "RTR?").unwrap(), "20\n");
    assert_eq!(q(&mut c, t, "DRC? 1").unwrap(), "1=1 2\n");
    assert_eq!(q(&mut c, t, "VEL 1 0.2"), None);
    // Triggered by the move: its first record is the start.
    assert_eq!(q(&mut c, t, "DRT 1 1 0"), None);
    assert_eq!(q(&mut c, t + 0.1, "DRL? 1").unwrap(), "1=0\n");
    assert_eq!(q(&mut c, t + 0.1, "MOV 1 8.5"), None);
    let t0 = t + 0.1;
    // POS? at record instants while the recording runs (reading it never
    // changes what is recorded).
    let at: Vec<(f64, f64)> = (1..40)
        .map(|k| {
            let tk = t0 + 0.013 * f64::from(k);
            (tk, pos(&mut c, tk))
        })
        .collect();
    let end = t0 + 0.6;
    assert_eq!(q(&mut c, end, "DRL? 1").unwrap(), "1=601\n");
    let r = parse_records(&lines(&mut c, end, "DRR? 1 601 1")).unwrap();
    assert!((r.sample_time_s - 0.001).abs() < 1e-12);
    assert_eq!(r.rows(), 601);
    for (tk, p) in at {
        let i = ((tk - t0) / 0.001).round() as usize;
        if ((tk - t0) / 0.001 - i as f64).abs() < 1e-6 {
            assert!(
                (r.columns[0][i] - p).abs() < 1e-7,
                "{i}: {} vs {p}",
                r.columns[0][i]
            );
        }
    }
    assert!(r.columns[0].windows(2).all(|w| w[1] >= w[0]), "moving up");
    // Part of the table, from a later point.
    let part = parse_records(&lines(&mut c, end, "DRR? 101 50 1")).unwrap();
    assert_eq!(part.columns[0], r.columns[0][100..150].to_vec());
    // A full table stops; an immediate trigger restarts it.
    assert_eq!(q(&mut c, t0 + 5.0, "DRL? 1").unwrap(), "1=1024\n");
    assert_eq!(q(&mut c, t0 + 5.0, "DRT 1 4 0"), None);
    assert_eq!(q(&mut c, t0 + 5.0105, "DRL? 1").unwrap(), "1=11\n");
    // Refused: a table that does not exist, an option it does not know.
    assert_eq!(q(&mut c, t0 + 5.1, "DRC 3 1 2"), None);
    assert_eq!(err(&mut c, t0 + 5.1), 17);
    assert_eq!(q(&mut c, t0 + 5.1, "DRC 1 1 99"), None);
    assert_eq!(err(&mut c, t0 + 5.1), 17);
    assert_eq!(q(&mut c, t0 + 5.1, "RTR 0"), None);
    assert_eq!(err(&mut c, t0 + 5.1), 17);
    let hdr = q(&mut c, t0 + 5.1, "HDR?").unwrap();
    assert!(hdr.contains("2=Real Position of Axis"), "{hdr}");
}
