//! Replay of recorded runs through the `FrameSource` trait.

use std::path::Path;

use micropos::camera::files::{write_png, FileOptions, FileTiming};
use micropos::camera::{open_source, CameraError, OpenOptions, PixelFormat, SourceSpec};
use micropos::frame::{Frame, Pixels};

fn frame12(seed: u16) -> Frame {
    let px: Vec<u16> = (0..48u16).map(|i| (i * 85 + seed) % 4096).collect();
    Frame::new(8, 6, 12, Pixels::U16(px), 0.0, 0).unwrap()
}

fn open(
    pattern: &str,
    files: FileOptions,
) -> Result<Box<dyn micropos::camera::FrameSource>, CameraError> {
    let spec: SourceSpec = format!("files:{pattern}").parse().unwrap();
    open_source(
        &spec,
        &OpenOptions {
            files,
            ..OpenOptions::default()
        },
    )
}

#[test]
fn directory_replay_in_name_order_with_rate_timestamps_and_loop() {
    let dir = tempfile::tempdir().unwrap();
    // Written out of order; replay sorts by name.
    for k in [2u16, 0, 1] {
        write_png(&frame12(k), &dir.path().join(format!("f{k:04}.png"))).unwrap();
    }
    std::fs::write(dir.path().join("notes.txt"), "not an image").unwrap();
    let mut src = open(
        dir.path().to_str().unwrap(),
        FileOptions {
            looping: true,
            timing: FileTiming::Rate { rate_hz: 4.0 },
            ..FileOptions::default()
        },
    )
    .unwrap();
    let info = src.info();
    assert_eq!(
        (info.backend, info.width, info.height, info.bit_depth),
        ("files", 8, 6, 12)
    );
    assert_eq!(info.pixel_format, "Mono12");
    for k in 0..7u64 {
        let f = src.next_frame().unwrap();
        assert_eq!(f.sequence, k);
        assert_eq!(f.timestamp_s, k as f64 / 4.0);
        assert_eq!(f.pixels(), frame12((k % 3) as u16).pixels(), "frame {k}");
    }
    // Controls a replay does not have say so.
    let e = src.set_exposure_us(100.0).unwrap_err();
    assert!(
        e.to_string().contains("not supported by the files source"),
        "{e}"
    );
    assert!(matches!(
        src.set_gain_db(1.0),
        Err(CameraError::NotSupported { .. })
    ));
    assert!(matches!(
        src.set_pixel_format(PixelFormat::Mono8),
        Err(CameraError::NotSupported { .. })
    ));
    assert!(matches!(
        src.set_frame_rate_hz(5.0),
        Err(CameraError::NotSupported { .. })
    ));
}

#[test]
fn glob_replay_ends_and_reports_mismatched_files() {
    let dir = tempfile::tempdir().unwrap();
    let p = |n: &str| dir.path().join(n);
    let f8 = Frame::new(4, 2, 8, Pixels::U8((0..8).collect()), 0.0, 0).unwrap();
    write_png(&f8, &p("a_000.png")).unwrap();
    // A different size in the middle of the run.
    let other = Frame::new(2, 2, 8, Pixels::U8(vec![1; 4]), 0.0, 0).unwrap();
    write_png(&other, &p("a_001.png")).unwrap();
    // JPEG and TIFF of the right size.
    let img = image::GrayImage::from_raw(4, 2, (0..8).map(|v| v * 30).collect()).unwrap();
    img.save(p("a_002.tif")).unwrap();
    img.save(p("a_003.jpg")).unwrap();
    write_png(&f8, &p("b_000.png")).unwrap(); // not matched by the glob

    let pattern = format!("{}/a_*", dir.path().display());
    let mut src = open(&pattern, FileOptions::default()).unwrap();
    let f = src.next_frame().unwrap();
    assert_eq!((f.sequence, f.timestamp_s), (0, 0.0));
    let e = src.next_frame().unwrap_err();
    assert!(
        e.to_string()
            .contains("is 2×2 at 8 bits, the replay is 4×2"),
        "{e}"
    );
    // The stream goes on after a bad file; the gap shows in the sequence.
    let f = src.next_frame().unwrap();
    assert_eq!((f.sequence, f.timestamp_s), (2, 2.0));
    assert_eq!(f.get(3, 1), Some(210));
    let f = src.next_frame().unwrap();
    assert_eq!(f.sequence, 3);
    assert!(matches!(
        src.next_frame(),
        Err(CameraError::EndOfStream { frames: 4 })
    ));
}

#[test]
fn sixteen_bit_tiff_and_declared_depth() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("x.tiff");
    let img =
        image::ImageBuffer::<image::Luma<u16>, _>::from_raw(2, 2, vec![0u16, 1000, 3000, 4095])
            .unwrap();
    img.save(&path).unwrap();
    let mut src = open(path.to_str().unwrap(), FileOptions::default()).unwrap();
    assert_eq!(src.info().bit_depth, 16);
    assert_eq!(src.next_frame().unwrap().get(1, 1), Some(4095));
    let mut src = open(
        path.to_str().unwrap(),
        FileOptions {
            bit_depth: Some(12),
            ..FileOptions::default()
        },
    )
    .unwrap();
    let f = src.next_frame().unwrap();
    assert_eq!((f.bit_depth(), f.full_scale()), (12, 4095));
}

#[test]
fn bad_replays_fail_at_open() {
    let dir = tempfile::tempdir().unwrap();
    let e = open(dir.path().to_str().unwrap(), FileOptions::default()).unwrap_err();
    assert!(e.to_string().contains("matches no image files"), "{e}");
    let e = open("/nonexistent/micropos/run", FileOptions::default()).unwrap_err();
    assert!(matches!(e, CameraError::Io { .. }), "{e}");
    let bad = dir.path().join("broken.png");
    std::fs::write(&bad, b"\x89PNG\r\n\x1a\n garbage").unwrap();
    let e = open(bad.to_str().unwrap(), FileOptions::default()).unwrap_err();
    assert!(matches!(e, CameraError::Decode { .. }), "{e}");
    let good = dir.path().join("ok.png");
    write_png(&frame12(0), &good).unwrap();
    let e = open(
        good.to_str().unwrap(),
        FileOptions {
            timing: FileTiming::Rate { rate_hz: 0.0 },
            ..FileOptions::default()
        },
    )
    .unwrap_err();
    assert!(e.to_string().contains("positive number of Hz"), "{e}");
    assert!(Path::new(&good).exists());
}
