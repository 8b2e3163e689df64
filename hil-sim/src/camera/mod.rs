//! The simulated microscope camera: renders the Megarena pattern at the
//! platform's observed pose, on the rig's simulated clock.
//!
//! Timing (contract): a grab at simulated time `now` starts its exposure at
//! the next frame slot `max(now, last_start + 1/fps)`, exposes for
//! `exposure_us` and is rendered at the exposure mid-point; the clock is
//! advanced to the end of the exposure, so a grab costs frame time as on a
//! real camera. On a clock that does not advance on request (the in-process
//! rig's virtual clock) the frame is rendered at once and
//! [`SimCamera::ready_after`] says how long the caller must let pass before
//! it exists.
//!
//! Motion blur (contract): a grab integrates the pattern over its exposure
//! window: the frame's optical image is the mean of the pattern's images at
//! `n` equally spaced instants of the exposure, `n` odd and chosen so that
//! consecutive instants are at most a quarter pixel apart on the pattern
//! (`n` = 1, the mid-point alone, for a still platform: a still frame is
//! the sharp render, bit for bit), and the sensor (shading, noise,
//! quantisation) sees that mean once. Each dot is placed once, at its
//! position at the mid-point, with the frame's blurred stamp for its
//! sub-pixel phase: the mean of the dot's sharp stamps at every instant,
//! each instant's displacement from the mid-point rounded to 1/32 px, the
//! stamps' grid ([`fast::FastRenderer::render_path`]). Up to that rounding
//! and the order of float sums, this is the mean of the instants'
//! renders: a pixel differs from placing every instant's dots on their own
//! ([`fast::FastRenderer::render_path_per_instant`]) by a few codes at
//! most and by nothing on average. Why: a sweep frame then costs about
//! what a still frame does, not `n` dot passes. Motion of more than 16 px
//! from the mid-point within one exposure is placed instant by instant.
//! The truth reported with the frame is the one at the mid-point.
//!
//! Yaw (contract): the frame shows the pattern turned by the platform's
//! yaw at the exposure's mid-point (`RigTruth::platform_yaw_urad`, the
//! stage model's yaw terms), so the decoded θ is the mounting angle plus
//! that yaw; the pattern points of the path are the model's, whose yaw
//! terms already move the watched point as the turn about the carriages'
//! rotation centres does. Pitch and roll, out of the plane, show only as
//! that displacement.
//!
//! Timestamps (contract): a grabbed frame is stamped with the exposure
//! mid-point plus the fixed latency `latency_us` plus Gaussian jitter of σ
//! `timestamp_jitter_us`, drawn from the frame's noise seed (so a seed gives
//! the same stamps). micropos is not told the latency: the sweep
//! characterization estimates it. [`SimCamera::render_now`] (the GigE
//! server's free-running frames) exposes over the time before the fill and
//! is stamped the same way; the GigE server then puts the stamp on the
//! camera's own clock (`CameraConfig::camera_clock_ns`).
//!
//! Faults (contract): [`CameraMode::Stall`] (no answer: the socket server
//! drops the request, the in-process source times out), [`CameraMode::Garbage`]
//! (undecodable frames: blank and noise frames alternate).
//!
//! Beyond the pattern (10-bit, 4 µm: 12384 µm square) the frame shows part or
//! none of the dots and the decoder reports an error; it never yields a
//! position from outside the pattern.

pub mod config;
pub mod fast;
#[cfg(feature = "genicam")]
pub mod gige;
pub mod server;

use crate::clock::Clock;
use crate::rig::{Rig, RigTruth};
pub use config::CameraConfig;
use fast::FastRenderer;
use micropos::camera::{CameraError, CameraInfo, FrameClock, FrameSource};
use micropos::frame::Frame;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

/// Camera fault mode (contract: `{"camera":"stall"|"garbage"|"normal"}`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum CameraMode {
    /// Frames of the pattern.
    #[default]
    Normal,
    /// Grabs are never answered.
    Stall,
    /// Undecodable frames (blank and noise, alternating).
    Garbage,
}

/// One delivered frame with the truth it was rendered from.
#[derive(Debug, Clone)]
pub struct Grab {
    /// The frame (timestamp = exposure mid-point + latency + jitter,
    /// simulated s; see the module docs).
    pub frame: Frame,
    /// The rig's ground truth at the exposure mid-point.
    pub truth: RigTruth,
}

/// Why a grab gave no frame.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum GrabError {
    /// The camera is stalled (fault injection).
    #[error("camera stalled (fault injected)")]
    Stalled,
    /// Rendering failed.
    #[error("render: {0}")]
    Render(String),
}

#[derive(Debug)]
struct CameraState {
    renderer: FastRenderer,
    last_start_s: Option<f64>,
    /// From the last grab's request to the end of its exposure.
    ready_after: Duration,
    sequence: u64,
    mode: CameraMode,
    seed: u64,
}

/// The camera, shared between the socket server and in-process users.
#[derive(Debug)]
pub struct SimCamera {
    state: Mutex<CameraState>,
    rig: Arc<Rig>,
    clock: Arc<dyn Clock>,
}

impl SimCamera {
    /// A camera looking at the rig's pattern, on `clock`. `seed` seeds the
    /// per-frame noise.
    pub fn new(
        cfg: &CameraConfig,
        rig: Arc<Rig>,
        clock: Arc<dyn Clock>,
        seed: u64,
    ) -> Result<SimCamera, String> {
        let renderer = FastRenderer::new(cfg, rig.mounting().theta_deg.to_radians())?;
        Ok(SimCamera {
            state: Mutex::new(CameraState {
                renderer,
                last_start_s: None,
                ready_after: Duration::ZERO,
                sequence: 0,
                mode: CameraMode::Normal,
                seed,
            }),
            rig,
            clock,
        })
    }

    fn lock(&self) -> MutexGuard<'_, CameraState> {
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// The configuration.
    pub fn config(&self) -> CameraConfig {
        self.lock().renderer.config().clone()
    }

    /// Sets the fault mode.
    pub fn set_mode(&self, mode: CameraMode) {
        self.lock().mode = mode;
    }

    /// The fault mode.
    pub fn mode(&self) -> CameraMode {
        self.lock().mode
    }

    /// Takes one frame (see the module docs for timing).
    pub fn grab(&self) -> Result<Grab, GrabError> {
        let mut st = self.lock();
        if st.mode == CameraMode::Stall {
            return Err(GrabError::Stalled);
        }
        let cfg = st.renderer.config().clone();
        let now = self.clock.now().as_secs_f64();
        let period = 1.0 / cfg.fps;
        let start = match st.last_start_s {
            Some(l) => now.max(l + period),
            None => now,
        };
        let exposure = cfg.exposure_us * 1e-6;
        let end = start + exposure;
        let wait = Duration::try_from_secs_f64((end - now).max(0.0)).unwrap_or_default();
        if self.clock.advances_on_request() {
            self.clock.advance(wait);
        }
        st.ready_after = wait;
        st.last_start_s = Some(start);
        let mid = start + exposure / 2.0;
        let samples = self.blur_samples(&cfg, start, end);
        self.render_locked(&mut st, &cfg, mid, exposure, samples, None)
    }

    /// How many instants of the exposure `[start_s, end_s]` the frame
    /// averages (see the module docs): odd, consecutive instants at most a
    /// quarter pixel apart, at most [`MAX_BLUR_SAMPLES`].
    fn blur_samples(&self, cfg: &CameraConfig, start_s: f64, end_s: f64) -> usize {
        let at = |t: f64| Duration::try_from_secs_f64(t.max(0.0)).unwrap_or_default();
        let a = self.rig.actuator_um(at(start_s));
        let b = self.rig.actuator_um(at(end_s));
        let travel_um = (b[0] - a[0]).hypot(b[1] - a[1]);
        if !travel_um.is_finite() {
            return 1;
        }
        let n = (travel_um / (cfg.pixel_um / 4.0)).ceil().max(1.0) as usize;
        (n | 1).min(MAX_BLUR_SAMPLES)
    }

    /// From the last [`SimCamera::grab`]'s request to the end of its
    /// exposure, when the clock does not advance on request (the in-process
    /// rig's virtual clock): the time the caller must let pass before the
    /// frame exists. `None` when the grab advanced the clock itself.
    pub fn ready_after(&self) -> Option<Duration> {
        (!self.clock.advances_on_request()).then(|| self.lock().ready_after)
    }

    /// Fills a free-running camera's frame at the clock's current time: the
    /// exposure ended now (a frame is read out after it), so the frame
    /// integrates the pattern over the `exposure_us` before now (motion
    /// blur as for [`SimCamera::grab`]) and is stamped with its mid-point
    /// plus latency and jitter; the clock is not advanced. For a camera
    /// paced by wall time (the GigE Vision server), whose frames observe
    /// the rig rather than drive its clock. `sensor` is what the client set
    /// (exposure, gain); `None` renders at the rig's configured exposure
    /// and unity gain.
    pub fn render_now(&self, sensor: Option<SensorSettings>) -> Result<Grab, GrabError> {
        let mut st = self.lock();
        if st.mode == CameraMode::Stall {
            return Err(GrabError::Stalled);
        }
        let cfg = st.renderer.config().clone();
        let end = self.clock.now().as_secs_f64();
        let exposure = sensor.map_or(cfg.exposure_us, |s| s.exposure_us) * 1e-6;
        let start = (end - exposure).max(0.0);
        let samples = self.blur_samples(&cfg, start, end);
        self.render_locked(
            &mut st,
            &cfg,
            (start + end) / 2.0,
            end - start,
            samples,
            sensor,
        )
    }

    /// Renders the truth over an exposure of `exposure_s` centred on
    /// simulated time `mid` (mode: normal or garbage), blurred over
    /// `samples` instants and stamped with latency and jitter (module docs).
    fn render_locked(
        &self,
        st: &mut CameraState,
        cfg: &CameraConfig,
        mid: f64,
        exposure_s: f64,
        samples: usize,
        sensor: Option<SensorSettings>,
    ) -> Result<Grab, GrabError> {
        let at = |t: f64| Duration::try_from_secs_f64(t.max(0.0)).unwrap_or_default();
        st.sequence += 1;
        let seq = st.sequence;
        let noise_seed = st.seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) ^ seq;
        // The instants of the exposure in time order (the rig's model only
        // moves forward); the mid-point's truth is the frame's truth.
        let n = samples.max(1);
        let mut truth = None;
        let mut path = Vec::with_capacity(n);
        for k in 0..n {
            let t = if 2 * k + 1 == n {
                mid
            } else {
                mid + ((k as f64 + 0.5) / n as f64 - 0.5) * exposure_s
            };
            let tr = self.rig.truth(at(t));
            if 2 * k + 1 == n {
                truth = Some(tr);
            }
            path.push(tr.observed_pattern_um);
        }
        let truth = truth.unwrap_or_else(|| self.rig.truth(at(mid)));
        let mut rng = ChaCha8Rng::seed_from_u64(noise_seed ^ 0x7469_6d65);
        let jitter: f64 = rng.sample(rand_distr::StandardNormal);
        let stamp = mid + (cfg.latency_us + cfg.timestamp_jitter_us * jitter) * 1e-6;
        let frame = match st.mode {
            CameraMode::Garbage => st.renderer.garbage(seq % 2 == 0, noise_seed, stamp, seq),
            _ => {
                let illumination = 1.0
                    + cfg.illumination_drift
                        * (2.0 * std::f64::consts::PI * mid / cfg.illumination_period_s).sin();
                let (exposure, analog_gain) = match sensor {
                    Some(s) => (s.exposure_us / cfg.exposure_us, s.analog_gain()),
                    None => (1.0, 1.0),
                };
                // The platform turns the pattern: the mid-point's yaw.
                st.renderer
                    .set_yaw_rad(truth.platform_yaw_urad * 1e-6)
                    .map_err(GrabError::Render)?;
                st.renderer.render_path(
                    &path,
                    illumination * exposure,
                    analog_gain,
                    noise_seed,
                    stamp,
                    seq,
                )
            }
        }
        .map_err(GrabError::Render)?;
        Ok(Grab { frame, truth })
    }
}

/// Instants of one exposure averaged for motion blur, at most.
pub const MAX_BLUR_SAMPLES: usize = 63;

/// Exposure and gain as a client set them on the camera (GenICam
/// `ExposureTime`, `Gain`). Why a type: the rig's `[camera]` levels
/// (`background`, `foreground`) are defined at the configured exposure and
/// unity gain; these settings scale the image from there, so that a lab's
/// bring-up (`micropos camera grab --exposure-us … --gain-db …`) sees
/// what a real sensor would do: signal ∝ exposure time, shot noise grows
/// with the signal, gain amplifies signal and noise alike, saturation clips.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SensorSettings {
    /// Exposure time, µs (> 0).
    pub exposure_us: f64,
    /// Analog gain, dB (0 dB = unity; +6.02 dB doubles the output).
    pub gain_db: f64,
}

impl SensorSettings {
    /// The gain as an amplitude factor, 10^(dB/20).
    pub fn analog_gain(&self) -> f64 {
        10f64.powf(self.gain_db / 20.0)
    }
}

/// The camera as a micropos [`FrameSource`], in process.
#[derive(Debug, Clone)]
pub struct SimCameraSource {
    camera: Arc<SimCamera>,
    timeout: Duration,
}

impl SimCameraSource {
    /// A source taking frames from `camera`.
    pub fn new(camera: Arc<SimCamera>) -> Self {
        Self {
            camera,
            timeout: Duration::from_secs(2),
        }
    }
}

impl FrameSource for SimCameraSource {
    fn info(&self) -> CameraInfo {
        let c = self.camera.config();
        CameraInfo {
            backend: "sim",
            model: "hil-sim simulated microscope camera".into(),
            serial: "in-process".into(),
            width: c.width,
            height: c.height,
            pixel_format: format!("Mono{}", c.bit_depth),
            bit_depth: c.bit_depth,
        }
    }

    fn next_frame(&mut self) -> Result<Frame, CameraError> {
        match self.camera.grab() {
            Ok(g) => Ok(g.frame),
            // In process a stall is reported at once rather than after
            // sleeping the timeout: nothing would arrive anyway.
            Err(GrabError::Stalled) => Err(CameraError::Timeout {
                timeout_s: self.timeout.as_secs_f64(),
            }),
            Err(GrabError::Render(m)) => Err(CameraError::Backend {
                backend: "sim",
                message: m,
            }),
        }
    }

    fn set_timeout(&mut self, timeout: Duration) {
        self.timeout = timeout;
    }

    fn frame_ready_after(&self) -> Option<Duration> {
        self.camera.ready_after()
    }

    /// In process the camera's clock is the rig's (the daemon's clock
    /// reads the simulator's time: `hil_sim::run::in_process_environment`).
    fn frame_clock(&self) -> FrameClock {
        FrameClock::Rig
    }

    fn exposure_us(&self) -> Result<f64, CameraError> {
        Ok(self.camera.config().exposure_us)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::clock::ManualClock;
    use crate::rig::Mounting;
    use micropos::model::terms::{AngularConfig, AngularTerm, Rotation};
    use micropos::model::{Axis, MotionState, StageModel};
    use micropos::pattern::decode::{DecodeOptions, Decoder};

    /// A stage whose only error is a yaw of the x carriage of
    /// `slope_urad_per_mm`, its tool point 10 mm beside the drive line.
    fn yawing_stage(slope_urad_per_mm: f64) -> StageModel {
        let mut m = StageModel::ideal();
        let term = AngularTerm::new(
            "x_yaw",
            AngularConfig {
                axis: Axis::X,
                rotation: Rotation::Yaw,
                slope_urad_per_mm,
                period_um: 5000.0,
                sin_urad: vec![],
                cos_urad: vec![],
                arm_x_um: Some(0.0),
                arm_y_um: Some(10_000.0),
                arm_z_um: None,
                carries_other_axis: false,
            },
        )
        .unwrap();
        m.push_term(Box::new(term)).unwrap();
        m
    }

    /// The platform's yaw from the stage model shows in the decoded θ with
    /// its sign (θ = mounting angle + yaw, yaw right-handed about +z), and
    /// the decoded position is still the pattern point the truth names.
    #[test]
    fn the_platform_yaw_from_the_model_shows_in_the_decoded_theta() {
        let cfg = CameraConfig::default();
        let mounting = Mounting::default();
        let mount_rad = mounting.theta_deg.to_radians();
        let mut dec = Decoder::new(DecodeOptions::new(cfg.period_um, cfg.bits)).unwrap();
        for (slope, x_mm) in [(60.0, 8.0), (-60.0, 8.0), (60.0, 0.0), (-25.0, 4.0)] {
            let model = yawing_stage(slope);
            let yaw = model.platform_yaw_rad(&MotionState::at_rest(x_mm * 1000.0, 5000.0));
            assert!((yaw - slope * x_mm * 1e-6).abs() < 1e-12, "{yaw}");
            let rig = Arc::new(Rig::new(model, 5, [x_mm, 5.0], mounting).unwrap());
            let cam = SimCamera::new(&cfg, rig, Arc::new(ManualClock::new()), 11).unwrap();
            let g = cam.grab().unwrap();
            assert!((g.truth.platform_yaw_urad - yaw * 1e6).abs() < 1e-9);
            let d = dec.decode(&g.frame).unwrap();
            let seen_urad = (d.theta_rad - mount_rad) * 1e6;
            // One frame's θ error on this camera is about 20 µrad rms and
            // 50 µrad at worst, a function of the pose
            // (tests/it/decode_render.rs measures it); a yaw of the wrong
            // sign would be 960 µrad off.
            assert!(
                (seen_urad - yaw * 1e6).abs() < 100.0,
                "slope {slope} at x {x_mm} mm: yaw {:.1} µrad, decoded {seen_urad:.1} µrad",
                yaw * 1e6
            );
            let p = g.truth.observed_pattern_um;
            assert!(
                (d.x_um - p[0]).hypot(d.y_um - p[1]) < 0.01,
                "{d:?} against {p:?}"
            );
        }
    }
}
