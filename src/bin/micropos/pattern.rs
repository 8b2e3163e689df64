//! `micropos pattern export|plan`: make and choose Megarena patterns.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use clap::{Args, Subcommand};
use micropos::pattern::export::{
    write_gds, write_png_mask, write_svg, ExportLimits, GdsDate, GdsOptions, Layout, PngOptions,
    Region,
};
use micropos::pattern::plan::{plan, CameraGeometry};

/// Pattern subcommands.
#[derive(Debug, Subcommand)]
pub enum PatternCommand {
    /// Write a region of the layout for fabrication (.svg, .gds or .png).
    Export(ExportArgs),
    /// Recommend code depth and period for a range and a camera.
    Plan(PlanArgs),
}

/// `pattern export` options.
#[derive(Debug, Args)]
pub struct ExportArgs {
    /// Code depth n (4..=12).
    #[arg(long)]
    bits: u32,
    /// Period in µm.
    #[arg(long)]
    period_um: f64,
    /// Dot side in µm (default: half the period).
    #[arg(long)]
    dot_um: Option<f64>,
    /// Columns A:B (half-open, A ≤ c < B); default all.
    #[arg(long, value_parser = parse_range)]
    cols: Option<(i64, i64)>,
    /// Rows A:B (half-open); default all.
    #[arg(long, value_parser = parse_range)]
    rows: Option<(i64, i64)>,
    /// Region in µm instead of columns/rows: X0:X1,Y0:Y1 (dot centres inside, inclusive).
    #[arg(long, conflicts_with_all = ["cols", "rows"])]
    region_um: Option<String>,
    /// Output file; the extension picks the format (.svg, .gds, .png).
    #[arg(long)]
    out: PathBuf,
    /// PNG only: pixels per µm.
    #[arg(long, default_value_t = 1.0)]
    px_per_um: f64,
    /// PNG only: black dots on white (default: white dots on black).
    #[arg(long)]
    black_dots: bool,
    /// GDSII only: layer number.
    #[arg(long, default_value_t = 1)]
    layer: u16,
    /// GDSII only: cell name.
    #[arg(long, default_value = "MEGARENA")]
    cell: String,
    /// Refuse SVG/GDS files with more dots than this.
    #[arg(long, default_value_t = ExportLimits::default().max_dots)]
    max_dots: u64,
    /// Refuse PNG masks with more pixels than this.
    #[arg(long, default_value_t = ExportLimits::default().max_png_pixels)]
    max_png_pixels: u64,
}

/// `pattern plan` options.
#[derive(Debug, Args)]
pub struct PlanArgs {
    /// Wanted range along x, µm.
    #[arg(long)]
    range_x_um: f64,
    /// Wanted range along y, µm.
    #[arg(long)]
    range_y_um: f64,
    /// Camera width, px.
    #[arg(long)]
    width_px: u32,
    /// Camera height, px.
    #[arg(long)]
    height_px: u32,
    /// Pixel size at the object, µm (or give --sensor-pixel-um and --magnification).
    #[arg(long, required_unless_present_all = ["sensor_pixel_um", "magnification"])]
    pixel_um: Option<f64>,
    /// Sensor pixel pitch, µm.
    #[arg(long, requires = "magnification", conflicts_with = "pixel_um")]
    sensor_pixel_um: Option<f64>,
    /// Optical magnification.
    #[arg(long, requires = "sensor_pixel_um")]
    magnification: Option<f64>,
    /// Print JSON instead of text.
    #[arg(long)]
    json: bool,
}

fn parse_range(s: &str) -> Result<(i64, i64), String> {
    let (a, b) = s
        .split_once(':')
        .ok_or_else(|| format!("expected A:B, got {s:?}"))?;
    let a: i64 = a.trim().parse().map_err(|e| format!("{a:?}: {e}"))?;
    let b: i64 = b.trim().parse().map_err(|e| format!("{b:?}: {e}"))?;
    if b <= a {
        return Err(format!("empty range {a}:{b} (B must exceed A)"));
    }
    Ok((a, b))
}

fn parse_region_um(s: &str, period_um: f64) -> Result<Region> {
    let (x, y) = s
        .split_once(',')
        .context("--region-um expects X0:X1,Y0:Y1")?;
    let pair = |t: &str| -> Result<(f64, f64)> {
        let (a, b) = t
            .split_once(':')
            .context("--region-um expects X0:X1,Y0:Y1")?;
        Ok((a.trim().parse()?, b.trim().parse()?))
    };
    let ((x0, x1), (y0, y1)) = (pair(x)?, pair(y)?);
    if x1 < x0 || y1 < y0 {
        bail!("--region-um bounds must be increasing");
    }
    Ok(Region::from_um(x0, x1, y0, y1, period_um)?)
}

fn export(a: ExportArgs) -> Result<()> {
    let region = match (&a.region_um, a.cols, a.rows) {
        (Some(r), _, _) => Some(parse_region_um(r, a.period_um)?),
        (None, None, None) => None,
        (None, cols, rows) => {
            let full = micropos::pattern::sequence::LineSequence::new(a.bits)?.len() as i64;
            let (c0, c1) = cols.unwrap_or((0, full));
            let (r0, r1) = rows.unwrap_or((0, full));
            Some(Region { c0, c1, r0, r1 })
        }
    };
    let layout = Layout::new(a.bits, a.period_um, a.dot_um, region)?;
    let limits = ExportLimits {
        max_dots: a.max_dots,
        max_png_pixels: a.max_png_pixels,
    };
    let ext = a
        .out
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .unwrap_or_default();
    if !matches!(ext.as_str(), "svg" | "gds" | "gds2" | "gdsii" | "png") {
        bail!(
            "{}: unknown output format; use .svg, .gds or .png",
            a.out.display()
        );
    }
    let file = File::create(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    let mut w = BufWriter::with_capacity(1 << 20, file);
    let result = match ext.as_str() {
        "svg" => write_svg(&layout, &limits, &mut w).map(|n| format!("{n} dots")),
        "png" => write_png_mask(
            &layout,
            &PngOptions {
                px_per_um: a.px_per_um,
                dots_white: !a.black_dots,
            },
            &limits,
            &mut w,
        )
        .map(|(x, y)| format!("{x}×{y} px")),
        _ => {
            let now = std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map(|d| d.as_secs())
                .unwrap_or(0);
            let options = GdsOptions {
                cell: a.cell.clone(),
                layer: a.layer,
                date: GdsDate::from_unix(now),
                ..GdsOptions::default()
            };
            write_gds(&layout, &options, &limits, &mut w).map(|n| format!("{n} dots"))
        }
    };
    let what = match result.and_then(|s| w.flush().map(|_| s).map_err(Into::into)) {
        Ok(s) => s,
        Err(e) => {
            drop(w);
            // Do not leave a truncated mask behind.
            let _ = std::fs::remove_file(&a.out);
            return Err(e).with_context(|| format!("writing {}", a.out.display()));
        }
    };
    let r = layout.region();
    println!(
        "{}: {}-bit, period {} µm, dot {:.3} µm, columns {}..{}, rows {}..{}: {what}",
        a.out.display(),
        a.bits,
        a.period_um,
        layout.dot_um(),
        r.c0,
        r.c1,
        r.r0,
        r.r1
    );
    Ok(())
}

fn plan_cmd(a: PlanArgs) -> Result<()> {
    let camera = match (a.pixel_um, a.sensor_pixel_um, a.magnification) {
        (Some(pixel_um), _, _) => CameraGeometry {
            width_px: a.width_px,
            height_px: a.height_px,
            pixel_um,
        },
        (None, Some(s), Some(m)) => CameraGeometry::from_sensor(a.width_px, a.height_px, s, m)?,
        _ => bail!("give --pixel-um, or --sensor-pixel-um with --magnification"),
    };
    let p = plan(a.range_x_um, a.range_y_um, camera)?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&p)?);
    } else {
        print!("{}", p.to_text());
    }
    if p.recommended.is_none() {
        bail!("no feasible pattern for this range and camera");
    }
    Ok(())
}

/// Runs a pattern subcommand.
pub fn run(cmd: PatternCommand) -> Result<()> {
    match cmd {
        PatternCommand::Export(a) => export(a),
        PatternCommand::Plan(a) => plan_cmd(a),
    }
}
