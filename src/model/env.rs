//! What the simulator needs beyond the terms: the stochastic part
//! (settling noise, rough spots, minimum incremental motion) and the
//! environment (the ambient temperature history), with their checks.

use super::error::ModelError;
use serde::{Deserialize, Serialize};

/// What the simulator adds on top of the systematic model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct Stochastic {
    /// σ of the Gaussian settling error drawn for an axis each time it
    /// completes a move, `[x, y]`, µm. The datasheet's 0.1 µm unidirectional
    /// repeatability corresponds to σ ≈ 0.03 µm (ISO 9283 RP ≈ 2.6·σ for one
    /// axis).
    #[serde(default)]
    pub repeatability_sigma_um: [f64; 2],
    /// Minimum incremental motion, µm: a move shorter than this (from where
    /// the servo is) does not happen at all. 0.05 µm on the M-111.
    #[serde(default)]
    pub min_incremental_motion_um: f64,
    /// Grid to which commanded positions are rounded before moving, µm (the
    /// encoder count); 0 disables.
    #[serde(default)]
    pub position_quantum_um: f64,
    /// Places along an axis where the settling scatter is larger than
    /// `repeatability_sigma_um`: a damaged or contaminated stretch of screw
    /// or guideway where the carriage sticks and slips. Why: the paper's
    /// repeatability profile (Fig. 6) is ≤ 1 µm except at two isolated
    /// peaks, which a uniform σ cannot give.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub rough_spots: Vec<RoughSpot>,
}

/// A stretch of an axis with extra settling scatter (see
/// [`Stochastic::rough_spots`]). The extra σ at position `p` is
/// `sigma_um·exp(−(p − position_um)²/(2·width_um²))`, added in quadrature
/// to the axis's `repeatability_sigma_um`; it acts on the axis's own
/// component.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RoughSpot {
    /// The axis whose carriage sticks there.
    pub axis: super::state::Axis,
    /// Centre of the stretch, µm of commanded position of that axis.
    pub position_um: f64,
    /// Gaussian half-width σ of the stretch, µm (> 0).
    pub width_um: f64,
    /// Extra settling σ at the centre, µm (≥ 0).
    pub sigma_um: f64,
}

/// Most rough spots a model may have (each costs a term per settle).
pub const MAX_ROUGH_SPOTS: usize = 64;

impl Stochastic {
    /// Settling σ of axis `index` (0 = x, 1 = y) when it stops at
    /// commanded position `pos_um`, µm: the uniform σ and the rough spots in
    /// quadrature.
    pub fn settling_sigma_um(&self, index: usize, pos_um: f64) -> f64 {
        let base = self
            .repeatability_sigma_um
            .get(index)
            .copied()
            .unwrap_or(0.0);
        let mut var = base * base;
        for r in self.rough_spots.iter().filter(|r| r.axis.index() == index) {
            let z = (pos_um - r.position_um) / r.width_um;
            let s = r.sigma_um * (-0.5 * z * z).exp();
            var += s * s;
        }
        var.sqrt()
    }

    /// Rejects negative or non-finite values, naming the key.
    pub fn validate(&self) -> Result<(), ModelError> {
        for (i, s) in self.repeatability_sigma_um.iter().enumerate() {
            non_negative(&format!("stochastic.repeatability_sigma_um[{i}]"), *s)?;
        }
        if self.rough_spots.len() > MAX_ROUGH_SPOTS {
            return Err(ModelError::Invalid {
                key: "stochastic.rough_spots".into(),
                reason: format!(
                    "at most {MAX_ROUGH_SPOTS} spots, got {}",
                    self.rough_spots.len()
                ),
            });
        }
        for (i, r) in self.rough_spots.iter().enumerate() {
            let key = |k: &str| format!("stochastic.rough_spots[{i}].{k}");
            finite(&key("position_um"), r.position_um)?;
            non_negative(&key("sigma_um"), r.sigma_um)?;
            if !(r.width_um.is_finite() && r.width_um > 0.0) {
                return Err(ModelError::Invalid {
                    key: key("width_um"),
                    reason: format!("must be a finite number > 0, got {}", r.width_um),
                });
            }
        }
        non_negative(
            "stochastic.min_incremental_motion_um",
            self.min_incremental_motion_um,
        )?;
        non_negative("stochastic.position_quantum_um", self.position_quantum_um)?;
        Ok(())
    }
}

/// How the temperature varies between two profile points.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum Interpolation {
    /// Straight lines between points.
    Linear,
    /// Smoothstep (3t² − 2t³) between points: zero slope at every point, as
    /// a room settling between set points.
    #[default]
    Smooth,
}

/// One point of the ambient temperature history.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TemperaturePoint {
    /// Time since the start of the run, s.
    pub time_s: f64,
    /// Ambient temperature at the stage then, °C.
    pub temp_c: f64,
}

/// The ambient temperature history the simulator applies (the analysis uses
/// logged temperatures instead when it has them).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Environment {
    /// Interpolation between points.
    #[serde(default)]
    pub temperature_interpolation: Interpolation,
    /// Temperature points with strictly increasing times; held constant
    /// before the first and after the last.
    #[serde(default = "default_temperature")]
    pub temperature: Vec<TemperaturePoint>,
}

fn default_temperature() -> Vec<TemperaturePoint> {
    vec![TemperaturePoint {
        time_s: 0.0,
        temp_c: super::state::DEFAULT_TEMP_C,
    }]
}

impl Default for Environment {
    fn default() -> Self {
        Environment {
            temperature_interpolation: Interpolation::default(),
            temperature: default_temperature(),
        }
    }
}

impl Environment {
    /// Rejects an empty profile, non-finite values and times that do not
    /// increase, naming the key.
    pub fn validate(&self) -> Result<(), ModelError> {
        if self.temperature.is_empty() {
            return Err(ModelError::Invalid {
                key: "environment.temperature".into(),
                reason: "needs at least one point".into(),
            });
        }
        for (i, p) in self.temperature.iter().enumerate() {
            finite(&format!("environment.temperature[{i}].time_s"), p.time_s)?;
            finite(&format!("environment.temperature[{i}].temp_c"), p.temp_c)?;
            if i > 0 && p.time_s <= self.temperature[i - 1].time_s {
                return Err(ModelError::Invalid {
                    key: format!("environment.temperature[{i}].time_s"),
                    reason: format!(
                        "times must increase strictly, got {} after {}",
                        p.time_s,
                        self.temperature[i - 1].time_s
                    ),
                });
            }
        }
        Ok(())
    }

    /// Ambient temperature at `time_s`, °C. Non-finite time gives the first
    /// point's temperature.
    pub fn temperature_at(&self, time_s: f64) -> f64 {
        let pts = &self.temperature;
        let Some(first) = pts.first() else {
            return super::state::DEFAULT_TEMP_C;
        };
        if !time_s.is_finite() || time_s <= first.time_s {
            return first.temp_c;
        }
        for w in pts.windows(2) {
            let (a, b) = (w[0], w[1]);
            if time_s <= b.time_s {
                let t = (time_s - a.time_s) / (b.time_s - a.time_s);
                let s = match self.temperature_interpolation {
                    Interpolation::Linear => t,
                    Interpolation::Smooth => t * t * (3.0 - 2.0 * t),
                };
                return a.temp_c + s * (b.temp_c - a.temp_c);
            }
        }
        pts.last().map_or(first.temp_c, |p| p.temp_c)
    }
}

fn finite(key: &str, v: f64) -> Result<(), ModelError> {
    if v.is_finite() {
        Ok(())
    } else {
        Err(ModelError::Invalid {
            key: key.to_string(),
            reason: format!("must be a finite number, got {v}"),
        })
    }
}

fn non_negative(key: &str, v: f64) -> Result<(), ModelError> {
    finite(key, v)?;
    if v >= 0.0 {
        Ok(())
    } else {
        Err(ModelError::Invalid {
            key: key.to_string(),
            reason: format!("must be ≥ 0, got {v}"),
        })
    }
}

#[cfg(test)]
mod tests {

    #[test]
    fn rough_spots_add_scatter_where_they_are() {
        let s = Stochastic {
            repeatability_sigma_um: [0.03, 0.04],
            rough_spots: vec![RoughSpot {
                axis: super::super::Axis::X,
                position_um: 1000.0,
                width_um: 20.0,
                sigma_um: 0.5,
            }],
            ..Stochastic::default()
        };
        s.validate().unwrap();
        let at = |i, p| s.settling_sigma_um(i, p);
        assert!((at(0, 1000.0) - (0.03f64.powi(2) + 0.25).sqrt()).abs() < 1e-12);
        assert!((at(0, 5000.0) - 0.03).abs() < 1e-12);
        // The y axis does not feel an x spot.
        assert!((at(1, 1000.0) - 0.04).abs() < 1e-12);
        for bad in [
            RoughSpot {
                width_um: 0.0,
                ..s.rough_spots[0]
            },
            RoughSpot {
                sigma_um: -1.0,
                ..s.rough_spots[0]
            },
            RoughSpot {
                position_um: f64::NAN,
                ..s.rough_spots[0]
            },
        ] {
            let t = Stochastic {
                rough_spots: vec![bad],
                ..s.clone()
            };
            assert!(t.validate().is_err(), "{bad:?}");
        }
    }

    use super::*;

    #[test]
    fn temperature_profile_interpolates_and_holds() {
        let env = Environment {
            temperature_interpolation: Interpolation::Linear,
            temperature: vec![
                TemperaturePoint {
                    time_s: 0.0,
                    temp_c: 20.0,
                },
                TemperaturePoint {
                    time_s: 100.0,
                    temp_c: 21.0,
                },
            ],
        };
        env.validate().unwrap();
        assert_eq!(env.temperature_at(-5.0), 20.0);
        assert_eq!(env.temperature_at(25.0), 20.25);
        assert_eq!(env.temperature_at(1e9), 21.0);
        let smooth = Environment {
            temperature_interpolation: Interpolation::Smooth,
            ..env.clone()
        };
        // Smoothstep at t = 0.25: 0.15625.
        assert!((smooth.temperature_at(25.0) - 20.15625).abs() < 1e-12);
        assert_eq!(smooth.temperature_at(50.0), 20.5);
    }

    #[test]
    fn bad_profiles_name_the_key() {
        let mut env = Environment::default();
        env.temperature.push(TemperaturePoint {
            time_s: 0.0,
            temp_c: 20.0,
        });
        let e = env.validate().unwrap_err().to_string();
        assert!(e.contains("environment.temperature[1].time_s"), "{e}");
        env.temperature.clear();
        assert!(env.validate().is_err());
    }
}
