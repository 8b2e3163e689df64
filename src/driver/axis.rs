//! One C-863 axis in micrometres: bring-up, referencing, moves, velocity,
//! halt, and the rule that a position is only reported while the controller
//! says the axis is referenced.
//!
//! Invariants:
//! - Every position returned by [`Axis::position_um`] was read with `POS?`
//!   and followed on the same connection by `FRF?` = 1. A power-cycled
//!   controller answers `POS?` with 0 and `FRF?` with 0, so the position is
//!   refused ([`DriverError::NotReferenced`]) until [`Axis::reference`] runs.
//! - After a reconnect (new connection epoch) or a controller that stopped
//!   answering, the next operation first checks `*IDN?` against the serial
//!   number seen at bring-up: a different controller is never driven.
//! - Travel limits come from the controller (`TMN?`/`TMX?`) and targets
//!   outside them are refused before anything is sent.
//! - The driver never references or switches the servo on by itself after a
//!   fault: referencing moves the stage, so only [`Axis::reference`] does it.

mod recorder;
pub use recorder::Records;

use super::controller::Controller;
use super::error::DriverError;
use super::profile::{self, MotionLimits};
use super::units::{mm_to_um, um_to_mm};
use super::AxisEvent;
use crate::gcs::answer::{self, Identification};
use crate::gcs::{AxisId, Command, ControlChar, GcsErrorCode};
use serde::{Deserialize, Serialize};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tokio::sync::broadcast;
use tokio::time::Instant;

/// Longest time between two `ONT?` polls while a move cannot have ended
/// yet (see [`super::profile`]): a halt, a timeout or a lost line is still
/// seen within it.
const SPARSE_POLL: Duration = Duration::from_millis(50);

/// How an axis finds its reference.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ReferenceMode {
    /// `FRF`: the reference switch (mid travel on M-111 stages).
    #[default]
    Frf,
    /// `FNL`: the negative limit switch.
    Fnl,
    /// `FPL`: the positive limit switch.
    Fpl,
}

/// Per-axis behaviour that is not the line's.
#[derive(Debug, Clone, PartialEq)]
pub struct AxisParams {
    /// Name used in errors and events (`"x"`, `"y"`).
    pub name: String,
    /// The controller's axis identifier (`"1"` on a C-863).
    pub axis: AxisId,
    /// How [`Axis::reference`] references.
    pub reference: ReferenceMode,
    /// Longest time referencing may take.
    pub reference_timeout: Duration,
    /// Longest time [`Axis::wait_on_target`] waits by default.
    pub motion_timeout: Duration,
    /// Polling period of `#7` and `ONT?` while waiting.
    pub poll_interval: Duration,
}

/// A snapshot of an axis, as `micropos axes status` prints it.
#[derive(Debug, Clone, PartialEq)]
pub struct AxisStatus {
    /// Whether `FRF?` says the axis is referenced.
    pub referenced: bool,
    /// Whether the servo is on (`SVO?`).
    pub servo_on: bool,
    /// Whether the axis is on target (`ONT?`).
    pub on_target: bool,
    /// Position in µm; `None` when not referenced (it would mean nothing).
    pub position_um: Option<f64>,
    /// Commanded target in µm (`MOV?`); `None` when not referenced.
    pub target_um: Option<f64>,
    /// Velocity in µm/s (`VEL?`).
    pub velocity_um_per_s: f64,
}

#[derive(Debug)]
struct Inner {
    ctl: Controller,
    p: AxisParams,
    events: broadcast::Sender<AxisEvent>,
    identity: Identification,
    min_um: f64,
    max_um: f64,
    /// Connection epoch whose controller identity has been checked; 0 = must check.
    verified_epoch: AtomicU64,
    /// Last reference state seen (for ReferenceLost / Referenced events).
    referenced: Mutex<Option<bool>>,
    /// Velocity set through this driver, re-applied after a re-reference
    /// (a power cycle resets it to the controller default).
    velocity_mm_s: Mutex<Option<f64>>,
    /// Bumped by every halt/stop, so a waiter knows its move was cut short.
    halts: AtomicU64,
    halts_at_move: AtomicU64,
    /// What the wait for a move knows of it (see [`super::profile`]).
    motion: Mutex<Motion>,
}

/// The driver's knowledge of the axis's motion, each part with the
/// connection epoch it is from (a reconnect, possibly a power cycle, makes
/// it unknown).
#[derive(Debug, Default)]
struct Motion {
    /// `VEL?`, `ACC?`, `DEC?` as read.
    limits: Option<(u64, MotionLimits)>,
    /// The target of the last move command, µm.
    target_um: Option<(u64, f64)>,
    /// Where the axis rests: the target of a move seen on target since, µm.
    rest_um: Option<(u64, f64)>,
    /// The earliest the move under way can be on target.
    earliest: Option<Instant>,
}

/// One C-863 axis. Cheap to clone; all clones drive the same axis.
#[derive(Debug, Clone)]
pub struct Axis {
    inner: Arc<Inner>,
}

/// Identifies the controller and refuses anything but a C-863.
async fn identify_c863(ctl: &Controller) -> Result<(Identification, u64), DriverError> {
    let (idn, epoch) = ctl.identify().await?;
    if !idn.is_c863() {
        return Err(DriverError::NotC863 {
            target: ctl.label().to_owned(),
            model: idn.model.clone(),
            idn: format!(
                "{}, {}, {}, {}",
                idn.vendor, idn.model, idn.serial, idn.firmware
            ),
        });
    }
    Ok((idn, epoch))
}

impl Axis {
    /// Brings an axis up: `*IDN?` (a non-C-863 is refused), `ERR?` (clears a
    /// stale error so later checks are attributable), `CSV?` = 2.0, `SAI?`
    /// lists the axis, `TMN?`/`TMX?` (travel), `FRF?` (reference state).
    /// Changes nothing on the controller.
    pub async fn bring_up(
        ctl: Controller,
        p: AxisParams,
        events: broadcast::Sender<AxisEvent>,
    ) -> Result<Axis, DriverError> {
        let target = ctl.label().to_owned();
        let (identity, epoch) = identify_c863(&ctl).await?;
        let stale = ctl.error().await?;
        if !stale.is_ok() {
            tracing::info!(axis = %p.name, "cleared stale controller error at bring-up: {stale}");
        }
        let csv = Command::Csv;
        let (a, _) = ctl.query(&csv).await?;
        match answer::single_number(&a) {
            Ok(v) if (v - 2.0).abs() < 1e-9 => {}
            _ => {
                return Err(DriverError::UnsupportedSyntax {
                    target,
                    version: a.text(),
                })
            }
        }
        let sai = Command::SaiQuery { all: false };
        let (a, _) = ctl.query(&sai).await?;
        let available = match answer::word_list(&a) {
            Ok(w) => w,
            Err(e) => return Err(ctl.bad_answer(&sai, &a, e).await),
        };
        if !available.iter().any(|w| w == p.axis.as_str()) {
            return Err(DriverError::NoSuchAxis {
                target,
                axis: p.axis.to_string(),
                available,
            });
        }
        let tmn = Command::TmnQuery(vec![p.axis.clone()]);
        let min_mm = read_value(&ctl, &tmn, &p.axis, answer::number).await?.0;
        let tmx = Command::TmxQuery(vec![p.axis.clone()]);
        let max_mm = read_value(&ctl, &tmx, &p.axis, answer::number).await?.0;
        if min_mm > max_mm {
            return Err(DriverError::BadAnswer {
                command: "TMN?/TMX?".to_owned(),
                detail: "travel minimum above maximum".to_owned(),
                text: format!("{min_mm} > {max_mm}"),
            });
        }
        let frf = Command::FrfQuery(vec![p.axis.clone()]);
        let referenced = read_value(&ctl, &frf, &p.axis, answer::boolean).await?.0;
        tracing::info!(
            axis = %p.name, model = %identity.model, serial = %identity.serial,
            min_mm, max_mm, referenced, "axis up"
        );
        Ok(Axis {
            inner: Arc::new(Inner {
                ctl,
                events,
                identity,
                min_um: mm_to_um(min_mm),
                max_um: mm_to_um(max_mm),
                verified_epoch: AtomicU64::new(epoch),
                referenced: Mutex::new(Some(referenced)),
                velocity_mm_s: Mutex::new(None),
                halts: AtomicU64::new(0),
                halts_at_move: AtomicU64::new(0),
                motion: Mutex::new(Motion::default()),
                p,
            }),
        })
    }

    /// The axis name.
    pub fn name(&self) -> &str {
        &self.inner.p.name
    }

    /// The controller identification seen at bring-up.
    pub fn identity(&self) -> &Identification {
        &self.inner.identity
    }

    /// Travel range `(min, max)` in µm from `TMN?`/`TMX?`.
    pub fn travel_um(&self) -> (f64, f64) {
        (self.inner.min_um, self.inner.max_um)
    }

    /// The controller handle (for raw GCS access).
    pub fn controller(&self) -> &Controller {
        &self.inner.ctl
    }

    fn ctl(&self) -> &Controller {
        &self.inner.ctl
    }

    fn id(&self) -> Vec<AxisId> {
        vec![self.inner.p.axis.clone()]
    }

    fn not_referenced(&self) -> DriverError {
        DriverError::NotReferenced {
            axis: self.name().to_owned(),
        }
    }

    fn note_reference(&self, referenced: bool) {
        let mut last = self
            .inner
            .referenced
            .lock()
            .unwrap_or_else(|p| p.into_inner());
        let axis = self.name().to_owned();
        match (*last, referenced) {
            (Some(true), false) => {
                tracing::warn!(axis = %axis, "reference lost");
                let _ = self.inner.events.send(AxisEvent::ReferenceLost { axis });
            }
            (Some(false) | None, true) => {
                let _ = self.inner.events.send(AxisEvent::Referenced { axis });
            }
            _ => {}
        }
        *last = Some(referenced);
    }

    /// Makes sure the controller behind the line is the one brought up: after
    /// a reopen or a silence, `*IDN?` must show the same serial number.
    async fn verify(&self) -> Result<(), DriverError> {
        let now = self.ctl().line().epoch();
        if self.inner.verified_epoch.load(Ordering::SeqCst) == now {
            return Ok(());
        }
        let (idn, epoch) = identify_c863(self.ctl()).await?;
        if idn.serial != self.inner.identity.serial {
            let e = DriverError::ControllerChanged {
                target: self.ctl().label().to_owned(),
                expected: self.inner.identity.serial.clone(),
                found: idn.serial,
            };
            let _ = self.inner.events.send(AxisEvent::Fault {
                source: self.name().to_owned(),
                error: e.to_string(),
            });
            return Err(e);
        }
        self.inner.verified_epoch.store(epoch, Ordering::SeqCst);
        Ok(())
    }

    /// After a link fault the controller may have been swapped or reset.
    fn on_error<T>(&self, r: Result<T, DriverError>) -> Result<T, DriverError> {
        if let Err(e) = &r {
            if e.is_link_fault() {
                self.inner.verified_epoch.store(0, Ordering::SeqCst);
            }
        }
        r
    }

    async fn read<T>(
        &self,
        cmd: Command,
        f: impl Fn(&str) -> Result<T, answer::AnswerError>,
    ) -> Result<(T, u64), DriverError> {
        let r = read_value(self.ctl(), &cmd, &self.inner.p.axis, f).await;
        self.on_error(r)
    }

    async fn set(&self, cmd: Command) -> Result<u64, DriverError> {
        let r = self.ctl().set(&cmd).await;
        self.on_error(r)
    }

    /// Whether the controller says the axis is referenced (`FRF?`).
    pub async fn is_referenced(&self) -> Result<bool, DriverError> {
        self.verify().await?;
        let (r, _) = self
            .read(Command::FrfQuery(self.id()), answer::boolean)
            .await?;
        self.note_reference(r);
        Ok(r)
    }

    /// The position in µm, only if the axis is referenced: `POS?` then `FRF?`
    /// on the same connection (see the module invariants).
    pub async fn position_um(&self) -> Result<f64, DriverError> {
        self.verify().await?;
        let noise = self.ctl().line().noise_count();
        let (pos_mm, e1) = self
            .read(Command::PosQuery(self.id()), answer::number)
            .await?;
        let (referenced, e2) = self
            .read(Command::FrfQuery(self.id()), answer::boolean)
            .await?;
        if e1 != e2 {
            return Err(DriverError::Interrupted {
                target: self.ctl().label().to_owned(),
                command: "POS?".to_owned(),
            });
        }
        if self.ctl().line().noise_count() != noise {
            // Something out of turn arrived between POS? and the FRF? answer:
            // the POS? answer may have been garbage shaped like an answer.
            self.ctl().line().resync(self.ctl().timeout()).await;
            return Err(DriverError::BadAnswer {
                command: "POS?".to_owned(),
                detail: "bytes that belong to no request arrived while the position was read; not trusted".to_owned(),
                text: mm_to_um(pos_mm).to_string(),
            });
        }
        self.note_reference(referenced);
        if referenced {
            Ok(mm_to_um(pos_mm))
        } else {
            Err(self.not_referenced())
        }
    }

    /// `POS?` alone, µm, with the connection epoch it was read on: dense
    /// position sampling during a sweep characterization, where `POS?` +
    /// `FRF?` ([`Axis::position_um`]) would halve the rate. The caller reads
    /// [`Axis::position_um`] (which checks the reference) before and after
    /// the samples and keeps them only if every epoch is that one's (the
    /// module invariant: a position only with `FRF?` = 1 on the same
    /// connection epoch).
    pub async fn position_sample_um(&self) -> Result<(f64, u64), DriverError> {
        let (pos_mm, epoch) = self
            .read(Command::PosQuery(self.id()), answer::number)
            .await?;
        Ok((mm_to_um(pos_mm), epoch))
    }

    /// The connection epoch of this axis's line now (bumped on every
    /// reconnect).
    pub fn epoch(&self) -> u64 {
        self.ctl().line().epoch()
    }

    /// The commanded target in µm (`MOV?`), only if referenced.
    pub async fn target_um(&self) -> Result<f64, DriverError> {
        self.verify().await?;
        let (t, _) = self
            .read(Command::MovQuery(self.id()), answer::number)
            .await?;
        if self.is_referenced().await? {
            Ok(mm_to_um(t))
        } else {
            Err(self.not_referenced())
        }
    }

    /// Checks an absolute target in µm against the travel range without
    /// sending anything (so a two-axis move can be refused as a whole).
    pub fn check_target_um(&self, target_um: f64) -> Result<(), DriverError> {
        self.check_travel(target_um)
    }

    fn check_travel(&self, target_um: f64) -> Result<(), DriverError> {
        if !target_um.is_finite() {
            return Err(DriverError::Invalid(format!(
                "axis {}: target {target_um} µm is not a finite number",
                self.name()
            )));
        }
        // Half a GCS digit of slack (0.05 nm): a target read back from the
        // controller at its limit must be accepted again.
        let eps = 5e-5;
        if target_um < self.inner.min_um - eps || target_um > self.inner.max_um + eps {
            return Err(DriverError::OutOfTravel {
                axis: self.name().to_owned(),
                target_um,
                min_um: self.inner.min_um,
                max_um: self.inner.max_um,
            });
        }
        Ok(())
    }

    /// Explains a refused move: error 5 means unreferenced or servo off.
    async fn explain_move_error(&self, e: DriverError) -> DriverError {
        if e.gcs_code() != Some(GcsErrorCode::UNREFERENCED_OR_SERVO_OFF) {
            return e;
        }
        match self.is_referenced().await {
            Ok(false) => return self.not_referenced(),
            Ok(true) => {}
            Err(_) => return e,
        }
        match self
            .read(Command::SvoQuery(self.id()), answer::boolean)
            .await
        {
            Ok((false, _)) => DriverError::ServoOff {
                axis: self.name().to_owned(),
            },
            _ => e,
        }
    }

    /// Starts an absolute move to `target_um` (µm, controller coordinates)
    /// and returns once the controller accepted it (`MOV` + `ERR?` = 0).
    /// Targets outside the travel range are refused before anything is sent.
    pub async fn move_abs_um(&self, target_um: f64) -> Result<(), DriverError> {
        self.check_travel(target_um)?;
        self.verify().await?;
        let from = self.rest_um();
        self.mark_move();
        let sent = Instant::now();
        let cmd = Command::Mov(vec![(self.inner.p.axis.clone(), um_to_mm(target_um))]);
        match self.set(cmd).await {
            Ok(_) => {
                self.moving_to(target_um, from, sent).await;
                Ok(())
            }
            Err(e) => Err(self.explain_move_error(e).await),
        }
    }

    /// Starts a relative move by `distance_um` (µm, positive = towards
    /// larger positions). The resulting target (`MOV?` + distance) is checked
    /// against the travel range first.
    pub async fn move_rel_um(&self, distance_um: f64) -> Result<(), DriverError> {
        if !distance_um.is_finite() {
            return Err(DriverError::Invalid(format!(
                "axis {}: distance {distance_um} µm is not a finite number",
                self.name()
            )));
        }
        let target = self.target_um().await?;
        self.check_travel(target + distance_um)?;
        let from = self.rest_um();
        self.mark_move();
        let sent = Instant::now();
        let cmd = Command::Mvr(vec![(self.inner.p.axis.clone(), um_to_mm(distance_um))]);
        match self.set(cmd).await {
            Ok(_) => {
                self.moving_to(target + distance_um, from, sent).await;
                Ok(())
            }
            Err(e) => Err(self.explain_move_error(e).await),
        }
    }

    /// A halt or stop is sent: a waiter sees its move cut short, and where
    /// the axis will rest is unknown.
    fn mark_halt(&self) {
        self.inner.halts.fetch_add(1, Ordering::SeqCst);
        self.forget_rest();
    }

    fn mark_move(&self) {
        let h = self.inner.halts.load(Ordering::SeqCst);
        self.inner.halts_at_move.store(h, Ordering::SeqCst);
        self.forget_rest();
    }

    fn motion(&self) -> std::sync::MutexGuard<'_, Motion> {
        self.inner.motion.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Where the axis rests (the target of a move seen on target, on this
    /// connection), µm.
    fn rest_um(&self) -> Option<f64> {
        let epoch = self.epoch();
        self.motion()
            .rest_um
            .and_then(|(e, um)| (e == epoch).then_some(um))
    }

    /// The axis left its rest or stopped short: where it is, and when a move
    /// can end, are unknown until a move is seen on target.
    fn forget_rest(&self) {
        let mut m = self.motion();
        m.rest_um = None;
        m.earliest = None;
    }

    /// A move to `target_um` from rest at `from_um` was accepted; the
    /// command was sent no earlier than `sent`. Learns the earliest the
    /// axis can be on target, reading the controller's limits once per
    /// connection (a failed read leaves it unknown: every poll is made).
    async fn moving_to(&self, target_um: f64, from_um: Option<f64>, sent: Instant) {
        let epoch = self.epoch();
        self.motion().target_um = Some((epoch, target_um));
        let Some(from_um) = from_um else { return };
        let Some(limits) = self.motion_limits(epoch).await else {
            return;
        };
        let Some(t) = limits.min_move_s(um_to_mm(target_um - from_um)) else {
            return;
        };
        let lead = Duration::try_from_secs_f64(profile::lead_s(t)).unwrap_or_default();
        // Not if a halt or another move came meanwhile.
        if !self.halted_since_move() && self.motion().target_um == Some((epoch, target_um)) {
            self.motion().earliest = Some(sent + lead);
        }
    }

    /// `VEL?`, `ACC?`, `DEC?` of this connection, read once and kept.
    async fn motion_limits(&self, epoch: u64) -> Option<MotionLimits> {
        if let Some((e, l)) = self.motion().limits {
            if e == epoch {
                return Some(l);
            }
        }
        let id = self.id();
        let v = self
            .read(Command::VelQuery(id.clone()), answer::number)
            .await;
        let a = self
            .read(Command::AccQuery(id.clone()), answer::number)
            .await;
        let d = self.read(Command::DecQuery(id), answer::number).await;
        let (Ok((v, _)), Ok((a, _)), Ok((d, _))) = (v, a, d) else {
            return None;
        };
        let l = MotionLimits {
            velocity_mm_s: v,
            acceleration_mm_s2: a,
            deceleration_mm_s2: d,
        };
        l.min_move_s(0.0)?;
        self.motion().limits = Some((epoch, l));
        Some(l)
    }

    /// How many poll periods to sleep after a poll at `now`: one, or up to
    /// the first poll of the grid that can see the axis on target when the
    /// move cannot end before `earliest`, but never more than
    /// [`SPARSE_POLL`] between polls (a halt, a timeout and a lost line are
    /// still seen on time).
    fn polls_to_skip(&self, now: Instant) -> u32 {
        let poll = self.inner.p.poll_interval.as_nanos().max(1);
        let Some(earliest) = self.motion().earliest else {
            return 1;
        };
        let ahead = earliest.saturating_duration_since(now).as_nanos();
        let to_first = ahead.div_ceil(poll).max(1);
        let most = (SPARSE_POLL.as_nanos() / poll).max(1);
        u32::try_from(to_first.min(most)).unwrap_or(1)
    }

    /// Whether a halt was sent since the last move or reference began.
    fn halted_since_move(&self) -> bool {
        self.inner.halts.load(Ordering::SeqCst) != self.inner.halts_at_move.load(Ordering::SeqCst)
    }

    fn halted(&self) -> DriverError {
        DriverError::Halted {
            axis: self.name().to_owned(),
        }
    }

    /// Whether the axis is on target (`ONT?`).
    pub async fn on_target(&self) -> Result<bool, DriverError> {
        self.verify().await?;
        Ok(self
            .read(Command::OntQuery(self.id()), answer::boolean)
            .await?
            .0)
    }

    /// Whether the axis moves (`#5`, bit 0 = axis 1). Works while the
    /// controller is busy with another command.
    pub async fn is_moving(&self) -> Result<bool, DriverError> {
        let r = self.ctl().control(ControlChar::MotionStatus).await;
        let (a, _) = self.on_error(r)?;
        let Some(a) = a else {
            return Err(DriverError::Invalid("#5 returned no answer".to_owned()));
        };
        match answer::hex_word(&a) {
            Ok(w) => Ok(w & 1 != 0),
            Err(e) => {
                let cmd = Command::PosQuery(self.id());
                let mut err = self.ctl().bad_answer(&cmd, &a, e).await;
                if let DriverError::BadAnswer { command, .. } = &mut err {
                    *command = "#5".to_owned();
                }
                Err(err)
            }
        }
    }

    /// Waits until the axis is on target (polling `ONT?`), then returns the
    /// position. Fails with [`DriverError::Halted`] if the move was halted,
    /// [`DriverError::MotionTimeout`] after `timeout` (the axis keeps moving:
    /// call [`Axis::halt`] if that is wrong), and with
    /// [`DriverError::NotReferenced`] if the reference was lost meanwhile.
    pub async fn wait_on_target(&self, timeout: Option<Duration>) -> Result<f64, DriverError> {
        let timeout = timeout.unwrap_or(self.inner.p.motion_timeout);
        let start = Instant::now();
        loop {
            if self.halted_since_move() {
                return Err(self.halted());
            }
            if self.on_target().await? {
                let pos = self.position_um().await;
                if pos.is_ok() && !self.halted_since_move() {
                    let mut m = self.motion();
                    m.rest_um = m.target_um;
                    m.earliest = None;
                }
                return pos;
            }
            if start.elapsed() >= timeout {
                return Err(DriverError::MotionTimeout {
                    axis: self.name().to_owned(),
                    timeout,
                });
            }
            let skip = self.polls_to_skip(Instant::now());
            tokio::time::sleep(self.inner.p.poll_interval * skip).await;
        }
    }

    /// Sets the velocity in µm/s (must be positive). Remembered and
    /// re-applied after a re-reference, since a power cycle resets it.
    pub async fn set_velocity_um_per_s(&self, v_um_per_s: f64) -> Result<(), DriverError> {
        if !(v_um_per_s.is_finite() && v_um_per_s > 0.0) {
            return Err(DriverError::Invalid(format!(
                "axis {}: velocity {v_um_per_s} µm/s must be a positive number",
                self.name()
            )));
        }
        self.verify().await?;
        let v_mm = um_to_mm(v_um_per_s);
        // Re-read with the next move (the controller may round it).
        self.motion().limits = None;
        self.set(Command::Vel(vec![(self.inner.p.axis.clone(), v_mm)]))
            .await?;
        *self
            .inner
            .velocity_mm_s
            .lock()
            .unwrap_or_else(|p| p.into_inner()) = Some(v_mm);
        Ok(())
    }

    /// The velocity in µm/s (`VEL?`).
    pub async fn velocity_um_per_s(&self) -> Result<f64, DriverError> {
        self.verify().await?;
        Ok(mm_to_um(
            self.read(Command::VelQuery(self.id()), answer::number)
                .await?
                .0,
        ))
    }

    /// Halts the axis smoothly (`HLT`). The controller confirms with error 10
    /// (PI_CNTR_STOP), which this call consumes and treats as success; a
    /// caller waiting in [`Axis::wait_on_target`] gets [`DriverError::Halted`].
    pub async fn halt(&self) -> Result<(), DriverError> {
        self.mark_halt();
        let cmd = Command::Hlt(self.id());
        let r = self.ctl().set_with_code(&cmd).await;
        let (code, _) = self.on_error(r)?;
        accept_stop(cmd.to_text(), code)
    }

    /// Halts the axis smoothly (`HLT`, the same deceleration as
    /// [`Axis::halt`]) with the command written ahead of every queued
    /// exchange and without the transaction lock
    /// ([`Line::urgent_command`](super::line::Line::urgent_command)), then
    /// confirms it with `ERR?` in turn (10 or 0 is success). Why: the
    /// faults that call for a halt (reads timing out, a garbled line) are
    /// the ones that fill the line's queue; a halt behind them leaves the
    /// stage running for the queue's length in answer timeouts.
    pub async fn halt_now(&self) -> Result<(), DriverError> {
        self.mark_halt();
        let ctl = self.ctl();
        let cmd = Command::Hlt(self.id());
        let r = ctl.line().urgent_command(ctl.address(), &cmd).await;
        self.on_error(r)?;
        let code = self.on_error(self.ctl().error().await)?;
        accept_stop(cmd.to_text(), code)
    }

    /// Stops the controller at once with `#24` (abrupt), written ahead of
    /// every queued exchange and without the transaction lock
    /// ([`Line::urgent`](super::line::Line::urgent)); the stage stops when
    /// the byte is written. Error 10 that follows is then consumed (`ERR?`,
    /// in turn) as the confirmation.
    pub async fn stop(&self) -> Result<(), DriverError> {
        self.mark_halt();
        let ctl = self.ctl();
        let r = ctl.line().urgent(ctl.address(), ControlChar::StopAll).await;
        self.on_error(r)?;
        let code = self.on_error(self.ctl().error().await)?;
        accept_stop("#24".to_owned(), code)
    }

    /// References the axis: servo on (`SVO`), then `FRF`/`FNL`/`FPL` per
    /// configuration, waits for `#7` ready, checks `FRF?` = 1, re-applies a
    /// velocity set earlier, and returns the position in µm. The stage moves.
    /// On timeout the axis is halted.
    pub async fn reference(&self) -> Result<f64, DriverError> {
        self.verify().await?;
        let id = self.inner.p.axis.clone();
        self.set(Command::Svo(vec![(id.clone(), true)])).await?;
        self.mark_move();
        let start_cmd = match self.inner.p.reference {
            ReferenceMode::Frf => Command::Frf(self.id()),
            ReferenceMode::Fnl => Command::Fnl(self.id()),
            ReferenceMode::Fpl => Command::Fpl(self.id()),
        };
        self.set(start_cmd).await?;
        let timeout = self.inner.p.reference_timeout;
        let start = Instant::now();
        loop {
            tokio::time::sleep(self.inner.p.poll_interval).await;
            let r = self.ctl().control(ControlChar::Ready).await;
            let (a, _) = self.on_error(r)?;
            let ready = match a.as_ref().map(answer::ready) {
                Some(Ok(r)) => r,
                Some(Err(e)) => {
                    let a = a.unwrap_or_else(|| crate::gcs::Answer::from_lines(vec![]));
                    return Err(self.ctl().bad_answer(&Command::Frf(self.id()), &a, e).await);
                }
                None => false,
            };
            if ready {
                break;
            }
            if self.halted_since_move() {
                return Err(self.halted());
            }
            if start.elapsed() >= timeout {
                let _ = self.halt().await;
                return Err(DriverError::ReferenceTimeout {
                    axis: self.name().to_owned(),
                    timeout,
                });
            }
        }
        if !self.is_referenced().await? {
            // A halt ends the reference move "ready" and unreferenced, and
            // consumes its error 10: say it was halted, not that the controller
            // gave up.
            if self.halted_since_move() {
                return Err(self.halted());
            }
            // Ready but not referenced: the controller gave up; ERR? says why.
            let code = self.on_error(self.ctl().error().await)?;
            if !code.is_ok() {
                return Err(DriverError::Gcs {
                    command: "FRF".to_owned(),
                    code,
                });
            }
            return Err(self.not_referenced());
        }
        let v = *self
            .inner
            .velocity_mm_s
            .lock()
            .unwrap_or_else(|p| p.into_inner());
        if let Some(v) = v {
            self.motion().limits = None;
            self.set(Command::Vel(vec![(id, v)])).await?;
        }
        self.position_um().await
    }

    /// Reads the whole status. Position and target are `None` when the axis
    /// is not referenced.
    pub async fn status(&self) -> Result<AxisStatus, DriverError> {
        let referenced = self.is_referenced().await?;
        let servo_on = self
            .read(Command::SvoQuery(self.id()), answer::boolean)
            .await?
            .0;
        let on_target = self
            .read(Command::OntQuery(self.id()), answer::boolean)
            .await?
            .0;
        let velocity_um_per_s = self.velocity_um_per_s().await?;
        let (position_um, target_um) = if referenced {
            match self.position_um().await {
                Ok(p) => (Some(p), Some(self.target_um().await?)),
                Err(DriverError::NotReferenced { .. }) => (None, None),
                Err(e) => return Err(e),
            }
        } else {
            (None, None)
        };
        Ok(AxisStatus {
            referenced: position_um.is_some(),
            servo_on,
            on_target,
            position_um,
            target_um,
            velocity_um_per_s,
        })
    }
}

fn accept_stop(command: String, code: GcsErrorCode) -> Result<(), DriverError> {
    if code.is_ok() || code == GcsErrorCode::STOPPED {
        Ok(())
    } else {
        Err(DriverError::Gcs { command, code })
    }
}

/// Queries `cmd` and reads the value for `axis` with `f`; an unusable answer
/// becomes [`DriverError::BadAnswer`] and resynchronises the line.
async fn read_value<T>(
    ctl: &Controller,
    cmd: &Command,
    axis: &AxisId,
    f: impl Fn(&str) -> Result<T, answer::AnswerError>,
) -> Result<(T, u64), DriverError> {
    let (a, epoch) = ctl.query(cmd).await?;
    match answer::value_for(&a, axis, f) {
        Ok(v) => Ok((v, epoch)),
        Err(e) => Err(ctl.bad_answer(cmd, &a, e).await),
    }
}
