//! `hil-sim`: serve simulated C-863 controllers on pseudo-terminals.

use anyhow::Context;
use clap::{Parser, Subcommand};
use hil_sim::{AxisName, ServeConfig, SimHandle};
use std::io::Write;
use std::path::PathBuf;

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
        /// Unix socket for JSON-lines fault injection.
        #[arg(long)]
        control: Option<PathBuf>,
        /// Seed for serial numbers and power-up carriage positions.
        #[arg(long, default_value_t = 0)]
        seed: u64,
    },
}

#[tokio::main(flavor = "current_thread")]
async fn main() -> anyhow::Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("warn")),
        )
        .with_writer(std::io::stderr)
        .init();
    let cli = Cli::parse();
    match cli.cmd {
        Cmd::Serve {
            link_dir,
            daisy_chain,
            time_scale,
            control,
            seed,
        } => {
            let cfg = ServeConfig {
                link_dir,
                daisy_chain,
                time_scale,
                control_socket: control,
                seed,
            };
            // Handlers first: a signal right after the ready line must
            // already end in a clean shutdown.
            use tokio::signal::unix::{signal, SignalKind};
            let mut term = signal(SignalKind::terminate()).context("install SIGTERM handler")?;
            let mut int = signal(SignalKind::interrupt()).context("install SIGINT handler")?;
            let sim = tokio::task::spawn_blocking(move || SimHandle::start(cfg))
                .await
                .context("simulator start task")?
                .context("start simulator")?;
            let line = if daisy_chain {
                format!("hil-sim ready bus={}", sim.link(AxisName::X).display())
            } else {
                format!(
                    "hil-sim ready x={} y={}",
                    sim.link(AxisName::X).display(),
                    sim.link(AxisName::Y).display()
                )
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
            tokio::task::spawn_blocking(move || sim.shutdown())
                .await
                .context("simulator shutdown task")?;
            Ok(())
        }
    }
}
