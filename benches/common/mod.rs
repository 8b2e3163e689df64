//! The frame the decoder and web-view benches measure on, so their figures
//! are of one and the same frame.

use micropos::frame::Frame;
use micropos::pattern::render::{Pose, RenderConfig, Renderer};

/// A rendered 1024×768 8-bit frame: the pattern at a pose away from the
/// origin, rotated, with read noise.
pub fn frame() -> Frame {
    let mut r = Renderer::new(RenderConfig {
        period_um: 9.0,
        bits: 12,
        read_noise: 0.01,
        ..RenderConfig::default()
    })
    .expect("renderer");
    let pose = Pose {
        x_um: 12_345.6,
        y_um: 23_456.7,
        theta_rad: 0.3,
        pixel_um: 0.9,
        mirrored: false,
    };
    r.render(&pose, 1, 0.0, 0).expect("render")
}
