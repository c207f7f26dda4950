//! `warpbench field`: the pull-back as a displacement field that ITK, ANTs and 3D Slicer read, and for the linear
//! methods also as an ITK transform file (`.tfm`).
//!
//! At every voxel centre x of the output grid (the fixed volume's, or `--reference`'s), in LPS mm, the field holds
//!
//! ```text
//! D(x) = u(x) − x,    u = moving_from_fixed, the pull-back fitted on the landmark pairs
//! ```
//!
//! evaluated exactly (not through a control texture), slice by slice on every core. This is the convention of ITK's
//! `DisplacementFieldTransform` as `ResampleImageFilter` uses it: the output (fixed) point x is read from the input
//! (moving) point x + D(x). `--direction forward` writes instead, on the moving volume's grid (or `--reference`'s),
//!
//! ```text
//! D(y) = d(y) − y,    d = fixed_from_moving, fitted on the pairs over the moving volume's box
//! ```
//!
//! for users who move points or meshes with a field (a point y of the moving volume goes to y + D(y)).
//!
//! `--format` picks the flavour ([`FieldFormat`], written by [`warpbench_io::displacement::write_field_with`]):
//! `itk`, NIfTI-1 float32 intent `DISPVECT` with RAS vectors (ITK ≥ 5.3, Slicer); `ants`, NIfTI intent `VECTOR`
//! with LPS vectors (`antsApplyTransforms`); `nrrd`, Slicer's NRRD field, which also records the direction;
//! `metaimage`, ITK's MetaImage vector image (`.mha`, `.mhd` + `.raw`), as elastix's transformix writes its
//! `deformationField.mhd`.
//!
//! `--tfm` writes the pull-back itself as an ITK transform file ([`crate::project::stack::itk_transform_of`]: a thin-plate
//! spline, a B-spline or an affine, each exact), which ITK applies in LPS, like our patient space.
//!
//! [`run`] loads the files, calls the in-memory core [`displacement_field`] (the pairs checked, the fit, the
//! sampling, with a progress callback that can cancel) and writes with [`write_field`]; the window exports through
//! the same three.

use std::io::Write;
use std::num::NonZeroUsize;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Mutex, PoisonError};

use anyhow::anyhow;
use serde::Serialize;
use warpbench_io::displacement::{self, FieldDirection, FieldFormat};
use warpbench_io::geometry::{Index, Lps, Space, Transform};
use warpbench_io::itk_h5::{self, H5Transform};
use warpbench_io::itk_tfm::{self, ItkTransform};
use warpbench_io::landmarks::LandmarkPair;
use warpbench_io::learn2reg;
use warpbench_io::transform_file;
use warpbench_io::{Volume, volume};
use warpbench_solver::method::Method;
use warpbench_solver::spaces::{Fixed, Moving};
use warpbench_solver::warp::Warp;

use crate::args::{PairArgs, ReportArgs, VolumePairArgs, help};
use crate::brushed::Brushed;
use crate::exit::Failure;
use crate::fit;
use crate::inputs::{self, Names, OutputFile, PairVolumes};
use crate::project::stack::{FieldLayer, Layers};
use crate::warp::{FieldFormatArgs, InverseConsistency, WarpInputs};

/// The `--json` schema name.
pub const SCHEMA: &str = "warpbench-field/1";

/// What `warpbench field --help` says above the options; its first paragraph is the summary that `-h` and
/// `warpbench --help` show.
const HELP: &str = "\
Write the warp as a displacement field in the flavour ITK, ANTs or 3D Slicer reads, and optionally the exact
transform as an ITK transform file.

With --field instead of landmarks, the warp is that displacement field, in any flavour warp --field reads: it is
sampled on the output grid and written in --format, a converter between the flavours.

--direction pullback (default): at each voxel centre x of the fixed grid (or --reference's) the field holds
u(x) − x, u = moving_from_fixed fitted on the landmarks and evaluated exactly: ITK's DisplacementFieldTransform
maps fixed point x to moving point x + D(x), what resampling the moving volume needs. --direction forward: on
the moving grid (or --reference's), d(y) − y, d = fixed_from_moving: a moving point y goes to y + D(y), what
moving points or meshes needs.

--format itk (default): NIfTI intent DISPVECT (1006), vectors in RAS, as ITK ≥ 5.3 and Slicer read it;
--format ants: NIfTI intent VECTOR (1007), vectors in LPS, what antsApplyTransforms reads; --format nrrd: a NRRD
vector image in LPS that Slicer reads, stating the direction (displacement field type resampling or modeling);
--format metaimage: a MetaImage vector image in LPS (.mha, or .mhd with a .raw beside it), what elastix's
transformix writes as deformationField.mhd and every ITK reads; --format learn2reg (or a name ending .npz):
Learn2Reg's field, the pull-back's steps from fixed voxels to moving voxels, as .npz (float16, the challenge's
form until 2021) or .nii.gz (float32 (X, Y, Z, 3), its form since 2022); --format afni: AFNI's warp as 3dQwarp
saves one to .nii.gz (LPS vectors, AFNI's extension labelling them x_delta, y_delta, z_delta), which
3dNwarpApply -nwarp applies; --format fnirt: FSL FNIRT's relative deformation field for applywarp --rel.
Examples:

    warpbench field --fixed ct.nii.gz --moving mr.nii.gz --landmarks pairs.csv --out field.nii.gz
    warpbench field --fixed ct.nii.gz --moving mr.nii.gz --landmarks pairs.csv --format ants --out mr_to_ct1Warp.nii.gz
    warpbench field --fixed ct.nii.gz --moving mr.nii.gz --landmarks pairs.csv --format nrrd --out field.nrrd --tfm mr_to_ct.tfm
    warpbench field --fixed ct.nii.gz --moving mr.nii.gz --landmarks pairs.csv --format metaimage --out deformationField.mhd
    warpbench field --fixed 0001.nii.gz --moving 0002.nii.gz --landmarks pairs.csv --format learn2reg --out disp_0001_0002.nii.gz
    warpbench field --fixed ct.nii.gz --moving mr.nii.gz --field mr_to_ct1Warp.nii.gz --format nrrd --out field.nrrd";

/// The arguments of `warpbench field`.
#[derive(Debug, clap::Args)]
#[command(about = crate::args::summary(HELP), long_about = HELP)]
#[command(mut_args(help(&[
    ("fixed", "The fixed volume: its grid is the field's grid unless --reference is given"),
    ("moving", "The moving volume (landmarks are checked against it)"),
    ("json", "Print a JSON summary (schema warpbench-field/1, see docs/cli.md) to stdout"),
    ("force", "Overwrite --out (and --tfm) if they exist"),
])))]
#[command(mut_args(crate::args::or_session))]
pub struct FieldArgs {
    #[command(flatten)]
    pub volumes: VolumePairArgs,
    #[command(flatten)]
    pub pairs: PairArgs,
    /// A displacement field to write instead of a landmark warp (any flavour warp --field reads: ITK or ANTs NIfTI,
    /// NRRD, MetaImage, elastix, ITK HDF5, DICOM, Learn2Reg), sampled on the output grid: a converter between the
    /// flavours. A forward field is inverted point by point for the pull-back.
    #[arg(long, conflicts_with_all = ["landmarks", "moving_points", "fixed_points", "session", "method", "stiffness", "levels", "initial", "initial_field"])]
    pub field: Option<PathBuf>,
    #[command(flatten)]
    pub field_format: FieldFormatArgs,
    /// Sample the field on this volume's grid instead of the fixed volume's.
    #[arg(long)]
    pub reference: Option<PathBuf>,
    /// Also write the pull-back as an ITK transform file: the exact TPS, B-spline or affine (see warpbench transform;
    /// .h5 for ITK's HDF5 file; .mat, ANTs' MATLAB file, for the linear methods).
    #[arg(long)]
    pub tfm: Option<PathBuf>,
    /// The field's flavour: itk (NIfTI DISPVECT, RAS vectors), ants (NIfTI VECTOR, LPS), nrrd (Slicer's NRRD, LPS),
    /// metaimage (elastix's and ITK's .mha/.mhd, LPS), minc (an MNI grid transform .xfm), ngff (an OME-Zarr 0.6 field
    /// folder, .ome.zarr, which its name picks too), learn2reg (Learn2Reg's steps from fixed voxels to moving
    /// voxels: .npz, float16, the challenge's form until 2021; .nii.gz, float32, its form since 2022), fnirt (FSL
    /// FNIRT's relative deformation field, .nii or .nii.gz, for `applywarp --ref=GRID --in=MOVING --warp=OUT --rel`,
    /// GRID the output grid's volume: --reference, or the fixed one) or afni (AFNI's warp, .nii or .nii.gz, for
    /// `3dNwarpApply -nwarp OUT -source MOVING -master GRID`).
    #[arg(long, value_enum, default_value = "itk")]
    pub format: FormatArg,
    /// pullback (u(x) − x on the fixed grid) or forward (d(y) − y on the moving grid).
    #[arg(long, value_enum, default_value = "pullback")]
    pub direction: DirectionArg,
    /// The displacement field to write (.nii or .nii.gz; .nrrd for --format nrrd; .mha or .mhd for --format
    /// metaimage; .h5 for ITK's HDF5 transform file holding it as a DisplacementFieldTransform; .npz, or .nii.gz with
    /// --format learn2reg, for Learn2Reg's field, steps from fixed voxels to moving voxels; .nii.gz with --format
    /// fnirt for FSL's applywarp or --format afni for AFNI's 3dNwarpApply; a folder named .ome.zarr for OME-Zarr 0.6, RFC-5's displacements, on an
    /// axis-aligned grid).
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub report: ReportArgs,
}

/// `--format`: [`FieldFormat`] by its command-line name, or Learn2Reg's field ([`learn2reg`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum FormatArg {
    Itk,
    Ants,
    Nrrd,
    Metaimage,
    /// An MNI transform file (`.xfm`) of one grid transform, its vectors in `NAME_grid_0.mnc` beside it.
    Minc,
    /// Learn2Reg's field: steps from fixed voxels to moving voxels, `.npz` or `.nii.gz` by the name.
    Learn2reg,
    /// An OME-Zarr 0.6 field folder (`.ome.zarr`): RFC-5's `displacements`, as ngff-zarr reads it.
    Ngff,
    /// FSL FNIRT's deformation field of relative displacements (`.nii`, `.nii.gz`), in the FSL coordinates of the
    /// output grid (FNIRT's reference) and the moving volume (its input), as `fnirt --fout` writes one.
    Fnirt,
    /// AFNI's warp (`.nii`, `.nii.gz`), as `3dQwarp` saves one: LPS (DICOM) vectors, AFNI's extension labelling them,
    /// for `3dNwarpApply -nwarp`.
    Afni,
}

/// A field written against the pair's grids rather than in a flavour of its own ([`FormatArg::pair_output`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PairOutput {
    /// Learn2Reg's steps from fixed voxels to moving voxels ([`write_learn2reg`]).
    Learn2Reg,
    /// FNIRT's relative deformation field in the two grids' FSL coordinates ([`warpbench_io::fnirt::write_pullback`]).
    Fnirt,
}

impl PairOutput {
    /// How the summary names it: `learn2reg`, `fnirt`.
    #[must_use]
    pub const fn name(self) -> &'static str {
        match self {
            Self::Learn2Reg => "learn2reg",
            Self::Fnirt => "fnirt",
        }
    }

    /// Refuses the output before anything is computed ([`check_learn2reg_output`]; for FNIRT's field: over an input or
    /// an existing file without `--force`, a name other than NIfTI's, the forward direction).
    ///
    /// # Errors
    /// As said, naming the output.
    pub(crate) fn check(
        self,
        output: &OutputFile,
        format: FormatArg,
        direction: FieldDirection,
        reference: Option<&Path>,
        inputs: &[&Path],
    ) -> Result<(), Failure> {
        if self == Self::Learn2Reg {
            return check_learn2reg_output(output, format, direction, reference, inputs);
        }
        output.check(inputs).map_err(Failure::BadInput)?;
        let refuse = |why: &str| {
            Err(Failure::BadInput(anyhow!(
                "{}: --format fnirt writes FNIRT's deformation field, {why}",
                output.path.display()
            )))
        };
        if FieldFormat::from_extension(&output.path) != Some(FieldFormat::Itk) {
            return refuse("a NIfTI file: name it .nii or .nii.gz");
        }
        if direction == FieldDirection::Forward {
            return refuse(
                "which maps the reference (fixed) grid into the input (the pull-back): leave out --direction forward",
            );
        }
        Ok(())
    }

    /// Writes the pull-back `displacements_lps`, sampled on the grid `fixed` (LPS mm, i fastest), against the grid of
    /// the moving volume, atomically.
    ///
    /// # Errors
    /// What the writers refuse (a step beyond float16's range in an `.npz`, a singular grid), a failed write.
    pub fn write(
        self,
        out: &Path,
        fixed: ([usize; 3], &Transform<Lps, Index>),
        moving: ([usize; 3], &Transform<Lps, Index>),
        displacements_lps: &[[f32; 3]],
    ) -> Result<(), Failure> {
        match self {
            Self::Learn2Reg => write_learn2reg(out, fixed.0, fixed.1, moving.1, displacements_lps),
            Self::Fnirt => Ok(warpbench_io::fnirt::write_pullback(out, fixed, moving, displacements_lps)?),
        }
    }
}

impl FormatArg {
    /// Whether a pull-back field of this `--format` written to `out` is Learn2Reg's: `--format learn2reg`, or a
    /// name ending `.npz`, which picks that flavour as `.h5` picks ITK's transform file.
    #[must_use]
    pub fn is_learn2reg(self, out: &Path) -> bool {
        self == Self::Learn2reg || learn2reg::is_npz_name(out)
    }

    /// The field written against the pair's grids that a pull-back of this `--format` written to `out` is:
    /// Learn2Reg's ([`Self::is_learn2reg`]) or FNIRT's (`--format fnirt`); `None` for a flavour of its own.
    #[must_use]
    pub fn pair_output(self, out: &Path) -> Option<PairOutput> {
        if self == Self::Fnirt {
            Some(PairOutput::Fnirt)
        } else if self.is_learn2reg(out) {
            Some(PairOutput::Learn2Reg)
        } else {
            None
        }
    }

    /// The image flavour it names; `learn2reg` and `fnirt` write the pull-back alone, so a forward or inverse field
    /// written beside one takes the default flavour, `itk`.
    #[must_use]
    pub fn flavour(self) -> FieldFormat {
        match self {
            Self::Itk | Self::Learn2reg | Self::Fnirt => FieldFormat::Itk,
            Self::Ants => FieldFormat::Ants,
            Self::Nrrd => FieldFormat::Nrrd,
            Self::Metaimage => FieldFormat::MetaImage,
            Self::Minc => FieldFormat::Minc,
            Self::Ngff => FieldFormat::Ngff,
            Self::Afni => FieldFormat::Afni,
        }
    }

    /// [`Self::flavour`], except that the default (`itk`) writes an output named `.zarr` (`.ome.zarr`) as OME-Zarr,
    /// as a name ending `.npz` picks Learn2Reg's flavour.
    #[must_use]
    pub fn flavour_for(self, out: &Path) -> FieldFormat {
        match (self, FieldFormat::from_extension(out)) {
            (Self::Itk, Some(FieldFormat::Ngff)) => FieldFormat::Ngff,
            _ => self.flavour(),
        }
    }
}

/// `--direction`: [`FieldDirection`] by its command-line name.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum DirectionArg {
    Pullback,
    Forward,
}

impl From<DirectionArg> for FieldDirection {
    fn from(arg: DirectionArg) -> Self {
        match arg {
            DirectionArg::Pullback => Self::Pullback,
            DirectionArg::Forward => Self::Forward,
        }
    }
}

/// What was written: the `--json` document, schema `warpbench-field/1` (docs/cli.md).
#[derive(Clone, Debug, Serialize)]
pub struct FieldSummary {
    pub schema: &'static str,
    /// The displacement field written.
    pub out: String,
    /// The output grid: voxels along i, j, k, spacing and `lps_from_index` (row-major).
    pub dims: [usize; 3],
    pub spacing_mm: [f64; 3],
    pub lps_from_index: [[f64; 4]; 4],
    /// `"fixed"`, `"moving"` (`--direction forward`) or `"reference"`: whose grid the field is sampled on.
    pub grid: &'static str,
    /// The flavour written: `itk`, `ants`, `nrrd`, `metaimage` or `learn2reg`.
    pub format: &'static str,
    /// `pullback` (D = u(x) − x) or `forward` (D = d(y) − y).
    pub direction: &'static str,
    /// The method as fitted, e.g. `tps`, `tps(λ=0.5)`, `hbspline(4 levels)`, `affine`.
    pub method: String,
    /// Landmark pairs used (active, with both points).
    pub pairs: usize,
    /// The largest |D(x)| over the grid, mm.
    pub max_displacement_mm: f64,
    /// The ITK transform file written, or null.
    pub tfm: Option<String>,
    /// Its ITK class (e.g. `ThinPlateSplineKernelTransform_double_3_3`), or null.
    pub tfm_class: Option<&'static str>,
    /// What the fit found suspicious in the pairs, as printed on stderr.
    pub warnings: Vec<String>,
    /// With a session's brush: how well its fitted inverse undoes it (the pull-back is u ∘ b⁻¹), or null.
    pub inverse_consistency_mm: Option<InverseConsistency>,
}

/// Runs `warpbench field`: checks the outputs, loads, fits, samples, writes; prints the JSON summary to `out` with
/// `--json`, else what it wrote on stderr unless `--quiet`.
pub fn run(args: FieldArgs, out: &mut dyn Write) -> Result<FieldSummary, Failure> {
    let FieldArgs {
        volumes,
        pairs,
        field: given_field,
        field_format,
        reference,
        tfm,
        format: format_arg,
        direction,
        out: out_path,
        report,
    } = args;
    let ReportArgs { json, force, quiet } = report;
    let (format, direction) = (format_arg.flavour_for(&out_path), FieldDirection::from(direction));
    let reference_path = reference.clone();
    let inputs = WarpInputs::from_args(volumes, pairs, (given_field, field_format.format), reference, quiet)?;
    let output = OutputFile { path: out_path, force };
    let input_paths = inputs.paths();
    let pair_output = format_arg.pair_output(&output.path);
    if let Some(kind) = pair_output {
        kind.check(&output, format_arg, direction, reference_path.as_deref(), &input_paths)?;
    } else {
        check_field_output(&output, format, &input_paths)?;
    }
    // The method before any volume is loaded (`--stiffness auto` reads the pairs, and refuses some); a field alone
    // is the warp whatever the method.
    let method = match &inputs {
        WarpInputs::Pairs(p) => p.method().map_err(Failure::BadInput)?,
        WarpInputs::Field(_) => Method::Tps { stiffness: 0.0 },
    };
    if let (Some(tfm), WarpInputs::Field(f)) = (&tfm, &inputs) {
        return Err(Failure::BadInput(anyhow!(
            "{}: --tfm writes the exact transform of a landmark warp, and {} is a sampled field, which has none; \
             name --out .h5 for ITK's transform file over the field",
            tfm.display(),
            f.field.display()
        )));
    }
    if let Some(tfm) = &tfm
        && direction == FieldDirection::Forward
    {
        return Err(Failure::BadInput(anyhow!(
            "{}: an ITK transform file holds the pull-back (ITK's resampling direction), not the forward map that \
             --direction forward samples; write it in a run without --direction forward, or with warpbench transform",
            tfm.display()
        )));
    }
    if let Some(tfm) = &tfm {
        if tfm == &output.path {
            return Err(Failure::BadInput(anyhow!("{}: --tfm and --out are the same file", tfm.display())));
        }
        inputs::check_output(tfm, &input_paths, output.force).map_err(Failure::BadInput)?;
    }
    // A field in its own geometry is read before the volumes, so that one refused costs no loading; a Learn2Reg
    // field, in the volumes' voxels, and an ITK transform file, which may need the fixed grid, after them.
    let given = match &inputs {
        WarpInputs::Field(f) if !crate::warp::read_after_volumes(&f.field, f.format)? => {
            Some(crate::warp::read_warp_field(&f.field, None, quiet)?)
        }
        _ => None,
    };

    let PairVolumes { fixed, moving, reference } =
        crate::warp::load_volumes(&inputs, quiet).map_err(Failure::BadInput)?;
    let names = inputs.names(&output.path);
    let (grid, grid_name) = match (&reference, direction) {
        (Some(r), _) => (r, "reference"),
        (None, FieldDirection::Pullback) => (&fixed, "fixed"),
        (None, FieldDirection::Forward) => (&moving, "moving"),
    };
    if format == FieldFormat::Ngff && pair_output.is_none() {
        warpbench_io::ngff::check_grid(&output.path, &grid.lps_from_index)
            .map_err(|e| Failure::BadInput(anyhow!("{e} (the {grid_name} grid)")))?;
    }
    let (pairs, layers): (&[LandmarkPair], Layers) = match &inputs {
        WarpInputs::Pairs(p) => {
            let brushed = p.brushed().map_err(Failure::BadInput)?;
            if let (Some(tfm), Some(_)) = (&tfm, &brushed) {
                return Err(Failure::BadInput(anyhow!(
                    "{}: the session's brush strokes have no exact ITK transform; write the displacement field alone",
                    tfm.display()
                )));
            }
            let mut layers = Layers::new(p.start(&fixed, &moving).map_err(Failure::BadInput)?, brushed);
            layers.field = p.warp.field(&fixed, &moving).map_err(Failure::BadInput)?;
            crate::inputs::note_field_warnings(layers.field.as_deref(), quiet);
            (p.pairs().map_err(Failure::BadInput)?, layers)
        }
        WarpInputs::Field(f) => {
            let origin = f.field.display().to_string();
            let read = match given {
                Some(read) => read,
                None if f.format.reads_against_pair(&f.field)? => {
                    crate::warp::WarpField::Pullback(crate::warp::read_pair_field(&f.field, &fixed, &moving, quiet)?)
                }
                // An ITK transform file: B-splines sampled on the output grid of a pull-back (the fixed one for the
                // forward map, which inverts the pull-back there).
                None => crate::warp::read_warp_field(&f.field, Some(reference.as_ref().unwrap_or(&fixed)), quiet)?,
            };
            let layer = match read {
                crate::warp::WarpField::Pullback(s) => FieldLayer::pullback(s, &origin),
                crate::warp::WarpField::Forward(s) => FieldLayer::forward(s, &origin),
            };
            let mut layers = Layers::new(None, None);
            layers.field = Some(std::sync::Arc::new(layer));
            (&[], layers)
        }
    };
    let made_of =
        FieldInputs { fixed: &fixed, moving: &moving, pairs, names: &names, method: &method, layers: &layers };
    let field = sample_field_reporting(grid, &made_of, direction, quiet)?;
    if let Some(kind) = pair_output {
        kind.write(
            &output.path,
            (field.dims, &field.lps_from_index),
            (moving.dims, &moving.lps_from_index),
            &field.displacements_lps,
        )?;
        if let Some(path) = &tfm {
            write_field_transform(&field, path)?;
        }
    } else {
        write_field(&field, &output.path, format, tfm.as_deref())?;
    }

    let summary = FieldSummary {
        schema: SCHEMA,
        out: output.path.display().to_string(),
        dims: field.dims,
        spacing_mm: field.spacing_mm,
        lps_from_index: field.lps_from_index.rows(),
        grid: grid_name,
        format: pair_output.map_or(format.name(), PairOutput::name),
        direction: field.direction.name(),
        method: match &inputs {
            WarpInputs::Field(f) => format!("field {}", f.field.display()),
            WarpInputs::Pairs(_) => field.method,
        },
        pairs: field.pairs,
        max_displacement_mm: field.max_displacement_mm,
        tfm: tfm.as_ref().map(|p| p.display().to_string()),
        tfm_class: tfm.as_ref().and(field.transform.as_ref()).map(ItkTransform::type_name),
        warnings: field.warnings.clone(),
        inverse_consistency_mm: layers.brushed().map(Brushed::consistency),
    };
    if json {
        crate::exit::print_json(out, &summary, "the JSON summary")?;
    } else if !quiet {
        let d = summary.dims;
        let made_of = match &inputs {
            WarpInputs::Field(f) => format!("from {}", f.field.display()),
            WarpInputs::Pairs(_) => format!("{} landmark pairs, {}", summary.pairs, summary.method),
        };
        eprintln!(
            "wrote {} ({} {} field, {}×{}×{}, {made_of}, max |D| {:.2} mm)",
            summary.out, summary.format, summary.direction, d[0], d[1], d[2], summary.max_displacement_mm
        );
        if let Some(tfm) = &summary.tfm {
            eprintln!("wrote {tfm}");
        }
    }
    Ok(summary)
}

/// A displacement field on an output grid (the pull-back's, or the forward map's), and what the summary says about
/// it: what [`displacement_field`] and [`sample_field`] return and [`write_field`] writes.
#[derive(Clone, Debug, PartialEq)]
pub struct Field {
    /// The output grid: voxels along i, j, k, spacing and `lps_from_index`.
    pub dims: [usize; 3],
    pub spacing_mm: [f64; 3],
    pub lps_from_index: Transform<Lps, Index>,
    /// u(x) − x (or d(y) − y) at each voxel centre, LPS mm, i fastest.
    pub displacements_lps: Vec<[f32; 3]>,
    /// Which map the vectors sample.
    pub direction: FieldDirection,
    /// The largest |D| over the grid, mm.
    pub max_displacement_mm: f64,
    /// The method as fitted, e.g. `tps`, `affine`.
    pub method: String,
    /// Landmark pairs used (active, with both points).
    pub pairs: usize,
    /// The pull-back as the ITK transform that holds it exactly (what `--tfm` writes); `None` for a forward field.
    pub transform: Option<ItkTransform>,
    /// What the fit found suspicious in the pairs, `<landmark file>: <warning>` ([`fit::fit_warnings`]).
    pub warnings: Vec<String>,
}

/// The pull-back's displacement field `warpbench field` writes, in memory: `method` fitted on `pairs` (raw, as read:
/// checked against `moving` and `fixed` here, by [`inputs::check_pairs`]) over the fixed volume's box, and sampled
/// exactly at every voxel centre of `grid` (the fixed volume, or `--reference`; only its geometry is read). `names`
/// name the inputs and the output in messages. [`sample_field`] with [`FieldDirection::Pullback`].
///
/// `progress(done, total)` is called after slices of the grid are sampled (module docs); returning `false` stops
/// the sampling with [`Failure::Cancelled`] and no field.
pub fn displacement_field(
    grid: &Volume,
    fixed: &Volume,
    moving: &Volume,
    (pairs, layers): (&[LandmarkPair], &Layers),
    names: &Names,
    method: &Method,
    progress: &mut dyn FnMut(u64, u64) -> bool,
) -> Result<Field, Failure> {
    let inputs = FieldInputs { fixed, moving, pairs, names, method, layers };
    sample_field(grid, &inputs, FieldDirection::Pullback, progress)
}

/// What a field is made from: the pair, its landmark pairs (raw, as read), what messages call them, the method, and
/// the layers of the warp stack around the landmark fit ([`crate::project::stack`]).
#[derive(Clone, Copy, Debug)]
pub struct FieldInputs<'a> {
    pub fixed: &'a Volume,
    pub moving: &'a Volume,
    pub pairs: &'a [LandmarkPair],
    pub names: &'a Names,
    pub method: &'a Method,
    pub layers: &'a Layers,
}

/// The displacement field of `direction` on `grid`: the pull-back u fitted over the fixed box, D(x) = u(x) − x, or
/// the forward map d fitted over the moving box, D(y) = d(y) − y (module docs), sampled exactly at every voxel centre
/// of `grid` (only its geometry is read). The pairs are checked here ([`inputs::check_pairs`]).
pub fn sample_field(
    grid: &Volume,
    inputs: &FieldInputs,
    direction: FieldDirection,
    progress: &mut dyn FnMut(u64, u64) -> bool,
) -> Result<Field, Failure> {
    let FieldInputs { fixed, moving, pairs, names, method, layers } = *inputs;
    let c = inputs::check_pairs(&names.landmarks, pairs, moving, fixed, layers.min_pairs(method))
        .map_err(Failure::BadInput)?;
    let (dims, lps_from_index) = (grid.dims, grid.lps_from_index);
    let cancelled = || Failure::Cancelled(anyhow!("sampling the displacement field: cancelled"));
    let (sampled, transform) = match direction {
        FieldDirection::Pullback => {
            // The warp is the same whatever the output grid: fitted over the fixed box, as `render` and `warp` fit it.
            let moving_from_fixed = fit::pullback_stack(method, &c, inputs::volume_box::<Fixed>(fixed), layers.clone())
                .map_err(Failure::BadInput)?;
            volume::check_allocation(&names.out, dims, 12, volume::DEFAULT_MAX_VOXEL_BYTES)?;
            let sampled =
                sample_displacements(&moving_from_fixed, dims, &lps_from_index, progress).ok_or_else(cancelled)?;
            // With a brush (u ∘ b⁻¹) no ITK transform holds it exactly.
            (sampled, moving_from_fixed.itk_transform().ok())
        }
        FieldDirection::Forward => {
            // Fitted over the moving box, as `points --from moving` fits it; a brush moves where a moving point
            // appears (b ∘ d).
            let fixed_from_moving =
                fit::forward_stack(method, &c, inputs::volume_box::<Moving>(moving), layers.clone())
                    .map_err(Failure::BadInput)?;
            volume::check_allocation(&names.out, dims, 12, volume::DEFAULT_MAX_VOXEL_BYTES)?;
            let sampled = sample_displacements(&fixed_from_moving, dims, &lps_from_index, progress);
            (sampled.ok_or_else(cancelled)?, None)
        }
    };
    let Some(max_displacement_mm) = sampled.max_norm_mm else {
        return Err(Failure::Internal(anyhow!("the {method} warp is not finite somewhere in the output grid")));
    };
    Ok(Field {
        dims,
        spacing_mm: grid.spacing_mm(),
        lps_from_index,
        displacements_lps: sampled.displacements_lps,
        direction,
        max_displacement_mm,
        method: crate::brushed::describe(&method, layers.brushed()),
        pairs: c.moving.len(),
        transform,
        warnings: fit::fit_warnings(method, &c),
    })
}

/// [`sample_field`] as the commands run it: a progress bar on stderr from the first slice (after the checks and the
/// fit) unless `quiet`, and the fit's warnings printed there after.
///
/// # Errors
/// As [`sample_field`].
pub fn sample_field_reporting(
    grid: &Volume,
    inputs: &FieldInputs,
    direction: FieldDirection,
    quiet: bool,
) -> Result<Field, Failure> {
    let field = crate::progress::with_bar(quiet, "sampling the field", |progress| {
        sample_field(grid, inputs, direction, progress)
    });
    let field = field?;
    if !quiet {
        for w in &field.warnings {
            eprintln!("warpbench: warning: {w}");
        }
    }
    Ok(field)
}

/// Refuses a field output before anything is computed: over an input or an existing file without `--force` (a
/// `.mhd`'s `.raw` data file too), or under a name its flavour cannot take.
pub fn check_field_output(output: &OutputFile, format: FieldFormat, inputs: &[&Path]) -> Result<(), Failure> {
    output.check(inputs).map_err(Failure::BadInput)?;
    if format == FieldFormat::MetaImage {
        crate::warp::check_data_file(&output.path, inputs, output.force).map_err(Failure::BadInput)?;
    }
    if format == FieldFormat::Minc {
        let grid = OutputFile { path: warpbench_io::mni_xfm::grid_file_of(&output.path), force: output.force };
        grid.check(inputs).map_err(Failure::BadInput)?;
    }
    check_field_name(&output.path, format)
}

/// Refuses a name a field of `format` cannot be written to ([`displacement::check_output_name`]); a name ending
/// `.h5` takes the default flavour only, and is written as ITK's HDF5 transform file ([`write_displacements`]).
///
/// # Errors
/// The name, in words.
pub fn check_field_name(path: &Path, format: FieldFormat) -> Result<(), Failure> {
    if !itk_tfm::is_hdf5_name(path) {
        return Ok(displacement::check_output_name(path, format)?);
    }
    if format != FieldFormat::Itk {
        return Err(Failure::BadInput(anyhow!(
            "{}: a name ending .h5 is ITK's HDF5 transform file, which holds the field as ITK's \
             DisplacementFieldTransform, not the {format} flavour: leave out --format, or name the file for the \
             flavour",
            path.display()
        )));
    }
    Ok(())
}

/// Writes displacements sampled on a grid (`dims`, `lps_from_index`; LPS mm, i fastest) to `out`, atomically: for a
/// name ending `.h5`, ITK's HDF5 transform file holding them as one `DisplacementFieldTransform`
/// ([`crate::transform::H5_FIELD_CLASS`]: T(x) = x + D(x), a map from the grid's space, fixed to moving for a
/// pull-back, moving to fixed for a forward field, as ANTs' `Composite.h5` and `InverseComposite.h5`); else the image
/// of `format` ([`displacement::write_field_with`], which records `direction` where the flavour can).
///
/// # Errors
/// A name that does not fit `format` ([`check_field_name`]), or what the writers refuse.
pub fn write_displacements(
    out: &Path,
    format: FieldFormat,
    direction: FieldDirection,
    dims: [usize; 3],
    lps_from_index: &Transform<Lps, Index>,
    displacements_lps: &[[f32; 3]],
) -> Result<(), Failure> {
    if itk_tfm::is_hdf5_name(out) {
        check_field_name(out, format)?;
        itk_h5::write(out, &[H5Transform::Field { dims, lps_from_index, displacements_lps }])?;
    } else {
        displacement::write_field_with(out, format, direction, dims, lps_from_index, displacements_lps)?;
    }
    Ok(())
}

/// Writes `field` as `warpbench field` does: the displacement field at `out` in `format` and, when `tfm` is given,
/// the pull-back as an ITK transform file. Each write is atomic.
pub fn write_field(field: &Field, out: &Path, format: FieldFormat, tfm: Option<&Path>) -> Result<(), Failure> {
    if let Some(path) = tfm
        && field.transform.is_none()
    {
        return Err(no_transform(field, path));
    }
    write_displacements(out, format, field.direction, field.dims, &field.lps_from_index, &field.displacements_lps)?;
    if let Some(path) = tfm {
        write_field_transform(field, path)?;
    }
    Ok(())
}

/// Writes the pull-back that `field` samples as an ITK transform file (`--tfm`), atomically.
fn write_field_transform(field: &Field, path: &Path) -> Result<(), Failure> {
    let transform = field.transform.as_ref().ok_or_else(|| no_transform(field, path))?;
    Ok(transform_file::write(path, transform)?)
}

fn no_transform(field: &Field, path: &Path) -> Failure {
    Failure::BadInput(anyhow!(
        "{}: an ITK transform file holds the pull-back; this field samples the {} map",
        path.display(),
        field.direction
    ))
}

/// Refuses a Learn2Reg output ([`FormatArg::is_learn2reg`]) before anything is computed: over an input or an
/// existing file without `--force`; a name ending `.npz` with a flavour other than the default or `learn2reg`;
/// `--format learn2reg` under a name that is neither `.npz` nor NIfTI's; the forward direction or a `--reference`
/// grid (the challenge's field holds the pull-back on the fixed image's voxels).
pub(crate) fn check_learn2reg_output(
    output: &OutputFile,
    format: FormatArg,
    direction: FieldDirection,
    reference: Option<&Path>,
    inputs: &[&Path],
) -> Result<(), Failure> {
    output.check(inputs).map_err(Failure::BadInput)?;
    let name = output.path.display();
    let npz = learn2reg::is_npz_name(&output.path);
    let what =
        if npz { "a name ending .npz is Learn2Reg's field" } else { "--format learn2reg writes Learn2Reg's field" };
    let refuse = |why: String| Err(Failure::BadInput(anyhow!("{name}: {what}, {why}")));
    if !matches!(format, FormatArg::Itk | FormatArg::Learn2reg) {
        let format = format.flavour();
        return refuse(format!("not the {format} flavour: leave out --format, or name the file for the flavour"));
    }
    if !npz && FieldFormat::from_extension(&output.path) != Some(FieldFormat::Itk) {
        return refuse("as .npz (the challenge's form until 2021) or .nii.gz (its form since 2022)".into());
    }
    if direction == FieldDirection::Forward {
        return refuse("which maps fixed voxels to moving ones (the pull-back): leave out --direction forward".into());
    }
    if let Some(r) = reference {
        return refuse(format!(
            "which holds one vector per voxel of the fixed image: leave out --reference {}",
            r.display()
        ));
    }
    Ok(())
}

/// Writes pull-back displacements sampled on the fixed grid (`dims`, `fixed_lps_from_index`; LPS mm, i fastest) as
/// Learn2Reg's field at `out` ([`learn2reg::voxels_from_pullback`]: each fixed voxel's step to the moving voxel it
/// reads, in the voxels of the fixed grid and of the moving grid, `moving_lps_from_index`), atomically: `.npz`
/// (float16) for a name ending so, else the NIfTI form (float32, the fixed grid's affine).
///
/// # Errors
/// A step beyond float16's range in an `.npz`, a singular moving grid, a failed write.
pub fn write_learn2reg(
    out: &Path,
    dims: [usize; 3],
    fixed_lps_from_index: &Transform<Lps, Index>,
    moving_lps_from_index: &Transform<Lps, Index>,
    displacements_lps: &[[f32; 3]],
) -> Result<(), Failure> {
    let steps =
        learn2reg::voxels_from_pullback(out, dims, fixed_lps_from_index, moving_lps_from_index, displacements_lps)?;
    if learn2reg::is_npz_name(out) {
        Ok(learn2reg::write_voxel_field(out, &steps)?)
    } else {
        Ok(learn2reg::write_voxel_field_nifti(out, &steps, fixed_lps_from_index)?)
    }
}

/// A sampled displacement field.
#[derive(Clone, Debug, PartialEq)]
pub struct SampledField {
    /// w(x) − x at each voxel centre, LPS mm, i fastest.
    pub displacements_lps: Vec<[f32; 3]>,
    /// The largest |w(x) − x| (mm, before rounding to f32), or `None` when some value is not finite.
    pub max_norm_mm: Option<f64>,
}

/// Evaluates `warp` (w: From → To, e.g. the pull-back u = `moving_from_fixed`) at every voxel centre x of the grid
/// (`dims`, `lps_from_index`) and stores w(x) − x.
///
/// Slices (constant k) are handed out one at a time to one worker per core (`std::thread::scope`); each slice is one
/// [`Warp::apply_batch_raw`] call. `progress(done, total)` is called on the calling thread, which works too, after
/// each slice it evaluates, with the number of slices finished by all workers, and once more with `(total, total)`
/// if the helpers finished the last ones. When it returns `false` no worker takes another slice, and the result is
/// `None`.
pub fn sample_displacements<To: Space, From: Space>(
    warp: &dyn Warp<To, From>,
    dims: [usize; 3],
    lps_from_index: &Transform<Lps, Index>,
    progress: &mut dyn FnMut(u64, u64) -> bool,
) -> Option<SampledField> {
    let [nx, ny, nz] = dims;
    let slice = Slices { warp, nx, per_slice: nx * ny, nz, lps_from_index: lps_from_index.rows() };
    let mut displacements_lps = vec![[0.0f32; 3]; slice.per_slice * nz];
    let queue = Mutex::new(displacements_lps.chunks_mut(slice.per_slice.max(1)).enumerate());
    let shared = Shared { queue, finished: AtomicU64::new(0), cancelled: AtomicBool::new(false) };
    let workers = std::thread::available_parallelism().map_or(1, NonZeroUsize::get).min(nz.max(1));
    let mut last_reported = 0u64;
    let results: Vec<(f64, bool)> = std::thread::scope(|s| {
        let helpers: Vec<_> =
            (1..workers).map(|_| s.spawn(|| slice.run(&shared, &mut |_: u64, _: u64| true))).collect();
        let mut all = vec![slice.run(&shared, &mut |done, total| {
            last_reported = done;
            progress(done, total)
        })];
        // A helper that panicked (a bug in a warp) makes the field not finite: reported as an internal error.
        all.extend(helpers.into_iter().map(|h| h.join().unwrap_or((f64::NAN, false))));
        all
    });
    if shared.cancelled.load(Ordering::Relaxed) {
        return None;
    }
    // The helpers may have finished the last slices (or all of them) after the calling thread's last report: the
    // caller still hears that the work reached its end.
    if last_reported < nz as u64 && !progress(nz as u64, nz as u64) {
        return None;
    }
    let finite = results.iter().all(|&(_, f)| f);
    let max_norm_mm = results.iter().map(|&(m, _)| m).fold(0.0f64, f64::max);
    Some(SampledField { displacements_lps, max_norm_mm: finite.then_some(max_norm_mm) })
}

/// What each worker of [`sample_displacements`] needs.
struct Slices<'w, To: Space, From: Space> {
    warp: &'w dyn Warp<To, From>,
    nx: usize,
    per_slice: usize,
    nz: usize,
    lps_from_index: [[f64; 4]; 4],
}

type SliceQueue<'a> = Mutex<std::iter::Enumerate<std::slice::ChunksMut<'a, [f32; 3]>>>;

/// What the workers of [`sample_displacements`] share: the slices left, how many are finished, and whether the
/// caller cancelled.
struct Shared<'a> {
    queue: SliceQueue<'a>,
    finished: AtomicU64,
    cancelled: AtomicBool,
}

impl<To: Space, From: Space> Slices<'_, To, From> {
    /// Takes slices from the queue until it is empty or the work is cancelled (`progress` returned `false`, here or
    /// on another worker); returns the largest |d| seen and whether every value was finite.
    fn run(&self, shared: &Shared, progress: &mut dyn FnMut(u64, u64) -> bool) -> (f64, bool) {
        let m = &self.lps_from_index;
        let (mut xs, mut us) = (vec![[0.0f64; 3]; self.per_slice], vec![[0.0f64; 3]; self.per_slice]);
        let (mut max_mm, mut finite) = (0.0f64, true);
        loop {
            if shared.cancelled.load(Ordering::Relaxed) {
                break;
            }
            let next = shared.queue.lock().unwrap_or_else(PoisonError::into_inner).next();
            let Some((k, slice)) = next else { break };
            for (n, x_lps) in xs.iter_mut().enumerate() {
                let ijk = [(n % self.nx) as f64, (n / self.nx) as f64, k as f64];
                *x_lps = std::array::from_fn(|r| m[r][0] * ijk[0] + m[r][1] * ijk[1] + m[r][2] * ijk[2] + m[r][3]);
            }
            self.warp.apply_batch_raw(&xs, &mut us);
            for ((d, x), u) in slice.iter_mut().zip(&xs).zip(&us) {
                let d_mm = [u[0] - x[0], u[1] - x[1], u[2] - x[2]];
                let norm = d_mm.iter().map(|v| v * v).sum::<f64>().sqrt();
                finite &= norm.is_finite();
                max_mm = max_mm.max(norm);
                *d = d_mm.map(|v| v as f32);
            }
            let done = shared.finished.fetch_add(1, Ordering::Relaxed) + 1;
            if !progress(done, self.nz as u64) {
                shared.cancelled.store(true, Ordering::Relaxed);
            }
        }
        (max_mm, finite)
    }
}

#[cfg(test)]
mod tests {
    use warpbench_solver::linear::AffineWarp;

    use super::*;

    /// x ↦ M x + t from the rows of M (built through `Transform::linear`: the app does not depend on nalgebra).
    fn transform(rows: [[f64; 3]; 3], t: [f64; 3]) -> Transform<Lps, Index> {
        let mut m = Transform::<Lps, Index>::identity().linear();
        for (r, row) in rows.iter().enumerate() {
            for (c, &v) in row.iter().enumerate() {
                m[(r, c)] = v;
            }
        }
        Transform::from_linear_translation(m, t)
    }

    #[test]
    fn every_voxel_gets_its_own_displacement_and_progress_reaches_the_end() {
        // u(x) = A x + b on an oblique grid: D(x) = (A − I) x + b differs at every voxel, so a slice written to the
        // wrong k or a voxel out of order shows.
        let a = transform([[1.02, 0.01, 0.0], [-0.01, 0.99, 0.03], [0.0, 0.02, 1.01]], [0.0; 3]).linear();
        let u: AffineWarp<Moving, Fixed> = AffineWarp::new(a, [2.0, -1.0, 0.5]);
        let lps_from_index = transform([[1.5, 0.2, 0.0], [0.0, -2.0, 0.0], [0.1, 0.0, 3.0]], [-40.0, 30.0, -20.0]);
        let dims = [7, 5, 9];
        let mut reports = Vec::new();
        let sampled = sample_displacements(&u, dims, &lps_from_index, &mut |done, total| {
            reports.push((done, total));
            true
        })
        .expect("not cancelled");
        let mut max_mm = 0.0f64;
        for k in 0..9 {
            for j in 0..5 {
                for i in 0..7 {
                    let x =
                        lps_from_index.apply_point(warpbench_io::geometry::Point3::new(i as f64, j as f64, k as f64));
                    let x = x.coords();
                    let want: [f64; 3] = std::array::from_fn(|r| u.apply_raw(x)[r] - x[r]);
                    let got = sampled.displacements_lps[i + 7 * (j + 5 * k)];
                    let err = (0..3).map(|r| (want[r] - f64::from(got[r])).abs()).fold(0.0, f64::max);
                    assert!(err < 1e-5, "voxel ({i}, {j}, {k}): {got:?} vs {want:?}");
                    max_mm = max_mm.max(want.iter().map(|v| v * v).sum::<f64>().sqrt());
                }
            }
        }
        let reported = sampled.max_norm_mm.expect("finite");
        assert!((reported - max_mm).abs() < 1e-9, "{reported} vs {max_mm}");
        assert!(!reports.is_empty() && reports.iter().all(|&(d, t)| t == 9 && (1..=9).contains(&d)));
        assert!(reports.windows(2).all(|w| w[0].0 < w[1].0), "progress goes forward: {reports:?}");
        assert_eq!(reports.last(), Some(&(9, 9)), "progress reaches the end: {reports:?}");
    }
}
