//! Scalar images placed in a patient space, for the intensity-based parts of the solver ([`crate::align`] and
//! [`crate::suggest`]): trilinear samples and their gradient at any point in mm, and a resolution pyramid.
//!
//! An [`Image<S>`] holds f32 values (the volume's rescale applied) on a grid with `space_from_index` (ITK's
//! convention: index 0 is the centre of the first voxel). Trilinear interpolation is
//!
//! v(x) = Σ_{c ∈ {0,1}³} Π_a w_a(c_a) · v[⌊ξ⌋ + c],  ξ = index_from_space · x,  w_a(0) = 1 − (ξ_a − ⌊ξ_a⌋), w_a(1) = ξ_a − ⌊ξ_a⌋,
//!
//! defined for ξ in [0, dims − 1] on every axis (no extrapolation: a point outside reads as `None`), and its
//! gradient in mm is ∇v(x) = (index_from_space)ᵀ · ∂v/∂ξ, the exact derivative of the interpolant inside a cell.

use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;
use warpbench_io::Volume;
use warpbench_io::geometry::{Index, Point3, Space, Transform};

use crate::warp::Parallelism;
use crate::{Result, SolverError};

/// How far (in voxels) outside the outer voxel centres a point still reads the edge value: rounding in the
/// index map, not extrapolation.
pub const EDGE_TOLERANCE_VOX: f64 = 1e-6;

/// The partial blends of a cell's eight corners (ordered by (c_k, c_j, c_i) bits) at fractions (fx, fy, fz): along i
/// (`x_jk`), then j (`y_k`); the value is y0 + fz (y1 − y0).
struct Lerps {
    x00: f64,
    x10: f64,
    x01: f64,
    x11: f64,
    y0: f64,
    y1: f64,
}

impl Lerps {
    #[inline]
    fn of(c: &[f64; 8], [fx, fy, _]: [f64; 3]) -> Self {
        let x00 = c[0] + fx * (c[1] - c[0]);
        let x10 = c[2] + fx * (c[3] - c[2]);
        let x01 = c[4] + fx * (c[5] - c[4]);
        let x11 = c[6] + fx * (c[7] - c[6]);
        Self { x00, x10, x01, x11, y0: x00 + fy * (x10 - x00), y1: x01 + fy * (x11 - x01) }
    }
}

/// A scalar image in space `S`.
#[derive(Clone, Debug)]
pub struct Image<S: Space> {
    dims: [usize; 3],
    values: Vec<f32>,
    space_from_index: Transform<S, Index>,
    /// The inverse map's linear part and translation, raw for the kernels.
    index_from_space_linear: Matrix3<f64>,
    index_from_space_translation: Vector3<f64>,
}

/// A chunk of each of three images, x, y and z, as [`Image::central_gradient`] fills them.
type Chunks<'c> = ((&'c mut [f32], &'c mut [f32]), &'c mut [f32]);

/// A mask's values on its grid and the map to its continuous index from another image's voxel index: what
/// [`Image::keep_inside`] reads, without the image's space, so that its loop is compiled here once.
struct MaskGrid<'m> {
    dims: [usize; 3],
    values: &'m [f32],
    from_index: [[f64; 4]; 3],
}

impl MaskGrid<'_> {
    /// Whether voxel (i, j, k) of the other image is inside: the mask voxel nearest to it holds a number other
    /// than 0.
    fn keeps(&self, ijk: [usize; 3]) -> bool {
        let [i, j, k] = ijk.map(|c| c as f64);
        let mut at = [0usize; 3];
        for (a, row) in self.from_index.iter().enumerate() {
            let c = (row[0] * i + row[1] * j + row[2] * k + row[3]).round();
            if !(c >= 0.0 && c < self.dims[a] as f64) {
                return false;
            }
            at[a] = c as usize;
        }
        let v = self.values[at[0] + self.dims[0] * (at[1] + self.dims[1] * at[2])];
        v.is_finite() && v != 0.0
    }

    /// Sets to NaN the voxels of `values` (on a grid of `dims`) outside the mask; returns how many keep theirs.
    fn clear_outside(&self, values: &mut [f32], dims: [usize; 3], parallelism: Parallelism) -> usize {
        let [nx, ny, _] = dims;
        let clear = |(c, block): (usize, &mut [f32])| {
            let mut kept = 0usize;
            for (o, v) in block.iter_mut().enumerate() {
                let o = c * CHUNK + o;
                if self.keeps([o % nx, (o / nx) % ny, o / (nx * ny)]) {
                    kept += 1;
                } else {
                    *v = f32::NAN;
                }
            }
            kept
        };
        match parallelism {
            Parallelism::Sequential => values.chunks_mut(CHUNK).enumerate().map(clear).sum(),
            Parallelism::Rayon => values.par_chunks_mut(CHUNK).enumerate().map(clear).sum(),
        }
    }
}

/// Values per task of [`Image::from_volume`]'s conversion and [`Image::value_range`].
const CHUNK: usize = 1 << 16;

/// Reserves `n` values or says why not.
fn try_vec(n: usize, what: &str) -> Result<Vec<f32>> {
    let mut v = Vec::new();
    v.try_reserve_exact(n).map_err(|_| SolverError::Image(format!("no memory for {what} ({n} values)")))?;
    Ok(v)
}

impl<S: Space> Image<S> {
    /// An image of `values` (i fastest) on `dims` placed by `space_from_index`.
    ///
    /// # Errors
    /// [`SolverError::Image`] when the counts disagree, a side has fewer than 2 voxels or the geometry is singular.
    pub fn new(dims: [usize; 3], values: Vec<f32>, space_from_index: Transform<S, Index>) -> Result<Self> {
        let n = dims.iter().try_fold(1usize, |acc, &d| acc.checked_mul(d));
        if n != Some(values.len()) {
            return Err(SolverError::Image(format!("{} values for a {dims:?} grid", values.len())));
        }
        if dims.iter().any(|&d| d < 2) {
            return Err(SolverError::Image(format!(
                "the {} image is {}×{}×{} voxels: intensity matching needs at least 2 along every axis",
                S::NAME,
                dims[0],
                dims[1],
                dims[2]
            )));
        }
        let index_from_space =
            space_from_index.inverse().filter(|_| space_from_index.is_valid_affine()).ok_or_else(|| {
                SolverError::Image(format!("the {} image's voxel-to-patient matrix is singular", S::NAME))
            })?;
        Ok(Self {
            dims,
            values,
            space_from_index,
            index_from_space_linear: index_from_space.linear(),
            index_from_space_translation: Vector3::from(index_from_space.translation()),
        })
    }

    /// The volume's samples as f32 with its rescale applied, in space `S` (the volume's LPS, tagged), converted on
    /// the threads `parallelism` allows.
    ///
    /// # Errors
    /// As [`Self::new`], or when there is no memory for the copy.
    pub fn from_volume(volume: &Volume, parallelism: Parallelism) -> Result<Self> {
        let n = volume.data.len();
        let mut values = try_vec(n, "the image's f32 copy")?;
        let rescale = volume.rescale;
        let (slope, intercept) = if rescale.applied { (1.0, 0.0) } else { (rescale.slope, rescale.intercept) };
        // Within the reserved capacity: no reallocation. Converted in parallel blocks (each value on its own).
        values.resize(n, 0.0);
        let convert = |(c, block): (usize, &mut [f32])| {
            for (o, v) in block.iter_mut().enumerate() {
                *v = (slope * volume.data.get_f64(c * CHUNK + o) + intercept) as f32;
            }
        };
        match parallelism {
            Parallelism::Sequential => values.chunks_mut(CHUNK).enumerate().for_each(convert),
            Parallelism::Rayon => values.par_chunks_mut(CHUNK).enumerate().for_each(convert),
        }
        Self::new(volume.dims, values, Transform::from_matrix(*volume.lps_from_index.matrix()))
    }

    #[must_use]
    pub fn dims(&self) -> [usize; 3] {
        self.dims
    }

    /// The values, i fastest.
    #[must_use]
    pub fn values(&self) -> &[f32] {
        &self.values
    }

    #[must_use]
    pub fn space_from_index(&self) -> &Transform<S, Index> {
        &self.space_from_index
    }

    /// The voxel spacing along i, j and k, in mm.
    #[must_use]
    pub fn spacing_mm(&self) -> [f64; 3] {
        let l = self.space_from_index.linear();
        std::array::from_fn(|a| l.column(a).norm())
    }

    /// The centre of voxel (i, j, k), in mm.
    #[must_use]
    pub fn voxel_point(&self, i: usize, j: usize, k: usize) -> [f64; 3] {
        self.space_from_index.apply_point(Point3::new(i as f64, j as f64, k as f64)).coords()
    }

    /// The continuous index of `x_mm`.
    #[must_use]
    pub fn index_of(&self, x_mm: [f64; 3]) -> [f64; 3] {
        let xi = self.index_from_space_linear * Vector3::from(x_mm) + self.index_from_space_translation;
        [xi[0], xi[1], xi[2]]
    }

    /// ∂index/∂mm: the linear part of [`Self::index_of`].
    #[must_use]
    pub fn index_from_space_linear(&self) -> Matrix3<f64> {
        self.index_from_space_linear
    }

    /// The value at voxel (i, j, k).
    #[must_use]
    pub fn at(&self, i: usize, j: usize, k: usize) -> f32 {
        self.values[i + self.dims[0] * (j + self.dims[1] * k)]
    }

    /// The lower corner of the cell holding continuous index `xi` and the fractions in it; `None` outside
    /// [0, dims − 1].
    #[inline]
    fn cell(&self, xi: [f64; 3]) -> Option<([usize; 3], [f64; 3])> {
        let mut base = [0usize; 3];
        let mut frac = [0.0; 3];
        for a in 0..3 {
            let top = (self.dims[a] - 1) as f64;
            // A point on the outer voxel centres' plane, up to rounding in the index map, is inside.
            if !(xi[a] >= -EDGE_TOLERANCE_VOX && xi[a] <= top + EDGE_TOLERANCE_VOX) {
                return None;
            }
            let x = xi[a].clamp(0.0, top);
            // The last voxel's plane belongs to the cell below it, so that base + 1 stays inside.
            let b = (x.floor() as usize).min(self.dims[a] - 2);
            base[a] = b;
            frac[a] = x - b as f64;
        }
        Some((base, frac))
    }

    /// The eight corner values of the cell at `base`, ordered by (c_k, c_j, c_i) bits.
    #[inline]
    fn corners(&self, base: [usize; 3]) -> [f64; 8] {
        let [nx, ny, _] = self.dims;
        let o = base[0] + nx * (base[1] + ny * base[2]);
        let (sj, sk) = (nx, nx * ny);
        let v = &self.values;
        [
            f64::from(v[o]),
            f64::from(v[o + 1]),
            f64::from(v[o + sj]),
            f64::from(v[o + sj + 1]),
            f64::from(v[o + sk]),
            f64::from(v[o + sk + 1]),
            f64::from(v[o + sk + sj]),
            f64::from(v[o + sk + sj + 1]),
        ]
    }

    /// The trilinear value at continuous index `xi`, or `None` outside the grid.
    #[must_use]
    #[inline]
    pub fn sample_index(&self, xi: [f64; 3]) -> Option<f64> {
        let (base, f) = self.cell(xi)?;
        let l = Lerps::of(&self.corners(base), f);
        Some(l.y0 + f[2] * (l.y1 - l.y0))
    }

    /// The trilinear value at `x_mm`, or `None` outside the grid.
    #[must_use]
    #[inline]
    pub fn sample(&self, x_mm: [f64; 3]) -> Option<f64> {
        self.sample_index(self.index_of(x_mm))
    }

    /// The trilinear value at `x_mm` and its gradient in mm⁻¹ (value units per mm), or `None` outside the grid.
    #[must_use]
    #[inline]
    pub fn sample_with_gradient(&self, x_mm: [f64; 3]) -> Option<(f64, [f64; 3])> {
        let (base, f) = self.cell(self.index_of(x_mm))?;
        let [_, fy, fz] = f;
        let c = self.corners(base);
        let Lerps { x00, x10, x01, x11, y0, y1 } = Lerps::of(&c, f);
        let value = y0 + fz * (y1 - y0);
        // ∂/∂ξ_i: the i-differences blended over j and k; likewise for j and k.
        let di = {
            let d00 = c[1] - c[0];
            let d10 = c[3] - c[2];
            let d01 = c[5] - c[4];
            let d11 = c[7] - c[6];
            let e0 = d00 + fy * (d10 - d00);
            let e1 = d01 + fy * (d11 - d01);
            e0 + fz * (e1 - e0)
        };
        let dj = (x10 - x00) + fz * ((x11 - x01) - (x10 - x00));
        let dk = y1 - y0;
        let g = self.index_from_space_linear.transpose() * Vector3::new(di, dj, dk);
        Some((value, [g[0], g[1], g[2]]))
    }

    /// The image's gradient in mm⁻¹ along the space's axes, one image per axis on the same grid: central differences
    /// of the voxels (one-sided on the box's faces), NaN where a difference needs a voxel that has no value. Sampled
    /// trilinearly, it is a gradient that is continuous in position, where the trilinear interpolant's own gradient
    /// jumps on every cell face; its trilinear derivatives are then the Hessian.
    ///
    /// # Errors
    /// [`SolverError::Image`] when there is no memory for the three images.
    pub fn central_gradient(&self, parallelism: Parallelism) -> Result<[Self; 3]> {
        let [nx, ny, _] = self.dims;
        let n = self.values.len();
        let strides = [1, nx, nx * ny];
        // ∂/∂ξ_a at voxel o along index axis a.
        let along = |o: usize, a: usize| -> f64 {
            let i = [o % nx, (o / nx) % ny, o / (nx * ny)][a];
            let (before, after) = (i > 0, i + 1 < self.dims[a]);
            let (lo, hi) = (if before { o - strides[a] } else { o }, if after { o + strides[a] } else { o });
            (f64::from(self.values[hi]) - f64::from(self.values[lo])) / f64::from(u8::from(before) + u8::from(after))
        };
        let a = self.index_from_space_linear.transpose();
        let mut images = [
            try_vec(n, "the image's gradient")?,
            try_vec(n, "the image's gradient")?,
            try_vec(n, "the image's gradient")?,
        ];
        for values in &mut images {
            values.resize(n, 0.0);
        }
        // Each voxel's gradient once, written to the three images: a chunk of each, x, y and z.
        let fill = |(chunk, ((x, y), z)): (usize, Chunks<'_>)| {
            for k in 0..x.len() {
                let o = chunk * CHUNK + k;
                let g = a * Vector3::new(along(o, 0), along(o, 1), along(o, 2));
                (x[k], y[k], z[k]) = (g[0] as f32, g[1] as f32, g[2] as f32);
            }
        };
        let [x, y, z] = &mut images;
        match parallelism {
            Parallelism::Sequential => {
                x.chunks_mut(CHUNK).zip(y.chunks_mut(CHUNK)).zip(z.chunks_mut(CHUNK)).enumerate().for_each(fill);
            }
            Parallelism::Rayon => {
                x.par_chunks_mut(CHUNK)
                    .zip(y.par_chunks_mut(CHUNK))
                    .zip(z.par_chunks_mut(CHUNK))
                    .enumerate()
                    .for_each(fill);
            }
        }
        let [x, y, z] = images;
        let image = |values| Self::new(self.dims, values, self.space_from_index);
        Ok([image(x)?, image(y)?, image(z)?])
    }

    /// The smallest and largest finite value, or `None` when none is finite; read on the threads `parallelism`
    /// allows.
    #[must_use]
    pub fn value_range(&self, parallelism: Parallelism) -> Option<(f64, f64)> {
        let range = |block: &[f32]| {
            block
                .iter()
                .filter(|v| v.is_finite())
                .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &v| (lo.min(v), hi.max(v)))
        };
        let both = |a: (f32, f32), b: (f32, f32)| (a.0.min(b.0), a.1.max(b.1));
        let empty = (f32::INFINITY, f32::NEG_INFINITY);
        // The smallest and the largest do not depend on the order the blocks are combined in.
        let (lo, hi) = match parallelism {
            Parallelism::Sequential => range(&self.values),
            Parallelism::Rayon => self.values.par_chunks(CHUNK).map(range).reduce(|| empty, both),
        };
        (lo <= hi).then_some((f64::from(lo), f64::from(hi)))
    }

    /// The image shrunk by `factor` along every axis whose size allows it: each new voxel is the mean of a
    /// `factor`-wide block (a box filter, then subsampling), placed at the block's centre, so that the shrunk image
    /// covers the same box in mm. An axis with fewer than 2 · `factor` voxels keeps its size. The new slices are
    /// computed on the threads `parallelism` allows.
    ///
    /// # Errors
    /// When there is no memory for the result.
    pub fn shrink(&self, factor: usize, parallelism: Parallelism) -> Result<Self> {
        if factor <= 1 {
            return Ok(self.clone());
        }
        let f: [usize; 3] = std::array::from_fn(|a| if self.dims[a] >= 2 * factor { factor } else { 1 });
        let dims: [usize; 3] = std::array::from_fn(|a| self.dims[a] / f[a]);
        let n = dims[0] * dims[1] * dims[2];
        let mut values = try_vec(n, "a shrunk image")?;
        values.resize(n, 0.0);
        // One new slice (constant k) per task; each voxel is its own block's mean.
        let slice_of = |(k, slice): (usize, &mut [f32])| {
            for (n, out) in slice.iter_mut().enumerate() {
                let (i, j) = (n % dims[0], n / dims[0]);
                let mut sum = 0.0f64;
                let mut count = 0u32;
                for dk in 0..f[2] {
                    for dj in 0..f[1] {
                        for di in 0..f[0] {
                            let v = self.at(i * f[0] + di, j * f[1] + dj, k * f[2] + dk);
                            if v.is_finite() {
                                sum += f64::from(v);
                                count += 1;
                            }
                        }
                    }
                }
                *out = if count == 0 { f32::NAN } else { (sum / f64::from(count)) as f32 };
            }
        };
        let plane = dims[0] * dims[1];
        match parallelism {
            Parallelism::Sequential => values.chunks_mut(plane).enumerate().for_each(slice_of),
            Parallelism::Rayon => values.par_chunks_mut(plane).enumerate().for_each(slice_of),
        }
        // New index i' sits at old index f·i' + (f − 1)/2.
        let scale = Matrix3::from_diagonal(&Vector3::new(f[0] as f64, f[1] as f64, f[2] as f64));
        let shift: [f64; 3] = std::array::from_fn(|a| (f[a] as f64 - 1.0) / 2.0);
        let old_from_new: Transform<Index, Index> = Transform::from_linear_translation(scale, shift);
        Self::new(dims, values, self.space_from_index * old_from_new)
    }

    /// This image with no value (NaN) at every voxel whose centre is outside `mask`: the mask's voxel nearest to the
    /// centre (its own grid, anywhere in the same space) holds 0 or no number, or there is no mask voxel there. The
    /// second value is how many voxels keep theirs.
    ///
    /// # Errors
    /// When there is no memory for the copy.
    pub fn keep_inside(&self, mask: &Image<S>, parallelism: Parallelism) -> Result<(Self, usize)> {
        let mut values = try_vec(self.values.len(), "the masked image")?;
        values.extend_from_slice(&self.values);
        // The mask's continuous index of this image's voxel (i, j, k), one affine map: mask index ← space ← index.
        let space_from_index = self.space_from_index.matrix();
        let linear = mask.index_from_space_linear * space_from_index.fixed_view::<3, 3>(0, 0);
        let shift = mask.index_from_space_linear * space_from_index.fixed_view::<3, 1>(0, 3)
            + mask.index_from_space_translation;
        let mask_from_index: [[f64; 4]; 3] =
            std::array::from_fn(|r| [linear[(r, 0)], linear[(r, 1)], linear[(r, 2)], shift[r]]);
        let grid = MaskGrid { dims: mask.dims, values: &mask.values, from_index: mask_from_index };
        let kept = grid.clear_outside(&mut values, self.dims, parallelism);
        Ok((Self::new(self.dims, values, self.space_from_index)?, kept))
    }

    /// The same image tagged as another space (both are the same LPS millimetres).
    #[must_use]
    pub fn retag<T: Space>(self) -> Image<T> {
        Image {
            dims: self.dims,
            values: self.values,
            space_from_index: Transform::from_matrix(*self.space_from_index.matrix()),
            index_from_space_linear: self.index_from_space_linear,
            index_from_space_translation: self.index_from_space_translation,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::spaces::Fixed;

    #[test]
    fn a_mask_on_its_own_grid_keeps_the_voxels_nearest_its_nonzero_ones() {
        // The image: 10³ voxels of 1 mm from the origin. The mask: 5³ voxels of 2 mm, one of them 1 and one NaN.
        let values: Vec<f32> = (0..1000).map(|v| v as f32).collect();
        let image =
            Image::<Fixed>::new([10; 3], values, Transform::from_scale_translation([1.0; 3], [0.0; 3])).expect("image");
        let mut mask_values = vec![0.0f32; 125];
        mask_values[2 + 5 * (2 + 5 * 2)] = 1.0;
        mask_values[4 + 5 * (4 + 5 * 4)] = f32::NAN;
        let mask = Image::<Fixed>::new([5; 3], mask_values, Transform::from_scale_translation([2.0; 3], [0.0; 3]))
            .expect("mask");
        let (masked, kept) = image.keep_inside(&mask, Parallelism::Rayon).expect("masked");
        // Mask voxel 2 is nearest to the millimetres [3, 5) along each axis: image voxels 3 and 4.
        assert_eq!(kept, 8);
        for k in 0..10 {
            for j in 0..10 {
                for i in 0..10 {
                    let v = masked.at(i, j, k);
                    if [i, j, k].iter().all(|&c| c == 3 || c == 4) {
                        assert_eq!(v.to_bits(), image.at(i, j, k).to_bits());
                    } else {
                        assert!(v.is_nan(), "voxel {i} {j} {k}: {v}");
                    }
                }
            }
        }
        let (sequential, _) = image.keep_inside(&mask, Parallelism::Sequential).expect("masked");
        assert_eq!(
            sequential.values().iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
            masked.values().iter().map(|v| v.to_bits()).collect::<Vec<_>>()
        );
    }

    /// A linear function of the index on an oblique grid: trilinear interpolation reproduces it, and its gradient
    /// in mm is (linearᵀ)⁻¹ applied to the index gradient.
    #[test]
    fn trilinear_reproduces_a_linear_function_and_its_gradient_in_mm() {
        let dims = [5, 6, 7];
        let a = [0.5, -1.25, 2.0];
        let values: Vec<f32> = (0..dims[2])
            .flat_map(|k| (0..dims[1]).flat_map(move |j| (0..dims[0]).map(move |i| (i, j, k))))
            .map(|(i, j, k)| (a[0] * i as f64 + a[1] * j as f64 + a[2] * k as f64) as f32)
            .collect();
        let rot = nalgebra::Rotation3::from_euler_angles(0.3, -0.2, 0.5).into_inner();
        let linear = rot * Matrix3::from_diagonal(&Vector3::new(1.5, 0.8, 2.5));
        let image: Image<Fixed> =
            Image::new(dims, values, Transform::from_linear_translation(linear, [10.0, -4.0, 3.0]))
                .expect("in the test");
        let xi = [1.3, 2.7, 5.9];
        let x = image.space_from_index.apply_point(Point3::new(xi[0], xi[1], xi[2])).coords();
        let (v, g) = image.sample_with_gradient(x).expect("in the test");
        let expect = a[0] * xi[0] + a[1] * xi[1] + a[2] * xi[2];
        assert!((v - expect).abs() < 1e-4, "{v} vs {expect}");
        assert!((image.sample(x).expect("in the test") - v).abs() < 1e-12);
        // v(x) = aᵀ · index_from_space · x, so ∇v = (index_from_space linear)ᵀ a.
        let expect_g = linear.try_inverse().expect("in the test").transpose() * Vector3::from(a);
        for c in 0..3 {
            assert!((g[c] - expect_g[c]).abs() < 1e-6, "{g:?} vs {expect_g:?}");
        }
        // Outside the grid: nothing.
        let outside = image.space_from_index.apply_point(Point3::new(-0.01, 2.0, 2.0)).coords();
        assert!(image.sample(outside).is_none());
        // The last voxel plane is inside.
        let last = image.space_from_index.apply_point(Point3::new(4.0, 5.0, 6.0)).coords();
        assert!((image.sample(last).expect("in the test") - f64::from(image.at(4, 5, 6))).abs() < 1e-4);
    }

    /// The central-difference gradient of a quadratic in mm on an oblique, anisotropic grid: exact at every voxel
    /// off the faces (central differences are exact for quadratics), exact on the faces for a linear function (the
    /// one-sided differences there), and NaN beside a voxel without a value.
    #[test]
    fn the_central_gradient_is_exact_for_quadratics_inside_and_linears_on_the_faces() {
        let dims = [5, 4, 6];
        let linear = Matrix3::new(0.9, -0.3, 0.1, 0.2, 1.4, 0.0, -0.1, 0.2, 2.1);
        let place = Transform::<Fixed, Index>::from_linear_translation(linear, [3.0, -2.0, 1.0]);
        let c = [0.7, -1.3, 0.4];
        let at = |o: usize| {
            let index = [o % dims[0], (o / dims[0]) % dims[1], o / (dims[0] * dims[1])];
            (index, place.apply_point(Point3::from_array(index.map(|v| v as f64))).coords())
        };
        let n = dims.iter().product::<usize>();
        for quadratic in [false, true] {
            // f(x) = c·x (+ x₀ x₁ / 4): its gradient c (+ (x₁, x₀, 0) / 4).
            let f =
                |x: [f64; 3]| c[0] * x[0] + c[1] * x[1] + c[2] * x[2] + if quadratic { x[0] * x[1] / 4.0 } else { 0.0 };
            let values = (0..n).map(|o| f(at(o).1) as f32).collect();
            let image = Image::<Fixed>::new(dims, values, place).expect("image");
            let gradient = image.central_gradient(Parallelism::Sequential).expect("gradient");
            for o in 0..n {
                let (index, x) = at(o);
                let face = (0..3).any(|a| index[a] == 0 || index[a] == dims[a] - 1);
                if quadratic && face {
                    continue;
                }
                let want = if quadratic { [c[0] + x[1] / 4.0, c[1] + x[0] / 4.0, c[2]] } else { c };
                for a in 0..3 {
                    let got = f64::from(gradient[a].values()[o]);
                    // f32 values of size ~10 differenced over ~1 mm: rounding ~1e-5.
                    assert!((got - want[a]).abs() < 1e-4, "{index:?} axis {a}: {got} vs {}", want[a]);
                }
            }
        }
        let mut values = vec![1.0f32; n];
        values[1 + dims[0] * (1 + dims[1])] = f32::NAN;
        let image = Image::<Fixed>::new(dims, values, place).expect("image");
        let gradient = image.central_gradient(Parallelism::Rayon).expect("gradient");
        assert!(gradient[0].values()[2 + dims[0] * (1 + dims[1])].is_nan(), "beside the voxel without a value");
        assert!(gradient[0].values()[3 + dims[0] * (3 + 3 * dims[1])].is_finite());
    }

    /// Shrinking keeps the box: a linear function keeps its values at the same mm positions.
    /// The rescale is applied (CT's slope and intercept), values beyond a block of the conversion land in place,
    /// and rayon's pool gives the same image as the calling thread.
    #[test]
    fn a_volume_becomes_its_rescaled_values_on_either_parallelism() {
        let dims = [300, 250, 2];
        let n = dims[0] * dims[1] * dims[2];
        assert!(n > 2 * CHUNK, "the conversion crosses blocks");
        let stored: Vec<i16> = (0..n).map(|i| (i % 4001) as i16 - 1000).collect();
        let mut volume = Volume::new(
            std::path::Path::new("test.nii"),
            dims,
            warpbench_io::volume::VoxelData::I16(stored.clone()),
            Transform::from_scale_translation([0.5, 0.7, 2.0], [-10.0, 5.0, 0.0]),
            warpbench_io::volume::GeometrySource::NiftiPixdim,
        )
        .expect("in the test");
        volume.rescale = warpbench_io::volume::Rescale { slope: 2.0, intercept: -1024.0, applied: false };
        let sequential: Image<Fixed> = Image::from_volume(&volume, Parallelism::Sequential).expect("in the test");
        let pooled: Image<Fixed> = Image::from_volume(&volume, Parallelism::Rayon).expect("in the test");
        for (i, &v) in stored.iter().enumerate() {
            let want = (2.0 * f64::from(v) - 1024.0) as f32;
            assert_eq!(sequential.values()[i].to_bits(), want.to_bits(), "value {i}");
            assert_eq!(pooled.values()[i].to_bits(), want.to_bits(), "value {i}");
        }
        // Stored −1000 to 3000: −3024 to 4976 after the rescale, read alike either way.
        assert_eq!(sequential.value_range(Parallelism::Sequential), Some((-3024.0, 4976.0)));
        assert_eq!(pooled.value_range(Parallelism::Rayon), Some((-3024.0, 4976.0)));
    }

    #[test]
    fn shrinking_keeps_a_linear_function_in_place() {
        let dims = [8, 9, 10];
        let values: Vec<f32> = (0..dims[2])
            .flat_map(|k| (0..dims[1]).flat_map(move |j| (0..dims[0]).map(move |i| (i, j, k))))
            .map(|(i, j, k)| (3.0 * i as f64 - 2.0 * j as f64 + 0.5 * k as f64) as f32)
            .collect();
        let image: Image<Fixed> =
            Image::new(dims, values, Transform::from_scale_translation([1.0, 2.0, 0.5], [1.0, 2.0, 3.0]))
                .expect("in the test");
        let small = image.shrink(2, Parallelism::Sequential).expect("in the test");
        assert_eq!(small.dims(), [4, 4, 5]);
        for (i, j, k) in [(0, 0, 0), (3, 3, 4), (1, 2, 3)] {
            let x = small.voxel_point(i, j, k);
            let want = image.sample(x).expect("in the test");
            assert!((f64::from(small.at(i, j, k)) - want).abs() < 1e-4, "{i} {j} {k}");
        }
        // On rayon's pool each voxel is computed the same way: the same values to the bit.
        let pooled = image.shrink(2, Parallelism::Rayon).expect("in the test");
        assert_eq!(pooled.dims(), small.dims());
        assert!(pooled.values().iter().zip(small.values()).all(|(a, b)| a.to_bits() == b.to_bits()));
    }
}
