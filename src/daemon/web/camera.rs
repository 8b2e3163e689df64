//! The camera view: the newest frame, downscaled and contrast-stretched to
//! an 8-bit PNG on the blocking pool, and the decode's overlay (position,
//! angle, quality, the dot lattice in the downscaled image's pixels) as
//! JSON; the page draws the lattice on a canvas over the image, so focus
//! and alignment can be judged by eye.
//!
//! Why it never disturbs decoding or motion: frames reach it through
//! [`FrameTap`] (the decode path only `try_lock`s to keep its newest
//! frame, it never waits), the downscale and the PNG encoding run on the
//! blocking pool, and at most `camera_max_hz` renders a second are made
//! however many viewers ask (the newest render is shared).

use crate::daemon::vision::{FrameTap, Snapshot, SnapshotDecode};
use crate::frame::Frame;
use serde_json::{json, Value};
use std::collections::VecDeque;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Most lattice points sent with one overlay.
pub const MAX_LATTICE_POINTS: usize = 4000;

/// Smallest spacing of the drawn lattice points in the downscaled image,
/// px: a fine pattern (dots a few pixels apart) is drawn every `stride`-th
/// dot, so the overlay shows the lattice's position and angle without
/// hiding the image.
pub const MIN_LATTICE_SPACING_PX: f64 = 12.0;

/// One rendered view.
#[derive(Debug, Clone)]
pub struct Rendered {
    /// Frame sequence number.
    pub sequence: u64,
    /// The PNG.
    pub png: Arc<Vec<u8>>,
    /// What the page overlays (see [`overlay`]).
    pub overlay: Value,
}

/// Renders kept: the newest and the one before, so a page that fetched an
/// overlay still finds its image when a new render came in between.
const KEPT: usize = 2;

/// The camera view's state: the tap and the newest renders.
#[derive(Debug)]
pub struct CameraView {
    tap: Arc<FrameTap>,
    min_interval: Duration,
    max_px: u32,
    renders: tokio::sync::Mutex<(Option<Instant>, VecDeque<Rendered>)>,
}

impl CameraView {
    /// A view of `tap` at most `max_hz` renders a second, `max_px` on the
    /// longer side.
    pub fn new(tap: Arc<FrameTap>, max_hz: f64, max_px: u32) -> CameraView {
        CameraView {
            tap,
            min_interval: Duration::try_from_secs_f64(1.0 / max_hz)
                .unwrap_or(Duration::from_secs(1)),
            max_px,
            renders: tokio::sync::Mutex::new((None, VecDeque::new())),
        }
    }

    /// The newest render, made anew if the last one is older than the rate
    /// allows and a newer frame exists; `None` while the camera has
    /// delivered no frame yet.
    pub async fn current(&self) -> Option<Rendered> {
        let mut g = self.renders.lock().await;
        let due = g.0.is_none_or(|t| t.elapsed() >= self.min_interval);
        if due {
            if let Some(snap) = self.tap.latest() {
                let newest = g.1.back().map(|r| r.sequence);
                if newest != Some(snap.frame.sequence) {
                    let max_px = self.max_px;
                    let r = tokio::task::spawn_blocking(move || render(&snap, max_px)).await;
                    match r {
                        Ok(Ok(r)) => {
                            g.1.push_back(r);
                            while g.1.len() > KEPT {
                                g.1.pop_front();
                            }
                        }
                        Ok(Err(e)) => tracing::warn!("camera view: {e}"),
                        Err(e) => tracing::warn!("camera view: render task failed: {e}"),
                    }
                }
                g.0 = Some(Instant::now());
            }
        }
        g.1.back().cloned()
    }

    /// The kept render of frame `sequence`, if still kept.
    pub async fn by_sequence(&self, sequence: u64) -> Option<Rendered> {
        let g = self.renders.lock().await;
        g.1.iter().find(|r| r.sequence == sequence).cloned()
    }
}

/// Why a render failed.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    /// The frame has no pixels.
    #[error("empty frame")]
    Empty,
    /// PNG encoding failed.
    #[error("PNG encoding: {0}")]
    Png(#[from] image::ImageError),
}

/// Downscales, stretches and encodes `snap`, and computes its overlay.
pub fn render(snap: &Snapshot, max_px: u32) -> Result<Rendered, RenderError> {
    let (small, w, h, factor) = downscale(&snap.frame, max_px.max(1) as usize)?;
    let img = image::GrayImage::from_raw(w as u32, h as u32, small).ok_or(RenderError::Empty)?;
    let mut png = Vec::new();
    img.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)?;
    Ok(Rendered {
        sequence: snap.frame.sequence,
        png: Arc::new(png),
        overlay: overlay(snap, w, h, factor),
    })
}

/// Box-averages `frame` by the smallest integer factor that brings its
/// longer side to at most `max_px`, and stretches the result's range to
/// 0..=255 (a dim pattern is still seen). Returns the pixels, width,
/// height and the factor.
pub fn downscale(
    frame: &Frame,
    max_px: usize,
) -> Result<(Vec<u8>, usize, usize, usize), RenderError> {
    let (fw, fh) = (frame.width(), frame.height());
    if fw == 0 || fh == 0 {
        return Err(RenderError::Empty);
    }
    let factor = fw.max(fh).div_ceil(max_px).max(1);
    let (w, h) = (fw / factor, fh / factor);
    if w == 0 || h == 0 {
        return Err(RenderError::Empty);
    }
    let mut sums = vec![0u64; w * h];
    for y in 0..h * factor {
        for x in 0..w * factor {
            sums[(y / factor) * w + x / factor] += u64::from(frame.get(x, y).unwrap_or(0));
        }
    }
    let lo = sums.iter().copied().min().unwrap_or(0);
    let hi = sums.iter().copied().max().unwrap_or(0);
    let span = (hi - lo).max(1);
    let px = sums
        .iter()
        .map(|&s| u8::try_from((s - lo) * 255 / span).unwrap_or(u8::MAX))
        .collect();
    Ok((px, w, h, factor))
}

/// The overlay in the downscaled image's pixel frame: the decode (`null`
/// when the frame did not decode) and the lattice of dot centres (phase
/// 0 of both fine-grid directions) inside the image.
pub fn overlay(snap: &Snapshot, w: usize, h: usize, factor: usize) -> Value {
    let f = &snap.frame;
    let decode = snap.decoded.map(|d| {
        let (lattice, stride) = lattice_px(&d, f.width() as f64, f.height() as f64, factor as f64);
        json!({
            "x_um": d.x_um, "y_um": d.y_um, "theta_rad": d.theta_rad,
            "pixel_um": d.pixel_um, "quality": d.quality,
            "coherence": d.grid.coherence,
            "lattice": lattice,
            "lattice_stride": stride,
        })
    });
    json!({
        "sequence": f.sequence,
        "width": w,
        "height": h,
        "factor": factor,
        "frame_width": f.width(),
        "frame_height": f.height(),
        "decode": decode,
    })
}

/// Dot centres in the downscaled image: the points `u` where
/// `k_d · (u − c) + φ_d = 2π n_d` for both directions `d`, `c` the image
/// centre, every `stride`-th dot in each direction (spacing at least
/// [`MIN_LATTICE_SPACING_PX`]); flattened `[x0, y0, x1, y1, …]`, at most
/// [`MAX_LATTICE_POINTS`]. Returns the points and the stride.
pub fn lattice_px(d: &SnapshotDecode, fw: f64, fh: f64, factor: f64) -> (Vec<f64>, i64) {
    let k = d.grid.k;
    let phi = d.grid.phi;
    let det = k[0][0] * k[1][1] - k[0][1] * k[1][0];
    if !(det.is_finite() && det.abs() > 1e-12 && factor > 0.0) {
        return (Vec::new(), 1);
    }
    // Pitch of each direction in the downscaled image, px.
    let pitch = |dir: usize| std::f64::consts::TAU / k[dir][0].hypot(k[dir][1]) / factor;
    let stride = (MIN_LATTICE_SPACING_PX / pitch(0).min(pitch(1)))
        .ceil()
        .clamp(1.0, 1e6) as i64;
    let (cx, cy) = (fw / 2.0, fh / 2.0);
    // The phase range of each direction over the image's corners.
    let corners = [(0.0, 0.0), (fw, 0.0), (0.0, fh), (fw, fh)];
    let range = |dir: usize| {
        let vals = corners.map(|(x, y)| k[dir][0] * (x - cx) + k[dir][1] * (y - cy) + phi[dir]);
        let tau = std::f64::consts::TAU;
        let lo = vals.iter().copied().fold(f64::INFINITY, f64::min) / tau;
        let hi = vals.iter().copied().fold(f64::NEG_INFINITY, f64::max) / tau;
        (lo.floor() as i64, hi.ceil() as i64)
    };
    let (a0, a1) = range(0);
    let (b0, b1) = range(1);
    let mut out = Vec::new();
    let tau = std::f64::consts::TAU;
    for n0 in (a0..=a1).filter(|n| n.rem_euclid(stride) == 0) {
        for n1 in (b0..=b1).filter(|n| n.rem_euclid(stride) == 0) {
            let r0 = tau * n0 as f64 - phi[0];
            let r1 = tau * n1 as f64 - phi[1];
            // Solve K (u − c) = r.
            let dx = (r0 * k[1][1] - r1 * k[0][1]) / det;
            let dy = (k[0][0] * r1 - k[1][0] * r0) / det;
            let (x, y) = (cx + dx, cy + dy);
            if (0.0..fw).contains(&x) && (0.0..fh).contains(&y) {
                if out.len() / 2 >= MAX_LATTICE_POINTS {
                    return (out, stride);
                }
                out.push(x / factor);
                out.push(y / factor);
            }
        }
    }
    (out, stride)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::Pixels;

    fn frame(w: usize, h: usize, f: impl Fn(usize, usize) -> u16) -> Frame {
        let px = (0..h)
            .flat_map(|y| (0..w).map(move |x| (x, y)))
            .map(|(x, y)| f(x, y))
            .collect();
        Frame::new(w, h, 12, Pixels::U16(px), 0.0, 7).unwrap()
    }

    #[test]
    fn downscale_averages_blocks_and_stretches() {
        // Left half 100, right half 300 → 0 and 255 after the stretch.
        let f = frame(8, 4, |x, _| if x < 4 { 100 } else { 300 });
        let (px, w, h, factor) = downscale(&f, 4).unwrap();
        assert_eq!((w, h, factor), (4, 2, 2));
        assert_eq!(px, vec![0, 0, 255, 255, 0, 0, 255, 255]);
        // Already small enough: factor 1.
        assert_eq!(downscale(&f, 100).unwrap().3, 1);
    }

    #[test]
    fn lattice_points_are_at_phase_zero() {
        let f = frame(64, 48, |_, _| 0);
        let grid = crate::pattern::decode::Grid {
            k: [
                [std::f64::consts::TAU / 8.0, 0.0],
                [0.0, std::f64::consts::TAU / 8.0],
            ],
            phi: [0.0, 0.0],
            amplitude: [1.0, 1.0],
            coherence: 1.0,
            phase_rms_rad: 0.0,
            blob_slope_px: [0.0, 0.0],
            distortion_px: 0.0,
        };
        let d = SnapshotDecode {
            x_um: 0.0,
            y_um: 0.0,
            theta_rad: 0.0,
            pixel_um: 0.5,
            quality: 9.0,
            grid,
        };
        let (pts, stride) = lattice_px(&d, 64.0, 48.0, 1.0);
        // A pitch of 8 px with a dot at the centre (32, 24): 8 × 6 dots,
        // every 2nd drawn (12 px spacing at least): 4 × 3.
        assert_eq!((pts.len() / 2, stride), (4 * 3, 2));
        for p in pts.chunks(2) {
            let (x, y) = (p[0], p[1]);
            assert!(
                ((x - 32.0) / 16.0 - ((x - 32.0) / 16.0).round()).abs() < 1e-9,
                "{x}"
            );
            assert!(
                ((y - 24.0) / 16.0 - ((y - 24.0) / 16.0).round()).abs() < 1e-9,
                "{y}"
            );
        }
        // Downscaled by 2 the dots are 4 px apart: every 3rd is drawn.
        let (pts, stride) = lattice_px(&d, 64.0, 48.0, 2.0);
        assert_eq!(stride, 3);
        assert!(!pts.is_empty() && pts.len() / 2 < 8 * 6);
        for p in pts.chunks(2) {
            let (x, y) = (p[0] * 2.0, p[1] * 2.0);
            assert!(
                ((x - 32.0) / 8.0 - ((x - 32.0) / 8.0).round()).abs() < 1e-9,
                "{x}"
            );
            assert!(
                ((y - 24.0) / 8.0 - ((y - 24.0) / 8.0).round()).abs() < 1e-9,
                "{y}"
            );
        }
        let snap = Snapshot {
            frame: Arc::new(f),
            decoded: Some(d),
        };
        let r = render(&snap, 32).unwrap();
        assert_eq!(r.sequence, 7);
        assert_eq!(&r.png[1..4], b"PNG");
        assert_eq!(r.overlay["width"], 32);
        assert_eq!(r.overlay["decode"]["quality"], 9.0);
    }
}
