//! Golden images of the presets' look: four 128×128 renders of the phantoms (no jitter), compared with PNGs in
//! `tests/golden/`. Create or refresh them with `UPDATE_GOLDENS=1 cargo test -p warpbench-gpu --test golden`, look at
//! them, and commit them. The PNGs hold the renderer's premultiplied RGBA as it is.
//!
//! The fourth is a lit iso-surface render (shading mode iso, default lighting).
//!
//! Tolerance, derived per image and never tuned to the driver the goldens were made on (lavapipe): a golden is
//! itself some device's image, so this device's render may differ from it by as much as each differs from the
//! exact CPU reference. The golden's distance is measured (the largest channel difference between it and the exact
//! reference); this device's is its [`Allowance`] ([`DeviceFilter`]: the references with the weights rounded at the
//! device's bits). An unlit image must lie within the sum in every channel; an iso image within
//! [`Allowance::iso_bound`] plus the golden's distance on its non-flipping pixels, all but the share of pixels the
//! rounding flips ([`Allowance::fraction_over`] + [`GRAZING_F32`]) and those the golden flips itself.

mod common;

use std::path::PathBuf;

use common::*;
use warpbench_gpu::{
    BlendMode, FeatureRequest, OrbitCamera, PrefilterSettings, Projection, RenderSettings, Shading, ShadingMode,
};

const SIZE: u32 = 128;

fn golden_path(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/golden").join(format!("{name}.png"))
}

#[test]
fn preset_goldens() {
    let Some(ctx) = context(FeatureRequest::default()) else { return };
    let update = std::env::var("UPDATE_GOLDENS").is_ok_and(|v| v == "1");
    let p = Phantoms::new();
    let warp = sample_control(16, CTRL_MIN, CTRL_MAX, smooth_displacement);
    // Prefiltered copies (σ = 1 voxel) for the shaded case; the unlit ones do not read them.
    let scene = Scene::new(&ctx, &p, Some(&warp), 16).with_prefilter(PrefilterSettings::default());
    let gpu = GpuScene::new(&ctx, &scene);
    let cam =
        OrbitCamera::fit(v3(-75.0, -75.0, -75.0), v3(75.0, 75.0, 75.0), Projection::Perspective { fov_y_rad: 0.6 });
    let cam = OrbitCamera { azimuth_rad: 0.6, elevation_rad: 0.35, ..cam };
    let mix = BlendMode::Mix { moving_weight: 0.5 };
    let cases = [
        ("ct_bone_fixed_only", BlendMode::FixedOnly, ShadingMode::None),
        ("mr_t1_moving_warped", BlendMode::MovingOnly, ShadingMode::None),
        ("mix_warped", mix, ShadingMode::None),
        // Lit iso-surfaces of both volumes (CT 300 HU, MR 110), the MR's through the warp, mixed.
        ("iso_shaded_mix_warped", mix, ShadingMode::Iso),
    ];
    let filter = DeviceFilter::measure(&ctx);
    let mut failures = Vec::new();
    for (name, blend, mode) in cases {
        let shading = Shading::with_mode(mode);
        let settings = RenderSettings { blend, samples_per_voxel: 2.0, shading, ..Default::default() };
        let u = scene.uniforms(&cam, &settings, (SIZE, SIZE));
        let img = gpu.render(&ctx, &scene, &u);
        let path = golden_path(name);
        if update {
            image::save_buffer(&path, &img, SIZE, SIZE, image::ExtendedColorType::Rgba8).expect("write golden");
            eprintln!("wrote {}", path.display());
            continue;
        }
        let Ok(golden) = image::open(&path) else {
            failures.push(format!("{name}: missing {} (run with UPDATE_GOLDENS=1)", path.display()));
            continue;
        };
        let golden = golden.to_rgba8();
        let golden = golden.as_raw();
        let allowance = scene.allowance(&u, filter);
        let pixels = (SIZE * SIZE) as f32;
        let (ok, verdict) = if mode == ShadingMode::Iso {
            // The golden's own distance over the pixels where it flips no hit, and the share it flips.
            let golden_shade = max_diff_below(&allowance.exact, golden, 16);
            let bound = allowance.iso_bound().saturating_add(golden_shade);
            let golden_flips = pixels_over(&allowance.exact, golden, bound) as f32 / pixels;
            let allowed = allowance.fraction_over(bound) + golden_flips + GRAZING_F32;
            let over = pixels_over(&img, golden, bound) as f32 / pixels;
            let verdict = format!("{:.2}% of the pixels > {bound}/255 (allowed {:.2}%)", 100.0 * over, 100.0 * allowed);
            (over <= allowed, verdict)
        } else {
            let golden_distance = max_diff(&allowance.exact, golden, 0).0;
            let tolerance = allowance.tolerance().saturating_add(golden_distance);
            let (max, above) = max_diff(&img, golden, tolerance);
            (max <= tolerance, format!("max {max}/255 ({above} channels over {tolerance}/255)"))
        };
        eprintln!("{name}: {verdict}; {}", allowance.describe());
        if !ok {
            let new = path.with_extension("new.png");
            let _ = image::save_buffer(&new, &img, SIZE, SIZE, image::ExtendedColorType::Rgba8);
            failures.push(format!("{name}: {verdict}; this run's image is {}", new.display()));
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// The largest channel difference between `a` and `b` over the pixels where it is below `flip`.
fn max_diff_below(a: &[u8], b: &[u8], flip: u8) -> u8 {
    a.chunks_exact(4)
        .zip(b.chunks_exact(4))
        .map(|(p, q)| p.iter().zip(q).map(|(x, y)| x.abs_diff(*y)).max().unwrap_or(0))
        .filter(|&d| d < flip)
        .max()
        .unwrap_or(0)
}
