//! The web viewer at `/`: one HTML page and two scripts (the viewer and its reprojection),
//! embedded in the binary (no build step).

use axum::http::header;
use axum::response::{Html, IntoResponse};

const INDEX_HTML: &str = include_str!("../../static/index.html");
const VIEWER_JS: &str = include_str!("../../static/viewer.js");
const REPROJECT_JS: &str = include_str!("../../static/reproject.js");

/// `GET /`.
pub async fn index() -> Html<&'static str> {
    Html(INDEX_HTML)
}

/// `GET /viewer.js`.
pub async fn script() -> impl IntoResponse {
    (
        [(header::CONTENT_TYPE, "text/javascript; charset=utf-8")],
        VIEWER_JS,
    )
}

/// `GET /reproject.js`: the viewer's WebGL2 reprojection of frames with depth.
pub async fn reproject_script() -> impl IntoResponse {
    (
        [(header::CONTENT_TYPE, "text/javascript; charset=utf-8")],
        REPROJECT_JS,
    )
}
