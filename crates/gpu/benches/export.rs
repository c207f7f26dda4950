//! Export benchmark: a procedural CT-like i16 head of `--dims` (256³ by default, 240 mm box, slightly
//! rotated against the target) resampled onto an axis-aligned target grid of the same size through a TPS pull-back
//! with `--centres` (100) centres, every row on the full target (nothing is extrapolated):
//!
//! 1. CPU, through a `--ctrl`³ (64³) control texture sampled from the TPS (as the renderer uses it): nearest,
//!    trilinear, Catmull-Rom; the identity (resampling only); the exact TPS per voxel;
//! 2. GPU (wgpu's default adapter, or the one `WGPU_BACKEND` chooses): the same five cases, each run including the
//!    source's upload (in its own type), every slab's readback and the output's allocation; and the GPU's fixed
//!    cost, measured once: a new device, the export pass, and a first 8³ export (the pipeline's compilation);
//! 3. the memory-bandwidth floor: a plain copy of input + output bytes (i16 → i16: a memcpy of the source into a
//!    buffer of the output's size), on one thread and on rayon's pool; ratio = export time / floor;
//! 4. `--backend auto`'s rule (`warpbench_gpu::export::choose_path`) for each case: its estimates beside the
//!    measured times, and its choice, so that a run on a real GPU shows whether the rule's constants hold.
//!
//! Each case reports the best of `--repeats` (3) runs after one warm-up run, wall clock, and the process's CPU time
//! per run (all threads; on a machine shared with other work, CPU time / threads estimates the wall time of an idle
//! machine).
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
use warpbench_gpu::export::{ExportDevice, ExportPath, choose_path, cpu_estimate_ms, gpu_estimate_ms};
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
    repeats: usize,
    gpu: bool,
}

fn options() -> Result<Options, String> {
    let mut o = Options { dims: 256, ctrl: 64, centres: 100, repeats: 3, gpu: true };
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
            "--tps-dims" | "--gpu-tps-dims" => {
                return Err(format!("{a} is gone: every row runs on the full --dims target, nothing is extrapolated"));
            }
            "--repeats" => o.repeats = value()?,
            "--no-gpu" => o.gpu = false,
            _ => {} // --bench and whatever else cargo passes
        }
    }
    if o.dims < 2 || o.ctrl < 2 {
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
    let row = |path: &str, case: &str, kernel: &str, (d, cpu): (Duration, Option<Duration>)| {
        let cpu = cpu.map_or_else(|| "?".into(), |c| format!("{:.0}", ms(c)));
        println!(
            "| {path} | {case} | {kernel} | {n}³ | {:.0} | {:.1} | {:.0} | {cpu} | {} |",
            ms(d),
            d.as_secs_f64() * 1e9 / voxels as f64,
            ms(d) / ms(floor),
            load_average()
        );
    };
    let control_name = format!("control {}³", o.ctrl);
    let tps_name = format!("exact TPS, N = {}", o.centres);
    // The five cases, CPU and GPU alike: (pull-back, its name, kernel, its name).
    let cases = [
        (PullBack::Control(control), control_name.as_str(), Interpolation::Trilinear, "trilinear"),
        (PullBack::Control(control), control_name.as_str(), Interpolation::CatmullRom, "Catmull-Rom"),
        (PullBack::Control(control), control_name.as_str(), Interpolation::Nearest, "nearest"),
        (PullBack::Identity, "identity", Interpolation::Trilinear, "trilinear"),
        (PullBack::Tps(tps), tps_name.as_str(), Interpolation::Trilinear, "trilinear"),
    ];
    let request =
        |pullback, kernel| ExportRequest { interpolation: kernel, ..ExportRequest::new(source, target, pullback) };
    let run_cpu = |request: &ExportRequest<'_>| {
        std::hint::black_box(export_cpu(request, &mut |_| true).expect("warm-up CPU export"));
        best_of(o.repeats, || {
            std::hint::black_box(export_cpu(request, &mut |_| true).expect("CPU export"));
        })
    };
    let mut cpu_ms = Vec::new();
    for (pullback, name, kernel, kernel_name) in cases {
        let measured = run_cpu(&request(pullback, kernel));
        cpu_ms.push(ms(measured.0));
        row("CPU", name, kernel_name, measured);
    }

    let mut gpu_ms: Vec<Option<f64>> = vec![None; cases.len()];
    let mut device = ExportDevice::None;
    if o.gpu {
        let cold = Instant::now();
        match GpuContext::headless() {
            Err(e) => println!("\nno GPU figures: {e}"),
            Ok(ctx) => {
                let device_ms = ms(cold.elapsed());
                device = ExportDevice::of(&ctx);
                let pass = ExportPass::new(&ctx).expect("export pass");
                let tiny_samples = vec![0i16; 8 * 8 * 8];
                let tiny = ExportRequest::new(
                    SourceVolume {
                        dims: [8; 3],
                        samples: ExportSamples::I16(&tiny_samples),
                        lps_from_index: grid(8, 0.0),
                    },
                    TargetGrid { dims: [8; 3], lps_from_index: grid(8, 0.0) },
                    PullBack::Identity,
                );
                pass.run(&ctx, &tiny, &mut |_| true).expect("first GPU export");
                let fixed_ms = ms(cold.elapsed());
                let gpu = format!("GPU ({})", ctx.describe());
                for (i, (pullback, name, kernel, kernel_name)) in cases.into_iter().enumerate() {
                    let r = request(pullback, kernel);
                    pass.run(&ctx, &r, &mut |_| true).expect("warm-up GPU export");
                    let measured = best_of(o.repeats, || {
                        std::hint::black_box(pass.run(&ctx, &r, &mut |_| true).expect("GPU export"));
                    });
                    gpu_ms[i] = Some(ms(measured.0));
                    row(&gpu, name, kernel_name, measured);
                }
                println!(
                    "\nGPU fixed cost: device {device_ms:.0} ms; device, export pass and a first 8³ export (one pipeline \
                     compiled) {fixed_ms:.0} ms (the rule assumes {:.0} ms)",
                    warpbench_gpu::export::GPU_FIXED_MS
                );
                let slab =
                    ExportPass::slab_slices(&ctx, &request(PullBack::Control(control), Interpolation::Trilinear))
                        .expect("slab");
                println!("slab: {slab} slices of {n}² per dispatch (control texture, i16 output) on this device");
            }
        }
    }

    let threads = rayon::current_num_threads();
    println!(
        "\n`--backend auto`'s rule on {threads} threads ({device:?} device; a GPU estimate includes the fixed cost, the \
         measured GPU times do not):"
    );
    println!(
        "\n| case | interpolation | CPU ms (rule) | GPU ms (rule) | CPU ms measured | GPU ms measured | rule picks |"
    );
    println!("|---|---|---|---|---|---|---|");
    for (i, (pullback, name, kernel, kernel_name)) in cases.into_iter().enumerate() {
        let r = request(pullback, kernel);
        let pick = match choose_path(&r, threads, device).path {
            ExportPath::Cpu => "CPU",
            ExportPath::Gpu => "GPU",
        };
        let measured_gpu = gpu_ms[i].map_or_else(|| "–".to_owned(), |v| format!("{v:.0}"));
        println!(
            "| {name} | {kernel_name} | {:.0} | {:.0} | {:.0} | {measured_gpu} | {pick} |",
            cpu_estimate_ms(&r, threads),
            gpu_estimate_ms(&r),
            cpu_ms[i]
        );
    }
}
