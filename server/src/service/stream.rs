//! `/v1/stream`: interactive frame streaming over a WebSocket (protocol: `docs/protocol.md`).
//!
//! Each session runs two tasks joined with `select!`: the receiver parses client messages and
//! publishes the latest wanted frame on a `watch` channel (latest wins: an unrendered request
//! is simply overwritten and counted as dropped), and the sender renders and sends at most
//! `max_in_flight` unacknowledged frames. Nothing queues beyond one request, one frame being
//! rendered and a bounded channel of error messages, so a slow client costs dropped frames,
//! never memory.

use std::collections::BTreeMap;
use std::sync::Arc;
use std::time::{Duration, Instant};

use axum::extract::rejection::QueryRejection;
use axum::extract::ws::{Message, WebSocket, WebSocketUpgrade};
use axum::extract::{Query, State, ws::rejection::WebSocketUpgradeRejection};
use axum::response::Response;
use futures_util::{SinkExt as _, StreamExt as _};
use lumigraph_core::frame::Frame;
use lumigraph_core::render::RenderOptions;
use lumigraph_core::view::View;
use serde::{Deserialize, Serialize};
use tokio::sync::{mpsc, watch};

use super::AppState;
use super::assets::{AssetSummary, LoadedAsset};
use super::error::AppError;
use super::frames::{
    ColorFormat, Encoding, Knobs, Plan, encode_blocking, encode_color, goal_calibration, lod_ladder,
};
use lumigraph_core::calibration::{Calibration, Goal};
use lumigraph_core::lod::Ladder;

/// Version of the stream protocol, sent in `hello`.
pub const PROTOCOL_VERSION: u32 = 1;
/// Bytes of the binary frame header.
pub const FRAME_HEADER_LEN: usize = 40;
/// Largest client message in bytes.
const MAX_CLIENT_MESSAGE: usize = 64 << 10;
/// Error messages buffered for the client; more are dropped.
const ERROR_QUEUE: usize = 16;

/// Query of `GET /v1/stream`.
#[derive(Debug, Deserialize, utoipa::IntoParams)]
#[serde(deny_unknown_fields)]
#[into_params(parameter_in = Query)]
pub struct StreamQuery {
    /// Asset to stream (default: the first asset in id order).
    pub asset: Option<String>,
}

/// Opens a stream session (WebSocket upgrade). 404 for an unknown asset, 503 when the session
/// limit is reached.
#[utoipa::path(get, path = "/v1/stream", tag = "stream",
    params(StreamQuery),
    responses((status = 101, description = "WebSocket; see docs/protocol.md"),
        (status = 404, body = super::error::ErrorBody), (status = 503, body = super::error::ErrorBody)))]
pub async fn stream(
    State(state): State<AppState>,
    query: Result<Query<StreamQuery>, QueryRejection>,
    upgrade: Result<WebSocketUpgrade, WebSocketUpgradeRejection>,
) -> Result<Response, AppError> {
    let Query(query) = query.map_err(|e| AppError::Invalid(e.body_text()))?;
    let asset = match &query.asset {
        Some(id) => state.assets().get(id)?,
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
        .on_upgrade(move |socket| async move {
            state.metrics().sessions_add(1);
            run_session(socket, state.clone(), asset).await;
            state.metrics().sessions_add(-1);
            drop(permit);
        }))
}

/// Sticky per-session settings; each `settings` message overrides the fields it names.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Settings {
    /// Cameras of full-quality frames: 12, 42, 162 or 642 (absent: all of the asset's).
    pub lod: Option<u32>,
    /// March step in bounding-sphere diameters (absent: the method's default).
    pub step: Option<f32>,
    /// Depth tolerance in bounding-sphere diameters (absent: step / 2).
    pub tolerance: Option<f32>,
    /// `default` or `fixed`.
    pub method: Option<lumigraph_core::render::Method>,
    /// Coarse-to-fine factor of the default method (2–16, 0 = off; absent: 4).
    pub guide: Option<u32>,
    /// Codec of full-quality (resting) frames: `png`, `webp` (lossless) or `jpeg`.
    pub still_codec: ColorFormat,
    /// JPEG quality of full-quality frames.
    pub still_quality: u8,
    /// Send reduced frames while the view changes; `false` = every frame at full quality.
    pub interactive: bool,
    /// Codec of interactive frames.
    pub interactive_codec: ColorFormat,
    /// JPEG quality of interactive frames.
    pub interactive_quality: u8,
    /// Fixed resolution scale of interactive frames in [0.1, 1]; absent = chosen from the
    /// measured render speed to hold `target_fps`.
    pub interactive_scale: Option<f32>,
    /// Camera count of interactive frames (absent: the full-quality `lod`).
    pub interactive_lod: Option<u32>,
    /// Frame rate the adaptive interactive scale aims for, 1..=120.
    pub target_fps: f32,
    /// How long the view must rest before the full-quality frame, 0..=10000 ms.
    pub rest_ms: u32,
    /// Frames sent but not acknowledged before the server waits: 1 or 2.
    pub max_in_flight: u32,
    /// RGBA8 where nothing is hit (JPEG: the matte colour).
    pub background: [u8; 4],
    /// Opacity per layer name, in [0, 1].
    pub layers: BTreeMap<String, f32>,
    /// Named state of the asset (lighting, animation frame); absent = the base state.
    pub state: Option<String>,
    /// Full-quality frames use the cheapest setting the asset's calibration predicts to reach
    /// this masked PSNR (dB), chosen per frame size; excludes `lod`/`step`/`tolerance`/`method`.
    #[serde(default)]
    pub target_psnr: Option<f64>,
    /// Full-quality frames use the most accurate setting predicted to render within this many
    /// ms at the frame's size; excludes the knobs and `target_psnr`.
    #[serde(default)]
    pub budget_ms: Option<f64>,
    /// Automatic LOD for every frame (interactive frames, smaller, may take coarser levels):
    /// the bound on the predicted silhouette error in pixels; the knobs stay pinned; excludes
    /// `target_psnr` / `budget_ms`.
    #[serde(default)]
    pub auto_lod: Option<f64>,
    /// With `auto_lod`: only settings whose calibrated masked PSNR reaches this (dB).
    #[serde(default)]
    pub lod_min_psnr: Option<f64>,
    /// With `auto_lod`: only settings within this many dB of the most accurate level (default 2).
    #[serde(default)]
    pub lod_max_psnr_drop: Option<f64>,
    /// With `auto_lod`: cross-fade band below each switch (fraction of the projected size).
    #[serde(default)]
    pub lod_blend: Option<f64>,
}

impl Settings {
    fn defaults(rest: Duration) -> Self {
        Self {
            lod: None,
            step: None,
            tolerance: None,
            method: None,
            guide: None,
            still_codec: ColorFormat::Jpeg,
            still_quality: 90,
            interactive: true,
            interactive_codec: ColorFormat::Jpeg,
            interactive_quality: 50,
            interactive_scale: None,
            interactive_lod: None,
            target_fps: 20.0,
            rest_ms: u32::try_from(rest.as_millis()).unwrap_or(u32::MAX),
            max_in_flight: 2,
            background: [0; 4],
            layers: BTreeMap::new(),
            state: None,
            target_psnr: None,
            budget_ms: None,
            auto_lod: None,
            lod_min_psnr: None,
            lod_max_psnr_drop: None,
            lod_blend: None,
        }
    }
}

/// Settings checked against the asset, with the core options precomputed.
#[derive(Clone, Debug)]
struct Effective {
    settings: Settings,
    still_options: RenderOptions,
    interactive_options: RenderOptions,
    /// Cameras of each kind of frame, for the header.
    still_cameras: u32,
    interactive_cameras: u32,
    /// Opacity of layer 0 (the one rendered), multiplied into alpha.
    opacity: f32,
    /// A quality or time goal for full-quality frames, with the calibration that serves it.
    goal: Option<(Goal, Arc<Calibration>)>,
    /// Automatic LOD for every frame.
    ladder: Option<Arc<Ladder>>,
}

fn validate_settings(settings: Settings, asset: &LoadedAsset) -> Result<Effective, String> {
    let s = &settings;
    for (name, codec) in [
        ("still_codec", s.still_codec),
        ("interactive_codec", s.interactive_codec),
    ] {
        if codec == ColorFormat::None {
            return Err(format!("{name} must be png, jpeg or webp"));
        }
    }
    for (name, q) in [
        ("still_quality", s.still_quality),
        ("interactive_quality", s.interactive_quality),
    ] {
        if !(1..=100).contains(&q) {
            return Err(format!("{name} must be in 1..=100, got {q}"));
        }
    }
    if let Some(scale) = s.interactive_scale
        && !(scale.is_finite() && (0.1..=1.0).contains(&scale))
    {
        return Err(format!(
            "interactive_scale must be in [0.1, 1], got {scale}"
        ));
    }
    if !(s.target_fps.is_finite() && (1.0..=120.0).contains(&s.target_fps)) {
        return Err(format!(
            "target_fps must be in [1, 120], got {}",
            s.target_fps
        ));
    }
    if s.rest_ms > 10_000 {
        return Err(format!("rest_ms must be in 0..=10000, got {}", s.rest_ms));
    }
    if !(1..=2).contains(&s.max_in_flight) {
        return Err(format!(
            "max_in_flight must be 1 or 2, got {}",
            s.max_in_flight
        ));
    }
    let header = &asset.header;
    let mut opacity = header.layers.first().map_or(1.0, |l| l.default_opacity);
    for (name, &value) in &s.layers {
        let Some(index) = header.layers.iter().position(|l| &l.name == name) else {
            let names: Vec<&str> = header.layers.iter().map(|l| l.name.as_str()).collect();
            return Err(format!(
                "the asset has no layer {name:?} (layers: {names:?})"
            ));
        };
        if !(value.is_finite() && (0.0..=1.0).contains(&value)) {
            return Err(format!(
                "opacity of layer {name:?} must be in [0, 1], got {value}"
            ));
        }
        if index == 0 {
            opacity = value;
        }
    }
    if let Some(state) = &s.state {
        match header.states.iter().position(|st| &st.name == state) {
            None => {
                let names: Vec<&str> = header.states.iter().map(|st| st.name.as_str()).collect();
                return Err(format!(
                    "the asset has no state {state:?} (states: {names:?})"
                ));
            }
            Some(0) => {}
            Some(_) => {
                return Err(format!(
                    "rendering state {state:?} is not supported yet: only the base state renders"
                ));
            }
        }
    }
    let knobs = Knobs {
        lod: s.lod,
        step: s.step,
        tolerance: s.tolerance,
        method: s.method,
        guide: s.guide,
    };
    let ladder = lod_ladder(
        s.auto_lod,
        s.lod_min_psnr,
        s.lod_max_psnr_drop,
        s.lod_blend,
        &knobs,
        s.target_psnr.is_some() || s.budget_ms.is_some(),
        asset,
    )
    .map_err(|e| e.to_string())?;
    let goal =
        goal_calibration(s.target_psnr, s.budget_ms, &knobs, asset).map_err(|e| e.to_string())?;
    if let Some((goal, calibration)) = &goal {
        // Checks the goal's value now rather than at the first frame.
        calibration
            .choose(*goal, 64, 64, asset.header.geometry.camera_count)
            .map_err(|e| e.to_string())?;
    }
    let still_options = knobs.to_options(asset).map_err(|e| e.to_string())?;
    let interactive_options = Knobs {
        lod: s.interactive_lod.or(s.lod),
        ..knobs
    }
    .to_options(asset)
    .map_err(|e| e.to_string())?;
    let cameras = |o: &RenderOptions| o.resolve(asset.field.max_level).map_or(0, |r| r.cameras);
    Ok(Effective {
        still_cameras: cameras(&still_options),
        interactive_cameras: cameras(&interactive_options),
        still_options,
        interactive_options,
        opacity,
        settings,
        goal,
        ladder,
    })
}

/// What the sender should show next: the latest view and settings.
#[derive(Clone, Debug)]
struct Wanted {
    /// Bumped by every accepted view or settings message.
    seq: u64,
    /// View messages accepted so far (for dropped-frame accounting).
    views: u64,
    /// The request id of the latest view.
    request_id: u32,
    view: Option<View>,
    /// Skip the interactive frame for this view.
    still: bool,
    /// When the latest view or settings change arrived (the rest timer starts here).
    arrived: Instant,
    effective: Arc<Effective>,
}

/// Client messages (`type` selects the variant; see docs/protocol.md).
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ViewMessage {
    id: u32,
    view: View,
    #[serde(default)]
    still: bool,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct AckMessage {
    frame: u32,
}

#[derive(Serialize)]
struct ErrorMessage<'a> {
    r#type: &'static str,
    request: Option<u32>,
    kind: &'a str,
    message: &'a str,
}

fn error_text(request: Option<u32>, kind: &str, message: &str) -> String {
    serde_json::to_string(&ErrorMessage {
        r#type: "error",
        request,
        kind,
        message,
    })
    .unwrap_or_default()
}

#[derive(Serialize)]
struct Hello<'a> {
    r#type: &'static str,
    protocol: u32,
    asset: AssetSummary,
    settings: &'a Settings,
    max_px: u32,
    header_len: usize,
}

async fn run_session(socket: WebSocket, state: AppState, asset: Arc<LoadedAsset>) {
    let (mut sink, mut source) = socket.split();
    let defaults = Settings::defaults(state.config().rest_delay);
    let effective = match validate_settings(defaults, &asset) {
        Ok(e) => Arc::new(e),
        Err(message) => {
            let _ = sink
                .send(Message::Text(error_text(None, "internal", &message).into()))
                .await;
            return;
        }
    };
    let hello = Hello {
        r#type: "hello",
        protocol: PROTOCOL_VERSION,
        asset: asset.summary(),
        settings: &effective.settings,
        max_px: state.config().max_px,
        header_len: FRAME_HEADER_LEN,
    };
    let Ok(hello) = serde_json::to_string(&hello) else {
        return;
    };
    if sink.send(Message::Text(hello.into())).await.is_err() {
        return;
    }
    let wanted = Wanted {
        seq: 0,
        views: 0,
        request_id: 0,
        view: None,
        still: false,
        arrived: Instant::now(),
        effective,
    };
    let (wanted_tx, wanted_rx) = watch::channel(wanted);
    let (ack_tx, ack_rx) = watch::channel(0u32);
    let (error_tx, error_rx) = mpsc::channel::<String>(ERROR_QUEUE);
    let receiver = receive_loop(&mut source, &state, &asset, &wanted_tx, &ack_tx, &error_tx);
    let sender = Sender {
        state: &state,
        asset: &asset,
        sink: &mut sink,
        wanted: wanted_rx,
        acked: ack_rx,
        errors: error_rx,
        shutdown: state.shutdown_signal(),
        frame_id: 0,
        dropped: 0,
        ms_per_mpx: None,
    };
    tokio::select! {
        () = receiver => {}
        () = sender.run() => {}
    }
    let _ = sink.send(Message::Close(None)).await;
    let _ = sink.close().await;
}

async fn receive_loop(
    source: &mut futures_util::stream::SplitStream<WebSocket>,
    state: &AppState,
    asset: &LoadedAsset,
    wanted: &watch::Sender<Wanted>,
    acked: &watch::Sender<u32>,
    errors: &mpsc::Sender<String>,
) {
    let report = |request: Option<u32>, kind: &str, message: &str| {
        state.metrics().error(kind);
        // A client that does not read its errors loses some; it never grows a queue.
        let _ = errors.try_send(error_text(request, kind, message));
    };
    while let Some(message) = source.next().await {
        let text = match message {
            Ok(Message::Text(text)) => text,
            Ok(Message::Binary(_)) => {
                report(
                    None,
                    "bad_message",
                    "binary messages are not accepted: send JSON text",
                );
                continue;
            }
            Ok(Message::Close(_)) | Err(_) => return,
            Ok(Message::Ping(_) | Message::Pong(_)) => continue,
        };
        let mut value: serde_json::Value = match serde_json::from_str(text.as_str()) {
            Ok(v) => v,
            Err(e) => {
                report(None, "malformed_json", &format!("malformed JSON: {e}"));
                continue;
            }
        };
        let request = value
            .get("id")
            .and_then(serde_json::Value::as_u64)
            .and_then(|v| u32::try_from(v).ok());
        let kind = value
            .as_object_mut()
            .and_then(|o| o.remove("type"))
            .and_then(|t| t.as_str().map(str::to_owned));
        match kind.as_deref() {
            Some("view") => match serde_json::from_value::<ViewMessage>(value) {
                Ok(message) => {
                    if let Err(e) = message.view.basis(state.config().max_px) {
                        report(Some(message.id), "invalid", &e.to_string());
                        continue;
                    }
                    wanted.send_modify(|w| {
                        w.seq += 1;
                        w.views += 1;
                        w.request_id = message.id;
                        w.view = Some(message.view);
                        w.still = message.still;
                        w.arrived = Instant::now();
                    });
                }
                Err(e) => report(request, "invalid", &format!("invalid view message: {e}")),
            },
            Some("settings") => {
                let current = wanted.borrow().effective.settings.clone();
                match merge_settings(&current, value).and_then(|s| validate_settings(s, asset)) {
                    Ok(effective) => wanted.send_modify(|w| {
                        w.seq += 1;
                        w.arrived = Instant::now();
                        w.effective = Arc::new(effective);
                    }),
                    Err(message) => report(request, "invalid", &message),
                }
            }
            Some("ack") => match serde_json::from_value::<AckMessage>(value) {
                Ok(ack) => {
                    acked.send_if_modified(|last| {
                        let newer = ack.frame > *last;
                        if newer {
                            *last = ack.frame;
                        }
                        newer
                    });
                }
                Err(e) => report(request, "invalid", &format!("invalid ack message: {e}")),
            },
            Some(other) => report(
                request,
                "invalid",
                &format!("unknown message type {other:?}: use view, settings or ack"),
            ),
            None => report(
                request,
                "invalid",
                "a message needs a string field `type` (view, settings or ack)",
            ),
        }
    }
}

/// Applies the fields of a `settings` message to `current`.
fn merge_settings(current: &Settings, patch: serde_json::Value) -> Result<Settings, String> {
    let serde_json::Value::Object(patch) = patch else {
        return Err("a settings message must be a JSON object".to_owned());
    };
    let mut merged = serde_json::to_value(current).map_err(|e| e.to_string())?;
    if let serde_json::Value::Object(merged) = &mut merged {
        for (key, value) in patch {
            merged.insert(key, value);
        }
    }
    serde_json::from_value(merged).map_err(|e| format!("invalid settings: {e}"))
}

/// Quality level of a frame, as in the header.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Quality {
    Interactive = 0,
    Full = 1,
}

struct Sender<'a> {
    state: &'a AppState,
    asset: &'a Arc<LoadedAsset>,
    sink: &'a mut futures_util::stream::SplitSink<WebSocket, Message>,
    wanted: watch::Receiver<Wanted>,
    acked: watch::Receiver<u32>,
    errors: mpsc::Receiver<String>,
    shutdown: watch::Receiver<bool>,
    frame_id: u32,
    dropped: u64,
    /// Measured interactive render cost, milliseconds per megapixel (moving average).
    ms_per_mpx: Option<f64>,
}

enum Wake {
    Changed,
    Rested,
    Error(String),
    Closed,
}

impl Sender<'_> {
    async fn run(mut self) {
        // Sequence numbers of the last frame sent and of the last full-quality frame sent.
        let mut sent_seq = 0u64;
        let mut full_seq = 0u64;
        let mut rendered_views = 0u64;
        loop {
            if *self.shutdown.borrow() {
                break;
            }
            let want = self.wanted.borrow_and_update().clone();
            let in_flight = self
                .frame_id
                .saturating_sub(*self.acked.borrow_and_update());
            let window_open = in_flight < want.effective.settings.max_in_flight;
            let mut rest_deadline = None;
            if let (Some(view), true) = (&want.view, window_open) {
                let interactive = want.effective.settings.interactive && !want.still;
                if want.seq > sent_seq {
                    let skipped = want.views.saturating_sub(rendered_views + 1);
                    if skipped > 0 {
                        self.dropped += skipped;
                        self.state.metrics().dropped(skipped);
                    }
                    rendered_views = want.views;
                    let quality = if interactive {
                        Quality::Interactive
                    } else {
                        Quality::Full
                    };
                    if !self.send_frame(&want, view, quality).await {
                        break;
                    }
                    sent_seq = want.seq;
                    if quality == Quality::Full {
                        full_seq = want.seq;
                    }
                    continue;
                }
                if full_seq < want.seq {
                    let rest = Duration::from_millis(u64::from(want.effective.settings.rest_ms));
                    rest_deadline = Some(tokio::time::Instant::from_std(want.arrived + rest));
                }
            }
            match self.wait(rest_deadline).await {
                Wake::Changed => {}
                Wake::Rested => {
                    let want = self.wanted.borrow().clone();
                    if want.seq == sent_seq {
                        if let Some(view) = &want.view
                            && !self.send_frame(&want, view, Quality::Full).await
                        {
                            break;
                        }
                        full_seq = want.seq;
                    }
                }
                Wake::Error(text) => {
                    if self.sink.send(Message::Text(text.into())).await.is_err() {
                        break;
                    }
                }
                Wake::Closed => break,
            }
        }
        let unrendered = self.wanted.borrow().views.saturating_sub(rendered_views);
        if unrendered > 0 {
            self.state.metrics().dropped(unrendered);
        }
    }

    async fn wait(&mut self, rest_deadline: Option<tokio::time::Instant>) -> Wake {
        let rest = async {
            match rest_deadline {
                Some(deadline) => tokio::time::sleep_until(deadline).await,
                None => std::future::pending::<()>().await,
            }
        };
        tokio::select! {
            changed = self.wanted.changed() => if changed.is_ok() { Wake::Changed } else { Wake::Closed },
            changed = self.acked.changed() => if changed.is_ok() { Wake::Changed } else { Wake::Closed },
            changed = self.shutdown.changed() => if changed.is_ok() { Wake::Changed } else { Wake::Closed },
            error = self.errors.recv() => error.map_or(Wake::Closed, Wake::Error),
            () = rest => Wake::Rested,
        }
    }

    /// Renders, encodes and sends one frame; false when the socket is gone.
    async fn send_frame(&mut self, want: &Wanted, view: &View, quality: Quality) -> bool {
        let effective = &want.effective;
        let settings = &effective.settings;
        let (mut view, options, encoding, cameras) = match quality {
            Quality::Interactive => (
                view.clone(),
                effective.interactive_options,
                Encoding {
                    format: settings.interactive_codec,
                    quality: settings.interactive_quality,
                    background: settings.background,
                },
                effective.interactive_cameras,
            ),
            Quality::Full => (
                view.clone(),
                effective.still_options,
                Encoding {
                    format: settings.still_codec,
                    quality: settings.still_quality,
                    background: settings.background,
                },
                effective.still_cameras,
            ),
        };
        let (options, cameras) = match (&effective.goal, quality) {
            (Some((goal, calibration)), Quality::Full) => match calibration.choose(
                *goal,
                view.width,
                view.height,
                self.asset.header.geometry.camera_count,
            ) {
                Ok(choice) => (choice.options(), choice.cameras),
                Err(_) => (options, cameras),
            },
            _ => (options, cameras),
        };
        if quality == Quality::Interactive {
            let scale = settings.interactive_scale.map_or_else(
                || self.adaptive_scale(&view, settings.target_fps),
                f64::from,
            );
            view.width = ((f64::from(view.width) * scale).round() as u32).max(1);
            view.height = ((f64::from(view.height) * scale).round() as u32).max(1);
        }
        let plan = match &effective.ladder {
            Some(ladder) => Plan::Lod(Arc::clone(ladder)),
            None => Plan::Options(options),
        };
        let rendered = match self
            .state
            .pool()
            .render(Arc::clone(self.asset), view, plan)
            .await
        {
            Ok(r) => r,
            Err(err) => {
                self.state.metrics().error(err.kind());
                let message = if matches!(err, AppError::Internal(_)) {
                    tracing::error!(error = format!("{err:#}"), "stream render failed");
                    "render failed (details are in the server log)".to_owned()
                } else {
                    err.to_string()
                };
                let text = error_text(Some(want.request_id), err.kind(), &message);
                return self.sink.send(Message::Text(text.into())).await.is_ok();
            }
        };
        let pixels_mpx = f64::from(rendered.frame.width) * f64::from(rendered.frame.height) / 1e6;
        if quality == Quality::Interactive && pixels_mpx > 0.0 {
            let sample = rendered.render_ms / pixels_mpx;
            self.ms_per_mpx = Some(
                self.ms_per_mpx
                    .map_or(sample, |old| 0.7 * old + 0.3 * sample),
            );
        }
        let lod_cameras = rendered.lod.map(|d| d.level.cameras);
        let opacity = effective.opacity;
        let mut frame = rendered.frame;
        let encoded = encode_blocking(move || {
            apply_opacity(&mut frame, opacity);
            let bytes = encode_color(&frame, encoding).map_err(|e| {
                AppError::Internal(anyhow::Error::new(e).context("encoding a frame"))
            })?;
            Ok((bytes, frame.width, frame.height))
        })
        .await;
        let ((bytes, width, height), encode_ms) = match encoded {
            Ok(ok) => ok,
            Err(err) => {
                tracing::error!(error = format!("{err:#}"), "stream encode failed");
                let text = error_text(
                    Some(want.request_id),
                    "internal",
                    "encoding the frame failed",
                );
                return self.sink.send(Message::Text(text.into())).await.is_ok();
            }
        };
        self.frame_id += 1;
        let header = FrameHeader {
            codec: encoding.format,
            quality,
            frame_id: self.frame_id,
            request_id: want.request_id,
            width,
            height,
            render_ms: rendered.render_ms as f32,
            encode_ms: encode_ms as f32,
            dropped: u32::try_from(self.dropped).unwrap_or(u32::MAX),
            cameras: u16::try_from(lod_cameras.unwrap_or(cameras)).unwrap_or(u16::MAX),
        };
        let mut message = Vec::with_capacity(FRAME_HEADER_LEN + bytes.len());
        header.write(&mut message);
        message.extend_from_slice(&bytes);
        let quality_name = if quality == Quality::Full {
            "full"
        } else {
            "interactive"
        };
        self.state.metrics().frame(
            "stream",
            quality_name,
            message.len(),
            rendered.render_ms,
            encode_ms,
            encoding.format.name(),
        );
        self.sink
            .send(Message::Binary(message.into()))
            .await
            .is_ok()
    }

    /// Resolution scale that keeps an interactive frame within the frame budget of `target_fps`.
    fn adaptive_scale(&self, view: &View, target_fps: f32) -> f64 {
        let Some(ms_per_mpx) = self.ms_per_mpx.filter(|v| *v > 0.0) else {
            return 0.5;
        };
        let budget_ms = 1000.0 / f64::from(target_fps);
        let full_mpx = f64::from(view.width) * f64::from(view.height) / 1e6;
        let scale = (budget_ms / ms_per_mpx / full_mpx).sqrt();
        // Quantized so small speed changes do not change the frame size every frame.
        ((scale.clamp(0.25, 1.0) * 8.0).floor() / 8.0).max(0.25)
    }
}

fn apply_opacity(frame: &mut Frame, opacity: f32) {
    if opacity >= 1.0 {
        return;
    }
    for px in frame.color.chunks_exact_mut(4) {
        px[3] = (f32::from(px[3]) * opacity).round() as u8;
    }
}

/// The 40-byte little-endian header in front of every binary frame (docs/protocol.md).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameHeader {
    /// Image codec.
    pub codec: ColorFormat,
    quality: Quality,
    /// Frame id, 1, 2, 3... per session.
    pub frame_id: u32,
    /// The `id` of the view message this frame answers.
    pub request_id: u32,
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Render time, ms.
    pub render_ms: f32,
    /// Encode time, ms.
    pub encode_ms: f32,
    /// View requests dropped so far in this session.
    pub dropped: u32,
    /// Cameras used.
    pub cameras: u16,
}

impl FrameHeader {
    fn write(&self, out: &mut Vec<u8>) {
        out.extend_from_slice(b"LGF1");
        out.extend_from_slice(&(FRAME_HEADER_LEN as u16).to_le_bytes());
        out.push(match self.codec {
            ColorFormat::Png => 0,
            ColorFormat::Jpeg => 1,
            ColorFormat::Webp => 2,
            ColorFormat::None => 255,
        });
        out.push(self.quality as u8);
        out.extend_from_slice(&self.frame_id.to_le_bytes());
        out.extend_from_slice(&self.request_id.to_le_bytes());
        out.extend_from_slice(&self.width.to_le_bytes());
        out.extend_from_slice(&self.height.to_le_bytes());
        out.extend_from_slice(&self.render_ms.to_le_bytes());
        out.extend_from_slice(&self.encode_ms.to_le_bytes());
        out.extend_from_slice(&self.dropped.to_le_bytes());
        out.extend_from_slice(&self.cameras.to_le_bytes());
        out.extend_from_slice(&0u16.to_le_bytes());
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn header_is_40_bytes() {
        let header = FrameHeader {
            codec: ColorFormat::Jpeg,
            quality: Quality::Full,
            frame_id: 7,
            request_id: 9,
            width: 64,
            height: 32,
            render_ms: 1.5,
            encode_ms: 0.25,
            dropped: 3,
            cameras: 162,
        };
        let mut out = Vec::new();
        header.write(&mut out);
        assert_eq!(out.len(), FRAME_HEADER_LEN);
        assert_eq!(&out[..4], b"LGF1");
        assert_eq!(out[6], 1);
        assert_eq!(out[7], 1);
        assert_eq!(u32::from_le_bytes([out[8], out[9], out[10], out[11]]), 7);
        assert_eq!(u16::from_le_bytes([out[36], out[37]]), 162);
    }

    #[test]
    fn settings_merge_keeps_unnamed_fields() {
        let current = Settings::defaults(Duration::from_millis(250));
        let merged = merge_settings(
            &current,
            serde_json::json!({"lod": 42, "still_codec": "png"}),
        )
        .unwrap();
        assert_eq!(merged.lod, Some(42));
        assert_eq!(merged.still_codec, ColorFormat::Png);
        assert_eq!(merged.interactive_quality, 50);
        assert!(merge_settings(&current, serde_json::json!({"bogus": 1})).is_err());
    }
}
