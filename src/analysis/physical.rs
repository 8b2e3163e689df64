//! Characterization logs of a stage built from its physical description,
//! not from [`crate::model::StageModel`]: the second test bench of the
//! discrepancy analysis.
//!
//! Why apart from the model: a test whose log comes from the model's own
//! terms shares every assumption of the analysis (the same play operator,
//! the same harmonic series, the same Gaussian bump). Here each error is
//! made the way the mechanism makes it, in code that does not call the
//! model:
//! * a **screw** whose nut sits at `cmd·(1 + ε) + Σ a_k·sin(2πk·cmd/P + φ_k)`
//!   along it, with the harmonic amplitudes and phases of the flank in
//!   contact (the forward flank when the nut pushes the carriage forward);
//! * a **nut with play** `B`: a hysteresis state machine — the carriage
//!   moves only when the nut's flank reaches it, and stays where it was
//!   left otherwise;
//! * **guideway angles** (yaw and pitch of each carriage: a slope plus a
//!   waviness) acting through the tool point's Abbe arms;
//! * a **squareness** angle between the axes (the y carriage leans towards
//!   +x, so the x reading gains `angle·y`);
//! * **thermal** expansion of the screws and a thermal offset of the
//!   platform, under a room temperature that wanders;
//! * a slow **drift** of the x reading with time;
//! * settling scatter per move and camera noise per reading.
//!
//! Optional hidden effects ([`PhysicalEffect`]) add structure the stage
//! model lacks: a dent in a guideway (a raised-cosine profile, not a
//! Gaussian), a bearing's periodic error, elastic wind-up of the drive
//! (lost motion growing with the move's length), a periodic air-conditioning
//! cycle, a drift of the y reading.
//!
//! The plan is the one of [`super::generate::SimPlan`] (per cycle an x scan
//! forward and back, a y scan forward and back, random points), walked by
//! this file's own loop; the output is the same measurement-log format
//! ([`SimLog`]).

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use serde::Serialize;

use crate::charact::log::{Columns, Metadata, Record};
use crate::model::Axis;

use super::generate::{SimLog, SimPlan};
use super::AnalysisError;

/// One harmonic of a screw's periodic lead error: amplitude and phase.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Harmonic {
    /// Amplitude, µm.
    pub amplitude_um: f64,
    /// Phase, rad.
    pub phase_rad: f64,
}

/// A guideway angle along its axis: `slope·p + amplitude·sin(2πp/P + φ)`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct GuideAngle {
    /// Linear trend, µrad per mm of travel.
    pub slope_urad_per_mm: f64,
    /// Waviness amplitude, µrad.
    pub amplitude_urad: f64,
    /// Waviness period, µm of travel.
    pub period_um: f64,
    /// Waviness phase, rad.
    pub phase_rad: f64,
}

impl GuideAngle {
    fn at_urad(&self, p_um: f64) -> f64 {
        self.slope_urad_per_mm * p_um / 1000.0
            + self.amplitude_urad
                * (std::f64::consts::TAU * p_um / self.period_um + self.phase_rad).sin()
    }
}

/// One axis's drive and guide.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PhysicalAxis {
    /// Screw lead (pitch), µm: the period of the cyclic error.
    pub lead_um: f64,
    /// Cumulative lead error, ppm (> 0: the nut goes further than
    /// commanded).
    pub scale_ppm: f64,
    /// Periodic lead error of the forward flank, harmonics 1, 2, …
    pub forward: Vec<Harmonic>,
    /// ... of the backward flank.
    pub backward: Vec<Harmonic>,
    /// Play between nut and carriage, µm (≥ 0).
    pub play_um: f64,
    /// Yaw of the carriage (about z).
    pub yaw: GuideAngle,
    /// Pitch of the carriage (about the other horizontal axis).
    pub pitch: GuideAngle,
    /// Thermal expansion of the screw, ppm per °C.
    pub expansion_ppm_per_c: f64,
}

/// Structure a stage may have that the default stage model lacks.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub enum PhysicalEffect {
    /// A dent (or bump) in the guideway of `axis`, moving `component`:
    /// `depth·(1 + cos(π(p − p0)/h))/2` for `|p − p0| < h`.
    Dent {
        /// Axis whose position it depends on.
        axis: Axis,
        /// Component it moves.
        component: Axis,
        /// Centre `p0`, µm.
        position_um: f64,
        /// Half width `h`, µm.
        half_width_um: f64,
        /// Peak displacement, µm (signed).
        depth_um: f64,
    },
    /// A bearing's (or gear's) periodic error at a period the screw does
    /// not have.
    Bearing {
        /// Axis whose position it depends on.
        axis: Axis,
        /// Component it moves.
        component: Axis,
        /// Period, µm of travel.
        period_um: f64,
        /// Amplitude, µm.
        amplitude_um: f64,
        /// Phase, rad.
        phase_rad: f64,
    },
    /// Elastic wind-up of the drive of `axis`: after a move of length `L`
    /// the carriage lags `A·(1 − exp(−L/λ))` behind it.
    WindUp {
        /// The axis.
        axis: Axis,
        /// `A`, µm.
        amplitude_um: f64,
        /// `λ`, µm of move.
        length_um: f64,
    },
    /// A periodic disturbance in time (air-conditioning cycle).
    AirCycle {
        /// Component it moves.
        component: Axis,
        /// Period, s.
        period_s: f64,
        /// Amplitude, µm.
        amplitude_um: f64,
        /// Phase, rad.
        phase_rad: f64,
    },
    /// A drift of the y reading with time, µm/h.
    DriftY {
        /// Rate, µm/h.
        rate_um_per_h: f64,
    },
}

/// A whole XY stage from its physical description.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PhysicalStage {
    /// The x axis (lower carriage).
    pub x: PhysicalAxis,
    /// The y axis (upper carriage).
    pub y: PhysicalAxis,
    /// Squareness, µrad: the y carriage leans towards +x.
    pub squareness_urad: f64,
    /// Tool point's Abbe arms: beside the x drive line (y), beside the y
    /// drive line (x), above both (z), µm.
    pub arm_um: [f64; 3],
    /// Thermal offset of the platform per °C, `[x, y]` µm/°C.
    pub thermal_offset_um_per_c: [f64; 2],
    /// Drift of the x reading with time, µm/h.
    pub drift_x_um_per_h: f64,
    /// Settling scatter per completed move, σ µm.
    pub settling_sigma_um: f64,
    /// Hidden effects.
    pub effects: Vec<PhysicalEffect>,
}

fn uniform(rng: &mut ChaCha8Rng, lo: f64, hi: f64) -> f64 {
    lo + (hi - lo) * rng.gen::<f64>()
}

fn harmonics(rng: &mut ChaCha8Rng, a1: f64) -> Vec<Harmonic> {
    vec![
        Harmonic {
            amplitude_um: a1,
            phase_rad: uniform(rng, 0.0, std::f64::consts::TAU),
        },
        Harmonic {
            amplitude_um: a1 * uniform(rng, 0.0, 0.3),
            phase_rad: uniform(rng, 0.0, std::f64::consts::TAU),
        },
    ]
}

impl PhysicalAxis {
    /// A leadscrew axis drawn from `rng`: 400 µm lead, scale ±300 ppm,
    /// cyclic amplitude 0.3–4 µm (second harmonic up to 30 % of it), the
    /// backward flank within ±25 % and ±0.5 rad of the forward one, play
    /// 0.3–5 µm, guide slopes ±10 µrad/mm with a 5 mm waviness up to
    /// ±30 µrad.
    pub fn random(rng: &mut ChaCha8Rng) -> Self {
        let a1 = uniform(rng, 0.3, 4.0);
        let forward = harmonics(rng, a1);
        let backward = forward
            .iter()
            .map(|h| Harmonic {
                amplitude_um: h.amplitude_um * uniform(rng, 0.75, 1.25),
                phase_rad: h.phase_rad + uniform(rng, -0.5, 0.5),
            })
            .collect();
        let angle = |rng: &mut ChaCha8Rng| GuideAngle {
            slope_urad_per_mm: uniform(rng, -10.0, 10.0),
            amplitude_urad: uniform(rng, -30.0, 30.0),
            period_um: 5000.0,
            phase_rad: uniform(rng, 0.0, std::f64::consts::TAU),
        };
        let yaw = angle(rng);
        let pitch = angle(rng);
        PhysicalAxis {
            lead_um: 400.0,
            scale_ppm: uniform(rng, -300.0, 300.0),
            forward,
            backward,
            play_um: uniform(rng, 0.3, 5.0),
            yaw,
            pitch,
            expansion_ppm_per_c: uniform(rng, -12.0, 12.0),
        }
    }

    /// Nut position along the screw for commanded `cmd`, µm, with the
    /// flank in contact (`forward`) and the screw's temperature excess.
    fn nut_um(&self, cmd_um: f64, forward: bool, dt_c: f64) -> f64 {
        let flank = if forward {
            &self.forward
        } else {
            &self.backward
        };
        let periodic: f64 = flank
            .iter()
            .enumerate()
            .map(|(k, h)| {
                h.amplitude_um
                    * (std::f64::consts::TAU * (k + 1) as f64 * cmd_um / self.lead_um + h.phase_rad)
                        .sin()
            })
            .sum();
        cmd_um * (1.0 + 1e-6 * (self.scale_ppm + self.expansion_ppm_per_c * dt_c)) + periodic
    }
}

impl PhysicalStage {
    /// A stage drawn from `seed` with every family at random (both signs,
    /// ranges wider than the paper's: squareness ±10 mrad, scale ±300 ppm,
    /// play 0.3–5 µm, cyclic 0.3–4 µm, drift 0–0.3 µm/h) and no hidden
    /// effect.
    pub fn random(seed: u64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x9a75_1ca1_0000_0005);
        let x = PhysicalAxis::random(&mut rng);
        let y = PhysicalAxis::random(&mut rng);
        let drift = uniform(&mut rng, 0.0, 0.3) * if rng.gen::<bool>() { 1.0 } else { -1.0 };
        PhysicalStage {
            x,
            y,
            squareness_urad: uniform(&mut rng, -10_000.0, 10_000.0),
            arm_um: [10_000.0, 8_000.0, 25_000.0],
            thermal_offset_um_per_c: [uniform(&mut rng, -0.5, 0.5), uniform(&mut rng, -0.5, 0.5)],
            drift_x_um_per_h: drift,
            settling_sigma_um: 0.035,
            effects: Vec::new(),
        }
    }
}

/// The carriage of one axis: where it is, where its nut was commanded
/// last, and the last move.
#[derive(Debug, Clone, Copy)]
struct Carriage {
    cmd_um: f64,
    pos_um: f64,
    /// +1 after a forward move, −1 after a backward one.
    dir: f64,
    last_move_um: f64,
}

impl Carriage {
    fn start(axis: &PhysicalAxis, cmd_um: f64, dt_c: f64) -> Self {
        // Approached from below: the forward flank holds it.
        Carriage {
            cmd_um,
            pos_um: axis.nut_um(cmd_um, true, dt_c) - axis.play_um / 2.0,
            dir: 1.0,
            last_move_um: 0.0,
        }
    }

    /// Moves the nut to `cmd` in one monotonic move: the hysteresis of the
    /// play. The nut's position is monotonic in the command (the periodic
    /// lead error's slope is far below 1), so the end point decides.
    fn move_to(&mut self, axis: &PhysicalAxis, cmd_um: f64, dt_c: f64) {
        let d = cmd_um - self.cmd_um;
        if d.abs() < 1e-9 {
            return;
        }
        let forward = d > 0.0;
        let half = axis.play_um / 2.0;
        if forward {
            let reach = axis.nut_um(cmd_um, true, dt_c) - half;
            if reach > self.pos_um {
                self.pos_um = reach;
            }
        } else {
            let reach = axis.nut_um(cmd_um, false, dt_c) + half;
            if reach < self.pos_um {
                self.pos_um = reach;
            }
        }
        self.dir = if forward { 1.0 } else { -1.0 };
        self.last_move_um = d.abs();
        self.cmd_um = cmd_um;
    }
}

/// Room temperature: a seeded mean-reverting walk with knots every 600 s,
/// linear in between, around 20 °C.
fn temperature_walk(seed: u64, end_s: f64, walk_c: f64) -> Vec<(f64, f64)> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x7e4d_0000_0000_0006);
    let mut out = Vec::new();
    let mut t = 0.0;
    let mut temp = 20.0;
    while t <= end_s + 600.0 {
        out.push((t, temp));
        let z: f64 = StandardNormal.sample(&mut rng);
        temp += walk_c * z - 0.1 * (temp - 20.0);
        t += 600.0;
    }
    out
}

fn temp_at(knots: &[(f64, f64)], t: f64) -> f64 {
    let k = knots.partition_point(|(kt, _)| *kt <= t).max(1) - 1;
    let (ta, va) = knots[k];
    let (tb, vb) = knots.get(k + 1).copied().unwrap_or((ta + 600.0, va));
    va + (vb - va) * ((t - ta) / (tb - ta)).clamp(0.0, 1.0)
}

/// Runs `stage` through `plan` (settling scatter and camera noise seeded
/// by `seed`): the log a camera would have recorded. Errors: an invalid
/// plan (see [`SimPlan`]), a negative play or a non-positive lead, period
/// or length.
pub fn simulate_physical_log(
    stage: &PhysicalStage,
    plan: &SimPlan,
    seed: u64,
) -> Result<SimLog, AnalysisError> {
    plan.validate()?;
    for a in [&stage.x, &stage.y] {
        let ok =
            a.play_um >= 0.0 && a.lead_um > 0.0 && a.yaw.period_um > 0.0 && a.pitch.period_um > 0.0;
        if !ok {
            return Err(AnalysisError::Invalid(
                "physical stage: play must be ≥ 0, lead and waviness periods > 0".into(),
            ));
        }
    }
    for e in &stage.effects {
        let ok = match e {
            PhysicalEffect::Dent { half_width_um, .. } => *half_width_um > 0.0,
            PhysicalEffect::Bearing { period_um, .. } => *period_um > 0.0,
            PhysicalEffect::WindUp { length_um, .. } => *length_um > 0.0,
            PhysicalEffect::AirCycle { period_s, .. } => *period_s > 0.0,
            PhysicalEffect::DriftY { .. } => true,
        };
        if !ok {
            return Err(AnalysisError::Invalid(format!(
                "physical effect {e:?}: widths, periods and lengths must be > 0"
            )));
        }
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x9c4a_0000_0000_0007);
    let temps = temperature_walk(seed, plan.duration_s(), plan.temp_walk_c);
    let start = [plan.x_range_um[0] - 50.0, plan.x_scan_y_um];
    let mut cx = Carriage::start(&stage.x, start[0], 0.0);
    let mut cy = Carriage::start(&stage.y, start[1], 0.0);
    let mut settle = [0.0; 2];
    let mut records = Vec::with_capacity(plan.points());
    let mut visit = |x: f64, y: f64, t: f64, segment: &str, cycle: u32, rng: &mut ChaCha8Rng| {
        let temp_c = temp_at(&temps, t);
        let dt_c = temp_c - 20.0;
        for (k, (c, a, cmd)) in [(&mut cx, &stage.x, x), (&mut cy, &stage.y, y)]
            .into_iter()
            .enumerate()
        {
            if (cmd - c.cmd_um).abs() >= 1e-9 {
                c.move_to(a, cmd, dt_c);
                let z: f64 = StandardNormal.sample(rng);
                settle[k] = stage.settling_sigma_um * z;
            }
        }
        let reading = position(stage, &cx, &cy, t, dt_c);
        let nx: f64 = StandardNormal.sample(rng);
        let ny: f64 = StandardNormal.sample(rng);
        records.push(Record {
            t_s: t,
            segment: segment.to_string(),
            cycle,
            x_target_um: x,
            y_target_um: y,
            x_cmd_um: x,
            y_cmd_um: y,
            x_meas_um: reading[0] + settle[0] + plan.camera_sigma_um * nx,
            y_meas_um: reading[1] + settle[1] + plan.camera_sigma_um * ny,
            temp_c: Some((temp_c * 1e4).round() / 1e4),
            theta_urad: None,
            extra: Vec::new(),
        });
    };
    let mut t = 0.0;
    visit(start[0], start[1], t, "start", 0, &mut rng);
    let ramp = |a: f64, b: f64| -> Vec<f64> {
        let n = ((b - a).abs() / plan.step_um).round() as usize;
        let s = if b >= a { plan.step_um } else { -plan.step_um };
        (0..=n).map(|i| a + s * i as f64).collect()
    };
    for cycle in 0..plan.cycles {
        let [x0, x1] = plan.x_range_um;
        for x in ramp(x0, x1).into_iter().chain(ramp(x1, x0)) {
            t += plan.dwell_s;
            visit(x, plan.x_scan_y_um, t, "scan_x", cycle, &mut rng);
        }
        let [y0, y1] = plan.y_range_um;
        for y in ramp(y0, y1).into_iter().chain(ramp(y1, y0)) {
            t += plan.dwell_s;
            visit(plan.y_scan_x_um, y, t, "scan_y", cycle, &mut rng);
        }
        for _ in 0..plan.random_points {
            t += plan.dwell_s;
            let x = x0 + (x1 - x0) * rng.gen::<f64>();
            let y = y0 + (y1 - y0) * rng.gen::<f64>();
            visit(x, y, t, "random", cycle, &mut rng);
        }
    }
    let mut metadata = Metadata::new();
    metadata.insert("source", "micropos physical stage (synthetic)");
    metadata.insert("seed", seed.to_string());
    Ok(SimLog {
        records,
        columns: Columns::new(true, Vec::new())?,
        metadata,
    })
}

/// Where the tool point is (what an ideal camera reads), µm.
fn position(stage: &PhysicalStage, cx: &Carriage, cy: &Carriage, t_s: f64, dt_c: f64) -> [f64; 2] {
    let (px, py) = (cx.pos_um, cy.pos_um);
    let [arm_beside_x, arm_beside_y, arm_z] = stage.arm_um;
    // Angles in µrad → displacement µm: θ·arm·1e-6.
    let yaw_x = stage.x.yaw.at_urad(px);
    let pitch_x = stage.x.pitch.at_urad(px);
    let yaw_y = stage.y.yaw.at_urad(py);
    let pitch_y = stage.y.pitch.at_urad(py);
    let mut x = px - 1e-6 * yaw_x * arm_beside_x
        + 1e-6 * pitch_x * arm_z
        + 1e-6 * stage.squareness_urad * py;
    let mut y = py + 1e-6 * yaw_y * arm_beside_y - 1e-6 * pitch_y * arm_z;
    x += stage.thermal_offset_um_per_c[0] * dt_c + stage.drift_x_um_per_h * t_s / 3600.0;
    y += stage.thermal_offset_um_per_c[1] * dt_c;
    for e in &stage.effects {
        match *e {
            PhysicalEffect::Dent {
                axis,
                component,
                position_um,
                half_width_um,
                depth_um,
            } => {
                let p = if axis == Axis::X { px } else { py };
                let u = (p - position_um) / half_width_um;
                if u.abs() < 1.0 {
                    let v = depth_um * 0.5 * (1.0 + (std::f64::consts::PI * u).cos());
                    add(&mut x, &mut y, component, v);
                }
            }
            PhysicalEffect::Bearing {
                axis,
                component,
                period_um,
                amplitude_um,
                phase_rad,
            } => {
                let p = if axis == Axis::X { px } else { py };
                let v = amplitude_um * (std::f64::consts::TAU * p / period_um + phase_rad).sin();
                add(&mut x, &mut y, component, v);
            }
            PhysicalEffect::WindUp {
                axis,
                amplitude_um,
                length_um,
            } => {
                let c = if axis == Axis::X { cx } else { cy };
                let v = -c.dir * amplitude_um * (1.0 - (-c.last_move_um / length_um).exp());
                add(&mut x, &mut y, axis, v);
            }
            PhysicalEffect::AirCycle {
                component,
                period_s,
                amplitude_um,
                phase_rad,
            } => {
                let v = amplitude_um * (std::f64::consts::TAU * t_s / period_s + phase_rad).sin();
                add(&mut x, &mut y, component, v);
            }
            PhysicalEffect::DriftY { rate_um_per_h } => y += rate_um_per_h * t_s / 3600.0,
        }
    }
    [x, y]
}

fn add(x: &mut f64, y: &mut f64, component: Axis, v: f64) {
    match component {
        Axis::X => *x += v,
        Axis::Y => *y += v,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn quiet(mut s: PhysicalStage) -> PhysicalStage {
        s.settling_sigma_um = 0.0;
        s
    }

    fn plan() -> SimPlan {
        SimPlan {
            step_um: 100.0,
            cycles: 1,
            random_points: 5,
            camera_sigma_um: 0.0,
            temp_walk_c: 0.0,
            ..SimPlan::default()
        }
    }

    #[test]
    fn play_is_hysteresis_of_the_carriage() {
        // Only play on x: forward readings trail by B/2, backward lead by B/2.
        let mut s = quiet(PhysicalStage::random(3));
        for a in [&mut s.x, &mut s.y] {
            a.scale_ppm = 0.0;
            a.forward.clear();
            a.backward.clear();
            a.yaw.slope_urad_per_mm = 0.0;
            a.yaw.amplitude_urad = 0.0;
            a.pitch.slope_urad_per_mm = 0.0;
            a.pitch.amplitude_urad = 0.0;
        }
        s.x.play_um = 3.0;
        s.squareness_urad = 0.0;
        s.drift_x_um_per_h = 0.0;
        let log = simulate_physical_log(&s, &plan(), 1).unwrap();
        let scan: Vec<&Record> = log
            .records
            .iter()
            .filter(|r| r.segment == "scan_x")
            .collect();
        let n = scan.len() / 2;
        for r in &scan[1..n] {
            assert!((r.x_meas_um - r.x_cmd_um + 1.5).abs() < 1e-9, "{r:?}");
        }
        // The first point after the reversal is the turning point itself
        // (no move); the ones after it lead.
        for r in &scan[n + 1..] {
            assert!((r.x_meas_um - r.x_cmd_um - 1.5).abs() < 1e-9, "{r:?}");
        }
    }

    #[test]
    fn squareness_moves_x_with_y() {
        let mut s = quiet(PhysicalStage::random(4));
        s.squareness_urad = 2000.0;
        let a = simulate_physical_log(&s, &plan(), 1).unwrap();
        s.squareness_urad = 0.0;
        let b = simulate_physical_log(&s, &plan(), 1).unwrap();
        for (ra, rb) in a.records.iter().zip(&b.records) {
            let want = 2e-3 * rb.y_meas_um;
            // y_meas differs from the carriage's y by the y guide's angles
            // (≤ ~1 µm): 2 nm of x at 2 mrad.
            assert!((ra.x_meas_um - rb.x_meas_um - want).abs() < 0.01);
        }
    }

    #[test]
    fn refuses_invalid_stage() {
        let mut s = PhysicalStage::random(5);
        s.x.play_um = -1.0;
        assert!(simulate_physical_log(&s, &plan(), 1).is_err());
        let mut s = PhysicalStage::random(5);
        s.effects.push(PhysicalEffect::Dent {
            axis: Axis::X,
            component: Axis::X,
            position_um: 1.0,
            half_width_um: 0.0,
            depth_um: 1.0,
        });
        assert!(simulate_physical_log(&s, &plan(), 1).is_err());
    }
}
