//! elastix's `DeformationFieldTransform`: a transform that is a displacement field on a grid of its own, read as
//! elastix's `itk::DeformationFieldInterpolatingTransform` applies it.

use std::path::{Path, PathBuf};

use nalgebra::{Matrix3, Vector3};

use super::params::{ParameterMap, find_beside};
use crate::displacement::{head, read_flavoured};
use crate::error::{Error, Result};
use crate::nifti::DisplacementField;

/// How a [`FieldStep`] reads its field between voxel centres: `DeformationFieldInterpolationOrder`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FieldInterpolation {
    /// 0, elastix's default: the vector of the nearest voxel centre (ITK's `VectorNearestNeighborInterpolateImageFunction`,
    /// halves rounded up).
    Nearest,
    /// 1: trilinear between the eight centres around the point (ITK's `VectorLinearInterpolateImageFunction`), the
    /// outermost centres' vectors held out to the grid's edge.
    Linear,
}

impl FieldInterpolation {
    /// The `DeformationFieldInterpolationOrder` that names it.
    #[must_use]
    pub const fn order(self) -> u8 {
        match self {
            Self::Nearest => 0,
            Self::Linear => 1,
        }
    }
}

/// A `DeformationFieldTransform`: T(x) = x + D(x) inside the field's grid, where D is the field read between its
/// voxel centres by `interpolation`; T(x) = x outside it. The grid reaches half a voxel past the outermost centres
/// (ITK's `IsInsideBuffer`: continuous index in [−½, n − ½) on every axis).
#[derive(Clone, Debug, PartialEq)]
pub struct FieldStep {
    /// The field file, as found.
    pub file: PathBuf,
    pub field: DisplacementField,
    pub interpolation: FieldInterpolation,
    /// (direction · spacing)⁻¹, and the origin: index = M (x − origin), as ITK converts a point to an index.
    index_from_lps: (Matrix3<f64>, Vector3<f64>),
}

impl FieldStep {
    /// The field `field` read from `file`, with `interpolation`; `name` (the parameter file) is used in errors: a
    /// grid whose axes are singular.
    ///
    /// # Errors
    /// As above.
    pub fn new(
        name: &Path,
        file: PathBuf,
        field: DisplacementField,
        interpolation: FieldInterpolation,
    ) -> Result<Self> {
        let lps_from_index = &field.lps_from_index;
        let inverse = lps_from_index.linear().try_inverse().filter(|m| m.iter().all(|v| v.is_finite()));
        let Some(m) = inverse else {
            return Err(Error::invalid(name, format!("the grid of its field {} is singular", file.display())));
        };
        let origin = Vector3::from(lps_from_index.translation());
        Ok(Self { file, field, interpolation, index_from_lps: (m, origin) })
    }

    /// T(x), LPS mm.
    #[must_use]
    pub fn apply(&self, x: [f64; 3]) -> [f64; 3] {
        let (m, origin) = &self.index_from_lps;
        let c = m * (Vector3::from(x) - origin);
        let dims = self.field.dims;
        if (0..3).any(|a| !(c[a] >= -0.5 && c[a] < dims[a] as f64 - 0.5)) {
            return x;
        }
        let at = |i: usize, j: usize, k: usize| self.field.displacements_lps[i + dims[0] * (j + dims[1] * k)];
        let d: [f64; 3] = match self.interpolation {
            FieldInterpolation::Nearest => {
                // Inside the buffer ⌊c + ½⌋ lies in [0, n − 1].
                let n = |a: usize| ((c[a] + 0.5).floor() as usize).min(dims[a] - 1);
                at(n(0), n(1), n(2)).map(f64::from)
            }
            FieldInterpolation::Linear => {
                let base: [f64; 3] = std::array::from_fn(|a| c[a].floor());
                let clamp = |a: usize, i: f64| (i.max(0.0) as usize).min(dims[a] - 1);
                let mut d = [0.0; 3];
                for corner in 0..8_usize {
                    let mut weight = 1.0;
                    let mut ijk = [0; 3];
                    for a in 0..3 {
                        let upper = corner >> a & 1 == 1;
                        let t = c[a] - base[a];
                        weight *= if upper { t } else { 1.0 - t };
                        ijk[a] = clamp(a, base[a] + f64::from(u8::from(upper)));
                    }
                    let v = at(ijk[0], ijk[1], ijk[2]);
                    for (d, v) in d.iter_mut().zip(v) {
                        *d += weight * f64::from(v);
                    }
                }
                d
            }
        };
        [x[0] + d[0], x[1] + d[1], x[2] + d[2]]
    }
}

/// The `DeformationFieldTransform` of a parameter file `name`: its `DeformationFieldFileName` (looked for beside the
/// file, then as given; a field of any flavour warpbench reads, but not another parameter file) and its
/// `DeformationFieldInterpolationOrder` (0 when absent, as elastix reads it).
pub(super) fn read(name: &Path, map: &ParameterMap) -> Result<FieldStep> {
    let given = map
        .text(name, "DeformationFieldFileName")?
        .filter(|f| !f.is_empty())
        .ok_or_else(|| Error::invalid(name, "the DeformationFieldTransform has no (DeformationFieldFileName …)"))?;
    let interpolation = match map.numbers(name, "DeformationFieldInterpolationOrder")?.as_deref() {
        None | Some([0.0]) => FieldInterpolation::Nearest,
        Some([1.0]) => FieldInterpolation::Linear,
        Some(other) => {
            return Err(Error::invalid(
                name,
                format!("DeformationFieldInterpolationOrder {other:?} is neither 0 nor 1"),
            ));
        }
    };
    let file = find_beside(name, given, "DeformationFieldFileName")?;
    let head = head(&file)?;
    if super::looks_like_parameter_file(&head) {
        // It would be read as the field of its transform, and one naming itself would never end.
        return Err(Error::invalid(
            name,
            format!("its DeformationFieldFileName {} is a transform parameter file, not a field", file.display()),
        ));
    }
    let read = read_flavoured(&file, &head)?.ok_or_else(|| {
        Error::unsupported(&file, "not a displacement field: neither NIfTI (intent 1006 or 1007), NRRD nor MetaImage")
    })?;
    let field = read.field;
    FieldStep::new(name, file, field, interpolation)
}
