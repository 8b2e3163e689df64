//! `micropos`: the command-line tool (offline tools and, later, the daemon
//! client). Each subcommand lives in its own module; this file only wires
//! them up and maps outcomes to exit codes scripts can rely on:
//! 0 success, 1 a runtime failure (device, decode, I/O), 2 a usage error.

mod camera;
mod decode;
mod pattern;

use std::process::ExitCode;

use clap::{Parser, Subcommand};

/// micropos command-line tool.
#[derive(Debug, Parser)]
#[command(name = "micropos", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Commands,
}

#[derive(Debug, Subcommand)]
enum Commands {
    /// Decode the absolute position of Megarena pattern image(s).
    Decode(decode::Args),
    /// Cameras and other frame sources: list, grab, stream.
    #[command(subcommand)]
    Camera(camera::CameraCommand),
    /// Megarena patterns: export for fabrication, plan depth and period.
    #[command(subcommand)]
    Pattern(pattern::PatternCommand),
}

/// Maps a subcommand that only succeeds or fails to an exit code.
fn done(r: anyhow::Result<()>) -> anyhow::Result<ExitCode> {
    r.map(|()| ExitCode::SUCCESS)
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let (result, failure) = match cli.command {
        // decode reports per-image failures itself (exit 1); an error here
        // means unusable arguments.
        Commands::Decode(args) => (decode::run(&args), 2),
        Commands::Camera(c) => (done(camera::run(c)), 1),
        Commands::Pattern(c) => (done(pattern::run(c)), 1),
    };
    match result {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::from(failure)
        }
    }
}
