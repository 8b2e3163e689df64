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
/// `tests/diagnose_drift.rs` on the default thermal drift).
pub const LOG_DRIFT_METHOD: DriftMethod = DriftMethod::Adaptive {
    time_constant_s: 1200.0,
};

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
        }),
    ))
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
}
