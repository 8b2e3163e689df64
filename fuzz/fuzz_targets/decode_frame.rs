//! Arbitrary bytes → a small frame (dimensions, depth, pixels) and decoder
//! options → `Decoder::decode` and `Decoder::track` must return a result or
//! an error, never panic, whatever the pixels hold.
#![no_main]

use libfuzzer_sys::fuzz_target;
use micropos::frame::{Frame, Pixels};
use micropos::pattern::decode::{DecodeOptions, Decoder, Polarity};

fuzz_target!(|data: &[u8]| {
    if data.len() < 6 {
        return;
    }
    let w = 1 + usize::from(data[0] % 128);
    let h = 1 + usize::from(data[1] % 128);
    let bits = 4 + u32::from(data[2] % 9);
    let flags = data[3];
    let period_um = 1.0 + f64::from(data[4]) / 8.0;
    let rest = &data[6..];
    let n = w * h;
    let frame = if flags & 1 == 0 {
        let px: Vec<u8> = (0..n).map(|i| rest.get(i).copied().unwrap_or(0)).collect();
        Frame::new(w, h, 8, Pixels::U8(px), 0.0, 0)
    } else {
        let depth = 9 + data[5] % 8;
        let max = (1u32 << depth) - 1;
        let px: Vec<u16> = (0..n)
            .map(|i| {
                let lo = rest.get(2 * i).copied().unwrap_or(0);
                let hi = rest.get(2 * i + 1).copied().unwrap_or(0);
                (u32::from(u16::from_le_bytes([lo, hi])) % (max + 1)) as u16
            })
            .collect();
        Frame::new(w, h, depth, Pixels::U16(px), 0.0, 0)
    };
    let Ok(frame) = frame else {
        return;
    };
    let mut opts = DecodeOptions::new(period_um, bits);
    opts.mirrored = flags & 2 != 0;
    opts.polarity = match (flags >> 2) % 3 {
        0 => Polarity::Auto,
        1 => Polarity::BrightDots,
        _ => Polarity::DarkDots,
    };
    // The period check against a known pixel size (any value, also absurd).
    if flags & 64 != 0 {
        opts.pixel_um = Some(f64::from(data[5]) / 32.0);
    }
    let Ok(mut d) = Decoder::new(opts) else {
        return;
    };
    let _ = d.decode(&frame);
    let _ = d.track(&frame);
    let _ = d.track(&frame);
});
