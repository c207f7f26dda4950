//! `warpbench register`: a deformable registration by intensities under the landmarks
//! ([`warpbench_solver::register`]): a B-spline free-form deformation composed under the current pull-back (the
//! landmarks' warp on `--initial` or a session's start, or the identity), which maximises the similarity of the two
//! volumes (`--metric`, inside the masks when given) while it keeps the pairs.
//!
//! It writes the registered pull-back u = u₀ ∘ T as a displacement field in the flavours of `warpbench field`
//! (default ITK's NIfTI `DISPVECT`), sampled exactly at every voxel of the fixed grid; with `--out-inverse-field` its
//! inverse on the moving grid, and with `--out` the moving volume resampled through it. `--json` reports each level
//! (the similarity, iterations, time), the pairs' residuals and the smallest det ∇u.

use std::io::Write;
use std::ops::ControlFlow;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::anyhow;
use serde::Serialize;
use warpbench_io::Volume;
use warpbench_io::displacement::{FieldDirection, FieldFormat};
use warpbench_io::geometry::{Point3, Space};
use warpbench_io::landmarks::LandmarkPair;
use warpbench_solver::SolverError;
use warpbench_solver::align::MIN_SAMPLES_INSIDE;
use warpbench_solver::diagnostics::JacobianReport;
use warpbench_solver::field::SampledField;
use warpbench_solver::image::Image;
use warpbench_solver::invert;
use warpbench_solver::linear::AffineWarp;
use warpbench_solver::method::Method;
use warpbench_solver::register::device::SampleDevice;
use warpbench_solver::register::{
    LevelReport, RegisterPair, RegisterParams, RegisterProgress, Registration, Similarity, folding, register_on,
};
use warpbench_solver::spaces::{Aabb, Fixed, Moving};
use warpbench_solver::warp::{Composed, Parallelism, Warp};

use crate::args::{MethodArgs, PairArgs, ReportArgs, VolumePairArgs, help};
use crate::brushed::InverseConsistency;
use crate::exit::Failure;
use crate::field::{FormatArg, sample_displacements};
use crate::fit;
use crate::gpu_samples::{GpuSamples, SampleDeviceChoice};
use crate::inputs::{self, Correspondences, LandmarkWarp, Names, OutputFile};
use crate::progress::Bar;
use crate::project::stack::{Layers, StackPullback};
use crate::settings::{MethodKind, Stiffness};

/// The `--json` schema name.
pub const SCHEMA: &str = "warpbench-register/2";

/// What `warpbench register --help` says above the options; its first paragraph is the summary that `-h` and
/// `warpbench --help` show.
const HELP: &str = "\
Register the moving volume to the fixed one by intensities, under the landmarks: a deformable refinement that
keeps the pairs, written as a displacement field (and optionally the warped volume).

The warp starts from the landmarks' (--landmarks or --session, with --method and --initial as for warp), the
starting transform alone (--initial), or the identity, and a cubic B-spline deformation under it maximises the
similarity of the two volumes (--metric: Mattes mutual information by default, so an MRI registers to a CT; local
correlation or edges), read inside --fixed-mask and --moving-mask when given, while the pairs' squared distances
(--landmark-weight) and the bending energy keep it honest, over --levels resolution levels down to a control
spacing of --grid-mm. The field holds u(x) − x at each voxel of the fixed grid, as `warpbench field` writes it
(ITK maps fixed point x to moving point x + D(x)); `warpbench warp --field` applies it again, and
--out-inverse-field writes its inverse on the moving grid. Examples:

    warpbench register --fixed ct.nii.gz --moving mr.nii.gz --landmarks pairs.csv --out-field field.nii.gz
    warpbench register --fixed ct.nii.gz --moving mr.nii.gz --initial start.tfm --out-field field.nii.gz --out mr_in_ct.nii.gz --json";

/// The arguments of `warpbench register`.
#[derive(Debug, clap::Args)]
#[command(about = crate::args::summary(HELP), long_about = HELP)]
#[command(mut_args(help(&[
    ("fixed", "The fixed volume (NIfTI, NRRD or a DICOM series folder): the field's grid"),
    ("moving", "The moving volume: any modality (mutual information needs no common intensity scale)"),
    ("json", "Print a JSON summary (schema warpbench-register/2, see docs/cli.md) to stdout"),
    ("force", "Overwrite --out-field (and --out) if they exist"),
])))]
#[command(mut_args(crate::args::or_session))]
pub struct RegisterArgs {
    #[command(flatten)]
    pub volumes: VolumePairArgs,
    #[command(flatten)]
    pub pairs: RegisterPairArgs,
    /// The displacement field to write: the registered pull-back, u(x) − x on the fixed grid (.nii or .nii.gz;
    /// .nrrd for --format nrrd; .mha or .mhd for --format metaimage; .h5 for ITK's HDF5 transform file holding it as
    /// a DisplacementFieldTransform, as ANTs' Composite.h5; .npz, or .nii.gz with --format learn2reg, for Learn2Reg's
    /// field, steps from fixed voxels to moving voxels; .nii.gz with --format fnirt for FSL's applywarp, with --format
    /// afni for AFNI's 3dNwarpApply).
    #[arg(long, value_name = "FILE")]
    pub out_field: PathBuf,
    /// Also write the moving volume resampled through the registered warp onto the fixed grid (.nii, .nii.gz, .nrrd,
    /// .mha, .mhd, .mgh, .mgz, .mnc or .ome.zarr).
    #[arg(long, value_name = "FILE")]
    pub out: Option<PathBuf>,
    /// Also write the inverse, d(y) − y on the moving grid with d = fixed_from_moving ≈ u⁻¹, as `warpbench field
    /// --direction forward` writes it: a moving point y goes to y + D(y), what moving points and meshes need (ANTs'
    /// InverseWarp). It is u inverted by scattered-data interpolation and fixed-point refinement; --json says how
    /// closely it undoes u.
    #[arg(long, value_name = "FILE")]
    pub out_inverse_field: Option<PathBuf>,
    /// The field's flavour: itk (NIfTI DISPVECT, RAS vectors), ants (NIfTI VECTOR, LPS), nrrd (Slicer's NRRD, LPS),
    /// metaimage (elastix's and ITK's .mha/.mhd, LPS), learn2reg (Learn2Reg's steps from fixed voxels to moving
    /// voxels, .npz or .nii.gz) or fnirt (FSL FNIRT's relative deformation field, .nii or .nii.gz, for `applywarp
    /// --ref=FIXED --in=MOVING --warp=FILE --rel`) or afni (AFNI's warp, .nii or .nii.gz, for `3dNwarpApply -nwarp
    /// FILE`); an inverse field beside learn2reg or fnirt is itk.
    #[arg(long, value_enum, default_value = "itk")]
    pub format: FormatArg,
    /// The similarity measure: mi (Mattes mutual information: any two modalities; the default), ngf (normalised
    /// gradient fields: the edges, whatever their contrast) or lncc (local normalised cross-correlation: one modality
    /// under a smooth gain and offset, MR–MR). With --session, the session's "Match by" unless given.
    #[arg(long, value_enum)]
    pub metric: Option<crate::settings::Metric>,
    /// The finest control-point spacing, mm.
    #[arg(long, default_value_t = RegisterParams::default().grid_mm)]
    pub grid_mm: f64,
    /// Resolution levels, coarse to fine: each halves the control spacing and the image shrink.
    #[arg(long, default_value_t = RegisterParams::default().levels)]
    pub levels: usize,
    /// The weight of the pairs' squared distances |u(q) − p|², per mm², at the coarsest level; each finer level takes
    /// 1/8 of the one before (0: the pairs only start the warp).
    #[arg(long, default_value_t = RegisterParams::default().landmark_weight)]
    pub landmark_weight: f64,
    /// The weight of the bending energy (smoothness).
    #[arg(long, default_value_t = RegisterParams::default().bending_weight)]
    pub bending_weight: f64,
    /// Fixed sample points per level.
    #[arg(long, default_value_t = RegisterParams::default().samples)]
    pub samples: usize,
    /// Optimiser iterations per level, at most.
    #[arg(long, default_value_t = RegisterParams::default().max_iterations)]
    pub iterations: usize,
    /// The seed of the sample points (the same seed gives the same result, bit for bit, on one device).
    #[arg(long, default_value_t = RegisterParams::default().seed)]
    pub seed: u64,
    /// Read the fixed volume only where this mask is not 0, as elastix's and ANTs' fixed masks do: leave out what has
    /// no counterpart in the moving volume (a lesion, a resection, the scanner's table). Any volume in patient space;
    /// each fixed voxel takes the mask voxel nearest to its centre, and none outside the mask's grid. With --session,
    /// the session's fixed mask unless given.
    #[arg(long, value_name = "FILE")]
    pub fixed_mask: Option<PathBuf>,
    /// Likewise for the moving volume: a sample that lands where this mask is 0 counts as outside the moving volume.
    /// With --session, the session's moving mask unless given.
    #[arg(long, value_name = "FILE")]
    pub moving_mask: Option<PathBuf>,
    /// Where the samples of mi and lncc are read: auto (a hardware GPU when there is one, else the CPU), cpu or gpu.
    #[arg(long, value_enum, default_value = "auto")]
    pub backend: crate::warp::BackendArg,
    #[command(flatten)]
    pub report: ReportArgs,
}

/// The landmarks and the warp the registration starts from: [`PairArgs`] less the hierarchical B-spline's `--levels`
/// (here `--levels` are the registration's), which a B-spline start takes at its default.
#[derive(Clone, Debug, clap::Args)]
pub struct RegisterPairArgs {
    /// A window session (.warpbench.json): its landmark pairs, its warp method, its starting transform and its brush
    /// strokes, instead of --landmarks and the method flags.
    #[arg(long, conflicts_with_all = ["landmarks", "moving_points", "fixed_points", "method", "stiffness", "initial", "initial_field"])]
    pub session: Option<PathBuf>,
    /// Landmark pairs: BigWarp CSV or BigWarp JSON (.json, also a BigWarp settings file), moving then fixed, LPS mm.
    #[arg(long)]
    pub landmarks: Option<PathBuf>,
    /// Slicer point list (.mrk.json or .fcsv) of the moving points; with --fixed-points.
    #[arg(long)]
    pub moving_points: Option<PathBuf>,
    /// Slicer point list of the fixed points, matched to --moving-points by order.
    #[arg(long)]
    pub fixed_points: Option<PathBuf>,
    /// The landmark warp the registration starts from.
    #[arg(long, value_enum, default_value_t)]
    pub method: MethodKind,
    /// TPS stiffness λ ≥ 0 (0 interpolates the landmarks), or auto: the λ under which the pairs are most likely
    /// (generalised maximum likelihood).
    #[arg(long, default_value_t)]
    pub stiffness: Stiffness,
    /// A starting transform under the landmark warp: an ITK affine .tfm (or ANTs' .mat, or elastix's linear
    /// TransformParameters.N.txt) mapping fixed points to moving points (LPS mm), as `warpbench align` writes it; or
    /// FSL's FLIRT matrix, read against --fixed (its -ref) and --moving (its -in), AFNI's .aff12.1D or FreeSurfer's
    /// .lta.
    #[arg(long, value_name = "TFM")]
    pub initial: Option<PathBuf>,
    /// A displacement field under the landmark warp, in mm (the flavours `warp --field` reads). It maps fixed points
    /// first and --initial after it, as antsApplyTransforms -t FIELD -t TFM does.
    #[arg(long, value_name = "FIELD")]
    pub initial_field: Option<PathBuf>,
    /// How --initial-field is read: auto (by its content) or learn2reg (Learn2Reg's steps from fixed voxels to moving
    /// voxels, .npz or an (X, Y, Z, 3) NIfTI, which says nothing of its units otherwise).
    #[arg(long, value_name = "FORMAT", value_enum, default_value = "auto", requires = "initial_field")]
    pub initial_field_format: crate::project::field_file::FieldReadFormat,
}

impl From<RegisterPairArgs> for PairArgs {
    fn from(a: RegisterPairArgs) -> Self {
        Self {
            session: a.session,
            landmarks: a.landmarks,
            moving_points: a.moving_points,
            fixed_points: a.fixed_points,
            method: MethodArgs { method: a.method, stiffness: a.stiffness, levels: None },
            initial: a.initial,
            initial_field: a.initial_field,
            initial_field_format: a.initial_field_format,
        }
    }
}

/// One pair after the registration.
#[derive(Clone, Debug, Serialize)]
pub struct PairResidual {
    /// 1-based, as in the landmark file.
    pub index: usize,
    pub name: String,
    /// |u(q) − p|, mm.
    pub residual_mm: f64,
}

/// The settings the registration ran with.
#[derive(Clone, Debug, Serialize)]
pub struct RegisterSettings {
    pub metric: Similarity,
    pub grid_mm: f64,
    pub levels: usize,
    pub landmark_weight: f64,
    pub bending_weight: f64,
    pub samples: usize,
    pub iterations: usize,
    pub seed: u64,
    /// `--fixed-mask`, or null.
    pub fixed_mask: Option<String>,
    /// `--moving-mask`, or null.
    pub moving_mask: Option<String>,
}

/// What was found and written: the `--json` document, schema `warpbench-register/2` (docs/cli.md).
#[derive(Clone, Debug, Serialize)]
pub struct RegisterSummary {
    pub schema: &'static str,
    pub out_field: String,
    pub out: Option<String>,
    /// `--out-inverse-field`, or null.
    pub out_inverse_field: Option<String>,
    /// How closely the inverse undoes the registered warp, ‖u(d(y)) − y‖ over a grid where it was fitted; null
    /// without `--out-inverse-field`.
    pub inverse_consistency: Option<InverseConsistency>,
    /// The field's flavour: `itk`, `ants`, `nrrd`, `metaimage`, `learn2reg`, `fnirt` or `afni`.
    pub format: &'static str,
    /// The warp the registration started from, e.g. `tps`, `tps on start.tfm`, `identity`.
    pub start: String,
    pub settings: RegisterSettings,
    /// Pairs kept (active, with both points).
    pub pairs: usize,
    pub levels: Vec<LevelReport>,
    /// Each pair's distance after the registration.
    pub residuals: Vec<PairResidual>,
    /// det ∇u of the registered pull-back at 64³ points over the fixed volume's box.
    pub jacobian: JacobianSummary,
    /// The largest |u(x) − x| over the fixed grid, mm.
    pub max_displacement_mm: f64,
    /// Wall time of the registration itself (reading and writing excluded), seconds.
    pub register_s: f64,
    /// Where the samples were read: `cpu`, or `gpu: ` and the adapter.
    pub device: String,
    /// Why `--backend auto` stayed on the CPU when it looked for a GPU.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub cpu_fallback: Option<String>,
}

/// The folding check of the result.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct JacobianSummary {
    pub min_det: f64,
    pub max_det: f64,
    /// The fraction of points with det ≤ 0.
    pub fraction_folded: f64,
    pub points: usize,
}

impl From<JacobianReport> for JacobianSummary {
    fn from(r: JacobianReport) -> Self {
        Self { min_det: r.min_det, max_det: r.max_det, fraction_folded: r.fraction_folded, points: r.points }
    }
}

/// The pull-back the registration starts from.
#[derive(Debug)]
enum Start {
    Stack(Box<StackPullback>),
    Linear(AffineWarp<Moving, Fixed>),
}

impl Start {
    fn warp(&self) -> &dyn Warp<Moving, Fixed> {
        match self {
            Self::Stack(s) => s.as_ref(),
            Self::Linear(a) => a,
        }
    }
}

/// What a registration is made from, as the command line and the window hand it over.
#[derive(Clone, Copy, Debug)]
pub struct RefineInputs<'a> {
    pub fixed: &'a Volume,
    pub moving: &'a Volume,
    /// What messages call the two volumes: their paths, or the window's names.
    pub names: [&'a str; 2],
    /// The landmark pairs as read (checked here against the volumes).
    pub pairs: &'a [LandmarkPair],
    /// What messages call the pairs: the landmark file, or the window's table.
    pub origin: &'a str,
    pub method: &'a Method,
    /// Where the fixed volume counts, and what messages call it: the registration reads the fixed volume only at
    /// voxels whose nearest mask voxel is not 0 (elastix's and ANTs' fixed mask).
    pub fixed_mask: Option<(&'a Volume, &'a str)>,
    /// The same for the moving volume (their moving mask): a sample that lands where the moving mask is 0 counts
    /// as outside the moving volume.
    pub moving_mask: Option<(&'a Volume, &'a str)>,
}

/// A registration and what it started from: the one result the command line writes and the window keeps.
#[derive(Debug)]
pub struct Refinement {
    start: Start,
    /// The warp it started from, e.g. `tps`, `tps on start.tfm`, `identity`.
    pub start_name: String,
    /// The pairs it kept (active, with both points, inside their volumes).
    pub kept: Correspondences,
    pub registration: Registration,
    /// det ∇u of the result at 64³ points over the fixed volume's box.
    pub jacobian: JacobianReport,
    /// Wall time of the registration itself, seconds.
    pub register_s: f64,
}

impl Refinement {
    /// The registered pull-back u = u₀ ∘ T.
    #[must_use]
    pub fn pullback(&self) -> Composed<'_, Moving, Fixed, Fixed> {
        self.registration.deformation.pullback(self.start.warp())
    }

    /// Each kept pair's distance |u(q) − p| after the registration.
    #[must_use]
    pub fn residuals(&self) -> Vec<PairResidual> {
        let u = self.pullback();
        let k = &self.kept;
        k.fixed
            .iter()
            .zip(&k.moving)
            .zip(&k.labels)
            .map(|((q, p), (index, name))| {
                let (a, b) = (u.apply_raw(q.coords()), p.coords());
                let residual_mm = (0..3).map(|i| (a[i] - b[i]).powi(2)).sum::<f64>().sqrt();
                PairResidual { index: *index, name: name.clone(), residual_mm }
            })
            .collect()
    }
}

/// Registers `inputs.moving` to `inputs.fixed` under the pairs (module docs). The start u₀ is the warp stack of
/// `layers` with the landmark fit when there are pairs enough for the method or a base under it, else the identity;
/// the active pairs inside their volumes are kept by the registration either way. `progress` hears after each
/// evaluation; [`ControlFlow::Break`] stops the work with [`Failure::Cancelled`]. The mutual information's samples
/// are read on `device` when one is given ([`crate::gpu_samples`]).
///
/// # Errors
/// [`Failure::BadInput`] for a pair outside its volume, a volume with one value, volumes that do not overlap, or
/// settings out of range, naming the inputs; [`Failure::Cancelled`]; [`Failure::Internal`] when the device fails.
pub fn refine(
    inputs: RefineInputs<'_>,
    layers: Layers,
    params: &RegisterParams,
    device: Option<&dyn SampleDevice>,
    progress: &mut dyn FnMut(&RegisterProgress) -> ControlFlow<()>,
) -> Result<Refinement, Failure> {
    let RefineInputs {
        fixed,
        moving,
        names: [fixed_name, moving_name],
        pairs,
        origin,
        method,
        fixed_mask,
        moving_mask,
    } = inputs;
    params.validate().map_err(|e| Failure::BadInput(anyhow!("{e}")))?;
    let kept = inputs::check_pairs(origin, pairs, moving, fixed, 0).map_err(Failure::BadInput)?;
    let (start, start_name) = if layers.has_base() || kept.moving.len() >= method.needs().min_pairs {
        let name = layers.describe(method, kept.moving.len());
        let u = fit::pullback_stack(method, &kept, inputs::volume_box::<Fixed>(fixed), layers)
            .map_err(Failure::BadInput)?;
        (Start::Stack(Box::new(u)), name)
    } else {
        let name = match kept.moving.len() {
            0 => "identity".to_owned(),
            n => format!("identity ({n} pairs; {method} needs {})", method.needs().min_pairs),
        };
        (Start::Linear(AffineWarp::identity()), name)
    };
    let register_pairs: Vec<RegisterPair> =
        kept.fixed.iter().zip(&kept.moving).map(|(&fixed, &moving)| RegisterPair { fixed, moving }).collect();
    let fixed_image = Image::<Fixed>::from_volume(fixed, Parallelism::Rayon)
        .map_err(|e| Failure::BadInput(anyhow!("{fixed_name}: {e}")))?;
    let fixed_image = match fixed_mask {
        None => fixed_image,
        Some((mask, mask_name)) => masked(&fixed_image, mask, [mask_name, fixed_name])?,
    };
    let moving_image = Image::<Moving>::from_volume(moving, Parallelism::Rayon)
        .map_err(|e| Failure::BadInput(anyhow!("{moving_name}: {e}")))?;
    let moving_image = match moving_mask {
        None => moving_image,
        Some((mask, mask_name)) => masked(&moving_image, mask, [mask_name, moving_name])?,
    };
    let started = Instant::now();
    let registration =
        register_on(&fixed_image, &moving_image, start.warp(), &register_pairs, params, device, progress).map_err(
            |e| match e {
                SolverError::Cancelled => {
                    Failure::Cancelled(anyhow!("registering {moving_name} to {fixed_name}: cancelled"))
                }
                SolverError::Device(message) => {
                    Failure::Internal(anyhow!("registering {moving_name} to {fixed_name}: {message}"))
                }
                e => Failure::BadInput(anyhow!("registering {moving_name} to {fixed_name}: {e}")),
            },
        )?;
    let register_s = started.elapsed().as_secs_f64();
    let jacobian = folding(&registration, start.warp(), &fixed_image, [64; 3], Parallelism::Rayon);
    Ok(Refinement { start, start_name, kept, registration, jacobian, register_s })
}

/// Inverts the registered pull-back `u` ([`warpbench_solver::invert`]) and writes d(y) − y on the moving grid to
/// `path` ([`FieldDirection::Forward`]). The inverse is fitted and checked where u has preimages: the moving volume's
/// box within the box of u over the fixed volume's, less a moving voxel on each side (beyond it the B-spline holds
/// its edge values).
///
/// # Errors
/// [`Failure::BadInput`] when u maps the fixed volume outside the moving one; the inversion's and the write's.
fn write_inverse<W: Warp<Moving, Fixed>>(
    u: &W,
    [fixed, moving]: [&Volume; 2],
    path: &Path,
    format: FieldFormat,
    bar: &Bar,
) -> Result<InverseConsistency, Failure> {
    let fixed_box = inputs::volume_box::<Fixed>(fixed);
    let moving_box = inputs::volume_box::<Moving>(moving);
    let (flo, fhi) = (fixed_box.min.coords(), fixed_box.max.coords());
    let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
    for n in 0..9 * 9 * 9 {
        let t = [n % 9, (n / 9) % 9, n / 81].map(|c| c as f64 / 8.0);
        let y = u.apply_raw(std::array::from_fn(|a| flo[a] + t[a] * (fhi[a] - flo[a])));
        for a in 0..3 {
            (lo[a], hi[a]) = (lo[a].min(y[a]), hi[a].max(y[a]));
        }
    }
    let voxel = moving.spacing_mm().into_iter().fold(0.0, f64::max);
    let (mlo, mhi) = (moving_box.min.coords(), moving_box.max.coords());
    let lo: [f64; 3] = std::array::from_fn(|a| lo[a].max(mlo[a]) + voxel);
    let hi: [f64; 3] = std::array::from_fn(|a| hi[a].min(mhi[a]) - voxel);
    if (0..3).any(|a| lo[a] >= hi[a] || lo[a].is_nan() || hi[a].is_nan()) {
        return Err(Failure::BadInput(anyhow!(
            "{}: the registered warp maps the fixed volume outside the moving volume: no inverse to write",
            path.display()
        )));
    }
    let target = Aabb::new(Point3::from_array(lo), Point3::from_array(hi));
    bar.set("inverting the warp", 0, 1);
    let (inverse, report) = invert::invert(u, fixed_box, target, &invert::InvertParams::default())
        .map_err(|e| Failure::Internal(anyhow!("{}: inverting the registered warp: {e}", path.display())))?;
    let (dims, lps_from_index) = (moving.dims, moving.lps_from_index);
    warpbench_io::volume::check_allocation(path, dims, 12, warpbench_io::volume::DEFAULT_MAX_VOXEL_BYTES)?;
    let sampled = sample_displacements(&inverse, dims, &lps_from_index, &mut |done, total| {
        bar.set("sampling the inverse", done, total);
        true
    })
    .ok_or_else(|| Failure::Internal(anyhow!("sampling the inverse stopped")))?;
    crate::field::write_displacements(
        path,
        format,
        FieldDirection::Forward,
        dims,
        &lps_from_index,
        &sampled.displacements_lps,
    )?;
    Ok(InverseConsistency { rms_mm: report.rms_mm, max_mm: report.max_mm, points: report.check_points })
}

/// `image` read only inside `mask` ([`RefineInputs::fixed_mask`]); `names` are the mask's and the volume's.
///
/// # Errors
/// [`Failure::BadInput`] when the mask keeps fewer voxels than a registration samples at least.
fn masked<S: Space>(image: &Image<S>, mask: &Volume, [mask_name, volume_name]: [&str; 2]) -> Result<Image<S>, Failure> {
    let mask_image = Image::<S>::from_volume(mask, Parallelism::Rayon)
        .map_err(|e| Failure::BadInput(anyhow!("{mask_name}: {e}")))?;
    let (image, kept) = image
        .keep_inside(&mask_image, Parallelism::Rayon)
        .map_err(|e| Failure::BadInput(anyhow!("{mask_name}: {e}")))?;
    if kept < MIN_SAMPLES_INSIDE {
        return Err(Failure::BadInput(anyhow!(
            "{mask_name}: the mask keeps {kept} voxels of {volume_name} (nonzero mask voxels nearest to its voxel \
             centres); the registration needs at least {MIN_SAMPLES_INSIDE}"
        )));
    }
    Ok(image)
}

/// Runs `warpbench register`: checks the outputs, loads, fits the start, registers, writes the field (and the warped
/// volume) atomically; prints the JSON summary to `out` with `--json`, else what it wrote on stderr unless `--quiet`.
pub fn run(args: RegisterArgs, out: &mut dyn Write) -> Result<RegisterSummary, Failure> {
    let RegisterArgs {
        volumes,
        pairs,
        out_field,
        out: out_volume,
        out_inverse_field,
        format,
        metric,
        grid_mm,
        levels,
        landmark_weight,
        bending_weight,
        samples,
        iterations,
        seed,
        fixed_mask,
        moving_mask,
        backend,
        report,
    } = args;
    let ReportArgs { json, force, quiet } = report;
    let format_arg = format;
    let format = format_arg.flavour_for(&out_field);
    let given = LandmarkWarp::try_from(PairArgs::from(pairs)).map_err(Failure::BadInput)?;
    let volumes = given.volumes(volumes, quiet).map_err(Failure::BadInput)?;
    // The session's choices for Refine by intensities, where the command line does not make them.
    let session = given.session_refine.clone();
    let metric = metric.or(session.as_ref().map(|s| s.metric)).unwrap_or_default();
    let fixed_mask = fixed_mask.or(session.as_ref().and_then(|s| s.fixed_mask.clone()));
    let moving_mask = moving_mask.or(session.and_then(|s| s.moving_mask));
    let params = RegisterParams {
        similarity: metric.similarity(),
        grid_mm,
        levels,
        landmark_weight,
        bending_weight,
        samples,
        max_iterations: iterations,
        seed,
        parallelism: Parallelism::Rayon,
        ..RegisterParams::default()
    };
    let mut input_paths = vec![volumes.fixed.as_path(), volumes.moving.as_path()];
    input_paths.extend(given.paths());
    input_paths.extend(fixed_mask.as_deref());
    input_paths.extend(moving_mask.as_deref());
    let pair_output = format_arg.pair_output(&out_field);
    let field_output = OutputFile { path: out_field.clone(), force };
    if let Some(kind) = pair_output {
        kind.check(&field_output, format_arg, FieldDirection::Pullback, None, &input_paths)?;
    } else {
        crate::field::check_field_output(&field_output, format, &input_paths)?;
    }
    if let Some(path) = &out_inverse_field {
        if path == &out_field || out_volume.as_ref() == Some(path) {
            return Err(Failure::BadInput(anyhow!("{}: --out-inverse-field is another output too", path.display())));
        }
        crate::field::check_field_output(&OutputFile { path: path.clone(), force }, format, &input_paths)?;
    }
    if let Some(path) = &out_volume {
        if path == &out_field {
            return Err(Failure::BadInput(anyhow!("{}: --out and --out-field are the same file", path.display())));
        }
        inputs::check_output(path, &input_paths, force).map_err(Failure::BadInput)?;
        crate::warp::check_data_file(path, &input_paths, force).map_err(Failure::BadInput)?;
        crate::warp::check_outputs(path, None).map_err(Failure::BadInput)?;
    }
    params.validate().map_err(|e| Failure::BadInput(anyhow!("{e}")))?;
    let choice = crate::gpu_samples::choose(backend.into(), params.similarity).map_err(|e| {
        if crate::gpu_samples::reads(params.similarity) {
            Failure::Internal(anyhow!("--backend gpu: {e}"))
        } else {
            Failure::BadInput(anyhow!("{e}"))
        }
    })?;
    let (gpu, device, cpu_fallback) = match &choice {
        SampleDeviceChoice::Cpu { note } => (None, "cpu".to_owned(), note.clone()),
        SampleDeviceChoice::Gpu(ctx) => {
            let gpu = GpuSamples::new(ctx).map_err(|e| Failure::Internal(anyhow!("registering on the GPU: {e}")))?;
            (Some(gpu), format!("gpu: {}", ctx.describe()), None)
        }
    };
    given.warp.check_start().map_err(Failure::BadInput)?;
    let (fixed_volume, moving_volume) = inputs::load_pair(&volumes, quiet).map_err(Failure::BadInput)?;
    let inputs::VolumePair { fixed, moving, .. } = volumes;
    if let Some(path) = &out_volume {
        crate::warp::check_output_grid(path, &fixed_volume).map_err(Failure::BadInput)?;
    }
    if format == FieldFormat::Ngff {
        let grids = [
            (Some(&out_field).filter(|_| pair_output.is_none()), &fixed_volume),
            (out_inverse_field.as_ref(), &moving_volume),
        ];
        for (path, grid) in grids {
            if let Some(path) = path {
                warpbench_io::ngff::check_grid(path, &grid.lps_from_index).map_err(|e| Failure::BadInput(e.into()))?;
            }
        }
    }
    let start_transform = given.warp.start(&fixed_volume, &moving_volume).map_err(Failure::BadInput)?;
    let (fixed_name, moving_name) = (fixed.display().to_string(), moving.display().to_string());
    let load_mask = |mask: &Option<PathBuf>| match mask {
        Some(path) => {
            inputs::load_volume(&inputs::VolumeArg::other(path), quiet).map(|v| Some((v, path.display().to_string())))
        }
        None => Ok(None),
    };
    let masks =
        [load_mask(&fixed_mask).map_err(Failure::BadInput)?, load_mask(&moving_mask).map_err(Failure::BadInput)?];
    let (pairs, origin, method, brushed) = match &given.landmarks {
        Some(landmarks) => {
            let brushed =
                crate::brushed::Brushed::new(&given.warp.brush, &landmarks.describe()).map_err(Failure::BadInput)?;
            (landmarks.pairs().map_err(Failure::BadInput)?, landmarks.describe(), given.method(), brushed)
        }
        None => (&[][..], String::new(), given.method(), None),
    };
    let method = method.map_err(Failure::BadInput)?;
    let inputs = RefineInputs {
        fixed: &fixed_volume,
        moving: &moving_volume,
        names: [&fixed_name, &moving_name],
        pairs,
        origin: &origin,
        method: &method,
        fixed_mask: masks[0].as_ref().map(|(volume, name)| (volume, name.as_str())),
        moving_mask: masks[1].as_ref().map(|(volume, name)| (volume, name.as_str())),
    };
    let bar = Bar::new(quiet);
    let mut layers = Layers::new(start_transform, brushed);
    layers.field = given.warp.field(&fixed_volume, &moving_volume).map_err(Failure::BadInput)?;
    crate::inputs::note_field_warnings(layers.field.as_deref(), quiet);
    let refinement = refine(inputs, layers, &params, gpu.as_ref().map(|g| g as &dyn SampleDevice), &mut |p| {
        bar.set("registering", (p.fraction() * 1000.0) as u64, 1000);
        ControlFlow::Continue(())
    })?;
    let u = refinement.pullback();
    let residuals = refinement.residuals();

    let (dims, lps_from_index) = (fixed_volume.dims, fixed_volume.lps_from_index);
    warpbench_io::volume::check_allocation(&out_field, dims, 12, warpbench_io::volume::DEFAULT_MAX_VOXEL_BYTES)?;
    let sampled = sample_displacements(&u, dims, &lps_from_index, &mut |done, total| {
        bar.set("sampling the field", done, total);
        true
    })
    .ok_or_else(|| Failure::Internal(anyhow!("sampling the field stopped")))?;
    let Some(max_displacement_mm) = sampled.max_norm_mm else {
        return Err(Failure::Internal(anyhow!("the registered warp is not finite somewhere in the fixed grid")));
    };
    if let Some(kind) = pair_output {
        kind.write(
            &out_field,
            (dims, &lps_from_index),
            (moving_volume.dims, &moving_volume.lps_from_index),
            &sampled.displacements_lps,
        )?;
    } else {
        crate::field::write_displacements(
            &out_field,
            format,
            FieldDirection::Pullback,
            dims,
            &lps_from_index,
            &sampled.displacements_lps,
        )?;
    }
    let inverse_consistency = match &out_inverse_field {
        Some(path) => Some(write_inverse(&u, [&fixed_volume, &moving_volume], path, format, &bar)?),
        None => None,
    };
    if let Some(path) = &out_volume {
        let field = SampledField::<Moving, Fixed>::new(dims, lps_from_index, sampled.displacements_lps)
            .map_err(|e| Failure::Internal(anyhow!("{}: {e}", out_field.display())))?;
        let names =
            Names { moving: moving_name.clone(), landmarks: refinement.start_name.clone(), out: path.to_owned() };
        let resampled =
            crate::warp::resample_through_field(&fixed_volume, &moving_volume, field, &out_field, &names, &mut |p| {
                bar.set("resampling", p.slices_done as u64, p.slices_total as u64);
                true
            })?;
        let description = crate::warp::series_description("registered", &moving);
        crate::warp::write_outputs(&resampled.volume, path, None, &description, None)?;
    }
    bar.finish();

    let summary = RegisterSummary {
        schema: SCHEMA,
        out_field: out_field.display().to_string(),
        out: out_volume.as_ref().map(|p| p.display().to_string()),
        out_inverse_field: out_inverse_field.as_ref().map(|p| p.display().to_string()),
        inverse_consistency,
        format: pair_output.map_or(format.name(), crate::field::PairOutput::name),
        start: refinement.start_name.clone(),
        settings: RegisterSettings {
            metric: params.similarity,
            grid_mm,
            levels,
            landmark_weight,
            bending_weight,
            samples,
            iterations,
            seed,
            fixed_mask: fixed_mask.as_ref().map(|p| p.display().to_string()),
            moving_mask: moving_mask.as_ref().map(|p| p.display().to_string()),
        },
        pairs: refinement.kept.moving.len(),
        levels: refinement.registration.levels.clone(),
        residuals,
        jacobian: refinement.jacobian.into(),
        max_displacement_mm,
        register_s: refinement.register_s,
        device,
        cpu_fallback,
    };
    if json {
        crate::exit::print_json(out, &summary, "the JSON summary")?;
    } else if !quiet {
        let last = summary.levels.last();
        let worst = summary.residuals.iter().map(|r| r.residual_mm).fold(0.0, f64::max);
        eprintln!(
            "wrote {} ({} field; registered from {} under {} pairs (worst {:.2} mm), {} {:.4}, min det ∇u \
             {:.3}, max |D| {:.2} mm, {:.1} s)",
            summary.out_field,
            summary.format,
            summary.start,
            summary.pairs,
            worst,
            summary.settings.metric,
            last.map_or(0.0, |l| l.similarity),
            summary.jacobian.min_det,
            summary.max_displacement_mm,
            summary.register_s
        );
        if let Some(path) = &summary.out {
            eprintln!("wrote {path}");
        }
    }
    Ok(summary)
}
