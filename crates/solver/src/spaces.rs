//! The two patient spaces of a registration, as types.
//!
//! Both are DICOM LPS in mm, but they are different frames until the registration relates them:
//! a landmark pair is (p_i ∈ [`Moving`], q_i ∈ [`Fixed`]). The forward warp d maps moving to fixed
//! (`Warp<Fixed, Moving>`, named `fixed_from_moving`); the **pull-back** u = d⁻¹ maps fixed to moving
//! (`Warp<Moving, Fixed>`, named `moving_from_fixed`). Rendering and export use the pull-back:
//! v'(x) = v_moving(u(x)) (Brunet et al. 2006 §3).

use warpbench_io::geometry::{Lps, Point3, Space};

/// The moving volume's LPS space, in mm.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Moving;
impl Space for Moving {
    const NAME: &'static str = "moving";
}

/// The fixed (reference) volume's LPS space, in mm.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Fixed;
impl Space for Fixed {
    const NAME: &'static str = "fixed";
}

/// Tags a point read from a file (plain LPS) as belonging to the moving volume's space.
#[must_use]
pub fn as_moving(p: Point3<Lps>) -> Point3<Moving> {
    Point3::from_array(p.coords())
}

/// Tags a point read from a file (plain LPS) as belonging to the fixed volume's space.
#[must_use]
pub fn as_fixed(p: Point3<Lps>) -> Point3<Fixed> {
    Point3::from_array(p.coords())
}

/// An axis-aligned box in space `S` (e.g. the fixed volume's bounds, over which a control texture is sampled).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Aabb<S: Space> {
    pub min: Point3<S>,
    pub max: Point3<S>,
}

impl<S: Space> Aabb<S> {
    #[must_use]
    pub fn new(min: Point3<S>, max: Point3<S>) -> Self {
        Self { min, max }
    }

    /// The smallest box holding all `points`, grown by `margin` mm on every side; `None` when empty.
    #[must_use]
    pub fn around(points: &[Point3<S>], margin: f64) -> Option<Self> {
        let first = points.first()?.coords();
        let (mut lo, mut hi) = (first, first);
        for p in points {
            let c = p.coords();
            for a in 0..3 {
                lo[a] = lo[a].min(c[a]);
                hi[a] = hi[a].max(c[a]);
            }
        }
        Some(Self {
            min: Point3::new(lo[0] - margin, lo[1] - margin, lo[2] - margin),
            max: Point3::new(hi[0] + margin, hi[1] + margin, hi[2] + margin),
        })
    }

    /// Edge lengths in mm.
    #[must_use]
    pub fn size(&self) -> [f64; 3] {
        let (a, b) = (self.min.coords(), self.max.coords());
        [b[0] - a[0], b[1] - a[1], b[2] - a[2]]
    }

    #[must_use]
    pub fn contains(&self, p: &Point3<S>) -> bool {
        let (a, b, c) = (self.min.coords(), self.max.coords(), p.coords());
        (0..3).all(|i| c[i] >= a[i] && c[i] <= b[i])
    }

    /// True when every edge is finite and positive.
    #[must_use]
    pub fn is_valid(&self) -> bool {
        self.size().iter().all(|s| s.is_finite() && *s > 0.0)
    }
}
