//! The simulated rig: ONE stage error model shared by both controllers, and
//! the mounting of the pattern on the platform.
//!
//! Why shared: the stage model is 2-D (squareness, cross coupling: the X
//! error depends on Y) and has history (play, settling noise), so the two
//! C-863s cannot each own a per-axis model. Each controller reports its
//! actuator trajectory through the [`Platform`] seam
//! ([`Platform::actuator_path`]); the [`Rig`] keeps both paths and commits a
//! move to the [`StageSimulator`] (`move_axis`) at the moment the carriage
//! stops, in time order across both axes, and evaluates positions during
//! travel with `preview`. Time only moves forward: between events the model
//! `wait`s, so thermal drift follows simulated time.
//!
//! # Frames and signs
//! - *stage frame* (µm): the model's frame; the commanded position of an
//!   axis is its actuator position (after referencing, actuator µm = encoder
//!   µm = `POS?`·1000). `true_um` = where the platform really is;
//!   `observed_um` = true + observation terms (optics drift).
//! - *pattern frame* (µm, see `micropos::pattern`): the camera is fixed, the
//!   pattern moves with the platform. The pattern point under the image
//!   centre is `P = offset − R(θ)·observed_um` with
//!   `R(θ) = [[cos θ, sin θ], [−sin θ, cos θ]]`: a platform move of +d along
//!   stage x moves the point under the centre by d *against* the pattern
//!   direction of stage +x. θ is the mounting angle, equal to the decoder's
//!   `theta_rad` (angle from image +x to pattern +x, towards image +y)
//!   because the camera's image axes are the stage axes (not mirrored).
//! - *platform yaw* φ (rad; reported in µrad): the stage model's
//!   [`StageModel::platform_yaw_rad`], the yaw terms of both carriages
//!   summed, right-handed about +z (+x towards +y). The platform turns the
//!   pattern with it, so the camera renders it at θ + φ and the decoder
//!   reads `theta_rad` = mounting angle + φ. The turn is about the
//!   carriages' rotation centres, and what it does to the point under the
//!   camera is already in `observed_um` (the yaw terms' displacement
//!   φ·(ẑ × arm) of that point): the pattern point under the image centre
//!   stays `P` above, and the image turns about it. Pitch and roll tilt the
//!   platform out of the plane; the in-plane pattern sees only the
//!   displacement they cause.
//! - *tool point* (`[tool] offset_um` of the rig file): a point fixed on the
//!   platform at that offset from the point the model follows (the one
//!   under the camera), in the platform's own frame (the stage axes when the
//!   platform is not turned). Its truth is `true_um + R_z(φ)·offset`: the
//!   platform is rigid, so the offset turns with it.

use crate::controller::{ActuatorPath, Platform};
use micropos::model::{Axis, ModelError, MotionState, SimStep, StageModel, StageSimulator};
use serde::{Deserialize, Serialize};
use std::path::Path;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

/// How the pattern is fixed on the end platform.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Mounting {
    /// Mounting angle θ, degrees (see the module docs). Unknown to micropos.
    pub theta_deg: f64,
    /// Pattern point under the image centre when the platform is at stage
    /// (0, 0), µm. The default (12100, 12100) puts stage x, y ∈ ≈[−80, 11890]
    /// µm inside a 10-bit 4 µm pattern (12384 µm) with the whole view on the
    /// pattern; beyond, frames do not decode (errors, not wrong numbers).
    pub offset_um: [f64; 2],
}

impl Default for Mounting {
    fn default() -> Self {
        Self {
            theta_deg: 0.3,
            offset_um: [12100.0, 12100.0],
        }
    }
}

impl Mounting {
    fn rot(&self) -> (f64, f64) {
        self.theta_deg.to_radians().sin_cos()
    }

    /// Pattern point under the image centre for a platform at `stage_um`.
    pub fn pattern_point(&self, stage_um: [f64; 2]) -> [f64; 2] {
        let (s, c) = self.rot();
        let [x, y] = stage_um;
        [
            self.offset_um[0] - (c * x + s * y),
            self.offset_um[1] - (-s * x + c * y),
        ]
    }

    /// The platform position (stage frame) that puts `pattern_um` under the
    /// image centre (inverse of [`Mounting::pattern_point`]).
    pub fn stage_point(&self, pattern_um: [f64; 2]) -> [f64; 2] {
        let (s, c) = self.rot();
        let d = [
            self.offset_um[0] - pattern_um[0],
            self.offset_um[1] - pattern_um[1],
        ];
        [c * d[0] - s * d[1], s * d[0] + c * d[1]]
    }
}

/// Ground truth of the rig at one instant.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct RigTruth {
    /// Simulated time, s.
    pub sim_time_s: f64,
    /// Where the platform really is (stage frame), µm.
    pub true_um: [f64; 2],
    /// Where the camera sees it (stage frame, true + observation terms), µm.
    pub observed_stage_um: [f64; 2],
    /// Pattern point under the image centre, as the camera decodes it, µm.
    pub observed_pattern_um: [f64; 2],
    /// The platform's yaw φ, µrad (module docs: the model's yaw terms,
    /// right-handed about +z): with `true_um`, the platform pose (x, y, θ).
    /// The decoder reads the mounting angle plus this.
    pub platform_yaw_urad: f64,
    /// Where the configured tool point really is (stage frame, µm:
    /// `true_um + R_z(φ)·offset`), if the rig file names one.
    pub tool_um: Option<[f64; 2]>,
    /// Actuator positions, µm.
    pub actuator_um: [f64; 2],
    /// Whether either axis is travelling.
    pub moving: bool,
}

#[derive(Debug)]
struct RigState {
    sim: StageSimulator,
    paths: [ActuatorPath; 2],
    /// Whether the end of `paths[i]` is in the model already.
    committed: [bool; 2],
    model_time_s: f64,
}

/// The shared rig (see the module docs). Cheap to share: `Arc<Rig>`.
#[derive(Debug)]
pub struct Rig {
    state: Mutex<RigState>,
    mounting: Mounting,
    tool: ToolConfig,
}

fn rest(actuator_mm: f64) -> ActuatorPath {
    ActuatorPath {
        offset_mm: actuator_mm,
        profile: None,
        rest_encoder_mm: 0.0,
    }
}

fn axis_of(i: usize) -> Axis {
    if i == 0 {
        Axis::X
    } else {
        Axis::Y
    }
}

impl Rig {
    /// A rig running `model`, both carriages at rest at `initial_actuator_mm`
    /// (power-up positions). `seed` fixes the model's settling noise.
    pub fn new(
        model: StageModel,
        seed: u64,
        initial_actuator_mm: [f64; 2],
        mounting: Mounting,
    ) -> Result<Rig, ModelError> {
        let start = MotionState::at_rest(
            initial_actuator_mm[0] * 1000.0,
            initial_actuator_mm[1] * 1000.0,
        );
        let sim = StageSimulator::new(model, start, seed)?;
        Ok(Rig {
            state: Mutex::new(RigState {
                sim,
                paths: [rest(initial_actuator_mm[0]), rest(initial_actuator_mm[1])],
                committed: [true, true],
                model_time_s: 0.0,
            }),
            mounting,
            tool: ToolConfig::default(),
        })
    }

    /// The same rig with a tool point (`[tool]` of the rig file) whose truth
    /// [`Rig::truth`] reports.
    pub fn with_tool(mut self, tool: ToolConfig) -> Rig {
        self.tool = tool;
        self
    }

    /// The leadscrew periods of the stage model this rig runs, µm (one per
    /// `leadscrew_cyclic` term): what a plan's step must resolve, so a
    /// report can say when it did not.
    pub fn lead_periods_um(&self) -> Vec<f64> {
        let st = self.lock();
        st.sim
            .model()
            .params()
            .into_iter()
            .filter(|p| {
                p.kind == micropos::model::terms::cyclic::LEADSCREW_KIND
                    && p.info.name == "period_um"
            })
            .map(|p| p.info.value)
            .collect()
    }

    /// The pattern mounting.
    pub fn mounting(&self) -> &Mounting {
        &self.mounting
    }

    fn lock(&self) -> MutexGuard<'_, RigState> {
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// The platform of one axis, to install in its controller.
    pub fn platform(self: &Arc<Self>, axis: Axis) -> Box<dyn Platform> {
        Box::new(RigAxis {
            rig: self.clone(),
            axis,
        })
    }

    /// A new trajectory of `axis`, planned at `now`.
    pub fn set_path(&self, axis: Axis, path: &ActuatorPath, now: Duration) {
        let mut st = self.lock();
        let t = now.as_secs_f64();
        st.catch_up(t);
        let i = axis.index();
        let same_rest = path.profile.is_none()
            && (st.paths[i].final_actuator_mm() - path.final_actuator_mm()).abs() < 1e-12
            && st.committed[i];
        st.paths[i] = path.clone();
        if same_rest {
            return;
        }
        // Interrupted travel (a new MOV, HLT, STP) is never committed: only
        // where the carriage finally stops goes into the model's history.
        st.committed[i] = false;
        if path.profile.is_none() || path.end_time().is_some_and(|e| e <= now) {
            st.commit(i, t);
        }
    }

    /// Actuator positions at `now`, µm, from the planned paths alone: no
    /// model evaluation, so it never moves the model's time (the camera
    /// asks it for the end of an exposure before rendering its middle).
    pub fn actuator_um(&self, now: Duration) -> [f64; 2] {
        let st = self.lock();
        [
            st.paths[0].actuator_mm(now) * 1000.0,
            st.paths[1].actuator_mm(now) * 1000.0,
        ]
    }

    /// Ground truth at `now`.
    pub fn truth(&self, now: Duration) -> RigTruth {
        let t = now.as_secs_f64();
        let mut st = self.lock();
        st.catch_up(t);
        let actuator_um = [
            st.paths[0].actuator_mm(now) * 1000.0,
            st.paths[1].actuator_mm(now) * 1000.0,
        ];
        let moving = !(st.committed[0] && st.committed[1]);
        let step: Result<SimStep, ModelError> = if moving {
            st.sim.preview(actuator_um[0], actuator_um[1], t)
        } else {
            Ok(st.sim.current())
        };
        let (true_um, observed_stage_um, yaw_rad) = match step {
            Ok(s) => (
                [s.true_um.x_um, s.true_um.y_um],
                [s.observed_um.x_um, s.observed_um.y_um],
                st.sim.model().platform_yaw_rad(&s.state),
            ),
            Err(e) => {
                tracing::warn!("stage model: {e}");
                ([f64::NAN; 2], [f64::NAN; 2], f64::NAN)
            }
        };
        let tool_um = self.tool.offset_um.map(|[ox, oy]| {
            let (s, c) = yaw_rad.sin_cos();
            [true_um[0] + c * ox - s * oy, true_um[1] + s * ox + c * oy]
        });
        RigTruth {
            sim_time_s: t,
            true_um,
            observed_stage_um,
            observed_pattern_um: self.mounting.pattern_point(observed_stage_um),
            platform_yaw_urad: yaw_rad * 1e6,
            tool_um,
            actuator_um,
            moving,
        }
    }
}

impl RigState {
    fn commit(&mut self, i: usize, at_s: f64) {
        let t = at_s.max(self.model_time_s);
        let target = self.paths[i].final_actuator_mm() * 1000.0;
        match self.sim.move_axis(axis_of(i), target, t, 0) {
            Ok(_) => self.model_time_s = t,
            Err(e) => tracing::warn!("stage model refused a move of axis {i}: {e}"),
        }
        self.committed[i] = true;
    }

    /// Commits every move that has ended by `t` (in time order), then lets
    /// the model wait until `t`.
    fn catch_up(&mut self, t: f64) {
        loop {
            let next = (0..2)
                .filter(|&i| !self.committed[i])
                .filter_map(|i| {
                    self.paths[i]
                        .end_time()
                        .map(|e| (i, e.as_secs_f64()))
                        .filter(|&(_, e)| e <= t)
                })
                .min_by(|a, b| a.1.total_cmp(&b.1));
            match next {
                Some((i, e)) => self.commit(i, e),
                None => break,
            }
        }
        if t > self.model_time_s {
            match self.sim.wait(t) {
                Ok(_) => self.model_time_s = t,
                Err(e) => tracing::warn!("stage model: {e}"),
            }
        }
    }
}

/// One axis's view of the shared rig, installed in its controller.
#[derive(Debug)]
pub struct RigAxis {
    rig: Arc<Rig>,
    axis: Axis,
}

impl Platform for RigAxis {
    fn platform_position_mm(&self, _actuator_mm: f64, now: Duration) -> f64 {
        self.rig.truth(now).true_um[self.axis.index()] / 1000.0
    }

    fn actuator_path(&mut self, path: &ActuatorPath, now: Duration) {
        self.rig.set_path(self.axis, path, now);
    }
}

/// The rig file (`config/sim-rig.toml`): which stage model, how the pattern
/// is mounted, what the camera is. Every key optional (defaults: the
/// paper's rig); unknown keys are errors.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RigConfig {
    /// Stage model file, relative to the rig file; none = the paper default
    /// (`config/stage-model.toml`, compiled in).
    pub model: Option<std::path::PathBuf>,
    /// Pattern mounting.
    pub mounting: Mounting,
    /// Simulated camera.
    pub camera: crate::camera::config::CameraConfig,
    /// The controllers' servo loops.
    pub servo: ServoConfig,
    /// A tool point on the platform whose truth is reported.
    pub tool: ToolConfig,
}

/// A tool point on the platform (`[tool]` of the rig file): reported in the
/// ground truth (`RigTruth::tool_um`, the control socket's `tool_*_um`), so
/// a test can check a position away from the point the camera watches,
/// where the platform's yaw adds `φ × offset`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ToolConfig {
    /// Offset from the point the camera watches (the model's observed
    /// point) to the tool point, in the platform's frame (the stage axes
    /// when the platform is not turned), µm; none (the default) = no tool
    /// point. Finite, |v| ≤ [`MAX_TOOL_OFFSET_UM`].
    pub offset_um: Option<[f64; 2]>,
}

/// Largest tool offset accepted, µm per axis: 1 m, far beyond any point on
/// a microscope stage's platform, so a typo in units (nm for µm) is caught.
pub const MAX_TOOL_OFFSET_UM: f64 = 1e6;

/// The controllers' servo loops (`[servo]` of the rig file).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ServoConfig {
    /// Following-error time constant τ = 1/Kv, ms: at velocity `v` the
    /// encoder (what `POS?` reports) and with it the carriage trail the
    /// commanded trajectory by `v·τ` (0.24 µm at 120 µm/s for the default
    /// 2 ms), as a velocity-gain servo does. Why it is modelled: a sweep
    /// characterization that placed frames on the *commanded* trajectory
    /// would read the lag as camera delay; micropos places them on the
    /// sampled `POS?` positions, which contain it. 0..=20; 0 = none.
    pub following_lag_ms: f64,
}

impl Default for ServoConfig {
    fn default() -> Self {
        ServoConfig {
            following_lag_ms: 2.0,
        }
    }
}

impl RigConfig {
    /// Parses a rig file; a relative `model` path is resolved against
    /// `base_dir` (the file's directory).
    pub fn from_toml(text: &str, base_dir: Option<&Path>) -> Result<RigConfig, String> {
        let mut c: RigConfig = toml::from_str(text).map_err(|e| e.to_string())?;
        if let (Some(m), Some(b)) = (&c.model, base_dir) {
            if m.is_relative() {
                c.model = Some(b.join(m));
            }
        }
        c.validate()?;
        Ok(c)
    }

    /// Reads and parses a rig file.
    pub fn load(path: &Path) -> Result<RigConfig, String> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| format!("read rig file {}: {e}", path.display()))?;
        Self::from_toml(&text, path.parent())
            .map_err(|e| format!("rig file {}: {e}", path.display()))
    }

    /// Checks mounting and camera.
    pub fn validate(&self) -> Result<(), String> {
        let m = &self.mounting;
        if !(m.theta_deg.is_finite() && m.theta_deg.abs() <= 45.0) {
            return Err(format!(
                "mounting.theta_deg = {}: must be within ±45°",
                m.theta_deg
            ));
        }
        if !m.offset_um.iter().all(|v| v.is_finite() && v.abs() < 1e7) {
            return Err(format!(
                "mounting.offset_um = {:?}: must be finite, |v| < 1e7 µm",
                m.offset_um
            ));
        }
        if let Some(o) = self.tool.offset_um {
            if !o
                .iter()
                .all(|v| v.is_finite() && v.abs() <= MAX_TOOL_OFFSET_UM)
            {
                return Err(format!(
                    "tool.offset_um = {o:?}: must be finite, |v| ≤ {MAX_TOOL_OFFSET_UM} µm"
                ));
            }
        }
        let lag = self.servo.following_lag_ms;
        if !(lag.is_finite() && (0.0..=20.0).contains(&lag)) {
            return Err(format!(
                "servo.following_lag_ms = {lag}: must be within 0..=20"
            ));
        }
        self.camera.validate()
    }
}

/// Loads a stage model file (`None`: the paper default).
pub fn load_model(path: Option<&Path>) -> Result<StageModel, String> {
    match path {
        None => StageModel::paper_default().map_err(|e| format!("paper default model: {e}")),
        Some(p) => {
            let text = std::fs::read_to_string(p)
                .map_err(|e| format!("read model file {}: {e}", p.display()))?;
            StageModel::from_toml(&text).map_err(|e| format!("model file {}: {e}", p.display()))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_shipped_rig_file_is_the_default() {
        let text = include_str!("../../config/sim-rig.toml");
        let base = Path::new(env!("CARGO_MANIFEST_DIR")).join("../config");
        let c = RigConfig::from_toml(text, Some(&base)).unwrap();
        assert_eq!(c.mounting, Mounting::default());
        assert_eq!(c.camera, crate::camera::config::CameraConfig::default());
        assert_eq!(c.servo, ServoConfig::default());
        assert_eq!(c.tool, ToolConfig::default());
        let m = load_model(c.model.as_deref()).unwrap();
        assert_eq!(
            m.to_toml().unwrap(),
            StageModel::paper_default().unwrap().to_toml().unwrap()
        );
        let e = RigConfig::from_toml("[camera]\nfps = -1\n", None).unwrap_err();
        assert!(e.contains("camera.fps"), "{e}");
        let e = RigConfig::from_toml("[mounting]\ntheta = 1\n", None).unwrap_err();
        assert!(e.contains("theta"), "{e}");
        let e = RigConfig::from_toml("[servo]\nfollowing_lag_ms = -1\n", None).unwrap_err();
        assert!(e.contains("servo.following_lag_ms"), "{e}");
        assert_eq!(c.tool.offset_um, None);
        let t = RigConfig::from_toml("[tool]\noffset_um = [1500.0, -20.5]\n", None).unwrap();
        assert_eq!(t.tool.offset_um, Some([1500.0, -20.5]));
        for bad in ["[2e6, 0.0]", "[0.0, nan]", "[1.0]", "\"x\""] {
            let e =
                RigConfig::from_toml(&format!("[tool]\noffset_um = {bad}\n"), None).unwrap_err();
            assert!(e.contains("offset_um"), "{bad}: {e}");
        }
        let e = RigConfig::from_toml("[tool]\noffset = [1.0, 2.0]\n", None).unwrap_err();
        assert!(e.contains("offset"), "{e}");
    }

    /// The platform pose: the model's yaw in µrad, and a tool point that
    /// turns with the platform about the watched point.
    #[test]
    fn the_truth_reports_the_platform_yaw_and_the_tool_point() {
        let model = StageModel::paper_default().unwrap();
        let at = MotionState::at_rest(9000.0, 3000.0);
        let yaw = model.platform_yaw_rad(&at);
        let rig = Rig::new(model, 1, [9.0, 3.0], Mounting::default())
            .unwrap()
            .with_tool(ToolConfig {
                offset_um: Some([0.0, 50_000.0]),
            });
        let t = rig.truth(Duration::ZERO);
        assert!(yaw.abs() > 10e-6, "{yaw}");
        assert!((t.platform_yaw_urad - yaw * 1e6).abs() < 1e-9, "{t:?}");
        let tool = t.tool_um.unwrap();
        // A positive yaw moves a point at +y from the watched one towards −x.
        assert!((tool[0] - (t.true_um[0] - yaw.sin() * 50_000.0)).abs() < 1e-9);
        assert!((tool[1] - (t.true_um[1] + yaw.cos() * 50_000.0)).abs() < 1e-9);
        let plain = Rig::new(StageModel::ideal(), 1, [9.0, 3.0], Mounting::default()).unwrap();
        let t = plain.truth(Duration::ZERO);
        assert_eq!((t.platform_yaw_urad, t.tool_um), (0.0, None));
    }

    #[test]
    fn mounting_round_trips_and_moves_against_the_platform() {
        let m = Mounting::default();
        let p0 = m.pattern_point([0.0, 0.0]);
        assert_eq!(p0, m.offset_um);
        let p1 = m.pattern_point([100.0, 0.0]);
        // +100 µm of platform x: the point under the centre moves ≈ −100 µm
        // along pattern x, and by +sin θ·100 along pattern y.
        assert!((p1[0] - p0[0] + 100.0 * 0.3f64.to_radians().cos()).abs() < 1e-9);
        assert!((p1[1] - p0[1] - 100.0 * 0.3f64.to_radians().sin()).abs() < 1e-9);
        let s = m.stage_point(m.pattern_point([1234.5, -678.9]));
        assert!((s[0] - 1234.5).abs() < 1e-9 && (s[1] + 678.9).abs() < 1e-9);
    }

    #[test]
    fn moves_commit_when_they_end_and_travel_is_previewed() {
        use crate::motion::{Limits, Profile};
        let rig =
            Arc::new(Rig::new(StageModel::ideal(), 1, [7.5, 7.5], Mounting::default()).unwrap());
        let lim = Limits {
            velocity: 1.0,
            acceleration: 10.0,
            deceleration: 10.0,
        };
        let p = Profile::plan(Duration::ZERO, 7.5, 0.0, 8.5, lim);
        let end = p.end_time();
        let path = ActuatorPath {
            offset_mm: 0.0,
            profile: Some(p),
            rest_encoder_mm: 7.5,
        };
        rig.set_path(Axis::X, &path, Duration::ZERO);
        let mid = rig.truth(end / 2);
        assert!(mid.moving);
        assert!((mid.true_um[0] - 8000.0).abs() < 1.0, "{mid:?}");
        let done = rig.truth(end + Duration::from_millis(1));
        assert!(!done.moving);
        assert!((done.true_um[0] - 8500.0).abs() < 1e-9);
        assert!((done.true_um[1] - 7500.0).abs() < 1e-9);
    }
}
