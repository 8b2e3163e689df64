//! Tool moves (`move` with `tool`): the target is where a `[tools]` point
//! should be, at an arm from the watched point. The watched point's target
//! is `tool − R_z(θ)·offset` with θ the yaw the active table's `[yaw]`
//! predicts at the arrival (`crate::comp::yaw`); θ depends on where the
//! stage is commanded and how it arrives, so the plan is made again with
//! the yaw of its own command (twice: the yaw changes by µrad per mm, the
//! command by µm, so the second pass changes nothing measurable).
//! Without yaw tables θ = 0, and the reply says so (`yaw_source: none`).

use std::sync::Arc;

use super::Rig;
use crate::comp::{pattern_for_tool_um, Compensator, MovePlan, PlanOptions, YawTables};
use crate::daemon::comp::Active;
use crate::daemon::protocol::{ErrorCode, MoveMode, MoveRequest, ProtoError, ToolMove};
use crate::model::{Direction, XyUm};

/// A tool move's target and the yaw it was planned with.
pub(super) struct ToolTarget {
    name: String,
    offset_um: [f64; 2],
    tool_um: [f64; 2],
    yaw: Option<Arc<YawTables>>,
    yaw_urad: f64,
}

impl ToolTarget {
    /// The tool move `req` asks for, with the yaw tables of `active`;
    /// `None` for a move of the watched point.
    pub(super) fn of_request(
        rig: &Rig,
        req: &MoveRequest,
        active: Option<&Active>,
    ) -> Result<Option<ToolTarget>, ProtoError> {
        let Some(name) = &req.tool else {
            return Ok(None);
        };
        let (name, point) = rig
            .cfg
            .tools
            .resolve(Some(name))
            .map_err(|e| ProtoError::new(ErrorCode::BadValue, e))?;
        let (Some(x), Some(y)) = (req.x_um, req.y_um) else {
            return Err(ProtoError::new(
                ErrorCode::MissingField,
                "a tool move needs x_um and y_um",
            ));
        };
        Ok(Some(ToolTarget {
            name: name.to_owned(),
            offset_um: point.offset_um,
            tool_um: [x, y],
            yaw: active.and_then(|a| a.yaw.clone()),
            yaw_urad: 0.0,
        }))
    }

    /// The watched point's target for the yaw predicted at command `cmd`
    /// reached with `dirs` (θ = 0 without yaw tables).
    pub(super) fn pattern_target(&mut self, cmd_um: [f64; 2], dirs: [Direction; 2]) -> XyUm {
        self.yaw_urad = self
            .yaw
            .as_ref()
            .map_or(0.0, |y| y.yaw_urad(cmd_um[0], cmd_um[1], dirs));
        let p = pattern_for_tool_um(self.tool_um, self.yaw_urad, self.offset_um);
        XyUm {
            x_um: p[0],
            y_um: p[1],
        }
    }

    /// The first estimate of the watched point's target: the yaw at the
    /// tool's target less its arm, both directions' mean.
    pub(super) fn first_target(&mut self) -> XyUm {
        let p = pattern_for_tool_um(self.tool_um, 0.0, self.offset_um);
        self.pattern_target(p, [Direction::Unknown; 2])
    }

    /// The reply's `tool` part.
    pub(super) fn reply(&self, mode: MoveMode) -> ToolMove {
        ToolMove {
            name: self.name.clone(),
            offset_um: self.offset_um,
            tool_target_um: self.tool_um,
            yaw_urad: self.yaw_urad,
            yaw_source: if self.yaw.is_some() { "table" } else { "none" }.to_owned(),
            closed_on: (mode == MoveMode::ClosedLoop).then(|| "pattern".to_owned()),
        }
    }
}

impl Rig {
    /// Plans the move to `target` shifted by the drift `offset_um`; for a
    /// tool move plans again with the yaw of the plan's own command (see
    /// the module docs). Returns the plan and the watched point's target.
    pub(super) fn plan_target(
        &self,
        comp: &dyn Compensator,
        tool: Option<&mut ToolTarget>,
        target: XyUm,
        offset_um: [f64; 2],
        start: [f64; 2],
        opts: &PlanOptions,
    ) -> Result<(MovePlan, XyUm), ProtoError> {
        let shifted = |t: XyUm| XyUm {
            x_um: t.x_um - offset_um[0],
            y_um: t.y_um - offset_um[1],
        };
        let mut target = target;
        let mut plan = self.comp.plan(comp, shifted(target), start, opts)?;
        if let Some(t) = tool {
            if t.yaw.is_some() {
                for _ in 0..2 {
                    target = t.pattern_target([plan.cmd.x_um, plan.cmd.y_um], plan.arrival);
                    plan = self.comp.plan(comp, shifted(target), start, opts)?;
                }
            }
        }
        Ok((plan, target))
    }
}
