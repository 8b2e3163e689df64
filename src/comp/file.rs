//! Compensation files: TOML, `format_version = 1`, specified in
//! `docs/compensation-tables.md`.
//!
//! A file holds one compensation (lookup tables or a fitted stage model),
//! the vision→stage frame it was built in (if known) and where it came
//! from (log path and FNV-1a hash, creation date, free metadata), so that a
//! lab can tell months later which measurement a number was corrected with.
//! The daemon reads it with [`CompFile::read_path`], turns it into a
//! [`Compensator`] with [`CompFile::compensator`], and swaps it in without
//! restart. Every defect is an error naming the key.

use std::collections::BTreeMap;
use std::io::{Read, Write};
use std::path::Path;

use serde::{Deserialize, Serialize};

use super::frame::VisionFrame;
use super::grid::{GridCompensator, GridTable};
use super::table::{CompTable, LookupCompensator};
use super::yaw::YawTables;
use super::{invalid, CompError, Compensator, ModelCompensator};
use crate::model::StageModel;

/// The version this code reads and writes.
pub const COMP_FORMAT_VERSION: u32 = 1;

/// Largest file accepted, bytes (a 5 µm table over 15 mm is ~0.5 MB).
pub const MAX_FILE_BYTES: u64 = 64 << 20;

/// Which compensation the file holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum CompKind {
    /// `[lookup]`: the paper's tables.
    Lookup,
    /// `[model]`: a fitted stage model (the model file format, nested).
    Model,
    /// `[grid]`: a 2-D error map ([`GridTable`]).
    Grid,
}

impl CompKind {
    /// The kind's name in files and replies.
    pub fn as_str(self) -> &'static str {
        match self {
            CompKind::Lookup => "lookup",
            CompKind::Model => "model",
            CompKind::Grid => "grid",
        }
    }
}

/// Where the compensation came from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct SourceInfo {
    /// Path of the measurement log, as given when building.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub log_path: Option<String>,
    /// FNV-1a 64-bit hash of the log's bytes, 16 lowercase hex digits
    /// (identifies the log; not a cryptographic hash).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub log_fnv1a64: Option<String>,
    /// Records used.
    #[serde(default)]
    pub records: u64,
    /// Free key/value metadata (operator, stage serial, the log's `#`
    /// metadata, fit residuals...).
    #[serde(default)]
    pub metadata: BTreeMap<String, String>,
}

/// A compensation file. See the module docs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CompFile {
    /// Must be [`COMP_FORMAT_VERSION`].
    pub format_version: u32,
    /// Which section is present.
    pub kind: CompKind,
    /// When the file was made (RFC 3339 text chosen by the writer; the
    /// library has no clock).
    pub created: String,
    /// Free text.
    #[serde(default)]
    pub description: String,
    /// Provenance.
    #[serde(default)]
    pub source: SourceInfo,
    /// The vision→stage transform the scans were mapped with.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frame: Option<VisionFrame>,
    /// The area the scans covered (`tables build` writes it). A model
    /// file needs it to know its range; a lookup table's own positions are
    /// its area (for a lookup file this key is only informative).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub area: Option<super::Area>,
    /// Tables (kind = "lookup").
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lookup: Option<CompTable>,
    /// Stage model in the model-file format (kind = "model").
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub model: Option<toml::Table>,
    /// A 2-D error map (kind = "grid").
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub grid: Option<GridTable>,
    /// The platform's yaw measured by the same scans (µrad, positive +x
    /// towards +y, relative to the tie), beside any kind: what moves a
    /// tool point predict its arm's turn with. Absent in files built from
    /// logs without θ.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub yaw: Option<YawTables>,
}

impl CompFile {
    /// A lookup-table file.
    pub fn lookup(table: CompTable, created: impl Into<String>, source: SourceInfo) -> Self {
        CompFile {
            format_version: COMP_FORMAT_VERSION,
            kind: CompKind::Lookup,
            created: created.into(),
            description: String::new(),
            source,
            frame: None,
            area: None,
            lookup: Some(table),
            model: None,
            grid: None,
            yaw: None,
        }
    }

    /// A 2-D map file; its area is the span of its nodes.
    pub fn grid(table: GridTable, created: impl Into<String>, source: SourceInfo) -> Self {
        CompFile {
            format_version: COMP_FORMAT_VERSION,
            kind: CompKind::Grid,
            created: created.into(),
            description: String::new(),
            source,
            frame: None,
            area: Some(table.area()),
            lookup: None,
            model: None,
            grid: Some(table),
            yaw: None,
        }
    }

    /// A model file (the model is rendered in the model-file format).
    pub fn model(
        model: &StageModel,
        created: impl Into<String>,
        source: SourceInfo,
    ) -> Result<Self, CompError> {
        let text = model.to_toml()?;
        let table: toml::Table = toml::from_str(&text)
            .map_err(|e| CompError::File(format!("rendering the model: {e}")))?;
        Ok(CompFile {
            format_version: COMP_FORMAT_VERSION,
            kind: CompKind::Model,
            created: created.into(),
            description: String::new(),
            source,
            frame: None,
            area: None,
            lookup: None,
            model: Some(table),
            grid: None,
            yaw: None,
        })
    }

    /// Parses and validates a file.
    pub fn from_toml(text: &str) -> Result<Self, CompError> {
        // Check the version first so that a newer file gets a clear message
        // rather than "unknown field".
        let raw: toml::Table = toml::from_str(text).map_err(|e| syntax_error(text, &e))?;
        match raw.get("format_version") {
            Some(toml::Value::Integer(v)) if *v == i64::from(COMP_FORMAT_VERSION) => {}
            Some(toml::Value::Integer(v)) => {
                return Err(CompError::File(format!(
                    "format_version = {v}: this micropos reads format_version {COMP_FORMAT_VERSION}"
                )))
            }
            Some(_) => return Err(CompError::File("format_version must be an integer".into())),
            None => return Err(CompError::File("missing key `format_version`".into())),
        }
        let f: CompFile = toml::from_str(text).map_err(|e| CompError::File(e.to_string()))?;
        f.validate()?;
        Ok(f)
    }

    /// Checks the sections against `kind` and every value.
    pub fn validate(&self) -> Result<(), CompError> {
        if self.format_version != COMP_FORMAT_VERSION {
            return Err(invalid(
                "format_version",
                format!("must be {COMP_FORMAT_VERSION}"),
            ));
        }
        match (self.kind, &self.lookup, &self.model, &self.grid) {
            (CompKind::Lookup, Some(t), None, None) => t.validate()?,
            (CompKind::Model, None, Some(_), None) => {
                self.stage_model()?;
            }
            (CompKind::Grid, None, None, Some(g)) => g.validate()?,
            (k, _, _, _) => {
                return Err(invalid(
                    "kind",
                    format!("kind = \"{0}\" needs exactly the [{0}] section", k.as_str()),
                ))
            }
        }
        if let Some(h) = &self.source.log_fnv1a64 {
            if h.len() != 16 || !h.chars().all(|c| c.is_ascii_hexdigit()) {
                return Err(invalid("source.log_fnv1a64", "must be 16 hex digits"));
            }
        }
        if let Some(fr) = &self.frame {
            fr.validate()?;
        }
        if let Some(a) = &self.area {
            a.validate("area")?;
        }
        if let Some(y) = &self.yaw {
            y.validate()?;
        }
        Ok(())
    }

    /// The stage model of a `kind = "model"` file.
    pub fn stage_model(&self) -> Result<StageModel, CompError> {
        let t = self
            .model
            .as_ref()
            .ok_or_else(|| invalid("model", "section missing"))?;
        let text = toml::to_string(t).map_err(|e| CompError::File(format!("[model]: {e}")))?;
        StageModel::from_toml(&text).map_err(|e| CompError::File(format!("[model]: {e}")))
    }

    /// The compensator this file describes.
    pub fn compensator(&self) -> Result<Box<dyn Compensator>, CompError> {
        self.validate()?;
        match self.kind {
            CompKind::Lookup => match &self.lookup {
                Some(t) => Ok(Box::new(LookupCompensator::new(t.clone())?)),
                None => Err(invalid("lookup", "section missing")),
            },
            CompKind::Model => Ok(Box::new(
                ModelCompensator::new(self.stage_model()?).with_area(self.area),
            )),
            CompKind::Grid => match &self.grid {
                Some(g) => Ok(Box::new(GridCompensator::new(g.clone())?)),
                None => Err(invalid("grid", "section missing")),
            },
        }
    }

    /// The file text.
    pub fn to_toml(&self) -> Result<String, CompError> {
        self.validate()?;
        toml::to_string(self).map_err(|e| CompError::File(format!("cannot write: {e}")))
    }

    /// Reads from a reader (at most [`MAX_FILE_BYTES`]).
    pub fn read_from(reader: impl Read) -> Result<Self, CompError> {
        let mut bytes = Vec::new();
        reader
            .take(MAX_FILE_BYTES + 1)
            .read_to_end(&mut bytes)
            .map_err(|e| CompError::Io {
                path: "<reader>".into(),
                message: e.to_string(),
            })?;
        Self::from_bytes(&bytes)
    }

    /// Parses bytes (UTF-8 TOML).
    pub fn from_bytes(bytes: &[u8]) -> Result<Self, CompError> {
        if bytes.len() as u64 > MAX_FILE_BYTES {
            return Err(CompError::File(format!(
                "larger than {MAX_FILE_BYTES} bytes"
            )));
        }
        let text =
            std::str::from_utf8(bytes).map_err(|e| CompError::File(format!("not UTF-8: {e}")))?;
        Self::from_toml(text)
    }

    /// Reads a file (a symbolic link is refused).
    pub fn read_path(path: impl AsRef<Path>) -> Result<Self, CompError> {
        let p = path.as_ref();
        let io = |e: std::io::Error| CompError::Io {
            path: p.display().to_string(),
            message: e.to_string(),
        };
        let f = crate::nofollow::open(p).map_err(io)?;
        Self::read_from(f).map_err(|e| match e {
            CompError::Io { message, .. } => CompError::Io {
                path: p.display().to_string(),
                message,
            },
            other => other,
        })
    }

    /// Writes to a writer.
    pub fn write_to(&self, mut w: impl Write) -> Result<(), CompError> {
        let text = self.to_toml()?;
        w.write_all(text.as_bytes()).map_err(|e| CompError::Io {
            path: "<writer>".into(),
            message: e.to_string(),
        })
    }

    /// Writes a file atomically (a new temporary file with a random name in
    /// the same directory, then rename; links never followed,
    /// [`crate::nofollow`]): a daemon watching the path never sees half a
    /// file.
    pub fn write_path(&self, path: impl AsRef<Path>) -> Result<(), CompError> {
        let p = path.as_ref();
        let io = |e: std::io::Error| CompError::Io {
            path: p.display().to_string(),
            message: e.to_string(),
        };
        let text = self.to_toml()?;
        crate::nofollow::write_atomic(p, text.as_bytes()).map_err(io)
    }
}

/// FNV-1a 64-bit hash of `bytes`, 16 lowercase hex digits: names a log in
/// [`SourceInfo::log_fnv1a64`].
pub fn fnv1a64_hex(bytes: &[u8]) -> String {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in bytes {
        h ^= u64::from(*b);
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    format!("{h:016x}")
}

/// A TOML syntax error by line, without the line itself: toml's own
/// message quotes the offending text, and the daemon sends this error to
/// clients about files in its data directory, which may hold anything.
fn syntax_error(text: &str, e: &toml::de::Error) -> CompError {
    let newlines_before = |at: usize| {
        let end = at.min(text.len());
        text.as_bytes()[..end]
            .iter()
            .filter(|&&b| b == b'\n')
            .count()
    };
    let line = e.span().map(|s| newlines_before(s.start) + 1);
    CompError::File(match line {
        Some(l) => format!(
            "not a TOML table file: syntax error at line {l} ({})",
            e.message()
        ),
        None => format!("not a TOML table file: {}", e.message()),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fnv_matches_the_reference_vectors() {
        assert_eq!(fnv1a64_hex(b""), "cbf29ce484222325");
        assert_eq!(fnv1a64_hex(b"a"), "af63dc4c8601ec8c");
        assert_eq!(fnv1a64_hex(b"foobar"), "85944171f73967e8");
    }

    #[test]
    fn version_and_kind_errors_are_clear() {
        let e = CompFile::from_toml("format_version = 2\nkind = \"lookup\"\ncreated = \"x\"\n")
            .unwrap_err();
        assert!(e.to_string().contains("reads format_version 1"), "{e}");
        let e = CompFile::from_toml("kind = \"lookup\"").unwrap_err();
        assert!(e.to_string().contains("format_version"), "{e}");
        let e = CompFile::from_toml("format_version = 1\nkind = \"lookup\"\ncreated = \"x\"\n")
            .unwrap_err();
        assert!(e.to_string().contains("[lookup]"), "{e}");
        let e = CompFile::from_toml("format_version = 1\nkind = \"magic\"\ncreated = \"x\"\n")
            .unwrap_err();
        assert!(e.to_string().contains("kind"), "{e}");
    }

    /// `tables load` reads through `read_path`: a planted link is refused,
    /// and the error never quotes the target's first line.
    #[test]
    fn a_file_that_is_not_toml_is_refused_without_quoting_it() {
        let dir = tempfile::tempdir().unwrap();
        for (text, line) in [
            ("SECRET=hunter2-very-secret\n", 1),
            ("# notes\n\nc4ca4238a0b923820dcc509a6f75849b hunter2\n", 3),
        ] {
            let p = dir.path().join("secret.toml");
            std::fs::write(&p, text).unwrap();
            let e = CompFile::read_path(&p).unwrap_err().to_string();
            assert!(!e.contains("hunter2") && !e.contains("c4ca"), "{e}");
            assert!(e.contains(&format!("line {line}")), "{e}");
        }
    }

    #[test]
    fn read_path_refuses_a_link_without_quoting_the_target() {
        let d = tempfile::tempdir().unwrap();
        let secret = d.path().join("secret");
        std::fs::write(&secret, "root:secret-hash:0:0\n").unwrap();
        let link = d.path().join("t-paper.toml");
        std::os::unix::fs::symlink(&secret, &link).unwrap();
        let e = CompFile::read_path(&link).unwrap_err().to_string();
        assert!(e.contains("symbolic link"), "{e}");
        assert!(!e.contains("secret-hash"), "{e}");
    }
}
