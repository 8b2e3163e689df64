//! Least-squares fit of a [`StageModel`]'s parameters to measurements.
//!
//! Residual per sample: `measured − (cmd + Σ all contributions)` (x and y).
//! The solver is Levenberg–Marquardt (Gauss–Newton first, damped only when
//! a step does not lower the cost); when every free parameter belongs to a
//! linear term ([`Term::is_linear`]) the first step is the exact linear
//! least-squares solution and the fit stops there.
//!
//! Each step solves the column-scaled jacobian (columns to unit norm, so µm,
//! ppm and µrad parameters are comparable) through QR then an SVD of `R`,
//! truncating singular values below `rank_tolerance · s_max`. A parameter the
//! data cannot identify (a zero column, or a combination of parameters with
//! the same effect, e.g. lead error and pitch slope on a straight-line run)
//! therefore gets no update instead of a huge one, and is listed in
//! [`FitReport::unidentifiable`] together with its partners.
//!
//! [`Term::is_linear`]: super::term::Term::is_linear

use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};

use super::state::MotionState;
use super::{ModelError, StageModel};

/// One measurement: the state the stage was in and where the camera saw it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Sample {
    /// State (commanded position, history, time, temperature).
    pub state: MotionState,
    /// Measured x in the stage frame, µm.
    pub measured_x_um: f64,
    /// Measured y in the stage frame, µm.
    pub measured_y_um: f64,
}

impl From<&super::sim::SimStep> for Sample {
    /// A simulated measurement: the simulator's state and what the camera
    /// saw (before camera noise).
    fn from(s: &super::sim::SimStep) -> Self {
        Sample {
            state: s.state,
            measured_x_um: s.observed_um.x_um,
            measured_y_um: s.observed_um.y_um,
        }
    }
}

/// How to fit.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FitOptions {
    /// Which parameters are free, as patterns on full names `term.param`:
    /// `*` matches any run of characters (`x_cyclic.*`, `*.backlash_um`,
    /// `*`). Empty means all. A pattern that matches nothing is an error (a
    /// typo would otherwise silently fix a parameter).
    pub free: Vec<String>,
    /// Iteration limit (each iteration: one jacobian, one decomposition).
    pub max_iterations: usize,
    /// Singular values below this fraction of the largest (of the
    /// column-scaled jacobian) are treated as zero.
    pub rank_tolerance: f64,
}

impl Default for FitOptions {
    fn default() -> Self {
        FitOptions {
            free: Vec::new(),
            max_iterations: 50,
            rank_tolerance: 1e-9,
        }
    }
}

impl FitOptions {
    /// Options freeing exactly the parameters matching `patterns`.
    pub fn free<S: Into<String>>(patterns: impl IntoIterator<Item = S>) -> Self {
        FitOptions {
            free: patterns.into_iter().map(Into::into).collect(),
            ..FitOptions::default()
        }
    }
}

/// Result for one free parameter.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FittedParam {
    /// Full name `term.param`.
    pub name: String,
    /// Unit.
    pub unit: String,
    /// Value before the fit.
    pub initial: f64,
    /// Fitted value (the initial one when unidentifiable).
    pub value: f64,
    /// 1-σ standard error from the residual scatter, in the parameter's
    /// unit; `None` when unidentifiable or without redundancy. It assumes
    /// independent residuals: common-mode errors (the settling error a static
    /// axis keeps during a whole line, slow thermal drift) make it
    /// optimistic, by 10× or more for slopes such as lead error or
    /// squareness on line-by-line characterization data.
    pub std_error: Option<f64>,
    /// False when the data cannot determine it (see the module docs).
    pub identifiable: bool,
}

/// What a fit did.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FitReport {
    /// Free parameters, in model order.
    pub params: Vec<FittedParam>,
    /// Number of samples (each gives an x and a y residual).
    pub samples: usize,
    /// RMS residual before the fit `[x, y]`, µm.
    pub initial_residual_rms_um: [f64; 2],
    /// RMS residual after the fit `[x, y]`, µm.
    pub residual_rms_um: [f64; 2],
    /// Numerical rank of the (column-scaled) jacobian.
    pub rank: usize,
    /// Condition number `s_max/s_min` of the column-scaled jacobian over
    /// the free parameters; infinite when some combination is unidentifiable.
    pub condition: f64,
    /// Full names of parameters the data cannot identify (kept at their
    /// initial values).
    pub unidentifiable: Vec<String>,
    /// Iterations run.
    pub iterations: usize,
    /// True when the last step no longer changed the solution (always true
    /// for a linear fit).
    pub converged: bool,
    /// True when every free parameter is in a linear term (single solve).
    pub linear: bool,
}

/// `*` glob on full parameter names.
fn glob(pattern: &str, text: &str) -> bool {
    let parts: Vec<&str> = pattern.split('*').collect();
    if parts.len() == 1 {
        return pattern == text;
    }
    let mut rest = text;
    for (i, part) in parts.iter().enumerate() {
        if i == 0 {
            match rest.strip_prefix(part) {
                Some(r) => rest = r,
                None => return false,
            }
        } else if i == parts.len() - 1 {
            return rest.ends_with(part);
        } else {
            match rest.find(part) {
                Some(at) => rest = &rest[at + part.len()..],
                None => return false,
            }
        }
    }
    true
}

fn validate_samples(samples: &[Sample]) -> Result<(), ModelError> {
    if samples.is_empty() {
        return Err(ModelError::Fit {
            reason: "no samples".into(),
        });
    }
    for (i, s) in samples.iter().enumerate() {
        s.state.validate().map_err(|e| ModelError::Fit {
            reason: format!("sample {i}: {e}"),
        })?;
        if !s.measured_x_um.is_finite() || !s.measured_y_um.is_finite() {
            return Err(ModelError::Fit {
                reason: format!("sample {i}: measured position is not finite"),
            });
        }
    }
    Ok(())
}

fn residuals(model: &StageModel, samples: &[Sample]) -> Vec<f64> {
    let mut r = Vec::with_capacity(2 * samples.len());
    for s in samples {
        let o = model.observed_position(&s.state);
        r.push(s.measured_x_um - o.x_um);
        r.push(s.measured_y_um - o.y_um);
    }
    r
}

fn rms_xy(r: &[f64]) -> [f64; 2] {
    let n = (r.len() / 2).max(1) as f64;
    let sx: f64 = r.iter().step_by(2).map(|v| v * v).sum();
    let sy: f64 = r.iter().skip(1).step_by(2).map(|v| v * v).sum();
    [(sx / n).sqrt(), (sy / n).sqrt()]
}

fn cost(r: &[f64]) -> f64 {
    r.iter().map(|v| v * v).sum()
}

/// The linearized problem at one point, decomposed once so that steps for
/// any damping come cheap.
struct Linearized {
    /// Column scales (norms of the jacobian columns; 1 for zero columns).
    scale: Vec<f64>,
    /// Singular values of the scaled jacobian.
    sv: Vec<f64>,
    /// `uᵢᵀ·Qᵀr` per singular value.
    proj: Vec<f64>,
    /// Right singular vectors: `v[(param, k)]`.
    v: DMatrix<f64>,
    /// Singular values above the rank tolerance.
    kept: Vec<bool>,
}

impl Linearized {
    /// Levenberg–Marquardt step in parameter units (free order) for damping
    /// `lambda` (0 = Gauss–Newton): `Σ vᵢ·sᵢ/(sᵢ² + λ)·projᵢ` over kept
    /// singular values, unscaled. Minimal-norm: directions the data cannot
    /// see get no update.
    fn step(&self, lambda: f64) -> (Vec<f64>, f64) {
        let k = self.scale.len();
        let mut scaled = vec![0.0; k];
        for (i, keep) in self.kept.iter().enumerate() {
            if *keep {
                let coef = self.sv[i] / (self.sv[i] * self.sv[i] + lambda) * self.proj[i];
                for (c, x) in scaled.iter_mut().enumerate() {
                    *x += self.v[(c, i)] * coef;
                }
            }
        }
        let norm = scaled.iter().map(|x| x * x).sum::<f64>().sqrt();
        (
            scaled.iter().zip(&self.scale).map(|(x, s)| x / s).collect(),
            norm,
        )
    }

    fn smax(&self) -> f64 {
        self.sv.iter().copied().fold(0.0, f64::max)
    }
}

/// A jacobian column with a smaller norm (µm per parameter unit, over all
/// samples) carries no information: the parameter is unidentifiable there.
/// Every physical sensitivity in this model is orders of magnitude larger;
/// rounding noise of sin/cos at multiples of π is orders smaller.
const MIN_SENSITIVITY: f64 = 1e-12;

fn linearize(
    model: &StageModel,
    samples: &[Sample],
    free: &[usize],
    r: &[f64],
    rank_tolerance: f64,
) -> Result<Linearized, ModelError> {
    let k = free.len();
    // At least as many rows as columns (zero rows change nothing) so the QR
    // below is of a tall matrix.
    let m = (2 * samples.len()).max(k);
    let mut j = DMatrix::<f64>::zeros(m, k);
    for (i, s) in samples.iter().enumerate() {
        let full = model.jacobian(&s.state);
        for (c, &p) in free.iter().enumerate() {
            let d = full.get(p).copied().unwrap_or([0.0; 2]);
            j[(2 * i, c)] = d[0];
            j[(2 * i + 1, c)] = d[1];
        }
    }
    if j.iter().any(|v| !v.is_finite()) {
        return Err(ModelError::Fit {
            reason: "the jacobian is not finite (parameters or positions far out of range)".into(),
        });
    }
    let mut scale = vec![1.0; k];
    for (c, sc) in scale.iter_mut().enumerate() {
        let n = j.column(c).norm();
        if n > MIN_SENSITIVITY {
            *sc = n;
            j.column_mut(c).scale_mut(1.0 / n);
        } else {
            // Rounding noise (sin(5π) = 6e-16), not information: scaling it
            // to unit norm would turn it into a huge step.
            j.column_mut(c).fill(0.0);
        }
    }
    let mut rhs = DVector::<f64>::zeros(m);
    for (i, v) in r.iter().enumerate() {
        rhs[i] = *v;
    }
    let qr = j.qr();
    qr.q_tr_mul(&mut rhs);
    let rmat = qr.r();
    let qtb = rhs.rows(0, k).into_owned();
    let svd = rmat
        .try_svd(true, true, f64::EPSILON, 10_000)
        .ok_or_else(|| ModelError::Fit {
            reason: "singular value decomposition did not converge".into(),
        })?;
    let (Some(u), Some(vt)) = (svd.u, svd.v_t) else {
        return Err(ModelError::Fit {
            reason: "singular vectors missing".into(),
        });
    };
    let sv: Vec<f64> = svd.singular_values.iter().copied().collect();
    let smax = sv.iter().copied().fold(0.0, f64::max);
    let kept: Vec<bool> = sv
        .iter()
        .map(|s| smax > 0.0 && *s > rank_tolerance * smax)
        .collect();
    let proj = (0..sv.len()).map(|i| u.column(i).dot(&qtb)).collect();
    Ok(Linearized {
        scale,
        sv,
        proj,
        v: vt.transpose(),
        kept,
    })
}

/// Fits `model` to `samples` (see the module docs). On success the model
/// holds the fitted values; on error it is unchanged.
pub fn fit(
    model: &mut StageModel,
    samples: &[Sample],
    options: &FitOptions,
) -> Result<FitReport, ModelError> {
    validate_samples(samples)?;
    if !(options.rank_tolerance.is_finite() && options.rank_tolerance >= 0.0) {
        return Err(ModelError::Fit {
            reason: format!("rank_tolerance must be ≥ 0, got {}", options.rank_tolerance),
        });
    }
    let all = model.params();
    let free: Vec<usize> = if options.free.is_empty() {
        (0..all.len()).collect()
    } else {
        for pat in &options.free {
            if !all.iter().any(|p| glob(pat, &p.full_name)) {
                return Err(ModelError::UnknownParam { name: pat.clone() });
            }
        }
        (0..all.len())
            .filter(|&i| options.free.iter().any(|pat| glob(pat, &all[i].full_name)))
            .collect()
    };
    if free.is_empty() {
        return Err(ModelError::Fit {
            reason: "no free parameter".into(),
        });
    }
    let linear = free
        .iter()
        .all(|&i| model.term(&all[i].term).is_some_and(|t| t.is_linear()));

    let mut work = model.clone();
    let p0 = work.parameter_vector();
    let mut p = p0.clone();
    let mut r = residuals(&work, samples);
    let initial_rms = rms_xy(&r);
    let mut c = cost(&r);
    let mut iterations = 0;
    let mut converged = false;
    // Levenberg–Marquardt damping, relative to s_max² of the scaled
    // jacobian; 0 = pure Gauss–Newton, tried first.
    let mut damping = 0.0;
    while iterations < options.max_iterations {
        iterations += 1;
        let lin = linearize(&work, samples, &free, &r, options.rank_tolerance)?;
        let smax2 = lin.smax().powi(2);
        let mut accepted = false;
        for _ in 0..40 {
            let (step, step_norm) = lin.step(damping * smax2);
            let mut trial = p.clone();
            for (d, &i) in step.iter().zip(&free) {
                trial[i] += d;
            }
            if work.set_parameter_vector(&trial).is_ok() {
                let rt = residuals(&work, samples);
                let ct = cost(&rt);
                if ct.is_finite() && ct <= c {
                    let rel = (c - ct) / c.max(f64::MIN_POSITIVE);
                    p = trial;
                    r = rt;
                    c = ct;
                    accepted = true;
                    if linear || rel < 1e-14 || step_norm < 1e-12 {
                        converged = true;
                    }
                    damping = if damping > 1e-12 { damping / 10.0 } else { 0.0 };
                    break;
                }
            }
            damping = if damping == 0.0 { 1e-6 } else { damping * 10.0 };
            if damping > 1e12 {
                break;
            }
        }
        if !accepted {
            // No damping lowers the cost: we are at the (local) minimum.
            work.set_parameter_vector(&p)?;
            converged = true;
        }
        if converged {
            break;
        }
    }

    // Report at the solution.
    let s = linearize(&work, samples, &free, &r, options.rank_tolerance)?;
    let smax = s.sv.iter().copied().fold(0.0, f64::max);
    let smin = s.sv.iter().copied().fold(f64::INFINITY, f64::min);
    let rank = s.kept.iter().filter(|k| **k).count();
    let condition = if smin > 0.0 {
        smax / smin
    } else {
        f64::INFINITY
    };
    let dof = (2 * samples.len()).saturating_sub(rank);
    let sigma2 = if dof > 0 { c / dof as f64 } else { f64::NAN };
    let mut params = Vec::with_capacity(free.len());
    let mut unidentifiable = Vec::new();
    for (col, &i) in free.iter().enumerate() {
        let null_weight: f64 = (0..s.kept.len())
            .filter(|&k| !s.kept[k])
            .map(|k| s.v[(col, k)].powi(2))
            .sum();
        let identifiable = null_weight <= 1e-2;
        let var_scaled: f64 = (0..s.kept.len())
            .filter(|&k| s.kept[k])
            .map(|k| (s.v[(col, k)] / s.sv[k]).powi(2))
            .sum();
        let se = (sigma2 * var_scaled).sqrt() / s.scale[col];
        if !identifiable {
            unidentifiable.push(all[i].full_name.clone());
        }
        params.push(FittedParam {
            name: all[i].full_name.clone(),
            unit: all[i].info.unit.to_string(),
            initial: p0[i],
            value: p[i],
            std_error: (identifiable && se.is_finite()).then_some(se),
            identifiable,
        });
    }
    *model = work;
    Ok(FitReport {
        params,
        samples: samples.len(),
        initial_residual_rms_um: initial_rms,
        residual_rms_um: rms_xy(&r),
        rank,
        condition,
        unidentifiable,
        iterations,
        converged,
        linear,
    })
}

impl StageModel {
    /// Fits the parameters to measurements by least squares; see
    /// [`fit::fit`](super::fit::fit). On success the model holds the fitted values.
    pub fn fit(
        &mut self,
        samples: &[Sample],
        options: &FitOptions,
    ) -> Result<FitReport, ModelError> {
        fit(self, samples, options)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn glob_matches() {
        assert!(glob("*", "a.b"));
        assert!(glob("x_cyclic.*", "x_cyclic.forward_sin_1_um"));
        assert!(!glob("x_cyclic.*", "y_cyclic.forward_sin_1_um"));
        assert!(glob("*.backlash_um", "y_backlash.backlash_um"));
        assert!(glob("*cyclic*sin*", "x_cyclic.backward_sin_2_um"));
        assert!(glob("a.b", "a.b"));
        assert!(!glob("a.b", "a.bc"));
        assert!(!glob("a*b*b", "ab"));
    }

    #[test]
    fn degenerate_problems_report_instead_of_failing() {
        // One sample, every parameter free: far more unknowns than data,
        // bilinear angle × arm pairs among them. No error, nothing blows up,
        // the sample is matched, the degeneracy is reported.
        let mut m = StageModel::paper_default().unwrap();
        let p0 = m.parameter_vector();
        let s = Sample {
            state: MotionState::at_rest(1000.0, 2000.0),
            measured_x_um: 1010.0,
            measured_y_um: 1995.0,
        };
        let r = m.fit(&[s], &FitOptions::default()).unwrap();
        assert!(r.rank <= 2, "{}", r.rank);
        let before = r.initial_residual_rms_um[0].hypot(r.initial_residual_rms_um[1]);
        let after = r.residual_rms_um[0].hypot(r.residual_rms_um[1]);
        assert!(after <= before * 1e-6, "{before} → {after}");
        assert!(m.parameter_vector().iter().all(|v| v.is_finite()));
        assert!(r.unidentifiable.len() >= r.params.len() - 2);
        // The same sample with only linear terms free is solved exactly
        // (minimal-norm), in one step.
        let mut m = StageModel::paper_default().unwrap();
        let r = m
            .fit(
                &[s],
                &FitOptions::free(["squareness.*", "*_lead.*", "x_cyclic.*"]),
            )
            .unwrap();
        assert!(r.linear && r.iterations == 1);
        assert!(
            r.residual_rms_um[0] < 1e-9 && r.residual_rms_um[1] < 1e-9,
            "{:?}",
            r.residual_rms_um
        );
        // Only thermal terms free at the reference temperature: the jacobian
        // is exactly zero, nothing can move.
        let mut m = StageModel::paper_default().unwrap();
        let r = m
            .fit(
                &[s],
                &FitOptions::free(["stage_thermal.*", "optics_thermal.*"]),
            )
            .unwrap();
        assert_eq!(r.rank, 0);
        assert_eq!(r.unidentifiable.len(), 6);
        assert!(r.params.iter().all(|p| p.std_error.is_none()));
        assert_eq!(m.parameter_vector(), p0);
    }

    #[test]
    fn empty_and_bad_samples_are_errors() {
        let mut m = StageModel::paper_default().unwrap();
        assert!(m.fit(&[], &FitOptions::default()).is_err());
        let s = Sample {
            state: MotionState::at_rest(0.0, 0.0),
            measured_x_um: f64::NAN,
            measured_y_um: 0.0,
        };
        let e = m.fit(&[s], &FitOptions::default()).unwrap_err().to_string();
        assert!(e.contains("sample 0"), "{e}");
        let s = Sample {
            measured_x_um: 0.0,
            ..s
        };
        let e = m
            .fit(&[s], &FitOptions::free(["nope.*"]))
            .unwrap_err()
            .to_string();
        assert!(e.contains("nope.*"), "{e}");
    }
}
