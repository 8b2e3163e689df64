//! `micropos plot LOG... --out DIR`: the paper's figures from measurement
//! logs — Figs. 4, 5, 6 from characterization scans, Figs. 10, 11 from
//! validation runs — as PNG and/or SVG.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result};
use micropos::plot::{plot_logs, read_logs, Format};

/// Arguments of `micropos plot`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Measurement logs (micropos measurement log format, any writer):
    /// characterization logs (segments scan_x, scan_y) and/or validation
    /// logs (segments square, random; columns mode and pose).
    #[arg(required = true)]
    pub logs: Vec<PathBuf>,
    /// Directory for the figures (created if needed).
    #[arg(long)]
    pub out: PathBuf,
    /// File format: png, svg or both.
    #[arg(long, default_value = "both", value_parser = parse_format)]
    pub format: Format,
}

fn parse_format(s: &str) -> Result<Format, String> {
    s.parse()
}

/// Runs the subcommand: prints each file written, notes on stderr.
pub fn run(args: &Args) -> Result<ExitCode> {
    let logs = read_logs(&args.logs).context("reading the logs")?;
    for l in &logs {
        for w in l.log.warnings.iter().take(5) {
            eprintln!("warning: {}: line {}: {:?}", l.name, w.line, w.kind);
        }
    }
    let p = plot_logs(&logs, &args.out, args.format)
        .with_context(|| format!("plotting into {}", args.out.display()))?;
    for n in &p.notes {
        eprintln!("note: {n}");
    }
    for f in &p.files {
        println!("{}", f.display());
    }
    Ok(ExitCode::SUCCESS)
}
