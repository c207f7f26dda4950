//! A chain of ITK transforms, as ITK's transform files hold them: one transform, or the members of a
//! `CompositeTransform`, the last applied first ([`ItkChain`]). Read from ITK's HDF5 files ([`crate::itk_h5::read`])
//! and text files ([`parse_text`]); [`crate::transform_file::read_chain`] reads either.
//!
//! A text `.tfm` of several transforms is laid out as ITK's `TransformFileWriter` writes a composite (SimpleITK's
//! `WriteTransform` of a `CompositeTransform`):
//!
//! ```text
//! #Insight Transform File V1.0
//! #Transform 0
//! Transform: CompositeTransform_double_3_3
//! #Transform 1
//! Transform: AffineTransform_double_3_3
//! Parameters: …
//! FixedParameters: …
//! #Transform 2
//! Transform: BSplineTransform_double_3_3
//! Parameters: …
//! FixedParameters: …
//! ```
//!
//! with the members' classes and numbers those of a one-transform file ([`crate::itk_tfm`]). 3D Slicer's
//! `InverseBSplineTransform` (a B-spline S saved in its modeling direction, meaning S⁻¹; `vtkITKTransformInverse.h`)
//! is read in a text file as in an `.h5`, alone or as a member ([`ItkStep::Inverse`]). A thin-plate spline is refused
//! in a chain: ITK stores only its landmarks and fits it again on reading, and its landmarks are read as pairs
//! ([`crate::landmarks`]).

use std::path::Path;

use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;

use crate::displacement::check::first_non_finite;
use crate::displacement::{FieldDirection, FieldSource, ReadField, SampleGrid};
use crate::elastix::FieldStep;
use crate::error::{Error, Result};
use crate::geometry::{Index, Lps, Point3, Transform};
use crate::itk_tfm::{ItkAffine, ItkBSpline, ItkTransform, transform_of};
use crate::nifti::DisplacementField;
use crate::volume::{self, GeometrySource};

/// The displacement-field classes read (ITK writes the double one).
pub(crate) const FIELD_TYPES: [&str; 2] =
    ["DisplacementFieldTransform_double_3_3", "DisplacementFieldTransform_float_3_3"];

/// The composite classes, which may stand only first (group `0` of an `.h5`, `#Transform 0` of a `.tfm`).
pub(crate) const COMPOSITE_TYPES: [&str; 2] = ["CompositeTransform_double_3_3", "CompositeTransform_float_3_3"];

/// 3D Slicer's class for a grid transform saved in its modeling direction: the field is the map from the moving
/// space to the fixed one (module docs).
pub(crate) const SLICER_INVERSE_FIELD_TYPES: [&str; 2] =
    ["InverseDisplacementFieldTransform_double_3_3", "InverseDisplacementFieldTransform_float_3_3"];

/// 3D Slicer's class for a B-spline held in its modeling direction: the transform meant is the spline's inverse.
pub(crate) const SLICER_INVERSE_BSPLINE_TYPES: [&str; 2] =
    ["InverseBSplineTransform_double_3_3", "InverseBSplineTransform_float_3_3"];

/// One transform of a chain.
#[derive(Clone, Debug, PartialEq)]
pub enum ItkStep {
    /// An affine or a cubic B-spline, as a `.tfm` holds them.
    Transform(ItkTransform),
    /// A `DisplacementFieldTransform`.
    Field(Box<FieldStep>),
    /// 3D Slicer's `InverseBSplineTransform` or `InverseDisplacementFieldTransform` in a composite: the inverse of
    /// the B-spline or field its parameters describe (module docs), found point by point.
    Inverse(InverseStep),
}

/// What a 3D Slicer `Inverse…` class holds: the transform whose inverse it stands for.
#[derive(Clone, Debug, PartialEq)]
pub enum InverseStep {
    BSpline(ItkBSpline),
    Field(Box<FieldStep>),
}

impl InverseStep {
    /// The forward map S(y) whose inverse the step is, LPS mm.
    fn forward(&self, y: [f64; 3]) -> [f64; 3] {
        match self {
            Self::BSpline(b) => b.apply(y),
            Self::Field(f) => f.apply(y),
        }
    }

    /// Slicer's class for it (the `_double_3_3` one).
    #[must_use]
    pub fn type_name(&self) -> &'static str {
        match self {
            Self::BSpline(_) => SLICER_INVERSE_BSPLINE_TYPES[0],
            Self::Field(_) => SLICER_INVERSE_FIELD_TYPES[0],
        }
    }
}

impl ItkStep {
    /// T(x), LPS mm ([`inverse_point`] for [`Self::Inverse`]).
    fn apply(&self, x: [f64; 3]) -> [f64; 3] {
        match self {
            Self::Transform(ItkTransform::Affine(a)) => a.apply(x),
            Self::Transform(ItkTransform::BSpline(b)) => b.apply(x),
            // `read` refuses a thin-plate spline: it has no weights until it is fitted again.
            Self::Transform(ItkTransform::ThinPlateSpline(_)) => x,
            Self::Field(f) => f.apply(x),
            Self::Inverse(step) => inverse_point(|y| step.forward(y), x),
        }
    }
}

/// How close T(y) must come to x for y to be T⁻¹(x), mm: far below any image's precision, and reached in a few
/// Newton steps by a smooth transform.
const INVERSE_TOLERANCE_MM: f64 = 1e-6;

/// The most Newton steps [`inverse_point`] takes.
const INVERSE_ITERATIONS: usize = 100;

/// y with S(y) = x within [`INVERSE_TOLERANCE_MM`], S = `forward` ([`crate::geometry::newton_inverse`] on a
/// central-difference Jacobian, h = 10⁻³ mm, from the better of x and x − (S(x) − x)). Where it does not converge
/// (at a jump of S: ITK's B-spline and field are the identity outside their domain, so S jumps at its edge; or where
/// S folds), the point of least residual found, as VTK gives its last estimate there
/// (`vtkWarpTransform::InverseTransformPoint`, which inverts Slicer's warps to a looser 10⁻³ mm).
fn inverse_point(forward: impl Fn([f64; 3]) -> [f64; 3], x: [f64; 3]) -> [f64; 3] {
    const H: f64 = 1e-3;
    let jacobian = |y: [f64; 3]| {
        let mut j = Matrix3::zeros();
        for a in 0..3 {
            let (mut up, mut down) = (y, y);
            up[a] += H;
            down[a] -= H;
            let (tu, td) = (forward(up), forward(down));
            for c in 0..3 {
                j[(c, a)] = (tu[c] - td[c]) / (2.0 * H);
            }
        }
        j
    };
    let norm = |y: [f64; 3]| {
        let f = forward(y);
        ((f[0] - x[0]).powi(2) + (f[1] - x[1]).powi(2) + (f[2] - x[2]).powi(2)).sqrt()
    };
    let sx = forward(x);
    let guess = [2.0 * x[0] - sx[0], 2.0 * x[1] - sx[1], 2.0 * x[2] - sx[2]];
    let start = if norm(guess) < norm(x) { guess } else { x };
    crate::geometry::newton_inverse(&forward, jacobian, x, start, (INVERSE_TOLERANCE_MM, INVERSE_ITERATIONS))
}

/// The transforms of a file in the file's order (a composite's members; one for a file of one transform).
#[derive(Clone, Debug, PartialEq)]
pub struct ItkChain {
    /// T₁, …, Tₙ: the last is applied first (module docs).
    pub steps: Vec<ItkStep>,
}

impl ItkChain {
    /// T(x) = T₁(T₂(… Tₙ(x))): fixed → moving, LPS mm.
    #[must_use]
    pub fn apply(&self, x: [f64; 3]) -> [f64; 3] {
        self.steps.iter().rev().fold(x, |p, step| step.apply(p))
    }

    /// The chain as one affine when every transform in it is an affine; else the class of the first that is not.
    ///
    /// # Errors
    /// The ITK class of the first transform that is not linear.
    pub fn affine(&self) -> std::result::Result<ItkAffine, &'static str> {
        let (mut matrix, mut offset) = (Matrix3::identity(), Vector3::zeros());
        for step in self.steps.iter().rev() {
            let a = match step {
                ItkStep::Transform(ItkTransform::Affine(a)) => a,
                ItkStep::Transform(t) => return Err(t.type_name()),
                ItkStep::Field(_) => return Err(FIELD_TYPES[0]),
                ItkStep::Inverse(inner) => return Err(inner.type_name()),
            };
            offset = a.matrix * offset + Vector3::from(a.offset());
            matrix = a.matrix * matrix;
        }
        Ok(ItkAffine::from_offset(matrix, offset.into()))
    }

    /// The displacement field applied first (the last in the file): the grid of the fixed space that the chain
    /// starts from, where [`crate::itk_h5::read_field`] samples it.
    pub(crate) fn innermost_field(&self) -> Option<&FieldStep> {
        self.steps.iter().rev().find_map(|s| match s {
            ItkStep::Field(f) | ItkStep::Inverse(InverseStep::Field(f)) => Some(f.as_ref()),
            ItkStep::Inverse(InverseStep::BSpline(_)) | ItkStep::Transform(_) => None,
        })
    }
}

impl ItkChain {
    /// The chain sampled at every voxel centre x of the grid `dims`, `lps_from_index`: D(x) = T(x) − x, LPS mm, the
    /// pull-back, as SimpleITK's `TransformToDisplacementField` gives it on that grid. `path` is used in errors.
    ///
    /// # Errors
    /// A grid too large for memory; a displacement that is not finite, naming the voxel.
    pub fn sample(
        &self,
        path: &Path,
        dims: [usize; 3],
        lps_from_index: Transform<Lps, Index>,
        geometry_source: GeometrySource,
    ) -> Result<DisplacementField> {
        let n = volume::check_allocation(path, dims, 12, volume::DEFAULT_MAX_VOXEL_BYTES)?;
        let mut displacements_lps: Vec<[f32; 3]> = volume::try_with_capacity(path, n, "the displacement vectors")?;
        let [nx, ny, _] = dims;
        (0..n)
            .into_par_iter()
            .map(|v| {
                let ijk = [(v % nx) as f64, ((v / nx) % ny) as f64, (v / (nx * ny)) as f64];
                let x = lps_from_index.apply_point(Point3::new(ijk[0], ijk[1], ijk[2])).coords();
                let y = self.apply(x);
                [(y[0] - x[0]) as f32, (y[1] - x[1]) as f32, (y[2] - x[2]) as f32]
            })
            .collect_into_vec(&mut displacements_lps);
        if let Some(ijk) = first_non_finite(dims, &displacements_lps) {
            return Err(Error::invalid(path, format!("the displacement at voxel {ijk:?} (i, j, k) is not finite")));
        }
        Ok(DisplacementField { dims, lps_from_index, geometry_source, displacements_lps })
    }

    /// T⁻¹(y), found point by point by Newton's method on T to 1e-6 mm (central-difference Jacobian; where it does
    /// not converge, at a jump of a member at its domain's edge or where T folds, the point of least residual found).
    #[must_use]
    pub fn apply_inverse(&self, y: [f64; 3]) -> [f64; 3] {
        inverse_point(|x| self.apply(x), y)
    }

    /// Whether it holds a displacement field (then it is sampled on that field's grid, [`Self::field_on`]).
    #[must_use]
    pub fn has_field(&self) -> bool {
        self.innermost_field().is_some()
    }

    /// The chain as a displacement field, the pull-back: sampled at the voxel centres of the field applied first
    /// when it holds one (whatever `grid` is given), else on `grid`. `source` is what the field is reported as; `path`
    /// is used in errors.
    ///
    /// # Errors
    /// A chain of linear transforms only (a starting transform, not a field); one of B-splines without a `grid`
    /// (they give none of their own: their control points are not where a field is sampled); as [`Self::sample`].
    pub fn field_on(&self, path: &Path, grid: Option<&SampleGrid>, source: FieldSource) -> Result<ReadField> {
        let (dims, lps_from_index, geometry_source) = if let Some(f) = self.innermost_field() {
            (f.field.dims, f.field.lps_from_index, GeometrySource::ItkTransformFile)
        } else if self.affine().is_ok() {
            return Err(Error::unsupported(
                path,
                "it holds only linear transforms, and no displacement field: it is a starting transform (--initial)",
            ));
        } else if let Some(grid) = grid {
            (grid.dims, grid.lps_from_index, grid.geometry_source)
        } else {
            return Err(Error::unsupported(
                path,
                "it holds a B-spline and no displacement field, so it gives no grid to sample a field on; it is \
                 sampled on the fixed volume's grid where a command has one (warpbench warp, render or field \
                 --field with --fixed; Python's read_field(path, fixed=, moving=); the window)",
            ));
        };
        let field = self.sample(path, dims, lps_from_index, geometry_source)?;
        Ok(ReadField { field, source, direction: Some(FieldDirection::Pullback), warnings: Vec::new() })
    }
}

/// What an ITK transform file gives as a field, from one reading of it: a displacement field (one the file holds,
/// with the chain around it sampled on its grid), or a chain of B-splines and affines, which has no grid.
#[derive(Clone, Debug, PartialEq)]
pub enum FieldOrChain {
    Field(ReadField),
    Chain(ItkChain),
}

/// Parses the text of a `.tfm` holding one transform or a composite (module docs) as its chain; `name` is used in
/// errors: a class warpbench does not read, numbers of the wrong count, a composite inside the composite, a
/// thin-plate spline.
///
/// # Errors
/// As above.
pub fn parse_text(name: &Path, text: &str) -> Result<ItkChain> {
    let blocks = crate::itk_tfm::parse_blocks(name, text)?;
    let mut steps = Vec::with_capacity(blocks.len());
    for (n, block) in blocks.iter().enumerate() {
        let kind = block.kind;
        if COMPOSITE_TYPES.contains(&kind) {
            if n == 0 && blocks.len() > 1 {
                continue;
            }
            let why = if n == 0 { "holds no transforms" } else { "is a composite inside the composite" };
            return Err(Error::invalid(name, format!("#Transform {n} ({kind}) {why}")));
        }
        let (params, fixed) = (&block.params, &block.fixed);
        let step = if SLICER_INVERSE_BSPLINE_TYPES.contains(&kind) {
            let plain = kind.strip_prefix("Inverse").unwrap_or(kind);
            match transform_of(name, plain, params, fixed)? {
                ItkTransform::BSpline(b) => ItkStep::Inverse(InverseStep::BSpline(b)),
                _ => return Err(Error::invalid(name, format!("#Transform {n} is {kind}, but not a B-spline"))),
            }
        } else if FIELD_TYPES.contains(&kind) || SLICER_INVERSE_FIELD_TYPES.contains(&kind) {
            return Err(Error::unsupported(
                name,
                format!(
                    "#Transform {n} is a {kind} in a text file; warpbench reads displacement field transforms from \
                     ITK's HDF5 files (.h5) and field images (.nii.gz, .nrrd, .mha)"
                ),
            ));
        } else {
            match transform_of(name, kind, params, fixed)? {
                ItkTransform::ThinPlateSpline(_) if blocks.len() > 1 => {
                    return Err(Error::unsupported(
                        name,
                        format!(
                            "#Transform {n} is a {kind}: ITK stores only its landmarks and fits it again on reading; \
                             a spline in a composite is not read (a file of the spline alone is read as landmark \
                             pairs, --landmarks)"
                        ),
                    ));
                }
                t => ItkStep::Transform(t),
            }
        };
        steps.push(step);
    }
    Ok(ItkChain { steps })
}
