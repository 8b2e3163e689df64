//! The stateful, stochastic side of the model: what `hil-sim` runs.
//!
//! [`StageSimulator`] keeps the servo position of each axis, the motion
//! history (through [`MotionTracker`], which is where the play state lives, as
//! run lengths that do not depend on the backlash parameter) and the current
//! settling error, and evaluates the systematic [`StageModel`] on top. Sans-IO:
//! the caller gives simulated time; seeded, so a run is reproducible.
//!
//! Per move of an axis, in order:
//! 1. the target is rounded to `position_quantum_um` (if non-zero);
//! 2. if it is closer than `min_incremental_motion_um` to where the servo is,
//!    nothing happens (no motion, no new settling error, history unchanged);
//! 3. otherwise the servo (screw) goes exactly there and a new settling error
//!    `N(0, σ_axis)` is drawn for that axis; it stays until the axis moves
//!    again.
//!
//! `true = servo + Σ Platform terms + settling error`,
//! `observed = true + Σ Observation terms`.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use serde::{Deserialize, Serialize};

use super::state::{Axis, MotionState, MotionTracker, Waypoint};
use super::{ModelError, StageModel, XyUm};

/// The outcome of one simulator step.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SimStep {
    /// What was asked for, µm.
    pub commanded: XyUm,
    /// The state the model was evaluated on (servo positions, history,
    /// time, temperature).
    pub state: MotionState,
    /// Which axes actually moved `[x, y]`.
    pub moved: [bool; 2],
    /// Where the platform really is, µm (ground truth).
    pub true_um: XyUm,
    /// Where the camera sees it, µm (ground truth plus observation terms,
    /// before any camera noise).
    pub observed_um: XyUm,
    /// Settling error currently applied `[x, y]`, µm.
    pub settling_um: [f64; 2],
}

/// See the module docs.
#[derive(Debug, Clone)]
pub struct StageSimulator {
    model: StageModel,
    tracker: MotionTracker,
    rng: ChaCha8Rng,
    settling_um: [f64; 2],
    last_commanded: XyUm,
}

impl StageSimulator {
    /// Starts at `start` (e.g. [`MotionState::at_rest`] at the reference
    /// position) with settling error 0. `seed` fixes every random draw.
    pub fn new(model: StageModel, start: MotionState, seed: u64) -> Result<Self, ModelError> {
        let tracker = MotionTracker::new(start)?;
        let c = start.cmd_xy_um();
        Ok(StageSimulator {
            model,
            tracker,
            rng: ChaCha8Rng::seed_from_u64(seed),
            settling_um: [0.0; 2],
            last_commanded: XyUm::from(c),
        })
    }

    /// The model being run.
    pub fn model(&self) -> &StageModel {
        &self.model
    }

    /// The current state.
    pub fn state(&self) -> &MotionState {
        self.tracker.state()
    }

    /// Commands both axes to `(x_um, y_um)` and lets them settle at `time_s`
    /// (ambient temperature from the model's environment). Non-finite input
    /// is rejected and changes nothing.
    pub fn move_to(
        &mut self,
        x_um: f64,
        y_um: f64,
        time_s: f64,
        cycle: u32,
    ) -> Result<SimStep, ModelError> {
        for (what, v) in [
            ("target x_um", x_um),
            ("target y_um", y_um),
            ("time_s", time_s),
        ] {
            if !v.is_finite() {
                return Err(ModelError::NonFinite { what: what.into() });
            }
        }
        let st = *self.tracker.state();
        let stoch = self.model.stochastic();
        let mut servo = st.cmd_xy_um();
        let mut moved = [false; 2];
        for (i, target) in [x_um, y_um].into_iter().enumerate() {
            let q = stoch.position_quantum_um;
            let t = if q > 0.0 {
                (target / q).round() * q
            } else {
                target
            };
            if !t.is_finite() {
                return Err(ModelError::NonFinite {
                    what: "quantized target".into(),
                });
            }
            let d = (t - servo[i]).abs();
            if d > 0.0 && d >= stoch.min_incremental_motion_um {
                servo[i] = t;
                moved[i] = true;
            }
        }
        let temp_c = self.model.environment().temperature_at(time_s);
        let state = self.tracker.step(Waypoint {
            x_um: servo[0],
            y_um: servo[1],
            time_s,
            temp_c,
            cycle,
        })?;
        let stoch = self.model.stochastic();
        for i in 0..2 {
            if moved[i] {
                let z: f64 = StandardNormal.sample(&mut self.rng);
                self.settling_um[i] = stoch.settling_sigma_um(i, servo[i]) * z;
            }
        }
        self.last_commanded = XyUm { x_um, y_um };
        checked(self.evaluate(state, moved))
    }

    /// Commands one axis only (each C-863 moves its own axis); the other
    /// stays where its servo is.
    pub fn move_axis(
        &mut self,
        axis: Axis,
        target_um: f64,
        time_s: f64,
        cycle: u32,
    ) -> Result<SimStep, ModelError> {
        let mut t = self.tracker.state().cmd_xy_um();
        t[axis.index()] = target_um;
        let keep = self.last_commanded;
        let step = self.move_to(t[0], t[1], time_s, cycle);
        // Remember what was asked of the other axis too, not its servo
        // position.
        if step.is_ok() {
            match axis {
                Axis::X => self.last_commanded.y_um = keep.y_um,
                Axis::Y => self.last_commanded.x_um = keep.x_um,
            }
        }
        step.map(|mut s| {
            s.commanded = self.last_commanded;
            s
        })
    }

    /// Where the platform would be with the screws at `(x_um, y_um)` at
    /// `time_s`, without committing anything: no history change, no new
    /// settling draw. For rendering the camera while the stage is still
    /// travelling.
    ///
    /// An axis away from where it was last sent is travelling: its
    /// settling error, the servo's scatter at rest, does not apply (the
    /// servo tracks the trajectory; a new error is drawn where it stops).
    /// An axis at rest keeps its own. Why it matters: a
    /// rest error carried through a constant-velocity pass is an offset
    /// constant over the pass, which a sweep characterization cannot tell
    /// from the camera delay (σ 0.035 µm per pass read as ≈ ±0.2 ms).
    pub fn preview(&self, x_um: f64, y_um: f64, time_s: f64) -> Result<SimStep, ModelError> {
        let mut tracker = self.tracker.clone();
        let temp_c = self.model.environment().temperature_at(time_s);
        // Where each axis was last sent (its target, before rounding to the
        // quantum and the minimum motion): equal to it means at rest.
        let rest = [self.last_commanded.x_um, self.last_commanded.y_um];
        let cycle = tracker.state().cycle;
        let state = tracker.step(Waypoint {
            x_um,
            y_um,
            time_s,
            temp_c,
            cycle,
        })?;
        let settling = [
            if x_um == rest[0] {
                self.settling_um[0]
            } else {
                0.0
            },
            if y_um == rest[1] {
                self.settling_um[1]
            } else {
                0.0
            },
        ];
        let mut step = checked(self.evaluate_with(state, [false; 2], settling))?;
        step.commanded = XyUm { x_um, y_um };
        Ok(step)
    }

    /// Lets time pass without motion (the room drifts, the platform and the
    /// view follow the thermal terms).
    pub fn wait(&mut self, time_s: f64) -> Result<SimStep, ModelError> {
        if !time_s.is_finite() {
            return Err(ModelError::NonFinite {
                what: "time_s".into(),
            });
        }
        let temp_c = self.model.environment().temperature_at(time_s);
        let state = self.tracker.wait(time_s, temp_c)?;
        checked(self.evaluate(state, [false; 2]))
    }

    /// The current step again (no motion, no time).
    pub fn current(&self) -> SimStep {
        self.evaluate(*self.tracker.state(), [false; 2])
    }

    fn evaluate(&self, state: MotionState, moved: [bool; 2]) -> SimStep {
        self.evaluate_with(state, moved, self.settling_um)
    }

    fn evaluate_with(&self, state: MotionState, moved: [bool; 2], settling: [f64; 2]) -> SimStep {
        let platform = self.model.platform_error_um(&state);
        let all = self.model.observed_error_um(&state);
        let c = state.cmd_xy_um();
        let t = [
            c[0] + platform[0] + settling[0],
            c[1] + platform[1] + settling[1],
        ];
        let o = [t[0] + all[0] - platform[0], t[1] + all[1] - platform[1]];
        SimStep {
            commanded: self.last_commanded,
            state,
            moved,
            true_um: t.into(),
            observed_um: o.into(),
            settling_um: settling,
        }
    }
}

/// A model with valid parameters and a valid state is finite; this keeps a
/// NaN from ever reaching a simulated controller or camera if that is ever
/// broken (e.g. by a term registered from outside).
fn checked(step: SimStep) -> Result<SimStep, ModelError> {
    let v = [
        step.true_um.x_um,
        step.true_um.y_um,
        step.observed_um.x_um,
        step.observed_um.y_um,
    ];
    if v.iter().all(|x| x.is_finite()) {
        Ok(step)
    } else {
        Err(ModelError::NonFinite {
            what: "simulated position (a model term returned a non-finite value)".into(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::env::Stochastic;
    use crate::model::terms::{BacklashConfig, BacklashTerm};

    fn backlash_only(min_inc: f64, sigma: f64) -> StageModel {
        let mut m = StageModel::ideal();
        m.push_term(Box::new(
            BacklashTerm::new(
                "xb",
                BacklashConfig {
                    axis: Axis::X,
                    backlash_um: 2.0,
                },
            )
            .unwrap(),
        ))
        .unwrap();
        m.set_stochastic(Stochastic {
            repeatability_sigma_um: [sigma, sigma],
            min_incremental_motion_um: min_inc,
            position_quantum_um: 0.0,
            rough_spots: Vec::new(),
        })
        .unwrap();
        m
    }

    #[test]
    fn short_move_after_reversal_does_not_move_the_platform() {
        let mut s = StageSimulator::new(backlash_only(0.0, 0.0), MotionState::at_rest(0.0, 0.0), 1)
            .unwrap();
        s.move_to(100.0, 0.0, 1.0, 0).unwrap();
        let a = s.move_to(50.0, 0.0, 2.0, 0).unwrap();
        assert_eq!(a.true_um.x_um, 51.0);
        let b = s.move_to(51.0, 0.0, 3.0, 0).unwrap();
        assert_eq!(b.true_um.x_um, 51.0, "1 µm back into a 2 µm play");
        let c = s.move_to(60.0, 0.0, 4.0, 0).unwrap();
        assert_eq!(c.true_um.x_um, 59.0);
    }

    #[test]
    fn moves_below_the_resolution_do_not_happen() {
        let mut s =
            StageSimulator::new(backlash_only(0.05, 0.03), MotionState::at_rest(0.0, 0.0), 7)
                .unwrap();
        let a = s.move_to(10.0, 5.0, 1.0, 0).unwrap();
        assert_eq!(a.moved, [true, true]);
        let b = s.move_to(10.03, 5.0, 2.0, 0).unwrap();
        assert_eq!(b.moved, [false, false]);
        assert_eq!(b.true_um, a.true_um);
        assert_eq!(b.state.cmd_xy_um(), [10.0, 5.0]);
        let c = s.move_to(10.06, 5.0, 3.0, 0).unwrap();
        assert_eq!(c.moved, [true, false]);
        assert_ne!(c.settling_um[0], a.settling_um[0]);
        assert_eq!(c.settling_um[1], a.settling_um[1]);
    }

    #[test]
    fn single_axis_moves_and_previews() {
        let mut s = StageSimulator::new(backlash_only(0.0, 0.0), MotionState::at_rest(0.0, 0.0), 1)
            .unwrap();
        s.move_to(100.0, 20.0, 1.0, 0).unwrap();
        let a = s.move_axis(Axis::Y, 50.0, 2.0, 0).unwrap();
        assert_eq!(a.moved, [false, true]);
        assert_eq!(a.state.cmd_xy_um(), [100.0, 50.0]);
        assert_eq!(
            a.commanded,
            XyUm {
                x_um: 100.0,
                y_um: 50.0
            }
        );
        // Mid-travel back to 98 µm: 2 µm into the play, the platform has
        // not moved yet; the preview commits nothing.
        let before = *s.state();
        let p = s.preview(98.0, 50.0, 2.5).unwrap();
        assert_eq!(p.true_um.x_um, 99.0);
        assert_eq!(*s.state(), before);
        assert!(s.move_axis(Axis::X, f64::NAN, 3.0, 0).is_err());
    }

    /// A travelling axis carries no rest error; the axis at rest keeps its
    /// own, and where the travel ends a new one is drawn.
    #[test]
    fn travel_drops_the_rest_error_of_the_moving_axis() {
        let mut s = StageSimulator::new(backlash_only(0.0, 0.5), MotionState::at_rest(0.0, 0.0), 3)
            .unwrap();
        let a = s.move_to(100.0, 20.0, 1.0, 0).unwrap();
        assert!(a.settling_um[0].abs() > 0.0 && a.settling_um[1].abs() > 0.0);
        let still = s.preview(100.0, 20.0, 1.5).unwrap();
        assert_eq!(still.true_um, a.true_um);
        let p = s.preview(140.0, 20.0, 1.5).unwrap();
        assert_eq!(p.settling_um, [0.0, a.settling_um[1]]);
        // Forward motion with the play taken up: the platform trails by B/2 = 1.
        assert!((p.true_um.x_um - 139.0).abs() < 1e-12, "{p:?}");
        assert_eq!(p.true_um.y_um, a.true_um.y_um);
        let b = s.move_to(140.0, 20.0, 2.0, 0).unwrap();
        assert_ne!(b.settling_um[0], 0.0);
        assert_eq!(b.settling_um[1], a.settling_um[1]);
    }

    #[test]
    fn seeded_runs_repeat_and_bad_input_is_rejected() {
        let m = StageModel::paper_default().unwrap();
        let run = |seed| {
            let mut s =
                StageSimulator::new(m.clone(), MotionState::at_rest(7500.0, 7500.0), seed).unwrap();
            (0..20)
                .map(|i| {
                    s.move_to(7000.0 + 37.0 * i as f64, 7300.0, i as f64, 0)
                        .unwrap()
                        .true_um
                })
                .collect::<Vec<_>>()
        };
        assert_eq!(run(3), run(3));
        assert_ne!(run(3), run(4));
        let mut s = StageSimulator::new(m, MotionState::at_rest(0.0, 0.0), 0).unwrap();
        assert!(s.move_to(f64::NAN, 0.0, 0.0, 0).is_err());
        assert!(s.wait(f64::INFINITY).is_err());
        assert_eq!(s.state().cmd_xy_um(), [0.0, 0.0]);
    }
}
