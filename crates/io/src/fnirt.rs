//! FSL FNIRT's nonlinear warps, read as the pull-back on the fixed grid: `fnirt --fout` and `convertwarp --out`
//! deformation fields, and `fnirt --cout` cubic B-spline coefficient fields ([`crate::nifti::read_fnirt_file`] reads
//! the files as stored).
//!
//! FNIRT, like FLIRT, works in FSL's coordinates of each image ([`crate::fsl`]: voxel indices times the voxel sizes,
//! the first axis reversed for an image whose voxel-to-world matrix has a positive determinant). A warp maps the
//! reference image's FSL coordinates p to the source (input) image's: `applywarp --ref=REF --in=IN --warp=W` samples
//! IN there. So an FNIRT warp means nothing without its two images: the reference is warpbench's fixed volume, the
//! source its moving one, and the pull-back on the fixed grid is
//!
//! ```text
//! u(x) = W_moving · S_moving⁻¹ · q(S_fixed · W_fixed⁻¹ · x),
//! ```
//!
//! with q the warp in FSL coordinates, S the FSL matrices and W the grids' `lps_from_index`:
//!
//! - **Deformation field** (intent 2006), on the reference image's grid: q(p) = p + v, or q(p) = v where the file holds
//!   absolute positions (`convertwarp --absout`). Nothing in the file says which; as fslpy (FSL's own Python
//!   library, `nonlinear.detectDeformationType`) does, the values are taken as absolute positions when they spread
//!   more (the sum of the three components' standard deviations) than the values less each voxel's own position, and
//!   as relative displacements otherwise, and the reader says which it took.
//! - **Coefficient field** (intent 2007): q(p) = A⁻¹·p + d(i), with A the affine FNIRT started from (the file's sform,
//!   a FLIRT matrix), and d the cubic B-spline of the coefficients at reference voxel i: knot c lies at voxel
//!   (c − 1)·s for the knot spacing s, as fslpy's `CoefficientField.displacements` and `fnirtfileutils` evaluate it.
//!   The premat is added as `fnirtfileutils` adds it (fslpy's `coefficientFieldToDeformationField`).
//!
//! The fixed volume must be FNIRT's reference: a deformation field's grid must be the fixed grid (its dims, and its
//! sform or qform within 0.01 mm at the corners where it has one); a coefficient field's recorded reference dims
//! and voxel sizes must be the fixed volume's. Anything else is refused, naming the file: the warp would land
//! elsewhere.
//!
//! Checked against fslpy 3.29.1 (`crates/io/tests/fnirt.rs`, fixtures by `data-scripts/fnirt_fixtures.py`).

use std::path::Path;

use nalgebra::{Matrix4, Vector4};
use rayon::prelude::*;

use crate::error::{Error, Result};
use crate::fsl::{Grid, fsl_from_index};
use crate::nifti::{CoefficientField, DisplacementField, FnirtFile, read_fnirt_file};
use crate::volume::GeometrySource;

/// How far (mm) a deformation field's own grid may lie from the fixed grid at its corners.
const GRID_TOLERANCE_MM: f64 = 0.01;

/// A relative tolerance on the reference voxel sizes a coefficient field records (FNIRT writes them as float32).
const SPACING_TOLERANCE: f64 = 1e-4;

/// An FNIRT warp read as the pull-back, with what the reader inferred.
#[derive(Clone, Debug, PartialEq)]
pub struct ReadFnirt {
    /// The pull-back u(x) − x on the fixed grid, LPS mm.
    pub field: DisplacementField,
    /// What was inferred (a deformation field's relative or absolute values) or assumed.
    pub warnings: Vec<String>,
}

/// Reads the FNIRT warp at `path` as the pull-back on `fixed`'s grid, with `fixed` FNIRT's reference image and
/// `moving` its input (module docs). Errors name the file: what [`read_fnirt_file`] refuses, a fixed volume that is
/// not the warp's reference, a warp that leads beyond any finite point.
pub fn read_pullback(path: &Path, fixed: Grid<'_>, moving: Grid<'_>) -> Result<ReadFnirt> {
    let file = read_fnirt_file(path)?;
    let singular = |what: &str| Error::invalid(path, format!("{what} cannot be inverted"));
    let moving_index_from_fsl =
        fsl_from_index(moving).try_inverse().ok_or_else(|| singular("the moving volume's grid"))?;
    let lps_from_moving_fsl = moving.1.matrix() * moving_index_from_fsl;
    let fixed_fsl_from_index = fsl_from_index(fixed);
    let mut warnings = Vec::new();
    let lps_from_fixed_index = fixed.1.matrix();
    // u(x) − x at reference voxel n, from the input's FSL position q it reads.
    #[allow(clippy::cast_possible_truncation, reason = "a field's vectors are f32 in every flavour")]
    let displacement = |n: usize, dims: [usize; 3], q: [f64; 3]| {
        let x = lps_from_fixed_index * index_point(n, dims);
        let u = lps_from_moving_fsl * Vector4::new(q[0], q[1], q[2], 1.0);
        [0, 1, 2].map(|c| (u[c] - x[c]) as f32)
    };
    let (displacements_lps, dims) = match file {
        FnirtFile::Deformation { dims, lps_from_index, vectors } => {
            check_deformation_grid(path, fixed, dims, lps_from_index.as_ref().map(|(t, _)| t), &mut warnings)?;
            let absolute = looks_absolute(dims, &vectors, &fixed_fsl_from_index);
            warnings.push(if absolute {
                "read as absolute positions (as `convertwarp --absout` writes them): the values spread more than \
                 the displacements they would make (fslpy's test)"
                    .to_string()
            } else {
                "read as relative displacements (as `fnirt --fout` and `convertwarp` write them): the values spread \
                 less than positions would (fslpy's test)"
                    .to_string()
            });
            let displacements = vectors
                .par_iter()
                .enumerate()
                .map(|(n, v)| {
                    let v = v.map(f64::from);
                    let q = if absolute {
                        v
                    } else {
                        let p = fixed_fsl_from_index * index_point(n, dims);
                        [p[0] + v[0], p[1] + v[1], p[2] + v[2]]
                    };
                    displacement(n, dims, q)
                })
                .collect::<Vec<_>>();
            (displacements, dims)
        }
        FnirtFile::CubicCoefficients(c) => {
            check_coefficient_reference(path, fixed, &c)?;
            let source_from_reference =
                c.reference_from_source_fsl.try_inverse().ok_or_else(|| singular("the starting affine (the sform)"))?;
            let dims = fixed.0;
            let displacements = spline_displacements(&c, dims, &|n, d| {
                let q = source_from_reference * (fixed_fsl_from_index * index_point(n, dims));
                displacement(n, dims, [q[0] + d[0], q[1] + d[1], q[2] + d[2]])
            });
            (displacements, dims)
        }
    };
    if let Some(ijk) = crate::displacement::check::first_non_finite(dims, &displacements_lps) {
        return Err(Error::invalid(
            path,
            format!("the warp at voxel {ijk:?} (i, j, k) leads beyond any finite point of the moving volume"),
        ));
    }
    let field = DisplacementField {
        dims,
        lps_from_index: *fixed.1,
        geometry_source: GeometrySource::FnirtReferenceImage,
        displacements_lps,
    };
    Ok(ReadFnirt { field, warnings })
}

/// Writes the pull-back `displacements_lps` (u(x) − x at the voxel centres of `fixed`, LPS mm, i fastest) as an FNIRT
/// deformation field of relative displacements on that grid, atomically, with `fixed` as FNIRT's reference and
/// `moving` as its input: at reference voxel i, v = S_moving · W_moving⁻¹ · u(x) − S_fixed · i, what `applywarp
/// --ref=FIXED --in=MOVING --warp=OUT --rel` applies. [`read_pullback`] reads it back to the same pull-back.
///
/// # Errors
/// A singular grid, a vector that is not finite, a grid NIfTI-1 cannot hold, a failed write (named by `path`).
pub fn write_pullback(path: &Path, fixed: Grid<'_>, moving: Grid<'_>, displacements_lps: &[[f32; 3]]) -> Result<()> {
    let singular = |what: &str| Error::invalid(path, format!("{what} cannot be inverted"));
    let moving_fsl_from_lps =
        fsl_from_index(moving) * moving.1.matrix().try_inverse().ok_or_else(|| singular("the moving volume's grid"))?;
    let fixed_fsl_from_index = fsl_from_index(fixed);
    let lps_from_fixed_index = fixed.1.matrix();
    let dims = fixed.0;
    #[allow(clippy::cast_possible_truncation, reason = "a field's vectors are f32 in every flavour")]
    let displacements_fsl = displacements_lps
        .par_iter()
        .enumerate()
        .map(|(n, d)| {
            let i = index_point(n, dims);
            let x = lps_from_fixed_index * i;
            let u = Vector4::new(x[0] + f64::from(d[0]), x[1] + f64::from(d[1]), x[2] + f64::from(d[2]), 1.0);
            let q = moving_fsl_from_lps * u;
            let p = fixed_fsl_from_index * i;
            [0, 1, 2].map(|c| (q[c] - p[c]) as f32)
        })
        .collect::<Vec<_>>();
    crate::nifti::write_deformation_field(path, (dims, fixed.1), &displacements_fsl)
}

/// What can be told of an FNIRT file without its images ([`summary`]).
#[derive(Clone, Debug, PartialEq)]
pub struct Summary {
    /// The file's grid: the reference image's voxels, or the knots.
    pub dims: [usize; 3],
    /// A deformation field's own grid (the reference image's) and where it came from, where it carries one.
    pub lps_from_index:
        Option<(crate::geometry::Transform<crate::geometry::Lps, crate::geometry::Index>, GeometrySource)>,
    /// The largest displacement, mm: a deformation field's, told relative or absolute on its own grid; for
    /// coefficients a bound (the spline's weights are positive and sum to at most 1, so no displacement exceeds the
    /// largest coefficient), not counting the starting affine.
    pub max_displacement_mm: f64,
    /// What the file is and how it is read, for the user.
    pub notes: Vec<String>,
}

/// What the FNIRT file at `path` is, without its images (`warpbench info`). Errors: as [`read_fnirt_file`].
pub fn summary(path: &Path) -> Result<Summary> {
    let largest = |vectors: &mut dyn Iterator<Item = [f64; 3]>| {
        vectors.map(|d| d.iter().map(|c| c * c).sum::<f64>().sqrt()).fold(0.0, f64::max)
    };
    let read_with = "read against its reference image (the fixed volume) and input (the moving one): warp --fixed REF \
                     --moving IN --field FILE";
    Ok(match read_fnirt_file(path)? {
        FnirtFile::Deformation { dims, lps_from_index, vectors } => {
            let Some((own, source)) = lps_from_index else {
                let max = largest(&mut vectors.iter().map(|v| v.map(f64::from)));
                return Ok(Summary {
                    dims,
                    lps_from_index: None,
                    max_displacement_mm: max,
                    notes: vec![
                        format!("an FSL FNIRT deformation field without a geometry, {read_with}"),
                        "the largest value is shown: relative or absolute is told against the reference".into(),
                    ],
                });
            };
            let s = fsl_from_index((dims, &own));
            let absolute = looks_absolute(dims, &vectors, &s);
            let max = largest(&mut vectors.iter().enumerate().map(|(n, v)| {
                let p = if absolute { s * index_point(n, dims) } else { Vector4::zeros() };
                [0, 1, 2].map(|c| f64::from(v[c]) - p[c])
            }));
            let kind = if absolute { "absolute positions" } else { "relative displacements" };
            Summary {
                dims,
                lps_from_index: Some((own, source)),
                max_displacement_mm: max,
                notes: vec![format!("an FSL FNIRT deformation field of {kind} (fslpy's test), {read_with}")],
            }
        }
        FnirtFile::CubicCoefficients(c) => Summary {
            dims: c.dims,
            lps_from_index: None,
            max_displacement_mm: largest(&mut c.coefficients.iter().map(|v| v.map(f64::from))),
            notes: vec![
                format!(
                    "FSL FNIRT cubic B-spline coefficients over a reference image of {:?} voxels of {:?} mm, knots \
                     every {:?} voxels, {read_with}",
                    c.reference_dims, c.reference_spacing_mm, c.knot_spacing
                ),
                "the largest displacement shown is a bound, the largest coefficient, without the starting affine"
                    .into(),
            ],
        },
    })
}

/// Voxel `n` (i fastest) of a grid of `dims`, as a homogeneous point.
fn index_point(n: usize, dims: [usize; 3]) -> Vector4<f64> {
    let (i, j, k) = (n % dims[0], (n / dims[0]) % dims[1], n / (dims[0] * dims[1]));
    Vector4::new(i as f64, j as f64, k as f64, 1.0)
}

/// Refuses a deformation field that does not lie on the fixed grid; notes one that carries no geometry.
fn check_deformation_grid(
    path: &Path,
    (fixed_dims, fixed_lps_from_index): Grid<'_>,
    dims: [usize; 3],
    own: Option<&crate::geometry::Transform<crate::geometry::Lps, crate::geometry::Index>>,
    warnings: &mut Vec<String>,
) -> Result<()> {
    if dims != fixed_dims {
        return Err(Error::invalid(
            path,
            format!(
                "the FNIRT field has {dims:?} voxels and the fixed volume {fixed_dims:?}: FNIRT writes its field on \
                 its reference image's grid; give that image (fnirt's --ref) as the fixed volume"
            ),
        ));
    }
    let Some(own) = own else {
        warnings.push("the field has no sform or qform: taken on the fixed volume's grid, as fslpy takes it".into());
        return Ok(());
    };
    let apart = crate::volume::corner_indices(dims)
        .iter()
        .map(|i| own.apply_point(*i).distance(&fixed_lps_from_index.apply_point(*i)))
        .fold(0.0, f64::max);
    if apart > GRID_TOLERANCE_MM {
        return Err(Error::invalid(
            path,
            format!(
                "the FNIRT field's sform/qform places its grid up to {apart:.3} mm from the fixed volume's: FNIRT \
                 writes its field on its reference image's grid; give that image (fnirt's --ref) as the fixed volume"
            ),
        ));
    }
    Ok(())
}

/// Refuses a coefficient field made with a reference image other than the fixed volume.
fn check_coefficient_reference(
    path: &Path,
    (fixed_dims, fixed_lps_from_index): Grid<'_>,
    c: &CoefficientField,
) -> Result<()> {
    let linear = fixed_lps_from_index.linear();
    let spacing = [0, 1, 2].map(|a| linear.column(a).norm());
    let same_dims = c.reference_dims == fixed_dims;
    let same_spacing =
        (0..3).all(|a| (c.reference_spacing_mm[a] - spacing[a]).abs() <= SPACING_TOLERANCE * spacing[a].max(1.0));
    if same_dims && same_spacing {
        return Ok(());
    }
    Err(Error::invalid(
        path,
        format!(
            "the FNIRT coefficients were made with a reference image of {:?} voxels of {:?} mm, and the fixed volume \
             has {fixed_dims:?} voxels of {spacing:?} mm: give that reference image (fnirt's --ref) as the fixed \
             volume",
            c.reference_dims, c.reference_spacing_mm
        ),
    ))
}

/// fslpy's test (`detectDeformationType`): absolute when the values spread more than the values less each reference
/// voxel's own FSL position.
fn looks_absolute(dims: [usize; 3], vectors: &[[f32; 3]], fsl_from_index: &Matrix4<f64>) -> bool {
    let spread = |relative: bool| -> f64 {
        (0..3)
            .map(|c| {
                let values = vectors.iter().enumerate().map(|(n, v)| {
                    let p = if relative { (fsl_from_index * index_point(n, dims))[c] } else { 0.0 };
                    f64::from(v[c]) - p
                });
                standard_deviation(values)
            })
            .sum()
    };
    spread(false) > spread(true)
}

/// The population standard deviation, by Welford's update.
fn standard_deviation(values: impl Iterator<Item = f64>) -> f64 {
    let (mut n, mut mean, mut m2) = (0.0, 0.0, 0.0);
    for v in values {
        n += 1.0;
        let delta = v - mean;
        mean += delta / n;
        m2 += delta * (v - mean);
    }
    if n > 0.0 { (m2 / n).sqrt() } else { 0.0 }
}

/// The cubic B-spline's four weights at fraction `u` of a knot interval, taps `floor` .. `floor` + 3.
fn weights(u: f64) -> [f64; 4] {
    let u2 = u * u;
    let u3 = u2 * u;
    [(1.0 - u).powi(3) / 6.0, (3.0 * u3 - 6.0 * u2 + 4.0) / 6.0, (-3.0 * u3 + 3.0 * u2 + 3.0 * u + 1.0) / 6.0, u3 / 6.0]
}

/// The first tap and the weights of reference voxel `i` along an axis of knot spacing `s`.
fn taps(i: usize, s: f64) -> (isize, [f64; 4]) {
    let f = i as f64 / s;
    let base = f.floor();
    #[allow(clippy::cast_possible_truncation, reason = "a knot index of a grid that fits in memory")]
    (base as isize, weights(f - base))
}

/// `finish(n, d)` of the spline's displacement d (FSL mm) at every voxel n of the reference grid `dims`, i fastest;
/// taps outside the knot grid count as zero, as in fslpy. Separable: per row of the reference grid, the knots are
/// combined along j and k once, then along i per voxel.
fn spline_displacements(
    c: &CoefficientField,
    dims: [usize; 3],
    finish: &(dyn Fn(usize, [f64; 3]) -> [f32; 3] + Sync),
) -> Vec<[f32; 3]> {
    let [kx, ky, kz] = c.dims;
    let knot = |a: isize, b: isize, n: isize| -> Option<&[f32; 3]> {
        let inside = |v: isize, len: usize| usize::try_from(v).ok().filter(|&v| v < len);
        let (a, b, n) = (inside(a, kx)?, inside(b, ky)?, inside(n, kz)?);
        c.coefficients.get(a + kx * (b + ky * n))
    };
    let x_taps: Vec<_> = (0..dims[0]).map(|i| taps(i, c.knot_spacing[0])).collect();
    let mut out = vec![[0.0f32; 3]; dims[0] * dims[1] * dims[2]];
    out.par_chunks_mut(dims[0]).enumerate().for_each(|(row, out)| {
        let (j, k) = (row % dims[1], row / dims[1]);
        let (bj, wj) = taps(j, c.knot_spacing[1]);
        let (bk, wk) = taps(k, c.knot_spacing[2]);
        // This row's knots along i, combined along j and k.
        let combined: Vec<[f64; 3]> = (0..kx)
            .map(|a| {
                let mut sum = [0.0; 3];
                for (m, wm) in wj.iter().enumerate() {
                    for (n, wn) in wk.iter().enumerate() {
                        #[allow(clippy::cast_possible_wrap, reason = "a knot index of a grid that fits in memory")]
                        if let Some(v) = knot(a as isize, bj + m as isize, bk + n as isize) {
                            for (s, &v) in sum.iter_mut().zip(v) {
                                *s += wm * wn * f64::from(v);
                            }
                        }
                    }
                }
                sum
            })
            .collect();
        for (i, (o, &(bi, wi))) in out.iter_mut().zip(&x_taps).enumerate() {
            let mut d = [0.0; 3];
            for (l, wl) in wi.iter().enumerate() {
                let a = bi + l as isize;
                if let Some(v) = usize::try_from(a).ok().and_then(|a| combined.get(a)) {
                    for (d, v) in d.iter_mut().zip(v) {
                        *d += wl * v;
                    }
                }
            }
            *o = finish(row * dims[0] + i, d);
        }
    });
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_weights_are_a_partition_of_unity_and_match_the_centred_spline() {
        // The centred cubic B-spline B(t) at the four taps' offsets.
        let b = |t: f64| {
            let t = t.abs();
            if t < 1.0 {
                (3.0 * t.powi(3) - 6.0 * t * t + 4.0) / 6.0
            } else if t < 2.0 {
                (2.0 - t).powi(3) / 6.0
            } else {
                0.0
            }
        };
        for u in [0.0, 0.125, 0.5, 0.9] {
            let w = weights(u);
            assert!((w.iter().sum::<f64>() - 1.0).abs() < 1e-15);
            for (l, w) in w.iter().enumerate() {
                assert!((w - b(u + 1.0 - l as f64)).abs() < 1e-15, "u {u} tap {l}");
            }
        }
    }

    #[test]
    fn the_spread_test_tells_positions_from_displacements() {
        let dims = [6, 5, 4];
        let s = Matrix4::from_diagonal(&Vector4::new(2.0, 2.0, 3.0, 1.0));
        let n = dims[0] * dims[1] * dims[2];
        #[allow(clippy::cast_possible_truncation, reason = "small test values")]
        let positions: Vec<[f32; 3]> = (0..n)
            .map(|n| {
                let p = s * index_point(n, dims);
                [p[0] as f32 + 0.5, p[1] as f32, p[2] as f32 - 1.0]
            })
            .collect();
        let displacements: Vec<[f32; 3]> = (0..n).map(|n| [0.5, (n % 3) as f32 * 0.2, -1.0]).collect();
        assert!(looks_absolute(dims, &positions, &s));
        assert!(!looks_absolute(dims, &displacements, &s));
    }
}
