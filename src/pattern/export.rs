//! Fabrication export of the Megarena layout: SVG, GDSII and PNG masks.
//!
//! Why: the pattern is made by lithography from a mask the decoder must agree
//! with bit for bit. Exporting straight from [`LineSequence`] — the same
//! definition the renderer and decoder use — removes the hand-drawn mask as
//! a source of error.
//!
//! Geometry: dot (c, r) is a square of side `dot_um` centred at
//! (c·p, r·p) µm in the pattern frame (see [`crate::pattern`]). A region is
//! the half-open column range c0..c1 and row range r0..r1; its canvas spans
//! [c0·p − p/2, c1·p − p/2) × [r0·p − p/2, r1·p − p/2), so each cell of the
//! grid is one period wide with its dot in the middle.
//!
//! Axis orientation: every format writes pattern coordinates unchanged.
//! SVG and PNG have y pointing down on screen, so they look like the camera
//! image of the pattern (row index grows downwards). GDSII has y pointing
//! up, so a GDS viewer shows the same layout mirrored top-to-bottom; the
//! coordinates of every dot are nevertheless identical in all three.
//!
//! Size: full patterns hold millions of dots (12-bit: ~88 million), so the
//! writers stream to any `Write` (wrap files in a `BufWriter`) and never
//! build the file in memory; [`ExportLimits`] refuses requests that would
//! silently fill a disk.
//!
//! This module does no I/O of its own: callers pass the writer.

use std::io::{self, Write};

use thiserror::Error;

use super::sequence::{LineSequence, SequenceError};

/// Why an export was refused or failed.
#[derive(Debug, Error)]
pub enum ExportError {
    /// The request makes no geometric sense.
    #[error("bad export request: {0}")]
    BadRequest(String),
    /// The code depth is not supported.
    #[error(transparent)]
    Sequence(#[from] SequenceError),
    /// The output would exceed the configured limit.
    #[error("{what} ({amount}) exceeds the limit {limit}; export a smaller region or raise the limit ({hint})")]
    TooLarge {
        /// What is too large ("dots", "PNG pixels").
        what: &'static str,
        /// The requested amount.
        amount: u64,
        /// The limit in force.
        limit: u64,
        /// How to raise it.
        hint: &'static str,
    },
    /// Writing failed.
    #[error("write failed: {0}")]
    Io(#[from] io::Error),
    /// The PNG encoder refused.
    #[error("PNG encoding failed: {0}")]
    Png(String),
}

/// A rectangular block of the dot grid: columns `c0..c1`, rows `r0..r1`
/// (half-open, like Rust ranges).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Region {
    /// First column.
    pub c0: i64,
    /// One past the last column.
    pub c1: i64,
    /// First row.
    pub r0: i64,
    /// One past the last row.
    pub r1: i64,
}

impl Region {
    /// The whole pattern of a sequence.
    pub fn full(seq: &LineSequence) -> Self {
        let l = seq.len() as i64;
        Self {
            c0: 0,
            c1: l,
            r0: 0,
            r1: l,
        }
    }

    /// The columns and rows whose dot centres lie in [x0, x1] × [y0, y1] µm.
    pub fn from_um(
        x0: f64,
        x1: f64,
        y0: f64,
        y1: f64,
        period_um: f64,
    ) -> Result<Self, ExportError> {
        if ![x0, x1, y0, y1, period_um].iter().all(|v| v.is_finite()) || period_um <= 0.0 {
            return Err(ExportError::BadRequest(
                "region bounds and period must be finite, period positive".into(),
            ));
        }
        let lo = |v: f64| (v / period_um).ceil();
        let hi = |v: f64| (v / period_um).floor() + 1.0;
        let lim = 1e15;
        let vals = [lo(x0), hi(x1), lo(y0), hi(y1)];
        if vals.iter().any(|v| v.abs() > lim) {
            return Err(ExportError::BadRequest("region is absurdly large".into()));
        }
        Ok(Self {
            c0: vals[0] as i64,
            c1: vals[1] as i64,
            r0: vals[2] as i64,
            r1: vals[3] as i64,
        })
    }

    /// Number of columns.
    pub fn cols(&self) -> u64 {
        self.c1.saturating_sub(self.c0).max(0) as u64
    }

    /// Number of rows.
    pub fn rows(&self) -> u64 {
        self.r1.saturating_sub(self.r0).max(0) as u64
    }
}

/// Guards against runaway exports.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ExportLimits {
    /// Most dots an SVG or GDSII file may hold. A GDSII boundary takes 72
    /// bytes and an SVG rect about 60, so the default 20 million dots is
    /// about 1.4 GB.
    pub max_dots: u64,
    /// Most pixels a PNG mask may have (default 1 gigapixel).
    pub max_png_pixels: u64,
}

impl Default for ExportLimits {
    fn default() -> Self {
        Self {
            max_dots: 20_000_000,
            max_png_pixels: 1 << 30,
        }
    }
}

/// A region of the layout ready to export.
#[derive(Debug, Clone)]
pub struct Layout {
    seq: LineSequence,
    period_um: f64,
    dot_um: f64,
    region: Region,
}

impl Layout {
    /// Checks the request. `dot_um` = None uses half the period, the
    /// pattern's design value; a dot may not exceed the period (neighbours
    /// would merge and the grid would vanish).
    pub fn new(
        bits: u32,
        period_um: f64,
        dot_um: Option<f64>,
        region: Option<Region>,
    ) -> Result<Self, ExportError> {
        let seq = LineSequence::new(bits)?;
        if !(period_um.is_finite() && period_um > 0.0) {
            return Err(ExportError::BadRequest(format!(
                "period must be a positive number of µm, got {period_um}"
            )));
        }
        let dot_um = dot_um.unwrap_or(period_um / 2.0);
        if !(dot_um.is_finite() && dot_um > 0.0 && dot_um < period_um) {
            return Err(ExportError::BadRequest(format!(
                "dot size must be in (0, period) = (0, {period_um}) µm, got {dot_um}"
            )));
        }
        let region = region.unwrap_or_else(|| Region::full(&seq));
        if region.c1 <= region.c0 || region.r1 <= region.r0 {
            return Err(ExportError::BadRequest(format!(
                "empty region: columns {}..{}, rows {}..{}",
                region.c0, region.c1, region.r0, region.r1
            )));
        }
        let l = seq.len() as i64;
        if region.c1 <= 0 || region.r1 <= 0 || region.c0 >= l || region.r0 >= l {
            return Err(ExportError::BadRequest(format!(
                "region columns {}..{}, rows {}..{} lies outside the pattern 0..{l}",
                region.c0, region.c1, region.r0, region.r1
            )));
        }
        Ok(Self {
            seq,
            period_um,
            dot_um,
            region,
        })
    }

    /// The sequence the layout follows.
    pub fn sequence(&self) -> &LineSequence {
        &self.seq
    }

    /// Period in µm.
    pub fn period_um(&self) -> f64 {
        self.period_um
    }

    /// Dot side in µm.
    pub fn dot_um(&self) -> f64 {
        self.dot_um
    }

    /// The exported region.
    pub fn region(&self) -> Region {
        self.region
    }

    /// Canvas origin (top-left in SVG/PNG) and size in µm.
    pub fn canvas_um(&self) -> (f64, f64, f64, f64) {
        let p = self.period_um;
        (
            self.region.c0 as f64 * p - p / 2.0,
            self.region.r0 as f64 * p - p / 2.0,
            self.region.cols() as f64 * p,
            self.region.rows() as f64 * p,
        )
    }

    /// The region clipped to the pattern, where dots can exist.
    fn clipped(&self) -> (i64, i64, i64, i64) {
        let l = self.seq.len() as i64;
        (
            self.region.c0.max(0),
            self.region.c1.min(l),
            self.region.r0.max(0),
            self.region.r1.min(l),
        )
    }

    /// Exact number of dots in the region, in O(rows + columns).
    pub fn dot_count(&self) -> u64 {
        let (c0, c1, r0, r1) = self.clipped();
        let (mut cols, mut cols_not3) = (0u64, 0u64);
        for c in c0..c1 {
            if self.seq.line(c) {
                cols += 1;
                if c.rem_euclid(3) != 0 {
                    cols_not3 += 1;
                }
            }
        }
        (r0..r1)
            .filter(|&r| self.seq.line(r))
            .map(|r| {
                if r.rem_euclid(3) == 0 {
                    cols_not3
                } else {
                    cols
                }
            })
            .sum()
    }

    /// Present dots, row by row, columns ascending.
    pub fn dots(&self) -> impl Iterator<Item = (i64, i64)> + '_ {
        let (c0, c1, r0, r1) = self.clipped();
        (r0..r1).filter(|&r| self.seq.line(r)).flat_map(move |r| {
            (c0..c1)
                .filter(move |&c| self.seq.dot(c, r))
                .map(move |c| (c, r))
        })
    }

    fn check_dots(&self, limits: &ExportLimits) -> Result<u64, ExportError> {
        let n = self.dot_count();
        if n > limits.max_dots {
            return Err(ExportError::TooLarge {
                what: "dots",
                amount: n,
                limit: limits.max_dots,
                hint: "--max-dots",
            });
        }
        Ok(n)
    }
}

/// Formats a length in µm with at most 6 decimals (1 pm), trailing zeros
/// removed, so SVG files are compact and free of float noise.
fn fmt_um(v: f64) -> String {
    let s = format!("{v:.6}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    if s == "-0" {
        "0".into()
    } else {
        s.to_string()
    }
}

/// Writes the layout as SVG: one `<rect>` per dot, user unit = 1 µm, the
/// document size given in mm so viewers and plotters scale it right.
/// Returns the number of dots written.
pub fn write_svg<W: Write>(
    layout: &Layout,
    limits: &ExportLimits,
    mut out: W,
) -> Result<u64, ExportError> {
    layout.check_dots(limits)?;
    let (x0, y0, w, h) = layout.canvas_um();
    let (p, d) = (layout.period_um, layout.dot_um);
    let r = layout.region;
    writeln!(out, r#"<?xml version="1.0" encoding="UTF-8"?>"#)?;
    writeln!(
        out,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{}mm" height="{}mm" viewBox="{} {} {} {}">"#,
        fmt_um(w / 1000.0),
        fmt_um(h / 1000.0),
        fmt_um(x0),
        fmt_um(y0),
        fmt_um(w),
        fmt_um(h)
    )?;
    writeln!(
        out,
        "<desc>Megarena pattern, {}-bit code, period {} um, dot {} um, columns {}..{}, rows {}..{}. \
         User unit = 1 um; dot (c, r) centred at (c*p, r*p); y grows downwards.</desc>",
        layout.seq.bits(),
        fmt_um(p),
        fmt_um(d),
        r.c0,
        r.c1,
        r.r0,
        r.r1
    )?;
    writeln!(out, r#"<g fill="black" stroke="none">"#)?;
    let ds = fmt_um(d);
    let mut n = 0u64;
    for (c, r) in layout.dots() {
        writeln!(
            out,
            r#"<rect x="{}" y="{}" width="{ds}" height="{ds}"/>"#,
            fmt_um(c as f64 * p - d / 2.0),
            fmt_um(r as f64 * p - d / 2.0)
        )?;
        n += 1;
    }
    writeln!(out, "</g>\n</svg>")?;
    out.flush()?;
    Ok(n)
}

/// A GDSII timestamp (BGNLIB/BGNSTR), UTC.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct GdsDate {
    /// Full year, e.g. 2025.
    pub year: u16,
    /// 1..=12.
    pub month: u16,
    /// 1..=31.
    pub day: u16,
    /// 0..=23.
    pub hour: u16,
    /// 0..=59.
    pub minute: u16,
    /// 0..=59.
    pub second: u16,
}

impl GdsDate {
    /// The UTC date of a Unix time (seconds since 1970-01-01).
    pub fn from_unix(secs: u64) -> Self {
        let t = crate::clock::UtcTime::from_unix(secs);
        Self {
            year: t.year.clamp(0, i64::from(u16::MAX)) as u16,
            month: t.month as u16,
            day: t.day as u16,
            hour: t.hour as u16,
            minute: t.minute as u16,
            second: t.second as u16,
        }
    }

    fn words(&self) -> [u16; 6] {
        [
            self.year,
            self.month,
            self.day,
            self.hour,
            self.minute,
            self.second,
        ]
    }
}

/// GDSII output options.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct GdsOptions {
    /// Library name (LIBNAME).
    pub library: String,
    /// Cell name (STRNAME); GDSII allows A–Z, a–z, 0–9, `_`, `?`, `$`, up to 32 characters.
    pub cell: String,
    /// Layer number of the dots.
    pub layer: u16,
    /// Datatype of the dots.
    pub datatype: u16,
    /// Creation/modification date written in BGNLIB and BGNSTR. Fixed by
    /// default so identical requests give identical files.
    pub date: GdsDate,
}

impl Default for GdsOptions {
    fn default() -> Self {
        Self {
            library: "MICROPOS".into(),
            cell: "MEGARENA".into(),
            layer: 1,
            datatype: 0,
            date: GdsDate::from_unix(0),
        }
    }
}

/// GDSII record types used here (record type byte, data type byte).
pub mod gds_record {
    /// HEADER, int2.
    pub const HEADER: [u8; 2] = [0x00, 0x02];
    /// BGNLIB, int2 ×12.
    pub const BGNLIB: [u8; 2] = [0x01, 0x02];
    /// LIBNAME, ASCII.
    pub const LIBNAME: [u8; 2] = [0x02, 0x06];
    /// UNITS, real8 ×2.
    pub const UNITS: [u8; 2] = [0x03, 0x05];
    /// ENDLIB, no data.
    pub const ENDLIB: [u8; 2] = [0x04, 0x00];
    /// BGNSTR, int2 ×12.
    pub const BGNSTR: [u8; 2] = [0x05, 0x02];
    /// STRNAME, ASCII.
    pub const STRNAME: [u8; 2] = [0x06, 0x06];
    /// ENDSTR, no data.
    pub const ENDSTR: [u8; 2] = [0x07, 0x00];
    /// BOUNDARY, no data.
    pub const BOUNDARY: [u8; 2] = [0x08, 0x00];
    /// LAYER, int2.
    pub const LAYER: [u8; 2] = [0x0D, 0x02];
    /// DATATYPE, int2.
    pub const DATATYPE: [u8; 2] = [0x0E, 0x02];
    /// XY, int4 pairs.
    pub const XY: [u8; 2] = [0x10, 0x03];
    /// ENDEL, no data.
    pub const ENDEL: [u8; 2] = [0x11, 0x00];
}

/// Database unit: 1 nm. User unit: 1 µm, so UNITS holds (1e-3, 1e-9):
/// a database unit is 1e-3 user units and 1e-9 m.
pub const GDS_DB_UNIT_M: f64 = 1e-9;
/// User units per database unit (µm per nm).
pub const GDS_USER_PER_DB: f64 = 1e-3;

/// Encodes a GDSII 8-byte real: sign bit, 7-bit base-16 exponent with
/// excess 64, 56-bit mantissa m with value = m / 2^56 · 16^(exp − 64) and
/// 1/16 ≤ m / 2^56 < 1. The mantissa is rounded to nearest. Values whose
/// exponent does not fit (|v| ≥ 16^63 or 0 < |v| < 16^−65) are refused.
pub fn gds_real8(v: f64) -> Result<[u8; 8], ExportError> {
    if !v.is_finite() {
        return Err(ExportError::BadRequest(format!(
            "GDSII real cannot hold {v}"
        )));
    }
    if v == 0.0 {
        return Ok([0; 8]);
    }
    let sign = if v < 0.0 { 1u64 << 63 } else { 0 };
    let mut m = v.abs();
    let mut e: i32 = 0;
    while m >= 1.0 {
        m /= 16.0;
        e += 1;
    }
    while m < 1.0 / 16.0 {
        m *= 16.0;
        e -= 1;
    }
    // m·2^56 is exact in f64 terms up to the rounding of the product, which
    // only scales by a power of two: the rounding happens in `round`.
    let mut mant = (m * (1u64 << 56) as f64).round() as u64;
    if mant >= 1 << 56 {
        mant >>= 4;
        e += 1;
    }
    let exp = e + 64;
    if !(0..=127).contains(&exp) {
        return Err(ExportError::BadRequest(format!(
            "{v} is outside the GDSII real range"
        )));
    }
    Ok((sign | (exp as u64) << 56 | mant).to_be_bytes())
}

/// Decodes a GDSII 8-byte real (see [`gds_real8`]).
pub fn gds_real8_decode(b: [u8; 8]) -> f64 {
    let bits = u64::from_be_bytes(b);
    let sign = if bits >> 63 == 1 { -1.0 } else { 1.0 };
    let exp = ((bits >> 56) & 0x7F) as i32 - 64;
    let mant = (bits & ((1 << 56) - 1)) as f64 / (1u64 << 56) as f64;
    sign * mant * 16f64.powi(exp)
}

fn gds_rec<W: Write>(out: &mut W, kind: [u8; 2], data: &[u8]) -> Result<(), ExportError> {
    let len = u16::try_from(data.len() + 4)
        .map_err(|_| ExportError::BadRequest("GDSII record too long".into()))?;
    out.write_all(&len.to_be_bytes())?;
    out.write_all(&kind)?;
    out.write_all(data)?;
    Ok(())
}

fn gds_name(name: &str, what: &str) -> Result<Vec<u8>, ExportError> {
    if name.is_empty()
        || name.len() > 32
        || !name
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || matches!(b, b'_' | b'?' | b'$'))
    {
        return Err(ExportError::BadRequest(format!(
            "GDSII {what} {name:?} must be 1–32 characters of A–Z a–z 0–9 _ ? $"
        )));
    }
    let mut v = name.as_bytes().to_vec();
    if v.len() % 2 == 1 {
        v.push(0);
    }
    Ok(v)
}

/// Converts µm to database units (nm), refusing what an int4 cannot hold.
fn to_db(v_um: f64) -> Result<i32, ExportError> {
    let nm = (v_um / GDS_USER_PER_DB).round();
    if !(nm >= f64::from(i32::MIN) && nm <= f64::from(i32::MAX)) {
        return Err(ExportError::BadRequest(format!(
            "coordinate {v_um} µm does not fit GDSII's 32-bit nm grid (±2.1 m)"
        )));
    }
    Ok(nm as i32)
}

/// Writes the layout as a GDSII stream: one cell holding one closed
/// 5-point BOUNDARY per dot, coordinates in nm (rounded to the nearest nm).
/// Returns the number of dots written.
pub fn write_gds<W: Write>(
    layout: &Layout,
    options: &GdsOptions,
    limits: &ExportLimits,
    mut out: W,
) -> Result<u64, ExportError> {
    layout.check_dots(limits)?;
    let lib = gds_name(&options.library, "library name")?;
    let cell = gds_name(&options.cell, "cell name")?;
    // Fail before writing anything if the far corner does not fit.
    let (x0, y0, w, h) = layout.canvas_um();
    to_db(x0 + w)?;
    to_db(y0 + h)?;
    to_db(x0)?;
    to_db(y0)?;

    let int2s = |v: &[u16]| v.iter().flat_map(|x| x.to_be_bytes()).collect::<Vec<u8>>();
    let date = options.date.words();
    let two_dates: Vec<u16> = date.iter().chain(date.iter()).copied().collect();
    gds_rec(&mut out, gds_record::HEADER, &600u16.to_be_bytes())?;
    gds_rec(&mut out, gds_record::BGNLIB, &int2s(&two_dates))?;
    gds_rec(&mut out, gds_record::LIBNAME, &lib)?;
    let mut units = Vec::with_capacity(16);
    units.extend_from_slice(&gds_real8(GDS_USER_PER_DB)?);
    units.extend_from_slice(&gds_real8(GDS_DB_UNIT_M)?);
    gds_rec(&mut out, gds_record::UNITS, &units)?;
    gds_rec(&mut out, gds_record::BGNSTR, &int2s(&two_dates))?;
    gds_rec(&mut out, gds_record::STRNAME, &cell)?;

    let (p, half) = (layout.period_um, layout.dot_um / 2.0);
    let layer = options.layer.to_be_bytes();
    let datatype = options.datatype.to_be_bytes();
    let mut xy = [0u8; 40];
    let mut n = 0u64;
    for (c, r) in layout.dots() {
        let (cx, cy) = (c as f64 * p, r as f64 * p);
        let (xa, xb) = (to_db(cx - half)?, to_db(cx + half)?);
        let (ya, yb) = (to_db(cy - half)?, to_db(cy + half)?);
        // Counter-clockwise in a y-up frame, closed (last = first).
        let pts = [(xa, ya), (xb, ya), (xb, yb), (xa, yb), (xa, ya)];
        for (k, (x, y)) in pts.iter().enumerate() {
            xy[8 * k..8 * k + 4].copy_from_slice(&x.to_be_bytes());
            xy[8 * k + 4..8 * k + 8].copy_from_slice(&y.to_be_bytes());
        }
        gds_rec(&mut out, gds_record::BOUNDARY, &[])?;
        gds_rec(&mut out, gds_record::LAYER, &layer)?;
        gds_rec(&mut out, gds_record::DATATYPE, &datatype)?;
        gds_rec(&mut out, gds_record::XY, &xy)?;
        gds_rec(&mut out, gds_record::ENDEL, &[])?;
        n += 1;
    }
    gds_rec(&mut out, gds_record::ENDSTR, &[])?;
    gds_rec(&mut out, gds_record::ENDLIB, &[])?;
    out.flush()?;
    Ok(n)
}

/// PNG mask options.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PngOptions {
    /// Resolution in pixels per µm.
    pub px_per_um: f64,
    /// Dots white (255) on black (0) when true, black on white otherwise.
    pub dots_white: bool,
}

/// Writes the layout as an 8-bit grayscale PNG holding only 0 and 255.
///
/// Pixel (j, i) covers [x0 + j/s, x0 + (j+1)/s) × [y0 + i/s, y0 + (i+1)/s)
/// µm for s px/µm and canvas origin (x0, y0) (see [`Layout::canvas_um`]);
/// it is a dot pixel when its centre lies strictly inside a dot square.
/// Rows are streamed, so memory stays at one row. Returns (width, height).
pub fn write_png_mask<W: Write>(
    layout: &Layout,
    options: &PngOptions,
    limits: &ExportLimits,
    out: W,
) -> Result<(u32, u32), ExportError> {
    let s = options.px_per_um;
    if !(s.is_finite() && s > 0.0) {
        return Err(ExportError::BadRequest(format!(
            "PNG resolution must be a positive number of px/µm, got {s}"
        )));
    }
    let (x0, y0, w_um, h_um) = layout.canvas_um();
    let (wf, hf) = ((w_um * s).round(), (h_um * s).round());
    let pixels = wf * hf;
    if !(pixels.is_finite() && pixels <= limits.max_png_pixels as f64) {
        return Err(ExportError::TooLarge {
            what: "PNG pixels",
            amount: if pixels.is_finite() {
                pixels as u64
            } else {
                u64::MAX
            },
            limit: limits.max_png_pixels,
            hint: "--max-png-pixels",
        });
    }
    if wf < 1.0 || hf < 1.0 || wf > f64::from(u32::MAX) || hf > f64::from(u32::MAX) {
        return Err(ExportError::BadRequest(format!(
            "a {wf}×{hf} px image cannot be written; change the resolution"
        )));
    }
    let (w, h) = (wf as u32, hf as u32);
    let (p, half) = (layout.period_um, layout.dot_um / 2.0);
    // Which grid line (if any) each pixel column / row centre falls on.
    let nearest = |v: f64| -> Option<i64> {
        let k = (v / p).round();
        ((v - k * p).abs() < half).then_some(k as i64)
    };
    let col_of: Vec<Option<i64>> = (0..w)
        .map(|j| nearest(x0 + (f64::from(j) + 0.5) / s))
        .collect();
    let (on, off) = if options.dots_white {
        (255u8, 0u8)
    } else {
        (0, 255)
    };

    let mut enc = png::Encoder::new(out, w, h);
    enc.set_color(png::ColorType::Grayscale);
    enc.set_depth(png::BitDepth::Eight);
    let mut writer = enc
        .write_header()
        .map_err(|e| ExportError::Png(e.to_string()))?;
    let mut stream = writer
        .stream_writer()
        .map_err(|e| ExportError::Png(e.to_string()))?;
    let mut row = vec![off; w as usize];
    for i in 0..h {
        let r = nearest(y0 + (f64::from(i) + 0.5) / s);
        for (px, c) in row.iter_mut().zip(&col_of) {
            *px = match (c, r) {
                (Some(c), Some(r)) if layout.seq.dot(*c, r) => on,
                _ => off,
            };
        }
        stream.write_all(&row)?;
    }
    stream
        .finish()
        .map_err(|e| ExportError::Png(e.to_string()))?;
    Ok((w, h))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn real8_known_values() {
        assert_eq!(gds_real8(1.0).unwrap(), [0x41, 0x10, 0, 0, 0, 0, 0, 0]);
        assert_eq!(gds_real8(-1.0).unwrap(), [0xC1, 0x10, 0, 0, 0, 0, 0, 0]);
        assert_eq!(gds_real8(0.0).unwrap(), [0; 8]);
        // 1e-9 m per database unit: the UNITS value found in nm-grid files.
        assert_eq!(
            gds_real8(1e-9).unwrap(),
            [0x39, 0x44, 0xB8, 0x2F, 0xA0, 0x9B, 0x5A, 0x54]
        );
        // 1e-3: the f64 value 0.001000…0208 rounds to …A7F0; many tools
        // write the truncated …A7EF. Both decode to 1e-3 within 1 ulp-ish.
        assert_eq!(
            gds_real8(1e-3).unwrap(),
            [0x3E, 0x41, 0x89, 0x37, 0x4B, 0xC6, 0xA7, 0xF0]
        );
        let classic = gds_real8_decode([0x3E, 0x41, 0x89, 0x37, 0x4B, 0xC6, 0xA7, 0xEF]);
        assert!((classic - 1e-3).abs() < 1e-18, "{classic}");
        assert_eq!(gds_real8_decode(gds_real8(1e-3).unwrap()), 1e-3);
        assert!(gds_real8(f64::NAN).is_err());
        assert!(gds_real8(1e300).is_err());
    }

    #[test]
    fn real8_round_trips() {
        for v in [0.5, 3.25, -1234.5678, 1e-6, 7e10, 1.0 / 3.0] {
            let d = gds_real8_decode(gds_real8(v).unwrap());
            assert!((d - v).abs() <= v.abs() * 1e-15, "{v} -> {d}");
        }
    }

    #[test]
    fn dates() {
        let d = GdsDate::from_unix(0);
        assert_eq!((d.year, d.month, d.day, d.hour), (1970, 1, 1, 0));
        // 2024-02-29 12:34:56 UTC = 1709210096.
        let d = GdsDate::from_unix(1_709_210_096);
        assert_eq!(
            (d.year, d.month, d.day, d.hour, d.minute, d.second),
            (2024, 2, 29, 12, 34, 56)
        );
    }

    #[test]
    fn dot_count_matches_iteration() {
        for (bits, region) in [
            (4, None),
            (
                5,
                Some(Region {
                    c0: -5,
                    c1: 40,
                    r0: 3,
                    r1: 17,
                }),
            ),
            (
                6,
                Some(Region {
                    c0: 100,
                    c1: 200,
                    r0: 0,
                    r1: 1,
                }),
            ),
        ] {
            let l = Layout::new(bits, 4.0, None, region).unwrap();
            let n = l.dots().count() as u64;
            assert_eq!(l.dot_count(), n, "bits {bits}");
            assert!(l.dots().all(|(c, r)| l.sequence().dot(c, r)));
        }
        // 4-bit pattern: L = 3·(15 + 3) = 54 lines.
        let l = Layout::new(4, 4.0, None, None).unwrap();
        let brute = (0..54)
            .flat_map(|r| (0..54).map(move |c| (c, r)))
            .filter(|&(c, r)| l.sequence().dot(c, r))
            .count() as u64;
        assert_eq!(l.dot_count(), brute);
    }

    #[test]
    fn rejects_bad_requests() {
        assert!(Layout::new(4, 0.0, None, None).is_err());
        assert!(Layout::new(4, 4.0, Some(4.0), None).is_err());
        assert!(Layout::new(4, 4.0, Some(-1.0), None).is_err());
        assert!(Layout::new(3, 4.0, None, None).is_err());
        let empty = Region {
            c0: 5,
            c1: 5,
            r0: 0,
            r1: 3,
        };
        assert!(Layout::new(4, 4.0, None, Some(empty)).is_err());
        let outside = Region {
            c0: 100,
            c1: 200,
            r0: 0,
            r1: 3,
        };
        assert!(Layout::new(4, 4.0, None, Some(outside)).is_err());
        let l = Layout::new(12, 4.0, None, None).unwrap();
        let e = write_svg(&l, &ExportLimits::default(), io::sink()).unwrap_err();
        assert!(
            matches!(e, ExportError::TooLarge { what: "dots", .. }),
            "{e}"
        );
        let e = write_gds(
            &l,
            &GdsOptions::default(),
            &ExportLimits::default(),
            io::sink(),
        )
        .unwrap_err();
        assert!(matches!(e, ExportError::TooLarge { .. }), "{e}");
        let opts = PngOptions {
            px_per_um: 4.0,
            dots_white: true,
        };
        let e = write_png_mask(&l, &opts, &ExportLimits::default(), io::sink()).unwrap_err();
        assert!(
            matches!(
                e,
                ExportError::TooLarge {
                    what: "PNG pixels",
                    ..
                }
            ),
            "{e}"
        );
        let bad_name = GdsOptions {
            cell: "has space".into(),
            ..GdsOptions::default()
        };
        let small = Layout::new(4, 4.0, None, None).unwrap();
        assert!(write_gds(&small, &bad_name, &ExportLimits::default(), io::sink()).is_err());
        // Coordinates beyond ±2.1 m do not fit int4 nm.
        let huge = Layout::new(10, 1e6, None, None).unwrap();
        assert!(write_gds(
            &huge,
            &GdsOptions::default(),
            &ExportLimits::default(),
            io::sink()
        )
        .is_err());
    }

    #[test]
    fn region_from_um() {
        let r = Region::from_um(0.0, 40.0, -2.0, 8.0, 4.0).unwrap();
        assert_eq!(
            r,
            Region {
                c0: 0,
                c1: 11,
                r0: 0,
                r1: 3
            }
        );
        assert!(Region::from_um(0.0, f64::INFINITY, 0.0, 1.0, 4.0).is_err());
    }

    #[test]
    fn svg_numbers_are_clean() {
        assert_eq!(fmt_um(0.1 + 0.2), "0.3");
        assert_eq!(fmt_um(-2.0), "-2");
        assert_eq!(fmt_um(-0.0000001), "0");
        assert_eq!(fmt_um(12384.0), "12384");
    }
}
