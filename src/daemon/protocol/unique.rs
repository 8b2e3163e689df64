//! JSON with every object key named once.
//!
//! Why: `serde_json` keeps the last of two equal keys, other parsers the
//! first. `{"cmd":"status","cmd":"move"}` would run as a move here while a
//! filter or a log reader upstream reads a status: one line, two meanings.
//! A request that names a key twice, at any depth, is refused instead.

use serde::de::{self, Deserialize, Deserializer, MapAccess, SeqAccess, Visitor};
use serde_json::{Map, Value};

/// A JSON value whose objects had no repeated key.
pub(super) struct UniqueValue(pub(super) Value);

/// Marker that starts the error a repeated key raises (so the caller can
/// tell it from a syntax error).
pub(super) const DUPLICATE: &str = "duplicate key ";

impl<'de> Deserialize<'de> for UniqueValue {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        d.deserialize_any(UniqueVisitor)
    }
}

struct UniqueVisitor;

impl<'de> Visitor<'de> for UniqueVisitor {
    type Value = UniqueValue;

    fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        f.write_str("a JSON value")
    }

    fn visit_bool<E>(self, v: bool) -> Result<UniqueValue, E> {
        Ok(UniqueValue(Value::Bool(v)))
    }

    fn visit_i64<E>(self, v: i64) -> Result<UniqueValue, E> {
        Ok(UniqueValue(Value::from(v)))
    }

    fn visit_u64<E>(self, v: u64) -> Result<UniqueValue, E> {
        Ok(UniqueValue(Value::from(v)))
    }

    fn visit_f64<E>(self, v: f64) -> Result<UniqueValue, E> {
        // JSON numbers are finite; `from` maps anything else to null.
        Ok(UniqueValue(Value::from(v)))
    }

    fn visit_str<E>(self, v: &str) -> Result<UniqueValue, E> {
        Ok(UniqueValue(Value::String(v.to_owned())))
    }

    fn visit_string<E>(self, v: String) -> Result<UniqueValue, E> {
        Ok(UniqueValue(Value::String(v)))
    }

    fn visit_unit<E>(self) -> Result<UniqueValue, E> {
        Ok(UniqueValue(Value::Null))
    }

    fn visit_none<E>(self) -> Result<UniqueValue, E> {
        Ok(UniqueValue(Value::Null))
    }

    fn visit_some<D: Deserializer<'de>>(self, d: D) -> Result<UniqueValue, D::Error> {
        UniqueValue::deserialize(d)
    }

    fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<UniqueValue, A::Error> {
        let mut v = Vec::new();
        while let Some(UniqueValue(e)) = seq.next_element()? {
            v.push(e);
        }
        Ok(UniqueValue(Value::Array(v)))
    }

    fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<UniqueValue, A::Error> {
        let mut obj = Map::new();
        while let Some(k) = map.next_key::<String>()? {
            if obj.contains_key(&k) {
                return Err(de::Error::custom(format!("{DUPLICATE}{k:?}")));
            }
            let UniqueValue(v) = map.next_value()?;
            obj.insert(k, v);
        }
        Ok(UniqueValue(Value::Object(obj)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn parse(s: &str) -> Result<Value, String> {
        serde_json::from_str::<UniqueValue>(s)
            .map(|u| u.0)
            .map_err(|e| e.to_string())
    }

    #[test]
    fn a_repeated_key_is_refused_at_any_depth() {
        assert!(parse(r#"{"cmd":"status","cmd":"move"}"#)
            .unwrap_err()
            .contains("\"cmd\""));
        assert!(parse(r#"{"a":[{"b":1,"b":2}]}"#)
            .unwrap_err()
            .contains("\"b\""));
        // The same key in two objects is no repetition.
        assert!(parse(r#"{"a":{"b":1},"c":{"b":2}}"#).is_ok());
        // An escaped spelling of the same key is the same key.
        assert!(parse(r#"{"cmd":1,"c\u006dd":2}"#).is_err());
    }

    proptest! {
        #[test]
        fn without_repeats_it_reads_what_serde_json_reads(v in any::<std::collections::BTreeMap<String, i64>>()) {
            let text = serde_json::to_string(&v).unwrap();
            prop_assert_eq!(parse(&text).unwrap(), serde_json::from_str::<Value>(&text).unwrap());
        }

        #[test]
        fn any_text_is_read_or_refused(s in ".{0,200}") {
            let _ = parse(&s);
        }
    }
}
