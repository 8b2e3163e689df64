//! Exact area coverage: each pixel's value is the area of the pixel square
//! covered by the (rotated) square dots, by clipping the pixel polygon
//! against the dot.

use super::{Pose, Renderer};

impl Renderer {
    /// Fills `buf` (frame plus margin) with the dot coverage of each pixel.
    pub(super) fn coverage(&mut self, pose: &Pose) {
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
}
