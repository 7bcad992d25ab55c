//! Encoders, decoders and file writers for frames: colour as PNG, JPEG or WebP, depth as NumPy
//! `.npy` or OpenEXR (and, for viewers, a 16-bit PNG of the depth range).
//!
//! Every `encode_*` function works in memory (the service sends the bytes), every `write_*`
//! function encodes first and then writes through [`atomic_write`], so a failed encode touches no
//! file and a failed write leaves no partial file. Readers take untrusted files: sizes are checked
//! against the data present and against [`MAX_DECODE_PIXELS`] before anything is allocated.
//!
//! Depth is `width * height` f32 values, row-major with the top row first, `+inf` where nothing is
//! hit (DESIGN §3). Both depth formats store the f32 bits unchanged, so `+inf`, NaN payloads and
//! denormals round-trip exactly:
//! - `.npy`: a float32 array of shape `(height, width)` in C order (`np.load` gives the image);
//! - `.exr`: one float32 channel named `"Z"`, ZIP-compressed scanlines (lossless).

use std::io::{Cursor, Write};
use std::path::{Path, PathBuf};

use image::codecs::png::PngEncoder;
use image::codecs::webp::WebPEncoder;
use image::{ExtendedColorType, ImageEncoder, ImageFormat, ImageReader};

use crate::fsutil::atomic_write;

/// Largest image (in pixels) a reader accepts: 2^28 = 16384², 1 GiB of f32 depth.
pub const MAX_DECODE_PIXELS: u64 = 1 << 28;

/// Boxed error of an encoder or decoder library (or a message about invalid content).
type BoxError = Box<dyn std::error::Error + Send + Sync>;

/// Why an image could not be encoded, decoded, written or read.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ImageIoError {
    /// Reading or writing the file failed.
    #[error("file i/o failed on {}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// The encoder rejected the image (e.g. a zero or too large dimension).
    #[error("encoding {format} failed")]
    Encode {
        /// "PNG", "JPEG", "WebP", "NPY" or "EXR".
        format: &'static str,
        /// The encoder's error.
        source: BoxError,
    },
    /// The data is corrupt, truncated, too large or not an image of the expected kind.
    #[error("decoding {format} failed")]
    Decode {
        /// "PNG", "NPY" or "EXR".
        format: &'static str,
        /// The decoder's error, or what is wrong with the content.
        source: BoxError,
    },
    /// The file extension names no format this function writes or reads.
    #[error("unsupported file extension of {} (expected {expected})", path.display())]
    UnsupportedExtension {
        /// The file.
        path: PathBuf,
        /// The extensions that are supported.
        expected: &'static str,
    },
    /// A pixel buffer's length does not match `width * height` times its values per pixel.
    #[error("{actual} values given for a {width}x{height} image, expected {expected}")]
    SizeMismatch {
        /// Image width.
        width: u32,
        /// Image height.
        height: u32,
        /// Values expected.
        expected: u64,
        /// Values given.
        actual: usize,
    },
}

impl ImageIoError {
    fn encode(format: &'static str, source: impl Into<BoxError>) -> Self {
        Self::Encode {
            format,
            source: source.into(),
        }
    }

    fn decode(format: &'static str, source: impl Into<BoxError>) -> Self {
        Self::Decode {
            format,
            source: source.into(),
        }
    }
}

/// Checks that `len == width * height * per_pixel`.
fn check_size(width: u32, height: u32, per_pixel: u64, len: usize) -> Result<(), ImageIoError> {
    // u32 · u32 · 4 < 2^66 would overflow u64 only for absurd sizes; checked anyway.
    let expected = u64::from(width)
        .checked_mul(u64::from(height))
        .and_then(|p| p.checked_mul(per_pixel));
    if expected == Some(len as u64) {
        Ok(())
    } else {
        Err(ImageIoError::SizeMismatch {
            width,
            height,
            expected: expected.unwrap_or(u64::MAX),
            actual: len,
        })
    }
}

/// Writes already encoded `bytes` to `path` atomically.
fn write_bytes(path: &Path, bytes: &[u8]) -> Result<(), ImageIoError> {
    atomic_write::<std::io::Error>(path, |w| w.write_all(bytes)).map_err(|source| {
        ImageIoError::Io {
            path: path.to_path_buf(),
            source,
        }
    })
}

/// Reads the whole file at `path`.
fn read_bytes(path: &Path) -> Result<Vec<u8>, ImageIoError> {
    std::fs::read(path).map_err(|source| ImageIoError::Io {
        path: path.to_path_buf(),
        source,
    })
}

/// Lower-case extension of `path`, if any.
fn extension(path: &Path) -> Option<String> {
    path.extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
}

// ---------------------------------------------------------------------------------------------
// Colour

/// Encodes RGBA8 pixels as an 8-bit RGBA PNG (fast deflate: frames are encoded per request).
pub fn encode_png_rgba8(width: u32, height: u32, rgba: &[u8]) -> Result<Vec<u8>, ImageIoError> {
    check_size(width, height, 4, rgba.len())?;
    let mut out = Vec::new();
    PngEncoder::new(&mut out)
        .write_image(rgba, width, height, ExtendedColorType::Rgba8)
        .map_err(|e| ImageIoError::encode("PNG", e))?;
    Ok(out)
}

/// Writes RGBA8 pixels to `path` as a PNG, atomically.
pub fn write_png_rgba8(
    path: &Path,
    width: u32,
    height: u32,
    rgba: &[u8],
) -> Result<(), ImageIoError> {
    write_bytes(path, &encode_png_rgba8(width, height, rgba)?)
}

/// Decodes a PNG of any colour type and bit depth into RGBA8; returns `(width, height, rgba)`.
pub fn decode_png_rgba8(bytes: &[u8]) -> Result<(u32, u32, Vec<u8>), ImageIoError> {
    let mut reader = ImageReader::with_format(Cursor::new(bytes), ImageFormat::Png);
    let mut limits = image::Limits::default();
    limits.max_alloc = Some(MAX_DECODE_PIXELS * 4);
    reader.limits(limits);
    let image = reader
        .decode()
        .map_err(|e| ImageIoError::decode("PNG", e))?;
    let rgba = image.into_rgba8();
    Ok((rgba.width(), rgba.height(), rgba.into_raw()))
}

/// Reads a PNG file into RGBA8; returns `(width, height, rgba)`.
pub fn read_png_rgba8(path: &Path) -> Result<(u32, u32, Vec<u8>), ImageIoError> {
    decode_png_rgba8(&read_bytes(path)?)
}

/// Encodes RGBA8 pixels as a baseline JPEG, compositing each pixel over the opaque `background`
/// with its (straight) alpha, since JPEG has no alpha channel. `quality` is clamped to 1..=100.
pub fn encode_jpeg(
    width: u32,
    height: u32,
    rgba: &[u8],
    quality: u8,
    background: [u8; 3],
) -> Result<Vec<u8>, ImageIoError> {
    check_size(width, height, 4, rgba.len())?;
    // Opaque and empty pixels (all but the silhouette's) are copied, not blended: the same
    // bytes as the blend, in a third of its time.
    let mut rgb = vec![0u8; rgba.len() / 4 * 3];
    for (px, out) in rgba.chunks_exact(4).zip(rgb.chunks_exact_mut(3)) {
        match px[3] {
            255 => out.copy_from_slice(&px[..3]),
            0 => out.copy_from_slice(&background),
            alpha => {
                let alpha = u32::from(alpha);
                for (c, o) in out.iter_mut().enumerate() {
                    let over = u32::from(px[c]) * alpha + u32::from(background[c]) * (255 - alpha);
                    *o = ((over + 127) / 255) as u8;
                }
            }
        }
    }
    let (Ok(w), Ok(h)) = (u16::try_from(width), u16::try_from(height)) else {
        return Err(ImageIoError::encode(
            "JPEG",
            format!("{width}x{height} is larger than JPEG's 65535 px per side"),
        ));
    };
    encode_rgb_jpeg(&rgb, w, h, quality.clamp(1, 100))
}

/// Baseline JPEG of packed RGB8, full-resolution chroma (4:4:4), through libjpeg-turbo.
#[cfg(feature = "turbojpeg")]
fn encode_rgb_jpeg(
    rgb: &[u8],
    width: u16,
    height: u16,
    quality: u8,
) -> Result<Vec<u8>, ImageIoError> {
    use std::cell::RefCell;
    thread_local! {
        // One compressor per thread, reused: its working buffers stay allocated.
        static COMPRESSOR: RefCell<Option<turbojpeg::Compressor>> = const { RefCell::new(None) };
    }
    COMPRESSOR.with(|cell| {
        let mut slot = cell.borrow_mut();
        let compressor = match slot.as_mut() {
            Some(compressor) => compressor,
            None => slot
                .insert(turbojpeg::Compressor::new().map_err(|e| ImageIoError::encode("JPEG", e))?),
        };
        compressor.set_quality(i32::from(quality));
        compressor.set_subsamp(turbojpeg::Subsamp::None);
        let (width, height) = (usize::from(width), usize::from(height));
        let image = turbojpeg::Image {
            pixels: rgb,
            width,
            pitch: width * 3,
            height,
            format: turbojpeg::PixelFormat::RGB,
        };
        compressor
            .compress_to_vec(image)
            .map_err(|e| ImageIoError::encode("JPEG", e))
    })
}

#[cfg(not(feature = "turbojpeg"))]
use encode_rgb_jpeg_rust as encode_rgb_jpeg;

/// Baseline JPEG of packed RGB8, full-resolution chroma (4:4:4), in pure Rust (`jpeg-encoder`
/// with SIMD): the same bytes and PSNR per quality as the `image` crate's encoder gave, in a
/// third of its time; libjpeg-turbo (feature `turbojpeg`) takes a quarter of this one's.
#[cfg_attr(all(feature = "turbojpeg", not(test)), allow(dead_code))]
fn encode_rgb_jpeg_rust(
    rgb: &[u8],
    width: u16,
    height: u16,
    quality: u8,
) -> Result<Vec<u8>, ImageIoError> {
    let mut out = Vec::new();
    let mut encoder = jpeg_encoder::Encoder::new(&mut out, quality);
    encoder.set_sampling_factor(jpeg_encoder::SamplingFactor::R_4_4_4);
    encoder
        .encode(rgb, width, height, jpeg_encoder::ColorType::Rgb)
        .map_err(|e| ImageIoError::encode("JPEG", e))?;
    Ok(out)
}

/// Encodes RGBA8 pixels as a lossless WebP (the `image` crate's WebP encoder has no lossy
/// mode; use JPEG where smaller, lossy frames are wanted).
pub fn encode_webp_lossless(width: u32, height: u32, rgba: &[u8]) -> Result<Vec<u8>, ImageIoError> {
    check_size(width, height, 4, rgba.len())?;
    let mut out = Vec::new();
    WebPEncoder::new_lossless(&mut out)
        .write_image(rgba, width, height, ExtendedColorType::Rgba8)
        .map_err(|e| ImageIoError::encode("WebP", e))?;
    Ok(out)
}

// ---------------------------------------------------------------------------------------------
// Depth: NumPy .npy

/// Encodes depth as a `.npy` float32 (little-endian) array of shape `(height, width)`, C order.
pub fn encode_depth_npy(width: u32, height: u32, depth: &[f32]) -> Result<Vec<u8>, ImageIoError> {
    use npyz::WriterBuilder;
    check_size(width, height, 1, depth.len())?;
    let encode = |e: std::io::Error| ImageIoError::encode("NPY", e);
    let mut out = Vec::with_capacity(128 + 4 * depth.len());
    let mut writer = npyz::WriteOptions::new()
        .default_dtype()
        .shape(&[u64::from(height), u64::from(width)])
        .writer(&mut out)
        .begin_nd()
        .map_err(encode)?;
    writer.extend(depth.iter().copied()).map_err(encode)?;
    writer.finish().map_err(encode)?;
    Ok(out)
}

/// Writes depth to `path` as `.npy` (see [`encode_depth_npy`]), atomically.
pub fn write_depth_npy(
    path: &Path,
    width: u32,
    height: u32,
    depth: &[f32],
) -> Result<(), ImageIoError> {
    write_bytes(path, &encode_depth_npy(width, height, depth)?)
}

/// Decodes a `.npy` float32 array of shape `(height, width)` (either byte order, C or Fortran
/// order); returns `(width, height, depth)` with depth row-major.
pub fn decode_depth_npy(bytes: &[u8]) -> Result<(u32, u32, Vec<f32>), ImageIoError> {
    let invalid = |msg: String| ImageIoError::decode("NPY", msg);
    // npyz trusts the header (it multiplies the shape unchecked and preallocates from it), so
    // the header length and the shape are validated here first.
    let (data_offset, shape) = npy_preflight(bytes).map_err(invalid)?;
    let [height, width] = shape;
    let npy = npyz::NpyFile::new(bytes).map_err(|e| ImageIoError::decode("NPY", e))?;
    match npy.dtype() {
        npyz::DType::Plain(t) if t.type_char() == npyz::TypeChar::Float && t.size_field() == 4 => {}
        other => {
            return Err(invalid(format!(
                "expected float32, found dtype {}",
                other.descr()
            )));
        }
    }
    let data_len = (bytes.len() - data_offset) as u64;
    let pixels = u64::from(width) * u64::from(height);
    if pixels > MAX_DECODE_PIXELS || data_len != 4 * pixels {
        return Err(invalid(format!(
            "shape ({height}, {width}) does not fit {data_len} data bytes or exceeds the size limit"
        )));
    }
    let order = npy.order();
    let values: Vec<f32> = npy.into_vec().map_err(|e| ImageIoError::decode("NPY", e))?;
    let depth = match order {
        npyz::Order::C => values,
        npyz::Order::Fortran => {
            // Stored column by column: element (i, j) sits at j * height + i.
            let (w, h) = (width as usize, height as usize);
            (0..h)
                .flat_map(|i| (0..w).map(move |j| (i, j)))
                .map(|(i, j)| values[j * h + i])
                .collect()
        }
    };
    Ok((width, height, depth))
}

/// Reads a `.npy` depth file (see [`decode_depth_npy`]).
pub fn read_depth_npy(path: &Path) -> Result<(u32, u32, Vec<f32>), ImageIoError> {
    decode_depth_npy(&read_bytes(path)?)
}

/// Validates the `.npy` preamble and extracts a 2-D shape that fits `u32`: returns the offset
/// of the data and `[rows, columns]`.
fn npy_preflight(bytes: &[u8]) -> Result<(usize, [u32; 2]), String> {
    const MAGIC: &[u8] = b"\x93NUMPY";
    if bytes.len() < 10 || !bytes.starts_with(MAGIC) {
        return Err("not an .npy file (bad magic)".into());
    }
    let (len_bytes, header_start) = match bytes[6] {
        1 => (2, 10),
        2 | 3 => (4, 12),
        v => return Err(format!("unsupported .npy version {v}")),
    };
    let Some(len_field) = bytes.get(8..8 + len_bytes) else {
        return Err("truncated header".into());
    };
    let header_len = len_field
        .iter()
        .rev()
        .fold(0_usize, |acc, &b| (acc << 8) | usize::from(b));
    let data_offset = header_start + header_len;
    let Some(header) = bytes.get(header_start..data_offset) else {
        return Err("truncated header".into());
    };
    let header = std::str::from_utf8(header).map_err(|_| "header is not UTF-8".to_string())?;
    let dims =
        npy_shape(header).ok_or_else(|| format!("no readable shape in header {header:?}"))?;
    match dims[..] {
        [rows, columns] => Ok((data_offset, [rows, columns])),
        _ => Err(format!(
            "expected a 2-D (height, width) array, found shape {dims:?}"
        )),
    }
}

/// The integers of the `'shape'` tuple of an `.npy` header dict, each fitting `u32`.
fn npy_shape(header: &str) -> Option<Vec<u32>> {
    let key = header
        .find("'shape'")
        .or_else(|| header.find("\"shape\""))?;
    let rest = header[key + "'shape'".len()..]
        .trim_start()
        .strip_prefix(':')?
        .trim_start();
    let rest = rest.strip_prefix('(').or_else(|| rest.strip_prefix('['))?;
    let end = rest.find([')', ']'])?;
    rest[..end]
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| s.parse::<u32>().ok())
        .collect()
}

// ---------------------------------------------------------------------------------------------
// Depth: OpenEXR

/// Encodes depth as a single-layer OpenEXR with one float32 channel `"Z"` (ZIP, lossless).
pub fn encode_depth_exr(width: u32, height: u32, depth: &[f32]) -> Result<Vec<u8>, ImageIoError> {
    use exr::prelude::{AnyChannel, AnyChannels, Encoding, FlatSamples, Image, Layer};
    use exr::prelude::{LayerAttributes, SmallVec, WritableImage};
    check_size(width, height, 1, depth.len())?;
    let channel = AnyChannel::new("Z", FlatSamples::F32(depth.to_vec()));
    let layer = Layer::new(
        (width as usize, height as usize),
        LayerAttributes::default(),
        Encoding::SMALL_LOSSLESS,
        AnyChannels::sort(SmallVec::from_elem(channel, 1)),
    );
    let mut out = Cursor::new(Vec::new());
    Image::from_layer(layer)
        .write()
        .to_buffered(&mut out)
        .map_err(|e| ImageIoError::encode("EXR", e))?;
    Ok(out.into_inner())
}

/// Writes depth to `path` as OpenEXR (see [`encode_depth_exr`]), atomically.
pub fn write_depth_exr(
    path: &Path,
    width: u32,
    height: u32,
    depth: &[f32],
) -> Result<(), ImageIoError> {
    write_bytes(path, &encode_depth_exr(width, height, depth)?)
}

/// Decodes the first layer of an OpenEXR file: its `"Z"` channel, or its only channel if it has
/// one; half-float and integer samples are converted to f32. Returns `(width, height, depth)`.
pub fn decode_depth_exr(bytes: &[u8]) -> Result<(u32, u32, Vec<f32>), ImageIoError> {
    use exr::prelude::{FlatSamples, ReadChannels, ReadLayers, read};
    let invalid = |msg: String| ImageIoError::decode("EXR", msg);
    let meta = exr::meta::MetaData::read_from_buffered(Cursor::new(bytes), false)
        .map_err(|e| ImageIoError::decode("EXR", e))?;
    if meta.requirements.has_deep_data {
        return Err(invalid("deep data is not supported".into()));
    }
    for header in &meta.headers {
        let area = (header.layer_size.0 as u64).checked_mul(header.layer_size.1 as u64);
        if area.is_none_or(|a| a > MAX_DECODE_PIXELS) {
            return Err(invalid(format!(
                "layer size {:?} exceeds the size limit",
                header.layer_size
            )));
        }
    }
    let image = read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .first_valid_layer()
        .all_attributes()
        .from_buffered(Cursor::new(bytes))
        .map_err(|e| ImageIoError::decode("EXR", e))?;
    let layer = image.layer_data;
    let channels = &layer.channel_data.list;
    let channel = match channels.iter().find(|c| c.name == *"Z") {
        Some(c) => c,
        None if channels.len() == 1 => &channels[0],
        None => {
            let names: Vec<String> = channels.iter().map(|c| c.name.to_string()).collect();
            return Err(invalid(format!("no \"Z\" channel among {names:?}")));
        }
    };
    let depth: Vec<f32> = match &channel.sample_data {
        FlatSamples::F32(v) => v.clone(),
        FlatSamples::F16(v) => v.iter().map(|h| h.to_f32()).collect(),
        FlatSamples::U32(v) => v.iter().map(|&u| u as f32).collect(),
    };
    let (Ok(width), Ok(height)) = (u32::try_from(layer.size.0), u32::try_from(layer.size.1)) else {
        return Err(invalid(format!(
            "layer size {:?} does not fit u32",
            layer.size
        )));
    };
    if depth.len() as u64 != u64::from(width) * u64::from(height) {
        return Err(invalid(format!(
            "channel has {} samples for a {width}x{height} layer (subsampled channels are not supported)",
            depth.len()
        )));
    }
    Ok((width, height, depth))
}

/// Reads an OpenEXR depth file (see [`decode_depth_exr`]).
pub fn read_depth_exr(path: &Path) -> Result<(u32, u32, Vec<f32>), ImageIoError> {
    decode_depth_exr(&read_bytes(path)?)
}

// ---------------------------------------------------------------------------------------------
// Depth: 16-bit PNG (for viewers)

/// Encodes depth as a 16-bit grey PNG: `round((d - near) / (far - near) · 65534)`, 65535 where
/// nothing is hit, with `near` and `far` the smallest and largest finite depths (both 0 when
/// none is finite). Returns the bytes and `(near, far)`, which a reader needs to map values back.
pub fn encode_depth_png16(
    width: u32,
    height: u32,
    depth: &[f32],
) -> Result<(Vec<u8>, (f32, f32)), ImageIoError> {
    check_size(width, height, 1, depth.len())?;
    let (near, far) = depth
        .iter()
        .filter(|d| d.is_finite())
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &d| {
            (lo.min(d), hi.max(d))
        });
    let (near, far) = if near.is_finite() {
        (near, far)
    } else {
        (0.0, 0.0)
    };
    let span = far - near;
    let values: Vec<u16> = depth
        .iter()
        .map(|&d| {
            if !d.is_finite() {
                u16::MAX
            } else if span > 0.0 {
                (((d - near) / span) * 65534.0).round().clamp(0.0, 65534.0) as u16
            } else {
                0
            }
        })
        .collect();
    let image = image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_raw(width, height, values)
        .ok_or_else(|| {
        ImageIoError::encode("PNG", "depth buffer size does not match the image")
    })?;
    let mut bytes = Vec::new();
    image
        .write_to(&mut Cursor::new(&mut bytes), ImageFormat::Png)
        .map_err(|e| ImageIoError::encode("PNG", e))?;
    Ok((bytes, (near, far)))
}

// ---------------------------------------------------------------------------------------------
// Depth: by extension

const DEPTH_EXTENSIONS: &str = ".npy or .exr";

/// Writes depth as `.npy` or `.exr`, chosen by the extension of `path` (case-insensitive).
pub fn write_depth(
    path: &Path,
    width: u32,
    height: u32,
    depth: &[f32],
) -> Result<(), ImageIoError> {
    match extension(path).as_deref() {
        Some("npy") => write_depth_npy(path, width, height, depth),
        Some("exr") => write_depth_exr(path, width, height, depth),
        _ => Err(ImageIoError::UnsupportedExtension {
            path: path.to_path_buf(),
            expected: DEPTH_EXTENSIONS,
        }),
    }
}

/// Reads depth from `.npy` or `.exr`, chosen by the extension of `path` (case-insensitive).
pub fn read_depth(path: &Path) -> Result<(u32, u32, Vec<f32>), ImageIoError> {
    match extension(path).as_deref() {
        Some("npy") => read_depth_npy(path),
        Some("exr") => read_depth_exr(path),
        _ => Err(ImageIoError::UnsupportedExtension {
            path: path.to_path_buf(),
            expected: DEPTH_EXTENSIONS,
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Depth values that must survive bit-exactly: ordinary, +inf (no hit), -inf, zeros of both
    /// signs, the smallest and largest denormals, the extremes, and NaNs with distinct payloads.
    fn tricky_depth() -> Vec<f32> {
        let mut d = vec![
            1.5,
            f32::INFINITY,
            f32::NEG_INFINITY,
            0.0,
            -0.0,
            f32::from_bits(1),
            f32::from_bits(0x007f_ffff),
            f32::MIN_POSITIVE,
            f32::MAX,
            f32::MIN,
            f32::NAN,
            f32::from_bits(0x7fc0_1234),
            f32::from_bits(0xffa0_0001),
            1e-3,
            123_456.79,
        ];
        d.extend((0..15).map(|k| k as f32 * 0.25 - 1.0));
        d
    }

    fn bits(v: &[f32]) -> Vec<u32> {
        v.iter().map(|x| x.to_bits()).collect()
    }

    #[test]
    fn npy_round_trip_is_bit_exact() {
        let depth = tricky_depth(); // 30 values: 6 wide, 5 high
        let bytes = encode_depth_npy(6, 5, &depth).unwrap();
        let header = String::from_utf8_lossy(&bytes[10..128]);
        assert!(
            header.contains("'descr': '<f4'") && header.contains("'shape': (5, 6, )"),
            "{header}"
        );
        let (w, h, back) = decode_depth_npy(&bytes).unwrap();
        assert_eq!((w, h), (6, 5));
        assert_eq!(bits(&back), bits(&depth));

        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("depth.npy");
        write_depth(&path, 6, 5, &depth).unwrap();
        let (w, h, back) = read_depth(&path).unwrap();
        assert_eq!((w, h, bits(&back)), (6, 5, bits(&depth)));
    }

    #[test]
    fn exr_round_trip_is_bit_exact() {
        let depth = tricky_depth();
        let bytes = encode_depth_exr(6, 5, &depth).unwrap();
        let (w, h, back) = decode_depth_exr(&bytes).unwrap();
        assert_eq!((w, h), (6, 5));
        assert_eq!(bits(&back), bits(&depth));

        // A realistic frame: a covered disc on +inf, larger than one 16-line ZIP block.
        let (w, h) = (37_u32, 41_u32);
        let frame: Vec<f32> = (0..w * h)
            .map(|k| {
                let (i, j) = ((k / w) as f32 - 20.0, (k % w) as f32 - 18.0);
                if i * i + j * j < 200.0 {
                    3.0 + 0.01 * i - 0.002 * j
                } else {
                    f32::INFINITY
                }
            })
            .collect();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("depth.EXR");
        write_depth(&path, w, h, &frame).unwrap();
        let (rw, rh, back) = read_depth(&path).unwrap();
        assert_eq!((rw, rh, bits(&back)), (w, h, bits(&frame)));
    }

    #[test]
    fn npy_fortran_order_and_big_endian_are_read() {
        // np.asfortranarray(np.arange(6, dtype='>f4').reshape(2, 3)): rows [0 1 2], [3 4 5].
        let header = "{'descr': '>f4', 'fortran_order': True, 'shape': (2, 3), }";
        let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
        let padded = format!("{header:<117}\n");
        bytes.extend((padded.len() as u16).to_le_bytes());
        bytes.extend(padded.as_bytes());
        for v in [0.0_f32, 3.0, 1.0, 4.0, 2.0, 5.0] {
            bytes.extend(v.to_be_bytes());
        }
        let (w, h, depth) = decode_depth_npy(&bytes).unwrap();
        assert_eq!((w, h), (3, 2));
        assert_eq!(depth, [0.0, 1.0, 2.0, 3.0, 4.0, 5.0]);
    }

    #[test]
    fn npy_rejects_bad_input_without_panicking() {
        let good = encode_depth_npy(3, 2, &[0.0; 6]).unwrap();
        let with_header = |h: &str| {
            let mut b = b"\x93NUMPY\x01\x00".to_vec();
            let padded = format!("{h:<117}\n");
            b.extend((padded.len() as u16).to_le_bytes());
            b.extend(padded.as_bytes());
            b.extend([0_u8; 24]);
            b
        };
        let cases: Vec<Vec<u8>> = vec![
            Vec::new(),
            b"not a numpy file at all".to_vec(),
            good[..good.len() - 1].to_vec(), // truncated data
            good[..50].to_vec(),             // truncated header
            // Header length pointing past the end (v2 header, u32 length).
            [b"\x93NUMPY\x02\x00".as_slice(), &u32::MAX.to_le_bytes()].concat(),
            // A shape whose product overflows u64, and one whose data is absent.
            with_header(
                "{'descr': '<f4', 'fortran_order': False, 'shape': (4294967296, 4294967296), }",
            ),
            with_header(
                "{'descr': '<f4', 'fortran_order': False, 'shape': (4294967295, 4294967295), }",
            ),
            with_header("{'descr': '<f4', 'fortran_order': False, 'shape': (6,), }"),
            with_header("{'descr': '<f8', 'fortran_order': False, 'shape': (1, 3), }"),
            with_header("{'descr': '|O', 'fortran_order': False, 'shape': (2, 3), }"),
            with_header("{'descr': '<f4', 'fortran_order': False, }"),
        ];
        for (k, bytes) in cases.iter().enumerate() {
            let result = decode_depth_npy(bytes);
            assert!(
                matches!(result, Err(ImageIoError::Decode { format: "NPY", .. })),
                "case {k}: {result:?}"
            );
        }
    }

    #[test]
    fn exr_rejects_bad_input_and_reads_other_layouts() {
        use exr::prelude::{AnyChannel, AnyChannels, Encoding, FlatSamples, Image, Layer};
        use exr::prelude::{LayerAttributes, WritableImage, f16};
        for bytes in [
            &b""[..],
            b"garbage",
            &encode_depth_exr(4, 4, &[1.0; 16]).unwrap()[..60],
        ] {
            assert!(matches!(
                decode_depth_exr(bytes),
                Err(ImageIoError::Decode { format: "EXR", .. })
            ));
        }
        // Two channels, none named Z: rejected; one channel with another name: accepted.
        let write = |names: &[&str]| {
            let list = names
                .iter()
                .map(|&n| AnyChannel::new(n, FlatSamples::F16(vec![f16::from_f32(0.5); 4])))
                .collect();
            let layer = Layer::new(
                (2, 2),
                LayerAttributes::default(),
                Encoding::UNCOMPRESSED,
                AnyChannels::sort(list),
            );
            let mut out = Cursor::new(Vec::new());
            Image::from_layer(layer)
                .write()
                .to_buffered(&mut out)
                .unwrap();
            out.into_inner()
        };
        assert!(matches!(
            decode_depth_exr(&write(&["A", "B"])),
            Err(ImageIoError::Decode { .. })
        ));
        assert_eq!(
            decode_depth_exr(&write(&["depth"])).unwrap(),
            (2, 2, vec![0.5; 4])
        );
        assert_eq!(
            decode_depth_exr(&write(&["A", "Z"])).unwrap(),
            (2, 2, vec![0.5; 4])
        );
    }

    #[test]
    fn png_round_trip_is_exact() {
        let (w, h) = (13_u32, 7_u32);
        let rgba: Vec<u8> = (0..w * h * 4).map(|k| (k * 37 % 256) as u8).collect();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("frame.png");
        write_png_rgba8(&path, w, h, &rgba).unwrap();
        assert_eq!(read_png_rgba8(&path).unwrap(), (w, h, rgba.clone()));
        assert_eq!(
            decode_png_rgba8(&encode_png_rgba8(w, h, &rgba).unwrap()).unwrap(),
            (w, h, rgba)
        );
        assert!(matches!(
            decode_png_rgba8(b"\x89PNG garbage"),
            Err(ImageIoError::Decode { format: "PNG", .. })
        ));
    }

    #[test]
    fn jpeg_composites_alpha_over_background() {
        // Left half transparent (must become the background), right half opaque grey.
        let (w, h) = (16_u32, 16_u32);
        let rgba: Vec<u8> = (0..w * h)
            .flat_map(|k| {
                if k % w < 8 {
                    [255, 0, 0, 0]
                } else {
                    [128, 128, 128, 255]
                }
            })
            .collect();
        let jpeg = encode_jpeg(w, h, &rgba, 95, [0, 0, 255]).unwrap();
        assert_eq!(&jpeg[..2], b"\xff\xd8");
        let decoded = image::load_from_memory_with_format(&jpeg, ImageFormat::Jpeg)
            .unwrap()
            .into_rgb8();
        let left = decoded.get_pixel(2, 8).0;
        let right = decoded.get_pixel(13, 8).0;
        assert!(left[2] > 230 && left[0] < 25, "{left:?}");
        assert!(right.iter().all(|&c| c.abs_diff(128) < 6), "{right:?}");
        // Quality outside 1..=100 is clamped, not an error.
        assert!(encode_jpeg(w, h, &rgba, 0, [0; 3]).is_ok());
        // Partial alpha blends: 200 at alpha 128 over 0 is round(200·128/255) = 100 (a flat
        // image at q100 decodes within a few levels).
        let half = [200, 200, 200, 128].repeat((w * h) as usize);
        let jpeg = encode_jpeg(w, h, &half, 100, [0; 3]).unwrap();
        let decoded = image::load_from_memory_with_format(&jpeg, ImageFormat::Jpeg)
            .unwrap()
            .into_rgb8();
        assert!(
            decoded
                .pixels()
                .all(|p| p.0.iter().all(|&c| c.abs_diff(100) <= 2)),
            "{:?}",
            decoded.get_pixel(0, 0)
        );
    }

    /// Odd sizes (partial 8×8 blocks at the edges), 1×1 and a smooth gradient decode to the
    /// encoded size, within the error JPEG allows at the quality: a smooth gradient comes back
    /// above 40 dB PSNR at q90 and above 32 dB at q50 (bounds any baseline 4:4:4 encoder meets
    /// on a gradient; a broken colour transform or block order misses them by far). Sides over
    /// 65535 px are an error.
    #[test]
    fn jpeg_sizes_and_quality() {
        for (w, h) in [(1_u32, 1_u32), (37, 23), (256, 9)] {
            let rgba: Vec<u8> = (0..w * h)
                .flat_map(|k| {
                    let (x, y) = (k % w, k / w);
                    [
                        (x * 255 / w.max(2)) as u8,
                        (y * 255 / h.max(2)) as u8,
                        90,
                        255,
                    ]
                })
                .collect();
            for (quality, floor_db) in [(90_u8, 40.0), (50, 32.0)] {
                let jpeg = encode_jpeg(w, h, &rgba, quality, [0; 3]).unwrap();
                let decoded = image::load_from_memory_with_format(&jpeg, ImageFormat::Jpeg)
                    .unwrap()
                    .into_rgb8();
                assert_eq!(decoded.dimensions(), (w, h));
                let mse = decoded
                    .as_raw()
                    .iter()
                    .zip(rgba.chunks_exact(4).flat_map(|p| &p[..3]))
                    .map(|(&a, &b)| (f64::from(a) - f64::from(b)).powi(2))
                    .sum::<f64>()
                    / f64::from(w * h * 3);
                let psnr = 10.0 * (255.0_f64 * 255.0 / mse.max(1e-10)).log10();
                assert!(psnr > floor_db, "{w}x{h} q{quality}: {psnr} dB");
            }
        }
        let wide = vec![0u8; 65_536 * 4];
        assert!(matches!(
            encode_jpeg(65_536, 1, &wide, 90, [0; 3]),
            Err(ImageIoError::Encode { format: "JPEG", .. })
        ));
    }

    /// Both encoders (libjpeg-turbo where the feature is on, `jpeg-encoder` otherwise) make
    /// baseline 4:4:4 JPEGs of the same quality scale: on a smooth gradient with an edge their
    /// decodings agree above 40 dB at q90 and their sizes within 15 %.
    #[cfg(feature = "turbojpeg")]
    #[test]
    fn turbojpeg_and_the_rust_encoder_agree() {
        let (w, h) = (96_u16, 64_u16);
        let rgb: Vec<u8> = (0..u32::from(w) * u32::from(h))
            .flat_map(|k| {
                let (x, y) = (k % u32::from(w), k / u32::from(w));
                let edge = if x > 50 { 60 } else { 0 };
                [(x * 2) as u8, (y * 3) as u8, (120 + edge) as u8]
            })
            .collect();
        let turbo = super::encode_rgb_jpeg(&rgb, w, h, 90).unwrap();
        let rust = super::encode_rgb_jpeg_rust(&rgb, w, h, 90).unwrap();
        let decode = |bytes: &[u8]| {
            image::load_from_memory_with_format(bytes, ImageFormat::Jpeg)
                .unwrap()
                .into_rgb8()
                .into_raw()
        };
        let (a, b) = (decode(&turbo), decode(&rust));
        let mse = a
            .iter()
            .zip(&b)
            .map(|(&x, &y)| (f64::from(x) - f64::from(y)).powi(2))
            .sum::<f64>()
            / a.len() as f64;
        let psnr = 10.0 * (255.0_f64 * 255.0 / mse.max(1e-10)).log10();
        assert!(psnr > 40.0, "{psnr} dB between the encoders");
        let ratio = turbo.len() as f64 / rust.len() as f64;
        assert!(
            (0.85..1.15).contains(&ratio),
            "sizes {} vs {}",
            turbo.len(),
            rust.len()
        );
    }

    #[test]
    fn webp_is_lossless() {
        let (w, h) = (9_u32, 5_u32);
        let rgba: Vec<u8> = (0..w * h * 4).map(|k| (k * 53 % 251) as u8).collect();
        let webp = encode_webp_lossless(w, h, &rgba).unwrap();
        let decoded = image::load_from_memory_with_format(&webp, ImageFormat::WebP)
            .unwrap()
            .into_rgba8();
        assert_eq!(decoded.into_raw(), rgba);
    }

    #[test]
    fn size_mismatch_is_an_error() {
        let err = encode_png_rgba8(4, 4, &[0; 63]).unwrap_err();
        assert!(matches!(
            err,
            ImageIoError::SizeMismatch {
                width: 4,
                height: 4,
                expected: 64,
                actual: 63
            }
        ));
        assert!(matches!(
            encode_jpeg(2, 2, &[0; 4], 90, [0; 3]),
            Err(ImageIoError::SizeMismatch { .. })
        ));
        assert!(matches!(
            encode_webp_lossless(2, 2, &[0; 4]),
            Err(ImageIoError::SizeMismatch { .. })
        ));
        assert!(matches!(
            encode_depth_npy(3, 3, &[0.0; 8]),
            Err(ImageIoError::SizeMismatch { .. })
        ));
        assert!(matches!(
            encode_depth_exr(3, 3, &[0.0; 10]),
            Err(ImageIoError::SizeMismatch { .. })
        ));
        assert!(matches!(
            encode_png_rgba8(u32::MAX, u32::MAX, &[]),
            Err(ImageIoError::SizeMismatch { .. })
        ));
    }

    #[test]
    fn unsupported_extension_is_an_error() {
        let dir = tempfile::tempdir().unwrap();
        for name in ["depth.png", "depth", "depth.npy.tmp"] {
            let path = dir.path().join(name);
            let err = write_depth(&path, 1, 1, &[1.0]).unwrap_err();
            assert!(
                matches!(&err, ImageIoError::UnsupportedExtension { path: p, .. } if *p == path)
            );
            assert!(err.to_string().contains(".npy or .exr"), "{err}");
            assert!(matches!(
                read_depth(&path),
                Err(ImageIoError::UnsupportedExtension { .. })
            ));
        }
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
    }

    #[test]
    fn failed_writes_leave_no_file() {
        let dir = tempfile::tempdir().unwrap();
        // Encoding fails: nothing is created.
        let path = dir.path().join("bad.npy");
        assert!(write_depth(&path, 2, 2, &[0.0; 3]).is_err());
        assert!(write_png_rgba8(&dir.path().join("bad.png"), 2, 2, &[0; 3]).is_err());
        // The directory does not exist: an Io error naming the path.
        let missing = dir.path().join("missing").join("d.exr");
        assert!(
            matches!(write_depth(&missing, 1, 1, &[1.0]), Err(ImageIoError::Io { path, .. }) if path == missing)
        );
        // The rename fails (a directory is in the way): the temporary file is removed again.
        let blocked = dir.path().join("blocked.png");
        std::fs::create_dir(&blocked).unwrap();
        std::fs::write(blocked.join("keep"), b"x").unwrap();
        assert!(matches!(
            write_png_rgba8(&blocked, 1, 1, &[1, 2, 3, 4]),
            Err(ImageIoError::Io { .. })
        ));
        let names: Vec<_> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names, ["blocked.png"]);
        // An existing file is replaced whole or not at all.
        let target = dir.path().join("d.npy");
        write_depth(&target, 1, 1, &[7.0]).unwrap();
        assert!(write_depth(&target, 1, 1, &[7.0, 8.0]).is_err());
        assert_eq!(read_depth(&target).unwrap(), (1, 1, vec![7.0]));
    }

    #[test]
    fn png16_depth_maps_the_finite_range_and_marks_misses() {
        let depth = [2.0, f32::INFINITY, 4.0, 3.0, f32::NAN, 2.5];
        let (bytes, range) = encode_depth_png16(3, 2, &depth).unwrap();
        assert_eq!(range, (2.0, 4.0));
        let image = ImageReader::with_format(Cursor::new(&bytes), ImageFormat::Png)
            .decode()
            .unwrap();
        assert_eq!((image.width(), image.height()), (3, 2));
        let values = image.into_luma16().into_raw();
        assert_eq!(values, [0, u16::MAX, 65534, 32767, u16::MAX, 16384]);
        // Nothing finite: the range is (0, 0) and every pixel a miss.
        let (bytes, range) = encode_depth_png16(1, 1, &[f32::INFINITY]).unwrap();
        assert_eq!(range, (0.0, 0.0));
        let image = ImageReader::with_format(Cursor::new(&bytes), ImageFormat::Png)
            .decode()
            .unwrap();
        assert_eq!(image.into_luma16().into_raw(), [u16::MAX]);
        // One depth everywhere: span 0 maps to 0.
        let (_, range) = encode_depth_png16(2, 1, &[1.5, 1.5]).unwrap();
        assert_eq!(range, (1.5, 1.5));
        assert!(matches!(
            encode_depth_png16(2, 2, &[1.0; 3]),
            Err(ImageIoError::SizeMismatch { .. })
        ));
    }
}
