//! Registration benchmark (issue 31's speed target: a 256³ pair refined in at most 10 s on 2 cores and 1 s on a real
//! GPU): the refinement the window and `warpbench register` run ([`warpbench_app::register::refine`], defaults, from
//! the identity, no pairs), with the mutual information's samples read on the CPU and on the GPU, alternating, medians.
//!
//! The pair is the one of `data-scripts/register_speed.py`, made here without Python so that the GPU machine can run
//! it: Colin27 (`tests/data/nifti/ch2.nii.gz`) resampled trilinearly onto n³ voxels spanning its voxel centres as the
//! fixed volume, and as the moving volume the same grid shifted by s = (2, −1, 1) mm with its intensities remapped as
//! a second modality's (t ↦ 1000 (1 − t)^1.5 + 50 t, t the intensity scaled to [0, 1]). The truth is u(x) = x − s; the
//! bench reports the mean |u(x) − (x − s)| over the voxels of the head (fixed intensity above a fifth of its
//! largest) on a 16³ grid, so the two paths are compared on accuracy too.
//!
//! ```sh
//! cargo bench -p warpbench-app --bench register
//! cargo bench -p warpbench-app --bench register -- --size 128 --rounds 1 --backends cpu
//! ```
//!
//! The last round of each backend is broken down by level (control points, samples, evaluations, seconds), and on
//! the GPU into the time in the device's calls (upload, value pass, gradient pass, each with its readback) and the
//! CPU's share (histogram, optimiser, pyramid), so that a missed target shows what bounds it.
//!
//! Options: `--size N` (256), `--rounds N` (3), `--backends cpu,gpu` (both; the GPU is wgpu's default adapter, or the
//! one `WGPU_BACKEND` chooses), `--metric mi|lncc|ngf` (mi; ngf has no GPU path). It only runs when `--bench` is among the arguments (as `cargo bench` passes), so
//! `cargo test --benches` does not run it.

use std::ops::ControlFlow;
use std::path::Path;
use std::sync::Mutex;
use std::time::{Duration, Instant};

use warpbench_app::gpu_samples::GpuSamples;
use warpbench_app::project::stack::Layers;
use warpbench_app::register::{RefineInputs, refine};
use warpbench_app::settings::Metric;
use warpbench_gpu::GpuContext;
use warpbench_io::geometry::{Index, Lps, Transform};
use warpbench_io::{GeometrySource, Volume, VoxelData};
use warpbench_solver::image::Image;
use warpbench_solver::method::Method;
use warpbench_solver::register::LevelReport;
use warpbench_solver::register::RegisterParams;
use warpbench_solver::register::device::{DeviceLevel, DeviceSamples, SampleDevice};
use warpbench_solver::spaces::Fixed;
use warpbench_solver::warp::{Parallelism, Warp};

const SHIFT_MM: [f64; 3] = [2.0, -1.0, 1.0];

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Backend {
    Cpu,
    Gpu,
}

/// Time spent in one kind of device call, and how many.
#[derive(Clone, Copy, Default)]
struct CallTime {
    calls: usize,
    total: Duration,
}

impl CallTime {
    fn add(&mut self, started: Instant) {
        self.calls += 1;
        self.total += started.elapsed();
    }
}

/// Where a GPU refinement's time went on the device side: uploads, the value pass and the gradient pass, each with
/// its dispatch, its wait and its readback (the device's calls return only when their results are on the CPU).
#[derive(Clone, Copy, Default)]
struct DeviceTimes {
    prepare: CallTime,
    values: CallTime,
    gradient: CallTime,
}

/// A [`SampleDevice`] that times the calls of the one it wraps, so that a missed target shows whether the device or
/// the CPU's share (histogram, optimiser, pyramid, fold check) bounds it.
struct Timed<'a> {
    inner: &'a dyn SampleDevice,
    times: Mutex<DeviceTimes>,
}

impl Timed<'_> {
    fn record(&self, f: impl FnOnce(&mut DeviceTimes) -> &mut CallTime, started: Instant) {
        // A poisoned lock only means another call panicked; its counts are still the best there are.
        let mut times = self.times.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        f(&mut times).add(started);
    }
}

impl SampleDevice for Timed<'_> {
    fn describe(&self) -> String {
        self.inner.describe()
    }

    fn prepare<'d>(&'d self, level: &DeviceLevel<'_>) -> Result<Box<dyn DeviceSamples + 'd>, String> {
        let started = Instant::now();
        let inner = self.inner.prepare(level)?;
        self.record(|t| &mut t.prepare, started);
        Ok(Box::new(TimedLevel { timed: self, inner }))
    }
}

struct TimedLevel<'d> {
    timed: &'d Timed<'d>,
    inner: Box<dyn DeviceSamples + 'd>,
}

impl DeviceSamples for TimedLevel<'_> {
    fn values(&self, phi: &[f64], out: &mut [f64]) -> Result<(), String> {
        let started = Instant::now();
        self.inner.values(phi, out)?;
        self.timed.record(|t| &mut t.values, started);
        Ok(())
    }

    fn weighted_gradient(&self, weights: &[f64], out: &mut [f64]) -> Result<(), String> {
        let started = Instant::now();
        self.inner.weighted_gradient(weights, out)?;
        self.timed.record(|t| &mut t.gradient, started);
        Ok(())
    }
}

struct Options {
    size: usize,
    rounds: usize,
    backends: Vec<Backend>,
    metric: Metric,
}

fn options() -> Result<Options, String> {
    let mut o = Options { size: 256, rounds: 3, backends: vec![Backend::Cpu, Backend::Gpu], metric: Metric::Mi };
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        let mut value = |name: &str| args.next().ok_or(format!("{name} needs a value"));
        match a.as_str() {
            "--size" => o.size = value("--size")?.parse().map_err(|e| format!("--size: {e}"))?,
            "--rounds" => o.rounds = value("--rounds")?.parse().map_err(|e| format!("--rounds: {e}"))?,
            "--metric" => o.metric = value("--metric")?.parse().map_err(|e| format!("--metric: {e}"))?,
            "--backends" => {
                o.backends = value("--backends")?
                    .split(',')
                    .map(|b| match b {
                        "cpu" => Ok(Backend::Cpu),
                        "gpu" => Ok(Backend::Gpu),
                        other => Err(format!("--backends: {other} (cpu or gpu)")),
                    })
                    .collect::<Result<_, _>>()?;
            }
            "--bench" => {}
            other => return Err(format!("unknown option {other}")),
        }
    }
    if o.size < 16 || o.rounds == 0 || o.backends.is_empty() {
        return Err("--size ≥ 16, --rounds ≥ 1 and at least one backend".into());
    }
    Ok(o)
}

/// The fixed and moving volumes (module docs) on `n`³ voxels.
fn pair(n: usize) -> (Volume, Volume) {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let t1 = warpbench_io::open(root.join("tests/data/nifti/ch2.nii.gz")).expect("the Colin27 fixture");
    let image = Image::<Fixed>::from_volume(&t1, Parallelism::Rayon).expect("an image");
    // n³ voxels spanning the fixture's voxel centres.
    let scale: [f64; 3] = std::array::from_fn(|a| (t1.dims[a] - 1) as f64 / (n - 1) as f64);
    let lps_from_index: Transform<Lps, Index> =
        t1.lps_from_index * Transform::<Index, Index>::from_scale_translation(scale, [0.0; 3]);
    let point = |o: usize| {
        let p = lps_from_index.apply_point(warpbench_io::geometry::Point3::new(
            (o % n) as f64,
            ((o / n) % n) as f64,
            (o / (n * n)) as f64,
        ));
        p.coords()
    };
    let fixed: Vec<f32> = (0..n * n * n).map(|o| image.sample(point(o)).unwrap_or(0.0) as f32).collect();
    let shifted: Vec<f64> = (0..n * n * n)
        .map(|o| {
            let x = point(o);
            image.sample([x[0] + SHIFT_MM[0], x[1] + SHIFT_MM[1], x[2] + SHIFT_MM[2]]).unwrap_or(0.0)
        })
        .collect();
    let (lo, hi) = shifted.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &v| (l.min(v), h.max(v)));
    let moving: Vec<f32> = shifted
        .iter()
        .map(|&v| {
            let t = (v - lo) / (hi - lo);
            (1000.0 * (1.0 - t).powf(1.5) + 50.0 * t) as f32
        })
        .collect();
    let volume = |name: &str, values: Vec<f32>| {
        Volume::new(
            Path::new(name),
            [n; 3],
            VoxelData::F32(values),
            lps_from_index,
            GeometrySource::NiftiSform { code: 1 },
        )
        .expect("a volume")
    };
    (volume("fixed", fixed), volume("moving", moving))
}

struct Run {
    seconds: f64,
    similarity: f64,
    error_mm: f64,
    levels: Vec<LevelReport>,
    /// With a device: the time in its calls.
    device: Option<DeviceTimes>,
}

impl Run {
    /// Where the time went: each level, and with a device its calls against the CPU's share.
    fn breakdown(&self) -> Vec<String> {
        let mut lines: Vec<String> = self
            .levels
            .iter()
            .map(|l| {
                format!(
                    "    shrink {}: {} control points, {} samples, {} evaluations, {:.3} s",
                    l.shrink, l.control_points, l.samples, l.evaluations, l.seconds
                )
            })
            .collect();
        if let Some(d) = self.device {
            let call = |name: &str, c: CallTime| {
                let each = if c.calls == 0 { 0.0 } else { c.total.as_secs_f64() * 1e3 / c.calls as f64 };
                format!("{name} {:.3} s ({} × {each:.2} ms)", c.total.as_secs_f64(), c.calls)
            };
            let on_device = (d.prepare.total + d.values.total + d.gradient.total).as_secs_f64();
            lines.push(format!(
                "    device calls {on_device:.3} s: {}, {}, {}; the CPU's share {:.3} s",
                call("upload", d.prepare),
                call("values", d.values),
                call("gradient", d.gradient),
                self.seconds - on_device
            ));
        }
        lines
    }
}

fn run(fixed: &Volume, moving: &Volume, metric: Metric, device: Option<&dyn SampleDevice>) -> Run {
    let method = Method::from_name("tps").expect("tps");
    let inputs = RefineInputs {
        fixed,
        moving,
        names: ["fixed", "moving"],
        pairs: &[],
        origin: "no landmarks",
        method: &method,
        fixed_mask: None,
        moving_mask: None,
    };
    let timed = device.map(|inner| Timed { inner, times: Mutex::new(DeviceTimes::default()) });
    let refinement = refine(
        inputs,
        Layers::new(None, None),
        &RegisterParams { similarity: metric.similarity(), ..RegisterParams::default() },
        timed.as_ref().map(|t| t as &dyn SampleDevice),
        &mut |_| ControlFlow::Continue(()),
    )
    .expect("the registration");
    let u = refinement.pullback();
    let image = Image::<Fixed>::from_volume(fixed, Parallelism::Rayon).expect("an image");
    let largest = image.values().iter().fold(0.0f32, |m, &v| m.max(v));
    let (mut sum, mut count) = (0.0, 0usize);
    let n = fixed.dims[0];
    for k in 0..16 {
        for j in 0..16 {
            for i in 0..16 {
                let ijk = [i, j, k].map(|c| (c * (n - 1)) / 15);
                if image.at(ijk[0], ijk[1], ijk[2]) < 0.2 * largest {
                    continue;
                }
                let x = image.voxel_point(ijk[0], ijk[1], ijk[2]);
                let y = u.apply_raw(x);
                sum += (0..3).map(|a| (y[a] - (x[a] - SHIFT_MM[a])).powi(2)).sum::<f64>().sqrt();
                count += 1;
            }
        }
    }
    Run {
        seconds: refinement.register_s,
        similarity: refinement.registration.levels.last().map_or(0.0, |l| l.similarity),
        error_mm: sum / count.max(1) as f64,
        levels: refinement.registration.levels.clone(),
        device: timed.map(|t| t.times.into_inner().unwrap_or_else(std::sync::PoisonError::into_inner)),
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    if !std::env::args().any(|a| a == "--bench") {
        return;
    }
    let o = match options() {
        Ok(o) => o,
        Err(e) => {
            eprintln!("register bench: {e}");
            std::process::exit(2);
        }
    };
    let (fixed, moving) = pair(o.size);
    let ctx = o.backends.contains(&Backend::Gpu).then(|| GpuContext::headless().expect("a GPU adapter"));
    let gpu = ctx.as_ref().map(|c| GpuSamples::new(c).expect("the GPU pass"));
    println!(
        "register bench: {n}³ pair (Colin27 against a remapped copy shifted by {SHIFT_MM:?} mm), --metric {}, \
         defaults, from the identity; {} CPU threads{}",
        o.metric,
        rayon::current_num_threads(),
        ctx.as_ref().map_or(String::new(), |c| format!("; GPU {}", c.describe())),
        n = o.size
    );
    let mut seconds: Vec<(Backend, Vec<f64>)> = o.backends.iter().map(|&b| (b, Vec::new())).collect();
    for round in 0..o.rounds {
        // Alternating: each round runs every backend once.
        for (backend, times) in &mut seconds {
            let device = match backend {
                Backend::Cpu => None,
                Backend::Gpu => gpu.as_ref().map(|g| g as &dyn SampleDevice),
            };
            let r = run(&fixed, &moving, o.metric, device);
            println!(
                "  round {round} {backend:?}: {:.3} s, {} {:.4}, mean error {:.3} mm",
                r.seconds,
                o.metric.measure(),
                r.similarity,
                r.error_mm
            );
            if round + 1 == o.rounds {
                // The last round's split, so that a missed target shows what bounds it.
                for line in r.breakdown() {
                    println!("{line}");
                }
            }
            times.push(r.seconds);
        }
    }
    let medians: Vec<(Backend, f64)> = seconds.into_iter().map(|(b, t)| (b, median(t))).collect();
    for (b, m) in &medians {
        println!("register {b:?}: median {m:.3} s over {} rounds", o.rounds);
    }
    let find = |b| medians.iter().find(|(x, _)| *x == b).map(|(_, m)| *m);
    if let (Some(cpu), Some(gpu)) = (find(Backend::Cpu), find(Backend::Gpu)) {
        println!("register GPU/CPU: {:.2}× the CPU's time", gpu / cpu);
    }
    if let Some(g) = find(Backend::Gpu) {
        let verdict = if g <= 1.0 { "met" } else { "missed" };
        println!("target: a {}³ refinement in ≤ 1 s on a real GPU: {g:.3} s, {verdict}", o.size);
    }
}
