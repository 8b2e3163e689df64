//! `micropos paper [--model M]`: runs the paper's own procedure on a stage
//! model and sets every quantitative statement of the paper beside what the
//! model gives (median and spread over seeds). Exit 0 when every statement
//! holds, 3 when some do not (the table says which), 1 on errors.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result};
use micropos::analysis::paper::{compare, reproduce, to_text, PaperOptions};
use micropos::model::StageModel;
use serde_json::json;

/// Arguments of `micropos paper`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Stage model file (default: the built-in default,
    /// config/stage-model.toml).
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Number of seeds (1, 2, …); the statements are judged on the median.
    #[arg(long, default_value_t = 5)]
    pub seeds: u64,
    /// Time between the end of the characterization and the validations, s.
    #[arg(long, default_value_t = 0.0)]
    pub delay_s: f64,
    /// JSON on stdout instead of the table.
    #[arg(long)]
    pub json: bool,
}

/// Runs the subcommand.
pub fn run(args: &Args) -> Result<ExitCode> {
    let model = match &args.model {
        Some(p) => {
            let text = std::fs::read_to_string(p)
                .with_context(|| format!("cannot read model file {}", p.display()))?;
            StageModel::from_toml(&text).with_context(|| format!("model file {}", p.display()))?
        }
        None => StageModel::paper_default().context("built-in default model")?,
    };
    if args.seeds == 0 || args.seeds > 1000 {
        anyhow::bail!("--seeds must be between 1 and 1000, got {}", args.seeds);
    }
    let opts = PaperOptions {
        validation_delay_s: args.delay_s,
        ..PaperOptions::default()
    };
    let runs = (1..=args.seeds)
        .map(|s| reproduce(&model, &opts, s).with_context(|| format!("seed {s}")))
        .collect::<Result<Vec<_>>>()?;
    let checks = compare(&runs);
    if args.json {
        let v = json!({"statements": checks, "runs": runs, "options": opts});
        println!("{}", serde_json::to_string_pretty(&v)?);
    } else {
        print!("{}", to_text(&checks, &runs));
    }
    Ok(if checks.iter().all(|c| c.holds) {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(3)
    })
}
