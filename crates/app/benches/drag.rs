//! Drag-event benchmark (issue 7): what the window does on one landmark drag event, headless, on the same code
//! path: both warps of the moved pairs, the pull-back's control texture made the viewer's, the moving glyphs placed
//! through the forward warp, and the 3-D view rendered at the interaction sample rate with the glyphs
//! ([`warpbench_app::gui::viewer::Viewer`]), waiting for the GPU to finish.
//!
//! The pair is the demo pair (the Colin27 MRI as fixed, the Cranium CT as moving, from `tests/data/nifti`), with N
//! seeded pairs in the central 80 % of the fixed box and a smooth 5 mm displacement; each event moves pair 0's fixed
//! point (or, with `--end moving`, its moving point) by 0.5 mm, as a drag does. With a TPS the events go through
//! [`warpbench_app::fit::DragFit`] as the window's do: the basis (both directions factorised, which the window does on
//! a thread after the full fit before a drag, [`warpbench_app::fit::DragBasis`]) and the drag's start from it (the
//! dragged pair's unit responses, and with the texture on the CPU the drag's texture sampled) are timed once, then
//! each event is its O(N²) coefficient update and its
//! texture, updated on the CPU and uploaded or, with `--gpu-eval`, the pull-back's centres and weights uploaded and
//! evaluated by `ControlEvalPass` (issue 28). `--full-refit` times the full [`warpbench_app::fit::fit_warp`] (or
//! [`warpbench_app::fit::fit_warp_on_gpu`]) per event instead, as before. Reports the mean and best event time and
//! its parts: coefficient update (or the fits), control texture, glyphs, frame.
//!
//! ```sh
//! cargo bench -p warpbench-app --bench drag
//! cargo bench -p warpbench-app --bench drag -- --size 1920x1080 --pairs 100 --events 20
//! cargo bench -p warpbench-app --bench drag -- --pairs 1000 --events 10 --end moving
//! cargo bench -p warpbench-app --bench drag -- --size 320x240 --pairs 1000 --events 10 --gpu-eval
//! ```
//!
//! Options: `--size WxH` (default 1920x1080), `--pairs N` (100), `--events N` (10), `--end fixed|moving` (fixed),
//! `--full-refit` (no drag fast path), `--method NAME` (tps; also
//! hbspline, affine, similarity, rigid; `--gpu-eval` takes tps and hbspline), `--grid N` (control texture
//! edge, 48 as the window), `--full` (the full sample rate instead of the interaction one), `--gpu-eval` (the control
//! texture evaluated on the GPU by `ControlEvalPass`, as the window does on a real GPU), `--gpu-prefilter`
//! (on a CPU driver, the prefilter as a compute pass at upload instead of on the CPU while preparing), `--refine`
//! (after the events, the release as the window paces it on a CPU driver ([`warpbench_app::gui::pacing`]): the
//! reduced view, then the full view band by band, once with the cost per pixel unknown and once with it measured; it
//! reports the longest band, which is what a UI frame waits for, against the one-pass full view), `--field` (a smooth
//! displacement field under the pairs, as Refine by intensities leaves one: the drag updates the landmark layers and
//! applies the field to the CPU texture; with `--gpu-eval` it refits in full, as the window does). The adapter is wgpu's
//! default, or the one `WGPU_BACKEND` chooses. It only runs when `--bench` is among the arguments (as `cargo bench`
//! passes), so `cargo test --benches` does not run it.

use std::time::{Duration, Instant};

use warpbench_app::fit::{self, ControlRoute, DragBasis, DragFit, fit_warp, fit_warp_on_gpu};
use warpbench_app::gui::pacing::{BAND_ALIGN_ROWS, Bands, RefineJob, interactive_size};
use warpbench_app::gui::viewer::{DeviceFacts, LayerData, Viewer};
use warpbench_app::project::demo;
use warpbench_app::project::stack::Layers;
use warpbench_gpu::glam::Vec3;
use warpbench_gpu::{
    GlyphPair, GlyphStyle, GpuContext, OrbitCamera, Projection, Quality, RenderSettings, SlicePlane, pair_glyphs,
};
use warpbench_io::Volume;
use warpbench_io::geometry::{Lps, Point3};
use warpbench_solver::method::Method;
use warpbench_solver::spaces::{Fixed, Moving, as_fixed, as_moving};
use warpbench_solver::tps_drag::DraggedEnd;
use warpbench_solver::warp::Warp;

struct Options {
    size: (u32, u32),
    pairs: usize,
    events: usize,
    grid: usize,
    quality: Quality,
    gpu_eval: bool,
    refine: bool,
    method: Method,
    gpu_prefilter: bool,
    end: DraggedEnd,
    event_fit: EventFit,
    under: Under,
}

/// What lies under the pairs in the warp stack.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Under {
    Nothing,
    /// A smooth displacement field (`--field`, [`field_layers`]).
    Field,
}

/// How a TPS drag event fits.
#[derive(Clone, Copy, PartialEq, Eq)]
enum EventFit {
    /// Through [`DragFit`], as the window does.
    DragFastPath,
    /// [`fit_warp`] (or, with `--gpu-eval`, [`fit_warp_on_gpu`]) on every event (`--full-refit`), as the window did
    /// before.
    FullRefit,
}

/// The parts of one drag event, in order.
struct Parts {
    /// From the pairs to both warps (with a full refit and the texture on the GPU, the texture too).
    fit: Duration,
    /// The control texture made the viewer's.
    texture: Duration,
    /// The glyphs placed: the forward warp at the N moving points.
    glyphs: Duration,
    /// The 3-D view rendered, waiting for the GPU.
    frame: Duration,
}

impl Parts {
    fn total(&self) -> Duration {
        self.fit + self.texture + self.glyphs + self.frame
    }
}

fn options() -> Result<Options, String> {
    let mut o = Options {
        size: (1920, 1080),
        pairs: 100,
        events: 10,
        grid: 48,
        quality: Quality::Interactive,
        gpu_eval: false,
        refine: false,
        method: Method::Tps { stiffness: 0.0 },
        gpu_prefilter: false,
        end: DraggedEnd::Fixed,
        event_fit: EventFit::DragFastPath,
        under: Under::Nothing,
    };
    let args: Vec<String> = std::env::args().skip(1).collect();
    let mut it = args.iter();
    while let Some(a) = it.next() {
        let mut value = || it.next().ok_or_else(|| format!("{a} needs a value"));
        let number = |v: &str| v.parse::<usize>().map_err(|e| format!("{a}: {e}"));
        match a.as_str() {
            "--size" => {
                let v = value()?;
                let (w, h) = v.split_once('x').ok_or_else(|| format!("--size {v}: expected WxH"))?;
                o.size =
                    (w.parse().map_err(|e| format!("--size: {e}"))?, h.parse().map_err(|e| format!("--size: {e}"))?);
            }
            "--pairs" => o.pairs = number(value()?)?,
            "--events" => o.events = number(value()?)?.max(1),
            "--grid" => o.grid = number(value()?)?,
            "--full" => o.quality = Quality::Full,
            "--gpu-eval" => o.gpu_eval = true,
            "--refine" => o.refine = true,
            "--gpu-prefilter" => o.gpu_prefilter = true,
            "--full-refit" => o.event_fit = EventFit::FullRefit,
            "--field" => o.under = Under::Field,
            "--end" => {
                o.end = match value()?.as_str() {
                    "fixed" => DraggedEnd::Fixed,
                    "moving" => DraggedEnd::Moving,
                    v => return Err(format!("--end {v}: fixed or moving")),
                }
            }
            "--method" => {
                let v = value()?;
                o.method = Method::from_name(v).ok_or_else(|| format!("--method {v}: tps, hbspline, affine, ...?"))?;
            }
            "--bench" => {}
            other => return Err(format!("unknown option {other}")),
        }
    }
    Ok(o)
}

/// A number in [0, 1) from `i` and `salt` (a fixed, seedless sequence).
fn hash01(i: usize, salt: u64) -> f64 {
    let mut x = (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ salt.wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x ^= x >> 31;
    x = x.wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^= x >> 29;
    (x >> 11) as f64 / (1u64 << 53) as f64
}

/// N fixed points in the central 80 % of the fixed box and their moving points 5 mm away along a smooth field.
fn pairs(fixed: &Volume, n: usize) -> (Vec<Point3<Lps>>, Vec<Point3<Lps>>) {
    let (lo, hi) = box_lps(fixed);
    let q: Vec<Point3<Lps>> = (0..n)
        .map(|i| {
            let c: [f64; 3] = std::array::from_fn(|a| lo[a] + (0.1 + 0.8 * hash01(i, a as u64 + 1)) * (hi[a] - lo[a]));
            Point3::new(c[0], c[1], c[2])
        })
        .collect();
    let p = q
        .iter()
        .map(|q| {
            let c = q.coords();
            Point3::new(
                c[0] + 5.0 * (c[1] / 25.0).sin(),
                c[1] + 5.0 * (c[2] / 30.0).sin(),
                c[2] + 5.0 * (c[0] / 28.0).cos(),
            )
        })
        .collect();
    (q, p)
}

fn box_lps(v: &Volume) -> ([f64; 3], [f64; 3]) {
    let b = warpbench_app::inputs::volume_box::<Fixed>(v);
    (b.min.coords(), b.max.coords())
}

fn main() {
    if !std::env::args().any(|a| a == "--bench") {
        return;
    }
    let o = match options() {
        Ok(o) => o,
        Err(e) => {
            eprintln!("drag bench: {e}");
            std::process::exit(2);
        }
    };
    let (fixed, moving) = match demo::demo_paths() {
        Some((ct, mr)) => (
            warpbench_io::open(&mr).unwrap_or_else(|e| panic!("{e}")),
            warpbench_io::open(&ct).unwrap_or_else(|e| panic!("{e}")),
        ),
        None => (demo::phantom(96, 2.0, [0.0; 3], false), demo::phantom(96, 2.0, [6.0, -4.0, 3.0], true)),
    };
    let ctx = match GpuContext::headless() {
        Ok(c) => c,
        Err(e) => {
            eprintln!("drag bench: no GPU adapter ({e})");
            return;
        }
    };
    let adapter = ctx.describe();
    let filterable = ctx.capabilities.float32_filterable;
    // As the window does once a pair is read: prepared on the loading thread, uploaded on the UI thread.
    // --gpu-prefilter: the prefilter compute pass at upload even on a CPU driver, as the window did before it
    // prefiltered on the loading thread.
    let facts = DeviceFacts { cpu_driver: ctx.is_cpu_driver() && !o.gpu_prefilter, ..DeviceFacts::of(&ctx) };
    let prepare_start = Instant::now();
    let layers = [&fixed, &moving].map(|v| LayerData::prepare(v, facts).unwrap_or_else(|e| panic!("{e:#}")));
    let prepare = prepare_start.elapsed();
    let upload_start = Instant::now();
    let mut viewer = Viewer::from_layers(ctx, &layers[0], &layers[1]).unwrap_or_else(|e| panic!("{e:#}"));
    viewer.ctx.wait_idle().unwrap_or_else(|e| panic!("{e}"));
    let upload = upload_start.elapsed();
    drop(layers);
    let (lo, hi) = viewer.scene_box();
    let camera = OrbitCamera::fit(lo, hi, Projection::Perspective { fov_y_rad: 0.6 });
    // The window's own defaults (shaded DVR at one sample per voxel, the mix blend).
    let settings = warpbench_app::project::document::ViewSettings::default().render_settings();
    let method = o.method;
    let boxes =
        (warpbench_app::inputs::volume_box::<Fixed>(&fixed), warpbench_app::inputs::volume_box::<Moving>(&moving));
    let (mut q, mut p) = pairs(&fixed, o.pairs);
    let stack = match o.under {
        Under::Field => field_layers(&fixed),
        Under::Nothing => Layers::default(),
    };
    // A field under the pairs keeps the full fit on the GPU route (`DragFit::start`).
    let fast = o.event_fit == EventFit::DragFastPath
        && matches!(method, Method::Tps { .. })
        && !(o.under == Under::Field && o.gpu_eval);
    let route = if o.gpu_eval { ControlRoute::Gpu } else { ControlRoute::Cpu };
    let (mut drag, mut drag_start) = (None::<DragFit>, Duration::ZERO);
    let (q0, p0) = (q[0].coords(), p[0].coords());
    // What the window factorises on a thread after the full fit before the drag (`fit::DragBasis`).
    let basis_start = Instant::now();
    let mut basis = fast.then(|| {
        let (fixed_pts, moving_pts): (Vec<_>, Vec<_>) =
            (q.iter().copied().map(as_fixed).collect(), p.iter().copied().map(as_moving).collect());
        DragBasis::new(&method, (&fixed_pts, &moving_pts), &stack).expect("a TPS").unwrap_or_else(|e| panic!("{e:#}"))
    });
    let basis_time = basis_start.elapsed();

    let mut event = |e: usize| -> Parts {
        // The drag: pair 0's point moves 0.5 mm along L.
        match o.end {
            DraggedEnd::Fixed => q[0] = Point3::new(q0[0] + 0.5 * (e % 7) as f64, q0[1], q0[2]),
            DraggedEnd::Moving => p[0] = Point3::new(p0[0] + 0.5 * (e % 7) as f64, p0[1], p0[2]),
        }
        let t0 = Instant::now();
        let fixed_pts: Vec<_> = q.iter().copied().map(as_fixed).collect();
        let moving_pts: Vec<_> = p.iter().copied().map(as_moving).collect();
        if let Some(basis) = basis.take() {
            // The drag's first event, as the window starts it: from the basis the last full fit left.
            let start = DragFit::from_basis(basis, (boxes.0, o.grid), (0, o.end), route);
            drag = Some(start.expect("a TPS").unwrap_or_else(|e| panic!("{e:#}")));
            drag_start = t0.elapsed();
        }
        let (fitted, t1) = if let Some(drag) = &drag {
            let event = drag.event(&fixed_pts, &moving_pts).expect("the drag's fast path");
            let t1 = Instant::now();
            drag.show(&event, &mut viewer).unwrap_or_else(|e| panic!("{e:#}"));
            (event.into_fitted(), t1)
        } else if o.gpu_eval {
            let fitted = fit_warp_on_gpu(&method, &fixed_pts, &moving_pts, boxes, o.grid, &mut viewer, &stack);
            (fitted.unwrap_or_else(|e| panic!("{e:#}")), Instant::now())
        } else {
            let (fitted, prepared) = fit_warp(&method, &fixed_pts, &moving_pts, boxes, o.grid, filterable, &stack)
                .unwrap_or_else(|e| panic!("{e:#}"));
            let t1 = Instant::now();
            viewer.set_control(Some(&prepared));
            (fitted, t1)
        };
        let t2 = Instant::now();
        // The moving glyphs where the window draws them: d(pᵢ) through the forward warp.
        let glyph_pairs: Vec<GlyphPair> = q
            .iter()
            .zip(&p)
            .map(|(q, p)| GlyphPair {
                moving_ref: Some(Vec3::from_array(fitted.forward.apply(as_moving(*p)).coords().map(|v| v as f32))),
                fixed_ref: Some(Vec3::from_array(q.coords().map(|v| v as f32))),
                selected: false,
                active: true,
            })
            .collect();
        let glyphs = pair_glyphs(&glyph_pairs, &GlyphStyle::default());
        let t3 = Instant::now();
        let target =
            viewer.render_view(&camera, &settings, o.quality, o.size, &glyphs).unwrap_or_else(|e| panic!("{e:#}"));
        viewer.ctx.wait_idle().unwrap_or_else(|e| panic!("{e}"));
        drop(target);
        Parts { fit: t1 - t0, texture: t2 - t1, glyphs: t3 - t2, frame: t3.elapsed() }
    };
    // Warm-up: pipelines compile, the pool fills (and the drag starts).
    for e in 0..2 {
        event(e);
    }
    let parts: Vec<Parts> = (0..o.events).map(|e| event(e + 2)).collect();
    // The two fits alone: with --gpu-eval, what a drag event leaves on the CPU besides the pick.
    let fixed_pts: Vec<_> = q.iter().copied().map(as_fixed).collect();
    let moving_pts: Vec<_> = p.iter().copied().map(as_moving).collect();
    let fits = (0..o.events.max(5))
        .map(|_| {
            let t = Instant::now();
            let pullback = fit::pullback(&method, &fixed_pts, &moving_pts, boxes.0).unwrap_or_else(|e| panic!("{e}"));
            let forward = fit::forward(&method, &fixed_pts, &moving_pts, boxes.1).unwrap_or_else(|e| panic!("{e}"));
            let elapsed = t.elapsed();
            drop((pullback, forward));
            elapsed
        })
        .min()
        .unwrap_or_default();
    let n = o.events as u32;
    let ms = |d: Duration| d.as_secs_f64() * 1e3;
    let mean = |part: fn(&Parts) -> Duration| ms(parts.iter().map(part).sum::<Duration>() / n);
    let best = parts.iter().map(Parts::total).min().unwrap_or_default();
    println!(
        "drag bench: {adapter}; {}x{} view, {:?} quality, {} pairs ({method}), {}³ control texture on the {}, {} events",
        o.size.0,
        o.size.1,
        o.quality,
        o.pairs,
        o.grid,
        if o.gpu_eval { "GPU" } else { "CPU" },
        o.events
    );
    println!(
        "showing the pair: prepared {:.0} ms (loading thread: LayerData::prepare, {}), uploaded {:.0} ms (UI thread: \
         Viewer::from_layers, pipelines included{})",
        ms(prepare),
        if facts.cpu_driver { "with the CPU prefilter" } else { "texels only" },
        ms(upload),
        if facts.cpu_driver { "" } else { ", with the GPU prefilter" }
    );
    let (fit_part, texture_part) = match (drag.is_some(), o.gpu_eval) {
        (true, true) => ("coefficient update (DragFit::event, both directions)", "upload + GPU eval (DragFit::show)"),
        (true, false) => {
            ("coefficient update (DragFit::event, both directions)", "CPU texture + upload (DragFit::show)")
        }
        (false, true) => ("two fits + GPU eval (fit_warp_on_gpu)", "nothing more"),
        (false, false) => ("two fits + CPU texture (fit_warp)", "upload"),
    };
    println!(
        "per drag event: mean {:.2} ms (best {:.2} ms) = {fit_part} {:.2} ms + {texture_part} {:.2} ms + glyphs (d(p) \
         of the {} moving points) {:.2} ms + frame (render, wait) {:.2} ms",
        mean(Parts::total),
        ms(best),
        mean(|t| t.fit),
        mean(|t| t.texture),
        o.pairs,
        mean(|t| t.glyphs),
        mean(|t| t.frame),
    );
    if fast {
        println!(
            "drag fast path ({} point, fit::DragFit, texture on the {}): started once in {:.1} ms (from the basis \
             the last full fit left, {:.1} ms on its own thread: both directions factorised; pair 0's unit \
             responses{}), then each event above is its step",
            if o.end == DraggedEnd::Fixed { "fixed" } else { "moving" },
            if o.gpu_eval { "GPU" } else { "CPU" },
            ms(drag_start),
            ms(basis_time),
            if o.gpu_eval { "" } else { " and the drag's texture sampled" }
        );
    }
    println!("the two fits alone (pull-back and forward, CPU): best {:.2} ms", ms(fits));
    if o.refine {
        refine(&viewer, &camera, &settings, o.size);
        slices(&viewer, &fixed, &settings);
    }
}

/// The release after a drag on a CPU driver, as the window paces it: the one-pass full view for reference, the
/// reduced view shown at once, and the full view band by band (without glyphs, which are drawn once at the end).
fn refine(viewer: &Viewer, camera: &OrbitCamera, settings: &RenderSettings, size: (u32, u32)) {
    let ms = |d: Duration| d.as_secs_f64() * 1e3;
    let wait = || viewer.ctx.wait_idle().unwrap_or_else(|e| panic!("{e}"));
    let timed = |f: &dyn Fn()| {
        let t = Instant::now();
        f();
        wait();
        t.elapsed()
    };
    let once = timed(&|| drop(viewer.render_view(camera, settings, Quality::Full, size, &[]).expect("full view")));
    let per_px = ms(once) / (f64::from(size.0) * f64::from(size.1));
    let small = interactive_size(size, Some(per_px));
    let reduced =
        timed(&|| drop(viewer.render_view(camera, settings, Quality::Interactive, small, &[]).expect("reduced view")));
    println!(
        "release: one-pass full view {:.0} ms ({:.2} us/px); reduced view {}x{} {:.0} ms",
        ms(once),
        per_px * 1e3,
        small.0,
        small.1,
        ms(reduced)
    );
    refine_thread(viewer, camera, settings, size, per_px);
    for (label, view_cost) in [("cost unknown (first view)", None), ("cost measured", Some(per_px))] {
        let target = viewer.view_target(size);
        let mut bands = Bands::new(size.0, size.1);
        let mut times = Vec::new();
        while !bands.done() {
            let band = bands.next_aligned(view_cost, BAND_ALIGN_ROWS);
            let t = Instant::now();
            viewer
                .render_view_rows(camera, settings, Quality::Full, &target, band.clone())
                .unwrap_or_else(|e| panic!("{e:#}"));
            wait();
            times.push(ms(t.elapsed()));
            bands.rendered(&band, ms(t.elapsed()));
        }
        let total: f64 = times.iter().sum();
        let mut sorted = times.clone();
        sorted.sort_by(f64::total_cmp);
        println!(
            "bands, {label}: {} frames, longest {:.0} ms, median {:.0} ms, total {:.0} ms",
            times.len(),
            sorted.last().copied().unwrap_or(0.0),
            sorted.get(sorted.len() / 2).copied().unwrap_or(0.0),
            total
        );
    }
}

/// The window's refinement thread ([`RefineJob`]) for the same view: the time until it hands the view back.
fn refine_thread(viewer: &Viewer, camera: &OrbitCamera, settings: &RenderSettings, size: (u32, u32), per_px: f64) {
    let work = viewer.refine_work(camera, settings, viewer.view_target(size), Some(per_px));
    let (wake, woken) = std::sync::mpsc::channel();
    let t = Instant::now();
    let job = RefineJob::start(work, move || {
        wake.send(()).ok();
    })
    .unwrap_or_else(|e| panic!("{e}"));
    woken.recv().unwrap_or_else(|e| panic!("{e}"));
    let elapsed = t.elapsed();
    job.poll().expect("done").unwrap_or_else(|e| panic!("{e}"));
    println!("bands on the refinement thread: {:.0} ms", elapsed.as_secs_f64() * 1e3);
}

/// The three slice views through the fixed grid's centre, as the window renders them after a change (without
/// glyphs).
fn slices(viewer: &Viewer, fixed: &Volume, settings: &RenderSettings) {
    let m = fixed.lps_from_index.rows();
    let planes = [
        SlicePlane::axial(&m, fixed.dims, 0.0),
        SlicePlane::coronal(&m, fixed.dims, 0.0),
        SlicePlane::sagittal(&m, fixed.dims, 0.0),
    ];
    let render = || {
        let t = Instant::now();
        for plane in &planes {
            drop(viewer.render_slice(plane, settings, &[]).unwrap_or_else(|e| panic!("{e:#}")));
        }
        viewer.ctx.wait_idle().unwrap_or_else(|e| panic!("{e}"));
        t.elapsed()
    };
    render();
    let best = (0..5).map(|_| render()).min().unwrap_or_default();
    let sizes: Vec<String> = planes.iter().map(|p| format!("{}x{}", p.size.0, p.size.1)).collect();
    println!("three slices ({}): best of 5 {:.1} ms", sizes.join(", "), best.as_secs_f64() * 1e3);
}

/// A smooth displacement field under the landmarks (`--field`), on the fixed volume's box at 2 mm, up to 4 mm: what
/// the window's Refine by intensities or a field chosen under the landmarks leaves as a layer of the warp stack.
fn field_layers(fixed: &Volume) -> Layers {
    use warpbench_app::project::stack::FieldLayer;
    use warpbench_io::geometry::{Index, Transform};
    use warpbench_solver::field::SampledField;
    let fixed_box = warpbench_app::inputs::volume_box::<Fixed>(fixed);
    let (lo, hi) = (fixed_box.min.coords(), fixed_box.max.coords());
    let dims: [usize; 3] = std::array::from_fn(|a| ((hi[a] - lo[a]) / 2.0).ceil() as usize + 1);
    let lps_from_index = Transform::<Lps, Index>::from_scale_translation([2.0; 3], lo);
    let mut displacements = Vec::with_capacity(dims.iter().product());
    for k in 0..dims[2] {
        for j in 0..dims[1] {
            for i in 0..dims[0] {
                let [x, y, z] = [i, j, k].map(|n| n as f64 * 2.0);
                let d = [4.0 * (y / 40.0).sin(), 3.0 * (z / 35.0).cos(), 2.0 * (x / 50.0).sin()];
                displacements.push(d.map(|v| v as f32));
            }
        }
    }
    let field = SampledField::new(dims, lps_from_index, displacements).unwrap_or_else(|e| panic!("{e}"));
    Layers { field: Some(std::sync::Arc::new(FieldLayer::pullback(field, "the bench's field"))), ..Layers::default() }
}
