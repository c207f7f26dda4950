//! Every shader in the registry parses and validates with naga (no device), and every Rust uniform struct matches
//! naga's layout of the WGSL struct of the same name (size, field names, offsets). All failures are reported at once.

use warpbench_gpu::raycast::RaycastRenderer;
use warpbench_gpu::shaders::{ALL, Stage};

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

/// Validation failures of one shader (empty when it is fine).
fn check(shader: &warpbench_gpu::shaders::ShaderSource) -> Vec<String> {
    let mut failures = Vec::new();
    let module = match naga::front::wgsl::parse_str(shader.source) {
        Ok(m) => m,
        Err(e) => return vec![e.emit_to_string_with_path(shader.source, shader.path)],
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
    for rust in shader.uniform_structs {
        let Some(ty) = module.types.iter().find(|(_, t)| t.name.as_deref() == Some(rust.name)) else {
            failures.push(format!("{}: no struct `{}`", shader.path, rust.name));
            continue;
        };
        let naga::TypeInner::Struct { members, span } = &ty.1.inner else {
            failures.push(format!("{}: `{}` is not a struct", shader.path, rust.name));
            continue;
        };
        if *span as usize != rust.size {
            failures.push(format!("{}: `{}` is {span} bytes in WGSL, {} in Rust", shader.path, rust.name, rust.size));
        }
        let wgsl: Vec<(&str, usize)> = members
            .iter()
            .filter_map(|m| m.name.as_deref().map(|n| (n, m.offset as usize)))
            .filter(|(n, _)| !n.starts_with("_pad"))
            .collect();
        if wgsl != rust.fields {
            failures.push(format!(
                "{}: `{}` fields differ:\n  WGSL {wgsl:?}\n  Rust {:?}",
                shader.path, rust.name, rust.fields
            ));
        }
    }
    failures
}

#[test]
fn every_shader_validates_and_matches_its_rust_structs() {
    assert!(!ALL.is_empty());
    let failures: Vec<String> = ALL.iter().flat_map(check).collect();
    assert!(failures.is_empty(), "{} shader problem(s):\n{}", failures.len(), failures.join("\n"));
}

#[test]
fn a_broken_shader_is_rejected_with_a_readable_message() {
    let mut broken = warpbench_gpu::shaders::RAYCAST;
    broken.source = "@fragment fn fs_raycast() -> @location(0) vec4<f32> { return vec4<f32>(1.0, 2.0); }";
    let failures = check(&broken);
    assert!(failures.iter().any(|f| f.contains("shaders/raycast.wgsl")), "{failures:?}");
    let mut renamed = warpbench_gpu::shaders::RAYCAST;
    renamed.entry_points = &[("fs_missing", Stage::Fragment)];
    assert!(check(&renamed).iter().any(|f| f.contains("fs_missing")));
}
