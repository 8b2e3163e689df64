//! The x–y panel: its axes (linear or log y, equal aspect when asked),
//! and its traces as lines, dashed lines, dots or crosses. A file of its
//! own: one of the two panel kinds, drawn from [`super::XyPanel`].

use super::super::{FAMILY, PALETTE};
use super::axes::{label_area, linear_ticks, log_ticks, pad_range, tick_label, ymap, Coord, Keyed};
use super::legend::{draw_legend, panel_areas, LegendItem};
use super::text::{MARGIN, X_LABEL_AREA};
use super::{Scale, Style, XyPanel};
use plotters::coord::Shift;
use plotters::prelude::*;

/// Dot radius for `n` points in a panel: large enough to see on a
/// 50-point test, small enough not to merge on a 2000-point scan.
pub(super) fn dot_radius(n: usize) -> i32 {
    match n {
        0..=300 => 3,
        301..=2000 => 2,
        _ => 1,
    }
}

pub(super) fn draw_xy<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    p: &XyPanel,
) -> Result<(), String>
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

pub(super) fn draw_traces<DB: DrawingBackend>(
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
