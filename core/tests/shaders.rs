//! Every WGSL module parses and validates with naga on the CPU, so a broken shader fails CI
//! without any GPU or driver.

#[test]
fn every_shader_validates_with_naga() {
    for (name, source) in lumigraph_core::shaders::all() {
        let source = source.as_str();
        let module = naga::front::wgsl::parse_str(source).unwrap_or_else(|e| {
            panic!("{name}.wgsl does not parse:\n{}", e.emit_to_string(source))
        });
        let mut validator = naga::valid::Validator::new(
            naga::valid::ValidationFlags::all(),
            naga::valid::Capabilities::all(),
        );
        validator.validate(&module).unwrap_or_else(|e| {
            panic!(
                "{name}.wgsl does not validate:\n{}",
                e.emit_to_string(source)
            )
        });
    }
}

#[test]
fn every_shader_file_is_embedded() {
    // A new .wgsl file must be added to `shaders::all()` (or be shared code included by one).
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../shaders");
    for entry in std::fs::read_dir(&dir).expect("shaders dir") {
        let path = entry.expect("entry").path();
        if path.extension().is_some_and(|e| e == "wgsl") {
            let stem = path
                .file_stem()
                .and_then(|s| s.to_str())
                .unwrap_or_default()
                .to_owned();
            assert!(
                lumigraph_core::shaders::all()
                    .iter()
                    .any(|(n, _)| *n == stem),
                "{stem}.wgsl is not in shaders::all()"
            );
        }
    }
}

#[test]
fn marcher_without_subgroups_needs_none() {
    // Devices without `wgpu::Features::SUBGROUP` (the GL backend, some drivers) get the plain
    // atomic counters: that variant must validate without the subgroup capabilities, and the
    // other must need them.
    let without = naga::valid::Capabilities::all()
        - naga::valid::Capabilities::SUBGROUP
        - naga::valid::Capabilities::SUBGROUP_BARRIER
        - naga::valid::Capabilities::SUBGROUP_VERTEX_STAGE;
    let validates = |source: &str| {
        let module = naga::front::wgsl::parse_str(source).expect("parses");
        naga::valid::Validator::new(naga::valid::ValidationFlags::all(), without)
            .validate(&module)
            .is_ok()
    };
    assert!(validates(&lumigraph_core::shaders::render_source(false)));
    assert!(!validates(&lumigraph_core::shaders::render_source(true)));
}
