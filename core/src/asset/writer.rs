//! Writing `.lfa` files: pages are compressed and streamed as images arrive; header and index
//! go last and the preamble is patched at the end, so quality reports can be added after the
//! pages. Files are written beside the target and renamed into place only when complete.

use std::collections::HashSet;
use std::fs::File;
use std::io::{BufWriter, Cursor, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use super::format::{IndexEntry, Layout, PREAMBLE_LEN, Preamble, crc32, encode_index};
use super::header::{AssetHeader, Channel};
use super::{AssetError, Codec, ImageKey, MAX_HEADER_LEN, Result, ZSTD_LEVEL};
use crate::fsutil::{atomic_write, temp_path_for};

/// Images smaller than this are compressed on the calling thread; thread start-up would cost
/// more than it saves.
const PARALLEL_MIN_BYTES: usize = 1 << 20;
/// Upper bound on compression threads per image.
const MAX_THREADS: usize = 8;

/// Streams an asset into a temporary file beside `path`; [`AssetWriter::finish`] renames it
/// into place. Dropping the writer without finishing (or after an error) removes the temporary
/// file, so the target is never left partial.
///
/// ```no_run
/// # use lumigraph_core::asset::*;
/// # fn demo(header: AssetHeader, images: Vec<(ImageKey, Vec<u8>)>) -> Result<()> {
/// let mut writer = AssetWriter::create("bunny.lfa", header)?;
/// for (key, bytes) in &images {
///     writer.add_image(*key, bytes)?;
/// }
/// writer.set_quality(serde_json::json!({"masked_psnr_db": 27.1}));
/// writer.finish()
/// # }
/// ```
pub struct AssetWriter {
    target: PathBuf,
    tmp: PathBuf,
    /// `None` once finished; the temporary file is removed on drop unless `committed`.
    encoder: Option<Encoder<BufWriter<File>>>,
    committed: bool,
}

impl AssetWriter {
    /// Validates `header` and creates the temporary file beside `path`.
    pub fn create(path: impl AsRef<Path>, header: AssetHeader) -> Result<Self> {
        let target = path.as_ref().to_path_buf();
        // Validate before touching the file system: an invalid header leaves nothing behind.
        Layout::new(&header)?;
        crate::fsutil::check_target(&target)?;
        let tmp = temp_path_for(&target);
        let file = File::create_new(&tmp)?;
        let mut writer = Self {
            target,
            tmp,
            encoder: None,
            committed: false,
        };
        // If writing the placeholder preamble fails, `writer`'s drop removes the file.
        writer.encoder = Some(Encoder::new(
            BufWriter::with_capacity(1 << 20, file),
            header,
        )?);
        Ok(writer)
    }

    /// Adds one image: `bytes` is the whole `resolution_px²` image, row-major, top row first,
    /// in the channel's encoding. Errors about the key or the length change nothing, and the
    /// writer can go on; after an I/O error it refuses further work.
    pub fn add_image(&mut self, key: ImageKey, bytes: &[u8]) -> Result<()> {
        self.encoder
            .as_mut()
            .ok_or(AssetError::WriterFailed)?
            .add_image(key, bytes)
    }

    /// Adds some pages of an image of a state other than 0 (`pages` strictly increasing page
    /// numbers); the image's other pages read from state 0. `bytes` is the whole image, as for
    /// [`Self::add_image`]. An image with fewer than all its pages makes the file version 4
    /// ([`super::PARTIAL_IMAGES_SINCE`]); no pages adds nothing.
    pub fn add_pages(&mut self, key: ImageKey, bytes: &[u8], pages: &[u32]) -> Result<()> {
        self.encoder
            .as_mut()
            .ok_or(AssetError::WriterFailed)?
            .add_pages(key, bytes, pages)
    }

    /// The page grid of the asset being written.
    ///
    /// # Errors
    /// [`AssetError::WriterFailed`] after a failed write.
    pub fn page_grid(&self) -> Result<super::PageGrid> {
        Ok(self
            .encoder
            .as_ref()
            .ok_or(AssetError::WriterFailed)?
            .layout
            .grid)
    }

    /// Sets the header's quality report (replacing any earlier one).
    pub fn set_quality(&mut self, value: serde_json::Value) {
        if let Some(encoder) = self.encoder.as_mut() {
            encoder.header.quality = Some(value);
        }
    }

    /// Records the wall-clock bake time in the header's provenance (known only at the end).
    pub fn set_bake_ms(&mut self, bake_ms: f64) {
        if let Some(encoder) = self.encoder.as_mut() {
            encoder.header.provenance.bake_ms = bake_ms;
        }
    }

    /// Writes header and index, patches the preamble, syncs and renames over the target.
    /// Fails (and removes the temporary file) if state 0 lacks any layer × camera × channel.
    pub fn finish(mut self) -> Result<()> {
        let encoder = self.encoder.take().ok_or(AssetError::WriterFailed)?;
        let file = encoder
            .finish()?
            .into_inner()
            .map_err(std::io::IntoInnerError::into_error)?;
        file.sync_all()?;
        drop(file);
        std::fs::rename(&self.tmp, &self.target)?;
        self.committed = true;
        Ok(())
    }
}

impl Drop for AssetWriter {
    fn drop(&mut self) {
        // Close the file first: some platforms cannot remove an open file.
        drop(self.encoder.take());
        if !self.committed {
            let _ = std::fs::remove_file(&self.tmp);
        }
    }
}

/// Writes a whole asset atomically: on any error nothing appears at `path` (an existing file
/// there is left untouched) and no temporary file remains.
pub fn write_asset(
    path: impl AsRef<Path>,
    header: AssetHeader,
    images: impl IntoIterator<Item = (ImageKey, Vec<u8>)>,
) -> Result<()> {
    Layout::new(&header)?;
    atomic_write(path.as_ref(), |w| {
        let mut encoder = Encoder::new(w, header)?;
        for (key, bytes) in images {
            encoder.add_image(key, &bytes)?;
        }
        encoder.finish()?;
        Ok(())
    })
}

/// Encodes a whole asset in memory (for uploads, tests and [`super::AssetFile::from_bytes`]).
pub fn encode_asset(
    header: AssetHeader,
    images: impl IntoIterator<Item = (ImageKey, Vec<u8>)>,
) -> Result<Vec<u8>> {
    let mut encoder = Encoder::new(Cursor::new(Vec::new()), header)?;
    for (key, bytes) in images {
        encoder.add_image(key, &bytes)?;
    }
    Ok(encoder.finish()?.into_inner())
}

/// Re-encodes `asset` in memory with another header of the same layout (a new quality report,
/// say), copying every stored page as it is: no decoding, no recompression, and the states'
/// partial images stay partial.
///
/// # Errors
/// A header whose layout (page grid, layers, states, cameras, encodings, block compression)
/// differs from the asset's, or a page whose checksum fails.
pub fn with_header(asset: &super::AssetFile, header: AssetHeader) -> Result<Vec<u8>> {
    let layout = Layout::new(&header)?;
    let old = Layout::new(asset.header())?;
    if (layout.grid, layout.layers, layout.states, layout.cameras)
        != (old.grid, old.layers, old.states, old.cameras)
        || Channel::ALL.map(|c| layout.bytes_per_texel(c))
            != Channel::ALL.map(|c| old.bytes_per_texel(c))
        || (layout.color_block, layout.depth_block) != (old.color_block, old.depth_block)
        || header.format_version < asset.header().format_version
    {
        return Err(AssetError::Header(
            "a new header must keep the asset's layout and format version".to_owned(),
        ));
    }
    let mut encoder = Encoder::new(Cursor::new(Vec::new()), header)?;
    for entry in asset.index() {
        let bytes = asset.stored_bytes(entry)?;
        encoder.sink.write_all(&bytes)?;
        encoder.entries.push(IndexEntry::new(
            entry.key,
            entry.page,
            entry.codec,
            encoder.position,
            entry.length,
            entry.raw_length,
            entry.crc32,
        ));
        encoder.position += u64::from(entry.length);
        encoder.added.insert(entry.key);
    }
    Ok(encoder.finish()?.into_inner())
}

/// Encodes an asset in memory one image at a time: each image's pages are compressed as it is
/// added, so only the compressed asset is held (a bake kept in memory, light states included,
/// costs its file size, not its decoded size).
pub struct MemoryWriter {
    encoder: Encoder<Cursor<Vec<u8>>>,
}

impl MemoryWriter {
    /// A writer for an asset with `header`.
    ///
    /// # Errors
    /// An invalid header.
    pub fn new(header: AssetHeader) -> Result<Self> {
        Ok(Self {
            encoder: Encoder::new(Cursor::new(Vec::new()), header)?,
        })
    }

    /// Adds one image, as [`AssetWriter::add_image`] does.
    ///
    /// # Errors
    /// As [`AssetWriter::add_image`].
    pub fn add_image(&mut self, key: ImageKey, bytes: &[u8]) -> Result<()> {
        self.encoder.add_image(key, bytes)
    }

    /// Adds some pages of an image, as [`AssetWriter::add_pages`] does.
    ///
    /// # Errors
    /// As [`AssetWriter::add_pages`].
    pub fn add_pages(&mut self, key: ImageKey, bytes: &[u8], pages: &[u32]) -> Result<()> {
        self.encoder.add_pages(key, bytes, pages)
    }

    /// The page grid of the asset being written.
    pub fn page_grid(&self) -> super::PageGrid {
        self.encoder.layout.grid
    }

    /// Records the wall-clock bake time in the header's provenance.
    pub fn set_bake_ms(&mut self, bake_ms: f64) {
        self.encoder.header.provenance.bake_ms = bake_ms;
    }

    /// The encoded asset.
    ///
    /// # Errors
    /// If state 0 lacks any layer × camera × channel, or an earlier write failed.
    pub fn finish(self) -> Result<Vec<u8>> {
        Ok(self.encoder.finish()?.into_inner())
    }
}

/// The format logic of writing, over any seekable sink.
struct Encoder<W: Write + Seek> {
    sink: W,
    header: AssetHeader,
    layout: Layout,
    /// Next write position (the sink's length).
    position: u64,
    entries: Vec<IndexEntry>,
    added: HashSet<ImageKey>,
    /// Set when a write failed midway: the sink's content is unknown from then on.
    failed: bool,
}

/// A page ready to store.
struct StoredPage {
    codec: Codec,
    bytes: Vec<u8>,
    raw_length: u32,
}

impl<W: Write + Seek> Encoder<W> {
    /// Validates the header and writes a zeroed preamble as a placeholder: until `finish`
    /// patches it, the file fails the magic check.
    fn new(mut sink: W, header: AssetHeader) -> Result<Self> {
        let layout = Layout::new(&header)?;
        sink.write_all(&[0u8; PREAMBLE_LEN as usize])?;
        Ok(Self {
            sink,
            header,
            layout,
            position: PREAMBLE_LEN,
            entries: Vec::new(),
            added: HashSet::new(),
            failed: false,
        })
    }

    fn add_image(&mut self, key: ImageKey, bytes: &[u8]) -> Result<()> {
        let all: Vec<u32> = (0..self.layout.grid.page_count()).collect();
        self.add_pages_unchecked(key, bytes, &all)
    }

    fn add_pages(&mut self, key: ImageKey, bytes: &[u8], pages: &[u32]) -> Result<()> {
        let bad = |reason: &str| {
            Err(AssetError::PartialImage {
                key,
                reason: reason.to_owned(),
            })
        };
        let count = self.layout.grid.page_count();
        if key.state == 0 && pages.len() != count as usize {
            return bad("state 0 stores every page of every image");
        }
        if !pages.windows(2).all(|w| w[0] < w[1]) {
            return bad("page numbers must be strictly increasing");
        }
        if pages.last().is_some_and(|&p| p >= count) {
            return bad(&format!("an image has {count} pages"));
        }
        if pages.is_empty() {
            return Ok(());
        }
        self.add_pages_unchecked(key, bytes, pages)
    }

    /// Stores `pages` (strictly increasing, in range) of `key`'s image.
    fn add_pages_unchecked(&mut self, key: ImageKey, bytes: &[u8], pages: &[u32]) -> Result<()> {
        if self.failed {
            return Err(AssetError::WriterFailed);
        }
        self.layout.check_key(key)?;
        let expected = self.layout.image_bytes(key.channel);
        if bytes.len() as u64 != expected {
            return Err(AssetError::ImageSize {
                key,
                expected,
                actual: bytes.len() as u64,
            });
        }
        if self.added.contains(&key) {
            return Err(AssetError::DuplicateImage { key });
        }
        let stored_pages = compress_image(&self.layout, key, bytes, pages)?;

        self.failed = true;
        for (&page, stored) in pages.iter().zip(stored_pages) {
            self.sink.write_all(&stored.bytes)?;
            self.entries.push(IndexEntry::new(
                key,
                page,
                stored.codec,
                self.position,
                stored.bytes.len() as u32,
                stored.raw_length,
                crc32(&stored.bytes),
            ));
            self.position += stored.bytes.len() as u64;
        }
        self.failed = false;
        self.added.insert(key);
        if pages.len() != self.layout.grid.page_count() as usize {
            self.header.format_version =
                self.header.format_version.max(super::PARTIAL_IMAGES_SINCE);
        }
        Ok(())
    }

    fn finish(mut self) -> Result<W> {
        if self.failed {
            return Err(AssetError::WriterFailed);
        }
        let layout = self.layout;
        for layer in 0..layout.layers {
            for camera in 0..layout.cameras {
                for channel in Channel::ALL {
                    let key = ImageKey::new(layer as u16, 0, camera, channel);
                    if !self.added.contains(&key) {
                        return Err(AssetError::IncompleteBaseState { missing: key });
                    }
                }
            }
        }
        self.entries.sort_unstable_by_key(IndexEntry::sort_key);
        let index = encode_index(&self.entries)?;
        let header = serde_json::to_vec_pretty(&self.header).map_err(AssetError::HeaderEncode)?;
        if header.len() as u64 > MAX_HEADER_LEN {
            return Err(AssetError::Header(format!(
                "the encoded header is {} bytes; the limit is {MAX_HEADER_LEN} (is the quality \
                 report too large?)",
                header.len()
            )));
        }
        let header_offset = self.position;
        let index_offset = header_offset + header.len() as u64;
        self.sink.write_all(&header)?;
        self.sink.write_all(&index)?;
        let preamble = Preamble::new(
            self.header.format_version,
            header_offset,
            header.len() as u64,
            crc32(&header),
            index_offset,
            index.len() as u64,
            crc32(&index),
        );
        self.sink.seek(SeekFrom::Start(0))?;
        self.sink.write_all(&preamble.to_bytes())?;
        self.sink.flush()?;
        Ok(self.sink)
    }
}

/// Cuts `pages` out of `bytes` and compresses each, in parallel for large images.
fn compress_image(
    layout: &Layout,
    key: ImageKey,
    bytes: &[u8],
    pages: &[u32],
) -> Result<Vec<StoredPage>> {
    let page_count = pages.len() as u32;
    let threads = std::thread::available_parallelism()
        .map_or(1, std::num::NonZero::get)
        .min(MAX_THREADS)
        .min(page_count as usize);
    if threads <= 1 || bytes.len() < PARALLEL_MIN_BYTES {
        return compress_pages(layout, key, bytes, pages);
    }
    let per_thread = page_count.div_ceil(threads as u32) as usize;
    let chunks: Vec<Result<Vec<StoredPage>>> = std::thread::scope(|scope| {
        let handles: Vec<_> = pages
            .chunks(per_thread)
            .map(|chunk| scope.spawn(move || compress_pages(layout, key, bytes, chunk)))
            .collect();
        handles
            .into_iter()
            .map(|h| {
                h.join()
                    .unwrap_or_else(|panic| std::panic::resume_unwind(panic))
            })
            .collect()
    });
    let mut pages = Vec::with_capacity(page_count as usize);
    for chunk in chunks {
        pages.extend(chunk?);
    }
    Ok(pages)
}

fn compress_pages(
    layout: &Layout,
    key: ImageKey,
    bytes: &[u8],
    pages: &[u32],
) -> Result<Vec<StoredPage>> {
    let encode_err = |page, source| AssetError::Encode { key, page, source };
    let mut compressor = zstd::bulk::Compressor::new(ZSTD_LEVEL)
        .map_err(|e| encode_err(pages.first().copied().unwrap_or(0), e))?;
    let bpp = layout.bytes_per_texel(key.channel) as usize;
    let side = layout.grid.width() as usize;
    let mut out = Vec::with_capacity(pages.len());
    for (page, rect) in pages
        .iter()
        .filter_map(|&page| Some((page, layout.grid.page_rect(page)?)))
    {
        let row_bytes = rect.width as usize * bpp;
        let mut raw = Vec::with_capacity(row_bytes * rect.height as usize);
        for y in rect.y as usize..(rect.y + rect.height) as usize {
            let start = (y * side + rect.x as usize) * bpp;
            raw.extend_from_slice(&bytes[start..start + row_bytes]);
        }
        let raw = match layout.block(key.channel) {
            Some(codec) => codec
                .encode(layout.encoding(key.channel), &raw, rect.width, rect.height)
                .ok_or_else(|| AssetError::Page {
                    key,
                    page,
                    reason: format!(
                        "{codec} needs pages of whole 4x4 blocks; this one is {}x{}",
                        rect.width, rect.height
                    ),
                })?,
            None => raw,
        };
        let raw_length = raw.len() as u32;
        let compressed = compressor.compress(&raw).map_err(|e| encode_err(page, e))?;
        out.push(if compressed.len() < raw.len() {
            StoredPage {
                codec: Codec::Zstd,
                bytes: compressed,
                raw_length,
            }
        } else {
            StoredPage {
                codec: Codec::Raw,
                bytes: raw,
                raw_length,
            }
        });
    }
    Ok(out)
}
