// Ray casting of the fixed and the (deformed) moving volume together, in one compute pass: one invocation per pixel
// (cs_raycast, 8×8 pixels a workgroup), writing the image and the first-hit depth to storage textures. A compute
// shader rather than a fragment shader because data-centre GPUs run fragment shaders on a few of their processors
// only (an NVIDIA H200 gave the same per-pixel loop 1/26 of the throughput as a fragment shader); on desktop GPUs
// and CPU drivers the two run alike.
//
// Space names follow STYLE.md: `ref` is the shared render space (the fixed volume's LPS, mm), `lps` a
// volume's own patient space, `tex` [0,1]^3 texture coordinates, `ctrl_tex` the control texture's.
// Every sample x_ref is mapped through the volume's pull-back u (Brunet et al. 2006 §3.2):
//   u(x) = x + disp(ctrl_tex_from_ref · x)     (or u(x) = x on the identity fast path)
// then through the volume's procedural deformation p, computed here per sample (§3.3; crates/gpu/src/procedural.rs;
// the identity when its kind is PROCEDURAL_NONE), sampled at tex_from_lps · p(u(x)), classified with the volume's
// transfer function and blended. A view deformation w (a lens or widget, §5.2–5.3; crates/gpu/src/view_deformation.rs)
// acts before the pull-back: the sample is read at p(u(w(x))).
//
// Shading (Brunet et al. 2006 §3.4; Westermann & Rezk-Salama 2001 §3.3): the gradient at x_ref is the gradient of the
// deformed prefiltered copy v_pf, by the chain rule through Φ = p∘u∘w (warped_gradient_at):
//   ∇(v_pf∘Φ)(x) = J_Φ(x)ᵀ ∇v_pf(Φ(x)),   J_Φ column i = [Φ(x + h e_i) − Φ(x − h e_i)] / (2h)
// with ∇v_pf one hardware-filtered lookup of the copy's gradient texture (central differences per texel); without a
// copy, central differences of the volume through the warp, g_i = [v(Φ(x + h e_i)) − v(Φ(x − h e_i))] / (2h). Either
// way it is the gradient of the deformed volume, so the lighting follows the deformation. Headlight l = −ray direction:
//   colour' = clamp(colour·(ambient + diffuse·|n·l|) + specular·|n·l|^shininess, 0, 1),  n = g/|g|
// (|n·l| = 1 where |g| is ~0). DVR shades every sample with opacity > 0; iso mode finds, per volume, the first sample
// whose value ≥ iso_value, refines it by bisection between the last two samples, shades it opaque, and blends the two
// volumes' hits once by the blend mode.
//
// Slices (cs_slice, crates/gpu/src/slice.rs): one sample per pixel at x_ref = origin + (px + 1/2)·u + (py + 1/2)·v
// (ref_from_frag_px), the same warp, sampling, window and transfer function; each volume contributes its TF colour
// with opacity 1 inside its texture box (transparent outside); blended by the blend mode; no shading, no compositing.
//
// First hit (cs_raycast's second output, for depth-testing landmark glyphs, crates/gpu/src/glyph.rs): the NDC depth
// (0 near … 1 far) of the first sample where the accumulated opacity reaches HIT_OPACITY (DVR) or of the nearer
// iso-surface hit; NO_HIT_DEPTH where the ray hits nothing. A point at distance t along the ray (from the near-plane
// point o, direction r) has NDC depth z = t·n_w / (k − t·d_w), where n = ref_from_clip·(ndc, 0, 1), d =
// ref_from_clip·(ndc, 1, 1) − n and k = (d.xyz − o·d_w)·r: ref_from_clip is linear in homogeneous coordinates.
//
// The CPU reference in crates/gpu/src/cpu_reference.rs implements the same math: keep the two in sync.

// A deformation of a volume's data computed per sample (crates/gpu/src/procedural.rs gives the formulas). The Rust
// twin is `ProceduralUniforms` in crates/gpu/src/procedural.rs (tests/shaders.rs compares the layouts).
struct ProceduralUniforms {
    // sine: the origin o; twist, bend, bump: the centre c
    centre_mm: vec3<f32>,
    // PROCEDURAL_*
    kind: u32,
    // shift: the offset t; bump: the vector w
    vector_mm: vec3<f32>,
    // sine: A
    amplitude_mm: f32,
    // sine: k
    wavenumber_per_mm: vec3<f32>,
    // twist: rad/mm; bend: the curvature, 1/mm
    rate_per_mm: f32,
    // sine: φ
    phase_rad: vec3<f32>,
    // bump: σ
    sigma_mm: f32,
    // twist: the axis; bend: the axial axis
    axis: u32,
    // bend: the normal axis
    normal_axis: u32,
    // bend: ±1, the direction of n
    normal_sign: f32,
    _pad0: u32,
}

// A deformation of the view a volume is drawn through, applied to x_ref before its pull-back
// (crates/gpu/src/view_deformation.rs gives the formulas). The Rust twin is `ViewDeformationUniforms` in
// crates/gpu/src/view_deformation.rs (tests/shaders.rs compares the layouts).
struct ViewDeformationUniforms {
    // fish-eye: the lens's centre; leafer: a point of the hinge line
    centre_ref: vec3<f32>,
    // VIEW_*
    kind: u32,
    // leafer: the unit direction the book opens towards
    front: vec3<f32>,
    // fish-eye: R
    radius_mm: f32,
    // leafer: the cut plane's unit normal
    normal: vec3<f32>,
    // fish-eye: a; leafer: the opening θ, radians
    amplitude: f32,
}

// The Rust twin is `VolumeUniforms` in crates/gpu/src/raycast.rs (tests/shaders.rs compares the layouts).
struct VolumeUniforms {
    tex_from_lps: mat4x4<f32>,
    ctrl_tex_from_ref: mat4x4<f32>,
    // value = value_offset + value_scale * texel
    value_offset: f32,
    value_scale: f32,
    // TF coordinate = clamp((value - window_low) / window_width, 0, 1)
    window_low: f32,
    window_width: f32,
    // this volume's row in the transfer-function texture
    tf_row: u32,
    opacity_scale: f32,
    flags: u32,
    // iso-surface threshold, value units
    iso_value: f32,
    procedural: ProceduralUniforms,
    view: ViewDeformationUniforms,
}

// The Rust twin is `EmptySpaceUniforms` in crates/gpu/src/raycast.rs (tests/shaders.rs compares the layouts).
struct EmptySpaceUniforms {
    // ref-space corner of brick (0, 0, 0)
    min_ref: vec3<f32>,
    // 0: skip nothing (empty_space_tex is a placeholder)
    enabled: u32,
    dims: vec3<u32>,
    // brick edge, ref mm
    brick_mm: f32,
}

// The Rust twin is `RaycastUniforms` in crates/gpu/src/raycast.rs (tests/shaders.rs compares the layouts).
struct RaycastUniforms {
    ref_from_clip: mat4x4<f32>,
    box_min_ref: vec3<f32>,
    step_mm: f32,
    box_max_ref: vec3<f32>,
    ref_step_mm: f32,
    viewport_px: vec2<f32>,
    blend_mode: u32,
    flags: u32,
    blend_weight: f32,
    checker_cell_mm: f32,
    max_steps: u32,
    jitter_seed: u32,
    shading_mode: u32,
    bisection_steps: u32,
    // central-difference step h, ref mm
    gradient_step_mm: f32,
    ambient: f32,
    diffuse: f32,
    specular: f32,
    shininess: f32,
    _pad0: u32,
    fixed: VolumeUniforms,
    moving: VolumeUniforms,
    // Slices only: ref from framebuffer coordinates (pixel centres at i + 1/2).
    ref_from_frag_px: mat4x4<f32>,
    empty_space: EmptySpaceUniforms,
}

// VolumeUniforms.flags
const VOLUME_VISIBLE: u32 = 1u;
const VOLUME_HAS_WARP: u32 = 2u;
const VOLUME_MANUAL_FILTER: u32 = 4u;
const VOLUME_HAS_PREFILTER: u32 = 8u;

// ProceduralUniforms.kind
const PROCEDURAL_NONE: u32 = 0u;
const PROCEDURAL_SHIFT: u32 = 1u;
const PROCEDURAL_SINE: u32 = 2u;
const PROCEDURAL_TWIST: u32 = 3u;
const PROCEDURAL_BEND: u32 = 4u;
const PROCEDURAL_BUMP: u32 = 5u;

// ViewDeformationUniforms.kind
const VIEW_NONE: u32 = 0u;
const VIEW_FISH_EYE: u32 = 1u;
const VIEW_LEAFER: u32 = 2u;
// What a view deformation reads where it shows nothing (the leafer's opening): a point no volume contains.
const VIEW_EMPTY: f32 = -1.0e30;

// Which deformations computed in the shader a pipeline carries (DEFORM_* bits). The pipelines are specialised on it
// (crates/gpu/src/raycast.rs, RaycastUniforms::deformations): a frame without a procedural or a view deformation runs
// a pipeline that compiles none of their code. Every bit by default, for validation.
override DEFORMATIONS: u32 = 3u;
const DEFORM_PROCEDURAL: u32 = 1u;
const DEFORM_VIEW: u32 = 2u;

// RaycastUniforms.shading_mode. The pipeline is specialised on it: SHADING is set to the same value at pipeline
// creation, so each mode's pipeline compiles only its own code.
override SHADING: u32 = 0u;
const SHADING_NONE: u32 = 0u;
const SHADING_DVR: u32 = 1u;
const SHADING_ISO: u32 = 2u;

// What the frame's two volumes' flags have in common, which the raycast and slice pipelines are specialised on
// (crates/gpu/src/raycast.rs, LayerVariant): whether any volume is filtered by hand (VOLUME_MANUAL_FILTER), and whether
// every volume has a prefiltered copy (VOLUME_HAS_PREFILTER). A branch on a volume's flag that the variant settles is
// compiled out: a CPU driver runs both sides of a branch it cannot prove uniform, masked, so the hand filter and the
// gradients without a copy cost there even where no volume takes them. The defaults keep every branch (picks).
override ANY_MANUAL_FILTER: bool = true;
override ALL_PREFILTERED: bool = false;

// Below this squared gradient length (normalised texel units per mm) the normal is undefined: |n·l| = 1.
const MIN_GRADIENT_SQ: f32 = 1e-12;

// RaycastUniforms.flags
const RAYCAST_JITTER: u32 = 1u;
const RAYCAST_PREINTEGRATED: u32 = 2u;

// empty_space_tex cells: the volume may be non-transparent in the brick (crates/gpu/src/empty_space.rs).
const OCCUPIED_FIXED: u32 = 1u;
const OCCUPIED_MOVING: u32 = 2u;

// RaycastUniforms.blend_mode
const BLEND_MIX: u32 = 0u;
const BLEND_ADDITIVE: u32 = 1u;
const BLEND_DIFFERENCE: u32 = 2u;
const BLEND_CHECKERBOARD: u32 = 3u;
const BLEND_RED_CYAN: u32 = 4u;
const BLEND_FIXED_ONLY: u32 = 5u;
const BLEND_MOVING_ONLY: u32 = 6u;

const EARLY_EXIT_ALPHA: f32 = 0.99;
// `HIT_OPACITY` and `NO_HIT_DEPTH` in crates/gpu/src/target.rs (tests/shaders.rs compares the values).
const HIT_OPACITY: f32 = 0.5;
const NO_HIT_DEPTH: f32 = 2.0;

// The Rust code binds these through the `SLOT_*` constants of crates/gpu/src/raycast.rs
// (tests/shaders.rs compares the numbers).
@group(0) @binding(0) var<uniform> u: RaycastUniforms;
@group(0) @binding(1) var fixed_tex: texture_3d<f32>;
@group(0) @binding(2) var moving_tex: texture_3d<f32>;
@group(0) @binding(3) var fixed_ctrl_tex: texture_3d<f32>;
@group(0) @binding(4) var moving_ctrl_tex: texture_3d<f32>;
@group(0) @binding(5) var tf_tex: texture_2d<f32>;
// Trilinear (or nearest, on the manual-filter path), clamp-to-edge.
@group(0) @binding(6) var volume_sampler: sampler;
// Trilinear, clamp-to-edge: control textures.
@group(0) @binding(7) var linear_sampler: sampler;
// The gradients of the prefiltered copies (Rgba16Float, ∂v/∂tex per texel, crates/gpu/src/prefilter.rs; a 1×1×1
// placeholder without VOLUME_HAS_PREFILTER), filtered in hardware through linear_sampler.
@group(0) @binding(8) var fixed_grad_tex: texture_3d<f32>;
@group(0) @binding(9) var moving_grad_tex: texture_3d<f32>;
// Empty-space grid: one cell (OCCUPIED_* bits) per ref-space brick; a 1×1×1 "all occupied" placeholder when
// u.empty_space.enabled is 0.
@group(0) @binding(10) var empty_space_tex: texture_3d<u32>;
// Pre-integration tables (crates/gpu/src/transfer.rs, PreIntegrationTable): Rgba32Float 256×256, texel (front entry,
// back entry) the premultiplied colour and opacity of a segment one step long; 1×1 placeholders unless
// RAYCAST_PREINTEGRATED.
@group(0) @binding(11) var fixed_preint_tex: texture_2d<f32>;
@group(0) @binding(12) var moving_preint_tex: texture_2d<f32>;

// The pass's own bindings in group 1 (picking's are bindings 0–2 of the same group, crates/gpu/src/pick.rs): the band
// of rows a dispatch covers and the two images it writes. The Rust twin is `BandUniforms` in
// crates/gpu/src/raycast.rs (tests/shaders.rs compares the layouts).
struct BandUniforms {
    // The first row (from the top) of the band and the row after its last.
    first_row: u32,
    end_row: u32,
    _pad0: u32,
    _pad1: u32,
}

@group(1) @binding(3) var<uniform> band: BandUniforms;
// Premultiplied RGBA8 (crates/gpu/src/target.rs, RenderTarget::COLOUR_FORMAT).
@group(1) @binding(4) var out_colour: texture_storage_2d<rgba8unorm, write>;
// The first hit's NDC depth as f32 bits (RenderTarget::HIT_DEPTH_FORMAT), what the glyph pass depth-tests against.
@group(1) @binding(5) var out_hit_depth: texture_storage_2d<r32uint, write>;

// Pixels per workgroup along x and y (`WORKGROUP_EDGE` in crates/gpu/src/raycast.rs): 8×8 neighbouring rays, which
// march alike and stop at about the same sample.
const WORKGROUP_EDGE: u32 = 8u;

// The pixel of invocation `id` in the band, or false when it lies outside the image or the band.
fn band_pixel(id: vec3<u32>) -> vec3<u32> {
    let px = vec2<u32>(id.x, id.y + band.first_row);
    let inside = px.x < u32(u.viewport_px.x) && px.y < band.end_row;
    return vec3<u32>(px, select(0u, 1u, inside));
}

// PCG hash (Jarzynski & Olano 2020): a reproducible per-pixel jitter.
fn pcg_hash(v: u32) -> u32 {
    let state = v * 747796405u + 2891336453u;
    let word = ((state >> ((state >> 28u) + 4u)) ^ state) * 277803737u;
    return (word >> 22u) ^ word;
}

// Picks filter every lookup by hand (the pipeline sets EXACT_FILTER, crates/gpu/src/pick.rs): a device's hardware
// filter may round its weights to as little as 4 bits (Vulkan's subTexelPrecisionBits; 8 on NVIDIA), which moves a
// threshold crossing by a fraction of a voxel; by hand the weights are exact f32 on every device, so a pick lands
// where the CPU reference says. Frames filter in hardware.
override EXACT_FILTER: bool = false;

// Trilinear interpolation by hand (8 textureLoad), clamp-to-edge, texel centres at (i + ½)/n, exact f32 weights.
fn load_trilinear(vol: texture_3d<f32>, p_tex: vec3<f32>) -> vec4<f32> {
    let dims = vec3<i32>(textureDimensions(vol));
    let n = vec3<f32>(dims);
    let c = clamp(p_tex * n - vec3<f32>(0.5), vec3<f32>(0.0), n - vec3<f32>(1.0));
    let i0 = vec3<i32>(floor(c));
    let f = c - floor(c);
    let i1 = min(i0 + vec3<i32>(1), dims - vec3<i32>(1));
    let c000 = textureLoad(vol, vec3<i32>(i0.x, i0.y, i0.z), 0);
    let c100 = textureLoad(vol, vec3<i32>(i1.x, i0.y, i0.z), 0);
    let c010 = textureLoad(vol, vec3<i32>(i0.x, i1.y, i0.z), 0);
    let c110 = textureLoad(vol, vec3<i32>(i1.x, i1.y, i0.z), 0);
    let c001 = textureLoad(vol, vec3<i32>(i0.x, i0.y, i1.z), 0);
    let c101 = textureLoad(vol, vec3<i32>(i1.x, i0.y, i1.z), 0);
    let c011 = textureLoad(vol, vec3<i32>(i0.x, i1.y, i1.z), 0);
    let c111 = textureLoad(vol, vec3<i32>(i1.x, i1.y, i1.z), 0);
    let x00 = mix(c000, c100, f.x);
    let x10 = mix(c010, c110, f.x);
    let x01 = mix(c001, c101, f.x);
    let x11 = mix(c011, c111, f.x);
    return mix(mix(x00, x10, f.y), mix(x01, x11, f.y), f.z);
}

// A scalar volume filtered by hand: when its format is not filterable on this device, and in picks.
fn sample_manual(vol: texture_3d<f32>, p_tex: vec3<f32>) -> f32 {
    return load_trilinear(vol, p_tex).r;
}

// Empty-space skipping (crates/gpu/src/empty_space.rs). Sample k of the lattice t_k = t_enter + (k + jitter)·step
// lies at x_ref. When its brick is empty for every volume in `mask`, returns the index of the next sample to take:
// the last one before the brick's exit (at least k + 1, at most max_steps), so every skipped sample lies inside the
// brick (the grid's bricks are grown by a margin for the rounding) and those taken are the same as without
// skipping. Returns k when there is nothing to skip.
fn skip_empty(k: u32, x_ref: vec3<f32>, origin: vec3<f32>, dir: vec3<f32>, t_enter: f32, jitter: f32, mask: u32) -> u32 {
    let t_exit = empty_brick_exit(x_ref, origin, dir, mask);
    if t_exit < 0.0 {
        return k;
    }
    let k_last = floor((t_exit - t_enter) / u.step_mm - jitter);
    return u32(clamp(k_last, f32(k + 1u), f32(u.max_steps)));
}

// Pre-integration's skip: the index of the last lattice sample in sample k's brick when the brick is empty for every
// volume in `mask`, else k. The segments between samples k and that one lie in the brick, where every value a
// lookup can read has zero opacity, so each is exactly transparent (both ends' TF coordinates lie in the brick's
// zero-opacity range, and so does every entry the table integrated between them).
fn last_in_empty_brick(k: u32, x_ref: vec3<f32>, origin: vec3<f32>, dir: vec3<f32>, t_enter: f32, jitter: f32, mask: u32) -> u32 {
    let t_exit = empty_brick_exit(x_ref, origin, dir, mask);
    if t_exit < 0.0 {
        return k;
    }
    let k_last = floor((t_exit - t_enter) / u.step_mm - jitter);
    return u32(clamp(k_last, f32(k), f32(u.max_steps)));
}

// Where the ray origin + t·dir leaves the brick of x_ref, when that brick is empty for every volume in `mask`;
// -1 when it is not (or skipping is off, or x_ref is outside the grid).
fn empty_brick_exit(x_ref: vec3<f32>, origin: vec3<f32>, dir: vec3<f32>, mask: u32) -> f32 {
    let e = u.empty_space;
    if e.enabled == 0u {
        return -1.0;
    }
    let c = (x_ref - e.min_ref) / e.brick_mm;
    if any(c < vec3<f32>(0.0)) || any(c >= vec3<f32>(e.dims)) {
        return -1.0;
    }
    let b = vec3<i32>(floor(c));
    if (textureLoad(empty_space_tex, b, 0).r & mask) != 0u {
        return -1.0;
    }
    let lo = e.min_ref + vec3<f32>(b) * e.brick_mm;
    let exit_plane = select(lo, lo + vec3<f32>(e.brick_mm), dir > vec3<f32>(0.0));
    let crosses = abs(dir) > vec3<f32>(1e-20);
    let t_axis = select(vec3<f32>(3.0e38), (exit_plane - origin) / select(vec3<f32>(1.0), dir, crosses), crosses);
    return max(min(min(t_axis.x, t_axis.y), t_axis.z), 0.0);
}

// The displacement p(y) − y of a procedural deformation at y (the volume's LPS, mm); written as a displacement so
// that a zero amplitude adds exactly 0. The CPU twin is ProceduralUniforms::displacement (same order of operations).
fn procedural_displacement(q: ProceduralUniforms, y: vec3<f32>) -> vec3<f32> {
    switch q.kind {
        case PROCEDURAL_SHIFT: {
            return q.vector_mm;
        }
        case PROCEDURAL_SINE: {
            let r = y - q.centre_mm;
            let arg = q.wavenumber_per_mm * r.yzx + q.phase_rad;
            return q.amplitude_mm * sin(arg);
        }
        case PROCEDURAL_TWIST: {
            let a = q.axis % 3u;
            let ua = (a + 1u) % 3u;
            let va = (a + 2u) % 3u;
            let theta = q.rate_per_mm * (y[a] - q.centre_mm[a]);
            let du = y[ua] - q.centre_mm[ua];
            let dv = y[va] - q.centre_mm[va];
            let s = sin(theta);
            let half = sin(0.5 * theta);
            let cos_minus_one = -2.0 * half * half;
            var d = vec3<f32>(0.0);
            d[ua] = du * cos_minus_one - dv * s;
            d[va] = du * s + dv * cos_minus_one;
            return d;
        }
        case PROCEDURAL_BEND: {
            let k = q.rate_per_mm;
            if k == 0.0 {
                return vec3<f32>(0.0);
            }
            let a = q.axis % 3u;
            let b = q.normal_axis % 3u;
            let s = y[a] - q.centre_mm[a];
            let n = q.normal_sign * (y[b] - q.centre_mm[b]);
            let phi = k * s;
            let sn = sin(phi);
            let half = sin(0.5 * phi);
            let s1 = sn / k - n * sn;
            let n1 = 2.0 * half * half / k + n * cos(phi);
            var d = vec3<f32>(0.0);
            d[a] = s1 - s;
            d[b] = q.normal_sign * (n1 - n);
            return d;
        }
        case PROCEDURAL_BUMP: {
            let r = y - q.centre_mm;
            let g = exp(-dot(r, r) / (2.0 * q.sigma_mm * q.sigma_mm));
            return g * q.vector_mm;
        }
        default: {
            return vec3<f32>(0.0);
        }
    }
}

// w(x_ref): the view deformation the volume is drawn through (the identity for VIEW_NONE); written as displacements,
// so that a zero amplitude or angle leaves x exactly. The CPU twin is ViewDeformationUniforms::pullback.
fn view_pullback(w: ViewDeformationUniforms, x_ref: vec3<f32>) -> vec3<f32> {
    if w.kind == VIEW_FISH_EYE {
        let d = x_ref - w.centre_ref;
        let r = length(d);
        if r < w.radius_mm {
            let q = 1.0 - r / w.radius_mm;
            return x_ref - d * (w.amplitude * q * q);
        }
    } else if w.kind == VIEW_LEAFER {
        // (u, v) in the plane across the hinge; the n half (φ ≥ θ) turns back by −θ, the other by +θ, and the
        // opening between them shows nothing.
        let r = x_ref - w.centre_ref;
        let u = dot(r, w.front);
        let v = dot(r, w.normal);
        let theta = w.amplitude;
        let phi = atan2(v, u);
        if abs(phi) < theta {
            return vec3<f32>(VIEW_EMPTY);
        }
        var sigma = -1.0;
        if phi >= 0.0 {
            sigma = 1.0;
        }
        let s = sigma * sin(theta);
        let half = sin(0.5 * theta);
        let c1 = -2.0 * half * half;
        return x_ref + w.front * (u * c1 + v * s) + w.normal * (v * c1 - u * s);
    }
    return x_ref;
}

// u(w(x_ref)): ref point x_ref through the volume's view deformation, then its pull-back into the volume's LPS space
// (through its control texture when it has one). This is the point a landmark records (picking reports it); the
// data is read at p(u(w(x))).
fn pullback_lps(ctrl: texture_3d<f32>, v: VolumeUniforms, x_ref: vec3<f32>) -> vec3<f32> {
    var p_lps = x_ref;
    if (DEFORMATIONS & DEFORM_VIEW) != 0u && v.view.kind != VIEW_NONE {
        p_lps = view_pullback(v.view, x_ref);
    }
    if (v.flags & VOLUME_HAS_WARP) != 0u {
        let c_tex = (v.ctrl_tex_from_ref * vec4<f32>(p_lps, 1.0)).xyz;
        if EXACT_FILTER {
            p_lps = p_lps + load_trilinear(ctrl, c_tex).xyz;
        } else {
            p_lps = p_lps + textureSampleLevel(ctrl, linear_sampler, c_tex, 0.0).xyz;
        }
    }
    return p_lps;
}

// p(y): the volume's LPS point whose data its LPS point y shows, through its procedural deformation when it has one.
fn procedural_lps(v: VolumeUniforms, y_lps: vec3<f32>) -> vec3<f32> {
    if (DEFORMATIONS & DEFORM_PROCEDURAL) != 0u && v.procedural.kind != PROCEDURAL_NONE {
        return y_lps + procedural_displacement(v.procedural, y_lps);
    }
    return y_lps;
}

// tex(p(y)): the volume's texture coordinates of its LPS point y, through its procedural deformation when it has one.
fn data_tex(v: VolumeUniforms, y_lps: vec3<f32>) -> vec3<f32> {
    return (v.tex_from_lps * vec4<f32>(procedural_lps(v, y_lps), 1.0)).xyz;
}

// Φ(x_ref) = p(u(w(x_ref))): the volume's LPS point whose data ref point x_ref shows, through its view deformation,
// its warp and its procedural deformation when it has them.
fn data_lps(ctrl: texture_3d<f32>, v: VolumeUniforms, x_ref: vec3<f32>) -> vec3<f32> {
    return procedural_lps(v, pullback_lps(ctrl, v, x_ref));
}

// tex(Φ(x_ref)): the volume's texture coordinates of ref point x_ref.
fn warp_to_tex(ctrl: texture_3d<f32>, v: VolumeUniforms, x_ref: vec3<f32>) -> vec3<f32> {
    return (v.tex_from_lps * vec4<f32>(data_lps(ctrl, v, x_ref), 1.0)).xyz;
}

// Whether Φ is the identity for this volume: no warp, no view or procedural deformation.
fn undeformed(v: VolumeUniforms) -> bool {
    let view = (DEFORMATIONS & DEFORM_VIEW) != 0u && v.view.kind != VIEW_NONE;
    let procedural = (DEFORMATIONS & DEFORM_PROCEDURAL) != 0u && v.procedural.kind != PROCEDURAL_NONE;
    return (v.flags & VOLUME_HAS_WARP) == 0u && !view && !procedural;
}

fn outside_tex(p_tex: vec3<f32>) -> bool {
    return any(p_tex < vec3<f32>(0.0)) || any(p_tex > vec3<f32>(1.0));
}

// The volume's normalised texel at p_tex.
fn volume_texel(vol: texture_3d<f32>, v: VolumeUniforms, p_tex: vec3<f32>) -> f32 {
    if EXACT_FILTER || (ANY_MANUAL_FILTER && (v.flags & VOLUME_MANUAL_FILTER) != 0u) {
        return sample_manual(vol, p_tex);
    }
    return textureSampleLevel(vol, volume_sampler, p_tex, 0.0).r;
}

// The volume's value (value units) at p_tex.
fn volume_value(vol: texture_3d<f32>, v: VolumeUniforms, p_tex: vec3<f32>) -> f32 {
    return v.value_offset + v.value_scale * volume_texel(vol, v, p_tex);
}

// The gradient of the deformed volume at x_ref, ∇(v∘Φ)(x_ref), in normalised texel units per mm, whose data point
// Φ(x_ref) is y_lps (the caller has it from the value's lookup).
// With a prefiltered copy (VOLUME_HAS_PREFILTER): the chain rule, ∇(v∘Φ)(x) = J_Φ(x)ᵀ ∇v(Φ(x)). ∇v(y) is one
// hardware-filtered lookup of the copy's gradient texture (∂v/∂tex), taken to LPS by tex_from_lps: ∂v/∂y_b =
// Σ_a ∂tex_a/∂y_b · ∂v/∂tex_a. J_Φ is the identity for an undeformed volume, else central differences of Φ in ref
// space, column i = [Φ(x + h e_i) − Φ(x − h e_i)] / 2h (one-sided where an end shows nothing, as in the leafer's
// opening). So a lit sample costs 6 control-texture lookups and one gradient lookup on a warped volume, one gradient
// lookup on an undeformed one.
// Without a copy: central differences of the volume itself through the warp, g_i = [v(Φ(x + h e_i)) −
// v(Φ(x − h e_i))] / 2h.
fn warped_gradient_at(vol: texture_3d<f32>, ctrl: texture_3d<f32>, grad: texture_3d<f32>, v: VolumeUniforms, x_ref: vec3<f32>, y_lps: vec3<f32>) -> vec3<f32> {
    let h = u.gradient_step_mm;
    if !ALL_PREFILTERED && (v.flags & VOLUME_HAS_PREFILTER) == 0u {
        var g = vec3<f32>(0.0);
        for (var i = 0; i < 3; i++) {
            var e = vec3<f32>(0.0);
            e[i] = h;
            let plus = volume_texel(vol, v, warp_to_tex(ctrl, v, x_ref + e));
            let minus = volume_texel(vol, v, warp_to_tex(ctrl, v, x_ref - e));
            g[i] = (plus - minus) / (2.0 * h);
        }
        return g;
    }
    let p_tex = (v.tex_from_lps * vec4<f32>(y_lps, 1.0)).xyz;
    var g_tex: vec3<f32>;
    if EXACT_FILTER {
        g_tex = load_trilinear(grad, p_tex).xyz;
    } else {
        g_tex = textureSampleLevel(grad, linear_sampler, p_tex, 0.0).xyz;
    }
    let m = v.tex_from_lps;
    let g_lps = vec3<f32>(dot(m[0].xyz, g_tex), dot(m[1].xyz, g_tex), dot(m[2].xyz, g_tex));
    if undeformed(v) {
        return g_lps;
    }
    var g = vec3<f32>(0.0);
    for (var i = 0; i < 3; i++) {
        var e = vec3<f32>(0.0);
        e[i] = h;
        // An end in a view deformation's empty part (VIEW_EMPTY, kept by the warp's small displacement) is replaced
        // by x itself.
        let plus_w = pullback_lps(ctrl, v, x_ref + e);
        let minus_w = pullback_lps(ctrl, v, x_ref - e);
        var plus = y_lps;
        var minus = y_lps;
        var span = 0.0;
        if plus_w.x != VIEW_EMPTY {
            plus = procedural_lps(v, plus_w);
            span += h;
        }
        if minus_w.x != VIEW_EMPTY {
            minus = procedural_lps(v, minus_w);
            span += h;
        }
        if span > 0.0 {
            g[i] = dot(plus - minus, g_lps) / span;
        }
    }
    return g;
}

// warped_gradient_at x_ref, its data point looked up here.
fn warped_gradient(vol: texture_3d<f32>, ctrl: texture_3d<f32>, grad: texture_3d<f32>, v: VolumeUniforms, x_ref: vec3<f32>) -> vec3<f32> {
    return warped_gradient_at(vol, ctrl, grad, v, x_ref, data_lps(ctrl, v, x_ref));
}

// Headlight shading of a straight colour with gradient g; `light` is the unit vector towards the eye.
fn shade(rgb: vec3<f32>, g: vec3<f32>, light: vec3<f32>) -> vec3<f32> {
    let len_sq = dot(g, g);
    var n_dot_l = 1.0;
    if len_sq > MIN_GRADIENT_SQ {
        n_dot_l = abs(dot(g, light)) * inverseSqrt(len_sq);
    }
    n_dot_l = min(n_dot_l, 1.0);
    var spec = 0.0;
    if u.specular > 0.0 {
        // n·l^shininess, as exp2/log2 (pow(0, s) is undefined in WGSL).
        spec = u.specular * exp2(u.shininess * log2(max(n_dot_l, 1e-7)));
    }
    return clamp(rgb * (u.ambient + u.diffuse * n_dot_l) + vec3<f32>(spec), vec3<f32>(0.0), vec3<f32>(1.0));
}

// One volume's classified sample at x_ref: premultiplied RGBA, opacity-corrected for the step, lit in DVR mode.
// Transparent outside the volume's [0,1]^3 texture box.
fn classify(vol: texture_3d<f32>, ctrl: texture_3d<f32>, grad: texture_3d<f32>, v: VolumeUniforms, x_ref: vec3<f32>, step_ratio: f32, light: vec3<f32>) -> vec4<f32> {
    let y_lps = data_lps(ctrl, v, x_ref);
    let p_tex = (v.tex_from_lps * vec4<f32>(y_lps, 1.0)).xyz;
    if outside_tex(p_tex) {
        return vec4<f32>(0.0);
    }
    let value = volume_value(vol, v, p_tex);
    let t = clamp((value - v.window_low) / v.window_width, 0.0, 1.0);
    let rgba = sample_tf(v.tf_row, t);
    let alpha = clamp(rgba.a * v.opacity_scale, 0.0, 1.0);
    // Opacity correction: α' = 1 − (1 − α)^(step / ref_step).
    let alpha_corrected = 1.0 - exp2(step_ratio * log2(max(1.0 - alpha, 1e-7)));
    var rgb = rgba.rgb;
    if SHADING == SHADING_DVR && alpha_corrected > 0.0 {
        rgb = shade(rgb, warped_gradient_at(vol, ctrl, grad, v, x_ref, y_lps), light);
    }
    return vec4<f32>(rgb * alpha_corrected, alpha_corrected);
}

// Pre-integration (crates/gpu/src/transfer.rs): the TF coordinate of one volume at x_ref, or -1 outside its texture
// box (a segment with an end outside is transparent, as per-sample classification makes the sample there).
fn tf_coord_at(vol: texture_3d<f32>, ctrl: texture_3d<f32>, v: VolumeUniforms, x_ref: vec3<f32>) -> f32 {
    let p_tex = warp_to_tex(ctrl, v, x_ref);
    if outside_tex(p_tex) {
        return -1.0;
    }
    return clamp((volume_value(vol, v, p_tex) - v.window_low) / v.window_width, 0.0, 1.0);
}

// The table's premultiplied RGBA of the segment from TF coordinate t_front to t_back, bilinear between entries by
// hand (texel (i, j) at t = (i/255, j/255)), as sample_tf.
fn sample_preintegrated(table: texture_2d<f32>, t_front: f32, t_back: f32) -> vec4<f32> {
    let x = clamp(vec2<f32>(t_front, t_back), vec2<f32>(0.0), vec2<f32>(1.0)) * 255.0;
    let i0 = min(vec2<u32>(floor(x)), vec2<u32>(255u));
    let i1 = min(i0 + vec2<u32>(1u), vec2<u32>(255u));
    let f = x - vec2<f32>(i0);
    let a = textureLoad(table, vec2<u32>(i0.x, i0.y), 0);
    let b = textureLoad(table, vec2<u32>(i1.x, i0.y), 0);
    let c = textureLoad(table, vec2<u32>(i0.x, i1.y), 0);
    let d = textureLoad(table, vec2<u32>(i1.x, i1.y), 0);
    return mix(mix(a, b, f.x), mix(c, d, f.x), f.y);
}

// One volume's pre-integrated segment between TF coordinates t_front and t_back: premultiplied RGBA from its table,
// transparent when an end is outside the volume's box; in DVR mode the segment's straight colour C/α is lit with
// the gradient at x_shade (the segment's midpoint) and premultiplied again.
fn classify_segment(vol: texture_3d<f32>, ctrl: texture_3d<f32>, grad: texture_3d<f32>, table: texture_2d<f32>, v: VolumeUniforms, t_front: f32, t_back: f32, x_shade: vec3<f32>, light: vec3<f32>) -> vec4<f32> {
    if t_front < 0.0 || t_back < 0.0 {
        return vec4<f32>(0.0);
    }
    let c = sample_preintegrated(table, t_front, t_back);
    if SHADING == SHADING_DVR && c.a > 0.0 {
        let rgb = shade(c.rgb / c.a, warped_gradient(vol, ctrl, grad, v, x_shade), light);
        return vec4<f32>(rgb * c.a, c.a);
    }
    return c;
}

// The DVR march with pre-integrated classification: the same sample lattice as per-sample classification; sample
// k (k ≥ 1) closes the segment from sample k − 1, which is classified from the table of each volume, blended at its
// midpoint and composited "over" at sample k (its depth for the first hit). Empty bricks are jumped over as
// `last_in_empty_brick` says, the front of the next segment re-sampled where the jump lands, so the image is the
// same as without skipping.
fn march_preintegrated(near_h: vec4<f32>, far_h: vec4<f32>, origin: vec3<f32>, dir: vec3<f32>, t_enter: f32, t_far: f32, jitter: f32, use_fixed: bool, use_moving: bool, mask: u32, light: vec3<f32>) -> RaycastOutput {
    var acc = vec4<f32>(0.0);
    var hit_depth = NO_HIT_DEPTH;
    // The front sample's TF coordinates (-1: outside the volume's box).
    var front_f = -1.0;
    var front_m = -1.0;
    for (var k = 0u; k < u.max_steps; k++) {
        let t = t_enter + (f32(k) + jitter) * u.step_mm;
        if t >= t_far {
            break;
        }
        let x_ref = origin + t * dir;
        var back_f = -1.0;
        var back_m = -1.0;
        if use_fixed {
            back_f = tf_coord_at(fixed_tex, fixed_ctrl_tex, u.fixed, x_ref);
        }
        if use_moving {
            back_m = tf_coord_at(moving_tex, moving_ctrl_tex, u.moving, x_ref);
        }
        if k > 0u {
            let x_mid = x_ref - (0.5 * u.step_mm) * dir;
            var f = vec4<f32>(0.0);
            var m = vec4<f32>(0.0);
            if use_fixed {
                f = classify_segment(fixed_tex, fixed_ctrl_tex, fixed_grad_tex, fixed_preint_tex, u.fixed, front_f, back_f, x_mid, light);
            }
            if use_moving {
                m = classify_segment(moving_tex, moving_ctrl_tex, moving_grad_tex, moving_preint_tex, u.moving, front_m, back_m, x_mid, light);
            }
            let c = blend(f, m, x_mid);
            acc += (1.0 - acc.a) * c;
            if hit_depth == NO_HIT_DEPTH && acc.a >= HIT_OPACITY {
                hit_depth = ndc_depth(near_h, far_h, origin, dir, t);
            }
            if acc.a > EARLY_EXIT_ALPHA {
                break;
            }
        }
        front_f = back_f;
        front_m = back_m;
        let last = last_in_empty_brick(k, x_ref, origin, dir, t_enter, jitter, mask);
        if last > k {
            let x_last = origin + (t_enter + (f32(last) + jitter) * u.step_mm) * dir;
            if use_fixed {
                front_f = tf_coord_at(fixed_tex, fixed_ctrl_tex, u.fixed, x_last);
            }
            if use_moving {
                front_m = tf_coord_at(moving_tex, moving_ctrl_tex, u.moving, x_last);
            }
            k = last;
        }
    }
    return RaycastOutput(acc, bitcast<u32>(hit_depth));
}

// The value at x_ref, or -inf outside the volume's texture box (never a hit).
fn iso_value_at(vol: texture_3d<f32>, ctrl: texture_3d<f32>, v: VolumeUniforms, x_ref: vec3<f32>) -> f32 {
    let p_tex = warp_to_tex(ctrl, v, x_ref);
    if outside_tex(p_tex) {
        return -3.4e38;
    }
    return volume_value(vol, v, p_tex);
}

// Iso mode: the ray parameter of the first point with value ≥ iso_value (the first such sample, refined by bisection
// between it and the previous sample), or -1 without a hit.
fn iso_hit(vol: texture_3d<f32>, ctrl: texture_3d<f32>, v: VolumeUniforms, origin: vec3<f32>, dir: vec3<f32>, t_enter: f32, t_far: f32, jitter: f32) -> f32 {
    var t_prev = -1.0;
    for (var k = 0u; k < u.max_steps; k++) {
        let t = t_enter + (f32(k) + jitter) * u.step_mm;
        if t >= t_far {
            break;
        }
        if iso_value_at(vol, ctrl, v, origin + t * dir) >= v.iso_value {
            if t_prev < 0.0 {
                return t;
            }
            var lo = t_prev;
            var hi = t;
            for (var b = 0u; b < u.bisection_steps; b++) {
                let mid = 0.5 * (lo + hi);
                if iso_value_at(vol, ctrl, v, origin + mid * dir) >= v.iso_value {
                    hi = mid;
                } else {
                    lo = mid;
                }
            }
            return 0.5 * (lo + hi);
        }
        t_prev = t;
    }
    return -1.0;
}

// Iso mode: the lit, opaque colour (premultiplied, α = 1) of a hit at x_ref: the TF colour of the value there.
fn iso_colour(vol: texture_3d<f32>, ctrl: texture_3d<f32>, grad: texture_3d<f32>, v: VolumeUniforms, x_ref: vec3<f32>, light: vec3<f32>) -> vec4<f32> {
    let p_tex = warp_to_tex(ctrl, v, x_ref);
    let value = volume_value(vol, v, p_tex);
    let t = clamp((value - v.window_low) / v.window_width, 0.0, 1.0);
    let rgb = shade(sample_tf(v.tf_row, t).rgb, warped_gradient(vol, ctrl, grad, v, x_ref), light);
    return vec4<f32>(rgb, 1.0);
}

// Linear interpolation between the 256 entries of row `row` (entry i at t = i/255), done by hand with two
// textureLoad: the sampler's filtering weights have as little as 8 bits on some devices (lavapipe), which biases
// low opacities that are composited ~100 times; by hand the result is exact f32 on every device.
fn sample_tf(row: u32, t: f32) -> vec4<f32> {
    let x = clamp(t, 0.0, 1.0) * 255.0;
    let i0 = min(u32(floor(x)), 255u);
    let i1 = min(i0 + 1u, 255u);
    let f = x - f32(i0);
    let a = textureLoad(tf_tex, vec2<u32>(i0, row), 0);
    let b = textureLoad(tf_tex, vec2<u32>(i1, row), 0);
    return mix(a, b, f);
}

fn luminance(c: vec3<f32>) -> f32 {
    return dot(c, vec3<f32>(0.2126, 0.7152, 0.0722));
}

fn is_visible(v: VolumeUniforms) -> bool {
    return (v.flags & VOLUME_VISIBLE) != 0u;
}

// Combines the two premultiplied samples by the blend mode (premultiplied out).
fn blend(f: vec4<f32>, m: vec4<f32>, x_ref: vec3<f32>) -> vec4<f32> {
    switch u.blend_mode {
        case BLEND_ADDITIVE: {
            return min(f + m, vec4<f32>(1.0));
        }
        case BLEND_DIFFERENCE: {
            return vec4<f32>(abs(f.rgb - m.rgb), max(f.a, m.a));
        }
        case BLEND_CHECKERBOARD: {
            let cell = vec3<i32>(floor(x_ref / u.checker_cell_mm));
            if ((cell.x + cell.y + cell.z) & 1) == 0 {
                return f;
            }
            return m;
        }
        case BLEND_RED_CYAN: {
            let lf = luminance(f.rgb);
            let lm = luminance(m.rgb);
            return vec4<f32>(lf, lm, lm, 1.0 - (1.0 - f.a) * (1.0 - m.a));
        }
        case BLEND_FIXED_ONLY: {
            return f;
        }
        case BLEND_MOVING_ONLY: {
            return m;
        }
        default: {
            return mix(f, m, u.blend_weight);
        }
    }
}

// The ray's span through the proxy box by the slab test: (t_enter, t_far), t_enter clamped to the ray's start at
// 0 (the near plane); empty where t_far ≤ t_enter. The frame and both picking marches enter the box the same way.
fn proxy_box_span(origin: vec3<f32>, dir: vec3<f32>) -> vec2<f32> {
    let inv_dir = 1.0 / dir;
    let t0 = (u.box_min_ref - origin) * inv_dir;
    let t1 = (u.box_max_ref - origin) * inv_dir;
    let t_near = max(max(min(t0.x, t1.x), min(t0.y, t1.y)), min(t0.z, t1.z));
    let t_far = min(min(max(t0.x, t1.x), max(t0.y, t1.y)), max(t0.z, t1.z));
    return vec2<f32>(max(t_near, 0.0), t_far);
}

struct RaycastOutput {
    colour: vec4<f32>,
    // The f32 depth's bits, as out_hit_depth stores them.
    hit_depth: u32,
}

fn no_hit(colour: vec4<f32>) -> RaycastOutput {
    return RaycastOutput(colour, bitcast<u32>(NO_HIT_DEPTH));
}

// The NDC depth of the point at distance t along the pixel's ray (see the header).
fn ndc_depth(near_h: vec4<f32>, far_h: vec4<f32>, origin_ref: vec3<f32>, dir_ref: vec3<f32>, t: f32) -> f32 {
    let d = far_h - near_h;
    let k = dot(d.xyz - origin_ref * d.w, dir_ref);
    return t * near_h.w / (k - t * d.w);
}

@compute @workgroup_size(WORKGROUP_EDGE, WORKGROUP_EDGE)
fn cs_raycast(@builtin(global_invocation_id) id: vec3<u32>) {
    let px = band_pixel(id);
    if px.z == 0u {
        return;
    }
    let out = raycast_pixel(px.xy);
    textureStore(out_colour, px.xy, out.colour);
    textureStore(out_hit_depth, px.xy, vec4<u32>(out.hit_depth, 0u, 0u, 0u));
}

// The colour and first hit of pixel `px` (its centre at px + ½, y down).
fn raycast_pixel(px: vec2<u32>) -> RaycastOutput {
    // Pixel centre → NDC (y up) → a ray in ref space between the near and the far plane.
    let centre = vec2<f32>(px) + vec2<f32>(0.5);
    let ndc = vec2<f32>(centre.x / u.viewport_px.x * 2.0 - 1.0, 1.0 - centre.y / u.viewport_px.y * 2.0);
    let near_h = u.ref_from_clip * vec4<f32>(ndc, 0.0, 1.0);
    let far_h = u.ref_from_clip * vec4<f32>(ndc, 1.0, 1.0);
    let origin_ref = near_h.xyz / near_h.w;
    let dir_ref = normalize(far_h.xyz / far_h.w - origin_ref);

    let span = proxy_box_span(origin_ref, dir_ref);
    let t_enter = span.x;
    let t_far = span.y;
    if t_far <= t_enter {
        return no_hit(vec4<f32>(0.0));
    }

    var jitter = 0.0;
    if (u.flags & RAYCAST_JITTER) != 0u {
        let h = pcg_hash(px.x + pcg_hash(px.y + pcg_hash(u.jitter_seed)));
        jitter = f32(h >> 8u) / 16777216.0;
    }

    let step_ratio = u.step_mm / u.ref_step_mm;
    let use_fixed = is_visible(u.fixed) && u.blend_mode != BLEND_MOVING_ONLY;
    let use_moving = is_visible(u.moving) && u.blend_mode != BLEND_FIXED_ONLY;
    let light = -dir_ref;

    if SHADING == SHADING_ISO {
        var t_f = -1.0;
        var t_m = -1.0;
        if use_fixed {
            t_f = iso_hit(fixed_tex, fixed_ctrl_tex, u.fixed, origin_ref, dir_ref, t_enter, t_far, jitter);
        }
        if use_moving {
            t_m = iso_hit(moving_tex, moving_ctrl_tex, u.moving, origin_ref, dir_ref, t_enter, t_far, jitter);
        }
        if t_f < 0.0 && t_m < 0.0 {
            return no_hit(vec4<f32>(0.0));
        }
        var f = vec4<f32>(0.0);
        var m = vec4<f32>(0.0);
        // The checkerboard picks its cell at the nearer hit.
        var t_near_hit = t_f;
        if t_f >= 0.0 {
            f = iso_colour(fixed_tex, fixed_ctrl_tex, fixed_grad_tex, u.fixed, origin_ref + t_f * dir_ref, light);
        }
        if t_m >= 0.0 {
            m = iso_colour(moving_tex, moving_ctrl_tex, moving_grad_tex, u.moving, origin_ref + t_m * dir_ref, light);
            if t_f < 0.0 || t_m < t_f {
                t_near_hit = t_m;
            }
        }
        let colour = blend(f, m, origin_ref + t_near_hit * dir_ref);
        return RaycastOutput(colour, bitcast<u32>(ndc_depth(near_h, far_h, origin_ref, dir_ref, t_near_hit)));
    }

    var acc = vec4<f32>(0.0);
    var hit_depth = NO_HIT_DEPTH;
    var mask = 0u;
    if use_fixed {
        mask |= OCCUPIED_FIXED;
    }
    if use_moving {
        mask |= OCCUPIED_MOVING;
    }
    if (u.flags & RAYCAST_PREINTEGRATED) != 0u {
        return march_preintegrated(near_h, far_h, origin_ref, dir_ref, t_enter, t_far, jitter, use_fixed, use_moving, mask, light);
    }
    for (var k = 0u; k < u.max_steps; k++) {
        let t = t_enter + (f32(k) + jitter) * u.step_mm;
        if t >= t_far {
            break;
        }
        let x_ref = origin_ref + t * dir_ref;
        // Samples in empty bricks would add premultiplied zero: jump over them, staying on the lattice.
        let next = skip_empty(k, x_ref, origin_ref, dir_ref, t_enter, jitter, mask);
        if next > k {
            k = next - 1u;
            continue;
        }
        var f = vec4<f32>(0.0);
        var m = vec4<f32>(0.0);
        if use_fixed {
            f = classify(fixed_tex, fixed_ctrl_tex, fixed_grad_tex, u.fixed, x_ref, step_ratio, light);
        }
        if use_moving {
            m = classify(moving_tex, moving_ctrl_tex, moving_grad_tex, u.moving, x_ref, step_ratio, light);
        }
        let c = blend(f, m, x_ref);
        // Front-to-back "over" compositing of premultiplied colour.
        acc += (1.0 - acc.a) * c;
        if hit_depth == NO_HIT_DEPTH && acc.a >= HIT_OPACITY {
            hit_depth = ndc_depth(near_h, far_h, origin_ref, dir_ref, t);
        }
        if acc.a > EARLY_EXIT_ALPHA {
            break;
        }
    }
    return RaycastOutput(acc, bitcast<u32>(hit_depth));
}

// Slices: one volume's TF colour at x_ref, opaque inside the volume's texture box, transparent outside.
fn slice_sample(vol: texture_3d<f32>, ctrl: texture_3d<f32>, v: VolumeUniforms, x_ref: vec3<f32>) -> vec4<f32> {
    let p_tex = warp_to_tex(ctrl, v, x_ref);
    if outside_tex(p_tex) {
        return vec4<f32>(0.0);
    }
    let value = volume_value(vol, v, p_tex);
    let t = clamp((value - v.window_low) / v.window_width, 0.0, 1.0);
    return vec4<f32>(sample_tf(v.tf_row, t).rgb, 1.0);
}

@compute @workgroup_size(WORKGROUP_EDGE, WORKGROUP_EDGE)
fn cs_slice(@builtin(global_invocation_id) id: vec3<u32>) {
    let px = band_pixel(id);
    if px.z == 0u {
        return;
    }
    textureStore(out_colour, px.xy, slice_pixel(px.xy));
}

// The slice's colour at pixel `px` (its centre at px + ½).
fn slice_pixel(px: vec2<u32>) -> vec4<f32> {
    let centre = vec2<f32>(px) + vec2<f32>(0.5);
    let x_ref = (u.ref_from_frag_px * vec4<f32>(centre, 0.0, 1.0)).xyz;
    var f = vec4<f32>(0.0);
    var m = vec4<f32>(0.0);
    if is_visible(u.fixed) && u.blend_mode != BLEND_MOVING_ONLY {
        f = slice_sample(fixed_tex, fixed_ctrl_tex, u.fixed, x_ref);
    }
    if is_visible(u.moving) && u.blend_mode != BLEND_FIXED_ONLY {
        m = slice_sample(moving_tex, moving_ctrl_tex, u.moving, x_ref);
    }
    return blend(f, m, x_ref);
}

// Ray picking (crates/gpu/src/pick.rs; Brunet et al. 2006 §4.1, §5.1): a compute entry point over the same bindings,
// so that a pick marches exactly the samples the frame shows. One invocation per ray, in ref space, through the
// proxy box, at the frame's step, without jitter, through the target volume's pull-back. Probes (per sample s, the
// target volume's uncorrected TF opacity α(s) = TF(value)·opacity_scale, its deformed-space gradient g(s) in value
// units per mm):
//   PROBE_OPACITY:     α(s) ≥ threshold;
//   PROBE_GRADIENT:    |g(s)| ≥ threshold;
//   PROBE_ACCUMULATED: A(s) ≥ threshold, the target volume's front-to-back accumulated opacity, with the partial
//                      step A(s) = A_prev + (1 − A_prev)·(1 − (1 − α(s))^((s − t_prev)/ref_step)) inside the last step.
// The first sample that satisfies the probe is refined by `bisection_steps` bisections between it and the previous
// sample. The hit reports x_ref, its distance along the ray, the pull-back u(x_ref) in the volume's LPS space and the
// value there. The CPU reference is `cpu_reference::pick`.

// The Rust twin is `PickUniforms` in crates/gpu/src/pick.rs (tests/shaders.rs compares the layouts).
struct PickUniforms {
    probe: u32,
    target_volume: u32,
    threshold: f32,
    ray_count: u32,
    bisection_steps: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

// The Rust twin is `PickRay` in crates/gpu/src/pick.rs (tests/shaders.rs compares the layouts).
struct PickRay {
    origin_ref: vec3<f32>,
    _pad0: f32,
    dir_ref: vec3<f32>,
    _pad1: f32,
}

// The Rust twin is `PickHit` in crates/gpu/src/pick.rs (tests/shaders.rs compares the layouts).
struct PickHit {
    x_ref: vec3<f32>,
    t_mm: f32,
    p_lps: vec3<f32>,
    value: f32,
    hit: u32,
    target_volume: u32,
    _pad0: u32,
    _pad1: u32,
}

const PROBE_OPACITY: u32 = 0u;
const PROBE_GRADIENT: u32 = 1u;
const PROBE_ACCUMULATED: u32 = 2u;
const TARGET_FIXED: u32 = 0u;

// Bound through the `SLOT_*` constants of crates/gpu/src/pick.rs (tests/shaders.rs compares the numbers).
@group(1) @binding(0) var<uniform> pick: PickUniforms;
@group(1) @binding(1) var<storage, read> pick_rays: array<PickRay>;
@group(1) @binding(2) var<storage, read_write> pick_hits: array<PickHit>;

// The target volume's uncorrected opacity at x_ref (0 outside its texture box).
fn pick_alpha(vol: texture_3d<f32>, ctrl: texture_3d<f32>, v: VolumeUniforms, x_ref: vec3<f32>) -> f32 {
    let p_tex = warp_to_tex(ctrl, v, x_ref);
    if outside_tex(p_tex) {
        return 0.0;
    }
    let t = clamp((volume_value(vol, v, p_tex) - v.window_low) / v.window_width, 0.0, 1.0);
    return clamp(sample_tf(v.tf_row, t).a * v.opacity_scale, 0.0, 1.0);
}

// The probe's quantity at x_ref (opacity, or gradient magnitude in value units per mm); the accumulated probe uses
// the opacity and composites it in cs_pick.
fn pick_quantity(vol: texture_3d<f32>, ctrl: texture_3d<f32>, grad: texture_3d<f32>, v: VolumeUniforms, x_ref: vec3<f32>) -> f32 {
    if pick.probe == PROBE_GRADIENT {
        if outside_tex(warp_to_tex(ctrl, v, x_ref)) {
            return 0.0;
        }
        return abs(v.value_scale) * length(warped_gradient(vol, ctrl, grad, v, x_ref));
    }
    return pick_alpha(vol, ctrl, v, x_ref);
}

// Opacity accumulated over a partial step of `len_mm` at opacity α, on top of `acc`.
fn accumulate(acc: f32, alpha: f32, len_mm: f32) -> f32 {
    return acc + (1.0 - acc) * (1.0 - exp2(len_mm / u.ref_step_mm * log2(max(1.0 - alpha, 1e-7))));
}

fn pick_march(vol: texture_3d<f32>, ctrl: texture_3d<f32>, grad: texture_3d<f32>, v: VolumeUniforms, ray: PickRay) -> PickHit {
    var out: PickHit;
    out.hit = 0u;
    out.target_volume = pick.target_volume;
    let origin = ray.origin_ref;
    let dir = ray.dir_ref;
    let span = proxy_box_span(origin, dir);
    let t_enter = span.x;
    let t_far = span.y;
    if !(t_far > t_enter) {
        return out;
    }
    var t_prev = -1.0;
    var acc = 0.0;
    // Empty-space skipping as the frame does, in the target volume's bricks: where its opacity is zero, neither the
    // opacity nor the accumulated probe (threshold > 0) can fire and the accumulated opacity does not change. The
    // gradient probe does not depend on the transfer function and skips nothing.
    var mask = OCCUPIED_MOVING;
    if pick.target_volume == TARGET_FIXED {
        mask = OCCUPIED_FIXED;
    }
    let may_skip = pick.probe != PROBE_GRADIENT && pick.threshold > 0.0;
    for (var k = 0u; k < u.max_steps; k++) {
        let t = t_enter + f32(k) * u.step_mm;
        if t >= t_far {
            break;
        }
        if may_skip {
            let next = skip_empty(k, origin + t * dir, origin, dir, t_enter, 0.0, mask);
            if next > k {
                // The previous sample for the bisection is the last one skipped, as without skipping.
                t_prev = t_enter + f32(next - 1u) * u.step_mm;
                k = next - 1u;
                continue;
            }
        }
        let q = pick_quantity(vol, ctrl, grad, v, origin + t * dir);
        var found = false;
        if pick.probe == PROBE_ACCUMULATED {
            found = accumulate(acc, q, u.step_mm) >= pick.threshold;
        } else {
            found = q >= pick.threshold;
        }
        if found {
            var t_hit = t;
            var t_inside = t;
            if t_prev >= 0.0 {
                var lo = t_prev;
                var hi = t;
                for (var b = 0u; b < pick.bisection_steps; b++) {
                    let mid = 0.5 * (lo + hi);
                    let qm = pick_quantity(vol, ctrl, grad, v, origin + mid * dir);
                    var inside = false;
                    if pick.probe == PROBE_ACCUMULATED {
                        inside = accumulate(acc, qm, mid - t_prev) >= pick.threshold;
                    } else {
                        inside = qm >= pick.threshold;
                    }
                    if inside {
                        hi = mid;
                    } else {
                        lo = mid;
                    }
                }
                t_hit = 0.5 * (lo + hi);
                t_inside = hi;
            }
            return pick_hit_at(vol, ctrl, v, origin, dir, t_hit, t_inside);
        }
        if pick.probe == PROBE_ACCUMULATED {
            acc = accumulate(acc, q, u.step_mm);
        }
        t_prev = t;
    }
    return out;
}

// PROBE_ACCUMULATED when the frame pre-integrates (RAYCAST_PREINTEGRATED): the frame's own compositing, segment by
// segment. Sample k (k ≥ 1) closes the segment from sample k − 1 with the table's opacity α(s_{k−1}, s_k), so
// A(s_k) = A_prev + (1 − A_prev)·α(s_{k−1}, s_k); inside the segment that first reaches the level, the partial
// segment from t_prev to s has A(s) = A_prev + (1 − A_prev)·(1 − (1 − α(s_{k−1}, s(s)))^((s − t_prev)/step)): the
// table's segment is one step long, and a segment's optical depth scales with its length for the same values. The
// same samples, bisection and empty-space jumps as the frame (`march_preintegrated`).
fn pick_march_preintegrated(vol: texture_3d<f32>, ctrl: texture_3d<f32>, table: texture_2d<f32>, v: VolumeUniforms, ray: PickRay) -> PickHit {
    var out: PickHit;
    out.hit = 0u;
    out.target_volume = pick.target_volume;
    let origin = ray.origin_ref;
    let dir = ray.dir_ref;
    let span = proxy_box_span(origin, dir);
    let t_enter = span.x;
    let t_far = span.y;
    if !(t_far > t_enter) {
        return out;
    }
    var mask = OCCUPIED_MOVING;
    if pick.target_volume == TARGET_FIXED {
        mask = OCCUPIED_FIXED;
    }
    let may_skip = pick.threshold > 0.0;
    var acc = 0.0;
    var t_prev = t_enter;
    var front = -1.0;
    for (var k = 0u; k < u.max_steps; k++) {
        let t = t_enter + f32(k) * u.step_mm;
        if t >= t_far {
            break;
        }
        let back = tf_coord_at(vol, ctrl, v, origin + t * dir);
        if k > 0u {
            var alpha = 0.0;
            if front >= 0.0 && back >= 0.0 {
                alpha = sample_preintegrated(table, front, back).a;
            }
            if acc + (1.0 - acc) * alpha >= pick.threshold {
                var lo = t_prev;
                var hi = t;
                for (var b = 0u; b < pick.bisection_steps; b++) {
                    let mid = 0.5 * (lo + hi);
                    let s_mid = tf_coord_at(vol, ctrl, v, origin + mid * dir);
                    var alpha_part = 0.0;
                    if front >= 0.0 && s_mid >= 0.0 {
                        let a = sample_preintegrated(table, front, s_mid).a;
                        alpha_part = 1.0 - exp2((mid - t_prev) / u.step_mm * log2(max(1.0 - a, 1e-7)));
                    }
                    if acc + (1.0 - acc) * alpha_part >= pick.threshold {
                        hi = mid;
                    } else {
                        lo = mid;
                    }
                }
                return pick_hit_at(vol, ctrl, v, origin, dir, 0.5 * (lo + hi), hi);
            }
            acc += (1.0 - acc) * alpha;
        }
        front = back;
        t_prev = t;
        if may_skip {
            let last = last_in_empty_brick(k, origin + t * dir, origin, dir, t_enter, 0.0, mask);
            if last > k {
                t_prev = t_enter + f32(last) * u.step_mm;
                front = tf_coord_at(vol, ctrl, v, origin + t_prev * dir);
                k = last;
            }
        }
    }
    return out;
}

// The hit at t_hit along the ray: x_ref, its pull-back u(w(x_ref)) into the volume's LPS space and the value there
// (read at p(u(w(x_ref))) under a procedural deformation). t_inside is the nearest point known to satisfy the probe
// (the bisection's upper end): where a view deformation shows nothing at t_hit (the leafer's opening, whose edge is a
// face of the volume) the hit is reported there instead, on the face.
fn pick_hit_at(vol: texture_3d<f32>, ctrl: texture_3d<f32>, v: VolumeUniforms, origin: vec3<f32>, dir: vec3<f32>, t_hit: f32, t_inside: f32) -> PickHit {
    var out: PickHit;
    var t = t_hit;
    if (DEFORMATIONS & DEFORM_VIEW) != 0u && v.view.kind != VIEW_NONE && view_pullback(v.view, origin + t_hit * dir).x == VIEW_EMPTY {
        t = t_inside;
    }
    let x_ref = origin + t * dir;
    let p_lps = pullback_lps(ctrl, v, x_ref);
    out.hit = 1u;
    out.target_volume = pick.target_volume;
    out.x_ref = x_ref;
    out.t_mm = t;
    out.p_lps = p_lps;
    out.value = volume_value(vol, v, data_tex(v, p_lps));
    return out;
}

@compute @workgroup_size(64)
fn cs_pick(@builtin(global_invocation_id) id: vec3<u32>) {
    let i = id.x;
    if i >= pick.ray_count {
        return;
    }
    let ray = pick_rays[i];
    if (u.flags & RAYCAST_PREINTEGRATED) != 0u && pick.probe == PROBE_ACCUMULATED {
        if pick.target_volume == TARGET_FIXED {
            pick_hits[i] = pick_march_preintegrated(fixed_tex, fixed_ctrl_tex, fixed_preint_tex, u.fixed, ray);
        } else {
            pick_hits[i] = pick_march_preintegrated(moving_tex, moving_ctrl_tex, moving_preint_tex, u.moving, ray);
        }
        return;
    }
    if pick.target_volume == TARGET_FIXED {
        pick_hits[i] = pick_march(fixed_tex, fixed_ctrl_tex, fixed_grad_tex, u.fixed, ray);
    } else {
        pick_hits[i] = pick_march(moving_tex, moving_ctrl_tex, moving_grad_tex, u.moving, ray);
    }
}
