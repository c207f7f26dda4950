//! OME-Zarr 0.6 displacement fields: RFC-5's `displacements` transformation, as ngff-zarr 0.50 writes and reads it
//! (`itk_displacement_field_to_ngff_transform`, `declare_field_transform`, `ngff_displacement_field_to_itk_transform`).
//!
//! A standalone field store is a multiscale whose level-0 array holds the field: a `displacement` axis of three
//! components first, then the space axes, and whose own `coordinateTransformations` declare a `displacements`
//! transformation from a spatial coordinate system onto itself (or onto another of the same axes) by that array.
//! The i-th component is the displacement along the i-th axis of the output system, in that axis's unit; the grid
//! is placed as an image's is ([`super`]: scale, translation, RFC-4 orientation, units in mm). A point x maps to
//! x + D(x): ITK's `DisplacementFieldTransform`, the pull-back u = moving_from_fixed when it resamples the moving
//! image onto the fixed grid.
//!
//! [`read_field`] also takes an image whose multiscale declares the transformation with `path` naming a field group
//! of its own (the layout that writes a field beside the image it displaces). It refuses `coordinates` (absolute
//! positions), a field on a lower resolution level, anything whose axes are not one component axis of three and
//! three space axes `x`, `y`, `z`, and a field oriented otherwise than `x`, `y`, `z` along L, P, S: such a field's
//! vectors are in the intrinsic axes of the two images it relates, which the store alone does not give (ngff-zarr
//! refuses it too). Axes without a unit are taken as mm and axes without orientation as L, P, S, as ngff-zarr and
//! ITK take them, with a warning each.
//!
//! [`write_field`] writes the standalone layout, version 0.6: array `0` of float32 (c, z, y, x), components (S, P,
//! L) along axes `z`, `y`, `x` in millimetres with RFC-4 orientations `inferior-to-superior`,
//! `anterior-to-posterior`, `right-to-left`: the samples in LPS order, as a volume is written ([`super::write()`]),
//! so that the grid needs no orientation to be placed and ngff-zarr reads it without the two images. An oblique grid
//! is refused.

use std::path::Path;
use std::sync::Arc;

use serde_json::json;
use zarrs::array::{ArrayBuilder, ArraySubset, data_type};
use zarrs::filesystem::FilesystemStore;

use super::image::{Layout, check_chunks, lps_from_index, samples};
use super::meta::{self, AxisKind};
use super::write::{CHUNK, Reorder, ZSTD_LEVEL, check_destination, image_name, publish, space_axis};
use crate::atomic::StagingDir;
use crate::displacement::check::{check_field_to_write, first_non_finite};
use crate::error::{Error, Result};
use crate::geometry::{Index, Lps, Transform};
use crate::nifti::DisplacementField;
use crate::sample::with_stored_type;
use crate::volume::{DEFAULT_MAX_VOXEL_BYTES, GeometrySource, check_allocation};

/// Reads the displacement field of the OME-Zarr store `path` (module docs), with a warning for each assumption (an
/// axis without a unit taken as mm, axes without orientation taken as L, P, S).
///
/// # Errors
/// A store without a `displacements` transformation, axes other than one component axis of three and `x`, `y`, `z`,
/// an unknown unit, a corrupt chunk, a vector that is not finite, a field over the memory cap; each names `path`.
pub fn read_field(path: &Path) -> Result<(DisplacementField, Vec<String>)> {
    read_field_capped(path, DEFAULT_MAX_VOXEL_BYTES)
}

/// [`read_field`], refusing a field of more than `max_voxel_bytes` of samples (before anything is decoded).
///
/// # Errors
/// As [`read_field`].
pub fn read_field_capped(path: &Path, max_voxel_bytes: u64) -> Result<(DisplacementField, Vec<String>)> {
    crate::files::check_file_or_folder(path)?;
    let Some(entry) = meta::field_entry(path)? else {
        return Err(Error::unsupported(
            path,
            "an OME-Zarr store that declares no displacements transformation (RFC-5, OME-Zarr 0.6): not a \
             displacement field",
        ));
    };
    if entry.kind != "displacements" {
        return Err(Error::unsupported(
            path,
            format!("a {} field (absolute positions); warpbench reads displacements fields", entry.kind),
        ));
    }
    let image = meta::read_image(path, &entry.group)?;
    let array = meta::read_array_meta(path, &image.array_path)?;
    let (layout, component) = field_layout(path, &image, &array)?;
    check_orientation(path, &image, &layout)?;
    let mut warnings = Vec::new();
    let grid = lps_from_index(path, &image, &layout, &mut warnings)?;
    let n = check_allocation(path, layout.dims, 3 * array.stored.bytes(), max_voxel_bytes)?;
    check_chunks(path, &array, max_voxel_bytes)?;
    let values = with_stored_type!(array.stored, T => samples::<T>(path, &image, &layout, 3 * n)?).to_f32();

    // The LPS mm of one unit along each component: component q is along the output axis of its name, which is the
    // grid's column of the space axis so named, divided by that axis's scale.
    let names: Vec<&str> = if entry.component_axes.len() == 3 {
        entry.component_axes.iter().map(String::as_str).collect()
    } else {
        // No output system declared: the components follow the space axes in the array's order.
        image.axes.iter().filter(|a| a.kind == AxisKind::Space).map(|a| a.name.as_str()).collect()
    };
    let linear = grid.linear();
    let mut unit = [[0.0f64; 3]; 3];
    for (q, name) in names.iter().enumerate() {
        let Some(c) = (0..3).find(|&c| image.axes[layout.spatial[c]].name == *name) else {
            return Err(Error::invalid(path, format!("component {q} is along axis {name:?}, which the grid lacks")));
        };
        let scale = image.scale[layout.spatial[c]];
        unit[q] = std::array::from_fn(|r| linear[(r, c)] / scale);
    }

    let shape: Vec<usize> = layout.ranges.iter().map(|r| (r.end - r.start) as usize).collect();
    let mut strides = vec![1usize; shape.len()];
    for a in (0..shape.len().saturating_sub(1)).rev() {
        strides[a] = strides[a + 1] * shape[a + 1];
    }
    let [ni, nj, nk] = layout.dims;
    let [si, sj, sk] = layout.spatial.map(|a| strides[a]);
    let sc = strides[component];
    let mut displacements_lps = Vec::with_capacity(n);
    for k in 0..nk {
        for j in 0..nj {
            for i in 0..ni {
                let base = i * si + j * sj + k * sk;
                let mut d = [0.0f64; 3];
                for (q, u) in unit.iter().enumerate() {
                    let v = f64::from(values[base + q * sc]);
                    for r in 0..3 {
                        d[r] += v * u[r];
                    }
                }
                displacements_lps.push(d.map(|v| v as f32));
            }
        }
    }
    if let Some(ijk) = first_non_finite(layout.dims, &displacements_lps) {
        return Err(Error::invalid(path, format!("the displacement at voxel {ijk:?} (i, j, k) is not finite")));
    }
    let field = DisplacementField {
        dims: layout.dims,
        lps_from_index: grid,
        geometry_source: GeometrySource::OmeZarr,
        displacements_lps,
    };
    Ok((field, warnings))
}

/// Refuses a field oriented otherwise than x, y, z along L, P, S: its vectors and grid are then relative to the two
/// images it was made between, which a field store alone does not give (ngff-zarr refuses it too, without them).
fn check_orientation(path: &Path, image: &meta::Image, layout: &Layout) -> Result<()> {
    const LPS: [(&str, &str); 3] =
        [("x", "right-to-left"), ("y", "anterior-to-posterior"), ("z", "inferior-to-superior")];
    let axes = layout.spatial.map(|a| &image.axes[a]);
    if axes.iter().all(|a| a.orientation.is_none()) {
        return Ok(());
    }
    let lps = axes.iter().all(|a| LPS.iter().any(|(n, o)| a.name == *n && a.orientation.as_deref() == Some(*o)));
    if lps {
        return Ok(());
    }
    let given: Vec<String> =
        axes.iter().map(|a| format!("{} {}", a.name, a.orientation.as_deref().unwrap_or("(none)"))).collect();
    Err(Error::unsupported(
        path,
        format!(
            "a field oriented {}: its vectors are in the axes of the two images it was made between, which the field              alone does not give (ngff-zarr cannot place it either); write it on a grid along x, y, z = L, P, S",
            given.join(", ")
        ),
    ))
}

/// The field's layout (its space axes, fastest first, and everything read) and its component axis.
fn field_layout(path: &Path, image: &meta::Image, array: &meta::ArrayMeta) -> Result<(Layout, usize)> {
    let names: Vec<&str> = image.axes.iter().map(|a| a.name.as_str()).collect();
    if array.shape.len() != image.axes.len() {
        return Err(Error::invalid(
            path,
            format!("the field has {} axes {names:?} but its array {} dimensions", names.len(), array.shape.len()),
        ));
    }
    let mut component = None;
    let mut spatial = Vec::new();
    let mut ranges = Vec::new();
    for (a, (axis, &len)) in image.axes.iter().zip(&array.shape).enumerate() {
        ranges.push(0..len);
        match &axis.kind {
            AxisKind::Space => spatial.push(a),
            AxisKind::Other(t) if t == "displacement" && component.is_none() => component = Some(a),
            kind if len > 1 => {
                return Err(Error::unsupported(
                    path,
                    format!("the field has {len} {} (axis {:?}); a 3-D field has none", kind.samples(), axis.name),
                ));
            }
            _ => ranges[a] = 0..len.min(1),
        }
    }
    let Some(component) = component else {
        return Err(Error::invalid(
            path,
            format!("no axis of type \"displacement\" holds the vectors (axes {names:?})"),
        ));
    };
    if array.shape[component] != 3 {
        return Err(Error::unsupported(
            path,
            format!("the field holds {} components per point; a 3-D field holds 3", array.shape[component]),
        ));
    }
    let mut seen: Vec<&str> = spatial.iter().map(|&a| image.axes[a].name.as_str()).collect();
    seen.sort_unstable();
    let Ok(spatial) = <[usize; 3]>::try_from(spatial.iter().rev().copied().collect::<Vec<_>>()) else {
        return Err(Error::unsupported(
            path,
            format!("the field's axes are {names:?}; a 3-D field has three space axes"),
        ));
    };
    if seen != ["x", "y", "z"] {
        return Err(Error::unsupported(
            path,
            format!("the space axis names are {seen:?}; warpbench places x, y and z (as ngff-zarr and ITK do)"),
        ));
    }
    let dims = spatial.map(|a| array.shape[a] as usize);
    Ok((Layout { spatial, dims, ranges }, component))
}

/// Writes a displacement field (`displacements_lps`, LPS mm, i fastest, on the grid `dims`, `lps_from_index`) as a
/// standalone OME-Zarr 0.6 field store in the folder `path` (module docs), atomically; an existing Zarr store is
/// replaced, as [`super::write()`] replaces one.
///
/// # Errors
/// An oblique grid, a vector that is not finite, a destination that is a file or a folder of something else, and any
/// failure to write; each names `path`.
pub fn write_field(
    path: &Path,
    dims: [usize; 3],
    lps_from_index: &Transform<Lps, Index>,
    displacements_lps: &[[f32; 3]],
) -> Result<()> {
    check_field_to_write(path, dims, lps_from_index, displacements_lps)?;
    let reorder = Reorder::of(path, lps_from_index)?;
    let replacing = check_destination(path)?;
    let staging = StagingDir::new_beside(path)?;
    let [nx, ny, nz] = reorder.dims(dims);
    // (c, z, y, x): the S, P and L components, each in the written order.
    let mut values = Vec::with_capacity(3 * displacements_lps.len());
    for m in [2, 1, 0] {
        let plane: Vec<f32> = displacements_lps.iter().map(|d| d[m]).collect();
        values.extend(reorder.apply(dims, &plane));
    }
    let zarr = |e: &dyn std::fmt::Display| Error::invalid(path, format!("writing the field's array: {e}"));
    let shape = vec![3, nz as u64, ny as u64, nx as u64];
    let chunks: Vec<u64> = shape.iter().map(|&d| d.clamp(1, CHUNK)).collect();
    let store = FilesystemStore::new(staging.path()).map_err(|e| zarr(&e))?;
    let array = ArrayBuilder::new(shape.clone(), chunks, data_type::float32(), 0.0f32)
        .bytes_to_bytes_codecs(vec![Arc::new(zarrs::array::codec::ZstdCodec::new(ZSTD_LEVEL, false))])
        .dimension_names(Some(["c", "z", "y", "x"]))
        .build(Arc::new(store), "/0")
        .map_err(|e| zarr(&e))?;
    array.store_metadata().map_err(|e| zarr(&e))?;
    array.store_array_subset(&ArraySubset::new_with_shape(shape), values).map_err(|e| zarr(&e))?;

    let spacing = crate::geometry::spacing_mm(lps_from_index);
    let [sx, sy, sz] = reorder.source_spacing(spacing);
    let first = reorder.first_voxel(dims);
    let origin =
        lps_from_index.apply_point(crate::geometry::Point3::new(first[0] as f64, first[1] as f64, first[2] as f64));
    let [l, p, s] = origin.coords();
    let name = image_name(path);
    let root = json!({
        "zarr_format": 3,
        "node_type": "group",
        "attributes": { "ome": { "version": "0.6", "multiscales": [{
            "name": name,
            "coordinateSystems": [
                { "name": "intrinsic", "axes": [
                    { "name": "c", "type": "displacement", "discrete": true }, space_axis(2), space_axis(1), space_axis(0),
                ] },
                { "name": "physical", "axes": [space_axis(2), space_axis(1), space_axis(0)] },
            ],
            "datasets": [{
                "path": "0",
                "coordinateTransformations": [{
                    "type": "sequence",
                    "name": "0_to_intrinsic",
                    "input": { "path": "0" },
                    "output": { "name": "intrinsic" },
                    "transformations": [
                        { "type": "scale", "scale": [1.0, sz, sy, sx] },
                        { "type": "translation", "translation": [0.0, s, p, l] },
                    ],
                }],
            }],
            "coordinateTransformations": [{
                "type": "displacements",
                "path": "0",
                "input": { "name": "physical" },
                "output": { "name": "physical" },
                "interpolation": "linear",
            }],
        }] } },
    });
    publish(path, staging, &root, replacing)
}
