//! The GenICam source against aravis's own fake camera, for real: aravis
//! opens the in-process "Fake" device (`genicam:Fake_1`), streams frames
//! through its stream thread and buffer pool, and the source converts them.
//! No process or network is needed. Everything runs in one test function
//! because aravis keeps global interface state, and that function holds
//! [`crate::ARAVIS`] against the other test of this binary that reaches
//! aravis (`camera_v4l2`'s listing of every backend's cameras). Feature
//! `genicam` (on this module's line in `main.rs`).

use std::time::Duration;

use micropos::camera::{open_source, CameraError, OpenOptions, PixelFormat, SourceSpec};
use micropos::frame::Pixels;

#[test]
fn fake_camera_streams_and_takes_settings() {
    let _aravis = crate::ARAVIS.lock().unwrap_or_else(|e| e.into_inner());
    let spec: SourceSpec = "genicam:Fake_1".parse().unwrap();
    let options = OpenOptions {
        timeout: Duration::from_secs(5),
        ..OpenOptions::default()
    };
    let mut cam = open_source(&spec, &options).unwrap();
    let info = cam.info();
    assert_eq!(info.backend, "genicam");
    assert!(info.model.contains("Fake"), "{info:?}");
    assert!(info.width > 0 && info.height > 0, "{info:?}");

    // Frames arrive with the advertised size, rising sequence and time.
    let mut last: Option<(u64, f64)> = None;
    for _ in 0..4 {
        let f = cam.next_frame().unwrap();
        assert_eq!((f.width(), f.height()), (info.width, info.height));
        assert_eq!(f.bit_depth(), info.bit_depth);
        if let Some((seq, t)) = last {
            assert!(f.sequence > seq, "sequence {} after {seq}", f.sequence);
            assert!(f.timestamp_s > t, "time {} after {t}", f.timestamp_s);
        }
        last = Some((f.sequence, f.timestamp_s));
    }

    // Exposure and gain are applied and read back.
    let e = cam.set_exposure_us(5000.0).unwrap();
    assert!((e - 5000.0).abs() < 1.0, "exposure {e}");
    assert!((cam.exposure_us().unwrap() - 5000.0).abs() < 1.0);
    let g = cam.set_gain_db(2.0).unwrap();
    assert!((g - 2.0).abs() < 0.1, "gain {g}");
    assert!(matches!(
        cam.set_exposure_us(-1.0),
        Err(CameraError::OutOfRange { .. })
    ));
    assert!(matches!(
        cam.set_gain_db(f64::NAN),
        Err(CameraError::OutOfRange { .. })
    ));

    // The fake camera's test pattern is not flat.
    let f = cam.next_frame().unwrap();
    let (min, max) = match f.pixels() {
        Pixels::U8(p) => (
            p.iter().copied().map(u16::from).min(),
            p.iter().copied().map(u16::from).max(),
        ),
        Pixels::U16(p) => (p.iter().copied().min(), p.iter().copied().max()),
    };
    assert!(min < max, "flat frame {min:?}..{max:?}");

    // Pixel formats: switch to each mono format the camera offers.
    let formats = cam.pixel_formats().unwrap();
    eprintln!("fake camera pixel formats: {formats:?}");
    // aravis 0.8 fake camera offers Mono8 and Mono16: both paths run.
    assert!(formats.contains(&PixelFormat::Mono8), "{formats:?}");
    assert!(formats.contains(&PixelFormat::Mono16), "{formats:?}");
    for fmt in [PixelFormat::Mono16, PixelFormat::Mono8] {
        if !formats.contains(&fmt) {
            continue;
        }
        cam.set_pixel_format(fmt).unwrap();
        assert_eq!(cam.info().bit_depth, fmt.bit_depth());
        let f = cam.next_frame().unwrap();
        assert_eq!(f.bit_depth(), fmt.bit_depth());
        match (fmt, f.pixels()) {
            (PixelFormat::Mono8, Pixels::U8(_)) | (PixelFormat::Mono16, Pixels::U16(_)) => {}
            (fmt, _) => panic!("{fmt} gave the wrong storage"),
        }
    }
    if !formats.contains(&PixelFormat::Mono12) {
        assert!(matches!(
            cam.set_pixel_format(PixelFormat::Mono12),
            Err(CameraError::NotSupported { .. })
        ));
    }

    // Frame rate control.
    let r = cam.set_frame_rate_hz(10.0).unwrap();
    assert!((r - 10.0).abs() < 0.5, "rate {r}");

    // A camera that does not exist gives a clear error, not a panic.
    let missing: SourceSpec = "genicam:Fake_99".parse().unwrap();
    let err = open_source(&missing, &options).unwrap_err();
    assert!(matches!(err, CameraError::NoDevice { .. }), "{err}");
    let missing: SourceSpec = "genicam:No-Such-Camera-42".parse().unwrap();
    let err = open_source(&missing, &options).unwrap_err();
    assert!(matches!(err, CameraError::NoDevice { .. }), "{err}");
}
