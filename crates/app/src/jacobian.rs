//! `warpbench jacobian`: maps of the warp on the fixed grid (or of its forward map on the moving grid), as volumes:
//! det ∇u, where the warp squeezes (below 1), stretches (above 1) or folds (at or below 0), and |u(x) − x|, how far
//! it moves each point.
//!
//! At every voxel centre x of the output grid (the fixed volume's, or `--reference`'s), u = moving_from_fixed the
//! pull-back of the whole warp stack (starting transform, field, landmark fit, brush) fitted as `field` fits it:
//!
//! ```text
//! --quantity det (default):  det ∇u(x), from the warp's analytic Jacobian (the brush's through its inverse)
//! --quantity magnitude:       |u(x) − x| in mm, the length of the vector `warpbench field` writes there
//! ```
//!
//! With `--direction forward` the map is of d = fixed_from_moving instead, on the moving grid (or `--reference`'s),
//! fitted as `field --direction forward` fits it: det ∇d(y), how much the moving volume's content at y grows (above
//! 1) or shrinks on its way to the fixed volume, and |d(y) − y|.
//!
//! These are the maps BigWarp shows as its Jacobian and warp-magnitude overlays and the window draws over its
//! slices (and exports through [`jacobian_map`]); ANTs writes the first with `CreateJacobianDeterminantImage`. ITK's
//! `DisplacementFieldJacobianDeterminantFilter` computes det ∇u by central differences of a field's voxels; this is
//! the derivative itself. The map is float32, in the format its name says (`.nii`, `.nii.gz`, `.nrrd`, `.mha`,
//! `.mhd`), on the grid's geometry.

use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::anyhow;
use rayon::prelude::*;
use serde::Serialize;
use warpbench_io::displacement::FieldDirection;
use warpbench_io::geometry::Point3;
use warpbench_io::volume::VoxelData;
use warpbench_io::{Volume, volume};
use warpbench_solver::spaces::{Fixed, Moving};
use warpbench_solver::warp::Warp;

use crate::args::{PairArgs, ReportArgs, VolumePairArgs, help};
use crate::exit::Failure;
use crate::field::{DirectionArg, FieldInputs};
use crate::fit;
use crate::inputs::{self, OutputFile, PairInputs, PairVolumes};
use crate::project::stack::{Layers, StackForward, StackPullback};

/// The `--json` schema name.
pub const SCHEMA: &str = "warpbench-jacobian/1";

const HELP: &str = "\
Write a map of the warp as a volume: its Jacobian determinant, or how far it moves each point.

--quantity det (the default): det ∇u, below 1 where the warp squeezes, above 1 where it stretches, at or below 0
where it folds; --quantity magnitude: |u(x) − x| in mm. u = moving_from_fixed, the pull-back fitted on the
landmarks (and the session's or --initial's layers), evaluated exactly at every voxel centre.
--direction forward maps d = fixed_from_moving on the moving grid instead (det ∇d: above 1 where the moving
volume's content grows on its way to the fixed volume; |d(y) − y|), as field --direction forward samples d.

The map is float32, written as its name says: .nii, .nii.gz, .nrrd, .mha, .mhd, .mgh, .mgz, .mnc or .ome.zarr. --json reports the smallest and
largest value, where the smallest is, and the fraction of voxels that fold.
Examples:

    warpbench jacobian --fixed ct.nii.gz --moving mr.nii.gz --landmarks pairs.csv --out det.nii.gz
    warpbench jacobian --fixed ct.nii.gz --moving mr.nii.gz --session case.warpbench.json --quantity magnitude --out moved_mm.nrrd
    warpbench jacobian --fixed followup.nii.gz --moving baseline.nii.gz --landmarks pairs.csv --direction forward --out growth_on_baseline.nii.gz";

/// The arguments of `warpbench jacobian`.
#[derive(Debug, clap::Args)]
#[command(about = crate::args::summary(HELP), long_about = HELP)]
#[command(mut_args(help(&[
    ("fixed", "The fixed volume: its grid is the map's grid unless --reference is given"),
    ("moving", "The moving volume (landmarks are checked against it)"),
    ("json", "Print a JSON summary (schema warpbench-jacobian/1, see docs/cli.md) to stdout"),
    ("force", "Overwrite --out if it exists"),
])))]
#[command(mut_args(crate::args::or_session))]
pub struct JacobianArgs {
    #[command(flatten)]
    pub volumes: VolumePairArgs,
    #[command(flatten)]
    pub pairs: PairArgs,
    /// Sample the map on this volume's grid instead of the fixed volume's.
    #[arg(long)]
    pub reference: Option<PathBuf>,
    /// det (det ∇u) or magnitude (|u(x) − x|, mm).
    #[arg(long, value_enum, default_value = "det")]
    pub quantity: Quantity,
    /// pullback: the map of u = moving_from_fixed on the fixed grid; forward: of d = fixed_from_moving on the moving
    /// grid (det ∇d, |d(y) − y|), as `field --direction forward` samples d.
    #[arg(long, value_enum, default_value = "pullback")]
    pub direction: DirectionArg,
    /// The map to write: .nii, .nii.gz, .nrrd, .mha or .mhd.
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub report: ReportArgs,
}

/// What a map holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Quantity {
    /// det ∇u(x).
    Det,
    /// |u(x) − x|, mm.
    Magnitude,
}

impl Quantity {
    /// What a map of it is called in messages (the window's too, whose font has ASCII and Latin letters only).
    #[must_use]
    pub const fn describe(self) -> &'static str {
        match self {
            Self::Det => "Jacobian determinant",
            Self::Magnitude => "warp magnitude (mm)",
        }
    }

    /// The value of the pull-back at fixed point `x`.
    #[must_use]
    pub fn at(self, u: &StackPullback, x: [f64; 3]) -> f64 {
        match self {
            Self::Det => u.det_jacobian_at(x),
            Self::Magnitude => distance(u.apply_raw(x), x),
        }
    }

    /// The value of the forward map at moving point `p`.
    #[must_use]
    pub fn at_forward(self, d: &StackForward, p: [f64; 3]) -> f64 {
        match self {
            Self::Det => d.det_jacobian_at(p),
            Self::Magnitude => distance(d.apply_raw(p), p),
        }
    }
}

fn distance(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

/// The `--json` document, schema `warpbench-jacobian/1` (docs/cli.md).
#[derive(Clone, Debug, Serialize)]
pub struct JacobianSummary {
    pub schema: &'static str,
    pub out: String,
    pub quantity: Quantity,
    /// The output grid: voxels along i, j, k and `lps_from_index` (row-major).
    pub dims: [usize; 3],
    pub lps_from_index: [[f64; 4]; 4],
    /// `"fixed"`, `"moving"` (`--direction forward`) or `"reference"`: whose grid the map is sampled on.
    pub grid: &'static str,
    /// `"pullback"` (u = moving_from_fixed) or `"forward"` (d = fixed_from_moving): whose map it is.
    pub direction: &'static str,
    /// The method as fitted, e.g. `tps`.
    pub method: String,
    /// Landmark pairs used.
    pub pairs: usize,
    /// The smallest value, and the voxel centre (LPS mm) where it is.
    pub min: f64,
    pub min_at_lps: [f64; 3],
    pub max: f64,
    /// For `det`: the fraction of voxels where det ∇u ≤ 0 (the warp folds); null for `magnitude`.
    pub fraction_folded: Option<f64>,
}

/// Runs `warpbench jacobian`: checks the output, loads, fits, samples, writes; the summary on `out` with `--json`.
pub fn run(args: JacobianArgs, out: &mut dyn Write) -> Result<JacobianSummary, Failure> {
    let JacobianArgs { volumes, pairs, reference, quantity, direction, out: out_path, report } = args;
    let direction = FieldDirection::from(direction);
    let ReportArgs { json, force, quiet } = report;
    let inputs = PairInputs::new(volumes, pairs, reference, quiet).map_err(Failure::BadInput)?;
    let output = OutputFile { path: out_path, force };
    output.check(&inputs.paths()).map_err(Failure::BadInput)?;
    crate::warp::check_data_file(&output.path, &inputs.paths(), force).map_err(Failure::BadInput)?;
    crate::warp::check_outputs(&output.path, None).map_err(Failure::BadInput)?;
    let method = inputs.method().map_err(Failure::BadInput)?;
    let PairVolumes { fixed, moving, reference } = inputs.load_volumes(quiet).map_err(Failure::BadInput)?;
    let names = inputs.names(&output.path);
    let mut layers = Layers::new(
        inputs.start(&fixed, &moving).map_err(Failure::BadInput)?,
        inputs.brushed().map_err(Failure::BadInput)?,
    );
    layers.field = inputs.warp.field(&fixed, &moving).map_err(Failure::BadInput)?;
    crate::inputs::note_field_warnings(layers.field.as_deref(), quiet);
    let (grid, grid_name) = match (&reference, direction) {
        (Some(r), _) => (r, "reference"),
        (None, FieldDirection::Pullback) => (&fixed, "fixed"),
        (None, FieldDirection::Forward) => (&moving, "moving"),
    };
    crate::warp::check_output_grid(&output.path, grid).map_err(Failure::BadInput)?;
    let pairs = inputs.pairs().map_err(Failure::BadInput)?;
    let made_of =
        FieldInputs { fixed: &fixed, moving: &moving, pairs, names: &names, method: &method, layers: &layers };
    let map = jacobian_map(grid, &made_of, quantity, direction)?;
    warpbench_io::write_volume(&output.path, &map.volume)?;
    let summary = JacobianSummary {
        schema: SCHEMA,
        out: output.path.display().to_string(),
        quantity,
        dims: map.volume.dims,
        lps_from_index: map.volume.lps_from_index.rows(),
        grid: grid_name,
        direction: match direction {
            FieldDirection::Pullback => "pullback",
            FieldDirection::Forward => "forward",
        },
        method: map.method.clone(),
        pairs: map.pairs,
        min: map.min,
        min_at_lps: map.min_at_lps,
        max: map.max,
        fraction_folded: map.fraction_folded,
    };
    if json {
        crate::exit::print_json(out, &summary, "the JSON summary")?;
    } else if !quiet {
        let d = summary.dims;
        eprintln!(
            "wrote {} ({} map, {}×{}×{}, {} landmark pairs, {}, from {:.4} to {:.4})",
            summary.out,
            quantity.describe(),
            d[0],
            d[1],
            d[2],
            summary.pairs,
            summary.method,
            summary.min,
            summary.max
        );
    }
    Ok(summary)
}

/// `quantity` of the pull-back made of `inputs` (the pairs checked as `field` checks them, fitted over the fixed
/// box on the stack's layers), or of the forward map (fitted over the moving box, as `field --direction forward`
/// fits it), at every voxel centre of `grid`: what `warpbench jacobian` writes, and the window's export.
///
/// # Errors
/// Bad pairs or a failed fit (bad input), as `field`; and as [`sample_map`].
pub fn jacobian_map(
    grid: &Volume,
    inputs: &FieldInputs,
    quantity: Quantity,
    direction: FieldDirection,
) -> Result<Map, Failure> {
    let FieldInputs { fixed, moving, pairs, names, method, layers } = *inputs;
    let c = inputs::check_pairs(&names.landmarks, pairs, moving, fixed, layers.min_pairs(method))
        .map_err(Failure::BadInput)?;
    let mut map = match direction {
        FieldDirection::Pullback => {
            let u = fit::pullback_stack(method, &c, inputs::volume_box::<Fixed>(fixed), layers.clone())
                .map_err(Failure::BadInput)?;
            sample_map(&u, quantity, grid, &names.out)?
        }
        FieldDirection::Forward => {
            let d = fit::forward_stack(method, &c, inputs::volume_box::<Moving>(moving), layers.clone())
                .map_err(Failure::BadInput)?;
            sample_map_with(|p| quantity.at_forward(&d, p), quantity, grid, &names.out)?
        }
    };
    map.method = crate::brushed::describe(method, layers.brushed());
    map.pairs = c.moving.len();
    Ok(map)
}

/// A map on a grid, and what `--json` says of it.
#[derive(Clone, Debug)]
pub struct Map {
    /// The values, float32, on the grid's geometry.
    pub volume: Volume,
    /// The smallest value, and the voxel centre (LPS mm) where it is first.
    pub min: f64,
    pub min_at_lps: [f64; 3],
    pub max: f64,
    /// For det ∇u: the fraction of voxels at or below 0.
    pub fraction_folded: Option<f64>,
    /// The warp's method as fitted, and its pairs ([`jacobian_map`] fills them in).
    pub method: String,
    pub pairs: usize,
}

/// `quantity` of `u` at every voxel centre of `grid` (only its geometry is read), as a float32 volume on that grid
/// named `name`, on every core.
///
/// # Errors
/// The map too large for memory; a value that is not finite in f32 (an internal error naming the voxel).
pub fn sample_map(u: &StackPullback, quantity: Quantity, grid: &Volume, name: &Path) -> Result<Map, Failure> {
    sample_map_with(|x| quantity.at(u, x), quantity, grid, name)
}

/// [`sample_map`] of `value`, the map's value at a voxel centre (LPS mm), which is `quantity` (of the pull-back or
/// of the forward map: [`Quantity::at`], [`Quantity::at_forward`]).
///
/// # Errors
/// As [`sample_map`].
pub fn sample_map_with(
    value: impl Fn([f64; 3]) -> f64 + Sync,
    quantity: Quantity,
    grid: &Volume,
    name: &Path,
) -> Result<Map, Failure> {
    let n = volume::check_allocation(name, grid.dims, 4, volume::DEFAULT_MAX_VOXEL_BYTES)?;
    let [nx, ny, _] = grid.dims;
    let lps_from_index = grid.lps_from_index;
    let centre = |v: usize| {
        let ijk = [(v % nx) as f64, ((v / nx) % ny) as f64, (v / (nx * ny)) as f64];
        lps_from_index.apply_point(Point3::new(ijk[0], ijk[1], ijk[2])).coords()
    };
    let values: Vec<f32> = (0..n).into_par_iter().map(|v| value(centre(v)) as f32).collect();
    if let Some(v) = values.iter().position(|v| !v.is_finite()) {
        let ijk = [v % nx, (v / nx) % ny, v / (nx * ny)];
        return Err(Failure::Internal(anyhow!(
            "the warp's {} is not finite at voxel {ijk:?} (i, j, k)",
            quantity.describe()
        )));
    }
    let (mut at, mut min, mut max, mut folded) = (0, f64::INFINITY, f64::NEG_INFINITY, 0usize);
    for (v, &value) in values.iter().enumerate() {
        let value = f64::from(value);
        if value < min {
            (min, at) = (value, v);
        }
        max = max.max(value);
        folded += usize::from(value <= 0.0);
    }
    let fraction_folded = (quantity == Quantity::Det).then(|| folded as f64 / n.max(1) as f64);
    let volume = Volume::new(name, grid.dims, VoxelData::F32(values), lps_from_index, grid.geometry_source)?;
    Ok(Map { volume, min, min_at_lps: centre(at), max, fraction_folded, method: String::new(), pairs: 0 })
}
