//! The HTTP handlers of `/v1`, health, readiness and metrics.

use std::path::{Path as FsPath, PathBuf};
use std::sync::Arc;

use axum::Json;
use axum::body::{Body, Bytes};
use axum::extract::multipart::MultipartRejection;
use axum::extract::rejection::{BytesRejection, QueryRejection};
use axum::extract::{Multipart, Path, Query, Request, State};
use axum::http::{HeaderMap, HeaderName, HeaderValue, StatusCode, Uri, header};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use futures_util::StreamExt as _;
use lumigraph_core::auto_bake::AutoTarget;
use lumigraph_core::bake::BakeOptions;
use lumigraph_core::mesh::{MeshFormat, load_mesh_from_bytes};
use lumigraph_core::quality::Quality;
use lumigraph_core::view::View;
use serde::{Deserialize, Serialize};
use tokio::io::AsyncWriteExt as _;

use super::assets::{
    AssetSummary, LoadError, LoadedAsset, load_file, upload_temp_name, validate_id,
};
use super::codecs::{
    ColorFormat, DepthFormat, Encoding, encode_blocking, encode_color, encode_depth,
};
use super::content_store::StoreError;
use super::error::{AppError, ErrorBody, ErrorKind};
use super::jobs::{self, BakeWork, JobStatus};
use super::journal::{JobSpec, now_unix_ms};
use super::render_pool::{plan, quality_error};
use super::render_query;
use super::state::{AppState, random_id};

/// Counts error responses by kind for `/metrics`.
pub async fn count_errors(State(state): State<AppState>, request: Request, next: Next) -> Response {
    let response = next.run(request).await;
    if let Some(ErrorKind(kind)) = response.extensions().get::<ErrorKind>() {
        state.metrics().error(kind);
    }
    response
}

/// 404 for unknown routes.
pub async fn not_found(uri: Uri) -> AppError {
    AppError::NotFound(format!("no route for {}", uri.path()))
}

/// 405 for known routes with the wrong method.
pub async fn method_not_allowed() -> AppError {
    AppError::Rejected {
        status: StatusCode::METHOD_NOT_ALLOWED,
        message: "method not allowed on this route".to_owned(),
    }
}

fn body_error(rejection: &BytesRejection, limit: usize) -> AppError {
    AppError::from_rejection(rejection.status(), rejection.body_text(), limit as u64)
}

/// Maps a failure to read a streamed request body (an upload, or a bake form through the
/// multipart parser, whose own status and message are `status` and `message`): 408 when the
/// body stalled past `--body-timeout-secs`, 413 past the size limit, otherwise the client's
/// fault, never a 5xx (the parser answers 500 for a body that failed to arrive).
fn body_read_error(
    state: &AppState,
    err: &(dyn std::error::Error + 'static),
    status: StatusCode,
    message: String,
    limit: u64,
) -> AppError {
    let mut cause = Some(err);
    while let Some(e) = cause {
        if e.is::<tower_http::timeout::TimeoutError>() {
            return AppError::Rejected {
                status: StatusCode::REQUEST_TIMEOUT,
                message: format!(
                    "the request body stalled: no data for {} s",
                    state.config().body_idle_timeout.as_secs_f64()
                ),
            };
        }
        if e.is::<http_body_util::LengthLimitError>() {
            return AppError::TooLarge { limit };
        }
        cause = e.source();
    }
    let status = if status.is_server_error() {
        StatusCode::BAD_REQUEST
    } else {
        status
    };
    AppError::from_rejection(status, message, limit)
}

/// Health of the process (always 200 while it answers).
#[derive(Serialize, utoipa::ToSchema)]
pub struct Health {
    /// `ok`.
    pub status: &'static str,
}

/// Liveness: the process answers.
#[utoipa::path(get, path = "/healthz", tag = "ops", responses((status = 200, body = Health)))]
pub async fn healthz() -> Json<Health> {
    Json(Health { status: "ok" })
}

/// Readiness of the service.
#[derive(Serialize, utoipa::ToSchema)]
pub struct Readiness {
    /// Whether the device is up and the assets folder has been loaded.
    pub ready: bool,
    /// Assets loaded.
    pub assets: usize,
    /// The GPU adapter in use.
    pub adapter: String,
}

/// Readiness: 200 once the device is up and the assets are loaded (the demo baked if needed),
/// while the render path moves; 503 while loading, and when requests have waited longer than
/// `--render-stall-secs` with no render completing (a stuck device or driver).
#[utoipa::path(get, path = "/readyz", tag = "ops", responses(
    (status = 200, body = Readiness),
    (status = 503, body = ErrorBody, description = "loading, the render path is stuck, or the asset store fails (the message says why)")))]
pub async fn readyz(State(state): State<AppState>) -> Result<Json<Readiness>, AppError> {
    if !state.is_ready() {
        if let Some(reason) = state.store_failure() {
            return Err(AppError::Unavailable(format!("not ready: {reason}")));
        }
        return Err(AppError::Unavailable(
            "loading assets (baking the demo scene on first start)".to_owned(),
        ));
    }
    if let Some(why) = state.recovering() {
        return Err(AppError::Unavailable(why));
    }
    let health = state.pool().health();
    let bound = state.config().render_stall_timeout;
    if let Some(stalled) = health.stalled_for.filter(|s| *s > bound) {
        return Err(AppError::Unavailable(format!(
            "the render path is stuck: {} requests have waited {:.0} s with no render \
             completing (bound {:.0} s, --render-stall-secs)",
            health.in_flight,
            stalled.as_secs_f64(),
            bound.as_secs_f64(),
        )));
    }
    Ok(Json(Readiness {
        ready: true,
        assets: state.assets().len(),
        adapter: state.inner.adapter.clone(),
    }))
}

/// Prometheus metrics in the OpenMetrics text format.
#[utoipa::path(get, path = "/metrics", tag = "ops", responses((status = 200, content_type = "application/openmetrics-text", body = String)))]
pub async fn metrics(State(state): State<AppState>) -> impl IntoResponse {
    let resident = state.pool().renderer().resident();
    state.metrics().set_asset_memory(
        resident.fields,
        state.assets().charged_bytes(),
        state.assets().limits().memory_budget,
    );
    state
        .metrics()
        .set_memory(state.budget().used(), state.budget().total());
    (
        [(
            header::CONTENT_TYPE,
            "application/openmetrics-text; version=1.0.0; charset=utf-8",
        )],
        state.metrics().encode(),
    )
}

/// Every asset.
#[utoipa::path(get, path = "/v1/assets", tag = "assets", responses((status = 200, body = [AssetSummary])))]
pub async fn list_assets(State(state): State<AppState>) -> Json<Vec<AssetSummary>> {
    Json(state.assets().list())
}

/// One asset with its full header.
#[derive(Serialize, utoipa::ToSchema)]
pub struct AssetDetail {
    /// The summary.
    #[serde(flatten)]
    pub summary: AssetSummary,
    /// The `.lfa` header: kind, geometry, channels, layers, states, provenance, quality report.
    #[schema(value_type = Object)]
    pub header: serde_json::Value,
}

fn detail(asset: &LoadedAsset) -> Result<AssetDetail, AppError> {
    let header = serde_json::to_value(&asset.header).map_err(|e| AppError::Internal(e.into()))?;
    Ok(AssetDetail {
        summary: asset.summary(),
        header,
    })
}

/// One asset: header (kind, cameras, resolution, layers, states, quality report).
#[utoipa::path(get, path = "/v1/assets/{id}", tag = "assets",
    params(("id" = String, Path, description = "asset id", pattern = "^[A-Za-z0-9][A-Za-z0-9_-]{0,63}$", min_length = 1, max_length = 64)),
    responses((status = 200, body = AssetDetail), (status = 404, body = ErrorBody), (status = 413, body = ErrorBody),
        (status = 422, body = ErrorBody), (status = 503, body = ErrorBody, description = "loading, or the asset store fails")))]
pub async fn get_asset(
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> Result<Json<AssetDetail>, AppError> {
    let asset = state.asset(&id).await?;
    Ok(Json(detail(&asset)?))
}

/// Deletes an asset and its file (token-protected when a token is configured). The file's
/// removal is synced to disk before the 204: a deleted asset stays deleted across a crash.
#[utoipa::path(delete, path = "/v1/assets/{id}", tag = "assets",
    params(("id" = String, Path, description = "asset id", pattern = "^[A-Za-z0-9][A-Za-z0-9_-]{0,63}$", min_length = 1, max_length = 64)),
    security(("bearer" = [])),
    responses((status = 204), (status = 401, body = ErrorBody), (status = 404, body = ErrorBody),
        (status = 422, body = ErrorBody, description = "invalid id"),
        (status = 503, body = ErrorBody, description = "the asset store fails")))]
pub async fn delete_asset(
    State(state): State<AppState>,
    headers: HeaderMap,
    Path(id): Path<String>,
) -> Result<StatusCode, AppError> {
    state.authorize(&headers)?;
    validate_id(&id)?;
    // No fetch of this id runs meanwhile, so none can bring it back after the 204.
    let _store_lock = match state.store() {
        Some(_) => Some(state.lock_store_id(&id).await),
        None => None,
    };
    let mut named = false;
    if let Some(store) = state.store() {
        // The name goes first: once the 204 is sent no replica loads the asset anew (those
        // that hold it keep serving it until they restart or evict it). A record that is not
        // a valid record is removed too.
        named = match store.resolve(&id).await {
            Ok(record) => record.is_some(),
            Err(StoreError::BadRecord { .. }) => true,
            Err(err) => return Err(store_unavailable(err)),
        };
        store.remove_name(&id).await.map_err(store_unavailable)?;
        if named {
            tracing::info!(id, "asset name removed from the store");
        }
    }
    if !named {
        state.assets().get(&id)?;
    }
    let Some(asset) = state.assets().remove(&id) else {
        return if named {
            Ok(StatusCode::NO_CONTENT)
        } else {
            Err(AppError::NotFound(format!("no asset with id {id:?}")))
        };
    };
    state.metrics().set_assets(state.assets().len());
    // A file of the store's cache may be shared with other ids: it is left to eviction.
    if asset.path.parent() != Some(state.assets().dir()) {
        tracing::info!(id, "asset deleted");
        return Ok(StatusCode::NO_CONTENT);
    }
    // The unlink is made durable (the folder synced) before the 204: a deleted asset stays
    // deleted across a crash.
    let path = asset.path.clone();
    let dir = state.assets().dir().to_path_buf();
    tokio::task::spawn_blocking(move || {
        match std::fs::remove_file(&path) {
            Err(err) if err.kind() != std::io::ErrorKind::NotFound => Err(err),
            _ => Ok(()),
        }
        .and_then(|()| lumigraph_core::sync_dir(&dir))
        .map_err(|err| anyhow::Error::new(err).context(format!("removing {}", path.display())))
    })
    .await
    .map_err(|e| AppError::Internal(e.into()))?
    .map_err(AppError::Internal)?;
    tracing::info!(id, "asset deleted");
    Ok(StatusCode::NO_CONTENT)
}

/// A store failure as the client sees it (503, the reason in the message and the log).
fn store_unavailable(err: StoreError) -> AppError {
    tracing::error!(error = %err, "the asset store failed");
    match err {
        StoreError::NameTaken { .. } => AppError::Conflict(err.to_string()),
        err => AppError::Unavailable(err.to_string()),
    }
}

/// 409 when the shared store already names `id` (another replica's upload or bake).
async fn check_store_free(state: &AppState, id: &str) -> Result<(), AppError> {
    if let Some(store) = state.store()
        && let Some(record) = store.resolve(id).await.map_err(store_unavailable)?
    {
        return Err(AppError::Conflict(format!(
            "asset id {id:?} is taken in the asset store (it names content {}): delete it \
             first or choose another id",
            record.sha256
        )));
    }
    Ok(())
}

/// Query of `POST /v1/assets`.
#[derive(Deserialize, utoipa::IntoParams)]
#[serde(deny_unknown_fields)]
#[into_params(parameter_in = Query)]
pub struct UploadQuery {
    /// Id of the new asset (default: a random `asset-…` id).
    #[param(
        pattern = "^[A-Za-z0-9][A-Za-z0-9_-]{0,63}$",
        min_length = 1,
        max_length = 64
    )]
    pub id: Option<String>,
}

/// Removes a temporary upload file unless disarmed.
struct TempFile(Option<PathBuf>);

impl TempFile {
    fn path(&self) -> Option<&FsPath> {
        self.0.as_deref()
    }
}

impl Drop for TempFile {
    fn drop(&mut self) {
        if let Some(path) = self.0.take() {
            let _ = std::fs::remove_file(path);
        }
    }
}

/// Uploads an `.lfa` file (the raw request body). The file is streamed to a temporary file,
/// fully verified (every page checksum) and loaded onto the GPU before it is renamed into the
/// assets folder, so a bad upload leaves nothing behind; the file and the rename are synced to
/// disk before the 201, so an acknowledged upload survives a crash.
#[utoipa::path(post, path = "/v1/assets", tag = "assets",
    params(UploadQuery),
    request_body(content = Vec<u8>, content_type = "application/octet-stream", description = "an .lfa file"),
    security(("bearer" = [])),
    responses((status = 201, body = AssetSummary), (status = 401, body = ErrorBody),
        (status = 408, body = ErrorBody, description = "the body stalled"), (status = 409, body = ErrorBody),
        (status = 413, body = ErrorBody), (status = 422, body = ErrorBody),
        (status = 503, body = ErrorBody, description = "memory busy, or the asset store fails")))]
pub async fn upload_asset(
    State(state): State<AppState>,
    headers: HeaderMap,
    query: Result<Query<UploadQuery>, QueryRejection>,
    body: Body,
) -> Result<Response, AppError> {
    state.authorize(&headers)?;
    let Query(query) = query.map_err(|e| AppError::Invalid(e.body_text()))?;
    let limit = state.config().max_upload_bytes;
    if declared_length(&headers).is_some_and(|len| len > limit) {
        return Err(AppError::TooLarge { limit });
    }
    let id = query.id.unwrap_or_else(|| random_id("asset"));
    let reservation = state.assets().reserve(&id)?;
    check_store_free(&state, &id).await?;
    let temp = TempFile(Some(
        state
            .assets()
            .dir()
            .join(upload_temp_name(&random_id("tmp"))),
    ));
    let temp_path = temp.path().map(FsPath::to_path_buf).unwrap_or_default();
    let internal =
        |e: std::io::Error| AppError::Internal(anyhow::Error::new(e).context("writing the upload"));
    let mut file = tokio::fs::File::create(&temp_path)
        .await
        .map_err(internal)?;
    let mut stream = body.into_data_stream();
    let mut written = 0u64;
    while let Some(chunk) = stream.next().await {
        let chunk = chunk.map_err(|e| {
            let message = format!("reading the upload failed: {e}");
            body_read_error(&state, &e, StatusCode::BAD_REQUEST, message, limit)
        })?;
        written += chunk.len() as u64;
        if written > limit {
            return Err(AppError::TooLarge { limit });
        }
        file.write_all(&chunk).await.map_err(internal)?;
    }
    file.sync_all().await.map_err(internal)?;
    drop(file);
    let loader = state.clone();
    let check_path = temp_path.clone();
    let check_id = id.clone();
    let loaded = tokio::task::spawn_blocking(move || {
        let engine = loader.pool().engine();
        load_file(loader.assets(), &engine, &check_id, &check_path).map_err(|e| (e, engine))
    })
    .await
    .map_err(|e| AppError::Internal(e.into()))?
    .map_err(|(e, engine)| match e {
        LoadError::OverLimit(message) => AppError::OverLimit(message),
        LoadError::Busy(message) => AppError::Unavailable(message),
        other => state
            .pool()
            .device_lost(&engine)
            .unwrap_or_else(|| AppError::BadUpload(format!("not a usable .lfa asset: {other}"))),
    })?;
    // Published from the temporary file before it is renamed and listed: an acknowledged
    // upload is in the store, and one the store refuses (or one cut off meanwhile) leaves
    // nothing behind here. No fetch of the id interleaves.
    let _store_lock = match state.store() {
        Some(store) => {
            let lock = state.lock_store_id(&id).await;
            store
                .publish(&id, &temp_path)
                .await
                .map_err(store_unavailable)?;
            Some(lock)
        }
        None => None,
    };
    let final_path = state.assets().path_for(&id);
    tokio::fs::rename(&temp_path, &final_path)
        .await
        .map_err(internal)?;
    // The rename is made durable before the 201: an acknowledged upload survives a crash.
    let dir = state.assets().dir().to_path_buf();
    tokio::task::spawn_blocking(move || lumigraph_core::sync_dir(&dir))
        .await
        .map_err(|e| AppError::Internal(e.into()))?
        .map_err(internal)?;
    let mut temp = temp;
    temp.0 = None;
    let mut asset = loaded;
    asset.path = final_path;
    let summary = asset.summary();
    state.assets().insert(asset);
    drop(reservation);
    state.metrics().set_assets(state.assets().len());
    tracing::info!(id, bytes = written, "asset uploaded");
    let location = HeaderValue::from_str(&format!("/v1/assets/{id}"))
        .map_err(|e| AppError::Internal(e.into()))?;
    Ok((
        StatusCode::CREATED,
        [(header::LOCATION, location)],
        Json(summary),
    )
        .into_response())
}

/// A view (DESIGN §3), documented here because the core type carries no schema.
#[derive(utoipa::ToSchema)]
#[allow(dead_code)]
pub struct ViewSchema {
    /// Eye position `[x, y, z]`, world units.
    #[schema(min_items = 3, max_items = 3)]
    pub eye: [f64; 3],
    /// Point looked at.
    #[schema(min_items = 3, max_items = 3)]
    pub target: [f64; 3],
    /// Up direction (default, when absent: `[0, 1, 0]`; not `null`); not zero, not parallel to
    /// `target - eye`.
    #[schema(required = false, min_items = 3, max_items = 3)]
    pub up: [f64; 3],
    /// Vertical field of view in degrees, in (0, 180).
    #[schema(exclusive_minimum = 0.0, exclusive_maximum = 180.0)]
    pub yfov_deg: f64,
    /// Width in pixels, 1..=max_px.
    #[schema(minimum = 1)]
    pub width: u32,
    /// Height in pixels, 1..=max_px.
    #[schema(minimum = 1)]
    pub height: u32,
}

/// Body of `POST /v1/assets/{id}/render`: the view, the output fields and, at the top level,
/// the quality keys (core `Quality`: knobs, a goal or automatic LOD). A goal's choice comes
/// back in `X-Chosen-Cameras`, `X-Chosen-Step`, `X-Predicted-Psnr`, `X-Predicted-Ms` and
/// `X-Goal-Met` (`false`: no calibrated setting meets it, the closest is used); an automatic-LOD
/// decision in `X-Projected-Px`, `X-Chosen-Cameras`, `X-Chosen-Step`, `X-Predicted-Error-Px`,
/// `X-Predicted-Psnr`, `X-Goal-Met` and, inside a cross-fade band, `X-Lod-Blend:
/// CAMERAS,STEP,WEIGHT`.
#[derive(Debug, utoipa::ToSchema)]
#[allow(dead_code)]
pub struct RenderRequest {
    /// The view (DESIGN §3), in the asset's world coordinates.
    #[schema(value_type = ViewSchema)]
    pub view: View,
    /// RGBA8 background where nothing is hit; default transparent black.
    #[schema(value_type = Option<Vec<u8>>, min_items = 4, max_items = 4)]
    pub background: Option<[u8; 4]>,
    /// Colour codec; default, when absent, `png` (not `null`). `none` returns only the depth
    /// image.
    #[schema(required = false)]
    pub format: ColorFormat,
    /// JPEG quality 1..=100, default 90.
    #[schema(minimum = 1, maximum = 100)]
    pub quality: Option<u8>,
    /// Also return depth in this format (see the response description).
    pub depth: Option<DepthFormat>,
    // The quality keys (core `Quality`) sit at the top level of the body: openapi.rs merges
    // their properties into this object, whose schema then allows no other key (the server
    // refuses unknown ones). An `allOf` of the two closed objects would match no body at all.
}

/// The fields of a render body other than the quality keys.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RenderFields {
    view: View,
    background: Option<[u8; 4]>,
    #[serde(default)]
    format: ColorFormat,
    quality: Option<u8>,
    depth: Option<DepthFormat>,
}

/// A render request body, parsed and checked as far as it can be without its asset.
#[derive(Debug)]
pub struct RenderBody {
    fields: RenderFields,
    /// Colour quality, 1..=100.
    quality: u8,
    knobs: Quality,
}

impl RenderBody {
    /// Parses a `POST /v1/assets/{id}/render` body and checks its view against `max_px`, its
    /// quality and formats, and its quality keys' shape (the plan needs the asset).
    ///
    /// # Errors
    /// [`AppError::MalformedJson`] for malformed JSON, [`AppError::Invalid`] for bad values.
    pub fn parse(body: &[u8], max_px: u32) -> Result<Self, AppError> {
        let body: serde_json::Map<String, serde_json::Value> =
            serde_json::from_slice(body).map_err(|e| AppError::from_json(&e))?;
        Self::from_map(body, max_px)
    }

    /// Checks a render body already parsed as a JSON object (a `POST` body, or the body
    /// [`render_query::body_from_query`] builds from a `GET` query) as [`RenderBody::parse`] does.
    ///
    /// # Errors
    /// [`AppError::Invalid`] for bad values.
    pub fn from_map(
        mut body: serde_json::Map<String, serde_json::Value>,
        max_px: u32,
    ) -> Result<Self, AppError> {
        let knobs = Quality::take_from(&mut body).map_err(quality_error)?;
        let fields: RenderFields = serde_json::from_value(serde_json::Value::Object(body))
            .map_err(|e| AppError::from_json(&e))?;
        fields
            .view
            .basis(max_px)
            .map_err(|e| AppError::Invalid(e.to_string()))?;
        let quality = fields.quality.unwrap_or(90);
        if !(1..=100).contains(&quality) {
            return Err(AppError::Invalid(format!(
                "quality must be in 1..=100, got {quality}"
            )));
        }
        if fields.format == ColorFormat::None && fields.depth.is_none() {
            return Err(AppError::Invalid(
                "format `none` needs a `depth` format".to_owned(),
            ));
        }
        Ok(Self {
            fields,
            quality,
            knobs,
        })
    }
}

fn ms_header(value: f64) -> HeaderValue {
    HeaderValue::from_str(&format!("{value:.3}")).unwrap_or(HeaderValue::from_static("0"))
}

/// Renders one view. Colour only: the image is the body. With `depth` and `format: none`: the
/// depth image is the body. With both: a `multipart/mixed` body whose first part is the colour
/// image and second the depth image (each with `Content-Type`). `X-Render-Ms`, `X-Encode-Ms`,
/// `X-Frame-Width`, `X-Frame-Height` come with every answer; `X-Depth-Near`/`X-Depth-Far` with
/// `png16` depth.
#[utoipa::path(post, path = "/v1/assets/{id}/render", tag = "render",
    params(("id" = String, Path, description = "asset id", pattern = "^[A-Za-z0-9][A-Za-z0-9_-]{0,63}$", min_length = 1, max_length = 64)),
    request_body = RenderRequest,
    responses(
        (status = 200, description = "image/png, image/jpeg, image/webp, a depth image or multipart/mixed"),
        (status = 400, body = ErrorBody, description = "malformed JSON"),
        (status = 404, body = ErrorBody),
        (status = 408, body = ErrorBody, description = "the body stalled or did not arrive in time"),
        (status = 413, body = ErrorBody),
        (status = 422, body = ErrorBody, description = "invalid view or knobs"),
        (status = 503, body = ErrorBody, description = "render queue full, loading, or the asset store fails")))]
pub async fn render_asset(
    State(state): State<AppState>,
    Path(id): Path<String>,
    body: Result<Bytes, BytesRejection>,
) -> Result<Response, AppError> {
    let body = body.map_err(|e| body_error(&e, state.config().max_json_bytes))?;
    let asset = state.asset(&id).await?;
    let body = RenderBody::parse(&body, state.config().max_px)?;
    let plan = plan(&body.knobs, &asset)?;
    render_response(&state, asset, body, plan).await
}

/// How long shared caches may keep a render link's image before asking again (with
/// `If-None-Match`, answered 304 without rendering while the asset is unchanged). Short,
/// because an id can be given to new content (a delete and an upload).
const RENDER_LINK_MAX_AGE_S: u32 = 300;

/// Renders one view given as query parameters, so that a link is also an image: the render
/// body's keys, with the view's fields at the top level (`eye=x,y,z` or the viewer's orbit
/// form `az`/`el`/`dist` in degrees and world units, `target`, `up`, `yfov_deg`, `width`,
/// `height`), `background=r,g,b,a`, `format`, `quality` and the quality keys (`lod=12&step=0.02`,
/// `method=fixed`, ...); no `depth`. The answer is the `POST` render's, bit for bit, with the
/// same headers, plus an `ETag` (the asset's content, the server's version and adapter and the
/// canonical parameters) and `Cache-Control: public, max-age=300`; `If-None-Match` with that tag
/// is answered 304 without rendering.
#[utoipa::path(get, path = "/v1/assets/{id}/render", tag = "render",
    params(("id" = String, Path, description = "asset id", pattern = "^[A-Za-z0-9][A-Za-z0-9_-]{0,63}$", min_length = 1, max_length = 64),
        RenderLinkQuery),
    responses(
        (status = 200, description = "image/png, image/jpeg or image/webp, with ETag and Cache-Control"),
        (status = 304, description = "If-None-Match matched the ETag: the cached image is current"),
        (status = 404, body = ErrorBody),
        (status = 413, body = ErrorBody),
        (status = 422, body = ErrorBody, description = "unknown, repeated, missing, malformed or out-of-range parameter (the message names it)"),
        (status = 503, body = ErrorBody, description = "render queue full, loading, or the asset store fails")))]
pub async fn render_link(
    State(state): State<AppState>,
    Path(id): Path<String>,
    headers: HeaderMap,
    query: Result<Query<Vec<(String, String)>>, QueryRejection>,
) -> Result<Response, AppError> {
    let Query(pairs) = query.map_err(|e| AppError::Invalid(e.body_text()))?;
    let asset = state.asset(&id).await?;
    let map = render_query::body_from_query(&pairs)?;
    let canonical = serde_json::to_string(&map).map_err(|e| AppError::Internal(e.into()))?;
    let body = RenderBody::from_map(map, state.config().max_px)?;
    let plan = plan(&body.knobs, &asset)?;
    let tag = format!(
        "\"{}\"",
        &lumigraph_core::bake::sha256_hex(
            format!(
                "lumigraph {}\n{}\n{}\n{canonical}",
                env!("CARGO_PKG_VERSION"),
                state.inner.adapter,
                asset.content_id
            )
            .as_bytes()
        )[..32]
    );
    let etag = HeaderValue::from_str(&tag).map_err(|e| AppError::Internal(e.into()))?;
    let cache_control = HeaderValue::from_str(&format!("public, max-age={RENDER_LINK_MAX_AGE_S}"))
        .map_err(|e| AppError::Internal(e.into()))?;
    if if_none_match(&headers, &tag) {
        return Ok((
            StatusCode::NOT_MODIFIED,
            [(header::ETAG, etag), (header::CACHE_CONTROL, cache_control)],
        )
            .into_response());
    }
    let mut response = render_response(&state, asset, body, plan).await?;
    response.headers_mut().insert(header::ETAG, etag);
    response
        .headers_mut()
        .insert(header::CACHE_CONTROL, cache_control);
    Ok(response)
}

/// Whether an `If-None-Match` header lists `tag` (weak comparison, RFC 9110 §13.1.2) or is `*`.
fn if_none_match(headers: &HeaderMap, tag: &str) -> bool {
    headers
        .get_all(header::IF_NONE_MATCH)
        .iter()
        .filter_map(|v| v.to_str().ok())
        .flat_map(|v| v.split(','))
        .map(str::trim)
        .any(|candidate| candidate == "*" || candidate.trim_start_matches("W/") == tag)
}

pub use link_params::RenderLinkQuery;

// utoipa's derive builds the 24 parameters' descriptions in one array on the stack, once per
// OpenAPI document: above clippy's 16 KiB bound, harmless for a call made at start-up.
#[allow(clippy::large_stack_arrays)]
mod link_params {
    /// The parameters of `GET /v1/assets/{id}/render` (for the OpenAPI document; the handler reads
    /// them as pairs, so that unknown and repeated ones are refused by name).
    #[derive(utoipa::IntoParams)]
    #[into_params(parameter_in = Query)]
    #[allow(dead_code)]
    pub struct RenderLinkQuery {
        /// Eye position `x,y,z` (world units); or give `az`, `el`, `dist` instead.
        #[param(pattern = "^[^,]+,[^,]+,[^,]+$")]
        pub eye: Option<String>,
        /// Orbit form: azimuth in degrees about +y, from +z towards +x (with `el`, `dist`).
        pub az: Option<f64>,
        /// Orbit form: elevation in degrees above the x-z plane.
        pub el: Option<f64>,
        /// Orbit form: distance from `target`, world units, above 0.
        #[param(exclusive_minimum = 0.0)]
        pub dist: Option<f64>,
        /// Point looked at, `x,y,z`.
        #[param(pattern = "^[^,]+,[^,]+,[^,]+$")]
        pub target: String,
        /// Up direction `x,y,z` (default `0,1,0`).
        #[param(pattern = "^[^,]+,[^,]+,[^,]+$")]
        pub up: Option<String>,
        /// Vertical field of view in degrees, in (0, 180).
        #[param(exclusive_minimum = 0.0, exclusive_maximum = 180.0)]
        pub yfov_deg: f64,
        /// Width in pixels, 1..=max_px.
        #[param(minimum = 1)]
        pub width: u32,
        /// Height in pixels, 1..=max_px.
        #[param(minimum = 1)]
        pub height: u32,
        /// RGBA background `r,g,b,a` (0..=255 each) where nothing is hit; default `0,0,0,0`.
        #[param(pattern = "^\\d{1,3},\\d{1,3},\\d{1,3},\\d{1,3}$")]
        pub background: Option<String>,
        /// `png` (default), `jpeg` or `webp`.
        #[param(pattern = "^(png|jpeg|webp)$")]
        pub format: Option<String>,
        /// JPEG quality 1..=100, default 90.
        #[param(minimum = 1, maximum = 100)]
        pub quality: Option<u8>,
        /// Cameras (12, 42, 162, 642 or a level 0-3), as in the render body.
        pub lod: Option<u32>,
        /// March step, as in the render body.
        pub step: Option<f32>,
        /// Depth agreement tolerance, as in the render body.
        pub tolerance: Option<f32>,
        /// `default` or `fixed`.
        #[param(pattern = "^(default|fixed)$")]
        pub method: Option<String>,
        /// Coarse-to-fine factor, as in the render body.
        pub guide: Option<u32>,
        /// Goal: masked PSNR (dB), as in the render body.
        pub target_psnr: Option<f64>,
        /// Goal: time budget (ms), as in the render body.
        pub budget_ms: Option<f64>,
        /// Automatic LOD: silhouette error bound in pixels, as in the render body.
        pub auto_lod: Option<f64>,
        /// With `auto_lod`: PSNR floor (dB).
        pub lod_min_psnr: Option<f64>,
        /// With `auto_lod`: largest PSNR drop (dB) below the most accurate level.
        pub lod_max_psnr_drop: Option<f64>,
        /// With `auto_lod`: cross-fade band.
        pub lod_blend: Option<f64>,
        /// Still refinement samples, 1..=256.
        pub refine: Option<u32>,
    }
}

/// Renders a checked request with its plan and answers the image with the render headers: the
/// one path of `POST` and `GET` renders.
async fn render_response(
    state: &AppState,
    asset: Arc<LoadedAsset>,
    body: RenderBody,
    plan: lumigraph_core::quality::Plan,
) -> Result<Response, AppError> {
    let RenderBody {
        fields: request,
        quality,
        ..
    } = body;
    let rendered = state
        .pool()
        .render(asset, request.view.clone(), plan, true)
        .await?;
    let decision = rendered.decision;
    if let Some(pages) = &rendered.pages {
        state.metrics().pages(pages);
    }
    let encoding = Encoding {
        format: request.format,
        quality,
        background: request.background.unwrap_or([0; 4]),
    };
    let depth_format = request.depth;
    let frame = rendered.frame;
    let (width, height) = (frame.width, frame.height);
    let ((color, depth), encode_ms) = encode_blocking(move || {
        let color = encode_color(&frame, encoding)
            .map_err(|e| AppError::Internal(anyhow::Error::new(e).context("encoding colour")))?;
        let depth = depth_format.map(|f| encode_depth(&frame, f)).transpose()?;
        Ok((color, depth))
    })
    .await?;
    let bytes = color.len() + depth.as_ref().map_or(0, |d| d.bytes.len());
    state.metrics().frame(
        "http",
        "full",
        bytes,
        rendered.render_ms,
        encode_ms,
        encoding.format.name(),
    );
    let mut headers = HeaderMap::new();
    headers.insert(
        HeaderName::from_static("x-render-ms"),
        ms_header(rendered.render_ms),
    );
    headers.insert(HeaderName::from_static("x-encode-ms"), ms_header(encode_ms));
    headers.insert(
        HeaderName::from_static("x-frame-width"),
        HeaderValue::from(width),
    );
    headers.insert(
        HeaderName::from_static("x-frame-height"),
        HeaderValue::from(height),
    );
    headers.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-store"));
    if let Some(pages) = &rendered.pages {
        for (name, value) in [
            ("x-page-faults", u64::from(pages.faults)),
            ("x-pages-loaded", u64::from(pages.pages_loaded)),
            ("x-degraded-px", pages.degraded_px),
            ("x-overview-px", pages.overview_px),
        ] {
            headers.insert(HeaderName::from_static(name), HeaderValue::from(value));
        }
    }
    for (name, value) in decision.report() {
        let name = HeaderName::from_bytes(format!("x-{name}").as_bytes())
            .map_err(|e| AppError::Internal(e.into()))?;
        let value = HeaderValue::from_str(&value).unwrap_or(HeaderValue::from_static("?"));
        headers.insert(name, value);
    }
    let body = if let (Some(depth), Some(depth_format)) = (depth, depth_format) {
        if let Some((near, far)) = depth.range {
            headers.insert(
                HeaderName::from_static("x-depth-near"),
                ms_header(f64::from(near)),
            );
            headers.insert(
                HeaderName::from_static("x-depth-far"),
                ms_header(f64::from(far)),
            );
        }
        if request.format == ColorFormat::None {
            headers.insert(
                header::CONTENT_TYPE,
                HeaderValue::from_static(depth_format.mime()),
            );
            depth.bytes
        } else {
            let boundary = format!("lumigraph-{:032x}", rand::random::<u128>());
            let content_type =
                HeaderValue::from_str(&format!("multipart/mixed; boundary={boundary}"))
                    .map_err(|e| AppError::Internal(e.into()))?;
            headers.insert(header::CONTENT_TYPE, content_type);
            multipart_mixed(
                &boundary,
                &[
                    ("color", request.format.mime(), &color),
                    ("depth", depth_format.mime(), &depth.bytes),
                ],
            )
        }
    } else {
        headers.insert(
            header::CONTENT_TYPE,
            HeaderValue::from_static(request.format.mime()),
        );
        color
    };
    Ok((headers, body).into_response())
}

fn multipart_mixed(boundary: &str, parts: &[(&str, &str, &[u8])]) -> Vec<u8> {
    let mut out = Vec::with_capacity(parts.iter().map(|p| p.2.len() + 160).sum());
    for (name, mime, bytes) in parts {
        out.extend_from_slice(
            format!("--{boundary}\r\nContent-Type: {mime}\r\nContent-Disposition: inline; name=\"{name}\"\r\nContent-Length: {}\r\n\r\n", bytes.len())
                .as_bytes(),
        );
        out.extend_from_slice(bytes);
        out.extend_from_slice(b"\r\n");
    }
    out.extend_from_slice(format!("--{boundary}--\r\n").as_bytes());
    out
}

/// Multipart form of `POST /v1/bake` (for the OpenAPI document).
#[derive(utoipa::ToSchema)]
#[allow(dead_code)]
pub struct BakeForm {
    /// The mesh file; its extension (.gltf .glb .obj .ply .stl .off) names the format unless
    /// `format` is given. glTF must embed its buffers and images.
    #[schema(value_type = String, format = Binary)]
    pub mesh: Vec<u8>,
    /// Mesh format, overriding the file name's extension (any case, an optional leading dot).
    #[schema(
        pattern = "^\\.?([Gg][Ll][Tt][Ff]|[Gg][Ll][Bb]|[Oo][Bb][Jj]|[Pp][Ll][Yy]|[Ss][Tt][Ll]|[Oo][Ff][Ff])$"
    )]
    pub format: Option<String>,
    /// Bake options as JSON, e.g. `{"cameras": 42, "resolution": 128}`.
    pub options: Option<String>,
    /// Id of the asset to create (default, also when empty: a random `mesh-…` id); surrounding
    /// whitespace is ignored.
    #[schema(pattern = "^\\s*([A-Za-z0-9][A-Za-z0-9_-]{0,63})?\\s*$")]
    pub id: Option<String>,
    /// `true` (default) or `false`, surrounding whitespace ignored: measure the scene's error
    /// against cost after the bake (a few seconds), so renders can ask for `target_psnr` /
    /// `budget_ms`.
    #[schema(pattern = "^\\s*(true|false)\\s*$")]
    pub calibrate: Option<String>,
    /// The automatic bake (`lumigraph bake --auto`, docs/auto-bake.md): `true` (target 27 dB
    /// masked PSNR), `{"target_psnr": DB}` or `{"max_bytes": N}`; camera count, map
    /// resolution and depth bits are chosen for the scene, so `options` may give the shading
    /// only. Tens of seconds to minutes: three calibration bakes come first. The job's report
    /// has the choice, its predicted and held-out masked PSNR and whether the target was met.
    pub auto: Option<String>,
}

/// The form's `auto` object.
#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct AutoField {
    target_psnr: Option<f64>,
    max_bytes: Option<u64>,
}

/// Reads the form's `auto` field: `true`/`false` or an object with one target.
fn parse_auto(text: &str) -> Result<Option<AutoTarget>, AppError> {
    let invalid = |why: String| AppError::Invalid(format!("auto: {why}"));
    let field: AutoField = match text.trim() {
        "false" => return Ok(None),
        "true" => AutoField {
            target_psnr: None,
            max_bytes: None,
        },
        json => serde_json::from_str(json).map_err(|e| {
            invalid(format!(
                "expected true, false, {{\"target_psnr\": DB}} or {{\"max_bytes\": N}} ({e})"
            ))
        })?,
    };
    AutoTarget::from_flags(field.target_psnr, field.max_bytes)
        .map(Some)
        .map_err(|e| invalid(e.to_string()))
}

/// Uploads a mesh and starts a bake job (token-protected when a token is configured). The
/// mesh and options are checked before the job starts: bad ones are answered 422 at once. The
/// job and its mesh are stored in the assets folder's job journal (`.jobs/`) before the 202: a
/// server that stops or crashes resumes the job at its next start, under the same job id.
#[utoipa::path(post, path = "/v1/bake", tag = "bake",
    request_body(content = BakeForm, content_type = "multipart/form-data"),
    security(("bearer" = [])),
    responses((status = 202, body = JobStatus), (status = 400, body = ErrorBody), (status = 401, body = ErrorBody),
        (status = 408, body = ErrorBody, description = "the body stalled"),
        (status = 409, body = ErrorBody), (status = 413, body = ErrorBody), (status = 422, body = ErrorBody),
        (status = 503, body = ErrorBody, description = "the asset store fails")))]
pub async fn bake(
    State(state): State<AppState>,
    headers: HeaderMap,
    multipart: Result<Multipart, MultipartRejection>,
) -> Result<Response, AppError> {
    state.authorize(&headers)?;
    let limit = state.config().max_mesh_bytes;
    // A declared oversize body is refused before any of it is read or buffered.
    if declared_length(&headers).is_some_and(|len| len > limit) {
        return Err(AppError::TooLarge { limit });
    }
    let mut multipart = multipart.map_err(|e| AppError::Rejected {
        status: e.status(),
        message: e.body_text(),
    })?;
    let field_error = |e: axum::extract::multipart::MultipartError| {
        body_read_error(&state, &e, e.status(), e.body_text(), limit)
    };
    let mut mesh: Option<(Option<String>, Bytes)> = None;
    let mut format = None;
    let mut options_json = None;
    let mut id = None;
    let mut calibrate = true;
    let mut auto = None;
    while let Some(field) = multipart.next_field().await.map_err(field_error)? {
        let name = field.name().unwrap_or_default().to_owned();
        match name.as_str() {
            "mesh" => {
                let file_name = field.file_name().map(str::to_owned);
                mesh = Some((file_name, field.bytes().await.map_err(field_error)?));
            }
            "format" => format = Some(field.text().await.map_err(field_error)?),
            "options" => options_json = Some(field.text().await.map_err(field_error)?),
            "id" => id = Some(field.text().await.map_err(field_error)?),
            "calibrate" => {
                calibrate = match field.text().await.map_err(field_error)?.trim() {
                    "true" => true,
                    "false" => false,
                    other => {
                        return Err(AppError::Invalid(format!(
                            "calibrate must be true or false, got {other:?}"
                        )));
                    }
                };
            }
            "auto" => auto = parse_auto(&field.text().await.map_err(field_error)?)?,
            other => {
                return Err(AppError::Invalid(format!(
                    "unknown form field {other:?}: expected mesh, format, options, id, \
                     calibrate, auto"
                )));
            }
        }
    }
    let Some((file_name, mesh_bytes)) = mesh else {
        return Err(AppError::Invalid(
            "the form needs a `mesh` file field".to_owned(),
        ));
    };
    let options_value: Option<serde_json::Value> = match options_json.as_deref().map(str::trim) {
        None | Some("") => None,
        Some(json) => Some(serde_json::from_str(json).map_err(|e| AppError::from_json(&e))?),
    };
    if auto.is_some()
        && let Some(serde_json::Value::Object(map)) = &options_value
    {
        let chosen: Vec<&str> = ["cameras", "resolution", "depth_bits"]
            .into_iter()
            .filter(|k| map.contains_key(*k))
            .collect();
        if !chosen.is_empty() {
            return Err(AppError::Invalid(format!(
                "auto chooses {} for the scene: leave them out of options",
                chosen.join(", ")
            )));
        }
        if map.contains_key("lights") {
            return Err(AppError::Invalid(
                "lights: an automatic bake chooses settings for the base state only; bake \
                 light states without auto"
                    .to_owned(),
            ));
        }
        if let Some(key) = ["color_codec", "depth_codec"]
            .into_iter()
            .find(|k| map.contains_key(*k))
        {
            return Err(AppError::Invalid(format!(
                "{key}: an automatic bake chooses settings for raw pages; bake block-compressed \
                 pages without auto"
            )));
        }
    }
    let mut options: BakeOptions = match options_value {
        None => BakeOptions::default(),
        Some(value) => serde_json::from_value(value).map_err(|e| AppError::from_json(&e))?,
    };
    if auto.is_some() {
        // The smallest setting the automatic bake can choose must fit the asset budget; the
        // job's counter counts the cameras of each bake of a chosen setting.
        options.cameras = lumigraph_core::geometry::CAMERA_COUNTS[0];
        options.resolution = lumigraph_core::auto_bake::AUTO_MIN_RESOLUTION;
        options.depth_bits = 8;
    }
    options
        .validate()
        .map_err(|e| AppError::Invalid(format!("invalid bake options: {e}")))?;
    check_bake_fits(&state, &options)?;
    let format_name = format.or_else(|| {
        file_name
            .as_deref()
            .and_then(|n| FsPath::new(n).extension())
            .and_then(|e| e.to_str())
            .map(str::to_owned)
    });
    let mesh_format = format_name.as_deref().and_then(MeshFormat::from_extension).ok_or_else(|| {
        AppError::Invalid(format!(
            "unknown mesh format {:?}: name the file with a .gltf .glb .obj .ply .stl or .off extension or send a `format` field",
            format_name.unwrap_or_default()
        ))
    })?;
    let id = id
        .map(|s| s.trim().to_owned())
        .filter(|s| !s.is_empty())
        .unwrap_or_else(|| random_id("mesh"));
    validate_id(&id)?;
    let reservation = state.assets().reserve(&id)?;
    check_store_free(&state, &id).await?;
    let parsed = tokio::task::spawn_blocking(move || {
        load_mesh_from_bytes(&mesh_bytes, mesh_format).map(|mesh| {
            (
                mesh,
                lumigraph_core::bake::sha256_hex(&mesh_bytes),
                mesh_bytes,
            )
        })
    })
    .await
    .map_err(|e| AppError::Internal(e.into()))?;
    let (mesh, mesh_sha256, mesh_bytes) = parsed.map_err(|e| AppError::BadUpload(e.to_string()))?;
    let spec = JobSpec {
        id: state.jobs().fresh_id(|id| state.journal().contains(id)),
        asset: id,
        options,
        format: mesh_format.extension().to_owned(),
        calibrate,
        auto,
        source_name: file_name.unwrap_or_else(|| format!("upload.{}", mesh_format.extension())),
        mesh_bytes: mesh_bytes.len() as u64,
        mesh_sha256,
        created_unix_ms: now_unix_ms(),
    };
    // From here on the work runs to its end even if the client goes away: a job stored in the
    // journal is always in the job list too.
    let starter = state.clone();
    let status = tokio::spawn(async move {
        let journal = starter.journal().clone();
        let stored = spec.clone();
        tokio::task::spawn_blocking(move || journal.write_pending(&stored, &mesh_bytes))
            .await
            .map_err(|e| AppError::Internal(e.into()))?
            .map_err(|e| AppError::Internal(anyhow::Error::new(e).context("storing the job")))?;
        let (job, forgotten) =
            starter
                .jobs()
                .create(spec.id.clone(), spec.asset.clone(), options.cameras);
        starter.forget_jobs(&forgotten);
        let status = job.status();
        let work = BakeWork {
            spec,
            mesh: Some(mesh),
        };
        jobs::spawn(starter, job, reservation, work);
        Ok::<_, AppError>(status)
    })
    .await
    .map_err(|e| AppError::Internal(e.into()))??;
    let location = HeaderValue::from_str(&format!("/v1/jobs/{}", status.id))
        .map_err(|e| AppError::Internal(e.into()))?;
    Ok((
        StatusCode::ACCEPTED,
        [(header::LOCATION, location)],
        Json(status),
    )
        .into_response())
}

/// Progress and result of a bake job. The newest 256 jobs are remembered, across restarts
/// (docs/protocol.md, Bake jobs and the journal).
#[utoipa::path(get, path = "/v1/jobs/{id}", tag = "bake",
    params(("id" = String, Path, description = "job id", pattern = "^[A-Za-z0-9][A-Za-z0-9_-]{0,63}$", min_length = 1, max_length = 64)),
    responses((status = 200, body = JobStatus), (status = 404, body = ErrorBody),
        (status = 422, body = ErrorBody, description = "invalid id")))]
pub async fn get_job(
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> Result<Json<JobStatus>, AppError> {
    validate_id(&id)?;
    let job = state
        .jobs()
        .get(&id)
        .ok_or_else(|| AppError::NotFound(format!("no job with id {id:?}")))?;
    Ok(Json(job.status()))
}

/// Refuses a bake whose asset could not be loaded under the store's limits, before any work:
/// the header the bake will write is checked as an upload's would be (the charge is dropped at
/// once; the finished asset is admitted again when it is loaded).
fn check_bake_fits(state: &AppState, options: &BakeOptions) -> Result<(), AppError> {
    let level = lumigraph_core::geometry::level_for_camera_count(options.cameras)
        .and_then(|l| u8::try_from(l).ok())
        .ok_or_else(|| AppError::Invalid(format!("{} is not a camera count", options.cameras)))?;
    let depth = if options.depth_bits == 8 {
        lumigraph_core::asset::Encoding::R8
    } else {
        lumigraph_core::asset::Encoding::R16
    };
    let frame = lumigraph_core::asset::LfFrame {
        center: [0.0; 3],
        radius: 1.0,
    };
    let mut header = lumigraph_core::asset::AssetHeader::new_spherical(
        level,
        options.resolution,
        frame,
        depth,
        lumigraph_core::asset::Provenance::default(),
    )
    .map_err(|e| AppError::Invalid(format!("invalid bake options: {e}")))?;
    // Light states are charged too: their maps go to the device with the base state's.
    if let Some(count) = options.lights {
        let states = lumigraph_core::light::state_descs(count)
            .map_err(|e| AppError::Invalid(format!("invalid bake options: {e}")))?;
        header.states.extend(states);
    }
    match state.assets().admit(&header) {
        Ok(_charge) => Ok(()),
        Err(LoadError::OverLimit(message)) => Err(AppError::OverLimit(message)),
        Err(LoadError::Busy(message)) => Err(AppError::Unavailable(message)),
        Err(other) => Err(AppError::Invalid(format!("invalid bake options: {other}"))),
    }
}

/// The request's declared `Content-Length`, if any and well-formed.
fn declared_length(headers: &HeaderMap) -> Option<u64> {
    headers
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.parse::<u64>().ok())
}
