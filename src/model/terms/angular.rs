//! Angular error motion of a carriage (yaw, pitch, roll) seen at the tool
//! point through its Abbe offset.
//!
//! Physics: the guideways make a moving carriage tilt as it travels (the
//! M-111 datasheet allows ±150 µrad of pitch and of yaw). The camera watches
//! a tool point offset from the axis's line of drive by an arm `r` (µm,
//! stage frame: `arm_x_um`, `arm_y_um`, `arm_z_um` = height above the
//! drive line). A small rotation `θ` about unit axis `â` moves the tool point
//! by `θ·(â × r)`; the in-plane part is the error:
//!
//! | rotation | `â` for axis x | `â` for axis y | in-plane displacement |
//! |---|---|---|---|
//! | `yaw`   | +z | +z | `(−θ·r_y, +θ·r_x)` |
//! | `pitch` | +y | +x | x: `(+θ·r_z, 0)`; y: `(0, −θ·r_z)` |
//! | `roll`  | +x | +y | x: `(0, −θ·r_z)`; y: `(+θ·r_z, 0)` |
//!
//! (right-handed rotations about the stage-frame axes: a positive yaw turns
//! +x towards +y, counter-clockwise seen from above.) A yaw also turns the
//! platform, and with it a pattern mounted on it: [`Term::yaw_rad`] reports
//! θ, which the simulated camera renders and the decoder reads as θ
//! (`docs/design/conventions.md`); the displacement above is that rotation
//! about the carriage's rotation centre (the tool point minus the arm) seen
//! at the tool point. Pitch and roll tilt the platform out of the plane: an
//! in-plane pattern sees only their displacement, never their angle. The angle, relative
//! to its value at commanded position 0, is a linear trend plus a periodic
//! part (guideway waviness):
//!
//! ```text
//! θ(p) = 1e-6·[ slope·p/1000 + Σ_k s_k·sin(2πkp/P) + c_k·cos(2πkp/P) − Σ_k c_k ]
//! ```
//! (the `− Σ c_k` keeps θ(0) = 0 so the term does not add a constant offset
//! that belongs to the frame transform). Bilinear in angle and arm (not
//! linear): only the products are identifiable from in-plane data, which the
//! fit reports.

use serde::{Deserialize, Serialize};

use super::super::state::{Axis, MotionState};
use super::super::term::{
    check_param_values, config_table, parse_term_config, require_finite, require_positive,
    ParamInfo, Term,
};
use super::super::ModelError;
use super::cyclic::MAX_HARMONICS;
use super::harmonics;

/// Kind name.
pub const KIND: &str = "angular";

/// Which rotation of the carriage (see the module table).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Rotation {
    /// About +z (vertical).
    Yaw,
    /// About the in-plane axis perpendicular to the motion.
    Pitch,
    /// About the motion axis itself.
    Roll,
}

fn default_period_um() -> f64 {
    5000.0
}

/// Model-file table of an angular term.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AngularConfig {
    /// The moving axis whose carriage tilts.
    pub axis: Axis,
    /// Which rotation.
    pub rotation: Rotation,
    /// Linear trend of the angle, µrad per mm of commanded position.
    pub slope_urad_per_mm: f64,
    /// Period of the periodic part, µm of commanded position.
    #[serde(default = "default_period_um")]
    pub period_um: f64,
    /// Sine amplitudes of the periodic part, harmonics 1..n, µrad (may be
    /// empty).
    #[serde(default)]
    pub sin_urad: Vec<f64>,
    /// Cosine amplitudes, same length as `sin_urad`, µrad.
    #[serde(default)]
    pub cos_urad: Vec<f64>,
    /// Abbe arm along x from the rotation centre to the tool point, µm
    /// (yaw only).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub arm_x_um: Option<f64>,
    /// Abbe arm along y, µm (yaw only).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub arm_y_um: Option<f64>,
    /// Height of the tool point above the drive line, µm (pitch and roll
    /// only).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub arm_z_um: Option<f64>,
    /// Yaw only: this carriage is the lower one and carries the other axis,
    /// so the tool point's arm in the other axis's direction grows with that
    /// axis's commanded position (`arm_x_um + x` for a yaw of the y
    /// carriage, `arm_y_um + y` for the x carriage). Why: it makes the
    /// error depend on both coordinates (`θ(y)·x`), which no pair of 1-D
    /// lookup tables measured along two scan lines can hold — one of the
    /// causes of the paper's random targets being worse than its square.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub carries_other_axis: bool,
}

/// The angular term.
#[derive(Debug, Clone, PartialEq)]
pub struct AngularTerm {
    name: String,
    cfg: AngularConfig,
}

impl AngularTerm {
    /// Builds and validates: arms must match the rotation (a yaw has no use
    /// for `arm_z_um`, a pitch or roll none for `arm_x_um`/`arm_y_um`).
    pub fn new(name: &str, mut cfg: AngularConfig) -> Result<Self, ModelError> {
        require_finite(name, "slope_urad_per_mm", cfg.slope_urad_per_mm)?;
        require_positive(name, "period_um", cfg.period_um)?;
        let n = cfg.sin_urad.len();
        if n > MAX_HARMONICS {
            return Err(ModelError::Invalid {
                key: format!("term `{name}`: sin_urad"),
                reason: format!("at most {MAX_HARMONICS} harmonics, got {n}"),
            });
        }
        if cfg.cos_urad.len() != n {
            return Err(ModelError::Invalid {
                key: format!("term `{name}`: cos_urad"),
                reason: format!(
                    "must have as many harmonics as sin_urad ({n}), got {}",
                    cfg.cos_urad.len()
                ),
            });
        }
        for (key, v) in [("sin_urad", &cfg.sin_urad), ("cos_urad", &cfg.cos_urad)] {
            for (i, x) in v.iter().enumerate() {
                require_finite(name, &format!("{key}[{i}]"), *x)?;
            }
        }
        let (allowed, forbidden): (&[&str], &[&str]) = match cfg.rotation {
            Rotation::Yaw => (&["arm_x_um", "arm_y_um"], &["arm_z_um"]),
            Rotation::Pitch | Rotation::Roll => (&["arm_z_um"], &["arm_x_um", "arm_y_um"]),
        };
        for key in forbidden {
            if arm_field(&mut cfg, key).is_some() {
                return Err(ModelError::Invalid {
                    key: format!("term `{name}`: {key}"),
                    reason: format!(
                        "does not apply to a {:?} rotation (use {})",
                        cfg.rotation,
                        allowed.join(", ")
                    ),
                });
            }
        }
        if cfg.carries_other_axis && cfg.rotation != Rotation::Yaw {
            return Err(ModelError::Invalid {
                key: format!("term `{name}`: carries_other_axis"),
                reason: format!(
                    "only a yaw sees the carried axis's travel in the plane, not a {:?}",
                    cfg.rotation
                ),
            });
        }
        for key in allowed {
            let slot = arm_field(&mut cfg, key);
            let v = slot.unwrap_or(0.0);
            require_finite(name, key, v)?;
            *slot = Some(v);
        }
        Ok(AngularTerm {
            name: name.to_string(),
            cfg,
        })
    }

    fn n(&self) -> usize {
        self.cfg.sin_urad.len()
    }

    /// Unit rotation axis in the stage frame.
    fn rotation_axis(&self) -> [f64; 3] {
        match (self.cfg.rotation, self.cfg.axis) {
            (Rotation::Yaw, _) => [0.0, 0.0, 1.0],
            (Rotation::Pitch, Axis::X) | (Rotation::Roll, Axis::Y) => [0.0, 1.0, 0.0],
            (Rotation::Pitch, Axis::Y) | (Rotation::Roll, Axis::X) => [1.0, 0.0, 0.0],
        }
    }

    /// The arm at `state`: the configured one, plus the carried axis's
    /// commanded position when the carriage carries it.
    fn arm(&self, state: &MotionState) -> [f64; 3] {
        let mut r = [
            self.cfg.arm_x_um.unwrap_or(0.0),
            self.cfg.arm_y_um.unwrap_or(0.0),
            self.cfg.arm_z_um.unwrap_or(0.0),
        ];
        if self.cfg.carries_other_axis {
            let other = match self.cfg.axis {
                Axis::X => Axis::Y,
                Axis::Y => Axis::X,
            };
            r[other.index()] += state.cmd_um(other);
        }
        r
    }

    /// In-plane part of `â × r`, µm per rad.
    fn lever(a: [f64; 3], r: [f64; 3]) -> [f64; 2] {
        [a[1] * r[2] - a[2] * r[1], a[2] * r[0] - a[0] * r[2]]
    }

    /// ∂θ/∂(angle params) in rad per param unit, and θ in rad.
    fn angle_basis(&self, p_um: f64) -> (Vec<f64>, f64) {
        let h = harmonics(p_um, self.cfg.period_um, self.n());
        let mut basis = Vec::with_capacity(1 + 2 * self.n());
        basis.push(1e-6 * p_um / 1000.0);
        for (s, c) in &h {
            basis.push(1e-6 * s);
            basis.push(1e-6 * (c - 1.0));
        }
        let mut theta = basis[0] * self.cfg.slope_urad_per_mm;
        for k in 0..self.n() {
            theta +=
                basis[1 + 2 * k] * self.cfg.sin_urad[k] + basis[2 + 2 * k] * self.cfg.cos_urad[k];
        }
        (basis, theta)
    }

    fn arm_keys(&self) -> &'static [(&'static str, usize)] {
        match self.cfg.rotation {
            Rotation::Yaw => &[("arm_x_um", 0), ("arm_y_um", 1)],
            Rotation::Pitch | Rotation::Roll => &[("arm_z_um", 2)],
        }
    }
}

fn arm_field<'a>(cfg: &'a mut AngularConfig, key: &str) -> &'a mut Option<f64> {
    match key {
        "arm_x_um" => &mut cfg.arm_x_um,
        "arm_y_um" => &mut cfg.arm_y_um,
        _ => &mut cfg.arm_z_um,
    }
}

impl Term for AngularTerm {
    fn name(&self) -> &str {
        &self.name
    }

    fn kind(&self) -> &'static str {
        KIND
    }

    fn params(&self) -> Vec<ParamInfo> {
        let what =
            format!("{:?} of the {} carriage", self.cfg.rotation, self.cfg.axis).to_lowercase();
        let mut out = vec![ParamInfo::new(
            "slope_urad_per_mm",
            "µrad/mm",
            self.cfg.slope_urad_per_mm,
            format!("linear trend of the {what} with its position"),
        )];
        for k in 0..self.n() {
            out.push(ParamInfo::new(
                format!("sin_{}_urad", k + 1),
                "µrad",
                self.cfg.sin_urad[k],
                format!(
                    "sine amplitude of harmonic {} of the periodic {what}",
                    k + 1
                ),
            ));
            out.push(ParamInfo::new(
                format!("cos_{}_urad", k + 1),
                "µrad",
                self.cfg.cos_urad[k],
                format!(
                    "cosine amplitude of harmonic {} of the periodic {what}",
                    k + 1
                ),
            ));
        }
        let arm = [
            self.cfg.arm_x_um.unwrap_or(0.0),
            self.cfg.arm_y_um.unwrap_or(0.0),
            self.cfg.arm_z_um.unwrap_or(0.0),
        ];
        for (key, i) in self.arm_keys() {
            out.push(ParamInfo::new(
                *key,
                "µm",
                arm[*i],
                format!(
                    "Abbe arm ({}) from the rotation centre to the tool point for the {what}",
                    &key[4..5]
                ),
            ));
        }
        out
    }

    fn set_params(&mut self, values: &[f64]) -> Result<(), ModelError> {
        let n = self.n();
        let keys = self.arm_keys();
        check_param_values(&self.name, 1 + 2 * n + keys.len(), values)?;
        self.cfg.slope_urad_per_mm = values[0];
        for k in 0..n {
            self.cfg.sin_urad[k] = values[1 + 2 * k];
            self.cfg.cos_urad[k] = values[2 + 2 * k];
        }
        for (j, (key, _)) in keys.iter().enumerate() {
            *arm_field(&mut self.cfg, key) = Some(values[1 + 2 * n + j]);
        }
        Ok(())
    }

    fn contribution(&self, state: &MotionState) -> [f64; 2] {
        let (_, theta) = self.angle_basis(state.cmd_um(self.cfg.axis));
        let l = Self::lever(self.rotation_axis(), self.arm(state));
        [theta * l[0], theta * l[1]]
    }

    /// A yaw turns the platform by θ about +z; a pitch or roll tilts it
    /// out of the plane, which an in-plane pattern does not see.
    fn yaw_rad(&self, state: &MotionState) -> f64 {
        match self.cfg.rotation {
            Rotation::Yaw => self.angle_basis(state.cmd_um(self.cfg.axis)).1,
            Rotation::Pitch | Rotation::Roll => 0.0,
        }
    }

    fn jacobian(&self, state: &MotionState) -> Vec<[f64; 2]> {
        let (basis, theta) = self.angle_basis(state.cmd_um(self.cfg.axis));
        let a = self.rotation_axis();
        let l = Self::lever(a, self.arm(state));
        let mut out: Vec<[f64; 2]> = basis.iter().map(|b| [b * l[0], b * l[1]]).collect();
        for (_, i) in self.arm_keys() {
            let mut unit = [0.0; 3];
            unit[*i] = 1.0;
            let dl = Self::lever(a, unit);
            out.push([theta * dl[0], theta * dl[1]]);
        }
        out
    }

    fn to_config(&self) -> Result<toml::Table, ModelError> {
        config_table(&self.name, &self.cfg)
    }

    fn clone_box(&self) -> Box<dyn Term> {
        Box::new(self.clone())
    }
}

pub(crate) fn build(name: &str, table: toml::Table) -> Result<Box<dyn Term>, ModelError> {
    let cfg = parse_term_config(name, KIND, table)?;
    Ok(Box::new(AngularTerm::new(name, cfg)?))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::term::numeric_jacobian;

    fn cfg(axis: Axis, rotation: Rotation) -> AngularConfig {
        AngularConfig {
            axis,
            rotation,
            slope_urad_per_mm: 10.0,
            period_um: 4000.0,
            sin_urad: vec![20.0],
            cos_urad: vec![5.0],
            arm_x_um: None,
            arm_y_um: None,
            arm_z_um: None,
            carries_other_axis: false,
        }
    }

    #[test]
    fn a_lower_carriage_yaw_grows_with_the_carried_axis() {
        // Yaw of the y carriage carrying x: dy = θ(y)·(arm_x + x).
        let mut c = cfg(Axis::Y, Rotation::Yaw);
        c.arm_x_um = Some(1000.0);
        c.carries_other_axis = true;
        let t = AngularTerm::new("y_yaw", c.clone()).unwrap();
        let at = |x: f64, y: f64| t.contribution(&MotionState::at_rest(x, y));
        let (_, theta) = t.angle_basis(2500.0);
        assert!(theta.abs() > 1e-6);
        let near = at(0.0, 2500.0);
        let far = at(8000.0, 2500.0);
        assert!((near[1] - theta * 1000.0).abs() < 1e-12);
        assert!((far[1] - theta * 9000.0).abs() < 1e-12);
        // Not separable: the y error's change with y depends on x.
        let d_near = at(0.0, 2500.0)[1] - at(0.0, 0.0)[1];
        let d_far = at(8000.0, 2500.0)[1] - at(8000.0, 0.0)[1];
        assert!((d_far - 9.0 * d_near).abs() < 1e-9);
        // The jacobian still matches the numeric one.
        let s = MotionState::at_rest(5000.0, 1200.0);
        let a = t.jacobian(&s);
        let n = numeric_jacobian(&t, &s);
        for (p, q) in a.iter().zip(&n) {
            assert!((p[0] - q[0]).abs() < 1e-6 && (p[1] - q[1]).abs() < 1e-6);
        }
        // Round trip keeps the flag; a pitch refuses it.
        let back = AngularTerm::new("y_yaw", t.cfg.clone()).unwrap();
        assert_eq!(back, t);
        let mut p = cfg(Axis::Y, Rotation::Pitch);
        p.carries_other_axis = true;
        assert!(AngularTerm::new("y_pitch", p).is_err());
    }

    #[test]
    fn pitch_of_x_with_height_moves_x() {
        let mut c = cfg(Axis::X, Rotation::Pitch);
        c.arm_z_um = Some(20_000.0);
        let t = AngularTerm::new("p", c).unwrap();
        // x = 1000 µm: θ = 10 µrad + 20·sin(π/2) + 5·(cos(π/2) − 1) = 25 µrad.
        // 25e-6 · 20 000 µm = 0.5 µm along +x.
        let d = t.contribution(&MotionState::at_rest(1000.0, 0.0));
        assert!((d[0] - 0.5).abs() < 1e-12 && d[1].abs() < 1e-15, "{d:?}");
        assert_eq!(t.contribution(&MotionState::at_rest(0.0, 0.0)), [0.0, 0.0]);
    }

    #[test]
    fn yaw_of_y_with_arms() {
        let mut c = cfg(Axis::Y, Rotation::Yaw);
        c.sin_urad.clear();
        c.cos_urad.clear();
        c.arm_x_um = Some(10_000.0);
        c.arm_y_um = Some(-5_000.0);
        let t = AngularTerm::new("yy", c).unwrap();
        // y = 2000 µm: θ = 20 µrad. (−θ·r_y, θ·r_x) = (0.1, 0.2) µm.
        let d = t.contribution(&MotionState::at_rest(0.0, 2000.0));
        assert!(
            (d[0] - 0.1).abs() < 1e-12 && (d[1] - 0.2).abs() < 1e-12,
            "{d:?}"
        );
    }

    /// The yaw the term reports is the angle whose rotation about the
    /// centre (tool point − arm) gives its displacement; a pitch turns no
    /// pattern in the plane.
    #[test]
    fn a_yaw_reports_its_angle_and_a_pitch_none() {
        let mut c = cfg(Axis::X, Rotation::Yaw);
        c.arm_x_um = Some(3000.0);
        c.arm_y_um = Some(-7000.0);
        let t = AngularTerm::new("xy", c.clone()).unwrap();
        let s = MotionState::at_rest(2500.0, 400.0);
        let yaw = t.yaw_rad(&s);
        let (_, theta) = t.angle_basis(2500.0);
        assert!(yaw.abs() > 1e-6 && yaw == theta, "{yaw}");
        // ẑ × (3000, −7000) = (7000, 3000): +x towards +y.
        let d = t.contribution(&s);
        assert!((d[0] - yaw * 7000.0).abs() < 1e-12 && (d[1] - yaw * 3000.0).abs() < 1e-12);
        let mut p = cfg(Axis::X, Rotation::Pitch);
        p.arm_z_um = Some(1000.0);
        let t = AngularTerm::new("xp", p).unwrap();
        assert!(t.contribution(&s)[0] != 0.0);
        assert_eq!(t.yaw_rad(&s), 0.0);
    }

    #[test]
    fn pitch_and_roll_signs() {
        let mut c = cfg(Axis::Y, Rotation::Pitch);
        c.sin_urad.clear();
        c.cos_urad.clear();
        c.arm_z_um = Some(1000.0);
        let t = AngularTerm::new("yp", c.clone()).unwrap();
        // θ = 10 µrad at 1 mm; about +x: y displacement −θ·r_z = −0.01 µm.
        let d = t.contribution(&MotionState::at_rest(0.0, 1000.0));
        assert!((d[1] + 0.01).abs() < 1e-12 && d[0] == 0.0, "{d:?}");
        c.rotation = Rotation::Roll;
        let t = AngularTerm::new("yr", c).unwrap();
        // Roll of y is about +y: x displacement +θ·r_z.
        let d = t.contribution(&MotionState::at_rest(0.0, 1000.0));
        assert!((d[0] - 0.01).abs() < 1e-12 && d[1] == 0.0, "{d:?}");
    }

    #[test]
    fn wrong_arm_is_rejected_by_name() {
        let mut c = cfg(Axis::X, Rotation::Pitch);
        c.arm_y_um = Some(1.0);
        let e = AngularTerm::new("p", c).unwrap_err().to_string();
        assert!(e.contains("arm_y_um"), "{e}");
    }

    #[test]
    fn jacobian_is_exact() {
        let mut c = cfg(Axis::X, Rotation::Yaw);
        c.arm_x_um = Some(3000.0);
        c.arm_y_um = Some(12_000.0);
        let t = AngularTerm::new("y", c).unwrap();
        let s = MotionState::at_rest(3333.0, 100.0);
        let e = t.jacobian(&s);
        let n = numeric_jacobian(&t, &s);
        assert_eq!(e.len(), t.params().len());
        for (a, b) in e.iter().zip(&n) {
            for k in 0..2 {
                assert!(
                    (a[k] - b[k]).abs() < 1e-6 * (1.0 + a[k].abs()),
                    "{e:?} {n:?}"
                );
            }
        }
    }
}
