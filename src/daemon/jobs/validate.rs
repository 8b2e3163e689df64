//! The validation job: the paper's square and its ten random targets
//! (Table II), in the modes `raw`, `table` (the paper's lookup tables),
//! `model` (a fitted stage model) and `closed_loop` (compensated, then
//! corrected on the camera), several cycles each, every arrival measured by
//! the camera and logged point by point.
//!
//! Targets are the paper's coordinates (`crate::charact::scan`: square from
//! 10 to 4010 µm, Table II) shifted by an origin inside the travel: by
//! default the start of the configured characterization scans, so the
//! validation covers the characterized area as in the paper (its scans ran
//! from 0); along an axis where the poses would leave the travel from
//! there, the travel's start ([`ORIGIN_CLEARANCE_UM`] in). An origin that
//! puts a pose outside the travel, or a table mode's pose outside its
//! table's area, is refused with the range of origins that fits. Poses are
//! labelled `A`…`D` / `AB3` (square) and `1`…`10`
//! (random) in the log's `pose` column.
//!
//! Figures: ISO 9283 AP and RP per pose (`crate::metrology::iso9283`).
//! ISO 9283 defines no aggregate over poses; the paper quotes one AP per
//! trajectory. The headline `ap_um` / `rp_um` of a trajectory and mode is
//! the **maximum over its poses** (bounds every pose a user may command);
//! `ap_mean_um` / `rp_mean_um` give the mean pose for comparison with
//! "typical" figures.
//!
//! Measuring frame: every mode is measured in one vision → stage frame, that
//! of the lookup table (else the model table), i.e. of the characterization
//! the compensation came from; without tables the job ties the camera
//! itself first ([`super::tie`]).

mod start;

use super::super::comp::{check_area, Active};
use super::super::drift::is_measurement_error;
use super::super::protocol::{
    to_value, ErrorCode, JobKind, JobState, MoveMode, MoveRequest, PairUm, ProtoError, Topic,
    ValidateMode, ValidateParams,
};
use super::super::rig::Rig;
use super::{append_record, lock, measure_retrying, tie, Ended, Jobs, Launch, Progress};
use crate::analysis::drift::DRIFT_REF_SEGMENT;
use crate::charact::log::{self, Columns, LogWriter, Metadata, Record};
use crate::charact::scan::{
    random_targets, square_pose_label, square_poses, SEGMENT_RANDOM, SEGMENT_SQUARE,
};
use crate::comp::{CompKind, VisionFrame};
use crate::metrology::iso9283::{self, Iso9283Error, Xy};
use crate::model::XyUm;
use serde_json::{json, Map, Value};
use std::fs::File;
use std::ops::ControlFlow;
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tokio::sync::watch;

/// Cycles per test and mode when the request names none. The paper does not
/// state its count; 3 is its characterization's and the least that gives
/// RP a spread.
pub const DEFAULT_CYCLES: u32 = 3;

/// Distance between square poses along a side when the request names none,
/// µm: 8 poses per side (corners included), 32 in all.
pub const DEFAULT_SQUARE_STEP_UM: f64 = 500.0;

/// Distance from the travel's start at which a default origin that cannot
/// be the characterization start puts the poses, where the travel allows,
/// µm. Why: a compensated command lies up
/// to the stage's error from its target (≈ 25 µm on the paper's stage) and
/// a unidirectional approach starts `overshoot_um` (20 µm by default)
/// below it, so a pose right at the travel's end could be refused in the
/// middle of the run. An origin the request names, or the characterization
/// start, is only held to the travel itself.
pub const ORIGIN_CLEARANCE_UM: f64 = 50.0;

/// A validation pose: its label and the paper's coordinates.
#[derive(Debug, Clone, PartialEq)]
pub struct Pose {
    /// `A`, `AB1`, … or `1` … `10`.
    pub label: String,
    /// Paper coordinates, µm (add the origin for stage targets).
    pub paper_um: XyUm,
}

/// The square's poses, one every `step_um` along each side, A first.
pub fn square(step_um: f64) -> Result<Vec<Pose>, ProtoError> {
    let pts =
        square_poses(step_um).map_err(|e| ProtoError::new(ErrorCode::BadValue, e.to_string()))?;
    let per_side = pts.len() / 4;
    Ok(pts
        .iter()
        .enumerate()
        .map(|(i, p)| Pose {
            label: square_pose_label(i, per_side),
            paper_um: p.target,
        })
        .collect())
}

/// Table II's targets, labelled 1 … 10.
pub fn random() -> Vec<Pose> {
    random_targets()
        .into_iter()
        .enumerate()
        .map(|(i, t)| Pose {
            label: (i + 1).to_string(),
            paper_um: t,
        })
        .collect()
}

/// The log's columns: the standard ones, then the mode, the pose label,
/// the controller-reported position, the decode quality and the live drift
/// correction subtracted from the target (empty when none; on `drift_ref`
/// rows: the drift measured there).
pub fn columns() -> Columns {
    Columns {
        temp_c: false,
        theta_urad: false,
        extra: [
            "mode",
            "pose",
            "x_reported_um",
            "y_reported_um",
            "vision_quality",
            "drift_x_um",
            "drift_y_um",
        ]
        .map(str::to_owned)
        .to_vec(),
    }
}

/// ISO 9283 figures of one trajectory in one mode: per pose, and the
/// aggregate (max and mean over poses, see the module docs). `targets` are
/// stage targets; `visits[i]` are the measured arrivals at pose `i`.
pub fn summarize(
    poses: &[Pose],
    targets: &[Xy],
    visits: &[Vec<Xy>],
) -> Result<Value, Iso9283Error> {
    let mut stats = Vec::new();
    let mut per_pose = Vec::new();
    for ((p, t), v) in poses.iter().zip(targets).zip(visits) {
        let s = iso9283::pose_stats(*t, v)?;
        per_pose.push(json!({
            "pose": p.label, "x_target_um": t.x_um, "y_target_um": t.y_um,
            "visits": s.visits, "ap_um": s.ap_um, "apx_um": s.apx_um, "apy_um": s.apy_um,
            "rp_um": s.rp_um,
        }));
        stats.push(s);
    }
    let sum = iso9283::summarize_poses(&stats)?;
    Ok(json!({
        "ap_um": sum.ap_max_um,
        "rp_um": sum.rp_max_um,
        "ap_mean_um": sum.ap_mean_um,
        "rp_mean_um": sum.rp_mean_um,
        "worst_pose": poses.get(sum.ap_max_pose).map(|p| p.label.clone()),
        "aggregation": "max over poses (ISO 9283 per pose); *_mean_um = mean over poses",
        "poses": per_pose,
    }))
}

/// Compensators the modes use, resolved at start.
#[derive(Debug, Clone)]
struct Comps {
    table: Option<Active>,
    model: Option<Active>,
}

impl Comps {
    fn for_mode(&self, mode: ValidateMode) -> Option<Active> {
        match mode {
            ValidateMode::Raw => None,
            ValidateMode::Table => self.table.clone(),
            ValidateMode::Model => self.model.clone(),
            ValidateMode::ClosedLoop => self.table.clone().or_else(|| self.model.clone()),
        }
    }
}

/// Everything the running job needs.
#[derive(Debug, Clone)]
struct Plan {
    tests: Vec<(&'static str, Vec<Pose>)>,
    modes: Vec<ValidateMode>,
    cycles: u32,
    origin: XyUm,
    frames: u32,
    settle_s: f64,
    comps: Comps,
    frame: Option<VisionFrame>,
}

impl Plan {
    fn total(&self) -> usize {
        self.tests.iter().map(|(_, p)| p.len()).sum::<usize>()
            * self.modes.len()
            * self.cycles as usize
    }
    fn target(&self, p: &Pose) -> XyUm {
        XyUm {
            x_um: self.origin.x_um + p.paper_um.x_um,
            y_um: self.origin.y_um + p.paper_um.y_um,
        }
    }
}

/// Moves to `target` in `mode`; returns the command finally sent and
/// whether a closed loop ended outside its tolerance (logged, counted).
/// `target`, given in the measuring frame, expressed in `active`, the frame
/// of the compensation that reaches it (unchanged for raw moves, tables
/// without a frame and tables in the measuring frame itself).
///
/// Why: each characterization ties the camera anew, so a table's stage frame
/// absorbs the drift at the time of its own tie, and two tables from
/// characterizations hours apart differ by that drift (a translation of
/// about 0.5 µm between the main job's paper and short characterizations).
/// A compensation lands its command in its own frame; measured in another,
/// it would carry the frames' offset as a bias of every arrival. Converting
/// the target makes every mode aim at the same physical point, so the modes
/// are compared on the compensation alone.
fn in_frame_of(measuring: &VisionFrame, active: Option<VisionFrame>, target: XyUm) -> XyUm {
    match active {
        Some(f) if f != *measuring => f.to_stage(measuring.to_vision(target)),
        _ => target,
    }
}

/// The offset of `active`'s frame from the measuring frame at `at`, µm
/// (`None`: same frame or none): recorded in the validation log.
fn frame_offset_um(
    measuring: &VisionFrame,
    active: Option<VisionFrame>,
    at: XyUm,
) -> Option<[f64; 2]> {
    let a = in_frame_of(measuring, active, at);
    (a != at).then_some([a.x_um - at.x_um, a.y_um - at.y_um])
}

async fn reach(
    rig: &Arc<Rig>,
    plan: &Plan,
    mode: ValidateMode,
    target: XyUm,
) -> Result<(XyUm, Value, Option<String>, Option<[f64; 2]>), ProtoError> {
    let move_mode = match mode {
        ValidateMode::Raw => MoveMode::Raw,
        ValidateMode::Table | ValidateMode::Model => MoveMode::Compensated,
        ValidateMode::ClosedLoop => MoveMode::ClosedLoop,
    };
    let req = MoveRequest {
        x_um: Some(target.x_um),
        y_um: Some(target.y_um),
        relative: false,
        mode: move_mode,
        wait: true,
        tolerance_um: None,
        tool: None,
    };
    let r = rig.move_with(&req, true, plan.comps.for_mode(mode)).await;
    let r = match r {
        Ok(v) => v,
        Err(e)
            if matches!(
                e.code,
                ErrorCode::RetryLimit | ErrorCode::Diverging | ErrorCode::NotConverged
            ) =>
        {
            // The stage is where the loop left it: measure it like any other
            // arrival (that is what a user gets), count the failure.
            tracing::warn!(
                "validation: closed loop to ({:.3}, {:.3}) µm: {}: {}",
                target.x_um,
                target.y_um,
                e.code,
                e.message
            );
            let pos = rig.position().await;
            let c = pos.commanded;
            let cmd = XyUm {
                x_um: c.x_um.unwrap_or(target.x_um),
                y_um: c.y_um.unwrap_or(target.y_um),
            };
            return Ok((
                cmd,
                to_value(&pos.controller),
                Some(e.code.to_string()),
                None,
            ));
        }
        Err(e) => return Err(e),
    };
    let cmd = match (&r.closed_loop, r.commanded) {
        (Some(cl), _) => XyUm {
            x_um: cl.commanded.x_um,
            y_um: cl.commanded.y_um,
        },
        (
            None,
            PairUm {
                x_um: Some(x_um),
                y_um: Some(y_um),
            },
        ) => XyUm { x_um, y_um },
        _ => target,
    };
    let reported = match r.reported {
        Some(p) => to_value(&p),
        None => to_value(&rig.position().await.controller),
    };
    let c = r
        .drift
        .as_ref()
        .map_or(&Value::Null, |d| &d["correction_um"]);
    let correction = c[0].as_f64().zip(c[1].as_f64()).map(|(x, y)| [x, y]);
    Ok((cmd, reported, None, correction))
}

type Visits = Vec<Vec<Xy>>;

/// Before a `table` or `model` point: re-measures the drift reference if
/// live correction is on and due, and logs it as a
/// [`DRIFT_REF_SEGMENT`] row (pose `ref`, drift columns = the drift
/// measured). A camera failure is recorded by the live state (estimate
/// untouched, `drift` event) and logs nothing; motion errors end the job.
/// Returns whether a row was logged.
async fn drift_reference(
    rig: &Arc<Rig>,
    plan: &Plan,
    mode: ValidateMode,
    cycle: u32,
    origin_t: f64,
    writer: &Arc<Mutex<LogWriter<File>>>,
    name: &str,
) -> Result<bool, ProtoError> {
    if !rig.drift.enabled() {
        return Ok(false);
    }
    let Some(active) = plan.comps.for_mode(mode) else {
        return Ok(false);
    };
    if !matches!(rig.drift_due(&active), Ok(true)) {
        return Ok(false);
    }
    let r = match rig
        .drift_measure(&active, plan.frames, plan.settle_s, true)
        .await
    {
        Ok(r) => r,
        Err(e) if is_measurement_error(e.code) => return Ok(false),
        Err(e) => return Err(e),
    };
    let num = |v: &Value| v.as_f64().map_or(String::new(), |v| format!("{v:.4}"));
    let rec = Record {
        t_s: r.sample.t_s - origin_t,
        segment: DRIFT_REF_SEGMENT.to_owned(),
        cycle,
        x_target_um: r.reference_um[0],
        y_target_um: r.reference_um[1],
        x_cmd_um: r.reference_um[0],
        y_cmd_um: r.reference_um[1],
        x_meas_um: r.sample.measured_um[0],
        y_meas_um: r.sample.measured_um[1],
        temp_c: None,
        theta_urad: None,
        extra: vec![
            mode.as_str().to_owned(),
            "ref".to_owned(),
            num(&r.reported["x_um"]),
            num(&r.reported["y_um"]),
            format!("{:.3}", r.quality),
            format!("{:.4}", r.sample.drift_um[0]),
            format!("{:.4}", r.sample.drift_um[1]),
        ],
    };
    append_record(writer, rec, name).await?;
    Ok(true)
}

/// Runs the validation: ties the vision frame (unless the tables carry
/// one), writes the log's head, then visits every pose of every test in
/// every mode, `cycles` times; `Ok` with the end state and, done, the
/// ISO 9283 results per test and mode.
async fn run(
    rig: &Arc<Rig>,
    plan: &Plan,
    name: &str,
    progress: &Arc<Mutex<Option<Progress>>>,
    mut cancel: watch::Receiver<bool>,
) -> Result<(JobState, Option<Value>), ProtoError> {
    let gen = rig.stop_generation();
    let Some(frame) = validation_frame(rig, plan, &mut cancel).await? else {
        return Ok((JobState::Cancelled, None));
    };
    let md = validation_metadata(rig, plan, &frame);
    let path = rig.cfg.daemon.data_dir.join(name);
    let sync = rig.cfg.log_sync();
    let writer: Arc<Mutex<LogWriter<File>>> = Arc::new(Mutex::new(
        tokio::task::spawn_blocking(move || log::create_file(&path, &md, columns(), sync))
            .await
            .map_err(|e| ProtoError::new(ErrorCode::Internal, e.to_string()))?
            .map_err(|e| {
                ProtoError::new(ErrorCode::LogError, format!("cannot create {name}: {e}"))
            })?,
    ));
    let run = Run {
        rig,
        plan,
        frame,
        origin_t: rig.clock.now_s(),
        writer,
        name,
        progress,
        gen,
        settle: Duration::try_from_secs_f64(plan.settle_s).unwrap_or_default(),
    };
    let mut done = 0usize;
    let mut results = Map::new();
    for (segment, poses) in &plan.tests {
        let mut per_mode = Map::new();
        for &mode in &plan.modes {
            match run
                .mode(segment, poses, mode, &mut done, &mut cancel)
                .await?
            {
                ControlFlow::Continue(r) => {
                    per_mode.insert(mode.as_str().to_owned(), r);
                }
                ControlFlow::Break(state) => return Ok((state, None)),
            }
        }
        results.insert((*segment).to_owned(), Value::Object(per_mode));
    }
    Ok((JobState::Done, Some(Value::Object(results))))
}

/// The frame the validation measures in: the tables', else one tied on
/// two 4 mm lines from the origin. `None` if cancelled meanwhile.
async fn validation_frame(
    rig: &Arc<Rig>,
    plan: &Plan,
    cancel: &mut watch::Receiver<bool>,
) -> Result<Option<VisionFrame>, ProtoError> {
    if let Some(f) = plan.frame {
        return Ok(Some(f));
    }
    let lines = [
        tie::TieLine {
            x_axis: true,
            start_um: plan.origin.x_um + 10.0,
            range_um: 4000.0,
            hold_um: plan.origin.y_um + 10.0,
        },
        tie::TieLine {
            x_axis: false,
            start_um: plan.origin.y_um + 10.0,
            range_um: 4000.0,
            hold_um: plan.origin.x_um + 10.0,
        },
    ];
    tokio::select! {
        r = tie::measure_frame(rig, lines, plan.frames, plan.settle_s) => Ok(Some(r?.frame)),
        _ = cancel.changed() => Ok(None),
    }
}

/// The validation log's metadata: the plan, the tables and their frames'
/// offsets from the measuring frame, the live drift correction.
fn validation_metadata(rig: &Rig, plan: &Plan, frame: &VisionFrame) -> Metadata {
    let mut md = Metadata::new();
    md.insert("job", "validate");
    let tests: Vec<&str> = plan.tests.iter().map(|(t, _)| *t).collect();
    md.insert("tests", tests.join(" "));
    let modes: Vec<&str> = plan.modes.iter().map(|m| m.as_str()).collect();
    md.insert("modes", modes.join(" "));
    md.insert("cycles", plan.cycles.to_string());
    md.insert("origin_x_um", plan.origin.x_um.to_string());
    md.insert("origin_y_um", plan.origin.y_um.to_string());
    md.insert("frames_per_point", plan.frames.to_string());
    md.insert("settle_s", plan.settle_s.to_string());
    if let Some(t) = &plan.comps.table {
        md.insert("table", t.name.clone());
    }
    if let Some(t) = &plan.comps.model {
        md.insert("model_table", t.name.clone());
    }
    for mode in [ValidateMode::Table, ValidateMode::Model] {
        if !plan.modes.contains(&mode) {
            continue;
        }
        let table_frame = plan.comps.for_mode(mode).and_then(|a| a.frame);
        if let Some([dx, dy]) = frame_offset_um(frame, table_frame, plan.origin) {
            let m = mode.as_str();
            md.insert(format!("{m}_frame_offset_x_um"), format!("{dx:.4}"));
            md.insert(format!("{m}_frame_offset_y_um"), format!("{dy:.4}"));
        }
    }
    super::tables::frame_to_metadata(&mut md, frame);
    let live = rig.drift.to_json(rig.clock.now_s());
    md.insert(
        "live_drift_method",
        live["method"].as_str().unwrap_or("off").to_owned(),
    );
    md.insert("live_drift_every_s", live["every_s"].to_string());
    md.insert("daemon_version", env!("CARGO_PKG_VERSION"));
    md
}

/// A running validation, as its modes and visits need it.
struct Run<'a> {
    rig: &'a Arc<Rig>,
    plan: &'a Plan,
    /// The frame measurements are taken in.
    frame: VisionFrame,
    /// Rig time of the log's t = 0, s.
    origin_t: f64,
    writer: Arc<Mutex<LogWriter<File>>>,
    name: &'a str,
    progress: &'a Arc<Mutex<Option<Progress>>>,
    /// The rig's stop generation at the start: a stop or fault moves it.
    gen: u64,
    settle: Duration,
}

/// One visit of a pose: where it was measured, and whether the closed
/// loop gave up on it.
struct Visit {
    measured: Xy,
    loop_failed: bool,
}

impl Run<'_> {
    /// One mode of one test: every pose `cycles` times, then its ISO 9283
    /// summary (with the closed loop's failures, the table and the drift
    /// references where they apply).
    async fn mode(
        &self,
        segment: &'static str,
        poses: &[Pose],
        mode: ValidateMode,
        done: &mut usize,
        cancel: &mut watch::Receiver<bool>,
    ) -> Result<ControlFlow<JobState, Value>, ProtoError> {
        let (rig, plan) = (self.rig, self.plan);
        let targets: Vec<Xy> = poses
            .iter()
            .map(|p| {
                let t = plan.target(p);
                Xy::new(t.x_um, t.y_um)
            })
            .collect();
        let mut visits: Visits = vec![Vec::new(); poses.len()];
        let mut drift_refs = 0usize;
        let mut loop_failures = 0u32;
        for cycle in 1..=plan.cycles {
            for (i, pose) in poses.iter().enumerate() {
                if *cancel.borrow_and_update() {
                    return Ok(ControlFlow::Break(JobState::Cancelled));
                }
                if rig.stop_generation() != self.gen {
                    return Ok(ControlFlow::Break(JobState::Stopped));
                }
                if matches!(mode, ValidateMode::Table | ValidateMode::Model) {
                    let (origin_t, writer, name) = (self.origin_t, &self.writer, self.name);
                    let logged = tokio::select! {
                        r = rig.retry_transient("drift reference", || drift_reference(rig, plan, mode, cycle, origin_t, writer, name)) => r?,
                        _ = cancel.changed() => return Ok(ControlFlow::Break(JobState::Cancelled)),
                    };
                    drift_refs += usize::from(logged);
                }
                let visit = match self.visit(segment, mode, cycle, pose, cancel).await? {
                    ControlFlow::Continue(v) => v,
                    ControlFlow::Break(state) => return Ok(ControlFlow::Break(state)),
                };
                loop_failures += u32::from(visit.loop_failed);
                visits[i].push(visit.measured);
                *done += 1;
                self.report(*done, segment, mode);
            }
        }
        let mut r = summarize(poses, &targets, &visits)
            .map_err(|e| ProtoError::new(ErrorCode::Internal, format!("ISO 9283: {e}")))?;
        if mode == ValidateMode::ClosedLoop {
            r["closed_loop_failures"] = json!(loop_failures);
        }
        if let Some(a) = plan.comps.for_mode(mode) {
            r["table"] = json!(a.name);
        }
        if rig.drift.enabled() && matches!(mode, ValidateMode::Table | ValidateMode::Model) {
            let mut d = rig.drift.to_json(rig.clock.now_s());
            d["references_logged"] = json!(drift_refs);
            r["drift"] = d;
        }
        Ok(ControlFlow::Continue(r))
    }

    /// Moves to a pose in `mode`, settles, measures and logs it.
    async fn visit(
        &self,
        segment: &'static str,
        mode: ValidateMode,
        cycle: u32,
        pose: &Pose,
        cancel: &mut watch::Receiver<bool>,
    ) -> Result<ControlFlow<JobState, Visit>, ProtoError> {
        let (rig, plan, clock) = (self.rig, self.plan, &self.rig.clock);
        let target = plan.target(pose);
        let what = format!(
            "{} move to ({:.3}, {:.3}) µm",
            mode.as_str(),
            target.x_um,
            target.y_um
        );
        let aim = in_frame_of(
            &self.frame,
            plan.comps.for_mode(mode).and_then(|a| a.frame),
            target,
        );
        let (cmd, reported, failure, correction) = tokio::select! {
            r = rig.retry_transient(&what, || reach(rig, plan, mode, aim)) => r?,
            _ = cancel.changed() => return Ok(ControlFlow::Break(JobState::Cancelled)),
        };
        clock.sleep(self.settle).await;
        let (m, quality) = measure_retrying(rig, plan.frames).await?;
        let meas = self.frame.to_stage(XyUm {
            x_um: m.x_um,
            y_um: m.y_um,
        });
        let num = |v: &Value| v.as_f64().map_or(String::new(), |v| format!("{v:.4}"));
        let rec = Record {
            t_s: clock.now_s() - self.origin_t,
            segment: segment.to_owned(),
            cycle,
            x_target_um: target.x_um,
            y_target_um: target.y_um,
            x_cmd_um: cmd.x_um,
            y_cmd_um: cmd.y_um,
            x_meas_um: meas.x_um,
            y_meas_um: meas.y_um,
            temp_c: None,
            theta_urad: None,
            extra: vec![
                mode.as_str().to_owned(),
                pose.label.clone(),
                num(&reported["x_um"]),
                num(&reported["y_um"]),
                format!("{quality:.3}"),
                correction.map_or(String::new(), |c| format!("{:.4}", c[0])),
                correction.map_or(String::new(), |c| format!("{:.4}", c[1])),
            ],
        };
        append_record(&self.writer, rec, self.name).await?;
        Ok(ControlFlow::Continue(Visit {
            measured: Xy::new(meas.x_um, meas.y_um),
            loop_failed: failure.is_some(),
        }))
    }

    /// The progress after `done` points, with an estimate of the rest and
    /// the test and mode under way, pushed as a `job` event.
    fn report(&self, done: usize, segment: &str, mode: ValidateMode) {
        let per_point = (self.rig.clock.now_s() - self.origin_t) / done as f64;
        let total = self.plan.total();
        let snapshot = {
            let mut g = lock(self.progress);
            g.as_mut().map(|pr| {
                pr.done = done;
                pr.eta_s = Some(per_point * (total - done) as f64);
                let mut j = pr.to_json();
                j["test"] = json!(segment);
                j["mode"] = json!(mode.as_str());
                j
            })
        };
        if let Some(s) = snapshot {
            self.rig.push(Topic::Job, "job", s);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::start::{origin_advice, origin_range, pose_span};
    use super::*;

    /// The case: the paper's poses from an origin centred for a
    /// 1000 × 500 µm scan in a 15 mm travel. The advice gives the origins
    /// that fit, with the CLI flags (it named only the request fields).
    #[test]
    fn origin_advice_names_the_flags_and_the_range_that_fits() {
        let both = vec![
            (SEGMENT_SQUARE, square(DEFAULT_SQUARE_STEP_UM).unwrap()),
            (SEGMENT_RANDOM, random()),
        ];
        let span = pose_span(&both);
        assert_eq!(span, Some([[10.0, 8196.0], [10.0, 4010.0]]));
        let travel = [(0.0, 15000.0), (0.0, 15000.0)];
        assert_eq!(
            origin_range([10.0, 8196.0], travel[0]),
            Some((-10.0, 6804.0))
        );
        let a = origin_advice(span, travel, "the travel", "fewer");
        assert_eq!(
            a,
            "the poses lie x 10.0 … 8196.0 µm and y 10.0 … 4010.0 µm from the origin, so an \
             origin x -10.0 … 6804.0 µm, y -10.0 … 10990.0 µm keeps every one inside the travel: \
             validate start --origin-x-um X --origin-y-um Y (request fields origin_x_um, origin_y_um)"
        );
        // A 1000 × 500 µm table cannot hold them, whatever the origin.
        let table = [(990.0, 2010.0), (990.0, 1510.0)];
        assert_eq!(origin_range([10.0, 8196.0], table[0]), None);
        let a = origin_advice(span, table, "that area", "characterize more");
        assert!(
            a.ends_with(
                "no origin keeps every one inside that area, too short in x (8186.0 µm of poses, \
                 1020.0 µm available) and y (4000.0 µm of poses, 520.0 µm available); characterize more"
            ),
            "{a}"
        );
        // An empty or non-finite span fits nothing.
        assert_eq!(origin_range([0.0, f64::NAN], travel[0]), None);
        assert_eq!(pose_span(&[]), None);
    }

    #[test]
    fn a_target_is_aimed_in_the_frame_of_its_compensation() {
        use proptest::prelude::*;
        use proptest::test_runner::{Config, TestRunner};
        let xy = |x_um, y_um| XyUm { x_um, y_um };
        let same = VisionFrame {
            rotation_rad: -3.13,
            mirrored: false,
            translation_um: [12038.0, 12164.0],
        };
        assert_eq!(in_frame_of(&same, Some(same), xy(1.0, 2.0)), xy(1.0, 2.0));
        assert_eq!(in_frame_of(&same, None, xy(1.0, 2.0)), xy(1.0, 2.0));
        assert_eq!(frame_offset_um(&same, Some(same), xy(1.0, 2.0)), None);
        // A later tie that absorbed (0.66, 0.51) µm more drift: the target
        // is aimed that much further in the later frame.
        let later = VisionFrame {
            translation_um: [12038.66, 12164.51],
            ..same
        };
        let off = frame_offset_um(&same, Some(later), xy(4000.0, 2000.0)).unwrap_or([0.0; 2]);
        assert!(
            (off[0] - 0.66).abs() < 1e-9 && (off[1] - 0.51).abs() < 1e-9,
            "{off:?}"
        );
        // Any two frames: the point aimed at in the compensation's frame is
        // the target once seen through the measuring frame.
        let frame =
            (-3.0f64..3.0, any::<bool>(), -2e4f64..2e4, -2e4f64..2e4).prop_map(|(r, m, tx, ty)| {
                VisionFrame {
                    rotation_rad: r,
                    mirrored: m,
                    translation_um: [tx, ty],
                }
            });
        let mut runner = TestRunner::new(Config::with_cases(300));
        runner
            .run(
                &(
                    frame,
                    -1e-5f64..1e-5,
                    -5.0f64..5.0,
                    -5.0f64..5.0,
                    0.0f64..1e4,
                    0.0f64..1e4,
                ),
                |(measuring, dr, dx, dy, x, y)| {
                    let other = VisionFrame {
                        rotation_rad: measuring.rotation_rad + dr,
                        translation_um: [
                            measuring.translation_um[0] + dx,
                            measuring.translation_um[1] + dy,
                        ],
                        ..measuring
                    };
                    let t = xy(x, y);
                    let aim = in_frame_of(&measuring, Some(other), t);
                    let seen = measuring.to_stage(other.to_vision(aim));
                    prop_assert!((seen.x_um - x).abs() < 1e-6 && (seen.y_um - y).abs() < 1e-6);
                    Ok(())
                },
            )
            .unwrap_or_else(|e| panic!("{e}"));
    }

    #[test]
    fn poses_follow_the_paper() {
        let s = square(500.0).unwrap();
        assert_eq!(s.len(), 32);
        assert_eq!(s[0].label, "A");
        assert_eq!((s[0].paper_um.x_um, s[0].paper_um.y_um), (10.0, 10.0));
        assert_eq!(s[8].label, "B");
        assert_eq!((s[8].paper_um.x_um, s[8].paper_um.y_um), (4010.0, 10.0));
        assert_eq!(s[16].label, "C");
        assert_eq!(s[24].label, "D");
        assert_eq!((s[24].paper_um.x_um, s[24].paper_um.y_um), (10.0, 4010.0));
        assert_eq!(s[31].label, "DA7");
        let r = random();
        assert_eq!(r.len(), 10);
        assert_eq!(r[0].label, "1");
        assert_eq!((r[5].paper_um.x_um, r[5].paper_um.y_um), (8196.0, 186.0));
        assert!(square(0.0).is_err());
    }

    #[test]
    fn aggregation_is_the_worst_and_the_mean_pose() {
        let poses = vec![
            Pose {
                label: "1".into(),
                paper_um: XyUm {
                    x_um: 0.0,
                    y_um: 0.0,
                },
            },
            Pose {
                label: "2".into(),
                paper_um: XyUm {
                    x_um: 0.0,
                    y_um: 0.0,
                },
            },
        ];
        let targets = [Xy::new(0.0, 0.0), Xy::new(10.0, 0.0)];
        // Pose 1: arrivals 3 and 5 µm off in x (AP 4, l = 1, 1: RP 1).
        // Pose 2: arrivals (10, 1), (10, 1) (AP 1, RP 0).
        let visits = vec![
            vec![Xy::new(3.0, 0.0), Xy::new(5.0, 0.0)],
            vec![Xy::new(10.0, 1.0), Xy::new(10.0, 1.0)],
        ];
        let r = summarize(&poses, &targets, &visits).unwrap();
        assert!((r["ap_um"].as_f64().unwrap() - 4.0).abs() < 1e-12);
        assert!((r["ap_mean_um"].as_f64().unwrap() - 2.5).abs() < 1e-12);
        assert!((r["rp_um"].as_f64().unwrap() - 1.0).abs() < 1e-12);
        assert!((r["rp_mean_um"].as_f64().unwrap() - 0.5).abs() < 1e-12);
        assert_eq!(r["worst_pose"], "1");
        assert_eq!(r["poses"].as_array().unwrap().len(), 2);
        assert!(summarize(&poses, &targets, &[vec![], vec![]]).is_err());
    }
}
