//! Compensation in the daemon: loaded tables, the active compensator and
//! the motion history, a component the rig owns (its moves plan with it:
//! `rig::motion`, `rig::closed_loop`).
//!
//! Why the daemon keeps the history: a table or model predicts the error from
//! the arrival direction and the play, which depend on every move made since
//! the reference, including raw moves and job steps. So every executed move
//! is committed here, whatever its mode.
//!
//! Activation swaps an `Arc<dyn Compensator>` under a mutex: a move in flight
//! keeps the compensator it started with; the next move uses the new one.

use super::protocol::{
    ErrorCode, Limits, LoadedTable, OutsideTable as OutsideTableReply, ProtoError,
    TableActivateReply, TableLoadReply, TablesListReply,
};
use crate::analysis::drift::DriftBaseline;
use crate::comp::{
    CompFile, CompKind, Compensator, MotionHistory, MovePlan, PlanOptions, VisionFrame,
};
use crate::model::state::MotionState;
use crate::model::XyUm;
use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

/// The active compensator and where it came from.
#[derive(Debug, Clone)]
pub struct Active {
    /// Table file name.
    pub name: String,
    /// The compensator.
    pub comp: Arc<dyn Compensator>,
    /// Vision → stage transform recorded with the table (closed loop needs it).
    pub frame: Option<VisionFrame>,
    /// Where the drift reference was measured when the table's data were
    /// taken (live drift correction measures against it); `None` for
    /// tables built from logs without reference re-measurements.
    pub drift_baseline: Option<DriftBaseline>,
    /// The platform's yaw measured with the table's data (`[yaw]`): what
    /// a tool move predicts its arm's turn with; `None` for tables built
    /// from logs without θ.
    pub yaw: Option<Arc<crate::comp::YawTables>>,
}

/// The drift baseline a table file records (`tables build` writes it).
fn baseline_of(name: &str, file: &CompFile) -> Result<Option<DriftBaseline>, ProtoError> {
    DriftBaseline::from_metadata(|k| file.source.metadata.get(k).map(String::as_str))
        .map_err(|e| comp_err(ErrorCode::BadValue, &format!("table {name}"), e))
}

/// Loaded tables, the active one, the motion history.
#[derive(Debug, Default)]
pub struct CompState {
    loaded: Mutex<BTreeMap<String, Arc<CompFile>>>,
    /// Load order with kinds (newest last).
    order: Mutex<Vec<(String, crate::comp::CompKind)>>,
    active: Mutex<Option<Active>>,
    history: Mutex<Option<MotionHistory>>,
    /// Drift correction subtracted from the last planned target, `[x, y]`
    /// µm: the user's target was `last_target + this` (relative moves
    /// continue from the user's target, not from the shifted one).
    target_offset: Mutex<[f64; 2]>,
}

/// The check of a compensated target against the characterized area of
/// the compensator `comp` (table file `name`), under `[compensation]
/// outside_table` (`cfg`). `what` names the target in messages ("target",
/// "validation pose 3").
///
/// `Ok(None)`: inside (or the compensator knows no area). `Ok(Some(info))`:
/// outside, allowed; `info` is what the reply carries (`area`,
/// `outside_by_um`, `policy`, and under `warn` a `warning` sentence).
/// `Err(outside_table)`: refused, the message naming the area and the
/// target. A model table extrapolates by physics, so `refuse` only warns
/// for it.
pub fn check_area(
    comp: &dyn Compensator,
    name: &str,
    target: XyUm,
    cfg: &crate::daemon::config::CompensationSection,
    what: &str,
) -> Result<Option<OutsideTableReply>, ProtoError> {
    use crate::daemon::config::OutsideTable;
    let Some(area) = comp.characterized_area() else {
        return Ok(None);
    };
    let margin = cfg.outside_margin_um;
    let by = area.outside_by_um(target, margin);
    if by == [0.0, 0.0] {
        return Ok(None);
    }
    let policy = match cfg.outside_table {
        OutsideTable::Refuse if comp.extrapolates_by_model() => OutsideTable::Warn,
        p => p,
    };
    let axes: Vec<String> = [("x", by[0]), ("y", by[1])]
        .iter()
        .filter(|(_, d)| *d > 0.0)
        .map(|(a, d)| format!("{d:.1} µm in {a}"))
        .collect();
    let sentence = format!(
        "{what} ({:.1}, {:.1}) µm is outside the area {} table {name} was characterized over ({area}, margin {margin} µm) by {}",
        target.x_um,
        target.y_um,
        comp.kind(),
        axes.join(" and ")
    );
    let info = |p: &str| OutsideTableReply {
        policy: p.to_owned(),
        area: Limits {
            x_um: area.x_um,
            y_um: area.y_um,
        },
        margin_um: margin,
        outside_by_um: by,
        warning: None,
    };
    match policy {
        OutsideTable::Refuse => Err(ProtoError::new(
            ErrorCode::OutsideTable,
            format!(
                "{sentence}: its correction there was never measured. Move raw, characterize that area, \
                 or set [compensation] outside_table = \"warn\""
            ),
        )),
        OutsideTable::Warn => {
            let extra = if comp.extrapolates_by_model() {
                "the model extrapolates its terms there, unmeasured"
            } else {
                "the table holds its end values there, unmeasured"
            };
            let w = format!("{sentence}: {extra}");
            tracing::warn!("{w}");
            let mut v = info("warn");
            v.warning = Some(w);
            Ok(Some(v))
        }
        OutsideTable::Extrapolate => Ok(Some(info("extrapolate"))),
    }
}

fn comp_err(code: ErrorCode, what: &str, e: impl std::fmt::Display) -> ProtoError {
    ProtoError::new(code, format!("{what}: {e}"))
}

impl CompState {
    /// The active compensator, if any.
    pub fn active(&self) -> Option<Active> {
        lock(&self.active).clone()
    }

    /// `tables list`: `.toml` files of the data directory, loaded, active.
    pub async fn list(&self, data_dir: &std::path::Path) -> Result<TablesListReply, ProtoError> {
        let dir = data_dir.to_owned();
        let files = tokio::task::spawn_blocking(move || -> std::io::Result<Vec<String>> {
            let mut v = Vec::new();
            for e in std::fs::read_dir(&dir)? {
                let name = e?.file_name().to_string_lossy().into_owned();
                if name.ends_with(".toml") && !name.starts_with('.') {
                    v.push(name);
                }
            }
            v.sort();
            Ok(v)
        })
        .await
        .map_err(|e| comp_err(ErrorCode::Internal, "listing tables", e))?
        .map_err(|e| comp_err(ErrorCode::LogError, "listing the data directory", e))?;
        let loaded: Vec<LoadedTable> = lock(&self.loaded)
            .iter()
            .map(|(n, f)| LoadedTable {
                name: n.clone(),
                kind: f.kind,
                created: f.created.clone(),
                records: f.source.records,
                has_frame: f.frame.is_some(),
            })
            .collect();
        Ok(TablesListReply {
            files,
            loaded,
            active: self.active().map(|a| a.name),
        })
    }

    /// `tables load NAME`: reads and checks the file (a bad file is refused
    /// with the reason; the active table stays as it was).
    pub async fn load(
        &self,
        data_dir: &std::path::Path,
        name: &str,
    ) -> Result<TableLoadReply, ProtoError> {
        let path = data_dir.join(name);
        let file = tokio::task::spawn_blocking(move || CompFile::read_path(&path))
            .await
            .map_err(|e| comp_err(ErrorCode::Internal, "loading a table", e))?
            .map_err(|e| comp_err(ErrorCode::BadValue, &format!("table {name}"), e))?;
        // Building the compensator checks the content, not only the syntax.
        file.compensator()
            .map_err(|e| comp_err(ErrorCode::BadValue, &format!("table {name}"), e))?;
        baseline_of(name, &file)?;
        let out = TableLoadReply {
            loaded: name.to_owned(),
            kind: file.kind,
            records: file.source.records,
        };
        {
            let mut order = lock(&self.order);
            order.retain(|(n, _)| n != name);
            order.push((name.to_owned(), file.kind));
        }
        lock(&self.loaded).insert(name.to_owned(), Arc::new(file));
        Ok(out)
    }

    /// `tables activate [NAME]`: swaps the active compensator (`None`
    /// deactivates). The table must be loaded first.
    pub fn activate(&self, name: Option<&str>) -> Result<TableActivateReply, ProtoError> {
        let Some(name) = name else {
            *lock(&self.active) = None;
            return Ok(TableActivateReply {
                active: None,
                kind: None,
            });
        };
        let (active, kind) = self.load_active(name)?;
        *lock(&self.active) = Some(active);
        Ok(TableActivateReply {
            active: Some(name.to_owned()),
            kind: Some(kind),
        })
    }

    /// A loaded table as a compensator with its frame, without activating
    /// it (a job that names its table, e.g. validation per mode).
    pub fn loaded(&self, name: &str) -> Result<Active, ProtoError> {
        self.load_active(name).map(|(active, _)| active)
    }

    /// A loaded table as a compensator with its frame, and its kind.
    fn load_active(&self, name: &str) -> Result<(Active, CompKind), ProtoError> {
        let file = lock(&self.loaded).get(name).cloned().ok_or_else(|| {
            ProtoError::new(
                ErrorCode::BadValue,
                format!("table {name:?} is not loaded; tables load it first"),
            )
        })?;
        let comp = file
            .compensator()
            .map_err(|e| comp_err(ErrorCode::BadValue, &format!("table {name}"), e))?;
        let active = Active {
            name: name.to_owned(),
            comp: Arc::from(comp),
            frame: file.frame,
            drift_baseline: baseline_of(name, &file)?,
            yaw: file.yaw.clone().map(Arc::new),
        };
        Ok((active, file.kind))
    }

    /// The most recently loaded table of `kind`, by name (validation's
    /// default table per mode: `tables build` loads what it wrote).
    pub fn latest_of_kind(&self, kind: CompKind) -> Option<String> {
        lock(&self.order)
            .iter()
            .rev()
            .find(|(_, k)| *k == kind)
            .map(|(n, _)| n.clone())
    }

    /// Records a move made without a plan (raw moves, job steps).
    pub fn commit_raw(&self, cmd: [Option<f64>; 2], time_s: f64) {
        *lock(&self.target_offset) = [0.0, 0.0];
        let mut h = lock(&self.history);
        let hist = match h.as_mut() {
            Some(h) => h,
            None => {
                let (Some(x), Some(y)) = (cmd[0], cmd[1]) else {
                    return;
                };
                match MotionHistory::new(MotionState::at_rest(x, y), 0.0) {
                    Ok(n) => {
                        *h = Some(n);
                        return;
                    }
                    Err(e) => {
                        tracing::warn!("motion history not started: {e}");
                        return;
                    }
                }
            }
        };
        let s = hist.state().cmd_xy_um();
        let c = XyUm {
            x_um: cmd[0].unwrap_or(s[0]),
            y_um: cmd[1].unwrap_or(s[1]),
        };
        if let Err(e) = hist.commit_move(c, c, time_s, crate::model::state::DEFAULT_TEMP_C) {
            tracing::warn!("motion history: {e}; restarting it at the command");
            *h = MotionHistory::new(MotionState::at_rest(c.x_um, c.y_um), 0.0).ok();
        }
    }

    /// Forgets the history (after a reference run or a fault: the play is
    /// unknown again).
    pub fn reset_history(&self) {
        *lock(&self.history) = None;
    }

    /// Plans a move to `target` with `comp`; `start` is the commanded
    /// position used if no history exists yet.
    pub fn plan(
        &self,
        comp: &dyn Compensator,
        target: XyUm,
        start: [f64; 2],
        opts: &PlanOptions,
    ) -> Result<MovePlan, ProtoError> {
        let mut h = lock(&self.history);
        if h.is_none() {
            *h = Some(
                MotionHistory::new(MotionState::at_rest(start[0], start[1]), 0.0)
                    .map_err(|e| comp_err(ErrorCode::Internal, "motion history", e))?,
            );
        }
        let Some(hist) = h.as_ref() else {
            return Err(ProtoError::new(ErrorCode::Internal, "no motion history"));
        };
        comp.command_for(target, hist, opts)
            .map_err(|e| comp_err(ErrorCode::BadValue, "planning the move", e))
    }

    /// Records an executed plan.
    pub fn commit_plan(&self, plan: &MovePlan, time_s: f64) {
        if let Some(h) = lock(&self.history).as_mut() {
            if let Err(e) = h.commit(plan, time_s, crate::model::state::DEFAULT_TEMP_C) {
                tracing::warn!("motion history: {e}");
            }
        }
    }

    /// The last target, if the history knows one.
    pub fn last_target(&self) -> Option<XyUm> {
        lock(&self.history).as_ref().map(|h| h.last_target())
    }

    /// After a closed loop: the move was for `target` (planned, before the
    /// drift `offset_um` it was shifted by), whatever its corrections
    /// commanded; see [`crate::comp::MotionHistory::set_last_target`].
    pub fn restore_target(&self, target: XyUm, offset_um: [f64; 2]) {
        if let Some(h) = lock(&self.history).as_mut() {
            h.set_last_target(target);
        }
        *lock(&self.target_offset) = offset_um;
    }

    /// Records the drift correction of the plan just committed (see
    /// `target_offset`).
    pub fn set_target_offset(&self, offset_um: [f64; 2]) {
        *lock(&self.target_offset) = offset_um;
    }

    /// The last target the user asked for: the planned one plus the drift
    /// correction it was shifted by.
    pub fn last_user_target(&self) -> Option<XyUm> {
        let o = *lock(&self.target_offset);
        self.last_target().map(|t| XyUm {
            x_um: t.x_um + o[0],
            y_um: t.y_um + o[1],
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::comp::{Area, CompError};
    use crate::daemon::config::{CompensationSection, OutsideTable};

    #[derive(Debug)]
    struct Fixed(bool);
    impl Compensator for Fixed {
        fn kind(&self) -> &'static str {
            if self.0 {
                "model"
            } else {
                "lookup"
            }
        }
        fn predicted_offset_um(&self, _: &MotionState) -> Result<[f64; 2], CompError> {
            Ok([22.65, 0.0])
        }
        fn characterized_area(&self) -> Option<Area> {
            Some(Area {
                x_um: [0.0, 1000.0],
                y_um: [0.0, 500.0],
            })
        }
        fn extrapolates_by_model(&self) -> bool {
            self.0
        }
    }

    fn cfg(p: OutsideTable) -> CompensationSection {
        CompensationSection {
            outside_table: p,
            ..CompensationSection::default()
        }
    }

    const OUT: XyUm = XyUm {
        x_um: 2500.0,
        y_um: 2300.0,
    };

    #[test]
    fn policies_refuse_warn_extrapolate() {
        let e = check_area(
            &Fixed(false),
            "t.toml",
            OUT,
            &cfg(OutsideTable::Refuse),
            "target",
        )
        .unwrap_err();
        assert_eq!(e.code, ErrorCode::OutsideTable);
        assert!(
            e.message.contains("target (2500.0, 2300.0) µm is outside the area lookup table t.toml was characterized over (x 0.0 … 1000.0 µm, y 0.0 … 500.0 µm, margin 10 µm) by 1490.0 µm in x and 1790.0 µm in y"),
            "{}",
            e.message
        );
        let w = check_area(
            &Fixed(false),
            "t.toml",
            OUT,
            &cfg(OutsideTable::Warn),
            "target",
        )
        .unwrap()
        .unwrap();
        assert_eq!(w.policy, "warn");
        assert!(w.warning.unwrap().contains("holds its end values"));
        let x = check_area(
            &Fixed(false),
            "t.toml",
            OUT,
            &cfg(OutsideTable::Extrapolate),
            "target",
        )
        .unwrap()
        .unwrap();
        assert_eq!(x.policy, "extrapolate");
        assert!(x.warning.is_none());
        let inside = XyUm {
            x_um: 1005.0,
            y_um: 250.0,
        };
        assert_eq!(
            check_area(&Fixed(false), "t", inside, &cfg(OutsideTable::Refuse), "t").unwrap(),
            None
        );
    }

    #[test]
    fn a_model_is_warned_about_not_refused() {
        let w = check_area(
            &Fixed(true),
            "m.toml",
            OUT,
            &cfg(OutsideTable::Refuse),
            "target",
        )
        .unwrap()
        .unwrap();
        assert_eq!(w.policy, "warn");
        assert!(w.warning.unwrap().contains("model extrapolates"));
    }
}
