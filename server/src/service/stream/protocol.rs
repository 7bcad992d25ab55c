//! The wire format: client and server messages and the binary frame header.

use lumigraph_core::view::View;
use serde::{Deserialize, Serialize};

use crate::service::assets::AssetSummary;
use crate::service::codecs::ColorFormat;

use super::adapt::MAX_RECEIVED_MS;

/// Version of the stream protocol, sent in `hello`.
pub const PROTOCOL_VERSION: u32 = 1;
/// Bytes of the binary frame header.
pub const FRAME_HEADER_LEN: usize = 40;

/// Client messages (`type` selects the variant; see docs/protocol.md).
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct ViewMessage {
    pub(super) id: u32,
    pub(super) view: View,
    #[serde(default)]
    pub(super) still: bool,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct AckMessage {
    pub(super) frame: u32,
    /// When the client received the frame whole, ms on any steady clock of the client's
    /// (`performance.now()`): only differences between acks are used.
    #[serde(default)]
    pub(super) received_ms: Option<f64>,
}

/// A client text message, parsed and checked as far as it can be without a session.
#[derive(Debug)]
pub(super) enum ClientMessage {
    /// A view to render (its basis is valid for the server's `max_px`).
    View(ViewMessage),
    /// A settings patch: the message's object without `type` (merged and validated against the
    /// session's settings and asset by the receiver), and its `id` for the error reply.
    Settings {
        /// The message's `id`, when it has one that fits a `u32`.
        request: Option<u32>,
        /// The fields to merge.
        patch: serde_json::Value,
    },
    /// A frame acknowledgement.
    Ack(AckMessage),
}

/// Why a client message was refused: what the error message sent back names.
#[derive(Debug, PartialEq, Eq)]
pub(super) struct Refusal {
    /// The message's `id`, when it has one that fits a `u32`.
    pub(super) request: Option<u32>,
    /// Error kind (`malformed_json` or `invalid`).
    pub(super) kind: &'static str,
    /// What is wrong.
    pub(super) message: String,
}

/// Parses one client text message (see docs/protocol.md).
pub(super) fn parse_client_message(text: &str, max_px: u32) -> Result<ClientMessage, Refusal> {
    let mut value: serde_json::Value = serde_json::from_str(text).map_err(|e| Refusal {
        request: None,
        kind: "malformed_json",
        message: format!("malformed JSON: {e}"),
    })?;
    let request = value
        .get("id")
        .and_then(serde_json::Value::as_u64)
        .and_then(|v| u32::try_from(v).ok());
    let invalid = |request: Option<u32>, message: String| Refusal {
        request,
        kind: "invalid",
        message,
    };
    let kind = value
        .as_object_mut()
        .and_then(|o| o.remove("type"))
        .and_then(|t| t.as_str().map(str::to_owned));
    match kind.as_deref() {
        Some("view") => {
            let message = serde_json::from_value::<ViewMessage>(value)
                .map_err(|e| invalid(request, format!("invalid view message: {e}")))?;
            message
                .view
                .basis(max_px)
                .map_err(|e| invalid(Some(message.id), e.to_string()))?;
            Ok(ClientMessage::View(message))
        }
        Some("settings") => Ok(ClientMessage::Settings {
            request,
            patch: value,
        }),
        Some("ack") => {
            let ack = serde_json::from_value::<AckMessage>(value)
                .map_err(|e| invalid(request, format!("invalid ack message: {e}")))?;
            if let Some(received) = ack.received_ms
                && !(received.is_finite() && (0.0..=MAX_RECEIVED_MS).contains(&received))
            {
                return Err(invalid(
                    request,
                    format!(
                        "invalid ack message: received_ms must be in [0, {MAX_RECEIVED_MS:e}], got {received}"
                    ),
                ));
            }
            Ok(ClientMessage::Ack(ack))
        }
        Some(other) => Err(invalid(
            request,
            format!("unknown message type {other:?}: use view, settings or ack"),
        )),
        None => Err(invalid(
            request,
            "a message needs a string field `type` (view, settings or ack)".to_owned(),
        )),
    }
}

#[derive(Serialize)]
struct ErrorMessage<'a> {
    r#type: &'static str,
    request: Option<u32>,
    kind: &'a str,
    message: &'a str,
}

pub(super) fn error_text(request: Option<u32>, kind: &str, message: &str) -> String {
    serde_json::to_string(&ErrorMessage {
        r#type: "error",
        request,
        kind,
        message,
    })
    .unwrap_or_default()
}

#[derive(Serialize)]
pub(super) struct Hello {
    pub(super) r#type: &'static str,
    pub(super) protocol: u32,
    pub(super) asset: AssetSummary,
    /// Every setting, the quality keys at the top level.
    pub(super) settings: serde_json::Value,
    pub(super) max_px: u32,
    pub(super) header_len: usize,
}

/// Quality level of a frame, as in the header.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Quality {
    Interactive = 0,
    Full = 1,
}

/// The 40-byte little-endian header in front of every binary frame (docs/protocol.md).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameHeader {
    /// Image codec.
    pub codec: ColorFormat,
    pub(super) quality: Quality,
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
    /// JPEG quality of the image (1..=100), 0 for a lossless codec.
    pub encoded_quality: u8,
    /// What adaptation to the link changed in this frame ([`FrameHeader::LINK_LIMITED`],
    /// [`FrameHeader::STILL_FALLBACK`]).
    pub flags: u8,
}

impl FrameHeader {
    /// Flag: the link made the server lower the interactive quality or scale below the
    /// settings.
    pub const LINK_LIMITED: u8 = 1;
    /// Flag: a resting frame was sent as JPEG because the lossless `still_codec` would have
    /// taken too long on the link.
    pub const STILL_FALLBACK: u8 = 2;

    pub(super) fn write(&self, out: &mut Vec<u8>) {
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
        out.push(self.encoded_quality);
        out.push(self.flags);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn acks_with_and_without_receive_times() {
        let received = |text: &str| match parse_client_message(text, 64) {
            Ok(ClientMessage::Ack(ack)) => Ok((ack.frame, ack.received_ms)),
            Ok(other) => panic!("not an ack: {other:?}"),
            Err(refusal) => Err(refusal.message),
        };
        assert_eq!(received(r#"{"type":"ack","frame":3}"#), Ok((3, None)));
        assert_eq!(
            received(r#"{"type":"ack","frame":3,"received_ms":1234.5}"#),
            Ok((3, Some(1234.5)))
        );
        for bad in ["-1", "1e13", "\"soon\"", "1e999", "[1]"] {
            let text = format!(r#"{{"type":"ack","frame":3,"received_ms":{bad}}}"#);
            let error = received(&text).expect_err(&text);
            let out_of_range = ["-1", "1e13"].contains(&bad);
            assert!(
                (out_of_range && error.contains("received_ms must be in"))
                    || (!out_of_range
                        && (error.starts_with("invalid ack message")
                            || error.starts_with("malformed JSON"))),
                "{bad}: {error}"
            );
        }
    }

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
            encoded_quality: 35,
            flags: FrameHeader::LINK_LIMITED,
        };
        let mut out = Vec::new();
        header.write(&mut out);
        assert_eq!(out.len(), FRAME_HEADER_LEN);
        assert_eq!(&out[..4], b"LGF1");
        assert_eq!(out[6], 1);
        assert_eq!(out[7], 1);
        assert_eq!(u32::from_le_bytes([out[8], out[9], out[10], out[11]]), 7);
        assert_eq!(u16::from_le_bytes([out[36], out[37]]), 162);
        assert_eq!((out[38], out[39]), (35, 1));
    }
}
