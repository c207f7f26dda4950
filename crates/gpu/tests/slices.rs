//! Slicing planes ([`warpbench_gpu::slice`]): the GPU slice (`cs_slice`) against the CPU reference, an axial slice
//! through voxel centres against the volume itself, and a translation warp against a pixel shift. 64³ volumes,
//! images ≤ 96².
//!
//! Tolerance of the GPU-vs-CPU comparison, derived per slice from the device's filter ([`Allowance`]): a slice is one
//! sample per pixel, so what differs is only the volume and control-texture lookups' hardware filter (weights a
//! conformant device may round to 2⁻ᵇ) and f32 evaluation order, then rounding to 8 bits; steep windows (the CT bone
//! preset) amplify a filter error. The slice may differ from the exact CPU slice by [`BASE_TOLERANCE`] plus the
//! largest difference between the exact slice and the slices with the weights rounded at the device's bits. The
//! axial and translation tests sample at texel centres, where every weight is 0 and rounding moves nothing; they
//! allow 1/255 (unorm8 rounding).

mod common;

use common::*;
use warpbench_gpu::{
    BlendMode, FeatureRequest, GpuFrame, GpuLayer, RaycastDrawData, RenderSettings, SlicePlane, TransferFunction,
    Window,
};

fn grey_ramp() -> TransferFunction {
    TransferFunction::from_points("grey", &[(0.0, [0.0, 0.0, 0.0, 1.0]), (1.0, [1.0, 1.0, 1.0, 1.0])])
}

fn planes(p: &Phantoms) -> Vec<(&'static str, SlicePlane)> {
    vec![
        ("axial", SlicePlane::axial(&p.ct_lps_from_index, [N; 3], 10.0)),
        ("coronal", SlicePlane::coronal(&p.ct_lps_from_index, [N; 3], -5.0)),
        (
            "oblique",
            SlicePlane::oblique([5.0, -3.0, 8.0], [1.0, 2.0, 3.0], [0.0, 0.0, 1.0], 2.2, (96, 80)).expect("plane"),
        ),
    ]
}

fn compare(request: FeatureRequest, label: &str, modes: &[BlendMode]) {
    let Some(ctx) = context(request) else { return };
    let filter = DeviceFilter::measure(&ctx);
    let phantoms = Phantoms::new();
    let warp = sample_control(16, CTRL_MIN, CTRL_MAX, smooth_displacement);
    let mut report = Vec::new();
    let mut failures = Vec::new();
    let mut renderer = None;
    for warped in [false, true] {
        let scene = Scene::new(&ctx, &phantoms, warped.then_some(&warp[..]), 16);
        let gpu = GpuScene::new(&ctx, &scene);
        let renderer = renderer.get_or_insert_with(|| warpbench_gpu::RaycastRenderer::new(&ctx).expect("renderer"));
        for (name, plane) in planes(&phantoms) {
            for &blend in modes {
                let u = scene.slice_uniforms(&plane, &RenderSettings { blend, ..Default::default() });
                let g = gpu.render_slice(&ctx, renderer, &scene, &u);
                let allowance = scene.slice_allowance(&u, filter);
                let (ok, verdict) = allowance.judge(&g, Look::Smooth);
                let cov = coverage(&allowance.exact);
                report.push(format!(
                    "{label} warp={warped} {name:>8} {:>12}: {verdict}, coverage {cov:.2}",
                    blend.name()
                ));
                if !ok || cov < 0.3 {
                    failures.push(report.last().cloned().unwrap_or_default());
                }
            }
        }
    }
    eprintln!("{}", report.join("\n"));
    assert!(failures.is_empty(), "GPU and CPU slices differ:\n{}", failures.join("\n"));
}

#[test]
fn gpu_slice_matches_cpu_reference() {
    let modes = [
        BlendMode::Mix { moving_weight: 0.5 },
        BlendMode::Difference,
        BlendMode::Checkerboard { cell_mm: 12.0 },
        BlendMode::RedCyan,
    ];
    compare(FeatureRequest::default(), "all features", &modes);
}

/// The manual-filter path (R32Float volumes, Rgba16Float control textures).
#[test]
fn gpu_slice_matches_cpu_reference_without_optional_features() {
    let request = FeatureRequest { allow_norm16: false, allow_float32_filterable: false };
    compare(request, "no features", &[BlendMode::Mix { moving_weight: 0.5 }]);
}

/// An axial slice through voxel centres of the unwarped fixed volume, with a grey ramp over the window [lo, hi], is
/// round(255·clamp((v − lo)/(hi − lo))) of the voxel values v of that slice, within unorm8 rounding (1/255).
#[test]
fn axial_slice_through_voxel_centres_reproduces_the_volume() {
    let Some(ctx) = context(FeatureRequest::default()) else { return };
    let phantoms = Phantoms::new();
    let mut scene = Scene::new(&ctx, &phantoms, None, 16);
    scene.tfs[0] = grey_ramp();
    let (lo, hi) = (-1000.0f64, 2000.0f64);
    scene.fixed_style.window = Window::from_range(lo as f32, hi as f32);
    let gpu = GpuScene::new(&ctx, &scene);
    let settings = RenderSettings { blend: BlendMode::FixedOnly, ..Default::default() };
    let mut worst = 0u8;
    // The grid is 3 mm, centred on 0: voxel k is at S = 3k − 94.5.
    for (position_mm, k) in [(-30.2, 21usize), (0.1, 32), (40.0, 45)] {
        let plane = SlicePlane::axial(&phantoms.ct_lps_from_index, [N; 3], position_mm);
        assert!((plane.ref_from_pixel(0.0, 0.0)[2] - (3.0 * k as f64 - 94.5)).abs() < 1e-9);
        let u = scene.slice_uniforms(&plane, &settings);
        let layer =
            |volume, style| GpuLayer { volume, control: None, prefiltered: None, style, procedural: None, view: None };
        let frame = GpuFrame {
            fixed: layer(&gpu.fixed, scene.fixed_style),
            moving: layer(&gpu.moving, scene.moving_style),
            tfs: &gpu.tfs,
        };
        let data = RaycastDrawData::for_slice(&ctx, &gpu.renderer, &frame, &plane, &settings);
        assert_eq!(data.uniforms, u, "RaycastDrawData::for_slice builds the same uniforms");
        let g = gpu.render_slice(&ctx, &gpu.renderer, &scene, &u);
        let expected: Vec<u8> = (0..N * N)
            .flat_map(|ij| {
                let v = f64::from(phantoms.ct[ij + N * N * k]);
                let grey = (((v - lo) / (hi - lo)).clamp(0.0, 1.0) * 255.0).round() as u8;
                [grey, grey, grey, 255]
            })
            .collect();
        let (max, _) = max_diff(&g, &expected, 0);
        let (cpu_max, _) = max_diff(&scene.cpu_slice(&u), &expected, 0);
        eprintln!("k = {k}: GPU max {max}/255, CPU max {cpu_max}/255 from the voxel values");
        worst = worst.max(max).max(cpu_max);
    }
    assert!(worst <= 1, "an axial slice through voxel centres differs from the volume by {worst}/255");
}

/// A constant displacement d = (6, −9, 0) mm pulls the moving volume back by d: on an axial plane of 3 mm pixels
/// (u = +L, v = +P) the warped slice at pixel (x, y) is the unwarped slice at (x + 2, y − 3).
#[test]
fn translation_warp_shifts_the_slice() {
    let Some(ctx) = context(FeatureRequest::default()) else { return };
    let phantoms = Phantoms::new();
    let d = glam::DVec3::new(6.0, -9.0, 0.0);
    let warp = sample_control(2, CTRL_MIN, CTRL_MAX, |_| d);
    let plain = Scene::new(&ctx, &phantoms, None, 2);
    let warped = Scene::new(&ctx, &phantoms, Some(&warp), 2);
    let (gpu_plain, gpu_warped) = (GpuScene::new(&ctx, &plain), GpuScene::new(&ctx, &warped));
    let plane = SlicePlane::axial(&phantoms.ct_lps_from_index, [N; 3], 6.0);
    let settings = RenderSettings { blend: BlendMode::MovingOnly, ..Default::default() };
    let a = gpu_plain.render_slice(&ctx, &gpu_plain.renderer, &plain, &plain.slice_uniforms(&plane, &settings));
    let b = gpu_warped.render_slice(&ctx, &gpu_plain.renderer, &warped, &warped.slice_uniforms(&plane, &settings));
    let (dx, dy) = (2usize, 3usize);
    let px = |img: &[u8], x: usize, y: usize| -> [u8; 4] {
        let i = 4 * (y * N + x);
        [img[i], img[i + 1], img[i + 2], img[i + 3]]
    };
    let (mut max, mut moved) = (0u8, 0usize);
    for y in dy..N {
        for x in 0..N - dx {
            let (p, q) = (px(&b, x, y), px(&a, x + dx, y - dy));
            max = max.max(p.iter().zip(q).map(|(s, t)| s.abs_diff(t)).max().unwrap_or(0));
            moved += usize::from(p != px(&a, x, y));
        }
    }
    eprintln!("shifted slice: max {max}/255; {moved} pixels changed by the warp; coverage {:.2}", coverage(&a));
    assert!(coverage(&a) > 0.3 && moved > 500, "the warp should visibly move the slice");
    assert!(max <= 1, "the warped slice is not the shifted unwarped one: max {max}/255");
}
