//! MINC 1: a netCDF classic file ([`super::netcdf`]). The image is the variable `image`, its dimensions the
//! variable's (slowest first), its samples big-endian `byte`, `short`, `int`, `float` or `double`, signed or not as
//! its `signtype` attribute says (`signed__` or `unsigned`; MINC's default, as libminc: unsigned for bytes, signed
//! otherwise). `valid_range` (or `valid_min` and `valid_max`) is an attribute of the image. Each dimension's `start`,
//! `step`, `direction_cosines` and `spacing` are attributes of the variable of the dimension's name, which MINC 1 lets
//! a file leave out. `image-min` and `image-max` are variables over the dimensions they vary over.

use std::path::Path;

use super::model::{Decoded, Dimension, Header, SliceRange, Want, finish};
use super::netcdf::{NcFile, NcType, Var};
use crate::error::{Error, Result};
use crate::options::LoadOptions;
use crate::sample::{self, StoredType, with_stored_type};

pub(super) fn read(name: &Path, bytes: Vec<u8>, opts: &LoadOptions, want: Want) -> Result<Decoded> {
    let file_bytes = bytes.len() as u64;
    let nc = NcFile::parse(bytes).map_err(|e| Error::invalid(name, format!("not a readable netCDF file: {e}")))?;
    let Some(image) = nc.var("image") else {
        return Err(Error::invalid(name, "a netCDF file without the variable image, so not a MINC volume"));
    };
    let header = header(name, &nc, image)?;
    header.checked_len(name, opts.max_voxel_bytes, Some(file_bytes))?;
    let raw = nc.raw(image).map_err(|e| Error::truncated(name, format!("the image cannot be read: {e}")))?;
    // netCDF's integers are signed; an unsigned image's bytes are read as their unsigned type.
    with_stored_type!(header.stored, T => {
        let samples: Vec<T> = sample::decode::<T>(&raw, true).collect();
        finish(name, &header, &samples, opts, want)
    })
}

fn header(name: &Path, nc: &NcFile, image: &Var) -> Result<Header> {
    let signed = match image.text("signtype").as_deref() {
        Some("signed__" | "signed") => true,
        Some("unsigned") => false,
        None => image.nc_type != NcType::Byte,
        Some(other) => {
            return Err(Error::invalid(name, format!("the image's signtype is {other:?}, not signed__ or unsigned")));
        }
    };
    let stored = match (image.nc_type, signed) {
        (NcType::Byte, true) => StoredType::I8,
        (NcType::Byte, false) => StoredType::U8,
        (NcType::Short, true) => StoredType::I16,
        (NcType::Short, false) => StoredType::U16,
        (NcType::Int, true) => StoredType::I32,
        (NcType::Int, false) => StoredType::U32,
        (NcType::Float, _) => StoredType::F32,
        (NcType::Double, _) => StoredType::F64,
        (NcType::Char, _) => {
            return Err(Error::unsupported(name, "the image holds characters (netCDF char), not numbers"));
        }
    };
    let mut dims = Vec::with_capacity(image.dims.len());
    for &d in &image.dims {
        let dim = &nc.dims[d];
        let var = nc.var(&dim.name);
        let len = usize::try_from(dim.len)
            .map_err(|_| Error::invalid(name, format!("{} has {} samples", dim.name, dim.len)))?;
        dims.push(Dimension {
            name: dim.name.clone(),
            len,
            start: var.map(|v| scalar(name, v, "start")).transpose()?.flatten(),
            step: var.map(|v| scalar(name, v, "step")).transpose()?.flatten(),
            cosines: var.and_then(|v| v.numbers("direction_cosines")).map(<[f64]>::to_vec),
            spacing: var.and_then(|v| v.text("spacing")),
        });
    }
    let valid_range = match (image.numbers("valid_range"), image.numbers("valid_min"), image.numbers("valid_max")) {
        (Some(&[a, b]), _, _) => Some([a, b]),
        (Some(v), _, _) => {
            return Err(Error::invalid(name, format!("the image's valid_range has {} values, not 2", v.len())));
        }
        (None, Some(&[lo]), Some(&[hi])) => Some([lo, hi]),
        (None, None, None) => None,
        _ => return Err(Error::invalid(name, "the image's valid_min and valid_max are not one number each")),
    };
    let range = match (nc.var("image-min"), nc.var("image-max")) {
        (Some(lo), Some(hi)) => {
            let (lo_dims, min) = slice_values(name, nc, lo)?;
            let (hi_dims, max) = slice_values(name, nc, hi)?;
            if lo_dims != hi_dims {
                return Err(Error::invalid(
                    name,
                    format!("image-min varies over {lo_dims:?} but image-max over {hi_dims:?}"),
                ));
            }
            Some(SliceRange { dims: lo_dims, min, max })
        }
        (None, None) => None,
        _ => return Err(Error::invalid(name, "it has one of image-min and image-max without the other")),
    };
    Ok(Header { dims, stored, valid_range, range })
}

/// The values of the variable `image-min` or `image-max` and the dimensions they vary over.
fn slice_values(name: &Path, nc: &NcFile, var: &Var) -> Result<(Vec<String>, Vec<f64>)> {
    let dims = var.dims.iter().map(|&d| nc.dims[d].name.clone()).collect();
    let values = nc.numbers(var).map_err(|e| Error::invalid(name, format!("{} cannot be read: {e}", var.name)))?;
    Ok((dims, values))
}

/// A one-number attribute of a dimension's variable, if present.
fn scalar(name: &Path, var: &Var, key: &str) -> Result<Option<f64>> {
    match var.numbers(key) {
        None => Ok(None),
        Some(&[x]) => Ok(Some(x)),
        Some(v) => Err(Error::invalid(name, format!("{}'s {key} has {} values, not 1", var.name, v.len()))),
    }
}
