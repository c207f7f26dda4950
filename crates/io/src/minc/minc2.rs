//! MINC 2: an HDF5 file (libminc 2's layout, read through `hdf5-pure`). The image is the dataset
//! `/minc-2.0/image/0/image` (resolution 0), its dimensions named, slowest first, by its `dimorder` attribute, its
//! sample type the dataset's; `valid_range` is its attribute. Each dimension's `start`, `step`, `direction_cosines`
//! and `spacing` are attributes of the dataset `/minc-2.0/dimensions/NAME`. `image-min` and `image-max` are datasets
//! beside the image: scalars, or arrays over the dimensions their own `dimorder` names (only as many as their rank,
//! as nibabel reads them).

use std::collections::HashMap;
use std::path::Path;

use hdf5_pure::{AttrValue, DType, Dataset, File};

use super::model::{Decoded, Dimension, Header, SliceRange, Want, finish};
use crate::error::{Error, Result};
use crate::options::LoadOptions;
use crate::sample::{StoredType, with_stored_type};
use crate::stream::MAX_DEFLATE_RATIO;

const IMAGE: &str = "/minc-2.0/image/0/image";
const IMAGE_MIN: &str = "/minc-2.0/image/0/image-min";
const IMAGE_MAX: &str = "/minc-2.0/image/0/image-max";
const DIMENSIONS: &str = "/minc-2.0/dimensions";

/// The most values `image-min` or `image-max` may hold: one per slice of a volume of many frames.
const MAX_RANGE_VALUES: u64 = 1 << 24;

pub(super) fn read(name: &Path, bytes: Vec<u8>, opts: &LoadOptions, want: Want) -> Result<Decoded> {
    let file_bytes = bytes.len() as u64;
    let file = File::from_bytes(bytes).map_err(|e| Error::invalid(name, format!("not a readable HDF5 file: {e}")))?;
    let image = file.dataset(IMAGE).map_err(|e| match e {
        hdf5_pure::Error::Format(hdf5_pure::FormatError::PathNotFound(_)) | hdf5_pure::Error::NotAGroup(_) => {
            Error::invalid(name, format!("an HDF5 file without {IMAGE}, so not a MINC 2 volume"))
        }
        e => Error::invalid(name, format!("{IMAGE} cannot be found: the HDF5 file is truncated or corrupt ({e})")),
    })?;
    let header = header(name, &file, &image, file_bytes)?;
    let compressed = !image.filters().is_empty();
    let n = header.checked_len(name, opts.max_voxel_bytes, (!compressed).then_some(file_bytes))?;
    if compressed && n as u128 * header.stored.bytes() as u128 > u128::from(file_bytes) * u128::from(MAX_DEFLATE_RATIO)
    {
        return Err(Error::truncated(
            name,
            format!("its {n} compressed samples cannot come from a file of {file_bytes} bytes"),
        ));
    }
    crate::hdf5_guard::check_chunks(name, &image, IMAGE, file_bytes)?;
    with_stored_type!(header.stored, T => {
        let raw: Vec<T> = image.read::<T>().map_err(|e| Error::invalid(name, format!("{IMAGE} cannot be read: {e}")))?;
        finish(name, &header, &raw, opts, want)
    })
}

fn header(name: &Path, file: &File, image: &Dataset, file_bytes: u64) -> Result<Header> {
    let shape = shape(name, image, IMAGE)?;
    let image_attrs = attrs(name, image, IMAGE)?;
    let order = dimorder(name, &image_attrs, IMAGE, shape.len())?;
    let stored = match image.dtype().map_err(|e| Error::invalid(name, format!("{IMAGE}'s type: {e}")))? {
        DType::U8 => StoredType::U8,
        DType::I8 => StoredType::I8,
        DType::U16 => StoredType::U16,
        DType::I16 => StoredType::I16,
        DType::U32 => StoredType::U32,
        DType::I32 => StoredType::I32,
        DType::U64 => StoredType::U64,
        DType::I64 => StoredType::I64,
        DType::F32 => StoredType::F32,
        DType::F64 => StoredType::F64,
        other => {
            return Err(Error::unsupported(
                name,
                format!("{IMAGE} holds {other} samples; warpbench reads integers and floats"),
            ));
        }
    };
    let mut dims = Vec::with_capacity(order.len());
    for (dim_name, &len) in order.iter().zip(&shape) {
        let at = format!("{DIMENSIONS}/{dim_name}");
        let a = match file.dataset(&at) {
            Ok(d) => attrs(name, &d, &at)?,
            Err(_) => HashMap::new(),
        };
        dims.push(Dimension {
            name: dim_name.clone(),
            len,
            start: scalar(name, &a, "start", &at)?,
            step: scalar(name, &a, "step", &at)?,
            cosines: numbers(&a, "direction_cosines"),
            spacing: text(&a, "spacing"),
        });
    }
    let valid_range = match numbers(&image_attrs, "valid_range") {
        None => None,
        Some(v) if v.len() == 2 => Some([v[0], v[1]]),
        Some(v) => return Err(Error::invalid(name, format!("{IMAGE}'s valid_range has {} values, not 2", v.len()))),
    };
    let range = match (file.dataset(IMAGE_MIN), file.dataset(IMAGE_MAX)) {
        (Ok(lo), Ok(hi)) => {
            let (lo_dims, min) = slice_values(name, &lo, IMAGE_MIN, file_bytes)?;
            let (hi_dims, max) = slice_values(name, &hi, IMAGE_MAX, file_bytes)?;
            if lo_dims != hi_dims {
                return Err(Error::invalid(
                    name,
                    format!("image-min varies over {lo_dims:?} but image-max over {hi_dims:?}"),
                ));
            }
            Some(SliceRange { dims: lo_dims, min, max })
        }
        (Err(_), Err(_)) => None,
        _ => return Err(Error::invalid(name, "it has one of image-min and image-max without the other")),
    };
    Ok(Header { dims, stored, valid_range, range })
}

/// The values of `image-min` or `image-max` and the dimensions they vary over.
fn slice_values(name: &Path, d: &Dataset, at: &str, file_bytes: u64) -> Result<(Vec<String>, Vec<f64>)> {
    let shape = shape(name, d, at)?;
    let count = shape.iter().try_fold(1u64, |a, &n| a.checked_mul(n as u64)).unwrap_or(u64::MAX);
    if count > MAX_RANGE_VALUES {
        return Err(Error::invalid(name, format!("{at} holds {count} values")));
    }
    crate::hdf5_guard::check_chunks(name, d, at, file_bytes)?;
    let attrs = attrs(name, d, at)?;
    let dims = if shape.is_empty() { Vec::new() } else { dimorder(name, &attrs, at, shape.len())? };
    let values = d.read_f64().map_err(|e| Error::invalid(name, format!("{at} cannot be read as numbers: {e}")))?;
    if values.len() as u64 != count {
        return Err(Error::invalid(name, format!("{at} holds {} values for its shape {shape:?}", values.len())));
    }
    Ok((dims, values))
}

fn shape(name: &Path, d: &Dataset, at: &str) -> Result<Vec<usize>> {
    let shape = d.shape().map_err(|e| Error::invalid(name, format!("{at}'s shape: {e}")))?;
    shape
        .into_iter()
        .map(|n| usize::try_from(n).map_err(|_| Error::invalid(name, format!("{at} has a dimension of {n} samples"))))
        .collect()
}

fn attrs(name: &Path, d: &Dataset, at: &str) -> Result<HashMap<String, AttrValue>> {
    d.attrs().map_err(|e| Error::invalid(name, format!("{at}'s attributes cannot be read: {e}")))
}

/// The first `rank` names of a `dimorder` attribute (`zspace,yspace,xspace`).
fn dimorder(name: &Path, attrs: &HashMap<String, AttrValue>, at: &str, rank: usize) -> Result<Vec<String>> {
    let Some(order) = text(attrs, "dimorder") else {
        return Err(Error::invalid(name, format!("{at} has no dimorder attribute naming its {rank} dimensions")));
    };
    let names: Vec<String> = order.split(',').map(|s| s.trim().to_string()).take(rank).collect();
    if names.len() < rank || names.iter().any(String::is_empty) {
        return Err(Error::invalid(name, format!("{at}'s dimorder {order:?} does not name its {rank} dimensions")));
    }
    Ok(names)
}

/// A string attribute, without the NULs a fixed-length string is padded with.
fn text(attrs: &HashMap<String, AttrValue>, key: &str) -> Option<String> {
    let s = match attrs.get(key)? {
        AttrValue::String(s) | AttrValue::AsciiString(s) => s.clone(),
        AttrValue::StringSized { value, .. } | AttrValue::AsciiStringSized { value, .. } => value.clone(),
        AttrValue::StringArray(v)
        | AttrValue::AsciiStringArray(v)
        | AttrValue::VarLenAsciiCharArray(v)
        | AttrValue::StringArraySized { values: v, .. }
        | AttrValue::AsciiStringArraySized { values: v, .. } => v.first()?.clone(),
        AttrValue::U8Array(b) => String::from_utf8_lossy(b).into_owned(),
        _ => return None,
    };
    Some(s.trim_end_matches('\0').to_string())
}

/// A numeric attribute, as doubles.
fn numbers(attrs: &HashMap<String, AttrValue>, key: &str) -> Option<Vec<f64>> {
    Some(match attrs.get(key)? {
        AttrValue::F64(x) => vec![*x],
        AttrValue::F32(x) => vec![f64::from(*x)],
        AttrValue::I8(x) => vec![f64::from(*x)],
        AttrValue::I16(x) => vec![f64::from(*x)],
        AttrValue::I32(x) => vec![f64::from(*x)],
        AttrValue::I64(x) => vec![*x as f64],
        AttrValue::U8(x) => vec![f64::from(*x)],
        AttrValue::U16(x) => vec![f64::from(*x)],
        AttrValue::U32(x) => vec![f64::from(*x)],
        AttrValue::U64(x) => vec![*x as f64],
        AttrValue::F64Array(v) => v.clone(),
        AttrValue::F32Array(v) => v.iter().map(|&x| f64::from(x)).collect(),
        AttrValue::I8Array(v) => v.iter().map(|&x| f64::from(x)).collect(),
        AttrValue::I16Array(v) => v.iter().map(|&x| f64::from(x)).collect(),
        AttrValue::I32Array(v) => v.iter().map(|&x| f64::from(x)).collect(),
        AttrValue::I64Array(v) => v.iter().map(|&x| x as f64).collect(),
        AttrValue::U16Array(v) => v.iter().map(|&x| f64::from(x)).collect(),
        AttrValue::U32Array(v) => v.iter().map(|&x| f64::from(x)).collect(),
        AttrValue::U64Array(v) => v.iter().map(|&x| x as f64).collect(),
        _ => return None,
    })
}

/// A one-number attribute of a dimension, if present.
fn scalar(name: &Path, attrs: &HashMap<String, AttrValue>, key: &str, at: &str) -> Result<Option<f64>> {
    match numbers(attrs, key) {
        None => Ok(None),
        Some(v) if v.len() == 1 => Ok(Some(v[0])),
        Some(v) => Err(Error::invalid(name, format!("{at}'s {key} has {} values, not 1", v.len()))),
    }
}
