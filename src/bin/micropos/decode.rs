//! `micropos decode IMAGE…`: absolute position of pattern images.
//!
//! Each argument is a file, a directory (all PNG/TIFF/JPEG files in it,
//! sorted) or a glob pattern with `*`/`?` in the file name. One output line
//! per image; with several images each line carries the file name. The exit
//! code is 0 when every image decoded, 1 when any failed.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{bail, Context, Result};
use micropos::imageio::load_frame;
use micropos::pattern::decode::{DecodeOptions, Decoder, Polarity};

/// Arguments of `micropos decode`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Image files, directories or globs (PNG 8/16-bit, TIFF, JPEG).
    #[arg(required = true)]
    pub images: Vec<String>,
    /// Pattern period, µm.
    #[arg(long)]
    pub period: f64,
    /// Code depth n of the pattern (4..=12).
    #[arg(long)]
    pub bits: u32,
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
            .and_then(|frame| decoder.decode(&frame).map_err(|e| e.to_string()));
        match (res, args.json) {
            (Ok(d), true) => {
                let mut v = serde_json::json!({
                    "x_um": d.x_um, "y_um": d.y_um, "theta_rad": d.theta_rad,
                    "pixel_um": d.pixel_um, "quality": d.quality,
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
                    "{prefix}x = {:.4} µm, y = {:.4} µm, θ = {:.6} rad ({:.4}°), pixel = {:.6} µm, code margin {:.1} bits",
                    d.x_um,
                    d.y_um,
                    d.theta_rad,
                    d.theta_rad.to_degrees(),
                    d.pixel_um,
                    d.quality
                );
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
