//! `warpbench warp`: resample the moving volume into the fixed volume's grid (or `--reference`'s) through the
//! landmark warp's pull-back, v′(x) = v(u(x)) with u = moving_from_fixed (as ITK's ResampleImageFilter does with a
//! transform that maps output points to input points), and write a volume with the output grid's geometry (NIfTI,
//! NRRD or MetaImage, by the output's name: [`warpbench_io::write_volume`]), and optionally a DICOM series.
//!
//! The pull-back is sampled into a `--grid`³ control texture over the output grid's box (the renderer's texture,
//! so the file shows what the app shows), or evaluated exactly at every voxel with `--exact` (TPS; affine,
//! similarity and rigid warps are exact through any control texture, because trilinear interpolation reproduces an
//! affine map). The resampling runs on the GPU (`--backend gpu`), on the CPU with rayon (`cpu`), or where it is
//! expected to finish first (`auto`, [`Backend::Auto`]); both give the same result (`warpbench_gpu::export`).
//!
//! With `--field F` ([`WarpInputs::Field`]) the pull-back is a displacement field read from a file instead of one
//! fitted on landmarks: u(x) = x + D(x), D interpolated trilinearly in the field's grid and zero outside it, as ITK's
//! `DisplacementFieldTransform` maps points ([`warpbench_solver::field::SampledField`]). Any flavour
//! [`warpbench_io::displacement::read_field_info`] reads will do (ITK's DISPVECT NIfTI, ANTs' VECTOR NIfTI, Slicer's
//! NRRD). A field that says it is the forward map d (NRRD `displacement field type:=modeling`) is inverted by
//! scattered-data interpolation ([`warpbench_solver::invert`]) and its inverse is the pull-back. `--grid N`
//! samples the field into the control texture like any other pull-back; `--exact` evaluates it at every voxel
//! centre of the output grid (a control texture laid texel on voxel, see `VoxelTexture`).
//!
//! [`run`] loads the files, calls the in-memory core [`resample`] (the pairs checked, the fit, the export, with a
//! progress callback that can cancel) and writes with [`write_outputs`]; the window exports through the same three.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, anyhow};
use serde::Serialize;
use warpbench_gpu::ControlDesc;
use warpbench_gpu::export::{
    ExportDevice, ExportPass, ExportPath, ExportRequest, ExportedSamples, Interpolation, OutputType, Progress,
    PullBack, SourceVolume, TargetGrid, choose_path, export_cpu,
};
use warpbench_gpu::{GpuContext, GpuError};
use warpbench_io::dicom_source::DicomSource;
use warpbench_io::dicom_write::{self, DicomSeriesOptions};
use warpbench_io::displacement::{self, FieldDirection};
use warpbench_io::geometry::{Index, Lps, Transform};
use warpbench_io::landmarks::LandmarkPair;
use warpbench_io::volume::{GeometrySource, VoxelData};
use warpbench_io::{Volume, VolumeFileKind};
use warpbench_solver::control::{ControlGrid, ControlTexture};
use warpbench_solver::field::SampledField;
use warpbench_solver::invert;
use warpbench_solver::method::{FittedWarp, Method};
use warpbench_solver::spaces::{Fixed, Moving};
use warpbench_solver::warp::Warp;

use crate::args::{PairArgs, ReportArgs, VolumePairArgs, help};
use crate::brushed::Brushed;
use crate::exit::Failure;
use crate::fit::{self, TpsParts};
use crate::inputs::{self, LandmarkWarp, Names, OutputFile, PairInputs, PairVolumes};
use crate::project::stack::Layers;
use crate::scene;

pub use crate::project::field_file::FieldReadFormat;

/// Where the resampling runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Backend {
    /// Whichever of the two is expected to finish first: `warpbench_gpu::export::choose_path`'s rule. The CPU
    /// without a hardware GPU (a CPU driver such as lavapipe or llvmpipe runs the same work on the same cores, more
    /// slowly), for samples that f32 does not hold, and where the GPU's fixed cost (a device, a pipeline) is not
    /// repaid: small outputs, and cheap kernels on many CPU threads. The GPU otherwise.
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

/// What `warp` pulls the moving volume back through: landmark pairs fitted with a method, or a displacement field.
#[derive(Clone, Debug)]
pub enum WarpInputs {
    /// The pair, landmarks, method, and the output grid (`reference`, else the fixed volume's).
    Pairs(PairInputs),
    /// The pair, a pull-back displacement field (`--field`), and the output grid.
    Field(FieldInputs),
}

/// The inputs of `warp --field`.
#[derive(Clone, Debug)]
pub struct FieldInputs {
    pub volumes: inputs::VolumePair,
    /// The displacement field: u(x) = x + D(x), u = moving_from_fixed.
    pub field: PathBuf,
    /// How it is told apart.
    pub format: FieldReadFormat,
    /// The output grid, when not the fixed volume's.
    pub reference: Option<PathBuf>,
}

/// `--field-format`, which `warp` and `render` share.
#[derive(Clone, Copy, Debug, clap::Args)]
pub struct FieldFormatArgs {
    /// How --field is read: auto (by its content) or learn2reg (Learn2Reg's steps from fixed voxels to moving voxels,
    /// .npz or an (X, Y, Z, 3) NIfTI, which says nothing of its units otherwise).
    #[arg(
        long = "field-format",
        id = "field_format",
        value_name = "FORMAT",
        value_enum,
        default_value = "auto",
        requires = "field"
    )]
    pub format: FieldReadFormat,
}

impl WarpInputs {
    /// From the command line: `--field` (read as `field_format` says) or the landmarks of `pairs`, exactly one of
    /// them.
    pub fn from_args(
        volumes: VolumePairArgs,
        pairs: PairArgs,
        (field, format): (Option<PathBuf>, FieldReadFormat),
        reference: Option<PathBuf>,
        quiet: bool,
    ) -> Result<Self, Failure> {
        let given = LandmarkWarp::try_from(pairs).map_err(Failure::BadInput)?;
        let volumes = given.volumes(volumes, quiet).map_err(Failure::BadInput)?;
        match (field, given.landmarks) {
            (Some(field), None) => Ok(Self::Field(FieldInputs { volumes, field, format, reference })),
            (None, Some(landmarks)) => Ok(Self::Pairs(PairInputs { volumes, landmarks, warp: given.warp, reference })),
            (Some(_), Some(_)) => Err(Failure::BadInput(anyhow!(
                "give either --field or landmarks (--landmarks, or --moving-points with --fixed-points), not both"
            ))),
            (None, None) => Err(Failure::BadInput(anyhow!(
                "give the warp: --landmarks, --moving-points with --fixed-points, --session, or --field"
            ))),
        }
    }

    /// The fixed and the moving volume.
    #[must_use]
    pub fn volumes(&self) -> &inputs::VolumePair {
        match self {
            Self::Pairs(p) => &p.volumes,
            Self::Field(f) => &f.volumes,
        }
    }

    #[must_use]
    pub fn reference(&self) -> Option<&Path> {
        match self {
            Self::Pairs(p) => p.reference.as_deref(),
            Self::Field(f) => f.reference.as_deref(),
        }
    }

    /// Every input file, which no output may be.
    #[must_use]
    pub fn paths(&self) -> Vec<&Path> {
        match self {
            Self::Pairs(p) => p.paths(),
            Self::Field(f) => [&f.volumes.fixed, &f.volumes.moving, &f.field]
                .into_iter()
                .map(PathBuf::as_path)
                .chain(f.reference.as_deref())
                .collect(),
        }
    }

    /// What messages call the inputs, and `out` (for a field, [`Names::landmarks`] is the field's path).
    #[must_use]
    pub fn names(&self, out: &Path) -> Names {
        match self {
            Self::Pairs(p) => p.names(out),
            Self::Field(f) => Names {
                moving: f.volumes.moving.display().to_string(),
                landmarks: f.field.display().to_string(),
                out: out.to_owned(),
            },
        }
    }
}

/// A displacement field read for `warp --field`: the pull-back u = moving_from_fixed, or the forward map d =
/// fixed_from_moving, which `warp` inverts.
#[derive(Clone, Debug)]
pub enum WarpField {
    /// u(x) = x + D(x) on the field's grid (ITK's convention, and what a NIfTI field is taken to be).
    Pullback(SampledField<Moving, Fixed>),
    /// d(y) = y + D(y): a NRRD field whose `displacement field type` is `modeling`.
    Forward(SampledField<Fixed, Moving>),
}

/// Reads a displacement field of any flavour ([`displacement::read_field_on`]: an ITK transform file of B-splines,
/// which gives no grid of its own, sampled on `grid`): a pull-back unless the file says it is the forward map
/// (NRRD's `displacement field type:=modeling`). What the reader assumed is printed on stderr unless `quiet`.
/// Errors name the file.
pub fn read_warp_field(path: &Path, grid: Option<&Volume>, quiet: bool) -> Result<WarpField, Failure> {
    let grid = grid.map(displacement::SampleGrid::of);
    let read = displacement::read_field_on(path, grid.as_ref())?;
    if !quiet {
        for w in &read.warnings {
            eprintln!("warpbench: warning: {}: {w}", path.display());
        }
    }
    let bad = |e: warpbench_solver::SolverError| Failure::BadInput(anyhow!("{}: {e}", path.display()));
    Ok(match read.direction {
        Some(FieldDirection::Forward) => {
            WarpField::Forward(SampledField::from_displacement_field(read.field).map_err(bad)?)
        }
        Some(FieldDirection::Pullback) | None => {
            WarpField::Pullback(SampledField::from_displacement_field(read.field).map_err(bad)?)
        }
    })
}

/// Reads a field that is read against the pair's grids (a Learn2Reg field, [`warpbench_io::learn2reg`], or an FSL
/// FNIRT warp, [`warpbench_io::fnirt`]) as the pull-back it states between `fixed` and `moving`
/// ([`crate::project::field_file::pair_pullback`]); what the reader inferred is printed on stderr unless `quiet`.
/// Errors name the file.
pub fn read_pair_field(
    path: &Path,
    fixed: &Volume,
    moving: &Volume,
    quiet: bool,
) -> Result<SampledField<Moving, Fixed>, Failure> {
    let (field, warnings) = crate::project::field_file::pair_pullback(
        path,
        (fixed.dims, &fixed.lps_from_index),
        (moving.dims, &moving.lps_from_index),
    )
    .map_err(Failure::BadInput)?;
    if !quiet {
        for w in &warnings {
            eprintln!("warpbench: warning: {}: {w}", path.display());
        }
    }
    Ok(field)
}

/// Whether `--field` at `path` is read once the volumes are: a Learn2Reg field (as `format` says), in their voxels,
/// an FNIRT warp, in their FSL coordinates, or an ITK transform file, which may hold B-splines that give no grid of
/// their own. A field in its own geometry is
/// read before them, so that one refused costs no loading.
///
/// # Errors
/// The file cannot be opened.
pub fn read_after_volumes(path: &Path, format: FieldReadFormat) -> Result<bool, Failure> {
    Ok(format.reads_against_pair(path)? || displacement::is_itk_transform_file(path)?)
}

/// [`read_warp_field`] for `render --field`, which takes the pull-back only: a forward field is refused.
pub fn read_pullback_field(
    path: &Path,
    grid: Option<&Volume>,
    quiet: bool,
) -> Result<SampledField<Moving, Fixed>, Failure> {
    match read_warp_field(path, grid, quiet)? {
        WarpField::Pullback(field) => Ok(field),
        WarpField::Forward(_) => Err(Failure::BadInput(anyhow!(
            "{}: a forward displacement field (displacement field type: modeling, fixed_from_moving); render \
             shows the moving volume through the pull-back: give the pull-back (resampling) field, e.g. from \
             `warpbench field --direction pullback`, or resample it with `warpbench warp --field`, which inverts it",
            path.display()
        ))),
    }
}

pub use crate::brushed::InverseConsistency;

/// What `warpbench warp --help` says above the options; its first paragraph is the summary that `-h` and
/// `warpbench --help` show.
const HELP: &str = "\
Resample the moving volume into the fixed volume's grid through the landmark warp, or through a displacement
field (--field), and write a volume (NIfTI, NRRD, MetaImage, MGH, MINC or OME-Zarr, by --out's name; and, with
--out-dicom, a DICOM series) with the fixed grid's geometry.

The pull-back u = moving_from_fixed is sampled into a --grid³ control texture over the output grid (what the
app shows), or evaluated exactly per voxel with --exact (TPS, a field). --field takes a pull-back field in
any flavour warpbench field writes (ITK NIfTI DISPVECT, ANTs NIfTI VECTOR, Slicer NRRD): u(x) = x + D(x),
D interpolated trilinearly and zero outside the field's grid, as ITK's DisplacementFieldTransform. A Learn2Reg
field (.npz, or its NIfTI form with --field-format learn2reg) holds steps from fixed voxels to moving voxels,
read in the two volumes' voxels. Examples:

    warpbench warp --fixed ct.nii.gz --moving mr.nii.gz --landmarks pairs.csv --out mr_in_ct.nii.gz
    warpbench warp --fixed ct.nii.gz --moving mr.nii.gz --moving-points mr.mrk.json --fixed-points ct.mrk.json --method rigid --interp cubic --out mr_rigid.nii.gz
    warpbench warp --fixed ct.nii.gz --moving mr.nii.gz --field mr_to_ct1Warp.nii.gz --exact --out mr_in_ct.nii.gz";

/// The arguments of `warpbench warp`.
#[derive(Debug, clap::Args)]
#[command(about = crate::args::summary(HELP), long_about = HELP)]
#[command(mut_args(help(&[
    ("fixed", "The fixed volume: its grid is the output grid. NIfTI, NRRD or a DICOM series folder"),
    ("moving", "The moving volume, resampled"),
    ("json", "Print a JSON report (schema warpbench-warp/1) to stdout"),
    ("force", "Overwrite --out if it exists"),
])))]
#[command(mut_args(crate::args::or_session))]
pub struct WarpArgs {
    #[command(flatten)]
    pub volumes: VolumePairArgs,
    #[command(flatten)]
    pub pairs: PairArgs,
    /// A pull-back displacement field to apply instead of landmarks (ITK or ANTs NIfTI, NRRD, MetaImage, or an ITK
    /// .h5 such as ANTs' Composite.h5; u(x) = x + D(x)), or Learn2Reg's field (steps from fixed to moving voxels:
    /// an .npz, or its NIfTI form with --field-format learn2reg).
    #[arg(long, conflicts_with_all = ["landmarks", "moving_points", "fixed_points", "session", "method", "stiffness", "levels", "initial", "initial_field"])]
    pub field: Option<PathBuf>,
    #[command(flatten)]
    pub field_format: FieldFormatArgs,
    /// Control-texture texels per axis over the output grid (2..=256).
    #[arg(long, default_value_t = 64, conflicts_with = "exact")]
    pub grid: usize,
    /// Evaluate the pull-back exactly at every voxel (TPS, the linear warps, a field) instead of a control texture.
    #[arg(long)]
    pub exact: bool,
    /// Interpolation: nearest, linear (trilinear) or cubic (Catmull-Rom).
    #[arg(long, value_enum, default_value = "linear")]
    pub interp: InterpArg,
    /// Where to resample: auto (the path expected to be faster for this size on this machine: the CPU without a
    /// hardware GPU), cpu or gpu.
    #[arg(long, value_enum, default_value = "auto")]
    pub backend: BackendArg,
    /// Write f32 samples instead of the moving volume's type (rounded half to even and clamped).
    #[arg(long)]
    pub float: bool,
    /// Another volume whose grid the output takes instead of the fixed volume's.
    #[arg(long)]
    pub reference: Option<PathBuf>,
    /// The value of voxels that map outside the moving volume (default −1024 for a CT, else 0).
    #[arg(long, allow_hyphen_values = true)]
    pub outside: Option<f64>,
    /// The volume to write: NIfTI (.nii, .nii.gz), NRRD (.nrrd), MetaImage (.mha; .mhd with a .raw beside it),
    /// FreeSurfer's MGH (.mgh, .mgz), MINC 2 (.mnc) or OME-Zarr (a folder named .ome.zarr; an axis-aligned grid).
    #[arg(long)]
    pub out: PathBuf,
    /// Also write the result as a DICOM series (new UIDs) into this new folder.
    #[arg(long)]
    pub out_dicom: Option<PathBuf>,
    #[command(flatten)]
    pub report: ReportArgs,
}

/// `--interp`: the export's interpolation by its command-line name.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum InterpArg {
    Nearest,
    Linear,
    Cubic,
}

impl From<InterpArg> for Interpolation {
    fn from(arg: InterpArg) -> Self {
        match arg {
            InterpArg::Nearest => Self::Nearest,
            InterpArg::Linear => Self::Trilinear,
            InterpArg::Cubic => Self::CatmullRom,
        }
    }
}

/// `--backend`: [`Backend`] by its command-line name.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum BackendArg {
    Auto,
    Cpu,
    Gpu,
}

impl From<BackendArg> for Backend {
    fn from(arg: BackendArg) -> Self {
        match arg {
            BackendArg::Auto => Self::Auto,
            BackendArg::Cpu => Self::Cpu,
            BackendArg::Gpu => Self::Gpu,
        }
    }
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
    /// The method as fitted (`tps`, `affine`, …), or `field` with `--field`.
    pub method: String,
    /// Landmark pairs used; 0 with `--field`.
    pub pairs: usize,
    /// The displacement field applied (`--field`), as given; `null` with landmarks.
    pub field: Option<String>,
    /// With a forward `--field`: how well its inverse, the pull-back used, undoes it; else `null`.
    pub inverse_consistency_mm: Option<InverseConsistency>,
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

/// Everything `warp` needs besides files: the method, and how the export runs ([`WarpArgs`] without paths).
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
    /// When the pull-back is the inverse of a forward field: its inverse consistency.
    pub inverse_consistency: Option<InverseConsistency>,
    /// Wall-clock seconds of the fit (landmark checks, fit, control texture) and of the resampling.
    pub fit_seconds: f64,
    pub resample_seconds: f64,
}

/// Resamples `moving` on `grid`'s geometry through the pull-back fitted on `pairs` (raw, as read: checked against
/// `moving` and `fixed` here, by [`inputs::check_pairs`]) on the warp stack's other `layers` (a starting transform
/// under it, a brush on top: u ∘ b⁻¹ goes through a control texture for `--grid` and is evaluated at every voxel for
/// `--exact`; [`crate::project::stack`]); the volume `warpbench warp`
/// writes, which is this function's result. `grid` is the output grid: the fixed volume, or `--reference`; only its geometry is read.
/// `names` name the inputs in messages.
///
/// `progress` is called after each slab of output slices; returning `false` stops the resampling with
/// [`Failure::Cancelled`] and no volume.
pub fn resample(
    grid: &Volume,
    fixed: &Volume,
    moving: &Volume,
    layers: (&[LandmarkPair], &Layers),
    names: &Names,
    settings: &WarpSettings,
    progress: &mut dyn FnMut(Progress) -> bool,
) -> Result<Resampled, Failure> {
    let fitted = Fitted::new(grid, fixed, moving, layers, names, settings)?;
    fitted.resample(moving, names, progress)
}

/// Resamples `moving` on `grid` through a pull-back field sampled on that grid, exactly at every voxel (`--exact`),
/// trilinear, in the moving volume's sample type, on the CPU: what `warpbench register --out` writes. `field_path`
/// names the field in messages.
pub fn resample_through_field(
    grid: &Volume,
    moving: &Volume,
    field: SampledField<Moving, Fixed>,
    field_path: &Path,
    names: &Names,
    progress: &mut dyn FnMut(Progress) -> bool,
) -> Result<Resampled, Failure> {
    let settings = ExportSettings {
        pullback: PullBackMode::Exact,
        interpolation: Interpolation::Trilinear,
        float: false,
        backend: Backend::Cpu,
        outside_value: None,
    };
    let fitted = Fitted::from_field(grid, moving, &WarpField::Pullback(field), field_path, &settings)?;
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

/// Refuses a volume output, as [`OutputFile::check`] refuses `out` itself, when the data file a `.mhd` writes beside
/// it (`.raw`) is an input or exists without `force`.
pub fn check_data_file(out: &Path, inputs: &[&Path], force: bool) -> anyhow::Result<()> {
    match warpbench_io::metaimage::detached_data_file(out) {
        Some(raw) => crate::inputs::check_output(&raw, inputs, force)
            .map_err(|e| anyhow!("{e:#} (the data file of {})", out.display())),
        None => Ok(()),
    }
}

/// Refuses outputs `warp` cannot write: `out` not named as a volume [`warpbench_io::write_volume`] writes (`.nii`,
/// `.nii.gz`, `.nrrd`, `.mha`, `.mhd`, `.mgh`, `.mgz`, `.mnc`, `.ome.zarr`), or `out_dicom` an existing folder that is not empty. (Whether `out` may be
/// replaced is [`OutputFile::check`]'s business, and [`check_data_file`]'s for a `.mhd`'s data file.)
pub fn check_outputs(out: &Path, out_dicom: Option<&Path>) -> anyhow::Result<()> {
    if VolumeFileKind::of(out).is_none() {
        return Err(anyhow!(
            "{}: --out must end in .nii, .nii.gz, .nrrd, .mha, .mhd, .mgh, .mgz, .mnc or .ome.zarr ({})",
            out.display(),
            VolumeFileKind::EXPECTED
        ));
    }
    if let Some(dir) = out_dicom
        && dir.exists()
        && std::fs::read_dir(dir).map_err(|e| anyhow!("{}: {e}", dir.display()))?.next().is_some()
    {
        return Err(anyhow!("{}: --out-dicom must be a new or empty folder", dir.display()));
    }
    Ok(())
}

/// Refuses an output grid that `out`'s format cannot hold (an oblique grid as OME-Zarr), once the volumes are loaded
/// and before any work is spent on the result.
pub fn check_output_grid(out: &Path, grid: &Volume) -> anyhow::Result<()> {
    if VolumeFileKind::of(out) == Some(VolumeFileKind::OmeZarr) {
        warpbench_io::ngff::check_grid(out, &grid.lps_from_index)?;
    }
    Ok(())
}

/// The DICOM series description `warp` writes: `warpbench <method> warp of <moving file name>`.
#[must_use]
pub fn series_description(method: &str, moving: &Path) -> String {
    format!("warpbench {method} warp of {}", file_name(moving))
}

/// Writes `volume` as `warp` does: a volume at `out` in the format its name says ([`warpbench_io::write_volume`]:
/// NIfTI, NRRD or MetaImage) and, when `out_dicom` is given, a DICOM series in that folder
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
    warpbench_io::write_volume(out, volume)?;
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

/// [`WarpSettings`] less the method: how the export runs, whatever the pull-back.
#[derive(Clone, Copy, Debug, PartialEq)]
struct ExportSettings {
    pullback: PullBackMode,
    interpolation: Interpolation,
    float: bool,
    backend: Backend,
    outside_value: Option<f64>,
}

impl From<&WarpSettings> for ExportSettings {
    fn from(s: &WarpSettings) -> Self {
        Self {
            pullback: s.pullback,
            interpolation: s.interpolation,
            float: s.float,
            backend: s.backend,
            outside_value: s.outside_value,
        }
    }
}

/// The outside value given, or −1024 for a CT and 0 otherwise.
fn outside_value(given: Option<f64>, moving: &Volume) -> f64 {
    given.unwrap_or(if scene::looks_like_ct(moving) { -1024.0 } else { 0.0 })
}

/// The pull-back as the export takes it, owned.
enum ExportPullBack {
    Tps(TpsParts),
    Control(ControlGrid, ControlTexture),
    Voxels(VoxelTexture),
}

impl ExportPullBack {
    fn desc(&self) -> PullBack<'_> {
        match self {
            Self::Tps(parts) => PullBack::Tps(parts.desc()),
            Self::Control(grid, texture) => PullBack::Control(scene::control_desc(grid, texture)),
            Self::Voxels(v) => PullBack::Control(v.desc()),
        }
    }
}

/// A pull-back evaluated exactly at every voxel centre of the output grid, held as a control texture laid texel
/// on voxel: how `--exact` applies a displacement field, through the export's control-texture path.
///
/// The export looks a control texture up in an axis-aligned box of the target grid's space. To put texel (i, j, k)
/// on voxel (i, j, k) of any grid, oblique or flipped too, the texture lives in the grid's index space scaled by its
/// spacings, r = o + S·(i, j, k) with S = diag(spacing_mm) and o the first voxel's centre; the export is given
/// `ref_from_index` (that map) as the target's geometry, and each texel stores u(x) − r at the voxel's LPS point
/// x = lps_from_index·(i, j, k), so that the export's r + texel is u(x), to the f32 rounding of the texel. For an
/// axis-aligned grid with positive spacings r is x itself. The texture holds 16 bytes per output voxel.
struct VoxelTexture {
    dims: [usize; 3],
    /// `[dx, dy, dz, 0]` per voxel, i fastest.
    texels: Vec<f32>,
    ref_from_index: [[f64; 4]; 4],
    box_min_ref: [f64; 3],
    box_max_ref: [f64; 3],
}

impl VoxelTexture {
    /// Refuses (before allocating) a texture over [`warpbench_io::volume::DEFAULT_MAX_VOXEL_BYTES`]; `field` names
    /// the field in that message.
    fn sample<W: Warp<Moving, Fixed> + ?Sized>(
        moving_from_fixed: &W,
        grid: &Volume,
        field: &Path,
    ) -> anyhow::Result<Self> {
        let dims = grid.dims;
        let m = grid.lps_from_index.rows();
        let spacing = grid.spacing_mm();
        let origin = [m[0][3], m[1][3], m[2][3]];
        let mut ref_from_index = [[0.0; 4]; 4];
        for a in 0..3 {
            ref_from_index[a][a] = spacing[a];
            ref_from_index[a][3] = origin[a];
        }
        ref_from_index[3][3] = 1.0;
        let box_min_ref = std::array::from_fn(|a| origin[a] - 0.5 * spacing[a]);
        let box_max_ref = std::array::from_fn(|a| origin[a] + (dims[a] as f64 - 0.5) * spacing[a]);
        let [nx, ny, nz] = dims;
        let voxels =
            warpbench_io::volume::check_allocation(field, dims, 16, warpbench_io::volume::DEFAULT_MAX_VOXEL_BYTES)
                .context("evaluating the field at every output voxel (--exact); --grid N needs far less memory")?;
        let mut texels: Vec<f32> =
            warpbench_io::volume::try_with_capacity(field, 4 * voxels, "the per-voxel field texture")?;
        let mut xs = vec![[0.0; 3]; nx];
        let mut us = vec![[0.0; 3]; nx];
        for k in 0..nz {
            for j in 0..ny {
                for (i, x) in xs.iter_mut().enumerate() {
                    let ijk = [i as f64, j as f64, k as f64];
                    *x = std::array::from_fn(|a| m[a][0] * ijk[0] + m[a][1] * ijk[1] + m[a][2] * ijk[2] + m[a][3]);
                }
                moving_from_fixed.apply_batch_raw(&xs, &mut us);
                for (i, u) in us.iter().enumerate() {
                    let r = [
                        origin[0] + spacing[0] * i as f64,
                        origin[1] + spacing[1] * j as f64,
                        origin[2] + spacing[2] * k as f64,
                    ];
                    texels.extend([(u[0] - r[0]) as f32, (u[1] - r[1]) as f32, (u[2] - r[2]) as f32, 0.0]);
                }
            }
        }
        Ok(Self { dims, texels, ref_from_index, box_min_ref, box_max_ref })
    }

    fn desc(&self) -> ControlDesc<'_> {
        ControlDesc {
            dims: self.dims,
            texels: &self.texels,
            box_min_ref: self.box_min_ref,
            box_max_ref: self.box_max_ref,
        }
    }
}

/// The pull-back [`Fitted`] is made from: fitted on landmark pairs, or read as a displacement field.
#[derive(Clone, Copy)]
enum Source<'a> {
    Fitted(&'a FittedWarp<Moving, Fixed>),
    /// A pull-back field (or a forward field's inverse) and the field's file, which messages name.
    Field(&'a dyn Warp<Moving, Fixed>, &'a Path),
}

/// The pull-back `source` as the export evaluates it on `grid` (the output grid) for `mode`, with the target grid
/// to give the export: `grid` itself, or for [`VoxelTexture`] its texture space.
fn export_pullback(
    source: Source<'_>,
    mode: PullBackMode,
    grid: &Volume,
) -> anyhow::Result<(ExportPullBack, TargetGrid)> {
    let target = TargetGrid { dims: grid.dims, lps_from_index: grid.lps_from_index.rows() };
    let target_box = inputs::volume_box::<Fixed>(grid);
    Ok(match (source, mode) {
        (Source::Fitted(FittedWarp::Tps(t)), PullBackMode::Exact) => (ExportPullBack::Tps(TpsParts::new(t)), target),
        (Source::Field(field, field_path), PullBackMode::Exact) => {
            let voxels = VoxelTexture::sample(field, grid, field_path)?;
            let target = TargetGrid { dims: grid.dims, lps_from_index: voxels.ref_from_index };
            (ExportPullBack::Voxels(voxels), target)
        }
        (Source::Fitted(warp), mode) => {
            let grid_n = match mode {
                PullBackMode::Grid(n) => n,
                // Linear warps: trilinear interpolation of an affine map is exact, so 2³ texels suffice.
                PullBackMode::Exact => 2,
            };
            let (grid, texture) = fit::control_texture(warp, target_box, grid_n)?;
            (ExportPullBack::Control(grid, texture), target)
        }
        (Source::Field(field, _), PullBackMode::Grid(n)) => {
            let (grid, texture) = scene::control_texture(field, target_box, n)?;
            (ExportPullBack::Control(grid, texture), target)
        }
    })
}

/// The first half of [`resample`]: the pairs checked, the warp fitted (or the field given), and what the export
/// needs besides the moving volume's samples. It holds only the output grid's geometry, so `run` frees the fixed and
/// reference voxels before the output is allocated.
struct Fitted {
    settings: ExportSettings,
    /// The method's name for the report: as fitted, or `field`.
    method: String,
    pairs: usize,
    pullback: ExportPullBack,
    target: TargetGrid,
    grid_lps_from_index: Transform<Lps, Index>,
    outside_value: f64,
    fit_seconds: f64,
    warnings: Vec<String>,
    inverse_consistency: Option<InverseConsistency>,
}

impl Fitted {
    fn new(
        grid: &Volume,
        fixed: &Volume,
        moving: &Volume,
        (pairs, layers): (&[LandmarkPair], &Layers),
        names: &Names,
        settings: &WarpSettings,
    ) -> Result<Self, Failure> {
        let start = Instant::now();
        let method = settings.method;
        let brush = layers.brushed();
        if layers.brush.is_none() {
            check_pullback_mode(&method, settings.pullback)?;
        }
        let c = inputs::check_pairs(&names.landmarks, pairs, moving, fixed, layers.min_pairs(&method))
            .map_err(Failure::BadInput)?;
        let target_box = inputs::volume_box::<Fixed>(grid);
        let pullback = fit::pullback_stack(&method, &c, target_box, layers.clone()).map_err(Failure::BadInput)?;
        let (pullback, target) = match pullback.as_fitted() {
            Some(u) => export_pullback(Source::Fitted(u), settings.pullback, grid),
            // A stack with a brush has no exact GPU form: through a control texture, or one texel per voxel for
            // --exact.
            None => export_pullback(Source::Field(&pullback, Path::new(&names.landmarks)), settings.pullback, grid),
        }
        .map_err(Failure::BadInput)?;
        Ok(Self {
            settings: ExportSettings::from(settings),
            method: layers.describe(&method, c.moving.len()),
            pairs: c.moving.len(),
            pullback,
            target,
            grid_lps_from_index: grid.lps_from_index,
            outside_value: outside_value(settings.outside_value, moving),
            fit_seconds: start.elapsed().as_secs_f64(),
            warnings: fit::fit_warnings(&method, &c),
            inverse_consistency: brush.map(Brushed::consistency),
        })
    }

    /// [`Self::new`] for a displacement field. A forward field d is inverted first by scattered-data interpolation
    /// ([`warpbench_solver::invert`], Brunet et al. 2006 §3.3) over the output grid's box, from samples of d over
    /// the moving volume's box; the inverse (a hierarchical B-spline) is the pull-back.
    fn from_field(
        grid: &Volume,
        moving: &Volume,
        field: &WarpField,
        field_path: &Path,
        settings: &ExportSettings,
    ) -> Result<Self, Failure> {
        let start = Instant::now();
        let inverted;
        let (moving_from_fixed, inverse_consistency): (&dyn Warp<Moving, Fixed>, _) = match field {
            WarpField::Pullback(u) => (u, None),
            WarpField::Forward(fixed_from_moving) => {
                // The field is zero outside its grid (ITK's rule), so d jumps back to the identity there; the
                // inverse is fitted where every preimage lies on the grid: the output box less the largest
                // displacement and a voxel's margin on each side (beyond it the B-spline holds its edge values).
                let margin =
                    fixed_from_moving.max_displacement_mm() + moving.spacing_mm().iter().copied().fold(0.0, f64::max);
                let out_box = inputs::volume_box::<Fixed>(grid);
                let (lo, hi) = (out_box.min.coords(), out_box.max.coords());
                let target_box = warpbench_solver::spaces::Aabb::new(
                    warpbench_io::geometry::Point3::from_array(std::array::from_fn(|a| lo[a] + margin)),
                    warpbench_io::geometry::Point3::from_array(std::array::from_fn(|a| hi[a] - margin)),
                );
                let (inverse, report) = invert::invert(
                    fixed_from_moving,
                    inputs::volume_box::<Moving>(moving),
                    target_box,
                    &invert::InvertParams::default(),
                )
                .map_err(|e| {
                    Failure::BadInput(anyhow!("{}: inverting the forward field: {e}", field_path.display()))
                })?;
                inverted = inverse;
                let consistency =
                    InverseConsistency { rms_mm: report.rms_mm, max_mm: report.max_mm, points: report.check_points };
                (&inverted, Some(consistency))
            }
        };
        let (pullback, target) = export_pullback(Source::Field(moving_from_fixed, field_path), settings.pullback, grid)
            .map_err(Failure::BadInput)?;
        Ok(Self {
            settings: *settings,
            method: "field".into(),
            pairs: 0,
            pullback,
            target,
            grid_lps_from_index: grid.lps_from_index,
            outside_value: outside_value(settings.outside_value, moving),
            fit_seconds: start.elapsed().as_secs_f64(),
            warnings: Vec::new(),
            inverse_consistency,
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
            Backend::Gpu => match GpuContext::headless().and_then(|ctx| gpu_export(&ctx, &request, progress)) {
                Ok((v, adapter)) => (Ok(v), format!("gpu: {adapter}")),
                Err(e) => (Err(e), "gpu".to_owned()),
            },
            Backend::Auto => match auto_device(&request) {
                AutoDevice::Cpu { note } => {
                    cpu_fallback = note;
                    (export_cpu(&request, progress), "cpu".to_owned())
                }
                AutoDevice::Gpu(ctx) => match gpu_export(&ctx, &request, progress) {
                    Ok((v, adapter)) => (Ok(v), format!("gpu: {adapter}")),
                    // A cancelled GPU export is not retried on the CPU.
                    Err(e) if !matches!(e, GpuError::Cancelled { .. }) => {
                        cpu_fallback = Some(e.to_string());
                        (export_cpu(&request, progress), "cpu".to_owned())
                    }
                    Err(e) => (Err(e), "gpu".to_owned()),
                },
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
            method: self.method.clone(),
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
            inverse_consistency: self.inverse_consistency,
            fit_seconds: self.fit_seconds,
            resample_seconds,
        })
    }
}

/// The fixed, moving and reference volumes of `inputs` ([`inputs::load_pair`], then the reference).
pub(crate) fn load_volumes(inputs: &WarpInputs, quiet: bool) -> anyhow::Result<PairVolumes> {
    let (fixed, moving) = inputs::load_pair(inputs.volumes(), quiet)?;
    let reference = inputs.reference().map(|p| inputs::load_volume(&inputs::VolumeArg::other(p), quiet)).transpose()?;
    Ok(PairVolumes { fixed, moving, reference })
}

/// Runs `warpbench warp`: loads, fits, resamples, writes (atomically), and reports: the JSON report to `out` with
/// `--json`, else a line on stderr unless `--quiet`. The work between loading and writing is [`resample`]'s.
pub fn run(args: WarpArgs, out: &mut dyn Write) -> Result<WarpReport, Failure> {
    let WarpArgs {
        volumes,
        pairs,
        field,
        field_format,
        grid,
        exact,
        interp,
        backend,
        float,
        reference,
        outside,
        out: out_path,
        out_dicom,
        report: ReportArgs { json, force, quiet },
    } = args;
    let inputs = WarpInputs::from_args(volumes, pairs, (field, field_format.format), reference, quiet)?;
    let output = OutputFile { path: out_path, force };
    output.check(&inputs.paths()).map_err(Failure::BadInput)?;
    check_data_file(&output.path, &inputs.paths(), force).map_err(Failure::BadInput)?;
    check_outputs(&output.path, out_dicom.as_deref()).map_err(Failure::BadInput)?;
    let export = ExportSettings {
        pullback: if exact { PullBackMode::Exact } else { PullBackMode::Grid(grid) },
        interpolation: interp.into(),
        float,
        backend: backend.into(),
        outside_value: outside,
    };
    let names = inputs.names(&output.path);

    let start = Instant::now();
    // A field is read before the volumes, so that a field `warp` refuses costs no volume loading; its time counts
    // as the fit's.
    let given = match &inputs {
        WarpInputs::Pairs(pairs) => {
            let method = pairs.method().map_err(Failure::BadInput)?;
            let brushed = pairs.brushed().map_err(Failure::BadInput)?;
            if brushed.is_none() {
                check_pullback_mode(&method, export.pullback)?;
            }
            Given::Pairs(method, pairs, brushed.map(Box::new))
        }
        WarpInputs::Field(f) if f.format.reads_against_pair(&f.field)? => Given::PairGrids(&f.field),
        WarpInputs::Field(f) if read_after_volumes(&f.field, f.format)? => Given::OnGrid(&f.field),
        WarpInputs::Field(f) => Given::Field(Box::new(read_warp_field(&f.field, None, quiet)?), &f.field),
    };
    let field_seconds = start.elapsed().as_secs_f64();
    let mut lap = Lap(Instant::now());
    let mut seconds = WarpSeconds::default();
    let PairVolumes { fixed, moving, reference } = load_volumes(&inputs, quiet).map_err(Failure::BadInput)?;
    seconds.load = lap.next();
    // `resample` in two halves: only the grids' geometry is needed after the fit, so their voxels are freed before
    // the output is allocated (peak memory: the moving volume and the output).
    let grid = reference.as_ref().unwrap_or(&fixed);
    check_output_grid(&output.path, grid).map_err(Failure::BadInput)?;
    let fitted = match given {
        Given::Pairs(method, inputs, brushed) => {
            let layers = inputs.warp.layers(brushed.map(|b| *b), &fixed, &moving).map_err(Failure::BadInput)?;
            crate::inputs::note_field_warnings(layers.field.as_deref(), quiet);
            let pairs = inputs.pairs().map_err(Failure::BadInput)?;
            let settings = WarpSettings {
                method,
                pullback: export.pullback,
                interpolation: export.interpolation,
                float: export.float,
                backend: export.backend,
                outside_value: export.outside_value,
            };
            Fitted::new(grid, &fixed, &moving, (pairs, &layers), &names, &settings)?
        }
        Given::Field(field, path) => Fitted::from_field(grid, &moving, &field, path, &export)?,
        Given::PairGrids(path) => {
            let field = WarpField::Pullback(read_pair_field(path, &fixed, &moving, quiet)?);
            Fitted::from_field(grid, &moving, &field, path, &export)?
        }
        // Sampled on the output grid, so that `--exact` evaluates the transform itself at every output voxel.
        Given::OnGrid(path) => {
            Fitted::from_field(grid, &moving, &read_warp_field(path, Some(grid), quiet)?, path, &export)?
        }
    };
    drop(reference);
    drop(fixed);

    seconds.fit = lap.next() + field_seconds;
    let bar = crate::progress::Bar::new(quiet);
    let resampled = fitted.resample(&moving, &names, &mut |p: Progress| {
        bar.set("resampling", p.slices_done as u64, p.slices_total as u64);
        true
    });
    bar.finish();
    let resampled = resampled?;
    if !quiet {
        for w in &resampled.warnings {
            eprintln!("warpbench: warning: {w}");
        }
    }
    if let Some(reason) = &resampled.cpu_fallback
        && !quiet
    {
        eprintln!("note: resampling on the CPU ({reason})");
    }
    seconds.resample = lap.next();

    let volume = &resampled.volume;
    let moving_path = &inputs.volumes().moving;
    let description = series_description(&resampled.method, moving_path);
    write_outputs(volume, &output.path, out_dicom.as_deref(), &description, Some((moving_path, &moving)))?;
    seconds.write = lap.next();
    seconds.total = start.elapsed().as_secs_f64();
    let report = WarpReport {
        schema: "warpbench-warp/1",
        out: output.path.display().to_string(),
        out_dicom: out_dicom.as_ref().map(|d| d.display().to_string()),
        dims: volume.dims,
        spacing_mm: volume.spacing_mm(),
        dtype: volume.sample_type().name(),
        method: resampled.method.clone(),
        pairs: resampled.pairs,
        field: match &inputs {
            WarpInputs::Field(f) => Some(f.field.display().to_string()),
            WarpInputs::Pairs(_) => None,
        },
        inverse_consistency_mm: resampled.inverse_consistency,
        pullback: resampled.pullback.clone(),
        interpolation: resampled.interpolation,
        backend: resampled.backend.clone(),
        outside_value: resampled.outside_value,
        warnings: resampled.warnings.clone(),
        seconds,
    };
    if json {
        crate::exit::print_json(out, &report, "the JSON report")?;
    } else if !quiet {
        let warp = match &report.field {
            Some(field) => format!("field {field}"),
            None => format!("{} pairs", report.pairs),
        };
        eprintln!(
            "wrote {} ({}×{}×{} {}, {warp}, {}, {})",
            report.out, report.dims[0], report.dims[1], report.dims[2], report.dtype, report.pullback, report.backend
        );
    }
    Ok(report)
}

/// The warp [`run`] applies, checked before any volume is loaded.
enum Given<'a> {
    /// A method, to fit on the pairs of the inputs' landmarks (read once: `--stiffness auto` may have read them),
    /// and the brush on top (the stack's other layers are read with the volumes: a field may need the fixed grid).
    Pairs(Method, &'a PairInputs, Option<Box<Brushed>>),
    /// A displacement field, read, and its file.
    Field(Box<WarpField>, &'a Path),
    /// A Learn2Reg field's or an FNIRT warp's file, read once the volumes are: its vectors are in their voxels or
    /// their FSL coordinates.
    PairGrids(&'a Path),
    /// An ITK transform file, read once the volumes are: it may hold B-splines, sampled on the output grid.
    OnGrid(&'a Path),
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

fn file_name(p: &Path) -> String {
    p.file_name().map_or_else(|| p.display().to_string(), |n| n.to_string_lossy().into_owned())
}

/// The export on `ctx`; the adapter's name with the result.
fn gpu_export(
    ctx: &GpuContext,
    request: &ExportRequest<'_>,
    progress: &mut dyn FnMut(Progress) -> bool,
) -> Result<(warpbench_gpu::export::ExportedVolume, String), GpuError> {
    let pass = ExportPass::new(ctx)?;
    let out = pass.run(ctx, request, progress)?;
    Ok((out, ctx.describe()))
}

/// Where [`Backend::Auto`] resamples.
enum AutoDevice {
    /// On the CPU; `note` says why when a GPU was tried (the CLI prints it).
    Cpu { note: Option<String> },
    /// On this GPU (boxed: a context is large).
    Gpu(Box<GpuContext>),
}

/// [`Backend::Auto`]'s choice for `request`: where `choose_path` expects it to finish first. The rule is first
/// asked as if a hardware GPU were there: when even that loses to the CPU (small outputs, cheap kernels on many
/// threads), no GPU device is made and nothing is noted. Otherwise a device is made, and a CPU driver, or a device
/// that cannot be made, sends the export to the CPU with a note.
fn auto_device(request: &ExportRequest<'_>) -> AutoDevice {
    let threads = rayon::current_num_threads();
    if choose_path(request, threads, ExportDevice::Hardware).path == ExportPath::Cpu {
        return AutoDevice::Cpu { note: None };
    }
    match GpuContext::headless() {
        Err(e) => AutoDevice::Cpu { note: Some(e.to_string()) },
        Ok(ctx) => {
            let choice = choose_path(request, threads, ExportDevice::of(&ctx));
            if choice.path == ExportPath::Cpu {
                AutoDevice::Cpu { note: Some(format!("{} ({})", choice.reason, ctx.describe())) }
            } else {
                AutoDevice::Gpu(Box::new(ctx))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use warpbench_gpu::export::ExportSamples;

    /// An n³ export of `samples` (i16) on a 1 mm grid, through the identity, with `kernel`.
    fn request(samples: &[i16], n: usize, kernel: Interpolation) -> ExportRequest<'_> {
        let mut lps_from_index = [[0.0; 4]; 4];
        for (a, row) in lps_from_index.iter_mut().enumerate() {
            row[a] = 1.0;
        }
        let source = SourceVolume { dims: [n; 3], samples: ExportSamples::I16(samples), lps_from_index };
        let target = TargetGrid { dims: [n; 3], lps_from_index };
        ExportRequest { interpolation: kernel, ..ExportRequest::new(source, target, PullBack::Identity) }
    }

    #[test]
    fn auto_keeps_a_small_export_on_the_cpu_without_making_a_device() {
        let samples = vec![0i16; 32 * 32 * 32];
        let chosen = auto_device(&request(&samples, 32, Interpolation::CatmullRom));
        assert!(matches!(chosen, AutoDevice::Cpu { note: None }), "a 32³ export made a device or a note");
    }

    #[test]
    fn auto_sends_a_large_costly_export_to_a_hardware_gpu_only() {
        // 256³ Catmull-Rom on one rayon thread: the rule expects a GPU to win, so it makes a device, and then keeps
        // the export on the CPU unless the device is a hardware GPU.
        let samples = vec![0i16; 256 * 256 * 256];
        let r = request(&samples, 256, Interpolation::CatmullRom);
        let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().expect("one-thread pool");
        match pool.install(|| auto_device(&r)) {
            AutoDevice::Gpu(ctx) => assert!(!ctx.is_cpu_driver(), "{}", ctx.describe()),
            AutoDevice::Cpu { note: Some(note) } => {
                assert!(note.contains("CPU driver") || note.contains("no GPU adapter"), "{note}");
            }
            AutoDevice::Cpu { note: None } => panic!("the rule kept a 256³ Catmull-Rom export on one thread"),
        }
    }
}
