//! `hil-sim`: serve simulated C-863 controllers on pseudo-terminals.

use anyhow::Context;
use clap::{Parser, Subcommand};
use hil_sim::clock::ManualClock;
use hil_sim::{AxisName, ServeConfig, SimHandle};
use std::io::Write;
use std::path::PathBuf;
use std::sync::Arc;

#[derive(Parser)]
#[command(
    name = "hil-sim",
    version,
    about = "Hardware-in-the-loop simulator for micropos"
)]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Serve two simulated C-863 controllers (X, Y) on ptys until SIGINT/SIGTERM.
    Serve {
        /// Directory for the symlinks to the ptys (x, y; or bus with --daisy-chain).
        #[arg(long)]
        link_dir: PathBuf,
        /// Both controllers on one pty: X at address 1, Y at address 2.
        #[arg(long)]
        daisy_chain: bool,
        /// Simulated seconds per wall second.
        #[arg(long, default_value_t = 1.0)]
        time_scale: f64,
        /// Virtual time driven by the client: simulated time stands still
        /// except for the control socket's `{"clock":"advance","s":S}` and
        /// each camera grab's exposure, never following wall time, so a
        /// client that sends the same requests in the same order gets the
        /// same answers on any machine (one seed, one transcript). A client
        /// that waits for a move in wall time (PIPython's `waitontarget`)
        /// waits forever here: it must advance the clock itself.
        #[arg(long, conflicts_with_all = ["time_scale", "genicam"])]
        manual_clock: bool,
        /// Unix socket for JSON-lines fault injection.
        #[arg(long)]
        control: Option<PathBuf>,
        /// Seed for serial numbers, power-up carriage positions, settling
        /// and camera noise.
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Rig file (model, pattern mounting, camera); default: the paper's
        /// rig (config/sim-rig.toml).
        #[arg(long)]
        rig: Option<PathBuf>,
        /// Stage model file (overrides the rig file's); default: the paper
        /// default (config/stage-model.toml).
        #[arg(long)]
        model: Option<PathBuf>,
        /// Unix socket for the simulated camera (default: DIR/camera.sock).
        #[arg(long)]
        camera_socket: Option<PathBuf>,
        /// Also serve the camera as a GigE Vision camera through aravis's
        /// fake GV camera (needs a build with the `genicam` feature); the
        /// ready line gains `genicam=ADDRESS` (open it as `genicam:ADDRESS`,
        /// e.g. `genicam:127.0.0.1`).
        #[arg(long)]
        genicam: bool,
        /// Interface (name or IPv4 address) the GigE Vision camera listens on.
        #[arg(long, default_value = "127.0.0.1", requires = "genicam")]
        genicam_interface: String,
    },
    /// Start the rig in-process, bring both axes up through the micropos
    /// driver over the ptys, move through a few targets and print commanded,
    /// controller-reported, vision-measured and true positions.
    Demo {
        /// Seed of the simulation.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Rig file (default: the paper's rig).
        #[arg(long)]
        rig: Option<PathBuf>,
    },
    /// The main job: the simulated rig plus microposd in-process, then as a
    /// socket client: reference, characterize (paper plan), a 10× shorter
    /// characterization, tables build, validate (square + Table II in raw,
    /// table, model, closed_loop); prints AP/RP next to the paper's figures.
    Run {
        /// Seed of the simulation.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Stage model file for the rig (default: the paper-faithful stage,
        /// config/stage-model-paper.toml, compiled in; the kinder default
        /// stage of the other commands: config/stage-model.toml).
        #[arg(long)]
        model: Option<PathBuf>,
        /// Rig file (default: the paper's rig).
        #[arg(long)]
        rig: Option<PathBuf>,
        /// Print exactly one JSON object on stdout (progress stays on stderr).
        #[arg(long)]
        json: bool,
        /// Directory for plots of the characterization and validation logs.
        #[arg(long)]
        plots: Option<PathBuf>,
        /// Keep the rig sockets, the daemon's data (logs, tables) and
        /// run.json here (default: a temporary directory, removed).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Reduced plan (50 µm steps, 1 cycle): a quick look, not the paper.
        #[arg(long)]
        short: bool,
        /// Distance between square poses, µm (default: the plan's, 500 on
        /// the paper plan, 1000 with --short).
        #[arg(long)]
        square_step_um: Option<f64>,
        /// Moves of varied length per cycle of the short characterization
        /// (lets the model table identify a lost motion that grows with the
        /// move length; default 40, 0 with --short).
        #[arg(long)]
        short_moves: Option<u32>,
        /// Settle time after each move of the short characterization, the
        /// validations and the sweep, s (default 0.3).
        #[arg(long)]
        settle_s: Option<f64>,
        /// Settle time per point of the paper characterization, s (default
        /// 2.0: the paper's 2.08 s per point and its 9.5 hours, and with
        /// them the thermal drift its tables carry; 0.3 with --short).
        #[arg(long)]
        paper_settle_s: Option<f64>,
        /// Spacing of the sweep row's static anchors, µm (default 250; 0 =
        /// none: the sweep's records then keep the pass's motion state).
        #[arg(long)]
        sweep_anchor_spacing_um: Option<f64>,
        /// Node pitch of the grid row's characterization, µm (default 100,
        /// 1000 with --short; 0 = no grid row).
        #[arg(long)]
        grid_pitch_um: Option<f64>,
        /// Serve the rig on ptys in real time, this many simulated seconds
        /// per wall second, instead of in process on the virtual clock
        /// (results then depend on the machine's load; default: virtual,
        /// one seed gives one result).
        #[arg(long)]
        time_scale: Option<f64>,
    },
}

fn main() -> anyhow::Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("warn")),
        )
        .with_writer(std::io::stderr)
        .with_ansi(micropos::stderr_colour())
        .init();
    let cli = Cli::parse();
    match cli.cmd {
        Cmd::Run {
            seed,
            model,
            rig,
            json,
            plots,
            out,
            short,
            square_step_um,
            short_moves,
            settle_s,
            paper_settle_s,
            sweep_anchor_spacing_um,
            grid_pitch_um,
            time_scale,
        } => main_job(
            seed,
            model,
            rig,
            json,
            plots,
            out,
            short,
            PlanFlags {
                square_step_um,
                short_moves,
                settle_s,
                paper_settle_s,
                anchor_spacing_um: sweep_anchor_spacing_um,
                grid_pitch_um,
            },
            time_scale,
        ),
        Cmd::Demo { seed, rig } => {
            let rig = match rig {
                Some(p) => hil_sim::rig::RigConfig::load(&p).map_err(anyhow::Error::msg)?,
                None => hil_sim::rig::RigConfig::default(),
            };
            // The demo's rig runs in process on the virtual clock.
            hil_sim::run::virtual_runtime()
                .context("tokio runtime")?
                .block_on(hil_sim::experiment::demo(seed, rig))
                .map_err(anyhow::Error::from)
        }
        cmd => tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .enable_all()
            .build()
            .context("tokio runtime")?
            .block_on(serve(cmd)),
    }
}

/// `hil-sim serve`.
async fn serve(cmd: Cmd) -> anyhow::Result<()> {
    match cmd {
        Cmd::Serve {
            link_dir,
            daisy_chain,
            time_scale,
            manual_clock,
            control,
            seed,
            rig,
            model,
            camera_socket,
            genicam,
            genicam_interface,
        } => {
            #[cfg(not(feature = "genicam"))]
            if genicam {
                anyhow::bail!(
                    "--genicam needs hil-sim built with the `genicam` feature (cargo build -p hil-sim --features genicam; needs libaravis-dev)"
                );
            }
            let rig = match rig {
                Some(p) => hil_sim::rig::RigConfig::load(&p).map_err(anyhow::Error::msg)?,
                None => hil_sim::rig::RigConfig::default(),
            };
            let control = control.unwrap_or_else(|| link_dir.join("control.sock"));
            let camera_socket = camera_socket.unwrap_or_else(|| link_dir.join("camera.sock"));
            let cfg = ServeConfig {
                link_dir,
                daisy_chain,
                time_scale,
                control_socket: Some(control.clone()),
                seed,
                rig,
                model,
                camera_socket: Some(camera_socket.clone()),
                stage_model: None,
                in_process: false,
            };
            // Handlers first: a signal right after the ready line must
            // already end in a clean shutdown.
            use tokio::signal::unix::{signal, SignalKind};
            let mut term = signal(SignalKind::terminate()).context("install SIGTERM handler")?;
            let mut int = signal(SignalKind::interrupt()).context("install SIGINT handler")?;
            let sim = tokio::task::spawn_blocking(move || {
                if manual_clock {
                    SimHandle::start_with_clock(cfg, Arc::new(ManualClock::new()))
                } else {
                    SimHandle::start(cfg)
                }
            })
            .await
            .context("simulator start task")?
            .context("start simulator")?;
            #[cfg(feature = "genicam")]
            let gige = if genicam {
                let camera = sim.camera().clone();
                let cfg = hil_sim::camera::gige::GigeConfig {
                    interface: genicam_interface.clone(),
                    ..Default::default()
                };
                let served = tokio::task::spawn_blocking(move || {
                    hil_sim::camera::gige::GigeCamera::start(camera, &cfg)
                })
                .await
                .context("GigE Vision camera start task")?
                .context("serve the GigE Vision camera")?;
                Some(served)
            } else {
                None
            };
            #[cfg(not(feature = "genicam"))]
            let _ = genicam_interface;
            let line = if daisy_chain {
                format!(
                    "hil-sim ready bus={} camera={} control={}",
                    sim.link(AxisName::X).display(),
                    camera_socket.display(),
                    control.display()
                )
            } else {
                format!(
                    "hil-sim ready x={} y={} camera={} control={}",
                    sim.link(AxisName::X).display(),
                    sim.link(AxisName::Y).display(),
                    camera_socket.display(),
                    control.display()
                )
            };
            let line = if manual_clock {
                format!("{line} clock=manual")
            } else {
                line
            };
            #[cfg(feature = "genicam")]
            let line = match &gige {
                // The address, not the discovered id: a client in another
                // process may discover the camera through a non-loopback
                // interface and then cannot receive its stream; opened by
                // address, aravis uses the interface that reaches it.
                Some(g) => format!("{line} genicam={}", g.interface()),
                None => line,
            };
            {
                let mut out = std::io::stdout().lock();
                writeln!(out, "{line}").context("write ready line")?;
                out.flush().context("flush ready line")?;
            }
            tokio::select! {
                _ = int.recv() => {}
                _ = term.recv() => {}
            }
            #[cfg(feature = "genicam")]
            if let Some(g) = gige {
                let stats = g.stats();
                tracing::info!(
                    "GigE Vision camera served {} frames ({:.1} frames/s, {} black)",
                    stats.frames,
                    stats.frame_rate_hz(),
                    stats.failures
                );
                tokio::task::spawn_blocking(move || g.stop())
                    .await
                    .context("GigE Vision camera stop task")?;
            }
            tokio::task::spawn_blocking(move || sim.shutdown())
                .await
                .context("simulator shutdown task")?;
            Ok(())
        }
        Cmd::Demo { .. } | Cmd::Run { .. } => {
            anyhow::bail!("demo and run start their own runtime")
        }
    }
}

/// `hil-sim run`'s flags that change its plan (absent: the plan's own).
struct PlanFlags {
    square_step_um: Option<f64>,
    short_moves: Option<u32>,
    settle_s: Option<f64>,
    paper_settle_s: Option<f64>,
    anchor_spacing_um: Option<f64>,
    grid_pitch_um: Option<f64>,
}

/// `hil-sim run`; see `hil_sim::run`.
#[allow(clippy::too_many_arguments)]
fn main_job(
    seed: u64,
    model: Option<PathBuf>,
    rig: Option<PathBuf>,
    json: bool,
    plots: Option<PathBuf>,
    out: Option<PathBuf>,
    short: bool,
    PlanFlags {
        square_step_um,
        short_moves,
        settle_s,
        paper_settle_s,
        anchor_spacing_um,
        grid_pitch_um,
    }: PlanFlags,
    time_scale: Option<f64>,
) -> anyhow::Result<()> {
    use hil_sim::run::{format_table, run, RunOptions, RunPlan};
    let rig = match rig {
        Some(p) => hil_sim::rig::RigConfig::load(&p).map_err(anyhow::Error::msg)?,
        None => hil_sim::rig::RigConfig::default(),
    };
    // Plots are drawn from the logs, so they must be kept: with --plots and
    // no --out the run directory is DIR/run.
    let out = out.or_else(|| plots.as_ref().map(|p| p.join("run")));
    // Without --model the main job simulates the paper-faithful stage
    // (compiled in, so it runs from any directory).
    let stage_model = match &model {
        Some(_) => None,
        None => Some(
            micropos::model::StageModel::from_toml(micropos::model::PAPER_FAITHFUL_TOML)
                .context("the compiled-in paper-faithful stage model")?,
        ),
    };
    let opts = RunOptions {
        seed,
        rig,
        model,
        stage_model,
        out_dir: out.clone(),
        time_scale,
        plan: {
            let mut p = if short {
                RunPlan::reduced()
            } else {
                RunPlan::paper()
            };
            if let Some(s) = square_step_um {
                anyhow::ensure!(
                    s.is_finite() && s > 0.0,
                    "--square-step-um must be a number > 0"
                );
                p.square_step_um = s;
            }
            if let Some(n) = short_moves {
                p.short_moves_per_cycle = n;
            }
            if let Some(h) = anchor_spacing_um {
                anyhow::ensure!(
                    h.is_finite() && h >= 0.0,
                    "--sweep-anchor-spacing-um must be a number ≥ 0"
                );
                p.sweep_anchor_spacing_um = h;
            }
            if let Some(g) = grid_pitch_um {
                anyhow::ensure!(
                    g.is_finite() && g >= 0.0,
                    "--grid-pitch-um must be a number ≥ 0 (0: no grid row)"
                );
                p.grid_pitch_um = g;
            }
            for (flag, value, slot) in [
                ("--settle-s", settle_s, &mut p.settle_s),
                ("--paper-settle-s", paper_settle_s, &mut p.paper_settle_s),
            ] {
                if let Some(s) = value {
                    anyhow::ensure!(
                        s.is_finite() && (0.0..=60.0).contains(&s),
                        "{flag} must be a number of seconds within 0..=60"
                    );
                    *slot = s;
                }
            }
            p
        },
    };
    let mut progress = |l: &str| eprintln!("hil-sim run: {l}");
    let report = run(opts, &mut progress)?;
    eprintln!("hil-sim run: finished in {:.1} wall s", report.wall_s);
    let walls: Vec<String> = report
        .phases_wall_s
        .iter()
        .map(|(k, v)| format!("{k} {v:.1}"))
        .collect();
    eprintln!("hil-sim run: wall s per phase: {}", walls.join(", "));
    if let Some(dir) = &report.data_dir {
        let full = serde_json::json!({"summary": report.summary, "validation": report.validation,
                                      "wall_s": report.wall_s,
                                      "phases_wall_s": serde_json::Map::from_iter(
                                          report.phases_wall_s.iter().map(|(k, v)| (k.clone(), serde_json::json!(v)))),
                                      "files": report.files});
        std::fs::write(dir.join("run.json"), format!("{full:#}\n"))
            .with_context(|| format!("writing {}", dir.join("run.json").display()))?;
        eprintln!(
            "hil-sim run: logs, tables and run.json in {}",
            dir.display()
        );
    }
    if let (Some(plots), Some(dir)) = (&plots, &report.data_dir) {
        // The paper's figures from the run's own logs, each log's own:
        // Figs. 4-6 of the characterization logs, Figs. 10-11 of each
        // validation log (the drift comparison's in figures of their own).
        let p = hil_sim::run::plot_run(dir, &report.files, plots, micropos::plot::Format::Both)
            .with_context(|| format!("drawing plots into {}", plots.display()))?;
        for n in &p.notes {
            eprintln!("hil-sim run: plot: {n}");
        }
        eprintln!(
            "hil-sim run: {} plot files in {}",
            p.files.len(),
            plots.display()
        );
    }
    if json {
        println!("{}", report.summary);
    } else {
        print!("{}", format_table(&report.summary));
    }
    Ok(())
}
