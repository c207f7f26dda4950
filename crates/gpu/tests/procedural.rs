//! Deformations computed in the shader: procedural deformations of a layer's data ([`warpbench_gpu::procedural`])
//! and deformations of the view ([`warpbench_gpu::view_deformation`], the fish-eye lens). The identities the renderer
//! states (a zero amplitude is the undeformed frame bit for bit; a shift is the volume translated), every kind
//! against the CPU reference in frames and slices, the shader against a control texture of the same deformation, and
//! the lens against its formula evaluated by the test. Picking through them is in `pick.rs`, empty-space skipping in
//! `empty_space.rs`.
//!
//! Tolerances:
//! - GPU vs CPU: derived from the device's filter as in `gpu_vs_cpu.rs` and `slices.rs` ([`Allowance`], their docs
//!   say why); the shader's sin, cos and exp may differ from Rust's f32 ones by a few ulps, which moves a sample by
//!   < 10⁻⁴ mm here.
//! - A shift against the translated volume: the same texture coordinates up to f32 rounding of y + t against
//!   (y − (−t)) folded into the matrix; measured 0–1/255, allowed 2/255.
//! - Shader against a 64³ control texture: trilinear interpolation of a sine of wavenumber k and amplitude A along
//!   one axis errs by at most h²/8·A·k² (h the texel spacing along that axis); on a linear ramp v(y) = g·y the value
//!   then errs by at most Σₐ |gₐ|·h²/8·A·kₐ², plus the f32 storage and the hardware filter's weights, which a device
//!   rounds to 2⁻ᵇ ([`DeviceFilter`]: A·k·h/2ᵇ per component of the control texture, |gₐ|·3 mm/2ᵇ for the ramp's
//!   own lookups), plus one grey level of rounding on each side.

mod common;

use common::*;
use glam::{DVec3, Vec3};
use warpbench_gpu::{
    Axis, BlendMode, ControlDesc, FeatureRequest, OrbitCamera, PrefilterSettings, PreparedControl, PreparedVolume,
    Procedural, Projection, RenderSettings, Shading, ShadingMode, SlicePlane, TransferFunction, ViewDeformation,
    VolumeBudget, VolumeDesc, VolumeSamples, Window,
};

const SIZE: (u32, u32) = (64, 64);

fn camera() -> OrbitCamera {
    let cam =
        OrbitCamera::fit(v3(-70.0, -70.0, -70.0), v3(70.0, 70.0, 70.0), Projection::Perspective { fov_y_rad: 0.6 });
    OrbitCamera { azimuth_rad: 0.5, elevation_rad: 0.3, ..cam }
}

/// One deformation of each kind whose largest displacement over the phantoms' ±100 mm is about `amplitude_mm`.
fn kinds(amplitude_mm: f32) -> Vec<Procedural> {
    let c = Vec3::new(4.0, -3.0, 2.0);
    let a = amplitude_mm;
    vec![
        Procedural::Shift { offset_mm: Vec3::new(0.7, -0.45, 0.55) * a },
        Procedural::Sine {
            origin_mm: c,
            amplitude_mm: a,
            wavenumber_per_mm: Vec3::splat(std::f32::consts::TAU / 190.0),
            phase_rad: Vec3::new(0.3, 1.7, 4.0),
        },
        // θ·R ≈ 2A at the far faces (R ≈ 90 mm from the axis, 96 mm along it).
        Procedural::Twist { centre_mm: c, axis: Axis::X, rate_rad_per_mm: 2.0 * a / (90.0 * 96.0) },
        // κ s²/2 ≈ A at s = 96 mm.
        Procedural::bend(c, Axis::Y, Axis::X, true, 2.0 * a / (96.0 * 96.0)),
        Procedural::Bump {
            centre_mm: c + Vec3::new(15.0, 0.0, 10.0),
            sigma_mm: 30.0,
            vector_mm: Vec3::new(0.8, -0.36, 0.48) * a,
        },
    ]
}

fn warped_scene(ctx: &warpbench_gpu::GpuContext, phantoms: &Phantoms, warp: &[f32]) -> Scene {
    Scene::new(ctx, phantoms, Some(warp), 16)
}

/// A zero amplitude of every kind gives the undeformed frame bit for bit (colour and first-hit depth, unlit and lit
/// through the landmark warp's control texture, with the same proxy box), and the same slices bit for bit.
#[test]
fn a_zero_amplitude_gives_the_undeformed_frame_exactly() {
    let Some(ctx) = context(FeatureRequest::default()) else { return };
    let phantoms = Phantoms::new();
    let warp = sample_control(16, CTRL_MIN, CTRL_MAX, smooth_displacement);
    let mut scene = warped_scene(&ctx, &phantoms, &warp);
    let gpu = GpuScene::new(&ctx, &scene);
    let plane = SlicePlane::oblique([5.0, -3.0, 8.0], [1.0, 2.0, 3.0], [0.0, 0.0, 1.0], 2.2, (64, 64)).expect("plane");
    let mut expected = Vec::new();
    let box_ref = scene.params().1.box_ref();
    let box_override_ref = Some((box_ref.0.as_vec3() - Vec3::splat(20.0), box_ref.1.as_vec3() + Vec3::splat(20.0)));
    let looks: Vec<RenderSettings> = [ShadingMode::None, ShadingMode::Dvr, ShadingMode::Iso]
        .into_iter()
        .map(|mode| RenderSettings { shading: Shading::with_mode(mode), box_override_ref, ..Default::default() })
        .collect();
    for settings in &looks {
        let u = scene.uniforms(&camera(), settings, SIZE);
        let target = gpu.render_target(&ctx, &gpu.renderer, &scene, &u);
        expected.push((target.read_back(&ctx).expect("colour"), target.read_hit_depth(&ctx).expect("depth")));
    }
    let slice =
        gpu.render_slice(&ctx, &gpu.renderer, &scene, &scene.slice_uniforms(&plane, &RenderSettings::default()));
    assert!(coverage(&expected[0].0) > 0.2 && coverage(&slice) > 0.3, "something to see");
    for p in kinds(0.0) {
        scene.moving_procedural = Some(p);
        for (settings, (colour, depth)) in looks.iter().zip(&expected) {
            let u = scene.uniforms(&camera(), settings, SIZE);
            let target = gpu.render_target(&ctx, &gpu.renderer, &scene, &u);
            let mode = settings.shading.mode.name();
            assert!(&target.read_back(&ctx).expect("colour") == colour, "{} {mode}: the colour changed", p.name());
            let d = target.read_hit_depth(&ctx).expect("depth");
            assert!(
                d.iter().zip(depth).all(|(a, b)| a.to_bits() == b.to_bits()),
                "{} {mode}: the depth changed",
                p.name()
            );
        }
        let u = scene.slice_uniforms(&plane, &RenderSettings::default());
        assert!(gpu.render_slice(&ctx, &gpu.renderer, &scene, &u) == slice, "{}: the slice changed", p.name());
    }
    // The lens at zero amplitude, on both layers.
    scene.moving_procedural = None;
    scene.views =
        [Some(ViewDeformation::FishEye { centre_ref: Vec3::new(10.0, 0.0, 5.0), radius_mm: 40.0, amplitude: 0.0 }); 2];
    for (settings, (colour, depth)) in looks.iter().zip(&expected) {
        let u = scene.uniforms(&camera(), settings, SIZE);
        let target = gpu.render_target(&ctx, &gpu.renderer, &scene, &u);
        assert!(&target.read_back(&ctx).expect("colour") == colour, "lens {}: colour", settings.shading.mode.name());
        let d = target.read_hit_depth(&ctx).expect("depth");
        assert!(d.iter().zip(depth).all(|(a, b)| a.to_bits() == b.to_bits()), "lens: the depth changed");
    }
    let u = scene.slice_uniforms(&plane, &RenderSettings::default());
    assert!(gpu.render_slice(&ctx, &gpu.renderer, &scene, &u) == slice, "lens: the slice changed");
    // The leafer closed, on both layers.
    let closed = ViewDeformation::leafer(Vec3::new(5.0, 0.0, 0.0), Vec3::new(0.3, -1.0, 0.2), Vec3::Z, 50.0, 0.0);
    scene.views = [closed; 2];
    for (settings, (colour, depth)) in looks.iter().zip(&expected) {
        let u = scene.uniforms(&camera(), settings, SIZE);
        let target = gpu.render_target(&ctx, &gpu.renderer, &scene, &u);
        assert!(&target.read_back(&ctx).expect("colour") == colour, "leafer {}: colour", settings.shading.mode.name());
        let d = target.read_hit_depth(&ctx).expect("depth");
        assert!(d.iter().zip(depth).all(|(a, b)| a.to_bits() == b.to_bits()), "leafer: the depth changed");
    }
    let u = scene.slice_uniforms(&plane, &RenderSettings::default());
    assert!(gpu.render_slice(&ctx, &gpu.renderer, &scene, &u) == slice, "leafer: the slice changed");
}

/// Every kind through the landmark warp's control texture: the GPU frame (unlit; lit DVR and iso for two kinds, with
/// gradients from the prefiltered copies as `gpu_vs_cpu.rs` compares them, and its allowance of 0.5 % of iso
/// silhouette pixels) and slice match the CPU reference, and the deformation visibly changes the unlit frame.
#[test]
fn every_kind_matches_the_cpu_reference() {
    let Some(ctx) = context(FeatureRequest::default()) else { return };
    let filter = DeviceFilter::measure(&ctx);
    let phantoms = Phantoms::new();
    let warp = sample_control(16, CTRL_MIN, CTRL_MAX, smooth_displacement);
    let mut scene = warped_scene(&ctx, &phantoms, &warp).with_prefilter(PrefilterSettings::default());
    let gpu = GpuScene::new(&ctx, &scene);
    let plane = SlicePlane::axial(&phantoms.ct_lps_from_index, [N; 3], 10.0);
    let slice_settings = RenderSettings { blend: BlendMode::MovingOnly, ..Default::default() };
    let undeformed_slice = scene.cpu_slice(&scene.slice_uniforms(&plane, &slice_settings));
    let undeformed_frame = scene.cpu(&scene.uniforms(&camera(), &RenderSettings::default(), SIZE));
    let (mut report, mut failures) = (Vec::new(), Vec::new());
    for p in kinds(6.0) {
        scene.moving_procedural = Some(p);
        // Channels the deformation moves in the frames (by > 2) and the slice (by > 8): none if it were ignored.
        let mut frame_moved = 0;
        let mut looks = vec![ShadingMode::None];
        if matches!(p, Procedural::Bend { .. }) {
            looks.push(ShadingMode::Dvr);
        }
        if matches!(p, Procedural::Twist { .. }) {
            looks.push(ShadingMode::Iso);
        }
        for mode in looks {
            let settings = RenderSettings { shading: Shading::with_mode(mode), ..Default::default() };
            let u = scene.uniforms(&camera(), &settings, SIZE);
            let g = gpu.render(&ctx, &scene, &u);
            let allowance = scene.allowance(&u, filter);
            let c = &allowance.exact;
            let (ok, verdict) = allowance.judge(&g, Look::of(mode));
            let (_, moved) = max_diff(c, &undeformed_frame, 2);
            report.push(format!(
                "{} {}: {verdict}; {moved} channels moved by > 2 by the deformation",
                p.name(),
                mode.name()
            ));
            frame_moved = frame_moved.max(moved);
            if !ok || coverage(c) < 0.2 {
                failures.push(report.last().cloned().unwrap_or_default());
            }
        }
        let u = scene.slice_uniforms(&plane, &slice_settings);
        let g = gpu.render_slice(&ctx, &gpu.renderer, &scene, &u);
        let allowance = scene.slice_allowance(&u, filter);
        let (ok, verdict) = allowance.judge(&g, Look::Smooth);
        let (_, moved) = max_diff(&allowance.exact, &undeformed_slice, 8);
        report.push(format!("{} slice: {verdict}; {moved} channels moved by > 8 by the deformation", p.name()));
        if !ok || frame_moved + moved < 40 {
            failures.push(report.last().cloned().unwrap_or_default());
        }
    }
    eprintln!("{}", report.join("\n"));
    assert!(failures.is_empty(), "procedural deformations:\n{}", failures.join("\n"));
}

/// A shift by t shows the volume translated by −t: the same frame and slice as the undeformed volume whose
/// `lps_from_index` is moved by −t (an independent path: the geometry, not the shader's deformation).
#[test]
fn a_shift_is_the_volume_translated() {
    let Some(ctx) = context(FeatureRequest::default()) else { return };
    let phantoms = Phantoms::new();
    let t = DVec3::new(9.0, -6.0, 4.5);
    let mut shifted = Scene::new(&ctx, &phantoms, None, 16);
    shifted.moving_procedural = Some(Procedural::Shift { offset_mm: t.as_vec3() });
    let mut moved = Phantoms::new();
    for (row, offset) in t.to_array().into_iter().enumerate() {
        moved.mr_lps_from_index[row][3] -= offset;
    }
    let translated = Scene::new(&ctx, &moved, None, 16);
    let (a, b) = (GpuScene::new(&ctx, &shifted), GpuScene::new(&ctx, &translated));
    // The proxy boxes agree but for the procedural bound's slack: draw both in the same box.
    let (lo, hi) = shifted.params().1.box_ref();
    let settings = RenderSettings {
        blend: BlendMode::MovingOnly,
        box_override_ref: Some((lo.as_vec3(), hi.as_vec3())),
        ..Default::default()
    };
    let (translated_lo, translated_hi) = translated.params().1.box_ref();
    assert!((lo - translated_lo).abs().max_element() <= 0.011 && (hi - translated_hi).abs().max_element() <= 0.011);
    let (ua, ub) = (shifted.uniforms(&camera(), &settings, SIZE), translated.uniforms(&camera(), &settings, SIZE));
    let (fa, fb) = (a.render(&ctx, &shifted, &ua), b.render_by(&ctx, &a.renderer, &translated, &ub));
    let (frame_max, _) = max_diff(&fa, &fb, 0);
    let plane = SlicePlane::coronal(&phantoms.ct_lps_from_index, [N; 3], -5.0);
    let (sa, sb) = (shifted.slice_uniforms(&plane, &settings), translated.slice_uniforms(&plane, &settings));
    let (ga, gb) =
        (a.render_slice(&ctx, &a.renderer, &shifted, &sa), b.render_slice(&ctx, &a.renderer, &translated, &sb));
    let (slice_max, _) = max_diff(&ga, &gb, 0);
    let unshifted = Scene::new(&ctx, &phantoms, None, 16);
    let su = unshifted.slice_uniforms(&plane, &settings);
    let (_, changed) = max_diff(&a.render_slice(&ctx, &a.renderer, &unshifted, &su), &ga, 8);
    eprintln!("shift against translation: frame max {frame_max}/255, slice max {slice_max}/255; {changed} moved");
    assert!(coverage(&fa) > 0.2 && changed > 300, "the shift should visibly move the volume");
    assert!(frame_max <= 2 && slice_max <= 2, "frame {frame_max}/255, slice {slice_max}/255");
}

/// The ramp's voxel spacing, mm.
const RAMP_SPACING_MM: f64 = 3.0;

/// A linear ramp v(y) = g·y (mm → value) on a 32³ grid of [`RAMP_SPACING_MM`], centred on 0.
fn ramp_volume(ctx: &warpbench_gpu::GpuContext, g: DVec3) -> PreparedVolume {
    let n = 32;
    let lps_from_index = grid_lps_from_index(n, RAMP_SPACING_MM, [0.0; 3], 0.0);
    let values: Vec<f32> = (0..n * n * n)
        .map(|i| {
            let idx = [(i % n) as f64, ((i / n) % n) as f64, (i / n / n) as f64];
            let y: [f64; 3] = std::array::from_fn(|r| {
                (0..3).map(|c| lps_from_index[r][c] * idx[c]).sum::<f64>() + lps_from_index[r][3]
            });
            g.dot(DVec3::from_array(y)) as f32
        })
        .collect();
    let desc = VolumeDesc { dims: [n; 3], samples: VolumeSamples::F32(&values), lps_from_index };
    PreparedVolume::prepare(&desc, ctx.capabilities, VolumeBudget::for_device(&ctx.limits)).expect("ramp")
}

/// Brunet et al.'s comparison as a law: the sine computed in the shader and the same sine sampled into a 64³ control
/// texture give slices of a linear ramp that differ by no more than the texture's interpolation error (module docs),
/// while the deformation itself moves them by much more.
#[test]
fn the_shader_and_a_control_texture_agree_within_its_sampling_error() {
    let Some(ctx) = context(FeatureRequest::default()) else { return };
    let weight_step = 1.0 / f64::from(1u32 << DeviceFilter::measure(&ctx).bits);
    let g = DVec3::new(1.0, 0.5, -0.25);
    let ramp = ramp_volume(&ctx, g);
    let (a_mm, k_per_mm) = (5.0f32, std::f32::consts::TAU / 40.0);
    let sine = Procedural::Sine {
        origin_mm: Vec3::ZERO,
        amplitude_mm: a_mm,
        wavenumber_per_mm: Vec3::splat(k_per_mm),
        phase_rad: Vec3::new(0.4, 1.1, 2.3),
    };
    let phantoms = Phantoms::new();
    let mut shader = Scene::new(&ctx, &phantoms, None, 16);
    shader.fixed = ramp.clone();
    shader.moving = ramp;
    shader.tfs =
        vec![TransferFunction::from_points("grey", &[(0.0, [0.0, 0.0, 0.0, 1.0]), (1.0, [1.0, 1.0, 1.0, 1.0])])];
    let window = 80.0;
    shader.moving_style = warpbench_gpu::LayerStyle {
        window: Window::from_range(-window / 2.0, window / 2.0),
        tf_row: 0,
        ..shader.moving_style
    };
    shader.fixed_style = shader.moving_style;
    let plain = Scene { control: None, ..clone_scene(&shader) };
    shader.moving_procedural = Some(sine);
    // The same deformation through a 64³ control texture over the ramp's preimage box.
    let (lo, hi) = shader.params().1.box_ref();
    let n = 64;
    let texels = sine.control_texels([n; 3], lo.to_array(), hi.to_array());
    let desc = ControlDesc { dims: [n; 3], texels: &texels, box_min_ref: lo.to_array(), box_max_ref: hi.to_array() };
    let texture = Scene {
        control: Some(PreparedControl::prepare(&desc, ctx.capabilities.float32_filterable).expect("control")),
        ..clone_scene(&plain)
    };
    let (gs, gt, gp) = (GpuScene::new(&ctx, &shader), GpuScene::new(&ctx, &texture), GpuScene::new(&ctx, &plain));
    // Planes well inside the ramp (±48 mm) so that every pixel reads it on both paths.
    let settings = RenderSettings { blend: BlendMode::MovingOnly, ..Default::default() };
    let h = (hi - lo) / f64::from(n as u32);
    let k = f64::from(k_per_mm);
    let interpolation =
        (0..3).map(|a| g[a].abs() * h[(a + 1) % 3].powi(2) / 8.0 * f64::from(a_mm) * k * k).sum::<f64>();
    let sampler = (0..3)
        .map(|a| g[a].abs() * (f64::from(a_mm) * k * h[(a + 1) % 3] + RAMP_SPACING_MM) * weight_step)
        .sum::<f64>();
    let grey_per_value = 255.0 / f64::from(window);
    let allowed = ((interpolation + sampler) * grey_per_value).ceil() as u8 + 2;
    for (name, plane) in [
        ("sagittal", SlicePlane::oblique([0.0, 0.0, 3.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0], 1.0, (64, 64))),
        ("oblique", SlicePlane::oblique([2.0, -1.0, 0.0], [1.0, 1.0, 0.0], [0.0, 0.3, 1.0], 1.0, (64, 64))),
    ] {
        let plane = plane.expect("plane");
        let u = |s: &Scene| s.slice_uniforms(&plane, &settings);
        let a = gs.render_slice(&ctx, &gs.renderer, &shader, &u(&shader));
        let b = gt.render_slice(&ctx, &gs.renderer, &texture, &u(&texture));
        let c = gp.render_slice(&ctx, &gs.renderer, &plain, &u(&plain));
        let (max, _) = max_diff(&a, &b, 0);
        let (moved, _) = max_diff(&a, &c, 0);
        eprintln!(
            "{name}: shader vs 64³ texture max {max}/255 (bound {allowed}: interpolation {interpolation:.4}, sampler \
             {sampler:.4} value units); the deformation moves it by up to {moved}/255"
        );
        assert!(a.chunks_exact(4).all(|p| p[3] == 255) && b.chunks_exact(4).all(|p| p[3] == 255), "{name}: all inside");
        assert!(max <= allowed, "{name}: shader and control texture differ by {max}/255 > {allowed}");
        assert!(moved >= 3 * allowed, "{name}: the deformation moves the slice by only {moved}/255");
    }
}

fn clone_scene(s: &Scene) -> Scene {
    Scene {
        fixed: s.fixed.clone(),
        moving: s.moving.clone(),
        control: s.control.clone(),
        tfs: s.tfs.clone(),
        fixed_style: s.fixed_style,
        moving_style: s.moving_style,
        prefilter: s.prefilter,
        fixed_pf: s.fixed_pf.clone(),
        moving_pf: s.moving_pf.clone(),
        moving_procedural: s.moving_procedural,
        views: s.views,
    }
}

/// The fish-eye lens on both layers, through the warp: the GPU frame (unlit and lit) and slice match the CPU
/// reference, and the lens visibly magnifies.
#[test]
fn the_fish_eye_lens_matches_the_cpu_reference() {
    let Some(ctx) = context(FeatureRequest::default()) else { return };
    let filter = DeviceFilter::measure(&ctx);
    let phantoms = Phantoms::new();
    let warp = sample_control(16, CTRL_MIN, CTRL_MAX, smooth_displacement);
    let mut scene = warped_scene(&ctx, &phantoms, &warp).with_prefilter(PrefilterSettings::default());
    let gpu = GpuScene::new(&ctx, &scene);
    let plane = SlicePlane::axial(&phantoms.ct_lps_from_index, [N; 3], 10.0);
    let settings = RenderSettings::default();
    let plain_frame = scene.cpu(&scene.uniforms(&camera(), &settings, SIZE));
    let plain_slice = scene.cpu_slice(&scene.slice_uniforms(&plane, &settings));
    // On the skull, facing the camera: the shell is what an unlit frame shows.
    scene.views =
        [Some(ViewDeformation::FishEye { centre_ref: Vec3::new(30.0, -65.0, 20.0), radius_mm: 35.0, amplitude: 0.6 });
            2];
    for mode in [ShadingMode::None, ShadingMode::Dvr] {
        let settings = RenderSettings { shading: Shading::with_mode(mode), ..Default::default() };
        let u = scene.uniforms(&camera(), &settings, SIZE);
        let g = gpu.render(&ctx, &scene, &u);
        let allowance = scene.allowance(&u, filter);
        let (ok, verdict) = allowance.judge(&g, Look::Smooth);
        eprintln!("lens {}: from the CPU reference {verdict}", mode.name());
        assert!(ok, "lens {}: {verdict}", mode.name());
        if mode == ShadingMode::None {
            let (most, moved) = max_diff(&allowance.exact, &plain_frame, 2);
            eprintln!("the lens moves the unlit frame by up to {most}/255, {moved} channels by > 2");
            assert!(moved > 100, "the lens moved only {moved} channels of the frame");
        }
    }
    let u = scene.slice_uniforms(&plane, &settings);
    let g = gpu.render_slice(&ctx, &gpu.renderer, &scene, &u);
    let allowance = scene.slice_allowance(&u, filter);
    let (ok, verdict) = allowance.judge(&g, Look::Smooth);
    let (_, moved) = max_diff(&allowance.exact, &plain_slice, 8);
    eprintln!("lens slice: {verdict}, {moved} channels moved by > 8");
    assert!(ok && moved > 100, "lens slice: {verdict}, {moved} moved");
}

/// The lens's formula, evaluated by the test in f64: on a linear ramp v(x) = g·x (grey window [−W/2, W/2]), the
/// slice pixel at x shows g·w(x) with w(x) = x − (x − c)·a (1 − r/R)² inside the ball, within the grey rounding.
#[test]
fn the_fish_eye_lens_shows_its_formula() {
    let Some(ctx) = context(FeatureRequest::default()) else { return };
    let g = DVec3::new(1.0, 0.5, -0.25);
    let ramp = ramp_volume(&ctx, g);
    let phantoms = Phantoms::new();
    let mut scene = Scene::new(&ctx, &phantoms, None, 16);
    scene.fixed = ramp.clone();
    scene.moving = ramp;
    scene.tfs =
        vec![TransferFunction::from_points("grey", &[(0.0, [0.0, 0.0, 0.0, 1.0]), (1.0, [1.0, 1.0, 1.0, 1.0])])];
    let window = 80.0f64;
    scene.fixed_style = warpbench_gpu::LayerStyle {
        window: Window::from_range(-window as f32 / 2.0, window as f32 / 2.0),
        tf_row: 0,
        ..scene.fixed_style
    };
    let (c, radius, a) = (DVec3::new(3.0, -2.0, 1.5), 25.0f64, 0.7f64);
    scene.views =
        [Some(ViewDeformation::FishEye { centre_ref: c.as_vec3(), radius_mm: radius as f32, amplitude: a as f32 }); 2];
    let gpu = GpuScene::new(&ctx, &scene);
    let plane = SlicePlane::oblique(c.to_array(), [1.0, 0.2, 0.0], [0.0, 0.1, 1.0], 1.0, (64, 64)).expect("plane");
    let settings = RenderSettings { blend: BlendMode::FixedOnly, ..Default::default() };
    let image = gpu.render_slice(&ctx, &gpu.renderer, &scene, &scene.slice_uniforms(&plane, &settings));
    let (mut worst, mut inside) = (0.0f64, 0);
    for py in 0..64u32 {
        for px in 0..64u32 {
            let x = DVec3::from_array(plane.ref_from_pixel(f64::from(px), f64::from(py)));
            let r = (x - c).length();
            let w = if r < radius { x - (x - c) * (a * (1.0 - r / radius).powi(2)) } else { x };
            inside += usize::from(r < radius);
            let expected = ((g.dot(w) + window / 2.0) / window).clamp(0.0, 1.0) * 255.0;
            let shown = f64::from(image[4 * (py * 64 + px) as usize]);
            worst = worst.max((shown - expected).abs());
        }
    }
    eprintln!("lens on a ramp: worst |grey − formula| {worst:.2} over 4096 pixels ({inside} in the lens)");
    assert!(inside > 1000, "the plane should cross the lens");
    assert!(worst <= 1.0, "the lens's slice is {worst} grey levels off its formula");
}

/// The camera's ray towards the scene centre and its up vector, for a leafer that opens towards the viewer.
fn towards_viewer(camera: &OrbitCamera) -> (Vec3, Vec3) {
    let clip_from_ref = camera.clip_from_ref(1.0);
    let ref_from_clip = clip_from_ref.inverse();
    let near = ref_from_clip.project_point3(Vec3::new(0.0, 0.0, 0.0));
    let far = ref_from_clip.project_point3(Vec3::new(0.0, 0.0, 1.0));
    let up = ref_from_clip.project_point3(Vec3::new(0.0, 0.5, 0.0)) - near;
    (near - far, up)
}

/// The leafer on the moving layer only, opened towards the camera through the warp: the GPU frame (unlit and lit)
/// and slice match the CPU reference, the frame shows the opening, and the fixed layer is untouched.
#[test]
fn the_leafer_matches_the_cpu_reference() {
    let Some(ctx) = context(FeatureRequest::default()) else { return };
    let filter = DeviceFilter::measure(&ctx);
    let phantoms = Phantoms::new();
    let warp = sample_control(16, CTRL_MIN, CTRL_MAX, smooth_displacement);
    let mut scene = warped_scene(&ctx, &phantoms, &warp).with_prefilter(PrefilterSettings::default());
    let gpu = GpuScene::new(&ctx, &scene);
    let (towards, up) = towards_viewer(&camera());
    let leafer = ViewDeformation::leafer(Vec3::new(4.0, -3.0, 2.0), towards, up, 90.0, 0.5).expect("a leafer");
    let moving_only = RenderSettings { blend: BlendMode::MovingOnly, ..Default::default() };
    let closed = scene.cpu(&scene.uniforms(&camera(), &moving_only, SIZE));
    scene.views = [None, Some(leafer)];
    // The same proxy box with and without the leafer, so that the fixed layer's samples are the same.
    let (lo, hi) = scene.params().1.box_ref();
    let (f_lo, f_hi) = scene.params().0.box_ref();
    let box_override_ref = Some((lo.min(f_lo).as_vec3(), hi.max(f_hi).as_vec3()));
    let fixed_only = RenderSettings { blend: BlendMode::FixedOnly, box_override_ref, ..Default::default() };
    let fixed_before = {
        let plain = Scene { views: [None; 2], ..clone_scene(&scene) };
        plain.cpu(&plain.uniforms(&camera(), &fixed_only, SIZE))
    };
    assert!(scene.cpu(&scene.uniforms(&camera(), &fixed_only, SIZE)) == fixed_before, "the fixed layer is untouched");
    for mode in [ShadingMode::None, ShadingMode::Dvr] {
        let settings = RenderSettings { shading: Shading::with_mode(mode), ..moving_only };
        let u = scene.uniforms(&camera(), &settings, SIZE);
        let g = gpu.render(&ctx, &scene, &u);
        let allowance = scene.allowance(&u, filter);
        let (tolerance, c) = (allowance.tolerance(), &allowance.exact);
        let (max, _) = max_diff(&g, c, BASE_TOLERANCE);
        let outliers = pixels_over(&g, c, tolerance);
        eprintln!("leafer {}: max {max}/255, {outliers} pixels > {tolerance} from the CPU reference", mode.name());
        // The opening's edges are threshold decisions (atan2 against θ) of the shader's and Rust's f32: allow a few
        // silhouette pixels there, as for iso-surfaces.
        assert!(outliers <= 20, "leafer {}: {outliers} pixels differ", mode.name());
        if mode == ShadingMode::None {
            let (_, opened) = max_diff(c, &closed, 8);
            assert!(opened > 500, "the opening changed only {opened} channels");
        }
    }
    let plane = SlicePlane::axial(&phantoms.ct_lps_from_index, [N; 3], 10.0);
    let u = scene.slice_uniforms(&plane, &moving_only);
    let g = gpu.render_slice(&ctx, &gpu.renderer, &scene, &u);
    let allowance = scene.slice_allowance(&u, filter);
    let outliers = pixels_over(&g, &allowance.exact, allowance.tolerance());
    assert!(outliers <= 20, "leafer slice: {outliers} pixels differ");
}

/// The leafer's formula, evaluated by the test in f64: on a linear ramp, a plane across the hinge shows g·w(x) with
/// each half turned back about the hinge, and nothing (transparent) in the opening |φ| < θ.
#[test]
fn the_leafer_shows_its_formula() {
    let Some(ctx) = context(FeatureRequest::default()) else { return };
    let g = DVec3::new(1.0, 0.5, -0.25);
    let ramp = ramp_volume(&ctx, g);
    let phantoms = Phantoms::new();
    let mut scene = Scene::new(&ctx, &phantoms, None, 16);
    scene.fixed = ramp.clone();
    scene.moving = ramp;
    scene.tfs =
        vec![TransferFunction::from_points("grey", &[(0.0, [0.0, 0.0, 0.0, 1.0]), (1.0, [1.0, 1.0, 1.0, 1.0])])];
    let window = 80.0f64;
    scene.fixed_style = warpbench_gpu::LayerStyle {
        window: Window::from_range(-window as f32 / 2.0, window as f32 / 2.0),
        tf_row: 0,
        ..scene.fixed_style
    };
    // Hinge along S through (0, 30, 0), opening towards −P (anterior), 25° each way.
    let (hinge, front, normal, theta) =
        (DVec3::new(0.0, 30.0, 0.0), DVec3::new(0.0, -1.0, 0.0), DVec3::X, 25f64.to_radians());
    let leafer = ViewDeformation::leafer(Vec3::new(0.0, -10.0, 0.0), front.as_vec3(), Vec3::Z, 40.0, theta as f32)
        .expect("a leafer");
    let Some(ViewDeformation::Leafer { hinge_ref, normal: n, .. }) = Some(leafer) else { unreachable!() };
    assert!((hinge_ref.as_dvec3() - hinge).length() < 1e-5 && (n.as_dvec3() - normal).length() < 1e-6, "{leafer:?}");
    scene.views = [Some(leafer); 2];
    let gpu = GpuScene::new(&ctx, &scene);
    // An axial plane (across the vertical hinge) through z = 3.
    let plane = SlicePlane::oblique([0.0, 5.0, 3.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0], 1.0, (64, 64)).expect("plane");
    let settings = RenderSettings { blend: BlendMode::FixedOnly, ..Default::default() };
    let image = gpu.render_slice(&ctx, &gpu.renderer, &scene, &scene.slice_uniforms(&plane, &settings));
    let (mut worst, mut empty, mut turned, mut edge) = (0.0f64, 0, 0, 0);
    for py in 0..64u32 {
        for px in 0..64u32 {
            let x = DVec3::from_array(plane.ref_from_pixel(f64::from(px), f64::from(py)));
            let r = x - hinge;
            let (u, v) = (r.dot(front), r.dot(normal));
            let phi = v.atan2(u);
            let alpha = image[4 * (py * 64 + px) as usize + 3];
            if (phi.abs() - theta).abs() < 1e-3 {
                edge += 1;
                continue;
            }
            if phi.abs() < theta {
                assert_eq!(
                    alpha,
                    0,
                    "pixel ({px}, {py}) at {x}, φ {:.3}°, in the opening shows something",
                    phi.to_degrees()
                );
                empty += 1;
                continue;
            }
            let turn = if phi >= 0.0 { -theta } else { theta };
            let (s, c) = turn.sin_cos();
            let w = x + front * (u * (c - 1.0) - v * s) + normal * (u * s + v * (c - 1.0));
            if w.abs().max_element() > 46.0 {
                continue; // turned out of the ramp's box (±48 mm)
            }
            let expected = ((g.dot(w) + window / 2.0) / window).clamp(0.0, 1.0) * 255.0;
            worst = worst.max((f64::from(image[4 * (py * 64 + px) as usize]) - expected).abs());
            assert_eq!(alpha, 255, "pixel ({px}, {py}) reads the ramp at {w}");
            turned += 1;
        }
    }
    eprintln!(
        "leafer on a ramp: {empty} pixels in the opening, {turned} turned, {edge} on its edges; worst {worst:.2}"
    );
    assert!(empty > 300 && turned > 2000, "{empty} open, {turned} turned");
    assert!(worst <= 1.0, "the leafer's slice is {worst} grey levels off its formula");
}
