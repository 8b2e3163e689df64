//! Multi-panel figures: x–y panels (lines, dots, crosses; linear or
//! logarithmic y) and grouped bar panels, written as PNG and/or SVG.
//!
//! Why a second drawing layer next to [`super::Chart`]: the paper's figures
//! put related views side by side (one panel per axis in Figs. 4–6; the
//! trajectory, the per-pose accuracy and a summary in Figs. 10–11), need
//! several traces sharing one colour and one legend entry (three cycles of
//! a forward pass), a logarithmic scale (raw 22 µm next to closed-loop
//! 0.1 µm) and bars. [`Figure`] is still plain data built by the numeric
//! code; [`render_figure`] alone knows plotters. The same data serializes
//! to JSON (`serde`: panels tagged `kind` = `xy` / `bars`, points as
//! `[x, y]`, non-finite values as `null`): the daemon's `figures` command
//! sends it and the web page draws it, so browser and files show one
//! computation.
//!
//! Ticks are computed here (1-2-5 steps on linear axes, decades and 2/5
//! subdivisions on log axes) and handed to plotters as fixed key points, so
//! every panel has one concrete coordinate type and labels read as data
//! values (a log axis is drawn as log10 of the data with labels mapped back).

use std::path::{Path, PathBuf};
use std::str::FromStr;

use plotters::coord::ranged1d::{DefaultFormatting, KeyPointHint, Ranged};
use plotters::coord::types::RangedCoordf64;
use plotters::coord::Shift;
use plotters::prelude::*;

use super::{font, PlotError, FAMILY, PALETTE};

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

/// Nice 1-2-5 ticks covering `[lo, hi]`, at most about `n` of them.
fn linear_ticks(lo: f64, hi: f64, n: usize) -> Vec<f64> {
    let span = hi - lo;
    if !(span.is_finite() && span > 0.0) {
        return vec![lo];
    }
    let raw = span / n.max(1) as f64;
    let mag = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 5.0, 10.0]
        .iter()
        .map(|m| m * mag)
        .find(|s| span / s <= n as f64)
        .unwrap_or(10.0 * mag);
    let first = (lo / step).ceil() as i64;
    let last = (hi / step).floor() as i64;
    (first..=last).map(|k| k as f64 * step).collect()
}

/// Ticks of a log axis in log10 space: decades, and 2 and 5 when few
/// decades are shown.
fn log_ticks(lo: f64, hi: f64) -> Vec<f64> {
    let decades = hi - lo;
    let mut out = Vec::new();
    let mults: &[f64] = if decades <= 3.0 {
        &[1.0, 2.0, 5.0]
    } else {
        &[1.0]
    };
    let (d0, d1) = (lo.floor() as i64, hi.ceil() as i64);
    for d in d0..=d1 {
        for m in mults {
            let v = d as f64 + m.log10();
            if v >= lo && v <= hi {
                out.push(v);
            }
        }
    }
    out
}

/// Significant digits for a tick label.
fn tick_label(v: f64) -> String {
    if v == 0.0 {
        return "0".into();
    }
    let a = v.abs();
    if !(1e-3..1e6).contains(&a) {
        return format!("{v:.0e}");
    }
    let s = format!("{v:.4}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    if s == "-0" {
        "0".into()
    } else {
        s.to_string()
    }
}

fn pad_range(lo: f64, hi: f64, frac: f64) -> (f64, f64) {
    if !(lo.is_finite() && hi.is_finite()) {
        (0.0, 1.0)
    } else if hi - lo <= 0.0 {
        let d = if lo == 0.0 { 0.5 } else { 0.05 * lo.abs() };
        (lo - d, hi + d)
    } else {
        let pad = frac * (hi - lo);
        (lo - pad, hi + pad)
    }
}

/// Value as drawn on the y axis (log10 on a log axis; `None` = not drawable).
fn ymap(scale: Scale, y: f64) -> Option<f64> {
    match scale {
        Scale::Linear => y.is_finite().then_some(y),
        Scale::Log => (y.is_finite() && y > 0.0).then(|| y.log10()),
    }
}

/// A linear f64 axis with the ticks given (plotters' own `WithKeyPoints`
/// over f64 loses the label formatter, so the mesh cannot be drawn).
struct Keyed {
    inner: RangedCoordf64,
    keys: Vec<f64>,
}

impl Keyed {
    fn new(lo: f64, hi: f64, keys: Vec<f64>) -> Self {
        Keyed {
            inner: (lo..hi).into(),
            keys,
        }
    }
}

impl Ranged for Keyed {
    type FormatOption = DefaultFormatting;
    type ValueType = f64;
    fn map(&self, value: &f64, limit: (i32, i32)) -> i32 {
        self.inner.map(value, limit)
    }
    fn key_points<Hint: KeyPointHint>(&self, hint: Hint) -> Vec<f64> {
        if hint.weight().allow_light_points() {
            Vec::new()
        } else {
            self.keys.clone()
        }
    }
    fn range(&self) -> std::ops::Range<f64> {
        self.inner.range()
    }
}

type Coord = Cartesian2d<Keyed, Keyed>;

fn label_area(y_label: &str) -> u32 {
    if y_label.is_empty() {
        45
    } else {
        75
    }
}

fn draw_xy<DB: DrawingBackend>(area: &DrawingArea<DB, Shift>, p: &XyPanel) -> Result<(), String>
where
    DB::ErrorType: 'static,
{
    let e = |x: DrawingAreaErrorKind<DB::ErrorType>| x.to_string();
    let pts: Vec<(usize, Vec<(f64, f64)>)> = p
        .traces
        .iter()
        .enumerate()
        .map(|(i, t)| {
            (
                i,
                t.points
                    .iter()
                    .filter(|(x, _)| x.is_finite())
                    .filter_map(|&(x, y)| ymap(p.y_scale, y).map(|y| (x, y)))
                    .collect(),
            )
        })
        .collect();
    let mut xr = (f64::INFINITY, f64::NEG_INFINITY);
    let mut yr = (f64::INFINITY, f64::NEG_INFINITY);
    for (_, v) in &pts {
        for &(x, y) in v {
            xr = (xr.0.min(x), xr.1.max(x));
            yr = (yr.0.min(y), yr.1.max(y));
        }
    }
    let (mut x0, mut x1) = pad_range(xr.0, xr.1, 0.03);
    let (mut y0, mut y1) = pad_range(yr.0, yr.1, 0.06);
    let (w, h) = area.dim_in_pixel();
    let y_area = label_area(&p.y_label);
    if p.equal_aspect {
        let pw = (w as f64 - y_area as f64 - 30.0).max(10.0);
        let ph = (h as f64 - 45.0 - 40.0).max(10.0);
        let (sx, sy) = ((x1 - x0) / pw, (y1 - y0) / ph);
        if sx > sy {
            let c = 0.5 * (y0 + y1);
            y0 = c - 0.5 * sx * ph;
            y1 = c + 0.5 * sx * ph;
        } else {
            let c = 0.5 * (x0 + x1);
            x0 = c - 0.5 * sy * pw;
            x1 = c + 0.5 * sy * pw;
        }
    }
    let x_keys = linear_ticks(x0, x1, 8);
    let y_keys = match p.y_scale {
        Scale::Linear => linear_ticks(y0, y1, 8),
        Scale::Log => log_ticks(y0, y1),
    };
    let scale = p.y_scale;
    let mut c = ChartBuilder::on(area)
        .caption(&p.title, (FAMILY, 17))
        .margin(10)
        .x_label_area_size(45)
        .y_label_area_size(y_area)
        .build_cartesian_2d(Keyed::new(x0, x1, x_keys), Keyed::new(y0, y1, y_keys))
        .map_err(e)?;
    c.configure_mesh()
        .x_desc(p.x_label.as_str())
        .y_desc(p.y_label.as_str())
        .x_label_formatter(&|v| tick_label(*v))
        .y_label_formatter(&|v| match scale {
            Scale::Linear => tick_label(*v),
            Scale::Log => tick_label(10f64.powf(*v)),
        })
        .label_style((FAMILY, 12))
        .axis_desc_style((FAMILY, 14))
        .bold_line_style(RGBColor(225, 225, 225))
        .draw()
        .map_err(e)?;
    draw_traces(&mut c, p, &pts).map_err(e)?;
    if p.traces.iter().any(|t| t.label.is_some()) {
        c.configure_series_labels()
            .label_font((FAMILY, 12))
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .position(SeriesLabelPosition::UpperRight)
            .draw()
            .map_err(e)?;
    }
    Ok(())
}

fn draw_traces<DB: DrawingBackend>(
    c: &mut ChartContext<'_, DB, Coord>,
    p: &XyPanel,
    pts: &[(usize, Vec<(f64, f64)>)],
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    for (i, v) in pts {
        let t = &p.traces[*i];
        let color = PALETTE[t.color % PALETTE.len()];
        let label = t.label.as_deref().unwrap_or("");
        // The part drawn last carries the legend entry.
        match t.style {
            Style::Line => {
                let a = c.draw_series(LineSeries::new(v.iter().copied(), color.stroke_width(1)))?;
                if t.label.is_some() {
                    a.label(label).legend(move |(x, y)| {
                        Rectangle::new([(x, y - 1), (x + 14, y + 1)], color.filled())
                    });
                }
            }
            Style::Dots | Style::LineDots => {
                if t.style == Style::LineDots {
                    c.draw_series(LineSeries::new(v.iter().copied(), color.stroke_width(1)))?;
                }
                let a = c.draw_series(v.iter().map(|&q| Circle::new(q, 2, color.filled())))?;
                if t.label.is_some() {
                    a.label(label)
                        .legend(move |(x, y)| Circle::new((x + 7, y), 3, color.filled()));
                }
            }
            Style::Crosses => {
                let a =
                    c.draw_series(v.iter().map(|&q| Cross::new(q, 4, color.stroke_width(1))))?;
                if t.label.is_some() {
                    a.label(label)
                        .legend(move |(x, y)| Cross::new((x + 7, y), 4, color.stroke_width(1)));
                }
            }
        }
    }
    Ok(())
}

fn draw_bars<DB: DrawingBackend>(area: &DrawingArea<DB, Shift>, p: &BarPanel) -> Result<(), String>
where
    DB::ErrorType: 'static,
{
    let e = |x: DrawingAreaErrorKind<DB::ErrorType>| x.to_string();
    let n = p.categories.len().max(1);
    let top = p
        .groups
        .iter()
        .flat_map(|g| g.values.iter().flatten())
        .copied()
        .filter(|v| v.is_finite())
        .fold(0.0f64, f64::max);
    let y1 = if top > 0.0 { top * 1.18 } else { 1.0 };
    let centres: Vec<f64> = (0..n).map(|i| i as f64 + 0.5).collect();
    let cats = p.categories.clone();
    let mut c = ChartBuilder::on(area)
        .caption(&p.title, (FAMILY, 17))
        .margin(10)
        .x_label_area_size(45)
        .y_label_area_size(label_area(&p.y_label))
        .build_cartesian_2d(
            Keyed::new(0.0, n as f64, centres),
            Keyed::new(0.0, y1, linear_ticks(0.0, y1, 8)),
        )
        .map_err(e)?;
    c.configure_mesh()
        .disable_x_mesh()
        .x_desc(p.x_label.as_str())
        .y_desc(p.y_label.as_str())
        .x_label_formatter(&|v| {
            let i = v.floor();
            if i >= 0.0 && (i as usize) < cats.len() {
                cats[i as usize].clone()
            } else {
                String::new()
            }
        })
        .y_label_formatter(&|v| tick_label(*v))
        .label_style((FAMILY, 12))
        .axis_desc_style((FAMILY, 14))
        .bold_line_style(RGBColor(225, 225, 225))
        .draw()
        .map_err(e)?;
    let k = p.groups.len().max(1) as f64;
    let width = 0.8 / k;
    for (gi, g) in p.groups.iter().enumerate() {
        let color = PALETTE[g.color % PALETTE.len()];
        let bars: Vec<(f64, f64)> = g
            .values
            .iter()
            .enumerate()
            .filter_map(|(i, v)| {
                v.filter(|v| v.is_finite())
                    .map(|v| (i as f64 + 0.1 + gi as f64 * width, v))
            })
            .collect();
        c.draw_series(
            bars.iter()
                .map(|&(x, v)| Rectangle::new([(x, 0.0), (x + width * 0.92, v)], color.filled())),
        )
        .map_err(e)?
        .label(g.label.as_str())
        .legend(move |(x, y)| Rectangle::new([(x, y - 4), (x + 14, y + 4)], color.filled()));
        c.draw_series(bars.iter().map(|&(x, v)| {
            Text::new(
                tick_label(round_sig(v, 3)),
                (x, v + 0.02 * y1),
                (FAMILY, 11).into_font(),
            )
        }))
        .map_err(e)?;
    }
    if !p.groups.is_empty() {
        c.configure_series_labels()
            .label_font((FAMILY, 12))
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .position(SeriesLabelPosition::UpperRight)
            .draw()
            .map_err(e)?;
    }
    Ok(())
}

/// `v` rounded to `n` significant digits (bar labels).
fn round_sig(v: f64, n: i32) -> f64 {
    if v == 0.0 || !v.is_finite() {
        return v;
    }
    let m = 10f64.powi(n - 1 - v.abs().log10().floor() as i32);
    (v * m).round() / m
}

fn draw_figure<DB: DrawingBackend>(root: DrawingArea<DB, Shift>, fig: &Figure) -> Result<(), String>
where
    DB::ErrorType: 'static,
{
    let e = |x: DrawingAreaErrorKind<DB::ErrorType>| x.to_string();
    root.fill(&WHITE).map_err(e)?;
    let root = root.titled(&fig.title, (FAMILY, 20)).map_err(e)?;
    let rows = root.split_evenly((fig.rows.len().max(1), 1));
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

/// Writes `fig` as `<stem>.png` and/or `<stem>.svg`; returns the files.
pub fn render_figure(fig: &Figure, stem: &Path, format: Format) -> Result<Vec<PathBuf>, PlotError> {
    font()?;
    let mut out = Vec::new();
    if format.png() {
        let png = stem.with_extension("png");
        draw_figure(BitMapBackend::new(&png, fig.size).into_drawing_area(), fig).map_err(|m| {
            PlotError::Draw {
                path: png.clone(),
                message: m,
            }
        })?;
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
    use super::*;

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
}
