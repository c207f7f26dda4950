//! `lps_from_index` from the header's direction, spacing and offset, and the frames of a 4-D file.

use std::path::Path;

use nalgebra::Matrix3;

use super::header::Header;
use crate::error::{Error, Result};
use crate::geometry::{Index, Lps, Transform};

/// The three spatial axes, the frames along a 4th axis (1 for a 3-D file) and `lps_from_index`.
pub(super) struct Geometry {
    pub(super) dims: [usize; 3],
    pub(super) frames: usize,
    pub(super) lps_from_index: Transform<Lps, Index>,
}

/// The geometry of `h`: `lps_from_index = [D · diag(spacing) | offset]`, with D the direction whose column a is
/// values a·n … a·n + 2 of `TransformMatrix` (n = NDims; column-major, as ITK writes it). Missing fields take MetaIO's
/// defaults: the identity, unit spacing, offset 0. In a 4-D file the 4th axis must not mix with the spatial ones.
pub(super) fn geometry(name: &Path, h: &Header) -> Result<Geometry> {
    let n = h.ndims;
    let dims = [h.dim_size[0], h.dim_size[1], h.dim_size[2]];
    let frames = if n == 4 { h.dim_size[3] } else { 1 };
    let direction = |r: usize, c: usize| h.direction.as_ref().map_or(if r == c { 1.0 } else { 0.0 }, |v| v[c * n + r]);
    if n == 4 {
        let mixed = (0..3).any(|a| direction(a, 3) != 0.0 || direction(3, a) != 0.0);
        if mixed {
            return Err(Error::unsupported(
                name,
                "the TransformMatrix mixes the 4th axis with the three spatial ones; only a 4th axis of frames is read",
            ));
        }
    }
    let spacing = h.spacing.as_ref().map_or([1.0; 3], |s| [s[0], s[1], s[2]]);
    let offset = h.offset.as_ref().map_or([0.0; 3], |o| [o[0], o[1], o[2]]);
    let linear = Matrix3::from_fn(|r, c| direction(r, c) * spacing[c]);
    Ok(Geometry { dims, frames, lps_from_index: Transform::from_linear_translation(linear, offset) })
}
