//! The points a landmark file holds: [`LandmarkPair`]s (BigWarp, plain CSV) and the [`SlicerPoint`]s of one side
//! (Slicer), both in LPS mm, and the flip of x and y that converts a RAS file's points.

use crate::geometry::{Lps, Point3};

/// One landmark pair: a point on the moving volume and its match on the fixed volume.
#[derive(Clone, Debug, PartialEq)]
pub struct LandmarkPair {
    /// Free text; may be empty or repeated.
    pub name: String,
    /// Whether the pair takes part in the warp (BigWarp "Active", Slicer "selected").
    pub active: bool,
    /// The point on the moving (source) volume, or `None` when not placed yet.
    pub moving: Option<Point3<Lps>>,
    /// The point on the fixed (target) volume, or `None` when not placed yet.
    pub fixed: Option<Point3<Lps>>,
}

impl LandmarkPair {
    /// An active pair with both halves.
    #[must_use]
    pub fn new(name: impl Into<String>, moving: Point3<Lps>, fixed: Point3<Lps>) -> Self {
        Self { name: name.into(), active: true, moving: Some(moving), fixed: Some(fixed) }
    }

    /// True when both halves are placed.
    #[must_use]
    pub fn is_complete(&self) -> bool {
        self.moving.is_some() && self.fixed.is_some()
    }
}

/// The moving and fixed points of the active pairs that have both halves, in file order.
#[must_use]
pub fn complete_active_pairs(pairs: &[LandmarkPair]) -> (Vec<Point3<Lps>>, Vec<Point3<Lps>>) {
    pairs.iter().filter(|p| p.active).filter_map(|p| Some((p.moving?, p.fixed?))).unzip()
}

/// One Slicer control point (one side of a pair).
#[derive(Clone, Debug, PartialEq)]
pub struct SlicerPoint {
    pub label: String,
    pub selected: bool,
    /// `None` for a point whose position is not defined (`positionStatus` other than `defined`).
    pub position: Option<Point3<Lps>>,
}

/// RAS ↔ LPS: `p` with x and y negated, as the RAS files are converted at I/O.
pub(super) fn flip_xy(p: Point3<Lps>) -> Point3<Lps> {
    let [x, y, z] = p.coords();
    Point3::new(-x, -y, z)
}
