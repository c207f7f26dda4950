//! Landmark glyphs ([`warpbench_gpu::glyph`]) and the ray caster's first-hit depth they are tested against.
//!
//! The scene is an analytic ball: a 32³ f32 volume of spacing 2 mm whose value is the signed distance R − |x| (mm)
//! to a sphere of radius R = 20 mm, classified by a step transfer function (opaque from v ≈ 0), so that the first
//! hit is the sphere's surface.
//!
//! Tolerances:
//! - Hit depth vs the analytic sphere: the hit is the first sample whose accumulated opacity reaches ½. The first
//!   sample inside can be partly transparent (the step TF is 5 LUT entries wide, and opacity is corrected to the
//!   0.5 mm step), so the hit lies at most two steps past the surface; trilinear interpolation of R − |x| moves the
//!   surface inwards by < h²/(8R) = 0.025 mm. Bound: [t_surface − 0.05, t_surface + 2·step + 0.05] mm.
//! - GPU vs CPU hit depth: the same samples, so equal to f32 noise (1e-3 mm) except where the GPU's sampler and the
//!   CPU disagree on which side of ½ a sample falls (a step, 0.5 mm): at most 2 % of the pixels.
//! - GPU vs CPU glyph images: glyph coverage, rim and blending are the same f32 formulas, quantised once per glyph
//!   write, so within [`BASE_TOLERANCE`]. Where a depth-test decision differs (a hit depth a step off at a glyph's
//!   edge, because the device's filter rounds its weights) a pixel may differ more. How many may is derived from the
//!   device's filter ([`DeviceFilter`]): the CPU composite over the exact hit depths against the composites over the
//!   hit depths with the weights rounded down, up and either way at the device's bits; the channels any of those
//!   moves past [`BASE_TOLERANCE`], plus one pixel's four channels for the f32 order of the hit depth.

mod common;

use common::*;
use glam::{Mat4, Vec2, Vec3};
use warpbench_gpu::cpu_reference::composite_glyphs;
use warpbench_gpu::target::NO_HIT_DEPTH;
use warpbench_gpu::{
    BlendMode, FeatureRequest, FilterPrecision, GlyphDrawData, GlyphInstance, GlyphRenderer, GlyphSettings,
    GlyphUniforms, OrbitCamera, Projection, RaycastDrawData, RaycastRenderer, RenderSettings, RenderTarget, SlicePlane,
};

const SIZE: (u32, u32) = (96, 96);
const SAMPLES_PER_VOXEL: f32 = 4.0;
const STEP_MM: f32 = BALL_SPACING_MM as f32 / SAMPLES_PER_VOXEL;

const MOVING: [f32; 4] = [1.0, 0.55, 0.0, 1.0];
const FIXED: [f32; 4] = [0.15, 0.55, 1.0, 1.0];
const LINE: [f32; 4] = [1.0, 1.0, 1.0, 0.85];

fn ball_scene(ctx: &warpbench_gpu::GpuContext) -> Scene {
    common::ball_scene(ctx, |r_mm| RADIUS_MM - r_mm, (-2.0, 2.0))
}

fn settings() -> RenderSettings {
    RenderSettings { blend: BlendMode::FixedOnly, samples_per_voxel: SAMPLES_PER_VOXEL, ..Default::default() }
}

/// Looks at the ball from anterior–left–superior, perspective, so that depths are not linear in t.
fn camera() -> OrbitCamera {
    let half = Vec3::splat(BALL_N as f32 * BALL_SPACING_MM as f32 / 2.0);
    let mut camera = OrbitCamera::fit(-half, half, Projection::Perspective { fov_y_rad: 0.7 });
    camera.azimuth_rad = 0.5;
    camera.elevation_rad = 0.3;
    camera.zoom = 1.8;
    camera
}

/// The ray of pixel centre `p` (framebuffer px): the near-plane point and the unit direction.
fn pixel_ray(ref_from_clip: Mat4, p: Vec2) -> (Vec3, Vec3, Vec2) {
    let ndc = Vec2::new(p.x / SIZE.0 as f32 * 2.0 - 1.0, 1.0 - p.y / SIZE.1 as f32 * 2.0);
    let near = ref_from_clip.project_point3(ndc.extend(0.0));
    let far = ref_from_clip.project_point3(ndc.extend(1.0));
    (near, (far - near).normalize(), ndc)
}

/// Distance along the pixel's ray of NDC depth `z`.
fn ray_distance(ref_from_clip: Mat4, ndc: Vec2, z: f32) -> f32 {
    ref_from_clip.project_point3(ndc.extend(z)).distance(ref_from_clip.project_point3(ndc.extend(0.0)))
}

/// The screen pixel (framebuffer px, y down) of `p_ref`.
fn pixel_of(clip_from_ref: Mat4, p_ref: Vec3) -> Vec2 {
    let ndc = clip_from_ref.project_point3(p_ref);
    Vec2::new((ndc.x + 1.0) * 0.5 * SIZE.0 as f32, (1.0 - ndc.y) * 0.5 * SIZE.1 as f32)
}

fn rgba(img: &[u8], p: Vec2) -> [u8; 4] {
    let i = 4 * (p.y as usize * SIZE.0 as usize + p.x as usize);
    [img[i], img[i + 1], img[i + 2], img[i + 3]]
}

#[test]
fn hit_depth_lies_on_the_analytic_sphere_and_matches_the_cpu() {
    let Some(ctx) = context(FeatureRequest::default()) else { return };
    let scene = ball_scene(&ctx);
    let gpu = GpuScene::new(&ctx, &scene);
    let u = scene.uniforms(&camera(), &settings(), SIZE);
    let target = gpu.render_target(&ctx, &gpu.renderer, &scene, &u);
    let gpu_depth = target.read_hit_depth(&ctx).expect("hit depth");
    let cpu_depth = scene.cpu_hit_depth(&u);
    let ref_from_clip = Mat4::from_cols_array_2d(&u.ref_from_clip);

    let (mut checked, mut worst_early, mut worst_late, mut disagree) = (0, 0.0f32, 0.0f32, 0);
    for y in 0..SIZE.1 {
        for x in 0..SIZE.0 {
            let i = (y * SIZE.0 + x) as usize;
            let (origin, dir, ndc) = pixel_ray(ref_from_clip, Vec2::new(x as f32 + 0.5, y as f32 + 0.5));
            let (g, c) = (gpu_depth[i], cpu_depth[i]);
            if (g == NO_HIT_DEPTH) != (c == NO_HIT_DEPTH)
                || (g != NO_HIT_DEPTH
                    && (ray_distance(ref_from_clip, ndc, g) - ray_distance(ref_from_clip, ndc, c)).abs() > 1e-3)
            {
                disagree += 1;
            }
            // Rays that pass well inside the sphere (not grazing) must hit it on its surface.
            let closest = (origin - origin.dot(dir) * dir).length();
            if closest < RADIUS_MM - 2.0 {
                let t_surface = sphere_entry(origin, dir, Vec3::ZERO, RADIUS_MM).expect("enters");
                assert!(g <= 1.0, "pixel ({x}, {y}) misses the ball");
                let err = ray_distance(ref_from_clip, ndc, g) - t_surface;
                worst_early = worst_early.min(err);
                worst_late = worst_late.max(err);
                checked += 1;
            } else if closest > RADIUS_MM + 1.0 {
                assert!(g > 1.0, "pixel ({x}, {y}) passes outside the ball but hit something");
            }
        }
    }
    eprintln!(
        "{checked} rays: hit − surface in [{worst_early:.3}, {worst_late:.3}] mm (step {STEP_MM} mm); GPU and CPU \
         differ at {disagree} pixels"
    );
    assert!(checked > 1000, "the ball covers too few pixels: {checked}");
    assert!(worst_early >= -0.05, "a hit before the surface: {worst_early} mm");
    assert!(worst_late <= 2.0 * STEP_MM + 0.05, "a hit later than two steps: {worst_late} mm");
    assert!(disagree * 50 <= gpu_depth.len(), "GPU and CPU hit depths differ at {disagree} pixels");
}

/// Glyph positions: a point on the near surface (visible), a point inside the ball (hidden behind the surface), a
/// point beside the ball (nothing to hide it), and a line from the visible point to the hidden one.
fn glyph_points(camera: &OrbitCamera) -> (Vec3, Vec3, Vec3) {
    let eye_dir = camera.eye_direction();
    let (right, up) = camera.right_up();
    let visible = (eye_dir + 0.3 * right).normalize() * RADIUS_MM;
    let hidden = -0.4 * RADIUS_MM * right + 0.2 * RADIUS_MM * up;
    let beside = 1.6 * RADIUS_MM * up;
    (visible, hidden, beside)
}

/// Renders the ball with `glyphs` over it (GPU), returns (frame without glyphs, frame with glyphs, CPU reference of
/// the latter, the channels past [`BASE_TOLERANCE`] that a device's filter rounding may cause in it).
fn render_with_glyphs(
    ctx: &warpbench_gpu::GpuContext,
    glyphs: &[GlyphInstance],
    glyph_settings: &GlyphSettings,
) -> (Vec<u8>, Vec<u8>, Vec<u8>, usize) {
    let scene = ball_scene(ctx);
    let gpu = GpuScene::new(ctx, &scene);
    let camera = camera();
    let u = scene.uniforms(&camera, &settings(), SIZE);
    let target = gpu.render_target(ctx, &gpu.renderer, &scene, &u);
    let before = target.read_back(ctx).expect("frame");
    let glyph_renderer = GlyphRenderer::new(ctx).expect("glyph renderer");
    let gu = GlyphUniforms::for_view(&camera, SIZE, glyph_settings);
    let data = GlyphDrawData::new(ctx, &glyph_renderer, gu, glyphs, Some(&target.hit_depth_view));
    glyph_renderer.render(ctx, &data, &target).expect("glyphs");
    let after = target.read_back(ctx).expect("frame with glyphs");

    let composite = |filtering| {
        let mut cpu = scene.cpu_with(&u, filtering);
        composite_glyphs(&gu, glyphs, &scene.cpu_hit_depth_with(&u, filtering), &mut cpu);
        cpu
    };
    let cpu = composite(FilterPrecision::EXACT);
    // A device may round each lookup either way: the union of the channels the variants move.
    let mut moved = vec![false; cpu.len()];
    for filtering in DeviceFilter::measure(ctx).family() {
        for (m, (a, b)) in moved.iter_mut().zip(cpu.iter().zip(composite(filtering))) {
            *m |= a.abs_diff(b) > BASE_TOLERANCE;
        }
    }
    let flips = moved.iter().filter(|&&m| m).count();
    (before, after, cpu, flips)
}

#[test]
fn glyphs_are_depth_tested_against_the_first_hit() {
    let Some(ctx) = context(FeatureRequest::default()) else { return };
    let camera = camera();
    let (visible, hidden, beside) = glyph_points(&camera);
    let glyphs = [
        GlyphInstance::line(visible, hidden, 2.0, LINE),
        GlyphInstance::point(visible, 5.0, MOVING),
        GlyphInstance::point(hidden, 5.0, FIXED),
        GlyphInstance::point(beside, 4.0, MOVING),
    ];
    let ghost = GlyphSettings { occluded_alpha: 0.25, ..Default::default() };
    let (_, after, cpu, flips) = render_with_glyphs(&ctx, &glyphs, &ghost);

    let (max, above) = max_diff(&after, &cpu, BASE_TOLERANCE);
    let allowed = flips + 4;
    eprintln!(
        "glyphs over the ball: GPU vs CPU max {max}/255, {above} channels > {BASE_TOLERANCE} (allowed {allowed}: the \
         filter's rounding moves {flips})"
    );
    assert!(above <= allowed, "GPU and CPU glyph images differ in {above} channels (max {max})");

    let clip_from_ref = camera.clip_from_ref(1.0);
    let opaque = |c: [f32; 4]| c.map(|v| (v * 255.0).round() as u8);
    // A visible point covers its centre pixel with its own colour, exactly.
    assert_eq!(rgba(&after, pixel_of(clip_from_ref, visible)), opaque(MOVING), "visible point");
    assert_eq!(rgba(&after, pixel_of(clip_from_ref, beside)), opaque(MOVING), "point beside the ball");
    // Alone, the hidden point is a ghost: a quarter of its colour over the surface.
    let (before, after, _, _) = render_with_glyphs(&ctx, &glyphs[2..3], &ghost);
    let p = pixel_of(clip_from_ref, hidden);
    let (b, a) = (rgba(&before, p), rgba(&after, p));
    let expected: Vec<u8> = (0..4)
        .map(|c| {
            let dst = f32::from(b[c]) / 255.0;
            let src = if c < 3 { FIXED[c] * 0.25 } else { 0.25 };
            ((src + dst * 0.75) * 255.0).round() as u8
        })
        .collect();
    for c in 0..4 {
        assert!(a[c].abs_diff(expected[c]) <= 1, "hidden point: {a:?} vs ghost {expected:?} over {b:?}");
    }

    // With occluded_alpha = 0 the hidden point (and the hidden part of the line) leaves the frame as it was.
    let (before, after, _, _) =
        render_with_glyphs(&ctx, &glyphs[2..3], &GlyphSettings { occluded_alpha: 0.0, ..ghost });
    assert_eq!(before, after, "a fully occluded glyph changed the frame");
}

#[test]
fn slice_glyphs_are_cut_by_the_slab() {
    let Some(ctx) = context(FeatureRequest::default()) else { return };
    let scene = ball_scene(&ctx);
    let gpu = GpuScene::new(&ctx, &scene);
    let renderer = RaycastRenderer::new(&ctx).expect("renderer");
    // An axial plane at S = 4 mm through the ball, 1 mm pixels.
    let plane =
        SlicePlane { origin_ref: [-48.0, -48.0, 4.0], u_ref: [1.0, 0.0, 0.0], v_ref: [0.0, 1.0, 0.0], size: SIZE };
    let slab = GlyphSettings { slab_half_mm: 3.0, ..Default::default() };
    let on_plane = Vec3::new(-20.0, -20.0, 4.0);
    let half_out = Vec3::new(20.0, -20.0, 4.0 + 1.5);
    let beyond = Vec3::new(-20.0, 20.0, 4.0 + 3.5);
    let glyphs = [
        // A line from S = −16 to S = 24: only the part within 3 mm of S = 4 is drawn.
        GlyphInstance::line(Vec3::new(10.0, 0.0, -16.0), Vec3::new(30.0, 40.0, 24.0), 2.0, LINE),
        GlyphInstance::point(on_plane, 6.0, MOVING),
        GlyphInstance::point(half_out, 6.0, FIXED),
        GlyphInstance::point(beyond, 6.0, FIXED),
    ];
    let u = scene.slice_uniforms(&plane, &settings());
    let f = warpbench_gpu::GpuLayer {
        volume: &gpu.fixed,
        control: None,
        prefiltered: None,
        style: scene.fixed_style,
        procedural: None,
        view: None,
    };
    let m = warpbench_gpu::GpuLayer {
        volume: &gpu.moving,
        control: None,
        prefiltered: None,
        style: scene.moving_style,
        procedural: None,
        view: None,
    };
    let frame = warpbench_gpu::GpuFrame { fixed: f, moving: m, tfs: &gpu.tfs };
    let data = RaycastDrawData::with_uniforms(&ctx, &renderer, &frame, u);
    let target = RenderTarget::new(&ctx, SIZE.0, SIZE.1);
    renderer.render_slice(&ctx, &data, &target).expect("slice");
    let before = target.read_back(&ctx).expect("slice");
    let glyph_renderer = GlyphRenderer::new(&ctx).expect("glyph renderer");
    let gu = GlyphUniforms::for_slice(&plane, &slab).expect("plane");
    let glyph_data = GlyphDrawData::new(&ctx, &glyph_renderer, gu, &glyphs, None);
    glyph_renderer.render(&ctx, &glyph_data, &target).expect("glyphs");
    let after = target.read_back(&ctx).expect("slice with glyphs");

    let mut cpu = scene.cpu_slice(&u);
    composite_glyphs(&gu, &glyphs, &[], &mut cpu);
    let (max, above) = max_diff(&after, &cpu, 2);
    eprintln!("glyphs over a slice: GPU vs CPU max {max}/255, {above} channels > 2");
    assert!(above == 0, "GPU and CPU slice glyphs differ in {above} channels (max {max})");

    // Changed pixels within `r` px of a point's position (pixel centres at i + ½).
    let changed_within = |p_ref: Vec3, r: f32| {
        let q = plane.pixel_from_ref(p_ref.as_dvec3().to_array()).expect("plane");
        let centre = Vec2::new(q[0] as f32 + 0.5, q[1] as f32 + 0.5);
        let mut n = 0;
        for y in 0..SIZE.1 {
            for x in 0..SIZE.0 {
                let i = 4 * (y * SIZE.0 + x) as usize;
                let d = Vec2::new(x as f32 + 0.5, y as f32 + 0.5).distance(centre);
                if d <= r && before[i..i + 4] != after[i..i + 4] {
                    n += 1;
                }
            }
        }
        n
    };
    // The on-plane point has its full radius 6 (about π·6² pixels); the point 1.5 mm out has 6·√(1 − ½²) = 5.2; the
    // point beyond the slab is not drawn.
    let full = changed_within(on_plane, 8.0);
    let shrunk = changed_within(half_out, 8.0);
    assert!((100..=140).contains(&full), "on-plane point covers {full} pixels");
    assert!((75..=100).contains(&shrunk), "point 1.5 mm out covers {shrunk} pixels");
    assert_eq!(changed_within(beyond, 8.0), 0, "a point beyond the slab was drawn");
    // The line: S = −16 + 40 s is within 3 mm of 4 for s ∈ [0.425, 0.575], i.e. (x, y) from (18.5, 17) to (21.5, 23).
    let line_pixel = |x: f32, y: f32| {
        let q = plane.pixel_from_ref([f64::from(x), f64::from(y), 4.0]).expect("plane");
        rgba(&after, Vec2::new(q[0] as f32 + 0.5, q[1] as f32 + 0.5))
            != rgba(&before, Vec2::new(q[0] as f32 + 0.5, q[1] as f32 + 0.5))
    };
    assert!(line_pixel(20.0, 20.0), "the line is missing where it crosses the plane");
    assert!(!line_pixel(15.0, 10.0) && !line_pixel(25.0, 30.0), "the line is drawn outside the slab");
}

#[test]
fn instance_updates_reuse_and_grow_the_buffer() {
    let Some(ctx) = context(FeatureRequest::default()) else { return };
    let renderer = GlyphRenderer::new(&ctx).expect("glyph renderer");
    let camera = camera();
    let gu = GlyphUniforms::for_view(&camera, SIZE, &GlyphSettings::default());
    let target = RenderTarget::new(&ctx, SIZE.0, SIZE.1);
    let one = [GlyphInstance::point(Vec3::ZERO, 4.0, MOVING)];
    // No hit depth (a fresh target's is 0, not NO_HIT_DEPTH): the placeholder, nothing occludes.
    let mut data = GlyphDrawData::new(&ctx, &renderer, gu, &one, None);
    // Many glyphs after one: the buffer grows; then none: nothing is drawn.
    let many: Vec<GlyphInstance> =
        (0..40).map(|k| GlyphInstance::point(Vec3::new(k as f32 - 20.0, 0.0, 0.0), 2.0, FIXED)).collect();
    data.update(&ctx, gu, &many);
    renderer.render(&ctx, &data, &target).expect("many");
    let img = target.read_back(&ctx).expect("read back");
    let mut cpu = vec![0u8; img.len()];
    composite_glyphs(&gu, &many, &[], &mut cpu);
    let (max, above) = max_diff(&img, &cpu, 2);
    assert!(above == 0, "40 glyphs: GPU vs CPU max {max}");
    assert!(coverage(&img) > 0.01, "nothing drawn");
    data.update(&ctx, gu, &[]);
    let empty = RenderTarget::new(&ctx, SIZE.0, SIZE.1);
    renderer.render(&ctx, &data, &empty).expect("none");
    assert!(empty.read_back(&ctx).expect("read back").iter().all(|&v| v == 0), "an empty update drew something");
}
