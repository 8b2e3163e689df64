//! ISO 230-2 figures of a real bidirectional axis test, checked against an
//! independent computation.
//!
//! Data: `tests/data/iso230-2/encoder-vs-setpoint.csv` (5 targets, 5 cycles,
//! forward = positive approach, units mm; see the README next to it). The
//! published report computed from this data is known to be wrong, so the
//! expected values below were produced by
//! `tests/data/iso230-2/reference_iso230_2.py`, which applies the
//! ISO 230-2:2014 definitions with exact 50-digit decimal arithmetic (Python
//! stdlib `decimal`, sharing no code with the crate), and pasted here. The
//! per-target means were also checked by hand: at −10 mm the forward
//! deviations are −0.099019, −0.094019, −0.082019, −0.091019, −0.094019 µm,
//! whose sum −0.460095 µm gives x̄↑ = −0.092019 µm.

use micropos::metrology::iso230_2::{evaluate, Approach, Observation};

const CSV: &str = include_str!("../data/iso230-2/encoder-vs-setpoint.csv");

fn observations() -> Vec<Observation> {
    CSV.lines()
        .skip(1)
        .filter(|l| !l.trim().is_empty())
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            assert_eq!(f.len(), 4, "bad line {l:?}");
            let approach = match f[1] {
                "forward" => Approach::Positive,
                "backward" => Approach::Negative,
                other => panic!("unknown direction {other:?}"),
            };
            Observation {
                cycle: f[0].parse().unwrap(),
                approach,
                // mm → µm
                target_um: f[2].parse::<f64>().unwrap() * 1000.0,
                measured_um: f[3].parse::<f64>().unwrap() * 1000.0,
            }
        })
        .collect()
}

/// 1e-9 µm: far below the data's 1e-7 µm resolution, far above f64 rounding
/// at 1e4 µm magnitudes (~2e-12 µm).
const TOL_UM: f64 = 1e-9;

fn assert_close(what: &str, got: f64, want: f64) {
    assert!(
        (got - want).abs() <= TOL_UM,
        "{what}: got {got:.12} µm, want {want:.12} µm"
    );
}

#[test]
fn axis_figures_match_independent_computation() {
    let obs = observations();
    assert_eq!(obs.len(), 50);
    let f = evaluate(&obs).unwrap();
    assert_eq!(f.cycles, 5);
    assert!(f.meets_iso_cycle_count());
    assert_eq!(f.targets.len(), 5);

    // Output of reference_iso230_2.py (µm).
    assert_close("B", f.reversal_um, 0.012200000000);
    assert_close("B̄", f.mean_reversal_um, -0.005400000000);
    assert_close("R↑", f.r_up_um, 0.062903100083);
    assert_close("R↓", f.r_down_um, 0.050326931160);
    assert_close("R", f.r_um, 0.068815015621);
    assert_close("E↑", f.e_up_um, 0.033000000000);
    assert_close("E↓", f.e_down_um, 0.024600000000);
    assert_close("E", f.e_um, 0.036800000000);
    assert_close("M", f.m_um, 0.027700000000);
    assert_close("A↑", f.a_up_um, 0.088807247527);
    assert_close("A↓", f.a_down_um, 0.064282418710);
    assert_close("A", f.a_um, 0.088807247527);
}

#[test]
fn per_target_figures_match_independent_computation() {
    let f = evaluate(&observations()).unwrap();
    // (target mm, x̄↑, x̄↓, s↑, s↓, B_i, R_i, x̄_i), µm, from reference_iso230_2.py.
    let want = [
        (
            -10.0,
            -0.0920190000,
            -0.0924190000,
            0.006284902545,
            0.008792041856,
            0.0004000000,
            0.035168167425,
            -0.0922190000,
        ),
        (
            -4.88,
            -0.1012190000,
            -0.0916190000,
            0.007293833012,
            0.006767569726,
            -0.0096000000,
            0.037722805476,
            -0.0964190000,
        ),
        (
            0.24,
            -0.0908190000,
            -0.0848190000,
            0.010425929215,
            0.007259476565,
            -0.0060000000,
            0.041703716861,
            -0.0878190000,
        ),
        (
            5.36,
            -0.0886190000,
            -0.0890190000,
            0.012177848743,
            0.009000000000,
            0.0004000000,
            0.048711394971,
            -0.0888190000,
        ),
        (
            10.48,
            -0.1216190000,
            -0.1094190000,
            0.015725775021,
            0.012581732790,
            -0.0122000000,
            0.068815015621,
            -0.1155190000,
        ),
    ];
    for (t, w) in f.targets.iter().zip(want) {
        assert!((t.target_um - w.0 * 1000.0).abs() < 1e-9);
        assert_close("x̄↑", t.mean_up_um, w.1);
        assert_close("x̄↓", t.mean_down_um, w.2);
        assert_close("s↑", t.s_up_um, w.3);
        assert_close("s↓", t.s_down_um, w.4);
        assert_close("B_i", t.reversal_um, w.5);
        assert_close("R_i", t.r_um, w.6);
        assert_close("x̄_i", t.mean_um, w.7);
        assert_close("R↑_i", t.r_up_um, 4.0 * w.3);
        assert_close("R↓_i", t.r_down_um, 4.0 * w.4);
    }
}

#[test]
fn dropping_a_cycle_of_one_target_is_refused() {
    let obs: Vec<_> = observations()
        .into_iter()
        .filter(|o| !(o.cycle == 4 && o.approach == Approach::Negative && o.target_um > 10_000.0))
        .collect();
    let err = evaluate(&obs).unwrap_err();
    let msg = err.to_string();
    assert!(msg.contains("cycle 4") && msg.contains("10480"), "{msg}");
}
