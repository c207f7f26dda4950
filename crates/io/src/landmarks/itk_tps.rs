//! A thin-plate-spline transform file, ITK's or 3D Slicer's (`.tfm` text or `.h5`), read as the landmark pairs it
//! holds.
//!
//! ITK stores a `ThinPlateSplineKernelTransform` as its landmarks only (source points as the parameters, target points
//! as the fixed parameters: [`crate::itk_tfm`]) and fits the spline again when it reads the file, with kernel
//! U(r) = r and no stiffness: the spline warpbench fits through the same pairs with `--method tps` and stiffness 0.
//! Which landmarks are the fixed points depends on the class:
//!
//! - **`ThinPlateSplineKernelTransform_double_3_3`** (ITK, and what `warpbench transform` writes): the file's
//!   transform is a resampling one, fixed → moving, so the **source** landmarks are the **fixed** points and the target
//!   ones the moving points. warpbench's pull-back through the pairs is ITK's transform.
//! - **`InverseThinPlateSplineKernelTransform_double_3_3`** (3D Slicer, for the spline of a landmark registration:
//!   Fiducial Registration Wizard, Landmark Registration): Slicer fits its spline from the moving points (source) to
//!   the fixed ones (target), and saves the transform in its resampling direction, the spline's inverse, under its own
//!   class name (Slicer's `vtkITKTransformConverter` writes the class for a VTK spline whose inverse flag is set, and
//!   reads it back as the spline from source to target, inverted). So the **source** landmarks are the **moving**
//!   points. Slicer's spline is warpbench's `fixed_from_moving` through the pairs (`warpbench points --from moving`,
//!   `field --direction forward`); Slicer resamples with that spline's exact inverse, which agrees with warpbench's
//!   pull-back at the landmarks and differs from it between them by as much as the warp is not inverse-consistent
//!   (the window's fit panel shows it; `points --from moving` and back with `--from fixed` measures it).
//!
//! The `_float_3_3` twins are read too. A file of any other class, or of several transforms, is refused with what it
//! holds. The pairs are named `Pt-0`, `Pt-1`, … in file order, as BigWarp names its points, and are all active.

use std::path::Path;

use super::points::LandmarkPair;
use crate::error::{Error, Result};
use crate::geometry::Point3;
use crate::itk_tfm::{self, ItkTransform};

/// Which way a thin-plate-spline file's spline goes, told by its class (module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SplineFileClass {
    /// ITK's `ThinPlateSplineKernelTransform`: fixed → moving, the source landmarks are the fixed points.
    Itk,
    /// 3D Slicer's `InverseThinPlateSplineKernelTransform`: the inverse of a spline from the moving points (source) to
    /// the fixed ones.
    SlicerInverse,
}

impl SplineFileClass {
    /// The class of ITK class name `kind` (`…_double_3_3` or `…_float_3_3`), or `None` for any other class.
    #[must_use]
    pub fn of(kind: &str) -> Option<Self> {
        match kind.strip_suffix("_double_3_3").or_else(|| kind.strip_suffix("_float_3_3")) {
            Some("ThinPlateSplineKernelTransform") => Some(Self::Itk),
            Some("InverseThinPlateSplineKernelTransform") => Some(Self::SlicerInverse),
            _ => None,
        }
    }
}

/// The pairs of a transform of ITK class `kind` with `params` (the source landmarks) and `fixed` (the target ones);
/// `name` is used in errors.
pub(super) fn spline_pairs(name: &Path, kind: &str, params: &[f64], fixed: &[f64]) -> Result<Vec<LandmarkPair>> {
    let class = SplineFileClass::of(kind).ok_or_else(|| {
        Error::unsupported(
            name,
            format!(
                "the transform file holds a {kind}, not a thin-plate spline: a transform file gives landmark pairs \
                 only when it holds ITK's ThinPlateSplineKernelTransform or 3D Slicer's \
                 InverseThinPlateSplineKernelTransform (a linear transform is a starting transform, --initial)"
            ),
        )
    })?;
    let plain = ItkTransform::ThinPlateSpline(itk_tfm::ItkThinPlateSpline { source_lps: vec![], target_lps: vec![] });
    let ItkTransform::ThinPlateSpline(spline) = itk_tfm::transform_of(name, plain.type_name(), params, fixed)? else {
        return Err(Error::invalid(name, format!("{kind}: the landmarks do not make a thin-plate spline")));
    };
    let (fixed_lps, moving_lps) = match class {
        SplineFileClass::Itk => (&spline.source_lps, &spline.target_lps),
        SplineFileClass::SlicerInverse => (&spline.target_lps, &spline.source_lps),
    };
    Ok(moving_lps
        .iter()
        .zip(fixed_lps)
        .enumerate()
        .map(|(i, (&[mx, my, mz], &[fx, fy, fz]))| {
            LandmarkPair::new(format!("Pt-{i}"), Point3::new(mx, my, mz), Point3::new(fx, fy, fz))
        })
        .collect())
}

/// The pairs of a `.tfm`'s text (module docs); `name` is used in errors.
pub(super) fn tfm_pairs(name: &Path, text: &str) -> Result<Vec<LandmarkPair>> {
    let lines = itk_tfm::parse_lines(name, text)?;
    spline_pairs(name, lines.kind, &lines.params, &lines.fixed)
}

/// The pairs of an `.h5` file's bytes (module docs); `name` is used in errors.
fn h5_pairs(name: &Path, bytes: Vec<u8>) -> Result<Vec<LandmarkPair>> {
    let raw = crate::itk_h5::parse_single(name, bytes)?;
    spline_pairs(name, &raw.kind, &raw.params, &raw.fixed)
}

/// The pairs of a thin-plate-spline transform file's bytes: an `.h5` (told by its first bytes) or a `.tfm`'s text;
/// `name` is used in errors.
///
/// # Errors
/// A file that is neither, a transform of another class or several transforms, landmark lists that do not match.
pub fn parse_spline_file(name: &Path, bytes: Vec<u8>) -> Result<Vec<LandmarkPair>> {
    if crate::itk_h5::looks_like_hdf5(&bytes) {
        h5_pairs(name, bytes)
    } else {
        tfm_pairs(name, &super::text::utf8(name, bytes)?)
    }
}

/// Whether `text` is an ITK transform file's (its first line is ITK's).
pub(super) fn looks_like_tfm(text: &str) -> bool {
    text.lines().next().is_some_and(|l| l.trim() == itk_tfm::MAGIC)
}
