//! One session's tasks: the receiver that parses client messages into the wanted frame, and the
//! sender that renders, encodes and sends frames.

use std::sync::{Arc, Mutex, PoisonError, Weak};
use std::time::{Duration, Instant};

use axum::extract::ws::{CloseFrame, Message, WebSocket, close_code};
use futures_util::{SinkExt as _, StreamExt as _};
use lumigraph_core::asset::AssetHeader;
use lumigraph_core::view::View;
use tokio::sync::{mpsc, watch};

use super::adapt::{self, LinkEstimator};
use super::protocol::{
    AnimationStamp, ClientMessage, DepthExtension, FRAME_HEADER_LEN, FrameHeader, Hello,
    PROTOCOL_VERSION, Quality, error_text, parse_client_message,
};
use super::settings::{Effective, Settings, merge_settings, validate_settings};
use crate::service::assets::LoadedAsset;
use crate::service::codecs::{
    ColorFormat, DepthFormat, Encoding, encode_blocking, encode_color, encode_depth,
};
use crate::service::error::AppError;
use crate::service::state::AppState;

use super::MAX_CLIENT_MESSAGE;

/// Error messages buffered for the client; more are dropped.
const ERROR_QUEUE: usize = 16;

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

pub(super) async fn run_session(socket: WebSocket, state: AppState, asset: Arc<LoadedAsset>) {
    let (mut sink, mut source) = socket.split();
    // The session keeps the header and a weak reference: an asset deleted while a viewer is
    // open is freed at once, and the session ends at its next frame.
    let header = asset.header.clone();
    let summary = asset.summary();
    let weak = Arc::downgrade(&asset);
    drop(asset);
    let asset = weak;
    let defaults = Settings::defaults(state.config().rest_delay);
    let effective = match validate_settings(defaults, &header) {
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
        asset: summary,
        settings: effective.settings.to_json(),
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
    let link = Mutex::new(LinkEstimator::default());
    let receiver = receive_loop(
        &mut source,
        &state,
        &header,
        &wanted_tx,
        &ack_tx,
        &error_tx,
        &link,
    );
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
        link: &link,
        jpeg_bytes_per_px_q50: None,
        depth_bytes_per_px: None,
        generation: state.pool().engine().generation,
        play_start: None,
    };
    let close = tokio::select! {
        close = receiver => close,
        () = sender.run() => state
            .is_shutting_down()
            .then(|| close_frame(close_code::AWAY, "the server is shutting down")),
    };
    // A client that closed first has had its close frame answered by the WebSocket layer.
    if let Some(close) = close {
        let _ = sink.send(Message::Close(Some(close))).await;
    }
    let _ = sink.close().await;
}

fn close_frame(code: u16, reason: &str) -> CloseFrame {
    CloseFrame {
        code,
        reason: reason.into(),
    }
}

/// The close frame that answers a failed read: 1009 for a message or frame over the limit,
/// 1002 for a protocol violation, 1007 for text that is not UTF-8; none when the connection
/// itself broke (nothing could be delivered).
fn close_for_error(err: axum::Error) -> Option<CloseFrame> {
    use tungstenite::error::{CapacityError, Error};
    let inner = err.into_inner();
    match inner.downcast_ref::<Error>()? {
        Error::Capacity(CapacityError::MessageTooLong { .. }) => Some(close_frame(
            close_code::SIZE,
            &format!("messages are limited to {MAX_CLIENT_MESSAGE} bytes"),
        )),
        Error::Capacity(_) => Some(close_frame(close_code::SIZE, "message too large")),
        Error::Protocol(e) => Some(close_frame(
            close_code::PROTOCOL,
            &format!("WebSocket protocol error: {e}"),
        )),
        Error::Utf8(_) => Some(close_frame(close_code::INVALID, "text is not UTF-8")),
        _ => None,
    }
}

/// Reads client messages until the client closes (`None`: nothing more to send), a read fails
/// or the session goes idle for the configured time (the close frame to send).
async fn receive_loop(
    source: &mut futures_util::stream::SplitStream<WebSocket>,
    state: &AppState,
    header: &AssetHeader,
    wanted: &watch::Sender<Wanted>,
    acked: &watch::Sender<u32>,
    errors: &mpsc::Sender<String>,
    link: &Mutex<LinkEstimator>,
) -> Option<CloseFrame> {
    let report = |request: Option<u32>, kind: &str, message: &str| {
        state.metrics().error(kind);
        // A client that does not read its errors loses some; it never grows a queue.
        let _ = errors.try_send(error_text(request, kind, message));
    };
    let idle = state.config().stream_idle_timeout;
    loop {
        let Ok(message) = tokio::time::timeout(idle, source.next()).await else {
            return Some(close_frame(
                close_code::POLICY,
                &format!(
                    "idle: no message for {} s; reconnect to continue",
                    idle.as_secs_f64()
                ),
            ));
        };
        let text = match message {
            None | Some(Ok(Message::Close(_))) => return None,
            Some(Err(err)) => return close_for_error(err),
            Some(Ok(Message::Text(text))) => text,
            Some(Ok(Message::Binary(_))) => {
                report(
                    None,
                    "bad_message",
                    "binary messages are not accepted: send JSON text",
                );
                continue;
            }
            Some(Ok(Message::Ping(_) | Message::Pong(_))) => continue,
        };
        match parse_client_message(text.as_str(), state.config().max_px) {
            Err(refusal) => report(refusal.request, refusal.kind, &refusal.message),
            Ok(ClientMessage::View(message)) => wanted.send_modify(|w| {
                w.seq += 1;
                w.views += 1;
                w.request_id = message.id;
                w.view = Some(message.view);
                w.still = message.still;
                w.arrived = Instant::now();
            }),
            Ok(ClientMessage::Settings { request, patch }) => {
                let current = wanted.borrow().effective.settings.clone();
                match merge_settings(&current, patch).and_then(|s| validate_settings(s, header)) {
                    Ok(effective) => wanted.send_modify(|w| {
                        w.seq += 1;
                        w.arrived = Instant::now();
                        w.effective = Arc::new(effective);
                    }),
                    Err(message) => report(request, "invalid", &message),
                }
            }
            Ok(ClientMessage::Ack(ack)) => {
                link.lock().unwrap_or_else(PoisonError::into_inner).on_ack(
                    ack.frame,
                    ack.received_ms,
                    Instant::now(),
                );
                acked.send_if_modified(|last| {
                    let newer = ack.frame > *last;
                    if newer {
                        *last = ack.frame;
                    }
                    newer
                });
            }
        }
    }
}

struct Sender<'a> {
    state: &'a AppState,
    asset: &'a Weak<LoadedAsset>,
    sink: &'a mut futures_util::stream::SplitSink<WebSocket, Message>,
    wanted: watch::Receiver<Wanted>,
    acked: watch::Receiver<u32>,
    errors: mpsc::Receiver<String>,
    shutdown: watch::Receiver<bool>,
    frame_id: u32,
    dropped: u64,
    /// Measured interactive render cost, milliseconds per megapixel (moving average).
    ms_per_mpx: Option<f64>,
    /// The link's estimate, fed by the receiver's acks.
    link: &'a Mutex<LinkEstimator>,
    /// Measured interactive JPEG size, bytes per pixel normalised to quality 50 (moving
    /// average).
    jpeg_bytes_per_px_q50: Option<f64>,
    /// Measured depth-image size of frames with the depth extension, bytes per pixel (moving
    /// average; `None` until one was sent; counted only while the `depth` setting is on).
    depth_bytes_per_px: Option<f64>,
    /// The engine generation when the session started (a later one: the device was replaced).
    generation: u64,
    /// When the animation started playing (`None`: not playing).
    play_start: Option<Instant>,
}

enum Wake {
    Changed,
    Rested,
    /// The next animation frame is due.
    Tick,
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
            // Errors go out before the next frame: a refused message the client sent before a
            // view is answered before that view's frame, in the order the client sent them.
            if !self.send_queued_errors().await {
                break;
            }
            let want = self.wanted.borrow_and_update().clone();
            let in_flight = self
                .frame_id
                .saturating_sub(*self.acked.borrow_and_update());
            let window_open = in_flight < want.effective.settings.max_in_flight;
            let playing = want.effective.settings.playing && want.effective.animation.is_some();
            match (playing, self.play_start) {
                (true, None) => self.play_start = Some(Instant::now()),
                (false, Some(_)) => self.play_start = None,
                _ => {}
            }
            // While playing, the next frame of the animation is due at the next multiple of the
            // frame period since the start (a frame the window cannot take is skipped).
            let tick_deadline = match (&want.effective.animation, self.play_start, &want.view) {
                (Some(animation), Some(start), Some(_)) if window_open => {
                    let period = 1.0 / animation.fps;
                    let next = ((start.elapsed().as_secs_f64() / period).floor() + 1.0) * period;
                    Some(tokio::time::Instant::from_std(
                        start + Duration::from_secs_f64(next),
                    ))
                }
                _ => None,
            };
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
            match self.wait(rest_deadline, tick_deadline).await {
                Wake::Changed => {}
                Wake::Tick => {
                    let want = self.wanted.borrow().clone();
                    if let Some(view) = &want.view {
                        // A resting view gets full-quality frames, a moving one interactive.
                        let quality = if full_seq == want.seq && sent_seq == want.seq {
                            Quality::Full
                        } else {
                            Quality::Interactive
                        };
                        if !self.send_frame(&want, view, quality).await {
                            break;
                        }
                    }
                }
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

    /// The plan of the animation frame to show (the one playing now, on the server's clock)
    /// and its stamp for the header; for an asset without an animation, `plan` unchanged.
    fn animation_frame(
        &self,
        effective: &Effective,
        plan: lumigraph_core::quality::Plan,
    ) -> (lumigraph_core::quality::Plan, Option<AnimationStamp>) {
        let Some(animation) = &effective.animation else {
            return (plan, None);
        };
        let stamp = |frame: usize| AnimationStamp {
            frame: u32::try_from(frame).unwrap_or(u32::MAX),
            time: (frame as f64 / animation.fps) as f32,
        };
        if let (true, Some(start)) = (effective.settings.playing, self.play_start) {
            let count = animation.states.len().max(1) as u64;
            let frame = ((start.elapsed().as_secs_f64() * animation.fps + 1e-6).floor() as u64
                % count) as usize;
            let state = animation.states.get(frame).copied();
            return (plan.with_state(state), Some(stamp(frame)));
        }
        let shown = plan.state().unwrap_or(0);
        let frame = animation.states.iter().position(|&s| s == shown);
        (plan, frame.map(stamp))
    }

    /// Sends the errors already queued; false when the socket is gone.
    async fn send_queued_errors(&mut self) -> bool {
        while let Ok(text) = self.errors.try_recv() {
            if self.sink.send(Message::Text(text.into())).await.is_err() {
                return false;
            }
        }
        true
    }

    async fn wait(
        &mut self,
        rest_deadline: Option<tokio::time::Instant>,
        tick_deadline: Option<tokio::time::Instant>,
    ) -> Wake {
        let rest = async {
            match rest_deadline {
                Some(deadline) => tokio::time::sleep_until(deadline).await,
                None => std::future::pending::<()>().await,
            }
        };
        let tick = async {
            match tick_deadline {
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
            () = tick => Wake::Tick,
        }
    }

    /// Renders, encodes and sends one frame; false when the socket is gone.
    async fn send_frame(&mut self, want: &Wanted, view: &View, quality: Quality) -> bool {
        let effective = &want.effective;
        let settings = &effective.settings;
        let (mut view, plan, mut encoding) = match quality {
            Quality::Interactive => (
                view.clone(),
                effective.motion.clone(),
                Encoding {
                    format: settings.interactive_codec,
                    quality: settings.interactive_quality,
                    background: settings.background,
                },
            ),
            Quality::Full => (
                view.clone(),
                effective.still.clone(),
                Encoding {
                    format: settings.still_codec,
                    quality: settings.still_quality,
                    background: settings.background,
                },
            ),
        };
        let link_bytes_per_s = if settings.adaptive {
            self.link
                .lock()
                .unwrap_or_else(PoisonError::into_inner)
                .bytes_per_s()
        } else {
            None
        };
        let mut flags = 0u8;
        // The link a lossless resting frame must arrive over in time, else it is sent as JPEG.
        let lossless_link = link_bytes_per_s
            .filter(|_| quality == Quality::Full && encoding.format != ColorFormat::Jpeg);
        if quality == Quality::Interactive {
            let best_scale = settings.interactive_scale.map_or_else(
                || self.adaptive_scale(&view, settings.target_fps),
                f64::from,
            );
            let measured = match (link_bytes_per_s, self.jpeg_bytes_per_px_q50) {
                (Some(bytes_per_s), Some(bytes_per_px_q50))
                    if encoding.format == ColorFormat::Jpeg =>
                {
                    Some(adapt::Link {
                        bytes_per_s,
                        bytes_per_px_q50,
                        depth_bytes_per_px: if settings.depth {
                            self.depth_bytes_per_px.unwrap_or(0.0)
                        } else {
                            0.0
                        },
                    })
                }
                _ => None,
            };
            let choice = adapt::choose_interactive(
                f64::from(view.width) * f64::from(view.height),
                best_scale,
                settings.interactive_scale.is_some(),
                settings.interactive_quality,
                settings.target_fps,
                measured,
            );
            if choice.link_limited {
                flags |= FrameHeader::LINK_LIMITED;
                self.state.metrics().adapted("interactive");
            }
            encoding.quality = choice.quality;
            let scale = choice.scale;
            view.width = ((f64::from(view.width) * scale).round() as u32).max(1);
            view.height = ((f64::from(view.height) * scale).round() as u32).max(1);
        }
        let Some(asset) = self.asset.upgrade() else {
            // Gone: deleted, or uploaded again to the new device after a device loss.
            let replaced = self.state.pool().engine().generation != self.generation;
            let (kind, message) = if replaced {
                (
                    "unavailable",
                    "the GPU device was replaced and the asset uploaded again; reconnect",
                )
            } else {
                ("not_found", "the asset was deleted; the session ends")
            };
            let text = error_text(Some(want.request_id), kind, message);
            let _ = self.sink.send(Message::Text(text.into())).await;
            return false;
        };
        // The view the frame is rendered for (interactive frames at their reduced size): the
        // depth extension carries it so the client can reproject the frame.
        let rendered_view = view.clone();
        let (plan, stamp) = self.animation_frame(effective, plan);
        // Interactive frames never wait for pages being read (they show the coarse level
        // there); the resting frame does.
        let wait_for_pages = quality != Quality::Interactive;
        let rendered = match self
            .state
            .pool()
            .render(asset, view, plan, wait_for_pages)
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
        if let Some(pages) = &rendered.pages {
            self.state.metrics().pages(pages);
        }
        let pixels_mpx = f64::from(rendered.frame.width) * f64::from(rendered.frame.height) / 1e6;
        if quality == Quality::Interactive && pixels_mpx > 0.0 {
            let sample = rendered.render_ms / pixels_mpx;
            self.ms_per_mpx = Some(
                self.ms_per_mpx
                    .map_or(sample, |old| 0.7 * old + 0.3 * sample),
            );
        }
        let cameras = rendered.decision.cameras();
        let with_depth = settings.depth;
        let frame = rendered.frame;
        let encoded = encode_blocking(move || {
            let encode = |encoding| {
                encode_color(&frame, encoding).map_err(|e| {
                    AppError::Internal(anyhow::Error::new(e).context("encoding a frame"))
                })
            };
            let mut bytes = encode(encoding)?;
            let mut used = encoding;
            if !adapt::still_fits(bytes.len(), lossless_link) {
                used = Encoding {
                    format: ColorFormat::Jpeg,
                    ..encoding
                };
                bytes = encode(used)?;
            }
            // The depth image follows the colour image; the header extension says where.
            let depth = if with_depth {
                let depth = encode_depth(&frame, DepthFormat::Png16)?;
                let sizes = (bytes.len(), depth.bytes.len());
                bytes.extend_from_slice(&depth.bytes);
                Some((sizes, depth.range.unwrap_or((0.0, 0.0))))
            } else {
                None
            };
            Ok((bytes, used, frame.width, frame.height, depth))
        })
        .await;
        let ((bytes, encoding, width, height, depth), encode_ms) = match encoded {
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
        if encoding.format != settings.still_codec && quality == Quality::Full {
            flags |= FrameHeader::STILL_FALLBACK;
            self.state.metrics().adapted("still_fallback");
        }
        let pixels = f64::from(width) * f64::from(height);
        // The colour and depth images are measured apart: only the colour shrinks with the JPEG
        // quality.
        let color_len = depth.map_or(bytes.len(), |((color, _), _)| color);
        if let Some(((_, depth_len), _)) = depth
            && pixels > 0.0
        {
            let sample = depth_len as f64 / pixels;
            self.depth_bytes_per_px = Some(
                self.depth_bytes_per_px
                    .map_or(sample, |old| 0.5 * old + 0.5 * sample),
            );
        }
        if quality == Quality::Interactive && encoding.format == ColorFormat::Jpeg && pixels > 0.0 {
            let sample = color_len as f64 / pixels / adapt::jpeg_size_factor(encoding.quality);
            self.jpeg_bytes_per_px_q50 = Some(
                self.jpeg_bytes_per_px_q50
                    .map_or(sample, |old| 0.5 * old + 0.5 * sample),
            );
        }
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
            cameras: u16::try_from(cameras).unwrap_or(u16::MAX),
            encoded_quality: if encoding.format == ColorFormat::Jpeg {
                encoding.quality
            } else {
                0
            },
            flags,
            animation: stamp,
            depth: depth.map(|((color_bytes, depth_bytes), (near, far))| {
                let f32x3 = |v: [f64; 3]| v.map(|x| x as f32);
                DepthExtension {
                    color_bytes: u32::try_from(color_bytes).unwrap_or(u32::MAX),
                    depth_bytes: u32::try_from(depth_bytes).unwrap_or(u32::MAX),
                    near,
                    far,
                    eye: f32x3(rendered_view.eye),
                    target: f32x3(rendered_view.target),
                    up: f32x3(rendered_view.up),
                    yfov_deg: rendered_view.yfov_deg as f32,
                }
            }),
        };
        let mut message = Vec::with_capacity(header.encoded_len() + bytes.len());
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
        // Recorded before the send: on a fast link the ack can arrive while it completes.
        let (bytes_per_s, round_trip_ms) = {
            let mut link = self.link.lock().unwrap_or_else(PoisonError::into_inner);
            link.on_sent(self.frame_id, message.len(), Instant::now());
            (link.bytes_per_s(), link.round_trip_ms())
        };
        self.state.metrics().link(bytes_per_s, round_trip_ms);
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
