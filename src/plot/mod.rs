//! Plot infrastructure: simple x–y charts (scatter and lines) written as
//! PNG and SVG with no system library.
//!
//! Why this shape: analyses (diagnose, later compensation and metrology
//! reports) need many similar plots — residuals against a variable,
//! periodograms, before/after — that a person opens in a browser or an
//! image viewer. A [`Chart`] is plain data (title, axis labels, series), so
//! the numeric code builds it without knowing plotters; [`render`] draws it
//! with `plotters` through its pure-Rust bitmap and SVG backends. Text uses
//! the DejaVu Sans font shipped in `assets/fonts/` (registered once through
//! plotters' `ab_glyph` feature), so no fontconfig/freetype is needed.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use plotters::coord::Shift;
use plotters::prelude::*;
use thiserror::Error;

pub mod charact;
pub mod diagnosis;
pub mod figure;
pub mod report;
pub mod validation;

pub use figure::Format;
pub use report::{plot_logs, read_logs, write_all, NamedLog, Plotted};

/// The shipped font (DejaVu Sans; license in `assets/fonts/LICENSE-DejaVu.txt`).
const FONT: &[u8] = include_bytes!("../../assets/fonts/DejaVuSans.ttf");
/// Family name plots use.
const FAMILY: &str = "sans-serif";

/// Why a plot could not be written.
#[derive(Debug, Error)]
pub enum PlotError {
    /// The font could not be registered.
    #[error("plot font: {0}")]
    Font(String),
    /// Drawing or encoding failed (the message comes from plotters).
    #[error("drawing {path}: {message}")]
    Draw {
        /// File being written.
        path: PathBuf,
        /// What went wrong.
        message: String,
    },
    /// A measurement log could not be read.
    #[error("cannot read log {path}: {reason}")]
    Log {
        /// The log file.
        path: PathBuf,
        /// Why (names the line and the reason). Not a `source`: the
        /// message already holds it, so error chains do not print it twice.
        reason: crate::charact::log::LogError,
    },
    /// Nothing to plot (no log, or a log without any plottable segment).
    #[error("nothing to plot: {what}")]
    Nothing {
        /// What was missing.
        what: String,
    },
    /// The output directory could not be created.
    #[error("cannot create {path}: {source}")]
    Io {
        /// The directory.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
}

/// How a series is drawn.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mark {
    /// Small dots (residuals).
    Dots,
    /// A polyline in x order (periodograms, fits).
    Line,
}

/// One data series.
#[derive(Debug, Clone, PartialEq)]
pub struct Series {
    /// Legend text.
    pub label: String,
    /// Points `(x, y)`; non-finite ones are skipped.
    pub points: Vec<(f64, f64)>,
    /// How to draw.
    pub mark: Mark,
}

/// An x–y chart.
#[derive(Debug, Clone, PartialEq)]
pub struct Chart {
    /// Caption.
    pub title: String,
    /// x-axis label with unit.
    pub x_label: String,
    /// y-axis label with unit.
    pub y_label: String,
    /// Series, drawn in order (later on top).
    pub series: Vec<Series>,
}

const PALETTE: [RGBColor; 6] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(255, 127, 14),
    RGBColor(148, 103, 189),
    RGBColor(100, 100, 100),
];

fn font() -> Result<(), PlotError> {
    static REGISTERED: OnceLock<Result<(), String>> = OnceLock::new();
    REGISTERED
        .get_or_init(|| {
            plotters::style::register_font(FAMILY, FontStyle::Normal, FONT)
                .map_err(|_| "the shipped DejaVu font does not load".to_string())
        })
        .clone()
        .map_err(PlotError::Font)
}

fn range(chart: &Chart) -> ((f64, f64), (f64, f64)) {
    let mut xr = (f64::INFINITY, f64::NEG_INFINITY);
    let mut yr = (f64::INFINITY, f64::NEG_INFINITY);
    for s in &chart.series {
        for &(x, y) in &s.points {
            if x.is_finite() && y.is_finite() {
                xr = (xr.0.min(x), xr.1.max(x));
                yr = (yr.0.min(y), yr.1.max(y));
            }
        }
    }
    let fix = |(lo, hi): (f64, f64)| {
        if !lo.is_finite() {
            (0.0, 1.0)
        } else if hi - lo <= 0.0 {
            (lo - 0.5, hi + 0.5)
        } else {
            let pad = 0.03 * (hi - lo);
            (lo - pad, hi + pad)
        }
    };
    (fix(xr), fix(yr))
}

fn draw<DB: DrawingBackend>(root: DrawingArea<DB, Shift>, chart: &Chart) -> Result<(), String>
where
    DB::ErrorType: 'static,
{
    let e = |x: DrawingAreaErrorKind<DB::ErrorType>| x.to_string();
    root.fill(&WHITE).map_err(e)?;
    let ((x0, x1), (y0, y1)) = range(chart);
    let mut c = ChartBuilder::on(&root)
        .caption(&chart.title, (FAMILY, 20))
        .margin(12)
        .x_label_area_size(45)
        .y_label_area_size(70)
        .build_cartesian_2d(x0..x1, y0..y1)
        .map_err(e)?;
    c.configure_mesh()
        .x_desc(chart.x_label.as_str())
        .y_desc(chart.y_label.as_str())
        .label_style((FAMILY, 13))
        .axis_desc_style((FAMILY, 15))
        .light_line_style(RGBColor(235, 235, 235))
        .draw()
        .map_err(e)?;
    // Dots large enough to see on a 50-point test, small enough not to
    // merge on a 2000-point scan.
    let total: usize = chart.series.iter().map(|s| s.points.len()).sum();
    let radius = match total {
        0..=300 => 3,
        301..=2000 => 2,
        _ => 1,
    };
    for (i, s) in chart.series.iter().enumerate() {
        let color = PALETTE[i % PALETTE.len()];
        let pts = s
            .points
            .iter()
            .copied()
            .filter(|(x, y)| x.is_finite() && y.is_finite());
        let anno = match s.mark {
            Mark::Dots => c
                .draw_series(pts.map(|p| Circle::new(p, radius, color.filled())))
                .map_err(e)?,
            Mark::Line => c
                .draw_series(LineSeries::new(pts, color.stroke_width(1)))
                .map_err(e)?,
        };
        anno.label(s.label.as_str())
            .legend(move |(x, y)| Rectangle::new([(x, y - 4), (x + 14, y + 4)], color.filled()));
    }
    if chart.series.len() > 1 || chart.series.iter().any(|s| !s.label.is_empty()) {
        c.configure_series_labels()
            .label_font((FAMILY, 13))
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .draw()
            .map_err(e)?;
    }
    root.present().map_err(e)?;
    Ok(())
}

/// Writes `chart` as `<stem>.png` (1000×600) and `<stem>.svg`; returns the
/// two paths.
pub fn render(chart: &Chart, stem: &Path) -> Result<Vec<PathBuf>, PlotError> {
    font()?;
    let png = stem.with_extension("png");
    let svg = stem.with_extension("svg");
    draw(
        BitMapBackend::new(&png, (1000, 600)).into_drawing_area(),
        chart,
    )
    .map_err(|m| PlotError::Draw {
        path: png.clone(),
        message: m,
    })?;
    draw(
        SVGBackend::new(&svg, (1000, 600)).into_drawing_area(),
        chart,
    )
    .map_err(|m| PlotError::Draw {
        path: svg.clone(),
        message: m,
    })?;
    Ok(vec![png, svg])
}

/// Creates `dir` (and parents) if needed.
pub fn ensure_dir(dir: &Path) -> Result<(), PlotError> {
    std::fs::create_dir_all(dir).map_err(|source| PlotError::Io {
        path: dir.to_path_buf(),
        source,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn renders_png_and_svg() {
        let dir = tempfile::tempdir().unwrap();
        let chart = Chart {
            title: "test µm".into(),
            x_label: "x (µm)".into(),
            y_label: "y (µm)".into(),
            series: vec![
                Series {
                    label: "dots".into(),
                    points: (0..50)
                        .map(|i| (i as f64, (i as f64 * 0.3).sin()))
                        .collect(),
                    mark: Mark::Dots,
                },
                Series {
                    label: "line".into(),
                    points: vec![(0.0, 0.0), (49.0, 1.0), (f64::NAN, 2.0)],
                    mark: Mark::Line,
                },
            ],
        };
        let files = render(&chart, &dir.path().join("c")).unwrap();
        let png = std::fs::read(&files[0]).unwrap();
        assert_eq!(&png[1..4], b"PNG");
        let svg = std::fs::read_to_string(&files[1]).unwrap();
        assert!(svg.contains("<svg") && svg.contains("dots"));
        // An empty chart still renders (axes only).
        let empty = Chart {
            series: vec![],
            ..chart
        };
        render(&empty, &dir.path().join("e")).unwrap();
    }
}
