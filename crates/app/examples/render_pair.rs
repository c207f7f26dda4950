//! Renders the real MRI (moving, `tests/data/nifti/ch2.nii.gz`) deformed onto the real CT (fixed,
//! `tests/data/nifti/cranium_ct.nii.gz`) in one ray-cast pass, and writes a PNG.
//!
//! ```text
//! cargo run --release -p warpbench-app --example render_pair -- out.png [mix|additive|difference|checkerboard|red-cyan|fixed-only|moving-only] [size] [none|dvr|iso]
//! ```
//!
//! Shading (default `dvr`): both volumes are lit with gradients of their Gaussian-prefiltered copies (σ = 1.5 voxels,
//! GPU prefilter pass), the MR's taken through the warp, with central differences over the coarsest spacing.
//!
//! The landmarks are the window's demo pairs (`project::demo::demo_landmarks`): 10 pairs around each head's centre of
//! mass (a rigid offset between the two heads) plus a few mm of local deformation. A TPS pull-back u = moving_from_fixed is fitted on them
//! (`Tps::<Moving, Fixed>::fit(q, p, 0)`), sampled into a 64³ control texture over the fixed volume's box, and the
//! GPU pulls the MR through it at every ray sample.

use anyhow::{Context, Result, bail};
use warpbench_app::project::demo;
use warpbench_app::scene;
use warpbench_app::settings::Blend;
use warpbench_gpu::{
    GpuContext, GpuControlTexture, GpuFrame, GpuLayer, GpuTransferFunctions, GpuVolume, LayerStyle, OrbitCamera,
    PrefilterPass, PrefilterSettings, PreparedControl, PreparedVolume, Preset, Projection, RaycastDrawData,
    RaycastRenderer, RenderSettings, RenderTarget, Shading, VolumeBudget, Window,
};
use warpbench_io::geometry::Point3;
use warpbench_solver::spaces::{Aabb, Fixed, Moving, as_fixed, as_moving};
use warpbench_solver::tps::Tps;

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let Some(out) = args.first() else { bail!("usage: render_pair OUT.png [blend] [size]") };
    let blend: Blend = args.get(1).map_or("mix", String::as_str).parse()?;
    let blend = blend.mode(0.5, 12.0);
    let size: u32 = args.get(2).map_or(Ok(512), |s| s.parse()).context("size")?;
    let shading_name = args.get(3).map_or("dvr", String::as_str);
    let shading = shading_name.parse::<warpbench_app::settings::Shading>()?.mode();
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let ct = warpbench_io::open(root.join("tests/data/nifti/cranium_ct.nii.gz")).context("reading the CT")?;
    let mr = warpbench_io::open(root.join("tests/data/nifti/ch2.nii.gz")).context("reading the MR")?;
    eprintln!("fixed CT {:?} {} spacing {:?}", ct.dims, ct.sample_type().name(), ct.spacing_mm());
    eprintln!("moving MR {:?} {} spacing {:?}", mr.dims, mr.sample_type().name(), mr.spacing_mm());

    // Landmarks: the window's demo pairs, the same pattern around each head's centre (bone in the CT, tissue in the
    // MR), with local jitter.
    let pairs = demo::demo_landmarks(&ct, &mr);
    let (q, p): (Vec<Point3<Fixed>>, Vec<Point3<Moving>>) =
        pairs.iter().filter_map(|pair| Some((as_fixed(pair.fixed?), as_moving(pair.moving?)))).unzip();
    let moving_from_fixed = Tps::<Moving, Fixed>::fit(&q, &p, 0.0).context("TPS fit")?;

    // A 64³ control texture over the fixed volume's box.
    let ctx = GpuContext::headless().context("GPU device")?;
    eprintln!("GPU: {}", ctx.describe());
    let budget = VolumeBudget::for_device(&ctx.limits);
    let (fixed_desc, moving_desc) = (scene::volume_desc(&ct), scene::volume_desc(&mr));
    let fixed = PreparedVolume::prepare(&fixed_desc, ctx.capabilities, budget)?;
    let moving = PreparedVolume::prepare(&moving_desc, ctx.capabilities, budget)?;
    for w in fixed.warnings.iter().chain(&moving.warnings) {
        eprintln!("warning: {w}");
    }
    let (lo, hi) = (fixed.info.box_min_lps, fixed.info.box_max_lps);
    let domain = Aabb::new(Point3::from_array(lo.to_array()), Point3::from_array(hi.to_array()));
    let (grid, control) = scene::control_texture(&moving_from_fixed, domain, 64)?;
    let control_desc = scene::control_desc(&grid, &control);
    let control = PreparedControl::prepare(&control_desc, ctx.capabilities.float32_filterable)?;

    let renderer = RaycastRenderer::new(&ctx)?;
    let fixed_gpu = GpuVolume::upload(&ctx, &fixed)?;
    let moving_gpu = GpuVolume::upload(&ctx, &moving)?;
    let control_gpu = GpuControlTexture::upload(&ctx, &control);
    let prefilter = PrefilterPass::new(&ctx)?;
    let pf_settings = PrefilterSettings { sigma_vox: 1.5, half_resolution: false };
    let fixed_pf = prefilter.run(&ctx, &fixed_gpu, pf_settings)?;
    let moving_pf = prefilter.run(&ctx, &moving_gpu, pf_settings)?;
    let tfs =
        GpuTransferFunctions::upload(&ctx, &[Preset::CtBone.transfer_function(), Preset::MrT1.transfer_function()]);
    let ct_window = Preset::CtBone.default_window().unwrap_or(Window::from_range(-300.0, 1700.0));
    let (_, mr_window) = scene::auto_style(&mr, Some(Preset::MrT1));
    let fixed_layer = GpuLayer {
        volume: &fixed_gpu,
        control: None,
        prefiltered: Some(&fixed_pf),
        style: LayerStyle { window: ct_window, tf_row: 0, opacity_scale: 0.6, visible: true, iso_value: 300.0 },
        procedural: None,
        view: None,
    };
    let moving_layer = GpuLayer {
        volume: &moving_gpu,
        control: Some(&control_gpu),
        prefiltered: Some(&moving_pf),
        style: LayerStyle {
            window: mr_window,
            tf_row: 1,
            opacity_scale: 1.0,
            visible: true,
            iso_value: mr_window.low() + 0.3 * mr_window.width,
        },
        procedural: None,
        view: None,
    };
    let cam = OrbitCamera::fit(lo.as_vec3(), hi.as_vec3(), Projection::Perspective { fov_y_rad: 0.6 });
    // Aimed at the fixed landmarks' centre.
    let centre: [f64; 3] = std::array::from_fn(|a| q.iter().map(|x| x.coords()[a]).sum::<f64>() / q.len() as f64);
    let target_ref = warpbench_gpu::glam::Vec3::from_array(centre.map(|v| v as f32));
    let cam = OrbitCamera { azimuth_rad: 0.6, elevation_rad: 0.25, zoom: 1.3, target_ref, ..cam };
    let coarsest_mm = fixed.info.spacing_mm.iter().chain(&moving.info.spacing_mm).fold(0.0f64, |a, &b| a.max(b)) as f32;
    let settings = RenderSettings {
        blend,
        samples_per_voxel: 1.0,
        jitter_seed: Some(1),
        // Central differences over the CT's coarsest spacing (its 1.5 mm slices), not the finest: smoother normals.
        shading: Shading { gradient_step_mm: Some(coarsest_mm), ..Shading::with_mode(shading) },
        ..Default::default()
    };
    let frame = GpuFrame { fixed: fixed_layer, moving: moving_layer, tfs: &tfs };
    let data = RaycastDrawData::new(&ctx, &renderer, &frame, &cam, &settings, (size, size));
    let target = RenderTarget::new(&ctx, size, size);
    let start = std::time::Instant::now();
    renderer.render(&ctx, &data, &target)?;
    let mut rgba = target.read_back(&ctx)?;
    eprintln!(
        "rendered {size}×{size} ({}, shading {}) in {:.2} s",
        blend.name(),
        shading.name(),
        start.elapsed().as_secs_f64()
    );
    // Premultiplied over black: the colour channels are the picture; make it opaque.
    for px in rgba.chunks_exact_mut(4) {
        px[3] = 255;
    }
    image::save_buffer(out, &rgba, size, size, image::ExtendedColorType::Rgba8)
        .with_context(|| format!("writing {out}"))?;
    eprintln!("wrote {out}");
    Ok(())
}
