//! Frame-time benchmark of the ray caster: two deterministic procedural volumes (a CT-like i16 head and an
//! MR-like u8 head, 256³ by default), 64³ control textures, a 512² image at 1 sample per voxel, and these cases
//! timed in the same run:
//!
//! 1. **undeformed**: both volumes, mix blend, no control texture (the identity fast path);
//! 2. **deformed**: the moving volume pulled back through a 64³ control texture;
//! 3. **deformed + shaded**: as 2, lit DVR with gradients through the warp from prefiltered copies made once;
//! 4. **deformed + shaded + prefilter**: as 3, with both volumes prefiltered again every frame (what a change of
//!    volume costs);
//! 5. **deformed + shaded, interactive**: as 3 at the interaction sample rate ([`warpbench_gpu::Quality`], 0.5
//!    samples per voxel);
//! 6. **pick** (three probes): click to result for one ray through the centre pixel into the deformed moving volume
//!    ([`warpbench_gpu::PickPass`]: upload, dispatch, read back);
//! 7. **empty-space skipping** ([`warpbench_gpu::empty_space`]): cases 1, 2 and 3 again with the frame skipping the
//!    bricks its grid marks empty, the grid's build time (once per change of look), the frame-time ratio
//!    without / with, and a check that both images are the same bytes;
//! 8. **targets**: the issue's targets read off the skipping cases, as the window draws: deformed + shaded DVR
//!    ≥ 60 fps, undeformed ≥ 120 fps, deformed / undeformed ≤ 1.25×, each said met or missed.
//!
//! With `--procedural`, instead, Brunet, Nowak & Gleicher 2006's Table 1: the moving volume alone under the same
//! deformation computed **in the shader** ([`warpbench_gpu::procedural`]: shift, sine, twist, bend, bump) and
//! **through a control texture** (`--ctrl`³, default 64³, sampled from the same deformation over the layer's proxy
//! box), in their two cases: 1, a transfer function alone (unlit); 2, gradients and diffuse shading (lit DVR from
//! prefiltered copies). It prints ms/frame for both paths, the ratio texture / shader (above 1: the shader is
//! faster; frames of the two paths alternate and the medians are compared), and the images' difference (mean and
//! largest per channel, /255).
//!
//! A frame is submit + wait + readback of the RGBA8 image (wall clock; warm-up frames, which also compile the
//! pipelines, are excluded). It prints ms/frame (mean and best) and the deformation overhead deformed/undeformed.
//!
//! ```sh
//! cargo bench -p warpbench-gpu --bench frame
//! cargo bench -p warpbench-gpu --bench frame -- --size 1920x1080 --dims 512x512x300 --frames 20
//! cargo bench -p warpbench-gpu --bench frame -- --demo --size 1024x768
//! cargo bench -p warpbench-gpu --bench frame -- --procedural --dims 256x256x192
//! ```
//!
//! Options: `--size WxH` (image), `--dims N` or `--dims NXxNYxNZ` (both volumes), `--ctrl N` (control texture
//! edge), `--ctrl-f16` (control textures in `Rgba16Float`, as on devices without filterable `Rgba32Float`: half the
//! bytes a texel; does it pay on this GPU?), `--frames N` (timed frames per case), `--spv S` (samples per voxel), `--preintegrated` (pre-integrated
//! classification, [`warpbench_gpu::Classification`], in every case), `--demo` (instead of the procedural
//! volumes, the window's demo pair from `tests/data/nifti`: the head CT as fixed (CT bone, its HU window) and the
//! head MRI as moving (MR T1, windowed from its foreground's 2nd to 99th percentile, as the window's automatic
//! look), the control texture moving the MRI's centre of mass onto the CT's plus the smooth warp). The adapter is wgpu's default, or the
//! one `WGPU_BACKEND` / `WGPU_ADAPTER_NAME` choose. It only runs when `--bench` is among the arguments (as
//! `cargo bench` passes), so `cargo test --benches` does not run it.

use std::time::{Duration, Instant};

use glam::{DVec3, Vec3};
use warpbench_gpu::{
    Axis, BlendMode, Classification, ControlDesc, GpuContext, GpuControlTexture, GpuFrame, GpuLayer, GpuPrefiltered,
    GpuTransferFunctions, GpuVolume, LayerStyle, OrbitCamera, PickPass, PickRay, PickRequest, PickTarget,
    PrefilterPass, PrefilterSettings, PreparedControl, PreparedVolume, Preset, Probe, Procedural, Projection, Quality,
    RaycastDrawData, RaycastRenderer, RenderSettings, RenderTarget, Shading, ShadingMode, VolumeBudget, VolumeDesc,
    VolumeSamples, Window,
};

/// Edge of both volumes' box, mm (whatever the dims).
const BOX_MM: f64 = 240.0;

struct Options {
    size: (u32, u32),
    dims: [usize; 3],
    ctrl: usize,
    frames: usize,
    samples_per_voxel: f32,
    demo: bool,
    classification: Classification,
    procedural: bool,
    /// Control textures in `Rgba16Float` (half the bytes a texel, filtered at a higher rate on many GPUs) even where
    /// `Rgba32Float` is filterable.
    ctrl_f16: bool,
}

fn parse_pair(s: &str) -> Option<Vec<usize>> {
    s.split('x').map(|p| p.parse().ok()).collect()
}

fn options() -> Result<Options, String> {
    let mut o = Options {
        size: (512, 512),
        dims: [256; 3],
        ctrl: 64,
        frames: 5,
        samples_per_voxel: 1.0,
        demo: false,
        classification: Classification::PerSample,
        procedural: false,
        ctrl_f16: false,
    };
    let args: Vec<String> = std::env::args().skip(1).collect();
    let mut it = args.iter();
    while let Some(a) = it.next() {
        let mut value = || it.next().ok_or_else(|| format!("{a} needs a value"));
        match a.as_str() {
            "--size" => match parse_pair(value()?).as_deref() {
                Some(&[w, h]) if w > 0 && h > 0 => o.size = (w as u32, h as u32),
                _ => return Err("--size WxH".into()),
            },
            "--dims" => match parse_pair(value()?).as_deref() {
                Some(&[n]) if n > 1 => o.dims = [n; 3],
                Some(&[x, y, z]) if x > 1 && y > 1 && z > 1 => o.dims = [x, y, z],
                _ => return Err("--dims N or NXxNYxNZ".into()),
            },
            "--ctrl" => o.ctrl = value()?.parse().map_err(|e| format!("--ctrl: {e}"))?,
            "--frames" => o.frames = value()?.parse().map_err(|e| format!("--frames: {e}"))?,
            "--spv" => o.samples_per_voxel = value()?.parse().map_err(|e| format!("--spv: {e}"))?,
            "--demo" => o.demo = true,
            "--preintegrated" => o.classification = Classification::PreIntegrated,
            "--procedural" => o.procedural = true,
            "--ctrl-f16" => o.ctrl_f16 = true,
            _ => {} // --bench and whatever else cargo passes
        }
    }
    o.frames = o.frames.max(1);
    o.ctrl = o.ctrl.max(2);
    Ok(o)
}

fn smoothstep(e0: f64, e1: f64, x: f64) -> f64 {
    let t = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// `f(p)` at every voxel of `dims`, p ∈ \[−½, ½\]³ the voxel centre in box units, z slabs on all cores.
fn generate<T: Send + Copy + Default>(dims: [usize; 3], f: impl Fn(DVec3) -> T + Sync) -> Vec<T> {
    let [nx, ny, nz] = dims;
    let mut out = vec![T::default(); nx * ny * nz];
    let threads = std::thread::available_parallelism().map_or(1, std::num::NonZero::get);
    let slab = nz.div_ceil(threads).max(1);
    std::thread::scope(|s| {
        for (c, chunk) in out.chunks_mut(slab * nx * ny).enumerate() {
            let f = &f;
            s.spawn(move || {
                for (n, v) in chunk.iter_mut().enumerate() {
                    let (i, j, k) = (n % nx, (n / nx) % ny, c * slab + n / (nx * ny));
                    let p = DVec3::new(
                        (i as f64 + 0.5) / nx as f64,
                        (j as f64 + 0.5) / ny as f64,
                        (k as f64 + 0.5) / nz as f64,
                    ) - DVec3::splat(0.5);
                    *v = f(p);
                }
            });
        }
    });
    out
}

/// A CT-like head (HU): skin, soft tissue, a bone shell, a dense blob and some high-frequency texture.
fn ct(p: DVec3) -> i16 {
    let w = 0.006;
    let r = (p * DVec3::new(1.0, 1.15, 1.05)).length();
    let head = 1.0 - smoothstep(0.42 - w, 0.42 + w, r);
    let bone = smoothstep(0.36 - w, 0.36 + w, r) * head;
    let blob = 1.0 - smoothstep(0.06, 0.07, (p - DVec3::new(0.12, -0.05, 0.1)).length());
    let texture = 30.0 * (p.x * 90.0).sin() * (p.y * 70.0).sin() * (p.z * 50.0).sin();
    (-1000.0 + (1040.0 + texture) * head + 1160.0 * bone + 600.0 * blob).round() as i16
}

/// An MR-like head (0..255): scalp, brain, two ventricles.
fn mr(p: DVec3) -> u8 {
    let w = 0.006;
    let brain = 1.0 - smoothstep(0.33 - w, 0.33 + w, (p * DVec3::new(1.1, 0.9, 1.2)).length());
    let scalp = 1.0 - smoothstep(0.4 - w, 0.4 + w, p.length());
    let vent = |c: DVec3| 1.0 - smoothstep(0.05, 0.06, (p - c).length());
    let v =
        60.0 * scalp + 150.0 * brain - 120.0 * (vent(DVec3::new(0.08, 0.0, 0.05)) + vent(DVec3::new(-0.08, 0.0, 0.05)));
    v.clamp(0.0, 255.0).round() as u8
}

/// Row-major `lps_from_index` of a `dims` grid filling a `BOX_MM` cube centred at `centre`, rotated by `angle_rad`.
fn grid(dims: [usize; 3], centre: DVec3, angle_rad: f64) -> [[f64; 4]; 4] {
    let (s, c) = angle_rad.sin_cos();
    let sp = dims.map(|d| BOX_MM / d as f64);
    let r = [[c * sp[0], -s * sp[1], 0.0], [s * sp[0], c * sp[1], 0.0], [0.0, 0.0, sp[2]]];
    let h = dims.map(|d| (d as f64 - 1.0) / 2.0);
    let mut m = [[0.0; 4]; 4];
    for row in 0..3 {
        m[row][..3].copy_from_slice(&r[row]);
        m[row][3] = centre[row] - (0..3).map(|a| r[row][a] * h[a]).sum::<f64>();
    }
    m[3][3] = 1.0;
    m
}

/// `[dx, dy, dz, 0]` of a smooth warp of a few mm (plus `offset`) at the texel centres of an n³ grid over `[lo, hi]`.
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

/// The values of `v` (every voxel), sorted.
fn sorted_values(v: &warpbench_io::Volume) -> Vec<f64> {
    let mut values: Vec<f64> = (0..v.data.len()).map(|i| v.data.get_f64(i)).filter(|x| x.is_finite()).collect();
    values.sort_by(f64::total_cmp);
    values
}

/// The window's automatic MR window: the foreground's (values above 5 % of the 99th percentile) 2nd to 99th
/// percentile.
fn mr_window(v: &warpbench_io::Volume) -> Window {
    let values = sorted_values(v);
    let q = |vals: &[f64], p: f64| vals[((vals.len() - 1) as f64 * p) as usize];
    let lo = values[0];
    let p99 = q(&values, 0.99);
    let floor = lo + 0.05 * (p99 - lo);
    let fg: Vec<f64> = values.iter().copied().filter(|&x| x > floor).collect();
    let (low, high) = (q(&fg, 0.02), q(&fg, 0.99));
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

/// Mean and best of `frames` timed calls of `frame` after `warmup` untimed ones.
fn time(frames: usize, warmup: usize, mut frame: impl FnMut()) -> (Duration, Duration) {
    for _ in 0..warmup {
        frame();
    }
    let mut times = Vec::with_capacity(frames);
    for _ in 0..frames {
        let t = Instant::now();
        frame();
        times.push(t.elapsed());
    }
    let mean = times.iter().sum::<Duration>() / frames as u32;
    (mean, times.into_iter().min().unwrap_or_default())
}

fn layer<'a>(
    volume: &'a GpuVolume,
    control: Option<&'a GpuControlTexture>,
    prefiltered: Option<&'a GpuPrefiltered>,
    style: LayerStyle,
) -> GpuLayer<'a> {
    GpuLayer { volume, control, prefiltered, style, procedural: None, view: None }
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

#[allow(clippy::too_many_lines, reason = "one linear benchmark script")]
fn main() {
    if !std::env::args().any(|a| a == "--bench") {
        return;
    }
    let o = match options() {
        Ok(o) => o,
        Err(e) => {
            eprintln!("frame bench: {e}");
            std::process::exit(2);
        }
    };
    let ctx = GpuContext::headless().expect("GPU context");
    let [nx, ny, nz] = o.dims;
    println!("adapter: {} {:?}", ctx.describe(), ctx.capabilities);
    println!(
        "volumes {nx}×{ny}×{nz} (CT i16, MR u8, {BOX_MM} mm boxes), control {c}³ {}, image {}×{}, {} sample(s)/voxel, \
         {} classification, {} timed frames per case",
        if o.ctrl_f16 || !ctx.capabilities.float32_filterable { "Rgba16Float" } else { "Rgba32Float" },
        o.size.0,
        o.size.1,
        o.samples_per_voxel,
        o.classification.name(),
        o.frames,
        c = o.ctrl
    );

    let t = Instant::now();
    let budget = VolumeBudget::for_device(&ctx.limits);
    let demo = o.demo.then(|| (demo_volume("cranium_ct.nii.gz"), demo_volume("ch2.nii.gz")));
    let (ct_samples, mr_samples) =
        if demo.is_some() { (Vec::new(), Vec::new()) } else { (generate(o.dims, ct), generate(o.dims, mr)) };
    let (fixed_desc, moving_desc) = match &demo {
        Some((f, m)) => {
            println!("demo pair: CT {:?}, MR {:?}", f.dims, m.dims);
            (demo_desc(f), demo_desc(m))
        }
        None => (
            VolumeDesc {
                dims: o.dims,
                samples: VolumeSamples::I16(&ct_samples),
                lps_from_index: grid(o.dims, DVec3::ZERO, 0.0),
            },
            VolumeDesc {
                dims: o.dims,
                samples: VolumeSamples::U8(&mr_samples),
                lps_from_index: grid(o.dims, DVec3::new(4.0, -3.0, 2.0), 10f64.to_radians()),
            },
        ),
    };
    let moving_window = demo.as_ref().map_or(Window::from_range(0.0, 220.0), |(_, m)| mr_window(m));
    // The demo's MRI is not in the CT's place: the warp moves it there (centres of mass, as its landmarks do).
    let offset = demo.as_ref().map_or(DVec3::ZERO, |(f, m)| {
        let (lo, hi) = sorted_values(m).first().zip(sorted_values(m).last()).map_or((0.0, 1.0), |(a, b)| (*a, *b));
        centroid_above(m, lo + 0.25 * (hi - lo)) - centroid_above(f, 300.0)
    });
    let fixed = PreparedVolume::prepare(&fixed_desc, ctx.capabilities, budget).expect("fixed");
    let moving = PreparedVolume::prepare(&moving_desc, ctx.capabilities, budget).expect("moving");
    for w in fixed.warnings.iter().chain(&moving.warnings) {
        println!("warning: {w}");
    }
    let (lo, hi) = (fixed.info.box_min_lps, fixed.info.box_max_lps);
    let texels = control_texels(o.ctrl, lo, hi, offset);
    let cdesc =
        ControlDesc { dims: [o.ctrl; 3], texels: &texels, box_min_ref: lo.to_array(), box_max_ref: hi.to_array() };
    let control =
        PreparedControl::prepare(&cdesc, ctx.capabilities.float32_filterable && !o.ctrl_f16).expect("control");
    let renderer = RaycastRenderer::new(&ctx).expect("renderer");
    let fixed_gpu = GpuVolume::upload(&ctx, &fixed).expect("upload");
    let moving_gpu = GpuVolume::upload(&ctx, &moving).expect("upload");
    let control_gpu = GpuControlTexture::upload(&ctx, &control);
    let tfs =
        GpuTransferFunctions::upload(&ctx, &[Preset::CtBone.transfer_function(), Preset::MrT1.transfer_function()]);
    let prefilter = PrefilterPass::new(&ctx).expect("prefilter pass");
    let pf_settings = PrefilterSettings::default();
    let fixed_pf = prefilter.run(&ctx, &fixed_gpu, pf_settings).expect("prefilter");
    let moving_pf = prefilter.run(&ctx, &moving_gpu, pf_settings).expect("prefilter");
    ctx.wait_idle().expect("wait");
    println!("setup (generate, prepare, upload, prefilter once): {:.0} ms", ms(t.elapsed()));

    let fixed_style = LayerStyle {
        window: Preset::CtBone.default_window().unwrap_or(Window::from_range(-300.0, 1700.0)),
        tf_row: 0,
        opacity_scale: 0.6,
        visible: true,
        iso_value: 300.0,
    };
    let moving_style =
        LayerStyle { window: moving_window, tf_row: 1, opacity_scale: 1.0, visible: true, iso_value: 110.0 };
    let cam = OrbitCamera::fit(lo.as_vec3(), hi.as_vec3(), Projection::Perspective { fov_y_rad: 0.6 });
    let centre = (0.5 * (lo + hi)).as_vec3();
    let cam = OrbitCamera { azimuth_rad: 0.6, elevation_rad: 0.25, target_ref: centre, ..cam };
    let target = RenderTarget::new(&ctx, o.size.0, o.size.1);
    let undeformed = GpuFrame {
        fixed: layer(&fixed_gpu, None, None, fixed_style),
        moving: layer(&moving_gpu, None, None, moving_style),
        tfs: &tfs,
    };
    let deformed = GpuFrame { moving: layer(&moving_gpu, Some(&control_gpu), None, moving_style), ..undeformed };
    let shaded = GpuFrame {
        fixed: layer(&fixed_gpu, None, Some(&fixed_pf), fixed_style),
        moving: layer(&moving_gpu, Some(&control_gpu), Some(&moving_pf), moving_style),
        tfs: &tfs,
    };
    // One proxy box in every case (the union of the undeformed and the deformed layers' boxes), so that the cases
    // differ only in the work per sample.
    let box_ref = [undeformed.fixed, undeformed.moving, shaded.moving]
        .iter()
        .map(|l| l.params().box_ref())
        .fold((DVec3::INFINITY, DVec3::NEG_INFINITY), |(lo, hi), (a, b)| (lo.min(a), hi.max(b)));
    let box_ref = (box_ref.0.as_vec3(), box_ref.1.as_vec3());
    let settings = |mode| RenderSettings {
        blend: BlendMode::Mix { moving_weight: 0.5 },
        box_override_ref: Some(box_ref),
        samples_per_voxel: o.samples_per_voxel,
        shading: Shading::with_mode(mode),
        classification: o.classification,
        ..Default::default()
    };
    let draw_at = |frame: &GpuFrame<'_>, mode, quality| {
        let data = RaycastDrawData::new(&ctx, &renderer, frame, &cam, &settings(mode).at(quality), o.size);
        renderer.render(&ctx, &data, &target).expect("render");
        std::hint::black_box(target.read_back(&ctx).expect("read back"));
    };
    let draw = |frame: &GpuFrame<'_>, mode| draw_at(frame, mode, Quality::Full);

    if o.procedural {
        procedural_table(&ctx, &renderer, &tfs, (&moving, &moving_gpu, &moving_pf, moving_style), &cam, &target, &o);
        return;
    }

    let mut results: Vec<(&str, Duration, Duration)> = Vec::new();
    let (mean, best) = time(o.frames, 1, || draw(&undeformed, ShadingMode::None));
    results.push(("undeformed", mean, best));
    let (mean, best) = time(o.frames, 1, || draw(&deformed, ShadingMode::None));
    results.push(("deformed", mean, best));
    let (mean, best) = time(o.frames, 1, || draw(&shaded, ShadingMode::Dvr));
    results.push(("deformed + shaded", mean, best));
    let (mean, best) = time(o.frames, 1, || draw_at(&shaded, ShadingMode::Dvr, Quality::Interactive));
    results.push(("deformed + shaded, interactive", mean, best));
    let (mean, best) = time(o.frames, 1, || {
        let mut encoder =
            ctx.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("prefilter") });
        let f = prefilter.encode(&ctx, &mut encoder, &fixed_gpu, pf_settings).expect("prefilter");
        let m = prefilter.encode(&ctx, &mut encoder, &moving_gpu, pf_settings).expect("prefilter");
        ctx.queue.submit([encoder.finish()]);
        let frame = GpuFrame {
            fixed: layer(&fixed_gpu, None, Some(&f), fixed_style),
            moving: layer(&moving_gpu, Some(&control_gpu), Some(&m), moving_style),
            tfs: &tfs,
        };
        draw(&frame, ShadingMode::Dvr);
    });
    results.push(("deformed + shaded + prefilter", mean, best));

    // Empty-space skipping: the grid of the frame's look (built once per change of look), then cases 2 and 3 again.
    let t = Instant::now();
    let empty_space = shaded.empty_space(&ctx, box_ref, [None, Some(&control)]);
    ctx.wait_idle().expect("wait");
    let grid_ms = ms(t.elapsed());
    // The undeformed frame's own grid (its moving layer has no warp, so the deformed frame's grid is not its).
    let undeformed_space = undeformed.empty_space(&ctx, box_ref, [None, None]);
    let draw_skipping_in = |frame: &GpuFrame<'_>, mode, grid: &warpbench_gpu::GpuEmptySpace| {
        let data =
            RaycastDrawData::new_with_empty_space(&ctx, &renderer, frame, &cam, &settings(mode), o.size, Some(grid));
        assert_eq!(data.uniforms.empty_space.enabled, 1, "the grid fits the frame");
        renderer.render(&ctx, &data, &target).expect("render");
        target.read_back(&ctx).expect("read back")
    };
    let draw_skipping = |frame: &GpuFrame<'_>, mode| draw_skipping_in(frame, mode, &empty_space);
    let (mean, best) = time(o.frames, 1, || {
        std::hint::black_box(draw_skipping_in(&undeformed, ShadingMode::None, &undeformed_space));
    });
    results.push(("undeformed, skipping", mean, best));
    let (mean, best) = time(o.frames, 1, || {
        std::hint::black_box(draw_skipping(&deformed, ShadingMode::None));
    });
    results.push(("deformed, skipping", mean, best));
    let (mean, best) = time(o.frames, 1, || {
        std::hint::black_box(draw_skipping(&shaded, ShadingMode::Dvr));
    });
    results.push(("deformed + shaded, skipping", mean, best));
    let same = |frame: &GpuFrame<'_>, mode| {
        let with = draw_skipping(frame, mode);
        let data = RaycastDrawData::new(&ctx, &renderer, frame, &cam, &settings(mode), o.size);
        renderer.render(&ctx, &data, &target).expect("render");
        with == target.read_back(&ctx).expect("read back")
    };
    let identical = [same(&deformed, ShadingMode::None), same(&shaded, ShadingMode::Dvr)];

    // Picking: click to result (upload one ray, dispatch, read back) on the deformed frame.
    let pick_pass = PickPass::new(&ctx, &renderer).expect("pick pass");
    let data = RaycastDrawData::new(&ctx, &renderer, &deformed, &cam, &settings(ShadingMode::None), o.size);
    let centre = [o.size.0 as f32 / 2.0, o.size.1 as f32 / 2.0];
    let ray = PickRay::from_pixel(&data.uniforms, centre).expect("ray");
    for (name, probe) in [
        ("pick, opacity 0.5, 1 ray", Probe::Opacity { threshold: 0.5 }),
        ("pick, gradient, 1 ray", Probe::Gradient { threshold: 50.0 }),
        ("pick, accumulated 0.95, 1 ray", Probe::default()),
    ] {
        let request = PickRequest::new(PickTarget::Moving, probe);
        let (mean, best) = time(o.frames.max(20), 2, || {
            std::hint::black_box(pick_pass.pick(&ctx, &data, &request, &[ray]).expect("pick"));
        });
        results.push((name, mean, best));
    }

    println!("{:<32} {:>12} {:>12}", "case", "mean ms", "best ms");
    for (name, mean, best) in &results {
        println!("{name:<32} {:>12.1} {:>12.1}", ms(*mean), ms(*best));
    }
    let ratio = ms(results[1].1) / ms(results[0].1);
    println!("deformation overhead (deformed / undeformed, means): {ratio:.2}×");
    let mean_of = |name: &str| results.iter().find(|r| r.0 == name).map_or(f64::NAN, |r| ms(r.1));
    println!(
        "empty-space grid: {:?} bricks of {:.2} mm, {:.0} % empty, built in {grid_ms:.1} ms",
        empty_space.lattice.dims,
        empty_space.lattice.brick_mm,
        100.0 * empty_space.empty_fraction
    );
    println!(
        "empty-space skipping (without / with, means): deformed {:.2}×, deformed + shaded (DVR) {:.2}×; images \
         identical: {}",
        mean_of("deformed") / mean_of("deformed, skipping"),
        mean_of("deformed + shaded") / mean_of("deformed + shaded, skipping"),
        if identical.iter().all(|&b| b) { "yes" } else { "NO" }
    );
    // The issue's targets, as the window draws (empty-space skipping on), whole frames with readback.
    let fps = |name: &str| 1000.0 / mean_of(name);
    let verdict = |met: bool| if met { "met" } else { "missed" };
    let shaded_fps = fps("deformed + shaded, skipping");
    let undeformed_fps = fps("undeformed, skipping");
    let overhead = mean_of("deformed, skipping") / mean_of("undeformed, skipping");
    println!("targets ({}×{}, empty-space skipping on, as the window draws):", o.size.0, o.size.1);
    println!("  deformed + shaded DVR: {shaded_fps:.1} fps (≥ 60): {}", verdict(shaded_fps >= 60.0));
    println!("  undeformed: {undeformed_fps:.1} fps (≥ 120): {}", verdict(undeformed_fps >= 120.0));
    println!("  deformation overhead (deformed / undeformed): {overhead:.2}× (≤ 1.25×): {}", verdict(overhead <= 1.25));
    if let Err(e) = ctx.check_errors() {
        println!("wgpu errors: {e}");
    }
}

/// The median ms of `frames` frames of `a` and of `b`, timed alternately (a, b, a, b, …) after one warm-up each.
fn alternating_medians<T>(frames: usize, mut a: impl FnMut() -> T, mut b: impl FnMut() -> T) -> (f64, f64) {
    std::hint::black_box((a(), b()));
    let (mut ta, mut tb) = (Vec::with_capacity(frames), Vec::with_capacity(frames));
    for _ in 0..frames {
        for (f, times) in [(&mut a as &mut dyn FnMut() -> T, &mut ta), (&mut b, &mut tb)] {
            let t = Instant::now();
            std::hint::black_box(f());
            times.push(ms(t.elapsed()));
        }
    }
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    (median(ta), median(tb))
}

/// Brunet et al. 2006's Table 1 (module docs): each deformation in the shader and through a control texture, unlit
/// and lit, the moving volume alone; ms/frame, the ratio and the images' difference.
fn procedural_table(
    ctx: &GpuContext,
    renderer: &RaycastRenderer,
    tfs: &GpuTransferFunctions,
    (moving, moving_gpu, moving_pf, style): (&PreparedVolume, &GpuVolume, &GpuPrefiltered, LayerStyle),
    cam: &OrbitCamera,
    target: &RenderTarget,
    o: &Options,
) {
    let (lo, hi) = (moving.info.box_min_lps, moving.info.box_max_lps);
    let (c, size) = ((0.5 * (lo + hi)).as_vec3(), (hi - lo).as_vec3());
    let a = 0.03 * size.min_element();
    // Amplitudes of 3 % of the box: a shift, a sine of one wavelength across it, a twist and a bend whose far faces
    // move by about that much, a bump of a fifth of the box.
    let deformations = [
        Procedural::Shift { offset_mm: Vec3::new(0.6, -0.64, 0.48) * a },
        Procedural::Sine {
            origin_mm: lo.as_vec3(),
            amplitude_mm: a,
            wavenumber_per_mm: Vec3::splat(std::f32::consts::TAU) / Vec3::new(size.y, size.z, size.x),
            phase_rad: Vec3::new(0.3, 1.7, 4.0),
        },
        Procedural::Twist { centre_mm: c, axis: Axis::Z, rate_rad_per_mm: 2.0 * a / (size.x * size.z) },
        Procedural::bend(c, Axis::Z, Axis::X, true, 8.0 * a / (size.z * size.z)),
        Procedural::Bump { centre_mm: c, sigma_mm: size.min_element() / 5.0, vector_mm: Vec3::new(0.6, 0.0, 0.8) * a },
    ];
    println!(
        "shader vs {n}³ control texture (Brunet et al. 2006 Table 1), moving volume alone, {} timed frames each",
        o.frames,
        n = o.ctrl
    );
    println!(
        "{:<7} {:<10} {:>12} {:>12} {:>16} {:>14} {:>12}",
        "case", "kind", "shader ms", "texture ms", "texture/shader", "mean |Δ|/255", "max |Δ|/255"
    );
    for (case, mode) in [("1 unlit", ShadingMode::None), ("2 lit", ShadingMode::Dvr)] {
        for p in deformations {
            let shader = GpuLayer {
                volume: moving_gpu,
                control: None,
                prefiltered: Some(moving_pf),
                style,
                procedural: Some(p),
                view: None,
            };
            let box_ref = shader.params().box_ref();
            let texels = p.control_texels([o.ctrl; 3], box_ref.0.to_array(), box_ref.1.to_array());
            let desc = ControlDesc {
                dims: [o.ctrl; 3],
                texels: &texels,
                box_min_ref: box_ref.0.to_array(),
                box_max_ref: box_ref.1.to_array(),
            };
            let prepared =
                PreparedControl::prepare(&desc, ctx.capabilities.float32_filterable && !o.ctrl_f16).expect("control");
            let control = GpuControlTexture::upload(ctx, &prepared);
            let texture = GpuLayer { control: Some(&control), procedural: None, ..shader };
            let settings = RenderSettings {
                blend: BlendMode::MovingOnly,
                box_override_ref: Some((box_ref.0.as_vec3(), box_ref.1.as_vec3())),
                samples_per_voxel: o.samples_per_voxel,
                shading: Shading::with_mode(mode),
                classification: o.classification,
                ..Default::default()
            };
            let draw = |layer: GpuLayer<'_>| {
                let frame = GpuFrame {
                    fixed: GpuLayer { style: LayerStyle { visible: false, ..style }, ..layer },
                    moving: layer,
                    tfs,
                };
                let data = RaycastDrawData::new(ctx, renderer, &frame, cam, &settings, o.size);
                renderer.render(ctx, &data, target).expect("render");
                target.read_back(ctx).expect("read back")
            };
            // Alternating frames, medians: a drift of the machine's load falls on both paths alike.
            let (shader_ms, texture_ms) = alternating_medians(o.frames, || draw(shader), || draw(texture));
            let (a, b) = (draw(shader), draw(texture));
            let diffs = a.iter().zip(&b).map(|(x, y)| f64::from(x.abs_diff(*y)));
            let (sum, max) = diffs.fold((0.0, 0.0f64), |(s, m), d| (s + d, m.max(d)));
            println!(
                "{case:<7} {:<10} {:>12.1} {:>12.1} {:>15.2}× {:>14.3} {:>12.0}",
                p.name(),
                shader_ms,
                texture_ms,
                texture_ms / shader_ms,
                sum / a.len() as f64,
                max
            );
        }
    }
    if let Err(e) = ctx.check_errors() {
        println!("wgpu errors: {e}");
    }
}
