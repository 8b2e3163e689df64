//! Running the paper's experiments on the simulated rig, end to end: the
//! micropos driver over the real ptys, the simulated camera, micropos's
//! decoder, ISO 9283 statistics.
//!
//! Why here: `hil-sim demo`, the done-when tests and the benchmark all need
//! the same session (start the rig, bring both axes up, move, wait on the
//! simulated clock, grab, decode) and the same vision-to-stage tie.
//!
//! Waiting: a move's profile time is skipped with a clock advance (the
//! session knows it talks to the simulator, as `micropos::clock::SimClock`
//! does), then `ONT?` is polled with small advances until both axes are on
//! target. The served clock also runs at `time_scale` × wall time so the
//! driver's wall-time polling during referencing makes progress.
//!
//! Vision → stage: micropos does not know how the pattern is mounted. The
//! tie ([`VisionTie`]) is a rigid transform (rotation + offset) fitted on
//! calibration moves along the X axis at the start of the session
//! (`calibrate`): the X axis defines the frame, as in the paper, so the
//! squareness error stays visible in Y moves, and the calibration points'
//! mean error is taken as zero.

use crate::camera::SimCameraSource;
use crate::rig::RigConfig;
use crate::serve::{AxisName, ServeConfig, SimError, SimHandle};
use micropos::camera::{CameraError, FrameSource};
use micropos::driver::{AxisEvent, DriverConfig, DriverError, Stage};
use micropos::metrology::iso9283::{self, Iso9283Error, PoseStats, PoseSummary, Xy};
use micropos::pattern::decode::{DecodeOptions, Decoder};
use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;
use tokio::sync::broadcast;

/// Why an experiment could not run.
#[derive(Debug, thiserror::Error)]
pub enum ExperimentError {
    /// The simulator failed.
    #[error("simulator: {0}")]
    Sim(#[from] SimError),
    /// The driver failed.
    #[error("driver: {0}")]
    Driver(#[from] DriverError),
    /// The camera failed.
    #[error("camera: {0}")]
    Camera(#[from] CameraError),
    /// A frame could not be decoded.
    #[error("decode at commanded ({x_um:.1}, {y_um:.1}) µm: {why}")]
    Decode {
        /// Commanded x, µm.
        x_um: f64,
        /// Commanded y, µm.
        y_um: f64,
        /// The decoder's message.
        why: String,
    },
    /// Statistics could not be computed.
    #[error("ISO 9283: {0}")]
    Iso(#[from] Iso9283Error),
    /// Anything else (setup, tie fit).
    #[error("{0}")]
    Other(String),
}

/// The paper's square (Fig. 10): corners A (10, 10), B (4010, 10),
/// C (4010, 4010), D (10, 4010) µm; `per_segment` poses on each of AB, BC,
/// CD, DA (starting at its first corner). The one definition is
/// `micropos::charact::scan::square_poses` (the daemon's validation uses it
/// too).
pub fn square_poses(per_segment: usize) -> Vec<[f64; 2]> {
    let n = per_segment.max(1);
    micropos::charact::scan::square_poses(4000.0 / n as f64)
        .map(|v| v.iter().map(|p| [p.target.x_um, p.target.y_um]).collect())
        .unwrap_or_default()
}

/// Table II of the paper: the ten random targets, µm
/// (= `micropos::charact::scan::RANDOM_TARGETS_UM`, the one definition).
pub const RANDOM_TARGETS: [[f64; 2]; 10] = {
    let t = micropos::charact::scan::RANDOM_TARGETS_UM;
    let mut out = [[0.0; 2]; 10];
    let mut i = 0;
    while i < 10 {
        out[i] = [t[i].0, t[i].1];
        i += 1;
    }
    out
};

/// Rigid map from decoded pattern positions to the stage frame:
/// `stage = Rot(φ)·(−P) + b` (the point under the image centre moves
/// against the platform).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VisionTie {
    /// Rotation φ, rad (equals the mounting angle for a perfect stage).
    pub phi_rad: f64,
    /// Offset b, µm.
    pub offset_um: [f64; 2],
}

impl VisionTie {
    /// Least-squares rigid fit (2-D Procrustes) of pattern points to stage
    /// points; needs at least two distinct points.
    pub fn fit(pairs: &[([f64; 2], [f64; 2])]) -> Result<VisionTie, String> {
        let n = pairs.len() as f64;
        if pairs.len() < 2 {
            return Err("a vision tie needs at least two points".into());
        }
        let q: Vec<[f64; 2]> = pairs.iter().map(|(p, _)| [-p[0], -p[1]]).collect();
        let e: Vec<[f64; 2]> = pairs.iter().map(|(_, s)| *s).collect();
        let qm = [
            q.iter().map(|v| v[0]).sum::<f64>() / n,
            q.iter().map(|v| v[1]).sum::<f64>() / n,
        ];
        let em = [
            e.iter().map(|v| v[0]).sum::<f64>() / n,
            e.iter().map(|v| v[1]).sum::<f64>() / n,
        ];
        let (mut sx, mut sd) = (0.0, 0.0);
        for (a, b) in q.iter().zip(&e) {
            let a = [a[0] - qm[0], a[1] - qm[1]];
            let b = [b[0] - em[0], b[1] - em[1]];
            sx += a[0] * b[1] - a[1] * b[0];
            sd += a[0] * b[0] + a[1] * b[1];
        }
        if !(sx.is_finite() && sd.is_finite()) || (sx == 0.0 && sd == 0.0) {
            return Err("vision tie: the points do not determine a rotation".into());
        }
        let phi = sx.atan2(sd);
        let (s, c) = phi.sin_cos();
        let offset = [
            em[0] - (c * qm[0] - s * qm[1]),
            em[1] - (s * qm[0] + c * qm[1]),
        ];
        Ok(VisionTie {
            phi_rad: phi,
            offset_um: offset,
        })
    }

    /// Stage-frame position of a decoded pattern point.
    pub fn to_stage(&self, pattern_um: [f64; 2]) -> [f64; 2] {
        let (s, c) = self.phi_rad.sin_cos();
        let q = [-pattern_um[0], -pattern_um[1]];
        [
            c * q[0] - s * q[1] + self.offset_um[0],
            s * q[0] + c * q[1] + self.offset_um[1],
        ]
    }
}

/// How to start a session.
#[derive(Debug, Clone)]
pub struct SessionOptions {
    /// Seed of the whole simulation.
    pub seed: u64,
    /// The rig.
    pub rig: RigConfig,
    /// Simulated seconds per wall second besides explicit advances.
    pub time_scale: f64,
    /// Take frames through the camera socket (`SimSocketSource`) instead of
    /// in process.
    pub camera_via_socket: bool,
    /// Serve the rig in process on the current runtime's clock
    /// ([`SimHandle::start_in_process`]; under a paused runtime, virtual
    /// time) instead of on ptys at `time_scale`; frames then come in
    /// process too.
    pub in_process: bool,
}

impl Default for SessionOptions {
    fn default() -> Self {
        Self {
            seed: 1,
            rig: RigConfig::default(),
            time_scale: 50.0,
            camera_via_socket: true,
            in_process: false,
        }
    }
}

/// One visit of a target.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Visit {
    /// Commanded, µm.
    pub commanded_um: [f64; 2],
    /// What the controllers report (`POS?`), µm.
    pub reported_um: [f64; 2],
    /// Decoded pattern point under the image centre, µm (pattern frame).
    pub pattern_um: [f64; 2],
    /// Ground truth (platform, stage frame), µm.
    pub true_um: [f64; 2],
    /// Simulated time of the frame, s.
    pub t_s: f64,
}

static SESSION_ID: AtomicU64 = AtomicU64::new(0);

/// A running rig with both axes brought up and referenced.
pub struct Session {
    sim: Option<SimHandle>,
    stage: Option<Stage>,
    camera: Option<Box<dyn FrameSource>>,
    decoder: Option<Decoder>,
    dir: PathBuf,
    velocity_um_s: [f64; 2],
    /// The vision tie, after [`Session::calibrate`].
    pub tie: Option<VisionTie>,
    in_process: bool,
}

impl std::fmt::Debug for Session {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Session").field("dir", &self.dir).finish()
    }
}

impl Session {
    /// Starts the rig (ptys, control and camera sockets in a fresh temporary
    /// directory), connects the driver and references both axes.
    pub async fn start(opts: SessionOptions) -> Result<Session, ExperimentError> {
        let dir = std::env::temp_dir().join(format!(
            "hil-sim-{}-{}",
            std::process::id(),
            SESSION_ID.fetch_add(1, Ordering::SeqCst)
        ));
        std::fs::create_dir_all(&dir)
            .map_err(|e| ExperimentError::Other(format!("create {}: {e}", dir.display())))?;
        let cfg = ServeConfig {
            link_dir: dir.clone(),
            time_scale: opts.time_scale,
            control_socket: (!opts.in_process).then(|| dir.join("control.sock")),
            camera_socket: (!opts.in_process).then(|| dir.join("camera.sock")),
            seed: opts.seed,
            rig: opts.rig.clone(),
            ..Default::default()
        };
        let sim = if opts.in_process {
            SimHandle::start_in_process(cfg)?
        } else {
            tokio::task::spawn_blocking(move || SimHandle::start(cfg))
                .await
                .map_err(|e| ExperimentError::Other(format!("simulator start task: {e}")))??
        };
        let mut dc = DriverConfig::default();
        dc.x.port = sim.link(AxisName::X);
        dc.y.port = sim.link(AxisName::Y);
        for a in [&mut dc.x, &mut dc.y] {
            a.timeout_ms = 1000;
            a.reference_timeout_s = 60.0;
            a.motion_timeout_s = 60.0;
        }
        let (tx, _rx) = broadcast::channel::<AxisEvent>(256);
        let stage = Stage::connect_via(&dc, tx, sim.link_opener().as_ref()).await?;
        let (rx, ry) = tokio::join!(stage.x.reference(), stage.y.reference());
        rx?;
        ry?;
        let vx = stage.x.velocity_um_per_s().await?;
        let vy = stage.y.velocity_um_per_s().await?;
        let camera: Box<dyn FrameSource> = if opts.camera_via_socket && !opts.in_process {
            let path = dir.join("camera.sock");
            tokio::task::spawn_blocking(move || {
                micropos::camera::simsocket::SimSocketSource::open(&path)
            })
            .await
            .map_err(|e| ExperimentError::Other(format!("camera open task: {e}")))
            .and_then(|r| r.map_err(ExperimentError::from))
            .map(|c| Box::new(c) as Box<dyn FrameSource>)?
        } else {
            Box::new(SimCameraSource::new(sim.camera().clone()))
        };
        let c = &opts.rig.camera;
        let decoder = Decoder::new(DecodeOptions::new(c.period_um, c.bits))
            .map_err(|e| ExperimentError::Other(format!("decoder: {e}")))?;
        Ok(Session {
            sim: Some(sim),
            stage: Some(stage),
            camera: Some(camera),
            decoder: Some(decoder),
            dir,
            velocity_um_s: [vx, vy],
            tie: None,
            in_process: opts.in_process,
        })
    }

    /// The simulator.
    pub fn sim(&self) -> Result<&SimHandle, ExperimentError> {
        self.sim
            .as_ref()
            .ok_or_else(|| ExperimentError::Other("simulator already shut down".into()))
    }

    /// The driver's stage.
    pub fn stage(&self) -> Result<&Stage, ExperimentError> {
        self.stage
            .as_ref()
            .ok_or_else(|| ExperimentError::Other("driver already closed".into()))
    }

    /// Moves both axes to `target_um`, waits on the simulated clock until
    /// both are on target, reads the controllers, grabs and decodes a frame.
    pub async fn visit(&mut self, target_um: [f64; 2]) -> Result<Visit, ExperimentError> {
        let stage = self.stage()?.clone();
        let before = [stage.x.target_um().await?, stage.y.target_um().await?];
        let (a, b) = tokio::join!(
            stage.x.move_abs_um(target_um[0]),
            stage.y.move_abs_um(target_um[1])
        );
        a?;
        b?;
        // Profile time of the longer move (trapezoid at the default
        // acceleration, 10 mm/s²) plus the 50 ms settle: skip it at once.
        let mut wait_s: f64 = 0.0;
        for i in 0..2 {
            let d = (target_um[i] - before[i]).abs();
            let v = self.velocity_um_s[i].max(1.0);
            wait_s = wait_s.max(d / v + v / 10_000.0);
        }
        self.pass(Duration::from_secs_f64(wait_s + 0.05)).await?;
        let mut polls = 0;
        loop {
            let (ox, oy) = tokio::join!(stage.x.on_target(), stage.y.on_target());
            if ox? && oy? {
                break;
            }
            polls += 1;
            if polls > 10_000 {
                return Err(ExperimentError::Other(format!(
                    "axes not on target at {target_um:?} after {polls} polls"
                )));
            }
            self.pass(Duration::from_millis(10)).await?;
        }
        let reported = [stage.x.position_um().await?, stage.y.position_um().await?];
        let (frame, pattern, cam, dec) = self.grab_decode().await?;
        self.camera = Some(cam);
        self.decoder = Some(dec);
        let truth = self.sim()?.truth();
        let pattern = pattern.map_err(|why| ExperimentError::Decode {
            x_um: target_um[0],
            y_um: target_um[1],
            why,
        })?;
        Ok(Visit {
            commanded_um: target_um,
            reported_um: reported,
            pattern_um: pattern,
            true_um: truth.true_um,
            t_s: frame,
        })
    }

    /// Lets `d` of simulated time pass: on the runtime's clock in process
    /// (the rig's clock is the runtime's), else by advancing the served
    /// clock at once.
    async fn pass(&self, d: Duration) -> Result<(), ExperimentError> {
        if self.in_process {
            tokio::time::sleep(d).await;
        } else {
            self.sim()?.advance(d);
        }
        Ok(())
    }

    /// Grab + decode on the blocking pool (a frame costs milliseconds).
    #[allow(clippy::type_complexity)]
    async fn grab_decode(
        &mut self,
    ) -> Result<(f64, Result<[f64; 2], String>, Box<dyn FrameSource>, Decoder), ExperimentError>
    {
        let (Some(mut cam), Some(mut dec)) = (self.camera.take(), self.decoder.take()) else {
            return Err(ExperimentError::Other("camera busy".into()));
        };
        let r = tokio::task::spawn_blocking(move || {
            let f = cam.next_frame();
            let ready = cam.frame_ready_after();
            let out = match f {
                Ok(f) => {
                    let t = f.timestamp_s;
                    let d = dec
                        .decode(&f)
                        .map(|d| [d.x_um, d.y_um])
                        .map_err(|e| e.to_string());
                    Ok((t, d))
                }
                Err(e) => Err(e),
            };
            (out, cam, dec, ready)
        })
        .await
        .map_err(|e| ExperimentError::Other(format!("grab task: {e}")))?;
        let (out, cam, dec, ready) = r;
        // On the virtual clock the frame exists once its exposure is over.
        if let Some(d) = ready {
            tokio::time::sleep(d).await;
        }
        match out {
            Ok((t, d)) => Ok((t, d, cam, dec)),
            Err(e) => {
                self.camera = Some(cam);
                self.decoder = Some(dec);
                Err(e.into())
            }
        }
    }

    /// Fits the vision tie on moves along X at y = 10 µm (x = 10 … 4010 µm,
    /// approached forward), the first moves of the session.
    pub async fn calibrate(&mut self) -> Result<VisionTie, ExperimentError> {
        let mut pairs = Vec::new();
        self.visit([0.0, 0.0]).await?;
        for i in 0..5 {
            let t = [10.0 + 1000.0 * i as f64, 10.0];
            let v = self.visit(t).await?;
            pairs.push((v.pattern_um, t));
        }
        let tie = VisionTie::fit(&pairs).map_err(ExperimentError::Other)?;
        self.tie = Some(tie);
        Ok(tie)
    }

    /// Visits `targets` in order, `cycles` times; returns the visits per
    /// target.
    pub async fn run(
        &mut self,
        targets: &[[f64; 2]],
        cycles: usize,
    ) -> Result<Vec<Vec<Visit>>, ExperimentError> {
        let mut out = vec![Vec::new(); targets.len()];
        for _ in 0..cycles {
            for (i, t) in targets.iter().enumerate() {
                out[i].push(self.visit(*t).await?);
            }
        }
        Ok(out)
    }

    /// Stops the simulator and removes the temporary directory.
    pub async fn shutdown(mut self) {
        self.camera = None;
        // The driver first, so it does not see its lines vanish.
        self.stage = None;
        tokio::time::sleep(Duration::from_millis(20)).await;
        if let Some(sim) = self.sim.take() {
            let _ = tokio::task::spawn_blocking(move || sim.shutdown()).await;
        }
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

impl Drop for Session {
    fn drop(&mut self) {
        self.stage = None;
        if let Some(sim) = self.sim.take() {
            sim.shutdown();
        }
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

/// ISO 9283 results of one experiment, measured by vision (tied to the stage
/// frame) and, for comparison, from the ground truth.
#[derive(Debug, Clone)]
pub struct Accuracy {
    /// Per-pose statistics, vision.
    pub vision: Vec<PoseStats>,
    /// Summary, vision.
    pub vision_summary: PoseSummary,
    /// Summary, ground truth (platform position).
    pub truth_summary: PoseSummary,
}

/// AP/RP of visits per target, with `tie` mapping vision to the stage frame.
pub fn accuracy(
    targets: &[[f64; 2]],
    visits: &[Vec<Visit>],
    tie: &VisionTie,
) -> Result<Accuracy, ExperimentError> {
    let mut vision = Vec::new();
    let mut truth = Vec::new();
    for (t, vs) in targets.iter().zip(visits) {
        let target = Xy::new(t[0], t[1]);
        let vis: Vec<Xy> = vs
            .iter()
            .map(|v| {
                let s = tie.to_stage(v.pattern_um);
                Xy::new(s[0], s[1])
            })
            .collect();
        let tru: Vec<Xy> = vs
            .iter()
            .map(|v| Xy::new(v.true_um[0], v.true_um[1]))
            .collect();
        vision.push(iso9283::pose_stats(target, &vis)?);
        truth.push(iso9283::pose_stats(target, &tru)?);
    }
    Ok(Accuracy {
        vision_summary: iso9283::summarize_poses(&vision)?,
        truth_summary: iso9283::summarize_poses(&truth)?,
        vision,
    })
}

/// `hil-sim demo`: see the crate README.
pub async fn demo(seed: u64, rig: RigConfig) -> Result<(), ExperimentError> {
    let wall = std::time::Instant::now();
    println!("hil-sim demo: starting the simulated rig (seed {seed}, in process on the virtual clock) and bringing both axes up through the micropos driver...");
    let mut s = Session::start(SessionOptions {
        seed,
        rig,
        in_process: true,
        ..Default::default()
    })
    .await?;
    let stage = s.stage()?.clone();
    for (name, ax) in [("x", &stage.x), ("y", &stage.y)] {
        let id = ax.identity();
        println!(
            "  axis {name}: {} {} serial {}, referenced at {:.3} µm",
            id.vendor,
            id.model,
            id.serial,
            ax.position_um().await?
        );
    }
    println!("calibrating the camera-to-stage tie: 5 moves along X at y = 10 µm (x = 10..4010 µm); the tie is a rigid fit (rotation + offset) on them");
    let tie = s.calibrate().await?;
    println!(
        "  tie: rotation {:.4}° (true mounting {:.4}°), offset ({:.1}, {:.1}) µm",
        tie.phi_rad.to_degrees(),
        s.sim()?.rig().mounting().theta_deg,
        tie.offset_um[0],
        tie.offset_um[1]
    );
    println!(
        "{:>22} {:>22} {:>22} {:>22} {:>8}",
        "commanded µm", "controller µm", "vision µm", "TRUE (ground truth) µm", "sim s"
    );
    for t in [
        [10.0, 4010.0],
        [4010.0, 4010.0],
        [3471.0, 2311.0],
        [8196.0, 186.0],
        [1035.0, 35.0],
    ] {
        let v = s.visit(t).await?;
        let m = tie.to_stage(v.pattern_um);
        println!(
            "({:>9.3},{:>9.3}) ({:>9.3},{:>9.3}) ({:>9.3},{:>9.3}) ({:>9.3},{:>9.3}) {:>8.2}",
            t[0],
            t[1],
            v.reported_um[0],
            v.reported_um[1],
            m[0],
            m[1],
            v.true_um[0],
            v.true_um[1],
            v.t_s
        );
    }
    let sim_s = s.sim()?.sim_time().as_secs_f64();
    drop(stage);
    s.shutdown().await;
    println!(
        "done: {sim_s:.1} simulated s in {:.2} wall s. The controllers report the commanded position; vision and truth show the stage errors (squareness, leadscrew, backlash).",
        wall.elapsed().as_secs_f64()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rig::Mounting;

    #[test]
    fn the_tie_recovers_a_mounting() {
        let m = Mounting::default();
        let pairs: Vec<_> = [
            [10.0, 10.0],
            [2000.0, 10.0],
            [4010.0, 10.0],
            [4010.0, 3000.0],
        ]
        .iter()
        .map(|s| (m.pattern_point(*s), *s))
        .collect();
        let tie = VisionTie::fit(&pairs).unwrap();
        assert!((tie.phi_rad - m.theta_deg.to_radians()).abs() < 1e-12);
        let s = tie.to_stage(m.pattern_point([1234.0, 567.0]));
        assert!((s[0] - 1234.0).abs() < 1e-9 && (s[1] - 567.0).abs() < 1e-9);
        assert!(VisionTie::fit(&pairs[..1]).is_err());
        assert_eq!(square_poses(2).len(), 8);
    }
}
