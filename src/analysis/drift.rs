//! Drift correction from re-measurements of a reference point.
//!
//! Why: over a run of hours the room temperature wanders and the platform
//! and the microscope drift by a micrometre or more, more than the stage's
//! repeatability. Re-measuring one reference point at intervals measures
//! that drift directly; subtracting the drift predicted at each point's
//! time corrects the log. The same group reported ≈ 100 nm residual with
//! an adaptive drift model against ≈ 400 nm with a static one.
//!
//! Two estimators, both causal (a prediction at `t` uses only
//! re-measurements taken at or before `t`, as a daemon correcting on line
//! must):
//! * [`DriftMethod::Static`]: a line `a + b·t` fitted once on the
//!   re-measurements of an initial calibration period, then extrapolated.
//! * [`DriftMethod::Adaptive`]: local linear regression with exponential
//!   forgetting (time constant τ) over all re-measurements so far, i.e. the
//!   steady state of a constant-velocity Kalman filter; it follows the
//!   drift as the room changes its mind.
//!
//! Drift here is `measured − nominal` of the reference point, µm, per axis;
//! correcting a measurement subtracts it.
//!
//! Sans-IO: the daemon integration (scheduling re-measurements) is separate.

use serde::{Deserialize, Serialize};

use super::AnalysisError;
use crate::charact::log::Record;

/// One re-measurement of the reference point.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ReferenceSample {
    /// Time, s (same origin as the log).
    pub t_s: f64,
    /// Measured − nominal position of the reference, `[x, y]` µm.
    pub drift_um: [f64; 2],
}

/// How drift is predicted.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum DriftMethod {
    /// Line fitted on the re-measurements of the first `calibration_s`
    /// seconds, extrapolated afterwards.
    Static {
        /// Length of the calibration period, s (> 0).
        calibration_s: f64,
    },
    /// Local linear fit with exponential forgetting.
    Adaptive {
        /// Forgetting time constant τ, s (> 0): re-measurements older than
        /// a few τ no longer count.
        time_constant_s: f64,
    },
}

/// Collects re-measurements and predicts drift; see the module docs.
#[derive(Debug, Clone, PartialEq)]
pub struct DriftEstimator {
    method: DriftMethod,
    samples: Vec<ReferenceSample>,
}

impl DriftEstimator {
    /// A new estimator; rejects non-positive or non-finite periods.
    pub fn new(method: DriftMethod) -> Result<Self, AnalysisError> {
        let v = match method {
            DriftMethod::Static { calibration_s } => calibration_s,
            DriftMethod::Adaptive { time_constant_s } => time_constant_s,
        };
        if !(v.is_finite() && v > 0.0) {
            return Err(AnalysisError::Invalid(format!(
                "drift method {method:?}: the period must be a finite number > 0"
            )));
        }
        Ok(DriftEstimator {
            method,
            samples: Vec::new(),
        })
    }

    /// Adds a re-measurement. Times must be finite and not go backwards;
    /// values finite.
    pub fn push(&mut self, s: ReferenceSample) -> Result<(), AnalysisError> {
        if !(s.t_s.is_finite() && s.drift_um.iter().all(|v| v.is_finite())) {
            return Err(AnalysisError::Invalid(
                "reference re-measurement: time and drift must be finite".into(),
            ));
        }
        if let Some(last) = self.samples.last() {
            if s.t_s < last.t_s {
                return Err(AnalysisError::Invalid(format!(
                    "reference re-measurement at {} s is earlier than the previous one ({} s)",
                    s.t_s, last.t_s
                )));
            }
        }
        self.samples.push(s);
        Ok(())
    }

    /// The re-measurements so far.
    pub fn samples(&self) -> &[ReferenceSample] {
        &self.samples
    }

    /// Predicted drift at `t_s`, `[x, y]` µm, from re-measurements taken at
    /// or before `t_s`; `None` before the first one.
    pub fn predict(&self, t_s: f64) -> Option<[f64; 2]> {
        let upto = self.samples.partition_point(|s| s.t_s <= t_s);
        let used = &self.samples[..upto];
        let first = used.first()?;
        let (used, weight): (&[ReferenceSample], Box<dyn Fn(f64) -> f64>) = match self.method {
            DriftMethod::Static { calibration_s } => {
                let end = used.partition_point(|s| s.t_s <= first.t_s + calibration_s);
                (&used[..end], Box::new(|_| 1.0))
            }
            DriftMethod::Adaptive { time_constant_s } => (
                used,
                Box::new(move |t: f64| (-(t_s - t) / time_constant_s).exp()),
            ),
        };
        let mut out = [0.0; 2];
        // Weighted line fit around the weighted mean time (well conditioned).
        let sw: f64 = used.iter().map(|s| weight(s.t_s)).sum();
        if sw <= 0.0 {
            return Some(used.last()?.drift_um);
        }
        let tm = used.iter().map(|s| weight(s.t_s) * s.t_s).sum::<f64>() / sw;
        let stt: f64 = used
            .iter()
            .map(|s| weight(s.t_s) * (s.t_s - tm).powi(2))
            .sum();
        for (c, o) in out.iter_mut().enumerate() {
            let ym = used
                .iter()
                .map(|s| weight(s.t_s) * s.drift_um[c])
                .sum::<f64>()
                / sw;
            let sty: f64 = used
                .iter()
                .map(|s| weight(s.t_s) * (s.t_s - tm) * (s.drift_um[c] - ym))
                .sum();
            // With one point (or all at one time) the slope is unknown: hold.
            let slope = if stt > 1e-9 * sw { sty / stt } else { 0.0 };
            *o = ym + slope * (t_s - tm);
        }
        Some(out)
    }

    /// Subtracts the predicted drift from the measured positions of
    /// `records` (those before the first re-measurement are left alone);
    /// returns how many were corrected.
    pub fn correct(&self, records: &mut [Record]) -> usize {
        let mut n = 0;
        for r in records {
            if let Some(d) = self.predict(r.t_s) {
                r.x_meas_um -= d[0];
                r.y_meas_um -= d[1];
                n += 1;
            }
        }
        n
    }
}

/// Segment name of the reference re-measurements a characterization logs
/// when `drift_every_s` is set (same columns as every record; target =
/// the reference point).
pub const DRIFT_REF_SEGMENT: &str = "drift_ref";

/// The method `tables build` uses on logs with reference re-measurements:
/// adaptive, τ = 20 min (the best of the static/adaptive comparison in
/// `tests/it/diagnose_drift.rs` on the default thermal drift).
pub const LOG_DRIFT_METHOD: DriftMethod = DriftMethod::Adaptive {
    time_constant_s: 1200.0,
};

/// Default forgetting time constant of live (working-session) adaptive
/// correction, s: the same 20 min as [`LOG_DRIFT_METHOD`].
pub const LIVE_TIME_CONSTANT_S: f64 = 1200.0;

/// What [`correct_log_drift`] did.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LogDriftCorrection {
    /// Reference re-measurements used.
    pub references: usize,
    /// Measurements corrected (those logged before the first reference
    /// are left alone).
    pub corrected: usize,
    /// Largest |drift| seen at the reference, `[x, y]` µm, relative to the
    /// first re-measurement.
    pub max_drift_um: [f64; 2],
    /// The state the corrected log (and every table built from it) refers
    /// to: the first re-measurement. A daemon correcting drift on line
    /// measures its drift against this.
    pub baseline: DriftBaseline,
}

/// Removes the [`DRIFT_REF_SEGMENT`] records from `records` and subtracts
/// the drift they measure from every other record's measured position.
///
/// Drift at a re-measurement is its `measured − target` minus that of the
/// first re-measurement: the reference's own static stage error cancels,
/// so the log is corrected to the state of the rig at the first
/// re-measurement (the start of the run). Causal: each record uses only
/// the re-measurements logged at or before it. Returns the records
/// unchanged and `None` when the log has no reference records.
pub fn correct_log_drift(
    records: &[Record],
    method: DriftMethod,
) -> Result<(Vec<Record>, Option<LogDriftCorrection>), AnalysisError> {
    let (refs, rest): (Vec<&Record>, Vec<&Record>) =
        records.iter().partition(|r| r.segment == DRIFT_REF_SEGMENT);
    let Some(first) = refs.first() else {
        return Ok((records.to_vec(), None));
    };
    let e0 = [first.error_x_um(), first.error_y_um()];
    let mut est = DriftEstimator::new(method)?;
    let mut max_drift_um = [0.0f64; 2];
    for r in &refs {
        // Error is target − measured, drift is measured − nominal.
        let d = [e0[0] - r.error_x_um(), e0[1] - r.error_y_um()];
        max_drift_um[0] = max_drift_um[0].max(d[0].abs());
        max_drift_um[1] = max_drift_um[1].max(d[1].abs());
        est.push(ReferenceSample {
            t_s: r.t_s,
            drift_um: d,
        })?;
    }
    let mut out: Vec<Record> = rest.into_iter().cloned().collect();
    let corrected = est.correct(&mut out);
    Ok((
        out,
        Some(LogDriftCorrection {
            references: refs.len(),
            corrected,
            max_drift_um,
            baseline: DriftBaseline {
                reference_um: [first.x_target_um, first.y_target_um],
                measured_um: [first.x_meas_um, first.y_meas_um],
            },
        }),
    ))
}

/// Where the reference point was measured when a table's data were taken
/// (the first re-measurement of the characterization, see
/// [`correct_log_drift`]).
///
/// Why it is kept with the table: a table maps a command to where the stage
/// went *in the rig's state at the baseline*. Later the same command lands
/// `d(t)` away; re-measuring the reference (approached the same way) gives
/// `d(t) = measured(t) − measured_um` at the reference, and a compensated
/// move to `T` commands the table's command for `T − d(t)`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct DriftBaseline {
    /// The reference point, `[x, y]` µm, controller coordinates.
    pub reference_um: [f64; 2],
    /// Where the camera measured it then, `[x, y]` µm, stage frame of the
    /// characterization's vision tie.
    pub measured_um: [f64; 2],
}

/// Keys of [`DriftBaseline`] in a table's `source.metadata`.
pub const BASELINE_KEYS: [&str; 4] = [
    "drift.reference_x_um",
    "drift.reference_y_um",
    "drift.baseline_x_um",
    "drift.baseline_y_um",
];

impl DriftBaseline {
    /// The metadata entries (keys [`BASELINE_KEYS`]), full precision.
    pub fn to_metadata(&self) -> Vec<(String, String)> {
        let v = [
            self.reference_um[0],
            self.reference_um[1],
            self.measured_um[0],
            self.measured_um[1],
        ];
        BASELINE_KEYS
            .iter()
            .zip(v)
            .map(|(k, v)| ((*k).to_owned(), format!("{v:?}")))
            .collect()
    }

    /// Reads it back: `Ok(None)` when no key is present (a table built from
    /// a log without reference re-measurements), an error when some are
    /// missing or unreadable (the table file was edited).
    pub fn from_metadata<'a>(
        get: impl Fn(&str) -> Option<&'a str>,
    ) -> Result<Option<DriftBaseline>, AnalysisError> {
        let raw: Vec<Option<&str>> = BASELINE_KEYS.iter().map(|k| get(k)).collect();
        if raw.iter().all(Option::is_none) {
            return Ok(None);
        }
        let mut v = [0.0; 4];
        for ((slot, r), k) in v.iter_mut().zip(&raw).zip(BASELINE_KEYS) {
            let text =
                r.ok_or_else(|| AnalysisError::Invalid(format!("drift baseline: {k} is missing")))?;
            *slot = text
                .trim()
                .parse::<f64>()
                .ok()
                .filter(|x| x.is_finite())
                .ok_or_else(|| {
                    AnalysisError::Invalid(format!(
                        "drift baseline: {k} = {text:?} is not a finite number"
                    ))
                })?;
        }
        Ok(Some(DriftBaseline {
            reference_um: [v[0], v[1]],
            measured_um: [v[2], v[3]],
        }))
    }
}

/// How a working session predicts the drift it corrects.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", tag = "method")]
pub enum LiveMethod {
    /// No correction (re-measurements are not taken).
    Off,
    /// The drift measured at the session's first re-measurement, held
    /// (the "static" model: one offset since the tables were built).
    Static,
    /// [`DriftMethod::Adaptive`] over the session's re-measurements: a
    /// local line with exponential forgetting, extrapolated to the move.
    Adaptive {
        /// Forgetting time constant τ, s (> 0).
        time_constant_s: f64,
    },
}

/// One live re-measurement, as reported and logged.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LiveSample {
    /// Rig time, s.
    pub t_s: f64,
    /// Where the reference was measured, `[x, y]` µm (stage frame).
    pub measured_um: [f64; 2],
    /// Drift relative to the baseline, `[x, y]` µm (measured − baseline).
    pub drift_um: [f64; 2],
}

/// Live drift state of a working session (sans-IO: the daemon measures,
/// this decides when, keeps the estimate and predicts the correction).
///
/// Invariants: the estimate only ever holds successful re-measurements of
/// the current reference against the current baseline ([`LiveDrift::arm`]
/// starts over when either changes); a failed re-measurement is counted
/// and reported but leaves the estimate untouched; predictions extrapolate
/// at most [`LiveDrift::MAX_EXTRAPOLATION_INTERVALS`] intervals beyond the
/// last good re-measurement (beyond that the correction is held, not
/// extrapolated into the unknown).
#[derive(Debug, Clone)]
pub struct LiveDrift {
    method: LiveMethod,
    every_s: f64,
    reference_um: Option<[f64; 2]>,
    /// The baseline in use; `table` says whether it came with the tables
    /// (else: the session's first re-measurement).
    baseline: Option<([f64; 2], bool)>,
    estimator: DriftEstimator,
    last_attempt_s: Option<f64>,
    failures: u32,
    last_error: Option<String>,
}

impl LiveDrift {
    /// How many intervals past the last good re-measurement a prediction
    /// may extrapolate.
    pub const MAX_EXTRAPOLATION_INTERVALS: f64 = 2.0;

    /// A session that re-measures every `every_s` (> 0) with `method`.
    pub fn new(method: LiveMethod, every_s: f64) -> Result<LiveDrift, AnalysisError> {
        if !(every_s.is_finite() && every_s > 0.0) {
            return Err(AnalysisError::Invalid(format!(
                "drift interval {every_s} s: must be a finite number > 0"
            )));
        }
        Ok(LiveDrift {
            method,
            every_s,
            reference_um: None,
            baseline: None,
            estimator: Self::estimator(method)?,
            last_attempt_s: None,
            failures: 0,
            last_error: None,
        })
    }

    fn estimator(method: LiveMethod) -> Result<DriftEstimator, AnalysisError> {
        DriftEstimator::new(match method {
            LiveMethod::Adaptive { time_constant_s } => DriftMethod::Adaptive { time_constant_s },
            // Unused for Static/Off (see `correction`), any valid period.
            _ => DriftMethod::Static { calibration_s: 1.0 },
        })
    }

    /// Off, with the default interval: what a daemon starts with when its
    /// configuration asks for nothing (infallible).
    pub fn off() -> LiveDrift {
        LiveDrift {
            method: LiveMethod::Off,
            every_s: 300.0,
            reference_um: None,
            baseline: None,
            estimator: DriftEstimator {
                method: DriftMethod::Static { calibration_s: 1.0 },
                samples: Vec::new(),
            },
            last_attempt_s: None,
            failures: 0,
            last_error: None,
        }
    }

    /// The method.
    pub fn method(&self) -> LiveMethod {
        self.method
    }

    /// The interval between re-measurements, s.
    pub fn every_s(&self) -> f64 {
        self.every_s
    }

    /// The reference point in use, if armed.
    pub fn reference_um(&self) -> Option<[f64; 2]> {
        self.reference_um
    }

    /// Changes the method and interval; the re-measurements are kept
    /// (they do not depend on the method).
    pub fn configure(&mut self, method: LiveMethod, every_s: f64) -> Result<(), AnalysisError> {
        let mut next = LiveDrift::new(method, every_s)?;
        for s in self.estimator.samples() {
            next.estimator.push(*s)?;
        }
        next.reference_um = self.reference_um;
        next.baseline = self.baseline;
        next.last_attempt_s = self.last_attempt_s;
        *self = next;
        Ok(())
    }

    /// Forgets every re-measurement (and a session baseline); the next
    /// re-measurement is due at once.
    pub fn reset(&mut self) {
        if let Ok(e) = Self::estimator(self.method) {
            self.estimator = e;
        }
        if self.baseline.is_some_and(|(_, table)| !table) {
            self.baseline = None;
        }
        self.last_attempt_s = None;
        self.failures = 0;
        self.last_error = None;
    }

    /// Prepares for moves compensated by a table with `baseline` (if it
    /// has one) re-measuring at `reference_um`. A change of reference or of
    /// baseline starts over: drift measured against another state of the
    /// rig does not apply.
    pub fn arm(&mut self, reference_um: [f64; 2], baseline: Option<DriftBaseline>) {
        let wanted = baseline.map(|b| (b.measured_um, true));
        let same_ref = self.reference_um == Some(reference_um);
        let same_base = match (wanted, self.baseline) {
            (Some(w), b) => Some(w) == b,
            // No table baseline: a session baseline, once taken, stays.
            (None, Some((_, table))) => !table,
            (None, None) => true,
        };
        if !(same_ref && same_base) {
            self.reference_um = Some(reference_um);
            self.baseline = wanted;
            self.reset();
        }
    }

    /// Whether a re-measurement is due at `now_s` (never when off or not
    /// armed; at once when none was attempted yet).
    pub fn due(&self, now_s: f64) -> bool {
        self.method != LiveMethod::Off
            && self.reference_um.is_some()
            && self
                .last_attempt_s
                .is_none_or(|t| now_s - t >= self.every_s)
    }

    /// Records a successful re-measurement; returns it with its drift.
    /// The first one of a session without a table baseline becomes the
    /// baseline (drift 0).
    pub fn record(&mut self, t_s: f64, measured_um: [f64; 2]) -> Result<LiveSample, AnalysisError> {
        if !measured_um.iter().all(|v| v.is_finite()) {
            return Err(AnalysisError::Invalid(
                "reference re-measurement: position must be finite".into(),
            ));
        }
        let base = self.baseline.map_or(measured_um, |(b, _)| b);
        let drift_um = [measured_um[0] - base[0], measured_um[1] - base[1]];
        self.estimator.push(ReferenceSample { t_s, drift_um })?;
        if self.baseline.is_none() {
            self.baseline = Some((measured_um, false));
        }
        self.last_attempt_s = Some(t_s);
        self.failures = 0;
        self.last_error = None;
        Ok(LiveSample {
            t_s,
            measured_um,
            drift_um,
        })
    }

    /// Records a failed re-measurement: the estimate is unchanged, the
    /// next attempt waits a full interval (a failing camera is not hammered
    /// before every move).
    pub fn record_failure(&mut self, t_s: f64, why: String) {
        self.last_attempt_s = Some(t_s);
        self.failures = self.failures.saturating_add(1);
        self.last_error = Some(why);
    }

    /// Consecutive failed re-measurements.
    pub fn failures(&self) -> u32 {
        self.failures
    }

    /// The correction to apply at `now_s`, `[x, y]` µm (subtract it from a
    /// compensated target); `None` when off or before any re-measurement.
    pub fn correction(&self, now_s: f64) -> Option<[f64; 2]> {
        let samples = self.estimator.samples();
        match self.method {
            LiveMethod::Off => None,
            LiveMethod::Static => samples.first().map(|s| s.drift_um),
            LiveMethod::Adaptive { .. } => {
                let last = samples.last()?;
                let t = now_s.min(last.t_s + Self::MAX_EXTRAPOLATION_INTERVALS * self.every_s);
                self.estimator.predict(t.max(last.t_s))
            }
        }
    }

    /// The state for `status` and events.
    pub fn to_json(&self, now_s: f64) -> serde_json::Value {
        let samples = self.estimator.samples();
        let method = match self.method {
            LiveMethod::Off => "off",
            LiveMethod::Static => "static",
            LiveMethod::Adaptive { .. } => "adaptive",
        };
        serde_json::json!({
            "method": method,
            "time_constant_s": match self.method {
                LiveMethod::Adaptive { time_constant_s } => Some(time_constant_s),
                _ => None,
            },
            "every_s": self.every_s,
            "reference_um": self.reference_um,
            "baseline_um": self.baseline.map(|b| b.0),
            "baseline": self.baseline.map(|b| if b.1 { "table" } else { "session" }),
            "references": samples.len(),
            "last": samples.last(),
            "correction_um": self.correction(now_s),
            "age_s": samples.last().map(|s| now_s - s.t_s),
            "failures": self.failures,
            "last_error": self.last_error,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn linear_drift_is_followed_exactly_by_both() {
        for m in [
            DriftMethod::Static {
                calibration_s: 3600.0,
            },
            DriftMethod::Adaptive {
                time_constant_s: 1800.0,
            },
        ] {
            let mut e = DriftEstimator::new(m).unwrap();
            assert!(e.predict(0.0).is_none());
            for k in 0..20 {
                let t = 600.0 * k as f64;
                e.push(ReferenceSample {
                    t_s: t,
                    drift_um: [0.1 + 1e-4 * t, -2e-5 * t],
                })
                .unwrap();
            }
            let p = e.predict(20_000.0).unwrap();
            assert!(
                (p[0] - 2.1).abs() < 1e-9 && (p[1] + 0.4).abs() < 1e-9,
                "{m:?}: {p:?}"
            );
        }
        let mut e = DriftEstimator::new(DriftMethod::Adaptive {
            time_constant_s: 60.0,
        })
        .unwrap();
        e.push(ReferenceSample {
            t_s: 10.0,
            drift_um: [1.0, 2.0],
        })
        .unwrap();
        assert_eq!(e.predict(100.0), Some([1.0, 2.0]));
        assert!(e
            .push(ReferenceSample {
                t_s: 5.0,
                drift_um: [0.0, 0.0]
            })
            .is_err());
        assert!(DriftEstimator::new(DriftMethod::Static { calibration_s: 0.0 }).is_err());
    }

    fn armed(method: LiveMethod) -> LiveDrift {
        let mut d = LiveDrift::new(method, 100.0).unwrap();
        d.arm(
            [0.0, 0.0],
            Some(DriftBaseline {
                reference_um: [0.0, 0.0],
                measured_um: [1.0, 2.0],
            }),
        );
        d
    }

    #[test]
    fn live_drift_is_relative_to_the_table_baseline() {
        let mut d = armed(LiveMethod::Adaptive {
            time_constant_s: 1000.0,
        });
        assert!(d.due(0.0));
        assert_eq!(d.correction(0.0), None);
        // Drift 0.5 µm in x at t = 0, growing 1 nm/s.
        for k in 0..5 {
            let t = 100.0 * k as f64;
            let s = d.record(t, [1.5 + 1e-3 * t, 2.0 - 1e-3 * t]).unwrap();
            assert!((s.drift_um[0] - (0.5 + 1e-3 * t)).abs() < 1e-12);
            assert!(!d.due(t + 50.0) && d.due(t + 100.0));
        }
        let c = d.correction(450.0).unwrap();
        assert!(
            (c[0] - 0.95).abs() < 1e-9 && (c[1] + 0.45).abs() < 1e-9,
            "{c:?}"
        );
        // Extrapolation stops two intervals after the last good sample.
        let far = d.correction(10_000.0).unwrap();
        assert!((far[0] - 1.1).abs() < 1e-9, "{far:?}");
        // Static holds the first offset.
        let mut s = armed(LiveMethod::Static);
        s.record(0.0, [1.5, 2.0]).unwrap();
        s.record(100.0, [1.6, 2.0]).unwrap();
        assert_eq!(s.correction(200.0), Some([0.5, 0.0]));
        // Off never asks and never corrects.
        let mut o = armed(LiveMethod::Off);
        assert!(!o.due(0.0));
        o.record(0.0, [5.0, 5.0]).unwrap();
        assert_eq!(o.correction(0.0), None);
    }

    #[test]
    fn failures_leave_the_estimate_and_rearming_starts_over() {
        let mut d = armed(LiveMethod::Adaptive {
            time_constant_s: 1000.0,
        });
        d.record(0.0, [1.3, 2.1]).unwrap();
        let before = d.correction(100.0);
        d.record_failure(100.0, "camera_stalled".into());
        assert_eq!(d.failures(), 1);
        assert_eq!(d.correction(100.0), before);
        assert!(!d.due(150.0) && d.due(200.0));
        assert!(d.record(200.0, [f64::NAN, 0.0]).is_err());
        // One good sample: held (equal up to rounding at another time).
        let (a, b) = (d.correction(200.0).unwrap(), before.unwrap());
        assert!((a[0] - b[0]).abs() < 1e-12 && (a[1] - b[1]).abs() < 1e-12);
        assert_eq!(d.estimator.samples().len(), 1, "the bad sample is not kept");
        d.record(200.0, [1.3, 2.1]).unwrap();
        assert_eq!(d.failures(), 0);
        // Same table again: kept. Another baseline: starts over.
        d.arm(
            [0.0, 0.0],
            Some(DriftBaseline {
                reference_um: [0.0, 0.0],
                measured_um: [1.0, 2.0],
            }),
        );
        assert!(d.correction(200.0).is_some());
        d.arm([0.0, 0.0], None);
        assert_eq!(d.correction(200.0), None);
        assert!(d.due(200.0));
        // Without a table baseline the first re-measurement is the baseline.
        let s = d.record(300.0, [7.0, 8.0]).unwrap();
        assert_eq!(s.drift_um, [0.0, 0.0]);
        let s = d.record(400.0, [7.25, 8.0]).unwrap();
        assert_eq!(s.drift_um, [0.25, 0.0]);
        d.arm([0.0, 0.0], None);
        assert_eq!(d.estimator.samples().len(), 2, "same session kept");
        assert!(LiveDrift::new(LiveMethod::Static, 0.0).is_err());
    }

    #[test]
    fn baseline_round_trips_through_table_metadata() {
        let b = DriftBaseline {
            reference_um: [0.0, 100.5],
            measured_um: [0.123456789, 99.87654321],
        };
        let md: std::collections::BTreeMap<String, String> = b.to_metadata().into_iter().collect();
        let get = |k: &str| md.get(k).map(String::as_str);
        assert_eq!(DriftBaseline::from_metadata(get).unwrap(), Some(b));
        assert_eq!(DriftBaseline::from_metadata(|_| None).unwrap(), None);
        let mut bad = md.clone();
        bad.insert(BASELINE_KEYS[2].into(), "nan".into());
        assert!(DriftBaseline::from_metadata(|k| bad.get(k).map(String::as_str)).is_err());
        bad.remove(BASELINE_KEYS[2]);
        assert!(DriftBaseline::from_metadata(|k| bad.get(k).map(String::as_str)).is_err());
    }
}
