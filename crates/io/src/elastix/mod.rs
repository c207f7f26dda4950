//! elastix transform parameter files (`TransformParameters.0.txt`): [`read_affine`] reads the linear ones (a chain of
//! them included) for `--initial`, [`write()`] writes every transform warpbench fits so that transformix applies it.
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
//!
//! `InitialTransformParameterFileName` names a file whose transform is applied first: with `HowToCombineTransforms
//! "Compose"` (the default) the chain is T(x) = T₁(T₀(x)). The `elastix` executable writes the path it was given;
//! it is looked for beside the file that names it, then as given.
//!
//! Checked against transformix (itk-elastix 0.25.4): the fixtures of `tests/data/elastix/` (elastix's own files, and
//! warpbench's) map points where transformix maps them (`data-scripts/elastix_transforms.py`).

mod params;
mod read;
mod write;

pub use params::looks_like_parameter_file;
pub use read::read_affine;
pub use write::{ElastixGrid, to_text, transform_name, write};
