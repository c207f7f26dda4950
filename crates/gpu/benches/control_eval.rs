//! Control-texture update benchmark: the cost of re-evaluating a pull-back into a 64³ control texture on
//! the GPU ([`ControlEvalPass`]), as a landmark drag does, for
//!
//! 1. a TPS pull-back of N = 100 landmarks,
//! 2. a TPS pull-back of N = 1000 landmarks,
//! 3. a hierarchical B-spline pull-back (the solver's default parameters: 4 levels, a 35³ lattice) of 100 landmarks,
//!
//! all fitted by `warpbench_solver` to landmarks in a 200 mm box centred at LPS (−20, 150, 400) mm, displaced by a
//! smooth 5–10 mm field. Each case is timed two ways, the target texture reused every time:
//!
//! - **update**: record the dispatch and copies, submit, wait for the GPU (no readback);
//! - **update + bounds**: the same plus the 32-byte readback of the displacement bounds
//!   ([`ControlEvalPass::evaluate_tps`], what gives a complete `ControlInfo`).
//!
//! and, for comparison, the CPU path to the same texture: sampling on the CPU (`warpbench_solver::control`, rayon),
//! then the upload.
//! Figures are wall-clock medians (and minima) after warm-up; warm-up also compiles the pipelines.
//!
//! ```sh
//! cargo bench -p warpbench-gpu --bench control_eval
//! cargo bench -p warpbench-gpu --bench control_eval -- --iterations 50 --n 64
//! ```
//!
//! Options: `--iterations N` (timed GPU updates per case, ≥ 20), `--n N` (control texture edge). It only runs when
//! `--bench` is among the arguments (as `cargo bench` passes), so `cargo test --benches` does not run it.

use std::time::{Duration, Instant};

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use warpbench_gpu::control_eval::PendingControl;
use warpbench_gpu::{
    BSplineDesc, ControlDesc, ControlEvalPass, ControlGridDesc, GpuContext, GpuControlTexture, LatticeDesc,
    PreparedControl, TpsDesc,
};
use warpbench_io::geometry::Point3;
use warpbench_solver::bspline::{BSplineParams, HierarchicalBSpline};
use warpbench_solver::control::{ControlGrid, ControlTexture};
use warpbench_solver::tps::{self, Tps};
use warpbench_solver::{Aabb, Fixed, Moving, Parallelism};

const CENTRE_LPS: [f64; 3] = [-20.0, 150.0, 400.0];
const HALF_BOX_MM: f64 = 100.0;
/// Timed CPU-path repetitions (it is slow; only for comparison).
const CPU_ITERATIONS: usize = 5;

/// `n` landmark pairs: fixed points uniform in the box, moving = fixed + a smooth 5–10 mm field + 0.5 mm jitter.
fn landmarks(n: usize, seed: u64) -> (Vec<Point3<Moving>>, Vec<Point3<Fixed>>) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut moving = Vec::with_capacity(n);
    let mut fixed = Vec::with_capacity(n);
    for _ in 0..n {
        let q: [f64; 3] = std::array::from_fn(|a| CENTRE_LPS[a] + rng.random_range(-HALF_BOX_MM..HALF_BOX_MM));
        let l = [q[0] - CENTRE_LPS[0], q[1] - CENTRE_LPS[1], q[2] - CENTRE_LPS[2]];
        let d = [6.0 + 2.0 * (l[1] / 30.0).sin(), -5.0 + 3.0 * (l[2] / 40.0).cos(), 7.0 + 2.0 * (l[0] / 35.0).sin()];
        let p: [f64; 3] = std::array::from_fn(|a| q[a] + d[a] + rng.random_range(-0.5..0.5));
        fixed.push(Point3::from_array(q));
        moving.push(Point3::from_array(p));
    }
    (moving, fixed)
}

fn domain() -> Aabb<Fixed> {
    let c = CENTRE_LPS;
    Aabb::new(
        Point3::new(c[0] - HALF_BOX_MM, c[1] - HALF_BOX_MM, c[2] - HALF_BOX_MM),
        Point3::new(c[0] + HALF_BOX_MM, c[1] + HALF_BOX_MM, c[2] + HALF_BOX_MM),
    )
}

/// A fitted warp as the plain data the pass takes.
enum Case {
    Tps { tps: Tps<Moving, Fixed>, centres: Vec<[f64; 3]>, weights: Vec<[f64; 3]> },
    BSpline { spline: HierarchicalBSpline<Moving, Fixed> },
}

impl Case {
    fn tps(n: usize) -> Self {
        let (moving, fixed) = landmarks(n, 7 + n as u64);
        let tps = tps::fit_pullback(&moving, &fixed, 0.0).expect("TPS fit");
        let centres = tps.centres().iter().map(Point3::coords).collect();
        let weights = tps.weights();
        Self::Tps { tps, centres, weights }
    }

    fn bspline(n: usize) -> Self {
        let (moving, fixed) = landmarks(n, 11);
        let spline = HierarchicalBSpline::fit_pullback(&moving, &fixed, domain(), &BSplineParams::default())
            .expect("B-spline fit");
        Self::BSpline { spline }
    }

    fn name(&self) -> String {
        match self {
            Self::Tps { centres, .. } => format!("TPS N = {}", centres.len()),
            Self::BSpline { spline } => format!("B-spline {:?} lattice", spline.lattice().dims()),
        }
    }

    fn encode(
        &self,
        ctx: &GpuContext,
        pass: &ControlEvalPass,
        encoder: &mut wgpu::CommandEncoder,
        grid: &ControlGridDesc,
        target: Option<GpuControlTexture>,
    ) -> PendingControl {
        match self {
            Self::Tps { tps, centres, weights } => {
                let a = tps.linear();
                let desc = TpsDesc {
                    centres_ref: centres,
                    weights,
                    linear: std::array::from_fn(|r| std::array::from_fn(|c| a[(r, c)])),
                    translation: tps.translation(),
                };
                pass.encode_tps(ctx, encoder, &desc, grid, target).expect("encode TPS")
            }
            Self::BSpline { spline } => {
                let l = spline.lattice();
                let lattice = LatticeDesc {
                    cells: l.cells(),
                    min_mm: l.min_mm(),
                    max_mm: l.max_mm(),
                    coefficients: l.coefficients(),
                };
                let desc = BSplineDesc { lattices: &[lattice] };
                pass.encode_bspline(ctx, encoder, &desc, grid, target).expect("encode B-spline")
            }
        }
    }

    /// The CPU path to the same texture: sample on the CPU (rayon), prepare, upload, wait.
    fn cpu_update(&self, ctx: &GpuContext, grid: ControlGrid) -> GpuControlTexture {
        let sampled = match self {
            Self::Tps { tps, .. } => ControlTexture::sample(tps, grid),
            Self::BSpline { spline } => {
                ControlTexture::sample_bspline(spline, grid, Parallelism::Rayon).expect("sample B-spline")
            }
        };
        let (min, max) = (grid.domain.min.coords(), grid.domain.max.coords());
        let desc = ControlDesc { dims: grid.dims, texels: sampled.as_f32s(), box_min_ref: min, box_max_ref: max };
        let prepared = PreparedControl::prepare(&desc, ctx.capabilities.float32_filterable).expect("prepare");
        let texture = GpuControlTexture::upload(ctx, &prepared);
        ctx.wait_idle().expect("wait");
        texture
    }
}

fn median_and_min(mut times: Vec<Duration>) -> (f64, f64) {
    times.sort();
    let ms = |d: Duration| d.as_secs_f64() * 1e3;
    (ms(times[times.len() / 2]), ms(times[0]))
}

fn options() -> Result<(usize, usize), String> {
    let (mut iterations, mut n) = (25, 64);
    let args: Vec<String> = std::env::args().skip(1).collect();
    let mut it = args.iter();
    while let Some(a) = it.next() {
        let mut value = || it.next().ok_or_else(|| format!("{a} needs a value"));
        match a.as_str() {
            "--iterations" => iterations = value()?.parse().map_err(|e| format!("--iterations: {e}"))?,
            "--n" => n = value()?.parse().map_err(|e| format!("--n: {e}"))?,
            _ => {} // --bench and whatever else cargo passes
        }
    }
    Ok((iterations.max(20), n.clamp(2, 256)))
}

fn main() {
    if !std::env::args().any(|a| a == "--bench") {
        return;
    }
    let (iterations, n) = match options() {
        Ok(o) => o,
        Err(e) => {
            eprintln!("control_eval bench: {e}");
            std::process::exit(2);
        }
    };
    let ctx = GpuContext::headless().expect("GPU context");
    let pass = ControlEvalPass::new(&ctx).expect("control eval pass");
    println!("adapter: {} {:?}", ctx.describe(), ctx.capabilities);
    let dom = domain();
    let grid = ControlGridDesc::cube(n, dom.min.coords(), dom.max.coords());
    let solver_grid = ControlGrid::cube(n, dom).expect("grid");
    println!(
        "control texture {n}³ over a {} mm box at LPS {CENTRE_LPS:?}; median (min) of {iterations} GPU updates, \
         {CPU_ITERATIONS} CPU updates",
        2.0 * HALF_BOX_MM
    );
    println!("{:<28} {:>22} {:>22} {:>22}", "case", "update ms", "update + bounds ms", "CPU sample + upload ms");

    let t = Instant::now();
    let cases = [Case::tps(100), Case::tps(1000), Case::bspline(100)];
    eprintln!("fits: {:.1} s", t.elapsed().as_secs_f64());
    for case in &cases {
        // Warm-up (pipeline compilation, staging buffer, first texture), and the bounds of this warp.
        let mut target = None;
        for _ in 0..3 {
            let mut encoder = ctx.device.create_command_encoder(&wgpu::CommandEncoderDescriptor::default());
            let pending = case.encode(&ctx, &pass, &mut encoder, &grid, target.take());
            ctx.queue.submit([encoder.finish()]);
            target = Some(pending.resolve(&ctx).expect("resolve"));
        }
        let info = target.as_ref().expect("warm-up texture").info;

        let mut update = Vec::with_capacity(iterations);
        for _ in 0..iterations {
            let t = Instant::now();
            let mut encoder = ctx.device.create_command_encoder(&wgpu::CommandEncoderDescriptor::default());
            let pending = case.encode(&ctx, &pass, &mut encoder, &grid, target.take());
            ctx.queue.submit([encoder.finish()]);
            ctx.wait_idle().expect("wait");
            update.push(t.elapsed());
            // Same warp every time: the bounds read back in the warm-up still hold.
            let (texture, view) = pending.into_texture();
            target = Some(GpuControlTexture { info, texture, view });
        }
        let mut with_bounds = Vec::with_capacity(iterations);
        for _ in 0..iterations {
            let t = Instant::now();
            let mut encoder = ctx.device.create_command_encoder(&wgpu::CommandEncoderDescriptor::default());
            let pending = case.encode(&ctx, &pass, &mut encoder, &grid, target.take());
            ctx.queue.submit([encoder.finish()]);
            let texture = pending.resolve(&ctx).expect("resolve");
            with_bounds.push(t.elapsed());
            assert_eq!(texture.info, info, "re-evaluating one warp gives the same bounds");
            target = Some(texture);
        }
        let cpu: Vec<Duration> = (0..CPU_ITERATIONS)
            .map(|_| {
                let t = Instant::now();
                drop(case.cpu_update(&ctx, solver_grid));
                t.elapsed()
            })
            .collect();
        let fmt = |(median, min): (f64, f64)| format!("{median:.3} ({min:.3})");
        println!(
            "{:<28} {:>22} {:>22} {:>22}",
            case.name(),
            fmt(median_and_min(update)),
            fmt(median_and_min(with_bounds)),
            fmt(median_and_min(cpu))
        );
    }
    ctx.check_errors().expect("wgpu errors");
}
