//! `micropos`: the command-line tool (offline tools and, later, the daemon
//! client). Each subcommand lives in its own module; this file only wires
//! them up.

mod camera;
mod pattern;

use anyhow::Result;
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
    /// Cameras and other frame sources: list, grab, stream.
    #[command(subcommand)]
    Camera(camera::CameraCommand),
    /// Megarena patterns: export for fabrication, plan depth and period.
    #[command(subcommand)]
    Pattern(pattern::PatternCommand),
}

fn main() -> Result<()> {
    match Cli::parse().command {
        Commands::Camera(c) => camera::run(c),
        Commands::Pattern(c) => pattern::run(c),
    }
}
