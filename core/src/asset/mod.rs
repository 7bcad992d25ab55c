//! The light-field asset container `.lfa` (DESIGN §5; byte-level spec in `docs/format.md`).
//!
//! An asset is one self-describing, random-access file:
//!
//! ```text
//! [preamble: 64 bytes][page data: independently compressed pages][JSON header][binary index]
//! ```
//!
//! The types a reader meets first:
//! - [`AssetHeader`]: the JSON header (geometry, frame, channels, layers, states, provenance,
//!   quality report), built with [`AssetHeader::new_spherical`].
//! - [`ImageKey`]: one image = (layer, state, camera, channel). Each image is cut into
//!   `page_size`² pages ([`PageGrid`]); the [`IndexEntry`] list maps every page to its bytes.
//! - [`AssetWriter`] streams images into a temporary file beside the target and renames it into
//!   place on [`AssetWriter::finish`]; [`write_asset`] and [`encode_asset`] are one-call forms.
//! - [`AssetFile`] opens a file (or bytes), validates preamble, header and index against the
//!   file's real length and sane limits, and reads images or single pages on demand, verifying
//!   each page's checksum and size. Images a non-base state leaves out fall back to state 0.
//!
//! Nothing read from a file is trusted: every count, offset and length is checked before it is
//! used, with checked arithmetic, and corrupt input is an [`AssetError`], never a panic or an
//! allocation larger than the file (or, for decoded images, than the header's validated size).

mod block;
mod format;
mod header;
mod reader;
mod writer;

use std::fmt;

pub use block::{BLOCK, BlockCodec};
pub use format::{
    Codec, INDEX_ENTRY_LEN, IndexEntry, MAGIC, MAX_HEADER_LEN, PREAMBLE_LEN, Preamble, zstd_bound,
};
pub use header::{
    AssetHeader, AssetKind, BLOCK_COMPRESSION_SINCE, Channel, ChannelDesc, DEFAULT_PAGE_SIZE,
    Encoding, Geometry, LAYER_ORDER_SINCE, LayerDesc, LayerOrder, LfFrame, MAX_CAMERA_LEVEL,
    MAX_LAYERS, MAX_PAGE_SIZE, MAX_RESOLUTION_PX, MAX_STATES, MIN_PAGE_SIZE, MapProjection,
    PageGrid, PageRect, Provenance, SphericalGeometry, StateDesc, TWO_PLANE_SINCE,
    TwoPlaneGeometry, camera_count_for_level, two_plane_frame,
};
pub use reader::AssetFile;
pub use writer::{AssetWriter, MemoryWriter, encode_asset, with_header, write_asset};

/// The newest `.lfa` format version this build reads and writes. Version 2 adds the colour
/// encoding `rgba8_premultiplied` (semi-transparent light fields, e.g. volumes), version 3 the
/// header field `layer_order` (depth layers composited in ray order); a writer writes the
/// lowest version that can express its asset ([`AssetHeader::required_version`]), so assets
/// without them stay version 1 or 2. Version 4 lets a state other than 0 store only some pages
/// of an image (deformation states store the pages that changed); the others read from state 0.
/// Version 5 adds the kind `two_plane` (DESIGN §9), version 6 block-compressed channels
/// (BC1/BC7 colour, BC4 depth: [`BlockCodec`]).
pub const FORMAT_VERSION: u32 = 6;
/// The first version whose non-base states may store part of an image.
pub const PARTIAL_IMAGES_SINCE: u32 = 4;
/// The oldest version this build reads.
pub const MIN_FORMAT_VERSION: u32 = 1;

/// zstd level used for pages: fast to write, and decoding speed barely depends on the level.
pub const ZSTD_LEVEL: i32 = 3;

/// One image of an asset: a camera's map of one channel, in one layer and one state.
///
/// Ordered like the index: by layer, then state, camera, channel.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct ImageKey {
    /// Index into [`AssetHeader::layers`].
    pub layer: u16,
    /// Index into [`AssetHeader::states`]; state 0 is the complete base state.
    pub state: u16,
    /// Camera index in the order of the camera set (see `lumigraph_core::geometry`).
    pub camera: u32,
    /// Colour or depth.
    pub channel: Channel,
}

impl ImageKey {
    /// Builds a key.
    pub fn new(layer: u16, state: u16, camera: u32, channel: Channel) -> Self {
        Self {
            layer,
            state,
            camera,
            channel,
        }
    }

    /// The same image in the base state (state 0), where omitted images fall back to.
    #[must_use]
    pub fn in_base_state(self) -> Self {
        Self { state: 0, ..self }
    }
}

impl fmt::Display for ImageKey {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "layer {} / state {} / camera {} / {}",
            self.layer, self.state, self.camera, self.channel
        )
    }
}

/// Everything that can go wrong writing or reading an `.lfa` file.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum AssetError {
    /// The operating system failed to read, write, sync or rename the file.
    #[error("asset file I/O failed")]
    Io(#[from] std::io::Error),
    /// The data does not start with the `.lfa` magic bytes: it is not an asset at all.
    #[error("not a lumigraph light-field asset: the data does not start with the .lfa magic bytes")]
    BadMagic,
    /// The preamble names a format version this build cannot read.
    #[error(
        "asset format version {found} is not supported: this build of lumigraph reads versions \
         1 to {supported} (a file from a newer lumigraph needs a newer reader)"
    )]
    UnsupportedVersion {
        /// The version in the file.
        found: u32,
        /// The newest version this build reads.
        supported: u32,
    },
    /// The data ends before a section the file declares.
    #[error(
        "the file is truncated: the {what} needs {needed} bytes but the file has only {available}"
    )]
    Truncated {
        /// Which section is cut off.
        what: &'static str,
        /// The file length the section needs.
        needed: u64,
        /// The actual file length.
        available: u64,
    },
    /// A stored CRC-32 does not match the bytes: the file is corrupt.
    #[error("checksum mismatch in the {what}: the file is corrupt")]
    Checksum {
        /// Which part failed, e.g. `header` or `page 3 of layer 0 / state 0 / camera 5 / depth`.
        what: String,
    },
    /// The fixed 64-byte preamble holds impossible values.
    #[error("invalid preamble: {0}")]
    Preamble(String),
    /// The JSON header is malformed or describes an asset outside the format's limits.
    #[error("invalid header: {0}")]
    Header(String),
    /// The asset is of a kind the operation does not handle.
    #[error("{what} does not handle {kind:?} light fields")]
    Kind {
        /// The operation.
        what: &'static str,
        /// The asset's kind.
        kind: AssetKind,
    },
    /// The binary page index is malformed or inconsistent with the header.
    #[error("invalid index: {0}")]
    Index(String),
    /// A page's stored bytes do not decode to the size the index promises.
    #[error("page {page} of {key} is corrupt: {reason}")]
    Page {
        /// The image the page belongs to (as stored, after the state fallback).
        key: ImageKey,
        /// Page number within the image.
        page: u32,
        /// What is wrong with it.
        reason: String,
    },
    /// zstd rejected a page's bytes (corrupt frame, or more data than the page can hold).
    #[error("page {page} of {key} could not be decompressed")]
    Decompress {
        /// The image the page belongs to (as stored, after the state fallback).
        key: ImageKey,
        /// Page number within the image.
        page: u32,
        /// The decoder's error.
        #[source]
        source: std::io::Error,
    },
    /// zstd failed to compress a page while writing.
    #[error("page {page} of {key} could not be compressed")]
    Encode {
        /// The image being written.
        key: ImageKey,
        /// Page number within the image.
        page: u32,
        /// The encoder's error.
        #[source]
        source: std::io::Error,
    },
    /// The key names a layer, state or camera the header does not have.
    #[error("{key} is outside the asset: {reason}")]
    KeyOutOfRange {
        /// The offending key.
        key: ImageKey,
        /// Which part is out of range.
        reason: String,
    },
    /// Neither the requested state nor the base state holds the image.
    #[error("the asset has no image for {key}")]
    MissingImage {
        /// The requested key.
        key: ImageKey,
    },
    /// The page number is beyond the image's page grid.
    #[error("{key} has no page {page}: its images have {page_count} pages")]
    MissingPage {
        /// The requested key.
        key: ImageKey,
        /// The requested page.
        page: u32,
        /// Pages per image.
        page_count: u32,
    },
    /// An image given to the writer has the wrong number of bytes.
    #[error(
        "{key} has {actual} bytes but the header's resolution and encoding need exactly {expected}"
    )]
    ImageSize {
        /// The image being written.
        key: ImageKey,
        /// `resolution_px² × bytes per texel`.
        expected: u64,
        /// The length given.
        actual: u64,
    },
    /// The writer was given the same image twice.
    #[error("{key} was added twice")]
    DuplicateImage {
        /// The repeated key.
        key: ImageKey,
    },
    /// The writer was finished before state 0 held every layer × camera × channel.
    #[error(
        "the base state is incomplete: no image for {missing} (state 0 must hold every layer, \
         camera and channel)"
    )]
    IncompleteBaseState {
        /// The first missing image.
        missing: ImageKey,
    },
    /// Some pages of an image asked of the base state, or a bad page list.
    #[error("cannot store part of {key}: {reason}")]
    PartialImage {
        /// The image.
        key: ImageKey,
        /// Why.
        reason: String,
    },
    /// The header could not be serialized to JSON.
    #[error("the header could not be encoded as JSON")]
    HeaderEncode(#[source] serde_json::Error),
    /// An earlier I/O failure left the writer's file in an unknown state; drop the writer.
    #[error("the writer failed earlier and cannot continue")]
    WriterFailed,
}

/// Shorthand for results of this module.
pub type Result<T, E = AssetError> = std::result::Result<T, E>;
