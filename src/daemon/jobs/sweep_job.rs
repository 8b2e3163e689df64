//! The sweep characterization job (`characterize start` with `mode =
//! sweep`): ties vision to stage as the step job does, then per pass sets
//! the swept axis's velocity, sends one move across the range plus run-ups,
//! samples the axis's position (from the controller's data recorder where
//! it has one, `jobs::sweep_recorder`, else `POS?` every
//! [`POS_SAMPLE_PERIOD`] of rig time; the log's metadata says which) and
//! collects every decoded frame until the axis arrives; at the end estimates the camera
//! delay and writes the log resampled onto the step grid
//! (`charact::sweep` has the method).
//!
//! After the two passes of each cycle on an axis (when `anchor_spacing_um`
//! is positive), the job stops at that axis's static anchors, forward then backward,
//! each reached as the step plan reaches its points (`charact::sweep::anchor`):
//! the records are corrected by the anchors' offset curves, so that they
//! describe the stage in the step plan's motion state.
//!
//! Unlike the step job, records are written when the sweep ends (the delay
//! and the anchor correction come from all passes): an interrupted
//! sweep logs nothing and is started again; `characterize resume` refuses
//! sweep logs. With a drift plan (`drift_every_s`, as the step job) the
//! job re-measures the drift reference before the first pass and before
//! each pass that starts `every_s` or more after the last re-measurement,
//! approached as the step job approaches it, and logs it between the
//! passes (segment `drift_ref`): `tables build` removes the drift over the
//! sweep as it does over a step characterization. The swept axis's velocity
//! is restored after every pass, also on errors.

mod output;

use super::sweep_recorder::{merge, Chunk, CHUNK_S, POLL_WITH_RECORDER, RECORD_RATE, RECORD_TABLE};
use super::{
    clamp_to_travel, drift_ref_record, lock, measure_retrying, move_raw_retrying, tie, Progress,
    PARK_APPROACH_UM,
};
use crate::charact::log::{self, Columns, Metadata, Record, SyncPolicy};
use crate::charact::plan::DriftPlan;
use crate::charact::scan::SEGMENTS_SWEEP_ANCHOR;
use crate::charact::sweep::anchor::{
    anchor_correction, anchor_route, AnchorCorrection, AnchorMeas,
};
use crate::charact::sweep::{
    estimate_delay, frames_at, resample, DelayEstimate, PassData, PassSpec, PosSample, SweepFrame,
    SweepPlan,
};
use crate::daemon::protocol::{ErrorCode, JobState, MoveRequest, ProtoError, Topic};
use crate::daemon::rig::{driver_error, Rig};
use crate::daemon::vision::Measurement;
use crate::driver::Axis;
use crate::model::XyUm;
use output::{anchor_json, records, result_json, sweep_metadata, RecordContext};
use serde_json::{json, Value};
use std::ops::ControlFlow;
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tokio::sync::watch;

/// Rig time between two `POS?` samples during a pass. A C-863 answers
/// `POS?` in ≈ 2 ms at 115200 baud; 5 ms leaves the line to the daemon's
/// other queries.
pub const POS_SAMPLE_PERIOD: Duration = Duration::from_millis(5);

/// The log's columns: the step job's plus the pass velocity, the frames'
/// mean camera stamp, how many frames a record averages and the anchor
/// correction in x and y (on a scan record the one applied, on an anchor
/// record that cycle's anchor − sweep difference; docs/measurement-log.md).
pub fn columns() -> Columns {
    let mut c = super::columns();
    c.extra.extend(
        [
            "velocity_um_per_s",
            "t_frame_s",
            "frames",
            "x_anchor_corr_um",
            "y_anchor_corr_um",
        ]
        .iter()
        .map(|s| (*s).to_owned()),
    );
    c
}

/// Log segment of an anchor record: `anchor_x_fwd`, `anchor_x_bwd`,
/// `anchor_y_fwd`, `anchor_y_bwd`. Not `scan_*`: the lookup tables, the
/// model fit and the plots take only the scan segments, and `diagnose`
/// leaves these out (their approach is not in the log).
pub fn anchor_segment(x_axis: bool, forward: bool) -> &'static str {
    SEGMENTS_SWEEP_ANCHOR[2 * usize::from(!x_axis) + usize::from(!forward)]
}

/// What the job needs besides the rig.
#[derive(Debug, Clone)]
pub struct SweepArgs {
    /// The plan.
    pub plan: SweepPlan,
    /// Log file name.
    pub name: String,
    /// Optional second log resampled without the delay correction (the
    /// anchor correction applied as in the log).
    pub uncorrected: Option<String>,
    /// Optional third log without the anchor correction (the delay
    /// correction applied as in the log).
    pub unanchored: Option<String>,
    /// Frames per tie point.
    pub frames_per_point: u32,
    /// Settle before each tie point and drift reference, s.
    pub settle_s: f64,
    /// Drift reference re-measurements between passes, if any.
    pub drift: Option<DriftPlan>,
}

/// Runs the sweep; returns the final state and the result (delay estimate,
/// frame counts) for the job's progress. The logs are written at the end,
/// from everything measured.
pub(super) async fn run(
    rig: &Arc<Rig>,
    a: &SweepArgs,
    progress: &Arc<Mutex<Option<Progress>>>,
    mut cancel: watch::Receiver<bool>,
) -> Result<(JobState, Value), ProtoError> {
    let plan = &a.plan;
    let began = rig.clock.now_s();
    let lines = [
        tie::TieLine {
            x_axis: true,
            start_um: plan.x_start_um,
            range_um: plan.x_range_um,
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
        r = tie::measure_frame(rig, lines, a.frames_per_point, a.settle_s) => r?,
        _ = cancel.changed() => return Ok((JobState::Cancelled, Value::Null)),
    };
    let m = match measure(rig, a, &tied, progress, &mut cancel).await? {
        ControlFlow::Continue(m) => m,
        ControlFlow::Break(state) => return Ok((state, Value::Null)),
    };
    let (result, n_records) = finish(rig, a, &tied, m, began).await?;
    if let Some(p) = lock(progress).as_mut() {
        p.done = n_records;
        p.total = n_records;
    }
    Ok((JobState::Done, result))
}

/// Everything a sweep measured, in the order measured.
struct Measured {
    /// Rig time the passes began at (after the tie), s: the logs' t = 0.
    origin: f64,
    passes: Vec<PassData>,
    /// Drift references and anchors, each with the index of the pass it
    /// precedes (`passes.len()`: after the last).
    between: Vec<(usize, Between)>,
    anchors: Vec<AnchorMeas>,
    /// Time spent measuring anchors, s.
    anchor_s: f64,
    /// Which axes' controllers recorded positions themselves.
    recorder: [bool; 2],
    recorded: RecorderStats,
}

/// The passes, with drift references when due and each cycle's anchors
/// after its two passes of an axis; `Break` with the state when cancelled
/// or stopped.
async fn measure(
    rig: &Arc<Rig>,
    a: &SweepArgs,
    tied: &tie::Tie,
    progress: &Arc<Mutex<Option<Progress>>>,
    cancel: &mut watch::Receiver<bool>,
) -> Result<ControlFlow<JobState, Measured>, ProtoError> {
    let plan = &a.plan;
    let origin = rig.clock.now_s();
    let gen = rig.stop_generation();
    let stage = rig.stage()?;
    let velocities = [
        stage.x.velocity_um_per_s().await.map_err(driver_error)?,
        stage.y.velocity_um_per_s().await.map_err(driver_error)?,
    ];
    let mut m = Measured {
        origin,
        passes: Vec::new(),
        between: Vec::new(),
        anchors: Vec::new(),
        anchor_s: 0.0,
        recorder: [
            plan.scan_x && has_recorder(&stage.x).await?,
            plan.scan_y && has_recorder(&stage.y).await?,
        ],
        recorded: RecorderStats::default(),
    };
    let specs = plan.passes();
    m.passes.reserve(specs.len());
    let mut last_ref_s: Option<f64> = None;
    let mut moved_away = false;
    let total = plan.records_total();
    for (k, spec) in specs.iter().enumerate() {
        if *cancel.borrow_and_update() {
            return Ok(ControlFlow::Break(JobState::Cancelled));
        }
        if rig.stop_generation() != gen {
            return Ok(ControlFlow::Break(JobState::Stopped));
        }
        // The anchors or a reference detour left the axis elsewhere.
        let mut park = k == 0 || specs[k - 1].x_axis != spec.x_axis || moved_away;
        if let Some(d) = &a.drift {
            if last_ref_s.is_none_or(|t| rig.clock.now_s() - t >= d.every_s) {
                let rec = tokio::select! {
                    r = drift_reference(rig, d, a, tied, origin, spec.cycle) => r?,
                    _ = cancel.changed() => return Ok(ControlFlow::Break(JobState::Cancelled)),
                };
                m.between.push((k, Between::Ref(rec)));
                last_ref_s = Some(rig.clock.now_s());
                // The detour left both axes at the reference.
                park = true;
            }
        }
        let use_recorder = m.recorder[usize::from(!spec.x_axis)];
        let r = tokio::select! {
            r = one_pass(rig, spec, park, tied, use_recorder, &mut m.recorded) => r?,
            _ = cancel.changed() => {
                // The pass was dropped mid-sweep: its velocity is still set.
                restore_velocities(rig, velocities).await;
                return Ok(ControlFlow::Break(JobState::Cancelled));
            }
        };
        m.passes.push(r);
        moved_away = false;
        // The cycle's two passes of this axis are done: its anchors.
        if !spec.forward && plan.anchor_every().is_some() {
            let t0 = rig.clock.now_s();
            for forward in [true, false] {
                let group = AnchorGroup {
                    x_axis: spec.x_axis,
                    forward,
                    cycle: spec.cycle,
                    hold_um: spec.hold_um,
                };
                let rows = tokio::select! {
                    r = anchor_group(rig, plan, &group, a, tied, gen) => r?,
                    _ = cancel.changed() => return Ok(ControlFlow::Break(JobState::Cancelled)),
                };
                let Some(rows) = rows else {
                    return Ok(ControlFlow::Break(JobState::Stopped));
                };
                for row in rows {
                    m.anchors.push(row.m);
                    m.between.push((k + 1, Between::Anchor(row)));
                }
            }
            m.anchor_s += rig.clock.now_s() - t0;
            moved_away = true;
        }
        let done = total * (k + 1) / specs.len();
        let elapsed = rig.clock.now_s() - origin;
        let eta = elapsed / (k + 1) as f64 * (specs.len() - k - 1) as f64;
        let snapshot = lock(progress).as_mut().map(|p| {
            p.done = done;
            p.eta_s = Some(eta);
            p.to_json()
        });
        if let Some(s) = snapshot {
            rig.push(Topic::Job, "job", s);
        }
    }
    Ok(ControlFlow::Continue(m))
}

/// From what was measured: the camera delay, the anchor correction, the
/// log (and its companions, which differ in the corrections applied only)
/// and the job's result with the number of records the log holds.
async fn finish(
    rig: &Arc<Rig>,
    a: &SweepArgs,
    tied: &tie::Tie,
    m: Measured,
    began: f64,
) -> Result<(Value, usize), ProtoError> {
    let plan = &a.plan;
    let est = estimate_delay(&m.passes).map_err(|e| {
        ProtoError::new(
            ErrorCode::LowQuality,
            format!("sweep characterization: {e}"),
        )
    })?;
    let corr = anchor_correction(&m.passes, &m.anchors, est.delay_s, plan.step_um);
    let duration_s = rig.clock.now_s() - began;
    let frames: usize = m.passes.iter().map(|p| p.frames.len()).sum();
    let samples: usize = m.passes.iter().map(|p| p.samples.len()).sum();
    let md = sweep_metadata(a, tied, &m, &est, &corr, [frames, samples], duration_s);
    let anchored = plan.anchor_every().is_some();
    let built = |delay_s: f64, apply: bool| {
        let ctx = RecordContext {
            plan,
            delay_s,
            origin: m.origin,
            corr: &corr,
            apply,
        };
        records(&m.passes, &m.between, &ctx)
    };
    let records = built(est.delay_s, anchored);
    let n_between = m.between.len();
    let n_refs = m
        .between
        .iter()
        .filter(|(_, b)| matches!(b, Between::Ref(_)))
        .count();
    let n_records = records.len() - n_between;
    // The log and its companions differ in the corrections applied only.
    let variant = |delay_s: f64, apply: bool| {
        let mut v = md.clone();
        v.insert("camera_delay_applied_s", format!("{delay_s:.7}"));
        v.insert(
            "sweep_anchor_correction_applied",
            (apply && anchored).to_string(),
        );
        v
    };
    write_log(rig, &a.name, variant(est.delay_s, true), records).await?;
    if let Some(u) = &a.uncorrected {
        write_log(rig, u, variant(0.0, true), built(0.0, anchored)).await?;
    }
    if let Some(u) = &a.unanchored {
        write_log(
            rig,
            u,
            variant(est.delay_s, false),
            built(est.delay_s, false),
        )
        .await?;
    }
    let mut result = result_json(&est, frames, samples, n_records, duration_s);
    result["drift_references"] = json!(n_refs);
    result["anchors"] = anchor_json(plan, &corr, m.anchors.len(), m.anchor_s);
    let source = |used: bool| if used { "data_recorder" } else { "pos_polling" };
    result["position_source"] = json!({
        "x": source(m.recorder[0]),
        "y": source(m.recorder[1]),
    });
    result["recorder_records"] = json!(m.recorded.records);
    Ok((result, n_records))
}

/// What the data recorder delivered over the sweep.
#[derive(Debug, Default)]
struct RecorderStats {
    /// Records read.
    records: usize,
    /// Their sample time, s (the last chunk's).
    sample_time_s: f64,
}

/// Whether `axis`'s controller has a data recorder the sweep can use:
/// `TNR?` answers with at least [`RECORD_TABLE`] tables and `DRC`/`RTR`
/// are accepted. A controller that refuses either is polled instead; a
/// link fault is an error.
async fn has_recorder(axis: &Axis) -> Result<bool, ProtoError> {
    match axis.recorder_tables().await {
        Ok(Some(n)) if n >= RECORD_TABLE => {}
        Ok(_) => return Ok(false),
        Err(e) if e.gcs_code().is_some() => return Ok(false),
        Err(e) => return Err(driver_error(e)),
    }
    match axis.record_actual_position(RECORD_TABLE, RECORD_RATE).await {
        Ok(()) => Ok(true),
        Err(e) if e.gcs_code().is_some() => {
            tracing::info!(
                "sweep: {} refuses the data recorder set-up ({e}); polling POS?",
                axis.name()
            );
            Ok(false)
        }
        Err(e) => Err(driver_error(e)),
    }
}

/// Sets both axes back to the velocities the job found (after a pass that
/// was cancelled before it could); a failure is logged, not returned (the
/// job ends either way).
async fn restore_velocities(rig: &Rig, velocities: [f64; 2]) {
    let Ok(stage) = rig.stage() else { return };
    for (axis, v) in [(&stage.x, velocities[0]), (&stage.y, velocities[1])] {
        if let Err(e) = axis.set_velocity_um_per_s(v).await {
            tracing::warn!("sweep: cannot restore the velocity of {}: {e}", axis.name());
        }
    }
}

/// What the job measured between passes, in the log's order.
enum Between {
    /// A drift reference re-measurement (its record as logged).
    Ref(Record),
    /// An anchor.
    Anchor(AnchorRow),
}

/// One anchor as the log holds it.
struct AnchorRow {
    /// The measurement.
    m: AnchorMeas,
    /// The controllers' reported positions after the final move, µm.
    reported: [Option<f64>; 2],
    /// Frames averaged.
    frames: u32,
    /// Decoded θ relative to the tie's, µrad (the log's `theta_urad`).
    theta_urad: Option<f64>,
}

/// The anchors of one axis, direction and cycle.
struct AnchorGroup {
    x_axis: bool,
    forward: bool,
    cycle: u32,
    /// Where the held axis stands (the passes' hold), µm.
    hold_um: f64,
}

/// Runs one group's route (`charact::sweep::anchor::anchor_route`): every stop a raw
/// move of the swept axis (the held one stays), at each anchor the step
/// job's settle and frames. `Ok(None)` if a stop or fault moved the stop
/// generation past `gen`.
async fn anchor_group(
    rig: &Arc<Rig>,
    plan: &SweepPlan,
    g: &AnchorGroup,
    a: &SweepArgs,
    tied: &tie::Tie,
    gen: u64,
) -> Result<Option<Vec<AnchorRow>>, ProtoError> {
    let mut rows = Vec::new();
    for stop in anchor_route(plan, g.x_axis, g.forward) {
        if rig.stop_generation() != gen {
            return Ok(None);
        }
        let (x, y) = if g.x_axis {
            clamp_to_travel(rig, stop.pos_um, g.hold_um)
        } else {
            clamp_to_travel(rig, g.hold_um, stop.pos_um)
        };
        let moved = move_raw_retrying(rig, x, y).await?;
        if !stop.measure {
            continue;
        }
        rig.clock
            .sleep(Duration::try_from_secs_f64(a.settle_s).unwrap_or_default())
            .await;
        let (m, quality) = measure_retrying(rig, a.frames_per_point).await?;
        let meas = tied.frame.to_stage(XyUm {
            x_um: m.x_um,
            y_um: m.y_um,
        });
        rows.push(AnchorRow {
            theta_urad: super::record::theta_urad(m.theta_rad, Some(tied.theta_rad)),
            m: AnchorMeas {
                x_axis: g.x_axis,
                forward: g.forward,
                cycle: g.cycle,
                pos_um: if g.x_axis { x } else { y },
                hold_um: if g.x_axis { y } else { x },
                meas,
                t_s: m.frame_t_s,
                quality,
            },
            reported: [
                moved.reported.and_then(|r| r.x_um),
                moved.reported.and_then(|r| r.y_um),
            ],
            frames: a.frames_per_point,
        });
    }
    Ok(Some(rows))
}

/// Measures the drift reference as the step job does (approached forward
/// on both axes from [`PARK_APPROACH_UM`] below, settled, `frames_per_point`
/// frames) and returns its record (segment `drift_ref`, cycle of the next
/// pass, time relative to `origin`; no velocity, one record of its own).
async fn drift_reference(
    rig: &Arc<Rig>,
    d: &DriftPlan,
    a: &SweepArgs,
    tied: &tie::Tie,
    origin: f64,
    cycle: u32,
) -> Result<Record, ProtoError> {
    let [rx, ry] = d.reference_um;
    let (ax, ay) = clamp_to_travel(rig, rx - PARK_APPROACH_UM, ry - PARK_APPROACH_UM);
    move_raw_retrying(rig, ax, ay).await?;
    let moved = move_raw_retrying(rig, rx, ry).await?;
    rig.clock
        .sleep(Duration::try_from_secs_f64(a.settle_s).unwrap_or_default())
        .await;
    let (m, quality) = measure_retrying(rig, a.frames_per_point).await?;
    let meas = tied.frame.to_stage(XyUm {
        x_um: m.x_um,
        y_um: m.y_um,
    });
    let mut rec = drift_ref_record(
        d.reference_um,
        &moved,
        meas,
        super::record::theta_urad(m.theta_rad, Some(tied.theta_rad)),
        quality,
        cycle,
        rig.clock.now_s() - origin,
    );
    rec.extra.extend([
        "0".to_owned(),
        format!("{:.6}", m.frame_t_s - origin),
        a.frames_per_point.to_string(),
        String::new(),
        String::new(),
    ]);
    Ok(rec)
}

/// Creates `name` in the data directory and writes the records (one sync
/// at the end: the data exist in memory until the sweep ends anyway).
async fn write_log(
    rig: &Rig,
    name: &str,
    md: Metadata,
    records: Vec<Record>,
) -> Result<(), ProtoError> {
    let path = rig.cfg.daemon.data_dir.join(name);
    let n = name.to_owned();
    tokio::task::spawn_blocking(move || {
        let mut w = log::create_file(&path, &md, columns(), SyncPolicy::FlushOnly)?;
        for r in &records {
            w.append(r)?;
        }
        w.sync()
    })
    .await
    .map_err(|e| ProtoError::new(ErrorCode::Internal, e.to_string()))?
    .map_err(|e| ProtoError::new(ErrorCode::LogError, format!("cannot write {n}: {e}")))
}

/// One pass: park first if it is the axis's first or follows a drift
/// reference (held axis by a forward approach, swept axis at the run-up
/// before the range), then sweep.
async fn one_pass(
    rig: &Arc<Rig>,
    spec: &PassSpec,
    park: bool,
    tied: &tie::Tie,
    recorder: bool,
    recorded: &mut RecorderStats,
) -> Result<PassData, ProtoError> {
    let (from, to) = spec.ends_um();
    // (x, y) of a swept and a held position, clamped into the travel.
    let place = |scan: f64, held: f64| {
        if spec.x_axis {
            clamp_to_travel(rig, scan, held)
        } else {
            clamp_to_travel(rig, held, scan)
        }
    };
    if park {
        let (x, y) = place(from, spec.hold_um - PARK_APPROACH_UM);
        move_raw_retrying(rig, x, y).await?;
        let (x, y) = place(from, spec.hold_um);
        move_raw_retrying(rig, x, y).await?;
    }
    let target = match place(to, spec.hold_um) {
        (x, _) if spec.x_axis => x,
        (_, y) => y,
    };
    let stage = rig.stage()?;
    let axis = if spec.x_axis { &stage.x } else { &stage.y };
    let before = axis.velocity_um_per_s().await.map_err(driver_error)?;
    axis.set_velocity_um_per_s(spec.velocity_um_per_s)
        .await
        .map_err(driver_error)?;
    let swept = sweep(rig, axis, spec, target, tied, recorder, recorded).await;
    let restored = axis
        .set_velocity_um_per_s(before)
        .await
        .map_err(driver_error);
    let data = swept?;
    restored?;
    Ok(data)
}

/// Sends the move to `target_um` and samples positions and frames until
/// the axis is there; positions from the data recorder when `recorder`
/// (`jobs::sweep_recorder`), else from `POS?` alone. The frames are
/// collected ([`collect_frames`]) while the positions are sampled
/// ([`PassIo::sample`]); the pass ends when the axis is on target.
async fn sweep(
    rig: &Arc<Rig>,
    axis: &Axis,
    spec: &PassSpec,
    target_um: f64,
    tied: &tie::Tie,
    recorder: bool,
    recorded: &mut RecorderStats,
) -> Result<PassData, ProtoError> {
    let Some(vision) = &rig.vision else {
        return Err(ProtoError::new(ErrorCode::CameraUnavailable, "no camera"));
    };
    let min_quality = rig.cfg.camera.min_quality;
    // The reference check of the samples' connection epoch (see
    // `Axis::position_sample_um`).
    let start_um = axis.position_um().await.map_err(driver_error)?;
    let epoch = axis.epoch();
    let _want = vision.want_stream();
    let mut rx = vision.latest.clone();
    rx.borrow_and_update();
    let mut req = MoveRequest::raw_to(target_um, target_um);
    if spec.x_axis {
        req.y_um = None;
    } else {
        req.x_um = None;
    }
    req.wait = false;
    let gen = rig.stop_generation();
    let frames: Mutex<Vec<SweepFrame>> = Mutex::new(Vec::new());
    let collect = collect_frames(&mut rx, tied, min_quality, &frames);
    let deadline_s =
        rig.clock.now_s() + (target_um - start_um).abs() / spec.velocity_um_per_s + 10.0;
    let io = PassIo {
        rig,
        axis,
        epoch,
        recorder,
    };
    let sample = io.sample(&req, target_um, gen, deadline_s);
    let (polls, chunks) = tokio::select! {
        r = sample => r?,
        () = collect => {
            return Err(ProtoError::new(ErrorCode::CameraUnavailable, "the camera pipeline ended"));
        }
    };
    axis.wait_on_target(None).await.map_err(driver_error)?;
    axis.position_um().await.map_err(driver_error)?;
    if axis.epoch() != epoch {
        return Err(reconnected());
    }
    let frames = frames.into_inner().unwrap_or_else(|p| p.into_inner());
    let samples = if recorder {
        for c in &chunks {
            recorded.records += c.positions_um.len();
            recorded.sample_time_s = c.sample_time_s;
        }
        merge(&chunks, &polls)
    } else {
        polls
    };
    Ok(PassData {
        spec: *spec,
        samples,
        frames,
    })
}

/// The refusal of a pass whose line reconnected: its positions may come
/// from two connections (transient: the pass can be run again).
fn reconnected() -> ProtoError {
    ProtoError::new(
        ErrorCode::NotConnected,
        "the line reconnected during a sweep; its positions are not trusted",
    )
    .into_transient()
}

/// Every new, good enough measurement `rx` publishes, as a frame of the
/// pass in stage coordinates, into `frames`; returns only when the camera
/// pipeline ends.
async fn collect_frames(
    rx: &mut watch::Receiver<Option<Measurement>>,
    tied: &tie::Tie,
    min_quality: f64,
    frames: &Mutex<Vec<SweepFrame>>,
) {
    let mut last = None;
    while rx.changed().await.is_ok() {
        let m = *rx.borrow_and_update();
        let Some(m) = m else { continue };
        if Some(m.sequence) == last || m.quality < min_quality {
            continue;
        }
        last = Some(m.sequence);
        lock(frames).push(SweepFrame {
            t_s: m.frame_t_s,
            meas: tied.frame.to_stage(XyUm {
                x_um: m.x_um,
                y_um: m.y_um,
            }),
            theta_urad: crate::daemon::vision::wrap_angle_rad(m.theta_rad - tied.theta_rad) * 1e6,
            quality: m.quality,
        });
    }
}

/// The position sampling of one pass: the swept axis on its connection
/// `epoch`, and whether the data recorder supplies the positions.
struct PassIo<'a> {
    rig: &'a Arc<Rig>,
    axis: &'a Axis,
    /// The connection the pass started on: samples of another are refused.
    epoch: u64,
    recorder: bool,
}

impl PassIo<'_> {
    /// Starts the table now; the exchange's rig-time bracket.
    async fn trigger(&self) -> Result<(f64, f64), ProtoError> {
        let a = self.rig.clock.now_s();
        let e = self
            .axis
            .trigger_recorder(RECORD_TABLE)
            .await
            .map_err(driver_error)?;
        if e != self.epoch {
            return Err(reconnected());
        }
        Ok((a, self.rig.clock.now_s()))
    }

    /// Reads what the table holds since `trigger_s`.
    async fn read_chunk(&self, trigger_s: (f64, f64)) -> Result<Chunk, ProtoError> {
        let (n, e) = self
            .axis
            .recorded_points(RECORD_TABLE)
            .await
            .map_err(driver_error)?;
        if e != self.epoch {
            return Err(reconnected());
        }
        let r = self
            .axis
            .read_records(RECORD_TABLE, 1, n)
            .await
            .map_err(driver_error)?;
        if r.epoch != self.epoch {
            return Err(reconnected());
        }
        Ok(Chunk {
            trigger_s,
            sample_time_s: r.sample_time_s,
            positions_um: r.positions_um,
        })
    }

    /// Sends the move `req` and samples `POS?` (and, with the recorder,
    /// reads the table every [`CHUNK_S`]) until the axis is at `target_um`;
    /// a stop (the stop generation moved from `gen`) or `deadline_s` ends
    /// it with an error. Returns the polled samples and the recorder's
    /// chunks.
    async fn sample(
        &self,
        req: &MoveRequest,
        target_um: f64,
        gen: u64,
        deadline_s: f64,
    ) -> Result<(Vec<PosSample>, Vec<Chunk>), ProtoError> {
        let (rig, axis) = (self.rig, self.axis);
        let mut chunks: Vec<Chunk> = Vec::new();
        let mut armed = if self.recorder {
            Some(self.trigger().await?)
        } else {
            None
        };
        rig.raw_move(req, true, true).await?;
        let mut samples: Vec<PosSample> = Vec::new();
        loop {
            let t0 = rig.clock.now_s();
            let (pos_um, e) = axis.position_sample_um().await.map_err(driver_error)?;
            let t1 = rig.clock.now_s();
            if e != self.epoch {
                return Err(reconnected());
            }
            samples.push(PosSample {
                t_s: (t0 + t1) / 2.0,
                pos_um,
            });
            let arrived = (pos_um - target_um).abs() < 0.01;
            if let Some(trig) = armed {
                if arrived || rig.clock.now_s() - trig.0 >= CHUNK_S {
                    chunks.push(self.read_chunk(trig).await?);
                    armed = if arrived {
                        None
                    } else {
                        Some(self.trigger().await?)
                    };
                }
            }
            if arrived {
                break;
            }
            if rig.stop_generation() != gen {
                return Err(ProtoError::new(
                    ErrorCode::Halted,
                    "a stop or fault halted the sweep",
                ));
            }
            if t1 > deadline_s {
                return Err(ProtoError::new(
                    ErrorCode::DriverError,
                    format!("the sweep to {target_um} µm did not arrive in time"),
                ));
            }
            rig.clock
                .sleep(if self.recorder {
                    POLL_WITH_RECORDER
                } else {
                    POS_SAMPLE_PERIOD
                })
                .await;
        }
        Ok((samples, chunks))
    }
}
