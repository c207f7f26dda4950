//! `warpbench transform` (and `field --tfm`): the pull-back u = `moving_from_fixed` as an ITK transform file, the
//! transform itself rather than a sampled field.
//!
//! ITK applies a transform file in LPS mm, our patient space, and a transform used for resampling maps output
//! (fixed) points to input (moving) points: u, as `warpbench warp` and `field` use it.
//! [`crate::project::stack::itk_transform_of`] writes each method as the ITK class that holds it exactly:
//!
//! - **TPS** → `ThinPlateSplineKernelTransform_double_3_3`, source landmarks = the spline's centres (the fixed
//!   points), target landmarks = u(centres). ITK's 3-D kernel is G(r) = r·I and its spline is affine + Σ wᵢ r, the
//!   same family as ours (U(r) = r), and ITK solves the interpolating system
//!
//!   ```text
//!   [K  P] [w]   [u(c)]
//!   [Pᵀ 0] [a] = [ 0  ]
//!   ```
//!
//!   on reading. With λ = 0, u(cᵢ) = pᵢ and this is our system. With λ > 0 our smoothing spline solves
//!   (K + λI) w + P a = p, Pᵀ w = 0, so its values at the centres are u(c) = K w + P a = p − λ w: the same (w, a)
//!   solve the interpolating system through u(c), which has one solution. So the file is the same transform for every
//!   stiffness; what ITK cannot hold is λ itself and the moving landmarks pᵢ (a stiffness in ITK's `SetStiffness`
//!   is not written to a file), so an ITK user who edits the landmarks gets an interpolating spline again.
//! - **Hierarchical B-spline** → one `BSplineTransform_double_3_3`: the solver already keeps the hierarchy as one
//!   refined lattice (each coarser level is refined into the finest exactly, and the affine initial approximation is
//!   reproduced by the cubic basis exactly), so the file holds the finest lattice's coefficients: grid size = cells +
//!   3, grid origin = domain min − one spacing, identity direction. Inside the lattice's domain (the fixed volume's
//!   voxel-edge box) ITK's evaluation is ours; outside it ITK's `BSplineTransform` is the identity, while warpbench
//!   holds the displacement at the box's edge (it clamps): the two differ only outside the fixed volume, where
//!   `warp` and `field` never sample.
//! - **Affine, similarity, rigid** → `AffineTransform_double_3_3` (centre 0, translation = offset).
//!
//! A name ending in `.h5` writes the same class in ITK's HDF5 transform file ([`warpbench_io::itk_h5`]), which can
//! also hold displacement fields and composites: a stack no other transform file holds exactly (a field or a brush)
//! is written there as ITK's composite of its layers, the landmark fit sampled on the fixed grid where ITK has no
//! class for it, or as one `DisplacementFieldTransform` over the whole pull-back sampled on the fixed grid
//! ([`write_h5_stack`]).
//!
//! `--format elastix` writes the same [`warpbench_io::itk_tfm::ItkTransform`] as an elastix transform parameter file
//! ([`warpbench_io::elastix::write`]): `SplineKernelTransform`, `BSplineTransform` or `AffineTransform` over the fixed
//! volume's grid. A stack with a field or a brush, which none of them holds, is written as a
//! `DeformationFieldTransform` over the pull-back sampled on the fixed grid ([`write_field_transform`]): at the grid's
//! voxel centres, where transformix resamples, it is u within the field's f32 rounding.

use std::io::Write;
use std::path::{Path, PathBuf};

use nalgebra::{Matrix4, Vector3};
use serde::Serialize;
use warpbench_io::dicom_reg::{self, DeformableRegistration, MatrixType, SpatialRegistration};
use warpbench_io::dicom_source::DicomSource;
use warpbench_io::displacement::{self, FieldDirection, FieldFormat};
use warpbench_io::elastix::{self, ElastixGrid};
use warpbench_io::geometry::{Index, Lps, Transform};
use warpbench_io::itk_h5::{self, H5Transform};
use warpbench_io::itk_tfm::{self, ItkAffine, ItkTransform};
use warpbench_io::transform_file;
use warpbench_io::{Volume, afni, fsl, lta, volume};
use warpbench_solver::method::FittedWarp;
use warpbench_solver::spaces::Fixed;

use crate::args::{PairArgs, ReportArgs, VolumePairArgs, help};
use crate::exit::Failure;
use crate::field::FieldInputs;
use crate::fit;
use crate::inputs::{self, OutputFile, PairInputs};
use crate::progress::with_bar;
use crate::project::stack::{ItkComposite, ItkRest, Layers};

/// The `--json` schema name.
pub const SCHEMA: &str = "warpbench-transform/1";

/// What `warpbench transform --help` says above the options; its first paragraph is the summary that `-h` and
/// `warpbench --help` show.
const HELP: &str = "\
Write the landmark warp as an ITK transform file (.tfm), the exact transform instead of a sampled field: TPS
as ThinPlateSplineKernelTransform_double_3_3 (any stiffness: the file is the same function), the hierarchical
B-spline as one BSplineTransform_double_3_3 (its finest lattice, exact inside the fixed volume's box; ITK is the
identity outside it), affine, similarity and rigid as AffineTransform_double_3_3. Name the file .h5 for ITK's
HDF5 transform file (what Slicer saves and ANTs writes as Composite.h5): the same class, and for a warp with a
field or brush strokes, which no other ITK file holds, ITK's composite of the starting transform, the field's own
transforms and the landmark fit (a TPS or a brush sampled on the fixed grid), or for a forward field or a brush
alone a DisplacementFieldTransform of the warp sampled on the fixed grid.

The file maps fixed points to moving points (u = moving_from_fixed, LPS mm): what ITK's ResampleImageFilter,
antsApplyTransforms and Slicer need to resample the moving volume onto the fixed one. SimpleITK reads the affine
and B-spline files; Slicer reads all three (Data > Add data, then apply the transform to the moving volume).

--format elastix writes the same transform as an elastix transform parameter file instead, which transformix
applies: SplineKernelTransform (ThinPlateSpline), BSplineTransform or AffineTransform. A session with a field or
brush strokes, which no transform file holds exactly, is written for elastix as a DeformationFieldTransform over its
field sampled on the fixed grid, saved beside it as NAME.field.mha (run transformix from the folder you ran this in).

--format dicom writes a DICOM registration (one .dcm, modality REG) between two DICOM series, for planning systems
and PACS: a Spatial Registration for a linear warp (its matrix maps the moving series' patient coordinates to the
fixed series'), a Deformable Spatial Registration of the warp sampled on the fixed grid for any other.

--format fsl writes FSL's FLIRT matrix (.mat, text) for a linear warp: from the moving volume's FSL coordinates to
the fixed volume's, for flirt -applyxfm -init with the moving volume as -in and the fixed one as -ref. --format afni
writes AFNI's matrix file (.aff12.1D) for 3dAllineate -1Dmatrix_apply, between volumes that are not oblique.
--format lta writes FreeSurfer's LTA (.lta, LINEAR_RAS_TO_RAS) with the moving volume as its src and the fixed one
as its dst, for mri_vol2vol --mov MOVING --targ FIXED --lta. --initial takes each of them, read against --fixed and
--moving.

    warpbench transform --fixed ct.nii.gz --moving mr.nii.gz --landmarks pairs.csv --method tps --out mr_to_ct.tfm
    warpbench transform --fixed ct.nii.gz --moving mr.nii.gz --session case.warpbench.json --out mr_to_ct.h5
    warpbench transform --fixed ct.nii.gz --moving mr.nii.gz --landmarks pairs.csv --format elastix --out TransformParameters.0.txt
    warpbench transform --fixed ct_series/ --moving mr_series/ --landmarks pairs.csv --method rigid --format dicom --out reg.dcm
    warpbench transform --fixed ct.nii.gz --moving mr.nii.gz --landmarks pairs.csv --method rigid --format fsl --out mr_to_ct.mat
    warpbench transform --fixed orig.mgz --moving pet.nii.gz --landmarks pairs.csv --method rigid --format lta --out pet_to_t1.lta";

/// The arguments of `warpbench transform`.
#[derive(Debug, clap::Args)]
#[command(about = crate::args::summary(HELP), long_about = HELP)]
#[command(mut_args(help(&[
    ("fixed", "The fixed volume (NIfTI, NRRD or a DICOM series folder): its box checks the landmarks and is the B-spline's domain"),
    ("moving", "The moving volume: its box checks the landmarks"),
])))]
#[command(mut_args(crate::args::or_session))]
pub struct TransformArgs {
    #[command(flatten)]
    pub volumes: VolumePairArgs,
    #[command(flatten)]
    pub pairs: PairArgs,
    /// The ITK transform file to write (.tfm or .txt; .h5, ITK's HDF5 file; .mat, ANTs' MATLAB file, for the
    /// linear methods), with --format elastix an elastix transform parameter file (e.g. TransformParameters.0.txt),
    /// with --format dicom a DICOM registration (.dcm), with --format lta FreeSurfer's .lta.
    #[arg(long, value_name = "FILE")]
    pub out: PathBuf,
    /// itk (default): an ITK transform file (ITK's HDF5 or ANTs' .mat by its name); elastix: an elastix transform
    /// parameter file, which transformix applies (SplineKernelTransform, BSplineTransform or AffineTransform; a
    /// DeformationFieldTransform over a field beside it for a session with a field or a brush); dicom: a DICOM
    /// (Deformable) Spatial Registration between two DICOM series; fsl, afni, lta: FSL's FLIRT matrix, AFNI's
    /// .aff12.1D or FreeSurfer's .lta, for a linear warp.
    #[arg(long, value_enum, default_value = "itk")]
    pub format: TransformFormat,
    #[command(flatten)]
    pub report: ReportArgs,
}

/// `--format`: whose transform file `transform` writes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum TransformFormat {
    /// ITK's `.tfm` (its HDF5 file for a name ending `.h5`, ANTs' `.mat` for one ending `.mat`).
    Itk,
    /// elastix's transform parameter file.
    Elastix,
    /// A DICOM registration object (`.dcm`, modality REG) between two DICOM series: a Spatial Registration for a
    /// linear warp, a Deformable Spatial Registration otherwise.
    Dicom,
    /// FSL's FLIRT matrix (`flirt -omat`) between the two volumes, for a linear warp.
    Fsl,
    /// AFNI's matrix file (`.aff12.1D`, `3dAllineate -1Dmatrix_apply`), for a linear warp between volumes that are not
    /// oblique.
    Afni,
    /// FreeSurfer's LTA (`.lta`, `mri_vol2vol --lta`), for a linear warp: src the moving volume, dst the fixed one.
    Lta,
    /// An MNI transform file (`.xfm`, `mincresample -transformation`), for a linear warp: the moving volume's world to
    /// the fixed one's, RAS mm.
    Minc,
}

impl TransformFormat {
    /// `itk`, `elastix`, `dicom`, `fsl`, `afni`, `lta` or `minc`.
    #[must_use]
    pub const fn name(self) -> &'static str {
        match self {
            Self::Itk => "itk",
            Self::Elastix => "elastix",
            Self::Dicom => "dicom",
            Self::Fsl => "fsl",
            Self::Afni => "afni",
            Self::Lta => "lta",
            Self::Minc => "minc",
        }
    }
}

/// The volumes a transform is written for, with the files they were read from: a DICOM registration names their
/// series.
#[derive(Clone, Copy, Debug)]
pub struct VolumePair<'a> {
    pub fixed: &'a Volume,
    pub moving: &'a Volume,
    pub fixed_path: Option<&'a Path>,
    pub moving_path: Option<&'a Path>,
}

/// What [`write_transform`] wrote.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Written {
    /// An ITK transform file of the transform's class.
    Itk,
    /// An elastix parameter file of this `(Transform …)`.
    Elastix(&'static str),
    /// A DICOM Spatial Registration with this Frame of Reference Transformation Matrix Type.
    Dicom(MatrixType),
    /// FSL's FLIRT matrix.
    Fsl,
    /// AFNI's matrix file.
    Afni,
    /// FreeSurfer's LTA.
    Lta,
    /// An MNI transform file.
    Minc,
}

impl Written {
    /// How messages name what was written: the elastix class, the DICOM matrix type, FLIRT's or AFNI's matrix, else
    /// `itk_class`.
    #[must_use]
    pub const fn class(self, itk_class: &'static str) -> &'static str {
        match self {
            Self::Itk => itk_class,
            Self::Fsl => "FLIRT matrix",
            Self::Afni => "AFNI matrix",
            Self::Lta => "LTA",
            Self::Minc => "MNI transform",
            Self::Elastix(class) => class,
            Self::Dicom(kind) => kind.name(),
        }
    }
}

/// What was written: the `--json` document, schema `warpbench-transform/1` (docs/cli.md).
#[derive(Clone, Debug, Serialize)]
pub struct TransformSummary {
    pub schema: &'static str,
    pub out: String,
    /// The ITK class that holds the transform (on a `.tfm`'s `Transform:` line); `CompositeTransform_double_3_3`
    /// for an `.h5` of several members.
    pub itk_class: &'static str,
    /// An `.h5` composite's members, in ITK's order (the last is applied first); the one class of any other file.
    pub members: Vec<&'static str>,
    /// `itk`, `elastix`, `dicom`, `fsl`, `afni` or `lta`: whose file was written.
    pub format: &'static str,
    /// With `--format elastix`, the file's `(Transform …)`: `SplineKernelTransform`, `BSplineTransform`,
    /// `AffineTransform`, or `DeformationFieldTransform` for a stack with a field or a brush; else null.
    pub elastix_transform: Option<&'static str>,
    /// With `--format dicom`, the Frame of Reference Transformation Matrix Type written: `RIGID`, `RIGID_SCALE` or
    /// `AFFINE`; else null.
    pub dicom_matrix_type: Option<&'static str>,
    /// The field a `DeformationFieldTransform` names, written beside it; else null.
    pub field: Option<String>,
    /// The method as fitted, e.g. `tps`, `tps(λ=0.5)`, `hbspline(4 levels)`, `affine`.
    pub method: String,
    /// Landmark pairs used (active, with both points).
    pub pairs: usize,
    /// `moving_from_fixed`: the file maps fixed points to moving points (LPS mm), as ITK's resampler uses it; for
    /// `--format dicom`, `fsl` and `lta` `fixed_from_moving`, the file's matrix's direction (moving coordinates to
    /// fixed ones).
    pub map: &'static str,
    /// For a B-spline, the box (LPS mm, min then max) outside which ITK applies the identity; else null.
    pub domain_lps: Option<[[f64; 3]; 2]>,
    /// What the fit found suspicious in the pairs, as printed on stderr.
    pub warnings: Vec<String>,
}

/// The pull-back as the exact transform that holds it, with what the reports say of it.
#[derive(Clone, Debug)]
pub struct ExactTransform {
    pub transform: ItkTransform,
    /// The warp's name in reports (e.g. `tps on start.tfm`).
    pub method: String,
    /// Landmark pairs used.
    pub pairs: usize,
    /// What the fit found suspicious in the pairs.
    pub warnings: Vec<String>,
    /// For a B-spline, the box (LPS mm, min then max) outside which ITK and elastix apply the identity.
    pub domain_lps: Option<[[f64; 3]; 2]>,
}

/// The core under `warpbench transform` and the window's transform export: checks the pairs, fits the pull-back over
/// the fixed box on the stack of `inputs.layers`, and returns the transform that holds it exactly.
///
/// # Errors
/// Bad pairs, a failed fit, or a stack no transform file holds (a field or a brush layer: the message says to write
/// a displacement field instead).
pub fn exact_transform(inputs: &FieldInputs) -> Result<ExactTransform, Failure> {
    let FieldInputs { fixed, moving, pairs, names, method, layers } = *inputs;
    let c = inputs::check_pairs(&names.landmarks, pairs, moving, fixed, layers.min_pairs(method))
        .map_err(Failure::BadInput)?;
    let warnings = fit::fit_warnings(method, &c);
    let moving_from_fixed = fit::pullback_stack(method, &c, inputs::volume_box::<Fixed>(fixed), layers.clone())
        .map_err(Failure::BadInput)?;
    let transform = moving_from_fixed.itk_transform().map_err(Failure::BadInput)?;
    let domain_lps = match moving_from_fixed.as_fitted() {
        Some(FittedWarp::BSpline(spline)) => Some([spline.lattice().min_mm(), spline.lattice().max_mm()]),
        _ => None,
    };
    Ok(ExactTransform {
        transform,
        method: layers.describe(method, c.moving.len()),
        pairs: c.moving.len(),
        warnings,
        domain_lps,
    })
}

/// Refuses a name `format` cannot be written to, before anything is computed: an elastix parameter file named `.mat`
/// (ANTs' binary affine) or `.h5` (ITK would read it as HDF5).
///
/// # Errors
/// That name, in words.
pub fn check_transform_name(path: &Path, format: TransformFormat) -> Result<(), Failure> {
    let extension = |e: &str| path.extension().is_some_and(|x| x.eq_ignore_ascii_case(e));
    if format == TransformFormat::Elastix && (extension("mat") || itk_tfm::is_hdf5_name(path)) {
        return Err(Failure::BadInput(anyhow::anyhow!(
            "{}: an elastix transform parameter file is text, not a .mat or an HDF5 file; name it e.g. \
             TransformParameters.0.txt",
            path.display()
        )));
    }
    if format == TransformFormat::Fsl && (extension("tfm") || extension("dcm") || itk_tfm::is_hdf5_name(path)) {
        return Err(Failure::BadInput(anyhow::anyhow!(
            "{}: FSL's FLIRT matrix is a text file of four lines, not an ITK, HDF5 or DICOM file; name it as \
             `flirt -omat` does, e.g. mr_to_ct.mat",
            path.display()
        )));
    }
    if format == TransformFormat::Afni
        && (extension("tfm") || extension("dcm") || extension("mat") || itk_tfm::is_hdf5_name(path))
    {
        return Err(Failure::BadInput(anyhow::anyhow!(
            "{}: AFNI's matrix file is text; name it as 3dAllineate -1Dmatrix_save does, e.g. mr_to_ct.aff12.1D",
            path.display()
        )));
    }
    if format == TransformFormat::Lta && !extension("lta") {
        return Err(Failure::BadInput(anyhow::anyhow!(
            "{}: FreeSurfer tells its transform files by their names: name an LTA .lta, e.g. mr_to_ct.lta",
            path.display()
        )));
    }
    if format == TransformFormat::Minc && !extension("xfm") {
        return Err(Failure::BadInput(anyhow::anyhow!(
            "{}: MINC's tools tell a transform file by its name: name it .xfm, e.g. mr_to_ct.xfm",
            path.display()
        )));
    }
    if format == TransformFormat::Dicom && !extension("dcm") {
        return Err(Failure::BadInput(anyhow::anyhow!(
            "{}: a DICOM registration is written to one file named .dcm, e.g. mr_to_ct_reg.dcm",
            path.display()
        )));
    }
    Ok(())
}

/// Writes `exact`'s transform to `path` in `format`, atomically: an ITK `.tfm` (its HDF5 file or ANTs' `.mat` for a
/// name ending so, [`transform_file::write`]), an elastix parameter file over the fixed volume's grid, or a DICOM
/// Spatial Registration between the two DICOM series `pair` was read from ([`write_dicom_registration`];
/// [`write_dicom`] also writes the deformable ones, and is what the command line and the window call for DICOM).
///
/// # Errors
/// What the writers refuse (a TPS or B-spline to `.mat` or DICOM, a name that does not fit, numbers that are not
/// finite, volumes that are not DICOM series for DICOM).
pub fn write_transform(
    path: &Path,
    exact: &ExactTransform,
    format: TransformFormat,
    pair: VolumePair,
) -> Result<Written, Failure> {
    check_transform_name(path, format)?;
    let transform = &exact.transform;
    Ok(match format {
        TransformFormat::Itk => {
            transform_file::write(path, transform)?;
            Written::Itk
        }
        TransformFormat::Elastix => {
            let grid = ElastixGrid { dims: pair.fixed.dims, lps_from_index: pair.fixed.lps_from_index };
            elastix::write(path, transform, &grid)?;
            Written::Elastix(elastix::transform_name(transform))
        }
        TransformFormat::Dicom => Written::Dicom(write_dicom_registration(path, exact, pair)?),
        TransformFormat::Fsl => {
            let (fixed, moving) = (pair.fixed, pair.moving);
            write_flirt(path, transform, (fixed.dims, &fixed.lps_from_index), (moving.dims, &moving.lps_from_index))?;
            Written::Fsl
        }
        TransformFormat::Afni => {
            write_afni(path, transform, &pair.fixed.lps_from_index, &pair.moving.lps_from_index)?;
            Written::Afni
        }
        TransformFormat::Lta => {
            let name = |p: Option<&Path>| p.map(|p| p.display().to_string()).unwrap_or_default();
            let fixed = ((pair.fixed.dims, &pair.fixed.lps_from_index), name(pair.fixed_path));
            let moving = ((pair.moving.dims, &pair.moving.lps_from_index), name(pair.moving_path));
            write_lta(path, transform, (fixed.0, &fixed.1), (moving.0, &moving.1))?;
            Written::Lta
        }
        TransformFormat::Minc => {
            write_xfm(path, transform)?;
            Written::Minc
        }
    })
}

/// Writes the affine `transform` (the pull-back, LPS mm) as FreeSurfer's LTA between the `fixed` volume, its dst, and
/// the `moving` one, its src, each a grid with the file it was read from ([`warpbench_io::lta`]).
///
/// # Errors
/// A transform that is not affine (an LTA holds nothing else), or what the writer refuses.
pub fn write_lta(
    path: &Path,
    transform: &ItkTransform,
    fixed: (fsl::Grid, &str),
    moving: (fsl::Grid, &str),
) -> Result<(), Failure> {
    check_transform_name(path, TransformFormat::Lta)?;
    let u = affine_matrix(path, transform, "FreeSurfer's LTA")?;
    lta::write(path, &u, fixed, moving)?;
    Ok(())
}

/// Writes the affine `transform` (the pull-back, LPS mm) as an MNI transform file: its inverse, the moving volume's
/// world to the fixed one's, RAS mm ([`warpbench_io::mni_xfm`]).
///
/// # Errors
/// A transform that is not affine (the file written holds a linear one), or what the writer refuses.
pub fn write_xfm(path: &Path, transform: &ItkTransform) -> Result<(), Failure> {
    check_transform_name(path, TransformFormat::Minc)?;
    let u = affine_matrix(path, transform, "an MNI transform file")?;
    warpbench_io::mni_xfm::write(path, &u)?;
    Ok(())
}

/// Writes the affine `transform` (the pull-back, LPS mm) as AFNI's matrix file between volumes whose grids are
/// `fixed` (AFNI's base) and `moving` (its source), neither oblique ([`warpbench_io::afni`]).
///
/// # Errors
/// A transform that is not affine, an oblique volume, or what the writer refuses.
pub fn write_afni(
    path: &Path,
    transform: &ItkTransform,
    fixed: &Transform<Lps, Index>,
    moving: &Transform<Lps, Index>,
) -> Result<(), Failure> {
    let u = affine_matrix(path, transform, "AFNI's matrix file")?;
    afni::check_cardinal(path, "fixed", fixed)?;
    afni::check_cardinal(path, "moving", moving)?;
    afni::write(path, &u)?;
    Ok(())
}

/// The refusal of a warp with a field (`field`) or else a brush as a layer, for a `format` that holds an affine only
/// (FSL's, AFNI's); `None` for the formats that hold more.
#[must_use]
pub fn affine_only(out: &Path, format: TransformFormat, field: bool) -> Option<Failure> {
    let what = match format {
        TransformFormat::Fsl => "FSL's FLIRT matrix",
        TransformFormat::Afni => "AFNI's matrix file",
        TransformFormat::Lta => "FreeSurfer's LTA",
        TransformFormat::Minc => "an MNI transform file",
        TransformFormat::Itk | TransformFormat::Elastix | TransformFormat::Dicom => return None,
    };
    Some(Failure::BadInput(anyhow::anyhow!(
        "{}: {what} holds an affine only, and this warp has {} as a layer: write it as a displacement field or as \
         ITK's HDF5 transform file (a name ending .h5)",
        out.display(),
        if field { "a displacement field" } else { "brush strokes" }
    )))
}

/// The affine `transform` as a 4 × 4 matrix; `what` names the file format that holds nothing else, in the refusal.
fn affine_matrix(path: &Path, transform: &ItkTransform, what: &str) -> Result<Matrix4<f64>, Failure> {
    let ItkTransform::Affine(affine) = transform else {
        return Err(Failure::BadInput(anyhow::anyhow!(
            "{}: {what} holds an affine only, not a {}: use --method affine, similarity or rigid (or a starting \
             transform alone), or write the deformable warp as a displacement field",
            path.display(),
            transform.type_name()
        )));
    };
    let mut u = Matrix4::identity();
    u.fixed_view_mut::<3, 3>(0, 0).copy_from(&affine.matrix);
    u.fixed_view_mut::<3, 1>(0, 3).copy_from(&Vector3::from(affine.offset()));
    Ok(u)
}

/// Writes the affine `transform` (the pull-back, LPS mm) as FSL's FLIRT matrix between the `fixed` grid, FLIRT's
/// reference, and the `moving` one, its input ([`warpbench_io::fsl`]).
///
/// # Errors
/// A transform that is not affine (a FLIRT matrix holds nothing else), or what the writer refuses.
pub fn write_flirt(path: &Path, transform: &ItkTransform, fixed: fsl::Grid, moving: fsl::Grid) -> Result<(), Failure> {
    let u = affine_matrix(path, transform, "FSL's FLIRT matrix")?;
    fsl::write(path, &fsl::flirt_from(path, &u, fixed, moving)?)?;
    Ok(())
}

/// What [`write_dicom`] wrote.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum DicomRegistration {
    /// A Spatial Registration whose matrix is of this type (a linear warp).
    Spatial(MatrixType),
    /// A Deformable Spatial Registration: the pull-back sampled on the fixed grid, moving points up to this far (mm).
    Deformable { max_displacement_mm: f64 },
}

/// The DICOM registration [`write_dicom`] wrote, with what reports say of the warp.
#[derive(Clone, Debug)]
pub struct DicomExport {
    pub registration: DicomRegistration,
    /// The warp's name in reports.
    pub method: String,
    pub pairs: usize,
    pub warnings: Vec<String>,
}

/// The DICOM series `pair` was read from, each as a [`DicomSource`].
///
/// # Errors
/// A volume not read from a file, or from a file or folder that is not DICOM, naming `out` and the volume.
fn dicom_sources(out: &Path, pair: VolumePair) -> Result<(DicomSource, DicomSource), Failure> {
    let source = |side: &str, volume: &Volume, at: Option<&Path>| -> Result<DicomSource, Failure> {
        let not_dicom = |what: String| {
            Failure::BadInput(anyhow::anyhow!(
                "{}: a DICOM registration relates two DICOM series, and the {side} volume {what}",
                out.display()
            ))
        };
        let at = at.ok_or_else(|| not_dicom("was not read from a file".into()))?;
        DicomSource::for_volume(at, volume)?.ok_or_else(|| not_dicom(format!("{} is not DICOM", at.display())))
    };
    Ok((source("fixed", pair.fixed, pair.fixed_path)?, source("moving", pair.moving, pair.moving_path)?))
}

/// Writes the pull-back of `made_of` as a DICOM registration between the two DICOM series `pair` was read from: a
/// Spatial Registration ([`write_dicom_registration`]) when the warp is linear, else a Deformable Spatial Registration
/// of the pull-back sampled at the fixed volume's voxel centres by `sample` (as `warpbench field` samples it), which
/// is also what a stack with a field or a brush is written as.
///
/// # Errors
/// A volume not read from DICOM (before anything is fitted), the fit's, the sampling's, the writers'.
pub fn write_dicom(
    path: &Path,
    made_of: &FieldInputs,
    pair: VolumePair,
    sample: &mut dyn FnMut(&FieldInputs) -> Result<crate::field::Field, Failure>,
) -> Result<DicomExport, Failure> {
    let (fixed, moving) = dicom_sources(path, pair)?;
    let layered = made_of.layers.field.is_some() || made_of.layers.brush.is_some();
    if !layered {
        let exact = exact_transform(made_of)?;
        if let ItkTransform::Affine(u) = &exact.transform {
            let description = format!("{} of {} pairs (warpbench)", exact.method, exact.pairs);
            let kind = write_spatial_registration(path, &fixed, &moving, u, &description)?;
            let ExactTransform { method, pairs, warnings, .. } = exact;
            return Ok(DicomExport { registration: DicomRegistration::Spatial(kind), method, pairs, warnings });
        }
    }
    let field = sample(made_of)?;
    write_deformable_registration(path, &fixed, &moving, &field)?;
    Ok(DicomExport {
        registration: DicomRegistration::Deformable { max_displacement_mm: field.max_displacement_mm },
        method: field.method,
        pairs: field.pairs,
        warnings: field.warnings,
    })
}

/// Writes a linear pull-back as a DICOM Spatial Registration ([`warpbench_io::dicom_reg`]): the fixed and the moving
/// volume must each have been read from a DICOM series, whose patient coordinate systems (Frames of Reference) it
/// relates by the matrix M = u⁻¹ (moving → fixed).
///
/// # Errors
/// A deformable transform (no matrix holds it: [`write_dicom`] writes those), a volume not read from DICOM, a series
/// without a Frame of Reference UID, both in one Frame of Reference, or the write's.
pub fn write_dicom_registration(path: &Path, exact: &ExactTransform, pair: VolumePair) -> Result<MatrixType, Failure> {
    let ItkTransform::Affine(u) = &exact.transform else {
        return Err(Failure::BadInput(anyhow::anyhow!(
            "{}: a DICOM Spatial Registration holds a matrix, and the {} warp is not linear",
            path.display(),
            exact.method
        )));
    };
    let (fixed, moving) = dicom_sources(path, pair)?;
    let description = format!("{} of {} pairs (warpbench)", exact.method, exact.pairs);
    write_spatial_registration(path, &fixed, &moving, u, &description)
}

/// Writes the linear pull-back `u` (fixed → moving) as a DICOM Spatial Registration from the series `moving` onto the
/// series `fixed`, whose matrix is u⁻¹ ([`warpbench_io::dicom_reg`]).
///
/// # Errors
/// A `u` that is not invertible, and the writer's.
pub fn write_spatial_registration(
    path: &Path,
    fixed: &DicomSource,
    moving: &DicomSource,
    u: &ItkAffine,
    description: &str,
) -> Result<MatrixType, Failure> {
    let mut moving_from_fixed = Matrix4::identity();
    moving_from_fixed.fixed_view_mut::<3, 3>(0, 0).copy_from(&u.matrix);
    moving_from_fixed.fixed_view_mut::<3, 1>(0, 3).copy_from(&Vector3::from(u.offset()));
    let mut fixed_from_moving = moving_from_fixed.try_inverse().ok_or_else(|| {
        Failure::BadInput(anyhow::anyhow!("{}: the warp ({description}) is not invertible", path.display()))
    })?;
    // The inverse of an affine map is affine: its last row is exactly (0, 0, 0, 1), whatever the rounding.
    fixed_from_moving.set_row(3, &nalgebra::RowVector4::new(0.0, 0.0, 0.0, 1.0));
    let reg = SpatialRegistration { fixed, moving, fixed_from_moving, description: description.to_owned() };
    Ok(dicom_reg::write(path, &reg)?)
}

/// Writes the pull-back `field` (sampled on a grid of the fixed frame) as a DICOM Deformable Spatial Registration from
/// the series `moving` onto the series `fixed` ([`warpbench_io::dicom_reg::write_deformable`]).
///
/// # Errors
/// The writer's.
pub fn write_deformable_registration(
    path: &Path,
    fixed: &DicomSource,
    moving: &DicomSource,
    field: &crate::field::Field,
) -> Result<(), Failure> {
    let reg = DeformableRegistration {
        fixed,
        moving,
        dims: field.dims,
        lps_from_index: field.lps_from_index,
        displacements_lps: &field.displacements_lps,
        description: format!("{} of {} pairs (warpbench)", field.method, field.pairs),
    };
    Ok(dicom_reg::write_deformable(path, &reg)?)
}

/// The field a `DeformationFieldTransform` written to `out` names: beside it, `out`'s name with `.field.mha` for
/// its extension (`TransformParameters.0.txt` → `TransformParameters.0.field.mha`).
#[must_use]
pub fn field_file_beside(out: &Path) -> PathBuf {
    let stem = out.file_stem().map_or_else(|| "transform".into(), |s| s.to_string_lossy().into_owned());
    out.with_file_name(format!("{stem}.field.mha"))
}

/// The name a `DeformationFieldTransform` at `out` gives its field `field_path`, refused before anything is written
/// when elastix cannot read it (not UTF-8, a quote or a control character in it).
///
/// # Errors
/// That name, naming `out`.
pub fn check_field_name<'p>(out: &Path, field_path: &'p Path) -> Result<&'p str, Failure> {
    let name = field_path.to_str().ok_or_else(|| {
        Failure::BadInput(anyhow::anyhow!("{}: elastix needs the field's name in UTF-8", field_path.display()))
    })?;
    elastix::check_field_name(out, name)?;
    Ok(name)
}

/// Runs `warpbench transform`: checks the output, loads, fits the pull-back over the fixed box, writes the file
/// atomically; prints the JSON summary to `out` with `--json`, else a line on stderr unless `--quiet`. With
/// `--format elastix`, a stack no transform file holds exactly (a session's field or brush) is written as a
/// `DeformationFieldTransform` over its sampled field ([`field_file_beside`]).
pub fn run(args: TransformArgs, out: &mut dyn Write) -> Result<TransformSummary, Failure> {
    let TransformArgs { volumes, pairs, out: out_path, format, report: ReportArgs { json, force, quiet } } = args;
    let inputs = PairInputs::new(volumes, pairs, None, quiet).map_err(Failure::BadInput)?;
    let input_paths = inputs.paths();
    OutputFile { path: out_path.clone(), force }.check(&input_paths).map_err(Failure::BadInput)?;
    check_transform_name(&out_path, format)?;
    let layered = !inputs.warp.brush.is_empty() || inputs.warp.base_field.is_some();
    let h5_field = format == TransformFormat::Itk && layered && itk_tfm::is_hdf5_name(&out_path);
    let as_field = format == TransformFormat::Elastix && layered;
    let field_path = field_file_beside(&out_path);
    if as_field {
        check_field_name(&out_path, &field_path)?;
        crate::field::check_field_output(
            &OutputFile { path: field_path.clone(), force },
            FieldFormat::MetaImage,
            &input_paths,
        )?;
    } else if layered && let Some(refusal) = affine_only(&out_path, format, inputs.warp.base_field.is_some()) {
        return Err(refusal);
    } else if !inputs.warp.brush.is_empty() && format == TransformFormat::Itk && !h5_field {
        return Err(Failure::BadInput(anyhow::anyhow!(
            "{}: the session's brush strokes have no exact ITK transform; name the output .h5 for ITK's HDF5 \
             transform file over the warp's displacement field, write the field with `warpbench field --session`, \
             or an elastix file over one with --format elastix",
            inputs.landmarks.describe()
        )));
    }
    let method = inputs.method().map_err(Failure::BadInput)?;
    let brushed = if layered { inputs.brushed().map_err(Failure::BadInput)? } else { None };
    inputs.warp.check_start().map_err(Failure::BadInput)?;
    let volumes = inputs.load_volumes(quiet).map_err(Failure::BadInput)?;
    let start = inputs.start(&volumes.fixed, &volumes.moving).map_err(Failure::BadInput)?;
    let mut layers = Layers::new(start, brushed);
    layers.field = inputs.warp.field(&volumes.fixed, &volumes.moving).map_err(Failure::BadInput)?;
    crate::inputs::note_field_warnings(layers.field.as_deref(), quiet);
    let pairs = inputs.pairs().map_err(Failure::BadInput)?;
    let names = inputs.names(&out_path);
    let made_of = FieldInputs {
        fixed: &volumes.fixed,
        moving: &volumes.moving,
        pairs,
        names: &names,
        method: &method,
        layers: &layers,
    };
    let summary = if format == TransformFormat::Dicom {
        let pair = VolumePair {
            fixed: &volumes.fixed,
            moving: &volumes.moving,
            fixed_path: Some(&inputs.volumes.fixed),
            moving_path: Some(&inputs.volumes.moving),
        };
        let mut sample =
            |m: &FieldInputs| crate::field::sample_field_reporting(&volumes.fixed, m, FieldDirection::Pullback, quiet);
        let export = write_dicom(&out_path, &made_of, pair, &mut sample)?;
        if matches!(export.registration, DicomRegistration::Spatial(_)) && !quiet {
            // The deformable path's sampling prints them.
            for w in &export.warnings {
                eprintln!("warpbench: warning: {w}");
            }
        }
        let (itk_class, dicom_matrix_type) = match export.registration {
            DicomRegistration::Spatial(kind) => ("AffineTransform_double_3_3", Some(kind.name())),
            DicomRegistration::Deformable { .. } => ("DisplacementFieldTransform_double_3_3", None),
        };
        TransformSummary {
            schema: SCHEMA,
            out: out_path.display().to_string(),
            itk_class,
            members: vec![itk_class],
            format: format.name(),
            elastix_transform: None,
            dicom_matrix_type,
            field: None,
            method: layers.describe(&method, export.pairs),
            pairs: export.pairs,
            map: match export.registration {
                DicomRegistration::Spatial(_) => "fixed_from_moving",
                DicomRegistration::Deformable { .. } => "moving_from_fixed",
            },
            domain_lps: None,
            warnings: export.warnings,
        }
    } else if h5_field {
        let written = with_bar(quiet, "sampling the field", |progress| write_h5_stack(&out_path, &made_of, progress))?;
        if !quiet {
            for w in &written.warnings {
                eprintln!("warpbench: warning: {w}");
            }
        }
        TransformSummary {
            schema: SCHEMA,
            out: out_path.display().to_string(),
            itk_class: written.itk_class,
            members: written.members,
            format: format.name(),
            elastix_transform: None,
            dicom_matrix_type: None,
            field: None,
            method: written.method,
            pairs: written.pairs,
            map: "moving_from_fixed",
            domain_lps: None,
            warnings: written.warnings,
        }
    } else if as_field {
        let field = crate::field::sample_field_reporting(&volumes.fixed, &made_of, FieldDirection::Pullback, quiet)?;
        write_field_transform(&out_path, &field_path, &field)?;
        TransformSummary {
            schema: SCHEMA,
            out: out_path.display().to_string(),
            itk_class: "DisplacementFieldTransform_double_3_3",
            members: vec!["DisplacementFieldTransform_double_3_3"],
            format: format.name(),
            elastix_transform: Some("DeformationFieldTransform"),
            dicom_matrix_type: None,
            field: Some(field_path.display().to_string()),
            method: layers.describe(&method, field.pairs),
            pairs: field.pairs,
            map: "moving_from_fixed",
            domain_lps: None,
            warnings: field.warnings,
        }
    } else {
        let exact = exact_transform(&made_of)?;
        if !quiet {
            for w in &exact.warnings {
                eprintln!("warpbench: warning: {w}");
            }
        }
        let pair = VolumePair {
            fixed: &volumes.fixed,
            moving: &volumes.moving,
            fixed_path: Some(&inputs.volumes.fixed),
            moving_path: Some(&inputs.volumes.moving),
        };
        let written = write_transform(&out_path, &exact, format, pair)?;
        TransformSummary {
            schema: SCHEMA,
            out: out_path.display().to_string(),
            itk_class: exact.transform.type_name(),
            members: vec![exact.transform.type_name()],
            format: format.name(),
            elastix_transform: match written {
                Written::Elastix(class) => Some(class),
                Written::Itk | Written::Dicom(_) | Written::Fsl | Written::Afni | Written::Lta | Written::Minc => None,
            },
            dicom_matrix_type: match written {
                Written::Dicom(kind) => Some(kind.name()),
                Written::Itk | Written::Elastix(_) | Written::Fsl | Written::Afni | Written::Lta | Written::Minc => {
                    None
                }
            },
            field: None,
            method: exact.method,
            pairs: exact.pairs,
            map: match format {
                TransformFormat::Dicom | TransformFormat::Fsl | TransformFormat::Lta | TransformFormat::Minc => {
                    "fixed_from_moving"
                }
                TransformFormat::Itk | TransformFormat::Elastix | TransformFormat::Afni => "moving_from_fixed",
            },
            domain_lps: exact.domain_lps,
            warnings: exact.warnings,
        }
    };
    if json {
        crate::exit::print_json(out, &summary, "the JSON summary")?;
    } else if !quiet {
        let maps = match (format, summary.map) {
            (TransformFormat::Dicom, "fixed_from_moving") => {
                "a matrix from the moving series' patient coordinates to the fixed series'"
            }
            (TransformFormat::Dicom, _) => "a deformation grid from the fixed series' frame to the moving series'",
            (TransformFormat::Fsl, _) => "FLIRT's matrix from the moving volume's FSL coordinates to the fixed one's",
            (TransformFormat::Lta, _) => "from the moving volume (src) to the fixed one (dst), RAS mm",
            (TransformFormat::Minc, _) => "from the moving volume's world to the fixed one's, RAS mm",
            _ => "maps fixed points to moving points, LPS mm",
        };
        eprintln!(
            "wrote {} ({}, {}, {} landmark pairs; {maps})",
            summary.out,
            summary.elastix_transform.or(summary.dicom_matrix_type).unwrap_or(match format {
                TransformFormat::Dicom => "Deformable Spatial Registration",
                TransformFormat::Fsl => "FLIRT matrix",
                TransformFormat::Afni => "AFNI matrix",
                TransformFormat::Lta => "LTA, LINEAR_RAS_TO_RAS",
                TransformFormat::Minc => "MNI transform, Linear",
                _ => summary.itk_class,
            }),
            summary.method,
            summary.pairs
        );
        if let Some(field) = &summary.field {
            eprintln!("wrote {field} (the field it names)");
        }
    }
    Ok(summary)
}

/// Writes `field` (a pull-back's) as a MetaImage at `field_path`, then the elastix `DeformationFieldTransform` at
/// `out` that names it as given (relative paths stay relative: transformix reads them from the folder it runs in,
/// like elastix's `-out`), over the field's grid; each atomically. What `--format elastix` writes for a stack no
/// transform file holds exactly.
///
/// # Errors
/// A name elastix cannot hold ([`check_field_name`]), or what the writers refuse; a refused name writes nothing.
pub fn write_field_transform(out: &Path, field_path: &Path, field: &crate::field::Field) -> Result<(), Failure> {
    let name = check_field_name(out, field_path)?;
    displacement::write_field(
        field_path,
        FieldFormat::MetaImage,
        field.dims,
        &field.lps_from_index,
        &field.displacements_lps,
    )?;
    let grid = ElastixGrid { dims: field.dims, lps_from_index: field.lps_from_index };
    elastix::write_field_transform(out, name, &grid)?;
    Ok(())
}

/// The class [`write_h5_field_transform`] writes (its vectors are single precision: [`warpbench_io::itk_h5`]).
pub const H5_FIELD_CLASS: &str = "DisplacementFieldTransform_float_3_3";

/// Writes `field`, a pull-back sampled on a grid, as ITK's HDF5 transform file at `out`, atomically: one
/// `DisplacementFieldTransform` ([`H5_FIELD_CLASS`]), T(x) = x + D(x) between the voxel centres and x outside the
/// grid. What `transform --out NAME.h5` writes for a stack no other ITK transform file holds exactly.
///
/// # Errors
/// A field of the forward map (ITK's transform is the pull-back), or what the writer refuses.
pub fn write_h5_field_transform(out: &Path, field: &crate::field::Field) -> Result<(), Failure> {
    if field.direction != FieldDirection::Pullback {
        return Err(Failure::Internal(anyhow::anyhow!(
            "{}: an ITK transform holds the pull-back; this field samples the {} map",
            out.display(),
            field.direction
        )));
    }
    let step = H5Transform::Field {
        dims: field.dims,
        lps_from_index: &field.lps_from_index,
        displacements_lps: &field.displacements_lps,
    };
    itk_h5::write(out, &[step])?;
    Ok(())
}

/// What [`write_h5_stack`] wrote.
#[derive(Clone, Debug)]
pub struct H5Stack {
    /// The class in the file's group `0`: `CompositeTransform_double_3_3` over several members, else the one's.
    pub itk_class: &'static str,
    /// The members' classes in ITK's order (the last is applied first); one for a single transform.
    pub members: Vec<&'static str>,
    /// The warp's name in reports ([`Layers::describe`]).
    pub method: String,
    /// Landmark pairs used.
    pub pairs: usize,
    /// Whether a member is a field sampled on the fixed grid (all of u, or the part over its base): outside that
    /// grid the member is the identity.
    pub sampled: bool,
    /// What the fit found suspicious in the pairs.
    pub warnings: Vec<String>,
}

/// Writes the pull-back of `made_of` (a stack with a field or a brush, which no `.tfm` holds) as ITK's HDF5
/// transform file at `out`, atomically. Over a pull-back field or a chain of ITK transforms (`--initial-field`, a
/// session's field) it is ITK's composite u = T₀ ∘ F ∘ R ([`crate::project::stack::StackPullback::itk_composite`]):
/// the starting transform and the field's own members as they are, so ITK applies them exactly, outside the fixed
/// volume too, and the landmark fit R over them as itself (an affine or a B-spline) or sampled on the fixed grid
/// (a TPS, or a brush). Otherwise (a forward field, or a brush alone) it is one `DisplacementFieldTransform` of u
/// sampled on the fixed grid ([`write_h5_field_transform`]). `progress(done, total)` hears each slice sampled and
/// cancels with `false`.
///
/// # Errors
/// Pairs outside the volumes, a fit that fails, a grid too large, a cancel, or what the writer refuses.
pub fn write_h5_stack(
    out: &Path,
    made_of: &FieldInputs,
    progress: &mut dyn FnMut(u64, u64) -> bool,
) -> Result<H5Stack, Failure> {
    let FieldInputs { fixed, moving, pairs, names, method, layers } = *made_of;
    if layers.field.as_ref().is_none_or(|f| f.itk_members().is_none()) {
        let field = crate::field::sample_field(fixed, made_of, FieldDirection::Pullback, progress)?;
        write_h5_field_transform(out, &field)?;
        return Ok(H5Stack {
            itk_class: H5_FIELD_CLASS,
            members: vec![H5_FIELD_CLASS],
            method: layers.describe(method, field.pairs),
            pairs: field.pairs,
            sampled: true,
            warnings: field.warnings,
        });
    }
    let c = inputs::check_pairs(&names.landmarks, pairs, moving, fixed, layers.min_pairs(method))
        .map_err(Failure::BadInput)?;
    let stack = fit::pullback_stack(method, &c, inputs::volume_box::<Fixed>(fixed), layers.clone())
        .map_err(Failure::BadInput)?;
    let composite = stack.itk_composite().ok_or_else(|| {
        Failure::Internal(anyhow::anyhow!("{}: the warp on a pull-back field has no ITK composite", out.display()))
    })?;
    let grid = (fixed.dims, &fixed.lps_from_index);
    let classes = write_h5_composite(out, &composite, Some(grid), &names.out, progress)?;
    let sampled = matches!(composite.rest, ItkRest::Sampled(_));
    Ok(H5Stack {
        itk_class: match classes.as_slice() {
            [one] => one,
            _ => itk_h5::COMPOSITE_CLASS,
        },
        members: classes,
        method: layers.describe(method, c.moving.len()),
        pairs: c.moving.len(),
        sampled,
        warnings: fit::fit_warnings(method, &c),
    })
}

/// Writes `composite` as ITK's HDF5 transform file at `out`, atomically, its members in ITK's order; a sampled rest
/// ([`ItkRest::Sampled`]) is sampled first at every voxel centre of `grid` (the fixed volume's: dims and
/// `lps_from_index`), `progress(done, total)` hearing each slice and cancelling with `false`. Returns the members'
/// classes. `name` names the output in a refusal of its size.
///
/// # Errors
/// A sampled rest without a grid, a grid too large, a cancel, a rest that is not finite, or what the writer
/// refuses.
pub fn write_h5_composite(
    out: &Path,
    composite: &ItkComposite<'_>,
    grid: Option<([usize; 3], &Transform<Lps, Index>)>,
    name: &Path,
    progress: &mut dyn FnMut(u64, u64) -> bool,
) -> Result<Vec<&'static str>, Failure> {
    let sampled = match (&composite.rest, grid) {
        (ItkRest::Sampled(_), None) => {
            return Err(Failure::BadInput(anyhow::anyhow!(
                "{}: the landmark fit over the field is sampled on the fixed grid, and no fixed volume was given",
                out.display()
            )));
        }
        (ItkRest::Sampled(rest), Some((dims, lps_from_index))) => {
            volume::check_allocation(name, dims, 12, volume::DEFAULT_MAX_VOXEL_BYTES)?;
            let field = crate::field::sample_displacements(rest, dims, lps_from_index, progress)
                .ok_or_else(|| Failure::Cancelled(anyhow::anyhow!("sampling the displacement field: cancelled")))?;
            if field.max_norm_mm.is_none() {
                return Err(Failure::Internal(anyhow::anyhow!(
                    "{}: the landmark fit is not finite somewhere in the fixed grid",
                    out.display()
                )));
            }
            Some((dims, lps_from_index, field.displacements_lps))
        }
        (ItkRest::Identity | ItkRest::Exact(_), _) => None,
    };
    let mut members: Vec<H5Transform<'_>> = composite.start.iter().map(H5Transform::Transform).collect();
    members.extend(composite.field.iter().copied());
    match (&composite.rest, &sampled) {
        (ItkRest::Exact(t), _) => members.push(H5Transform::Transform(t)),
        (_, Some((dims, lps_from_index, displacements_lps))) => {
            members.push(H5Transform::Field { dims: *dims, lps_from_index, displacements_lps });
        }
        (ItkRest::Identity | ItkRest::Sampled(_), None) => {}
    }
    itk_h5::write(out, &members)?;
    Ok(members.iter().map(H5Transform::class).collect())
}
