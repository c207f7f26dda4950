//! Hierarchical (multilevel) cubic B-spline warps: scattered-data approximation of a displacement field
//! (Lee, Wolberg & Shin 1997, "Scattered Data Interpolation with Multilevel B-Splines", IEEE TVCG 3(3)),
//! as used for landmark deformations by Brunet, Nowak & Gleicher 2006 §3.3 and §5.1.
//!
//! # The function
//!
//! A control lattice Φ of (m+3)×(n+3)×(o+3) coefficients φ_{ijk} ∈ ℝ³ is overlaid on a box Ω
//! (the *domain*) cut into m×n×o cells of edge h (per axis). In cell units u = (x − Ω.min)/h the
//! displacement is the tensor-product cubic B-spline (Lee et al. eq. 1, in 3-D)
//!
//! D(x) = Σ_{a=0}^{3} Σ_{b=0}^{3} Σ_{c=0}^{3} B_a(s) B_b(t) B_c(r) φ_{(i+a)(j+b)(k+c)},
//! with i = ⌊u_x⌋ − 1, s = u_x − ⌊u_x⌋ (likewise j, t and k, r),
//!
//! and the uniform cubic B-spline basis ([`basis`])
//! B₀(t) = (1−t)³/6, B₁(t) = (3t³ − 6t² + 4)/6, B₂(t) = (−3t³ + 3t² + 3t + 1)/6, B₃(t) = t³/6.
//! The paper's indices i ∈ [−1, m+1] are stored from 0, so storage index = paper index + 1: the lattice
//! has the usual 3 extra control points per axis. The warp is w(x) = x + D(x): the identity when D = 0.
//!
//! **Outside the domain** every coordinate is clamped to Ω before evaluation: D(x) = D(clamp_Ω(x)).
//! The displacement is continuous everywhere and constant along each axis beyond the box, so a far point
//! never sees the cubic's polynomial growth and nothing overflows; the Jacobian there is the identity
//! in the clamped axes. Landmarks outside Ω are fitted at their clamped positions, which is consistent
//! with this evaluation rule (two landmarks that clamp to one point conflict, and are approximated).
//!
//! # The BA algorithm (Lee et al. §3, eqs. 3–5)
//!
//! For a data point (x_c, z_c) with weights w_{abc} = B_a(s)B_b(t)B_c(r), the control value that
//! reproduces z_c with the smallest norm is φ_c = w_c z_c / Σ_{abc} w_{abc}²; a control point influenced
//! by several data points takes the weighted mean φ = Σ_c w_c² φ_c / Σ_c w_c² (zero when no data point
//! touches it). Here Σ_{abc} w² = (Σ_a B_a(s)²)(Σ_b B_b(t)²)(Σ_c B_c(r)²) factorises per axis, which makes
//! the algorithm separable on regular grids ([`HierarchicalBSpline::fit_grid_raw`]).
//!
//! # The multilevel hierarchy (Lee et al. §4)
//!
//! Level ℓ has 2^ℓ times the cells of level 0 ([`BSplineParams::coarsest`]); it is fitted by BA to the
//! residuals Δ^ℓ z_c = z_c − Σ_{ℓ'<ℓ} f_{ℓ'}(x_c) of the coarser levels, and fitting stops once every
//! residual is below [`BSplineParams::tolerance_mm`]. The levels are not kept apart: B-spline
//! refinement (Lee et al. §4.2) rewrites level ℓ's lattice exactly on level ℓ+1's, using the
//! two-scale relation of the cubic B-spline, per axis
//!
//! ψ_{2i} = (φ_{i−1} + 6φ_i + φ_{i+1}) / 8,   ψ_{2i+1} = (φ_i + φ_{i+1}) / 2,
//!
//! so the fitted warp is **one** lattice at the finest level used ([`ControlLattice::refine`] leaves the
//! field unchanged; a tested law). Evaluation costs 64 taps whatever the number of levels, and a shader
//! gets one coefficient array ([`ControlLattice::coefficients_f32`]).
//!
//! **Initial approximation.** Before level 0, an affine least-squares fit D₀(x) = A x + b of the
//! displacements is written into the coarsest lattice exactly (cubic B-splines reproduce linear
//! functions: φ_j = D₀(knot_j)), and the hierarchy fits what remains, as in the `mba` library's linear
//! initial approximation. Plain BA shrinks towards zero away from the data, so without this step a
//! constant or linear displacement would not be reproduced; with it both are reproduced exactly
//! everywhere in Ω (tested). A is a pseudo-inverse solution, so on scattered samples
//! ([`HierarchicalBSpline::fit_displacements_raw`]) 1–3 points or coplanar ones give a translation or an in-plane
//! affine map; landmark pairs ([`HierarchicalBSpline::fit`]) are refused in those cases, as for every method
//! ([`crate::pairs`]): the out-of-plane part would be arbitrary.
//!
//! # Two tiers
//!
//! [`HierarchicalBSpline::fit`] (and [`HierarchicalBSpline::fit_forward`] /
//! [`HierarchicalBSpline::fit_pullback`]) own the result and implement [`crate::Warp`] with an analytic
//! Jacobian. Below them, [`ControlLattice::eval_into`] and [`ControlLattice::sample_slices_into`]
//! write into `&mut` outputs and never allocate; the grid kernel is separable (contract z, then y,
//! then x), which costs ~12 multiply-adds per output value instead of 64.

use std::marker::PhantomData;
use std::ops::Range;

use nalgebra::{Matrix3, SymmetricEigen};
use rayon::prelude::*;
use warpbench_io::geometry::{Point3, Space};

use crate::spaces::{Aabb, Fixed, Moving};
use crate::{Parallelism, SolverError, Warp};

/// What a fit to landmark pairs needs ([`crate::pairs`]): the same as a TPS, since the affine initial approximation
/// is a full affine map: 4 distinct pairs, neither side coplanar.
pub const NEEDS: crate::pairs::Needs =
    crate::pairs::Needs { method: "hierarchical B-spline", min_pairs: 4, spread: crate::pairs::Spread::NotCoplanar };

/// The largest control lattice a fit may build (control points, all three axes together): 128³.
pub const MAX_CONTROL_POINTS: usize = 1 << 21;

/// The most extra BA passes on the finest lattice once all levels are used (see [`FitReport::finest_passes`]).
pub const MAX_FINEST_PASSES: usize = 8;

/// The uniform cubic B-spline basis B₀..B₃ at t ∈ [0, 1] (Lee et al. 1997 §3). They are ≥ 0 and sum to 1.
#[inline]
#[must_use]
pub fn basis(t: f64) -> [f64; 4] {
    let u = 1.0 - t;
    let t2 = t * t;
    let t3 = t2 * t;
    [u * u * u / 6.0, (3.0 * t3 - 6.0 * t2 + 4.0) / 6.0, (-3.0 * t3 + 3.0 * t2 + 3.0 * t + 1.0) / 6.0, t3 / 6.0]
}

/// The derivatives dB_a/dt of [`basis`]; they sum to 0.
#[inline]
#[must_use]
pub fn basis_derivative(t: f64) -> [f64; 4] {
    let u = 1.0 - t;
    [-0.5 * u * u, 1.5 * t * t - 2.0 * t, -1.5 * t * t + t + 0.5, 0.5 * t * t]
}

/// Parameters of the multilevel fit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BSplineParams {
    /// Control-lattice cells per axis at level 0 (the lattice has 3 more control points per axis).
    pub coarsest: [usize; 3],
    /// The most levels to fit; level ℓ has `coarsest · 2^ℓ` cells. At least 1.
    pub levels: usize,
    /// Stop adding levels once every landmark residual is below this (mm, ≥ 0).
    pub tolerance_mm: f64,
}

impl Default for BSplineParams {
    fn default() -> Self {
        Self { coarsest: [4, 4, 4], levels: 4, tolerance_mm: 0.01 }
    }
}

impl BSplineParams {
    /// Checks the parameters and returns the finest lattice's cells per axis.
    pub fn finest_cells(&self) -> crate::Result<[usize; 3]> {
        if self.coarsest.contains(&0) {
            return Err(SolverError::InvalidParameter(format!(
                "B-spline coarsest lattice needs at least one cell per axis, got {:?}",
                self.coarsest
            )));
        }
        if self.levels == 0 {
            return Err(SolverError::InvalidParameter("B-spline levels must be at least 1".into()));
        }
        if !(self.tolerance_mm.is_finite() && self.tolerance_mm >= 0.0) {
            return Err(SolverError::InvalidParameter(format!(
                "B-spline tolerance must be finite and ≥ 0 mm, got {}",
                self.tolerance_mm
            )));
        }
        let too_big = || {
            SolverError::InvalidParameter(format!(
                "B-spline lattice {:?} refined over {} levels exceeds {MAX_CONTROL_POINTS} control points",
                self.coarsest, self.levels
            ))
        };
        let factor = u32::try_from(self.levels - 1).ok().and_then(|l| 1usize.checked_shl(l)).ok_or_else(too_big)?;
        let mut cells = [0; 3];
        let mut points = 1usize;
        for (cell, coarse) in cells.iter_mut().zip(self.coarsest) {
            *cell = coarse.checked_mul(factor).ok_or_else(too_big)?;
            points = points.checked_mul(cell.checked_add(3).ok_or_else(too_big)?).ok_or_else(too_big)?;
        }
        if points > MAX_CONTROL_POINTS {
            return Err(too_big());
        }
        Ok(cells)
    }
}

/// How a fit ended.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FitReport {
    /// Levels fitted after the affine initial approximation (0 when it alone met the tolerance).
    pub levels_used: usize,
    /// Extra BA passes on the finest lattice after the last level, while a residual stayed above the
    /// tolerance (at most [`MAX_FINEST_PASSES`]).
    pub finest_passes: usize,
    /// Cells per axis of the final (finest) lattice.
    pub cells: [usize; 3],
    /// Largest residual ‖D(x_c) − z_c‖ over the data, mm.
    pub max_residual_mm: f64,
    /// Root-mean-square residual over the data, mm (0 with no data).
    pub rms_residual_mm: f64,
}

/// One cubic B-spline control lattice over an axis-aligned box, in raw mm (kernel tier).
///
/// Coefficients are stored flat, 3 values (dx, dy, dz in mm) per control point, x fastest:
/// `coefficients[((k * dims[1] + j) * dims[0] + i) * 3 + component]`, where storage index 0 is the
/// paper's index −1, so control point (i, j, k) sits at `min + (i − 1, j − 1, k − 1) · spacing`.
#[derive(Clone, Debug, PartialEq)]
pub struct ControlLattice {
    cells: [usize; 3],
    min_mm: [f64; 3],
    max_mm: [f64; 3],
    coefficients: Vec<f64>,
}

/// One axis of a regular grid, located in a lattice: the first control index and the 4 weights per sample.
#[derive(Clone, Debug, Default)]
struct AxisTable {
    start: Vec<usize>,
    weights: Vec<[f64; 4]>,
}

#[derive(Clone, Copy, PartialEq, Eq)]
enum Weights {
    /// B_a(s).
    Value,
    /// dB_a/ds / h, and 0 outside the domain (clamped coordinate).
    Derivative,
    /// BA weights B_a(s)³ / Σ_b B_b(s)² (Lee et al. eq. 3, one axis of the factorised sum).
    Fit,
}

impl ControlLattice {
    /// A zero lattice (D = 0) with `cells` per axis over [min_mm, max_mm]. Checks sizes before allocating.
    pub fn zeros(cells: [usize; 3], min_mm: [f64; 3], max_mm: [f64; 3]) -> crate::Result<Self> {
        if cells.contains(&0) {
            return Err(SolverError::InvalidParameter(format!("lattice needs ≥ 1 cell per axis, got {cells:?}")));
        }
        if !(0..3).all(|a| min_mm[a].is_finite() && max_mm[a].is_finite() && max_mm[a] > min_mm[a]) {
            return Err(SolverError::InvalidParameter(format!(
                "lattice box must be finite with positive size, got {min_mm:?}..{max_mm:?}"
            )));
        }
        let points = cells.iter().try_fold(1usize, |acc, &c| acc.checked_mul(c.checked_add(3)?));
        match points {
            Some(p) if p <= MAX_CONTROL_POINTS => Ok(Self { cells, min_mm, max_mm, coefficients: vec![0.0; p * 3] }),
            _ => Err(SolverError::InvalidParameter(format!(
                "lattice with {cells:?} cells exceeds {MAX_CONTROL_POINTS} control points"
            ))),
        }
    }

    /// Cells per axis (m, n, o).
    #[must_use]
    pub fn cells(&self) -> [usize; 3] {
        self.cells
    }

    /// Control points per axis: cells + 3.
    #[must_use]
    pub fn dims(&self) -> [usize; 3] {
        [self.cells[0] + 3, self.cells[1] + 3, self.cells[2] + 3]
    }

    /// The domain's lower corner, mm.
    #[must_use]
    pub fn min_mm(&self) -> [f64; 3] {
        self.min_mm
    }

    /// The domain's upper corner, mm.
    #[must_use]
    pub fn max_mm(&self) -> [f64; 3] {
        self.max_mm
    }

    /// Cell edge per axis, mm.
    #[must_use]
    pub fn spacing_mm(&self) -> [f64; 3] {
        std::array::from_fn(|a| (self.max_mm[a] - self.min_mm[a]) / self.cells[a] as f64)
    }

    /// The coefficients, flat (see the type's docs for the layout), mm.
    #[must_use]
    pub fn coefficients(&self) -> &[f64] {
        &self.coefficients
    }

    /// Mutable coefficients (same layout), e.g. to build a lattice by hand.
    pub fn coefficients_mut(&mut self) -> &mut [f64] {
        &mut self.coefficients
    }

    /// The coefficients converted to f32 for upload to a GPU (same layout).
    #[must_use]
    pub fn coefficients_f32(&self) -> Vec<f32> {
        self.coefficients.iter().map(|&c| c as f32).collect()
    }

    #[inline]
    fn locate(&self, x: f64, a: usize) -> (usize, f64, bool) {
        let (lo, hi) = (self.min_mm[a], self.max_mm[a]);
        let inside = x >= lo && x <= hi;
        let xc = x.clamp(lo, hi);
        let cells = self.cells[a];
        let u = (xc - lo) / (hi - lo) * cells as f64;
        // NaN casts to 0: a NaN input gives a NaN output, never a panic.
        let i = (u.floor() as usize).min(cells - 1);
        (i, u - i as f64, inside)
    }

    /// The control points that D(x) reads: the first storage index per axis (the 4 × 4 × 4 block starts there) and
    /// the basis weights B_a along each axis, as [`Self::eval_into`] uses them (x clamped to the domain).
    #[inline]
    pub(crate) fn footprint(&self, x: [f64; 3]) -> ([usize; 3], [[f64; 4]; 3]) {
        let located: [(usize, f64, bool); 3] = std::array::from_fn(|a| self.locate(x[a], a));
        (located.map(|l| l.0), located.map(|l| basis(l.1)))
    }

    /// [`Self::footprint`] with the derivative weights dB_a/dx along each axis (mm⁻¹) beside the basis weights.
    #[inline]
    pub(crate) fn footprint_with_derivatives(&self, x: [f64; 3]) -> ([usize; 3], [[f64; 4]; 3], [[f64; 4]; 3]) {
        let h = self.spacing_mm();
        let located: [(usize, f64, bool); 3] = std::array::from_fn(|a| self.locate(x[a], a));
        let derivatives = std::array::from_fn(|a| basis_derivative(located[a].1).map(|v| v / h[a]));
        (located.map(|l| l.0), located.map(|l| basis(l.1)), derivatives)
    }

    /// The warp x + D(x), mm.
    #[must_use]
    pub fn warp_raw(&self, x: [f64; 3]) -> [f64; 3] {
        let d = self.eval(x);
        [x[0] + d[0], x[1] + d[1], x[2] + d[2]]
    }

    /// The warp's Jacobian I + ∂D/∂x (analytic, [`Self::jacobian_into`]).
    #[must_use]
    pub fn warp_jacobian(&self, x: [f64; 3]) -> Matrix3<f64> {
        let mut j = [[0.0; 3]; 3];
        self.jacobian_into(x, &mut j);
        Matrix3::from_fn(|r, c| j[r][c] + if r == c { 1.0 } else { 0.0 })
    }

    /// Evaluates the displacement D(x) (mm) into `out`; no allocation.
    #[inline]
    pub fn eval_into(&self, x: [f64; 3], out: &mut [f64; 3]) {
        let (ix, s, _) = self.locate(x[0], 0);
        let (iy, t, _) = self.locate(x[1], 1);
        let (iz, r, _) = self.locate(x[2], 2);
        let (bx, by, bz) = (basis(s), basis(t), basis(r));
        let [n0, n1, _] = self.dims();
        let mut acc = [0.0; 3];
        for (c, wz) in bz.iter().enumerate() {
            for (b, wy) in by.iter().enumerate() {
                let wzy = wz * wy;
                let row = (((iz + c) * n1 + iy + b) * n0 + ix) * 3;
                let coef = &self.coefficients[row..row + 12];
                for (a, wx) in bx.iter().enumerate() {
                    let w = wzy * wx;
                    acc[0] += w * coef[3 * a];
                    acc[1] += w * coef[3 * a + 1];
                    acc[2] += w * coef[3 * a + 2];
                }
            }
        }
        *out = acc;
    }

    /// The displacement D(x), mm.
    #[must_use]
    pub fn eval(&self, x: [f64; 3]) -> [f64; 3] {
        let mut out = [0.0; 3];
        self.eval_into(x, &mut out);
        out
    }

    /// The displacement's Jacobian ∂D_r/∂x_c into `out[r][c]`; zero in an axis where x is outside the domain.
    pub fn jacobian_into(&self, x: [f64; 3], out: &mut [[f64; 3]; 3]) {
        let h = self.spacing_mm();
        let loc = [self.locate(x[0], 0), self.locate(x[1], 1), self.locate(x[2], 2)];
        let b: [[f64; 4]; 3] = std::array::from_fn(|a| basis(loc[a].1));
        let d: [[f64; 4]; 3] =
            std::array::from_fn(|a| if loc[a].2 { basis_derivative(loc[a].1).map(|v| v / h[a]) } else { [0.0; 4] });
        let [n0, n1, _] = self.dims();
        *out = [[0.0; 3]; 3];
        for c in 0..4 {
            for bb in 0..4 {
                let row = (((loc[2].0 + c) * n1 + loc[1].0 + bb) * n0 + loc[0].0) * 3;
                for a in 0..4 {
                    let gx = d[0][a] * b[1][bb] * b[2][c];
                    let gy = b[0][a] * d[1][bb] * b[2][c];
                    let gz = b[0][a] * b[1][bb] * d[2][c];
                    let coef = &self.coefficients[row + 3 * a..row + 3 * a + 3];
                    for (r, &phi) in coef.iter().enumerate() {
                        out[r][0] += gx * phi;
                        out[r][1] += gy * phi;
                        out[r][2] += gz * phi;
                    }
                }
            }
        }
    }

    /// B-spline refinement (Lee et al. §4.2): the same function on a lattice with twice the cells per axis.
    pub fn refine(&self) -> crate::Result<Self> {
        let cells = [self.cells[0] * 2, self.cells[1] * 2, self.cells[2] * 2];
        let mut fine = Self::zeros(cells, self.min_mm, self.max_mm)?;
        let src = self.dims();
        let dst = fine.dims();
        // One axis at a time: x, then y, then z (the refinement of a tensor product is separable).
        let mut a = vec![0.0; dst[0] * src[1] * src[2] * 3];
        refine_axis(&self.coefficients, [src[0], src[1], src[2]], 0, &mut a);
        let mut b = vec![0.0; dst[0] * dst[1] * src[2] * 3];
        refine_axis(&a, [dst[0], src[1], src[2]], 1, &mut b);
        refine_axis(&b, [dst[0], dst[1], src[2]], 2, &mut fine.coefficients);
        Ok(fine)
    }

    /// Refines this lattice `times` times (each doubles the cells).
    pub fn refined(&self, times: usize) -> crate::Result<Self> {
        let mut out = self.clone();
        for _ in 0..times {
            out = out.refine()?;
        }
        Ok(out)
    }

    /// Adds `other`'s function to this one's. Both must cover the same box with cells that differ by a
    /// power of two (the coarser is refined first); the result has the finer lattice.
    pub fn add(&self, other: &Self) -> crate::Result<Self> {
        // Exact comparison on purpose: both boxes come from the same domain, bit for bit.
        #[allow(clippy::float_cmp)]
        if self.min_mm != other.min_mm || self.max_mm != other.max_mm {
            return Err(SolverError::InvalidParameter("lattices to add must cover the same box".into()));
        }
        let (coarse, fine) = if self.cells[0] <= other.cells[0] { (self, other) } else { (other, self) };
        let mut times = 0;
        let mut refined = coarse.clone();
        while refined.cells[0] < fine.cells[0] {
            refined = refined.refine()?;
            times += 1;
            if times > 32 {
                break;
            }
        }
        if refined.cells != fine.cells {
            return Err(SolverError::InvalidParameter(format!(
                "lattices with {:?} and {:?} cells are not a power-of-two refinement apart",
                self.cells, other.cells
            )));
        }
        for (r, f) in refined.coefficients.iter_mut().zip(&fine.coefficients) {
            *r += f;
        }
        Ok(refined)
    }

    /// The knot position (mm) of storage index `s` on axis `a`.
    fn knot_mm(&self, a: usize, s: usize) -> f64 {
        self.min_mm[a] + (s as f64 - 1.0) * (self.max_mm[a] - self.min_mm[a]) / self.cells[a] as f64
    }

    fn axis_table(&self, grid: &RegularGrid, a: usize, kind: Weights) -> AxisTable {
        let n = grid.dims[a];
        let mut table = AxisTable { start: Vec::with_capacity(n), weights: Vec::with_capacity(n) };
        let h = self.spacing_mm()[a];
        for i in 0..n {
            let (start, s, inside) = self.locate(grid.coord(a, i), a);
            table.start.push(start);
            table.weights.push(match kind {
                Weights::Value => basis(s),
                Weights::Derivative if inside => basis_derivative(s).map(|v| v / h),
                Weights::Derivative => [0.0; 4],
                Weights::Fit => {
                    let b = basis(s);
                    let sum_sq: f64 = b.iter().map(|v| v * v).sum();
                    b.map(|v| v * v * v / sum_sq)
                }
            });
        }
        table
    }

    /// Scratch for [`ControlLattice::sample_slices_into`] on `grid`: the per-axis tables and two buffers.
    #[must_use]
    pub fn grid_scratch(&self, grid: &RegularGrid) -> GridScratch {
        let [n0, n1, _] = self.dims();
        GridScratch {
            x: self.axis_table(grid, 0, Weights::Value),
            y: self.axis_table(grid, 1, Weights::Value),
            z: self.axis_table(grid, 2, Weights::Value),
            plane: vec![0.0; n0 * n1 * 3],
            row: vec![0.0; n0 * 3],
            lattice_dims: self.dims(),
            grid_dims: grid.dims,
        }
    }

    /// Evaluates D on the z slices `slices` of `grid` into `out` (x fastest, `out.len()` = slices ×
    /// nx × ny), adding the grid position when `add_position` (then `out` holds the warped points).
    /// Separable: per slice, contract the lattice along z, then per row along y, then per sample along x.
    /// Never allocates; `scratch` must come from [`ControlLattice::grid_scratch`] for this lattice and grid.
    pub fn sample_slices_into(
        &self,
        grid: &RegularGrid,
        slices: Range<usize>,
        add_position: bool,
        out: &mut [[f64; 3]],
        scratch: &mut GridScratch,
    ) -> crate::Result<()> {
        if scratch.lattice_dims != self.dims() || scratch.grid_dims != grid.dims {
            return Err(SolverError::InvalidParameter("grid scratch was made for another lattice or grid".into()));
        }
        let per_slice = grid.dims[0] * grid.dims[1];
        if slices.end > grid.dims[2] || slices.start > slices.end || out.len() != per_slice * slices.len() {
            return Err(SolverError::InvalidParameter(format!(
                "output of {} values does not fit slices {slices:?} of a {:?} grid",
                out.len(),
                grid.dims
            )));
        }
        let GridScratch { x, y, z, plane, row, .. } = scratch;
        let mode = if add_position { Write::SetPlusPosition(grid) } else { Write::Set };
        contract(&self.coefficients, self.dims(), [x, y, z], slices, mode, out, plane, row);
        Ok(())
    }
}

/// Reusable buffers for the separable grid kernel (one per thread).
#[derive(Clone, Debug)]
pub struct GridScratch {
    x: AxisTable,
    y: AxisTable,
    z: AxisTable,
    plane: Vec<f64>,
    row: Vec<f64>,
    lattice_dims: [usize; 3],
    grid_dims: [usize; 3],
}

/// A regular grid of points `origin + (i, j, k) · spacing`, i < `dims[0]` etc., x fastest.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RegularGrid {
    pub origin_mm: [f64; 3],
    pub spacing_mm: [f64; 3],
    pub dims: [usize; 3],
}

impl RegularGrid {
    /// `dims` points per axis spanning [min, max] corner to corner (a single point sits at the centre).
    #[must_use]
    pub fn spanning(min_mm: [f64; 3], max_mm: [f64; 3], dims: [usize; 3]) -> Self {
        let mut origin_mm = [0.0; 3];
        let mut spacing_mm = [0.0; 3];
        for a in 0..3 {
            if dims[a] <= 1 {
                origin_mm[a] = 0.5 * (min_mm[a] + max_mm[a]);
            } else {
                origin_mm[a] = min_mm[a];
                spacing_mm[a] = (max_mm[a] - min_mm[a]) / (dims[a] - 1) as f64;
            }
        }
        Self { origin_mm, spacing_mm, dims }
    }

    /// `dims` cell-centred points per axis in [min, max]: the centres of a dims-cell partition.
    #[must_use]
    pub fn cell_centred(min_mm: [f64; 3], max_mm: [f64; 3], dims: [usize; 3]) -> Self {
        let spacing_mm: [f64; 3] = std::array::from_fn(|a| (max_mm[a] - min_mm[a]) / dims[a].max(1) as f64);
        let origin_mm = std::array::from_fn(|a| min_mm[a] + 0.5 * spacing_mm[a]);
        Self { origin_mm, spacing_mm, dims }
    }

    /// Number of points.
    #[must_use]
    pub fn len(&self) -> usize {
        self.dims[0] * self.dims[1] * self.dims[2]
    }

    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Coordinate `i` along axis `a`, mm.
    #[inline]
    #[must_use]
    pub fn coord(&self, a: usize, i: usize) -> f64 {
        self.origin_mm[a] + i as f64 * self.spacing_mm[a]
    }

    /// Point number `index` (x fastest), mm.
    #[must_use]
    pub fn point(&self, index: usize) -> [f64; 3] {
        let i = index % self.dims[0];
        let j = (index / self.dims[0]) % self.dims[1];
        let k = index / (self.dims[0] * self.dims[1]);
        [self.coord(0, i), self.coord(1, j), self.coord(2, k)]
    }

    fn check(&self) -> crate::Result<()> {
        let ok = (0..3).all(|a| self.origin_mm[a].is_finite() && self.spacing_mm[a].is_finite() && self.dims[a] > 0);
        if ok && self.dims.iter().try_fold(1usize, |acc, &d| acc.checked_mul(d)).is_some() {
            Ok(())
        } else {
            Err(SolverError::InvalidParameter(format!("invalid regular grid {self:?}")))
        }
    }
}

/// Refines along axis `axis` of a `dims` array of 3-vectors into `out` (that axis becomes 2(d−3)+3).
fn refine_axis(src: &[f64], dims: [usize; 3], axis: usize, out: &mut [f64]) {
    let n_src = dims[axis];
    let n_dst = 2 * (n_src - 3) + 3;
    let mut out_dims = dims;
    out_dims[axis] = n_dst;
    let stride_src = match axis {
        0 => 1,
        1 => dims[0],
        _ => dims[0] * dims[1],
    };
    let stride_dst = match axis {
        0 => 1,
        1 => out_dims[0],
        _ => out_dims[0] * out_dims[1],
    };
    let lines: Vec<(usize, usize)> = {
        let mut v = Vec::new();
        let (o0, o1, o2) = (out_dims[0], out_dims[1], out_dims[2]);
        for k in 0..o2 {
            for j in 0..o1 {
                for i in 0..o0 {
                    let idx = [i, j, k];
                    if idx[axis] != 0 {
                        continue;
                    }
                    let base_src = (k * dims[1] + j) * dims[0] + i;
                    let base_dst = (k * o1 + j) * o0 + i;
                    v.push((base_src, base_dst));
                }
            }
        }
        v
    };
    for (base_src, base_dst) in lines {
        for t in 0..n_dst {
            let d = (base_dst + t * stride_dst) * 3;
            if t % 2 == 1 {
                // Fine paper index 2i (even): (φ_{i−1} + 6φ_i + φ_{i+1}) / 8 at coarse storage i, i+1, i+2.
                let i = (t - 1) / 2;
                for c in 0..3 {
                    let p = |s: usize| src[(base_src + s * stride_src) * 3 + c];
                    out[d + c] = (p(i) + 6.0 * p(i + 1) + p(i + 2)) / 8.0;
                }
            } else {
                // Fine paper index 2i+1 (odd): (φ_i + φ_{i+1}) / 2 at coarse storage t/2, t/2 + 1.
                let i = t / 2;
                for c in 0..3 {
                    let p = |s: usize| src[(base_src + s * stride_src) * 3 + c];
                    out[d + c] = 0.5 * (p(i) + p(i + 1));
                }
            }
        }
    }
}

/// What [`contract`] does with each value it computes.
#[derive(Clone, Copy)]
enum Write<'g> {
    Set,
    /// Set the value plus the grid position (the warped point).
    SetPlusPosition(&'g RegularGrid),
    /// Subtract the value (residual update).
    Subtract,
}

/// The separable contraction (the arguments are the kernel's explicit inputs, outputs and scratch): out[k][j][i] = Σ_abc x_a(i) y_b(j) z_c(k) φ[sx_i + a][sy_j + b][sz_k + c].
#[allow(clippy::too_many_arguments)]
fn contract(
    coef: &[f64],
    n: [usize; 3],
    tables: [&AxisTable; 3],
    slices: Range<usize>,
    mode: Write<'_>,
    out: &mut [[f64; 3]],
    plane: &mut [f64],
    row: &mut [f64],
) {
    let [tx, ty, tz] = tables;
    let (nx, ny) = (tx.start.len(), ty.start.len());
    let (n0, n1) = (n[0], n[1]);
    let plane_len = n0 * n1 * 3;
    for (slab, k) in out.chunks_mut(nx * ny).zip(slices) {
        // z: plane[iy][ix] = Σ_c z_c φ[.., .., sz + c].
        let (sz, wz) = (tz.start[k], tz.weights[k]);
        let plane = &mut plane[..plane_len];
        plane.fill(0.0);
        for (c, w) in wz.iter().enumerate() {
            if *w == 0.0 {
                continue;
            }
            let src = &coef[(sz + c) * plane_len..(sz + c + 1) * plane_len];
            for (p, s) in plane.iter_mut().zip(src) {
                *p += w * s;
            }
        }
        for (j, (line, (sy, wy))) in slab.chunks_mut(nx).zip(ty.start.iter().zip(&ty.weights)).enumerate() {
            // y: row[ix] = Σ_b y_b plane[sy + b][ix].
            let row = &mut row[..n0 * 3];
            let p = |b: usize| &plane[(sy + b) * n0 * 3..(sy + b + 1) * n0 * 3];
            let (p0, p1, p2, p3) = (p(0), p(1), p(2), p(3));
            for idx in 0..n0 * 3 {
                row[idx] = wy[0] * p0[idx] + wy[1] * p1[idx] + wy[2] * p2[idx] + wy[3] * p3[idx];
            }
            // x: out = Σ_a x_a row[sx + a].
            let value = |sx: usize, wx: &[f64; 4], comp: usize| {
                let r = &row[sx * 3..sx * 3 + 12];
                wx[0] * r[comp] + wx[1] * r[3 + comp] + wx[2] * r[6 + comp] + wx[3] * r[9 + comp]
            };
            let taps = tx.start.iter().zip(&tx.weights);
            match mode {
                Write::Set => {
                    for (o, (&sx, wx)) in line.iter_mut().zip(taps) {
                        *o = [value(sx, wx, 0), value(sx, wx, 1), value(sx, wx, 2)];
                    }
                }
                Write::SetPlusPosition(grid) => {
                    let (yc, zc) = (grid.coord(1, j), grid.coord(2, k));
                    for (i, (o, (&sx, wx))) in line.iter_mut().zip(taps).enumerate() {
                        *o = [value(sx, wx, 0) + grid.coord(0, i), value(sx, wx, 1) + yc, value(sx, wx, 2) + zc];
                    }
                }
                Write::Subtract => {
                    for (o, (&sx, wx)) in line.iter_mut().zip(taps) {
                        o[0] -= value(sx, wx, 0);
                        o[1] -= value(sx, wx, 1);
                        o[2] -= value(sx, wx, 2);
                    }
                }
            }
        }
    }
}

impl ControlLattice {
    /// Evaluates the Jacobian of D, ∂D_r/∂x_c, on every point of `grid` into `out[index][r][c]` (separable:
    /// three contractions, each with one axis's weights differentiated).
    pub fn sample_jacobian_grid_into(
        &self,
        grid: &RegularGrid,
        out: &mut [[[f64; 3]; 3]],
        par: Parallelism,
    ) -> crate::Result<()> {
        grid.check()?;
        if out.len() != grid.len() {
            return Err(SolverError::InvalidParameter(format!(
                "Jacobian output has {} entries for a grid of {}",
                out.len(),
                grid.len()
            )));
        }
        let value: [AxisTable; 3] = std::array::from_fn(|a| self.axis_table(grid, a, Weights::Value));
        let deriv: [AxisTable; 3] = std::array::from_fn(|a| self.axis_table(grid, a, Weights::Derivative));
        let per_slice = grid.dims[0] * grid.dims[1];
        let [n0, n1, _] = self.dims();
        let run = |k0: usize, chunk: &mut [[[f64; 3]; 3]]| {
            let slices = k0..k0 + chunk.len() / per_slice;
            let mut tmp = vec![[0.0; 3]; chunk.len()];
            let mut plane = vec![0.0; n0 * n1 * 3];
            let mut row = vec![0.0; n0 * 3];
            for c in 0..3 {
                let tables: [&AxisTable; 3] = std::array::from_fn(|a| if a == c { &deriv[a] } else { &value[a] });
                contract(
                    &self.coefficients,
                    self.dims(),
                    tables,
                    slices.clone(),
                    Write::Set,
                    &mut tmp,
                    &mut plane,
                    &mut row,
                );
                for (o, t) in chunk.iter_mut().zip(&tmp) {
                    for r in 0..3 {
                        o[r][c] = t[r];
                    }
                }
            }
        };
        let slices_per_chunk = 4;
        match par {
            Parallelism::Sequential => run(0, out),
            Parallelism::Rayon => out
                .par_chunks_mut(per_slice * slices_per_chunk)
                .enumerate()
                .for_each(|(ci, chunk)| run(ci * slices_per_chunk, chunk)),
        }
        Ok(())
    }

    /// Evaluates D (or the warped position x + D when `add_position`) on every point of `grid`.
    pub fn sample_grid_into(
        &self,
        grid: &RegularGrid,
        add_position: bool,
        out: &mut [[f64; 3]],
        par: Parallelism,
    ) -> crate::Result<()> {
        grid.check()?;
        if out.len() != grid.len() {
            return Err(SolverError::InvalidParameter(format!(
                "grid output has {} entries for a grid of {}",
                out.len(),
                grid.len()
            )));
        }
        let per_slice = grid.dims[0] * grid.dims[1];
        let scratch = self.grid_scratch(grid);
        match par {
            Parallelism::Sequential => {
                let mut scratch = scratch;
                self.sample_slices_into(grid, 0..grid.dims[2], add_position, out, &mut scratch)
            }
            Parallelism::Rayon => {
                let slices_per_chunk = 2;
                out.par_chunks_mut(per_slice * slices_per_chunk).enumerate().try_for_each_init(
                    || scratch.clone(),
                    |s, (ci, chunk)| {
                        let k0 = ci * slices_per_chunk;
                        self.sample_slices_into(grid, k0..k0 + chunk.len() / per_slice, add_position, chunk, s)
                    },
                )
            }
        }
    }

    /// residual −= D on every point of `grid`, in place.
    fn subtract_grid(&self, grid: &RegularGrid, residual: &mut [[f64; 3]], par: Parallelism) {
        let tables: [AxisTable; 3] = std::array::from_fn(|a| self.axis_table(grid, a, Weights::Value));
        let per_slice = grid.dims[0] * grid.dims[1];
        let [n0, n1, _] = self.dims();
        let run = |k0: usize, chunk: &mut [[f64; 3]]| {
            let mut plane = vec![0.0; n0 * n1 * 3];
            let mut row = vec![0.0; n0 * 3];
            let slices = k0..k0 + chunk.len() / per_slice;
            let t = [&tables[0], &tables[1], &tables[2]];
            contract(&self.coefficients, self.dims(), t, slices, Write::Subtract, chunk, &mut plane, &mut row);
        };
        let slices_per_chunk = 4;
        match par {
            Parallelism::Sequential => run(0, residual),
            Parallelism::Rayon => residual
                .par_chunks_mut(per_slice * slices_per_chunk)
                .enumerate()
                .for_each(|(ci, chunk)| run(ci * slices_per_chunk, chunk)),
        }
    }

    /// The BA lattice (Lee et al. eqs. 3–5) of scattered `values` at `points` (already clamped to the box),
    /// on this lattice's geometry.
    fn ba_scattered(&self, points: &[[f64; 3]], values: &[[f64; 3]]) -> crate::Result<Self> {
        let mut phi = Self::zeros(self.cells, self.min_mm, self.max_mm)?;
        let mut omega = vec![0.0; phi.coefficients.len() / 3];
        let [n0, n1, _] = self.dims();
        for (p, z) in points.iter().zip(values) {
            let (ix, s, _) = self.locate(p[0], 0);
            let (iy, t, _) = self.locate(p[1], 1);
            let (iz, r, _) = self.locate(p[2], 2);
            let (bx, by, bz) = (basis(s), basis(t), basis(r));
            let sq = |b: &[f64; 4]| b.iter().map(|v| v * v).sum::<f64>();
            let inv_sum_sq = 1.0 / (sq(&bx) * sq(&by) * sq(&bz));
            for (c, wz) in bz.iter().enumerate() {
                for (b, wy) in by.iter().enumerate() {
                    let base = ((iz + c) * n1 + iy + b) * n0 + ix;
                    for (a, wx) in bx.iter().enumerate() {
                        let w = wx * wy * wz;
                        let w2 = w * w;
                        // δ += w² φ_c with φ_c = w z / Σ w² (eq. 3); ω += w² (eq. 5).
                        let k = w2 * w * inv_sum_sq;
                        let idx = base + a;
                        omega[idx] += w2;
                        for (coef, zc) in phi.coefficients[idx * 3..idx * 3 + 3].iter_mut().zip(z) {
                            *coef += k * zc;
                        }
                    }
                }
            }
        }
        for (chunk, w) in phi.coefficients.chunks_mut(3).zip(&omega) {
            if *w > 0.0 {
                for v in chunk {
                    *v /= w;
                }
            }
        }
        Ok(phi)
    }

    /// The BA lattice of `values` sampled on `grid`, separably: δ is the adjoint of the grid contraction
    /// with weights B³/ΣB² per axis, and ω = ω_x ⊗ ω_y ⊗ ω_z with ω_a = Σ B_a².
    fn ba_grid(&self, grid: &RegularGrid, values: &[[f64; 3]]) -> crate::Result<Self> {
        let mut phi = Self::zeros(self.cells, self.min_mm, self.max_mm)?;
        let [n0, n1, n2] = self.dims();
        let fit: [AxisTable; 3] = std::array::from_fn(|a| self.axis_table(grid, a, Weights::Fit));
        let omega: [Vec<f64>; 3] = std::array::from_fn(|a| {
            let table = self.axis_table(grid, a, Weights::Value);
            let mut w = vec![0.0; self.dims()[a]];
            for (s, b) in table.start.iter().zip(&table.weights) {
                for (k, v) in b.iter().enumerate() {
                    w[s + k] += v * v;
                }
            }
            w
        });
        let [nx, ny, _] = grid.dims;
        let plane_len = n0 * n1 * 3;
        let mut plane = vec![0.0; plane_len];
        let mut row = vec![0.0; n0 * 3];
        for (k, slab) in values.chunks(nx * ny).enumerate() {
            plane.fill(0.0);
            for (j, line) in slab.chunks(nx).enumerate() {
                row.fill(0.0);
                for (v, (sx, wx)) in line.iter().zip(fit[0].start.iter().zip(&fit[0].weights)) {
                    for (a, w) in wx.iter().enumerate() {
                        let r = &mut row[(sx + a) * 3..(sx + a) * 3 + 3];
                        r[0] += w * v[0];
                        r[1] += w * v[1];
                        r[2] += w * v[2];
                    }
                }
                let (sy, wy) = (fit[1].start[j], fit[1].weights[j]);
                for (b, w) in wy.iter().enumerate() {
                    let dst = &mut plane[(sy + b) * n0 * 3..(sy + b + 1) * n0 * 3];
                    for (d, r) in dst.iter_mut().zip(&row) {
                        *d += w * r;
                    }
                }
            }
            let (sz, wz) = (fit[2].start[k], fit[2].weights[k]);
            for (c, w) in wz.iter().enumerate() {
                let dst = &mut phi.coefficients[(sz + c) * plane_len..(sz + c + 1) * plane_len];
                for (d, p) in dst.iter_mut().zip(&plane) {
                    *d += w * p;
                }
            }
        }
        for iz in 0..n2 {
            for iy in 0..n1 {
                for ix in 0..n0 {
                    let w = omega[0][ix] * omega[1][iy] * omega[2][iz];
                    let idx = ((iz * n1 + iy) * n0 + ix) * 3;
                    if w > 0.0 {
                        phi.coefficients[idx..idx + 3].iter_mut().for_each(|v| *v /= w);
                    }
                }
            }
        }
        Ok(phi)
    }

    /// Writes the affine map D₀(x) = d̄ + A (x − p̄) into the coefficients (exact: φ_j = D₀(knot_j)).
    fn set_affine(&mut self, a_mat: &Matrix3<f64>, d_bar: [f64; 3], p_bar: [f64; 3]) {
        let [n0, n1, n2] = self.dims();
        for iz in 0..n2 {
            for iy in 0..n1 {
                for ix in 0..n0 {
                    let q = [
                        self.knot_mm(0, ix) - p_bar[0],
                        self.knot_mm(1, iy) - p_bar[1],
                        self.knot_mm(2, iz) - p_bar[2],
                    ];
                    let idx = ((iz * n1 + iy) * n0 + ix) * 3;
                    for r in 0..3 {
                        self.coefficients[idx + r] =
                            d_bar[r] + a_mat[(r, 0)] * q[0] + a_mat[(r, 1)] * q[1] + a_mat[(r, 2)] * q[2];
                    }
                }
            }
        }
    }
}

/// The data a hierarchy is fitted to: scattered (clamped) points, or a regular grid.
enum Data<'a> {
    Scattered(&'a [[f64; 3]]),
    Grid(&'a RegularGrid, Parallelism),
}

impl Data<'_> {
    fn ba(&self, geometry: &ControlLattice, residual: &[[f64; 3]]) -> crate::Result<ControlLattice> {
        match self {
            Data::Scattered(points) => geometry.ba_scattered(points, residual),
            Data::Grid(grid, _) => geometry.ba_grid(grid, residual),
        }
    }

    /// residual −= f(x_c) for the lattice's function f.
    fn subtract(&self, lattice: &ControlLattice, residual: &mut [[f64; 3]]) {
        match self {
            Data::Scattered(points) => {
                let mut v = [0.0; 3];
                for (p, r) in points.iter().zip(residual.iter_mut()) {
                    lattice.eval_into(*p, &mut v);
                    r[0] -= v[0];
                    r[1] -= v[1];
                    r[2] -= v[2];
                }
            }
            Data::Grid(grid, par) => lattice.subtract_grid(grid, residual, *par),
        }
    }

    /// Calls `f(point, index)` for every data point in order (grid points clamped to the lattice box).
    fn for_each_point(&self, lattice: &ControlLattice, mut f: impl FnMut([f64; 3], usize)) {
        match self {
            Data::Scattered(points) => points.iter().enumerate().for_each(|(i, p)| f(*p, i)),
            Data::Grid(grid, _) => {
                let axis = |a: usize| -> Vec<f64> {
                    (0..grid.dims[a]).map(|i| grid.coord(a, i).clamp(lattice.min_mm[a], lattice.max_mm[a])).collect()
                };
                let (xs, ys, zs) = (axis(0), axis(1), axis(2));
                let mut index = 0;
                for &z in &zs {
                    for &y in &ys {
                        for &x in &xs {
                            f([x, y, z], index);
                            index += 1;
                        }
                    }
                }
            }
        }
    }
}

/// Least-squares affine fit of `values` at the data points: (A, d̄, p̄) with D₀(x) = d̄ + A (x − p̄).
/// A = M C⁺ with C = Σ (p − p̄)(p − p̄)ᵀ and M = Σ (d − d̄)(p − p̄)ᵀ; directions in which the points do
/// not spread (eigenvalues of C below 1e-6 of the largest) get no slope. One pass of sums, taken
/// relative to the box centre so that they do not cancel.
fn affine_fit(data: &Data<'_>, values: &[[f64; 3]], lattice: &ControlLattice) -> (Matrix3<f64>, [f64; 3], [f64; 3]) {
    let centre: [f64; 3] = std::array::from_fn(|a| 0.5 * (lattice.min_mm[a] + lattice.max_mm[a]));
    let mut sp = [0.0; 3];
    let mut sd = [0.0; 3];
    let mut spp = [[0.0; 3]; 3];
    let mut sdp = [[0.0; 3]; 3];
    data.for_each_point(lattice, |p, i| {
        let v = values[i];
        let q = [p[0] - centre[0], p[1] - centre[1], p[2] - centre[2]];
        for r in 0..3 {
            sp[r] += q[r];
            sd[r] += v[r];
            for c in 0..3 {
                spp[r][c] += q[r] * q[c];
                sdp[r][c] += v[r] * q[c];
            }
        }
    });
    let n = values.len() as f64;
    let q_bar = sp.map(|v| v / n);
    let d_bar = sd.map(|v| v / n);
    let c_mat = Matrix3::from_fn(|r, c| spp[r][c] - n * q_bar[r] * q_bar[c]);
    let m_mat = Matrix3::from_fn(|r, c| sdp[r][c] - n * d_bar[r] * q_bar[c]);
    let p_bar = [q_bar[0] + centre[0], q_bar[1] + centre[1], q_bar[2] + centre[2]];
    let eig = SymmetricEigen::new(c_mat);
    let largest = eig.eigenvalues.iter().fold(0.0_f64, |acc, &l| acc.max(l));
    let mut c_pinv = Matrix3::<f64>::zeros();
    if largest > 0.0 {
        for (k, &l) in eig.eigenvalues.iter().enumerate() {
            if l > 1e-6 * largest {
                let e = eig.eigenvectors.column(k);
                c_pinv += e * e.transpose() / l;
            }
        }
    }
    let a_mat: Matrix3<f64> = m_mat * c_pinv;
    if a_mat.iter().all(|v| v.is_finite()) { (a_mat, d_bar, p_bar) } else { (Matrix3::zeros(), d_bar, p_bar) }
}

fn residual_stats(residual: &[[f64; 3]]) -> (f64, f64) {
    let mut max = 0.0_f64;
    let mut sum = 0.0;
    for r in residual {
        let sq = r[0] * r[0] + r[1] * r[1] + r[2] * r[2];
        max = max.max(sq.sqrt());
        sum += sq;
    }
    let rms = if residual.is_empty() { 0.0 } else { (sum / residual.len() as f64).sqrt() };
    (max, rms)
}

/// The multilevel fit (Lee et al. §4) of `values` at the data points, after the affine initial approximation.
fn fit_hierarchy(
    data: &Data<'_>,
    values: &[[f64; 3]],
    min_mm: [f64; 3],
    max_mm: [f64; 3],
    params: &BSplineParams,
) -> crate::Result<(ControlLattice, FitReport)> {
    params.finest_cells()?;
    let mut lattice = ControlLattice::zeros(params.coarsest, min_mm, max_mm)?;
    if values.is_empty() {
        let report = FitReport {
            levels_used: 0,
            finest_passes: 0,
            cells: lattice.cells,
            max_residual_mm: 0.0,
            rms_residual_mm: 0.0,
        };
        return Ok((lattice, report));
    }
    let (a_mat, d_bar, p_bar) = affine_fit(data, values, &lattice);
    lattice.set_affine(&a_mat, d_bar, p_bar);
    let mut residual = values.to_vec();
    data.subtract(&lattice, &mut residual);
    let mut levels_used = 0;
    for level in 0..params.levels {
        if residual_stats(&residual).0 < params.tolerance_mm {
            break;
        }
        if level > 0 {
            lattice = lattice.refine()?;
        }
        let phi = data.ba(&lattice, &residual)?;
        data.subtract(&phi, &mut residual);
        for (l, p) in lattice.coefficients.iter_mut().zip(&phi.coefficients) {
            *l += p;
        }
        levels_used += 1;
    }
    // Clustered data (several points within one control neighbourhood) keeps a residual after the last
    // level; repeating BA on the finest lattice shrinks it further at no cost in lattice size.
    let mut finest_passes = 0;
    while finest_passes < MAX_FINEST_PASSES && levels_used > 0 && residual_stats(&residual).0 >= params.tolerance_mm {
        let phi = data.ba(&lattice, &residual)?;
        data.subtract(&phi, &mut residual);
        for (l, p) in lattice.coefficients.iter_mut().zip(&phi.coefficients) {
            *l += p;
        }
        finest_passes += 1;
    }
    let (max_residual_mm, rms_residual_mm) = residual_stats(&residual);
    let cells = lattice.cells;
    Ok((lattice, FitReport { levels_used, finest_passes, cells, max_residual_mm, rms_residual_mm }))
}

/// A hierarchical cubic B-spline warp w(x) = x + D(x) from `From` to `To`, D on one control lattice
/// over a domain box in `From` (see the module docs). `fit_forward` gives `fixed_from_moving`,
/// `fit_pullback` gives `moving_from_fixed`.
#[derive(Clone, Debug)]
pub struct HierarchicalBSpline<To: Space, From: Space> {
    lattice: ControlLattice,
    domain: Aabb<From>,
    report: FitReport,
    /// What [`crate::pairs::validate`] found suspicious in the pairs of [`HierarchicalBSpline::fit`].
    warnings: Vec<crate::pairs::PairWarning>,
    spaces: PhantomData<fn(From) -> To>,
}

fn check_domain<S: Space>(domain: &Aabb<S>) -> crate::Result<()> {
    if domain.is_valid() && domain.min.is_finite() && domain.max.is_finite() {
        Ok(())
    } else {
        Err(SolverError::InvalidParameter(format!(
            "B-spline domain must be finite with positive size, got {:?}..{:?}",
            domain.min, domain.max
        )))
    }
}

impl<To: Space, From: Space> HierarchicalBSpline<To, From> {
    /// The identity warp (D = 0) on the coarsest lattice of `params` over `domain`.
    pub fn identity(domain: Aabb<From>, params: &BSplineParams) -> crate::Result<Self> {
        Self::fit_displacements_raw(&[], &[], domain, params)
    }

    /// Fits w(src_i) ≈ dst_i: the displacement dst_i − src_i as a function of src_i, over `domain`.
    ///
    /// The pairs are checked first by [`crate::pairs::validate`] with [`NEEDS`], as every method's are: at least 4
    /// distinct pairs, neither side coincident, collinear or coplanar (the affine initial approximation is
    /// undetermined across a plane: 3 pairs gave displacements of 258 mm, identical fixed points 3 895 mm). A
    /// repeated pair is counted once; what looks wrong is in [`Self::warnings`]. The identity is
    /// [`Self::identity`].
    pub fn fit(
        src: &[Point3<From>],
        dst: &[Point3<To>],
        domain: Aabb<From>,
        params: &BSplineParams,
    ) -> crate::Result<Self> {
        let checked = crate::pairs::validate(&NEEDS, src, dst)?;
        let points = checked.distinct_raw(src);
        let displacements: Vec<[f64; 3]> = points
            .iter()
            .zip(checked.distinct_raw(dst))
            .map(|(s, d)| [d[0] - s[0], d[1] - s[1], d[2] - s[2]])
            .collect();
        let mut fitted = Self::fit_displacements_raw(&points, &displacements, domain, params)?;
        fitted.warnings = checked.warnings;
        Ok(fitted)
    }

    /// Fits D(points_i) ≈ displacements_i (raw mm). Points outside `domain` are clamped into it. This is the lower
    /// tier for scattered samples of a displacement (e.g. [`crate::invert`]): it checks lengths and finiteness
    /// only, not the landmark rules of [`Self::fit`]; no points give the identity.
    pub fn fit_displacements_raw(
        points: &[[f64; 3]],
        displacements: &[[f64; 3]],
        domain: Aabb<From>,
        params: &BSplineParams,
    ) -> crate::Result<Self> {
        check_domain(&domain)?;
        if points.len() != displacements.len() {
            return Err(SolverError::InvalidParameter(format!(
                "{} sample points but {} displacements",
                points.len(),
                displacements.len()
            )));
        }
        if let Some(index) =
            points.iter().zip(displacements).position(|(p, d)| !(p.iter().chain(d.iter()).all(|v| v.is_finite())))
        {
            return Err(SolverError::InvalidParameter(format!("sample {} is not finite", index + 1)));
        }
        let (lo, hi) = (domain.min.coords(), domain.max.coords());
        let clamped: Vec<[f64; 3]> = points.iter().map(|p| std::array::from_fn(|a| p[a].clamp(lo[a], hi[a]))).collect();
        let (lattice, report) = fit_hierarchy(&Data::Scattered(&clamped), displacements, lo, hi, params)?;
        Ok(Self { lattice, domain, report, warnings: Vec::new(), spaces: PhantomData })
    }

    /// Fits D to `displacements` sampled on `grid` (x fastest), separably: each level costs O(grid + lattice).
    /// Gives the same lattice as [`Self::fit_displacements_raw`] on the grid's points; `par` splits the
    /// residual updates over z slices.
    pub fn fit_grid_raw(
        grid: &RegularGrid,
        displacements: &[[f64; 3]],
        domain: Aabb<From>,
        params: &BSplineParams,
        par: Parallelism,
    ) -> crate::Result<Self> {
        check_domain(&domain)?;
        grid.check()?;
        if displacements.len() != grid.len() {
            return Err(SolverError::InvalidParameter(format!(
                "a grid of {} points but {} displacements",
                grid.len(),
                displacements.len()
            )));
        }
        if let Some(index) = displacements.iter().position(|d| !d.iter().all(|v| v.is_finite())) {
            return Err(SolverError::InvalidParameter(format!("grid displacement {} is not finite", index + 1)));
        }
        let (lo, hi) = (domain.min.coords(), domain.max.coords());
        let (lattice, report) = fit_hierarchy(&Data::Grid(grid, par), displacements, lo, hi, params)?;
        Ok(Self { lattice, domain, report, warnings: Vec::new(), spaces: PhantomData })
    }

    /// Wraps a lattice (its box becomes the domain).
    #[must_use]
    pub fn from_lattice(lattice: ControlLattice, report: FitReport) -> Self {
        let domain = Aabb::new(Point3::from_array(lattice.min_mm), Point3::from_array(lattice.max_mm));
        Self { lattice, domain, report, warnings: Vec::new(), spaces: PhantomData }
    }

    /// The control lattice of D (finest level; all levels are refined onto it).
    #[must_use]
    pub fn lattice(&self) -> &ControlLattice {
        &self.lattice
    }

    /// Gives the lattice away.
    #[must_use]
    pub fn into_lattice(self) -> ControlLattice {
        self.lattice
    }

    /// The domain box in `From`.
    #[must_use]
    pub fn domain(&self) -> Aabb<From> {
        self.domain
    }

    /// What [`crate::pairs::validate`] found suspicious in the pairs of [`Self::fit`] (pairs numbered from 1); empty
    /// for the other constructors.
    #[must_use]
    pub fn warnings(&self) -> &[crate::pairs::PairWarning] {
        &self.warnings
    }

    /// How the fit ended (levels, residuals at the data).
    #[must_use]
    pub fn fit_report(&self) -> &FitReport {
        &self.report
    }

    /// The displacement D(x) = w(x) − x, mm.
    #[must_use]
    pub fn displacement_raw(&self, x: [f64; 3]) -> [f64; 3] {
        self.lattice.eval(x)
    }

    /// Writes w(x) for every point of `grid` (x fastest) into `out`, separably.
    pub fn sample_grid_into(&self, grid: &RegularGrid, out: &mut [[f64; 3]], par: Parallelism) -> crate::Result<()> {
        self.lattice.sample_grid_into(grid, true, out, par)
    }
}

impl HierarchicalBSpline<Fixed, Moving> {
    /// The forward warp `fixed_from_moving`: d(p_i) ≈ q_i, over a box in moving space.
    pub fn fit_forward(
        moving: &[Point3<Moving>],
        fixed: &[Point3<Fixed>],
        domain: Aabb<Moving>,
        params: &BSplineParams,
    ) -> crate::Result<Self> {
        Self::fit(moving, fixed, domain, params)
    }
}

impl HierarchicalBSpline<Moving, Fixed> {
    /// The pull-back `moving_from_fixed`, fitted directly from the reversed pairs: u(q_i) ≈ p_i, over a box
    /// in fixed space.
    pub fn fit_pullback(
        moving: &[Point3<Moving>],
        fixed: &[Point3<Fixed>],
        domain: Aabb<Fixed>,
        params: &BSplineParams,
    ) -> crate::Result<Self> {
        Self::fit(fixed, moving, domain, params)
    }
}

impl<Mid: Space, From: Space> HierarchicalBSpline<Mid, From> {
    /// The warp followed by the affine map `then`: then ∘ w. With w(x) = x + D(x) and then(y) = L y + t,
    /// then(w(x)) = x + D'(x), D'(x) = (L − I) x + t + L D(x); the uniform cubic basis reproduces affine functions
    /// exactly (control point k of an axis sits at min + (k − 1) h), so D' is a lattice of the same size with
    /// coefficients c'_k = (L − I) x_k + t + L c_k. Inside the domain it is exact; outside it the lattice clamps, as
    /// every lattice here does.
    #[must_use]
    pub fn followed_by<To: Space>(&self, then: &crate::linear::AffineWarp<To, Mid>) -> HierarchicalBSpline<To, From> {
        let l = then.linear();
        let t = nalgebra::Vector3::from(then.translation());
        let m = l - Matrix3::identity();
        let mut lattice = self.lattice.clone();
        let [n0, n1, n2] = lattice.dims();
        let h = lattice.spacing_mm();
        let min = lattice.min_mm;
        let coefficients = lattice.coefficients_mut();
        for kz in 0..n2 {
            for ky in 0..n1 {
                for kx in 0..n0 {
                    let o = ((kz * n1 + ky) * n0 + kx) * 3;
                    let x = nalgebra::Vector3::new(
                        min[0] + (kx as f64 - 1.0) * h[0],
                        min[1] + (ky as f64 - 1.0) * h[1],
                        min[2] + (kz as f64 - 1.0) * h[2],
                    );
                    let c = nalgebra::Vector3::new(coefficients[o], coefficients[o + 1], coefficients[o + 2]);
                    let c2 = m * x + t + l * c;
                    coefficients[o..o + 3].copy_from_slice(&[c2[0], c2[1], c2[2]]);
                }
            }
        }
        HierarchicalBSpline {
            lattice,
            domain: self.domain,
            report: self.report,
            warnings: self.warnings.clone(),
            spaces: PhantomData,
        }
    }
}

impl<To: Space, From: Space> Warp<To, From> for HierarchicalBSpline<To, From> {
    fn apply_raw(&self, x: [f64; 3]) -> [f64; 3] {
        self.lattice.warp_raw(x)
    }

    /// Analytic: I + ∂D/∂x from the B-spline derivative.
    fn jacobian_raw(&self, x: [f64; 3]) -> Matrix3<f64> {
        self.lattice.warp_jacobian(x)
    }
}
