//! The decoder never panics, whatever the frame.

use micropos::frame::{Frame, Pixels};
use micropos::pattern::decode::{DecodeOptions, Decoder};
use proptest::prelude::*;

proptest! {
    #![proptest_config(ProptestConfig { cases: 48, ..ProptestConfig::default() })]

    #[test]
    fn any_8bit_frame(w in 1usize..200, h in 1usize..200, seed in any::<u64>(), kind in 0u8..4, bits in 4u32..=12) {
        let n = w * h;
        let mut x = seed | 1;
        let px: Vec<u8> = (0..n).map(|i| {
            x ^= x << 13; x ^= x >> 7; x ^= x << 17;
            match kind {
                0 => (x & 0xff) as u8,            // noise
                1 => 77,                          // constant
                2 => if (i % w / 3 + i / w / 3) % 2 == 0 { 255 } else { 0 }, // checkerboard
                _ => ((i % w) * 255 / w.max(1)) as u8, // ramp
            }
        }).collect();
        let f = Frame::new(w, h, 8, Pixels::U8(px), 0.0, 0).unwrap();
        let mut d = Decoder::new(DecodeOptions::new(9.0, bits)).unwrap();
        let _ = d.decode(&f);
        let _ = d.track(&f);
    }

    #[test]
    fn any_16bit_frame(w in 16usize..120, h in 16usize..120, seed in any::<u64>(), depth in 9u8..=16) {
        let mut x = seed | 1;
        let max = (1u32 << depth) - 1;
        let px: Vec<u16> = (0..w * h).map(|_| { x ^= x << 13; x ^= x >> 7; x ^= x << 17; (x as u32 % (max + 1)) as u16 }).collect();
        let f = Frame::new(w, h, depth, Pixels::U16(px), 0.0, 0).unwrap();
        let mut d = Decoder::new(DecodeOptions::new(4.0, 6)).unwrap();
        let _ = d.decode(&f);
    }
}

#[test]
fn bad_options_are_errors() {
    assert!(Decoder::new(DecodeOptions::new(-1.0, 12)).is_err());
    assert!(Decoder::new(DecodeOptions::new(9.0, 13)).is_err());
    assert!(Decoder::new(DecodeOptions::new(f64::NAN, 12)).is_err());
}
