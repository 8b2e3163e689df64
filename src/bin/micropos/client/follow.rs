//! `--follow`: waits for a started job to end, shows its progress, then
//! prints how it ended and what to do next.
//!
//! Why the wait is the same on a terminal and in a pipe: a script or a CI
//! log must not take a job that still runs for finished — a `tables build`
//! typed right after would read the log only as far as it goes (issue 33).
//! Only the progress display differs: a bar for a person at a terminal, a
//! plain line now and then elsewhere (a hidden bar left a log with nothing
//! between the start and the end).

use super::{sweep_summary, typed, Conn, Unreachable};
use micropos::daemon::protocol::{
    from_reply, to_value, Command, Event, FaultEvent, JobEvent, JobKind, JobObject, JobProgress,
    JobReply, JobState, LaggedEvent, Topic,
};
use serde_json::Value;
use std::io::{IsTerminal, Write};
use std::process::ExitCode;
use std::time::{Duration, Instant};

/// Least time between two plain progress lines: often enough to show the
/// job is alive in a log, rarely enough not to drown it.
const PLAIN_EVERY: Duration = Duration::from_secs(10);

/// How progress is shown while the job runs.
enum View {
    /// A person watches a terminal.
    Bar(indicatif::ProgressBar),
    /// Output goes to a file or a pipe: a line on stderr now and then, so
    /// stdout holds only the replies and the outcome.
    Plain { last: Instant },
}

impl View {
    /// A bar when both stdout and stderr (where indicatif draws) are
    /// terminals, else plain lines (a bar would be hidden).
    fn new(job: Option<&JobProgress>) -> View {
        if !(std::io::stdout().is_terminal() && std::io::stderr().is_terminal()) {
            return View::Plain {
                last: Instant::now(),
            };
        }
        let bar = indicatif::ProgressBar::new(job.map_or(0, |j| j.total));
        bar.set_style(
            indicatif::ProgressStyle::with_template("{bar:40} {pos}/{len} points  ETA {msg}")
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
        );
        bar.set_position(job.map_or(0, |j| j.done));
        View::Bar(bar)
    }

    /// Shows a running job's `job` event.
    fn progress(&mut self, ev: &JobObject) {
        let Some(p) = ev.known() else {
            return;
        };
        match self {
            View::Bar(bar) => {
                bar.set_position(p.done);
                if let Some(eta) = p.eta_s {
                    bar.set_message(format!("{eta:.0} s"));
                }
            }
            View::Plain { last } => {
                if last.elapsed() >= PLAIN_EVERY {
                    *last = Instant::now();
                    eprintln!("{}", progress_line(p));
                }
            }
        }
    }

    /// A line between progress updates (a fault), not lost under the bar.
    fn note(&self, line: &str) {
        match self {
            View::Bar(bar) => bar.println(line),
            View::Plain { .. } => eprintln!("{line}"),
        }
    }

    /// Takes the bar off the terminal at the job's end (nothing for plain
    /// lines): the final state line replaces it. Why not leave it: a
    /// finished bar keeps the cursor at its end, so the final state was
    /// printed on the bar's line ("… 10/10 points  ETA done characterize
    /// c.csv: state done …") and read as no summary at all (issue 33).
    fn close(&self) {
        if let View::Bar(bar) = self {
            bar.finish_and_clear();
        }
    }
}

/// `progress: 5/12 points, ETA 30 s`.
fn progress_line(p: &JobProgress) -> String {
    let eta = p.eta_s.map_or(String::new(), |s| format!(", ETA {s:.0} s"));
    format!("progress: {}/{} points{eta}", p.done, p.total)
}

/// Whether a `job` object (event or status) is of a job that has ended.
fn ended(job: Option<&JobObject>) -> bool {
    match job {
        Some(JobObject::Known(p)) => p.state.ended(),
        // A state this client does not know (a newer daemon's) has ended
        // too; no state at all (no job yet) has not.
        Some(JobObject::Unknown(v)) => v["state"].is_string(),
        None => false,
    }
}

/// Waits until the job the `started` reply announced ends; its last `job`
/// object (the final event or a status's `job`). Losing the daemon is an
/// error that says the job's end is unknown.
pub(super) async fn follow(conn: &mut Conn, started: &JobReply) -> Result<JobObject, Unreachable> {
    let job = started.job.as_ref().and_then(JobObject::known);
    let kind = job.map_or(JobKind::Characterize, |j| j.kind);
    let log = job.map_or("?".to_owned(), |j| j.log.clone());
    let mut view = View::new(job);
    let end = wait_end(conn, &mut view, kind).await;
    view.close();
    end.map_err(|Unreachable(e)| {
        Unreachable(e.context(format!(
            "lost the daemon while following {kind} job {log}; its end is unknown (`micropos {kind} status` once the daemon is back)"
        )))
    })
}

/// The subscription and the event loop of [`follow`].
async fn wait_end(
    conn: &mut Conn,
    view: &mut View,
    kind: JobKind,
) -> Result<JobObject, Unreachable> {
    conn.request(Command::Subscribe(vec![Topic::Job, Topic::Fault]))
        .await?;
    // A job that ended before the subscription took effect sends no more
    // events: its status (asked after subscribing) says so.
    let mut last = job_status(conn, kind).await?;
    loop {
        if let Some(job) = last.as_ref().filter(|j| ended(Some(j))) {
            return Ok(job.clone());
        }
        let ev = conn.line().await?;
        match ev["event"].as_str() {
            Some(JobEvent::NAME) => {
                // Any object reads as a job object (an unknown one as sent).
                let job: JobObject = typed(&ev, "job event")?;
                view.progress(&job);
                last = Some(job);
            }
            Some(FaultEvent::NAME) => {
                let reason = from_reply::<FaultEvent>(&ev).map_or("?".to_owned(), |f| f.reason);
                view.note(&format!("fault: {reason}"));
            }
            // Events were dropped for this slow reader, perhaps the end:
            // the status has the job's state now.
            Some(LaggedEvent::NAME) => last = job_status(conn, kind).await?,
            _ => {}
        }
    }
}

/// The current `job` object of a `characterize` or `validate` status.
async fn job_status(conn: &mut Conn, kind: JobKind) -> Result<Option<JobObject>, Unreachable> {
    let s = conn.request(kind.status_command()).await?;
    let r: JobReply = typed(&s, "job status")?;
    Ok(r.job)
}

/// Prints how a followed job ended — its final state, then `summary` (what
/// it measured) and the next step if it ended done, else why not on stderr
/// — and returns the exit code: 0 only for `done`. With `json` the final
/// `job` object (or `json_reply` if given) is printed as one line instead.
pub(super) fn report_end(
    job: &JobObject,
    summary: Option<String>,
    json: bool,
    json_reply: Option<&Value>,
) -> ExitCode {
    let done = ended_done(job);
    let out = std::io::stdout();
    let mut out = out.lock();
    if json {
        let line = json_reply
            .cloned()
            .unwrap_or_else(|| to_value(&JobReply::job(Some(job.clone()))));
        let _ = writeln!(out, "{line}");
    } else {
        let _ = writeln!(out, "{}", final_line(job));
        if done {
            if let Some(s) = summary {
                let _ = writeln!(out, "{}", s.trim_end());
            }
            let _ = writeln!(out, "next: {}", next_step(job));
        }
    }
    if done {
        return ExitCode::SUCCESS;
    }
    eprintln!("error: {}", not_done(job));
    ExitCode::from(1)
}

/// Whether the job ended done: the only end a script may build on.
fn ended_done(job: &JobObject) -> bool {
    job.known().is_some_and(|p| p.state == JobState::Done)
}

/// `characterize run1.csv: state done, 12/12 points (1 retry)`; a job
/// this client cannot read (a newer daemon's state) as its JSON.
fn final_line(job: &JobObject) -> String {
    let p = match job {
        JobObject::Known(p) => p,
        JobObject::Unknown(v) => return format!("job ended: {v}"),
    };
    let retries = match p.retries {
        0 => String::new(),
        1 => " (1 retry)".to_owned(),
        n => format!(" ({n} retries)"),
    };
    format!(
        "{} {}: state {}, {}/{} points{retries}",
        p.kind, p.log, p.state, p.done, p.total
    )
}

/// What a person does after a job that ended done.
fn next_step(job: &JobObject) -> String {
    let p = job.known();
    let log = p.map_or("LOG", |p| p.log.as_str());
    if p.map(|p| p.kind) == Some(JobKind::Validate) {
        format!(
            "the log {log} is in the daemon's data_dir; its figures (Figs. 10-11): `micropos plot DATA_DIR/{log} --out DIR`, or the daemon's web view"
        )
    } else {
        format!("micropos tables build {log}")
    }
}

/// Why a job that did not end done ended, and what can be done.
fn not_done(job: &JobObject) -> String {
    let (kind, log, state, error) = match job {
        JobObject::Known(p) => (
            p.kind.as_str(),
            p.log.as_str(),
            p.state.as_str(),
            p.error.as_deref(),
        ),
        // A newer daemon's job, read as far as it goes.
        JobObject::Unknown(v) => (
            v["kind"].as_str().unwrap_or("job"),
            v["log"].as_str().unwrap_or("?"),
            v["state"].as_str().unwrap_or("?"),
            v["error"].as_str(),
        ),
    };
    let why = match (error, job.known().map(|p| p.state)) {
        (Some(e), _) if !e.is_empty() => e.to_owned(),
        (_, Some(JobState::Cancelled)) => "a client cancelled it".to_owned(),
        (_, Some(JobState::Stopped)) => {
            "a stop or a fault halted the rig (`micropos status`)".to_owned()
        }
        _ => "no reason given".to_owned(),
    };
    let resume = if kind == JobKind::Characterize.as_str() {
        format!(" (a step log resumes where it ended: `micropos characterize resume --log {log}`)")
    } else {
        String::new()
    };
    format!("{kind} job {log} ended {state}, not done: {why}{resume}")
}

/// The text summary of a characterization: the log it wrote, and a
/// sweep's delay and anchors.
pub(super) fn characterize_summary(job: &JobObject) -> Option<String> {
    let p = job.known();
    let log = format!(
        "log: {} in the daemon's data_dir, {} points",
        p.map_or("?", |p| p.log.as_str()),
        p.map_or(0, |p| p.done)
    );
    Some(match p.and_then(|p| sweep_summary(&p.result)) {
        Some(sweep) => format!("{log}\n{sweep}"),
        None => log,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Only done counts as success, the others say how the job ended; the next step
    /// names the log a characterization's tables are built from.
    #[test]
    fn only_done_exits_zero_and_the_next_step_names_the_log() {
        let job = |state: &str, kind: &str| -> JobObject {
            from_reply(
                &serde_json::json!({"kind": kind, "log": "c.csv", "state": state, "done": 3,
                   "total": 12, "retries": 0, "error": null}),
            )
            .unwrap()
        };
        assert!(ended_done(&job("done", "characterize")));
        for s in ["failed", "cancelled", "stopped", "running"] {
            assert!(!ended_done(&job(s, "characterize")), "{s}");
            assert!(not_done(&job(s, "validate")).contains(&format!("ended {s}")));
        }
        assert!(
            !ended(Some(&job("running", "validate"))) && ended(Some(&job("stopped", "validate")))
        );
        assert_eq!(
            next_step(&job("done", "characterize")),
            "micropos tables build c.csv"
        );
        assert!(next_step(&job("done", "validate")).contains("micropos plot DATA_DIR/c.csv"));
        assert_eq!(
            final_line(&job("done", "characterize")),
            "characterize c.csv: state done, 3/12 points"
        );
    }
}
