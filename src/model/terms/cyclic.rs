//! Leadscrew cyclic error and its cross-axis coupling.
//!
//! Physics: the nut follows the thread of the screw; thread form errors,
//! eccentricity of the screw and wobble of its bearing repeat once per turn,
//! i.e. every `period_um` (the lead, 400 µm on the M-111) of commanded
//! position, with harmonics. The paper's Fig. 4 shows this along x with
//! slightly different amplitudes forward and backward (the flank in contact
//! changes with direction); Fig. 5 shows the same period across the axis
//! (the nut wobble pushes the carriage sideways).
//!
//! ```text
//! φ = 2π·cmd/period
//! c = Σ_k  s_k^dir·sin(kφ) + c_k^dir·cos(kφ)    (µm)
//! ```
//! `dir` is the axis's last direction (forward/backward set; the mean of both
//! when unknown). `leadscrew_cyclic` adds `c` along the axis, `cross_coupling`
//! adds it across the axis. Linear in the amplitudes.

use serde::{Deserialize, Serialize};

use super::super::state::{Axis, MotionState};
use super::super::term::{
    check_param_values, config_table, parse_term_config, require_finite, require_positive,
    ParamInfo, Term,
};
use super::super::ModelError;
use super::{direction_weights, harmonics};

/// Kind name of the along-axis cyclic error.
pub const LEADSCREW_KIND: &str = "leadscrew_cyclic";
/// Kind name of the across-axis cyclic error.
pub const COUPLING_KIND: &str = "cross_coupling";
/// Most harmonics a term may have (more would fit measurement noise).
pub const MAX_HARMONICS: usize = 32;

fn default_period_um() -> f64 {
    400.0
}

/// Model-file table of a cyclic term.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CyclicConfig {
    /// The moving axis whose commanded position sets the phase.
    pub axis: Axis,
    /// Period of the error in commanded position, µm (the screw lead).
    #[serde(default = "default_period_um")]
    pub period_um: f64,
    /// Sine amplitudes of harmonics 1..n when the axis last moved forward, µm.
    pub forward_sin_um: Vec<f64>,
    /// Cosine amplitudes of harmonics 1..n when the axis last moved forward, µm.
    pub forward_cos_um: Vec<f64>,
    /// Sine amplitudes when the axis last moved backward, µm.
    pub backward_sin_um: Vec<f64>,
    /// Cosine amplitudes when the axis last moved backward, µm.
    pub backward_cos_um: Vec<f64>,
}

/// A cyclic term (either kind; see the module docs).
#[derive(Debug, Clone, PartialEq)]
pub struct CyclicTerm {
    name: String,
    across: bool,
    cfg: CyclicConfig,
}

impl CyclicTerm {
    /// Builds and validates. `across = false` is `leadscrew_cyclic`, `true`
    /// is `cross_coupling`.
    pub fn new(name: &str, across: bool, cfg: CyclicConfig) -> Result<Self, ModelError> {
        require_positive(name, "period_um", cfg.period_um)?;
        let n = cfg.forward_sin_um.len();
        if n == 0 || n > MAX_HARMONICS {
            return Err(ModelError::Invalid {
                key: format!("term `{name}`: forward_sin_um"),
                reason: format!("needs 1..={MAX_HARMONICS} harmonics, got {n}"),
            });
        }
        for (key, v) in [
            ("forward_sin_um", &cfg.forward_sin_um),
            ("forward_cos_um", &cfg.forward_cos_um),
            ("backward_sin_um", &cfg.backward_sin_um),
            ("backward_cos_um", &cfg.backward_cos_um),
        ] {
            if v.len() != n {
                return Err(ModelError::Invalid {
                    key: format!("term `{name}`: {key}"),
                    reason: format!(
                        "must have as many harmonics as forward_sin_um ({n}), got {}",
                        v.len()
                    ),
                });
            }
            for (i, x) in v.iter().enumerate() {
                require_finite(name, &format!("{key}[{i}]"), *x)?;
            }
        }
        Ok(CyclicTerm {
            name: name.to_string(),
            across,
            cfg,
        })
    }

    /// The validated configuration.
    pub fn config(&self) -> &CyclicConfig {
        &self.cfg
    }

    fn harmonics_count(&self) -> usize {
        self.cfg.forward_sin_um.len()
    }

    fn component(&self) -> usize {
        if self.across {
            self.cfg.axis.other().index()
        } else {
            self.cfg.axis.index()
        }
    }

    /// ∂c/∂amplitudes (the scalar along the component), params order.
    fn basis(&self, state: &MotionState) -> Vec<f64> {
        let n = self.harmonics_count();
        let ax = state.axis(self.cfg.axis);
        let (wf, wb) = direction_weights(ax.dir);
        let h = harmonics(ax.cmd_um, self.cfg.period_um, n);
        let mut out = Vec::with_capacity(4 * n);
        for w in [wf, wb] {
            for (s, c) in &h {
                out.push(w * s);
                out.push(w * c);
            }
        }
        out
    }

    fn values(&self) -> Vec<f64> {
        let mut out = Vec::with_capacity(4 * self.harmonics_count());
        for (s, c) in [
            (&self.cfg.forward_sin_um, &self.cfg.forward_cos_um),
            (&self.cfg.backward_sin_um, &self.cfg.backward_cos_um),
        ] {
            for (a, b) in s.iter().zip(c) {
                out.push(*a);
                out.push(*b);
            }
        }
        out
    }
}

impl Term for CyclicTerm {
    fn name(&self) -> &str {
        &self.name
    }

    fn kind(&self) -> &'static str {
        if self.across {
            COUPLING_KIND
        } else {
            LEADSCREW_KIND
        }
    }

    fn params(&self) -> Vec<ParamInfo> {
        let axis = self.cfg.axis;
        let comp = Axis::ALL[self.component()];
        let values = self.values();
        let mut out = Vec::with_capacity(values.len());
        let mut i = 0;
        for dir in ["forward", "backward"] {
            for k in 1..=self.harmonics_count() {
                for f in ["sin", "cos"] {
                    out.push(ParamInfo::new(
                        format!("{dir}_{f}_{k}_um"),
                        "µm",
                        values[i],
                        format!(
                            "{f} amplitude of harmonic {k} (period {} µm of {axis}) of the {comp} error after {dir} motion of {axis}",
                            short(self.cfg.period_um / k as f64)
                        ),
                    ));
                    i += 1;
                }
            }
        }
        out
    }

    fn set_params(&mut self, values: &[f64]) -> Result<(), ModelError> {
        let n = self.harmonics_count();
        check_param_values(&self.name, 4 * n, values)?;
        for k in 0..n {
            self.cfg.forward_sin_um[k] = values[2 * k];
            self.cfg.forward_cos_um[k] = values[2 * k + 1];
            self.cfg.backward_sin_um[k] = values[2 * n + 2 * k];
            self.cfg.backward_cos_um[k] = values[2 * n + 2 * k + 1];
        }
        Ok(())
    }

    fn contribution(&self, state: &MotionState) -> [f64; 2] {
        let v: f64 = self
            .basis(state)
            .iter()
            .zip(self.values())
            .map(|(b, p)| b * p)
            .sum();
        let mut out = [0.0; 2];
        out[self.component()] = v;
        out
    }

    fn is_linear(&self) -> bool {
        true
    }

    fn jacobian(&self, state: &MotionState) -> Vec<[f64; 2]> {
        let comp = self.component();
        self.basis(state)
            .into_iter()
            .map(|b| {
                let mut d = [0.0; 2];
                d[comp] = b;
                d
            })
            .collect()
    }

    fn to_config(&self) -> Result<toml::Table, ModelError> {
        config_table(&self.name, &self.cfg)
    }

    fn clone_box(&self) -> Box<dyn Term> {
        Box::new(self.clone())
    }
}

/// `133.333`, `400`: three decimals at most, no trailing zeros.
fn short(v: f64) -> String {
    let s = format!("{v:.3}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    s.to_string()
}

pub(crate) fn build_leadscrew(name: &str, table: toml::Table) -> Result<Box<dyn Term>, ModelError> {
    let cfg = parse_term_config(name, LEADSCREW_KIND, table)?;
    Ok(Box::new(CyclicTerm::new(name, false, cfg)?))
}

pub(crate) fn build_coupling(name: &str, table: toml::Table) -> Result<Box<dyn Term>, ModelError> {
    let cfg = parse_term_config(name, COUPLING_KIND, table)?;
    Ok(Box::new(CyclicTerm::new(name, true, cfg)?))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::state::{AxisMotion, Direction};
    use crate::model::term::numeric_jacobian;

    fn cfg() -> CyclicConfig {
        CyclicConfig {
            axis: Axis::X,
            period_um: 400.0,
            forward_sin_um: vec![1.0, 0.5],
            forward_cos_um: vec![0.2, 0.0],
            backward_sin_um: vec![2.0, 0.0],
            backward_cos_um: vec![0.0, -1.0],
        }
    }

    fn at(x: f64, dir: Direction) -> MotionState {
        let mut s = MotionState::at_rest(x, 0.0);
        s.axes[0] = AxisMotion {
            cmd_um: x,
            dir,
            run_um: 100.0,
            prev_run_um: None,
            last_move_um: 100.0,
        };
        s
    }

    #[test]
    fn hand_computed_values() {
        let t = CyclicTerm::new("c", false, cfg()).unwrap();
        // x = 100 µm: φ = π/2. sin φ = 1, cos φ = 0, sin 2φ = 0, cos 2φ = −1.
        let f = t.contribution(&at(100.0, Direction::Forward));
        assert!((f[0] - 1.0).abs() < 1e-12, "{f:?}");
        assert_eq!(f[1], 0.0);
        let b = t.contribution(&at(100.0, Direction::Backward));
        assert!((b[0] - (2.0 + 1.0)).abs() < 1e-12, "{b:?}");
        let u = t.contribution(&at(100.0, Direction::Unknown));
        assert!((u[0] - 2.0).abs() < 1e-12, "{u:?}");
        // x = 450 µm = 50 µm into the second period: φ = π/4.
        let s = std::f64::consts::FRAC_1_SQRT_2;
        let f = t.contribution(&at(450.0, Direction::Forward));
        assert!((f[0] - (s + 0.2 * s + 0.5)).abs() < 1e-12, "{f:?}");
        // Negative positions wrap the same way.
        let g = t.contribution(&at(-350.0, Direction::Forward));
        assert!((g[0] - f[0]).abs() < 1e-12);
    }

    #[test]
    fn coupling_goes_across() {
        let t = CyclicTerm::new("c", true, cfg()).unwrap();
        let f = t.contribution(&at(100.0, Direction::Forward));
        assert_eq!(f[0], 0.0);
        assert!((f[1] - 1.0).abs() < 1e-12);
        assert_eq!(t.kind(), COUPLING_KIND);
    }

    #[test]
    fn jacobian_matches_numeric_and_params_round_trip() {
        let mut t = CyclicTerm::new("c", false, cfg()).unwrap();
        let st = at(123.4, Direction::Backward);
        let exact = t.jacobian(&st);
        let num = numeric_jacobian(&t, &st);
        for (a, b) in exact.iter().zip(&num) {
            assert!((a[0] - b[0]).abs() < 1e-7 && (a[1] - b[1]).abs() < 1e-7);
        }
        let p: Vec<f64> = t.params().iter().map(|p| p.value).collect();
        assert_eq!(p, vec![1.0, 0.2, 0.5, 0.0, 2.0, 0.0, 0.0, -1.0]);
        t.set_params(&[0.0; 8]).unwrap();
        assert_eq!(t.contribution(&st), [0.0, 0.0]);
        assert!(t.set_params(&[0.0; 7]).is_err());
        assert!(t.set_params(&[f64::NAN; 8]).is_err());
    }

    #[test]
    fn validation_names_the_key() {
        let mut c = cfg();
        c.backward_cos_um = vec![1.0];
        let e = CyclicTerm::new("xc", false, c).unwrap_err().to_string();
        assert!(e.contains("backward_cos_um"), "{e}");
        let mut c = cfg();
        c.period_um = 0.0;
        let e = CyclicTerm::new("xc", false, c).unwrap_err().to_string();
        assert!(e.contains("period_um"), "{e}");
        let mut c = cfg();
        c.forward_cos_um[1] = f64::NAN;
        let e = CyclicTerm::new("xc", false, c).unwrap_err().to_string();
        assert!(e.contains("forward_cos_um[1]"), "{e}");
    }
}
