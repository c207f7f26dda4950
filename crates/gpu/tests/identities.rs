//! Laws of the warped rendering, GPU only (64³ volumes, 64×64 images, no jitter).

mod common;

use common::*;
use glam::{DVec3, Vec4};
use warpbench_gpu::cpu_reference::trilinear;
use warpbench_gpu::{BlendMode, FeatureRequest, OrbitCamera, Projection, RenderSettings, VolumeDesc, VolumeSamples};

const SIZE: (u32, u32) = (64, 64);

fn front_ortho() -> OrbitCamera {
    OrbitCamera::fit(v3(-80.0, -80.0, -80.0), v3(80.0, 80.0, 80.0), Projection::Orthographic)
}

fn moving_only() -> RenderSettings {
    // A fixed proxy box, so that adding a control texture does not move the ray starts.
    RenderSettings {
        blend: BlendMode::MovingOnly,
        box_override_ref: Some((v3(-100.0, -100.0, -100.0), v3(100.0, 100.0, 100.0))),
        ..Default::default()
    }
}

/// An all-zero control texture equals the identity fast path. Tolerance 1/255: the only difference is the
/// (exactly zero) displacement lookup.
#[test]
fn identity_control_texture_equals_the_fast_path() {
    let Some(ctx) = context(FeatureRequest::default()) else { return };
    let p = Phantoms::new();
    let zeros = vec![0.0f32; 4 * 8 * 8 * 8];
    let plain = Scene::new(&ctx, &p, None, 8);
    let warped = Scene::new(&ctx, &p, Some(&zeros), 8);
    let cam = OrbitCamera { azimuth_rad: 0.4, elevation_rad: 0.2, ..front_ortho() };
    let settings = RenderSettings { blend: BlendMode::Mix { moving_weight: 0.5 }, ..moving_only() };
    let a = GpuScene::new(&ctx, &plain).render(&ctx, &plain, &plain.uniforms(&cam, &settings, SIZE));
    let b = GpuScene::new(&ctx, &warped).render(&ctx, &warped, &warped.uniforms(&cam, &settings, SIZE));
    let (max, _) = max_diff(&a, &b, 0);
    eprintln!("identity control vs fast path: max {max}/255, coverage {:.2}", coverage(&a));
    assert!(max <= 1 && coverage(&a) > 0.2, "max {max}");
}

/// A constant displacement t along x (patient left), seen orthographically from the front (image x = +x): the
/// pull-back samples the moving volume at x + t, so the image moves by −t / pixel_mm pixels. t is a whole number of
/// pixels, so the shifted image samples exactly the same points; tolerance 2/255 (sampler rounding) in the interior.
#[test]
fn a_translation_warp_shifts_the_image() {
    let Some(ctx) = context(FeatureRequest::default()) else { return };
    let p = Phantoms::new();
    let cam = front_ortho();
    let pixel_mm = cam.pixel_mm(SIZE.1);
    let shift_px = 3usize;
    let t = shift_px as f64 * f64::from(pixel_mm);
    let shift = vec![[t as f32, 0.0, 0.0, 0.0]; 4 * 4 * 4].concat();
    let plain = Scene::new(&ctx, &p, None, 4);
    let moved = Scene::new(&ctx, &p, Some(&shift), 4);
    let a = GpuScene::new(&ctx, &plain).render(&ctx, &plain, &plain.uniforms(&cam, &moving_only(), SIZE));
    let b = GpuScene::new(&ctx, &moved).render(&ctx, &moved, &moved.uniforms(&cam, &moving_only(), SIZE));
    // b(x) = a(x + shift): compare columns 4..60.
    let w = SIZE.0 as usize;
    let (mut max, mut compared) = (0u8, 0usize);
    for y in 4..60 {
        for x in 4..(60 - shift_px) {
            for c in 0..4 {
                max = max.max(b[4 * (y * w + x) + c].abs_diff(a[4 * (y * w + x + shift_px) + c]));
                compared += 1;
            }
        }
    }
    let (unshifted, _) = max_diff(&a, &b, 0);
    eprintln!(
        "translation by {t:.3} mm = {shift_px} px: max {max}/255 over {compared} channels (unshifted: {unshifted})"
    );
    assert!(max <= 2, "max {max}");
    assert!(unshifted > 20, "the warp must visibly move the image");
}

/// Rendering through a warp ≈ rendering the moving volume resampled through the same warp on the CPU (trilinear,
/// onto the fixed 3 mm grid) without a warp. The pre-warped volume is interpolated twice (resampling, then the
/// texture), which smooths edges by up to one voxel: tolerance 24/255 max and 1.5/255 mean.
#[test]
fn warped_rendering_matches_a_prewarped_volume() {
    let Some(ctx) = context(FeatureRequest::default()) else { return };
    let p = Phantoms::new();
    let warp = sample_control(16, CTRL_MIN, CTRL_MAX, smooth_displacement);
    let warped = Scene::new(&ctx, &p, Some(&warp), 16);
    let ctrl = warped.control.as_ref().expect("control");
    // Resample the moving volume at u(x) for every voxel centre x of the fixed grid (same geometry as the CT).
    let fixed_lps_from_index = warped.fixed.info.lps_from_index;
    let mv = &warped.moving;
    let mut pre = Vec::with_capacity(N * N * N);
    for k in 0..N {
        for j in 0..N {
            for i in 0..N {
                let x = fixed_lps_from_index.transform_point3(DVec3::new(i as f64, j as f64, k as f64)).as_vec3();
                let u = x + ctrl.displacement(x);
                let t = mv.info.tex_from_lps.transform_point3(u);
                let inside = t.cmpge(glam::Vec3::ZERO).all() && t.cmple(glam::Vec3::ONE).all();
                let v = if inside { trilinear(mv.info.dims, t, |n| Vec4::splat(mv.value(n))).x } else { 0.0 };
                pre.push(v);
            }
        }
    }
    let pre_desc = VolumeDesc { dims: [N; 3], samples: VolumeSamples::F32(&pre), lps_from_index: p.ct_lps_from_index };
    let mut prewarped = Scene::new(&ctx, &p, None, 16);
    prewarped.moving = warpbench_gpu::PreparedVolume::prepare(
        &pre_desc,
        ctx.capabilities,
        warpbench_gpu::VolumeBudget::for_device(&ctx.limits),
    )
    .expect("prewarped");
    let cam = OrbitCamera { azimuth_rad: 0.6, elevation_rad: 0.25, ..front_ortho() };
    let a = GpuScene::new(&ctx, &warped).render(&ctx, &warped, &warped.uniforms(&cam, &moving_only(), SIZE));
    let b = GpuScene::new(&ctx, &prewarped).render(&ctx, &prewarped, &prewarped.uniforms(&cam, &moving_only(), SIZE));
    let (max, _) = max_diff(&a, &b, 0);
    let mean = a.iter().zip(&b).map(|(x, y)| f64::from(x.abs_diff(*y))).sum::<f64>() / a.len() as f64;
    eprintln!("warped vs pre-warped: max {max}/255, mean {mean:.3}/255, coverage {:.2}", coverage(&a));
    assert!(max <= 24 && mean <= 1.5 && coverage(&a) > 0.2, "max {max}, mean {mean}");
}

/// The proxy box follows the warp: a constant displacement d = (−120, 0, 0) mm moves the moving volume's content
/// 120 mm towards +x, past the fixed box (±96 mm) and the control texture's box (±96 mm). With the automatic proxy
/// box it is still drawn whole, and matches the same volume translated by +120 mm and rendered without a warp
/// (the two proxy boxes are the same, so the samples are the same points). Tolerance 2/255: sampler rounding of
/// texture coordinates that differ by f32 rounding.
#[test]
fn content_warped_outside_the_fixed_box_is_drawn() {
    let Some(ctx) = context(FeatureRequest::default()) else { return };
    let shift_mm = 120.0f32;
    let p = Phantoms::new();
    let mut translated = Phantoms::new();
    translated.mr_lps_from_index[0][3] += f64::from(shift_mm);
    let d = vec![[-shift_mm, 0.0, 0.0, 0.0]; 4 * 4 * 4].concat();
    let warped = Scene::new(&ctx, &p, Some(&d), 4);
    let moved = Scene::new(&ctx, &translated, None, 4);
    let cam = OrbitCamera::fit(v3(-150.0, -150.0, -150.0), v3(350.0, 350.0, 350.0), Projection::Orthographic);
    let settings = RenderSettings { blend: BlendMode::MovingOnly, ..Default::default() };
    let (uw, um) = (warped.uniforms(&cam, &settings, SIZE), moved.uniforms(&cam, &settings, SIZE));
    assert!(uw.box_max_ref[0] > 96.0 + shift_mm, "proxy box {:?}..{:?}", uw.box_min_ref, uw.box_max_ref);
    let a = GpuScene::new(&ctx, &warped).render(&ctx, &warped, &uw);
    let b = GpuScene::new(&ctx, &moved).render(&ctx, &moved, &um);
    // Pixels whose ref x is beyond the fixed and control boxes (x > 110 mm; image x = ref x, front view).
    let pixel_mm = cam.pixel_mm(SIZE.1);
    let first_col = ((110.0 - cam.target_ref.x) / pixel_mm + SIZE.0 as f32 / 2.0).ceil() as usize;
    let w = SIZE.0 as usize;
    let beyond = |img: &[u8]| {
        (0..SIZE.1 as usize)
            .flat_map(|y| (first_col..w).map(move |x| (y, x)))
            .filter(|&(y, x)| img[4 * (y * w + x) + 3] > 0)
            .count()
    };
    let (max, _) = max_diff(&a, &b, 0);
    eprintln!(
        "warped outside the fixed box: max {max}/255 vs translated, {} px beyond x = 110 mm (translated: {})",
        beyond(&a),
        beyond(&b)
    );
    assert!(beyond(&a) > 50 && beyond(&a) == beyond(&b), "content beyond the fixed box is cut");
    assert!(max <= 2, "max {max}");
}
