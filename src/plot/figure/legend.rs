//! Legends and the panel layout that makes room for them: the entries laid
//! out in rows of the panel's width, drawn in a strip below the axes, and
//! the split of a panel's cell into caption, chart and legend strip. A file
//! of its own: both panel kinds share it, and it is where the rule "the
//! legend never sits on the data" lives.

use super::super::{FAMILY, PALETTE};
use super::text::{
    draw_lines, ellipsize, fit_text, text_extent, CAPTION_PX, ENTRY_GAP, LEGEND_DOT_RADIUS,
    LEGEND_PX, MARGIN, MARK_GAP, MARK_W, MIN_TEXT_PX,
};
use super::Style;
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

/// How a legend entry shows its trace.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Marker {
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
pub(super) struct LegendItem {
    pub(super) label: String,
    pub(super) color: usize,
    pub(super) marker: Marker,
}

/// One row of a legend: per entry (item index, text as drawn, x of the
/// entry from the row's start), and the row's width.
pub(super) type LegendRow = (Vec<(usize, String, f64)>, f64);

/// A legend laid out in rows across its strip.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct LegendLayout {
    /// Font size, px.
    pub(super) size: f64,
    /// The rows, top to bottom.
    pub(super) rows: Vec<LegendRow>,
    /// Height of a row, px.
    pub(super) row_h: f64,
    /// Height of the strip, px.
    pub(super) height: f64,
}

/// Lays `items` out in rows of at most `width` px: one font size for all
/// (the largest down to [`MIN_TEXT_PX`] at which the widest fits a row),
/// a label still too wide shortened with "…".
pub(super) fn legend_layout(items: &[LegendItem], width: f64) -> Option<LegendLayout> {
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
pub(super) fn draw_legend<DB: DrawingBackend>(
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
pub(super) struct PanelAreas<DB: DrawingBackend> {
    pub(super) chart: DrawingArea<DB, Shift>,
    pub(super) legend: Option<(DrawingArea<DB, Shift>, LegendLayout)>,
}

pub(super) fn panel_areas<DB: DrawingBackend>(
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
