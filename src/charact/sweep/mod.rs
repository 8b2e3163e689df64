//! The sweep characterization's arithmetic, pure: the plan of passes, the
//! controller position at a frame's time, the resampling of a pass onto the
//! step plan's grid, and the camera delay estimated from the data. The
//! async job that moves the stage and collects samples and frames is
//! `daemon::jobs::sweep_job`; [`anchor`] corrects the records to static
//! anchors.
//!
//! # Method
//! Each axis sweeps forward and backward at constant velocity over its
//! range, `cycles` times; odd cycles at `velocity_um_per_s`, even ones at
//! twice it. During a pass the controller position is sampled (`POS?`,
//! rig-time stamps) and every camera frame is decoded with its own time
//! stamp. A frame's controller position is the samples' linear
//! interpolation at `t_frame − delay`: the axis as `POS?` reports it, the
//! servo's following error included, never the commanded trajectory (on
//! which a lag of `v·τ` would read as `τ` of camera delay:
//! `the_following_error_is_absorbed_by_the_sampled_positions`); frames where the interpolated
//! velocity is not the pass's (the acceleration zones at the ends) are
//! left out. The frames' errors `e = cmd − measured` are averaged per grid
//! cell (±step/2 around the step plan's points; a cell without a frame
//! interpolates its two neighbouring frames) and logged as if measured at
//! the grid point: the log has the step plan's segments, cycles and
//! targets, so `tables build`, `diagnose` and the plots read it unchanged.
//! A record carries the motion state of its pass (one move since the run-up
//! began); [`anchor`] measures the step plan's state at static
//! anchors and corrects the records to it.
//!
//! # Camera delay
//! A delay error Δ = true − assumed shifts the interpolated command by
//! `±v·Δ` (sign of the pass direction): forward and backward passes
//! disagree by `2·v·Δ` plus the direction-dependent error (backlash), which
//! is constant per direction. Per axis and direction, the pass means of `e`
//! over the stretch every pass covers are `a_dir + s·v·Δ` (`s` = ±1): with
//! two velocities, Δ is the least-squares slope against `s·v` after the
//! per-group means are removed (the backlash is the group mean). A pass's
//! mean is the integral of its frames' errors, linear between neighbours,
//! over that stretch (not a mean over grid cells: a cell's mean depends on
//! where in it the frames fell, which differs between velocities and
//! directions, and the leadscrew's cyclic error then reads as a delay:
//! −0.07 ms on a 25 µm grid in `the_delay_does_not_depend_on_the_grid`).
//! [`estimate_delay`] iterates this from zero until the step is below a
//! microsecond. With the cycles at v, 2v, v a drift linear in time cancels.
//! Every pass of an axis starts and ends at the same points
//! ([`SweepPlan::run_up_um`]), so an error that depends on the path since
//! the pass began (lost motion building up with the distance, hysteresis)
//! is the same at both velocities and drops out with the group means
//! (`a_path_dependent_error_is_not_read_as_delay`).
//!
//! What the fit cannot tell from the delay: any error proportional to the
//! signed velocity (a drive's viscous wind-up between encoder and platform
//! is one: it is then removed with the delay, which is what a table used at
//! rest needs), and offsets that change from pass to pass (a stage whose
//! rest error persisted through the next pass: σ 0.035 µm per pass scatters
//! the estimate by ≈ 0.2 ms on the paper plan).

pub mod anchor;

use crate::charact::log::Metadata;
use crate::charact::scan::PARK_APPROACH_UM;
use crate::model::XyUm;

/// The sweep plan: which axes, the step plan's grid, the velocities.
#[derive(Debug, Clone, PartialEq)]
pub struct SweepPlan {
    /// Sweep X.
    pub scan_x: bool,
    /// Sweep Y.
    pub scan_y: bool,
    /// Grid step the log is resampled onto, µm.
    pub step_um: f64,
    /// First X grid point, µm.
    pub x_start_um: f64,
    /// X range, µm.
    pub x_range_um: f64,
    /// First Y grid point, µm.
    pub y_start_um: f64,
    /// Y range, µm.
    pub y_range_um: f64,
    /// Forward + backward cycles per axis (≥ 2: two velocities).
    pub cycles: u32,
    /// Velocity of the odd cycles, µm/s (even cycles: twice it).
    pub velocity_um_per_s: f64,
    /// Spacing of the static anchors measured after each cycle's passes,
    /// µm, rounded to a multiple of `step_um` ([`anchor`]); 0 =
    /// none (the records then carry the pass's motion state).
    pub anchor_spacing_um: f64,
}

/// One constant-velocity pass.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PassSpec {
    /// X sweeps (else Y).
    pub x_axis: bool,
    /// Towards larger positions.
    pub forward: bool,
    /// 1-based cycle.
    pub cycle: u32,
    /// Velocity, µm/s (> 0).
    pub velocity_um_per_s: f64,
    /// First grid point of the swept axis, µm.
    pub start_um: f64,
    /// Range of the swept axis, µm.
    pub range_um: f64,
    /// Position of the held axis, µm.
    pub hold_um: f64,
    /// Run-up beyond each end of the range, µm: the same for every pass of
    /// the plan ([`SweepPlan::run_up_um`]).
    pub run_up_um: f64,
}

impl PassSpec {
    /// The log segment (the step plan's names).
    pub fn segment(&self) -> &'static str {
        match (self.x_axis, self.forward) {
            (true, true) => "scan_x_fwd",
            (true, false) => "scan_x_bwd",
            (false, true) => "scan_y_fwd",
            (false, false) => "scan_y_bwd",
        }
    }

    /// +1 forward, −1 backward.
    pub fn sign(&self) -> f64 {
        if self.forward {
            1.0
        } else {
            -1.0
        }
    }

    /// Where the pass starts and ends on the swept axis, µm (the range plus
    /// the run-up at each end, in the pass's direction).
    pub fn ends_um(&self) -> (f64, f64) {
        let (lo, hi) = (
            self.start_um - self.run_up_um,
            self.start_um + self.range_um + self.run_up_um,
        );
        if self.forward {
            (lo, hi)
        } else {
            (hi, lo)
        }
    }
}

/// Run-up at the plan's highest velocity, as time at that velocity (plus
/// [`PARK_APPROACH_UM`]): the acceleration zone must end before the first
/// grid point (frames there are left out by their velocity anyway).
pub const RUN_UP_S: f64 = 0.3;

/// Why a sweep cannot be planned or evaluated.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SweepError {
    /// A plan value is out of range.
    #[error("sweep plan: {0}")]
    Plan(String),
    /// Too few passes at distinct velocities to separate delay and backlash.
    #[error("the camera delay cannot be estimated: {0}")]
    NoDelay(String),
}

impl SweepPlan {
    /// Checks the values.
    pub fn validate(&self) -> Result<(), SweepError> {
        let finite = [
            self.step_um,
            self.x_start_um,
            self.x_range_um,
            self.y_start_um,
            self.y_range_um,
            self.velocity_um_per_s,
            self.anchor_spacing_um,
        ]
        .iter()
        .all(|v| v.is_finite());
        if !finite || self.step_um <= 0.0 || self.x_range_um <= 0.0 || self.y_range_um <= 0.0 {
            return Err(SweepError::Plan(
                "step and ranges must be positive numbers".into(),
            ));
        }
        if self.velocity_um_per_s <= 0.0 {
            return Err(SweepError::Plan(
                "velocity_um_per_s must be positive".into(),
            ));
        }
        if self.anchor_spacing_um < 0.0 {
            return Err(SweepError::Plan(
                "anchor_spacing_um must be 0 (no anchors) or positive".into(),
            ));
        }
        if self.cycles < 2 {
            return Err(SweepError::Plan(
                "a sweep needs cycles ≥ 2: the even cycles run at twice the velocity, which separates the camera delay from the backlash".into(),
            ));
        }
        if !(self.scan_x || self.scan_y) {
            return Err(SweepError::Plan("no axis to sweep".into()));
        }
        let n = |r: f64| r / self.step_um;
        if (n(self.x_range_um) + n(self.y_range_um)) * f64::from(self.cycles) > 1e7 {
            return Err(SweepError::Plan(
                "the resampled log would have more than 10 million records".into(),
            ));
        }
        Ok(())
    }

    /// Run-up beyond each end of the range, µm, the same for every pass:
    /// [`PARK_APPROACH_UM`] + [`RUN_UP_S`] at the plan's highest velocity.
    /// Why one for all: the estimate of the camera delay compares passes of
    /// one direction at two velocities, and takes whatever differs between
    /// them with the velocity for delay. A stage's error can depend on the
    /// path since the last reversal (lost motion that builds up with the
    /// distance travelled, hysteresis), and a run-up that grew with the
    /// velocity would start the faster passes farther back: on the paper's
    /// ranges a lost motion of 5 µm over 1 mm reads as +0.12 ms of delay.
    /// Passes that start and end at the same points share that path, and
    /// only what depends on the velocity differs.
    pub fn run_up_um(&self) -> f64 {
        let top = (1..=self.cycles.min(2))
            .map(|c| self.velocity_of_cycle(c))
            .fold(0.0, f64::max);
        PARK_APPROACH_UM + top * RUN_UP_S
    }

    /// Grid steps between two anchors (at least one), `None` without
    /// anchors.
    pub fn anchor_every(&self) -> Option<usize> {
        (self.anchor_spacing_um > 0.0 && self.step_um > 0.0)
            .then(|| ((self.anchor_spacing_um / self.step_um).round() as usize).max(1))
    }

    /// The anchor spacing the plan uses, µm (a multiple of the step; 0 =
    /// none).
    pub fn anchor_spacing_used_um(&self) -> f64 {
        self.anchor_every().map_or(0.0, |n| n as f64 * self.step_um)
    }

    /// Velocity of a cycle, µm/s.
    pub fn velocity_of_cycle(&self, cycle: u32) -> f64 {
        if cycle % 2 == 0 {
            2.0 * self.velocity_um_per_s
        } else {
            self.velocity_um_per_s
        }
    }

    /// The grid of one axis (the step plan's points), ascending.
    pub fn grid(&self, x_axis: bool) -> Vec<f64> {
        let (start, range) = if x_axis {
            (self.x_start_um, self.x_range_um)
        } else {
            (self.y_start_um, self.y_range_um)
        };
        let n = ((range / self.step_um) + 1e-9).floor() as u32;
        (0..=n)
            .map(|i| start + f64::from(i) * self.step_um)
            .collect()
    }

    /// Every pass, in order: X cycles (forward, backward), then Y.
    pub fn passes(&self) -> Vec<PassSpec> {
        let mut v = Vec::new();
        for x_axis in [true, false] {
            if (x_axis && !self.scan_x) || (!x_axis && !self.scan_y) {
                continue;
            }
            let (start_um, range_um, hold_um) = if x_axis {
                (
                    self.x_start_um,
                    self.x_range_um,
                    self.y_start_um + self.y_range_um / 2.0,
                )
            } else {
                (
                    self.y_start_um,
                    self.y_range_um,
                    self.x_start_um + self.x_range_um / 2.0,
                )
            };
            for cycle in 1..=self.cycles {
                for forward in [true, false] {
                    v.push(PassSpec {
                        x_axis,
                        forward,
                        cycle,
                        velocity_um_per_s: self.velocity_of_cycle(cycle),
                        start_um,
                        range_um,
                        hold_um,
                        run_up_um: self.run_up_um(),
                    });
                }
            }
        }
        v
    }

    /// Grid records the log will hold at most.
    pub fn records_total(&self) -> usize {
        self.passes()
            .iter()
            .map(|p| self.grid(p.x_axis).len())
            .sum()
    }

    /// Writes the plan into log metadata (`mode = sweep`).
    pub fn to_metadata(&self, md: &mut Metadata) {
        md.insert("job", "characterize");
        md.insert("mode", "sweep");
        md.insert("scan_x", self.scan_x.to_string());
        md.insert("scan_y", self.scan_y.to_string());
        md.insert("step_um", self.step_um.to_string());
        md.insert("x_start_um", self.x_start_um.to_string());
        md.insert("x_range_um", self.x_range_um.to_string());
        md.insert("y_start_um", self.y_start_um.to_string());
        md.insert("y_range_um", self.y_range_um.to_string());
        md.insert("cycles", self.cycles.to_string());
        md.insert("velocity_um_per_s", self.velocity_um_per_s.to_string());
        md.insert(
            "anchor_spacing_um",
            self.anchor_spacing_used_um().to_string(),
        );
    }
}

/// One controller position sample (`POS?`), rig time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PosSample {
    /// Rig time of the query, s.
    pub t_s: f64,
    /// Position of the swept axis, µm.
    pub pos_um: f64,
}

/// One decoded frame of a pass.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SweepFrame {
    /// The frame's own timestamp, rig time, s.
    pub t_s: f64,
    /// Measured position, stage frame, µm.
    pub meas: XyUm,
    /// Decoded θ relative to the tie's, µrad (the log's `theta_urad`: the
    /// platform's yaw since the tie, right-handed about +z).
    pub theta_urad: f64,
    /// Decoder quality.
    pub quality: f64,
}

/// What one pass recorded.
#[derive(Debug, Clone, PartialEq)]
pub struct PassData {
    /// The pass.
    pub spec: PassSpec,
    /// Controller samples, in time order.
    pub samples: Vec<PosSample>,
    /// Frames, in time order.
    pub frames: Vec<SweepFrame>,
}

/// Position and velocity of the swept axis at `t_s`, linear between the
/// bracketing samples; `None` outside the samples.
pub fn position_at(samples: &[PosSample], t_s: f64) -> Option<(f64, f64)> {
    let k = samples.partition_point(|s| s.t_s <= t_s);
    if k == 0 || k >= samples.len() {
        return None;
    }
    let (a, b) = (samples[k - 1], samples[k]);
    let dt = b.t_s - a.t_s;
    if dt.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
        return None;
    }
    let v = (b.pos_um - a.pos_um) / dt;
    Some((a.pos_um + v * (t_s - a.t_s), v))
}

/// Relative velocity deviation beyond which a frame counts as in an
/// acceleration zone.
pub const VELOCITY_TOLERANCE: f64 = 0.02;

/// A frame placed on the controller's trajectory.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameAt {
    /// Controller position of the swept axis at the frame's (corrected)
    /// time, µm.
    pub cmd_um: f64,
    /// `cmd − measured` of the swept axis, µm.
    pub e_scan_um: f64,
    /// `hold − measured` of the held axis, µm.
    pub e_held_um: f64,
    /// Corrected frame time (stamp − delay), rig s.
    pub t_s: f64,
    /// Decoded θ relative to the tie's, µrad.
    pub theta_urad: f64,
    /// Decoder quality.
    pub quality: f64,
}

/// The frames of `pass` at its constant velocity, placed on the trajectory
/// at `stamp − delay_s`, sorted by position.
pub fn frames_at(pass: &PassData, delay_s: f64) -> Vec<FrameAt> {
    let s = pass.spec;
    let want_v = s.sign() * s.velocity_um_per_s;
    let mut out: Vec<FrameAt> = pass
        .frames
        .iter()
        .filter_map(|f| {
            let t = f.t_s - delay_s;
            let (cmd, v) = position_at(&pass.samples, t)?;
            if (v - want_v).abs() > VELOCITY_TOLERANCE * s.velocity_um_per_s {
                return None;
            }
            let (scan, held) = if s.x_axis {
                (f.meas.x_um, f.meas.y_um)
            } else {
                (f.meas.y_um, f.meas.x_um)
            };
            Some(FrameAt {
                cmd_um: cmd,
                e_scan_um: cmd - scan,
                e_held_um: s.hold_um - held,
                t_s: t,
                theta_urad: f.theta_urad,
                quality: f.quality,
            })
        })
        .collect();
    out.sort_by(|a, b| a.cmd_um.total_cmp(&b.cmd_um));
    out
}

/// A pass's error at one grid point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GridValue {
    /// The grid point (swept axis), µm.
    pub pos_um: f64,
    /// `cmd − measured` of the swept axis, µm.
    pub e_scan_um: f64,
    /// `hold − measured` of the held axis, µm.
    pub e_held_um: f64,
    /// Mean corrected frame time, rig s.
    pub t_s: f64,
    /// Mean decoded θ relative to the tie's, µrad (averaged like the
    /// errors).
    pub theta_urad: f64,
    /// Mean decoder quality.
    pub quality: f64,
    /// Frames averaged (0: interpolated between the two neighbours).
    pub frames: usize,
}

/// `frames` (sorted by position) onto `grid`: per point the mean over the
/// frames within ±step/2, or if there are none the linear interpolation of
/// the nearest frame on each side when both are within 1.5 steps; `None`
/// where neither (an acceleration zone, a gap).
pub fn resample(frames: &[FrameAt], grid: &[f64], step_um: f64) -> Vec<Option<GridValue>> {
    let half = step_um / 2.0;
    grid.iter()
        .map(|&p| {
            let lo = frames.partition_point(|f| f.cmd_um < p - half);
            let hi = frames.partition_point(|f| f.cmd_um <= p + half);
            if hi > lo {
                let win = &frames[lo..hi];
                let n = win.len() as f64;
                let mean = |g: fn(&FrameAt) -> f64| win.iter().map(g).sum::<f64>() / n;
                return Some(GridValue {
                    pos_um: p,
                    e_scan_um: mean(|f| f.e_scan_um),
                    e_held_um: mean(|f| f.e_held_um),
                    t_s: mean(|f| f.t_s),
                    theta_urad: mean(|f| f.theta_urad),
                    quality: mean(|f| f.quality),
                    frames: win.len(),
                });
            }
            // No frame in the cell: lo == hi is the first frame beyond it.
            let (a, b) = (frames.get(lo.checked_sub(1)?)?, frames.get(lo)?);
            if p - a.cmd_um > 1.5 * step_um || b.cmd_um - p > 1.5 * step_um {
                return None;
            }
            let w = (p - a.cmd_um) / (b.cmd_um - a.cmd_um);
            let lerp = |x: f64, y: f64| x + w * (y - x);
            Some(GridValue {
                pos_um: p,
                e_scan_um: lerp(a.e_scan_um, b.e_scan_um),
                e_held_um: lerp(a.e_held_um, b.e_held_um),
                t_s: lerp(a.t_s, b.t_s),
                theta_urad: lerp(a.theta_urad, b.theta_urad),
                quality: a.quality.min(b.quality),
                frames: 0,
            })
        })
        .collect()
}

/// Mean of the swept axis's error over `[lo, hi]`, the frames (sorted by
/// position) joined by straight lines: the trapezoid integral over the
/// stretch divided by its length; `None` if the frames do not span it.
fn mean_over(frames: &[FrameAt], lo: f64, hi: f64) -> Option<f64> {
    let (first, last) = (frames.first()?, frames.last()?);
    if !(first.cmd_um <= lo && last.cmd_um >= hi && hi > lo) {
        return None;
    }
    let mut area = 0.0;
    for w in frames.windows(2) {
        let (a, b) = (w[0], w[1]);
        let (x0, x1) = (a.cmd_um.max(lo), b.cmd_um.min(hi));
        let len = b.cmd_um - a.cmd_um;
        // Skips empty and NaN stretches alike.
        if x1.partial_cmp(&x0) != Some(std::cmp::Ordering::Greater)
            || len.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater)
        {
            continue;
        }
        let at = |x: f64| a.e_scan_um + (b.e_scan_um - a.e_scan_um) * (x - a.cmd_um) / len;
        area += 0.5 * (at(x0) + at(x1)) * (x1 - x0);
    }
    let m = area / (hi - lo);
    m.is_finite().then_some(m)
}

/// The camera delay as the data shows it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DelayEstimate {
    /// Delay from the true exposure mid-point to the frame's stamp, s.
    pub delay_s: f64,
    /// Passes that entered the estimate.
    pub passes: usize,
    /// RMS of the pass means about the fitted model, µm.
    pub residual_um: f64,
    /// Iterations until the step fell below 1 µs.
    pub iterations: u32,
}

/// Estimates the camera delay from the passes (see the module docs).
pub fn estimate_delay(passes: &[PassData]) -> Result<DelayEstimate, SweepError> {
    let mut delay_s = 0.0;
    let mut last = None;
    for it in 1..=8u32 {
        let (step_s, used, rms) = delay_step(passes, delay_s)?;
        delay_s += step_s;
        last = Some(DelayEstimate {
            delay_s,
            passes: used,
            residual_um: rms,
            iterations: it,
        });
        if step_s.abs() < 1e-6 {
            break;
        }
    }
    last.ok_or_else(|| SweepError::NoDelay("no iteration ran".into()))
}

/// One least-squares step: the delay error Δ at the assumed `delay_s`, the
/// passes used and the RMS residual (µm).
fn delay_step(passes: &[PassData], delay_s: f64) -> Result<(f64, usize, f64), SweepError> {
    let (mut num, mut den) = (0.0, 0.0);
    let mut used = 0;
    let mut resid: Vec<(f64, f64)> = Vec::new();
    for x_axis in [true, false] {
        let on_axis: Vec<(&PassData, Vec<FrameAt>)> = passes
            .iter()
            .filter(|p| p.spec.x_axis == x_axis)
            .map(|p| (p, frames_at(p, delay_s)))
            .filter(|(_, f)| f.len() >= 2)
            .collect();
        // The stretch every pass of the axis covers.
        let lo = on_axis
            .iter()
            .filter_map(|(_, f)| f.first().map(|a| a.cmd_um))
            .fold(f64::NEG_INFINITY, f64::max);
        let hi = on_axis
            .iter()
            .filter_map(|(_, f)| f.last().map(|a| a.cmd_um))
            .fold(f64::INFINITY, f64::min);
        if on_axis.is_empty() || hi.partial_cmp(&lo) != Some(std::cmp::Ordering::Greater) {
            continue;
        }
        for forward in [true, false] {
            let group: Vec<(f64, f64)> = on_axis
                .iter()
                .filter(|(p, _)| p.spec.forward == forward)
                .filter_map(|(p, f)| {
                    let m = mean_over(f, lo, hi)?;
                    Some((p.spec.sign() * p.spec.velocity_um_per_s, m))
                })
                .collect();
            if group.len() < 2 {
                continue;
            }
            let k = group.len() as f64;
            let sv = group.iter().map(|g| g.0).sum::<f64>() / k;
            let se = group.iter().map(|g| g.1).sum::<f64>() / k;
            for &(v, e) in &group {
                num += (v - sv) * (e - se);
                den += (v - sv).powi(2);
                resid.push((v - sv, e - se));
            }
            used += group.len();
        }
    }
    if den <= 1e-12 {
        return Err(SweepError::NoDelay(
            "no axis and direction has passes at two velocities covering common grid points".into(),
        ));
    }
    let slope = num / den;
    let rms = (resid
        .iter()
        .map(|(v, e)| (e - slope * v).powi(2))
        .sum::<f64>()
        / resid.len().max(1) as f64)
        .sqrt();
    Ok((slope, used, rms))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plan() -> SweepPlan {
        SweepPlan {
            scan_x: true,
            scan_y: true,
            step_um: 5.0,
            x_start_um: 1000.0,
            x_range_um: 200.0,
            y_start_um: 2000.0,
            y_range_um: 100.0,
            cycles: 3,
            velocity_um_per_s: 100.0,
            anchor_spacing_um: 50.0,
        }
    }

    /// A synthetic pass: the platform follows the command with a backlash
    /// of `b` µm against the direction and a periodic error; the camera
    /// stamps `latency_s` late; samples every 5 ms, frames every 1/30 s;
    /// the pass from one end of its run-up to the other.
    fn pass(spec: PassSpec, latency_s: f64, b: f64) -> PassData {
        pass_with(
            spec,
            latency_s,
            b,
            30.0,
            &|c| 0.3 * (c / 37.0).sin(),
            &|_| 0.0,
        )
    }

    /// [`pass`] with the frame rate, the stage's error (of the command
    /// position, µm) and its lost motion against the direction (of the
    /// distance travelled since the pass started, µm) chosen.
    fn pass_with(
        spec: PassSpec,
        latency_s: f64,
        b: f64,
        fps: f64,
        error: &dyn Fn(f64) -> f64,
        history: &dyn Fn(f64) -> f64,
    ) -> PassData {
        let v = spec.velocity_um_per_s;
        let acc = 2000.0; // µm/s²
        let (p0, p1) = spec.ends_um();
        let ta = v / acc;
        let da = v * v / (2.0 * acc);
        let tc = ((p1 - p0).abs() - 2.0 * da) / v;
        let total = 2.0 * ta + tc;
        let s = spec.sign();
        let pos = |t: f64| -> f64 {
            let t = t.clamp(0.0, total);
            let d = if t < ta {
                0.5 * acc * t * t
            } else if t < ta + tc {
                da + v * (t - ta)
            } else {
                let u = total - t;
                (p1 - p0).abs() - 0.5 * acc * u * u
            };
            p0 + s * d
        };
        let samples = (0..)
            .map(|k| f64::from(k) * 0.005 - 0.1)
            .take_while(|&t| t < total + 0.1)
            .map(|t| PosSample {
                t_s: t,
                pos_um: pos(t),
            })
            .collect();
        let frames = (0..)
            .map(|k| f64::from(k) / fps - 0.05)
            .take_while(|&t| t < total + 0.05)
            .map(|t| {
                let c = pos(t);
                let err = error(c) - s * b - s * history((c - p0).abs());
                let scan = c + err;
                let meas = if spec.x_axis {
                    XyUm {
                        x_um: scan,
                        y_um: spec.hold_um + 0.1,
                    }
                } else {
                    XyUm {
                        x_um: spec.hold_um + 0.1,
                        y_um: scan,
                    }
                };
                SweepFrame {
                    t_s: t + latency_s,
                    meas,
                    theta_urad: 0.0,
                    quality: 100.0,
                }
            })
            .collect();
        PassData {
            spec,
            samples,
            frames,
        }
    }

    #[test]
    fn plan_alternates_velocities_and_directions() {
        let p = plan();
        p.validate().unwrap();
        let ps = p.passes();
        assert_eq!(ps.len(), 12);
        assert_eq!(ps[0].segment(), "scan_x_fwd");
        assert_eq!(ps[1].segment(), "scan_x_bwd");
        assert_eq!(ps[2].velocity_um_per_s, 200.0);
        assert_eq!(ps[6].segment(), "scan_y_fwd");
        assert_eq!(ps[6].hold_um, 1100.0);
        assert_eq!(p.grid(true).len(), 41);
        assert_eq!(p.records_total(), 6 * 41 + 6 * 21);
        assert!(SweepPlan {
            cycles: 1,
            ..p.clone()
        }
        .validate()
        .is_err());
        assert!(SweepPlan {
            velocity_um_per_s: f64::NAN,
            ..p
        }
        .validate()
        .is_err());
    }

    #[test]
    fn interpolation_between_samples() {
        let s = [
            PosSample {
                t_s: 0.0,
                pos_um: 0.0,
            },
            PosSample {
                t_s: 1.0,
                pos_um: 10.0,
            },
            PosSample {
                t_s: 2.0,
                pos_um: 30.0,
            },
        ];
        assert_eq!(position_at(&s, 0.5), Some((5.0, 10.0)));
        assert_eq!(position_at(&s, 1.5), Some((20.0, 20.0)));
        assert_eq!(position_at(&s, -0.1), None);
        assert_eq!(position_at(&s, 2.5), None);
        assert_eq!(position_at(&[], 0.0), None);
    }

    #[test]
    fn recovers_the_delay_apart_from_the_backlash() {
        let p = plan();
        for (latency_s, b) in [(0.0037, 1.0), (0.0121, -0.5), (0.0, 0.0)] {
            let passes: Vec<PassData> = p
                .passes()
                .into_iter()
                .map(|s| pass(s, latency_s, b))
                .collect();
            let est = estimate_delay(&passes).unwrap();
            assert!(
                (est.delay_s - latency_s).abs() < 2e-5,
                "{est:?} vs {latency_s}"
            );
            // Corrected, forward and backward differ by the backlash only.
            let g = p.grid(true);
            let f = resample(&frames_at(&passes[0], est.delay_s), &g, p.step_um);
            let r = resample(&frames_at(&passes[1], est.delay_s), &g, p.step_um);
            let mid = g.len() / 2;
            let (f, r) = (f[mid].unwrap(), r[mid].unwrap());
            assert!(
                (f.e_scan_um - r.e_scan_um - 2.0 * b).abs() < 0.01,
                "{f:?} {r:?}"
            );
            assert!((f.e_held_um + 0.1).abs() < 1e-9);
        }
    }

    /// The main job's case: frames 4 and 8 µm apart (30 frames/s at 120
    /// and 240 µm/s), the leadscrew's 400 µm cyclic error with harmonics,
    /// over 2 mm; delay, backlash and the error's amplitudes and phases
    /// drawn at random, both signs. The estimate is the same on any grid
    /// (it has none); a mean over 25 µm cells read −0.07 ms of the cyclic
    /// error as delay.
    #[test]
    fn the_delay_is_recovered_under_a_cyclic_error() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(17);
        for _ in 0..20 {
            let latency_s = rng.gen_range(0.0..0.012);
            let b = rng.gen_range(-2.5..2.5);
            let amp: [f64; 3] = [
                rng.gen_range(-2.0..2.0),
                rng.gen_range(-0.6..0.6),
                rng.gen_range(-0.3..0.3),
            ];
            let ph: [f64; 3] = [0, 1, 2].map(|_| rng.gen_range(0.0..std::f64::consts::TAU));
            let err = move |c: f64| {
                let w = std::f64::consts::TAU * c / 400.0;
                (0..3)
                    .map(|k| amp[k] * ((k + 1) as f64 * w + ph[k]).sin())
                    .sum::<f64>()
            };
            for step_um in [5.0, 25.0] {
                let p = SweepPlan {
                    step_um,
                    x_range_um: 2000.0,
                    y_range_um: 1000.0,
                    velocity_um_per_s: 120.0,
                    ..plan()
                };
                let passes: Vec<PassData> = p
                    .passes()
                    .into_iter()
                    .map(|s| pass_with(s, latency_s, b, 30.0, &err, &|_| 0.0))
                    .collect();
                let est = estimate_delay(&passes).unwrap();
                assert!(
                    (est.delay_s - latency_s).abs() < 2e-5,
                    "{est:?} vs {latency_s} (b {b}, amp {amp:?})"
                );
            }
        }
    }

    /// The servo's following error: at constant velocity the axis trails
    /// the command by v·τ, a shift of τ in time. Placed on the sampled
    /// positions (`POS?` reports the axis, lag included) the frames give
    /// the camera delay; placed on the commanded trajectory they would give
    /// delay + τ.
    #[test]
    fn the_following_error_is_absorbed_by_the_sampled_positions() {
        let p = plan();
        let (latency_s, tau) = (0.0042, 0.003);
        let estimate = |sampled: bool| {
            let passes: Vec<PassData> = p
                .passes()
                .into_iter()
                .map(|s| {
                    // Frames see the axis at t (= the command at t − τ),
                    // stamped t + latency.
                    let mut d = pass(s, latency_s + tau, 0.8);
                    if sampled {
                        // POS? at t + τ reads where the axis is then: the
                        // command of t.
                        for x in &mut d.samples {
                            x.t_s += tau;
                        }
                    }
                    d
                })
                .collect();
            estimate_delay(&passes).unwrap().delay_s
        };
        assert!((estimate(true) - latency_s).abs() < 2e-5);
        assert!((estimate(false) - latency_s - tau).abs() < 2e-5);
    }

    /// Stages whose error depends on the path since the pass began: a lost
    /// motion that builds up with the distance travelled,
    /// `A·(1 − exp(−L/λ))`, and a hysteresis loop that closes over `w`
    /// (`H·tanh(L/w)`), amplitudes and lengths drawn at random, with the
    /// backlash and the leadscrew's cyclic error. Every pass of the plan
    /// starts from the same run-up, so the path is the same at both
    /// velocities and the delay comes out at every draw. The same stages
    /// with a run-up that grows with the velocity (`20 µm + 0.3 s · v`, the
    /// faster passes starting farther back) read the difference in path
    /// as delay: that is checked too, so the test shows the effect exists.
    #[test]
    fn a_path_dependent_error_is_not_read_as_delay() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(29);
        let mut worst_shifted = 0.0f64;
        for _ in 0..12 {
            let latency_s = rng.gen_range(-0.004..0.012);
            let b = rng.gen_range(-2.5..2.5);
            let (a, lambda) = (rng.gen_range(1.0..6.0), rng.gen_range(100.0..3000.0));
            let (h, w) = (rng.gen_range(-1.0..1.0), rng.gen_range(20.0..300.0));
            let (c1, ph) = (
                rng.gen_range(-2.0..2.0),
                rng.gen_range(0.0..std::f64::consts::TAU),
            );
            let err = move |c: f64| c1 * (std::f64::consts::TAU * c / 400.0 + ph).sin();
            let hist = move |l: f64| a * (1.0 - (-l / lambda).exp()) + h * (l / w).tanh();
            let p = SweepPlan {
                x_range_um: rng.gen_range(500.0..4000.0),
                y_range_um: rng.gen_range(300.0..2000.0),
                velocity_um_per_s: rng.gen_range(60.0..200.0),
                ..plan()
            };
            let on = |specs: Vec<PassSpec>| -> f64 {
                let passes: Vec<PassData> = specs
                    .into_iter()
                    .map(|s| pass_with(s, latency_s, b, 30.0, &err, &hist))
                    .collect();
                estimate_delay(&passes).unwrap().delay_s - latency_s
            };
            let e = on(p.passes());
            assert!(
                e.abs() < 2e-5,
                "error {e} s (A {a} λ {lambda} H {h} w {w} plan {p:?})"
            );
            let shifted = p
                .passes()
                .into_iter()
                .map(|s| PassSpec {
                    run_up_um: PARK_APPROACH_UM + RUN_UP_S * s.velocity_um_per_s,
                    ..s
                })
                .collect();
            worst_shifted = worst_shifted.max(on(shifted).abs());
        }
        assert!(worst_shifted > 1e-4, "{worst_shifted}");
    }

    #[test]
    fn one_velocity_cannot_separate_delay_and_backlash() {
        let p = SweepPlan {
            cycles: 1,
            ..plan()
        };
        let passes: Vec<PassData> = p
            .passes()
            .into_iter()
            .map(|s| pass(s, 0.004, 1.0))
            .collect();
        assert!(matches!(
            estimate_delay(&passes),
            Err(SweepError::NoDelay(_))
        ));
    }

    #[test]
    fn acceleration_zones_are_left_out() {
        let p = plan();
        let spec = p.passes()[2]; // 200 µm/s
        let d = pass(spec, 0.0, 0.0);
        let at = frames_at(&d, 0.0);
        assert!(!at.is_empty());
        let da = 200.0f64.powi(2) / 4000.0;
        let (p0, p1) = spec.ends_um();
        for f in &at {
            assert!(
                f.cmd_um >= p0 + da - 0.5 && f.cmd_um <= p1 - da + 0.5,
                "{f:?}"
            );
        }
        // Frames exist only where the velocity is the pass's.
        assert!(at.len() < d.frames.len());
        let g = resample(&at, &p.grid(true), p.step_um);
        assert!(g.iter().all(Option::is_some), "the whole range is covered");
    }

    proptest::proptest! {
        /// Interpolated positions stay between their bracketing samples,
        /// and a constant error resamples to itself in every covered cell
        /// whatever the frame spacing, never to a made-up value.
        #[test]
        fn interpolation_and_resampling_are_bounded(
            dts in proptest::collection::vec(0.001f64..0.05, 2..40),
            v in -500.0f64..500.0,
            e in -5.0f64..5.0,
            spacing in 0.5f64..12.0,
            q in 0.0f64..1.0,
        ) {
            let mut t = 0.0;
            let samples: Vec<PosSample> = dts.iter().map(|dt| {
                t += dt;
                PosSample { t_s: t, pos_um: 100.0 + v * t }
            }).collect();
            let (t0, t1) = (samples[0].t_s, samples[samples.len() - 1].t_s);
            let tq = t0 + q * (t1 - t0);
            if let Some((p, vel)) = position_at(&samples, tq) {
                let (lo, hi) = (100.0 + v * t0, 100.0 + v * t1);
                proptest::prop_assert!(p >= lo.min(hi) - 1e-6 && p <= lo.max(hi) + 1e-6);
                proptest::prop_assert!((vel - v).abs() < 1e-6 * (1.0 + v.abs()) + 1e-3);
            }
            let frames: Vec<FrameAt> = (0..60).map(|k| FrameAt {
                cmd_um: f64::from(k) * spacing,
                e_scan_um: e,
                e_held_um: -e,
                t_s: f64::from(k),
                theta_urad: 0.0,
                quality: 50.0,
            }).collect();
            let grid: Vec<f64> = (0..80).map(|k| f64::from(k) * 5.0).collect();
            for g in resample(&frames, &grid, 5.0).into_iter().flatten() {
                proptest::prop_assert!((g.e_scan_um - e).abs() < 1e-9);
                proptest::prop_assert!((g.e_held_um + e).abs() < 1e-9);
                proptest::prop_assert!(g.pos_um <= 59.0 * spacing + 7.5);
            }
        }
    }
}
