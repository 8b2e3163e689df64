//! `micropos decode IMAGE…`: absolute position of pattern images.
//!
//! Each argument is a file, a directory (all PNG/TIFF/JPEG files in it,
//! sorted) or a glob pattern with `*`/`?` in the file name. One output line
//! per image; with several images each line carries the file name. The exit
//! code is 0 when every image decoded, 1 when any failed.
//!
//! What the numbers can be trusted for: the code read is checked against
//! `--bits` (a frame of another code depth is an error naming the depth that
//! fits; a view too short to tell says so in a warning), and with
//! `--pixel-um` the measured dot pitch against `--period` (a wrong period is
//! an error naming the period that fits). Without `--pixel-um` the period
//! cannot be checked, and the output says that too.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{bail, Context, Result};
use micropos::imageio::load_frame;
use micropos::pattern::decode::{DecodeError, DecodeOptions, Decoder, Polarity};

/// Arguments of `micropos decode`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Image files, directories or globs (PNG 8/16-bit, TIFF, JPEG).
    #[arg(required = true)]
    pub images: Vec<String>,
    /// Pattern period, µm. Every position scales with it; give --pixel-um
    /// so that a wrong period is caught.
    #[arg(long)]
    pub period: f64,
    /// Code depth n of the pattern (4..=12). Checked against the code read:
    /// a frame of another depth is refused with the depth that fits.
    #[arg(long)]
    pub bits: u32,
    /// The camera's pixel size on the pattern, µm (sensor pixel ÷
    /// magnification). Checks --period against the measured dot pitch
    /// (within 5 %); a frame where they disagree is refused with the period
    /// that fits.
    #[arg(long, value_name = "UM")]
    pub pixel_um: Option<f64>,
    /// The optical path mirrors the image.
    #[arg(long)]
    pub mirrored: bool,
    /// Dot polarity: auto, bright or dark.
    #[arg(long, default_value = "auto")]
    pub polarity: String,
    /// One JSON object per line.
    #[arg(long)]
    pub json: bool,
}

fn is_image(p: &Path) -> bool {
    p.extension()
        .and_then(|e| e.to_str())
        .map(|e| {
            matches!(
                e.to_ascii_lowercase().as_str(),
                "png" | "tif" | "tiff" | "jpg" | "jpeg"
            )
        })
        .unwrap_or(false)
}

/// Simple wildcard match (`*`, `?`) on one file name.
fn wildcard(pat: &[u8], name: &[u8]) -> bool {
    match (pat.first(), name.first()) {
        (None, None) => true,
        (Some(b'*'), _) => {
            wildcard(&pat[1..], name) || (!name.is_empty() && wildcard(pat, &name[1..]))
        }
        (Some(b'?'), Some(_)) => wildcard(&pat[1..], &name[1..]),
        (Some(a), Some(b)) if a == b => wildcard(&pat[1..], &name[1..]),
        _ => false,
    }
}

fn expand(arg: &str) -> Result<Vec<PathBuf>> {
    let p = Path::new(arg);
    if p.is_dir() {
        let mut v: Vec<PathBuf> = std::fs::read_dir(p)
            .with_context(|| format!("reading directory {arg}"))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.is_file() && is_image(p))
            .collect();
        v.sort();
        return Ok(v);
    }
    let name = p.file_name().and_then(|n| n.to_str()).unwrap_or("");
    if name.contains('*') || name.contains('?') {
        let dir = match p.parent() {
            Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
            _ => PathBuf::from("."),
        };
        let mut v: Vec<PathBuf> = std::fs::read_dir(&dir)
            .with_context(|| format!("reading directory {}", dir.display()))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|q| {
                q.file_name()
                    .and_then(|n| n.to_str())
                    .is_some_and(|n| wildcard(name.as_bytes(), n.as_bytes()))
            })
            .collect();
        v.sort();
        return Ok(v);
    }
    Ok(vec![p.to_path_buf()])
}

/// Runs the subcommand; `Ok(exit code)` unless the arguments are unusable.
pub fn run(args: &Args) -> Result<ExitCode> {
    let mut opts = DecodeOptions::new(args.period, args.bits);
    opts.mirrored = args.mirrored;
    opts.pixel_um = args.pixel_um;
    opts.polarity = match args.polarity.as_str() {
        "auto" => Polarity::Auto,
        "bright" => Polarity::BrightDots,
        "dark" => Polarity::DarkDots,
        other => bail!("--polarity must be auto, bright or dark, not {other:?}"),
    };
    let mut decoder = Decoder::new(opts).context("decoder options")?;
    let mut files = Vec::new();
    for a in &args.images {
        files.extend(expand(a)?);
    }
    if files.is_empty() {
        bail!("no image files match {:?}", args.images);
    }
    let many = files.len() > 1;
    let mut failed = false;
    for f in &files {
        let name = f.display().to_string();
        let res = load_frame(f)
            .map_err(|e| e.to_string())
            .and_then(|frame| decoder.decode(&frame).map_err(|e| error_text(&e, args)));
        match (res, args.json) {
            (Ok(d), true) => {
                let c = &d.details.code_check;
                let mut v = serde_json::json!({
                    "x_um": d.x_um, "y_um": d.y_um, "theta_rad": d.theta_rad,
                    "pixel_um": d.pixel_um, "quality": d.quality,
                    "code_margin_bits": d.details.code_margin_bits,
                    "code_lines": c.lines,
                    "code_mismatches": c.mismatches,
                    "code_confirmed": c.confirmed,
                    "period_checked": args.pixel_um.is_some(),
                    "warnings": warnings(&d, args),
                });
                if many {
                    v["file"] = serde_json::Value::String(name);
                }
                println!("{v}");
            }
            (Ok(d), false) => {
                let prefix = if many {
                    format!("{name}: ")
                } else {
                    String::new()
                };
                println!(
                    "{prefix}x = {:.3} µm, y = {:.3} µm, θ = {:.6} rad ({:.4}°), pixel = {:.6} µm, {}",
                    d.x_um,
                    d.y_um,
                    d.theta_rad,
                    d.theta_rad.to_degrees(),
                    d.pixel_um,
                    crate::fmt::margin_words(d.quality)
                );
                for w in warnings(&d, args) {
                    println!("{prefix}warning: {w}");
                }
            }
            (Err(e), true) => {
                failed = true;
                let mut v = serde_json::json!({ "error": e });
                if many {
                    v["file"] = serde_json::Value::String(name);
                }
                println!("{v}");
            }
            (Err(e), false) => {
                failed = true;
                let prefix = if many {
                    format!("{name}: ")
                } else {
                    String::new()
                };
                println!("{prefix}error: {e}");
            }
        }
    }
    Ok(if failed {
        ExitCode::from(1)
    } else {
        ExitCode::SUCCESS
    })
}

/// What the result cannot vouch for.
fn warnings(d: &micropos::pattern::decode::Decoded, args: &Args) -> Vec<String> {
    let mut w = Vec::new();
    let c = &d.details.code_check;
    if !c.confirmed {
        w.push(format!(
            "only {} and {} code lines read ({} and {} disagreeing): too few to confirm the \
             {}-bit code depth (a random reading matches that well ~{:.2} times), so a wrong --bits \
             would go unnoticed; a larger view confirms it",
            c.lines[0], c.lines[1], c.mismatches[0], c.mismatches[1], args.bits, c.chance
        ));
    }
    if args.pixel_um.is_none() {
        w.push(format!(
            "--period {} not checked (the dots are {:.2} px apart; give --pixel-um to check it)",
            args.period,
            args.period / d.pixel_um
        ));
    }
    w
}

/// The error with the flag that would fix it.
fn error_text(e: &DecodeError, args: &Args) -> String {
    match e {
        DecodeError::CodeDepthMismatch { fits_bits, .. } => {
            format!("{e}: try --bits {fits_bits}")
        }
        DecodeError::ScaleMismatch { fits_period_um, .. } => {
            format!(
                "{e}: try --period {fits_period_um:.3}, or check --pixel-um {}",
                args.pixel_um.unwrap_or(f64::NAN)
            )
        }
        e => e.to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::wildcard;

    #[test]
    fn wildcards() {
        assert!(wildcard(b"*.png", b"a.png"));
        assert!(wildcard(b"f?.jpg", b"f1.jpg"));
        assert!(!wildcard(b"*.png", b"a.jpg"));
    }
}
