//! [`SampledField`]: a warp given as displacement vectors on a grid, w(x) = x + D(x), the form of ITK's
//! `DisplacementFieldTransform` (and of ANTs' and Slicer's displacement fields).
//!
//! # The map
//!
//! The field holds one vector D_ijk (mm, LPS) at the centre of each voxel (i, j, k) of a grid whose geometry is
//! `lps_from_index`, in the space the warp maps **from** (for a pull-back u = `moving_from_fixed`: a grid in fixed
//! space, with D(x) = u(x) − x). At a point x, with continuous index c = index_from_lps · x:
//!
//! - **inside** the grid's box of voxel edges, −½ ≤ c_a ≤ n_a − ½ on every axis, D(x) is the trilinear
//!   interpolation of the vectors in the grid's own index space, the taps clamped to the grid (so the outer half
//!   voxel holds the edge voxels' vectors): ITK's `VectorLinearInterpolateImageFunction`, which clamps each
//!   neighbour index to the buffer. Because the interpolation runs in index space, an oblique grid (any
//!   direction cosines, any spacing) needs nothing special, and a field that is affine in x is reproduced exactly
//!   between the voxel centres;
//! - **outside** it, D(x) = 0: w(x) = x. This is ITK's rule (`DisplacementFieldTransform::TransformPoint` adds
//!   the interpolated vector only when `IsInsideBuffer` says the point is inside, and returns the input point
//!   otherwise); ANTs' `antsApplyTransforms` resamples through the same transform, so a field from ANTs or ITK
//!   shows here what it shows there.
//!
//! ITK's inside test is half-open (c_a < n_a − ½ at the upper faces); here both faces count as inside, widened by
//! [`EDGE_TOLERANCE_VOX`], so that a point computed to lie on the far face of the grid (the last texel of a control
//! texture over the same box, say) is not thrown outside by rounding. The two differ only within that tolerance
//! of the upper faces.
//!
//! # Kernels
//!
//! [`SampledField::apply_raw`] and the batch kernel [`Warp::apply_batch_raw`] (no allocation, no threads) both
//! go through one precomputed index_from_lps matrix; the vectors are stored as read (f32) and interpolated in f64.

use std::marker::PhantomData;

use warpbench_io::geometry::{Index, Lps, Space, Transform};
use warpbench_io::nifti::DisplacementField;

use crate::error::{Result, SolverError};
use crate::warp::Warp;

/// How far (in voxels) outside the grid's box of voxel edges a point still counts as inside (module docs).
pub const EDGE_TOLERANCE_VOX: f64 = 1e-6;

/// A displacement field as a warp from `From` to `To`: w(x) = x + D(x), D interpolated trilinearly inside the
/// grid and zero outside it (module docs). `SampledField<Moving, Fixed>` is a pull-back.
#[derive(Clone, Debug, PartialEq)]
pub struct SampledField<To: Space, From: Space> {
    dims: [usize; 3],
    lps_from_index: Transform<Lps, Index>,
    /// Rows of index_from_lps (the inverse of `lps_from_index`), the last row dropped.
    index_from_lps: [[f64; 4]; 3],
    /// D at each voxel centre, mm, i fastest.
    displacements: Vec<[f32; 3]>,
    spaces: PhantomData<(To, From)>,
}

impl<To: Space, From: Space> SampledField<To, From> {
    /// The field of `displacements` (mm, LPS, i fastest) on the grid `dims` with geometry `lps_from_index`
    /// (mm of `From`'s patient space). Refuses a grid with an empty axis, a count that does not match the grid,
    /// a geometry that is not a usable affine, and a vector that is not finite (naming its voxel, 0-based i, j, k).
    pub fn new(dims: [usize; 3], lps_from_index: Transform<Lps, Index>, displacements: Vec<[f32; 3]>) -> Result<Self> {
        let count = dims.iter().try_fold(1usize, |n, &d| n.checked_mul(d)).filter(|&n| n > 0);
        let Some(count) = count else {
            return Err(SolverError::InvalidParameter(format!(
                "displacement field dims {dims:?}: every axis needs a voxel"
            )));
        };
        if displacements.len() != count {
            return Err(SolverError::InvalidParameter(format!(
                "displacement field dims {dims:?} need {count} vectors, got {}",
                displacements.len()
            )));
        }
        let inverse = lps_from_index.inverse().filter(|_| lps_from_index.is_valid_affine());
        let Some(index_from_lps) = inverse else {
            return Err(SolverError::InvalidParameter(
                "the displacement field's voxel-to-patient matrix is singular or not finite".into(),
            ));
        };
        if let Some(at) = displacements.iter().position(|d| !d.iter().all(|v| v.is_finite())) {
            let (i, j, k) = (at % dims[0], at / dims[0] % dims[1], at / (dims[0] * dims[1]));
            return Err(SolverError::InvalidParameter(format!(
                "the displacement at voxel ({i}, {j}, {k}) is not finite: {:?}",
                displacements[at]
            )));
        }
        let rows = index_from_lps.rows();
        Ok(Self {
            dims,
            lps_from_index,
            index_from_lps: [rows[0], rows[1], rows[2]],
            displacements,
            spaces: PhantomData,
        })
    }

    /// The warp of a field as read from a file ([`warpbench_io::nifti::read_displacement_field`] and the other
    /// readers that return a [`DisplacementField`]).
    pub fn from_displacement_field(field: DisplacementField) -> Result<Self> {
        Self::new(field.dims, field.lps_from_index, field.displacements_lps)
    }

    /// Voxels along i, j, k.
    #[must_use]
    pub fn dims(&self) -> [usize; 3] {
        self.dims
    }

    /// The grid's geometry (mm of `From`).
    #[must_use]
    pub fn lps_from_index(&self) -> &Transform<Lps, Index> {
        &self.lps_from_index
    }

    /// The stored vectors, mm, i fastest.
    #[must_use]
    pub fn displacements(&self) -> &[[f32; 3]] {
        &self.displacements
    }

    /// The largest |D| over the stored vectors, mm.
    #[must_use]
    pub fn max_displacement_mm(&self) -> f64 {
        self.displacements
            .iter()
            .map(|d| d.iter().map(|&v| f64::from(v).powi(2)).sum::<f64>().sqrt())
            .fold(0.0, f64::max)
    }

    /// D(x) (module docs): `None` outside the grid's box of voxel edges, where the warp is the identity.
    #[must_use]
    pub fn displacement_raw(&self, x: [f64; 3]) -> Option<[f64; 3]> {
        trilinear_displacement(self.dims, &self.index_from_lps, &self.displacements, x)
    }
}

/// [`SampledField::displacement_raw`]'s kernel. Not generic over the spaces, so it is compiled once, here, with this
/// crate's optimisation: a caller built without it (a debug build of the app or its tests) still runs it optimised.
fn trilinear_displacement(
    dims: [usize; 3],
    index_from_lps: &[[f64; 4]; 3],
    displacements: &[[f32; 3]],
    x: [f64; 3],
) -> Option<[f64; 3]> {
    let m = index_from_lps;
    let mut base = [0usize; 3];
    let mut next = [0usize; 3];
    let mut frac = [0.0f64; 3];
    for a in 0..3 {
        let c = m[a][0] * x[0] + m[a][1] * x[1] + m[a][2] * x[2] + m[a][3];
        let n = dims[a];
        let top = n as f64 - 0.5;
        // Written so that NaN falls outside.
        if !(c >= -0.5 - EDGE_TOLERANCE_VOX && c <= top + EDGE_TOLERANCE_VOX) {
            return None;
        }
        // Clamping c to [0, n − 1] is clamping both taps to the grid, as ITK does.
        let c = c.clamp(0.0, (n - 1) as f64);
        let i0 = (c.floor() as usize).min(n.saturating_sub(2));
        base[a] = i0;
        next[a] = (i0 + 1).min(n - 1);
        frac[a] = c - i0 as f64;
    }
    let [nx, ny, _] = dims;
    let mut d = [0.0f64; 3];
    for corner in 0..8 {
        let pick = |a: usize| corner >> a & 1 == 1;
        let mut w = 1.0;
        let mut ijk = [0usize; 3];
        for a in 0..3 {
            if pick(a) {
                w *= frac[a];
                ijk[a] = next[a];
            } else {
                w *= 1.0 - frac[a];
                ijk[a] = base[a];
            }
        }
        if w == 0.0 {
            continue;
        }
        let v = displacements[ijk[0] + nx * (ijk[1] + ny * ijk[2])];
        for (da, va) in d.iter_mut().zip(v) {
            *da += w * f64::from(va);
        }
    }
    Some(d)
}

impl<To: Space, From: Space> Warp<To, From> for SampledField<To, From> {
    fn apply_raw(&self, x: [f64; 3]) -> [f64; 3] {
        match self.displacement_raw(x) {
            Some(d) => [x[0] + d[0], x[1] + d[1], x[2] + d[2]],
            None => x,
        }
    }

    fn apply_batch_raw(&self, xs: &[[f64; 3]], out: &mut [[f64; 3]]) {
        debug_assert_eq!(xs.len(), out.len());
        for (x, o) in xs.iter().zip(out.iter_mut()) {
            *o = self.apply_raw(*x);
        }
    }
}

/// How close [`PointInverse`] brings w(y) to the point it inverts, mm, and the most steps it takes.
pub const POINT_INVERSE_TOLERANCE_MM: f64 = 1e-7;
pub const POINT_INVERSE_MAX_STEPS: usize = 50;

/// w⁻¹ of a [`SampledField`] w(y) = y + D(y), point by point: for each x, the y with y + D(y) = x, by Newton's method
/// on the trilinear field (its Jacobian I + ∇D by central differences) from y₀ = x − D(x), each step halved until
/// the residual shrinks. Where the grid does not reach (D = 0 around x), y = x, as w is the identity there.
///
/// This is the inverse the field's own users compute when they need one at a few points (ITK's
/// `InverseDisplacementFieldImageFilter` fits one over a grid instead; Chen et al. 2008 use the fixed-point form
/// y ← x − D(y), which this falls back to where the Jacobian is singular). It converges where w is invertible
/// near x, i.e. det(I + ∇D) > 0; elsewhere it returns the iterate with the smallest residual, and
/// [`PointInverse::residual_raw`] says how far off it is.
#[derive(Clone, Copy, Debug)]
pub struct PointInverse<'a, To: Space, From: Space>(pub &'a SampledField<To, From>);

impl<To: Space, From: Space> PointInverse<'_, To, From> {
    /// |w(w⁻¹(x)) − x|, mm.
    #[must_use]
    pub fn residual_raw(&self, x: [f64; 3]) -> f64 {
        let y = self.apply_raw(x);
        distance(self.0.apply_raw(y), x)
    }
}

fn distance(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

impl<To: Space, From: Space> Warp<From, To> for PointInverse<'_, To, From> {
    fn apply_raw(&self, x: [f64; 3]) -> [f64; 3] {
        let w = self.0;
        let start = match w.displacement_raw(x) {
            Some(d) => [x[0] - d[0], x[1] - d[1], x[2] - d[2]],
            None => x,
        };
        warpbench_io::geometry::newton_inverse(
            |y| w.apply_raw(y),
            |y| w.jacobian_raw(y),
            x,
            start,
            (POINT_INVERSE_TOLERANCE_MM, POINT_INVERSE_MAX_STEPS),
        )
    }
}

#[cfg(test)]
// Exact equality is the law where the identity (outside) or the same code path must give the same bits.
#[allow(clippy::float_cmp)]
mod tests {
    use nalgebra::Matrix3;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    use super::*;
    use crate::spaces::{Fixed, Moving};

    type Pullback = SampledField<Moving, Fixed>;

    /// An oblique grid: rotated about two axes, anisotropic spacing, off the origin.
    fn oblique() -> Transform<Lps, Index> {
        let (s, c) = 0.5f64.sin_cos();
        let (s2, c2) = 0.3f64.sin_cos();
        let rz = Matrix3::new(c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0);
        let rx = Matrix3::new(1.0, 0.0, 0.0, 0.0, c2, -s2, 0.0, s2, c2);
        let scale = Matrix3::from_diagonal(&nalgebra::Vector3::new(1.5, 2.0, 3.0));
        Transform::from_linear_translation(rz * rx * scale, [-20.0, 7.5, 3.25])
    }

    fn lps_of(t: &Transform<Lps, Index>, c: [f64; 3]) -> [f64; 3] {
        t.apply_point(warpbench_io::geometry::Point3::from_array(c)).coords()
    }

    fn field_from(dims: [usize; 3], t: Transform<Lps, Index>, f: impl Fn([f64; 3]) -> [f64; 3]) -> Pullback {
        let mut d = Vec::new();
        for k in 0..dims[2] {
            for j in 0..dims[1] {
                for i in 0..dims[0] {
                    let v = f(lps_of(&t, [i as f64, j as f64, k as f64]));
                    d.push(v.map(|x| x as f32));
                }
            }
        }
        Pullback::new(dims, t, d).expect("field")
    }

    fn max_diff(a: [f64; 3], b: [f64; 3]) -> f64 {
        (0..3).map(|i| (a[i] - b[i]).abs()).fold(0.0, f64::max)
    }

    /// w(w⁻¹(x)) = x for a smooth field of a few mm on an oblique grid, at points x = w(y) for y inside, across the
    /// edge and outside the grid (ITK's field drops to zero at the edge, so some x near it have no preimage: x is
    /// taken as an image), checked against w itself, an independent evaluation.
    #[test]
    fn the_point_inverse_undoes_the_field() {
        let dims = [12, 10, 9];
        let t = oblique();
        let field =
            field_from(dims, t, |x| [3.0 * (x[1] / 9.0).sin(), -2.5 * (x[2] / 7.0).cos(), 1.5 * (x[0] / 11.0).sin()]);
        let inverse = PointInverse(&field);
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        for _ in 0..300 {
            let c = [rng.random_range(-3.0..14.0), rng.random_range(-3.0..12.0), rng.random_range(-3.0..11.0)];
            let x = field.apply_raw(lps_of(&t, c));
            let y = inverse.apply_raw(x);
            assert!(max_diff(field.apply_raw(y), x) < 1e-6, "w(w⁻¹(x)) from index {c:?}");
            assert!(inverse.residual_raw(x) < 1e-6);
        }
        let far = lps_of(&t, [100.0, 0.0, 0.0]);
        assert_eq!(inverse.apply_raw(far), far, "the identity far outside");
    }

    #[test]
    fn a_constant_field_shifts_inside_and_is_the_identity_outside() {
        let dims = [5, 4, 3];
        let t = oblique();
        let shift = [1.25, -3.5, 0.75];
        let field = field_from(dims, t, |_| shift);
        let shifted = |x: [f64; 3]| [x[0] + shift[0], x[1] + shift[1], x[2] + shift[2]];
        // Interior, the outer half voxel (clamped taps) and just inside the faces.
        for c in [[2.0, 1.5, 1.0], [-0.49, 0.0, 0.0], [4.49, 3.49, 2.49], [0.3, -0.5, 2.5], [4.5, 3.5, 2.5]] {
            let x = lps_of(&t, c);
            assert!(max_diff(field.apply_raw(x), shifted(x)) < 1e-12, "inside at index {c:?}");
        }
        // Outside the box of voxel edges: zero displacement (ITK).
        for c in [[-0.51, 1.0, 1.0], [2.0, 3.51, 1.0], [2.0, 1.0, -3.0], [100.0, 0.0, 0.0]] {
            let x = lps_of(&t, c);
            assert_eq!(field.apply_raw(x), x, "outside at index {c:?}");
            assert!(field.displacement_raw(x).is_none());
        }
        assert!((field.max_displacement_mm() - shift.iter().map(|v| v * v).sum::<f64>().sqrt()).abs() < 1e-6);
    }

    #[test]
    fn trilinear_interpolation_reproduces_a_linear_field_on_an_oblique_grid() {
        let dims = [6, 5, 4];
        let t = oblique();
        let a = Matrix3::new(0.02, -0.01, 0.03, 0.015, -0.02, 0.0, -0.01, 0.005, 0.025);
        let b = [2.0, -1.0, 0.5];
        let linear = move |x: [f64; 3]| {
            let v = a * nalgebra::Vector3::from(x);
            [v[0] + b[0], v[1] + b[1], v[2] + b[2]]
        };
        let field = field_from(dims, t, linear);
        let mut rng = ChaCha8Rng::seed_from_u64(16);
        let mut xs = Vec::new();
        for _ in 0..500 {
            // Between the voxel centres, where no tap is clamped.
            let c = std::array::from_fn(|ax| rng.random_range(0.0..(dims[ax] - 1) as f64));
            xs.push(lps_of(&t, c));
        }
        // The vectors are stored as f32 (|D| ≤ ~5 mm here): 1e-5 mm covers their rounding.
        let tolerance_mm = 1e-5;
        for x in &xs {
            let d = linear(*x);
            let expected = [x[0] + d[0], x[1] + d[1], x[2] + d[2]];
            assert!(max_diff(field.apply_raw(*x), expected) < tolerance_mm, "at {x:?}");
        }
        let mut batch = vec![[0.0; 3]; xs.len()];
        field.apply_batch_raw(&xs, &mut batch);
        for (x, o) in xs.iter().zip(&batch) {
            assert_eq!(*o, field.apply_raw(*x), "the batch kernel is the point kernel");
        }
    }

    #[test]
    fn weights_follow_the_grids_own_index_axes() {
        // A field that differs in every voxel, against the trilinear formula written out.
        let dims = [3, 4, 2];
        let t = oblique();
        let values: Vec<[f32; 3]> = (0..24).map(|n| [n as f32, (n * n % 7) as f32 - 3.0, 0.5 * n as f32]).collect();
        let field = Pullback::new(dims, t, values.clone()).expect("field");
        let at = |i: usize, j: usize, k: usize| values[i + 3 * (j + 4 * k)].map(f64::from);
        let (fx, fy, fz) = (0.25, 0.6, 0.9);
        let c = [1.0 + fx, 2.0 + fy, fz];
        let mut expected = [0.0; 3];
        for (i, wx) in [(1, 1.0 - fx), (2, fx)] {
            for (j, wy) in [(2, 1.0 - fy), (3, fy)] {
                for (k, wz) in [(0, 1.0 - fz), (1, fz)] {
                    let v = at(i, j, k);
                    for a in 0..3 {
                        expected[a] += wx * wy * wz * v[a];
                    }
                }
            }
        }
        let x = lps_of(&t, c);
        let d = field.displacement_raw(x).expect("inside");
        assert!(max_diff(d, expected) < 1e-9, "{d:?} vs {expected:?}");
        // In the outer half voxel along i the taps clamp to i = 2: the value at index (2, j, k) interpolated.
        let x = lps_of(&t, [2.4, 2.0 + fy, fz]);
        let edge = field.displacement_raw(x).expect("inside the edge half voxel");
        let mut want = [0.0; 3];
        for (j, wy) in [(2, 1.0 - fy), (3, fy)] {
            for (k, wz) in [(0, 1.0 - fz), (1, fz)] {
                let v = at(2, j, k);
                for a in 0..3 {
                    want[a] += wy * wz * v[a];
                }
            }
        }
        assert!(max_diff(edge, want) < 1e-9, "{edge:?} vs {want:?}");
    }

    #[test]
    fn a_single_voxel_axis_is_constant_along_it() {
        let t: Transform<Lps, Index> = Transform::from_scale_translation([2.0, 2.0, 2.0], [0.0, 0.0, 0.0]);
        let field = Pullback::new([2, 1, 1], t, vec![[0.0, 0.0, 0.0], [4.0, 2.0, 0.0]]).expect("field");
        let d = field.displacement_raw([1.0, 0.9, -0.9]).expect("inside");
        assert!(max_diff(d, [2.0, 1.0, 0.0]) < 1e-12, "{d:?}");
        assert!(field.displacement_raw([1.0, 1.1, 0.0]).is_none());
    }

    #[test]
    fn bad_fields_are_refused_with_the_reason() {
        let t = oblique();
        let e = Pullback::new([2, 2, 2], t, vec![[0.0; 3]; 7]).expect_err("count");
        assert!(e.to_string().contains("need 8 vectors, got 7"), "{e}");
        let e = Pullback::new([2, 0, 2], t, Vec::new()).expect_err("empty axis");
        assert!(e.to_string().contains("every axis"), "{e}");
        let flat: Transform<Lps, Index> = Transform::from_scale_translation([1.0, 0.0, 1.0], [0.0; 3]);
        let e = Pullback::new([2, 2, 2], flat, vec![[0.0; 3]; 8]).expect_err("singular");
        assert!(e.to_string().contains("singular"), "{e}");
        let mut nan = vec![[0.0; 3]; 8];
        nan[5][2] = f32::NAN;
        let e = Pullback::new([2, 2, 2], t, nan).expect_err("NaN");
        assert!(e.to_string().contains("voxel (1, 0, 1)"), "{e}");
        let e = Pullback::new([usize::MAX, 2, 2], t, Vec::new()).expect_err("overflow");
        assert!(e.to_string().contains("every axis"), "{e}");
    }
}
