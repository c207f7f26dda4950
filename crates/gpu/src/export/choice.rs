//! Which path an automatic export takes ([`choose_path`]): the CPU ([`crate::export::export_cpu`]) or the GPU
//! ([`crate::export::ExportPass`]), whichever is expected to finish first for this request on this machine, so that
//! an automatic choice (`warpbench warp --backend auto`) does not fall behind the CPU.
//!
//! # The rule
//!
//! 1. Without a hardware GPU → the CPU. A CPU driver (lavapipe, llvmpipe, WARP) runs the same arithmetic on the
//!    same cores as the CPU path, through a shader compiler and extra copies: always slower.
//! 2. Samples that f32 does not hold exactly → the CPU (the GPU path refuses them).
//! 3. Otherwise the GPU when its estimate is below the CPU's, where, for V output voxels and T rayon threads,
//!
//!    CPU ms = V · (k + p) / T, with k and p the CPU path's cost per voxel and thread of the kernel and the
//!    pull-back ([`CPU_KERNEL_NS`], [`CPU_PULLBACK_NS`], [`CPU_TPS_CENTRE_NS`]);
//!
//!    GPU ms = [`GPU_FIXED_MS`] + (source + output bytes) / [`GPU_LINK_BYTES_PER_NS`] + V · [`GPU_VOXEL_NS`]
//!    + V · N · [`GPU_TPS_CENTRE_NS`] for an exact TPS of N centres.
//!
//! The fixed cost (a device of its own, the pipeline's compilation, the first submission) is what makes small
//! exports faster on the CPU: an export the CPU path finishes in under [`GPU_FIXED_MS`] never goes to a GPU (on one
//! thread about 134³ voxels for Catmull-Rom through a control texture, 205³ for trilinear). Above it, the GPU wins
//! where the CPU's cost per voxel is high (Catmull-Rom, an exact TPS with many centres, few threads) and the CPU
//! keeps the cheap kernels on many threads, where both are bound by moving the bytes.
//!
//! The CPU figures are the export bench's CPU time per voxel and thread (`docs/benchmarks.md`), the smaller of two
//! machines' for each term: the 2-vCPU EPYC VM (2026-11-22, 256³, every row at full size) and the NVIDIA H200
//! machine's 16-thread host (2026-12-04, 512³). T is the thread count here and perfect scaling is assumed, so a
//! slower or busier CPU makes the rule pick the CPU more often than it should, never less: the rule errs towards
//! the CPU. The GPU figures are deliberately
//! pessimistic estimates (a link of 5 GB/s, a compute rate of a small discrete GPU) until the export bench
//! measures them on a real GPU; the bench prints this rule's estimates beside its measurements.

use super::request::{ExportRequest, Interpolation, PullBack, SampleType};
use crate::device::GpuContext;

/// CPU cost per voxel and thread of each kernel with the identity pull-back, ns: nearest, trilinear, Catmull-Rom.
pub const CPU_KERNEL_NS: [f64; 3] = [12.5, 17.0, 91.0];
/// Extra CPU cost per voxel and thread of a control-texture pull-back, ns.
pub const CPU_PULLBACK_NS: f64 = 12.0;
/// Extra CPU cost per voxel, thread and centre of an exact TPS, ns (the row kernel on an axis-aligned target).
pub const CPU_TPS_CENTRE_NS: f64 = 0.2;
/// A GPU export's fixed cost, ms: a device of its own, the pipeline's compilation, the first submission.
pub const GPU_FIXED_MS: f64 = 250.0;
/// Bytes per ns the upload and the readback move between host and GPU (5 GB/s, copies on the host included).
pub const GPU_LINK_BYTES_PER_NS: f64 = 5.0;
/// GPU cost per voxel of the kernel and pull-back, ns.
pub const GPU_VOXEL_NS: f64 = 0.1;
/// GPU cost per voxel and centre of an exact TPS, ns (≈ 10 flops at 1 Tflop/s).
pub const GPU_TPS_CENTRE_NS: f64 = 0.01;

/// The device an automatic export could use, as far as the choice is concerned.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ExportDevice {
    /// No adapter.
    None,
    /// An adapter that runs on the CPU (lavapipe, llvmpipe, WARP).
    CpuDriver,
    /// A GPU.
    Hardware,
}

impl ExportDevice {
    /// The kind of `ctx`'s adapter.
    #[must_use]
    pub fn of(ctx: &GpuContext) -> Self {
        if ctx.is_cpu_driver() { Self::CpuDriver } else { Self::Hardware }
    }
}

/// Where an export runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ExportPath {
    Cpu,
    Gpu,
}

/// [`choose_path`]'s answer, with the estimates it compared and why.
#[derive(Clone, Debug, PartialEq)]
pub struct PathChoice {
    pub path: ExportPath,
    /// Why, in words (for a note to the user).
    pub reason: String,
    /// The rule's estimate of the CPU path's wall time, ms.
    pub cpu_ms: f64,
    /// The rule's estimate of a hardware GPU's wall time (its fixed cost included), ms.
    pub gpu_ms: f64,
}

/// The rule's estimate of the CPU path's wall time for `request` on `cpu_threads` threads, ms.
#[must_use]
pub fn cpu_estimate_ms(request: &ExportRequest<'_>, cpu_threads: usize) -> f64 {
    let kernel = CPU_KERNEL_NS[match request.interpolation {
        Interpolation::Nearest => 0,
        Interpolation::Trilinear => 1,
        Interpolation::CatmullRom => 2,
    }];
    let pullback = match request.pullback {
        PullBack::Identity => 0.0,
        PullBack::Control(_) => CPU_PULLBACK_NS,
        PullBack::Tps(t) => CPU_TPS_CENTRE_NS * t.centres_ref.len() as f64,
    };
    voxels(request) * (kernel + pullback) / cpu_threads.max(1) as f64 * 1e-6
}

/// The rule's estimate of a hardware GPU's wall time for `request`, its fixed cost included, ms.
#[must_use]
pub fn gpu_estimate_ms(request: &ExportRequest<'_>) -> f64 {
    // Texels travel in the source's type (f64 as f32), the output in its own (f64 as f32).
    let wire = |t: SampleType| t.bytes().min(4) as f64;
    let bytes = request.source.samples.len() as f64 * wire(request.source.samples.sample_type())
        + voxels(request) * wire(request.output_type());
    let centres = match request.pullback {
        PullBack::Tps(t) => t.centres_ref.len() as f64,
        _ => 0.0,
    };
    GPU_FIXED_MS
        + (bytes / GPU_LINK_BYTES_PER_NS + voxels(request) * (GPU_VOXEL_NS + centres * GPU_TPS_CENTRE_NS)) * 1e-6
}

fn voxels(request: &ExportRequest<'_>) -> f64 {
    request.target.dims.iter().map(|&d| d as f64).product()
}

/// Where `request` should run on this machine: `cpu_threads` rayon threads and a GPU of kind `device` (module docs).
/// Calling it with [`ExportDevice::Hardware`] before any device exists tells whether a GPU could pay off at all, so
/// that an export the CPU wins anyway costs no device.
#[must_use]
pub fn choose_path(request: &ExportRequest<'_>, cpu_threads: usize, device: ExportDevice) -> PathChoice {
    let cpu_ms = cpu_estimate_ms(request, cpu_threads);
    let gpu_ms = gpu_estimate_ms(request);
    let choice = |path, reason: String| PathChoice { path, reason, cpu_ms, gpu_ms };
    match device {
        ExportDevice::None => return choice(ExportPath::Cpu, "no GPU adapter".into()),
        ExportDevice::CpuDriver => {
            return choice(ExportPath::Cpu, "the adapter is a CPU driver, slower than the CPU path".into());
        }
        ExportDevice::Hardware => {}
    }
    if !request.source.samples.exact_in_f32() {
        return choice(ExportPath::Cpu, "the samples are not all exact in f32, which the GPU path needs".into());
    }
    let estimates = format!(
        "estimated {cpu_ms:.0} ms on {cpu_threads} CPU threads, {gpu_ms:.0} ms on a GPU ({GPU_FIXED_MS:.0} ms of it \
         fixed)"
    );
    if gpu_ms < cpu_ms {
        choice(ExportPath::Gpu, format!("the GPU is faster here: {estimates}"))
    } else {
        choice(ExportPath::Cpu, format!("the CPU is faster here: {estimates}"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::control::ControlDesc;
    use crate::export::request::{ExportSamples, SourceVolume, TargetGrid};
    use crate::pullback::TpsDesc;

    fn grid(n: usize) -> [[f64; 4]; 4] {
        let mut m = [[0.0; 4]; 4];
        for (a, row) in m.iter_mut().enumerate().take(3) {
            row[a] = 240.0 / n as f64;
        }
        m[3][3] = 1.0;
        m
    }

    /// A request for an n³ i16 source and target (the samples are not read beyond their length and type).
    fn request<'a>(samples: &'a [i16], n: usize, pullback: PullBack<'a>, kernel: Interpolation) -> ExportRequest<'a> {
        let source = SourceVolume { dims: [n; 3], samples: ExportSamples::I16(samples), lps_from_index: grid(n) };
        let target = TargetGrid { dims: [n; 3], lps_from_index: grid(n) };
        ExportRequest { interpolation: kernel, ..ExportRequest::new(source, target, pullback) }
    }

    #[test]
    fn without_a_hardware_gpu_the_cpu_is_chosen_at_any_size() {
        let big = vec![0i16; 256 * 256 * 256];
        let r = request(&big, 256, PullBack::Identity, Interpolation::CatmullRom);
        for device in [ExportDevice::None, ExportDevice::CpuDriver] {
            let choice = choose_path(&r, 1, device);
            assert_eq!(choice.path, ExportPath::Cpu, "{device:?}: {choice:?}");
        }
        // The same request on one thread would take the GPU if there were one.
        assert_eq!(choose_path(&r, 1, ExportDevice::Hardware).path, ExportPath::Gpu);
    }

    #[test]
    fn small_exports_stay_on_the_cpu_large_costly_ones_go_to_the_gpu() {
        let small = vec![0i16; 64 * 64 * 64];
        let texels = vec![0.0f32; 4 * 8 * 8 * 8];
        let control = PullBack::Control(ControlDesc {
            dims: [8; 3],
            texels: &texels,
            box_min_ref: [0.0; 3],
            box_max_ref: [240.0; 3],
        });
        // 64³: even a Catmull-Rom export on one thread (40 ms) is done before a GPU device is ready.
        let r = request(&small, 64, control, Interpolation::CatmullRom);
        let choice = choose_path(&r, 1, ExportDevice::Hardware);
        assert_eq!(choice.path, ExportPath::Cpu, "{choice:?}");
        assert!(choice.cpu_ms < GPU_FIXED_MS && choice.reason.contains("CPU is faster"), "{choice:?}");

        // 512³ (the sizes only; the samples are a stand-in of the right length).
        let big = vec![0i16; 512 * 512 * 512];
        let trilinear = request(&big, 512, control, Interpolation::Trilinear);
        // Trilinear through a control texture is bound by moving the bytes: 64 threads keep it on the CPU, 4 do not.
        assert_eq!(choose_path(&trilinear, 64, ExportDevice::Hardware).path, ExportPath::Cpu);
        assert_eq!(choose_path(&trilinear, 4, ExportDevice::Hardware).path, ExportPath::Gpu);
        // Catmull-Rom costs the CPU 3.5× more per voxel: the GPU even against 16 threads (the H200 machine's).
        let cubic = request(&big, 512, control, Interpolation::CatmullRom);
        assert_eq!(choose_path(&cubic, 16, ExportDevice::Hardware).path, ExportPath::Gpu);
        // An exact TPS of 100 centres: 16 threads keep it (the CPU's row kernel is cheap per centre), 4 do not.
        let centres = vec![[0.0; 3]; 100];
        let weights = vec![[0.0; 3]; 100];
        let identity = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        let tps = PullBack::Tps(TpsDesc {
            centres_ref: &centres,
            weights: &weights,
            linear: identity,
            translation: [0.0; 3],
        });
        let exact = request(&big, 512, tps, Interpolation::Trilinear);
        assert_eq!(choose_path(&exact, 16, ExportDevice::Hardware).path, ExportPath::Cpu);
        let choice = choose_path(&exact, 4, ExportDevice::Hardware);
        assert_eq!(choice.path, ExportPath::Gpu, "{choice:?}");
        assert!(choice.reason.contains("GPU is faster"), "{choice:?}");
    }

    #[test]
    fn samples_the_gpu_refuses_stay_on_the_cpu() {
        // The rule checks the samples before the sizes: this small export names them.
        let wide = vec![(1 << 24) + 1; 8 * 8 * 8];
        let source = SourceVolume { dims: [8; 3], samples: ExportSamples::I32(&wide), lps_from_index: grid(8) };
        let target = TargetGrid { dims: [8; 3], lps_from_index: grid(8) };
        let r = ExportRequest {
            interpolation: Interpolation::CatmullRom,
            ..ExportRequest::new(source, target, PullBack::Identity)
        };
        let choice = choose_path(&r, 1, ExportDevice::Hardware);
        assert_eq!(choice.path, ExportPath::Cpu, "{choice:?}");
        assert!(choice.reason.contains("exact in f32"), "{choice:?}");
    }
}
