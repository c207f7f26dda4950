//! An elastix transform as the displacement field transformix writes for it (`transformix -def all`).

use std::path::Path;

use rayon::prelude::*;

use super::read::read_transform;
use super::transform::ElastixTransform;
use crate::error::{Error, Result};
use crate::geometry::Point3;
use crate::nifti::DisplacementField;
use crate::volume::{self, GeometrySource};

/// Reads the elastix transform parameter file at `path` with its chain ([`read_transform`]) and samples it at every
/// voxel centre x of the fixed grid the file names: D(x) = T(x) − x, LPS mm, the pull-back, as
/// `transformix -def all` writes `deformationField.mhd`. Errors name the file: one without the grid
/// (`Size`, `Spacing`, `Origin`), a field too large for memory, a displacement that is not finite in f32.
pub fn read_field(path: &Path) -> Result<DisplacementField> {
    let transform = read_transform(path)?;
    sample(path, &transform)
}

/// [`read_field`] of a chain already read; `name` is used in errors.
///
/// # Errors
/// As [`read_field`].
pub fn sample(name: &Path, transform: &ElastixTransform) -> Result<DisplacementField> {
    let grid = transform.grid.as_ref().ok_or_else(|| {
        Error::invalid(name, "the file gives no fixed grid (Size, Spacing, Origin), so there is nowhere to sample it")
    })?;
    let n = volume::check_allocation(name, grid.dims, 12, volume::DEFAULT_MAX_VOXEL_BYTES)?;
    let mut displacements_lps: Vec<[f32; 3]> = volume::try_with_capacity(name, n, "the displacement vectors")?;
    let [nx, ny, _] = grid.dims;
    (0..n)
        .into_par_iter()
        .map(|v| {
            let ijk = [(v % nx) as f64, ((v / nx) % ny) as f64, (v / (nx * ny)) as f64];
            let x = grid.lps_from_index.apply_point(Point3::new(ijk[0], ijk[1], ijk[2])).coords();
            let y = transform.apply(x);
            [(y[0] - x[0]) as f32, (y[1] - x[1]) as f32, (y[2] - x[2]) as f32]
        })
        .collect_into_vec(&mut displacements_lps);
    if let Some(ijk) = crate::displacement::check::first_non_finite(grid.dims, &displacements_lps) {
        return Err(Error::invalid(name, format!("the displacement at voxel {ijk:?} (i, j, k) is not finite")));
    }
    Ok(DisplacementField {
        dims: grid.dims,
        lps_from_index: grid.lps_from_index,
        geometry_source: GeometrySource::ElastixParameters,
        displacements_lps,
    })
}
