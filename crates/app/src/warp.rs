//! `warpbench warp`: resample the moving volume into the fixed volume's grid (or `--reference`'s) through the
//! landmark warp's pull-back, v′(x) = v(u(x)) with u = moving_from_fixed (as ITK's ResampleImageFilter does with a
//! transform that maps output points to input points), and write a NIfTI with the output grid's geometry, and
//! optionally a DICOM series.
//!
//! The pull-back is sampled into a `--grid`³ control texture over the output grid's box (the renderer's texture,
//! so the file shows what the app shows), or evaluated exactly at every voxel with `--exact` (TPS; affine,
//! similarity and rigid warps are exact through any control texture, because trilinear interpolation reproduces an
//! affine map). The resampling runs on the GPU (`--backend gpu`), on the CPU with rayon (`cpu`), or on the GPU when
//! there is an adapter and the samples fit f32 exactly (`auto`); both give the same result
//! (`warpbench_gpu::export`).

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::anyhow;
use serde::Serialize;
use warpbench_gpu::export::{
    ExportPass, ExportRequest, ExportSamples, ExportedSamples, Interpolation, OutputType, Progress, PullBack,
    SourceVolume, TargetGrid, export_cpu,
};
use warpbench_gpu::{GpuContext, GpuError, TpsDesc};
use warpbench_io::dicom_write::{self, DicomSeriesOptions};
use warpbench_io::volume::{GeometrySource, VoxelData};
use warpbench_io::{Volume, nifti};
use warpbench_solver::method::Method;
use warpbench_solver::spaces::{Fixed, Moving};
use warpbench_solver::tps::Tps;
use warpbench_solver::warp::Warp;

use crate::exit::Failure;
use crate::inputs::{self, LandmarkSource, OutputFile};
use crate::scene;

/// Where the resampling runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Backend {
    /// The GPU when a hardware adapter is found and the samples are exact in f32, else the CPU. A CPU driver
    /// (lavapipe, llvmpipe) is slower than the CPU path and holds the source again in host memory, so it is not
    /// used.
    #[default]
    Auto,
    Cpu,
    Gpu,
}

/// How the pull-back is evaluated.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PullBackMode {
    /// Sampled into an n³ control texture over the output grid's box.
    Grid(usize),
    /// Exact at every voxel (TPS).
    Exact,
}

/// Options of `warpbench warp`.
#[derive(Clone, Debug)]
pub struct WarpOptions {
    pub fixed: PathBuf,
    pub moving: PathBuf,
    pub landmarks: LandmarkSource,
    pub method: String,
    pub stiffness: f64,
    pub levels: Option<usize>,
    pub pullback: PullBackMode,
    pub interpolation: Interpolation,
    pub backend: Backend,
    /// f32 output instead of the moving volume's sample type.
    pub float: bool,
    pub reference: Option<PathBuf>,
    /// The value of output voxels that map outside the moving volume; `None`: −1024 for a CT, else 0.
    pub outside_value: Option<f64>,
    pub out: OutputFile,
    pub out_dicom: Option<PathBuf>,
    pub quiet: bool,
}

/// What `warp` did (`--json`, schema `warpbench-warp/1`).
#[derive(Clone, Debug, Serialize)]
pub struct WarpReport {
    pub schema: &'static str,
    pub out: String,
    pub out_dicom: Option<String>,
    pub dims: [usize; 3],
    pub spacing_mm: [f64; 3],
    pub dtype: &'static str,
    pub method: String,
    pub pairs: usize,
    /// `grid N` or `exact`.
    pub pullback: String,
    pub interpolation: &'static str,
    /// `cpu` or `gpu: <adapter>`.
    pub backend: String,
    pub outside_value: f64,
    /// Wall-clock seconds of each stage.
    pub seconds: WarpSeconds,
}

/// Wall-clock seconds of the stages of `warpbench warp`, for benchmarks: `load` (every input volume), `fit` (the
/// landmarks, the fit and the control texture), `resample` (the export, output allocation included), `write` (the
/// NIfTI, and the DICOM series when asked), and `total` (from the start of loading).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct WarpSeconds {
    pub load: f64,
    pub fit: f64,
    pub resample: f64,
    pub write: f64,
    pub total: f64,
}

fn export_samples(v: &Volume) -> ExportSamples<'_> {
    match &v.data {
        VoxelData::U8(d) => ExportSamples::U8(d),
        VoxelData::I16(d) => ExportSamples::I16(d),
        VoxelData::U16(d) => ExportSamples::U16(d),
        VoxelData::F32(d) => ExportSamples::F32(d),
    }
}

fn voxel_data(samples: ExportedSamples) -> Result<VoxelData, Failure> {
    Ok(match samples {
        ExportedSamples::U8(v) => VoxelData::U8(v),
        ExportedSamples::I16(v) => VoxelData::I16(v),
        ExportedSamples::U16(v) => VoxelData::U16(v),
        ExportedSamples::F32(v) => VoxelData::F32(v),
        other => return Err(Failure::Internal(anyhow!("export returned {:?} samples", other.sample_type()))),
    })
}

/// The pull-back as the export takes it, with its description for the report. `control` holds the sampled texels.
enum FittedPullBack {
    Tps(Tps<Moving, Fixed>),
    Other(Box<dyn Warp<Moving, Fixed>>),
}

impl FittedPullBack {
    fn as_warp(&self) -> &dyn Warp<Moving, Fixed> {
        match self {
            Self::Tps(t) => t,
            Self::Other(w) => w.as_ref(),
        }
    }
}

/// Plain TPS data for the GPU crate.
struct TpsParts {
    centres: Vec<[f64; 3]>,
    weights: Vec<[f64; 3]>,
    linear: [[f64; 3]; 3],
    translation: [f64; 3],
}

impl TpsParts {
    fn new(tps: &Tps<Moving, Fixed>) -> Self {
        let a = tps.linear();
        Self {
            centres: tps.centres().iter().map(warpbench_io::geometry::Point3::coords).collect(),
            weights: tps.weights(),
            linear: std::array::from_fn(|r| std::array::from_fn(|c| a[(r, c)])),
            translation: tps.translation(),
        }
    }

    fn desc(&self) -> TpsDesc<'_> {
        TpsDesc {
            centres_ref: &self.centres,
            weights: &self.weights,
            linear: self.linear,
            translation: self.translation,
        }
    }
}

fn interpolation_name(i: Interpolation) -> &'static str {
    match i {
        Interpolation::Nearest => "nearest",
        Interpolation::Trilinear => "linear",
        Interpolation::CatmullRom => "cubic (Catmull-Rom)",
    }
}

/// Runs `warpbench warp`: loads, fits, resamples, writes (atomically), and reports.
pub fn run(opts: &WarpOptions) -> Result<WarpReport, Failure> {
    let mut input_paths: Vec<&Path> = vec![&opts.fixed, &opts.moving];
    input_paths.extend(opts.landmarks.paths());
    input_paths.extend(opts.reference.as_deref());
    opts.out.check(&input_paths)?;
    if !is_nifti_name(&opts.out.path) {
        return Err(Failure::BadInput(anyhow!("{}: --out must end in .nii or .nii.gz", opts.out.path.display())));
    }
    if let Some(dir) = &opts.out_dicom
        && dir.exists()
        && std::fs::read_dir(dir).map_err(|e| Failure::BadInput(anyhow!("{}: {e}", dir.display())))?.next().is_some()
    {
        return Err(Failure::BadInput(anyhow!("{}: --out-dicom must be a new or empty folder", dir.display())));
    }
    let method = inputs::method_from_args(&opts.method, opts.stiffness, opts.levels)?;
    if opts.pullback == PullBackMode::Exact && matches!(method, Method::BSpline(_)) {
        return Err(Failure::BadInput(anyhow!(
            "--exact evaluates a TPS (or a linear warp) per voxel; use --grid N for the hierarchical B-spline"
        )));
    }

    let start = Instant::now();
    let mut lap = Lap(start);
    let mut seconds = WarpSeconds::default();
    let fixed = inputs::load_volume(&opts.fixed, opts.quiet)?;
    let moving = inputs::load_volume(&opts.moving, opts.quiet)?;
    let reference = opts.reference.as_deref().map(|p| inputs::load_volume(p, opts.quiet)).transpose()?;
    seconds.load = lap.next();
    let grid_volume = reference.as_ref().unwrap_or(&fixed);
    let pairs = opts.landmarks.read()?;
    let c = inputs::correspondences(&opts.landmarks, &pairs, &moving, &fixed, inputs::min_pairs(&method))?;
    let target_box = inputs::volume_box::<Fixed>(grid_volume);
    let pullback = match method {
        Method::Tps { stiffness } => FittedPullBack::Tps(
            Tps::fit_smoothing(&c.fixed, &c.moving, stiffness)
                .map_err(|e| Failure::BadInput(anyhow!("fitting the {method} warp: {e}")))?,
        ),
        _ => FittedPullBack::Other(inputs::fit_pullback(&method, &c, target_box)?),
    };

    // The pull-back as the export takes it.
    let tps_parts = match (&pullback, opts.pullback) {
        (FittedPullBack::Tps(t), PullBackMode::Exact) => Some(TpsParts::new(t)),
        _ => None,
    };
    let grid_n = match opts.pullback {
        PullBackMode::Grid(n) => n,
        // Linear warps: trilinear interpolation of an affine map is exact, so 2³ texels suffice.
        PullBackMode::Exact => 2,
    };
    let control =
        if tps_parts.is_none() { Some(scene::control_texture(pullback.as_warp(), target_box, grid_n)?) } else { None };
    let export_pullback = match (&tps_parts, &control) {
        (Some(parts), _) => PullBack::Tps(parts.desc()),
        (None, Some((grid, texture))) => PullBack::Control(scene::control_desc(grid, texture)),
        (None, None) => unreachable!("either the TPS parts or a control texture"),
    };
    let outside_value = opts.outside_value.unwrap_or(if scene::looks_like_ct(&moving) { -1024.0 } else { 0.0 });
    let source = SourceVolume {
        dims: moving.dims,
        samples: export_samples(&moving),
        lps_from_index: moving.lps_from_index.rows(),
    };
    let target = TargetGrid { dims: grid_volume.dims, lps_from_index: grid_volume.lps_from_index.rows() };
    let grid_lps_from_index = grid_volume.lps_from_index;
    // Only the grids' geometry is needed from here on: free their voxels before the output is allocated (peak
    // memory: the moving volume and the output).
    drop(reference);
    drop(fixed);
    let request = ExportRequest {
        interpolation: opts.interpolation,
        output: if opts.float { OutputType::F32 } else { OutputType::Source },
        outside_value,
        ..ExportRequest::new(source, target, export_pullback)
    };

    seconds.fit = lap.next();
    let bar = crate::progress::Bar::new(opts.quiet);
    let mut report_progress = |p: Progress| {
        bar.set("resampling", p.slices_done as u64, p.slices_total as u64);
        true
    };
    let (exported, backend) = match opts.backend {
        Backend::Cpu => (export_cpu(&request, &mut report_progress), "cpu".to_owned()),
        Backend::Gpu | Backend::Auto => match gpu_export(&request, opts.backend == Backend::Auto, &mut report_progress)
        {
            Ok((v, adapter)) => (Ok(v), format!("gpu: {adapter}")),
            Err(e) if opts.backend == Backend::Auto => {
                if !opts.quiet {
                    eprintln!("note: resampling on the CPU ({e})");
                }
                (export_cpu(&request, &mut report_progress), "cpu".to_owned())
            }
            Err(e) => (Err(e), "gpu".to_owned()),
        },
    };
    bar.finish();
    let exported = exported.map_err(|e| match e {
        GpuError::InvalidInput(_) => Failure::BadInput(anyhow!("resampling {}: {e}", opts.moving.display())),
        other => Failure::Internal(anyhow::Error::from(other).context("resampling")),
    })?;
    seconds.resample = lap.next();

    let mut volume = Volume::new(
        &opts.out.path,
        exported.dims,
        voxel_data(exported.samples)?,
        grid_lps_from_index,
        GeometrySource::NiftiSform { code: 1 },
    )?;
    volume.modality = moving.modality.clone();
    nifti::write(&opts.out.path, &volume)?;
    if let Some(dir) = &opts.out_dicom {
        let dicom_opts = DicomSeriesOptions {
            modality: moving.modality.clone(),
            series_description: format!("warpbench {method} warp of {}", file_name(&opts.moving)),
            ..DicomSeriesOptions::default()
        };
        dicom_write::write_series(dir, &volume, &dicom_opts)?;
    }
    seconds.write = lap.next();
    seconds.total = start.elapsed().as_secs_f64();
    Ok(WarpReport {
        schema: "warpbench-warp/1",
        out: opts.out.path.display().to_string(),
        out_dicom: opts.out_dicom.as_ref().map(|d| d.display().to_string()),
        dims: volume.dims,
        spacing_mm: volume.spacing_mm(),
        dtype: volume.sample_type().name(),
        method: method.to_string(),
        pairs: c.moving.len(),
        pullback: match opts.pullback {
            PullBackMode::Grid(n) => format!("grid {n}"),
            PullBackMode::Exact => "exact".into(),
        },
        interpolation: interpolation_name(opts.interpolation),
        backend,
        outside_value,
        seconds,
    })
}

/// Seconds since the previous lap.
struct Lap(Instant);

impl Lap {
    fn next(&mut self) -> f64 {
        let now = Instant::now();
        let seconds = now.duration_since(self.0).as_secs_f64();
        self.0 = now;
        seconds
    }
}

/// `.nii` or `.nii.gz`, in any case.
fn is_nifti_name(p: &Path) -> bool {
    let name = p.file_name().map(|n| n.to_string_lossy().to_ascii_lowercase()).unwrap_or_default();
    [".nii", ".nii.gz"].iter().any(|ext| name.len() > ext.len() && name.ends_with(ext))
}

fn file_name(p: &Path) -> String {
    p.file_name().map_or_else(|| p.display().to_string(), |n| n.to_string_lossy().into_owned())
}

/// The export on a headless GPU; the adapter's name with the result. `hardware_only` refuses CPU drivers.
fn gpu_export(
    request: &ExportRequest<'_>,
    hardware_only: bool,
    progress: &mut dyn FnMut(Progress) -> bool,
) -> Result<(warpbench_gpu::export::ExportedVolume, String), GpuError> {
    let ctx = GpuContext::headless()?;
    if hardware_only && ctx.is_cpu_driver() {
        return Err(GpuError::Unsupported(format!("the adapter is a CPU driver ({})", ctx.describe())));
    }
    let pass = ExportPass::new(&ctx)?;
    let out = pass.run(&ctx, request, progress)?;
    Ok((out, ctx.describe()))
}
