//! The vision→stage frame from the scans: rotation, mirror and offset are
//! recovered, the stage's scale error and squareness are NOT fitted away.

use micropos::charact::scan::CharacterizationPlan;
use micropos::comp::{estimate_vision_frame, FrameSample, VisionFrame};
use micropos::model::{MotionState, StageModel, StageSimulator, XyUm};

fn scans() -> (Vec<FrameSample>, Vec<FrameSample>) {
    let mut sim = StageSimulator::new(
        StageModel::paper_default().unwrap(),
        MotionState::at_rest(7500.0, 7500.0),
        8,
    )
    .unwrap();
    let (mut x, mut y) = (Vec::new(), Vec::new());
    for (i, p) in CharacterizationPlan::short()
        .points()
        .unwrap()
        .into_iter()
        .enumerate()
    {
        let s = sim
            .move_to(p.target.x_um, p.target.y_um, i as f64, p.cycle)
            .unwrap();
        if p.logged {
            let fs = FrameSample {
                cmd: p.target,
                vision: s.observed_um,
            };
            if p.segment == "scan_x" {
                x.push(fs);
            } else {
                y.push(fs);
            }
        }
    }
    (x, y)
}

#[test]
fn mounting_transform_is_recovered_and_stage_errors_are_kept() {
    let (x, y) = scans();
    // Reference: the scans seen in the stage frame itself.
    let (f0, r0) = estimate_vision_frame(&x, &y).unwrap();
    println!("stage frame: {f0:?} {r0:?}");
    assert!(!f0.mirrored);
    assert!(f0.rotation_rad.abs() < 20e-6, "{f0:?}");
    // The default model: 5300 µrad squareness (+ a little from the Y yaw);
    // lead + Abbe slopes make the X scale differ from 0 by ≥ 50 ppm.
    assert!((r0.squareness_urad - 5300.0).abs() < 300.0, "{r0:?}");
    assert!(r0.x_scale_ppm.abs() > 50.0, "{r0:?}");

    for mirrored in [false, true] {
        let mount = VisionFrame {
            rotation_rad: -0.0123,
            mirrored,
            translation_um: [-512.0, 2048.0],
        };
        let to_cam = |v: &[FrameSample]| -> Vec<FrameSample> {
            v.iter()
                .map(|s| FrameSample {
                    cmd: s.cmd,
                    vision: mount.to_vision(s.vision),
                })
                .collect()
        };
        let (f, r) = estimate_vision_frame(&to_cam(&x), &to_cam(&y)).unwrap();
        println!("mounted (mirrored {mirrored}): {f:?}");
        assert_eq!(f.mirrored, mirrored);
        // Same stage frame as the reference, to rounding.
        for s in x.iter().chain(&y) {
            let a = f.to_stage(mount.to_vision(s.vision));
            let b = f0.to_stage(s.vision);
            assert!((a.x_um - b.x_um).abs() < 1e-6 && (a.y_um - b.y_um).abs() < 1e-6);
        }
        assert!((r.x_scale_ppm - r0.x_scale_ppm).abs() < 1e-3);
        assert!((r.y_scale_ppm - r0.y_scale_ppm).abs() < 1e-3);
        assert!((r.squareness_urad - r0.squareness_urad).abs() < 1e-3);
    }
}

#[test]
fn wrong_scale_or_degenerate_scans_are_refused() {
    let (x, y) = scans();
    let scale = |v: &[FrameSample], k: f64| -> Vec<FrameSample> {
        v.iter()
            .map(|s| FrameSample {
                cmd: s.cmd,
                vision: XyUm {
                    x_um: s.vision.x_um * k,
                    y_um: s.vision.y_um * k,
                },
            })
            .collect()
    };
    let e = estimate_vision_frame(&scale(&x, 1.5), &scale(&y, 1.5)).unwrap_err();
    assert!(e.to_string().contains("pattern period"), "{e}");
    let e = estimate_vision_frame(&x, &x).unwrap_err();
    assert!(
        e.to_string().contains("does not move") || e.to_string().contains("apart"),
        "{e}"
    );
    assert!(estimate_vision_frame(&x[..1], &y).is_err());
}
