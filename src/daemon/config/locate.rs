//! Where in the file a configuration error is: the line and column of a
//! byte offset, the key path at an offset (`camera.pixl_um`) and the offset
//! of a key path, and the near miss of a misspelt key.
//!
//! Why: toml reports a wrong key or type with a byte span and serde's
//! message ("unknown field `pixl_um`, expected one of …"); a person needs
//! the line, the section and the key they mistyped (issue 33: "at byte
//! 217"). The key path comes from a second read of the same text by
//! `toml_edit`, which keeps every key's and value's span (`toml::Spanned`
//! cannot: it fails on the implicit table of a `[driver.x]` header); a
//! text that read cannot take (a syntax error) still gets its line and
//! column.

use std::ops::Range;
use toml_edit::{ImDocument, Item, TableLike, Value};

/// 1-based line and column (in characters) of byte `offset` of `text`
/// (clamped to the text, and back to a character boundary).
pub(super) fn line_column(text: &str, offset: usize) -> (usize, usize) {
    let mut at = offset.min(text.len());
    while !text.is_char_boundary(at) {
        at -= 1;
    }
    let before = &text[..at];
    let line = before.matches('\n').count() + 1;
    let line_start = before.rfind('\n').map_or(0, |i| i + 1);
    (line, before[line_start..].chars().count() + 1)
}

/// One segment of a key path.
#[derive(Debug, Clone, PartialEq)]
enum Segment {
    Key(String),
    Index(usize),
}

fn contains(span: Option<Range<usize>>, at: usize) -> bool {
    span.is_some_and(|s| s.start <= at && at < s.end.max(s.start + 1))
}

fn prefixed(first: Segment, rest: Vec<Segment>) -> Vec<Segment> {
    let mut p = vec![first];
    p.extend(rest);
    p
}

/// The path to the innermost key or value at `at` in a table (a section,
/// an inline table).
fn in_table(t: &dyn TableLike, at: usize) -> Option<Vec<Segment>> {
    for (k, item) in t.iter() {
        let key = || Segment::Key(k.to_owned());
        if contains(t.key(k).and_then(|k| k.span()), at) {
            return Some(vec![key()]);
        }
        if let Some(p) = in_item(item, at) {
            return Some(prefixed(key(), p));
        }
        if contains(item.span(), at) {
            return Some(vec![key()]);
        }
    }
    None
}

fn in_item(item: &Item, at: usize) -> Option<Vec<Segment>> {
    match item {
        Item::Table(t) => in_table(t, at),
        Item::ArrayOfTables(a) => a.iter().enumerate().find_map(|(i, t)| {
            in_table(t, at)
                .map(|p| prefixed(Segment::Index(i), p))
                .or_else(|| contains(t.span(), at).then(|| vec![Segment::Index(i)]))
        }),
        Item::Value(v) => in_value(v, at),
        Item::None => None,
    }
}

fn in_value(v: &Value, at: usize) -> Option<Vec<Segment>> {
    match v {
        Value::InlineTable(t) => in_table(t, at),
        Value::Array(a) => a.iter().enumerate().find_map(|(i, x)| {
            in_value(x, at)
                .map(|p| prefixed(Segment::Index(i), p))
                .or_else(|| contains(x.span(), at).then(|| vec![Segment::Index(i)]))
        }),
        _ => None,
    }
}

/// The dotted key path at byte `at` of `text` (`camera.pixl_um`,
/// `access.roles[1]`), if a key or value is there.
pub(super) fn key_at(text: &str, at: usize) -> Option<String> {
    let doc = ImDocument::parse(text).ok()?;
    let path = in_table(doc.as_table(), at)?;
    let mut s = String::new();
    for seg in path {
        match seg {
            Segment::Key(k) => {
                if !s.is_empty() {
                    s.push('.');
                }
                s.push_str(&k);
            }
            Segment::Index(i) => s.push_str(&format!("[{i}]")),
        }
    }
    (!s.is_empty()).then_some(s)
}

/// Where the dotted key `key` (`characterize.step_um`) is written in
/// `text`: the byte offset of its name, or of the deepest section of it
/// the file writes (a key left to its default is not written).
pub(super) fn offset_of(text: &str, key: &str) -> Option<usize> {
    let doc = ImDocument::parse(text).ok()?;
    let mut table: Option<&dyn TableLike> = Some(doc.as_table());
    let mut found = None;
    for part in key.split('.') {
        let Some((k, item)) = table.and_then(|t| t.get_key_value(part)) else {
            break;
        };
        found = k.span().or_else(|| item.span()).map(|s| s.start).or(found);
        table = item.as_table_like();
    }
    found
}

/// Edit distance between `a` and `b` (optimal string alignment: an
/// insertion, a deletion, a substitution or a swap of neighbours costs 1).
fn edit_distance(a: &str, b: &str) -> usize {
    let a: Vec<char> = a.chars().collect();
    let b: Vec<char> = b.chars().collect();
    let mut d = vec![vec![0usize; b.len() + 1]; a.len() + 1];
    for (i, row) in d.iter_mut().enumerate() {
        row[0] = i;
    }
    for (j, cell) in d[0].iter_mut().enumerate() {
        *cell = j;
    }
    for i in 1..=a.len() {
        for j in 1..=b.len() {
            let cost = usize::from(a[i - 1] != b[j - 1]);
            let mut v = (d[i - 1][j] + 1)
                .min(d[i][j - 1] + 1)
                .min(d[i - 1][j - 1] + cost);
            if i > 1 && j > 1 && a[i - 1] == b[j - 2] && a[i - 2] == b[j - 1] {
                v = v.min(d[i - 2][j - 2] + 1);
            }
            d[i][j] = v;
        }
    }
    d[a.len()][b.len()]
}

/// The candidate closest to `word`, if it is close enough to be a typo:
/// within a third of the word's length (at least 1, at most 3 edits).
pub(super) fn did_you_mean<'a>(word: &str, candidates: &[&'a str]) -> Option<&'a str> {
    let limit = (word.chars().count() / 3).clamp(1, 3);
    candidates
        .iter()
        .map(|c| (edit_distance(word, c), *c))
        .filter(|(d, _)| *d <= limit)
        .min_by_key(|(d, _)| *d)
        .map(|(_, c)| c)
}

/// From serde's "unknown field `x`, expected one of `a`, `b`" (or
/// "unknown variant …", "expected `a` or `b`"): the unknown word and the
/// expected ones.
pub(super) fn unknown_and_expected(message: &str) -> Option<(&str, Vec<&str>)> {
    let rest = message
        .strip_prefix("unknown field `")
        .or_else(|| message.strip_prefix("unknown variant `"))?;
    let (word, rest) = rest.split_once('`')?;
    let expected = rest
        .split_once("expected")
        .map(|(_, list)| list.split('`').skip(1).step_by(2).collect())
        .unwrap_or_default();
    Some((word, expected))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lines_and_columns_count_characters_from_one() {
        let t = "a = 1\n[µ]\nbc = 2\n";
        assert_eq!(line_column(t, 0), (1, 1));
        assert_eq!(line_column(t, t.find("bc").unwrap()), (3, 1));
        assert_eq!(line_column(t, t.find("= 2").unwrap()), (3, 4));
        // Inside the two-byte µ: back to its start.
        assert_eq!(line_column(t, 8), (2, 2));
        assert_eq!(line_column(t, 10_000).0, 4);
    }

    #[test]
    fn key_paths_at_keys_values_inline_tables_and_arrays() {
        let t = "[camera]\npixl_um = 0.4\nlist = [1,\n 2, \"x\"]\n[driver.x]\nport = 3\nin = { b = \"z\" }\n";
        let at = |s: &str| key_at(t, t.find(s).unwrap());
        assert_eq!(at("pixl_um").as_deref(), Some("camera.pixl_um"));
        assert_eq!(at("0.4").as_deref(), Some("camera.pixl_um"));
        assert_eq!(at("\"x\"").as_deref(), Some("camera.list[2]"));
        assert_eq!(at("3\n").as_deref(), Some("driver.x.port"));
        assert_eq!(at("\"z\"").as_deref(), Some("driver.x.in.b"));
        assert_eq!(offset_of(t, "driver.x.port"), t.find("port"));
        // Not written: the deepest section that is.
        assert_eq!(offset_of(t, "camera.bits"), t.find("camera"));
        assert_eq!(key_at("[camera\n", 3), None);
    }

    #[test]
    fn typos_find_their_key_and_strangers_do_not() {
        let keys = ["source", "period_um", "pixel_um", "bits"];
        assert_eq!(did_you_mean("pixl_um", &keys), Some("pixel_um"));
        assert_eq!(
            did_you_mean("sokcet", &["socket", "data_dir"]),
            Some("socket")
        );
        assert_eq!(did_you_mean("exposure_us", &keys), None);
        let (w, e) =
            unknown_and_expected("unknown field `pixl_um`, expected one of `source`, `pixel_um`")
                .unwrap();
        assert_eq!((w, e), ("pixl_um", vec!["source", "pixel_um"]));
        let (w, e) =
            unknown_and_expected("unknown variant `kalmn`, expected `off` or `kalman`").unwrap();
        assert_eq!((w, e), ("kalmn", vec!["off", "kalman"]));
        assert!(unknown_and_expected("invalid type: string \"x\", expected u64").is_none());
    }
}
