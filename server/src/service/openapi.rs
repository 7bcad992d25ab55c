//! The OpenAPI document at `/openapi.json`, generated from the handlers' annotations.

use axum::Json;
use axum::extract::State;
use serde_json::{Value, json};
use utoipa::openapi::security::{Http, HttpAuthScheme, SecurityScheme};
use utoipa::{Modify, OpenApi, PartialSchema};

use super::state::{AppState, ServeConfig};
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
        http::render_link,
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

/// `GET /openapi.json`: the document of this server, as configured.
pub async fn openapi_json(State(state): State<AppState>) -> Json<Value> {
    Json(document(state.config()))
}

/// The API description of a server with this configuration: [`ApiDoc`] with what its
/// annotations cannot say. The request bodies' schemas are closed (the server refuses unknown
/// keys and form fields), the render body's quality keys sit beside `view` (serde's `flatten`),
/// a view's size is bounded by `max_px`, and without a token no operation requires one.
pub fn document(config: &ServeConfig) -> Value {
    let mut doc = serde_json::to_value(ApiDoc::openapi()).unwrap_or_else(|e| {
        // Serialising the derived document cannot fail; answer an empty one rather than panic.
        tracing::error!(error = %e, "serialising the OpenAPI document");
        json!({})
    });
    let schemas = &mut doc["components"]["schemas"];
    let quality = serde_json::to_value(lumigraph_core::quality::Quality::schema())
        .unwrap_or_else(|_| json!({}));
    let render = &mut schemas["RenderRequest"];
    if let (Some(props), Some(keys)) = (
        render["properties"].as_object_mut(),
        quality["properties"].as_object(),
    ) {
        for (key, schema) in keys {
            props.insert(key.clone(), schema.clone());
        }
    }
    render["properties"]["background"]["items"]["maximum"] = json!(255);
    for name in ["RenderRequest", "ViewSchema", "BakeForm"] {
        schemas[name]["additionalProperties"] = json!(false);
    }
    for side in ["width", "height"] {
        schemas["ViewSchema"]["properties"][side]["maximum"] = json!(config.max_px);
    }
    if let Some(params) = doc["paths"]["/v1/assets/{id}/render"]["get"]["parameters"].as_array_mut()
    {
        for param in params
            .iter_mut()
            .filter(|p| p["name"] == "width" || p["name"] == "height")
        {
            param["schema"]["maximum"] = json!(config.max_px);
        }
    }
    if config.token.is_none() {
        // Nothing asks for the token: say so, or clients (and fuzzers) expect 401s.
        if let Some(paths) = doc["paths"].as_object_mut() {
            for operation in paths.values_mut().filter_map(Value::as_object_mut) {
                for op in operation.values_mut().filter_map(Value::as_object_mut) {
                    op.remove("security");
                }
            }
        }
    }
    doc
}
