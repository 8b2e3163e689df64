//! ISO 230-2:2014 evaluation of the positioning accuracy and repeatability of
//! one axis, from a bidirectional test.
//!
//! The test visits targets `P_i` (`i = 1..m`) in `n` cycles `j`, each target
//! once with a positive approach (↑, arriving while moving towards +) and
//! once with a negative approach (↓) per cycle. With the positional deviation
//! `x_ij = P_ij − P_i` (*measured minus target*, the standard's sign), the
//! figures are, exactly as ISO 230-2:2014 clause 3 defines them:
//!
//! | symbol | definition |
//! |---|---|
//! | `x̄↑_i`, `x̄↓_i` | mean unidirectional positional deviation, `Σ_j x_ij / n` |
//! | `x̄_i` | mean bidirectional positional deviation, `(x̄↑_i + x̄↓_i) / 2` |
//! | `B_i` | reversal value, `x̄↑_i − x̄↓_i` |
//! | `B` | reversal value of the axis, `max |B_i|` |
//! | `B̄` | mean reversal value, `Σ_i B_i / m` (signed) |
//! | `s↑_i`, `s↓_i` | estimator of unidirectional repeatability, `sqrt(Σ_j (x↑_ij − x̄↑_i)² / (n − 1))`, likewise ↓ |
//! | `R↑_i`, `R↓_i` | unidirectional repeatability, `4 s↑_i`, `4 s↓_i` |
//! | `R_i` | bidirectional repeatability, `max(2 s↑_i + 2 s↓_i + |B_i|, R↑_i, R↓_i)` |
//! | `R↑`, `R↓`, `R` | repeatability of the axis, `max_i` of the above |
//! | `E↑`, `E↓` | unidirectional systematic positional deviation, `max x̄↑_i − min x̄↑_i` |
//! | `E` | bidirectional systematic positional deviation, `max(x̄↑_i, x̄↓_i) − min(x̄↑_i, x̄↓_i)` |
//! | `M` | range of the mean bidirectional positional deviation, `max x̄_i − min x̄_i` |
//! | `A↑`, `A↓` | unidirectional accuracy, `max(x̄↑_i + 2 s↑_i) − min(x̄↑_i − 2 s↑_i)` |
//! | `A` | bidirectional accuracy, `max(x̄↑_i + 2 s↑_i, x̄↓_i + 2 s↓_i) − min(x̄↑_i − 2 s↑_i, x̄↓_i − 2 s↓_i)` |
//!
//! Conventions stated here because the standard leaves them to the user:
//! * The approach direction is given by the caller per observation; a test
//!   whose "forward" run moves towards + maps forward to [`Approach::Positive`].
//! * Targets are matched by exact equality of `target_um` (−0 equals +0): the
//!   same target must be written identically in every cycle, as a test
//!   program does. Results list targets in increasing order.
//! * At least 2 cycles are required (the `n − 1` estimator); the standard's
//!   test uses at least [`ISO_MIN_CYCLES`] = 5, which callers can check with
//!   [`AxisFigures::meets_iso_cycle_count`]. Every cycle must visit every
//!   target in both directions, as the standard's test does.
//! * Environmental compensation (temperature) is the caller's business; the
//!   deviations are evaluated as given.

use std::collections::{BTreeMap, BTreeSet};

use thiserror::Error;

/// Minimum number of cycles the ISO 230-2 standard test performs.
pub const ISO_MIN_CYCLES: usize = 5;

/// Direction of motion when arriving at a target.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Approach {
    /// ↑: the axis was moving in its positive direction when it arrived.
    Positive,
    /// ↓: the axis was moving in its negative direction when it arrived.
    Negative,
}

impl Approach {
    fn symbol(self) -> &'static str {
        match self {
            Approach::Positive => "positive (↑)",
            Approach::Negative => "negative (↓)",
        }
    }
}

impl std::fmt::Display for Approach {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.symbol())
    }
}

/// One measured arrival at a target.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Observation {
    /// The target position `P_i`, µm.
    pub target_um: f64,
    /// The cycle `j` this arrival belongs to (any numbering; only equality
    /// matters).
    pub cycle: u32,
    /// The approach direction.
    pub approach: Approach,
    /// The measured position `P_ij`, µm.
    pub measured_um: f64,
}

impl Observation {
    /// Positional deviation `x_ij = P_ij − P_i`, µm (measured minus target).
    pub fn deviation_um(&self) -> f64 {
        self.measured_um - self.target_um
    }
}

/// Why an ISO 230-2 evaluation was refused.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum Iso230Error {
    /// No observation at all.
    #[error("no observations")]
    NoObservations,
    /// A target or measured position is NaN or infinite.
    #[error(
        "observation #{index}: target {target_um} µm / measured {measured_um} µm is not finite"
    )]
    NonFinite {
        /// Zero-based index of the observation in the input.
        index: usize,
        /// Its target, µm.
        target_um: f64,
        /// Its measured position, µm.
        measured_um: f64,
    },
    /// The same target, approach and cycle appear twice.
    #[error("target {target_um} µm, {approach} approach, cycle {cycle} is measured more than once (observations #{first} and #{second})")]
    Duplicate {
        /// The target, µm.
        target_um: f64,
        /// The approach.
        approach: Approach,
        /// The cycle.
        cycle: u32,
        /// Index of the first occurrence.
        first: usize,
        /// Index of the repeated occurrence.
        second: usize,
    },
    /// A target was never approached from one of the two directions.
    #[error("target {target_um} µm has no {approach} approach; ISO 230-2 is bidirectional")]
    MissingApproach {
        /// The target, µm.
        target_um: f64,
        /// The direction that is missing.
        approach: Approach,
    },
    /// A cycle skipped a target in one direction while other targets were
    /// measured in that cycle (mismatched targets between cycles).
    #[error("cycle {cycle} has no {approach} measurement of target {target_um} µm, but other targets were measured in that cycle")]
    MissingVisit {
        /// The target, µm.
        target_um: f64,
        /// The approach.
        approach: Approach,
        /// The cycle lacking it.
        cycle: u32,
    },
    /// Fewer than two cycles: the repeatability estimator (n − 1) is undefined.
    #[error("{cycles} cycle(s) measured; at least 2 are needed (ISO 230-2 uses {ISO_MIN_CYCLES})")]
    TooFewCycles {
        /// Number of cycles found.
        cycles: usize,
    },
}

/// The per-target figures of ISO 230-2 (µm).
#[derive(Clone, Debug, PartialEq)]
pub struct TargetFigures {
    /// Target position `P_i`, µm.
    pub target_um: f64,
    /// `x̄↑_i`, mean deviation with positive approach.
    pub mean_up_um: f64,
    /// `x̄↓_i`, mean deviation with negative approach.
    pub mean_down_um: f64,
    /// `x̄_i = (x̄↑_i + x̄↓_i) / 2`.
    pub mean_um: f64,
    /// `s↑_i`, repeatability estimator with positive approach.
    pub s_up_um: f64,
    /// `s↓_i`, repeatability estimator with negative approach.
    pub s_down_um: f64,
    /// `B_i = x̄↑_i − x̄↓_i` (signed).
    pub reversal_um: f64,
    /// `R↑_i = 4 s↑_i`.
    pub r_up_um: f64,
    /// `R↓_i = 4 s↓_i`.
    pub r_down_um: f64,
    /// `R_i = max(2 s↑_i + 2 s↓_i + |B_i|, R↑_i, R↓_i)`.
    pub r_um: f64,
}

/// The axis figures of ISO 230-2 (µm), with the per-target figures they come
/// from.
#[derive(Clone, Debug, PartialEq)]
pub struct AxisFigures {
    /// Per-target figures, targets in increasing order.
    pub targets: Vec<TargetFigures>,
    /// Number of cycles `n`.
    pub cycles: usize,
    /// `B = max |B_i|`, reversal value of the axis (≥ 0).
    pub reversal_um: f64,
    /// `B̄ = mean B_i`, mean reversal value (signed).
    pub mean_reversal_um: f64,
    /// `R↑ = max R↑_i`.
    pub r_up_um: f64,
    /// `R↓ = max R↓_i`.
    pub r_down_um: f64,
    /// `R = max R_i`, bidirectional repeatability of the axis.
    pub r_um: f64,
    /// `E↑ = max x̄↑_i − min x̄↑_i`.
    pub e_up_um: f64,
    /// `E↓ = max x̄↓_i − min x̄↓_i`.
    pub e_down_um: f64,
    /// `E = max(x̄↑_i, x̄↓_i) − min(x̄↑_i, x̄↓_i)`.
    pub e_um: f64,
    /// `M = max x̄_i − min x̄_i`.
    pub m_um: f64,
    /// `A↑ = max(x̄↑_i + 2 s↑_i) − min(x̄↑_i − 2 s↑_i)`.
    pub a_up_um: f64,
    /// `A↓ = max(x̄↓_i + 2 s↓_i) − min(x̄↓_i − 2 s↓_i)`.
    pub a_down_um: f64,
    /// `A`, bidirectional accuracy of the axis.
    pub a_um: f64,
}

impl AxisFigures {
    /// Whether the test had at least the standard's 5 cycles. Figures from
    /// fewer cycles are computed the same way but are not ISO 230-2 results.
    pub fn meets_iso_cycle_count(&self) -> bool {
        self.cycles >= ISO_MIN_CYCLES
    }
}

/// Key for grouping targets by exact value; −0.0 is folded into +0.0.
fn target_key(t: f64) -> u64 {
    (t + 0.0).to_bits()
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len() as f64
}

fn sample_std(v: &[f64], m: f64) -> f64 {
    let ss: f64 = v.iter().map(|x| (x - m).powi(2)).sum();
    (ss / (v.len() as f64 - 1.0)).sqrt()
}

fn max_of(it: impl Iterator<Item = f64>) -> f64 {
    it.fold(f64::NEG_INFINITY, f64::max)
}

fn min_of(it: impl Iterator<Item = f64>) -> f64 {
    it.fold(f64::INFINITY, f64::min)
}

/// Per target and approach: cycle → (deviation, observation index).
type Visits = BTreeMap<u32, (f64, usize)>;

/// Evaluates a bidirectional ISO 230-2 test.
///
/// The observations may come in any order. The input is refused (see
/// [`Iso230Error`]) unless every cycle measured every target in both
/// directions exactly once, with at least two cycles and finite numbers.
pub fn evaluate(observations: &[Observation]) -> Result<AxisFigures, Iso230Error> {
    evaluate_with(observations, true)
}

/// The same figures by the same definitions when some visits are missing
/// (left out as outliers, or never measured): each target and approach
/// takes the mean and `s` of the visits it has, which must be at least two.
///
/// Why: a test whose first approach is an outlier of 100 µm has an `R` set
/// by that one visit; the figures without it, stated next to the
/// standard's, tell the reader what the other visits repeat to. They are
/// not the standard's figures (it defines them on complete cycles).
pub fn evaluate_allowing_gaps(observations: &[Observation]) -> Result<AxisFigures, Iso230Error> {
    evaluate_with(observations, false)
}

fn evaluate_with(observations: &[Observation], complete: bool) -> Result<AxisFigures, Iso230Error> {
    if observations.is_empty() {
        return Err(Iso230Error::NoObservations);
    }
    // target key → (target, up visits, down visits)
    let mut groups: BTreeMap<u64, (f64, Visits, Visits)> = BTreeMap::new();
    let mut all_cycles: BTreeSet<u32> = BTreeSet::new();
    for (index, o) in observations.iter().enumerate() {
        if !o.target_um.is_finite() || !o.measured_um.is_finite() {
            return Err(Iso230Error::NonFinite {
                index,
                target_um: o.target_um,
                measured_um: o.measured_um,
            });
        }
        let entry = groups
            .entry(target_key(o.target_um))
            .or_insert_with(|| (o.target_um + 0.0, Visits::new(), Visits::new()));
        let visits = match o.approach {
            Approach::Positive => &mut entry.1,
            Approach::Negative => &mut entry.2,
        };
        if let Some(&(_, first)) = visits.get(&o.cycle) {
            return Err(Iso230Error::Duplicate {
                target_um: o.target_um,
                approach: o.approach,
                cycle: o.cycle,
                first,
                second: index,
            });
        }
        visits.insert(o.cycle, (o.deviation_um(), index));
        all_cycles.insert(o.cycle);
    }

    let mut per_target: Vec<(f64, Vec<f64>, Vec<f64>)> = Vec::with_capacity(groups.len());
    for (target_um, up, down) in groups.into_values() {
        for (approach, visits) in [(Approach::Positive, &up), (Approach::Negative, &down)] {
            if visits.is_empty() {
                return Err(Iso230Error::MissingApproach {
                    target_um,
                    approach,
                });
            }
            if let Some(&cycle) = all_cycles.iter().find(|c| !visits.contains_key(c)) {
                if complete || visits.len() < 2 {
                    return Err(Iso230Error::MissingVisit {
                        target_um,
                        approach,
                        cycle,
                    });
                }
            }
        }
        let up: Vec<f64> = up.values().map(|v| v.0).collect();
        let down: Vec<f64> = down.values().map(|v| v.0).collect();
        per_target.push((target_um, up, down));
    }
    let cycles = all_cycles.len();
    if cycles < 2 {
        return Err(Iso230Error::TooFewCycles { cycles });
    }
    per_target.sort_by(|a, b| a.0.total_cmp(&b.0));

    let targets: Vec<TargetFigures> = per_target
        .iter()
        .map(|(target_um, up, down)| {
            let mean_up_um = mean(up);
            let mean_down_um = mean(down);
            let s_up_um = sample_std(up, mean_up_um);
            let s_down_um = sample_std(down, mean_down_um);
            let reversal_um = mean_up_um - mean_down_um;
            let r_up_um = 4.0 * s_up_um;
            let r_down_um = 4.0 * s_down_um;
            let r_um = (2.0 * s_up_um + 2.0 * s_down_um + reversal_um.abs())
                .max(r_up_um)
                .max(r_down_um);
            TargetFigures {
                target_um: *target_um,
                mean_up_um,
                mean_down_um,
                mean_um: (mean_up_um + mean_down_um) / 2.0,
                s_up_um,
                s_down_um,
                reversal_um,
                r_up_um,
                r_down_um,
                r_um,
            }
        })
        .collect();

    let t = &targets;
    let up_hi = || t.iter().map(|f| f.mean_up_um + 2.0 * f.s_up_um);
    let up_lo = || t.iter().map(|f| f.mean_up_um - 2.0 * f.s_up_um);
    let down_hi = || t.iter().map(|f| f.mean_down_um + 2.0 * f.s_down_um);
    let down_lo = || t.iter().map(|f| f.mean_down_um - 2.0 * f.s_down_um);
    let means_up = || t.iter().map(|f| f.mean_up_um);
    let means_down = || t.iter().map(|f| f.mean_down_um);
    let means = || t.iter().map(|f| f.mean_um);

    Ok(AxisFigures {
        cycles,
        reversal_um: max_of(t.iter().map(|f| f.reversal_um.abs())),
        mean_reversal_um: t.iter().map(|f| f.reversal_um).sum::<f64>() / t.len() as f64,
        r_up_um: max_of(t.iter().map(|f| f.r_up_um)),
        r_down_um: max_of(t.iter().map(|f| f.r_down_um)),
        r_um: max_of(t.iter().map(|f| f.r_um)),
        e_up_um: max_of(means_up()) - min_of(means_up()),
        e_down_um: max_of(means_down()) - min_of(means_down()),
        e_um: max_of(means_up().chain(means_down())) - min_of(means_up().chain(means_down())),
        m_um: max_of(means()) - min_of(means()),
        a_up_um: max_of(up_hi()) - min_of(up_lo()),
        a_down_um: max_of(down_hi()) - min_of(down_lo()),
        a_um: max_of(up_hi().chain(down_hi())) - min_of(up_lo().chain(down_lo())),
        targets,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn obs(target_um: f64, cycle: u32, approach: Approach, dev: f64) -> Observation {
        Observation {
            target_um,
            cycle,
            approach,
            measured_um: target_um + dev,
        }
    }

    fn close(a: f64, b: f64) -> bool {
        (a - b).abs() <= 1e-9
    }

    /// Two targets, three cycles, deviations chosen so every figure is a
    /// small rational or square root that can be checked on paper.
    fn small_case() -> Vec<Observation> {
        use Approach::*;
        let mut v = Vec::new();
        // Target 0: ↑ deviations 1, 2, 3 (mean 2, s = 1); ↓ deviations 0, 0, 0
        // (mean 0, s = 0).
        // Target 100: ↑ deviations −1, −1, −1 (mean −1, s = 0); ↓ deviations
        // 2, 4, 6 (mean 4, s = 2).
        let up0 = [1.0, 2.0, 3.0];
        let down0 = [0.0, 0.0, 0.0];
        let up1 = [-1.0, -1.0, -1.0];
        let down1 = [2.0, 4.0, 6.0];
        for c in 0..3 {
            v.push(obs(0.0, c as u32 + 1, Positive, up0[c]));
            v.push(obs(100.0, c as u32 + 1, Positive, up1[c]));
            v.push(obs(100.0, c as u32 + 1, Negative, down1[c]));
            v.push(obs(0.0, c as u32 + 1, Negative, down0[c]));
        }
        v
    }

    #[test]
    fn every_formula_on_a_hand_computed_case() {
        let f = evaluate(&small_case()).unwrap();
        assert_eq!(f.cycles, 3);
        assert!(!f.meets_iso_cycle_count());
        let [t0, t1] = [&f.targets[0], &f.targets[1]];
        assert_eq!(t0.target_um, 0.0);
        assert_eq!(t1.target_um, 100.0);
        // Target 0: x̄↑ = 2, x̄↓ = 0, x̄ = 1, s↑ = 1, s↓ = 0, B = 2,
        // R↑ = 4, R↓ = 0, R = max(2 + 0 + 2, 4, 0) = 4.
        assert!(close(t0.mean_up_um, 2.0) && close(t0.mean_down_um, 0.0));
        assert!(close(t0.mean_um, 1.0));
        assert!(close(t0.s_up_um, 1.0) && close(t0.s_down_um, 0.0));
        assert!(close(t0.reversal_um, 2.0));
        assert!(close(t0.r_up_um, 4.0) && close(t0.r_down_um, 0.0));
        assert!(close(t0.r_um, 4.0));
        // Target 100: x̄↑ = −1, x̄↓ = 4, x̄ = 1.5, s↑ = 0, s↓ = 2, B = −5,
        // R↑ = 0, R↓ = 8, R = max(0 + 4 + 5, 0, 8) = 9.
        assert!(close(t1.mean_up_um, -1.0) && close(t1.mean_down_um, 4.0));
        assert!(close(t1.mean_um, 1.5));
        assert!(close(t1.s_up_um, 0.0) && close(t1.s_down_um, 2.0));
        assert!(close(t1.reversal_um, -5.0));
        assert!(close(t1.r_up_um, 0.0) && close(t1.r_down_um, 8.0));
        assert!(close(t1.r_um, 9.0));
        // Axis: B = max(|2|, |−5|) = 5; B̄ = (2 − 5)/2 = −1.5;
        // R↑ = 4, R↓ = 8, R = 9.
        assert!(close(f.reversal_um, 5.0));
        assert!(close(f.mean_reversal_um, -1.5));
        assert!(close(f.r_up_um, 4.0) && close(f.r_down_um, 8.0) && close(f.r_um, 9.0));
        // E↑ = 2 − (−1) = 3; E↓ = 4 − 0 = 4; E = max(2, −1, 0, 4) − min(...) = 5;
        // M = 1.5 − 1 = 0.5.
        assert!(close(f.e_up_um, 3.0) && close(f.e_down_um, 4.0) && close(f.e_um, 5.0));
        assert!(close(f.m_um, 0.5));
        // A↑ = max(2 + 2, −1 + 0) − min(2 − 2, −1 − 0) = 4 − (−1) = 5.
        // A↓ = max(0 + 0, 4 + 4) − min(0 − 0, 4 − 4) = 8 − 0 = 8.
        // A = max(4, −1, 0, 8) − min(0, −1, 0, 0) = 8 − (−1) = 9.
        assert!(close(f.a_up_um, 5.0) && close(f.a_down_um, 8.0) && close(f.a_um, 9.0));
    }

    #[test]
    fn order_of_observations_does_not_matter() {
        let mut v = small_case();
        let a = evaluate(&v).unwrap();
        v.reverse();
        let b = evaluate(&v).unwrap();
        assert_eq!(a, b);
    }

    #[test]
    fn negative_zero_target_is_the_same_target() {
        let mut v = small_case();
        for o in v.iter_mut().filter(|o| o.cycle == 2 && o.target_um == 0.0) {
            o.target_um = -0.0;
        }
        let f = evaluate(&v).unwrap();
        assert_eq!(f.targets.len(), 2);
    }

    #[test]
    fn invalid_inputs_are_rejected_with_the_reason() {
        use Approach::*;
        assert_eq!(evaluate(&[]), Err(Iso230Error::NoObservations));

        // One cycle only.
        let one = [obs(0.0, 1, Positive, 0.1), obs(0.0, 1, Negative, 0.2)];
        assert_eq!(evaluate(&one), Err(Iso230Error::TooFewCycles { cycles: 1 }));

        // Missing approach: target 100 never approached negatively.
        let v: Vec<_> = small_case()
            .into_iter()
            .filter(|o| !(o.target_um == 100.0 && o.approach == Negative))
            .collect();
        assert_eq!(
            evaluate(&v),
            Err(Iso230Error::MissingApproach {
                target_um: 100.0,
                approach: Negative
            })
        );

        // Mismatched targets: cycle 2 skips target 0 positively.
        let v: Vec<_> = small_case()
            .into_iter()
            .filter(|o| !(o.target_um == 0.0 && o.approach == Positive && o.cycle == 2))
            .collect();
        assert_eq!(
            evaluate(&v),
            Err(Iso230Error::MissingVisit {
                target_um: 0.0,
                approach: Positive,
                cycle: 2
            })
        );

        // Extra target visited in one cycle only.
        let mut v = small_case();
        v.push(obs(50.0, 1, Positive, 0.0));
        v.push(obs(50.0, 1, Negative, 0.0));
        assert_eq!(
            evaluate(&v),
            Err(Iso230Error::MissingVisit {
                target_um: 50.0,
                approach: Positive,
                cycle: 2
            })
        );

        // Duplicate visit.
        let mut v = small_case();
        v.push(obs(0.0, 3, Negative, 0.0));
        assert!(matches!(
            evaluate(&v),
            Err(Iso230Error::Duplicate {
                cycle: 3,
                approach: Negative,
                second: 12,
                ..
            })
        ));

        // Non-finite values.
        let mut v = small_case();
        v[5].measured_um = f64::NAN;
        assert!(matches!(
            evaluate(&v),
            Err(Iso230Error::NonFinite { index: 5, .. })
        ));
        let mut v = small_case();
        v[0].target_um = f64::INFINITY;
        assert!(matches!(
            evaluate(&v),
            Err(Iso230Error::NonFinite { index: 0, .. })
        ));
    }
}
