// The per-sample work of an intensity registration under a cubic B-spline free-form deformation (the solver's
// `register` module), on the GPU.
//
// cs_values:   for each fixed sample s at continuous image index ξ_s, with its lattice footprint (first control
//              point i_s and basis weights B per axis), the displacement D = Σ_{a,b,c=0..3} Bx_a By_b Bz_c φ[i_s +
//              (a, b, c)] (mm), the displaced index η = ξ_s + A·D (A = ∂index/∂mm), and the trilinear value v(η) and
//              its gradient Aᵀ ∇_η v (per mm). NaN where η leaves [0, dims − 1] (beyond EDGE_TOLERANCE) or a corner is
//              not finite. One invocation per sample.
// cs_gradient: for each control point k, G_k = Σ_s w_s B_k(x_s) ∇v(η_s) over the samples whose footprint holds k (w_s
//              given per sample; a sample with w_s = 0 is skipped, so NaN gradients outside never enter). The samples
//              are sorted by their first control point (their "bucket"), so k reads the 4 × 4 × 4 buckets
//              i_s ∈ [k − 3, k] in a fixed order: no atomics, the same bits on every run. One invocation per control
//              point.
//
// The trilinear rule is the solver's `Image::sample_with_gradient` (cell = ⌊η⌋ clamped so that the last plane
// belongs to the cell below it), in f32. The host code is crates/gpu/src/ffd_samples.rs; keep them in sync.

// The Rust twin is `FfdUniforms` in crates/gpu/src/ffd_samples.rs (tests/shaders.rs compares the layouts).
struct FfdUniforms {
    // image voxels per axis
    image_dims: vec3<u32>,
    // samples
    sample_count: u32,
    // control points per axis
    lattice_dims: vec3<u32>,
    // invocations per row of a dispatch (workgroups in x × 64): index = x + y · row_invocations
    row_invocations: u32,
    // first-control-point positions per axis (lattice_dims − 3)
    buckets: vec3<u32>,
    // control points in all
    control_points: u32,
    // ∂index/∂mm
    index_from_mm: mat3x3<f32>,
}

// The Rust twin is `FfdSample` in crates/gpu/src/ffd_samples.rs.
struct FfdSample {
    // continuous image index of the undisplaced sample
    index: vec3<f32>,
    // first control point, linearised over `buckets` (x fastest)
    bucket: u32,
    // basis weights per axis, B_0..B_3
    weights: array<vec4<f32>, 3>,
}

@group(0) @binding(0) var<uniform> p: FfdUniforms;
@group(0) @binding(1) var image: texture_3d<f32>;
@group(0) @binding(2) var<storage, read> samples: array<FfdSample>;
// bucket b's samples are samples[bucket_starts[b] .. bucket_starts[b + 1]]
@group(0) @binding(3) var<storage, read> bucket_starts: array<u32>;
// 3 per control point, x fastest
@group(0) @binding(4) var<storage, read> phi: array<f32>;
// per sample: (value, gradient per mm)
@group(0) @binding(5) var<storage, read_write> hits: array<vec4<f32>>;
// per sample: the value alone (the host reads it back)
@group(0) @binding(6) var<storage, read_write> values: array<f32>;
// per sample: w_s
@group(0) @binding(7) var<storage, read> sample_weights: array<f32>;
// 3 per control point
@group(0) @binding(8) var<storage, read_write> gradient: array<f32>;

// Index tolerance of the image's edge (the solver's EDGE_TOLERANCE_VOX).
const EDGE_TOLERANCE: f32 = 1e-6;
const WORKGROUP: u32 = 64u;

fn nan() -> f32 {
    // A quiet NaN built at run time (a constant NaN may be folded away).
    return bitcast<f32>(0x7fc00000u);
}

fn voxel(i: vec3<u32>) -> f32 {
    return textureLoad(image, vec3<i32>(i), 0).x;
}

@compute @workgroup_size(64, 1, 1)
fn cs_values(@builtin(global_invocation_id) gid: vec3<u32>) {
    let s = gid.x + gid.y * p.row_invocations;
    if s >= p.sample_count {
        return;
    }
    let sample = samples[s];
    let nb = p.buckets;
    let first = vec3<u32>(sample.bucket % nb.x, (sample.bucket / nb.x) % nb.y, sample.bucket / (nb.x * nb.y));
    let nl = p.lattice_dims;
    var d = vec3<f32>(0.0);
    for (var c = 0u; c < 4u; c++) {
        for (var b = 0u; b < 4u; b++) {
            let wzy = sample.weights[2][c] * sample.weights[1][b];
            let row = ((first.z + c) * nl.y + first.y + b) * nl.x + first.x;
            for (var a = 0u; a < 4u; a++) {
                let w = wzy * sample.weights[0][a];
                let o = 3u * (row + a);
                d += w * vec3<f32>(phi[o], phi[o + 1u], phi[o + 2u]);
            }
        }
    }
    let eta = sample.index + p.index_from_mm * d;
    let top = vec3<f32>(p.image_dims - vec3<u32>(1u));
    if any(eta < vec3<f32>(-EDGE_TOLERANCE)) || any(eta > top + vec3<f32>(EDGE_TOLERANCE)) || any(eta != eta) {
        hits[s] = vec4<f32>(nan());
        values[s] = nan();
        return;
    }
    let x = clamp(eta, vec3<f32>(0.0), top);
    let base = min(vec3<u32>(floor(x)), p.image_dims - vec3<u32>(2u));
    let f = x - vec3<f32>(base);
    let c000 = voxel(base);
    let c100 = voxel(base + vec3<u32>(1u, 0u, 0u));
    let c010 = voxel(base + vec3<u32>(0u, 1u, 0u));
    let c110 = voxel(base + vec3<u32>(1u, 1u, 0u));
    let c001 = voxel(base + vec3<u32>(0u, 0u, 1u));
    let c101 = voxel(base + vec3<u32>(1u, 0u, 1u));
    let c011 = voxel(base + vec3<u32>(0u, 1u, 1u));
    let c111 = voxel(base + vec3<u32>(1u, 1u, 1u));
    // The solver's Lerps: along i, then j, then k.
    let x00 = c000 + f.x * (c100 - c000);
    let x10 = c010 + f.x * (c110 - c010);
    let x01 = c001 + f.x * (c101 - c001);
    let x11 = c011 + f.x * (c111 - c011);
    let y0 = x00 + f.y * (x10 - x00);
    let y1 = x01 + f.y * (x11 - x01);
    let value = y0 + f.z * (y1 - y0);
    let d00 = c100 - c000;
    let d10 = c110 - c010;
    let d01 = c101 - c001;
    let d11 = c111 - c011;
    let e0 = d00 + f.y * (d10 - d00);
    let e1 = d01 + f.y * (d11 - d01);
    let di = e0 + f.z * (e1 - e0);
    let dj = (x10 - x00) + f.z * ((x11 - x01) - (x10 - x00));
    let dk = y1 - y0;
    let g = transpose(p.index_from_mm) * vec3<f32>(di, dj, dk);
    let hit = vec4<f32>(value, g);
    // Finite iff no component is NaN or infinite: x − x is 0 only for finite x.
    if any((hit - hit) != vec4<f32>(0.0)) {
        hits[s] = vec4<f32>(nan());
        values[s] = nan();
        return;
    }
    hits[s] = hit;
    values[s] = value;
}

@compute @workgroup_size(64, 1, 1)
fn cs_gradient(@builtin(global_invocation_id) gid: vec3<u32>) {
    let k = gid.x + gid.y * p.row_invocations;
    if k >= p.control_points {
        return;
    }
    let nl = p.lattice_dims;
    let nb = p.buckets;
    let point = vec3<u32>(k % nl.x, (k / nl.x) % nl.y, k / (nl.x * nl.y));
    // Buckets i with i ≤ point ≤ i + 3, inside [0, nb − 1].
    let lo = max(vec3<i32>(point) - vec3<i32>(3), vec3<i32>(0));
    let hi = min(point, nb - vec3<u32>(1u));
    var acc = vec3<f32>(0.0);
    for (var bz = u32(lo.z); bz <= hi.z; bz++) {
        for (var by = u32(lo.y); by <= hi.y; by++) {
            for (var bx = u32(lo.x); bx <= hi.x; bx++) {
                let bucket = (bz * nb.y + by) * nb.x + bx;
                let offset = point - vec3<u32>(bx, by, bz);
                for (var s = bucket_starts[bucket]; s < bucket_starts[bucket + 1u]; s++) {
                    let w = sample_weights[s];
                    if w == 0.0 {
                        continue;
                    }
                    let weights = samples[s].weights;
                    let basis = weights[0][offset.x] * weights[1][offset.y] * weights[2][offset.z];
                    acc += (w * basis) * hits[s].yzw;
                }
            }
        }
    }
    gradient[3u * k] = acc.x;
    gradient[3u * k + 1u] = acc.y;
    gradient[3u * k + 2u] = acc.z;
}
