//! What a job writes and reports: its log's columns and records (the drift
//! reference row of both the step and the sweep job), appending them, and
//! its progress. A leaf the job files share.

use crate::analysis::drift::DRIFT_REF_SEGMENT;
use crate::charact::log::{Columns, LogWriter, Record};
use crate::daemon::protocol::{
    ErrorCode, JobKind, JobProgress, JobState, MoveReply, PairUm, ProtoError,
};
use crate::model::XyUm;
use serde_json::Value;
use std::fs::File;
use std::sync::atomic::AtomicU64;
use std::sync::{Arc, Mutex};

/// Locks, recovering a poisoned mutex (a panicked writer's data is still
/// the log's).
pub(crate) fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

/// The log's columns: the standard ones with the decoded θ
/// (`theta_urad`, relative to the tie's: [`theta_urad`]) plus the
/// controller-reported positions and the mean decode quality, so every
/// position source is kept.
pub fn columns() -> Columns {
    Columns {
        temp_c: false,
        theta_urad: true,
        extra: vec![
            "x_reported_um".to_owned(),
            "y_reported_um".to_owned(),
            "vision_quality".to_owned(),
        ],
    }
}

/// A point's `theta_urad` cell: its decoded θ (`theta_rad`, the frames'
/// mean) minus the one the log's tie absorbed (`tie_theta_rad`, metadata
/// [`TIE_THETA_KEY`](crate::charact::log::TIE_THETA_KEY)), µrad, wrapped
/// to a turn in (−π, π]; `None` for a log without the column (begun before
/// it existed: `tie_theta_rad` is then `None`).
pub(crate) fn theta_urad(theta_rad: f64, tie_theta_rad: Option<f64>) -> Option<f64> {
    tie_theta_rad.map(|t| crate::daemon::vision::wrap_angle_rad(theta_rad - t) * 1e6)
}

/// The tie's θ a resumed log's `theta_urad` is relative to: its metadata
/// key when the log has the column, else `None` (no θ written).
pub(crate) fn tie_theta_of(columns: &Columns, md: &crate::charact::log::Metadata) -> Option<f64> {
    if !columns.theta_urad {
        return None;
    }
    md.get(crate::charact::log::TIE_THETA_KEY)?
        .parse::<f64>()
        .ok()
        .filter(|t| t.is_finite())
}

/// Progress of the current or last job.
#[derive(Debug, Clone)]
pub struct Progress {
    /// Which job.
    pub kind: JobKind,
    /// Log file name.
    pub log: String,
    /// Running, or how it ended.
    pub state: JobState,
    /// Points logged.
    pub done: usize,
    /// Points in the plan.
    pub total: usize,
    /// Estimated remaining rig time, s.
    pub eta_s: Option<f64>,
    /// Why it failed or stopped.
    pub error: Option<String>,
    /// Operations retried after transient faults so far in this run of the
    /// job (the rig's [`Rig::job_retries`](crate::daemon::rig::Rig::job_retries), shared so status is live).
    pub retries: Arc<AtomicU64>,
    /// What a finished sweep found (camera delay, frames; see
    /// [`sweep_job`](super::sweep_job)); `null` otherwise.
    pub result: Value,
}

impl Progress {
    /// As JSON.
    pub fn to_json(&self) -> Value {
        self.to_reply().to_json()
    }

    /// As replies and events carry it.
    pub fn to_reply(&self) -> JobProgress {
        JobProgress {
            kind: self.kind,
            log: self.log.clone(),
            state: self.state,
            done: self.done as u64,
            total: self.total as u64,
            eta_s: self.eta_s,
            error: self.error.clone(),
            retries: self.retries.load(std::sync::atomic::Ordering::SeqCst),
            result: self.result.clone(),
        }
    }
}

/// Appends `rec` to a job's log on a blocking thread; the record is written,
/// flushed and synced before this returns (every logged point survives a
/// crash). `name` is the log's file name, for the error.
pub(crate) async fn append_record(
    writer: &Arc<Mutex<LogWriter<File>>>,
    rec: Record,
    name: &str,
) -> Result<(), ProtoError> {
    let w = writer.clone();
    tokio::task::spawn_blocking(move || lock(&w).append(&rec))
        .await
        .map_err(|e| ProtoError::new(ErrorCode::Internal, e.to_string()))?
        .map_err(|e| ProtoError::new(ErrorCode::LogError, format!("cannot append to {name}: {e}")))
}

/// The log record of a drift reference re-measurement (segment
/// `drift_ref`, target = command = the reference, the controllers' reported
/// position and the frame quality as extra columns): one shape for the step
/// and the sweep job, whose readers (`tables build`) treat both alike.
pub(crate) fn drift_ref_record(
    reference_um: [f64; 2],
    moved: &MoveReply,
    meas: XyUm,
    theta_urad: Option<f64>,
    quality: f64,
    cycle: u32,
    t_s: f64,
) -> Record {
    let [rx, ry] = reference_um;
    Record {
        t_s,
        segment: DRIFT_REF_SEGMENT.to_owned(),
        cycle,
        x_target_um: rx,
        y_target_um: ry,
        x_cmd_um: rx,
        y_cmd_um: ry,
        x_meas_um: meas.x_um,
        y_meas_um: meas.y_um,
        temp_c: None,
        theta_urad,
        extra: measured_columns(moved, quality),
    }
}

/// The extra columns of [`columns`] for a point reached by the move that
/// answered `moved` (its `reported` position, empty when unknown) and
/// measured at `quality`.
pub(crate) fn measured_columns(moved: &MoveReply, quality: f64) -> Vec<String> {
    let rep = moved.reported.unwrap_or(PairUm {
        x_um: None,
        y_um: None,
    });
    vec![
        rep.x_um.map_or(String::new(), |v| format!("{v:.4}")),
        rep.y_um.map_or(String::new(), |v| format!("{v:.4}")),
        format!("{quality:.3}"),
    ]
}
