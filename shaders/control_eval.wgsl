// Control textures evaluated on the GPU (Brunet, Nowak & Gleicher 2006 §3.3): the displacement of a pull-back,
// disp(x) = u(x) − x, at the centre of every texel (a, b, c) of a control grid, x = min + ((a, b, c) + ½)·pitch.
//
// cs_tps:     disp(o + x′) = (A − I) x′ + (A o + b − o) + Σᵢ wᵢ ‖x′ − (pᵢ − o)‖   (TPS pull-back, U(r) = r, about an
//             origin o; Davis 1997), with x′ = first_local + (a, b, c)·pitch_mm.
// cs_bspline: disp(x) = Σ_ℓ D_ℓ(clamp(x, Ω_ℓ)), D_ℓ the cubic B-spline of lattice ℓ (Lee, Wolberg & Shin 1997
//             eq. 1): in cell units u = (x − Ω.min)/h, i = min(⌊u⌋, cells − 1), s = u − i,
//             D = Σ_{a,b,c=0..3} B_a(s) B_b(t) B_c(r) φ[i+a, j+b, k+c] (storage index 0 = paper index −1).
//
// The result goes to a storage buffer laid out as a texture copy wants it (rows of `row_stride_texels` texels, a
// multiple of 256 bytes), as 4 f32 words per texel (Rgba32Float) or 2 words of packed halves (Rgba16Float); the host
// then copies the buffer into the 3-D control texture. (wgpu's GL backend binds a 3-D storage texture as one layer,
// so a storage texture would lose every slice but the first there.)
//
// Each workgroup also reduces, over its texels as stored, the componentwise min and max of the displacement, the
// largest f16 rounding error and a non-finite flag, and merges them into `bounds` with one atomic per value. Floats
// are merged as u32 through the order-preserving map `ordered` (negative: all bits flipped; positive: sign bit set).
//
// The host code is crates/gpu/src/control_eval.rs; its f64 references are `TpsDesc::eval` and `BSplineDesc::eval` in
// crates/gpu/src/pullback.rs. Keep them in sync.

// The Rust twin is `ControlEvalUniforms` in crates/gpu/src/control_eval.rs (tests/shaders.rs compares the layouts).
struct ControlEvalUniforms {
    // control texels per axis
    dims: vec3<u32>,
    // texels per row of the output buffer (256-byte rows)
    row_stride_texels: u32,
    // TPS: centre of texel (0, 0, 0) minus the origin o, mm
    first_local: vec3<f32>,
    // 1: store f16 halves (Rgba16Float), 0: f32 (Rgba32Float)
    store_f16: u32,
    // texel pitch, mm
    pitch_mm: vec3<f32>,
    // TPS: number of centres; B-spline: number of lattices
    count: u32,
    // TPS: A o + b − o, mm
    offset_mm: vec3<f32>,
    _pad0: u32,
    // TPS: A − I
    linear_minus_identity: mat3x3<f32>,
}

// One TPS centre: pᵢ − o (xyz, mm) and wᵢ (xyz); w components unused.
struct Centre {
    p_local: vec4<f32>,
    w: vec4<f32>,
}

// The Rust twin is `LatticeUniforms` in crates/gpu/src/control_eval.rs (tests/shaders.rs compares the layouts).
struct LatticeUniforms {
    // u (cell units, (x − Ω.min)/h) at the centre of texel (0, 0, 0)
    first_cell: vec3<f32>,
    // first coefficient of this lattice in `coefficients`
    coef_offset: u32,
    // u per texel: pitch / h
    cell_step: vec3<f32>,
    _pad0: u32,
    // cells per axis; the lattice has cells + 3 control points per axis
    cells: vec3<u32>,
    _pad1: u32,
}

// The Rust twin is `BSplineUniforms` in crates/gpu/src/control_eval.rs, `MAX_LATTICES` long (tests/shaders.rs
// compares the layouts).
struct BSplineUniforms {
    lattices: array<LatticeUniforms, 8>,
}

// Indices into `bounds`.
const MIN_X: u32 = 0u;
const MAX_X: u32 = 3u;
const QUANTISATION: u32 = 6u;
const NON_FINITE: u32 = 7u;
const WORKGROUP: u32 = 64u;
const F16_MAX: f32 = 65504.0;

// The Rust code binds these through the `SLOT_*` constants of crates/gpu/src/control_eval.rs
// (tests/shaders.rs compares the numbers).
@group(0) @binding(0) var<uniform> p: ControlEvalUniforms;
@group(0) @binding(1) var<storage, read_write> out_words: array<u32>;
@group(0) @binding(2) var<storage, read_write> bounds: array<atomic<u32>, 8>;
@group(0) @binding(3) var<storage, read> centres: array<Centre>;
@group(0) @binding(4) var<uniform> bs: BSplineUniforms;
@group(0) @binding(5) var<storage, read> coefficients: array<f32>;

// Per workgroup: xyz = min displacement, w = largest rounding error (lo); xyz = max displacement, w = non-finite (hi).
var<workgroup> wg_lo: array<vec4<f32>, WORKGROUP>;
var<workgroup> wg_hi: array<vec4<f32>, WORKGROUP>;

// An order-preserving map of f32 to u32 (for finite values and infinities).
fn ordered(x: f32) -> u32 {
    let bits = bitcast<u32>(x);
    return select(bits | 0x80000000u, ~bits, (bits & 0x80000000u) != 0u);
}

fn is_finite3(d: vec3<f32>) -> bool {
    // By the bits: WGSL lets implementations assume that NaN and infinity never occur in float comparisons.
    let e = vec3<u32>(0x7f800000u);
    return all((bitcast<vec3<u32>>(d) & e) != e);
}

// f16_bits and f16_value are in shaders/f16.wgsl, appended to this file.

// Stores the displacement of texel `id` and returns it as stored (rounded to f16 when storing halves), with the
// rounding error in w.
fn store(id: vec3<u32>, d: vec3<f32>) -> vec4<f32> {
    let texel = id.x + p.row_stride_texels * (id.y + p.dims.y * id.z);
    if p.store_f16 != 0u {
        let h = vec3<u32>(f16_bits(d.x), f16_bits(d.y), f16_bits(d.z));
        out_words[2u * texel] = h.x | (h.y << 16u);
        out_words[2u * texel + 1u] = h.z;
        let stored = vec3<f32>(f16_value(h.x), f16_value(h.y), f16_value(h.z));
        let err = abs(stored - d);
        return vec4<f32>(stored, max(err.x, max(err.y, err.z)));
    }
    out_words[4u * texel] = bitcast<u32>(d.x);
    out_words[4u * texel + 1u] = bitcast<u32>(d.y);
    out_words[4u * texel + 2u] = bitcast<u32>(d.z);
    out_words[4u * texel + 3u] = 0u;
    return vec4<f32>(d, 0.0);
}

// Stores texel `id` (when `inside`) and merges its bounds into `bounds` (every invocation must call this: barriers).
fn finish(id: vec3<u32>, local_index: u32, inside: bool, d: vec3<f32>) {
    var lo = vec4<f32>(3.0e38, 3.0e38, 3.0e38, 0.0);
    var hi = vec4<f32>(-3.0e38, -3.0e38, -3.0e38, 0.0);
    if inside {
        let finite = is_finite3(d) && (p.store_f16 == 0u || all(abs(d) <= vec3<f32>(F16_MAX)));
        if finite {
            let s = store(id, d);
            lo = s;
            hi = vec4<f32>(s.xyz, 0.0);
        } else {
            _ = store(id, vec3<f32>(0.0));
            hi.w = 1.0;
        }
    }
    wg_lo[local_index] = lo;
    wg_hi[local_index] = hi;
    for (var stride = WORKGROUP / 2u; stride > 0u; stride >>= 1u) {
        workgroupBarrier();
        if local_index < stride {
            let a = wg_lo[local_index];
            let b = wg_lo[local_index + stride];
            wg_lo[local_index] = vec4<f32>(min(a.xyz, b.xyz), max(a.w, b.w));
            wg_hi[local_index] = max(wg_hi[local_index], wg_hi[local_index + stride]);
        }
    }
    workgroupBarrier();
    if local_index == 0u {
        let l = wg_lo[0];
        let h = wg_hi[0];
        for (var c = 0u; c < 3u; c++) {
            atomicMin(&bounds[MIN_X + c], ordered(l[c]));
            atomicMax(&bounds[MAX_X + c], ordered(h[c]));
        }
        // Non-negative floats order as their bits.
        atomicMax(&bounds[QUANTISATION], bitcast<u32>(l.w));
        if h.w != 0.0 {
            atomicMax(&bounds[NON_FINITE], 1u);
        }
    }
}

@compute @workgroup_size(8, 8, 1)
fn cs_tps(@builtin(global_invocation_id) id: vec3<u32>, @builtin(local_invocation_index) local_index: u32) {
    let inside = all(id < p.dims);
    var d = vec3<f32>(0.0);
    if inside {
        let x = p.first_local + vec3<f32>(id) * p.pitch_mm;
        d = p.linear_minus_identity * x + p.offset_mm;
        for (var i = 0u; i < p.count; i++) {
            let c = centres[i];
            d += c.w.xyz * length(x - c.p_local.xyz);
        }
    }
    finish(id, local_index, inside, d);
}

// The uniform cubic B-spline basis B₀..B₃ at t ∈ [0, 1].
fn basis(t: f32) -> vec4<f32> {
    let u = 1.0 - t;
    let t2 = t * t;
    let t3 = t2 * t;
    return vec4<f32>(u * u * u, 3.0 * t3 - 6.0 * t2 + 4.0, -3.0 * t3 + 3.0 * t2 + 3.0 * t + 1.0, t3) / 6.0;
}

fn lattice_displacement(l: LatticeUniforms, id: vec3<u32>) -> vec3<f32> {
    let cells = vec3<f32>(l.cells);
    let u = clamp(l.first_cell + vec3<f32>(id) * l.cell_step, vec3<f32>(0.0), cells);
    let i = min(vec3<u32>(floor(u)), l.cells - vec3<u32>(1u));
    let s = u - vec3<f32>(i);
    let bx = basis(s.x);
    let by = basis(s.y);
    let bz = basis(s.z);
    let n = l.cells + vec3<u32>(3u);
    var d = vec3<f32>(0.0);
    for (var c = 0u; c < 4u; c++) {
        for (var b = 0u; b < 4u; b++) {
            let wzy = bz[c] * by[b];
            let row = l.coef_offset + 3u * (((i.z + c) * n.y + i.y + b) * n.x + i.x);
            for (var a = 0u; a < 4u; a++) {
                let k = row + 3u * a;
                d += (wzy * bx[a]) * vec3<f32>(coefficients[k], coefficients[k + 1u], coefficients[k + 2u]);
            }
        }
    }
    return d;
}

@compute @workgroup_size(8, 8, 1)
fn cs_bspline(@builtin(global_invocation_id) id: vec3<u32>, @builtin(local_invocation_index) local_index: u32) {
    let inside = all(id < p.dims);
    var d = vec3<f32>(0.0);
    if inside {
        for (var l = 0u; l < p.count; l++) {
            d += lattice_displacement(bs.lattices[l], id);
        }
    }
    finish(id, local_index, inside, d);
}
