//! Scene JSON (docs/scene.md) through every check that needs no file and no device.
#![no_main]

use libfuzzer_sys::fuzz_target;
use lumigraph_core::scene::SceneFile;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let _ = SceneFile::parse(text);
});
