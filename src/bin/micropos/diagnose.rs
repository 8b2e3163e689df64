//! `micropos diagnose LOG.csv`: what the stage model (the simulation) gets
//! wrong about a measurement log — findings with held-out gains, plots, and
//! an extended model file.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result};
use micropos::analysis::comp_gain::{compare_compensation, CompGainOptions};
use micropos::analysis::{diagnose, DiagnoseOptions};
use micropos::charact::log::read_file;
use micropos::model::StageModel;

/// Arguments of `micropos diagnose`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Measurement log (micropos measurement log format, any writer).
    pub log: PathBuf,
    /// Stage model file (default: the built-in paper default,
    /// config/stage-model.toml).
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Write plots (PNG + SVG) into this directory.
    #[arg(long)]
    pub plots: Option<PathBuf>,
    /// JSON report on stdout instead of text.
    #[arg(long)]
    pub json: bool,
    /// Write the extended model (base fit + findings) to this file.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Close the loop on a simulated rig: run the paper's square and
    /// random-target validations on a stage running this model file (the
    /// rig that has the effect, e.g. `micropos simlog --truth`), compensated
    /// by the original (base-fitted) and by the extended model, and report
    /// ISO 9283 AP/RP of both.
    #[arg(long, value_name = "RIG_MODEL.toml")]
    pub validate_on: Option<PathBuf>,
    /// Held-out z-score a finding must reach.
    #[arg(long, default_value_t = DiagnoseOptions::default().z_threshold)]
    pub z: f64,
    /// Held-out RMS gain (%) a finding must reach.
    #[arg(long, default_value_t = DiagnoseOptions::default().min_gain_pct)]
    pub min_gain: f64,
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
    let log = read_file(&args.log).with_context(|| format!("log {}", args.log.display()))?;
    for w in log.warnings.iter().take(5) {
        eprintln!("warning: {}: {w:?}", args.log.display());
    }
    let opts = DiagnoseOptions {
        z_threshold: args.z,
        min_gain_pct: args.min_gain,
        ..DiagnoseOptions::default()
    };
    let d = diagnose(&log, &model, &opts).context("diagnose")?;
    if let Some(dir) = &args.plots {
        let files = micropos::plot::diagnosis::write_all(&d, dir)
            .with_context(|| format!("plots into {}", dir.display()))?;
        if !args.json {
            println!("{} plot files in {}", files.len(), dir.display());
        }
    }
    if let Some(out) = &args.out {
        let text = d
            .extended_model
            .to_toml()
            .context("render extended model")?;
        std::fs::write(out, text).with_context(|| format!("write {}", out.display()))?;
        if !args.json {
            println!("extended model written to {}", out.display());
        }
    }
    let gain = match &args.validate_on {
        Some(p) => {
            let text = std::fs::read_to_string(p)
                .with_context(|| format!("cannot read rig model file {}", p.display()))?;
            let rig = StageModel::from_toml(&text)
                .with_context(|| format!("rig model file {}", p.display()))?;
            let end_s = log
                .records
                .iter()
                .map(|r| r.t_s)
                .filter(|t| t.is_finite())
                .fold(0.0, f64::max);
            let opts = CompGainOptions {
                start_time_s: end_s + 60.0,
                ..CompGainOptions::default()
            };
            Some(
                compare_compensation(&rig, &d.base_model, &d.extended_model, &opts)
                    .context("validation on the simulated rig")?,
            )
        }
        None => None,
    };
    let text = if args.json {
        let mut j = d.to_json();
        if let Some(g) = &gain {
            j["compensation"] = serde_json::to_value(g)?;
        }
        serde_json::to_string_pretty(&j)? + "\n"
    } else {
        let mut t = d.to_text();
        if let Some(g) = &gain {
            t += "\n";
            t += &g.to_text();
        }
        t
    };
    // A closed pipe (`| head`) is not a reason to panic.
    use std::io::Write;
    let _ = std::io::stdout().lock().write_all(text.as_bytes());
    Ok(ExitCode::SUCCESS)
}
