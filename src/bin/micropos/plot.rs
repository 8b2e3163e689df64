//! `micropos plot LOG... --out DIR`: the paper's figures from measurement
//! logs — Figs. 4, 5, 6 from characterization scans, Figs. 10, 11 from
//! validation runs — as PNG and/or SVG, each log's own; `--compare` draws
//! the validation logs given in one figure per trajectory, one series per
//! log and mode.

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
    /// Compare the validation logs given: one Fig. 10 / Fig. 11 over all of
    /// them (`validation_fig10_square`, …), a series per log and mode
    /// labelled `mode (log)`, instead of figures per log. Records of one
    /// mode from different logs are never pooled.
    #[arg(long)]
    pub compare: bool,
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
    let p = plot_logs(&logs, &args.out, args.format, args.compare)
        .with_context(|| format!("plotting into {}", args.out.display()))?;
    for n in &p.notes {
        eprintln!("note: {n}");
    }
    for f in &p.files {
        println!("{}", f.display());
    }
    Ok(ExitCode::SUCCESS)
}
