//! Every shader in the registry parses and validates with naga (no device), and every pass's interface matches its
//! WGSL: each Rust uniform struct has naga's layout of the WGSL struct of the same name (size, field names, offsets),
//! each bind slot the Rust code binds is the `@group(G) @binding(N)` of the WGSL variable it names, and each WGSL
//! constant with a Rust twin has its value. Every `@binding` of every shader belongs to some pass. All failures are
//! reported at once.

use std::collections::BTreeSet;

use warpbench_gpu::RaycastRenderer;
use warpbench_gpu::shaders::{ALL, BindSlot, INTERFACES, ShaderInterface, ShaderSource, Stage, WgslConstant};

/// The naga capabilities that correspond to the features the device may be given. Our optional features
/// (TEXTURE_FORMAT_16BIT_NORM, FLOAT32_FILTERABLE) are texture-format features with no shader capability, so the
/// shaders must validate with none: this also proves they run on a plain WebGPU-level device.
fn capabilities_for(features: wgpu::Features) -> naga::valid::Capabilities {
    assert!(RaycastRenderer::OPTIONAL_FEATURES.contains(features));
    naga::valid::Capabilities::empty()
}

fn stage_of(s: naga::ShaderStage) -> Option<Stage> {
    match s {
        naga::ShaderStage::Vertex => Some(Stage::Vertex),
        naga::ShaderStage::Fragment => Some(Stage::Fragment),
        naga::ShaderStage::Compute => Some(Stage::Compute),
        _ => None,
    }
}

/// The parsed module of `shader`, or the parse error with its path.
fn parse(shader: &ShaderSource) -> Result<naga::Module, String> {
    naga::front::wgsl::parse_str(shader.source).map_err(|e| e.emit_to_string_with_path(shader.source, shader.path))
}

/// Validation failures of one shader (empty when it is fine).
fn check(shader: &ShaderSource) -> Vec<String> {
    let mut failures = Vec::new();
    let module = match parse(shader) {
        Ok(m) => m,
        Err(e) => return vec![e],
    };
    let caps = capabilities_for(RaycastRenderer::OPTIONAL_FEATURES);
    if let Err(e) = naga::valid::Validator::new(naga::valid::ValidationFlags::all(), caps).validate(&module) {
        failures.push(format!("{}: {}", shader.path, e.emit_to_string_with_path(shader.source, shader.path)));
    }
    for (name, stage) in shader.entry_points {
        if !module.entry_points.iter().any(|ep| ep.name == *name && stage_of(ep.stage) == Some(*stage)) {
            failures.push(format!("{}: no {stage:?} entry point `{name}`", shader.path));
        }
    }
    failures
}

/// Where a WGSL module binds its global variable `name`, or what is wrong with it.
fn binding_of(module: &naga::Module, name: &str) -> Result<(u32, u32), String> {
    let (_, var) = module
        .global_variables
        .iter()
        .find(|(_, v)| v.name.as_deref() == Some(name))
        .ok_or_else(|| format!("no variable `{name}`"))?;
    let b = var.binding.as_ref().ok_or_else(|| format!("`{name}` has no @group/@binding"))?;
    Ok((b.group, b.binding))
}

/// The value of the module-scope `const name` (a scalar literal), or what is wrong with it.
fn constant_of(module: &naga::Module, name: &str) -> Result<f64, String> {
    let (_, c) = module
        .constants
        .iter()
        .find(|(_, c)| c.name.as_deref() == Some(name))
        .ok_or_else(|| format!("no const `{name}`"))?;
    match module.global_expressions[c.init] {
        naga::Expression::Literal(naga::Literal::F32(v)) => Ok(f64::from(v)),
        naga::Expression::Literal(naga::Literal::U32(v)) => Ok(f64::from(v)),
        naga::Expression::Literal(naga::Literal::I32(v)) => Ok(f64::from(v)),
        _ => Err(format!("const `{name}` is not a scalar literal")),
    }
}

/// Mismatches between one pass's interface and its shader (empty when they agree).
fn check_interface(interface: &ShaderInterface) -> Vec<String> {
    let path = interface.shader.path;
    let at = |what: String| format!("{path} ({}): {what}", interface.pass);
    let module = match parse(&interface.shader) {
        Ok(m) => m,
        Err(e) => return vec![e],
    };
    let mut failures = Vec::new();
    for rust in interface.uniform_structs {
        let Some(ty) = module.types.iter().find(|(_, t)| t.name.as_deref() == Some(rust.name)) else {
            failures.push(at(format!("no struct `{}`", rust.name)));
            continue;
        };
        let naga::TypeInner::Struct { members, span } = &ty.1.inner else {
            failures.push(at(format!("`{}` is not a struct", rust.name)));
            continue;
        };
        if *span as usize != rust.size {
            failures.push(at(format!("`{}` is {span} bytes in WGSL, {} in Rust", rust.name, rust.size)));
        }
        let wgsl: Vec<(&str, usize)> = members
            .iter()
            .filter_map(|m| m.name.as_deref().map(|n| (n, m.offset as usize)))
            .filter(|(n, _)| !n.starts_with("_pad"))
            .collect();
        if wgsl != rust.fields {
            failures.push(at(format!("`{}` fields differ:\n  WGSL {wgsl:?}\n  Rust {:?}", rust.name, rust.fields)));
        }
    }
    for slot in interface.slots {
        let rust = (slot.group, slot.binding);
        match binding_of(&module, slot.name) {
            Err(e) => failures.push(at(e)),
            Ok(wgsl) if wgsl != rust => failures.push(at(format!(
                "`{}` is @group({}) @binding({}) in WGSL, group {} binding {} in Rust",
                slot.name, wgsl.0, wgsl.1, rust.0, rust.1
            ))),
            Ok(_) => {}
        }
    }
    for constant in interface.constants {
        match constant_of(&module, constant.name) {
            Err(e) => failures.push(at(e)),
            Ok(wgsl) if wgsl.to_bits() != constant.value.to_bits() => {
                failures.push(at(format!("const `{}` is {wgsl} in WGSL, {} in Rust", constant.name, constant.value)));
            }
            Ok(_) => {}
        }
    }
    failures
}

/// The `@binding`s of `shader` that no interface of `interfaces` claims.
fn unclaimed_bindings(shader: &ShaderSource, interfaces: &[ShaderInterface]) -> Vec<String> {
    let Ok(module) = parse(shader) else { return Vec::new() };
    let claimed: BTreeSet<&str> = interfaces
        .iter()
        .filter(|i| i.shader.path == shader.path)
        .flat_map(|i| i.slots.iter().map(|s| s.name))
        .collect();
    module
        .global_variables
        .iter()
        .filter_map(|(_, v)| Some((v.name.as_deref()?, v.binding.as_ref()?)))
        .filter(|(name, _)| !claimed.contains(name))
        .map(|(name, b)| {
            format!("{}: `{name}` (@group({}) @binding({})) is bound by no pass", shader.path, b.group, b.binding)
        })
        .collect()
}

#[test]
fn every_shader_validates() {
    assert!(!ALL.is_empty());
    let failures: Vec<String> = ALL.iter().flat_map(check).collect();
    assert!(failures.is_empty(), "{} shader problem(s):\n{}", failures.len(), failures.join("\n"));
}

#[test]
fn every_interface_matches_its_shader_and_every_binding_has_a_pass() {
    assert!(!INTERFACES.is_empty());
    let mut failures: Vec<String> = INTERFACES.iter().flat_map(check_interface).collect();
    failures.extend(ALL.iter().flat_map(|s| unclaimed_bindings(s, INTERFACES)));
    for interface in INTERFACES {
        if !ALL.iter().any(|s| s.path == interface.shader.path) {
            failures
                .push(format!("{}: the shader of `{}` is not in the registry", interface.shader.path, interface.pass));
        }
    }
    for shader in ALL {
        if !INTERFACES.iter().any(|i| i.shader.path == shader.path) {
            failures.push(format!("{}: no pass declares an interface for it", shader.path));
        }
    }
    assert!(failures.is_empty(), "{} interface problem(s):\n{}", failures.len(), failures.join("\n"));
}

#[test]
fn a_broken_shader_is_rejected_with_a_readable_message() {
    let mut broken = warpbench_gpu::shaders::RAYCAST;
    broken.source = "@compute @workgroup_size(1) fn cs_raycast() { let c = vec4<f32>(1.0, 2.0); }";
    let failures = check(&broken);
    assert!(failures.iter().any(|f| f.contains("shaders/raycast.wgsl")), "{failures:?}");
    let mut renamed = warpbench_gpu::shaders::RAYCAST;
    renamed.entry_points = &[("cs_missing", Stage::Compute)];
    assert!(check(&renamed).iter().any(|f| f.contains("cs_missing")));
}

#[test]
fn a_slot_or_constant_the_wgsl_does_not_have_is_reported() {
    const RENUMBERED: &[BindSlot] = &[BindSlot::new(0, 2, "fixed_tex")];
    const REGROUPED: &[BindSlot] = &[BindSlot::new(1, 0, "u")];
    const MISNAMED: &[BindSlot] = &[BindSlot::new(0, 0, "uniforms")];
    const CHANGED: &[WgslConstant] = &[WgslConstant::f32("HIT_OPACITY", 0.25), WgslConstant::u32("NO_SUCH", 1)];
    let raycast = warpbench_gpu::raycast::INTERFACE;
    let renumbered = ShaderInterface { slots: RENUMBERED, ..raycast };
    let failures = check_interface(&renumbered);
    assert!(failures.iter().any(|f| f.contains("`fixed_tex` is @group(0) @binding(1) in WGSL")), "{failures:?}");
    let regrouped = ShaderInterface { slots: REGROUPED, ..raycast };
    assert!(check_interface(&regrouped).iter().any(|f| f.contains("`u` is @group(0) @binding(0)")));
    let misnamed = ShaderInterface { slots: MISNAMED, ..raycast };
    assert!(check_interface(&misnamed).iter().any(|f| f.contains("no variable `uniforms`")));
    let constants = check_interface(&ShaderInterface { constants: CHANGED, ..raycast });
    assert!(constants.iter().any(|f| f.contains("const `HIT_OPACITY` is 0.5 in WGSL, 0.25 in Rust")), "{constants:?}");
    assert!(constants.iter().any(|f| f.contains("no const `NO_SUCH`")), "{constants:?}");
    // Without the picking pass, its group-1 bindings in the same file belong to nobody.
    let without_pick: Vec<ShaderInterface> = INTERFACES.iter().copied().filter(|i| i.pass != "pick").collect();
    let unclaimed = unclaimed_bindings(&warpbench_gpu::shaders::RAYCAST, &without_pick);
    assert_eq!(unclaimed.len(), 3, "{unclaimed:?}");
}
