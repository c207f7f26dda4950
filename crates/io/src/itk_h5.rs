//! ITK's HDF5 transform files (`.h5`): what `antsRegistration` writes as `Composite.h5`, what 3D Slicer saves a
//! transform as, and what ITK and SimpleITK write for a transform file named `.h5` (`HDF5TransformIO`). Read:
//! [`read`] (the file's transforms, [`ItkChain`]), [`read_affine`] (a chain of linear transforms as one affine, for a
//! starting transform) and [`read_field`] (the whole chain sampled as a displacement field, for `--field`). Written:
//! [`write()`], one transform or a composite of several ([`H5Transform`]: the classes of a `.tfm`, and a displacement
//! field).
//!
//! # The format
//!
//! One group per transform under `/TransformGroup`, named `0`, `1`, …, each with three datasets:
//!
//! | dataset | holds |
//! |---|---|
//! | `TransformType` | the ITK class, a variable-length string (`AffineTransform_double_3_3`, …) |
//! | `TransformFixedParameters` | the class's fixed parameters, doubles (or floats for a `_float_` class) |
//! | `TransformParameters` | its parameters |
//!
//! The classes and their numbers are those of the text `.tfm` ([`crate::itk_tfm`]: the affine and ITK's other linear
//! classes, read as affines, and the cubic B-spline; a thin-plate spline is refused here, since it would have to be
//! fitted again: its landmarks are read as pairs by [`crate::landmarks::read_landmark_pairs`]), plus
//! **`DisplacementFieldTransform_double_3_3`**: the fixed parameters are 18 numbers, the field's size (voxels per
//! axis), origin (LPS mm), spacing (mm) and direction (row by row); the parameters are its vectors, LPS mm, three
//! per voxel (x, y, z), voxels in image order (x fastest). ITK maps T(x) = x + D(x), with D read trilinearly between
//! the voxel centres and the outermost centres held to the grid's edge, inside the grid (continuous index in
//! [−½, n − ½) on every axis) and T(x) = x outside it ([`crate::elastix::FieldStep`] with
//! [`crate::elastix::FieldInterpolation::Linear`] is the same rule).
//!
//! A composite (`CompositeTransform_double_3_3` in group `0`, with no parameters) lists its members in groups `1`,
//! `2`, …; ITK applies the **last one first**: T(x) = T₁(T₂(… Tₙ(x))). `antsRegistration` writes the affine first
//! and the displacement field after it, so a fixed point x goes to the moving point A(x + D(x)).
//!
//! Points are in LPS mm, as in every ITK file, and the transform maps the output (fixed) space to the input
//! (moving) one: a pull-back, `moving_from_fixed`. 3D Slicer's `Inverse…` classes (a transform saved in its
//! modeling direction: Slicer's `vtkITKTransformInverse.h` stores the parameters of a transform S, and the transform
//! meant is S⁻¹) are read for B-splines and displacement fields, in a composite or alone, as [`ItkStep::Inverse`]:
//! S⁻¹(x) found point by point by Newton's method, as Slicer's VTK inverts them. [`read_field`] reads a file holding
//! only an `InverseDisplacementFieldTransform` as the **forward** field it is (its vectors map a moving point y to
//! the fixed point y + D(y)), which its caller inverts over the whole grid; the landmarks of an
//! `InverseThinPlateSplineKernelTransform` are read as pairs, as those of ITK's spline ([`crate::landmarks`]); its
//! other classes are refused, with a message that says how to save the transform so that it can be read.
//!
//! Checked against SimpleITK 2.5.7 (`crates/io/tests/itk_h5.rs`; `tests/data/itk/h5_*.h5` written by SimpleITK, and
//! what its `TransformPoint` and `TransformToDisplacementField` give for them).
//!
//! # Writing
//!
//! [`write()`] lays the file out as ITK does, with the datasets' names as SimpleITK 2.5.7 writes them (the table
//! above), a variable-length ASCII string for the class (ITK's reader asks the HDF5 library for one, which converts
//! neither a fixed-length nor a UTF-8 string to it) and the parameters in doubles. A displacement field is written as
//! `DisplacementFieldTransform_float_3_3` with its vectors in single precision, the precision warpbench samples
//! fields in: the numbers are the field's own, at half the size of doubles (a 512 × 512 × 300 field is 0.9 GB), and
//! ITK reads the class into its double transform as it reads any float transform. ITK's version strings
//! (`/ITKVersion`, `/OSName`, …) are not written: no reader needs them, and warpbench is not ITK.
//! SimpleITK's reading of written files is checked in `crates/python/tests/test_itk_h5_sitk.py`.

use std::path::Path;

use hdf5_pure::{CharacterSet, Datatype, File, FileBuilder, GroupBuilder, StringPadding, make_u8_type};
use nalgebra::{Matrix3, Vector3};

use crate::displacement::check::first_non_finite;
use crate::displacement::{FieldDirection, FieldSource, ReadField, SampleGrid};
use crate::elastix::{FieldInterpolation, FieldStep};
use crate::error::{Error, Result};
use crate::geometry::{Index, Lps, Transform};
use crate::itk_chain::{COMPOSITE_TYPES, FIELD_TYPES, SLICER_INVERSE_BSPLINE_TYPES, SLICER_INVERSE_FIELD_TYPES};
pub use crate::itk_chain::{FieldOrChain, InverseStep, ItkChain, ItkStep};
use crate::itk_tfm::{ItkAffine, ItkTransform, known_types, transform_of};
use crate::nifti::DisplacementField;
use crate::volume::{self, GeometrySource};

/// The first 8 bytes of every HDF5 file (without a user block, as ITK writes it).
const SIGNATURE: &[u8; 8] = b"\x89HDF\r\n\x1a\n";

/// The longest file read: a displacement field of 256³ voxels in doubles is 400 MB.
const MAX_FILE_BYTES: u64 = 4 << 30;

/// The most transforms one file may hold (a composite's members); ANTs writes two or three.
const MAX_TRANSFORMS: usize = 64;

/// Whether `head`, a file's first bytes, is an HDF5 file.
#[must_use]
pub fn looks_like_hdf5(head: &[u8]) -> bool {
    head.starts_with(SIGNATURE)
}

/// Reads the transforms of an ITK `.h5` file (module docs). Errors name the file: one that is not HDF5, a group
/// without its datasets, a class warpbench does not read, parameters of the wrong count, a field too large for
/// memory.
pub fn read(path: &Path) -> Result<ItkChain> {
    parse(path, read_bytes(path)?)
}

/// The bytes of the regular file `path`, at most [`MAX_FILE_BYTES`].
fn read_bytes(path: &Path) -> Result<Vec<u8>> {
    let len = crate::files::check_regular_file(path)?.len();
    if len > MAX_FILE_BYTES {
        return Err(Error::invalid(path, format!("{len} bytes is too long for a transform file")));
    }
    std::fs::read(path).map_err(|e| Error::io(path, e))
}

/// [`read`] of a file's bytes; `path` is used in errors.
///
/// # Errors
/// As [`read`].
pub fn parse(path: &Path, bytes: Vec<u8>) -> Result<ItkChain> {
    let (file, members) = members(path, bytes)?;
    chain_of(path, &file, members)
}

/// The chain of `members` of `file` (module docs).
fn chain_of(path: &Path, file: &File, members: Vec<Member>) -> Result<ItkChain> {
    let mut steps = Vec::with_capacity(members.len());
    for Member { group, kind } in members {
        if SLICER_INVERSE_BSPLINE_TYPES.contains(&kind.as_str()) || SLICER_INVERSE_FIELD_TYPES.contains(&kind.as_str())
        {
            let plain = kind.strip_prefix("Inverse").unwrap_or(&kind);
            let inverse = match read_step(path, file, &group, plain)? {
                ItkStep::Transform(ItkTransform::BSpline(b)) => InverseStep::BSpline(b),
                ItkStep::Field(f) => InverseStep::Field(f),
                _ => {
                    return Err(Error::invalid(
                        path,
                        format!("{group} is {kind}, but its parameters are not a {plain}"),
                    ));
                }
            };
            steps.push(ItkStep::Inverse(inverse));
            continue;
        }
        if let Some(plain) = kind.strip_prefix("Inverse") {
            return Err(Error::unsupported(
                path,
                format!(
                    "{group} is {kind}, 3D Slicer's {plain} saved in its modeling direction, which warpbench reads \
                     only for B-splines and displacement fields; a thin-plate spline's landmarks are read as pairs \
                     (--landmarks); otherwise, in Slicer, invert the transform (or harden it) before saving"
                ),
            ));
        }
        steps.push(read_step(path, file, &group, &kind)?);
    }
    Ok(ItkChain { steps })
}

/// One transform of a file: its group and its class.
struct Member {
    group: String,
    kind: String,
}

/// The opened file and its transforms, without the composite that may hold them (group `0`): at least one, and no
/// composite inside the composite.
fn members(path: &Path, bytes: Vec<u8>) -> Result<(File, Vec<Member>)> {
    let file = File::from_bytes(bytes)
        .map_err(|e| Error::invalid(path, format!("not an HDF5 file warpbench can read: {e}")))?;
    let count = transform_count(path, &file)?;
    let mut members = Vec::with_capacity(count);
    for i in 0..count {
        let group = format!("/TransformGroup/{i}");
        let kind = read_kind(path, &file, &group)?;
        if COMPOSITE_TYPES.contains(&kind.as_str()) {
            if i == 0 {
                continue;
            }
            return Err(Error::unsupported(path, format!("{group} is a composite inside a composite ({kind})")));
        }
        members.push(Member { group, kind });
    }
    if members.is_empty() {
        return Err(Error::invalid(path, "the composite transform holds no transforms"));
    }
    Ok((file, members))
}

/// Reads an `.h5` file whose transforms are all affine, as the one affine they make (fixed → moving, LPS mm): a
/// starting transform.
///
/// # Errors
/// As [`read`], and a file holding a transform that is not linear, named by its class.
pub fn read_affine(path: &Path) -> Result<ItkAffine> {
    let chain = read(path)?;
    chain.affine().map_err(|kind| {
        Error::unsupported(
            path,
            format!(
                "it holds a {kind}, not only affine transforms; a starting transform is linear (read the file as a \
                 displacement field instead, e.g. with --field)"
            ),
        )
    })
}

/// The class and the numbers of a file's one transform, not yet interpreted: what a thin-plate spline's landmarks
/// are read from ([`crate::landmarks`]), whatever its class.
pub(crate) struct RawTransform {
    /// The ITK class, as `TransformType` names it.
    pub kind: String,
    /// `TransformParameters`.
    pub params: Vec<f64>,
    /// `TransformFixedParameters`.
    pub fixed: Vec<f64>,
}

/// The one transform of an `.h5` file's bytes (alone, or the only member of a composite); `path` is used in errors,
/// which also refuse a file of several transforms, naming their classes.
pub(crate) fn parse_single(path: &Path, bytes: Vec<u8>) -> Result<RawTransform> {
    let (file, members) = members(path, bytes)?;
    match members.as_slice() {
        [Member { group, kind }] => {
            let limit = 3 * crate::itk_tfm::MAX_TPS_LANDMARKS;
            let params = read_numbers(path, &file, group, "TransformParameters", limit)?;
            let fixed = read_numbers(path, &file, group, "TransformFixedParameters", limit)?;
            Ok(RawTransform { kind: kind.clone(), params, fixed })
        }
        many => Err(Error::unsupported(
            path,
            format!(
                "{} transforms ({}); one was expected",
                many.len(),
                many.iter().map(|m| m.kind.as_str()).collect::<Vec<_>>().join(", ")
            ),
        )),
    }
}

/// Reads an `.h5` file as a displacement field ([`crate::itk_chain::ItkChain::field_on`]: a chain holding a
/// displacement field sampled on the grid of the field applied first; one of B-splines on `grid`). A file holding
/// only 3D Slicer's `InverseDisplacementFieldTransform` is its field as stored, stated to be the forward map (module
/// docs).
///
/// # Errors
/// As [`read`] and [`crate::itk_chain::ItkChain::field_on`].
pub fn read_field_on(path: &Path, grid: Option<&SampleGrid>) -> Result<ReadField> {
    match read_field_or_chain(path)? {
        FieldOrChain::Field(read) => Ok(read),
        FieldOrChain::Chain(chain) => chain.field_on(path, grid, FieldSource::ItkHdf5),
    }
}

/// The `.h5` file read once, as the displacement field it holds (sampled on its grid, as [`read_field_on`] reads it)
/// or, when it holds none, as its chain.
///
/// # Errors
/// As [`read`], and what sampling the chain on its field's grid refuses.
pub fn read_field_or_chain(path: &Path) -> Result<FieldOrChain> {
    let (file, members) = members(path, read_bytes(path)?)?;
    if let [Member { group, kind }] = members.as_slice()
        && SLICER_INVERSE_FIELD_TYPES.contains(&kind.as_str())
    {
        let step = read_displacement_field(path, &file, group)?;
        return Ok(FieldOrChain::Field(ReadField {
            field: step.field,
            source: FieldSource::ItkHdf5,
            direction: Some(FieldDirection::Forward),
            warnings: Vec::new(),
        }));
    }
    let chain = chain_of(path, &file, members)?;
    if chain.has_field() {
        return chain.field_on(path, None, FieldSource::ItkHdf5).map(FieldOrChain::Field);
    }
    Ok(FieldOrChain::Chain(chain))
}

/// [`read_field_on`] without a grid: a file that holds a displacement field.
///
/// # Errors
/// As [`read_field_on`].
pub fn read_field(path: &Path) -> Result<ReadField> {
    read_field_on(path, None)
}

/// How many groups `/TransformGroup` holds, checked to be `0`, `1`, … with nothing else.
fn transform_count(path: &Path, file: &File) -> Result<usize> {
    let group = file.group("/TransformGroup").map_err(|e| {
        Error::invalid(path, format!("no /TransformGroup ({e}): an HDF5 file, but not an ITK transform file"))
    })?;
    let names = group.groups().map_err(|e| Error::invalid(path, format!("/TransformGroup cannot be listed: {e}")))?;
    if names.is_empty() {
        return Err(Error::invalid(path, "/TransformGroup holds no transform"));
    }
    if names.len() > MAX_TRANSFORMS {
        return Err(Error::invalid(path, format!("{} transforms; at most {MAX_TRANSFORMS} are read", names.len())));
    }
    let mut numbers: Vec<usize> = names.iter().filter_map(|n| n.parse().ok()).collect();
    numbers.sort_unstable();
    if numbers.len() != names.len() || numbers.iter().enumerate().any(|(i, &n)| i != n) {
        return Err(Error::invalid(
            path,
            format!("/TransformGroup holds groups {names:?}; ITK numbers its transforms 0, 1, 2, …"),
        ));
    }
    Ok(names.len())
}

/// The ITK class in `group`'s `TransformType`.
fn read_kind(path: &Path, file: &File, group: &str) -> Result<String> {
    let strings = file
        .dataset(&format!("{group}/TransformType"))
        .and_then(|d| d.read_string())
        .map_err(|e| Error::invalid(path, format!("{group}/TransformType cannot be read: {e}")))?;
    match strings.as_slice() {
        [kind] => Ok(kind.trim_end_matches('\0').trim().to_owned()),
        other => Err(Error::invalid(path, format!("{group}/TransformType holds {} strings, not one", other.len()))),
    }
}

/// The numbers of `group`'s dataset `name`, finite, at most `limit` of them.
fn read_numbers(path: &Path, file: &File, group: &str, name: &str, limit: usize) -> Result<Vec<f64>> {
    let at = format!("{group}/{name}");
    let dataset = file.dataset(&at).map_err(|e| Error::invalid(path, format!("{at} is missing: {e}")))?;
    let shape = dataset.shape().map_err(|e| Error::invalid(path, format!("{at}: {e}")))?;
    let len = shape.iter().try_fold(1u64, |a, &d| a.checked_mul(d)).unwrap_or(u64::MAX);
    if len > limit as u64 {
        return Err(Error::invalid(path, format!("{at} holds {len} numbers, more than the {limit} expected")));
    }
    crate::hdf5_guard::check_chunks(path, &dataset, &at, file.file_size())?;
    let values =
        dataset.read_f64().map_err(|e| Error::invalid(path, format!("{at} cannot be read as numbers: {e}")))?;
    if let Some(i) = values.iter().position(|v| !v.is_finite()) {
        return Err(Error::invalid(path, format!("{at}: number {} is not finite", i + 1)));
    }
    Ok(values)
}

/// The transform of class `kind` in `group`.
fn read_step(path: &Path, file: &File, group: &str, kind: &str) -> Result<ItkStep> {
    if FIELD_TYPES.contains(&kind) {
        return read_displacement_field(path, file, group).map(|f| ItkStep::Field(Box::new(f)));
    }
    let known = known_types();
    if !known.contains(&kind) {
        let mut all = known;
        all.extend(FIELD_TYPES);
        return Err(Error::unsupported(path, format!("{group} is a {kind}; only these are read: {}", all.join(", "))));
    }
    let limit = 3 * crate::itk_tfm::MAX_BSPLINE_CONTROL_POINTS;
    let fixed = read_numbers(path, file, group, "TransformFixedParameters", limit)?;
    let params = read_numbers(path, file, group, "TransformParameters", limit)?;
    match transform_of(path, kind, &params, &fixed)? {
        ItkTransform::ThinPlateSpline(_) => Err(Error::unsupported(
            path,
            format!(
                "{group} is a {kind}: ITK stores only its landmarks and fits it again on reading; give the file as \
                 landmark pairs (--landmarks), which warpbench fits the same way"
            ),
        )),
        t => Ok(ItkStep::Transform(t)),
    }
}

/// A `DisplacementFieldTransform` in `group` (module docs).
fn read_displacement_field(path: &Path, file: &File, group: &str) -> Result<FieldStep> {
    let f = read_numbers(path, file, group, "TransformFixedParameters", 18)?;
    if f.len() != 18 {
        return Err(Error::invalid(
            path,
            format!(
                "{group}/TransformFixedParameters: {} numbers, expected 18 (size, origin, spacing, direction)",
                f.len()
            ),
        ));
    }
    let mut dims = [0usize; 3];
    for (n, &v) in dims.iter_mut().zip(&f[..3]) {
        if v.fract() != 0.0 || !(1.0..=f64::from(u32::MAX)).contains(&v) {
            return Err(Error::invalid(
                path,
                format!("{group}: the field's size {:?} is not 3 whole numbers", &f[..3]),
            ));
        }
        *n = v as usize;
    }
    let n = volume::check_allocation(path, dims, 24, volume::DEFAULT_MAX_VOXEL_BYTES)?;
    let spacing = Matrix3::from_diagonal(&Vector3::new(f[6], f[7], f[8]));
    let direction = Matrix3::from_row_slice(&f[9..18]);
    let lps_from_index = Transform::from_linear_translation(direction * spacing, [f[3], f[4], f[5]]);
    let params = read_numbers(path, file, group, "TransformParameters", 3 * n)?;
    if params.len() != 3 * n {
        return Err(Error::invalid(
            path,
            format!(
                "{group}/TransformParameters: {} numbers, expected {} (3 per voxel of {dims:?})",
                params.len(),
                3 * n
            ),
        ));
    }
    let displacements_lps = params.chunks_exact(3).map(|v| [v[0] as f32, v[1] as f32, v[2] as f32]).collect();
    let field = DisplacementField {
        dims,
        lps_from_index,
        geometry_source: GeometrySource::ItkTransformFile,
        displacements_lps,
    };
    FieldStep::new(path, path.to_path_buf(), field, FieldInterpolation::Linear)
}

/// One transform for [`write()`], borrowed.
#[derive(Clone, Copy, Debug)]
pub enum H5Transform<'a> {
    /// An affine, a thin-plate spline or a cubic B-spline, as a `.tfm` holds them (ITK fits a thin-plate spline again
    /// on reading, from its landmarks).
    Transform(&'a ItkTransform),
    /// A `DisplacementFieldTransform`: T(x) = x + D(x), D sampled at the voxel centres of a grid (module docs).
    Field {
        /// Voxels along i, j, k.
        dims: [usize; 3],
        lps_from_index: &'a Transform<Lps, Index>,
        /// D at each voxel centre, LPS mm, i fastest.
        displacements_lps: &'a [[f32; 3]],
    },
    /// 3D Slicer's `Inverse…` class of a B-spline or a field (module docs), written under that class.
    Inverse(&'a InverseStep),
}

impl<'a> From<&'a ItkStep> for H5Transform<'a> {
    /// A transform as read, to be written again.
    fn from(step: &'a ItkStep) -> Self {
        match step {
            ItkStep::Transform(t) => Self::Transform(t),
            ItkStep::Field(f) => Self::Field {
                dims: f.field.dims,
                lps_from_index: &f.field.lps_from_index,
                displacements_lps: &f.field.displacements_lps,
            },
            ItkStep::Inverse(inverse) => Self::Inverse(inverse),
        }
    }
}

impl H5Transform<'_> {
    /// The class [`write()`] writes it under (its group's `TransformType`).
    #[must_use]
    pub fn class(&self) -> &'static str {
        match self {
            Self::Transform(t) => t.type_name(),
            Self::Field { .. } => FIELD_TYPES[1],
            Self::Inverse(InverseStep::BSpline(_)) => SLICER_INVERSE_BSPLINE_TYPES[0],
            Self::Inverse(InverseStep::Field(_)) => SLICER_INVERSE_FIELD_TYPES[1],
        }
    }
}

/// The class [`write()`] puts in group `0` over several transforms.
pub const COMPOSITE_CLASS: &str = COMPOSITE_TYPES[0];

/// Writes `chain` as ITK's HDF5 transform file, atomically (module docs, "Writing"): one transform in group `0`, or
/// for several a `CompositeTransform_double_3_3` in group `0` and the transforms in `1`, `2`, … in ITK's order (the
/// last is applied first: T(x) = T₁(T₂(… Tₙ(x)))).
///
/// # Errors
/// Nothing to write, a transform ITK cannot take (numbers that are not finite, mismatched landmarks, a grid too
/// small for a cubic B-spline), a field whose grid is singular or whose vector count is not one per voxel, or the
/// write itself; nothing is written then.
pub fn write(path: &Path, chain: &[H5Transform<'_>]) -> Result<()> {
    if chain.is_empty() {
        return Err(Error::invalid(path, "no transform to write"));
    }
    if chain.len() > MAX_TRANSFORMS {
        return Err(Error::invalid(path, format!("{} transforms; at most {MAX_TRANSFORMS} are written", chain.len())));
    }
    let mut builder = FileBuilder::new();
    let mut transforms = builder.create_group("TransformGroup");
    let offset = usize::from(chain.len() > 1);
    if offset == 1 {
        let mut group = transforms.create_group("0");
        write_class(&mut group, COMPOSITE_CLASS);
        transforms.add_group(group.finish());
    }
    for (i, step) in chain.iter().enumerate() {
        let mut group = transforms.create_group(&(i + offset).to_string());
        let class = step.class();
        match *step {
            H5Transform::Transform(t) => write_transform(path, &mut group, t, class)?,
            H5Transform::Field { dims, lps_from_index, displacements_lps } => {
                write_field_member(path, &mut group, (dims, lps_from_index, displacements_lps), class)?;
            }
            H5Transform::Inverse(InverseStep::BSpline(b)) => {
                write_transform(path, &mut group, &ItkTransform::BSpline(b.clone()), class)?;
            }
            H5Transform::Inverse(InverseStep::Field(f)) => {
                let field = (f.field.dims, &f.field.lps_from_index, f.field.displacements_lps.as_slice());
                write_field_member(path, &mut group, field, class)?;
            }
        }
        transforms.add_group(group.finish());
    }
    builder.add_group(transforms.finish());
    crate::write_atomic(path, |w| {
        builder.finish_to(w).map_err(|e| match e {
            hdf5_pure::Error::Io(io) => io,
            other => std::io::Error::other(other.to_string()),
        })
    })
}

/// An affine, a thin-plate spline or a B-spline in `group`, under `class`.
fn write_transform(path: &Path, group: &mut GroupBuilder, t: &ItkTransform, class: &str) -> Result<()> {
    t.check(path)?;
    let (params, fixed) = t.parameters();
    write_class(group, class);
    group.create_dataset("TransformFixedParameters").with_f64_data(&fixed);
    group.create_dataset("TransformParameters").with_f64_data(&params);
    Ok(())
}

/// A displacement field (its grid's dims, `lps_from_index`, and its vectors, LPS mm) in `group`, under `class`, the
/// vectors in single precision.
fn write_field_member(
    path: &Path,
    group: &mut GroupBuilder,
    (dims, lps_from_index, displacements_lps): ([usize; 3], &Transform<Lps, Index>, &[[f32; 3]]),
    class: &str,
) -> Result<()> {
    let fixed = field_fixed_parameters(path, dims, lps_from_index, displacements_lps.len())?;
    if let Some(ijk) = first_non_finite(dims, displacements_lps) {
        return Err(Error::invalid(path, format!("the displacement at voxel {ijk:?} (i, j, k) is not finite")));
    }
    write_class(group, class);
    group.create_dataset("TransformFixedParameters").with_f64_data(&fixed);
    group.create_dataset("TransformParameters").with_f32_data(displacements_lps.as_flattened());
    Ok(())
}

/// `group`'s `TransformType`, the class, as ITK writes it: one variable-length ASCII string. ITK reads it into a
/// variable-length `C_S1` string, and the HDF5 library converts neither a fixed-length string nor a UTF-8 one to that.
fn write_class(group: &mut GroupBuilder, class: &str) {
    let ascii = Datatype::VariableLength {
        is_string: true,
        padding: Some(StringPadding::NullTerminate),
        charset: Some(CharacterSet::Ascii),
        base_type: Box::new(make_u8_type()),
    };
    // The staged heap objects are the string's bytes whatever its character set; only the type is ASCII's.
    group.create_dataset("TransformType").with_vlen_strings(&[class]).with_dtype(ascii);
}

/// A `DisplacementFieldTransform`'s 18 fixed parameters (module docs): size, origin, spacing and direction (row by
/// row) of the grid whose index-to-LPS map is `lps_from_index`.
///
/// # Errors
/// A grid with an empty or singular axis, or `vectors` not one per voxel.
fn field_fixed_parameters(
    path: &Path,
    dims: [usize; 3],
    lps_from_index: &Transform<Lps, Index>,
    vectors: usize,
) -> Result<Vec<f64>> {
    let voxels = dims.iter().try_fold(1usize, |a, &n| a.checked_mul(n));
    if dims.contains(&0) || voxels != Some(vectors) {
        return Err(Error::invalid(path, format!("{vectors} displacement vectors for a grid of {dims:?} voxels")));
    }
    let linear = lps_from_index.linear();
    let spacing: [f64; 3] = std::array::from_fn(|a| linear.column(a).norm());
    let det = linear.determinant();
    if det == 0.0 || !det.is_finite() {
        return Err(Error::invalid(path, format!("the field's grid is singular: index to LPS {linear}")));
    }
    let direction = Matrix3::from_fn(|r, c| linear[(r, c)] / spacing[c]);
    let mut fixed = dims.map(|n| n as f64).to_vec();
    fixed.extend(lps_from_index.translation());
    fixed.extend(spacing);
    fixed.extend((0..3).flat_map(|r| (0..3).map(move |c| direction[(r, c)])));
    // A grid whose spacing overflows a double (axes near 1e308 mm) has no size, origin and spacing ITK can hold.
    if let Some(i) = fixed.iter().position(|v| !v.is_finite()) {
        return Err(Error::invalid(
            path,
            format!("the field's grid has no finite ITK geometry (fixed parameter {}): index to LPS {linear}", i + 1),
        ));
    }
    Ok(fixed)
}
