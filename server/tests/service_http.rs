//! Service tests: the router driven with `oneshot` (every endpoint, every bad input)
//! and one real server on port 0 driven over a WebSocket. GPU work runs on lavapipe here; the
//! asset is tiny (12 cameras, 32 px maps) so the whole file runs in seconds.

use std::fmt::Write as _;
use std::sync::{Arc, OnceLock};
use std::time::Duration;

use axum::body::Body;
use axum::http::{Request, StatusCode, header};
use futures_util::{SinkExt as _, StreamExt as _};
use lumigraph_core::bake::{BakeOptions, Baker};
use lumigraph_core::gpu::Gpu;
use lumigraph_core::mesh::Mesh;
use lumigraph_server::service::{AppState, ServeConfig, app, run};
use tokio_tungstenite::tungstenite::Message;
use tower::ServiceExt as _;

pub const TOKEN: &str = "test-token";

/// A unit sphere approximated by the level-1 icosphere of the core's camera set (42 vertices,
/// 80 triangles; winding counter-clockwise seen from outside).
pub fn icosahedron() -> Mesh {
    let set = lumigraph_core::geometry::camera_set();
    let positions = set
        .positions_for_level(1)
        .iter()
        .map(|p| [p.x, p.y, p.z])
        .collect();
    let triangles = set.level_triangles(1).iter().map(|t| t.v).collect();
    Mesh::from_arrays(positions, triangles, None).expect("valid icosphere")
}

/// The same icosahedron as OBJ text, for bake uploads.
pub fn icosahedron_obj() -> String {
    let mesh = icosahedron();
    let mut out = String::new();
    for p in &mesh.positions {
        let _ = writeln!(out, "v {} {} {}", p[0], p[1], p[2]);
    }
    for t in &mesh.triangles {
        let _ = writeln!(out, "f {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1);
    }
    out
}

pub fn gpu() -> Arc<Gpu> {
    Gpu::shared().expect("a GPU adapter (lavapipe: apt install mesa-vulkan-drivers)")
}

pub fn tiny_options() -> BakeOptions {
    BakeOptions {
        cameras: 12,
        resolution: 32,
        ..BakeOptions::default()
    }
}

/// The tiny asset's bytes, baked once per test binary.
pub fn tiny_asset() -> &'static [u8] {
    static BYTES: OnceLock<Vec<u8>> = OnceLock::new();
    BYTES.get_or_init(|| {
        let baker = Baker::new(gpu());
        baker
            .bake_to_bytes(
                &icosahedron(),
                &tiny_options(),
                &lumigraph_core::asset::Provenance::default(),
                &mut |_, _| {},
            )
            .expect("baking the tiny asset")
    })
}

/// A fresh assets folder holding `tiny.lfa` and a loaded state over it.
pub async fn setup(
    token: Option<&str>,
    tweak: impl FnOnce(&mut ServeConfig),
) -> (tempfile::TempDir, AppState) {
    let dir = tempfile::tempdir().expect("temp dir");
    std::fs::write(dir.path().join("tiny.lfa"), tiny_asset()).expect("writing the asset");
    let mut config = ServeConfig::new(dir.path(), "127.0.0.1:0".parse().expect("addr"));
    config.token = token.map(str::to_owned);
    config.bake_demo_if_empty = false;
    config.max_px = 512;
    tweak(&mut config);
    let state = tokio::task::spawn_blocking(move || AppState::new(config, gpu()))
        .await
        .expect("join")
        .expect("state");
    state.load_assets().await.expect("loading assets");
    (dir, state)
}

/// A view of the unit icosahedron from distance 3.
pub fn view_json(width: u32, height: u32) -> serde_json::Value {
    serde_json::json!({"eye": [0.3, 0.5, 3.0], "target": [0, 0, 0], "up": [0, 1, 0], "yfov_deg": 40,
                       "width": width, "height": height})
}

struct Reply {
    status: StatusCode,
    headers: axum::http::HeaderMap,
    body: Vec<u8>,
}

impl Reply {
    fn json(&self) -> serde_json::Value {
        serde_json::from_slice(&self.body)
            .unwrap_or_else(|e| panic!("not JSON ({e}): {}", String::from_utf8_lossy(&self.body)))
    }

    fn error_kind(&self) -> String {
        self.json()["error"]["kind"]
            .as_str()
            .unwrap_or_default()
            .to_owned()
    }

    fn header(&self, name: &str) -> &str {
        self.headers
            .get(name)
            .and_then(|v| v.to_str().ok())
            .unwrap_or_default()
    }
}

async fn send(state: &AppState, request: Request<Body>) -> Reply {
    let response = app(state.clone())
        .oneshot(request)
        .await
        .expect("infallible");
    let status = response.status();
    let headers = response.headers().clone();
    let body = axum::body::to_bytes(response.into_body(), usize::MAX)
        .await
        .expect("body")
        .to_vec();
    Reply {
        status,
        headers,
        body,
    }
}

async fn get(state: &AppState, uri: &str) -> Reply {
    send(
        state,
        Request::get(uri).body(Body::empty()).expect("request"),
    )
    .await
}

async fn post_json(state: &AppState, uri: &str, body: impl Into<Body>) -> Reply {
    let request = Request::post(uri)
        .header(header::CONTENT_TYPE, "application/json")
        .body(body.into())
        .expect("request");
    send(state, request).await
}

async fn render(state: &AppState, body: &serde_json::Value) -> Reply {
    post_json(state, "/v1/assets/tiny/render", body.to_string()).await
}

#[tokio::test(flavor = "multi_thread")]
async fn ops_endpoints_and_viewer() {
    let (_dir, state) = setup(None, |_| {}).await;
    assert_eq!(get(&state, "/healthz").await.status, StatusCode::OK);
    let ready = get(&state, "/readyz").await;
    assert_eq!(ready.status, StatusCode::OK);
    assert_eq!(ready.json()["assets"], 1);
    let openapi = get(&state, "/openapi.json").await.json();
    for path in [
        "/v1/assets",
        "/v1/assets/{id}",
        "/v1/assets/{id}/render",
        "/v1/bake",
        "/v1/jobs/{id}",
        "/v1/stream",
    ] {
        assert!(
            openapi["paths"][path].is_object(),
            "{path} missing from the OpenAPI document"
        );
    }
    let page = get(&state, "/").await;
    assert!(String::from_utf8_lossy(&page.body).contains("viewer.js"));
    let script = get(&state, "/viewer.js").await;
    assert!(script.header("content-type").starts_with("text/javascript"));
    assert!(String::from_utf8_lossy(&page.body).contains("reproject.js"));
    let script = get(&state, "/reproject.js").await;
    assert!(script.header("content-type").starts_with("text/javascript"));
    assert!(String::from_utf8_lossy(&script.body).contains("LumigraphReproject"));
    // One render so the histograms have samples, then the metrics.
    assert_eq!(
        render(&state, &serde_json::json!({"view": view_json(16, 16)}))
            .await
            .status,
        StatusCode::OK
    );
    assert_eq!(
        get(&state, "/v1/assets/nope").await.status,
        StatusCode::NOT_FOUND
    );
    let metrics = String::from_utf8(get(&state, "/metrics").await.body).expect("utf-8");
    for name in [
        "lumigraph_frames_total",
        "lumigraph_render_seconds",
        "lumigraph_encode_seconds",
        "lumigraph_stream_sessions",
        "lumigraph_dropped_frames_total",
        "lumigraph_bytes_sent_total",
        "lumigraph_errors_total",
        "lumigraph_assets",
    ] {
        assert!(
            metrics.contains(name),
            "{name} missing from /metrics:\n{metrics}"
        );
    }
    assert!(metrics.contains("kind=\"not_found\""), "{metrics}");
}

#[tokio::test(flavor = "multi_thread")]
async fn not_ready_until_loaded() {
    let dir = tempfile::tempdir().expect("temp dir");
    let mut config = ServeConfig::new(dir.path(), "127.0.0.1:0".parse().expect("addr"));
    config.bake_demo_if_empty = false;
    let state = tokio::task::spawn_blocking(move || AppState::new(config, gpu()))
        .await
        .expect("join")
        .expect("state");
    let reply = get(&state, "/readyz").await;
    assert_eq!(reply.status, StatusCode::SERVICE_UNAVAILABLE);
    assert_eq!(reply.error_kind(), "unavailable");
    state.load_assets().await.expect("load");
    assert_eq!(get(&state, "/readyz").await.status, StatusCode::OK);
}

#[tokio::test(flavor = "multi_thread")]
async fn lists_and_inspects_assets() {
    let (_dir, state) = setup(None, |_| {}).await;
    let list = get(&state, "/v1/assets").await.json();
    assert_eq!(list[0]["id"], "tiny");
    assert_eq!(list[0]["camera_count"], 12);
    assert_eq!(list[0]["resolution_px"], 32);
    let detail = get(&state, "/v1/assets/tiny").await;
    assert_eq!(detail.status, StatusCode::OK);
    let detail = detail.json();
    assert_eq!(detail["header"]["geometry"]["camera_count"], 12);
    assert_eq!(detail["header"]["kind"], "spherical");
    assert!(detail["header"]["layers"].is_array());
    let missing = get(&state, "/v1/assets/other").await;
    assert_eq!(missing.status, StatusCode::NOT_FOUND);
    assert_eq!(missing.error_kind(), "not_found");
}

#[tokio::test(flavor = "multi_thread")]
async fn path_traversal_ids_are_rejected() {
    let (dir, state) = setup(None, |_| {}).await;
    std::fs::write(dir.path().join(".hidden.lfa"), tiny_asset()).expect("write");
    for uri in [
        "/v1/assets/..%2F..%2Fetc%2Fpasswd",
        "/v1/assets/.hidden",
        "/v1/assets/%2e%2e",
        "/v1/assets/a.lfa",
        "/v1/jobs/..%2Fx",
    ] {
        let reply = get(&state, uri).await;
        assert_eq!(reply.status, StatusCode::UNPROCESSABLE_ENTITY, "{uri}");
        assert_eq!(reply.error_kind(), "invalid", "{uri}");
    }
    let reply = send(
        &state,
        Request::post("/v1/assets?id=..%2Fescape")
            .body(Body::from(tiny_asset().to_vec()))
            .expect("request"),
    )
    .await;
    assert_eq!(reply.status, StatusCode::UNPROCESSABLE_ENTITY);
    assert!(
        !dir.path()
            .parent()
            .expect("parent")
            .join("escape.lfa")
            .exists()
    );
    // The router never decodes `..` into a path: plain `..` segments do not reach a handler.
    assert_ne!(
        get(&state, "/v1/assets/../../etc/passwd").await.status,
        StatusCode::OK
    );
}

fn is_png(bytes: &[u8]) -> bool {
    bytes.starts_with(b"\x89PNG\r\n\x1a\n")
}

#[tokio::test(flavor = "multi_thread")]
async fn renders_every_codec() {
    let (_dir, state) = setup(None, |_| {}).await;
    let png = render(&state, &serde_json::json!({"view": view_json(48, 32)})).await;
    assert_eq!(
        png.status,
        StatusCode::OK,
        "{}",
        String::from_utf8_lossy(&png.body)
    );
    assert_eq!(png.header("content-type"), "image/png");
    assert!(is_png(&png.body));
    assert!(png.header("x-render-ms").parse::<f64>().is_ok());
    assert!(png.header("x-encode-ms").parse::<f64>().is_ok());
    assert_eq!(png.header("x-frame-width"), "48");
    let (w, h, rgba) = lumigraph_core::image_io::decode_png_rgba8(&png.body).expect("decode");
    assert_eq!((w, h), (48, 32));
    assert!(
        rgba.chunks_exact(4).any(|p| p[3] == 255),
        "the object is in view"
    );
    assert!(
        rgba.chunks_exact(4).any(|p| p[3] == 0),
        "the background is transparent"
    );

    let jpeg = render(&state, &serde_json::json!({"view": view_json(32, 32), "format": "jpeg", "quality": 50, "background": [255, 0, 0, 255]})).await;
    assert_eq!(jpeg.header("content-type"), "image/jpeg");
    assert!(jpeg.body.starts_with(&[0xff, 0xd8]));
    let webp = render(&state, &serde_json::json!({"view": view_json(32, 32), "format": "webp", "lod": 12, "method": "fixed"})).await;
    assert_eq!(webp.header("content-type"), "image/webp");
    assert_eq!(&webp.body[8..12], b"WEBP");

    let npy = render(
        &state,
        &serde_json::json!({"view": view_json(16, 8), "format": "none", "depth": "npy"}),
    )
    .await;
    assert_eq!(npy.header("content-type"), "application/x-npy");
    let (dw, dh, depth) = lumigraph_core::image_io::decode_depth_npy(&npy.body).expect("npy");
    assert_eq!((dw, dh), (16, 8));
    assert!(depth.iter().any(|d| d.is_finite()) && depth.iter().any(|d| d.is_infinite()));

    let both = render(
        &state,
        &serde_json::json!({"view": view_json(16, 16), "depth": "png16"}),
    )
    .await;
    let content_type = both.header("content-type").to_owned();
    let boundary = content_type
        .strip_prefix("multipart/mixed; boundary=")
        .expect("multipart");
    let text = String::from_utf8_lossy(&both.body);
    assert_eq!(text.matches(&format!("--{boundary}\r\n")).count(), 2);
    assert!(text.contains("Content-Type: image/png"));
    assert!(text.ends_with(&format!("--{boundary}--\r\n")));
    let near: f64 = both.header("x-depth-near").parse().expect("near");
    let far: f64 = both.header("x-depth-far").parse().expect("far");
    assert!(near > 0.0 && far >= near);

    let exr = render(
        &state,
        &serde_json::json!({"view": view_json(8, 8), "format": "none", "depth": "exr"}),
    )
    .await;
    assert_eq!(exr.status, StatusCode::OK);
    assert_eq!(
        lumigraph_core::image_io::decode_depth_exr(&exr.body)
            .expect("exr")
            .2
            .len(),
        64
    );
}

#[tokio::test(flavor = "multi_thread")]
async fn bad_render_requests_get_json_errors() {
    let (_dir, state) = setup(None, |c| c.max_json_bytes = 4096).await;
    let view = view_json(16, 16);
    let with = |key: &str, value: serde_json::Value| {
        let mut v = view.clone();
        v[key] = value;
        serde_json::json!({"view": v})
    };
    let cases: Vec<(String, StatusCode, &str)> = vec![
        ("{\"view\": ".to_owned(), StatusCode::BAD_REQUEST, "malformed_json"),
        ("not json".to_owned(), StatusCode::BAD_REQUEST, "malformed_json"),
        (r#"{"view": {"eye": [NaN, 0, 3], "target": [0,0,0], "yfov_deg": 40, "width": 8, "height": 8}}"#.to_owned(), StatusCode::BAD_REQUEST, "malformed_json"),
        (r#"{"view": {"eye": [1e999, 0, 3], "target": [0,0,0], "yfov_deg": 40, "width": 8, "height": 8}}"#.to_owned(), StatusCode::BAD_REQUEST, "malformed_json"),
        (with("yfov_deg", 180.into()).to_string(), StatusCode::UNPROCESSABLE_ENTITY, "invalid"),
        (with("yfov_deg", 0.into()).to_string(), StatusCode::UNPROCESSABLE_ENTITY, "invalid"),
        (with("width", 513.into()).to_string(), StatusCode::UNPROCESSABLE_ENTITY, "invalid"),
        (with("height", 0.into()).to_string(), StatusCode::UNPROCESSABLE_ENTITY, "invalid"),
        (with("width", (-4).into()).to_string(), StatusCode::UNPROCESSABLE_ENTITY, "invalid"),
        (with("target", serde_json::json!([0.3, 0.5, 3.0])).to_string(), StatusCode::UNPROCESSABLE_ENTITY, "invalid"),
        (with("up", serde_json::json!([0, 0, 0])).to_string(), StatusCode::UNPROCESSABLE_ENTITY, "invalid"),
        (with("zoom", 2.into()).to_string(), StatusCode::UNPROCESSABLE_ENTITY, "invalid"),
        (serde_json::json!({"view": view, "lod": 13}).to_string(), StatusCode::UNPROCESSABLE_ENTITY, "invalid"),
        (serde_json::json!({"view": view, "lod": 42}).to_string(), StatusCode::UNPROCESSABLE_ENTITY, "invalid"),
        (serde_json::json!({"view": view, "step": 0}).to_string(), StatusCode::UNPROCESSABLE_ENTITY, "invalid"),
        (serde_json::json!({"view": view, "format": "gif"}).to_string(), StatusCode::UNPROCESSABLE_ENTITY, "invalid"),
        (serde_json::json!({"view": view, "format": "jpeg", "quality": 0}).to_string(), StatusCode::UNPROCESSABLE_ENTITY, "invalid"),
        (serde_json::json!({"view": view, "background": [0, 0, 0, 256]}).to_string(), StatusCode::UNPROCESSABLE_ENTITY, "invalid"),
        (serde_json::json!({"view": view, "format": "none"}).to_string(), StatusCode::UNPROCESSABLE_ENTITY, "invalid"),
        (serde_json::json!({"view": view, "extra": 1}).to_string(), StatusCode::UNPROCESSABLE_ENTITY, "invalid"),
        (format!("{{\"view\": {view}, \"pad\": \"{}\"}}", "x".repeat(5000)), StatusCode::PAYLOAD_TOO_LARGE, "too_large"),
    ];
    for (body, status, kind) in cases {
        let reply = post_json(&state, "/v1/assets/tiny/render", body.clone()).await;
        assert_eq!(
            reply.status,
            status,
            "{body:.200}: {}",
            String::from_utf8_lossy(&reply.body)
        );
        assert_eq!(reply.error_kind(), kind, "{body:.200}");
        assert!(
            !reply.json()["error"]["message"]
                .as_str()
                .unwrap_or_default()
                .is_empty()
        );
    }
    let unknown = post_json(
        &state,
        "/v1/assets/ghost/render",
        serde_json::json!({"view": view}).to_string(),
    )
    .await;
    assert_eq!(unknown.status, StatusCode::NOT_FOUND);
    let wrong_method = send(
        &state,
        Request::put("/v1/assets/tiny/render")
            .body(Body::empty())
            .expect("request"),
    )
    .await;
    assert_eq!(wrong_method.status, StatusCode::METHOD_NOT_ALLOWED);
    assert_eq!(wrong_method.error_kind(), "rejected");
    // The server is still fine.
    assert_eq!(
        render(&state, &serde_json::json!({"view": view}))
            .await
            .status,
        StatusCode::OK
    );
}

/// `GET /v1/assets/tiny/render?QUERY` with optional `If-None-Match`.
async fn get_link(state: &AppState, query: &str, if_none_match: Option<&str>) -> Reply {
    let mut request = Request::get(format!("/v1/assets/tiny/render?{query}"));
    if let Some(tag) = if_none_match {
        request = request.header(header::IF_NONE_MATCH, tag);
    }
    send(state, request.body(Body::empty()).expect("request")).await
}

/// The `X-` header names of a render answer, but for the two timings, with their values.
fn render_headers(reply: &Reply) -> Vec<(String, String)> {
    let mut out: Vec<_> = reply
        .headers
        .iter()
        .filter(|(name, _)| {
            name.as_str().starts_with("x-")
                && !matches!(name.as_str(), "x-render-ms" | "x-encode-ms")
                || *name == header::CONTENT_TYPE
        })
        .map(|(n, v)| (n.to_string(), v.to_str().unwrap_or_default().to_owned()))
        .collect();
    out.sort();
    out
}

#[tokio::test(flavor = "multi_thread")]
async fn render_links_answer_the_post_render_bit_for_bit_and_revalidate() {
    let (_dir, state) = setup(None, |_| {}).await;
    // The same state as a body and as a query, in both view forms and several codecs.
    let orbit_eye =
        lumigraph_server::service::render_query::orbit_eye([0.1, -0.2, 0.05], 33.5, 21.25, 2.75);
    let cases = [
        (
            "eye=0.3,0.5,3&target=0,0,0&up=0,1,0&yfov_deg=40&width=48&height=32".to_owned(),
            serde_json::json!({"view": view_json(48, 32)}),
        ),
        (
            "format=webp&width=40&lod=12&step=0.02&tolerance=0.01&method=fixed&height=24\
             &target=0,0,0&eye=0.3,0.5,3&yfov_deg=35.5&background=10,20,30,255"
                .to_owned(),
            serde_json::json!({"view": {"eye": [0.3, 0.5, 3.0], "target": [0, 0, 0], "yfov_deg": 35.5,
                                        "width": 40, "height": 24},
                               "format": "webp", "lod": 12, "step": 0.02, "tolerance": 0.01,
                               "method": "fixed", "background": [10, 20, 30, 255]}),
        ),
        (
            "az=33.5&el=21.25&dist=2.75&target=0.1,-0.2,0.05&yfov_deg=40&width=32&height=32\
             &format=jpeg&quality=70&background=0,0,0,255&guide=0"
                .to_owned(),
            serde_json::json!({"view": {"eye": orbit_eye, "target": [0.1, -0.2, 0.05], "up": [0, 1, 0],
                                        "yfov_deg": 40, "width": 32, "height": 32},
                               "format": "jpeg", "quality": 70, "background": [0, 0, 0, 255],
                               "guide": 0}),
        ),
    ];
    let mut tags = Vec::new();
    for (query, body) in &cases {
        let link = get_link(&state, query, None).await;
        let posted = render(&state, body).await;
        assert_eq!(
            link.status,
            StatusCode::OK,
            "{query}: {}",
            String::from_utf8_lossy(&link.body)
        );
        assert_eq!(posted.status, StatusCode::OK, "{body}");
        assert!(
            link.body == posted.body,
            "{query}: the image differs from the POST render"
        );
        assert_eq!(render_headers(&link), render_headers(&posted), "{query}");
        assert!(link.header("x-render-ms").parse::<f64>().is_ok());
        assert!(link.header("x-encode-ms").parse::<f64>().is_ok());
        assert_eq!(link.header("cache-control"), "public, max-age=300");
        assert_eq!(posted.header("cache-control"), "no-store");
        let tag = link.header("etag").to_owned();
        assert!(
            tag.len() == 34 && tag.starts_with('"') && tag.ends_with('"'),
            "{tag}"
        );
        tags.push(tag);
    }
    tags.dedup();
    assert_eq!(tags.len(), cases.len(), "different renders share a tag");
    assert!(is_png(&get_link(&state, &cases[0].0, None).await.body));

    // The tag is a function of the state, not of its spelling: reordered, `40.0`, the default
    // `up` given or not, the orbit form of the same eye.
    let tag = &tags[0];
    for same in [
        "height=32&width=48&yfov_deg=40.0&target=0,0,0&eye=0.3,0.5,3&up=0,1,0",
        "eye=0.30,0.5,3e0&target=0,0,0&yfov_deg=40&width=48&height=32&up=0,1.0,0",
    ] {
        let reply = get_link(&state, same, None).await;
        assert_eq!(reply.status, StatusCode::OK);
        assert_eq!(reply.header("etag"), tag, "{same}");
    }
    // A tag the client holds is answered 304 without a body; a stale or weak one too where it
    // matches, any other with the image.
    for held in [
        tag.clone(),
        format!("W/{tag}"),
        format!("\"0123\", {tag}"),
        "*".to_owned(),
    ] {
        let reply = get_link(&state, &cases[0].0, Some(&held)).await;
        assert_eq!(reply.status, StatusCode::NOT_MODIFIED, "{held}");
        assert!(reply.body.is_empty());
        assert_eq!(reply.header("etag"), tag);
        assert_eq!(reply.header("cache-control"), "public, max-age=300");
    }
    let other = get_link(&state, &cases[0].0, Some(&tags[1])).await;
    assert_eq!(other.status, StatusCode::OK);
    assert!(is_png(&other.body));

    // New content under the same id gets new tags.
    let delete = send(
        &state,
        Request::delete("/v1/assets/tiny")
            .body(Body::empty())
            .expect("request"),
    )
    .await;
    assert_eq!(delete.status, StatusCode::NO_CONTENT);
    let uploaded = send(
        &state,
        upload("/v1/assets?id=tiny", None, asset_declaring_states(2)),
    )
    .await;
    assert_eq!(uploaded.status, StatusCode::CREATED);
    let renewed = get_link(&state, &cases[0].0, Some(tag)).await;
    assert_eq!(renewed.status, StatusCode::OK);
    assert_ne!(renewed.header("etag"), tag);
}

#[tokio::test(flavor = "multi_thread")]
async fn bad_render_links_get_json_errors_naming_the_parameter() {
    const VIEW: &str = "eye=0.3,0.5,3&target=0,0,0&yfov_deg=40&width=16&height=16";
    let (_dir, state) = setup(None, |_| {}).await;
    let cases: Vec<(String, StatusCode, &str)> = vec![
        (
            format!("{VIEW}&zoom=2"),
            StatusCode::UNPROCESSABLE_ENTITY,
            "zoom",
        ),
        (
            format!("{VIEW}&lod=12&lod=12"),
            StatusCode::UNPROCESSABLE_ENTITY,
            "`lod`",
        ),
        (
            format!("{VIEW}&depth=npy"),
            StatusCode::UNPROCESSABLE_ENTITY,
            "`depth`",
        ),
        (
            "target=0,0,0&yfov_deg=40&width=16&height=16".to_owned(),
            StatusCode::UNPROCESSABLE_ENTITY,
            "`eye`",
        ),
        (
            "eye=0.3,0.5,3&target=0,0,0&yfov_deg=40&width=16".to_owned(),
            StatusCode::UNPROCESSABLE_ENTITY,
            "`height`",
        ),
        (
            "eye=a,b,c&target=0,0,0&yfov_deg=40&width=16&height=16".to_owned(),
            StatusCode::UNPROCESSABLE_ENTITY,
            "`eye`",
        ),
        (
            "eye=0,0,3&target=0,0,0&yfov_deg=inf&width=16&height=16".to_owned(),
            StatusCode::UNPROCESSABLE_ENTITY,
            "`yfov_deg`",
        ),
        (
            "eye=0,0,3&target=0,0,0&yfov_deg=180&width=16&height=16".to_owned(),
            StatusCode::UNPROCESSABLE_ENTITY,
            "yfov",
        ),
        (
            "eye=0,0,3&target=0,0,0&yfov_deg=40&width=513&height=16".to_owned(),
            StatusCode::UNPROCESSABLE_ENTITY,
            "513",
        ),
        (
            "eye=0,0,3&target=0,0,0&yfov_deg=40&width=1.5&height=16".to_owned(),
            StatusCode::UNPROCESSABLE_ENTITY,
            "`width`",
        ),
        (
            "eye=0,0,0&target=0,0,0&yfov_deg=40&width=16&height=16".to_owned(),
            StatusCode::UNPROCESSABLE_ENTITY,
            "eye",
        ),
        (
            format!("{VIEW}&up=0,0,0"),
            StatusCode::UNPROCESSABLE_ENTITY,
            "up",
        ),
        (
            format!("{VIEW}&lod=13"),
            StatusCode::UNPROCESSABLE_ENTITY,
            "13",
        ),
        (
            format!("{VIEW}&lod=abc"),
            StatusCode::UNPROCESSABLE_ENTITY,
            "`lod`",
        ),
        (
            format!("{VIEW}&lod=12.5"),
            StatusCode::UNPROCESSABLE_ENTITY,
            "`lod`",
        ),
        (
            format!("{VIEW}&step=0"),
            StatusCode::UNPROCESSABLE_ENTITY,
            "step",
        ),
        (
            format!("{VIEW}&method=magic"),
            StatusCode::UNPROCESSABLE_ENTITY,
            "`method`",
        ),
        (
            format!("{VIEW}&format=gif"),
            StatusCode::UNPROCESSABLE_ENTITY,
            "gif",
        ),
        (
            format!("{VIEW}&format=none"),
            StatusCode::UNPROCESSABLE_ENTITY,
            "none",
        ),
        (
            format!("{VIEW}&quality=101"),
            StatusCode::UNPROCESSABLE_ENTITY,
            "quality",
        ),
        (
            format!("{VIEW}&background=0,0,0,256"),
            StatusCode::UNPROCESSABLE_ENTITY,
            "`background`",
        ),
        (
            format!("{VIEW}&target_psnr=30&lod=12"),
            StatusCode::UNPROCESSABLE_ENTITY,
            "target_psnr",
        ),
        (
            format!("{VIEW}&az=10"),
            StatusCode::UNPROCESSABLE_ENTITY,
            "`az`",
        ),
        (
            "az=10&el=0&target=0,0,0&yfov_deg=40&width=16&height=16".to_owned(),
            StatusCode::UNPROCESSABLE_ENTITY,
            "`dist`",
        ),
        (
            format!("{VIEW}&lod=%FF"),
            StatusCode::UNPROCESSABLE_ENTITY,
            "",
        ),
    ];
    for (query, status, needle) in cases {
        let reply = get_link(&state, &query, None).await;
        assert_eq!(
            reply.status,
            status,
            "{query}: {}",
            String::from_utf8_lossy(&reply.body)
        );
        assert_eq!(reply.error_kind(), "invalid", "{query}");
        let message = reply.json()["error"]["message"]
            .as_str()
            .unwrap_or_default()
            .to_owned();
        assert!(
            !message.is_empty() && message.contains(needle),
            "{query}: {message}"
        );
        assert!(
            reply.header("etag").is_empty(),
            "{query}: an error has no tag"
        );
    }
    // The checks shared with the POST body answer the POST body's words.
    for (query, body) in [
        (
            format!("{VIEW}&lod=13"),
            serde_json::json!({"view": view_json(16, 16), "lod": 13}),
        ),
        (
            "eye=0.3,0.5,3&target=0,0,0&yfov_deg=180&width=16&height=16".to_owned(),
            serde_json::json!({"view": {"eye": [0.3, 0.5, 3], "target": [0, 0, 0], "yfov_deg": 180,
                                        "width": 16, "height": 16}}),
        ),
    ] {
        let (link, posted) = (
            get_link(&state, &query, None).await,
            render(&state, &body).await,
        );
        assert_eq!(link.status, posted.status);
        assert_eq!(link.json(), posted.json(), "{query}");
    }
    // Unknown asset: 404 whatever the parameters.
    for query in [VIEW, "zoom=1"] {
        let reply = get(&state, &format!("/v1/assets/ghost/render?{query}")).await;
        assert_eq!(reply.status, StatusCode::NOT_FOUND, "{query}");
        assert_eq!(reply.error_kind(), "not_found");
    }
    let bad_id = get(&state, &format!("/v1/assets/bad..id/render?{VIEW}")).await;
    assert_eq!(bad_id.status, StatusCode::UNPROCESSABLE_ENTITY);
    // The server is still fine.
    assert_eq!(get_link(&state, VIEW, None).await.status, StatusCode::OK);
}

fn upload(uri: &str, token: Option<&str>, body: Vec<u8>) -> Request<Body> {
    let mut request = Request::post(uri).header(header::CONTENT_TYPE, "application/octet-stream");
    if let Some(token) = token {
        request = request.header(header::AUTHORIZATION, format!("Bearer {token}"));
    }
    request.body(Body::from(body)).expect("request")
}

/// The entries of an assets folder, sorted; of the bake job journal (`.jobs/`, whose records
/// come and go with jobs) only its temporary files, as `.jobs/NAME`.
fn dir_names(dir: &std::path::Path) -> Vec<String> {
    let list = |dir: &std::path::Path| -> Vec<String> {
        std::fs::read_dir(dir)
            .expect("dir")
            .map(|e| e.expect("entry").file_name().to_string_lossy().into_owned())
            .collect()
    };
    let journal = lumigraph_server::service::journal::JOURNAL_DIR;
    let mut names: Vec<String> = list(dir).into_iter().filter(|n| n != journal).collect();
    if dir.join(journal).is_dir() {
        names.extend(
            list(&dir.join(journal))
                .into_iter()
                .filter(|n| n.starts_with('.'))
                .map(|n| format!("{journal}/{n}")),
        );
    }
    names.sort();
    names
}

#[tokio::test(flavor = "multi_thread")]
async fn upload_and_delete_assets() {
    let (dir, state) = setup(Some(TOKEN), |c| c.max_upload_bytes = 1 << 20).await;
    let asset = tiny_asset().to_vec();
    assert_eq!(
        send(&state, upload("/v1/assets?id=copy", None, asset.clone()))
            .await
            .status,
        StatusCode::UNAUTHORIZED
    );
    let wrong = send(
        &state,
        upload("/v1/assets?id=copy", Some("nope"), asset.clone()),
    )
    .await;
    assert_eq!(wrong.status, StatusCode::UNAUTHORIZED);
    assert_eq!(wrong.header("www-authenticate"), "Bearer");

    // Corrupt uploads: 422 and nothing left on disk.
    let mut corrupt = asset.clone();
    let last = corrupt.len() - 10;
    corrupt[last] ^= 0xff;
    for bad in [
        b"not an asset".to_vec(),
        asset[..asset.len() / 2].to_vec(),
        corrupt,
        Vec::new(),
    ] {
        let reply = send(&state, upload("/v1/assets?id=bad", Some(TOKEN), bad)).await;
        assert_eq!(
            reply.status,
            StatusCode::UNPROCESSABLE_ENTITY,
            "{}",
            String::from_utf8_lossy(&reply.body)
        );
        assert_eq!(reply.error_kind(), "bad_upload");
        assert_eq!(dir_names(dir.path()), vec!["tiny.lfa"]);
    }
    let too_big = send(
        &state,
        upload("/v1/assets?id=big", Some(TOKEN), vec![0; (1 << 20) + 1]),
    )
    .await;
    assert_eq!(too_big.status, StatusCode::PAYLOAD_TOO_LARGE);
    assert_eq!(dir_names(dir.path()), vec!["tiny.lfa"]);

    let created = send(
        &state,
        upload("/v1/assets?id=copy", Some(TOKEN), asset.clone()),
    )
    .await;
    assert_eq!(
        created.status,
        StatusCode::CREATED,
        "{}",
        String::from_utf8_lossy(&created.body)
    );
    assert_eq!(created.header("location"), "/v1/assets/copy");
    assert_eq!(dir_names(dir.path()), vec!["copy.lfa", "tiny.lfa"]);
    assert_eq!(
        send(
            &state,
            upload("/v1/assets?id=copy", Some(TOKEN), asset.clone())
        )
        .await
        .status,
        StatusCode::CONFLICT
    );
    let rendered = post_json(
        &state,
        "/v1/assets/copy/render",
        serde_json::json!({"view": view_json(8, 8)}).to_string(),
    )
    .await;
    assert_eq!(rendered.status, StatusCode::OK);

    let delete = |token: Option<&str>| {
        let mut request = Request::delete("/v1/assets/copy");
        if let Some(token) = token {
            request = request.header(header::AUTHORIZATION, format!("Bearer {token}"));
        }
        request.body(Body::empty()).expect("request")
    };
    assert_eq!(
        send(&state, delete(None)).await.status,
        StatusCode::UNAUTHORIZED
    );
    assert_eq!(
        send(&state, delete(Some(TOKEN))).await.status,
        StatusCode::NO_CONTENT
    );
    assert_eq!(
        send(&state, delete(Some(TOKEN))).await.status,
        StatusCode::NOT_FOUND
    );
    assert_eq!(
        get(&state, "/v1/assets/copy").await.status,
        StatusCode::NOT_FOUND
    );
    assert_eq!(dir_names(dir.path()), vec!["tiny.lfa"]);
}

/// The tiny asset with `states` states declared of which only the base state is stored (the
/// others fall back to it): a valid file of a few kilobytes whose declared decoded size is
/// `states` times the tiny asset's.
fn asset_declaring_states(states: usize) -> Vec<u8> {
    let tiny = lumigraph_core::asset::AssetFile::from_bytes(tiny_asset().to_vec()).expect("tiny");
    let mut header = tiny.header().clone();
    header.states = (0..states)
        .map(|i| lumigraph_core::asset::StateDesc {
            name: format!("state-{i}"),
            params: serde_json::Map::new(),
        })
        .collect();
    let images: Vec<_> = tiny
        .index()
        .iter()
        .filter(|e| e.page == 0)
        .map(|e| (e.key, tiny.read_image(e.key).expect("image")))
        .collect();
    lumigraph_core::asset::encode_asset(header, images).expect("encoding")
}

/// The value of an unlabelled metric in a `/metrics` text.
async fn metric(state: &AppState, name: &str) -> u64 {
    let text = String::from_utf8(get(state, "/metrics").await.body).expect("utf-8");
    text.lines()
        .find_map(|l| l.strip_prefix(name)?.strip_prefix(' ')?.trim().parse().ok())
        .unwrap_or_else(|| panic!("no metric {name} in:\n{text}"))
}

/// Decoded size of the tiny asset: 12 cameras × 32² × (4 + 2) bytes.
const TINY_DECODED: u64 = 12 * 32 * 32 * 6;
/// Its texture bytes: 12 cameras, padded to 13 layers, × 32² × (4 + 8) bytes.
const TINY_GPU: u64 = 13 * 32 * 32 * 12;

#[tokio::test(flavor = "multi_thread")]
async fn assets_over_the_decoded_size_limit_are_refused_before_decoding() {
    // A 4 KB upload declaring 256 states decodes (as declared) to 256 × the tiny asset.
    let (dir, state) = setup(Some(TOKEN), |c| {
        c.max_asset_decoded_bytes = 1 << 20;
    })
    .await;
    let forged = asset_declaring_states(256);
    assert!(forged.len() < 64 << 10, "{} bytes", forged.len());
    lumigraph_core::asset::AssetFile::from_bytes(forged.clone()).expect("a valid asset");
    let reply = send(
        &state,
        upload("/v1/assets?id=forged", Some(TOKEN), forged.clone()),
    )
    .await;
    assert_eq!(reply.status, StatusCode::PAYLOAD_TOO_LARGE);
    assert_eq!(reply.error_kind(), "too_large");
    let message = reply.json()["error"]["message"]
        .as_str()
        .unwrap_or_default()
        .to_owned();
    let decoded = (TINY_DECODED * 256).to_string();
    for part in [
        decoded.as_str(),
        "1048576 bytes",
        "--max-asset-decoded-bytes",
        "256 states",
    ] {
        assert!(message.contains(part), "{part:?} not in {message:?}");
    }
    assert_eq!(dir_names(dir.path()), vec!["tiny.lfa"]);

    // The same file in the folder at start-up is skipped, the others load.
    std::fs::write(dir.path().join("forged.lfa"), &forged).expect("writing");
    let mut config = state.config().clone();
    config.max_asset_decoded_bytes = 1 << 20;
    let restarted = tokio::task::spawn_blocking(move || AppState::new(config, gpu()))
        .await
        .expect("join")
        .expect("state");
    restarted.load_assets().await.expect("loading");
    let ids: Vec<String> = restarted
        .assets()
        .list()
        .into_iter()
        .map(|a| a.id)
        .collect();
    assert_eq!(ids, vec!["tiny"]);
}

#[tokio::test(flavor = "multi_thread")]
async fn the_memory_budget_refuses_uploads_and_bakes_and_deleting_frees_it_at_once() {
    // Room for the tiny asset and one more.
    let (_dir, state) = setup(Some(TOKEN), |c| {
        c.asset_memory_budget = 2 * TINY_GPU + TINY_GPU / 2;
    })
    .await;
    assert_eq!(metric(&state, "lumigraph_gpu_light_fields").await, 1);
    assert_eq!(
        metric(&state, "lumigraph_asset_memory_bytes").await,
        TINY_GPU
    );
    let asset = tiny_asset().to_vec();
    let delete = |id: &str| {
        Request::delete(format!("/v1/assets/{id}"))
            .header(header::AUTHORIZATION, format!("Bearer {TOKEN}"))
            .body(Body::empty())
            .expect("request")
    };
    // Upload and delete, never rendering in between: each delete must give the memory back,
    // or the next upload would not fit.
    for round in 0..3 {
        let created = send(
            &state,
            upload("/v1/assets?id=second", Some(TOKEN), asset.clone()),
        )
        .await;
        assert_eq!(created.status, StatusCode::CREATED, "round {round}");
        assert_eq!(created.json()["gpu_bytes"], TINY_GPU);
        let refused = send(
            &state,
            upload("/v1/assets?id=third", Some(TOKEN), asset.clone()),
        )
        .await;
        assert_eq!(
            refused.status,
            StatusCode::PAYLOAD_TOO_LARGE,
            "round {round}"
        );
        let message = refused.json()["error"]["message"]
            .as_str()
            .unwrap_or_default()
            .to_owned();
        assert!(message.contains("--asset-memory-budget"), "{message}");
        assert!(
            message.contains(&(2 * TINY_GPU + TINY_GPU / 2).to_string()),
            "{message}"
        );
        assert_eq!(metric(&state, "lumigraph_gpu_light_fields").await, 2);
        assert_eq!(
            send(&state, delete("second")).await.status,
            StatusCode::NO_CONTENT
        );
        assert_eq!(
            metric(&state, "lumigraph_gpu_light_fields").await,
            1,
            "round {round}"
        );
        assert_eq!(
            metric(&state, "lumigraph_asset_memory_bytes").await,
            TINY_GPU
        );
    }
    assert_eq!(
        metric(&state, "lumigraph_asset_memory_budget_bytes").await,
        2 * TINY_GPU + TINY_GPU / 2
    );
    // A bake whose asset could not fit is refused before any work.
    let obj = icosahedron_obj();
    let reply = post_bake(
        &state,
        Some(TOKEN),
        &[
            ("mesh", Some("ico.obj"), obj.as_bytes()),
            ("options", None, br#"{"cameras": 162, "resolution": 256}"#),
        ],
    )
    .await;
    assert_eq!(reply.status, StatusCode::PAYLOAD_TOO_LARGE);
    assert!(
        reply.json()["error"]["message"]
            .as_str()
            .is_some_and(|m| m.contains("--asset-memory-budget")),
        "{}",
        String::from_utf8_lossy(&reply.body)
    );
}

#[tokio::test(flavor = "multi_thread")]
async fn the_server_memory_budget_makes_renders_wait_or_get_503_with_retry_after() {
    use lumigraph_server::service::budget::frame_bytes;
    // The tiny asset plus one 64×64 frame: a 128×128 frame can never fit (413), and a 64×64
    // frame fits only while nothing else is charged.
    let budget = TINY_GPU + frame_bytes(64, 64);
    let (_dir, state) = setup(Some(TOKEN), |c| {
        c.memory_budget = budget;
        c.asset_memory_budget = budget;
        c.memory_wait = std::time::Duration::from_millis(200);
    })
    .await;
    assert_eq!(
        state.budget().used(),
        TINY_GPU,
        "the loaded asset is charged"
    );
    let ok = render(&state, &serde_json::json!({"view": view_json(64, 64)})).await;
    assert_eq!(ok.status, StatusCode::OK);
    assert_eq!(
        state.budget().used(),
        TINY_GPU,
        "the frame's charge is given back"
    );
    let never = render(&state, &serde_json::json!({"view": view_json(128, 128)})).await;
    assert_eq!(never.status, StatusCode::PAYLOAD_TOO_LARGE);
    assert!(
        never.json()["error"]["message"]
            .as_str()
            .is_some_and(|m| m.contains("--memory-budget"))
    );
    // Memory taken by something else (another frame in flight): the render waits, then 503.
    let held = state
        .budget()
        .try_charge(frame_bytes(64, 64))
        .expect("fits");
    let busy = render(&state, &serde_json::json!({"view": view_json(64, 64)})).await;
    assert_eq!(busy.status, StatusCode::SERVICE_UNAVAILABLE);
    assert_eq!(
        busy.headers
            .get(header::RETRY_AFTER)
            .map(axum::http::HeaderValue::as_bytes),
        Some(&b"1"[..])
    );
    assert_eq!(busy.error_kind(), "unavailable");
    // An upload that fits the asset budget but not the server's memory now: 503, not 413.
    let upload_busy = send(
        &state,
        upload("/v1/assets?id=second", Some(TOKEN), tiny_asset().to_vec()),
    )
    .await;
    assert!(
        upload_busy.status == StatusCode::SERVICE_UNAVAILABLE
            || upload_busy.status == StatusCode::PAYLOAD_TOO_LARGE,
        "{}",
        String::from_utf8_lossy(&upload_busy.body)
    );
    // Given back while a render waits: that render goes through.
    let waiting = {
        let state = state.clone();
        tokio::spawn(async move {
            render(&state, &serde_json::json!({"view": view_json(64, 64)})).await
        })
    };
    tokio::time::sleep(std::time::Duration::from_millis(50)).await;
    drop(held);
    assert_eq!(waiting.await.expect("join").status, StatusCode::OK);
    assert_eq!(
        metric(&state, "lumigraph_memory_used_bytes").await,
        TINY_GPU
    );
    assert_eq!(
        metric(&state, "lumigraph_memory_budget_bytes").await,
        budget
    );
    // The render path moved: ready.
    assert_eq!(get(&state, "/readyz").await.status, StatusCode::OK);
}

#[tokio::test(flavor = "multi_thread")]
async fn a_lost_device_is_replaced_and_the_assets_uploaded_again() {
    // A device of its own: the injected loss must not reach the device the other tests share.
    let own = tokio::task::spawn_blocking(|| Gpu::new().map(Arc::new))
        .await
        .expect("join")
        .expect("a GPU adapter");
    let dir = tempfile::tempdir().expect("temp dir");
    std::fs::write(dir.path().join("tiny.lfa"), tiny_asset()).expect("writing the asset");
    let mut config = ServeConfig::new(dir.path(), "127.0.0.1:0".parse().expect("addr"));
    config.bake_demo_if_empty = false;
    config.max_px = 512;
    let device = Arc::clone(&own);
    let state = tokio::task::spawn_blocking(move || AppState::new(config, device))
        .await
        .expect("join")
        .expect("state");
    state.load_assets().await.expect("loading assets");
    let body = serde_json::json!({"view": view_json(64, 48)});
    let before = render(&state, &body).await;
    assert_eq!(before.status, StatusCode::OK);

    own.inject_device_loss("test");
    // The request in flight on the lost device fails at once with 503, never hangs.
    let during = tokio::time::timeout(std::time::Duration::from_secs(30), render(&state, &body))
        .await
        .expect("a render on a lost device must not hang");
    assert_eq!(during.status, StatusCode::SERVICE_UNAVAILABLE);
    assert_eq!(
        during
            .headers
            .get(header::RETRY_AFTER)
            .map(axum::http::HeaderValue::as_bytes),
        Some(&b"1"[..])
    );
    let message = during.json()["error"]["message"]
        .as_str()
        .unwrap_or_default()
        .to_owned();
    assert!(message.contains("device was lost"), "{message}");

    // The server opens a new device, uploads the asset again and is ready again.
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(120);
    loop {
        let ready = get(&state, "/readyz").await.status == StatusCode::OK;
        let replaced = state.pool().engine().generation == 1;
        if ready && replaced && state.assets().len() == 1 {
            break;
        }
        assert!(
            std::time::Instant::now() < deadline,
            "no recovery within 120 s"
        );
        tokio::time::sleep(std::time::Duration::from_millis(50)).await;
    }
    assert!(
        !Arc::ptr_eq(state.pool().engine().gpu(), &own),
        "a new device"
    );
    let after = render(&state, &body).await;
    assert_eq!(after.status, StatusCode::OK);
    // Same asset, same renderer code, a device of the same adapter: the same image.
    assert_eq!(after.body, before.body, "the frame after recovery differs");
    assert_eq!(metric(&state, "lumigraph_gpu_devices_lost_total").await, 1);
    assert_eq!(
        state.pool().renderer().resident().fields,
        1,
        "the asset lives on the new device"
    );
}

#[tokio::test(flavor = "multi_thread")]
async fn an_asset_budget_above_the_server_budget_is_refused_at_start() {
    let dir = tempfile::tempdir().expect("temp dir");
    let mut config = ServeConfig::new(dir.path(), "127.0.0.1:0".parse().expect("addr"));
    config.memory_budget = 1 << 30;
    config.asset_memory_budget = 2 << 30;
    let err = tokio::task::spawn_blocking(move || AppState::new(config, gpu()))
        .await
        .expect("join")
        .err()
        .expect("refused");
    assert!(format!("{err:#}").contains("--memory-budget"), "{err:#}");
}

#[tokio::test(flavor = "multi_thread")]
async fn temporary_files_left_by_a_killed_server_are_removed_at_start_up() {
    let dir = tempfile::tempdir().expect("temp dir");
    std::fs::write(dir.path().join("tiny.lfa"), tiny_asset()).expect("writing the asset");
    for planted in [
        ".upload-tmp-3f9c0a12b4d5e6f7.part",
        ".tiny.lfa.tmp-4242-0",
        ".mesh-1.lfa.tmp-77-3",
    ] {
        std::fs::write(dir.path().join(planted), b"half written").expect("planting");
    }
    for kept in ["notes.txt", ".keep"] {
        std::fs::write(dir.path().join(kept), b"not ours").expect("planting");
    }
    let mut config = ServeConfig::new(dir.path(), "127.0.0.1:0".parse().expect("addr"));
    config.bake_demo_if_empty = false;
    let state = tokio::task::spawn_blocking(move || AppState::new(config, gpu()))
        .await
        .expect("join")
        .expect("state");
    state.load_assets().await.expect("loading");
    assert_eq!(
        dir_names(dir.path()),
        vec![".keep", "notes.txt", "tiny.lfa"]
    );
    assert_eq!(state.assets().len(), 1);
}

#[tokio::test(flavor = "multi_thread")]
async fn a_bake_that_cannot_be_calibrated_fails_with_the_reason() {
    // One vertex at 1e20: the calibration views around the huge bounding sphere see nothing.
    let (dir, state) = setup(Some(TOKEN), |_| {}).await;
    let off = b"OFF\n5 5 0\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n1e20 0 0\n\
3 0 2 1\n3 0 1 3\n3 0 3 2\n3 1 2 3\n3 1 4 2\n";
    let accepted = post_bake(
        &state,
        Some(TOKEN),
        &[
            ("mesh", Some("far.off"), off),
            ("options", None, br#"{"cameras": 12, "resolution": 16}"#),
            ("id", None, b"far"),
        ],
    )
    .await;
    assert_eq!(accepted.status, StatusCode::ACCEPTED);
    let job_uri = accepted.header("location").to_owned();
    let status = finished_job(&state, &job_uri).await;
    assert_eq!(status["state"], "failed", "{status}");
    assert!(
        status.to_string().contains("could not measure any setting"),
        "{status}"
    );
    assert_eq!(dir_names(dir.path()), vec!["tiny.lfa"]);
    assert_eq!(
        get(&state, "/v1/assets/far").await.status,
        StatusCode::NOT_FOUND
    );
}

/// The status of the job at `job_uri` once it is done or failed (polled for up to 30 s; the
/// last status seen otherwise).
async fn finished_job(state: &AppState, job_uri: &str) -> serde_json::Value {
    let mut status = serde_json::Value::Null;
    for _ in 0..600 {
        status = get(state, job_uri).await.json();
        if status["state"] == "done" || status["state"] == "failed" {
            break;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    status
}

fn bake_form(fields: &[(&str, Option<&str>, &[u8])]) -> (String, Vec<u8>) {
    let boundary = "XtestBoundaryX".to_owned();
    let mut body = Vec::new();
    for (name, file_name, bytes) in fields {
        body.extend_from_slice(format!("--{boundary}\r\n").as_bytes());
        match file_name {
            Some(f) => body.extend_from_slice(format!("Content-Disposition: form-data; name=\"{name}\"; filename=\"{f}\"\r\nContent-Type: application/octet-stream\r\n\r\n").as_bytes()),
            None => body.extend_from_slice(format!("Content-Disposition: form-data; name=\"{name}\"\r\n\r\n").as_bytes()),
        }
        body.extend_from_slice(bytes);
        body.extend_from_slice(b"\r\n");
    }
    body.extend_from_slice(format!("--{boundary}--\r\n").as_bytes());
    (format!("multipart/form-data; boundary={boundary}"), body)
}

async fn post_bake(
    state: &AppState,
    token: Option<&str>,
    fields: &[(&str, Option<&str>, &[u8])],
) -> Reply {
    let (content_type, body) = bake_form(fields);
    let mut request = Request::post("/v1/bake").header(header::CONTENT_TYPE, content_type);
    if let Some(token) = token {
        request = request.header(header::AUTHORIZATION, format!("Bearer {token}"));
    }
    send(state, request.body(Body::from(body)).expect("request")).await
}

/// `POST /v1/bake` with `auto` (docs/auto-bake.md): bad targets and options that name what
/// the automatic bake chooses are refused at once, before a job exists.
#[tokio::test(flavor = "multi_thread")]
async fn auto_bake_jobs() {
    let (_dir, state) = setup(None, |_| {}).await;
    let obj = icosahedron_obj();
    for (auto, options, why) in [
        ("maybe", "", "expected true, false"),
        (r#"{"target_psnr": 27, "max_bytes": 10}"#, "", "not both"),
        (r#"{"target_psnr": -1}"#, "", "target PSNR"),
        (r#"{"target_psnr": 1e999}"#, "", "expected true, false"),
        (r#"{"max_bytes": 0}"#, "", "max bytes"),
        (r#"{"budget": 1}"#, "", "unknown field"),
        (
            "true",
            r#"{"cameras": 42, "depth_bits": 8}"#,
            "cameras, depth_bits",
        ),
        (
            "true",
            r#"{"color_codec": "bc1"}"#,
            "color_codec: an automatic bake chooses settings for raw pages",
        ),
        (
            "true",
            r#"{"depth_codec": "bc4"}"#,
            "depth_codec: an automatic",
        ),
    ] {
        let mut fields: Vec<(&str, Option<&str>, &[u8])> = vec![
            ("mesh", Some("ico.obj"), obj.as_bytes()),
            ("auto", None, auto.as_bytes()),
            ("id", None, b"ico"),
        ];
        if !options.is_empty() {
            fields.push(("options", None, options.as_bytes()));
        }
        let reply = post_bake(&state, None, &fields).await;
        let body = String::from_utf8_lossy(&reply.body).into_owned();
        assert_eq!(
            reply.status,
            StatusCode::UNPROCESSABLE_ENTITY,
            "{auto}: {body}"
        );
        assert!(body.contains(why), "{auto}: {body}");
    }

    // Nothing was accepted (the whole bake runs in the service end-to-end tests): the id of a
    // refused request is still free.
    assert_eq!(
        get(&state, "/v1/assets/ico").await.status,
        StatusCode::NOT_FOUND
    );
}

#[tokio::test(flavor = "multi_thread")]
async fn bake_jobs() {
    let (dir, state) = setup(Some(TOKEN), |c| c.max_mesh_bytes = 64 << 10).await;
    let obj = icosahedron_obj();
    let options = br#"{"cameras": 12, "resolution": 16}"#;
    let fields: [(&str, Option<&str>, &[u8]); 3] = [
        ("mesh", Some("ico.obj"), obj.as_bytes()),
        ("options", None, options),
        ("id", None, b"baked"),
    ];
    assert_eq!(
        post_bake(&state, None, &fields).await.status,
        StatusCode::UNAUTHORIZED
    );

    let bad_mesh = post_bake(
        &state,
        Some(TOKEN),
        &[("mesh", Some("x.obj"), b"v 0 0 0\nf 1 2 3\n")],
    )
    .await;
    assert_eq!(
        bad_mesh.status,
        StatusCode::UNPROCESSABLE_ENTITY,
        "{}",
        String::from_utf8_lossy(&bad_mesh.body)
    );
    assert_eq!(bad_mesh.error_kind(), "bad_upload");
    let bad_format = post_bake(
        &state,
        Some(TOKEN),
        &[("mesh", Some("x.xyz"), obj.as_bytes())],
    )
    .await;
    assert_eq!(bad_format.status, StatusCode::UNPROCESSABLE_ENTITY);
    let bad_options = post_bake(
        &state,
        Some(TOKEN),
        &[
            ("mesh", Some("x.obj"), obj.as_bytes()),
            ("options", None, br#"{"cameras": 13}"#),
        ],
    )
    .await;
    assert_eq!(bad_options.status, StatusCode::UNPROCESSABLE_ENTITY);
    let malformed_options = post_bake(
        &state,
        Some(TOKEN),
        &[
            ("mesh", Some("x.obj"), obj.as_bytes()),
            ("options", None, b"{cameras"),
        ],
    )
    .await;
    assert_eq!(malformed_options.status, StatusCode::BAD_REQUEST);
    let too_big = post_bake(
        &state,
        Some(TOKEN),
        &[("mesh", Some("x.obj"), &vec![b' '; 70 << 10])],
    )
    .await;
    assert_eq!(
        too_big.status,
        StatusCode::PAYLOAD_TOO_LARGE,
        "{}",
        String::from_utf8_lossy(&too_big.body)
    );
    let traversal = post_bake(
        &state,
        Some(TOKEN),
        &[
            ("mesh", Some("x.obj"), obj.as_bytes()),
            ("id", None, b"../up"),
        ],
    )
    .await;
    assert_eq!(traversal.status, StatusCode::UNPROCESSABLE_ENTITY);
    assert_eq!(dir_names(dir.path()), vec!["tiny.lfa"]);

    let accepted = post_bake(&state, Some(TOKEN), &fields).await;
    assert_eq!(
        accepted.status,
        StatusCode::ACCEPTED,
        "{}",
        String::from_utf8_lossy(&accepted.body)
    );
    let job = accepted.json();
    assert_eq!(job["asset"], "baked");
    let job_uri = accepted.header("location").to_owned();
    assert_eq!(
        post_bake(&state, Some(TOKEN), &fields).await.status,
        StatusCode::CONFLICT
    );
    let status = finished_job(&state, &job_uri).await;
    assert_eq!(status["state"], "done", "{status}");
    assert_eq!(status["cameras_done"], 12);
    assert!(status["report"]["asset_bytes"].as_u64().unwrap_or(0) > 0);
    let rendered = post_json(
        &state,
        "/v1/assets/baked/render",
        serde_json::json!({"view": view_json(8, 8)}).to_string(),
    )
    .await;
    assert_eq!(rendered.status, StatusCode::OK);
    assert_eq!(
        get(&state, "/v1/jobs/job-0000000000000000").await.status,
        StatusCode::NOT_FOUND
    );
    // Bakes are calibrated by default: renders can ask for a quality or a time instead of knobs.
    assert!(
        status["report"]["calibrate_ms"].as_f64().unwrap_or(0.0) > 0.0,
        "{status}"
    );
    let by_goal = post_json(
        &state,
        "/v1/assets/baked/render",
        serde_json::json!({"view": view_json(16, 16), "budget_ms": 1e6}).to_string(),
    )
    .await;
    assert_eq!(
        by_goal.status,
        StatusCode::OK,
        "{}",
        String::from_utf8_lossy(&by_goal.body)
    );
    assert_eq!(by_goal.header("x-chosen-cameras"), "12");
    assert_eq!(by_goal.header("x-goal-met"), "true");
    assert!(
        by_goal
            .header("x-predicted-psnr")
            .parse::<f64>()
            .is_ok_and(f64::is_finite)
    );
    let unreachable = post_json(
        &state,
        "/v1/assets/baked/render",
        serde_json::json!({"view": view_json(16, 16), "target_psnr": 99.0}).to_string(),
    )
    .await;
    assert_eq!(unreachable.status, StatusCode::OK);
    assert_eq!(unreachable.header("x-goal-met"), "false");
    // Automatic LOD reports its decision; pinned knobs stay.
    let auto = post_json(
        &state,
        "/v1/assets/baked/render",
        serde_json::json!({"view": view_json(16, 16), "auto_lod": 1.0, "lod": 12}).to_string(),
    )
    .await;
    assert_eq!(
        auto.status,
        StatusCode::OK,
        "{}",
        String::from_utf8_lossy(&auto.body)
    );
    assert_eq!(auto.header("x-chosen-cameras"), "12");
    let guided = post_json(
        &state,
        "/v1/assets/baked/render",
        serde_json::json!({"view": view_json(64, 64), "guide": 4}).to_string(),
    )
    .await;
    assert_eq!(guided.status, StatusCode::OK);
    for name in ["x-projected-px", "x-predicted-error-px", "x-chosen-step"] {
        assert!(
            auto.header(name).parse::<f64>().is_ok_and(|v| v > 0.0),
            "{name}: {}",
            auto.header(name)
        );
    }
    for (body, needle) in [
        (
            serde_json::json!({"view": view_json(8, 8), "auto_lod": 1.0, "budget_ms": 10.0}),
            "not both",
        ),
        (
            serde_json::json!({"view": view_json(8, 8), "auto_lod": 0.0}),
            "max_error_px",
        ),
        (
            serde_json::json!({"view": view_json(8, 8), "lod_blend": 0.1}),
            "need auto_lod",
        ),
        (
            serde_json::json!({"view": view_json(8, 8), "auto_lod": 1.0, "method": "fixed"}),
            "default-method",
        ),
        (
            serde_json::json!({"view": view_json(8, 8), "guide": 1}),
            "guide 1",
        ),
    ] {
        let reply = post_json(&state, "/v1/assets/baked/render", body.to_string()).await;
        assert_eq!(reply.status, StatusCode::UNPROCESSABLE_ENTITY, "{body}");
        assert!(
            String::from_utf8_lossy(&reply.body).contains(needle),
            "{body}: {}",
            String::from_utf8_lossy(&reply.body)
        );
    }
    for (body, needle) in [
        (
            serde_json::json!({"view": view_json(8, 8), "budget_ms": 10.0, "target_psnr": 20.0}),
            "not both",
        ),
        (
            serde_json::json!({"view": view_json(8, 8), "budget_ms": 10.0, "step": 0.1}),
            "do not send them",
        ),
        (
            serde_json::json!({"view": view_json(8, 8), "target_psnr": 27.0, "guide": 8}),
            "do not send them",
        ),
        (
            serde_json::json!({"view": view_json(8, 8), "budget_ms": -1.0}),
            "budget",
        ),
    ] {
        let reply = post_json(&state, "/v1/assets/baked/render", body.to_string()).await;
        assert_eq!(reply.status, StatusCode::UNPROCESSABLE_ENTITY, "{body}");
        assert!(
            String::from_utf8_lossy(&reply.body).contains(needle),
            "{body}"
        );
    }
    // The test asset was baked without calibration: the error says how to get one.
    let uncalibrated = render(
        &state,
        &serde_json::json!({"view": view_json(8, 8), "target_psnr": 20.0}),
    )
    .await;
    assert_eq!(uncalibrated.status, StatusCode::UNPROCESSABLE_ENTITY);
    assert!(String::from_utf8_lossy(&uncalibrated.body).contains("calibrate=true"));
    let bad_flag = post_bake(
        &state,
        Some(TOKEN),
        &[
            ("mesh", Some("x.obj"), obj.as_bytes()),
            ("calibrate", None, b"maybe"),
        ],
    )
    .await;
    assert_eq!(bad_flag.status, StatusCode::UNPROCESSABLE_ENTITY);
}

// ---------------------------------------------------------------------------------------------
// A real server on port 0, driven over a WebSocket.

struct FrameHeader {
    codec: u8,
    quality: u8,
    frame_id: u32,
    request_id: u32,
    width: u32,
    height: u32,
    dropped: u32,
    encoded_quality: u8,
    flags: u8,
    /// The animation extension: frame index and time.
    animation: Option<(u32, f32)>,
}

fn parse_frame(bytes: &[u8]) -> (FrameHeader, &[u8]) {
    assert_eq!(&bytes[..4], b"LGF1");
    let u32_at =
        |i: usize| u32::from_le_bytes([bytes[i], bytes[i + 1], bytes[i + 2], bytes[i + 3]]);
    let header_len = usize::from(u16::from_le_bytes([bytes[4], bytes[5]]));
    let header = FrameHeader {
        codec: bytes[6],
        quality: bytes[7],
        frame_id: u32_at(8),
        request_id: u32_at(12),
        width: u32_at(16),
        height: u32_at(20),
        dropped: u32_at(32),
        encoded_quality: bytes[38],
        flags: bytes[39],
        animation: (bytes[39] & 8 != 0).then(|| {
            let at = 40 + if bytes[39] & 4 != 0 { 60 } else { 0 };
            (
                u32_at(at),
                f32::from_le_bytes([bytes[at + 4], bytes[at + 5], bytes[at + 6], bytes[at + 7]]),
            )
        }),
    };
    (header, &bytes[header_len..])
}

type Ws =
    tokio_tungstenite::WebSocketStream<tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>>;

async fn next_message(ws: &mut Ws) -> Message {
    loop {
        let message = tokio::time::timeout(Duration::from_secs(60), ws.next())
            .await
            .expect("a message in time")
            .expect("open")
            .expect("ok");
        if !matches!(message, Message::Ping(_) | Message::Pong(_)) {
            return message;
        }
    }
}

async fn next_frame(ws: &mut Ws) -> (FrameHeader, Vec<u8>) {
    match next_message(ws).await {
        Message::Binary(bytes) => {
            let (header, image) = parse_frame(&bytes);
            (header, image.to_vec())
        }
        other => panic!("expected a frame, got {other:?}"),
    }
}

async fn next_json(ws: &mut Ws) -> serde_json::Value {
    match next_message(ws).await {
        Message::Text(text) => serde_json::from_str(text.as_str()).expect("JSON"),
        other => panic!("expected text, got {other:?}"),
    }
}

async fn send_json(ws: &mut Ws, value: serde_json::Value) {
    ws.send(Message::text(value.to_string()))
        .await
        .expect("send");
}

#[tokio::test(flavor = "multi_thread")]
async fn websocket_stream_on_a_real_server() {
    let (_dir, state) = setup(None, |c| c.max_sessions = 1).await;
    let (addr, stop_tx, server) = serve_on_loopback(state).await;
    let url = format!("ws://{addr}/v1/stream?asset=tiny");

    // Unknown asset: 404 before the upgrade.
    match tokio_tungstenite::connect_async(format!("ws://{addr}/v1/stream?asset=ghost")).await {
        Err(tokio_tungstenite::tungstenite::Error::Http(response)) => {
            assert_eq!(response.status(), StatusCode::NOT_FOUND);
        }
        other => panic!("expected 404, got {other:?}"),
    }
    let (mut ws, _) = tokio_tungstenite::connect_async(&url)
        .await
        .expect("connect");
    // The session limit is 1: a second client gets 503 with a clear message.
    match tokio_tungstenite::connect_async(&url).await {
        Err(tokio_tungstenite::tungstenite::Error::Http(response)) => {
            assert_eq!(response.status(), StatusCode::SERVICE_UNAVAILABLE);
            let body = String::from_utf8_lossy(response.body().as_deref().unwrap_or_default())
                .into_owned();
            assert!(body.contains("session limit"), "{body}");
        }
        other => panic!("expected 503, got {other:?}"),
    }

    let hello = next_json(&mut ws).await;
    assert_eq!(hello["type"], "hello");
    assert_eq!(hello["asset"]["id"], "tiny");
    assert_eq!(hello["header_len"], 40);

    // Full quality only, lossless: each view gets exactly one matching frame.
    send_json(
        &mut ws,
        serde_json::json!({"type": "settings", "interactive": false, "still_codec": "png"}),
    )
    .await;
    send_json(
        &mut ws,
        serde_json::json!({"type": "view", "id": 1, "view": view_json(40, 24)}),
    )
    .await;
    let (header, image) = next_frame(&mut ws).await;
    assert_eq!(
        (
            header.request_id,
            header.frame_id,
            header.quality,
            header.codec
        ),
        (1, 1, 1, 0)
    );
    let (w, h, _) = lumigraph_core::image_io::decode_png_rgba8(&image).expect("png");
    assert_eq!((w, h, header.width, header.height), (40, 24, 40, 24));
    send_json(&mut ws, serde_json::json!({"type": "ack", "frame": 1})).await;

    // Errors come back as messages and the socket stays usable.
    let mut bad = view_json(16, 16);
    bad["yfov_deg"] = 180.into();
    send_json(
        &mut ws,
        serde_json::json!({"type": "view", "id": 2, "view": bad}),
    )
    .await;
    let error = next_json(&mut ws).await;
    assert_eq!(
        (
            error["type"].as_str(),
            error["request"].as_u64(),
            error["kind"].as_str()
        ),
        (Some("error"), Some(2), Some("invalid"))
    );
    ws.send(Message::text("{not json")).await.expect("send");
    assert_eq!(next_json(&mut ws).await["kind"], "malformed_json");
    send_json(
        &mut ws,
        serde_json::json!({"type": "settings", "max_in_flight": 5}),
    )
    .await;
    assert_eq!(next_json(&mut ws).await["kind"], "invalid");
    send_json(&mut ws, serde_json::json!({"type": "warp"})).await;
    assert_eq!(next_json(&mut ws).await["kind"], "invalid");

    send_json(
        &mut ws,
        serde_json::json!({"type": "view", "id": 3, "view": view_json(16, 16)}),
    )
    .await;
    let (header, _) = next_frame(&mut ws).await;
    assert_eq!((header.request_id, header.frame_id), (3, 2));
    send_json(&mut ws, serde_json::json!({"type": "ack", "frame": 2})).await;

    // Interactive then full: a reduced JPEG at once, the full frame after the rest time.
    send_json(&mut ws, serde_json::json!({"type": "settings", "interactive": true, "interactive_scale": 0.5, "rest_ms": 50})).await;
    send_json(
        &mut ws,
        serde_json::json!({"type": "view", "id": 4, "view": view_json(64, 32)}),
    )
    .await;
    let mut frames = Vec::new();
    while frames
        .last()
        .is_none_or(|h: &FrameHeader| h.quality != 1 || h.request_id != 4)
    {
        let (header, _) = next_frame(&mut ws).await;
        send_json(
            &mut ws,
            serde_json::json!({"type": "ack", "frame": header.frame_id}),
        )
        .await;
        frames.push(header);
    }
    let interactive = frames
        .iter()
        .find(|h| h.request_id == 4 && h.quality == 0)
        .expect("an interactive frame for request 4");
    assert_eq!(
        (interactive.width, interactive.height, interactive.codec),
        (32, 16, 1)
    );
    let full = frames.last().expect("full");
    assert_eq!((full.width, full.height, full.codec), (64, 32, 0));

    // Flow control: without acks at most two frames arrive; the latest view wins and the
    // skipped ones are counted as dropped.
    send_json(
        &mut ws,
        serde_json::json!({"type": "settings", "interactive": false}),
    )
    .await;
    let (settings_frame, _) = next_frame(&mut ws).await;
    let mut last_frame = settings_frame.frame_id;
    for id in 10..30 {
        send_json(
            &mut ws,
            serde_json::json!({"type": "view", "id": id, "view": view_json(16, 16)}),
        )
        .await;
    }
    let (second, _) = next_frame(&mut ws).await;
    last_frame = last_frame.max(second.frame_id);
    // Window (2) is full now: nothing more may arrive until we ack.
    assert!(
        tokio::time::timeout(Duration::from_millis(500), ws.next())
            .await
            .is_err(),
        "a third unacknowledged frame arrived"
    );
    send_json(
        &mut ws,
        serde_json::json!({"type": "ack", "frame": last_frame}),
    )
    .await;
    // If the render was slow enough that view 29 was already the second frame, there is
    // nothing newer to send.
    let latest = if second.request_id == 29 {
        second
    } else {
        next_frame(&mut ws).await.0
    };
    assert_eq!(latest.request_id, 29, "latest view wins");
    assert!(latest.dropped > 0, "skipped views are counted");

    // Graceful shutdown: the session gets a Close frame and the server returns.
    stop_tx.send(()).expect("stop");
    let closed = tokio::time::timeout(Duration::from_secs(20), async {
        while let Some(Ok(message)) = ws.next().await {
            if matches!(message, Message::Close(_)) {
                return true;
            }
        }
        true
    })
    .await;
    assert!(closed.is_ok(), "session did not close on shutdown");
    tokio::time::timeout(Duration::from_secs(20), server)
        .await
        .expect("server stops")
        .expect("join")
        .expect("serve");
}

#[tokio::test(flavor = "multi_thread")]
async fn websocket_goals_choose_full_quality_settings() {
    // A calibrated copy of the tiny asset beside the uncalibrated one.
    let (dir, _) = setup(None, |_| {}).await;
    let calibrated = tokio::task::spawn_blocking(|| {
        let gpu = gpu();
        let renderer = lumigraph_core::render::Renderer::new(gpu.clone());
        let reference = lumigraph_core::reference::ReferenceRenderer::new(gpu.clone());
        lumigraph_core::calibration::bake_calibrated(
            &Baker::new(gpu),
            &renderer,
            &reference,
            &icosahedron(),
            &tiny_options(),
            &lumigraph_core::asset::Provenance::default(),
            &mut |_, _| {},
        )
        .expect("calibrated bake")
    })
    .await
    .expect("join");
    std::fs::write(dir.path().join("cal.lfa"), &calibrated.bytes).expect("write");
    let mut config = ServeConfig::new(dir.path(), "127.0.0.1:0".parse().expect("addr"));
    config.bake_demo_if_empty = false;
    let state = tokio::task::spawn_blocking(move || AppState::new(config, gpu()))
        .await
        .expect("join")
        .expect("state");
    state.load_assets().await.expect("loading assets");
    let (addr, stop_tx, server) = serve_on_loopback(state).await;

    let (mut ws, _) = tokio_tungstenite::connect_async(format!("ws://{addr}/v1/stream?asset=cal"))
        .await
        .expect("connect");
    assert_eq!(next_json(&mut ws).await["type"], "hello");
    // Bad goals are reported and the session stays usable.
    for (settings, needle) in [
        (
            serde_json::json!({"type": "settings", "budget_ms": 10.0, "target_psnr": 20.0}),
            "not both",
        ),
        (
            serde_json::json!({"type": "settings", "budget_ms": 10.0, "lod": 12}),
            "clear them",
        ),
        (
            serde_json::json!({"type": "settings", "budget_ms": -5.0}),
            "budget",
        ),
    ] {
        send_json(&mut ws, settings.clone()).await;
        let error = next_json(&mut ws).await;
        assert_eq!(error["type"], "error", "{settings}");
        assert!(
            error["message"]
                .as_str()
                .unwrap_or_default()
                .contains(needle),
            "{error}"
        );
    }
    send_json(
        &mut ws,
        serde_json::json!({"type": "settings", "interactive": false, "still_codec": "png", "target_psnr": 1.0}),
    )
    .await;
    send_json(
        &mut ws,
        serde_json::json!({"type": "view", "id": 5, "view": view_json(40, 24)}),
    )
    .await;
    let (header, image) = next_frame(&mut ws).await;
    assert_eq!(
        (header.request_id, header.width, header.height),
        (5, 40, 24)
    );
    assert!(is_png(&image));
    // Automatic LOD instead of the goal (cleared with null); with a goal it is refused.
    send_json(
        &mut ws,
        serde_json::json!({"type": "settings", "auto_lod": 1.0}),
    )
    .await;
    let error = next_json(&mut ws).await;
    assert!(
        error["message"]
            .as_str()
            .unwrap_or_default()
            .contains("not both"),
        "{error}"
    );
    send_json(
        &mut ws,
        serde_json::json!({"type": "settings", "target_psnr": null, "auto_lod": 1.0, "lod_blend": 0.0}),
    )
    .await;
    send_json(
        &mut ws,
        serde_json::json!({"type": "view", "id": 6, "view": view_json(40, 24)}),
    )
    .await;
    // A settings change re-renders the current view (request 5) first; acknowledge frames so
    // flow control lets the next one through.
    let mut answer = next_frame(&mut ws).await;
    for _ in 0..4 {
        send_json(
            &mut ws,
            serde_json::json!({"type": "ack", "frame": answer.0.frame_id}),
        )
        .await;
        if answer.0.request_id == 6 {
            break;
        }
        answer = next_frame(&mut ws).await;
    }
    let (header, image) = answer;
    assert_eq!((header.request_id, header.width), (6, 40));
    assert!(is_png(&image));
    ws.close(None).await.expect("close");

    // The uncalibrated asset refuses goals with a message saying how to get a calibration.
    let (mut ws, _) = tokio_tungstenite::connect_async(format!("ws://{addr}/v1/stream?asset=tiny"))
        .await
        .expect("connect");
    assert_eq!(next_json(&mut ws).await["type"], "hello");
    send_json(
        &mut ws,
        serde_json::json!({"type": "settings", "budget_ms": 100.0}),
    )
    .await;
    let error = next_json(&mut ws).await;
    assert!(
        error["message"]
            .as_str()
            .unwrap_or_default()
            .contains("calibrate=true"),
        "{error}"
    );
    ws.close(None).await.expect("close");
    let _ = stop_tx.send(());
    server.await.expect("join").expect("server");
}

/// Streams `frames` moving views to a new session, acking frame `i` with the receive time
/// `i × spacing_ms` (frames arriving that far apart: 5 s is a link of a few hundred bytes a
/// second for these frames, 1 ms a fast one), and returns each interactive frame's header and
/// size, then the resting frame's header after a `still` view.
async fn stream_with_reported_link(
    addr: std::net::SocketAddr,
    settings: serde_json::Value,
    frames: u32,
    spacing_ms: f64,
) -> (Vec<(FrameHeader, usize)>, FrameHeader) {
    let (mut ws, _) = tokio_tungstenite::connect_async(format!("ws://{addr}/v1/stream?asset=tiny"))
        .await
        .expect("connect");
    assert_eq!(next_json(&mut ws).await["type"], "hello");
    send_json(&mut ws, settings).await;
    let mut interactive = Vec::new();
    for id in 1..=frames {
        let mut view = view_json(256, 256);
        view["eye"][0] = (0.3 + 0.05 * f64::from(id)).into();
        send_json(
            &mut ws,
            serde_json::json!({"type": "view", "id": id, "view": view}),
        )
        .await;
        let (header, image) = next_frame(&mut ws).await;
        assert_eq!((header.request_id, header.quality), (id, 0));
        let received_ms = f64::from(id) * spacing_ms;
        send_json(
            &mut ws,
            serde_json::json!({"type": "ack", "frame": header.frame_id, "received_ms": received_ms}),
        )
        .await;
        interactive.push((header, image.len()));
    }
    send_json(
        &mut ws,
        serde_json::json!({"type": "view", "id": frames + 1, "view": view_json(256, 256), "still": true}),
    )
    .await;
    let (still, _) = next_frame(&mut ws).await;
    assert_eq!((still.request_id, still.quality), (frames + 1, 1));
    ws.close(None).await.expect("close");
    (interactive, still)
}

#[tokio::test(flavor = "multi_thread")]
async fn a_client_reporting_a_slow_link_gets_smaller_frames() {
    let (_dir, state) = setup(None, |_| {}).await;
    let (addr, stop_tx, server) = serve_on_loopback(state).await;
    // No resting frame while the views move: each view is answered by one interactive frame.
    let settings = serde_json::json!({"type": "settings", "rest_ms": 10000, "still_codec": "png"});
    // Frames 1 ms apart (faster than the server sends them: no link limit seen) and 5 s apart
    // (far longer than a render here takes, so the sample is the link's): a few hundred bytes a
    // second, below what even the smallest frame needs at 20 fps.
    let (fast, fast_still) = stream_with_reported_link(addr, settings.clone(), 6, 1.0).await;
    let (slow, slow_still) = stream_with_reported_link(addr, settings, 6, 5000.0).await;
    // The first two frames precede the first bandwidth sample (it needs two receive times).
    for ((f, f_bytes), (s, s_bytes)) in fast.iter().zip(&slow).skip(3) {
        assert_eq!(
            (f.encoded_quality, f.flags),
            (50, 0),
            "fast link: q50, not adapted"
        );
        assert_eq!(
            (s.encoded_quality, s.flags, s.width, s.height),
            (10, 1, 64, 64),
            "slow link: the smallest frame, flagged"
        );
        assert!(s_bytes < f_bytes, "slow {s_bytes} B >= fast {f_bytes} B");
    }
    // The resting frame: PNG as asked on the fast link; 256² PNG in a second at a few hundred B/s
    // cannot arrive in time, so JPEG (still_quality 90), flagged.
    assert_eq!((fast_still.codec, fast_still.flags), (0, 0));
    assert_eq!(
        (
            slow_still.codec,
            slow_still.encoded_quality,
            slow_still.flags
        ),
        (1, 90, 2)
    );

    // `adaptive: false` keeps the settings exactly, and a fixed scale stays under adaptation.
    let fixed = serde_json::json!({"type": "settings", "rest_ms": 10000, "adaptive": false});
    let (off, _) = stream_with_reported_link(addr, fixed, 5, 5000.0).await;
    assert!(
        off.iter()
            .all(|(h, _)| (h.encoded_quality, h.flags) == (50, 0))
    );
    let scaled =
        serde_json::json!({"type": "settings", "rest_ms": 10000, "interactive_scale": 0.5});
    let (kept, _) = stream_with_reported_link(addr, scaled, 5, 5000.0).await;
    let last = &kept[kept.len() - 1].0;
    assert_eq!((last.width, last.encoded_quality, last.flags), (128, 10, 1));
    let _ = stop_tx.send(());
    server.await.expect("join").expect("server");
}

#[tokio::test(flavor = "multi_thread")]
async fn deleting_an_asset_a_stream_shows_frees_it_at_once() {
    let (_dir, state) = setup(None, |_| {}).await;
    let created = send(
        &state,
        upload("/v1/assets?id=shown", None, tiny_asset().to_vec()),
    )
    .await;
    assert_eq!(created.status, StatusCode::CREATED);
    let (addr, stop_tx, server) = serve_on_loopback(state.clone()).await;
    let (mut ws, _) =
        tokio_tungstenite::connect_async(format!("ws://{addr}/v1/stream?asset=shown"))
            .await
            .expect("connect");
    assert_eq!(next_json(&mut ws).await["type"], "hello");
    send_json(
        &mut ws,
        serde_json::json!({"type": "view", "id": 1, "view": view_json(16, 16), "still": true}),
    )
    .await;
    let (frame, _) = next_frame(&mut ws).await;
    assert_eq!(frame.request_id, 1);
    assert_eq!(metric(&state, "lumigraph_gpu_light_fields").await, 2);

    // The open session does not keep the deleted asset on the device.
    let deleted = send(
        &state,
        Request::delete("/v1/assets/shown")
            .body(Body::empty())
            .expect("request"),
    )
    .await;
    assert_eq!(deleted.status, StatusCode::NO_CONTENT);
    assert_eq!(metric(&state, "lumigraph_gpu_light_fields").await, 1);
    assert_eq!(
        metric(&state, "lumigraph_asset_memory_bytes").await,
        TINY_GPU
    );

    // Its next view is answered with an error, then the session closes.
    send_json(
        &mut ws,
        serde_json::json!({"type": "view", "id": 2, "view": view_json(16, 16), "still": true}),
    )
    .await;
    let error = next_json(&mut ws).await;
    assert_eq!(error["kind"], "not_found", "{error}");
    assert_eq!(error["request"], 2);
    assert!(matches!(next_message(&mut ws).await, Message::Close(_)));
    let _ = stop_tx.send(());
    server.await.expect("join").expect("server");
}

/// Starts `run` on a free loopback port; the sender stops it.
async fn serve_on_loopback(
    state: AppState,
) -> (
    std::net::SocketAddr,
    tokio::sync::oneshot::Sender<()>,
    tokio::task::JoinHandle<anyhow::Result<()>>,
) {
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0")
        .await
        .expect("bind");
    let addr = listener.local_addr().expect("addr");
    let (stop_tx, stop_rx) = tokio::sync::oneshot::channel::<()>();
    let server = tokio::spawn(run(listener, state, async move {
        let _ = stop_rx.await;
    }));
    (addr, stop_tx, server)
}

/// A TCP connection to `addr` from the loopback address `from` (any 127.x.y.z works on Linux).
async fn connect_from(from: [u8; 4], addr: std::net::SocketAddr) -> tokio::net::TcpStream {
    let socket = tokio::net::TcpSocket::new_v4().expect("socket");
    socket
        .bind((std::net::Ipv4Addr::from(from), 0).into())
        .expect("bind the client address");
    socket.connect(addr).await.expect("connect")
}

/// Reads until the server closes the connection (or `limit` passes: `None`).
async fn read_to_close(stream: &mut tokio::net::TcpStream, limit: Duration) -> Option<String> {
    use tokio::io::AsyncReadExt as _;
    let mut reply = Vec::new();
    let read = tokio::time::timeout(limit, stream.read_to_end(&mut reply)).await;
    match read {
        Ok(_) => Some(String::from_utf8_lossy(&reply).into_owned()),
        Err(_) => None,
    }
}

#[tokio::test(flavor = "multi_thread")]
async fn slow_clients_are_cut_off_and_cannot_hold_the_render_path() {
    use tokio::io::AsyncWriteExt as _;
    let (_dir, state) = setup(None, |c| {
        c.header_timeout = Duration::from_secs(1);
        c.body_idle_timeout = Duration::from_secs(1);
        c.body_deadline = Duration::from_secs(1);
        c.max_connections_per_client = 4;
    })
    .await;
    let (addr, stop_tx, server) = serve_on_loopback(state).await;
    let body = serde_json::json!({"view": view_json(32, 32)}).to_string();
    let head = format!(
        "POST /v1/assets/tiny/render HTTP/1.1\r\nhost: x\r\ncontent-type: application/json\r\n\
         content-length: {}\r\nconnection: close\r\n\r\n",
        body.len()
    );

    // Four stalled clients of one address: half a request line, headers without a body, and
    // two that trickled one byte of the body.
    let mut stalled = Vec::new();
    for sent in [
        "POST /v1/assets/tiny/render HTTP/1.1\r\nhost: x\r\n".to_owned(),
        head.clone(),
        format!("{head}{{"),
        format!("{head}{{"),
    ] {
        let mut stream = connect_from([127, 0, 0, 1], addr).await;
        stream.write_all(sent.as_bytes()).await.expect("send");
        stalled.push(stream);
    }
    // A fifth connection of that address is refused at once with 429.
    let mut fifth = connect_from([127, 0, 0, 1], addr).await;
    let reply = read_to_close(&mut fifth, Duration::from_secs(5))
        .await
        .expect("the fifth connection is answered");
    assert!(reply.starts_with("HTTP/1.1 429"), "{reply}");
    assert!(reply.contains("at most 4"), "{reply}");
    let json = reply.split_once("\r\n\r\n").map_or("", |(_, body)| body);
    let json: serde_json::Value = serde_json::from_str(json).expect("a JSON error body");
    assert_eq!(json["error"]["kind"], "too_many_connections");
    // Another client renders meanwhile.
    let mut other = connect_from([127, 0, 0, 2], addr).await;
    other
        .write_all(format!("{head}{body}").as_bytes())
        .await
        .expect("send");
    let reply = read_to_close(&mut other, Duration::from_secs(30))
        .await
        .expect("the render is answered");
    assert!(reply.starts_with("HTTP/1.1 200"), "{reply:.300}");
    // The stalled ones are cut off within their deadlines: headers by closing, bodies by 408.
    for (i, stream) in stalled.iter_mut().enumerate() {
        let reply = read_to_close(stream, Duration::from_secs(10))
            .await
            .unwrap_or_else(|| panic!("stalled client {i} was not cut off"));
        if i >= 1 {
            assert!(reply.starts_with("HTTP/1.1 408"), "{i}: {reply}");
        }
    }
    // Their slots are free again.
    let mut again = connect_from([127, 0, 0, 1], addr).await;
    again
        .write_all(format!("{head}{body}").as_bytes())
        .await
        .expect("send");
    let reply = read_to_close(&mut again, Duration::from_secs(30))
        .await
        .expect("answered");
    assert!(reply.starts_with("HTTP/1.1 200"), "{reply:.300}");
    stop_tx.send(()).expect("stop");
    tokio::time::timeout(Duration::from_secs(20), server)
        .await
        .expect("server stops")
        .expect("join")
        .expect("serve");
}

/// The close frame that ends `ws` (within 10 s).
async fn close_code_of(ws: &mut Ws) -> Option<u16> {
    let wait = async {
        while let Some(message) = ws.next().await {
            match message {
                Ok(Message::Close(frame)) => return frame.map(|f| u16::from(f.code)),
                Ok(_) => {}
                Err(e) => panic!("the session broke instead of closing: {e}"),
            }
        }
        panic!("the session ended without a close frame")
    };
    tokio::time::timeout(Duration::from_secs(10), wait)
        .await
        .expect("the session was not closed")
}

#[tokio::test(flavor = "multi_thread")]
async fn idle_and_oversized_stream_sessions_are_closed_with_a_code() {
    let (_dir, state) = setup(None, |c| {
        c.stream_idle_timeout = Duration::from_secs(1);
        c.max_sessions = 2;
    })
    .await;
    let (addr, stop_tx, server) = serve_on_loopback(state).await;
    let url = format!("ws://{addr}/v1/stream?asset=tiny");

    // A silent session is closed with 1008 (policy) once idle, and frees its slot.
    let (mut silent, _) = tokio_tungstenite::connect_async(&url)
        .await
        .expect("connect");
    assert_eq!(next_json(&mut silent).await["type"], "hello");
    assert_eq!(close_code_of(&mut silent).await, Some(1008));

    // A message over 64 KiB is refused with 1009 (too big) before it is read whole, whether it
    // comes as one frame or as fragments.
    for fragmented in [false, true] {
        let (mut big, _) = tokio_tungstenite::connect_async(&url)
            .await
            .expect("connect");
        assert_eq!(next_json(&mut big).await["type"], "hello");
        let text = format!(
            "{{\"type\":\"view\",\"pad\":\"{}\"}}",
            "x".repeat(100 << 10)
        );
        if fragmented {
            use tokio_tungstenite::tungstenite::protocol::frame::Frame;
            use tokio_tungstenite::tungstenite::protocol::frame::coding::{Data, OpCode};
            let bytes = text.into_bytes();
            let (a, b) = bytes.split_at(40 << 10);
            let mut first = Frame::message(a.to_vec(), OpCode::Data(Data::Text), false);
            first.header_mut().is_final = false;
            big.send(Message::Frame(first)).await.expect("send");
            let _ = big
                .send(Message::Frame(Frame::message(
                    b.to_vec(),
                    OpCode::Data(Data::Continue),
                    true,
                )))
                .await;
        } else {
            big.send(Message::text(text)).await.expect("send");
        }
        assert_eq!(close_code_of(&mut big).await, Some(1009), "{fragmented}");
    }

    // A session that keeps talking stays open past the idle time.
    let (mut busy, _) = tokio_tungstenite::connect_async(&url)
        .await
        .expect("connect");
    assert_eq!(next_json(&mut busy).await["type"], "hello");
    for id in 0..4 {
        send_json(&mut busy, serde_json::json!({"type": "ack", "frame": id})).await;
        tokio::time::sleep(Duration::from_millis(400)).await;
    }
    send_json(
        &mut busy,
        serde_json::json!({"type": "view", "id": 7, "view": view_json(16, 16)}),
    )
    .await;
    let (frame, _) = next_frame(&mut busy).await;
    assert_eq!(frame.request_id, 7);
    stop_tx.send(()).expect("stop");
    assert_eq!(close_code_of(&mut busy).await, Some(1001));
    tokio::time::timeout(Duration::from_secs(20), server)
        .await
        .expect("server stops")
        .expect("join")
        .expect("serve");
}

#[tokio::test(flavor = "multi_thread")]
async fn openapi_documents_the_statuses_and_constraints_the_server_enforces() {
    let (_dir, state) = setup(None, |_| {}).await;
    let openapi = get(&state, "/openapi.json").await.json();
    let documented = |path: &str, method: &str, status: StatusCode| {
        openapi["paths"][path][method]["responses"][status.as_str()].is_object()
    };
    // Every status these requests get is in the document.
    let delete = send(
        &state,
        Request::delete("/v1/assets/bad..id")
            .body(Body::empty())
            .expect("request"),
    )
    .await;
    let cases = [
        ("/v1/assets/{id}", "delete", delete.status),
        (
            "/v1/jobs/{id}",
            "get",
            get(&state, "/v1/jobs/bad..id").await.status,
        ),
        ("/v1/stream", "get", get(&state, "/v1/stream").await.status),
        (
            "/v1/stream",
            "get",
            get(&state, "/v1/stream?asset=bad..id").await.status,
        ),
        (
            "/v1/stream",
            "get",
            get(&state, "/v1/stream?bogus=1").await.status,
        ),
        (
            "/v1/assets/{id}",
            "get",
            get(&state, "/v1/assets/bad..id").await.status,
        ),
        (
            "/v1/assets/{id}/render",
            "get",
            get(&state, "/v1/assets/tiny/render?zoom=1").await.status,
        ),
        (
            "/v1/assets/{id}/render",
            "get",
            get(&state, "/v1/assets/ghost/render").await.status,
        ),
    ];
    // A render link's size is bounded like a body's view.
    let link_params = openapi["paths"]["/v1/assets/{id}/render"]["get"]["parameters"]
        .as_array()
        .expect("GET render parameters");
    for side in ["width", "height"] {
        let param = link_params
            .iter()
            .find(|p| p["name"] == side)
            .unwrap_or_else(|| panic!("no {side} parameter"));
        assert_eq!(param["schema"]["maximum"], 512, "{param}");
        assert_eq!(param["required"], true, "{param}");
    }
    assert!(documented(
        "/v1/assets/{id}/render",
        "get",
        StatusCode::NOT_MODIFIED
    ));
    for (path, method, status) in cases {
        assert!(status.is_client_error(), "{path} {method}: {status}");
        assert!(
            documented(path, method, status),
            "{method} {path} answers {status}, which the OpenAPI document leaves out"
        );
    }
    for (path, method) in [
        ("/v1/assets/{id}/render", "post"),
        ("/v1/assets", "post"),
        ("/v1/bake", "post"),
    ] {
        assert!(
            documented(path, method, StatusCode::REQUEST_TIMEOUT),
            "{path}"
        );
    }
    // The id pattern on every id parameter, the view's vector lengths and minimum sizes.
    for (path, method) in [
        ("/v1/assets/{id}", "get"),
        ("/v1/assets/{id}", "delete"),
        ("/v1/assets/{id}/render", "post"),
        ("/v1/jobs/{id}", "get"),
        ("/v1/stream", "get"),
        ("/v1/assets", "post"),
    ] {
        let params = openapi["paths"][path][method]["parameters"]
            .as_array()
            .unwrap_or_else(|| panic!("{method} {path} has no parameters"));
        for param in params {
            assert_eq!(
                param["schema"]["pattern"], "^[A-Za-z0-9][A-Za-z0-9_-]{0,63}$",
                "{method} {path}: {param}"
            );
            assert_eq!(param["schema"]["maxLength"], 64, "{method} {path}");
        }
    }
    let view = &openapi["components"]["schemas"]["ViewSchema"]["properties"];
    for field in ["eye", "target"] {
        assert_eq!(view[field]["minItems"], 3, "{field}: {}", view[field]);
        assert_eq!(view[field]["maxItems"], 3, "{field}");
    }
    for field in ["width", "height"] {
        assert_eq!(view[field]["minimum"], 1, "{field}: {}", view[field]);
    }
}

#[tokio::test(flavor = "multi_thread")]
async fn websocket_stream_sends_depth_on_request() {
    use lumigraph_server::service::stream::{
        DEPTH_EXTENSION_LEN, FRAME_HEADER_LEN, FrameHeader, decode_depth, parse_frame,
    };
    let (_dir, state) = setup(None, |_| {}).await;
    let (addr, stop_tx, server) = serve_on_loopback(state.clone()).await;
    let (mut ws, _) = tokio_tungstenite::connect_async(format!("ws://{addr}/v1/stream?asset=tiny"))
        .await
        .expect("connect");
    let hello = next_json(&mut ws).await;
    assert_eq!(hello["settings"]["depth"], false);
    let next_binary = |message: Message| match message {
        Message::Binary(bytes) => bytes.to_vec(),
        other => panic!("expected a frame, got {other:?}"),
    };

    // Off by default: the 40-byte header, no flags (a PNG still on a fast link, so quality 0),
    // the colour image alone.
    send_json(
        &mut ws,
        serde_json::json!({"type": "settings", "interactive": false, "still_codec": "png"}),
    )
    .await;
    let view = view_json(40, 24);
    send_json(
        &mut ws,
        serde_json::json!({"type": "view", "id": 1, "view": view}),
    )
    .await;
    let plain = next_binary(next_message(&mut ws).await);
    let parsed = parse_frame(&plain).expect("frame");
    assert_eq!(u16::from_le_bytes([plain[4], plain[5]]), 40);
    assert_eq!((plain[38], plain[39]), (0, 0));
    assert!(parsed.header.depth.is_none() && parsed.depth.is_none());
    assert_eq!(parsed.color, &plain[FRAME_HEADER_LEN..]);
    send_json(&mut ws, serde_json::json!({"type": "ack", "frame": 1})).await;

    // On: the extension carries the view, and the depth decodes to the renderer's depth within
    // half a quantisation step (`(far - near) / 65534`, plus f32 rounding of the dequantisation).
    send_json(
        &mut ws,
        serde_json::json!({"type": "settings", "depth": true}),
    )
    .await;
    let with_depth = next_binary(next_message(&mut ws).await);
    let parsed = parse_frame(&with_depth).expect("frame with depth");
    assert_eq!(
        usize::from(u16::from_le_bytes([with_depth[4], with_depth[5]])),
        FRAME_HEADER_LEN + DEPTH_EXTENSION_LEN
    );
    // Byte 39's depth bit says so; the parsed flags leave it out.
    assert_eq!(with_depth[39], FrameHeader::DEPTH);
    assert_eq!(parsed.header.flags, 0);
    let extension = parsed.header.depth.expect("the depth extension");
    assert_eq!(extension.eye, [0.3, 0.5, 3.0]);
    assert_eq!(extension.target, [0.0; 3]);
    assert_eq!(extension.up, [0.0, 1.0, 0.0]);
    assert!((extension.yfov_deg - 40.0).abs() < f32::EPSILON);
    let (w, h, _) = lumigraph_core::image_io::decode_png_rgba8(parsed.color).expect("png");
    assert_eq!((w, h), (40, 24));
    let depth = decode_depth(parsed.depth.expect("depth image"), &extension, w, h).expect("depth");
    let npy = render(
        &state,
        &serde_json::json!({"view": view, "format": "none", "depth": "npy"}),
    )
    .await;
    assert_eq!(npy.status, StatusCode::OK);
    let (_, _, truth) = lumigraph_core::image_io::decode_depth_npy(&npy.body).expect("npy");
    let finite: Vec<f32> = truth.iter().copied().filter(|d| d.is_finite()).collect();
    assert!(!finite.is_empty(), "the view sees the object");
    let near = finite.iter().copied().fold(f32::INFINITY, f32::min);
    let far = finite.iter().copied().fold(f32::NEG_INFINITY, f32::max);
    assert_eq!((extension.near, extension.far), (near, far));
    let bound = 0.5 * (far - near) / 65534.0 + 4.0 * f32::EPSILON * far;
    for (got, want) in depth.iter().zip(&truth) {
        if want.is_finite() {
            assert!(
                (got - want).abs() <= bound,
                "{got} vs {want} (bound {bound})"
            );
        } else {
            assert!(got.is_infinite(), "{got} where nothing is hit");
        }
    }
    let _ = stop_tx.send(());
    let _ = server.await;
}

/// A small volume light field: a soft ball (value 100 at the centre, falling to 0 at radius 6
/// voxels) through a TF with a faint halo and an opaque core, 12 cameras × 32 px.
fn volume_asset() -> Vec<u8> {
    volume_asset_with(None)
}

/// The ball as a two-layer multi light field: its halo and its core through separate TFs.
fn layered_volume_asset() -> Vec<u8> {
    use lumigraph_core::volume::layers::VolumeLayer;
    use lumigraph_core::volume::tf::TransferFunction;
    let layer = |name: &str, tf: &str, opacity: f32| VolumeLayer {
        name: name.to_owned(),
        tf: TransferFunction::from_json(tf).expect("tf"),
        opacity,
        segment: None,
    };
    volume_asset_with(Some(vec![
        layer(
            "halo",
            r#"{"points": [[0, 0, 0, 0, 0], [5, 0.2, 0.5, 1, 0.1], [40, 0.2, 0.5, 1, 0.1], [50, 0, 0, 0, 0]]}"#,
            1.0,
        ),
        layer(
            "core",
            r#"{"points": [[0, 0, 0, 0, 0], [50, 0, 0, 0, 0], [60, 1, 0.6, 0.2, 1]]}"#,
            1.0,
        ),
    ]))
}

fn volume_asset_with(layers: Option<Vec<lumigraph_core::volume::layers::VolumeLayer>>) -> Vec<u8> {
    use lumigraph_core::volume::bake::{VolumeBakeOptions, VolumeBaker};
    use lumigraph_core::volume::tf::TransferFunction;
    use lumigraph_core::volume::{Volume, Voxels};
    let n = 16usize;
    let c = (n as f32 - 1.0) / 2.0;
    let mut values = Vec::with_capacity(n * n * n);
    for k in 0..n {
        for j in 0..n {
            for i in 0..n {
                let d = ((i as f32 - c).powi(2) + (j as f32 - c).powi(2) + (k as f32 - c).powi(2))
                    .sqrt();
                values.push((100.0 * (1.0 - d / 6.0)).max(0.0));
            }
        }
    }
    // Spacing 2/15 puts the ball (radius 0.8) around the origin like the tiny asset.
    let s = 2.0 / 15.0;
    let volume = Volume::from_values(
        [16, 16, 16],
        Voxels::Scalar(values),
        [[s, 0.0, 0.0], [0.0, s, 0.0], [0.0, 0.0, s]],
        [-1.0, -1.0, -1.0],
    )
    .expect("volume");
    let tf = TransferFunction::from_json(
        r#"{"points": [[0, 0, 0, 0, 0], [5, 0.2, 0.5, 1, 0.1], [40, 0.2, 0.5, 1, 0.1], [60, 1, 0.6, 0.2, 1]]}"#,
    )
    .expect("tf");
    let options = VolumeBakeOptions {
        cameras: 12,
        resolution: 32,
        ..VolumeBakeOptions::default()
    };
    let layers =
        layers.unwrap_or_else(|| vec![lumigraph_core::volume::layers::VolumeLayer::single(&tf)]);
    VolumeBaker::new(gpu())
        .bake_layers_to_bytes(
            &volume,
            &layers,
            &options,
            &lumigraph_core::asset::Provenance::default(),
            &mut |_, _| {},
        )
        .expect("volume bake")
        .0
}

/// A multi light field over HTTP: `layers` in the render body and the query string changes
/// the frame (the core hidden leaves only the halo), the summary lists the layers with their
/// opacities, and an unknown layer or a bad opacity is a 400 naming it.
#[tokio::test(flavor = "multi_thread")]
async fn layered_volumes_take_runtime_opacities_over_http() {
    let (dir, state) = setup(None, |_| {}).await;
    std::fs::write(dir.path().join("layers.lfa"), layered_volume_asset()).expect("write");
    state.load_assets().await.expect("loading assets");
    let summary = get(&state, "/v1/assets/layers").await;
    let summary: serde_json::Value = serde_json::from_slice(&summary.body).expect("json");
    assert_eq!(summary["layers"], serde_json::json!(["halo", "core"]));
    assert_eq!(summary["layer_opacities"], serde_json::json!([1.0, 1.0]));
    let uri = "/v1/assets/layers/render";
    let centre_alpha = |body: &[u8]| {
        let (w, h, rgba) = lumigraph_core::image_io::decode_png_rgba8(body).expect("png");
        rgba[4 * ((h as usize / 2) * w as usize + w as usize / 2) + 3]
    };
    let full = post_json(
        &state,
        uri,
        serde_json::json!({"view": view_json(48, 48)}).to_string(),
    )
    .await;
    assert_eq!(
        full.status,
        StatusCode::OK,
        "{}",
        String::from_utf8_lossy(&full.body)
    );
    let hidden = post_json(
        &state,
        uri,
        serde_json::json!({"view": view_json(48, 48), "layers": {"core": 0}}).to_string(),
    )
    .await;
    assert_eq!(
        hidden.status,
        StatusCode::OK,
        "{}",
        String::from_utf8_lossy(&hidden.body)
    );
    let (a_full, a_hidden) = (centre_alpha(&full.body), centre_alpha(&hidden.body));
    assert!(a_full >= 250, "the core is opaque: {a_full}");
    assert!(
        a_hidden < 200,
        "without the core only the halo is left: {a_hidden}"
    );
    // The query string's `name:opacity` form gives the same frame as the body.
    let query = get(
        &state,
        "/v1/assets/layers/render?eye=0,0,3&target=0,0,0&yfov_deg=40&width=48&height=48&layers=core:0&format=png",
    )
    .await;
    assert_eq!(
        query.status,
        StatusCode::OK,
        "{}",
        String::from_utf8_lossy(&query.body)
    );
    for (body, needle) in [
        (
            serde_json::json!({"view": view_json(48, 48), "layers": {"skin": 1}}),
            "no layer",
        ),
        (
            serde_json::json!({"view": view_json(48, 48), "layers": {"core": 1.5}}),
            "[0, 1]",
        ),
        (
            serde_json::json!({"view": view_json(48, 48), "layers": "core"}),
            "NAME=OPACITY",
        ),
    ] {
        let reply = post_json(&state, uri, body.to_string()).await;
        let text = String::from_utf8_lossy(&reply.body);
        assert_eq!(reply.status, StatusCode::UNPROCESSABLE_ENTITY, "{text}");
        assert!(text.contains(needle), "{needle}: {text}");
    }
}

/// Depth layers over HTTP: the ball's rays split where their opacity reaches 0.3 (format
/// version 3, `layer_order: "ray"` in the header the service reports); at full opacity the
/// centre is opaque, and with the back segment hidden only the front one is left.
#[tokio::test(flavor = "multi_thread")]
async fn depth_layered_volumes_take_runtime_opacities_over_http() {
    use lumigraph_core::volume::layers::VolumeLayer;
    let (dir, state) = setup(None, |_| {}).await;
    let layers = VolumeLayer::parse(
        r#"{"tf": {"points": [[0, 0, 0, 0, 0], [5, 0.2, 0.5, 1, 0.1], [40, 0.2, 0.5, 1, 0.1], [60, 1, 0.6, 0.2, 1]]},
            "split": {"opacity": [0.3]}, "layers": [{"name": "front"}, {"name": "back"}]}"#,
        std::path::Path::new("."),
    )
    .expect("depth layers");
    std::fs::write(
        dir.path().join("split.lfa"),
        volume_asset_with(Some(layers)),
    )
    .expect("write");
    state.load_assets().await.expect("loading assets");
    let detail = get(&state, "/v1/assets/split").await;
    let detail: serde_json::Value = serde_json::from_slice(&detail.body).expect("json");
    assert_eq!(detail["layers"], serde_json::json!(["front", "back"]));
    assert_eq!(detail["header"]["format_version"], 3);
    assert_eq!(detail["header"]["layer_order"], "ray");
    let centre_alpha = |body: &[u8]| {
        let (w, h, rgba) = lumigraph_core::image_io::decode_png_rgba8(body).expect("png");
        rgba[4 * ((h as usize / 2) * w as usize + w as usize / 2) + 3]
    };
    let mut alphas = Vec::new();
    let mut front_only = Vec::new();
    for layers in [serde_json::json!({}), serde_json::json!({"back": 0})] {
        let reply = post_json(
            &state,
            "/v1/assets/split/render",
            serde_json::json!({"view": view_json(48, 48), "layers": layers}).to_string(),
        )
        .await;
        assert_eq!(
            reply.status,
            StatusCode::OK,
            "{}",
            String::from_utf8_lossy(&reply.body)
        );
        alphas.push(centre_alpha(&reply.body));
        front_only = reply.body;
    }
    assert!(alphas[0] >= 250, "the whole ray is opaque: {alphas:?}");
    assert!(
        alphas[1] < 200,
        "the front segment alone is not: {alphas:?}"
    );
    // The stream's `layers` setting gives the same lossless frame.
    let streamed = one_png_frame_streamed(
        state,
        "split",
        Some(serde_json::json!({"type": "settings", "layers": {"back": 0}})),
    )
    .await;
    let decode = |png: &[u8]| {
        lumigraph_core::image_io::decode_png_rgba8(png)
            .expect("png")
            .2
    };
    assert_eq!(
        decode(&streamed),
        decode(&front_only),
        "the stream's frame with the back hidden is the HTTP one"
    );
}

/// Serves `state` on loopback, opens a stream of `asset`, asks for lossless still frames (and
/// sends `settings`, if any), requests one 48² view and returns its PNG.
async fn one_png_frame_streamed(
    state: AppState,
    asset: &str,
    settings: Option<serde_json::Value>,
) -> Vec<u8> {
    let (addr, stop_tx, server) = serve_on_loopback(state).await;
    let (mut ws, _) =
        tokio_tungstenite::connect_async(format!("ws://{addr}/v1/stream?asset={asset}"))
            .await
            .expect("connect");
    let hello = next_json(&mut ws).await;
    assert_eq!(hello["asset"]["id"], asset);
    send_json(
        &mut ws,
        serde_json::json!({"type": "settings", "interactive": false, "still_codec": "png"}),
    )
    .await;
    if let Some(settings) = settings {
        send_json(&mut ws, settings).await;
    }
    send_json(
        &mut ws,
        serde_json::json!({"type": "view", "id": 1, "view": view_json(48, 48)}),
    )
    .await;
    let (header, image) = next_frame(&mut ws).await;
    assert_eq!(header.request_id, 1);
    drop(ws);
    let _ = stop_tx.send(());
    let _ = server.await;
    image
}

/// A volume light field through the service: PNG frames carry the haze's partial alpha, an
/// opaque background composites it (JPEG and PNG alike), depth is reported only where the
/// opacity reached τ_d, and the stream serves it too.
#[tokio::test(flavor = "multi_thread")]
async fn volume_light_fields_render_with_alpha_over_http_and_the_stream() {
    let (dir, state) = setup(None, |_| {}).await;
    std::fs::write(dir.path().join("ball.lfa"), volume_asset()).expect("write");
    state.load_assets().await.expect("loading assets");
    let uri = "/v1/assets/ball/render";
    let png = post_json(
        &state,
        uri,
        serde_json::json!({"view": view_json(48, 48)}).to_string(),
    )
    .await;
    assert_eq!(
        png.status,
        StatusCode::OK,
        "{}",
        String::from_utf8_lossy(&png.body)
    );
    let (_, _, rgba) = lumigraph_core::image_io::decode_png_rgba8(&png.body).expect("png");
    let alphas: Vec<u8> = rgba.chunks_exact(4).map(|p| p[3]).collect();
    assert!(
        alphas.iter().any(|&a| a > 0 && a < 128),
        "the halo is partly transparent"
    );
    assert!(alphas.iter().any(|&a| a >= 250), "the core is opaque");
    assert!(alphas.contains(&0), "the corners are empty");
    // Over an opaque white background every pixel is opaque, and a hazy pixel is lighter than
    // its straight colour (white shows through).
    let white = post_json(
        &state,
        uri,
        serde_json::json!({"view": view_json(48, 48), "background": [255, 255, 255, 255]})
            .to_string(),
    )
    .await;
    let (_, _, over) = lumigraph_core::image_io::decode_png_rgba8(&white.body).expect("png");
    assert!(over.chunks_exact(4).all(|p| p[3] == 255));
    let hazy = alphas
        .iter()
        .position(|&a| a > 10 && a < 100)
        .expect("a hazy pixel");
    assert!(
        over[4 * hazy] > rgba[4 * hazy] && over[4 * hazy + 2] >= rgba[4 * hazy + 2],
        "{:?} over white is {:?}",
        &rgba[4 * hazy..4 * hazy + 4],
        &over[4 * hazy..4 * hazy + 4]
    );
    let npy = post_json(
        &state,
        uri,
        serde_json::json!({"view": view_json(48, 48), "format": "none", "depth": "npy"})
            .to_string(),
    )
    .await;
    let (_, _, depth) = lumigraph_core::image_io::decode_depth_npy(&npy.body).expect("npy");
    for (a, z) in alphas.iter().zip(&depth) {
        assert_eq!(z.is_finite(), *a >= 128, "alpha {a}, depth {z}");
    }
    let jpeg = post_json(
        &state,
        uri,
        serde_json::json!({"view": view_json(48, 48), "format": "jpeg", "background": [0, 0, 0, 255]})
            .to_string(),
    )
    .await;
    assert_eq!(jpeg.status, StatusCode::OK);
    assert!(jpeg.body.starts_with(&[0xff, 0xd8]));

    let image = one_png_frame_streamed(state, "ball", None).await;
    let (_, _, streamed) = lumigraph_core::image_io::decode_png_rgba8(&image).expect("png");
    assert_eq!(
        streamed, rgba,
        "the stream's lossless frame is the HTTP frame"
    );
}

/// `POST /v1/bake` takes the shading's `shadows` (DESIGN §9) in `options` like the rest of the
/// shading; the asset records it (so `eval` and `**lf.shading` shade the reference alike), and a
/// value that is not a boolean is a `422` before any job exists.
#[tokio::test(flavor = "multi_thread")]
async fn a_bake_takes_shadows_in_its_shading() {
    let (_dir, state) = setup(None, |_| {}).await;
    let obj = icosahedron_obj();
    let bad = post_bake(
        &state,
        None,
        &[
            ("mesh", Some("ico.obj"), obj.as_bytes()),
            (
                "options",
                None,
                br#"{"cameras": 12, "resolution": 16, "shading": {"shadows": "yes"}}"#,
            ),
        ],
    )
    .await;
    assert_eq!(bad.status, StatusCode::UNPROCESSABLE_ENTITY);
    let accepted = post_bake(
        &state,
        None,
        &[
            ("mesh", Some("ico.obj"), obj.as_bytes()),
            (
                "options",
                None,
                br#"{"cameras": 12, "resolution": 16, "shading": {"shadows": true}}"#,
            ),
            ("calibrate", None, b"false"),
            ("id", None, b"shadowed"),
        ],
    )
    .await;
    assert_eq!(accepted.status, StatusCode::ACCEPTED);
    let status = finished_job(&state, accepted.header("location")).await;
    assert_eq!(status["state"], "done", "{status}");
    let asset = get(&state, "/v1/assets/shadowed").await.json();
    assert_eq!(
        asset["header"]["provenance"]["bake_options"]["shading"]["shadows"],
        serde_json::Value::Bool(true),
        "{asset}"
    );
}

/// Light states through the service: `POST /v1/bake` takes `lights`, the render body and the
/// render link take `light` (world direction), the stream takes it as a sticky setting, and a
/// bad light or an asset without light states is a `422` naming the problem.
#[tokio::test(flavor = "multi_thread")]
async fn light_states_bake_and_relight_over_http_and_the_stream() {
    let (_dir, state) = setup(None, |_| {}).await;
    let obj = icosahedron_obj();
    let accepted = post_bake(
        &state,
        None,
        &[
            ("mesh", Some("ico.obj"), obj.as_bytes()),
            (
                "options",
                None,
                br#"{"cameras": 12, "resolution": 16, "lights": 12}"#,
            ),
            ("calibrate", None, b"false"),
            ("id", None, b"lit"),
        ],
    )
    .await;
    assert_eq!(accepted.status, StatusCode::ACCEPTED);
    let status = finished_job(&state, accepted.header("location")).await;
    assert_eq!(status["state"], "done", "{status}");
    let asset = get(&state, "/v1/assets/lit").await.json();
    assert_eq!(
        asset["states"].as_array().map(Vec::len),
        Some(15),
        "{asset}"
    );
    let render = |light: serde_json::Value| {
        let state = state.clone();
        async move {
            post_json(
                &state,
                "/v1/assets/lit/render",
                serde_json::json!({"view": view_json(32, 32), "light": light}).to_string(),
            )
            .await
        }
    };
    let above = render(serde_json::json!([0, 1, 0])).await;
    let below = render(serde_json::json!([0, -1, 0.2])).await;
    assert_eq!(
        above.status,
        StatusCode::OK,
        "{}",
        String::from_utf8_lossy(&above.body)
    );
    assert_eq!(below.status, StatusCode::OK);
    assert_ne!(above.body, below.body, "the light moved the shading");
    let link = get(&state, "/v1/assets/lit/render?eye=0.3,0.5,3&target=0,0,0&up=0,1,0&yfov_deg=40&width=32&height=32&light=0,1,0").await;
    assert_eq!(
        link.status,
        StatusCode::OK,
        "{}",
        String::from_utf8_lossy(&link.body)
    );
    for bad in [serde_json::json!([0, 0, 0]), serde_json::json!([1, 2])] {
        let reply = render(bad.clone()).await;
        assert_eq!(reply.status, StatusCode::UNPROCESSABLE_ENTITY, "{bad}");
    }
    let streamed = one_png_frame_streamed(
        state.clone(),
        "lit",
        Some(serde_json::json!({"type": "settings", "light": [0, 1, 0]})),
    )
    .await;
    let (_, _, rgba) = lumigraph_core::image_io::decode_png_rgba8(&streamed).expect("png");
    let (_, _, http) = lumigraph_core::image_io::decode_png_rgba8(
        &post_json(
            &state,
            "/v1/assets/lit/render",
            serde_json::json!({"view": view_json(48, 48), "light": [0, 1, 0]}).to_string(),
        )
        .await
        .body,
    )
    .expect("png");
    assert_eq!(rgba, http, "the stream relights as the render body does");
    // An asset baked without light states.
    let plain = post_bake(
        &state,
        None,
        &[
            ("mesh", Some("ico.obj"), obj.as_bytes()),
            ("options", None, br#"{"cameras": 12, "resolution": 16}"#),
            ("calibrate", None, b"false"),
            ("id", None, b"plain"),
        ],
    )
    .await;
    let status = finished_job(&state, plain.header("location")).await;
    assert_eq!(status["state"], "done", "{status}");
    let reply = post_json(
        &state,
        "/v1/assets/plain/render",
        serde_json::json!({"view": view_json(32, 32), "light": [0, 1, 0]}).to_string(),
    )
    .await;
    assert_eq!(reply.status, StatusCode::UNPROCESSABLE_ENTITY);
    assert!(
        String::from_utf8_lossy(&reply.body).contains("no light states"),
        "{}",
        String::from_utf8_lossy(&reply.body)
    );
}

/// A ground quad (±2) with a 0.5 box on it at x ∈ [box_x, box_x + 0.5].
fn yard_mesh(box_x: f32) -> lumigraph_core::mesh::Mesh {
    let mut v: Vec<[f32; 3]> = vec![
        [-2.0, 0.0, -2.0],
        [-2.0, 0.0, 2.0],
        [2.0, 0.0, 2.0],
        [2.0, 0.0, -2.0],
    ];
    let mut f: Vec<[u32; 3]> = vec![[0, 1, 2], [0, 2, 3]];
    let (lo, hi) = ([box_x, 0.0, -0.25], [box_x + 0.5, 0.5, 0.25]);
    for i in 0..8u32 {
        v.push(std::array::from_fn(|a| {
            if i & (1 << a) == 0 { lo[a] } else { hi[a] }
        }));
    }
    for q in [
        [0, 2, 3, 1],
        [4, 5, 7, 6],
        [0, 1, 5, 4],
        [2, 6, 7, 3],
        [0, 4, 6, 2],
        [1, 3, 7, 5],
    ] {
        f.push([4 + q[0], 4 + q[1], 4 + q[2]]);
        f.push([4 + q[0], 4 + q[2], 4 + q[3]]);
    }
    lumigraph_core::mesh::Mesh::from_arrays(v, f, None).expect("yard")
}

/// A deformation state through the service: the summary lists it, the render body and the
/// render link take `state`, the stream's `state` setting renders the same frame, and an
/// unknown state is a 422 naming the asset's states.
#[tokio::test(flavor = "multi_thread")]
async fn deformation_states_render_by_name_over_http_and_the_stream() {
    use lumigraph_core::bake::{BakeOptions, Baker, StateBake};
    use lumigraph_core::deform::StateMesh;
    let (dir, state) = setup(None, |_| {}).await;
    let (base, moved) = (yard_mesh(-0.8), yard_mesh(0.6));
    let baker = Baker::new(lumigraph_core::gpu::Gpu::shared().expect("gpu"));
    let bytes = baker
        .bake_states_to_bytes(
            &base,
            &StateBake {
                meshes: &[StateMesh {
                    name: "moved",
                    mesh: &moved,
                    source_name: "moved",
                    source_sha256: "",
                    params: None,
                }],
                ..StateBake::default()
            },
            &BakeOptions {
                cameras: 12,
                resolution: 32,
                ..BakeOptions::default()
            },
            &lumigraph_core::asset::Provenance::default(),
            &mut |_, _| {},
        )
        .expect("bake");
    std::fs::write(dir.path().join("yard.lfa"), bytes).expect("write");
    state.load_assets().await.expect("loading assets");
    let summary = get(&state, "/v1/assets/yard").await.json();
    assert_eq!(
        summary["deformations"],
        serde_json::json!(["moved"]),
        "{summary}"
    );
    let render = |body: serde_json::Value| {
        let state = state.clone();
        async move { post_json(&state, "/v1/assets/yard/render", body.to_string()).await }
    };
    let plain = render(serde_json::json!({"view": view_json(48, 48)})).await;
    let moved_reply =
        render(serde_json::json!({"view": view_json(48, 48), "state": "moved"})).await;
    assert_eq!(
        moved_reply.status,
        StatusCode::OK,
        "{}",
        String::from_utf8_lossy(&moved_reply.body)
    );
    assert_ne!(plain.body, moved_reply.body, "the state moved the box");
    let named_base = render(serde_json::json!({"view": view_json(48, 48), "state": "base"})).await;
    assert_eq!(named_base.body, plain.body);
    let link = get(&state, "/v1/assets/yard/render?eye=0.3,0.5,3&target=0,0,0&up=0,1,0&yfov_deg=40&width=48&height=48&state=moved").await;
    assert_eq!(link.status, StatusCode::OK);
    assert_eq!(
        lumigraph_core::image_io::decode_png_rgba8(&link.body).expect("png"),
        lumigraph_core::image_io::decode_png_rgba8(&moved_reply.body).expect("png")
    );
    let unknown = render(serde_json::json!({"view": view_json(48, 48), "state": "dent"})).await;
    assert_eq!(unknown.status, StatusCode::UNPROCESSABLE_ENTITY);
    let text = String::from_utf8_lossy(&unknown.body);
    assert!(
        text.contains("unknown state") && text.contains("base, moved"),
        "{text}"
    );
    let streamed = one_png_frame_streamed(
        state.clone(),
        "yard",
        Some(serde_json::json!({"type": "settings", "state": "moved"})),
    )
    .await;
    assert_eq!(
        lumigraph_core::image_io::decode_png_rgba8(&streamed).expect("png"),
        lumigraph_core::image_io::decode_png_rgba8(&moved_reply.body).expect("png"),
        "the stream renders the state as the render body does"
    );
}

/// A two-frame animation (the yard's box sliding, 2 fps): frame 0 the base state.
fn slide_asset() -> Vec<u8> {
    use lumigraph_core::bake::{BakeOptions, Baker, StateBake};
    use lumigraph_core::deform::{StateMesh, animation_params};
    let frames = [yard_mesh(-0.8), yard_mesh(0.6)];
    let params: Vec<_> = (0..2)
        .map(|i| animation_params("slide", i, 2.0, 0.5))
        .collect();
    let baker = Baker::new(lumigraph_core::gpu::Gpu::shared().expect("gpu"));
    baker
        .bake_states_to_bytes(
            &frames[0],
            &StateBake {
                meshes: &[StateMesh {
                    name: "frame_001",
                    mesh: &frames[1],
                    source_name: "",
                    source_sha256: "",
                    params: Some(&params[1]),
                }],
                frame: Some(lumigraph_core::deform::frame_around(&frames)),
                base_params: Some(&params[0]),
                ..StateBake::default()
            },
            &BakeOptions {
                cameras: 12,
                resolution: 32,
                ..BakeOptions::default()
            },
            &lumigraph_core::asset::Provenance::default(),
            &mut |_, _| {},
        )
        .expect("bake")
}

/// An animation through the service: `time` and `frame` in the render body and the link pick
/// the frame, a time outside the animation is a 422.
#[tokio::test(flavor = "multi_thread")]
async fn animation_frames_render_by_time_and_frame_over_http() {
    let (dir, state) = setup(None, |_| {}).await;
    let bytes = slide_asset();
    std::fs::write(dir.path().join("slide.lfa"), bytes).expect("write");
    state.load_assets().await.expect("loading assets");
    let render = |extra: serde_json::Value| {
        let state = state.clone();
        async move {
            let mut body = serde_json::json!({"view": view_json(48, 48)});
            if let (Some(b), Some(e)) = (body.as_object_mut(), extra.as_object()) {
                b.extend(e.clone());
            }
            post_json(&state, "/v1/assets/slide/render", body.to_string()).await
        }
    };
    let first = render(serde_json::json!({"time": 0.2})).await;
    let second = render(serde_json::json!({"time": 0.5})).await;
    let by_frame = render(serde_json::json!({"frame": 1})).await;
    let by_name = render(serde_json::json!({"state": "frame_001"})).await;
    let plain = render(serde_json::json!({})).await;
    assert_eq!(
        second.status,
        StatusCode::OK,
        "{}",
        String::from_utf8_lossy(&second.body)
    );
    assert_eq!(first.body, plain.body, "0.2 s shows frame 0");
    assert_ne!(first.body, second.body, "the box slid");
    assert_eq!(second.body, by_frame.body);
    assert_eq!(second.body, by_name.body);
    let link = get(&state, "/v1/assets/slide/render?eye=0.3,0.5,3&target=0,0,0&up=0,1,0&yfov_deg=40&width=48&height=48&frame=1").await;
    assert_eq!(link.status, StatusCode::OK);
    assert_eq!(
        lumigraph_core::image_io::decode_png_rgba8(&link.body).expect("png"),
        lumigraph_core::image_io::decode_png_rgba8(&second.body).expect("png")
    );
    for bad in [
        serde_json::json!({"time": 3.0}),
        serde_json::json!({"frame": 2}),
        serde_json::json!({"time": 0.1, "frame": 0}),
    ] {
        let reply = render(bad.clone()).await;
        assert_eq!(reply.status, StatusCode::UNPROCESSABLE_ENTITY, "{bad}");
    }
}

/// The stream plays an animation on the server's clock: with `playing`, frames keep coming for
/// one resting view, their headers stamped with the frame they show, both frames of the slide
/// in turn; an asset without an animation refuses `playing`.
#[tokio::test(flavor = "multi_thread")]
async fn the_stream_plays_an_animation_and_stamps_each_frame() {
    let (dir, state) = setup(None, |_| {}).await;
    std::fs::write(dir.path().join("slide.lfa"), slide_asset()).expect("write");
    state.load_assets().await.expect("loading assets");
    let (addr, stop_tx, server) = serve_on_loopback(state).await;
    let (mut ws, _) =
        tokio_tungstenite::connect_async(format!("ws://{addr}/v1/stream?asset=slide"))
            .await
            .expect("connect");
    let hello = next_json(&mut ws).await;
    assert_eq!(hello["asset"]["animation"]["frames"], 2, "{hello}");
    send_json(
        &mut ws,
        serde_json::json!({"type": "settings", "interactive": false, "still_codec": "png", "rest_ms": 0, "playing": true}),
    )
    .await;
    send_json(
        &mut ws,
        serde_json::json!({"type": "view", "id": 1, "view": view_json(32, 32)}),
    )
    .await;
    // At 2 fps the frames change every 0.5 s: 2.2 s shows both several times.
    let mut images: std::collections::HashMap<u32, Vec<u8>> = std::collections::HashMap::new();
    let mut shown = Vec::new();
    let start = std::time::Instant::now();
    while start.elapsed() < Duration::from_millis(2200) {
        let (header, image) = next_frame(&mut ws).await;
        send_json(
            &mut ws,
            serde_json::json!({"type": "ack", "frame": header.frame_id}),
        )
        .await;
        let (frame, time) = header.animation.expect("an animation stamp");
        assert!((time - frame as f32 * 0.5).abs() < 1e-6, "{frame} {time}");
        assert_eq!(header.request_id, 1, "frames of the one resting view");
        let (_, _, rgba) = lumigraph_core::image_io::decode_png_rgba8(&image).expect("png");
        if let Some(seen) = images.get(&frame) {
            assert_eq!(seen, &rgba, "frame {frame} looks the same each time");
        }
        images.insert(frame, rgba);
        shown.push(frame);
    }
    assert!(shown.contains(&0) && shown.contains(&1), "{shown:?}");
    assert!(shown.len() >= 4, "frames keep coming: {shown:?}");
    assert_ne!(images[&0], images[&1], "the box slid");
    // Pausing shows the frame `frame` names.
    send_json(
        &mut ws,
        serde_json::json!({"type": "settings", "playing": false, "frame": 1}),
    )
    .await;
    let mut last = None;
    for _ in 0..8 {
        let (header, _) = next_frame(&mut ws).await;
        send_json(
            &mut ws,
            serde_json::json!({"type": "ack", "frame": header.frame_id}),
        )
        .await;
        last = header.animation;
        if last.map(|(f, _)| f) == Some(1) {
            break;
        }
    }
    assert_eq!(last.map(|(f, _)| f), Some(1));
    drop(ws);
    let _ = stop_tx.send(());
    let _ = server.await;
}
