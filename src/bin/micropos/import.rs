//! `micropos import EXPORT --out LOG.csv`: an ISO 230-2 export (a CSV of
//! target, reading, direction, cycle, an ecmc-style `.dat` of targets
//! and forward/backward readings per cycle, or an ecmc markdown test
//! report's tables of readings) converted into the measurement
//! log format, so `diagnose`, `plot` and `tables build` read it without a
//! hand-edited file.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{bail, Context, Result};
use micropos::charact::import::{import_bytes, DirectionLabels, ImportFormat, ImportOptions, Unit};
use micropos::model::Axis;

/// Arguments of `micropos import`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// The export: a CSV with a header (columns target, reading or
    /// deviation, direction, cycle; see docs/measurement-log.md) or a
    /// `.dat` of `TGT_DATA[i]`, `REF_DATA_FWD[i,j]`, `REF_DATA_BWD[i,j]`.
    pub input: PathBuf,
    /// The measurement log to write (refused if it exists).
    #[arg(long)]
    pub out: PathBuf,
    /// The axis the export measured; the other is logged as unmeasured.
    #[arg(long, default_value = "x", value_parser = parse_axis)]
    pub axis: Axis,
    /// Units of every length in the export (m, mm, um, nm); default: the
    /// CSV header's suffixes (`target_mm`), or the `.dat`'s UNIT (mm).
    #[arg(long, value_parser = parse_unit)]
    pub units: Option<Unit>,
    /// Input format: auto (a `.dat` when it has TGT_DATA/REF_DATA keys, a
    /// markdown report when it has pipe tables, else CSV), csv, dat or
    /// report.
    #[arg(long, default_value = "auto", value_parser = parse_format)]
    pub format: ImportFormat,
    /// How a markdown report's forward/backward headings are read: auto
    /// (as labelled, except ecmc's per-cycle-column tables, which print
    /// them swapped), as-labelled or swapped.
    #[arg(long, default_value = "auto", value_parser = parse_directions)]
    pub directions: DirectionLabels,
}

fn parse_directions(s: &str) -> Result<DirectionLabels, String> {
    match s {
        "auto" => Ok(DirectionLabels::Auto),
        "as-labelled" | "as-labeled" => Ok(DirectionLabels::AsLabelled),
        "swapped" => Ok(DirectionLabels::Swapped),
        _ => Err(format!(
            "{s:?} is not a direction reading (auto, as-labelled, swapped)"
        )),
    }
}

fn parse_axis(s: &str) -> Result<Axis, String> {
    match s {
        "x" => Ok(Axis::X),
        "y" => Ok(Axis::Y),
        _ => Err(format!("{s:?} is not an axis (x or y)")),
    }
}

fn parse_unit(s: &str) -> Result<Unit, String> {
    Unit::parse(s).ok_or_else(|| format!("{s:?} is not a unit (m, mm, um, nm)"))
}

fn parse_format(s: &str) -> Result<ImportFormat, String> {
    match s {
        "auto" => Ok(ImportFormat::Auto),
        "csv" => Ok(ImportFormat::Csv),
        "dat" => Ok(ImportFormat::Dat),
        "report" | "md" => Ok(ImportFormat::Report),
        _ => Err(format!("{s:?} is not a format (auto, csv, dat, report)")),
    }
}

/// Runs the subcommand.
pub fn run(args: &Args) -> Result<ExitCode> {
    let data =
        std::fs::read(&args.input).with_context(|| format!("read {}", args.input.display()))?;
    let opts = ImportOptions {
        format: args.format,
        axis: args.axis,
        units: args.units,
        source: args
            .input
            .file_name()
            .map(|n| n.to_string_lossy().into_owned()),
        directions: args.directions,
    };
    let bytes = import_bytes(&data, &opts).with_context(|| args.input.display().to_string())?;
    if args.out.exists() {
        bail!("{} exists; not overwritten", args.out.display());
    }
    std::fs::write(&args.out, &bytes).with_context(|| format!("write {}", args.out.display()))?;
    let records = bytes
        .split(|&b| b == b'\n')
        .filter(|l| !l.is_empty() && l[0] != b'#')
        .count()
        .saturating_sub(1);
    println!(
        "{records} points written to {} (axis {}, other axis unmeasured)",
        args.out.display(),
        args.axis
    );
    Ok(ExitCode::SUCCESS)
}
