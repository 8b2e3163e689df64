//! CSV field syntax shared by the reader and the writer: comma-separated,
//! spaces around unquoted fields trimmed, RFC 4180 double quotes.

use std::borrow::Cow;

use super::LineError;

pub(super) fn is_field_space(c: char) -> bool {
    c == ' ' || c == '\t'
}

/// Splits a line into fields: comma-separated, spaces/tabs around unquoted
/// fields trimmed, RFC 4180 double quotes (with `""` for a quote) honoured.
pub(super) fn split_fields(line: &str) -> Result<Vec<Cow<'_, str>>, LineError> {
    let mut fields = Vec::new();
    let mut rest = line;
    loop {
        let trimmed = rest.trim_start_matches(is_field_space);
        if let Some(after_quote) = trimmed.strip_prefix('"') {
            let mut value = String::new();
            let mut chars = after_quote.char_indices();
            let end = loop {
                match chars.next() {
                    None => return Err(LineError::BadQuoting("quoted field is not closed")),
                    Some((i, '"')) => {
                        if after_quote[i + 1..].starts_with('"') {
                            value.push('"');
                            chars.next();
                        } else {
                            break i + 1;
                        }
                    }
                    Some((_, c)) => value.push(c),
                }
            };
            fields.push(Cow::Owned(value));
            let after = after_quote[end..].trim_start_matches(is_field_space);
            if after.is_empty() {
                return Ok(fields);
            }
            match after.strip_prefix(',') {
                Some(r) => rest = r,
                None => {
                    return Err(LineError::BadQuoting(
                        "text after the closing quote of a field",
                    ))
                }
            }
        } else {
            match trimmed.find(',') {
                Some(i) => {
                    fields.push(Cow::Borrowed(trimmed[..i].trim_end_matches(is_field_space)));
                    rest = &trimmed[i + 1..];
                }
                None => {
                    fields.push(Cow::Borrowed(trimmed.trim_end_matches(is_field_space)));
                    return Ok(fields);
                }
            }
        }
    }
}

/// Writes a field, quoting it when the reader would otherwise change it.
pub(super) fn push_field(out: &mut String, value: &str) {
    let needs_quotes = value.contains([',', '"'])
        || value.starts_with(is_field_space)
        || value.ends_with(is_field_space)
        || value.starts_with('#');
    if needs_quotes {
        out.push('"');
        out.push_str(&value.replace('"', "\"\""));
        out.push('"');
    } else {
        out.push_str(value);
    }
}
