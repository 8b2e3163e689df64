//! The Megarena pseudo-periodic pattern: its code sequence, its dot layout,
//! rendering and decoding.
//!
//! Pattern frame convention (used everywhere in micropos): origin at the
//! centre of dot (column 0, row 0); x grows with the column index, y with the
//! row index; units are micrometres. Dot (c, r) is centred at (c·p, r·p) for
//! period p.

pub mod decode;
pub mod export;
pub mod plan;
pub mod render;
pub mod sequence;
