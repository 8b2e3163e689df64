//! The main job's client of the daemon's socket: JSON lines, one request
//! and its reply at a time, jobs followed to their end. A file of its own:
//! the only I/O the pipeline does once the rig and the daemon are up.

use super::RunError;
use micropos::daemon::protocol::JobState;
use serde_json::{json, Value};
use std::path::Path;
use std::time::{Duration, Instant};
use tokio::io::{AsyncBufReadExt, AsyncWriteExt, BufReader};
use tokio::net::UnixStream;

/// How often a followed job's status is read.
const STATUS_POLL: Duration = Duration::from_secs(1);

/// A JSON-lines client of the daemon's socket.
pub(super) struct Client {
    r: BufReader<tokio::net::unix::OwnedReadHalf>,
    w: tokio::net::unix::OwnedWriteHalf,
    next: u64,
}

impl Client {
    pub(super) async fn connect(p: &Path) -> Result<Client, RunError> {
        let (r, w) = UnixStream::connect(p).await?.into_split();
        Ok(Client {
            r: BufReader::new(r),
            w,
            next: 0,
        })
    }

    /// Sends a request; its reply's fields, or the refusal as an error.
    pub(super) async fn call(&mut self, mut req: Value) -> Result<Value, RunError> {
        self.next += 1;
        req["id"] = json!(self.next);
        self.w.write_all(format!("{req}\n").as_bytes()).await?;
        loop {
            let mut l = String::new();
            if self.r.read_line(&mut l).await? == 0 {
                return Err(RunError::Setup("the daemon closed the connection".into()));
            }
            let v: Value = serde_json::from_str(&l)
                .map_err(|e| RunError::Setup(format!("unreadable reply {l:?}: {e}")))?;
            if v.get("event").is_some() || v["id"] != json!(self.next) {
                continue;
            }
            if v["ok"] == json!(true) {
                return Ok(v);
            }
            return Err(RunError::Refused {
                cmd: req["cmd"].as_str().unwrap_or("?").to_owned(),
                code: v["error"]["code"].as_str().unwrap_or("?").to_owned(),
                message: v["error"]["message"].as_str().unwrap_or("?").to_owned(),
            });
        }
    }

    /// The daemon's rig time, s.
    pub(super) async fn now_s(&mut self) -> Result<f64, RunError> {
        Ok(self.call(json!({"cmd": "status"})).await?["t_s"]
            .as_f64()
            .unwrap_or(f64::NAN))
    }

    /// Polls a job's status until it leaves `running`; reports progress.
    /// Starts the validation job `req` and follows it to its end; returns
    /// its final status.
    pub(super) async fn validate(
        &mut self,
        req: Value,
        progress: &mut dyn FnMut(&str),
    ) -> Result<Value, RunError> {
        self.call(req).await?;
        self.follow(
            json!({"cmd": "validate", "action": "status"}),
            "validate",
            progress,
        )
        .await
    }

    pub(super) async fn follow(
        &mut self,
        status_req: Value,
        what: &str,
        progress: &mut dyn FnMut(&str),
    ) -> Result<Value, RunError> {
        let mut last_print = Instant::now();
        loop {
            let s = self.call(status_req.clone()).await?;
            let job = &s["job"];
            let state = JobState::of(job);
            if state != Some(JobState::Running) {
                if state != Some(JobState::Done) {
                    return Err(RunError::Job {
                        kind: what.to_owned(),
                        state: job["state"].as_str().unwrap_or("?").to_owned(),
                        error: job["error"].as_str().unwrap_or("").to_owned(),
                    });
                }
                progress(&format!(
                    "{what}: done ({} points)",
                    job["done"].as_u64().unwrap_or(0)
                ));
                return Ok(s);
            }
            if last_print.elapsed() >= Duration::from_secs(5) {
                last_print = Instant::now();
                // No estimate before the job's first points.
                let eta = job["eta_s"].as_f64().filter(|e| e.is_finite()).map_or_else(
                    || "ETA not yet known".to_owned(),
                    |e| format!("ETA {e:.0} simulated s"),
                );
                progress(&format!(
                    "{what}: {}/{} points, {eta}",
                    job["done"].as_u64().unwrap_or(0),
                    job["total"].as_u64().unwrap_or(0),
                ));
            }
            // Rig time (virtual on the in-process rig): the job's end is
            // seen within a second, without thousands of status calls per
            // simulated hour.
            tokio::time::sleep(STATUS_POLL).await;
        }
    }
}
