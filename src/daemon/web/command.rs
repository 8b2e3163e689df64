//! `POST /api/command`: one request of the socket protocol (the same JSON
//! object a socket client sends) in the body, its reply line back, through
//! the same parser, role table, audit trail and [`Daemon::execute`] as the
//! socket.
//!
//! Who may do what: without `Authorization: Bearer <token>` only read
//! commands that change nothing (`status`, `position`, listings, …; not
//! `stop`, which changes state). With the configured token (`[web]
//! control = true`) the client acts with `[web] role`, checked like a
//! socket client's. Tokens are compared in constant time. `subscribe` is
//! refused: `GET /api/events` is its HTTP form. State-changing and refused
//! commands go to the audit trail with the client's address.
//!
//! HTTP status: 200 for every reply of the protocol (`ok` says the
//! outcome, as on the socket), 401 for a wrong or missing token when one
//! is needed, 403 for a role too low, 400 for a request that does not parse,
//! 413 for one over the protocol's size limit.

use super::shared::Web;
use crate::daemon::audit::Origin;
use crate::daemon::protocol::{self, Command, ErrorCode, ProtoError, Role};
use crate::daemon::Daemon;
use axum::body::Bytes;
use axum::extract::{ConnectInfo, State};
use axum::http::{header, HeaderMap, StatusCode};
use axum::response::{IntoResponse, Response};
use std::net::SocketAddr;
use std::sync::Arc;
use subtle::ConstantTimeEq;

/// What the request's credentials are worth.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Credential {
    /// No `Authorization` header.
    None,
    /// A bearer token that matches.
    Valid,
    /// A header that is not the token (or a token while control is off).
    Invalid,
}

/// Judges the `Authorization` header against `token` in constant time
/// (for tokens of equal length; the length itself is not secret: the
/// configuration check fixes only a minimum).
pub fn credential(headers: &HeaderMap, token: Option<&str>) -> Credential {
    let Some(h) = headers.get(header::AUTHORIZATION) else {
        return Credential::None;
    };
    let Some(given) = h.to_str().ok().and_then(|s| s.strip_prefix("Bearer ")) else {
        return Credential::Invalid;
    };
    match token {
        Some(t) if bool::from(t.as_bytes().ct_eq(given.trim().as_bytes())) => Credential::Valid,
        _ => Credential::Invalid,
    }
}

/// The role an HTTP client acts with: anonymous clients none, a valid
/// token `role`.
pub fn role_of(c: Credential, role: Role) -> Option<Role> {
    match c {
        Credential::Valid => Some(role),
        Credential::None | Credential::Invalid => None,
    }
}

/// Whether `cmd` may run for a client holding `role` (`None`: anonymous).
pub fn allowed(cmd: &Command, role: Option<Role>) -> bool {
    match role {
        Some(r) => r >= cmd.role(),
        None => cmd.role() == Role::Read && !cmd.changes_state(),
    }
}

fn reply(status: StatusCode, line: String) -> Response {
    (
        status,
        [
            (header::CONTENT_TYPE, "application/json"),
            (header::CACHE_CONTROL, "no-store"),
        ],
        line,
    )
        .into_response()
}

/// How long a request body may take to arrive once its header is in: a
/// client that announces a body and stalls gets 408 and its connection
/// closed, instead of holding one of the listener's connections forever.
pub const BODY_TIMEOUT: std::time::Duration = std::time::Duration::from_secs(10);

/// The most body bytes read (axum's default limit; anything over
/// [`protocol::MAX_REQUEST_BYTES`] is refused below with 413).
const BODY_READ_LIMIT: usize = 2 * 1024 * 1024;

/// Marks a connection of the listener's stop slots
/// ([`super::router::STOP_SLOTS`]): taken when the ordinary connections
/// are full, it serves `stop` and nothing else.
#[derive(Debug, Clone, Copy)]
pub struct StopOnly;

/// `POST /api/command`.
pub async fn command(
    State(web): State<Arc<Web>>,
    ConnectInfo(remote): ConnectInfo<SocketAddr>,
    stop_only: Option<axum::Extension<StopOnly>>,
    headers: HeaderMap,
    body: axum::body::Body,
) -> Response {
    let null = serde_json::Value::Null;
    let body: Bytes =
        match tokio::time::timeout(BODY_TIMEOUT, axum::body::to_bytes(body, BODY_READ_LIMIT)).await
        {
            Ok(Ok(b)) => b,
            Ok(Err(_)) => {
                return reply(
                    StatusCode::PAYLOAD_TOO_LARGE,
                    protocol::error_reply(&null, &protocol::too_large(BODY_READ_LIMIT)),
                )
            }
            Err(_) => {
                return reply(
                    StatusCode::REQUEST_TIMEOUT,
                    protocol::error_reply(
                        &null,
                        &ProtoError::new(
                            ErrorCode::BadValue,
                            format!(
                                "request body not received within {} s",
                                BODY_TIMEOUT.as_secs()
                            ),
                        ),
                    ),
                )
            }
        };
    if body.len() > protocol::MAX_REQUEST_BYTES {
        return reply(
            StatusCode::PAYLOAD_TOO_LARGE,
            protocol::error_reply(&null, &protocol::too_large(body.len())),
        );
    }
    let req = match protocol::parse_request(&body) {
        Ok(r) => r,
        Err(r) => {
            return reply(
                StatusCode::BAD_REQUEST,
                protocol::error_reply(&r.id, &r.error),
            )
        }
    };
    if stop_only.is_some() && !matches!(req.command, Command::Stop) {
        return reply(
            StatusCode::SERVICE_UNAVAILABLE,
            protocol::error_reply(
                &req.id,
                &ProtoError::new(
                    ErrorCode::Busy,
                    "the web listener's connections are all taken: this connection serves only stop",
                ),
            ),
        );
    }
    if matches!(req.command, Command::Subscribe(_)) {
        return reply(
            StatusCode::BAD_REQUEST,
            protocol::error_reply(
                &req.id,
                &ProtoError::new(
                    ErrorCode::BadValue,
                    "subscribe is the socket's; over HTTP read GET /api/events",
                ),
            ),
        );
    }
    let cred = credential(&headers, web.token.as_deref());
    let role = role_of(cred, web.role);
    run(&web.daemon, Origin::Http(remote), cred, role, req, &body).await
}

/// The role check, the audit record and the dispatch of one parsed
/// request.
async fn run(
    daemon: &Daemon,
    origin: Origin,
    cred: Credential,
    role: Option<Role>,
    req: protocol::Request,
    raw: &[u8],
) -> Response {
    let permitted = allowed(&req.command, role);
    if !daemon
        .audit
        .admit(origin, role, &req.command, raw, permitted)
    {
        let (status, why) = match cred {
            Credential::Valid => (
                StatusCode::FORBIDDEN,
                format!(
                    "{} needs role {}; the web token has {}",
                    req.command.name(),
                    req.command.role().as_str(),
                    role.map_or("none", Role::as_str)
                ),
            ),
            Credential::Invalid => (
                StatusCode::UNAUTHORIZED,
                "the bearer token is not valid (or [web] control is off)".to_owned(),
            ),
            Credential::None => (
                StatusCode::UNAUTHORIZED,
                format!(
                    "{} needs Authorization: Bearer <token> ([web] control = true)",
                    req.command.name()
                ),
            ),
        };
        return reply(
            status,
            protocol::error_reply(&req.id, &ProtoError::new(ErrorCode::PermissionDenied, why)),
        );
    }
    let line = protocol::reply(&req.id, daemon.execute(req.command).await);
    reply(StatusCode::OK, line)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parsed(line: &str) -> Command {
        protocol::parse_request(line.as_bytes()).unwrap().command
    }

    #[test]
    fn anonymous_clients_only_read() {
        assert!(allowed(&parsed(r#"{"cmd":"status"}"#), None));
        assert!(allowed(&parsed(r#"{"cmd":"position"}"#), None));
        assert!(!allowed(&parsed(r#"{"cmd":"stop"}"#), None));
        assert!(!allowed(
            &parsed(r#"{"cmd":"move","x_um":1,"y_um":2}"#),
            None
        ));
        assert!(!allowed(&parsed(r#"{"cmd":"config"}"#), None));
        let mv = parsed(r#"{"cmd":"move","x_um":1,"y_um":2}"#);
        assert!(allowed(&mv, Some(Role::Operate)));
        assert!(!allowed(&mv, Some(Role::Read)));
        assert!(!allowed(&parsed(r#"{"cmd":"reset"}"#), Some(Role::Operate)));
    }

    #[test]
    fn tokens_are_checked() {
        let mut h = HeaderMap::new();
        let t = Some("0123456789abcdef");
        assert_eq!(credential(&h, t), Credential::None);
        h.insert(
            header::AUTHORIZATION,
            "Bearer 0123456789abcdef".parse().unwrap(),
        );
        assert_eq!(credential(&h, t), Credential::Valid);
        assert_eq!(credential(&h, None), Credential::Invalid);
        h.insert(
            header::AUTHORIZATION,
            "Bearer 0123456789abcdeF".parse().unwrap(),
        );
        assert_eq!(credential(&h, t), Credential::Invalid);
        h.insert(
            header::AUTHORIZATION,
            "Basic 0123456789abcdef".parse().unwrap(),
        );
        assert_eq!(credential(&h, t), Credential::Invalid);
        assert_eq!(role_of(Credential::Invalid, Role::Admin), None);
        assert_eq!(role_of(Credential::Valid, Role::Read), Some(Role::Read));
    }
}
