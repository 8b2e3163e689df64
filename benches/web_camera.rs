//! The web view's camera render (`daemon::web::camera::render`: box
//! downscale of a 1024×768 frame to 480 px with an 8-bit stretch, PNG
//! encoding, the decode overlay with its dot lattice) against its parts, in
//! one run: the plain downscale is the baseline (the least any view must
//! do), so `render / downscale` says what the PNG and the overlay cost on
//! top. The render runs on the blocking pool at most `[web] camera_max_hz`
//! (default 2) times a second, whatever the number of viewers.

use criterion::{criterion_group, criterion_main, Criterion};
use micropos::daemon::vision::{Snapshot, SnapshotDecode};
use micropos::daemon::web::camera;
use micropos::pattern::decode::{DecodeOptions, Decoder};

mod common;
use common::frame;

fn bench(c: &mut Criterion) {
    let f = frame();
    let mut d = Decoder::new(DecodeOptions::new(9.0, 12)).expect("decoder");
    let dec = d.decode(&f).expect("decode");
    let snap = Snapshot {
        frame: std::sync::Arc::new(f.clone()),
        decoded: Some(SnapshotDecode {
            x_um: dec.x_um,
            y_um: dec.y_um,
            theta_rad: dec.theta_rad,
            pixel_um: dec.pixel_um,
            quality: dec.quality,
            grid: dec.grid,
        }),
    };
    let (small, w, h, factor) = camera::downscale(&f, 480).expect("downscale");
    let rendered = camera::render(&snap, 480).expect("render");
    let points = rendered.overlay["decode"]["lattice"]
        .as_array()
        .map_or(0, Vec::len)
        / 2;
    eprintln!(
        "{}×{} → {w}×{h} (factor {factor}), PNG {} bytes, {points} lattice points",
        f.width(),
        f.height(),
        rendered.png.len()
    );
    let mut g = c.benchmark_group("web_camera_1024x768");
    g.sample_size(30);
    g.bench_function("baseline_downscale_480px", |b| {
        b.iter(|| camera::downscale(&f, 480).expect("downscale"))
    });
    g.bench_function("png_encode_480px", |b| {
        b.iter(|| {
            let img = image::GrayImage::from_raw(w as u32, h as u32, small.clone()).expect("image");
            let mut png = Vec::new();
            img.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
                .expect("png");
            png
        })
    });
    g.bench_function("overlay_lattice", |b| {
        b.iter(|| camera::overlay(&snap, w, h, factor))
    });
    g.bench_function("render_480px", |b| {
        b.iter(|| camera::render(&snap, 480).expect("render"))
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
