//! Jobs as the rig sees them: owning the axes through the state machine
//! for a job's duration and retrying its moves and measurements after
//! transient faults.

use super::Rig;
use crate::daemon::protocol::{ErrorCode, ProtoError, Topic};
use crate::daemon::state::Activity;
use serde_json::json;
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::Duration;

impl Rig {
    /// Marks a job as owning the axes (refused unless idle and connected).
    pub fn begin_job(self: &Arc<Self>) -> Result<(), ProtoError> {
        let t = self.clock.now_s();
        self.core().begin_job(t)?;
        self.job_retries.store(0, Ordering::SeqCst);
        Ok(())
    }

    /// Runs one job operation (a move, a measurement), retrying it after a
    /// transient fault ([`ProtoError::transient`]) up to `daemon.job_retries`
    /// times, with a back-off of `daemon.job_retry_backoff_s` on the rig's
    /// clock, doubled per retry. Each retry is counted in
    /// [`Rig::job_retries`] and pushed as a `job_retry` event on the `job`
    /// topic. A permanent fault returns at once; so does a stop or fault of
    /// the rig during the back-off (`halted`: the job must notice it, not
    /// carry on). `op` must be idempotent: jobs retry absolute moves (the
    /// commanded position is re-queried after a failed move, see
    /// `raw_move`) and measurements, never relative moves.
    pub async fn retry_transient<T, F, Fut>(
        &self,
        operation: &str,
        mut op: F,
    ) -> Result<T, ProtoError>
    where
        F: FnMut() -> Fut,
        Fut: std::future::Future<Output = Result<T, ProtoError>>,
    {
        let max = self.cfg.daemon.job_retries;
        let mut backoff_s = self.cfg.daemon.job_retry_backoff_s;
        let gen = self.stop_generation();
        let mut attempt = 0u32;
        loop {
            let e = match op().await {
                Ok(v) => return Ok(v),
                Err(e) => e,
            };
            if !e.transient {
                return Err(e);
            }
            if attempt >= max {
                return Err(ProtoError::new(
                    e.code,
                    format!(
                        "{operation}: {} (a transient fault, but it persisted through {attempt} {}; daemon.job_retries = {max})",
                        e.message,
                        if attempt == 1 { "retry" } else { "retries" }
                    ),
                ));
            }
            attempt += 1;
            let total = self.job_retries.fetch_add(1, Ordering::SeqCst) + 1;
            tracing::warn!(
                "{operation}: transient fault ({}: {}); retry {attempt} of {max} in {backoff_s} s",
                e.code,
                e.message
            );
            self.push(
                Topic::Job,
                "job_retry",
                json!({"t_s": self.clock.now_s(), "operation": operation, "attempt": attempt,
                       "max": max, "code": e.code.as_str(), "error": e.message,
                       "backoff_s": backoff_s, "retries": total}),
            );
            self.clock
                .sleep(Duration::try_from_secs_f64(backoff_s).unwrap_or_default())
                .await;
            backoff_s *= 2.0;
            if self.stop_generation() != gen {
                return Err(ProtoError::new(
                    ErrorCode::Halted,
                    format!(
                        "{operation}: a stop or fault came while waiting to retry after: {}",
                        e.message
                    ),
                ));
            }
        }
    }

    /// Ends a job's ownership of the axes.
    pub fn end_job(&self) {
        let t = self.clock.now_s();
        self.core().end(Activity::Job, t);
    }
}
