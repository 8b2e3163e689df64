//! `micropos`: command-line tools (offline decoding; more subcommands come
//! from other modules). Kept tiny: parse, dispatch, map errors to exit codes.

mod decode;

use std::process::ExitCode;

use clap::{Parser, Subcommand};

/// micropos command-line tools.
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
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Commands::Decode(args) => decode::run(&args),
    };
    match result {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::from(2)
        }
    }
}
