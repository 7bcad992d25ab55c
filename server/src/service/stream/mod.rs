//! `/v1/stream`: interactive frame streaming over a WebSocket (protocol: `docs/protocol.md`).
//!
//! Each session runs two tasks joined with `select!`: the receiver parses client messages and
//! publishes the latest wanted frame on a `watch` channel (latest wins: an unrendered request
//! is simply overwritten and counted as dropped), and the sender renders and sends at most
//! `max_in_flight` unacknowledged frames. Nothing queues beyond one request, one frame being
//! rendered and a bounded channel of error messages, so a slow client costs dropped frames,
//! never memory.

mod adapt;
mod protocol;
mod session;
mod settings;

use std::sync::Arc;

use axum::extract::rejection::QueryRejection;
use axum::extract::ws::WebSocketUpgrade;
use axum::extract::{Query, State, ws::rejection::WebSocketUpgradeRejection};
use axum::response::Response;
use serde::Deserialize;

use super::error::AppError;
use super::state::AppState;

pub use protocol::{
    DEPTH_CODEC_PNG16, DEPTH_EXTENSION_LEN, DepthExtension, FRAME_HEADER_LEN, FrameError,
    FrameHeader, PROTOCOL_VERSION, ParsedFrame, decode_depth, parse_frame,
};
pub use settings::Settings;

/// Largest client message (and frame) in bytes: a larger one closes the session with 1009
/// before it is read whole.
const MAX_CLIENT_MESSAGE: usize = 64 << 10;

/// Parses and validates one client text message exactly as a new session on an asset with
/// `header` would (default settings, views up to `max_px`), without a session or a device: the
/// checks of the receive loop, for tests and fuzzing. `Err` holds the error message the client
/// would get.
///
/// # Errors
/// The refusal's message.
pub fn check_client_message(
    text: &str,
    header: &lumigraph_core::asset::AssetHeader,
    max_px: u32,
) -> Result<(), String> {
    let defaults = Settings::defaults(std::time::Duration::from_millis(250));
    match protocol::parse_client_message(text, max_px).map_err(|r| r.message)? {
        protocol::ClientMessage::Settings { patch, .. } => {
            settings::merge_settings(&defaults, patch)
                .and_then(|s| settings::validate_settings(s, header))?;
            Ok(())
        }
        protocol::ClientMessage::View(_) | protocol::ClientMessage::Ack(_) => Ok(()),
    }
}

/// Query of `GET /v1/stream`.
#[derive(Debug, Deserialize, utoipa::IntoParams)]
#[serde(deny_unknown_fields)]
#[into_params(parameter_in = Query)]
pub struct StreamQuery {
    /// Asset to stream (default: the first asset in id order).
    #[param(
        pattern = "^[A-Za-z0-9][A-Za-z0-9_-]{0,63}$",
        min_length = 1,
        max_length = 64
    )]
    pub asset: Option<String>,
}

/// Opens a stream session (WebSocket upgrade). 404 for an unknown asset, 503 when the session
/// limit is reached.
#[utoipa::path(get, path = "/v1/stream", tag = "stream",
    params(StreamQuery),
    responses((status = 101, description = "WebSocket; see docs/protocol.md"),
        (status = 400, body = super::error::ErrorBody, description = "not a WebSocket upgrade request"),
        (status = 404, body = super::error::ErrorBody),
        (status = 422, body = super::error::ErrorBody, description = "invalid query or asset id"),
        (status = 503, body = super::error::ErrorBody)))]
pub async fn stream(
    State(state): State<AppState>,
    query: Result<Query<StreamQuery>, QueryRejection>,
    upgrade: Result<WebSocketUpgrade, WebSocketUpgradeRejection>,
) -> Result<Response, AppError> {
    let Query(query) = query.map_err(|e| AppError::Invalid(e.body_text()))?;
    let asset = match &query.asset {
        Some(id) => state.asset(id).await?,
        None => state.assets().first().ok_or_else(|| {
            if state.is_ready() {
                AppError::NotFound("no asset is loaded".to_owned())
            } else {
                AppError::Unavailable("loading assets; retry shortly".to_owned())
            }
        })?,
    };
    let upgrade = upgrade.map_err(|e| AppError::Rejected {
        status: e.status(),
        message: e.body_text(),
    })?;
    let permit = Arc::clone(&state.inner.sessions)
        .try_acquire_owned()
        .map_err(|_| {
            AppError::Unavailable(format!(
                "the session limit of {} concurrent streams is reached; retry later",
                state.config().max_sessions
            ))
        })?;
    Ok(upgrade
        .max_message_size(MAX_CLIENT_MESSAGE)
        .max_frame_size(MAX_CLIENT_MESSAGE)
        .on_upgrade(move |socket| async move {
            state.metrics().sessions_add(1);
            session::run_session(socket, state.clone(), asset).await;
            state.metrics().sessions_add(-1);
            drop(permit);
        }))
}
