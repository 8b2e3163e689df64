//! `micropos axes`: the two axes through the driver (the same code path the
//! daemon uses): `status`, `reference`, `move X_UM Y_UM`.
//!
//! The axes are given either as two ports (`--port-x`, `--port-y`), as one
//! daisy-chained port (`--daisy-chain --port`, X at address 1 and Y at 2 by
//! default), or by a TOML file with a `[driver]` table (`--config`).

use anyhow::Context;
use micropos::driver::{AxisEvent, AxisStatus, DriverConfig, DriverError, Stage};
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;
use tokio::sync::broadcast;

/// Longest time `move` waits for both axes to arrive.
const MOVE_TIMEOUT: Duration = Duration::from_secs(120);

/// Arguments of `micropos axes`.
#[derive(Debug, clap::Args)]
#[command(group(clap::ArgGroup::new("wiring").required(true).args(["port_x", "port", "config"])))]
pub struct AxesArgs {
    /// Serial device of the X controller.
    #[arg(long, requires = "port_y", conflicts_with_all = ["port", "config"])]
    port_x: Option<PathBuf>,
    /// Serial device of the Y controller.
    #[arg(long, requires = "port_x")]
    port_y: Option<PathBuf>,
    /// Both controllers on one line (needs --port).
    #[arg(long, requires = "port")]
    daisy_chain: bool,
    /// The daisy-chained line (needs --daisy-chain).
    #[arg(long, requires = "daisy_chain", conflicts_with = "config")]
    port: Option<PathBuf>,
    /// Daisy-chain address of X.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u8).range(1..=16))]
    address_x: u8,
    /// Daisy-chain address of Y.
    #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u8).range(1..=16))]
    address_y: u8,
    /// Baud rate of the line(s).
    #[arg(long, default_value_t = 115_200)]
    baud: u32,
    /// Answer timeout in milliseconds.
    #[arg(long, default_value_t = 1000, value_parser = clap::value_parser!(u64).range(1..))]
    timeout_ms: u64,
    /// TOML file with a `[driver]` table (see config/driver.example.toml)
    /// instead of the port options.
    #[arg(long)]
    config: Option<PathBuf>,
    #[command(subcommand)]
    action: Action,
}

#[derive(Debug, clap::Subcommand)]
enum Action {
    /// Identification, travel, reference state, servo, position of both axes.
    Status,
    /// Reference both axes (servo on, FRF/FNL/FPL per configuration). The stage moves.
    Reference,
    /// Move both axes to absolute positions in µm, printing positions on the way.
    #[command(allow_negative_numbers = true)]
    Move {
        /// X target, µm.
        x_um: f64,
        /// Y target, µm.
        y_um: f64,
        /// Velocity for both axes, µm/s (default: leave as is).
        #[arg(long)]
        velocity_um_per_s: Option<f64>,
    },
}

fn config(a: &AxesArgs) -> anyhow::Result<DriverConfig> {
    if let Some(path) = &a.config {
        let text =
            std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
        let value: toml::Table =
            toml::from_str(&text).with_context(|| format!("parsing {}", path.display()))?;
        let table = match value.get("driver") {
            Some(toml::Value::Table(t)) => t.clone(),
            _ => value,
        };
        let cfg: DriverConfig = table
            .try_into()
            .with_context(|| format!("the driver settings in {}", path.display()))?;
        return Ok(cfg);
    }
    let mut cfg = DriverConfig::default();
    for ax in [&mut cfg.x, &mut cfg.y] {
        ax.baud = a.baud;
        ax.timeout_ms = a.timeout_ms;
    }
    match (&a.port_x, &a.port_y, &a.port) {
        (Some(x), Some(y), _) => {
            cfg.x.port = x.clone();
            cfg.y.port = y.clone();
        }
        (_, _, Some(bus)) => {
            cfg.x.port = bus.clone();
            cfg.y.port = bus.clone();
            cfg.x.address = Some(a.address_x);
            cfg.y.address = Some(a.address_y);
        }
        _ => anyhow::bail!("give --port-x and --port-y, or --daisy-chain --port, or --config"),
    }
    Ok(cfg)
}

/// Runs the action.
pub async fn run(a: AxesArgs) -> anyhow::Result<ExitCode> {
    let cfg = config(&a)?;
    let (events, mut rx) = broadcast::channel(256);
    let stage = Stage::connect(&cfg, events)
        .await
        .context("bringing up the axes")?;
    let result = match a.action {
        Action::Status => status(&stage).await,
        Action::Reference => reference(&stage).await,
        Action::Move {
            x_um,
            y_um,
            velocity_um_per_s,
        } => move_to(&stage, x_um, y_um, velocity_um_per_s).await,
    };
    while let Ok(e) = rx.try_recv() {
        match e {
            AxisEvent::Connected { .. } | AxisEvent::Referenced { .. } => {}
            other => eprintln!("note: {other:?}"),
        }
    }
    result.map(|()| ExitCode::SUCCESS)
}

fn fmt_um(v: Option<f64>) -> String {
    v.map_or_else(
        || "unknown (not referenced)".to_owned(),
        |v| format!("{v:.3} µm"),
    )
}

async fn status(stage: &Stage) -> anyhow::Result<()> {
    for ax in [&stage.x, &stage.y] {
        let id = ax.identity();
        let (min, max) = ax.travel_um();
        println!(
            "{}: {} serial {} firmware {} on {}",
            ax.name(),
            id.model,
            id.serial,
            id.firmware,
            ax.controller().label()
        );
        let AxisStatus {
            referenced,
            servo_on,
            on_target,
            position_um,
            target_um,
            velocity_um_per_s,
        } = ax
            .status()
            .await
            .with_context(|| format!("status of axis {}", ax.name()))?;
        println!("   travel {min:.3} .. {max:.3} µm, velocity {velocity_um_per_s:.1} µm/s");
        println!(
            "   referenced {}, servo {}, on target {}",
            yes(referenced),
            if servo_on { "on" } else { "off" },
            yes(on_target)
        );
        println!(
            "   position {}, target {}",
            fmt_um(position_um),
            fmt_um(target_um)
        );
    }
    Ok(())
}

fn yes(b: bool) -> &'static str {
    if b {
        "yes"
    } else {
        "no"
    }
}

async fn reference(stage: &Stage) -> anyhow::Result<()> {
    eprintln!("referencing x and y (the stage moves)...");
    let (x, y) = tokio::join!(stage.x.reference(), stage.y.reference());
    let x = x.context("referencing axis x")?;
    let y = y.context("referencing axis y")?;
    println!("referenced: x = {x:.3} µm, y = {y:.3} µm");
    Ok(())
}

async fn move_to(stage: &Stage, x_um: f64, y_um: f64, velocity: Option<f64>) -> anyhow::Result<()> {
    // Refuse the move as a whole: neither axis moves if one target is bad
    // or one axis is not referenced (checked again by `move_abs_both_um`,
    // after the velocity, which must not change for a refused move).
    stage.x.check_target_um(x_um).context("axis x")?;
    stage.y.check_target_um(y_um).context("axis y")?;
    for axis in [&stage.x, &stage.y] {
        if !axis.is_referenced().await? {
            return Err(DriverError::NotReferenced {
                axis: axis.name().to_owned(),
            })
            .context("nothing was moved");
        }
    }
    if let Some(v) = velocity {
        stage.x.set_velocity_um_per_s(v).await?;
        stage.y.set_velocity_um_per_s(v).await?;
    }
    stage
        .move_abs_both_um(x_um, y_um)
        .await
        .context("moving both axes")?;
    let start = std::time::Instant::now();
    loop {
        let (px, py) = tokio::join!(stage.x.position_um(), stage.y.position_um());
        let (px, py) = (px.context("axis x")?, py.context("axis y")?);
        let (ox, oy) = tokio::join!(stage.x.on_target(), stage.y.on_target());
        let done = ox.context("axis x")? && oy.context("axis y")?;
        println!(
            "x = {px:.3} µm  y = {py:.3} µm{}",
            if done { "  (on target)" } else { "" }
        );
        if done {
            return Ok(());
        }
        if start.elapsed() > MOVE_TIMEOUT {
            anyhow::bail!("the axes did not reach their targets within {MOVE_TIMEOUT:?}; they were left moving");
        }
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
}
