//! The wire format: client and server messages and the binary frame header.

use lumigraph_core::view::View;
use serde::{Deserialize, Serialize};

use crate::service::assets::AssetSummary;
use crate::service::codecs::ColorFormat;

use super::adapt::MAX_RECEIVED_MS;

/// Version of the stream protocol, sent in `hello`.
pub const PROTOCOL_VERSION: u32 = 1;
/// Bytes of the binary frame header without extensions.
pub const FRAME_HEADER_LEN: usize = 40;
/// Bytes of the depth extension appended to the header when the session asks for depth.
pub const DEPTH_EXTENSION_LEN: usize = 60;
/// Depth codec of the extension: a 16-bit grey PNG, `round((d - near) / (far - near) · 65534)`,
/// 65535 where nothing is hit (the HTTP `png16` convention).
pub const DEPTH_CODEC_PNG16: u8 = 1;

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
    /// The depth extension, present when the session's `depth` setting is on.
    pub depth: Option<DepthExtension>,
    /// The animation frame shown, for an asset with an animation (the animation extension).
    pub animation: Option<AnimationStamp>,
}

/// Which animation frame a frame shows (docs/protocol.md, "Animation extension").
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AnimationStamp {
    /// Frame index, 0 = the first.
    pub frame: u32,
    /// Its time in the animation, seconds.
    pub time: f32,
}

/// Bytes of the animation extension (after the depth extension, when both are present).
pub const ANIMATION_EXTENSION_LEN: usize = 8;

/// What a frame carries for reprojection: where its depth image is, the range its 16-bit values
/// map and the view it was rendered for (docs/protocol.md, "Depth extension").
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DepthExtension {
    /// Bytes of the colour image; the depth image follows it.
    pub color_bytes: u32,
    /// Bytes of the depth image.
    pub depth_bytes: u32,
    /// Depth of value 0 (the smallest finite depth), world units.
    pub near: f32,
    /// Depth of value 65534 (the largest finite depth), world units.
    pub far: f32,
    /// The view's eye.
    pub eye: [f32; 3],
    /// The view's target.
    pub target: [f32; 3],
    /// The view's up direction, as sent (not yet made orthogonal).
    pub up: [f32; 3],
    /// The view's vertical field of view, degrees.
    pub yfov_deg: f32,
}

/// Why a binary frame could not be read.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum FrameError {
    /// The message is shorter than its header says.
    #[error("frame of {len} bytes is shorter than its header ({needed} bytes)")]
    Truncated {
        /// Bytes received.
        len: usize,
        /// Bytes the header needs.
        needed: usize,
    },
    /// The first four bytes are not `LGF1`.
    #[error("bad frame magic {0:?}")]
    Magic([u8; 4]),
    /// A codec byte names no known codec.
    #[error("unknown {kind} codec {code}")]
    Codec {
        /// `colour` or `depth`.
        kind: &'static str,
        /// The byte.
        code: u8,
    },
    /// The colour and depth lengths do not add up to the message's payload.
    #[error(
        "colour ({color} bytes) and depth ({depth} bytes) do not fill the {payload}-byte payload"
    )]
    Lengths {
        /// Colour bytes in the extension.
        color: u32,
        /// Depth bytes in the extension.
        depth: u32,
        /// Bytes after the header.
        payload: usize,
    },
    /// The depth image is not a 16-bit grey PNG of the frame's size.
    #[error("depth image: {0}")]
    Depth(String),
}

/// A binary frame split into its parts.
#[derive(Debug)]
pub struct ParsedFrame<'a> {
    /// The header, with its depth extension when the flag is set.
    pub header: FrameHeader,
    /// The encoded colour image.
    pub color: &'a [u8],
    /// The encoded depth image, when the frame has the depth extension.
    pub depth: Option<&'a [u8]>,
}

fn u16_at(bytes: &[u8], at: usize) -> u16 {
    u16::from_le_bytes([bytes[at], bytes[at + 1]])
}

fn u32_at(bytes: &[u8], at: usize) -> u32 {
    u32::from_le_bytes([bytes[at], bytes[at + 1], bytes[at + 2], bytes[at + 3]])
}

fn f32_at(bytes: &[u8], at: usize) -> f32 {
    f32::from_bits(u32_at(bytes, at))
}

fn vec3_at(bytes: &[u8], at: usize) -> [f32; 3] {
    [
        f32_at(bytes, at),
        f32_at(bytes, at + 4),
        f32_at(bytes, at + 8),
    ]
}

/// Splits a binary frame into header, colour and depth image (the reader's side of
/// `FrameHeader::write`; clients in other languages follow docs/protocol.md).
///
/// # Errors
/// A message too short for its header, a wrong magic, an unknown codec, or extension lengths
/// that do not match the payload.
pub fn parse_frame(bytes: &[u8]) -> Result<ParsedFrame<'_>, FrameError> {
    let truncated = |needed: usize| FrameError::Truncated {
        len: bytes.len(),
        needed,
    };
    if bytes.len() < FRAME_HEADER_LEN {
        return Err(truncated(FRAME_HEADER_LEN));
    }
    let magic = [bytes[0], bytes[1], bytes[2], bytes[3]];
    if &magic != b"LGF1" {
        return Err(FrameError::Magic(magic));
    }
    let header_len = usize::from(u16_at(bytes, 4));
    let flags = bytes[39];
    let has_depth = flags & FrameHeader::DEPTH != 0;
    let has_animation = flags & FrameHeader::ANIMATION != 0;
    let animation_at = FRAME_HEADER_LEN + if has_depth { DEPTH_EXTENSION_LEN } else { 0 };
    let needed = animation_at
        + if has_animation {
            ANIMATION_EXTENSION_LEN
        } else {
            0
        };
    if header_len < needed || bytes.len() < header_len {
        return Err(truncated(header_len.max(needed)));
    }
    let codec = match bytes[6] {
        0 => ColorFormat::Png,
        1 => ColorFormat::Jpeg,
        2 => ColorFormat::Webp,
        255 => ColorFormat::None,
        code => {
            return Err(FrameError::Codec {
                kind: "colour",
                code,
            });
        }
    };
    let quality = if bytes[7] == 0 {
        Quality::Interactive
    } else {
        Quality::Full
    };
    let payload = &bytes[header_len..];
    let (depth, color, depth_image) = if has_depth {
        let at = FRAME_HEADER_LEN;
        if bytes[at] != DEPTH_CODEC_PNG16 {
            return Err(FrameError::Codec {
                kind: "depth",
                code: bytes[at],
            });
        }
        let extension = DepthExtension {
            color_bytes: u32_at(bytes, at + 4),
            near: f32_at(bytes, at + 8),
            far: f32_at(bytes, at + 12),
            eye: vec3_at(bytes, at + 16),
            target: vec3_at(bytes, at + 28),
            up: vec3_at(bytes, at + 40),
            yfov_deg: f32_at(bytes, at + 52),
            depth_bytes: u32_at(bytes, at + 56),
        };
        let color_len = extension.color_bytes as usize;
        if color_len.checked_add(extension.depth_bytes as usize) != Some(payload.len()) {
            return Err(FrameError::Lengths {
                color: extension.color_bytes,
                depth: extension.depth_bytes,
                payload: payload.len(),
            });
        }
        let (color, depth_image) = payload.split_at(color_len);
        (Some(extension), color, Some(depth_image))
    } else {
        (None, payload, None)
    };
    Ok(ParsedFrame {
        header: FrameHeader {
            codec,
            quality,
            frame_id: u32_at(bytes, 8),
            request_id: u32_at(bytes, 12),
            width: u32_at(bytes, 16),
            height: u32_at(bytes, 20),
            render_ms: f32_at(bytes, 24),
            encode_ms: f32_at(bytes, 28),
            dropped: u32_at(bytes, 32),
            cameras: u16_at(bytes, 36),
            encoded_quality: bytes[38],
            flags: flags & !(FrameHeader::DEPTH | FrameHeader::ANIMATION),
            depth,
            animation: has_animation.then(|| AnimationStamp {
                frame: u32_at(bytes, animation_at),
                time: f32_at(bytes, animation_at + 4),
            }),
        },
        color,
        depth: depth_image,
    })
}

/// Decodes a frame's depth image (codec [`DEPTH_CODEC_PNG16`]) to z-depths in world units,
/// `+inf` where nothing is hit, row-major from the top row. The image must be the frame's size.
///
/// # Errors
/// Not a PNG, not 16-bit grey, or another size than `width` × `height`.
pub fn decode_depth(
    image: &[u8],
    extension: &DepthExtension,
    width: u32,
    height: u32,
) -> Result<Vec<f32>, FrameError> {
    let decoded = image::load_from_memory_with_format(image, image::ImageFormat::Png)
        .map_err(|e| FrameError::Depth(e.to_string()))?;
    let image::DynamicImage::ImageLuma16(grey) = decoded else {
        return Err(FrameError::Depth("not a 16-bit grey PNG".to_owned()));
    };
    if grey.dimensions() != (width, height) {
        return Err(FrameError::Depth(format!(
            "{}x{} instead of the frame's {width}x{height}",
            grey.width(),
            grey.height()
        )));
    }
    let span = extension.far - extension.near;
    Ok(grey
        .into_raw()
        .into_iter()
        .map(|q| {
            if q == u16::MAX {
                f32::INFINITY
            } else {
                extension.near + f32::from(q) / 65534.0 * span
            }
        })
        .collect())
}

impl FrameHeader {
    /// Flag: the link made the server lower the interactive quality or scale below the
    /// settings.
    pub const LINK_LIMITED: u8 = 1;
    /// Flag: a resting frame was sent as JPEG because the lossless `still_codec` would have
    /// taken too long on the link.
    pub const STILL_FALLBACK: u8 = 2;
    /// Flag: the depth extension follows the 40-byte header (set by `FrameHeader::write`
    /// when [`FrameHeader::depth`] is present).
    pub const DEPTH: u8 = 4;

    /// Flag: the animation extension follows (the depth extension, if any, comes first).
    pub const ANIMATION: u8 = 8;

    /// Bytes of this header, extensions included.
    pub fn encoded_len(&self) -> usize {
        FRAME_HEADER_LEN
            + self.depth.map_or(0, |_| DEPTH_EXTENSION_LEN)
            + self.animation.map_or(0, |_| ANIMATION_EXTENSION_LEN)
    }

    /// Appends the header (and its depth extension) to `out`; the colour image, then the depth
    /// image, follow it.
    pub(super) fn write(&self, out: &mut Vec<u8>) {
        out.extend_from_slice(b"LGF1");
        out.extend_from_slice(&(self.encoded_len() as u16).to_le_bytes());
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
        let depth_flag = if self.depth.is_some() { Self::DEPTH } else { 0 };
        let animation_flag = if self.animation.is_some() {
            Self::ANIMATION
        } else {
            0
        };
        out.push(self.flags | depth_flag | animation_flag);
        if let Some(depth) = &self.depth {
            out.extend_from_slice(&[DEPTH_CODEC_PNG16, 0, 0, 0]);
            out.extend_from_slice(&depth.color_bytes.to_le_bytes());
            out.extend_from_slice(&depth.near.to_le_bytes());
            out.extend_from_slice(&depth.far.to_le_bytes());
            for v in depth.eye.iter().chain(&depth.target).chain(&depth.up) {
                out.extend_from_slice(&v.to_le_bytes());
            }
            out.extend_from_slice(&depth.yfov_deg.to_le_bytes());
            out.extend_from_slice(&depth.depth_bytes.to_le_bytes());
        }
        if let Some(stamp) = &self.animation {
            out.extend_from_slice(&stamp.frame.to_le_bytes());
            out.extend_from_slice(&stamp.time.to_le_bytes());
        }
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
            depth: None,
            animation: None,
        };
        let mut out = Vec::new();
        header.write(&mut out);
        assert_eq!(out.len(), FRAME_HEADER_LEN);
        assert_eq!(&out[..4], b"LGF1");
        assert_eq!(out[6], 1);
        assert_eq!(out[7], 1);
        assert_eq!(u32::from_le_bytes([out[8], out[9], out[10], out[11]]), 7);
        assert_eq!(u16::from_le_bytes([out[36], out[37]]), 162);
        // Without depth: no extension, no depth flag.
        assert_eq!((out[38], out[39]), (35, 1));
        let parsed = parse_frame(&out).unwrap();
        assert_eq!(parsed.header, header);
        assert!(parsed.depth.is_none() && parsed.color.is_empty());
        // The animation extension: 8 bytes after the base header, flag bit 3.
        let stamped = FrameHeader {
            animation: Some(AnimationStamp {
                frame: 12,
                time: 0.5,
            }),
            ..header
        };
        let mut out = Vec::new();
        stamped.write(&mut out);
        out.extend_from_slice(b"image");
        assert_eq!(out.len(), FRAME_HEADER_LEN + ANIMATION_EXTENSION_LEN + 5);
        assert_eq!(u16::from_le_bytes([out[4], out[5]]), 48);
        assert_eq!(out[39], 1 | FrameHeader::ANIMATION);
        assert_eq!(u32::from_le_bytes([out[40], out[41], out[42], out[43]]), 12);
        let parsed = parse_frame(&out).unwrap();
        assert_eq!((parsed.header, parsed.color), (stamped, &b"image"[..]));
        assert!(
            parse_frame(&out[..44]).is_err(),
            "a cut extension is refused"
        );
    }

    /// Depths covering a range with misses; quantised to 16 bits, the round trip through the
    /// header and the PNG must come back within half a quantisation step.
    #[test]
    fn depth_extension_round_trips_within_half_a_step() {
        let (width, height) = (37u32, 23u32);
        let depth: Vec<f32> = (0..width * height)
            .map(|i| {
                if i % 7 == 3 {
                    f32::INFINITY
                } else {
                    2.0 + (i as f32 * 0.618_034).fract() * 1.7
                }
            })
            .collect();
        let (png, (near, far)) =
            lumigraph_core::image_io::encode_depth_png16(width, height, &depth).unwrap();
        let color = b"colour bytes".to_vec();
        let header = FrameHeader {
            codec: ColorFormat::Png,
            quality: Quality::Interactive,
            frame_id: 1,
            request_id: 2,
            width,
            height,
            render_ms: 3.0,
            encode_ms: 4.0,
            dropped: 0,
            cameras: 12,
            encoded_quality: 0,
            flags: 0,
            depth: Some(DepthExtension {
                color_bytes: color.len() as u32,
                depth_bytes: png.len() as u32,
                near,
                far,
                eye: [0.5, 1.0, 3.0],
                target: [0.0, 0.25, 0.0],
                up: [0.0, 1.0, 0.0],
                yfov_deg: 40.0,
            }),
            animation: None,
        };
        let mut out = Vec::new();
        header.write(&mut out);
        assert_eq!(out.len(), FRAME_HEADER_LEN + DEPTH_EXTENSION_LEN);
        assert_eq!(usize::from(u16::from_le_bytes([out[4], out[5]])), 100);
        assert_eq!((out[38], out[39]), (0, FrameHeader::DEPTH));
        assert_eq!(out[40], DEPTH_CODEC_PNG16);
        out.extend_from_slice(&color);
        out.extend_from_slice(&png);
        let parsed = parse_frame(&out).unwrap();
        assert_eq!(parsed.header, header);
        assert_eq!(parsed.color, color.as_slice());
        let extension = parsed.header.depth.unwrap();
        let decoded = decode_depth(parsed.depth.unwrap(), &extension, width, height).unwrap();
        // Half a step of the 65534 steps between near and far, plus f32 rounding of the
        // dequantisation at these magnitudes (a few ulps of 4.0).
        let bound = 0.5 * (far - near) / 65534.0 + 4.0 * f32::EPSILON * far;
        for (sent, got) in depth.iter().zip(&decoded) {
            if sent.is_finite() {
                assert!(
                    (sent - got).abs() <= bound,
                    "{sent} -> {got}, bound {bound}"
                );
            } else {
                assert!(got.is_infinite());
            }
        }
        // Lengths that do not add up are refused, not read past.
        let mut short = out.clone();
        short.pop();
        assert!(matches!(
            parse_frame(&short),
            Err(FrameError::Lengths { .. })
        ));
        assert!(matches!(
            parse_frame(&out[..60]),
            Err(FrameError::Truncated { .. })
        ));
    }
}
