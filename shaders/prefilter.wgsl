// One axis of the separable 3-D Gaussian prefilter (Brunet et al. 2006 §3.4: gradients for shading are taken from a
// prefiltered copy of each volume). Three dispatches (x, y, z) filter a volume; each may halve its axis.
//
// Output texel j along `axis` sits at source index c_j = (j + ½)·n_src/n_dst − ½ (so that both textures cover the
// same [0,1]^3 box of voxel edges: c_j = j at full resolution, 2j + ½ at half resolution), and holds
//   Σ_i w_i · src[clamp(i, 0, n_src − 1)] / Σ_i w_i,   w_i = exp(−(i − c_j)² / (2σ²)),
// for i from floor(c_j) − radius to ceil(c_j) + radius (clamp-to-edge). Values are the volume's normalised texels.
//
// The output (and the source of the y and z passes) is an R32Float 2-D *array* texture, layer = z: wgpu's GL backend
// binds a 3-D storage texture as one layer (wgpu-hal 30 `ImageBinding`, layered = false), an array as all of them.
// The ray caster reads it with textureLoad and filters by hand.
//
// A fourth pass (cs_gradient) turns the filtered copy into what the ray caster shades with: its gradient per texel by
// central differences (clamp-to-edge), in normalised texel units per unit of texture coordinate,
//   g_a[i] = (v[min(i + e_a, n − 1)] − v[max(i − e_a, 0)]) · n_a / 2,
// written as Rgba16Float texels (the f16 bits of (g_x, g_y) and (g_z, 0) in two words) into a storage buffer in the copy layout of
// a z-slab (rows padded to 256 bytes), which the caller copies into the 3-D gradient texture: a storage buffer, as
// a 3-D storage texture is bound as one layer on GL. The ray caster filters that texture in hardware, one lookup per
// gradient.
//
// The CPU reference is `cpu_prefilter` and `PrefilteredTexels::gradients` in crates/gpu/src/prefilter.rs: keep them
// in sync.

// The Rust twin is `PrefilterUniforms` in crates/gpu/src/prefilter.rs (tests/shaders.rs compares the layouts).
struct PrefilterUniforms {
    axis: u32,
    radius_vox: u32,
    sigma_vox: f32,
    _pad0: u32,
    // the output's size (textureDimensions of a storage texture is not used: see above)
    dst_dims: vec3<u32>,
    _pad1: u32,
}

// The Rust code binds these through the `SLOT_*` constants of crates/gpu/src/prefilter.rs
// (tests/shaders.rs compares the numbers).
@group(0) @binding(0) var<uniform> p: PrefilterUniforms;
// x pass: the volume itself (any float format, read with textureLoad).
@group(0) @binding(1) var src_volume: texture_3d<f32>;
@group(0) @binding(2) var dst: texture_storage_2d_array<r32float, write>;
// y and z passes: the previous pass's output.
@group(0) @binding(3) var src_layers: texture_2d_array<f32>;

// The taps of output index j along the axis: first source index, last source index, centre.
struct Taps {
    lo: i32,
    hi: i32,
    c: f32,
}

fn taps(j: u32, n_src: u32) -> Taps {
    let c = (f32(j) + 0.5) * f32(n_src) / f32(p.dst_dims[p.axis]) - 0.5;
    return Taps(i32(floor(c)) - i32(p.radius_vox), i32(ceil(c)) + i32(p.radius_vox), c);
}

fn weight(i: i32, c: f32) -> f32 {
    let d = f32(i) - c;
    return exp(-d * d * (0.5 / (p.sigma_vox * p.sigma_vox)));
}

@compute @workgroup_size(4, 4, 4)
fn cs_gaussian_from_volume(@builtin(global_invocation_id) id: vec3<u32>) {
    if any(id >= p.dst_dims) {
        return;
    }
    let src_dims = textureDimensions(src_volume);
    let a = p.axis;
    let t = taps(id[a], src_dims[a]);
    let last = i32(src_dims[a]) - 1;
    var sum = 0.0;
    var weight_sum = 0.0;
    var q = vec3<i32>(id);
    for (var i = t.lo; i <= t.hi; i++) {
        let w = weight(i, t.c);
        q[a] = clamp(i, 0, last);
        sum += w * textureLoad(src_volume, q, 0).r;
        weight_sum += w;
    }
    textureStore(dst, id.xy, id.z, vec4<f32>(sum / weight_sum, 0.0, 0.0, 1.0));
}

@compute @workgroup_size(4, 4, 4)
fn cs_gaussian_from_layers(@builtin(global_invocation_id) id: vec3<u32>) {
    if any(id >= p.dst_dims) {
        return;
    }
    let src_dims = vec3<u32>(textureDimensions(src_layers), textureNumLayers(src_layers));
    let a = p.axis;
    let t = taps(id[a], src_dims[a]);
    let last = i32(src_dims[a]) - 1;
    var sum = 0.0;
    var weight_sum = 0.0;
    var q = vec3<i32>(id);
    for (var i = t.lo; i <= t.hi; i++) {
        let w = weight(i, t.c);
        q[a] = clamp(i, 0, last);
        sum += w * textureLoad(src_layers, q.xy, q.z, 0).r;
        weight_sum += w;
    }
    textureStore(dst, id.xy, id.z, vec4<f32>(sum / weight_sum, 0.0, 0.0, 1.0));
}

// The Rust twin is `GradientUniforms` in crates/gpu/src/prefilter.rs (tests/shaders.rs compares the layouts).
struct GradientUniforms {
    // the filtered copy's dims
    dims: vec3<u32>,
    // the slab's first z
    first_z: u32,
    // u32 words per row of the copy layout (bytes_per_row / 4)
    row_words: u32,
    // z planes in the slab
    slab_depth: u32,
    _pad0: u32,
    _pad1: u32,
}

@group(0) @binding(4) var<uniform> g: GradientUniforms;
// The filtered copy (the z pass's output).
@group(0) @binding(5) var filtered: texture_2d_array<f32>;
@group(0) @binding(6) var<storage, read_write> gradient_out: array<u32>;

fn filtered_at(q: vec3<i32>) -> f32 {
    return textureLoad(filtered, q.xy, q.z, 0).r;
}

// f16_bits is in shaders/f16.wgsl, appended to this file.

@compute @workgroup_size(4, 4, 4)
fn cs_gradient(@builtin(global_invocation_id) id: vec3<u32>) {
    let q = vec3<u32>(id.xy, id.z + g.first_z);
    if any(q >= g.dims) || id.z >= g.slab_depth {
        return;
    }
    let n = vec3<i32>(g.dims);
    let i = vec3<i32>(q);
    var grad = vec3<f32>(0.0);
    for (var a = 0; a < 3; a++) {
        var hi = i;
        var lo = i;
        hi[a] = min(i[a] + 1, n[a] - 1);
        lo[a] = max(i[a] - 1, 0);
        grad[a] = (filtered_at(hi) - filtered_at(lo)) * (0.5 * f32(n[a]));
    }
    let word = (id.z * g.dims.y + id.y) * g.row_words + 2u * id.x;
    gradient_out[word] = f16_bits(grad.x) | (f16_bits(grad.y) << 16u);
    gradient_out[word + 1u] = f16_bits(grad.z);
}
