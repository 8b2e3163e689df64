//! The step characterization's scan: each plan point moved to, settled,
//! measured and logged, in plan order, with the drift reference
//! re-measured on its schedule.
//!
//! Where the camera pipeline can defer a decode (on-demand capture: the
//! simulator's in-process rig), a point's frame is exposed and the job goes
//! on to the next point while the frame decodes; the point's record is
//! completed and appended once the next point's frame is exposed. Only the
//! wall time changes: the rig's history (every move, settle, exposure, noise
//! draw, and so every record) is the one of measuring each point before
//! moving on (`Vision::defer`). Records stay in plan order, each appended
//! before the next one is written, and every way out of the scan logs a
//! point whose frame decoded (a log stays resumable: a point is either in
//! it, measured, or measured again after a resume).
//!
//! A frame that did not decode (or decoded below `camera.min_quality`) is
//! found only after the stage left its point. The point is then measured
//! again where the rig is: the job goes back to it, approached from the
//! side its scan comes from (as after a drift reference detour), measures
//! it, and approaches the point it had gone on to again. Nothing is made
//! up, and the record says how each point was reached (`approach`).

use super::approach::ApproachTracker;
use super::record::{append_record, lock, measured_columns, Progress};
use super::{measure_reference, move_raw, scan_approach, scan_line, RefContext};
use crate::charact::log::{LogWriter, Record};
use crate::charact::plan::{self, DriftPlan, ScanPlan};
use crate::comp::VisionFrame;
use crate::daemon::protocol::MoveReply;
use crate::daemon::protocol::{ErrorCode, JobState, ProtoError, Topic};
use crate::daemon::rig::measure::{self, Exposed};
use crate::daemon::rig::Rig;
use crate::daemon::vision::Measurement;
use crate::model::XyUm;
use std::fs::File;
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tokio::sync::watch;

/// What the scan needs from the job.
pub(super) struct Scan<'a> {
    pub rig: &'a Arc<Rig>,
    pub plan: &'a ScanPlan,
    pub points: &'a [plan::Point],
    pub drift: Option<&'a DriftPlan>,
    pub frame: &'a VisionFrame,
    /// The tie's θ the log's `theta_urad` is relative to, rad (`None`: a
    /// log without the column).
    pub tie_theta_rad: Option<f64>,
    /// Rig time of the log's t = 0, s.
    pub origin: f64,
    pub writer: &'a Arc<Mutex<LogWriter<File>>>,
    pub name: &'a str,
    /// Whether the log has the `approach` column.
    pub with_approach: bool,
    pub progress: &'a Arc<Mutex<Option<Progress>>>,
    /// The first plan point of this run (after a resume, the first missing).
    pub start: usize,
    /// Whether a point's decode may run beside the move to the next
    /// (`characterize.overlap_decode`; only where the pipeline can defer).
    pub overlap: bool,
    /// The rig's stop generation when the job began: a `stop` since ends it.
    pub gen: u64,
    /// Rig time the scan began, s (for the progress's estimate).
    pub began: f64,
}

/// A point whose frames are exposed and decoding.
#[derive(Debug)]
struct Pending {
    exposed: Exposed,
    head: Head,
}

/// A measured point's record but for the measurement, taken when the
/// sequential job would take it (right after the exposure).
#[derive(Debug)]
struct Head {
    index: usize,
    t_s: f64,
    moved: MoveReply,
    approach: Option<String>,
}

/// Scans from `s.start` to the end of the plan; `Ok` with the job's end
/// state (`done`, `cancelled`, `stopped`). Every exit logs a point whose
/// frame was exposed and decoded.
pub(super) async fn run(
    s: &Scan<'_>,
    approach: &mut ApproachTracker,
    cancel: &mut watch::Receiver<bool>,
) -> Result<JobState, ProtoError> {
    let mut pending = None;
    let r = points(s, approach, cancel, &mut pending).await;
    if let Some(p) = pending.take() {
        // Left early (cancelled, stopped, an error): log it if it decoded,
        // without moving the stage again.
        if let Err(e) = settle(s, p, false).await {
            if r.is_ok() {
                return Err(e);
            }
            tracing::warn!("{}: a pending point was not logged: {e}", s.name);
        }
    }
    r
}

async fn points(
    s: &Scan<'_>,
    approach: &mut ApproachTracker,
    cancel: &mut watch::Receiver<bool>,
    pending: &mut Option<Pending>,
) -> Result<JobState, ProtoError> {
    let rig = s.rig;
    let clock = rig.clock.clone();
    let settle_for = Duration::try_from_secs_f64(s.plan.settle_s).unwrap_or_default();
    // Rig time of the last reference re-measurement (none yet: one is taken
    // before the first point, also after a resume, to re-anchor).
    let mut last_ref_s: Option<f64> = None;
    for (i, p) in s.points.iter().enumerate().skip(s.start) {
        if *cancel.borrow_and_update() {
            return Ok(JobState::Cancelled);
        }
        if rig.stop_generation() != s.gen {
            return Ok(JobState::Stopped);
        }
        // Re-approached already (the start's park or a reference detour).
        let mut approached = i == s.start;
        if let Some(d) = s.drift {
            if last_ref_s.is_none_or(|t| clock.now_s() - t >= d.every_s) {
                // The point before is logged first: records in order.
                if let Some(prev) = pending.take() {
                    settle(s, prev, true).await?;
                }
                let ctx = RefContext {
                    plan: s.plan,
                    frame: s.frame,
                    tie_theta_rad: s.tie_theta_rad,
                    origin: s.origin,
                    writer: s.writer,
                    name: s.name,
                    with_approach: s.with_approach,
                };
                if !measure_reference(rig, &ctx, d, p, approach, cancel).await? {
                    return Ok(JobState::Cancelled);
                }
                last_ref_s = Some(clock.now_s());
                approached = true;
            }
        }
        // A new scan line (X scan → Y scan): the held axis got there by a
        // long move. Park it again as at the start, so that every pass is
        // measured with the held axis after the same short forward approach
        // (what the model fit replays). Measured without it on the
        // paper-faithful stage, whose lost motion grows with the length of
        // the last move: x was 5 µm off through the first Y pass, until the
        // first reference detour re-approached it (the model table's fit
        // left 0.88 µm rms on x, 1.6 µm in the Y scan alone).
        let line = |q: &plan::Point| scan_line(q.segment);
        let before = i.checked_sub(1).and_then(|k| s.points.get(k));
        let new_line = line(p).is_some() && before.is_some_and(|q| line(q) != line(p));
        // A grid node is reached on each axis the way its segment says
        // (`grid`: from below on both), as the nodes along a row are: where
        // an axis moves against that way (a row, a pass or a cycle starting
        // again), or does not move but last moved the other way (a
        // serpentine's turn, a pass from above starting where the pass
        // from below ended), the node is approached from that side first,
        // so each map holds one arrival direction per axis.
        let grid_back = super::grid_ways(p.segment).is_some_and(|ways| {
            before.is_some_and(|q| {
                [(q.x_um, p.x_um), (q.y_um, p.y_um)]
                    .into_iter()
                    .zip(ways)
                    .enumerate()
                    .any(|(a, ((from, to), way))| {
                        let arrives = if to != from {
                            Some((to - from).signum())
                        } else {
                            approach.sign(a)
                        };
                        arrives != Some(way)
                    })
            })
        });
        if !approached && (new_line || grid_back) {
            let (x, y) = scan_approach(rig, p);
            if move_raw(rig, x, y, cancel).await?.is_none() {
                return Ok(JobState::Cancelled);
            }
            approach.moved_to(x, y);
        }
        let Some(moved) = move_raw(rig, p.x_um, p.y_um, cancel).await? else {
            return Ok(JobState::Cancelled);
        };
        approach.moved_to(p.x_um, p.y_um);
        clock.sleep(settle_for).await;
        let exposed = if s.overlap {
            measure::expose_retrying(rig, s.plan.frames_per_point).await?
        } else {
            None
        };
        let Some(exposed) = exposed else {
            // No overlap, or a pipeline that decodes as it goes: measure
            // here and now.
            let (m, quality) = measure::measure_retrying(rig, s.plan.frames_per_point).await?;
            log_point(s, &head(s, i, p, moved, approach), &m, quality).await?;
            continue;
        };
        let mut cur = Pending {
            exposed,
            head: head(s, i, p, moved, approach),
        };
        if let Some(Pending {
            exposed,
            head: prev,
        }) = pending.take()
        {
            match measure::finish(rig, exposed).await {
                Ok((m, quality)) => log_point(s, &prev, &m, quality).await?,
                Err(why) => {
                    let Some(again) =
                        measure_again(s, prev.index, &why, cur, approach, cancel).await?
                    else {
                        return Ok(JobState::Cancelled);
                    };
                    cur = again;
                }
            }
        }
        *pending = Some(cur);
    }
    if let Some(prev) = pending.take() {
        settle(s, prev, true).await?;
    }
    Ok(JobState::Done)
}

/// Completes a pending point where the stage still is (nothing moved since
/// its exposure): logged if it decoded; if not, measured again here when
/// `again` (the scan goes on), else left out (the job ends: a resume
/// measures it).
async fn settle(s: &Scan<'_>, p: Pending, again: bool) -> Result<(), ProtoError> {
    match measure::finish(s.rig, p.exposed).await {
        Ok((m, quality)) => log_point(s, &p.head, &m, quality).await,
        Err(why) if again => {
            let rig = s.rig;
            remeasuring(s, p.head.index, &why, false);
            let (m, quality) = measure::measure_retrying(rig, s.plan.frames_per_point).await?;
            let head = Head {
                t_s: rig.clock.now_s() - s.origin,
                ..p.head
            };
            log_point(s, &head, &m, quality).await
        }
        Err(why) => {
            tracing::warn!(
                "{}: point {} did not measure ({why}); not logged (a resume measures it)",
                s.name,
                p.head.index
            );
            Ok(())
        }
    }
}

/// Plan point `index` did not measure (`why`) and the stage has gone on to
/// the point of `cur` and exposed it: back to point `index`, measured there
/// and logged, then `cur`'s point reached and exposed again (its first
/// frame is published and dropped). Each is reached as its scan reaches it
/// ([`reach`]). `Ok(None)` if cancelled on the way.
async fn measure_again(
    s: &Scan<'_>,
    index: usize,
    why: &str,
    cur: Pending,
    approach: &mut ApproachTracker,
    cancel: &mut watch::Receiver<bool>,
) -> Result<Option<Pending>, ProtoError> {
    let rig = s.rig;
    remeasuring(s, index, why, true);
    let _ = measure::finish(rig, cur.exposed).await;
    let p = point(s, index)?;
    let Some(moved) = reach(s, p, approach, cancel).await? else {
        return Ok(None);
    };
    let (m, quality) = measure::measure_retrying(rig, s.plan.frames_per_point).await?;
    log_point(s, &head(s, index, p, moved, approach), &m, quality).await?;
    let index = cur.head.index;
    let p = point(s, index)?;
    let Some(moved) = reach(s, p, approach, cancel).await? else {
        return Ok(None);
    };
    let Some(exposed) = measure::expose_retrying(rig, s.plan.frames_per_point).await? else {
        return Err(ProtoError::new(
            ErrorCode::Internal,
            "the camera pipeline stopped deferring decodes",
        ));
    };
    Ok(Some(Pending {
        exposed,
        head: head(s, index, p, moved, approach),
    }))
}

/// Goes to `p` as its scan reaches it (from [`scan_approach`]), and waits
/// out the settle: the move's answer, `None` if cancelled.
async fn reach(
    s: &Scan<'_>,
    p: &plan::Point,
    approach: &mut ApproachTracker,
    cancel: &mut watch::Receiver<bool>,
) -> Result<Option<MoveReply>, ProtoError> {
    let rig = s.rig;
    let (x, y) = scan_approach(rig, p);
    if move_raw(rig, x, y, cancel).await?.is_none() {
        return Ok(None);
    }
    approach.moved_to(x, y);
    let Some(moved) = move_raw(rig, p.x_um, p.y_um, cancel).await? else {
        return Ok(None);
    };
    approach.moved_to(p.x_um, p.y_um);
    rig.clock
        .sleep(Duration::try_from_secs_f64(s.plan.settle_s).unwrap_or_default())
        .await;
    Ok(Some(moved))
}

/// The record of plan point `index` (`p`), reached by the move that
/// answered `moved`, measured now.
fn head(
    s: &Scan<'_>,
    index: usize,
    p: &plan::Point,
    moved: MoveReply,
    approach: &ApproachTracker,
) -> Head {
    Head {
        index,
        t_s: s.rig.clock.now_s() - s.origin,
        moved,
        approach: s.with_approach.then(|| approach.cell(p.segment)),
    }
}

/// Plan point `index`.
fn point<'a>(s: &Scan<'a>, index: usize) -> Result<&'a plan::Point, ProtoError> {
    s.points.get(index).ok_or_else(|| {
        ProtoError::new(
            ErrorCode::Internal,
            format!("plan point {index} does not exist"),
        )
    })
}

/// Says that plan point `index` is measured again (`job_remeasure`, topic
/// `job`; `detour`: the stage had left it). Why an event: a lab watching a
/// long job wants to see that frames fail to decode before they fail for
/// good, and where.
fn remeasuring(s: &Scan<'_>, index: usize, why: &str, detour: bool) {
    tracing::warn!(
        "{}: point {index} did not measure ({why}); measuring it again{}",
        s.name,
        if detour { " (going back to it)" } else { "" }
    );
    let (segment, cycle) = s
        .points
        .get(index)
        .map_or(("", 0), |p| (p.segment, p.cycle));
    s.rig.push(
        Topic::Job,
        "job_remeasure",
        serde_json::json!({"log": s.name, "point": index, "segment": segment, "cycle": cycle,
                           "reason": why, "detour": detour}),
    );
}

/// The log record of plan point `p` measured at `m` (pattern frame).
fn record(s: &Scan<'_>, p: &plan::Point, head: &Head, m: &Measurement, quality: f64) -> Record {
    let meas = s.frame.to_stage(XyUm {
        x_um: m.x_um,
        y_um: m.y_um,
    });
    let mut rec = Record {
        t_s: head.t_s,
        segment: p.segment.to_owned(),
        cycle: p.cycle,
        x_target_um: p.x_um,
        y_target_um: p.y_um,
        x_cmd_um: p.x_um,
        y_cmd_um: p.y_um,
        x_meas_um: meas.x_um,
        y_meas_um: meas.y_um,
        temp_c: None,
        theta_urad: super::record::theta_urad(m.theta_rad, s.tie_theta_rad),
        extra: measured_columns(&head.moved, quality),
    };
    if let Some(a) = &head.approach {
        rec.extra.push(a.clone());
    }
    rec
}

/// Appends the record of `head`'s point and reports the progress.
async fn log_point(
    s: &Scan<'_>,
    head: &Head,
    m: &Measurement,
    quality: f64,
) -> Result<(), ProtoError> {
    let p = point(s, head.index)?;
    append_record(s.writer, record(s, p, head, m, quality), s.name).await?;
    report(s, head.index + 1);
    Ok(())
}

/// Progress after `done` points, with the remaining rig time estimated
/// from the pace since the scan began.
fn report(s: &Scan<'_>, done: usize) {
    let now = s.rig.clock.now_s();
    let per_point = (now - s.began) / done.saturating_sub(s.start).max(1) as f64;
    let eta = per_point * s.points.len().saturating_sub(done) as f64;
    let snapshot = {
        let mut g = lock(s.progress);
        g.as_mut().map(|pr| {
            pr.done = done;
            pr.eta_s = Some(eta);
            pr.to_json()
        })
    };
    if let Some(snap) = snapshot {
        s.rig.push(Topic::Job, "job", snap);
    }
}
