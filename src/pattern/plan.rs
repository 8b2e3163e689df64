//! Choosing a pattern for a rig: code depth n and period p from the range
//! to measure and the camera.
//!
//! Why: the pattern is fabricated once and then fixes the rig's range and
//! resolution; a wrong choice (too few pixels per period, too few periods in
//! view, pattern shorter than the travel) is only found after the mask is
//! paid for. The rules, all checked per axis:
//!
//! 1. sampling: 7 ≤ p / pixel ≤ 15 px per period (the phase decoder needs
//!    the fundamental well below Nyquist, and more than ~15 px per period
//!    wastes field of view);
//! 2. decodability: the view spans at least 3(n + 1) periods in each
//!    direction ([`LineSequence::min_periods_in_view`]), so a full code
//!    window of n bits is always visible;
//! 3. range: the whole view must stay on the pattern, so the travel the
//!    pattern supports is L·p − FOV along each axis, with
//!    L = 3(2^n − 1 + n − 1) lines; it must reach the wanted range.
//!
//! The smallest feasible n is recommended (fewest periods needed in view,
//! smallest mask); the period is the one nearest 10 px per period inside the
//! feasible interval, on a 0.1 µm grid when the interval allows. Every depth
//! 4..=12 is reported with its feasible period interval or the reasons it
//! fails.

use serde::Serialize;
use thiserror::Error;

use super::sequence::{MAX_BITS, MIN_BITS};

/// Fewest camera pixels per period the decoder accepts.
pub const MIN_PX_PER_PERIOD: f64 = 7.0;
/// Most camera pixels per period worth spending.
pub const MAX_PX_PER_PERIOD: f64 = 15.0;
/// Preferred sampling when the interval allows a choice.
pub const TARGET_PX_PER_PERIOD: f64 = 10.0;

/// Why a plan request cannot be evaluated at all.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum PlanError {
    /// An input is not a positive finite number (or a zero pixel count).
    #[error("{0}")]
    BadInput(String),
}

/// The camera as seen at the object plane.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct CameraGeometry {
    /// Sensor width in pixels (x axis of the image).
    pub width_px: u32,
    /// Sensor height in pixels (y axis of the image).
    pub height_px: u32,
    /// Size of one pixel projected on the pattern, in µm.
    pub pixel_um: f64,
}

impl CameraGeometry {
    /// From the sensor's own pixel pitch and the optical magnification:
    /// pixel at the object = sensor pixel / magnification.
    pub fn from_sensor(
        width_px: u32,
        height_px: u32,
        sensor_pixel_um: f64,
        magnification: f64,
    ) -> Result<Self, PlanError> {
        positive("sensor pixel size", sensor_pixel_um)?;
        positive("magnification", magnification)?;
        Ok(Self {
            width_px,
            height_px,
            pixel_um: sensor_pixel_um / magnification,
        })
    }

    /// Field of view (x, y) in µm.
    pub fn fov_um(&self) -> (f64, f64) {
        (
            f64::from(self.width_px) * self.pixel_um,
            f64::from(self.height_px) * self.pixel_um,
        )
    }
}

fn positive(what: &str, v: f64) -> Result<(), PlanError> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(PlanError::BadInput(format!(
            "{what} must be a positive number, got {v}"
        )))
    }
}

/// Number of lines L of an n-bit pattern: 3(2^n − 1 + n − 1).
pub fn sequence_len(bits: u32) -> u64 {
    3 * ((1u64 << bits) - 1 + u64::from(bits) - 1)
}

/// A feasible depth with its period interval and the chosen period.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Candidate {
    /// Code depth n.
    pub bits: u32,
    /// Lines L per axis.
    pub lines: u64,
    /// Smallest period meeting every rule, µm.
    pub period_min_um: f64,
    /// Largest period meeting every rule, µm.
    pub period_max_um: f64,
    /// The suggested period, µm.
    pub period_um: f64,
    /// Camera pixels per period at the suggested period.
    pub px_per_period: f64,
    /// Periods across the view (x, y) at the suggested period.
    pub periods_in_view: (f64, f64),
    /// Periods the decoder needs across the view: 3(n + 1).
    pub periods_needed: u64,
    /// Pattern side L·p, µm.
    pub pattern_um: f64,
    /// Travel the pattern supports (x, y): L·p − FOV, µm.
    pub travel_um: (f64, f64),
}

/// One code depth's verdict.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "verdict", rename_all = "snake_case")]
pub enum DepthVerdict {
    /// The depth works; see the candidate.
    Feasible(Candidate),
    /// The depth cannot meet the rules.
    Infeasible {
        /// Code depth n.
        bits: u32,
        /// Each rule that fails, in words with numbers.
        reasons: Vec<String>,
    },
}

/// The answer to a plan request.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Plan {
    /// Wanted range (x, y), µm.
    pub range_um: (f64, f64),
    /// The camera.
    pub camera: CameraGeometry,
    /// Field of view (x, y), µm.
    pub fov_um: (f64, f64),
    /// The smallest feasible depth, if any.
    pub recommended: Option<Candidate>,
    /// Every depth from 4 to 12.
    pub depths: Vec<DepthVerdict>,
}

/// Evaluates every code depth for a wanted range (x, y) in µm and a camera.
pub fn plan(range_x_um: f64, range_y_um: f64, camera: CameraGeometry) -> Result<Plan, PlanError> {
    for (what, v) in [("range x", range_x_um), ("range y", range_y_um)] {
        if !(v.is_finite() && v >= 0.0) {
            return Err(PlanError::BadInput(format!(
                "{what} must be a non-negative number of µm, got {v}"
            )));
        }
    }
    positive("pixel size at the object", camera.pixel_um)?;
    if camera.width_px == 0 || camera.height_px == 0 {
        return Err(PlanError::BadInput(
            "camera width and height must be > 0 px".into(),
        ));
    }
    let (fov_x, fov_y) = camera.fov_um();
    let pix = camera.pixel_um;
    let min_side_px = camera.width_px.min(camera.height_px);
    let mut depths = Vec::new();
    for bits in MIN_BITS..=MAX_BITS {
        let lines = sequence_len(bits);
        let l = lines as f64;
        let need = 3 * (u64::from(bits) + 1);
        let p_lo_px = MIN_PX_PER_PERIOD * pix;
        let p_hi_px = MAX_PX_PER_PERIOD * pix;
        let p_hi_view = fov_x.min(fov_y) / need as f64;
        let p_lo_range = ((range_x_um + fov_x) / l).max((range_y_um + fov_y) / l);
        let p_lo = p_lo_px.max(p_lo_range);
        let p_hi = p_hi_px.min(p_hi_view);
        let mut reasons = Vec::new();
        if p_hi_view < p_lo_px {
            reasons.push(format!(
                "field of view too small: {need} periods of at least {MIN_PX_PER_PERIOD} px need {} px across the smaller side, the camera has {min_side_px} px",
                (need as f64 * MIN_PX_PER_PERIOD).ceil()
            ));
        }
        if p_lo_range > p_hi {
            let (tx, ty) = (l * p_hi - fov_x, l * p_hi - fov_y);
            reasons.push(format!(
                "pattern too short: at the largest usable period {} µm the {lines}-line pattern spans {} µm, travel {} × {} µm < wanted {} × {} µm",
                round3(p_hi),
                round3(l * p_hi),
                round3(tx.max(0.0)),
                round3(ty.max(0.0)),
                round3(range_x_um),
                round3(range_y_um)
            ));
        }
        if reasons.is_empty() && p_lo <= p_hi {
            let p = choose_period(p_lo, p_hi, TARGET_PX_PER_PERIOD * pix);
            depths.push(DepthVerdict::Feasible(Candidate {
                bits,
                lines,
                period_min_um: p_lo,
                period_max_um: p_hi,
                period_um: p,
                px_per_period: p / pix,
                periods_in_view: (fov_x / p, fov_y / p),
                periods_needed: need,
                pattern_um: l * p,
                travel_um: (l * p - fov_x, l * p - fov_y),
            }));
        } else {
            if reasons.is_empty() {
                reasons.push(format!(
                    "no period satisfies every rule: needs {} ≤ p ≤ {} µm",
                    round3(p_lo),
                    round3(p_hi)
                ));
            }
            depths.push(DepthVerdict::Infeasible { bits, reasons });
        }
    }
    let recommended = depths.iter().find_map(|d| match d {
        DepthVerdict::Feasible(c) => Some(c.clone()),
        DepthVerdict::Infeasible { .. } => None,
    });
    Ok(Plan {
        range_um: (range_x_um, range_y_um),
        camera,
        fov_um: (fov_x, fov_y),
        recommended,
        depths,
    })
}

fn round3(v: f64) -> f64 {
    (v * 1000.0).round() / 1000.0
}

/// The period in [lo, hi] nearest `target`, snapped to a 0.1 µm grid when a
/// grid value lies in the interval (masks are easier to specify and check
/// with round periods).
fn choose_period(lo: f64, hi: f64, target: f64) -> f64 {
    let t = target.clamp(lo, hi);
    let snapped = (t * 10.0).round() / 10.0;
    if (lo..=hi).contains(&snapped) {
        return snapped;
    }
    let (up, down) = ((lo * 10.0).ceil() / 10.0, (hi * 10.0).floor() / 10.0);
    if up <= hi {
        up
    } else if down >= lo {
        down
    } else {
        t
    }
}

impl Plan {
    /// A human-readable report.
    pub fn to_text(&self) -> String {
        let mut s = String::new();
        let c = &self.camera;
        s.push_str(&format!(
            "camera {}×{} px, {} µm/px at the object: field of view {} × {} µm\nwanted range {} × {} µm\n",
            c.width_px,
            c.height_px,
            c.pixel_um,
            round3(self.fov_um.0),
            round3(self.fov_um.1),
            self.range_um.0,
            self.range_um.1
        ));
        match &self.recommended {
            Some(r) => s.push_str(&format!(
                "\nrecommended: {}-bit code, period {} µm ({:.1} px/period), pattern {} × {} lines = {} mm square, travel {} × {} µm, {:.1} × {:.1} periods in view (needs {})\n",
                r.bits,
                round3(r.period_um),
                r.px_per_period,
                r.lines,
                r.lines,
                round3(r.pattern_um / 1000.0),
                round3(r.travel_um.0),
                round3(r.travel_um.1),
                r.periods_in_view.0,
                r.periods_in_view.1,
                r.periods_needed
            )),
            None => s.push_str("\nno code depth from 4 to 12 fits this camera and range; see below\n"),
        }
        s.push_str("\nby code depth:\n");
        for d in &self.depths {
            match d {
                DepthVerdict::Feasible(c) => s.push_str(&format!(
                    "  {:>2}-bit: ok, period {}..{} µm (suggest {}), travel up to {} × {} µm\n",
                    c.bits,
                    round3(c.period_min_um),
                    round3(c.period_max_um),
                    round3(c.period_um),
                    round3(c.lines as f64 * c.period_max_um - self.fov_um.0),
                    round3(c.lines as f64 * c.period_max_um - self.fov_um.1)
                )),
                DepthVerdict::Infeasible { bits, reasons } => s.push_str(&format!(
                    "  {bits:>2}-bit: infeasible: {}\n",
                    reasons.join("; ")
                )),
            }
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paper_rig_pattern_extent() {
        // 10-bit code, 4 µm period: L·p = 3·(1023 + 9)·4 µm.
        assert_eq!(sequence_len(10), 3096);
        assert_eq!(sequence_len(10) as f64 * 4.0, 12384.0);
        assert_eq!(sequence_len(4), 54);
        assert_eq!(
            sequence_len(12),
            crate::pattern::sequence::LineSequence::new(12)
                .unwrap()
                .len() as u64
        );
    }

    #[test]
    fn paper_like_rig_picks_ten_bits_four_um() {
        // 1024×768 camera at 0.4 µm/px: FOV 409.6 × 307.2 µm. Range 10 × 4 mm.
        // n = 9: L = 1557, needs p ≥ 10409.6/1557 = 6.686 µm, but
        //        p ≤ 15 px · 0.4 = 6.0 µm → too short.
        // n = 10: L = 3096, p ∈ [max(2.8, 10409.6/3096 = 3.362), min(6.0, 307.2/33 = 9.31)]
        //        = [3.362, 6.0]; 10 px/period → 4.0 µm.
        let cam = CameraGeometry {
            width_px: 1024,
            height_px: 768,
            pixel_um: 0.4,
        };
        let p = plan(10_000.0, 4_000.0, cam).unwrap();
        let r = p.recommended.clone().unwrap();
        assert_eq!(r.bits, 10);
        assert_eq!(r.period_um, 4.0);
        assert!((r.period_min_um - 10_409.6 / 3096.0).abs() < 1e-12);
        assert!((r.period_max_um - 6.0).abs() < 1e-12);
        assert!((r.px_per_period - 10.0).abs() < 1e-12);
        assert_eq!(r.periods_needed, 33);
        assert!((r.pattern_um - 12_384.0).abs() < 1e-9);
        match &p.depths[5] {
            DepthVerdict::Infeasible { bits: 9, reasons } => {
                assert!(reasons[0].contains("pattern too short"), "{reasons:?}")
            }
            other => panic!("9-bit should fail: {other:?}"),
        }
        assert!(p
            .to_text()
            .contains("recommended: 10-bit code, period 4 µm"));
    }

    #[test]
    fn small_camera_is_infeasible_with_reason() {
        // 100 px: even n = 4 needs 15 periods × 7 px = 105 px.
        let cam = CameraGeometry {
            width_px: 100,
            height_px: 100,
            pixel_um: 1.0,
        };
        let p = plan(100.0, 100.0, cam).unwrap();
        assert!(p.recommended.is_none());
        for d in &p.depths {
            match d {
                DepthVerdict::Infeasible { reasons, .. } => {
                    assert!(
                        reasons[0].contains("field of view too small"),
                        "{reasons:?}"
                    )
                }
                other => panic!("{other:?}"),
            }
        }
        assert!(p.to_text().contains("no code depth"));
    }

    #[test]
    fn tiny_range_takes_smallest_depth_and_big_range_none() {
        // 2048×2048 at 0.5 µm/px (FOV 1024 µm); 100 µm range: 4-bit works?
        // n = 4: L = 54, p ∈ [max(3.5, 1124/54 = 20.8), min(7.5, 1024/15)] → empty.
        // n = 5: L = 3·(31 + 4) = 105, p ≥ 1124/105 = 10.7 > 7.5 → no.
        // n = 6: L = 3·(63 + 5) = 204, p ≥ 5.51, ≤ 7.5 → yes; 10 px = 5.0 → clamp 5.6 (grid).
        let cam = CameraGeometry {
            width_px: 2048,
            height_px: 2048,
            pixel_um: 0.5,
        };
        let p = plan(100.0, 100.0, cam).unwrap();
        let r = p.recommended.unwrap();
        assert_eq!(r.bits, 6);
        assert!((r.period_min_um - 1124.0 / 204.0).abs() < 1e-12);
        assert_eq!(r.period_um, 5.6);
        // A 1 m range is beyond even 12 bits at 7.5 µm (12318 · 7.5 = 92 mm).
        let p = plan(1e6, 1e6, cam).unwrap();
        assert!(p.recommended.is_none());
    }

    #[test]
    fn from_sensor_and_bad_inputs() {
        let c = CameraGeometry::from_sensor(1024, 768, 4.65, 10.0).unwrap();
        assert!((c.pixel_um - 0.465).abs() < 1e-12);
        assert!(CameraGeometry::from_sensor(1, 1, 4.0, 0.0).is_err());
        let cam = CameraGeometry {
            width_px: 0,
            height_px: 10,
            pixel_um: 1.0,
        };
        assert!(plan(1.0, 1.0, cam).is_err());
        let cam = CameraGeometry {
            width_px: 10,
            height_px: 10,
            pixel_um: f64::NAN,
        };
        assert!(plan(1.0, 1.0, cam).is_err());
        let cam = CameraGeometry {
            width_px: 10,
            height_px: 10,
            pixel_um: 1.0,
        };
        assert!(plan(-1.0, 1.0, cam).is_err());
    }

    #[test]
    fn period_snapping() {
        assert_eq!(choose_period(3.36, 6.0, 4.0), 4.0);
        assert_eq!(choose_period(5.51, 7.5, 5.0), 5.6);
        assert_eq!(choose_period(5.51, 5.55, 5.0), 5.51);
    }
}
