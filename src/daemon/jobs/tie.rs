//! The run's own vision → stage tie: before a characterization (or a
//! validation without tables) logs anything, it moves along one line of X
//! and one line of Y, measures with the camera, and fits the rigid frame
//! with [`crate::comp::estimate_vision_frame`] (rotation from the direction
//! of X motion, mirror from the turn to Y motion, translation so the mean of
//! `command − stage(vision)` over the X tie line is zero; no scale, so lead
//! errors stay in the data; squareness stays in the Y scan). The X line runs
//! through the start corner of the scanned area, so the frame's origin is
//! that corner's X axis, as the paper's.
//!
//! Why a pre-scan rather than a fit on the finished log: the log is
//! appended point by point in the stage frame, so the frame must be known
//! before the first record; the metadata (written with the header) records
//! it, and a resumed job maps its frames with the same transform.
//!
//! The tie points are spaced by whole multiples of the leadscrew pitch
//! ([`PITCH_UM`], the paper's 400 µm): the screw's cyclic error is then the
//! same at every tie point and does not tilt the fitted direction. Every
//! tie point is reached forward (the line starts with an unmeasured move to
//! its first position), so backlash does not either.

use super::super::protocol::{ErrorCode, ProtoError};
use super::super::rig::Rig;
use super::measure_retrying;
use crate::charact::log::Metadata;
use crate::comp::{estimate_vision_frame, FrameReport, FrameSample, VisionFrame};
use crate::model::XyUm;
use std::sync::Arc;
use std::time::Duration;

/// Leadscrew pitch the tie spacing is a multiple of, µm (M-111: 400 µm).
pub const PITCH_UM: f64 = 400.0;

/// Positions along one tie line: from `start_um`, forward, spaced by a
/// multiple of [`PITCH_UM`] (about ten points over the range) when the range
/// allows at least two steps, else by half the range.
pub fn tie_positions(start_um: f64, range_um: f64) -> Vec<f64> {
    let k = (range_um / PITCH_UM / 10.0).floor().max(1.0);
    let mut step = PITCH_UM * k;
    if range_um < 2.0 * step {
        step = range_um / 2.0;
    }
    let n = (range_um / step + 1e-9).floor() as usize;
    (0..=n).map(|i| start_um + step * i as f64).collect()
}

/// One tie line: the moving axis (`x_axis`), its start and range, the held
/// position of the other axis.
#[derive(Debug, Clone, Copy)]
pub struct TieLine {
    /// True: X moves.
    pub x_axis: bool,
    /// First position of the moving axis, µm.
    pub start_um: f64,
    /// Range, µm.
    pub range_um: f64,
    /// Held position of the other axis, µm.
    pub hold_um: f64,
}

async fn raw_move(rig: &Arc<Rig>, x_um: f64, y_um: f64) -> Result<(), ProtoError> {
    super::move_raw_retrying(rig, x_um, y_um).await.map(|_| ())
}

/// Measures the two tie lines and fits the frame. `frames` frames are
/// averaged per point after `settle_s`.
pub async fn measure_frame(
    rig: &Arc<Rig>,
    lines: [TieLine; 2],
    frames: u32,
    settle_s: f64,
) -> Result<(VisionFrame, FrameReport), ProtoError> {
    let settle = Duration::try_from_secs_f64(settle_s).unwrap_or_default();
    let mut samples: [Vec<FrameSample>; 2] = [Vec::new(), Vec::new()];
    for (i, l) in lines.iter().enumerate() {
        let pos = tie_positions(l.start_um, l.range_um);
        let xy = |p: f64| {
            if l.x_axis {
                (p, l.hold_um)
            } else {
                (l.hold_um, p)
            }
        };
        for (k, p) in pos.iter().enumerate() {
            let (x, y) = xy(*p);
            raw_move(rig, x, y).await?;
            if k == 0 {
                // The arrival direction of the first point is unknown.
                continue;
            }
            rig.clock.sleep(settle).await;
            let (m, _) = measure_retrying(rig, frames).await?;
            samples[i].push(FrameSample {
                cmd: XyUm { x_um: x, y_um: y },
                vision: XyUm {
                    x_um: m.x_um,
                    y_um: m.y_um,
                },
            });
        }
    }
    estimate_vision_frame(&samples[0], &samples[1]).map_err(|e| {
        ProtoError::new(
            ErrorCode::CameraUnavailable,
            format!("tying the camera to the stage: {e}"),
        )
    })
}

/// Records the frame in log metadata (read back by
/// [`super::tables::frame_from_metadata`]).
pub fn to_metadata(md: &mut Metadata, frame: &VisionFrame, report: &FrameReport) {
    md.insert("vision_frame_rotation_rad", frame.rotation_rad.to_string());
    md.insert("vision_frame_mirrored", frame.mirrored.to_string());
    md.insert(
        "vision_frame_translation_x_um",
        frame.translation_um[0].to_string(),
    );
    md.insert(
        "vision_frame_translation_y_um",
        frame.translation_um[1].to_string(),
    );
    md.insert("vision_frame_method", "tie pre-scan, estimate_vision_frame");
    md.insert("tie_squareness_urad", report.squareness_urad.to_string());
    md.insert("tie_x_scale_ppm", report.x_scale_ppm.to_string());
    md.insert("tie_y_scale_ppm", report.y_scale_ppm.to_string());
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tie_points_are_pitch_multiples_when_possible() {
        let p = tie_positions(0.0, 9500.0);
        assert_eq!(p.len(), 12);
        assert_eq!(p[1], 800.0);
        assert!(p.iter().all(|v| (v / PITCH_UM).fract() == 0.0));
        let p = tie_positions(100.0, 4200.0);
        assert_eq!(
            p,
            (0..=10)
                .map(|i| 100.0 + 400.0 * i as f64)
                .collect::<Vec<_>>()
        );
        let p = tie_positions(0.0, 500.0);
        assert_eq!(p, vec![0.0, 250.0, 500.0]);
    }
}
