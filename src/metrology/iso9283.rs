//! ISO 9283 pose accuracy (AP) and pose repeatability (RP) in the XY plane.
//!
//! These are the figures Tan et al. report for the XY stage (paper eqs. 1–3
//! and 6): a target pose `(x_T, y_T)` is visited `n` times, the measured
//! positions `(x_j, y_j)` have the barycentre `(x̄, ȳ)`, and
//!
//! * `APx = x̄ − x_T`, `APy = ȳ − y_T`, `AP = sqrt(APx² + APy²)`: how far the
//!   *average* arrival is from where it was sent (systematic error);
//! * `l_j = sqrt((x_j − x̄)² + (y_j − ȳ)²)`, `l̄ = mean(l_j)`,
//!   `S_l = sqrt(Σ(l_j − l̄)² / (n − 1))`, `RP = l̄ + 3·S_l`: the radius of the
//!   circle around the barycentre that holds (nearly) all arrivals (random
//!   error).
//!
//! Sign convention: `APx`/`APy` follow ISO 9283, *measured minus target*.
//! This is the opposite of the paper's error sign `target − measured` used in
//! the measurement log (`crate::charact::log::Record::error_x_um`); `AP` itself
//! is a distance and has no sign.
//!
//! AP is defined for any `n ≥ 1` (a pose visited once has AP equal to the
//! distance of that single arrival). RP needs `n ≥ 2` because `S_l` divides
//! by `n − 1`; with one visit it is reported as `None` rather than as a
//! misleading zero.

use thiserror::Error;

/// A point in the stage XY plane, in micrometres.
///
/// Used for both targets and measured positions so that AP and RP are
/// computed in one frame; the caller is responsible for expressing both in
/// the stage frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Xy {
    /// X coordinate, µm.
    pub x_um: f64,
    /// Y coordinate, µm.
    pub y_um: f64,
}

impl Xy {
    /// A point from its coordinates in micrometres.
    pub fn new(x_um: f64, y_um: f64) -> Self {
        Self { x_um, y_um }
    }

    fn is_finite(self) -> bool {
        self.x_um.is_finite() && self.y_um.is_finite()
    }
}

/// Why an ISO 9283 figure could not be computed.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum Iso9283Error {
    /// A pose was given without any measured visit: neither AP nor RP exist.
    #[error("pose has no measured visit; AP needs at least one, RP at least two")]
    NoVisits,
    /// The target pose holds a NaN or infinite coordinate.
    #[error("target pose ({x_um}, {y_um}) µm is not finite")]
    NonFiniteTarget {
        /// Target x, µm.
        x_um: f64,
        /// Target y, µm.
        y_um: f64,
    },
    /// A measured visit holds a NaN or infinite coordinate.
    #[error("measured visit #{index} ({x_um}, {y_um}) µm is not finite")]
    NonFiniteVisit {
        /// Zero-based index of the visit in the input slice.
        index: usize,
        /// Measured x, µm.
        x_um: f64,
        /// Measured y, µm.
        y_um: f64,
    },
    /// A summary was asked for over an empty set of poses.
    #[error("no poses to summarise")]
    NoPoses,
}

/// ISO 9283 figures of one target pose.
#[derive(Clone, Debug, PartialEq)]
pub struct PoseStats {
    /// The target (commanded) pose, µm.
    pub target: Xy,
    /// Number of measured visits `n`.
    pub visits: usize,
    /// Barycentre `(x̄, ȳ)` of the measured visits, µm.
    pub barycentre: Xy,
    /// `APx = x̄ − x_T`, µm (ISO sign: measured minus target).
    pub apx_um: f64,
    /// `APy = ȳ − y_T`, µm (ISO sign: measured minus target).
    pub apy_um: f64,
    /// `AP = sqrt(APx² + APy²)`, µm; always ≥ 0.
    pub ap_um: f64,
    /// `l̄`, mean distance of the visits to their barycentre, µm.
    pub l_mean_um: f64,
    /// `S_l`, sample standard deviation (n − 1) of those distances, µm;
    /// `None` when `n < 2`.
    pub s_l_um: Option<f64>,
    /// `RP = l̄ + 3·S_l`, µm; `None` when `n < 2`.
    pub rp_um: Option<f64>,
}

/// Computes AP and RP of one target pose from its measured visits.
///
/// Errors when there is no visit or when any coordinate is not finite; a NaN
/// would otherwise propagate silently into every figure.
pub fn pose_stats(target: Xy, visits: &[Xy]) -> Result<PoseStats, Iso9283Error> {
    if !target.is_finite() {
        return Err(Iso9283Error::NonFiniteTarget {
            x_um: target.x_um,
            y_um: target.y_um,
        });
    }
    if let Some((index, v)) = visits.iter().enumerate().find(|(_, v)| !v.is_finite()) {
        return Err(Iso9283Error::NonFiniteVisit {
            index,
            x_um: v.x_um,
            y_um: v.y_um,
        });
    }
    if visits.is_empty() {
        return Err(Iso9283Error::NoVisits);
    }
    let n = visits.len() as f64;
    let x_bar = visits.iter().map(|v| v.x_um).sum::<f64>() / n;
    let y_bar = visits.iter().map(|v| v.y_um).sum::<f64>() / n;
    let apx_um = x_bar - target.x_um;
    let apy_um = y_bar - target.y_um;
    let ap_um = apx_um.hypot(apy_um);

    let l: Vec<f64> = visits
        .iter()
        .map(|v| (v.x_um - x_bar).hypot(v.y_um - y_bar))
        .collect();
    let l_mean_um = l.iter().sum::<f64>() / n;
    let s_l_um = (visits.len() >= 2).then(|| {
        let ss: f64 = l.iter().map(|lj| (lj - l_mean_um).powi(2)).sum();
        (ss / (n - 1.0)).sqrt()
    });
    let rp_um = s_l_um.map(|s| l_mean_um + 3.0 * s);

    Ok(PoseStats {
        target,
        visits: visits.len(),
        barycentre: Xy::new(x_bar, y_bar),
        apx_um,
        apy_um,
        ap_um,
        l_mean_um,
        s_l_um,
        rp_um,
    })
}

/// AP and RP aggregated over several target poses.
///
/// ISO 9283 reports AP and RP *per pose*; it defines no aggregate. A single
/// number is still what people quote (the paper's "accuracy about 22 µm" is
/// read off the per-pose curves of its Figs. 10 and 11), so both the worst
/// pose (`*_max_um`) and the typical pose (`*_mean_um`) are given. micropos
/// reports the **maximum** as the headline accuracy, because it is the only
/// one of the two that bounds the error at every pose a user may command;
/// the mean is given to compare with "typical" figures such as the paper's.
#[derive(Clone, Debug, PartialEq)]
pub struct PoseSummary {
    /// Number of poses summarised.
    pub poses: usize,
    /// Largest AP over the poses, µm (headline accuracy).
    pub ap_max_um: f64,
    /// Index (into the input slice) of the pose with the largest AP.
    pub ap_max_pose: usize,
    /// Mean of the per-pose AP values, µm.
    pub ap_mean_um: f64,
    /// Largest RP over the poses, µm; `None` unless every pose has an RP
    /// (a summary that skipped single-visit poses would understate it).
    pub rp_max_um: Option<f64>,
    /// Index of the pose with the largest RP, when `rp_max_um` is `Some`.
    pub rp_max_pose: Option<usize>,
    /// Mean of the per-pose RP values, µm, with the same rule as `rp_max_um`.
    pub rp_mean_um: Option<f64>,
}

/// Summarises per-pose figures into the worst and the mean pose.
pub fn summarize_poses(stats: &[PoseStats]) -> Result<PoseSummary, Iso9283Error> {
    let first = stats.first().ok_or(Iso9283Error::NoPoses)?;
    let n = stats.len() as f64;
    let mut ap_max_pose = 0;
    let mut ap_max_um = first.ap_um;
    for (i, s) in stats.iter().enumerate() {
        if s.ap_um > ap_max_um {
            ap_max_um = s.ap_um;
            ap_max_pose = i;
        }
    }
    let ap_mean_um = stats.iter().map(|s| s.ap_um).sum::<f64>() / n;

    let rps: Option<Vec<f64>> = stats.iter().map(|s| s.rp_um).collect();
    let (rp_max_um, rp_max_pose, rp_mean_um) = match rps {
        Some(rps) => {
            let mut best = 0;
            for (i, r) in rps.iter().enumerate() {
                if *r > rps[best] {
                    best = i;
                }
            }
            let mean = rps.iter().sum::<f64>() / n;
            (Some(rps[best]), Some(best), Some(mean))
        }
        None => (None, None, None),
    };
    Ok(PoseSummary {
        poses: stats.len(),
        ap_max_um,
        ap_max_pose,
        ap_mean_um,
        rp_max_um,
        rp_max_pose,
        rp_mean_um,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: f64, b: f64, tol: f64) -> bool {
        (a - b).abs() <= tol
    }

    #[test]
    fn ap_of_symmetric_visits_is_offset_of_their_centre() {
        // Visits (1,0), (3,0), (2,1), (2,-1) around (2,0); target (0,0).
        // Barycentre (2,0) by hand, so APx = 2, APy = 0, AP = 2.
        let v = [
            Xy::new(1.0, 0.0),
            Xy::new(3.0, 0.0),
            Xy::new(2.0, 1.0),
            Xy::new(2.0, -1.0),
        ];
        let s = pose_stats(Xy::new(0.0, 0.0), &v).unwrap();
        assert_eq!(s.visits, 4);
        assert!(close(s.barycentre.x_um, 2.0, 1e-12));
        assert!(close(s.barycentre.y_um, 0.0, 1e-12));
        assert!(close(s.apx_um, 2.0, 1e-12));
        assert!(close(s.apy_um, 0.0, 1e-12));
        assert!(close(s.ap_um, 2.0, 1e-12));
        // All four visits are at distance 1 from the barycentre: l̄ = 1,
        // S_l = 0, RP = 1.
        assert!(close(s.l_mean_um, 1.0, 1e-12));
        assert!(close(s.s_l_um.unwrap(), 0.0, 1e-12));
        assert!(close(s.rp_um.unwrap(), 1.0, 1e-12));
    }

    #[test]
    fn rp_of_three_collinear_visits_by_hand() {
        // Visits x = 0, 3, 6 (y = 0) for target (10, 4).
        // Barycentre (3, 0): APx = 3 − 10 = −7, APy = 0 − 4 = −4,
        // AP = sqrt(49 + 16) = sqrt(65).
        // l = 3, 0, 3: l̄ = 2; Σ(l − l̄)² = 1 + 4 + 1 = 6; S = sqrt(6/2) = sqrt(3);
        // RP = 2 + 3·sqrt(3).
        let v = [Xy::new(0.0, 0.0), Xy::new(3.0, 0.0), Xy::new(6.0, 0.0)];
        let s = pose_stats(Xy::new(10.0, 4.0), &v).unwrap();
        assert!(close(s.apx_um, -7.0, 1e-12));
        assert!(close(s.apy_um, -4.0, 1e-12));
        assert!(close(s.ap_um, 65f64.sqrt(), 1e-12));
        assert!(close(s.l_mean_um, 2.0, 1e-12));
        assert!(close(s.s_l_um.unwrap(), 3f64.sqrt(), 1e-12));
        assert!(close(s.rp_um.unwrap(), 2.0 + 3.0 * 3f64.sqrt(), 1e-12));
    }

    #[test]
    fn single_visit_has_ap_but_no_rp() {
        let s = pose_stats(Xy::new(1.0, 1.0), &[Xy::new(4.0, 5.0)]).unwrap();
        assert!(close(s.ap_um, 5.0, 1e-12));
        assert_eq!(s.l_mean_um, 0.0);
        assert_eq!(s.s_l_um, None);
        assert_eq!(s.rp_um, None);
    }

    #[test]
    fn bad_inputs_are_rejected() {
        assert_eq!(
            pose_stats(Xy::new(0.0, 0.0), &[]),
            Err(Iso9283Error::NoVisits)
        );
        assert!(matches!(
            pose_stats(Xy::new(f64::NAN, 0.0), &[Xy::new(0.0, 0.0)]),
            Err(Iso9283Error::NonFiniteTarget { .. })
        ));
        assert!(matches!(
            pose_stats(
                Xy::new(0.0, 0.0),
                &[Xy::new(0.0, 0.0), Xy::new(0.0, f64::INFINITY)]
            ),
            Err(Iso9283Error::NonFiniteVisit { index: 1, .. })
        ));
        assert_eq!(summarize_poses(&[]), Err(Iso9283Error::NoPoses));
    }

    #[test]
    fn summary_reports_worst_and_mean_pose() {
        // AP per pose: 5 (one visit, no RP), 1, 3.
        let a = pose_stats(Xy::new(0.0, 0.0), &[Xy::new(3.0, 4.0)]).unwrap();
        let b = pose_stats(Xy::new(0.0, 0.0), &[Xy::new(-1.0, 1.0), Xy::new(1.0, 1.0)]).unwrap();
        let c = pose_stats(Xy::new(0.0, 0.0), &[Xy::new(3.0, 0.0), Xy::new(3.0, 0.0)]).unwrap();
        let s = summarize_poses(&[b.clone(), a.clone(), c.clone()]).unwrap();
        assert_eq!(s.poses, 3);
        assert!(close(s.ap_max_um, 5.0, 1e-12));
        assert_eq!(s.ap_max_pose, 1);
        assert!(close(s.ap_mean_um, 3.0, 1e-12));
        // Pose a has one visit: no RP aggregate.
        assert_eq!(s.rp_max_um, None);
        assert_eq!(s.rp_mean_um, None);

        // b: visits 1 µm either side of the barycentre, l = 1, 1: RP = 1.
        // c: identical visits, RP = 0.
        let s = summarize_poses(&[c, b]).unwrap();
        assert!(close(s.ap_max_um, 3.0, 1e-12));
        assert_eq!(s.ap_max_pose, 0);
        assert!(close(s.rp_max_um.unwrap(), 1.0, 1e-12));
        assert_eq!(s.rp_max_pose, Some(1));
        assert!(close(s.rp_mean_um.unwrap(), 0.5, 1e-12));
    }
}
