//! The rig's counters and gauges for `GET /metrics` (OpenMetrics text,
//! Prometheus scrapes it), so a lab with many rigs points its existing
//! Prometheus/Grafana at them instead of micropos growing a fleet manager.
//! Names, types and units: `docs/design/web.md`.
//!
//! Two kinds of sources: event counters that the rig bumps where the event
//! happens (moves and their error codes, latched faults, reconnects) and
//! values that already live elsewhere (the vision pipeline's counters, the
//! latest decode, drift, the job's progress), copied into the registry at
//! scrape time (`Metrics::render`, in `web::metrics`) so nothing is counted
//! twice. Here, outside `web/`, because the rig owns the counters and must
//! not depend on the optional web front door that serves them.

use crate::daemon::protocol::ErrorCode;
use crate::daemon::vision::VisionStats;
use prometheus_client::encoding::EncodeLabelSet;
use prometheus_client::metrics::counter::Counter;
use prometheus_client::metrics::family::Family;
use prometheus_client::metrics::gauge::Gauge;
use prometheus_client::registry::Registry;
use std::collections::HashSet;
use std::sync::atomic::AtomicU64;
use std::sync::Mutex;

/// Label of a move error.
#[derive(Debug, Clone, Hash, PartialEq, Eq, EncodeLabelSet)]
struct CodeLabel {
    code: &'static str,
}

/// Label of a per-axis gauge.
#[derive(Debug, Clone, Hash, PartialEq, Eq, EncodeLabelSet)]
pub(crate) struct AxisLabel {
    pub(crate) axis: &'static str,
}

/// Labels of a position gauge.
#[derive(Debug, Clone, Hash, PartialEq, Eq, EncodeLabelSet)]
pub(crate) struct PositionLabel {
    pub(crate) source: &'static str,
    pub(crate) axis: &'static str,
}

pub(crate) type FloatGauge = Gauge<f64, AtomicU64>;

/// The daemon's metrics: a registry and handles to what is in it.
#[derive(Debug)]
pub struct Metrics {
    pub(crate) registry: Registry,
    moves: Counter,
    move_errors: Family<CodeLabel, Counter>,
    faults: Counter,
    reconnects: Counter,
    lines_seen: Mutex<HashSet<String>>,
    pub(crate) frames: Counter,
    pub(crate) frames_decoded: Counter,
    pub(crate) decode_failures: Counter,
    pub(crate) decode_rate_hz: FloatGauge,
    /// `(rig time s, decoded count)` of the last rate sample.
    pub(crate) rate_sample: Mutex<Option<(f64, u64)>>,
    pub(crate) decode_quality_bits: FloatGauge,
    pub(crate) residual_um: Family<AxisLabel, FloatGauge>,
    pub(crate) drift_um: Family<AxisLabel, FloatGauge>,
    pub(crate) position_um: Family<PositionLabel, FloatGauge>,
    pub(crate) job_running: Gauge,
    pub(crate) job_points_done: Gauge,
    pub(crate) job_points_total: Gauge,
    pub(crate) job_progress_ratio: FloatGauge,
    pub(crate) job_eta_seconds: FloatGauge,
    pub(crate) faulted: Gauge,
}

/// The shortest rig time between two samples of the decode rate, s: a
/// rate over a shorter window is mostly the jitter of frame arrivals.
pub(crate) const RATE_WINDOW_S: f64 = 1.0;

impl Metrics {
    /// Registers every metric; `vision` (the pipeline's counters, if a
    /// camera is configured) contributes its decode-time histogram.
    pub fn new(vision: Option<&VisionStats>) -> Metrics {
        let mut r = Registry::default();
        let m = Metrics {
            moves: Counter::default(),
            move_errors: Family::default(),
            faults: Counter::default(),
            reconnects: Counter::default(),
            lines_seen: Mutex::new(HashSet::new()),
            frames: Counter::default(),
            frames_decoded: Counter::default(),
            decode_failures: Counter::default(),
            decode_rate_hz: FloatGauge::default(),
            rate_sample: Mutex::new(None),
            decode_quality_bits: FloatGauge::default(),
            residual_um: Family::default(),
            drift_um: Family::default(),
            position_um: Family::default(),
            job_running: Gauge::default(),
            job_points_done: Gauge::default(),
            job_points_total: Gauge::default(),
            job_progress_ratio: FloatGauge::default(),
            job_eta_seconds: FloatGauge::default(),
            faulted: Gauge::default(),
            registry: Registry::default(),
        };
        // Counters are registered without `_total`: the encoder adds it.
        r.register(
            "micropos_moves",
            "Moves that reached their target (client and job moves)",
            m.moves.clone(),
        );
        r.register(
            "micropos_move_errors",
            "Moves that failed, by protocol error code",
            m.move_errors.clone(),
        );
        r.register(
            "micropos_faults",
            "Faults that halted both axes and latched",
            m.faults.clone(),
        );
        r.register(
            "micropos_reconnects",
            "Controller lines that came back after a loss",
            m.reconnects.clone(),
        );
        r.register(
            "micropos_vision_frames",
            "Camera frames received",
            m.frames.clone(),
        );
        r.register(
            "micropos_vision_frames_decoded",
            "Camera frames decoded",
            m.frames_decoded.clone(),
        );
        r.register(
            "micropos_vision_decode_failures",
            "Camera frames that did not decode",
            m.decode_failures.clone(),
        );
        r.register(
            "micropos_vision_decode_rate_hz",
            "Frames decoded per second of rig time (over at least 1 s)",
            m.decode_rate_hz.clone(),
        );
        r.register(
            "micropos_vision_decode_quality_bits",
            "Quality of the newest decode (smaller code margin, bits)",
            m.decode_quality_bits.clone(),
        );
        if let Some(v) = vision {
            r.register(
                "micropos_vision_decode_seconds",
                "Wall time of one decode",
                v.decode_seconds.clone(),
            );
        }
        r.register(
            "micropos_vision_residual_um",
            "Vision (in the stage frame: the rig's tie, else the active table's frame) minus controller position",
            m.residual_um.clone(),
        );
        r.register(
            "micropos_drift_correction_um",
            "Live drift correction applied to compensated moves",
            m.drift_um.clone(),
        );
        r.register(
            "micropos_position_um",
            "Position by source (commanded, controller, vision through the rig's tie or the active table's frame; absent untied)",
            m.position_um.clone(),
        );
        r.register(
            "micropos_fault_latched",
            "1 while a fault is latched (cleared by reset)",
            m.faulted.clone(),
        );
        r.register(
            "micropos_job_running",
            "1 while a job runs",
            m.job_running.clone(),
        );
        r.register(
            "micropos_job_points_done",
            "Points done by the current or last job",
            m.job_points_done.clone(),
        );
        r.register(
            "micropos_job_points",
            "Points planned for the current or last job",
            m.job_points_total.clone(),
        );
        r.register(
            "micropos_job_progress_ratio",
            "Done over planned points of the current or last job (0..1)",
            m.job_progress_ratio.clone(),
        );
        r.register(
            "micropos_job_eta_seconds",
            "Estimated rig time until the running job ends",
            m.job_eta_seconds.clone(),
        );
        Metrics { registry: r, ..m }
    }

    /// A move ended: `Ok` or its error code.
    pub fn record_move(&self, r: Result<(), ErrorCode>) {
        match r {
            Ok(()) => {
                self.moves.inc();
            }
            Err(code) => {
                self.move_errors
                    .get_or_create(&CodeLabel {
                        code: code.as_str(),
                    })
                    .inc();
            }
        }
    }

    /// A fault halted both axes and latched.
    pub fn record_fault(&self) {
        self.faults.inc();
    }

    /// A controller line connected; a line seen before counts as a
    /// reconnect.
    pub fn record_link_up(&self, line: &str) {
        let again = match self.lines_seen.lock() {
            Ok(mut seen) => !seen.insert(line.to_owned()),
            Err(_) => true,
        };
        if again {
            self.reconnects.inc();
        }
    }
}
