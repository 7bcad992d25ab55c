//! Every WGSL module parses and validates with naga on the CPU, so a broken shader fails CI
//! without any GPU or driver.

#[test]
fn every_shader_validates_with_naga() {
    let marcher = [
        ("render", lumigraph_core::render::shader_source(false)),
        (
            "render (subgroups)",
            lumigraph_core::render::shader_source(true),
        ),
    ];
    for (name, source) in lumigraph_core::shaders::all().into_iter().chain(marcher) {
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
    // A new .wgsl file must be added to `shaders::all()` (or be shared code included by one);
    // the marcher's stages to `shaders::RENDER_FILES`.
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../shaders");
    let stems = |dir: &std::path::Path| -> Vec<String> {
        std::fs::read_dir(dir)
            .expect("shaders dir")
            .map(|entry| entry.expect("entry").path())
            .filter(|path| path.extension().is_some_and(|e| e == "wgsl"))
            .filter_map(|path| path.file_stem()?.to_str().map(str::to_owned))
            .collect()
    };
    for stem in stems(&dir) {
        assert!(
            lumigraph_core::shaders::all()
                .iter()
                .any(|(n, _)| *n == stem),
            "{stem}.wgsl is not in shaders::all()"
        );
    }
    let stages = stems(&dir.join("render"));
    assert_eq!(stages.len(), lumigraph_core::shaders::RENDER_FILES.len());
    for stem in stages {
        assert!(
            lumigraph_core::shaders::RENDER_FILES
                .iter()
                .any(|(n, _)| *n == stem),
            "render/{stem}.wgsl is not in shaders::RENDER_FILES"
        );
    }
    assert!(
        !dir.join("render.wgsl").exists(),
        "the marcher is split by stage"
    );
}

#[test]
fn render_params_match_the_rust_layout() {
    // Every member of the WGSL `RenderParams`, in order, has the name and byte offset of the
    // Rust struct's member, and the struct's size matches: a field added, moved or retyped on
    // one side only fails here, without a GPU.
    let source = lumigraph_core::render::shader_source(false);
    let module = naga::front::wgsl::parse_str(&source).expect("parses");
    let members = module
        .types
        .iter()
        .find_map(|(_, ty)| match &ty.inner {
            naga::TypeInner::Struct { members, span }
                if ty.name.as_deref() == Some("RenderParams") =>
            {
                Some((members.clone(), *span))
            }
            _ => None,
        })
        .expect("a RenderParams struct");
    let (members, span) = members;
    let wgsl: Vec<(String, usize)> = members
        .iter()
        .map(|m| (m.name.clone().unwrap_or_default(), m.offset as usize))
        .collect();
    let rust: Vec<(String, usize)> = lumigraph_core::render::render_params_layout()
        .into_iter()
        .map(|(name, offset)| (name.to_owned(), offset))
        .collect();
    assert_eq!(wgsl, rust);
    assert_eq!(span, 288);
}

#[test]
fn marcher_constants_are_generated_once() {
    // The constants Rust and WGSL share come from the generated preamble only: no stage file
    // defines one of them again, and the stage files hold none of the values by hand.
    let source = lumigraph_core::render::shader_source(false);
    let generated: Vec<&str> = source
        .lines()
        .filter_map(|line| line.strip_prefix("const "))
        .filter_map(|rest| rest.split(':').next())
        .collect();
    for name in [
        "EDGE_BASE",
        "EDGE_CODES",
        "EDGE_E_LEVELS",
        "BOUNDING_RADIUS",
        "METHOD_FIXED",
        "ROLE_COARSE",
        "TILED_GIVEN_BACK",
    ] {
        assert_eq!(
            generated.iter().filter(|n| **n == name).count(),
            1,
            "{name} is defined once"
        );
    }
    for (stage, text) in lumigraph_core::shaders::RENDER_FILES {
        for literal in [
            "57343u",
            "8192u",
            "0.70710678",
            "511u",
            "ROLE == 1u",
            "ROLE == 3u",
        ] {
            assert!(
                !text.contains(literal),
                "render/{stage}.wgsl holds {literal}"
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
    assert!(validates(&lumigraph_core::render::shader_source(false)));
    assert!(!validates(&lumigraph_core::render::shader_source(true)));
}

/// What an expression's value depends on: constants only, uniform-buffer values (and
/// constants), or anything else (invocation ids, textures, storage, private state).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
enum Dependence {
    Constant,
    Uniform,
    Varying,
}

/// Finds the branches lavapipe's uniform inlining would rebuild a shader for: an `if`, `switch`
/// or loop exit whose condition depends on uniform-buffer values and constants alone (a loop's
/// condition is an `if` in naga's IR). Functions are analysed per call, with their arguments'
/// dependence; locals and private globals by the join of everything stored in them.
struct UniformBranches<'m> {
    module: &'m naga::Module,
    privates: std::collections::HashMap<naga::Handle<naga::GlobalVariable>, Dependence>,
    changed: bool,
    report: bool,
    found: std::collections::BTreeSet<String>,
}

impl UniformBranches<'_> {
    fn function(&mut self, function: &naga::Function, args: &[Dependence]) -> Dependence {
        // Until what is stored in the locals stops changing, then once more to report.
        let report = std::mem::replace(&mut self.report, false);
        let mut locals: std::collections::HashMap<_, Dependence> =
            std::collections::HashMap::default();
        let mut stable = false;
        loop {
            if stable {
                self.report = report;
            }
            let before = locals.clone();
            let mut state = FunctionState {
                function,
                args,
                locals: &mut locals,
                calls: std::collections::HashMap::default(),
                returned: Dependence::Constant,
            };
            for (handle, local) in function.local_variables.iter() {
                let init = local
                    .init
                    .map_or(Dependence::Constant, |e| state.expr(self, e));
                let entry = state.locals.entry(handle).or_insert(Dependence::Constant);
                *entry = (*entry).max(init);
            }
            state.block(self, &function.body);
            let returned = state.returned;
            if stable {
                return returned;
            }
            stable = locals == before;
        }
    }
}

struct FunctionState<'f, 'l> {
    function: &'f naga::Function,
    args: &'f [Dependence],
    locals: &'l mut std::collections::HashMap<naga::Handle<naga::LocalVariable>, Dependence>,
    calls: std::collections::HashMap<naga::Handle<naga::Expression>, Dependence>,
    returned: Dependence,
}

impl FunctionState<'_, '_> {
    fn expr(&self, a: &UniformBranches, h: naga::Handle<naga::Expression>) -> Dependence {
        use naga::Expression as E;
        match &self.function.expressions[h] {
            E::Literal(_) | E::Constant(_) | E::Override(_) | E::ZeroValue(_) => {
                Dependence::Constant
            }
            E::FunctionArgument(i) => self.args[*i as usize],
            E::GlobalVariable(g) => match a.module.global_variables[*g].space {
                naga::AddressSpace::Uniform => Dependence::Uniform,
                naga::AddressSpace::Private => {
                    a.privates.get(g).copied().unwrap_or(Dependence::Constant)
                }
                _ => Dependence::Varying,
            },
            E::LocalVariable(l) => self.locals.get(l).copied().unwrap_or(Dependence::Constant),
            E::Load { pointer } => self.expr(a, *pointer),
            E::AccessIndex { base, .. } => self.expr(a, *base),
            E::Access { base, index } => self.expr(a, *base).max(self.expr(a, *index)),
            E::Splat { value, .. } => self.expr(a, *value),
            E::Swizzle { vector, .. } => self.expr(a, *vector),
            E::Unary { expr, .. } | E::As { expr, .. } => self.expr(a, *expr),
            E::Binary { left, right, .. } => self.expr(a, *left).max(self.expr(a, *right)),
            E::Select {
                condition,
                accept,
                reject,
            } => self
                .expr(a, *condition)
                .max(self.expr(a, *accept))
                .max(self.expr(a, *reject)),
            E::Relational { argument, .. } => self.expr(a, *argument),
            E::Math {
                arg,
                arg1,
                arg2,
                arg3,
                ..
            } => [Some(*arg), *arg1, *arg2, *arg3]
                .into_iter()
                .flatten()
                .map(|e| self.expr(a, e))
                .max()
                .unwrap_or(Dependence::Constant),
            E::Compose { components, .. } => components
                .iter()
                .map(|&e| self.expr(a, e))
                .max()
                .unwrap_or(Dependence::Constant),
            E::CallResult(_) => self.calls.get(&h).copied().unwrap_or(Dependence::Varying),
            _ => Dependence::Varying,
        }
    }

    fn condition(&self, a: &mut UniformBranches, h: naga::Handle<naga::Expression>, what: &str) {
        if a.report && self.expr(a, h) == Dependence::Uniform {
            let name = self.function.name.as_deref().unwrap_or("?");
            a.found.insert(format!("{what} in fn {name}"));
        }
    }

    fn block(&mut self, a: &mut UniformBranches, block: &naga::Block) {
        use naga::Statement as S;
        for statement in block {
            match statement {
                S::Block(inner) => self.block(a, inner),
                S::If {
                    condition,
                    accept,
                    reject,
                } => {
                    self.condition(a, *condition, "if");
                    self.block(a, accept);
                    self.block(a, reject);
                }
                S::Switch { selector, cases } => {
                    self.condition(a, *selector, "switch");
                    for case in cases {
                        self.block(a, &case.body);
                    }
                }
                S::Loop {
                    body,
                    continuing,
                    break_if,
                } => {
                    self.block(a, body);
                    self.block(a, continuing);
                    if let Some(e) = break_if {
                        self.condition(a, *e, "loop exit");
                    }
                }
                S::Return { value: Some(e) } => {
                    self.returned = self.returned.max(self.expr(a, *e));
                }
                S::Store { pointer, value } => {
                    let value = self.expr(a, *value);
                    let mut root = *pointer;
                    while let naga::Expression::AccessIndex { base, .. }
                    | naga::Expression::Access { base, .. } = &self.function.expressions[root]
                    {
                        root = *base;
                    }
                    match &self.function.expressions[root] {
                        naga::Expression::LocalVariable(l) => {
                            let entry = self.locals.entry(*l).or_insert(Dependence::Constant);
                            *entry = (*entry).max(value);
                        }
                        naga::Expression::GlobalVariable(g)
                            if a.module.global_variables[*g].space
                                == naga::AddressSpace::Private =>
                        {
                            let entry = a.privates.entry(*g).or_insert(Dependence::Constant);
                            if value > *entry {
                                *entry = value;
                                a.changed = true;
                            }
                        }
                        _ => {}
                    }
                }
                S::Call {
                    function,
                    arguments,
                    result,
                } => {
                    let args: Vec<_> = arguments.iter().map(|&e| self.expr(a, e)).collect();
                    let callee = &a.module.functions[*function];
                    let returned = a.function(callee, &args);
                    if let Some(r) = result {
                        self.calls.insert(*r, returned);
                    }
                }
                _ => {}
            }
        }
    }
}

/// The marcher's source with its overrides fixed as constants, the way the driver sees one
/// pipeline.
fn specialised_marcher(source: &str, methods: u32, role: u32, span: i32) -> String {
    source
        .replace(
            "override METHODS: u32 = METHODS_BOTH;",
            &format!("const METHODS: u32 = {methods}u;"),
        )
        .replace(
            "override ROLE: u32 = ROLE_PLAIN;",
            &format!("const ROLE: u32 = {role}u;"),
        )
        .replace(
            "override TILE_SPAN: i32 = 4;",
            &format!("const TILE_SPAN: i32 = {span};"),
        )
}

/// The uniform-only branches of every pipeline the renderer builds from the marcher (METHODS
/// 1–3 × ROLE 0–4 × TILE_SPAN 3–4).
fn uniform_branches(source: &str) -> Vec<String> {
    let mut found = Vec::new();
    for (methods, role, span) in (1..=3)
        .flat_map(|m| (0..=4).map(move |r| (m, r)))
        .flat_map(|(m, r)| [3, 4].map(|s| (m, r, s)))
    {
        let label = format!("METHODS {methods}, ROLE {role}, TILE_SPAN {span}");
        found.extend(uniform_branches_of(
            &specialised_marcher(source, methods, role, span),
            &label,
        ));
    }
    found.sort();
    found.dedup();
    found
}

/// The uniform-only branches of a module whose overrides are already constants.
fn uniform_branches_of(specialised: &str, label: &str) -> Vec<String> {
    assert!(
        !specialised.contains("override "),
        "an override declaration left unspecialised"
    );
    let module = naga::front::wgsl::parse_str(specialised).expect("parses");
    let mut found = Vec::new();
    for entry in &module.entry_points {
        let mut analysis = UniformBranches {
            module: &module,
            privates: std::collections::HashMap::default(),
            changed: true,
            report: false,
            found: std::collections::BTreeSet::default(),
        };
        // Private globals: until what is stored in them stops changing, then report.
        while analysis.changed {
            analysis.changed = false;
            let args = vec![Dependence::Varying; entry.function.arguments.len()];
            analysis.function(&entry.function, &args);
        }
        analysis.report = true;
        let args = vec![Dependence::Varying; entry.function.arguments.len()];
        analysis.function(&entry.function, &args);
        for f in analysis.found {
            found.push(format!("{} ({label}): {f}", entry.name));
        }
    }
    found
}

/// The two-plane renderer's pipelines (MODE 0–3 × APERTURE) branch on no uniform value alone:
/// lavapipe rebuilds such a shader whenever its uniform buffer is bound (with the mode and
/// aperture as uniforms, an empty frame cost 28 ms at 512²; as overrides, 7 ms).
#[test]
fn two_plane_pipelines_have_no_branch_on_uniform_values_alone() {
    let mut found = Vec::new();
    for (source, paged) in [
        (lumigraph_core::shaders::TWO_PLANE, false),
        (lumigraph_core::shaders::TWO_PLANE_PAGED, true),
    ] {
        for mode in 0..4 {
            for aperture in [false, true] {
                // The paged pipelines' OVERVIEW, the resident ones' DEPTH_PYRAMID.
                for variant in [false, true] {
                    let specialised = source
                        .replace(
                            "override MODE: u32 = 1u;",
                            &format!("const MODE: u32 = {mode}u;"),
                        )
                        .replace(
                            "override APERTURE: bool = false;",
                            &format!("const APERTURE: bool = {aperture};"),
                        )
                        .replace(
                            "override OVERVIEW: bool = true;",
                            &format!("const OVERVIEW: bool = {variant};"),
                        )
                        .replace(
                            "override DEPTH_PYRAMID: bool = true;",
                            &format!("const DEPTH_PYRAMID: bool = {variant};"),
                        );
                    found.extend(uniform_branches_of(
                        &specialised,
                        &format!(
                            "MODE {mode}, APERTURE {aperture}, OVERVIEW/DEPTH_PYRAMID {variant}, paged {paged}"
                        ),
                    ));
                }
            }
        }
    }
    assert!(
        found.is_empty(),
        "branches on uniform values alone:\n{}",
        found.join("\n")
    );
}

#[test]
fn marcher_has_no_branch_on_uniform_values_alone() {
    // Lavapipe (Mesa 22.3) inlines the uniform values such a branch reads and rebuilds the
    // shader every time its uniform buffer is bound (no cache): it cost every guided frame a
    // rebuild (~3 ms from Mesa's shader cache, 0.7 s without one) until `per_invocation`.
    let source = lumigraph_core::render::shader_source(false);
    let found = uniform_branches(&source);
    assert!(
        found.is_empty(),
        "branches on uniform values alone:\n{}",
        found.join("\n")
    );
    // The check finds one when there is one (the branch the renderer used to have).
    let planted = source.replace(
        "    g_invocation = global_id.x;",
        "    g_invocation = global_id.x;\n    if params.tiled != 0u {\n        out_depth[0] = 1.0;\n    }",
    );
    assert_ne!(planted, source);
    // In one pipeline (every one runs `cs_main`'s prologue): the check is the same per pipeline.
    let found = uniform_branches_of(&specialised_marcher(&planted, 3, 0, 4), "planted");
    assert!(
        found
            .iter()
            .any(|f| f.starts_with("cs_main") && f.ends_with("if in fn cs_main")),
        "{found:?}"
    );
}
