//! The `.lfa` reader on arbitrary bytes, as an upload meets it: parse and validate preamble,
//! header and index; then, for an asset whose decoded size the service would admit, verify
//! every page and decode every image. Checksums are not compared in fuzz builds
//! (`crc_matches`), so mutations reach the parsing behind them.
#![no_main]

use libfuzzer_sys::fuzz_target;
use lumigraph_core::asset::AssetFile;

/// Decoded bytes above which the target stops after validation, as the service refuses such
/// an upload before reading its pages (`--max-asset-decoded-bytes`); kept far below
/// libFuzzer's 2 GiB allocation limit so that a real over-allocation still reports.
const DECODE_LIMIT: u64 = 64 << 20;

fuzz_target!(|data: &[u8]| {
    let Ok(file) = AssetFile::from_bytes(data.to_vec()) else {
        return;
    };
    let header = file.header();
    let _ = header.validate();
    if header.decoded_bytes() > DECODE_LIMIT {
        return;
    }
    if file.verify_all().is_err() {
        return;
    }
    let keys: Vec<_> = file.index().iter().map(|entry| entry.key).collect();
    for key in keys {
        let _ = file.read_image(key);
    }
});
