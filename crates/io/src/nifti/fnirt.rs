//! The two files FSL's FNIRT writes for a nonlinear warp, as they are stored ([`crate::fnirt`] turns them into the
//! pull-back): a deformation field (`fnirt --fout`, `convertwarp --out`, intent 2006) and a cubic B-spline coefficient
//! field (`fnirt --cout`, intent 2007), each a float (X, Y, Z, 3) array.
//!
//! A coefficient field uses the header its own way (FSL's `fnirt_file_writer.cpp`, as fslpy reads it): `pixdim` holds
//! the knot spacing in reference voxels, `intent_p1..3` the reference image's voxel sizes, the qform's offsets the
//! reference image's dims, and the sform the affine FNIRT started from (a FLIRT matrix, source to reference).

use std::path::Path;

use flate2::read::MultiGzDecoder;
use nalgebra::Matrix4;

use super::field::{field_dims, read_planes, write_frames_with_intent};
use super::geometry::lps_from_index;
use super::header::{Header, pair_error, read_header};
use super::source::{Extent, GZIP_MAGIC, Source, open_file};
use crate::error::{Error, Result};
use crate::geometry::{Index, Lps, Transform};
use crate::volume::GeometrySource;

/// `FSL_FNIRT_DISPLACEMENT_FIELD` (FSL's NIfTI intents): a deformation field, relative displacements or absolute
/// coordinates in mm.
pub const FSL_FNIRT_DISPLACEMENT_FIELD: i32 = 2006;
/// `FSL_CUBIC_SPLINE_COEFFICIENTS`: FNIRT's cubic B-spline coefficients.
pub const FSL_CUBIC_SPLINE_COEFFICIENTS: i32 = 2007;
/// `FSL_DCT_COEFFICIENTS`: discrete cosine transform coefficients.
pub const FSL_DCT_COEFFICIENTS: i32 = 2008;
/// `FSL_QUADRATIC_SPLINE_COEFFICIENTS`: FNIRT's quadratic B-spline coefficients.
pub const FSL_QUADRATIC_SPLINE_COEFFICIENTS: i32 = 2009;
/// `FSL_TOPUP_CUBIC_SPLINE_COEFFICIENTS`: TOPUP's field in Hz as cubic B-spline coefficients.
pub const FSL_TOPUP_CUBIC_SPLINE_COEFFICIENTS: i32 = 2016;
/// `FSL_TOPUP_QUADRATIC_SPLINE_COEFFICIENTS`: TOPUP's field in Hz as quadratic B-spline coefficients.
pub const FSL_TOPUP_QUADRATIC_SPLINE_COEFFICIENTS: i32 = 2017;
/// `FSL_TOPUP_FIELD`: TOPUP's off-resonance field in Hz.
pub const FSL_TOPUP_FIELD: i32 = 2018;

/// Every FSL intent code: a NIfTI file that carries one is FSL's, whatever else it holds.
pub const FSL_INTENTS: [i32; 7] = [
    FSL_FNIRT_DISPLACEMENT_FIELD,
    FSL_CUBIC_SPLINE_COEFFICIENTS,
    FSL_DCT_COEFFICIENTS,
    FSL_QUADRATIC_SPLINE_COEFFICIENTS,
    FSL_TOPUP_CUBIC_SPLINE_COEFFICIENTS,
    FSL_TOPUP_QUADRATIC_SPLINE_COEFFICIENTS,
    FSL_TOPUP_FIELD,
];

/// An FNIRT file as stored.
#[derive(Clone, Debug, PartialEq)]
pub enum FnirtFile {
    /// A deformation field on the reference image's grid: at each voxel a relative displacement or an absolute
    /// position, in FSL's coordinates (mm) of the source image, the vector's components as stored.
    Deformation {
        dims: [usize; 3],
        /// The field's own grid, from its sform or qform (FNIRT copies the reference image's), and which it came
        /// from; `None` when both codes are 0.
        lps_from_index: Option<(Transform<Lps, Index>, GeometrySource)>,
        vectors: Vec<[f32; 3]>,
    },
    /// Cubic B-spline coefficients over the reference image's voxels.
    CubicCoefficients(CoefficientField),
}

/// A cubic B-spline coefficient field (module docs).
#[derive(Clone, Debug, PartialEq)]
pub struct CoefficientField {
    /// Knots along i, j, k.
    pub dims: [usize; 3],
    /// Reference voxels between knots (`pixdim`).
    pub knot_spacing: [f64; 3],
    /// The reference image's voxel sizes, mm (`intent_p1..3`).
    pub reference_spacing_mm: [f64; 3],
    /// The reference image's dims (the qform's offsets).
    pub reference_dims: [usize; 3],
    /// The affine FNIRT started from (the sform): a FLIRT matrix from the source image's FSL coordinates to the
    /// reference image's.
    pub reference_from_source_fsl: Matrix4<f64>,
    /// The coefficients, mm in the reference image's FSL coordinates, i fastest.
    pub coefficients: Vec<[f32; 3]>,
}

/// The FSL intent code of the NIfTI file at `path` (plain or gzip), if it has one of [`FSL_INTENTS`]; `None` for
/// any other NIfTI file or any file that is not NIfTI.
///
/// # Errors
/// The file cannot be opened or read.
pub fn fsl_intent(path: &Path) -> Result<Option<i32>> {
    Ok(intent_code(path)?.filter(|c| FSL_INTENTS.contains(c)))
}

/// The intent code of the NIfTI file at `path` (plain or gzip), read from its header alone; `None` for a folder or a
/// file whose first bytes are no NIfTI header.
///
/// # Errors
/// The file cannot be opened or read.
pub fn intent_code(path: &Path) -> Result<Option<i32>> {
    if path.is_dir() {
        return Ok(None);
    }
    let (mut src, _) = open_file(path)?;
    Ok(read_header(path, &mut src).ok().map(|h| h.intent_code))
}

/// Reads the FNIRT file at `path` (`.nii` or `.nii.gz`). Errors name the file: another intent (a TOPUP field, a DCT
/// or quadratic coefficient field among them, each named), a shape that is not (X, Y, Z, 3), a sample type other
/// than float, a vector that is not finite.
pub fn read_fnirt_file(path: &Path) -> Result<FnirtFile> {
    let (mut src, extent) = open_file(path)?;
    read_source(path, &mut src, extent)
}

/// [`read_fnirt_file`] from memory (gzip detected by the magic bytes); `name` is used in errors.
pub fn read_fnirt_file_bytes(name: &Path, bytes: &[u8]) -> Result<FnirtFile> {
    if bytes.starts_with(&GZIP_MAGIC) {
        read_source(name, &mut MultiGzDecoder::new(bytes), Extent::Gzip(bytes.len() as u64))
    } else {
        let mut src = bytes;
        read_source(name, &mut src, Extent::Exact(bytes.len() as u64))
    }
}

fn read_source<S: Source>(path: &Path, src: &mut S, extent: Extent) -> Result<FnirtFile> {
    let h = read_header(path, src)?;
    if h.pair {
        return Err(pair_error(path, "an FNIRT warp is read from one .nii or .nii.gz file"));
    }
    let refused = |what: &str| Err(Error::unsupported(path, format!("intent_code {}: {what}", h.intent_code)));
    match h.intent_code {
        FSL_FNIRT_DISPLACEMENT_FIELD | FSL_CUBIC_SPLINE_COEFFICIENTS => {}
        FSL_QUADRATIC_SPLINE_COEFFICIENTS => {
            return refused(
                "FNIRT's quadratic B-spline coefficients are not read; write the warp as a deformation field with \
                 FSL's `fnirtfileutils --in=COEF --ref=REF --out=FIELD` and give that",
            );
        }
        FSL_DCT_COEFFICIENTS => {
            return refused(
                "discrete cosine transform coefficients are not read; write the warp as a deformation field with \
                 FSL's `fnirtfileutils --in=COEF --ref=REF --out=FIELD` and give that",
            );
        }
        FSL_TOPUP_FIELD | FSL_TOPUP_CUBIC_SPLINE_COEFFICIENTS | FSL_TOPUP_QUADRATIC_SPLINE_COEFFICIENTS => {
            return refused("a TOPUP off-resonance field (Hz), not a registration warp; FSL's `applytopup` applies it");
        }
        _ => return refused("not an FSL FNIRT warp (intent 2006, a deformation field, or 2007, coefficients)"),
    }
    if h.dim[0] != 4 || h.dim[4] != 3 || h.dim[1..4].iter().any(|&d| d < 1) {
        return Err(Error::invalid(
            path,
            format!("dim = {:?}; an FNIRT warp is an (X, Y, Z, 3) array, dim = [4, X, Y, Z, 3, …]", h.dim),
        ));
    }
    let dims = field_dims(path, &h)?;
    let vectors = read_planes(path, src, extent, &h, dims, [1.0; 3], 0)?;
    if h.intent_code == FSL_FNIRT_DISPLACEMENT_FIELD {
        let lps_from_index = if h.sform_code > 0 || h.qform_code > 0 {
            let (t, source, _) = lps_from_index(path, &h, dims)?;
            Some((t, source))
        } else {
            None
        };
        return Ok(FnirtFile::Deformation { dims, lps_from_index, vectors });
    }
    coefficient_field(path, &h, dims, vectors).map(FnirtFile::CubicCoefficients)
}

fn coefficient_field(
    path: &Path,
    h: &Header,
    dims: [usize; 3],
    coefficients: Vec<[f32; 3]>,
) -> Result<CoefficientField> {
    let knot_spacing = [h.pixdim[1], h.pixdim[2], h.pixdim[3]];
    let reference_spacing_mm = h.intent_p;
    let reference_dims = h.qoffset;
    let positive = |v: &[f64; 3]| v.iter().all(|&x| x.is_finite() && x > 0.0);
    if !positive(&knot_spacing) {
        return Err(Error::invalid(path, format!("knot spacing (pixdim 1..3) {knot_spacing:?}: not positive")));
    }
    if !positive(&reference_spacing_mm) {
        return Err(Error::invalid(
            path,
            format!("the reference image's voxel sizes (intent_p1..3) {reference_spacing_mm:?}: not positive"),
        ));
    }
    if !positive(&reference_dims) || reference_dims.iter().any(|d| d.fract() != 0.0) {
        return Err(Error::invalid(
            path,
            format!("the reference image's dims (the qform's offsets) {reference_dims:?}: not whole positive numbers"),
        ));
    }
    let mut m = Matrix4::identity();
    for (r, row) in h.srow.iter().enumerate() {
        for (c, &v) in row.iter().enumerate() {
            m[(r, c)] = v;
        }
    }
    if h.sform_code <= 0 {
        // FNIRT always writes the affine it started from; fslpy takes an unset sform as the identity.
        m = Matrix4::identity();
    }
    if !m.iter().all(|v| v.is_finite()) || m.fixed_view::<3, 3>(0, 0).determinant().abs() < 1e-12 {
        return Err(Error::invalid(
            path,
            "the starting affine (the sform) is singular or not finite: not an FNIRT coefficient field",
        ));
    }
    #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss, reason = "whole and positive, checked above")]
    let reference_dims = reference_dims.map(|d| d as usize);
    Ok(CoefficientField {
        dims,
        knot_spacing,
        reference_spacing_mm,
        reference_dims,
        reference_from_source_fsl: m,
        coefficients,
    })
}

/// Writes an FNIRT deformation field of relative displacements (what `fnirt --fout` writes), atomically: float32,
/// dim = [4, X, Y, Z, 3], intent 2006, the reference grid's sform and qform, and `displacements_fsl` (mm, in the
/// reference's and input's FSL coordinates) as they are. Non-finite vectors are refused.
///
/// # Errors
/// A grid NIfTI-1 cannot hold, a vector that is not finite, a failed write (named by `path`).
pub fn write_deformation_field(
    path: &Path,
    reference: ([usize; 3], &Transform<Lps, Index>),
    displacements_fsl: &[[f32; 3]],
) -> Result<()> {
    #[allow(clippy::cast_possible_truncation, reason = "2006 fits in NIfTI-1's i16 intent code")]
    let intent = FSL_FNIRT_DISPLACEMENT_FIELD as i16;
    write_frames_with_intent(path, reference, displacements_fsl, "warpbench FNIRT field, relative, mm", intent)
}
