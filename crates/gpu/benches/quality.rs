//! Image-quality benchmark of the ray caster's sample rate (issue 15, target 6): each demo volume rendered alone at
//! 320², front view, at one sample per voxel by each method, against the plain classification at 8 samples per voxel
//! as the reference.
//!
//! Cases: the head CT (`tests/data/nifti/cranium_ct.nii.gz`, fixed, CT bone with its HU window) and the head MRI
//! (`ch2.nii.gz`, moving, MR T1 with the app's automatic window), with the look the window and `warpbench render`
//! give them (opacity scale 1, orthographic, the camera fitted to the volume's box, looking from the front: this is
//! the setting of the issue's figures, which `warpbench render --size 320x320` reproduces); each unlit (shading none)
//! and lit (shading DVR, gradients from prefiltered copies, σ = 1 voxel), each without and with a warp (a 64³
//! control texture: a smooth displacement of a few mm, and for the MRI also the shift of its centre of mass onto the
//! CT's, as the frame bench's `--demo`). Each is rendered alone (blend fixed-only or moving-only, the other layer
//! hidden).
//!
//! Figures per case and method: **mean |diff|**, the mean absolute difference of the 8-bit premultiplied RGB
//! channels against the reference over the head (the pixels where either image has alpha > 0), in grey levels
//! (0–255); **PSNR** over the whole image's RGB (peak 255); and the time of the one frame (submit, wait, read back; a
//! rough figure: the frame bench times frames properly).
//!
//! ```sh
//! cargo bench -p warpbench-gpu --bench quality
//! cargo bench -p warpbench-gpu --bench quality -- --size 320 --reference-spv 8 --save /tmp/quality
//! ```
//!
//! Options: `--size N` (image edge, default 320), `--reference-spv S` (default 8), `--save DIR` (write each image as
//! PNG: premultiplied RGBA, as rendered), `--only NAME` (cases whose name contains NAME). It only runs when `--bench`
//! is among the arguments (as `cargo bench` passes), so `cargo test --benches` does not run it.

use std::time::{Duration, Instant};

use glam::DVec3;
use warpbench_gpu::transfer::PreIntegrationTable;
use warpbench_gpu::{
    BlendMode, Classification, ControlDesc, GpuContext, GpuControlTexture, GpuFrame, GpuLayer, GpuTransferFunctions,
    GpuVolume, LayerStyle, OrbitCamera, PrefilterPass, PrefilterSettings, PreparedControl, PreparedVolume, Preset,
    Projection, RaycastDrawData, RaycastRenderer, RenderSettings, RenderTarget, Shading, ShadingMode, VolumeBudget,
    VolumeDesc, VolumeSamples, Window,
};

struct Options {
    size: u32,
    reference_spv: f32,
    save: Option<std::path::PathBuf>,
    only: Option<String>,
}

fn options() -> Result<Options, String> {
    let mut o = Options { size: 320, reference_spv: 8.0, save: None, only: None };
    let args: Vec<String> = std::env::args().skip(1).collect();
    let mut it = args.iter();
    while let Some(a) = it.next() {
        let mut value = || it.next().ok_or_else(|| format!("{a} needs a value"));
        match a.as_str() {
            "--size" => o.size = value()?.parse().map_err(|e| format!("--size: {e}"))?,
            "--reference-spv" => o.reference_spv = value()?.parse().map_err(|e| format!("--reference-spv: {e}"))?,
            "--save" => o.save = Some(value()?.into()),
            "--only" => o.only = Some(value()?.clone()),
            _ => {} // --bench and whatever else cargo passes
        }
    }
    o.size = o.size.max(8);
    Ok(o)
}

/// The demo pair's file (`tests/data/nifti/<name>`), read by `warpbench_io`.
fn demo_volume(name: &str) -> warpbench_io::Volume {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/nifti").join(name);
    warpbench_io::open(&path).unwrap_or_else(|e| panic!("demo volume {}: {e}", path.display()))
}

fn demo_desc(v: &warpbench_io::Volume) -> VolumeDesc<'_> {
    use warpbench_io::VoxelData;
    let samples = match &v.data {
        VoxelData::U8(d) => VolumeSamples::U8(d),
        VoxelData::I16(d) => VolumeSamples::I16(d),
        VoxelData::U16(d) => VolumeSamples::U16(d),
        VoxelData::F32(d) => VolumeSamples::F32(d),
    };
    VolumeDesc { dims: v.dims, samples, lps_from_index: v.lps_from_index.rows() }
}

/// The `q`-quantile of the values above `floor`, from every 7th sample (the app's `scene::quantile_above`).
fn quantile_above(v: &warpbench_io::Volume, floor: f64, q: f64) -> Option<f64> {
    let mut vals: Vec<f64> =
        (0..v.data.len()).step_by(7).map(|i| v.data.get_f64(i)).filter(|x| x.is_finite() && *x > floor).collect();
    if vals.is_empty() {
        return None;
    }
    let k = ((vals.len() - 1) as f64 * q.clamp(0.0, 1.0)).round() as usize;
    let (_, x, _) = vals.select_nth_unstable_by(k, f64::total_cmp);
    Some(*x)
}

/// The app's automatic MR window (`scene::auto_style`, what the window and `warpbench render` show): from the 2nd
/// percentile of the foreground (values above 5 % of the 99th percentile) to the 99th percentile.
fn mr_window(v: &warpbench_io::Volume, lo: f64, hi: f64) -> Window {
    let p99 = quantile_above(v, lo, 0.99).unwrap_or(hi);
    let floor = lo + 0.05 * (p99 - lo);
    let low = quantile_above(v, floor, 0.02).unwrap_or(lo);
    let high = if p99 > low { p99 } else { hi.max(low + 1.0) };
    Window::from_range(low as f32, high as f32)
}

/// The LPS centroid of the voxels of `v` above `threshold` (every 2nd voxel).
fn centroid_above(v: &warpbench_io::Volume, threshold: f64) -> DVec3 {
    let (mut sum, mut n) = (DVec3::ZERO, 0.0);
    let m = glam::DMat4::from_cols_array_2d(&v.lps_from_index.rows()).transpose();
    for k in (0..v.dims[2]).step_by(2) {
        for j in (0..v.dims[1]).step_by(2) {
            for i in (0..v.dims[0]).step_by(2) {
                if v.data.get_f64(i + v.dims[0] * (j + v.dims[1] * k)) > threshold {
                    sum += m.transform_point3(DVec3::new(i as f64, j as f64, k as f64));
                    n += 1.0;
                }
            }
        }
    }
    if n > 0.0 { sum / n } else { DVec3::ZERO }
}

/// `[dx, dy, dz, 0]` of a smooth warp of a few mm (plus `offset`) at the texel centres of an n³ grid over `[lo, hi]`
/// (the frame bench's).
fn control_texels(n: usize, lo: DVec3, hi: DVec3, offset: DVec3) -> Vec<f32> {
    let mut out = Vec::with_capacity(4 * n * n * n);
    for c in 0..n {
        for b in 0..n {
            for a in 0..n {
                let f = DVec3::new(a as f64 + 0.5, b as f64 + 0.5, c as f64 + 0.5) / n as f64;
                let x = lo + f * (hi - lo);
                let s = (x / 40.0).map(f64::sin);
                let d = offset + DVec3::new(4.0 + 3.0 * s.y, -3.0 + 2.5 * s.z, 2.0 + 2.0 * s.x);
                out.extend([d.x as f32, d.y as f32, d.z as f32, 0.0]);
            }
        }
    }
    out
}

/// Mean |diff| of the RGB channels over the pixels where either image has alpha > 0, and PSNR (dB) of the RGB
/// channels over the whole image.
fn compare(image: &[u8], reference: &[u8]) -> (f64, f64) {
    let (mut head_sum, mut head_channels, mut sq_sum, mut channels) = (0u64, 0u64, 0u64, 0u64);
    for (p, q) in image.chunks_exact(4).zip(reference.chunks_exact(4)) {
        let head = p[3] > 0 || q[3] > 0;
        for c in 0..3 {
            let d = u64::from(p[c].abs_diff(q[c]));
            sq_sum += d * d;
            channels += 1;
            if head {
                head_sum += d;
                head_channels += 1;
            }
        }
    }
    let mean = head_sum as f64 / head_channels.max(1) as f64;
    let mse = sq_sum as f64 / channels.max(1) as f64;
    let psnr = if mse > 0.0 { 10.0 * (255.0 * 255.0 / mse).log10() } else { f64::INFINITY };
    (mean, psnr)
}

/// One method at one sample rate.
#[derive(Clone, Copy)]
struct Method {
    name: &'static str,
    samples_per_voxel: f32,
    classification: Classification,
    /// Per-pixel jittered ray starts (the window's fixed hash of pixel and seed; no flicker between frames).
    jitter_seed: Option<u32>,
}

#[allow(clippy::too_many_lines, reason = "one linear benchmark script")]
fn main() {
    if !std::env::args().any(|a| a == "--bench") {
        return;
    }
    let o = match options() {
        Ok(o) => o,
        Err(e) => {
            eprintln!("quality bench: {e}");
            std::process::exit(2);
        }
    };
    let ctx = GpuContext::headless().expect("GPU context");
    println!("adapter: {} {:?}", ctx.describe(), ctx.capabilities);
    let t = Instant::now();
    let (ct, mr) = (demo_volume("cranium_ct.nii.gz"), demo_volume("ch2.nii.gz"));
    println!("demo pair: CT {:?}, MR {:?}", ct.dims, mr.dims);
    let (lo, hi) = mr.data.finite_range().unwrap_or((0.0, 1.0));
    let moving_window = mr_window(&mr, lo, hi);
    let mr_offset = centroid_above(&mr, lo + 0.25 * (hi - lo)) - centroid_above(&ct, 300.0);
    let budget = VolumeBudget::for_device(&ctx.limits);
    let fixed = PreparedVolume::prepare(&demo_desc(&ct), ctx.capabilities, budget).expect("fixed");
    let moving = PreparedVolume::prepare(&demo_desc(&mr), ctx.capabilities, budget).expect("moving");
    let fixed_gpu = GpuVolume::upload(&ctx, &fixed).expect("upload");
    let moving_gpu = GpuVolume::upload(&ctx, &moving).expect("upload");
    // Control textures over the CT's box: the CT's a smooth warp alone, the MRI's that plus its centroid shift.
    let (box_lo, box_hi) = (fixed.info.box_min_lps, fixed.info.box_max_lps);
    let control = |offset| {
        let texels = control_texels(64, box_lo, box_hi, offset);
        let desc = ControlDesc {
            dims: [64; 3],
            texels: &texels,
            box_min_ref: box_lo.to_array(),
            box_max_ref: box_hi.to_array(),
        };
        let prepared = PreparedControl::prepare(&desc, ctx.capabilities.float32_filterable).expect("control");
        GpuControlTexture::upload(&ctx, &prepared)
    };
    let (fixed_ctrl, moving_ctrl) = (control(DVec3::ZERO), control(mr_offset));
    let tfs =
        GpuTransferFunctions::upload(&ctx, &[Preset::CtBone.transfer_function(), Preset::MrT1.transfer_function()]);
    let prefilter = PrefilterPass::new(&ctx).expect("prefilter pass");
    let fixed_pf = prefilter.run(&ctx, &fixed_gpu, PrefilterSettings::default()).expect("prefilter");
    let moving_pf = prefilter.run(&ctx, &moving_gpu, PrefilterSettings::default()).expect("prefilter");
    let renderer = RaycastRenderer::new(&ctx).expect("renderer");
    ctx.wait_idle().expect("wait");
    println!("setup: {:.0} ms", t.elapsed().as_secs_f64() * 1e3);

    let fixed_style = LayerStyle {
        window: Preset::CtBone.default_window().unwrap_or(Window::from_range(-300.0, 1700.0)),
        tf_row: 0,
        opacity_scale: 1.0,
        visible: true,
        iso_value: 300.0,
    };
    let moving_style =
        LayerStyle { window: moving_window, tf_row: 1, opacity_scale: 1.0, visible: true, iso_value: 110.0 };
    let hidden = |s: LayerStyle| LayerStyle { visible: false, ..s };
    let target = RenderTarget::new(&ctx, o.size, o.size);

    let methods = [
        Method {
            name: "plain 1 spv, jitter",
            samples_per_voxel: 1.0,
            classification: Classification::PerSample,
            jitter_seed: Some(1),
        },
        Method {
            name: "plain 1 spv",
            samples_per_voxel: 1.0,
            classification: Classification::PerSample,
            jitter_seed: None,
        },
        Method {
            name: "pre-integrated 1 spv",
            samples_per_voxel: 1.0,
            classification: Classification::PreIntegrated,
            jitter_seed: None,
        },
        Method {
            name: "plain 2 spv",
            samples_per_voxel: 2.0,
            classification: Classification::PerSample,
            jitter_seed: None,
        },
        Method {
            name: "pre-integrated 2 spv",
            samples_per_voxel: 2.0,
            classification: Classification::PreIntegrated,
            jitter_seed: None,
        },
    ];
    let reference = Method {
        name: "reference",
        samples_per_voxel: o.reference_spv,
        classification: Classification::PerSample,
        jitter_seed: None,
    };
    let t = Instant::now();
    let table = PreIntegrationTable::build(&Preset::MrT1.transfer_function(), 1.0, 1.0);
    println!(
        "a pre-integration table ({} entries, MR T1, on the CPU): {:.1} ms",
        table.texels.len(),
        t.elapsed().as_secs_f64() * 1e3
    );
    println!(
        "image {0}×{0}, front view; reference: plain classification at {1} samples/voxel; mean |diff| over the head \
         (grey levels of 8-bit RGB), PSNR over the image",
        o.size, o.reference_spv
    );
    println!("{:<22} {:<22} {:>10} {:>9} {:>10}", "case", "method", "mean|diff|", "PSNR dB", "frame ms");
    let mut worst: Vec<(&str, f64)> = methods.iter().map(|m| (m.name, 0.0f64)).collect();
    for volume in ["CT", "MR"] {
        for mode in [ShadingMode::None, ShadingMode::Dvr] {
            for warped in [false, true] {
                let case = format!("{volume} {} {}", mode.name(), if warped { "warped" } else { "plain" });
                if o.only.as_ref().is_some_and(|s| !case.contains(s.as_str())) {
                    continue;
                }
                let (fixed_layer, moving_layer, blend) = if volume == "CT" {
                    (
                        GpuLayer {
                            volume: &fixed_gpu,
                            control: warped.then_some(&fixed_ctrl),
                            prefiltered: Some(&fixed_pf),
                            style: fixed_style,
                            procedural: None,
                            view: None,
                        },
                        GpuLayer {
                            volume: &moving_gpu,
                            control: None,
                            prefiltered: None,
                            style: hidden(moving_style),
                            procedural: None,
                            view: None,
                        },
                        BlendMode::FixedOnly,
                    )
                } else {
                    (
                        GpuLayer {
                            volume: &fixed_gpu,
                            control: None,
                            prefiltered: None,
                            style: hidden(fixed_style),
                            procedural: None,
                            view: None,
                        },
                        GpuLayer {
                            volume: &moving_gpu,
                            control: warped.then_some(&moving_ctrl),
                            prefiltered: Some(&moving_pf),
                            style: moving_style,
                            procedural: None,
                            view: None,
                        },
                        BlendMode::MovingOnly,
                    )
                };
                let frame = GpuFrame { fixed: fixed_layer, moving: moving_layer, tfs: &tfs };
                let shown = if volume == "CT" { frame.fixed } else { frame.moving };
                let (box_min, box_max) = shown.params().box_ref();
                let cam = OrbitCamera::fit(box_min.as_vec3(), box_max.as_vec3(), Projection::Orthographic);
                // One frame each: the reference first, which also compiles the shading mode's pipeline.
                let render = |m: &Method| -> (Vec<u8>, Duration) {
                    let settings = RenderSettings {
                        blend,
                        samples_per_voxel: m.samples_per_voxel,
                        classification: m.classification,
                        jitter_seed: m.jitter_seed,
                        shading: Shading::with_mode(mode),
                        ..Default::default()
                    };
                    let data = RaycastDrawData::new(&ctx, &renderer, &frame, &cam, &settings, (o.size, o.size));
                    let t = Instant::now();
                    renderer.render(&ctx, &data, &target).expect("render");
                    let image = target.read_back(&ctx).expect("read back");
                    (image, t.elapsed())
                };
                let save = |name: &str, image: &[u8]| {
                    if let Some(dir) = &o.save {
                        let file = format!("{case} {name}.png").replace(' ', "_");
                        std::fs::create_dir_all(dir).expect("create --save directory");
                        image::save_buffer(dir.join(file), image, o.size, o.size, image::ExtendedColorType::Rgba8)
                            .expect("write png");
                    }
                };
                let (ref_image, ref_time) = render(&reference);
                save(reference.name, &ref_image);
                for (i, m) in methods.iter().enumerate() {
                    let (image, time) = render(m);
                    save(m.name, &image);
                    let (mean, psnr) = compare(&image, &ref_image);
                    worst[i].1 = worst[i].1.max(mean);
                    println!("{case:<22} {:<22} {mean:>10.2} {psnr:>9.1} {:>10.0}", m.name, time.as_secs_f64() * 1e3);
                }
                println!(
                    "{case:<22} {:<22} {:>10} {:>9} {:>10.0}",
                    format!("(reference {} spv)", o.reference_spv),
                    "",
                    "",
                    ref_time.as_secs_f64() * 1e3
                );
            }
        }
    }
    for (name, mean) in worst {
        println!("worst mean |diff|, {name}: {mean:.2} grey levels (target ≤ 1.0 at 1 spv)");
    }
    if let Err(e) = ctx.check_errors() {
        println!("wgpu errors: {e}");
    }
}
