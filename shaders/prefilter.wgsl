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
// The CPU reference is `cpu_prefilter` in crates/gpu/src/prefilter.rs: keep the two in sync.

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
