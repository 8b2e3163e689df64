//! The page: one HTML file, its script and its style sheet, compiled into
//! the binary (`include_str!`), so a user needs no build step, no npm and
//! no files beside the daemon.
//!
//! `GET /` carries the rig's state at the moment it is served (the
//! `status` and `position` replies and the camera overlay, as JSON in a
//! data block) and the first camera image as an `<img>`: the page shows the
//! rig when its `load` event fires, before any request of its own, and the
//! image holds the `load` event until it has arrived. So a screenshot taken
//! at `load` (`chromium --headless --screenshot`) shows positions and the
//! camera, and the event stream, which never ends, is opened only after
//! `load` (`static/app.js`).

use super::shared::Web;
use crate::daemon::protocol::Command;
use axum::extract::State;
use axum::http::header;
use axum::response::IntoResponse;
use serde_json::{json, Value};
use std::sync::Arc;

/// `index.html`.
pub const INDEX_HTML: &str = include_str!("static/index.html");
/// `app.js`: the served state, then (after `load`) EventSource on
/// `/api/events`, the camera canvas, the panels.
pub const APP_JS: &str = include_str!("static/app.js");
/// `figures.js`: draws the `figures` command's data as SVG.
pub const FIGURES_JS: &str = include_str!("static/figures.js");
/// `style.css`.
pub const STYLE_CSS: &str = include_str!("static/style.css");

/// Security headers of every page response: no framing, no sniffing, and
/// a content security policy that allows only this origin's scripts,
/// styles, images and event stream.
const CSP: &str = "default-src 'self'; img-src 'self' blob: data:; style-src 'self'; script-src 'self'; connect-src 'self'; frame-ancestors 'none'";

fn page<B: IntoResponse>(content_type: &'static str, body: B) -> impl IntoResponse {
    (
        [
            (header::CONTENT_TYPE, content_type),
            (header::CONTENT_SECURITY_POLICY, CSP),
            (header::X_CONTENT_TYPE_OPTIONS, "nosniff"),
            (header::CACHE_CONTROL, "no-cache"),
        ],
        body,
    )
}

/// Where `index.html` takes the state it is served with.
pub const INITIAL_MARK: &str = "<!--initial-state-->";

/// `GET /`: the page with the rig's state at this moment (see the module
/// header). A command that fails leaves its part out; the page then waits
/// for the event stream as it would without it.
pub async fn index(State(web): State<Arc<Web>>) -> impl IntoResponse {
    let mut state = serde_json::Map::new();
    for (name, cmd) in [("status", Command::Status), ("position", Command::Position)] {
        if let Ok(v) = web.daemon.execute(cmd).await {
            state.insert(name.to_owned(), v);
        }
    }
    let camera = match &web.camera {
        Some(view) => view.current().await.map(|r| r.overlay),
        None => None,
    };
    if let Some(o) = &camera {
        state.insert("camera".to_owned(), o.clone());
    }
    let sequence = camera
        .as_ref()
        .and_then(|o| o.get("sequence"))
        .and_then(Value::as_u64);
    page(
        "text/html; charset=utf-8",
        render_index(&Value::Object(state), sequence),
    )
}

/// `index.html` with `state` as a JSON data block (id `initial-state`)
/// and, given a frame `sequence`, that frame's image (id `camera-first`,
/// hidden: the script draws it on the camera canvas).
pub fn render_index(state: &Value, sequence: Option<u64>) -> String {
    let mut block = format!(
        "<script type=\"application/json\" id=\"initial-state\">{}</script>",
        json_in_html(state)
    );
    if let Some(n) = sequence {
        block.push_str(&format!(
            "<img id=\"camera-first\" src=\"/api/camera.png?seq={n}\" alt=\"\" hidden>"
        ));
    }
    INDEX_HTML.replacen(INITIAL_MARK, &block, 1)
}

/// `v` as JSON that cannot end the `<script>` element it sits in: `<`,
/// `>` and `&` (only ever inside strings in JSON) written as `\u` escapes,
/// which `JSON.parse` reads back unchanged. A fault reason or log name
/// containing `</script>` stays data.
fn json_in_html(v: &Value) -> String {
    let text = serde_json::to_string(v).unwrap_or_else(|_| json!({}).to_string());
    let mut out = String::with_capacity(text.len());
    for c in text.chars() {
        match c {
            '<' => out.push_str("\\u003c"),
            '>' => out.push_str("\\u003e"),
            '&' => out.push_str("\\u0026"),
            c => out.push(c),
        }
    }
    out
}

/// `GET /app.js`.
pub async fn app_js() -> impl IntoResponse {
    page("text/javascript; charset=utf-8", APP_JS)
}

/// `GET /figures.js`.
pub async fn figures_js() -> impl IntoResponse {
    page("text/javascript; charset=utf-8", FIGURES_JS)
}

/// `GET /style.css`.
pub async fn style_css() -> impl IntoResponse {
    page("text/css; charset=utf-8", STYLE_CSS)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The state block parses back to the state, whatever its strings
    /// hold, and nothing in it closes the `<script>` element early.
    #[test]
    fn the_initial_state_stays_data() {
        let state = json!({"status": {"rig": {"fault_latched": {"reason": "</script><script>alert(1)</script> & <b>"}}}});
        let html = render_index(&state, Some(42));
        let start = html
            .find("id=\"initial-state\">")
            .map(|i| i + "id=\"initial-state\">".len());
        let start = start.unwrap();
        let end = start + html[start..].find("</script>").unwrap();
        let back: Value = serde_json::from_str(&html[start..end]).unwrap();
        assert_eq!(back, state);
        assert!(html.contains("<img id=\"camera-first\" src=\"/api/camera.png?seq=42\""));
        assert!(!html.contains(INITIAL_MARK));
        assert!(!render_index(&json!({}), None).contains("camera-first"));
    }
}
