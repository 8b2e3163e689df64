//! What the sensor adds after the optics: illumination shading, vignetting
//! and dust (shared with the simulator's fast renderer), shot and read noise,
//! and quantisation to the frame's bit depth.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

use super::Renderer;
use crate::frame::{Frame, FrameError, Pixels};

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
    pub(super) fn build_shade(&mut self) {
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

    /// Shading, noise and quantisation of the frame area of `buf`.
    pub(super) fn finish(
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
