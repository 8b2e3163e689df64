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

use std::path::{Path, PathBuf};
use std::str::FromStr;

use plotters::coord::ranged1d::{DefaultFormatting, KeyPointHint, Ranged};
use plotters::coord::types::RangedCoordf64;
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use plotters::style::FontTransform;

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

/// Font sizes, px: figure title, panel caption, legend, bar values, and
/// the smallest any of them is shrunk to before it is wrapped or shortened.
const TITLE_PX: f64 = 20.0;
const CAPTION_PX: f64 = 17.0;
const LEGEND_PX: f64 = 12.0;
const VALUE_PX: f64 = 11.0;
const MIN_TEXT_PX: f64 = 9.0;
/// Line height as a multiple of the font size.
const LINE_SPACING: f64 = 1.25;
/// Space around a figure's title and a panel's chart, px.
const MARGIN: f64 = 10.0;
/// Height of the x-axis label area (tick labels and description), px.
const X_LABEL_AREA: u32 = 45;
/// Width of a legend marker, the gap to its text and the gap between
/// entries, px.
const MARK_W: f64 = 18.0;
const MARK_GAP: f64 = 5.0;
const ENTRY_GAP: f64 = 18.0;
/// Radius of a legend's dot marker, px: larger than any data dot (at most
/// 3), so the two are told apart in a drawing.
pub const LEGEND_DOT_RADIUS: i32 = 4;

/// Width and height (px) of `text` at `size` px in the shipped font; 0.6 em
/// per character when the font cannot lay it out.
///
/// Why measured here and not left to plotters: plotters centres a caption
/// and lets it run off both edges when it is wider than its area; every
/// text this module draws is fitted to its space first with these numbers
/// (the ones the bitmap backend draws with).
pub fn text_extent(text: &str, size: f64) -> (f64, f64) {
    let _ = font();
    match (FAMILY, size).into_font().box_size(text) {
        Ok((w, h)) => (f64::from(w), f64::from(h)),
        Err(_) => (0.6 * size * text.chars().count() as f64, size),
    }
}

/// A text broken into lines at one font size.
#[derive(Debug, Clone, PartialEq)]
pub struct Fitted {
    /// The lines, top to bottom (none for an empty text).
    pub lines: Vec<String>,
    /// Font size, px.
    pub size: f64,
}

impl Fitted {
    /// Height of the lines, px.
    pub fn height(&self) -> f64 {
        self.lines.len() as f64 * self.size * LINE_SPACING
    }
}

/// Greedy word wrap of `text` into lines no wider than `max_w` px at
/// `size`; a word wider than a line is broken between characters.
fn wrap(text: &str, max_w: f64, size: f64) -> Vec<String> {
    let fits = |s: &str| text_extent(s, size).0 <= max_w;
    let mut lines: Vec<String> = Vec::new();
    let mut line = String::new();
    for word in text.split_whitespace() {
        let joined = if line.is_empty() {
            word.to_string()
        } else {
            format!("{line} {word}")
        };
        if fits(&joined) {
            line = joined;
            continue;
        }
        if !line.is_empty() {
            lines.push(std::mem::take(&mut line));
        }
        if fits(word) {
            line = word.to_string();
            continue;
        }
        for ch in word.chars() {
            let mut next = line.clone();
            next.push(ch);
            if !line.is_empty() && !fits(&next) {
                lines.push(std::mem::take(&mut line));
                next = ch.to_string();
            }
            line = next;
        }
    }
    if !line.is_empty() {
        lines.push(line);
    }
    lines
}

/// Fits `text` into lines no wider than `max_w` px: at the largest size
/// from `size` down to `min_size` (steps of 10 %) that needs at most
/// `max_lines` lines, else at `min_size` in as many lines as it takes.
pub fn fit_text(text: &str, max_w: f64, size: f64, min_size: f64, max_lines: usize) -> Fitted {
    let min_size = min_size.min(size);
    let mut s = size;
    loop {
        let lines = wrap(text, max_w, s);
        if lines.len() <= max_lines.max(1) {
            return Fitted { lines, size: s };
        }
        if s <= min_size {
            return Fitted { lines, size: s };
        }
        s = (s * 0.9).max(min_size);
    }
}

/// `text` shortened with "…" until it is at most `max_w` px wide at `size`.
fn ellipsize(text: &str, max_w: f64, size: f64) -> String {
    if text_extent(text, size).0 <= max_w {
        return text.to_string();
    }
    let mut chars: Vec<char> = text.chars().collect();
    while !chars.is_empty() {
        chars.pop();
        let s: String = chars.iter().collect::<String>() + "…";
        if text_extent(&s, size).0 <= max_w {
            return s;
        }
    }
    "…".into()
}

/// Draws `f`'s lines centred on `x_centre`, the first one's top at `top`
/// (pixel coordinates of `area`).
fn draw_lines<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    f: &Fitted,
    x_centre: i32,
    top: i32,
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    let style =
        TextStyle::from((FAMILY, f.size).into_font()).pos(Pos::new(HPos::Center, VPos::Top));
    for (k, line) in f.lines.iter().enumerate() {
        let y = top + (k as f64 * f.size * LINE_SPACING).round() as i32;
        area.draw(&Text::new(line.as_str(), (x_centre, y), style.clone()))?;
    }
    Ok(())
}

/// How a legend entry shows its trace.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Marker {
    Line,
    Dashed,
    Dot,
    LineDot,
    Cross,
    Bar,
}

impl From<Style> for Marker {
    fn from(s: Style) -> Self {
        match s {
            Style::Line => Marker::Line,
            Style::Dashed => Marker::Dashed,
            Style::Dots => Marker::Dot,
            Style::LineDots => Marker::LineDot,
            Style::Crosses => Marker::Cross,
        }
    }
}

/// One legend entry.
#[derive(Debug, Clone, PartialEq)]
struct LegendItem {
    label: String,
    color: usize,
    marker: Marker,
}

/// One row of a legend: per entry (item index, text as drawn, x of the
/// entry from the row's start), and the row's width.
type LegendRow = (Vec<(usize, String, f64)>, f64);

/// A legend laid out in rows across its strip.
#[derive(Debug, Clone, PartialEq)]
struct LegendLayout {
    /// Font size, px.
    size: f64,
    /// The rows, top to bottom.
    rows: Vec<LegendRow>,
    /// Height of a row, px.
    row_h: f64,
    /// Height of the strip, px.
    height: f64,
}

/// Lays `items` out in rows of at most `width` px: one font size for all
/// (the largest down to [`MIN_TEXT_PX`] at which the widest fits a row),
/// a label still too wide shortened with "…".
fn legend_layout(items: &[LegendItem], width: f64) -> Option<LegendLayout> {
    if items.is_empty() {
        return None;
    }
    let avail = (width - 2.0 * MARGIN).max(60.0);
    let room = avail - MARK_W - MARK_GAP;
    let mut size = LEGEND_PX;
    while size > MIN_TEXT_PX && items.iter().any(|i| text_extent(&i.label, size).0 > room) {
        size = (size * 0.9).max(MIN_TEXT_PX);
    }
    let mut rows: Vec<LegendRow> = Vec::new();
    let mut row: Vec<(usize, String, f64)> = Vec::new();
    let mut x = 0.0;
    for (k, item) in items.iter().enumerate() {
        let text = ellipsize(&item.label, room, size);
        let w = MARK_W + MARK_GAP + text_extent(&text, size).0;
        if !row.is_empty() && x + ENTRY_GAP + w > avail {
            rows.push((std::mem::take(&mut row), x));
            x = 0.0;
        }
        let at = if row.is_empty() { 0.0 } else { x + ENTRY_GAP };
        row.push((k, text, at));
        x = at + w;
    }
    rows.push((row, x));
    let row_h = (size * 1.5).ceil();
    // Frame padding above and below the rows, and a gap before the next
    // panel's caption.
    let height = rows.len() as f64 * row_h + 2.0 * 4.0 + 4.0 + 10.0;
    Some(LegendLayout {
        size,
        rows,
        row_h,
        height,
    })
}

/// Draws a legend laid out by [`legend_layout`] into its strip `area`
/// (below the chart, outside the plotting area): a thin frame, then each
/// entry's marker and text.
fn draw_legend<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    items: &[LegendItem],
    l: &LegendLayout,
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    let (w, _) = area.dim_in_pixel();
    let w = f64::from(w);
    let widest = l.rows.iter().map(|r| r.1).fold(0.0, f64::max);
    let x_frame = ((w - widest) / 2.0 - 6.0).max(0.0);
    let top = 4.0;
    area.draw(&Rectangle::new(
        [
            (x_frame.round() as i32, top as i32),
            (
                (x_frame + widest + 12.0).min(w - 1.0).round() as i32,
                (top + 4.0 + l.rows.len() as f64 * l.row_h + 4.0).round() as i32,
            ),
        ],
        RGBColor(190, 190, 190).stroke_width(1),
    ))?;
    let style =
        TextStyle::from((FAMILY, l.size).into_font()).pos(Pos::new(HPos::Left, VPos::Center));
    for (r, (row, row_w)) in l.rows.iter().enumerate() {
        let x0 = (w - row_w) / 2.0;
        let y = (top + 4.0 + (r as f64 + 0.5) * l.row_h).round() as i32;
        for (k, text, at) in row {
            let item = &items[*k];
            let color = PALETTE[item.color % PALETTE.len()];
            let x = (x0 + at).round() as i32;
            let m = MARK_W as i32;
            match item.marker {
                Marker::Line => area.draw(&PathElement::new(
                    vec![(x, y), (x + m, y)],
                    color.stroke_width(2),
                ))?,
                Marker::Dashed => {
                    area.draw(&PathElement::new(
                        vec![(x, y), (x + 7, y)],
                        color.stroke_width(1),
                    ))?;
                    area.draw(&PathElement::new(
                        vec![(x + 11, y), (x + m, y)],
                        color.stroke_width(1),
                    ))?;
                }
                Marker::Dot => area.draw(&Circle::new(
                    (x + m / 2, y),
                    LEGEND_DOT_RADIUS,
                    color.filled(),
                ))?,
                Marker::LineDot => {
                    area.draw(&PathElement::new(
                        vec![(x, y), (x + m, y)],
                        color.stroke_width(1),
                    ))?;
                    area.draw(&Circle::new(
                        (x + m / 2, y),
                        LEGEND_DOT_RADIUS,
                        color.filled(),
                    ))?;
                }
                Marker::Cross => {
                    area.draw(&Cross::new((x + m / 2, y), 4, color.stroke_width(1)))?
                }
                Marker::Bar => area.draw(&Rectangle::new(
                    [(x + 2, y - 5), (x + m - 2, y + 5)],
                    color.filled(),
                ))?,
            }
            area.draw(&Text::new(
                text.as_str(),
                (x + m + MARK_GAP as i32, y),
                style.clone(),
            ))?;
        }
    }
    Ok(())
}

/// A panel cell split into its caption (drawn here, fitted to the cell's
/// width), the chart and the legend strip below it: the legend never sits
/// on the data.
struct PanelAreas<DB: DrawingBackend> {
    chart: DrawingArea<DB, Shift>,
    legend: Option<(DrawingArea<DB, Shift>, LegendLayout)>,
}

fn panel_areas<DB: DrawingBackend>(
    cell: &DrawingArea<DB, Shift>,
    title: &str,
    items: &[LegendItem],
) -> Result<PanelAreas<DB>, DrawingAreaErrorKind<DB::ErrorType>> {
    let (w, h) = cell.dim_in_pixel();
    let (w, h) = (f64::from(w), f64::from(h));
    let cap = fit_text(title, w - 2.0 * MARGIN, CAPTION_PX, 10.0, 2);
    let cap_h = if cap.lines.is_empty() {
        0.0
    } else {
        draw_lines(cell, &cap, (w / 2.0).round() as i32, 6)?;
        cap.height() + 8.0
    };
    let legend = legend_layout(items, w);
    let leg_h = legend.as_ref().map_or(0.0, |l| l.height);
    let (_, rest) = cell.split_vertically(cap_h.round() as i32);
    let rest_h = (h - cap_h).max(0.0);
    let chart_h = (rest_h - leg_h).max(rest_h.min(60.0));
    let (chart, below) = rest.split_vertically(chart_h.round() as i32);
    Ok(PanelAreas {
        chart,
        legend: legend.map(|l| (below, l)),
    })
}

/// Dot radius for `n` points in a panel: large enough to see on a
/// 50-point test, small enough not to merge on a 2000-point scan.
fn dot_radius(n: usize) -> i32 {
    match n {
        0..=300 => 3,
        301..=2000 => 2,
        _ => 1,
    }
}

fn draw_xy<DB: DrawingBackend>(area: &DrawingArea<DB, Shift>, p: &XyPanel) -> Result<(), String>
where
    DB::ErrorType: 'static,
{
    let e = |x: DrawingAreaErrorKind<DB::ErrorType>| x.to_string();
    let items: Vec<LegendItem> = p
        .traces
        .iter()
        .filter_map(|t| {
            t.label.as_ref().map(|l| LegendItem {
                label: l.clone(),
                color: t.color,
                marker: t.style.into(),
            })
        })
        .collect();
    let areas = panel_areas(area, &p.title, &items).map_err(e)?;
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
    let (w, h) = areas.chart.dim_in_pixel();
    let y_area = label_area(&p.y_label);
    if p.equal_aspect {
        let pw = (f64::from(w) - f64::from(y_area) - 2.0 * MARGIN).max(10.0);
        let ph = (f64::from(h) - f64::from(X_LABEL_AREA) - 2.0 * MARGIN).max(10.0);
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
    let mut c = ChartBuilder::on(&areas.chart)
        .margin(MARGIN as u32)
        .x_label_area_size(X_LABEL_AREA)
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
    let radius = dot_radius(pts.iter().map(|(_, v)| v.len()).sum());
    draw_traces(&mut c, p, &pts, radius).map_err(e)?;
    if let Some((a, l)) = &areas.legend {
        draw_legend(a, &items, l).map_err(e)?;
    }
    Ok(())
}

fn draw_traces<DB: DrawingBackend>(
    c: &mut ChartContext<'_, DB, Coord>,
    p: &XyPanel,
    pts: &[(usize, Vec<(f64, f64)>)],
    radius: i32,
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    for (i, v) in pts {
        let t = &p.traces[*i];
        let color = PALETTE[t.color % PALETTE.len()];
        match t.style {
            Style::Line => {
                c.draw_series(LineSeries::new(v.iter().copied(), color.stroke_width(1)))?;
            }
            Style::Dashed => {
                c.draw_series(DashedLineSeries::new(
                    v.iter().copied(),
                    6,
                    4,
                    color.stroke_width(1),
                ))?;
            }
            Style::Dots | Style::LineDots => {
                if t.style == Style::LineDots {
                    c.draw_series(LineSeries::new(v.iter().copied(), color.stroke_width(1)))?;
                }
                c.draw_series(v.iter().map(|&q| Circle::new(q, radius, color.filled())))?;
            }
            Style::Crosses => {
                c.draw_series(v.iter().map(|&q| Cross::new(q, 4, color.stroke_width(1))))?;
            }
        }
    }
    Ok(())
}

/// The text above a bar: the group's label for it, else the value to three
/// significant digits.
fn bar_text(g: &BarGroup, i: usize, v: f64) -> String {
    g.value_labels
        .get(i)
        .cloned()
        .flatten()
        .unwrap_or_else(|| tick_label(round_sig(v, 3)))
}

fn draw_bars<DB: DrawingBackend>(area: &DrawingArea<DB, Shift>, p: &BarPanel) -> Result<(), String>
where
    DB::ErrorType: 'static,
{
    let e = |x: DrawingAreaErrorKind<DB::ErrorType>| x.to_string();
    let items: Vec<LegendItem> = p
        .groups
        .iter()
        .map(|g| LegendItem {
            label: g.label.clone(),
            color: g.color,
            marker: Marker::Bar,
        })
        .collect();
    let areas = panel_areas(area, &p.title, &items).map_err(e)?;
    let n = p.categories.len().max(1);
    let k = p.groups.len().max(1) as f64;
    let width = 0.8 / k;
    let (w, h) = areas.chart.dim_in_pixel();
    let y_area = label_area(&p.y_label);
    let pw = (f64::from(w) - f64::from(y_area) - 2.0 * MARGIN).max(10.0);
    // Category names fitted to their slot (wrapped into two lines, or
    // smaller): drawn here, not by the mesh, which would let long ones run
    // into each other.
    let slot_px = pw / n as f64;
    let cats: Vec<Fitted> = p
        .categories
        .iter()
        .map(|c| fit_text(c, slot_px - 6.0, 12.0, MIN_TEXT_PX, 2))
        .collect();
    let cat_h = cats.iter().map(Fitted::height).fold(0.0, f64::max);
    let x_area = X_LABEL_AREA + (cat_h - 15.0).max(0.0).round() as u32;
    let ph = (f64::from(h) - f64::from(x_area) - 2.0 * MARGIN).max(10.0);
    let top = p
        .groups
        .iter()
        .flat_map(|g| g.values.iter().flatten())
        .copied()
        .filter(|v| v.is_finite())
        .fold(0.0f64, f64::max);
    // Value labels: horizontal when each fits the width of its bar and
    // the gap beside it, else turned upright, so no two ever overlap.
    let labels: Vec<Vec<Option<String>>> = p
        .groups
        .iter()
        .map(|g| {
            g.values
                .iter()
                .enumerate()
                .map(|(i, v)| v.filter(|v| v.is_finite()).map(|v| bar_text(g, i, v)))
                .collect()
        })
        .collect();
    let bar_px = width * pw / n as f64;
    let widest = labels
        .iter()
        .flatten()
        .flatten()
        .map(|l| text_extent(l, VALUE_PX).0)
        .fold(0.0, f64::max);
    let upright = widest > bar_px - 2.0;
    let value_px = if upright {
        VALUE_PX.min((bar_px - 2.0).max(7.0))
    } else {
        VALUE_PX
    };
    let room = if upright {
        labels
            .iter()
            .flatten()
            .flatten()
            .map(|l| text_extent(l, value_px).0)
            .fold(0.0, f64::max)
    } else {
        value_px * LINE_SPACING
    } + 6.0;
    // Head room above the tallest bar for its label (at most 3/4 of the
    // plot kept for it).
    let y1 = if top > 0.0 {
        top * ph / (ph - room).max(0.25 * ph)
    } else {
        1.0
    };
    let centres: Vec<f64> = (0..n).map(|i| i as f64 + 0.5).collect();
    let mut c = ChartBuilder::on(&areas.chart)
        .margin(MARGIN as u32)
        .x_label_area_size(x_area)
        .y_label_area_size(y_area)
        .build_cartesian_2d(
            Keyed::new(0.0, n as f64, centres),
            Keyed::new(0.0, y1, linear_ticks(0.0, y1, 8)),
        )
        .map_err(e)?;
    c.configure_mesh()
        .disable_x_mesh()
        .x_desc(p.x_label.as_str())
        .y_desc(p.y_label.as_str())
        .x_label_formatter(&|_| String::new())
        .y_label_formatter(&|v| tick_label(*v))
        .label_style((FAMILY, 12))
        .axis_desc_style((FAMILY, 14))
        .bold_line_style(RGBColor(225, 225, 225))
        .draw()
        .map_err(e)?;
    let base = areas.chart.get_base_pixel();
    let to_area = |q: (i32, i32)| (q.0 - base.0, q.1 - base.1);
    for (i, f) in cats.iter().enumerate() {
        let (x, y) = to_area(c.backend_coord(&(i as f64 + 0.5, 0.0)));
        draw_lines(&areas.chart, f, x, y + 6).map_err(e)?;
    }
    let value_style = TextStyle::from((FAMILY, value_px).into_font());
    let value_style = if upright {
        value_style
            .transform(FontTransform::Rotate270)
            .pos(Pos::new(HPos::Left, VPos::Center))
    } else {
        value_style.pos(Pos::new(HPos::Center, VPos::Bottom))
    };
    for (gi, g) in p.groups.iter().enumerate() {
        let color = PALETTE[g.color % PALETTE.len()];
        let bars: Vec<(usize, f64, f64)> = g
            .values
            .iter()
            .enumerate()
            .filter_map(|(i, v)| {
                v.filter(|v| v.is_finite())
                    .map(|v| (i, i as f64 + 0.1 + gi as f64 * width, v))
            })
            .collect();
        c.draw_series(
            bars.iter().map(|&(_, x, v)| {
                Rectangle::new([(x, 0.0), (x + width * 0.92, v)], color.filled())
            }),
        )
        .map_err(e)?;
        for &(i, x, v) in &bars {
            let Some(text) = labels[gi][i].as_deref() else {
                continue;
            };
            let (px, py) = to_area(c.backend_coord(&(x + width * 0.46, v)));
            areas
                .chart
                .draw(&Text::new(text, (px, py - 3), value_style.clone()))
                .map_err(e)?;
        }
    }
    if let Some((a, l)) = &areas.legend {
        draw_legend(a, &items, l).map_err(e)?;
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
