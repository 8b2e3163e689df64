//! The one way a job starts: its progress set, its task spawned, its end
//! written back, whatever the job. Characterization (step, grid, sweep,
//! resumed) and validation differ in what they run, not in how they are
//! started, followed, cancelled or ended.

use super::{lock, Jobs, Progress, Running};
use crate::daemon::protocol::{JobEvent, JobKind, JobObject, JobReply, JobState, ProtoError};
use crate::daemon::rig::Rig;
use serde_json::Value;
use std::future::Future;
use std::sync::Arc;
use tokio::sync::watch;

/// How a job's run ended, as [`Jobs::spawn`] writes it into the progress.
#[derive(Debug)]
pub(crate) struct Ended {
    pub state: JobState,
    /// What a finished sweep found (the progress's `result`); `null`
    /// otherwise.
    pub result: Value,
    /// A validation's `{"results", "logs"}`: `validate status` returns it,
    /// and the job's last event carries both keys. `None` for a
    /// characterization, and for a validation that did not finish.
    pub validation: Option<Value>,
}

impl Ended {
    /// An end with nothing to report beyond its state.
    pub fn state(state: JobState) -> Self {
        Self {
            state,
            result: Value::Null,
            validation: None,
        }
    }
}

/// What [`Jobs::spawn`] needs to know of a job besides its run.
#[derive(Debug)]
pub(crate) struct Launch {
    pub kind: JobKind,
    /// For the warning when it fails: "characterization c.csv".
    pub what: String,
    /// Every log the job writes, its own first (see [`Running::logs`]).
    pub logs: Vec<String>,
    /// Points already logged (a resumed job) and in the whole plan.
    pub done: usize,
    pub total: usize,
}

impl Jobs {
    /// Starts `run` as the job `launch` describes; `run` gets the receiver
    /// that `cancel` signals. The caller has taken the rig for the job
    /// (`Rig::begin_job`); the task gives it back when `run` ends, before
    /// the progress says so, so that a client that sees the job ended
    /// finds the rig free. Returns the start reply, `{"job": progress}`.
    pub(crate) fn spawn<F, Fut>(&self, rig: &Arc<Rig>, launch: Launch, run: F) -> JobReply
    where
        F: FnOnce(watch::Receiver<bool>) -> Fut,
        Fut: Future<Output = Result<Ended, ProtoError>> + Send + 'static,
    {
        let (cancel, cancel_rx) = watch::channel(false);
        *lock(&self.progress) = Some(Progress {
            kind: launch.kind,
            log: launch.logs.first().cloned().unwrap_or_default(),
            state: JobState::Running,
            done: launch.done,
            total: launch.total,
            eta_s: None,
            error: None,
            retries: rig.job_retries.clone(),
            result: Value::Null,
        });
        if launch.kind == JobKind::Validate {
            *lock(&self.validation) = None;
        }
        let job = run(cancel_rx);
        let (progress, validation, rig2) =
            (self.progress.clone(), self.validation.clone(), rig.clone());
        let (kind, what) = (launch.kind, launch.what);
        let task = tokio::spawn(async move {
            let r = job.await;
            rig2.end_job();
            let (ended, error) = match r {
                Ok(ended) => (ended, None),
                Err(e) => {
                    tracing::warn!("{what} failed: {e}");
                    (Ended::state(JobState::Failed), Some(e.to_string()))
                }
            };
            if kind == JobKind::Validate {
                *lock(&validation) = ended.validation.clone();
            }
            let mut g = lock(&progress);
            if let Some(p) = g.as_mut() {
                p.state = ended.state;
                p.result = ended.result;
                p.error = error;
                p.eta_s = None;
                let mut ev = JobEvent::of(p.to_reply());
                if let Some(v) = &ended.validation {
                    ev.results = Some(v["results"].clone());
                    ev.logs = Some(v["logs"].clone());
                }
                rig2.emit(&ev);
            }
        });
        *lock(&self.running) = Some(Running {
            cancel,
            task,
            kind: launch.kind,
            logs: launch.logs,
        });
        JobReply::job(
            lock(&self.progress)
                .as_ref()
                .map(|p| JobObject::from(p.to_reply())),
        )
    }
}
