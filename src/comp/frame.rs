//! The vision→stage transform, estimated from the characterization scans.
//!
//! The pattern is mounted at an unknown small angle and offset, and the
//! optics may mirror it. The transform is rigid plus an optional mirror:
//!
//! ```text
//! stage = R(rotation_rad) · M · vision + translation_um,   M = diag(1, ±1)
//! ```
//!
//! **No scale is fitted.** The pattern period is the length reference: a
//! stage whose screw runs 150 ppm long must show +150 ppm in the
//! compensation tables, not have it absorbed into the transform.
//!
//! **Rotation vs squareness.** A rotation of the camera and an
//! out-of-squareness of the Y stage both tilt the Y scan; they cannot be
//! told apart from the data alone. micropos *defines* the stage x axis as the
//! measured direction of X motion: `rotation_rad` makes the X scan's
//! least-squares direction (d vision / d x command) point along +x. The Y
//! scan's deviation from perpendicular that remains IS the squareness
//! (reported, and left in the data for `δx(y)` to compensate).
//!
//! **Mirror.** The stage frame is right-handed; the vision frame is
//! mirrored when turning from the X-motion direction to the Y-motion
//! direction is clockwise in it (negative cross product).
//!
//! **Translation.** The origin of a stage without an absolute reference is
//! a convention: `translation_um` makes the mean of `command − stage(vision)`
//! over the X scan's samples zero. The X axis of motion then defines the
//! frame's direction and origin, as in the paper: errors of Y motion
//! (squareness first) are measured from that line, so a square whose first
//! side runs along it shows the paper's full ≈ 22 µm squareness error
//! instead of half of it split ± around the middle of the Y range.

use serde::{Deserialize, Serialize};

use super::{invalid, CompError};
use crate::model::XyUm;

/// One scan sample: what was commanded and where the camera saw it (in the
/// camera's pattern frame, µm).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FrameSample {
    /// Commanded position, stage frame, µm.
    pub cmd: XyUm,
    /// Decoded position, pattern (vision) frame, µm.
    pub vision: XyUm,
}

/// `stage = R(rotation_rad)·M·vision + translation_um`; see the module docs.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VisionFrame {
    /// Rotation, rad, counter-clockwise from vision (after the mirror) to
    /// stage.
    pub rotation_rad: f64,
    /// True when vision y is flipped before rotating.
    pub mirrored: bool,
    /// Translation, µm `[x, y]`.
    pub translation_um: [f64; 2],
}

impl VisionFrame {
    /// The identity.
    pub const IDENTITY: VisionFrame = VisionFrame {
        rotation_rad: 0.0,
        mirrored: false,
        translation_um: [0.0, 0.0],
    };

    /// Finite values, |rotation| ≤ π.
    pub fn validate(&self) -> Result<(), CompError> {
        if !(self.rotation_rad.is_finite() && self.rotation_rad.abs() <= std::f64::consts::PI) {
            return Err(invalid("frame.rotation_rad", "must be finite, within ±π"));
        }
        if !self
            .translation_um
            .iter()
            .all(|v| v.is_finite() && v.abs() <= 1e9)
        {
            return Err(invalid(
                "frame.translation_um",
                "must be finite, within ±1e9",
            ));
        }
        Ok(())
    }

    /// Vision → stage.
    pub fn to_stage(&self, v: XyUm) -> XyUm {
        let vy = if self.mirrored { -v.y_um } else { v.y_um };
        let (s, c) = self.rotation_rad.sin_cos();
        XyUm {
            x_um: c * v.x_um - s * vy + self.translation_um[0],
            y_um: s * v.x_um + c * vy + self.translation_um[1],
        }
    }

    /// Stage → vision (exact inverse of [`VisionFrame::to_stage`]).
    pub fn to_vision(&self, p: XyUm) -> XyUm {
        let (dx, dy) = (
            p.x_um - self.translation_um[0],
            p.y_um - self.translation_um[1],
        );
        let (s, c) = self.rotation_rad.sin_cos();
        let (x, y) = (c * dx + s * dy, -s * dx + c * dy);
        XyUm {
            x_um: x,
            y_um: if self.mirrored { -y } else { y },
        }
    }
}

/// What the frame estimate found about the stage.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FrameReport {
    /// Length of X motion measured on the pattern per commanded length − 1,
    /// ppm (the stage's lead error plus thermal expansion; kept in the data).
    pub x_scale_ppm: f64,
    /// Same for Y, ppm.
    pub y_scale_ppm: f64,
    /// Squareness: angle of the Y motion from the stage's +y axis towards
    /// +x, µrad (model sign).
    pub squareness_urad: f64,
    /// RMS of `command − stage(vision)` over all samples `[x, y]`, µm (the
    /// stage's errors, not a fit quality).
    pub rms_error_um: [f64; 2],
}

/// Direction (d vision / d command) of a 1-DoF scan by least squares.
fn direction(samples: &[FrameSample], along_x: bool) -> Result<[f64; 2], CompError> {
    let n = samples.len() as f64;
    let c: Vec<f64> = samples
        .iter()
        .map(|s| if along_x { s.cmd.x_um } else { s.cmd.y_um })
        .collect();
    let cm = c.iter().sum::<f64>() / n;
    let um = samples.iter().map(|s| s.vision.x_um).sum::<f64>() / n;
    let vm = samples.iter().map(|s| s.vision.y_um).sum::<f64>() / n;
    let (mut scc, mut scu, mut scv) = (0.0, 0.0, 0.0);
    for (s, ci) in samples.iter().zip(&c) {
        let d = ci - cm;
        scc += d * d;
        scu += d * (s.vision.x_um - um);
        scv += d * (s.vision.y_um - vm);
    }
    if scc.is_nan() || scc <= 0.0 {
        return Err(CompError::NoData {
            what: format!(
                "the {} scan does not move its axis",
                if along_x { "X" } else { "Y" }
            ),
        });
    }
    Ok([scu / scc, scv / scc])
}

/// Estimates the vision→stage transform from the X scan and the Y scan
/// samples (see the module docs). Refuses data whose scale is far from 1
/// (wrong pattern period or pixel size) or whose scans are not roughly
/// perpendicular.
pub fn estimate_vision_frame(
    x_scan: &[FrameSample],
    y_scan: &[FrameSample],
) -> Result<(VisionFrame, FrameReport), CompError> {
    for (name, s) in [("X", x_scan), ("Y", y_scan)] {
        if s.len() < 2 {
            return Err(CompError::NoData {
                what: format!("the {name} scan has {} samples (need ≥ 2)", s.len()),
            });
        }
        if s.iter().any(|p| {
            ![p.cmd.x_um, p.cmd.y_um, p.vision.x_um, p.vision.y_um]
                .iter()
                .all(|v| v.is_finite())
        }) {
            return Err(invalid(format!("{name} scan"), "holds a non-finite value"));
        }
    }
    let a = direction(x_scan, true)?;
    let b = direction(y_scan, false)?;
    let (la, lb) = (a[0].hypot(a[1]), b[0].hypot(b[1]));
    for (name, l) in [("X", la), ("Y", lb)] {
        if !(0.9..=1.1).contains(&l) {
            return Err(invalid(
                format!("{name} scan"),
                format!(
                    "moves {l:.4} µm on the pattern per µm commanded: the pattern period or the pixel size is wrong (expected ≈ 1)"
                ),
            ));
        }
    }
    let cross = a[0] * b[1] - a[1] * b[0];
    let cos = (a[0] * b[0] + a[1] * b[1]) / (la * lb);
    if cos.abs() > 0.1 {
        return Err(invalid(
            "scans",
            format!(
                "X and Y motion are {:.1}° apart on the pattern (expected ≈ 90°)",
                cos.acos().to_degrees()
            ),
        ));
    }
    let mirrored = cross < 0.0;
    let m = |v: [f64; 2]| if mirrored { [v[0], -v[1]] } else { v };
    let am = m(a);
    let rotation_rad = -am[1].atan2(am[0]);
    let mut frame = VisionFrame {
        rotation_rad,
        mirrored,
        translation_um: [0.0, 0.0],
    };
    // Origin: the mean error along the X scan is zero. The X axis alone
    // defines the frame (direction and origin), as in the paper, so the
    // squareness and every other error of Y motion stay in the data measured
    // from that line, instead of being split ± around the middle of the Y
    // scan (which would halve the apparent squareness error).
    let nx = x_scan.len() as f64;
    let (mut tx, mut ty) = (0.0, 0.0);
    for s in x_scan {
        let p = frame.to_stage(s.vision);
        tx += s.cmd.x_um - p.x_um;
        ty += s.cmd.y_um - p.y_um;
    }
    frame.translation_um = [tx / nx, ty / nx];
    let all = x_scan.iter().chain(y_scan);
    let n = (x_scan.len() + y_scan.len()) as f64;
    let (mut ex, mut ey) = (0.0, 0.0);
    for s in all {
        let p = frame.to_stage(s.vision);
        ex += (s.cmd.x_um - p.x_um).powi(2);
        ey += (s.cmd.y_um - p.y_um).powi(2);
    }
    // Y direction in the stage frame.
    let bz = {
        let (sn, c) = rotation_rad.sin_cos();
        let bm = m(b);
        [c * bm[0] - sn * bm[1], sn * bm[0] + c * bm[1]]
    };
    let report = FrameReport {
        x_scale_ppm: (la - 1.0) * 1e6,
        y_scale_ppm: (lb - 1.0) * 1e6,
        squareness_urad: bz[0].atan2(bz[1]) * 1e6,
        rms_error_um: [(ex / n).sqrt(), (ey / n).sqrt()],
    };
    frame.validate()?;
    Ok((frame, report))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn to_vision_inverts_to_stage() {
        for mirrored in [false, true] {
            let f = VisionFrame {
                rotation_rad: 0.3,
                mirrored,
                translation_um: [12.0, -7.0],
            };
            let p = XyUm {
                x_um: 123.0,
                y_um: -45.0,
            };
            let q = f.to_stage(f.to_vision(p));
            assert!((q.x_um - p.x_um).abs() < 1e-9 && (q.y_um - p.y_um).abs() < 1e-9);
        }
    }
}
