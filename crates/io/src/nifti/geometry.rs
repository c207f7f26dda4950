//! `lps_from_index` from the header by the first of the spec's three methods that applies (sform, qform,
//! pixdim; see [`super`]), with a warning when the sform and the qform disagree; and, for the writer, the qform of
//! a linear part ([`qform_from_linear`]).

use std::path::Path;

use nalgebra::{Matrix3, Matrix4};

use super::header::Header;
use crate::error::{Error, Result};
use crate::geometry::{Index, Lps, Ras, Transform, lps_from_ras};
use crate::volume::{self, GeometrySource};

/// One voxel spacing from pixdim[axis] (1 to 3): its magnitude. A zero or non-finite spacing is an
/// error on an axis the file uses; beyond dim[0] the axis has one voxel and we take 1.
fn spacing(path: &Path, h: &Header, axis: usize) -> Result<f64> {
    let p = h.pixdim[axis];
    if h.dim[0] < axis as i64 && !(p.is_finite() && p != 0.0) {
        return Ok(1.0);
    }
    if !p.is_finite() || p == 0.0 {
        return Err(Error::invalid(
            path,
            format!("pixdim[{axis}] is {p}: the voxel spacing must be finite and non-zero"),
        ));
    }
    Ok(p.abs())
}

/// The qform's `ras_from_index` (NIfTI-1 method 2; `nifti_quatern_to_mat44` in nifti1_io.c).
fn ras_from_index_qform(bcd: [f64; 3], qoffset: [f64; 3], spacing: [f64; 3], qfac: f64) -> Matrix4<f64> {
    let [mut b, mut c, mut d] = bcd;
    let bcd2 = b * b + c * c + d * d;
    let a = if 1.0 - bcd2 < 1e-7 {
        let n = bcd2.sqrt();
        if n > 0.0 {
            (b, c, d) = (b / n, c / n, d / n);
        }
        0.0
    } else {
        (1.0 - bcd2).sqrt()
    };
    let rotation = Matrix3::new(
        a * a + b * b - c * c - d * d,
        2.0 * (b * c - a * d),
        2.0 * (b * d + a * c),
        2.0 * (b * c + a * d),
        a * a + c * c - b * b - d * d,
        2.0 * (c * d - a * b),
        2.0 * (b * d - a * c),
        2.0 * (c * d + a * b),
        a * a + d * d - c * c - b * b,
    );
    let scale = Matrix3::from_diagonal(&nalgebra::Vector3::new(spacing[0], spacing[1], qfac * spacing[2]));
    let mut m = Matrix4::identity();
    m.fixed_view_mut::<3, 3>(0, 0).copy_from(&(rotation * scale));
    for r in 0..3 {
        m[(r, 3)] = qoffset[r];
    }
    m
}

/// The qform's `ras_from_index` from the header's quaternion, qoffset and pixdim, checked for finite values.
fn qform(path: &Path, h: &Header) -> Result<Matrix4<f64>> {
    let spacing = [spacing(path, h, 1)?, spacing(path, h, 2)?, spacing(path, h, 3)?];
    let qfac = if h.pixdim[0] < 0.0 { -1.0 } else { 1.0 };
    if !h.quatern_bcd.iter().chain(&h.qoffset).all(|v| v.is_finite()) {
        return Err(Error::invalid(
            path,
            format!("the qform is not finite: quatern_b/c/d {:?}, qoffset {:?}", h.quatern_bcd, h.qoffset),
        ));
    }
    Ok(ras_from_index_qform(h.quatern_bcd, h.qoffset, spacing, qfac))
}

/// Two mappings of the same grid closer than this everywhere on it (and of the same handedness) agree: float32
/// storage and the qform's float32 quaternion (whose a loses digits near a 180° turn) differ by less.
const SFORM_QFORM_TOL_MM: f64 = 0.1;

/// When both the sform and the qform are set, a warning if they place the `dims` grid differently: how far apart
/// the two mappings are at the grid's 8 corner voxels (mm), whether one is the mirror image of the other, and
/// which one is used. nibabel (and we) use the sform; ITK and SimpleITK use the qform.
fn sform_qform_disagreement(path: &Path, h: &Header, sform: &Matrix4<f64>, dims: [usize; 3]) -> Option<String> {
    let (s_code, q_code) = (h.sform_code, h.qform_code);
    let q = match qform(path, h) {
        Ok(q) => q,
        Err(e) => {
            return Some(format!(
                "qform_code is {q_code} but the qform is unusable ({}); the sform (code {s_code}) is used",
                e.kind
            ));
        }
    };
    let (sform, qform): (Transform<Ras, Index>, Transform<Ras, Index>) =
        (Transform::from_matrix(*sform), Transform::from_matrix(q));
    let apart_mm = volume::corner_indices(dims)
        .into_iter()
        .map(|p| sform.apply_point(p).distance(&qform.apply_point(p)))
        .fold(0.0, f64::max);
    let mirrored = (sform.linear().determinant() < 0.0) != (qform.linear().determinant() < 0.0);
    if apart_mm <= SFORM_QFORM_TOL_MM && !mirrored {
        return None;
    }
    let handedness = if mirrored {
        "and of opposite handedness (one is the mirror image of the other, e.g. a left-right flip)"
    } else {
        "with the same handedness"
    };
    Some(format!(
        "the sform (code {s_code}) and the qform (code {q_code}) disagree: they are up to {apart_mm:.2} mm apart at \
         the volume's corners, {handedness}; the sform is used, as nibabel does (ITK and SimpleITK use the qform, \
         so they place this volume elsewhere)"
    ))
}

/// `lps_from_index`, where it came from, and a warning when the sform and the qform are both set but disagree.
pub(super) fn lps_from_index(
    path: &Path,
    h: &Header,
    dims: [usize; 3],
) -> Result<(Transform<Lps, Index>, GeometrySource, Option<String>)> {
    let mut warning = None;
    let (ras_from_index, source, what) = if h.sform_code > 0 {
        let mut m = Matrix4::identity();
        for (r, row) in h.srow.iter().enumerate() {
            for (c, &v) in row.iter().enumerate() {
                m[(r, c)] = v;
            }
        }
        if h.qform_code > 0 {
            warning = sform_qform_disagreement(path, h, &m, dims);
        }
        (m, GeometrySource::NiftiSform { code: h.sform_code }, "sform (srow_x/y/z)")
    } else if h.qform_code > 0 {
        (qform(path, h)?, GeometrySource::NiftiQform { code: h.qform_code }, "qform")
    } else {
        let spacing = [spacing(path, h, 1)?, spacing(path, h, 2)?, spacing(path, h, 3)?];
        let m = Matrix4::from_diagonal(&nalgebra::Vector4::new(spacing[0], spacing[1], spacing[2], 1.0));
        (m, GeometrySource::NiftiPixdim, "pixdim")
    };
    let ras_from_index: Transform<Ras, Index> = Transform::from_matrix(ras_from_index);
    if !ras_from_index.is_valid_affine() {
        return Err(Error::invalid(
            path,
            format!("the {what} voxel-to-world matrix is singular or not finite: {:?}", ras_from_index.rows()),
        ));
    }
    Ok((lps_from_ras() * ras_from_index, source, warning))
}

/// The qform of a linear part: quaternion (b, c, d) of the nearest rotation, qfac, and column lengths.
///
/// As `nifti_mat44_to_quatern` (nifti1_io.c): normalise the columns, take the orthogonal polar factor
/// (exact for a rigid direction matrix, the nearest rotation for a sheared one), flip the k column
/// when the determinant is negative (qfac = −1), then extract the quaternion with a ≥ 0.
pub(super) fn qform_from_linear(linear: &Matrix3<f64>) -> ([f64; 3], f64, [f64; 3]) {
    let spacing = [linear.column(0).norm(), linear.column(1).norm(), linear.column(2).norm()];
    let mut r = *linear;
    for (mut col, s) in r.column_iter_mut().zip(spacing) {
        col /= s;
    }
    if let Some(svd) = r.try_svd(true, true, 1e-15, 200)
        && let (Some(u), Some(v_t)) = (svd.u, svd.v_t)
    {
        r = u * v_t;
    }
    let mut qfac = 1.0;
    if r.determinant() < 0.0 {
        qfac = -1.0;
        r.column_mut(2).neg_mut();
    }
    let (r11, r12, r13) = (r[(0, 0)], r[(0, 1)], r[(0, 2)]);
    let (r21, r22, r23) = (r[(1, 0)], r[(1, 1)], r[(1, 2)]);
    let (r31, r32, r33) = (r[(2, 0)], r[(2, 1)], r[(2, 2)]);
    let trace1 = r11 + r22 + r33 + 1.0;
    let (a, b, c, d);
    if trace1 > 0.5 {
        a = 0.5 * trace1.sqrt();
        b = 0.25 * (r32 - r23) / a;
        c = 0.25 * (r13 - r31) / a;
        d = 0.25 * (r21 - r12) / a;
    } else {
        let xd = 1.0 + r11 - (r22 + r33);
        let yd = 1.0 + r22 - (r11 + r33);
        let zd = 1.0 + r33 - (r11 + r22);
        if xd > 1.0 {
            b = 0.5 * xd.sqrt();
            c = 0.25 * (r12 + r21) / b;
            d = 0.25 * (r13 + r31) / b;
            a = 0.25 * (r32 - r23) / b;
        } else if yd > 1.0 {
            c = 0.5 * yd.sqrt();
            b = 0.25 * (r12 + r21) / c;
            d = 0.25 * (r23 + r32) / c;
            a = 0.25 * (r13 - r31) / c;
        } else {
            d = 0.5 * zd.sqrt();
            b = 0.25 * (r13 + r31) / d;
            c = 0.25 * (r23 + r32) / d;
            a = 0.25 * (r21 - r12) / d;
        }
    }
    let sign = if a < 0.0 { -1.0 } else { 1.0 };
    ([sign * b, sign * c, sign * d], qfac, spacing)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quaternion_round_trip_for_proper_and_improper_rotations() {
        let theta: f64 = 0.3;
        let (s, c) = theta.sin_cos();
        let rot = Matrix3::new(c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0);
        for flip in [1.0, -1.0] {
            let linear = rot * Matrix3::from_diagonal(&nalgebra::Vector3::new(0.5, 0.7, 2.0 * flip));
            let (bcd, qfac, spacing) = qform_from_linear(&linear);
            assert!((qfac - flip).abs() < f64::EPSILON);
            let m = ras_from_index_qform(bcd, [0.0; 3], spacing, qfac);
            let back = m.fixed_view::<3, 3>(0, 0).into_owned();
            assert!((back - linear).abs().max() < 1e-12, "{back} vs {linear}");
        }
        // A 180° turn about x: a = 0, the second branch.
        let linear = Matrix3::from_diagonal(&nalgebra::Vector3::new(1.0, -1.0, -1.0));
        let (bcd, qfac, spacing) = qform_from_linear(&linear);
        let back = ras_from_index_qform(bcd, [0.0; 3], spacing, qfac).fixed_view::<3, 3>(0, 0).into_owned();
        assert!((back - linear).abs().max() < 1e-12);
    }
}
