//! Texture decoding (PNG, JPEG, WebP via `image`) and size limits.
//!
//! Bytes are kept as display values: no sRGB decoding; 16-bit and float images are converted to
//! 8 bits by `image`'s `to_rgba8` (scaled, clamped), grey and grey-alpha are expanded to RGBA.

use image::imageops::FilterType;
use image::{ImageReader, Limits, RgbaImage};

use crate::mesh::{MAX_TEXTURE_PX, MeshError, Texture};

/// Largest decoder allocation for one image (a hostile header cannot make us allocate more).
const MAX_DECODE_BYTES: u64 = 1 << 30;

/// Largest side accepted from a file before downscaling (beyond this the file is rejected).
const MAX_DECODE_SIDE_PX: u32 = 65_536;

/// Decodes an encoded image (format guessed from its bytes) into an RGBA8 texture no larger than
/// [`MAX_TEXTURE_PX`] per side. `index` names the texture in errors; `what` says where it came
/// from.
pub(super) fn decode(index: usize, what: &str, bytes: &[u8]) -> Result<Texture, MeshError> {
    let error = |message: String| MeshError::Texture {
        index,
        message: format!("{what}: {message}"),
    };
    let mut reader = ImageReader::new(std::io::Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|e| error(e.to_string()))?;
    if reader.format().is_none() {
        return Err(error("not a PNG, JPEG or WebP image".to_owned()));
    }
    let mut limits = Limits::default();
    limits.max_alloc = Some(MAX_DECODE_BYTES);
    limits.max_image_width = Some(MAX_DECODE_SIDE_PX);
    limits.max_image_height = Some(MAX_DECODE_SIDE_PX);
    reader.limits(limits);
    let image = reader.decode().map_err(|e| error(e.to_string()))?;
    let rgba = image.into_rgba8();
    let mut texture = Texture {
        width: rgba.width(),
        height: rgba.height(),
        rgba8: rgba.into_raw(),
    };
    validate_and_limit(index, &mut texture)?;
    Ok(texture)
}

/// Checks a texture's dimensions against its bytes and downscales it so that no side exceeds
/// [`MAX_TEXTURE_PX`] (aspect kept, each side at least 1 px, triangle filter).
pub(super) fn validate_and_limit(index: usize, texture: &mut Texture) -> Result<(), MeshError> {
    let error = |message: String| MeshError::Texture { index, message };
    if texture.width == 0 || texture.height == 0 {
        return Err(error(format!(
            "size {}x{} has a zero side",
            texture.width, texture.height
        )));
    }
    let expected = u64::from(texture.width) * u64::from(texture.height) * 4;
    if expected != texture.rgba8.len() as u64 {
        return Err(error(format!(
            "{}x{} RGBA8 needs {expected} bytes, found {}",
            texture.width,
            texture.height,
            texture.rgba8.len()
        )));
    }
    let longest = texture.width.max(texture.height);
    if longest <= MAX_TEXTURE_PX {
        return Ok(());
    }
    let scale = f64::from(MAX_TEXTURE_PX) / f64::from(longest);
    let side = |px: u32| ((f64::from(px) * scale).round() as u32).clamp(1, MAX_TEXTURE_PX);
    let (width, height) = (side(texture.width), side(texture.height));
    let pixels = std::mem::take(&mut texture.rgba8);
    let image = RgbaImage::from_raw(texture.width, texture.height, pixels)
        .ok_or_else(|| error("pixel buffer does not match its size".to_owned()))?;
    let resized = image::imageops::resize(&image, width, height, FilterType::Triangle);
    tracing::info!(
        texture = index,
        from = %format!("{}x{}", texture.width, texture.height),
        to = %format!("{width}x{height}"),
        "downscaled texture to the {MAX_TEXTURE_PX} px limit"
    );
    *texture = Texture {
        width,
        height,
        rgba8: resized.into_raw(),
    };
    Ok(())
}
