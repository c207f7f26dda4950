//! MINC 1: a netCDF classic file (`CDF` 1, or 2 with 64-bit offsets; read through the `netcdf3` crate). The image is
//! the variable `image`, its dimensions the variable's (slowest first), its samples big-endian `byte`, `short`,
//! `int`, `float` or `double`, signed or not as its `signtype` attribute says (`signed__` or `unsigned`; MINC's
//! default, as libminc: unsigned for bytes, signed otherwise). `valid_range` (or `valid_min` and `valid_max`) is an
//! attribute of the image. Each dimension's `start`, `step`, `direction_cosines` and `spacing` are attributes of the
//! variable of the dimension's name, which MINC 1 lets a file leave out. `image-min` and `image-max` are variables
//! over the dimensions they vary over.

use std::io::Cursor;
use std::path::Path;

use netcdf3::{DataType, DataVector, FileReader, Variable};

use super::{Dimension, Header, SliceRange, volume_of};
use crate::error::{Error, Result};
use crate::options::LoadOptions;
use crate::sample::StoredType;
use crate::volume::Volume;

pub(super) fn read(name: &Path, bytes: Vec<u8>, opts: &LoadOptions) -> Result<Volume> {
    let file_bytes = bytes.len() as u64;
    let label = name.to_string_lossy().into_owned();
    let mut reader = FileReader::open_seek_read(&label, Box::new(Cursor::new(bytes)))
        .map_err(|e| Error::invalid(name, format!("not a readable netCDF file: {e}")))?;
    check_sizes(name, &reader, file_bytes)?;
    let header = header(name, &mut reader)?;
    header.checked_len(name, opts.max_voxel_bytes, Some(file_bytes))?;
    let raw = reader.read_var("image").map_err(|e| Error::invalid(name, format!("the image cannot be read: {e}")))?;
    // netCDF's integers are signed; an unsigned image's bytes are the same, read as their unsigned type.
    match (raw, header.stored) {
        (DataVector::I8(v), StoredType::U8) => {
            volume_of(name, &header, &v.iter().map(|&x| x as u8).collect::<Vec<_>>(), opts)
        }
        (DataVector::I8(v), _) => volume_of(name, &header, &v, opts),
        (DataVector::I16(v), StoredType::U16) => {
            volume_of(name, &header, &v.iter().map(|&x| x as u16).collect::<Vec<_>>(), opts)
        }
        (DataVector::I16(v), _) => volume_of(name, &header, &v, opts),
        (DataVector::I32(v), StoredType::U32) => {
            volume_of(name, &header, &v.iter().map(|&x| x as u32).collect::<Vec<_>>(), opts)
        }
        (DataVector::I32(v), _) => volume_of(name, &header, &v, opts),
        (DataVector::F32(v), _) => volume_of(name, &header, &v, opts),
        (DataVector::F64(v), _) => volume_of(name, &header, &v, opts),
        (DataVector::U8(_), _) => {
            Err(Error::unsupported(name, "the image holds characters (netCDF char), not numbers"))
        }
    }
}

/// Refuses a file any of whose variables cannot fit it, before anything reads one: the crate computes sizes without
/// checking them, so each is checked here first.
fn check_sizes(name: &Path, reader: &FileReader, file_bytes: u64) -> Result<()> {
    let data_set = reader.data_set();
    let records = data_set.num_records().unwrap_or(0) as u128;
    for var in data_set.get_vars() {
        let mut count = 1u128;
        for (a, dim) in var.get_dims().iter().enumerate() {
            let n = if a == 0 && dim.is_unlimited() { records } else { dim.size() as u128 };
            count = count.saturating_mul(n.max(1));
        }
        let bytes = count.saturating_mul(var.data_type().size_of() as u128);
        if bytes > u128::from(file_bytes) {
            return Err(Error::truncated(
                name,
                format!("the variable {} holds {bytes} bytes, more than the file's {file_bytes}", var.name()),
            ));
        }
    }
    Ok(())
}

fn header(name: &Path, reader: &mut FileReader) -> Result<Header> {
    let data_set = reader.data_set();
    let Some(image) = data_set.get_var("image") else {
        return Err(Error::invalid(name, "a netCDF file without the variable image, so not a MINC volume"));
    };
    let signed = match image.get_attr_as_string("signtype").as_deref().map(|s| s.trim_end_matches('\0')) {
        Some("signed__" | "signed") => true,
        Some("unsigned") => false,
        None => image.data_type() != DataType::I8,
        Some(other) => {
            return Err(Error::invalid(name, format!("the image's signtype is {other:?}, not signed__ or unsigned")));
        }
    };
    let stored = match (image.data_type(), signed) {
        (DataType::I8, true) => StoredType::I8,
        (DataType::I8, false) => StoredType::U8,
        (DataType::I16, true) => StoredType::I16,
        (DataType::I16, false) => StoredType::U16,
        (DataType::I32, true) => StoredType::I32,
        (DataType::I32, false) => StoredType::U32,
        (DataType::F32, _) => StoredType::F32,
        (DataType::F64, _) => StoredType::F64,
        (DataType::U8, _) => {
            return Err(Error::unsupported(name, "the image holds characters (netCDF char), not numbers"));
        }
    };
    let records = data_set.num_records().unwrap_or(0);
    let mut dims = Vec::new();
    for (a, dim) in image.get_dims().iter().enumerate() {
        let dim_name = dim.name();
        let len = if a == 0 && dim.is_unlimited() { records } else { dim.size() };
        let var = data_set.get_var(&dim_name);
        dims.push(Dimension {
            start: var.map(|v| scalar(name, v, "start")).transpose()?.flatten(),
            step: var.map(|v| scalar(name, v, "step")).transpose()?.flatten(),
            cosines: var.and_then(|v| numbers(v, "direction_cosines")),
            spacing: var.and_then(|v| v.get_attr_as_string("spacing")).map(|s| s.trim_end_matches('\0').to_string()),
            name: dim_name,
            len,
        });
    }
    let valid_range = match (numbers(image, "valid_range"), numbers(image, "valid_min"), numbers(image, "valid_max")) {
        (Some(v), _, _) if v.len() == 2 => Some([v[0], v[1]]),
        (Some(v), _, _) => {
            return Err(Error::invalid(name, format!("the image's valid_range has {} values, not 2", v.len())));
        }
        (None, Some(lo), Some(hi)) if lo.len() == 1 && hi.len() == 1 => Some([lo[0], hi[0]]),
        (None, None, None) => None,
        _ => return Err(Error::invalid(name, "the image's valid_min and valid_max are not one number each")),
    };
    let has = |v: &str| data_set.get_var(v).is_some();
    let range = match (has("image-min"), has("image-max")) {
        (true, true) => {
            let (lo_dims, min) = slice_values(name, reader, "image-min")?;
            let (hi_dims, max) = slice_values(name, reader, "image-max")?;
            if lo_dims != hi_dims {
                return Err(Error::invalid(
                    name,
                    format!("image-min varies over {lo_dims:?} but image-max over {hi_dims:?}"),
                ));
            }
            Some(SliceRange { dims: lo_dims, min, max })
        }
        (false, false) => None,
        _ => return Err(Error::invalid(name, "it has one of image-min and image-max without the other")),
    };
    Ok(Header { dims, stored, valid_range, range })
}

/// The values of the variable `image-min` or `image-max` and the dimensions they vary over.
fn slice_values(name: &Path, reader: &mut FileReader, var: &str) -> Result<(Vec<String>, Vec<f64>)> {
    let dims = reader.data_set().get_var(var).map(Variable::dim_names).unwrap_or_default();
    let values = match reader.read_var(var).map_err(|e| Error::invalid(name, format!("{var} cannot be read: {e}")))? {
        DataVector::I8(v) => v.iter().map(|&x| f64::from(x)).collect(),
        DataVector::I16(v) => v.iter().map(|&x| f64::from(x)).collect(),
        DataVector::I32(v) => v.iter().map(|&x| f64::from(x)).collect(),
        DataVector::F32(v) => v.iter().map(|&x| f64::from(x)).collect(),
        DataVector::F64(v) => v,
        DataVector::U8(_) => return Err(Error::invalid(name, format!("{var} holds characters, not numbers"))),
    };
    Ok((dims, values))
}

/// A numeric attribute of `var`, as doubles.
fn numbers(var: &Variable, key: &str) -> Option<Vec<f64>> {
    let attr = var.get_attr(key)?;
    if let Some(v) = attr.get_f64() {
        return Some(v.to_vec());
    }
    if let Some(v) = attr.get_f32() {
        return Some(v.iter().map(|&x| f64::from(x)).collect());
    }
    if let Some(v) = attr.get_i32() {
        return Some(v.iter().map(|&x| f64::from(x)).collect());
    }
    if let Some(v) = attr.get_i16() {
        return Some(v.iter().map(|&x| f64::from(x)).collect());
    }
    attr.get_i8().map(|v| v.iter().map(|&x| f64::from(x)).collect())
}

/// A one-number attribute of a dimension's variable, if present.
fn scalar(name: &Path, var: &Variable, key: &str) -> Result<Option<f64>> {
    match numbers(var, key) {
        None => Ok(None),
        Some(v) if v.len() == 1 => Ok(Some(v[0])),
        Some(v) => Err(Error::invalid(name, format!("{}'s {key} has {} values, not 1", var.name(), v.len()))),
    }
}
