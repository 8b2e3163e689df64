//! What starts, re-plans and stops motion and referencing, and the checks
//! a C-863 makes before it accepts a move (servo, reference, soft limits).
//!
//! Why a file of its own: these are the state transitions shared by the
//! control characters (`#24`) and the GCS commands (`MOV`, `FRF`, `STP`, ...).

use super::{Activity, Controller, RefKind, E, EDGE_SEARCH_TIME, SETTLE_TIME};
use crate::motion::Limits;
use crate::params;
use micropos::gcs::AxisId;
use std::time::Duration;

impl Controller {
    /// STP / #24: stop at once (the motor is braked hard; the profile is cut).
    pub(super) fn stop_now(&mut self, now: Duration) {
        self.stalled = false;
        let (p, _) = self.state_at(now);
        self.encoder_mm = p;
        if matches!(self.activity, Activity::Moving(_)) {
            self.target_mm = p;
        }
        if matches!(self.activity, Activity::Referencing { .. }) {
            self.referenced = false;
        }
        self.activity = Activity::Idle;
        self.settled_at = now + SETTLE_TIME;
        self.set_error(E::STOPPED);
    }

    /// Starts (or re-plans) a move to `target` from the current state.
    pub(super) fn start_move(&mut self, now: Duration, target: f64) {
        self.stalled = false;
        let profile = self.plan_from_here(now, target, self.limits());
        self.target_mm = target;
        self.activity = Activity::Moving(profile);
    }

    /// After VEL/ACC/DEC change while moving: continue to the same target
    /// with the new limits.
    pub(super) fn replan(&mut self, now: Duration) {
        if let Activity::Moving(p) = &self.activity {
            if !p.is_done(now) {
                let t = self.target_mm;
                self.start_move(now, t);
            }
        }
    }

    pub(super) fn check_move_allowed(&self, now: Duration) -> Result<(), E> {
        if !self.servo {
            return Err(E::UNREFERENCED_OR_SERVO_OFF);
        }
        if self.is_referencing(now) {
            return Err(E::UNREFERENCED_OR_SERVO_OFF);
        }
        if self.reference_mode && !self.referenced {
            return Err(E::UNREFERENCED_OR_SERVO_OFF);
        }
        Ok(())
    }

    pub(super) fn check_limits(&self, target: f64) -> Result<(), E> {
        let lo = self.params.number(params::MAX_TRAVEL_NEG, 0.0);
        let hi = self.params.number(params::MAX_TRAVEL_POS, 15.0);
        // Targets are compared at the 0.1 nm resolution they are written in.
        let t = (target * 1e7).round() / 1e7;
        if t < lo || t > hi {
            Err(E::POS_OUT_OF_LIMITS)
        } else {
            Ok(())
        }
    }

    pub(super) fn start_referencing(
        &mut self,
        now: Duration,
        axes: &[AxisId],
        kind: RefKind,
    ) -> Result<(), E> {
        Self::axes(axes)?;
        if !self.servo {
            return Err(E::UNREFERENCED_OR_SERVO_OFF);
        }
        if self.is_moving(now) {
            return Err(E::NOT_ALLOWED_WHILE_MOVING);
        }
        let switch_actuator = match kind {
            RefKind::Reference => self.stage.reference_mm,
            RefKind::NegativeLimit => self.stage.negative_limit_mm,
            RefKind::PositiveLimit => self.stage.positive_limit_mm,
        };
        let limits = Limits {
            velocity: self.params.number(params::REFERENCE_VELOCITY, 0.5),
            ..self.limits()
        };
        let profile = self.plan_from_here(now, switch_actuator - self.offset_mm, limits);
        // The following error's decay is part of the edge search.
        let done_at = profile.command_end_time() + EDGE_SEARCH_TIME;
        self.referenced = false;
        self.activity = Activity::Referencing {
            profile,
            done_at,
            kind,
        };
        Ok(())
    }
}
