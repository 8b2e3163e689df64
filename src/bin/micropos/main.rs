//! `micropos`: the command-line tool. Each subcommand lives in its own file;
//! this file only parses arguments and maps results to exit codes
//! (0 ok, 1 runtime error, 2 usage error).

mod axes;
mod gcs;

use clap::{Parser, Subcommand};
use std::process::ExitCode;

/// micropos command-line tool.
#[derive(Debug, Parser)]
#[command(name = "micropos", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Commands,
}

#[derive(Debug, Subcommand)]
enum Commands {
    /// Raw GCS console to one controller (real hardware bring-up).
    Gcs(gcs::GcsArgs),
    /// Status, referencing and moves of the two axes through the driver.
    Axes(axes::AxesArgs),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    tracing_subscriber::fmt()
        .with_writer(std::io::stderr)
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("warn")),
        )
        .init();
    let rt = match tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
    {
        Ok(rt) => rt,
        Err(e) => {
            eprintln!("error: cannot start the async runtime: {e}");
            return ExitCode::from(1);
        }
    };
    let result = rt.block_on(async {
        match cli.command {
            Commands::Gcs(a) => gcs::run(a).await,
            Commands::Axes(a) => axes::run(a).await,
        }
    });
    match result {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::from(1)
        }
    }
}
