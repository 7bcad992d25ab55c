//! `.lfa` container tests through the public API: round trips, the state fallback, header field
//! names, truncation, byte flips, hostile sizes (with an allocation watchdog), atomic writes and
//! a property-based round trip.
//!
//! File manipulation here follows `docs/format.md` byte for byte rather than calling crate
//! internals, so the tests also check that the spec describes what the code does.

// The watchdog below is a `GlobalAlloc`, which needs `unsafe impl`; it only forwards to `System`.
#![allow(unsafe_code)]

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::path::Path;

use lumigraph_core::asset::{
    AssetError, AssetFile, AssetHeader, AssetWriter, BLOCK_COMPRESSION_SINCE, BlockCodec, Channel,
    Codec, Encoding, Geometry, ImageKey, LayerDesc, LfFrame, MemoryWriter, Provenance, StateDesc,
    encode_asset, write_asset,
};
use proptest::prelude::*;
use serde_json::{Value, json};

// ---------------------------------------------------------------------------------------------
// Allocation watchdog: records the largest single allocation request made on the current
// thread while enabled, so a test can prove the reader never sizes a buffer from a claimed
// length it has not checked against the data.

struct Watchdog;

thread_local! {
    static LARGEST: Cell<Option<usize>> = const { Cell::new(None) };
}

fn note_allocation(size: usize) {
    // `try_with`: allocations during thread teardown must not panic.
    let _ = LARGEST.try_with(|largest| {
        if let Some(max) = largest.get() {
            largest.set(Some(max.max(size)));
        }
    });
}

unsafe impl GlobalAlloc for Watchdog {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        note_allocation(layout.size());
        unsafe { System.alloc(layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        note_allocation(layout.size());
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        note_allocation(new_size);
        unsafe { System.realloc(ptr, layout, new_size) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static GLOBAL: Watchdog = Watchdog;

/// Runs `f` and returns its result with the largest single allocation it made.
fn largest_allocation<R>(f: impl FnOnce() -> R) -> (R, usize) {
    LARGEST.with(|l| l.set(Some(0)));
    let result = f();
    let largest = LARGEST.with(|l| l.replace(None)).unwrap_or(0);
    (result, largest)
}

// ---------------------------------------------------------------------------------------------
// Fixtures.

/// Deterministic pseudo-random bytes (SplitMix64), so failures reproduce.
fn pseudo_random(seed: u64, len: usize) -> Vec<u8> {
    let mut state = seed;
    let mut out = Vec::with_capacity(len + 8);
    while out.len() < len {
        state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        out.extend_from_slice(&(z ^ (z >> 31)).to_le_bytes());
    }
    out.truncate(len);
    out
}

/// Image content for a key: random for odd cameras (stored raw), compressible otherwise (zstd).
fn content(header: &AssetHeader, key: ImageKey, salt: u64) -> Vec<u8> {
    let [width, height] = header.image_size().map(|x| x as usize);
    let bpp = header.encoding(key.channel).unwrap().bytes_per_texel() as usize;
    let seed = salt
        ^ (u64::from(key.layer) << 48)
        ^ (u64::from(key.state) << 32)
        ^ (u64::from(key.camera) << 8)
        ^ u64::from(key.channel == Channel::Depth);
    let mut bytes = pseudo_random(seed, width * height * bpp);
    if key.camera.is_multiple_of(2) {
        // Long runs so zstd wins; a few random bytes so images still differ.
        for (i, b) in bytes.iter_mut().enumerate() {
            if i % 61 != 0 {
                *b = 0;
            }
        }
    }
    bytes
}

/// Images with their bytes, as the writer takes them.
type Images = Vec<(ImageKey, Vec<u8>)>;
/// What a hostile input must be rejected with.
type Check = fn(&AssetError) -> bool;
/// An edit of the preamble's fields.
type PreamblePatch = Box<dyn Fn(&mut RawPreamble)>;
/// An edit of the header JSON.
type HeaderEdit = Box<dyn Fn(&mut Value)>;

fn frame() -> LfFrame {
    LfFrame {
        center: [0.5, -1.0, 2.0],
        radius: 0.75,
    }
}

fn provenance() -> Provenance {
    Provenance {
        source_name: "bunny.ply".to_owned(),
        source_sha256: "ab".repeat(32),
        lumigraph_version: "0.1.0".to_owned(),
        bake_options: json!({"cameras": 12, "resolution": 40}),
        triangles: 69_451,
        vertices: 35_947,
        bake_ms: 1234.5,
        created_unix: 1_700_000_000,
    }
}

fn header(camera_level: u8, resolution_px: u32, page_size: u32, depth: Encoding) -> AssetHeader {
    let mut header =
        AssetHeader::new_spherical(camera_level, resolution_px, frame(), depth, provenance())
            .unwrap();
    header.page_size = page_size;
    header
}

/// Every base-state image of `header`.
fn base_keys(header: &AssetHeader) -> Vec<ImageKey> {
    let mut keys = Vec::new();
    for layer in 0..header.layers.len() as u16 {
        for camera in 0..header.camera_count() {
            for channel in Channel::ALL {
                keys.push(ImageKey::new(layer, 0, camera, channel));
            }
        }
    }
    keys
}

fn images_for(header: &AssetHeader, keys: &[ImageKey], salt: u64) -> Images {
    keys.iter()
        .map(|&k| (k, content(header, k, salt)))
        .collect()
}

/// Level 0, 12 cameras, 40 px with 16 px pages: 3 × 3 pages, the last row and column 8 px.
fn small_asset() -> (AssetHeader, Images, Vec<u8>) {
    let header = header(0, 40, 16, Encoding::R16);
    let images = images_for(&header, &base_keys(&header), 1);
    let bytes = encode_asset(header.clone(), images.clone()).unwrap();
    (header, images, bytes)
}

/// A few-kilobyte asset (one page per image, R8 depth) for exhaustive corruption tests.
fn tiny_asset() -> Vec<u8> {
    let header = header(0, 16, 16, Encoding::R8);
    encode_asset(header.clone(), images_for(&header, &base_keys(&header), 2)).unwrap()
}

// ---------------------------------------------------------------------------------------------
// Spec-level access to the raw bytes (docs/format.md "Preamble"), independent of the crate.

#[derive(Clone, Copy, Debug)]
struct RawPreamble {
    version: u32,
    flags: u32,
    header_offset: u64,
    header_len: u64,
    header_crc: u32,
    index_offset: u64,
    index_len: u64,
    index_crc: u32,
}

fn u32_at(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes(b[at..at + 4].try_into().unwrap())
}

fn u64_at(b: &[u8], at: usize) -> u64 {
    u64::from_le_bytes(b[at..at + 8].try_into().unwrap())
}

fn raw_preamble(b: &[u8]) -> RawPreamble {
    assert_eq!(&b[..8], b"LFA\x00\r\n\x1a\n");
    assert_eq!(
        u32_at(b, 56),
        crc32fast::hash(&b[..56]),
        "preamble checksum"
    );
    assert!(b[60..64].iter().all(|&x| x == 0), "preamble padding");
    RawPreamble {
        version: u32_at(b, 8),
        flags: u32_at(b, 12),
        header_offset: u64_at(b, 16),
        header_len: u64_at(b, 24),
        header_crc: u32_at(b, 32),
        index_offset: u64_at(b, 36),
        index_len: u64_at(b, 44),
        index_crc: u32_at(b, 52),
    }
}

/// Writes `p` into the first 64 bytes with a correct preamble checksum.
fn put_preamble(b: &mut [u8], p: RawPreamble) {
    b[8..12].copy_from_slice(&p.version.to_le_bytes());
    b[12..16].copy_from_slice(&p.flags.to_le_bytes());
    b[16..24].copy_from_slice(&p.header_offset.to_le_bytes());
    b[24..32].copy_from_slice(&p.header_len.to_le_bytes());
    b[32..36].copy_from_slice(&p.header_crc.to_le_bytes());
    b[36..44].copy_from_slice(&p.index_offset.to_le_bytes());
    b[44..52].copy_from_slice(&p.index_len.to_le_bytes());
    b[52..56].copy_from_slice(&p.index_crc.to_le_bytes());
    let crc = crc32fast::hash(&b[..56]);
    b[56..60].copy_from_slice(&crc.to_le_bytes());
}

fn patch_preamble(bytes: &[u8], f: impl FnOnce(&mut RawPreamble)) -> Vec<u8> {
    let mut out = bytes.to_vec();
    let mut p = raw_preamble(&out);
    f(&mut p);
    put_preamble(&mut out, p);
    out
}

fn header_bytes(b: &[u8]) -> &[u8] {
    let p = raw_preamble(b);
    &b[p.header_offset as usize..(p.header_offset + p.header_len) as usize]
}

fn index_bytes(b: &[u8]) -> &[u8] {
    let p = raw_preamble(b);
    &b[p.index_offset as usize..(p.index_offset + p.index_len) as usize]
}

/// Rebuilds the file with new header and index bytes (checksums fixed): page data unchanged,
/// then the header, then the index, as the writer lays them out.
fn rebuild(b: &[u8], header: &[u8], index: &[u8]) -> Vec<u8> {
    let p = raw_preamble(b);
    let data_end = p.header_offset.min(p.index_offset) as usize;
    let mut out = b[..data_end].to_vec();
    out.extend_from_slice(header);
    out.extend_from_slice(index);
    put_preamble(
        &mut out,
        RawPreamble {
            header_offset: data_end as u64,
            header_len: header.len() as u64,
            header_crc: crc32fast::hash(header),
            index_offset: (data_end + header.len()) as u64,
            index_len: index.len() as u64,
            index_crc: crc32fast::hash(index),
            ..p
        },
    );
    out
}

fn with_header_json(b: &[u8], f: impl FnOnce(&mut Value)) -> Vec<u8> {
    let mut json: Value = serde_json::from_slice(header_bytes(b)).unwrap();
    f(&mut json);
    rebuild(b, &serde_json::to_vec(&json).unwrap(), index_bytes(b))
}

fn with_index(b: &[u8], f: impl FnOnce(&mut Vec<u8>)) -> Vec<u8> {
    let mut index = index_bytes(b).to_vec();
    f(&mut index);
    rebuild(b, header_bytes(b), &index)
}

/// Byte offset of field `at` of index entry `entry` within the index.
fn entry_field(entry: usize, at: usize) -> usize {
    4 + 36 * entry + at
}

fn files_in(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    names
}

// ---------------------------------------------------------------------------------------------
// Round trips.

#[test]
fn round_trip_is_bit_exact_from_file_and_bytes() {
    let (header, images, bytes) = small_asset();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("small.lfa");
    write_asset(&path, header.clone(), images.clone()).unwrap();
    assert_eq!(
        std::fs::read(&path).unwrap(),
        bytes,
        "file and in-memory encodings agree"
    );
    assert_eq!(files_in(dir.path()), ["small.lfa"]);

    let from_file = AssetFile::open(&path).unwrap();
    let from_bytes = AssetFile::from_bytes(bytes.clone()).unwrap();
    for asset in [&from_file, &from_bytes] {
        assert_eq!(asset.header(), &header);
        assert_eq!(asset.file_len(), bytes.len() as u64);
        assert_eq!(asset.index().len(), 12 * 2 * 9);
        asset.verify_all().unwrap();
        for (key, expected) in &images {
            assert_eq!(&asset.read_image(*key).unwrap(), expected, "{key}");
        }
    }
    // The watchdog sees the decoded image (so an empty reading below means something).
    let (_, largest) = largest_allocation(|| from_bytes.read_image(images[0].0));
    assert!(largest >= 40 * 40 * 4, "watchdog saw {largest}");
    // Both codecs occur: random images do not compress, the zero-heavy ones do.
    let codecs: Vec<Codec> = from_file.index().iter().map(|e| e.codec).collect();
    assert!(codecs.contains(&Codec::Raw) && codecs.contains(&Codec::Zstd));
}

#[test]
fn pages_cover_the_image_with_partial_edge_pages() {
    let (header, images, bytes) = small_asset();
    let asset = AssetFile::from_bytes(bytes).unwrap();
    let grid = header.page_grid().unwrap();
    assert_eq!((grid.pages_per_row(), grid.page_count()), (3, 9));
    let (key, image) = &images[3]; // camera 1, depth: 2 bytes per texel
    assert_eq!(key.channel, Channel::Depth);
    for page in 0..9 {
        let rect = grid.page_rect(page).unwrap();
        let bytes = asset.read_page(*key, page).unwrap();
        let mut expected = Vec::new();
        for y in rect.y..rect.y + rect.height {
            let start = ((y * 40 + rect.x) * 2) as usize;
            expected.extend_from_slice(&image[start..start + (rect.width * 2) as usize]);
        }
        assert_eq!(bytes, expected, "page {page}");
    }
    let edge = grid.page_rect(8).unwrap();
    assert_eq!((edge.x, edge.y, edge.width, edge.height), (32, 32, 8, 8));
    assert!(matches!(
        asset.read_page(*key, 9),
        Err(AssetError::MissingPage {
            page: 9,
            page_count: 9,
            ..
        })
    ));
    let outside = ImageKey::new(0, 0, 12, Channel::Color);
    assert!(matches!(
        asset.read_image(outside),
        Err(AssetError::KeyOutOfRange { .. })
    ));
    assert!(matches!(
        asset.read_image(ImageKey::new(1, 0, 0, Channel::Color)),
        Err(AssetError::KeyOutOfRange { .. })
    ));
}

#[test]
fn file_layout_follows_the_spec() {
    let (_, _, bytes) = small_asset();
    let p = raw_preamble(&bytes);
    assert_eq!((p.version, p.flags), (1, 0));
    // Pages, then header, then index, which ends the file.
    assert!(p.header_offset >= 64);
    assert_eq!(p.index_offset, p.header_offset + p.header_len);
    assert_eq!(p.index_offset + p.index_len, bytes.len() as u64);
    assert_eq!(crc32fast::hash(header_bytes(&bytes)), p.header_crc);
    assert_eq!(crc32fast::hash(index_bytes(&bytes)), p.index_crc);

    let index = index_bytes(&bytes);
    let count = u32_at(index, 0) as usize;
    assert_eq!(index.len(), 4 + 36 * count);
    let mut previous = None;
    let mut data_bytes = 0u64;
    for i in 0..count {
        let e = &index[4 + 36 * i..4 + 36 * (i + 1)];
        let key = (
            u16::from_le_bytes([e[0], e[1]]),
            u16::from_le_bytes([e[2], e[3]]),
            u32_at(e, 4),
            e[8],
            u32_at(e, 12),
        );
        assert!(e[9] <= 1 && e[10] == 0 && e[11] == 0);
        assert!(previous < Some(key), "sorted and unique");
        previous = Some(key);
        let (offset, length) = (u64_at(e, 16), u64::from(u32_at(e, 24)));
        let stored = &bytes[offset as usize..(offset + length) as usize];
        assert_eq!(crc32fast::hash(stored), u32_at(e, 32));
        data_bytes += length;
    }
    // The reference writer leaves no gaps: page data fills [64, header_offset).
    assert_eq!(64 + data_bytes, p.header_offset);
}

#[test]
fn layers_and_states_with_fallback_to_the_base_state() {
    let mut header = header(0, 24, 16, Encoding::R32F);
    header.layers = vec![
        LayerDesc {
            name: "surface".to_owned(),
            default_opacity: 1.0,
        },
        LayerDesc {
            name: "interior".to_owned(),
            default_opacity: 0.5,
        },
    ];
    let mut light = serde_json::Map::new();
    light.insert("light_dir".to_owned(), json!([0.0, 1.0, 0.0]));
    let mut deformed = serde_json::Map::new();
    deformed.insert("frame".to_owned(), json!(3));
    header.states.push(StateDesc {
        name: "light_top".to_owned(),
        params: light,
    });
    header.states.push(StateDesc {
        name: "deformed".to_owned(),
        params: deformed,
    });

    let mut keys = base_keys(&header);
    for layer in 0..2 {
        // State 1 (a light direction) changes colour only: depth falls back.
        for camera in 0..12 {
            keys.push(ImageKey::new(layer, 1, camera, Channel::Color));
        }
        // State 2 (a deformation) stores only the cameras that see the change.
        for camera in [0, 5] {
            for channel in Channel::ALL {
                keys.push(ImageKey::new(layer, 2, camera, channel));
            }
        }
    }
    let images = images_for(&header, &keys, 3);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("states.lfa");
    let mut writer = AssetWriter::create(&path, header.clone()).unwrap();
    // Any insertion order works; the index is sorted on finish.
    for (key, bytes) in images.iter().rev() {
        writer.add_image(*key, bytes).unwrap();
    }
    writer.set_quality(json!({"masked_psnr_db": 27.5}));
    writer.finish().unwrap();

    let asset = AssetFile::open(&path).unwrap();
    assert_eq!(
        asset.header().quality,
        Some(json!({"masked_psnr_db": 27.5}))
    );
    assert_eq!(asset.header().layers, header.layers);
    assert_eq!(asset.header().states, header.states);
    assert_eq!(asset.index().len(), keys.len() * 4);
    asset.verify_all().unwrap();

    let stored: std::collections::HashMap<ImageKey, Vec<u8>> = images.into_iter().collect();
    for layer in 0..2 {
        for state in 0..3 {
            for camera in 0..12 {
                for channel in Channel::ALL {
                    let key = ImageKey::new(layer, state, camera, channel);
                    let owner = if stored.contains_key(&key) {
                        key
                    } else {
                        key.in_base_state()
                    };
                    assert_eq!(asset.has_image(key), owner == key);
                    assert_eq!(asset.stored_pages(key), if owner == key { 4 } else { 0 });
                    assert_eq!(asset.read_image(key).unwrap(), stored[&owner], "{key}");
                    assert_eq!(asset.read_page(key, 3).unwrap().len(), 8 * 8 * 4);
                }
            }
        }
    }
    // A state that does not exist is out of range, not a fallback.
    assert!(matches!(
        asset.read_image(ImageKey::new(0, 3, 0, Channel::Color)),
        Err(AssetError::KeyOutOfRange { .. })
    ));
}

#[test]
fn a_state_may_store_some_pages_from_version_4_and_the_rest_read_from_state_0() {
    // 40 px, 16 px pages: 3 × 3 pages of 16, 16 and 8 texels a side.
    let mut header = header(0, 40, 16, Encoding::R16);
    header.states.push(StateDesc {
        name: "dent".to_owned(),
        params: serde_json::Map::new(),
    });
    assert_eq!(header.format_version, 1);
    let base = images_for(&header, &base_keys(&header), 1);
    let color = ImageKey::new(0, 1, 4, Channel::Color);
    let depth = ImageKey::new(0, 1, 4, Channel::Depth);
    let new_color = content(&header, color, 2);
    let new_depth = content(&header, depth, 3);
    let mut writer = MemoryWriter::new(header.clone()).unwrap();
    for (key, bytes) in &base {
        writer.add_image(*key, bytes).unwrap();
    }
    // Refused: part of a base image, pages out of order or out of the grid.
    let base_color = ImageKey::new(0, 0, 4, Channel::Color);
    for (key, pages) in [
        (base_color, vec![0]),
        (color, vec![3, 1]),
        (color, vec![1, 1]),
        (color, vec![9]),
    ] {
        let err = writer.add_pages(key, &new_color, &pages).unwrap_err();
        assert!(matches!(err, AssetError::PartialImage { .. }), "{err}");
    }
    writer.add_pages(color, &new_color, &[1, 8]).unwrap();
    writer.add_pages(depth, &new_depth, &[4]).unwrap();
    // No pages: nothing stored, not an error.
    writer
        .add_pages(ImageKey::new(0, 1, 5, Channel::Color), &new_color, &[])
        .unwrap();
    let bytes = writer.finish().unwrap();
    let asset = AssetFile::from_bytes(bytes.clone()).unwrap();
    assert_eq!(asset.header().format_version, 4);
    assert_eq!(raw_preamble(&bytes).version, 4);
    assert_eq!(asset.index().len(), 12 * 2 * 9 + 3);
    assert_eq!(asset.stored_pages(color), 2);
    assert_eq!(asset.stored_pages(depth), 1);
    assert!(!asset.has_image(ImageKey::new(0, 1, 5, Channel::Color)));

    // Each page reads from the state where it is stored, else from state 0.
    let grid = asset.header().page_grid().unwrap();
    let expect = |key: ImageKey, new: &[u8], stored: &[u32]| {
        let bpp = if key.channel == Channel::Color { 4 } else { 2 };
        let old = &base
            .iter()
            .find(|(k, _)| *k == key.in_base_state())
            .unwrap()
            .1;
        let mut want = old.clone();
        for &page in stored {
            let r = grid.page_rect(page).unwrap();
            for y in r.y..r.y + r.height {
                let at = (y as usize * 40 + r.x as usize) * bpp;
                let len = r.width as usize * bpp;
                want[at..at + len].copy_from_slice(&new[at..at + len]);
            }
        }
        assert_eq!(asset.read_image(key).unwrap(), want, "{key}");
        for page in 0..9 {
            let r = grid.page_rect(page).unwrap();
            let mut rows = Vec::new();
            for y in r.y..r.y + r.height {
                let at = (y as usize * 40 + r.x as usize) * bpp;
                rows.extend_from_slice(&want[at..at + r.width as usize * bpp]);
            }
            assert_eq!(
                asset.read_page(key, page).unwrap(),
                rows,
                "{key} page {page}"
            );
        }
    };
    expect(color, &new_color, &[1, 8]);
    expect(depth, &new_depth, &[4]);
    asset.verify_all().unwrap();

    // The same index under version 3, where images are whole: refused, naming the rule.
    let v3 = with_header_json(&bytes, |h| h["format_version"] = json!(3));
    let v3 = patch_preamble(&v3, |p| p.version = 3);
    let err = AssetFile::from_bytes(v3).unwrap_err();
    assert!(
        matches!(&err, AssetError::Index(m) if m.contains("whole")),
        "{err}"
    );
    // A partial image in state 0 is refused in version 4 too.
    let missing_base_page = with_index(&bytes, |ix| {
        // Drop entry 0 (state 0's first page) and fix the count.
        ix.drain(4..4 + 36);
        let count = u32::from_le_bytes(ix[..4].try_into().unwrap()) - 1;
        ix[..4].copy_from_slice(&count.to_le_bytes());
    });
    assert!(matches!(
        AssetFile::from_bytes(missing_base_page),
        Err(AssetError::Index(_))
    ));
}

#[test]
fn header_json_uses_the_documented_field_names() {
    let (header, _, bytes) = small_asset();
    let json: Value = serde_json::from_slice(header_bytes(&bytes)).unwrap();
    let keys = |v: &Value| -> Vec<String> {
        let mut k: Vec<String> = v.as_object().unwrap().keys().cloned().collect();
        k.sort();
        k
    };
    assert_eq!(
        keys(&json),
        [
            "channels",
            "format_version",
            "frame",
            "geometry",
            "kind",
            "layers",
            "page_size",
            "provenance",
            "quality",
            "states"
        ]
    );
    assert_eq!(json["format_version"], 1);
    assert_eq!(json["kind"], "spherical");
    assert_eq!(
        json["geometry"],
        json!({"camera_level": 0, "camera_count": 12, "resolution_px": 40, "map": "parabolic"})
    );
    assert_eq!(
        json["frame"],
        json!({"center": [0.5, -1.0, 2.0], "radius": 0.75})
    );
    assert_eq!(json["page_size"], 16);
    assert_eq!(
        json["channels"],
        json!([{"name": "color", "encoding": "rgba8"}, {"name": "depth", "encoding": "r16"}])
    );
    assert_eq!(
        json["layers"],
        json!([{"name": "default", "default_opacity": 1.0}])
    );
    assert_eq!(json["states"], json!([{"name": "base", "params": {}}]));
    assert_eq!(
        keys(&json["provenance"]),
        [
            "bake_ms",
            "bake_options",
            "created_unix",
            "lumigraph_version",
            "source_name",
            "source_sha256",
            "triangles",
            "vertices"
        ]
    );
    assert_eq!(json["quality"], Value::Null);
    // The other depth encodings' spellings.
    for (encoding, name) in [(Encoding::R8, "r8"), (Encoding::R32F, "r32f")] {
        assert_eq!(serde_json::to_value(encoding).unwrap(), name);
    }
    let parsed: AssetHeader = serde_json::from_value(json).unwrap();
    assert_eq!(parsed, header);
}

#[test]
fn decoded_size_counts_every_declared_image_without_overflow() {
    // 12 cameras × 40² texels × (4 colour + 2 depth bytes), one layer, one state.
    let small = header(0, 40, 16, Encoding::R16);
    assert_eq!(small.decoded_bytes(), 12 * 40 * 40 * 6);
    // The largest header the format accepts: 642 cameras at 8192 px, 256 layers × 256 states,
    // R32F depth, about 2.2e16 bytes; it validates, so a reader must check its size first.
    let mut largest = header(3, 8192, 4096, Encoding::R32F);
    largest.layers = (0..256)
        .map(|i| LayerDesc {
            name: format!("l{i}"),
            default_opacity: 1.0,
        })
        .collect();
    largest.states = (0..256)
        .map(|i| StateDesc {
            name: format!("s{i}"),
            params: serde_json::Map::new(),
        })
        .collect();
    largest.validate().unwrap();
    assert_eq!(
        largest.decoded_bytes(),
        642 * 8192 * 8192 * 8 * 256 * 256_u64
    );
    // Fields beyond what validation allows saturate instead of wrapping to a small number.
    let Geometry::Spherical(g) = &mut largest.geometry else {
        panic!("a spherical header")
    };
    g.camera_count = u32::MAX;
    g.resolution_px = u32::MAX;
    assert_eq!(largest.decoded_bytes(), u64::MAX);
}

#[test]
fn header_constructor_and_frame() {
    let h = AssetHeader::new_spherical(2, 256, frame(), Encoding::R16, provenance()).unwrap();
    assert_eq!(h.camera_count(), 162);
    assert_eq!(h.page_size, 128);
    assert_eq!(h.encoding(Channel::Depth), Some(Encoding::R16));
    for level in [4, 255] {
        assert!(matches!(
            AssetHeader::new_spherical(level, 256, frame(), Encoding::R16, provenance()),
            Err(AssetError::Header(_))
        ));
    }
    for (resolution, depth) in [
        (0, Encoding::R16),
        (8193, Encoding::R16),
        (64, Encoding::Rgba8),
    ] {
        assert!(matches!(
            AssetHeader::new_spherical(1, resolution, frame(), depth, provenance()),
            Err(AssetError::Header(_))
        ));
    }

    let f = frame();
    let s = f.world_from_lf_scale();
    assert!((s - 0.75 * std::f64::consts::SQRT_2).abs() < 1e-15);
    let m = f.world_from_lf();
    let apply = |m: &[[f64; 4]; 4], p: [f64; 3]| -> [f64; 3] {
        std::array::from_fn(|r| m[0][r] * p[0] + m[1][r] * p[1] + m[2][r] * p[2] + m[3][r])
    };
    // The LF origin is the sphere's centre; a point at LF radius 1/√2 is on the bounding sphere.
    assert_eq!(apply(&m, [0.0; 3]), f.center);
    let on_sphere = apply(&m, [std::f64::consts::FRAC_1_SQRT_2, 0.0, 0.0]);
    assert!((on_sphere[0] - f.center[0] - f.radius).abs() < 1e-12);
    let back = apply(&f.lf_from_world(), on_sphere);
    assert!((back[0] - std::f64::consts::FRAC_1_SQRT_2).abs() < 1e-12);
}

#[test]
fn ray_ordered_layers_need_format_version_3() {
    use lumigraph_core::asset::{LAYER_ORDER_SINCE, LayerOrder};
    let mut h = AssetHeader::new_spherical(0, 16, frame(), Encoding::R16, provenance()).unwrap();
    assert_eq!(
        (h.layer_order, h.required_version()),
        (LayerOrder::Depth, 1)
    );
    // The default order is left out of the JSON, so version-1 and -2 headers stay as they were.
    let json = serde_json::to_value(&h).unwrap();
    assert!(json.get("layer_order").is_none(), "{json}");
    h.set_layer_order(LayerOrder::Ray);
    assert_eq!(h.format_version, LAYER_ORDER_SINCE);
    assert_eq!(h.validate().map_err(|e| e.to_string()), Ok(()));
    let json = serde_json::to_value(&h).unwrap();
    assert_eq!(json["layer_order"], "ray");
    assert_eq!(serde_json::from_value::<AssetHeader>(json).unwrap(), h);
    // Premultiplied colour (version 2) and ray order: still version 3; back to depth order:
    // version 2.
    h.set_color_encoding(Encoding::Rgba8Premultiplied);
    assert_eq!(h.format_version, 3);
    h.set_layer_order(LayerOrder::Depth);
    assert_eq!(h.format_version, 2);
    // A header that says ray order at version 2 is refused, naming the field.
    h.layer_order = LayerOrder::Ray;
    let msg = h.validate().unwrap_err().to_string();
    assert!(
        msg.contains("layer_order") && msg.contains("version 3"),
        "{msg}"
    );
}

#[test]
fn readers_can_be_shared_between_threads() {
    fn assert_send_sync<T: Send + Sync>() {}
    assert_send_sync::<AssetFile>();
    let (_, images, bytes) = small_asset();
    let asset = AssetFile::from_bytes(bytes).unwrap();
    std::thread::scope(|scope| {
        for chunk in images.chunks(images.len() / 2) {
            let asset = &asset;
            scope.spawn(move || {
                for (key, image) in chunk {
                    assert_eq!(&asset.read_image(*key).unwrap(), image);
                }
            });
        }
    });
}

// ---------------------------------------------------------------------------------------------
// Corruption.

#[test]
fn truncation_anywhere_is_a_typed_error() {
    let (_, _, bytes) = small_asset();
    let asset = AssetFile::from_bytes(bytes.clone()).unwrap();
    let p = raw_preamble(&bytes);
    let mut cuts = vec![0u64, 1, 7, 8, 9, 12, 16, 55, 56, 60, 63, 64, 65];
    for e in asset.index() {
        cuts.extend([e.offset, e.offset + 1, e.offset + u64::from(e.length) - 1]);
    }
    for (start, len) in [
        (p.header_offset, p.header_len),
        (p.index_offset, p.index_len),
    ] {
        cuts.extend([start - 1, start, start + 1, start + 4, start + len - 1]);
    }
    cuts.extend((0..bytes.len() as u64).step_by(97));
    cuts.retain(|&c| c < bytes.len() as u64);
    cuts.sort_unstable();
    cuts.dedup();

    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("cut.lfa");
    for cut in cuts {
        let prefix = bytes[..cut as usize].to_vec();
        std::fs::write(&path, &prefix).unwrap();
        for result in [AssetFile::from_bytes(prefix), AssetFile::open(&path)] {
            match result {
                Err(AssetError::Truncated { available, .. }) => assert_eq!(available, cut),
                other => panic!("cut at {cut}: expected Truncated, got {other:?}"),
            }
        }
    }
}

#[test]
fn every_single_byte_flip_is_detected() {
    let bytes = tiny_asset();
    assert!(bytes.len() < 32 << 10, "keep the exhaustive test fast");
    let mut seen = std::collections::BTreeMap::<String, usize>::new();
    for at in 0..bytes.len() {
        for mask in [0x01u8, 0x80, 0xFF] {
            let mut corrupt = bytes.clone();
            corrupt[at] ^= mask;
            let result = AssetFile::from_bytes(corrupt).and_then(|asset| asset.verify_all());
            let Err(err) = result else {
                panic!("flipping byte {at} with {mask:#04x} went unnoticed");
            };
            assert!(!matches!(err, AssetError::Io(_)), "byte {at}: {err:?}");
            let kind = format!("{err:?}");
            let kind = kind.split([' ', '(', '{']).next().unwrap().to_owned();
            *seen.entry(kind).or_default() += 1;
        }
    }
    // Magic, version, checksums and padding each catch some flips.
    for kind in ["BadMagic", "UnsupportedVersion", "Checksum", "Preamble"] {
        assert!(seen.contains_key(kind), "{seen:?}");
    }
}

/// Opens `bytes` (from a file, then from memory) under the allocation watchdog: the result
/// must be an error matching `expect`, and no single allocation may exceed what the data itself
/// could justify.
fn assert_rejected(name: &str, bytes: Vec<u8>, expect: Check) {
    let budget = 2 * bytes.len() + (64 << 10);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("hostile.lfa");
    std::fs::write(&path, &bytes).unwrap();
    let (from_file, largest_file) = largest_allocation(|| AssetFile::open(&path));
    let (from_bytes, largest_bytes) = largest_allocation(|| AssetFile::from_bytes(bytes));
    for (source, result, largest) in [
        ("file", from_file, largest_file),
        ("bytes", from_bytes, largest_bytes),
    ] {
        match result {
            Err(ref err) if expect(err) => {}
            other => panic!("{name} ({source}): unexpected result {other:?}"),
        }
        assert!(
            largest <= budget,
            "{name} ({source}): allocated {largest} bytes (budget {budget})"
        );
    }
}

#[test]
fn hostile_preamble_values_are_typed_errors_without_big_allocations() {
    let bytes = tiny_asset();
    let big = 1u64 << 40;
    let p = raw_preamble(&bytes);
    let cases: Vec<(&str, PreamblePatch, Check)> = vec![
        (
            "header_len max",
            Box::new(|p| p.header_len = u64::MAX),
            |e| matches!(e, AssetError::Header(_)),
        ),
        (
            "header_len 2^40",
            Box::new(move |p| p.header_len = big),
            |e| matches!(e, AssetError::Header(_)),
        ),
        (
            "header_len 16 MiB",
            Box::new(|p| p.header_len = 16 << 20),
            |e| matches!(e, AssetError::Truncated { what: "header", .. }),
        ),
        ("index_len max", Box::new(|p| p.index_len = u64::MAX), |e| {
            matches!(e, AssetError::Preamble(_))
        }),
        (
            "index_len 2^40",
            Box::new(move |p| p.index_len = big),
            |e| matches!(e, AssetError::Truncated { what: "index", .. }),
        ),
        (
            "header_offset max",
            Box::new(|p| p.header_offset = u64::MAX),
            |e| matches!(e, AssetError::Preamble(_)),
        ),
        (
            "header_offset 2^40",
            Box::new(move |p| p.header_offset = big),
            |e| matches!(e, AssetError::Truncated { .. }),
        ),
        (
            "index_offset max",
            Box::new(|p| p.index_offset = u64::MAX),
            |e| matches!(e, AssetError::Preamble(_)),
        ),
        (
            "index_offset 2^40",
            Box::new(move |p| p.index_offset = big),
            |e| matches!(e, AssetError::Truncated { .. }),
        ),
        (
            "header in preamble",
            Box::new(|p| p.header_offset = 0),
            |e| matches!(e, AssetError::Preamble(_)),
        ),
        (
            "index in preamble",
            Box::new(|p| p.index_offset = 63),
            |e| matches!(e, AssetError::Preamble(_)),
        ),
        (
            "header overlaps index",
            Box::new(move |p| p.header_offset = p.index_offset - 1),
            |e| matches!(e, AssetError::Preamble(_) | AssetError::Truncated { .. }),
        ),
        (
            "index overlaps header",
            Box::new(move |p| p.index_offset = p.header_offset),
            |e| matches!(e, AssetError::Preamble(_)),
        ),
        (
            "index one byte short",
            Box::new(|p| p.index_len -= 1),
            |e| matches!(e, AssetError::Preamble(_)),
        ),
        ("flags", Box::new(|p| p.flags = 1), |e| {
            matches!(e, AssetError::Preamble(_))
        }),
        ("version 7", Box::new(|p| p.version = 7), |e| {
            matches!(
                e,
                AssetError::UnsupportedVersion {
                    found: 7,
                    supported: 6
                }
            )
        }),
        // A version this reader knows, but not the one the header was written as.
        (
            "version 2 preamble, version 1 header",
            Box::new(|p| p.version = 2),
            |e| matches!(e, AssetError::Header(m) if m.contains("header says format version 1")),
        ),
        ("version 0", Box::new(|p| p.version = 0), |e| {
            matches!(e, AssetError::UnsupportedVersion { found: 0, .. })
        }),
    ];
    assert!(p.index_offset > p.header_offset);
    for (name, patch, expect) in cases {
        assert_rejected(name, patch_preamble(&bytes, patch), expect);
    }

    // Bytes after the last section.
    let mut appended = bytes.clone();
    appended.extend_from_slice(b"extra");
    assert_rejected("appended bytes", appended, |e| {
        matches!(e, AssetError::Preamble(_))
    });
    // Padding is outside the checksum but must be zero.
    let mut padded = bytes.clone();
    padded[63] = 1;
    assert_rejected("padding", padded, |e| matches!(e, AssetError::Preamble(_)));
    // A corrupted preamble field without a fixed checksum.
    let mut flipped = bytes.clone();
    flipped[20] ^= 0x10;
    assert_rejected("preamble crc", flipped, |e| {
        matches!(e, AssetError::Checksum { .. })
    });
    // Not an asset at all; and shorter than the magic.
    assert_rejected("text", b"hello, world\n".to_vec(), |e| {
        matches!(e, AssetError::BadMagic)
    });
    assert_rejected("empty", Vec::new(), |e| {
        matches!(e, AssetError::Truncated { .. })
    });
    assert_rejected("magic only", bytes[..8].to_vec(), |e| {
        matches!(e, AssetError::Truncated { .. })
    });
}

#[test]
fn hostile_index_values_are_typed_errors_without_big_allocations() {
    let bytes = tiny_asset();
    let asset = AssetFile::from_bytes(bytes.clone()).unwrap();
    let p = raw_preamble(&bytes);
    let index_err = |e: &AssetError| matches!(e, AssetError::Index(_));
    let put32 = |at: usize, v: u32| {
        move |ix: &mut Vec<u8>| ix[at..at + 4].copy_from_slice(&v.to_le_bytes())
    };
    let put64 = |at: usize, v: u64| {
        move |ix: &mut Vec<u8>| ix[at..at + 8].copy_from_slice(&v.to_le_bytes())
    };

    assert_rejected(
        "count max",
        with_index(&bytes, put32(0, u32::MAX)),
        index_err,
    );
    assert_rejected("count +1", with_index(&bytes, put32(0, 25)), index_err);
    assert_rejected(
        "empty index",
        with_index(&bytes, |ix| ix.truncate(4)),
        index_err,
    );
    assert_rejected("no count", with_index(&bytes, Vec::clear), index_err);
    assert_rejected(
        "partial entry",
        with_index(&bytes, |ix| {
            ix.pop();
        }),
        index_err,
    );
    assert_rejected(
        "count 0",
        with_index(&bytes, |ix| {
            ix.truncate(4);
            ix[..4].copy_from_slice(&0u32.to_le_bytes());
        }),
        index_err,
    );
    assert_rejected(
        "raw_length max",
        with_index(&bytes, put32(entry_field(0, 28), u32::MAX)),
        index_err,
    );
    assert_rejected(
        "length max",
        with_index(&bytes, put32(entry_field(1, 24), u32::MAX)),
        index_err,
    );
    assert_rejected(
        "length 0",
        with_index(&bytes, put32(entry_field(1, 24), 0)),
        index_err,
    );
    assert_rejected(
        "offset max",
        with_index(&bytes, put64(entry_field(2, 16), u64::MAX)),
        index_err,
    );
    assert_rejected(
        "offset 2^40",
        with_index(&bytes, put64(entry_field(2, 16), 1 << 40)),
        index_err,
    );
    assert_rejected(
        "offset in preamble",
        with_index(&bytes, put64(entry_field(2, 16), 10)),
        index_err,
    );
    assert_rejected(
        "offset in header",
        with_index(&bytes, put64(entry_field(2, 16), p.header_offset)),
        index_err,
    );
    assert_rejected(
        "page 1",
        with_index(&bytes, put32(entry_field(0, 12), 1)),
        index_err,
    );
    assert_rejected(
        "page max",
        with_index(&bytes, put32(entry_field(0, 12), u32::MAX)),
        index_err,
    );
    assert_rejected(
        "camera 12",
        with_index(&bytes, put32(entry_field(0, 4), 12)),
        index_err,
    );
    assert_rejected(
        "layer 1",
        with_index(&bytes, |ix| ix[entry_field(23, 0)] = 1),
        index_err,
    );
    assert_rejected(
        "state 1",
        with_index(&bytes, |ix| ix[entry_field(23, 2)] = 1),
        index_err,
    );
    assert_rejected(
        "channel 2",
        with_index(&bytes, |ix| ix[entry_field(0, 8)] = 2),
        index_err,
    );
    assert_rejected(
        "codec 2",
        with_index(&bytes, |ix| ix[entry_field(0, 9)] = 2),
        index_err,
    );
    assert_rejected(
        "reserved",
        with_index(&bytes, |ix| ix[entry_field(0, 10)] = 1),
        index_err,
    );
    // A raw page whose codec says zstd (length < raw_length is plausible for zstd, but here
    // the entry becomes a raw page with the wrong length).
    let raw_entry = asset
        .index()
        .iter()
        .position(|e| e.codec == Codec::Zstd)
        .unwrap();
    assert_rejected(
        "zstd page marked raw",
        with_index(&bytes, |ix| ix[entry_field(raw_entry, 9)] = 0),
        index_err,
    );
    assert_rejected(
        "duplicate entry",
        with_index(&bytes, |ix| {
            let first = ix[4..40].to_vec();
            ix[40..76].copy_from_slice(&first);
        }),
        index_err,
    );
    assert_rejected(
        "swapped entries",
        with_index(&bytes, |ix| {
            let (a, b) = (ix[4..40].to_vec(), ix[40..76].to_vec());
            ix[4..40].copy_from_slice(&b);
            ix[40..76].copy_from_slice(&a);
        }),
        index_err,
    );
    // Dropping an image of state 0 leaves the base state incomplete.
    assert_rejected(
        "base state incomplete",
        with_index(&bytes, |ix| {
            ix.truncate(ix.len() - 36);
            ix[..4].copy_from_slice(&23u32.to_le_bytes());
        }),
        index_err,
    );
}

#[test]
fn hostile_header_values_are_typed_errors() {
    let bytes = tiny_asset();
    let header_err = |e: &AssetError| matches!(e, AssetError::Header(_));
    let edits: Vec<(&str, HeaderEdit)> = vec![
        (
            "resolution 10^6",
            Box::new(|h| h["geometry"]["resolution_px"] = json!(1_000_000)),
        ),
        (
            "resolution 0",
            Box::new(|h| h["geometry"]["resolution_px"] = json!(0)),
        ),
        (
            "resolution -1",
            Box::new(|h| h["geometry"]["resolution_px"] = json!(-1)),
        ),
        (
            "resolution 2^40",
            Box::new(|h| h["geometry"]["resolution_px"] = json!(1u64 << 40)),
        ),
        (
            "camera_count mismatch",
            Box::new(|h| h["geometry"]["camera_count"] = json!(42)),
        ),
        (
            "camera_level 4",
            Box::new(|h| {
                h["geometry"]["camera_level"] = json!(4);
                h["geometry"]["camera_count"] = json!(2562);
            }),
        ),
        (
            "map",
            Box::new(|h| h["geometry"]["map"] = json!("equirect")),
        ),
        ("kind", Box::new(|h| h["kind"] = json!("two_plane"))),
        (
            "format_version",
            Box::new(|h| h["format_version"] = json!(2)),
        ),
        ("page_size 24", Box::new(|h| h["page_size"] = json!(24))),
        ("page_size 0", Box::new(|h| h["page_size"] = json!(0))),
        ("page_size 8192", Box::new(|h| h["page_size"] = json!(8192))),
        ("page_size 8", Box::new(|h| h["page_size"] = json!(8))),
        (
            "no depth",
            Box::new(|h| h["channels"] = json!([{"name": "color", "encoding": "rgba8"}])),
        ),
        (
            "two colors",
            Box::new(|h| {
                let color = json!({"name": "color", "encoding": "rgba8"});
                h["channels"] = json!([color.clone(), color]);
            }),
        ),
        (
            "r16 colour",
            Box::new(|h| h["channels"][0]["encoding"] = json!("r16")),
        ),
        (
            "rgba8 depth",
            Box::new(|h| h["channels"][1]["encoding"] = json!("rgba8")),
        ),
        (
            "bc7 colour",
            Box::new(|h| h["channels"][0]["encoding"] = json!("bc7")),
        ),
        ("no layers", Box::new(|h| h["layers"] = json!([]))),
        (
            "257 layers",
            Box::new(|h| {
                h["layers"] = Value::Array(
                    (0..257)
                        .map(|i| json!({"name": format!("l{i}"), "default_opacity": 1.0}))
                        .collect(),
                );
            }),
        ),
        (
            "duplicate layer names",
            Box::new(|h| {
                let layer = json!({"name": "a", "default_opacity": 1.0});
                h["layers"] = json!([layer.clone(), layer]);
            }),
        ),
        (
            "empty layer name",
            Box::new(|h| h["layers"][0]["name"] = json!("")),
        ),
        (
            "opacity 2",
            Box::new(|h| h["layers"][0]["default_opacity"] = json!(2.0)),
        ),
        (
            "opacity -0.5",
            Box::new(|h| h["layers"][0]["default_opacity"] = json!(-0.5)),
        ),
        // Ray-ordered layers are a version-3 field; a version-1 header cannot say it.
        (
            "layer_order ray in version 1",
            Box::new(|h| h["layer_order"] = json!("ray")),
        ),
        (
            "layer_order unknown",
            Box::new(|h| h["layer_order"] = json!("random")),
        ),
        ("no states", Box::new(|h| h["states"] = json!([]))),
        ("radius 0", Box::new(|h| h["frame"]["radius"] = json!(0.0))),
        (
            "radius -1",
            Box::new(|h| h["frame"]["radius"] = json!(-1.0)),
        ),
        (
            "radius huge",
            Box::new(|h| h["frame"]["radius"] = json!(f64::MAX)),
        ),
        (
            "centre null",
            Box::new(|h| h["frame"]["center"] = json!([0.0, null, 0.0])),
        ),
        ("unknown field", Box::new(|h| h["extra"] = json!(1))),
        (
            "unknown nested field",
            Box::new(|h| h["geometry"]["extra"] = json!(1)),
        ),
        (
            "missing field",
            Box::new(|h| {
                h.as_object_mut().unwrap().remove("frame");
            }),
        ),
        (
            "bake_ms negative",
            Box::new(|h| h["provenance"]["bake_ms"] = json!(-1.0)),
        ),
        ("not an object", Box::new(|h| *h = json!([1, 2, 3]))),
    ];
    for (name, edit) in edits {
        let hostile = with_header_json(&bytes, |h| edit(h));
        assert_rejected(name, hostile, header_err);
    }
    // Not JSON at all, and JSON nested far deeper than serde_json's recursion limit.
    let index = index_bytes(&bytes).to_vec();
    assert_rejected("garbage", rebuild(&bytes, b"\x00\xff{", &index), header_err);
    let mut deep = header_bytes(&bytes).to_vec();
    deep.truncate(deep.len() - 1);
    deep.extend_from_slice(b",\"x\":");
    deep.extend(std::iter::repeat_n(b'[', 100_000));
    assert_rejected("deep nesting", rebuild(&bytes, &deep, &index), header_err);
}

#[test]
fn hostile_page_data_is_a_typed_error_on_read() {
    let bytes = tiny_asset();
    let asset = AssetFile::from_bytes(bytes.clone()).unwrap();
    // Take a raw (random) colour page: 16 × 16 × 4 = 1024 stored bytes.
    let at = asset
        .index()
        .iter()
        .position(|e| e.codec == Codec::Raw && e.key.channel == Channel::Color)
        .unwrap();
    let entry = asset.index()[at];
    assert_eq!(entry.raw_length, 1024);

    // Replace it with a valid zstd frame that decodes to far more than the page holds, fix the
    // checksum and mark it zstd: the index is plausible, the read must fail without allocating
    // the frame's claimed size.
    let bomb = zstd::bulk::compress(&vec![0u8; 8 << 20], 19).unwrap();
    assert!(bomb.len() < 1024);
    let mut hostile = bytes.clone();
    let start = entry.offset as usize;
    hostile[start..start + bomb.len()].copy_from_slice(&bomb);
    let hostile = with_index(&hostile, |ix| {
        ix[entry_field(at, 9)] = 1;
        ix[entry_field(at, 24)..entry_field(at, 28)]
            .copy_from_slice(&(bomb.len() as u32).to_le_bytes());
        ix[entry_field(at, 32)..entry_field(at, 36)]
            .copy_from_slice(&crc32fast::hash(&bomb).to_le_bytes());
    });
    let asset = AssetFile::from_bytes(hostile).unwrap();
    let (result, largest) = largest_allocation(|| asset.read_image(entry.key));
    assert!(
        matches!(result, Err(AssetError::Decompress { page: 0, .. })),
        "{result:?}"
    );
    assert!(
        largest < 1 << 20,
        "allocated {largest} bytes for a 1 KiB page"
    );
    assert!(asset.verify_all().is_err());

    // A frame that decodes to too few bytes.
    let short = zstd::bulk::compress(&[7u8; 100], 3).unwrap();
    let mut hostile = bytes.clone();
    hostile[start..start + short.len()].copy_from_slice(&short);
    let hostile = with_index(&hostile, |ix| {
        ix[entry_field(at, 9)] = 1;
        ix[entry_field(at, 24)..entry_field(at, 28)]
            .copy_from_slice(&(short.len() as u32).to_le_bytes());
        ix[entry_field(at, 32)..entry_field(at, 36)]
            .copy_from_slice(&crc32fast::hash(&short).to_le_bytes());
    });
    let asset = AssetFile::from_bytes(hostile).unwrap();
    assert!(matches!(
        asset.read_page(entry.key, 0),
        Err(AssetError::Page { page: 0, .. })
    ));

    // A flipped page byte: caught by the page checksum, naming the page.
    let mut flipped = bytes.clone();
    flipped[start + 5] ^= 1;
    let asset = AssetFile::from_bytes(flipped).unwrap();
    match asset.read_image(entry.key) {
        Err(AssetError::Checksum { what }) => assert!(what.contains("page 0 of layer 0"), "{what}"),
        other => panic!("{other:?}"),
    }
}

#[test]
fn error_messages_say_what_is_wrong() {
    let bytes = tiny_asset();
    let v7 = patch_preamble(&bytes, |p| p.version = 7);
    let msg = AssetFile::from_bytes(v7).unwrap_err().to_string();
    assert!(
        msg.contains("version 7") && msg.contains("reads versions 1 to 6"),
        "{msg}"
    );
    let msg = AssetFile::from_bytes(b"GIF89a".to_vec())
        .unwrap_err()
        .to_string();
    assert!(msg.contains("not a lumigraph light-field asset"), "{msg}");
    let msg = AssetFile::from_bytes(bytes[..100].to_vec())
        .unwrap_err()
        .to_string();
    assert!(msg.contains("truncated") && msg.contains("100"), "{msg}");
    let hostile = with_header_json(&bytes, |h| h["geometry"]["camera_count"] = json!(42));
    let msg = AssetFile::from_bytes(hostile).unwrap_err().to_string();
    assert!(
        msg.contains("camera_count 42") && msg.contains("12 cameras"),
        "{msg}"
    );
}

// ---------------------------------------------------------------------------------------------
// Atomic writes.

#[test]
fn failed_or_abandoned_writers_leave_nothing_behind() {
    let header = header(0, 16, 16, Encoding::R16);
    let images = images_for(&header, &base_keys(&header), 4);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("out.lfa");

    // A wrong length is refused without side effects; dropping the writer removes the temp file.
    let mut writer = AssetWriter::create(&path, header.clone()).unwrap();
    assert_eq!(
        files_in(dir.path()).len(),
        1,
        "the temp file exists while writing"
    );
    let (key, bytes) = &images[0];
    assert!(matches!(
        writer.add_image(*key, &bytes[1..]),
        Err(AssetError::ImageSize {
            expected: 1024,
            actual: 1023,
            ..
        })
    ));
    writer.add_image(*key, bytes).unwrap();
    assert!(matches!(
        writer.add_image(*key, bytes),
        Err(AssetError::DuplicateImage { .. })
    ));
    assert!(matches!(
        writer.add_image(ImageKey::new(0, 1, 0, Channel::Color), bytes),
        Err(AssetError::KeyOutOfRange { .. })
    ));
    drop(writer);
    assert!(files_in(dir.path()).is_empty());

    // Finishing with an incomplete base state fails and cleans up.
    let mut writer = AssetWriter::create(&path, header.clone()).unwrap();
    for (key, bytes) in &images[..images.len() - 1] {
        writer.add_image(*key, bytes).unwrap();
    }
    let missing = images.last().unwrap().0;
    assert!(matches!(
        writer.finish(),
        Err(AssetError::IncompleteBaseState { missing: m }) if m == missing
    ));
    assert!(files_in(dir.path()).is_empty());

    // An invalid header creates nothing at all.
    let mut bad = header.clone();
    let Geometry::Spherical(g) = &mut bad.geometry else {
        panic!("a spherical header")
    };
    g.camera_count = 13;
    assert!(matches!(
        AssetWriter::create(&path, bad.clone()),
        Err(AssetError::Header(_))
    ));
    assert!(matches!(
        write_asset(&path, bad, images.clone()),
        Err(AssetError::Header(_))
    ));
    assert!(files_in(dir.path()).is_empty());

    // write_asset over an existing file: a bad image leaves the old file untouched.
    std::fs::write(&path, b"previous").unwrap();
    let mut broken = images.clone();
    broken[5].1.pop();
    assert!(matches!(
        write_asset(&path, header.clone(), broken),
        Err(AssetError::ImageSize { .. })
    ));
    assert_eq!(std::fs::read(&path).unwrap(), b"previous");
    assert_eq!(files_in(dir.path()), ["out.lfa"]);

    // And a good write replaces it.
    write_asset(&path, header.clone(), images.clone()).unwrap();
    assert_eq!(files_in(dir.path()), ["out.lfa"]);
    AssetFile::open(&path).unwrap().verify_all().unwrap();
}

#[test]
fn large_images_compress_in_parallel_and_round_trip() {
    // 512 px RGBA8 = 1 MiB per colour image: above the parallel threshold.
    let header = header(0, 520, 128, Encoding::R16);
    let images = images_for(&header, &base_keys(&header), 5);
    let bytes = encode_asset(header.clone(), images.clone()).unwrap();
    let asset = AssetFile::from_bytes(bytes).unwrap();
    assert_eq!(asset.header().page_grid().unwrap().page_count(), 25);
    for (key, image) in images.iter().step_by(5) {
        assert_eq!(&asset.read_image(*key).unwrap(), image);
    }
}

// ---------------------------------------------------------------------------------------------
// Property-based round trip.

proptest! {
    #![proptest_config(ProptestConfig { cases: 24, ..ProptestConfig::default() })]

    #[test]
    fn prop_round_trip(
        level in 0u8..=1,
        resolution in 1u32..=48,
        page_size in prop::sample::select(vec![16u32, 32]),
        depth in prop::sample::select(vec![Encoding::R16, Encoding::R8, Encoding::R32F]),
        layers in 1usize..=2,
        states in 1usize..=3,
        omit_mask in any::<u64>(),
        salt in any::<u64>(),
    ) {
        let mut header = header(level, resolution, page_size, depth);
        header.layers = (0..layers)
            .map(|i| LayerDesc { name: format!("layer{i}"), default_opacity: 1.0 / (i + 1) as f32 })
            .collect();
        header.states = (0..states)
            .map(|i| StateDesc { name: format!("state{i}"), params: serde_json::Map::new() })
            .collect();
        let mut keys = base_keys(&header);
        for key in base_keys(&header) {
            for state in 1..states as u16 {
                let bit = (u64::from(key.camera) * 2 + u64::from(state)) % 64;
                if omit_mask >> bit & 1 == 0 {
                    keys.push(ImageKey { state, ..key });
                }
            }
        }
        let images = images_for(&header, &keys, salt);
        let bytes = encode_asset(header.clone(), images.clone()).unwrap();
        let asset = AssetFile::from_bytes(bytes).unwrap();
        prop_assert_eq!(asset.header(), &header);
        asset.verify_all().unwrap();
        let stored: std::collections::HashMap<_, _> = images.into_iter().collect();
        for key in &keys {
            prop_assert_eq!(&asset.read_image(*key).unwrap(), &stored[key]);
        }
        for key in base_keys(&header) {
            for state in 1..states as u16 {
                let key = ImageKey { state, ..key };
                let owner = if stored.contains_key(&key) { key } else { key.in_base_state() };
                prop_assert_eq!(&asset.read_image(key).unwrap(), &stored[&owner]);
            }
        }
    }
}

/// A two-plane asset (format version 5): a 3 × 2 uv grid of 40 × 24 px images in 16 px pages
/// (3 × 2 pages, the last column 8 px wide and the last row 8 px high) round-trips bit for bit,
/// page by page and image by image; its header's kind, geometry, version and encodings must
/// agree.
#[test]
fn two_plane_assets_round_trip_with_rectangular_images() {
    let planes = lumigraph_core::two_plane::TwoPlanes::from_json(
        r#"{"right": [1, 0, 0], "up": [0, 1, 0],
            "uv": {"center": [0, 0, 2], "size": [1, 0.5], "grid": [3, 2]},
            "st": {"center": [0, 0, 0], "size": [2, 1.2], "resolution": [40, 24]}}"#,
    )
    .unwrap();
    let mut header = AssetHeader::new_two_plane(planes, 16, Provenance::default()).unwrap();
    header.provenance.lumigraph_version = "test".to_owned();
    assert_eq!(header.format_version, 5);
    assert_eq!(header.required_version(), 5);
    assert_eq!(header.camera_count(), 6);
    assert_eq!(header.image_size(), [40, 24]);
    assert_eq!(header.camera_level(), None);
    assert!(matches!(
        header.spherical("a test"),
        Err(AssetError::Kind { what: "a test", .. })
    ));
    let grid = header.page_grid().unwrap();
    assert_eq!((grid.pages_per_row(), grid.page_count()), (3, 6));
    let last = grid.page_rect(5).unwrap();
    assert_eq!((last.x, last.y, last.width, last.height), (32, 16, 8, 8));
    // The frame is the corners' bounding sphere: centre halfway between the planes.
    assert!((header.frame.center[2] - 1.0).abs() < 1e-12);
    assert_eq!(header.decoded_bytes(), 6 * 40 * 24 * 8);

    let images = images_for(&header, &base_keys(&header), 5);
    let bytes = encode_asset(header.clone(), images.clone()).unwrap();
    assert_eq!(raw_preamble(&bytes).version, 5);
    let asset = AssetFile::from_bytes(bytes).unwrap();
    assert_eq!(asset.header(), &header);
    asset.verify_all().unwrap();
    for (key, want) in &images {
        assert_eq!(&asset.read_image(*key).unwrap(), want, "{key}");
    }

    // A kind that does not match the geometry, a version below 5, other encodings.
    let mut bad = header.clone();
    bad.kind = lumigraph_core::asset::AssetKind::Spherical;
    assert!(matches!(bad.validate(), Err(AssetError::Header(m)) if m.contains("does not match")));
    let mut bad = header.clone();
    bad.format_version = 4;
    assert!(matches!(bad.validate(), Err(AssetError::Header(m)) if m.contains("version 5")));
    let mut bad = header.clone();
    bad.channels[1].encoding = Encoding::R16;
    assert!(matches!(bad.validate(), Err(AssetError::Header(m)) if m.contains("r32f")));
    // Invalid planes inside an otherwise valid header.
    let mut bad = header.clone();
    let Geometry::TwoPlane(g) = &mut bad.geometry else {
        panic!("two-plane")
    };
    g.planes.uv.grid = [0, 2];
    assert!(matches!(bad.validate(), Err(AssetError::Header(m)) if m.contains("uv grid")));
    // The JSON header of a spherical asset still parses as spherical, and a two-plane header
    // whose planes have an unknown field is refused.
    let text = serde_json::to_string(&header).unwrap();
    assert!(text.contains("\"two_plane\"") && text.contains("\"planes\""));
    let broken = text.replace("\"grid\"", "\"grid\": [3, 2], \"cells\"");
    assert!(serde_json::from_str::<AssetHeader>(&broken).is_err());
}

// Block compression (format version 6).

/// A map-like image: a gradient inside a disc (A = 255, depth codes of a ramp), empty outside,
/// with an edge texel (A = 77) that the colour codecs drop.
fn map_images(header: &AssetHeader) -> Images {
    let [w, h] = header.image_size();
    base_keys(header)
        .into_iter()
        .map(|key| {
            let mut bytes = Vec::new();
            for i in 0..h {
                for j in 0..w {
                    let (x, y) = (
                        f64::from(j) / f64::from(w) - 0.5,
                        f64::from(i) / f64::from(h) - 0.5,
                    );
                    let inside = x * x + y * y < 0.15;
                    match key.channel {
                        Channel::Color if inside => bytes.extend([
                            (120.0 + 200.0 * x) as u8,
                            (90.0 + 150.0 * y) as u8,
                            (key.camera * 10) as u8,
                            255,
                        ]),
                        Channel::Color if i == 0 && j == 0 => bytes.extend([9, 9, 0, 77]),
                        Channel::Color => bytes.extend([0, 0, 0, 0]),
                        _ if inside => bytes.push((100 + (i + j) / 4) as u8),
                        _ => bytes.push(255),
                    }
                }
            }
            (key, bytes)
        })
        .collect()
}

/// BC7 colour and BC4 depth: version 6, pages of blocks (raw_length = blocks' bytes), and
/// `read_image` / `read_page` decode them to the channel's encoding: colour within 12 codes
/// (BC7 at the fastest setting, worst in blocks cut by the silhouette) and 1.5 on average,
/// coverage exact, the edge texel dropped;
/// depth codes within 2 (BC4 end points and 3-bit indices over ramps of ≤ 8 codes per block,
/// blocks of one value exact) and 255 ("no hit") kept exactly wherever a block holds only it.
/// `read_image_blocks` gives the blocks in the GPU copy layout.
#[test]
fn block_compressed_pages_round_trip_to_texels() {
    let mut header = header(0, 48, 16, Encoding::R8);
    header
        .set_compression(Channel::Color, Some(BlockCodec::Bc7))
        .unwrap();
    header
        .set_compression(Channel::Depth, Some(BlockCodec::Bc4))
        .unwrap();
    assert_eq!(header.format_version, BLOCK_COMPRESSION_SINCE);
    let images = map_images(&header);
    let bytes = encode_asset(header.clone(), images.clone()).unwrap();
    let asset = AssetFile::from_bytes(bytes).unwrap();
    assert_eq!(asset.header(), &header);
    asset.verify_all().unwrap();
    assert_eq!(asset.compression(Channel::Color), Some(BlockCodec::Bc7));
    for entry in asset.index() {
        // 16 blocks per 16 × 16 page: 16 bytes each (BC7), 8 (BC4).
        let expected = if entry.key.channel == Channel::Color {
            16 * 16
        } else {
            16 * 8
        };
        assert_eq!(entry.raw_length, expected, "{}", entry.key);
    }
    for (key, original) in &images {
        let back = asset.read_image(*key).unwrap();
        assert_eq!(back.len(), original.len());
        if key.channel == Channel::Color {
            let mut total = 0u64;
            for (a, b) in original.chunks_exact(4).zip(back.chunks_exact(4)) {
                if a[3] == 255 {
                    assert_eq!(b[3], 255);
                    assert!((0..3).all(|k| a[k].abs_diff(b[k]) <= 12), "{a:?} → {b:?}");
                    total += (0..3).map(|k| u64::from(a[k].abs_diff(b[k]))).sum::<u64>();
                } else {
                    assert_eq!(b, [0, 0, 0, 0], "{a:?}");
                }
            }
            assert!(
                total as f64 / (3.0 * 48.0 * 48.0) < 1.5,
                "mean error {total}"
            );
        } else {
            for (a, b) in original.iter().zip(&back) {
                assert!(a.abs_diff(*b) <= 2, "{a} → {b}");
            }
        }
        // A page reads as its rectangle of the image.
        let page = asset.read_page(*key, 4).unwrap();
        let bpp = if key.channel == Channel::Color { 4 } else { 1 };
        let row = 16 * bpp;
        for r in 0..16 {
            let start = ((16 + r) * 48 + 16) * bpp;
            assert_eq!(&page[r * row..(r + 1) * row], &back[start..start + row]);
        }
        let blocks = asset.read_image_blocks(*key).unwrap();
        let block_bytes = if key.channel == Channel::Color { 16 } else { 8 };
        assert_eq!(blocks.len(), 12 * 12 * block_bytes);
    }
    // Depth blocks wholly outside the disc stay exactly "no hit".
    let depth = asset
        .read_image(ImageKey::new(0, 0, 0, Channel::Depth))
        .unwrap();
    assert!(depth[..4].iter().all(|&d| d == 255));
}

#[test]
fn block_compression_that_does_not_fit_is_refused() {
    let mut h = header(0, 48, 16, Encoding::R16);
    let before = h.clone();
    // BC4 compresses 8-bit depth only; BC1 keeps no partial alpha.
    assert!(
        h.set_compression(Channel::Depth, Some(BlockCodec::Bc4))
            .is_err()
    );
    assert!(
        h.set_compression(Channel::Depth, Some(BlockCodec::Bc7))
            .is_err()
    );
    assert_eq!(h, before, "unchanged on error");
    h.set_color_encoding(Encoding::Rgba8Premultiplied);
    assert!(
        h.set_compression(Channel::Color, Some(BlockCodec::Bc1))
            .is_err()
    );
    h.set_compression(Channel::Color, Some(BlockCodec::Bc7))
        .unwrap();
    assert_eq!(h.format_version, BLOCK_COMPRESSION_SINCE);
    // Maps that are not whole 4 × 4 blocks.
    let mut odd = header(0, 42, 16, Encoding::R16);
    let err = odd
        .set_compression(Channel::Color, Some(BlockCodec::Bc1))
        .unwrap_err()
        .to_string();
    assert!(err.contains("whole 4x4 blocks"), "{err}");
    assert_eq!(odd.format_version, 1, "unchanged on error");
    // A version-5 header that names a compression is refused at open.
    let mut bc = header(0, 48, 16, Encoding::R16);
    bc.set_compression(Channel::Color, Some(BlockCodec::Bc1))
        .unwrap();
    let bytes = encode_asset(
        bc.clone(),
        map_images(&header(0, 48, 16, Encoding::R16))
            .into_iter()
            .map(|(k, v)| {
                (
                    k,
                    if k.channel == Channel::Depth {
                        v.iter().flat_map(|&d| [d, 0]).collect::<Vec<u8>>()
                    } else {
                        v
                    },
                )
            })
            .collect::<Images>(),
    )
    .unwrap();
    AssetFile::from_bytes(bytes.clone()).unwrap();
    let old = patch_preamble(
        &with_header_json(&bytes, |v| v["format_version"] = json!(5)),
        |p| p.version = 5,
    );
    let err = AssetFile::from_bytes(old).unwrap_err().to_string();
    assert!(err.contains("needs format version 6"), "{err}");
    let unknown = with_header_json(&bytes, |v| v["channels"][0]["compression"] = json!("dxt5"));
    assert!(AssetFile::from_bytes(unknown).is_err());
}
