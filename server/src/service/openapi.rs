//! The OpenAPI document at `/openapi.json`, generated from the handlers' annotations.

use axum::Json;
use utoipa::openapi::security::{Http, HttpAuthScheme, SecurityScheme};
use utoipa::{Modify, OpenApi};

use super::{http, stream};

/// A view (DESIGN §3), documented here because the core type carries no schema.
#[derive(utoipa::ToSchema)]
#[allow(dead_code)]
pub struct ViewSchema {
    /// Eye position `[x, y, z]`, world units.
    pub eye: [f64; 3],
    /// Point looked at.
    pub target: [f64; 3],
    /// Up direction (default `[0, 1, 0]`); not zero, not parallel to `target - eye`.
    pub up: Option<[f64; 3]>,
    /// Vertical field of view in degrees, in (0, 180).
    pub yfov_deg: f64,
    /// Width in pixels, 1..=max_px.
    pub width: u32,
    /// Height in pixels, 1..=max_px.
    pub height: u32,
}

struct BearerAuth;

impl Modify for BearerAuth {
    fn modify(&self, openapi: &mut utoipa::openapi::OpenApi) {
        let components = openapi.components.get_or_insert_with(Default::default);
        components.add_security_scheme(
            "bearer",
            SecurityScheme::Http(Http::new(HttpAuthScheme::Bearer)),
        );
    }
}

/// The API description.
#[derive(OpenApi)]
#[openapi(
    info(
        title = "lumigraph render service",
        description = "Light-field assets, one-shot renders, bake jobs and WebSocket frame streaming \
                       (protocol: docs/protocol.md)."
    ),
    paths(
        http::healthz,
        http::readyz,
        http::metrics,
        http::list_assets,
        http::get_asset,
        http::delete_asset,
        http::upload_asset,
        http::render_asset,
        http::bake,
        http::get_job,
        stream::stream,
    ),
    components(schemas(ViewSchema)),
    modifiers(&BearerAuth),
    tags(
        (name = "assets", description = "List, inspect, upload and delete .lfa assets"),
        (name = "render", description = "Render one view"),
        (name = "bake", description = "Bake uploaded meshes into assets"),
        (name = "stream", description = "Interactive frame streaming over WebSocket"),
        (name = "ops", description = "Health, readiness, metrics"),
    )
)]
pub struct ApiDoc;

/// `GET /openapi.json`.
pub async fn openapi_json() -> Json<utoipa::openapi::OpenApi> {
    Json(ApiDoc::openapi())
}
