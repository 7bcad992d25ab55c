//! `POST /v1/assets/{id}/render` bodies through every check made before the asset's plan.
#![no_main]

use libfuzzer_sys::fuzz_target;
use lumigraph_server::service::http::RenderBody;

fuzz_target!(|data: &[u8]| {
    let _ = RenderBody::parse(data, 4096);
});
