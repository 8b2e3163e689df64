//! The code lattices' bilinear samples: the one loop the coarse stage
//! lends the decoder's helper thread ([`LatticeJob`]) and the sampling
//! itself ([`sample_lattice`]).

use super::super::helper::Work;
use crate::frame::{Frame, Pixels};

/// One lattice of [`sample_lattice`] for the helper thread: its
/// parameters and its own output buffer (swapped with the stage's).
#[derive(Debug, Default)]
pub(crate) struct LatticeJob {
    pub(super) w: usize,
    pub(super) h: usize,
    pub(super) origin: [f64; 2],
    pub(super) da: [f64; 2],
    pub(super) db: [f64; 2],
    pub(super) ni: usize,
    pub(super) nj: usize,
    pub(super) offs: [[f64; 2]; 5],
    pub(super) n_offs: usize,
    pub(super) out: Vec<f32>,
}

impl Work for LatticeJob {
    fn run(&mut self, frame: &Frame) {
        self.sample(frame);
    }

    fn into_any(self: Box<Self>) -> Box<dyn std::any::Any + Send> {
        self
    }
}

impl LatticeJob {
    /// Samples the lattice (on the helper thread).
    fn sample(&mut self, frame: &Frame) {
        let offs = &self.offs[..self.n_offs.min(5)];
        let (w, h) = (self.w, self.h);
        match frame.pixels() {
            Pixels::U8(p) => sample_lattice(
                p,
                w,
                h,
                self.origin,
                self.da,
                self.db,
                self.ni,
                self.nj,
                offs,
                &mut self.out,
            ),
            Pixels::U16(p) => sample_lattice(
                p,
                w,
                h,
                self.origin,
                self.da,
                self.db,
                self.ni,
                self.nj,
                offs,
                &mut self.out,
            ),
        }
    }
}

/// Samples the frame bilinearly at the lattice points u0 + i·da + j·db
/// (i < ni, j < nj; pixel centres at integer + 0.5), row-major into `out`;
/// each value is the sum over the sample offsets `offs` about the point, NaN
/// when any of them falls outside the frame. Generic over the pixel type so
/// the inner loop has no per-pixel format dispatch.
///
/// Speed (the per-dot stage's largest cost): the offsets' bounding box is
/// tested once per lattice point (the frame is a box, so all offsets are
/// inside exactly when the box is), and each bilinear sample reads its
/// 2 × 2 pixels through one slice of `w + 2` pixels: one bounds check per
/// sample instead of four. (A version handling eight points at once in
/// vector registers measured slower: the pixel reads are gathers, which
/// dominate either way.)
#[allow(clippy::too_many_arguments)]
pub(super) fn sample_lattice<T: Copy + Into<f32>>(
    p: &[T],
    w: usize,
    h: usize,
    u0: [f64; 2],
    da: [f64; 2],
    db: [f64; 2],
    ni: usize,
    nj: usize,
    offs: &[[f64; 2]],
    out: &mut Vec<f32>,
) {
    out.clear();
    if w < 2 || h < 2 || p.len() < w * h {
        out.resize(ni * nj, f32::NAN);
        return;
    }
    // Signed 32-bit pixel indices: f64 ↔ i32 conversions are single
    // instructions, f64 ↔ usize ones are not on x86-64.
    let (Ok(w2), Ok(h2)) = (i32::try_from(w - 2), i32::try_from(h - 2)) else {
        out.resize(ni * nj, f32::NAN);
        return;
    };
    let xmax = (w - 1) as f64;
    let ymax = (h - 1) as f64;
    let lo = offs
        .iter()
        .fold([0.0f64; 2], |m, o| [m[0].min(o[0]), m[1].min(o[1])]);
    let hi = offs
        .iter()
        .fold([0.0f64; 2], |m, o| [m[0].max(o[0]), m[1].max(o[1])]);
    for j in 0..nj {
        // Pixel-index coordinates (centre of pixel 0 at 0).
        let rx = u0[0] - 0.5 + j as f64 * db[0];
        let ry = u0[1] - 0.5 + j as f64 * db[1];
        for i in 0..ni {
            let xc = rx + i as f64 * da[0];
            let yc = ry + i as f64 * da[1];
            if !(xc + lo[0] >= 0.0 && yc + lo[1] >= 0.0 && xc + hi[0] <= xmax && yc + hi[1] <= ymax)
            {
                out.push(f32::NAN);
                continue;
            }
            let mut acc = 0.0f32;
            for o in offs {
                let (x, y) = (xc + o[0], yc + o[1]);
                // Inside the frame (box test above), so non-negative:
                // truncation is floor.
                let jx = (x as i32).min(w2);
                let iy = (y as i32).min(h2);
                let fx = (x - f64::from(jx)) as f32;
                let fy = (y - f64::from(iy)) as f32;
                let q = iy as usize * w + jx as usize;
                let Some(win) = p.get(q..q + w + 2) else {
                    acc = f32::NAN;
                    break;
                };
                let (a, b, c, d) = (
                    win[0].into(),
                    win[1].into(),
                    win[w].into(),
                    win[w + 1].into(),
                );
                let top = a + fx * (b - a);
                let bot = c + fx * (d - c);
                acc += top + fy * (bot - top);
            }
            out.push(acc);
        }
    }
}
