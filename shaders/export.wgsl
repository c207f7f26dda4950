// Export of the warped moving volume: v'(x) = v(u(x)) resampled onto a target grid (usually the fixed volume's),
// with u the pull-back ref → moving LPS (Brunet, Nowak & Gleicher 2006; resampling as a pull-back, as ITK's
// ResampleImageFilter does). One invocation per target voxel of one z-slab (x fastest), its value rounded, clamped and
// packed into the output's own type here (8- and 16-bit types four and two to a word), so that the host copies
// bytes out and converts nothing (crates/gpu/src/export/gpu.rs).
//
// Per voxel (i, j, k) of the target grid, with every affine map composed in f64 on the host:
//   s = source_index_from_target_index · (i, j, k)                   (the pull-back's identity part)
//   s += source_index_from_lps · d,  d = the pull-back's displacement u(x) − x in mm:
//     control texture: trilinear, clamp-to-edge lookup of the texels at c = pullback_from_target_index · (i, j, k)
//                      (continuous texel index, centres at integers);
//     TPS:             d(x′) = (A − I) x′ + (A o + b − o) + Σ wₙ ‖x′ − pₙ′‖ at x′ = pullback_from_target_index ·
//                      (i, j, k), local mm about the origin o (crates/gpu/src/pullback.rs, `TpsLocal`).
//   inside ⇔ −½ ≤ s ≤ n − ½ on every axis (the voxel-edge box, as ITK's continuous-index buffer test); outside
//   voxels get `outside_stored`, inside ones nearest / trilinear / Catmull-Rom with clamp-to-edge taps, stored as
//   the output type: rounded half to even and clamped for integers, as the CPU path's `Sample::from_f64` does.
//
// The CPU path (crates/gpu/src/export/cpu.rs) does the same f32 operations in the same order: keep them in sync.

// The Rust twin is `ExportUniforms` in crates/gpu/src/export/gpu.rs (tests/shaders.rs compares the layouts).
struct ExportUniforms {
    // Columns; an affine map is applied as ((m[3] + j·m[1]) + k·m[2]) + i·m[0].
    source_index_from_target_index: mat4x4<f32>,
    // Control: continuous control-texel index; TPS: local mm (x′); unused for the identity.
    pullback_from_target_index: mat4x4<f32>,
    // Linear part (columns 0..2) maps a displacement in mm to source voxels.
    source_index_from_lps: mat4x4<f32>,
    // Rows of (A − I | A o + b − o).
    tps_row0: vec4<f32>,
    tps_row1: vec4<f32>,
    tps_row2: vec4<f32>,
    target_dims: vec3<u32>,
    slab_first_slice: u32,
    source_dims: vec3<u32>,
    // Target voxels in this slab (whole slices).
    slab_voxels: u32,
    control_dims: vec3<u32>,
    centre_count: u32,
    // The outside value as the output stores it (the host rounded and clamped it), in the low bits.
    outside_stored: u32,
    // Invocations along x of the dispatch (a multiple of 64): the voxel of invocation id is id.x + id.y · this.
    invocations_per_row: u32,
    _pad0: u32,
    _pad1: u32,
}

// The pipelines are specialised on the pull-back, the kernel, the source's texel type and the output type
// (crates/gpu/src/export/gpu.rs, `PipelineKey`): each compiles only its own path. The defaults are for validation.
override PULLBACK: u32 = 0u;
const PULLBACK_IDENTITY: u32 = 0u;
const PULLBACK_CONTROL: u32 = 1u;
const PULLBACK_TPS: u32 = 2u;

override INTERPOLATION: u32 = 1u;
const INTERPOLATION_NEAREST: u32 = 0u;
const INTERPOLATION_TRILINEAR: u32 = 1u;
const INTERPOLATION_CATMULL_ROM: u32 = 2u;

// Which of the three source bindings holds the volume, in its own type (the other two are 1×1×1 placeholders).
override SOURCE: u32 = 0u;
const SOURCE_FLOAT: u32 = 0u;
const SOURCE_SINT: u32 = 1u;
const SOURCE_UINT: u32 = 2u;

// The output's sample type: f32 words, or integers packed little-endian, 4 (8-bit), 2 (16-bit) or 1 per word.
override OUTPUT: u32 = 0u;
const OUTPUT_F32: u32 = 0u;
const OUTPUT_U8: u32 = 1u;
const OUTPUT_I8: u32 = 2u;
const OUTPUT_U16: u32 = 3u;
const OUTPUT_I16: u32 = 4u;
const OUTPUT_U32: u32 = 5u;
const OUTPUT_I32: u32 = 6u;

// The Rust code binds these through the `SLOT_*` constants of crates/gpu/src/export/gpu.rs
// (tests/shaders.rs compares the numbers).
@group(0) @binding(0) var<uniform> u: ExportUniforms;
// The moving volume in its own type, read with textureLoad (filtered by hand, with full-precision weights): f32
// samples (and f64 samples exact in f32) as R32Float, signed integers as R8Sint / R16Sint / R32Sint, unsigned ones
// as R8Uint / R16Uint / R32Uint. Every value converts to f32 exactly (the host refuses 32-bit samples beyond 2²⁴).
@group(0) @binding(1) var source_float: texture_3d<f32>;
@group(0) @binding(5) var source_sint: texture_3d<i32>;
@group(0) @binding(6) var source_uint: texture_3d<u32>;
// Control texels [dx, dy, dz, 0] mm as Rgba32Float (a 1×1×1 placeholder without a control texture).
@group(0) @binding(2) var control: texture_3d<f32>;
// TPS terms: centre pₙ′ (local mm) at 2n, weight wₙ at 2n + 1.
@group(0) @binding(3) var<storage, read> tps_terms: array<vec4<f32>>;
// One slab of the output, packed (see OUTPUT).
@group(0) @binding(4) var<storage, read_write> slab: array<u32>;

fn affine(m: mat4x4<f32>, ijk: vec3<f32>) -> vec3<f32> {
    let row = (m[3].xyz + ijk.y * m[1].xyz) + ijk.z * m[2].xyz;
    return row + ijk.x * m[0].xyz;
}

// a + f (b − a): exact at f = 0, and constant where a = b.
fn lerp1(a: f32, b: f32, f: f32) -> f32 {
    return a + f * (b - a);
}

fn lerp3(a: vec3<f32>, b: vec3<f32>, f: f32) -> vec3<f32> {
    return a + f * (b - a);
}

fn control_texel(x: i32, y: i32, z: i32) -> vec3<f32> {
    return textureLoad(control, vec3<i32>(x, y, z), 0).xyz;
}

fn control_displacement(c_in: vec3<f32>) -> vec3<f32> {
    let last = vec3<f32>(u.control_dims - vec3<u32>(1u));
    let c = min(max(c_in, vec3<f32>(0.0)), last);
    let c0 = floor(c);
    let f = c - c0;
    let i0 = vec3<i32>(c0);
    let i1 = min(i0 + vec3<i32>(1), vec3<i32>(u.control_dims) - vec3<i32>(1));
    let x00 = lerp3(control_texel(i0.x, i0.y, i0.z), control_texel(i1.x, i0.y, i0.z), f.x);
    let x10 = lerp3(control_texel(i0.x, i1.y, i0.z), control_texel(i1.x, i1.y, i0.z), f.x);
    let x01 = lerp3(control_texel(i0.x, i0.y, i1.z), control_texel(i1.x, i0.y, i1.z), f.x);
    let x11 = lerp3(control_texel(i0.x, i1.y, i1.z), control_texel(i1.x, i1.y, i1.z), f.x);
    return lerp3(lerp3(x00, x10, f.y), lerp3(x01, x11, f.y), f.z);
}

fn tps_displacement(x: vec3<f32>) -> vec3<f32> {
    var d = vec3<f32>(
        ((u.tps_row0.x * x.x + u.tps_row0.y * x.y) + u.tps_row0.z * x.z) + u.tps_row0.w,
        ((u.tps_row1.x * x.x + u.tps_row1.y * x.y) + u.tps_row1.z * x.z) + u.tps_row1.w,
        ((u.tps_row2.x * x.x + u.tps_row2.y * x.y) + u.tps_row2.z * x.z) + u.tps_row2.w,
    );
    for (var n = 0u; n < u.centre_count; n++) {
        let e = x - tps_terms[2u * n].xyz;
        let r = sqrt(e.x * e.x + (e.y * e.y + e.z * e.z));
        d += tps_terms[2u * n + 1u].xyz * r;
    }
    return d;
}

fn source_value(x: i32, y: i32, z: i32) -> f32 {
    let last = vec3<i32>(u.source_dims) - vec3<i32>(1);
    let q = clamp(vec3<i32>(x, y, z), vec3<i32>(0), last);
    switch SOURCE {
        case SOURCE_SINT: {
            return f32(textureLoad(source_sint, q, 0).r);
        }
        case SOURCE_UINT: {
            return f32(textureLoad(source_uint, q, 0).r);
        }
        default: {
            return textureLoad(source_float, q, 0).r;
        }
    }
}

// Catmull-Rom weights of the taps at −1, 0, 1, 2 for the fraction t ∈ [0, 1): (0, 1, 0, 0) at t = 0.
fn catmull_rom(t: f32) -> vec4<f32> {
    return vec4<f32>(
        t * (-0.5 + t * (1.0 - 0.5 * t)),
        1.0 + t * t * (-2.5 + 1.5 * t),
        t * (0.5 + t * (2.0 - 1.5 * t)),
        t * t * (-0.5 + 0.5 * t),
    );
}

fn weighted4(w: vec4<f32>, v: vec4<f32>) -> f32 {
    return ((w.x * v.x + w.y * v.y) + w.z * v.z) + w.w * v.w;
}

fn interpolate(s: vec3<f32>) -> f32 {
    if INTERPOLATION == INTERPOLATION_NEAREST {
        let q = vec3<i32>(floor(s + vec3<f32>(0.5)));
        return source_value(q.x, q.y, q.z);
    }
    let s0 = floor(s);
    let f = s - s0;
    let i0 = vec3<i32>(s0);
    if INTERPOLATION == INTERPOLATION_TRILINEAR {
        let i1 = i0 + vec3<i32>(1);
        let x00 = lerp1(source_value(i0.x, i0.y, i0.z), source_value(i1.x, i0.y, i0.z), f.x);
        let x10 = lerp1(source_value(i0.x, i1.y, i0.z), source_value(i1.x, i1.y, i0.z), f.x);
        let x01 = lerp1(source_value(i0.x, i0.y, i1.z), source_value(i1.x, i0.y, i1.z), f.x);
        let x11 = lerp1(source_value(i0.x, i1.y, i1.z), source_value(i1.x, i1.y, i1.z), f.x);
        return lerp1(lerp1(x00, x10, f.y), lerp1(x01, x11, f.y), f.z);
    }
    let wx = catmull_rom(f.x);
    let wy = catmull_rom(f.y);
    let wz = catmull_rom(f.z);
    var along_z = vec4<f32>(0.0);
    for (var c = 0; c < 4; c++) {
        var along_y = vec4<f32>(0.0);
        for (var b = 0; b < 4; b++) {
            let y = i0.y + b - 1;
            let z = i0.z + c - 1;
            along_y[b] = weighted4(
                wx,
                vec4<f32>(
                    source_value(i0.x - 1, y, z),
                    source_value(i0.x, y, z),
                    source_value(i0.x + 1, y, z),
                    source_value(i0.x + 2, y, z),
                ),
            );
        }
        along_z[c] = weighted4(wy, along_y);
    }
    return weighted4(wz, along_z);
}

// Output voxels per 32-bit word.
fn voxels_per_word() -> u32 {
    switch OUTPUT {
        case OUTPUT_U8, OUTPUT_I8: {
            return 4u;
        }
        case OUTPUT_U16, OUTPUT_I16: {
            return 2u;
        }
        default: {
            return 1u;
        }
    }
}

// An interpolated (finite, for integer outputs) value as the output stores it, in the low bits: rounded half to
// even (WGSL's round) and clamped to the type's range, the CPU path's `Sample::from_f64` of the same f32. The
// bounds of the 8- and 16-bit types are exact in f32; for 32-bit integers the upper bound is not, so values at or
// beyond 2³¹ (2³²) take the maximum explicitly.
fn stored(v: f32) -> u32 {
    let r = round(v);
    switch OUTPUT {
        case OUTPUT_U8: {
            return u32(clamp(r, 0.0, 255.0));
        }
        case OUTPUT_I8: {
            return bitcast<u32>(i32(clamp(r, -128.0, 127.0))) & 0xffu;
        }
        case OUTPUT_U16: {
            return u32(clamp(r, 0.0, 65535.0));
        }
        case OUTPUT_I16: {
            return bitcast<u32>(i32(clamp(r, -32768.0, 32767.0))) & 0xffffu;
        }
        case OUTPUT_U32: {
            if r >= 4294967296.0 {
                return 0xffffffffu;
            }
            return u32(max(r, 0.0));
        }
        case OUTPUT_I32: {
            if r >= 2147483648.0 {
                return 0x7fffffffu;
            }
            return bitcast<u32>(i32(max(r, -2147483648.0)));
        }
        default: {
            return bitcast<u32>(v);
        }
    }
}

// Target voxel `v` of the slab (x fastest), as stored.
fn voxel(v: u32) -> u32 {
    let dims = u.target_dims;
    let row = v / dims.x;
    let ijk = vec3<f32>(f32(v % dims.x), f32(row % dims.y), f32(u.slab_first_slice + row / dims.y));
    var s = affine(u.source_index_from_target_index, ijk);
    if PULLBACK != PULLBACK_IDENTITY {
        var d: vec3<f32>;
        if PULLBACK == PULLBACK_CONTROL {
            d = control_displacement(affine(u.pullback_from_target_index, ijk));
        } else {
            d = tps_displacement(affine(u.pullback_from_target_index, ijk));
        }
        let l = u.source_index_from_lps;
        s += (l[0].xyz * d.x + l[1].xyz * d.y) + l[2].xyz * d.z;
    }
    let n = vec3<f32>(u.source_dims);
    if all(s >= vec3<f32>(-0.5)) && all(s <= n - vec3<f32>(0.5)) {
        return stored(interpolate(s));
    }
    return u.outside_stored;
}

// One workgroup's stored voxels, packed into words by the first invocation of each word.
var<workgroup> stored_bits: array<u32, 64>;

@compute @workgroup_size(64, 1, 1)
fn cs_export(@builtin(global_invocation_id) id: vec3<u32>, @builtin(local_invocation_index) lane: u32) {
    // The slab's voxel of this invocation; a workgroup's 64 voxels start at a multiple of 64 (invocations_per_row
    // is a multiple of the workgroup size), so its words are whole.
    let v = id.x + id.y * u.invocations_per_row;
    var bits = 0u;
    if v < u.slab_voxels {
        bits = voxel(v);
    }
    let per_word = voxels_per_word();
    if per_word == 1u {
        if v < u.slab_voxels {
            slab[v] = bits;
        }
        return;
    }
    // 8- and 16-bit outputs: one voxel per invocation (as many in flight as for 32-bit ones), packed little-endian
    // through workgroup memory; voxels past the slab's end pack as 0 and are never read back.
    stored_bits[lane] = bits;
    workgroupBarrier();
    if lane % per_word == 0u && v < u.slab_voxels {
        let width = 32u / per_word;
        var packed = 0u;
        for (var p = 0u; p < per_word; p++) {
            packed |= stored_bits[lane + p] << (p * width);
        }
        slab[v / per_word] = packed;
    }
}
