//! The OBJ mesh loader on arbitrary bytes, as a bake upload meets it (nothing is read from
//! the file system), through the validation every loaded mesh gets.
#![no_main]

use libfuzzer_sys::fuzz_target;
use lumigraph_core::mesh::{MeshFormat, load_mesh_from_bytes};

fuzz_target!(|data: &[u8]| {
    let _ = load_mesh_from_bytes(data, MeshFormat::Obj);
});
