//! `micropos camera list|grab|stream`: look at what a frame source delivers.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use clap::{Args, Subcommand};
use micropos::camera::files::{write_png, FileOptions, FileTiming};
use micropos::camera::{
    backends, frame_mean, list_cameras, open_source, CameraInfo, FrameSource, OpenOptions,
    PixelFormat, SourceSpec,
};
use micropos::frame::Frame;

/// Camera subcommands.
#[derive(Debug, Subcommand)]
pub enum CameraCommand {
    /// List cameras of every compiled-in backend.
    List,
    /// Grab frames and write them as PNG (16-bit PNG for deeper frames).
    Grab {
        #[command(flatten)]
        source: SourceArgs,
        /// Output file; with --count > 1, frames go to FILE-000000.png, …
        #[arg(long)]
        out: PathBuf,
        /// Number of frames to write.
        #[arg(long, default_value_t = 1)]
        count: u64,
    },
    /// Print sequence, timestamp, mean and frame rate of each frame.
    Stream {
        #[command(flatten)]
        source: SourceArgs,
        /// Stop after this many frames (default: until the source ends).
        #[arg(long)]
        count: Option<u64>,
    },
}

/// Which source, and its settings.
#[derive(Debug, Args)]
pub struct SourceArgs {
    /// v4l2:/dev/videoN | genicam[:ID] | files:DIR_OR_GLOB
    #[arg(long)]
    source: SourceSpec,
    /// Exposure time in µs.
    #[arg(long)]
    exposure_us: Option<f64>,
    /// Analog gain in dB.
    #[arg(long)]
    gain_db: Option<f64>,
    /// Pixel format: Mono8, Mono10, Mono12, Mono14, Mono16 or YUYV.
    #[arg(long)]
    pixel_format: Option<PixelFormat>,
    /// Acquisition frame rate in Hz (cameras) or replay rate (files).
    #[arg(long)]
    rate_hz: Option<f64>,
    /// Seconds to wait for a frame before giving up.
    #[arg(long, default_value_t = 5.0)]
    timeout_s: f64,
    /// Replay: start over after the last file.
    #[arg(long)]
    r#loop: bool,
    /// Replay: with --rate-hz, deliver frames no faster than the rate.
    #[arg(long)]
    pace: bool,
}

impl SourceArgs {
    fn open(&self) -> Result<Box<dyn FrameSource>> {
        if !(self.timeout_s.is_finite() && self.timeout_s > 0.0) {
            bail!("--timeout-s must be a positive number of seconds");
        }
        let is_files = matches!(self.source, SourceSpec::Files { .. });
        let options = OpenOptions {
            timeout: Duration::from_secs_f64(self.timeout_s.min(86_400.0)),
            files: FileOptions {
                looping: self.r#loop,
                timing: match (is_files, self.rate_hz) {
                    (true, Some(rate_hz)) => FileTiming::Rate { rate_hz },
                    _ => FileTiming::FileOrder,
                },
                pace: self.pace,
                bit_depth: None,
            },
        };
        let mut src = open_source(&self.source, &options)
            .with_context(|| format!("opening {}", self.source))?;
        if let Some(f) = self.pixel_format {
            src.set_pixel_format(f)?;
        }
        if let Some(e) = self.exposure_us {
            let got = src.set_exposure_us(e)?;
            eprintln!("exposure {got:.1} µs");
        }
        if let Some(g) = self.gain_db {
            let got = src.set_gain_db(g)?;
            eprintln!("gain {got:.2} dB");
        }
        if let (Some(r), false) = (self.rate_hz, is_files) {
            let got = src.set_frame_rate_hz(r)?;
            eprintln!("frame rate {got:.3} Hz");
        }
        Ok(src)
    }
}

/// The source and what its frames are, from `frame` (`sim … : 1024×768
/// Mono10 (10 bit)`). Why from the frame: a source's info can be stale or
/// empty until a frame arrived (the simulated camera's says 0×0, 0 bit
/// before its first frame; a format change takes effect at the next
/// frame), and what was grabbed is what the user asks about. The info's
/// pixel format is kept only when it agrees with the frame's depth.
fn describe(info: &CameraInfo, frame: &Frame) -> String {
    let bits = frame.bit_depth();
    let format = if info.bit_depth == bits && !info.pixel_format.is_empty() {
        info.pixel_format.clone()
    } else {
        format!("Mono{bits}")
    };
    format!(
        "{} {} {}: {}×{} {format} ({bits} bit)",
        info.backend,
        info.model,
        info.serial,
        frame.width(),
        frame.height()
    )
}

/// Runs a camera subcommand.
pub fn run(cmd: CameraCommand) -> Result<()> {
    match cmd {
        CameraCommand::List => {
            let (have, missing) = backends();
            println!("backends compiled in: {}", have.join(", "));
            if !missing.is_empty() {
                println!(
                    "not compiled in: {} (rebuild with --features {})",
                    missing.join(", "),
                    missing.join(",")
                );
            }
            for (backend, result) in list_cameras() {
                match result {
                    Ok(cams) if cams.is_empty() => println!("{backend}: no cameras found"),
                    Ok(cams) => {
                        for c in cams {
                            println!("{}\t{}", c.source, c.description);
                        }
                    }
                    Err(e) => println!("{backend}: cannot enumerate: {e}"),
                }
            }
            println!("files: replay with --source files:DIR_OR_GLOB");
            Ok(())
        }
        CameraCommand::Grab { source, out, count } => {
            if count == 0 {
                bail!("--count must be at least 1");
            }
            let mut src = source.open()?;
            for k in 0..count {
                let frame = src.next_frame().context("grabbing a frame")?;
                if k == 0 {
                    eprintln!("{}", describe(&src.info(), &frame));
                }
                let path = if count == 1 {
                    out.clone()
                } else {
                    let stem = out.with_extension("");
                    PathBuf::from(format!("{}-{k:06}.png", stem.display()))
                };
                write_png(&frame, &path)?;
                println!(
                    "{}\tseq {}\tt {:.6} s\t{}×{} {} bit",
                    path.display(),
                    frame.sequence,
                    frame.timestamp_s,
                    frame.width(),
                    frame.height(),
                    frame.bit_depth()
                );
            }
            Ok(())
        }
        CameraCommand::Stream { source, count } => {
            let mut src = source.open()?;
            let mut n = 0u64;
            let mut last_t: Option<f64> = None;
            let mut errors_in_a_row = 0u32;
            let started = Instant::now();
            println!("seq\ttimestamp_s\tmean\tfps");
            while count.is_none_or(|c| n < c) {
                let frame = match src.next_frame() {
                    Ok(f) => {
                        errors_in_a_row = 0;
                        f
                    }
                    Err(micropos::camera::CameraError::EndOfStream { .. }) => break,
                    Err(e) => {
                        eprintln!("frame error: {e}");
                        errors_in_a_row += 1;
                        if errors_in_a_row >= 10 {
                            bail!("10 frame errors in a row, last: {e}");
                        }
                        n += 1;
                        continue;
                    }
                };
                if n == 0 {
                    eprintln!("{}", describe(&src.info(), &frame));
                }
                let fps = last_t
                    .map(|t| frame.timestamp_s - t)
                    .filter(|dt| *dt > 0.0)
                    .map_or(String::from("-"), |dt| format!("{:.2}", 1.0 / dt));
                last_t = Some(frame.timestamp_s);
                println!(
                    "{}\t{:.6}\t{:.2}\t{fps}",
                    frame.sequence,
                    frame.timestamp_s,
                    frame_mean(&frame)
                );
                n += 1;
            }
            let secs = started.elapsed().as_secs_f64();
            eprintln!("{n} frames in {secs:.2} s");
            Ok(())
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Issue 33: a 1024 × 768 10-bit frame was announced as "0×0 Mono8 (0
    /// bit)" from the simulated camera's info before its first frame.
    #[test]
    fn the_description_is_the_frames_not_a_stale_infos() {
        let pixels = micropos::frame::Pixels::U16(vec![0; 1024 * 768]);
        let frame = Frame::new(1024, 768, 10, pixels, 0.0, 0).unwrap();
        let empty = CameraInfo {
            backend: "sim",
            model: "m".into(),
            serial: "s".into(),
            width: 0,
            height: 0,
            pixel_format: "Mono8".into(),
            bit_depth: 0,
        };
        assert_eq!(
            describe(&empty, &frame),
            "sim m s: 1024×768 Mono10 (10 bit)"
        );
        let agreeing = CameraInfo {
            pixel_format: "Mono10".into(),
            bit_depth: 10,
            ..empty
        };
        assert_eq!(
            describe(&agreeing, &frame),
            "sim m s: 1024×768 Mono10 (10 bit)"
        );
    }
}
