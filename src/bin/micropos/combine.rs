//! `micropos combine ZONE.csv ZONE.csv … --out COMBINED.csv`: grid logs of
//! one stage measured zone by zone, each with its own instrument set-up,
//! combined into one map: the set-ups (offsets and cross slopes) fitted on
//! the overlaps (`analysis::grid::zones`), the table printed, the map
//! written as one grid log that `diagnose` and `tables build` read.

use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{bail, Context, Result};
use micropos::analysis::diagnose::MEASURED_AXES_KEY;
use micropos::analysis::grid::zones::{combined_log, write_text};
use micropos::analysis::grid::{combine_zones, GridMap, Zone, ZoneOptions};
use micropos::charact::log::{parse_bytes, read_file, MeasurementLog, Metadata};

/// Arguments of `micropos combine`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// The zones' grid logs (e.g. from `micropos import --format grid`),
    /// two or more, every one overlapping another by at least two rows and
    /// two columns, all linked to the reference.
    #[arg(required = true, num_args = 2..)]
    pub zones: Vec<PathBuf>,
    /// The combined log to write (refused if it exists).
    #[arg(long)]
    pub out: PathBuf,
    /// The zone whose set-up is the combined map's frame, by its place in
    /// the list (1 = the first).
    #[arg(long, default_value_t = 1)]
    pub reference: usize,
    /// Distance within which nodes of different zones are one node, µm
    /// (default: 1 % of the smallest node spacing of any zone).
    #[arg(long)]
    pub node_tol_um: Option<f64>,
}

/// Whether a log's `measured_axes` metadata, if any, names both axes.
fn measures_both(log: &MeasurementLog) -> bool {
    log.metadata.get(MEASURED_AXES_KEY).is_none_or(|v| {
        let axes: Vec<String> = v
            .split([',', ' ', ';'])
            .map(|p| p.trim().to_ascii_lowercase())
            .collect();
        axes.iter().any(|a| a == "x") && axes.iter().any(|a| a == "y")
    })
}

/// Reads one zone's log as a map.
fn read_zone(path: &Path) -> Result<(MeasurementLog, GridMap)> {
    let log = read_file(path).with_context(|| format!("log {}", path.display()))?;
    if !measures_both(&log) {
        bail!(
            "{}: its {MEASURED_AXES_KEY} metadata does not name both x and y; a zone must \
             measure both",
            path.display()
        );
    }
    let map = GridMap::from_log(&log, [true, true]).with_context(|| {
        format!(
            "{} is not a grid log (its targets do not fill a lattice of at least 3 × 3 \
             positions, half of its cells or more)",
            path.display()
        )
    })?;
    Ok((log, map))
}

/// The zones' names: their file names, or their paths when two file names
/// are the same.
fn names(paths: &[PathBuf]) -> Vec<String> {
    let file = |p: &PathBuf| {
        p.file_name().map_or_else(
            || p.display().to_string(),
            |n| n.to_string_lossy().into_owned(),
        )
    };
    let short: Vec<String> = paths.iter().map(file).collect();
    let unique = short
        .iter()
        .all(|n| short.iter().filter(|m| *m == n).count() == 1);
    if unique {
        short
    } else {
        paths.iter().map(|p| p.display().to_string()).collect()
    }
}

/// Metadata carried from the zones: each zone's `source`, and `plan` when
/// every zone has the same (the daemon's grid plan fixes how the nodes
/// were reached, which the table keeps).
fn carried(logs: &[MeasurementLog]) -> Metadata {
    let mut md = Metadata::new();
    for (k, log) in logs.iter().enumerate() {
        if let Some(s) = log.metadata.get("source") {
            md.insert(format!("zone_{}_source", k + 1), s);
        }
    }
    let plans: Vec<Option<&str>> = logs.iter().map(|l| l.metadata.get("plan")).collect();
    if let Some(Some(p)) = plans.first() {
        if plans.iter().all(|q| q == &Some(*p)) {
            md.insert("plan", *p);
        }
    }
    md
}

/// Runs the subcommand.
pub fn run(args: &Args) -> Result<ExitCode> {
    if args.out.exists() {
        bail!("{} exists; not overwritten", args.out.display());
    }
    if args.reference == 0 || args.reference > args.zones.len() {
        bail!(
            "--reference {}: there are zones 1 to {}",
            args.reference,
            args.zones.len()
        );
    }
    let (logs, maps): (Vec<_>, Vec<_>) = args
        .zones
        .iter()
        .map(|p| read_zone(p))
        .collect::<Result<Vec<_>>>()?
        .into_iter()
        .unzip();
    let zones: Vec<Zone> = names(&args.zones)
        .into_iter()
        .zip(maps)
        .map(|(name, map)| Zone { name, map })
        .collect();
    let opts = ZoneOptions {
        reference: args.reference - 1,
        node_tol_um: args.node_tol_um,
    };
    let comb = combine_zones(&zones, &opts).context("combining the zones")?;
    let mut text = String::new();
    write_text(&mut text, &comb);
    print!("{text}");
    let bytes = combined_log(&comb, &carried(&logs)).context("writing the combined log")?;
    let back = parse_bytes(&bytes).context("reading the combined log back")?;
    if GridMap::from_log(&back, [true, true]).is_none() {
        bail!(
            "the combined map fills {} of its {} × {} nodes: its log would not read as a grid \
             (the zones' lattices do not line up; a wider --node-tol-um merges nearby nodes); \
             not written",
            comb.map.filled(),
            comb.map.nx(),
            comb.map.ny()
        );
    }
    write_new(&args.out, &bytes)?;
    println!(
        "{} nodes of the combined map written to {} (in the set-up of zone {})",
        comb.map.filled(),
        args.out.display(),
        zones[opts.reference].name
    );
    Ok(ExitCode::SUCCESS)
}

/// Writes `bytes` to a new file `out` (never over an existing one).
fn write_new(out: &Path, bytes: &[u8]) -> Result<()> {
    let mut f = std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(out)
        .with_context(|| format!("{}: not written (exists?)", out.display()))?;
    f.write_all(bytes)
        .and_then(|()| f.sync_all())
        .with_context(|| format!("write {}", out.display()))
}
