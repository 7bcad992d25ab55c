//! MetaImage (ITK) volumes: `.mha` with the data after the header (`ElementDataFile = LOCAL`),
//! `.mhd` with the data in the file `ElementDataFile` names (relative to the header's folder).
//!
//! Header keys (case-insensitive, `Key = Value`, one per line): `NDims` 2 or 3, `DimSize`,
//! `ElementType` (`MET_UCHAR`, `MET_CHAR`, `MET_USHORT`, `MET_SHORT`, `MET_UINT`, `MET_INT`,
//! `MET_ULONG_LONG`, `MET_LONG_LONG`, `MET_FLOAT`, `MET_DOUBLE`), `ElementSpacing` (or
//! `ElementSize`), `Offset` (or `Origin`, `Position`), `TransformMatrix` (or `Rotation`,
//! `Orientation`: nine numbers, the first three the direction of the i axis, as ITK writes it),
//! `BinaryDataByteOrderMSB` (or `ElementByteOrderMSB`), `CompressedData` (zlib),
//! `ElementNumberOfChannels` 1, `HeaderSize` (bytes to skip in the data file; −1: the data is
//! the file's end). `ElementDataFile` ends the header. Lists of files are not supported.

use std::path::Path;

use super::{
    RawVolume, Result, VolumeFormat, VoxelType, data_bytes, exact, header_error, header_line,
    inflate_exact, numbers, read_detached,
};

const FORMAT: VolumeFormat = VolumeFormat::MetaImage;

pub(super) fn read(bytes: &[u8], folder: Option<&Path>) -> Result<RawVolume> {
    let mut fields: Vec<(String, String)> = Vec::new();
    let mut at = 0usize;
    let mut data_file = None;
    while data_file.is_none() {
        let line = header_line(FORMAT, bytes, &mut at)?
            .ok_or_else(|| header_error(FORMAT, "the header has no ElementDataFile line"))?
            .trim();
        if line.is_empty() {
            continue;
        }
        let (key, value) = line.split_once('=').ok_or_else(|| {
            header_error(FORMAT, format!("header line {line:?} is not Key = Value"))
        })?;
        let (key, value) = (key.trim().to_ascii_lowercase(), value.trim().to_owned());
        if key == "elementdatafile" {
            data_file = Some(value);
        } else {
            fields.push((key, value));
        }
    }
    let data_file = data_file.unwrap_or_default();
    let get = |names: &[&str]| {
        fields
            .iter()
            .rev()
            .find(|(k, _)| names.contains(&k.as_str()))
            .map(|(_, v)| v.as_str())
    };
    let flag = |names: &[&str]| get(names).is_some_and(|v| v.eq_ignore_ascii_case("true"));

    let ndims = get(&["ndims"]).ok_or_else(|| header_error(FORMAT, "NDims is missing"))?;
    let ndims: usize = ndims
        .parse()
        .ok()
        .filter(|n| (2..=3).contains(n))
        .ok_or_else(|| header_error(FORMAT, format!("NDims {ndims} is not 2 or 3")))?;
    let channels = get(&["elementnumberofchannels"]).unwrap_or("1");
    if channels != "1" {
        return Err(header_error(
            FORMAT,
            format!("ElementNumberOfChannels {channels}: only scalar volumes are supported"),
        ));
    }
    let pad =
        |v: Vec<f64>, fill: f64| -> [f64; 3] { [v[0], v[1], v.get(2).copied().unwrap_or(fill)] };
    let list = |key: &str, names: &[&str], n: usize| -> Result<Option<Vec<f64>>> {
        let Some(value) = get(names) else {
            return Ok(None);
        };
        let v: Vec<f64> = if n == 2 {
            numbers::<2>(FORMAT, key, value)?.to_vec()
        } else if n == 3 {
            numbers::<3>(FORMAT, key, value)?.to_vec()
        } else if n == 4 {
            numbers::<4>(FORMAT, key, value)?.to_vec()
        } else {
            numbers::<9>(FORMAT, key, value)?.to_vec()
        };
        Ok(Some(v))
    };
    let dims = list("DimSize", &["dimsize"], ndims)?
        .ok_or_else(|| header_error(FORMAT, "DimSize is missing"))?;
    if dims
        .iter()
        .any(|d| !(d.fract() == 0.0 && *d >= 1.0 && *d <= 1e9))
    {
        return Err(header_error(
            FORMAT,
            format!("DimSize {dims:?} is not positive integers"),
        ));
    }
    let dims = pad(dims, 1.0).map(|d| d as u64);
    let voxel_type = match get(&["elementtype"])
        .map(str::to_ascii_uppercase)
        .as_deref()
    {
        Some("MET_UCHAR") => VoxelType::U8,
        Some("MET_CHAR") => VoxelType::I8,
        Some("MET_USHORT") => VoxelType::U16,
        Some("MET_SHORT") => VoxelType::I16,
        Some("MET_UINT" | "MET_ULONG") => VoxelType::U32,
        Some("MET_INT" | "MET_LONG") => VoxelType::I32,
        Some("MET_ULONG_LONG") => VoxelType::U64,
        Some("MET_LONG_LONG") => VoxelType::I64,
        Some("MET_FLOAT") => VoxelType::F32,
        Some("MET_DOUBLE") => VoxelType::F64,
        Some(other) => {
            return Err(header_error(
                FORMAT,
                format!("ElementType {other} is not a scalar integer or float type"),
            ));
        }
        None => return Err(header_error(FORMAT, "ElementType is missing")),
    };
    let spacing = list("ElementSpacing", &["elementspacing", "elementsize"], ndims)?
        .map_or([1.0; 3], |v| pad(v, 1.0));
    let origin =
        list("Offset", &["offset", "origin", "position"], ndims)?.map_or([0.0; 3], |v| pad(v, 0.0));
    let direction: [[f64; 3]; 3] = match list(
        "TransformMatrix",
        &["transformmatrix", "rotation", "orientation"],
        ndims * ndims,
    )? {
        None => [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        Some(m) if ndims == 3 => [[m[0], m[1], m[2]], [m[3], m[4], m[5]], [m[6], m[7], m[8]]],
        Some(m) => [[m[0], m[1], 0.0], [m[2], m[3], 0.0], [0.0, 0.0, 1.0]],
    };
    let affine = [0, 1, 2].map(|c| direction[c].map(|x| x * spacing[c]));
    let big_endian = flag(&["binarydatabyteordermsb", "elementbyteordermsb"]);
    let compressed = flag(&["compresseddata"]);
    if get(&["binarydata"]).is_some_and(|v| !v.eq_ignore_ascii_case("true")) {
        return Err(header_error(
            FORMAT,
            "BinaryData = False (text data) is not supported",
        ));
    }
    let expected = data_bytes(&dims, voxel_type)?;

    let detached;
    let source: &[u8] = if data_file.eq_ignore_ascii_case("local") {
        bytes.get(at..).unwrap_or_default()
    } else if data_file.eq_ignore_ascii_case("list") || data_file.contains('%') {
        return Err(header_error(
            FORMAT,
            format!("ElementDataFile {data_file}: file lists are not supported"),
        ));
    } else {
        detached = read_detached(FORMAT, folder, &data_file)?;
        &detached
    };
    let skip: i64 = get(&["headersize"])
        .map(str::parse)
        .transpose()
        .map_err(|_| header_error(FORMAT, "HeaderSize is not an integer"))?
        .unwrap_or(0);
    let source = match skip {
        0 => source,
        -1 if !compressed => source
            .get(source.len().saturating_sub(expected as usize)..)
            .unwrap_or_default(),
        s if s > 0 => source.get(s as usize..).unwrap_or_default(),
        s => {
            return Err(header_error(
                FORMAT,
                format!("HeaderSize {s} is not allowed"),
            ));
        }
    };
    let data = if compressed {
        inflate_exact(FORMAT, flate2::read::ZlibDecoder::new(source), expected)?
    } else {
        exact(FORMAT, source, expected)?
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
