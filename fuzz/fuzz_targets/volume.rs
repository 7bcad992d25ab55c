//! The volume readers on arbitrary bytes, as an upload meets them (no file system: detached
//! data files are refused). The first byte picks the format by file name; the rest is the file.
#![no_main]

use libfuzzer_sys::fuzz_target;
use lumigraph_core::volume::{LoadOptions, Volume};

const NAMES: [&str; 8] = [
    "v.nii", "v.nii.gz", "v.npy", "v.mha", "v.nrrd", "v.inr", "v.inr.gz", "v.vti",
];

fuzz_target!(|data: &[u8]| {
    let Some((&pick, file)) = data.split_first() else {
        return;
    };
    let name = NAMES[usize::from(pick) % NAMES.len()];
    let labels = pick >= 128;
    let _ = Volume::from_bytes(
        name,
        file,
        &LoadOptions {
            labels,
            spacing: None,
        },
    );
});
