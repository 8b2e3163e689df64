//! The simulated camera's configuration (`[camera]` of the rig file): its
//! fields, defaults, range checks and the equivalent exact-renderer
//! configuration. Its own file so the rig file and the renderers read it
//! without importing the camera.

use serde::{Deserialize, Serialize};
use std::ops::RangeInclusive;

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
    /// Negative: the stamp precedes the mid-point (a camera that stamps
    /// the exposure's start, or a trigger sent ahead of it).
    pub latency_us: f64,
    /// Timestamp jitter σ, µs (Gaussian, drawn per frame from the frame's
    /// noise seed).
    pub timestamp_jitter_us: f64,
    /// The camera's own clock (the tick counter a GigE Vision camera puts
    /// in each frame's leader) reads `(t + clock_offset_s) · (1 +
    /// clock_rate_ppm · 1e-6)` at rig time `t`, s: a camera powered up
    /// before the rig started. Only the served GigE camera stamps on it;
    /// in process the camera stamps rig times.
    pub clock_offset_s: f64,
    /// The camera clock's rate error, ppm (a crystal's tens of ppm; either
    /// sign). See `clock_offset_s`.
    pub clock_rate_ppm: f64,
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
            clock_offset_s: 5400.0,
            clock_rate_ppm: 30.0,
        }
    }
}

impl CameraConfig {
    /// Checks every value, in the order of the fields; the message names
    /// the key and the accepted range.
    pub fn validate(&self) -> Result<(), String> {
        // (key, value, whether it is accepted, the accepted range)
        let check = |name, v: f64, ok: bool, why| (name, v, ok, why);
        let within = |name, v: f64, r: RangeInclusive<f64>, why| (name, v, r.contains(&v), why);
        let period_px = self.period_um / self.pixel_um;
        let (dust_min, dust_max) = (self.dust_radius_px[0], self.dust_radius_px[1]);
        let before = [
            within("width", self.width as f64, 16.0..=8192.0, "16..=8192"),
            within("height", self.height as f64, 16.0..=8192.0, "16..=8192"),
            within("bit_depth", f64::from(self.bit_depth), 8.0..=16.0, "8..=16"),
            within("bits", f64::from(self.bits), 4.0..=12.0, "4..=12"),
            check("period_um", self.period_um, self.period_um > 0.0, "> 0"),
            check("pixel_um", self.pixel_um, self.pixel_um > 0.0, "> 0"),
            within(
                "period in px",
                period_px,
                3.0..=64.0,
                "period_um / pixel_um must be 3..=64 px",
            ),
            check(
                "fps",
                self.fps,
                self.fps > 0.0 && self.fps <= 10_000.0,
                "0 < fps <= 10000",
            ),
            check(
                "exposure_us",
                self.exposure_us,
                self.exposure_us > 0.0 && self.exposure_us * 1e-6 <= 1.0 / self.fps,
                "> 0 and at most one frame period",
            ),
            within("background", self.background, 0.0..=1.0, "0..=1"),
            within("foreground", self.foreground, 0.0..=1.0, "0..=1"),
            within("blur_sigma_px", self.blur_sigma_px, 0.0..=5.0, "0..=5"),
            within(
                "defocus_radius_px",
                self.defocus_radius_px,
                0.0..=10.0,
                "0..=10",
            ),
        ];
        let gradients = self
            .gradient
            .map(|g| check("gradient", g, g.abs() < 1.9, "|g| < 1.9"));
        let after = [
            check(
                "vignetting",
                self.vignetting,
                (0.0..1.0).contains(&self.vignetting),
                "0..1",
            ),
            check(
                "full_well_e",
                self.full_well_e,
                self.full_well_e >= 0.0,
                ">= 0",
            ),
            within("read_noise", self.read_noise, 0.0..=1.0, "0..=1"),
            within("dust_fraction", self.dust_fraction, 0.0..=0.9, "0..=0.9"),
            check(
                "dust_radius_px",
                dust_min,
                dust_min > 0.0 && dust_max >= dust_min && dust_max <= 1000.0,
                "0 < min <= max <= 1000",
            ),
            within(
                "dust_transmission",
                self.dust_transmission,
                0.0..=1.0,
                "0..=1",
            ),
            check(
                "illumination_drift",
                self.illumination_drift,
                (0.0..0.5).contains(&self.illumination_drift),
                "0..0.5",
            ),
            check(
                "illumination_period_s",
                self.illumination_period_s,
                self.illumination_period_s > 0.0,
                "> 0",
            ),
            within("latency_us", self.latency_us, -1e6..=1e6, "−1e6..=1e6"),
            within(
                "timestamp_jitter_us",
                self.timestamp_jitter_us,
                0.0..=1e4,
                "0..=1e4",
            ),
            within(
                "clock_offset_s",
                self.clock_offset_s,
                0.0..=1e8,
                "0..=1e8 (a tick counter starts at 0 when the camera powers up)",
            ),
            within(
                "clock_rate_ppm",
                self.clock_rate_ppm,
                -500.0..=500.0,
                "−500..=500",
            ),
        ];
        let checks = before.into_iter().chain(gradients).chain(after);
        for (name, v, ok, why) in checks {
            if !(ok && v.is_finite()) {
                return Err(format!("camera.{name} = {v}: {why}"));
            }
        }
        Ok(())
    }

    /// The camera clock's reading at rig time `rig_s`, ns (see
    /// `clock_offset_s`); 0 before the counter started.
    pub fn camera_clock_ns(&self, rig_s: f64) -> u64 {
        let s = (rig_s + self.clock_offset_s) * (1.0 + self.clock_rate_ppm * 1e-6);
        if s.is_finite() && s > 0.0 {
            // Saturates at u64::MAX (585 years of nanoseconds).
            (s * 1e9).round() as u64
        } else {
            0
        }
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

#[cfg(test)]
mod tests {
    use super::*;

    /// The default camera passes; a value out of its range (or not a
    /// number) is refused naming its key, whatever the others.
    #[test]
    fn the_default_passes_and_each_bad_value_names_its_key() {
        let ok = CameraConfig::default();
        assert_eq!(ok.validate(), Ok(()));
        type Spoil = fn(&mut CameraConfig);
        let cases: [(&str, Spoil); 10] = [
            ("width", |c| c.width = 8),
            ("bits", |c| c.bits = 13),
            ("period in px", |c| c.pixel_um = c.period_um),
            ("fps", |c| c.fps = 0.0),
            ("exposure_us", |c| c.exposure_us = 2e6 / c.fps),
            ("gradient", |c| c.gradient[1] = -2.0),
            ("vignetting", |c| c.vignetting = 1.0),
            ("dust_radius_px", |c| c.dust_radius_px = [3.0, 2.0]),
            ("latency_us", |c| c.latency_us = -2e6),
            ("clock_rate_ppm", |c| c.clock_rate_ppm = f64::NAN),
        ];
        for (key, spoil) in cases {
            let mut c = ok.clone();
            spoil(&mut c);
            let e = c.validate().unwrap_err();
            assert!(e.starts_with(&format!("camera.{key} = ")), "{key}: {e}");
        }
    }
}
