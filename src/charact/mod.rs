//! Characterization runs and their measurement log.
//!
//! [`log`] defines the on-disk measurement log (CSV with `#` metadata), its
//! tolerant reader and its crash-safe appending writer. The log is the
//! contract between the daemon that measures and every tool that analyses,
//! including tools written by others, so its format is specified in
//! `docs/measurement-log.md` and kept stable. [`import`] converts ISO 230-2
//! exports of other instruments into that format (`micropos import`).

pub mod import;
pub mod import_grid;
pub mod log;
pub mod plan;
pub mod scan;
pub mod sweep;
