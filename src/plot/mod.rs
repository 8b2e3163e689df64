//! Plot infrastructure: x–y charts and multi-panel figures written as PNG
//! and SVG with no system library.
//!
//! Why this shape: analyses (diagnose, compensation and metrology reports)
//! need many similar plots — residuals against a variable, periodograms,
//! before/after, the paper's figures — that a person opens in a browser or
//! an image viewer. A [`Chart`] (one panel) and a [`figure::Figure`]
//! (panels in rows) are plain data, so the numeric code builds them without
//! knowing plotters; [`figure::render_figure`] draws both with `plotters`
//! through its pure-Rust bitmap and SVG backends. Text uses
//! the DejaVu Sans font shipped in `assets/fonts/` (registered once through
//! plotters' `ab_glyph` feature), so no fontconfig/freetype is needed.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use plotters::prelude::*;
use thiserror::Error;

pub mod charact;
pub mod diagnosis;
pub mod figure;
pub mod report;
#[cfg(test)]
pub(crate) mod svg_check;
pub mod validation;

pub use figure::Format;
pub use report::{figure_set, plot_logs, read_logs, write_all, FigureSet, NamedLog, Plotted};

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

/// Trace colours by index (a [`figure::Trace::color`]); index 5, grey, is
/// for references (targets). Ten, so that a comparison of several runs'
/// modes keeps one colour per series.
const PALETTE: [RGBColor; 10] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(255, 127, 14),
    RGBColor(148, 103, 189),
    RGBColor(100, 100, 100),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(188, 189, 34),
    RGBColor(23, 190, 207),
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

impl Chart {
    /// The chart as a one-panel [`figure::Figure`] of `size` pixels: its
    /// title the figure's, its series traces in palette order.
    pub fn to_figure(&self, size: (u32, u32)) -> figure::Figure {
        let traces = self
            .series
            .iter()
            .enumerate()
            .map(|(i, s)| figure::Trace {
                label: (!s.label.is_empty()).then(|| s.label.clone()),
                color: i,
                points: s.points.clone(),
                style: match s.mark {
                    Mark::Dots => figure::Style::Dots,
                    Mark::Line => figure::Style::Line,
                },
            })
            .collect();
        figure::Figure {
            title: self.title.clone(),
            rows: vec![vec![figure::Panel::Xy(figure::XyPanel {
                title: String::new(),
                x_label: self.x_label.clone(),
                y_label: self.y_label.clone(),
                traces,
                y_scale: figure::Scale::Linear,
                equal_aspect: false,
            })]],
            size,
        }
    }
}

/// Writes `chart` as `<stem>.png` (1000×600) and `<stem>.svg`; returns the
/// two paths. Drawn by [`figure::render_figure`], so a chart follows the
/// same layout rules as every figure (title fitted to the width, legend
/// below the axes).
pub fn render(chart: &Chart, stem: &Path) -> Result<Vec<PathBuf>, PlotError> {
    figure::render_figure(&chart.to_figure((1000, 600)), stem, Format::Both)
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
