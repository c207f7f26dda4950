//! elastix transform parameter files (`TransformParameters.0.txt`): [`read_transform`] reads one and the chain of
//! initial transforms under it, [`read_affine`] a linear chain as one affine (for `--initial`), [`read_field`] a
//! chain as the displacement field transformix writes for it (for `--field`), and [`write()`] writes every
//! transform warpbench fits so that transformix applies it.
//!
//! # The format
//!
//! One parameter a line, `(Name value value …)`: strings in double quotes, numbers bare; `//` starts a comment. This
//! is what elastix 5 writes for a rigid registration (itk-elastix 0.25.4, keys sorted as it writes them):
//!
//! ```text
//! (CenterOfRotationPoint 17.25 22.25 21.75)
//! (ComputeZYX "false")
//! (Direction 1 0 0 0 1 0 0 0 1)
//! (FixedImageDimension 3)
//! (HowToCombineTransforms "Compose")
//! (InitialTransformParameterFileName "NoInitialTransform")
//! (NumberOfParameters 6)
//! (Origin 0 0 0)
//! (Size 24 24 24)
//! (Spacing 1.5 1.5 1.5)
//! (Transform "EulerTransform")
//! (TransformParameters -0.0459 0.0350 0.1359 2.2929 -1.2780 0.9393)
//! …                                        the resampler's settings (interpolator, pixel type, output format)
//! ```
//!
//! A transform T maps a point x of the fixed image to the moving image, in ITK's physical space (LPS mm): the
//! pull-back, what resampling the moving image onto the fixed grid needs, like `--initial`'s `.tfm`. `Size`,
//! `Spacing`, `Origin` and `Direction` (column by column) are the fixed image's grid, where transformix resamples.
//!
//! # Transforms
//!
//! With c the `CenterOfRotationPoint` and t the translation, as ITK's classes that elastix wraps compute them:
//!
//! | `Transform` | `TransformParameters` | T(x) |
//! |---|---|---|
//! | `TranslationTransform` | t | x + t |
//! | `EulerTransform` | θx θy θz t | R (x − c) + c + t; R = Rz Rx Ry, or Rz Ry Rx with `ComputeZYX "true"` |
//! | `SimilarityTransform` | versor v (3), t, scale s | s R(v) (x − c) + c + t; R(v) the rotation of the unit quaternion (√(1 − ‖v‖²), v) |
//! | `AffineTransform` | A row by row (9), t | A (x − c) + c + t |
//! | `SplineKernelTransform` | the target landmarks (x y z each) | the thin-plate spline (kernel r) through `FixedImageLandmarks` → targets |
//! | `BSplineTransform` | the control points' x displacements, then y, then z | x + cubic B-spline over `GridSize`, `GridOrigin`, `GridSpacing`, `GridDirection` |
//! | `DeformationFieldTransform` | none: `DeformationFieldFileName` names a displacement field D | x + D(x) on D's grid, x outside it |
//!
//! `BSplineTransform` (or `RecursiveBSplineTransform`) is read when cubic (`BSplineTransformSplineOrder 3`), not
//! cyclic, its grid indexed from 0: as ITK's, it is x itself outside the region where all 4 × 4 × 4 of a point's
//! control points exist. `SplineKernelTransform` is read with the `ThinPlateSpline` kernel, solved as ITK solves it,
//! relaxed by `SplineRelaxationFactor` ([`ThinPlateKernel`]). `DeformationFieldTransform` reads its field as elastix
//! does ([`FieldStep`]): the vector of the nearest voxel centre (`DeformationFieldInterpolationOrder 0`, the default)
//! or trilinear between centres (`1`), the outermost vectors held to half a voxel past the outermost centres, and
//! x itself beyond; the field is any flavour warpbench reads, looked for beside the parameter file, then as given.
//!
//! `InitialTransformParameterFileName` names a file whose transform is applied first: with `HowToCombineTransforms
//! "Compose"` (the default) the chain is T(x) = T₁(T₀(x)). The `elastix` executable writes the path it was given;
//! it is looked for beside the file that names it, then as given.
//!
//! # As a displacement field
//!
//! [`read_field`] samples the whole chain at every voxel centre of the named file's fixed grid (`Size`, `Spacing`,
//! `Origin`, `Direction`): D(x) = T(x) − x, the pull-back, f32, as `transformix -def all` writes
//! `deformationField.mhd`. Resampling the moving image onto that grid through it is what transformix does at those
//! centres; between them the field is trilinear, and outside the grid it is 0, as every displacement field.
//!
//! Checked against transformix (itk-elastix 0.25.4): the fixtures of `tests/data/elastix/` (elastix's own files, and
//! warpbench's) map points where transformix maps them (`data-scripts/elastix_transforms.py`).

mod deformation_field;
mod field;
mod params;
mod read;
mod transform;
mod write;

pub use deformation_field::{FieldInterpolation, FieldStep};
pub use field::{read_field, sample};
pub use params::looks_like_parameter_file;
pub use read::{parse_transform, read_affine, read_transform};
pub use transform::{ElastixTransform, Link, MAX_KERNEL_LANDMARKS, Step, ThinPlateKernel};
pub use write::{
    ElastixGrid, check_field_name, field_transform_text, to_text, transform_name, write, write_field_transform,
};
