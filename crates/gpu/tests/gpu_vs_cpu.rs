//! GPU readback vs the CPU reference on 64³ volumes at 64×64, for every blend mode, with and without a warp.
//!
//! Tolerance: `TOLERANCE` = 4/255 per channel. Both sides use the same texels, uniforms and transfer functions
//! (interpolated by hand on both sides); what remains is the volume and control-texture sampler (lavapipe filters
//! with reduced-precision weights), f32 evaluation order (exp2/log2, matrix products) and rounding to 8 bits,
//! accumulated over ~60 composited samples. Measured on lavapipe (Mesa 22.3.6, llvmpipe LLVM 15): max 3/255 with
//! hardware filtering, 1/255 on the manual-filter fallback.

mod common;

use common::*;
use warpbench_gpu::{
    BlendMode, Classification, FeatureRequest, OrbitCamera, PrefilterPass, PrefilterSettings, PrefilteredTexels,
    Projection, RenderSettings, Shading, ShadingMode,
};

const SIZE: (u32, u32) = (64, 64);
/// Largest per-channel difference allowed.
const TOLERANCE: u8 = 4;
/// Differences above this are counted in the report.
const TYPICAL: u8 = 2;

fn camera() -> OrbitCamera {
    let cam =
        OrbitCamera::fit(v3(-70.0, -70.0, -70.0), v3(70.0, 70.0, 70.0), Projection::Perspective { fov_y_rad: 0.6 });
    OrbitCamera { azimuth_rad: 0.5, elevation_rad: 0.3, ..cam }
}

fn compare(request: FeatureRequest, label: &str, modes: &[BlendMode], classification: Classification) {
    let Some(ctx) = context(request) else { return };
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
            let c = scene.cpu(&u);
            let (max, above) = max_diff(&g, &c, TYPICAL);
            let cov = coverage(&c);
            report.push(format!(
                "{label} warp={warped} {:>12}: max {max}/255, {above} channels > {TYPICAL}, coverage {cov:.2}",
                blend.name()
            ));
            if max > TOLERANCE || cov < 0.2 {
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

/// Pixels whose largest channel difference is above `limit`.
fn pixels_over(a: &[u8], b: &[u8], limit: u8) -> usize {
    a.chunks_exact(4)
        .zip(b.chunks_exact(4))
        .filter(|(p, q)| p.iter().zip(*q).any(|(x, y)| x.abs_diff(*y) > limit))
        .count()
}

/// Shaded DVR and iso-surfaces (gradients through the warp, from the prefiltered copies: the GPU pass's output on
/// the GPU side, [`warpbench_gpu::prefilter::cpu_prefilter`] on the CPU side).
///
/// Tolerance: DVR `SHADED_TOLERANCE` per channel everywhere. Iso: the same on all but `ISO_OUTLIERS` of the pixels.
/// The gradients agree closely because both sides read the same prefiltered texels (GPU pass vs CPU reference within
/// 1e-6) and filter them by hand in f32.
/// An iso hit is a threshold decision on the hardware-filtered volume, so where a ray grazes the surface one side
/// can hit a sample the other misses (a silhouette pixel, or a hit one step later with another normal); those
/// pixels can differ by anything. Measured on lavapipe (Mesa 22.3.6, llvmpipe LLVM 15): DVR max 2/255; iso max 3/255
/// outside ≤ 0.12% outlier pixels with hardware filtering (5 of 4096), none on the manual-filter path; the same on
/// `WGPU_BACKEND=gl` (llvmpipe GL 4.5, no FLOAT32_FILTERABLE).
fn compare_shaded(
    request: FeatureRequest,
    label: &str,
    cases: &[(ShadingMode, BlendMode)],
    classification: Classification,
) {
    const SHADED_TOLERANCE: u8 = 4;
    const ISO_OUTLIERS: f32 = 0.005;
    let Some(ctx) = context(request) else { return };
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
        let c = scene.cpu(&u);
        let (max, _) = max_diff(&g, &c, TYPICAL);
        let over = pixels_over(&g, &c, SHADED_TOLERANCE);
        let frac = over as f32 / (SIZE.0 * SIZE.1) as f32;
        let within = pixels_over(&g, &c, TYPICAL);
        let cov = coverage(&c);
        report.push(format!(
            "{label} {} {:>12}: max {max}/255, {within} px > {TYPICAL}, {over} px ({:.2}%) > \
                 {SHADED_TOLERANCE}, coverage {cov:.2}",
            mode.name(),
            blend.name(),
            100.0 * frac
        ));
        let ok = match mode {
            ShadingMode::Iso => frac <= ISO_OUTLIERS,
            _ => max <= SHADED_TOLERANCE,
        };
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
