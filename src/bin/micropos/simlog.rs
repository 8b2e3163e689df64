//! `micropos simlog --seed N [--effect KIND] --out LOG.csv`: a synthetic
//! characterization log from the simulated stage with one hidden effect,
//! to try `micropos diagnose` on. `--extra-column` adds logged quantities
//! the model has no input for (humidity, pressure), optionally with an
//! effect that follows one: what `diagnose` reports as kind `other`.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{bail, Context, Result};
use micropos::analysis::generate::{
    add_extra_column, draw_effect, simulate_log, truth_model, SimPlan, GENERATED_KINDS,
};
use micropos::analysis::FindingKind;
use micropos::model::{Axis, StageModel};

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
    /// Adds a logged numeric column (a wandering, humidity-like quantity
    /// drawn from the seed), repeatable: `NAME` only logs it;
    /// `NAME:AXIS:UM_PER_UNIT` (e.g. `humidity_pct:x:0.05`) also moves the
    /// measured AXIS position by UM_PER_UNIT × (value − its mean), an
    /// effect the model cannot express (`diagnose` reports kind `other`).
    /// Not in the `--truth` model (it has no input for the column).
    #[arg(long = "extra-column", value_name = "NAME[:AXIS:UM_PER_UNIT]")]
    pub extra_column: Vec<String>,
}

/// One `--extra-column` value.
#[derive(Debug, Clone, PartialEq)]
struct ExtraColumn {
    name: String,
    effect: Option<(Axis, f64)>,
}

/// Parses `NAME` or `NAME:AXIS:UM_PER_UNIT`. The name itself is checked
/// by the log format when the column is added (empty, repeated, a standard
/// column).
fn parse_extra_column(spec: &str) -> Result<ExtraColumn> {
    let usage = "expected NAME or NAME:AXIS:UM_PER_UNIT, e.g. humidity_pct or humidity_pct:x:0.05";
    let parts: Vec<&str> = spec.split(':').collect();
    let (name, effect) = match parts.as_slice() {
        [name] => (*name, None),
        [name, axis, k] => {
            let axis = match axis.trim() {
                "x" | "X" => Axis::X,
                "y" | "Y" => Axis::Y,
                other => bail!("--extra-column {spec:?}: axis must be x or y, got {other:?}"),
            };
            let k: f64 = k.trim().parse().map_err(|e| {
                anyhow::anyhow!("--extra-column {spec:?}: UM_PER_UNIT {k:?} is not a number ({e})")
            })?;
            if !k.is_finite() {
                bail!("--extra-column {spec:?}: UM_PER_UNIT must be finite, got {k}");
            }
            (*name, Some((axis, k)))
        }
        _ => bail!("--extra-column {spec:?}: {usage}"),
    };
    if name.trim().is_empty() {
        bail!("--extra-column {spec:?}: the column name is empty ({usage})");
    }
    Ok(ExtraColumn {
        name: name.to_owned(),
        effect,
    })
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
    let extra = args
        .extra_column
        .iter()
        .map(|s| parse_extra_column(s))
        .collect::<Result<Vec<_>>>()?;
    let truth = truth_model(&base, effect.as_ref(), &plan, args.seed)?;
    let mut log = simulate_log(&truth, &plan, args.seed)?;
    for (i, c) in extra.iter().enumerate() {
        // A series of its own per column, reproducible from the seed.
        let seed = args.seed ^ (0xE7C0_u64 + i as u64);
        add_extra_column(&mut log, &c.name, seed, c.effect)
            .with_context(|| format!("--extra-column {:?}", c.name))?;
    }
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
        for c in &extra {
            match c.effect {
                Some((axis, k)) => println!(
                    "hidden: measured {axis} follows column {} by {k} µm per unit",
                    c.name
                ),
                None => println!("column {}: logged only, no effect", c.name),
            }
        }
    }
    Ok(ExitCode::SUCCESS)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn extra_column_specs() {
        assert_eq!(
            parse_extra_column("humidity_pct").unwrap(),
            ExtraColumn {
                name: "humidity_pct".into(),
                effect: None
            }
        );
        assert_eq!(
            parse_extra_column("p_hpa:Y:-0.25").unwrap(),
            ExtraColumn {
                name: "p_hpa".into(),
                effect: Some((Axis::Y, -0.25))
            }
        );
        for (bad, why) in [
            ("h:z:1", "axis must be x or y"),
            ("h:x:abc", "not a number"),
            ("h:x:inf", "finite"),
            ("h:x", "expected NAME"),
            ("h:x:1:2", "expected NAME"),
            (":x:1", "name is empty"),
            ("", "name is empty"),
        ] {
            let e = parse_extra_column(bad).unwrap_err().to_string();
            assert!(e.contains(why), "{bad}: {e}");
        }
    }
}
