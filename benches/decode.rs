//! Decoder speed on a rendered 1024×768 8-bit frame: cold decode, tracking
//! decode, each stage, and a plain full-frame real 2-D FFT as the baseline.
//! The reference C++ decoder takes 90.9 ms per such frame on this machine.
//! The web view's render of the same frame: `benches/web_camera.rs`.

use criterion::{criterion_group, criterion_main, Criterion};
use micropos::pattern::decode::{DecodeOptions, Decoder};
use realfft::RealFftPlanner;
use rustfft::FftPlanner;

mod common;
use common::frame;

fn bench(c: &mut Criterion) {
    let f = frame();
    let mut d = Decoder::new(DecodeOptions::new(9.0, 12)).expect("decoder");
    let g = d.fine_stage(&f).expect("grid");
    d.decode(&f).expect("decode");
    eprintln!("decoder SIMD kernels: {}", d.simd_kernels());
    let mut grp = c.benchmark_group("decode_1024x768");
    grp.sample_size(20);
    grp.bench_function("cold", |b| b.iter(|| d.decode(&f).expect("decode")));
    grp.bench_function("tracking", |b| b.iter(|| d.track(&f).expect("track")));
    grp.bench_function("fine_stage_cold", |b| {
        b.iter(|| d.fine_stage(&f).expect("fine"))
    });
    grp.bench_function("dot_stage", |b| {
        b.iter(|| d.dot_stage(&f, &g).expect("dots"))
    });
    // Baseline: full-frame real 2-D FFT (rows real-to-complex, then columns).
    let (w, h) = (f.width(), f.height());
    let mut data = Vec::new();
    f.to_f32_into(&mut data);
    let r2c = RealFftPlanner::<f32>::new().plan_fft_forward(w);
    let c2c = FftPlanner::<f32>::new().plan_fft_forward(h);
    let nc = w / 2 + 1;
    let mut spec = vec![realfft::num_complex::Complex::new(0.0f32, 0.0); nc * h];
    let mut col = vec![realfft::num_complex::Complex::new(0.0f32, 0.0); h];
    let mut scratch = r2c.make_scratch_vec();
    let mut cs =
        vec![realfft::num_complex::Complex::new(0.0f32, 0.0); c2c.get_inplace_scratch_len()];
    let mut rowbuf = vec![0f32; w];
    grp.bench_function("baseline_full_fft2d", |b| {
        b.iter(|| {
            for i in 0..h {
                rowbuf.copy_from_slice(&data[i * w..(i + 1) * w]);
                r2c.process_with_scratch(
                    &mut rowbuf,
                    &mut spec[i * nc..(i + 1) * nc],
                    &mut scratch,
                )
                .expect("fft");
            }
            for x in 0..nc {
                for i in 0..h {
                    col[i] = spec[i * nc + x];
                }
                c2c.process_with_scratch(&mut col, &mut cs);
            }
            col[0]
        })
    });
    grp.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
