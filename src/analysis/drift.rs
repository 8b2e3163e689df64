//! Drift correction from re-measurements of a reference point (placeholder
//! filled in below).
