//! Vision against controller: where the camera decodes the platform, against
//! where the controllers count it, in one frame. A breach of
//! `safety.deviation_um` is a fault of the motion supervisor (halt both
//! axes, latch `deviation` until `reset`), as a following error is.
//!
//! Why: the following-error check compares the controller with its own
//! commanded trajectory, so it cannot see a carriage that slips against its
//! encoder (a coupling giving way, a knock against the platform): the
//! controller counts on as if nothing happened. The camera sees the platform
//! itself.
//!
//! The frame. Vision is in pattern µm; [`DeviationJudge::set_frame`] gives
//! the rotation (and mirror) from vision to stage: the rig's vision tie
//! (`daemon::vision_tie`, taken after `reference`), else the active table's
//! vision frame (fitted by the characterization that built it) or, with
//! `safety.deviation_frame = "camera"`, `camera.rotation_rad`. The
//! translation is *tied*: the first good measurement with both axes at rest
//! (no move watched, two controller reads around the frame that agree)
//! after the daemon connected, after a `reset` and after a reference run
//! sets `tie = controller − R·vision`. From then on, per axis,
//!
//! `deviation = (R·vision + tie) − controller`   (µm, stage frame),
//!
//! positive when the platform stands farther along +axis than the
//! controller counts. Controller positions are only known at reads; a
//! frame is judged once a read after it exists, against the span of the
//! reads just before and just after it (at rest a point, while moving the
//! distance covered between two reads: the check is looser while moving by
//! about v × `safety.supervise_interval_ms`). Every move target sent between
//! those two reads widens the span, with the target in force when the
//! first of them was sent: a stage can leave and come back between two
//! reads (a drift re-measurement's detour to its reference is one move
//! there and one back, both shorter than a poll period on a fast rig), and
//! two reads that agree then say nothing about where it was in between.
//! Judged on the reads alone, such a frame was a false fault, and one taken
//! "at rest" for the tie offset it by the detour. `|deviation|` beyond the
//! span by more than the bound is the fault. A static stage error (tens of µm
//! over the travel, what compensation tables describe) and slow thermal
//! drift stay within it; the default bound (100 µm) is above both.
//!
//! No decode, no check: frames that do not decode (off the pattern, a
//! stalled camera) leave the judge without input, and that is not a fault;
//! the supervisor reports a move during which frames arrived but none
//! decoded (event `vision_unchecked`). Sans-IO: times are rig seconds.

use super::protocol::{DeviationStatus, PerAxis};
use super::state::AxisId;
use crate::comp::frame::VisionFrame;
use std::collections::VecDeque;

/// Most controller reads kept per axis (the oldest go first).
const MAX_SAMPLES: usize = 256;
/// Most frames waiting for a controller read after them.
const MAX_PENDING: usize = 64;
/// Two reads around a frame farther apart than this do not judge it (a
/// line that was silent in between), s.
const MAX_GAP_S: f64 = 2.0;
/// Reads around a frame that differ by less than this count as "at rest"
/// for the tie, µm.
const REST_UM: f64 = 1.0;

/// One controller position read: it happened between `t0_s` and `t1_s`.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Read {
    t0_s: f64,
    t1_s: f64,
    um: f64,
}

/// One move command of an axis: its target was sent between `t0_s` and
/// `t1_s` (the controller took it somewhere in between).
#[derive(Debug, Clone, Copy, PartialEq)]
struct Sent {
    t0_s: f64,
    t1_s: f64,
    target_um: f64,
}

/// A decoded frame in the stage's orientation (rotated, not yet tied).
#[derive(Debug, Clone, Copy, PartialEq)]
struct Seen {
    /// Grab requested (the exposure began no earlier), s.
    t0_s: f64,
    /// The frame's own stamp (its exposure ended no later), s.
    t1_s: f64,
    rotated_um: [f64; 2],
}

/// The outcome of judging the frames that could be judged.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Judged {
    /// The newest deviation judged, µm `[x, y]` (for `status`).
    pub last_um: Option<[f64; 2]>,
    /// A tie was taken (its offset, µm).
    pub tied_um: Option<[f64; 2]>,
    /// The fault to latch, if the bound was exceeded.
    pub fault: Option<String>,
}

/// The judge.
#[derive(Debug, Clone)]
pub struct DeviationJudge {
    bound_um: f64,
    frame: Option<VisionFrame>,
    reads: [VecDeque<Read>; 2],
    sent: [VecDeque<Sent>; 2],
    pending: VecDeque<Seen>,
    tie_um: Option<[f64; 2]>,
    /// Where the frame comes from, or why there is none (for `status`).
    frame_source: String,
    /// False after a breach until [`DeviationJudge::retie`]: one fault per
    /// breach, not one per frame.
    armed: bool,
    last_um: Option<[f64; 2]>,
}

impl DeviationJudge {
    /// A judge with bound `bound_um` (0: off), no frame and no tie yet.
    pub fn new(bound_um: f64) -> Self {
        Self {
            bound_um,
            frame: None,
            reads: [VecDeque::new(), VecDeque::new()],
            sent: [VecDeque::new(), VecDeque::new()],
            pending: VecDeque::new(),
            tie_um: None,
            frame_source: "no frame yet".to_owned(),
            armed: true,
            last_um: None,
        }
    }

    /// The vision → stage orientation (its translation is ignored: the tie
    /// replaces it); `None`: unknown, no check. `source`: where it comes
    /// from, or why there is none (for `status`). A change of orientation
    /// drops the tie.
    pub fn set_frame(&mut self, frame: Option<VisionFrame>, source: String) {
        self.frame_source = source;
        let orient = |f: &VisionFrame| (f.rotation_rad, f.mirrored);
        if self.frame.as_ref().map(orient) != frame.as_ref().map(orient) {
            self.frame = frame;
            self.tie_um = None;
            self.pending.clear();
        }
    }

    /// Forgets the tie, the reads and the frames waiting, and arms the
    /// check again: after `reset` (the operator acknowledged where the
    /// stage stands), after a reference run (the counts changed meaning)
    /// and when the stage (re)connects.
    pub fn retie(&mut self) {
        self.tie_um = None;
        self.reads = [VecDeque::new(), VecDeque::new()];
        self.sent = [VecDeque::new(), VecDeque::new()];
        self.pending.clear();
        self.armed = true;
        self.last_um = None;
    }

    /// Whether a tie is in force (the check is running).
    pub fn tied(&self) -> bool {
        self.tie_um.is_some()
    }

    /// Whether the check runs now: a bound, a frame, a tie at rest and no
    /// breach since the last [`DeviationJudge::retie`].
    pub fn checking(&self) -> bool {
        self.bound_um > 0.0 && self.frame.is_some() && self.tie_um.is_some() && self.armed
    }

    /// The state for `status`: `armed` is true only while the check runs
    /// ([`DeviationJudge::checking`]); `state` says in words what it does
    /// or why it does not, `frame` where its orientation comes from.
    pub fn to_reply(&self) -> DeviationStatus {
        let state = if self.bound_um <= 0.0 {
            "off: safety.deviation_um = 0".to_owned()
        } else if self.frame.is_none() {
            format!("off: {}", self.frame_source)
        } else if !self.armed {
            "off after a breach until reset".to_owned()
        } else if self.tie_um.is_none() {
            "waiting: it ties its translation at the first decoded frame with both axes at rest"
                .to_owned()
        } else {
            format!(
                "checking: vision − controller within ±{} µm per axis (stage frame)",
                self.bound_um
            )
        };
        DeviationStatus {
            armed: self.checking(),
            state,
            bound_um: self.bound_um,
            frame: self.frame.is_some().then(|| self.frame_source.clone()),
            frame_known: self.frame.is_some(),
            tied: self.tie_um.is_some(),
            last_um: self.last_um.map(PerAxis::of),
        }
    }

    /// [`to_reply`](Self::to_reply) as JSON.
    pub fn to_json(&self) -> serde_json::Value {
        super::protocol::to_value(&self.to_reply())
    }

    /// A controller position read of `axis` between `t0_s` and `t1_s`.
    pub fn controller(&mut self, axis: AxisId, t0_s: f64, t1_s: f64, um: f64) {
        if !(t0_s.is_finite() && t1_s.is_finite() && um.is_finite()) || t1_s < t0_s {
            return;
        }
        let q = &mut self.reads[idx(axis)];
        q.push_back(Read { t0_s, t1_s, um });
        while q.len() > MAX_SAMPLES {
            q.pop_front();
        }
    }

    /// A move of `axis` to `target_um` (controller µm) sent between `t0_s`
    /// and `t1_s`: frames between the reads around it are judged against
    /// a span that holds the target (see the module docs).
    pub fn commanded(&mut self, axis: AxisId, t0_s: f64, t1_s: f64, target_um: f64) {
        if !(t0_s.is_finite() && t1_s.is_finite() && target_um.is_finite()) || t1_s < t0_s {
            return;
        }
        let q = &mut self.sent[idx(axis)];
        q.push_back(Sent {
            t0_s,
            t1_s,
            target_um,
        });
        while q.len() > MAX_SAMPLES {
            q.pop_front();
        }
    }

    /// A decoded frame (pattern µm, already of good enough quality): grab
    /// requested at `t0_s`, stamped `t1_s`.
    pub fn vision(&mut self, t0_s: f64, t1_s: f64, x_um: f64, y_um: f64) {
        if self.bound_um <= 0.0 || !self.armed {
            return;
        }
        let Some(f) = &self.frame else { return };
        if ![t0_s, t1_s, x_um, y_um].iter().all(|v| v.is_finite()) {
            return;
        }
        let r = VisionFrame {
            translation_um: [0.0, 0.0],
            ..*f
        }
        .to_stage(crate::model::XyUm { x_um, y_um });
        self.pending.push_back(Seen {
            t0_s,
            t1_s: t1_s.max(t0_s),
            rotated_um: [r.x_um, r.y_um],
        });
        while self.pending.len() > MAX_PENDING {
            self.pending.pop_front();
        }
    }

    /// Judges every frame that has a controller read after it on both axes.
    /// `quiet`: no move is watched (a tie may be taken).
    pub fn judge(&mut self, quiet: bool) -> Judged {
        let mut out = Judged::default();
        while let Some(seen) = self.pending.front().copied() {
            let spans = [self.span(0, &seen), self.span(1, &seen)];
            let (sx, sy) = match spans {
                [Span::Later, _] | [_, Span::Later] => break,
                [Span::Known(a, b), Span::Known(c, d)] => ((a, b), (c, d)),
                _ => {
                    // No read before it (or a gap): not judged.
                    self.pending.pop_front();
                    continue;
                }
            };
            self.pending.pop_front();
            if !self.armed {
                continue;
            }
            let Some(tie) = self.tie_um else {
                if quiet && sx.1 - sx.0 < REST_UM && sy.1 - sy.0 < REST_UM {
                    let tie = [
                        0.5 * (sx.0 + sx.1) - seen.rotated_um[0],
                        0.5 * (sy.0 + sy.1) - seen.rotated_um[1],
                    ];
                    self.tie_um = Some(tie);
                    out.tied_um = Some(tie);
                }
                continue;
            };
            let mut dev = [0.0; 2];
            let mut breach = Vec::new();
            for (i, (lo, hi)) in [sx, sy].into_iter().enumerate() {
                let seen_um = seen.rotated_um[i] + tie[i];
                dev[i] = seen_um - seen_um.clamp(lo, hi);
                if dev[i].abs() > self.bound_um {
                    let name = if i == 0 { "x" } else { "y" };
                    breach.push(format!(
                        "axis {name}: vision deviation {:+.1} µm (vision {seen_um:.1} µm, controller {lo:.1}..{hi:.1} µm around the frame at t {:.3} s; vision − controller, stage frame; safety.deviation_um = {} µm)",
                        dev[i], seen.t0_s, self.bound_um
                    ));
                }
            }
            self.last_um = Some(dev);
            out.last_um = Some(dev);
            if !breach.is_empty() {
                self.armed = false;
                self.tie_um = None;
                self.pending.clear();
                out.fault = Some(breach.join("; "));
                break;
            }
        }
        out
    }

    /// The controller positions of axis `i` around the frame `seen`, as
    /// (low, high): the last read that ended before the grab and the first
    /// that began after the stamp, widened by every target sent between
    /// them and, if there is one, by the target in force when the first of
    /// those was sent (the stage may still have been on its way there).
    fn span(&self, i: usize, seen: &Seen) -> Span {
        let q = &self.reads[i];
        let before = q.iter().rev().find(|r| r.t1_s <= seen.t0_s);
        let after = q.iter().find(|r| r.t0_s >= seen.t1_s);
        let (b, a) = match (before, after) {
            (_, None) => return Span::Later,
            (None, Some(_)) => return Span::Never,
            (Some(b), Some(a)) if a.t0_s - b.t1_s > MAX_GAP_S => return Span::Never,
            (Some(b), Some(a)) => (b, a),
        };
        let (mut lo, mut hi) = (b.um.min(a.um), b.um.max(a.um));
        let sent = &self.sent[i];
        // Sent while the window [b.t0, a.t1] was open (the command's own
        // interval overlapping it: it may have reached the controller on
        // either side of a read's edge).
        let within = |c: &Sent| c.t1_s >= b.t0_s && c.t0_s <= a.t1_s;
        if sent.iter().any(within) {
            let in_force = sent.iter().rev().find(|c| c.t1_s < b.t0_s);
            for c in sent.iter().filter(|c| within(c)).chain(in_force) {
                lo = lo.min(c.target_um);
                hi = hi.max(c.target_um);
            }
        }
        Span::Known(lo, hi)
    }
}

/// What the reads say about an axis around a frame.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Span {
    /// Between these positions (low, high), µm.
    Known(f64, f64),
    /// No read after it yet.
    Later,
    /// It cannot be judged (no read before it, or a gap).
    Never,
}

fn idx(a: AxisId) -> usize {
    match a {
        AxisId::X => 0,
        AxisId::Y => 1,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use serde_json::{json, Value};

    fn frame(rot: f64, mirrored: bool) -> Option<VisionFrame> {
        Some(VisionFrame {
            rotation_rad: rot,
            mirrored,
            translation_um: [0.0, 0.0],
        })
    }

    /// A stage at `p` (stage µm) seen through `f` with translation `t`:
    /// the pattern coordinates the camera would decode.
    fn pattern(f: &VisionFrame, t: [f64; 2], p: [f64; 2]) -> (f64, f64) {
        let v = VisionFrame {
            translation_um: t,
            ..*f
        }
        .to_vision(crate::model::XyUm {
            x_um: p[0],
            y_um: p[1],
        });
        (v.x_um, v.y_um)
    }

    fn read_both(j: &mut DeviationJudge, t: f64, p: [f64; 2]) {
        j.controller(AxisId::X, t, t + 0.001, p[0]);
        j.controller(AxisId::Y, t, t + 0.001, p[1]);
    }

    /// The stage at rest at `p` (stage µm) from t 0 to 0.1 s, read on both
    /// sides of a frame seen through `f` with translation `t_off`: what
    /// the judge makes of it at rest (the tie).
    fn rest_at(j: &mut DeviationJudge, f: &VisionFrame, t_off: [f64; 2], p: [f64; 2]) -> Judged {
        read_both(j, 0.0, p);
        let (vx, vy) = pattern(f, t_off, p);
        j.vision(0.01, 0.02, vx, vy);
        read_both(j, 0.1, p);
        j.judge(true)
    }

    #[test]
    fn a_slip_at_rest_or_moving_beyond_the_bound_is_a_fault_within_it_is_not() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0xde71);
        for _ in 0..200 {
            let f = frame(
                rng.gen_range(-std::f64::consts::PI..std::f64::consts::PI),
                rng.gen_bool(0.5),
            )
            .unwrap();
            let t_off = [rng.gen_range(-2e4..2e4), rng.gen_range(-2e4..2e4)];
            let bound = rng.gen_range(20.0..200.0);
            let mut j = DeviationJudge::new(bound);
            j.set_frame(Some(f), String::new());
            let p0 = [rng.gen_range(0.0..15000.0), rng.gen_range(0.0..15000.0)];
            // At rest: the tie.
            let r = rest_at(&mut j, &f, t_off, p0);
            assert!(r.tied_um.is_some() && r.fault.is_none(), "{r:?}");
            // Moving at v along a random direction, the platform off the
            // count by `slip` on one axis (random sign and size).
            let v = [
                rng.gen_range(-1500.0..1500.0),
                rng.gen_range(-1500.0..1500.0),
            ];
            let axis = rng.gen_range(0..2usize);
            let slip = rng.gen_range(0.0..3.0 * bound) * if rng.gen_bool(0.5) { 1.0 } else { -1.0 };
            let moving = rng.gen_bool(0.5);
            let at = |t: f64| {
                if moving {
                    [p0[0] + v[0] * (t - 0.1), p0[1] + v[1] * (t - 0.1)]
                } else {
                    p0
                }
            };
            read_both(&mut j, 0.2, at(0.2));
            let mut truth = at(0.25);
            truth[axis] += slip;
            let (vx, vy) = pattern(&f, t_off, truth);
            j.vision(0.25, 0.25, vx, vy);
            read_both(&mut j, 0.3, at(0.3));
            let r = j.judge(!moving);
            // Within the span of the reads around it, the frame is on the
            // count; beyond by more than the bound, a fault.
            let (a, b) = (at(0.2)[axis], at(0.3)[axis]);
            let (lo, hi) = (a.min(b), a.max(b));
            let seen = truth[axis];
            let beyond = seen - seen.clamp(lo - 1e-6, hi + 1e-6);
            if beyond.abs() > bound * 1.001 {
                let e = r.fault.expect("a fault");
                let name = if axis == 0 { "axis x" } else { "axis y" };
                assert!(e.contains(name) && e.contains("vision deviation"), "{e}");
                let sign = if slip > 0.0 { "+" } else { "-" };
                assert!(e.contains(&format!("deviation {sign}")), "{e}");
                // Disarmed until retie: later frames are not judged.
                j.vision(0.35, 0.35, vx, vy);
                read_both(&mut j, 0.4, at(0.3));
                assert_eq!(j.judge(true), Judged::default());
            } else if beyond.abs() < bound * 0.999 {
                assert!(r.fault.is_none(), "{r:?} slip {slip} bound {bound}");
                let d = r.last_um.unwrap();
                assert!((d[axis] - beyond).abs() < 1e-3, "{d:?} vs {beyond}");
            }
        }
    }

    /// A stage driven by random moves (some sent before the last one
    /// arrived, many out and back within one read period, as a drift
    /// re-measurement's detour to its reference is), read now and then and
    /// seen often, with no slip: never a fault, and every tie the true one.
    /// Judged on the reads alone, the detours gave both false faults and
    /// ties offset by the detour.
    #[test]
    fn moves_between_two_reads_neither_fault_nor_offset_the_tie() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0x5e47);
        let (mut detours, mut ties) = (0, 0);
        for case in 0..200 {
            let f = frame(
                rng.gen_range(-std::f64::consts::PI..std::f64::consts::PI),
                rng.gen_bool(0.5),
            )
            .unwrap();
            let t_off = [rng.gen_range(-2e4..2e4), rng.gen_range(-2e4..2e4)];
            let mut j = DeviationJudge::new(rng.gen_range(20.0..200.0));
            j.set_frame(Some(f), String::new());
            let v_um_s = rng.gen_range(200.0..20000.0);
            let read_period_s = rng.gen_range(0.02..1.0);
            let mut pos = [rng.gen_range(0.0..15000.0), rng.gen_range(0.0..15000.0)];
            let mut target = pos;
            let dt = 1e-3;
            let (mut next_read, mut next_frame) = (0.0, 0.0);
            let mut next_cmd = rng.gen_range(0.0..0.5);
            // Where a detour returns to.
            let mut back: Option<[f64; 2]> = None;
            let mut t = 0.0;
            while t < 4.0 {
                if t >= next_cmd {
                    let home = target;
                    target = if let Some(b) = back.take() {
                        b
                    } else if rng.gen_bool(0.4) {
                        detours += 1;
                        back = Some(home);
                        [
                            home[0] + rng.gen_range(-600.0..600.0),
                            home[1] + rng.gen_range(-600.0..600.0),
                        ]
                    } else {
                        [rng.gen_range(0.0..15000.0), rng.gen_range(0.0..15000.0)]
                    };
                    for a in [AxisId::X, AxisId::Y] {
                        j.commanded(a, t, t + 2e-4, target[idx(a)]);
                    }
                    next_cmd = t + if back.is_some() {
                        rng.gen_range(0.005..0.15)
                    } else {
                        rng.gen_range(0.005..0.6)
                    };
                }
                for i in 0..2 {
                    pos[i] += (target[i] - pos[i]).clamp(-v_um_s * dt, v_um_s * dt);
                }
                if t >= next_frame {
                    let (vx, vy) = pattern(&f, t_off, pos);
                    j.vision(t, t + 5e-4, vx, vy);
                    next_frame = t + 0.004;
                }
                if t >= next_read {
                    read_both(&mut j, t, pos);
                    next_read = t + read_period_s * rng.gen_range(0.5..1.5);
                }
                let r = j.judge(pos == target);
                assert!(r.fault.is_none(), "case {case} t {t}: false fault: {r:?}");
                if let Some(tie) = r.tied_um {
                    ties += 1;
                    // R·vision + tie is the controller's count, anywhere.
                    let (vx, vy) = pattern(&f, t_off, pos);
                    let rot = VisionFrame {
                        translation_um: [0.0, 0.0],
                        ..f
                    }
                    .to_stage(crate::model::XyUm { x_um: vx, y_um: vy });
                    let seen = [rot.x_um + tie[0], rot.y_um + tie[1]];
                    assert!(
                        (seen[0] - pos[0]).abs() < REST_UM && (seen[1] - pos[1]).abs() < REST_UM,
                        "case {case}: tie off: {seen:?} vs {pos:?}"
                    );
                    // As after a `reset`: the next tie is checked too.
                    j.retie();
                }
                t += dt;
            }
        }
        assert!(
            detours > 300 && ties > 100,
            "{detours} detours, {ties} ties"
        );
    }

    /// Tied at rest; between two reads at the same place the stage goes to
    /// a reference 500 µm away and back. A frame there is on the count; the
    /// same frame off it by more than the bound beyond the detour is still a
    /// fault.
    #[test]
    fn a_detour_between_two_reads_is_on_the_count_and_a_slip_in_it_is_not() {
        // Where the frame sees the platform on x, and whether that is a fault
        // (bound 50 µm; the detour spans 7000..7500 µm).
        for (seen_x, fault) in [
            (7000.0, false),
            (7250.0, false),
            (6920.0, true),
            (7580.0, true),
        ] {
            let f = frame(0.3, false).unwrap();
            let t_off = [1000.0, -2000.0];
            let mut j = DeviationJudge::new(50.0);
            j.set_frame(Some(f), String::new());
            let home = [7500.0, 7500.0];
            let corner = [7000.0, 7000.0];
            assert!(rest_at(&mut j, &f, t_off, home).tied_um.is_some());
            for (a, i) in [(AxisId::X, 0), (AxisId::Y, 1)] {
                j.commanded(a, 0.11, 0.111, corner[i]);
            }
            let (vx, vy) = pattern(&f, t_off, [seen_x, corner[1]]);
            j.vision(0.15, 0.151, vx, vy);
            for (a, i) in [(AxisId::X, 0), (AxisId::Y, 1)] {
                j.commanded(a, 0.16, 0.161, home[i]);
            }
            read_both(&mut j, 0.2, home);
            let r = j.judge(true);
            assert!(r.tied_um.is_none(), "{r:?}");
            if fault {
                let e = r
                    .fault
                    .clone()
                    .unwrap_or_else(|| panic!("a fault at {seen_x}: {r:?}"));
                assert!(e.contains("axis x") && !e.contains("axis y"), "{e}");
            } else {
                assert!(r.fault.is_none(), "{r:?}");
                assert_eq!(
                    r.last_um
                        .map(|d| d.map(f64::abs).iter().sum::<f64>() < 1e-6),
                    Some(true)
                );
            }
        }
    }

    /// Read on its way out to a target (7200 µm, bound for 7000), the stage
    /// goes on to 7050 µm before the command back to 7500 µm comes: a frame
    /// at 7050 µm is on the count (the target in force then widens the span
    /// of the reads at 7200 and 7500 µm).
    #[test]
    fn the_target_in_force_when_a_move_overtakes_it_counts_too() {
        let f = frame(-1.2, true).unwrap();
        let t_off = [300.0, 400.0];
        let mut j = DeviationJudge::new(50.0);
        j.set_frame(Some(f), String::new());
        assert!(rest_at(&mut j, &f, t_off, [7500.0, 7500.0])
            .tied_um
            .is_some());
        j.commanded(AxisId::X, 0.11, 0.111, 7000.0);
        read_both(&mut j, 0.2, [7200.0, 7500.0]);
        let (vx, vy) = pattern(&f, t_off, [7050.0, 7500.0]);
        j.vision(0.25, 0.251, vx, vy);
        j.commanded(AxisId::X, 0.26, 0.261, 7500.0);
        read_both(&mut j, 0.4, [7500.0, 7500.0]);
        let r = j.judge(false);
        assert!(r.fault.is_none(), "{r:?}");
        assert_eq!(r.last_um.map(|d| d[0].abs() < 1e-6), Some(true), "{r:?}");
    }

    #[test]
    fn no_frame_no_tie_no_check_and_a_frame_waits_for_a_read_after_it() {
        let mut j = DeviationJudge::new(50.0);
        read_both(&mut j, 0.0, [100.0, 100.0]);
        j.vision(0.01, 0.01, 0.0, 0.0);
        read_both(&mut j, 0.1, [100.0, 100.0]);
        assert_eq!(j.judge(true), Judged::default());
        j.set_frame(frame(0.0, false), String::new());
        j.vision(0.11, 0.12, 5.0, -5.0);
        // No read after the frame yet: waits.
        assert_eq!(j.judge(true), Judged::default());
        read_both(&mut j, 0.2, [100.0, 100.0]);
        let r = j.judge(true);
        assert_eq!(r.tied_um, Some([95.0, 105.0]));
        // While moving no tie is taken: a fresh judge stays untied.
        let mut k = DeviationJudge::new(50.0);
        k.set_frame(frame(0.0, false), String::new());
        read_both(&mut k, 0.0, [0.0, 0.0]);
        k.vision(0.01, 0.01, 0.0, 0.0);
        read_both(&mut k, 0.1, [0.0, 0.0]);
        assert!(k.judge(false).tied_um.is_none());
        assert!(!k.tied());
        // A gap of silence around a frame: not judged.
        let mut g = DeviationJudge::new(50.0);
        g.set_frame(frame(0.0, false), String::new());
        read_both(&mut g, 0.0, [0.0, 0.0]);
        g.vision(1.0, 1.0, 0.0, 0.0);
        read_both(&mut g, 3.5, [0.0, 0.0]);
        assert_eq!(g.judge(true), Judged::default());
    }

    #[test]
    fn a_new_orientation_or_a_retie_drops_the_tie() {
        let mut j = DeviationJudge::new(50.0);
        j.set_frame(frame(0.5, false), String::new());
        read_both(&mut j, 0.0, [0.0, 0.0]);
        j.vision(0.01, 0.01, 0.0, 0.0);
        read_both(&mut j, 0.1, [0.0, 0.0]);
        assert!(j.judge(true).tied_um.is_some());
        // The same orientation with another translation keeps it.
        j.set_frame(
            Some(VisionFrame {
                rotation_rad: 0.5,
                mirrored: false,
                translation_um: [1.0, 2.0],
            }),
            String::new(),
        );
        assert!(j.tied());
        j.set_frame(frame(0.5, true), String::new());
        assert!(!j.tied());
        read_both(&mut j, 0.2, [0.0, 0.0]);
        j.vision(0.21, 0.21, 0.0, 0.0);
        read_both(&mut j, 0.3, [0.0, 0.0]);
        assert!(j.judge(true).tied_um.is_some());
        j.retie();
        assert!(!j.tied());
    }

    /// `status` says armed only while the check runs, and why not
    /// otherwise (before: `armed: true` with no frame and no tie, the
    /// check silently off).
    #[test]
    fn armed_only_while_checking_and_says_why_not() {
        let mut j = DeviationJudge::new(50.0);
        j.set_frame(
            None,
            "vision is not tied to the stage: no reference run".to_owned(),
        );
        let s = j.to_json();
        assert_eq!(
            (s["armed"].clone(), s["tied"].clone()),
            (json!(false), json!(false))
        );
        assert_eq!(
            s["state"],
            "off: vision is not tied to the stage: no reference run"
        );
        assert_eq!(s["frame"], Value::Null);
        j.set_frame(frame(0.5, false), "tie after reference".to_owned());
        let s = j.to_json();
        assert_eq!(s["armed"], false);
        assert!(s["state"].as_str().unwrap().starts_with("waiting: "), "{s}");
        assert_eq!(s["frame"], "tie after reference");
        read_both(&mut j, 0.0, [0.0, 0.0]);
        j.vision(0.01, 0.01, 0.0, 0.0);
        read_both(&mut j, 0.1, [0.0, 0.0]);
        j.judge(true);
        let s = j.to_json();
        assert_eq!(
            (s["armed"].clone(), s["tied"].clone()),
            (json!(true), json!(true))
        );
        assert!(
            s["state"].as_str().unwrap().starts_with("checking: "),
            "{s}"
        );
        // A breach disarms it until retie.
        read_both(&mut j, 0.2, [0.0, 0.0]);
        j.vision(0.21, 0.21, 500.0, 0.0);
        read_both(&mut j, 0.3, [0.0, 0.0]);
        assert!(j.judge(true).fault.is_some());
        let s = j.to_json();
        assert_eq!(s["armed"], false);
        assert_eq!(s["state"], "off after a breach until reset");
        let mut off = DeviationJudge::new(0.0);
        off.set_frame(frame(0.5, false), String::new());
        assert_eq!(off.to_json()["state"], "off: safety.deviation_um = 0");
    }
}
