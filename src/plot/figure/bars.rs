//! The grouped bar panel: bars per category and group, their value labels
//! (rounded, with the unit, turned upright when they do not fit side by
//! side). A file of its own: one of the two panel kinds, drawn from
//! [`super::BarPanel`].

use super::super::{FAMILY, PALETTE};
use super::axes::{label_area, linear_ticks, tick_label, Keyed};
use super::legend::{draw_legend, panel_areas, LegendItem, Marker};
use super::text::{
    draw_lines, fit_text, text_extent, Fitted, LINE_SPACING, MARGIN, MIN_TEXT_PX, VALUE_PX,
    X_LABEL_AREA,
};
use super::{BarGroup, BarPanel};
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use plotters::style::FontTransform;

/// The text above a bar: the group's label for it, else the value to three
/// significant digits.
pub(super) fn bar_text(g: &BarGroup, i: usize, v: f64) -> String {
    g.value_labels
        .get(i)
        .cloned()
        .flatten()
        .unwrap_or_else(|| tick_label(round_sig(v, 3)))
}

pub(super) fn draw_bars<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    p: &BarPanel,
) -> Result<(), String>
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
pub(super) fn round_sig(v: f64, n: i32) -> f64 {
    if v == 0.0 || !v.is_finite() {
        return v;
    }
    let m = 10f64.powi(n - 1 - v.abs().log10().floor() as i32);
    (v * m).round() / m
}
