//! Runtime-dispatched SIMD kernels for the decoder's hot loops.
//!
//! Why here and why `pulp`: the library forbids `unsafe` and is built for
//! baseline x86-64 (no `target-cpu`), so its loops compile to SSE2, where the
//! demodulation's integer dot products run at a quarter of the rate an AVX2
//! core offers (LLVM widens each i16 product to i32 and uses half of every
//! `pmaddwd`). `pulp` checks the CPU once and runs a kernel inside a function
//! compiled with AVX2 enabled, with safe wrappers for the intrinsics, so the
//! crate keeps `#![forbid(unsafe_code)]`. Every kernel has a portable
//! fallback with the same exact integer result: which path ran never changes
//! a decoded position.

#[cfg(target_arch = "x86_64")]
use pulp::x86::V3;

/// Number of tables a row is multiplied with in [`Kernels::tile_dots_u8`]:
/// cos and sin of each of the two grid directions, and the plain window.
pub(crate) const TABLES: usize = 5;

/// The kernels the running CPU supports, found once per decoder.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Kernels {
    #[cfg(target_arch = "x86_64")]
    v3: Option<V3>,
}

impl Kernels {
    /// The fastest kernels this CPU runs.
    pub(crate) fn detect() -> Self {
        Self {
            #[cfg(target_arch = "x86_64")]
            v3: V3::try_new(),
        }
    }

    /// The portable kernels only (tests compare them with [`Self::detect`]).
    #[cfg(test)]
    pub(crate) fn portable() -> Self {
        Self {
            #[cfg(target_arch = "x86_64")]
            v3: None,
        }
    }

    /// Name of the kernel set in use, for benchmarks and logs.
    pub(crate) fn name(&self) -> &'static str {
        #[cfg(target_arch = "x86_64")]
        if self.v3.is_some() {
            return "avx2";
        }
        "portable"
    }

    /// For each tile `t` (pixels `bounds[t]..bounds[t + 1]` of one 8-bit
    /// row), the exact integer dot products of the pixels with the
    /// [`TABLES`] i16 tables, written to `out[t]`. Tiles past the row or the
    /// tables, or beyond `out`, are left out.
    ///
    /// No overflow: |pixel · entry| ≤ 255 · 32767 and a tile of fewer than
    /// 257 pixels sums under 2³¹; longer tiles wrap exactly as the portable
    /// path does.
    pub(crate) fn tile_dots_u8(
        &self,
        px: &[u8],
        tabs: [&[i16]; TABLES],
        bounds: &[usize],
        out: &mut [[i32; TABLES]],
    ) {
        #[cfg(target_arch = "x86_64")]
        if let Some(simd) = self.v3 {
            pulp::Simd::vectorize(
                simd,
                TileDotsV3 {
                    simd,
                    px,
                    tabs,
                    bounds,
                    out,
                },
            );
            return;
        }
        for (t, o) in out.iter_mut().enumerate() {
            let Some((x, tabs)) = tile(px, &tabs, bounds, t) else {
                break;
            };
            *o = tabs.map(|a| dot_u8_i16(x, a));
        }
    }
}

/// Pixels and tables of tile `t`, or `None` when the tile does not exist
/// or reaches past the row or a table.
#[inline(always)]
fn tile<'a>(
    px: &'a [u8],
    tabs: &[&'a [i16]; TABLES],
    bounds: &[usize],
    t: usize,
) -> Option<(&'a [u8], [&'a [i16]; TABLES])> {
    let (&j0, &j1) = (bounds.get(t)?, bounds.get(t + 1)?);
    let x = px.get(j0..j1)?;
    let t = |k: usize| tabs[k].get(j0..j1);
    Some((x, [t(0)?, t(1)?, t(2)?, t(3)?, t(4)?]))
}

/// Exact dot product of 8-bit pixels with an i16 table (wrapping, as the
/// vector kernel).
#[inline(always)]
fn dot_u8_i16(x: &[u8], a: &[i16]) -> i32 {
    x.iter()
        .zip(a)
        .map(|(&x, &a)| i32::from(x) * i32::from(a))
        .fold(0i32, i32::wrapping_add)
}

/// The AVX2 tile kernel: sixteen pixels widened to i16 at once, each table
/// multiplied in with `vpmaddwd` (sixteen products, summed in pairs into
/// eight i32 lanes), the lanes summed once per tile.
#[cfg(target_arch = "x86_64")]
struct TileDotsV3<'a, 'b> {
    simd: V3,
    px: &'a [u8],
    tabs: [&'a [i16]; TABLES],
    bounds: &'a [usize],
    out: &'b mut [[i32; TABLES]],
}

#[cfg(target_arch = "x86_64")]
impl pulp::WithSimd for TileDotsV3<'_, '_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _: S) {
        use core::arch::x86_64::{__m128i, __m256i};
        let s = self.simd;
        for (t, o) in self.out.iter_mut().enumerate() {
            let Some((x, tabs)) = tile(self.px, &self.tabs, self.bounds, t) else {
                break;
            };
            let (xh, xt) = pulp::as_arrays::<16, u8>(x);
            let h = |k: usize| pulp::as_arrays::<16, i16>(tabs[k]).0;
            let z = s.avx._mm256_setzero_si256();
            let mut acc = [z; TABLES];
            // One zipped walk: every table has the tile's length, so no
            // per-chunk bounds checks.
            for (((((xc, a0), a1), a2), a3), a4) in
                xh.iter().zip(h(0)).zip(h(1)).zip(h(2)).zip(h(3)).zip(h(4))
            {
                let xw = s
                    .avx2
                    ._mm256_cvtepu8_epi16(pulp::cast::<[u8; 16], __m128i>(*xc));
                for (acc, a) in acc.iter_mut().zip([a0, a1, a2, a3, a4]) {
                    let av: __m256i = pulp::cast(*a);
                    *acc = s
                        .avx2
                        ._mm256_add_epi32(*acc, s.avx2._mm256_madd_epi16(xw, av));
                }
            }
            let n = xh.len() * 16;
            for (k, o) in o.iter_mut().enumerate() {
                let lanes: [i32; 8] = pulp::cast(acc[k]);
                let head = lanes.iter().fold(0i32, |a, &b| a.wrapping_add(b));
                let tail = tabs[k].get(n..).map_or(0, |a| dot_u8_i16(xt, a));
                *o = head.wrapping_add(tail);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Deterministic pseudo-random fill (xorshift), no external seed state.
    fn fill(seed: u64, n: usize) -> (Vec<u8>, [Vec<i16>; TABLES]) {
        let mut s = seed | 1;
        let mut next = move || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            s
        };
        let px = (0..n).map(|_| next() as u8).collect();
        let tabs = std::array::from_fn(|_| (0..n).map(|_| next() as i16).collect());
        (px, tabs)
    }

    fn reference(px: &[u8], tabs: &[Vec<i16>; TABLES], bounds: &[usize]) -> Vec<[i32; TABLES]> {
        bounds
            .windows(2)
            .map(|b| {
                std::array::from_fn(|k| {
                    (b[0]..b[1]).fold(0i32, |acc, j| {
                        acc.wrapping_add(i32::from(px[j]) * i32::from(tabs[k][j]))
                    })
                })
            })
            .collect()
    }

    #[test]
    fn every_kernel_matches_the_plain_sum_exactly() {
        // Row lengths and tile splits that exercise full vectors, tails
        // shorter than a vector, empty tiles and a single tile.
        let cases: [(usize, &[usize]); 5] = [
            (1024, &[0, 64, 128, 192, 256, 320, 384, 448, 512, 1024]),
            (1000, &[0, 62, 125, 187, 250, 1000]),
            (37, &[0, 5, 5, 21, 37]),
            (15, &[0, 15]),
            (300, &[0, 300]),
        ];
        for (seed, (n, bounds)) in cases.iter().enumerate() {
            let (px, tabs) = fill(seed as u64 + 7, *n);
            let want = reference(&px, &tabs, bounds);
            let refs: [&[i16]; TABLES] = std::array::from_fn(|k| tabs[k].as_slice());
            for kern in [Kernels::detect(), Kernels::portable()] {
                let mut got = vec![[0i32; TABLES]; bounds.len() - 1];
                kern.tile_dots_u8(&px, refs, bounds, &mut got);
                assert_eq!(got, want, "kernel {} on case {seed}", kern.name());
            }
        }
    }

    #[test]
    fn tiles_past_the_row_are_left_out() {
        let (px, tabs) = fill(3, 40);
        let refs: [&[i16]; TABLES] = std::array::from_fn(|k| tabs[k].as_slice());
        for kern in [Kernels::detect(), Kernels::portable()] {
            let mut got = vec![[9i32; TABLES]; 3];
            kern.tile_dots_u8(&px, refs, &[0, 20, 80, 90], &mut got);
            assert_eq!(got[0], reference(&px, &tabs, &[0, 20])[0]);
            assert_eq!(got[1], [9; TABLES]);
            assert_eq!(got[2], [9; TABLES]);
        }
    }
}
