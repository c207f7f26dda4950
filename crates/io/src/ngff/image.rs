//! Reading an OME-Zarr image as a volume ([`read()`]): the layout of its axes, its placement in LPS, its samples.
//! The field reader ([`super::field`]) shares the layout, the placement and the samples.

use std::path::Path;
use std::sync::Arc;

use nalgebra::{Matrix3, Matrix4};
use zarrs::array::{Array, ArraySubset};
use zarrs::filesystem::FilesystemStore;

use super::meta::{self, ArrayMeta, Axis, AxisKind, Image};
use crate::error::{Error, ErrorKind, Result};
use crate::geometry::{Index, Lps, Transform};
use crate::options::LoadOptions;
use crate::sample::{Stored, StoredType, with_stored_type};
use crate::volume::{GeometrySource, Volume, VoxelData, check_allocation};

/// Reads the OME-Zarr image in the folder `path` (the module docs of [`super`]).
///
/// # Errors
/// A folder that is not an OME-Zarr image, a version other than 0.4, 0.5 and 0.6, axes other than the module docs
/// say, a transformation other than scale and translation, an unknown unit, a missing or corrupt array, samples
/// that are not integers or floats, a volume over [`LoadOptions::max_voxel_bytes`]; each names the folder.
pub fn read(path: &Path, opts: &mut LoadOptions) -> Result<Volume> {
    crate::files::check_file_or_folder(path)?;
    let image = meta::read_image(path, "")?;
    let array = meta::read_array_meta(path, &image.array_path)?;
    let layout = Layout::of(path, &image, &array, opts.frame)?;
    let mut warnings = Vec::new();
    let lps_from_index = lps_from_index(path, &image, &layout, &mut warnings)?;
    let n = check_allocation(path, layout.dims, array.stored.bytes(), opts.max_voxel_bytes)?;
    check_chunks(path, &array, opts.max_voxel_bytes)?;
    opts.report(path, "reading", 0, 1)?;
    let data = with_stored_type!(array.stored, T => samples::<T>(path, &image, &layout, n)?);
    opts.report(path, "reading", 1, 1)?;
    let mut volume = Volume::new(path, layout.dims, data, lps_from_index, GeometrySource::OmeZarr)?;
    if image.levels > 1 {
        warnings.push(format!("the full-resolution level of {} was read", image.levels));
    }
    volume.metadata.warnings.extend(warnings);
    Ok(volume)
}

/// Where the image's axes are in the array and what is read of it.
#[derive(Clone, Debug)]
pub(super) struct Layout {
    /// The array axes that are i, j and k: the spatial ones, fastest first.
    pub(super) spatial: [usize; 3],
    /// Voxels along i, j, k.
    pub(super) dims: [usize; 3],
    /// The part of the array read: every spatial sample, one frame, the one sample of any other axis.
    pub(super) ranges: Vec<std::ops::Range<u64>>,
}

impl Layout {
    fn of(path: &Path, image: &Image, array: &ArrayMeta, frame: Option<usize>) -> Result<Self> {
        let names: Vec<&str> = image.axes.iter().map(|a| a.name.as_str()).collect();
        if array.shape.len() != image.axes.len() {
            return Err(Error::invalid(
                path,
                format!(
                    "the image has {} axes {names:?} but its array {} dimensions",
                    image.axes.len(),
                    array.shape.len()
                ),
            ));
        }
        let mut spatial = Vec::new();
        let mut time = None;
        let mut ranges: Vec<std::ops::Range<u64>> = Vec::new();
        for (a, (axis, &len)) in image.axes.iter().zip(&array.shape).enumerate() {
            ranges.push(0..len);
            match &axis.kind {
                AxisKind::Space => spatial.push(a),
                AxisKind::Time if time.is_none() => time = Some(a),
                AxisKind::Other(t) if t == "displacement" => {
                    return Err(Error::unsupported(
                        path,
                        "a displacement field (OME-Zarr 0.6, RFC-5), not a volume: give it where a field is taken \
                         (--field, --initial-field, the window's Use displacement field)",
                    ));
                }
                kind if len > 1 => {
                    let what = kind.samples();
                    return Err(Error::unsupported(
                        path,
                        format!(
                            "the image has {len} {what} (axis {:?}); warpbench reads one value per voxel: save one \
                             channel as an image of its own",
                            axis.name
                        ),
                    ));
                }
                _ => {}
            }
        }
        let Ok(spatial) = <[usize; 3]>::try_from(spatial.iter().rev().copied().collect::<Vec<_>>()) else {
            return Err(Error::unsupported(
                path,
                format!("the image's axes are {names:?}, {} of them space axes; a volume has three", spatial.len()),
            ));
        };
        let mut seen: Vec<&str> = spatial.iter().map(|&a| image.axes[a].name.as_str()).collect();
        seen.sort_unstable();
        if seen != ["x", "y", "z"] {
            return Err(Error::unsupported(
                path,
                format!("the space axis names are {seen:?}; warpbench places x, y and z (as ngff-zarr and ITK do)"),
            ));
        }
        let frames = time.map_or(1, |t| array.shape[t]);
        let chosen = match (frame, frames) {
            (None, 1) => 0,
            (None, frames) => {
                return Err(Error::new(
                    path,
                    ErrorKind::FrameRequired { frames: usize::try_from(frames).unwrap_or(usize::MAX) },
                ));
            }
            (Some(t), n) if t as u64 >= n => {
                return Err(Error::invalid(path, format!("frame {t} is out of range: the image has {n} frame(s)")));
            }
            (Some(t), _) => t as u64,
        };
        for (a, r) in ranges.iter_mut().enumerate() {
            if Some(a) == time {
                *r = chosen..chosen + 1;
            } else if !spatial.contains(&a) {
                *r = 0..r.end.min(1);
            }
        }
        let mut dims = [0usize; 3];
        for (d, &a) in dims.iter_mut().zip(&spatial) {
            *d = usize::try_from(array.shape[a]).map_err(|_| Error::invalid(path, "an axis is too long"))?;
        }
        Ok(Self { spatial, dims, ranges })
    }
}

/// Millimetres per unit of a UDUNITS-2 length unit (the ones OME-Zarr allows for space axes).
fn mm_per_unit(unit: &str) -> Option<f64> {
    Some(match unit {
        "angstrom" => 1e-7,
        "attometer" => 1e-15,
        "centimeter" => 10.0,
        "decimeter" => 100.0,
        "exameter" => 1e21,
        "femtometer" => 1e-12,
        "foot" => 304.8,
        "gigameter" => 1e12,
        "hectometer" => 1e5,
        "inch" => 25.4,
        "kilometer" => 1e6,
        "megameter" => 1e9,
        "meter" => 1e3,
        "micrometer" => 1e-3,
        "mile" => 1_609_344.0,
        "millimeter" => 1.0,
        "nanometer" => 1e-6,
        "parsec" => 3.085_677_581_491_367e19,
        "petameter" => 1e18,
        "picometer" => 1e-9,
        "terameter" => 1e15,
        "yard" => 914.4,
        "yoctometer" => 1e-21,
        "yottameter" => 1e27,
        "zeptometer" => 1e-18,
        "zettameter" => 1e24,
        _ => return None,
    })
}

/// The LPS unit vector of an RFC-4 orientation value, for the six that name a patient axis.
fn lps_direction(orientation: &str) -> Option<[f64; 3]> {
    Some(match orientation {
        "right-to-left" => [1.0, 0.0, 0.0],
        "left-to-right" => [-1.0, 0.0, 0.0],
        "anterior-to-posterior" => [0.0, 1.0, 0.0],
        "posterior-to-anterior" => [0.0, -1.0, 0.0],
        "inferior-to-superior" => [0.0, 0.0, 1.0],
        "superior-to-inferior" => [0.0, 0.0, -1.0],
        _ => return None,
    })
}

/// The LPS direction of the axis named `x`, `y` or `z` when nothing orients it.
fn named_direction(name: &str) -> [f64; 3] {
    match name {
        "x" => [1.0, 0.0, 0.0],
        "y" => [0.0, 1.0, 0.0],
        _ => [0.0, 0.0, 1.0],
    }
}

/// The image's `lps_from_index` (module docs), with a warning for each assumption.
pub(super) fn lps_from_index(
    path: &Path,
    image: &Image,
    layout: &Layout,
    warnings: &mut Vec<String>,
) -> Result<Transform<Lps, Index>> {
    let axes: [&Axis; 3] = layout.spatial.map(|a| &image.axes[a]);
    let mut mm = [1.0; 3];
    let mut unitless = Vec::new();
    for (m, axis) in mm.iter_mut().zip(&axes) {
        match axis.unit.as_deref() {
            None | Some("") => unitless.push(axis.name.as_str()),
            Some(u) => {
                *m = mm_per_unit(u).ok_or_else(|| {
                    Error::unsupported(path, format!("axis {:?} has the unit {u:?}, which is not a length", axis.name))
                })?;
            }
        }
    }
    if !unitless.is_empty() {
        unitless.sort_unstable();
        warnings.push(format!("the axes {unitless:?} give no unit: taken as mm"));
    }
    let oriented: Option<Vec<[f64; 3]>> =
        axes.iter().map(|a| a.orientation.as_deref().and_then(lps_direction)).collect();
    let directions: [[f64; 3]; 3] = if let Some(d) = oriented {
        [d[0], d[1], d[2]]
    } else {
        let given: Vec<String> =
            axes.iter().filter_map(|a| a.orientation.as_ref().map(|o| format!("{} {o}", a.name))).collect();
        let why = if given.is_empty() {
            "no axis gives an anatomical orientation".to_owned()
        } else {
            format!("the orientation ({}) does not name a patient axis for each of x, y, z", given.join(", "))
        };
        warnings.push(format!("{why}: x, y and z taken as left, posterior and superior (as ngff-zarr and ITK do)"));
        axes.map(|a| named_direction(&a.name))
    };
    let linear = Matrix3::from_fn(|r, c| directions[c][r] * image.scale[layout.spatial[c]] * mm[c]);
    let mut origin = [0.0; 3];
    for (c, axis) in axes.iter().enumerate() {
        let slot = match axis.name.as_str() {
            "x" => 0,
            "y" => 1,
            _ => 2,
        };
        origin[slot] = image.translation[layout.spatial[c]] * mm[c];
    }
    // RFC-4's text makes each axis's coordinate grow along its orientation, which would put voxel 0 at
    // Σ direction · translation; ngff-zarr (whose reading warpbench follows) puts it at the translations of x, y, z.
    let literal: [f64; 3] = std::array::from_fn(|r| {
        (0..3).map(|c| directions[c][r] * image.translation[layout.spatial[c]] * mm[c]).sum::<f64>()
    });
    if (0..3).any(|r| (literal[r] - origin[r]).abs() > 1e-9 * (1.0 + origin[r].abs())) {
        let [a, b, c] = literal;
        warnings.push(format!(
            "voxel 0 is placed at the translations of x, y and z as LPS mm, as ngff-zarr reads an oriented image; \
             RFC-4's text, with these orientations, would place it at ({a}, {b}, {c})"
        ));
    }
    let mut m = Matrix4::identity();
    m.fixed_view_mut::<3, 3>(0, 0).copy_from(&linear);
    for (r, o) in origin.iter().enumerate() {
        m[(r, 3)] = *o;
    }
    let t = Transform::from_matrix(m);
    if !t.is_valid_affine() {
        return Err(Error::invalid(path, "two space axes have the same orientation: the grid is singular"));
    }
    Ok(t)
}

/// The largest chunk decoded, in bytes, when the image itself is smaller.
const MAX_CHUNK_BYTES: u128 = 1 << 30;

/// The most inner chunks a shard may index (16 bytes each in its index).
const MAX_INNER_CHUNKS: u128 = 1 << 22;

/// Refuses chunks whose decoded size is past what the image could need, and shards whose index would be larger than
/// the cap, before `zarrs` allocates one.
pub(super) fn check_chunks(path: &Path, array: &ArrayMeta, max_voxel_bytes: u64) -> Result<()> {
    let cap = MAX_CHUNK_BYTES.min(u128::from(max_voxel_bytes)).max(1 << 20);
    for shape in &array.chunk_shapes {
        if shape.len() != array.shape.len() || shape.contains(&0) {
            return Err(Error::invalid(
                path,
                format!("the chunk shape {shape:?} does not fit the array's {:?}", array.shape),
            ));
        }
        let bytes = shape.iter().try_fold(array.stored.bytes() as u128, |a, &d| a.checked_mul(u128::from(d)));
        if let [outer, inner] = array.chunk_shapes.as_slice()
            && shape == outer
        {
            let count =
                outer.iter().zip(inner).try_fold(1u128, |n, (&o, &i)| n.checked_mul(u128::from(o.div_ceil(i.max(1)))));
            if count.is_none_or(|n| n > MAX_INNER_CHUNKS) {
                return Err(Error::invalid(
                    path,
                    format!(
                        "a shard of {outer:?} samples in chunks of {inner:?} holds more chunks than warpbench indexes"
                    ),
                ));
            }
        }
        if bytes.is_none_or(|b| b > cap) {
            return Err(Error::invalid(
                path,
                format!("a chunk of {shape:?} samples is larger than warpbench decodes at once ({cap} bytes)"),
            ));
        }
    }
    Ok(())
}

/// The samples of the image's chosen part, decoded by `zarrs` as the stored type `T`, in the volume's type.
pub(super) fn samples<T: Stored + zarrs::array::ElementOwned>(
    path: &Path,
    image: &Image,
    layout: &Layout,
    n: usize,
) -> Result<VoxelData> {
    let zarr =
        |e: &dyn std::fmt::Display| Error::invalid(path, format!("the image's array {:?}: {e}", image.array_path));
    let store = FilesystemStore::new(path).map_err(|e| zarr(&e))?;
    let array = Array::open(Arc::new(store), &format!("/{}", image.array_path)).map_err(|e| zarr(&e))?;
    let subset = ArraySubset::new_with_ranges(&layout.ranges);
    let raw: Vec<T> = array.retrieve_array_subset(&subset).map_err(|e| {
        Error::invalid(path, format!("a chunk of the image's array {:?} cannot be read: {e}", image.array_path))
    })?;
    if raw.len() != n {
        return Err(zarr(&format!("{} samples decoded, {n} expected", raw.len())));
    }
    Ok(match T::into_voxels(raw) {
        Ok(data) => data,
        Err(raw) => {
            let mut data = VoxelData::try_empty(path, StoredType::unscaled(T::TYPE), n, "the voxel samples")?;
            data.extend_from(raw.into_iter());
            data
        }
    })
}
