//! JSON into a `serde_json::Value` that refuses a key repeated in one
//! object, at any nesting level.
//!
//! Why: `serde_json` keeps the last of two equal keys silently, so
//! `{"cmd":"status","cmd":"move"}` would run as a move while anything that
//! filtered the request reading the first key saw a status. A request with
//! a repeated key has no single meaning; it is refused, naming the key.

use std::fmt;

use serde::de::{self, DeserializeSeed, Deserializer, MapAccess, SeqAccess, Visitor};
use serde_json::{Map, Number, Value};

/// The prefix of the `serde_json` error message a repeated key produces;
/// [`parse_strict`] uses it to tell a repeated key from malformed JSON.
const DUPLICATE: &str = "duplicate key ";

/// Why a text is not a request's JSON.
#[derive(Debug)]
pub(crate) enum StrictError {
    /// A key appears twice in one object (the key, as written).
    DuplicateKey(String),
    /// Not JSON at all.
    Json(serde_json::Error),
}

/// Parses `text` as JSON, refusing a key repeated in any object.
pub(crate) fn parse_strict(text: &str) -> Result<Value, StrictError> {
    let mut de = serde_json::Deserializer::from_str(text);
    let parsed = StrictValue.deserialize(&mut de).and_then(|v| {
        de.end()?;
        Ok(v)
    });
    parsed.map_err(|e| {
        let msg = e.to_string();
        match msg.strip_prefix(DUPLICATE) {
            // The message is `duplicate key "<key>" at line L column C`;
            // the key is JSON-quoted so a quote in it cannot end it early.
            Some(rest) if e.is_data() => {
                let key = rest.rsplit_once(" at line ").map_or(rest, |(k, _)| k);
                StrictError::DuplicateKey(
                    serde_json::from_str::<String>(key).unwrap_or_else(|_| key.to_owned()),
                )
            }
            _ => StrictError::Json(e),
        }
    })
}

/// A seed that builds a [`Value`] and refuses repeated keys.
#[derive(Clone, Copy)]
struct StrictValue;

impl<'de> DeserializeSeed<'de> for StrictValue {
    type Value = Value;
    fn deserialize<D: Deserializer<'de>>(self, d: D) -> Result<Value, D::Error> {
        d.deserialize_any(self)
    }
}

impl<'de> Visitor<'de> for StrictValue {
    type Value = Value;

    fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("any JSON value")
    }
    fn visit_bool<E>(self, v: bool) -> Result<Value, E> {
        Ok(Value::Bool(v))
    }
    fn visit_i64<E>(self, v: i64) -> Result<Value, E> {
        Ok(Value::Number(v.into()))
    }
    fn visit_u64<E>(self, v: u64) -> Result<Value, E> {
        Ok(Value::Number(v.into()))
    }
    fn visit_f64<E>(self, v: f64) -> Result<Value, E> {
        Ok(Number::from_f64(v).map_or(Value::Null, Value::Number))
    }
    fn visit_str<E>(self, v: &str) -> Result<Value, E> {
        Ok(Value::String(v.to_owned()))
    }
    fn visit_string<E>(self, v: String) -> Result<Value, E> {
        Ok(Value::String(v))
    }
    fn visit_none<E>(self) -> Result<Value, E> {
        Ok(Value::Null)
    }
    fn visit_unit<E>(self) -> Result<Value, E> {
        Ok(Value::Null)
    }
    fn visit_some<D: Deserializer<'de>>(self, d: D) -> Result<Value, D::Error> {
        d.deserialize_any(self)
    }
    fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Value, A::Error> {
        let mut out = Vec::new();
        while let Some(v) = seq.next_element_seed(StrictValue)? {
            out.push(v);
        }
        Ok(Value::Array(out))
    }
    fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<Value, A::Error> {
        let mut out = Map::new();
        while let Some(key) = map.next_key::<String>()? {
            if out.contains_key(&key) {
                let quoted = serde_json::to_string(&key).unwrap_or_default();
                return Err(de::Error::custom(format_args!("{DUPLICATE}{quoted}")));
            }
            let v = map.next_value_seed(StrictValue)?;
            out.insert(key, v);
        }
        Ok(Value::Object(out))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn dup(text: &str) -> Option<String> {
        match parse_strict(text) {
            Err(StrictError::DuplicateKey(k)) => Some(k),
            _ => None,
        }
    }

    #[test]
    fn repeated_top_level_key_is_named() {
        assert_eq!(
            dup(r#"{"cmd":"status","cmd":"move"}"#).as_deref(),
            Some("cmd")
        );
    }

    #[test]
    fn repeated_nested_key_is_named() {
        assert_eq!(
            dup(r#"{"a":[1,{"b":{"x":1,"x":2}}]}"#).as_deref(),
            Some("x")
        );
    }

    #[test]
    fn escaped_spellings_of_one_key_are_one_key() {
        assert_eq!(dup(r#"{"cmd":1,"\u0063md":2}"#).as_deref(), Some("cmd"));
        assert_eq!(
            dup(r#"{"a\" at line 1":1,"a\" at line 1":2}"#).as_deref(),
            Some("a\" at line 1")
        );
    }

    #[test]
    fn same_key_in_sibling_objects_is_fine() {
        let v = parse_strict(r#"{"a":{"k":1},"b":{"k":2},"k":[{"k":3},{"k":4}]}"#);
        assert!(v.is_ok());
    }

    #[test]
    fn malformed_json_is_not_a_duplicate() {
        assert!(matches!(
            parse_strict(r#"{"a":1,"#),
            Err(StrictError::Json(_))
        ));
        assert!(matches!(
            parse_strict(r#"{"a":1} x"#),
            Err(StrictError::Json(_))
        ));
    }

    fn json() -> impl Strategy<Value = Value> {
        let leaf = prop_oneof![
            Just(Value::Null),
            any::<bool>().prop_map(Value::Bool),
            any::<i64>().prop_map(|n| Value::Number(n.into())),
            "[a-z\"\\\\]{0,6}".prop_map(Value::String),
        ];
        leaf.prop_recursive(4, 32, 6, |inner| {
            prop_oneof![
                proptest::collection::vec(inner.clone(), 0..5).prop_map(Value::Array),
                proptest::collection::btree_map("[a-z\"]{0,4}", inner, 0..5)
                    .prop_map(|m| Value::Object(m.into_iter().collect())),
            ]
        })
    }

    proptest! {
        /// Without repeats the strict parser agrees with `serde_json`.
        #[test]
        fn agrees_with_serde_json_without_repeats(v in json()) {
            let text = serde_json::to_string(&v).unwrap();
            prop_assert_eq!(parse_strict(&text).ok(), Some(v));
        }

        /// Repeating any key of any object is refused, naming that key.
        #[test]
        fn any_repeated_key_is_refused(v in json(), key in "[a-z\"]{0,4}", inner in json()) {
            let text = serde_json::to_string(&v).unwrap();
            let k = serde_json::to_string(&key).unwrap();
            let i = serde_json::to_string(&inner).unwrap();
            let doc = format!("{{\"w\":{text},{k}:{i},{k}:{text}}}");
            prop_assert_eq!(dup(&doc), Some(key));
        }
    }
}
