//! FSL's FLIRT affine matrix (`flirt -omat`, `convert_xfm`), the linear transform of FSL's pipelines: a text file of
//! four rows of four numbers, M, which maps a point of the input (moving) image to the reference (fixed) image in
//! FSL's own coordinates of each.
//!
//! FSL's coordinates of an image are its voxel indices scaled by the voxel size, in mm, with the first axis reversed
//! when the image's voxel-to-world matrix has a positive determinant (a "neurological" image, as FSL calls it):
//! x_FSL = S · (i, j, k, 1) with S = diag(dx, dy, dz) for a negative determinant and, for a positive one,
//! i replaced by (nx − 1) − i. The voxel sizes are the lengths of the matrix's columns, so a sheared or oblique
//! grid is read as FSL reads it. The determinant of the LPS matrix is that of NIfTI's RAS one (two axes turn).
//!
//! With W the fixed and moving images' `lps_from_index` and S their FSL matrices, the pull-back warpbench uses
//! (fixed points to moving points, LPS mm) is
//!
//! ```text
//! u = W_moving · S_moving⁻¹ · M⁻¹ · S_fixed · W_fixed⁻¹,
//! ```
//!
//! and a pull-back u is written as M = S_fixed · W_fixed⁻¹ · u⁻¹ · W_moving · S_moving⁻¹ (nitransforms'
//! `FSLLinearTransform.to_ras` and `from_ras` make the same products in RAS). So a FLIRT matrix means nothing
//! without the two images it was made with.
//!
//! Reading takes 16 finite numbers on four lines (any whitespace between them, blank lines ignored), whose last row is
//! (0, 0, 0, 1) within 1e-6, in a file of at most 4 KiB; anything else is refused, naming the file. Writing puts
//! each row on a line, twelve decimals, two spaces apart, as FLIRT writes its own (with six).

use std::path::Path;

use nalgebra::{Matrix3, Matrix4};

use crate::error::{Error, Result};
use crate::files::read_small_text;
use crate::geometry::{Index, Lps, Transform};

/// The largest FLIRT matrix file read (FLIRT's own are about 150 bytes).
const MAX_BYTES: u64 = 4096;

/// An image's grid, as the conversions need it: voxels along i, j, k and its `lps_from_index`.
pub type Grid<'a> = ([usize; 3], &'a Transform<Lps, Index>);

/// Whether `head` (a file's first bytes) is meant as a FLIRT matrix: short text of four lines of four numbers
/// ([`parse`] says what else it needs).
#[must_use]
pub fn looks_like_flirt_matrix(head: &[u8]) -> bool {
    let Some(text) = std::str::from_utf8(head).ok().filter(|_| head.len() < MAX_BYTES as usize) else {
        return false;
    };
    let rows: Vec<&str> = text.lines().map(str::trim).filter(|l| !l.is_empty()).collect();
    rows.len() == 4
        && rows.iter().all(|row| {
            let values: Vec<&str> = row.split_whitespace().collect();
            values.len() == 4 && values.iter().all(|v| v.parse::<f64>().is_ok())
        })
}

/// Reads the FLIRT matrix at `path` (module docs).
///
/// # Errors
/// A file that is not a regular file or cannot be read, one larger than 4 KiB, or text that is not a FLIRT matrix;
/// the message names the file.
pub fn read(path: &Path) -> Result<Matrix4<f64>> {
    parse(path, &read_small_text(path, MAX_BYTES, "a FLIRT matrix (four lines of four numbers)")?)
}

/// Parses a FLIRT matrix's text (module docs); `path` names it in errors.
///
/// # Errors
/// Not four lines of four finite numbers, or a last row that is not (0, 0, 0, 1).
pub fn parse(path: &Path, text: &str) -> Result<Matrix4<f64>> {
    let rows: Vec<&str> = text.lines().map(str::trim).filter(|l| !l.is_empty()).collect();
    if rows.len() != 4 {
        return Err(Error::invalid(path, format!("{} lines of numbers: a FLIRT matrix has 4", rows.len())));
    }
    let mut m = Matrix4::zeros();
    for (r, row) in rows.iter().enumerate() {
        let values: Vec<&str> = row.split_whitespace().collect();
        if values.len() != 4 {
            return Err(Error::invalid(path, format!("line {}: {} numbers, not 4", r + 1, values.len())));
        }
        for (c, v) in values.iter().enumerate() {
            let value: f64 = v
                .parse()
                .ok()
                .filter(|x: &f64| x.is_finite())
                .ok_or_else(|| Error::invalid(path, format!("line {}: {v:?} is not a finite number", r + 1)))?;
            m[(r, c)] = value;
        }
    }
    let last = [m[(3, 0)], m[(3, 1)], m[(3, 2)], m[(3, 3)] - 1.0];
    if last.iter().any(|v| v.abs() > 1e-6) {
        return Err(Error::invalid(path, "the last line is not 0 0 0 1: not an affine FLIRT matrix"));
    }
    m.set_row(3, &nalgebra::RowVector4::new(0.0, 0.0, 0.0, 1.0));
    Ok(m)
}

/// FSL's coordinates of a grid's voxels: x_FSL = S · (i, j, k, 1) (module docs).
#[must_use]
pub fn fsl_from_index((dims, lps_from_index): Grid<'_>) -> Matrix4<f64> {
    let linear: Matrix3<f64> = lps_from_index.linear();
    let sizes = [linear.column(0).norm(), linear.column(1).norm(), linear.column(2).norm()];
    let mut s = Matrix4::from_diagonal(&nalgebra::Vector4::new(sizes[0], sizes[1], sizes[2], 1.0));
    if linear.determinant() > 0.0 {
        s[(0, 0)] = -sizes[0];
        s[(0, 3)] = dims[0].saturating_sub(1) as f64 * sizes[0];
    }
    s
}

/// The pull-back u (fixed points to moving points, LPS mm) of the FLIRT matrix `flirt` made with `fixed` as the
/// reference and `moving` as the input (module docs).
///
/// # Errors
/// A matrix or a grid that cannot be inverted (`name` names the file).
pub fn moving_from_fixed(name: &Path, flirt: &Matrix4<f64>, fixed: Grid<'_>, moving: Grid<'_>) -> Result<Matrix4<f64>> {
    let singular = |what: &str| Error::invalid(name, format!("{what} cannot be inverted"));
    let flirt_inverse = flirt.try_inverse().ok_or_else(|| singular("the FLIRT matrix"))?;
    let fixed_index = fixed.1.matrix().try_inverse().ok_or_else(|| singular("the fixed volume's grid"))?;
    let moving_fsl = fsl_from_index(moving).try_inverse().ok_or_else(|| singular("the moving volume's grid"))?;
    Ok(moving.1.matrix() * moving_fsl * flirt_inverse * fsl_from_index(fixed) * fixed_index)
}

/// The FLIRT matrix of the pull-back `moving_from_fixed` (LPS mm) between `fixed` (FLIRT's reference) and `moving`
/// (its input): the inverse of [`moving_from_fixed`].
///
/// # Errors
/// A pull-back or a grid that cannot be inverted (`name` names the output).
pub fn flirt_from(
    name: &Path,
    moving_from_fixed: &Matrix4<f64>,
    fixed: Grid<'_>,
    moving: Grid<'_>,
) -> Result<Matrix4<f64>> {
    let singular = |what: &str| Error::invalid(name, format!("{what} cannot be inverted"));
    let fixed_from_moving = moving_from_fixed.try_inverse().ok_or_else(|| singular("the warp"))?;
    let fixed_index = fixed.1.matrix().try_inverse().ok_or_else(|| singular("the fixed volume's grid"))?;
    let moving_fsl = fsl_from_index(moving).try_inverse().ok_or_else(|| singular("the moving volume's grid"))?;
    Ok(fsl_from_index(fixed) * fixed_index * fixed_from_moving * moving.1.matrix() * moving_fsl)
}

/// The text of a FLIRT matrix: each row on a line, twelve decimals, two spaces apart.
#[must_use]
pub fn to_text(m: &Matrix4<f64>) -> String {
    let mut text = String::new();
    for r in 0..4 {
        let row: Vec<String> = (0..4).map(|c| format!("{:.12}", m[(r, c)] + 0.0)).collect();
        text.push_str(&row.join("  "));
        text.push('\n');
    }
    text
}

/// Writes `m` as a FLIRT matrix at `path`, atomically ([`to_text`]).
///
/// # Errors
/// A number that is not finite, or the write itself.
pub fn write(path: &Path, m: &Matrix4<f64>) -> Result<()> {
    if !m.iter().all(|v| v.is_finite()) {
        return Err(Error::invalid(path, "the matrix is not finite"));
    }
    let text = to_text(m);
    crate::write_atomic(path, |w| w.write_all(text.as_bytes()))
}
