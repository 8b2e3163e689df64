//! Sampling a view's dot sites and background points: the fine grid's
//! lattice mapped onto the frame, its extent, and the two lattices'
//! bilinear samples (the half lattice lent to the decoder's helper thread
//! when there is one). A file of its own: the one pixel pass of the
//! per-dot stage, shared by the search and the tracking check.

use super::super::error::DecodeError;
use super::super::fine::{Grid, HELPER_MIN_PIXELS};
use super::super::helper::take_back;
use super::lattice::{sample_lattice, LatticeJob};
use super::CoarseStage;
use crate::frame::{Frame, Pixels};
use crate::pattern::sequence::LineSequence;

impl CoarseStage {
    /// Samples every dot site and background point of the view into `g0`
    /// and `g1`; returns (na, nb, a0, b0): the integer lattice's size and
    /// first lattice coordinates.
    pub(super) fn sample(
        &mut self,
        frame: &Frame,
        grid: &Grid,
        seq: &LineSequence,
    ) -> Result<(usize, usize, i64, i64), DecodeError> {
        let (w, h) = (frame.width(), frame.height());
        let tau = std::f64::consts::TAU;
        let k = grid.k;
        let det = k[0][0] * k[1][1] - k[0][1] * k[1][0];
        if det.abs() < 1e-12 {
            return Err(DecodeError::NoGrid("degenerate grid".into()));
        }
        // K⁻¹: image offset of a lattice-coordinate step.
        let inv = [
            [k[1][1] / det, -k[0][1] / det],
            [-k[1][0] / det, k[0][0] / det],
        ];
        let da = [inv[0][0] * tau, inv[1][0] * tau];
        let db = [inv[0][1] * tau, inv[1][1] * tau];
        let (cx, cy) = (w as f64 / 2.0, h as f64 / 2.0);
        let u00 = [
            cx - (inv[0][0] * grid.phi[0] + inv[0][1] * grid.phi[1]),
            cy - (inv[1][0] * grid.phi[0] + inv[1][1] * grid.phi[1]),
        ];
        // Lattice coordinate range over the frame.
        let lat = |u: f64, v: f64| {
            let x = u - cx;
            let y = v - cy;
            (
                (k[0][0] * x + k[0][1] * y + grid.phi[0]) / tau,
                (k[1][0] * x + k[1][1] * y + grid.phi[1]) / tau,
            )
        };
        let mut amin = f64::MAX;
        let mut amax = f64::MIN;
        let mut bmin = f64::MAX;
        let mut bmax = f64::MIN;
        for (u, v) in [
            (0.0, 0.0),
            (w as f64, 0.0),
            (0.0, h as f64),
            (w as f64, h as f64),
        ] {
            let (a, b) = lat(u, v);
            amin = amin.min(a);
            amax = amax.max(a);
            bmin = bmin.min(b);
            bmax = bmax.max(b);
        }
        let a0 = amin.ceil() as i64;
        let b0 = bmin.ceil() as i64;
        let na = (amax.floor() as i64 - a0 + 1).max(0) as usize;
        let nb = (bmax.floor() as i64 - b0 + 1).max(0) as usize;
        if na * nb > 4_000_000 || na < 9 || nb < 9 {
            return Err(DecodeError::TooFewPeriods {
                got: na.min(nb),
                need: seq.min_periods_in_view(),
            });
        }
        // One bilinear sample per dot site (integer lattice) and per
        // background point (half lattice); both polarity hypotheses below
        // read the same samples. The dots are ≥ 3 px and blurred, so the
        // centre sample carries the site's contrast.
        let g1_origin = [
            u00[0] + (a0 as f64 - 0.5) * da[0] + (b0 as f64 - 0.5) * db[0],
            u00[1] + (a0 as f64 - 0.5) * da[1] + (b0 as f64 - 0.5) * db[1],
        ];
        let g0_origin = [
            u00[0] + a0 as f64 * da[0] + b0 as f64 * db[0],
            u00[1] + a0 as f64 * da[1] + b0 as f64 * db[1],
        ];
        // Centre plus four points at ±1/6 period along the lattice axes: the
        // mean over the dot's core is robust to blur, noise and the few
        // tenths of a pixel that lens distortion moves a site.
        let mut offs = [[0.0; 2]; 5];
        for (t, &(fa, fb)) in [(0.0, 0.0), (1.0, 0.0), (-1.0, 0.0), (0.0, 1.0), (0.0, -1.0)]
            .iter()
            .enumerate()
        {
            offs[t] = [
                (fa * da[0] + fb * db[0]) / 6.0,
                (fa * da[1] + fb * db[1]) / 6.0,
            ];
        }
        let offs: &[[f64; 2]] = if self.single_sample {
            &offs[..1]
        } else {
            &offs
        };
        // The half lattice on the helper thread when the decode lent it
        // this frame (see `decode::helper`), the integer one here.
        let mut lent = false;
        if let Some(helper) = &self.helper {
            let mut job = self.lattice_job.take().unwrap_or_default();
            if w * h >= HELPER_MIN_PIXELS {
                job.w = w;
                job.h = h;
                job.origin = g1_origin;
                job.da = da;
                job.db = db;
                job.ni = na + 1;
                job.nj = nb + 1;
                job.offs[..offs.len()].copy_from_slice(offs);
                job.n_offs = offs.len();
                match helper.submit(frame, job) {
                    Ok(()) => lent = true,
                    Err(j) => self.lattice_job = take_back(j),
                }
            } else {
                self.lattice_job = Some(job);
            }
        }
        match frame.pixels() {
            Pixels::U8(p) => {
                sample_lattice(p, w, h, g0_origin, da, db, na, nb, offs, &mut self.g0);
            }
            Pixels::U16(p) => {
                sample_lattice(p, w, h, g0_origin, da, db, na, nb, offs, &mut self.g0);
            }
        }
        let done = if lent {
            self.helper.as_ref().and_then(|h| h.wait())
        } else {
            None
        };
        if let Some(mut job) = done.and_then(take_back::<LatticeJob>) {
            std::mem::swap(&mut self.g1, &mut job.out);
            self.lattice_job = Some(job);
        } else {
            // Not lent, or the helper failed (a panic): on this thread.
            match frame.pixels() {
                Pixels::U8(p) => sample_lattice(
                    p,
                    w,
                    h,
                    g1_origin,
                    da,
                    db,
                    na + 1,
                    nb + 1,
                    offs,
                    &mut self.g1,
                ),
                Pixels::U16(p) => sample_lattice(
                    p,
                    w,
                    h,
                    g1_origin,
                    da,
                    db,
                    na + 1,
                    nb + 1,
                    offs,
                    &mut self.g1,
                ),
            }
        }
        Ok((na, nb, a0, b0))
    }
}
