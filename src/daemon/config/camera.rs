//! `[camera]`: the frame source and its decoding.

use serde::{Deserialize, Serialize};

/// `[camera]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CameraSection {
    /// Frame source (`v4l2:/dev/video0`, `genicam[:ID]`, `files:GLOB`,
    /// `sim:PATH` for hil-sim's camera socket); empty = no camera (vision features
    /// answer `camera_unavailable`).
    pub source: String,
    /// Longest wait for a frame, ms.
    pub timeout_ms: u64,
    /// Replay sources: start again after the last file.
    pub looping: bool,
    /// Pattern period, µm.
    pub period_um: f64,
    /// Pattern code depth (4..=12).
    pub bits: u32,
    /// The optics mirror the image.
    pub mirrored: bool,
    /// The camera's pixel size on the pattern, µm (sensor pixel ÷
    /// magnification), if known. Why: `period_um` only scales every
    /// position, so a wrong one gives confident positions off by its ratio;
    /// with the pixel size set, every decode checks the measured dot pitch
    /// against `period_um` (within 5 %) and a frame where they disagree is a
    /// decode error naming the period that fits. Unset: not checked.
    pub pixel_um: Option<f64>,
    /// Oldest measurement a closed-loop move or a job point may use, s.
    pub max_age_s: f64,
    /// Lowest decode quality accepted: the code evidence in bits (log₂
    /// likelihood ratio of the best code position over the runner-up). The
    /// decoder itself refuses less than 16 bits; clean frames score hundreds,
    /// so a lab can raise this to reject marginal frames (dust, defocus).
    pub min_quality: f64,
    /// Angle from the pattern frame to the stage frame, rad
    /// (counter-clockwise positive): stage = R(angle)·vision + offset.
    pub rotation_rad: f64,
    /// After a successful reference run of both axes, tie vision to the
    /// stage (`daemon::vision_tie`: two short lines, about 14 measurements,
    /// then back where the reference left the stage). Why on by default:
    /// without a tie a decoded position is no stage position and the
    /// vision-vs-controller deviation check has no frame (unless a table
    /// with one is active). Off: `reference` moves only to the reference.
    pub tie_after_reference: bool,
}

impl Default for CameraSection {
    fn default() -> Self {
        Self {
            source: String::new(),
            timeout_ms: 2000,
            looping: false,
            period_um: 9.0,
            bits: 12,
            mirrored: false,
            pixel_um: None,
            max_age_s: 1.0,
            min_quality: 16.0,
            rotation_rad: 0.0,
            tie_after_reference: true,
        }
    }
}
