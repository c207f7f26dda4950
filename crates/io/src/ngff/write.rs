//! The OME-Zarr writer: a volume as an OME-Zarr 0.5 image (Zarr v3), one resolution level, placed so that every
//! reader puts it where warpbench has it.
//!
//! OME-Zarr has no rotation in 0.5, so only a grid whose axes run along the patient axes (any order, either sense:
//! what an axial, coronal or sagittal acquisition gives) is written, and an oblique one is refused. The samples are
//! stored in LPS order: the array's axes are `z`, `y`, `x` (x fastest), `x` growing to the patient's left, `y` to
//! posterior and `z` to superior, each with its RFC-4 orientation (`right-to-left`, `anterior-to-posterior`,
//! `inferior-to-superior`), in millimetres, the scale the spacing and the translation voxel 0's LPS position. A
//! volume stored otherwise (a NIfTI in RAS order, say) has its samples reordered, which moves no voxel in space.
//! This order is the one in which ngff-zarr's reading (voxel 0 at the translations of x, y, z) and RFC-4's text
//! (each axis's coordinate grows along its orientation) agree, and in which a reader that ignores orientation and
//! takes x, y, z as ITK's axes (as ngff-zarr and ITK do) places the image too.
//!
//! The array is named `0`, chunked in 64³ blocks, zstd-compressed (level 3), little-endian, in the volume's own
//! sample type (u8, i16, u16 or f32). Like every output it appears whole or not at all: it is written into a
//! staging folder beside the destination and renamed onto it, replacing an existing Zarr store only (never another
//! folder), in one step where the system can exchange two names.

use std::path::Path;
use std::sync::Arc;

use nalgebra::Vector3;
use rayon::prelude::*;
use serde_json::json;
use zarrs::array::builder::ArrayBuilderFillValue;
use zarrs::array::{ArrayBuilder, ArraySubset, DataType, Element, data_type};
use zarrs::filesystem::FilesystemStore;

use crate::atomic::StagingDir;
use crate::error::{Error, Result};
use crate::geometry::{Index, Lps, Transform};
use crate::volume::{Volume, VoxelData};

/// The most a grid axis may lean off the patient axis it is written along: the sine of the angle, about 0.2
/// seconds of arc (0.26 µm across 256 mm). Scanners' axis-aligned grids are within it, and an oblique one is not.
pub const MAX_OBLIQUE_SINE: f64 = 1e-6;

/// The chunk edge, in voxels.
pub(super) const CHUNK: u64 = 64;

/// zstd's level: its default, which zarr-python and ngff-zarr use.
pub(super) const ZSTD_LEVEL: i32 = 3;

/// The RFC-4 orientation of x, y, z as warpbench writes them: +L, +P, +S.
const ORIENTATIONS: [&str; 3] = ["right-to-left", "anterior-to-posterior", "inferior-to-superior"];

/// How the volume's axes become the written ones: the written axis along L, P and S (x, y, z) is the volume's
/// axis `source[m]`, reversed where `reversed[m]`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) struct Reorder {
    source: [usize; 3],
    reversed: [bool; 3],
}

impl Reorder {
    /// The reorder of the grid `lps_from_index`, or an error saying how oblique it is.
    pub(super) fn of(path: &Path, lps_from_index: &Transform<Lps, Index>) -> Result<Self> {
        let m = lps_from_index.matrix();
        let mut source = [usize::MAX; 3];
        let mut reversed = [false; 3];
        for a in 0..3 {
            let column = Vector3::new(m[(0, a)], m[(1, a)], m[(2, a)]);
            let spacing = column.norm();
            let along = (0..3).max_by(|&p, &q| column[p].abs().total_cmp(&column[q].abs())).unwrap_or(0);
            let off = (0..3).filter(|&r| r != along).map(|r| column[r] * column[r]).sum::<f64>().sqrt();
            if !(spacing > 0.0 && off <= MAX_OBLIQUE_SINE * spacing) || source[along] != usize::MAX {
                let degrees = (off / spacing).clamp(0.0, 1.0).asin().to_degrees();
                return Err(Error::unsupported(
                    path,
                    format!(
                        "an oblique grid as OME-Zarr (axis {} is {degrees:.3}° off the nearest patient axis): \
                         OME-Zarr 0.5 stores only grids along the patient axes; write NIfTI, NRRD, MetaImage or \
                         MINC, or resample onto an axis-aligned grid (warp --reference)",
                        ["i", "j", "k"][a]
                    ),
                ));
            }
            source[along] = a;
            reversed[along] = column[along] < 0.0;
        }
        Ok(Self { source, reversed })
    }

    fn is_identity(self) -> bool {
        self.source == [0, 1, 2] && self.reversed == [false; 3]
    }

    /// The written grid's voxels along x, y, z.
    pub(super) fn dims(self, dims: [usize; 3]) -> [usize; 3] {
        self.source.map(|a| dims[a])
    }

    /// The spacing along x, y, z of a grid whose spacing along i, j, k is `spacing`.
    pub(super) fn source_spacing(self, spacing: [f64; 3]) -> [f64; 3] {
        self.source.map(|a| spacing[a])
    }

    /// The volume's index of the written voxel 0.
    pub(super) fn first_voxel(self, dims: [usize; 3]) -> [usize; 3] {
        let mut index = [0; 3];
        for m in 0..3 {
            if self.reversed[m] {
                index[self.source[m]] = dims[self.source[m]] - 1;
            }
        }
        index
    }

    /// `samples` (the volume's, i fastest) in the written order, x fastest.
    pub(super) fn apply<T: Copy + Send + Sync + Default>(self, dims: [usize; 3], samples: &[T]) -> Vec<T> {
        let strides = [1, dims[0], dims[0] * dims[1]];
        let first = self.first_voxel(dims);
        let start: isize = (0..3).map(|a| (first[a] * strides[a]) as isize).sum();
        let step: [isize; 3] = std::array::from_fn(|m| {
            let s = strides[self.source[m]] as isize;
            if self.reversed[m] { -s } else { s }
        });
        let [nx, ny, _] = self.dims(dims);
        let mut out = vec![T::default(); samples.len()];
        out.par_chunks_mut(nx * ny).enumerate().for_each(|(z, slab)| {
            for (y, row) in slab.chunks_mut(nx).enumerate() {
                let mut at = start + z as isize * step[2] + y as isize * step[1];
                for v in row {
                    *v = samples[at as usize];
                    at += step[0];
                }
            }
        });
        out
    }
}

/// Refuses a grid that [`write()`] cannot write to `path` (an oblique one), before any work is spent on the volume.
pub fn check_grid(path: &Path, lps_from_index: &Transform<Lps, Index>) -> Result<()> {
    Reorder::of(path, lps_from_index).map(|_| ())
}

/// Writes `volume` as an OME-Zarr 0.5 image in the folder `path` (module docs). An existing `path` must be an empty
/// folder or a Zarr store, which is replaced.
///
/// # Errors
/// An oblique grid, a `path` that is a file or a folder holding something other than a Zarr store, and any
/// failure to write; each names `path`.
pub fn write(path: &Path, volume: &Volume) -> Result<()> {
    let n = crate::volume::checked_voxel_count(path, volume.dims)?;
    if volume.data.len() != n {
        return Err(Error::invalid(path, format!("{} samples for dims {:?}", volume.data.len(), volume.dims)));
    }
    if !volume.lps_from_index.is_valid_affine() {
        return Err(Error::invalid(path, "the voxel-to-patient matrix is singular or not finite"));
    }
    let reorder = Reorder::of(path, &volume.lps_from_index)?;
    let replacing = check_destination(path)?;
    let staging = StagingDir::new_beside(path)?;
    match &volume.data {
        VoxelData::U8(s) => store_array(path, staging.path(), volume.dims, reorder, s, data_type::uint8())?,
        VoxelData::I16(s) => store_array(path, staging.path(), volume.dims, reorder, s, data_type::int16())?,
        VoxelData::U16(s) => store_array(path, staging.path(), volume.dims, reorder, s, data_type::uint16())?,
        VoxelData::F32(s) => store_array(path, staging.path(), volume.dims, reorder, s, data_type::float32())?,
    }
    publish(path, staging, &group_attributes(path, volume, reorder), replacing)
}

/// Writes the root group's `zarr.json` (`root`) into `staging`, flushes everything under it, and renames it onto
/// `path` (replacing the store there when `replacing`).
pub(super) fn publish(path: &Path, staging: StagingDir, root: &serde_json::Value, replacing: bool) -> Result<()> {
    crate::write_atomic(&staging.path().join("zarr.json"), |w| {
        serde_json::to_writer_pretty(&mut *w, root).map_err(std::io::Error::other)?;
        w.write_all(b"\n")
    })?;
    sync_tree(staging.path()).map_err(|e| Error::io(path, e))?;
    if replacing { staging.persist_replacing(path) } else { staging.persist(path) }
}

/// Whether `path` exists as a Zarr store to replace; `Ok(false)` for a new path or an empty folder.
pub(super) fn check_destination(path: &Path) -> Result<bool> {
    let Ok(meta) = std::fs::symlink_metadata(path) else { return Ok(false) };
    if !meta.is_dir() {
        return Err(Error::invalid(path, "exists and is not a folder: an OME-Zarr image is a folder"));
    }
    if super::meta::looks_like_zarr(path) {
        return Ok(true);
    }
    if std::fs::read_dir(path).map_err(|e| Error::io(path, e))?.next().is_some() {
        return Err(Error::invalid(
            path,
            "the folder exists and holds something other than a Zarr store, which warpbench does not replace",
        ));
    }
    Ok(false)
}

/// Stores the array `0` of `samples` (the volume's order) in the store at `staging`, reordered.
fn store_array<T: Element + Copy + Send + Sync + Default + Into<ArrayBuilderFillValue>>(
    path: &Path,
    staging: &Path,
    dims: [usize; 3],
    reorder: Reorder,
    samples: &[T],
    data_type: DataType,
) -> Result<()> {
    let zarr = |e: &dyn std::fmt::Display| Error::invalid(path, format!("writing the image's array: {e}"));
    let [nx, ny, nz] = reorder.dims(dims);
    let shape = vec![nz as u64, ny as u64, nx as u64];
    let chunks: Vec<u64> = shape.iter().map(|&d| d.clamp(1, CHUNK)).collect();
    let store = FilesystemStore::new(staging).map_err(|e| zarr(&e))?;
    let array = ArrayBuilder::new(shape.clone(), chunks, data_type, T::default())
        .bytes_to_bytes_codecs(vec![Arc::new(zarrs::array::codec::ZstdCodec::new(ZSTD_LEVEL, false))])
        .dimension_names(Some(["z", "y", "x"]))
        .build(Arc::new(store), "/0")
        .map_err(|e| zarr(&e))?;
    array.store_metadata().map_err(|e| zarr(&e))?;
    let subset = ArraySubset::new_with_shape(shape);
    if reorder.is_identity() {
        array.store_array_subset(&subset, samples)
    } else {
        array.store_array_subset(&subset, reorder.apply(dims, samples))
    }
    .map_err(|e| zarr(&e))
}

/// The root group's `zarr.json`: the OME-Zarr 0.5 multiscale of the one level.
fn group_attributes(path: &Path, volume: &Volume, reorder: Reorder) -> serde_json::Value {
    let [x, y, z] = reorder.source_spacing(volume.spacing_mm());
    let first = reorder.first_voxel(volume.dims);
    let [l, p, s] = volume.voxel_lps(first[0], first[1], first[2]).coords();
    let axes: Vec<serde_json::Value> = [2, 1, 0].into_iter().map(space_axis).collect();
    let name = image_name(path);
    json!({
        "zarr_format": 3,
        "node_type": "group",
        "attributes": {
            "ome": {
                "version": "0.5",
                "multiscales": [{
                    "name": name,
                    "axes": axes,
                    "datasets": [{
                        "path": "0",
                        "coordinateTransformations": [
                            { "type": "scale", "scale": [z, y, x] },
                            { "type": "translation", "translation": [s, p, l] },
                        ],
                    }],
                }],
            },
        },
    })
}

/// The space axis along patient axis `m` (0 L, 1 P, 2 S) as written: `x`, `y` or `z`, in millimetres, with its
/// RFC-4 orientation.
pub(super) fn space_axis(m: usize) -> serde_json::Value {
    let name = ["x", "y", "z"][m];
    json!({
        "name": name,
        "type": "space",
        "unit": "millimeter",
        "orientation": { "type": "anatomical", "value": ORIENTATIONS[m] },
    })
}

/// The multiscale's `name`: the folder's name without `.zarr` and `.ome`.
pub(super) fn image_name(path: &Path) -> String {
    let name = path.file_name().map_or_else(String::new, |n| n.to_string_lossy().into_owned());
    let stem = name.strip_suffix(".zarr").map(|n| n.strip_suffix(".ome").unwrap_or(n));
    stem.unwrap_or(&name).to_owned()
}

/// Flushes every file and folder under `dir` to disk, so that the rename that publishes them comes after their
/// data.
fn sync_tree(dir: &Path) -> std::io::Result<()> {
    for entry in std::fs::read_dir(dir)? {
        let entry = entry?;
        let kind = entry.file_type()?;
        if kind.is_dir() {
            sync_tree(&entry.path())?;
        } else if kind.is_file() {
            std::fs::File::open(entry.path())?.sync_all()?;
        }
    }
    #[cfg(unix)]
    std::fs::File::open(dir)?.sync_all()?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_reversed_permuted_grid_is_gathered_in_lps_order() {
        // Volume axes: i along -P, j along +S, k along -L (2×3×4 voxels), so x (L) = reversed k, y (P) = reversed
        // i, z (S) = j.
        let reorder = Reorder { source: [2, 0, 1], reversed: [true, true, false] };
        let dims = [2, 3, 4];
        let samples: Vec<u32> = (0..24).collect();
        let out = reorder.apply(dims, &samples);
        let [nx, ny, _] = reorder.dims(dims);
        assert_eq!(reorder.dims(dims), [4, 2, 3]);
        for z in 0..3 {
            for y in 0..2 {
                for x in 0..4 {
                    let (i, j, k) = (1 - y, z, 3 - x);
                    assert_eq!(out[x + nx * (y + ny * z)], samples[i + 2 * (j + 3 * k)], "x {x} y {y} z {z}");
                }
            }
        }
        assert_eq!(reorder.first_voxel(dims), [1, 0, 3]);
    }
}
