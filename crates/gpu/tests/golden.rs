//! Golden images of the presets' look: four 128×128 renders of the phantoms (no jitter), compared with PNGs in
//! `tests/golden/`. Create or refresh them with `UPDATE_GOLDENS=1 cargo test -p warpbench-gpu --test golden`, look at
//! them, and commit them. The PNGs hold the renderer's premultiplied RGBA as it is.
//!
//! The fourth is a lit iso-surface render (shading mode iso, default lighting).
//!
//! Tolerance: 3/255 per channel, for lavapipe (Mesa 22.3.6, llvmpipe LLVM 15) where they were made. Other drivers
//! filter with other weight precision (the GPU-vs-CPU test measured 3/255 on lavapipe alone); on a real GPU expect
//! to need `UPDATE_GOLDENS=1` or a looser tolerance, which is why the numeric GPU-vs-CPU test is the main oracle.

mod common;

use std::path::PathBuf;

use common::*;
use warpbench_gpu::{
    BlendMode, FeatureRequest, OrbitCamera, PrefilterSettings, Projection, RenderSettings, Shading, ShadingMode,
};

const SIZE: u32 = 128;
const TOLERANCE: u8 = 3;

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
    let mut failures = Vec::new();
    for (name, blend, mode) in cases {
        let shading = Shading::with_mode(mode);
        let settings = RenderSettings { blend, samples_per_voxel: 2.0, shading, ..Default::default() };
        let img = gpu.render(&ctx, &scene, &scene.uniforms(&cam, &settings, (SIZE, SIZE)));
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
        let (max, above) = max_diff(&img, golden.as_raw(), TOLERANCE);
        eprintln!("{name}: max {max}/255 ({above} channels over {TOLERANCE})");
        if max > TOLERANCE {
            let new = path.with_extension("new.png");
            let _ = image::save_buffer(&new, &img, SIZE, SIZE, image::ExtendedColorType::Rgba8);
            failures.push(format!("{name}: max {max}/255 > {TOLERANCE}; this run's image is {}", new.display()));
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}
