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
//!
//! [`run`] loads the files, calls the in-memory core [`resample`] (the pairs checked, the fit, the export, with a
//! progress callback that can cancel) and writes with [`write_outputs`]; the window exports through the same three.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::anyhow;
use serde::Serialize;
use warpbench_gpu::export::{
    ExportPass, ExportRequest, ExportedSamples, Interpolation, OutputType, Progress, PullBack, SourceVolume,
    TargetGrid, export_cpu,
};
use warpbench_gpu::{GpuContext, GpuError};
use warpbench_io::dicom_source::DicomSource;
use warpbench_io::dicom_write::{self, DicomSeriesOptions};
use warpbench_io::geometry::{Index, Lps, Transform};
use warpbench_io::landmarks::LandmarkPair;
use warpbench_io::volume::{GeometrySource, VoxelData};
use warpbench_io::{Volume, nifti};
use warpbench_solver::control::{ControlGrid, ControlTexture};
use warpbench_solver::method::{FittedWarp, Method};
use warpbench_solver::spaces::Fixed;

use crate::exit::Failure;
use crate::fit::{self, TpsParts};
use crate::inputs::{self, Names, OutputFile, PairInputs, PairVolumes};
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
    /// The pair, landmarks, method, and the output grid (`reference`, else the fixed volume's).
    pub inputs: PairInputs,
    pub pullback: PullBackMode,
    pub interpolation: Interpolation,
    pub backend: Backend,
    /// f32 output instead of the moving volume's sample type.
    pub float: bool,
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
    /// What the fit found suspicious in the pairs (a pair given twice, a nearly flat set), as printed on stderr.
    pub warnings: Vec<String>,
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

fn voxel_data(samples: ExportedSamples) -> Result<VoxelData, Failure> {
    Ok(match samples {
        ExportedSamples::U8(v) => VoxelData::U8(v),
        ExportedSamples::I16(v) => VoxelData::I16(v),
        ExportedSamples::U16(v) => VoxelData::U16(v),
        ExportedSamples::F32(v) => VoxelData::F32(v),
        other => return Err(Failure::Internal(anyhow!("export returned {:?} samples", other.sample_type()))),
    })
}

fn interpolation_name(i: Interpolation) -> &'static str {
    match i {
        Interpolation::Nearest => "nearest",
        Interpolation::Trilinear => "linear",
        Interpolation::CatmullRom => "cubic (Catmull-Rom)",
    }
}

/// Everything `warp` needs besides files: the settings of [`WarpOptions`] without paths.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WarpSettings {
    /// The warp model, as fitted on the landmark pairs.
    pub method: Method,
    pub pullback: PullBackMode,
    pub interpolation: Interpolation,
    /// f32 output instead of the moving volume's sample type.
    pub float: bool,
    pub backend: Backend,
    /// The value of output voxels that map outside the moving volume; `None`: −1024 for a CT, else 0.
    pub outside_value: Option<f64>,
}

/// What [`resample`] made: the volume `warp` writes, and what its report says about it.
#[derive(Debug)]
pub struct Resampled {
    /// The moving volume resampled on the output grid: its geometry (`NiftiSform { code: 1 }`), the moving
    /// volume's sample type (f32 with [`WarpSettings::float`]) and modality.
    pub volume: Volume,
    /// The method as fitted, e.g. `tps`, `affine`.
    pub method: String,
    /// Landmark pairs used (active, with both points).
    pub pairs: usize,
    /// `grid N` or `exact`.
    pub pullback: String,
    pub interpolation: &'static str,
    /// `cpu` or `gpu: <adapter>`.
    pub backend: String,
    /// The outside value used (given, or chosen from the moving volume's modality).
    pub outside_value: f64,
    /// Why [`Backend::Auto`] resampled on the CPU, when a GPU was tried and not used (the CLI prints it as a note).
    pub cpu_fallback: Option<String>,
    /// What the fit found suspicious in the pairs, `<landmark file>: <warning>` ([`fit::fit_warnings`]).
    pub warnings: Vec<String>,
    /// Wall-clock seconds of the fit (landmark checks, fit, control texture) and of the resampling.
    pub fit_seconds: f64,
    pub resample_seconds: f64,
}

/// Resamples `moving` on `grid`'s geometry through the pull-back fitted on `pairs` (raw, as read: checked against
/// `moving` and `fixed` here, by [`inputs::check_pairs`]); the volume `warpbench warp` writes, which is this
/// function's result. `grid` is the output grid: the fixed volume, or `--reference`; only its geometry is read.
/// `names` name the inputs in messages.
///
/// `progress` is called after each slab of output slices; returning `false` stops the resampling with
/// [`Failure::Cancelled`] and no volume.
pub fn resample(
    grid: &Volume,
    fixed: &Volume,
    moving: &Volume,
    pairs: &[LandmarkPair],
    names: &Names,
    settings: &WarpSettings,
    progress: &mut dyn FnMut(Progress) -> bool,
) -> Result<Resampled, Failure> {
    let fitted = Fitted::new(grid, fixed, moving, pairs, names, settings)?;
    fitted.resample(moving, names, progress)
}

/// Refuses `--exact` with the hierarchical B-spline (it is evaluated through a control texture only).
fn check_pullback_mode(method: &Method, pullback: PullBackMode) -> Result<(), Failure> {
    if pullback == PullBackMode::Exact && matches!(method, Method::BSpline(_)) {
        return Err(Failure::BadInput(anyhow!(
            "--exact evaluates a TPS (or a linear warp) per voxel; use --grid N for the hierarchical B-spline"
        )));
    }
    Ok(())
}

/// Refuses outputs `warp` cannot write: `out` not `.nii`/`.nii.gz`, or `out_dicom` an existing folder that is not
/// empty. (Whether `out` may be replaced is [`OutputFile::check`]'s business.)
pub fn check_outputs(out: &Path, out_dicom: Option<&Path>) -> anyhow::Result<()> {
    if !is_nifti_name(out) {
        return Err(anyhow!("{}: --out must end in .nii or .nii.gz", out.display()));
    }
    if let Some(dir) = out_dicom
        && dir.exists()
        && std::fs::read_dir(dir).map_err(|e| anyhow!("{}: {e}", dir.display()))?.next().is_some()
    {
        return Err(anyhow!("{}: --out-dicom must be a new or empty folder", dir.display()));
    }
    Ok(())
}

/// The DICOM series description `warp` writes: `warpbench <method> warp of <moving file name>`.
#[must_use]
pub fn series_description(method: &str, moving: &Path) -> String {
    format!("warpbench {method} warp of {}", file_name(moving))
}

/// Writes `volume` as `warp` does: a NIfTI at `out` and, when `out_dicom` is given, a DICOM series in that folder
/// (new or empty) with `series_description` and the volume's modality. Each write is atomic. With the moving
/// volume's path (`moving`: the volume read from it), a DICOM moving series is the series' source: its patient,
/// study, equipment and acquisition attributes are copied and its images referenced.
pub fn write_outputs(
    volume: &Volume,
    out: &Path,
    out_dicom: Option<&Path>,
    series_description: &str,
    moving: Option<(&Path, &Volume)>,
) -> Result<(), Failure> {
    // Read before anything is written, so a source that cannot be read leaves no output.
    let source = match (out_dicom, moving) {
        (Some(_), Some((path, moving))) => DicomSource::for_volume(path, moving)?,
        _ => None,
    };
    nifti::write(out, volume)?;
    if let Some(dir) = out_dicom {
        let dicom_opts = DicomSeriesOptions {
            modality: volume.modality.clone(),
            series_description: series_description.to_owned(),
            source,
            ..DicomSeriesOptions::default()
        };
        dicom_write::write_series(dir, volume, &dicom_opts)?;
    }
    Ok(())
}

/// The pull-back as the export takes it, owned.
enum ExportPullBack {
    Tps(TpsParts),
    Control(ControlGrid, ControlTexture),
}

impl ExportPullBack {
    fn desc(&self) -> PullBack<'_> {
        match self {
            Self::Tps(parts) => PullBack::Tps(parts.desc()),
            Self::Control(grid, texture) => PullBack::Control(scene::control_desc(grid, texture)),
        }
    }
}

/// The first half of [`resample`]: the pairs checked, the warp fitted, and what the export needs besides the moving
/// volume's samples. It holds only the output grid's geometry, so `run` frees the fixed and reference voxels before
/// the output is allocated.
struct Fitted {
    settings: WarpSettings,
    pairs: usize,
    pullback: ExportPullBack,
    target: TargetGrid,
    grid_lps_from_index: Transform<Lps, Index>,
    outside_value: f64,
    fit_seconds: f64,
    warnings: Vec<String>,
}

impl Fitted {
    fn new(
        grid: &Volume,
        fixed: &Volume,
        moving: &Volume,
        pairs: &[LandmarkPair],
        names: &Names,
        settings: &WarpSettings,
    ) -> Result<Self, Failure> {
        let start = Instant::now();
        let method = settings.method;
        check_pullback_mode(&method, settings.pullback)?;
        let c = inputs::check_pairs(&names.landmarks, pairs, moving, fixed, inputs::min_pairs(&method))
            .map_err(Failure::BadInput)?;
        let target_box = inputs::volume_box::<Fixed>(grid);
        let pullback = fit::pullback_of(&method, &c, target_box).map_err(Failure::BadInput)?;
        let pullback = match (&pullback, settings.pullback) {
            (FittedWarp::Tps(t), PullBackMode::Exact) => ExportPullBack::Tps(TpsParts::new(t)),
            (_, mode) => {
                let grid_n = match mode {
                    PullBackMode::Grid(n) => n,
                    // Linear warps: trilinear interpolation of an affine map is exact, so 2³ texels suffice.
                    PullBackMode::Exact => 2,
                };
                let (grid, texture) = fit::control_texture(&pullback, target_box, grid_n).map_err(Failure::BadInput)?;
                ExportPullBack::Control(grid, texture)
            }
        };
        let outside_value = settings.outside_value.unwrap_or(if scene::looks_like_ct(moving) { -1024.0 } else { 0.0 });
        Ok(Self {
            settings: *settings,
            pairs: c.moving.len(),
            pullback,
            target: TargetGrid { dims: grid.dims, lps_from_index: grid.lps_from_index.rows() },
            grid_lps_from_index: grid.lps_from_index,
            outside_value,
            fit_seconds: start.elapsed().as_secs_f64(),
            warnings: fit::fit_warnings(&method, &c),
        })
    }

    /// The second half of [`resample`]: `moving` (the volume the pairs were checked against) through the export.
    fn resample(
        &self,
        moving: &Volume,
        names: &Names,
        progress: &mut dyn FnMut(Progress) -> bool,
    ) -> Result<Resampled, Failure> {
        let start = Instant::now();
        let settings = &self.settings;
        let source = SourceVolume {
            dims: moving.dims,
            samples: scene::export_samples(&moving.data),
            lps_from_index: moving.lps_from_index.rows(),
        };
        let request = ExportRequest {
            interpolation: settings.interpolation,
            output: if settings.float { OutputType::F32 } else { OutputType::Source },
            outside_value: self.outside_value,
            ..ExportRequest::new(source, self.target, self.pullback.desc())
        };
        let mut cpu_fallback = None;
        let (exported, backend) = match settings.backend {
            Backend::Cpu => (export_cpu(&request, progress), "cpu".to_owned()),
            Backend::Gpu | Backend::Auto => match gpu_export(&request, settings.backend == Backend::Auto, progress) {
                Ok((v, adapter)) => (Ok(v), format!("gpu: {adapter}")),
                // A cancelled GPU export is not retried on the CPU.
                Err(e) if settings.backend == Backend::Auto && !matches!(e, GpuError::Cancelled { .. }) => {
                    cpu_fallback = Some(e.to_string());
                    (export_cpu(&request, progress), "cpu".to_owned())
                }
                Err(e) => (Err(e), "gpu".to_owned()),
            },
        };
        let exported = exported.map_err(|e| match e {
            GpuError::InvalidInput(_) => Failure::BadInput(anyhow!("resampling {}: {e}", names.moving)),
            GpuError::Cancelled { .. } => Failure::Cancelled(anyhow::Error::from(e).context("resampling")),
            other => Failure::Internal(anyhow::Error::from(other).context("resampling")),
        })?;
        let resample_seconds = start.elapsed().as_secs_f64();

        let mut volume = Volume::new(
            &names.out,
            exported.dims,
            voxel_data(exported.samples)?,
            self.grid_lps_from_index,
            GeometrySource::NiftiSform { code: 1 },
        )?;
        volume.modality = moving.modality.clone();
        Ok(Resampled {
            volume,
            method: settings.method.to_string(),
            pairs: self.pairs,
            pullback: match settings.pullback {
                PullBackMode::Grid(n) => format!("grid {n}"),
                PullBackMode::Exact => "exact".into(),
            },
            interpolation: interpolation_name(settings.interpolation),
            backend,
            outside_value: self.outside_value,
            cpu_fallback,
            warnings: self.warnings.clone(),
            fit_seconds: self.fit_seconds,
            resample_seconds,
        })
    }
}

/// [`PairInputs::load_volumes`], but with `quiet` the fixed and moving volumes load on two threads: inflating and
/// decoding a file is one thread's work, so the two take about the time of the slower one (the 176×256×256 head MRI
/// of `data-scripts/compare_itk_warp.py` loaded as both, on a busy 2-core machine: 0.76 s, against 1.03 s one after
/// the other with the bars). With progress bars they load one after the other, so that the bars do not interleave.
/// Errors come in the same order either way: the fixed volume's first.
fn load_volumes(inputs: &PairInputs, quiet: bool) -> anyhow::Result<PairVolumes> {
    if !quiet {
        return inputs.load_volumes(quiet);
    }
    let (fixed, moving) = std::thread::scope(|s| {
        let moving = s.spawn(|| inputs::load_volume(&inputs.moving, true));
        let fixed = inputs::load_volume(&inputs.fixed, true);
        (fixed, moving.join().unwrap_or_else(|panic| std::panic::resume_unwind(panic)))
    });
    let (fixed, moving) = (fixed?, moving?);
    let reference = inputs.reference.as_deref().map(|p| inputs::load_volume(p, true)).transpose()?;
    Ok(PairVolumes { fixed, moving, reference })
}

/// Runs `warpbench warp`: loads, fits, resamples, writes (atomically), and reports. The work between loading and
/// writing is [`resample`]'s.
pub fn run(opts: &WarpOptions) -> Result<WarpReport, Failure> {
    opts.out.check(&opts.inputs.paths()).map_err(Failure::BadInput)?;
    check_outputs(&opts.out.path, opts.out_dicom.as_deref()).map_err(Failure::BadInput)?;
    let method = opts.inputs.method().map_err(Failure::BadInput)?;
    check_pullback_mode(&method, opts.pullback)?;
    let settings = WarpSettings {
        method,
        pullback: opts.pullback,
        interpolation: opts.interpolation,
        float: opts.float,
        backend: opts.backend,
        outside_value: opts.outside_value,
    };
    let names = opts.inputs.names(&opts.out.path);

    let start = Instant::now();
    let mut lap = Lap(start);
    let mut seconds = WarpSeconds::default();
    let PairVolumes { fixed, moving, reference } = load_volumes(&opts.inputs, opts.quiet).map_err(Failure::BadInput)?;
    seconds.load = lap.next();
    let pairs = opts.inputs.landmarks.read().map_err(Failure::BadInput)?;
    // `resample` in two halves: only the grids' geometry is needed after the fit, so their voxels are freed before
    // the output is allocated (peak memory: the moving volume and the output).
    let fitted = Fitted::new(reference.as_ref().unwrap_or(&fixed), &fixed, &moving, &pairs, &names, &settings)?;
    drop(reference);
    drop(fixed);

    seconds.fit = lap.next();
    let bar = crate::progress::Bar::new(opts.quiet);
    let resampled = fitted.resample(&moving, &names, &mut |p: Progress| {
        bar.set("resampling", p.slices_done as u64, p.slices_total as u64);
        true
    });
    bar.finish();
    let resampled = resampled?;
    if !opts.quiet {
        for w in &resampled.warnings {
            eprintln!("warpbench: warning: {w}");
        }
    }
    if let Some(reason) = &resampled.cpu_fallback
        && !opts.quiet
    {
        eprintln!("note: resampling on the CPU ({reason})");
    }
    seconds.resample = lap.next();

    let volume = &resampled.volume;
    let description = series_description(&resampled.method, &opts.inputs.moving);
    write_outputs(
        volume,
        &opts.out.path,
        opts.out_dicom.as_deref(),
        &description,
        Some((&opts.inputs.moving, &moving)),
    )?;
    seconds.write = lap.next();
    seconds.total = start.elapsed().as_secs_f64();
    Ok(WarpReport {
        schema: "warpbench-warp/1",
        out: opts.out.path.display().to_string(),
        out_dicom: opts.out_dicom.as_ref().map(|d| d.display().to_string()),
        dims: volume.dims,
        spacing_mm: volume.spacing_mm(),
        dtype: volume.sample_type().name(),
        method: resampled.method.clone(),
        pairs: resampled.pairs,
        pullback: resampled.pullback.clone(),
        interpolation: resampled.interpolation,
        backend: resampled.backend.clone(),
        outside_value: resampled.outside_value,
        warnings: resampled.warnings.clone(),
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
