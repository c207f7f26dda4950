//! `lps_from_index` from the header's space, space directions and origin (or its spacings), with the
//! non-spatial axis of a 4-D file dropped.

use std::path::Path;

use nalgebra::Matrix3;

use super::header::Header;
use crate::error::{Error, Result};
use crate::geometry::{Index, Lps, Transform};
use crate::volume::GeometrySource;

/// The three spatial axes, `lps_from_index` and where it came from.
pub(super) struct Geometry {
    pub(super) dims: [usize; 3],
    pub(super) lps_from_index: Transform<Lps, Index>,
    pub(super) source: GeometrySource,
}

pub(super) fn geometry(name: &Path, h: &mut Header) -> Result<Geometry> {
    let dimension = h.sizes.len();
    // Which axis (if any) is not spatial.
    let dropped: Option<usize> = if let Some(dirs) = &h.directions {
        let nones: Vec<usize> = (0..dimension).filter(|&a| dirs[a].is_none()).collect();
        if nones.len() + 3 != dimension {
            return Err(Error::unsupported(
                name,
                format!(
                    "{} of {dimension} axes have a space direction; exactly 3 spatial axes are needed",
                    dimension - nones.len()
                ),
            ));
        }
        nones.first().copied()
    } else if dimension == 4 {
        let nan_spacing = h.spacings.as_ref().and_then(|s| one_index(s.iter().map(|x| x.is_nan())));
        let kind_marked = h.kinds.as_ref().filter(|k| k.len() == 4).and_then(|k| {
            one_index(k.iter().map(|k| !matches!(k.as_str(), "domain" | "space" | "time" | "???" | "none")))
        });
        nan_spacing.or(kind_marked).or_else(|| h.sizes.iter().position(|&n| n == 1))
    } else {
        None
    };
    if dimension == 4 {
        let a = dropped.ok_or_else(|| {
            Error::unsupported(
                name,
                format!("4-D data of sizes {:?}: vector and time-series volumes are not supported", h.sizes),
            )
        })?;
        if h.sizes[a] != 1 {
            return Err(Error::unsupported(
                name,
                format!(
                    "axis {a} is not spatial and has {} samples (sizes {:?}): vector and 4-D volumes are not supported",
                    h.sizes[a], h.sizes
                ),
            ));
        }
    }
    let spatial: Vec<usize> = (0..dimension).filter(|&a| Some(a) != dropped).collect();
    let dims = [h.sizes[spatial[0]], h.sizes[spatial[1]], h.sizes[spatial[2]]];

    if let (Some(space), Some(dirs)) = (h.space, &h.directions) {
        let s = space.lps_signs();
        let mut linear = Matrix3::zeros();
        for (c, &a) in spatial.iter().enumerate() {
            let d = dirs[a].unwrap_or([0.0; 3]);
            for r in 0..3 {
                linear[(r, c)] = s[r] * d[r];
            }
        }
        let o = h.origin.unwrap_or_else(|| {
            h.warnings.push("the header has no \"space origin\"; origin 0 assumed".to_string());
            [0.0; 3]
        });
        let origin_lps = [s[0] * o[0], s[1] * o[1], s[2] * o[2]];
        return Ok(Geometry {
            dims,
            lps_from_index: Transform::from_linear_translation(linear, origin_lps),
            source: GeometrySource::NrrdSpace,
        });
    }
    let scale = if let Some(sp) = &h.spacings {
        let v = [sp[spatial[0]], sp[spatial[1]], sp[spatial[2]]];
        if v.iter().any(|x| x.is_nan()) {
            return Err(Error::invalid(name, format!("a spatial axis has spacing nan: {sp:?}")));
        }
        v
    } else {
        h.warnings.push("the header has neither a space nor spacings; unit spacing assumed".to_string());
        [1.0; 3]
    };
    Ok(Geometry {
        dims,
        lps_from_index: Transform::from_scale_translation(scale, [0.0; 3]),
        source: GeometrySource::NrrdSpacings,
    })
}

/// The index of the only `true`, if exactly one.
fn one_index(it: impl Iterator<Item = bool>) -> Option<usize> {
    let hits: Vec<usize> = it.enumerate().filter(|(_, b)| *b).map(|(i, _)| i).collect();
    if hits.len() == 1 { Some(hits[0]) } else { None }
}
