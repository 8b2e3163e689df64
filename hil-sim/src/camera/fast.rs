//! A fast renderer of the Megarena pattern for a fixed mounting angle,
//! turned per frame by the platform's yaw.
//!
//! Why: micropos's exact renderer (`micropos::pattern::render`) clips every
//! pixel against every dot and blurs the whole frame: 30–80 ms per
//! 1024 × 768 frame, too slow for a 9.5-hour characterization of ≈ 16 000
//! frames. Here the mounting angle, pixel size and PSF are fixed for the
//! life of the renderer, so the image of one dot depends only on its
//! sub-pixel phase. [`FastRenderer::new`] precomputes, for Q × Q sub-pixel
//! phases, the *stamp* of one dot: the pixel-integrated intensity of a
//! square dot (side p/2) convolved with a Gaussian PSF. A frame is then the
//! sum of the stamps of the visible dots (nearest phase; Q = 32, so a dot is
//! placed within 1/64 px, and the phase errors of thousands of dots average
//! out), shaded (illumination gradient, vignetting, dust, illumination
//! drift), with shot and read noise drawn from a precomputed Gaussian table
//! at per-row random offsets, and quantised.
//!
//! Motion blur: a frame whose pattern moves during the exposure is the
//! mean of the images at several instants ([`FastRenderer::render_path`]).
//! The pattern moves rigidly, so every dot moves by the same displacement
//! from the middle instant, and its blurred image depends only on its
//! phase there: per frame, a table of *blurred stamps* (for each of the
//! Q × Q phases, the mean of the sharp stamps at each instant's
//! displacement, rounded to 1/Q px) is built, and each dot is placed once.
//! Building the table adds Q² = 1024 stamps per instant, fewer than the
//! 4000–4500 dots of a frame, and a sweep at constant velocity reuses it
//! frame after frame; placing each dot per instant
//! ([`FastRenderer::render_path_per_instant`], the reference) costs one
//! dot pass per instant.
//!
//! The platform's yaw: a frame may turn the pattern by a small angle from
//! the mounting angle ([`FastRenderer::set_yaw_rad`]; the simulated camera
//! sets the platform's yaw at the exposure's mid-point). Every dot is then
//! placed at its position in the turned pattern, with the stamps of the
//! mounting angle: the yaw moves the dots (over a 1024-px frame, 1 mrad is
//! half a pixel at the edges: what the decoder measures as θ), while it
//! would turn each square dot's own image by the same angle, its corners by
//! (2.5·√2 px)·1 mrad ≈ 0.004 px for the default camera, which leaves its
//! centre and so every decoded number in place; hence the limit
//! [`MAX_YAW_RAD`] and no stamps rebuilt per frame. The motion-blurred
//! stamps' displacements are turned the same way, and the yaw's change
//! within one exposure (≤ 0.02 µrad in a 2 ms exposure of a 240 µm/s
//! sweep on the paper stage) is neglected: the frame is turned by its mid-point's yaw.
//!
//! Same conventions as micropos's renderer (pixel j covers [j, j+1), the
//! pose is the pattern point at (W/2, H/2), θ from image +x to pattern +x).
//! A defocus disc of radius R is approximated by a Gaussian of the same
//! variance (σ² + R²/4). Stamps are exact PSF-then-pixel integration (the
//! Gaussian-blurred square is a product of error functions in the dot's own
//! axes; the pixel integral is a 32 × 32 midpoint sum via a summed-area
//! table).
//!
//! The files: this one builds the stamps and renders a frame band by band;
//! `stamp` places the dots, `blur` builds a moving frame's blurred stamps,
//! `sensor` shades, adds noise and quantises.

use super::config::CameraConfig;
use micropos::frame::{Frame, Pixels};
use micropos::pattern::render::{shading_map, Shading};
use micropos::pattern::sequence::LineSequence;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use sensor::FinishParams;
use stamp::{StampGeom, StampTable};

mod blur;
mod sensor;
mod stamp;

/// Sub-pixel phases per pixel side.
const Q: usize = 32;
/// Length of the Gaussian noise table (power of two).
const NOISE_LEN: usize = 1 << 20;
/// Largest spread of a blurred stamp's instants, px: longer paths are
/// rendered instant by instant (see [`FastRenderer::build_blur`]).
const MAX_BLUR_SPREAD_PX: usize = 16;
/// Image rows rendered at once by one thread (see
/// [`FastRenderer::render_pixels`]): 64 rows of a 1024-px frame are a
/// 256 KB accumulator, which stays in a core's L2 cache.
const BAND_ROWS: usize = 64;

/// Largest turn of a frame from the mounting angle
/// ([`FastRenderer::set_yaw_rad`]), rad: 10 mrad, 66 times the M-111's
/// datasheet yaw (±150 µrad). Why a limit: the dots keep the mounting
/// angle's stamps; at 10 mrad a default dot's corners are 0.035 px off,
/// beyond it the stamps would have to turn too.
pub const MAX_YAW_RAD: f64 = 0.01;

/// Standard normal CDF via erfc (W. J. Cody-style rational approximation by
/// Numerical Recipes' erfc, |error| < 1.2e-7).
fn phi(x: f64) -> f64 {
    0.5 * erfc(-x / std::f64::consts::SQRT_2)
}

fn erfc(x: f64) -> f64 {
    let z = x.abs();
    let t = 1.0 / (1.0 + 0.5 * z);
    let r = t
        * (-z * z - 1.265_512_23
            + t * (1.000_023_68
                + t * (0.374_091_96
                    + t * (0.096_784_18
                        + t * (-0.186_288_06
                            + t * (0.278_868_07
                                + t * (-1.135_203_98
                                    + t * (1.488_515_87
                                        + t * (-0.822_152_23 + t * 0.170_872_77)))))))))
            .exp();
    if x >= 0.0 {
        r
    } else {
        2.0 - r
    }
}

/// See the module docs.
#[derive(Debug, Clone)]
pub struct FastRenderer {
    cfg: CameraConfig,
    theta_rad: f64,
    /// The turn of the next frames from `theta_rad` (the platform's yaw),
    /// rad, and sin, cos of the angle the dots are placed at,
    /// `theta_rad + yaw_rad` ([`FastRenderer::set_yaw_rad`]).
    yaw_rad: f64,
    view_sin_cos: (f64, f64),
    seq: LineSequence,
    k: usize,
    side: usize,
    /// Stride of a stamp row: `side` rounded up to whole vectors of 8,
    /// padded with +0.0 (see [`FastRenderer::stamp_rows`]).
    stride: usize,
    stamps: Vec<f32>,
    shade: Vec<f32>,
    noise: Vec<f32>,
    /// The two threads' band accumulators, [`BAND_ROWS`] rows each.
    acc: Vec<f32>,
    /// The last blurred frame's stamps ([`FastRenderer::build_blur`]),
    /// their shape, and the displacements they were built for (empty: no
    /// table).
    blur: Vec<f32>,
    blur_geom: StampGeom,
    blur_key: Vec<(i64, i64)>,
    /// Whether `acc` is +0.0 everywhere: the sensor pass clears each row
    /// once it has read it (the row is in cache then), so a band needs no
    /// separate pass to zero it; false while a render is under way (a
    /// render that panicked leaves it false, and the next one zeroes).
    acc_zero: bool,
    /// The CPU's vector extensions, found once: the pixel loops run
    /// compiled for them (`pulp`'s run-time dispatch). Same bits on every
    /// width: each lane does the scalar loop's IEEE operations, in the
    /// same order, and nothing is fused.
    arch: pulp::Arch,
}

impl FastRenderer {
    /// Builds the stamps for `cfg` at mounting angle `theta_rad`.
    pub fn new(cfg: &CameraConfig, theta_rad: f64) -> Result<FastRenderer, String> {
        cfg.validate()?;
        if !theta_rad.is_finite() {
            return Err(format!("mounting angle {theta_rad} is not finite"));
        }
        let seq = LineSequence::new(cfg.bits).map_err(|e| e.to_string())?;
        let h = cfg.period_um / (4.0 * cfg.pixel_um);
        let sigma = (cfg.blur_sigma_px.powi(2) + cfg.defocus_radius_px.powi(2) / 4.0).sqrt();
        let (sn, cs) = theta_rad.sin_cos();
        let k = (h * (cs.abs() + sn.abs()) + 4.0 * sigma + 1.0).ceil() as usize;
        let side = 2 * k + 1;
        // Fine grid of the blurred dot, samples at (g + 0.5)/Q px, g ∈ [−G, G).
        let g = (k + 1) * Q;
        let n = 2 * g;
        let bx = |x: f64| -> f64 {
            if sigma > 0.0 {
                phi((h - x) / sigma) - phi((-h - x) / sigma)
            } else if x.abs() < h {
                1.0
            } else {
                0.0
            }
        };
        let mut sat = vec![0f64; (n + 1) * (n + 1)];
        for iy in 0..n {
            let dv = (iy as f64 - g as f64 + 0.5) / Q as f64;
            let mut row = 0.0;
            for ix in 0..n {
                let du = (ix as f64 - g as f64 + 0.5) / Q as f64;
                let a = du * cs + dv * sn;
                let b = -du * sn + dv * cs;
                row += bx(a) * bx(b);
                sat[(iy + 1) * (n + 1) + ix + 1] = sat[iy * (n + 1) + ix + 1] + row;
            }
        }
        let block = |x0: usize, y0: usize| -> f64 {
            let w = n + 1;
            sat[(y0 + Q) * w + x0 + Q] - sat[y0 * w + x0 + Q] - sat[(y0 + Q) * w + x0]
                + sat[y0 * w + x0]
        };
        let norm = 1.0 / (Q * Q) as f64;
        let stride = side.div_ceil(8) * 8;
        let mut stamps = vec![0f32; Q * Q * side * stride];
        for b in 0..Q {
            for a in 0..Q {
                let base = (b * Q + a) * side * stride;
                for ky in 0..side {
                    let y0 = (ky as i64 - k as i64) * Q as i64 - b as i64 + g as i64;
                    for kx in 0..side {
                        let x0 = (kx as i64 - k as i64) * Q as i64 - a as i64 + g as i64;
                        // In range by construction (see the module docs).
                        let v = block(x0 as usize, y0 as usize) * norm;
                        stamps[base + ky * stride + kx] = v as f32;
                    }
                }
            }
        }
        let mut rng = ChaCha8Rng::seed_from_u64(cfg.dust_seed ^ 0x6e6f697365);
        let noise: Vec<f32> = (0..NOISE_LEN)
            .map(|_| rng.sample::<f32, _>(rand_distr::StandardNormal))
            .collect();
        let mut r = FastRenderer {
            cfg: cfg.clone(),
            theta_rad,
            yaw_rad: 0.0,
            view_sin_cos: theta_rad.sin_cos(),
            seq,
            k,
            side,
            stride,
            stamps,
            shade: Vec::new(),
            noise,
            acc: vec![0.0; 2 * BAND_ROWS * cfg.width],
            blur: Vec::new(),
            blur_geom: StampGeom::default(),
            blur_key: Vec::new(),
            acc_zero: true,
            arch: pulp::Arch::new(),
        };
        r.build_shade();
        Ok(r)
    }

    /// The configuration.
    pub fn config(&self) -> &CameraConfig {
        &self.cfg
    }

    /// The mounting angle the stamps were built for, rad.
    pub fn theta_rad(&self) -> f64 {
        self.theta_rad
    }

    /// Turns the pattern of the frames rendered from now on by `yaw_rad`
    /// from the mounting angle (the platform's yaw, right-handed about +z
    /// of the stage frame = the image frame, so the decoder reads θ =
    /// mounting angle + yaw): the dots are placed at `theta_rad + yaw_rad`,
    /// with the mounting angle's stamps (module docs). 0 renders as before,
    /// bit for bit. Errors: not finite or beyond ±[`MAX_YAW_RAD`] (the
    /// renderer keeps its previous yaw).
    pub fn set_yaw_rad(&mut self, yaw_rad: f64) -> Result<(), String> {
        if !(yaw_rad.is_finite() && yaw_rad.abs() <= MAX_YAW_RAD) {
            return Err(format!(
                "platform yaw {yaw_rad} rad: must be finite, within ±{MAX_YAW_RAD} rad"
            ));
        }
        self.yaw_rad = yaw_rad;
        self.view_sin_cos = (self.theta_rad + yaw_rad).sin_cos();
        Ok(())
    }

    /// The turn [`FastRenderer::set_yaw_rad`] set last, rad.
    pub fn yaw_rad(&self) -> f64 {
        self.yaw_rad
    }

    fn build_shade(&mut self) {
        self.shade = shading_map(&Shading {
            width: self.cfg.width,
            height: self.cfg.height,
            gradient: self.cfg.gradient,
            vignetting: self.cfg.vignetting,
            dust_fraction: self.cfg.dust_fraction,
            dust_radius_px: (self.cfg.dust_radius_px[0], self.cfg.dust_radius_px[1]),
            dust_transmission: self.cfg.dust_transmission,
            dust_seed: self.cfg.dust_seed,
        });
    }

    /// Renders the frame's pixels for the pattern points `path_um` (each
    /// the pattern point at the image centre at one instant of the
    /// exposure, weighted equally: the exposure's integral of the moving
    /// pattern): the top and bottom halves of the image on two threads,
    /// each in bands of [`BAND_ROWS`] rows: sum into the (zeroed) band
    /// accumulator the part of every dot's stamp that falls on the band's
    /// rows, in the frame's dot order (so every pixel gets the same
    /// additions in the same order as on one thread over the whole frame:
    /// same bits), then turn the band into pixels and zero it. One point
    /// has weight exactly 1, so a still frame is the sharp render bit for
    /// bit; several points place each dot once, with the frame's blurred
    /// stamp ([`FastRenderer::build_blur`]). Why bands: a band's
    /// accumulator (256 KB) stays in the core's cache from the first stamp
    /// to the sensor pass, where a whole-frame accumulator (3 MB) goes to
    /// memory and back three times (stamps, sensor pass, clearing); the
    /// cost is that a dot whose stamp straddles two bands is placed twice.
    fn render_pixels(
        &mut self,
        path_um: &[[f64; 2]],
        p: &FinishParams,
        placement: Placement,
    ) -> Vec<u16> {
        let blurred =
            placement == Placement::Blurred && path_um.len() > 1 && self.build_blur(path_um);
        let mut acc = std::mem::take(&mut self.acc);
        let zeroed = std::mem::replace(&mut self.acc_zero, false);
        let (w, h) = (self.cfg.width, self.cfg.height);
        let (points, table) = if blurred {
            (&path_um[path_um.len() / 2..][..1], self.blur_table())
        } else {
            // One point, none (a blank frame), a path too long for one
            // blurred stamp, or placement asked for instant by instant:
            // each instant's sharp stamps, weighted.
            (path_um, self.sharp_table(1.0 / path_um.len().max(1) as f32))
        };
        let mut out16 = vec![0u16; w * h];
        let (acc_top, acc_bottom) = acc.split_at_mut(BAND_ROWS * w);
        let (out_top, out_bottom) = out16.split_at_mut(h / 2 * w);
        let this = &*self;
        let half = |acc: &mut [f32], out: &mut [u16], row0: usize| {
            this.arch.dispatch(Half {
                r: this,
                zeroed,
                points,
                table,
                p,
                acc,
                out,
                row0,
            });
        };
        std::thread::scope(|s| {
            s.spawn(|| half(acc_bottom, out_bottom, h / 2));
            half(acc_top, out_top, 0);
        });
        self.acc = acc;
        self.acc_zero = true;
        out16
    }

    /// The frame as the reference two-pass render computes it: all sharp
    /// stamps into a whole-frame accumulator (each image half summed on its
    /// own, instant by instant), then the sensor model over the whole
    /// frame. What [`FastRenderer::render_pixels`] must reproduce bit for
    /// bit for one point and for a path placed instant by instant.
    #[cfg(test)]
    fn two_pass(
        &self,
        path_um: &[[f64; 2]],
        light: f64,
        analog_gain: f64,
        noise_seed: u64,
    ) -> Vec<u16> {
        let (w, h) = (self.cfg.width, self.cfg.height);
        let mut acc = vec![0f32; w * h];
        let table = self.sharp_table(1.0 / path_um.len().max(1) as f32);
        for &[x, y] in path_um {
            self.stamp_rows(&mut acc[..h / 2 * w], 0, x, y, &table);
            self.stamp_rows(&mut acc[h / 2 * w..], h / 2, x, y, &table);
        }
        let p = self.finish_params(light, analog_gain, noise_seed);
        let mut out16 = vec![0u16; w * h];
        self.finish_rows(&p, &mut acc, &mut out16, 0);
        out16
    }

    /// Renders the pattern with `(x_um, y_um)` (pattern frame) at the image
    /// centre. `gain` scales the illumination (drift); `noise_seed` picks
    /// this frame's noise.
    pub fn render(
        &mut self,
        x_um: f64,
        y_um: f64,
        gain: f64,
        noise_seed: u64,
        timestamp_s: f64,
        sequence: u64,
    ) -> Result<Frame, String> {
        self.render_exposed(x_um, y_um, gain, 1.0, noise_seed, timestamp_s, sequence)
    }

    /// [`FastRenderer::render`] with the sensor's two settings apart:
    /// `light` scales the collected signal (illumination × exposure time
    /// relative to the configured exposure), `analog_gain` amplifies signal,
    /// shot noise and read noise alike after collection. Why apart: a longer
    /// exposure improves the signal-to-noise ratio, more gain only makes the
    /// image brighter (and saturates sooner), as on a real sensor.
    #[allow(clippy::too_many_arguments)]
    pub fn render_exposed(
        &mut self,
        x_um: f64,
        y_um: f64,
        light: f64,
        analog_gain: f64,
        noise_seed: u64,
        timestamp_s: f64,
        sequence: u64,
    ) -> Result<Frame, String> {
        self.render_path(
            &[[x_um, y_um]],
            light,
            analog_gain,
            noise_seed,
            timestamp_s,
            sequence,
        )
    }

    /// [`FastRenderer::render_exposed`] of a pattern that moves during the
    /// exposure: `path_um` holds the pattern point at the image centre at
    /// equally spaced instants of the exposure, and the frame is the mean
    /// of their images (motion blur; see `SimCamera::grab` for how many
    /// instants). One point is the still frame, bit for bit. Several are
    /// placed once per dot with this frame's blurred stamps
    /// ([`FastRenderer::build_blur`]: the mean of the sharp stamps at each
    /// instant's displacement from the middle instant, rounded to 1/32 px),
    /// which costs about one still frame's dot pass instead of one per
    /// instant; a path spread over more than [`MAX_BLUR_SPREAD_PX`] is
    /// placed instant by instant (as
    /// [`FastRenderer::render_path_per_instant`]). Errors: an empty path, a
    /// point not finite or beyond 10⁹ µm, light or gain out of range.
    #[allow(clippy::too_many_arguments)]
    pub fn render_path(
        &mut self,
        path_um: &[[f64; 2]],
        light: f64,
        analog_gain: f64,
        noise_seed: u64,
        timestamp_s: f64,
        sequence: u64,
    ) -> Result<Frame, String> {
        self.render_placed(
            path_um,
            light,
            analog_gain,
            noise_seed,
            timestamp_s,
            sequence,
            Placement::Blurred,
        )
    }

    /// [`FastRenderer::render_path`] with every instant's sharp stamps
    /// placed on their own (weight 1/n each): each dot's phase rounded at
    /// every instant rather than at the middle one plus a rounded
    /// displacement. The reference the blurred stamps are measured against
    /// (tests, `benches/render_blur.rs`); n times the dot pass of a still
    /// frame. Same frame as `render_path` for one point.
    #[allow(clippy::too_many_arguments)]
    pub fn render_path_per_instant(
        &mut self,
        path_um: &[[f64; 2]],
        light: f64,
        analog_gain: f64,
        noise_seed: u64,
        timestamp_s: f64,
        sequence: u64,
    ) -> Result<Frame, String> {
        self.render_placed(
            path_um,
            light,
            analog_gain,
            noise_seed,
            timestamp_s,
            sequence,
            Placement::PerInstant,
        )
    }

    /// Checks the inputs of a render (see [`FastRenderer::render_path`])
    /// and renders with the dots placed as `placement` says.
    #[allow(clippy::too_many_arguments)]
    fn render_placed(
        &mut self,
        path_um: &[[f64; 2]],
        light: f64,
        analog_gain: f64,
        noise_seed: u64,
        timestamp_s: f64,
        sequence: u64,
        placement: Placement,
    ) -> Result<Frame, String> {
        if path_um.is_empty() {
            return Err("no pattern position to render".to_owned());
        }
        for &[x_um, y_um] in path_um {
            if !(x_um.is_finite() && y_um.is_finite() && x_um.abs() < 1e9 && y_um.abs() < 1e9) {
                return Err(format!("pattern position ({x_um}, {y_um}) is not finite"));
            }
        }
        if !(light.is_finite() && light >= 0.0 && analog_gain.is_finite() && analog_gain > 0.0) {
            return Err(format!(
                "sensor settings: light {light} and analog gain {analog_gain} must be finite, light ≥ 0, gain > 0"
            ));
        }
        let p = self.finish_params(light, analog_gain, noise_seed);
        let out16 = self.render_pixels(path_um, &p, placement);
        self.to_frame(out16, timestamp_s, sequence)
    }

    /// A frame with no pattern: background (with shading and noise) when
    /// `noise_only` is false, uniform random pixels otherwise (camera fault).
    pub fn garbage(
        &mut self,
        noise_only: bool,
        noise_seed: u64,
        timestamp_s: f64,
        sequence: u64,
    ) -> Result<Frame, String> {
        if noise_only {
            let mut rng = ChaCha8Rng::seed_from_u64(noise_seed);
            let fs = (1u32 << self.cfg.bit_depth) - 1;
            let n = self.cfg.width * self.cfg.height;
            let px = if self.cfg.bit_depth <= 8 {
                Pixels::U8((0..n).map(|_| rng.gen_range(0..=fs) as u8).collect())
            } else {
                Pixels::U16((0..n).map(|_| rng.gen_range(0..=fs) as u16).collect())
            };
            return Frame::new(
                self.cfg.width,
                self.cfg.height,
                self.cfg.bit_depth,
                px,
                timestamp_s,
                sequence,
            )
            .map_err(|e| e.to_string());
        }
        let p = self.finish_params(1.0, 1.0, noise_seed);
        let out16 = self.render_pixels(&[], &p, Placement::PerInstant);
        self.to_frame(out16, timestamp_s, sequence)
    }
}

/// One image half of [`FastRenderer::render_pixels`], band by band, as a
/// `pulp` operation: its body (and the inlined stamp and sensor loops) is
/// compiled once per instruction set and run with the widest the CPU has.
struct Half<'a> {
    r: &'a FastRenderer,
    /// The band accumulator is +0.0 already (see `FastRenderer::acc_zero`).
    zeroed: bool,
    /// The pattern points whose dots `table` places.
    points: &'a [[f64; 2]],
    table: StampTable<'a>,
    p: &'a FinishParams,
    /// The band accumulator ([`BAND_ROWS`] rows).
    acc: &'a mut [f32],
    /// The half's pixels (whole rows).
    out: &'a mut [u16],
    /// The half's first image row.
    row0: usize,
}

impl pulp::WithSimd for Half<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _: S) {
        if !self.zeroed {
            self.acc.fill(0.0);
        }
        let w = self.r.cfg.width;
        for (b, out) in self.out.chunks_mut(BAND_ROWS * w).enumerate() {
            let acc = &mut self.acc[..out.len()];
            let band0 = self.row0 + b * BAND_ROWS;
            for &[x, y] in self.points {
                self.r.stamp_rows(acc, band0, x, y, &self.table);
            }
            self.r.finish_rows(self.p, acc, out, band0);
        }
    }
}

/// How [`FastRenderer::render_pixels`] places the dots of several instants.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Placement {
    /// Once, with the frame's blurred stamps where the path allows.
    Blurred,
    /// Once per instant, with the sharp stamps.
    PerInstant,
}

#[cfg(test)]
mod tests;
