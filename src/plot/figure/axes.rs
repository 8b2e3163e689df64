//! Axes: the ticks (1-2-5 steps on linear axes, decades and 2/5
//! subdivisions on log axes), their labels, the padded data ranges, and
//! the fixed-key coordinate type handed to plotters. A file of its own:
//! pure arithmetic on the data's ranges, shared by the x–y and bar panels.

use super::Scale;
use plotters::coord::cartesian::Cartesian2d;
use plotters::coord::ranged1d::{DefaultFormatting, KeyPointHint, Ranged};
use plotters::coord::types::RangedCoordf64;

/// Nice 1-2-5 ticks covering `[lo, hi]`, at most about `n` of them.
pub(super) fn linear_ticks(lo: f64, hi: f64, n: usize) -> Vec<f64> {
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
pub(super) fn log_ticks(lo: f64, hi: f64) -> Vec<f64> {
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
pub(super) fn tick_label(v: f64) -> String {
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

pub(super) fn pad_range(lo: f64, hi: f64, frac: f64) -> (f64, f64) {
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
pub(super) fn ymap(scale: Scale, y: f64) -> Option<f64> {
    match scale {
        Scale::Linear => y.is_finite().then_some(y),
        Scale::Log => (y.is_finite() && y > 0.0).then(|| y.log10()),
    }
}

/// A linear f64 axis with the ticks given (plotters' own `WithKeyPoints`
/// over f64 loses the label formatter, so the mesh cannot be drawn).
pub(super) struct Keyed {
    pub(super) inner: RangedCoordf64,
    pub(super) keys: Vec<f64>,
}

impl Keyed {
    pub(super) fn new(lo: f64, hi: f64, keys: Vec<f64>) -> Self {
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

pub(super) type Coord = Cartesian2d<Keyed, Keyed>;

pub(super) fn label_area(y_label: &str) -> u32 {
    if y_label.is_empty() {
        45
    } else {
        75
    }
}
