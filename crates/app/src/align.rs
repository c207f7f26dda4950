//! `warpbench align`: the automatic initial alignment ([`warpbench_solver::align`], Mattes mutual information,
//! rigid or affine, multi-resolution, from the centres of mass) written as an ITK transform file.
//!
//! The file holds the pull-back T = `moving_from_fixed` as `AffineTransform_double_3_3` (LPS mm, fixed points to
//! moving points), as ITK's registration writes its result and as `warpbench transform` writes a linear fit, so
//! SimpleITK, ANTs and Slicer apply it to the moving volume directly: a `.tfm` (text), or for a name ending in
//! `.mat` the MATLAB v4 file that ANTs writes (`antsApplyTransforms -t start.mat`), with the same numbers
//! ([`warpbench_io::itk_tfm`]).

use std::io::Write;
use std::path::PathBuf;
use std::time::Instant;

use serde::Serialize;
use warpbench_io::itk_tfm::{ItkAffine, ItkTransform};
use warpbench_io::transform_file;
use warpbench_solver::align::{AlignKind, AlignParams, LevelReport, align, rotation_angle_deg};
use warpbench_solver::image::Image;
use warpbench_solver::spaces::{Fixed, Moving};
use warpbench_solver::warp::Parallelism;

use crate::args::{ReportArgs, VolumePairArgs, help};
use crate::exit::Failure;
use crate::inputs::{OutputFile, VolumePair, load_pair};

/// The `--json` schema name.
pub const SCHEMA: &str = "warpbench-align/1";

/// What `warpbench align --help` says above the options; its first paragraph is the summary that `-h` and
/// `warpbench --help` show.
const HELP: &str = "\
Align the moving volume to the fixed one automatically, by intensities, and write the result as an ITK
transform file.

Rigid (6 parameters), or with --affine rigid then affine (12), maximising the Mattes mutual information of the
two volumes (so an MRI aligns to a CT), over 3 resolution levels (--shrink 4,2,1), from their centres of mass.
The file (AffineTransform_double_3_3) maps fixed points to moving points (LPS mm), as ITK's registration
writes its result: SimpleITK, ANTs and Slicer resample the moving volume with it. A name ending in .mat
writes the same affine as ANTs' MATLAB file (what antsRegistration writes as 0GenericAffine.mat); one ending in
.1D (.aff12.1D) as AFNI's matrix file, for 3dAllineate -1Dmatrix_apply, when neither volume is oblique; one
ending in .lta as FreeSurfer's LTA (src the moving volume, dst the fixed one), for mri_vol2vol --lta; one ending
in .xfm as an MNI transform file (the moving volume's world to the fixed one's, RAS), for mincresample. Examples:

    warpbench align --fixed ct.nii.gz --moving mr.nii.gz --out-tfm mr_to_ct.tfm
    warpbench align --fixed ct.nii.gz --moving mr.nii.gz --out-tfm mr_to_ct.mat --affine --json";

/// The arguments of `warpbench align`.
#[derive(Debug, clap::Args)]
#[command(about = crate::args::summary(HELP), long_about = HELP)]
#[command(mut_args(help(&[
    ("fixed", "The fixed volume (NIfTI, NRRD or a DICOM series folder)"),
    ("moving", "The moving volume: any modality (mutual information needs no common intensity scale)"),
])))]
pub struct AlignArgs {
    #[command(flatten)]
    pub volumes: VolumePairArgs,
    /// The ITK transform file to write (.tfm or .txt; .h5 for ITK's HDF5 file, .mat for ANTs' MATLAB file; .aff12.1D
    /// for AFNI's matrix file, .lta for FreeSurfer's, .xfm for MINC's): the pull-back, fixed points to moving points.
    #[arg(long, value_name = "FILE")]
    pub out_tfm: PathBuf,
    /// Refine the rigid result to an affine one (12 parameters) at the finest level.
    #[arg(long)]
    pub affine: bool,
    /// Fixed sample points per resolution level.
    #[arg(long, default_value_t = AlignParams::default().samples)]
    pub samples: usize,
    /// Histogram bins per image.
    #[arg(long, default_value_t = AlignParams::default().bins)]
    pub bins: usize,
    /// Shrink factors of the resolution levels, coarse to fine, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "4,2,1")]
    pub shrink: Vec<usize>,
    /// The seed of the sample points (the same seed gives the same result).
    #[arg(long, default_value_t = AlignParams::default().seed)]
    pub seed: u64,
    #[command(flatten)]
    pub report: ReportArgs,
}

/// What was found: the `--json` document, schema `warpbench-align/1` (docs/cli.md).
#[derive(Clone, Debug, Serialize)]
pub struct AlignSummary {
    pub schema: &'static str,
    pub out: String,
    pub kind: AlignKind,
    /// The result, rows of the 4×4 matrix (LPS mm): fixed points to moving points.
    pub moving_from_fixed: [[f64; 4]; 4],
    /// The centre-of-mass start, likewise.
    pub initial_moving_from_fixed: [[f64; 4]; 4],
    /// The rotation's angle (of the polar factor for an affine result), degrees.
    pub rotation_deg: f64,
    /// How far the transform moves the fixed volume's centre, mm.
    pub centre_shift_mm: f64,
    /// The final Mattes mutual information, nats.
    pub mutual_information: f64,
    pub levels: Vec<LevelReport>,
    /// Wall time of the alignment itself (reading excluded), seconds.
    pub align_s: f64,
}

/// Runs `warpbench align`: checks the output, loads both volumes, aligns, writes the file atomically; prints the JSON
/// summary to `out` with `--json`, else a line on stderr unless `--quiet`.
pub fn run(args: AlignArgs, out: &mut dyn Write) -> Result<AlignSummary, Failure> {
    let AlignArgs { volumes, out_tfm, affine, samples, bins, shrink, seed, report } = args;
    let volumes = VolumePair::given(volumes).map_err(Failure::BadInput)?;
    let VolumePair { fixed, moving, .. } = &volumes;
    let ReportArgs { json, force, quiet } = report;
    OutputFile { path: out_tfm.clone(), force }.check(&[fixed, moving]).map_err(Failure::BadInput)?;
    let params = AlignParams {
        kind: if affine { AlignKind::Affine } else { AlignKind::Rigid },
        bins,
        shrink_factors: shrink,
        samples,
        seed,
        ..AlignParams::default()
    };
    let (fixed_volume, moving_volume) = load_pair(&volumes, quiet).map_err(Failure::BadInput)?;
    // AFNI's matrix file holds the alignment only between volumes that are not oblique: refused before aligning.
    let afni_out = warpbench_io::afni::is_afni_name(&out_tfm);
    if afni_out {
        warpbench_io::afni::check_cardinal(&out_tfm, "fixed", &fixed_volume.lps_from_index)?;
        warpbench_io::afni::check_cardinal(&out_tfm, "moving", &moving_volume.lps_from_index)?;
    }
    let fixed_image = Image::<Fixed>::from_volume(&fixed_volume, Parallelism::Rayon)
        .map_err(|e| Failure::BadInput(anyhow::anyhow!("{}: {e}", fixed.display())))?;
    let moving_image = Image::<Moving>::from_volume(&moving_volume, Parallelism::Rayon)
        .map_err(|e| Failure::BadInput(anyhow::anyhow!("{}: {e}", moving.display())))?;
    // FreeSurfer's LTA states the two volumes' grids.
    let grids = ((fixed_volume.dims, fixed_volume.lps_from_index), (moving_volume.dims, moving_volume.lps_from_index));
    drop((fixed_volume, moving_volume));
    let started = Instant::now();
    let result = align(&fixed_image, &moving_image, &params)
        .map_err(|e| Failure::BadInput(anyhow::anyhow!("aligning {} to {}: {e}", moving.display(), fixed.display())))?;
    let align_s = started.elapsed().as_secs_f64();
    let t = &result.moving_from_fixed;
    if afni_out {
        warpbench_io::afni::write(&out_tfm, t.matrix())?;
    } else if warpbench_io::mni_xfm::is_xfm_name(&out_tfm) {
        warpbench_io::mni_xfm::write(&out_tfm, t.matrix())?;
    } else if warpbench_io::lta::is_lta_name(&out_tfm) {
        let ((fixed_dims, fixed_grid), (moving_dims, moving_grid)) = &grids;
        let (fixed_name, moving_name) = (fixed.display().to_string(), moving.display().to_string());
        warpbench_io::lta::write(
            &out_tfm,
            t.matrix(),
            ((*fixed_dims, fixed_grid), &fixed_name),
            ((*moving_dims, moving_grid), &moving_name),
        )?;
    } else {
        transform_file::write(&out_tfm, &ItkTransform::Affine(ItkAffine::from_offset(t.linear(), t.translation())))?;
    }

    let dims = fixed_image.dims();
    let centre = warpbench_io::geometry::Point3::<Fixed>::from_array(
        fixed_image
            .space_from_index()
            .apply_point(warpbench_io::geometry::Point3::from_array(dims.map(|d| (d - 1) as f64 / 2.0)))
            .coords(),
    );
    let moved = t.apply_point(centre);
    let summary = AlignSummary {
        schema: SCHEMA,
        out: out_tfm.display().to_string(),
        kind: params.kind,
        moving_from_fixed: t.rows(),
        initial_moving_from_fixed: result.initial_moving_from_fixed.rows(),
        rotation_deg: rotation_angle_deg(&t.linear()),
        centre_shift_mm: (0..3).map(|a| (moved.coords()[a] - centre.coords()[a]).powi(2)).sum::<f64>().sqrt(),
        mutual_information: result.mutual_information,
        levels: result.levels,
        align_s,
    };
    if json {
        crate::exit::print_json(out, &summary, "the JSON summary")?;
    } else if !quiet {
        eprintln!(
            "wrote {} ({} alignment: rotation {:.2}°, the fixed volume's centre moved {:.2} mm, mutual information \
             {:.4}, {:.2} s; maps fixed points to moving points, LPS mm)",
            summary.out,
            summary.kind,
            summary.rotation_deg,
            summary.centre_shift_mm,
            summary.mutual_information,
            align_s
        );
    }
    Ok(summary)
}
