//! The V4L2 source without hardware: a missing device node is a clear
//! error, never a panic, and listing works on a machine with no cameras.
//! Feature `v4l2` (on this module's line in `main.rs`).

use micropos::camera::{list_cameras, open_source, CameraError, OpenOptions, SourceSpec};

#[test]
fn missing_device_is_a_clear_error() {
    let spec: SourceSpec = "v4l2:/dev/video-micropos-missing-97".parse().unwrap();
    let err = open_source(&spec, &OpenOptions::default()).unwrap_err();
    match &err {
        CameraError::NoDevice { path, .. } => {
            assert_eq!(path, "/dev/video-micropos-missing-97")
        }
        other => panic!("expected NoDevice, got {other}"),
    }
    let msg = err.to_string();
    assert!(
        msg.starts_with("no device /dev/video-micropos-missing-97"),
        "{msg}"
    );
}

#[test]
fn a_file_that_is_not_a_video_device_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("video0");
    std::fs::write(&p, b"not a device").unwrap();
    let spec = SourceSpec::V4l2 { path: p };
    let err = open_source(&spec, &OpenOptions::default()).unwrap_err();
    assert!(
        matches!(
            err,
            CameraError::Backend {
                backend: "v4l2",
                ..
            }
        ),
        "{err}"
    );
}

#[test]
fn listing_does_not_fail_without_cameras() {
    // With `genicam` the listing asks aravis's interfaces too, which
    // `camera_genicam` may be using in another thread of this process.
    #[cfg(feature = "genicam")]
    let _aravis = crate::ARAVIS.lock().unwrap_or_else(|e| e.into_inner());
    let all = list_cameras();
    let (_, v4l2) = all
        .iter()
        .find(|(b, _)| *b == "v4l2")
        .expect("v4l2 backend compiled in");
    let cams = v4l2.as_ref().unwrap();
    assert!(cams.iter().all(|c| c.source.starts_with("v4l2:/dev/video")));
}
