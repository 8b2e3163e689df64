//! Camera buffer conversion with arbitrary geometry and bytes must never
//! panic, and a frame it returns has the requested size.
#![no_main]

use libfuzzer_sys::fuzz_target;
use micropos::camera::convert::to_frame;
use micropos::camera::PixelFormat;

fuzz_target!(|data: &[u8]| {
    if data.len() < 7 {
        return;
    }
    let format = PixelFormat::ALL[usize::from(data[0]) % PixelFormat::ALL.len()];
    let width = usize::from(u16::from_le_bytes([data[1], data[2]]) % 512);
    let height = usize::from(u16::from_le_bytes([data[3], data[4]]) % 512);
    let stride = usize::from(u16::from_le_bytes([data[5], data[6]]));
    if let Ok(f) = to_frame(format, width, height, stride, &data[7..], 0.0, 0) {
        assert_eq!((f.width(), f.height()), (width, height));
    }
});
