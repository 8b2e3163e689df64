//! Readers of one request field each: the JSON type, the range and the
//! file-name rule, each with the error message a person can act on.
//!
//! Why a file of its own: every command's parser is built from these, so
//! a field of the same kind is checked and worded the same everywhere.

use serde_json::{Map, Value};

use super::{ErrorCode, ProtoError};

/// File names from clients stay inside the data directory: no separators,
/// no `..`, no hidden files, printable and short.
pub(super) fn check_file_name(field: &str, name: &str) -> Result<(), ProtoError> {
    let ok = !name.is_empty()
        && name.len() <= 128
        && !name.starts_with('.')
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.'));
    if ok {
        Ok(())
    } else {
        Err(ProtoError::new(
            ErrorCode::BadValue,
            format!(
                "{field} {:?} must be a plain file name (letters, digits, - _ .; no path, not hidden)",
                truncate(name, 64)
            ),
        ))
    }
}

pub(super) fn req_str<'a>(obj: &'a Map<String, Value>, key: &str) -> Result<&'a str, ProtoError> {
    match obj.get(key) {
        None => Err(ProtoError::new(
            ErrorCode::MissingField,
            format!("field {key} is missing"),
        )),
        Some(Value::String(s)) => Ok(s),
        Some(v) => Err(wrong_type(key, "a string", v)),
    }
}

pub(super) fn opt_str<'a>(
    obj: &'a Map<String, Value>,
    key: &str,
) -> Result<Option<&'a str>, ProtoError> {
    match obj.get(key) {
        None | Some(Value::Null) => Ok(None),
        Some(Value::String(s)) => Ok(Some(s)),
        Some(v) => Err(wrong_type(key, "a string", v)),
    }
}

pub(super) fn opt_bool(obj: &Map<String, Value>, key: &str) -> Result<Option<bool>, ProtoError> {
    match obj.get(key) {
        None | Some(Value::Null) => Ok(None),
        Some(Value::Bool(b)) => Ok(Some(*b)),
        Some(v) => Err(wrong_type(key, "true or false", v)),
    }
}

/// A finite number within ±1e9 (µm or s): anything else is a typo.
pub(super) fn opt_f64(obj: &Map<String, Value>, key: &str) -> Result<Option<f64>, ProtoError> {
    match obj.get(key) {
        None | Some(Value::Null) => Ok(None),
        Some(Value::Number(n)) => match n.as_f64() {
            Some(v) if v.is_finite() && v.abs() <= 1e9 => Ok(Some(v)),
            _ => Err(ProtoError::new(
                ErrorCode::BadValue,
                format!("{key} = {n} is out of range (|value| ≤ 1e9)"),
            )),
        },
        Some(v) => Err(wrong_type(key, "a number", v)),
    }
}

/// An optional number that must lie in `lo..=hi`; `shown` is the range as
/// the error message states it.
pub(super) fn opt_f64_within(
    obj: &Map<String, Value>,
    key: &str,
    lo: f64,
    hi: f64,
    shown: &str,
) -> Result<Option<f64>, ProtoError> {
    let v = opt_f64(obj, key)?;
    match v {
        Some(x) if !(lo..=hi).contains(&x) => Err(ProtoError::new(
            ErrorCode::BadValue,
            format!("{key} must be within {shown}, got {x}"),
        )),
        _ => Ok(v),
    }
}

pub(super) fn opt_count(
    obj: &Map<String, Value>,
    key: &str,
    min: u64,
    max: u64,
) -> Result<Option<u32>, ProtoError> {
    match obj.get(key) {
        None | Some(Value::Null) => Ok(None),
        Some(Value::Number(n)) => match n.as_u64() {
            Some(v) if (min..=max).contains(&v) => Ok(Some(v as u32)),
            _ => Err(ProtoError::new(
                ErrorCode::BadValue,
                format!("{key} = {n} must be an integer within {min}..={max}"),
            )),
        },
        Some(v) => Err(wrong_type(key, "an integer", v)),
    }
}

/// An optional `[x, y]` pair of finite numbers, µm.
pub(super) fn opt_xy(obj: &Map<String, Value>, key: &str) -> Result<Option<[f64; 2]>, ProtoError> {
    let Some(v) = obj.get(key) else {
        return Ok(None);
    };
    match v
        .as_array()
        .map(|a| a.iter().map(Value::as_f64).collect::<Vec<_>>())
    {
        Some(a) if a.len() == 2 => match (a[0], a[1]) {
            (Some(x), Some(y)) if x.is_finite() && y.is_finite() => Ok(Some([x, y])),
            _ => Err(wrong_type(key, "two finite numbers [x, y]", v)),
        },
        _ => Err(wrong_type(key, "an array [x, y] of two numbers", v)),
    }
}

/// The refusal of a word a keyword field does not know: one wording for
/// every such field (`mode "x" unknown; use raw, ...`), the word cut to 64
/// characters so a huge value is not echoed back whole.
pub(super) fn unknown_word(what: &str, got: &str, choices: &str) -> ProtoError {
    ProtoError::new(
        ErrorCode::BadValue,
        format!("{what} {:?} unknown; use {choices}", truncate(got, 64)),
    )
}

pub(super) fn wrong_type(key: &str, expected: &str, got: &Value) -> ProtoError {
    ProtoError::new(
        ErrorCode::WrongType,
        format!("{key} must be {expected}, got {}", type_name(got)),
    )
}

pub(super) fn type_name(v: &Value) -> &'static str {
    match v {
        Value::Null => "null",
        Value::Bool(_) => "a boolean",
        Value::Number(_) => "a number",
        Value::String(_) => "a string",
        Value::Array(_) => "an array",
        Value::Object(_) => "an object",
    }
}

pub(super) fn truncate(s: &str, max_chars: usize) -> String {
    s.chars().take(max_chars).collect()
}
