//! View JSON (one view or a list of views, as `--views` files and camera traces hold) and the
//! view basis every render builds from it.
#![no_main]

use libfuzzer_sys::fuzz_target;
use lumigraph_core::view::View;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok(views) = View::parse_many(text) {
        for view in views {
            let _ = view.basis(4096);
        }
    }
});
