//! A fast renderer of the Megarena pattern for a fixed mounting angle.
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
//! Same conventions as micropos's renderer (pixel j covers [j, j+1), the
//! pose is the pattern point at (W/2, H/2), θ from image +x to pattern +x).
//! A defocus disc of radius R is approximated by a Gaussian of the same
//! variance (σ² + R²/4). Stamps are exact PSF-then-pixel integration (the
//! Gaussian-blurred square is a product of error functions in the dot's own
//! axes; the pixel integral is a 32 × 32 midpoint sum via a summed-area
//! table).

use super::config::CameraConfig;
use micropos::frame::{Frame, Pixels};
use micropos::pattern::render::{shading_map, Shading};
use micropos::pattern::sequence::LineSequence;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Sub-pixel phases per pixel side.
const Q: usize = 32;
/// Length of the Gaussian noise table (power of two).
const NOISE_LEN: usize = 1 << 20;
/// Image rows rendered at once by one thread (see
/// [`FastRenderer::render_pixels`]): 64 rows of a 1024-px frame are a
/// 256 KB accumulator, which stays in a core's L2 cache.
const BAND_ROWS: usize = 64;

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
            seq,
            k,
            side,
            stride,
            stamps,
            shade: Vec::new(),
            noise,
            acc: vec![0.0; 2 * BAND_ROWS * cfg.width],
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
    /// rows, instant by instant and in the same dot order (so every pixel
    /// gets the same additions in the same order as on one thread over the
    /// whole frame: same bits), then turn the band into pixels and zero it.
    /// One point has weight exactly 1, so a still frame is the sharp render
    /// bit for bit. Why bands: a band's accumulator
    /// (256 KB) stays in the core's cache from the first stamp to the
    /// sensor pass, where a whole-frame accumulator (3 MB) goes to memory
    /// and back three times (stamps, sensor pass, clearing); the cost is
    /// that a dot whose stamp straddles two bands is placed twice.
    fn render_pixels(&mut self, path_um: &[[f64; 2]], p: &FinishParams) -> Vec<u16> {
        let mut acc = std::mem::take(&mut self.acc);
        let zeroed = std::mem::replace(&mut self.acc_zero, false);
        let (w, h) = (self.cfg.width, self.cfg.height);
        let weight = 1.0 / path_um.len().max(1) as f32;
        let mut out16 = vec![0u16; w * h];
        let (acc_top, acc_bottom) = acc.split_at_mut(BAND_ROWS * w);
        let (out_top, out_bottom) = out16.split_at_mut(h / 2 * w);
        let this = &*self;
        let half = |acc: &mut [f32], out: &mut [u16], row0: usize| {
            this.arch.dispatch(Half {
                r: this,
                zeroed,
                path_um,
                weight,
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

    /// The frame as the reference two-pass render computes it: all stamps
    /// into a whole-frame accumulator (each image half summed on its own,
    /// instant by instant), then the sensor model over the whole frame.
    /// What [`FastRenderer::render_pixels`] must reproduce bit for bit.
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
        let weight = 1.0 / path_um.len().max(1) as f32;
        for &[x, y] in path_um {
            self.stamp_rows(&mut acc[..h / 2 * w], 0, x, y, weight);
            self.stamp_rows(&mut acc[h / 2 * w..], h / 2, x, y, weight);
        }
        let p = self.finish_params(light, analog_gain, noise_seed);
        let mut out16 = vec![0u16; w * h];
        self.finish_rows(&p, &mut acc, &mut out16, 0);
        out16
    }

    /// Adds the stamps of the dots seen with `(x_um, y_um)` at the image
    /// centre, times `weight`, to the image rows `row0..` that `band`
    /// (whole rows of the accumulator) holds.
    #[inline(always)]
    fn stamp_rows(&self, band: &mut [f32], row0: usize, x_um: f64, y_um: f64, weight: f32) {
        let (w, h) = (self.cfg.width as i64, self.cfg.height as i64);
        let band_lo = row0 as i64;
        let band_hi = band_lo + (band.len() / self.cfg.width) as i64;
        let p = self.cfg.period_um;
        let s = self.cfg.pixel_um;
        let (sn, cs) = self.theta_rad.sin_cos();
        let (e1, e2) = ((cs, sn), (-sn, cs));
        let (cxi, cyi) = (w as f64 / 2.0, h as f64 / 2.0);
        // Pattern bounding box of the band's rows plus the stamp margin:
        // every dot whose stamp reaches the band, in the frame's dot order.
        let m = self.k as f64 + 1.0;
        let (v_lo, v_hi) = (band_lo as f64 - m, band_hi as f64 + m);
        let mut cmin = f64::MAX;
        let mut cmax = f64::MIN;
        let mut rmin = f64::MAX;
        let mut rmax = f64::MIN;
        for (u, v) in [
            (-m, v_lo),
            (w as f64 + m, v_lo),
            (-m, v_hi),
            (w as f64 + m, v_hi),
        ] {
            let du = u - cxi;
            let dv = v - cyi;
            let x = x_um + s * (cs * du + sn * dv);
            let y = y_um + s * (-sn * du + cs * dv);
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
        let k = self.k as i64;
        let (side, stride) = (self.side, self.stride);
        let wu = w as usize;
        for r in r0..r1 {
            if !self.seq.line(r) {
                continue;
            }
            let dy = (r as f64 * p - y_um) / s;
            for c in c0..c1 {
                if !self.seq.dot(c, r) {
                    continue;
                }
                let dx = (c as f64 * p - x_um) / s;
                let uc = cxi + e1.0 * dx + e2.0 * dy;
                let vc = cyi + e1.1 * dx + e2.1 * dy;
                let mut j0 = floor(uc);
                let mut a = round_non_negative((uc - j0) * Q as f64) as usize;
                if a >= Q {
                    a = 0;
                    j0 += 1.0;
                }
                let mut i0 = floor(vc);
                let mut b = round_non_negative((vc - i0) * Q as f64) as usize;
                if b >= Q {
                    b = 0;
                    i0 += 1.0;
                }
                let (j0, i0) = (j0 as i64 - k, i0 as i64 - k);
                if j0 >= w || i0 >= band_hi || j0 + side as i64 <= 0 || i0 + side as i64 <= band_lo
                {
                    continue;
                }
                let ph = (b * Q + a) * side * stride;
                let stamp = &self.stamps[ph..ph + side * stride];
                let kx0 = (-j0).max(0) as usize;
                let kx1 = ((w - j0).min(side as i64)) as usize;
                let ky0 = (band_lo - i0).max(0);
                let ky1 = (band_hi - i0).min(side as i64);
                // A stamp whose padded rows fit in the image adds whole
                // vectors: the padding adds +0.0 · weight = +0.0, which
                // leaves every sum as it was (the accumulator starts at
                // +0.0 and is never −0.0), so the bits are those of the
                // unpadded row.
                let whole = j0 >= 0 && j0 + stride as i64 <= w;
                for ky in ky0..ky1 {
                    let row = (i0 + ky - band_lo) as usize * wu;
                    let ky = ky as usize;
                    if whole {
                        let at = row + j0 as usize;
                        let dst = &mut band[at..at + stride];
                        let src = &stamp[ky * stride..(ky + 1) * stride];
                        for (d, s) in dst.chunks_exact_mut(8).zip(src.chunks_exact(8)) {
                            add8(d, s, weight);
                        }
                        continue;
                    }
                    let dst = &mut band
                        [row + (j0 + kx0 as i64) as usize..row + (j0 + kx1 as i64) as usize];
                    let src = &stamp[ky * stride + kx0..ky * stride + kx1];
                    for (d, s) in dst.iter_mut().zip(src) {
                        *d += s * weight;
                    }
                }
            }
        }
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
    /// instants). Why averaged renders rather than a smeared stamp: the
    /// stamps stay exact and the cost is one dot pass per instant, a few
    /// for the blur of a sweep (0.2–1 µm per exposure).
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
        let out16 = self.render_pixels(path_um, &p);
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
        let out16 = self.render_pixels(&[], &p);
        self.to_frame(out16, timestamp_s, sequence)
    }

    /// The sensor model's constants for one frame and its noise offsets:
    /// each row reads the noise table from its own random offset, drawn in
    /// row order (so the frame is a function of the seed alone).
    fn finish_params(&self, gain: f64, analog_gain: f64, noise_seed: u64) -> FinishParams {
        let (w, h) = (self.cfg.width, self.cfg.height);
        let (bg, fg) = if self.cfg.dark_dots {
            (self.cfg.foreground as f32, self.cfg.background as f32)
        } else {
            (self.cfg.background as f32, self.cfg.foreground as f32)
        };
        let inv_fw = if self.cfg.full_well_e > 0.0 {
            (1.0 / self.cfg.full_well_e) as f32
        } else {
            0.0
        };
        let mut rng = ChaCha8Rng::seed_from_u64(noise_seed);
        FinishParams {
            fs: ((1u32 << self.cfg.bit_depth) - 1) as f32,
            bg,
            fg,
            g: gain as f32,
            ag: analog_gain as f32,
            inv_fw,
            rn2: (self.cfg.read_noise * self.cfg.read_noise) as f32,
            offsets: (0..h)
                .map(|_| rng.gen_range(0..NOISE_LEN.saturating_sub(w).max(1)))
                .collect(),
        }
    }

    /// Shades, adds noise to and quantises the image rows `row0..` whose
    /// accumulated stamps `acc` holds (whole rows) into `out`, and zeroes
    /// each row of `acc` once read. Row by row over equal-length slices,
    /// written in place: the loop body is branch-free, so its arithmetic
    /// compiles to vector code.
    #[inline(always)]
    fn finish_rows(&self, p: &FinishParams, acc: &mut [f32], out: &mut [u16], row0: usize) {
        let w = self.cfg.width;
        let (shade, noise) = (&self.shade, &self.noise);
        let FinishParams {
            fs,
            bg,
            fg,
            g,
            ag,
            inv_fw,
            rn2,
            ..
        } = *p;
        for (k, (out, acc)) in out
            .chunks_exact_mut(w)
            .zip(acc.chunks_exact_mut(w))
            .enumerate()
        {
            let i = row0 + k;
            let shade = &shade[i * w..(i + 1) * w];
            let off = p.offsets[i];
            let noise_row = &noise[off..(off + w).min(NOISE_LEN)];
            for (((o, &c), &sh), &n) in out.iter_mut().zip(&*acc).zip(shade).zip(noise_row) {
                let v = (bg + (fg - bg) * c) * sh * g;
                let var = v.max(0.0) * inv_fw + rn2;
                let v = ag * (v + n * var.sqrt());
                *o = quantize((v * fs).max(0.0).min(fs));
            }
            acc.fill(0.0);
        }
    }

    /// The frame of quantised pixels `out16` (narrowed to bytes for depths
    /// up to 8 bits).
    fn to_frame(&self, out16: Vec<u16>, timestamp_s: f64, sequence: u64) -> Result<Frame, String> {
        let (w, h) = (self.cfg.width, self.cfg.height);
        let pixels = if self.cfg.bit_depth <= 8 {
            Pixels::U8(out16.iter().map(|&v| v as u8).collect())
        } else {
            Pixels::U16(out16)
        };
        Frame::new(w, h, self.cfg.bit_depth, pixels, timestamp_s, sequence)
            .map_err(|e| e.to_string())
    }
}

/// One image half of [`FastRenderer::render_pixels`], band by band, as a
/// `pulp` operation: its body (and the inlined stamp and sensor loops) is
/// compiled once per instruction set and run with the widest the CPU has.
struct Half<'a> {
    r: &'a FastRenderer,
    /// The band accumulator is +0.0 already (see `FastRenderer::acc_zero`).
    zeroed: bool,
    path_um: &'a [[f64; 2]],
    weight: f32,
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
            for &[x, y] in self.path_um {
                self.r.stamp_rows(acc, band0, x, y, self.weight);
            }
            self.r.finish_rows(self.p, acc, out, band0);
        }
    }
}

/// The sensor model's constants for one frame (see
/// [`FastRenderer::finish_params`]).
#[derive(Debug, Clone)]
struct FinishParams {
    /// Full scale, ADC codes.
    fs: f32,
    /// Background and dot levels, fractions of full scale.
    bg: f32,
    fg: f32,
    /// Illumination × exposure, and analog gain.
    g: f32,
    ag: f32,
    /// 1 / full well, and read noise², in the model's units.
    inv_fw: f32,
    rn2: f32,
    /// Per row: the start of its noise in the Gaussian table.
    offsets: Vec<usize>,
}

/// `d += s · weight` over eight lanes: both read into registers before
/// the store, so the compiler need not prove that `d` and `s` do not
/// overlap and emits one vector multiply and add (a plain loop over the
/// two slices stayed scalar).
#[inline(always)]
fn add8(d: &mut [f32], s: &[f32], weight: f32) {
    let (Ok(dv), Ok(sv)) = (<[f32; 8]>::try_from(&*d), <[f32; 8]>::try_from(s)) else {
        return;
    };
    let mut out = [0f32; 8];
    for ((o, a), b) in out.iter_mut().zip(dv).zip(sv) {
        *o = a + b * weight;
    }
    d.copy_from_slice(&out);
}

/// `x.floor()`, exactly, for |x| < 2⁶³ (a dot's image position). Why not
/// `f64::floor`: the baseline x86-64 target has no rounding instruction,
/// so that is a libm call, two per dot and instant of every frame.
#[inline(always)]
fn floor(x: f64) -> f64 {
    let t = x as i64 as f64;
    if t > x {
        t - 1.0
    } else {
        t
    }
}

/// `x.round()` (half away from zero), exactly, for 0 ≤ x < 2⁶³: the
/// fractional part `x − trunc(x)` of a float is exact. Same reason as
/// [`floor`].
#[inline(always)]
fn round_non_negative(x: f64) -> f64 {
    let t = x as i64 as f64;
    if x - t >= 0.5 {
        t + 1.0
    } else {
        t
    }
}

/// 2²³ as f32: adding it to a value in [0, 2²³) leaves that value rounded
/// to an integer (ties to even) in the low mantissa bits.
const ROUND_MAGIC: f32 = 8_388_608.0;

/// `x` (in 0..=65535, not NaN) rounded to the nearest integer, ties to even,
/// as the ADC's code. Why not `x.round() as u16`: Rust's float-to-int
/// casts must saturate and map NaN to 0, which keeps LLVM from vectorizing
/// the loop; this is two vector instructions and the pixel loop is the
/// simulated camera's largest cost.
#[inline(always)]
fn quantize(x: f32) -> u16 {
    ((x + ROUND_MAGIC).to_bits() - ROUND_MAGIC.to_bits()) as u16
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantize_rounds_to_nearest_even() {
        for (x, want) in [
            (0.0, 0u16),
            (0.49, 0),
            (0.5, 0),
            (0.51, 1),
            (1.5, 2),
            (2.5, 2),
            (1023.4, 1023),
            (65534.5, 65534),
            (65535.0, 65535),
        ] {
            assert_eq!(quantize(x), want, "{x}");
        }
        for i in 0..=65535u16 {
            assert_eq!(quantize(f32::from(i)), i);
        }
    }

    #[test]
    fn inline_floor_and_round_are_the_std_ones() {
        let mut xs = vec![
            0.0,
            -0.0,
            0.5,
            1.5,
            2.5,
            0.499_999_999_999_999_94,
            -0.5,
            -1.0,
            -1.000_000_000_000_000_2,
            31.999_999_999_999_996,
            1e9,
            -1e9 + 0.5,
            4_503_599_627_370_497.0,
        ];
        let mut z = 0.123_456_789f64;
        for _ in 0..10_000 {
            z = (z * 3.9 * (1.0 - z)).clamp(1e-9, 1.0 - 1e-9);
            xs.push((z - 0.5) * 2e4);
            xs.push(z * 32.0);
        }
        for x in xs {
            assert_eq!(floor(x), x.floor(), "floor({x})");
            if x >= 0.0 {
                assert_eq!(round_non_negative(x), x.round(), "round({x})");
            }
        }
    }

    #[test]
    fn erfc_is_accurate() {
        for (x, want) in [
            (0.0, 1.0),
            (0.5, 0.479_500_122_186_953_5),
            (1.0, 0.157_299_207_050_285_1),
            (-1.0, 1.842_700_792_949_715),
            (2.5, 4.069_520_174_449_59e-4),
        ] {
            assert!((erfc(x) - want).abs() < 2e-7, "erfc({x})");
        }
    }

    #[test]
    fn banded_render_gives_the_two_pass_frame_bit_for_bit() {
        // Odd heights: the halves differ in size and end in partial bands
        // (71 rows: one band and a bit per half; 171: several). A still
        // frame, a blurred one (three instants) and a blank one, rendered
        // both ways on the same renderer.
        for height in [71, 171] {
            let cfg = CameraConfig {
                width: 96,
                height,
                ..CameraConfig::default()
            };
            let mut r = FastRenderer::new(&cfg, 0.3f64.to_radians()).unwrap();
            let paths: [&[[f64; 2]]; 2] = [
                &[[1234.5, 987.25]],
                &[[2000.0, 1500.0], [2000.3, 1500.1], [2000.6, 1500.2]],
            ];
            for (k, path) in paths.into_iter().enumerate() {
                let seed = 17 + k as u64;
                let banded = r.render_path(path, 0.9, 1.3, seed, 1.0, 5).unwrap();
                let two_pass = r.two_pass(path, 0.9, 1.3, seed);
                assert_eq!(
                    banded.pixels(),
                    &Pixels::U16(two_pass),
                    "height {height}, path {k}"
                );
                assert_ne!(
                    r.render_path(path, 0.9, 1.3, seed + 1, 1.0, 5)
                        .unwrap()
                        .pixels(),
                    banded.pixels(),
                    "another noise seed gives another frame"
                );
            }
            let blank = r.garbage(false, 3, 0.0, 1).unwrap();
            assert_eq!(blank.pixels(), &Pixels::U16(r.two_pass(&[], 1.0, 1.0, 3)));
        }
    }

    #[test]
    fn a_stamp_integrates_to_the_dot_area() {
        let cfg = CameraConfig {
            width: 64,
            height: 64,
            ..CameraConfig::default()
        };
        let r = FastRenderer::new(&cfg, 0.3f64.to_radians()).unwrap();
        let (side, stride) = (r.side, r.stride);
        let area_px = (cfg.period_um / 2.0 / cfg.pixel_um).powi(2);
        for ph in [0, 5, Q * Q - 1] {
            let s: f32 = r.stamps[ph * side * stride..(ph + 1) * side * stride]
                .iter()
                .sum();
            assert!(
                (f64::from(s) - area_px).abs() < 1e-3 * area_px,
                "{s} vs {area_px}"
            );
        }
    }
}
