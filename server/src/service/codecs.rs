//! The codecs of a frame: colour (PNG, JPEG, WebP) and depth (npy, EXR, 16-bit PNG), encoded off
//! the async runtime.

use std::time::Instant;

use lumigraph_core::frame::Frame;
use lumigraph_core::image_io;
use serde::{Deserialize, Serialize};

use super::error::AppError;

/// Colour codec of a frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum ColorFormat {
    /// Lossless 8-bit RGBA PNG.
    #[default]
    Png,
    /// Baseline JPEG, composited over the background (no alpha).
    Jpeg,
    /// Lossless WebP with alpha.
    Webp,
    /// No colour image (only depth).
    None,
}

impl ColorFormat {
    /// MIME type.
    pub fn mime(self) -> &'static str {
        match self {
            ColorFormat::Png => "image/png",
            ColorFormat::Jpeg => "image/jpeg",
            ColorFormat::Webp => "image/webp",
            ColorFormat::None => "application/octet-stream",
        }
    }

    /// Label used in metrics and the stream header.
    pub fn name(self) -> &'static str {
        match self {
            ColorFormat::Png => "png",
            ColorFormat::Jpeg => "jpeg",
            ColorFormat::Webp => "webp",
            ColorFormat::None => "none",
        }
    }
}

/// Depth codec of a frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum DepthFormat {
    /// NumPy `.npy`, float32, shape (height, width), `inf` where nothing is hit.
    Npy,
    /// OpenEXR, one float32 channel `Z`, `inf` where nothing is hit.
    Exr,
    /// 16-bit grey PNG: `round((d - near) / (far - near) · 65534)`, 65535 = no hit; `near` and
    /// `far` are the smallest and largest finite depths, sent as `X-Depth-Near`/`X-Depth-Far`.
    Png16,
}

impl DepthFormat {
    /// MIME type.
    pub fn mime(self) -> &'static str {
        match self {
            DepthFormat::Npy => "application/x-npy",
            DepthFormat::Exr => "image/x-exr",
            DepthFormat::Png16 => "image/png",
        }
    }
}

/// How a colour frame is encoded.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Encoding {
    /// The codec.
    pub format: ColorFormat,
    /// JPEG quality 1..=100 (ignored by lossless codecs).
    pub quality: u8,
    /// RGBA written where nothing is hit (JPEG: its RGB is the matte).
    pub background: [u8; 4],
}

/// Encodes a frame's colour (blocking).
pub fn encode_color(frame: &Frame, encoding: Encoding) -> Result<Vec<u8>, image_io::ImageIoError> {
    let rgba = frame.with_background(encoding.background);
    let [r, g, b, _] = encoding.background;
    match encoding.format {
        ColorFormat::Png => image_io::encode_png_rgba8(frame.width, frame.height, &rgba),
        ColorFormat::Jpeg => image_io::encode_jpeg(
            frame.width,
            frame.height,
            &rgba,
            encoding.quality,
            [r, g, b],
        ),
        ColorFormat::Webp => image_io::encode_webp_lossless(frame.width, frame.height, &rgba),
        ColorFormat::None => Ok(Vec::new()),
    }
}

/// An encoded depth image and, for `png16`, the depth range it maps.
pub struct EncodedDepth {
    /// The bytes.
    pub bytes: Vec<u8>,
    /// `(near, far)` of a `png16` image.
    pub range: Option<(f32, f32)>,
}

/// Encodes a frame's depth (blocking).
pub fn encode_depth(frame: &Frame, format: DepthFormat) -> Result<EncodedDepth, AppError> {
    let encode_err = |e: image_io::ImageIoError| {
        AppError::Internal(anyhow::Error::new(e).context("encoding depth"))
    };
    match format {
        DepthFormat::Npy => Ok(EncodedDepth {
            bytes: image_io::encode_depth_npy(frame.width, frame.height, &frame.depth)
                .map_err(encode_err)?,
            range: None,
        }),
        DepthFormat::Exr => Ok(EncodedDepth {
            bytes: image_io::encode_depth_exr(frame.width, frame.height, &frame.depth)
                .map_err(encode_err)?,
            range: None,
        }),
        DepthFormat::Png16 => {
            let (bytes, range) =
                image_io::encode_depth_png16(frame.width, frame.height, &frame.depth)
                    .map_err(encode_err)?;
            Ok(EncodedDepth {
                bytes,
                range: Some(range),
            })
        }
    }
}

/// Runs a blocking encode off the runtime and times it.
pub async fn encode_blocking<T: Send + 'static>(
    work: impl FnOnce() -> Result<T, AppError> + Send + 'static,
) -> Result<(T, f64), AppError> {
    tokio::task::spawn_blocking(move || {
        let start = Instant::now();
        work().map(|out| (out, start.elapsed().as_secs_f64() * 1e3))
    })
    .await
    .map_err(|e| AppError::Internal(anyhow::Error::new(e).context("encode task failed")))?
}
