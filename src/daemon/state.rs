//! The safe-state machine, pure: inputs are what happened (driver events,
//! client actions, job ends), outputs are what must be done (halt both
//! axes) and whether motion is allowed now.
//!
//! Invariants:
//! - any fault (line down, controller fault, reference lost, a supervisor
//!   verdict) yields [`Action::HaltAll`] and latches it;
//! - while a fault is latched nothing moves: moves, reference runs and
//!   jobs are refused ([`Refusal::FaultLatched`]) until a client
//!   acknowledges it with [`Input::Reset`]; a fault that lost a reference
//!   leaves that axis unreferenced after the reset, so it must be
//!   referenced again before it moves;
//! - a client `stop` halts but latches nothing (it is not a fault);
//! - motion needs both lines up; a move of an axis needs it referenced.

use super::protocol::{to_value, PerAxis, RigStatus, TimedReason};
use serde_json::Value;

/// One of the two axes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AxisId {
    /// X.
    X,
    /// Y.
    Y,
}

impl AxisId {
    /// `"x"` / `"y"`.
    pub fn name(self) -> &'static str {
        match self {
            AxisId::X => "x",
            AxisId::Y => "y",
        }
    }
    fn index(self) -> usize {
        match self {
            AxisId::X => 0,
            AxisId::Y => 1,
        }
    }
    /// From a driver axis name.
    pub fn from_name(s: &str) -> Option<AxisId> {
        match s {
            "x" => Some(AxisId::X),
            "y" => Some(AxisId::Y),
            _ => None,
        }
    }
}

/// What the rig is doing.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Activity {
    /// Nothing commanded.
    Idle,
    /// Client moves in progress.
    Moving,
    /// A reference run.
    Referencing,
    /// A job owns the axes.
    Job,
}

impl Activity {
    fn as_str(self) -> &'static str {
        match self {
            Activity::Idle => "idle",
            Activity::Moving => "moving",
            Activity::Referencing => "referencing",
            Activity::Job => "job",
        }
    }
}

/// An input to the machine.
#[derive(Debug, Clone, PartialEq)]
pub enum Input {
    /// Connecting the stage failed (it is retried): why, for `status`
    /// and for refusals until it connects.
    ConnectFailed(String),
    /// The stage is connected and brought up (both axes).
    StageUp {
        /// Referenced state per axis (X, Y).
        referenced: [bool; 2],
    },
    /// A line (re)opened.
    LinkUp(AxisId),
    /// A line went down.
    LinkDown(AxisId, String),
    /// An axis was referenced.
    Referenced(AxisId),
    /// An axis lost its reference (power cycle).
    ReferenceLost(AxisId),
    /// A controller fault that is not a line loss.
    Fault(String),
    /// Activity began.
    Begin(Activity),
    /// Activity ended.
    End(Activity),
    /// `stop` from a client.
    Stop,
    /// A client acknowledged the latched fault (`reset`).
    Reset,
}

/// What the caller must do.
#[derive(Debug, Clone, PartialEq)]
pub enum Action {
    /// Halt both axes now and stop any job; report `reason` to subscribers.
    HaltAll {
        /// Why.
        reason: String,
    },
}

/// A latched fault.
#[derive(Debug, Clone, PartialEq)]
pub struct FaultRecord {
    /// Rig time, s.
    pub t_s: f64,
    /// What happened.
    pub reason: String,
}

/// Why motion is refused now.
#[derive(Debug, Clone, PartialEq)]
pub enum Refusal {
    /// The stage never connected or a line is down.
    NotConnected(String),
    /// An axis is not referenced.
    NotReferenced(AxisId),
    /// Something else owns the axes.
    Busy(Activity),
    /// A fault is latched (its reason): `reset` first.
    FaultLatched(String),
}

/// The machine.
#[derive(Debug, Clone)]
pub struct SafetyState {
    stage_up: bool,
    link_up: [bool; 2],
    referenced: [bool; 2],
    activity: Activity,
    moves_in_flight: u32,
    last_fault: Option<FaultRecord>,
    latched: bool,
    faults: u64,
    /// Why the stage has not connected (the last failed attempt).
    connect_error: Option<FaultRecord>,
    /// Why each line went down, while it is down.
    link_down_reason: [Option<String>; 2],
}

impl Default for SafetyState {
    fn default() -> Self {
        Self::new()
    }
}

impl SafetyState {
    /// Before the stage connected: nothing may move.
    pub fn new() -> Self {
        Self {
            stage_up: false,
            link_up: [false; 2],
            referenced: [false; 2],
            activity: Activity::Idle,
            moves_in_flight: 0,
            last_fault: None,
            latched: false,
            faults: 0,
            connect_error: None,
            link_down_reason: [None, None],
        }
    }

    /// Applies an input at rig time `t_s`.
    pub fn apply(&mut self, input: Input, t_s: f64) -> Vec<Action> {
        let fault = |me: &mut Self, reason: String| {
            me.faults += 1;
            me.latched = true;
            me.last_fault = Some(FaultRecord {
                t_s,
                reason: reason.clone(),
            });
            me.activity = Activity::Idle;
            me.moves_in_flight = 0;
            vec![Action::HaltAll { reason }]
        };
        match input {
            Input::ConnectFailed(reason) => {
                self.connect_error = Some(FaultRecord { t_s, reason });
                vec![]
            }
            Input::StageUp { referenced } => {
                self.stage_up = true;
                self.link_up = [true; 2];
                self.link_down_reason = [None, None];
                self.connect_error = None;
                self.referenced = referenced;
                vec![]
            }
            Input::LinkUp(a) => {
                self.link_up[a.index()] = true;
                self.link_down_reason[a.index()] = None;
                vec![]
            }
            Input::LinkDown(a, why) => {
                let was_up = self.link_up[a.index()];
                self.link_up[a.index()] = false;
                self.link_down_reason[a.index()] = Some(why.clone());
                if was_up || self.activity != Activity::Idle {
                    fault(self, format!("axis {} line down: {why}", a.name()))
                } else {
                    vec![]
                }
            }
            Input::Referenced(a) => {
                self.referenced[a.index()] = true;
                vec![]
            }
            Input::ReferenceLost(a) => {
                self.referenced[a.index()] = false;
                fault(
                    self,
                    format!(
                        "axis {} lost its reference (controller power cycle?); reference it again",
                        a.name()
                    ),
                )
            }
            Input::Fault(why) => fault(self, why),
            Input::Begin(Activity::Moving) => {
                self.moves_in_flight += 1;
                if self.activity == Activity::Idle {
                    self.activity = Activity::Moving;
                }
                vec![]
            }
            Input::Begin(a) => {
                self.activity = a;
                vec![]
            }
            Input::End(Activity::Moving) => {
                self.moves_in_flight = self.moves_in_flight.saturating_sub(1);
                if self.moves_in_flight == 0 && self.activity == Activity::Moving {
                    self.activity = Activity::Idle;
                }
                vec![]
            }
            Input::End(a) => {
                if self.activity == a {
                    self.activity = if self.moves_in_flight > 0 {
                        Activity::Moving
                    } else {
                        Activity::Idle
                    };
                }
                vec![]
            }
            Input::Reset => {
                self.latched = false;
                vec![]
            }
            Input::Stop => {
                self.activity = Activity::Idle;
                self.moves_in_flight = 0;
                vec![Action::HaltAll {
                    reason: "stop requested by a client".to_owned(),
                }]
            }
        }
    }

    fn not_latched(&self) -> Result<(), Refusal> {
        match (&self.last_fault, self.latched) {
            (Some(f), true) => Err(Refusal::FaultLatched(f.reason.clone())),
            (None, true) => Err(Refusal::FaultLatched("a fault".to_owned())),
            _ => Ok(()),
        }
    }

    /// The latched fault, if one is latched (it stays in
    /// [`SafetyState::last_fault`] after `reset`).
    pub fn latched(&self) -> Option<&FaultRecord> {
        self.last_fault.as_ref().filter(|_| self.latched)
    }

    fn connected(&self) -> Result<(), Refusal> {
        if !self.stage_up {
            return Err(Refusal::NotConnected(self.not_connected_because()));
        }
        for a in [AxisId::X, AxisId::Y] {
            if !self.link_up[a.index()] {
                return Err(Refusal::NotConnected(format!(
                    "axis {} line is down{}",
                    a.name(),
                    self.link_down_reason[a.index()]
                        .as_deref()
                        .map(|w| format!(": {w}"))
                        .unwrap_or_default()
                )));
            }
        }
        Ok(())
    }

    /// Why the stage is not connected, in words (before it first
    /// connects).
    pub fn not_connected_because(&self) -> String {
        match &self.connect_error {
            Some(e) => format!(
                "the controllers are not connected: {} (microposd retries; check [driver] port and the cable, its log has every attempt)",
                e.reason
            ),
            None => "the controllers are not connected yet (connecting)".to_owned(),
        }
    }

    /// Per axis, why it is not connected (`None` when it is).
    fn axis_not_connected(&self, a: AxisId) -> Option<String> {
        if !self.stage_up {
            Some(self.not_connected_because())
        } else if !self.link_up[a.index()] {
            Some(format!(
                "line down{}",
                self.link_down_reason[a.index()]
                    .as_deref()
                    .map(|w| format!(": {w}"))
                    .unwrap_or_default()
            ))
        } else {
            None
        }
    }

    /// Whether a client move of these axes may start (`from_job` for moves
    /// the job itself makes).
    pub fn may_move(&self, axes: [bool; 2], from_job: bool) -> Result<(), Refusal> {
        self.connected()?;
        self.not_latched()?;
        match self.activity {
            Activity::Job if !from_job => return Err(Refusal::Busy(Activity::Job)),
            Activity::Referencing => return Err(Refusal::Busy(Activity::Referencing)),
            _ => {}
        }
        for a in [AxisId::X, AxisId::Y] {
            if axes[a.index()] && !self.referenced[a.index()] {
                return Err(Refusal::NotReferenced(a));
            }
        }
        Ok(())
    }

    /// Whether a reference run or a job may start.
    pub fn may_take_axes(&self) -> Result<(), Refusal> {
        self.connected()?;
        self.not_latched()?;
        match self.activity {
            Activity::Idle => Ok(()),
            a => Err(Refusal::Busy(a)),
        }
    }

    /// Whether an axis is referenced.
    pub fn referenced(&self, a: AxisId) -> bool {
        self.referenced[a.index()]
    }

    /// What the rig is doing.
    pub fn activity(&self) -> Activity {
        self.activity
    }

    /// The last fault, if any.
    pub fn last_fault(&self) -> Option<&FaultRecord> {
        self.last_fault.as_ref()
    }

    /// A name for the overall state: `disconnected`, `fault`,
    /// `unreferenced`, `idle`, `moving`, `referencing`, `job`.
    pub fn mode(&self) -> &'static str {
        if self.connected().is_err() {
            "disconnected"
        } else if self.latched {
            "fault"
        } else if self.activity == Activity::Idle && !(self.referenced[0] && self.referenced[1]) {
            "unreferenced"
        } else {
            self.activity.as_str()
        }
    }

    /// The state for `status` (`rig`), `reset` and the `state` event.
    pub fn to_reply(&self) -> RigStatus {
        let why = [AxisId::X, AxisId::Y].map(|a| self.axis_not_connected(a));
        let timed = |f: &FaultRecord| TimedReason {
            t_s: f.t_s,
            reason: f.reason.clone(),
        };
        RigStatus {
            mode: self.mode().to_owned(),
            activity: self.activity.as_str().to_owned(),
            connected: PerAxis::of([
                self.stage_up && self.link_up[0],
                self.stage_up && self.link_up[1],
            ]),
            referenced: PerAxis::of(self.referenced),
            faults: self.faults,
            last_fault: self.last_fault.as_ref().map(timed),
            fault_latched: self.latched().map(timed),
            not_connected: why.iter().any(Option::is_some).then(|| PerAxis::of(why)),
        }
    }

    /// [`to_reply`](Self::to_reply) as JSON.
    pub fn to_json(&self) -> Value {
        to_value(&self.to_reply())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn up() -> SafetyState {
        let mut s = SafetyState::new();
        s.apply(
            Input::StageUp {
                referenced: [true, true],
            },
            0.0,
        );
        s
    }

    #[test]
    fn status_and_refusals_say_why_the_stage_is_not_connected() {
        let mut s = SafetyState::new();
        assert!(s.to_json()["not_connected"]["x"]
            .as_str()
            .unwrap()
            .contains("connecting"));
        s.apply(
            Input::ConnectFailed("x: cannot open /dev/ttyUSB7: No such file or directory".into()),
            1.0,
        );
        let j = s.to_json();
        for a in ["x", "y"] {
            assert!(
                j["not_connected"][a]
                    .as_str()
                    .unwrap()
                    .contains("/dev/ttyUSB7"),
                "{j}"
            );
        }
        let Err(Refusal::NotConnected(m)) = s.may_move([true, true], false) else {
            panic!("moved while not connected");
        };
        assert!(
            m.contains("/dev/ttyUSB7") && m.contains("[driver] port"),
            "{m}"
        );
        s.apply(
            Input::StageUp {
                referenced: [true, true],
            },
            2.0,
        );
        assert!(s.to_json().get("not_connected").is_none());
        s.apply(Input::LinkDown(AxisId::Y, "read timeout".into()), 3.0);
        let j = s.to_json();
        assert!(j["not_connected"]["x"].is_null(), "{j}");
        assert!(
            j["not_connected"]["y"]
                .as_str()
                .unwrap()
                .contains("read timeout"),
            "{j}"
        );
        s.apply(Input::LinkUp(AxisId::Y), 4.0);
        assert!(s.to_json().get("not_connected").is_none());
    }

    #[test]
    fn nothing_moves_before_connection_or_reference() {
        let s = SafetyState::new();
        assert!(matches!(
            s.may_move([true, false], false),
            Err(Refusal::NotConnected(_))
        ));
        let mut s = SafetyState::new();
        s.apply(
            Input::StageUp {
                referenced: [true, false],
            },
            0.0,
        );
        assert!(s.may_move([true, false], false).is_ok());
        assert_eq!(
            s.may_move([false, true], false),
            Err(Refusal::NotReferenced(AxisId::Y))
        );
        assert_eq!(s.mode(), "unreferenced");
    }

    #[test]
    fn a_line_loss_halts_all_and_latches() {
        let mut s = up();
        s.apply(Input::Begin(Activity::Job), 1.0);
        let a = s.apply(Input::LinkDown(AxisId::X, "eof".into()), 2.0);
        assert!(matches!(&a[..], [Action::HaltAll { reason }] if reason.contains("axis x")));
        assert_eq!(s.activity(), Activity::Idle);
        assert_eq!(s.mode(), "disconnected");
        assert!(s.may_move([false, true], false).is_err());
        // A repeated report of the same loss is not a second fault.
        assert!(s
            .apply(Input::LinkDown(AxisId::X, "again".into()), 2.1)
            .is_empty());
        s.apply(Input::LinkUp(AxisId::X), 3.0);
        // The line is back, the fault stays latched until a client resets.
        assert!(matches!(
            s.may_move([true, true], false),
            Err(Refusal::FaultLatched(r)) if r.contains("axis x line down")
        ));
        assert!(matches!(s.may_take_axes(), Err(Refusal::FaultLatched(_))));
        assert_eq!(s.mode(), "fault");
        s.apply(Input::Reset, 3.5);
        assert!(s.may_move([true, true], false).is_ok());
        assert_eq!(s.last_fault().unwrap().t_s, 2.0);
        assert!(s.latched().is_none());
    }

    #[test]
    fn reference_loss_requires_re_referencing() {
        let mut s = up();
        let a = s.apply(Input::ReferenceLost(AxisId::Y), 1.0);
        assert_eq!(a.len(), 1);
        s.apply(Input::Reset, 1.5);
        assert_eq!(
            s.may_move([false, true], false),
            Err(Refusal::NotReferenced(AxisId::Y))
        );
        s.apply(Input::Referenced(AxisId::Y), 2.0);
        assert!(s.may_move([true, true], false).is_ok());
    }

    #[test]
    fn jobs_own_the_axes_and_moves_nest() {
        let mut s = up();
        s.apply(Input::Begin(Activity::Moving), 0.0);
        s.apply(Input::Begin(Activity::Moving), 0.0);
        assert_eq!(s.may_take_axes(), Err(Refusal::Busy(Activity::Moving)));
        s.apply(Input::End(Activity::Moving), 0.0);
        assert_eq!(s.activity(), Activity::Moving);
        s.apply(Input::End(Activity::Moving), 0.0);
        assert!(s.may_take_axes().is_ok());
        s.apply(Input::Begin(Activity::Job), 0.0);
        assert_eq!(
            s.may_move([true, true], false),
            Err(Refusal::Busy(Activity::Job))
        );
        assert!(s.may_move([true, true], true).is_ok());
        assert_eq!(s.apply(Input::Stop, 0.0).len(), 1);
        assert_eq!(s.activity(), Activity::Idle);
        // A client stop is not a fault: nothing to reset.
        assert!(s.may_move([true, true], false).is_ok());
    }

    #[test]
    fn a_latched_fault_refuses_all_motion_until_reset() {
        let mut s = up();
        s.apply(Input::Begin(Activity::Moving), 0.0);
        let a = s.apply(Input::Fault("axis x following error 900 µm".into()), 1.0);
        assert_eq!(a.len(), 1);
        assert_eq!(s.activity(), Activity::Idle);
        for r in [
            s.may_move([true, false], false),
            s.may_move([false, true], true),
            s.may_take_axes(),
        ] {
            assert!(matches!(r, Err(Refusal::FaultLatched(m)) if m.contains("following")));
        }
        assert_eq!(
            s.to_json()["fault_latched"]["reason"],
            "axis x following error 900 µm"
        );
        // A stop does not clear it; only a reset does.
        s.apply(Input::Stop, 2.0);
        assert!(s.may_move([true, true], false).is_err());
        s.apply(Input::Reset, 3.0);
        assert!(s.may_move([true, true], false).is_ok());
        assert!(s.to_json()["fault_latched"].is_null());
        assert_eq!(s.mode(), "idle");
    }
}
