//! Long jobs: one at a time, owning the axes through the state machine.
//! Characterization ([`Jobs::start`]), validation ([`validate`]); `tables
//! build` ([`tables`]) is a request, not a job.
//!
//! A job stops at the first of: done, `cancel`, `stop`, a fault (the stop
//! generation of the rig moved), or an error. Its log stays resumable in
//! every case: each point is appended and flushed before the next move.

pub mod approach;
pub mod record;
mod scan;
mod spawn;
pub mod sweep_job;
pub mod sweep_recorder;
pub mod tables;
pub mod tie;
pub mod validate;

pub use approach::step_columns;
/// The record helpers the job files share.
pub(crate) use record::{append_record, drift_ref_record, lock};
pub use record::{columns, Progress};
pub(crate) use spawn::{Ended, Launch};

/// The measuring helpers every job uses, from the rig (`rig::measure`).
pub(crate) use super::rig::measure::{
    clamp_to_travel, measure_retrying, move_raw_retrying, PARK_APPROACH_UM,
};

use super::protocol::{
    Axes, CharacterizeMode, CharacterizeParams, CharacterizePlan, ErrorCode, GridApproach,
    GridOrder, JobKind, JobProgress, JobReply, JobState, MoveReply, ProtoError,
};
use super::rig::Rig;
use crate::analysis::drift::DRIFT_REF_SEGMENT;
use crate::charact::log::{self, LogWriter, Metadata};
use crate::charact::plan::{self, DriftPlan, ScanPlan};
use crate::charact::sweep::{self, anchor};
use crate::comp::VisionFrame;
use crate::model::XyUm;
use approach::ApproachTracker;
use serde_json::Value;
use std::fs::File;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tokio::sync::watch;

/// Velocity of a sweep's odd cycles when the request names none, µm/s:
/// at the simulated camera's 30 frames/s the even cycles (twice it) still
/// put a frame within every 5 µm cell (8 µm apart: neighbours interpolate).
pub const DEFAULT_SWEEP_VELOCITY_UM_PER_S: f64 = 120.0;

/// Most points a characterization plan may have (a log's resume refuses
/// more, `plan::ScanPlan::from_metadata`).
const MAX_PLAN_POINTS: f64 = 1e7;

#[derive(Debug)]
struct Running {
    cancel: watch::Sender<bool>,
    task: tokio::task::JoinHandle<()>,
    /// For a refusal's message.
    kind: JobKind,
    /// Every log the job writes (the first is its own; a sweep's
    /// companions follow), so that `tables build` refuses them while it
    /// runs: see [`Jobs::check_log_finished`].
    logs: Vec<String>,
}

/// The job manager.
#[derive(Debug, Default)]
pub struct Jobs {
    running: Mutex<Option<Running>>,
    progress: Arc<Mutex<Option<Progress>>>,
    /// Results of the current or last validation (see [`validate`]).
    validation: Arc<Mutex<Option<Value>>>,
}

impl Jobs {
    /// Progress of the current or last job (`null` if none ran).
    pub fn status(&self) -> Option<JobProgress> {
        lock(&self.progress).as_ref().map(Progress::to_reply)
    }

    /// Whether a job is running.
    pub fn is_running(&self) -> bool {
        lock(&self.running)
            .as_ref()
            .is_some_and(|r| !r.task.is_finished())
    }

    /// Refuses `log` while the running job writes it (`job_state`): a table
    /// built from a log the job is still writing covers only the points
    /// measured so far and would pass for the whole plan (issue 33: a
    /// `tables build` typed right after a `--follow` that returned early).
    pub fn check_log_finished(&self, log: &str) -> Result<(), ProtoError> {
        let running = lock(&self.running);
        let Some(r) = running.as_ref().filter(|r| !r.task.is_finished()) else {
            return Ok(());
        };
        if !r.logs.iter().any(|l| l == log) {
            return Ok(());
        }
        let own = r.logs.first().map_or(log, String::as_str);
        let progress = lock(&self.progress)
            .as_ref()
            .map(|p| format!(" ({} of {} points)", p.done, p.total))
            .unwrap_or_default();
        Err(ProtoError::new(
            ErrorCode::JobState,
            format!(
                "{log} is still being written by the running {kind} job {own}{progress}: wait for it to end (`{kind} status` shows how far it is) or cancel it (`{kind} cancel`), then build",
                kind = r.kind
            ),
        ))
    }

    /// Cancels the running job; its log stays resumable.
    pub async fn cancel(&self) -> Result<Option<JobProgress>, ProtoError> {
        let r = lock(&self.running).take();
        let Some(r) = r else {
            return Err(ProtoError::new(ErrorCode::JobState, "no job is running"));
        };
        let _ = r.cancel.send(true);
        // The job finishes its current point (a move in flight is waited).
        let _ = r.task.await;
        Ok(self.status())
    }

    /// Stops a running job without waiting (shutdown, stop).
    pub fn signal_cancel(&self) {
        if let Some(r) = lock(&self.running).as_ref() {
            let _ = r.cancel.send(true);
        }
    }

    /// Refuses a new job while one runs, or on a rig without a camera
    /// (`what` measures with it: "characterization", "validation").
    fn check_can_start(&self, rig: &Rig, what: &str) -> Result<(), ProtoError> {
        if self.is_running() {
            return Err(ProtoError::new(
                ErrorCode::Busy,
                "a job is already running; cancel it first",
            ));
        }
        if rig.vision.is_none() {
            return Err(ProtoError::new(
                ErrorCode::CameraUnavailable,
                format!("{what} measures with the camera; none is configured (camera.source)"),
            ));
        }
        Ok(())
    }

    fn log_path(rig: &Rig, name: &str) -> PathBuf {
        rig.cfg.daemon.data_dir.join(name)
    }

    /// Starts a new characterization. Every refusal comes before anything
    /// moves or is written, in the order of the checks below.
    pub async fn start(
        &self,
        rig: &Arc<Rig>,
        p: CharacterizeParams,
    ) -> Result<JobReply, ProtoError> {
        self.check_can_start(rig, "characterization")?;
        check_plan_options(&p)?;
        let plan = scan_plan(rig, &p)?;
        let name = p
            .log
            .clone()
            .unwrap_or_else(|| format!("charact-{}.csv", unix_seconds()));
        if Self::log_path(rig, &name).exists() {
            return Err(ProtoError::new(
                ErrorCode::LogError,
                format!("log {name} exists already; resume it or choose another name"),
            ));
        }
        // Both modes re-measure the same drift reference.
        let d = &rig.cfg.characterize;
        let drift_every_s = p.drift_every_s.unwrap_or(d.drift_every_s);
        let drift = (drift_every_s > 0.0).then(|| DriftPlan {
            every_s: drift_every_s,
            reference_um: p
                .drift_reference_um
                .or(d.drift_reference_um)
                .unwrap_or([plan.x_start_um, plan.y_start_um]),
        });
        if p.mode == Some(CharacterizeMode::Sweep) {
            return self.start_sweep(rig, p, &plan, name, drift);
        }
        rig.begin_job()?;
        let total = plan.points().len();
        let job = StepJob {
            plan,
            drift,
            name,
            resumed: None,
        };
        Ok(self.launch(rig, job, 0, total))
    }

    /// The sweep mode's part of [`Jobs::start`]: its plan from the step
    /// plan's area, and its companion logs checked.
    fn start_sweep(
        &self,
        rig: &Arc<Rig>,
        p: CharacterizeParams,
        plan: &ScanPlan,
        name: String,
        drift: Option<DriftPlan>,
    ) -> Result<JobReply, ProtoError> {
        let sweep = sweep::SweepPlan {
            scan_x: plan.scan_x,
            scan_y: plan.scan_y,
            step_um: plan.step_um,
            x_start_um: plan.x_start_um,
            x_range_um: plan.x_range_um,
            y_start_um: plan.y_start_um,
            y_range_um: plan.y_range_um,
            cycles: plan.cycles,
            velocity_um_per_s: p
                .velocity_um_per_s
                .unwrap_or(DEFAULT_SWEEP_VELOCITY_UM_PER_S),
            anchor_spacing_um: p
                .anchor_spacing_um
                .unwrap_or(anchor::DEFAULT_ANCHOR_SPACING_UM),
        };
        sweep
            .validate()
            .map_err(|e| ProtoError::new(ErrorCode::BadValue, e.to_string()))?;
        let companions = [
            ("uncorrected_log", &p.uncorrected_log),
            ("unanchored_log", &p.unanchored_log),
        ];
        for (key, u) in companions {
            let Some(u) = u else { continue };
            let clash = u == &name
                || companions
                    .iter()
                    .any(|(k, o)| *k != key && o.as_ref() == Some(u));
            if clash || Self::log_path(rig, u).exists() {
                return Err(ProtoError::new(
                    ErrorCode::LogError,
                    format!("{key} {u} exists already or names another log of the job"),
                ));
            }
        }
        rig.begin_job()?;
        let total = sweep.records_total();
        let args = sweep_job::SweepArgs {
            plan: sweep,
            name,
            uncorrected: p.uncorrected_log,
            unanchored: p.unanchored_log,
            frames_per_point: plan.frames_per_point,
            settle_s: plan.settle_s,
            drift,
        };
        Ok(self.launch_sweep(rig, args, total))
    }

    /// Resumes a job from its log.
    pub async fn resume(&self, rig: &Arc<Rig>, name: &str) -> Result<JobReply, ProtoError> {
        if self.is_running() {
            return Err(ProtoError::new(ErrorCode::Busy, "a job is already running"));
        }
        if rig.vision.is_none() {
            return Err(ProtoError::new(
                ErrorCode::CameraUnavailable,
                "no camera is configured (camera.source)",
            ));
        }
        let path = Self::log_path(rig, name);
        let sync = rig.cfg.log_sync();
        // A log begun before the `theta_urad` or the `approach` column
        // existed goes on without.
        let (writer, resume) = tokio::task::spawn_blocking(move || {
            let older = [
                step_columns().with_theta(false),
                columns(),
                columns().with_theta(false),
            ];
            let mut r = log::open_append(&path, &step_columns(), sync);
            for c in &older {
                match r {
                    Err(e @ log::LogError::ColumnsMismatch { .. }) => {
                        r = log::open_append(&path, c, sync).map_err(|_| e);
                    }
                    _ => break,
                }
            }
            r
        })
        .await
        .map_err(|e| ProtoError::new(ErrorCode::Internal, e.to_string()))?
        .map_err(|e| {
            ProtoError::new(
                ErrorCode::LogError,
                format!("cannot resume {name}: {}", e.without_content()),
            )
        })?;
        if resume.metadata.get("mode") == Some("sweep") {
            return Err(ProtoError::new(
                ErrorCode::JobState,
                format!("{name} is a sweep log: a sweep is written when it ends and cannot be resumed; start a new one"),
            ));
        }
        let plan = ScanPlan::from_metadata(&resume.metadata)
            .map_err(|e| ProtoError::new(ErrorCode::LogError, format!("{name}: {e}")))?;
        // The frame the job started with: its own tie (vision_frame_*), or
        // for a log with only `vision_offset_*` keys the configured rotation
        // plus the first point's offset.
        let legacy = (|| {
            let x = resume.metadata.get("vision_offset_x_um")?.parse().ok()?;
            let y = resume.metadata.get("vision_offset_y_um")?.parse().ok()?;
            Some(VisionFrame {
                rotation_rad: rig.cfg.camera.rotation_rad,
                mirrored: false,
                translation_um: [x, y],
            })
        })();
        let offset = tables::frame_from_metadata(&resume.metadata)
            .map_err(|e| ProtoError::new(ErrorCode::LogError, format!("{name}: {e}")))?
            .or(legacy)
            .ok_or_else(|| {
                ProtoError::new(
                    ErrorCode::LogError,
                    format!("{name}: the vision frame (vision_frame_*) is missing in the metadata"),
                )
            })?;
        let drift = DriftPlan::from_metadata(&resume.metadata)
            .map_err(|e| ProtoError::new(ErrorCode::LogError, format!("{name}: {e}")))?;
        let total = plan.points().len();
        let mut done = usize::try_from(resume.records).unwrap_or(usize::MAX);
        if drift.is_some() {
            // Reference re-measurements are not plan points: count the rest.
            let path = Self::log_path(rig, name);
            let refs = tokio::task::spawn_blocking(move || {
                let bytes = crate::nofollow::read(&path)?;
                let parsed = log::parse_bytes(&bytes)
                    .map_err(|e| std::io::Error::other(e.without_content()))?;
                Ok::<_, std::io::Error>(
                    parsed
                        .records
                        .iter()
                        .filter(|r| r.segment == DRIFT_REF_SEGMENT)
                        .count(),
                )
            })
            .await
            .map_err(|e| ProtoError::new(ErrorCode::Internal, e.to_string()))?
            .map_err(|e| {
                ProtoError::new(ErrorCode::LogError, format!("cannot resume {name}: {e}"))
            })?;
            done = done.saturating_sub(refs);
        }
        if done >= total {
            return Err(ProtoError::new(
                ErrorCode::JobState,
                format!("{name} is complete ({done} of {total} points)"),
            ));
        }
        let t0 = resume.last_record.map_or(0.0, |r| r.t_s);
        let tie_theta = record::tie_theta_of(writer.columns(), &resume.metadata);
        rig.begin_job()?;
        let job = StepJob {
            plan,
            drift,
            name: name.to_owned(),
            resumed: Some((writer, offset, t0, tie_theta)),
        };
        Ok(self.launch(rig, job, done, total))
    }

    /// Starts the sweep job task (see [`sweep_job`]).
    fn launch_sweep(&self, rig: &Arc<Rig>, args: sweep_job::SweepArgs, total: usize) -> JobReply {
        let logs = [
            Some(&args.name),
            args.uncorrected.as_ref(),
            args.unanchored.as_ref(),
        ]
        .into_iter()
        .flatten()
        .cloned()
        .collect();
        let launch = Launch {
            kind: JobKind::Characterize,
            what: format!("sweep characterization {}", args.name),
            logs,
            done: 0,
            total,
        };
        let (rig2, progress) = (rig.clone(), self.progress.clone());
        self.spawn(rig, launch, |cancel| async move {
            let (state, result) = sweep_job::run(&rig2, &args, &progress, cancel).await?;
            Ok(Ended {
                result,
                ..Ended::state(state)
            })
        })
    }

    /// Starts a step or grid characterization's task, new or resumed
    /// (`resumed`: the log's writer, its frame and its last record's time,
    /// s; `done` of `total` points logged).
    fn launch(&self, rig: &Arc<Rig>, job: StepJob, done: usize, total: usize) -> JobReply {
        let launch = Launch {
            kind: JobKind::Characterize,
            what: format!("characterization {}", job.name),
            logs: vec![job.name.clone()],
            done,
            total,
        };
        let (rig2, progress) = (rig.clone(), self.progress.clone());
        self.spawn(rig, launch, move |cancel| async move {
            run(&rig2, job, done, &progress, cancel)
                .await
                .map(Ended::state)
        })
    }
}

/// A step or grid characterization to run: its plan, drift references,
/// log, and for a resumed job the log's writer, frame and last record's
/// time (s).
struct StepJob {
    plan: ScanPlan,
    drift: Option<DriftPlan>,
    name: String,
    /// A resumed log: its writer, frame, last record's time (s) and the
    /// tie's θ its `theta_urad` is relative to (rad; `None`: no column).
    resumed: Option<(LogWriter<File>, VisionFrame, f64, Option<f64>)>,
}

/// Refuses the options that belong to another plan or mode than the one
/// requested (each names the option that would make sense of it).
fn check_plan_options(p: &CharacterizeParams) -> Result<(), ProtoError> {
    let grid = p.plan == Some(CharacterizePlan::Grid);
    let refusal = if p.pitch_um.is_some() && !grid {
        "pitch_um is the grid plan's node spacing: give plan = \"grid\" (the scan lines take step_um)"
    } else if p.approach.is_some() && !grid {
        "approach is how the grid plan reaches its nodes: give plan = \"grid\" (the scan lines are measured both ways already)"
    } else if p.order.is_some() && !grid {
        "order is the grid plan's node order: give plan = \"grid\""
    } else if p.order == Some(GridOrder::Serpentine) && p.approach != Some(GridApproach::Both) {
        "a serpentine's returning rows reach x from above: give approach = \"both\" (every node is then measured each way on each axis)"
    } else if grid && p.mode == Some(CharacterizeMode::Sweep) {
        "the grid plan is measured point by point: mode sweep scans lines only"
    } else {
        return Ok(());
    };
    Err(ProtoError::new(ErrorCode::BadValue, refusal))
}

/// The step or grid plan a start request asks for: the request's values,
/// else the configuration's; an area the configuration does not place is
/// centred in the allowed travel. Refused when the area does not fit the
/// travel, the step exceeds a range, or the plan is too large.
fn scan_plan(rig: &Rig, p: &CharacterizeParams) -> Result<ScanPlan, ProtoError> {
    let d = &rig.cfg.characterize;
    let axes = p.axes.unwrap_or(Axes::Both);
    let grid = p.plan == Some(CharacterizePlan::Grid);
    let step_um = if grid {
        p.pitch_um.or(p.step_um).unwrap_or(d.step_um)
    } else {
        p.step_um.unwrap_or(d.step_um)
    };
    let x_range_um = p.x_range_um.unwrap_or(d.x_range_um);
    let y_range_um = p.y_range_um.unwrap_or(d.y_range_um);
    let limits = rig.status().limits;
    let start = |configured: Option<f64>, axis: &str, range: f64| match configured {
        Some(v) => Ok(v),
        None => centred_start(
            limits.map(|l| if axis == "x_um" { l.x_um } else { l.y_um }),
            axis,
            range,
        ),
    };
    let plan = ScanPlan {
        grid,
        grid_both: p.approach == Some(GridApproach::Both),
        grid_serpentine: p.order == Some(GridOrder::Serpentine),
        scan_x: axes.x(),
        scan_y: axes.y(),
        step_um,
        x_start_um: start(d.x_start_um, "x_um", x_range_um)?,
        x_range_um,
        y_start_um: start(d.y_start_um, "y_um", y_range_um)?,
        y_range_um,
        cycles: p.cycles.unwrap_or(d.cycles),
        frames_per_point: p.frames_per_point.unwrap_or(d.frames_per_point),
        settle_s: p.settle_s.unwrap_or(d.settle_s),
        moves_per_cycle: p.moves_per_cycle.unwrap_or(0),
    };
    if step_um > x_range_um.min(y_range_um) {
        return Err(ProtoError::new(
            ErrorCode::BadValue,
            if grid {
                "the grid's pitch exceeds a range"
            } else {
                "step_um exceeds a scan range"
            },
        ));
    }
    if plan.points_upper_bound() > MAX_PLAN_POINTS {
        return Err(ProtoError::new(
            ErrorCode::BadValue,
            format!(
                "the plan has about {:.0} points, more than {MAX_PLAN_POINTS:.0}: a larger step or pitch, or smaller ranges",
                plan.points_upper_bound()
            ),
        ));
    }
    Ok(plan)
}

/// The start of a `range` µm long scan centred in the allowed travel
/// `limits` (status's `[lo, hi]` of `axis`, µm).
fn centred_start(limits: Option<[f64; 2]>, axis: &str, range: f64) -> Result<f64, ProtoError> {
    match limits {
        Some([lo, hi]) if hi - lo < range => Err(ProtoError::new(
            ErrorCode::OutOfTravel,
            format!("{axis} range {range} µm exceeds the allowed travel {lo}..{hi} µm"),
        )),
        Some([lo, hi]) => Ok((lo + hi - range) / 2.0),
        None => Err(ProtoError::new(
            ErrorCode::NotConnected,
            "the controllers are not connected",
        )),
    }
}

fn unix_seconds() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs())
}

async fn run(
    rig: &Arc<Rig>,
    job: StepJob,
    start: usize,
    progress: &Arc<Mutex<Option<Progress>>>,
    mut cancel: watch::Receiver<bool>,
) -> Result<JobState, ProtoError> {
    let StepJob {
        plan,
        drift,
        name,
        resumed,
    } = job;
    let (plan, name) = (&plan, name.as_str());
    let points = plan.points();
    let gen = rig.stop_generation();
    let clock = rig.clock.clone();
    let writer: Arc<Mutex<LogWriter<File>>>;
    let frame: VisionFrame;
    let origin;
    let tie_theta_rad: Option<f64>;
    if let Some((w, f, t0, theta)) = resumed {
        writer = Arc::new(Mutex::new(w));
        frame = f;
        tie_theta_rad = theta;
        origin = clock.now_s() - t0;
    } else {
        // A new job ties the vision frame to the stage frame on its own
        // data first (see `tie`), then writes the frame into the metadata.
        let lines = [
            tie::TieLine {
                x_axis: true,
                start_um: plan.x_start_um,
                range_um: plan.x_range_um,
                // Through the start corner: the frame's origin line.
                hold_um: plan.y_start_um,
            },
            tie::TieLine {
                x_axis: false,
                start_um: plan.y_start_um,
                range_um: plan.y_range_um,
                hold_um: plan.x_start_um,
            },
        ];
        let tied = tokio::select! {
            r = tie::measure_frame(rig, lines, plan.frames_per_point, plan.settle_s) => r?,
            _ = cancel.changed() => return Ok(JobState::Cancelled),
        };
        frame = tied.frame;
        tie_theta_rad = Some(tied.theta_rad);
        let mut md = Metadata::new();
        plan.to_metadata(&mut md);
        if let Some(d) = &drift {
            d.to_metadata(&mut md);
        }
        tie::to_metadata(&mut md, &tied);
        md.insert("daemon_version", env!("CARGO_PKG_VERSION"));
        let path = rig.cfg.daemon.data_dir.join(name);
        let sync = rig.cfg.log_sync();
        let w =
            tokio::task::spawn_blocking(move || log::create_file(&path, &md, step_columns(), sync))
                .await
                .map_err(|e| ProtoError::new(ErrorCode::Internal, e.to_string()))?
                .map_err(|e| {
                    ProtoError::new(ErrorCode::LogError, format!("cannot create {name}: {e}"))
                })?;
        writer = Arc::new(Mutex::new(w));
        origin = clock.now_s();
    }
    // How each axis was last reached, for the log's `approach` column.
    let with_approach = approach::has_approach(lock(&writer).columns());
    let mut approach = ApproachTracker::default();
    // Park the held axis by a forward approach (what the tables and the
    // model fit assume; measured without it: the X scan's y held after a
    // backward arrival put the Y backlash, 1.7 µm, into every table value).
    if let Some(p0) = points.get(start) {
        let (x, y) = scan_approach(rig, p0);
        if move_raw(rig, x, y, &mut cancel).await?.is_none() {
            return Ok(JobState::Cancelled);
        }
        approach.moved_to(x, y);
    }
    let scan = scan::Scan {
        rig,
        plan,
        points: &points,
        drift: drift.as_ref(),
        frame: &frame,
        tie_theta_rad,
        origin,
        writer: &writer,
        name,
        with_approach,
        progress,
        start,
        overlap: rig.cfg.characterize.overlap_decode,
        gen,
        began: clock.now_s(),
    };
    scan::run(&scan, &mut approach, &mut cancel).await
}

/// What a reference re-measurement needs from the running job.
struct RefContext<'a> {
    plan: &'a ScanPlan,
    frame: &'a VisionFrame,
    /// The tie's θ the log's `theta_urad` is relative to, rad.
    tie_theta_rad: Option<f64>,
    origin: f64,
    writer: &'a Arc<Mutex<LogWriter<File>>>,
    name: &'a str,
    /// Whether the log has the `approach` column (empty on reference rows).
    with_approach: bool,
}

/// Moves to `x`, `y` (µm, raw) and waits; `Ok(None)` if cancelled meanwhile.
/// Transient faults are retried (an absolute move: sending it again is
/// harmless; see [`Rig::retry_transient`]).
async fn move_raw(
    rig: &Arc<Rig>,
    x: f64,
    y: f64,
    cancel: &mut watch::Receiver<bool>,
) -> Result<Option<MoveReply>, ProtoError> {
    tokio::select! {
        r = move_raw_retrying(rig, x, y) => r.map(Some),
        _ = cancel.changed() => Ok(None),
    }
}

/// Measures the drift reference and logs it (segment `drift_ref`, cycle of
/// the next point), then re-approaches the next scan point `next` from the
/// side its scan comes from, so the scan's backlash state is as without the
/// detour. The reference itself is always approached forward on both axes
/// from [`PARK_APPROACH_UM`] below: its backlash is the same every time and
/// cancels in the drift (differences between re-measurements).
/// `Ok(false)` if cancelled.
async fn measure_reference(
    rig: &Arc<Rig>,
    ctx: &RefContext<'_>,
    d: &DriftPlan,
    next: &plan::Point,
    approach: &mut ApproachTracker,
    cancel: &mut watch::Receiver<bool>,
) -> Result<bool, ProtoError> {
    let clock = rig.clock.clone();
    let [rx, ry] = d.reference_um;
    let (ax, ay) = clamp_to_travel(rig, rx - PARK_APPROACH_UM, ry - PARK_APPROACH_UM);
    if move_raw(rig, ax, ay, cancel).await?.is_none() {
        return Ok(false);
    }
    approach.moved_to(ax, ay);
    let Some(moved) = move_raw(rig, rx, ry, cancel).await? else {
        return Ok(false);
    };
    approach.moved_to(rx, ry);
    clock
        .sleep(Duration::try_from_secs_f64(ctx.plan.settle_s).unwrap_or_default())
        .await;
    let (m, quality) = measure_retrying(rig, ctx.plan.frames_per_point).await?;
    let meas = ctx.frame.to_stage(XyUm {
        x_um: m.x_um,
        y_um: m.y_um,
    });
    let mut rec = drift_ref_record(
        d.reference_um,
        &moved,
        meas,
        record::theta_urad(m.theta_rad, ctx.tie_theta_rad),
        quality,
        next.cycle,
        clock.now_s() - ctx.origin,
    );
    if ctx.with_approach {
        rec.extra.push(String::new());
    }
    append_record(ctx.writer, rec, ctx.name).await?;
    let (x, y) = scan_approach(rig, next);
    let moved = move_raw(rig, x, y, cancel).await?.is_some();
    if moved {
        approach.moved_to(x, y);
    }
    Ok(moved)
}

/// The scan line a segment belongs to (`Some('x')` for `scan_x_fwd` and
/// `scan_x_bwd`), `None` for the other segments (moves).
/// The way a grid node of `segment` is reached on each axis (`+1` from
/// below, `−1` from above; plain `grid`: from below on both), or `None`
/// for a segment that is no grid node's.
fn grid_ways(segment: &str) -> Option<[f64; 2]> {
    let sign = |d: crate::model::Direction| d.sign();
    if segment == plan::SEGMENT_GRID {
        return Some([1.0, 1.0]);
    }
    crate::charact::scan::grid_direction(segment).map(|d| [sign(d[0]), sign(d[1])])
}

fn scan_line(segment: &str) -> Option<char> {
    if segment.starts_with("scan_x") {
        Some('x')
    } else if segment.starts_with("scan_y") {
        Some('y')
    } else {
        None
    }
}

/// Where to go before `next` so that it is reached as its scan reaches it:
/// a grid node (segments `grid`, `grid_fwd`, `grid_bwd`) from the side of
/// its pass on both axes;
/// the held axis from [`PARK_APPROACH_UM`] below (the park), the scanned
/// axis from the side of its pass (below forward, above backward); for a
/// point of no scan line (moves) both from below. Clamped into the travel:
/// a scan starting at the end of the travel (the paper's frame: 0) has no
/// room below and is approached from the end itself (as the plain scan
/// arrives there).
fn scan_approach(rig: &Rig, next: &plan::Point) -> (f64, f64) {
    let dir = if next.segment.ends_with("_bwd") {
        -1.0
    } else {
        1.0
    };
    let (x, y) = if let Some([wx, wy]) = grid_ways(next.segment) {
        (
            next.x_um - wx * PARK_APPROACH_UM,
            next.y_um - wy * PARK_APPROACH_UM,
        )
    } else if scan_line(next.segment) == Some('x') {
        (
            next.x_um - dir * PARK_APPROACH_UM,
            next.y_um - PARK_APPROACH_UM,
        )
    } else {
        (
            next.x_um - PARK_APPROACH_UM,
            next.y_um - dir * PARK_APPROACH_UM,
        )
    };
    clamp_to_travel(rig, x, y)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// While a sweep runs, `tables build` is refused each of its logs
    /// (its own and the companions) with `job_state` naming the job; other
    /// logs pass; once the job's task has ended, its logs pass too.
    #[tokio::test]
    async fn a_running_jobs_logs_are_refused_until_it_ends() {
        let jobs = Jobs::default();
        let (cancel, _rx) = watch::channel(false);
        let (end, ended) = tokio::sync::oneshot::channel::<()>();
        let task = tokio::spawn(async move {
            let _ = ended.await;
        });
        *lock(&jobs.running) = Some(Running {
            cancel,
            task,
            kind: JobKind::Characterize,
            logs: vec!["s.csv".into(), "s-raw.csv".into()],
        });
        for log in ["s.csv", "s-raw.csv"] {
            let e = jobs.check_log_finished(log).unwrap_err();
            assert_eq!(e.code, ErrorCode::JobState);
            assert!(
                e.message.contains("running characterize job s.csv")
                    && e.message.contains("characterize cancel"),
                "{}",
                e.message
            );
        }
        assert!(jobs.check_log_finished("other.csv").is_ok());
        end.send(()).unwrap();
        while !lock(&jobs.running).as_ref().unwrap().task.is_finished() {
            tokio::task::yield_now().await;
        }
        assert!(jobs.check_log_finished("s.csv").is_ok());
    }
}
