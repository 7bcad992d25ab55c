//! INRIA (Inrimage 4) volumes, `.inr` or gzip-compressed `.inr.gz`: a header of 256-byte
//! blocks from `#INRIMAGE-4#{` to `##}`, then the voxels.
//!
//! Keys: `XDIM`, `YDIM`, `ZDIM`, `VDIM` (must be 1), `TYPE` (`unsigned fixed`, `signed fixed`,
//! `float`), `PIXSIZE` (`8 bits` … `64 bits`), `SCALE=2**n` (fixed-point: a value is the stored
//! integer divided by 2ⁿ), `CPU` (`decm`, `alpha`, `pc`: little-endian; `sun`, `sgi`: big-endian),
//! `VX`, `VY`, `VZ` (spacing, default 1). The origin is 0 (the format has none).

use std::io::Read;

use super::{
    RawVolume, Result, VolumeFormat, VoxelType, data_bytes, diagonal, exact, header_error,
    inflate_exact,
};

const FORMAT: VolumeFormat = VolumeFormat::Inria;
const MAGIC: &[u8] = b"#INRIMAGE-4#{";
const END: &[u8] = b"##}";

pub(super) fn read(bytes: &[u8], gz: bool) -> Result<RawVolume> {
    // The header is at most 1 MiB of 256-byte blocks; a gzip file is inflated that far first.
    let head = if gz {
        let mut out = Vec::new();
        flate2::read::MultiGzDecoder::new(bytes)
            .take(super::MAX_HEADER_BYTES as u64)
            .read_to_end(&mut out)
            .map_err(|e| header_error(FORMAT, format!("gzip: {e}")))?;
        out
    } else {
        bytes[..bytes.len().min(super::MAX_HEADER_BYTES)].to_vec()
    };
    if !head.starts_with(MAGIC) {
        return Err(header_error(
            FORMAT,
            "not an INRIA file (magic #INRIMAGE-4#{)",
        ));
    }
    let end = head
        .windows(END.len())
        .position(|w| w == END)
        .ok_or_else(|| header_error(FORMAT, "the header has no ##} end (or is over 1 MiB)"))?;
    // The header fills whole 256-byte blocks, the last ending in "##}\n".
    let header_len = (end + END.len() + 1).div_ceil(256) * 256;
    let text = std::str::from_utf8(&head[MAGIC.len()..end])
        .map_err(|_| header_error(FORMAT, "the header is not text"))?;
    let mut fields = Vec::new();
    for line in text
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty() && !l.starts_with('#'))
    {
        let (key, value) = line.split_once('=').ok_or_else(|| {
            header_error(FORMAT, format!("header line {line:?} is not KEY=VALUE"))
        })?;
        fields.push((key.trim().to_ascii_uppercase(), value.trim().to_owned()));
    }
    let get = |key: &str| {
        fields
            .iter()
            .find(|(k, _)| k == key)
            .map(|(_, v)| v.as_str())
    };
    let int = |key: &str, default: Option<u64>| -> Result<u64> {
        match get(key) {
            None => default.ok_or_else(|| header_error(FORMAT, format!("{key} is missing"))),
            Some(v) => v.parse().map_err(|_| {
                header_error(FORMAT, format!("{key}={v} is not a non-negative integer"))
            }),
        }
    };
    let dims = [
        int("XDIM", None)?,
        int("YDIM", None)?,
        int("ZDIM", Some(1))?,
    ];
    let vdim = int("VDIM", Some(1))?;
    if vdim != 1 {
        return Err(header_error(
            FORMAT,
            format!("VDIM={vdim}: only scalar volumes are supported"),
        ));
    }
    let bits = get("PIXSIZE")
        .ok_or_else(|| header_error(FORMAT, "PIXSIZE is missing"))?
        .trim_end_matches("bits")
        .trim()
        .to_owned();
    let ty = get("TYPE").ok_or_else(|| header_error(FORMAT, "TYPE is missing"))?;
    let voxel_type = match (ty.to_ascii_lowercase().as_str(), bits.as_str()) {
        ("unsigned fixed", "8") => VoxelType::U8,
        ("unsigned fixed", "16") => VoxelType::U16,
        ("unsigned fixed", "32") => VoxelType::U32,
        ("unsigned fixed", "64") => VoxelType::U64,
        ("signed fixed", "8") => VoxelType::I8,
        ("signed fixed", "16") => VoxelType::I16,
        ("signed fixed", "32") => VoxelType::I32,
        ("signed fixed", "64") => VoxelType::I64,
        ("float", "32") => VoxelType::F32,
        ("float", "64") => VoxelType::F64,
        _ => {
            return Err(header_error(
                FORMAT,
                format!("TYPE={ty} with PIXSIZE={bits} bits is not supported"),
            ));
        }
    };
    let big_endian = match get("CPU").map(str::to_ascii_lowercase).as_deref() {
        None | Some("decm" | "alpha" | "pc") => false,
        Some("sun" | "sgi") => true,
        Some(other) => return Err(header_error(FORMAT, format!("CPU={other} is unknown"))),
    };
    let scale = match get("SCALE") {
        None => 1.0,
        Some(s) => {
            let exponent: i32 = s
                .strip_prefix("2**")
                .and_then(|e| e.trim().parse().ok())
                .filter(|e| (0..=63).contains(e))
                .ok_or_else(|| {
                    header_error(FORMAT, format!("SCALE={s} is not 2**n with n in 0..=63"))
                })?;
            if voxel_type == VoxelType::F32 || voxel_type == VoxelType::F64 {
                1.0
            } else {
                2f64.powi(-exponent)
            }
        }
    };
    let spacing = ["VX", "VY", "VZ"].map(|k| get(k).map_or(Ok(1.0), str::parse::<f64>));
    let spacing = match spacing {
        [Ok(x), Ok(y), Ok(z)] => [x, y, z],
        _ => return Err(header_error(FORMAT, "VX, VY or VZ is not a number")),
    };
    let expected = data_bytes(&dims, voxel_type)?;
    let data = if gz {
        let all = inflate_exact(
            FORMAT,
            flate2::read::MultiGzDecoder::new(bytes),
            header_len as u64 + expected,
        )?;
        all[header_len..].to_vec()
    } else {
        exact(
            FORMAT,
            bytes.get(header_len..).unwrap_or_default(),
            expected,
        )?
    };
    Ok(RawVolume {
        dims,
        voxel_type,
        big_endian,
        scale: (scale, 0.0),
        affine: diagonal(spacing),
        origin: [0.0; 3],
        data,
    })
}
