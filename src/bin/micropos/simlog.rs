//! `micropos simlog --seed N [--effect KIND] --out LOG.csv`: a synthetic
//! characterization log from the simulated stage with one hidden effect,
//! to try `micropos diagnose` on.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{bail, Context, Result};
use micropos::analysis::generate::{
    draw_effect, simulate_log, truth_model, SimPlan, GENERATED_KINDS,
};
use micropos::analysis::FindingKind;
use micropos::model::StageModel;

/// Arguments of `micropos simlog`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Seed of everything random (effect, temperature history, noise).
    #[arg(long)]
    pub seed: u64,
    /// Hidden effect kind (position_periodic, scale, localized, time_drift,
    /// time_periodic, reversal, cross_axis, temperature), `none`, or
    /// omitted for one drawn from the seed.
    #[arg(long)]
    pub effect: Option<String>,
    /// Output log (must not exist).
    #[arg(long)]
    pub out: PathBuf,
    /// Also write the truth model (base + hidden term) here: `hil-sim
    /// --model` can run it.
    #[arg(long)]
    pub truth: Option<PathBuf>,
    /// Base model (default: the built-in paper default).
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Scan step, µm.
    #[arg(long, default_value_t = 20.0)]
    pub step: f64,
    /// Print the hidden effect (spoils the game).
    #[arg(long)]
    pub reveal: bool,
}

/// Runs the subcommand.
pub fn run(args: &Args) -> Result<ExitCode> {
    let base = match &args.model {
        Some(p) => StageModel::from_toml(
            &std::fs::read_to_string(p).with_context(|| format!("read {}", p.display()))?,
        )?,
        None => StageModel::paper_default()?,
    };
    let plan = SimPlan {
        step_um: args.step,
        ..SimPlan::default()
    };
    let effect = match args.effect.as_deref() {
        Some("none") => None,
        None => Some(draw_effect(args.seed, None, &plan)?),
        Some(k) => match FindingKind::parse(k) {
            Some(kind) if GENERATED_KINDS.contains(&kind) => {
                Some(draw_effect(args.seed, Some(kind), &plan)?)
            }
            _ => bail!(
                "unknown effect `{k}` (known: none, {})",
                GENERATED_KINDS.map(|k| k.as_str()).join(", ")
            ),
        },
    };
    let truth = truth_model(&base, effect.as_ref(), &plan, args.seed)?;
    let log = simulate_log(&truth, &plan, args.seed)?;
    let bytes = log.to_bytes()?;
    use std::io::Write;
    let mut f = std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(&args.out)
        .with_context(|| format!("create {}", args.out.display()))?;
    f.write_all(&bytes)?;
    if let Some(t) = &args.truth {
        std::fs::write(t, truth.to_toml()?).with_context(|| format!("write {}", t.display()))?;
    }
    println!(
        "{} points written to {}",
        log.records.len(),
        args.out.display()
    );
    if args.reveal {
        match &effect {
            Some(e) => println!(
                "hidden: {} (axis {}, component {}) {}",
                e.kind,
                e.axis,
                e.component,
                serde_json::to_string(&e.params)?
            ),
            None => println!("hidden: none"),
        }
    }
    Ok(ExitCode::SUCCESS)
}
