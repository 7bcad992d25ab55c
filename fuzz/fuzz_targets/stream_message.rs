//! `/v1/stream` client text messages (view, settings, ack) through the checks a session makes,
//! settings merged into the defaults and validated against a 162-camera asset's header.
#![no_main]

use std::sync::LazyLock;

use libfuzzer_sys::fuzz_target;
use lumigraph_core::asset::{AssetHeader, Encoding, LfFrame, Provenance};
use lumigraph_server::service::stream::check_client_message;

static HEADER: LazyLock<AssetHeader> = LazyLock::new(|| {
    let frame = LfFrame {
        center: [0.0; 3],
        radius: 1.0,
    };
    AssetHeader::new_spherical(2, 64, frame, Encoding::R16, Provenance::default())
        .expect("a valid 162-camera header")
});

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let _ = check_client_message(text, &HEADER, 4096);
});
