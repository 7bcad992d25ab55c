//! NRRD volumes (`NRRD0001`–`NRRD0005`): `.nrrd` with the data after the header's blank line,
//! `.nhdr` with the data in the file `data file` names (relative to the header's folder).
//!
//! Fields: `type` (every integer and float spelling of the standard), `dimension` 2 or 3,
//! `sizes`, `encoding` `raw`, `gzip`/`gz` or `ascii`/`text`/`txt`, `endian`, `space directions`
//! (one vector per axis: the columns of the affine; `none` is refused) or `spacings`, `space
//! origin`, `byte skip` (−1 with raw data: the data is the file's end) and `line skip`. Key/value
//! pairs (`key:=value`) and comments are ignored.

use std::io::Read;
use std::path::Path;

use super::{
    RawVolume, Result, VolumeFormat, VoxelType, data_bytes, diagonal, exact, header_error,
    header_line, inflate_exact, read_detached,
};

const FORMAT: VolumeFormat = VolumeFormat::Nrrd;

pub(super) fn read(bytes: &[u8], folder: Option<&Path>) -> Result<RawVolume> {
    if !(bytes.starts_with(b"NRRD000") && bytes.len() > 8 && (b'1'..=b'5').contains(&bytes[7])) {
        return Err(header_error(
            FORMAT,
            "not an NRRD file (magic NRRD0001..NRRD0005)",
        ));
    }
    let mut fields: Vec<(String, String)> = Vec::new();
    let mut at = bytes
        .iter()
        .position(|&b| b == b'\n')
        .map_or(bytes.len(), |p| p + 1);
    while let Some(line) = header_line(FORMAT, bytes, &mut at)? {
        if line.is_empty() {
            break;
        }
        if line.starts_with('#') || line.contains(":=") {
            continue;
        }
        let (key, value) = line.split_once(": ").ok_or_else(|| {
            header_error(
                FORMAT,
                format!("header line {line:?} is not `field: value`"),
            )
        })?;
        fields.push((key.trim().to_ascii_lowercase(), value.trim().to_owned()));
    }
    let get = |names: &[&str]| {
        fields
            .iter()
            .find(|(k, _)| names.contains(&k.as_str()))
            .map(|(_, v)| v.as_str())
    };
    let dimension =
        get(&["dimension"]).ok_or_else(|| header_error(FORMAT, "dimension is missing"))?;
    let dimension: usize = dimension
        .parse()
        .ok()
        .filter(|n| (2..=3).contains(n))
        .ok_or_else(|| header_error(FORMAT, format!("dimension {dimension} is not 2 or 3")))?;
    let sizes: Vec<u64> = get(&["sizes"])
        .ok_or_else(|| header_error(FORMAT, "sizes is missing"))?
        .split_whitespace()
        .map(str::parse)
        .collect::<Result<_, _>>()
        .map_err(|_| header_error(FORMAT, "sizes is not a list of integers"))?;
    if sizes.len() != dimension {
        return Err(header_error(
            FORMAT,
            format!("sizes has {} values for dimension {dimension}", sizes.len()),
        ));
    }
    let dims = [sizes[0], sizes[1], sizes.get(2).copied().unwrap_or(1)];
    let ty = get(&["type"]).ok_or_else(|| header_error(FORMAT, "type is missing"))?;
    let voxel_type = match ty.to_ascii_lowercase().as_str() {
        "signed char" | "int8" | "int8_t" => VoxelType::I8,
        "uchar" | "unsigned char" | "uint8" | "uint8_t" => VoxelType::U8,
        "short" | "short int" | "signed short" | "signed short int" | "int16" | "int16_t" => {
            VoxelType::I16
        }
        "ushort" | "unsigned short" | "unsigned short int" | "uint16" | "uint16_t" => {
            VoxelType::U16
        }
        "int" | "signed int" | "int32" | "int32_t" => VoxelType::I32,
        "uint" | "unsigned int" | "uint32" | "uint32_t" => VoxelType::U32,
        "longlong"
        | "long long"
        | "long long int"
        | "signed long long"
        | "signed long long int"
        | "int64"
        | "int64_t" => VoxelType::I64,
        "ulonglong" | "unsigned long long" | "unsigned long long int" | "uint64" | "uint64_t" => {
            VoxelType::U64
        }
        "float" => VoxelType::F32,
        "double" => VoxelType::F64,
        other => {
            return Err(header_error(
                FORMAT,
                format!("type {other:?} is not supported"),
            ));
        }
    };
    let encoding = get(&["encoding"])
        .ok_or_else(|| header_error(FORMAT, "encoding is missing"))?
        .to_ascii_lowercase();
    let big_endian = match get(&["endian"]).map(str::to_ascii_lowercase).as_deref() {
        Some("big") => true,
        Some("little") => false,
        None if voxel_type.bytes() == 1
            || matches!(encoding.as_str(), "ascii" | "text" | "txt") =>
        {
            false
        }
        None => {
            return Err(header_error(
                FORMAT,
                "endian is missing for multi-byte voxels",
            ));
        }
        Some(other) => {
            return Err(header_error(
                FORMAT,
                format!("endian {other:?} is not big or little"),
            ));
        }
    };
    let affine = if let Some(directions) = get(&["space directions"]) {
        let vectors: Vec<&str> = directions.split_whitespace().collect();
        if vectors.len() != dimension || vectors.contains(&"none") {
            return Err(header_error(
                FORMAT,
                format!("space directions {directions:?} needs one vector per axis (no `none`)"),
            ));
        }
        let mut columns = [[0.0; 3], [0.0; 3], [0.0, 0.0, 1.0]];
        for (c, v) in vectors.iter().enumerate() {
            let parsed: Vec<f64> = v
                .trim_matches(|ch| ch == '(' || ch == ')')
                .split(',')
                .map(|x| x.trim().parse())
                .collect::<Result<_, _>>()
                .map_err(|_| {
                    header_error(FORMAT, format!("space direction {v} is not a vector"))
                })?;
            if !(2..=3).contains(&parsed.len()) {
                return Err(header_error(
                    FORMAT,
                    format!("space direction {v} is not a 2- or 3-vector"),
                ));
            }
            for (r, x) in parsed.iter().enumerate() {
                columns[c][r] = *x;
            }
        }
        columns
    } else if let Some(spacings) = get(&["spacings"]) {
        let s: Vec<f64> = spacings
            .split_whitespace()
            .map(str::parse)
            .collect::<Result<_, _>>()
            .map_err(|_| header_error(FORMAT, "spacings is not a list of numbers"))?;
        if s.len() != dimension {
            return Err(header_error(
                FORMAT,
                format!("spacings has {} values", s.len()),
            ));
        }
        diagonal([s[0], s[1], s.get(2).copied().unwrap_or(1.0)])
    } else {
        diagonal([1.0; 3])
    };
    let origin = match get(&["space origin"]) {
        None => [0.0; 3],
        Some(o) => {
            let v: Vec<f64> = o
                .trim_matches(|ch| ch == '(' || ch == ')')
                .split(',')
                .map(|x| x.trim().parse())
                .collect::<Result<_, _>>()
                .map_err(|_| header_error(FORMAT, format!("space origin {o} is not a vector")))?;
            match v[..] {
                [x, y] => [x, y, 0.0],
                [x, y, z] => [x, y, z],
                _ => {
                    return Err(header_error(
                        FORMAT,
                        format!("space origin {o} is not a 2- or 3-vector"),
                    ));
                }
            }
        }
    };
    let expected = data_bytes(&dims, voxel_type)?;

    let detached;
    let mut source: &[u8] = match get(&["data file", "datafile"]) {
        None => bytes.get(at..).unwrap_or_default(),
        Some(name) if name.contains(' ') || name.starts_with("LIST") => {
            return Err(header_error(
                FORMAT,
                format!("data file {name:?}: file lists are not supported"),
            ));
        }
        Some(name) => {
            detached = read_detached(FORMAT, folder, name)?;
            &detached
        }
    };
    let count = |key: &[&str]| -> Result<i64> {
        get(key)
            .map(str::parse)
            .transpose()
            .map_err(|_| header_error(FORMAT, format!("{} is not an integer", key[0])))
            .map(|v| v.unwrap_or(0))
    };
    let line_skip = count(&["line skip", "lineskip"])?;
    if line_skip < 0 {
        return Err(header_error(FORMAT, "line skip is negative"));
    }
    for _ in 0..line_skip {
        let next = source
            .iter()
            .position(|&b| b == b'\n')
            .ok_or_else(|| header_error(FORMAT, "line skip runs past the end of the data"))?;
        source = &source[next + 1..];
    }
    let byte_skip = count(&["byte skip", "byteskip"])?;
    let data = match encoding.as_str() {
        "raw" => {
            let source = match byte_skip {
                -1 => source
                    .get(source.len().saturating_sub(expected as usize)..)
                    .unwrap_or_default(),
                s if s >= 0 => source.get(s as usize..).unwrap_or_default(),
                s => {
                    return Err(header_error(
                        FORMAT,
                        format!("byte skip {s} is not allowed"),
                    ));
                }
            };
            exact(FORMAT, source, expected)?
        }
        "gzip" | "gz" => {
            if byte_skip < 0 {
                return Err(header_error(FORMAT, "byte skip -1 needs raw encoding"));
            }
            let mut decoder = flate2::read::MultiGzDecoder::new(source);
            std::io::copy(
                &mut (&mut decoder).take(byte_skip as u64),
                &mut std::io::sink(),
            )
            .map_err(|e| header_error(FORMAT, format!("gzip: {e}")))?;
            inflate_exact(FORMAT, decoder, expected)?
        }
        "ascii" | "text" | "txt" => ascii(source, voxel_type, big_endian, expected)?,
        other => {
            return Err(header_error(
                FORMAT,
                format!("encoding {other:?} is not supported (raw, gzip or ascii)"),
            ));
        }
    };
    Ok(RawVolume {
        dims,
        voxel_type,
        big_endian,
        scale: (1.0, 0.0),
        affine,
        origin,
        data,
    })
}

/// Text voxels re-encoded as the stored type (so one decoder serves every encoding).
fn ascii(source: &[u8], ty: VoxelType, big_endian: bool, expected: u64) -> Result<Vec<u8>> {
    let text =
        std::str::from_utf8(source).map_err(|_| header_error(FORMAT, "ascii data is not text"))?;
    encode_text(FORMAT, text, ty, big_endian, expected)
}

/// Whitespace- or comma-separated numbers re-encoded as `ty`: exactly `expected` bytes' worth,
/// else a [`super::VolumeError::DataSize`] (NRRD `ascii`, VTK `ascii`).
pub(super) fn encode_text(
    format: VolumeFormat,
    text: &str,
    ty: VoxelType,
    big_endian: bool,
    expected: u64,
) -> Result<Vec<u8>> {
    let source = text.as_bytes();
    let count = expected / ty.bytes() as u64;
    let mut out = Vec::with_capacity(expected.min(source.len() as u64 * 8) as usize);
    let mut found = 0u64;
    for word in text
        .split(|c: char| c.is_whitespace() || c == ',')
        .filter(|w| !w.is_empty())
    {
        found += 1;
        if found > count {
            break;
        }
        let v: f64 = word
            .parse()
            .map_err(|_| header_error(format, format!("ascii value {word:?} is not a number")))?;
        let be = big_endian;
        macro_rules! put {
            ($t:ty) => {{
                let x = v as $t;
                out.extend_from_slice(&if be { x.to_be_bytes() } else { x.to_le_bytes() });
            }};
        }
        match ty {
            VoxelType::U8 => put!(u8),
            VoxelType::I8 => put!(i8),
            VoxelType::U16 => put!(u16),
            VoxelType::I16 => put!(i16),
            VoxelType::U32 => put!(u32),
            VoxelType::I32 => put!(i32),
            VoxelType::U64 => put!(u64),
            VoxelType::I64 => put!(i64),
            VoxelType::F32 => put!(f32),
            VoxelType::F64 => put!(f64),
        }
    }
    if found != count {
        return Err(super::VolumeError::DataSize {
            format,
            expected,
            found: found.saturating_mul(ty.bytes() as u64),
        });
    }
    Ok(out)
}
