//! The sensor: shading, shot and read noise from the precomputed Gaussian
//! table, quantisation to ADC codes, and the frame built from the codes.
//! A file of its own: what turns the accumulated light of a band into
//! pixels, after the dots are placed.

use super::{FastRenderer, NOISE_LEN};
use micropos::frame::{Frame, Pixels};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

impl FastRenderer {
    /// The sensor model's constants for one frame and its noise offsets:
    /// each row reads the noise table from its own random offset, drawn in
    /// row order (so the frame is a function of the seed alone).
    pub(super) fn finish_params(
        &self,
        gain: f64,
        analog_gain: f64,
        noise_seed: u64,
    ) -> FinishParams {
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
    pub(super) fn finish_rows(
        &self,
        p: &FinishParams,
        acc: &mut [f32],
        out: &mut [u16],
        row0: usize,
    ) {
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
    pub(super) fn to_frame(
        &self,
        out16: Vec<u16>,
        timestamp_s: f64,
        sequence: u64,
    ) -> Result<Frame, String> {
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

/// The sensor model's constants for one frame (see
/// [`FastRenderer::finish_params`]).
#[derive(Debug, Clone)]
pub(super) struct FinishParams {
    /// Full scale, ADC codes.
    pub(super) fs: f32,
    /// Background and dot levels, fractions of full scale.
    pub(super) bg: f32,
    pub(super) fg: f32,
    /// Illumination × exposure, and analog gain.
    pub(super) g: f32,
    pub(super) ag: f32,
    /// 1 / full well, and read noise², in the model's units.
    pub(super) inv_fw: f32,
    pub(super) rn2: f32,
    /// Per row: the start of its noise in the Gaussian table.
    pub(super) offsets: Vec<usize>,
}

/// 2²³ as f32: adding it to a value in [0, 2²³) leaves that value rounded
/// to an integer (ties to even) in the low mantissa bits.
pub(super) const ROUND_MAGIC: f32 = 8_388_608.0;

/// `x` (in 0..=65535, not NaN) rounded to the nearest integer, ties to even,
/// as the ADC's code. Why not `x.round() as u16`: Rust's float-to-int
/// casts must saturate and map NaN to 0, which keeps LLVM from vectorizing
/// the loop; this is two vector instructions and the pixel loop is the
/// simulated camera's largest cost.
#[inline(always)]
pub(super) fn quantize(x: f32) -> u16 {
    ((x + ROUND_MAGIC).to_bits() - ROUND_MAGIC.to_bits()) as u16
}
