// Landmark glyphs: points (discs with a dark rim) and lines (between the points of a pair), drawn over a ray-cast
// frame or a slice. See crates/gpu/src/glyph.rs for the conventions; the CPU reference is
// `cpu_reference::composite_glyphs`: keep the two in sync.
//
// Each instance is a capsule in screen space: the pixels within radius_px of the projected segment [a, b] (a = b
// for a point). Coverage = clamp(radius_px + ½ − dist_px, 0, 1), a one-pixel anti-aliased edge. One quad per
// instance, the capsule's box grown by one pixel, so every covered pixel centre lies inside it.
//
// 3-D view (mode 0): a glyph fragment at NDC depth z_g (affine in screen space along a projected segment) is compared
// with the ray caster's first-hit depth z_h at its pixel. Both are converted to distances along the pixel's ray,
// t(z) = |x_ref(z) − x_ref(0)| with x_ref(z) = ref_from_clip·(ndc, z, 1); the fragment is behind when
// t(z_g) > t(z_h) + depth_tolerance_mm, and its opacity is then multiplied by occluded_alpha (0 hides it).
//
// Slice (mode 1): the segment is clipped to the slab |n·x − plane_offset_mm| ≤ slab_half_mm around the plane and
// projected onto it; a point at distance d from the plane is drawn with radius radius_px·√(1 − (d/slab_half_mm)²),
// the cross-section of a ball, so it shrinks away from its slice and vanishes beyond the slab.

// The Rust twin is `GlyphUniforms` in crates/gpu/src/glyph.rs (tests/shaders.rs compares the layouts).
struct GlyphUniforms {
    clip_from_ref: mat4x4<f32>,
    ref_from_clip: mat4x4<f32>,
    plane_normal_ref: vec3<f32>,
    plane_offset_mm: f32,
    viewport_px: vec2<f32>,
    mode: u32,
    occluded_alpha: f32,
    depth_tolerance_mm: f32,
    slab_half_mm: f32,
    outline_px: f32,
    _pad0: f32,
}

const MODE_VIEW: u32 = 0u;
const MODE_SLICE: u32 = 1u;
const KIND_POINT: u32 = 0u;
// `NO_HIT_DEPTH` in crates/gpu/src/target.rs (tests/shaders.rs compares the values).
const NO_HIT_DEPTH: f32 = 2.0;

// The Rust code binds these through the `SLOT_*` constants of crates/gpu/src/glyph.rs
// (tests/shaders.rs compares the numbers).
@group(0) @binding(0) var<uniform> g: GlyphUniforms;
// The ray caster's first-hit NDC depth (f32 bits in R32Uint; a 1×1 NO_HIT_DEPTH placeholder for slices).
@group(0) @binding(1) var hit_depth_tex: texture_2d<u32>;

// The Rust twin is `GlyphInstance` in crates/gpu/src/glyph.rs, a per-instance vertex buffer (tests/shaders.rs
// compares the layouts).
struct GlyphInstance {
    @location(0) a_ref: vec3<f32>,
    @location(1) radius_px: f32,
    @location(2) b_ref: vec3<f32>,
    @location(3) kind: u32,
    @location(4) colour: vec4<f32>,
}

struct GlyphVarying {
    @builtin(position) position: vec4<f32>,
    // Projected end points (framebuffer px) and their NDC depths.
    @location(0) @interpolate(flat) a_px: vec2<f32>,
    @location(1) @interpolate(flat) b_px: vec2<f32>,
    @location(2) @interpolate(flat) depths: vec2<f32>,
    @location(3) @interpolate(flat) radius_px: f32,
    @location(4) @interpolate(flat) kind: u32,
    @location(5) @interpolate(flat) colour: vec4<f32>,
}

// Framebuffer pixel (y down) and NDC depth of a ref point; w ≤ 0 (behind a perspective eye) gives z < 0.
fn project(p_ref: vec3<f32>) -> vec3<f32> {
    let clip = g.clip_from_ref * vec4<f32>(p_ref, 1.0);
    if clip.w <= 0.0 {
        return vec3<f32>(0.0, 0.0, -1.0);
    }
    let ndc = clip.xyz / clip.w;
    return vec3<f32>((ndc.x + 1.0) * 0.5 * g.viewport_px.x, (1.0 - ndc.y) * 0.5 * g.viewport_px.y, ndc.z);
}

fn culled() -> GlyphVarying {
    var out: GlyphVarying;
    out.position = vec4<f32>(2.0, 2.0, 2.0, 1.0);
    return out;
}

@vertex
fn vs_glyph(@builtin(vertex_index) vertex_index: u32, inst: GlyphInstance) -> GlyphVarying {
    var a = inst.a_ref;
    var b = inst.b_ref;
    var radius = inst.radius_px;
    if g.mode == MODE_SLICE {
        let da = dot(g.plane_normal_ref, a) - g.plane_offset_mm;
        let db = dot(g.plane_normal_ref, b) - g.plane_offset_mm;
        if inst.kind == KIND_POINT {
            let q = da / g.slab_half_mm;
            if abs(q) > 1.0 {
                return culled();
            }
            radius *= sqrt(1.0 - q * q);
        } else {
            // Clip s ∈ [0, 1] of a + s(b − a) to |da + s(db − da)| ≤ slab_half_mm.
            var s0 = 0.0;
            var s1 = 1.0;
            let dd = db - da;
            if abs(dd) < 1e-12 {
                if abs(da) > g.slab_half_mm {
                    return culled();
                }
            } else {
                let s_lo = (-g.slab_half_mm - da) / dd;
                let s_hi = (g.slab_half_mm - da) / dd;
                s0 = max(s0, min(s_lo, s_hi));
                s1 = min(s1, max(s_lo, s_hi));
                if s0 > s1 {
                    return culled();
                }
            }
            let e = inst.b_ref - inst.a_ref;
            a = inst.a_ref + s0 * e;
            b = inst.a_ref + s1 * e;
        }
    }
    let pa = project(a);
    let pb = project(b);
    if pa.z < 0.0 || pb.z < 0.0 || radius <= 0.0 {
        return culled();
    }
    let e = pb.xy - pa.xy;
    let len = length(e);
    var dir = vec2<f32>(1.0, 0.0);
    if len > 1e-6 {
        dir = e / len;
    }
    let nrm = vec2<f32>(-dir.y, dir.x);
    let r = radius + 1.0;
    // Two triangles: corners (end, side) = (0,-1) (1,-1) (1,1), (0,-1) (1,1) (0,1).
    let ends = array<f32, 6>(0.0, 1.0, 1.0, 0.0, 1.0, 0.0);
    let sides = array<f32, 6>(-1.0, -1.0, 1.0, -1.0, 1.0, 1.0);
    let end = ends[vertex_index % 6u];
    let side = sides[vertex_index % 6u];
    let corner = mix(pa.xy - dir * r, pb.xy + dir * r, end) + nrm * side * r;

    var out: GlyphVarying;
    out.position = vec4<f32>(corner.x / g.viewport_px.x * 2.0 - 1.0, 1.0 - corner.y / g.viewport_px.y * 2.0, 0.5, 1.0);
    out.a_px = pa.xy;
    out.b_px = pb.xy;
    out.depths = vec2<f32>(pa.z, pb.z);
    out.radius_px = radius;
    out.kind = inst.kind;
    out.colour = inst.colour;
    return out;
}

// Distance along the pixel's ray (ref mm, from the near plane) of NDC depth z.
fn ray_distance(ndc_xy: vec2<f32>, z: f32) -> f32 {
    let near_h = g.ref_from_clip * vec4<f32>(ndc_xy, 0.0, 1.0);
    let p_h = g.ref_from_clip * vec4<f32>(ndc_xy, z, 1.0);
    return distance(p_h.xyz / p_h.w, near_h.xyz / near_h.w);
}

@fragment
fn fs_glyph(in: GlyphVarying) -> @location(0) vec4<f32> {
    let p = in.position.xy;
    let e = in.b_px - in.a_px;
    let len_sq = dot(e, e);
    var s = 0.0;
    if len_sq > 1e-12 {
        s = clamp(dot(p - in.a_px, e) / len_sq, 0.0, 1.0);
    }
    let dist = distance(p, in.a_px + s * e);
    let coverage = clamp(in.radius_px + 0.5 - dist, 0.0, 1.0);
    if coverage <= 0.0 {
        discard;
    }
    var rgb = in.colour.rgb;
    if in.kind == KIND_POINT {
        // A dark rim outline_px wide, anti-aliased like the edge.
        let rim = clamp(dist - (in.radius_px - g.outline_px) + 0.5, 0.0, 1.0);
        rgb = mix(rgb, vec3<f32>(0.0), rim);
    }
    var alpha = in.colour.a * coverage;
    if g.mode == MODE_VIEW {
        // Clamped: the 1×1 placeholder (no frame underneath) reads as no hit everywhere.
        let texel = min(vec2<u32>(p), textureDimensions(hit_depth_tex) - vec2<u32>(1u));
        let hit = bitcast<f32>(textureLoad(hit_depth_tex, texel, 0).r);
        if hit <= 1.0 {
            let ndc_xy = vec2<f32>(p.x / g.viewport_px.x * 2.0 - 1.0, 1.0 - p.y / g.viewport_px.y * 2.0);
            let z = mix(in.depths.x, in.depths.y, s);
            if ray_distance(ndc_xy, z) > ray_distance(ndc_xy, hit) + g.depth_tolerance_mm {
                alpha *= g.occluded_alpha;
            }
        }
    }
    if alpha <= 0.0 {
        discard;
    }
    return vec4<f32>(rgb * alpha, alpha);
}
