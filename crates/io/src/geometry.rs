//! Points, vectors and transforms that carry their coordinate space in the type.
//!
//! A transform is named `b_from_a` and has type `Transform<B, A>`, so chains read
//! right to left and only compose when the spaces match:
//!
//! ```
//! use warpbench_io::geometry::{Index, Lps, Point3, Transform};
//! let lps_from_index: Transform<Lps, Index> = Transform::from_scale_translation([2.0, 2.0, 3.0], [-10.0, 5.0, 0.0]);
//! let p_lps = lps_from_index.apply_point(Point3::new(1.0, 0.0, 2.0));
//! assert_eq!(p_lps.coords(), [-8.0, 5.0, 6.0]);
//! ```
//!
//! Inside kernels and GPU packing, use raw arrays or nalgebra via [`Transform::matrix`].

use std::fmt;
use std::marker::PhantomData;
use std::ops::Mul;

use nalgebra::{Matrix3, Matrix4, Vector3 as NVector3, Vector4};

/// A named coordinate space (a zero-sized marker type).
pub trait Space: Copy + fmt::Debug + Default + Send + Sync + 'static {
    /// Short name used in `Debug` output and docs.
    const NAME: &'static str;
}

macro_rules! space {
    ($(#[$doc:meta])* $name:ident, $label:literal) => {
        $(#[$doc])*
        #[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
        pub struct $name;
        impl Space for $name {
            const NAME: &'static str = $label;
        }
    };
}

space!(
    /// A volume's continuous voxel index (i, j, k); 0 is the centre of the first voxel, as in ITK.
    Index,
    "index"
);
space!(
    /// Patient space, DICOM LPS (+x left, +y posterior, +z superior), in mm.
    Lps,
    "lps"
);
space!(
    /// NIfTI/Slicer world space, RAS (+x right, +y anterior, +z superior), in mm. Only at file I/O.
    Ras,
    "ras"
);

/// A point in space `S`.
#[derive(Clone, Copy, PartialEq)]
pub struct Point3<S: Space> {
    xyz: [f64; 3],
    space: PhantomData<S>,
}

/// A displacement (direction and length) in space `S`. Translations do not act on it.
#[derive(Clone, Copy, PartialEq)]
pub struct Vector3<S: Space> {
    xyz: [f64; 3],
    space: PhantomData<S>,
}

impl<S: Space> Point3<S> {
    #[must_use]
    pub const fn new(x: f64, y: f64, z: f64) -> Self {
        Self { xyz: [x, y, z], space: PhantomData }
    }
    #[must_use]
    pub const fn from_array(xyz: [f64; 3]) -> Self {
        Self { xyz, space: PhantomData }
    }
    #[must_use]
    pub const fn coords(&self) -> [f64; 3] {
        self.xyz
    }
    #[must_use]
    pub fn is_finite(&self) -> bool {
        self.xyz.iter().all(|c| c.is_finite())
    }
    /// The vector from `other` to `self`.
    #[must_use]
    pub fn sub(&self, other: &Self) -> Vector3<S> {
        Vector3::new(self.xyz[0] - other.xyz[0], self.xyz[1] - other.xyz[1], self.xyz[2] - other.xyz[2])
    }
    #[must_use]
    pub fn add(&self, v: &Vector3<S>) -> Self {
        let w = v.coords();
        Self::new(self.xyz[0] + w[0], self.xyz[1] + w[1], self.xyz[2] + w[2])
    }
    #[must_use]
    pub fn distance(&self, other: &Self) -> f64 {
        self.sub(other).norm()
    }
}

impl<S: Space> Vector3<S> {
    #[must_use]
    pub const fn new(x: f64, y: f64, z: f64) -> Self {
        Self { xyz: [x, y, z], space: PhantomData }
    }
    #[must_use]
    pub const fn coords(&self) -> [f64; 3] {
        self.xyz
    }
    #[must_use]
    pub fn norm(&self) -> f64 {
        self.dot(self).sqrt()
    }
    #[must_use]
    pub fn dot(&self, o: &Self) -> f64 {
        self.xyz[0] * o.xyz[0] + self.xyz[1] * o.xyz[1] + self.xyz[2] * o.xyz[2]
    }
}

impl<S: Space> fmt::Debug for Point3<S> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "Point3<{}>({}, {}, {})", S::NAME, self.xyz[0], self.xyz[1], self.xyz[2])
    }
}
impl<S: Space> fmt::Debug for Vector3<S> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "Vector3<{}>({}, {}, {})", S::NAME, self.xyz[0], self.xyz[1], self.xyz[2])
    }
}

/// An affine map from space `From` to space `To`, stored as a 4×4 homogeneous matrix (f64).
#[derive(Clone, Copy, PartialEq)]
pub struct Transform<To: Space, From: Space> {
    to_from: Matrix4<f64>,
    spaces: PhantomData<(To, From)>,
}

impl<To: Space, From: Space> fmt::Debug for Transform<To, From> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "Transform<{} <- {}>{:?}", To::NAME, From::NAME, self.rows())
    }
}

impl<To: Space, From: Space> Transform<To, From> {
    /// Wraps a homogeneous matrix whose last row must be (0, 0, 0, 1) for an affine map.
    #[must_use]
    pub fn from_matrix(to_from: Matrix4<f64>) -> Self {
        Self { to_from, spaces: PhantomData }
    }

    /// Builds `[linear | translation]` from a 3×3 linear part and a translation.
    #[must_use]
    pub fn from_linear_translation(linear: Matrix3<f64>, translation: [f64; 3]) -> Self {
        let mut m = Matrix4::identity();
        m.fixed_view_mut::<3, 3>(0, 0).copy_from(&linear);
        m[(0, 3)] = translation[0];
        m[(1, 3)] = translation[1];
        m[(2, 3)] = translation[2];
        Self::from_matrix(m)
    }

    /// Axis-aligned scale followed by a translation.
    #[must_use]
    pub fn from_scale_translation(scale: [f64; 3], translation: [f64; 3]) -> Self {
        Self::from_linear_translation(Matrix3::from_diagonal(&NVector3::from(scale)), translation)
    }

    #[must_use]
    pub fn identity() -> Self {
        Self::from_matrix(Matrix4::identity())
    }

    /// The homogeneous matrix (column vectors: `p_to = M * p_from`).
    #[must_use]
    pub fn matrix(&self) -> &Matrix4<f64> {
        &self.to_from
    }

    /// The matrix as four rows, row-major.
    #[must_use]
    pub fn rows(&self) -> [[f64; 4]; 4] {
        let m = &self.to_from;
        std::array::from_fn(|r| std::array::from_fn(|c| m[(r, c)]))
    }

    /// The 3×3 linear part.
    #[must_use]
    pub fn linear(&self) -> Matrix3<f64> {
        self.to_from.fixed_view::<3, 3>(0, 0).into_owned()
    }

    #[must_use]
    pub fn translation(&self) -> [f64; 3] {
        [self.to_from[(0, 3)], self.to_from[(1, 3)], self.to_from[(2, 3)]]
    }

    #[must_use]
    pub fn apply_point(&self, p: Point3<From>) -> Point3<To> {
        let [x, y, z] = p.coords();
        let q = self.to_from * Vector4::new(x, y, z, 1.0);
        Point3::new(q[0], q[1], q[2])
    }

    #[must_use]
    pub fn apply_vector(&self, v: Vector3<From>) -> Vector3<To> {
        let [x, y, z] = v.coords();
        let q = self.linear() * NVector3::new(x, y, z);
        Vector3::new(q[0], q[1], q[2])
    }

    /// The inverse map, or `None` when the linear part is singular or not finite.
    #[must_use]
    pub fn inverse(&self) -> Option<Transform<From, To>> {
        if !self.to_from.iter().all(|v| v.is_finite()) {
            return None;
        }
        self.to_from.try_inverse().map(Transform::from_matrix)
    }

    /// True when the map is a usable affine: every entry finite, every column of the linear part of finite,
    /// non-zero length (so a volume's spacing is finite), the columns' directions not (nearly) coplanar, and an
    /// inverse with finite entries.
    ///
    /// Singularity is judged on the unit columns, |det [d₀/‖d₀‖ d₁/‖d₁‖ d₂/‖d₂‖]| > [`MIN_UNIT_DETERMINANT`],
    /// so that it does not depend on the scale: a grid of 10⁻⁵ mm voxels is valid (if implausible), one whose
    /// third axis lies in the plane of the first two is not.
    #[must_use]
    pub fn is_valid_affine(&self) -> bool {
        if !self.to_from.iter().all(|v| v.is_finite()) {
            return false;
        }
        let mut unit = self.linear();
        for mut c in unit.column_iter_mut() {
            let n = c.norm();
            if !(n.is_finite() && n > 0.0) {
                return false;
            }
            c /= n;
        }
        unit.determinant().abs() > MIN_UNIT_DETERMINANT
            && self.to_from.try_inverse().is_some_and(|inv| inv.iter().all(|v| v.is_finite()))
    }

    /// Largest absolute difference between the entries of two transforms.
    #[must_use]
    pub fn max_abs_diff(&self, other: &Self) -> f64 {
        self.to_from.iter().zip(other.to_from.iter()).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max)
    }
}

/// Below this |determinant| of its unit columns, a linear part counts as singular (see
/// [`Transform::is_valid_affine`]): the volume of the parallelepiped of the three unit directions, 1 for
/// orthogonal axes.
pub const MIN_UNIT_DETERMINANT: f64 = 1e-6;

/// `c_from_b * b_from_a = c_from_a`: composes only when the inner spaces match.
impl<C: Space, B: Space, A: Space> Mul<Transform<B, A>> for Transform<C, B> {
    type Output = Transform<C, A>;
    fn mul(self, rhs: Transform<B, A>) -> Transform<C, A> {
        Transform::from_matrix(self.to_from * rhs.to_from)
    }
}

/// RAS ↔ LPS: negate x and y. The map is its own inverse.
#[must_use]
pub fn lps_from_ras() -> Transform<Lps, Ras> {
    Transform::from_scale_translation([-1.0, -1.0, 1.0], [0.0; 3])
}

/// RAS ↔ LPS: negate x and y.
#[must_use]
pub fn ras_from_lps() -> Transform<Ras, Lps> {
    Transform::from_scale_translation([-1.0, -1.0, 1.0], [0.0; 3])
}

/// Voxel spacing in mm: the lengths of the columns of the linear part of `lps_from_index`.
#[must_use]
pub fn spacing_mm(lps_from_index: &Transform<Lps, Index>) -> [f64; 3] {
    let l = lps_from_index.linear();
    [l.column(0).norm(), l.column(1).norm(), l.column(2).norm()]
}

/// Unit direction cosines (columns) of `lps_from_index`: the LPS direction of +i, +j, +k.
#[must_use]
pub fn direction_cosines(lps_from_index: &Transform<Lps, Index>) -> Matrix3<f64> {
    let mut l = lps_from_index.linear();
    for mut c in l.column_iter_mut() {
        let n = c.norm();
        if n > 0.0 {
            c /= n;
        }
    }
    l
}

/// y with `forward`(y) = x, by Newton's method from `start`: each step is J⁻¹ r with J = `jacobian`(y) and r =
/// `forward`(y) − x (where J is singular, the fixed-point step r), halved up to 20 times until the residual falls; at
/// most `max_steps` steps, stopping within `tolerance_mm`. Returns the point of least residual found: within the
/// tolerance where `forward` is invertible near x, the best it reached elsewhere (where it folds or jumps). Raw
/// coordinates, mm: the one point inversion of fields, splines and ITK's chains.
pub fn newton_inverse(
    forward: impl Fn([f64; 3]) -> [f64; 3],
    jacobian: impl Fn([f64; 3]) -> Matrix3<f64>,
    x: [f64; 3],
    start: [f64; 3],
    (tolerance_mm, max_steps): (f64, usize),
) -> [f64; 3] {
    let residual = |y: [f64; 3]| {
        let f = forward(y);
        [f[0] - x[0], f[1] - x[1], f[2] - x[2]]
    };
    let norm = |r: [f64; 3]| (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]).sqrt();
    // Each step taken lowers the residual, so (y, r) is always the best point found.
    let (mut y, mut r) = (start, residual(start));
    for _ in 0..max_steps {
        let size = norm(r);
        if size.is_nan() || size <= tolerance_mm {
            break;
        }
        let step = match jacobian(y).try_inverse() {
            Some(inverse) => (inverse * NVector3::from(r)).into(),
            None => r,
        };
        let mut scale = 1.0;
        let mut moved = false;
        for _ in 0..20 {
            let trial = [y[0] - scale * step[0], y[1] - scale * step[1], y[2] - scale * step[2]];
            let rt = residual(trial);
            if norm(rt) < size {
                (y, r, moved) = (trial, rt, true);
                break;
            }
            scale *= 0.5;
        }
        if !moved {
            break;
        }
    }
    y
}

#[cfg(test)]
#[allow(clippy::float_cmp, reason = "the expected values are exact in binary floating point")]
mod tests {
    use super::*;

    /// Newton's method inverts a smooth map to its tolerance from a poor start, falls back on the fixed-point step
    /// where it is told the Jacobian is singular, and at a jump returns the best point it reached.
    #[test]
    fn newton_inverse_finds_the_preimage_or_the_nearest_point() {
        let f = |y: [f64; 3]| [y[0] + 0.3 * y[1].sin(), y[1] + 0.2 * y[2].cos(), y[2] + 0.25 * y[0].sin()];
        let jacobian = |y: [f64; 3]| {
            Matrix3::new(1.0, 0.3 * y[1].cos(), 0.0, 0.0, 1.0, -0.2 * y[2].sin(), 0.25 * y[0].cos(), 0.0, 1.0)
        };
        let x = [1.0, -2.0, 0.5];
        let y = newton_inverse(f, jacobian, x, [5.0, 5.0, 5.0], (1e-12, 50));
        let back = f(y);
        assert!((0..3).all(|a| (back[a] - x[a]).abs() < 1e-12), "f({y:?}) = {back:?}");
        let y = newton_inverse(f, |_| Matrix3::zeros(), x, x, (1e-9, 200));
        let back = f(y);
        assert!((0..3).all(|a| (back[a] - x[a]).abs() < 1e-9), "fixed point: f({y:?}) = {back:?}");
        // A jump of 1 at 0 along the first axis: 0.5 has no preimage; the best point is at the jump, half away.
        let jump = |y: [f64; 3]| [if y[0] < 0.0 { y[0] } else { y[0] + 1.0 }, y[1], y[2]];
        let y = newton_inverse(jump, |_| Matrix3::identity(), [0.5, 0.0, 0.0], [0.5, 0.0, 0.0], (1e-9, 50));
        assert!(y[0].abs() < 1e-9 && ((jump(y)[0] - 0.5).abs() - 0.5).abs() < 1e-9, "{y:?}");
    }

    #[test]
    fn compose_and_invert() {
        let lps_from_index: Transform<Lps, Index> =
            Transform::from_scale_translation([0.5, 0.5, 2.0], [10.0, -20.0, 30.0]);
        let ras_from_index = ras_from_lps() * lps_from_index;
        let p = ras_from_index.apply_point(Point3::new(2.0, 4.0, 1.0));
        assert_eq!(p.coords(), [-11.0, 18.0, 32.0]);
        let index_from_lps = lps_from_index.inverse().expect("invertible");
        let back = index_from_lps.apply_point(lps_from_index.apply_point(Point3::new(3.0, 1.0, 7.0)));
        assert!((back.coords()[2] - 7.0).abs() < 1e-12);
        assert_eq!(spacing_mm(&lps_from_index), [0.5, 0.5, 2.0]);
    }

    #[test]
    fn vectors_ignore_translation() {
        let t: Transform<Lps, Index> = Transform::from_scale_translation([1.0, 1.0, 1.0], [5.0, 5.0, 5.0]);
        assert_eq!(t.apply_vector(Vector3::new(1.0, 0.0, 0.0)).coords(), [1.0, 0.0, 0.0]);
    }

    #[test]
    fn validity_is_judged_on_unit_directions_and_finite_lengths() {
        let tiny: Transform<Lps, Index> = Transform::from_scale_translation([1e-5; 3], [0.0; 3]);
        assert!(tiny.is_valid_affine(), "small voxels are valid (if implausible)");
        // Finite entries whose column length (and determinant) overflow: an infinite spacing.
        let huge: Transform<Lps, Index> = Transform::from_scale_translation([1e308; 3], [0.0; 3]);
        assert!(!huge.is_valid_affine());
        assert!(spacing_mm(&huge).iter().all(|s| s.is_infinite()));
        let coplanar: Transform<Lps, Index> =
            Transform::from_linear_translation(Matrix3::new(1.0, 0.0, 1.0, 0.0, 1.0, 1.0, 0.0, 0.0, 1e-9), [0.0; 3]);
        assert!(!coplanar.is_valid_affine());
        let subnormal: Transform<Lps, Index> = Transform::from_scale_translation([1e-310; 3], [0.0; 3]);
        assert!(!subnormal.is_valid_affine(), "its inverse is not finite");
    }

    #[test]
    fn singular_has_no_inverse() {
        let t: Transform<Lps, Index> = Transform::from_scale_translation([1.0, 0.0, 1.0], [0.0; 3]);
        assert!(t.inverse().is_none());
        assert!(!t.is_valid_affine());
    }
}
