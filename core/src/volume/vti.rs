//! VTK XML image data (`.vti`): one piece covering the `WholeExtent`, the point-data array
//! named by `PointData Scalars` (else the first point-data array), one component.
//!
//! Data formats: `ascii`, `binary` (base64 inside the `DataArray`) and `appended` (after the
//! `_` of `AppendedData`, `encoding="raw"` or `"base64"`, at the array's `offset`), each
//! uncompressed or with `compressor="vtkZLibDataCompressor"` (zlib blocks behind a header of
//! `header_type` integers: block count, block size, last block size, compressed sizes).
//! Uncompressed base64 data is read as one stream of header and data (as VTK and meshio write
//! it), or as a separately encoded header followed by the data. Index `(i, j, k)` relative to
//! the extent's first point is at `Origin + Direction·(Spacing ⊙ (extent₀ + (i, j, k)))`.

use std::io::Read;

use base64::Engine;
use quick_xml::events::{BytesStart, Event};

use super::{
    RawVolume, Result, VolumeError, VolumeFormat, VoxelType, data_bytes, exact, header_error,
};

const FORMAT: VolumeFormat = VolumeFormat::Vti;
const B64: base64::engine::GeneralPurpose = base64::engine::general_purpose::STANDARD;

#[derive(Default)]
struct Array {
    ty: String,
    name: String,
    format: String,
    offset: Option<usize>,
    components: String,
    text: String,
}

pub(super) fn read(bytes: &[u8]) -> Result<RawVolume> {
    // The appended section is raw bytes, not XML: split it off before parsing.
    let (xml, appended) = match find(bytes, b"<AppendedData") {
        Some(at) => {
            let tag_end = bytes[at..]
                .iter()
                .position(|&b| b == b'>')
                .map(|p| at + p)
                .ok_or_else(|| header_error(FORMAT, "AppendedData tag is not closed"))?;
            let tag = String::from_utf8_lossy(&bytes[at..=tag_end]).into_owned();
            let underscore = bytes[tag_end..]
                .iter()
                .position(|&b| b == b'_')
                .map(|p| tag_end + p)
                .ok_or_else(|| header_error(FORMAT, "AppendedData has no `_` marker"))?;
            // Raw data ends where the closing tag begins: data that runs into it is truncated.
            let section = &bytes[underscore + 1..];
            let end = section
                .windows(b"</AppendedData>".len())
                .rposition(|w| w == b"</AppendedData>")
                .ok_or_else(|| header_error(FORMAT, "AppendedData is not closed"))?;
            (&bytes[..at], Some((tag, &section[..end])))
        }
        None => (bytes, None),
    };
    let xml = std::str::from_utf8(xml).map_err(|_| header_error(FORMAT, "the XML is not UTF-8"))?;
    let mut reader = quick_xml::Reader::from_str(xml);
    let mut file_attrs = Vec::new();
    let mut image_attrs = Vec::new();
    let mut piece_extent = None;
    let mut scalars_name = None;
    let mut arrays: Vec<Array> = Vec::new();
    let mut in_point_data = false;
    let mut in_array = false;
    let mut saw_cell_data = false;
    loop {
        let event = reader
            .read_event()
            .map_err(|e| header_error(FORMAT, format!("XML: {e}")))?;
        match event {
            Event::Start(e) | Event::Empty(e) => {
                let attrs = attributes(&e)?;
                match e.local_name().as_ref() {
                    b"VTKFile" => file_attrs = attrs,
                    b"ImageData" => image_attrs = attrs,
                    b"Piece" => piece_extent = get(&attrs, "Extent").map(str::to_owned),
                    b"PointData" => {
                        in_point_data = true;
                        scalars_name = get(&attrs, "Scalars").map(str::to_owned);
                    }
                    b"CellData" => saw_cell_data = true,
                    b"DataArray" if in_point_data => {
                        in_array = true;
                        arrays.push(Array {
                            ty: get(&attrs, "type").unwrap_or_default().to_owned(),
                            name: get(&attrs, "Name").unwrap_or_default().to_owned(),
                            format: get(&attrs, "format").unwrap_or("ascii").to_owned(),
                            offset: get(&attrs, "offset").and_then(|o| o.trim().parse().ok()),
                            components: get(&attrs, "NumberOfComponents").unwrap_or("1").to_owned(),
                            text: String::new(),
                        });
                    }
                    _ => {}
                }
            }
            Event::Text(t) if in_array => {
                let text = t
                    .decode()
                    .map_err(|e| header_error(FORMAT, format!("XML text: {e}")))?;
                if let Some(array) = arrays.last_mut() {
                    array.text.push_str(&text);
                }
            }
            Event::End(e) => match e.local_name().as_ref() {
                b"PointData" => in_point_data = false,
                b"DataArray" => in_array = false,
                _ => {}
            },
            Event::Eof => break,
            _ => {}
        }
    }
    if get(&file_attrs, "type") != Some("ImageData") {
        return Err(header_error(FORMAT, "not a VTKFile of type ImageData"));
    }
    let big_endian = match get(&file_attrs, "byte_order").unwrap_or("LittleEndian") {
        "LittleEndian" => false,
        "BigEndian" => true,
        other => {
            return Err(header_error(
                FORMAT,
                format!("byte_order {other} is unknown"),
            ));
        }
    };
    let header_type = match get(&file_attrs, "header_type").unwrap_or("UInt32") {
        "UInt32" => VoxelType::U32,
        "UInt64" => VoxelType::U64,
        other => {
            return Err(header_error(
                FORMAT,
                format!("header_type {other} is unknown"),
            ));
        }
    };
    let compressed = match get(&file_attrs, "compressor") {
        None | Some("") => false,
        Some("vtkZLibDataCompressor") => true,
        Some(other) => {
            return Err(header_error(
                FORMAT,
                format!("compressor {other} is not supported (vtkZLibDataCompressor is)"),
            ));
        }
    };
    let extent = get(&image_attrs, "WholeExtent")
        .ok_or_else(|| header_error(FORMAT, "ImageData has no WholeExtent"))?;
    let e: [f64; 6] = super::numbers(FORMAT, "WholeExtent", extent)?;
    if e.iter().any(|x| x.fract() != 0.0 || x.abs() > 1e9)
        || e[1] < e[0]
        || e[3] < e[2]
        || e[5] < e[4]
    {
        return Err(header_error(
            FORMAT,
            format!("WholeExtent {extent:?} is not a valid extent"),
        ));
    }
    if let Some(piece) = &piece_extent {
        let p: [f64; 6] = super::numbers(FORMAT, "Piece Extent", piece)?;
        if p != e {
            return Err(header_error(
                FORMAT,
                "the piece does not cover the WholeExtent (several pieces are not supported)",
            ));
        }
    }
    let dims = [
        (e[1] - e[0]) as u64 + 1,
        (e[3] - e[2]) as u64 + 1,
        (e[5] - e[4]) as u64 + 1,
    ];
    let origin: [f64; 3] = get(&image_attrs, "Origin")
        .map_or(Ok([0.0; 3]), |v| super::numbers(FORMAT, "Origin", v))?;
    let spacing: [f64; 3] = get(&image_attrs, "Spacing")
        .map_or(Ok([1.0; 3]), |v| super::numbers(FORMAT, "Spacing", v))?;
    let d: [f64; 9] = get(&image_attrs, "Direction")
        .map_or(Ok([1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]), |v| {
            super::numbers(FORMAT, "Direction", v)
        })?;
    // Direction is row-major: column c (the direction of index axis c) is (d[c], d[3+c], d[6+c]).
    let affine = [0, 1, 2].map(|c| {
        [
            d[c] * spacing[c],
            d[3 + c] * spacing[c],
            d[6 + c] * spacing[c],
        ]
    });
    let start = [e[0], e[2], e[4]];
    let mut origin_first = origin;
    for (c, column) in affine.iter().enumerate() {
        for r in 0..3 {
            origin_first[r] += column[r] * start[c];
        }
    }

    if arrays.is_empty() {
        return Err(header_error(
            FORMAT,
            if saw_cell_data {
                "only cell data found: a volume needs point data (one value per voxel)"
            } else {
                "no point-data array"
            },
        ));
    }
    let array = match &scalars_name {
        Some(name) => arrays.iter().find(|a| &a.name == name).ok_or_else(|| {
            header_error(
                FORMAT,
                format!("PointData Scalars names {name:?}, which is not there"),
            )
        })?,
        None => &arrays[0],
    };
    if array.components.trim() != "1" {
        return Err(header_error(
            FORMAT,
            format!(
                "array {:?} has {} components: only scalar volumes are supported",
                array.name, array.components
            ),
        ));
    }
    let voxel_type = match array.ty.as_str() {
        "Int8" | "Char" => VoxelType::I8,
        "UInt8" => VoxelType::U8,
        "Int16" => VoxelType::I16,
        "UInt16" => VoxelType::U16,
        "Int32" => VoxelType::I32,
        "UInt32" => VoxelType::U32,
        "Int64" => VoxelType::I64,
        "UInt64" => VoxelType::U64,
        "Float32" => VoxelType::F32,
        "Float64" => VoxelType::F64,
        other => {
            return Err(header_error(
                FORMAT,
                format!("DataArray type {other:?} is not supported"),
            ));
        }
    };
    let expected = data_bytes(&dims, voxel_type)?;
    let codec = Codec {
        header_type,
        big_endian,
        compressed,
        expected,
    };
    let data = match array.format.as_str() {
        "ascii" => ascii(&array.text, voxel_type, big_endian, expected)?,
        "binary" => codec.base64(array.text.trim())?,
        "appended" => {
            let (tag, section) = appended
                .ok_or_else(|| header_error(FORMAT, "appended data array but no AppendedData"))?;
            let offset = array
                .offset
                .ok_or_else(|| header_error(FORMAT, "appended data array without an offset"))?;
            let section = section.get(offset..).ok_or_else(|| {
                header_error(FORMAT, format!("offset {offset} is past the appended data"))
            })?;
            if tag.contains("encoding=\"base64\"") {
                let end = section
                    .iter()
                    .position(|&b| b == b'<' || b.is_ascii_whitespace())
                    .unwrap_or(section.len());
                let text = std::str::from_utf8(&section[..end])
                    .map_err(|_| header_error(FORMAT, "base64 appended data is not text"))?;
                codec.base64(text)?
            } else if tag.contains("encoding=\"raw\"") {
                codec.raw(section)?
            } else {
                return Err(header_error(
                    FORMAT,
                    format!("AppendedData {tag}: encoding raw or base64 expected"),
                ));
            }
        }
        other => {
            return Err(header_error(
                FORMAT,
                format!("DataArray format {other:?} is unknown"),
            ));
        }
    };
    Ok(RawVolume {
        dims,
        voxel_type,
        big_endian,
        scale: (1.0, 0.0),
        affine,
        origin: origin_first,
        data,
    })
}

fn find(haystack: &[u8], needle: &[u8]) -> Option<usize> {
    haystack.windows(needle.len()).position(|w| w == needle)
}

fn attributes(e: &BytesStart<'_>) -> Result<Vec<(String, String)>> {
    e.attributes()
        .map(|a| {
            let a = a.map_err(|err| header_error(FORMAT, format!("XML attribute: {err}")))?;
            let value = a
                .unescape_value()
                .map_err(|err| header_error(FORMAT, format!("XML attribute: {err}")))?;
            Ok((
                String::from_utf8_lossy(a.key.as_ref()).into_owned(),
                value.into_owned(),
            ))
        })
        .collect()
}

fn get<'a>(attrs: &'a [(String, String)], key: &str) -> Option<&'a str> {
    attrs
        .iter()
        .find(|(k, _)| k == key)
        .map(|(_, v)| v.as_str())
}

/// How an array's binary data is framed.
struct Codec {
    header_type: VoxelType,
    big_endian: bool,
    compressed: bool,
    expected: u64,
}

impl Codec {
    fn word(&self, b: &[u8]) -> u64 {
        self.header_type.decode(b, self.big_endian) as u64
    }

    /// Raw bytes (appended `raw`): header then data.
    fn raw(&self, section: &[u8]) -> Result<Vec<u8>> {
        let w = self.header_type.bytes();
        let short = || header_error(FORMAT, "the data's header is truncated");
        if !self.compressed {
            let count = self.word(section.get(..w).ok_or_else(short)?);
            if count != self.expected {
                return Err(VolumeError::DataSize {
                    format: FORMAT,
                    expected: self.expected,
                    found: count,
                });
            }
            return exact(
                FORMAT,
                section.get(w..w + count as usize).unwrap_or_default(),
                count,
            )
            .map_err(|_| truncated(self.expected, section.len().saturating_sub(w)));
        }
        let head = section.get(..3 * w).ok_or_else(short)?;
        let blocks = self.word(&head[..w]);
        // Every block holds at least one byte and has a compressed-size entry.
        if blocks > self.expected.max(1) || blocks as usize > section.len() / w {
            return Err(header_error(
                FORMAT,
                format!("{blocks} compressed blocks is not plausible"),
            ));
        }
        let header_len = (3 + blocks as usize) * w;
        let header = section.get(..header_len).ok_or_else(short)?;
        self.inflate(header, &section[header_len..])
    }

    /// Base64 text (inline `binary` or appended `base64`).
    fn base64(&self, text: &str) -> Result<Vec<u8>> {
        let text: String = text.split_whitespace().collect();
        let w = self.header_type.bytes();
        let chars = |bytes: usize| bytes.div_ceil(3) * 4;
        let bad = |e: base64::DecodeError| header_error(FORMAT, format!("base64: {e}"));
        if !self.compressed {
            // One stream of header and data, else a header encoded on its own, then the data.
            if let Ok(all) = B64.decode(&text)
                && all.len() >= w
                && self.word(&all[..w]) == self.expected
            {
                return exact(FORMAT, &all[w..], self.expected);
            }
            let head = B64
                .decode(
                    text.get(..chars(w))
                        .ok_or_else(|| truncated(self.expected, 0))?,
                )
                .map_err(bad)?;
            let count = self.word(head.get(..w).ok_or_else(|| truncated(self.expected, 0))?);
            if count != self.expected {
                return Err(VolumeError::DataSize {
                    format: FORMAT,
                    expected: self.expected,
                    found: count,
                });
            }
            let data = B64.decode(&text[chars(w)..]).map_err(bad)?;
            return exact(FORMAT, &data, self.expected);
        }
        let first = B64
            .decode(
                text.get(..chars(3 * w))
                    .ok_or_else(|| truncated(self.expected, 0))?,
            )
            .map_err(bad)?;
        let blocks = self.word(first.get(..w).ok_or_else(|| truncated(self.expected, 0))?);
        if blocks > self.expected.max(1) || (blocks as usize).saturating_mul(w) > text.len() {
            return Err(header_error(
                FORMAT,
                format!("{blocks} compressed blocks is not plausible"),
            ));
        }
        let header_chars = chars((3 + blocks as usize) * w);
        let header = B64
            .decode(
                text.get(..header_chars)
                    .ok_or_else(|| truncated(self.expected, 0))?,
            )
            .map_err(bad)?;
        let data = B64.decode(&text[header_chars..]).map_err(bad)?;
        self.inflate(&header, &data)
    }

    /// zlib blocks behind `[blocks, block size, last block size, compressed sizes…]`.
    fn inflate(&self, header: &[u8], mut data: &[u8]) -> Result<Vec<u8>> {
        let w = self.header_type.bytes();
        let words: Vec<u64> = header.chunks_exact(w).map(|b| self.word(b)).collect();
        let (blocks, block, last) = (words[0], words[1], words[2]);
        let last = if last == 0 { block } else { last };
        let total = if blocks == 0 {
            0
        } else {
            (blocks - 1).saturating_mul(block).saturating_add(last)
        };
        if total != self.expected {
            return Err(VolumeError::DataSize {
                format: FORMAT,
                expected: self.expected,
                found: total,
            });
        }
        let mut out = Vec::with_capacity(self.expected as usize);
        for (n, &size) in words[3..].iter().enumerate() {
            let size = usize::try_from(size).unwrap_or(usize::MAX);
            let chunk = data
                .get(..size)
                .ok_or_else(|| truncated(self.expected, out.len()))?;
            data = &data[size..];
            let want = if n as u64 + 1 == blocks { last } else { block };
            let before = out.len();
            flate2::read::ZlibDecoder::new(chunk)
                .take(want + 1)
                .read_to_end(&mut out)
                .map_err(|e| header_error(FORMAT, format!("zlib block {n}: {e}")))?;
            if (out.len() - before) as u64 != want {
                return Err(header_error(
                    FORMAT,
                    format!(
                        "zlib block {n} inflates to {} bytes, not {want}",
                        out.len() - before
                    ),
                ));
            }
        }
        Ok(out)
    }
}

fn truncated(expected: u64, found: usize) -> VolumeError {
    VolumeError::DataSize {
        format: FORMAT,
        expected,
        found: found as u64,
    }
}

/// Text values re-encoded as the stored type.
fn ascii(text: &str, ty: VoxelType, big_endian: bool, expected: u64) -> Result<Vec<u8>> {
    super::nrrd::encode_text(FORMAT, text, ty, big_endian, expected)
}
