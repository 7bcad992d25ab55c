//! Reading `.lfa` files: open validates preamble, header and index; pages are read, verified
//! and decoded on demand.

use std::fmt;
use std::fs::File;
use std::path::Path;

use super::format::{Layout, PREAMBLE_LEN, Preamble, crc_matches, parse_index};
use super::header::{AssetHeader, Channel};
use super::{AssetError, BLOCK, BlockCodec, Codec, ImageKey, IndexEntry, Result};

/// Where the bytes come from.
enum Source {
    File(File),
    Bytes(Vec<u8>),
}

impl Source {
    /// Reads `len` bytes at `offset`. Callers pass ranges already checked against the length
    /// seen at open; a file that shrank since then gives an I/O error, not a panic.
    fn read_at(&self, offset: u64, len: usize) -> Result<Vec<u8>> {
        match self {
            Source::File(file) => {
                let mut buf = vec![0u8; len];
                read_exact_at(file, &mut buf, offset)?;
                Ok(buf)
            }
            Source::Bytes(bytes) => {
                let slice = usize::try_from(offset)
                    .ok()
                    .and_then(|start| bytes.get(start..start.checked_add(len)?))
                    .ok_or(AssetError::Truncated {
                        what: "requested range",
                        needed: offset.saturating_add(len as u64),
                        available: bytes.len() as u64,
                    })?;
                Ok(slice.to_vec())
            }
        }
    }

    /// Borrows a range without copying where possible.
    fn with_range<T>(
        &self,
        offset: u64,
        len: usize,
        f: impl FnOnce(&[u8]) -> Result<T>,
    ) -> Result<T> {
        match self {
            Source::Bytes(bytes) => {
                let slice = usize::try_from(offset)
                    .ok()
                    .and_then(|start| bytes.get(start..start.checked_add(len)?))
                    .ok_or(AssetError::Truncated {
                        what: "requested range",
                        needed: offset.saturating_add(len as u64),
                        available: bytes.len() as u64,
                    })?;
                f(slice)
            }
            Source::File(_) => f(&self.read_at(offset, len)?),
        }
    }
}

#[cfg(unix)]
fn read_exact_at(file: &File, buf: &mut [u8], offset: u64) -> std::io::Result<()> {
    std::os::unix::fs::FileExt::read_exact_at(file, buf, offset)
}

#[cfg(windows)]
fn read_exact_at(file: &File, mut buf: &mut [u8], mut offset: u64) -> std::io::Result<()> {
    use std::os::windows::fs::FileExt;
    while !buf.is_empty() {
        match file.seek_read(buf, offset) {
            Ok(0) => return Err(std::io::ErrorKind::UnexpectedEof.into()),
            Ok(n) => {
                buf = &mut buf[n..];
                offset += n as u64;
            }
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    Ok(())
}

#[cfg(not(any(unix, windows)))]
fn read_exact_at(_file: &File, _buf: &mut [u8], _offset: u64) -> std::io::Result<()> {
    Err(std::io::Error::new(
        std::io::ErrorKind::Unsupported,
        "positional file reads are not available on this platform; use AssetFile::from_bytes",
    ))
}

/// An opened, validated asset. Pages are read on demand; `&self` methods may run on several
/// threads at once.
pub struct AssetFile {
    source: Source,
    file_len: u64,
    preamble: Preamble,
    header: AssetHeader,
    layout: Layout,
    index: Vec<IndexEntry>,
}

impl fmt::Debug for AssetFile {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("AssetFile")
            .field("file_len", &self.file_len)
            .field("preamble", &self.preamble)
            .field("header", &self.header)
            .field("index_entries", &self.index.len())
            .finish_non_exhaustive()
    }
}

impl AssetFile {
    /// Opens `path` and validates preamble, header and index (not the pages: see
    /// [`Self::verify_all`]). Reads only the preamble, header and index.
    pub fn open(path: impl AsRef<Path>) -> Result<Self> {
        let file = File::open(path)?;
        let file_len = file.metadata()?.len();
        Self::parse(Source::File(file), file_len)
    }

    /// Validates an asset held in memory, e.g. an upload, exactly as [`Self::open`] does.
    pub fn from_bytes(bytes: Vec<u8>) -> Result<Self> {
        let file_len = bytes.len() as u64;
        Self::parse(Source::Bytes(bytes), file_len)
    }

    fn parse(source: Source, file_len: u64) -> Result<Self> {
        let head = source.read_at(0, file_len.min(PREAMBLE_LEN) as usize)?;
        let preamble = Preamble::parse(&head, file_len)?;
        // Both lengths were checked against the file's length (and the header's against
        // 16 MiB), so these reads never allocate more than the file holds.
        let header = source.with_range(
            preamble.header_offset,
            preamble.header_len as usize,
            |bytes| {
                if !crc_matches(bytes, preamble.header_crc32) {
                    return Err(AssetError::Checksum {
                        what: "header".to_owned(),
                    });
                }
                serde_json::from_slice::<AssetHeader>(bytes).map_err(|e| {
                    AssetError::Header(format!(
                        "not a valid version {} header: {e}",
                        preamble.format_version
                    ))
                })
            },
        )?;
        if header.format_version != preamble.format_version {
            return Err(AssetError::Header(format!(
                "header says format version {} but this is a version {} file",
                header.format_version, preamble.format_version
            )));
        }
        let layout = Layout::new(&header)?;
        let index = source.with_range(
            preamble.index_offset,
            preamble.index_len as usize,
            |bytes| {
                if !crc_matches(bytes, preamble.index_crc32) {
                    return Err(AssetError::Checksum {
                        what: "index".to_owned(),
                    });
                }
                parse_index(bytes, &layout, preamble.page_data_end())
            },
        )?;
        Ok(Self {
            source,
            file_len,
            preamble,
            header,
            layout,
            index,
        })
    }

    /// The validated header.
    pub fn header(&self) -> &AssetHeader {
        &self.header
    }

    /// The validated index, sorted by (layer, state, camera, channel, page).
    pub fn index(&self) -> &[IndexEntry] {
        &self.index
    }

    /// The validated preamble.
    pub fn preamble(&self) -> &Preamble {
        &self.preamble
    }

    /// Length of the file (or byte buffer) in bytes.
    pub fn file_len(&self) -> u64 {
        self.file_len
    }

    /// Whether any page of the image is stored under exactly this key (no state fallback).
    pub fn has_image(&self, key: ImageKey) -> bool {
        !self.entries_of(key).is_empty()
    }

    /// How many of the image's pages are stored under exactly this key: all of them in state
    /// 0; in another state from 0 (the image reads from state 0) to all (from version 4 a
    /// state may store only the pages that differ from state 0).
    pub fn stored_pages(&self, key: ImageKey) -> u32 {
        self.entries_of(key).len() as u32
    }

    /// The index entry serving each page of `key`: the page stored under `key` if there is
    /// one, else the same page of state 0.
    fn page_entries(&self, key: ImageKey) -> Result<Vec<&IndexEntry>> {
        self.layout.check_key(key)?;
        let page_count = self.layout.grid.page_count() as usize;
        let own = self.entries_of(key);
        if own.len() == page_count {
            return Ok(own.iter().collect());
        }
        let base = self.entries_of(key.in_base_state());
        if base.len() != page_count {
            // Validated at open (state 0 is complete), so unreachable in practice.
            return Err(AssetError::MissingImage { key });
        }
        let mut own = own.iter().peekable();
        Ok(base
            .iter()
            .map(|b| own.next_if(|e| e.page == b.page).unwrap_or(b))
            .collect())
    }

    /// Reads the whole image for `key` (each page falling back to state 0 where the state
    /// omits it): `resolution_px²` texels, row-major, top row first, in the channel's
    /// encoding. Every page's checksum and decoded size are verified.
    pub fn read_image(&self, key: ImageKey) -> Result<Vec<u8>> {
        self.assemble(key, true)
    }

    /// The block compression of `channel`'s pages, if any.
    pub fn compression(&self, channel: Channel) -> Option<BlockCodec> {
        self.layout.block(channel)
    }

    /// Reads the whole image for `key` as its stored 4 × 4 blocks, for a GPU that samples them:
    /// `(width / 4) × (height / 4)` blocks row-major, top row first (the layout of a
    /// block-compressed texture's copy). [`AssetError::Header`] if the channel is not
    /// block-compressed.
    pub fn read_image_blocks(&self, key: ImageKey) -> Result<Vec<u8>> {
        if self.layout.block(key.channel).is_none() {
            return Err(AssetError::Header(format!(
                "the {} channel is not block-compressed",
                key.channel
            )));
        }
        self.assemble(key, false)
    }

    /// The image for `key`: texels (block-compressed pages decoded when `decode_blocks`), or
    /// the blocks themselves.
    fn assemble(&self, key: ImageKey, decode_blocks: bool) -> Result<Vec<u8>> {
        let entries = self.page_entries(key)?;
        let block = self.layout.block(key.channel);
        let texel_bpp = self.layout.bytes_per_texel(key.channel) as usize;
        // Blocks: one 'texel' per 4 × 4 block.
        let (unit, bpp) = match block {
            Some(codec) if !decode_blocks => (BLOCK as usize, codec.block_bytes() as usize),
            _ => (1, texel_bpp),
        };
        let side = self.layout.grid.width() as usize / unit;
        let rows = self.layout.grid.height() as usize / unit;
        // Validated header: ≤ 8192² × 4 bytes.
        let mut image = vec![0u8; side * rows * bpp];
        let mut decoder = PageDecoder::new()?;

        let mut put_page = |entry: &IndexEntry, stored_bytes: &[u8]| -> Result<()> {
            let stored = decoder.decode(entry, stored_bytes)?;
            // Validated at open, so this error is unreachable in practice.
            let rect = self.layout.grid.page_rect(entry.page).ok_or_else(|| {
                AssetError::Index(format!("page {} is outside the page grid", entry.page))
            })?;
            let decoded;
            let page = match block {
                Some(codec) if decode_blocks => {
                    decoded = self.decode_blocks(codec, entry, stored, rect)?;
                    decoded.as_slice()
                }
                _ => stored,
            };
            let row_bytes = rect.width as usize / unit * bpp;
            let (x, y) = (rect.x as usize / unit, rect.y as usize / unit);
            for (row, src) in page.chunks_exact(row_bytes).enumerate() {
                let start = ((y + row) * side + x) * bpp;
                image[start..start + row_bytes].copy_from_slice(src);
            }
            Ok(())
        };

        // The writer stores an image's pages back to back: then one read fetches each run.
        for run in entries.chunk_by(|a, b| a.offset + u64::from(a.length) == b.offset) {
            let start = run[0].offset;
            let span: u64 = run.iter().map(|e| u64::from(e.length)).sum();
            self.source.with_range(start, span as usize, |bytes| {
                for entry in run {
                    let at = (entry.offset - start) as usize;
                    put_page(entry, &bytes[at..at + entry.length as usize])?;
                }
                Ok(())
            })?;
        }
        Ok(image)
    }

    /// Reads one page of the image for `key` (with the state fallback, per page): the page's
    /// rectangle ([`super::PageGrid::page_rect`]) row-major in the channel's encoding.
    pub fn read_page(&self, key: ImageKey, page: u32) -> Result<Vec<u8>> {
        self.layout.check_key(key)?;
        let page_count = self.layout.grid.page_count();
        if page >= page_count {
            return Err(AssetError::MissingPage {
                key,
                page,
                page_count,
            });
        }
        let find = |k: ImageKey| self.entries_of(k).iter().find(|e| e.page == page);
        let entry = find(key)
            .or_else(|| find(key.in_base_state()))
            .ok_or(AssetError::MissingImage { key })?;
        let mut decoder = PageDecoder::new()?;
        let block = self.layout.block(key.channel);
        let rect = self.layout.grid.page_rect(page);
        self.source
            .with_range(entry.offset, entry.length as usize, |bytes| {
                let stored = decoder.decode(entry, bytes)?;
                match (block, rect) {
                    (Some(codec), Some(rect)) => self.decode_blocks(codec, entry, stored, rect),
                    _ => Ok(stored.to_vec()),
                }
            })
    }

    /// The texels of a block-compressed page (`stored`: its blocks, verified and unzipped).
    fn decode_blocks(
        &self,
        codec: BlockCodec,
        entry: &IndexEntry,
        stored: &[u8],
        rect: super::PageRect,
    ) -> Result<Vec<u8>> {
        codec
            .decode(
                self.layout.encoding(entry.key.channel),
                stored,
                rect.width,
                rect.height,
            )
            .ok_or_else(|| AssetError::Page {
                key: entry.key,
                page: entry.page,
                reason: format!("{codec} blocks of the wrong size"),
            })
    }

    /// Reads, checks and decodes every page of the file.
    pub fn verify_all(&self) -> Result<()> {
        let mut decoder = PageDecoder::new()?;
        for entry in &self.index {
            self.source
                .with_range(entry.offset, entry.length as usize, |bytes| {
                    decoder.decode(entry, bytes).map(|_| ())
                })?;
        }
        Ok(())
    }

    /// The stored (encoded) bytes of an index entry of this asset, checked against its CRC.
    pub(crate) fn stored_bytes(&self, entry: &IndexEntry) -> Result<Vec<u8>> {
        let bytes = self.source.read_at(entry.offset, entry.length as usize)?;
        if !super::format::crc_matches(&bytes, entry.crc32) {
            return Err(AssetError::Checksum {
                what: format!("page {} of {}", entry.page, entry.key),
            });
        }
        Ok(bytes)
    }

    /// The entries stored under exactly `key` (sorted by page; empty if none).
    fn entries_of(&self, key: ImageKey) -> &[IndexEntry] {
        let from = self.index.partition_point(|e| e.key < key);
        let to = from + self.index[from..].partition_point(|e| e.key == key);
        &self.index[from..to]
    }
}

/// Verifies and decodes pages, reusing one zstd context and one buffer.
struct PageDecoder {
    zstd: zstd::bulk::Decompressor<'static>,
    buf: Vec<u8>,
}

impl PageDecoder {
    fn new() -> Result<Self> {
        Ok(Self {
            zstd: zstd::bulk::Decompressor::new()?,
            buf: Vec::new(),
        })
    }

    /// Checks `stored` against the entry's CRC and decodes it to exactly `raw_length` bytes.
    /// The one-shot decoder writes into a buffer of `raw_length` bytes and fails rather than
    /// grow it, and needs no window buffer of its own, so a hostile frame cannot make it
    /// allocate more than the (validated) page size.
    fn decode<'a>(&'a mut self, entry: &IndexEntry, stored: &'a [u8]) -> Result<&'a [u8]> {
        if !crc_matches(stored, entry.crc32) {
            return Err(AssetError::Checksum {
                what: format!("page {} of {}", entry.page, entry.key),
            });
        }
        match entry.codec {
            Codec::Raw => Ok(stored),
            Codec::Zstd => {
                let raw_length = entry.raw_length as usize;
                self.buf.clear();
                self.buf.resize(raw_length, 0);
                let written = self
                    .zstd
                    .decompress_to_buffer(stored, self.buf.as_mut_slice())
                    .map_err(|source| AssetError::Decompress {
                        key: entry.key,
                        page: entry.page,
                        source,
                    })?;
                if written != raw_length {
                    return Err(AssetError::Page {
                        key: entry.key,
                        page: entry.page,
                        reason: format!("decoded to {written} bytes instead of {raw_length}"),
                    });
                }
                Ok(&self.buf)
            }
        }
    }
}
