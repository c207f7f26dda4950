//! Export benchmark: a procedural CT-like i16 head of `--dims` (256³ by default, 240 mm box, slightly
//! rotated against the target) resampled onto an axis-aligned 256³ target grid through a TPS pull-back with
//! `--centres` (100) centres:
//!
//! 1. CPU, through a `--ctrl`³ (64³) control texture sampled from the TPS (as the renderer uses it): nearest,
//!    trilinear, Catmull-Rom; and the identity (resampling only);
//! 2. CPU, exact TPS per voxel, on a `--tps-dims`³ target (48³ by default), extrapolated to the full target by the
//!    per-voxel cost;
//! 3. GPU (wgpu's default adapter, or the one `WGPU_BACKEND` chooses): control texture, full target; exact TPS on a
//!    `--gpu-tps-dims`³ target (64³), extrapolated;
//! 4. the memory-bandwidth floor: a plain copy of input + output bytes (i16 → i16: a memcpy of the source into a
//!    buffer of the output's size), on one thread and on rayon's pool; ratio = export time / floor.
//!
//! Each case reports the best of `--repeats` (3) runs after one warm-up run, wall clock, including allocation of the
//! output (and for the GPU the source upload and every slab's readback), and the process's CPU time per run (all
//! threads; on a machine shared with other work, CPU time / threads estimates the wall time of an idle machine).
//!
//! ```sh
//! cargo bench -p warpbench-gpu --bench export
//! cargo bench -p warpbench-gpu --bench export -- --dims 128 --centres 50 --repeats 5
//! ```
//!
//! `--no-gpu` skips the GPU cases. It only runs when `--bench` is among the arguments (as `cargo bench` passes), so `cargo test --benches` does not.

use std::time::{Duration, Instant};

use glam::DVec3;
use rayon::prelude::*;
use warpbench_gpu::{
    ControlDesc, ExportPass, ExportRequest, ExportSamples, GpuContext, Interpolation, PullBack, SourceVolume,
    TargetGrid, TpsDesc, export_cpu,
};

/// Edge of the source and target boxes, mm.
const BOX_MM: f64 = 240.0;

struct Options {
    dims: usize,
    ctrl: usize,
    centres: usize,
    tps_dims: usize,
    gpu_tps_dims: usize,
    repeats: usize,
    gpu: bool,
}

fn options() -> Result<Options, String> {
    let mut o = Options { dims: 256, ctrl: 64, centres: 100, tps_dims: 48, gpu_tps_dims: 64, repeats: 3, gpu: true };
    let args: Vec<String> = std::env::args().skip(1).collect();
    let mut it = args.iter();
    while let Some(a) = it.next() {
        let mut value = || -> Result<usize, String> {
            let v = it.next().ok_or_else(|| format!("{a} needs a value"))?;
            v.parse().map_err(|e| format!("{a}: {e}"))
        };
        match a.as_str() {
            "--dims" => o.dims = value()?,
            "--ctrl" => o.ctrl = value()?,
            "--centres" => o.centres = value()?,
            "--tps-dims" => o.tps_dims = value()?,
            "--gpu-tps-dims" => o.gpu_tps_dims = value()?,
            "--repeats" => o.repeats = value()?,
            "--no-gpu" => o.gpu = false,
            _ => {} // --bench and whatever else cargo passes
        }
    }
    if o.dims < 2 || o.ctrl < 2 || o.tps_dims < 2 || o.gpu_tps_dims < 2 {
        return Err("sizes must be at least 2".into());
    }
    o.repeats = o.repeats.max(1);
    Ok(o)
}

/// A deterministic pseudo-random value in [0, 1).
fn hash01(i: u64, seed: u64) -> f64 {
    let mut x = i ^ seed.wrapping_mul(0x9E37_79B9_7F4A_7C15);
    x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^= x >> 31;
    (x >> 11) as f64 / (1u64 << 53) as f64
}

fn smoothstep(e0: f64, e1: f64, x: f64) -> f64 {
    let t = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// A CT-like head (HU) at p ∈ \[−½, ½\]³: skin, soft tissue with fine texture, a bone shell, a dense blob.
fn ct(p: DVec3) -> i16 {
    let w = 0.006;
    let r = (p * DVec3::new(1.0, 1.15, 1.05)).length();
    let head = 1.0 - smoothstep(0.42 - w, 0.42 + w, r);
    let bone = smoothstep(0.36 - w, 0.36 + w, r) * head;
    let blob = 1.0 - smoothstep(0.06, 0.07, (p - DVec3::new(0.12, -0.05, 0.1)).length());
    let texture = 30.0 * (p.x * 90.0).sin() * (p.y * 70.0).sin() * (p.z * 50.0).sin();
    (-1000.0 + (1040.0 + texture) * head + 1160.0 * bone + 600.0 * blob).round() as i16
}

/// Row-major `lps_from_index` of an n³ grid filling a `BOX_MM` cube centred at the origin, rotated by `angle_rad`
/// about z.
fn grid(n: usize, angle_rad: f64) -> [[f64; 4]; 4] {
    let (s, c) = angle_rad.sin_cos();
    let sp = BOX_MM / n as f64;
    let r = [[c * sp, -s * sp, 0.0], [s * sp, c * sp, 0.0], [0.0, 0.0, sp]];
    let h = (n as f64 - 1.0) / 2.0;
    let mut m = [[0.0; 4]; 4];
    for row in 0..3 {
        m[row][..3].copy_from_slice(&r[row]);
        m[row][3] = -h * (r[row][0] + r[row][1] + r[row][2]);
    }
    m[3][3] = 1.0;
    m
}

/// A smooth TPS pull-back with `n` centres in the central 200 mm: mean-free random weights scaled to displacements
/// of a few mm, and a near-identity affine part.
fn tps(n: usize) -> (Vec<[f64; 3]>, Vec<[f64; 3]>) {
    let centres: Vec<[f64; 3]> =
        (0..n as u64).map(|i| std::array::from_fn(|a| (hash01(3 * i + a as u64, 1) - 0.5) * 200.0)).collect();
    let mut weights: Vec<[f64; 3]> =
        (0..n as u64).map(|i| std::array::from_fn(|a| hash01(3 * i + a as u64, 2) - 0.5)).collect();
    for a in 0..3 {
        let mean = weights.iter().map(|w| w[a]).sum::<f64>() / n as f64;
        for w in &mut weights {
            w[a] = (w[a] - mean) * 0.02;
        }
    }
    (centres, weights)
}

/// The pull-back sampled at the texel centres of an n³ control texture over the target box.
fn control_texels(tps: &TpsDesc<'_>, n: usize) -> Vec<f32> {
    let lo = -BOX_MM / 2.0;
    (0..n * n * n)
        .into_par_iter()
        .flat_map_iter(|t| {
            let abc = [t % n, (t / n) % n, t / (n * n)];
            let x: [f64; 3] = std::array::from_fn(|a| lo + (abc[a] as f64 + 0.5) / n as f64 * BOX_MM);
            let u = tps.eval(x);
            [(u[0] - x[0]) as f32, (u[1] - x[1]) as f32, (u[2] - x[2]) as f32, 0.0]
        })
        .collect()
}

/// CPU time of the whole process (user + system, all threads) from /proc/self/stat, in clock ticks of 10 ms
/// (`CLK_TCK` = 100 on Linux); `None` elsewhere.
fn process_cpu_time() -> Option<Duration> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    let fields: Vec<&str> = stat.rsplit_once(')')?.1.split_whitespace().collect();
    let ticks: u64 = fields.get(11)?.parse::<u64>().ok()? + fields.get(12)?.parse::<u64>().ok()?;
    Some(Duration::from_millis(ticks * 10))
}

/// The machine's 1-minute load average (other processes compete for the cores when it exceeds the thread count).
fn load_average() -> String {
    std::fs::read_to_string("/proc/loadavg").map_or_else(|_| "?".into(), |s| s.split(' ').next().unwrap_or("?").into())
}

/// Best wall-clock time of `repeats` runs, and the mean process CPU time per run.
fn best_of(repeats: usize, mut f: impl FnMut()) -> (Duration, Option<Duration>) {
    let cpu_before = process_cpu_time();
    let best = (0..repeats)
        .map(|_| {
            let t = Instant::now();
            f();
            t.elapsed()
        })
        .min()
        .unwrap_or_default();
    let cpu = cpu_before.zip(process_cpu_time()).map(|(a, b)| b.saturating_sub(a) / repeats as u32);
    (best, cpu)
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
            eprintln!("export bench: {e}");
            std::process::exit(2);
        }
    };
    let n = o.dims;
    let voxels = n * n * n;
    println!(
        "export bench: {n}³ i16 source → {n}³ i16 target, TPS with {} centres, {}³ control texture, {} rayon \
         threads, best of {}",
        o.centres,
        o.ctrl,
        rayon::current_num_threads(),
        o.repeats
    );
    let t = Instant::now();
    let samples: Vec<i16> = (0..voxels)
        .into_par_iter()
        .map(|v| {
            let ijk = DVec3::new((v % n) as f64, ((v / n) % n) as f64, (v / (n * n)) as f64);
            ct((ijk + DVec3::splat(0.5)) / n as f64 - DVec3::splat(0.5))
        })
        .collect();
    let source = SourceVolume { dims: [n; 3], samples: ExportSamples::I16(&samples), lps_from_index: grid(n, 0.05) };
    let target = TargetGrid { dims: [n; 3], lps_from_index: grid(n, 0.0) };
    let (centres, weights) = tps(o.centres);
    let tps = TpsDesc {
        centres_ref: &centres,
        weights: &weights,
        linear: [[1.01, 0.02, 0.0], [-0.02, 0.99, 0.01], [0.0, -0.01, 1.0]],
        translation: [2.0, -1.5, 1.0],
    };
    let t_ctrl = Instant::now();
    let texels = control_texels(&tps, o.ctrl);
    let ctrl_ms = ms(t_ctrl.elapsed());
    let control = ControlDesc {
        dims: [o.ctrl; 3],
        texels: &texels,
        box_min_ref: [-BOX_MM / 2.0; 3],
        box_max_ref: [BOX_MM / 2.0; 3],
    };
    let max_disp = texels.chunks_exact(4).map(|c| c[..3].iter().map(|v| v * v).sum::<f32>().sqrt()).fold(0.0, f32::max);
    println!(
        "setup: volume {:.0} ms; control texture sampled from the exact TPS in {ctrl_ms:.1} ms; largest displacement \
         {max_disp:.1} mm",
        ms(t.elapsed()) - ctrl_ms
    );

    // The floor: read the input and write the output once.
    let bytes = 2 * voxels;
    let src_bytes: &[u8] = bytemuck::cast_slice(&samples);
    let mut dst = vec![0u8; bytes];
    let copy_1 = best_of(o.repeats + 2, || dst.copy_from_slice(src_bytes)).0;
    let chunk = bytes.div_ceil(rayon::current_num_threads() * 4).max(1);
    let copy_n = best_of(o.repeats + 2, || {
        dst.par_chunks_mut(chunk).zip(src_bytes.par_chunks(chunk)).for_each(|(d, s)| d.copy_from_slice(s));
    })
    .0;
    std::hint::black_box(&dst);
    let floor = copy_1.min(copy_n);
    let gib_s = |d: Duration| 2.0 * bytes as f64 / d.as_secs_f64() / f64::from(1 << 30);
    println!(
        "floor (copy {} MiB in + {} MiB out): {:.1} ms on 1 thread ({:.1} GiB/s), {:.1} ms on the pool ({:.1} GiB/s)",
        bytes >> 20,
        bytes >> 20,
        ms(copy_1),
        gib_s(copy_1),
        ms(copy_n),
        gib_s(copy_n)
    );

    println!("\n| path | pull-back | interpolation | target | wall (ms) | ns/voxel | × floor | CPU (ms) | load |");
    println!("|---|---|---|---|---|---|---|---|---|");
    let row = |path: &str, pullback: &str, kernel: &str, dims: usize, (d, cpu): (Duration, Option<Duration>)| {
        let scale = voxels as f64 / (dims * dims * dims) as f64;
        let per_voxel = d.as_secs_f64() * 1e9 / (dims * dims * dims) as f64;
        let full = ms(d) * scale;
        let cpu = cpu.map_or_else(|| "?".into(), |c| format!("{:.0}", ms(c) * scale));
        let note = if dims == n { String::new() } else { format!(" (from {dims}³)") };
        println!(
            "| {path} | {pullback} | {kernel} | {n}³{note} | {full:.0} | {per_voxel:.1} | {:.0} | {cpu} | {} |",
            full / ms(floor),
            load_average()
        );
    };
    let kernels = [
        ("trilinear", Interpolation::Trilinear),
        ("Catmull-Rom", Interpolation::CatmullRom),
        ("nearest", Interpolation::Nearest),
    ];
    let run_cpu = |request: &ExportRequest<'_>| {
        std::hint::black_box(export_cpu(request, &mut |_| true).expect("warm-up CPU export"));
        best_of(o.repeats, || {
            std::hint::black_box(export_cpu(request, &mut |_| true).expect("CPU export"));
        })
    };
    for (name, kernel) in kernels {
        let request =
            ExportRequest { interpolation: kernel, ..ExportRequest::new(source, target, PullBack::Control(control)) };
        row("CPU", &format!("control {}³", o.ctrl), name, n, run_cpu(&request));
    }
    let identity = ExportRequest::new(source, target, PullBack::Identity);
    row("CPU", "identity", "trilinear", n, run_cpu(&identity));
    let small = TargetGrid { dims: [o.tps_dims; 3], lps_from_index: grid(o.tps_dims, 0.0) };
    let exact = ExportRequest::new(source, small, PullBack::Tps(tps));
    row("CPU", &format!("exact TPS, N = {}", o.centres), "trilinear", o.tps_dims, run_cpu(&exact));

    if !o.gpu {
        return;
    }
    let ctx = match GpuContext::headless() {
        Ok(ctx) => ctx,
        Err(e) => {
            println!("\nno GPU figures: {e}");
            return;
        }
    };
    let pass = ExportPass::new(&ctx).expect("export pass");
    let run_gpu = |request: &ExportRequest<'_>| {
        pass.run(&ctx, request, &mut |_| true).expect("warm-up GPU export");
        best_of(o.repeats, || {
            std::hint::black_box(pass.run(&ctx, request, &mut |_| true).expect("GPU export"));
        })
    };
    let gpu = format!("GPU ({})", ctx.describe());
    for (name, kernel) in &kernels[..2] {
        let request =
            ExportRequest { interpolation: *kernel, ..ExportRequest::new(source, target, PullBack::Control(control)) };
        row(&gpu, &format!("control {}³", o.ctrl), name, n, run_gpu(&request));
    }
    let small = TargetGrid { dims: [o.gpu_tps_dims; 3], lps_from_index: grid(o.gpu_tps_dims, 0.0) };
    let exact = ExportRequest::new(source, small, PullBack::Tps(tps));
    row(&gpu, &format!("exact TPS, N = {}", o.centres), "trilinear", o.gpu_tps_dims, run_gpu(&exact));
    let slab_request = ExportRequest::new(source, target, PullBack::Control(control));
    println!(
        "\nslab: {} slices of {n}² per dispatch on this device",
        ExportPass::slab_slices(&ctx, &slab_request).expect("slab")
    );
}
