//! Renders camera frames of the Megarena pattern at a known pose.
//!
//! Why: the decoder's accuracy claims (1e-3 px noise and bias, zero wrong
//! absolute positions) can only be checked against frames whose ground truth
//! is exact, and the simulated camera of `hil-sim` needs the same frames.
//!
//! # Conventions
//! * Pattern frame: origin at the centre of dot (0, 0), x along increasing
//!   column, y along increasing row, µm. Dot (c, r) is a square of side p/2
//!   centred at (c·p, r·p), present per [`LineSequence::dot`].
//! * Image frame: pixel j covers [j, j+1); the pose is that of the image
//!   centre point (W/2, H/2).
//! * A pattern point seen at image point u = (u, v) is
//!   X = (x, y) + s·R·M·(u − W/2, v − H/2), R = [[cos θ, sin θ], [−sin θ, cos θ]],
//!   s the pixel size in µm, M = diag(1, −1) for a mirrored optical path and
//!   the identity otherwise. θ is the angle from the image +x axis to the
//!   pattern +x axis, towards image +y.
//!
//! # Image formation
//! Dots are area-integrated exactly: each pixel's value is the area of the
//! pixel square covered by the (rotated) square dots, computed by clipping the
//! pixel polygon against the dot (pixels wholly inside or outside a dot skip the
//! clipping). This matters because the decoder's sub-1e-3-px bias tests would
//! otherwise measure the renderer's own sampling error. The coverage image is
//! then blurred (Gaussian PSF, optional defocus disc), shaded (linear
//! illumination gradient, radial vignetting), occluded by dust, given shot and
//! read noise, and quantised. Everything random comes from a seeded ChaCha RNG.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use thiserror::Error;

use super::sequence::{LineSequence, SequenceError};
use crate::frame::{Frame, FrameError, Pixels};

/// Why a renderer cannot be built or a frame cannot be rendered.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum RenderError {
    /// The code depth is not supported.
    #[error(transparent)]
    Sequence(#[from] SequenceError),
    /// The frame parameters do not make a frame.
    #[error(transparent)]
    Frame(#[from] FrameError),
    /// A configuration value is out of its meaningful range.
    #[error("invalid render parameter {name} = {value}: {why}")]
    Invalid {
        /// Parameter name.
        name: &'static str,
        /// Offending value.
        value: f64,
        /// What range is expected.
        why: &'static str,
    },
}

/// Where the camera looks: the pattern point at the image centre and the
/// image-to-pattern similarity (see the module conventions).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    /// Pattern x of the image centre point, µm.
    pub x_um: f64,
    /// Pattern y of the image centre point, µm.
    pub y_um: f64,
    /// Angle from image +x to pattern +x, towards image +y, rad.
    pub theta_rad: f64,
    /// Size of one pixel on the pattern, µm.
    pub pixel_um: f64,
    /// True when the optical path mirrors the image (M = diag(1, −1)).
    pub mirrored: bool,
}

impl Pose {
    /// Pattern point (µm) seen at image point (u, v) (pixels, frame of size
    /// `width` × `height`).
    pub fn pattern_point(&self, width: usize, height: usize, u: f64, v: f64) -> (f64, f64) {
        let du = u - width as f64 / 2.0;
        let mut dv = v - height as f64 / 2.0;
        if self.mirrored {
            dv = -dv;
        }
        let (s, c) = self.theta_rad.sin_cos();
        (
            self.x_um + self.pixel_um * (c * du + s * dv),
            self.y_um + self.pixel_um * (-s * du + c * dv),
        )
    }
}

/// Everything about the simulated optics, sensor and pattern except the pose.
#[derive(Debug, Clone, PartialEq)]
pub struct RenderConfig {
    /// Frame width, px.
    pub width: usize,
    /// Frame height, px.
    pub height: usize,
    /// Sensor bit depth: 8 gives `Pixels::U8`, 9..=16 give `Pixels::U16`.
    pub bit_depth: u8,
    /// Pattern period p, µm.
    pub period_um: f64,
    /// Code depth n of the pattern.
    pub bits: u32,
    /// Dark dots on a bright background when true; the real pattern image
    /// (tests/data/megarena-12bit-9um.jpg) shows bright dots on dark, the
    /// default.
    pub dark_dots: bool,
    /// Background level, fraction of full scale.
    pub background: f64,
    /// Dot level, fraction of full scale.
    pub foreground: f64,
    /// Gaussian PSF standard deviation, px (0 = none).
    pub blur_sigma_px: f64,
    /// Defocus: radius of a uniform disc PSF, px (0 = in focus).
    pub defocus_radius_px: f64,
    /// Linear illumination gradient: relative intensity change from the left
    /// to the right edge (x) and from the top to the bottom edge (y).
    pub gradient: [f64; 2],
    /// Vignetting: relative intensity drop at the frame corners (quadratic in
    /// the distance from the centre).
    pub vignetting: f64,
    /// Electrons at full scale for shot noise; 0 disables shot noise.
    pub full_well_e: f64,
    /// Read noise standard deviation, fraction of full scale.
    pub read_noise: f64,
    /// Fraction of the frame area covered by dust (0..0.9).
    pub dust_fraction: f64,
    /// Dust blob radius range, px.
    pub dust_radius_px: (f64, f64),
    /// Transmission of dust (0 = opaque black).
    pub dust_transmission: f64,
    /// Seed for the dust layout (fixed per renderer: dust sits on the optics,
    /// not on the pattern).
    pub dust_seed: u64,
    /// Sub-pixels per pixel side (1..=4) for the optical blur. The PSF acts
    /// before pixel integration in a real camera; blurring the exact coverage
    /// on a grid `oversample` times finer and then box-summing to pixels keeps
    /// that order, so the dot pattern's high harmonics are attenuated by the
    /// PSF before they alias. With 1 the blur is applied after integration:
    /// faster, but at periods commensurate with the pixel grid (e.g. exactly
    /// 10 px, θ = 0) aliased harmonics bias phase-based decoders by ~6e-3 px.
    /// 2 removes that for any PSF with σ ≥ 0.3 px.
    pub oversample: usize,
    /// Put a dot on every lattice site (no code, no empty crossings): a plain
    /// grid. Decoder tests use it to separate effects of the missing (coded)
    /// dots from everything else; such frames cannot be decoded absolutely.
    pub plain_grid: bool,
}

impl Default for RenderConfig {
    /// 1024 × 768, 8-bit, 9 µm period, 12-bit code, bright dots, a mild
    /// diffraction-like blur and 0.5 % read noise: a clean microscope image.
    fn default() -> Self {
        Self {
            width: 1024,
            height: 768,
            bit_depth: 8,
            period_um: 9.0,
            bits: 12,
            dark_dots: false,
            background: 0.15,
            foreground: 0.85,
            blur_sigma_px: 0.8,
            defocus_radius_px: 0.0,
            gradient: [0.0, 0.0],
            vignetting: 0.0,
            full_well_e: 0.0,
            read_noise: 0.005,
            dust_fraction: 0.0,
            dust_radius_px: (3.0, 25.0),
            dust_transmission: 0.1,
            dust_seed: 1,
            oversample: 2,
            plain_grid: false,
        }
    }
}

/// A renderer holding the code sequence and scratch buffers, so rendering a
/// stream of frames allocates nothing after the first.
#[derive(Debug, Clone)]
pub struct Renderer {
    cfg: RenderConfig,
    seq: LineSequence,
    margin: usize,
    /// Coverage / intensity buffer with a margin on every side.
    buf: Vec<f32>,
    tmp: Vec<f32>,
    kernel: Vec<f32>,
    disc: Vec<f32>,
    disc_r: usize,
    /// Per-pixel shading (illumination × vignetting × dust), frame-sized.
    shade: Vec<f32>,
}

fn check(name: &'static str, value: f64, ok: bool, why: &'static str) -> Result<(), RenderError> {
    if ok && value.is_finite() {
        Ok(())
    } else {
        Err(RenderError::Invalid { name, value, why })
    }
}

/// What multiplies the pattern's light before noise: illumination gradient,
/// vignetting and occluding dust, all fixed to the image.
///
/// Why shared: the exact renderer here and the simulator's fast renderer
/// must put the same dust in the same place for the same seed, so tests can
/// compare them pixel for pixel.
#[derive(Debug, Clone, PartialEq)]
pub struct Shading {
    /// Frame width, px.
    pub width: usize,
    /// Frame height, px.
    pub height: usize,
    /// Linear illumination change across the frame (x, y), fraction of the
    /// centre value from the centre to the edge.
    pub gradient: [f64; 2],
    /// Light lost in the corners, fraction (quadratic in the radius).
    pub vignetting: f64,
    /// Fraction of the frame covered by dust.
    pub dust_fraction: f64,
    /// Dust blob radius range, px.
    pub dust_radius_px: (f64, f64),
    /// Light a dust blob lets through, fraction.
    pub dust_transmission: f64,
    /// Seed of the dust layout.
    pub dust_seed: u64,
}

/// The per-pixel light factor of [`Shading`], row-major.
pub fn shading_map(sh: &Shading) -> Vec<f32> {
    let (w, h) = (sh.width, sh.height);
    let (cx, cy) = (w as f64 / 2.0, h as f64 / 2.0);
    let r2max = (cx * cx + cy * cy).max(f64::MIN_POSITIVE);
    let mut shade = Vec::with_capacity(w * h);
    for i in 0..h {
        let y = i as f64 + 0.5 - cy;
        for j in 0..w {
            let x = j as f64 + 0.5 - cx;
            let g = 1.0 + sh.gradient[0] * x / w as f64 + sh.gradient[1] * y / h as f64;
            let v = 1.0 - sh.vignetting * (x * x + y * y) / r2max;
            shade.push((g * v).max(0.0) as f32);
        }
    }
    if sh.dust_fraction > 0.0 {
        let mut rng = ChaCha8Rng::seed_from_u64(sh.dust_seed);
        let mut dust = vec![0f32; w * h];
        let target = sh.dust_fraction * (w * h) as f64;
        let mut covered = 0.0;
        let (rmin, rmax) = sh.dust_radius_px;
        // Bounded: each blob covers at least one pixel's worth of area
        // on average, so the loop ends; the cap guards tiny frames.
        let mut tries = 0;
        while covered < target && tries < 100_000 {
            tries += 1;
            let rad = rng.gen_range(rmin..=rmax);
            let bx = rng.gen_range(0.0..w as f64);
            let by = rng.gen_range(0.0..h as f64);
            let i0 = (by - rad - 1.0).floor().max(0.0) as usize;
            let i1 = ((by + rad + 1.0).ceil() as usize).min(h);
            let j0 = (bx - rad - 1.0).floor().max(0.0) as usize;
            let j1 = ((bx + rad + 1.0).ceil() as usize).min(w);
            for i in i0..i1 {
                for j in j0..j1 {
                    let d = ((j as f64 + 0.5 - bx).powi(2) + (i as f64 + 0.5 - by).powi(2)).sqrt();
                    // Soft 1-px edge.
                    let m = (rad + 0.5 - d).clamp(0.0, 1.0) as f32;
                    let cell = &mut dust[i * w + j];
                    if m > *cell {
                        covered += f64::from(m - *cell);
                        *cell = m;
                    }
                }
            }
        }
        let t = sh.dust_transmission as f32;
        for (s, d) in shade.iter_mut().zip(&dust) {
            *s *= 1.0 - d * (1.0 - t);
        }
    }
    shade
}

impl Renderer {
    /// Builds a renderer, checking the configuration.
    pub fn new(cfg: RenderConfig) -> Result<Self, RenderError> {
        let seq = LineSequence::new(cfg.bits)?;
        if cfg.width == 0 || cfg.height == 0 {
            return Err(FrameError::Empty {
                width: cfg.width,
                height: cfg.height,
            }
            .into());
        }
        check(
            "width",
            cfg.width as f64,
            cfg.width <= 1 << 15,
            "at most 32768",
        )?;
        check(
            "height",
            cfg.height as f64,
            cfg.height <= 1 << 15,
            "at most 32768",
        )?;
        check(
            "bit_depth",
            f64::from(cfg.bit_depth),
            (1..=16).contains(&cfg.bit_depth),
            "1..=16",
        )?;
        check("period_um", cfg.period_um, cfg.period_um > 0.0, "> 0")?;
        check(
            "blur_sigma_px",
            cfg.blur_sigma_px,
            (0.0..=50.0).contains(&cfg.blur_sigma_px),
            "0..=50",
        )?;
        check(
            "defocus_radius_px",
            cfg.defocus_radius_px,
            (0.0..=30.0).contains(&cfg.defocus_radius_px),
            "0..=30",
        )?;
        check(
            "dust_fraction",
            cfg.dust_fraction,
            (0.0..=0.9).contains(&cfg.dust_fraction),
            "0..=0.9",
        )?;
        check(
            "dust_radius_px",
            cfg.dust_radius_px.0,
            cfg.dust_radius_px.0 > 0.0 && cfg.dust_radius_px.1 >= cfg.dust_radius_px.0,
            "0 < min <= max",
        )?;
        check("read_noise", cfg.read_noise, cfg.read_noise >= 0.0, ">= 0")?;
        check(
            "full_well_e",
            cfg.full_well_e,
            cfg.full_well_e >= 0.0,
            ">= 0",
        )?;
        check(
            "vignetting",
            cfg.vignetting,
            (0.0..1.0).contains(&cfg.vignetting),
            "0..1",
        )?;
        for g in cfg.gradient {
            check("gradient", g, g.abs() < 1.9, "|g| < 1.9")?;
        }
        check(
            "oversample",
            cfg.oversample as f64,
            (1..=4).contains(&cfg.oversample),
            "1..=4",
        )?;
        let f = cfg.oversample;
        let sigma = cfg.blur_sigma_px * f as f64;
        let kr = (4.0 * sigma).ceil() as usize;
        let kernel: Vec<f32> = if cfg.blur_sigma_px > 0.0 {
            let w: Vec<f64> = (0..=2 * kr)
                .map(|i| {
                    let d = i as f64 - kr as f64;
                    (-0.5 * d * d / (sigma * sigma)).exp()
                })
                .collect();
            let sum: f64 = w.iter().sum();
            w.iter().map(|v| (v / sum) as f32).collect()
        } else {
            vec![1.0]
        };
        let disc_r = (cfg.defocus_radius_px * f as f64).ceil() as usize;
        let disc = disc_kernel(cfg.defocus_radius_px * f as f64, disc_r);
        // Margin in output pixels, enough for both kernels on the fine grid.
        let margin = (kernel.len() / 2 + disc_r + f).div_ceil(f) + 1;
        let mut r = Self {
            cfg,
            seq,
            margin,
            buf: Vec::new(),
            tmp: Vec::new(),
            kernel,
            disc,
            disc_r,
            shade: Vec::new(),
        };
        r.build_shade();
        Ok(r)
    }

    /// The configuration in use.
    pub fn config(&self) -> &RenderConfig {
        &self.cfg
    }

    /// The pattern's line sequence.
    pub fn sequence(&self) -> &LineSequence {
        &self.seq
    }

    fn build_shade(&mut self) {
        self.shade = shading_map(&Shading {
            width: self.cfg.width,
            height: self.cfg.height,
            gradient: self.cfg.gradient,
            vignetting: self.cfg.vignetting,
            dust_fraction: self.cfg.dust_fraction,
            dust_radius_px: self.cfg.dust_radius_px,
            dust_transmission: self.cfg.dust_transmission,
            dust_seed: self.cfg.dust_seed,
        });
    }

    /// Renders the pattern seen at `pose`; `noise_seed` seeds this frame's
    /// shot and read noise (use a different seed per frame of a stream).
    pub fn render(
        &mut self,
        pose: &Pose,
        noise_seed: u64,
        timestamp_s: f64,
        sequence: u64,
    ) -> Result<Frame, RenderError> {
        check("pixel_um", pose.pixel_um, pose.pixel_um > 0.0, "> 0")?;
        check("x_um", pose.x_um, pose.x_um.abs() < 1e9, "finite")?;
        check("y_um", pose.y_um, pose.y_um.abs() < 1e9, "finite")?;
        check(
            "theta_rad",
            pose.theta_rad,
            pose.theta_rad.abs() < 1e6,
            "finite",
        )?;
        let period_px = self.cfg.period_um / pose.pixel_um;
        check(
            "period in pixels",
            period_px,
            period_px >= 1.0,
            ">= 1 px per period",
        )?;
        self.coverage(pose);
        self.blur();
        self.downsample();
        Ok(self.finish(noise_seed, timestamp_s, sequence)?)
    }

    /// Fills `buf` (frame plus margin) with the dot coverage of each pixel.
    fn coverage(&mut self, pose: &Pose) {
        // Everything here runs on the fine grid (oversample × finer).
        let f = self.cfg.oversample;
        let m = self.margin * f;
        let (w, h) = (self.cfg.width * f, self.cfg.height * f);
        let pose = &Pose {
            pixel_um: pose.pixel_um / f as f64,
            ..*pose
        };
        let bw = w + 2 * m;
        let bh = h + 2 * m;
        self.buf.clear();
        self.buf.resize(bw * bh, 0.0);
        let p = self.cfg.period_um;
        let s = pose.pixel_um;
        let (sn, cs) = pose.theta_rad.sin_cos();
        let fy = if pose.mirrored { -1.0 } else { 1.0 };
        // Image directions (px per µm / s) of the pattern axes: u = c + M Rᵀ (X − X0)/s.
        let e1 = (cs, fy * sn);
        let e2 = (-sn, fy * cs);
        // Image point of a pattern point, in buffer coordinates.
        let cxb = w as f64 / 2.0 + m as f64;
        let cyb = h as f64 / 2.0 + m as f64;
        let to_img = |x: f64, y: f64| {
            let dx = (x - pose.x_um) / s;
            let dy = (y - pose.y_um) / s;
            (cxb + e1.0 * dx + e2.0 * dy, cyb + e1.1 * dx + e2.1 * dy)
        };
        // Pattern bounding box of the buffer.
        let mut cmin = f64::MAX;
        let mut cmax = f64::MIN;
        let mut rmin = f64::MAX;
        let mut rmax = f64::MIN;
        for (u, v) in [
            (0.0, 0.0),
            (bw as f64, 0.0),
            (0.0, bh as f64),
            (bw as f64, bh as f64),
        ] {
            let (x, y) = pose.pattern_point(w, h, u - m as f64, v - m as f64);
            cmin = cmin.min(x / p);
            cmax = cmax.max(x / p);
            rmin = rmin.min(y / p);
            rmax = rmax.max(y / p);
        }
        let len = self.seq.len() as f64;
        let c0 = (cmin - 1.0).floor().max(0.0) as i64;
        let c1 = (cmax + 1.0).ceil().min(len) as i64;
        let r0 = (rmin - 1.0).floor().max(0.0) as i64;
        let r1 = (rmax + 1.0).ceil().min(len) as i64;
        let hside = p / (4.0 * s); // half side of a dot, px
                                   // Half extent of a pixel square projected on a dot axis.
        let rp = 0.5 * (cs.abs() + sn.abs());
        let ext = hside * (cs.abs() + sn.abs()) + 1.0;
        let plain = self.cfg.plain_grid;
        for r in r0..r1 {
            if !plain && !self.seq.line(r) {
                continue;
            }
            for c in c0..c1 {
                if !plain && !self.seq.dot(c, r) {
                    continue;
                }
                let (uc, vc) = to_img(c as f64 * p, r as f64 * p);
                if uc < -ext || vc < -ext || uc > bw as f64 + ext || vc > bh as f64 + ext {
                    continue;
                }
                let j0 = (uc - ext).floor().max(0.0) as usize;
                let j1 = ((uc + ext).ceil().max(0.0) as usize).min(bw);
                let i0 = (vc - ext).floor().max(0.0) as usize;
                let i1 = ((vc + ext).ceil().max(0.0) as usize).min(bh);
                for i in i0..i1 {
                    let dy = i as f64 + 0.5 - vc;
                    let row = &mut self.buf[i * bw..(i + 1) * bw];
                    for (j, cell) in row.iter_mut().enumerate().take(j1).skip(j0) {
                        let dx = j as f64 + 0.5 - uc;
                        // Pixel centre in dot-local coordinates.
                        let a = dx * e1.0 + dy * e1.1;
                        let b = dx * e2.0 + dy * e2.1;
                        if a.abs() >= hside + rp || b.abs() >= hside + rp {
                            continue;
                        }
                        let cov = if a.abs() <= hside - rp && b.abs() <= hside - rp {
                            1.0
                        } else {
                            clipped_area(a, b, e1, e2, hside)
                        };
                        *cell += cov as f32;
                    }
                }
            }
        }
    }

    /// Applies the Gaussian PSF (separable) and the defocus disc to `buf`.
    fn blur(&mut self) {
        let f = self.cfg.oversample;
        let m = self.margin * f;
        let bw = self.cfg.width * f + 2 * m;
        let bh = self.cfg.height * f + 2 * m;
        let k = &self.kernel;
        let kr = k.len() / 2;
        if kr > 0 {
            self.tmp.clear();
            self.tmp.resize(bw * bh, 0.0);
            // Horizontal pass into tmp.
            for i in 0..bh {
                let src = &self.buf[i * bw..(i + 1) * bw];
                let dst = &mut self.tmp[i * bw..(i + 1) * bw];
                for j in kr..bw.saturating_sub(kr) {
                    let mut acc = 0.0f32;
                    for (t, &kv) in k.iter().enumerate() {
                        acc += kv * src[j + t - kr];
                    }
                    dst[j] = acc;
                }
            }
            // Vertical pass back into buf, row-wise for cache friendliness.
            self.buf.iter_mut().for_each(|v| *v = 0.0);
            for i in kr..bh.saturating_sub(kr) {
                for (t, &kv) in k.iter().enumerate() {
                    let src = &self.tmp[(i + t - kr) * bw..(i + t - kr + 1) * bw];
                    let dst = &mut self.buf[i * bw..(i + 1) * bw];
                    for (d, s) in dst.iter_mut().zip(src) {
                        *d += kv * s;
                    }
                }
            }
        }
        let dr = self.disc_r;
        if dr > 0 {
            self.tmp.clear();
            self.tmp.resize(bw * bh, 0.0);
            let dn = 2 * dr + 1;
            for i in dr..bh - dr {
                for di in 0..dn {
                    let src = &self.buf[(i + di - dr) * bw..(i + di - dr + 1) * bw];
                    let dst = &mut self.tmp[i * bw..(i + 1) * bw];
                    for dj in 0..dn {
                        let kv = self.disc[di * dn + dj];
                        if kv == 0.0 {
                            continue;
                        }
                        for j in dr..bw - dr {
                            dst[j] += kv * src[j + dj - dr];
                        }
                    }
                }
            }
            std::mem::swap(&mut self.buf, &mut self.tmp);
        }
    }

    /// Box-sums the fine grid into output pixels (frame plus margin).
    fn downsample(&mut self) {
        let f = self.cfg.oversample;
        if f == 1 {
            return;
        }
        let m = self.margin;
        let bw = self.cfg.width + 2 * m;
        let bh = self.cfg.height + 2 * m;
        let fw = bw * f;
        let norm = 1.0 / (f * f) as f32;
        self.tmp.clear();
        self.tmp.resize(bw * bh, 0.0);
        for i in 0..bh {
            let dst = &mut self.tmp[i * bw..(i + 1) * bw];
            for a in 0..f {
                let src = &self.buf[(i * f + a) * fw..(i * f + a + 1) * fw];
                for (d, chunk) in dst.iter_mut().zip(src.chunks_exact(f)) {
                    *d += chunk.iter().sum::<f32>();
                }
            }
            dst.iter_mut().for_each(|v| *v *= norm);
        }
        std::mem::swap(&mut self.buf, &mut self.tmp);
    }

    /// Shading, noise and quantisation of the frame area of `buf`.
    fn finish(
        &mut self,
        noise_seed: u64,
        timestamp_s: f64,
        sequence: u64,
    ) -> Result<Frame, FrameError> {
        let m = self.margin;
        let (w, h) = (self.cfg.width, self.cfg.height);
        let bw = w + 2 * m;
        let fs = ((1u32 << self.cfg.bit_depth) - 1) as f32;
        let mut rng = ChaCha8Rng::seed_from_u64(noise_seed);
        let (bg, fg) = if self.cfg.dark_dots {
            (self.cfg.foreground as f32, self.cfg.background as f32)
        } else {
            (self.cfg.background as f32, self.cfg.foreground as f32)
        };
        let fw = self.cfg.full_well_e as f32;
        let rn = self.cfg.read_noise as f32;
        let mut out = Vec::with_capacity(w * h);
        for i in 0..h {
            let row = &self.buf[(i + m) * bw + m..(i + m) * bw + m + w];
            let shade = &self.shade[i * w..(i + 1) * w];
            for (&c, &sh) in row.iter().zip(shade) {
                let mut v = (bg + (fg - bg) * c) * sh;
                if fw > 0.0 {
                    let n: f32 = rng.sample(StandardNormal);
                    let e = (v.max(0.0) * fw).sqrt();
                    v += n * e / fw;
                }
                if rn > 0.0 {
                    let n: f32 = rng.sample(StandardNormal);
                    v += n * rn;
                }
                out.push((v * fs).round().clamp(0.0, fs));
            }
        }
        let pixels = if self.cfg.bit_depth <= 8 {
            Pixels::U8(out.iter().map(|&v| v as u8).collect())
        } else {
            Pixels::U16(out.iter().map(|&v| v as u16).collect())
        };
        Frame::new(w, h, self.cfg.bit_depth, pixels, timestamp_s, sequence)
    }
}

/// Disc PSF of radius `r` px on a (2·rc+1)² grid, weights = area of each
/// pixel inside the disc (8×8 supersampled), normalised.
fn disc_kernel(r: f64, rc: usize) -> Vec<f32> {
    if rc == 0 {
        return vec![1.0];
    }
    let n = 2 * rc + 1;
    let mut k = vec![0f64; n * n];
    const SS: usize = 8;
    for i in 0..n {
        for j in 0..n {
            let mut cnt = 0;
            for a in 0..SS {
                for b in 0..SS {
                    let y = i as f64 - rc as f64 - 0.5 + (a as f64 + 0.5) / SS as f64;
                    let x = j as f64 - rc as f64 - 0.5 + (b as f64 + 0.5) / SS as f64;
                    if x * x + y * y <= r * r {
                        cnt += 1;
                    }
                }
            }
            k[i * n + j] = cnt as f64;
        }
    }
    let sum: f64 = k.iter().sum();
    k.iter().map(|v| (v / sum.max(1.0)) as f32).collect()
}

/// Exact area of the intersection of a unit pixel (centre at dot-local
/// (a, b), sides along the image axes whose dot-local directions are given by
/// `e1`, `e2` components) with the square |x|, |y| ≤ h.
fn clipped_area(a: f64, b: f64, e1: (f64, f64), e2: (f64, f64), h: f64) -> f64 {
    // Image unit vectors in dot-local coordinates: image x -> (e1.0, e2.0), image y -> (e1.1, e2.1).
    let ix = (e1.0 * 0.5, e2.0 * 0.5);
    let iy = (e1.1 * 0.5, e2.1 * 0.5);
    let mut poly = [(0.0, 0.0); 8];
    let mut n = 4;
    poly[0] = (a - ix.0 - iy.0, b - ix.1 - iy.1);
    poly[1] = (a + ix.0 - iy.0, b + ix.1 - iy.1);
    poly[2] = (a + ix.0 + iy.0, b + ix.1 + iy.1);
    poly[3] = (a - ix.0 + iy.0, b - ix.1 + iy.1);
    // Clip against x <= h, -x <= h, y <= h, -y <= h.
    for (axis, sign) in [(0, 1.0), (0, -1.0), (1, 1.0), (1, -1.0)] {
        let mut out = [(0.0, 0.0); 8];
        let mut m = 0;
        let val = |p: (f64, f64)| sign * if axis == 0 { p.0 } else { p.1 } - h;
        for k in 0..n {
            let cur = poly[k];
            let nxt = poly[(k + 1) % n];
            let dc = val(cur);
            let dn = val(nxt);
            if dc <= 0.0 {
                if m < 8 {
                    out[m] = cur;
                    m += 1;
                }
                if dn > 0.0 && m < 8 {
                    let t = dc / (dc - dn);
                    out[m] = (cur.0 + t * (nxt.0 - cur.0), cur.1 + t * (nxt.1 - cur.1));
                    m += 1;
                }
            } else if dn <= 0.0 && m < 8 {
                let t = dc / (dc - dn);
                out[m] = (cur.0 + t * (nxt.0 - cur.0), cur.1 + t * (nxt.1 - cur.1));
                m += 1;
            }
        }
        poly = out;
        n = m;
        if n < 3 {
            return 0.0;
        }
    }
    let mut area = 0.0;
    for k in 0..n {
        let p0 = poly[k];
        let p1 = poly[(k + 1) % n];
        area += p0.0 * p1.1 - p1.0 * p0.1;
    }
    (0.5 * area).abs()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ideal(w: usize, h: usize) -> RenderConfig {
        RenderConfig {
            width: w,
            height: h,
            blur_sigma_px: 0.0,
            read_noise: 0.0,
            background: 0.0,
            foreground: 1.0,
            bits: 4,
            period_um: 10.0,
            ..RenderConfig::default()
        }
    }

    #[test]
    fn clipped_area_matches_supersampling() {
        let (s, c) = 0.37f64.sin_cos();
        let e1 = (c, s);
        let e2 = (-s, c);
        for &(a, b) in &[(0.0, 0.0), (2.3, 0.1), (2.6, 2.4), (-2.5, 1.0), (3.1, -3.0)] {
            let exact = clipped_area(a, b, e1, e2, 2.5);
            // Supersample the pixel in image coordinates.
            let n = 400;
            let mut cnt = 0;
            for i in 0..n {
                for j in 0..n {
                    let dx = (j as f64 + 0.5) / n as f64 - 0.5;
                    let dy = (i as f64 + 0.5) / n as f64 - 0.5;
                    let la = a + dx * e1.0 + dy * e1.1;
                    let lb = b + dx * e2.0 + dy * e2.1;
                    if la.abs() <= 2.5 && lb.abs() <= 2.5 {
                        cnt += 1;
                    }
                }
            }
            let ss = cnt as f64 / (n * n) as f64;
            assert!((exact - ss).abs() < 5e-3, "({a},{b}) exact {exact} ss {ss}");
        }
    }

    #[test]
    fn total_coverage_equals_dot_area() {
        // Sum of pixel values equals the number of dots times the dot area,
        // for any rotation, when all dots lie well inside the frame.
        let mut r = Renderer::new(RenderConfig {
            bit_depth: 16,
            ..ideal(200, 200)
        })
        .unwrap();
        let seq = r.sequence().clone();
        let pose = Pose {
            x_um: 305.0,
            y_um: 412.0,
            theta_rad: 0.7,
            pixel_um: 1.0,
            mirrored: false,
        };
        let f = r.render(&pose, 0, 0.0, 0).unwrap();
        let mut sum = 0.0;
        let mut inside = 0usize;
        let mut border = false;
        for c in 0..seq.len() as i64 {
            for rr in 0..seq.len() as i64 {
                let x = c as f64 * 10.0 - pose.x_um;
                let y = rr as f64 * 10.0 - pose.y_um;
                // Image position (no mirror): u = c + Rᵀ d.
                let (sn, cs) = pose.theta_rad.sin_cos();
                let u = 100.0 + cs * x - sn * y;
                let v = 100.0 + sn * x + cs * y;
                let in_frame = (5.0..195.0).contains(&u) && (5.0..195.0).contains(&v);
                let near = (-5.0..205.0).contains(&u) && (-5.0..205.0).contains(&v);
                if seq.dot(c, rr) {
                    if in_frame {
                        inside += 1;
                    } else if near {
                        border = true;
                    }
                }
            }
        }
        assert!(!border || inside > 0);
        if let Pixels::U16(p) = f.pixels() {
            sum += p.iter().map(|&v| f64::from(v) / 65535.0).sum::<f64>();
        }
        // Dots partly outside make the sum an upper-bounded mix; check only
        // that the sum is between the inside-only area and a loose bound.
        assert!(
            sum >= inside as f64 * 25.0 * 0.999,
            "sum {sum} inside {inside}"
        );
    }

    #[test]
    fn axis_aligned_dot_position_and_mirror() {
        let mut r = Renderer::new(ideal(64, 64)).unwrap();
        // Dot (2, 2) exists (row/col 2 are full lines, not a 0,0 crossing).
        assert!(r.sequence().dot(2, 2));
        let pose = Pose {
            x_um: 20.0,
            y_um: 20.0,
            theta_rad: 0.0,
            pixel_um: 1.0,
            mirrored: false,
        };
        let f = r.render(&pose, 0, 0.0, 0).unwrap();
        // Dot centred at the image centre (32, 32), side 5 px: pixels 30..34 full.
        assert_eq!(f.get(31, 31), Some(255));
        assert_eq!(f.get(33, 33), Some(255));
        // Edge pixels half covered.
        assert_eq!(f.get(29, 31), Some(128));
        assert_eq!(f.get(37, 32), Some(0));
        // θ = 90°: pattern +x points along image +y.
        let pose90 = Pose {
            x_um: 25.0,
            theta_rad: std::f64::consts::FRAC_PI_2,
            ..pose
        };
        let f = r.render(&pose90, 0, 0.0, 0).unwrap();
        // Pattern point x=20 (dot 2) lies at image v = 32 - 5 = 27.
        assert_eq!(f.get(32, 27), Some(255));
        assert_eq!(f.get(32, 32), Some(0));
        // Pattern +y points along image −x: dot row 3 (y = 30) is at u = 22.
        assert_eq!(f.get(22, 27), Some(255));
        let mirrored = Pose {
            y_um: 25.0,
            mirrored: true,
            ..pose
        };
        let f = r.render(&mirrored, 0, 0.0, 0).unwrap();
        // Mirrored: pattern +y points along image −v, dot row 2 at v = 32 + 5.
        assert_eq!(f.get(32, 37), Some(255));
    }

    #[test]
    fn rejects_bad_parameters() {
        assert!(Renderer::new(RenderConfig {
            bits: 3,
            ..RenderConfig::default()
        })
        .is_err());
        assert!(Renderer::new(RenderConfig {
            blur_sigma_px: f64::NAN,
            ..RenderConfig::default()
        })
        .is_err());
        let mut r = Renderer::new(ideal(8, 8)).unwrap();
        let pose = Pose {
            x_um: 0.0,
            y_um: 0.0,
            theta_rad: 0.0,
            pixel_um: 0.0,
            mirrored: false,
        };
        assert!(r.render(&pose, 0, 0.0, 0).is_err());
    }

    #[test]
    fn noise_is_seeded_and_dust_darkens() {
        let cfg = RenderConfig {
            width: 96,
            height: 64,
            read_noise: 0.02,
            full_well_e: 10_000.0,
            ..RenderConfig::default()
        };
        let pose = Pose {
            x_um: 500.0,
            y_um: 700.0,
            theta_rad: 0.2,
            pixel_um: 0.9,
            mirrored: false,
        };
        let mut r = Renderer::new(cfg.clone()).unwrap();
        let a = r.render(&pose, 5, 0.0, 0).unwrap();
        let b = r.render(&pose, 5, 0.0, 0).unwrap();
        let c = r.render(&pose, 6, 0.0, 0).unwrap();
        assert_eq!(a, b);
        assert_ne!(a, c);
        let mut dusty = Renderer::new(RenderConfig {
            dust_fraction: 0.3,
            read_noise: 0.0,
            full_well_e: 0.0,
            ..cfg.clone()
        })
        .unwrap();
        let mut clean = Renderer::new(RenderConfig {
            read_noise: 0.0,
            full_well_e: 0.0,
            ..cfg
        })
        .unwrap();
        let sum = |f: &Frame| match f.pixels() {
            Pixels::U8(p) => p.iter().map(|&v| u64::from(v)).sum::<u64>(),
            Pixels::U16(_) => 0,
        };
        let d = dusty.render(&pose, 0, 0.0, 0).unwrap();
        let cl = clean.render(&pose, 0, 0.0, 0).unwrap();
        assert!((sum(&d) as f64) < 0.85 * sum(&cl) as f64);
    }
}
