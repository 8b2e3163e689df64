//! Property tests of the metrology invariants (fixed seed, no failure
//! persistence, so every run checks the same cases).

use micropos::metrology::iso230_2::{evaluate, Approach, Observation};
use micropos::metrology::iso9283::{pose_stats, Xy};
use proptest::prelude::*;

fn config() -> ProptestConfig {
    ProptestConfig {
        cases: 256,
        failure_persistence: None,
        rng_algorithm: proptest::test_runner::RngAlgorithm::ChaCha,
        rng_seed: proptest::test_runner::RngSeed::Fixed(0x6d65_7472_6f6c_6f67),
        ..ProptestConfig::default()
    }
}

fn xy() -> impl Strategy<Value = Xy> {
    (-1.0e4..1.0e4f64, -1.0e4..1.0e4f64).prop_map(|(x, y)| Xy::new(x, y))
}

fn close(a: f64, b: f64, scale: f64) -> bool {
    (a - b).abs() <= 1e-9 * scale.max(1.0)
}

proptest! {
    #![proptest_config(config())]

    /// AP depends only on target − barycentre: moving target and visits by the
    /// same vector keeps it. RP does not look at the target at all: moving
    /// only the visits keeps it. Both are ≥ 0, and rotating everything about
    /// the origin keeps both (they are distances).
    #[test]
    fn iso9283_invariances(
        target in xy(),
        visits in prop::collection::vec(xy(), 1..12),
        shift in xy(),
        other_target in xy(),
        angle_rad in -3.2..3.2f64,
    ) {
        let s = pose_stats(target, &visits).unwrap();
        prop_assert!(s.ap_um >= 0.0);
        prop_assert!(s.l_mean_um >= 0.0);
        if let Some(rp) = s.rp_um {
            prop_assert!(rp >= 0.0);
            prop_assert!(rp >= s.l_mean_um);
        }
        prop_assert_eq!(s.rp_um.is_some(), visits.len() >= 2);

        let mv = |p: Xy| Xy::new(p.x_um + shift.x_um, p.y_um + shift.y_um);
        let moved: Vec<Xy> = visits.iter().copied().map(mv).collect();
        let both = pose_stats(mv(target), &moved).unwrap();
        prop_assert!(close(both.ap_um, s.ap_um, 1e5));
        prop_assert!(close(both.apx_um, s.apx_um, 1e5));
        prop_assert!(close(both.apy_um, s.apy_um, 1e5));

        let visits_only = pose_stats(other_target, &moved).unwrap();
        match (visits_only.rp_um, s.rp_um) {
            (Some(a), Some(b)) => prop_assert!(close(a, b, 1e5)),
            (None, None) => {}
            _ => prop_assert!(false, "RP presence changed"),
        }

        let (sn, cs) = angle_rad.sin_cos();
        let rot = |p: Xy| Xy::new(cs * p.x_um - sn * p.y_um, sn * p.x_um + cs * p.y_um);
        let rotated: Vec<Xy> = visits.iter().copied().map(rot).collect();
        let r = pose_stats(rot(target), &rotated).unwrap();
        prop_assert!(close(r.ap_um, s.ap_um, 1e5));
        if let (Some(a), Some(b)) = (r.rp_um, s.rp_um) {
            prop_assert!(close(a, b, 1e5));
        }
    }
}

/// A complete bidirectional test: `targets` × `cycles` × 2 deviations.
fn iso230_case() -> impl Strategy<Value = (Vec<f64>, usize, Vec<f64>)> {
    (1usize..6, 2usize..6).prop_flat_map(|(m, n)| {
        (
            prop::collection::btree_set(-50_000i32..50_000, m).prop_map(|s| {
                s.into_iter()
                    .map(|t| f64::from(t) * 0.5)
                    .collect::<Vec<_>>()
            }),
            Just(n),
            prop::collection::vec(-20.0..20.0f64, m * n * 2),
        )
    })
}

fn build(
    targets: &[f64],
    cycles: usize,
    devs: &[f64],
    offset_um: f64,
    shift_um: f64,
) -> Vec<Observation> {
    let mut v = Vec::new();
    let mut k = 0;
    for c in 0..cycles {
        for approach in [Approach::Positive, Approach::Negative] {
            for &t in targets {
                v.push(Observation {
                    target_um: t + shift_um,
                    cycle: c as u32,
                    approach,
                    measured_um: t + shift_um + devs[k] + offset_um,
                });
                k += 1;
            }
        }
    }
    v
}

proptest! {
    #![proptest_config(config())]

    /// Orderings that follow from the definitions: A ≥ E ≥ max(E↑, E↓),
    /// E ≥ M, A ≥ max(A↑, A↓), R ≥ max(R↑, R↓), R_i ≥ |B_i|, B ≥ |B̄|, all
    /// ranges ≥ 0; a constant offset on every deviation changes none of the
    /// axis figures except the means; moving the whole test along the axis
    /// changes nothing.
    #[test]
    fn iso230_invariants((targets, cycles, devs) in iso230_case(), offset in -100.0..100.0f64, shift in -1.0e4..1.0e4f64) {
        let f = evaluate(&build(&targets, cycles, &devs, 0.0, 0.0)).unwrap();
        let eps = 1e-9;
        prop_assert_eq!(f.cycles, cycles);
        prop_assert_eq!(f.targets.len(), targets.len());
        prop_assert!(f.a_um + eps >= f.e_um);
        prop_assert!(f.e_um + eps >= f.e_up_um.max(f.e_down_um));
        prop_assert!(f.e_um + eps >= f.m_um);
        prop_assert!(f.a_um + eps >= f.a_up_um.max(f.a_down_um));
        prop_assert!(f.a_up_um + eps >= f.e_up_um);
        prop_assert!(f.a_down_um + eps >= f.e_down_um);
        prop_assert!(f.r_um + eps >= f.r_up_um.max(f.r_down_um));
        prop_assert!(f.r_um + eps >= f.reversal_um);
        prop_assert!(f.reversal_um + eps >= f.mean_reversal_um.abs());
        for t in &f.targets {
            prop_assert!(t.r_um + eps >= t.reversal_um.abs());
            prop_assert!(t.s_up_um >= 0.0 && t.s_down_um >= 0.0);
        }
        for x in [f.m_um, f.e_um, f.e_up_um, f.e_down_um, f.r_um, f.reversal_um, f.a_um] {
            prop_assert!(x >= 0.0);
        }

        let g = evaluate(&build(&targets, cycles, &devs, offset, 0.0)).unwrap();
        let h = evaluate(&build(&targets, cycles, &devs, 0.0, shift)).unwrap();
        for other in [&g, &h] {
            for (a, b) in [
                (f.a_um, other.a_um), (f.a_up_um, other.a_up_um), (f.a_down_um, other.a_down_um),
                (f.e_um, other.e_um), (f.e_up_um, other.e_up_um), (f.e_down_um, other.e_down_um),
                (f.m_um, other.m_um), (f.r_um, other.r_um), (f.r_up_um, other.r_up_um),
                (f.r_down_um, other.r_down_um), (f.reversal_um, other.reversal_um),
                (f.mean_reversal_um, other.mean_reversal_um),
            ] {
                // Tolerance: rounding of deviations at |target| ≤ 3.5e4 µm.
                prop_assert!((a - b).abs() <= 1e-7, "{} vs {}", a, b);
            }
        }
        for (a, b) in f.targets.iter().zip(&g.targets) {
            prop_assert!((b.mean_um - a.mean_um - offset).abs() <= 1e-7);
        }
    }
}
