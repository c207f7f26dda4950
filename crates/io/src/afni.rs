//! AFNI's affine matrix file (`.aff12.1D`), what `3dAllineate -1Dmatrix_save`, `3dvolreg -1Dmatrix_save` and
//! `cat_matvec` write and `3dAllineate -1Dmatrix_apply` reads: comment lines starting with `#`, then one row of twelve
//! numbers per matrix, the 3 × 4 matrix row by row. AFNI's documentation (R. W. Cox, "-1Dmatrix_save and
//! -1Dmatrix_apply", 2007) defines it as the base-to-source transformation in DICOM coordinates: it takes (x, y, z) in
//! the base image to (x, y, z) in the source image, with x to the left, y to the back and z up. That is warpbench's
//! pull-back u (fixed points to moving points, LPS mm) with the base as the fixed volume and the source as the moving
//! one, so the file's numbers are u's own.
//!
//! AFNI's programs work on an oblique dataset in its "cardinal" coordinates (its obliquity dropped) unless told
//! otherwise, and the matrix is then not a map between the datasets' real positions; warpbench refuses the file when
//! either volume is oblique (an axis more than 0.01° from the nearest axis of the patient space, as nitransforms
//! tells obliquity) rather than guess ([`check_cardinal`]).
//!
//! Reading takes exactly one row of 12 finite numbers (`3dvolreg` writes one per sub-brick of a time series: keep the
//! one you mean), in a text file of at most 64 KiB; anything else is refused, naming the file. Writing puts AFNI's
//! comment line and the row, each number as the shortest decimal that reads back to it.

use std::path::Path;

use nalgebra::Matrix4;

use crate::error::{Error, Result};
use crate::files::read_small_text;
use crate::geometry::{Index, Lps, Transform};

/// The largest file read (3dvolreg's one row per sub-brick of a long run stays well under it).
const MAX_BYTES: u64 = 65_536;

/// The comment line AFNI's programs write above the rows.
const HEADER: &str = "# 3dAllineate matrices (DICOM-to-DICOM, row-by-row):";

/// An oblique axis: more than this many degrees from the nearest axis of the patient space.
pub const OBLIQUE_DEGREES: f64 = 0.01;

/// Whether `path` is named as AFNI's matrix files are: ending `.1D` (`.aff12.1D`), in any case.
#[must_use]
pub fn is_afni_name(path: &Path) -> bool {
    path.extension().is_some_and(|e| e.eq_ignore_ascii_case("1d"))
}

/// The rows of `text` that are not comments or blank.
fn rows(text: &str) -> Vec<&str> {
    text.lines().map(str::trim).filter(|l| !l.is_empty() && !l.starts_with('#')).collect()
}

/// Whether `head` (a file's first bytes) is meant as an AFNI matrix file: text whose rows are each twelve numbers
/// ([`parse`] says what else it needs). A last row without its line end may be cut by the head's length (3dvolreg's
/// file of many rows), and is not looked at.
#[must_use]
pub fn looks_like_afni_matrix(head: &[u8]) -> bool {
    let Some(text) = crate::files::head_text(head) else { return false };
    let mut rows = rows(text);
    if rows.len() > 1 && !text.ends_with('\n') {
        rows.pop();
    }
    !rows.is_empty()
        && rows.iter().all(|row| {
            let values: Vec<&str> = row.split_whitespace().collect();
            values.len() == 12 && values.iter().all(|v| v.parse::<f64>().is_ok())
        })
}

/// Reads the AFNI matrix at `path`: u = `moving_from_fixed`, LPS mm (module docs).
///
/// # Errors
/// A file that is not a regular file or cannot be read, one larger than 64 KiB, or text that is not one AFNI matrix;
/// the message names the file.
pub fn read(path: &Path) -> Result<Matrix4<f64>> {
    parse(path, &read_small_text(path, MAX_BYTES, "an AFNI matrix file (.aff12.1D)")?)
}

/// Parses an AFNI matrix file's text (module docs); `path` names it in errors.
///
/// # Errors
/// No row, more than one, or a row that is not twelve finite numbers.
pub fn parse(path: &Path, text: &str) -> Result<Matrix4<f64>> {
    let rows = rows(text);
    let row = match rows.as_slice() {
        [row] => row,
        [] => return Err(Error::invalid(path, "no matrix: an AFNI matrix file has a row of 12 numbers")),
        more => {
            return Err(Error::invalid(
                path,
                format!(
                    "{} matrices (3dvolreg writes one per sub-brick of a time series): keep the one row you mean, \
                     e.g. with cat_matvec",
                    more.len()
                ),
            ));
        }
    };
    let values: Vec<&str> = row.split_whitespace().collect();
    if values.len() != 12 {
        return Err(Error::invalid(path, format!("{} numbers on the matrix's row, not 12", values.len())));
    }
    let mut m = Matrix4::identity();
    for (n, v) in values.iter().enumerate() {
        let value: f64 = v
            .parse()
            .ok()
            .filter(|x: &f64| x.is_finite())
            .ok_or_else(|| Error::invalid(path, format!("number {}: {v:?} is not a finite number", n + 1)))?;
        m[(n / 4, n % 4)] = value;
    }
    Ok(m)
}

/// The largest angle, in degrees, between an axis of `lps_from_index` and the nearest axis of the patient space.
#[must_use]
pub fn obliquity_degrees(lps_from_index: &Transform<Lps, Index>) -> f64 {
    let linear = lps_from_index.linear();
    (0..3)
        .map(|c| {
            let column = linear.column(c);
            let cosine = column.amax() / column.norm();
            cosine.clamp(-1.0, 1.0).acos().to_degrees()
        })
        .fold(0.0, f64::max)
}

/// Refuses an oblique grid (module docs): `which` names the volume, `path` the matrix file.
///
/// # Errors
/// The volume is oblique.
pub fn check_cardinal(path: &Path, which: &str, lps_from_index: &Transform<Lps, Index>) -> Result<()> {
    let degrees = obliquity_degrees(lps_from_index);
    if degrees > OBLIQUE_DEGREES {
        return Err(Error::invalid(
            path,
            format!(
                "the {which} volume is oblique ({degrees:.3}° off the patient axes): AFNI's matrices between oblique \
                 datasets are in their cardinal coordinates, which warpbench does not guess; deoblique the volumes \
                 (3dWarp -deoblique) and register again, or write the transform as ITK's (.tfm)"
            ),
        ));
    }
    Ok(())
}

/// The text of an AFNI matrix file: AFNI's comment line, then the row of `moving_from_fixed`'s twelve numbers.
#[must_use]
pub fn to_text(moving_from_fixed: &Matrix4<f64>) -> String {
    let row: Vec<String> = (0..12).map(|n| format!("{}", moving_from_fixed[(n / 4, n % 4)] + 0.0)).collect();
    format!("{HEADER}\n{}\n", row.join(" "))
}

/// Writes `moving_from_fixed` as an AFNI matrix file at `path`, atomically ([`to_text`]).
///
/// # Errors
/// A number that is not finite, or the write itself.
pub fn write(path: &Path, moving_from_fixed: &Matrix4<f64>) -> Result<()> {
    if !moving_from_fixed.iter().all(|v| v.is_finite()) {
        return Err(Error::invalid(path, "the matrix is not finite"));
    }
    let text = to_text(moving_from_fixed);
    crate::write_atomic(path, |w| w.write_all(text.as_bytes()))
}
