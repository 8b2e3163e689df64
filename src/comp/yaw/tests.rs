use super::*;
use crate::charact::scan::{SEGMENT_SCAN_X, SEGMENT_SCAN_Y};
use proptest::prelude::*;

fn rec(seg: &str, x: f64, y: f64, theta_urad: Option<f64>) -> Record {
    Record {
        t_s: 0.0,
        segment: seg.into(),
        cycle: 1,
        x_target_um: x,
        y_target_um: y,
        x_cmd_um: x,
        y_cmd_um: y,
        x_meas_um: x,
        y_meas_um: y,
        temp_c: None,
        theta_urad,
        extra: vec![],
    }
}

/// A stage's yaw as the sum of its carriages': per axis a slope (µrad per
/// mm), a period's sine (µrad, µm) and a hysteresis between directions
/// (µrad, added backward).
#[derive(Clone, Copy)]
struct AxisYaw {
    slope_urad_per_mm: f64,
    amp_urad: f64,
    period_um: f64,
    hyst_urad: f64,
}

impl AxisYaw {
    fn at(&self, p_um: f64, d: Direction) -> f64 {
        let h = if d == Direction::Backward {
            self.hyst_urad
        } else {
            0.0
        };
        self.slope_urad_per_mm * p_um * 1e-3
            + self.amp_urad * (std::f64::consts::TAU * p_um / self.period_um).sin()
            + h
    }
}

/// A scan log: the X scan at `y = 1000`, the Y scan at `x = 500`, both
/// 0 … 2000 µm by 100 µm, `cycles` forward-and-back passes; `noise(i)` is
/// added to record `i`'s θ; a constant 40 µrad stands for the yaw at the
/// tie's anchor that `theta_urad` is relative to.
fn log(yx: AxisYaw, yy: AxisYaw, cycles: usize, noise: impl Fn(usize) -> f64) -> Vec<Record> {
    let pass: Vec<f64> = (0..=20).map(|i| 100.0 * f64::from(i)).collect();
    let mut out = Vec::new();
    let mut i = 0;
    for (seg, hold) in [(SEGMENT_SCAN_X, 1000.0), (SEGMENT_SCAN_Y, 500.0)] {
        for _ in 0..cycles {
            for (dir, order) in [
                (Direction::Forward, pass.clone()),
                (Direction::Backward, pass.iter().rev().copied().collect()),
            ] {
                for p in order {
                    let (x, y, dx, dy) = if seg == SEGMENT_SCAN_X {
                        (p, hold, dir, Direction::Forward)
                    } else {
                        (hold, p, Direction::Forward, dir)
                    };
                    let th = yx.at(x, dx) + yy.at(y, dy) - 40.0 + noise(i);
                    out.push(rec(seg, x, y, Some(th)));
                    i += 1;
                }
            }
        }
    }
    out
}

const FLAT: AxisYaw = AxisYaw {
    slope_urad_per_mm: 0.0,
    amp_urad: 0.0,
    period_um: 1000.0,
    hyst_urad: 0.0,
};

/// A known slope and period on either axis, both signs: the sum of the
/// tables is the stage's yaw (less the constant at the tie) at every
/// table point, either direction.
#[test]
fn a_known_slope_and_period_are_recovered_with_either_sign() {
    for sign in [1.0, -1.0] {
        let yx = AxisYaw {
            slope_urad_per_mm: 30.0 * sign,
            amp_urad: 12.0 * sign,
            period_um: 800.0,
            hyst_urad: 5.0,
        };
        let yy = AxisYaw {
            slope_urad_per_mm: -20.0 * sign,
            amp_urad: 7.0,
            period_um: 1300.0,
            hyst_urad: -3.0,
        };
        let recs = log(yx, yy, 2, |_| 0.0);
        let (t, report) = YawTables::from_records(&recs, &TableBuildOptions::default())
            .unwrap()
            .unwrap();
        assert_eq!(report.x_points, [21, 21]);
        assert_eq!(report.y_points, [21, 21]);
        assert_eq!(report.repeat_rms_urad, Some(0.0));
        use Direction::*;
        for x in [0.0, 300.0, 1700.0, 2000.0] {
            for y in [0.0, 1000.0, 1400.0] {
                for d in [
                    [Forward, Forward],
                    [Backward, Forward],
                    [Forward, Backward],
                    [Backward, Backward],
                ] {
                    let want = yx.at(x, d[0]) + yy.at(y, d[1]) - 40.0;
                    let got = t.yaw_urad(x, y, d);
                    assert!(
                        (got - want).abs() < 1e-9,
                        "{sign} {x} {y} {d:?}: {got} vs {want}"
                    );
                }
            }
        }
        // The sign survives: +x end against −x end.
        let slope =
            t.yaw_urad(2000.0, 1000.0, [Forward; 2]) - t.yaw_urad(0.0, 1000.0, [Forward; 2]);
        assert!(slope * sign > 50.0, "{slope}");
    }
}

/// θ noise of 5 µrad rms on 8 visits per point: the tables recover the
/// yaw within 3σ of the mean of the visits, and the report's repeat rms
/// is the noise.
#[test]
fn noise_averages_out_and_is_reported() {
    let yx = AxisYaw {
        slope_urad_per_mm: 25.0,
        amp_urad: 10.0,
        period_um: 700.0,
        hyst_urad: 0.0,
    };
    // A deterministic uniform noise of rms 5 µrad (±√3·5).
    let noise = |i: usize| {
        let u =
            ((i as u64).wrapping_mul(6_364_136_223_846_793_005) >> 11) as f64 / (1u64 << 53) as f64;
        (2.0 * u - 1.0) * 5.0 * 3f64.sqrt()
    };
    let recs = log(yx, FLAT, 8, noise);
    let (t, report) = YawTables::from_records(&recs, &TableBuildOptions::default())
        .unwrap()
        .unwrap();
    let rms = report.repeat_rms_urad.unwrap();
    assert!((3.5..6.5).contains(&rms), "{rms}");
    // At y_hold the y table is 0 by its reference: the x table's mean of
    // 8 visits alone, σ = 5/√8.
    let bound = 3.0 * 5.0 / 8f64.sqrt();
    for x in (0..=20).map(|i| 100.0 * f64::from(i)) {
        let want = yx.at(x, Direction::Forward) - 40.0;
        let got = t.yaw_urad(x, 1000.0, [Direction::Forward; 2]);
        assert!((got - want).abs() < bound, "{x}: {got} vs {want}");
    }
}

/// A log without θ builds no yaw table; one with θ on only part of a scan
/// says which segment lacks it.
#[test]
fn no_theta_no_yaw_table() {
    let mut recs = log(FLAT, FLAT, 1, |_| 0.0);
    for r in &mut recs {
        r.theta_urad = None;
    }
    assert!(
        YawTables::from_records(&recs, &TableBuildOptions::default())
            .unwrap()
            .is_none()
    );
    for r in recs.iter_mut().filter(|r| r.segment == SEGMENT_SCAN_X) {
        r.theta_urad = Some(1.0);
    }
    let e = YawTables::from_records(&recs, &TableBuildOptions::default()).unwrap_err();
    assert!(e.to_string().contains(SEGMENT_SCAN_Y), "{e}");
}

#[test]
fn a_defective_table_names_its_key() {
    let recs = log(FLAT, FLAT, 1, |_| 0.0);
    let (mut t, _) = YawTables::from_records(&recs, &TableBuildOptions::default())
        .unwrap()
        .unwrap();
    t.y_scan.backward.yaw_urad[3] = f64::NAN;
    let e = t.validate().unwrap_err().to_string();
    assert!(e.contains("yaw.y_scan.backward.yaw_urad[3]"), "{e}");
}

#[test]
fn a_90_degree_yaw_turns_the_arm() {
    let t = tool_from_pattern_um([1.0, 2.0], std::f64::consts::FRAC_PI_2 * 1e6, [10.0, 0.0]);
    assert!(
        (t[0] - 1.0).abs() < 1e-9 && (t[1] - 12.0).abs() < 1e-9,
        "{t:?}"
    );
}

proptest! {
    /// The tool ↔ pattern transform is invertible and keeps the arm's
    /// length.
    #[test]
    fn tool_and_pattern_are_inverse(
        px in -1e5f64..1e5, py in -1e5f64..1e5,
        ox in -5e4f64..5e4, oy in -5e4f64..5e4,
        yaw in -1e4f64..1e4,
    ) {
        let t = tool_from_pattern_um([px, py], yaw, [ox, oy]);
        let p = pattern_for_tool_um(t, yaw, [ox, oy]);
        prop_assert!((p[0] - px).abs() < 1e-6 && (p[1] - py).abs() < 1e-6);
        let arm = (t[0] - px).hypot(t[1] - py);
        prop_assert!((arm - ox.hypot(oy)).abs() < 1e-6);
    }
}

/// A file with yaw tables round-trips; the section is optional.
#[test]
fn yaw_tables_ride_in_a_compensation_file() {
    let recs = log(FLAT, FLAT, 1, |i| i as f64 * 0.1);
    let (t, _) = YawTables::from_records(&recs, &TableBuildOptions::default())
        .unwrap()
        .unwrap();
    let m = crate::model::StageModel::paper_default().unwrap();
    let mut f = crate::comp::CompFile::model(&m, "t", crate::comp::SourceInfo::default()).unwrap();
    let without = crate::comp::CompFile::from_toml(&f.to_toml().unwrap()).unwrap();
    assert_eq!(without.yaw, None);
    f.yaw = Some(t);
    let back = crate::comp::CompFile::from_toml(&f.to_toml().unwrap()).unwrap();
    assert_eq!(back, f);
}
