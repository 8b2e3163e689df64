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
