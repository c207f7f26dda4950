//! Refine by intensities in the window (issue 31, item 3): the registration of `warpbench register`
//! ([`crate::register::refine`]) run on a thread of its own on the pair as loaded, from the warp stack under the brush
//! (the starting transform, the displacement field and the landmark fit), keeping the active pairs.
//!
//! Its result becomes the document's displacement field, the layer under the landmark fit: with T₀ the starting
//! transform (the identity without one) and u the registered pull-back, F = T₀⁻¹ ∘ u, so the stack T₀ ∘ F ∘ r ∘ b⁻¹
//! ([`crate::project::stack`]) shows the registration live, the landmark fit r refines on top of it (it is about the
//! identity while the pairs are where the registration kept them) and the brush b stays on top. F is sampled on a grid
//! of at most [`FIELD_MAX_SIDE`] points a side spanning the fixed volume's voxel centres (the registration's control
//! points are [`RegisterParams::grid_mm`] apart, so trilinear interpolation of F loses little), and written as an ITK
//! displacement field (NIfTI `DISPVECT`) in the window's state folder, atomically, before the document names it: undo
//! and sessions keep it by its path.

use std::ops::ControlFlow;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, TryRecvError};
use std::sync::{Arc, Mutex, PoisonError};
use std::thread::JoinHandle;

use warpbench_io::Volume;
use warpbench_io::displacement::{self, FieldDirection, FieldFormat};
use warpbench_io::geometry::{Index, Lps, Transform};
use warpbench_io::landmarks::LandmarkPair;
use warpbench_solver::linear::AffineWarp;
use warpbench_solver::method::Method;
use warpbench_solver::register::RegisterParams;
use warpbench_solver::spaces::{Fixed, Moving};
use warpbench_solver::warp::Warp;

use warpbench_solver::register::device::SampleDevice;

use crate::exit::Failure;
use crate::gpu_samples::GpuSamples;
use crate::project::document::{FitPoints, StartingTransform};
use crate::project::stack::Layers;
use crate::register::{RefineInputs, refine};
use crate::settings::Metric;

/// The refined field's grid has at most this many points along each axis.
pub const FIELD_MAX_SIDE: usize = 128;

/// What a refinement starts from: the pair as loaded and the document's stack under the brush.
#[derive(Clone, Debug)]
pub struct RefineInput {
    pub fixed: Arc<Volume>,
    pub moving: Arc<Volume>,
    pub pairs: Vec<LandmarkPair>,
    pub method: Method,
    pub start: Option<StartingTransform>,
    pub field: Option<crate::project::field_file::FieldFile>,
    /// Where to write the refined field.
    pub out: PathBuf,
    /// The window's GPU, when it is a hardware one: the samples of mutual information and local correlation are read
    /// there ([`crate::gpu_samples`]; `register --backend auto`'s rule). A CPU driver is not passed.
    pub gpu: Option<Arc<warpbench_gpu::GpuContext>>,
    /// How the registration runs: the solver's defaults with the document's Match by as its measure.
    pub params: RegisterParams,
    /// Read the fixed volume only where this mask volume is not 0.
    pub fixed_mask: Option<PathBuf>,
    /// Read the moving volume only where this mask volume is not 0.
    pub moving_mask: Option<PathBuf>,
}

/// A finished refinement: the field to put under the landmarks and what to say about it.
#[derive(Clone, Debug, PartialEq)]
pub struct Refined {
    pub field: PathBuf,
    pub summary: String,
}

/// The refinement's result and the pairs it was made on, so the window can offer to run it again once they moved.
#[derive(Clone, Debug, PartialEq)]
pub struct RefinedOn {
    pub refined: Refined,
    pub pairs: FitPoints,
}

/// A refinement being computed.
#[derive(Debug)]
pub struct IntensityJob {
    done: Receiver<Result<Refined, String>>,
    /// The fraction done, as f64 bits.
    fraction: Arc<AtomicU64>,
    cancel: Arc<AtomicBool>,
    thread: Mutex<Option<JoinHandle<()>>>,
}

impl IntensityJob {
    /// Starts refining on a new thread; `wake` is called as the work advances and when it is done.
    ///
    /// # Errors
    /// When the thread cannot be started.
    pub fn start(input: RefineInput, wake: impl Fn() + Send + 'static) -> std::io::Result<Self> {
        let (send, done) = std::sync::mpsc::channel();
        let fraction = Arc::new(AtomicU64::new(0f64.to_bits()));
        let cancel = Arc::new(AtomicBool::new(false));
        let (f, c) = (Arc::clone(&fraction), Arc::clone(&cancel));
        let thread = std::thread::Builder::new().name("refine-by-intensities".into()).spawn(move || {
            let mut last = 0.0;
            let result = refine_pair(&input, &mut |done| {
                // A repaint per percent is enough for the bar.
                if done - last >= 0.01 || done >= 1.0 {
                    last = done;
                    f.store(done.to_bits(), Ordering::Relaxed);
                    wake();
                }
                !c.load(Ordering::Relaxed)
            });
            // The receiver is gone when the window closed meanwhile: nothing to hand back.
            if send.send(result).is_ok() {
                wake();
            }
        })?;
        Ok(Self { done, fraction, cancel, thread: Mutex::new(Some(thread)) })
    }

    /// The fraction done, 0..1.
    #[must_use]
    pub fn fraction(&self) -> f32 {
        f64::from_bits(self.fraction.load(Ordering::Relaxed)) as f32
    }

    /// Asks the work to stop; its result is then an error that says so.
    pub fn cancel(&self) {
        self.cancel.store(true, Ordering::Relaxed);
    }

    /// The result once it is there; an error when the thread ended without one (it panicked).
    #[must_use]
    pub fn poll(&self) -> Option<Result<Refined, String>> {
        match self.done.try_recv() {
            Ok(result) => Some(result),
            Err(TryRecvError::Empty) => None,
            Err(TryRecvError::Disconnected) => Some(Err("Refine by intensities stopped (a bug): try again".into())),
        }
    }
}

impl Drop for IntensityJob {
    /// Stops the work and waits for its thread, so that nothing of it runs after its window closed.
    fn drop(&mut self) {
        self.cancel();
        if let Some(thread) = self.thread.lock().unwrap_or_else(PoisonError::into_inner).take() {
            let _ = thread.join();
        }
    }
}

/// x ↦ T₀⁻¹(u(x)): the registered pull-back seen under the starting transform (module docs).
struct UnderStart<'a> {
    pullback: &'a dyn Warp<Moving, Fixed>,
    start_inverse: Option<AffineWarp<Fixed, Moving>>,
}

impl Warp<Moving, Fixed> for UnderStart<'_> {
    fn apply_raw(&self, x: [f64; 3]) -> [f64; 3] {
        let u = self.pullback.apply_raw(x);
        self.start_inverse.as_ref().map_or(u, |t| t.apply_raw(u))
    }
}

/// The grid of the refined field: at most [`FIELD_MAX_SIDE`] points a side, spanning `fixed`'s voxel centres.
fn field_grid(fixed: &Volume) -> ([usize; 3], Transform<Lps, Index>) {
    let dims = fixed.dims.map(|n| n.clamp(2, FIELD_MAX_SIDE));
    let scale: [f64; 3] = std::array::from_fn(|a| (fixed.dims[a].max(2) - 1) as f64 / (dims[a] - 1) as f64);
    let index_from_grid: Transform<Index, Index> = Transform::from_scale_translation(scale, [0.0; 3]);
    (dims, fixed.lps_from_index * index_from_grid)
}

/// Registers the pair of `input` and writes the field to put under the landmarks (module docs). `progress(done)`
/// hears the fraction done; `false` cancels.
///
/// # Errors
/// The registration's refusals and the write's, in the window's words.
pub fn refine_pair(input: &RefineInput, progress: &mut dyn FnMut(f64) -> bool) -> Result<Refined, String> {
    let start = input.start.as_ref().map(StartingTransform::start).transpose().map_err(|e| format!("{e:#}"))?;
    let field = match &input.field {
        Some(file) => Some(Arc::new(file.layer().map_err(|e| format!("{e:#}"))?)),
        None => None,
    };
    let read_mask = |mask: &Option<PathBuf>, side: &str| match mask {
        Some(path) => warpbench_io::open(path)
            .map(|v| Some((v, path.display().to_string())))
            .map_err(|e| format!("Refine by intensities: the {side} mask: {e}")),
        None => Ok(None),
    };
    let masks = [read_mask(&input.fixed_mask, "fixed")?, read_mask(&input.moving_mask, "moving")?];
    let start_inverse = start.as_ref().map(|s| *s.fixed_from_moving());
    let layers = Layers { start, field, brush: None };
    let inputs = RefineInputs {
        fixed: &input.fixed,
        moving: &input.moving,
        names: ["the fixed volume", "the moving volume"],
        pairs: &input.pairs,
        origin: "the landmark table",
        method: &input.method,
        fixed_mask: masks[0].as_ref().map(|(volume, name)| (volume, name.as_str())),
        moving_mask: masks[1].as_ref().map(|(volume, name)| (volume, name.as_str())),
    };
    let params = &input.params;
    // A GPU whose pass cannot be made, or a measure it does not read, leaves the work on the CPU, as `--backend auto`
    // does.
    let gpu = input
        .gpu
        .as_deref()
        .filter(|_| crate::gpu_samples::reads(params.similarity))
        .and_then(|ctx| GpuSamples::new(ctx).ok());
    let device = gpu.as_ref().map(|g| g as &dyn SampleDevice);
    let on = if gpu.is_some() { "on the GPU" } else { "on the CPU" };
    let refinement = refine(inputs, layers, params, device, &mut |p| {
        if progress(0.95 * p.fraction()) { ControlFlow::Continue(()) } else { ControlFlow::Break(()) }
    })
    .map_err(|e| match e {
        Failure::Cancelled(_) => "Refine by intensities: cancelled; the warp is as it was".to_owned(),
        e => format!("Refine by intensities: {:#}", e.error()),
    })?;
    let pullback = refinement.pullback();
    let under = UnderStart { pullback: &pullback, start_inverse };
    let (dims, lps_from_index) = field_grid(&input.fixed);
    let sampled = crate::field::sample_displacements(&under, dims, &lps_from_index, &mut |_, _| true)
        .filter(|s| s.max_norm_mm.is_some())
        .ok_or("Refine by intensities: the registered warp is not finite somewhere in the fixed volume")?;
    write_field(&input.out, dims, &lps_from_index, &sampled.displacements_lps)?;
    progress(1.0);
    let last = refinement.registration.levels.last();
    let worst = refinement.residuals().iter().map(|r| r.residual_mm).fold(0.0, f64::max);
    let pairs = match refinement.kept.moving.len() {
        0 => "no pairs".to_owned(),
        n => format!("{n} pairs within {worst:.2} mm"),
    };
    let summary = format!(
        "Refined by intensities from {}{}: {} {:.3} to {:.3}, {pairs}, smallest Jacobian determinant {:.2}, {:.1} s \
         {on}",
        refinement.start_name,
        masks_said(input),
        Metric::from(params.similarity).measure(),
        refinement.registration.levels.first().map_or(0.0, |l| l.similarity_start),
        last.map_or(0.0, |l| l.similarity),
        refinement.jacobian.min_det,
        refinement.register_s
    );
    Ok(Refined { field: input.out.clone(), summary })
}

/// How a summary names the masks, e.g. " inside the fixed mask brain.nii.gz"; empty without one.
fn masks_said(input: &RefineInput) -> String {
    [("fixed", &input.fixed_mask), ("moving", &input.moving_mask)]
        .into_iter()
        .filter_map(|(side, mask)| {
            let name = mask.as_deref()?.file_name()?.to_string_lossy().into_owned();
            Some(format!(" inside the {side} mask {name}"))
        })
        .collect::<Vec<_>>()
        .join(" and")
}

/// Writes the field (ITK's NIfTI `DISPVECT`), creating its folder.
fn write_field(
    out: &Path,
    dims: [usize; 3],
    lps_from_index: &Transform<Lps, Index>,
    d: &[[f32; 3]],
) -> Result<(), String> {
    if let Some(dir) = out.parent() {
        std::fs::create_dir_all(dir).map_err(|e| format!("Refine by intensities: {}: {e}", dir.display()))?;
    }
    displacement::write_field_with(out, FieldFormat::Itk, FieldDirection::Pullback, dims, lps_from_index, d)
        .map_err(|e| format!("Refine by intensities: {e}"))
}
