//! The `Host` allow-list: every request must name this listener by a
//! loopback name (`localhost`, `127.0.0.1`, `[::1]`, any port) or by one
//! of `[web] hosts`.
//!
//! Why: DNS rebinding. A page from `evil.example` whose name later resolves
//! to 127.0.0.1 is same-origin with the listener in the browser, and could
//! read the camera image, positions, figures and metrics; its requests
//! still carry `Host: evil.example`, which this check refuses (421) before
//! any route runs.

use axum::extract::Request;
use axum::http::{header, StatusCode};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use std::sync::Arc;

/// Names accepted without configuration (any port).
pub const LOOPBACK_HOSTS: [&str; 3] = ["localhost", "127.0.0.1", "[::1]"];

/// The name of a `Host` header value without its port, lower-cased;
/// `None` when it is malformed (empty, bad port, unclosed `[`).
pub fn host_name(value: &str) -> Option<String> {
    let v = value.trim();
    let (name, rest) = if v.starts_with('[') {
        let end = v.find(']')?;
        (&v[..=end], &v[end + 1..])
    } else {
        match v.rsplit_once(':') {
            Some((n, _)) => (n, &v[n.len()..]),
            None => (v, ""),
        }
    };
    if !rest.is_empty() {
        let port = rest.strip_prefix(':')?;
        if port.is_empty() || port.len() > 5 || !port.bytes().all(|b| b.is_ascii_digit()) {
            return None;
        }
    }
    let name = name.strip_suffix('.').unwrap_or(name);
    if !plausible_name(name) {
        return None;
    }
    Some(name.to_ascii_lowercase())
}

/// A DNS name (letters, digits, `-`, `_`, dots between non-empty labels)
/// or a bracketed IPv6 literal (hex digits, `:`, `.`). Why this strict: a
/// name compared with the allow-list must read back as itself, with no
/// spaces, control characters or empty labels that two parsers could see
/// differently.
fn plausible_name(name: &str) -> bool {
    if let Some(inner) = name.strip_prefix('[').and_then(|n| n.strip_suffix(']')) {
        return !inner.is_empty()
            && inner.contains(':')
            && inner
                .bytes()
                .all(|b| b.is_ascii_hexdigit() || b == b':' || b == b'.');
    }
    !name.is_empty()
        && name.split('.').all(|label| {
            !label.is_empty()
                && label
                    .bytes()
                    .all(|b| b.is_ascii_alphanumeric() || b == b'-' || b == b'_')
        })
}

/// Whether a request with `Host: value` (`None`: no header) may be served.
pub fn allowed(value: Option<&str>, extra: &[String]) -> bool {
    let Some(name) = value.and_then(host_name) else {
        return false;
    };
    LOOPBACK_HOSTS.contains(&name.as_str())
        || extra.iter().filter_map(|h| host_name(h)).any(|h| h == name)
}

/// The middleware: 421 Misdirected Request for a `Host` not allowed.
pub async fn check(extra: Arc<Vec<String>>, req: Request, next: Next) -> Response {
    let value = req
        .headers()
        .get(header::HOST)
        .and_then(|v| v.to_str().ok());
    if allowed(value, &extra) {
        return next.run(req).await;
    }
    (
        StatusCode::MISDIRECTED_REQUEST,
        [(header::CACHE_CONTROL, "no-store")],
        "Host not allowed: use http://localhost:PORT/ or a name listed in [web] hosts\n",
    )
        .into_response()
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn loopback_names_pass_with_any_port() {
        for h in [
            "localhost",
            "localhost:8080",
            "LOCALHOST:1",
            "127.0.0.1:8080",
            "[::1]:8080",
            "[::1]",
            "localhost.",
        ] {
            assert!(allowed(Some(h), &[]), "{h}");
        }
    }

    #[test]
    fn other_names_and_malformed_values_are_refused() {
        for h in [
            "evil.example",
            "evil.example:8080",
            "localhost.evil.example",
            "127.0.0.1.nip.io",
            "localhost:",
            "localhost:80x",
            "[::1",
            "[::1]x",
            "::1",
            "",
            "192.168.1.5:8080",
            "localhost..",
            "local host",
            "localhost\t:80",
            ".localhost",
            "[]",
            "[zz::1]",
        ] {
            assert!(!allowed(Some(h), &[]), "{h}");
        }
        assert!(!allowed(None, &[]));
    }

    #[test]
    fn configured_names_pass() {
        let extra = vec!["rig.lab".to_owned(), "192.168.20.5".to_owned()];
        assert!(allowed(Some("rig.lab:8080"), &extra));
        assert!(allowed(Some("RIG.LAB"), &extra));
        assert!(allowed(Some("192.168.20.5:8080"), &extra));
        assert!(!allowed(Some("rig.lab.evil.example"), &extra));
    }

    proptest! {
        #[test]
        fn never_panics(s in ".{0,40}") {
            let _ = allowed(Some(&s), &["rig.lab".to_owned()]);
        }

        /// A name read from a header reads back as itself, and a value is
        /// allowed when listed exactly when it is well formed.
        #[test]
        fn names_read_back_as_themselves(s in "[a-zA-Z0-9.:\\[\\] _-]{0,24}") {
            if let Some(n) = host_name(&s) {
                prop_assert_eq!(host_name(&n), Some(n.clone()));
            }
            prop_assert_eq!(allowed(Some(&s), std::slice::from_ref(&s)), host_name(&s).is_some());
        }
    }
}
