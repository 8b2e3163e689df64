//! What the model is evaluated on: the commanded position of both axes plus
//! the bits of motion history a log can hold.
//!
//! Why history and not just position: a leadscrew stage does not land in the
//! same place when it arrives from the left or from the right (backlash,
//! direction-dependent cyclic error), and after a short move the play between
//! screw and nut may not be fully taken up; and the lost motion itself may
//! depend on how long the last single move was (elastic wind-up, friction
//! that is only fully loaded after a long move). [`MotionState`] carries exactly
//! the history those effects need, expressed in commanded quantities only, so
//! that the simulator (which knows everything) and the analysis (which only
//! has a log of targets) build the same state with the same code:
//! [`MotionTracker`].

use serde::{Deserialize, Serialize};

use super::ModelError;

/// One of the two stacked stages.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Axis {
    /// The X stage (lower stage of the stack in the paper's rig).
    X,
    /// The Y stage.
    Y,
}

impl Axis {
    /// Both axes, in component order (x first).
    pub const ALL: [Axis; 2] = [Axis::X, Axis::Y];

    /// Component index: 0 for x, 1 for y (the order of every `[f64; 2]`
    /// contribution in this module).
    pub const fn index(self) -> usize {
        match self {
            Axis::X => 0,
            Axis::Y => 1,
        }
    }

    /// The other axis (the one across this one).
    pub const fn other(self) -> Axis {
        match self {
            Axis::X => Axis::Y,
            Axis::Y => Axis::X,
        }
    }

    /// Lower-case name, as used in model files and parameter names.
    pub const fn as_str(self) -> &'static str {
        match self {
            Axis::X => "x",
            Axis::Y => "y",
        }
    }
}

impl std::fmt::Display for Axis {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// Direction of the last motion of an axis, as the paper defines it: from the
/// previous target to the current one.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Direction {
    /// Last motion went towards larger commanded coordinates.
    Forward,
    /// Last motion went towards smaller commanded coordinates.
    Backward,
    /// The axis has not moved since the history started: direction-dependent
    /// terms use the mean of their forward and backward values and the play
    /// is taken as centred.
    #[default]
    Unknown,
}

impl Direction {
    /// +1 forward, −1 backward, 0 unknown.
    pub const fn sign(self) -> f64 {
        match self {
            Direction::Forward => 1.0,
            Direction::Backward => -1.0,
            Direction::Unknown => 0.0,
        }
    }
}

/// Commanded position and motion history of one axis.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct AxisMotion {
    /// Commanded (screw) position in the stage frame, µm. For the simulator
    /// this is where the servo really put the screw; for a log it is the
    /// target.
    pub cmd_um: f64,
    /// Direction of the last motion of this axis.
    pub dir: Direction,
    /// Commanded travel since the last reversal, in `dir`, µm (≥ 0). Several
    /// consecutive moves in the same direction add up.
    pub run_um: f64,
    /// Length of the run before the last reversal, µm. `None` means the
    /// current run is the first motion since the history started (the
    /// platform was taken as centred in its play then).
    pub prev_run_um: Option<f64>,
    /// Length of the last single commanded move of this axis, µm (≥ 0; 0
    /// when it has not moved since the history started). Unlike `run_um`
    /// it does not add up over consecutive moves in one direction: it is
    /// what the `step_size` term needs (lost motion that depends on the
    /// length of the preceding move). Invariant kept by [`MotionTracker`]:
    /// `0 < last_move_um ≤ run_um` once the direction is known. Absent in
    /// states serialized before it existed: read as 0.
    #[serde(default)]
    pub last_move_um: f64,
}

impl AxisMotion {
    /// An axis at rest at `cmd_um` with no known history.
    pub const fn at_rest(cmd_um: f64) -> Self {
        AxisMotion {
            cmd_um,
            dir: Direction::Unknown,
            run_um: 0.0,
            prev_run_um: None,
            last_move_um: 0.0,
        }
    }

    /// An axis at `cmd_um` that arrived there by a long move in `dir` (long
    /// enough to take up any play, and long enough that any effect of the
    /// move length has saturated).
    pub const fn arrived(cmd_um: f64, dir: Direction) -> Self {
        AxisMotion {
            cmd_um,
            dir,
            run_um: f64::MAX,
            prev_run_um: None,
            last_move_um: f64::MAX,
        }
    }

    fn validate(&self, axis: Axis) -> Result<(), ModelError> {
        let what = |field: &str| format!("motion state {axis}.{field}");
        if !self.cmd_um.is_finite() {
            return Err(ModelError::NonFinite {
                what: what("cmd_um"),
            });
        }
        if self.cmd_um.abs() > MAX_POSITION_UM {
            return Err(ModelError::Invalid {
                key: what("cmd_um"),
                reason: format!(
                    "{} µm is beyond any stage (limit ±{MAX_POSITION_UM:e} µm)",
                    self.cmd_um
                ),
            });
        }
        if self.run_um.is_nan() || self.run_um < 0.0 {
            return Err(ModelError::NonFinite {
                what: format!("{} (must be ≥ 0)", what("run_um")),
            });
        }
        if self.last_move_um.is_nan() || self.last_move_um < 0.0 {
            return Err(ModelError::NonFinite {
                what: format!("{} (must be ≥ 0)", what("last_move_um")),
            });
        }
        if let Some(p) = self.prev_run_um {
            if p.is_nan() || p < 0.0 {
                return Err(ModelError::NonFinite {
                    what: format!("{} (must be ≥ 0)", what("prev_run_um")),
                });
            }
        }
        Ok(())
    }
}

/// Everything the stage model is evaluated on. See the module docs.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct MotionState {
    /// Per axis, in [`Axis::index`] order: `[x, y]`.
    pub axes: [AxisMotion; 2],
    /// Time since the start of the run, s (drives nothing in the built-in
    /// terms, but logs hold it and later terms may use it).
    pub time_s: f64,
    /// Ambient temperature at the stage, °C (thermal terms use the
    /// difference to their reference temperature).
    pub temp_c: f64,
    /// Characterization cycle number (0-based), for grouping in analyses.
    pub cycle: u32,
}

/// Largest commanded position magnitude a valid state may have, µm (1 km:
/// far beyond any stage, small enough that every term stays finite).
pub const MAX_POSITION_UM: f64 = 1e9;

/// Highest temperature a valid state may have, °C.
pub const MAX_TEMP_C: f64 = 1e4;

/// The temperature a [`MotionState`] gets when nothing else is known, °C. The
/// thermal terms of the default model use it as their reference, so a state
/// built without a temperature has no thermal contribution.
pub const DEFAULT_TEMP_C: f64 = 20.0;

impl MotionState {
    /// Both axes at rest at the given commanded position, no history, time 0,
    /// [`DEFAULT_TEMP_C`].
    pub const fn at_rest(x_um: f64, y_um: f64) -> Self {
        MotionState {
            axes: [AxisMotion::at_rest(x_um), AxisMotion::at_rest(y_um)],
            time_s: 0.0,
            temp_c: DEFAULT_TEMP_C,
            cycle: 0,
        }
    }

    /// Both axes at the given position, each having arrived by a long move in
    /// the given direction (play fully taken up).
    pub const fn arrived(x_um: f64, x_dir: Direction, y_um: f64, y_dir: Direction) -> Self {
        MotionState {
            axes: [
                AxisMotion::arrived(x_um, x_dir),
                AxisMotion::arrived(y_um, y_dir),
            ],
            time_s: 0.0,
            temp_c: DEFAULT_TEMP_C,
            cycle: 0,
        }
    }

    /// The motion of one axis.
    pub const fn axis(&self, axis: Axis) -> &AxisMotion {
        &self.axes[axis.index()]
    }

    /// Commanded position of one axis, µm.
    pub const fn cmd_um(&self, axis: Axis) -> f64 {
        self.axes[axis.index()].cmd_um
    }

    /// Commanded position `[x_um, y_um]`.
    pub const fn cmd_xy_um(&self) -> [f64; 2] {
        [self.axes[0].cmd_um, self.axes[1].cmd_um]
    }

    /// Rejects states a term could turn into NaN or infinity: non-finite
    /// positions, temperatures or times, positions beyond
    /// [`MAX_POSITION_UM`], temperatures outside −273.15..=[`MAX_TEMP_C`],
    /// negative (or NaN) run and move lengths.
    pub fn validate(&self) -> Result<(), ModelError> {
        for axis in Axis::ALL {
            self.axis(axis).validate(axis)?;
        }
        if !self.time_s.is_finite() {
            return Err(ModelError::NonFinite {
                what: "motion state time_s".into(),
            });
        }
        if !self.temp_c.is_finite() {
            return Err(ModelError::NonFinite {
                what: "motion state temp_c".into(),
            });
        }
        if !(-273.15..=MAX_TEMP_C).contains(&self.temp_c) {
            return Err(ModelError::Invalid {
                key: "motion state temp_c".into(),
                reason: format!("{} °C is outside -273.15..={MAX_TEMP_C} °C", self.temp_c),
            });
        }
        Ok(())
    }
}

/// One commanded waypoint fed to a [`MotionTracker`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Waypoint {
    /// Commanded x, µm (stage frame).
    pub x_um: f64,
    /// Commanded y, µm (stage frame).
    pub y_um: f64,
    /// Time at which the stage has settled there, s.
    pub time_s: f64,
    /// Ambient temperature then, °C.
    pub temp_c: f64,
    /// Characterization cycle number.
    pub cycle: u32,
}

impl Waypoint {
    /// A waypoint at time 0, [`DEFAULT_TEMP_C`], cycle 0.
    pub const fn at(x_um: f64, y_um: f64) -> Self {
        Waypoint {
            x_um,
            y_um,
            time_s: 0.0,
            temp_c: DEFAULT_TEMP_C,
            cycle: 0,
        }
    }
}

/// Builds [`MotionState`]s from a sequence of commanded positions.
///
/// The one place where direction and run lengths are derived: the simulator
/// feeds it the positions the servo really reached, the analysis feeds it the
/// targets of a log, so both evaluate the model on identical histories. An
/// axis whose target equals its current position has not moved: its direction
/// and runs are kept (the paper's "direction from the previous target").
#[derive(Debug, Clone, PartialEq)]
pub struct MotionTracker {
    state: MotionState,
    min_move_um: f64,
}

impl MotionTracker {
    /// Starts from `start` (e.g. [`MotionState::at_rest`] at the reference
    /// position after `FRF`).
    pub fn new(start: MotionState) -> Result<Self, ModelError> {
        start.validate()?;
        Ok(MotionTracker {
            state: start,
            min_move_um: 0.0,
        })
    }

    /// Ignores moves shorter than `min_move_um` (measured from the tracked
    /// position), as the stage does (its minimum incremental motion): with
    /// the model's `stochastic.min_incremental_motion_um` a log replay sees
    /// the same states as the simulator did.
    pub fn with_min_move(mut self, min_move_um: f64) -> Result<Self, ModelError> {
        if !(min_move_um.is_finite() && min_move_um >= 0.0) {
            return Err(ModelError::Invalid {
                key: "min_move_um".into(),
                reason: format!("must be a finite number ≥ 0, got {min_move_um}"),
            });
        }
        self.min_move_um = min_move_um;
        Ok(self)
    }

    /// The state after the last waypoint.
    pub const fn state(&self) -> &MotionState {
        &self.state
    }

    /// Moves to `wp` and returns the new state. Non-finite input is rejected
    /// and leaves the tracker unchanged.
    pub fn step(&mut self, wp: Waypoint) -> Result<MotionState, ModelError> {
        let mut next = self.state;
        advance(&mut next.axes[0], wp.x_um, self.min_move_um);
        advance(&mut next.axes[1], wp.y_um, self.min_move_um);
        next.time_s = wp.time_s;
        next.temp_c = wp.temp_c;
        next.cycle = wp.cycle;
        next.validate()?;
        self.state = next;
        Ok(next)
    }

    /// Updates time and temperature without motion (the stage sits still
    /// while the room drifts).
    pub fn wait(&mut self, time_s: f64, temp_c: f64) -> Result<MotionState, ModelError> {
        let mut next = self.state;
        next.time_s = time_s;
        next.temp_c = temp_c;
        next.validate()?;
        self.state = next;
        Ok(next)
    }

    /// States for a whole sequence of waypoints (a log), in order, from
    /// `start`, every move taken as made.
    pub fn states_for(
        start: MotionState,
        waypoints: &[Waypoint],
    ) -> Result<Vec<MotionState>, ModelError> {
        MotionTracker::new(start)?.replay(waypoints)
    }

    /// Steps through `waypoints` and returns every state, in order.
    pub fn replay(&mut self, waypoints: &[Waypoint]) -> Result<Vec<MotionState>, ModelError> {
        waypoints.iter().map(|wp| self.step(*wp)).collect()
    }
}

fn advance(axis: &mut AxisMotion, target_um: f64, min_move_um: f64) {
    let delta = target_um - axis.cmd_um;
    if delta == 0.0 || !delta.is_finite() {
        // No motion (or garbage, which validate() rejects afterwards).
        axis.cmd_um = target_um;
        return;
    }
    if delta.abs() < min_move_um {
        // Below the minimum incremental motion: the stage does not move.
        return;
    }
    let dir = if delta > 0.0 {
        Direction::Forward
    } else {
        Direction::Backward
    };
    axis.last_move_um = delta.abs();
    if dir == axis.dir {
        axis.run_um += delta.abs();
    } else {
        axis.prev_run_um = match axis.dir {
            Direction::Unknown => None,
            _ => Some(axis.run_um),
        };
        axis.run_um = delta.abs();
        axis.dir = dir;
    }
    axis.cmd_um = target_um;
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tracker_accumulates_runs_and_records_reversals() {
        let mut t = MotionTracker::new(MotionState::at_rest(0.0, 0.0)).unwrap();
        let s = t.step(Waypoint::at(10.0, 0.0)).unwrap();
        assert_eq!(s.axes[0].dir, Direction::Forward);
        assert_eq!(s.axes[0].run_um, 10.0);
        assert_eq!(s.axes[0].last_move_um, 10.0);
        assert_eq!(s.axes[0].prev_run_um, None);
        assert_eq!(s.axes[1].last_move_um, 0.0);
        assert_eq!(s.axes[1].dir, Direction::Unknown);
        let s = t.step(Waypoint::at(15.0, 0.0)).unwrap();
        assert_eq!(s.axes[0].run_um, 15.0);
        // The run adds up, the last move does not.
        assert_eq!(s.axes[0].last_move_um, 5.0);
        let s = t.step(Waypoint::at(14.0, -3.0)).unwrap();
        assert_eq!(s.axes[0].dir, Direction::Backward);
        assert_eq!(s.axes[0].run_um, 1.0);
        assert_eq!(s.axes[0].prev_run_um, Some(15.0));
        assert_eq!(s.axes[0].last_move_um, 1.0);
        assert_eq!(s.axes[1].dir, Direction::Backward);
        assert_eq!(s.axes[1].run_um, 3.0);
        assert_eq!(s.axes[1].last_move_um, 3.0);
        // A zero move keeps the history, including the last move's length.
        let s = t.step(Waypoint::at(14.0, -3.0)).unwrap();
        assert_eq!(s.axes[0].dir, Direction::Backward);
        assert_eq!(s.axes[0].run_um, 1.0);
        assert_eq!(s.axes[0].last_move_um, 1.0);
    }

    #[test]
    fn tracker_ignores_moves_below_the_minimum() {
        let mut t = MotionTracker::new(MotionState::at_rest(0.0, 0.0))
            .unwrap()
            .with_min_move(0.05)
            .unwrap();
        t.step(Waypoint::at(10.0, 0.0)).unwrap();
        let s = t.step(Waypoint::at(9.97, 0.0)).unwrap();
        assert_eq!(s.axes[0].cmd_um, 10.0);
        assert_eq!(s.axes[0].last_move_um, 10.0);
        assert_eq!(s.axes[0].dir, Direction::Forward);
        let s = t.step(Waypoint::at(9.94, 0.0)).unwrap();
        assert_eq!(s.axes[0].cmd_um, 9.94);
        assert_eq!(s.axes[0].dir, Direction::Backward);
        assert!(MotionTracker::new(MotionState::at_rest(0.0, 0.0))
            .unwrap()
            .with_min_move(f64::NAN)
            .is_err());
    }

    #[test]
    fn tracker_rejects_non_finite_and_stays_put() {
        let mut t = MotionTracker::new(MotionState::at_rest(1.0, 2.0)).unwrap();
        assert!(t.step(Waypoint::at(f64::NAN, 0.0)).is_err());
        assert!(t.step(Waypoint::at(0.0, f64::INFINITY)).is_err());
        let mut wp = Waypoint::at(0.0, 0.0);
        wp.temp_c = f64::NAN;
        assert!(t.step(wp).is_err());
        assert_eq!(t.state().cmd_xy_um(), [1.0, 2.0]);
    }

    #[test]
    fn last_move_is_validated_and_defaults_when_absent() {
        let mut s = MotionState::at_rest(0.0, 0.0);
        s.axes[1].last_move_um = -1.0;
        assert!(s.validate().is_err());
        s.axes[1].last_move_um = f64::NAN;
        assert!(s.validate().is_err());
        s.axes[1].last_move_um = 5.0;
        assert!(s.validate().is_ok());
        // A state serialized before the field existed still loads.
        let json = r#"{"cmd_um":1.0,"dir":"forward","run_um":3.0,"prev_run_um":null}"#;
        let a: AxisMotion = serde_json::from_str(json).unwrap();
        assert_eq!(a.last_move_um, 0.0);
        assert_eq!(a.run_um, 3.0);
    }
}
