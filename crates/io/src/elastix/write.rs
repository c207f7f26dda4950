//! Writing a transform as an elastix transform parameter file that transformix applies.

use std::fmt::Write as _;
use std::path::Path;

use crate::error::{Error, Result};
use crate::geometry::{Index, Lps, Transform};
use crate::itk_tfm::ItkTransform;

/// The fixed image's grid, which a parameter file names as where transformix resamples (`Size`, `Spacing`,
/// `Origin`, `Direction`).
#[derive(Clone, Debug, PartialEq)]
pub struct ElastixGrid {
    pub dims: [usize; 3],
    pub lps_from_index: Transform<Lps, Index>,
}

/// The parameter file of `transform` over `grid` (module docs of [`super`]): the parameters sorted by name, as
/// itk-elastix writes them, numbers in their shortest round-trip form. The thin-plate spline is a
/// `SplineKernelTransform` (`ThinPlateSpline`, kernel r, relaxation 0: it interpolates its targets, as the `.tfm`
/// does), the B-spline a cubic `BSplineTransform` on the same lattice, the affine an `AffineTransform`.
#[must_use]
pub fn to_text(transform: &ItkTransform, grid: &ElastixGrid) -> String {
    let mut entries = grid_entries(grid);
    let parameters: Vec<f64> = match transform {
        ItkTransform::Affine(a) => {
            entries.push(("Transform", quoted(transform_name(transform))));
            entries.push(("CenterOfRotationPoint", numbers(a.center)));
            (0..3).flat_map(|r| (0..3).map(move |c| a.matrix[(r, c)])).chain(a.translation).collect()
        }
        ItkTransform::ThinPlateSpline(t) => {
            entries.push(("Transform", quoted(transform_name(transform))));
            entries.push(("SplineKernelType", quoted("ThinPlateSpline")));
            entries.push(("SplinePoissonRatio", "0.3".into()));
            entries.push(("SplineRelaxationFactor", "0".into()));
            entries.push(("FixedImageLandmarks", numbers(t.source_lps.iter().flatten().copied())));
            t.target_lps.iter().flatten().copied().collect()
        }
        ItkTransform::BSpline(b) => {
            entries.push(("Transform", quoted(transform_name(transform))));
            entries.push(("BSplineTransformSplineOrder", "3".into()));
            entries.push(("UseCyclicTransform", quoted("false")));
            entries.push(("GridSize", b.grid_size.map(|n| n.to_string()).join(" ")));
            entries.push(("GridIndex", "0 0 0".into()));
            entries.push(("GridSpacing", numbers(b.grid_spacing_mm)));
            entries.push(("GridOrigin", numbers(b.grid_origin_lps)));
            // Column by column: column a is grid axis a.
            entries.push(("GridDirection", numbers((0..3).flat_map(|a| (0..3).map(move |r| b.grid_direction[r][a])))));
            (0..3).flat_map(|c| b.coefficients_mm.iter().map(move |v| v[c])).collect()
        }
    };
    entries.push(("NumberOfParameters", parameters.len().to_string()));
    entries.push(("TransformParameters", numbers(parameters)));
    lines(entries)
}

/// The parameter file of a `DeformationFieldTransform` over `grid` whose field is the file `field_file` names
/// (as the file will say it: transformix looks for it from the folder it runs in, warpbench beside the parameter
/// file first), read trilinearly (`DeformationFieldInterpolationOrder 1`), so that at `grid`'s voxel centres it is
/// the field's vectors.
#[must_use]
pub fn field_transform_text(field_file: &str, grid: &ElastixGrid) -> String {
    let mut entries = grid_entries(grid);
    entries.push(("Transform", quoted("DeformationFieldTransform")));
    entries.push(("DeformationFieldFileName", quoted(field_file)));
    entries.push(("DeformationFieldInterpolationOrder", "1".into()));
    entries.push(("NumberOfParameters", "0".into()));
    lines(entries)
}

/// Writes [`field_transform_text`] to `path`, atomically. A name elastix cannot quote (a `"` or a line break in
/// it) or a grid that is not a valid affine is refused and nothing is written.
pub fn write_field_transform(path: &Path, field_file: &str, grid: &ElastixGrid) -> Result<()> {
    check_grid(path, grid)?;
    check_field_name(path, field_file)?;
    let text = field_transform_text(field_file, grid);
    crate::write_atomic(path, |w| w.write_all(text.as_bytes()))
}

/// Refuses a field name the parameter file `path` cannot hold: one with a `"` or a control character in it, which
/// elastix's parser cannot read. Callers that write the field first check here before.
///
/// # Errors
/// That name, naming `path`.
pub fn check_field_name(path: &Path, field_file: &str) -> Result<()> {
    if field_file.chars().any(|c| c == '"' || c.is_control()) {
        return Err(Error::invalid(
            path,
            format!("the field's name {field_file:?} holds a quote or a control character, which elastix cannot read"),
        ));
    }
    Ok(())
}

/// The entries every file writes: the fixed grid and transformix's resampler settings.
fn grid_entries(grid: &ElastixGrid) -> Vec<(&'static str, String)> {
    let (columns, spacing) = crate::metaimage::direction_spacing(&grid.lps_from_index);
    vec![
        ("CompressResultImage", quoted("false")),
        ("DefaultPixelValue", "0".into()),
        ("Direction", numbers(columns.iter().flatten().copied())),
        ("FinalBSplineInterpolationOrder", "3".into()),
        ("FixedImageDimension", "3".into()),
        ("FixedInternalImagePixelType", quoted("float")),
        ("HowToCombineTransforms", quoted("Compose")),
        ("Index", "0 0 0".into()),
        ("InitialTransformParameterFileName", quoted("NoInitialTransform")),
        ("MovingImageDimension", "3".into()),
        ("MovingInternalImagePixelType", quoted("float")),
        ("Origin", numbers(grid.lps_from_index.translation())),
        ("ResampleInterpolator", quoted("FinalBSplineInterpolator")),
        ("Resampler", quoted("DefaultResampler")),
        ("ResultImageFormat", quoted("nii")),
        ("ResultImagePixelType", quoted("float")),
        ("Size", grid.dims.map(|n| n.to_string()).join(" ")),
        ("Spacing", numbers(spacing)),
        ("UseDirectionCosines", quoted("true")),
    ]
}

/// The entries sorted by name, one `(Name value …)` line each.
fn lines(mut entries: Vec<(&str, String)>) -> String {
    entries.sort_by(|a, b| a.0.cmp(b.0));
    let mut text = String::new();
    for (key, value) in entries {
        let _ = writeln!(text, "({key} {value})");
    }
    text
}

/// The `(Transform …)` [`to_text`] writes for `transform`.
#[must_use]
pub const fn transform_name(transform: &ItkTransform) -> &'static str {
    match transform {
        ItkTransform::Affine(_) => "AffineTransform",
        ItkTransform::ThinPlateSpline(_) => "SplineKernelTransform",
        ItkTransform::BSpline(_) => "BSplineTransform",
    }
}

/// Writes [`to_text`] to `path`, atomically. A transform with a non-finite number, or a grid that is not a valid
/// affine, is refused and nothing is written.
pub fn write(path: &Path, transform: &ItkTransform, grid: &ElastixGrid) -> Result<()> {
    check_grid(path, grid)?;
    if !is_finite(transform) {
        return Err(Error::invalid(path, "the transform holds a number that is not finite"));
    }
    let text = to_text(transform, grid);
    crate::write_atomic(path, |w| w.write_all(text.as_bytes()))
}

fn check_grid(path: &Path, grid: &ElastixGrid) -> Result<()> {
    if grid.lps_from_index.is_valid_affine() {
        Ok(())
    } else {
        Err(Error::invalid(path, "the fixed grid's voxel-to-patient matrix is singular or not finite"))
    }
}

fn is_finite(transform: &ItkTransform) -> bool {
    let finite = |v: &[f64]| v.iter().all(|x| x.is_finite());
    match transform {
        ItkTransform::Affine(a) => finite(a.matrix.as_slice()) && finite(&a.translation) && finite(&a.center),
        ItkTransform::ThinPlateSpline(t) => t.source_lps.iter().chain(&t.target_lps).all(|p| finite(p)),
        ItkTransform::BSpline(b) => {
            finite(&b.grid_origin_lps)
                && finite(&b.grid_spacing_mm)
                && b.grid_direction.iter().all(|r| finite(r))
                && b.coefficients_mm.iter().all(|c| finite(c))
        }
    }
}

fn quoted(s: &str) -> String {
    format!("\"{s}\"")
}

fn numbers(values: impl IntoIterator<Item = f64>) -> String {
    values.into_iter().map(|v| format!("{}", v + 0.0)).collect::<Vec<_>>().join(" ")
}
