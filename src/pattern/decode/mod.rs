//! Absolute position decoding of Megarena frames.
//!
//! # Conventions
//! * Pattern frame: origin at the centre of dot (0, 0), x along increasing
//!   column, y along increasing row, µm.
//! * Image frame: pixel j covers [j, j+1); the reported position is that of
//!   the image centre point (W/2, H/2).
//! * θ is the angle from the image +x axis to the pattern +x axis, towards
//!   image +y, in (−π, π] (the code tells 90°/180°/270° apart). A pattern point
//!   seen at image point u is X = (x, y) + s·R·M·(u − (W/2, H/2)) with
//!   R = [[cos θ, sin θ], [−sin θ, cos θ]], s the pixel size in µm and
//!   M = diag(1, −1) when [`DecodeOptions::mirrored`] is set (identity
//!   otherwise). A mirror cannot be detected from the image — the pattern is
//!   symmetric under transposition — so it is an option, never a guess: a
//!   wrong setting swaps x and y.
//!
//! # Stages
//! [`fine`] (full frame, O(pixels)): the two grid wave vectors and their
//! phases at the image centre. [`coarse`] (per dot site): polarity,
//! orientation and the code position. Both use the same lattice origin — the
//! dot site nearest the centre in the fine grid is the site whose absolute
//! line indices the code gives — so the absolute position is
//! p · (line of site 0 + fractional phase), and a phase wrap can never slip a
//! period.
//!
//! # Quality
//! [`Decoded::quality`] is the smaller of the two code-correlation margins in
//! bits of evidence: log₂ of the likelihood ratio between the chosen code
//! offset and the runner-up, from per-dot log-likelihood ratios (present vs
//! absent, calibrated per frame on the dots whose state the layout fixes,
//! each capped at 2 nats) summed along the code lines. Decoding refuses
//! (error [`DecodeError::CodeAmbiguous`]) below
//! [`CoarseThresholds::min_code_margin_bits`] (default 16 bits, about six
//! clearly read dots net on the lines that tell the two offsets apart).
//! Clean 1024×768 views of a 12-bit pattern score in the hundreds; 768×640
//! crops of the real image (runner-up offsets differing in a single code
//! line) score 80–110. Finer diagnostics are in [`Quality`].

// `!(x >= t)` is deliberate: it also rejects NaN. Index loops mirror the maths.
#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::needless_range_loop)]

pub mod coarse;
mod error;
pub mod fine;
mod helper;
mod simd;
mod sites;

pub use coarse::{CoarseThresholds, CodeCheck, CODE_CHANCE_MAX};
pub use fine::Grid;

use std::sync::Arc;

use crate::frame::Frame;
use crate::pattern::sequence::LineSequence;
use sites::{missing_dot_correction, theta_wave_vectors};

pub use error::DecodeError;

/// Which way the dots are contrasted.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Polarity {
    /// Decide per frame from the dot layout (the wrong polarity's "sites" are
    /// the background points, which show no line structure).
    #[default]
    Auto,
    /// Bright dots on a dark background (the real pattern under bright field).
    BrightDots,
    /// Dark dots on a bright background.
    DarkDots,
}

/// Decoder options.
#[derive(Debug, Clone, PartialEq)]
pub struct DecodeOptions {
    /// Pattern period p, µm.
    pub period_um: f64,
    /// Code depth n of the pattern (4..=12).
    pub bits: u32,
    /// The optical path mirrors the image (see module conventions).
    pub mirrored: bool,
    /// Dot polarity.
    pub polarity: Polarity,
    /// Smallest period accepted, px (below ~3 px the dots alias).
    pub min_period_px: f64,
    /// Minimum phase coherence of the fine grid (see [`Grid::coherence`]).
    pub min_coherence: f64,
    /// Per-dot stage thresholds.
    pub thresholds: CoarseThresholds,
    /// Model lens distortion: take the centre phase and the local wave
    /// vectors from a cubic polynomial fitted to the tile phases instead of
    /// the affine (windowed-sum) estimate. The reported position stays the
    /// image centre point's; [`Grid::distortion_px`] is reported either way.
    /// Off by default: on undistorted synthetic frames it costs accuracy
    /// (measured: std 8e-4 px instead of 4e-4, and a 7e-3 px offset, because
    /// each tile's phase carries its own missing-dot bias, which the
    /// polynomial's centre value picks up and the exact missing-dot
    /// correction — derived for the global window — does not remove). Use it
    /// only where lens distortion dominates (real optics, several 0.1 px).
    pub distortion: bool,
    /// The camera's pixel size on the pattern, µm (sensor pixel ÷
    /// magnification), when known. Why: the period only scales every
    /// position, so a wrong period decodes to confident, wrongly scaled
    /// positions; with the pixel size known the measured dot pitch
    /// (px) × pixel size must give the period, and a frame where it does not
    /// is refused ([`DecodeError::ScaleMismatch`]).
    pub pixel_um: Option<f64>,
    /// Largest relative disagreement between the pixel size the period
    /// implies and [`DecodeOptions::pixel_um`] (default 0.05: a nominal
    /// magnification is rarely better than a few %, while the nearest wrong
    /// periods a lab uses differ by 10 % or more).
    pub pixel_tolerance: f64,
}

impl DecodeOptions {
    /// Options for a pattern of period `period_um` and code depth `bits`,
    /// defaults elsewhere.
    pub fn new(period_um: f64, bits: u32) -> Self {
        Self {
            period_um,
            bits,
            mirrored: false,
            polarity: Polarity::Auto,
            min_period_px: 3.0,
            min_coherence: 0.5,
            thresholds: CoarseThresholds::default(),
            distortion: false,
            pixel_um: None,
            pixel_tolerance: 0.05,
        }
    }
}

/// True when the wave-vector pairs `a` and `b` (rad/px) describe the same
/// lattice: every vector of `b` is within 5 % of |k| of a vector of `a` or
/// its negative (the axis labels and signs do not matter).
fn same_lattice(a: &[[f64; 2]; 2], b: &[[f64; 2]; 2]) -> bool {
    b.iter().all(|v| {
        let r = v[0].hypot(v[1]);
        a.iter().any(|u| {
            (u[0] - v[0]).hypot(u[1] - v[1]) < 0.05 * r
                || (u[0] + v[0]).hypot(u[1] + v[1]) < 0.05 * r
        })
    })
}

/// Diagnostics of one decode.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Quality {
    /// Code-correlation margins (bits of evidence, see the module docs)
    /// along the pattern x and y axes.
    pub code_margin_bits: [f64; 2],
    /// Readable code lines along x and y.
    pub code_bits: [usize; 2],
    /// Estimated code-bit disagreements of the chosen offsets (soft units).
    pub code_errors: [f64; 2],
    /// Orientation template correlation (1 = perfect) and its lead.
    pub orientation_score: f64,
    /// Lead of the chosen orientation hypothesis over the runner-up.
    pub orientation_margin: f64,
    /// Fine-grid phase coherence (1 = perfect plane waves).
    pub coherence: f64,
    /// RMS of fine tile phase residuals, rad.
    pub phase_rms_rad: f64,
    /// Mean fundamental amplitude, fraction of full scale.
    pub amplitude: f64,
    /// True when the dots were found dark on a bright background.
    pub dark_dots: bool,
    /// Whether the code read confirms the configured code depth beyond
    /// chance (see [`CodeCheck`]); an unconfirmed result is a position the
    /// frame cannot vouch for (too few code lines to tell the depth).
    pub code_check: CodeCheck,
}

/// An absolute pose of the image centre on the pattern.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Decoded {
    /// Pattern x of the image centre point, µm.
    pub x_um: f64,
    /// Pattern y of the image centre point, µm.
    pub y_um: f64,
    /// Angle from image +x to pattern +x, towards image +y, rad, (−π, π].
    pub theta_rad: f64,
    /// Pixel size on the pattern, µm (mean of both axes).
    pub pixel_um: f64,
    /// Smaller code margin in bits of evidence (see the module docs).
    pub quality: f64,
    /// Detailed diagnostics.
    pub details: Quality,
    /// The fine grid used (image coordinates).
    pub grid: Grid,
    /// True when this result came from the tracking path.
    pub tracked: bool,
    /// True when the code position was the previous frame's prediction,
    /// verified (tracking fast path), rather than searched.
    pub code_predicted: bool,
}

/// The code fix of a decoded frame and its centre line coordinates.
type LastFix = (coarse::CodeFix, [f64; 2]);

/// A reusable decoder: FFT plans and all buffers survive across frames, so a
/// warm decoder does not allocate per frame (for frames of a fixed size).
#[derive(Debug)]
pub struct Decoder {
    opts: DecodeOptions,
    seq: LineSequence,
    fine: fine::FineStage,
    coarse: coarse::CoarseStage,
    last: Option<Grid>,
    /// Code fix of the last decoded frame and its centre line coordinates.
    last_fix: Option<LastFix>,
    /// Whether [`Decoder::decode_shared`] tried to start the helper thread.
    helper_tried: bool,
}

impl Decoder {
    /// Builds a decoder, checking the options.
    pub fn new(opts: DecodeOptions) -> Result<Self, DecodeError> {
        let seq = LineSequence::new(opts.bits)?;
        if !(opts.period_um.is_finite() && opts.period_um > 0.0) {
            return Err(DecodeError::Options(format!(
                "period_um must be > 0, got {}",
                opts.period_um
            )));
        }
        if !(opts.min_period_px.is_finite() && opts.min_period_px >= 2.0) {
            return Err(DecodeError::Options(format!(
                "min_period_px must be >= 2 (Nyquist), got {}",
                opts.min_period_px
            )));
        }
        if let Some(px) = opts.pixel_um {
            if !(px.is_finite() && px > 0.0) {
                return Err(DecodeError::Options(format!(
                    "pixel_um must be a finite number > 0, got {px}"
                )));
            }
        }
        if !(opts.pixel_tolerance.is_finite() && opts.pixel_tolerance > 0.0) {
            return Err(DecodeError::Options(format!(
                "pixel_tolerance must be a finite number > 0, got {}",
                opts.pixel_tolerance
            )));
        }
        let mut fine = fine::FineStage::new();
        fine.model_distortion = opts.distortion;
        Ok(Self {
            opts,
            seq,
            fine,
            coarse: coarse::CoarseStage::default(),
            last: None,
            last_fix: None,
            helper_tried: false,
        })
    }

    /// [`Decoder::decode`] on two threads: the demodulation's lower tile
    /// rows and one of the two code lattices run on a helper thread the
    /// decoder starts on its first call (and stops when dropped), reading
    /// `frame` through the `Arc` (a clone held for this call only: when it
    /// returns, `frame` is unshared again). Same result, bit for bit, as
    /// [`Decoder::decode`], and a warm decoder allocates nothing here
    /// either. Why an `Arc`: the library has no `unsafe`, so a long-lived
    /// thread can only read a frame it co-owns. Falls back to one thread
    /// when the helper cannot start.
    pub fn decode_shared(&mut self, frame: &Arc<Frame>) -> Result<Decoded, DecodeError> {
        self.with_helper(frame, |d, f| d.decode(f))
    }

    /// [`Decoder::track`] on two threads, as [`Decoder::decode_shared`].
    pub fn track_shared(&mut self, frame: &Arc<Frame>) -> Result<Decoded, DecodeError> {
        self.with_helper(frame, |d, f| d.track(f))
    }

    fn with_helper(
        &mut self,
        frame: &Arc<Frame>,
        op: impl FnOnce(&mut Self, &Frame) -> Result<Decoded, DecodeError>,
    ) -> Result<Decoded, DecodeError> {
        if !self.helper_tried {
            self.helper_tried = true;
            match helper::Helper::start() {
                Ok(h) => {
                    let h = Arc::new(h);
                    self.coarse.helper = Some(h.clone());
                    self.fine.helper = Some(h);
                }
                Err(e) => tracing::warn!("decoder: no helper thread ({e}); decoding on one"),
            }
        }
        let Some(h) = self.fine.helper.clone() else {
            return op(self, frame);
        };
        h.share(Some(frame.clone()));
        let r = op(self, frame);
        h.share(None);
        r
    }

    /// The options in use.
    pub fn options(&self) -> &DecodeOptions {
        &self.opts
    }

    /// Which SIMD kernels the decoder runs on this CPU (`"avx2"` or
    /// `"portable"`): a benchmark figure means little without it.
    pub fn simd_kernels(&self) -> &'static str {
        self.fine.kernels_name()
    }

    /// Cold full-frame stage: FFT peak search, then demodulation and plane
    /// fit. Public so the stages can be benchmarked separately.
    pub fn fine_stage(&mut self, frame: &Frame) -> Result<Grid, DecodeError> {
        let k0 = self.peak_search(frame)?;
        let g = self.fine.refine(frame, k0, 2)?;
        self.check_grid(&g)?;
        Ok(g)
    }

    fn check_grid(&self, g: &Grid) -> Result<(), DecodeError> {
        let ka = g.k[0][0].hypot(g.k[0][1]);
        let kb = g.k[1][0].hypot(g.k[1][1]);
        let ratio = ka / kb;
        if !(0.9..=1.1).contains(&ratio) {
            return Err(DecodeError::NoGrid(format!(
                "the two grid periods differ by a factor {ratio:.3}"
            )));
        }
        let cos = (g.k[0][0] * g.k[1][0] + g.k[0][1] * g.k[1][1]) / (ka * kb);
        if cos.abs() > 0.1 {
            return Err(DecodeError::NoGrid(format!(
                "grid directions are {:.1}° apart, not 90°",
                cos.acos().to_degrees()
            )));
        }
        let period = std::f64::consts::TAU / ka.max(kb);
        if !(period >= self.opts.min_period_px) {
            return Err(DecodeError::NoGrid(format!(
                "period {period:.2} px is below the minimum {:.2} px",
                self.opts.min_period_px
            )));
        }
        if !(g.coherence >= self.opts.min_coherence) {
            return Err(DecodeError::NoGrid(format!(
                "grid phase incoherent across the frame ({:.2} < {:.2}; period {period:.2} px, \
                 amplitudes {:.3}/{:.3} of full scale, tile phase rms {:.2} rad: blur, \
                 occlusion or a second periodic component beating with the grid)",
                g.coherence,
                self.opts.min_coherence,
                g.amplitude[0],
                g.amplitude[1],
                g.phase_rms_rad
            )));
        }
        Ok(())
    }

    /// Per-dot stage on a fine grid: polarity, orientation, code position,
    /// and the final pose.
    pub fn dot_stage(&mut self, frame: &Frame, grid: &Grid) -> Result<Decoded, DecodeError> {
        let polarity = match self.opts.polarity {
            Polarity::Auto => None,
            Polarity::BrightDots => Some(false),
            Polarity::DarkDots => Some(true),
        };
        let fix = self
            .coarse
            .run(frame, grid, &self.seq, polarity, &self.opts.thresholds)?;
        self.finish(frame, grid, &fix)
    }

    /// The pose from a fine grid and a code fix.
    fn finish(
        &mut self,
        frame: &Frame,
        grid: &Grid,
        fix: &coarse::CodeFix,
    ) -> Result<Decoded, DecodeError> {
        let tau = std::f64::consts::TAU;
        let mut phi = [0.0; 2];
        for d in 0..2 {
            phi[d] = if fix.dark_dots {
                grid.phi[d] - std::f64::consts::PI
            } else {
                grid.phi[d]
            };
        }
        let present = |ma: i64, mb: i64| {
            self.seq.dot(
                fix.origin[0] + fix.sigma[0] * ma,
                fix.origin[1] + fix.sigma[1] * mb,
            )
        };
        let (w, h) = (frame.width(), frame.height());
        let corr = missing_dot_correction(grid, phi, w, h, present);
        // The rotation from the moments' wave vectors where they are
        // available (see `sites::theta_wave_vectors`), else the tile fit's.
        let k_theta = self
            .fine
            .moments(frame, grid.k)
            .and_then(|m| theta_wave_vectors(grid, &m, phi, w, h, present))
            .unwrap_or(grid.k);
        let mut line_c = [0.0; 2];
        for d in 0..2 {
            line_c[d] = fix.origin[d] as f64 + fix.sigma[d] as f64 * (phi[d] - corr[d]) / tau;
        }
        let mirrored = self.opts.mirrored;
        let x_is_a = (fix.sigma[0] == fix.sigma[1]) ^ mirrored;
        let (xa, ya) = if x_is_a { (0, 1) } else { (1, 0) };
        let p = self.opts.period_um;
        let kx = [
            fix.sigma[xa] as f64 * grid.k[xa][0],
            fix.sigma[xa] as f64 * grid.k[xa][1],
        ];
        let ky = [
            fix.sigma[ya] as f64 * grid.k[ya][0],
            fix.sigma[ya] as f64 * grid.k[ya][1],
        ];
        let turned = |k: &[f64; 2], sign: i64| [sign as f64 * k[0], sign as f64 * k[1]];
        let (tx, ty) = (
            turned(&k_theta[xa], fix.sigma[xa]),
            turned(&k_theta[ya], fix.sigma[ya]),
        );
        let (t1, t2) = if mirrored {
            (f64::atan2(-tx[1], tx[0]), f64::atan2(-ty[0], -ty[1]))
        } else {
            (f64::atan2(tx[1], tx[0]), f64::atan2(-ty[0], ty[1]))
        };
        let theta = f64::atan2(t1.sin() + t2.sin(), t1.cos() + t2.cos());
        let pixel_um = p * (kx[0].hypot(kx[1]) + ky[0].hypot(ky[1])) / (2.0 * tau);
        if let Some(known) = self.opts.pixel_um {
            if !((pixel_um / known - 1.0).abs() <= self.opts.pixel_tolerance) {
                let period_px = p / pixel_um;
                return Err(DecodeError::ScaleMismatch {
                    period_um: p,
                    period_px,
                    measured_pixel_um: pixel_um,
                    expected_pixel_um: known,
                    fits_period_um: period_px * known,
                });
            }
        }
        let m = [fix.code_margin_bits[xa], fix.code_margin_bits[ya]];
        let out = Decoded {
            x_um: p * line_c[xa],
            y_um: p * line_c[ya],
            theta_rad: theta,
            pixel_um,
            quality: m[0].min(m[1]),
            details: Quality {
                code_margin_bits: m,
                code_bits: [fix.code_bits[xa], fix.code_bits[ya]],
                code_errors: [fix.code_errors[xa], fix.code_errors[ya]],
                orientation_score: fix.orientation_score,
                orientation_margin: fix.orientation_margin,
                coherence: grid.coherence,
                phase_rms_rad: grid.phase_rms_rad,
                amplitude: 0.5 * (grid.amplitude[0] + grid.amplitude[1]),
                dark_dots: fix.dark_dots,
                code_check: fix.code_check,
            },
            grid: *grid,
            tracked: false,
            code_predicted: false,
        };
        if ![out.x_um, out.y_um, out.theta_rad, out.pixel_um]
            .iter()
            .all(|v| v.is_finite())
        {
            return Err(DecodeError::NoGrid("non-finite pose".into()));
        }
        self.last_fix = Some((*fix, line_c));
        Ok(out)
    }

    /// Decodes a frame from scratch (peak search included).
    ///
    /// Lattice hypotheses: the peak search's reading of the spectrum (which
    /// peak is the fundamental) is tried first. If it yields no grid, an
    /// incoherent one, or a dot layout without the pattern's line structure —
    /// under heavy blur the 3-period structure's k/3 or diagonal
    /// (k_a ± k_b)/3 components can outshine the fundamental and the search
    /// locks onto them — the other readings of the strongest peak (see
    /// `fine::LATTICE_READINGS`), strongest fundamental first, are each held
    /// to the same grid, orientation and code checks, and the first that
    /// passes all of them is the answer. A frame that decodes at once costs
    /// nothing extra; when every reading fails, the first reading's error is
    /// returned.
    pub fn decode(&mut self, frame: &Frame) -> Result<Decoded, DecodeError> {
        self.last = None;
        self.last_fix = None;
        let k0 = self.peak_search(frame);
        let first = match k0 {
            Ok(k) => self.decode_at(frame, k),
            Err(ref e) => Err(e.clone()),
        };
        let err = match first {
            Ok(d) => {
                self.last = Some(d.grid);
                return Ok(d);
            }
            Err(e) => e,
        };
        if !matches!(
            err,
            DecodeError::NoGrid(_)
                | DecodeError::Orientation(_)
                | DecodeError::TooFewPeriods { .. }
        ) {
            return Err(err);
        }
        // Every alternative reading is scored by its full decode; the one
        // with the most code evidence wins. Two readings that both pass but
        // put the view in different places are a contradiction: refuse.
        let mut best: Option<(usize, Decoded, Option<LastFix>)> = None;
        let mut contradiction = false;
        for i in 0..self.fine.alternatives() {
            let Some(k) = self.fine.alternative(i) else {
                break;
            };
            if k0.as_ref().is_ok_and(|k0| same_lattice(k0, &k)) {
                continue;
            }
            let Ok(d) = self.decode_at(frame, k) else {
                continue;
            };
            if let Some((_, b, _)) = &best {
                let apart = (b.x_um - d.x_um).hypot(b.y_um - d.y_um) > 0.25 * self.opts.period_um;
                contradiction |= apart;
                if d.quality <= b.quality {
                    continue;
                }
            }
            best = Some((i, d, self.last_fix));
        }
        match best {
            Some((i, d, fix)) if !contradiction => {
                // Make the winner's blob estimate and code fix current for
                // tracking.
                let _ = self.fine.alternative(i);
                self.last_fix = fix;
                self.last = Some(d.grid);
                Ok(d)
            }
            Some(_) => Err(DecodeError::NoGrid(format!(
                "lattice readings of the spectrum decode to different positions ({err})"
            ))),
            None => Err(err),
        }
    }

    /// The peak search with the admissible period range of the options and
    /// the code depth.
    fn peak_search(&mut self, frame: &Frame) -> Result<[[f64; 2]; 2], DecodeError> {
        let (w, h) = (frame.width(), frame.height());
        let need = self.seq.min_periods_in_view() as f64;
        let max_period = (w.min(h) as f64 / need).max(self.opts.min_period_px * 1.01);
        self.fine
            .peak_search(frame, self.opts.min_period_px, max_period)
    }

    /// Refinement, grid checks and the per-dot stage from approximate wave
    /// vectors `k0`.
    fn decode_at(&mut self, frame: &Frame, k0: [[f64; 2]; 2]) -> Result<Decoded, DecodeError> {
        let g = self.fine.refine(frame, k0, 2)?;
        self.check_grid(&g)?;
        self.dot_stage(frame, &g)
    }

    /// Decodes a frame of a stream. Reuses the previous frame's grid
    /// frequencies (no peak search), polarity, axis directions and code
    /// position: the new fine phase tells how many whole periods the view
    /// moved (assuming less than half a period of motion between frames), and
    /// the predicted code offset is verified against the visible code lines
    /// (see the tracking check in [`coarse`]). A failed check runs the full
    /// per-dot search on the tracked grid; a failed grid falls back to
    /// [`Decoder::decode`]. A tracked result is therefore held to the same
    /// orientation and code margins as a cold one.
    pub fn track(&mut self, frame: &Frame) -> Result<Decoded, DecodeError> {
        if let Some(last) = self.last {
            let grid = self.fine.refine(frame, last.k, 2).and_then(|g| {
                self.check_grid(&g)?;
                if g.amplitude[0] < 0.5 * last.amplitude[0]
                    || g.amplitude[1] < 0.5 * last.amplitude[1]
                {
                    return Err(DecodeError::NoGrid("grid amplitude collapsed".into()));
                }
                Ok(g)
            });
            if let Ok(g) = grid {
                let mut out = self.predict_fix(&g).and_then(|pred| {
                    let fix =
                        self.coarse
                            .verify(frame, &g, &self.seq, &pred, &self.opts.thresholds)?;
                    let mut d = self.finish(frame, &g, &fix)?;
                    d.code_predicted = true;
                    Ok(d)
                });
                if out.is_err() {
                    out = self.dot_stage(frame, &g);
                }
                if let Ok(mut d) = out {
                    d.tracked = true;
                    self.last = Some(d.grid);
                    return Ok(d);
                }
            }
        }
        self.decode(frame)
    }

    /// The code fix expected for a tracked grid: the previous fix with the
    /// line origins moved so that the centre's line coordinate changes by
    /// less than half a period.
    fn predict_fix(&self, g: &Grid) -> Result<coarse::CodeFix, DecodeError> {
        let Some((mut fix, line_c)) = self.last_fix else {
            return Err(DecodeError::NoGrid("no previous code fix".into()));
        };
        for d in 0..2 {
            let phi = if fix.dark_dots {
                g.phi[d] - std::f64::consts::PI
            } else {
                g.phi[d]
            };
            let o = (line_c[d] - fix.sigma[d] as f64 * phi / std::f64::consts::TAU).round();
            if !(o.abs() < 1e12) {
                return Err(DecodeError::NoGrid("non-finite tracking prediction".into()));
            }
            fix.origin[d] = o as i64;
        }
        Ok(fix)
    }
}
