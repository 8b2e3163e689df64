//! The page: one HTML file, its script and its style sheet, compiled into
//! the binary (`include_str!`), so a user needs no build step, no npm and
//! no files beside the daemon.

use axum::http::header;
use axum::response::IntoResponse;

/// `index.html`.
pub const INDEX_HTML: &str = include_str!("static/index.html");
/// `app.js`: EventSource on `/api/events`, the camera canvas, the panels.
pub const APP_JS: &str = include_str!("static/app.js");
/// `figures.js`: draws the `figures` command's data as SVG.
pub const FIGURES_JS: &str = include_str!("static/figures.js");
/// `style.css`.
pub const STYLE_CSS: &str = include_str!("static/style.css");

/// Security headers of every page response: no framing, no sniffing, and
/// a content security policy that allows only this origin's scripts,
/// styles, images and event stream.
const CSP: &str = "default-src 'self'; img-src 'self' blob: data:; style-src 'self'; script-src 'self'; connect-src 'self'; frame-ancestors 'none'";

fn page(content_type: &'static str, body: &'static str) -> impl IntoResponse {
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

/// `GET /`.
pub async fn index() -> impl IntoResponse {
    page("text/html; charset=utf-8", INDEX_HTML)
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
