//! Replies and events, serialized to one line each.
//!
//! Why a file of its own: the daemon's connection tasks write only these
//! lines; their shape (`id` echoed, `ok`, `error.code`) is the other half
//! of the protocol.

use serde_json::{Map, Value};

use super::replies::error_body_value;
use super::ProtoError;

/// A success reply: `{"id":…,"ok":true, …fields}` plus newline.
pub fn ok_reply(id: &Value, fields: Map<String, Value>) -> String {
    let mut obj = Map::new();
    obj.insert("id".to_owned(), id.clone());
    obj.insert("ok".to_owned(), Value::Bool(true));
    for (k, v) in fields {
        if k != "id" && k != "ok" {
            obj.insert(k, v);
        }
    }
    line(Value::Object(obj))
}

/// The fields of an ok reply or an event from a command's result: an
/// object's own fields, anything else under `result`. Why here: the socket
/// and the HTTP listener answer with the same reply lines.
pub fn reply_fields(v: Value) -> Map<String, Value> {
    match v {
        Value::Object(m) => m,
        other => {
            let mut m = Map::new();
            m.insert("result".to_owned(), other);
            m
        }
    }
}

/// The reply line to a command's result: the one shape both front doors
/// and every command answer with.
pub fn reply(id: &Value, result: Result<Value, ProtoError>) -> String {
    match result {
        Ok(v) => ok_reply(id, reply_fields(v)),
        Err(e) => error_reply(id, &e),
    }
}

/// An error reply: `{"id":…,"ok":false,"error":{"code":…,"message":…}}`.
pub fn error_reply(id: &Value, e: &ProtoError) -> String {
    line(error_reply_value(id, e))
}

/// An error reply as a value: what [`error_reply`] writes, and what a
/// client that refuses a request itself (a word the protocol does not
/// know, read from its command line) shows as if the daemon had refused.
pub fn error_reply_value(id: &Value, e: &ProtoError) -> Value {
    let mut obj = Map::new();
    obj.insert("id".to_owned(), id.clone());
    obj.insert("ok".to_owned(), Value::Bool(false));
    obj.insert("error".to_owned(), error_body_value(e));
    Value::Object(obj)
}

/// A pushed event: `{"event":name, …fields}` plus newline.
pub fn event_line(name: &str, fields: Map<String, Value>) -> String {
    let mut obj = Map::new();
    obj.insert("event".to_owned(), Value::from(name));
    for (k, v) in fields {
        if k != "event" {
            obj.insert(k, v);
        }
    }
    line(Value::Object(obj))
}

fn line(v: Value) -> String {
    // Serializing a Value cannot fail (string keys, no non-finite floats:
    // serde_json turns those into null).
    let mut s = v.to_string();
    s.push('\n');
    s
}
