//! Laws of the warped rendering, GPU only (64³ volumes, 64×64 images, no jitter).

mod common;

use common::*;
use glam::{DVec3, Vec4};
use warpbench_gpu::sampling::trilinear;
use warpbench_gpu::{
    BlendMode, FeatureRequest, LayerStyle, OrbitCamera, PrefilterSettings, PrefilteredTexels, PreparedVolume,
    Projection, RenderSettings, Shading, ShadingMode, TransferFunction, VolumeBudget, VolumeDesc, VolumeSamples,
    Window,
};

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

fn ball(p: &Phantoms) -> Vec<f32> {
    let m = p.ct_lps_from_index;
    let mut out = Vec::with_capacity(N * N * N);
    for k in 0..N {
        for j in 0..N {
            for i in 0..N {
                let x = DVec3::new(
                    m[0][0] * i as f64 + m[0][3],
                    m[1][1] * j as f64 + m[1][3],
                    m[2][2] * k as f64 + m[2][3],
                );
                let edge = |r: f64, r0: f64| (0.5 - (r - r0) / 6.0).clamp(0.0, 1.0);
                let v = edge(x.length(), 45.0).max(edge((x - DVec3::new(30.0, -25.0, 20.0)).length(), 18.0));
                out.push(v as f32);
            }
        }
    }
    out
}

/// A non-rigid warp: an anisotropic stretch plus a bend, so the deformed ball's normals differ from the ball's.
fn squash(x: DVec3) -> DVec3 {
    DVec3::new(0.3 * x.x, -0.15 * x.y + 6.0 * (x.x / 35.0).sin(), 8.0 * (x.y / 40.0).sin())
}

/// The lighting follows the deformation (Brunet et al. 2006 §3.4): a ball rendered and shaded *through* a non-rigid
/// warp equals the ball resampled through the same warp on the CPU (trilinear onto the fixed grid; its prefiltered
/// copy resampled the same way) and rendered and shaded without a warp: the gradients taken through the warp are
/// the gradients of the deformed volume. DVR and iso. The pre-warped volume is interpolated twice (resampling,
/// then the texture), which shifts edges by a fraction of a voxel; an iso hit is a threshold decision, so a grazing
/// ray can hit in one image and miss in the other. Tolerance: mean 1.5/255, and at most 20 of 4096 pixels over
/// 24/255. Measured on lavapipe (Mesa 22.3.6, llvmpipe LLVM 15): DVR max 18/255, mean 0.25, no outliers; iso mean
/// 0.26 with a few silhouette outliers. The warp must change the image: ≥ 60/255 from the unwarped ball.
#[test]
fn shading_follows_the_deformation() {
    let Some(ctx) = context(FeatureRequest::default()) else { return };
    let p = Phantoms::new();
    let budget = VolumeBudget::for_device(&ctx.limits);
    let pf_settings = PrefilterSettings { sigma_vox: 1.0, half_resolution: false };
    let samples = ball(&p);
    let desc = VolumeDesc { dims: [N; 3], samples: VolumeSamples::F32(&samples), lps_from_index: p.ct_lps_from_index };
    let ball_vol = PreparedVolume::prepare(&desc, ctx.capabilities, budget).expect("ball");
    let warp = sample_control(16, CTRL_MIN, CTRL_MAX, squash);
    let style = LayerStyle {
        window: Window::from_range(0.0, 1.0),
        tf_row: 1,
        opacity_scale: 1.0,
        visible: true,
        iso_value: 0.5,
    };
    let tf = TransferFunction::from_points(
        "ball",
        &[
            (0.0, [0.9, 0.8, 0.6, 0.0]),
            (0.3, [0.9, 0.8, 0.6, 0.0]),
            (0.7, [0.9, 0.8, 0.6, 0.5]),
            (1.0, [0.9, 0.8, 0.6, 0.5]),
        ],
    );
    // Only the moving layer is drawn, and only it has a prefiltered copy (the GPU pass's, unless replaced).
    let with_ball = |warp: Option<&[f32]>, vol: PreparedVolume| {
        let mut s = Scene::new(&ctx, &p, warp, 16);
        s.prefilter = Some(pf_settings);
        s.moving_pf = Some(PrefilteredTexels::from_volume(&vol, pf_settings));
        s.moving = vol;
        s.moving_style = style;
        s.tfs[1] = tf.clone();
        s
    };
    let warped = with_ball(Some(&warp), ball_vol.clone());
    let plain = with_ball(None, ball_vol.clone());
    // Pre-warp the ball and its prefiltered copy: the value at u(x) for every voxel centre x of the fixed grid.
    let ctrl = warped.control.as_ref().expect("control");
    let pf = warped.moving_pf.as_ref().expect("prefiltered");
    let (mut pre, mut pre_pf) = (Vec::with_capacity(N * N * N), Vec::with_capacity(N * N * N));
    for k in 0..N {
        for j in 0..N {
            for i in 0..N {
                let x = DVec3::from_array(std::array::from_fn(|r| {
                    let m = p.ct_lps_from_index[r];
                    m[0] * i as f64 + m[1] * j as f64 + m[2] * k as f64 + m[3]
                }))
                .as_vec3();
                let t = ball_vol.info.tex_from_lps.transform_point3(x + ctrl.displacement(x));
                let inside = t.cmpge(glam::Vec3::ZERO).all() && t.cmple(glam::Vec3::ONE).all();
                let v = trilinear(ball_vol.info.dims, t, |n| Vec4::splat(ball_vol.value(n))).x;
                pre.push(if inside { v } else { 0.0 });
                pre_pf.push(trilinear(pf.dims, t, |n| Vec4::splat(pf.texels[n])).x);
            }
        }
    }
    let pre_desc = VolumeDesc { dims: [N; 3], samples: VolumeSamples::F32(&pre), lps_from_index: p.ct_lps_from_index };
    let mut prewarped = with_ball(None, PreparedVolume::prepare(&pre_desc, ctx.capabilities, budget).expect("pre"));
    // The pre-warped copy's texels are normalised like the ball's (both span [0, 1] or are raw f32).
    // Uploaded as it is: no GPU pass for this one.
    prewarped.moving_pf = Some(PrefilteredTexels::new([N as u32; 3], pre_pf));
    prewarped.prefilter = None;

    let gpu_warped = GpuScene::new(&ctx, &warped);
    let gpu_plain = GpuScene::new(&ctx, &plain);
    let gpu_pre = GpuScene::new(&ctx, &prewarped);
    let cam = OrbitCamera { azimuth_rad: 0.7, elevation_rad: 0.35, zoom: 2.2, ..front_ortho() };
    let mut failures = Vec::new();
    for mode in [ShadingMode::Dvr, ShadingMode::Iso] {
        let settings = RenderSettings { shading: Shading::with_mode(mode), ..moving_only() };
        // One renderer (one pipeline compile) for the three scenes.
        let r = &gpu_warped.renderer;
        let a = gpu_warped.render_by(&ctx, r, &warped, &warped.uniforms(&cam, &settings, SIZE));
        let b = gpu_pre.render_by(&ctx, r, &prewarped, &prewarped.uniforms(&cam, &settings, SIZE));
        let c = gpu_plain.render_by(&ctx, r, &plain, &plain.uniforms(&cam, &settings, SIZE));
        let (max, _) = max_diff(&a, &b, 0);
        let mean = a.iter().zip(&b).map(|(x, y)| f64::from(x.abs_diff(*y))).sum::<f64>() / a.len() as f64;
        let outliers = pixels_over(&a, &b, 24);
        let (unwarped, _) = max_diff(&a, &c, 0);
        let line = format!(
            "{}: warped vs pre-warped max {max}/255, mean {mean:.3}/255, {outliers} px > 24/255; vs the unwarped \
             ball max {unwarped}/255; coverage {:.2}",
            mode.name(),
            coverage(&a)
        );
        eprintln!("{line}");
        if outliers > 20 || mean > 1.5 || unwarped < 60 || coverage(&a) < 0.2 {
            failures.push(line);
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// A frame rendered band by band (uneven bands, one of a single row, the last past the bottom; jitter and shading
/// on) equals the frame rendered at once, colour and first-hit depth, bit for bit: a pixel's ray depends on that
/// pixel only. A later band changes only its own rows.
#[test]
fn a_frame_rendered_in_bands_equals_the_whole_frame() {
    let Some(ctx) = context(FeatureRequest::default()) else { return };
    let p = Phantoms::new();
    let warp = sample_control(16, CTRL_MIN, CTRL_MAX, smooth_displacement);
    let scene = Scene::new(&ctx, &p, Some(&warp), 16);
    let gpu = GpuScene::new(&ctx, &scene);
    let cam = OrbitCamera { azimuth_rad: 0.5, elevation_rad: 0.3, ..front_ortho() };
    let settings = RenderSettings {
        jitter_seed: Some(7),
        shading: Shading::with_mode(ShadingMode::Dvr),
        ..RenderSettings::default()
    };
    let u = scene.uniforms(&cam, &settings, SIZE);
    let whole = gpu.render_target(&ctx, &gpu.renderer, &scene, &u);
    let banded = warpbench_gpu::RenderTarget::new(&ctx, SIZE.0, SIZE.1);
    gpu.render_rows_into(&ctx, &gpu.renderer, &scene, &u, &banded, &[0..7, 7..30, 30..31, 31..90]);
    let read =
        |t: &warpbench_gpu::RenderTarget| (t.read_back(&ctx).expect("colour"), t.read_hit_depth(&ctx).expect("depth"));
    let (whole_rgba, whole_depth) = read(&whole);
    assert!(coverage(&whole_rgba) > 0.2, "the frame shows too little: {}", coverage(&whole_rgba));
    let (banded_rgba, banded_depth) = read(&banded);
    assert!(whole_rgba == banded_rgba, "colour differs: {:?}", max_diff(&whole_rgba, &banded_rgba, 0));
    assert!(whole_depth.iter().map(|d| d.to_bits()).eq(banded_depth.iter().map(|d| d.to_bits())), "hit depth differs");

    // Another frame over rows 20..30 only: those rows become the other frame's, the rest stay.
    let other = scene.uniforms(&cam, &RenderSettings { blend: BlendMode::Difference, ..settings }, SIZE);
    let other_rgba = gpu.render(&ctx, &scene, &other);
    gpu.render_rows_into(&ctx, &gpu.renderer, &scene, &other, &banded, std::slice::from_ref(&(20..30)));
    let (mixed, _) = read(&banded);
    let row = |img: &[u8], y: usize| img[4 * SIZE.0 as usize * y..4 * SIZE.0 as usize * (y + 1)].to_vec();
    let changed = (0..SIZE.1 as usize).filter(|&y| row(&whole_rgba, y) != row(&other_rgba, y)).count();
    assert!(changed > 10, "the two frames should differ on many rows: {changed}");
    for y in 0..SIZE.1 as usize {
        let expected = if (20..30).contains(&y) { row(&other_rgba, y) } else { row(&whole_rgba, y) };
        assert!(row(&mixed, y) == expected, "row {y} is not the expected frame's");
    }
}
