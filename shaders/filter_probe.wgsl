// The filtering-precision probe (crates/gpu/src/filter_probe.rs): a 2×1×1 texture holding 0 and 1 is sampled by the
// hardware trilinear filter at n points between its two texel centres, the k-th at weight f = k/n. With texels 0 and
// 1 the filtered value is the weight itself, as the device rounds it (Vulkan's subTexelPrecisionBits), so the
// readback shows how many fractional bits the weights keep and which way they are rounded.

// The Rust twin is `ProbeUniforms` in crates/gpu/src/filter_probe.rs (tests/shaders.rs compares the layouts).
struct ProbeUniforms {
    // Samples (the length of probe_out that is written).
    count: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

// Bound through the `SLOT_*` constants of crates/gpu/src/filter_probe.rs (tests/shaders.rs compares the numbers).
@group(0) @binding(0) var<uniform> probe: ProbeUniforms;
@group(0) @binding(1) var probe_tex: texture_3d<f32>;
@group(0) @binding(2) var probe_sampler: sampler;
@group(0) @binding(3) var<storage, read_write> probe_out: array<f32>;

@compute @workgroup_size(64)
fn cs_filter_probe(@builtin(global_invocation_id) id: vec3<u32>) {
    if id.x >= probe.count {
        return;
    }
    // Texel centres at x = 1/4 and 3/4: texel coordinate 2x − ½ = f between them.
    let f = f32(id.x) / f32(probe.count);
    let x = (0.5 + f) * 0.5;
    probe_out[id.x] = textureSampleLevel(probe_tex, probe_sampler, vec3<f32>(x, 0.5, 0.5), 0.0).r;
}
