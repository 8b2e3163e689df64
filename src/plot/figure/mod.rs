//! Multi-panel figures: x–y panels (lines, dashed lines, dots, crosses;
//! linear or logarithmic y) and grouped bar panels, written as PNG and/or
//! SVG. Every plot of the crate is drawn here ([`super::render`] turns a
//! one-panel [`super::Chart`] into a [`Figure`]).
//!
//! Why this shape: the paper's figures put related views side by side (one
//! panel per axis in Figs. 4–6; the trajectory, the per-pose accuracy and a
//! summary in Figs. 10–11), need several traces sharing one colour and one
//! legend entry (three cycles of a forward pass), a logarithmic scale (raw
//! 22 µm next to closed-loop 0.1 µm) and bars. [`Figure`] is plain data
//! built by the numeric code; [`render_figure`] alone knows plotters. The
//! same data serializes to JSON (`serde`: panels tagged `kind` = `xy` /
//! `bars`, points as `[x, y]`, non-finite values as `null`): the daemon's
//! `figures` command sends it and the web page draws it, so browser and
//! files show one computation.
//!
//! Layout rules, so that a figure shows its data and all its text:
//! * every title, caption and category name is fitted to the width it has
//!   (wrapped at words, then shrunk; measured with the shipped font, see
//!   [`text_extent`]), never left to run off the canvas;
//! * legends sit in a strip below their panel's axes, never on the
//!   plotting area;
//! * bar values carry their own text ([`BarGroup::value_labels`]: rounded to
//!   the resolution, with the unit) and are turned upright when they do not
//!   fit beside each other.
//!
//! Ticks are computed here (1-2-5 steps on linear axes, decades and 2/5
//! subdivisions on log axes) and handed to plotters as fixed key points, so
//! every panel has one concrete coordinate type and labels read as data
//! values (a log axis is drawn as log10 of the data with labels mapped back).

use super::{font, PlotError};
use bars::draw_bars;
use plotters::coord::Shift;
use plotters::prelude::*;
use std::path::{Path, PathBuf};
use std::str::FromStr;
use text::{draw_lines, MARGIN, TITLE_PX};
use xy::draw_xy;

mod axes;
mod bars;
mod legend;
mod text;
mod xy;

pub use text::{fit_text, text_extent, Fitted, LEGEND_DOT_RADIUS};

/// Which files a figure is written as.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Format {
    /// PNG only (bitmap, for reports and quick viewing).
    Png,
    /// SVG only (vector, text searchable, for papers).
    Svg,
    /// Both PNG and SVG.
    #[default]
    Both,
}

impl Format {
    fn png(self) -> bool {
        matches!(self, Format::Png | Format::Both)
    }
    fn svg(self) -> bool {
        matches!(self, Format::Svg | Format::Both)
    }
}

impl FromStr for Format {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.trim().to_ascii_lowercase().as_str() {
            "png" => Ok(Format::Png),
            "svg" => Ok(Format::Svg),
            "both" => Ok(Format::Both),
            other => Err(format!(
                "unknown plot format `{other}` (expected png, svg or both)"
            )),
        }
    }
}

/// How a trace is drawn.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Style {
    /// Polyline through the points in the given order.
    Line,
    /// Filled dots.
    Dots,
    /// Polyline with a dot at each point.
    LineDots,
    /// Dashed polyline (bands such as ISO 230-2's mean ± 2s).
    Dashed,
    /// Crosses (targets).
    Crosses,
}

/// One trace of an x–y panel.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Trace {
    /// Legend text; `None` keeps the trace out of the legend (e.g. the
    /// second and third cycle of a pass, which share the first one's entry).
    pub label: Option<String>,
    /// Index into the palette (traces sharing a colour share a meaning).
    pub color: usize,
    /// Points `(x, y)`; non-finite ones (and, on a log axis, y ≤ 0) are
    /// skipped.
    pub points: Vec<(f64, f64)>,
    /// How to draw it.
    pub style: Style,
}

/// Scale of the y axis.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Scale {
    /// Linear.
    #[default]
    Linear,
    /// Base-10 logarithmic (positive values only).
    Log,
}

/// An x–y panel.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct XyPanel {
    /// Panel caption.
    pub title: String,
    /// x-axis label, with unit.
    pub x_label: String,
    /// y-axis label, with unit.
    pub y_label: String,
    /// Traces, drawn in order.
    pub traces: Vec<Trace>,
    /// y scale.
    pub y_scale: Scale,
    /// Same µm per pixel on both axes (plan views of the stage).
    pub equal_aspect: bool,
}

/// One bar series of a [`BarPanel`]: one value per category.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct BarGroup {
    /// Legend text.
    pub label: String,
    /// Palette index.
    pub color: usize,
    /// Value per category; `None` = not available (no bar drawn).
    pub values: Vec<Option<f64>>,
    /// The text printed above each bar, e.g. `0.10 µm`: the value rounded
    /// to what the measurement resolves, with its unit (see
    /// [`BarGroup::labelled`]). Carried in the data so that the files and
    /// the web page print the same text; `None` (or a missing entry): the
    /// value to three significant digits.
    pub value_labels: Vec<Option<String>>,
}

impl BarGroup {
    /// A bar series whose value labels are the values rounded to
    /// `resolution` (e.g. 0.01) followed by `unit` (e.g. `µm`).
    pub fn labelled(
        label: impl Into<String>,
        color: usize,
        values: Vec<Option<f64>>,
        resolution: f64,
        unit: &str,
    ) -> Self {
        let value_labels = values
            .iter()
            .map(|v| {
                v.filter(|v| v.is_finite())
                    .map(|v| value_label(v, resolution, unit))
            })
            .collect();
        BarGroup {
            label: label.into(),
            color,
            values,
            value_labels,
        }
    }
}

/// `v` rounded to a multiple of `resolution` and printed with the decimals
/// that resolution has, then `unit`: `value_label(0.100124, 0.01, "µm")` =
/// `0.10 µm`. Why not significant digits: a value is known to the
/// measurement's resolution, whatever its size (22.08 µm and 0.05 µm alike).
pub fn value_label(v: f64, resolution: f64, unit: &str) -> String {
    let (r, decimals) = if resolution.is_finite() && resolution > 0.0 {
        let d = (-resolution.log10() - 1e-9).ceil().max(0.0) as usize;
        ((v / resolution).round() * resolution, d)
    } else {
        (v, 3)
    };
    // No "-0.00".
    let r = if r == 0.0 { 0.0 } else { r };
    if unit.is_empty() {
        format!("{r:.decimals$}")
    } else {
        format!("{r:.decimals$} {unit}")
    }
}

/// A grouped bar chart with the value printed above each bar (bars of very
/// different heights stay readable).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct BarPanel {
    /// Panel caption.
    pub title: String,
    /// Category names along x.
    pub categories: Vec<String>,
    /// x-axis label.
    pub x_label: String,
    /// y-axis label, with unit.
    pub y_label: String,
    /// The bar series.
    pub groups: Vec<BarGroup>,
}

/// A panel of a figure.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Panel {
    /// x–y traces.
    Xy(XyPanel),
    /// Grouped bars.
    Bars(BarPanel),
}

/// A figure: a title and rows of panels (each row split evenly).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Figure {
    /// Figure title (names the data it comes from).
    pub title: String,
    /// Rows of panels, top to bottom.
    pub rows: Vec<Vec<Panel>>,
    /// Size in pixels (PNG) / user units (SVG).
    pub size: (u32, u32),
}

/// A figure with the file stem it is written under (`<stem>.png` /
/// `<stem>.svg`).
#[derive(Debug, Clone, PartialEq)]
pub struct NamedFigure {
    /// File stem, e.g. `validate_fig11_random`.
    pub stem: String,
    /// The figure.
    pub figure: Figure,
}

fn draw_figure<DB: DrawingBackend>(root: DrawingArea<DB, Shift>, fig: &Figure) -> Result<(), String>
where
    DB::ErrorType: 'static,
{
    let e = |x: DrawingAreaErrorKind<DB::ErrorType>| x.to_string();
    root.fill(&WHITE).map_err(e)?;
    let (w, _) = root.dim_in_pixel();
    let title = fit_text(&fig.title, f64::from(w) - 2.0 * MARGIN, TITLE_PX, 11.0, 3);
    let title_h = if title.lines.is_empty() {
        0.0
    } else {
        draw_lines(&root, &title, (f64::from(w) / 2.0).round() as i32, 6).map_err(e)?;
        title.height() + 12.0
    };
    let (_, body) = root.split_vertically(title_h.round() as i32);
    let rows = body.split_evenly((fig.rows.len().max(1), 1));
    for (row, area) in fig.rows.iter().zip(rows) {
        let cells = area.split_evenly((1, row.len().max(1)));
        for (panel, cell) in row.iter().zip(cells) {
            match panel {
                Panel::Xy(p) => draw_xy(&cell, p)?,
                Panel::Bars(p) => draw_bars(&cell, p)?,
            }
        }
    }
    root.present().map_err(e)?;
    Ok(())
}

/// Draws `fig` into an RGB buffer and encodes it with the `image` crate the
/// decoder already uses, so plotters needs no encoder of its own (its
/// `bitmap_encoder` feature brings a second, older `image` into the build).
fn write_png(fig: &Figure, png: &Path) -> Result<(), PlotError> {
    let draw = |message: String| PlotError::Draw {
        path: png.to_path_buf(),
        message,
    };
    let (w, h) = fig.size;
    let mut rgb = vec![0u8; w as usize * h as usize * 3];
    draw_figure(
        BitMapBackend::with_buffer(&mut rgb, fig.size).into_drawing_area(),
        fig,
    )
    .map_err(draw)?;
    let img = image::RgbImage::from_raw(w, h, rgb)
        .ok_or_else(|| draw(format!("a {w}×{h} buffer of the wrong length")))?;
    img.save_with_format(png, image::ImageFormat::Png)
        .map_err(|e| draw(format!("writing the PNG: {e}")))
}

/// Writes `fig` as `<stem>.png` and/or `<stem>.svg`; returns the files.
pub fn render_figure(fig: &Figure, stem: &Path, format: Format) -> Result<Vec<PathBuf>, PlotError> {
    font()?;
    let mut out = Vec::new();
    if format.png() {
        let png = stem.with_extension("png");
        write_png(fig, &png)?;
        out.push(png);
    }
    if format.svg() {
        let svg = stem.with_extension("svg");
        draw_figure(SVGBackend::new(&svg, fig.size).into_drawing_area(), fig).map_err(|m| {
            PlotError::Draw {
                path: svg.clone(),
                message: m,
            }
        })?;
        out.push(svg);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::axes::{linear_ticks, log_ticks, tick_label};
    use super::bars::round_sig;
    use super::*;
    use crate::plot::svg_check::{circles, texts, texts_off_canvas, BoxPx};

    #[test]
    fn ticks_are_nice_and_inside() {
        assert_eq!(
            linear_ticks(0.0, 10.0, 5),
            vec![0.0, 2.0, 4.0, 6.0, 8.0, 10.0]
        );
        let t = linear_ticks(-0.37, 0.91, 8);
        assert!(t.iter().all(|v| (-0.37..=0.91).contains(v)));
        assert!(t.len() >= 4 && t.len() <= 9, "{t:?}");
        let l = log_ticks(-1.0, 1.5);
        assert!(l.contains(&0.0) && l.contains(&-1.0) && l.contains(&1.0));
        assert_eq!(tick_label(10f64.powf(l[0])), "0.1");
        assert_eq!(tick_label(2.5), "2.5");
        assert_eq!(tick_label(-0.0), "0");
        assert_eq!(round_sig(0.012345, 3), 0.0123);
        assert!("PNG".parse::<Format>().is_ok() && "gif".parse::<Format>().is_err());
    }

    fn svg_of(fig: &Figure) -> String {
        let dir = tempfile::tempdir().unwrap();
        let files = render_figure(fig, &dir.path().join("f"), Format::Svg).unwrap();
        std::fs::read_to_string(&files[0]).unwrap()
    }

    fn xy(title: &str, traces: Vec<Trace>) -> Panel {
        Panel::Xy(XyPanel {
            title: title.into(),
            x_label: "x (µm)".into(),
            y_label: "y (µm)".into(),
            traces,
            y_scale: Scale::Linear,
            equal_aspect: false,
        })
    }

    #[test]
    fn text_is_fitted_to_its_width() {
        let long = "Fig. 11: accuracy on the random points, 10 poses, up to 10 visits each; AP max (µm): raw 18.741, table 6.588, model 7.755, closed_loop 0.058 — validate.csv, validate-drift-off.csv, validate-drift-static.csv, validate-drift-adaptive.csv, validate-grid.csv";
        let f = fit_text(long, 600.0, 20.0, 11.0, 3);
        assert!(
            f.lines.len() <= 3 && f.size <= 20.0 && f.size >= 11.0,
            "{f:?}"
        );
        for l in &f.lines {
            assert!(text_extent(l, f.size).0 <= 600.0, "{l}");
        }
        assert_eq!(f.lines.join(" "), long, "nothing dropped");
        // A word longer than the line is broken, never cut off.
        let f = fit_text(&"x".repeat(400), 100.0, 20.0, 11.0, 2);
        assert_eq!(f.lines.concat(), "x".repeat(400));
        assert!(f.lines.iter().all(|l| text_extent(l, f.size).0 <= 100.0));
        assert!(fit_text("", 100.0, 20.0, 11.0, 2).lines.is_empty());
        assert_eq!(value_label(0.100124, 0.01, "µm"), "0.10 µm");
        assert_eq!(value_label(0.0572587, 0.01, "µm"), "0.06 µm");
        assert_eq!(value_label(18.7414, 0.01, "µm"), "18.74 µm");
        assert_eq!(value_label(-0.001, 0.01, "µm"), "0.00 µm");
        assert_eq!(value_label(4.26, 0.1, ""), "4.3");
    }

    /// Titles and captions far wider than the canvas: every text the SVG
    /// holds lies on the canvas (plotters alone centres them and cuts
    /// both ends).
    #[test]
    fn titles_and_captions_stay_on_the_canvas() {
        let long = "Fig. 11: accuracy on the random points, 10 poses, up to 10 visits each; AP max (µm): raw 18.741, table 6.588, model 7.755, closed_loop 0.058 — validate.csv, validate-drift-off.csv, validate-drift-static.csv, validate-drift-adaptive.csv, validate-grid.csv";
        let dots = |c: usize| Trace {
            label: Some(format!("series {c}")),
            color: c,
            points: (0..20).map(|i| (i as f64, (i * c) as f64)).collect(),
            style: Style::Dots,
        };
        let fig = Figure {
            title: long.into(),
            rows: vec![vec![
                xy(long, vec![dots(0), dots(1)]),
                xy(
                    "plan view: measured positions, deviations drawn ×500 over the whole square",
                    vec![dots(2)],
                ),
            ]],
            size: (900, 500),
        };
        let svg = svg_of(&fig);
        let off = texts_off_canvas(&svg);
        assert!(off.is_empty(), "text off the canvas: {off:#?}");
        // All of the title is there.
        let all: Vec<String> = texts(&svg).into_iter().map(|t| t.text).collect();
        assert!(
            all.iter().any(|t| t.contains("validate-grid.csv")),
            "{all:?}"
        );
        assert!(all.iter().any(|t| t.starts_with("Fig. 11")), "{all:?}");
    }

    /// Data over the whole range, the upper right corner included (where a
    /// legend used to sit): no legend text or marker is on the data.
    #[test]
    fn legends_are_drawn_below_the_axes_off_the_data() {
        let grid = |c: usize| Trace {
            label: Some(format!("mode {c} (run-{c}.csv), AP max {c}.00 µm")),
            color: c,
            points: (0..15)
                .flat_map(|i| (0..15).map(move |j| (i as f64 + 0.1 * c as f64, j as f64)))
                .collect(),
            style: if c == 2 { Style::LineDots } else { Style::Dots },
        };
        let lines = Trace {
            label: Some("a line".into()),
            color: 3,
            points: vec![(0.0, 0.0), (14.0, 14.0)],
            style: Style::Line,
        };
        let fig = Figure {
            title: "legend test".into(),
            rows: vec![vec![xy("panel", vec![grid(0), grid(1), grid(2), lines])]],
            size: (800, 500),
        };
        let svg = svg_of(&fig);
        let data: Vec<(f64, f64, f64)> = circles(&svg)
            .into_iter()
            .filter(|c| c.2 < f64::from(LEGEND_DOT_RADIUS))
            .collect();
        assert_eq!(data.len(), 3 * 225, "every data point drawn");
        let bbox = data
            .iter()
            .map(|&(x, y, r)| BoxPx {
                x0: x - r,
                y0: y - r,
                x1: x + r,
                y1: y + r,
            })
            .reduce(|a, b| a.union(&b))
            .unwrap();
        let labels: Vec<_> = texts(&svg)
            .into_iter()
            .filter(|t| t.text.starts_with("mode ") || t.text == "a line")
            .collect();
        assert_eq!(labels.len(), 4, "one legend entry per labelled trace");
        for t in &labels {
            assert!(
                !t.bbox().overlaps(&bbox, 0.0),
                "legend {:?} at {:?} on the data {bbox:?}",
                t.text,
                t.bbox()
            );
            assert!(t.bbox().y0 > bbox.y1, "legend below the data: {t:?}");
        }
        for (x, y, r) in circles(&svg)
            .into_iter()
            .filter(|c| c.2 >= f64::from(LEGEND_DOT_RADIUS))
        {
            assert!(y - r > bbox.y1, "legend marker at ({x}, {y}) on the data");
        }
        assert!(texts_off_canvas(&svg).is_empty());
    }

    /// Bars whose values differ in the sixth digit and bars too narrow for
    /// their labels: labels are the values at the resolution with the
    /// unit, and no two overlap.
    #[test]
    fn bar_labels_are_rounded_with_units_and_never_overlap() {
        let values = [0.100124, 0.0572587, 18.7414, 3.2243, 1.36520, 0.0513];
        for (categories, width) in [(4usize, 1400u32), (9, 700)] {
            let groups: Vec<BarGroup> = (0..3)
                .map(|g| {
                    BarGroup::labelled(
                        format!("group {g}"),
                        g,
                        (0..categories)
                            .map(|c| Some(values[(c * 3 + g) % values.len()]))
                            .collect(),
                        0.01,
                        "µm",
                    )
                })
                .collect();
            let fig = Figure {
                title: "bars".into(),
                rows: vec![vec![Panel::Bars(BarPanel {
                    title: "summary per mode".into(),
                    categories: (0..categories)
                        .map(|c| format!("table (validate-drift-{c}.csv)"))
                        .collect(),
                    x_label: "mode".into(),
                    y_label: "µm".into(),
                    groups,
                })]],
                size: (width, 500),
            };
            let svg = svg_of(&fig);
            let labels: Vec<_> = texts(&svg)
                .into_iter()
                .filter(|t| t.text.ends_with(" µm"))
                .collect();
            assert_eq!(labels.len(), 3 * categories, "one label per bar");
            for t in &labels {
                let v: f64 = t.text.trim_end_matches(" µm").parse().unwrap();
                assert!(
                    values.iter().any(|w| (w - v).abs() <= 0.005 + 1e-12),
                    "{}",
                    t.text
                );
                assert_eq!(
                    t.text.split('.').nth(1).map(|d| d.chars().count()),
                    Some(5),
                    "two decimals: {}",
                    t.text
                );
            }
            let others: Vec<_> = texts(&svg)
                .into_iter()
                .filter(|t| !t.text.ends_with(" µm"))
                .collect();
            for (i, a) in labels.iter().enumerate() {
                for b in &labels[i + 1..] {
                    assert!(
                        !a.bbox().overlaps(&b.bbox(), 0.0),
                        "{categories} categories: {:?} {:?} overlap {:?} {:?}",
                        a.text,
                        a.bbox(),
                        b.text,
                        b.bbox()
                    );
                }
                for o in &others {
                    assert!(
                        !a.bbox().overlaps(&o.bbox(), 0.0),
                        "{:?} overlaps {:?}",
                        a.text,
                        o.text
                    );
                }
            }
            let off = texts_off_canvas(&svg);
            assert!(off.is_empty(), "{off:#?}");
        }
    }
}
