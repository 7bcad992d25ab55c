//! The OpenAPI document at `/openapi.json`, generated from the handlers' annotations.

use axum::Json;
use utoipa::openapi::security::{Http, HttpAuthScheme, SecurityScheme};
use utoipa::{Modify, OpenApi};

use super::{http, stream};

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
    components(schemas(http::ViewSchema)),
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
