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
use micropos::charact::import_grid::{
    import_grid_bytes, is_grid_export, ErrorSign, GridImportOptions,
};
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
    /// Input format: auto (a 2-D grid when it is a header-plus-rows export
    /// with `:START` or a CSV naming x and y targets, a `.dat` when it has
    /// TGT_DATA/REF_DATA keys, a markdown report when it has pipe tables,
    /// else CSV), grid, csv, dat or report.
    #[arg(long, default_value = "auto", value_parser = parse_format)]
    pub format: Format,
    /// Sign of a 2-D grid CSV's error columns: meas-minus-target (ISO
    /// 230-2's deviation) or target-minus-meas.
    #[arg(long, default_value = "meas-minus-target", value_parser = parse_sign)]
    pub error_sign: ErrorSign,
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

/// A 1-D ISO 230-2 format, or a 2-D grid.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    /// One of the 1-D formats (or auto).
    OneAxis(ImportFormat),
    /// A 2-D grid export (`charact::import_grid`).
    Grid,
}

fn parse_format(s: &str) -> Result<Format, String> {
    match s {
        "auto" => Ok(Format::OneAxis(ImportFormat::Auto)),
        "csv" => Ok(Format::OneAxis(ImportFormat::Csv)),
        "dat" => Ok(Format::OneAxis(ImportFormat::Dat)),
        "report" | "md" => Ok(Format::OneAxis(ImportFormat::Report)),
        "grid" => Ok(Format::Grid),
        _ => Err(format!(
            "{s:?} is not a format (auto, grid, csv, dat, report)"
        )),
    }
}

fn parse_sign(s: &str) -> Result<ErrorSign, String> {
    match s {
        "meas-minus-target" => Ok(ErrorSign::MeasuredMinusTarget),
        "target-minus-meas" => Ok(ErrorSign::TargetMinusMeasured),
        _ => Err(format!(
            "{s:?} is not an error sign (meas-minus-target, target-minus-meas)"
        )),
    }
}

/// Runs the subcommand.
pub fn run(args: &Args) -> Result<ExitCode> {
    let data =
        std::fs::read(&args.input).with_context(|| format!("read {}", args.input.display()))?;
    let source = args
        .input
        .file_name()
        .map(|n| n.to_string_lossy().into_owned());
    let grid = match args.format {
        Format::Grid => true,
        Format::OneAxis(ImportFormat::Auto) => is_grid_export(&data),
        Format::OneAxis(_) => false,
    };
    if grid {
        let opts = GridImportOptions {
            units: args.units,
            error_sign: args.error_sign,
            source,
        };
        let bytes =
            import_grid_bytes(&data, &opts).with_context(|| args.input.display().to_string())?;
        let records = write_new(&args.out, &bytes)?;
        println!(
            "{records} points of a 2-D grid written to {} (both axes measured)",
            args.out.display()
        );
        return Ok(ExitCode::SUCCESS);
    }
    let format = match args.format {
        Format::OneAxis(f) => f,
        Format::Grid => ImportFormat::Auto,
    };
    let opts = ImportOptions {
        format,
        axis: args.axis,
        units: args.units,
        source,
        directions: args.directions,
    };
    let bytes = import_bytes(&data, &opts).with_context(|| args.input.display().to_string())?;
    let records = write_new(&args.out, &bytes)?;
    println!(
        "{records} points written to {} (axis {}, other axis unmeasured)",
        args.out.display(),
        args.axis
    );
    Ok(ExitCode::SUCCESS)
}

/// Writes `bytes` to `out`, which must not exist; returns the records.
fn write_new(out: &std::path::Path, bytes: &[u8]) -> Result<usize> {
    if out.exists() {
        bail!("{} exists; not overwritten", out.display());
    }
    std::fs::write(out, bytes).with_context(|| format!("write {}", out.display()))?;
    Ok(bytes
        .split(|&b| b == b'\n')
        .filter(|l| !l.is_empty() && l[0] != b'#')
        .count()
        .saturating_sub(1))
}
