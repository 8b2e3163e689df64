//! `micropos`: the command-line tool — offline tools (decode, pattern,
//! diagnose, simlog), hardware bring-up (gcs, axes, camera) and the client of
//! the `microposd` daemon. Each subcommand lives in its own module; this file
//! only wires them up and maps outcomes to exit codes scripts can rely on:
//! 0 success, 1 a runtime failure or refusal, 2 a usage error, 3 daemon
//! unreachable.

mod axes;
mod camera;
mod client;
mod combine;
mod decode;
mod diagnose;
mod fmt;
mod gcs;
mod import;
mod paper;
mod pattern;
mod plot;
mod simlog;

use std::future::Future;
use std::process::ExitCode;

use clap::{Parser, Subcommand};

/// micropos command-line tool.
#[derive(Debug, Parser)]
#[command(name = "micropos", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Commands,
    #[command(flatten)]
    daemon: client::GlobalOpts,
}

#[derive(Debug, Subcommand)]
enum Commands {
    /// Raw GCS console to one controller (real hardware bring-up).
    Gcs(gcs::GcsArgs),
    /// Status, referencing and moves of the two axes through the driver.
    Axes(axes::AxesArgs),
    /// Decode the absolute position of Megarena pattern image(s).
    Decode(decode::Args),
    /// Cameras and other frame sources: list, grab, stream.
    #[command(subcommand)]
    Camera(camera::CameraCommand),
    /// Megarena patterns: export for fabrication, plan depth and period.
    #[command(subcommand)]
    Pattern(pattern::PatternCommand),
    /// Commands to the microposd daemon (over its Unix socket).
    #[command(flatten)]
    Daemon(client::ClientCommand),
    /// Print shell completions (bash, zsh, fish, ...).
    Completions {
        /// The shell.
        shell: clap_complete::Shell,
    },
    /// What the stage model gets wrong about a measurement log: findings,
    /// held-out gains, plots, extended model.
    Diagnose(diagnose::Args),
    /// Convert an ISO 230-2 export (CSV of target, reading, direction,
    /// cycle; or a .dat of targets and forward/backward readings per cycle)
    /// into a measurement log.
    Import(import::Args),
    /// Combine grid logs of overlapping zones of one stage, each taken
    /// with its own instrument set-up, into one map: the set-ups' offsets
    /// and cross slopes fitted on the overlaps, one grid log written.
    ///
    /// Zone k reads e = E + s_k (e = meas − target), s_k = (ox + a·(y − yc),
    /// oy + b·(x − xc)): offsets at the zone's centre (xc, yc), cross slopes
    /// a = d(ex)/dy and b = d(ey)/dx in µrad (a turn of the whole instrument
    /// by φ counter-clockwise is a = −φ, b = +φ). Printed per zone relative to
    /// the reference zone, ± 1σ, with its overlap nodes and the rms of its
    /// overlap differences; the map is written in the reference's set-up.
    /// See docs/measurement-log.md.
    Combine(combine::Args),
    /// The paper's procedure run on a stage model: every quantitative
    /// statement of the paper beside the model's figures.
    Paper(paper::Args),
    /// Synthetic characterization log with one hidden effect (try diagnose).
    Simlog(simlog::Args),
    /// The paper's figures (4, 5, 6, 10, 11) from measurement logs, PNG/SVG.
    Plot(plot::Args),
}

/// Maps a subcommand that only succeeds or fails to an exit code.
fn done(r: anyhow::Result<()>) -> anyhow::Result<ExitCode> {
    r.map(|()| ExitCode::SUCCESS)
}

/// Runs an async subcommand on a small runtime (only the commands that talk
/// to devices need one).
fn block_on<F: Future<Output = anyhow::Result<ExitCode>>>(f: F) -> anyhow::Result<ExitCode> {
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .map_err(|e| anyhow::anyhow!("cannot start the async runtime: {e}"))?;
    rt.block_on(f)
}

/// Restores the default SIGPIPE action, so `micropos … | head` ends quietly
/// like any Unix filter instead of panicking in `println!` when the reader
/// goes away (Rust ignores SIGPIPE and turns EPIPE into a panic).
fn default_sigpipe() {
    // SAFETY: called first thing in main, before any thread exists; setting a
    // signal disposition to SIG_DFL installs no handler code.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
}

fn main() -> ExitCode {
    default_sigpipe();
    let cli = Cli::parse();
    tracing_subscriber::fmt()
        .with_writer(std::io::stderr)
        .with_ansi(micropos::stderr_colour())
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("warn")),
        )
        .init();
    let (result, failure) = match cli.command {
        Commands::Gcs(a) => (block_on(gcs::run(a)), 1),
        Commands::Axes(a) => (block_on(axes::run(a)), 1),
        // decode reports per-image failures itself (exit 1); an error here
        // means unusable arguments.
        Commands::Decode(args) => (decode::run(&args), 2),
        Commands::Camera(c) => (done(camera::run(c)), 1),
        Commands::Pattern(c) => (done(pattern::run(c)), 1),
        Commands::Daemon(c) => (block_on(client::run(cli.daemon, c)), 1),
        Commands::Completions { shell } => {
            let mut cmd = <Cli as clap::CommandFactory>::command();
            clap_complete::generate(shell, &mut cmd, "micropos", &mut std::io::stdout());
            (Ok(ExitCode::SUCCESS), 1)
        }
        Commands::Diagnose(a) => (diagnose::run(&a), 1),
        Commands::Import(a) => (import::run(&a), 1),
        Commands::Combine(a) => (combine::run(&a), 1),
        Commands::Simlog(a) => (simlog::run(&a), 1),
        Commands::Paper(a) => (paper::run(&a), 1),
        Commands::Plot(a) => (plot::run(&a), 1),
    };
    match result {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {}", micropos::error_text(e.as_ref()));
            ExitCode::from(failure)
        }
    }
}
