//! GPU readback vs the CPU reference on 64³ volumes at 64×64, for every blend mode, with and without a warp.
//!
//! Tolerances are derived per image from the device's filter ([`DeviceFilter`], measured by the probe), never tuned
//! to a driver. Both sides use the same texels, uniforms and transfer functions (interpolated by hand on both sides);
//! what remains is the hardware filter of the volume and control-texture lookups, whose weights a conformant device
//! may round to 2⁻ᵇ (b = 8 on NVIDIA, at least 4), f32 evaluation order and the rounding of the result to 8 bits. So
//! the CPU reference is computed exactly and with the weights rounded down, up and either way at the device's b
//! ([`Allowance`]): an unlit or DVR image may differ from the exact one by [`BASE_TOLERANCE`] plus the largest
//! difference between the exact and a rounded reference, in every channel.

mod common;

use common::*;
use warpbench_gpu::{
    BlendMode, Classification, FeatureRequest, FilterProbe, OrbitCamera, PrefilterPass, PrefilterSettings,
    PrefilteredTexels, Projection, RenderSettings, Shading, ShadingMode,
};

const SIZE: (u32, u32) = (64, 64);

fn camera() -> OrbitCamera {
    let cam =
        OrbitCamera::fit(v3(-70.0, -70.0, -70.0), v3(70.0, 70.0, 70.0), Projection::Perspective { fov_y_rad: 0.6 });
    OrbitCamera { azimuth_rad: 0.5, elevation_rad: 0.3, ..cam }
}

fn compare(request: FeatureRequest, label: &str, modes: &[BlendMode], classification: Classification) {
    let Some(ctx) = context(request) else { return };
    let filter = DeviceFilter::measure(&ctx);
    let phantoms = Phantoms::new();
    let warp = sample_control(16, CTRL_MIN, CTRL_MAX, smooth_displacement);
    let mut report = Vec::new();
    let mut failures = Vec::new();
    for warped in [false, true] {
        let scene = Scene::new(&ctx, &phantoms, warped.then_some(&warp[..]), 16);
        let gpu = GpuScene::new(&ctx, &scene);
        for &blend in modes {
            let settings = RenderSettings { blend, classification, ..Default::default() };
            let u = scene.uniforms(&camera(), &settings, SIZE);
            let g = gpu.render(&ctx, &scene, &u);
            let allowance = scene.allowance(&u, filter);
            let (ok, verdict) = allowance.judge(&g, Look::Smooth);
            let cov = coverage(&allowance.exact);
            report.push(format!("{label} warp={warped} {:>12}: {verdict}, coverage {cov:.2}", blend.name()));
            if !ok || cov < 0.2 {
                failures.push(report.last().cloned().unwrap_or_default());
            }
        }
    }
    eprintln!("{}", report.join("\n"));
    assert!(failures.is_empty(), "GPU and CPU differ:\n{}", failures.join("\n"));
}

#[test]
fn gpu_matches_cpu_reference_for_every_blend_mode() {
    compare(FeatureRequest::default(), "all features", &BlendMode::ALL, Classification::PerSample);
}

/// Pre-integrated classification ([`Classification::PreIntegrated`]): the same tables on both sides
/// ([`warpbench_gpu::transfer::PreIntegrationTable`], looked up by hand in f32), so the same tolerance.
#[test]
fn gpu_matches_cpu_reference_when_preintegrated() {
    let modes = [BlendMode::Mix { moving_weight: 0.5 }, BlendMode::FixedOnly, BlendMode::MovingOnly];
    compare(FeatureRequest::default(), "pre-integrated", &modes, Classification::PreIntegrated);
    let cases = [(ShadingMode::Dvr, MIX), (ShadingMode::Dvr, BlendMode::MovingOnly)];
    compare_shaded(FeatureRequest::default(), "pre-integrated", &cases, Classification::PreIntegrated);
}

/// Without TEXTURE_FORMAT_16BIT_NORM and FLOAT32_FILTERABLE: volumes are R32Float filtered by hand in the shader,
/// control textures Rgba16Float (the CPU side uses the same f16-rounded displacements). Only sampling changes, so
/// two blend modes suffice.
#[test]
fn gpu_matches_cpu_reference_without_optional_features() {
    let request = FeatureRequest { allow_norm16: false, allow_float32_filterable: false };
    compare(
        request,
        "no features",
        &[BlendMode::Mix { moving_weight: 0.5 }, BlendMode::Checkerboard { cell_mm: 12.0 }],
        Classification::PerSample,
    );
}

/// Shaded DVR and iso-surfaces (gradients through the warp, from the prefiltered copies: the GPU pass's output on
/// the GPU side, [`warpbench_gpu::prefilter::cpu_prefilter`] on the CPU side).
///
/// Tolerance: DVR as the unlit images, [`Allowance::tolerance`] per channel everywhere. The gradients agree closely
/// because both sides read the same prefiltered texels (GPU pass vs CPU reference within 1e-6) and filter them by
/// hand in f32.
/// Iso: an iso hit is a threshold decision on the hardware-filtered volume, so where a ray grazes the surface one
/// side can hit a sample the other misses (a silhouette pixel, or a hit one step later with another normal); those
/// pixels can differ by anything. So the image is compared by the fraction of its pixels past a bound
/// ([`Allowance::iso_bound`], the tolerance over the pixels where no rounded reference flips): at most the largest
/// fraction of pixels a rounded reference moves past that bound from the exact one ([`Allowance::fraction_over`]),
/// plus [`GRAZING_F32`] for the f32 order of the ray's setup, which can flip a grazing pixel on its own
/// ([`Allowance::judge`]).
fn compare_shaded(
    request: FeatureRequest,
    label: &str,
    cases: &[(ShadingMode, BlendMode)],
    classification: Classification,
) {
    let Some(ctx) = context(request) else { return };
    let filter = DeviceFilter::measure(&ctx);
    let phantoms = Phantoms::new();
    let warp = sample_control(16, CTRL_MIN, CTRL_MAX, smooth_displacement);
    let mut report = Vec::new();
    let mut failures = Vec::new();
    // The fixed layer is not warped, the moving one is: both gradient paths in one scene. The moving layer's copy is
    // at half resolution.
    let mut scene = Scene::new(&ctx, &phantoms, Some(&warp), 16)
        .with_prefilter(PrefilterSettings { sigma_vox: 1.0, half_resolution: false });
    let half = PrefilterSettings { sigma_vox: 1.5, half_resolution: true };
    scene.moving_pf = Some(PrefilteredTexels::from_volume(&scene.moving, half));
    let mut gpu = GpuScene::new(&ctx, &scene);
    let pass = PrefilterPass::new(&ctx).expect("prefilter pass");
    gpu.moving_pf = Some(pass.run(&ctx, &gpu.moving, half).expect("prefilter"));
    for &(mode, blend) in cases {
        let settings =
            RenderSettings { blend, shading: Shading::with_mode(mode), classification, ..Default::default() };
        let u = scene.uniforms(&camera(), &settings, SIZE);
        let g = gpu.render(&ctx, &scene, &u);
        let allowance = scene.allowance(&u, filter);
        let (ok, verdict) = allowance.judge(&g, Look::of(mode));
        let cov = coverage(&allowance.exact);
        report.push(format!("{label} {} {:>12}: {verdict}, coverage {cov:.2}", mode.name(), blend.name()));
        if !ok || cov < 0.2 {
            failures.push(report.last().cloned().unwrap_or_default());
        }
    }
    eprintln!("{}", report.join("\n"));
    assert!(failures.is_empty(), "GPU and CPU differ:\n{}", failures.join("\n"));
}

const MIX: BlendMode = BlendMode::Mix { moving_weight: 0.5 };

#[test]
fn gpu_matches_cpu_reference_when_shaded() {
    let cases = [
        (ShadingMode::Dvr, MIX),
        (ShadingMode::Iso, MIX),
        (ShadingMode::Iso, BlendMode::Checkerboard { cell_mm: 12.0 }),
    ];
    compare_shaded(FeatureRequest::default(), "all features", &cases, Classification::PerSample);
}

#[test]
fn gpu_matches_cpu_reference_when_shaded_without_optional_features() {
    let request = FeatureRequest { allow_norm16: false, allow_float32_filterable: false };
    compare_shaded(
        request,
        "no features",
        &[(ShadingMode::Dvr, MIX), (ShadingMode::Iso, MIX)],
        Classification::PerSample,
    );
}

/// The probe measures the device's filter weights ([`FilterProbe`]): Vulkan requires at least 4 fractional bits, and
/// the model it yields reproduces every sample it took ([`warpbench_gpu::filter_probe::FormatPrecision::predict`]).
#[test]
fn the_filter_probe_measures_a_conformant_precision_that_its_model_reproduces() {
    let Some(ctx) = context(FeatureRequest::default()) else { return };
    let probe = FilterProbe::new(&ctx).expect("probe");
    let measured = probe.measure(&ctx).expect("measure");
    eprintln!("{}", measured.describe());
    assert!(!measured.formats.is_empty());
    for f in &measured.formats {
        assert!(f.bits >= 4, "{:?}: {} bits, below Vulkan's least", f.format, f.bits);
        let values = probe.sample(&ctx, f.format).expect("sample");
        let n = values.len() as f32;
        let worst = values.iter().enumerate().map(|(k, v)| (f.predict(k as f32 / n) - v).abs()).fold(0.0, f32::max);
        // Where the rounding is not resolved (finer than the probe, mixed, or hidden by the 8-bit format's steps),
        // the prediction is within one step of the grid.
        let step = if f.unorm8_results { 1.0 / 255.0 } else { 1.0 / (1u32 << f.bits) as f32 };
        let bound = if f.rounding.is_some() { 1e-4 } else { step + 1e-6 };
        assert!(worst <= bound, "{:?}: the model is {worst} from the device's filtered values", f.format);
    }
}
