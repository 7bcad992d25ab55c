//! Byte-level layout of `.lfa` version 1: preamble, index entries, page grid, and the checks
//! that turn untrusted bytes into validated structures.

use super::header::{AssetHeader, Channel, PageGrid};
use super::{AssetError, FORMAT_VERSION, ImageKey, MIN_FORMAT_VERSION, Result};

/// First 8 bytes of every `.lfa` file. The `\r\n`, `\x1a` and `\n` catch text-mode transfers
/// that rewrite line endings or stop at Ctrl-Z, like PNG's signature.
pub const MAGIC: [u8; 8] = *b"LFA\x00\r\n\x1a\n";
/// Length of the fixed preamble.
pub const PREAMBLE_LEN: u64 = 64;
/// Length of one binary index entry.
pub const INDEX_ENTRY_LEN: u64 = 36;
/// Largest accepted JSON header.
pub const MAX_HEADER_LEN: u64 = 16 << 20;
/// Bytes the preamble checksum covers (everything before the checksum itself).
const PREAMBLE_CRC_LEN: usize = 56;
/// Bytes before the first index entry (the entry count).
const INDEX_COUNT_LEN: u64 = 4;

/// CRC-32 (IEEE, as zlib and PNG) of `bytes`.
pub(crate) fn crc32(bytes: &[u8]) -> u32 {
    crc32fast::hash(bytes)
}

/// Whether `bytes` have the CRC-32 `expected`. Fuzz builds (`--cfg fuzzing`, set by cargo-fuzz)
/// accept any checksum, so that mutated inputs reach the parsing behind each check instead of
/// stopping at it; every other build compares.
pub(crate) fn crc_matches(bytes: &[u8], expected: u32) -> bool {
    cfg!(fuzzing) || crc32(bytes) == expected
}

/// The largest zstd frame the reference encoder emits for `raw_len` input bytes
/// (`ZSTD_COMPRESSBOUND`); any longer zstd page is rejected.
pub fn zstd_bound(raw_len: u32) -> u64 {
    let n = u64::from(raw_len);
    let small_input_margin = if n < (128 << 10) {
        ((128 << 10) - n) >> 11
    } else {
        0
    };
    n + (n >> 8) + small_input_margin
}

/// How a page's bytes are stored.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum Codec {
    /// The raw texel bytes.
    Raw,
    /// One or more zstd frames that decode to the raw texel bytes.
    Zstd,
}

impl Codec {
    /// The codec's code in the binary index.
    pub fn code(self) -> u8 {
        match self {
            Codec::Raw => 0,
            Codec::Zstd => 1,
        }
    }

    /// The codec for an index code, `None` for unknown codes.
    pub fn from_code(code: u8) -> Option<Self> {
        match code {
            0 => Some(Codec::Raw),
            1 => Some(Codec::Zstd),
            _ => None,
        }
    }
}

/// The fixed 64-byte start of the file: where the header and the index are.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub struct Preamble {
    /// Format version (1 or 2).
    pub format_version: u32,
    /// Reserved flags, 0 in version 1.
    pub flags: u32,
    /// File offset of the JSON header.
    pub header_offset: u64,
    /// Length of the JSON header.
    pub header_len: u64,
    /// CRC-32 of the JSON header bytes.
    pub header_crc32: u32,
    /// File offset of the binary index.
    pub index_offset: u64,
    /// Length of the binary index (4 + 36 × entries).
    pub index_len: u64,
    /// CRC-32 of the binary index bytes.
    pub index_crc32: u32,
}

impl Preamble {
    pub(crate) fn new(
        format_version: u32,
        header_offset: u64,
        header_len: u64,
        header_crc32: u32,
        index_offset: u64,
        index_len: u64,
        index_crc32: u32,
    ) -> Self {
        Self {
            format_version,
            flags: 0,
            header_offset,
            header_len,
            header_crc32,
            index_offset,
            index_len,
            index_crc32,
        }
    }

    /// The 64 bytes on disk, with the preamble checksum.
    pub fn to_bytes(&self) -> [u8; PREAMBLE_LEN as usize] {
        let mut b = [0u8; PREAMBLE_LEN as usize];
        b[0..8].copy_from_slice(&MAGIC);
        b[8..12].copy_from_slice(&self.format_version.to_le_bytes());
        b[12..16].copy_from_slice(&self.flags.to_le_bytes());
        b[16..24].copy_from_slice(&self.header_offset.to_le_bytes());
        b[24..32].copy_from_slice(&self.header_len.to_le_bytes());
        b[32..36].copy_from_slice(&self.header_crc32.to_le_bytes());
        b[36..44].copy_from_slice(&self.index_offset.to_le_bytes());
        b[44..52].copy_from_slice(&self.index_len.to_le_bytes());
        b[52..56].copy_from_slice(&self.index_crc32.to_le_bytes());
        let crc = crc32(&b[..PREAMBLE_CRC_LEN]);
        b[56..60].copy_from_slice(&crc.to_le_bytes());
        b
    }

    /// Parses the start of a file of `file_len` bytes: `bytes` holds its first
    /// `min(64, file_len)` bytes. Checks magic, version, checksum, flags and padding, and that
    /// the header and index ranges lie inside the file, after the preamble, without overlap,
    /// and that the file ends where the later of the two ends.
    pub fn parse(bytes: &[u8], file_len: u64) -> Result<Self> {
        let magic_len = bytes.len().min(MAGIC.len());
        if bytes[..magic_len] != MAGIC[..magic_len] {
            return Err(AssetError::BadMagic);
        }
        if (bytes.len() as u64) < PREAMBLE_LEN {
            return Err(AssetError::Truncated {
                what: "preamble",
                needed: PREAMBLE_LEN,
                available: file_len,
            });
        }
        // The version is read before the checksum: a future version may lay out the rest of
        // the preamble differently, and its readers must still get a clear "unsupported".
        let format_version = read_u32(bytes, 8);
        if !(MIN_FORMAT_VERSION..=FORMAT_VERSION).contains(&format_version) {
            return Err(AssetError::UnsupportedVersion {
                found: format_version,
                supported: FORMAT_VERSION,
            });
        }
        if !crc_matches(&bytes[..PREAMBLE_CRC_LEN], read_u32(bytes, 56)) {
            return Err(AssetError::Checksum {
                what: "preamble".to_owned(),
            });
        }
        let preamble = Self {
            format_version,
            flags: read_u32(bytes, 12),
            header_offset: read_u64(bytes, 16),
            header_len: read_u64(bytes, 24),
            header_crc32: read_u32(bytes, 32),
            index_offset: read_u64(bytes, 36),
            index_len: read_u64(bytes, 44),
            index_crc32: read_u32(bytes, 52),
        };
        if preamble.flags != 0 {
            return Err(AssetError::Preamble(format!(
                "flags are {:#x}; version 1 defines none",
                preamble.flags
            )));
        }
        if bytes[60..64].iter().any(|&b| b != 0) {
            return Err(AssetError::Preamble(
                "the padding after the checksum is not zero".to_owned(),
            ));
        }
        if preamble.header_len > MAX_HEADER_LEN {
            return Err(AssetError::Header(format!(
                "the header claims {} bytes; the limit is {MAX_HEADER_LEN}",
                preamble.header_len
            )));
        }
        let header_end = section_end(
            "header",
            preamble.header_offset,
            preamble.header_len,
            file_len,
        )?;
        let index_end = section_end("index", preamble.index_offset, preamble.index_len, file_len)?;
        if preamble.header_offset < index_end && preamble.index_offset < header_end {
            return Err(AssetError::Preamble(
                "the header and index ranges overlap".to_owned(),
            ));
        }
        let end = header_end.max(index_end);
        if end != file_len {
            return Err(AssetError::Preamble(format!(
                "{} bytes follow the last section (the file must end where the header or index \
                 ends)",
                file_len - end
            )));
        }
        Ok(preamble)
    }

    /// End of the page-data region: pages lie in `[64, page_data_end)`.
    pub fn page_data_end(&self) -> u64 {
        self.header_offset.min(self.index_offset)
    }
}

/// Checks that `[offset, offset + len)` lies after the preamble and inside the file.
fn section_end(what: &'static str, offset: u64, len: u64, file_len: u64) -> Result<u64> {
    if offset < PREAMBLE_LEN {
        return Err(AssetError::Preamble(format!(
            "the {what} offset {offset} lies inside the 64-byte preamble"
        )));
    }
    let end = offset.checked_add(len).ok_or_else(|| {
        AssetError::Preamble(format!(
            "the {what} offset {offset} plus length {len} overflows 64 bits"
        ))
    })?;
    if end > file_len {
        return Err(AssetError::Truncated {
            what,
            needed: end,
            available: file_len,
        });
    }
    Ok(end)
}

/// One index entry: where one page of one image is stored and how.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub struct IndexEntry {
    /// The image the page belongs to.
    pub key: ImageKey,
    /// Page number within the image.
    pub page: u32,
    /// How the bytes are stored.
    pub codec: Codec,
    /// File offset of the stored bytes.
    pub offset: u64,
    /// Stored (compressed) length.
    pub length: u32,
    /// Decoded length: the page's texels × bytes per texel.
    pub raw_length: u32,
    /// CRC-32 of the stored bytes.
    pub crc32: u32,
}

impl IndexEntry {
    pub(crate) fn new(
        key: ImageKey,
        page: u32,
        codec: Codec,
        offset: u64,
        length: u32,
        raw_length: u32,
        crc32: u32,
    ) -> Self {
        Self {
            key,
            page,
            codec,
            offset,
            length,
            raw_length,
            crc32,
        }
    }

    /// The sort key of the index: (layer, state, camera, channel, page).
    pub fn sort_key(&self) -> (ImageKey, u32) {
        (self.key, self.page)
    }

    fn encode_into(&self, out: &mut Vec<u8>) {
        out.extend_from_slice(&self.key.layer.to_le_bytes());
        out.extend_from_slice(&self.key.state.to_le_bytes());
        out.extend_from_slice(&self.key.camera.to_le_bytes());
        out.push(self.key.channel.code());
        out.push(self.codec.code());
        out.extend_from_slice(&0u16.to_le_bytes());
        out.extend_from_slice(&self.page.to_le_bytes());
        out.extend_from_slice(&self.offset.to_le_bytes());
        out.extend_from_slice(&self.length.to_le_bytes());
        out.extend_from_slice(&self.raw_length.to_le_bytes());
        out.extend_from_slice(&self.crc32.to_le_bytes());
    }
}

/// Encodes sorted entries as the binary index: a `u32` count then 36-byte entries.
pub(crate) fn encode_index(entries: &[IndexEntry]) -> Result<Vec<u8>> {
    let count = u32::try_from(entries.len()).map_err(|_| {
        AssetError::Index(format!(
            "{} pages do not fit the index's 32-bit count",
            entries.len()
        ))
    })?;
    let mut out = Vec::with_capacity(4 + entries.len() * INDEX_ENTRY_LEN as usize);
    out.extend_from_slice(&count.to_le_bytes());
    for entry in entries {
        entry.encode_into(&mut out);
    }
    Ok(out)
}

/// Geometry of a validated header that index checks and readers need.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Layout {
    pub grid: PageGrid,
    pub layers: u32,
    pub states: u32,
    pub cameras: u32,
    /// Each channel's texel encoding and the block compression of its pages.
    pub color_encoding: super::Encoding,
    pub depth_encoding: super::Encoding,
    pub color_block: Option<super::BlockCodec>,
    pub depth_block: Option<super::BlockCodec>,
    /// Whether states other than 0 may store some pages of an image (version 4 and later).
    pub partial_images: bool,
}

impl Layout {
    /// Validates `header` and derives the layout.
    pub fn new(header: &AssetHeader) -> Result<Self> {
        header.validate()?;
        let encoding = |channel| {
            header
                .encoding(channel)
                .ok_or_else(|| AssetError::Header(format!("no {channel} channel")))
        };
        Ok(Self {
            grid: header.page_grid()?,
            layers: header.layers.len() as u32,
            states: header.states.len() as u32,
            cameras: header.camera_count(),
            color_encoding: encoding(Channel::Color)?,
            depth_encoding: encoding(Channel::Depth)?,
            color_block: header.compression(Channel::Color),
            depth_block: header.compression(Channel::Depth),
            partial_images: header.format_version >= super::PARTIAL_IMAGES_SINCE,
        })
    }

    pub fn bytes_per_texel(&self, channel: Channel) -> u32 {
        self.encoding(channel).bytes_per_texel()
    }

    /// Bytes of a whole image of `channel` (≤ 8192² × 4, so it fits `usize` on 64-bit hosts).
    pub fn image_bytes(&self, channel: Channel) -> u64 {
        u64::from(self.grid.width())
            * u64::from(self.grid.height())
            * u64::from(self.bytes_per_texel(channel))
    }

    /// The encoding of `channel`'s texels.
    pub fn encoding(&self, channel: Channel) -> super::Encoding {
        match channel {
            Channel::Color => self.color_encoding,
            Channel::Depth => self.depth_encoding,
        }
    }

    /// The block compression of `channel`'s pages.
    pub fn block(&self, channel: Channel) -> Option<super::BlockCodec> {
        match channel {
            Channel::Color => self.color_block,
            Channel::Depth => self.depth_block,
        }
    }

    /// The `raw_length` of `page` of a `channel` image: its texels' bytes, or its blocks' where
    /// the channel is block-compressed (≤ 4096² × 4 < 2³²).
    pub fn page_bytes(&self, channel: Channel, page: u32) -> Option<u32> {
        let rect = self.grid.page_rect(page)?;
        let bytes = match self.block(channel) {
            Some(codec) => codec.stored_bytes(rect.width, rect.height),
            None => rect.texels() * u64::from(self.bytes_per_texel(channel)),
        };
        u32::try_from(bytes).ok()
    }

    /// Checks that `key` names a layer, state and camera of the asset.
    pub fn check_key(&self, key: ImageKey) -> Result<()> {
        let reason = if u32::from(key.layer) >= self.layers {
            format!("the asset has {} layers", self.layers)
        } else if u32::from(key.state) >= self.states {
            format!("the asset has {} states", self.states)
        } else if key.camera >= self.cameras {
            format!("the asset has {} cameras", self.cameras)
        } else {
            return Ok(());
        };
        Err(AssetError::KeyOutOfRange { key, reason })
    }

    /// Images in the base state: layers × cameras × channels.
    fn base_images(&self) -> u64 {
        u64::from(self.layers) * u64::from(self.cameras) * Channel::ALL.len() as u64
    }
}

/// Parses and validates the binary index against the layout and the page-data region
/// `[64, page_data_end)`. The result is sorted, unique, in range, with every stored image
/// complete and state 0 holding every layer × camera × channel.
pub(crate) fn parse_index(
    bytes: &[u8],
    layout: &Layout,
    page_data_end: u64,
) -> Result<Vec<IndexEntry>> {
    let index_err = |msg: String| AssetError::Index(msg);
    let len = bytes.len() as u64;
    if len < INDEX_COUNT_LEN || !(len - INDEX_COUNT_LEN).is_multiple_of(INDEX_ENTRY_LEN) {
        return Err(index_err(format!(
            "the index is {len} bytes, which is not a 4-byte count plus whole 36-byte entries"
        )));
    }
    let count = u64::from(read_u32(bytes, 0));
    let room = (len - INDEX_COUNT_LEN) / INDEX_ENTRY_LEN;
    if count != room {
        return Err(index_err(format!(
            "the index claims {count} entries but its length holds {room}"
        )));
    }
    let pages = u64::from(layout.grid.page_count());
    let base_entries = layout.base_images() * pages;
    if count < base_entries {
        return Err(index_err(format!(
            "the index has {count} entries but the base state alone needs {base_entries}"
        )));
    }
    let max_entries = base_entries * u64::from(layout.states);
    if count > max_entries {
        return Err(index_err(format!(
            "the index has {count} entries but the header allows at most {max_entries}"
        )));
    }

    // `count ≤ len / 36`, so this allocation is bounded by bytes actually present.
    let mut entries = Vec::with_capacity(count as usize);
    for raw in bytes[INDEX_COUNT_LEN as usize..].chunks_exact(INDEX_ENTRY_LEN as usize) {
        let position = entries.len();
        let entry = parse_entry(raw, layout, page_data_end)
            .map_err(|msg| index_err(format!("entry {position}: {msg}")))?;
        if let Some(prev) = entries.last().map(IndexEntry::sort_key)
            && prev >= entry.sort_key()
        {
            return Err(index_err(format!(
                "entry {position} ({}, page {}) is out of order or repeated",
                entry.key, entry.page
            )));
        }
        entries.push(entry);
    }

    // Entries are sorted, unique and in range, so an image is complete exactly when it has
    // `pages` entries, and state 0 is complete exactly when it holds `base_images` images.
    // From version 4 an image of another state may hold any of its pages (the others read
    // from state 0).
    let mut base_images = 0u64;
    for group in entries.chunk_by(|a, b| a.key == b.key) {
        let partial_allowed = layout.partial_images && group[0].key.state != 0;
        if group.len() as u64 != pages && !partial_allowed {
            return Err(index_err(format!(
                "{} has {} of its {pages} pages; an image is stored whole or not at all",
                group[0].key,
                group.len()
            )));
        }
        if group[0].key.state == 0 {
            base_images += 1;
        }
    }
    if base_images != layout.base_images() {
        return Err(index_err(format!(
            "state 0 holds {base_images} images but must hold all {} (layers × cameras × \
             channels)",
            layout.base_images()
        )));
    }
    Ok(entries)
}

fn parse_entry(
    raw: &[u8],
    layout: &Layout,
    page_data_end: u64,
) -> std::result::Result<IndexEntry, String> {
    let channel_code = raw[8];
    let codec_code = raw[9];
    let channel = Channel::from_code(channel_code)
        .ok_or_else(|| format!("unknown channel code {channel_code}"))?;
    let codec =
        Codec::from_code(codec_code).ok_or_else(|| format!("unknown codec {codec_code}"))?;
    if read_u16(raw, 10) != 0 {
        return Err("reserved bytes are not zero".to_owned());
    }
    let key = ImageKey::new(
        read_u16(raw, 0),
        read_u16(raw, 2),
        read_u32(raw, 4),
        channel,
    );
    layout.check_key(key).map_err(|e| e.to_string())?;
    let entry = IndexEntry::new(
        key,
        read_u32(raw, 12),
        codec,
        read_u64(raw, 16),
        read_u32(raw, 24),
        read_u32(raw, 28),
        read_u32(raw, 32),
    );
    let expected_raw = layout.page_bytes(channel, entry.page).ok_or_else(|| {
        format!(
            "page {} is beyond the {} pages of an image",
            entry.page,
            layout.grid.page_count()
        )
    })?;
    if entry.raw_length != expected_raw {
        return Err(format!(
            "page {} of {key} claims {} decoded bytes; its size and encoding give {expected_raw}",
            entry.page, entry.raw_length
        ));
    }
    let max_stored = match codec {
        Codec::Raw => u64::from(expected_raw),
        Codec::Zstd => zstd_bound(expected_raw),
    };
    let stored = u64::from(entry.length);
    if (codec == Codec::Raw && stored != max_stored) || stored > max_stored || stored == 0 {
        return Err(format!(
            "page {} of {key} stores {stored} bytes, impossible for {codec:?} with {expected_raw} \
             decoded bytes",
            entry.page
        ));
    }
    let end = entry.offset.checked_add(stored);
    if entry.offset < PREAMBLE_LEN || end.is_none_or(|end| end > page_data_end) {
        return Err(format!(
            "page {} of {key} at offset {} (+{stored}) lies outside the page data [64, \
             {page_data_end})",
            entry.page, entry.offset
        ));
    }
    Ok(entry)
}

fn read_u16(b: &[u8], at: usize) -> u16 {
    u16::from_le_bytes([b[at], b[at + 1]])
}

fn read_u32(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]])
}

fn read_u64(b: &[u8], at: usize) -> u64 {
    let mut a = [0u8; 8];
    a.copy_from_slice(&b[at..at + 8]);
    u64::from_le_bytes(a)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn preamble_round_trips_and_is_64_bytes() {
        let p = Preamble::new(1, 1000, 200, 7, 1200, 40, 9);
        let bytes = p.to_bytes();
        assert_eq!(&bytes[..8], &MAGIC);
        assert_eq!(Preamble::parse(&bytes, 1240).unwrap(), p);
        assert!(matches!(
            Preamble::parse(&bytes, 1239),
            Err(AssetError::Truncated { what: "index", .. })
        ));
        assert!(matches!(
            Preamble::parse(&bytes, 1241),
            Err(AssetError::Preamble(_))
        ));
    }

    #[test]
    fn zstd_bound_matches_the_library() {
        for n in [
            0u32,
            1,
            100,
            4096,
            65_536,
            131_071,
            131_072,
            1 << 20,
            64 << 20,
        ] {
            assert_eq!(
                zstd_bound(n),
                zstd::zstd_safe::compress_bound(n as usize) as u64,
                "n = {n}"
            );
        }
    }

    #[test]
    fn page_grid_edges() {
        let grid = PageGrid::new(40, 16).unwrap();
        assert_eq!(grid.pages_per_row(), 3);
        assert_eq!(grid.page_count(), 9);
        let last = grid.page_rect(8).unwrap();
        assert_eq!((last.x, last.y, last.width, last.height), (32, 32, 8, 8));
        assert_eq!(grid.page_rect(9), None);
        assert_eq!(PageGrid::new(0, 16), None);
        assert_eq!(PageGrid::new(u32::MAX, 1), None);
    }

    #[test]
    fn index_entry_is_36_bytes() {
        let entry = IndexEntry::new(
            ImageKey::new(1, 2, 3, Channel::Depth),
            4,
            Codec::Zstd,
            5,
            6,
            7,
            8,
        );
        let bytes = encode_index(&[entry]).unwrap();
        assert_eq!(bytes.len() as u64, 4 + INDEX_ENTRY_LEN);
    }
}
