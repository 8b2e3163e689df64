//! Test support: reads back what a figure's SVG drew — every text with its
//! box (measured with the font the renderer fits text with) and every
//! circle — so tests can check that text stays on the canvas, legends stay
//! off the data and labels do not overlap.

use super::figure::text_extent;

/// A box in canvas pixels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BoxPx {
    pub x0: f64,
    pub y0: f64,
    pub x1: f64,
    pub y1: f64,
}

impl BoxPx {
    /// Whether the two boxes share more than `slack` px in both directions.
    pub fn overlaps(&self, o: &BoxPx, slack: f64) -> bool {
        self.x0 + slack < o.x1
            && o.x0 + slack < self.x1
            && self.y0 + slack < o.y1
            && o.y0 + slack < self.y1
    }

    /// Whether the box lies within `0..w` × `0..h` (`slack` px allowed).
    pub fn inside(&self, w: f64, h: f64, slack: f64) -> bool {
        self.x0 >= -slack && self.y0 >= -slack && self.x1 <= w + slack && self.y1 <= h + slack
    }

    /// The smallest box holding both.
    pub fn union(&self, o: &BoxPx) -> BoxPx {
        BoxPx {
            x0: self.x0.min(o.x0),
            y0: self.y0.min(o.y0),
            x1: self.x1.max(o.x1),
            y1: self.y1.max(o.y1),
        }
    }
}

/// One `<text>` element.
#[derive(Debug, Clone, PartialEq)]
pub struct SvgText {
    pub x: f64,
    pub y: f64,
    /// `start`, `middle` or `end`.
    pub anchor: String,
    /// The `dy` attribute: `0.76em` (top), `0.5ex` (centre), `-0.5ex`
    /// (bottom).
    pub dy: String,
    /// Font size as drawn (plotters writes size / 1.24 into the SVG).
    pub size_px: f64,
    /// Rotation, degrees (0, 90, 270).
    pub rotate: f64,
    pub text: String,
}

impl SvgText {
    /// The box the text covers.
    pub fn bbox(&self) -> BoxPx {
        let (w, h) = text_extent(&self.text, self.size_px);
        let (ax0, ax1) = match self.anchor.as_str() {
            "middle" => (-w / 2.0, w / 2.0),
            "end" => (-w, 0.0),
            _ => (0.0, w),
        };
        let (ay0, ay1) = match self.dy.as_str() {
            "0.76em" => (0.0, h),
            "0.5ex" => (-h / 2.0, h / 2.0),
            _ => (-h, 0.0),
        };
        // SVG rotate(a) about (x, y): x' = dx cos a − dy sin a, y' = dx sin a + dy cos a.
        let (x0, x1, y0, y1) = match self.rotate.round() as i64 {
            270 => (ay0, ay1, -ax1, -ax0),
            90 => (-ay1, -ay0, ax0, ax1),
            _ => (ax0, ax1, ay0, ay1),
        };
        BoxPx {
            x0: self.x + x0,
            y0: self.y + y0,
            x1: self.x + x1,
            y1: self.y + y1,
        }
    }
}

fn attr(tag: &str, name: &str) -> Option<String> {
    let key = format!(" {name}=\"");
    let i = tag.find(&key)? + key.len();
    let j = tag[i..].find('"')? + i;
    Some(tag[i..j].to_string())
}

fn num(tag: &str, name: &str) -> f64 {
    attr(tag, name)
        .and_then(|v| v.trim().parse().ok())
        .unwrap_or(f64::NAN)
}

fn unescape(s: &str) -> String {
    s.replace("&lt;", "<")
        .replace("&gt;", ">")
        .replace("&quot;", "\"")
        .replace("&apos;", "'")
        .replace("&amp;", "&")
}

/// The canvas size from the `<svg>` element.
pub fn canvas(svg: &str) -> (f64, f64) {
    let i = svg.find("<svg").expect("an <svg> element");
    let tag = &svg[i..i + svg[i..].find('>').expect("closed <svg>")];
    (num(tag, "width"), num(tag, "height"))
}

/// Every `<text>` element.
pub fn texts(svg: &str) -> Vec<SvgText> {
    let mut out = Vec::new();
    let mut rest = svg;
    while let Some(i) = rest.find("<text ") {
        rest = &rest[i..];
        let end = rest.find('>').expect("closed <text>");
        let tag = &rest[..end];
        let close = rest.find("</text>").expect("</text>");
        let text = unescape(rest[end + 1..close].trim());
        let rotate = attr(tag, "transform")
            .and_then(|t| {
                t.strip_prefix("rotate(")
                    .and_then(|r| r.split(',').next())
                    .and_then(|a| a.trim().parse().ok())
            })
            .unwrap_or(0.0);
        out.push(SvgText {
            x: num(tag, "x"),
            y: num(tag, "y"),
            anchor: attr(tag, "text-anchor").unwrap_or_else(|| "start".into()),
            dy: attr(tag, "dy").unwrap_or_default(),
            size_px: num(tag, "font-size") * 1.24,
            rotate,
            text,
        });
        rest = &rest[close..];
    }
    out
}

/// Every `<circle>`: centre and radius.
pub fn circles(svg: &str) -> Vec<(f64, f64, f64)> {
    let mut out = Vec::new();
    let mut rest = svg;
    while let Some(i) = rest.find("<circle ") {
        rest = &rest[i..];
        let end = rest.find('>').expect("closed <circle>");
        let tag = &rest[..end];
        out.push((num(tag, "cx"), num(tag, "cy"), num(tag, "r")));
        rest = &rest[end..];
    }
    out
}

/// Every text whose box leaves the canvas, as "text: box".
pub fn texts_off_canvas(svg: &str) -> Vec<String> {
    let (w, h) = canvas(svg);
    texts(svg)
        .into_iter()
        .filter(|t| !t.bbox().inside(w, h, 0.5))
        .map(|t| format!("{:?}: {:?}", t.text, t.bbox()))
        .collect()
}
