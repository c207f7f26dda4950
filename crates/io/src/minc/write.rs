//! Writing MINC 2 (`.mnc`), in the layout libminc 2.4 writes (and ITK's `MINCImageIO` through it): the samples in
//! the volume's own type (u8 as `ubyte`, i16 `short`, u16 `ushort`, f32 `float`), with an `image-min` and
//! `image-max` that map each stored value to itself, so no reader rescales them. The file is HDF5 1.8's format
//! (superblock 2), with the samples stored whole, uncompressed: the libminc inside ITK 5.4 refuses the 1.10 format
//! `hdf5-pure` writes by default, and `hdf5-pure` compresses only in that format. Each volume axis is named after the world axis it runs closest to (as `nii2mnc` names them; i, j, k as
//! `xspace`, `yspace`, `zspace` when that does not pick three different ones), with its direction as
//! `direction_cosines`, its voxel size as `step` and `start` such that Σ cosines · start is voxel 0's RAS position.

use std::path::Path;

use hdf5_pure::{AttrValue, DatasetBuilder, FileBuilder, LibVer};
use nalgebra::{Matrix3, Vector3};

use super::model::{SPATIAL, VECTOR};
use crate::error::{Error, Result};
use crate::geometry::{Index, Lps, Transform, ras_from_lps};
use crate::volume::{self, Volume, VoxelData};

/// Writes `volume` as MINC 2 at `path` (module docs). Atomic.
pub fn write(path: &Path, volume: &Volume) -> Result<()> {
    let bytes = to_bytes(path, volume)?;
    crate::write_atomic(path, |w| w.write_all(&bytes))
}

/// The bytes [`write()`] puts in a file; `name` is used in errors.
pub fn to_bytes(name: &Path, volume: &Volume) -> Result<Vec<u8>> {
    let n = volume::checked_voxel_count(name, volume.dims)?;
    if volume.data.len() != n {
        return Err(Error::invalid(name, format!("{} samples for dims {:?}", volume.data.len(), volume.dims)));
    }
    layout(name, volume.dims, &volume.lps_from_index, Samples::Scalar(&volume.data))
}

/// The bytes of a MINC 2 displacement grid: `displacements_lps` (one vector a voxel, i fastest, LPS mm) on the grid
/// `dims`, `lps_from_index`, written as float RAS vectors along a `vector_dimension` of 3, the fastest dimension, as
/// libminc and ITK write a `Grid_Transform`'s `Displacement_Volume`; `name` is used in errors.
///
/// # Errors
/// Vectors not one per voxel or not finite (the voxel named), a singular grid.
pub fn grid_to_bytes(
    name: &Path,
    dims: [usize; 3],
    lps_from_index: &Transform<Lps, Index>,
    displacements_lps: &[[f32; 3]],
) -> Result<Vec<u8>> {
    let n = volume::checked_voxel_count(name, dims)?;
    if displacements_lps.len() != n {
        return Err(Error::invalid(name, format!("{} vectors for dims {dims:?}", displacements_lps.len())));
    }
    if let Some(ijk) = crate::displacement::check::first_non_finite(dims, displacements_lps) {
        return Err(Error::invalid(name, format!("the displacement at voxel {ijk:?} (i, j, k) is not finite")));
    }
    let ras: Vec<f32> = displacements_lps.iter().flat_map(|&[x, y, z]| [-x, -y, z]).collect();
    layout(name, dims, lps_from_index, Samples::Vectors(&ras))
}

/// What a file holds at each voxel.
#[derive(Clone, Copy)]
enum Samples<'a> {
    Scalar(&'a VoxelData),
    /// Three floats a voxel, RAS.
    Vectors(&'a [f32]),
}

/// The MINC 2 file of `samples` on the grid `dims`, `lps_from_index` (module docs).
fn layout(name: &Path, dims: [usize; 3], lps_from_index: &Transform<Lps, Index>, samples: Samples) -> Result<Vec<u8>> {
    if !lps_from_index.is_valid_affine() {
        return Err(Error::invalid(name, "the voxel-to-patient matrix is singular or not finite"));
    }
    let ras_from_index = ras_from_lps() * *lps_from_index;
    let linear = ras_from_index.linear();
    let origin = ras_from_index.translation();
    let steps: [f64; 3] = std::array::from_fn(|c| linear.column(c).norm());
    let cosines = Matrix3::from_fn(|r, c| linear[(r, c)] / steps[c]);
    let Some(starts) = cosines.try_inverse().map(|inv| inv * Vector3::from(origin)) else {
        return Err(Error::invalid(name, "the voxel axes are not independent"));
    };
    let names = axis_names(&cosines);

    let mut builder = FileBuilder::new();
    // HDF5 1.8's format, as libminc 2.4 writes: libminc does not open the 1.10 format hdf5-pure writes by default.
    builder.with_libver_bounds(LibVer::Earliest, LibVer::V18);
    let mut minc = builder.create_group("minc-2.0");
    minc.set_attr("minc_version", AttrValue::AsciiString("2.0".into()));
    minc.set_attr("history", AttrValue::AsciiString(format!("warpbench {}\n", env!("CARGO_PKG_VERSION"))));
    let mut dimensions = minc.create_group("dimensions");
    for axis in 0..3 {
        let d = dimensions.create_dataset(names[axis]);
        d.with_f64_data(&[0.0]).with_shape(&[]);
        let column = cosines.column(axis);
        let comments = match names[axis] {
            "xspace" => "X increases from patient left to right",
            "yspace" => "Y increases from patient posterior to anterior",
            _ => "Z increases from patient inferior to superior",
        };
        for (key, value) in [
            ("alignment", AttrValue::AsciiString("centre".into())),
            ("class", AttrValue::AsciiString("spatial".into())),
            ("comments", AttrValue::AsciiString(comments.into())),
            ("direction_cosines", AttrValue::F64Array(vec![column[0], column[1], column[2]])),
            ("length", AttrValue::I32(i32::try_from(dims[axis]).unwrap_or(i32::MAX))),
            ("spacing", AttrValue::AsciiString("regular__".into())),
            ("start", AttrValue::F64(starts[axis])),
            ("step", AttrValue::F64(steps[axis])),
            ("units", AttrValue::AsciiString("mm".into())),
        ] {
            d.set_attr(key, value);
        }
        standard(d);
        d.set_attr("vartype", AttrValue::AsciiString("dimension____".into()));
    }
    if matches!(samples, Samples::Vectors(_)) {
        let d = dimensions.create_dataset(VECTOR);
        d.with_f64_data(&[0.0]).with_shape(&[]);
        d.set_attr("length", AttrValue::I32(3));
    }
    minc.add_group(dimensions.finish());
    let mut image_group = minc.create_group("image");
    let mut zero = image_group.create_group("0");
    let mut dimorder = format!("{},{},{}", names[2], names[1], names[0]);
    let mut shape = vec![dims[2] as u64, dims[1] as u64, dims[0] as u64];
    let (lo, hi) = match samples {
        Samples::Scalar(data) => value_range(data),
        Samples::Vectors(v) => float_range(v),
    };
    let image = zero.create_dataset("image");
    match samples {
        Samples::Scalar(VoxelData::U8(v)) => image.with_u8_data(v),
        Samples::Scalar(VoxelData::I16(v)) => image.with_i16_data(v),
        Samples::Scalar(VoxelData::U16(v)) => image.with_u16_data(v),
        Samples::Scalar(VoxelData::F32(v)) => image.with_f32_data(v),
        Samples::Vectors(v) => {
            dimorder.push_str(",vector_dimension");
            shape.push(3);
            image.with_f32_data(v)
        }
    };
    image.with_shape(&shape);
    image.set_attr("dimorder", AttrValue::AsciiString(dimorder));
    image.set_attr("valid_range", AttrValue::F64Array(vec![lo, hi]));
    image.set_attr("complete", AttrValue::AsciiString("true_".into()));
    standard(image);
    image.set_attr("vartype", AttrValue::AsciiString("group________".into()));
    for (key, value) in [("image-min", lo), ("image-max", hi)] {
        let d = zero.create_dataset(key);
        d.with_f64_data(&[value]).with_shape(&[]);
        standard(d);
        d.set_attr("vartype", AttrValue::AsciiString("var_attribute".into()));
    }
    image_group.add_group(zero.finish());
    minc.add_group(image_group.finish());
    let info = minc.create_group("info");
    minc.add_group(info.finish());
    builder.add_group(minc.finish());
    builder.finish().map_err(|e| Error::invalid(name, format!("the MINC 2 file cannot be laid out: {e}")))
}

/// The attributes libminc puts on each of its variables.
fn standard(d: &mut DatasetBuilder) {
    d.set_attr("varid", AttrValue::AsciiString("MINC standard variable".into()));
    d.set_attr("version", AttrValue::AsciiString("MINC Version    2.0".into()));
}

/// The MINC names of the volume's i, j and k axes (module docs).
fn axis_names(cosines: &Matrix3<f64>) -> [&'static str; 3] {
    let nearest: [usize; 3] = std::array::from_fn(|c| cosines.column(c).iamax());
    if nearest[0] != nearest[1] && nearest[1] != nearest[2] && nearest[0] != nearest[2] {
        nearest.map(|w| SPATIAL[w].0)
    } else {
        [SPATIAL[0].0, SPATIAL[1].0, SPATIAL[2].0]
    }
}

/// The valid range written: an integer type's whole range, so that image-min and image-max equal to it map every
/// stored value to itself; a float volume's own range (floats are not rescaled), as libminc writes it.
fn value_range(data: &VoxelData) -> (f64, f64) {
    match data {
        VoxelData::U8(_) => (0.0, f64::from(u8::MAX)),
        VoxelData::I16(_) => (f64::from(i16::MIN), f64::from(i16::MAX)),
        VoxelData::U16(_) => (0.0, f64::from(u16::MAX)),
        VoxelData::F32(v) => float_range(v),
    }
}

/// The range of the finite values of `v`, (0, 1) when there are none.
fn float_range(v: &[f32]) -> (f64, f64) {
    let finite = v.iter().filter(|x| x.is_finite()).map(|&x| f64::from(x));
    let (lo, hi) = finite.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), x| (lo.min(x), hi.max(x)));
    if lo <= hi { (lo, hi) } else { (0.0, 1.0) }
}
