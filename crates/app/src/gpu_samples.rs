//! The GPU as the reader of a registration's samples ([`warpbench_solver::register::device`]): the displaced values
//! and the weighted gradient of each mutual-information level run in [`warpbench_gpu::ffd_samples`], while the
//! histogram and the optimiser stay on the CPU. `warpbench register --backend` and the window's refinement choose it
//! with [`Backend`]'s rule.

use warpbench_gpu::GpuContext;
use warpbench_gpu::ffd_samples::{FfdImage, FfdLevel, FfdSamplePoint, FfdSamplesPass, PreparedFfd};
use warpbench_solver::register::Similarity;
use warpbench_solver::register::device::{DeviceLevel, DeviceSamples, SampleDevice};

use crate::warp::Backend;

/// The registration's samples on one GPU.
#[derive(Debug)]
pub struct GpuSamples<'c> {
    ctx: &'c GpuContext,
    pass: FfdSamplesPass,
}

impl<'c> GpuSamples<'c> {
    /// The pipelines on `ctx`.
    ///
    /// # Errors
    /// The device's, naming it, when it lacks what the pass needs.
    pub fn new(ctx: &'c GpuContext) -> Result<Self, String> {
        let pass = FfdSamplesPass::new(ctx).map_err(|e| format!("{}: {e}", ctx.describe()))?;
        Ok(Self { ctx, pass })
    }
}

impl SampleDevice for GpuSamples<'_> {
    fn describe(&self) -> String {
        self.ctx.describe()
    }

    fn prepare<'d>(&'d self, level: &DeviceLevel<'_>) -> Result<Box<dyn DeviceSamples + 'd>, String> {
        let a = level.image.index_from_space_linear();
        let samples: Vec<FfdSamplePoint> = level
            .samples
            .iter()
            .map(|s| FfdSamplePoint { index: s.index, first: s.first, weights: s.weights })
            .collect();
        let ffd = FfdLevel {
            image: FfdImage {
                dims: level.image.dims(),
                values: level.image.values(),
                index_from_mm: std::array::from_fn(|r| std::array::from_fn(|c| a[(r, c)])),
            },
            lattice_dims: level.lattice_dims,
            samples: &samples,
        };
        let prepared = self.pass.prepare(self.ctx, &ffd).map_err(|e| self.failed(&e))?;
        Ok(Box::new(GpuLevel { device: self, prepared }))
    }
}

impl GpuSamples<'_> {
    fn failed(&self, e: &warpbench_gpu::GpuError) -> String {
        format!("the GPU ({}) failed: {e}", self.ctx.describe())
    }
}

/// One level on the GPU.
struct GpuLevel<'d> {
    device: &'d GpuSamples<'d>,
    prepared: PreparedFfd,
}

impl DeviceSamples for GpuLevel<'_> {
    fn values(&self, phi: &[f64], out: &mut [f64]) -> Result<(), String> {
        self.prepared.values(self.device.ctx, phi, out).map_err(|e| self.device.failed(&e))
    }

    fn weighted_gradient(&self, weights: &[f64], out: &mut [f64]) -> Result<(), String> {
        self.prepared.weighted_gradient(self.device.ctx, weights, out).map_err(|e| self.device.failed(&e))
    }
}

/// Where a registration reads its samples.
#[derive(Debug)]
pub enum SampleDeviceChoice {
    /// On the CPU's threads; `note` says why when a GPU was looked for and not taken.
    Cpu { note: Option<String> },
    /// On this GPU.
    Gpu(Box<GpuContext>),
}

/// Whether a GPU reads the samples of `similarity` (mutual information and local correlation; normalised gradient
/// fields run on the CPU only).
#[must_use]
pub fn reads(similarity: Similarity) -> bool {
    match similarity {
        Similarity::Mi | Similarity::Lncc => true,
        Similarity::Ngf => false,
    }
}

/// [`Backend`]'s rule for a registration with `similarity`: `cpu` never makes a device; `gpu` makes one or fails;
/// `auto` takes a hardware GPU for mutual information and local correlation, and the CPU otherwise (a CPU driver such
/// as lavapipe runs the same passes on the same cores, more slowly; normalised gradient fields run on the CPU only).
///
/// # Errors
/// With `gpu`: no adapter, or normalised gradient fields (which have no GPU path).
pub fn choose(backend: Backend, similarity: Similarity) -> Result<SampleDeviceChoice, String> {
    match (backend, reads(similarity)) {
        (Backend::Cpu, _) | (Backend::Auto, false) => Ok(SampleDeviceChoice::Cpu { note: None }),
        (Backend::Gpu, false) => {
            Err("--backend gpu: the GPU reads the samples of --metric mi and lncc only; use --backend cpu or auto"
                .into())
        }
        (Backend::Gpu, true) => {
            GpuContext::headless().map(|ctx| SampleDeviceChoice::Gpu(Box::new(ctx))).map_err(|e| e.to_string())
        }
        (Backend::Auto, true) => Ok(match GpuContext::headless() {
            Err(e) => SampleDeviceChoice::Cpu { note: Some(e.to_string()) },
            Ok(ctx) if ctx.is_cpu_driver() => {
                SampleDeviceChoice::Cpu { note: Some(format!("{} is a CPU driver", ctx.describe())) }
            }
            Ok(ctx) => SampleDeviceChoice::Gpu(Box::new(ctx)),
        }),
    }
}
