//! Control textures: a pull-back u = d⁻¹ sampled on a regular grid in fixed space, the form in which
//! the renderer evaluates it (Brunet, Nowak & Gleicher 2006 §3.3; Rezk-Salama et al. 2001): one 3-D
//! texture lookup, with hardware trilinear filtering, replaces the evaluation of u per sample.
//!
//! # Layout and conventions
//!
//! A [`ControlGrid`] of n₀ × n₁ × n₂ texels covers a box [min, max] of fixed LPS space. **Texel
//! centres** follow the GPU convention: texel (a, b, c) sits at texture coordinate
//! ((a + ½)/n₀, (b + ½)/n₁, (c + ½)/n₂), that is at
//!
//! ```text
//! x_abc = min + ((a + ½)/n₀ · (max₀ − min₀), (b + ½)/n₁ · (max₁ − min₁), (c + ½)/n₂ · (max₂ − min₂))
//! ```
//!
//! so `tex = (x − min) / (max − min)` maps the box onto [0, 1]³ and a trilinear sampler with
//! clamp-to-edge addressing reproduces [`ControlTexture::lookup_raw`] exactly.
//!
//! Each texel stores the **displacement** u(x) − x in mm (moving LPS minus fixed LPS, both patient
//! space) as `[dx, dy, dz, 0]` f32, texels in x-fastest order: the buffer uploads as an
//! `Rgba32Float` 3-D texture as it is. Displacements, not absolute coordinates, keep precision when
//! the GPU falls back to 16-bit floats (absolute coordinates of 300 mm would be quantised to 0.25 mm).

use rayon::prelude::*;
use warpbench_io::geometry::Point3;

use crate::bspline::{HierarchicalBSpline, RegularGrid};
use crate::error::{Result, SolverError};
use crate::method::FittedWarp;
use crate::spaces::{Aabb, Fixed, Moving};
use crate::warp::{Parallelism, Warp};

/// Smallest and largest texel count per axis that [`ControlGrid::new`] accepts.
pub const MIN_TEXELS: usize = 2;
pub const MAX_TEXELS: usize = 256;

/// A regular grid of texel centres over a box in fixed space.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ControlGrid {
    pub dims: [usize; 3],
    pub domain: Aabb<Fixed>,
}

impl ControlGrid {
    /// A grid of `dims` texels over `domain`; each axis needs 2..=256 texels and a positive, finite extent.
    pub fn new(dims: [usize; 3], domain: Aabb<Fixed>) -> Result<Self> {
        if dims.iter().any(|&n| !(MIN_TEXELS..=MAX_TEXELS).contains(&n)) {
            return Err(SolverError::InvalidParameter(format!(
                "control grid dims {dims:?}: each axis needs {MIN_TEXELS} to {MAX_TEXELS} texels"
            )));
        }
        if !domain.is_valid() {
            return Err(SolverError::InvalidParameter(format!("control grid box {domain:?} is empty or not finite")));
        }
        Ok(Self { dims, domain })
    }

    /// An n³ grid over `domain`.
    pub fn cube(n: usize, domain: Aabb<Fixed>) -> Result<Self> {
        Self::new([n; 3], domain)
    }

    #[must_use]
    pub fn texel_count(&self) -> usize {
        self.dims.iter().product()
    }

    /// Texel pitch along each axis, in mm.
    #[must_use]
    pub fn pitch_mm(&self) -> [f64; 3] {
        let s = self.domain.size();
        std::array::from_fn(|a| s[a] / self.dims[a] as f64)
    }

    /// The fixed-space position of texel (a, b, c)'s centre.
    #[must_use]
    pub fn texel_centre(&self, abc: [usize; 3]) -> [f64; 3] {
        let (min, pitch) = (self.domain.min.coords(), self.pitch_mm());
        std::array::from_fn(|i| min[i] + (abc[i] as f64 + 0.5) * pitch[i])
    }

    /// Continuous texel coordinates of `x` (texel centres at integers).
    #[must_use]
    pub fn texel_coords(&self, x: [f64; 3]) -> [f64; 3] {
        let (min, pitch) = (self.domain.min.coords(), self.pitch_mm());
        std::array::from_fn(|i| (x[i] - min[i]) / pitch[i] - 0.5)
    }
}

/// A sampled pull-back: displacements u(x) − x at the texel centres of `grid`.
#[derive(Clone, Debug, PartialEq)]
pub struct ControlTexture {
    pub grid: ControlGrid,
    /// `[dx, dy, dz, 0]` in mm per texel, x fastest (see the module docs).
    pub texels: Vec<[f32; 4]>,
}

/// Samples the pull-back `moving_from_fixed` at every texel centre of `grid` into `out`
/// (`grid.texel_count()` texels). Runs on the calling thread or on rayon's pool, as `parallelism` says.
pub fn sample_pullback_into<W: Warp<Moving, Fixed> + ?Sized>(
    moving_from_fixed: &W,
    grid: &ControlGrid,
    parallelism: Parallelism,
    out: &mut [[f32; 4]],
) {
    assert_eq!(out.len(), grid.texel_count(), "output length must match the grid");
    let [nx, ny, _] = grid.dims;
    let row = |(j_k, texels): (usize, &mut [[f32; 4]])| {
        let (j, k) = (j_k % ny, j_k / ny);
        let mut xs = [[0.0; 3]; MAX_TEXELS];
        let mut us = [[0.0; 3]; MAX_TEXELS];
        for (i, x) in xs.iter_mut().enumerate().take(nx) {
            *x = grid.texel_centre([i, j, k]);
        }
        moving_from_fixed.apply_batch_raw(&xs[..nx], &mut us[..nx]);
        for ((t, x), u) in texels.iter_mut().zip(&xs).zip(&us) {
            *t = [(u[0] - x[0]) as f32, (u[1] - x[1]) as f32, (u[2] - x[2]) as f32, 0.0];
        }
    };
    match parallelism {
        Parallelism::Sequential => out.chunks_mut(nx).enumerate().for_each(row),
        Parallelism::Rayon => out.par_chunks_mut(nx).enumerate().for_each(row),
    }
}

impl ControlTexture {
    /// Samples the pull-back `moving_from_fixed` on `grid` texel by texel ([`sample_pullback_into`]), using rayon.
    pub fn sample<W: Warp<Moving, Fixed> + ?Sized>(moving_from_fixed: &W, grid: ControlGrid) -> Self {
        let mut texels = vec![[0.0; 4]; grid.texel_count()];
        sample_pullback_into(moving_from_fixed, &grid, Parallelism::Rayon, &mut texels);
        Self { grid, texels }
    }

    /// [`Self::sample`] for a pull-back as [`crate::Method::fit`] gives it: a hierarchical B-spline through
    /// [`Self::sample_bspline`] (the same texels to rounding, about 18× faster), the other kinds texel by texel.
    #[must_use]
    pub fn sample_fitted(moving_from_fixed: &FittedWarp<Moving, Fixed>, grid: ControlGrid) -> Self {
        if let FittedWarp::BSpline(spline) = moving_from_fixed
            && let Ok(texture) = Self::sample_bspline(spline, grid, Parallelism::Rayon)
        {
            return texture;
        }
        Self::sample(moving_from_fixed, grid)
    }

    /// The same texture for a hierarchical B-spline pull-back, through the lattice's separable grid
    /// sampler (one 1-D basis table per axis; about 18× faster than evaluating texel by texel).
    pub fn sample_bspline(
        moving_from_fixed: &HierarchicalBSpline<Moving, Fixed>,
        grid: ControlGrid,
        parallelism: Parallelism,
    ) -> Result<Self> {
        let (min, max) = (grid.domain.min.coords(), grid.domain.max.coords());
        let centres = RegularGrid::cell_centred(min, max, grid.dims);
        let mut displacement = vec![[0.0f64; 3]; grid.texel_count()];
        moving_from_fixed.lattice().sample_grid_into(&centres, false, &mut displacement, parallelism)?;
        let texels = displacement.iter().map(|d| [d[0] as f32, d[1] as f32, d[2] as f32, 0.0]).collect();
        Ok(Self { grid, texels })
    }

    /// The texels as plain f32s, ready for upload as an `Rgba32Float` 3-D texture.
    #[must_use]
    pub fn as_f32s(&self) -> &[f32] {
        self.texels.as_flattened()
    }

    /// u(x) by trilinear interpolation of the texels with clamp-to-edge addressing: the math of the
    /// GPU's filtered lookup, in f64.
    #[must_use]
    pub fn lookup_raw(&self, x: [f64; 3]) -> [f64; 3] {
        let t = self.grid.texel_coords(x);
        let mut base = [0usize; 3];
        let mut frac = [0.0f64; 3];
        for a in 0..3 {
            let n = self.grid.dims[a];
            let c = t[a].clamp(0.0, (n - 1) as f64);
            let i0 = (c.floor() as usize).min(n - 2);
            base[a] = i0;
            frac[a] = c - i0 as f64;
        }
        let [nx, ny, _] = self.grid.dims;
        let mut d = [0.0f64; 3];
        for dz in 0..2 {
            for dy in 0..2 {
                for dx in 0..2 {
                    let w = (if dx == 1 { frac[0] } else { 1.0 - frac[0] })
                        * (if dy == 1 { frac[1] } else { 1.0 - frac[1] })
                        * (if dz == 1 { frac[2] } else { 1.0 - frac[2] });
                    let idx = (base[0] + dx) + nx * ((base[1] + dy) + ny * (base[2] + dz));
                    let texel = self.texels[idx];
                    for (da, ta) in d.iter_mut().zip(texel) {
                        *da += w * f64::from(ta);
                    }
                }
            }
        }
        [x[0] + d[0], x[1] + d[1], x[2] + d[2]]
    }
}

/// The control texture is itself a pull-back (approximate, piecewise trilinear).
impl Warp<Moving, Fixed> for ControlTexture {
    fn apply_raw(&self, x: [f64; 3]) -> [f64; 3] {
        self.lookup_raw(x)
    }
}

/// Largest and RMS distance between the control texture's lookup and the exact pull-back, over
/// `probes` points inside the grid's box (the accuracy of the texture as a stand-in for u).
#[must_use]
pub fn texture_error_mm<W: Warp<Moving, Fixed> + ?Sized>(
    texture: &ControlTexture,
    moving_from_fixed: &W,
    probes: &[Point3<Fixed>],
) -> (f64, f64) {
    let (mut max, mut sum_sq) = (0.0f64, 0.0f64);
    for p in probes {
        let x = p.coords();
        let (a, b) = (texture.lookup_raw(x), moving_from_fixed.apply_raw(x));
        let e = ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt();
        max = max.max(e);
        sum_sq += e * e;
    }
    (max, (sum_sq / probes.len().max(1) as f64).sqrt())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// u(x) = A x + t: trilinear interpolation reproduces affine maps exactly inside the texel-centre hull.
    #[derive(Debug)]
    struct Affine;
    impl Warp<Moving, Fixed> for Affine {
        fn apply_raw(&self, x: [f64; 3]) -> [f64; 3] {
            [1.1 * x[0] + 0.2 * x[1] + 3.0, 0.9 * x[1] - 0.1 * x[2] - 2.0, x[2] + 0.05 * x[0] + 1.0]
        }
    }

    fn grid() -> ControlGrid {
        ControlGrid::new([8, 6, 5], Aabb::new(Point3::new(-100.0, -80.0, -50.0), Point3::new(100.0, 70.0, 60.0)))
            .expect("valid grid")
    }

    #[test]
    fn texel_centres_sit_half_a_pitch_inside_the_box() {
        let g = grid();
        let c0 = g.texel_centre([0, 0, 0]);
        let p = g.pitch_mm();
        assert!((c0[0] - (-100.0 + 0.5 * p[0])).abs() < 1e-12);
        let t = g.texel_coords(g.texel_centre([3, 2, 4]));
        assert!((t[0] - 3.0).abs() < 1e-12 && (t[1] - 2.0).abs() < 1e-12 && (t[2] - 4.0).abs() < 1e-12);
    }

    #[test]
    fn texels_hold_displacements_and_lookup_reproduces_affine_maps() {
        let g = grid();
        let tex = ControlTexture::sample(&Affine, g);
        let x = g.texel_centre([2, 3, 1]);
        let u = Affine.apply_raw(x);
        let t = tex.texels[2 + 8 * (3 + 6)]; // texel (2, 3, 1) of an 8 × 6 × 5 grid
        assert!(((u[0] - x[0]) as f32 - t[0]).abs() < 1e-4 && t[3] == 0.0);
        // Inside the hull of texel centres, trilinear interpolation of an affine map is exact
        // (up to the f32 storage of the displacements).
        let lo = g.texel_centre([0, 0, 0]);
        let hi = g.texel_centre([7, 5, 4]);
        for s in 0..50 {
            let f = f64::from(s) / 49.0;
            let x = [lo[0] + f * (hi[0] - lo[0]), lo[1] + (1.0 - f) * (hi[1] - lo[1]), lo[2] + f * f * (hi[2] - lo[2])];
            let (a, b) = (tex.lookup_raw(x), Affine.apply_raw(x));
            for i in 0..3 {
                assert!((a[i] - b[i]).abs() < 1e-4, "{x:?}: {a:?} vs {b:?}");
            }
        }
    }

    #[test]
    fn serial_and_parallel_sampling_agree() {
        let g = grid();
        let mut a = vec![[0.0; 4]; g.texel_count()];
        let mut b = a.clone();
        sample_pullback_into(&Affine, &g, Parallelism::Sequential, &mut a);
        sample_pullback_into(&Affine, &g, Parallelism::Rayon, &mut b);
        assert_eq!(a, b);
    }

    #[test]
    fn bspline_fast_path_equals_texel_by_texel_sampling() {
        use nalgebra::Matrix3;

        use crate::bspline::BSplineParams;
        use crate::linear::AffineWarp;
        let g = grid();
        let q: Vec<Point3<Fixed>> = (0..12)
            .map(|i| Point3::new(-90.0 + 15.0 * f64::from(i), 40.0 * f64::from(i % 3) - 60.0, 8.0 * f64::from(i % 5)))
            .collect();
        let p: Vec<Point3<Moving>> = q.iter().map(|y| Point3::from_array(Affine.apply_raw(y.coords()))).collect();
        let u = HierarchicalBSpline::fit(&q, &p, g.domain, &BSplineParams::default()).expect("fit");
        let fast = ControlTexture::sample_bspline(&u, g, Parallelism::Rayon).expect("sample");
        let mut slow = vec![[0.0; 4]; g.texel_count()];
        sample_pullback_into(&u, &g, Parallelism::Rayon, &mut slow);
        let worst = fast.as_f32s().iter().zip(slow.as_flattened()).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
        assert!(worst < 1e-4, "fast and texel-by-texel sampling differ by {worst} mm");
        // `sample_fitted` takes the fast path for the B-spline as `Method::fit` returns it, and samples the others.
        assert_eq!(ControlTexture::sample_fitted(&FittedWarp::BSpline(u), g).texels, fast.texels);
        let shear = Matrix3::new(1.0, 0.1, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0);
        let affine = FittedWarp::Linear(AffineWarp::new(shear, [1.0, -2.0, 0.5]));
        assert_eq!(ControlTexture::sample_fitted(&affine, g).texels, ControlTexture::sample(&affine, g).texels);
        assert!(ControlTexture::sample(&Affine, g).texels.iter().any(|t| t[0] != 0.0), "other warps still sample");
    }

    #[test]
    fn invalid_grids_are_rejected() {
        let b = Aabb::new(Point3::new(0.0, 0.0, 0.0), Point3::new(1.0, 1.0, 1.0));
        assert!(ControlGrid::new([1, 4, 4], b).is_err());
        assert!(ControlGrid::new([4, 4, 300], b).is_err());
        let flat = Aabb::new(Point3::new(0.0, 0.0, 0.0), Point3::new(1.0, 0.0, 1.0));
        assert!(ControlGrid::new([4, 4, 4], flat).is_err());
    }
}
