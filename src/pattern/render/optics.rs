//! Optics on the coverage image: the Gaussian PSF and defocus disc on the
//! fine grid, then box-summing to output pixels.

use super::Renderer;

impl Renderer {
    /// Applies the Gaussian PSF (separable) and the defocus disc to `buf`.
    pub(super) fn blur(&mut self) {
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
    pub(super) fn downsample(&mut self) {
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
}
