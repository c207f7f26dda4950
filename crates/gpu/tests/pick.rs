//! Ray picking ([`warpbench_gpu::pick`]) against analytic balls and the CPU march
//! ([`warpbench_gpu::cpu_reference::pick`]).
//!
//! Scenes: the analytic ball of `common` (32³, 2 mm voxels, value = a function of the distance to the centre), as
//! the fixed volume, and as the moving volume displaced by a known smooth warp.
//!
//! Tolerances:
//! - Depth on the ball (opacity probe, one sample per voxel, 8 bisections): the issue asks for 0.25 voxel (0.5 mm).
//!   The bisection leaves step/256 = 0.008 mm and the step transfer function puts the surface at v = 0; what remains
//!   is trilinear interpolation of R − r, whose iso-surface bulges inwards by up to ~3·h²/(8R) = 0.075 mm per
//!   cell direction. Measured on lavapipe: 0.15 mm (0.08 voxel).
//! - A feature moved by the warp (the moving ball): the hit's pull-back p_lps lies on the undeformed ball's surface
//!   within 0.5 voxel (the bound; the same error sources as above), and the hit is where the frame draws the
//!   surface: the render's first hit (the first *sample* with accumulated opacity ≥ ½) lies within one step behind
//!   the pick (the same samples, refined).
//! - GPU vs CPU: the same samples and the same formulas in f32, and a pick filters every lookup by hand with exact
//!   weights on the GPU as on the CPU, whatever the device's hardware filter (`shaders/raycast.wgsl`,
//!   EXACT_FILTER). What remains is f32 evaluation order (a few ulps of a value, which moves a threshold crossing by
//!   < 10⁻³ mm on these volumes: gradient ≈ 1 value unit per mm, ≥ 60 per mm for the tanh ball near its threshold)
//!   and the bisection's last step, step/2⁹ = 0.004 mm, when the two sides take a different last branch. Bound:
//!   0.05 mm, and the same hit/miss for all but 1 % of the rays (grazing rays).

mod common;

use common::*;
use glam::{DVec3, Mat4, Vec3};
use warpbench_gpu::cpu_reference::{self, CpuLayer};
use warpbench_gpu::{
    BlendMode, Classification, ControlDesc, FeatureRequest, GpuContext, GpuFrame, GpuLayer, OrbitCamera, PickHit,
    PickPass, PickRay, PickRequest, PickTarget, PreparedControl, Probe, Projection, RaycastDrawData, RaycastUniforms,
    RenderSettings,
};

const SIZE: (u32, u32) = (64, 64);
/// One sample per voxel: coarse on purpose, so that the bisection has work to do.
const SAMPLES_PER_VOXEL: f32 = 1.0;
const VOXEL_MM: f32 = BALL_SPACING_MM as f32;
/// The moving ball's centre in moving LPS, and the warp's rigid part, which brings it back near the fixed origin.
const MOVING_CENTRE: [f64; 3] = [8.0, -6.0, 4.0];

fn camera() -> OrbitCamera {
    let half = Vec3::splat(BALL_N as f32 * VOXEL_MM / 2.0);
    let mut camera = OrbitCamera::fit(-half, half, Projection::Perspective { fov_y_rad: 0.7 });
    camera.azimuth_rad = -0.4;
    camera.elevation_rad = 0.2;
    camera.zoom = 1.8;
    camera
}

/// The pull-back of the moving scene: u(x) = x + c_m + a smooth bulge of up to 3 mm.
fn moving_from_ref(x: DVec3) -> DVec3 {
    let bulge = DVec3::new((x.y / 9.0).sin(), (x.z / 11.0).sin(), (x.x / 10.0).cos()) * 3.0;
    x + DVec3::from_array(MOVING_CENTRE) + bulge
}

/// The moving scene: the fixed layer is a hidden ball at the origin, the moving layer the ball at [`MOVING_CENTRE`]
/// pulled back through a 48³ control texture of [`moving_from_ref`].
fn moving_scene(ctx: &GpuContext, value: impl Fn(f32) -> f32 + Copy, window: (f32, f32)) -> Scene {
    let mut scene = ball_scene(ctx, value, window);
    scene.moving = ball_volume(ctx, MOVING_CENTRE, value);
    let (lo, hi) = ([-48.0; 3], [48.0; 3]);
    let texels = sample_control(48, lo, hi, |x| moving_from_ref(x) - x);
    let desc = ControlDesc { dims: [48; 3], texels: &texels, box_min_ref: lo, box_max_ref: hi };
    scene.control = Some(PreparedControl::prepare(&desc, ctx.capabilities.float32_filterable).expect("control"));
    std::mem::swap(&mut scene.fixed_style.visible, &mut scene.moving_style.visible);
    scene
}

fn uniforms(scene: &Scene, blend: BlendMode) -> RaycastUniforms {
    uniforms_with(scene, blend, Classification::default())
}

fn uniforms_with(scene: &Scene, blend: BlendMode, classification: Classification) -> RaycastUniforms {
    let settings = RenderSettings { blend, samples_per_voxel: SAMPLES_PER_VOXEL, classification, ..Default::default() };
    scene.uniforms(&camera(), &settings, SIZE)
}

/// Rays through every `stride`-th pixel centre.
fn pixel_rays(u: &RaycastUniforms, stride: u32) -> Vec<([u32; 2], PickRay)> {
    let mut rays = Vec::new();
    for y in (0..SIZE.1).step_by(stride as usize) {
        for x in (0..SIZE.0).step_by(stride as usize) {
            let ray = PickRay::from_pixel(u, [x as f32 + 0.5, y as f32 + 0.5]).expect("ray");
            rays.push(([x, y], ray));
        }
    }
    rays
}

/// GPU picks of `rays` in `scene`, and the CPU reference's.
fn pick_both(
    ctx: &GpuContext,
    scene: &Scene,
    u: &RaycastUniforms,
    request: &PickRequest,
    rays: &[PickRay],
) -> (Vec<PickHit>, Vec<PickHit>) {
    let gpu = GpuScene::new(ctx, scene);
    let f = GpuLayer {
        volume: &gpu.fixed,
        control: None,
        prefiltered: None,
        style: scene.fixed_style,
        procedural: None,
        view: scene.views[0],
    };
    let m = GpuLayer {
        volume: &gpu.moving,
        control: gpu.control.as_ref(),
        prefiltered: None,
        style: scene.moving_style,
        procedural: scene.moving_procedural,
        view: scene.views[1],
    };
    let frame = GpuFrame { fixed: f, moving: m, tfs: &gpu.tfs };
    let data = RaycastDrawData::with_uniforms(ctx, &gpu.renderer, &frame, *u);
    let pass = PickPass::new(ctx, &gpu.renderer).expect("pick pass");
    let hits = pass.pick(ctx, &data, request, rays).expect("pick");
    let fc = CpuLayer::new(&scene.fixed, None, None);
    let mc = CpuLayer::new(&scene.moving, scene.control.as_ref(), None);
    let tables = cpu_reference::preintegration_tables(u, &scene.tfs);
    let cpu = rays
        .iter()
        .map(|r| cpu_reference::pick_with_tables(u, &fc, &mc, &scene.tfs, tables.as_ref(), request, r))
        .collect();
    (hits, cpu)
}

/// Asserts GPU and CPU agree (module docs) and returns how many rays hit.
fn assert_agree(label: &str, gpu: &[PickHit], cpu: &[PickHit]) -> usize {
    let (mut both, mut differ, mut worst) = (0, 0, 0.0f32);
    for (g, c) in gpu.iter().zip(cpu) {
        match (g.found(), c.found()) {
            (Some(g), Some(c)) => {
                both += 1;
                worst = worst.max(Vec3::from_array(g.x_ref).distance(Vec3::from_array(c.x_ref)));
                assert_eq!(g.target_volume, c.target_volume);
            }
            (None, None) => {}
            _ => differ += 1,
        }
    }
    eprintln!("{label}: {both} hits on both, {differ} hit on one only, worst distance {worst:.4} mm");
    assert!(differ * 100 <= gpu.len(), "{label}: GPU and CPU disagree on hit/miss for {differ} rays");
    assert!(worst <= 0.05, "{label}: GPU and CPU hits {worst} mm apart");
    both
}

#[test]
fn opacity_probe_finds_the_analytic_sphere() {
    let Some(ctx) = context(FeatureRequest::default()) else { return };
    let scene = ball_scene(&ctx, |r| RADIUS_MM - r, (-2.0, 2.0));
    let u = uniforms(&scene, BlendMode::FixedOnly);
    let rays = pixel_rays(&u, 2);
    let request = PickRequest::new(PickTarget::Fixed, Probe::Opacity { threshold: 0.5 });
    let just_rays: Vec<PickRay> = rays.iter().map(|(_, r)| *r).collect();
    let (gpu, cpu) = pick_both(&ctx, &scene, &u, &request, &just_rays);
    assert_agree("opacity probe, fixed ball", &gpu, &cpu);

    let (mut checked, mut worst) = (0, 0.0f32);
    for (ray, hit) in just_rays.iter().zip(&gpu) {
        let (origin, dir) = (Vec3::from_array(ray.origin_ref), Vec3::from_array(ray.dir_ref));
        let closest = (origin - origin.dot(dir) * dir).length();
        if closest > RADIUS_MM - 1.0 {
            continue; // grazing or missing rays
        }
        let t_surface = sphere_entry(origin, dir, Vec3::ZERO, RADIUS_MM).expect("enters");
        let hit = hit.found().expect("a ray through the ball hits it");
        worst = worst.max((hit.t_mm - t_surface).abs());
        // The pull-back of the identity is the point itself, and the value there is ~0 (the surface).
        assert!(hit.x_ref.iter().zip(&hit.p_lps).all(|(a, b)| a.to_bits() == b.to_bits()), "identity pull-back");
        assert!(hit.value.abs() < 0.05, "value {} at the surface", hit.value);
        checked += 1;
    }
    eprintln!("{checked} rays: |t_hit − t_surface| ≤ {worst:.4} mm (voxel {VOXEL_MM} mm, step {VOXEL_MM} mm)");
    assert!(checked > 200, "too few rays through the ball: {checked}");
    assert!(worst <= 0.25 * VOXEL_MM, "pick depth off by {worst} mm > 0.25 voxel");
    // Without bisection the error is up to a step: the refinement is what makes picks finer than the samples.
    let coarse = PickRequest { bisection_steps: 0, ..request };
    let (gpu0, _) = pick_both(&ctx, &scene, &u, &coarse, &just_rays);
    let worst0 = just_rays
        .iter()
        .zip(&gpu0)
        .filter_map(|(ray, hit)| {
            let (origin, dir) = (Vec3::from_array(ray.origin_ref), Vec3::from_array(ray.dir_ref));
            let t = sphere_entry(origin, dir, Vec3::ZERO, RADIUS_MM - 1.0)?;
            Some((hit.found()?.t_mm - (t - 1.0)).abs())
        })
        .fold(0.0f32, f32::max);
    assert!(worst0 > 4.0 * worst, "bisection did not refine: {worst0} vs {worst}");
}

#[test]
fn a_warped_feature_is_picked_where_it_is_drawn_and_maps_back() {
    let Some(ctx) = context(FeatureRequest::default()) else { return };
    for classification in Classification::ALL {
        picked_where_drawn(&ctx, classification);
    }
}

/// The frame's compositing and the accumulated probe agree for `classification` (per sample, or segment by segment).
fn picked_where_drawn(ctx: &GpuContext, classification: Classification) {
    let scene = moving_scene(ctx, |r| RADIUS_MM - r, (-2.0, 2.0));
    let u = uniforms_with(&scene, BlendMode::MovingOnly, classification);
    let rays = pixel_rays(&u, 2);
    let just_rays: Vec<PickRay> = rays.iter().map(|(_, r)| *r).collect();
    // The frame's own first hit: accumulated opacity ½ at the first sample.
    let gpu_scene = GpuScene::new(ctx, &scene);
    let target = gpu_scene.render_target(ctx, &gpu_scene.renderer, &scene, &u);
    let drawn = target.read_hit_depth(ctx).expect("hit depth");
    let request = PickRequest::new(PickTarget::Moving, Probe::Accumulated { level: 0.5 });
    let (gpu, cpu) = pick_both(ctx, &scene, &u, &request, &just_rays);
    let hits = assert_agree(&format!("accumulated ½, warped moving ball, {}", classification.name()), &gpu, &cpu);
    assert!(hits > 300, "too few hits: {hits}");

    let ref_from_clip = Mat4::from_cols_array_2d(&u.ref_from_clip);
    let centre = DVec3::from_array(MOVING_CENTRE).as_vec3();
    let (mut worst_surface, mut worst_drawn) = (0.0f32, (0.0f32, 0.0f32));
    for ((px, ray), hit) in rays.iter().zip(&gpu) {
        let Some(hit) = hit.found() else { continue };
        // Maps back onto the undeformed ball's surface.
        worst_surface = worst_surface.max((Vec3::from_array(hit.p_lps).distance(centre) - RADIUS_MM).abs());
        // Where the frame draws it: the render's first hit is the first sample at or past the pick.
        let z = drawn[(px[1] * SIZE.0 + px[0]) as usize];
        assert!(z <= 1.0, "pixel {px:?}: picked but the frame shows nothing");
        let ndc =
            glam::Vec2::new(px[0] as f32 + 0.5, px[1] as f32 + 0.5) / glam::Vec2::new(SIZE.0 as f32, SIZE.1 as f32);
        let ndc = glam::Vec2::new(ndc.x * 2.0 - 1.0, 1.0 - ndc.y * 2.0);
        let near = ref_from_clip.project_point3(ndc.extend(0.0));
        let t_drawn = ref_from_clip.project_point3(ndc.extend(z)).distance(near);
        let t_pick = Vec3::from_array(hit.x_ref).distance(Vec3::from_array(ray.origin_ref));
        let d = t_drawn - t_pick;
        worst_drawn = (worst_drawn.0.min(d), worst_drawn.1.max(d));
    }
    let step = u.step_mm;
    eprintln!(
        "pull-backs within {worst_surface:.4} mm of the undeformed surface; drawn − picked in [{:.4}, {:.4}] mm (step \
         {step} mm)",
        worst_drawn.0, worst_drawn.1
    );
    assert!(worst_surface <= 0.5 * VOXEL_MM, "a pick maps back {worst_surface} mm off the undeformed surface");
    assert!(
        worst_drawn.0 >= -0.01 && worst_drawn.1 <= step + 0.01,
        "picks are not where the frame draws: {worst_drawn:?}"
    );
}

/// Picking marches through the layer's procedural deformation as the frame draws it
/// ([`warpbench_gpu::procedural`]): under a shift by t the ball is drawn, and picked, at −t; the hit reports the
/// point of the deformed volume's own space (u(x) = x without a warp) and the value read at p(x), ~0 on the surface.
/// Under a bend the GPU and the CPU march agree, and the frame's first hit lies within a step behind each pick.
#[test]
fn picks_march_through_a_procedural_deformation() {
    let Some(ctx) = context(FeatureRequest::default()) else { return };
    let mut scene = ball_scene(&ctx, |r| RADIUS_MM - r, (-2.0, 2.0));
    std::mem::swap(&mut scene.fixed_style.visible, &mut scene.moving_style.visible);
    let t = Vec3::new(5.0, -3.5, 2.5);
    scene.moving_procedural = Some(warpbench_gpu::Procedural::Shift { offset_mm: t });
    let u = uniforms(&scene, BlendMode::MovingOnly);
    let rays: Vec<PickRay> = pixel_rays(&u, 2).into_iter().map(|(_, r)| r).collect();
    let request = PickRequest::new(PickTarget::Moving, Probe::Opacity { threshold: 0.5 });
    let (gpu, cpu) = pick_both(&ctx, &scene, &u, &request, &rays);
    assert_agree("opacity probe, shifted ball", &gpu, &cpu);
    let (mut checked, mut worst) = (0, 0.0f32);
    for (ray, hit) in rays.iter().zip(&gpu) {
        let (origin, dir) = (Vec3::from_array(ray.origin_ref), Vec3::from_array(ray.dir_ref));
        let o = origin + t;
        if (o - o.dot(dir) * dir).length() > RADIUS_MM - 1.0 {
            continue;
        }
        let t_surface = sphere_entry(origin, dir, -t, RADIUS_MM).expect("enters");
        let hit = hit.found().expect("a ray through the shifted ball hits it");
        worst = worst.max((hit.t_mm - t_surface).abs());
        assert!(hit.x_ref.iter().zip(&hit.p_lps).all(|(a, b)| a.to_bits() == b.to_bits()), "u is the identity");
        assert!(hit.value.abs() < 0.05, "value {} at the surface", hit.value);
        checked += 1;
    }
    eprintln!("{checked} rays through the shifted ball: |t_hit − t_surface| ≤ {worst:.4} mm");
    assert!(checked > 200 && worst <= 0.25 * VOXEL_MM, "{checked} rays, worst {worst} mm");

    // A bend through the warp: the pick and the picture agree.
    let mut scene = moving_scene(&ctx, |r| RADIUS_MM - r, (-2.0, 2.0));
    let centre = DVec3::from_array(MOVING_CENTRE).as_vec3();
    scene.moving_procedural =
        Some(warpbench_gpu::Procedural::bend(centre, warpbench_gpu::Axis::Z, warpbench_gpu::Axis::X, true, 0.01));
    let u = uniforms(&scene, BlendMode::MovingOnly);
    let pixels = pixel_rays(&u, 2);
    let rays: Vec<PickRay> = pixels.iter().map(|(_, r)| *r).collect();
    let request = PickRequest::new(PickTarget::Moving, Probe::Accumulated { level: 0.5 });
    let (gpu, cpu) = pick_both(&ctx, &scene, &u, &request, &rays);
    assert!(assert_agree("accumulated ½, bent warped ball", &gpu, &cpu) > 300);
    let gpu_scene = GpuScene::new(&ctx, &scene);
    let drawn = gpu_scene.render_target(&ctx, &gpu_scene.renderer, &scene, &u).read_hit_depth(&ctx).expect("depth");
    let ref_from_clip = Mat4::from_cols_array_2d(&u.ref_from_clip);
    let mut worst_drawn = (0.0f32, 0.0f32);
    for ((px, ray), hit) in pixels.iter().zip(&gpu) {
        let Some(hit) = hit.found() else { continue };
        let z = drawn[(px[1] * SIZE.0 + px[0]) as usize];
        assert!(z <= 1.0, "pixel {px:?}: picked but the frame shows nothing");
        let ndc = glam::Vec2::new(
            (px[0] as f32 + 0.5) / SIZE.0 as f32 * 2.0 - 1.0,
            1.0 - (px[1] as f32 + 0.5) / SIZE.1 as f32 * 2.0,
        );
        let near = ref_from_clip.project_point3(ndc.extend(0.0));
        let d = ref_from_clip.project_point3(ndc.extend(z)).distance(near)
            - Vec3::from_array(hit.x_ref).distance(Vec3::from_array(ray.origin_ref));
        worst_drawn = (worst_drawn.0.min(d), worst_drawn.1.max(d));
    }
    eprintln!("bent ball: drawn − picked in [{:.4}, {:.4}] mm (step {} mm)", worst_drawn.0, worst_drawn.1, u.step_mm);
    assert!(worst_drawn.0 >= -0.01 && worst_drawn.1 <= u.step_mm + 0.01, "picks are not where the frame draws");
}

/// Picking marches through a view deformation as the frame draws it ([`warpbench_gpu::view_deformation`]): through
/// the fish-eye lens centred on the fixed ball, the ball is drawn, and hit, magnified at the radius r with ρ(r) = R
/// (ρ(r) = r (1 − a (1 − r/L)²)), while the hit's point of the volume, w(x), lies on the undeformed ball's surface:
/// what a landmark stores. GPU and CPU agree.
#[test]
fn a_pick_through_the_lens_lands_on_the_undeformed_ball() {
    let Some(ctx) = context(FeatureRequest::default()) else { return };
    let mut scene = ball_scene(&ctx, |r| RADIUS_MM - r, (-2.0, 2.0));
    let (lens_mm, a) = (30.0f64, 0.5f64);
    scene.views = [Some(warpbench_gpu::ViewDeformation::FishEye {
        centre_ref: Vec3::ZERO,
        radius_mm: lens_mm as f32,
        amplitude: a as f32,
    }); 2];
    let rho = |r: f64| r * (1.0 - a * (1.0 - r / lens_mm).powi(2));
    let (mut lo, mut hi) = (0.0, lens_mm);
    for _ in 0..60 {
        let mid = 0.5 * (lo + hi);
        if rho(mid) < f64::from(RADIUS_MM) { lo = mid } else { hi = mid }
    }
    let shown_mm = (0.5 * (lo + hi)) as f32;
    let u = uniforms(&scene, BlendMode::FixedOnly);
    let rays: Vec<PickRay> = pixel_rays(&u, 2).into_iter().map(|(_, r)| r).collect();
    let request = PickRequest::new(PickTarget::Fixed, Probe::Opacity { threshold: 0.5 });
    let (gpu, cpu) = pick_both(&ctx, &scene, &u, &request, &rays);
    assert_agree("opacity probe, ball through the lens", &gpu, &cpu);
    let (mut checked, mut worst_shown, mut worst_stored) = (0, 0.0f32, 0.0f32);
    for (ray, hit) in rays.iter().zip(&gpu) {
        let (origin, dir) = (Vec3::from_array(ray.origin_ref), Vec3::from_array(ray.dir_ref));
        if (origin - origin.dot(dir) * dir).length() > shown_mm - 1.5 {
            continue;
        }
        let hit = hit.found().expect("a ray through the magnified ball hits it");
        worst_shown = worst_shown.max((Vec3::from_array(hit.x_ref).length() - shown_mm).abs());
        worst_stored = worst_stored.max((Vec3::from_array(hit.p_lps).length() - RADIUS_MM).abs());
        checked += 1;
    }
    eprintln!(
        "{checked} rays: hits {worst_shown:.3} mm from the magnified radius {shown_mm:.2} mm, stored points \
         {worst_stored:.3} mm from the ball's {RADIUS_MM} mm"
    );
    assert!(checked > 200, "{checked} rays");
    assert!(worst_shown <= 0.5 * VOXEL_MM && worst_stored <= 0.25 * VOXEL_MM, "{worst_shown} / {worst_stored} mm");
}

/// Picking marches through the leafer as the frame draws it: with the ball cut through its centre and opened
/// towards the camera, rays into the opening hit a cut face, and what they store is the point of the undeformed
/// ball on the cut plane (inside the ball). GPU and CPU agree, and the frame's first hit lies within a step behind
/// each pick.
#[test]
fn a_pick_through_the_leafer_lands_on_the_cut_plane() {
    let Some(ctx) = context(FeatureRequest::default()) else { return };
    let mut scene = ball_scene(&ctx, |r| RADIUS_MM - r, (-2.0, 2.0));
    let u0 = uniforms(&scene, BlendMode::FixedOnly);
    let ref_from_clip = Mat4::from_cols_array_2d(&u0.ref_from_clip);
    let (near, far) = (ref_from_clip.project_point3(Vec3::ZERO), ref_from_clip.project_point3(Vec3::Z));
    let up = ref_from_clip.project_point3(Vec3::new(0.0, 0.5, 0.0)) - near;
    let leafer = warpbench_gpu::ViewDeformation::leafer(Vec3::ZERO, near - far, up, 30.0, 0.45).expect("a leafer");
    let warpbench_gpu::ViewDeformation::Leafer { hinge_ref, normal, .. } = leafer else { unreachable!() };
    scene.views = [Some(leafer), None];
    let u = uniforms(&scene, BlendMode::FixedOnly);
    let pixels = pixel_rays(&u, 2);
    let rays: Vec<PickRay> = pixels.iter().map(|(_, r)| *r).collect();
    let request = PickRequest::new(PickTarget::Fixed, Probe::Accumulated { level: 0.5 });
    let (gpu, cpu) = pick_both(&ctx, &scene, &u, &request, &rays);
    assert!(assert_agree("accumulated ½, ball through the leafer", &gpu, &cpu) > 200);
    let gpu_scene = GpuScene::new(&ctx, &scene);
    let drawn = gpu_scene.render_target(&ctx, &gpu_scene.renderer, &scene, &u).read_hit_depth(&ctx).expect("depth");
    let (mut on_cut, mut worst_drawn) = (0, (0.0f32, 0.0f32));
    for ((px, ray), hit) in pixels.iter().zip(&gpu) {
        let Some(hit) = hit.found() else { continue };
        let p = Vec3::from_array(hit.p_lps);
        assert!(p.length() <= RADIUS_MM + 0.5, "a stored point {p} off the ball");
        if (p - hinge_ref).dot(normal).abs() < 0.05 && p.length() < RADIUS_MM - 1.0 {
            on_cut += 1; // inside the ball, on the cut plane: a hit on a cut face
        }
        let z = drawn[(px[1] * SIZE.0 + px[0]) as usize];
        assert!(z <= 1.0, "pixel {px:?}: picked but the frame shows nothing");
        let ndc = glam::Vec2::new(
            (px[0] as f32 + 0.5) / SIZE.0 as f32 * 2.0 - 1.0,
            1.0 - (px[1] as f32 + 0.5) / SIZE.1 as f32 * 2.0,
        );
        let n = ref_from_clip.project_point3(ndc.extend(0.0));
        let d = ref_from_clip.project_point3(ndc.extend(z)).distance(n)
            - Vec3::from_array(hit.x_ref).distance(Vec3::from_array(ray.origin_ref));
        worst_drawn = (worst_drawn.0.min(d), worst_drawn.1.max(d));
    }
    eprintln!(
        "leafer: {on_cut} picks on the cut faces; drawn − picked in [{:.4}, {:.4}] mm",
        worst_drawn.0, worst_drawn.1
    );
    assert!(on_cut > 40, "only {on_cut} picks landed on the cut faces");
    assert!(worst_drawn.0 >= -0.01 && worst_drawn.1 <= u.step_mm + 0.01, "picks are not where the frame draws");
}

#[test]
fn gradient_and_accumulated_probes_match_the_cpu_march() {
    let Some(ctx) = context(FeatureRequest::default()) else { return };
    // A soft ball: 1000·tanh((R − r)/3 mm); its gradient peaks at the surface at 333 per mm.
    let soft = |r: f32| 1000.0 * ((RADIUS_MM - r) / 3.0).tanh();
    for warped in [false, true] {
        let scene =
            if warped { moving_scene(&ctx, soft, (-100.0, 100.0)) } else { ball_scene(&ctx, soft, (-100.0, 100.0)) };
        let (target, blend, centre) = if warped {
            (PickTarget::Moving, BlendMode::MovingOnly, DVec3::from_array(MOVING_CENTRE).as_vec3())
        } else {
            (PickTarget::Fixed, BlendMode::FixedOnly, Vec3::ZERO)
        };
        let per_sample = uniforms(&scene, blend);
        let preintegrated = uniforms_with(&scene, blend, Classification::PreIntegrated);
        let rays: Vec<PickRay> = pixel_rays(&per_sample, 3).into_iter().map(|(_, r)| r).collect();
        for (probe, u) in [
            (Probe::Gradient { threshold: 167.0 }, per_sample),
            (Probe::Accumulated { level: 0.95 }, per_sample),
            (Probe::Accumulated { level: 0.95 }, preintegrated),
        ] {
            let request = PickRequest::new(target, probe);
            let (gpu, cpu) = pick_both(&ctx, &scene, &u, &request, &rays);
            let label = format!(
                "{probe:?}, warped {warped}, pre-integrated {}",
                u.flags & warpbench_gpu::raycast::RAYCAST_PREINTEGRATED != 0
            );
            let hits = assert_agree(&label, &gpu, &cpu);
            assert!(hits > 100, "{probe:?}: too few hits ({hits})");
            // Half the peak gradient is reached outside the surface, where sech²((R − r)/3) = ½: r = R + 2.6 mm,
            // widened by the central differences; the accumulated probe stops just inside the window's middle.
            let radii: Vec<f32> =
                gpu.iter().filter_map(PickHit::found).map(|h| Vec3::from_array(h.p_lps).distance(centre)).collect();
            let (lo, hi) = radii.iter().fold((f32::MAX, f32::MIN), |(lo, hi), &r| (lo.min(r), hi.max(r)));
            eprintln!("{probe:?} warped {warped}: hit radii in [{lo:.3}, {hi:.3}] mm");
            let expected = match probe {
                Probe::Gradient { .. } => (RADIUS_MM + 1.0)..=(RADIUS_MM + 4.5),
                _ => (RADIUS_MM - 1.0)..=(RADIUS_MM + 0.5),
            };
            assert!(
                expected.contains(&lo) && expected.contains(&hi),
                "{probe:?}: radii [{lo}, {hi}] not in {expected:?}"
            );
        }
    }
}

#[test]
fn empty_and_oversized_requests() {
    let Some(ctx) = context(FeatureRequest::default()) else { return };
    let scene = ball_scene(&ctx, |r| RADIUS_MM - r, (-2.0, 2.0));
    let u = uniforms(&scene, BlendMode::FixedOnly);
    let request = PickRequest::new(PickTarget::Fixed, Probe::default());
    let (gpu, _) = pick_both(&ctx, &scene, &u, &request, &[]);
    assert!(gpu.is_empty());
    // A ray that points away from the box misses.
    let away = PickRay::new(Vec3::new(0.0, -200.0, 0.0), Vec3::new(0.0, -1.0, 0.0)).expect("ray");
    let (gpu, cpu) = pick_both(&ctx, &scene, &u, &request, &[away]);
    assert!(gpu[0].found().is_none() && cpu[0].found().is_none());
    let bad = PickRequest::new(PickTarget::Fixed, Probe::Opacity { threshold: f32::NAN });
    let g = GpuScene::new(&ctx, &scene);
    let f = GpuLayer {
        volume: &g.fixed,
        control: None,
        prefiltered: None,
        style: scene.fixed_style,
        procedural: None,
        view: None,
    };
    let frame = GpuFrame { fixed: f, moving: f, tfs: &g.tfs };
    let data = RaycastDrawData::with_uniforms(&ctx, &g.renderer, &frame, u);
    let pass = PickPass::new(&ctx, &g.renderer).expect("pass");
    assert!(pass.pick(&ctx, &data, &bad, &[away]).is_err(), "a NaN threshold was accepted");
    let too_many = vec![away; PickPass::MAX_RAYS + 1];
    assert!(pass.pick(&ctx, &data, &request, &too_many).is_err(), "too many rays were accepted");
}
