//! Backlash as play between screw and nut/platform.
//!
//! Physics: the nut has `B` µm of axial play on the screw. While the screw
//! pushes in one direction the platform trails it by `B/2` (measured from
//! the centre of the play); after a reversal the first `B` µm of commanded
//! motion only cross the gap and the platform does not move. That is the
//! classic play (backlash) operator: with `o` = platform − screw,
//!
//! ```text
//! on a screw move Δu:   o ← clamp(o − Δu, −B/2, +B/2)
//! ```
//!
//! After a long forward run `o = −B/2`, after a long backward run `o = +B/2`:
//! the forward and backward error curves are offset by `B` (the paper's
//! ≈ 2 µm between the two directions of Fig. 4). After a short move the offset
//! depends on the move length, which a direction-only lookup table cannot
//! represent.
//!
//! The term is stateless: it replays the play operator over the history in
//! [`AxisMotion`]: the run before the last reversal (`prev_run_um`) and the
//! current run (`run_um`), starting from the play fully taken up by the run
//! before those (or centred when `prev_run_um` is `None`, the start of the
//! history). That equals [`PlayOperator`] driven by the full sequence except
//! when the run before the previous one was itself shorter than `B` (a
//! zigzag of three or more sub-`B` runs), where it may differ by up to `B`.
//!
//! For fitting, `B < 0` is accepted as the linear continuation `o = −dir·B/2`
//! (a model file must say `B ≥ 0`).

use serde::{Deserialize, Serialize};

use super::super::spec::{param, ParamSpec, SpecTerm, TermSpec};
use super::super::state::{Axis, AxisMotion, Direction, MotionState};

/// Kind name.
pub const KIND: &str = "backlash";

/// Model-file table of a backlash term.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BacklashConfig {
    /// The axis with the play.
    pub axis: Axis,
    /// Total play `B` between screw and nut, µm (≥ 0). The platform lags the
    /// screw by `B/2` while pushed; a reversal loses `B` µm of motion.
    pub backlash_um: f64,
}

/// The stateful play operator, exact for any input history. The simulator's
/// tests and the proptests use it as the reference for [`play_offset_um`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlayOperator {
    half_um: f64,
    offset_um: f64,
}

impl PlayOperator {
    /// Play of total width `backlash_um` (negative taken as 0), starting
    /// centred.
    pub fn new(backlash_um: f64) -> Self {
        let half_um = if backlash_um.is_finite() {
            backlash_um.max(0.0) / 2.0
        } else {
            0.0
        };
        PlayOperator {
            half_um,
            offset_um: 0.0,
        }
    }

    /// Moves the screw by `delta_um`; returns the new platform − screw
    /// offset, always within ±B/2.
    pub fn step(&mut self, delta_um: f64) -> f64 {
        if delta_um.is_finite() {
            self.offset_um = (self.offset_um - delta_um).clamp(-self.half_um, self.half_um);
        }
        self.offset_um
    }

    /// Current platform − screw offset, µm.
    pub fn offset_um(&self) -> f64 {
        self.offset_um
    }
}

/// Platform − screw offset (µm) for a play of `backlash_um` after the history
/// in `axis` (see the module docs for the exactness condition).
pub fn play_offset_um(axis: &AxisMotion, backlash_um: f64) -> f64 {
    let d = axis.dir.sign();
    if axis.dir == Direction::Unknown || !backlash_um.is_finite() {
        return 0.0;
    }
    if backlash_um <= 0.0 {
        return -d * backlash_um / 2.0;
    }
    let h = backlash_um / 2.0;
    let start = match axis.prev_run_um {
        None => 0.0,
        // Before the previous run the axis moved in direction `d` long
        // enough: o = −d·h. The previous run moved by −d·prev.
        Some(prev) => (-d * h + d * prev).clamp(-h, h),
    };
    (start - d * axis.run_um).clamp(-h, h)
}

/// The backlash kind: one parameter, `backlash_um`, non-linear.
#[derive(Debug, Clone, PartialEq)]
pub struct Backlash;

/// The backlash term.
pub type BacklashTerm = SpecTerm<Backlash>;

impl TermSpec for Backlash {
    type Config = BacklashConfig;
    const KIND: &'static str = KIND;
    const PARAMS: &'static [ParamSpec<BacklashConfig>] = &[param!(
        backlash_um,
        "µm",
        NonNegative,
        |c| {
            format!(
                "play between screw and nut of {}: lost motion on reversal; the platform trails the screw by half of it",
                c.axis
            )
        },
        nonlinear
    )];

    fn contribution(cfg: &BacklashConfig, state: &MotionState) -> [f64; 2] {
        let mut out = [0.0; 2];
        out[cfg.axis.index()] = play_offset_um(state.axis(cfg.axis), cfg.backlash_um);
        out
    }
}

#[cfg(test)]
mod tests {
    use super::super::super::term::Term;
    use super::*;

    fn axis(dir: Direction, run: f64, prev: Option<f64>) -> AxisMotion {
        AxisMotion {
            cmd_um: 0.0,
            dir,
            run_um: run,
            prev_run_um: prev,
            last_move_um: run,
        }
    }

    #[test]
    fn long_runs_trail_by_half_the_play() {
        assert_eq!(
            play_offset_um(&axis(Direction::Forward, 50.0, Some(50.0)), 2.0),
            -1.0
        );
        assert_eq!(
            play_offset_um(&axis(Direction::Backward, 50.0, Some(50.0)), 2.0),
            1.0
        );
        assert_eq!(
            play_offset_um(&axis(Direction::Unknown, 0.0, None), 2.0),
            0.0
        );
    }

    #[test]
    fn short_move_after_reversal_crosses_the_gap_first() {
        // Long backward run (o = +1), then 0.5 µm forward: platform does not
        // move, the screw advanced 0.5 µm: o = +0.5.
        assert_eq!(
            play_offset_um(&axis(Direction::Forward, 0.5, Some(100.0)), 2.0),
            0.5
        );
        // 1.5 µm forward: o = −0.5; 2 µm or more: −1.
        assert_eq!(
            play_offset_um(&axis(Direction::Forward, 1.5, Some(100.0)), 2.0),
            -0.5
        );
        assert_eq!(
            play_offset_um(&axis(Direction::Forward, 3.0, Some(100.0)), 2.0),
            -1.0
        );
        // Previous run of only 0.5 µm backward after a long forward run:
        // o went −1 → −0.5; now 0.25 µm forward: o = −0.75.
        assert_eq!(
            play_offset_um(&axis(Direction::Forward, 0.25, Some(0.5)), 2.0),
            -0.75
        );
        // From the centred start: 0.3 µm forward → o = −0.3.
        assert_eq!(
            play_offset_um(&axis(Direction::Forward, 0.3, None), 2.0),
            -0.3
        );
    }

    #[test]
    fn matches_the_play_operator_on_a_history() {
        let b = 2.0;
        let mut op = PlayOperator::new(b);
        // Long run backward, then short forward, then short backward.
        op.step(-10.0);
        op.step(0.7);
        let o = op.step(-0.4);
        assert_eq!(
            play_offset_um(&axis(Direction::Backward, 0.4, Some(0.7)), b),
            o
        );
    }

    #[test]
    fn term_puts_it_on_its_axis() {
        let t = BacklashTerm::new(
            "yb",
            BacklashConfig {
                axis: Axis::Y,
                backlash_um: 2.0,
            },
        )
        .unwrap();
        let s = MotionState::arrived(0.0, Direction::Forward, 0.0, Direction::Backward);
        assert_eq!(t.contribution(&s), [0.0, 1.0]);
        let j = t.jacobian(&s);
        assert!((j[0][1] - 0.5).abs() < 1e-9, "{j:?}");
        assert!(BacklashTerm::new(
            "yb",
            BacklashConfig {
                axis: Axis::Y,
                backlash_um: -1.0
            }
        )
        .is_err());
    }
}
