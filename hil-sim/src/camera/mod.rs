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
//! window: the frame is the mean of renders at `n` equally spaced instants
//! of the exposure, `n` odd and chosen so that consecutive instants are at
//! most a quarter pixel apart on the pattern (`n` = 1, the mid-point alone,
//! for a still platform: a still frame is unchanged by the blur model).
//! The truth reported with the frame is the one at the mid-point.
//!
//! Timestamps (contract): a grabbed frame is stamped with the exposure
//! mid-point plus the fixed latency `latency_us` plus Gaussian jitter of σ
//! `timestamp_jitter_us`, drawn from the frame's noise seed (so a seed gives
//! the same stamps). micropos is not told the latency: the sweep
//! characterization estimates it. [`SimCamera::render_now`] (the GigE
//! server's free-running frames) stamps the render time, without blur.
//!
//! Faults (contract): [`CameraMode::Stall`] (no answer: the socket server
//! drops the request, the in-process source times out), [`CameraMode::Garbage`]
//! (undecodable frames: blank and noise frames alternate).
//!
//! Beyond the pattern (10-bit, 4 µm: 12384 µm square) the frame shows part or
//! none of the dots and the decoder reports an error; it never yields a
//! position from outside the pattern.

pub mod fast;
#[cfg(feature = "genicam")]
pub mod gige;
pub mod server;

use crate::clock::Clock;
use crate::rig::{Rig, RigTruth};
use fast::FastRenderer;
use micropos::camera::{CameraError, CameraInfo, FrameSource};
use micropos::frame::Frame;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

/// Optics, sensor and pattern of the simulated camera (`[camera]` of the rig
/// file). Defaults: the paper's rig.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CameraConfig {
    /// Frame width, px.
    pub width: usize,
    /// Frame height, px.
    pub height: usize,
    /// Sensor bit depth (8 → u8 pixels, 9..=16 → u16).
    pub bit_depth: u8,
    /// Pattern period, µm.
    pub period_um: f64,
    /// Code depth of the pattern (10 → 3096 lines, 12384 µm at 4 µm).
    pub bits: u32,
    /// Pixel size on the pattern, µm (0.4 → 10 px per period).
    pub pixel_um: f64,
    /// Frame rate, frames per simulated second.
    pub fps: f64,
    /// Exposure time, µs.
    pub exposure_us: f64,
    /// Dark dots on a bright background (false: bright dots, as the real
    /// pattern under bright field).
    pub dark_dots: bool,
    /// Background level, fraction of full scale.
    pub background: f64,
    /// Dot level, fraction of full scale.
    pub foreground: f64,
    /// Gaussian PSF σ, px.
    pub blur_sigma_px: f64,
    /// Defocus disc radius, px (approximated by a Gaussian of equal variance).
    pub defocus_radius_px: f64,
    /// Linear illumination gradient, relative change left→right, top→bottom.
    pub gradient: [f64; 2],
    /// Vignetting: relative intensity drop at the corners.
    pub vignetting: f64,
    /// Electrons at full scale (shot noise); 0 = none.
    pub full_well_e: f64,
    /// Read noise σ, fraction of full scale.
    pub read_noise: f64,
    /// Fraction of the frame covered by dust (0..0.9).
    pub dust_fraction: f64,
    /// Dust blob radius range, px.
    pub dust_radius_px: [f64; 2],
    /// Dust transmission (0 = opaque).
    pub dust_transmission: f64,
    /// Seed of the dust layout (and of the noise table).
    pub dust_seed: u64,
    /// Illumination drift: relative amplitude of a slow sinusoidal change of
    /// the lamp intensity.
    pub illumination_drift: f64,
    /// Period of the illumination drift, simulated s.
    pub illumination_period_s: f64,
    /// Fixed delay from the true exposure mid-point to the frame's
    /// timestamp, µs (a camera's trigger-to-stamp latency; hidden from
    /// micropos, which estimates it from a sweep characterization).
    pub latency_us: f64,
    /// Timestamp jitter σ, µs (Gaussian, drawn per frame from the frame's
    /// noise seed).
    pub timestamp_jitter_us: f64,
}

impl Default for CameraConfig {
    fn default() -> Self {
        Self {
            width: 1024,
            height: 768,
            bit_depth: 10,
            period_um: 4.0,
            bits: 10,
            pixel_um: 0.4,
            fps: 30.0,
            exposure_us: 2000.0,
            dark_dots: false,
            background: 0.15,
            foreground: 0.8,
            blur_sigma_px: 0.9,
            defocus_radius_px: 0.0,
            gradient: [0.03, -0.02],
            vignetting: 0.08,
            full_well_e: 10_000.0,
            read_noise: 0.003,
            dust_fraction: 0.0,
            dust_radius_px: [3.0, 25.0],
            dust_transmission: 0.1,
            dust_seed: 1,
            illumination_drift: 0.02,
            illumination_period_s: 3600.0,
            latency_us: 3700.0,
            timestamp_jitter_us: 20.0,
        }
    }
}

impl CameraConfig {
    /// Checks every value; the message names the key and the accepted range.
    pub fn validate(&self) -> Result<(), String> {
        let chk = |name: &str, v: f64, ok: bool, why: &str| {
            if ok && v.is_finite() {
                Ok(())
            } else {
                Err(format!("camera.{name} = {v}: {why}"))
            }
        };
        chk(
            "width",
            self.width as f64,
            (16..=8192).contains(&self.width),
            "16..=8192",
        )?;
        chk(
            "height",
            self.height as f64,
            (16..=8192).contains(&self.height),
            "16..=8192",
        )?;
        chk(
            "bit_depth",
            f64::from(self.bit_depth),
            (8..=16).contains(&self.bit_depth),
            "8..=16",
        )?;
        chk(
            "bits",
            f64::from(self.bits),
            (4..=12).contains(&self.bits),
            "4..=12",
        )?;
        chk("period_um", self.period_um, self.period_um > 0.0, "> 0")?;
        chk("pixel_um", self.pixel_um, self.pixel_um > 0.0, "> 0")?;
        chk(
            "period in px",
            self.period_um / self.pixel_um,
            (3.0..=64.0).contains(&(self.period_um / self.pixel_um)),
            "period_um / pixel_um must be 3..=64 px",
        )?;
        chk(
            "fps",
            self.fps,
            self.fps > 0.0 && self.fps <= 10_000.0,
            "0 < fps <= 10000",
        )?;
        chk(
            "exposure_us",
            self.exposure_us,
            self.exposure_us > 0.0 && self.exposure_us * 1e-6 <= 1.0 / self.fps,
            "> 0 and at most one frame period",
        )?;
        chk(
            "background",
            self.background,
            (0.0..=1.0).contains(&self.background),
            "0..=1",
        )?;
        chk(
            "foreground",
            self.foreground,
            (0.0..=1.0).contains(&self.foreground),
            "0..=1",
        )?;
        chk(
            "blur_sigma_px",
            self.blur_sigma_px,
            (0.0..=5.0).contains(&self.blur_sigma_px),
            "0..=5",
        )?;
        chk(
            "defocus_radius_px",
            self.defocus_radius_px,
            (0.0..=10.0).contains(&self.defocus_radius_px),
            "0..=10",
        )?;
        for g in self.gradient {
            chk("gradient", g, g.abs() < 1.9, "|g| < 1.9")?;
        }
        chk(
            "vignetting",
            self.vignetting,
            (0.0..1.0).contains(&self.vignetting),
            "0..1",
        )?;
        chk(
            "full_well_e",
            self.full_well_e,
            self.full_well_e >= 0.0,
            ">= 0",
        )?;
        chk(
            "read_noise",
            self.read_noise,
            (0.0..=1.0).contains(&self.read_noise),
            "0..=1",
        )?;
        chk(
            "dust_fraction",
            self.dust_fraction,
            (0.0..=0.9).contains(&self.dust_fraction),
            "0..=0.9",
        )?;
        chk(
            "dust_radius_px",
            self.dust_radius_px[0],
            self.dust_radius_px[0] > 0.0
                && self.dust_radius_px[1] >= self.dust_radius_px[0]
                && self.dust_radius_px[1] <= 1000.0,
            "0 < min <= max <= 1000",
        )?;
        chk(
            "dust_transmission",
            self.dust_transmission,
            (0.0..=1.0).contains(&self.dust_transmission),
            "0..=1",
        )?;
        chk(
            "illumination_drift",
            self.illumination_drift,
            (0.0..0.5).contains(&self.illumination_drift),
            "0..0.5",
        )?;
        chk(
            "illumination_period_s",
            self.illumination_period_s,
            self.illumination_period_s > 0.0,
            "> 0",
        )?;
        chk(
            "latency_us",
            self.latency_us,
            (0.0..=1e6).contains(&self.latency_us),
            "0..=1e6",
        )?;
        chk(
            "timestamp_jitter_us",
            self.timestamp_jitter_us,
            (0.0..=1e4).contains(&self.timestamp_jitter_us),
            "0..=1e4",
        )?;
        Ok(())
    }

    /// The equivalent configuration of micropos's exact renderer (no noise
    /// there: the caller sets what it compares).
    pub fn exact_render_config(&self) -> micropos::pattern::render::RenderConfig {
        micropos::pattern::render::RenderConfig {
            width: self.width,
            height: self.height,
            bit_depth: self.bit_depth,
            period_um: self.period_um,
            bits: self.bits,
            dark_dots: self.dark_dots,
            background: self.background,
            foreground: self.foreground,
            blur_sigma_px: self.blur_sigma_px,
            defocus_radius_px: self.defocus_radius_px,
            gradient: self.gradient,
            vignetting: self.vignetting,
            full_well_e: self.full_well_e,
            read_noise: self.read_noise,
            dust_fraction: self.dust_fraction,
            dust_radius_px: (self.dust_radius_px[0], self.dust_radius_px[1]),
            dust_transmission: self.dust_transmission,
            dust_seed: self.dust_seed,
            oversample: 2,
            plain_grid: false,
        }
    }
}

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
        self.render_locked(
            &mut st,
            &cfg,
            mid,
            Exposure::Grab { exposure, samples },
            None,
        )
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

    /// Renders the platform's pose at the clock's current time, without the
    /// frame-slot timing of [`SimCamera::grab`] and without advancing the
    /// clock: for a free-running camera paced by wall time (the GigE Vision
    /// server), whose frames observe the rig rather than drive its clock.
    /// `sensor` is what the client set (exposure, gain); `None` renders at
    /// the rig's configured exposure and unity gain.
    pub fn render_now(&self, sensor: Option<SensorSettings>) -> Result<Grab, GrabError> {
        let mut st = self.lock();
        if st.mode == CameraMode::Stall {
            return Err(GrabError::Stalled);
        }
        let cfg = st.renderer.config().clone();
        let now = self.clock.now().as_secs_f64();
        self.render_locked(&mut st, &cfg, now, Exposure::Instant, sensor)
    }

    /// Renders the truth around simulated time `at_s` (mode: normal or
    /// garbage): at that instant, or integrated over a grab's exposure
    /// centred there, stamped with latency and jitter (module docs).
    fn render_locked(
        &self,
        st: &mut CameraState,
        cfg: &CameraConfig,
        at_s: f64,
        exposure: Exposure,
        sensor: Option<SensorSettings>,
    ) -> Result<Grab, GrabError> {
        let mid = at_s;
        let at = |t: f64| Duration::try_from_secs_f64(t.max(0.0)).unwrap_or_default();
        st.sequence += 1;
        let seq = st.sequence;
        let noise_seed = st.seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) ^ seq;
        // The instants of the exposure in time order (the rig's model only
        // moves forward); the mid-point's truth is the frame's truth.
        let (truth, path, stamp) = match exposure {
            Exposure::Instant => {
                let truth = self.rig.truth(at(mid));
                (truth, vec![truth.observed_pattern_um], mid)
            }
            Exposure::Grab { exposure, samples } => {
                let n = samples.max(1);
                let mut truth = None;
                let mut path = Vec::with_capacity(n);
                for k in 0..n {
                    let t = if 2 * k + 1 == n {
                        mid
                    } else {
                        mid + ((k as f64 + 0.5) / n as f64 - 0.5) * exposure
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
                (truth, path, stamp)
            }
        };
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

/// Renders of one exposure averaged for motion blur, at most.
pub const MAX_BLUR_SAMPLES: usize = 63;

/// What a render integrates over.
#[derive(Debug, Clone, Copy)]
enum Exposure {
    /// One instant, stamped with it (free-running GigE frames).
    Instant,
    /// A grab's exposure of `exposure` s centred on the render time,
    /// averaged over `samples` instants, stamped with latency and jitter.
    Grab { exposure: f64, samples: usize },
}

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
    fn stamps_on_rig_clock(&self) -> bool {
        true
    }

    fn exposure_us(&self) -> Result<f64, CameraError> {
        Ok(self.camera.config().exposure_us)
    }
}
