//! Text: the figure's font sizes and spacings, the measure of a text in
//! the shipped font, and fitting it to its width (wrapped at words, then
//! shrunk, then shortened) before it is drawn. A file of its own: every
//! title, caption, legend and bar value goes through it, so no text runs
//! off the canvas.

use super::super::{font, FAMILY};
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

/// Font sizes, px: figure title, panel caption, legend, bar values, and
/// the smallest any of them is shrunk to before it is wrapped or shortened.
pub(super) const TITLE_PX: f64 = 20.0;

pub(super) const CAPTION_PX: f64 = 17.0;

pub(super) const LEGEND_PX: f64 = 12.0;

pub(super) const VALUE_PX: f64 = 11.0;

pub(super) const MIN_TEXT_PX: f64 = 9.0;

/// Line height as a multiple of the font size.
pub(super) const LINE_SPACING: f64 = 1.25;

/// Space around a figure's title and a panel's chart, px.
pub(super) const MARGIN: f64 = 10.0;

/// Height of the x-axis label area (tick labels and description), px.
pub(super) const X_LABEL_AREA: u32 = 45;

/// Width of a legend marker, the gap to its text and the gap between
/// entries, px.
pub(super) const MARK_W: f64 = 18.0;

pub(super) const MARK_GAP: f64 = 5.0;

pub(super) const ENTRY_GAP: f64 = 18.0;

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
pub(super) fn wrap(text: &str, max_w: f64, size: f64) -> Vec<String> {
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
pub(super) fn ellipsize(text: &str, max_w: f64, size: f64) -> String {
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
pub(super) fn draw_lines<DB: DrawingBackend>(
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
